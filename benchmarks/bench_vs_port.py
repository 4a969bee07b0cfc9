"""Training throughput of each learned model as the zoo runs it vs the reference-style port, with the allocator.

``bench_models.py --vs-reference`` times a model on the zoo's ops and on the port's ops in one process,
so both share one allocator: that ratio is the code's alone. ``floaff-zoo`` also sets glibc's malloc to
keep freed memory (``floaff_zoo.runtime``), which a standalone port does not. This script times, per
model, four fresh processes (one per configuration, alternating over ``--rounds``), same weights and
batch (B = 8 x 4096 synthetic points, forward, loss, backward, Adam step):

    port, system malloc | port, kept memory | zoo, system malloc | zoo, kept memory (as ``floaff-zoo`` runs)

and prints samples/s (best round's median step) with three ratios against the port under the system
allocator: zoo code only (same allocator), allocator only, and as shipped; plus zoo/port with both on
kept memory. Absolute numbers move with machine load; compare ratios measured in one run.

    python benchmarks/bench_vs_port.py                          # every learned model, 2 rounds
    python benchmarks/bench_vs_port.py --models pointnet2_ssg --rounds 1 --iters 2
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
LEARNED = ["pointnet2_ssg", "pointnet2_msg", "votenet", "h3dnet", "navaff", "n2m", "cfar"]
#: (key, ops, FLOAFF_ZOO_MALLOC)
CONFIGS = [("port_system", "port", "system"), ("port_kept", "port", "keep"), ("zoo_system", "zoo", "system"),
           ("zoo_kept", "zoo", "keep")]  # fmt: skip


def child(model: str, ops: str, iters: int, warmup: int, threads: int | None) -> dict:
    """Time ``iters`` training steps of ``model`` in this process (malloc set from the environment)."""
    import importlib.util

    import torch

    from floaff_zoo import runtime

    kept = runtime.keep_freed_memory()
    if threads:
        torch.set_num_threads(threads)
    spec = importlib.util.spec_from_file_location("bench_models", HERE / "bench_models.py")
    bm = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bm)
    batch = bm.make_batch(8, 4096, 32)
    torch.manual_seed(0)
    net = bm.build(model)
    net.train()
    opt = torch.optim.Adam(net.parameters(), lr=1e-4)
    ctx = bm.load_reference().reference_ops if ops == "port" else contextlib.nullcontext

    def step():
        opt.zero_grad(set_to_none=True)
        loss, _, _ = net.model_step(batch)
        loss.backward()
        opt.step()

    with ctx():
        ts = bm.timed(step, iters, warmup)
    return {"sps": batch["scene_xyz"].shape[0] / statistics.median(ts), "kept": kept}


def run_config(model: str, ops: str, malloc: str, a: argparse.Namespace) -> dict:
    cmd = [sys.executable, __file__, "--child", model, ops, "--iters", str(a.iters), "--warmup", str(a.warmup)]
    if a.threads:
        cmd += ["--threads", str(a.threads)]
    env = dict(os.environ, FLOAFF_ZOO_MALLOC=malloc)
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"{model} {ops} {malloc}: child failed:\n{proc.stderr[-2000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--models", nargs="*", default=LEARNED, choices=LEARNED)
    p.add_argument("--rounds", type=int, default=2, help="passes over the four configurations (best kept)")
    p.add_argument("--iters", type=int, default=3)
    p.add_argument("--warmup", type=int, default=1)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--child", nargs=2, metavar=("MODEL", "OPS"), help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.rounds < 1 or a.iters < 1 or a.warmup < 0 or not a.models:
        p.error("--rounds and --iters must be >= 1, --warmup >= 0 and --models must name a model")
    if a.threads is not None and a.threads < 1:  # 0 ran on torch's default silently, -1 failed in every child
        p.error(f"--threads must be >= 1, got {a.threads}")
    if a.child:
        print(json.dumps(child(a.child[0], a.child[1], a.iters, a.warmup, a.threads)))
        return 0
    print(
        "train samples/s, B=8 x 4096 points; port = the model on benchmarks/reference_pointnet2.py's ops; "
        f"best of {a.rounds} round(s), each the median of {a.iters} steps, one fresh process per configuration"
    )
    print(
        f"{'model':<14} {'port sys':>9} {'port kept':>9} {'zoo sys':>9} {'zoo kept':>9}   "
        f"{'code':>6} {'alloc':>6} {'shipped':>7} {'zoo/port kept':>13}"
    )
    for model in a.models:
        best: dict[str, float] = {}
        for _ in range(a.rounds):
            for key, ops, malloc in CONFIGS:
                r = run_config(model, ops, malloc, a)
                if malloc == "keep" and not r["kept"]:
                    raise RuntimeError("keep_freed_memory() was not applied (not glibc?): nothing to compare")
                best[key] = max(best.get(key, 0.0), r["sps"])
        base = best["port_system"]
        print(
            f"{model:<14} {base:9.2f} {best['port_kept']:9.2f} {best['zoo_system']:9.2f} {best['zoo_kept']:9.2f}   "
            f"x{best['zoo_system'] / base:5.2f} x{best['port_kept'] / base:5.2f} x{best['zoo_kept'] / base:6.2f} "
            f"x{best['zoo_kept'] / best['port_kept']:12.2f}",
            flush=True,
        )
    print(
        "code = zoo sys / port sys (the ops alone); alloc = port kept / port sys (the allocator alone); "
        "shipped = zoo kept / port sys (floaff-zoo vs a standalone port)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
