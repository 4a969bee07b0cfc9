"""Resuming a killed curriculum stage: only from a run with the same stage arguments, and into that run's own
directory so the stage's best checkpoint is the best over the epochs before and after the kill."""

from __future__ import annotations

import csv
import io
import json
import re
import shutil
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch
import yaml

from floaff_zoo.cli import run_lightning
from floaff_zoo.curriculum import CurriculumError, run_curriculum
from floaff_zoo.hub.registry import sha256_file
from floaff_zoo.runs import resolve_ckpt_alias

ROOT = Path(__file__).resolve().parents[2]
# lr 0.01 on the tiny pair: val_rmse is lowest at epoch 0 and ~0.02 higher from epoch 1 on
OVERRIDES = {
    "trainer.max_epochs": 4,
    "trainer.accelerator": "cpu",
    "trainer.enable_progress_bar": False,
    "trainer.enable_model_summary": False,
    "model.init_args.train.lr": 0.01,
}


def _experiment(tmp_path: Path, max_epochs: int = 4) -> Path:
    """A one-stage experiment on the tiny synthetic data and the tiny PointNet."""
    exp = {
        "root": str(tmp_path / "run"),
        "data": [str(ROOT / "configs/data/synthetic_tiny.yaml")],
        "model": [str(ROOT / "configs/models/tiny_pointnet.yaml")],
        "overrides": {**OVERRIDES, "trainer.max_epochs": max_epochs},
        "stages": [{"name": "s1"}],
    }
    path = tmp_path / "exp.yaml"
    path.write_text(yaml.safe_dump(exp))
    return path


def _killed_after(epochs: int, seen: list | None = None):
    """A runner whose fit is killed after ``epochs`` epochs (0: before it starts), before the curriculum records it."""

    def runner(args):
        if seen is not None:
            seen.append(args)
        if epochs:
            runner.cli = run_lightning(args + ["--trainer.max_epochs", str(epochs)])
        raise KeyboardInterrupt("simulated kill")

    return runner


def _spy(seen: list):
    def runner(args):
        seen.append(args)
        return run_lightning(args)

    return runner


def _val_rmse(stage_dir: Path, min_epoch: int = 0) -> list[float]:
    """Every val_rmse logged under a stage folder (all its runs) from ``min_epoch`` on."""
    rows = [r for f in stage_dir.rglob("metrics.csv") for r in csv.DictReader(f.open())]
    return [float(r["val_rmse"]) for r in rows if r.get("val_rmse") and int(r["epoch"]) >= min_epoch]


def test_resumed_stage_records_the_best_over_the_whole_stage(tmp_path, capsys):
    exp = _experiment(tmp_path)
    killed = _killed_after(2)
    with pytest.raises(KeyboardInterrupt):
        run_curriculum(exp, runner=killed)
    cb = killed.cli.trainer.checkpoint_callback
    pre_best, pre_path = float(cb.best_model_score), cb.best_model_path
    seen: list = []
    (rec,) = run_curriculum(exp, runner=_spy(seen))
    sdir = tmp_path / "run" / "s1"
    assert "--ckpt_path" in seen[0] and rec["resumed_from"].endswith("last.ckpt")
    assert min(_val_rmse(sdir, min_epoch=2)) > pre_best  # the scenario: the stage's best is from before the kill
    assert rec["checkpoint"] == pre_path and rec["best_score"] == pytest.approx(pre_best)
    assert resolve_ckpt_alias("best", sdir) == rec["checkpoint"]  # `--ckpt_path best` agrees
    # one run directory, whose metrics.csv still holds the epochs before the kill
    (metrics,) = sdir.rglob("metrics.csv")
    epochs = {int(r["epoch"]) for r in csv.DictReader(metrics.open())}
    assert epochs == {0, 1, 2, 3} and Path(rec["checkpoint"]).parents[1] == metrics.parent


