"""Rollout job functions for worker-pool tests: fast, and light enough for spawned workers to import
(``floaff_zoo.sim.rollout`` only; no torch). Success is a deterministic function of the world pose."""

from __future__ import annotations

import math
import os
import time
from pathlib import Path

from floaff_zoo.sim.rollout import RolloutResult

BASE_RATE = 0.3
#: a folder where every job drops a file named after its worker's pid (tests pick a worker to kill)
PID_DIR_ENV = "FLOAFF_TEST_PID_DIR"
#: the scene seed whose rollout misbehaves in crashing_job / hanging_job
BAD_SEED = 3


def fake_success(x: float, y: float) -> bool:
    """Pseudo-random but deterministic in the pose rounded to 2 decimals; P(success) = BASE_RATE."""
    h = math.sin(round(x, 2) * 12.9898 + round(y, 2) * 78.233) * 43758.5453
    return (h - math.floor(h)) < BASE_RATE


def fake_job(job) -> RolloutResult:
    """One 'rollout' of 50 ms: job = (spec dict, pose, seed), as RolloutService sends it to a worker."""
    folder = os.environ.get(PID_DIR_ENV)
    if folder:
        Path(folder, str(os.getpid())).touch()
    time.sleep(0.05)
    ok = fake_success(job[1][0], job[1][1])
    return RolloutResult(success=ok, reason="success" if ok else "not_closed", sim_seconds=1.0, wall_seconds=0.05)


def crashing_job(job) -> RolloutResult:
    """Kills its worker (like a segfault) on the scene with seed BAD_SEED, every time."""
    if job[0]["seed"] == BAD_SEED:
        os._exit(9)
    return fake_job(job)


def hanging_job(job) -> RolloutResult:
    """Never returns on the scene with seed BAD_SEED (a worker stuck in a deadlock)."""
    if job[0]["seed"] == BAD_SEED:
        time.sleep(3600)
    return fake_job(job)


def raising_job(job) -> RolloutResult:
    """Raises a Python exception (a scene that cannot be built) on the scene with seed BAD_SEED."""
    if job[0]["seed"] == BAD_SEED:
        raise ValueError("no cabinet wall in this layout")
    return fake_job(job)
