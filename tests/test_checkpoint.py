"""LatestCheckpoint: last.ckpt is the newest training state, the best stays the best (and keeps its state key)."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import pytest
import torch
from lightning.pytorch.demos.boring_classes import BoringModel

from floaff_zoo.callbacks.checkpoint import LatestCheckpoint
from floaff_zoo.runs import RunError, resolve_ckpt_alias


class GetsWorse(BoringModel):
    """A validation metric that grows every step: only the first validation is the best."""

    def validation_step(self, batch, batch_idx):
        self.log("worse", float(self.global_step))
        return super().validation_step(batch, batch_idx)


def _fit(tmp_path: Path, callback, max_steps: int = 7, val_batches: int = 1) -> L.Trainer:
    trainer = L.Trainer(
        default_root_dir=tmp_path,
        max_steps=max_steps,
        val_check_interval=2,
        check_val_every_n_epoch=None,
        limit_val_batches=val_batches,
        callbacks=[callback],
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
    )
    trainer.fit(GetsWorse())
    return trainer


def _step(path: str | Path) -> int:
    return torch.load(path, map_location="cpu", weights_only=True)["global_step"]


def test_last_is_the_final_state_and_best_the_first(tmp_path):
    cb = LatestCheckpoint(dirpath=tmp_path / "ck", monitor="worse", mode="min", save_last=True)
    _fit(tmp_path, cb)
    assert _step(tmp_path / "ck" / "last.ckpt") == 7  # the end of training, after the last validation (step 6)
    assert _step(cb.best_model_path) == 2
    # the aliases of `floaff-zoo test --ckpt_path` read the same: the state key is ModelCheckpoint's
    state = torch.load(tmp_path / "ck" / "last.ckpt", map_location="cpu", weights_only=True)
    assert any(k.startswith("ModelCheckpoint{") for k in state["callbacks"])
    assert _step(resolve_ckpt_alias("best", tmp_path / "ck")) == 2
    assert _step(resolve_ckpt_alias("last", tmp_path / "ck")) == 7


def test_best_is_never_the_last_epochs_weights_in_disguise(tmp_path):
    """A run whose best checkpoint was deleted handed out last.ckpt as "best" (test, predict and hub push)."""
    cb = LatestCheckpoint(dirpath=tmp_path / "ck", monitor="worse", mode="min", save_last=True)
    _fit(tmp_path, cb)
    Path(cb.best_model_path).unlink()
    with pytest.raises(RunError, match=r"records the best checkpoint .*epoch.*which is gone.*pass a checkpoint file"):
        resolve_ckpt_alias("best", tmp_path / "ck")
    assert _step(resolve_ckpt_alias("last", tmp_path / "ck")) == 7


def test_a_moved_run_reads_its_own_best_file(tmp_path):
    """The recorded absolute path came first: after a run moved, a file there (another run's) was handed out."""
    cb = LatestCheckpoint(dirpath=tmp_path / "ck", monitor="worse", mode="min", save_last=True)
    _fit(tmp_path, cb)
    moved = tmp_path / "moved"
    (tmp_path / "ck").rename(moved)
    Path(cb.best_model_path).parent.mkdir()
    torch.save({"global_step": 99}, cb.best_model_path)  # another run's file at the old path
    assert _step(resolve_ckpt_alias("best", moved)) == 2


def test_plain_model_checkpoint_keeps_the_best_as_last(tmp_path):
    """Why the subclass exists: Lightning's own last.ckpt stops at the last improvement (the test above: 7)."""
    _fit(
        tmp_path,
        L.pytorch.callbacks.ModelCheckpoint(dirpath=tmp_path / "ck", monitor="worse", mode="min", save_last=True),
    )
    assert _step(tmp_path / "ck" / "last.ckpt") == 2


def test_a_second_fit_into_the_same_directory_keeps_the_first_last(tmp_path):
    """As Lightning does: another fit's last.ckpt stays, the new fit's newest state goes to last-v1.ckpt (here a fit
    without validation that stops inside its first epoch: only the end of training writes it)."""
    _fit(tmp_path, LatestCheckpoint(dirpath=tmp_path / "ck", monitor="worse", mode="min", save_last=True))
    first = (tmp_path / "ck" / "last.ckpt").read_bytes()
    cb = LatestCheckpoint(dirpath=tmp_path / "ck", save_last=True)
    _fit(tmp_path, cb, max_steps=3, val_batches=0)
    assert (tmp_path / "ck" / "last.ckpt").read_bytes() == first
    assert Path(cb.last_model_path).name == "last-v1.ckpt" and _step(cb.last_model_path) == 3


def test_link_mode_never_writes_through_the_link(tmp_path):
    """save_last="link" makes last.ckpt a link to a top-k file: refreshing it must replace the link, not write the
    newest state into the best file."""
    cb = LatestCheckpoint(dirpath=tmp_path / "ck", monitor="worse", mode="min", save_last="link")
    _fit(tmp_path, cb)
    assert _step(cb.best_model_path) == 2 and _step(tmp_path / "ck" / "last.ckpt") == 7


@pytest.mark.parametrize("dirpath", ["taken", "taken/ck"])
def test_a_file_as_the_checkpoint_folder_is_refused_before_training(tmp_path, dirpath):
    """A dirpath that is a file or under one failed in mkdir (FileExistsError, NotADirectoryError) at the first
    save, after the first validation or epoch of training."""
    from lightning.pytorch.utilities.exceptions import MisconfigurationException

    class Counted(GetsWorse):
        steps = 0

        def training_step(self, batch, batch_idx):
            Counted.steps += 1
            return super().training_step(batch, batch_idx)

    (tmp_path / "taken").write_text("notes")
    cb = LatestCheckpoint(dirpath=tmp_path / dirpath, monitor="worse", mode="min", save_last=True)
    trainer = L.Trainer(default_root_dir=tmp_path, max_steps=3, callbacks=[cb], logger=False, enable_progress_bar=False)
    with pytest.raises(MisconfigurationException, match=f"dirpath {tmp_path / dirpath}: {tmp_path / 'taken'} is not"):
        trainer.fit(Counted())
    assert Counted.steps == 0 and (tmp_path / "taken").read_text() == "notes"
