"""Per-slot job functions that misbehave, for generator retry tests (importable by spawned workers)."""

from __future__ import annotations

import os
import time
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


def interrupted(job, out, preset_dict, save_images):
    """The run is stopped (Ctrl-C) in the middle of this slot."""
    raise KeyboardInterrupt


def slow_marker(job, out, preset_dict, save_images):
    """Write pid_<pid>, take 8 s, then mark the slot done (after_<slot>): a worker still running after its driver
    died would write the mark."""
    Path(out, f"pid_{os.getpid()}").write_text(str(os.getpid()))
    time.sleep(8)
    Path(out, f"after_{job.key.replace('/', '_')}").touch()
    return {"key": job.key, "status": "dropped", "scene_id": None, "attempts": [], "reason": "x", "wall_s": 0.0}


def crash_first_slot(job, out, preset_dict, save_images):
    """Kill the worker process on slot train0 only; every other slot is dropped after 2 s (in flight meanwhile)."""
    Path(out, f"tries_{job.key.replace('/', '_')}_{os.getpid()}").touch()
    if job.key.endswith("/train0"):
        os._exit(3)
    time.sleep(2)
    return {"key": job.key, "status": "dropped", "scene_id": None, "attempts": [], "reason": "x", "wall_s": 0.0}
