"""PointNet2Module: PointNet++ (SSG or MSG) adapted to floor affordance (MoMa-Kitchen baseline).

Also home of the small helpers the other point models share (input extraction, the scene + floor
forward, bf16 autocast, in-place ``torch.compile``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from typing import Any, Literal

import torch
from torch import Tensor, nn

from floaff_zoo.contract import Batch
from floaff_zoo.models.base import FloAffModule, FloAffTrainConfig, check_choices, check_dropout, check_sizes
from floaff_zoo.nn.nets import PointNet2Net, check_inputs, require_valid
from floaff_zoo.nn.placement import OCCUPANCY_CHANNELS, footprint_occupancy

#: default PointNet++ sizes for scenes in metres (robot base frame, a few metres across)
SSG_DEFAULTS: dict[str, Any] = {
    "npoints": [1024, 256, 64],
    "radii": [[0.2], [0.4], [0.8]],
    "nsamples": [[32], [32], [32]],
    "mlps": [[[64, 64, 128]], [[128, 128, 256]], [[256, 256, 512]]],
    "fp_mlps": [[256, 256], [256, 128], [128, 128]],
}
MSG_DEFAULTS: dict[str, Any] = {
    "npoints": [1024, 256, 64],
    "radii": [[0.1, 0.2], [0.2, 0.4], [0.4, 0.8]],
    "nsamples": [[16, 32], [16, 32], [16, 32]],
    "mlps": [
        [[32, 32, 64], [64, 64, 128]],
        [[64, 64, 128], [128, 128, 256]],
        [[128, 196, 256], [128, 196, 256]],
    ],
    "fp_mlps": [[256, 256], [256, 128], [128, 128]],
}


# ----------------------------------------------------------------------------- shared helpers
def scene_inputs(batch: Batch, feat_channels: int) -> tuple[Tensor, Tensor, Tensor]:
    """(scene_xyz [B,N,3] f32, scene_feat [B,N,C] f32, scene_mask [B,N] bool), checked."""
    xyz = batch["scene_xyz"].float()
    feat = batch["scene_feat"][..., :feat_channels].float()
    mask = batch.get("scene_mask")
    mask = torch.ones(xyz.shape[:2], dtype=torch.bool, device=xyz.device) if mask is None else mask.bool()
    check_inputs(scene_xyz=xyz, scene_feat=feat)
    require_valid("scene_mask", mask)
    return xyz, feat, mask


def floor_inputs(batch: Batch) -> tuple[Tensor, Tensor]:
    """(floor_xyz [B,M,3] f32, floor_mask [B,M] bool), checked."""
    xyz = batch["floor_xyz"].float()
    mask = batch.get("floor_mask")
    mask = torch.ones(xyz.shape[:2], dtype=torch.bool, device=xyz.device) if mask is None else mask.bool()
    check_inputs(floor_xyz=xyz)
    require_valid("floor_mask", mask)
    return xyz, mask


@contextlib.contextmanager
def maybe_bf16(enabled: bool, device: torch.device) -> Iterator[None]:
    """bf16 autocast around the MLPs when ``enabled`` (neighbour search stays fp32 inside the ops)."""
    if enabled:
        with torch.autocast(device_type=device.type, dtype=torch.bfloat16):
            yield
    else:
        yield


def run_scene_floor_net(
    net: nn.Module, batch: Batch, feat_channels: int, bf16: bool, occupancy_input: bool = False
) -> Any:
    """``net(scene, floor, robot, target, fps=...)`` on a batch (PointNet++, VoteNet- and H3DNet-style nets).

    Inputs are checked; FPS runs first, outside autocast; the MLPs run in bf16 when ``bf16``. With
    ``occupancy_input`` the net also gets ``floor_feat`` = ``nn.placement.footprint_occupancy`` [B, M, 2].
    Returns what the net returns (scores [B, M], possibly with aux geometry), not cast.
    """
    xyz, feat, mask = scene_inputs(batch, feat_channels)
    fxyz, fmask = floor_inputs(batch)
    target = batch["target_xyz"].float()
    extra = {"floor_feat": footprint_occupancy(xyz, mask, fxyz, target)} if occupancy_input else {}
    fps = net.sample(xyz, mask)
    with maybe_bf16(bf16, xyz.device):
        return net(xyz, feat, mask, fxyz, fmask, batch["robot"].float(), target, fps=fps, **extra)


def maybe_compile(net: nn.Module, enabled: bool) -> None:
    """``torch.compile`` the net's forward in place (state-dict keys unchanged); FPS stays outside.

    Static shapes: the set-abstraction levels call one function at several sizes, which turns on dynamic shapes
    by default, and with them inductor fails to compile the backward (torch 2.13). A new batch shape compiles
    again, up to torch's recompile limit; past it that part runs eagerly.
    """
    if enabled:
        net.compile(dynamic=False)


def resolve_sizes(variant: str, **given: Any) -> dict[str, Any]:
    """Fill ``None`` size arguments from the variant's defaults."""
    base = SSG_DEFAULTS if variant == "ssg" else MSG_DEFAULTS
    return {k: (v if v is not None else base[k]) for k, v in given.items()}


