"""Farthest point sampling on CUDA as one Triton kernel (the GPU counterpart of ``nn/_fps_ext.py``).

FPS is a chain of ``npoint`` dependent steps. The torch path runs each step as about ten small kernels, so
on a GPU a forward is bound by kernel launches: measured on an H200, 1,360 steps per PointNet++ forward made
training slower than on 16 CPU threads (``docs/performance.md``). Here one program per cloud keeps the cloud
and its running distances in registers and loops over the steps itself: one launch per FPS call.

The kernel serves both FPS variants of the zoo: exact FPS (``ops.farthest_point_sample``, ``tol = 0``: the
first index holding the largest distance) and CFAR's tie-tolerant FPS (``cfar.tolerant_fps``: the first index
within ``tol`` of it). Distances are ``(dx*dx + dy*dy) + dz*dz`` in float32 with FMA contraction disabled, as
the torch path and the C++ kernel round them, so the three give the same centres.

Triton ships with the CUDA builds of torch; where it is missing (CPU builds) ``available()`` is False and callers
keep the torch path, as they do with ``FLOAFF_ZOO_FPS_BACKEND=torch`` and, after one warning, where Triton is
installed but cannot compile or launch the kernel (a GPU or driver it does not support). ``TRITON_INTERPRET=1``
runs the kernel on CPU tensors (the tests use it).
"""

from __future__ import annotations

import os
import warnings

import torch
from torch import Tensor

from floaff_zoo.nn import _fps_ext

try:  # an optional dependency: present with CUDA builds of torch
    import triton
    import triton.language as tl
except ImportError:  # pragma: no cover - depends on the install
    triton = None

#: clouds larger than this keep the torch path (the kernel holds a whole cloud in one program's registers)
MAX_POINTS = 1 << 16

#: why the kernel could not run here (set by the first failed launch; the torch loop serves from then on)
_state: dict[str, str | None] = {"error": None}

#: whether Triton's CPU interpreter runs the kernel (``TRITON_INTERPRET=1`` when this module was imported: the
#: decorator reads it then), which serves CPU tensors too
INTERPRETED = os.environ.get("TRITON_INTERPRET", "0") not in ("", "0")


def available(xyz: Tensor) -> bool:
    """Whether the kernel serves ``xyz`` [B, N, 3]: Triton importable, a CUDA tensor (or the interpreter), eager.

    Raises:
        ValueError: for an unknown ``FLOAFF_ZOO_FPS_BACKEND`` (``torch`` keeps the torch path).
    """
    if triton is None or xyz.shape[1] > MAX_POINTS or torch.compiler.is_compiling():
        return False
    if _fps_ext.backend_requested() == "torch" or _state["error"] is not None:
        return False
    return xyz.is_cuda or INTERPRETED


if triton is not None:

    @triton.jit
    def _fps_kernel(xyz_ptr, mask_ptr, out_ptr, n, npoint, tol, BLOCK: tl.constexpr):
        """One cloud per program: xyz [3, N] (SoA) and mask [N] of cloud ``program_id`` -> out [npoint]."""
        cloud = tl.program_id(0).to(tl.int64)
        offs = tl.arange(0, BLOCK)
        inside = offs < n
        base = xyz_ptr + cloud * 3 * n
        x = tl.load(base + offs, mask=inside, other=0.0)
        y = tl.load(base + n + offs, mask=inside, other=0.0)
        z = tl.load(base + 2 * n + offs, mask=inside, other=0.0)
        valid = (tl.load(mask_ptr + cloud * n + offs, mask=inside, other=0) != 0) & inside
        # invalid points hold -1: min(-1, d) keeps them there and they never reach the maximum
        dist = tl.where(valid, 1e10, -1.0)
        far = tl.min(tl.where(valid, offs, BLOCK), axis=0)  # the first valid point
        for j in range(npoint):
            tl.store(out_ptr + cloud * npoint + j, far.to(tl.int64))
            dx = x - tl.load(base + far)
            dy = y - tl.load(base + n + far)
            dz = z - tl.load(base + 2 * n + far)
            d = (dx * dx + dy * dy) + dz * dz
            dist = tl.where(valid, tl.minimum(dist, d), dist)
            best = tl.max(dist, axis=0)
            far = tl.min(tl.where(dist >= best - tol, offs, BLOCK), axis=0)


def fps(xyz: Tensor, mask: Tensor, npoint: int, tol: float = 0.0) -> Tensor | None:
    """FPS from the first valid point, ties within ``tol`` (m^2) to the lowest index; None if the kernel cannot run.

    Args:
        xyz: [B, N, 3] on CUDA (any tensor under the interpreter); mask: [B, N] bool with a valid point per
            cloud (checked by the callers); npoint: centres; tol: 0 for exact FPS.
    Returns:
        [B, npoint] int64; a cloud with fewer valid points than ``npoint`` repeats its first valid point. None (with
        one warning, and ``available`` False from then on) when Triton cannot compile or launch it here: the caller
        runs the torch loop.
    """
    b, n, _ = xyz.shape
    soa = xyz.detach().float().transpose(1, 2).contiguous()  # [B, 3, N]: coalesced loads per coordinate
    out = torch.empty(b, npoint, dtype=torch.long, device=xyz.device)
    if b == 0 or npoint == 0:  # nothing to launch
        return out
    block = triton.next_power_of_2(max(n, 16))
    warps = min(32, max(4, block // 512))  # about 16 points per thread
    try:  # no FMA contraction: the same rounding as the torch path and the C++ kernel
        _fps_kernel[(b,)](soa, mask.to(torch.uint8).contiguous(), out, n, npoint, float(tol),
                          BLOCK=block, num_warps=warps, enable_fp_fusion=False)  # fmt: skip
    except Exception as exc:  # noqa: BLE001 - e.g. a GPU older than Triton supports: the torch loop serves
        _state["error"] = f"{type(exc).__name__}: {exc}"
        first_line = _state["error"].splitlines()[0][:200]
        warnings.warn(f"floaff_zoo: Triton FPS kernel unavailable, using the torch loop ({first_line})", stacklevel=3)
        return None
    return out
