"""Speed of the zoo's point models on CPU, with a reference-style PointNet++ measured in the same run.

Prints, per model (shipped ``configs/models/<name>.yaml`` sizes): parameters, train samples/s
(B = 8 x 4096 points: forward, loss, backward, Adam step) and single-sample predict latency
(eval, ``inference_mode``). Then the PointNet++ parity/speed check against
``benchmarks/reference_pointnet2.py`` (Conv2d layout, sort ball query, naive FPS): same weights and
FPS indices -> max |difference| of the outputs, and throughput ratios per mode (fp32 eager, bf16,
compile, compile + bf16). Absolute numbers move with machine load; the ratios carry over.

    python benchmarks/bench_models.py --quick            # few iterations, no compile modes
    python benchmarks/bench_models.py --models navaff n2m --iters 5
    python benchmarks/bench_models.py --modes eager bf16 compile compile_bf16 --skip-models
    python benchmarks/bench_models.py --skip-models --skip-reference --vs-reference pointnet2_ssg cfar
"""

from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import statistics
import sys
import time
from pathlib import Path

import torch
import yaml

ROOT = Path(__file__).resolve().parents[1]
MODELS = ["pointnet2_ssg", "pointnet2_msg", "votenet", "h3dnet", "navaff", "n2m", "c2f_exp", "cfar", "cfar_axisnet"]
#: pseudo-model: the shipped CFAR config as deployed, its yaw from a (shipped-size) AxisNet snapped to the
#: kitchen's axes (``eval_yaw_source: axisnet_manhattan``), so predict latency includes AxisNet
WITH_AXISNET = {"cfar_axisnet": "cfar"}
#: PointNet++ SSG of the layout study in docs/background.md §6 (1 M parameters class)
SEG = dict(
    in_channels=1,
    npoints=[1024, 256, 64],
    radii=[[0.1], [0.2], [0.4]],
    nsamples=[[32], [32], [32]],
    mlps=[[[64, 64, 128]], [[128, 128, 256]], [[256, 384, 512]]],
    fp_mlps=[[256, 256], [256, 128], [128, 128, 128]],
    head=[],
    xyz_first=True,
)


