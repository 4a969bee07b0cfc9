"""AxisNet: a lightweight PointNet that estimates the target's front yaw (paper appendix "AxisNet").

Input per point ``x_i = [p_bar_i ; m_i]`` in R^4: ``p_bar = (p - t) / r`` (coordinates relative to the
target centre ``t``, divided by the crop radius ``r`` so they lie in the unit ball; the paper says only
"normalized") and ``m_i`` the target flag (scene_feat channel 0). Points are cropped to the sphere of
radius ``r`` around ``t`` (same crop and empty-crop fallback as CFAR). Shared per-point MLP, masked max
pooling, MLP head, output the l2-normalised ``[sin(yaw), cos(yaw)]`` of the front normal's yaw (robot
frame, the contract's ``target_yaw`` convention).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from floaff_zoo.nn.cfar import crop_mask, plain_mlp, rotate_z
from floaff_zoo.nn.pointnet2 import SharedMLP, masked_max

__all__ = ["AxisNet", "angle_error_deg", "axis_inputs", "rotate_about_target", "yaw_from_vector", "yaw_to_vector"]


def yaw_to_vector(yaw: Tensor) -> Tensor:
    """yaw [...] (rad) -> [..., 2] = (sin, cos), the paper's q_o."""
    return torch.stack([torch.sin(yaw), torch.cos(yaw)], dim=-1)


def yaw_from_vector(q: Tensor) -> Tensor:
    """[..., 2] (sin, cos) -> yaw [...] in (-pi, pi]."""
    return torch.atan2(q[..., 0], q[..., 1])


def angle_error_deg(pred_yaw: Tensor, target_yaw: Tensor) -> Tensor:
    """Absolute wrapped angle difference in degrees, [...] x2 -> [...] in [0, 180]."""
    d = torch.remainder(pred_yaw - target_yaw + math.pi, 2 * math.pi) - math.pi
    return d.abs() * (180.0 / math.pi)


def rotate_about_target(xyz: Tensor, target_xyz: Tensor, angle: Tensor) -> Tensor:
    """Rotate points [B, N, 3] about the vertical axis through target [B, 3] by angle [B]."""
    return rotate_z(xyz - target_xyz[:, None], angle) + target_xyz[:, None]


def axis_inputs(
    scene_xyz: Tensor,
    scene_feat: Tensor,
    scene_mask: Tensor,
    target_xyz: Tensor,
    radius: float,
    names: Sequence[str] | None = None,
) -> tuple[Tensor, Tensor]:
    """Build AxisNet's per-point input.

    Args:
        scene_xyz: [B, N, 3]; scene_feat: [B, N, C>=1] (channel 0 = target flag); scene_mask: [B, N];
        target_xyz: [B, 3]; radius: crop radius (m); names: sample names for errors.
    Returns:
        (x [B, N, 4] zeros where masked, mask [B, N] = valid and inside the crop).
    """
    keep, used = crop_mask(scene_xyz, scene_mask, target_xyz, radius, names)
    if scene_feat.ndim != 3 or scene_feat.shape[:2] != scene_xyz.shape[:2] or scene_feat.shape[-1] < 1:
        # torch.cat's or the first Linear's error named no argument; [1, N, C] one was not broadcast either
        raise ValueError(
            f"axis_inputs: scene_feat must be [{scene_xyz.shape[0]}, {scene_xyz.shape[1]}, C >= 1] (channel 0 = "
            f"target flag), got {list(scene_feat.shape)}"
        )
    rel = (scene_xyz - target_xyz[:, None]) / used[:, None, None]
    x = torch.cat([rel, scene_feat[..., :1].to(rel.dtype)], dim=-1)
    return torch.where(keep[..., None], x, torch.zeros_like(x)), keep


class AxisNet(nn.Module):
    """PointNet: shared MLP (Linear+BN+ReLU) -> masked max pool -> MLP -> normalised (sin, cos).

    Args:
        in_channels: per-point input size (4 = xyz + target flag); widths: shared MLP widths;
        head: hidden widths of the global head (plain Linear+ReLU, so a batch of one still trains).
    """

    def __init__(
        self, in_channels: int = 4, widths: Sequence[int] = (64, 128, 256), head: Sequence[int] = (128, 64)
    ) -> None:
        super().__init__()
        self.point_mlp = SharedMLP(in_channels, list(widths))
        self.head = plain_mlp(self.point_mlp.out_channels, list(head))
        self.out = nn.Linear(head[-1] if head else self.point_mlp.out_channels, 2)

    def forward(self, x: Tensor, mask: Tensor) -> Tensor:
        """x [B, N, in_channels], mask [B, N] -> q [B, 2] unit (sin, cos), float32."""
        if not torch.is_grad_enabled() and self.point_mlp.rowwise():
            h = self._pool_rowwise(x, mask)
        else:
            # padding/cropped points never touch BatchNorm statistics (SharedMLP runs the valid rows only)
            h = masked_max(self.point_mlp(x, mask), mask, dim=1)
        # float32 whatever the autocast: in bfloat16 the yaw read off q was rounded to ~1 deg and left the model in it
        return F.normalize(self.out(self.head(h)).float(), dim=-1, eps=1e-6)

    def _pool_rowwise(self, x: Tensor, mask: Tensor) -> Tensor:
        """``masked_max(point_mlp(x), mask, 1)`` [B, C] for an MLP without batch statistics: each cloud's valid
        points are pooled on their own (no [B, N, C] scatter; the last ReLU after the max). A cloud without a
        valid point gets the dtype's lowest value, as ``masked_max`` gives it."""
        out = []
        for b in range(x.shape[0]):
            rows = x[b][mask[b]]
            if rows.shape[0] == 0:
                low = torch.finfo(x.dtype).min
                out.append(x.new_full((self.point_mlp.out_channels,), low))
            else:
                out.append(self.point_mlp.pooled(rows, dim=0))
        return torch.stack(out)
