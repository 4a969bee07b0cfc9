"""Success rate under fresh episodes: the task's randomness drawn again and the base parked with noise.

    python scripts/fresh_sr.py --root data/floaff_dense --benchmark layouts [[NAME=]MODEL ...] \
        [--episodes 4] [--sigma-xy 0.02] [--sigma-yaw-deg 2] [--json out.json]

The generated labels and ``floaff-zoo test`` roll every pose out once, with the annotation's task seed (the same
initial door / drawer opening) at the exact pose, so the Oracle scores 1.00 by construction, on the machine that
made the labels. A robot parks a few centimetres off and meets a door opened a little more or less. This script
measures that: for every feasible candidate cell of every test scene it runs ``--episodes`` rollouts, each with a
fresh task seed (not the annotation's) and the pose perturbed by N(0, sigma_xy) per axis and N(0, sigma_yaw), and
takes the success fraction as the cell's *fresh success probability*. Cells the generator filtered as infeasible
(collision, out of reach: never rolled out) keep probability 0; cells its IK pre-filter refused under the
annotation's draw are rolled out, since a fresh draw may leave the arm a solution (``floaff_zoo.sim.repeat``).

Every view then stands where each scorer puts it, and its fresh SR is the probability of that cell:

- ``label``: the argmax of the view's ground-truth label (the Oracle of ``floaff-zoo test``);
- ``best``: the observed cell of highest fresh probability (a hindsight bound for this evaluation);
- each MODEL (hub name or checkpoint): its predicted argmax, chosen as ``RolloutSuccessRate`` chooses.
  ``NAME=MODEL`` names it; repeating a NAME (one checkpoint per seed) adds a pooled row: the mean and sample std
  over those runs (``pooled`` in the JSON; each run keeps its own row as ``NAME/<k>``).

``--sigma-xy 0 --sigma-yaw-deg 0`` keeps the exact poses (only the task seed is new); ``--annotation-seed`` keeps
the annotation's task seed (only the parking noise is new): the two parts of the fresh evaluation, separately.
For each scorer it also prints ``exact``, the annotated outcome of the chosen cell, which is what
``floaff-zoo test`` measures when its Oracle scores 1.00 (the pose is the cell's pose, the seed the annotation's, and
a cell the annotation filtered is refused by the rollout as well). ``--top-k K`` chooses as
``RolloutSuccessRate(top_k=K, free_space="cloud")``; with ``--full-cloud`` the footprint is checked in every point the
view's file stores instead of the ``--num-points`` sample (the batch's ``full_xyz``: the DataModule's ``full_cloud``).
Rollouts run in ``--workers`` processes; the probabilities are deterministic for a given ``--seed`` on one machine.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from script_cli import add_parking_noise, check_parking_noise, floor_model, refuse_folders  # noqa: E402

from floaff_zoo.atomic import atomic_write_text  # noqa: E402
from floaff_zoo.callbacks.rollout import check_clouds, choose_pose, cloud_free  # noqa: E402
from floaff_zoo.contract import TASKS  # noqa: E402
from floaff_zoo.frames import base_to_world  # noqa: E402
from floaff_zoo.predict import named_models  # noqa: E402
from floaff_zoo.sim.fileformat import BENCHMARKS  # noqa: E402
from floaff_zoo.sim.repeat import fresh_probability, perturbed_poses, scene_probabilities, service_runner  # noqa: E402

__all__ = [
    "fresh_probability",
    "nearest_cells",
    "parse_models",
    "perturbed_poses",
    "pool_runs",
    "service_runner",
    "summarize",
    "view_choices",
]


def split_data(
    prog: str,
    root: str,
    benchmark: str,
    split: str,
    num_points: int,
    full_cloud: bool,
    batch_size: int = 8,
    val_layout: int | None = None,
) -> tuple[Any, dict[str, dict]]:
    """The FloAff-Kitchen DataModule set up for ``split`` ("test" or "val", the latter with the fold ``val_layout``)
    and {scene id: scene record} of that split's scenes, as ``fresh_sr.py`` and ``scene_sr.py`` read them.

    Validation scenes are train scenes on disk (a task with one train scene lends views of it to val). A missing root,
    a corrupt file or no finished scene ends the script with ``prog``'s message.
    """
    from lightning.pytorch.utilities.exceptions import MisconfigurationException

    from floaff_zoo.data.floaff_kitchen import FloAffKitchenDataModule
    from floaff_zoo.sim import fileformat as ff

    try:
        dm = FloAffKitchenDataModule(
            root=root,
            benchmark=benchmark,
            tasks=list(TASKS),
            batch_size=batch_size,
            num_points=num_points,
            val_layout=val_layout,
            full_cloud=full_cloud,
        )
        dm.setup("test" if split == "test" else "fit")
        keep = {s.removesuffix(" (views)") for s in dm.split_scenes.get(split, [])}
        files_split = "test" if split == "test" else "train"
        scenes = {
            s["scene_id"]: s
            for s in ff.iter_scenes(root, benchmark=benchmark, split=files_split)
            if s["scene_id"] in keep
        }
    except (OSError, ValueError, LookupError, MisconfigurationException) as exc:
        raise SystemExit(f"{prog}: {exc}") from exc
    if not scenes:
        raise SystemExit(f"{prog}: no finished {split} scene of {benchmark} under {root}")
    return dm, scenes


def nearest_cells(cand_xy: np.ndarray, xy: np.ndarray, cell: float, where: str) -> np.ndarray:
    """Index of the candidate under each world point: cand_xy [M, 2], xy [K, 2] -> [K]; off-grid is an error."""
    d = np.linalg.norm(np.asarray(xy, float)[:, None, :2] - cand_xy[None], axis=-1)
    idx = d.argmin(axis=1)
    far = d[np.arange(len(idx)), idx] > 0.5 * cell
    if far.any():
        raise ValueError(f"{where}: {int(far.sum())} floor point(s) lie off the scene's candidate grid")
    return idx


def view_choices(
    batch: dict,
    scores: dict[str, np.ndarray],
    scenes: dict[str, dict],
    probs: dict[str, np.ndarray],
    top_k: int = 1,
    full_cloud: bool = False,
) -> list[dict]:
    """Per view of a batch: task, view, and per scorer the chosen cell's (exact outcome, fresh probability).

    scores: scorer name -> [B, M] per-point scores (``label`` and the models). ``best`` is added: the observed
    cell of highest fresh probability. ``top_k`` > 1: the best of the top k poses free in the view's cloud (every
    stored point with ``full_cloud``, else the batch's sample).
    """
    from floaff_zoo.sim.kitchen import SceneSpec

    floor, mask, target = (batch[k].numpy() for k in ("floor_xyz", "floor_mask", "target_xyz"))
    if top_k > 1:  # as RolloutSuccessRate(free_space="cloud" | "full_cloud")
        cloud, cloud_mask = check_clouds(batch, "full_cloud" if full_cloud else "cloud")
    out = []
    for i, meta in enumerate(batch["meta"]):
        sim, tie = meta["sim"], int(meta.get("index", i))
        sid = SceneSpec.from_dict(sim).scene_id
        if sid not in scenes:
            raise KeyError(f"view {meta.get('sample_id', i)}: scene {sid} has no fresh probabilities")
        scene, p = scenes[sid], probs[sid]
        cand = np.asarray(scene["candidates"]["xy"], float)
        cell = float(scene["candidates"]["cell"])
        exact = np.asarray(scene["labels"]["success"]) > 0
        where = str(meta.get("sample_id", sid))
        row = {"task": meta["task"], "view": meta["view"]}
        free = None
        if top_k > 1:
            free = cloud_free(cloud[i][cloud_mask[i]], sim["base_pose_world"])
        for name, s in scores.items():
            # the Oracle (``label``) stands on its argmax, as the test's does: top 1, no footprint check
            k, check = (1, None) if name == "label" else (top_k, free)
            # footprints checked at the exact pose the callback rolls out (the view's float32 one where no target_world)
            pose, _ = choose_pose(
                floor[i], s[i], mask[i], target[i], sim["base_pose_world"], k, check, tie, None, sim.get("target_world")
            )
            c = nearest_cells(cand, np.array([pose[:2]]), cell, where)[0]
            row[name] = (bool(exact[c]), float(p[c]))
        seen = nearest_cells(cand, base_to_world(floor[i][mask[i]], sim["base_pose_world"]), cell, where)
        best = seen[np.argmax(p[seen])]
        row["best"] = (bool(exact[best]), float(p[best]))
        out.append(row)
    return out


def summarize(rows: list[dict], scorers: list[str]) -> dict[str, dict[str, dict[str, float]]]:
    """scorer -> {"exact" | "fresh": {task..., front, side, all: mean}}."""
    out: dict[str, dict[str, dict[str, float]]] = {}
    groups = {t: [r for r in rows if r["task"] == t] for t in TASKS}
    groups.update({v: [r for r in rows if r["view"] == v] for v in ("front", "side")})
    groups["all"] = rows
    for s in scorers:
        out[s] = {
            kind: {g: float(np.mean([r[s][k] for r in rs])) for g, rs in groups.items() if rs}
            for k, kind in enumerate(("exact", "fresh"))
        }
    return out


def parse_models(specs: list[str]) -> tuple[dict[str, str], dict[str, list[str]]]:
    """['[NAME=]MODEL', ...] -> (scorer key -> model, NAME -> its scorer keys), as ``predict.named_models`` reads them.

    A NAME given once is its own key; a repeated NAME gets keys ``NAME/0``, ``NAME/1``, ... in order.
    """
    try:
        named = named_models(specs)
    except ValueError as exc:
        raise SystemExit(f"fresh_sr: {exc}") from exc
    if {"label", "best"} & named.keys():
        raise SystemExit("fresh_sr: bad model argument: 'label' and 'best' name the built-in scorers")
    keys: dict[str, str] = {}
    groups: dict[str, list[str]] = {}
    for name, models in named.items():
        groups[name] = [name] if len(models) == 1 else [f"{name}/{k}" for k in range(len(models))]
        keys.update(zip(groups[name], models))
    return keys, groups


def pool_runs(sr: dict[str, dict[str, dict[str, float]]], groups: dict[str, list[str]]) -> dict[str, dict]:
    """NAME -> {"runs": n, "exact" | "fresh": {column: {"mean", "std"}}} over the NAME's runs (std: ddof 1, 0 alone)."""
    out: dict[str, dict] = {}
    for name, keys in groups.items():
        row: dict = {"runs": len(keys)}
        for kind in ("exact", "fresh"):
            cols = sr[keys[0]][kind]
            vals = {c: np.array([sr[k][kind][c] for k in keys], float) for c in cols}
            row[kind] = {
                c: {"mean": float(v.mean()), "std": float(v.std(ddof=1)) if len(v) > 1 else 0.0}
                for c, v in vals.items()
            }
        out[name] = row
    return out


