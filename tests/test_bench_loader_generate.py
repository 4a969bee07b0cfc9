"""benchmarks/bench_loader.py and bench_generate.py: what their figures are measured over."""

from __future__ import annotations

import re

import pytest

from tests._scripts import load_benchmark


def test_the_loader_benchmark_parses_cold_every_run_and_counts_every_split(tmp_path, capsys):
    """Its cache lived in the dataset folder and stayed, so a second run's "cold setup" was a cache hit (670x
    faster); and the rate divided by the train samples while the setup parsed the test split too."""
    bl = load_benchmark("bench_loader")
    root = tmp_path / "moma"
    bl.write_moma_like(root, 4)  # the same 4 samples in the train and (as other scenes) the test split file
    args = ["--root", str(root), "--num-points", "64", "--batch-size", "2", "--epochs", "1", "--steps", "1"]
    for _ in range(2):
        bl.main(args)
        out = capsys.readouterr().out
        assert "(8 samples of every split parsed)" in out and "4 train samples" in out
        assert sorted(p.name for p in root.iterdir()) == ["data_split", "info", "rgbd"]  # nothing left behind


def test_the_loader_benchmarks_cold_setup_times_no_first_import(tmp_path):
    """With --root (nothing written first) the cold setup imported open3d and scipy's KD-tree on its first sample,
    a one-off of the process timed as parsing (about 0.6 s: a quarter of a 16-sample setup)."""
    import json
    import subprocess
    import sys

    from tests._scripts import ROOT

    root = tmp_path / "moma"
    load_benchmark("bench_loader").write_moma_like(root, 4)
    driver = f"""
import json, sys
from tests._scripts import load_benchmark
bench_loader = load_benchmark("bench_loader")
from floaff_zoo.data.moma_kitchen import MoMaKitchenDataModule
import time, types
seen, clock = [], []  # at each setup: were the readers' modules imported when the timer last started?
real = time.perf_counter
def stamp():
    clock.append(all(m in sys.modules for m in ("open3d", "scipy.spatial")))
    return real()
bench_loader.time = types.SimpleNamespace(perf_counter=stamp)
setup = MoMaKitchenDataModule.setup
def spy(self, stage=None):
    seen.append(clock[-1])
    return setup(self, stage)
MoMaKitchenDataModule.setup = spy
bench_loader.main(["--root", {str(root)!r}, "--num-points", "64", "--batch-size", "2", "--epochs", "1", "--steps", "1"])
print(json.dumps(seen))
"""
    proc = subprocess.run([sys.executable, "-c", driver], capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == [True, True]  # the cold setup, then the warm one


def test_the_loader_benchmark_refuses_max_samples_it_would_ignore(tmp_path, capsys):
    """FloAffKitchenDataModule takes no max_samples: --dataset floaff --max-samples N timed every sample of the
    benchmark (or failed later on the data) while the run looked limited to N."""
    bl = load_benchmark("bench_loader")
    with pytest.raises(SystemExit) as exc:
        bl.main(["--dataset", "floaff", "--root", str(tmp_path), "--max-samples", "4"])
    assert exc.value.code == 2 and "--max-samples applies to --dataset moma only" in capsys.readouterr().err


def _epoch_start_lines(bl, root, capsys, methods: list[str], workers: int) -> list[str]:
    args = ["--root", str(root), "--num-points", "64", "--batch-size", "2", "--epoch-start"]
    bl.main(
        [*args, "--epoch-start-workers", str(workers), "--epoch-start-epochs", "2", "--epoch-start-methods", *methods]
    )
    out = capsys.readouterr().out
    assert "loader (cached" not in out and "train step" not in out  # the throughput figures are not measured
    head = out.index("epoch start (iterator + first batch)")
    return out[head:].strip().splitlines()


def _check_method_lines(lines: list[str], method: str) -> None:
    at = next(i for i, line in enumerate(lines) if line.startswith(f"{method:5s}: start restarted "))
    start, epoch = lines[at], lines[at + 1]
    assert "persistent" in start and "once per fit" in start and re.search(r"restarted / persistent = [\d.]+x", start)
    assert re.search(r"epoch loading restarted +[\d.]+ s, persistent +[\d.]+ s, restarted / persistent = ", epoch)
    assert re.search(r"the restart costs -?[\d.]+ s per epoch, -?\d+% of the restarted epoch's loading$", epoch)


def test_the_loader_benchmark_times_an_epoch_start_with_workers_restarted_and_persistent(tmp_path, capsys):
    """--epoch-start (new): the cost of starting the train loader's workers anew each epoch (as the data modules do,
    for an exact resume) against persistent ones, as medians, their ratio and a share of the epoch's loading."""
    bl = load_benchmark("bench_loader")
    root = tmp_path / "moma"
    bl.write_moma_like(root, 4)
    lines = _epoch_start_lines(bl, root, capsys, ["fork"], 2)
    assert lines[0].startswith("epoch start (iterator + first batch), 2 workers, batch 2, 4 train samples (2 batches)")
    assert "medians over epochs 2-2" in lines[0]
    _check_method_lines(lines, "fork")
    assert not any(line.startswith("spawn") for line in lines)
    with pytest.raises(SystemExit):
        bl.main(["--root", str(root), "--epoch-start", "--epoch-start-epochs", "1"])  # no epoch after the first
    assert "--epoch-start-epochs >= 2" in capsys.readouterr().err


@pytest.mark.slow
def test_the_loader_benchmarks_epoch_start_runs_under_spawn(tmp_path, capsys):
    """Under spawn every worker unpickles the dataset and imports the package anew (about 10 s of CPU each: slow)."""
    bl = load_benchmark("bench_loader")
    root = tmp_path / "moma"
    bl.write_moma_like(root, 4)
    _check_method_lines(_epoch_start_lines(bl, root, capsys, ["spawn"], 1), "spawn")


def test_the_generate_benchmark_refuses_a_folder_it_would_resume(tmp_path):
    """A second run with the same --out resumed the first one's scenes and printed that as the preset's wall time."""
    bg = load_benchmark("bench_generate")
    (tmp_path / "tiny").mkdir()
    (tmp_path / "tiny" / "manifest.json").write_text("{}")
    with pytest.raises(SystemExit, match="holds an earlier run, which generate would resume"):
        bg.bench_preset("tiny", 1, tmp_path)


def test_run_all_refreshes_both_loader_sections(tmp_path, monkeypatch):
    """bench_loader.py has two sections in docs/performance.md (its throughput, and its --epoch-start timing):
    ``run_all.py --only bench_loader`` runs both commands and replaces both sections in place."""
    import subprocess

    run_all = load_benchmark("run_all")
    titles = [title for title, script, _, _ in run_all.SUITE if script == "bench_loader.py"]
    assert len(titles) == 2
    out = tmp_path / "perf.md"
    out.write_text("# Performance\n\nold\n\n" + "".join(f"## {t}\n\nold {i}\n\n" for i, t in enumerate(titles)))
    ran = []

    def fake(cmd, **kw):
        ran.append(cmd[2:])
        return subprocess.CompletedProcess(cmd, 0, stdout=f"new {len(ran)}", stderr="")

    monkeypatch.setattr(run_all.subprocess, "run", fake)
    assert run_all.main(["--only", "bench_loader", "--out", str(out)]) == 0
    assert ran == [["--samples", "16"], ["--epoch-start", "--epoch-start-epochs", "4"]]
    text = out.read_text()
    assert "old 0" not in text and "old 1" not in text
    assert text.index(titles[0]) < text.index("new 1") < text.index(titles[1]) < text.index("new 2")


def test_the_generate_benchmark_refuses_bad_arguments_before_anything_runs(tmp_path, monkeypatch, capsys):
    """--views 0 timed no view and printed 0.0 ms/view with exit 0; a negative --workers, an --out under a file or
    holding an earlier run failed only after the render and scaling runs (minutes); a --data typo reported nothing."""
    bg = load_benchmark("bench_generate")
    ran = []
    monkeypatch.setattr(bg, "bench_render", lambda *a: ran.append(a) or pytest.fail("ran"))
    (tmp_path / "file").write_text("x")
    (tmp_path / "old" / "small").mkdir(parents=True)
    (tmp_path / "old" / "small" / "manifest.json").write_text("{}")
    for args, said in (
        (["--views", "0"], "--views must be >= 1, got 0"),
        (["--image-size", "-1"], "--image-size must be >= 1, got -1"),
        (["--workers", "-1"], "--workers must be >= 0, got -1"),
        (["--data", str(tmp_path / "nope")], f"--data {tmp_path / 'nope'}: not a folder"),
        (["--out", str(tmp_path / "file" / "x")], f"--out {tmp_path / 'file' / 'x'}: {tmp_path / 'file'} is not a"),
        (["--small", "--out", str(tmp_path / "old")], f"{tmp_path / 'old' / 'small'} holds an earlier run"),
    ):
        with pytest.raises(SystemExit) as exc:
            bg.main(args)
        assert exc.value.code == 2 and said in capsys.readouterr().err, args
    assert ran == []


def test_a_malformed_manifest_is_skipped_with_a_line_not_a_traceback(tmp_path):
    """The manifests are read at the end of the run: a finished one without its counts (or not an object) raised
    KeyError / AttributeError there, after every figure was measured."""
    import json

    bg = load_benchmark("bench_generate")
    # c: a wall time that is text failed in its line's format, and was called "unreadable"
    counts = {"scenes_ok": 1, "scenes_dropped": 0, "views_total": 2}
    config = {"benchmarks": ["styles"], "max_candidates": 9}
    texts = {"counts": counts, "config": config, "scenes": {}, "preset": "tiny", "workers": 1}
    bad = (("a", {"status": "done", "wall_s": 3.0}), ("b", [1, 2]), ("c", {"status": "done", "wall_s": "3 s", **texts}))
    for name, man in bad:
        (tmp_path / name).mkdir()
        (tmp_path / name / "manifest.json").write_text(json.dumps(man))
    lines = bg.manifest_walls(tmp_path)
    assert len(lines) == 3 and all("not a generate manifest" in line and "skipped" in line for line in lines)
    assert "KeyError" in lines[0] and "AttributeError" in lines[1] and "ValueError" in lines[2]


@pytest.mark.parametrize(
    ("args", "said"),
    [
        (["--root", "{tmp}/nope"], "--root {tmp}/nope: not a folder"),  # a MisconfigurationException traceback
        (["--root", "{tmp}/file"], "--root {tmp}/file: not a folder"),
        (["--dataset", "floaff", "--root", "{tmp}", "--benchmark", "style"], "argument --benchmark: invalid choice"),
    ],
)
def test_the_loader_benchmark_refuses_a_missing_root_or_unknown_benchmark_by_name(tmp_path, args, said, capsys):
    (tmp_path / "file").write_text("x")
    bl = load_benchmark("bench_loader")
    with pytest.raises(SystemExit) as exc:
        bl.main([a.format(tmp=tmp_path) for a in args])
    assert exc.value.code == 2 and said.format(tmp=tmp_path) in capsys.readouterr().err
