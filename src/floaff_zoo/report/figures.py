"""Qualitative figures like the paper's: ground-truth map beside the predicted map, chosen pose marked.

With simulator metadata the maps are drawn in the world frame over a top-down outline of the
rebuilt kitchen (``SimScene.floor_outline``) with ``floaff_zoo.sim.pictures.plot_floor_map``;
without it (MoMa-Kitchen, synthetic) as a plain scatter in the view's robot base frame.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from floaff_zoo.atomic import atomic_write
from floaff_zoo.contract import best_pose
from floaff_zoo.frames import base_to_world, pose_to_base, pose_to_world


@dataclass
class FigureSample:
    """One sample to draw (valid floor points only; base frame of the view).

    floor_xyz [M, 3], label [M], scores [M], target_xyz [3], target_yaw (rad); meta as in the
    contract; ``chosen`` / ``oracle`` are optional world (sim samples) or base-frame poses chosen elsewhere
    (e.g. by RolloutSuccessRate with top-k), ``success`` / ``oracle_success`` their rollout outcomes.
    """

    floor_xyz: np.ndarray
    label: np.ndarray
    scores: np.ndarray
    target_xyz: np.ndarray
    target_yaw: float
    meta: dict[str, Any] = field(default_factory=dict)
    chosen: tuple[float, float, float] | None = None
    oracle: tuple[float, float, float] | None = None
    success: bool | None = None
    oracle_success: bool | None = None

    def __post_init__(self) -> None:
        """Shapes checked where the sample is made: out of step, matplotlib failed at the drawing, naming no sample
        (scores of another length), or the panels drew the wrong cells (a [M, 1] label broadcast)."""
        who = f"figure sample {(self.meta or {}).get('sample_id', '?')!s}"
        m = np.shape(self.floor_xyz)
        if len(m) != 2 or m[1] != 3:
            raise ValueError(f"{who}: floor_xyz must be [M, 3], got {list(m)}")
        for name in ("label", "scores"):
            if np.shape(getattr(self, name)) != m[:1]:
                raise ValueError(f"{who}: {name} must be [M={m[0]}], got {list(np.shape(getattr(self, name)))}")
        if np.shape(self.target_xyz) != (3,):
            raise ValueError(f"{who}: target_xyz must be [3], got {list(np.shape(self.target_xyz))}")


def _plt():
    import matplotlib

    if matplotlib.get_backend().lower() != "agg":
        matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def grid_spacing(xy: np.ndarray, default: float = 0.05) -> float:
    """Median nearest-neighbour distance of floor points [M, 2+] (the candidate grid's cell size)."""
    pts = np.asarray(xy, dtype=np.float64)[:, :2]
    if len(pts) < 2:
        return default
    from scipy.spatial import cKDTree

    d, _ = cKDTree(pts).query(pts, k=2)
    step = float(np.median(d[:, 1]))
    return step if step > 1e-6 else default


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("_") or "sample"


def _outcome(ok: bool | None, marked: bool = True) -> str:
    """A panel title's suffix: the rollout's outcome, or that no pose is marked (``drawn_pose`` None)."""
    if not marked:
        return " (no pose: no finite value)"
    return "" if ok is None else (" (success)" if ok else " (fail)")


def drawn_pose(s: FigureSample, given: Any, values: np.ndarray, base: Sequence[float] | None) -> tuple | None:
    """The pose a panel marks, in the panel's frame: the world when ``base`` (the view's base pose) is given (a
    figure over the kitchen), else the base frame. ``given`` (the rolled-out pose, a world pose for sim samples) is
    turned back into the base frame for a sim sample drawn without its kitchen; without one, the top-scored cell of
    ``values`` [M], or None where no cell has a finite value (a diverged model's NaN map, a view without floor):
    best_pose's error failed the finished test run and lost its report."""
    world_base = ((s.meta or {}).get("sim") or {}).get("base_pose_world")
    if given is not None:
        return tuple(given) if base is not None or world_base is None else pose_to_base(given, world_base)
    if not np.isfinite(np.asarray(values, dtype=np.float64)).any():
        return None
    # ties broken as predict and the SR callback break them (seeded by the sample's index)
    p = best_pose(s.floor_xyz, values, None, s.target_xyz, 1, seed=int((s.meta or {}).get("index", 0)))[0]
    return pose_to_world(p, base) if base is not None else p


def draw_sample(
    fig_sample: FigureSample,
    path: str | Path,
    outline: Sequence[np.ndarray] | None = None,
) -> Path:
    """Write one PNG: [ground truth | prediction].

    Args:
        outline: world polygons of the kitchen (sim samples); None draws the plain base-frame scatter.
    """
    plt = _plt()
    s = fig_sample
    sim = (s.meta or {}).get("sim") if outline is not None else None
    base = sim["base_pose_world"] if sim is not None else None

    gt_pose, pr_pose = drawn_pose(s, s.oracle, s.label, base), drawn_pose(s, s.chosen, s.scores, base)
    fig, axes = plt.subplots(1, 2, figsize=(8.6, 4.0), dpi=100)
    try:
        meta = s.meta or {}
        title = f"{meta.get('task', '')} | {meta.get('view', '') or '-'} | {meta.get('sample_id', '')}"
        fig.suptitle(title, fontsize=9)
        panels = (("ground truth", s.label, gt_pose, s.oracle_success), ("prediction", s.scores, pr_pose, s.success))
        if sim is not None:
            from floaff_zoo.sim.pictures import plot_floor_map

            xy = base_to_world(s.floor_xyz[:, :2], base)
            t = base_to_world(np.asarray(s.target_xyz, dtype=np.float64)[None, :2], base)[0]
            tyaw = float(s.target_yaw) + float(base[2])
            cell = grid_spacing(xy)
            for ax, (name, values, pose, ok) in zip(axes, panels):
                pc = plot_floor_map(
                    ax,
                    list(outline),
                    xy,
                    np.clip(values, 0, 1),
                    cell,
                    t,
                    tyaw,
                    chosen_xy=None if pose is None else np.array(pose[:2]),
                    title=name + _outcome(ok, pose is not None),
                )
            fig.colorbar(pc, ax=list(axes), fraction=0.03, pad=0.02)
        else:
            for ax, (name, values, pose, ok) in zip(axes, panels):
                sc = ax.scatter(
                    s.floor_xyz[:, 0],
                    s.floor_xyz[:, 1],
                    c=np.clip(values, 0, 1),
                    s=14,
                    marker="s",
                    cmap="viridis",
                    vmin=0.0,
                    vmax=1.0,
                )
                t = np.asarray(s.target_xyz, dtype=np.float64)
                ax.plot(t[0], t[1], marker="*", color="red", markersize=12)
                ln = 0.3
                ax.annotate(
                    "",
                    xy=(t[0] + ln * math.cos(s.target_yaw), t[1] + ln * math.sin(s.target_yaw)),
                    xytext=(t[0], t[1]),
                    arrowprops=dict(arrowstyle="->", color="red", lw=1.5),
                )
                if pose is not None:
                    ax.plot(pose[0], pose[1], marker="x", color="black", markersize=10, mew=2.0)
                ax.plot(0.0, 0.0, marker="^", color="tab:orange", markersize=8)  # the observing robot
                ax.set_aspect("equal")
                ax.set_xlabel("x [m] (robot base frame)")
                ax.set_ylabel("y [m]")
                ax.set_title(name + _outcome(ok, pose is not None), fontsize=9)
            fig.colorbar(sc, ax=list(axes), fraction=0.03, pad=0.02)
        path = Path(path)
        # whole or not at all (a temp file renamed over it): a montage reading meanwhile never meets half a PNG
        atomic_write(path, lambda f: fig.savefig(f, format="png"))
        return path
    finally:
        plt.close(fig)


def write_figures(
    samples: Sequence[FigureSample],
    out_dir: str | Path,
    outline_fn: Callable[[dict[str, Any]], Sequence[np.ndarray]] | None = None,
) -> list[Path]:
    """Draw every sample into ``out_dir`` (``<task>_<view>_<k>.png``); returns the written paths.

    outline_fn: ``meta['sim'] -> world polygons``; default rebuilds the scene with
    ``floaff_zoo.sim.kitchen.build_scene`` (one build per scene). A sample whose scene cannot be
    rebuilt is drawn as a plain scatter (the failure is named in a warning).
    """
    import warnings

    outlines: dict[str, Sequence[np.ndarray] | None] = {}
    counts: dict[str, int] = {}  # per file-name prefix: groups whose names it spells alike share one count
    paths: list[Path] = []
    for s in samples:
        sim = (s.meta or {}).get("sim")
        outline = None
        if sim and "base_pose_world" in sim:
            key = repr(sorted((k, str(v)) for k, v in sim.items() if k in ("layout_id", "style_id", "seed", "task")))
            if key not in outlines:
                try:
                    outlines[key] = (outline_fn or default_outline)(sim)
                except Exception as exc:  # drawing must not fail a finished test run
                    warnings.warn(
                        f"figures: cannot rebuild scene {sim!r} ({exc}); drawing a plain scatter", stacklevel=2
                    )
                    outlines[key] = None
            outline = outlines[key]
        meta = s.meta or {}
        # the (task, view) group's k-th figure; two groups whose names spell one file name ("Close Drawer" and
        # "Close_Drawer", task "a_b" view "c" and task "a" view "b_c") count on, or the later drew over the earlier
        prefix = f"{_safe(str(meta.get('task', 'task')))}_{_safe(str(meta.get('view', '') or 'view'))}"
        k = counts.get(prefix, 0)
        counts[prefix] = k + 1
        paths.append(draw_sample(s, Path(out_dir) / f"{prefix}_{k}.png", outline))
    return paths


def default_outline(sim: dict[str, Any]) -> list[np.ndarray]:
    """Furniture/wall footprints (world polygons) of the scene ``meta['sim']`` describes."""
    from floaff_zoo.sim.kitchen import SceneSpec, build_scene

    return build_scene(SceneSpec.from_dict(sim)).floor_outline()
