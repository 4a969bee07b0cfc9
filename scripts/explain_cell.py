"""Why a candidate cell of a generated scene succeeds or fails: the annotation's verdict, checked again step by step.

    python scripts/explain_cell.py data/floaff_dense/layouts/L5_S4_s773636571_CloseDoubleDoor --cell 0,-0.7 \
        --cell 0.1,-0.7
    python scripts/explain_cell.py <scene directory> --grid      # the annotation's reasons over the whole grid

A cell is given in the target frame (x° along the target's front, y° < 0 in front of it, metres; the nearest
candidate of the scene's grid is used). For each cell this prints the annotation's reason and label, then runs the
annotation's feasibility filters one at a time (reach, the front plane, a wall between base and target, the base
footprint over a furniture footprint, the tucked robot touching the scene in the task's reset state, naming the
bodies touched) and, for a feasible cell, one rollout of the annotation's episode (``--seed``, the exact pose the
annotation simulated): its outcome, the task's state and the robot's contacts with the scene when it ended.

``--grid`` prints the reasons as a map, one character per cell, far rows first, the target's front below the last
row of the map: ``O`` success, ``c`` failed in rollout (collision or another rollout failure), ``i`` refused by the
IK pre-check, ``#`` infeasible (filtered_collision), ``-`` never rolled out (a budgeted preset's skipped_budget),
blank out of reach. Needs MuJoCo (the scene is rebuilt).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

from floaff_zoo.sim import fileformat as ff
from floaff_zoo.sim.annotate import SKIPPED_REASON
from floaff_zoo.sim.views import candidates_in_target_frame

#: one character per annotation reason in the ``--grid`` map (any other rollout failure prints ``c``)
GRID_CHARS = {
    "success": "O",
    "filtered_collision": "#",
    "filtered_reach": " ",
    "ik_unreachable": "i",
    SKIPPED_REASON: "-",  # never rolled out: drawn as a failed rollout before
}


def nearest_candidate(scene: dict, xo: float, yo: float) -> int:
    """Index of the candidate cell nearest to target-frame (x°, y°) m; ValueError when none is within a cell."""
    d = np.hypot(*(candidates_in_target_frame(scene) - np.array([xo, yo])).T)
    i = int(d.argmin())
    if d[i] > float(scene["candidates"]["cell"]):
        raise ValueError(f"no candidate cell near x°={xo}, y°={yo} m in {scene['scene_id']} (nearest {d[i]:.2f} m)")
    return i


def reason_map(scene: dict) -> list[str]:
    """The annotation's reasons as rows of characters (``GRID_CHARS``), far rows first, rows in front only."""
    h, w = scene["candidates"]["grid_shape"]
    reasons = scene["labels"]["reasons"]
    yo = candidates_in_target_frame(scene)[:, 1].reshape(h, w)
    rows = []
    for r in range(h):
        if yo[r, 0] > -1e-6:  # on or behind the target's front plane: never a base pose
            continue
        rows.append("".join(GRID_CHARS.get(reasons[r * w + c], "c") for c in range(w)))
    return rows


def check_pose(sim, x: float, y: float, yaw: float, seed: int) -> list[tuple[str, str]]:
    """The annotation's filters one at a time for a world pose: [(check, verdict)], up to the first that refuses."""
    from floaff_zoo.sim.rollout import FRONT_PLANE_TOL
    from floaff_zoo.sim.tasks import target_frame

    c = sim.target.pos[:2]
    dist = float(np.hypot(x - c[0], y - c[1]))
    out = [("reach", f"{dist:.2f} m from the target (limit {sim.task.r_arm:.2f} m)")]
    if dist >= sim.task.r_arm:
        return out + [("verdict", "filtered_reach")]
    yo = float(target_frame(sim.target, np.array([x, y]))[1])
    checks = (
        ("front plane", yo > -FRONT_PLANE_TOL, f"y° = {yo:+.2f} m"),
        ("wall between", sim.wall_between(x, y, c), ""),
        ("footprint over furniture", not sim.footprint_free(x, y, yaw), ""),
    )
    for name, bad, note in checks:
        if bad and name == "footprint over furniture":  # name what the base would stand in
            note = "the robot parked there touches: " + fmt_contacts(tucked_contacts(sim, x, y, yaw, seed))
        out.append((name, " ".join(filter(None, ("REFUSED" if bad else "ok", note)))))
        if bad:
            return out + [("verdict", "filtered_collision")]
    touched = tucked_contacts(sim, x, y, yaw, seed)
    out.append(("tucked robot in the reset state", "REFUSED, touches: " + fmt_contacts(touched) if touched else "ok"))
    return out + [("verdict", "filtered_collision" if touched else "feasible")]


