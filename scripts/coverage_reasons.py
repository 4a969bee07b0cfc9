"""How often a candidate cell the view's cloud calls free is infeasible, by how much of its footprint the view shows.

    python scripts/coverage_reasons.py --root data/floaff_dense [--split train] [--every 20] [--json out.json]

Labels only, no model and no simulator. For every ``--every``-th view of each scene of the split and every candidate
cell in front of the target (``filtered_reach`` cells left out), the base footprint parked there facing the target is
checked in the view's stored cloud (``floor.footprint_blocked``, the rollout callback's ``free_space: full_cloud``);
of the cells it calls free, the share of the footprint the cloud shows (``floor.footprint_coverage``) is binned, and
per benchmark, task and bin the script prints how many (view, cell) pairs there are and which share of them the
annotation marks ``filtered_collision`` (furniture or the robot's body where the base would stand) and ``success``.
This is the diagnostic behind ``scripts/scene_sr.py --min-observed`` (docs/results.md, "Preferring footprints the
view shows"): run it on training scenes, never on test scenes, when deciding anything.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from floaff_zoo.atomic import atomic_write_text
from floaff_zoo.floor import footprint_blocked, footprint_coverage
from floaff_zoo.frames import base_to_world
from floaff_zoo.sim import fileformat as ff
from floaff_zoo.sim.views import candidates_in_target_frame

sys.path.insert(0, str(Path(__file__).resolve().parent))
from script_cli import refuse_folders  # noqa: E402

#: upper edges of the coverage bins (the last bin is [0.75, 1])
BINS = (0.25, 0.5, 0.75)


def coverage_bin(cov: float) -> str:
    """'<0.25', '<0.5', '<0.75' or '>=0.75'."""
    for edge in BINS:
        if cov < edge:
            return f"<{edge:g}"
    return f">={BINS[-1]:g}"


def scene_counts(scene: dict, every: int) -> dict[str, dict[str, int]]:
    """{bin: {"n", "filtered_collision", "success"}} over (view, free cell) pairs of one scene."""
    xy = np.asarray(scene["candidates"]["xy"], float)
    yaw = np.asarray(scene["candidates"]["yaw"], float)
    reasons = scene["labels"]["reasons"]
    ahead = candidates_in_target_frame(scene)[:, 1] < -1e-3  # behind the target's front is never a base pose
    cells = [i for i, r in enumerate(reasons) if ahead[i] and r != "filtered_reach"]
    out: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    for view in scene["views"][:: max(1, every)]:
        arrays = ff.read_view(Path(scene["dir"]) / view["file"])
        world = base_to_world(arrays["scene_xyz"], arrays["base_pose_world"])
        for i in cells:
            pose = (xy[i, 0], xy[i, 1], yaw[i])
            if footprint_blocked(world, pose):
                continue
            b = out[coverage_bin(footprint_coverage(world, pose))]
            b["n"] += 1
            b[reasons[i] if reasons[i] in ("filtered_collision", "success") else "other"] += 1
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--root", default="data/floaff_dense")
    p.add_argument("--split", default="train", choices=["train", "test"])
    p.add_argument("--every", type=int, default=20, help="use every n-th view of each scene")
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    refuse_folders(p, json=a.json)
    if a.every < 1:
        p.error("--every must be >= 1")
    table: dict[str, dict[str, dict[str, int]]] = defaultdict(lambda: defaultdict(lambda: defaultdict(int)))
    scenes = 0
    try:
        for scene in ff.iter_scenes(a.root, split=a.split):
            scenes += 1
            if "reasons" not in scene["labels"] or "yaw" not in scene["candidates"]:
                raise ff.FormatError(f"{scene['dir']}: no per-cell reasons or yaws (format 1 data); regenerate it")
            key = f"{scene['benchmark']}/{scene['task']}"
            for b, c in scene_counts(scene, a.every).items():
                for k, v in c.items():
                    table[key][b][k] += v
    except (OSError, ValueError) as exc:
        raise SystemExit(f"coverage_reasons: {exc}") from exc
    if not scenes:
        raise SystemExit(f"coverage_reasons: no finished {a.split} scene under {a.root}")
    if not table:  # said "no finished scene" too, of a root that has them
        raise SystemExit(
            f"coverage_reasons: no view of the {scenes} {a.split} scene(s) under {a.root} shows a cell in front of "
            "the target free in its cloud (no row to print)"
        )
    order = [f"<{e:g}" for e in BINS] + [f">={BINS[-1]:g}"]
    print("| benchmark/task | footprint shown | (view, cell) pairs | filtered_collision | success |")
    print("|---|---|---:|---:|---:|")
    for key in sorted(table):
        for b in order:
            c = table[key].get(b)
            if c and c["n"]:
                n = c["n"]
                print(f"| {key} | {b} | {n} | {c['filtered_collision'] / n:.2f} | {c['success'] / n:.2f} |")
    if a.json:
        doc = {"root": a.root, "split": a.split, "every": a.every, "bins": list(BINS), "counts": table}
        atomic_write_text(a.json, json.dumps(doc, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    raise SystemExit(run(main, "coverage_reasons"))
