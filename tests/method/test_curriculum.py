"""PFAL through the curriculum runner: two tiny stages, teacher handling, lineage and resuming."""

import csv
import json
import sys
from pathlib import Path

import pytest
import torch
import yaml

from floaff_zoo.cli import run_lightning
from floaff_zoo.curriculum import CurriculumError, load_experiment, main, run_curriculum
from floaff_zoo.hub.registry import sha256_file
from floaff_zoo.models.cfar import CFARModule

EXP = "tests/configs/pfal_tiny.yaml"
SETS = ["trainer.accelerator=cpu", "data.init_args.num_val=2", "trainer.limit_train_batches=3"]


def _distill_steps(stage_dir: Path) -> list[float]:
    rows = list(csv.DictReader(next(stage_dir.rglob("metrics.csv")).open()))
    return [float(r["train_distill_step"]) for r in rows if r.get("train_distill_step")]


@pytest.fixture(scope="module")
def pfal_run(tmp_path_factory):
    """Run the two stages once for the whole module (the expensive part, ~10 s)."""
    root = tmp_path_factory.mktemp("pfal")
    captured = {}

    def on_end(name, cli):
        if cli.model.teacher is not None:
            captured["teacher_state"] = {k: v.clone() for k, v in cli.model.teacher.state_dict().items()}
            captured["teacher_grads"] = [p.grad for p in cli.model.teacher.parameters()]
            captured["teacher_training"] = cli.model.teacher.training

    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        records = run_curriculum(EXP, root=root, sets=SETS, on_stage_end=on_end)
    finally:
        torch.set_num_threads(old)
    return root, records, captured


def test_stage2_starts_from_stage1_and_distils_from_it(pfal_run, root):
    run_root, records, captured = pfal_run
    s1, s2 = records
    assert s1["status"] == s2["status"] == "done"
    assert s2["from_stages"] == {
        "model.init_args.weights": s1["checkpoint"],
        "model.init_args.teacher": s1["checkpoint"],
    }
    stage1 = torch.load(s1["checkpoint"], weights_only=True)
    # the student built with the stage-2 arguments holds stage 1's weights exactly
    args = yaml.safe_load((root / "tests/configs/cfar_tiny.yaml").read_text())["model"]["init_args"]
    student = CFARModule(**args, weights=s1["checkpoint"])
    for k, v in student.state_dict().items():
        if k.startswith("net."):
            assert torch.equal(v, stage1["state_dict"][k]), k
    # teacher: unchanged by stage 2 (parameters and BN buffers), no grads, eval mode
    for k, v in captured["teacher_state"].items():
        assert torch.equal(v, stage1["state_dict"]["net.local_encoder." + k]), k
    assert all(g is None for g in captured["teacher_grads"])
    assert captured["teacher_training"] is False
    # distillation: exactly zero at the first step (student == teacher), positive once weights moved
    steps = _distill_steps(run_root / "stage2_drawer")
    assert len(steps) >= 3
    assert abs(steps[0]) < 1e-10
    assert max(steps[1:]) > 0
    assert not _distill_steps_in(run_root / "stage1_pnp")


def _distill_steps_in(stage_dir: Path) -> list[float]:
    rows = list(csv.DictReader(next(stage_dir.rglob("metrics.csv")).open()))
    return [r for r in rows if r.get("train_distill_step")]


def test_student_checkpoint_has_no_teacher_and_records_lineage(pfal_run):
    run_root, records, _ = pfal_run
    s1, s2 = records
    for ckpt in Path(s2["checkpoint"]).parent.glob("*.ckpt"):
        state = torch.load(ckpt, weights_only=True)
        assert not [k for k in state["state_dict"] if k.startswith("teacher.")], ckpt
        assert state["floaff_lineage"]["teacher_sha256"] == sha256_file(s1["checkpoint"])
        # stage 2 starts from stage 1's checkpoint (weights): its name and hash are recorded too
        assert state["floaff_lineage"]["weights"] == s1["checkpoint"]
        assert state["floaff_lineage"]["weights_sha256"] == sha256_file(s1["checkpoint"])
    # reloads without the teacher file being needed for loading
    m = CFARModule.load_from_checkpoint(s2["checkpoint"], weights_only=True)
    assert m.teacher is None
    lineage = json.loads((run_root / "lineage.json").read_text())
    assert lineage["complete"] is True  # every stage in: read_lineage accepts it
    assert [s["stage"] for s in lineage["stages"]] == ["stage1_pnp", "stage2_drawer"]
    for s in lineage["stages"]:
        assert s["sha256"] == sha256_file(s["checkpoint"]) and "val_rmse" in s["metrics"]
        assert s["configs"] == ["configs/data/synthetic_tiny.yaml", "tests/configs/cfar_tiny.yaml"]


