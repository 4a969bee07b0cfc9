"""scripts/reproduce_small.sh copies the report of the job it ran: two jobs testing one run at once each get theirs."""

from __future__ import annotations

import json
import os
import subprocess
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

#: a stand-in for `floaff-zoo test`: the report (its label and residual scale) in a new version folder beside the
#: run, after the delay $DELAY_<scale> seconds
FAKE_FZ = textwrap.dedent(
    """\
    #!/usr/bin/env bash
    cfg=$3; scale=none; label=
    while [ $# -gt 0 ]; do
      case $1 in
        --model.init_args.residual_scale) scale=$2 ;;
        --trainer.callbacks.init_args.label) label=$2 ;;
      esac
      shift
    done
    d=$(dirname "$cfg")/../version_scale$scale; mkdir -p "$d"
    delay=DELAY_$scale; sleep "${!delay}"
    printf '{"label": "%s", "residual_scale": "%s"}' "$label" "$scale" > "$d/report.json"; echo x > "$d/report.md"
    """
)


def _finished_curriculum(runs: Path) -> None:
    """``runs/layouts/occ_recipe_s0``: a curriculum whose last stage finished (lineage.json, config, last.ckpt)."""
    run = runs / "layouts" / "occ_recipe_s0" / "stage2" / "cfarmodule" / "version_0"
    (run / "checkpoints").mkdir(parents=True)
    (run / "config.yaml").write_text("")
    ckpt = run / "checkpoints" / "last.ckpt"
    ckpt.write_text("")
    lineage = {"complete": True, "stages": [{"checkpoint": str(ckpt)}]}
    (runs / "layouts" / "occ_recipe_s0" / "lineage.json").write_text(json.dumps(lineage))


