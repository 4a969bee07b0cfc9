"""FloAff benchmark generator: build scenes, annotate floor candidates with rollouts, render front/side views, write.

    floaff-zoo generate --preset small --out data/floaff_sim [--workers N] [--backend local|ray] [--seed S] ...

Determinism: every scene slot (benchmark, task, split, index) gets its seed from a hash of (global seed, benchmark,
task, split, index, attempt), never from worker order, and each scene is generated start to finish by one worker with
single-threaded annotation, so the output does not depend on the worker count or back end. A slot whose scene has no
positive candidate is dropped and retried with the next attempt's seed (up to ``max_seed_attempts``), as the paper
drops scenes without positives; so is a kitchen whose furniture keeps a part the task's reset opens below half its
travel (``Task.blocked_parts``), before it is annotated. Wall times live only in manifest.json.

Floor points (format 2, GENERATOR_VERSION 2.x): each view stores the cells of the scene's label grid (the annotation's
target-centred window and cell) that hold at least one ground point of THAT view's cloud (``floaff_zoo.floor``:
z < FLOOR_Z_MAX), labelled by ``annotate.cell_labels``: what the robot could know from its view, not the filtered
candidate set. A view whose observed floor holds no cell at all, no cell with a successful rollout, or whose
best-labelled observed cell failed (``view_rejection``) is rejected and resampled like a view that misses the target;
rejections are counted in scene.json and the manifest.

Robustness: a scene is written into ``<benchmark>/.staging/<scene_id>`` and moved into place with one rename after its
scene.json is written; resume skips scenes whose scene.json says status "ok". A job that raises or whose worker process
dies is retried once, then reported "failed" in the manifest.
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import contextlib
import dataclasses
import hashlib
import itertools
import multiprocessing as mp
import numbers
import os
import shutil
import sys
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from floaff_zoo.atomic import LockedError, folder_lock
from floaff_zoo.checks import check_integer
from floaff_zoo.runtime import THREAD_ENV, exit_with_parent, one_thread_children
from floaff_zoo.sim import fileformat as ff
from floaff_zoo.sim.presets import ALL_BENCHMARKS, ALL_TASKS, PRESETS, GenPreset, get_preset, view_counts

__all__ = ["GENERATOR_VERSION", "SceneJob", "derive_seed", "generate", "main", "plan_jobs", "run_job"]

GENERATOR_VERSION = "2.3.1"
#: task reset seed of the rollouts (annotate_scene) and of the rendered views, so both see the same fixture state
ANNOTATE_SEED = 0


# ------------------------------------------------------------------------------------------------ planning
def check_seed(seed: object) -> None:
    """ValueError unless ``seed`` is an integer (any sign; not a bool): ``int()`` cut 1.5 to seed 1, recorded as 1."""
    if not isinstance(seed, numbers.Integral) or isinstance(seed, bool):
        raise ValueError(f"seed must be an integer, got {seed!r}")


def derive_seed(global_seed: int, *parts: Any) -> int:
    """Deterministic 31-bit seed from the global seed and identifying parts (independent of PYTHONHASHSEED)."""
    check_seed(global_seed)
    key = "|".join([str(int(global_seed))] + [str(p) for p in parts]).encode()
    return int.from_bytes(hashlib.sha256(key).digest()[:4], "little") & 0x7FFFFFFF


@dataclass(frozen=True)
class SceneJob:
    """One scene slot to fill. seeds: the per-attempt scene seeds (tried in order until a scene has a positive)."""

    benchmark: str
    task: str
    split: str
    slot: int
    layout_id: int
    style_id: int
    seeds: tuple[int, ...]
    n_front: int
    n_side: int

    @property
    def key(self) -> str:
        return f"{self.benchmark}/{self.task}/{self.split}{self.slot}"


def _split_ids(ids: list[int], name: str) -> tuple[list[int], int]:
    """Sorted ids -> (seen ids, held-out id = the last one)."""
    if len(set(ids)) < len(ids):  # a repeated held-out id was also a seen one: the test split was not unseen
        raise ValueError(f"{name} ids given more than once: {ids}")
    if len(ids) < 2:
        raise ValueError(f"need at least 2 {name} ids to hold one out for the test split, got {ids}")
    ids = sorted(ids)
    return ids[:-1], ids[-1]


def plan_jobs(
    preset: GenPreset,
    seed: int,
    layout_ids: list[int],
    style_ids: list[int],
) -> list[SceneJob]:
    """All scene slots of a run, in a fixed order (benchmark, task, split, slot).

    Styles: training scenes cycle over the seen layouts and seen styles; the test scene uses the first seen layout
    with the held-out (unseen) style. Layouts: training scenes cycle over seen layouts (and seen styles); the test
    scene uses the held-out layout with the first seen style.
    """
    seen_l, held_l = _split_ids(layout_ids, "layout")
    seen_s, held_s = _split_ids(style_ids, "style")
    jobs: list[SceneJob] = []
    for bench in preset.benchmarks:
        for task in preset.tasks:
            ti = ALL_TASKS.index(task)  # not the position in --tasks: adding or reordering tasks keeps every kitchen
            for split, n in (("train", preset.n_train), ("test", preset.n_test)):
                for i in range(n):
                    if split == "train":
                        lay = seen_l[(i + ti) % len(seen_l)]
                        sty = seen_s[(i + 2 * ti) % len(seen_s)]
                    elif bench == "styles":
                        lay, sty = seen_l[(i + ti) % len(seen_l)], held_s
                    else:
                        lay, sty = held_l, seen_s[(i + ti) % len(seen_s)]
                    seeds = tuple(derive_seed(seed, bench, task, split, i, a) for a in range(preset.max_seed_attempts))
                    nf, ns = view_counts(preset, bench, task, split, i)
                    jobs.append(SceneJob(bench, task, split, i, lay, sty, seeds, nf, ns))
    return jobs


# ------------------------------------------------------------------------------------------------ one scene
def _spec(job: SceneJob, seed: int):
    from floaff_zoo.sim.kitchen import SceneSpec

    return SceneSpec(layout_id=job.layout_id, style_id=job.style_id, seed=seed, task=job.task)


def _scene_id(spec: Any) -> str:
    sid = spec.scene_id
    return sid() if callable(sid) else str(sid)


def same_generator(rec: dict[str, Any]) -> bool:
    """Whether a scene record was made by this format version and this generator's major.minor (what resume keeps:
    another's labels or views may differ)."""
    made = ff.labels_version(str(rec.get("generator_version", "")))
    return rec.get("format_version", 1) == ff.FORMAT_VERSION and made == ff.labels_version(GENERATOR_VERSION)