def test_rerun_skips_finished_and_resumes_killed_stage(pfal_run, capsys):
    run_root, records, _ = pfal_run

    def refuse(args):
        raise AssertionError(f"a finished stage was rerun: {args}")

    again = run_curriculum(EXP, root=run_root, sets=SETS, runner=refuse)
    assert [r["checkpoint"] for r in again] == [r["checkpoint"] for r in records]
    assert capsys.readouterr().out.count("already finished") == 2
    # simulate a kill during stage 2: it resumes from its last.ckpt through --ckpt_path
    stage_file = run_root / "stage2_drawer" / "stage.json"
    rec = json.loads(stage_file.read_text())
    stage_file.write_text(json.dumps({"stage": rec["stage"], "status": "running", "args": rec["args"]}))
    mark_file = Path(rec["checkpoint"]).parents[1] / "curriculum_run.json"  # a killed fit never marks its run ended
    for kept in stage_file.parent.glob("stage.*.json"):  # nor keeps a finished record by its digest
        kept.unlink()
    mark_file.write_text(json.dumps({k: v for k, v in json.loads(mark_file.read_text()).items() if k != "fit_ended"}))
    seen = []

    def spy(args):
        seen.append(args)
        old = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            return run_lightning(args)
        finally:
            torch.set_num_threads(old)

    run_curriculum(EXP, root=run_root, sets=SETS, runner=spy)
    assert len(seen) == 1 and "--ckpt_path" in seen[0]
    assert seen[0][seen[0].index("--ckpt_path") + 1].endswith(".ckpt")
    assert json.loads(stage_file.read_text())["status"] == "done"


def test_teacher_with_another_architecture_lists_the_keys(pfal_run, root):
    _, records, _ = pfal_run
    args = yaml.safe_load((root / "tests/configs/cfar_tiny.yaml").read_text())["model"]["init_args"]
    args["local_mlps"] = [[16, 16], [16, 24]]
    student = CFARModule(**args, teacher=records[0]["checkpoint"])
    with pytest.raises(ValueError, match=r"net\.local_encoder\.levels\.1\.mlps\.0\.linears\.1\.weight"):
        student.setup("fit")


def test_without_fd_the_teacher_is_not_loaded_nor_recorded(pfal_run, root):
    """w/o FD never reads the teacher: it was loaded anyway (a second encoder in memory, and a teacher file that
    had to exist) and the saved lineage named a teacher the stage did not learn from."""
    _, records, _ = pfal_run
    args = yaml.safe_load((root / "tests/configs/cfar_tiny.yaml").read_text())["model"]["init_args"]
    for use_fd, weight in ((False, 1.0), (True, 0.0)):
        student = CFARModule(**{**args, "use_fd": use_fd, "distill_weight": weight}, teacher=records[0]["checkpoint"])
        student.setup("fit")
        assert student.teacher is None and not student.distill_active
        checkpoint = {"state_dict": student.state_dict()}
        student.on_save_checkpoint(checkpoint)
        assert checkpoint["floaff_lineage"]["teacher"] is None
    student = CFARModule(**args, teacher=records[0]["checkpoint"])
    student.setup("fit")
    assert student.teacher is not None and student.distill_active


def test_dry_run_and_bad_experiment(tmp_path, root, monkeypatch, capsys):
    monkeypatch.chdir(root)
    assert main(["--config", EXP, "--dry-run", "--set", "trainer.max_epochs=1", "--root", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert (
        out.count("floaff-zoo fit") == 2
        and "--model.init_args.teacher" in out
        and "<best checkpoint of stage1_pnp>" in out
    )
    assert not (tmp_path / "lineage.json").exists()
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"stages": [{"name": "a", "from_stages": {"model.init_args.teacher": "zz"}}]}))
    with pytest.raises(CurriculumError, match="zz"):
        main(["--config", str(bad), "--dry-run"])
    with pytest.raises(CurriculumError, match="key=value"):
        main(["--config", EXP, "--dry-run", "--set", "trainer.max_epochs"])


OVERRIDE_FILES = sorted(
    str(p.relative_to(Path(__file__).resolve().parents[2]))
    for sub in ("ablations", "sweep_crop")  # recipe/ and budget/ hold other kinds (tests/test_configs.py)
    for p in (Path(__file__).resolve().parents[2] / "configs" / "experiments" / sub).glob("*.yaml")
)


# every shipped experiment's stages parse: tests/test_configs.py


