"""Ray backend on a local cluster: same bytes as the local backend for generate, same outcomes for RolloutService.

ray is part of the dev extra (``pip install -e .[dev]``), so these tests always run in development and CI.
"""

from __future__ import annotations

import os

import pytest
import ray

from floaff_zoo.sim import generate as gen
from floaff_zoo.sim.kitchen import SceneSpec
from floaff_zoo.sim.presets import get_preset
from floaff_zoo.sim.rollout import RolloutService

from .test_generate import MINI, _labels
from .test_rollout import _front_pose


def _ray_children() -> list[str]:
    """Names of live (non-zombie) descendants of this process that belong to ray (raylet, gcs_server, workers)."""
    import psutil

    out = []
    for p in psutil.Process(os.getpid()).children(recursive=True):
        try:
            if p.status() == psutil.STATUS_ZOMBIE:
                continue
            cmd = " ".join(p.cmdline())
        except psutil.NoSuchProcess:
            continue
        if "ray" in cmd:
            out.append(cmd[:120])
    return out


def _wait_no_ray_children(timeout_s: float = 15.0) -> list[str]:
    """ray.shutdown() signals its processes; give them a moment to exit, then report whatever is left."""
    import time

    t_end = time.monotonic() + timeout_s
    left = _ray_children()
    while left and time.monotonic() < t_end:
        time.sleep(0.2)
        left = _ray_children()
    return left


@pytest.fixture
def ray_cleanup(monkeypatch):
    """Each test starts its own local cluster through the code under test; make sure none outlives the test.

    The cluster is kept on the loopback address: on Linux ray binds a local cluster to the node's network IP unless
    clusters are "disabled" (the flag ray reads for Windows/macOS), which makes it use 127.0.0.1. The env var reaches
    the raylet/GCS/worker processes; the attribute covers a ray module imported before this test.
    """
    from ray._private import ray_constants

    assert not ray.is_initialized(), "a ray cluster is already running in this process"
    monkeypatch.setenv(ray_constants.ENABLE_RAY_CLUSTERS_ENV_VAR, "0")
    monkeypatch.setattr(ray_constants, "ENABLE_RAY_CLUSTER", False)
    yield
    was_running = ray.is_initialized()
    ray.shutdown()  # no-op when the code under test already shut it down
    left = _wait_no_ray_children()
    assert not was_running, "the code under test left its ray cluster running"
    assert not left, f"ray processes left behind: {left}"


def test_generate_ray_matches_local_byte_for_byte(tmp_path, ray_cleanup):
    p = get_preset("tiny", **MINI)
    loc = gen.generate(tmp_path / "loc", p, seed=0, workers=1, backend="local", quiet=True)
    # no address: generate starts a local 2-CPU cluster (no dashboard) and shuts it down when done
    man = gen.generate(tmp_path / "ray", p, seed=0, workers=2, backend="ray", quiet=True)
    assert man["backend"] == "ray" and man["status"] == "done" and man["counts"]["scenes_failed"] == 0
    assert man["counts"]["scenes_ok"] == loc["counts"]["scenes_ok"] == len(p.tasks) * (p.n_train + p.n_test)
    assert not ray.is_initialized()
    a, b = _labels(tmp_path / "loc"), _labels(tmp_path / "ray")
    assert sorted(a) == sorted(b) and len(a) == man["counts"]["scenes_ok"]
    assert a == b  # scene ids, success flags, label grid, floor labels and point clouds of every view


def test_rollout_service_ray_matches_local(scene_factory, ray_cleanup):
    sc = scene_factory("CloseDrawer")
    spec = SceneSpec(0, 0, 0, "CloseDrawer")
    poses = [
        _front_pose(sc, 0.65, 0.3),
        _front_pose(sc, 3.0, 0.0),
        _front_pose(sc, 0.8, -0.3),
        _front_pose(sc, 0.55, 0.15),
    ]
    jobs = [(spec, pose) for pose in poses]
    loc = RolloutService(workers=1, backend="local").run(jobs)
    svc = RolloutService(workers=2, backend="ray")
    try:
        rem = svc.run(jobs)
        assert ray.is_initialized()
        assert len(ray.nodes()) == 1 and ray.cluster_resources().get("CPU") == 2.0
    finally:
        svc.close()
    assert not ray.is_initialized()  # the service started the cluster, so close() ends it
    assert [(r.success, r.reason) for r in rem] == [(r.success, r.reason) for r in loc]
    assert [r.sim_seconds for r in rem] == [r.sim_seconds for r in loc]
    assert any(r.success for r in loc) and not all(r.success for r in loc)  # both outcomes are compared
