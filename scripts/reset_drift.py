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
import math
import sys
from pathlib import Path

import numpy as np

from floaff_zoo.sim import fileformat as ff
from floaff_zoo.sim.kitchen import PARK_POSE, SceneSpec, build_scene, release_scene

sys.path.insert(0, str(Path(__file__).resolve().parent))
from script_cli import refuse_folders  # noqa: E402

try:
    from floaff_zoo.sim.rollout import hold_still
except ImportError:  # a simulator before generator 2.3 first on PYTHONPATH (to check an older copy): the same loop
    import mujoco

    from floaff_zoo.sim.controllers import CTRL_DT

    def hold_still(scene, seconds: float) -> None:
        """``floaff_zoo.sim.rollout.hold_still`` of generator 2.3: base and arm held, ``seconds`` simulated."""
        m, d = scene.model, scene.data
        nsub = max(1, int(round(CTRL_DT / m.opt.timestep)))
        q = scene.robot.ik_q(d)
        scene.robot.hold(d, q[1:], float(q[0]), True)
        for _ in range(int(round(seconds / (nsub * m.opt.timestep)))):
            mujoco.mj_step(m, d, nsub)


#: the parts' opening fractions in a task's state (PnPCounterToCab's object and gripper entries are left out)
OPENING_KEYS = ("drawer_open", "door_pos_open", "door_neg_open", "door_open", "cab_door_open")


def openings(scene) -> dict[str, float]:
    """{part: opening fraction} of the scene's task state."""
    return {k: round(float(v), 4) for k, v in scene.task.state(scene).items() if k in OPENING_KEYS}


def scene_drift(spec: SceneSpec, seconds: float) -> dict:
    """{"reset": {part: opening}, "after": {part: opening}, "moved": max |after - reset|} for one scene."""
    scene = build_scene(spec)
    release_scene(spec)  # one scene each: the per-process cache kept every compiled kitchen (~70 MB) otherwise
    scene.robot.set_base_pose(scene.data, *PARK_POSE)
    scene.reset_task(np.random.default_rng(0))
    before = openings(scene)
    hold_still(scene, seconds)
    after = openings(scene)
    moved = max((abs(after[k] - before[k]) for k in before), default=0.0)
    return {"reset": before, "after": after, "moved": round(moved, 4)}


def read_spec(folder: Path) -> tuple[dict, SceneSpec | None]:
    """A scene folder's scene.json and the SceneSpec its ``spec`` names (None for a slot the generator dropped or
    failed: no scene to reset; FormatError naming the file for a spec that names no kitchen)."""
    path = folder / ff.SCENE_JSON
    meta = ff.read_json(path)
    if isinstance(meta, dict) and meta.get("status", "ok") != "ok":
        return meta, None
    try:
        return meta, SceneSpec.from_dict(meta["spec"])
    except (TypeError, KeyError, ValueError) as exc:
        raise ff.FormatError(f"{path}: 'spec' must hold layout_id, style_id, seed and task ({exc!r})") from exc


def scene_folders(root: Path, benchmark: str | None) -> list[Path]:
    """The scene folders of ``root`` that hold a scene.json, as ``fileformat.iter_scenes`` lists them (a killed run's
    ``.staging`` and the ``.retired`` scenes left out)."""
    benches = [benchmark] if benchmark else list(ff.BENCHMARKS)
    return [
        d
        for b in benches
        if (root / b).is_dir()
        for d in sorted((root / b).iterdir())
        if d.is_dir() and not d.name.startswith(".") and (d / ff.SCENE_JSON).is_file()
    ]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--root", type=Path, required=True, help="a generated dataset (its benchmark folders inside)")
    p.add_argument("--benchmark", default=None, help="one benchmark folder only (layouts / styles)")
    p.add_argument("--seconds", type=float, default=2.0, help="simulated seconds with the robot parked away")
    p.add_argument("--tol", type=float, default=0.005, help="a move larger than this (fraction of opening) counts")
    p.add_argument("--json", type=Path, default=None, help="write every scene's record here")
    args = p.parse_args(argv)
    refuse_folders(p, json=args.json)
    if not (0 < args.seconds < math.inf and 0 <= args.tol < math.inf):  # NaN passed a plain comparison
        p.error(f"--seconds must be a finite number > 0 and --tol one >= 0, got {args.seconds} and {args.tol}")
    folders = scene_folders(args.root, args.benchmark)
    if not folders:
        raise FileNotFoundError(f"{args.root}: no scene folders under {args.benchmark or ', '.join(ff.BENCHMARKS)}")
    # every scene.json read before any simulation: a corrupt one used to stop the run after the scenes before it
    scenes = [(d, *read_spec(d)) for d in folders]
    records, moved = [], 0
    for d, meta, spec in scenes:
        if spec is None:
            continue
        rec = {"scene": f"{d.parent.name}/{d.name}", "split": meta.get("split"), **scene_drift(spec, args.seconds)}
        records.append(rec)
        flag = rec["moved"] > args.tol
        moved += flag
        mark = "  MOVED" if flag else ""
        print(f"{rec['scene']:<52} {rec['split'] or '':<5} reset {rec['reset']} after {rec['after']}{mark}")
    print(f"{moved} of {len(records)} scene(s): a part moved by itself more than {args.tol:g} in {args.seconds:g} s")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)  # not floaff_zoo.atomic: an older src may be first
        args.json.write_text(json.dumps({"seconds": args.seconds, "tol": args.tol, "scenes": records}, indent=1))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    sys.exit(run(main, "reset_drift"))