def tucked_contacts(sim, x: float, y: float, yaw: float, seed: int) -> list[tuple[str, str, float]]:
    """Robot-scene contacts with the base at the pose, the arm tucked and the task in its reset state for ``seed``."""
    sim.robot.set_base_pose(sim.data, x, y, yaw)
    sim.reset_task(np.random.default_rng(int(seed)))
    return sim.robot_contacts()


def fmt_contacts(contacts: list[tuple[str, str, float]], limit: int = 4) -> str:
    """'robot body - scene body (depth cm)', deepest first."""
    if not contacts:
        return "none"
    seen: dict[tuple[str, str], float] = {}
    for a, b, dist in contacts:
        seen.setdefault((a, b), dist)
    parts = [f"{a} - {b} ({-100 * d:.1f} cm)" for (a, b), d in list(seen.items())[:limit]]
    return ", ".join(parts) + (f" and {len(seen) - limit} more" if len(seen) > limit else "")


def explain(scene: dict, index: int, seed: int = 0) -> list[tuple[str, str]]:
    """[(item, text)] for one candidate cell: the recorded verdict, the filters, and a rollout when feasible."""
    from floaff_zoo.sim.kitchen import SceneSpec, build_scene
    from floaff_zoo.sim.rollout import rollout

    cand, labels = scene["candidates"], scene["labels"]
    x, y = (float(v) for v in cand["xy"][index])
    yaw = float(cand["yaw"][index])
    xo, yo = candidates_in_target_frame(scene)[index]
    out = [
        ("cell", f"#{index}: x° = {xo:+.2f} m, y° = {yo:+.2f} m (world x {x:.3f}, y {y:.3f}, yaw {yaw:.3f})"),
        ("annotation", f"{labels['reasons'][index]} (label {float(labels['label'][index]):.2f})"),
    ]
    sim = build_scene(SceneSpec.from_dict(scene["spec"]))
    out += check_pose(sim, x, y, yaw, seed)
    if out[-1][1] != "feasible":
        return out
    res = rollout(sim, (x, y, yaw), seed=seed, check_pose=False)
    state = ", ".join(f"{k} {v:.2f}" for k, v in res.state.items())
    out.append(("rollout", f"{res.reason} after {res.sim_seconds:.2f} s simulated; task state: {state}"))
    out.append(("contacts when it ended", fmt_contacts(sim.robot_contacts())))
    return out


def parse_cell(text: str) -> tuple[float, float]:
    try:
        xo, yo = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"a cell is 'x,y' in metres (target frame), got {text!r}") from None
    if not (math.isfinite(xo) and math.isfinite(yo)):  # NaN is nearest to no cell: argmin chose cell #0 silently
        raise argparse.ArgumentTypeError(f"a cell is 'x,y' in finite metres (target frame), got {text!r}")
    return xo, yo


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("scene", help="a generated scene's directory (or its scene.json)")
    p.add_argument("--cell", type=parse_cell, action="append", default=[], help="x,y in the target frame (m)")
    p.add_argument("--grid", action="store_true", help="print the annotation's reasons over the whole grid")
    p.add_argument("--seed", type=int, default=0, help="episode seed (the annotation's is 0)")
    a = p.parse_args(argv)
    if not a.cell and not a.grid:
        p.error("give --cell x,y (repeatable) and/or --grid")
    if a.seed < 0:  # numpy's episode generator takes no negative seed: a ValueError traceback mid-way
        p.error(f"--seed must be >= 0, got {a.seed}")
    try:
        scene = ff.read_scene(a.scene)
        if "reasons" not in scene["labels"] or "yaw" not in scene["candidates"]:
            raise ff.FormatError(f"{Path(a.scene)}: no per-cell reasons or yaws (format 1 data); regenerate it")
        cells = [nearest_candidate(scene, xo, yo) for xo, yo in a.cell]
    except (OSError, ValueError) as exc:
        raise SystemExit(f"explain_cell: {exc}") from exc
    print(f"{scene['scene_id']} ({scene['split']}, {scene['task']})")
    if a.grid:
        print("far from the target at the top; the target's front below the last row; x° grows to the right")
        for row in reason_map(scene):
            print("  |" + row + "|")
    for i in cells:
        print()
        for item, text in explain(scene, i, a.seed):
            print(f"  {item}: {text}")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    raise SystemExit(run(main, "explain_cell"))