class PointNet2Module(FloAffModule):
    """PointNet++ encoder over the observation + robot MLP + FP onto the floor points + sigmoid head.

    The scene cloud (xyz + the first ``feat_channels`` feature channels: target flag [, RGB]) goes
    through SSG or MSG set abstraction; the robot descriptor's MLP code is concatenated to the
    deepest level; feature propagation climbs back to the first level's centres and then onto the
    floor points (skip features: floor xyz, xy offset and distance to the target); a per-point
    head gives the score in [0, 1].

    Args:
        variant: ``ssg`` (single scale) or ``msg`` (multi scale).
        npoints, radii, nsamples, mlps, fp_mlps: sizes; ``None`` = the variant's defaults
            (``SSG_DEFAULTS``/``MSG_DEFAULTS``). ``fp_mlps`` has one entry per SA level; the last is
            the FP onto the floor points.
        robot_width, head_width, dropout: robot MLP width, head width, head dropout.
        occupancy_input: append the base footprint's occupancy from the view's cloud at each floor point to the
            floor skip features (``nn.placement.footprint_occupancy``, the input of ``CFARModule(occupancy_input)``;
            off by default: a fairness check of that input, not part of the MoMa-Kitchen baseline).
        compile: ``torch.compile`` the net (opt-in; 30-50 s first step on CPU).
        bf16: bf16 autocast for the MLPs (opt-in; needs AVX512-BF16/AMX to pay off on CPU).
        (the rest: see :class:`FloAffModule`)
    """

    def __init__(
        self,
        variant: Literal["ssg", "msg"] = "ssg",
        npoints: list[int] | None = None,
        radii: list[list[float]] | None = None,
        nsamples: list[list[int]] | None = None,
        mlps: list[list[list[int]]] | None = None,
        fp_mlps: list[list[int]] | None = None,
        robot_width: int = 64,
        head_width: int = 64,
        dropout: float = 0.1,
        occupancy_input: bool = False,
        compile: bool = False,
        bf16: bool = False,
        feat_channels: int = 1,
        robot_dim: int = 2,
        train: FloAffTrainConfig = FloAffTrainConfig(),  # noqa: B008 - frozen
        weights: str | None = None,
    ) -> None:
        super().__init__(feat_channels=feat_channels, robot_dim=robot_dim, train=train, weights=weights)

    def configure_models(self) -> None:
        h = self.hparams
        check_dropout(h["dropout"], type(self).__name__)
        check_sizes(h, ("robot_width", "head_width"), type(self).__name__)
        check_choices(type(self), {"variant": h["variant"]})  # named by this module, before PointNet2Net's check
        sizes = resolve_sizes(
            h["variant"],
            npoints=h["npoints"],
            radii=h["radii"],
            nsamples=h["nsamples"],
            mlps=h["mlps"],
            fp_mlps=h["fp_mlps"],
        )
        self.net = PointNet2Net(
            h["variant"],
            h["feat_channels"],
            h["robot_dim"],
            robot_width=h["robot_width"],
            head_width=h["head_width"],
            dropout=h["dropout"],
            floor_feat_channels=OCCUPANCY_CHANNELS if h["occupancy_input"] else 0,
            **sizes,
        )
        maybe_compile(self.net, h["compile"])

    def forward(self, batch: Batch) -> Tensor:
        h = self.hparams
        return run_scene_floor_net(self.net, batch, h["feat_channels"], h["bf16"], h["occupancy_input"]).float()
