"""Rollout job functions for RolloutService pool tests (importable by spawned workers)."""

from __future__ import annotations

import os
import time
from pathlib import Path

from floaff_zoo.sim.rollout import RolloutResult

#: the folder ``touch_slowly`` marks its jobs in (set before the pool starts: spawned workers inherit it)
MARK_DIR_ENV = "FLOAFF_TEST_MARK_DIR"


def touch_slowly(job) -> RolloutResult:
    """Mark job ``pose[0]`` as run, after 10 ms."""
    time.sleep(0.01)
    Path(os.environ[MARK_DIR_ENV], f"{int(job[1][0])}").touch()
    return RolloutResult(True, "success", 0.0, 0.01)


def spawn_environment(job) -> RolloutResult:
    """The worker's BLAS thread variables as its process was started with them (/proc/self/environ: what a
    library loaded at start-up read, whatever the initializer set later)."""
    env = dict(kv.split("=", 1) for kv in Path("/proc/self/environ").read_text().split("\0") if "=" in kv)
    state = {k: env.get(k) for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    return RolloutResult(True, "success", 0.0, 0.0, state)
