"""The demo command: its wiring (fast) and the whole pipeline (slow, about 10 minutes on 2 cores)."""

import json
from pathlib import Path

import pytest

from floaff_zoo.cli import main


def test_demo_help_and_configs_exist(root, monkeypatch, capsys):
    monkeypatch.chdir(root)
    with pytest.raises(SystemExit) as ex:
        main(["demo", "--help"])
    assert ex.value.code == 0
    assert "--preset" in capsys.readouterr().out
    from floaff_zoo import demo

    for cfg in (demo.EXPERIMENT, demo.DATA_CONFIG, demo.BASELINE_CONFIG, demo.EVAL_CONFIG):
        assert (root / cfg).is_file(), cfg


def test_demo_folders_follow_the_preset():
    """`demo --preset small` generated into data/floaff_demo, where the generator refuses another preset's settings
    after a `make demo`."""
    from floaff_zoo.demo import parse_args

    assert (parse_args([]).data, parse_args([]).runs) == ("data/floaff_demo", "runs/demo")
    small = parse_args(["--preset", "small"])
    assert (small.data, small.runs) == ("data/floaff_small", "runs/demo_small")
    given = parse_args(["--preset", "small", "--data", "d", "--runs", "r"])
    assert (given.data, given.runs) == ("d", "r")


def test_demo_curriculum_dry_run_lists_three_stages(root, monkeypatch, capsys):
    monkeypatch.chdir(root)
    from floaff_zoo import curriculum, demo

    assert curriculum.main(["--config", demo.EXPERIMENT, "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert out.count("# stage") == 3 and "stage2_door_drawer" in out and "model.init_args.teacher" in out


@pytest.mark.slow
def test_demo_end_to_end(root, monkeypatch, tmp_path):
    monkeypatch.chdir(root)
    assert main(["demo", "--data", str(tmp_path / "data"), "--runs", str(tmp_path / "runs"), "--epochs", "2"]) == 0
    reports = sorted(Path(tmp_path / "runs").rglob("report.json"))
    assert len(reports) == 2
    for rep in reports:
        data = json.loads(rep.read_text())
        assert data["sr"]["available"] and data["sr"]["oracle"]["all"]["mean"] >= 0.9


def test_demo_outside_the_repository_is_one_line(tmp_path, monkeypatch, capsys):
    """Run from another folder, the demo ended in a traceback (FileNotFoundError) instead of a one-line error."""
    from floaff_zoo.demo import main as demo_main

    monkeypatch.chdir(tmp_path)
    assert demo_main([], raise_errors=False) == 2
    err = capsys.readouterr().err
    assert "demo configs not found" in err and "run the demo from the repository root" in err
    assert "Traceback" not in err


def test_demo_reuses_a_baseline_only_when_fitted_with_the_same_data_and_epochs(tmp_path, monkeypatch, capsys):
    """A baseline finished by `demo --epochs 1 --data A` was reused by `demo --epochs 30 --data B` (and its report
    then compared with a model trained on B), and by a demo on data generated again into A (beside a curriculum
    re-fitted on the new data)."""
    import floaff_zoo.cli
    from floaff_zoo import demo
    from floaff_zoo.runs import data_fingerprint, mark_finished

    def fit(*args, **kwargs):
        raise RuntimeError("fitting")

    monkeypatch.setattr(floaff_zoo.cli, "run_lightning", fit)
    monkeypatch.chdir(tmp_path)
    for name in ("a", "b"):
        (tmp_path / "data" / name / "s0").mkdir(parents=True)
        (tmp_path / "data" / name / "s0" / "scene.json").write_text("{}")
    run = tmp_path / "pointnet2" / "version_0"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "last.ckpt").write_bytes(b"x")
    folder = (tmp_path / "data" / "a").resolve()  # what `demo --data data/a --epochs 1` records
    args = {"data": str(folder), "data_fingerprint": data_fingerprint(folder), "max_epochs": 1}
    mark_finished(run, run / "checkpoints" / "last.ckpt", {"epochs": 1, "args": args})
    (folder / ".cache").mkdir()  # the fit's sample cache and the generator's run log, which every demo run
    (folder / "manifest.json").write_text('{"wall_s": 2.0}')  # rewrites, change nothing
    assert demo._fit_baseline("data/a", tmp_path / "pointnet2", 1) == run
    for data, epochs in (("data/b", 1), ("data/a", 30)):
        with pytest.raises(RuntimeError, match="fitting"):
            demo._fit_baseline(data, tmp_path / "pointnet2", epochs)
    assert "was fitted with" in capsys.readouterr().out
    (folder / "s0" / "scene.json").write_text('{"generated": "again"}')
    with pytest.raises(RuntimeError, match="fitting"):
        demo._fit_baseline("data/a", tmp_path / "pointnet2", 1)
    assert "the data in data/a changed since" in capsys.readouterr().out


def test_a_failing_comparison_table_fails_the_demo(root, tmp_path, monkeypatch, capsys):
    """`floaff-zoo table` failed (exit code 2, e.g. no usable report) and the demo still said it finished (0)."""
    from floaff_zoo import curriculum, demo
    from floaff_zoo.sim import generate

    monkeypatch.chdir(root)
    monkeypatch.setattr(generate, "main", lambda argv: 0)
    monkeypatch.setattr(curriculum, "main", lambda argv, raise_errors=False: 0)
    stage = {"checkpoint": str(tmp_path / "cfar" / "checkpoints" / "last.ckpt")}
    monkeypatch.setattr(curriculum, "read_lineage", lambda root: {"stages": [stage]})
    monkeypatch.setattr(demo, "_fit_baseline", lambda data, root, epochs: tmp_path / "pointnet2")
    monkeypatch.setattr(demo, "_test", lambda run, data, ckpt=None: tmp_path / "none" / "report.json")  # not written
    assert demo.main(["--data", str(tmp_path / "data"), "--runs", str(tmp_path / "runs")], raise_errors=False) == 2
    assert "floaff-zoo demo: error: the map, sr_views, sr_tasks table(s) failed" in capsys.readouterr().err


@pytest.mark.parametrize("below", ["", "runs"])
def test_demo_runs_folder_blocked_by_a_file_is_refused_before_generating(tmp_path, below, capsys):
    """`--runs <a file>` generated the whole benchmark first and failed at the curriculum's first stage."""
    from floaff_zoo.demo import parse_args

    blocker = tmp_path / "taken"
    blocker.write_text("not a folder")
    with pytest.raises(SystemExit) as ex:
        parse_args(["--data", str(tmp_path / "data"), "--runs", str(blocker / below)])
    assert ex.value.code == 2
    assert f"{blocker} exists and is not a folder" in capsys.readouterr().err
    assert not (tmp_path / "data").exists()
    assert parse_args(["--runs", str(tmp_path / "new" / "runs")]).runs == str(tmp_path / "new" / "runs")
