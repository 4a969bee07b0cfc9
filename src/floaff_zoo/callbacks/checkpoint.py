"""The checkpoint callback every ``floaff-zoo fit`` gets: the best by the model's monitor, and a ``last.ckpt`` that is
the newest training state.

Lightning 2.6's ``ModelCheckpoint(save_last=True)`` refreshes ``last.ckpt`` only in a step where it also saves a top-k
checkpoint, i.e. where the monitored metric improved; after that its ``last.ckpt`` is the best state, not the latest,
so a fit that ends without improving loses its final weights and a killed fit resumes from the best step.
:class:`LatestCheckpoint` also writes ``last.ckpt`` at every checkpointing point (validation or epoch end) and at the
end of training. It uses Lightning's public API only (``trainer.save_checkpoint``, ``format_checkpoint_name``,
``last_model_path``), so a Lightning upgrade that changes ``ModelCheckpoint``'s internals does not break it; where
Lightning itself saved ``last.ckpt`` in the same step (an improvement) the file is written a second time with the
same state.
"""

from __future__ import annotations

import lightning as L
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.trainer.states import TrainerFn
from lightning.pytorch.utilities.exceptions import MisconfigurationException

from floaff_zoo.atomic import existing_ancestor

__all__ = ["LatestCheckpoint"]


class LatestCheckpoint(ModelCheckpoint):
    """``ModelCheckpoint`` whose ``last.ckpt`` (``save_last=True``) is always the newest state (module docstring).

    Its state is stored under ``ModelCheckpoint``'s own key, so checkpoints written before read the same way.
    """

    _latest_step: int | None = None  # the global step whose state ``_refresh_last`` last wrote

    @property
    def state_key(self) -> str:
        return super().state_key.replace(type(self).__qualname__, "ModelCheckpoint", 1)

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        """Refuse a local ``dirpath`` that is a file or lies under one before fitting: the first save failed in its
        ``mkdir`` after the first epoch or validation."""
        super().setup(trainer, pl_module, stage)
        if stage != "fit" or not self.dirpath or "://" in str(self.dirpath):  # a remote store has no folders
            return
        found = existing_ancestor(self.dirpath)  # ModelCheckpoint resolved its links
        if not found.is_dir():
            raise MisconfigurationException(f"LatestCheckpoint: dirpath {self.dirpath}: {found} is not a folder")

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        super().on_validation_end(trainer, pl_module)
        self._refresh_last(trainer)

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        super().on_train_epoch_end(trainer, pl_module)
        self._refresh_last(trainer)  # a validation at this epoch's end already wrote this step: skipped

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        super().on_train_end(trainer, pl_module)
        self._refresh_last(trainer)

    def _refresh_last(self, trainer: L.Trainer) -> None:
        """Write ``last.ckpt`` with the current state, once per global step, while fitting with ``save_last``."""
        if not self.save_last or trainer.fast_dev_run or trainer.sanity_checking or self.dirpath is None:
            return
        if trainer.state.fn != TrainerFn.FITTING or self._latest_step == trainer.global_step:
            return
        path = self.last_model_path or self._new_last_path(trainer)
        self.last_model_path = path  # before saving: the state this checkpoint records names it
        trainer.save_checkpoint(path, self.save_weights_only)
        self._latest_step = trainer.global_step

    def _new_last_path(self, trainer: L.Trainer) -> str:
        """``<dirpath>/last.ckpt``, or ``last-v1.ckpt``, ... where another fit's file is there (kept, as Lightning
        keeps it)."""
        metrics = dict(trainer.callback_metrics)
        path = self.format_checkpoint_name(metrics, self.CHECKPOINT_NAME_LAST)
        ver = self.STARTING_VERSION
        while self.file_exists(path, trainer):
            path = self.format_checkpoint_name(metrics, self.CHECKPOINT_NAME_LAST, ver=ver)
            ver += 1
        return path
