"""Loader throughput vs a PointNet++ training step (samples/s), on the same machine.

Usage::

    python benchmarks/bench_loader.py                      # synthetic MoMa-Kitchen-sized data in a temp dir
    python benchmarks/bench_loader.py --root data/moma_kitchen --max-samples 512
    python benchmarks/bench_loader.py --dataset floaff --root data/floaff_sim
    python benchmarks/bench_loader.py --epoch-start        # the cost of restarting the train workers each epoch

Without ``--root`` it writes ``--samples`` samples in the official MoMa-Kitchen layout with the
official cloud sizes (16,647 global / 10,701 floor points) into a temp dir. It reports:
1. the cold setup (parse PLY/CSV + KD-tree flags, building the cache) in samples/s;
2. the warm loader (cache hits, YawPerturb + Jitter, collate to ``--num-points``) in samples/s;
3. a PointNet++ training step (forward + backward + Adam) on batches from that loader, in samples/s:
   ``floaff_zoo.models.pointnet2.PointNet2Module`` when it exists, else the SSG
   ``floaff_zoo.nn.pointnet2.PointNet2Seg`` per-point regressor on the scene cloud (printed).
The target is loader >= 5x the train step.

With ``--epoch-start`` it times instead the start of a train epoch (creating the iterator and getting its first
batch) over ``--epoch-start-epochs`` epochs, with ``--epoch-start-workers`` workers started anew every epoch (as the
data modules' train loader does, for an exact resume) and persistent ones, under the ``fork`` and ``spawn`` start
methods, in interleaved epochs; it prints the medians, their ratio and each epoch's whole loading time.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from floaff_zoo.names import BENCHMARKS


def write_moma_like(root: Path, n: int, seed: int = 0) -> None:
    """n samples (n // 4 configurations x 4 views) in the official layout, official cloud sizes; the test split lists
    them again under other scene ids."""
    import open3d as o3d

    from floaff_zoo.data import moma_kitchen as mk

    rng = np.random.default_rng(seed)

    def ply(path: Path, xyz: np.ndarray) -> None:
        pcd = o3d.geometry.PointCloud()
        pcd.points = o3d.utility.Vector3dVector(xyz)
        path.parent.mkdir(parents=True, exist_ok=True)
        o3d.io.write_point_cloud(str(path), pcd)

    lines = []
    for i in range(n):
        cfg = f"RGBD-{100000 + i // 4 % 6}-target_1_bottle#1_barrier_01"
        rel = f"{cfg}/position_{i}.0_1.0_0_orientation_0.0_0.0_1.0_6.123233995736766e-17"
        d = root / "rgbd" / rel / mk.PCD_DIR
        floor = np.c_[rng.uniform(0, 3, (mk.FLOOR_MAX, 2)), rng.uniform(0, 0.015, mk.FLOOR_MAX)]
        target = np.array([1.6, 0.3, 0.9]) + rng.normal(scale=0.03, size=(300, 3))
        barrier = np.array([1.7, -0.3, 0.9]) + rng.normal(scale=0.03, size=(200, 3))
        rest = rng.uniform([0, -2, 0], [3, 2, 2], (mk.GLOBAL_MAX - 500 - 8000, 3))
        ply(d / mk.GLOBAL_PLY, np.concatenate([floor[:8000], rest, target, barrier]))
        ply(d / mk.FLOOR_PLY, floor)
        ply(d / mk.TARGET_PLY, target)
        ply(d / mk.BARRIER_PLY[0], barrier)
        np.savetxt(
            root / "rgbd" / rel / mk.LABEL_TXT, np.c_[floor, rng.uniform(0, 1, mk.FLOOR_MAX)], delimiter=",", fmt="%.6f"
        )
        info = root / "info" / cfg[5:] / mk.INFO_JSON
        info.parent.mkdir(parents=True, exist_ok=True)
        info.write_text(json.dumps({"robot_name": "panda"}))
        lines.append(rel)
    # the test split lists the same samples under other scene ids (links to the train folders): it is parsed as its
    # own split, and the data module refuses a test split that shares a scene with the train split
    test = [rel.replace("RGBD-1", "RGBD-2", 1) for rel in lines]
    for cfg in sorted({rel.split("/")[0] for rel in lines}):
        (root / "rgbd" / cfg.replace("RGBD-1", "RGBD-2", 1)).symlink_to(cfg)
        (root / "info" / ("2" + cfg[6:])).symlink_to(cfg[5:])
    (root / "data_split").mkdir(parents=True, exist_ok=True)
    for split, rels in (("train", lines), ("test", test)):
        (root / "data_split" / f"kitchen_{split}.txt").write_text("\n".join(rels) + "\n")


def make_dm(args: argparse.Namespace, root: Path, cache_dir: Path):
    """The data module under test, its sample cache in ``cache_dir`` (a fresh one per run: a cache left in the
    dataset folder made every later 'cold' setup a cache hit)."""
    from floaff_zoo.data.transforms import Jitter, YawPerturb

    common = dict(
        batch_size=args.batch_size,
        num_workers=args.workers,
        num_points=args.num_points,
        collate_mode="resample",
        train_transforms=[YawPerturb(5.0), Jitter(0.005)],
        cache=True,
        cache_dir=str(cache_dir),
    )
    if args.dataset == "moma":
        from floaff_zoo.data.moma_kitchen import MoMaKitchenDataModule

        return MoMaKitchenDataModule(root=str(root), val_fraction=0.0, max_samples=args.max_samples, **common)
    from floaff_zoo.data.floaff_kitchen import FloAffKitchenDataModule

    return FloAffKitchenDataModule(root=str(root), benchmark=args.benchmark, **common)


def preload_readers() -> None:
    """Import what the readers import on first use (open3d for the PLY files, scipy's KD-tree for MoMa-Kitchen's
    flags): a one-off of the process (about 0.6 s, a quarter of a 16-sample setup) that the cold setup otherwise
    timed as parsing whenever ``--root`` was given (writing the synthetic samples imported open3d before)."""
    import open3d  # noqa: F401
    from scipy.spatial import cKDTree  # noqa: F401


def loader_rate(dm, epochs: int) -> tuple[float, list]:
    loader = dm.train_dataloader()
    n, batches = 0, []
    t = time.perf_counter()
    for _ in range(epochs):
        for b in loader:
            n += b["scene_xyz"].shape[0]
            if len(batches) < 3:
                batches.append(b)
    return n / (time.perf_counter() - t), batches


def _timed_epoch(loader) -> tuple[float, float]:
    """(seconds to the first batch, seconds to the end) of one epoch of ``loader``, from the iterator's creation."""
    t = time.perf_counter()
    it = iter(loader)
    next(it)
    first = time.perf_counter() - t
    for _ in it:
        pass
    return first, time.perf_counter() - t


def epoch_start_times(dm, workers: int, epochs: int, method: str) -> dict[str, list[tuple[float, float]]]:
    """``_timed_epoch`` of each epoch for the data module's train loader with its workers started anew every epoch
    (``restarted``, as shipped) and with ``persistent`` ones, under the start method ``method``; the two alternate
    epoch by epoch, so a change of machine load reaches both. Both loaders are the shipped one with only the
    workers, their persistence and the start method set (the same dataset, sampler, collate and generator)."""
    from torch.utils.data import DataLoader

    base = dm.train_dataloader()
    loaders = {
        mode: DataLoader(
            base.dataset,
            batch_size=base.batch_size,
            sampler=base.sampler,
            num_workers=workers,
            persistent_workers=mode == "persistent",
            collate_fn=base.collate_fn,
            generator=base.generator,
            multiprocessing_context=method,
        )
        for mode in ("restarted", "persistent")
    }
    times: dict[str, list[tuple[float, float]]] = {mode: [] for mode in loaders}
    for _ in range(epochs):
        for mode, loader in loaders.items():
            times[mode].append(_timed_epoch(loader))
    del loaders  # the persistent workers end with their loader
    return times


def report_epoch_start(dm, workers: int, epochs: int, methods: list[str]) -> None:
    """Print, per start method, the epoch-start medians (epochs after the first: the persistent loader's first one
    starts its workers, once per fit, printed apart), their ratio restarted / persistent, and the medians of the
    epoch's whole loading time, whose difference is the restart's cost per epoch (the first batch waits for one
    worker only: the others' start falls in the rest of the epoch)."""
    n = len(dm.datasets["train"])
    batches = -(-n // dm.batch_size)
    print(
        f"\nepoch start (iterator + first batch), {workers} workers, batch {dm.batch_size}, {n} train samples "
        f"({batches} batches); medians over epochs 2-{epochs}, restarted and persistent epochs interleaved"
    )
    for method in methods:
        if method not in multiprocessing.get_all_start_methods():
            print(f"{method:5s}: not available on this platform")
            continue
        times = epoch_start_times(dm, workers, epochs, method)
        start = {m: statistics.median(t[0] for t in ts[1:]) for m, ts in times.items()}
        whole = {m: statistics.median(t[1] for t in ts[1:]) for m, ts in times.items()}
        cost = whole["restarted"] - whole["persistent"]
        print(
            f"{method:5s}: start restarted {start['restarted']:7.3f} s, persistent {start['persistent']:7.3f} s "
            f"(its first epoch {times['persistent'][0][0]:.3f} s, once per fit), "
            f"restarted / persistent = {start['restarted'] / start['persistent']:.1f}x"
        )
        print(
            f"       epoch loading restarted {whole['restarted']:7.3f} s, persistent {whole['persistent']:7.3f} s, "
            f"restarted / persistent = {whole['restarted'] / whole['persistent']:.1f}x; the restart costs "
            f"{cost:.3f} s per epoch, {100 * cost / whole['restarted']:.0f}% of the restarted epoch's loading"
        )


def train_step_rate(batches: list, steps: int) -> tuple[float, str]:
    try:
        from floaff_zoo.models.pointnet2 import PointNet2Module  # type: ignore[import-not-found]

        model = PointNet2Module(feat_channels=1)
        what = "floaff_zoo.models.pointnet2.PointNet2Module (default args)"

        def step(b):
            loss, _, _ = model.model_step(b)
            return loss
    except ImportError:
        from floaff_zoo.nn.pointnet2 import PointNet2Seg

        model = PointNet2Seg(
            in_channels=1,
            npoints=[1024, 256, 64, 16],
            radii=[[0.1], [0.2], [0.4], [0.8]],
            nsamples=[[32], [32], [32], [32]],
            mlps=[[[32, 32, 64]], [[64, 64, 128]], [[128, 128, 256]], [[256, 256, 512]]],
            fp_mlps=[[256, 256], [256, 256], [256, 128], [128, 128, 128]],
            head=[128],
        )
        what = "floaff_zoo.nn.pointnet2.PointNet2Seg (SSG, 4 levels 1024/256/64/16, per-point MSE on scene points)"

        def step(b):
            out = torch.sigmoid(model(b["scene_xyz"], b["scene_feat"][..., :1], b["scene_mask"]))
            return ((out - (b["scene_feat"][..., 0] > 0).float()) ** 2).mean()

    opt = torch.optim.Adam(model.parameters(), 1e-3)
    model.train()
    step(batches[0]).backward()  # warm-up
    n = 0
    t = time.perf_counter()
    for i in range(steps):
        b = batches[i % len(batches)]
        opt.zero_grad()
        step(b).backward()
        opt.step()
        n += b["scene_xyz"].shape[0]
    return n / (time.perf_counter() - t), what


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--dataset", choices=["moma", "floaff"], default="moma")
    p.add_argument("--root", default=None, help="dataset root (default: write MoMa-sized samples to a temp dir)")
    p.add_argument("--benchmark", default="styles", choices=BENCHMARKS, help="FloAff benchmark (--dataset floaff)")
    p.add_argument("--samples", type=int, default=32, help="samples to write when --root is not given")
    p.add_argument("--max-samples", type=int, default=None, help="first N records of each split (--dataset moma)")
    p.add_argument("--num-points", type=int, default=4096)
    p.add_argument("--batch-size", type=int, default=8)
    p.add_argument("--workers", type=int, default=0)
    p.add_argument("--epochs", type=int, default=3)
    p.add_argument("--steps", type=int, default=3)
    p.add_argument(
        "--epoch-start",
        action="store_true",
        help="time the start of a train epoch instead: workers restarted each epoch vs persistent, fork vs spawn",
    )
    p.add_argument("--epoch-start-workers", type=int, default=2, help="loader workers of --epoch-start")
    p.add_argument("--epoch-start-epochs", type=int, default=6, help="epochs per loader of --epoch-start")
    p.add_argument(
        "--epoch-start-methods",
        nargs="+",
        choices=["fork", "spawn"],
        default=["fork", "spawn"],
        help="worker start methods of --epoch-start (spawn: the default on macOS and Windows)",
    )
    args = p.parse_args(argv)
    if args.epochs < 1 or args.steps < 1:
        p.error("--epochs and --steps must be >= 1")
    if args.epoch_start_workers < 1 or args.epoch_start_epochs < 2:  # the medians leave the first epoch out
        p.error("--epoch-start-workers must be >= 1 and --epoch-start-epochs >= 2")
    for flag in ("samples", "num_points", "batch_size", "max_samples"):
        if (value := getattr(args, flag)) is not None and value < 1:
            p.error(f"--{flag.replace('_', '-')} must be >= 1, got {value}")
    if args.workers < 0:
        p.error(f"--workers must be >= 0, got {args.workers}")
    if args.dataset == "floaff" and args.max_samples is not None:  # FloAffKitchenDataModule has no such option
        p.error("--max-samples applies to --dataset moma only (the FloAff data module reads every sample)")
    if args.root is not None and not Path(args.root).is_dir():  # the data module's traceback named it only
        p.error(f"--root {args.root}: not a folder")
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", torch.get_num_threads())))
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.root) if args.root else Path(tmp) / "moma"
        if not args.root:
            if args.dataset != "moma":
                p.error("--dataset floaff needs --root (generate data with `floaff-zoo generate`)")
            t = time.perf_counter()
            write_moma_like(root, args.samples)
            print(f"wrote {args.samples} MoMa-sized samples in {time.perf_counter() - t:.1f} s")
        cache = Path(tmp) / "cache"
        dm = make_dm(args, root, cache)
        if args.epoch_start:
            dm.setup("fit")
            report_epoch_start(dm, args.epoch_start_workers, args.epoch_start_epochs, args.epoch_start_methods)
            return
        preload_readers()  # the cold setup times parsing and the cache, not the first import of the readers' modules
        t = time.perf_counter()
        dm.setup("fit")
        n = len(dm.datasets["train"])
        # every split the setup parsed (MoMa-Kitchen's fit builds the test split too when val_fraction is 0)
        parsed = sum(len(ds) for ds in {id(d): d for d in dm.datasets.values()}.values())
        cold = parsed / (time.perf_counter() - t)
        dm2 = make_dm(args, root, cache)
        t = time.perf_counter()
        dm2.setup("fit")
        warm_setup = time.perf_counter() - t
        rate, batches = loader_rate(dm2, args.epochs)
        step_rate, what = train_step_rate(batches, args.steps)
        print(
            f"\ntorch threads {torch.get_num_threads()}, loader workers {args.workers}, batch {args.batch_size}, "
            f"num_points {args.num_points}, {n} train samples"
        )
        print(f"cold setup (parse + build cache): {cold:8.1f} samples/s ({parsed} samples of every split parsed)")
        print(f"warm setup (cache hits):          {warm_setup:8.2f} s")
        print(f"loader (cached, transforms, collate): {rate:8.1f} samples/s")
        print(f"train step [{what}]: {step_rate:8.2f} samples/s")
        print(f"loader / train step = {rate / step_rate:.1f}x (target >= 5x)")


if __name__ == "__main__":
    main()
