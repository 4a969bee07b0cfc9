"""The Triton FPS kernel (what CUDA runs) against the torch path, through Triton's CPU interpreter.

The interpreter is chosen when Triton's decorator runs, so the checks run in a fresh process with
``TRITON_INTERPRET=1``; ``tests/test_devices.py`` runs the compiled kernel where there is a GPU.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import warnings

import pytest
import torch

from floaff_zoo.nn import _fps_triton, cfar, ops

pytest.importorskip("triton")

CHECKS = textwrap.dedent(
    """
    import math, os
    import torch
    from floaff_zoo.nn import _fps_triton, cfar, ops

    assert _fps_triton.INTERPRETED
    g = torch.Generator().manual_seed(0)

    def reference(fn, *args):
        # the torch loops: no C++ kernel, no Triton
        os.environ["FLOAFF_ZOO_FPS_BACKEND"] = "torch"
        os.environ["FLOAFF_ZOO_CPU_PATHS"] = "portable"
        try:
            return fn(*args)
        finally:
            del os.environ["FLOAFF_ZOO_FPS_BACKEND"], os.environ["FLOAFF_ZOO_CPU_PATHS"]

    # exact FPS: padded first points, a cloud with fewer valid points than centres, a non-power-of-two N
    xyz = torch.rand(3, 700, 3, generator=g)
    mask = torch.rand(3, 700, generator=g) > 0.3
    mask[0, :5] = False
    mask[2] = False
    mask[2, [9, 300, 650]] = True
    for npoint in (1, 64, 200):
        got = _fps_triton.fps(xyz, mask, npoint)
        want = reference(ops.farthest_point_sample_torch, xyz, mask, npoint)
        assert torch.equal(got, want), npoint
        assert mask.gather(1, got).all()
    # the C++ kernel's centres too, where it builds
    assert torch.equal(_fps_triton.fps(xyz, mask, 64), ops.farthest_point_sample(xyz, mask, 64))

    # tie-tolerant FPS on a regular floor grid (almost every step a tie), and on a rotated copy of it
    side = torch.arange(24, dtype=torch.float32) * 0.1
    grid = torch.stack([*torch.meshgrid(side, side, indexing="ij"), torch.zeros(24, 24)], -1).reshape(1, -1, 3)
    grid_mask = torch.ones(1, 576, dtype=torch.bool)
    got = _fps_triton.fps(grid, grid_mask, 48, cfar.FPS_TIE_TOL)
    assert torch.equal(got, reference(cfar.tolerant_fps, grid, grid_mask, 48))
    turned = cfar.rotate_z(cfar.rotate_z(grid, torch.tensor([0.7])), torch.tensor([-0.7]))
    assert torch.equal(_fps_triton.fps(turned, grid_mask, 48, cfar.FPS_TIE_TOL), got)

    # dispatch: the portable path of both FPS variants calls the kernel once each
    calls = []
    kernel = _fps_triton.fps
    _fps_triton.fps = lambda *a: calls.append(a) or kernel(*a)
    os.environ["FLOAFF_ZOO_CPU_PATHS"] = "portable"
    assert torch.equal(ops.farthest_point_sample(xyz, mask, 64), kernel(xyz, mask, 64))
    assert torch.equal(cfar.tolerant_fps(grid, grid_mask, 48), got)
    assert len(calls) == 2, len(calls)
    print("triton fps ok")
    """
)


def test_the_triton_kernel_picks_the_torch_paths_centres(root):
    env = {**os.environ, "TRITON_INTERPRET": "1", "OMP_NUM_THREADS": "1"}
    env.pop("FLOAFF_ZOO_FPS_BACKEND", None)
    env.pop("FLOAFF_ZOO_CPU_PATHS", None)
    done = subprocess.run(
        [sys.executable, "-c", CHECKS], cwd=root, env=env, capture_output=True, text=True, timeout=600
    )
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-4000:]
    assert "triton fps ok" in done.stdout


def test_the_kernel_serves_cuda_tensors_only(monkeypatch):
    """Without the interpreter a CPU cloud keeps the CPU paths; a cloud past MAX_POINTS or the torch switch too."""
    monkeypatch.setattr(_fps_triton, "INTERPRETED", False)  # as in a process that did not ask for the interpreter
    assert not _fps_triton.available(torch.zeros(1, 64, 3))
    assert ops.fps_backend("cpu") in ("cpp", "torch")  # the CPU never reports the GPU kernel
    monkeypatch.setattr(_fps_triton, "INTERPRETED", True)
    assert _fps_triton.available(torch.zeros(1, 64, 3))
    assert not _fps_triton.available(torch.zeros(1, _fps_triton.MAX_POINTS + 1, 3))
    monkeypatch.setenv("FLOAFF_ZOO_FPS_BACKEND", "torch")
    assert not _fps_triton.available(torch.zeros(1, 64, 3))
    monkeypatch.delenv("FLOAFF_ZOO_FPS_BACKEND")
    # the label of another device (meta stands in for CUDA, served here by the interpreter) is per cloud size: a
    # cloud past the kernel's cap takes the torch loop, which the label said was Triton
    monkeypatch.setenv("TRITON_INTERPRET", "1")
    assert ops.fps_backend("meta") == ops.fps_backend("meta", _fps_triton.MAX_POINTS) == "triton"
    assert ops.fps_backend("meta", _fps_triton.MAX_POINTS + 1) == "torch"
    monkeypatch.setenv("FLOAFF_ZOO_FPS_BACKEND", "trition")
    with pytest.raises(ValueError, match="FLOAFF_ZOO_FPS_BACKEND='trition'"):
        _fps_triton.available(torch.zeros(1, 64, 3))


class _BrokenLaunch:
    """Stands in for the jitted kernel where Triton cannot compile it (``kernel[grid](...)`` raises)."""

    def __getitem__(self, grid):
        def launch(*args, **kwargs):
            raise RuntimeError("PTX .version 8.7 does not support .target sm_60\nmore")

        return launch


def test_a_kernel_that_cannot_run_falls_back_to_the_torch_loop_once(monkeypatch):
    """Triton installed but unable to compile for the GPU: one warning, the torch loop's centres, no second try."""
    monkeypatch.setattr(_fps_triton, "INTERPRETED", True)  # lets a CPU tensor reach the kernel
    monkeypatch.setenv("TRITON_INTERPRET", "1")
    monkeypatch.setenv("FLOAFF_ZOO_CPU_PATHS", "portable")  # no C++ kernel in front of it
    monkeypatch.setattr(_fps_triton, "_fps_kernel", _BrokenLaunch())
    monkeypatch.setitem(_fps_triton._state, "error", None)
    xyz = torch.rand(2, 300, 3, generator=torch.Generator().manual_seed(3))
    mask = torch.ones(2, 300, dtype=torch.bool)
    assert _fps_triton.available(xyz)
    with pytest.warns(UserWarning, match=r"Triton FPS kernel unavailable, using the torch loop \(RuntimeError: PTX"):
        got = ops.farthest_point_sample(xyz, mask, 32)
    assert torch.equal(got, ops.farthest_point_sample_torch(xyz, mask, 32))
    assert not _fps_triton.available(xyz) and "sm_60" in _fps_triton._state["error"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # remembered: neither a second launch nor a second warning
        assert torch.equal(ops.farthest_point_sample(xyz, mask, 32), got)
        tolerant = cfar.tolerant_fps(xyz, mask, 16)
    monkeypatch.setenv("FLOAFF_ZOO_FPS_BACKEND", "torch")
    assert torch.equal(tolerant, cfar.tolerant_fps(xyz, mask, 16))
