"""Pure-PyTorch point operations (CPU and GPU) used by every point network of the zoo.

Conventions: points are channels-last ``[B, N, 3]``, features ``[B, N, C]``, masks ``[B, N]``
bool (True = valid). Invalid (padded) points are never chosen as FPS centres, ball-query or kNN
neighbours, or interpolation sources: they get ``+inf`` distance.

Neighbour search always runs in float32 with autocast disabled, so bf16 autocast only touches the
MLPs (docs/background.md §6).
"""

from __future__ import annotations

import math
import os

import torch
from torch import Tensor

from floaff_zoo.checks import check_integer
from floaff_zoo.nn import _fps_ext

__all__ = [
    "ball_query",
    "ball_query_multi",
    "check_finite",
    "cpu_fast_paths",
    "extreme_over_dim",
    "farthest_point_sample",
    "farthest_point_sample_torch",
    "fps_backend",
    "gpu_fps_kernel",
    "index_points",
    "knn",
    "point_kernel",
    "square_distance",
    "three_interpolate",
    "three_nn",
    "weighted_gather3",
]

#: elements of a [B, S, N] distance/key matrix above which the torch ball query chunks over centres
_CHUNK_ELEMS = 1 << 24


def check_finite(name: str, x: Tensor) -> None:
    """Raise ``ValueError`` naming ``name`` when ``x`` holds NaN or Inf."""
    if x.is_floating_point() and not torch.isfinite(x).all():
        bad = int((~torch.isfinite(x)).sum())
        raise ValueError(f"{name} contains {bad} NaN/Inf value(s)")


def check_features(owner: str, name: str, feat: Tensor | None, xyz: Tensor, channels: int) -> None:
    """Raise ``ValueError`` unless ``feat`` is [B, N, channels] for points xyz [B, N, 3] (None allowed for 0
    channels): another width failed inside a Linear ("mat1 and mat2 shapes"), another N inside a gather or cat.
    Shapes only, no device sync."""
    want = [*xyz.shape[:2], channels]
    got = None if feat is None else list(feat.shape)
    if (feat is None and channels) or (feat is not None and got != want):
        raise ValueError(f"{owner}: {name} must be {want} for xyz {list(xyz.shape)}, got {got}")


def check_floor_feat(owner: str, floor_feat: Tensor | None, floor_xyz: Tensor, channels: int) -> None:
    """:func:`check_features` of the extra per-floor-point inputs of the nets that take them
    (``floor_feat_channels``; ``owner`` names the net), which also refuse any given to a net built without."""
    if not channels and floor_feat is not None:
        raise ValueError(f"{owner}: floor_feat given but the net was built with floor_feat_channels=0")
    check_features(owner, "floor_feat", floor_feat, floor_xyz, channels)


def check_points(name: str, xyz: Tensor) -> None:
    """Raise ``ValueError`` naming ``name`` unless ``xyz`` is [B, N, 3] (shape only: no device sync)."""
    if xyz.ndim != 3 or xyz.shape[-1] != 3:
        raise ValueError(f"{name} must be [B, N, 3], got {list(xyz.shape)}")


def _check_queries(name: str, queries: Tensor, cloud: Tensor) -> None:
    """``queries`` [B, S, 3] for the cloud [B, N, 3]: the same batch (the torch path broadcast a batch of 1 over B,
    the C++ kernels refused it)."""
    check_points(name, queries)
    if queries.shape[0] != cloud.shape[0]:
        raise ValueError(
            f"{name} must be [{cloud.shape[0]}, S, 3] for a batch of {cloud.shape[0]}, got {list(queries.shape)}"
        )


def full_mask(xyz: Tensor, mask: Tensor | None, name: str) -> Tensor:
    """``mask`` [B, N] as bool, all True for None; ``ValueError`` naming ``name`` for another shape."""
    if mask is None:
        return torch.ones(xyz.shape[:2], dtype=torch.bool, device=xyz.device)
    if mask.shape != xyz.shape[:2]:
        raise ValueError(f"{name} must be {list(xyz.shape[:2])}, got {list(mask.shape)}")
    return mask.bool()


