"""The test report names what was tested: the checkpoint as loaded, the weights by their hash, and this run's SR."""

from __future__ import annotations

import json
from pathlib import Path

import lightning as L
import pytest

from floaff_zoo.callbacks.report import TestReport
from floaff_zoo.callbacks.rollout import RolloutSuccessRate
from floaff_zoo.hub.registry import sha256_file
from tests.report._fake_world import ConstantModule, FakeService, LabelModule, loader, make_samples, quiet_trainer


class _Overwrite(L.Callback):
    """Replaces the checkpoint file while the test runs (a fit still running rewrites last.ckpt)."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def on_test_epoch_end(self, trainer, pl_module) -> None:
        self.path.write_bytes(b"another fit's checkpoint")


def test_the_checkpoint_is_named_as_it_was_loaded(tmp_path):
    """The report hashed the checkpoint when the test ended: a file rewritten meanwhile was recorded by bytes that
    were never tested (or as null when it had gone)."""
    samples = make_samples(4)
    first = quiet_trainer([])
    first.test(ConstantModule(), dataloaders=loader(samples), verbose=False)
    ckpt = tmp_path / "m.ckpt"
    first.save_checkpoint(ckpt)
    loaded = sha256_file(ckpt)
    report = TestReport(out_dir=str(tmp_path / "r"), figures=False)
    quiet_trainer([report, _Overwrite(ckpt)]).test(
        ConstantModule(), dataloaders=loader(samples), ckpt_path=str(ckpt), verbose=False
    )
    rep = json.loads((tmp_path / "r" / "report.json").read_text())
    assert rep["checkpoint"] == {"path": str(ckpt.resolve()), "sha256": loaded}
    assert sha256_file(ckpt) != loaded


def test_a_run_without_rollouts_reports_no_earlier_sr(tmp_path):
    """A second test whose rollouts were off reported the first test's SR (the callback kept its summary) and left
    the first run's sr_episodes.json beside the new report."""
    samples = make_samples(4)
    rollout = RolloutSuccessRate(service=FakeService, progress=False)
    report = TestReport(out_dir=str(tmp_path), figures=False)
    trainer = quiet_trainer([rollout, report])
    trainer.test(LabelModule(), dataloaders=loader(samples), verbose=False)
    assert json.loads((tmp_path / "report.json").read_text())["sr"]["available"] is True
    assert (tmp_path / "sr_episodes.json").is_file()
    rollout.on_test = False
    trainer.test(ConstantModule(), dataloaders=loader(samples), verbose=False)
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["sr"]["available"] is False and not (tmp_path / "sr_episodes.json").exists()


def test_weights_given_by_hub_name_or_folder_are_named_by_their_hash():
    """Weights given by hub name or exported folder were recorded with sha256 null (only a file was hashed), so a
    table took two tests of one set of weights for two seeds."""
    from types import SimpleNamespace

    from floaff_zoo.callbacks.report import checkpoint_record

    module = SimpleNamespace(hparams={"weights": "cfar-pfal.floaff-dense-layouts.v11"}, weights_sha256="ab" * 32)
    record = checkpoint_record(SimpleNamespace(ckpt_path=None), module)
    assert record == {"path": "cfar-pfal.floaff-dense-layouts.v11", "sha256": "ab" * 32}
    assert checkpoint_record(SimpleNamespace(ckpt_path=None), SimpleNamespace(hparams={})) is None


def test_a_new_report_in_the_folder_removes_the_earlier_figures_and_says_so(tmp_path, capsys):
    """A second test into the same folder overwrote report.json without a word and left the first test's figures of
    groups it did not draw in figures/, beside a report that does not list them."""
    samples = make_samples(4)
    for s in samples:
        s["meta"].pop("sim")  # plain scatters: no kitchen to rebuild
    report = TestReport(out_dir=str(tmp_path), figures_per_group=1)
    trainer = quiet_trainer([report])
    trainer.test(ConstantModule(), dataloaders=loader(samples), verbose=False)
    assert len(list((tmp_path / "figures").glob("*.png"))) == 4  # (task, view): 2 x 2
    assert "replaced the earlier report" not in capsys.readouterr().out
    trainer.test(ConstantModule(), dataloaders=loader(samples[:2]), verbose=False)  # the front views only
    rep = json.loads((tmp_path / "report.json").read_text())
    assert sorted(f"figures/{f.name}" for f in (tmp_path / "figures").glob("*.png")) == sorted(rep["figures"])
    assert len(rep["figures"]) == 2
    assert f"replaced the earlier report in {tmp_path} (4 figure(s) removed)" in capsys.readouterr().out


