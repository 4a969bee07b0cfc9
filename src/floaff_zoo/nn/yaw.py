"""Training-free estimates of the target's front yaw from what the robot sees (no simulator field).

Both follow the contract's convention: ``yaw`` is the angle (rad, robot base frame, from +x, CCW) of the
target's front-facing outward normal.

* :func:`heading_yaw`: the robot looks at the target from the front or side region, so the direction from
  the target back to the robot base is a coarse estimate of the front normal (its error is the viewing
  angle, tens of degrees in side views).
* :func:`manhattan_yaw`: kitchens are built from boxes, so the vertical faces near the target are
  axis-aligned up to one unknown rotation. The dominant horizontal normal direction of those faces, known
  modulo 90 deg, is estimated from local surface normals (k-NN PCA) with the 4-theta circular mean; of the
  four directions it allows, the one closest to a coarse reference yaw is the front. With AxisNet's yaw as
  the reference this snaps AxisNet's estimate onto the kitchen's axes (exact whenever AxisNet is within
  45 deg); with :func:`heading_yaw` it is training-free but wrong in side views (robot > 45 deg off the
  normal).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor

from floaff_zoo.checks import check_integer, check_number
from floaff_zoo.nn.ops import check_points, full_mask

__all__ = ["MANHATTAN_K", "heading_yaw", "local_normals", "manhattan_yaw"]

#: neighbours of the local PCA that gives each point's surface normal
MANHATTAN_K = 12
#: a normal counts as horizontal (a vertical face) when |n_z| is below this
HORIZONTAL_NZ = 0.3
#: points used per sample (the nearest ones to the target): bounds the k-NN cost
MAX_POINTS = 1024


def heading_yaw(target_xyz: Tensor) -> Tensor:
    """Yaw [B] of the direction from the target [B, 3] back to the robot base (the frame origin)."""
    if target_xyz.ndim != 2 or target_xyz.shape[-1] != 3:  # a [3] target failed in indexing naming nothing
        raise ValueError(f"heading_yaw: target_xyz must be [B, 3], got {list(target_xyz.shape)}")
    return torch.atan2(-target_xyz[:, 1], -target_xyz[:, 0])


def local_normals(xyz: Tensor, k: int = MANHATTAN_K) -> tuple[Tensor, Tensor]:
    """Unit surface normals and planarity from the PCA of each point's k nearest neighbours.

    Args:
        xyz: [N, 3] (N > k).
    Returns:
        (normals [N, 3], planarity [N] in [0, 1]: 1 - smallest / middle eigenvalue, high on flat faces).
    Raises:
        ValueError: for xyz not [N, 3] with N > k, or k not an integer >= 1 (k = 0 called every point planar).
    """
    check_integer("k", k, 1, owner="local_normals")
    if xyz.ndim != 2 or xyz.shape[-1] != 3 or xyz.shape[0] <= k:  # torch's topk failed: "selected index k out of range"
        raise ValueError(f"local_normals: xyz must be [N, 3] with N > k = {k}, got {list(xyz.shape)}")
    d = torch.cdist(xyz, xyz)
    idx = d.topk(k + 1, largest=False).indices  # [N, k+1], includes the point itself
    nb = xyz[idx]  # [N, k+1, 3]
    centred = nb - nb.mean(1, keepdim=True)
    cov = centred.transpose(1, 2) @ centred / (k + 1)  # [N, 3, 3]
    evals, evecs = torch.linalg.eigh(cov.double())  # ascending
    normals = evecs[..., 0].to(xyz.dtype)
    planarity = (1.0 - evals[:, 0] / evals[:, 1].clamp_min(1e-12)).clamp(0, 1).to(xyz.dtype)
    return normals, planarity


def _sample_manhattan_yaw(xyz: Tensor, target: Tensor, radius: float) -> Tensor | None:
    """Dominant face orientation (mod 90 deg) near one target, or None. xyz [N, 3] (valid points), target [3]."""
    d = (xyz - target).norm(dim=-1)
    near = xyz[d <= radius]
    unique = torch.unique(near, dim=0)
    if len(unique) < len(near):  # a cloud padded by repetition: copies made neighbourhoods "planar" at any normal
        near = unique
    if len(near) <= MANHATTAN_K:
        return None
    if len(near) > MAX_POINTS:
        near = near[(near - target).norm(dim=-1).topk(MAX_POINTS, largest=False).indices]
    normals, planarity = local_normals(near)
    w = planarity * (normals[:, 2].abs() < HORIZONTAL_NZ)
    if float(w.sum()) <= 0:
        return None
    theta = torch.atan2(normals[:, 1], normals[:, 0])
    c, s = (w * torch.cos(4 * theta)).sum(), (w * torch.sin(4 * theta)).sum()
    if float(torch.hypot(c, s)) < 1e-6:
        return None
    return torch.atan2(s, c) / 4


def manhattan_yaw(
    scene_xyz: Tensor,
    scene_mask: Tensor,
    target_xyz: Tensor,
    radius: float = 1.2,
    reference: Tensor | None = None,
) -> Tensor:
    """Front-yaw estimate [B]: the Manhattan face direction that is the target's front.

    Args:
        scene_xyz: [B, N, 3]; scene_mask: [B, N] bool; target_xyz: [B, 3]; radius: neighbourhood (m);
        reference: [B] a coarse yaw (e.g. AxisNet's): the Manhattan direction nearest to it wins; default
            :func:`heading_yaw`, right only when the robot stands within 45 deg of the front normal.
    Returns:
        yaw [B] (rad) in [-pi, pi); samples without a usable vertical face keep the reference (or
        :func:`heading_yaw`).
    Raises:
        ValueError: for a shape that does not fit (a [B + 1] reference gave B + 1 yaws), or a radius not a finite
            number > 0 (NaN found no face near any target: every sample kept its reference, silently).
    """
    check_points("manhattan_yaw: scene_xyz", scene_xyz)
    scene_mask = full_mask(scene_xyz, scene_mask, "manhattan_yaw: scene_mask")
    b = scene_xyz.shape[0]
    if list(target_xyz.shape) != [b, 3]:
        raise ValueError(f"manhattan_yaw: target_xyz must be [{b}, 3], got {list(target_xyz.shape)}")
    if reference is not None and reference.numel() != b:
        raise ValueError(f"manhattan_yaw: reference must be [{b}], got {list(reference.shape)}")
    check_number("radius", radius, strict=True, owner="manhattan_yaw")
    head = heading_yaw(target_xyz)
    out = (head if reference is None else reference.to(head.dtype).reshape(-1)).clone()
    for i in range(scene_xyz.shape[0]):
        pts, t = scene_xyz[i][scene_mask[i]].float(), target_xyz[i].float()
        base = _sample_manhattan_yaw(pts, t, radius)
        if base is None:
            continue
        cands = base + torch.arange(4, device=base.device, dtype=base.dtype) * (math.pi / 2)
        off = (torch.remainder(cands - out[i] + math.pi, 2 * math.pi) - math.pi).abs()
        out[i] = cands[off.argmin()].to(out.dtype)
    return torch.remainder(out + math.pi, 2 * math.pi) - math.pi
