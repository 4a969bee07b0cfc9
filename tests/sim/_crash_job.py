"""Per-slot job functions that misbehave, for generator retry tests (importable by spawned workers)."""

from __future__ import annotations

import os
from pathlib import Path

from floaff_zoo.sim import fileformat as ff


def crash_always(job, out, preset_dict, save_images):
    """Leave a half-written staging dir behind and kill the worker process (like a segfault)."""
    ff.staging_dir(out, job.benchmark, f"half_{job.key.replace('/', '_')}").mkdir(parents=True, exist_ok=True)
    Path(out, f"tries_{job.key.replace('/', '_')}_{os.getpid()}").touch()
    os._exit(3)


def error_then_drop(job, out, preset_dict, save_images):
    """First call: an exception record; second call: the slot is dropped (no positive candidate)."""
    marker = Path(out, f"seen_{job.key.replace('/', '_')}")
    if not marker.exists():
        marker.touch()
        return {
            "key": job.key,
            "status": "error",
            "scene_id": None,
            "attempts": [],
            "reason": "RuntimeError: x",
            "traceback": "tb",
            "wall_s": 0.0,
        }
    return {
        "key": job.key,
        "status": "dropped",
        "scene_id": None,
        "attempts": [],
        "reason": "no positive",
        "wall_s": 0.0,
    }
