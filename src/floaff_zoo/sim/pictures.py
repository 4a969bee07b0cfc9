"""Pictures of generated scenes (matplotlib Agg): top-down floor-affordance map and egocentric RGB views."""

from __future__ import annotations

import io
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from floaff_zoo.checks import check_integer, check_number

__all__ = ["plot_floor_map", "render_topdown_png", "rgb_png"]


def _plt():
    import matplotlib

    if matplotlib.get_backend().lower() != "agg":
        matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    return plt


def plot_floor_map(
    ax,
    outline_polys: Sequence[np.ndarray],
    cells_xy: np.ndarray,
    values: np.ndarray,
    cell: float,
    target_xy: np.ndarray | None = None,
    target_yaw: float | None = None,
    chosen_xy: np.ndarray | None = None,
    title: str | None = None,
    vmin: float = 0.0,
    vmax: float = 1.0,
    cmap: str = "viridis",
):
    """Draw a floor map on a matplotlib Axes (world or any planar frame, metres).

    outline_polys: list of [K,2] polygons (kitchen outline / furniture footprints) drawn as grey outlines.
    cells_xy [M,2] cell centres and values [M] drawn as square cells of side `cell` coloured by value.
    target_xy [2] + target_yaw: a red star with an arrow along the target's front normal. chosen_xy [2]: a white x.
    Returns the PatchCollection of cells (for a colorbar).
    """
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Polygon, Rectangle

    # a NaN or negative cell drew no cell (or a mirrored one) without a word; a NaN cell centre was not drawn, or
    # failed in matplotlib's axis limits naming nothing
    check_number("cell", cell, strict=True, owner="plot_floor_map")
    cells_xy = np.asarray(cells_xy, dtype=np.float64).reshape(-1, 2)
    values = np.asarray(values, dtype=np.float64).reshape(-1)
    if len(values) != len(cells_xy):
        raise ValueError(f"values has {len(values)} entries, cells_xy has {len(cells_xy)}")
    if not np.isfinite(cells_xy).all():
        raise ValueError(f"plot_floor_map: cells_xy must be finite, got {cells_xy[~np.isfinite(cells_xy).all(1)][0]}")
    for poly in outline_polys:
        p = np.asarray(poly, dtype=np.float64).reshape(-1, 2)
        if len(p) >= 2:
            ax.add_patch(Polygon(p, closed=True, fill=False, edgecolor="0.35", linewidth=1.0))
    h = cell / 2.0
    rects = [Rectangle((x - h, y - h), cell, cell) for x, y in cells_xy]
    pc = PatchCollection(rects, cmap=cmap, edgecolor="none")
    pc.set_array(values)
    pc.set_clim(vmin, vmax)
    ax.add_collection(pc)
    pts = [cells_xy] + [np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in outline_polys]
    if target_xy is not None:
        t = np.asarray(target_xy, dtype=np.float64)[:2]
        pts.append(t[None])
        ax.plot(t[0], t[1], marker="*", color="red", markersize=12, zorder=5)
        if target_yaw is not None:
            L = max(0.3, 3 * cell)
            ax.annotate(
                "",
                xy=(t[0] + L * math.cos(target_yaw), t[1] + L * math.sin(target_yaw)),
                xytext=(t[0], t[1]),
                arrowprops=dict(arrowstyle="->", color="red", lw=1.5),
                zorder=5,
            )
    if chosen_xy is not None:
        c = np.asarray(chosen_xy, dtype=np.float64)[:2]
        ax.plot(c[0], c[1], marker="x", color="white", markersize=10, mew=2.5, zorder=6)
        ax.plot(c[0], c[1], marker="x", color="black", markersize=10, mew=1.0, zorder=7)
    allp = np.concatenate([p for p in pts if len(p)], axis=0) if any(len(p) for p in pts) else np.zeros((1, 2))
    lo, hi = allp.min(axis=0) - 0.2, allp.max(axis=0) + 0.2
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    if title:
        ax.set_title(title, fontsize=9)
    return pc


