"""The checkpoint callback every ``floaff-zoo fit`` gets: the best by the model's monitor, and a ``last.ckpt`` that is
the newest training state.

Lightning 2.6's ``ModelCheckpoint(save_last=True)`` refreshes ``last.ckpt`` only in a step where it also saves a top-k
checkpoint, i.e. where the monitored metric improved; after that its ``last.ckpt`` is the best state, not the latest,
so a fit that ends without improving loses its final weights and a killed fit resumes from the best step.
:class:`LatestCheckpoint` also writes ``last.ckpt`` at every checkpointing point (validation or epoch end) and at the
end of training.
"""

from __future__ import annotations

import lightning as L
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.trainer.states import TrainerFn

__all__ = ["LatestCheckpoint"]


class LatestCheckpoint(ModelCheckpoint):
    """``ModelCheckpoint`` whose ``last.ckpt`` (``save_last=True``) is always the newest state (module docstring).

    Its state is stored under ``ModelCheckpoint``'s own key, so checkpoints written before read the same way.
    """

    _latest_step: int | None = None  # the global step whose state ``_refresh_last`` last wrote

    @property
    def state_key(self) -> str:
        return super().state_key.replace(type(self).__qualname__, "ModelCheckpoint", 1)

    def on_validation_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        super().on_validation_end(trainer, pl_module)
        if not self._should_save_on_train_epoch_end(trainer):  # else the top-k save comes at the epoch's end
            self._refresh_last(trainer)

    def on_train_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        super().on_train_epoch_end(trainer, pl_module)
        if self._should_save_on_train_epoch_end(trainer):
            self._refresh_last(trainer)

    def on_train_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        super().on_train_end(trainer, pl_module)
        self._refresh_last(trainer)

    def _refresh_last(self, trainer: L.Trainer) -> None:
        """Write ``last.ckpt`` unless checkpointing is off or this step already wrote it (a top-k save)."""
        if not self.save_last or trainer.fast_dev_run or trainer.sanity_checking:
            return
        if trainer.state.fn != TrainerFn.FITTING or self._last_global_step_saved == trainer.global_step:
            return
        if self._latest_step == trainer.global_step:
            return
        saved = self._last_global_step_saved
        self._save_last_checkpoint(trainer, self._monitor_candidates(trainer))
        # the step counter says "a top-k checkpoint was saved here": writing last.ckpt must not block a later one
        self._last_global_step_saved = saved
        self._latest_step = trainer.global_step
