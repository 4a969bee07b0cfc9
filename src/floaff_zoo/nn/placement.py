"""Base-placement geometry shared by N2M-style and C2F-Exp-style models (pure torch).

Occupancy follows N2M's collision check (docs/background.md §3): points higher than ``z_min`` are
rasterised into ``cell``-sized cells; a base pose collides when an occupied cell centre lies in
the rotated robot footprint (``length`` x ``width``; ``back_frac`` of the length behind the base
origin, the rest in front).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

__all__ = ["footprint_collides", "heading_to", "occupied_cells"]


def occupied_cells(xyz: Tensor, mask: Tensor | None = None, cell: float = 0.02, z_min: float = 0.05) -> Tensor:
    """Centres of occupied grid cells.

    Args:
        xyz: [N, 3] scene points (one sample); mask: [N] valid points; cell: cell size (m);
        z_min: points at or below this height are floor and do not occupy.
    Returns:
        [K, 2] unique occupied cell centres (xy).
    """
    keep = xyz[:, 2] > z_min
    if mask is not None:
        keep = keep & mask.bool()
    ij = torch.floor(xyz[keep, :2].float() / cell).long()
    if ij.numel() == 0:
        return xyz.new_zeros(0, 2)
    ij = torch.unique(ij, dim=0)
    return (ij.float() + 0.5) * cell


def footprint_collides(
    cells: Tensor,
    poses: Tensor,
    length: float = 0.63,
    width: float = 0.5,
    back_frac: float = 0.83,
) -> Tensor:
    """Which poses put an occupied cell inside the robot footprint.

    Args:
        cells: [K, 2] occupied cell centres; poses: [P, 3] (x, y, yaw); length/width: footprint
        (m, along/across the heading); back_frac: share of ``length`` behind the base origin.
    Returns:
        [P] bool, True = collision.
    """
    if cells.numel() == 0:
        return torch.zeros(poses.shape[0], dtype=torch.bool, device=poses.device)
    d = cells[None, :, :] - poses[:, None, :2]  # [P, K, 2]
    c, s = torch.cos(poses[:, 2])[:, None], torch.sin(poses[:, 2])[:, None]
    fwd = d[..., 0] * c + d[..., 1] * s
    side = -d[..., 0] * s + d[..., 1] * c
    inside = (fwd >= -back_frac * length) & (fwd <= (1 - back_frac) * length) & (side.abs() <= width / 2)
    return inside.any(dim=1)


def heading_to(xy: Tensor, target_xy: Tensor) -> Tensor:
    """Yaw (rad) that faces ``target_xy`` from each ``xy``: [..., 2] -> [...]."""
    d = target_xy - xy
    return torch.atan2(d[..., 1], d[..., 0])


def wrap_angle(a: Tensor) -> Tensor:
    """Wrap angles to (-pi, pi]."""
    return torch.remainder(a + math.pi, 2 * math.pi) - math.pi