def annotated_failures(scene: dict) -> np.ndarray:
    """[M] bool: the cells of a scene record whose annotation failed: rolled out without success, or refused by the IK
    pre-filter (the rollout's own t = 0 check). Not a cell over the rollout budget (status ``SKIPPED``): it was never
    rolled out, so its outcome is unknown, and counting it mixed the fresh successes of unknown cells in."""
    from floaff_zoo.sim.annotate import SKIPPED

    cand = scene["candidates"]
    failed = np.asarray(cand["valid"], bool) & ~(np.asarray(scene["labels"]["success"]) > 0)
    return failed & (np.asarray(cand["status"]) != SKIPPED) if "status" in cand else failed


def cell_stats(scenes: dict[str, dict], probs: dict[str, np.ndarray]) -> dict[str, dict[str, float]]:
    """Per task: annotated successful cells per scene, their mean fresh probability, the mean fresh probability of the
    annotated failures (:func:`annotated_failures`), and cells with p >= 0.5."""
    out: dict[str, dict[str, float]] = {}
    for t in TASKS:
        ids = [s for s in scenes if scenes[s]["task"] == t]
        if not ids:
            continue
        succ = [np.asarray(scenes[s]["labels"]["success"]) > 0 for s in ids]
        out[t] = {
            "scenes": len(ids),
            "annotated_success_cells": float(np.mean([m.sum() for m in succ])),
            "fresh_p_of_annotated_successes": float(np.mean(np.concatenate([probs[s][m] for s, m in zip(ids, succ)]))),
            "fresh_p_of_annotated_failures": float(
                np.mean(np.concatenate([probs[s][annotated_failures(scenes[s])] for s in ids]))
            ),
            "cells_p_ge_half": float(np.mean([(probs[s] >= 0.5).sum() for s in ids])),
        }
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("models", nargs="*", help="[NAME=]MODEL: hub name or checkpoint; repeat a NAME to pool runs")
    p.add_argument("--root", default="data/floaff_dense")
    p.add_argument("--benchmark", default="layouts", choices=BENCHMARKS)
    p.add_argument(
        "--split",
        default="test",
        choices=["test", "val"],
        help="test scenes, or the validation scenes the DataModule holds out of train (val_scenes=1, seed 0)",
    )
    p.add_argument("--episodes", type=int, default=4)
    add_parking_noise(p)
    p.add_argument(
        "--annotation-seed", action="store_true", help="every episode keeps the annotation's task seed (noise only)"
    )
    p.add_argument("--num-points", type=int, default=1024)
    # the dense configs' test batch: a cropped model's padded cloud, hence its output, depends on the batch
    p.add_argument("--batch-size", type=int, default=4)
    p.add_argument("--workers", type=int, default=1)
    p.add_argument("--top-k", type=int, default=1, help="> 1: best of the top-k poses free in the view's cloud")
    p.add_argument(
        "--full-cloud", action="store_true", help="with --top-k: check in every stored point, not the network's sample"
    )
    p.add_argument("--probs", default=None, help="cache of the fresh probabilities (.npz; read if it exists)")
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    check_parking_noise(p, a)
    if a.episodes < 1:
        p.error("--episodes must be >= 1")
    if min(a.top_k, a.workers, a.batch_size) < 1:
        p.error("--top-k, --workers and --batch-size must be >= 1")
    if a.full_cloud and a.top_k == 1:
        p.error("--full-cloud chooses the cloud that --top-k checks: give --top-k > 1")
    if a.probs and not a.probs.endswith(".npz"):
        p.error(f"--probs must name a .npz file, got {a.probs!r}")
    refuse_folders(p, probs=a.probs, json=a.json)

    from floaff_zoo.sim.generate import ANNOTATE_SEED

    keys, groups = parse_models(a.models)
    models = {k: floor_model(m, f"fresh_sr: {m}") for k, m in keys.items()}  # a bad model fails before the data
    dm, scenes = split_data("fresh_sr", a.root, a.benchmark, a.split, a.num_points, a.full_cloud, a.batch_size)
    setting = dict(episodes=a.episodes, sigma_xy=a.sigma_xy, sigma_yaw_deg=a.sigma_yaw_deg, seed=a.seed)
    if a.annotation_seed:
        setting["task_seed"] = "annotation"
    seeds = [ANNOTATE_SEED] * a.episodes if a.annotation_seed else []
    try:
        probs = scene_probabilities(scenes, setting, Path(a.probs) if a.probs else None, a.workers, seeds)
    except ValueError as exc:
        raise SystemExit(f"fresh_sr: {exc}") from exc

    rows: list[dict] = []
    with torch.no_grad():
        for batch in dm.test_dataloader() if a.split == "test" else dm.val_dataloader():
            scores = {"label": batch["floor_label"].numpy()}
            scores.update({m: net(batch).numpy() for m, net in models.items()})
            try:
                rows += view_choices(batch, scores, scenes, probs, a.top_k, a.full_cloud)
            except (KeyError, ValueError) as exc:  # a scene without probabilities, a floor point off its grid
                raise SystemExit(f"fresh_sr: {exc.args[0]}") from exc
    scorers = ["label", "best", *keys]
    sr = summarize(rows, scorers)
    pooled = pool_runs(sr, {n: ks for n, ks in groups.items() if len(ks) > 1})
    cells = cell_stats(scenes, probs)
    print(f"{a.benchmark} {a.split}: {len(rows)} views, {setting}")
    cols = [*TASKS, "front", "side", "all"]
    print("| scorer | SR | " + " | ".join(cols) + " |")
    print("|---|---|" + "---:|" * len(cols))
    for s in scorers:
        for kind in ("exact", "fresh"):
            print(f"| {s} | {kind} | " + " | ".join(f"{sr[s][kind].get(c, float('nan')):.2f}" for c in cols) + " |")
    for n, row in pooled.items():
        for kind in ("exact", "fresh"):
            cells_txt = " | ".join(f"{row[kind][c]['mean']:.2f} ± {row[kind][c]['std']:.2f}" for c in cols)
            print(f"| {n} ({row['runs']} runs) | {kind} | {cells_txt} |")
    for t, c in cells.items():
        print(f"{t}: " + ", ".join(f"{k} {v:.2f}" for k, v in c.items()))
    if a.json:
        atomic_write_text(
            a.json,
            json.dumps(
                {
                    "setting": setting,
                    "top_k": a.top_k,
                    "full_cloud": a.full_cloud,
                    "views": len(rows),
                    "models": keys,
                    "sr": sr,
                    "pooled": pooled,
                    "cells": cells,
                },
                indent=1,
            )
            + "\n",
        )
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    raise SystemExit(run(main, "fresh_sr"))
