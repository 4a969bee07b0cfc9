"""AxisNetModule: trains/evaluates AxisNet, the target-yaw estimator CFAR uses at inference.

It shares :class:`~floaff_zoo.models.base.ZooModule` (CLI, ``train`` recipe, optimiser, checkpoints, hub,
``save_pretrained``) with the floor-map models but predicts no floor scores: training, validation, test and
predict steps work on the target yaw (``validation_step``/``test_step`` return ``{"loss", "yaw" [B]}``):

* loss: MSE between the predicted unit vector ``(sin, cos)`` and the ground-truth one (paper);
* augmentation (training only): a uniform yaw in ``[-rot_aug_deg, +rot_aug_deg]`` about the vertical
  axis through the target, label turned by the same angle, plus Gaussian jitter ``jitter_sigma`` (m);
* metric: mean absolute wrapped angle error in degrees, logged as ``{stage}_angle_error_deg``; the
  checkpoint monitor is ``val_angle_error_deg`` (mode min). The paper keeps the lowest validation loss;
  for unit vectors ``|q - q*|^2 = 2 - 2 cos(err)``, so both select almost always the same epoch.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import torch
from torch import Tensor
from torchmetrics import Metric, MetricCollection
from torchmetrics.utilities.distributed import gather_all_tensors

from floaff_zoo.checks import check_integer, check_number, check_numbers
from floaff_zoo.contract import Batch
from floaff_zoo.metrics import _cat_or_empty, _first_occurrence, fill_empty_cat_states
from floaff_zoo.models.base import TrainConfig, ZooModule, batch_index, sample_names
from floaff_zoo.nn.axisnet import (
    AxisNet,
    angle_error_deg,
    axis_inputs,
    rotate_about_target,
    yaw_from_vector,
    yaw_to_vector,
)


class AngleErrorDeg(Metric):
    """Mean absolute wrapped angle error in degrees. ``update(pred_yaw [B], target_yaw [B], index [B] | None)``
    (radians; ``index``: each sample's position in its split).

    Samples with one ``index`` count once, as the floor-map metrics count them: ``DistributedSampler`` pads the
    last rank-batches by repeating samples, which weighed the repeats twice in AxisNet's monitored error. Without
    ``index`` every row counts.
    """

    is_differentiable = False
    higher_is_better = False
    full_state_update = False

    def __init__(self) -> None:
        super().__init__()
        self.add_state("rows", default=[], dist_reduce_fx="cat")  # [B, 2] (index or -1, error deg) per update

    def update(self, pred_yaw: Tensor, target_yaw: Tensor, index: Tensor | None = None) -> None:
        if pred_yaw.shape != target_yaw.shape:
            raise ValueError(f"AngleErrorDeg: shapes differ, {tuple(pred_yaw.shape)} vs {tuple(target_yaw.shape)}")
        if not (torch.isfinite(pred_yaw).all() and torch.isfinite(target_yaw).all()):
            raise ValueError("AngleErrorDeg: NaN/Inf yaw")
        err = angle_error_deg(pred_yaw.double(), target_yaw.double()).reshape(-1)
        if index is not None and index.numel() != err.numel():  # torch.stack failed naming no argument
            raise ValueError(f"AngleErrorDeg: index must have {err.numel()} entries, got {list(index.shape)}")
        idx = torch.full_like(err, -1.0) if index is None else index.reshape(-1).to(err)
        self.rows.append(torch.stack([idx, err], dim=1))

    def _sync_dist(self, dist_sync_fn: Any = gather_all_tensors, process_group: Any = None) -> None:
        fill_empty_cat_states(self, {"rows": (2, torch.float64)})
        super()._sync_dist(dist_sync_fn, process_group)

    def compute(self) -> Tensor:
        rows = _cat_or_empty(self.rows, 2, torch.float64, self.device)  # a list before a DDP sync, a tensor after
        if rows.shape[0] == 0:
            return torch.tensor(float("nan"))
        keys = rows[:, 0].clone()
        unkeyed = keys < 0  # rows without an index are distinct samples: give each a key of its own
        keys[unkeyed] = -1.0 - torch.arange(int(unkeyed.sum()), dtype=keys.dtype, device=keys.device)
        return rows[_first_occurrence(keys), 1].mean().float()


def _check_widths(name: str, value: object, owner: str) -> None:
    """Raise ValueError unless ``value`` is None or a list of integers >= 1, naming ``name`` (and the entry)."""
    if value is None:
        return
    if not isinstance(value, (list, tuple)):  # a text is iterable: "64" read as widths 6 and 4
        raise ValueError(f"{owner}: {name} must be a list of integers >= 1, got {value!r}")
    for i, width in enumerate(value):
        check_integer(f"{name}[{i}]", width, 1, owner=owner)


class AxisNetModule(ZooModule):
    """AxisNet (paper appendix): PointNet on ``[p - t (scaled by 1/r); target flag]`` -> unit (sin, cos).

    Args:
        crop_radius: points farther than this from the target centre are dropped (m); coordinates
            are divided by it. Use the CFAR radius of the benchmark (1.3 Styles, 1.2 Layouts).
        widths: shared per-point MLP widths; head: global MLP widths.
        rot_aug_deg: training yaw augmentation half-range (paper: 90).
        jitter_sigma: training Gaussian coordinate jitter (m; paper: 0.005).
        train: optimiser recipe (:class:`~floaff_zoo.models.base.TrainConfig`; paper: Adam 1e-4, no
            schedule, batch 32, 200 epochs, best validation checkpoint).
        weights: pretrained initialisation (see :class:`~floaff_zoo.models.base.ZooModule`).
    """

    monitor: ClassVar[str] = "val_angle_error_deg"
    mode: ClassVar[str] = "min"
    output_key: ClassVar[str] = "yaw"
    empty_means_default: ClassVar[tuple[str, ...]] = ("widths",)
    metrics_in_progress_bar: ClassVar[bool] = True

    def __init__(
        self,
        crop_radius: float = 1.3,
        widths: list[int] | None = None,
        head: list[int] | None = None,
        rot_aug_deg: float = 90.0,
        jitter_sigma: float = 0.005,
        train: TrainConfig = TrainConfig(lr=1e-4, scheduler="none"),  # noqa: B008 - frozen
        weights: str | None = None,
    ) -> None:
        super().__init__(train=train, weights=weights)

    # ----------------------------------------------------------------- hooks
    def configure_models(self) -> None:
        h = self.hparams
        # NaN cropped every point away and blamed the samples; inf divided every coordinate down to 0
        check_number("crop_radius", h["crop_radius"], strict=True, owner=type(self).__name__)
        # negative or NaN turned the augmentation off silently
        check_numbers({k: h[k] for k in ("rot_aug_deg", "jitter_sigma")}, owner=type(self).__name__)
        if h["widths"] is not None and not h["widths"]:  # [] built the default widths, silently
            raise ValueError(f"{type(self).__name__}: widths needs >= 1 width (null for [64, 128, 256]), got []")
        for name in ("widths", "head"):  # 8.5, True or a text failed in torch.empty naming no argument
            _check_widths(name, h[name], type(self).__name__)
        widths = h["widths"] if h["widths"] is not None else [64, 128, 256]
        self.net = AxisNet(4, widths, h["head"] if h["head"] is not None else [128, 64])

    def configure_losses(self) -> None:
        self.criterion = torch.nn.MSELoss()

    def configure_metrics(self) -> None:
        for stage in ("train", "val", "test"):
            setattr(
                self, f"{stage}_metrics", MetricCollection({"angle_error_deg": AngleErrorDeg()}, prefix=f"{stage}_")
            )

    # ----------------------------------------------------------------- inference API
    def estimate_yaw(
        self,
        scene_xyz: Tensor,
        scene_feat: Tensor,
        scene_mask: Tensor,
        target_xyz: Tensor,
        names: list[str] | None = None,
    ) -> Tensor:
        """Front yaw [B] (rad, robot frame) from a scene [B,N,3], features [B,N,C], mask [B,N], target [B,3]."""
        x, mask = axis_inputs(scene_xyz, scene_feat, scene_mask, target_xyz, self.hparams["crop_radius"], names)
        return yaw_from_vector(self.net(x, mask))

    def forward(self, batch: Batch) -> Tensor:
        """Yaw estimate [B] (not floor scores: AxisNet has no floor output)."""
        return self.estimate_yaw(
            batch["scene_xyz"], batch["scene_feat"], batch["scene_mask"], batch["target_xyz"], sample_names(batch)
        )

    # ----------------------------------------------------------------- steps
    def augment(self, batch: Batch) -> Batch:
        """A uniform yaw in +-``rot_aug_deg`` about the target (label turned with it) + xyz jitter."""
        h = self.hparams
        xyz, yaw = batch["scene_xyz"], batch["target_yaw"].reshape(-1)
        if h["rot_aug_deg"] > 0:
            delta = (torch.rand(yaw.shape, device=yaw.device) * 2 - 1) * math.radians(h["rot_aug_deg"])
            xyz = rotate_about_target(xyz, batch["target_xyz"], delta)
            yaw = yaw + delta
        if h["jitter_sigma"] > 0:
            xyz = xyz + torch.randn_like(xyz) * h["jitter_sigma"]
        return {**batch, "scene_xyz": xyz, "target_yaw": yaw.reshape(batch["target_yaw"].shape)}

    def model_step(self, batch: Batch) -> tuple[Tensor, Tensor, dict[str, Tensor]]:
        """(loss, predicted yaw [B], {}): MSE between the predicted and the true (sin, cos)."""
        x, mask = axis_inputs(
            batch["scene_xyz"],
            batch["scene_feat"],
            batch["scene_mask"],
            batch["target_xyz"],
            self.hparams["crop_radius"],
            sample_names(batch),
        )
        q = self.net(x, mask)
        loss = self.criterion(q, yaw_to_vector(batch["target_yaw"].reshape(-1)).to(q.dtype))
        return loss, yaw_from_vector(q), {}

    def update_metrics(self, metrics: MetricCollection, pred: Tensor, batch: Batch) -> None:
        metrics.update(pred, batch["target_yaw"].reshape(-1), batch_index(batch, pred.device))

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
