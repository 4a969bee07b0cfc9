"""Base-placement geometry shared by N2M-style and C2F-Exp-style models and the footprint-occupancy input (pure torch).

Occupancy follows N2M's collision check (docs/background.md §3): points higher than ``z_min`` are
rasterised into ``cell``-sized cells; a base pose collides when an occupied cell centre lies in
the rotated robot footprint (``length`` x ``width``; ``back_frac`` of the length behind the base
origin, the rest in front).
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import torch
from torch import Tensor

from floaff_zoo.checks import check_integer, check_number, check_numbers
from floaff_zoo.floor import FLOOR_Z_MAX, FOOTPRINT, check_footprint, check_z_range

__all__ = [
    "footprint_collides",
    "footprint_counts",
    "footprint_occupancy",
    "footprint_seen",
    "heading_to",
    "occupied_cells",
]

#: ``footprint_occupancy`` channels: log(1 + obstacle points in the footprint), and that count, rescaled to
#: ``OCCUPANCY_REF_POINTS`` valid points, reaching ``OCCUPANCY_MIN_POINTS`` (the number ``floor.footprint_blocked``
#: uses, applied to the rescaled count: a density-normalised flag, not the rollout callback's test)
OCCUPANCY_CHANNELS = 2
OCCUPANCY_MIN_POINTS = 2
#: occupancy counts are expressed for a cloud of this many valid points (density-independent feature)
OCCUPANCY_REF_POINTS = 1024


def occupied_cells(xyz: Tensor, mask: Tensor | None = None, cell: float = 0.02, z_min: float = 0.05) -> Tensor:
    """Centres of occupied grid cells.

    Args:
        xyz: [N, 3] scene points (one sample); mask: [N] valid points; cell: cell size (m);
        z_min: points at or below this height are floor and do not occupy.
    Returns:
        [K, 2] unique occupied cell centres (xy).
    Raises:
        ValueError: for xyz not [N, 3], a mask not [N] (a [1] one was broadcast), a cell not finite and > 0.
    """
    if xyz.ndim != 2 or xyz.shape[-1] != 3:
        raise ValueError(f"occupied_cells: xyz must be [N, 3] (one sample), got {list(xyz.shape)}")
    if mask is not None and mask.shape != xyz.shape[:1]:
        raise ValueError(f"occupied_cells: mask must be [{xyz.shape[0]}], got {list(mask.shape)}")
    # 0 put every point in one cell at -0, NaN gave NaN centres; a NaN z_min called every point floor
    check_number("cell", cell, strict=True, owner="occupied_cells")
    check_number("z_min", z_min, low=-math.inf, owner="occupied_cells")
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
    Raises:
        ValueError: for poses not [P, 3] or cells not [K, 2] (a [K, 1] one was broadcast as x = y), a length or
            width not a finite number > 0, a back_frac not in [0, 1] (NaN in any put no cell inside: no collision).
    """
    check_numbers({"length": length, "width": width}, strict=True, owner="footprint_collides")
    check_number("back_frac", back_frac, high=1.0, owner="footprint_collides")
    if poses.ndim != 2 or poses.shape[-1] != 3:
        raise ValueError(f"footprint_collides: poses must be [P, 3] (x, y, yaw), got {list(poses.shape)}")
    if cells.ndim != 2 or cells.shape[-1] != 2:
        raise ValueError(f"footprint_collides: cells must be [K, 2], got {list(cells.shape)}")
    if cells.numel() == 0:
        return torch.zeros(poses.shape[0], dtype=torch.bool, device=poses.device)
    d = cells[None, :, :] - poses[:, None, :2]  # [P, K, 2]
    c, s = torch.cos(poses[:, 2])[:, None], torch.sin(poses[:, 2])[:, None]
    fwd = d[..., 0] * c + d[..., 1] * s
    side = -d[..., 0] * s + d[..., 1] * c
    inside = (fwd >= -back_frac * length) & (fwd <= (1 - back_frac) * length) & (side.abs() <= width / 2)
    return inside.any(dim=1)


def _check_footprint(owner: str, footprint: object, chunk: object) -> None:
    """Raise ValueError unless ``footprint`` is one (``floor.check_footprint``) and ``chunk`` an integer >= 1 (a chunk
    of 0, -3 or 2.5 ran as 1 or 2)."""
    check_footprint(owner, footprint)
    check_integer("chunk", chunk, 1, owner=owner)