def find_done(out: Path, job: SceneJob, min_views: int = 0) -> str | None:
    """scene_id of an already committed scene of this slot (any attempt) in this format version, else None.

    A scene of another format version (an older generator) is not resumed: it is regenerated, so one dataset never
    mixes floor rules; nor is a scene of another generator minor version (its rollouts, hence labels, or its views
    may differ: 2.1 changed the CloseDoubleDoor push, 2.2 refuses views past a wall or with the camera in furniture,
    2.3 moves the side runs of corner layouts off the back run's fronts).
    Nor is a scene drawn with another top-up (``min_views`` in its scene.json; a scene written before the field
    existed counts as topped up when it holds at least ``min_views`` views).
    """
    for sid in _seed_scene_ids(job):
        rec = ff.committed_record(out, job.benchmark, sid)
        if rec is not None:
            if rec.get("slot") != job.key or not same_generator(rec):
                continue
            if rec.get("views_requested", [job.n_front, job.n_side]) != [job.n_front, job.n_side]:
                continue  # the paper preset's counts per scene follow --n-train / --n-test
            if "min_views" in rec:
                topped_up = rec["min_views"] == min_views
            else:
                topped_up = len(rec.get("views", [])) >= min_views
            if topped_up:
                return sid
    return None


def _seed_scene_ids(job: SceneJob) -> list[str]:
    """The scene_ids the slot's seed attempts draw, in attempt order: the only scenes a job of it commits."""
    return [_scene_id(_spec(job, s)) for s in job.seeds]


def slot_scenes(out: Path, job: SceneJob, ids: list[str] | None = None) -> list[str]:
    """scene_ids of the committed scenes of this slot (any format or generator version, any kitchen: a scene drawn
    when the slot had another layout or style, by an older generator, is found too), by the slot in their scene.json.

    What a rerun that regenerates the slot must move out of the readers' way; found without the previous manifest,
    which an interrupted rerun leaves without the slot's scene_id. ``ids``: the scenes of the benchmark to look at
    (default every one; a run that read them all at its start passes the slot's scenes then and
    :func:`_seed_scene_ids`, instead of reading every scene.json again after each job).
    """
    if ids is None:
        dirs = committed_scene_dirs(out)
    else:
        dirs = [
            d for d in (ff.scene_dir(out, job.benchmark, s) for s in sorted(set(ids))) if (d / ff.SCENE_JSON).is_file()
        ]
    return scenes_by_slot(dirs).get((job.benchmark, job.key), [])


def scenes_by_slot(dirs: list[Path]) -> dict[tuple[str, str], list[str]]:
    """(benchmark, slot key) -> scene_ids of the scene folders ``dirs`` (``committed_scene_dirs``), by the slot their
    scene.json names, each read once; a folder whose scene.json does not parse or names no slot is left out."""
    return slots_of(read_records(dirs))


def read_records(dirs: list[Path]) -> dict[tuple[str, str], Any]:
    """(benchmark, scene_id) -> the parsed scene.json of each scene folder of ``dirs``, in their order, each read
    once; a folder whose scene.json does not parse is left out."""
    records: dict[tuple[str, str], Any] = {}
    for d in dirs:
        try:
            records[(d.parent.name, d.name)] = ff.read_json(d / ff.SCENE_JSON)
        except ff.FormatError:
            continue
    return records


def slots_of(records: dict[tuple[str, str], Any]) -> dict[tuple[str, str], list[str]]:
    """(benchmark, slot key) -> scene_ids of ``read_records``' records, by the slot each names (none: left out)."""
    found: dict[tuple[str, str], list[str]] = {}
    for (bench, sid), rec in records.items():
        if isinstance(rec, dict) and isinstance(rec.get("slot"), str):
            found.setdefault((bench, rec["slot"]), []).append(sid)
    return found


def committed_scene_dirs(out: Path) -> list[Path]:
    """Every folder under ``out`` that the readers would take for a scene (a scene.json inside), any benchmark."""
    return sorted(
        d
        for b in ALL_BENCHMARKS
        if (out / b).is_dir()
        for d in (out / b).iterdir()
        if d.is_dir() and not d.name.startswith(".") and (d / ff.SCENE_JSON).is_file()
    )