def render_topdown_png(
    outline_polys: Sequence[np.ndarray],
    cells_xy: np.ndarray,
    values: np.ndarray,
    cell: float,
    target_xy: np.ndarray,
    target_yaw: float,
    title: str,
    view_poses: np.ndarray | None = None,
    size_px: int = 256,
) -> bytes:
    """PNG bytes of a top-down map; view_poses [V,4] (x, y, yaw, is_side) are drawn as small arrows."""
    # a NaN or negative size drew the smallest picture without a word; [V,3] poses failed in numpy's reshape
    check_integer("size_px", size_px, 1, owner="render_topdown_png")
    if view_poses is not None and np.asarray(view_poses).size and np.asarray(view_poses).shape[-1:] != (4,):
        shape = np.asarray(view_poses).shape
        raise ValueError(f"render_topdown_png: view_poses must be [V,4] (x, y, yaw, is_side), got {shape}")
    plt = _plt()
    dpi = max(60, size_px // 3)  # the figure is 6.4 x 5 in; size_px scales its resolution
    fig, ax = plt.subplots(figsize=(6.4, 5.0), dpi=dpi)
    try:
        pc = plot_floor_map(ax, outline_polys, cells_xy, values, cell, target_xy, target_yaw, title=title)
        fig.colorbar(pc, ax=ax, fraction=0.046, pad=0.04, label="label")
        if view_poses is not None and len(view_poses):
            for x, y, yaw, side in np.asarray(view_poses, dtype=np.float64).reshape(-1, 4):
                col = "tab:orange" if side else "tab:cyan"
                ax.arrow(x, y, 0.15 * math.cos(yaw), 0.15 * math.sin(yaw), color=col, width=0.01, zorder=4)
        buf = io.BytesIO()
        fig.savefig(buf, format="png", bbox_inches="tight")
        return buf.getvalue()
    finally:
        plt.close(fig)


def picture_path(path: str | Path, who: str, example: str = "picture.png", error: type[Exception] = ValueError) -> Path:
    """The picture file to write for ``path``: ``.png`` added when it has no suffix (matplotlib would add it without
    saying so); ``error`` naming ``who`` (e.g. ``"plot: "``, ``"--out "``), before anything is drawn, for a folder
    (matplotlib wrote ``<folder>.png`` beside it) or a suffix matplotlib cannot write."""
    from matplotlib.backend_bases import FigureCanvasBase

    path = Path(path)
    if path.is_dir():
        raise error(f"{who}{path}: is a folder; name the picture to write, e.g. {path / example}")
    if not path.suffix:
        return path.with_suffix(".png")
    formats = FigureCanvasBase.get_supported_filetypes()
    if path.suffix[1:].lower() not in formats:
        raise error(f"{who}{path}: cannot write {path.suffix!r} pictures; use one of {sorted(formats)}")
    return path


def rgb_png(rgb: np.ndarray, min_size: int = 128) -> bytes:
    """PNG bytes of an RGB image [H,W,3] of integers 0..255 (uint8), upscaled by an integer nearest-neighbour factor
    to >= min_size.

    Raises:
        ValueError: another shape, an empty image, or values that are not integers 0..255 (a float image in [0, 1]
            was cast to an all-black picture, 300 wrapped to 44, NaN became 0).
    """
    check_integer("min_size", min_size, 1, owner="rgb_png")  # NaN failed in math.ceil naming nothing
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.size == 0:
        raise ValueError(f"rgb must be a non-empty [H,W,3] image, got {rgb.shape}")
    if rgb.dtype != np.uint8:
        values = rgb.astype(np.float64)
        if not (np.isfinite(values).all() and values.min() >= 0 and values.max() <= 255 and (values % 1 == 0).all()):
            unit = np.isfinite(values).all() and values.min() >= 0 and values.max() <= 1
            raise ValueError(
                f"rgb must hold integers 0..255 (uint8), got {rgb.dtype} in [{values.min()}, {values.max()}]"
                + ("; scale a [0, 1] image by 255" if unit else "")
            )
        rgb = rgb.astype(np.uint8)
    k = max(1, int(math.ceil(min_size / max(1, min(rgb.shape[:2])))))
    if k > 1:
        rgb = np.repeat(np.repeat(rgb, k, axis=0), k, axis=1)
    plt = _plt()
    buf = io.BytesIO()
    plt.imsave(buf, rgb, format="png")
    return buf.getvalue()


def save_bytes(path: str | Path, data: bytes) -> None:
    """Atomic write of picture bytes."""
    from floaff_zoo.sim.fileformat import atomic_write_bytes

    atomic_write_bytes(path, data)