def _distance_parts(src: Tensor, dst: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """fp32 pieces of ``square_distance``: (mm [B,N,M] = -2 src.dst, |src|^2 [B,N], |dst|^2 [B,M]).

    ``-2`` scales ``src`` before the matmul instead of the product after it: a power of two, so
    the result is bit-identical and saves one pass over the [B, N, M] matrix.
    """
    src2, ssq, dst, dsq = _direct_parts(src, dst)
    with torch.autocast(device_type=src.device.type, enabled=False):
        return torch.matmul(src2, dst.transpose(1, 2)), ssq, dsq


def _direct_parts(src: Tensor, dst: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """(-2 src [B, N, 3], |src|^2 [B, N], dst [B, M, 3], |dst|^2 [B, M]), fp32, contiguous, autocast off: the
    pieces of ``square_distance``, shared by the torch path (``_distance_parts``) and the C++ neighbour
    kernels, which compute the distances row by row without writing the [B, N, M] matrix.
    """
    with torch.autocast(device_type=src.device.type, enabled=False):
        src = src.float()
        dst = dst.float().contiguous()
        return (src * -2.0).contiguous(), torch.sum(src**2, -1).contiguous(), dst, torch.sum(dst**2, -1).contiguous()


def square_distance(src: Tensor, dst: Tensor) -> Tensor:
    """Squared Euclidean distances, float32, autocast off.

    Args:
        src: [B, N, 3]; dst: [B, M, 3].
    Returns:
        [B, N, M] = (-2 src.dst + |src|^2) + |dst|^2 (the classic PointNet++ formula and order).
    """
    mm, ssq, dsq = _distance_parts(src, dst)
    return mm.add_(ssq[:, :, None]).add_(dsq[:, None, :])


#: ``fast`` (default): CPU tensors take the CPU-only paths (C++ kernels, oneDNN calls, cache-sized chunks);
#: ``portable``: they take the device-independent torch code that CUDA runs, to check that path without a GPU
CPU_PATHS_ENV = "FLOAFF_ZOO_CPU_PATHS"


def portable_requested() -> bool:
    """Whether ``FLOAFF_ZOO_CPU_PATHS=portable`` asks CPU tensors to run the device-independent code.

    Raises:
        ValueError: for a value other than ``fast`` or ``portable``.
    """
    value = os.environ.get(CPU_PATHS_ENV, "fast").strip().lower() or "fast"
    if value not in ("fast", "portable"):
        raise ValueError(f"{CPU_PATHS_ENV}={value!r}: choose fast or portable")
    return value == "portable"


def cpu_fast_paths(device: torch.device) -> bool:
    """Whether CPU-only fast paths may serve tensors on ``device``: CPU, eager, not ``portable``.

    Under ``torch.compile`` the torch code is traced instead (a pybind or oneDNN call would break the graph).
    """
    return device.type == "cpu" and not torch.compiler.is_compiling() and not portable_requested()


def point_kernel(device: torch.device):
    """The C++ point kernels (``nn/_fps_ext.py``) where ``cpu_fast_paths(device)``, else None (torch path)."""
    if not cpu_fast_paths(device):
        return None
    return _fps_ext.load_kernel()


def extreme_over_dim(z: Tensor, dim: int, take_min: Tensor) -> tuple[Tensor, Tensor]:
    """Per channel the max over ``dim`` (the min where ``take_min``) and the index of its first occurrence.

    Args:
        z: [..., K, ..., C] with ``dim`` the K axis (not the last); take_min: [C] bool.
    Returns:
        (values, indices) shaped like z without ``dim``, as ``torch.max``/``torch.min`` give them
        (first extreme among ties, NaN wins). The C++ kernel reads z once; the torch path takes a
        max and, only when some channel wants it, a min.
    """
    dim = dim % z.ndim
    if dim == z.ndim - 1:
        raise ValueError("extreme_over_dim: dim must not be the channel (last) dim")
    kernel = point_kernel(z.device)
    differentiable = torch.is_grad_enabled() and z.requires_grad  # the kernel has no backward
    if kernel is not None and not differentiable and z.dtype in (torch.float32, torch.float64):
        vals, idx = kernel.extreme_over_dim(z.reshape(math.prod(z.shape[:dim]), z.shape[dim], -1), take_min)
        out_shape = z.shape[:dim] + z.shape[dim + 1 :]
        return vals.view(out_shape), idx.view(out_shape)
    vals, idx = z.max(dim=dim)
    if bool(take_min.any()):
        low, low_idx = z.min(dim=dim)
        vals, idx = torch.where(take_min, low, vals), torch.where(take_min, low_idx, idx)
    return vals, idx


def index_points(points: Tensor, idx: Tensor) -> Tensor:
    """Gather points/features by index.

    Args:
        points: [B, N, C]; idx: [B, *S] int64 in [0, N).
    Returns:
        [B, *S, C]. Uses ``torch.gather`` (fast backward) when gradients flow, advanced indexing
        (faster forward) otherwise.
    Raises:
        ValueError: for points not [B, N, C] or idx of another B (advanced indexing broadcast a batch of 1 over the
            other's B, and the gather path regrouped the indices into B rows).
    """
    b = points.shape[0]
    if points.ndim != 3 or idx.ndim < 1 or idx.shape[0] != b:
        raise ValueError(
            f"index_points: points must be [B, N, C] and idx [B, ...] of the same B, got points "
            f"{list(points.shape)}, idx {list(idx.shape)}"
        )
    if points.requires_grad and torch.is_grad_enabled():
        flat = idx.reshape(b, -1)
        out = torch.gather(points, 1, flat[..., None].expand(-1, -1, points.shape[-1]))
        return out.reshape(*idx.shape, points.shape[-1])
    batch = torch.arange(b, device=points.device).view(b, *([1] * (idx.ndim - 1)))
    return points[batch, idx]


# ----------------------------------------------------------------------------- FPS
def fps_backend(device: str | torch.device = "cpu", points: int = 1) -> str:
    """Which FPS implementation ``farthest_point_sample`` uses on ``device`` right now, for clouds of ``points``
    points (N, padding included).

    ``cpp`` (the C++ kernel) or ``torch`` on the CPU; ``triton`` (``nn/_fps_triton.py``, where Triton is installed)
    or ``torch`` on CUDA: the Triton kernel serves clouds of up to ``_fps_triton.MAX_POINTS`` points, larger ones
    take the torch loop.
    """
    device = torch.device(device)
    if device.type != "cpu":
        probe = torch.empty(1, int(points), 3, device=device)
        return "triton" if gpu_fps_kernel(probe) is not None else "torch"
    # farthest_point_sample skips the kernel under FLOAFF_ZOO_CPU_PATHS=portable
    return "cpp" if not portable_requested() and _fps_ext.load_kernel() is not None else "torch"


def gpu_fps_kernel(xyz: Tensor):
    """The Triton FPS module (``nn/_fps_triton.py``) where it serves ``xyz`` (CUDA, Triton installed), else None.

    Imported on first use: Triton's import costs ~0.2 s, which CPU-only processes need not pay.
    """
    if not xyz.is_cuda and os.environ.get("TRITON_INTERPRET", "0") in ("", "0"):
        return None
    from floaff_zoo.nn import _fps_triton

    return _fps_triton if _fps_triton.available(xyz) else None


def _fps_prepare(xyz: Tensor, mask: Tensor | None, npoint: int) -> Tensor:
    check_points("xyz", xyz)
    check_integer("npoint", npoint, 1, owner="farthest_point_sample")  # 2.5 was cut to 2 by the kernels
    mask = full_mask(xyz, mask, "mask")
    counts = mask.sum(dim=1)
    if (counts == 0).any():
        bad = torch.nonzero(counts == 0).flatten().tolist()
        raise ValueError(f"farthest_point_sample: cloud(s) {bad} of the batch have no valid point")
    return mask


@torch.no_grad()
def farthest_point_sample_torch(xyz: Tensor, mask: Tensor | None, npoint: int) -> Tensor:
    """Vectorised pure-torch FPS (structure-of-arrays loop over ``npoint``); see ``farthest_point_sample``."""
    mask = _fps_prepare(xyz, mask, npoint)
    pts = xyz.detach().float().transpose(1, 2).contiguous()  # [B, 3, N] SoA
    x, y, z = pts[:, 0], pts[:, 1], pts[:, 2]
    b, n = mask.shape
    dist = torch.where(mask, torch.full_like(x, 1e10), torch.full_like(x, -1.0))
    out = torch.empty(b, npoint, dtype=torch.long, device=xyz.device)
    far = mask.long().argmax(dim=1)  # first valid index (0 when valid)
    d = torch.empty_like(x)
    tmp = torch.empty_like(x)
    for j in range(npoint):
        out[:, j] = far
        c = far[:, None]
        torch.sub(x, x.gather(1, c), out=d)
        d.mul_(d)
        # separate mul/add (no FMA) so the sums round exactly like the C++ kernel
        torch.sub(y, y.gather(1, c), out=tmp)
        d.add_(tmp.mul_(tmp))
        torch.sub(z, z.gather(1, c), out=tmp)
        d.add_(tmp.mul_(tmp))
        # invalid points keep -1 (never the argmax while a valid point exists)
        torch.where(dist < 0, dist, torch.minimum(dist, d), out=dist)
        far = dist.argmax(dim=1)
    return out


@torch.no_grad()
def farthest_point_sample(xyz: Tensor, mask: Tensor | None, npoint: int) -> Tensor:
    """Exact farthest point sampling, deterministic start at the first valid point (index 0 if valid).

    Padded points are never selected. When a cloud has fewer valid points than ``npoint``, the
    remaining centres repeat valid points (all distances are 0, so the lowest-index valid point
    is repeated): this documented fallback keeps shapes static; the result is still a valid
    subset with duplicates.

    Args:
        xyz: [B, N, 3]; mask: [B, N] bool or None (all valid); npoint: number of centres.
    Returns:
        [B, npoint] int64 indices into N.
    Raises:
        ValueError: when a cloud has no valid point, or shapes are wrong.
    """
    mask = _fps_prepare(xyz, mask, npoint)
    # the kernel also under torch.compile: an unrolled loop of ``npoint`` steps would swamp the graph
    kernel = _fps_ext.load_kernel() if xyz.device.type == "cpu" and not portable_requested() else None
    if kernel is not None:
        return kernel.fps_forward(xyz.detach().float().contiguous(), mask.contiguous(), int(npoint))
    gpu = gpu_fps_kernel(xyz)
    out = gpu.fps(xyz, mask, int(npoint)) if gpu is not None else None  # CUDA: one launch, not ~10 per centre
    return out if out is not None else farthest_point_sample_torch(xyz, mask, npoint)


# ----------------------------------------------------------------------------- neighbours
def ball_query(radius: float, nsample: int, xyz: Tensor, new_xyz: Tensor, mask: Tensor | None = None) -> Tensor:
    """First ``nsample`` valid points (in index order) within ``radius`` of each centre.

    Same output as the classic sort-based query (``idx[d > r^2] = N; sort; [:K]``; pad with the
    first neighbour), computed by the C++ selection kernel on CPU (one scan per centre that stops
    at K hits) or else with ``topk`` on an index key (4x faster than the sort). A centre with no
    valid point in its ball (possible only for centres not drawn from ``xyz``) falls back to its
    nearest valid point.

    Args:
        radius: ball radius (m); nsample: K; xyz: [B, N, 3]; new_xyz: [B, S, 3]; mask: [B, N].
    Returns:
        [B, S, K] int64 indices into N.
    """
    return ball_query_multi([radius], [nsample], xyz, new_xyz, mask)[0]


def ball_query_multi(
    radii: list[float], nsamples: list[int], xyz: Tensor, new_xyz: Tensor, mask: Tensor | None = None
) -> list[Tensor]:
    """``ball_query`` for several (radius, K) pairs sharing one distance matrix (MSG levels).

    The torch path chunks over centres so the [B, S, N] matrices stay below ~16 M elements; the C++ path
    computes one centre's distance row at a time (same rounding as ``square_distance``, except for tiny
    products, at most ~16 points on one side, which torch's matmul may round an ulp apart: a tie can then
    pick another neighbour).

    Returns:
        one [B, S, K_i] int64 tensor per scale.
    Raises:
        ValueError: for a radius that is negative or NaN or a K below 1, a cloud without a valid point, bad shapes.
    """
    check_points("xyz", xyz)
    _check_queries("new_xyz", new_xyz, xyz)
    if len(radii) != len(nsamples):
        raise ValueError(f"radii {radii} and nsamples {nsamples} differ in length")
    # squared, a negative radius was the ball of its absolute value; a NaN one held no point (nearest fallback)
    if not all(float(r) >= 0 for r in radii):
        raise ValueError(f"ball_query: every radius must be >= 0, got {list(radii)}")
    for k in nsamples:  # K = 0: [B, S, 0] on the torch path, an error in the C++ kernel; 2.5 was cut to 2
        check_integer("nsample", k, 1, owner="ball_query")
    mask = full_mask(xyz, mask, "mask")
    if not mask.any(dim=1).all():
        raise ValueError("ball_query: a cloud of the batch has no valid point")
    b, n, _ = xyz.shape
    s = new_xyz.shape[1]
    kernel = point_kernel(xyz.device)
    if kernel is not None and len(radii) <= 8:  # the kernel's scan counts hits for at most 8 scales
        # per centre: its distance row (never the [B, S, N] matrix), one scan for every scale, stopping at K hits
        r2 = [float(r) ** 2 for r in radii]
        return list(kernel.ball_direct(*_direct_parts(new_xyz, xyz), mask.contiguous(), r2, [int(k) for k in nsamples]))
    chunk = max(1, _CHUNK_ELEMS // max(1, b * n))
    parts: list[list[Tensor]] = [[] for _ in radii]
    ar = torch.arange(n, device=xyz.device, dtype=torch.long)
    all_valid = not torch.compiler.is_compiling() and bool(mask.all())  # no data-dependent branch in graphs
    for start in range(0, s, chunk):
        sqr = square_distance(new_xyz[:, start : start + chunk], xyz)  # [B, s, N]
        if not all_valid:
            sqr = sqr.masked_fill_(~mask[:, None, :], float("inf"))
        nearest = None
        for i, (radius, nsample) in enumerate(zip(radii, nsamples)):
            key = torch.where(sqr <= radius**2, ar, n)  # out-of-ball -> N (sorted last)
            k = min(nsample, n)
            idx = key.topk(k, dim=-1, largest=False, sorted=True).values
            first = idx[..., :1]
            empty = first == n
            if empty.any():
                nearest = sqr.argmin(dim=-1, keepdim=True) if nearest is None else nearest
                first = torch.where(empty, nearest, first)
            idx = torch.where(idx == n, first, idx)
            if k < nsample:
                idx = torch.cat([idx, first.expand(-1, -1, nsample - k)], dim=-1)
            parts[i].append(idx)
    return [p[0] if len(p) == 1 else torch.cat(p, dim=1) for p in parts]


def knn(k: int, xyz: Tensor, new_xyz: Tensor, mask: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """k nearest valid neighbours of each query point.

    Args:
        k: neighbours; xyz: [B, N, 3]; new_xyz: [B, S, 3]; mask: [B, N].
    Returns:
        (sq_dist [B, S, k] ascending, idx [B, S, k]). When fewer than k points are valid the
        tail repeats the nearest neighbour (distance repeated too).
    Raises:
        ValueError: for k below 1 (0 gave [B, S, 0], a negative k failed inside ``topk``), bad shapes.
    """
    if int(k) < 1:
        raise ValueError(f"knn: k must be >= 1, got {k}")
    check_points("xyz", xyz)
    _check_queries("new_xyz", new_xyz, xyz)
    mask = full_mask(xyz, mask, "mask")
    if not mask.any(dim=1).all():
        raise ValueError("knn: a cloud of the batch has no valid point")
    sqr = square_distance(new_xyz, xyz).masked_fill(~mask[:, None, :], float("inf"))
    kk = min(k, xyz.shape[1])
    dist, idx = sqr.topk(kk, dim=-1, largest=False, sorted=True)
    bad = torch.isinf(dist)
    if bad.any():
        dist = torch.where(bad, dist[..., :1], dist)
        idx = torch.where(bad, idx[..., :1], idx)
    if kk < k:
        dist = torch.cat([dist, dist[..., :1].expand(-1, -1, k - kk)], dim=-1)
        idx = torch.cat([idx, idx[..., :1].expand(-1, -1, k - kk)], dim=-1)
    return dist, idx


def three_nn(unknown: Tensor, known: Tensor, known_mask: Tensor | None = None) -> tuple[Tensor, Tensor]:
    """Three nearest valid known points of every unknown point.

    Returns:
        (sq_dist [B, n, 3] from the picks' coordinate differences, never below 0, idx [B, n, 3]); with fewer
        than 3 valid known points the missing
        slots get distance ``inf`` (zero interpolation weight) and index 0. The distances carry no gradient on
        any path (the C++ kernel has none), so a model whose known points are learned (VoteNet's votes) trains
        the same on CPU, CUDA and the portable path.
    """
    dist, idx = _three_nn_search(unknown, known, known_mask)
    # the picks' distances again from coordinate differences: the search's expanded |a|^2 - 2 a.b + |b|^2 goes below
    # 0 for (near-)coincident points, and inverse-distance weights then took both signs and cancelled (features 1, 2
    # and 3 interpolated to -776 on one path, 1.10 on the other), as the official kernel's differences cannot
    picked = index_points(known.detach().float(), idx)  # [B, n, 3, 3]
    exact = ((unknown.detach().float()[:, :, None] - picked) ** 2).sum(-1)
    return torch.where(torch.isinf(dist), dist, exact), idx


def _three_nn_search(unknown: Tensor, known: Tensor, known_mask: Tensor | None) -> tuple[Tensor, Tensor]:
    """``three_nn``'s picks by the expanded distance (C++ kernel or torch): (sq_dist [B, n, 3], idx [B, n, 3])."""
    check_points("known", known)
    _check_queries("unknown", unknown, known)
    masked = known_mask is not None
    known_mask = full_mask(known, known_mask, "known_mask")  # checked: a [1, m] mask was broadcast on the torch path
    kernel = point_kernel(unknown.device)
    if kernel is not None:
        return tuple(kernel.three_nn_direct(*_direct_parts(unknown, known), known_mask.contiguous()))
    sqr = square_distance(unknown.detach(), known.detach())  # no gradient, as in the C++ kernel
    if masked:
        sqr = sqr.masked_fill(~known_mask[:, None, :], float("inf"))
    k = min(3, known.shape[1])
    # three passes of min, each taking the lowest index among equal distances as the C++ kernel does (topk orders
    # ties arbitrarily: on a regular floor grid ~9 % of points got other neighbours on CUDA than on the CPU)
    work, dists, picks = sqr, [], []  # sqr is this call's own tensor: overwritten in place, no copy
    for _ in range(k):
        d, i = work.min(dim=-1)
        dists.append(d)
        picks.append(i)
        work.scatter_(-1, i[..., None], float("inf"))
    dist, idx = torch.stack(dists, dim=-1), torch.stack(picks, dim=-1)
    if k < 3:
        pad = 3 - k
        dist = torch.cat([dist, dist.new_full((*dist.shape[:2], pad), float("inf"))], dim=-1)
        idx = torch.cat([idx, idx.new_zeros((*idx.shape[:2], pad))], dim=-1)
    idx = torch.where(torch.isinf(dist), torch.zeros_like(idx), idx)
    return dist, idx


def three_interpolate(unknown: Tensor, known: Tensor, known_feat: Tensor, known_mask: Tensor | None = None) -> Tensor:
    """Inverse-squared-distance interpolation from the 3 nearest known points (PointNet++ FP).

    Weights are ``1 / (d^2 + 1e-8)`` normalised, ``d^2`` the squared distance (as the classic
    PyTorch port), taken from the coordinate differences of the 3 picks (never below 0). A single known point is
    broadcast. A sample with no valid known point (an all-padding cloud) interpolates to 0, not NaN (0 / 0), without
    asking the device whether one exists.

    Args:
        unknown: [B, n, 3]; known: [B, m, 3]; known_feat: [B, m, C]; known_mask: [B, m].
    Returns:
        [B, n, C] in ``known_feat``'s dtype.
    Raises:
        ValueError: for bad shapes, among them known_feat not [B, m, C] for known [B, m, 3] (a longer one was read
            at the known points' indices), and a known cloud of no point.
    """
    check_interpolation_inputs(unknown, known, known_feat, known_mask)
    b, n, _ = unknown.shape
    if known.shape[1] == 1:  # the mask checked here too: a [1, 1] one was broadcast over the batch
        feat = known_feat if known_mask is None else torch.where(known_mask.bool()[..., None], known_feat, 0.0)
        return feat.expand(b, n, known_feat.shape[-1])
    dist, idx = three_nn(unknown, known, known_mask)
    recip = 1.0 / (dist + 1e-8)  # inf distance -> weight 0
    # a valid pick's weight is >= 1 / (d^2 + 1e-8), far above ``tiny``: the clamp only turns 0 / 0 into 0
    weight = recip / recip.sum(dim=-1, keepdim=True).clamp_min(torch.finfo(recip.dtype).tiny)
    return weighted_gather3(known_feat, idx, weight.to(known_feat.dtype))


def check_interpolation_inputs(unknown: Tensor, known: Tensor, known_feat: Tensor, known_mask: Tensor | None) -> None:
    """Raise ``ValueError`` naming the argument unless unknown [B, n, 3], known [B, m, 3] (m >= 1), known_feat
    [B, m, C] and known_mask [B, m] or None fit together (shape checks only: no device sync)."""
    check_points("known", known)
    _check_queries("unknown", unknown, known)
    if known.shape[1] == 0:
        raise ValueError(f"known must hold at least one point, got {list(known.shape)}")
    if known_feat.ndim != 3 or known_feat.shape[:2] != known.shape[:2]:
        b, m = known.shape[:2]
        raise ValueError(f"known_feat must be [{b}, {m}, C] for known [{b}, {m}, 3], got {list(known_feat.shape)}")
    if known_mask is not None and known_mask.shape != known.shape[:2]:
        raise ValueError(f"known_mask must be {list(known.shape[:2])}, got {list(known_mask.shape)}")


def weighted_gather3(feat: Tensor, idx: Tensor, weight: Tensor) -> Tensor:
    """``sum_k weight[..., k] * feat[idx[..., k]]``: the gather and weighted sum of 3-NN interpolation.

    Args:
        feat: [B, m, C]; idx: [B, n, 3] int64 in [0, m); weight: [B, n, 3] in feat's dtype.
    Returns:
        [B, n, C]. Without gradients on CPU (fp32/64, eager) one C++ pass that never writes the
        [B, n, 3, C] gathered tensor and sums in torch's order (bit for bit, tested); else gather + sum.
    Raises:
        ValueError: for weight not of idx's shape (the torch path broadcast a [B, 1, 3] one) or bad shapes.
    """
    if feat.ndim != 3 or idx.ndim != 3 or idx.shape[0] != feat.shape[0] or weight.shape != idx.shape:
        raise ValueError(
            f"weighted_gather3: need feat [B, m, C], idx [B, n, k], weight [B, n, k], got feat {list(feat.shape)}, "
            f"idx {list(idx.shape)}, weight {list(weight.shape)}"
        )
    kernel = point_kernel(feat.device)
    if (
        kernel is not None
        and not (torch.is_grad_enabled() and (feat.requires_grad or weight.requires_grad))
        and feat.dtype in (torch.float32, torch.float64)
        and weight.dtype == feat.dtype
        and idx.shape[-1] == 3
    ):
        return kernel.weighted_gather3(feat.contiguous(), idx.contiguous(), weight.contiguous())
    grouped = index_points(feat, idx)  # [B, n, k, C]
    return (grouped * weight[..., None]).sum(dim=2)