def load_reference():
    spec = importlib.util.spec_from_file_location("reference_pointnet2", ROOT / "benchmarks" / "reference_pointnet2.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def require_positive(parser: argparse.ArgumentParser, args: argparse.Namespace, *names: str) -> None:
    """``parser.error`` naming the first of the size flags ``names`` (dest names) given a value < 1 (None: unset);
    they ended in tracebacks (an empty batch, set_num_threads(0)) instead."""
    for name in names:
        value = getattr(args, name)
        if value is not None and value < 1:
            parser.error(f"--{name.replace('_', '-')} must be >= 1, got {value}")


def parse_device(parser: argparse.ArgumentParser, value: str) -> torch.device:
    """``--device value`` as a torch device; a name torch does not know, a device type the benchmarks do not time
    (``meta``, ``mps``: they failed deep in the first model call), CUDA without a device or a CUDA index past the
    last device ends ``parser``."""
    try:
        device = torch.device(value)
    except RuntimeError as exc:
        parser.error(f"--device {value!r}: not a torch device ({exc})")
    if device.type not in ("cpu", "cuda"):
        parser.error(f"--device {value!r}: the benchmarks run on cpu or cuda, not {device.type}")
    if device.type == "cuda" and not torch.cuda.is_available():
        parser.error(f"--device {value!r}: torch sees no CUDA device here")
    if device.type == "cuda" and device.index is not None and device.index >= torch.cuda.device_count():
        parser.error(f"--device {value!r}: torch sees {torch.cuda.device_count()} CUDA device(s) here")
    return device


def synced(device: torch.device):
    """What ends a timed call on ``device``: a CUDA synchronize (kernels run asynchronously), nothing on the CPU."""
    return (lambda: torch.cuda.synchronize(device)) if device.type == "cuda" else (lambda: None)


def make_batch(b: int, n: int, floor_cells: int):
    from floaff_zoo.contract import collate_samples
    from floaff_zoo.data.synthetic import make_synthetic_sample

    return collate_samples([make_synthetic_sample(i, num_points=n, floor_cells=floor_cells) for i in range(b)])


def _config(name: str) -> tuple[type, dict]:
    """(model class, init_args) of the shipped config ``configs/models/<name>.yaml``."""
    cfg = yaml.safe_load((ROOT / "configs" / "models" / f"{name}.yaml").read_text())["model"]
    mod_name, cls_name = cfg["class_path"].rsplit(".", 1)
    return getattr(importlib.import_module(mod_name), cls_name), cfg.get("init_args") or {}


def _accepted(cls: type) -> set[str]:
    import inspect

    return set(inspect.signature(cls.__init__).parameters)


def build(name: str, **overrides):
    """The shipped config's model; overrides the class does not take (e.g. ``bf16`` for CFAR) are dropped."""
    if name in WITH_AXISNET:
        return build_with_axisnet(WITH_AXISNET[name], **overrides)
    cls, init_args = _config(name)
    accepted = _accepted(cls)
    return cls(**{**init_args, **{k: v for k, v in overrides.items() if k in accepted}})


def runs_in_mode(name: str, mode: str) -> bool:
    """Whether ``name``'s model class takes the options ``mode`` asks for (``bf16``, ``compile``); a row of a model
    that does not runs eager fp32 and says so."""
    accepted = _accepted(_config(WITH_AXISNET.get(name, name))[0])
    return all(opt in accepted for opt in ("bf16", "compile") if opt in mode)


def build_with_axisnet(name: str, **overrides):
    """``name``'s shipped config with an untrained shipped-size AxisNet (exported to a temp dir) for its yaw."""
    import tempfile

    torch.manual_seed(1)
    axis = build("axisnet")
    with tempfile.TemporaryDirectory() as tmp:
        axis.save_pretrained(tmp)
        torch.manual_seed(0)
        return build(name, axisnet=tmp, eval_yaw_source="axisnet_manhattan", **overrides)


#: single-sample predict calls timed per model (at least)
PREDICT_ITERS = 15


def timed(fn, iters: int, warmup: int) -> list[float]:
    for _ in range(warmup):
        fn()
    out = []
    for _ in range(iters):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return out


def fmt(ts: list[float]) -> str:
    return f"min {1e3 * min(ts):8.1f} ms  median {1e3 * statistics.median(ts):8.1f} ms"


def bench_model(name: str, batch, single, iters: int, warmup: int, mode: str) -> dict:
    torch.manual_seed(0)
    model = build(name, bf16="bf16" in mode, compile="compile" in mode)
    params = sum(p.numel() for p in model.parameters())
    res = {"name": name, "mode": mode, "params": params}
    if model.trainable:
        opt = torch.optim.Adam(model.parameters(), lr=1e-4)
        model.train()

        def step():
            opt.zero_grad(set_to_none=True)
            loss, _, _ = model.model_step(batch)
            loss.backward()
            opt.step()

        ts = timed(step, iters, warmup)
        res["train_sps"] = batch["scene_xyz"].shape[0] / statistics.median(ts)
        res["train"] = ts
    model.eval()

    def pred():
        with torch.inference_mode():
            model(single)

    ts = timed(pred, max(iters, PREDICT_ITERS), warmup)  # cheap: more calls make the median robust to load
    res["predict"] = ts
    res["predict_ms"] = 1e3 * statistics.median(ts)
    res["predict_min_ms"] = 1e3 * min(ts)
    return res


def bench_model_vs_reference(name: str, batch, single, iters: int, warmup: int) -> dict:
    """One model on the zoo's ops and on the port's ops (``reference_ops``), same weights and inputs.

    Returns the max |difference| of the eval outputs (B=1 and the batch) and both train throughputs.
    """
    import copy

    ref_mod = load_reference()
    torch.manual_seed(0)
    ours = build(name)
    ref = copy.deepcopy(ours)
    res = {"name": name}
    for m in (ours, ref):
        m.eval()
    with torch.inference_mode():
        a1, a8 = ours(single), ours(batch)
        with ref_mod.reference_ops():
            b1, b8 = ref(single), ref(batch)
    res["diff"] = max((a1 - b1).abs().max().item(), (a8 - b8).abs().max().item())
    if not ours.trainable:
        return res
    steps = {}
    for key, model, ctx in (("ours", ours, contextlib.nullcontext), ("ref", ref, ref_mod.reference_ops)):
        model.train()
        opt = torch.optim.Adam(model.parameters(), lr=1e-4)

        def step(model=model, opt=opt, ctx=ctx):
            with ctx():
                opt.zero_grad(set_to_none=True)
                loss, _, _ = model.model_step(batch)
                loss.backward()
                opt.step()

        steps[key] = step
        for _ in range(warmup):
            step()
    # interleaved (ours, ref, ours, ref, ...): both see the same machine load; the ratio is the median of
    # the per-round ratios, so a slow spell that hits one round moves neither side alone
    times: dict[str, list[float]] = {"ours": [], "ref": []}
    for _ in range(iters):
        for key in ("ours", "ref"):
            times[key] += timed(steps[key], 1, 0)
    b = batch["scene_xyz"].shape[0]
    res["ours_sps"] = b / statistics.median(times["ours"])
    res["ref_sps"] = b / statistics.median(times["ref"])
    res["ratios"] = sorted(r / o for o, r in zip(times["ours"], times["ref"], strict=True))
    return res


def bench_reference(n: int, b: int, iters: int, warmup: int, modes: list[str]) -> None:
    from floaff_zoo.nn.ops import fps_backend
    from floaff_zoo.nn.pointnet2 import PointNet2Seg

    ref_mod = load_reference()
    torch.manual_seed(0)
    ref = ref_mod.RefPointNet2Seg(**SEG)
    ours = PointNet2Seg(**SEG)
    ref_mod.convert_to_channels_last(ref, ours)
    g = torch.Generator().manual_seed(0)
    xyz = torch.rand(b, n, 3, generator=g)
    xyz[..., 2] *= 0.3
    feat = torch.randn(b, n, 1, generator=g)
    target = torch.rand(b, n, generator=g)
    fps = ours.encoder.sample(xyz, None)
    ref.eval()
    ours.eval()
    with torch.no_grad():
        diff = (ref(xyz, feat, fps) - ours(xyz, feat, None, fps)).abs().max().item()
    print(
        f"\n== PointNet++ SSG ({sum(p.numel() for p in ours.parameters()) / 1e6:.3f} M params), B={b} x {n} points, "
        f"FPS backend {fps_backend()}"
    )
    print(f"parity (same weights + FPS indices, eval, fp32): max |ref - ours| = {diff:.2e}")

    def train_step(model, opt, fwd):
        def step():
            opt.zero_grad(set_to_none=True)
            loss = torch.nn.functional.binary_cross_entropy_with_logits(fwd(), target)
            loss.backward()
            opt.step()

        return step

    ref.train()
    opt = torch.optim.Adam(ref.parameters(), 1e-4)
    ts_ref = timed(train_step(ref, opt, lambda: ref(xyz, feat)), iters, warmup)  # naive FPS inside, as the port
    ref.eval()
    with torch.inference_mode():
        lat_ref = timed(lambda: ref(xyz[:1], feat[:1]), max(iters, 3), warmup)
    sps_ref = b / statistics.median(ts_ref)
    print(
        f"reference (Conv2d, sort, naive FPS)  train {sps_ref:6.2f} samples/s ({fmt(ts_ref)}); "
        f"predict B=1 {1e3 * statistics.median(lat_ref):7.1f} ms"
    )
    for mode in modes:
        torch.manual_seed(0)
        net = PointNet2Seg(**SEG)
        if "compile" in mode:
            net.compile()
        bf16 = "bf16" in mode

        def fwd(x=xyz, f=feat, net=net, bf16=bf16):  # bound now: the closure runs inside this iteration only
            idx = net.encoder.sample(x, None)  # FPS outside compile/autocast
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
                return net(x, f, None, idx).float()

        net.train()
        opt = torch.optim.Adam(net.parameters(), 1e-4)
        t0 = time.perf_counter()
        train_step(net, opt, fwd)()
        first = time.perf_counter() - t0
        ts = timed(train_step(net, opt, fwd), iters, max(0, warmup - 1))
        net.eval()
        with torch.inference_mode():
            lat = timed(lambda: fwd(xyz[:1], feat[:1]), max(iters, 3), warmup + (1 if "compile" in mode else 0))
        sps = b / statistics.median(ts)
        print(
            f"ours {mode:<13} first step {first:5.1f} s  train {sps:6.2f} samples/s ({fmt(ts)}) "
            f"x{sps / sps_ref:4.2f} vs reference; predict B=1 {1e3 * statistics.median(lat):7.1f} ms "
            f"(x{statistics.median(lat_ref) / statistics.median(lat):4.2f})"
        )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--quick", action="store_true", help="2 timed iterations, 1 warm-up, eager modes only")
    p.add_argument("--models", nargs="*", default=MODELS, choices=MODELS)
    p.add_argument("--skip-models", action="store_true", help="only the reference comparison")
    p.add_argument("--skip-reference", action="store_true")
    p.add_argument("--modes", nargs="*", default=None, choices=["eager", "bf16", "compile", "compile_bf16"])
    p.add_argument("--model-mode", default="eager", choices=["eager", "bf16", "compile", "compile_bf16"])
    p.add_argument("--batch", type=int, default=8)
    p.add_argument("--points", type=int, default=4096)
    p.add_argument("--floor-cells", type=int, default=32, help="floor grid side (32 -> 1024 floor points)")
    p.add_argument("--iters", type=int, default=None)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--warmup", type=int, default=1, help="untimed calls before timing (compile modes add one)")
    p.add_argument(
        "--points-sweep",
        type=int,
        nargs="*",
        default=[],
        help="also time --sweep-models at these cloud sizes (how time grows with points)",
    )
    p.add_argument(
        "--vs-reference",
        nargs="*",
        default=[],
        choices=MODELS,
        help="also time these models against themselves on the reference port's ops (slow: the port is)",
    )
    p.add_argument("--sweep-models", nargs="*", default=None, choices=MODELS, help="default: pointnet2_ssg cfar")
    a = p.parse_args(argv)
    if not a.models:
        p.error(f"--models: name at least one of {MODELS}")
    if a.iters is not None and a.iters < 1:
        p.error("--iters must be >= 1")
    if a.warmup < 1:  # ours always has an untimed first step: the reference needs one too to be timed fairly
        p.error("--warmup must be >= 1")
    require_positive(p, a, "batch", "points", "floor_cells", "threads")
    if any(n < 1 for n in a.points_sweep):  # an empty cloud failed deep in make_batch, after the models' timings
        p.error(f"--points-sweep sizes must be >= 1, got {a.points_sweep}")
    if a.sweep_models is not None and not a.points_sweep:  # was ignored without a word
        p.error("--sweep-models names the models of --points-sweep; give --points-sweep too")
    if a.points_sweep and a.sweep_models == []:  # a heading over no row, exit 0
        p.error(f"--sweep-models: name at least one of {MODELS} for --points-sweep")
    a.sweep_models = ["pointnet2_ssg", "cfar"] if a.sweep_models is None else a.sweep_models
    if a.skip_models and a.skip_reference and not (a.vs_reference or a.points_sweep):  # printed a version line, exit 0
        p.error("nothing to time: --skip-models and --skip-reference without --vs-reference or --points-sweep")
    if a.threads:
        torch.set_num_threads(a.threads)
    iters = a.iters or (2 if a.quick else 5)
    warmup = a.warmup
    modes = a.modes or (["eager", "bf16"] if a.quick else ["eager", "bf16", "compile", "compile_bf16"])
    print(
        f"torch {torch.__version__}, threads {torch.get_num_threads()}, cpu {torch.backends.cpu.get_cpu_capability()}"
    )
    if not a.skip_models:
        batch = make_batch(a.batch, a.points, a.floor_cells)
        single = make_batch(1, a.points, a.floor_cells)
        print(
            f"\n== models, mode {a.model_mode}: train B={a.batch} x {a.points} points "
            f"({a.floor_cells**2} floor points), predict B=1"
        )
        for name in a.models:
            r = bench_model(name, batch, single, iters, warmup, a.model_mode)
            train = (
                f"train {r['train_sps']:6.2f} samples/s ({fmt(r['train'])})" if "train_sps" in r else "training-free"
            )
            eager = "" if runs_in_mode(name, a.model_mode) else f" [no {a.model_mode} option: eager fp32]"
            print(
                f"{name:<14} {r['params'] / 1e6:7.3f} M params  {train}; predict {r['predict_ms']:7.1f} ms "
                f"(median of {len(r['predict'])}, min {r['predict_min_ms']:.1f}){eager}",
                flush=True,
            )
    if a.vs_reference:
        batch = make_batch(a.batch, a.points, a.floor_cells)
        single = make_batch(1, a.points, a.floor_cells)
        ref_iters = max(a.iters or 0, 5)
        print(
            f"\n== every model vs itself on the reference port's ops (benchmarks/reference_pointnet2.py "
            f"reference_ops: naive FPS, sort ball query and 3-NN, Conv + BN layout), same weights; "
            f"train B={a.batch} x {a.points} points, eval outputs compared at B=1 and B={a.batch}; "
            f"{ref_iters} interleaved rounds, x = median per-round ratio (range min-max)"
        )
        for name in a.vs_reference:
            r = bench_model_vs_reference(name, batch, single, ref_iters, warmup)
            line = f"{name:<14} outputs max |ours - ref| = {r['diff']:.1e}"
            if "ours_sps" in r:
                line += (
                    f"; train ours {r['ours_sps']:6.2f} samples/s, reference-style {r['ref_sps']:6.2f} samples/s: "
                    f"x{statistics.median(r['ratios']):.2f} ({r['ratios'][0]:.2f}-{r['ratios'][-1]:.2f})"
                )
            print(line, flush=True)
    if a.points_sweep:
        print(
            f"\n== growth with points, mode {a.model_mode}: train B={a.batch}, predict B=1, "
            f"{a.floor_cells**2} floor points"
        )
        for name in a.sweep_models:
            base = None
            for n in a.points_sweep:
                r = bench_model(
                    name,
                    make_batch(a.batch, n, a.floor_cells),
                    make_batch(1, n, a.floor_cells),
                    iters,
                    warmup,
                    a.model_mode,
                )
                base = base or (n, r.get("train_sps"), r["predict_ms"])
                rel = f" (x{base[1] / r['train_sps']:.2f} step time vs {base[0]} points)" if r.get("train_sps") else ""
                train = f"train {r['train_sps']:6.2f} samples/s{rel}" if "train_sps" in r else "training-free"
                print(f"{name:<14} {n:6d} points  {train}; predict {r['predict_ms']:7.1f} ms", flush=True)
    if not a.skip_reference:
        bench_reference(a.points, a.batch, iters, warmup, modes)
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT / "src"))
    sys.exit(main())
