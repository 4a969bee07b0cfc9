"""The rollout worker pool survives a dead worker (the lost episodes are retried on a fresh pool) and never hangs:
a job that keeps killing its worker, or a worker that hangs, ends the evaluation with an error naming the episode.

The jobs are fake 50 ms rollouts (tests/report/_fake_jobs.py), so these tests measure the pool, not MuJoCo."""

from __future__ import annotations

import os
import signal
import threading
import time

import lightning as L
import pytest

from floaff_zoo.callbacks.rollout import RolloutSuccessRate
from floaff_zoo.sim.kitchen import SceneSpec
from floaff_zoo.sim.rollout import RolloutJobError, RolloutPoolError, RolloutService
from tests.report import _fake_jobs
from tests.report._fake_world import ConstantModule, LabelModule, loader, make_samples


def _kill_a_worker_once_busy(pid_dir, after_s: float = 0.3) -> threading.Thread:
    """Background thread: once a worker has started a job, SIGKILL it (mid-evaluation)."""

    def kill():
        t_end = time.monotonic() + 60
        while time.monotonic() < t_end and not os.listdir(pid_dir):
            time.sleep(0.02)
        time.sleep(after_s)
        os.kill(int(sorted(os.listdir(pid_dir))[0]), signal.SIGKILL)

    thread = threading.Thread(target=kill, daemon=True)
    thread.start()
    return thread


def _sr(module, samples, workers: int, job_fn=_fake_jobs.fake_job) -> tuple[dict, RolloutSuccessRate]:
    cb = RolloutSuccessRate(
        service=lambda w, b, c: RolloutService(w, b, c, job_fn=job_fn), workers=workers, progress=False
    )
    trainer = L.Trainer(
        accelerator="cpu",
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        enable_checkpointing=False,
        callbacks=[cb],
    )
    return trainer.test(module, dataloaders=loader(samples), verbose=False)[0], cb


def test_killed_worker_episodes_are_retried_and_the_sr_is_unchanged(tmp_path, monkeypatch):
    samples = make_samples(40)
    reference, _ = _sr(ConstantModule(), samples, workers=1)  # in-process: no pool involved
    monkeypatch.setenv(_fake_jobs.PID_DIR_ENV, str(tmp_path))
    killer = _kill_a_worker_once_busy(tmp_path)
    res, cb = _sr(ConstantModule(), samples, workers=2)
    killer.join(timeout=1)
    assert not killer.is_alive()
    assert len(os.listdir(tmp_path)) >= 3  # the two first workers and at least one fresh one after the kill
    assert res["test_sr_all"] == reference["test_sr_all"] and res["test_oracle_sr_all"] == 1.0
    assert cb.summaries["test"]["n_evaluated"] == 40

    (tmp_path / "again").mkdir()
    monkeypatch.setenv(_fake_jobs.PID_DIR_ENV, str(tmp_path / "again"))
    killer = _kill_a_worker_once_busy(tmp_path / "again", after_s=0.1)
    res, _ = _sr(LabelModule(), samples, workers=2)
    killer.join(timeout=1)
    assert not killer.is_alive()
    assert len(os.listdir(tmp_path / "again")) >= 3  # a worker was killed and replaced here too
    assert res["test_sr_all"] == 1.0 and res["test_oracle_sr_all"] == 1.0


def _jobs(n: int):
    return [(SceneSpec(0, 0, seed, "CloseDrawer"), (0.1 * seed, 0.5, 0.0)) for seed in range(n)]


def test_a_job_that_always_kills_its_worker_is_named():
    svc = RolloutService(workers=2, max_retries=1, job_fn=_fake_jobs.crashing_job)
    try:
        with pytest.raises(
            RolloutPoolError, match=r"L0_S0_s3_CloseDrawer at \(0\.3, 0\.5, 0\.0\) killed its worker process 3 times"
        ):
            svc.run(_jobs(8))
    finally:
        svc.close()


def test_a_hanging_worker_times_out_naming_the_episode():
    svc = RolloutService(workers=2, timeout_s=4.0, job_fn=_fake_jobs.hanging_job)
    try:
        with pytest.raises(RolloutPoolError, match=r"no progress for 4 s.*L0_S0_s3_CloseDrawer"):
            svc.run(_jobs(8))
    finally:
        svc.close()
    assert svc._pool is None  # the stuck workers were killed, not left behind


@pytest.mark.parametrize("workers", [1, 2])
def test_a_job_that_raises_is_named(workers):
    """An exception raised inside a rollout came back bare from a pool worker (which of the jobs raised it was
    nowhere) and, with one worker, straight from the job function."""
    svc = RolloutService(workers=workers, job_fn=_fake_jobs.raising_job)
    try:
        with pytest.raises(
            RolloutJobError,
            match=r"rollout L0_S0_s3_CloseDrawer at \(0\.3, 0\.5, 0\.0\) raised ValueError: no cabinet wall",
        ):
            svc.run(_jobs(8))
        assert svc._pool is None  # the other chunks were stopped, not left running
    finally:
        svc.close()


def test_pool_chunks_stay_short_however_many_jobs():
    """A chunk held len(jobs) / (4 x workers) jobs, and timeout_s counts finished chunks: a large enough evaluation
    of healthy rollouts (a few thousand jobs per worker) reported a hanging worker."""
    from floaff_zoo.sim.rollout import MAX_CHUNK_JOBS, _chunks

    for n, workers in ((5, 2), (100, 2), (30_000, 2), (30_000, 8)):
        chunks = _chunks(n, workers)
        assert [i for c in chunks for i in c] == list(range(n))  # every job once, in order (sorted by scene)
        assert max(map(len, chunks)) <= MAX_CHUNK_JOBS
    assert len(_chunks(100, 2)) == 9  # small evaluations keep about four chunks per worker


_SIMULATED: list[tuple[float, float, float]] = []


def _recording_job(job):
    _SIMULATED.append(tuple(job[1]))
    return _fake_jobs.fake_job(job)


def test_the_evaluation_rolls_out_the_chosen_pose_as_the_annotation_does():
    """Default rounding = the annotation's (6 decimals): the simulated pose is the chosen one, not a 2-decimal
    neighbour (which flips knife-edge rollouts: docs/background.md §5)."""
    from floaff_zoo.frames import ROLLOUT_POSE_DECIMALS

    _SIMULATED.clear()
    _, cb = _sr(LabelModule(), make_samples(12), workers=1, job_fn=_recording_job)
    assert ROLLOUT_POSE_DECIMALS == 6 and cb.cache_decimals == ROLLOUT_POSE_DECIMALS
    chosen = {tuple(round(v, 6) for v in ep["pose"]) for ep in cb.episodes["test"]}
    assert chosen <= set(_SIMULATED)
    assert any(abs(v - round(v, 2)) > 1e-4 for p in chosen for v in p)  # finer than 2 decimals reached the sim
