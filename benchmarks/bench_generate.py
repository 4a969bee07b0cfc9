"""Benchmark the FloAff generator: render ms per view, wall time of the tiny preset (and small on request), how
generation time grows with the number of scenes, and (``--grid``) what the paper's 0.05 m candidate grid costs
against the dense preset's 0.1 m in the same run.

    python benchmarks/bench_generate.py [--small] [--grid] [--workers 1] [--views 8] [--out DIR]

Prints a small report; nothing is kept unless --out is given.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from floaff_zoo.atomic import existing_ancestor  # noqa: E402


def bench_render(n_views: int, image_size: int) -> dict[str, float]:
    """Build one CloseDrawer scene and time view sampling + rendering (ms per view, by view kind)."""
    from floaff_zoo.sim.kitchen import SceneSpec, build_scene
    from floaff_zoo.sim.render import Renderer
    from floaff_zoo.sim.views import ViewConfig, render_view, sample_view_poses

    t0 = time.perf_counter()
    scene = build_scene(SceneSpec(layout_id=0, style_id=0, seed=0, task="CloseDrawer"))
    build_s = time.perf_counter() - t0
    cfg = ViewConfig(image_size=image_size)
    r = Renderer(scene.model, image_size, image_size)
    out = {"build_s": build_s}
    try:
        for kind in ("front", "side"):
            rng = np.random.default_rng(0)
            t0 = time.perf_counter()
            got = sample_view_poses(scene, r, kind, n_views, cfg, rng)
            dt = time.perf_counter() - t0
            out[f"{kind}_sample_ms_per_view"] = 1e3 * dt / max(1, len(got))
            out[f"{kind}_views"] = len(got)
            # pure render + back-projection cost at the accepted poses
            t0 = time.perf_counter()
            for pose, _ in got:
                render_view(scene, r, pose, cfg, rng)
            out[f"{kind}_render_ms_per_view"] = 1e3 * (time.perf_counter() - t0) / max(1, len(got))
    finally:
        r.close()
    return out


def bench_preset(name: str, workers: int, out: Path | None, **overrides) -> tuple[float, dict]:
    from floaff_zoo.sim.generate import generate
    from floaff_zoo.sim.presets import get_preset

    tmp = Path(tempfile.mkdtemp(prefix=f"bench_{name}_")) if out is None else out / name
    if out is not None and _holds_a_run(tmp):  # generate would resume it: no wall time
        raise SystemExit(f"bench_generate: {tmp} holds an earlier run, which generate would resume: give a new --out")
    try:
        t0 = time.perf_counter()
        man = generate(tmp, get_preset(name, **overrides), seed=0, workers=workers, quiet=True)
        return time.perf_counter() - t0, man
    finally:
        if out is None:
            shutil.rmtree(tmp, ignore_errors=True)


def _holds_a_run(folder: Path) -> bool:
    """Whether ``folder`` holds anything (an earlier run, which generate would resume)."""
    return folder.is_dir() and any(folder.iterdir())


def check_args(ap: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """``ap.error`` naming the flag of a bad value, before anything runs: ``--views`` below 1 timed no view and
    printed 0.0 ms/view, and a bad ``--workers`` or ``--out`` failed only after the render and scaling runs."""
    for flag in ("views", "image_size"):
        if (value := getattr(args, flag)) < 1:
            ap.error(f"--{flag.replace('_', '-')} must be >= 1, got {value}")
    if args.workers < 0:
        ap.error(f"--workers must be >= 0, got {args.workers}")
    if args.data is not None and not Path(args.data).is_dir():
        ap.error(f"--data {args.data}: not a folder")  # a typo reported no manifest without a word
    if args.out is None:
        return
    out = Path(args.out)
    folder = existing_ancestor(out)  # generate creates the missing ones
    if not folder.is_dir():
        ap.error(f"--out {out}: {folder} is not a folder")
    for name in ("tiny", "small") if args.small else ("tiny",):
        if _holds_a_run(out / name):
            ap.error(f"--out {out}: {out / name} holds an earlier run, which generate would resume: give a new --out")


def _phase_means(man: dict) -> str:
    b, a, v = [], [], []
    for s in man["scenes"].values():
        for att in s.get("attempts", []):
            b.append(att.get("build_s", 0.0))
            a.append(att.get("annotate_s", 0.0))
            if "views_s" in att:
                v.append(att["views_s"])
    f = lambda x: f"{np.mean(x):.2f}" if x else "n/a"  # noqa: E731
    return f"per scene attempt: build {f(b)} s, annotate {f(a)} s, views+write {f(v)} s"


def grid_rows(workers: int, cells: tuple[float, ...] = (0.1, 0.05)) -> list[str]:
    """Annotate one Layouts training scene per task on each candidate grid (the dense preset otherwise, one view of
    each kind so annotation dominates); a line per grid: candidates, annotate seconds, and both against the first."""
    got = {}
    for cell in cells:
        one_view = {"views_per_scene": (1, 1), "min_views": 0}
        wall, man = bench_preset(
            "dense", workers, None, benchmarks=("layouts",), n_train=1, n_test=0, cell=cell, **one_view
        )
        atts = [a for sc in man["scenes"].values() for a in sc.get("attempts", []) if "annotate_s" in a]
        if not atts:
            raise RuntimeError(f"--grid: no scene was annotated at {cell} m (counts: {man.get('counts')})")
        got[cell] = (sum(a.get("n_candidates", 0) for a in atts), sum(a["annotate_s"] for a in atts), wall, len(atts))
    ref = cells[0]
    lines = [
        f"[grid] {cell:.2f} m: {n} scene attempts, {cand} candidates, annotate {ann:.1f} s, wall {wall:.1f} s "
        f"(x{cand / max(1, got[ref][0]):.2f} candidates, x{ann / max(1e-9, got[ref][1]):.2f} annotate time vs {ref} m)"
        for cell, (cand, ann, wall, n) in got.items()
    ]
    return lines


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--small", action="store_true", help="also time the small preset (long: many minutes)")
    ap.add_argument("--grid", action="store_true", help="also compare the 0.05 m candidate grid with 0.1 m")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--views", type=int, default=8, help="views per kind for the render benchmark")
    ap.add_argument("--image-size", type=int, default=128)
    ap.add_argument("--out", default=None, help="keep generated data here")
    ap.add_argument(
        "--data",
        default=None,
        help="also report the wall time recorded in the manifest of every "
        "benchmark generated under this folder (by `floaff-zoo generate`; default: data, where it exists)",
    )
    args = ap.parse_args(argv)
    check_args(ap, args)
    out = Path(args.out) if args.out else None

    r = bench_render(args.views, args.image_size)
    print(f"[render] scene build {r['build_s']:.2f} s; image {args.image_size}^2")
    for kind in ("front", "side"):
        print(
            f"[render] {kind}: {r[f'{kind}_views']} views, render+backproject {r[f'{kind}_render_ms_per_view']:.1f} "
            f"ms/view, sampling incl. rejected poses {r[f'{kind}_sample_ms_per_view']:.1f} ms/view"
        )

    # growth with the number of scenes: tiny preset with 1, 2 and 4 scenes (1 or 2 tasks, train+test)
    rows = []
    for tasks, n_test in ((("CloseDrawer",), 0), (("CloseDrawer",), 1), (("CloseDrawer", "OpenSingleDoor"), 1)):
        wall, man = bench_preset("tiny", args.workers, None, tasks=tasks, n_test=n_test)
        n = len(man["scenes"])
        rows.append((n, wall, man))
        print(
            f"[scaling] tiny, {n} scene(s), workers={args.workers}: {wall:.1f} s ({wall / n:.1f} s/scene); "
            + _phase_means(man)
        )
    if len(rows) >= 2:
        (n0, w0, _), (n1, w1, _) = rows[0], rows[-1]
        print(f"[scaling] marginal cost {(w1 - w0) / max(1, n1 - n0):.1f} s per extra scene")
    wall, man = bench_preset("tiny", args.workers, out)
    c = man["counts"]
    print(f"[tiny] {c['scenes_ok']} scenes, {c['views_total']} views: {wall:.1f} s wall (workers={args.workers})")
    if args.small:
        wall, man = bench_preset("small", args.workers, out)
        c = man["counts"]
        print(
            f"[small] {c['scenes_ok']} scenes ok, {c['scenes_dropped']} dropped, {c['views_total']} views: "
            f"{wall / 60:.1f} min wall (workers={args.workers}); " + _phase_means(man)
        )
    if args.grid:
        for line in grid_rows(args.workers):
            print(line)
    for line in manifest_walls(Path(args.data or "data")):
        print(line)
    return 0


def manifest_walls(root: Path) -> list[str]:
    """One line per finished benchmark under ``root``: preset, scenes, views, workers and the wall time its
    ``floaff-zoo generate`` run recorded (a resumed run records only its own part). These are read from the
    manifest, not measured in this run: each line says so and when the manifest's run ended."""
    import json

    lines = []
    for path in sorted(root.glob("*/manifest.json")):
        try:
            man = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            lines.append(f"[manifest] {path}: unreadable ({exc}); skipped")
            continue
        try:
            line = _manifest_line(path, man)
        except (KeyError, TypeError, AttributeError, ValueError) as exc:  # read last: one bad file ended the run
            lines.append(f"[manifest] {path}: not a generate manifest ({type(exc).__name__}: {exc}); skipped")
            continue
        if line is not None:
            lines.append(line)
    return lines