def _check_batch_shapes(xyz: Tensor, mask: Tensor, floor_xy: Tensor, target_xy: Tensor) -> None:
    """Raise ValueError naming the argument whose shape does not fit [B, N, 3] / [B, N] / [B, M, 2] / [B, 2]."""
    if xyz.dim() != 3 or xyz.shape[-1] != 3:
        raise ValueError(f"footprint_counts: xyz must be [B, N, 3], got {list(xyz.shape)}")
    b, n = xyz.shape[:2]
    checks = (
        ("mask", mask, f"[B, N] = [{b}, {n}]", list(mask.shape) == [b, n]),
        ("floor_xy", floor_xy, f"[B, M, 2] with B = {b}", floor_xy.dim() == 3 and list(floor_xy.shape[::2]) == [b, 2]),
        ("target_xy", target_xy, f"[B, 2] = [{b}, 2]", list(target_xy.shape) == [b, 2]),
    )
    for name, t, want, ok in checks:
        if not ok:
            raise ValueError(f"footprint_counts: {name} must be {want}, got {list(t.shape)}")


@torch.no_grad()
def footprint_counts(
    xyz: Tensor,
    mask: Tensor,
    floor_xy: Tensor,
    target_xy: Tensor,
    footprint: tuple[float, float, float] = FOOTPRINT,
    z_range: tuple[float, float] = (FLOOR_Z_MAX, 1.2),
    chunk: int = 256,
) -> Tensor:
    """Obstacle points of each view's cloud inside the base footprint parked on each floor point, facing the target.

    The batched torch form of ``floaff_zoo.floor.footprint_blocked`` (same rectangle, same heights), with one
    difference: a point repeated in the cloud (as the ``resample`` collate and ``ResamplePoints`` repeat the points
    of a short cloud) counts each time, where ``footprint_blocked`` counts distinct points. On a cloud of distinct
    points ``footprint_blocked(cloud, pose) == (count >= min_points)`` for the pose ``best_pose`` gives a floor
    point. (Trained models read these counts: counting distinct points would change their inputs.)

    Args:
        xyz: [B, N, 3] clouds (floor at z = 0); mask: [B, N] bool valid points;
        floor_xy: [B, M, 2] base positions; target_xy: [B, 2] (the base faces it);
        footprint: (length, width, front) m (``floor.FOOTPRINT``); z_range: heights that block;
        chunk: floor points per pass (bounds the [B, chunk, N] temporaries).
    Returns:
        [B, M] counts in ``xyz``'s dtype (no gradient).
    """
    _check_batch_shapes(xyz, mask, floor_xy, target_xy)
    _check_footprint("footprint_counts", footprint, chunk)
    check_z_range("footprint_counts", z_range)
    length, width, front = footprint
    z = xyz[..., 2]
    keep = mask.bool() & torch.isfinite(xyz).all(-1) & (z > z_range[0]) & (z <= z_range[1])  # [B, N]
    out = []
    for along, across in _footprint_frames(xyz, floor_xy, target_xy, chunk):
        inside = (along <= front) & (along >= front - length) & (across.abs() <= width / 2) & keep[:, None, :]
        out.append(inside.sum(-1))
    return torch.cat(out, dim=1).to(xyz.dtype)


def _footprint_frames(xyz: Tensor, floor_xy: Tensor, target_xy: Tensor, chunk: int) -> Iterator[tuple[Tensor, Tensor]]:
    """Every point in the frame of a base parked on each floor point facing the target, ``chunk`` floor points at a
    time: (along the heading, across it) [B, m, N] each, m <= chunk, in floor-point order."""
    yaw = heading_to(floor_xy, target_xy[:, None, :])  # [B, M]
    c, s = torch.cos(yaw), torch.sin(yaw)
    step = chunk
    for m0 in range(0, floor_xy.shape[1], step):
        sl = slice(m0, m0 + step)
        d = xyz[:, None, :, :2] - floor_xy[:, sl, None, :]  # [B, m, N, 2]
        cc, ss = c[:, sl, None], s[:, sl, None]
        yield d[..., 0] * cc + d[..., 1] * ss, -d[..., 0] * ss + d[..., 1] * cc


