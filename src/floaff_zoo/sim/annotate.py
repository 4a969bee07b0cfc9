"""Rollout-based floor-affordance annotation of one scene (paper appendix, "Cross-scene Floor Affordance Benchmark").

Pipeline per scene:
1. candidate grid in the TARGET frame (see ``tasks`` module doc): cells (x°, y°) on a regular
   ``cell`` lattice with |x°| <= r_x, |y°| <= r_y (task dependent, ``tasks.candidate_region``),
   heading toward the target centre (``rollout.heading_to_target``);
2. collision-aware filtering: cells behind the target's front plane (y° > 0: inside the fixture,
   the counter or the wall), cells separated from the target by a wall (outside the room), the N2M
   footprint vs furniture footprints, then the robot's base, torso and arm (tuck pose, task reset
   state) vs scene geometry; all counted as ``filtered_collision`` and never rolled out;
3. reach filter ||b_xy - c|| < r_arm (task default ``Task.r_arm``);
4. IK pre-filter: the scripted policy's own key-point IK check (``Policy.reset``); a candidate that
   fails it would end the rollout at t = 0 with ``ik_unreachable``, so skipping it cannot change
   the label (same code path);
5. one rollout per remaining candidate -> binary label;
6. Gaussian smoothing of the binary grid (``scipy.ndimage.gaussian_filter``, sigma = ``sigma_cells``
   cells, mode "constant"; cells skipped for the budget count as unknown, not as failures, since generator 2.2:
   :func:`_smooth`), then max-normalised to 1 when any candidate succeeded; filtered cells are set to 0 after the
   normalisation (:func:`cell_labels`), so the map can peak below 1 when its maximum lay on a filtered cell.

Every cell ends with a ``status``: ``FILTERED`` (steps 2-4: infeasible, never rolled out), ``ROLLED_OUT``
(step 5) or ``SKIPPED`` (feasible but over the ``max_candidates`` budget: never considered).
:func:`cell_labels` turns (label, status) into the per-cell labels of format v2 view files.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from floaff_zoo.checks import check_integer, check_number
from floaff_zoo.frames import ROLLOUT_POSE_DECIMALS
from floaff_zoo.sim.controllers import default_policy
from floaff_zoo.sim.kitchen import SimScene
from floaff_zoo.sim.rollout import RolloutService, heading_to_target, pose_filter, rollout, start_rollout
from floaff_zoo.sim.tasks import target_frame_to_world

#: Annotation.status codes: filtered as infeasible (collision / wall / reach / IK), rolled out, skipped (budget)
FILTERED, ROLLED_OUT, SKIPPED = 0, 1, 2
#: the reason recorded for a cell over the ``max_candidates`` budget (status ``SKIPPED``)
SKIPPED_REASON = "skipped_budget"


def cell_labels(label: np.ndarray, status: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-cell labels of format v2 (docs/data_format.md): label [M], status [M] -> (label [M] f32, known [M] bool).

    ROLLED_OUT: the smoothed rollout label; FILTERED: 0 (the robot cannot stand or act there), known;
    SKIPPED (never rolled out): the smoothed label of the neighbouring rollouts, NOT known.
    """
    lab = np.asarray(label, dtype=np.float32).reshape(-1)
    st = np.asarray(status).reshape(-1)
    if st.shape != lab.shape:
        raise ValueError(f"cell_labels: status has {st.size} cells, label has {lab.size}")
    bad = ~np.isin(st, (FILTERED, ROLLED_OUT, SKIPPED))
    if bad.any():
        raise ValueError(f"cell_labels: unknown status code(s) {sorted(set(st[bad].tolist()))}")
    return np.where(st == FILTERED, np.float32(0.0), lab).astype(np.float32), st != SKIPPED