def _inside_polys(xy: np.ndarray, polys: list[np.ndarray], margin: float = 0.0) -> np.ndarray:
    """Points [M,2] inside (or within `margin` of) any convex polygon [K,2] -> bool [M]."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    hit = np.zeros(len(xy), dtype=bool)
    for poly in polys:
        p = np.asarray(poly, dtype=np.float64).reshape(-1, 2)
        if len(p) < 3:
            continue
        e = np.roll(p, -1, axis=0) - p  # edges [K,2]
        rel = xy[:, None, :] - p[None, :, :]  # [M,K,2]
        cross = e[None, :, 0] * rel[..., 1] - e[None, :, 1] * rel[..., 0]  # [M,K]
        hit |= np.all(cross > 0, axis=1) | np.all(cross < 0, axis=1)
        if margin > 0:  # distance to each edge segment
            t = np.clip((rel * e[None]).sum(-1) / np.maximum((e * e).sum(-1), 1e-12)[None], 0.0, 1.0)
            d = np.linalg.norm(rel - t[..., None] * e[None], axis=-1).min(axis=1)
            hit |= d < margin
    return hit


def floor_cells(
    grid_xy: np.ndarray,
    grid_shape: tuple[int, int],
    polys: list[np.ndarray],
    target_xy: np.ndarray,
    target_yaw: float,
    cell: float,
) -> np.ndarray:
    """Grid cells [M,2] (row-major, grid_shape (H, W)) that are free floor of the room in front of the target.

    A cell is floor when its centre is outside every furniture/wall footprint and it is connected (4-neighbours)
    to the cell nearest 0.7 m in front of the target without crossing footprints grown by half a cell (so thin
    walls cannot be leaked through): this drops cells inside furniture and behind walls, which are no ground points.
    Returns bool [M].
    """
    from collections import deque

    from floaff_zoo.sim.views import world_to_target

    xy = np.asarray(grid_xy, dtype=np.float64).reshape(-1, 2)
    h, w = (int(v) for v in grid_shape)
    if h * w != len(xy):
        raise ValueError(f"grid_shape {grid_shape} does not match {len(xy)} cells")
    inside = _inside_polys(xy, polys)
    blocked = (inside | _inside_polys(xy, polys, margin=cell / 2)).reshape(h, w)
    xo = world_to_target(xy, target_xy, target_yaw)
    open_idx = np.flatnonzero(~blocked.ravel())
    if open_idx.size == 0:
        return ~inside
    seed = open_idx[np.argmin(np.hypot(xo[open_idx, 0], xo[open_idx, 1] + 0.7))]
    reach = np.zeros((h, w), dtype=bool)
    q = deque([divmod(int(seed), w)])
    reach[q[0]] = True
    while q:
        r, c = q.popleft()
        for rr, cc in ((r + 1, c), (r - 1, c), (r, c + 1), (r, c - 1)):
            if 0 <= rr < h and 0 <= cc < w and not reach[rr, cc] and not blocked[rr, cc]:
                reach[rr, cc] = True
                q.append((rr, cc))
    # the ring next to the reached area (near a footprint but outside it) is floor too
    ring = np.zeros_like(reach)
    ring[1:] |= reach[:-1]
    ring[:-1] |= reach[1:]
    ring[:, 1:] |= reach[:, :-1]
    ring[:, :-1] |= reach[:, 1:]
    return ((reach | ring).ravel()) & ~inside


def _arr(x: Any, dtype: Any = np.float64) -> np.ndarray:
    return np.asarray(x, dtype=dtype)


def grid_lattice(
    grid_xy: np.ndarray, grid_shape: tuple[int, int], cell: float, target_xy: np.ndarray, target_yaw: float
) -> Any:
    """The ``floaff_zoo.floor.FloorLattice`` of an annotation grid (world frame); checks it reproduces grid_xy [M,2]."""
    from floaff_zoo.floor import FloorLattice

    h, w = (int(v) for v in grid_shape)
    if h % 2 == 0 or w % 2 == 0:
        raise ValueError(f"annotation grid shape {grid_shape} is not target-centred (odd sizes expected)")
    lat = FloorLattice(
        (float(target_xy[0]), float(target_xy[1])),
        float(target_yaw) + np.pi / 2,
        float(cell),
        ((h - 1) // 2, (w - 1) // 2),
    )
    err = float(np.abs(lat.centers() - np.asarray(grid_xy, dtype=np.float64).reshape(-1, 2)).max(initial=0.0))
    if err > 1e-4:
        raise ValueError(f"the floor lattice does not reproduce the annotation grid (max error {err:.3g} m)")
    return lat


def view_rejection(seen: np.ndarray, cell_label: np.ndarray, success: np.ndarray) -> str | None:
    """Why a view with observed cells seen [M] bool is not kept (None: keep), given the v2 labels [M] and rollout
    success [M] bool: it sees no grid cell ("no_floor_cell"), no cell whose rollout succeeded ("no_positive_cell"),
    or its best-labelled cells include a failed one ("best_cell_fails": the smoothed map of successes it does not
    see outranks the ones it sees, so the label's own argmax would fail)."""
    if not seen.any():
        return "no_floor_cell"
    if not (seen & success).any():
        return "no_positive_cell"
    lab = np.where(seen, cell_label, -np.inf)
    if not success[lab >= lab.max() - 1e-6].all():
        return "best_cell_fails"
    return None


def view_floor_cells(scene_xyz: np.ndarray, base_pose: np.ndarray, lattice: Any) -> np.ndarray:
    """Grid cells [M] bool holding a ground point of one view's base-frame cloud scene_xyz [N,3] (pose [3] world)."""
    from floaff_zoo.floor import FLOOR_Z_MAX, observed_cells
    from floaff_zoo.sim.views import base_to_world

    world = base_to_world(np.asarray(scene_xyz, dtype=np.float64), np.asarray(base_pose, dtype=np.float64))
    return observed_cells(world, lattice, FLOOR_Z_MAX)


def view_requests(job: SceneJob, preset: GenPreset, n_done: Callable[[], int]) -> Iterator[tuple[str, int]]:
    """The (view kind, count) requests of one scene, in order: the preset's front and side counts, then the top-up.

    The top-up asks each region in turn (front, then side) for the views still missing to ``preset.min_views``;
    ``n_done()`` is read after each request is served, so a region that fills the gap ends it. The same rng serves
    every request, so the views before the top-up are those a preset without it draws.
    """
    yield "front", job.n_front
    yield "side", job.n_side
    for kind in ("front", "side"):
        missing = preset.min_views - n_done()
        if missing <= 0:
            return
        yield kind, missing


def _write_scene(
    out: Path,
    job: SceneJob,
    spec: Any,
    scene: Any,
    ann: Any,
    preset: GenPreset,
    save_images: bool,
    rng_views: np.random.Generator,
) -> dict[str, Any]:
    """Render views, write everything into the staging dir, write scene.json last and commit. Returns view counts
    (both 0, and nothing committed, when no view was kept)."""
    from floaff_zoo.floor import FLOOR_Z_MAX
    from floaff_zoo.sim.annotate import cell_labels
    from floaff_zoo.sim.pictures import render_topdown_png, rgb_png
    from floaff_zoo.sim.render import Renderer
    from floaff_zoo.sim.views import ROBOT_DESCRIPTOR, ViewConfig, make_view_sample, sample_view_poses

    sid = _scene_id(spec)
    stage = ff.staging_dir(out, job.benchmark, sid)
    if stage.exists():
        shutil.rmtree(stage)
    (stage / "views").mkdir(parents=True)
    vcfg = ViewConfig(
        front_rx=preset.front_rx,
        front_ry=preset.front_ry,
        side_rx=preset.side_rx,
        side_ry=preset.side_ry,
        max_dist=preset.max_dist,
        image_size=preset.image_size,
        depth_max=preset.depth_max,
        max_points=preset.max_points,
        min_target_pixels=preset.min_target_pixels,
        max_tries_per_view=preset.max_tries_per_view,
    )
    # views see the task's reset state used by the rollouts (e.g. the drawer open for CloseDrawer): annotate_scene
    # resets with default_rng(ANNOTATE_SEED) before every rollout
    scene.reset_task(np.random.default_rng(ANNOTATE_SEED))
    grid_xy = _arr(ann.grid_xy).reshape(-1, 2)
    label = _arr(ann.label, np.float32).reshape(-1)
    tpos = _arr(scene.target.pos).reshape(3)
    tyaw = float(scene.target.yaw)
    outline = [np.asarray(p, dtype=np.float64) for p in scene.floor_outline()]
    on_floor = (
        floor_cells(grid_xy, tuple(ann.grid_shape), outline, tpos[:2], tyaw, float(ann.cell))
        if preset.floor_only
        else np.ones(len(grid_xy), dtype=bool)
    )
    if getattr(ann, "status", None) is None:
        raise ValueError("the annotation has no per-cell status (FILTERED / ROLLED_OUT / SKIPPED): use annotate_scene")
    status = _arr(ann.status, np.int8).reshape(-1)
    success = _arr(ann.success, bool).reshape(-1)
    cell_label, known = cell_labels(label, status)
    lattice = grid_lattice(grid_xy, tuple(ann.grid_shape), float(ann.cell), tpos[:2], tyaw)
    rejected = {"no_floor_cell": 0, "no_positive_cell": 0, "best_cell_fails": 0}

    def keep_view(pose: np.ndarray, obs: Any) -> bool:
        why = view_rejection(view_floor_cells(obs.scene_xyz, pose, lattice), cell_label, success)
        if why:
            rejected[why] += 1
        return not why

    views: list[dict[str, Any]] = []
    first_rgb: dict[str, np.ndarray] = {}
    renderer = Renderer(scene.model, preset.image_size, preset.image_size)
    try:
        for kind, n in view_requests(job, preset, lambda: len(views)):
            for pose, obs in sample_view_poses(scene, renderer, kind, n, vcfg, rng_views, accept=keep_view):
                vid = f"{kind}_{sum(v['view'] == kind for v in views):04d}"
                seen = view_floor_cells(obs.scene_xyz, pose, lattice)
                arrays = make_view_sample(
                    obs,
                    pose,
                    tpos,
                    tyaw,
                    grid_xy[seen],
                    cell_label[seen],
                    save_images=save_images,
                    floor_known=known[seen],
                    floor_index=np.flatnonzero(seen),
                )
                ff.validate_view(arrays, stage / "views" / f"{vid}.npz", ff.FORMAT_VERSION)
                ff.atomic_save_npz(stage / "views" / f"{vid}.npz", arrays)
                views.append(
                    {
                        "view_id": vid,
                        "view": kind,
                        "file": f"views/{vid}.npz",
                        "base_pose_world": pose.tolist(),
                        "n_points": int(len(obs.scene_xyz)),
                        "n_target_points": int(obs.n_target),
                        "n_floor_cells": int(seen.sum()),
                        "n_positive_cells": int((seen & success).sum()),
                        "n_unknown_cells": int((seen & ~known).sum()),
                    }
                )
                first_rgb.setdefault(kind, obs.rgb)
    finally:
        renderer.close()
    if not views:  # no region gave an acceptable view: a scene without one would be committed and hold no sample
        shutil.rmtree(stage, ignore_errors=True)
        return {"front": 0, "side": 0}
    valid = _arr(getattr(ann, "valid", np.ones(len(label), bool)), bool).reshape(-1)
    title = f"{job.benchmark} {job.task} {job.split} L{spec.layout_id} S{spec.style_id}"
    poses = np.array([v["base_pose_world"] + [v["view"] == "side"] for v in views], dtype=np.float64).reshape(-1, 4)
    ff.atomic_write_bytes(
        stage / "topdown.png",
        render_topdown_png(
            outline,
            grid_xy[on_floor],
            cell_label[on_floor],
            float(ann.cell),
            tpos[:2],
            tyaw,
            title,
            poses,
            preset.picture_size,
        ),
    )
    for kind in ("front", "side"):
        if kind in first_rgb:
            ff.atomic_write_bytes(stage / f"{kind}.png", rgb_png(first_rgb[kind], preset.picture_size))
    counts = {k: (int(v) if isinstance(v, (int, np.integer)) else v) for k, v in dict(ann.counts).items()}
    rec = {
        "format_version": ff.FORMAT_VERSION,
        "generator_version": GENERATOR_VERSION,
        "benchmark": job.benchmark,
        "split": job.split,
        "slot": job.key,
        "scene_id": sid,
        "spec": spec.to_dict(),
        "task": job.task,
        "target": {"pos": tpos.tolist(), "yaw": tyaw},
        "candidates": {
            "xy": grid_xy.tolist(),
            "yaw": _arr(ann.yaw).reshape(-1).tolist(),
            "valid": valid.astype(int).tolist(),
            "on_floor": on_floor.astype(int).tolist(),
            "status": status.astype(int).tolist(),
            "view_cells": "observed",
            "grid_shape": [int(v) for v in ann.grid_shape],
            "cell": float(ann.cell),
        },
        "labels": {
            "success": _arr(ann.success).reshape(-1).astype(int).tolist(),
            "label": label.astype(float).tolist(),
            "reasons": [str(r) for r in getattr(ann, "reasons", [])],
            "cell_label": cell_label.astype(float).tolist(),
            "known": known.astype(int).tolist(),
        },
        "floor_rule": {"ground_z_max": FLOOR_Z_MAX, "min_points": 1},
        "annotation_counts": counts,
        "sigma": float(preset.sigma_cells),
        "robot": [round(float(v), 6) for v in ROBOT_DESCRIPTOR],
        "views": views,
        "n_views": {"front": sum(v["view"] == "front" for v in views), "side": sum(v["view"] == "side" for v in views)},
        "min_views": int(preset.min_views),
        "views_requested": [int(job.n_front), int(job.n_side)],
        "views_rejected": rejected,
        "pictures": ["topdown.png"] + [f"{k}.png" for k in ("front", "side") if k in first_rgb],
        "status": "ok",
    }
    ff.atomic_write_json(stage / ff.SCENE_JSON, rec)  # scene.json LAST: it commits the scene
    ff.commit_scene_dir(stage, ff.scene_dir(out, job.benchmark, sid))
    return rec["n_views"]


def run_job(job: SceneJob, out: str, preset_dict: dict[str, Any], save_images: bool) -> dict[str, Any]:
    """Fill one scene slot (runs in a worker). Never raises for scene problems: returns a status record.

    status: "ok" (scene committed), "dropped" (no attempt could be reset, had a positive candidate and an acceptable
    view: each attempt records ``dropped_reset_blocked``, ``dropped_no_positive`` or ``dropped_no_view``) or "error"
    (exception; the driver retries once). Records the attempts (seed, scene_id, outcome) and timings.
    """
    from floaff_zoo.sim.annotate import annotate_scene
    from floaff_zoo.sim.kitchen import build_scene, release_scene

    preset = GenPreset.from_dict(preset_dict)
    outp = Path(out)
    t0 = time.perf_counter()
    attempts: list[dict[str, Any]] = []
    try:
        for seed in job.seeds:
            spec = _spec(job, seed)
            sid = _scene_id(spec)
            ta = time.perf_counter()
            scene = build_scene(spec)
            # no other slot or attempt draws this kitchen, and this attempt keeps its scene: without the release the
            # per-process cache of compiled kitchens grew by ~70 MB per attempt for a worker's whole run
            release_scene(spec)
            blocked = scene.task.blocked_parts(scene)
            if blocked:  # a closing task half done at reset, or a cabinet the object cannot go into
                attempts.append({"seed": seed, "scene_id": sid, "outcome": "dropped_reset_blocked", "blocked": blocked})
                continue
            tb = time.perf_counter()
            ann = annotate_scene(
                scene,
                cell=preset.cell,
                r_arm=preset.r_arm,
                sigma_cells=preset.sigma_cells,
                workers=1,
                max_candidates=preset.max_candidates,
                seed=ANNOTATE_SEED,
            )
            tc = time.perf_counter()
            n_pos = int(np.asarray(ann.success).sum())
            att = {
                "seed": seed,
                "scene_id": sid,
                "n_candidates": int(len(np.asarray(ann.label).reshape(-1))),
                "n_positive": n_pos,
                "build_s": tb - ta,
                "annotate_s": tc - tb,
            }
            if n_pos == 0:
                att["outcome"] = "dropped_no_positive"
                attempts.append(att)
                continue
            nv = _write_scene(
                outp, job, spec, scene, ann, preset, save_images, np.random.default_rng(derive_seed(seed, "views"))
            )
            if not sum(nv.values()):  # the next attempt's kitchen, as for a scene without a positive candidate
                att.update(outcome="dropped_no_view", views_s=time.perf_counter() - tc)
                attempts.append(att)
                continue
            att.update(outcome="ok", views_s=time.perf_counter() - tc, n_views=nv)
            attempts.append(att)
            return {
                "key": job.key,
                "status": "ok",
                "scene_id": sid,
                "attempts": attempts,
                "wall_s": time.perf_counter() - t0,
                "pid": os.getpid(),
            }
        return {
            "key": job.key,
            "status": "dropped",
            "scene_id": None,
            "attempts": attempts,
            "reason": f"no scene that resets, with a positive candidate and a kept view, in {len(job.seeds)} seed "
            "attempts",
            "wall_s": time.perf_counter() - t0,
            "pid": os.getpid(),
        }
    except Exception as exc:  # noqa: BLE001 - reported to the driver, which retries once
        return {
            "key": job.key,
            "status": "error",
            "scene_id": None,
            "attempts": attempts,
            "reason": f"{type(exc).__name__}: {exc}",
            "traceback": traceback.format_exc(),
            "wall_s": time.perf_counter() - t0,
            "pid": os.getpid(),
        }


# ------------------------------------------------------------------------------------------------ execution
def _worker_init(driver: int) -> None:
    """A scene worker's set-up; ``driver``: the pid of the process that started it."""
    # one BLAS/OpenMP thread per worker (docs/background.md §5); _run_local starts the workers with them already
    for k in THREAD_ENV:
        os.environ[k] = "1"
    os.environ.setdefault("MUJOCO_GL", "egl")
    # a worker outlives a killed driver otherwise: it would finish its queued scenes into --out beside the rerun (a
    # scene being written stays in .staging/, which the next run deletes)
    exit_with_parent(driver)


class _Progress:
    """tqdm when installed, else one line per finished scene on stderr."""

    def __init__(self, total: int, quiet: bool) -> None:
        self.total, self.n, self.quiet = total, 0, quiet
        self._bar = None
        if not quiet:
            try:
                from tqdm import tqdm

                self._bar = tqdm(total=total, desc="scenes", unit="scene", file=sys.stderr)
            except ImportError:
                self._bar = None

    def update(self, msg: str) -> None:
        self.n += 1
        if self.quiet:
            return
        if self._bar is not None:
            self._bar.set_postfix_str(msg[:60])
            self._bar.update(1)
        else:
            print(f"[generate] {self.n}/{self.total} {msg}", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()


def _run_local(jobs, out, preset_dict, save_images, workers, on_result, job_fn=None) -> None:
    """Run jobs; workers == 0 runs in this process (no crash isolation), else in spawned worker processes.

    A Python exception in a job comes back as status "error". A dead worker process (a segfault, the OOM killer)
    breaks its whole pool, so every job in flight there fails with it and none of them can be blamed: they are run
    again each in a process of its own, where a crash is the job's. Each job gets at most 2 tries of its own.
    """
    job_fn = job_fn or run_job
    tries = {j.key: 0 for j in jobs}
    if workers == 0:
        for job in jobs:
            for _ in range(2):
                tries[job.key] += 1
                res = job_fn(job, out, preset_dict, save_images)
                if res["status"] != "error":
                    break
            on_result(job, res, tries[job.key])
        return
    with one_thread_children():  # the workers start during the submits, with one BLAS thread each
        queue = [(job, False) for job in jobs]  # (job, alone: in a process of its own)
        while queue:
            shared = [job for job, alone in queue if not alone]
            alone = [job for job, alone in queue if alone]
            queue = []
            for job in shared + alone:
                tries[job.key] += 1
            args = (workers, job_fn, out, preset_dict, save_images)
            # as each job finishes (the manifest records it at once, for a resume)
            outcomes = itertools.chain(_in_shared_pool(shared, *args), _each_alone(alone, *args))
            for job, res, was_alone in outcomes:
                if res.get("pool_broken") and not was_alone:
                    tries[job.key] -= 1  # maybe another job killed the worker: not this job's try
                    queue.append((job, True))
                elif res["status"] == "error" and tries[job.key] < 2:
                    queue.append((job, was_alone))
                else:
                    res.pop("pool_broken", None)
                    on_result(job, res, tries[job.key])


def _died(job: SceneJob, exc: BaseException) -> dict[str, Any]:
    """The status record of a job whose worker process died."""
    return {
        "key": job.key,
        "status": "error",
        "scene_id": None,
        "attempts": [],
        "reason": f"worker died: {type(exc).__name__}: {exc}",
        "wall_s": None,
        "pool_broken": isinstance(exc, cf.process.BrokenProcessPool),
    }


def _in_shared_pool(jobs, workers, job_fn, out, preset_dict, save_images) -> Iterator[tuple[SceneJob, dict, bool]]:
    """(job, status record, False) of each of ``jobs`` run in one pool of ``workers`` processes, as they finish."""
    if not jobs:
        return
    ctx = mp.get_context("spawn")
    with cf.ProcessPoolExecutor(
        max_workers=workers, mp_context=ctx, initializer=_worker_init, initargs=(os.getpid(),)
    ) as pool:
        futs = {pool.submit(job_fn, job, out, preset_dict, save_images): job for job in jobs}
        for fut in cf.as_completed(futs):
            try:
                res = fut.result()
            except Exception as exc:  # noqa: BLE001 - BrokenProcessPool & co: the worker died
                res = _died(futs[fut], exc)
            yield futs[fut], res, False


def _each_alone(jobs, workers, job_fn, out, preset_dict, save_images) -> Iterator[tuple[SceneJob, dict, bool]]:
    """(job, status record, True) of each of ``jobs`` run in a worker process of its own, ``workers`` at a time."""
    if not jobs:
        return
    ctx = mp.get_context("spawn")

    def one(job: SceneJob) -> dict[str, Any]:
        with cf.ProcessPoolExecutor(
            max_workers=1, mp_context=ctx, initializer=_worker_init, initargs=(os.getpid(),)
        ) as pool:
            try:
                return pool.submit(job_fn, job, out, preset_dict, save_images).result()
            except Exception as exc:  # noqa: BLE001 - the worker died: this job's doing
                return _died(job, exc)

    with cf.ThreadPoolExecutor(max_workers=workers) as threads:
        futs = {threads.submit(one, job): job for job in jobs}
        for fut in cf.as_completed(futs):
            yield futs[fut], fut.result(), True


def _run_ray(jobs, out, preset_dict, save_images, workers, address, on_result) -> None:
    """Run jobs as ray tasks (one CPU each); a local cluster is started when no address is given.

    Workers write scene dirs under ``out`` and the driver reads them back, so with a multi-machine cluster ``out``
    must be on a file system shared by every node (mounted at the same path).
    """
    out = str(Path(out).resolve())  # ray workers do not share the driver's working directory
    try:
        import ray
    except ImportError as exc:
        raise SystemExit("--backend ray needs ray, which is not installed: pip install ray") from exc
    started = False
    if not ray.is_initialized():
        if address:
            try:
                ray.init(address=address, ignore_reinit_error=True, log_to_driver=False)
            except (ConnectionError, RuntimeError) as exc:  # an unreachable cluster: a 71-line traceback
                raise ValueError(f"--address {address}: cannot connect to a ray cluster ({exc})") from exc
        else:
            ray.init(num_cpus=max(1, workers), ignore_reinit_error=True, log_to_driver=False, include_dashboard=False)
        started = True
    env = {
        "env_vars": {
            "OMP_NUM_THREADS": "1",
            "OPENBLAS_NUM_THREADS": "1",
            "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"),
        }
    }
    remote = ray.remote(num_cpus=1, max_retries=0, runtime_env=env)(run_job)
    tries = {j.key: 0 for j in jobs}
    try:
        pending = list(jobs)
        while pending:
            refs = {}
            for job in pending:
                tries[job.key] += 1
                refs[remote.remote(job, out, preset_dict, save_images)] = job
            retry = []
            waiting = list(refs)
            while waiting:
                done, waiting = ray.wait(waiting, num_returns=1)
                job = refs[done[0]]
                try:
                    res = ray.get(done[0])
                except Exception as exc:  # noqa: BLE001 - worker crash / ray system error
                    res = {
                        "key": job.key,
                        "status": "error",
                        "scene_id": None,
                        "attempts": [],
                        "reason": f"ray task failed: {type(exc).__name__}: {exc}",
                        "wall_s": None,
                    }
                if res["status"] == "error" and tries[job.key] < 2:
                    retry.append(job)
                    continue
                on_result(job, res, tries[job.key])
            pending = retry
    finally:
        if started:
            ray.shutdown()


def _package_versions() -> dict[str, str | None]:
    from importlib import metadata

    out: dict[str, str | None] = {}
    for name in ("mujoco", "robosuite", "numpy", "scipy", "floaff-zoo"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out


def _summarise(manifest: dict[str, Any]) -> None:
    """Fill manifest['counts'] and manifest['drops'] from manifest['scenes'] (in place)."""
    counts: dict[str, Any] = {
        "scenes_ok": 0,
        "scenes_dropped": 0,
        "scenes_failed": 0,
        "scenes_pending": 0,
        "views_front": 0,
        "views_side": 0,
        "views_rejected_no_positive_cell": 0,
        "views_rejected_no_floor_cell": 0,
        "views_rejected_best_cell_fails": 0,
        "per": {},
    }
    drops = []
    for key, s in sorted(manifest["scenes"].items()):
        st = s["status"]
        counts[
            {"ok": "scenes_ok", "dropped": "scenes_dropped", "failed": "scenes_failed"}.get(st, "scenes_pending")
        ] += 1
        per = counts["per"].setdefault(
            f"{s['benchmark']}/{s['task']}/{s['split']}", {"scenes": 0, "views_front": 0, "views_side": 0}
        )
        if st == "ok":
            per["scenes"] += 1
            nv = s.get("n_views", {})
            per["views_front"] += int(nv.get("front", 0))
            per["views_side"] += int(nv.get("side", 0))
            counts["views_front"] += int(nv.get("front", 0))
            counts["views_side"] += int(nv.get("side", 0))
            for why, k in (s.get("views_rejected") or {}).items():
                counts[f"views_rejected_{why}"] = counts.get(f"views_rejected_{why}", 0) + int(k)
        for a in s.get("attempts", []):
            why = {
                "dropped_reset_blocked": "a part the reset opens is blocked",
                "dropped_no_positive": "no positive candidate",
                "dropped_no_view": "no view kept",
            }
            if a.get("outcome") in why:
                drops.append({"slot": key, "scene_id": a["scene_id"], "seed": a["seed"], "reason": why[a["outcome"]]})
        if st in ("failed", "dropped"):
            drops.append({"slot": key, "scene_id": None, "reason": f"{st}: {s.get('reason')}"})
    counts["views_total"] = counts["views_front"] + counts["views_side"]
    manifest["counts"] = counts
    manifest["drops"] = drops


def generate(
    out: str | Path,
    preset: GenPreset,
    seed: int = 0,
    workers: int = 1,
    backend: str = "local",
    address: str | None = None,
    save_images: bool = False,
    quiet: bool = False,
    job_fn: Callable[..., dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """Generate (or resume) a benchmark into `out`; returns the final manifest dict (also written to manifest.json).

    job_fn: the per-slot function with run_job's signature (default run_job; replaced only by tests that simulate
    crashing workers; it must be importable by name for process workers).
    """
    if not isinstance(preset, GenPreset):  # a preset's name or dict failed with an AttributeError
        raise TypeError(f"generate: preset must be a GenPreset (presets.get_preset), got {type(preset).__name__}")
    preset = preset.validate()
    if backend not in ("local", "ray"):
        raise ValueError(f"backend must be 'local' or 'ray', got {backend!r}")
    if address and backend != "ray":  # the local pool ignored it: the scenes were not made on the named cluster
        raise ValueError(f"address {address!r} names a ray cluster: give it with backend 'ray'")
    check_integer("workers", workers, 0)  # 1.5 or "2" failed with a TypeError once the folder was locked
    check_seed(seed)  # before the folder is made
    outp = check_out_dir(out)
    with contextlib.ExitStack() as stack:
        try:
            stack.enter_context(folder_lock(outp / GENERATE_LOCK, wait=False))
        except LockedError as exc:  # its start would delete the other run's half-built scenes (.staging)
            raise ValueError(
                f"--out {outp}: another `floaff-zoo generate` is writing into this folder; wait for it to end"
            ) from exc
        return _generate(outp, preset, seed, workers, backend, address, save_images, quiet, job_fn)


def _generate(
    outp: Path,
    preset: GenPreset,
    seed: int,
    workers: int,
    backend: str,
    address: str | None,
    save_images: bool,
    quiet: bool,
    job_fn: Callable[..., dict[str, Any]] | None,
) -> dict[str, Any]:
    """``generate`` into the checked folder ``outp``, under its lock."""
    from floaff_zoo.sim.kitchen import LAYOUTS, STYLES

    jobs = plan_jobs(preset, seed, list(LAYOUTS), list(STYLES))
    for b in preset.benchmarks:  # leftovers of killed runs
        shutil.rmtree(outp / b / ff.STAGING, ignore_errors=True)
    t0 = time.perf_counter()
    manifest: dict[str, Any] = {
        "format_version": ff.FORMAT_VERSION,
        "generator_version": GENERATOR_VERSION,
        "packages": _package_versions(),
        "preset": preset.name,
        "seed": int(seed),
        "config": preset.to_dict(),
        "save_images": bool(save_images),
        "backend": backend,
        "workers": int(workers),
        "scenes": {},
        "wall_s": None,
        "status": "running",
    }
    old, why = None, "missing"
    if (outp / ff.MANIFEST).is_file():
        try:
            old = ff.read_manifest(outp)
        except ff.FormatError as exc:
            why = f"unreadable ({exc})"
    if old is not None:
        check_resume_settings(old, manifest, outp)
    elif found := committed_scene_dirs(outp):
        raise ValueError(
            f"{outp}: holds {len(found)} generated scene(s) (e.g. {found[0]}) but its manifest.json is {why}, so the "
            "settings they were made with cannot be checked against this run's: generate into another --out, or "
            "restore manifest.json"
        )
    todo: list[SceneJob] = []
    records = read_records(committed_scene_dirs(outp))  # every scene.json read once, at the start
    by_slot = slots_of(records)
    retire: dict[str, list[str]] = {}  # resumed slot -> its other scenes, moved aside once the run is not refused
    for job in jobs:
        base = {
            "benchmark": job.benchmark,
            "task": job.task,
            "split": job.split,
            "slot": job.slot,
            "layout_id": job.layout_id,
            "style_id": job.style_id,
        }
        sid = find_done(outp, job, preset.min_views)
        if sid is not None:
            prev = (old or {}).get("scenes", {}).get(job.key, {})
            rec = ff.read_scene(ff.scene_dir(outp, job.benchmark, sid))
            # a rerun killed between committing this scene and moving the slot's earlier one aside left both
            others = set(by_slot.get((job.benchmark, job.key), [])) | (
                {prev["scene_id"]} if prev.get("scene_id") else set()
            )
            others.discard(sid)
            if others:
                retire[job.key] = sorted(others)
            manifest["scenes"][job.key] = {
                **base,
                "status": "ok",
                "scene_id": sid,
                "resumed": True,
                "n_views": rec.get("n_views", {}),
                "attempts": prev.get("attempts", []),
                "views_rejected": rec.get("views_rejected", {}),
                "wall_s": prev.get("wall_s"),
            }
        else:
            manifest["scenes"][job.key] = {**base, "status": "pending"}
            todo.append(job)
    # slots of an earlier run that this run leaves out (fewer tasks, scenes or benchmarks): their scenes stay and
    # are read, so the manifest keeps describing them
    stale: list[str] = []
    checked: set[tuple[str, str]] = set()

    def left_out(bench: str, sid: str) -> dict[str, Any] | None:
        """The scene.json of a left-out slot's scene, its generator checked once; None when it is not committed.
        From the records read at the start: nothing has written a scene since."""
        rec = ff.committed(records.get((bench, sid)))
        if rec is None:
            return None
        if (bench, sid) not in checked and not same_generator(rec):
            stale.append(f"{bench}/{sid} (generator {rec.get('generator_version') or '1.x'})")
        checked.add((bench, sid))
        return rec

    for key, s in sorted((old or {}).get("scenes", {}).items()):
        sid = s.get("scene_id")
        if key not in manifest["scenes"] and sid and left_out(s["benchmark"], sid) is not None:
            manifest["scenes"][key] = {**s, "in_plan": False}
    # and those the previous manifest does not name (a run killed after committing a slot's scene but before
    # recording it, or an interrupted rerun's manifest, written without the id of a scene it was to regenerate): by
    # the slot their scene.json names
    planned = {job.key for job in jobs}
    for (bench, key), ids in sorted(by_slot.items()):
        if key in planned:  # resumed (its other scenes retired) or regenerated
            continue
        for sid in ids:
            rec = left_out(bench, sid)
            if rec is not None and key not in manifest["scenes"]:
                manifest["scenes"][key] = _left_out_entry(bench, key, sid, rec)
    if stale:  # kept beside this run's scenes, they would mix generator versions in one dataset
        raise ValueError(
            f"{outp}: holds {len(stale)} scene(s) of another generator version outside this run's plan (e.g. "
            f"{', '.join(stale[:3])}); one dataset must not mix them: rerun with the slots that hold them (the "
            f"recorded --tasks, --n-train, --n-test: manifest.json 'config') so they are regenerated, or generate "
            f"into another --out"
        )
    kept = {(s["benchmark"], s.get("scene_id")) for s in manifest["scenes"].values() if s["status"] == "ok"}
    for key, ids in retire.items():  # readers list folders: a slot's scene that is not the resumed one must go
        bench = manifest["scenes"][key]["benchmark"]
        retired = [sid for sid in ids if (bench, sid) not in kept and ff.retire_scene(outp, bench, sid) is not None]
        if retired:
            manifest["scenes"][key]["retired"] = retired[0] if len(retired) == 1 else retired
    _summarise(manifest)
    ff.atomic_write_json(outp / ff.MANIFEST, manifest)
    prog = _Progress(len(todo), quiet)

    def on_result(job: SceneJob, res: dict[str, Any], n_tries: int) -> None:
        st = {"ok": "ok", "dropped": "dropped"}.get(res["status"], "failed")
        entry = {
            **manifest["scenes"][job.key],
            "status": st,
            "scene_id": res.get("scene_id"),
            "tries": n_tries,
            "attempts": res.get("attempts", []),
            "wall_s": res.get("wall_s"),
            "resumed": False,
        }
        # the slot's earlier scenes are not this run's result, so readers must not see them
        prev = (old or {}).get("scenes", {}).get(job.key, {}).get("scene_id")
        # the slot's scenes at the start of the run and those its seeds drew since (a worker that died after
        # committing one), not every scene.json again after each job
        looked = set(by_slot.get((job.benchmark, job.key), [])) | set(_seed_scene_ids(job))
        looked.discard(res.get("scene_id"))
        stale = ({prev} if prev else set()) | set(slot_scenes(outp, job, sorted(looked)))
        stale.discard(res.get("scene_id"))
        retired = [sid for sid in sorted(stale) if ff.retire_scene(outp, job.benchmark, sid) is not None]
        if retired:
            entry["retired"] = retired[0] if len(retired) == 1 else retired
        if st == "ok":
            rec = ff.read_scene(ff.scene_dir(outp, job.benchmark, res["scene_id"]))
            entry["n_views"] = rec["n_views"]
            entry["views_rejected"] = rec.get("views_rejected", {})
        else:
            entry["reason"] = res.get("reason")
            if "traceback" in res:
                entry["traceback"] = res["traceback"][-4000:]
        manifest["scenes"][job.key] = entry
        _summarise(manifest)
        ff.atomic_write_json(outp / ff.MANIFEST, manifest)
        prog.update(f"{job.key} {st}")

    pdict = preset.to_dict()
    try:
        if backend == "ray":
            _run_ray(todo, str(outp), pdict, save_images, max(1, workers), address, on_result)
        else:
            _run_local(todo, str(outp), pdict, save_images, workers, on_result, job_fn)
    finally:
        prog.close()
        for b in preset.benchmarks:
            shutil.rmtree(outp / b / ff.STAGING, ignore_errors=True)
    manifest["wall_s"] = time.perf_counter() - t0
    manifest["status"] = "done"
    _summarise(manifest)
    ff.atomic_write_json(outp / ff.MANIFEST, manifest)
    return manifest


def _left_out_entry(bench: str, key: str, sid: str, rec: dict[str, Any]) -> dict[str, Any]:
    """The manifest entry of a committed scene of slot ``key`` (``<benchmark>/<task>/<split><index>``) that this
    run's plan leaves out, made from its scene.json ``rec`` (the previous manifest does not name it)."""
    split = rec.get("split")
    index = key.rsplit("/", 1)[-1][len(split) :] if isinstance(split, str) else ""
    spec = rec.get("spec") if isinstance(rec.get("spec"), dict) else {}
    return {
        "benchmark": bench,
        "task": rec.get("task"),
        "split": split,
        "slot": int(index) if index.isdigit() else None,
        "layout_id": spec.get("layout_id"),
        "style_id": spec.get("style_id"),
        "status": "ok",
        "scene_id": sid,
        "resumed": True,
        "n_views": rec.get("n_views", {}),
        "attempts": [],
        "views_rejected": rec.get("views_rejected", {}),
        "wall_s": None,
        "in_plan": False,
    }


#: preset fields a rerun into the same folder may change: which slots exist and how many views a scene is topped up
#: to (a scene's own record says whether it holds enough, see find_done)
RESUMABLE_FIELDS = frozenset({"name", "benchmarks", "tasks", "n_train", "n_test", "min_views"})


def check_resume_settings(old: dict[str, Any], new: dict[str, Any], out: Path) -> None:
    """Refuse to resume a folder whose manifest records other generation settings (grid cell, views, image size,
    candidate cap, seed, ...): its finished scenes would be kept and the manifest would describe settings they were
    not made with. Fields an older manifest lacks are not compared.

    Raises:
        ValueError: naming the folder and every differing setting.
    """
    was, now = old.get("config") or {}, new["config"]
    diffs = [
        f"{k} {was[k]!r} -> {now[k]!r}" for k in sorted((set(was) & set(now)) - RESUMABLE_FIELDS) if was[k] != now[k]
    ]
    diffs += [f"{k} {old[k]!r} -> {new[k]!r}" for k in ("seed", "save_images") if k in old and old[k] != new[k]]
    if diffs:
        raise ValueError(
            f"{out}: its scenes were generated with other settings ({'; '.join(diffs)}); resuming would mix them: "
            "generate into another --out, or rerun with the recorded settings (manifest.json 'config')"
        )


#: the lock a run holds on its output folder (two runs into one folder would delete each other's staging)
GENERATE_LOCK = ".generate.lock"


def check_out_dir(out: str | Path) -> Path:
    """Create the output folder ``out`` (or accept an existing one) before any scene is built.

    Raises:
        ValueError: naming ``out`` when it is a file or cannot be created (a file on its path, no permission).
    """
    if not str(out).strip():  # an unset shell variable: the dataset went into the working folder
        raise ValueError("--out is empty; name the output folder")
    outp = Path(out)
    if outp.exists() and not outp.is_dir():
        raise ValueError(f"--out {outp}: exists and is not a folder; name a new or existing output folder")
    try:
        outp.mkdir(parents=True, exist_ok=True)
    except OSError as exc:  # a file where a parent folder should be, a read-only disk, ...
        raise ValueError(f"--out {outp}: cannot create the output folder ({exc.strerror or exc})") from exc
    return outp


def failure_lines(manifest: dict[str, Any], limit: int = 3) -> list[str]:
    """One console line per failed slot, the first ``limit`` in slot order, then a count of the rest: the reasons
    would otherwise be only in manifest.json."""
    failed = [(k, s.get("reason")) for k, s in sorted(manifest["scenes"].items()) if s.get("status") == "failed"]
    lines = [f"[generate] failed {key}: {' '.join(str(why).split())}" for key, why in failed[:limit]]
    if len(failed) > limit:
        lines.append(f"[generate] ... and {len(failed) - limit} more failed slot(s): see manifest.json")
    return lines


# ------------------------------------------------------------------------------------------------ CLI
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="floaff-zoo generate",
        description="Generate the simulated FloAff benchmark (Styles/Layouts) with MuJoCo rollouts.",
    )
    p.add_argument("--preset", default="small", choices=sorted(PRESETS), help="generation preset (default: small)")
    p.add_argument("--out", default="data/floaff_sim", help="output directory (default: data/floaff_sim)")
    p.add_argument("--workers", type=int, default=1, help="worker processes (0 = in this process; default 1)")
    p.add_argument("--backend", default="local", choices=["local", "ray"], help="local process pool or ray")
    p.add_argument("--address", default=None, help="ray cluster address (default: start a local cluster)")
    p.add_argument("--seed", type=int, default=0, help="global seed (default 0)")
    p.add_argument("--save-images", action="store_true", help="also store rgb/depth images in each view file")
    p.add_argument("--benchmarks", nargs="+", choices=list(ALL_BENCHMARKS), default=None)
    p.add_argument("--tasks", nargs="+", choices=list(ALL_TASKS), default=None)
    p.add_argument("--n-train", type=int, default=None, help="override: training scenes per task")
    p.add_argument("--n-test", type=int, default=None, help="override: test scenes per task")
    p.add_argument("--cell", type=float, default=None, help="override: candidate grid cell (m)")
    p.add_argument("--max-candidates", type=int, default=None, help="override: max rollouts per scene (0 = no cap)")
    p.add_argument(
        "--views",
        type=int,
        nargs=2,
        metavar=("FRONT", "SIDE"),
        default=None,
        help="override: front and side views per scene",
    )
    p.add_argument(
        "--min-views",
        type=int,
        default=None,
        help="override: top a scene up to this many views from the same regions (0 = off; dense: 200)",
    )
    p.add_argument("--image-size", type=int, default=None, help="override: ego image size (pixels)")
    p.add_argument("--quiet", action="store_true", help="no progress output")
    return p


def _cli_error(message: str) -> int:
    """Print a usage error of ``floaff-zoo generate`` and return its exit code (2)."""
    print(f"floaff-zoo generate: error: {message}", file=sys.stderr)
    return 2


def main(argv: list[str] | None = None) -> int:
    """CLI entry point; returns 0 when every slot is ok or dropped, 1 when some scene failed, 2 for settings that
    do not fit each other or the output folder."""
    args = build_parser().parse_args(argv)
    try:  # the overrides are checked here, before any scene is built
        preset = get_preset(
            args.preset,
            benchmarks=tuple(args.benchmarks) if args.benchmarks else None,
            tasks=tuple(args.tasks) if args.tasks else None,
            n_train=args.n_train,
            n_test=args.n_test,
            cell=args.cell,
            max_candidates=args.max_candidates or None,
            views_per_scene=tuple(args.views) if args.views else None,
            min_views=args.min_views,
            image_size=args.image_size,
        )
    except ValueError as exc:
        return _cli_error(f"{exc} (preset {args.preset!r} with the given overrides)")
    if args.max_candidates == 0:
        preset = dataclasses.replace(preset, max_candidates=None)
    if args.views and preset.use_paper_view_counts:
        return _cli_error(f"--views: the {args.preset!r} preset spreads the paper's view counts over its scenes")
    if args.address and args.backend != "ray":
        return _cli_error("--address names a ray cluster: give it with --backend ray")
    try:
        man = generate(
            args.out,
            preset,
            seed=args.seed,
            workers=args.workers,
            backend=args.backend,
            address=args.address,
            save_images=args.save_images,
            quiet=args.quiet,
        )
    except ValueError as exc:  # settings that do not fit the folder or each other
        return _cli_error(str(exc))
    c = man["counts"]
    print(
        f"[generate] {args.out}: {c['scenes_ok']} scenes ok, {c['scenes_dropped']} dropped, "
        f"{c['scenes_failed']} failed; "
        f"{c['views_front']} front + {c['views_side']} side views; {man['wall_s']:.1f} s",
        file=sys.stderr,
    )
    for line in failure_lines(man):
        print(line, file=sys.stderr)
    return 0 if c["scenes_failed"] == 0 else 1


if __name__ == "__main__":
    raise SystemExit(main())