@pytest.mark.parametrize("slow", ["0", "2"])
def test_two_jobs_testing_one_run_at_once_copy_their_own_reports(tmp_path, slow):
    """Each test found its report as the first report.json written beside the run since it started: the slower of
    two jobs testing one run (occ_recipe_rs0_s0 and occ_recipe_rs2_s0) could copy the faster one's report."""
    _finished_curriculum(tmp_path / "runs")
    fz = tmp_path / "fakefz"
    fz.write_text(FAKE_FZ)
    fz.chmod(0o755)
    env = {
        **os.environ,
        "FZ": str(fz),
        "PRESET": "dense",
        "RUNS": str(tmp_path / "runs"),
        "OUT": str(tmp_path / "out"),
        "PAR": "2",
        "DELAY_0": "2" if slow == "0" else "0.2",
        "DELAY_2": "2" if slow == "2" else "0.2",
    }
    jobs = ["occ_recipe_rs0_s0", "occ_recipe_rs2_s0"]
    done = subprocess.run(
        [str(ROOT / "scripts" / "reproduce_small.sh"), *jobs], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stdout + done.stderr
    for scale in ("0", "2"):
        report = json.loads((tmp_path / "out" / "layouts" / f"occ_recipe_rs{scale}_s0" / "report.json").read_text())
        assert report["residual_scale"] == scale, (slow, report)


def test_reports_name_no_folder_of_the_checkout_they_are_copied_into(tmp_path):
    """Run from a git worktree with RUNS and OUT in the main checkout, the copied reports kept that checkout's absolute
    paths (the machine's folders): they are made relative to it, as to the checkout the script runs from."""
    main = tmp_path / "main"
    subprocess.run(["git", "init", "-q", str(main)], check=True)
    _finished_curriculum(main / "runs")
    fz = tmp_path / "fakefz"
    fz.write_text(FAKE_FZ.replace('"residual_scale": "%s"}', f'"residual_scale": "%s", "data": "{main}/data/x"}}'))
    fz.chmod(0o755)
    env = {**os.environ, "FZ": str(fz), "PRESET": "dense", "RUNS": str(main / "runs"), "DELAY_0": "0"}
    env["OUT"] = str(main / "docs" / "results" / "x")
    done = subprocess.run(
        [str(ROOT / "scripts" / "reproduce_small.sh"), "occ_recipe_rs0_s0"],
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    report = json.loads((main / "docs" / "results" / "x" / "layouts" / "occ_recipe_rs0_s0" / "report.json").read_text())
    assert report["data"] == "data/x", report


#: a stand-in for `floaff-zoo fit` and `test` that logs each call's arguments, one per line, to $LOG: fit makes the run
#: folder (config.yaml, checkpoints/last.ckpt), test writes a labelled report beside it
FAKE_FZ_LOGGING = textwrap.dedent(
    """\
    #!/usr/bin/env bash
    printf '%s\\n' "$@" > "$LOG.$1.$$"; echo "== $1 $$" >> "$LOG"
    cmd=$1; root=; cfg=; label=
    while [ $# -gt 0 ]; do
      case $1 in
        --trainer.default_root_dir) root=$2 ;;
        --config) [ -z "$cfg" ] && cfg=$2 ;;
        --trainer.callbacks.init_args.label) label=$2 ;;
      esac
      shift
    done
    if [ "$cmd" = fit ]; then
      mkdir -p "$root/m/version_0/checkpoints"; : > "$root/m/version_0/checkpoints/last.ckpt"
      : > "$root/m/version_0/config.yaml"
    else
      d=$(dirname "$cfg")/../version_1; mkdir -p "$d"
      printf '{"label": "%s"}' "$label" > "$d/report.json"; echo x > "$d/report.md"
    fi
    """
)


def _single_task_env(tmp_path: Path) -> dict[str, str]:
    fz = tmp_path / "fakefz"
    fz.write_text(FAKE_FZ_LOGGING)
    fz.chmod(0o755)
    return {
        **os.environ,
        "FZ": str(fz),
        "PRESET": "dense",
        "RUNS": str(tmp_path / "runs"),
        "OUT": str(tmp_path / "out"),
        "LOG": str(tmp_path / "calls"),
        "PAR": "1",
    }


def _calls(tmp_path: Path, cmd: str) -> list[list[str]]:
    return [f.read_text().splitlines() for f in sorted(tmp_path.glob(f"calls.{cmd}.*"))]


def _value(args: list[str], flag: str) -> str:
    return args[args.index(flag) + 1]


def test_single_task_job_trains_and_tests_its_own_task_only(tmp_path):
    """`st_<task>_<model>_s<seed>` (the paper's Table 3: one model per task) fits on its task alone, on the whole
    training pool, for PFAL's per-task share of the budget (250 steps), and tests on that task only."""
    axis = tmp_path / "runs" / "styles" / "pool_cfar_pfal_s1" / "axisnet.ckpt"
    axis.parent.mkdir(parents=True)
    axis.write_text("")
    lineage = {"complete": True, "stages": [{"checkpoint": str(axis)}]}
    (axis.parent / "lineage.json").write_text(json.dumps(lineage))
    env = _single_task_env(tmp_path)
    jobs = ["st_osd_pointnet2_s0", "styles_st_cdd_cfar_s1"]
    done = subprocess.run(
        [str(ROOT / "scripts" / "reproduce_small.sh"), *jobs], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stdout + done.stderr
    fits, tests = _calls(tmp_path, "fit"), _calls(tmp_path, "test")
    assert len(fits) == 2 and len(tests) == 2
    by_model = {("cfar_demo" in " ".join(f)): f for f in fits}
    pn2, cfar = by_model[False], by_model[True]
    for fit, task in ((pn2, "OpenSingleDoor"), (cfar, "CloseDoubleDoor")):
        # a flag given twice counts at its last occurrence (jsonargparse): the budget file's 1,000 steps are replaced
        last = {fit[i]: fit[i + 1] for i in range(len(fit) - 1) if fit[i].startswith("--")}
        assert last["--data.init_args.tasks"] == f"[{task}]"
        assert last["--data.init_args.val_scenes"] == "0"
        assert last["--trainer.max_steps"] == "250"
    assert _value(cfar, "--model.init_args.axisnet") == str(axis)
    # the Styles curriculum's crop radius (configs/experiments/pfal_dense_styles.yaml), not the demo config's 1.2 m
    assert _value(cfar, "--model.init_args.crop_radius") == "1.3"
    assert _value(cfar, "--seed_everything") == "1"
    assert "configs/data/floaff_dense_styles.yaml" in cfar
    assert sorted(_value(t, "--data.init_args.tasks") for t in tests) == ['["CloseDoubleDoor"]', '["OpenSingleDoor"]']
    assert (tmp_path / "out" / "layouts" / "st_osd_pointnet2_s0" / "report.json").is_file()
    assert (tmp_path / "out" / "styles" / "st_cdd_cfar_s1" / "report.json").is_file()


@pytest.mark.parametrize(
    ("job", "message"),
    [
        ("st_sink_pointnet2_s0", "unknown task 'sink'"),
        ("st_osd_resnet_s0", "unknown model 'resnet'"),
        ("st_osd_pointnet2", "no seed"),
        ("st_osd_cfar_s0", "run pool_cfar_pfal_s0 first"),
    ],
)
def test_single_task_job_names_what_is_wrong(tmp_path, job, message):
    env = _single_task_env(tmp_path)
    done = subprocess.run(
        [str(ROOT / "scripts" / "reproduce_small.sh"), job], env=env, capture_output=True, text=True, timeout=120
    )
    assert done.returncode != 0
    log = (tmp_path / "runs" / "logs" / f"{job}.log").read_text()
    assert message in log, log
    assert not _calls(tmp_path, "fit")


#: a stand-in for scripts/fresh_labels.py: the "labels" of a data copy are the numbers in its labels.txt
FAKE_FRESH_LABELS = textwrap.dedent(
    """\
    import argparse
    import json
    from pathlib import Path

    import numpy as np

    p = argparse.ArgumentParser()
    for flag in ("--root", "--benchmark", "--episodes", "--out"):
        p.add_argument(flag)
    p.add_argument("--zero-failures", action="store_true")
    a = p.parse_args()
    label = np.loadtxt(Path(a.root) / "labels.txt")
    setting = json.dumps({"made_from": {"L0_scene": str(label.tolist())}})
    np.savez(a.out, setting=setting, **{"L0_scene/label": label})
    """
)


def test_success_labels_of_another_data_copy_are_refused(tmp_path):
    """runs/labels/success_train_<bench>.npz was made once and reused whatever DATA_ROOT said: a job on another copy
    of the data trained on the first copy's labels without a word. It is kept for a copy with the same labels (at any
    path) and refused, untouched, for a copy with others."""
    import sys

    import numpy as np

    repo = tmp_path / "repo"  # the script works in the folder above its own: runs/labels lands here, not in ROOT
    (repo / "scripts").mkdir(parents=True)
    (repo / "scripts" / "reproduce_small.sh").write_bytes((ROOT / "scripts" / "reproduce_small.sh").read_bytes())
    (repo / "scripts" / "reproduce_small.sh").chmod(0o755)
    (repo / "scripts" / "fresh_labels.py").write_text(FAKE_FRESH_LABELS)
    (repo / "configs").symlink_to(ROOT / "configs")
    copies = {"a": "1 2 3", "a_again": "1 2 3", "b": "1 2 4"}
    for name, labels in copies.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "labels.txt").write_text(labels)
    env = _single_task_env(tmp_path)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env['PATH']}"  # a python3 with numpy
    axis = tmp_path / "runs" / "layouts" / "pool_succ_occ_recipe_s0" / "axisnet.ckpt"
    axis.parent.mkdir(parents=True)
    axis.write_text("")
    (axis.parent / "lineage.json").write_text(json.dumps({"complete": True, "stages": [{"checkpoint": str(axis)}]}))
    job, labels = "st_drawer_cfar_best_s0", repo / "runs" / "labels" / "success_train_layouts.npz"

    def run(copy: str) -> subprocess.CompletedProcess:
        env.update(DATA_ROOT=str(tmp_path / copy), OUT=str(tmp_path / f"out_{copy}"))
        cmd = [str(repo / "scripts" / "reproduce_small.sh"), job]
        return subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=120)

    done = run("a")
    assert done.returncode == 0, done.stdout + done.stderr
    assert np.load(labels)["L0_scene/label"].tolist() == [1, 2, 3]
    np.savez(labels, setting="{}", **{"L0_scene/label": np.load(labels)["L0_scene/label"]})  # written before made_from
    before = labels.read_bytes()
    done = run("a_again")  # another path, the same labels: kept, a file without made_from too (finished stages
    assert done.returncode == 0, done.stdout + done.stderr  # record its sha256: a new file would re-fit them all)
    assert labels.read_bytes() == before
    n_fits = len(_calls(tmp_path, "fit"))
    assert n_fits == 2  # both jobs ran through to their fits
    done = run("b")
    assert done.returncode != 0
    log = (tmp_path / "runs" / "logs" / f"{job}.log").read_text()
    assert "holds other labels than" in log and "another copy of the data" in log, log
    assert len(_calls(tmp_path, "fit")) == n_fits  # nothing trained on them
    assert np.load(labels)["L0_scene/label"].tolist() == [1, 2, 3]
    assert sorted(p.name for p in labels.parent.iterdir()) == [labels.name]  # no file made aside is left
