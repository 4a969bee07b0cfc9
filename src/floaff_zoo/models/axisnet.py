"""AxisNetModule: trains/evaluates AxisNet, the target-yaw estimator CFAR uses at inference.

It is a :class:`FloAffModule` only so it shares the CLI, optimiser, checkpoints and hub; it does not
predict floor scores. Training, validation, test and predict steps work on the target yaw:

* loss: MSE between the predicted unit vector ``(sin, cos)`` and the ground-truth one (paper);
* augmentation (training only): a uniform yaw in ``[-rot_aug_deg, +rot_aug_deg]`` about the vertical
  axis through the target, label turned by the same angle, plus Gaussian jitter ``jitter_sigma`` (m);
* metric: mean absolute wrapped angle error in degrees, logged as ``{stage}_angle_error_deg``; the
  checkpoint monitor is ``val_angle_error_deg`` (mode min). The paper keeps the lowest validation loss;
  for unit vectors ``|q - q*|^2 = 2 - 2 cos(err)``, so both select almost always the same epoch.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar, Literal

import torch
from torch import Tensor
from torchmetrics import Metric, MetricCollection

from floaff_zoo.contract import Batch, SampleError, check_batch
from floaff_zoo.models.base import FloAffModule
from floaff_zoo.nn.axisnet import AxisNet, angle_error_deg, axis_inputs, rotate_about_target, yaw_from_vector, yaw_to_vector


class AngleErrorDeg(Metric):
    """Mean absolute wrapped angle error in degrees. ``update(pred_yaw [B], target_yaw [B])`` (radians)."""

    is_differentiable = False
    higher_is_better = False
    full_state_update = False

    def __init__(self) -> None:
        super().__init__()
        self.add_state("total", default=torch.tensor(0.0, dtype=torch.float64), dist_reduce_fx="sum")
        self.add_state("count", default=torch.tensor(0, dtype=torch.long), dist_reduce_fx="sum")

    def update(self, pred_yaw: Tensor, target_yaw: Tensor) -> None:
        if pred_yaw.shape != target_yaw.shape:
            raise ValueError(f"AngleErrorDeg: shapes differ, {tuple(pred_yaw.shape)} vs {tuple(target_yaw.shape)}")
        if not (torch.isfinite(pred_yaw).all() and torch.isfinite(target_yaw).all()):
            raise ValueError("AngleErrorDeg: NaN/Inf yaw")
        err = angle_error_deg(pred_yaw.double(), target_yaw.double())
        self.total += err.sum()
        self.count += err.numel()

    def compute(self) -> Tensor:
        if int(self.count) == 0:
            return torch.tensor(float("nan"))
        return (self.total / self.count).float()


class AxisNetModule(FloAffModule):
    """AxisNet (paper appendix): PointNet on ``[p - t (scaled by 1/r); target flag]`` -> unit (sin, cos).

    Args:
        crop_radius: points farther than this from the target centre are dropped (m); coordinates
            are divided by it. Use the CFAR radius of the benchmark (1.3 Styles, 1.2 Layouts).
        widths: shared per-point MLP widths; head: global MLP widths.
        rot_aug_deg: training yaw augmentation half-range (paper: 90).
        jitter_sigma: training Gaussian coordinate jitter (m; paper: 0.005).
        feat_channels: scene_feat channels required (channel 0, the target flag, is used).
        optimizer / lr / weight_decay / scheduler / weights: see :class:`FloAffModule`
            (paper: Adam 1e-4, batch 32, 200 epochs, best validation checkpoint).
        robot_dim, loss, sdl_beta, sim_variant, metric_reduction: unused (kept for the shared schema).
    """

    monitor: ClassVar[str] = "val_angle_error_deg"
    mode: ClassVar[str] = "min"

    def __init__(
        self,
        crop_radius: float = 1.3,
        widths: list[int] | None = None,
        head: list[int] | None = None,
        rot_aug_deg: float = 90.0,
        jitter_sigma: float = 0.005,
        feat_channels: int = 1,
        robot_dim: int = 2,
        loss: Literal["mse", "aff", "navaff"] = "mse",
        sdl_beta: float = 1.0,
        optimizer: Literal["adam", "adamw"] = "adam",
        lr: float = 1e-4,
        weight_decay: float = 0.0,
        scheduler: Literal["cosine", "plateau", "none"] = "none",
        sim_variant: Literal["cosine", "hist"] = "cosine",
        metric_reduction: Literal["per_sample", "official_batchwise"] = "per_sample",
        weights: str | None = None,
    ) -> None:
        super().__init__(
            feat_channels=feat_channels, robot_dim=robot_dim, loss=loss, sdl_beta=sdl_beta, optimizer=optimizer,
            lr=lr, weight_decay=weight_decay, scheduler=scheduler, sim_variant=sim_variant,
            metric_reduction=metric_reduction, weights=weights,
        )

    # ----------------------------------------------------------------- hooks
    def configure_models(self) -> None:
        h = self.hparams
        if h["crop_radius"] <= 0:
            raise ValueError(f"AxisNetModule: crop_radius must be > 0, got {h['crop_radius']}")
        self.net = AxisNet(4, h["widths"] or [64, 128, 256], h["head"] if h["head"] is not None else [128, 64])

    def configure_losses(self) -> None:
        self.criterion = torch.nn.MSELoss()

    def configure_metrics(self) -> None:
        for stage in ("train", "val", "test"):
            setattr(self, f"{stage}_metrics", MetricCollection({"angle_error_deg": AngleErrorDeg()}, prefix=f"{stage}_"))

    def check_inputs(self, batch: Batch) -> None:
        check_batch(batch)
        if batch["scene_feat"].shape[-1] < 1:
            raise SampleError("AxisNetModule: scene_feat needs channel 0 (target flag)")

    # ----------------------------------------------------------------- inference API
    def estimate_yaw(self, scene_xyz: Tensor, scene_feat: Tensor, scene_mask: Tensor, target_xyz: Tensor,
                     names: list[str] | None = None) -> Tensor:
        """Front yaw [B] (rad, robot frame) from a scene [B,N,3], features [B,N,C], mask [B,N], target [B,3]."""
        x, mask = axis_inputs(scene_xyz, scene_feat, scene_mask, target_xyz, self.hparams["crop_radius"], names)
        return yaw_from_vector(self.net(x, mask))

    def forward(self, batch: Batch) -> Tensor:
        """Yaw estimate [B] (not floor scores: AxisNet has no floor output)."""
        return self.estimate_yaw(batch["scene_xyz"], batch["scene_feat"], batch["scene_mask"], batch["target_xyz"],
                                 _names(batch))

    # ----------------------------------------------------------------- steps
    def model_step(self, batch: Batch) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """(loss, predicted yaw [B], {}) with the training augmentation when ``self.training``."""
        xyz, target, yaw = batch["scene_xyz"], batch["target_xyz"], batch["target_yaw"].reshape(-1)
        h = self.hparams
        if self.training and h["rot_aug_deg"] > 0:
            delta = (torch.rand(yaw.shape, device=yaw.device) * 2 - 1) * math.radians(h["rot_aug_deg"])
            xyz = rotate_about_target(xyz, target, delta)
            yaw = yaw + delta
        if self.training and h["jitter_sigma"] > 0:
            xyz = xyz + torch.randn_like(xyz) * h["jitter_sigma"]
        x, mask = axis_inputs(xyz, batch["scene_feat"], batch["scene_mask"], target, h["crop_radius"], _names(batch))
        q = self.net(x, mask)
        loss = self.criterion(q, yaw_to_vector(yaw).to(q.dtype))
        self._yaw_target = yaw  # the (augmented) label the metric compares against
        return loss, yaw_from_vector(q), {}

    def _shared_step(self, batch: Batch, stage: str) -> tuple[Tensor, Tensor]:
        self.check_inputs(batch)
        loss, pred, _ = self.model_step(batch)
        if not torch.isfinite(loss):
            raise FloatingPointError(f"{stage} loss is {loss.item()} on samples {_names(batch)[:4]}")
        bsz = batch["scene_xyz"].shape[0]
        self.log(f"{stage}_loss", loss, batch_size=bsz, prog_bar=stage != "test", on_epoch=True, on_step=stage == "train")
        metrics = getattr(self, f"{stage}_metrics")
        metrics.update(pred.detach(), self._yaw_target.detach())
        self.log_dict(metrics, batch_size=bsz, on_epoch=True, on_step=False, prog_bar=stage == "val")
        return loss, pred

    def predict_step(self, batch: Batch, batch_idx: int, dataloader_idx: int = 0) -> dict[str, Any]:
        self.check_inputs(batch)
        yaw = self(batch)
        gt = batch["target_yaw"].reshape(-1)
        return {
            "yaw": yaw.detach().cpu(),
            "target_yaw": gt.cpu(),
            "angle_error_deg": angle_error_deg(yaw.detach(), gt).cpu(),
            "target_xyz": batch["target_xyz"].cpu(),
            "meta": batch["meta"],
        }


def _names(batch: Batch) -> list[str]:
    return [str(m.get("sample_id", i)) for i, m in enumerate(batch.get("meta") or [])]