def probability_label(
    prob: np.ndarray, status: np.ndarray, shape: tuple[int, int], sigma_cells: float = 1.0
) -> np.ndarray:
    """Per-cell labels from success *probabilities* (several episodes per cell) instead of one binary rollout.

    prob [M] in [0, 1], status [M] (``FILTERED`` / ``ROLLED_OUT`` / ``SKIPPED``), shape (H, W) with H*W = M ->
    label [M] f32: smoothed and max-normalised as the generated labels (step 6), filtered cells 0 (:func:`cell_labels`).
    """
    p = np.asarray(prob, dtype=np.float64).reshape(-1)
    finite = p[np.isfinite(p)]
    if p.size != int(np.prod(shape)) or finite.size < p.size or finite.min(initial=0) < 0 or finite.max(initial=0) > 1:
        span = f"range [{finite.min():.3g}, {finite.max():.3g}]" if finite.size else "no finite value"
        raise ValueError(
            f"probability_label: need {int(np.prod(shape))} finite probabilities in [0, 1] for grid {tuple(shape)}, "
            f"got {p.size} ({p.size - finite.size} not finite, {span})"
        )
    check_number("sigma_cells", sigma_cells, owner="probability_label", note="0 = no smoothing")
    st = np.asarray(status).reshape(-1)
    if st.size != p.size:  # else _smooth's reshape of the known mask failed, naming neither argument
        raise ValueError(f"probability_label: status has {st.size} cells, prob has {p.size} (grid {tuple(shape)})")
    return cell_labels(_smooth(p, shape, sigma_cells, st != SKIPPED), st)[0]


@dataclass
class Annotation:
    """Labels of one scene. Arrays are over M = H*W candidates in row-major (y°, x°) order."""

    grid_xy: np.ndarray  # [M,2] world xy of the base origin
    yaw: np.ndarray  # [M] heading toward the target
    valid: np.ndarray  # [M] bool: passed collision + reach filtering
    success: np.ndarray  # [M] bool: rollout succeeded (False where filtered/prefiltered)
    label: np.ndarray  # [M] float32 smoothed, max-normalised
    reasons: list[str]  # [M] "success" / failure reason / "filtered_collision" / "filtered_reach"
    counts: dict
    grid_shape: tuple[int, int]
    cell: float
    sigma_cells: float = 1.0
    wall_seconds: float = 0.0
    extra: dict = field(default_factory=dict)
    status: np.ndarray | None = None  # [M] int8 FILTERED / ROLLED_OUT / SKIPPED (module doc)


def candidate_grid(
    scene: SimScene, cell: float, r_x: float, r_y: float
) -> tuple[np.ndarray, tuple[int, int], np.ndarray]:
    """Target-frame lattice -> (world xy [M,2], (H, W), target-frame xy [M,2])."""
    check_number("cell", cell, strict=True, owner="candidate_grid")
    nx = int(math.floor(r_x / cell + 1e-9))
    ny = int(math.floor(r_y / cell + 1e-9))
    xs = np.arange(-nx, nx + 1) * cell
    ys = np.arange(-ny, ny + 1) * cell
    yy, xx = np.meshgrid(ys, xs, indexing="ij")
    xo = np.stack([xx.ravel(), yy.ravel()], axis=1)
    return target_frame_to_world(scene.target, xo), (len(ys), len(xs)), xo


def _smooth(binary: np.ndarray, shape: tuple[int, int], sigma: float, known: np.ndarray | None = None) -> np.ndarray:
    """Step 6 over values [M] (1/0 successes, or probabilities) on the (H, W) grid -> label [M] f32.

    ``known`` [M] bool (``status != SKIPPED``): cells over the ``max_candidates`` budget were never rolled out, so
    they carry no value; the smoothing then weighs each cell's neighbourhood by the share of it that is known (the
    kernel's mass over the grid divided by its mass over known cells) instead of counting the skipped cells as
    failures, which lowered the labels of rolled-out cells beside them. Without skipped cells the map is unchanged.
    """
    from scipy.ndimage import gaussian_filter

    g = binary.reshape(shape).astype(np.float64)
    skipped = known is not None and not np.asarray(known, dtype=bool).all()
    if skipped:
        k = np.asarray(known, dtype=np.float64).reshape(shape)
        g = g * k
    if sigma > 0:
        g = gaussian_filter(g, sigma=sigma, mode="constant")
        if skipped:
            mass = gaussian_filter(k, sigma=sigma, mode="constant")
            full = gaussian_filter(np.ones(shape), sigma=sigma, mode="constant")
            g = np.where(mass > 1e-9, g * full / np.maximum(mass, 1e-9), 0.0)
    mx = g.max()
    if mx > 0:
        g = g / mx
    return g.ravel().astype(np.float32)


