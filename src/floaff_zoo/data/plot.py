"""Quick look at one sample: scene points coloured by the target flag, floor points by their label."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import torch

from floaff_zoo.contract import Sample
from floaff_zoo.sim.pictures import picture_path


def _np(x: Any) -> np.ndarray:
    return x.detach().cpu().numpy() if torch.is_tensor(x) else np.asarray(x)


def _mask(sample: Sample, key: str, n: int) -> np.ndarray:
    """``sample[key]`` [n] as bool (all True when absent); ValueError naming the field when its length is not n."""
    mask = _np(sample.get(key, np.ones(n, bool))).astype(bool).reshape(-1)
    if len(mask) != n:
        raise ValueError(f"plot: {key} has {len(mask)} entries for {n} points")
    return mask


def plot(sample: Sample, path: str | Path | None = None, scores: Any = None) -> Any:
    """Top view (x forward, y left) + side view of one sample (matplotlib Agg; no display needed).

    Args:
        sample: a contract sample (numpy or tensors; masks optional).
        path: save the figure there (PNG) when given.
        scores: optional predicted per-floor-point scores [M] shown in a third panel.
    Returns:
        the matplotlib Figure (closed after saving when ``path`` is given).
    """
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    path = picture_path(path, "plot: ", "sample.png") if path is not None else None
    xyz = _np(sample["scene_xyz"])
    flag = _np(sample["scene_feat"]).reshape(xyz.shape[0], -1)[:, 0]
    smask = _mask(sample, "scene_mask", len(xyz))
    floor = _np(sample["floor_xyz"])
    label = _np(sample["floor_label"]).reshape(-1)
    fmask = _mask(sample, "floor_mask", len(floor))
    if scores is not None:
        scores = _np(scores).reshape(-1)
        if len(scores) != len(floor):
            raise ValueError(f"plot: scores has {len(scores)} entries for {len(floor)} floor points")
    t = _np(sample["target_xyz"]).reshape(3)
    yaw = float(_np(sample["target_yaw"]))
    xyz, flag, floor, label = xyz[smask], flag[smask], floor[fmask], label[fmask]
    panels = 3 if scores is not None else 2
    fig, axes = plt.subplots(1, panels, figsize=(5 * panels, 4.6))
    colours = np.where(flag > 0, "tab:red", np.where(flag < 0, "tab:blue", "0.7"))
    ax = axes[0]
    ax.scatter(xyz[:, 0], xyz[:, 1], s=1, c=colours, alpha=0.5)
    sc = ax.scatter(floor[:, 0], floor[:, 1], s=8, c=label, cmap="viridis", vmin=0, vmax=1)
    ax.plot([0], [0], marker="^", color="k", ms=9, label="robot")
    ax.plot([t[0]], [t[1]], marker="*", color="tab:red", ms=14, label="target")
    ax.arrow(t[0], t[1], 0.4 * math.cos(yaw), 0.4 * math.sin(yaw), width=0.02, color="tab:red")
    ax.set_aspect("equal")
    ax.set_xlabel("x forward (m)")
    ax.set_ylabel("y left (m)")
    ax.legend(loc="best", fontsize=7)
    fig.colorbar(sc, ax=ax, label="floor label")
    meta = sample.get("meta") or {}
    ax.set_title(
        f"{meta.get('dataset', '')} {meta.get('task', '')} {meta.get('view', '')}\n{meta.get('sample_id', '')}",
        fontsize=8,
    )
    ax = axes[1]
    ax.scatter(xyz[:, 0], xyz[:, 2], s=1, c=colours, alpha=0.5)
    ax.set_xlabel("x forward (m)")
    ax.set_ylabel("z up (m)")
    ax.set_title("side view (red target, blue obstacle)", fontsize=8)
    if scores is not None:
        ax = axes[2]
        sc = ax.scatter(floor[:, 0], floor[:, 1], s=8, c=scores[fmask], cmap="viridis", vmin=0, vmax=1)
        ax.set_aspect("equal")
        ax.set_title("prediction", fontsize=8)
        fig.colorbar(sc, ax=ax)
    fig.tight_layout()
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=100)
        plt.close(fig)
    return fig


__all__ = ["plot"]
