"""FloAffModule: the base LightningModule every model of the zoo derives from (torchgeo style).

Subclasses declare their typed, defaulted init args (the LightningCLI schema), pass the shared
ones to ``super().__init__`` and implement ``configure_models`` (build ``self.net``) and
``forward(batch) -> [B, M]`` scores in [0, 1]. Losses, metrics, optimiser, scheduler, pretrained
weights and input checks live here once.
"""

from __future__ import annotations

from typing import Any, ClassVar, Literal

import lightning as L
import torch
from lightning.pytorch.utilities.exceptions import MisconfigurationException
from torch import Tensor
from torchmetrics import MetricCollection

from floaff_zoo.contract import Batch, SampleError, check_batch
from floaff_zoo.losses import build_loss
from floaff_zoo.metrics import affordance_metrics


class FloAffModule(L.LightningModule):
    """Base task: floor-affordance regression on the sample contract (see ``floaff_zoo.contract``).

    Args:
        feat_channels: how many ``scene_feat`` channels the net consumes (channel 0 = target flag).
        robot_dim: size of the robot descriptor.
        loss: ``mse``; ``aff`` = MSE + ``sdl_beta`` x Soft Dice (paper); ``navaff`` = NavAff's
            randomised 0.7-weighted MSE.
        sdl_beta: weight of the Soft Dice term for ``loss="aff"``.
        optimizer: ``adam`` or ``adamw``.
        lr: learning rate.
        weight_decay: weight decay.
        scheduler: ``cosine`` (T_max = max_epochs, eta_min 1e-6), ``plateau`` on ``val_rmse``, or ``none``.
        sim_variant: SIM metric variant, ``cosine`` (FloAff paper) or ``hist`` (MoMa-Kitchen code).
        metric_reduction: ``per_sample`` or ``official_batchwise`` (64-sample chunks, MoMa-Kitchen).
        weights: pretrained initialisation: a ``.ckpt``/``.safetensors`` path, an exported
            directory or a hub name. Not for resuming (use ``--ckpt_path``).
    """

    monitor: ClassVar[str] = "val_rmse"
    mode: ClassVar[str] = "min"
    #: models without learnable parameters (C2F-Exp) set this False; ``fit`` then refuses.
    trainable: ClassVar[bool] = True

    def __init__(
        self,
        feat_channels: int = 1,
        robot_dim: int = 2,
        loss: Literal["mse", "aff", "navaff"] = "mse",
        sdl_beta: float = 1.0,
        optimizer: Literal["adam", "adamw"] = "adam",
        lr: float = 1e-3,
        weight_decay: float = 0.0,
        scheduler: Literal["cosine", "plateau", "none"] = "cosine",
        sim_variant: Literal["cosine", "hist"] = "cosine",
        metric_reduction: Literal["per_sample", "official_batchwise"] = "per_sample",
        weights: str | None = None,
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        # The values the base actually received: subclasses may not expose every base argument,
        # so these are read from here (hparams hold only the subclass's own signature, which keeps
        # checkpoints loadable by that signature).
        self.base_cfg: dict = {
            "feat_channels": feat_channels, "robot_dim": robot_dim, "loss": loss, "sdl_beta": sdl_beta,
            "optimizer": optimizer, "lr": lr, "weight_decay": weight_decay, "scheduler": scheduler,
            "sim_variant": sim_variant, "metric_reduction": metric_reduction, "weights": weights,
        }
        self.configure_models()
        self.configure_losses()
        self.configure_metrics()
        if weights:
            self.load_pretrained(weights)

    # ----------------------------------------------------------------- hooks for subclasses
    def configure_models(self) -> None:
        """Build ``self.net``. Subclasses must override."""
        raise MisconfigurationException(f"{type(self).__name__} must implement configure_models()")

    def configure_losses(self) -> None:
        """Set ``self.criterion(pred [B,M], target [B,M], mask [B,M]) -> scalar``."""
        self.criterion = build_loss(self.base_cfg["loss"], beta=self.base_cfg["sdl_beta"])

    def configure_metrics(self) -> None:
        """One MetricCollection per stage (train keeps the cheap ones)."""
        full = affordance_metrics(
            sim_variant=self.base_cfg["sim_variant"],
            reduction=self.base_cfg["metric_reduction"],
        )
        self.val_metrics = full.clone(prefix="val_")
        self.test_metrics = full.clone(prefix="test_")
        self.train_metrics = MetricCollection({k: full[k].clone() for k in ("rmse", "mae")}, prefix="train_")

    def forward(self, batch: Batch) -> Tensor:  # pragma: no cover - abstract
        """Scores in [0, 1] for every floor point: [B, M]."""
        raise MisconfigurationException(f"{type(self).__name__} must implement forward(batch)")

    # ----------------------------------------------------------------- shared machinery
    def affordance_loss(self, scores: Tensor, batch: Batch) -> Tensor:
        """Masked affordance loss of ``scores`` [B, M] against ``batch['floor_label']``."""
        return self.criterion(scores, batch["floor_label"], batch["floor_mask"])

    def model_step(self, batch: Batch) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """Forward + loss. Returns (loss, scores [B, M], extra scalars to log)."""
        scores = self(batch)
        return self.affordance_loss(scores, batch), scores, {}

    def check_inputs(self, batch: Batch) -> None:
        """Fail early and clearly when the data does not fit the model's configuration."""
        check_batch(batch)
        c = batch["scene_feat"].shape[-1]
        if c < self.base_cfg["feat_channels"]:
            raise SampleError(
                f"{type(self).__name__}: model.feat_channels={self.base_cfg['feat_channels']} but the data "
                f"gives scene_feat with {c} channel(s); lower model.init_args.feat_channels or add features"
            )
        r = batch["robot"].shape[-1]
        if r != self.base_cfg["robot_dim"]:
            raise SampleError(
                f"{type(self).__name__}: model.robot_dim={self.base_cfg['robot_dim']} but the data gives "
                f"robot descriptors of size {r}; set model.init_args.robot_dim: {r}"
            )

    def _shared_step(self, batch: Batch, stage: str) -> tuple[Tensor, Tensor]:
        self.check_inputs(batch)
        loss, scores, extra = self.model_step(batch)
        if not torch.isfinite(loss):
            names = [m.get("sample_id", "?") for m in batch["meta"]]
            raise FloatingPointError(f"{stage} loss is {loss.item()} on samples {names[:4]}")
        bsz = batch["scene_xyz"].shape[0]
        self.log(f"{stage}_loss", loss, batch_size=bsz, prog_bar=stage != "test", on_epoch=True, on_step=stage == "train")
        for name, value in extra.items():
            self.log(f"{stage}_{name}", value, batch_size=bsz, on_epoch=True, on_step=False)
        metrics = getattr(self, f"{stage}_metrics")
        index = torch.as_tensor(
            [int(m.get("index", -1)) for m in batch["meta"]], device=scores.device, dtype=torch.long
        )
        metrics.update(scores.detach().float(), batch["floor_label"], batch["floor_mask"], index if (index >= 0).all() else None)
        self.log_dict(metrics, batch_size=bsz, on_epoch=True, on_step=False)
        return loss, scores

    def training_step(self, batch: Batch, batch_idx: int) -> Tensor:
        return self._shared_step(batch, "train")[0]

    def validation_step(self, batch: Batch, batch_idx: int) -> Tensor:
        return self._shared_step(batch, "val")[0]

    def test_step(self, batch: Batch, batch_idx: int) -> Tensor:
        loss, scores = self._shared_step(batch, "test")
        self.last_test_scores = scores.detach()
        return loss

    def predict_step(self, batch: Batch, batch_idx: int, dataloader_idx: int = 0) -> dict[str, Any]:
        self.check_inputs(batch)
        scores = self(batch)
        return {
            "scores": scores.detach().cpu(),
            "floor_xyz": batch["floor_xyz"].cpu(),
            "floor_mask": batch["floor_mask"].cpu(),
            "target_xyz": batch["target_xyz"].cpu(),
            "meta": batch["meta"],
        }

    def on_fit_start(self) -> None:
        if not self.trainable:
            raise MisconfigurationException(
                f"{type(self).__name__} is training-free: it has no weights to fit. "
                "Run `floaff-zoo test` or `predict` with it directly (no --ckpt_path needed)."
            )

    def configure_optimizers(self) -> Any:
        params = [p for p in self.parameters() if p.requires_grad]
        if not params:
            raise MisconfigurationException(f"{type(self).__name__} has no trainable parameters")
        h = self.base_cfg
        cls = torch.optim.AdamW if h["optimizer"] == "adamw" else torch.optim.Adam
        opt = cls(params, lr=h["lr"], weight_decay=h["weight_decay"])
        match h["scheduler"]:
            case "none":
                return opt
            case "cosine":
                t_max = max(1, int(self.trainer.max_epochs or 1)) if self._trainer is not None else 1
                sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=t_max, eta_min=1e-6)
                return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "epoch"}}
            case "plateau":
                sched = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, mode=self.mode, patience=3)
                return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "monitor": self.monitor}}
        raise MisconfigurationException(f"unknown scheduler {h['scheduler']!r}")

    # ----------------------------------------------------------------- pretrained weights
    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        # The state dict already holds the pretrained weights: record where they came from, but
        # save ``weights: null`` so reloading the checkpoint never needs that source again.
        hp = checkpoint.get("hyper_parameters")
        if hp and hp.get("weights"):
            checkpoint.setdefault("floaff_lineage", {})["weights"] = hp["weights"]
            checkpoint["hyper_parameters"] = {**hp, "weights": None}

    def load_pretrained(self, name_or_path: str) -> None:
        """Initialise from a checkpoint/hub name; layers whose shapes differ are dropped with a warning."""
        from floaff_zoo.hub import resolve_state_dict

        state, _info = resolve_state_dict(name_or_path)
        load_matching_state(self, state, source=name_or_path)

    @classmethod
    def from_pretrained(cls, name_or_path: str, map_location: str = "cpu") -> "FloAffModule":
        """Build the model a checkpoint/hub entry describes and load its weights (no code is executed)."""
        from floaff_zoo.hub import load_model

        model = load_model(name_or_path, map_location=map_location, expected=cls)
        if not isinstance(model, cls):
            raise TypeError(f"{name_or_path!r} holds a {type(model).__name__}, not a {cls.__name__}")
        return model


def load_matching_state(module: torch.nn.Module, state: dict[str, Tensor], source: str) -> list[str]:
    """Load ``state`` into ``module``, skipping (and reporting) keys with mismatched shapes.

    Returns:
        the list of skipped keys.
    Raises:
        ValueError: when nothing at all matches (almost surely the wrong checkpoint).
    """
    import warnings

    own = module.state_dict()
    keep, skipped = {}, []
    for k, v in state.items():
        if k in own and own[k].shape == v.shape:
            keep[k] = v
        elif k in own:
            skipped.append(f"{k}: {tuple(v.shape)} vs {tuple(own[k].shape)}")
    if not keep:
        raise ValueError(f"no parameter of {source} matches {type(module).__name__}; wrong checkpoint?")
    if skipped:
        warnings.warn(f"{source}: skipped {len(skipped)} layer(s) with other shapes: {skipped[:5]}", stacklevel=2)
    module.load_state_dict(keep, strict=False)
    return skipped