@pytest.mark.parametrize("override", OVERRIDE_FILES)
def test_ablation_and_sweep_files_override_cfar(override, root, monkeypatch, capsys):
    monkeypatch.chdir(root)
    with pytest.raises(SystemExit):
        run_lightning(
            [
                "fit",
                "--config",
                "configs/data/synthetic_tiny.yaml",
                "--config",
                "configs/models/cfar.yaml",
                "--model.init_args.crop_radius",
                "1.2",
                "--config",
                override,
                "--print_config",
            ]
        )
    printed = yaml.safe_load(capsys.readouterr().out)
    init = printed["model"]["init_args"]
    name = Path(override).stem
    if name.startswith("r1."):
        assert init["crop_radius"] == pytest.approx(float(name[1:]))
        assert printed["trainer"]["default_root_dir"].endswith(name)  # distinct run per radius
    else:
        assert init["use_" + name.removeprefix("no_")] is False


def test_sweep_covers_the_paper_radii(root):
    radii = sorted(float(p.stem[1:]) for p in (root / "configs/experiments/sweep_crop").glob("r*.yaml"))
    assert radii == pytest.approx([1.10, 1.15, 1.20, 1.25, 1.30, 1.35, 1.40])


def test_prior_residual_through_pfal_keeps_stage1_prior(tmp_path, root, monkeypatch):
    """The recipe's prior residual: stage 1 fills its task's grid, stage 2 adds its own and keeps stage 1's."""
    monkeypatch.chdir(root)
    extra = tmp_path / "residual.yaml"
    extra.write_text("model:\n  init_args:\n    prior_residual: true\n")
    old = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        s1, s2 = run_curriculum(EXP, root=tmp_path / "run", sets=SETS, extra_configs=[str(extra)])
    finally:
        torch.set_num_threads(old)
    m1 = CFARModule.load_from_checkpoint(s1["checkpoint"], weights_only=True)
    m2 = CFARModule.load_from_checkpoint(s2["checkpoint"], weights_only=True)
    assert m1.prior.seen_tasks() == ["PnPCounterToCab"]
    assert sorted(m2.prior.seen_tasks()) == ["CloseDrawer", "PnPCounterToCab"]
    pnp = m1.prior.tasks.index("PnPCounterToCab")
    assert torch.equal(m1.prior.sums[pnp], m2.prior.sums[pnp])  # stage 2 did not refill stage 1's task
    # an untrained residual predicts the prior itself
    fresh = CFARModule(
        **yaml.safe_load((root / "tests/configs/cfar_tiny.yaml").read_text())["model"]["init_args"],
        prior_residual=True,
        eval_yaw_source="gt",
    ).eval()
    fresh.prior.load_state_dict(m2.prior.state_dict())
    from floaff_zoo.contract import collate_samples
    from floaff_zoo.data.synthetic import make_synthetic_sample
    from floaff_zoo.nn.cfar import canonical_transform

    b = collate_samples([make_synthetic_sample(i, 256, 8, "CloseDrawer") for i in range(2)])
    with torch.no_grad():
        scores = fresh(b)
        canon = canonical_transform(
            b["scene_xyz"], b["scene_mask"], b["floor_xyz"], b["target_xyz"], b["target_yaw"], None
        )
        prior = fresh.prior.read(fresh.prior.task_index(["CloseDrawer"] * 2), canon.floor_xyz[..., :2])
    assert torch.allclose(scores, prior.clamp(1e-3, 1 - 1e-3), atol=1e-5)