def _manifest_line(path: Path, man: dict) -> str | None:
    """``manifest_walls``'s line of the manifest ``man`` read from ``path``; None for an unfinished run."""
    if man.get("status") != "done" or not man.get("wall_s"):
        return None
    c, cfg = man["counts"], man["config"]
    resumed = sum(1 for sc in man["scenes"].values() if sc.get("resumed"))
    made = sum(1 for sc in man["scenes"].values() if not sc.get("resumed"))  # incl. dropped slots
    ended = _dt.datetime.fromtimestamp(path.stat().st_mtime, _dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    rate = f"{man['wall_s'] / made:.1f} s/slot" if made else "s/slot n/a: every slot was resumed"
    return (
        f"[preset {man['preset']}, from {path} written {ended}, not timed here] {path.parent.name}: "
        f"{'+'.join(cfg['benchmarks'])}, {c['scenes_ok']} scenes ok, {c['scenes_dropped']} dropped, "
        f"{c['views_total']} views, max {cfg['max_candidates']} rollouts/scene: {man['wall_s']:.0f} s wall with "
        f"{man['workers']} worker(s) for the {made} scene slot(s) that run filled ({rate})"
        + (f"; {resumed} scene(s) came from an earlier run" if resumed else "")
    )


if __name__ == "__main__":
    sys.exit(main())
