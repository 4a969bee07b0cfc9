"""CFAR: the canonical transform T(P, S) (pure torch functions) and the CFAR network.

Canonical transform (paper eqs. crop + rotation), on padded batches with masks:

1. crop: keep scene points with ``||p - t|| <= r`` (cropped points get mask False and zero coordinates);
2. align: ``p_hat = R_z(phi) (p - t)`` with ``phi = -pi/2 - yaw`` so that the target's front-facing
   outward normal (``target_yaw``, the contract's convention: angle of the normal from +x, CCW)
   points along **-y** in the canonical frame.

   The paper writes the rotation as ``R(pi - theta_o)``; with the contract's ``yaw`` that literal formula
   would send the front to -x, not to -y as the paper (and the contract) state. The two agree when the
   paper's ``theta_o = yaw - pi/2`` (its angle is measured from a reference axis turned by 90 deg), so we
   implement the stated goal, front -> -y. Any constant offset only rotates the whole canonical frame.

Floor points go through the same rigid map (centre + rotation) but are **not** cropped: every floor
point keeps its score, and the order of floor points is never changed, so mapping predictions back to
the robot frame is the identity on the score vector. :func:`robot_from_canonical` gives the 4x4
canonical -> robot transform for pictures.

Empty crop: when a sample keeps no valid point, its radius grows x1.25 up to 3 times; if it is still
empty a :class:`~floaff_zoo.contract.SampleError` names the sample.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from floaff_zoo.checks import check_integer, check_number
from floaff_zoo.contract import SampleError
from floaff_zoo.nn.ops import (
    check_floor_feat,
    check_interpolation_inputs,
    check_points,
    full_mask,
    gpu_fps_kernel,
    point_kernel,
    weighted_gather3,
)
from floaff_zoo.nn.pointnet2 import FeaturePropagation, PointNet2Encoder, SharedMLP

__all__ = [
    "CFARNet",
    "CanonicalCloud",
    "CROP_GROWTH",
    "CROP_RETRIES",
    "alignment_angle",
    "canonical_transform",
    "canonical_to_robot",
    "crop_mask",
    "plain_mlp",
    "robot_from_canonical",
    "rotate_z",
    "sample_levels",
    "stable_three_interpolate",
    "tolerant_fps",
]

#: empty-crop fallback: the radius grows by this factor ...
CROP_GROWTH = 1.25
#: ... at most this many times before the sample is rejected
CROP_RETRIES = 3


def _check_batch_vector(owner: str, name: str, t: Tensor, want: list[int]) -> None:
    """Raise ``ValueError`` unless ``t`` has exactly the shape ``want`` (a [1] or [1, 3] one broadcast silently)."""
    if list(t.shape) != want:
        raise ValueError(f"{owner}: {name} must be {want}, got {list(t.shape)}")


def rotate_z(xyz: Tensor, angle: Tensor) -> Tensor:
    """Rotate points about +z. xyz [B, N, 3], angle [B] (rad) -> [B, N, 3]."""
    check_points("rotate_z: xyz", xyz)
    _check_batch_vector("rotate_z", "angle", angle, [xyz.shape[0]])
    c, s = torch.cos(angle)[:, None], torch.sin(angle)[:, None]
    x, y, z = xyz.unbind(-1)
    return torch.stack([c * x - s * y, s * x + c * y, z], dim=-1)


def alignment_angle(yaw: Tensor | None, batch: int, device: torch.device, dtype: torch.dtype) -> Tensor:
    """Rotation angle phi [B] that sends a front normal of angle ``yaw`` [B] to -y; zeros when yaw is None."""
    if yaw is None:
        return torch.zeros(batch, device=device, dtype=dtype)
    if yaw.ndim < 1 or yaw.shape[0] != batch or yaw.numel() != batch:  # a [2, 2] yaw was reshaped into 4 samples
        raise ValueError(f"alignment_angle: yaw must be [{batch}] for a batch of {batch}, got {list(yaw.shape)}")
    return -0.5 * math.pi - yaw.to(dtype).reshape(batch)


def crop_mask(
    xyz: Tensor,
    mask: Tensor,
    centre: Tensor,
    radius: float | None,
    names: Sequence[str] | None = None,
) -> tuple[Tensor, Tensor]:
    """Sphere crop with the empty-crop fallback.

    Args:
        xyz: [B, N, 3]; mask: [B, N] bool; centre: [B, 3]; radius: metres, or None (no crop);
        names: sample names for the error message (default: batch positions).
    Returns:
        (mask [B, N] bool: valid and within the radius used, radius_used [B] float).
    Raises:
        SampleError: a sample has no valid point even at ``radius * 1.25**3`` (or no valid point at all).
    """
    check_points("crop_mask: xyz", xyz)
    b = xyz.shape[0]
    # a [B, 1] or [1, N] mask and a [1, 3] centre were broadcast over the batch
    mask = full_mask(xyz, mask, "crop_mask: mask")
    _check_batch_vector("crop_mask", "centre", centre, [b, 3])
    if radius is None:
        empty = ~mask.any(dim=1)
        if empty.any():
            raise SampleError(f"CFAR crop: sample(s) {_names(empty, names)} have no valid scene point")
        return mask, torch.full((b,), float("inf"), device=xyz.device)
    check_number("crop radius", radius, strict=True)  # NaN kept no point and blamed the samples; None = no crop
    d2 = ((xyz - centre[:, None, :]) ** 2).sum(-1)  # [B, N]
    used = torch.full((b,), float(radius), device=xyz.device, dtype=xyz.dtype)
    keep = mask & (d2 <= used[:, None] ** 2)
    for _ in range(CROP_RETRIES):
        empty = ~keep.any(dim=1)
        if not empty.any():
            break
        used = torch.where(empty, used * CROP_GROWTH, used)
        keep = mask & (d2 <= used[:, None] ** 2)
    empty = ~keep.any(dim=1)
    if empty.any():
        r_max = radius * CROP_GROWTH**CROP_RETRIES
        raise SampleError(
            f"CFAR crop: sample(s) {_names(empty, names)} keep no scene point within {radius:.3g} m of the "
            f"target centre, even after growing the radius x{CROP_GROWTH} {CROP_RETRIES} times (to {r_max:.3g} m); "
            "check target_xyz / scene_xyz of these samples"
        )
    return keep, used


def _names(flags: Tensor, names: Sequence[str] | None) -> list[str]:
    idx = torch.nonzero(flags).flatten().tolist()
    return [str(names[i]) if names is not None and i < len(names) else f"#{i}" for i in idx]


@dataclass
class CanonicalCloud:
    """Output of :func:`canonical_transform` (all tensors in the canonical frame).

    xyz [B, N, 3] (zeros where mask is False), mask [B, N], floor_xyz [B, M, 3], angle [B] (phi, rad),
    centre [B, 3] (target centre, robot frame), radius [B] (crop radius used; inf without crop).
    """

    xyz: Tensor
    mask: Tensor
    floor_xyz: Tensor
    angle: Tensor
    centre: Tensor
    radius: Tensor


def canonical_transform(
    scene_xyz: Tensor,
    scene_mask: Tensor,
    floor_xyz: Tensor,
    target_xyz: Tensor,
    yaw: Tensor | None,
    radius: float | None,
    extra_angle: Tensor | None = None,
    names: Sequence[str] | None = None,
) -> CanonicalCloud:
    """T(P, S): crop around the target, centre on it, rotate its front to -y.

    Args:
        scene_xyz: [B, N, 3]; scene_mask: [B, N]; floor_xyz: [B, M, 3]; target_xyz: [B, 3];
        yaw: [B] front-normal yaw (rad, robot frame) or None (no alignment, w/o-Align ablation);
        radius: crop radius (m) or None (w/o-Crop ablation);
        extra_angle: [B] additional rotation (rad) about the target, e.g. the +-5 deg training
            perturbation of the alignment;
        names: sample names for error messages.
    Returns:
        :class:`CanonicalCloud`.
    """
    b = scene_xyz.shape[0]
    keep, used = crop_mask(scene_xyz, scene_mask, target_xyz, radius, names)
    if floor_xyz.ndim != 3 or floor_xyz.shape[0] != b or floor_xyz.shape[-1] != 3:  # a batch of 1 was broadcast
        raise ValueError(f"canonical_transform: floor_xyz must be [{b}, M, 3], got {list(floor_xyz.shape)}")
    angle = alignment_angle(yaw, b, scene_xyz.device, scene_xyz.dtype)
    if extra_angle is not None:
        _check_batch_vector("canonical_transform", "extra_angle", extra_angle, [b])
        angle = angle + extra_angle.to(angle.dtype)
    xyz = rotate_z(scene_xyz - target_xyz[:, None, :], angle)
    xyz = torch.where(keep[..., None], xyz, torch.zeros_like(xyz))
    floor = rotate_z(floor_xyz - target_xyz[:, None, :], angle)
    return CanonicalCloud(xyz=xyz, mask=keep, floor_xyz=floor, angle=angle, centre=target_xyz, radius=used)


def canonical_to_robot(xyz: Tensor, centre: Tensor, angle: Tensor) -> Tensor:
    """Inverse of the rigid part of T: canonical [B, N, 3] -> robot frame [B, N, 3] (centre [B, 3], angle [B])."""
    _check_batch_vector("canonical_to_robot", "centre", centre, [xyz.shape[0], 3])
    return rotate_z(xyz, -angle) + centre[:, None, :]


def robot_from_canonical(centre: Tensor, angle: Tensor) -> Tensor:
    """Homogeneous canonical -> robot transform [B, 4, 4] (p_robot = T @ [p_canonical; 1])."""
    b = centre.shape[0]
    c, s = torch.cos(-angle), torch.sin(-angle)
    out = torch.zeros(b, 4, 4, dtype=centre.dtype, device=centre.device)
    out[:, 0, 0], out[:, 0, 1], out[:, 1, 0], out[:, 1, 1] = c, -s, s, c
    out[:, 2, 2] = 1.0
    out[:, :3, 3] = centre
    out[:, 3, 3] = 1.0
    return out


#: squared-distance tolerance (m^2) under which FPS treats candidates as tied (see ``tolerant_fps``)
FPS_TIE_TOL = 1e-4


@torch.no_grad()
def tolerant_fps(xyz: Tensor, mask: Tensor | None, npoint: int, tol: float = FPS_TIE_TOL) -> Tensor:
    """Farthest point sampling whose choice does not flip under float noise.

    Exact FPS breaks ties by rounding noise; on a regular floor grid almost every step is a tie, so
    a rotated copy of the same scene (equal up to 1e-6 m after canonicalisation) would pick other
    centres. Here every candidate within ``tol`` (m^2) of the farthest distance counts as tied and the
    lowest index wins. Starts at the first valid point; padded points are never chosen (fewer valid
    points than ``npoint`` -> valid points repeat).

    Args:
        xyz: [B, N, 3]; mask: [B, N] bool or None; npoint: centres; tol: tie tolerance (m^2).
    Returns:
        [B, npoint] int64.
    Raises:
        ValueError: for npoint below 1, a cloud without a valid point, bad shapes (a [B, 1] mask was broadcast).
    """
    check_points("tolerant_fps: xyz", xyz)
    check_integer("npoint", npoint, 1, owner="tolerant_fps")
    b, n, _ = xyz.shape
    mask = full_mask(xyz, mask, "tolerant_fps: mask")  # a [B, 1] one was broadcast
    if not mask.any(dim=1).all():
        raise ValueError("tolerant_fps: a cloud of the batch has no valid point")
    kernel = point_kernel(xyz.device)
    if kernel is not None:  # the same loop in C++ (one Python call instead of ~6 ops per centre)
        return kernel.tolerant_fps_forward(xyz.detach().float().contiguous(), mask.contiguous(), int(npoint), tol)
    gpu = gpu_fps_kernel(xyz)
    out = gpu.fps(xyz, mask, int(npoint), tol) if gpu is not None else None  # CUDA: the loop as one Triton launch
    if out is not None:
        return out
    pts = xyz.detach().float()  # float32 noise (~1e-6 m^2) is far below tol
    dist = torch.where(mask, torch.full((b, n), float("inf"), dtype=pts.dtype, device=xyz.device), -1.0)
    cur = mask.long().argmax(dim=1)
    out = torch.empty(b, npoint, dtype=torch.long, device=xyz.device)
    ar = torch.arange(n, device=xyz.device)
    for j in range(npoint):
        out[:, j] = cur
        d = ((pts - pts[torch.arange(b), cur][:, None]) ** 2).sum(-1)
        dist = torch.where(mask, torch.minimum(dist, d), dist)
        best = dist.amax(dim=1, keepdim=True)
        tied = dist >= best - tol
        cur = torch.where(tied, ar, n).amin(dim=1)
    return out


#: where ``stable_three_interpolate`` parks masked known points: 1e4 m away, a weight ~1e-8 of a neighbour's at 1 m
MASKED_KNOWN_AT = 1.0e4


def stable_three_interpolate(
    unknown: Tensor, known: Tensor, known_feat: Tensor, tol: float = FPS_TIE_TOL, known_mask: Tensor | None = None
) -> Tensor:
    """Inverse-squared-distance interpolation from 3 neighbours chosen without float-noise flips.

    Like PointNet++ FP (weights ``1 / (d^2 + 1e-8)``), but each neighbour is the lowest-index point
    among those within ``tol`` (m^2) of the nearest remaining distance, so equidistant grid neighbours
    are chosen the same way in a rotated copy of the scene.

    Args:
        unknown: [B, n, 3]; known: [B, m, 3]; known_feat: [B, m, C]; known_mask: [B, m] bool or None (all
            valid): a masked point is moved ``MASKED_KNOWN_AT`` away, chosen only where fewer than 3 remain,
            and then with a negligible weight.
    Returns:
        [B, n, C].
    Raises:
        ValueError: for bad shapes (a longer known_feat was read at the known points' indices, a batch of 1 or a
            [B, 1] mask broadcast).
    """
    check_interpolation_inputs(unknown, known, known_feat, known_mask)
    b, n, _ = unknown.shape
    m = known.shape[1]
    if m == 1:
        return known_feat.expand(b, n, known_feat.shape[-1])
    if known_mask is not None and not bool(known_mask.all()):
        known = torch.where(known_mask[..., None], known, known.new_tensor(MASKED_KNOWN_AT))
    dist_t, idx_t = _stable_three_nn(unknown.detach(), known.detach(), tol)
    # weights in at least float32: in float16 the 1e-8 rounds to 0, and a coincident point's weight was inf -> NaN
    wdtype = torch.promote_types(known_feat.dtype, torch.float32)
    recip = 1.0 / (dist_t.to(wdtype) + 1e-8)
    weight = recip / recip.sum(-1, keepdim=True)
    return weighted_gather3(known_feat, idx_t, weight.to(known_feat.dtype))


def _stable_three_nn(unknown: Tensor, known: Tensor, tol: float) -> tuple[Tensor, Tensor]:
    """(sq_dist [B, n, k] float64, idx [B, n, k]), k = min(3, m): the picks of ``stable_three_interpolate``."""
    kernel = point_kernel(unknown.device)
    if kernel is not None:
        dist, idx = kernel.stable_three_nn(unknown, known, tol)
        return dist, idx
    d = ((unknown.double()[:, :, None] - known.double()[:, None]) ** 2).sum(-1)  # [B, n, m]
    m = known.shape[1]
    ar = torch.arange(m, device=unknown.device)
    idx, dist = [], []
    for _ in range(min(3, m)):
        best = d.amin(dim=-1, keepdim=True)
        pick = torch.where(d <= best + tol, ar, m).amin(dim=-1, keepdim=True)  # [B, n, 1]
        idx.append(pick)
        dist.append(d.gather(-1, pick))
        d = d.scatter(-1, pick, float("inf"))
    return torch.cat(dist, -1), torch.cat(idx, -1)


def sample_levels(encoder: PointNet2Encoder, xyz: Tensor, mask: Tensor | None) -> list[Tensor | None]:
    """Tie-tolerant FPS indices for every level of ``encoder`` (drop-in for ``encoder.sample``)."""
    out: list[Tensor | None] = []
    cur, cur_mask = xyz, mask
    for sa in encoder.levels:
        if sa.group_all:
            out.append(None)
            break
        idx = tolerant_fps(cur, cur_mask, sa.npoint)
        out.append(idx)
        cur, cur_mask = torch.gather(cur, 1, idx[..., None].expand(-1, -1, 3)), None
    return out


#: ball-query radii are scaled by this so floor-grid points at exactly r (0.05 m grid, r = 0.2 m)
#: are inside whatever the float noise of the canonical transform
BALL_MARGIN = 1.0 + 1e-4


def plain_mlp(in_channels: int, widths: Sequence[int]) -> nn.Sequential:
    """Linear + ReLU per layer on [..., C_in] -> [..., widths[-1]] (identity when widths is empty)."""
    for w in widths:  # 2.5, True or -1 failed inside nn.Linear; 0 is refused by the models' check_layer_sizes
        check_integer("widths: a layer's width", w, 0, owner="plain_mlp")
    layers: list[nn.Module] = []
    c = in_channels
    for w in widths:
        layers += [nn.Linear(c, w), nn.ReLU()]
        c = w
    return nn.Sequential(*layers)


class CFARNet(nn.Module):
    """The CFAR predictor on canonical inputs.

    * local encoder: PointNet++ SSG on the canonical local cloud with the first ``feat_channels``
      scene features (channel 0 = target flag), ending in a group-all level: its pooled output
      ``g`` [B, C_g] is the global code (and the feature PFAL distils, ``L_shared``);
    * floor encoder: PointNet++ SSG on the canonical floor points + feature propagation back to
      every floor point;
    * robot MLP on the robot descriptor;
    * fusion/decoder: per floor point ``[floor feature, g, robot code, local context]`` -> MLP -> sigmoid,
      where the local context is the last local SA level's features interpolated (3-NN in the
      horizontal plane) at the floor point, giving each floor cell the nearby geometry.

    Args:
        feat_channels: scene feature channels used; robot_dim: robot descriptor size;
        local_npoints / local_radii / local_nsamples / local_mlps: SSG levels of the local encoder
            (one radius / nsample / width list per level); local_global_mlp: group-all widths (C_g = last);
        floor_npoints / floor_radii / floor_nsamples / floor_mlps: floor encoder levels;
        floor_fp_mlps: FP widths, deepest first (one per floor level);
        robot_mlp: robot MLP widths; head: decoder hidden widths.
        floor_encoder: ``set`` (paper: PointNet++ over the floor points, so a point's feature depends on
            the other points asked) or ``pointwise`` (each floor point encoded alone from Fourier features
            of its canonical xy: scores do not depend on which other queries are asked; a departure).
        floor_point_mlp / fourier_freqs: widths and number of octaves of the pointwise floor encoder.
        floor_feat_channels: extra per-floor-point input channels given to the decoder (``floor_feat`` of
            :meth:`logits`, e.g. the footprint occupancy of ``CFARModule(occupancy_input=True)``); 0 = none.
    """

    def __init__(
        self,
        feat_channels: int = 1,
        robot_dim: int = 2,
        local_npoints: Sequence[int] = (512, 128),
        local_radii: Sequence[float] = (0.1, 0.3),
        local_nsamples: Sequence[int] = (32, 32),
        local_mlps: Sequence[Sequence[int]] = ((32, 32, 64), (64, 64, 128)),
        local_global_mlp: Sequence[int] = (128, 256),
        floor_npoints: Sequence[int] = (256, 64),
        floor_radii: Sequence[float] = (0.2, 0.5),
        floor_nsamples: Sequence[int] = (16, 16),
        floor_mlps: Sequence[Sequence[int]] = ((32, 32, 64), (64, 64, 128)),
        floor_fp_mlps: Sequence[Sequence[int]] = ((128, 128), (128, 64)),
        robot_mlp: Sequence[int] = (32, 64),
        head: Sequence[int] = (256, 128),
        floor_encoder: str = "set",
        floor_point_mlp: Sequence[int] = (64, 64),
        fourier_freqs: int = 4,
        floor_feat_channels: int = 0,
    ) -> None:
        super().__init__()
        # int() cut 2.5 to 2 and read True as 1; a negative feat_channels dropped the last feature channels
        # (feat[..., :-1]) and a negative fourier_freqs failed inside nn.Linear
        for name, value in (
            ("floor_feat_channels", floor_feat_channels),
            ("feat_channels", feat_channels),
            ("fourier_freqs", fourier_freqs),
        ):
            check_integer(name, value, 0, owner="CFARNet")
        self.floor_feat_channels = int(floor_feat_channels)
        if not local_npoints or not floor_npoints:
            raise ValueError("CFARNet needs at least one local and one floor set-abstraction level")
        if not local_global_mlp:  # without the group-all level g was the first centre's features, silently
            raise ValueError("CFARNet: local_global_mlp needs at least one width (the global code g)")
        for name, radii in (("local_radii", local_radii), ("floor_radii", floor_radii)):
            for r in radii:  # before the margin's product: a text failed there ("can't multiply sequence")
                check_number(name, r, strict=True, owner="CFARNet")
        if floor_encoder not in ("set", "pointwise"):
            raise ValueError(f"CFARNet: floor_encoder must be 'set' or 'pointwise', got {floor_encoder!r}")
        self.floor_mode = floor_encoder
        self.fourier_freqs = int(fourier_freqs)
        self.feat_channels = feat_channels
        self.local_encoder = PointNet2Encoder(
            feat_channels,
            list(local_npoints),
            [[r * BALL_MARGIN] for r in local_radii],
            [[k] for k in local_nsamples],
            [[list(m)] for m in local_mlps],
            xyz_first=True,
            group_all_mlp=list(local_global_mlp),
        )
        self.floor_encoder = PointNet2Encoder(
            0,
            list(floor_npoints),
            [[r * BALL_MARGIN] for r in floor_radii],
            [[k] for k in floor_nsamples],
            [[list(m)] for m in floor_mlps],
            xyz_first=True,
        )
        if len(floor_fp_mlps) != len(floor_npoints):
            raise ValueError(f"floor_fp_mlps needs {len(floor_npoints)} entries (one per floor level)")
        ch = [3] + self.floor_encoder.level_channels[1:]  # level-0 skip = floor xyz
        self.floor_fp = nn.ModuleList()
        cur = ch[-1]
        for lvl, widths in zip(range(len(floor_npoints) - 1, -1, -1), floor_fp_mlps):
            fp = FeaturePropagation(ch[lvl] + cur, list(widths))
            self.floor_fp.append(fp)
            cur = fp.out_channels
        if floor_encoder == "pointwise":
            # the set encoder is not used: drop it so its weights neither train nor load
            self.floor_encoder, self.floor_fp = None, None
            self.floor_point = plain_mlp(2 + 4 * self.fourier_freqs, list(floor_point_mlp))
            cur = floor_point_mlp[-1] if floor_point_mlp else 2 + 4 * self.fourier_freqs
        # plain Linear+ReLU (no BatchNorm): one vector per sample, a batch of 1 must still train
        self.robot_mlp = plain_mlp(robot_dim, list(robot_mlp))
        self.global_channels = self.local_encoder.out_channels
        context_channels = self.local_encoder.level_channels[-2]
        fused = cur + self.global_channels + (robot_mlp[-1] if robot_mlp else robot_dim) + context_channels + 3
        fused += self.floor_feat_channels
        self.head = SharedMLP(fused, list(head))
        self.out = nn.Linear(head[-1] if head else fused, 1)

    def encode_local(
        self, xyz: Tensor, feat: Tensor, mask: Tensor
    ) -> tuple[Tensor, list[tuple[Tensor, Tensor | None]], list[Tensor | None]]:
        """Canonical cloud xyz [B,N,3], feat [B,N,C], mask [B,N] -> (g [B, C_g], all levels, per level 1..L its
        centre mask [B, S_l] (False on a repeated centre) or None: ``PointNet2Encoder.kept_masks``)."""
        fps = sample_levels(self.local_encoder, xyz, mask)
        srcs = self.local_encoder.sources(fps)
        levels = self.local_encoder(xyz, feat[..., : self.feat_channels], mask, fps, srcs)
        return levels[-1][1][:, 0], levels, self.local_encoder.kept_masks(srcs)

    def fourier(self, xy: Tensor) -> Tensor:
        """Canonical floor xy [B, M, 2] -> [B, M, 2 + 4F]: xy and sin/cos at F octaves (wavelengths 2 m, 1 m, ...)."""
        if self.fourier_freqs <= 0:
            return xy
        f = (2.0 ** torch.arange(self.fourier_freqs, device=xy.device, dtype=xy.dtype)) * (2 * math.pi / 2.0)
        ang = xy[..., None] * f  # [B, M, 2, F]
        return torch.cat([xy, torch.sin(ang).flatten(-2), torch.cos(ang).flatten(-2)], dim=-1)

    def encode_floor(self, floor_xyz: Tensor, floor_mask: Tensor) -> Tensor:
        """Per-floor-point features [B, M, C] from canonical floor points [B, M, 3] (mask [B, M])."""
        if self.floor_mode == "pointwise":
            return self.floor_point(self.fourier(floor_xyz[..., :2]))
        fps = sample_levels(self.floor_encoder, floor_xyz, floor_mask)
        srcs = self.floor_encoder.sources(fps)
        flv = self.floor_encoder(floor_xyz, None, floor_mask, fps, srcs)
        # level 0 = the floor points themselves (padding masked); deeper levels: a floor with fewer points than
        # centres repeats one, kept out of the batch statistics and the interpolation (in training its rows are 0)
        masks = [floor_mask] + self.floor_encoder.kept_masks(srcs)
        skips: list[Tensor | None] = [floor_xyz] + [f for _, f in flv[1:]]
        cur = flv[-1][1]
        n = len(flv) - 1
        for j, fp in enumerate(self.floor_fp):
            lvl = n - 1 - j
            interp = stable_three_interpolate(flv[lvl][0], flv[lvl + 1][0], cur, known_mask=masks[lvl + 1])
            skip = skips[lvl]
            h = interp if skip is None else torch.cat([skip, interp], dim=-1)
            cur = fp.mlp(h, masks[lvl])
        return cur

    def forward(
        self,
        xyz: Tensor,
        feat: Tensor,
        mask: Tensor,
        floor_xyz: Tensor,
        floor_mask: Tensor,
        robot: Tensor,
        floor_feat: Tensor | None = None,
    ) -> tuple[Tensor, Tensor]:
        """Canonical inputs -> (scores [B, M] in [0, 1], g [B, C_g]).

        xyz [B,N,3], feat [B,N,C], mask [B,N] (canonical local cloud), floor_xyz [B,M,3] (canonical),
        floor_mask [B,M], robot [B,R], floor_feat [B,M,floor_feat_channels] (None when 0 channels).
        """
        logits, g = self.logits(xyz, feat, mask, floor_xyz, floor_mask, robot, floor_feat)
        return torch.sigmoid(logits), g

    def logits(
        self,
        xyz: Tensor,
        feat: Tensor,
        mask: Tensor,
        floor_xyz: Tensor,
        floor_mask: Tensor,
        robot: Tensor,
        floor_feat: Tensor | None = None,
    ) -> tuple[Tensor, Tensor]:
        """As :meth:`forward`, before the sigmoid: (logits [B, M], g [B, C_g])."""
        m = floor_xyz.shape[1]
        check_floor_feat("CFARNet", floor_feat, floor_xyz, self.floor_feat_channels)
        g, levels, kept = self.encode_local(xyz, feat, mask)
        cur = self.encode_floor(floor_xyz, floor_mask)
        # local context: last SA level (before group-all), interpolated in the horizontal plane; a crop with fewer
        # points than the level's centres repeats one, which would fill several of the 3 neighbours
        cxyz, cfeat = levels[-2]
        flat = torch.tensor([1.0, 1.0, 0.0], device=floor_xyz.device, dtype=floor_xyz.dtype)
        ctx = stable_three_interpolate(floor_xyz * flat, cxyz * flat, cfeat, known_mask=kept[-2])
        rob = self.robot_mlp(robot)
        parts = [cur, g[:, None].expand(-1, m, -1), rob[:, None].expand(-1, m, -1), ctx, floor_xyz]
        z = torch.cat(parts + ([floor_feat.to(cur.dtype)] if floor_feat is not None else []), dim=-1)
        return self.out(self.head(z, floor_mask)).squeeze(-1), g
