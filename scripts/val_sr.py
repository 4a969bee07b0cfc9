"""Rollout success rate of several models on the validation scenes (the split used to choose, never test).

    python scripts/val_sr.py --root data/floaff_dense --benchmark layouts MODEL [MODEL ...] [--json out.json]

MODEL is a hub name or a checkpoint path. The split is the DataModule's (``val_scenes=1`` per task, seeded, as
in training; or the scenes of ``--val-scene-ids``), its points are resampled with the evaluation seed, and the pose
is chosen as ``RolloutSuccessRate`` does (argmax of the predicted map, ties broken by the sample index) and rolled
out once. ``--crop-first R`` adds the ``TargetCrop`` evaluation transform for models trained with it
(configs/experiments/recipe/crop_first.yaml). ``--top-k K`` stands on the best of the top K poses whose base footprint
is free in the view's own cloud (``RolloutSuccessRate(top_k=K, free_space="cloud")``).
Prints SR per task and over all views.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from script_cli import floor_model, refuse_folders, refuse_repeats  # noqa: E402

from floaff_zoo.atomic import atomic_write_text  # noqa: E402
from floaff_zoo.callbacks.rollout import choose_pose, cloud_free, default_service
from floaff_zoo.contract import TASKS
from floaff_zoo.data.floaff_kitchen import FloAffKitchenDataModule
from floaff_zoo.data.transforms import TargetCrop
from floaff_zoo.sim.fileformat import BENCHMARKS
from floaff_zoo.sim.kitchen import SceneSpec


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("models", nargs="+", help="hub names or checkpoint paths")
    p.add_argument("--root", default="data/floaff_dense")
    p.add_argument("--benchmark", default="layouts", choices=BENCHMARKS)
    p.add_argument("--num-points", type=int, default=1024)
    p.add_argument("--val-scene-ids", nargs="+", default=None, help="pinned validation scenes (as in training)")
    p.add_argument("--crop-first", type=float, default=None, metavar="R", help="TargetCrop radius (m)")
    p.add_argument("--top-k", type=int, default=1, help="> 1: best of the top-k poses free in the view's cloud")
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    refuse_folders(p, json=a.json)
    if a.top_k < 1:
        p.error(f"--top-k must be >= 1, got {a.top_k}")
    refuse_repeats(p, "model", a.models)
    if a.crop_first is not None and not a.crop_first > 0:  # TargetCrop's ValueError was a traceback after the models
        p.error(f"--crop-first must be a radius > 0 (m), got {a.crop_first}")
    models = {m: floor_model(m, f"val_sr: {m}") for m in a.models}  # a bad model fails before the data are set up
    dm = FloAffKitchenDataModule(
        root=a.root,
        benchmark=a.benchmark,
        tasks=list(TASKS),
        val_scenes=1,
        val_scene_ids=a.val_scene_ids,
        batch_size=8,
        num_points=a.num_points,
    )
    if a.crop_first is not None:
        dm.eval_transforms = [TargetCrop(a.crop_first)]
    dm.setup("fit")
    jobs: dict[str, list] = {m: [] for m in a.models}
    tasks: list[str] = []
    with torch.no_grad():
        for batch in dm.val_dataloader():
            floor, mask, target = (batch[k].numpy() for k in ("floor_xyz", "floor_mask", "target_xyz"))
            scores = {m: net(batch).numpy() for m, net in models.items()}
            for i, meta in enumerate(batch["meta"]):
                sim, seed = meta["sim"], int(meta.get("index", i))
                spec = SceneSpec.from_dict(sim)
                free = None
                if a.top_k > 1:  # as RolloutSuccessRate(free_space="cloud"): the view's own cloud
                    xyz = batch["scene_xyz"][i][batch["scene_mask"][i]].numpy()
                    free = cloud_free(xyz, sim["base_pose_world"])
                for m in a.models:
                    pose, _ = choose_pose(
                        floor[i],
                        scores[m][i],
                        mask[i],
                        target[i],
                        sim["base_pose_world"],
                        a.top_k,
                        free,
                        seed,
                        target_world=sim.get("target_world"),  # the annotation's exact pose, as floaff-zoo test
                    )
                    jobs[m].append((spec, pose))
                tasks.append(meta["task"])
    service = default_service()
    out: dict[str, dict[str, float]] = {}
    for m in a.models:
        ok = np.array([r.success for r in service.run(jobs[m])], dtype=float)
        row = {t: float(ok[[x == t for x in tasks]].mean()) for t in TASKS if t in tasks}
        row["all"] = float(ok.mean())
        out[m] = row
    print(f"{a.benchmark} validation scenes {dm.split_scenes['val']}, {len(tasks)} views")
    print("| model | " + " | ".join(next(iter(out.values()))) + " |")
    print("|---|" + "---:|" * len(next(iter(out.values()))))
    for m, row in out.items():
        print(f"| {m} | " + " | ".join(f"{v:.2f}" for v in row.values()) + " |")
    if a.json:
        atomic_write_text(
            a.json, json.dumps({"val_scenes": dm.split_scenes["val"], "top_k": a.top_k, "sr": out}, indent=1) + "\n"
        )
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    raise SystemExit(run(main, "val_sr"))
