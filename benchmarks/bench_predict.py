"""Single-sample predict latency as shipped, in interleaved rounds with the reference-style port.

Each round calls every model once (B = 1, 4,096 points, 1,024 floor points; the shipped configs' models in
eval mode under ``no_grad``, as ``floaff_zoo.predict`` calls them), in an order that rotates from
round to round. The figure is the median over rounds, with the 10th and 90th percentiles: the shared
machine moves single calls by up to 2x, and interleaving spreads that over every model alike. The reference
is each model itself, same weights and same input, on the reference-style port's ops
(``benchmarks/reference_pointnet2.py``'s ``reference_ops``: naive FPS, sort ball query and 3-NN), timed in
rounds of its own, half before and half after (one port call evicts the caches and slows the next call of
any model by ~10 %). The allocator is set as ``floaff_zoo.predict.resolve_model`` sets it (``--malloc
system`` leaves glibc's default).

    python benchmarks/bench_predict.py                       # 60 rounds, PointNet++ and CFAR
    python benchmarks/bench_predict.py --rounds 20 --models pointnet2_ssg votenet cfar_axisnet
    python benchmarks/bench_predict.py --device cuda         # on a GPU: each call ends with a synchronize
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import functools
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_models as bm  # noqa: E402  (this folder's helper: shipped configs, synthetic batches)

from floaff_zoo import runtime  # noqa: E402
from floaff_zoo.nn.ops import fps_backend  # noqa: E402

DEFAULT_MODELS = ["pointnet2_ssg", "cfar", "cfar_axisnet"]


def percentile(xs: list[float], q: float) -> float:
    """The q-quantile of xs (nearest rank)."""
    s = sorted(xs)
    return s[min(len(s) - 1, max(0, round(q * (len(s) - 1))))]


def callers(
    names: list[str], points: int, floor_cells: int, device: torch.device | None = None
) -> tuple[dict[str, Callable[[], None]], dict[str, Callable[[], None]]]:
    """(name -> a zero-argument predict call on ``device``, name -> the same model and input on the port's ops)."""
    device = device or torch.device("cpu")
    single = {k: v.to(device) if torch.is_tensor(v) else v for k, v in bm.make_batch(1, points, floor_cells).items()}
    sync = bm.synced(device)
    ref_mod = bm.load_reference()
    calls: dict[str, Callable[[], None]] = {}
    ports: dict[str, Callable[[], None]] = {}
    for name in names:
        torch.manual_seed(0)
        model = bm.build(name).eval().to(device)

        def call(model=model, ops=contextlib.nullcontext):
            with torch.no_grad(), ops():  # as floaff_zoo.predict runs the model
                model(single)
            sync()

        calls[name] = call
        ports[name] = functools.partial(call, copy.deepcopy(model), ref_mod.reference_ops)
    return calls, ports


def run_rounds(calls: dict[str, Callable[[], None]], rounds: int, warmup: int) -> dict[str, list[float]]:
    """Seconds per call, per name: ``rounds`` rounds, each calling every name once in a rotating order."""
    names = list(calls)
    for _ in range(warmup):
        for name in names:
            calls[name]()
    times: dict[str, list[float]] = {n: [] for n in names}
    for r in range(rounds):
        for name in names[r % len(names) :] + names[: r % len(names)]:
            t = time.perf_counter()
            calls[name]()
            times[name].append(time.perf_counter() - t)
    return times


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--models", nargs="*", default=DEFAULT_MODELS, choices=bm.MODELS)
    p.add_argument("--rounds", type=int, default=60)
    p.add_argument("--warmup", type=int, default=3)
    p.add_argument("--points", type=int, default=4096)
    p.add_argument("--floor-cells", type=int, default=32, help="floor grid side (32 -> 1024 floor points)")
    p.add_argument("--malloc", default="keep", choices=["keep", "system"], help="keep: as resolve_model sets it")
    p.add_argument("--device", default="cpu", help="torch device of the models and the batch, e.g. cuda")
    a = p.parse_args(argv)
    if a.rounds < 1:
        p.error("--rounds must be >= 1")
    if not a.models:
        p.error(f"--models: name at least one of {bm.MODELS}")
    if a.warmup < 0:
        p.error("--warmup must be >= 0")
    bm.require_positive(p, a, "points", "floor_cells")
    a.models = list(dict.fromkeys(a.models))  # a name given twice is timed once
    device = bm.parse_device(p, a.device)
    kept = runtime.keep_freed_memory() if a.malloc == "keep" else False
    calls, ports = callers(a.models, a.points, a.floor_cells, device)
    ref_rounds = max(1, a.rounds // 6)  # the port is ~5-10x slower: fewer calls give as steady a median
    before = run_rounds(ports, ref_rounds, 1)
    times = run_rounds(calls, a.rounds, a.warmup)
    after = run_rounds(ports, ref_rounds, 0)
    port_times = {n: before[n] + after[n] for n in ports}
    print(
        f"== predict B=1 x {a.points} points ({a.floor_cells**2} floor points), {a.rounds} interleaved rounds, "
        f"malloc {a.malloc} (kept: {kept}), torch {torch.__version__}, threads {torch.get_num_threads()}, "
        f"device {device}{' (' + torch.cuda.get_device_name(device) + ')' if device.type == 'cuda' else ''}, "
        f"FPS {fps_backend(device, a.points)}"
    )
    print(
        f"{'model':<16}{'median':>10}{'p10':>9}{'p90':>9}{'min':>9}   {'port ops':>9}"
        "   port ops median / model median (same model and input)"
    )
    for name, ts in times.items():
        ms = [1e3 * t for t in ts]
        port = statistics.median(port_times[name])
        print(
            f"{name:<16}{statistics.median(ms):7.1f} ms{percentile(ms, 0.1):6.1f} ms{percentile(ms, 0.9):6.1f} ms"
            f"{min(ms):6.1f} ms{1e3 * port:7.1f} ms   x{port / statistics.median(ts):5.2f}"
        )
    if "pointnet2_ssg" in times:  # the "CFAR no slower than PointNet++", per round
        for x in (m for m in a.models if m.startswith("cfar")):
            ratio = statistics.median(t / u for t, u in zip(times[x], times["pointnet2_ssg"]))
            print(f"{x} / pointnet2_ssg: median per-round time ratio {ratio:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
