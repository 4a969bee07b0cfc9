"""Success rate of the predict API with its defaults vs with the dataset's floor points, on generated test views.

    python scripts/predict_sr.py --root data/floaff_small --benchmark layouts \
        --model <ckpt or hub name> [--json out.json]

For every test view: ``predict_from_points`` once with ``floor_xyz=None`` and ``target_yaw=None`` (the
API's defaults: the observed floor cells of the cloud, nothing from the simulator) and once with the view's
own floor points; the best pose of each is rolled out in the rebuilt scene. Prints SR_all per task for
both; ``floaff-zoo test`` scores the second with the same rollouts.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from script_cli import floor_model, refuse_folders  # noqa: E402

from floaff_zoo.atomic import atomic_write_text
from floaff_zoo.frames import facing_pose, pose_to_world
from floaff_zoo.predict import check_cell, predict_from_points
from floaff_zoo.sim import fileformat as ff
from floaff_zoo.sim.kitchen import SceneSpec
from floaff_zoo.sim.rollout import RolloutService


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--root", required=True)
    p.add_argument("--benchmark", default="layouts", choices=ff.BENCHMARKS)
    p.add_argument("--model", required=True)
    p.add_argument("--cell", type=float, default=0.1, help="grid cell of the model's training data (m)")
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    refuse_folders(p, json=a.json)
    try:  # else predict's ValueError, naming no option, was a traceback at the first view, after the model loaded
        check_cell(a.cell)
    except ValueError as exc:
        p.error(f"--cell: {exc}")
    scenes = list(ff.iter_scenes(a.root, benchmark=a.benchmark, split="test"))
    if not scenes:  # else every SR read nan (the mean of no rollout) and the script exited 0
        raise SystemExit(f"predict_sr: no finished test scene under {Path(a.root) / a.benchmark}")
    # predict_from_points refuses a model without a floor map too, but as a TypeError traceback after the first view
    model = floor_model(a.model, f"predict_sr: --model {a.model}")
    jobs: dict[str, list] = {"default": [], "dataset": []}
    tasks: list[str] = []
    for scene in scenes:
        for view in scene["views"]:
            s = ff.read_sample(scene, view)
            sim, task = s["meta"]["sim"], s["meta"]["task"]
            args = (s["scene_xyz"], s["scene_feat"])
            common = dict(robot=s["robot"], target_xyz=s["target_xyz"], k=1, task=task, num_points=1024)
            default = predict_from_points(model, *args, None, target_yaw=None, cell=a.cell, **common)
            dataset = predict_from_points(model, *args, s["floor_xyz"], target_yaw=None, **common)
            spec = SceneSpec.from_dict(sim)
            target_world = sim.get("target_world")  # faced in float64, as floaff-zoo test does
            for key, pred in (("default", default), ("dataset", dataset)):
                pose = pose_to_world(pred.best_pose, sim["base_pose_world"])
                jobs[key].append((spec, pose if target_world is None else facing_pose(pose, target_world)))
            tasks.append(task)
    service = RolloutService()
    out: dict[str, dict[str, float]] = {}
    for key, js in jobs.items():
        ok = np.array([r.success for r in service.run(js)], dtype=float)
        out[key] = {t: float(ok[[x == t for x in tasks]].mean()) for t in sorted(set(tasks))}
        out[key]["all"] = float(ok.mean())
    print(f"{a.benchmark} test, {len(tasks)} views; SR with predict's default floor vs the dataset's floor points")
    print("| floor queries | " + " | ".join(out["default"]) + " |")
    print("|---|" + "---:|" * len(out["default"]))
    for key in out:
        print(f"| {key} | " + " | ".join(f"{v:.2f}" for v in out[key].values()) + " |")
    if a.json:
        atomic_write_text(a.json, json.dumps(out, indent=1))  # a missing folder failed after every rollout
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    raise SystemExit(run(main, "predict_sr"))
