"""What two simulator-given inputs of a view tell, and how far a robot's own estimate of one lies from it.

    python scripts/target_inputs.py --root data/floaff_dense --benchmark layouts --split test [--every 1] \
        [--json out.json]

For every view (every ``--every``-th of each scene) of the split, per task:

- **the floor queries' lattice angle**: the benchmark's floor points are cells of the annotation's lattice, aligned
  with the target frame. The angle of their nearest-neighbour vectors (a 4θ circular mean, so modulo 90°) is
  compared with the simulator's ``target_yaw`` modulo 90°: how well the queries alone give the target frame away;
- **the target point's estimate from the target's pixels**: the distance in the floor plane from the task's target
  point (``target_xyz``, the centre of the fixture's front face) to the centroid of the stored cloud's flagged points
  (what ``floaff_zoo.predict.predict`` uses without ``target_xyz``), and to the centroid of the flagged points within
  3, 5 or 10 cm of the nearest one to the robot (a front-surface guess).

Medians, 90th percentiles and maxima go to stdout and ``--json``. Files only, no model, no simulator.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from floaff_zoo.atomic import atomic_write_text
from floaff_zoo.sim.fileformat import BENCHMARKS

sys.path.insert(0, str(Path(__file__).resolve().parent))
from script_cli import refuse_folders  # noqa: E402

BANDS = (0.03, 0.05, 0.10)


def lattice_angle(floor_xy: np.ndarray) -> float | None:
    """The orientation (rad, in [0, pi/2)) of a square lattice's points [M, 2] from their nearest-neighbour vectors
    (4θ circular mean); None with fewer than 3 points."""
    if len(floor_xy) < 3:
        return None
    d = np.linalg.norm(floor_xy[:, None] - floor_xy[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    v = floor_xy[d.argmin(axis=1)] - floor_xy
    theta = np.arctan2(v[:, 1], v[:, 0])
    mean = math.atan2(float(np.sin(4 * theta).mean()), float(np.cos(4 * theta).mean())) / 4
    return mean % (math.pi / 2)


def angle_error_deg(a: float, b: float) -> float:
    """|a - b| modulo 90°, in degrees, in [0, 45]."""
    e = (a - b) % (math.pi / 2)
    return math.degrees(min(e, math.pi / 2 - e))


def target_estimates(xyz: np.ndarray, flag: np.ndarray) -> dict[str, np.ndarray] | None:
    """Target point guesses from a cloud xyz [N, 3] (robot base frame) and its flag [N]: the flagged points'
    centroid, and the centroid of those within each band of the nearest one to the robot; None without a flag."""
    pts = xyz[flag > 0]
    if len(pts) == 0:
        return None
    r = np.hypot(pts[:, 0], pts[:, 1])
    out = {"centroid": pts.mean(axis=0)}
    for band in BANDS:
        out[f"nearest_{band:g}"] = pts[r <= r.min() + band].mean(axis=0)
    return out


def summary(values: list[float]) -> dict[str, float]:
    v = np.asarray(values, float)
    return {"n": int(v.size), "median": float(np.median(v)), "p90": float(np.quantile(v, 0.9)), "max": float(v.max())}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--root", default="data/floaff_dense")
    p.add_argument("--benchmark", default="layouts", choices=BENCHMARKS)
    p.add_argument("--split", default="test", choices=["train", "test"])
    p.add_argument("--every", type=int, default=1, help="use every n-th view of each scene")
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    refuse_folders(p, json=a.json)
    if a.every < 1:
        p.error("--every must be >= 1")
    from floaff_zoo.sim import fileformat as ff

    angle: dict[str, list[float]] = defaultdict(list)
    offsets: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    read = 0
    try:
        for scene in ff.iter_scenes(a.root, benchmark=a.benchmark, split=a.split):
            for v in scene["views"][:: a.every]:
                read += 1
                view = ff.read_sample(scene, v, a.root)
                task = view["meta"]["task"]
                fa = lattice_angle(np.asarray(view["floor_xyz"], float)[:, :2])
                if fa is not None:
                    angle[task].append(angle_error_deg(fa, float(view["target_yaw"])))
                est = target_estimates(np.asarray(view["scene_xyz"], float), np.asarray(view["scene_feat"])[:, 0])
                for name, guess in (est or {}).items():
                    offsets[name][task].append(float(np.hypot(*(guess - view["target_xyz"])[:2])))
    except (OSError, ValueError, KeyError) as exc:
        raise SystemExit(f"target_inputs: {exc}") from exc
    if not read:
        raise SystemExit(f"target_inputs: no {a.benchmark} {a.split} view under {a.root}")
    if not angle and not offsets:  # was "no view" too, of a root that has them
        raise SystemExit(
            f"target_inputs: none of the {read} {a.benchmark} {a.split} view(s) read under {a.root} has 3 or more "
            "floor points or a flagged target point (nothing to measure)"
        )
    res = {
        "benchmark": a.benchmark,
        "split": a.split,
        "every": a.every,
        "lattice_angle_error_deg": {t: summary(v) for t, v in sorted(angle.items())},
        "target_offset_m": {n: {t: summary(v) for t, v in sorted(by.items())} for n, by in offsets.items()},
    }
    for t, s in res["lattice_angle_error_deg"].items():
        print(f"{a.benchmark} {a.split} {t}: lattice angle error median {s['median']:.2f} deg, p90 {s['p90']:.2f}")
    for n, by in res["target_offset_m"].items():
        every = np.concatenate([np.asarray(v) for v in offsets[n].values()])
        cells = ", ".join(f"{t} {s['median']:.3f}" for t, s in by.items())
        print(f"{a.benchmark} {a.split} {n}: median xy offset {np.median(every):.3f} m ({cells})")
    if a.json:
        atomic_write_text(a.json, json.dumps(res, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    raise SystemExit(run(main, "target_inputs"))
