"""The scene table of a ``scene_sr.py --json`` file, checked (shared by the scripts that read those files)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np


def _fraction(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and 0.0 <= v <= 1.0


def checked_scenes(doc: Any, where: str, prog: str) -> dict[str, dict]:
    """``doc["scenes"]`` ({scene id: {task, views, sr: {NAME: SR}}}); exits naming ``where`` when it is not a
    scene_sr JSON: no scenes, or a scene without a task, with views < 1 (its SR would read nan) or an SR value that is
    not a number in [0, 1]."""
    scenes = doc.get("scenes") if isinstance(doc, dict) else None
    if not isinstance(scenes, dict) or not scenes:
        raise SystemExit(f"{prog}: {where} is not a scene_sr.py --json output (no scenes)")
    for sid, s in scenes.items():
        views = s.get("views") if isinstance(s, dict) else None
        ok = (
            isinstance(s, dict)
            and isinstance(s.get("task"), str)
            and isinstance(views, int)
            and not isinstance(views, bool)
            and views > 0
            and isinstance(s.get("sr"), dict)
            and all(_fraction(v) for v in s["sr"].values())
        )
        if not ok:
            raise SystemExit(f"{prog}: {where}: scene {sid} needs a task, views >= 1 and SR values in [0, 1]")
    return scenes


def sr_all(scenes: dict[str, dict], ids: list[str], name: str) -> float:
    """SR over all views of the listed scenes (a scene listed twice counts twice)."""
    views = np.array([scenes[s]["views"] for s in ids], float)
    return float(np.dot(views, [scenes[s]["sr"][name] for s in ids]) / views.sum())