@pytest.mark.parametrize(
    ("stage", "field"),
    [
        ({"from_stages": ["first"]}, "'from_stages' must be a mapping"),
        ({"overrides": ["trainer.max_epochs=1"]}, "'overrides' must be a mapping"),
        ({"root": 5}, "'root' must be a directory path"),
        ({"shared": "no"}, "'shared' must be true or false"),
        ({"tasks": ["CloseDrawer", 3]}, "'tasks' must be a list of task names"),
        ({"tasks": ["CloseDrawr"]}, "'tasks': unknown tasks ['CloseDrawr']; valid tasks: ['PnPCounterToCab'"),
        ({"tasks": []}, "'tasks': empty tasks list; choose from ['PnPCounterToCab'"),
        ({"model": {"file": "x.yaml"}}, "'model': expected a list of file names"),
    ],
)
def test_malformed_stage_field_names_file_stage_and_field(tmp_path, stage, field):
    """Lists for mappings were AttributeErrors, a number for root a TypeError, shared: "no" silently true."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"stages": [{"name": "first"}, {"name": "second", **stage}]}))
    with pytest.raises(CurriculumError) as info:
        load_experiment(bad)
    assert str(info.value).startswith(f"experiment config {bad}: stage 1 (second): {field}")


@pytest.mark.parametrize(
    ("top", "message"),
    [
        ({"stages": [{"name": ["a", "b"]}]}, "stage 0: 'name' must be a text"),
        ({"root": 5, "stages": [{"name": "a"}]}, "'root' must be a directory path"),
        ({"extends": ["base.yaml"], "stages": [{"name": "a"}]}, "'extends' must be a file name"),
    ],
)
def test_malformed_top_level_field_names_file_and_field(tmp_path, top, message):
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(top))
    with pytest.raises(CurriculumError) as info:
        load_experiment(bad)
    assert str(info.value).startswith(f"experiment config {bad}: {message}")


def test_invalid_yaml_is_one_line_naming_the_file(tmp_path):
    """YAML's message came through on 8 lines that called the file "<unicode string>"."""
    bad = tmp_path / "bad.yaml"
    bad.write_text("data: [configs/data/synthetic_tiny.yaml\nmodel: [configs/\n")
    with pytest.raises(CurriculumError) as info:
        load_experiment(bad)
    message = str(info.value)
    assert message.startswith(f"experiment config {bad}: invalid YAML (while parsing a flow sequence in bad.yaml")
    assert "\n" not in message and "<unicode string>" not in message


def test_curriculum_error_is_one_line_and_exit_2_at_the_console(tmp_path, root, monkeypatch, capsys):
    """`floaff-zoo` passed its argv on as a list, so every curriculum error re-raised: a traceback and exit 1."""
    from floaff_zoo import cli

    monkeypatch.chdir(root)
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"stages": [{"name": "a", "tasks": "CloseDrawer"}]}))
    monkeypatch.setattr(sys, "argv", ["floaff-zoo", "curriculum", "--config", str(bad), "--dry-run"])
    assert cli.main() == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert err == [
        f"floaff-zoo curriculum: error: experiment config {bad}: stage 0 (a): 'tasks' must be a list of "
        "task names, got 'CloseDrawer'"
    ]
    with pytest.raises(CurriculumError, match="'tasks'"):  # a Python caller still gets the exception
        cli.main(["curriculum", "--config", str(bad), "--dry-run"])


def test_a_stage_fit_error_is_one_line_naming_the_stage(tmp_path, root, monkeypatch, capsys):
    """A user error of a stage's fit (here a value the data module rejects in __init__, which the pre-check does not
    parse) was a traceback at the console, naming no stage."""
    monkeypatch.chdir(root)
    argv = ["--config", EXP, "--root", str(tmp_path), "--set", "data.init_args.num_val=-1"]
    assert main(argv, raise_errors=False) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith("floaff-zoo curriculum: error: stage stage1_pnp: ")
    assert "data.num_val must be an integer >= 0, got -1" in err[0]


def test_dry_run_refuses_an_override_no_stage_accepts(tmp_path, root, monkeypatch, capsys):
    """A dry run printed the commands of a mistyped --set key and exited 0; the run itself refused them."""
    monkeypatch.chdir(root)
    args = ["--config", EXP, "--dry-run", "--set", "trainer.max_epoch=1", "--root", str(tmp_path)]
    assert main(args, raise_errors=False) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and "its fit arguments do not parse" in err[0] and "max_epoch" in err[0], err


def test_dry_run_refuses_a_missing_config_file(tmp_path, root, monkeypatch, capsys):
    """A dry run printed the commands of a missing --extra-config or stage config file and exited 0."""
    monkeypatch.chdir(root)
    missing = str(tmp_path / "nosuch.yaml")
    assert main(["--config", EXP, "--dry-run", "--extra-config", missing], raise_errors=False) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and f"config file {missing} does not exist" in err[0]
    exp = yaml.safe_load((root / EXP).read_text())
    exp["stages"][1]["configs"] = [missing]
    bad = tmp_path / "pfal_missing.yaml"
    bad.write_text(yaml.safe_dump(exp))
    assert main(["--config", str(bad), "--dry-run"], raise_errors=False) == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and f"stage stage2_drawer: config file {missing} does not exist" in err[0]


