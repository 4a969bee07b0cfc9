"""Run records: the demo refits a baseline fit that was killed (finished.json), and damaged curriculum records
are errors that name the file instead of silently starting over."""

from __future__ import annotations

import json
import types
from pathlib import Path

import pytest

from floaff_zoo import curriculum, demo
from floaff_zoo.curriculum import CurriculumError, read_lineage, run_curriculum
from floaff_zoo.runs import FINISHED_FILE, RunError, finished_runs, mark_finished, read_finished, resolve_ckpt_alias

EXP = "tests/configs/pfal_tiny.yaml"


class FakeFit:
    """Stands in for ``floaff_zoo.cli.run_lightning``: writes a run dir like a fit does, optionally 'killed'."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.calls: list[list[str]] = []
        self.kill = False

    def __call__(self, args: list[str]):
        self.calls.append(args)
        run = self.root / "pointnet2module" / f"version_{len(self.calls) - 1}"
        (run / "checkpoints").mkdir(parents=True)
        (run / "config.yaml").write_text("model: {}\n")
        last = run / "checkpoints" / "last.ckpt"
        last.write_bytes(b"weights")
        if self.kill:  # killed after the first epoch's checkpoint: last.ckpt exists, fit never returned
            raise KeyboardInterrupt
        cb = types.SimpleNamespace(best_model_path=str(last), last_model_path=str(last))
        return types.SimpleNamespace(
            trainer=types.SimpleNamespace(checkpoint_callback=cb, log_dir=str(run), current_epoch=2)
        )


def test_finished_marker_round_trip_and_corrupt_marker_is_named(tmp_path):
    run = tmp_path / "version_0"
    run.mkdir()
    assert read_finished(run) is None
    ckpt = run / "last.ckpt"
    ckpt.write_bytes(b"x")
    mark_finished(run, ckpt, {"epochs": 3})
    rec = read_finished(run)
    assert rec["checkpoint"] == str(ckpt) and rec["epochs"] == 3 and "T" in rec["finished"]
    assert [r for r, _ in finished_runs(tmp_path)] == [run]
    ckpt.unlink()  # a marker whose checkpoint is gone does not count
    assert finished_runs(tmp_path) == []
    (run / FINISHED_FILE).write_text("{not json")
    with pytest.raises(RunError, match=str(run / FINISHED_FILE)):
        read_finished(run)
    (run / FINISHED_FILE).write_bytes(b"\xff\xfe{}")  # not UTF-8: a bare UnicodeDecodeError before
    with pytest.raises(RunError, match=str(run / FINISHED_FILE)):
        read_finished(run)


def test_demo_refits_a_killed_baseline_and_reuses_a_finished_one(tmp_path, monkeypatch, capsys):
    import floaff_zoo.cli

    fake = FakeFit(tmp_path / "runs")
    monkeypatch.setattr(floaff_zoo.cli, "run_lightning", fake)
    fake.kill = True
    with pytest.raises(KeyboardInterrupt):
        demo._fit_baseline("data/x", fake.root, epochs=2)
    assert list(fake.root.rglob("last.ckpt")) and not list(fake.root.rglob(FINISHED_FILE))

    fake.kill = False
    run = demo._fit_baseline("data/x", fake.root, epochs=2)  # the killed run is not reused
    assert len(fake.calls) == 2 and run.name == "version_1"
    assert "did not finish" in capsys.readouterr().out
    rec = read_finished(run)
    assert Path(rec["checkpoint"]) == run / "checkpoints" / "last.ckpt"

    assert demo._fit_baseline("data/x", fake.root, epochs=2) == run  # finished: reused, no third fit
    assert len(fake.calls) == 2 and "reusing" in capsys.readouterr().out


def _never(args):
    raise AssertionError(f"no stage should run: {args}")


def test_corrupt_stage_record_is_an_error_naming_it(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    cfg = curriculum.load_experiment(EXP)
    stage_file = curriculum.stage_dir(cfg, cfg["stages"][0], tmp_path) / curriculum.STAGE_FILE
    stage_file.parent.mkdir(parents=True)
    stage_file.write_text('{"stage": "stage1_pnp", "status": "do')  # truncated by a full disk, say
    with pytest.raises(CurriculumError, match=str(stage_file)):
        run_curriculum(EXP, root=tmp_path, runner=_never)
    stage_file.write_bytes(b'{"stage": "caf\xe9"}')  # bytes that are no UTF-8: a UnicodeDecodeError traceback
    with pytest.raises(CurriculumError, match=f"{stage_file}: corrupt curriculum record"):
        run_curriculum(EXP, root=tmp_path, runner=_never)
    latin = tmp_path / "latin.yaml"
    latin.write_bytes(b"stages:\n  - name: caf\xe9\n")
    with pytest.raises(CurriculumError, match=f"experiment config {latin}: invalid YAML"):
        curriculum.load_experiment(latin)


@pytest.mark.parametrize(
    ("field", "value"), [("checkpoint", 123), ("before", 5), ("args", ["fit", 3]), ("started", "at noon")]
)
def test_a_stage_record_field_of_the_wrong_kind_is_named(tmp_path, root, monkeypatch, field, value):
    """A stage.json that parses but holds e.g. a number for its checkpoint crashed with a TypeError traceback."""
    monkeypatch.chdir(root)
    cfg = curriculum.load_experiment(EXP)
    stage_file = curriculum.stage_dir(cfg, cfg["stages"][0], tmp_path) / curriculum.STAGE_FILE
    stage_file.parent.mkdir(parents=True)
    stage_file.write_text(json.dumps({"stage": "stage1_pnp", "status": "running", field: value}))
    with pytest.raises(CurriculumError, match=rf"{stage_file}: field '{field}' is .*, not a"):
        run_curriculum(EXP, root=tmp_path, runner=_never)


def test_an_unfinished_lineage_is_refused_and_a_dry_run_ignores_a_damaged_one(tmp_path, root, monkeypatch, capsys):
    """A rerun killed in a later stage left a lineage of the earlier stages alone, and its last stage read as the
    curriculum's; a dry run (which only prints) failed on a damaged lineage."""
    monkeypatch.chdir(root)
    lineage = tmp_path / curriculum.LINEAGE_FILE
    stage = {"stage": "stage1_pnp", "checkpoint": "x.ckpt"}
    lineage.write_text(json.dumps({"complete": False, "stages": [stage]}))
    with pytest.raises(CurriculumError, match=rf"{lineage}: the curriculum did not finish \(stages done: stage1_pnp\)"):
        read_lineage(tmp_path)
    assert read_lineage(tmp_path, finished=False)["stages"] == [stage]
    lineage.write_text(json.dumps({"stages": [stage]}))  # an older runner's record: no mark, accepted
    assert read_lineage(tmp_path)["stages"] == [stage]
    lineage.write_text("[1, 2")
    assert len(run_curriculum(EXP, root=tmp_path, dry_run=True, runner=_never)) == 0
    assert capsys.readouterr().out.count("# stage") == len(curriculum.load_experiment(EXP)["stages"])