def test_a_truncated_last_checkpoint_says_how_to_go_on(tmp_path, capsys):
    """A kill while the checkpoint was written leaves a truncated ``last.ckpt``: the stage names it and says that
    deleting it starts the stage again, which then works."""
    exp = _experiment(tmp_path, max_epochs=2)
    with pytest.raises(KeyboardInterrupt):
        run_curriculum(exp, runner=_killed_after(1))
    (last,) = (tmp_path / "run" / "s1").rglob("last.ckpt")
    last.write_bytes(last.read_bytes()[: last.stat().st_size // 2])
    with pytest.raises(CurriculumError, match=rf"stage s1: cannot resume the killed fit: {re.escape(str(last))}: not a "
                       r"readable checkpoint .*Delete that file .* else starts afresh"):  # fmt: skip
        run_curriculum(exp)
    last.unlink()
    (rec,) = run_curriculum(exp)
    assert rec["resumed_from"] is None and Path(rec["checkpoint"]).is_file()


@pytest.mark.parametrize(
    "text", [b"trainer: [unclosed\n", b"\xff\xfe", b"trainer:\n  logger: {class_path: CSVLogger, init_args: [1]}\n"]
)
def test_a_killed_run_with_a_damaged_config_file_still_resumes(tmp_path, capsys, text):
    """A killed run whose config.yaml did not parse (or named a logger with odd init args) stopped the rerun with a
    YAML, Unicode or TypeError traceback: the stage resumes from its last.ckpt into a new run directory."""
    exp = _experiment(tmp_path, max_epochs=2)
    with pytest.raises(KeyboardInterrupt):
        run_curriculum(exp, runner=_killed_after(1))
    (last,) = (tmp_path / "run" / "s1").rglob("last.ckpt")
    (last.parents[1] / "config.yaml").write_bytes(text)
    (rec,) = run_curriculum(exp)
    assert rec["resumed_from"] == str(last) and Path(rec["checkpoint"]).is_file()
    assert "cannot resume into" in capsys.readouterr().out


def test_changed_arguments_never_resume_an_older_run(tmp_path, capsys):
    exp = _experiment(tmp_path, max_epochs=2)
    (old,) = run_curriculum(exp)
    sets = ["model.init_args.train.lr=0.003"]  # the recipe changed, and its first rerun was killed at once
    with pytest.raises(KeyboardInterrupt):
        run_curriculum(exp, sets=sets, runner=_killed_after(0))
    capsys.readouterr()
    seen: list = []
    (new,) = run_curriculum(exp, sets=sets, runner=_spy(seen))
    assert "--ckpt_path" not in seen[0] and new["resumed_from"] is None
    assert "starting a fresh fit" in capsys.readouterr().out
    assert Path(new["checkpoint"]).parents[1] != Path(old["checkpoint"]).parents[1]
    state = torch.load(new["checkpoint"], weights_only=True)
    assert state["hyper_parameters"]["train"]["lr"] == pytest.approx(0.003)


def test_killed_run_with_new_arguments_resumes_itself(tmp_path):
    exp = _experiment(tmp_path, max_epochs=2)
    (old,) = run_curriculum(exp)
    sets = ["model.init_args.train.lr=0.003"]
    with pytest.raises(KeyboardInterrupt):
        run_curriculum(exp, sets=sets, runner=_killed_after(1))
    old_run = Path(old["checkpoint"]).parents[1]
    killed_run = next(p for p in (tmp_path / "run" / "s1").rglob("version_*") if p != old_run)
    seen: list = []
    (new,) = run_curriculum(exp, sets=sets, runner=_spy(seen))
    assert Path(new["resumed_from"]).parents[1] == killed_run == Path(new["checkpoint"]).parents[1]
    marker = json.loads((killed_run / "curriculum_run.json").read_text())
    assert marker["digest"] == new["digest"]


def test_finished_stage_reruns_when_a_config_file_it_reads_changed(tmp_path, capsys):
    exp = _experiment(tmp_path, max_epochs=1)
    data = tmp_path / "data.yaml"
    data.write_text((ROOT / "configs/data/synthetic_tiny.yaml").read_text())
    spec = yaml.safe_load(exp.read_text())
    spec["data"] = [str(data)]
    exp.write_text(yaml.safe_dump(spec))
    (old,) = run_curriculum(exp)

    def refuse(args):
        raise AssertionError(f"a finished stage was rerun: {args}")

    run_curriculum(exp, runner=refuse)  # nothing changed: skipped
    assert "already finished" in capsys.readouterr().out
    data.write_text(data.read_text() + "\n# edited after the stage finished\n")
    seen: list = []
    (new,) = run_curriculum(exp, runner=_spy(seen))
    assert len(seen) == 1 and "a --config file it reads changed" in capsys.readouterr().out
    assert new["digest"] != old["digest"] and new["checkpoint"] != old["checkpoint"]


def test_a_finished_run_is_never_resumed(tmp_path, capsys):
    """A finished stage whose checkpoint was replaced is re-fit; when that re-fit was killed before its first
    checkpoint, the next run resumed the OLD finished run: Lightning trained nothing and the stage recorded whatever
    file then sat at the old best path (here another fit's checkpoint) as done."""
    exp = _experiment(tmp_path, max_epochs=2)
    (old,) = run_curriculum(exp)
    other = run_lightning(
        ["fit", "--config", str(ROOT / "configs/data/synthetic_tiny.yaml"), "--config",
         str(ROOT / "configs/models/tiny_pointnet.yaml"), "--trainer.max_epochs", "1", "--trainer.accelerator", "cpu",
         "--trainer.enable_progress_bar", "false", "--trainer.default_root_dir", str(tmp_path / "other"),
         "--model.init_args.train.lr", "0.5"]
    )  # fmt: skip
    Path(old["checkpoint"]).write_bytes(Path(other.trainer.checkpoint_callback.best_model_path).read_bytes())
    with pytest.raises(KeyboardInterrupt):
        run_curriculum(exp, runner=_killed_after(0))
    capsys.readouterr()
    seen: list = []
    (new,) = run_curriculum(exp, runner=_spy(seen))
    assert "--ckpt_path" not in seen[0] and new["resumed_from"] is None
    assert Path(new["checkpoint"]).parents[1] != Path(old["checkpoint"]).parents[1]
    state = torch.load(new["checkpoint"], weights_only=True)
    assert state["hyper_parameters"]["train"]["lr"] == pytest.approx(0.01)  # the stage's own fit, not the swap


def test_a_later_stage_reruns_when_its_teacher_was_refit_into_the_same_path(tmp_path, capsys):
    """Stage 2 names stage 1's checkpoint by path. Without validation that path is .../version_0/.../last.ckpt:
    stage 1 re-fit into a fresh folder writes a new checkpoint at the same path, and stage 2 (its arguments
    unchanged) was skipped as finished, trained from a teacher that no longer exists."""
    exp = _experiment(tmp_path, max_epochs=1)
    spec = yaml.safe_load(exp.read_text())
    spec["stages"] = [{"name": "s1"}, {"name": "s2", "from_stages": {"model.init_args.weights": "s1"}}]
    spec["overrides"]["trainer.limit_val_batches"] = 0  # no validation: each stage's checkpoint is its last.ckpt
    exp.write_text(yaml.safe_dump(spec))
    s1, s2 = run_curriculum(exp)
    spec["stages"][0]["overrides"] = {"model.init_args.train.lr": 0.003}  # stage 1 only: stage 2's arguments stay
    exp.write_text(yaml.safe_dump(spec))
    shutil.rmtree(tmp_path / "run" / "s1")  # stage 1 is re-fit with another recipe into the same folder
    seen: list = []
    new1, new2 = run_curriculum(exp, runner=_spy(seen))
    assert new1["checkpoint"] == s1["checkpoint"] and new1["sha256"] != s1["sha256"]  # same path, new weights
    assert len(seen) == 2 and f"a file its arguments name ({s1['checkpoint']}) changed" in capsys.readouterr().out
    assert new2["inputs"] == {new1["checkpoint"]: new1["sha256"]}


def test_a_finished_stage_reruns_when_a_file_its_config_file_names_changed(tmp_path, capsys):
    """Only files named in the fit arguments were hashed: a checkpoint or label file named inside a --config file
    (a recipe's init weights, data.init_args.train_labels) was rewritten by a script, and the finished stage was
    skipped, trained from the old file."""
    exp = _experiment(tmp_path, max_epochs=1)
    (pre,) = run_curriculum(exp)
    weights = tmp_path / "init.ckpt"
    shutil.copy(pre["checkpoint"], weights)
    extra = tmp_path / "init_from.yaml"
    extra.write_text(f"model:\n  init_args:\n    weights: {weights}\n")
    (old,) = run_curriculum(exp, extra_configs=[str(extra)])
    assert old["inputs"] == {str(weights): sha256_file(weights)}
    shutil.copy(old["checkpoint"], weights)  # other weights at the same path, the config file unchanged
    capsys.readouterr()
    seen: list = []
    (new,) = run_curriculum(exp, extra_configs=[str(extra)], runner=_spy(seen))
    assert (
        len(seen) == 1 and f"a file its arguments name ({weights}) changed since it finished" in capsys.readouterr().out
    )
    assert new["inputs"] == {str(weights): sha256_file(weights)}


def test_a_killed_stage_whose_input_file_changed_starts_afresh(tmp_path, capsys):
    """A killed stage resumed whenever its digest matched: its weights file (an earlier stage's checkpoint re-fit
    into the same path) replaced since the kill, the resumed fit went on from epochs trained on the old weights."""
    exp = _experiment(tmp_path, max_epochs=2)
    (pre,) = run_curriculum(exp, root=tmp_path / "pre", sets=["trainer.max_epochs=1"])
    weights = tmp_path / "init.ckpt"
    shutil.copy(pre["checkpoint"], weights)
    sets = [f"model.init_args.weights={weights}"]
    killed = _killed_after(1)
    with pytest.raises(KeyboardInterrupt):
        run_curriculum(exp, sets=sets, runner=killed)
    shutil.copy(killed.cli.trainer.checkpoint_callback.last_model_path, weights)  # same path, other weights
    capsys.readouterr()
    seen: list = []
    (new,) = run_curriculum(exp, sets=sets, runner=_spy(seen))
    assert "--ckpt_path" not in seen[0] and new["resumed_from"] is None
    assert f"({weights}) changed since the killed run started; starting a fresh fit" in capsys.readouterr().out
    assert new["inputs"] == {str(weights): sha256_file(weights)}


def test_a_run_folder_shared_with_other_arguments_is_never_resumed(tmp_path, capsys):
    """With trainer.logger false every fit of a stage writes one folder, marked with the digest of the first: a
    rerun resumed from the newest last.ckpt there, written by a killed fit with other arguments (another lr)."""
    exp = _experiment(tmp_path, max_epochs=2)
    spec = yaml.safe_load(exp.read_text())
    spec["overrides"]["trainer.logger"] = False
    exp.write_text(yaml.safe_dump(spec))
    with pytest.raises(KeyboardInterrupt):
        run_curriculum(exp, runner=_killed_after(1))
    with pytest.raises(KeyboardInterrupt):  # other arguments, killed in the same folder
        run_curriculum(exp, sets=["model.init_args.train.lr=0.5"], runner=_killed_after(1))
    capsys.readouterr()
    seen: list = []
    (rec,) = run_curriculum(exp, runner=_spy(seen))
    assert "--ckpt_path" not in seen[0] and rec["resumed_from"] is None
    assert "fits with other arguments wrote checkpoints into it too" in capsys.readouterr().out
    state = torch.load(rec["checkpoint"], weights_only=True)
    assert state["hyper_parameters"]["train"]["lr"] == pytest.approx(0.01)


def test_a_kill_while_a_finished_stage_is_recorded_loses_no_fit(tmp_path, monkeypatch, capsys):
    """The run was marked finished before the stage record was written: a kill in between made the next run find
    no resumable run and re-fit the whole stage ("no checkpoint of a run with these arguments")."""
    import floaff_zoo.curriculum as curriculum

    exp = _experiment(tmp_path, max_epochs=1)
    write = curriculum._write_json

    def killed_at_done_record(path, data):
        if path.name == "stage.json" and data.get("status") == "done":
            raise KeyboardInterrupt("simulated kill")
        write(path, data)

    monkeypatch.setattr(curriculum, "_write_json", killed_at_done_record)
    with pytest.raises(KeyboardInterrupt):
        run_curriculum(exp)
    monkeypatch.setattr(curriculum, "_write_json", write)
    (first_run,) = (tmp_path / "run" / "s1").rglob("version_*")
    capsys.readouterr()
    seen: list = []
    (rec,) = run_curriculum(exp, runner=_spy(seen))
    assert "--ckpt_path" in seen[0] and "starting a fresh fit" not in capsys.readouterr().out
    assert Path(rec["checkpoint"]).parents[1] == first_run and rec["runs"] == [str(first_run)]
    assert json.loads((first_run / "curriculum_run.json").read_text())["fit_ended"] is True
    # killed after the record, before its run is marked finished: the next run skips the stage and marks it
    sets = ["model.init_args.train.lr=0.003"]

    def killed_at_mark(run, record):
        if not json.loads((run / "curriculum_run.json").read_text()).get("fit_ended"):
            raise KeyboardInterrupt("simulated kill")

    monkeypatch.setattr(curriculum, "_mark_finished", killed_at_mark)
    with pytest.raises(KeyboardInterrupt):
        run_curriculum(exp, sets=sets)
    monkeypatch.undo()

    def refuse(args):
        raise AssertionError(f"a finished stage was rerun: {args}")

    (again,) = run_curriculum(exp, sets=sets, runner=refuse)
    assert json.loads((Path(again["runs"][0]) / "curriculum_run.json").read_text())["fit_ended"] is True


def test_experiment_checks_extends_roots_and_shared_folders(tmp_path):
    """An experiment extending another without a root wrote into the other's run folder; a missing 'extends' file
    was named without the file that extends it; two stages in one folder overwrote each other's records."""
    from floaff_zoo.curriculum import CurriculumError, load_experiment

    parent = tmp_path / "parent.yaml"
    spec = yaml.safe_load(_experiment(tmp_path).read_text())
    del spec["root"]
    parent.write_text(yaml.safe_dump(spec))
    child = tmp_path / "child.yaml"
    child.write_text(yaml.safe_dump({"extends": "parent.yaml", "overrides": {"trainer.max_epochs": 1}}))
    assert load_experiment(child)["root"] == "runs/child" and load_experiment(parent)["root"] == "runs/parent"
    orphan = tmp_path / "orphan.yaml"
    orphan.write_text(yaml.safe_dump({"extends": "nonexist.yaml"}))
    with pytest.raises(CurriculumError, match=r"orphan\.yaml: 'extends' nonexist\.yaml: no such file"):
        load_experiment(orphan)
    spec["stages"] = [{"name": "a", "root": str(tmp_path / "same")}, {"name": "b", "root": str(tmp_path / "same")}]
    parent.write_text(yaml.safe_dump(spec))
    with pytest.raises(CurriculumError, match="stages 'a' and 'b' share a folder"):
        load_experiment(parent)
    # --root moves the stages without their own root: b's folder becomes a's, unchecked, even in a dry run
    spec["stages"] = [{"name": "a", "root": str(tmp_path / "moved" / "b")}, {"name": "b"}]
    parent.write_text(yaml.safe_dump(spec))
    load_experiment(parent)
    with pytest.raises(CurriculumError, match=r"\(run folder .*moved\): stages 'a' and 'b' share a folder"):
        run_curriculum(parent, root=tmp_path / "moved", dry_run=True)


def test_a_rerun_marks_the_earlier_lineage_incomplete_until_it_is_checked(tmp_path):
    """While a rerun re-fits an earlier stage, read_lineage accepted the previous run's lineage as complete."""
    from floaff_zoo.curriculum import CurriculumError, read_lineage

    exp = _experiment(tmp_path, max_epochs=1)
    run_curriculum(exp)
    assert read_lineage(tmp_path / "run")["complete"] is True
    with pytest.raises(KeyboardInterrupt):
        run_curriculum(exp, sets=["model.init_args.train.lr=0.003"], runner=_killed_after(0))
    with pytest.raises(CurriculumError):
        read_lineage(tmp_path / "run")
    assert read_lineage(tmp_path / "run", finished=False)["complete"] is False


def test_a_shared_stage_folder_keeps_every_finished_fit(tmp_path, capsys):
    """Two experiments sharing a stage folder (one AxisNet for several curricula): a fit of the other experiment
    replaced the folder's record, so the first experiment re-fit its finished stage, and every stage after it."""
    exp = _experiment(tmp_path, max_epochs=1)
    spec = yaml.safe_load(exp.read_text())
    spec["stages"] = [{"name": "pre", "root": str(tmp_path / "shared")}, {"name": "s1"}]
    exp.write_text(yaml.safe_dump(spec))
    first = run_curriculum(exp)
    run_curriculum(exp, root=tmp_path / "other", sets=["seed_everything=1"])  # refits the shared stage
    capsys.readouterr()

    def refuse(args):
        raise AssertionError(f"a finished stage was rerun: {args}")

    again = run_curriculum(exp, runner=refuse)
    assert [r["checkpoint"] for r in again] == [r["checkpoint"] for r in first]
    assert capsys.readouterr().out.count("already finished") == 2


def test_a_stage_another_curriculum_is_working_on_is_waited_for(tmp_path, monkeypatch):
    """Two curricula sharing a stage folder (the Layouts AxisNet) fitted it at once, each tagging the other's live run
    as its own: the second now waits for the stage's lock, and a DDP worker process (nonzero LOCAL_RANK) takes none."""
    import io
    import threading
    import time as clock

    from floaff_zoo.atomic import folder_lock
    from floaff_zoo.curriculum import STAGE_LOCK, CurriculumError, _stage_lock

    sdir = tmp_path / "axisnet"
    held, release = threading.Event(), threading.Event()

    def other_curriculum():
        with folder_lock(sdir / STAGE_LOCK):
            held.set()
            release.wait(10)

    thread = threading.Thread(target=other_curriculum)
    thread.start()
    held.wait(10)
    threading.Timer(0.5, release.set).start()
    out, t0 = io.StringIO(), clock.monotonic()
    with _stage_lock("axisnet", sdir, out):
        waited = clock.monotonic() - t0
    thread.join()
    assert waited >= 0.4 and "another curriculum is working on" in out.getvalue()
    with folder_lock(sdir / STAGE_LOCK):  # held by "rank 0": a worker process of the same run goes on
        monkeypatch.setenv("LOCAL_RANK", "1")
        with _stage_lock("axisnet", sdir, out):
            pass
    monkeypatch.setenv("LOCAL_RANK", "one")  # a traceback from int() before
    with pytest.raises(CurriculumError, match="LOCAL_RANK='one': not a whole-number rank"):
        with _stage_lock("axisnet", sdir, out):
            pass


def test_a_resumed_fit_that_is_killed_again_keeps_its_metrics_in_place(tmp_path):
    """The rows before the resume went back into metrics.csv only when the resumed fit returned: killed again, the
    run's metrics.csv held only the epochs after the resume (the rest sat in metrics.before_resume.csv)."""
    from floaff_zoo.curriculum import KEPT_METRICS

    exp = _experiment(tmp_path)
    with pytest.raises(KeyboardInterrupt):
        run_curriculum(exp, runner=_killed_after(2))
    seen: list = []
    with pytest.raises(KeyboardInterrupt):
        run_curriculum(exp, runner=_killed_after(3, seen))
    assert "--ckpt_path" in seen[0]  # it resumed, then was killed after one more epoch
    (metrics,) = (tmp_path / "run" / "s1").rglob("metrics.csv")
    assert {int(r["epoch"]) for r in csv.DictReader(metrics.open())} == {0, 1, 2}
    assert not (metrics.parent / KEPT_METRICS).exists()


def test_a_weights_file_rewritten_during_the_fit_is_not_recorded_as_its_input(tmp_path, capsys):
    """The done record hashed its input files after the fit: a weights file rewritten meanwhile was recorded as what
    the stage started from, so the next run skipped a stage trained from other weights."""
    from floaff_zoo.models.tiny import TinyPointNetModule

    init = tmp_path / "init.pt"
    torch.save(TinyPointNetModule().state_dict(), init)
    exp = _experiment(tmp_path, max_epochs=1)
    sets = [f"model.init_args.weights={init}"]

    def rewrites(args):
        cli = run_lightning(args)
        torch.manual_seed(1)
        torch.save(TinyPointNetModule().state_dict(), init)  # e.g. the earlier stage refit into the same path
        return cli

    run_curriculum(exp, sets=sets, runner=rewrites)
    capsys.readouterr()
    run_curriculum(exp, sets=sets)
    assert f"rerunning, a file its arguments name ({init}) changed" in capsys.readouterr().out


def test_a_run_marked_by_an_older_runner_stays_resumable_after_its_resumed_fit_writes(tmp_path):
    """A run mark without input files (written before they were recorded) that its own stage resumed and that wrote a
    newer checkpoint was marked shared: None inputs against {} looked like other arguments, and it was never resumed
    again. The digest decides for such a mark, as it does when resuming."""
    import time

    from floaff_zoo import curriculum as cur

    run = tmp_path / "cfarmodule" / "version_0"
    (run / "checkpoints").mkdir(parents=True)
    (run / cur.RUN_FILE).write_text(json.dumps({"stage": "s", "digest": "D", "args": ["fit"]}))
    started = time.time() - 5
    (run / "checkpoints" / "last.ckpt").write_bytes(b"newer than the fit's start")
    cur._mark_shared(run, {"stage": "s", "digest": "D", "args": ["fit"], "inputs": {}}, started)
    assert not json.loads((run / cur.RUN_FILE).read_text()).get("shared")
    cur._mark_shared(run, {"stage": "s", "digest": "other", "args": ["fit"], "inputs": {}}, started)
    assert json.loads((run / cur.RUN_FILE).read_text()).get("shared") is True  # another digest still marks it


def test_a_killed_fit_resumes_after_a_finished_fit_of_other_arguments_took_its_folder(tmp_path):
    """A finished fit found again by its digest replaced a killed fit's running record without marking the killed
    run as its own, and only a running record was looked at for a resume: the killed fit started afresh."""
    exp = _experiment(tmp_path, max_epochs=1)
    run_curriculum(exp)  # arguments A, finished
    longer = ["trainer.max_epochs=4"]
    with pytest.raises(KeyboardInterrupt):
        run_curriculum(exp, sets=longer, runner=_killed_after(2))  # arguments B, killed after 2 epochs

    def refuse(args):
        raise AssertionError(f"a finished stage was rerun: {args}")

    run_curriculum(exp, runner=refuse)  # A again: its record back in the folder
    seen: list = []
    (rec,) = run_curriculum(exp, sets=longer, runner=_spy(seen))
    assert "--ckpt_path" in seen[0] and rec["resumed_from"]


def test_a_stage_digest_takes_a_config_given_as_yaml_text():
    """The CLI reads a --config value that is no file as YAML text; the curriculum's digest called Path.is_file on it,
    which raised a bare OSError (ENAMETOOLONG) for a long text."""
    from floaff_zoo.curriculum import _digest

    long_text = "{trainer: {max_epochs: 1}}" + " " * 5000
    assert _digest(["fit", "--config", long_text]) == _digest(["fit", "--config", long_text])


def test_a_finished_stage_reruns_when_its_data_folder_changed(tmp_path, capsys):
    """The data a stage trained on was not among its inputs: after the data was generated again into the same folder,
    a rerun skipped the stage trained on the old data. The sample cache its fit writes into the folder, a generator
    run that made nothing (it rewrites manifest.json, as every demo run does) and the other benchmark's scenes change
    nothing, and a record written before data folders were kept is compared on its files, as it was."""
    from tests.data.floaff_fixture import make_floaff_dataset

    data = tmp_path / "floaff"
    make_floaff_dataset(data, problems=False)
    exp = tmp_path / "exp.yaml"
    overrides = {**OVERRIDES, "trainer.max_epochs": 1, "data.init_args.root": str(data)}
    overrides |= {"data.init_args.num_points": 256, "data.init_args.batch_size": 2}
    exp.write_text(
        yaml.safe_dump(
            {
                "root": str(tmp_path / "run"),
                "data": [str(ROOT / "configs/data/floaff_layouts.yaml")],
                "model": [str(ROOT / "configs/models/tiny_pointnet.yaml")],
                "overrides": overrides,
                "stages": [{"name": "s1"}],
            }
        )
    )
    (first,) = run_curriculum(exp)
    key = f"{data}/layouts/"  # the benchmark's folder the stage reads
    assert list(first["inputs"]) == [key] and (data / ".cache").is_dir()  # the fit cached samples there
    seen: list = []
    capsys.readouterr()
    run_curriculum(exp, runner=_spy(seen))
    assert not seen and "already finished" in capsys.readouterr().out
    stage_file = tmp_path / "run" / "s1" / "stage.json"
    record = json.loads(stage_file.read_text())
    stage_file.write_text(json.dumps({**record, "inputs": {}}))  # as written before data folders were kept
    run_curriculum(exp, runner=_spy(seen))
    assert not seen
    stage_file.write_text(json.dumps(record))
    (data / "manifest.json").write_text(json.dumps({"wall_s": 1.5}))  # a generate resume that made nothing
    (data / "styles" / "s_new").mkdir(parents=True)  # the other benchmark generated into the same root
    (data / "styles" / "s_new" / "scene.json").write_text("{}")
    run_curriculum(exp, runner=_spy(seen))
    assert not seen
    scene = next((data / "layouts").rglob("scene.json"))  # the data generated again: other scene records
    scene.write_text(scene.read_text() + "\n")
    capsys.readouterr()
    (new,) = run_curriculum(exp, runner=_spy(seen))
    assert len(seen) == 1 and f"rerunning, its data folder ({key}) changed" in capsys.readouterr().out
    assert new["inputs"][key] != first["inputs"][key]


def _fake_fit(args):
    """A fit that trains nothing: it writes a checkpoint where the stage's ModelCheckpoint would."""
    ckpt = Path(args[args.index("--trainer.default_root_dir") + 1], "checkpoints", "best.ckpt")
    ckpt.parent.mkdir(parents=True, exist_ok=True)
    ckpt.write_bytes(b"weights")
    callback = SimpleNamespace(best_model_path=str(ckpt), last_model_path="", best_model_score=None, monitor=None)
    return SimpleNamespace(trainer=SimpleNamespace(checkpoint_callback=callback, global_step=1, callback_metrics={}))


def test_a_data_folder_every_stage_reads_is_walked_once_per_run(tmp_path, monkeypatch):
    """Each stage walked and hashed the data folder again: three times for a three-stage curriculum on one folder.
    The records keep its fingerprint for every stage; a second run walks it again (the data may have been
    regenerated between runs)."""
    import floaff_zoo.curriculum
    from floaff_zoo.runs import data_fingerprint

    data = tmp_path / "data"
    (data / "scenes").mkdir(parents=True)
    (data / "scenes" / "scene.json").write_text("{}")
    exp = tmp_path / "exp.yaml"
    exp.write_text(
        yaml.safe_dump(
            {
                "root": str(tmp_path / "run"),
                "data": [str(ROOT / "configs/data/synthetic_tiny.yaml")],
                "model": [str(ROOT / "configs/models/tiny_pointnet.yaml")],
                "overrides": {"data.init_args.root": str(data)},
                "stages": [{"name": "s1"}, {"name": "s2"}, {"name": "s3"}],
            }
        )
    )
    walked: list[Path] = []
    monkeypatch.setattr(floaff_zoo.curriculum, "data_fingerprint", lambda p: walked.append(p) or data_fingerprint(p))
    records = run_curriculum(exp, runner=_fake_fit, out=io.StringIO())
    assert walked == [data]
    assert [r["inputs"] for r in records] == [{f"{data}/": data_fingerprint(data)}] * 3
    again = run_curriculum(exp, runner=_fake_fit, out=io.StringIO())  # every stage finished: skipped
    assert walked == [data, data] and again == records