def test_demo_curriculum_error_is_one_line_and_exit_2_at_the_console(tmp_path, root, monkeypatch, capsys):
    """The demo's curriculum step: one error line (not the curriculum's and the demo's), exit code 2."""
    from floaff_zoo import cli, demo
    from floaff_zoo.sim import generate

    monkeypatch.chdir(root)
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump({"stages": [{"name": "a", "overrides": ["trainer.max_epochs=1"]}]}))
    monkeypatch.setattr(demo, "EXPERIMENT", str(bad))
    monkeypatch.setattr(generate, "main", lambda argv: 0)  # the benchmark is not needed to reach the curriculum
    monkeypatch.setattr(sys, "argv", ["floaff-zoo", "demo", "--data", str(tmp_path / "d"), "--runs", str(tmp_path)])
    assert cli.main() == 2
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(err) == 1 and err[0].startswith(f"floaff-zoo curriculum: error: experiment config {bad}: stage 0 (a)")


def test_typo_in_a_later_stage_fails_before_the_first_stage_trains(tmp_path, root, monkeypatch):
    """A stage's fit arguments were first parsed when that stage started: a mistyped key in stage 2's overrides
    failed only after stage 1 had trained (minutes to hours on the dense protocol)."""
    monkeypatch.chdir(root)
    exp = yaml.safe_load((root / EXP).read_text())
    exp["stages"][1]["overrides"] = {"model.init_args.distil_weight": 0.5}  # distill_weight
    bad = tmp_path / "pfal_typo.yaml"
    bad.write_text(yaml.safe_dump(exp))
    run_root = tmp_path / "run"
    with pytest.raises(CurriculumError, match=r"stage stage2_drawer: its fit arguments do not parse: .*distil_weight"):
        main(["--config", str(bad), "--root", str(run_root)] + [f"--set={s}" for s in SETS])
    assert not (run_root / "stage1_pnp").exists()  # nothing trained, nothing written
    # a typo in an --extra-config file names the stage it first reaches
    extra = tmp_path / "extra.yaml"
    extra.write_text("model:\n  init_args:\n    crop_radus: 1.0\n")
    with pytest.raises(CurriculumError, match=r"stage stage1_pnp: its fit arguments do not parse: .*crop_radus"):
        main(["--config", EXP, "--root", str(run_root), "--extra-config", str(extra)])
    assert not run_root.exists()


@pytest.mark.parametrize(
    "bad, named", [("trainer.gradient_clip_val=.nan", "gradient_clip_val"), ("seed_everything=-1", "is not a seed")]
)
def test_a_bad_value_in_any_stage_is_named_before_the_first_stage_trains(tmp_path, root, monkeypatch, bad, named):
    """The value checks of `floaff-zoo fit` ran in hooks the curriculum's pre-check skipped: a bad --set failed only
    when the stage's fit started, after the earlier stages had trained."""
    import floaff_zoo.cli

    monkeypatch.chdir(root)
    seen: list = []
    monkeypatch.setattr(floaff_zoo.cli, "run_lightning", seen.append)  # the default runner, which pre-checks
    with pytest.raises(CurriculumError, match=named):
        run_curriculum(EXP, root=tmp_path, sets=[*SETS, bad])
    assert seen == []  # no stage ran


@pytest.mark.parametrize(
    "key, value, named",
    [
        ("teacher", "missing/stage1.ckpt", r"teacher missing/stage1\.ckpt: no such file or directory"),
        ("weights", "text.ckpt", r"weights: .*text\.ckpt: not a readable checkpoint"),
        ("axisnet", "no-such-hub-name", r"axisnet: 'no-such-hub-name' is not a checkpoint file"),
    ],
)
def test_a_later_stages_weights_file_that_does_not_load_is_named_before_the_first_stage_trains(
    tmp_path, root, monkeypatch, key, value, named
):
    """A teacher, weights or AxisNet file named in stage 2 was first read when stage 2's fit started: a missing or
    damaged file failed after stage 1 had trained."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "text.ckpt").write_text("not a checkpoint")
    for folder in ("configs", "tests"):
        (tmp_path / folder).symlink_to(root / folder)
    exp = yaml.safe_load((root / EXP).read_text())
    exp["stages"][1]["overrides"] = {f"model.init_args.{key}": value}
    del exp["stages"][1]["from_stages"]  # which would name stage 1's checkpoint instead
    bad = tmp_path / "pfal_files.yaml"
    bad.write_text(yaml.safe_dump(exp))
    run_root = tmp_path / "run"
    with pytest.raises(CurriculumError, match=rf"stage stage2_drawer: model\.init_args\.{named}"):
        run_curriculum(bad, root=run_root, sets=SETS)
    assert not run_root.exists()  # nothing trained, nothing written
    # w/o FD never reads the teacher: it need not exist (test_without_fd_the_teacher_is_not_loaded_nor_recorded)
    if key == "teacher":
        assert len(run_curriculum(bad, root=run_root, sets=[*SETS, "model.init_args.use_fd=false"], dry_run=True)) == 0