def test_corrupt_lineage_is_an_error_naming_it(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    lineage = tmp_path / curriculum.LINEAGE_FILE
    lineage.write_text("[1, 2")
    with pytest.raises(CurriculumError, match=str(lineage)):
        read_lineage(tmp_path)
    with pytest.raises(CurriculumError, match=str(lineage)):
        run_curriculum(EXP, root=tmp_path, runner=_never)
    lineage.write_text(json.dumps({"stages": []}))
    with pytest.raises(CurriculumError, match="stages"):
        read_lineage(tmp_path)
    lineage.unlink()
    with pytest.raises(CurriculumError, match="run the curriculum first"):
        read_lineage(tmp_path)


@pytest.fixture
def truncated_run(tmp_path):
    """A run directory whose last.ckpt was cut short (a full disk, a copy interrupted)."""
    import torch

    last = tmp_path / "run" / "version_0" / "checkpoints" / "last.ckpt"
    last.parent.mkdir(parents=True)
    torch.save({"state_dict": {"w": torch.zeros(4096)}, "callbacks": {}, "pytorch-lightning_version": "2"}, last)
    last.write_bytes(last.read_bytes()[:5000])
    return tmp_path / "run", last


def test_best_of_a_run_with_a_truncated_last_ckpt_is_a_run_error_naming_it(truncated_run):
    run, last = truncated_run
    with pytest.raises(RunError, match=f"--ckpt_path best: {last}: not a readable checkpoint"):
        resolve_ckpt_alias("best", run)
    assert resolve_ckpt_alias("last", run) == str(last)  # not read: the CLI checks the file it is given


def test_hub_push_of_a_run_with_a_truncated_last_ckpt_exits_2(truncated_run, capsys):
    from floaff_zoo.cli import main

    assert main(["hub", "push", str(truncated_run[0] / "version_0"), "--name", "tiny.truncated.v1"]) == 2
    err = capsys.readouterr().err
    assert "floaff-zoo hub: error:" in err
    assert "last.ckpt: not a readable checkpoint" in err  # the truncated file named, not "no last.ckpt found"


def test_another_models_unreadable_last_ckpt_does_not_block_best(truncated_run):
    """Under one default_root_dir, a newer cut-off last.ckpt of another run (killed, or still being written) stopped
    `--ckpt_path best` of every model; it is now passed over (and its error raised when nothing else is found)."""
    import os

    import torch

    root, cut = truncated_run
    mine = root / "tinypointnetmodule" / "version_0" / "checkpoints" / "last.ckpt"
    mine.parent.mkdir(parents=True)
    hp = {"_class_path": "floaff_zoo.models.tiny.TinyPointNetModule"}
    torch.save({"state_dict": {}, "hyper_parameters": hp, "callbacks": {}, "pytorch-lightning_version": "2"}, mine)
    os.utime(mine, (1, 1))  # older than the cut-off file
    assert resolve_ckpt_alias("best", root, model_class="TinyPointNetModule") == str(mine)
    mine.unlink()
    with pytest.raises(RunError, match=rf"--ckpt_path best: {cut}: not a readable checkpoint"):  # maybe its own
        resolve_ckpt_alias("best", root, model_class="TinyPointNetModule")


def test_the_data_fingerprint_reads_what_a_fit_trains_on_and_not_what_it_writes(tmp_path):
    """What decides whether a finished stage or demo baseline is reused (runs.data_fingerprint)."""
    from floaff_zoo.runs import data_fingerprint

    data, other = tmp_path / "data", tmp_path / "other"
    (data / "s0").mkdir(parents=True)
    (data / "s0" / "scene.json").write_text('{"labels": [1]}')
    (other / "s1").mkdir(parents=True)
    (other / "s1" / "scene.json").write_text('{"labels": [0]}')
    (data / "linked").symlink_to(other, target_is_directory=True)
    (data / "linked_again").symlink_to(data, target_is_directory=True)  # a cycle is walked once
    (data / "linked_twice").symlink_to(other, target_is_directory=True)  # so is a folder linked twice
    (data / "labels.txt").write_text("1" * ((1 << 20) + 1))  # large tables count by size, not content
    first = data_fingerprint(data)
    (data / ".cache").mkdir()  # what fits write there, and the generator's run log
    (data / ".cache" / "x.pt").write_bytes(b"x")
    (data / "manifest.json").write_text('{"wall_s": 1}')
    (data / "labels.txt").write_text("2" * ((1 << 20) + 1))
    assert data_fingerprint(data) == first
    (other / "s1" / "scene.json").write_text('{"labels": [1]}')  # a linked folder generated again
    assert data_fingerprint(data) != first


def test_a_last_ckpt_that_is_no_file_is_passed_over_and_named(tmp_path):
    """A link to a removed checkpoint (or a folder) named last.ckpt stopped `--ckpt_path last|best` with a bare
    FileNotFoundError from sorting by time, or was handed out as the checkpoint."""
    import os

    ckpts = tmp_path / "m" / "version_0" / "checkpoints"
    ckpts.mkdir(parents=True)
    os.symlink(tmp_path / "removed.ckpt", ckpts / "last.ckpt")
    (ckpts / "last-v1.ckpt").mkdir()
    with pytest.raises(RunError, match=r"no last.ckpt under .* \(2 not a file, e\.g\. "):
        resolve_ckpt_alias("last", tmp_path)
    real = tmp_path / "m" / "version_1" / "checkpoints" / "last.ckpt"
    real.parent.mkdir(parents=True)
    real.write_bytes(b"weights")
    os.utime(real, (1, 1))  # older than the link: still the only file
    assert resolve_ckpt_alias("last", tmp_path) == str(real)


@pytest.mark.parametrize(
    "callbacks",
    [
        ["ModelCheckpoint"],
        {"ModelCheckpoint{'monitor': 'val/loss'}": "x.ckpt"},
        {"ModelCheckpoint{}": {"best_model_path": 5}},
    ],
)
def test_best_of_a_checkpoint_with_damaged_callback_states_is_named(tmp_path, callbacks):
    """Callback states that are not Lightning's mappings were an AttributeError/TypeError traceback."""
    import torch

    last = tmp_path / "m" / "version_0" / "checkpoints" / "last.ckpt"
    last.parent.mkdir(parents=True)
    torch.save({"state_dict": {}, "callbacks": callbacks, "pytorch-lightning_version": "2"}, last)
    with pytest.raises(RunError, match=f"--ckpt_path best: {last}: "):
        resolve_ckpt_alias("best", tmp_path)


def test_a_checkpoint_whose_hyper_parameters_are_no_mapping_records_no_class(tmp_path):
    import torch

    last = tmp_path / "m" / "version_0" / "checkpoints" / "last.ckpt"
    last.parent.mkdir(parents=True)
    torch.save({"state_dict": {}, "hyper_parameters": ["lr"], "pytorch-lightning_version": "2"}, last)
    with pytest.raises(RunError, match=r"no last.ckpt of TinyPointNetModule .*\(no class recorded\)"):
        resolve_ckpt_alias("best", tmp_path, model_class="TinyPointNetModule")
