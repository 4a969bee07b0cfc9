"""Where one training step of a shipped model spends its time: wall ms per step and the top ops (torch.profiler).

Each model is the shipped config (``configs/models/<name>.yaml``, as ``bench_models.py`` builds it) on a synthetic
batch; a step is its ``training_step`` loss, the backward pass and zeroed gradients, ended by a CUDA synchronize on
a GPU. After ``--warmup`` steps, ``--steps`` steps are timed without the profiler (the figure to compare), then one
step is profiled. On CUDA the table's footer gives that step's GPU-busy time and the report counts its kernel
launches: a step whose GPU-busy time is a small part of its wall time is bound by the host (Python, launches,
synchronizations), not the GPU. Compare ratios between models or settings of one run, not the absolute figures.

    python benchmarks/profile_step.py                                  # PointNet++ SSG and CFAR on the CPU
    python benchmarks/profile_step.py --device cuda --models cfar navaff --rows 20
    FLOAFF_ZOO_FPS_BACKEND=torch python benchmarks/profile_step.py --device cuda   # without the FPS kernels
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import torch
from torch.profiler import ProfilerActivity, profile

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_models as bm  # noqa: E402  (this folder's helper: shipped configs, synthetic batches)

from floaff_zoo.nn.ops import fps_backend  # noqa: E402

#: host-side calls that launch a kernel (torch's through the runtime, Triton's through the driver)
LAUNCH_CALLS = ("cudaLaunchKernel", "cudaLaunchKernelExC", "cuLaunchKernel", "cuLaunchKernelEx")
#: models whose ``training_step`` runs outside a Trainer (C2F-Exp is training-free)
TRAINABLE = [m for m in bm.MODELS if m not in ("c2f_exp", "cfar_axisnet")]


def make_step(model: torch.nn.Module, batch: dict, device: torch.device):
    """A zero-argument training step of ``model`` on ``batch``: loss, backward, zeroed gradients (synchronized)."""
    sync = bm.synced(device)

    def step() -> None:
        out = model.training_step(batch, 0)
        loss = out["loss"] if isinstance(out, dict) else out
        loss.backward()
        model.zero_grad(set_to_none=True)
        sync()

    return step


def profile_model(name: str, device: torch.device, batch: int, points: int, steps: int, warmup: int, rows: int) -> str:
    """The report of one model: ms per step over ``steps`` timed steps, then the profiled step's top ``rows`` ops."""
    torch.manual_seed(0)
    model = bm.build(name).train().to(device)
    data = {k: v.to(device) if torch.is_tensor(v) else v for k, v in bm.make_batch(batch, points, 32).items()}
    step = make_step(model, data, device)
    for _ in range(warmup):
        step()
    t = time.perf_counter()
    for _ in range(steps):
        step()
    per_step = (time.perf_counter() - t) / steps
    cuda = device.type == "cuda"
    with profile(activities=[ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else [])) as prof:
        step()
    events = prof.key_averages()
    lines = [f"== {name}: {per_step * 1e3:.1f} ms per step (B={batch} x {points} points, mean of {steps})"]
    if cuda:  # the table's footer gives the GPU-busy time ("Self CUDA time total")
        launches = sum(e.count for e in events if e.key in LAUNCH_CALLS)
        lines.append(f"profiled step: {launches} kernel launches")
    key = "self_cuda_time_total" if cuda else "self_cpu_time_total"
    lines.append(events.table(sort_by=key, row_limit=rows, max_name_column_width=50))
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--models", nargs="+", default=["pointnet2_ssg", "cfar"], choices=TRAINABLE)
    p.add_argument("--device", default="cpu", help="torch device, e.g. cuda")
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--points", type=int, default=4096)
    p.add_argument("--steps", type=int, default=5, help="timed steps (without the profiler)")
    p.add_argument("--warmup", type=int, default=3)
    p.add_argument("--rows", type=int, default=14, help="ops listed per model")
    a = p.parse_args(argv)
    if a.steps < 1 or a.warmup < 0:
        p.error("--steps must be >= 1 and --warmup >= 0")
    bm.require_positive(p, a, "batch", "points", "rows")
    device = bm.parse_device(p, a.device)
    print(
        f"torch {torch.__version__}, threads {torch.get_num_threads()}, device {device}, "
        f"FPS {fps_backend(device, a.points)}"
    )
    with warnings.catch_warnings():  # training_step logs; outside a Trainer Lightning warns on every call
        warnings.filterwarnings("ignore", message=".*self.trainer.* reference is not registered.*")
        warnings.filterwarnings("ignore", message=".*self.log.*")
        for name in a.models:
            print(profile_model(name, device, a.batch, a.points, a.steps, a.warmup, a.rows), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
