"""Success rate per test scene, and error bars that resample scenes instead of views.

    python scripts/scene_sr.py --root data/floaff_dense --benchmark layouts [--split test] [--json out.json] \
        recipe=<ckpt or hub name> recipe=<another seed> prior=canonical-prior.floaff-dense-layouts.v9 ...

Every view of a test scene asks the same question about one kitchen, and a model tends to choose the same
target-relative cell in most of them, so one scene's 200 views are not 200 independent trials: a scene adds
or removes its whole weight at once. ``floaff-zoo test``'s bootstrap resamples views and says nothing about
that. This script scores each model's argmax as ``RolloutSuccessRate`` chooses it (top 1) by the annotated
outcome of the chosen cell (the test's SR: the test replays the annotation's episode at the annotation's exact pose
and refuses the cells it filtered; before 2026-12-06 it parked at a pose rebuilt from float32, which changed 4
outcomes in 51,859 view evaluations, ``docs/results.md``), then reports:

- SR per scene, per task and over all views, for every NAME (runs given under one NAME, e.g. seeds, are averaged
  per scene: a row of the tables);
- a **scene bootstrap**: the test scenes of each task resampled with replacement (``--draws`` times), SR_all
  recomputed; its std is the error bar of SR_all over kitchens;
- for every pair of NAMEs, the difference of SR_all with its scene-bootstrap 90 % interval (paired: the same
  resampled scenes for both);
- **why the chosen cells fail**: per task, the share of views whose chosen cell the annotation marks as a success,
  refused for the base footprint over furniture (``filtered_collision``), out of reach (``filtered_reach``), without
  an arm solution (``ik_unreachable``), or rolled out and failed (``rollout``: a collision, a door not opened...),
  runs averaged: what a better free-space reading could win, and what only a better reading of the task could.

``--residual-scales 0,0.5`` also scores every NAME whose runs all predict a residual over the canonical prior
(``CFARModule`` with ``prior_residual``) with the learned residual logit scaled by each value (``residual_scale``;
0 = the checkpoint's own prior with its AxisNet yaw), as NAME@0, NAME@0.5.

``--ensemble`` also scores every NAME with two runs or more as one model, NAME+ens, that averages its runs' maps
before the argmax (a deep ensemble: it costs the runs' training budgets together, so it is a diagnostic of seed
variance, not a row of an equal-budget table).

``--top-k 10`` stands each view on the best of its top 10 cells whose base footprint is free in the view's own cloud
(the callback's ``free_space: cloud`` footprint check) instead of the argmax; ``--footprint-margin 0.05`` grows the
checked footprint by 5 cm on every side (a cloud too sparse to put two points into a thin overlap with furniture
may still put them just outside it); ``--full-cloud`` checks it in every point the view's file stores (4,096 in the
``dense`` preset, what the robot's depth image gave) instead of the ``--num-points`` sample the network reads;
``--min-observed 0.5`` prefers, among the free cells, those whose footprint that cloud shows on half its 0.1 m
sub-squares or more (``floor.footprint_coverage``; a rejected hypothesis, not offered by the callback: docs/results.md,
"Preferring footprints the view shows").

``--deploy-queries`` asks every model about the floor cells a robot would build itself (``floaff-zoo predict``'s
default grid: the observed cells of a 0.1 m lattice aligned with the heading from the robot to the target, in the
same window, read from every point the view's file stores) instead of the benchmark's floor points, which are cells of
the annotation's lattice, aligned with the simulator's target frame: their arrangement gives that frame away to a
model whose floor encoder reads the query set. Each chosen cell is then scored by the annotated outcome of the
nearest label cell within half a cell's diagonal; a choice farther from every label cell (outside the annotation's
window) counts as a failure, reason ``off_grid``. The nearest-cell outcome is an approximation (the base stands up to
7 cm from where the annotation rolled out), the same for every model: a query-independent model's change measures it.

``--target-from-mask`` (with ``--deploy-queries``) also gives every model the target point ``floaff_zoo.predict``
estimates from an RGB-D view without a known target: the centroid of the points that carry the target flag, instead
of the task's target point (the centre of the fixture's front face), and builds the robot's grid around it.

Labels only, no simulator; one to two minutes per model and benchmark on one core.
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import sys
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fresh_sr import nearest_cells, split_data  # noqa: E402
from script_cli import floor_model, refuse_folders  # noqa: E402
from sr_json import sr_all  # noqa: E402

from floaff_zoo.atomic import atomic_write_text  # noqa: E402
from floaff_zoo.callbacks.rollout import check_clouds, choose_pose, cloud_free, cloud_observed  # noqa: E402
from floaff_zoo.contract import TASKS  # noqa: E402
from floaff_zoo.predict import named_models  # noqa: E402
from floaff_zoo.sim.annotate import SKIPPED_REASON  # noqa: E402
from floaff_zoo.sim.fileformat import BENCHMARKS  # noqa: E402

# per view: (task, scene id, {name: [outcome per run]}, {name: [annotation reason of the chosen cell per run]})
Row = tuple[str, str, dict[str, list[bool]], dict[str, list[str]]]
#: the annotation's reasons kept apart in the breakdown; every other one is a failed rollout
REASONS = ("success", "filtered_collision", "filtered_reach", "ik_unreachable")
#: ``--deploy-queries``: a chosen cell with no label cell within half a cell's diagonal (outside the label window)
OFF_GRID = "off_grid"
#: a cell a budgeted preset (``tiny``, CI) never rolled out: labelled a failure, but no rollout failed there
SKIPPED = SKIPPED_REASON


def parse_models(specs: list[str]) -> dict[str, list[str]]:
    """['name=model', ...] -> {name: [model, ...]} in order; a bare model is its own name."""
    try:
        return named_models(specs)
    except ValueError as exc:
        raise SystemExit(f"scene_sr: {exc}") from exc


def parse_scales(text: str | None) -> list[float]:
    """'0,0.5,1.5' -> [0.0, 0.5, 1.5]; every value finite and >= 0."""
    if text is None:  # an empty text is refused below: it scored no scaled row, without a word
        return []
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise SystemExit(f"scene_sr: --residual-scales takes comma-separated numbers, got {text!r}") from None
    if not all(np.isfinite(v) and v >= 0 for v in vals):
        raise SystemExit(f"scene_sr: --residual-scales must be finite and >= 0, got {text!r}")
    return vals


def with_residual_scales(nets: dict[str, list], scales: list[float]) -> dict[str, list]:
    """Add NAME@s (copies of NAME's runs with ``residual_scale = s``) for every NAME whose runs have a prior.

    Raises:
        ValueError: scales are given but no NAME's runs all have a prior (the option would add no row).
    """
    out = dict(nets)
    scaled = [name for name, runs in nets.items() if all(getattr(r, "prior", None) is not None for r in runs)]
    if scales and not scaled:
        raise ValueError(
            "--residual-scales scales the residual of prior-residual models (CFARModule with prior_residual): "
            f"no NAME's runs all have one ({', '.join(nets)})"
        )
    taken = [f"{name}@{s:g}" for name in scaled for s in scales if f"{name}@{s:g}" in nets]
    if taken:  # the scaled copies replaced that NAME's own runs without a word
        raise ValueError(f"--residual-scales would name rows {taken}, which are NAMEs given: rename them")
    for name in scaled:
        runs = nets[name]
        for s in scales:
            copies = [copy.deepcopy(r) for r in runs]
            for c in copies:
                c.hparams["residual_scale"] = s
            out[f"{name}@{s:g}"] = copies
    return out


def ensembled(groups: dict[str, list]) -> list[str]:
    """The NAMEs that get an ensemble row: those given two runs or more."""
    return [name for name, runs in groups.items() if len(runs) > 1]


def ensemble_scores(scores: dict[str, list[np.ndarray]]) -> dict[str, list[np.ndarray]]:
    """Add NAME+ens, the mean of NAME's runs' scores (one run, [B, M]), for every NAME with two runs or more."""
    return {**scores, **{f"{name}+ens": [np.mean(np.stack(scores[name]), axis=0)] for name in ensembled(scores)}}


def deployment_queries(batch: dict, cell: float) -> dict:
    """The batch with its floor points replaced by the cells a robot builds (``predict.default_floor_grid`` over
    every stored point of the view, ``full_xyz``; no target yaw: the lattice faces the robot): floor_xyz [B, M', 3],
    floor_mask [B, M'], floor_label 0 (unknown; models do not read it).

    Raises:
        ValueError: the batch has no stored cloud, or a view shows no floor cell around its target.
    """
    from floaff_zoo.contract import SampleError
    from floaff_zoo.predict import default_floor_grid

    cloud, cloud_mask = check_clouds(batch, "full_cloud")
    grids = []
    for i, meta in enumerate(batch["meta"]):
        try:
            grids.append(default_floor_grid(batch["target_xyz"][i].numpy(), cloud[i][cloud_mask[i]], None, cell))
        except SampleError as exc:
            raise ValueError(f"view {meta.get('sample_id', i)}: {exc}") from exc
    m = max(len(g) for g in grids)
    floor = torch.zeros(len(grids), m, 3)
    mask = torch.zeros(len(grids), m, dtype=torch.bool)
    for i, g in enumerate(grids):
        floor[i, : len(g)] = torch.from_numpy(g)
        mask[i, : len(g)] = True
    return {**batch, "floor_xyz": floor, "floor_mask": mask, "floor_label": torch.zeros(len(grids), m)}


def mask_centroid_targets(batch: dict) -> tuple[dict, int]:
    """(the batch with target_xyz [B, 3] replaced by the centroid of each view's points flagged as the target
    (``scene_feat`` channel 0 > 0), what ``predict`` uses when it is given no target point; the number of views
    whose sample holds no flagged point and keep the task's target point: the stored cloud, which ``predict``
    would read whole, has flagged points in every view, but the batch carries their flags for its sample only)."""
    flag = (batch["scene_feat"][..., 0] > 0) & batch["scene_mask"]
    counts = flag.sum(dim=1)
    centroid = (batch["scene_xyz"] * flag[..., None]).sum(dim=1) / counts.clamp_min(1)[:, None]
    target = torch.where((counts > 0)[:, None], centroid.to(batch["target_xyz"].dtype), batch["target_xyz"])
    return {**batch, "target_xyz": target}, int((counts == 0).sum())


def label_cell(cand: np.ndarray, xy: Sequence[float], cell: float, where: str, off_grid: bool) -> int | None:
    """Index of the label cell under a world point xy [2] (cand [M, 2]): within half a cell, or with ``off_grid``
    within half a cell's diagonal (a lattice of another orientation), else None; without ``off_grid`` a point off
    the grid is an error."""
    if not off_grid:
        return int(nearest_cells(cand, np.array([xy[:2]]), cell, where)[0])
    d = np.linalg.norm(cand - np.asarray(xy[:2], float), axis=1)
    c = int(d.argmin())
    return c if d[c] <= 0.5 * math.sqrt(2.0) * cell + 1e-6 else None


def view_outcomes(
    batch: dict,
    scores: dict[str, list[np.ndarray]],
    scenes: dict[str, dict],
    top_k: int = 1,
    margin: float = 0.0,
    full_cloud: bool = False,
    min_observed: float = 0.0,
    off_grid: bool = False,
) -> list[Row]:
    """Annotated outcome of each run's chosen cell, per view of a batch (scores: name -> per run [B, M]).

    ``top_k`` > 1: the best of the top-k cells whose base footprint is free in the view's own cloud, as
    ``RolloutSuccessRate(top_k=k, free_space="cloud")`` chooses (each candidate's footprint checked at the pose the
    callback rolls out: the annotation's exact one where ``meta['sim']`` gives ``target_world``), the footprint grown
    by ``margin`` (m) on every side;
    ``full_cloud``: in every point the view's file stores (the batch's ``full_xyz``: ``check_clouds``), not the
    batch's sample; ``min_observed`` > 0: free cells whose footprint that cloud shows on at least this share come
    first (``cloud_observed``); ``off_grid``: the batch's floor points are not label cells (``deployment_queries``),
    a choice is scored by the nearest label cell, and one outside the annotation's window fails (``OFF_GRID``).
    """
    from floaff_zoo.sim.kitchen import SceneSpec

    floor, mask, target = (batch[k].numpy() for k in ("floor_xyz", "floor_mask", "target_xyz"))
    if top_k > 1:
        cloud, cloud_mask = check_clouds(batch, "full_cloud" if full_cloud else "cloud")
    rows = []
    for i, meta in enumerate(batch["meta"]):
        sim = meta["sim"]
        sid = SceneSpec.from_dict(sim).scene_id
        if sid not in scenes:
            raise KeyError(f"view {meta.get('sample_id', i)}: scene {sid} is not under the data root")
        scene = scenes[sid]
        cand = np.asarray(scene["candidates"]["xy"], float)
        cell = float(scene["candidates"]["cell"])
        success = np.asarray(scene["labels"]["success"]) > 0
        free = prefer = None
        if top_k > 1:
            free = cloud_free(cloud[i][cloud_mask[i]], sim["base_pose_world"], margin)
            if min_observed > 0:
                prefer = cloud_observed(cloud[i][cloud_mask[i]], sim["base_pose_world"], min_observed)
        reasons = scene["labels"].get("reasons")
        out: dict[str, list[bool]] = {}
        why: dict[str, list[str]] = {}
        base, tie = sim["base_pose_world"], int(meta.get("index", i))
        # the footprint check reads the pose the callback rolls out, the annotation's exact one, not the view's float32
        facing = sim.get("target_world")
        for name, runs in scores.items():
            out[name], why[name] = [], []
            for s in runs:
                pose, _ = choose_pose(floor[i], s[i], mask[i], target[i], base, top_k, free, tie, prefer, facing)
                c = label_cell(cand, pose, cell, sid, off_grid)
                out[name].append(c is not None and bool(success[c]))
                if c is None:
                    why[name].append(OFF_GRID)
                else:
                    why[name].append(failure_kind(reasons[c]) if reasons is not None else "unknown")
        rows.append((meta["task"], sid, out, why))
    return rows


def failure_kind(reason: str) -> str:
    """An annotation reason as a column of the breakdown: one of ``REASONS``, ``SKIPPED`` (counted as a failed
    rollout before) or ``rollout``."""
    return reason if reason in (*REASONS, SKIPPED) else "rollout"


def breakdown_columns(shares: dict[str, dict[str, dict[str, float]]]) -> list[str]:
    """The columns of the printed breakdown: ``REASONS`` and ``rollout``, then ``unknown``, ``off_grid`` and
    ``skipped_budget`` where some name's views have them."""
    extra = ("unknown", OFF_GRID, SKIPPED)
    return [*REASONS, "rollout"] + [k for k in extra if any(k in t["all"] for t in shares.values())]


def reason_shares(rows: list[Row], names: list[str]) -> dict[str, dict[str, dict[str, float]]]:
    """name -> task (and ``all``) -> {kind: share of views}, runs averaged; kinds: ``REASONS``, ``rollout``
    (and ``unknown`` for scenes written before the annotation kept its reasons)."""
    counts: dict[str, dict[str, dict[str, float]]] = {n: defaultdict(lambda: defaultdict(float)) for n in names}
    views: dict[str, int] = defaultdict(int)
    for task, _sid, _out, why in rows:
        views[task] += 1
        views["all"] += 1
        for n in names:
            for kind in why[n]:
                for t in (task, "all"):
                    counts[n][t][kind] += 1.0 / len(why[n])
    order = sorted(set(views) - {"all"}) + ["all"]
    return {n: {t: {k: v / views[t] for k, v in sorted(counts[n][t].items())} for t in order} for n in names}


def per_scene(rows: list[Row], names: list[str]) -> dict[str, dict]:
    """scene id -> {task, views, SR per name (runs averaged)}."""
    acc: dict[str, dict] = {}
    for task, sid, out, *_ in rows:
        a = acc.setdefault(sid, {"task": task, "views": 0, "sum": defaultdict(float)})
        a["views"] += 1
        for n in names:
            a["sum"][n] += float(np.mean(out[n]))
    return {
        sid: {"task": a["task"], "views": a["views"], "sr": {n: a["sum"][n] / a["views"] for n in names}}
        for sid, a in sorted(acc.items())
    }


def scenes_by_task(scenes: dict[str, dict]) -> dict[str, list[str]]:
    """task -> its scene ids, tasks in sorted order."""
    by_task: dict[str, list[str]] = defaultdict(list)
    for sid, s in scenes.items():
        by_task[s["task"]].append(sid)
    return dict(sorted(by_task.items()))


def scene_bootstrap(scenes: dict[str, dict], names: list[str], draws: int, seed: int) -> np.ndarray:
    """[draws, len(names)] SR_all with the scenes of each task resampled with replacement."""
    rng = np.random.default_rng(seed)
    by_task = scenes_by_task(scenes)
    out = np.empty((draws, len(names)))
    for d in range(draws):
        ids = [sid for t in by_task for sid in rng.choice(by_task[t], size=len(by_task[t]))]
        out[d] = [sr_all(scenes, ids, n) for n in names]
    return out


def summarize(scenes: dict[str, dict], names: list[str], draws: int, seed: int) -> dict:
    """SR per task and over all views, scene-bootstrap std, and paired differences with 90 % intervals."""
    by_task = scenes_by_task(scenes)
    boot = scene_bootstrap(scenes, names, draws, seed)
    res: dict = {"models": {}, "differences": {}}
    for k, n in enumerate(names):
        tasks = {t: sr_all(scenes, ids, n) for t, ids in by_task.items()}
        res["models"][n] = {
            "sr_all": sr_all(scenes, list(scenes), n),
            "scene_bootstrap_std": float(boot[:, k].std()),
            **tasks,
        }
    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            d = boot[:, a] - boot[:, b]
            res["differences"][f"{names[a]} - {names[b]}"] = {
                "diff": res["models"][names[a]]["sr_all"] - res["models"][names[b]]["sr_all"],
                "p05": float(np.quantile(d, 0.05)),
                "p95": float(np.quantile(d, 0.95)),
            }
    return res


def print_scenes(table: dict[str, dict], names: list[str], extra: str | None = None) -> None:
    """Print SR per scene and name (``per_scene``'s table); ``extra``: a per-scene field shown after the id."""
    cols = [extra] if extra else []
    print("| scene | " + "".join(f"{c} | " for c in cols) + "task | views | " + " | ".join(names) + " |")
    print("|---|" + "---:|" * len(cols) + "---|---:|" + "---:|" * len(names))
    for sid, s in table.items():
        lead = "".join(f"{s[c]} | " for c in cols)
        print(f"| {sid} | {lead}{s['task']} | {s['views']} | " + " | ".join(f"{s['sr'][n]:.2f}" for n in names) + " |")


def print_summary(res: dict) -> None:
    """Print ``summarize``'s result: SR per name (all views, per task) and the paired differences."""
    print("| name | SR_all | scene-bootstrap std | " + " | ".join(TASKS) + " |")
    print("|---|---:|---:|" + "---:|" * len(TASKS))
    for n, m in res["models"].items():
        print(
            f"| {n} | {m['sr_all']:.3f} | {m['scene_bootstrap_std']:.3f} | "
            + " | ".join(f"{m.get(t, float('nan')):.2f}" for t in TASKS)
            + " |"
        )
    for pair, d in res["differences"].items():
        print(f"{pair}: {d['diff']:+.3f} (scene bootstrap 90 %: {d['p05']:+.3f} to {d['p95']:+.3f})")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("models", nargs="+", help="NAME=MODEL (hub name or checkpoint); repeat a NAME to pool runs")
    p.add_argument("--root", default="data/floaff_dense")
    p.add_argument("--benchmark", default="layouts", choices=BENCHMARKS)
    p.add_argument("--split", default="test", choices=["test", "val"])
    p.add_argument(
        "--val-layout",
        type=int,
        default=None,
        help="with --split val: the validation scenes are every train scene of this layout (a cross-validation fold, "
        "the DataModule's val_layout, as the models were trained)",
    )
    p.add_argument("--draws", type=int, default=2000, help="scene-bootstrap draws")
    p.add_argument("--seed", type=int, default=0, help="seed of the scene bootstrap")
    p.add_argument("--num-points", type=int, default=1024)
    p.add_argument(
        "--residual-scales",
        default=None,
        help="e.g. 0,0.5,1.5: also score prior-residual models with their residual scaled by each (NAME@s)",
    )
    p.add_argument("--top-k", type=int, default=1, help="> 1: best of the top-k cells free in the view's cloud")
    p.add_argument(
        "--footprint-margin", type=float, default=0.0, help="with --top-k: grow the checked footprint by this (m)"
    )
    p.add_argument(
        "--full-cloud",
        action="store_true",
        help="with --top-k: check the footprint in every point the view's file stores, not the network's sample",
    )
    p.add_argument(
        "--min-observed",
        type=float,
        default=0.0,
        help="with --top-k: prefer free cells whose footprint the checked cloud shows on this share of it (0 = off)",
    )
    p.add_argument("--ensemble", action="store_true", help="also score NAME+ens: the mean map of NAME's runs")
    p.add_argument(
        "--deploy-queries",
        action="store_true",
        help="ask the models about the floor cells a robot builds (predict's default grid), not the label cells",
    )
    p.add_argument(
        "--target-from-mask",
        action="store_true",
        help="with --deploy-queries: the target point is the centroid of the flagged points, as predict estimates it",
    )
    p.add_argument("--json", default=None)
    a = p.parse_args(argv)
    refuse_folders(p, json=a.json)
    if a.draws < 1:
        p.error("--draws must be >= 1")
    if a.seed < 0:  # numpy's generator takes no negative seed: a traceback after every model had been scored
        p.error(f"--seed must be >= 0, got {a.seed}")
    if a.val_layout is not None and a.split != "val":
        p.error("--val-layout chooses the validation scenes: give --split val")
    if a.top_k < 1:
        p.error(f"--top-k must be >= 1, got {a.top_k}")
    if not (np.isfinite(a.footprint_margin) and a.footprint_margin >= 0):
        p.error(f"--footprint-margin must be finite and >= 0, got {a.footprint_margin}")
    if a.footprint_margin > 0 and a.top_k == 1:
        p.error("--footprint-margin grows the footprint that --top-k checks: give --top-k > 1")
    if not 0.0 <= a.min_observed <= 1.0:
        p.error(f"--min-observed must be in [0, 1], got {a.min_observed}")
    if a.min_observed > 0 and a.top_k == 1:
        p.error("--min-observed orders the cells that --top-k checks: give --top-k > 1")
    if a.target_from_mask and not a.deploy_queries:
        p.error("--target-from-mask moves the target the robot's grid is built around: give --deploy-queries")
    if a.full_cloud and a.top_k == 1:
        p.error("--full-cloud chooses the cloud that --top-k checks: give --top-k > 1")
    scales = parse_scales(a.residual_scales)
    groups = parse_models(a.models)
    if a.ensemble and not ensembled(groups):
        p.error("--ensemble averages the runs of one NAME: give some NAME two runs or more (NAME=a.ckpt NAME=b.ckpt)")
    if a.ensemble and (taken := [f"{n}+ens" for n in ensembled(groups) if f"{n}+ens" in groups]):
        p.error(f"--ensemble would name rows {taken}, which are NAMEs given: rename them")  # replaced their runs

    try:  # a bad model name, or one without a floor map, ends here with its message, before any data is read
        runs = {n: [floor_model(m, f"scene_sr: {m}") for m in ms] for n, ms in groups.items()}
        nets = with_residual_scales(runs, scales)
    except (OSError, ValueError, LookupError) as exc:
        raise SystemExit(f"scene_sr: {exc}") from exc
    stored = a.full_cloud or a.deploy_queries  # the deployment grid reads every stored point, as predict does
    dm, scenes = split_data("scene_sr", a.root, a.benchmark, a.split, a.num_points, stored, val_layout=a.val_layout)
    cells = {float(s["candidates"]["cell"]) for s in scenes.values()}
    rows: list[Row] = []
    kept_targets = 0  # --target-from-mask: views whose sample shows no target point (they keep the task's)
    with torch.no_grad():
        for batch in dm.test_dataloader() if a.split == "test" else dm.val_dataloader():
            if a.deploy_queries:
                try:
                    if a.target_from_mask:
                        batch, kept = mask_centroid_targets(batch)
                        kept_targets += kept
                    batch = deployment_queries(batch, min(cells))
                except ValueError as exc:
                    raise SystemExit(f"scene_sr: {exc}") from exc
            scores = {n: [net(batch).numpy() for net in runs] for n, runs in nets.items()}
            if a.ensemble:
                scores = ensemble_scores(scores)
            try:
                rows += view_outcomes(
                    batch, scores, scenes, a.top_k, a.footprint_margin, a.full_cloud, a.min_observed, a.deploy_queries
                )
            except (KeyError, ValueError) as exc:  # a view whose scene is not under the root, a point off its grid
                raise SystemExit(f"scene_sr: {exc.args[0]}") from exc
    n_runs = {n: len(r) for n, r in nets.items()}
    if a.ensemble:
        n_runs.update({f"{n}+ens": 1 for n in ensembled(nets)})
    names = list(n_runs)
    table = per_scene(rows, names)
    res = summarize(table, names, a.draws, a.seed)

    print(
        f"{a.benchmark} {a.split}: {len(rows)} views in {len(table)} scenes; runs per name: "
        + ", ".join(f"{n} {k}" for n, k in n_runs.items())
    )
    if a.target_from_mask:
        print(f"--target-from-mask: {kept_targets} view(s) with no flagged point in the sample kept the task's target")
    print_scenes(table, names)
    print()
    print_summary(res)
    shares = reason_shares(rows, names)
    kinds = breakdown_columns(shares)
    print()
    print("Share of views by the annotation's verdict on the chosen cell:")
    print("| name | task | " + " | ".join(kinds) + " |")
    print("|---|---|" + "---:|" * len(kinds))
    for n, by_task in shares.items():
        for t, by_kind in by_task.items():
            print(f"| {n} | {t} | " + " | ".join(f"{by_kind.get(k, 0.0):.2f}" for k in kinds) + " |")
    if a.json:
        runs = {n: groups[n] if n in groups else groups[n.rpartition("@")[0]] for n in nets}
        runs.update({n: runs[n.removesuffix("+ens")] for n in names if n not in runs})
        out = {
            "benchmark": a.benchmark,
            "split": a.split,
            "val_layout": a.val_layout,
            "runs": runs,
            "residual_scales": scales,
            "ensemble": a.ensemble,
            "top_k": a.top_k,
            "footprint_margin": a.footprint_margin,
            "full_cloud": a.full_cloud,
            "min_observed": a.min_observed,
            "deploy_queries": a.deploy_queries,
            "target_from_mask": a.target_from_mask,
            "views_keeping_the_target": kept_targets if a.target_from_mask else None,
            "draws": a.draws,
            "seed": a.seed,  # the bootstrap's: its intervals repeat only with it
            "scenes": table,
            **res,
            "reasons": shares,
        }
        atomic_write_text(a.json, json.dumps(out, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from script_cli import run

    raise SystemExit(run(main, "scene_sr"))