@torch.no_grad()
def footprint_seen(
    xyz: Tensor,
    mask: Tensor,
    floor_xy: Tensor,
    target_xy: Tensor,
    footprint: tuple[float, float, float] = FOOTPRINT,
    cell: float = 0.1,
    chunk: int = 128,
) -> Tensor:
    """Share of the base footprint parked on each floor point, facing the target, that each view's cloud shows.

    The batched torch form of ``floaff_zoo.floor.footprint_coverage`` (same rectangle, same ``cell`` m sub-squares;
    any point of any height counts as seen): what ``CFARModule(coverage_input=True)`` gives its decoder.

    Args:
        xyz: [B, N, 3] clouds; mask: [B, N] bool valid points; floor_xy: [B, M, 2]; target_xy: [B, 2];
        footprint: (length, width, front) m; cell: sub-square side (m); chunk: floor points per pass.
    Returns:
        [B, M] shares in [0, 1] in ``xyz``'s dtype (no gradient).
    """
    _check_batch_shapes(xyz, mask, floor_xy, target_xy)
    _check_footprint("footprint_seen", footprint, chunk)
    check_number("cell", cell, strict=True, owner="footprint_seen")
    length, width, front = footprint
    na, nw = math.ceil(length / cell - 1e-9), math.ceil(width / cell - 1e-9)
    keep = mask.bool() & torch.isfinite(xyz).all(-1)  # [B, N]
    out = []
    for along, across in _footprint_frames(xyz, floor_xy, target_xy, chunk):
        a0, w0 = along - (front - length), across + width / 2  # from the footprint's back-left corner
        inside = (a0 >= 0) & (a0 <= length) & (w0 >= 0) & (w0 <= width) & keep[:, None, :]
        ia = torch.clamp(torch.floor(a0 / cell), 0, na - 1).long()
        iw = torch.clamp(torch.floor(w0 / cell), 0, nw - 1).long()
        idx = torch.where(inside, ia * nw + iw, torch.full_like(ia, na * nw))  # points outside: a spare bin
        seen = torch.zeros(*idx.shape[:2], na * nw + 1, dtype=torch.bool, device=xyz.device)
        seen.scatter_(2, idx, True)
        out.append(seen[..., :-1].sum(-1))
    return torch.cat(out, dim=1).to(xyz.dtype) / (na * nw)


@torch.no_grad()
def footprint_occupancy(xyz: Tensor, mask: Tensor, floor_xyz: Tensor, target_xyz: Tensor) -> Tensor:
    """Per-floor-point input channels saying whether a base parked there would stand in the view's obstacles.

    Counts (``footprint_counts``, robot frame, the whole cloud) are rescaled to a cloud of ``OCCUPANCY_REF_POINTS``
    valid points, so a model trained at one density reads the same feature from a denser or sparser cloud at
    deployment. Models with an ``occupancy_input`` switch (CFAR, PointNet++) feed this to their floor decoder.

    Args:
        xyz: [B, N, 3] clouds; mask: [B, N] valid points; floor_xyz: [B, M, 3]; target_xyz: [B, 3].
    Returns:
        [B, M, OCCUPANCY_CHANNELS]: log(1 + count), and count >= ``OCCUPANCY_MIN_POINTS`` as 0/1, both of the
        rescaled count (so the flag is not ``footprint_blocked``: a 4,096-point cloud needs 8 points in the
        footprint to set it, where the rollout callback's check needs 2).
    """
    counts = footprint_counts(xyz, mask, floor_xyz[..., :2], target_xyz[..., :2])
    valid = mask.sum(dim=1, keepdim=True).clamp(min=1).to(counts.dtype)  # [B, 1]
    counts = counts * (OCCUPANCY_REF_POINTS / valid)
    return torch.stack([torch.log1p(counts), (counts >= OCCUPANCY_MIN_POINTS).to(counts.dtype)], dim=-1)


def heading_to(xy: Tensor, target_xy: Tensor) -> Tensor:
    """Yaw (rad) that faces ``target_xy`` from each ``xy``: [..., 2] -> [...]."""
    d = target_xy - xy
    return torch.atan2(d[..., 1], d[..., 0])