def test_a_reader_of_the_earlier_report_never_meets_half_of_the_new_one(tmp_path):
    """report.json was rewritten in place: a table reading it while a second test wrote got the start of one report
    and the end of the other (unreadable, skipped), or an empty file where the writer was killed."""
    samples = make_samples(4)
    trainer = quiet_trainer([TestReport(out_dir=str(tmp_path), figures=False)])
    trainer.test(ConstantModule(), dataloaders=loader(samples), verbose=False)
    first = (tmp_path / "report.json").read_bytes()
    with open(tmp_path / "report.json", "rb", buffering=0) as reader:  # unbuffered: the rest is read from the file
        head = reader.read(len(first) // 2)
        trainer.test(LabelModule(), dataloaders=loader(samples), verbose=False)
        assert head + reader.read() == first
    assert json.loads((tmp_path / "report.json").read_text())["metrics"]["test_pcc"] == 1.0


def test_a_report_that_cannot_be_written_leaves_the_earlier_one(tmp_path, monkeypatch):
    """report.json was written before report.md was rendered: a failure there left the new report.json beside the
    earlier report.md (and the new sr_episodes.json beside the earlier report.json, had the first write failed)."""
    import floaff_zoo.callbacks.report as report_module

    samples = make_samples(4)
    rollout = RolloutSuccessRate(service=FakeService, progress=False)
    trainer = quiet_trainer([rollout, TestReport(out_dir=str(tmp_path), figures=True)])
    trainer.test(ConstantModule(), dataloaders=loader(samples), verbose=False)
    figures = json.loads((tmp_path / "report.json").read_text())["figures"]  # redrawn before the render: the
    assert figures  # earlier report listed PNGs of the failed run
    names = ("report.json", "report.md", "sr_episodes.json", *figures)
    before = {name: (tmp_path / name).read_bytes() for name in names}

    def fails(report):
        raise RuntimeError("cannot render")

    monkeypatch.setattr(report_module, "render_markdown", fails)
    with pytest.raises(RuntimeError, match="cannot render"):
        trainer.test(LabelModule(), dataloaders=loader(samples), verbose=False)
    assert {name: (tmp_path / name).read_bytes() for name in before} == before


def test_two_tests_into_one_folder_write_one_after_the_other(tmp_path, capsys):
    """Two tests writing into one folder at once interleaved their figures and reports (one report listing the
    other's figures): a test writes while it holds the folder's lock, and says why it waits for it."""
    import threading

    from floaff_zoo.atomic import folder_lock

    samples = make_samples(4)
    for s in samples:
        s["meta"].pop("sim")
    ended = threading.Event()

    class Ended(L.Callback):
        def on_test_end(self, trainer, pl_module) -> None:
            ended.set()

    trainer = quiet_trainer([Ended(), TestReport(out_dir=str(tmp_path), figures=False)])
    errors: list[BaseException] = []

    def test() -> None:
        try:
            trainer.test(ConstantModule(), dataloaders=loader(samples), verbose=False)
        except BaseException as exc:  # noqa: BLE001 - re-raised below, in the test's thread
            errors.append(exc)
            ended.set()

    with folder_lock(tmp_path / ".report.lock"):  # another test is writing its report here
        thread = threading.Thread(target=test)
        thread.start()
        assert ended.wait(120)
        thread.join(1.0)
        assert thread.is_alive() and not (tmp_path / "report.json").exists()
    thread.join(120)
    assert not errors and not thread.is_alive() and (tmp_path / "report.json").is_file()
    assert f"another test is writing its report into {tmp_path}; waiting" in capsys.readouterr().out


class _CountBatches(L.Callback):
    def __init__(self) -> None:
        self.batches = 0

    def on_test_batch_end(self, *args, **kwargs) -> None:
        self.batches += 1


def test_a_report_folder_that_cannot_take_the_report_is_refused_before_the_test(tmp_path):
    """A file in place of the report folder, of its ``figures`` folder, or a folder in place of ``report.json`` failed
    at the test's end, after every batch and rollout: the results were lost."""
    from lightning.pytorch.utilities.exceptions import MisconfigurationException

    (tmp_path / "file").write_text("x")
    (tmp_path / "figs").mkdir()
    (tmp_path / "figs" / "figures").write_text("x")
    (tmp_path / "json" / "report.json").mkdir(parents=True)
    for out, figures, said in (
        (tmp_path / "file" / "run", False, f"cannot write the report into {tmp_path / 'file' / 'run'}: "),
        (tmp_path / "figs", True, f"{tmp_path / 'figs' / 'figures'} is not a folder; the figures go into one"),
        (tmp_path / "json", False, f"{tmp_path / 'json' / 'report.json'} is a folder; the report writes a file"),
    ):
        counted = _CountBatches()
        trainer = quiet_trainer([counted, TestReport(out_dir=str(out), figures=figures)])
        with pytest.raises(MisconfigurationException, match=f"TestReport: {said}"):
            trainer.test(ConstantModule(), dataloaders=loader(make_samples(2)), verbose=False)
        assert counted.batches == 0
    # without figures a file named figures is no obstacle
    quiet_trainer([TestReport(out_dir=str(tmp_path / "figs"), figures=False)]).test(
        ConstantModule(), dataloaders=loader(make_samples(2)), verbose=False
    )
    assert (tmp_path / "figs" / "report.json").is_file()
    # a folder named sr_episodes.json stands in the way only of a test that rolls out and writes its episodes
    (tmp_path / "eps" / "sr_episodes.json").mkdir(parents=True)
    quiet_trainer([TestReport(out_dir=str(tmp_path / "eps"), figures=False)]).test(
        ConstantModule(), dataloaders=loader(make_samples(2)), verbose=False
    )
    assert (tmp_path / "eps" / "report.json").is_file()
    rollout = RolloutSuccessRate(service=FakeService, progress=False)
    with pytest.raises(MisconfigurationException, match="sr_episodes.json is a folder; the report writes a file"):
        quiet_trainer([rollout, TestReport(out_dir=str(tmp_path / "eps"), figures=False)]).test(
            ConstantModule(), dataloaders=loader(make_samples(2)), verbose=False
        )
