"""Does a scene's task start where its reset puts it? The reset state of every scene of a generated dataset, and how
far the target's doors or drawer move by themselves in the first seconds with the robot parked away.

    python scripts/reset_drift.py --root data/floaff_dense [--benchmark layouts] [--seconds 2] [--json out.json]

For each scene folder (its layout, style, seed and task: ``scene.json``'s ``spec``) the kitchen is rebuilt by the
installed simulator, the task is reset with episode seed 0 (the annotation's first), the robot is parked at the
simulator's parking pose with its arm held still, and ``--seconds`` of simulation run. A part that moves more than
``--tol`` (a fraction of its full opening) was reset into other furniture, and the contact forces moved it: its
scene's labels measured a task that had partly done itself, or been made harder (the corner-layout defect of
generator 2.2 and earlier, ``docs/data_format.md``). Run it with the simulator of the generator in question (e.g. a
git worktree of an older commit first on ``PYTHONPATH``) to see which of that copy's scenes carry the defect.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from floaff_zoo.sim import fileformat as ff
from floaff_zoo.sim.kitchen import PARK_POSE, SceneSpec, build_scene
from floaff_zoo.sim.rollout import hold_still

#: the parts' opening fractions in a task's state (PnPCounterToCab's object and gripper entries are left out)
OPENING_KEYS = ("drawer_open", "door_pos_open", "door_neg_open", "door_open", "cab_door_open")


def openings(scene) -> dict[str, float]:
    """{part: opening fraction} of the scene's task state."""
    return {k: round(float(v), 4) for k, v in scene.task.state(scene).items() if k in OPENING_KEYS}


def scene_drift(spec: SceneSpec, seconds: float) -> dict:
    """{"reset": {part: opening}, "after": {part: opening}, "moved": max |after - reset|} for one scene."""
    scene = build_scene(spec)
    scene.robot.set_base_pose(scene.data, *PARK_POSE)
    scene.reset_task(np.random.default_rng(0))
    before = openings(scene)
    hold_still(scene, seconds)
    after = openings(scene)
    moved = max((abs(after[k] - before[k]) for k in before), default=0.0)
    return {"reset": before, "after": after, "moved": round(moved, 4)}


def read_spec(folder: Path) -> tuple[dict, SceneSpec]:
    """A scene folder's scene.json and the SceneSpec its ``spec`` names (FormatError naming the file otherwise)."""
    path = folder / ff.SCENE_JSON
    meta = ff.read_json(path)
    spec = meta.get("spec") if isinstance(meta, dict) else None
    try:
        return meta, SceneSpec(int(spec["layout_id"]), int(spec["style_id"]), int(spec["seed"]), str(spec["task"]))
    except (TypeError, KeyError, ValueError) as exc:
        raise ff.FormatError(f"{path}: 'spec' must hold layout_id, style_id, seed and task ({exc!r})") from exc


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--root", type=Path, required=True, help="a generated dataset (its benchmark folders inside)")
    p.add_argument("--benchmark", default=None, help="one benchmark folder only (layouts / styles)")
    p.add_argument("--seconds", type=float, default=2.0, help="simulated seconds with the robot parked away")
    p.add_argument("--tol", type=float, default=0.005, help="a move larger than this (fraction of opening) counts")
    p.add_argument("--json", type=Path, default=None, help="write every scene's record here")
    args = p.parse_args(argv)
    if args.seconds <= 0 or args.tol < 0:
        p.error(f"--seconds must be > 0 and --tol >= 0, got {args.seconds} and {args.tol}")
    benches = [args.benchmark] if args.benchmark else ["layouts", "styles"]
    folders = [d for b in benches if (args.root / b).is_dir() for d in sorted((args.root / b).iterdir()) if d.is_dir()]
    if not folders:
        raise FileNotFoundError(f"{args.root}: no scene folders under {', '.join(benches)}")
    records, moved = [], 0
    for d in folders:
        meta, spec = read_spec(d)
        rec = {"scene": f"{d.parent.name}/{d.name}", "split": meta.get("split"), **scene_drift(spec, args.seconds)}
        records.append(rec)
        flag = rec["moved"] > args.tol
        moved += flag
        mark = "  MOVED" if flag else ""
        print(f"{rec['scene']:<52} {rec['split'] or '':<5} reset {rec['reset']} after {rec['after']}{mark}")
    print(f"{moved} of {len(records)} scene(s): a part moved by itself more than {args.tol:g} in {args.seconds:g} s")
    if args.json:
        args.json.write_text(json.dumps({"seconds": args.seconds, "tol": args.tol, "scenes": records}, indent=1))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    sys.exit(run(main, "reset_drift"))