def annotate_scene(
    scene: SimScene,
    cell: float = 0.05,
    r_arm: float | None = None,
    sigma_cells: float = 1.0,
    workers: int = 1,
    max_candidates: int | None = None,
    seed: int = 0,
) -> Annotation:
    """Label one scene's candidate grid with rollouts; see the module doc.

    max_candidates: roll out at most this many filtered candidates (evenly spaced subset, the rest
    are labelled failures with reason "skipped_budget"; for tests/CI).
    r_arm: the reach filter's radius; None (the only value accepted besides the task's own) takes the task's.

    Raises:
        ValueError: an ``r_arm`` other than the task's: the evaluation refuses poses by the task's reach
            (``rollout.pose_filter``), and so do pool workers, so the labels would disagree with the rollouts.
    """
    t0 = time.perf_counter()
    # a NaN or negative sigma left the labels unsmoothed without a word; a negative or fractional budget failed in
    # np.linspace after every filter ran, True was a budget of 1; a float seed failed in the first reset
    check_number("sigma_cells", sigma_cells, owner="annotate_scene", note="0 = no smoothing")
    check_integer("max_candidates", max_candidates, 1, owner="annotate_scene", none_means="no cap")
    check_integer("seed", seed, 0, owner="annotate_scene")
    check_integer("workers", workers, 0, owner="annotate_scene")
    task = scene.task
    r_x, r_y = task.candidate_region()
    if r_arm is not None and float(r_arm) != task.r_arm:
        raise ValueError(
            f"annotate_scene: r_arm={r_arm} differs from the {scene.spec.task} task's reach {task.r_arm} m, by which "
            "the evaluation refuses poses (rollout.pose_filter): such labels would disagree with the rollouts from "
            "a chosen pose; change the task's r_arm instead"
        )
    r_arm = task.r_arm
    xy, shape, _ = candidate_grid(scene, cell, r_x, r_y)
    xy = np.round(xy, 6)  # the exact poses simulated, identical in every worker
    M = len(xy)
    yaws = np.round(np.array([heading_to_target(scene, x, y) for x, y in xy]), 6)
    reasons = [""] * M
    valid = np.zeros(M, dtype=bool)
    counts = dict(
        candidates=M,
        filtered_collision=0,
        filtered_reach=0,
        prefiltered_ik=0,
        rolled_out=0,
        positives=0,
        skipped_budget=0,
    )
    for i in range(M):
        # the same filters refuse an infeasible pose at evaluation time (rollout.pose_filter)
        reasons[i] = pose_filter(scene, float(xy[i, 0]), float(xy[i, 1]), float(yaws[i]), seed, r_arm)
        if reasons[i]:
            counts[reasons[i]] += 1
            continue
        valid[i] = True
    # IK pre-filter with the policy's own key-point check
    todo = []
    for i in np.flatnonzero(valid):
        pol = default_policy(scene.spec.task)
        start_rollout(scene, (xy[i, 0], xy[i, 1], yaws[i]), pol, seed)
        if pol.reason:
            reasons[i] = pol.reason
            counts["prefiltered_ik"] += 1
        else:
            todo.append(int(i))
    if max_candidates is not None and len(todo) > max_candidates:
        keep = set(np.linspace(0, len(todo) - 1, max_candidates).round().astype(int).tolist())
        for k, i in enumerate(todo):
            if k not in keep:
                reasons[i] = SKIPPED_REASON
                counts[SKIPPED_REASON] += 1
        todo = [i for k, i in enumerate(todo) if k in keep]
    success = np.zeros(M, dtype=bool)
    if workers > 1 and len(todo) > 1:  # the service runs one job in this process, on a second build of the scene
        svc = RolloutService(workers=workers, cache_decimals=ROLLOUT_POSE_DECIMALS, seed=seed)
        try:
            res = svc.run([(scene.spec, (float(xy[i, 0]), float(xy[i, 1]), float(yaws[i]))) for i in todo])
        finally:
            svc.close()
    else:
        res = [rollout(scene, (float(xy[i, 0]), float(xy[i, 1]), float(yaws[i])), None, seed, False) for i in todo]
    status = np.full(M, FILTERED, dtype=np.int8)
    status[[i for i, r in enumerate(reasons) if r == SKIPPED_REASON]] = SKIPPED
    status[todo] = ROLLED_OUT
    for i, r in zip(todo, res):
        success[i] = r.success
        reasons[i] = r.reason
    counts["rolled_out"] = len(todo)
    counts["positives"] = int(success.sum())
    scene.reset_task(np.random.default_rng(seed))
    return Annotation(
        grid_xy=xy.astype(np.float64),
        yaw=yaws,
        valid=valid,
        success=success,
        label=_smooth(success, shape, sigma_cells, status != SKIPPED),
        reasons=reasons,
        counts=counts,
        grid_shape=shape,
        cell=float(cell),
        sigma_cells=float(sigma_cells),
        wall_seconds=time.perf_counter() - t0,
        status=status,
    )
