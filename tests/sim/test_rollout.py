import math
import re
import sys

import numpy as np
import pytest

from floaff_zoo.sim.annotate import annotate_scene
from floaff_zoo.sim.kitchen import SceneSpec
from floaff_zoo.sim.rollout import RolloutService, heading_to_target, pose_filter, rollout


def _front_pose(sc, dist, lat):
    t = sc.target
    n = np.array([math.cos(t.yaw), math.sin(t.yaw)])
    u = np.array([-n[1], n[0]])
    p = t.pos[:2] + dist * n + lat * u
    return (round(float(p[0]), 4), round(float(p[1]), 4), round(heading_to_target(sc, *p), 4))


def _find_success(sc):
    for dist in (0.65, 0.8, 0.55):
        for lat in (0.3, -0.3, 0.15, -0.15):
            pose = _front_pose(sc, dist, lat)
            r = rollout(sc, pose)
            if r.success:
                return pose, r
    pytest.fail("no successful CloseDrawer pose found near the drawer")


def test_success_reruns_to_success_and_is_deterministic(scene_factory):
    sc = scene_factory("CloseDrawer")
    pose, r = _find_success(sc)
    r2 = rollout(sc, pose)
    assert r2.success and r2.reason == "success"
    assert r2.sim_seconds == r.sim_seconds and r2.state == r.state


@pytest.mark.parametrize("field", ["qpos", "qvel"])
def test_a_diverged_simulation_is_unstable_not_a_success(scene_factory, field, tmp_path, monkeypatch):
    """A NaN in qpos or qvel makes mj_step warn (BADQPOS / BADQVEL) and reset the state to qpos0, where the drawer
    stands closed: the rollout checked only BADQACC and scored the reset state a CloseDrawer success."""
    from floaff_zoo.sim.controllers import default_policy

    monkeypatch.chdir(tmp_path)  # MuJoCo writes its warnings to MUJOCO_LOG.TXT in the working directory
    sc = scene_factory("CloseDrawer")
    pose, _ = _find_success(sc)
    policy = default_policy("CloseDrawer")
    act = policy.act

    def diverging(scene, t):
        if abs(t - 0.5) < 1e-6:  # half a second in, one arm joint's state becomes NaN
            adr = scene.robot.arm_qadr[3] if field == "qpos" else scene.robot.arm_dadr[3]
            getattr(scene.data, field)[adr] = np.nan
        return act(scene, t)

    policy.act = diverging
    r = rollout(sc, pose, policy)
    assert not r.success and r.reason == "unstable"


def test_far_pose_fails(scene_factory):
    for task in ("CloseDrawer", "OpenSingleDoor"):
        sc = scene_factory(task)
        # refused as the annotation filters it (out of reach), nothing simulated
        r = rollout(sc, _front_pose(sc, 3.0, 0.0))
        assert not r.success and r.reason == "filtered_reach" and r.sim_seconds == 0.0
        # simulated anyway, the policy cannot reach the fixture
        r = rollout(sc, _front_pose(sc, 3.0, 0.0), check_pose=False)
        assert not r.success and r.reason == "ik_unreachable"


def test_pose_filter_refuses_what_the_annotation_filters(scene_factory):
    """Evaluation and annotation share one feasibility filter; checked against the scene's primitives, not against
    itself: out of reach, behind the front plane or with the base over furniture is refused, a successful pose is
    not, and a refused pose is never simulated."""
    sc = scene_factory("CloseDrawer")
    t = sc.target
    assert pose_filter(sc, *_front_pose(sc, 3.0, 0.0)) == "filtered_reach"
    assert pose_filter(sc, *_front_pose(sc, -0.3, 0.0)) == "filtered_collision"  # inside the fixture
    assert pose_filter(sc, *_find_success(sc)[0]) == ""
    a = annotate_scene(sc, cell=0.2)
    c = t.pos[:2]
    for i, (x, y) in enumerate(a.grid_xy):
        reason = pose_filter(sc, float(x), float(y), float(a.yaw[i]))
        if np.hypot(x - c[0], y - c[1]) >= sc.task.r_arm:
            assert reason == "filtered_reach"
        elif not sc.footprint_free(x, y, a.yaw[i]):
            assert reason == "filtered_collision"
        if a.valid[i]:  # the annotation kept it: feasible
            assert reason == ""
    i = next(i for i, r in enumerate(a.reasons) if r == "filtered_collision")
    r = rollout(sc, (*a.grid_xy[i], a.yaw[i]))
    assert not r.success and r.reason == "filtered_collision" and r.sim_seconds == 0.0 and r.state == {}


def test_heading_faces_target(scene_factory):
    sc = scene_factory("CloseDrawer")
    x, y = sc.target.pos[0] + 1.0, sc.target.pos[1]
    assert abs(heading_to_target(sc, x, y) - math.pi) < 1e-9


def test_bad_pose_rejected(scene_factory):
    """A bad base pose is refused naming the function and argument that got it (the rollout said only "base_pose
    must be finite", the service's cache nothing, and a pose that is no numbers gave float()'s bare error)."""
    sc = scene_factory("CloseDrawer")
    for bad in ((0.0, float("nan"), 0.0), ("x", 0.0, 0.0), (0.0, 0.0)):
        with pytest.raises(ValueError, match=r"^rollout: base_pose must be 3 finite values \(x, y, yaw\)"):
            rollout(sc, bad)
    with pytest.raises(ValueError, match=r"^RolloutService.run: the job's pose must be 3 finite values"):
        RolloutService().run([(SceneSpec(0, 0, 0, "CloseDrawer"), ("x", 0.0, 0.0))])


@pytest.mark.parametrize("bad", [0, 1, 2])
def test_non_finite_pose_is_refused_not_filtered(scene_factory, bad):
    """pose_filter, footprint_free and wall_between reported a NaN pose as a collision, a blocked footprint and a wall
    (no comparison with a NaN finds a separating axis): a broken pose read as an infeasible one; they now refuse it."""
    sc = scene_factory("CloseDrawer")
    pose = list(_front_pose(sc, 0.65, 0.3))
    assert pose_filter(sc, *pose) == ""
    pose[bad] = float("nan")
    with pytest.raises(ValueError, match="finite"):
        pose_filter(sc, *pose)
    with pytest.raises(ValueError, match="finite"):
        sc.footprint_free(*pose)
    with pytest.raises(ValueError, match="finite"):
        sc.set_base_pose(*pose)
    if bad < 2:
        with pytest.raises(ValueError, match="finite"):
            sc.wall_between(pose[0], pose[1], sc.target.pos)
    with pytest.raises(ValueError, match="finite"):
        sc.wall_between(0.0, -3.0, (float("inf"), 0.0))


def test_service_cache_and_workers(scene_factory):
    sc = scene_factory("CloseDrawer")
    spec = SceneSpec(0, 0, 0, "CloseDrawer")
    jobs = [(spec, _front_pose(sc, 0.65, 0.3)), (spec, _front_pose(sc, 3.0, 0.0)), (spec, _front_pose(sc, 0.8, -0.3))]
    one = RolloutService(workers=1).run(jobs)
    svc2 = RolloutService(workers=2)
    try:
        two = svc2.run(jobs)
    finally:
        svc2.close()
    assert [(r.success, r.reason, r.sim_seconds) for r in one] == [(r.success, r.reason, r.sim_seconds) for r in two]
    svc = RolloutService(workers=1)
    svc.run(jobs[:1])
    assert len(svc.cache) == 1
    svc.run(jobs[:1])
    assert len(svc.cache) == 1


def test_ray_backend_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # ray is a dev dependency: simulate a user without it
    with pytest.raises(ImportError, match="needs the 'ray' package"):
        RolloutService(backend="ray")
    with pytest.raises(ValueError, match="backend"):
        RolloutService(backend="dask")


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"workers": 2.5}, "RolloutService: workers must be an integer >= 1, got 2.5"),  # ran 2 workers
        ({"workers": True}, "RolloutService: workers must be an integer >= 1, got True"),
        ({"workers": "2"}, "RolloutService: workers must be an integer >= 1, got '2'"),  # a bare TypeError
        ({"workers": float("nan")}, "RolloutService: workers must be an integer >= 1, got nan"),
        ({"cache_decimals": -1}, "RolloutService: cache_decimals must be an integer >= 0, got -1"),  # 10 m cells
        ({"seed": -1}, "RolloutService: seed must be an integer >= 0, got -1"),  # failed in the first rollout
        ({"seed": 2.5}, "RolloutService: seed must be an integer >= 0, got 2.5"),
        ({"max_retries": 1.5}, "RolloutService: max_retries must be an integer >= 0, got 1.5"),
        ({"timeout_s": float("inf")}, "RolloutService: timeout_s must be a finite number > 0, got inf"),
        ({"timeout_s": True}, "RolloutService: timeout_s must be a finite number > 0, got True"),  # 1 s
        ({"timeout_s": "5"}, "RolloutService: timeout_s must be a finite number > 0, got '5'"),
    ],
)
def test_a_bad_service_setting_is_named(kwargs, message):
    with pytest.raises(ValueError, match=f"^{re.escape(message)}$"):
        RolloutService(**kwargs)


def test_a_bad_seed_r_arm_seconds_or_scene_is_named():
    """A seed 2.5 reset the task as seed 2, -1 failed in numpy's rng naming nothing (mid-run in a pool); a NaN
    r_arm filtered no pose by reach; hold_still ran nothing for a negative time and failed in int() for a NaN.
    Every check comes before the scene is touched, so no scene is built here."""
    import floaff_zoo.sim.rollout as ro

    scene = object()
    with pytest.raises(ValueError, match=r"^pose_filter: seed must be an integer >= 0, got 2\.5"):
        pose_filter(scene, 0.0, 0.0, 0.0, seed=2.5)
    with pytest.raises(ValueError, match=r"^pose_filter: r_arm must be a finite number > 0 or null"):
        pose_filter(scene, 0.0, 0.0, 0.0, r_arm=float("nan"))
    with pytest.raises(ValueError, match=r"^rollout: seed must be an integer >= 0, got -1"):
        rollout(scene, (0.0, 0.0, 0.0), seed=-1)
    with pytest.raises(TypeError, match=r"^rollout: scene must be a SimScene or a SceneSpec, got dict"):
        rollout({}, (0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match=r"^start_rollout: seed must be an integer >= 0, got None"):
        ro.start_rollout(scene, (0.0, 0.0, 0.0), None, seed=None)
    for bad in (-1.0, float("nan"), "1"):
        with pytest.raises(ValueError, match=r"^hold_still: seconds must be a finite number >= 0"):
            ro.hold_still(scene, bad)
    with pytest.raises(ValueError, match=r"^RolloutService.run: seed must be an integer >= 0 or null"):
        RolloutService().run([(SceneSpec(0, 0, 0, "CloseDrawer"), (0.0, 0.0, 0.0))], seed=-1)
    with pytest.raises(TypeError, match=r"^RolloutService: job_fn must be a function"):
        RolloutService(job_fn=None)


def test_one_service_serves_every_task_seed(monkeypatch):
    """repeat.service_runner kept one service, hence one pool of worker processes with their scene caches, alive per
    task seed (per episode); one service now takes the seed per run and keeps the results of each seed apart."""
    import floaff_zoo.sim.rollout as ro
    from floaff_zoo.sim.repeat import service_runner

    seen: list[int] = []

    def fake_job(job):
        seen.append(job[2])
        return ro.RolloutResult(success=job[2] % 2 == 0, reason="fake", sim_seconds=0.0, wall_seconds=0.0)

    made: list = []

    class CountingService(ro.RolloutService):
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs, job_fn=fake_job)
            made.append(self)

    monkeypatch.setattr(ro, "RolloutService", CountingService)
    job = [(SceneSpec(0, 0, 0, "CloseDrawer"), (0.5, -1.0, 1.0))]
    run = service_runner(1)
    assert run(4, job) == [True] and run(5, job) == [False] and run(4, job) == [True]
    assert len(made) == 1 and seen == [4, 5]  # one service; the seed-4 result came from its cache
    assert len(made[0].cache) == 2


def _jobs_module():
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    import _rollout_jobs

    return _rollout_jobs


def test_close_after_an_interrupted_run_drops_the_queued_rollouts(tmp_path, monkeypatch):
    """close() waited for every chunk still queued when run() was interrupted (Ctrl-C): a hung worker kept it
    waiting for ever."""
    import floaff_zoo.sim.rollout as ro

    rj = _jobs_module()
    monkeypatch.setenv(rj.MARK_DIR_ENV, str(tmp_path))
    svc = RolloutService(workers=2, job_fn=rj.touch_slowly)
    jobs = [(SceneSpec(0, 0, 0, "CloseDrawer"), (float(i), 0.0, 0.0)) for i in range(400)]  # 13 chunks of <= 32
    wait = ro.cf.wait

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt("simulated Ctrl-C while the rollouts run")

    monkeypatch.setattr(ro.cf, "wait", interrupted)
    with pytest.raises(KeyboardInterrupt):
        svc.run(jobs)
    monkeypatch.setattr(ro.cf, "wait", wait)
    svc.close()
    ran = len(list(tmp_path.iterdir()))
    assert ran <= 5 * ro.MAX_CHUNK_JOBS, ran  # the chunks running or handed to a worker, not the 400


def test_pool_workers_start_with_one_blas_thread(monkeypatch):
    """The thread variables were set only while the pool object was made; its workers start at the first submit,
    and load numpy before their initializer runs: each started with as many BLAS threads as cores."""
    import os

    from floaff_zoo.runtime import THREAD_ENV

    rj = _jobs_module()
    for k in THREAD_ENV:
        monkeypatch.delenv(k, raising=False)
    svc = RolloutService(workers=2, job_fn=rj.spawn_environment)
    try:
        results = svc.run([(SceneSpec(0, 0, 0, "CloseDrawer"), (float(i), 0.0, 0.0)) for i in range(8)])
    finally:
        svc.close()
    assert all(r.state == dict.fromkeys(THREAD_ENV, "1") for r in results), [r.state for r in results]
    assert not any(k in os.environ for k in THREAD_ENV)  # this process's environment is as it was


def test_a_rollout_process_keeps_only_its_most_recent_scenes(monkeypatch):
    """A rollout worker (or the training process with workers=1) kept every scene it built, each with its compiled
    kitchen (~80 MB), for its whole life; it keeps the last WORKER_SCENES_SIZE."""
    import floaff_zoo.sim.rollout as ro

    monkeypatch.setattr(ro, "_WORKER_SCENES", {})
    monkeypatch.setattr(ro, "WORKER_SCENES_SIZE", 2, raising=False)
    specs = [SceneSpec(0, 0, s, "CloseDrawer") for s in (11, 12, 13)]
    for spec in specs:  # a pose off the floor: refused by the pose filter, the scene is built all the same
        ro._run_job((spec.to_dict(), (9.0, 9.0, 0.0), 0))
    assert list(ro._WORKER_SCENES) == specs[1:]


def test_close_releases_the_scenes_built_for_rollouts_in_this_process():
    """With workers=1 (the callback's default) the scenes were built in the training process and kept for its
    life (~80 MB each), close() or not."""
    import floaff_zoo.sim.kitchen as kitchen
    import floaff_zoo.sim.rollout as ro

    spec, other = SceneSpec(0, 0, 7, "CloseDrawer"), SceneSpec(0, 0, 8, "CloseDrawer")
    svc, beside = RolloutService(workers=1), RolloutService(workers=1)
    svc.run([(spec, (9.0, 9.0, 0.0))])
    beside.run([(other, (9.0, 9.0, 0.0))])
    assert spec in ro._WORKER_SCENES and (0, 0, 7) in kitchen._CACHE
    svc.close()
    assert spec not in ro._WORKER_SCENES and (0, 0, 7) not in kitchen._CACHE
    assert other in ro._WORKER_SCENES  # a service beside it keeps its scenes until it closes
    beside.close()
    assert other not in ro._WORKER_SCENES


def test_closing_a_service_leaves_the_scenes_an_open_service_shares(monkeypatch):
    """close() released every scene it had run, also one an open service beside it ran (which then built it again
    for its next rollout) and the compiled kitchen that another task's scene of an open service shares."""
    import floaff_zoo.sim.kitchen as kitchen
    import floaff_zoo.sim.rollout as ro

    builds: list[SceneSpec] = []
    real = ro.build_scene
    monkeypatch.setattr(ro, "build_scene", lambda spec: builds.append(spec) or real(spec))
    drawer, door = SceneSpec(0, 0, 31, "CloseDrawer"), SceneSpec(0, 0, 31, "OpenSingleDoor")
    svc, beside, other_task = RolloutService(workers=1), RolloutService(workers=1), RolloutService(workers=1)
    for s, spec in ((svc, drawer), (beside, drawer), (other_task, door)):
        s.run([(spec, (9.0, 9.0, 0.0))])  # off the floor: refused by the pose filter, the scene built all the same
    assert builds == [drawer, door]
    svc.close()
    beside.run([(drawer, (9.0, 8.0, 0.0))])  # a pose not in its result cache: a rollout in the scene it ran
    assert builds == [drawer, door] and drawer in ro._WORKER_SCENES
    beside.close()
    assert drawer not in ro._WORKER_SCENES
    assert (0, 0, 31) in kitchen._CACHE  # the door scene of the open service uses the kitchen
    other_task.close()
    assert door not in ro._WORKER_SCENES and (0, 0, 31) not in kitchen._CACHE
    assert not {svc, beside, other_task} & set(ro._OPEN_SERVICES)  # another test's unclosed service may be left


def test_a_copy_of_a_service_closing_leaves_the_scenes_of_the_open_ones():
    """A count of open users per scene missed copies: a deep copy of a service that ran a scene, closed, and then the
    original closed, released the scene while a third service that ran it was still open."""
    import copy

    import floaff_zoo.sim.rollout as ro

    drawer = SceneSpec(0, 0, 32, "CloseDrawer")
    first, beside = RolloutService(workers=1), RolloutService(workers=1)
    for s in (first, beside):
        s.run([(drawer, (9.0, 9.0, 0.0))])  # off the floor: refused by the pose filter, the scene built all the same
    copy.deepcopy(first).close()
    first.close()
    assert drawer in ro._WORKER_SCENES  # ``beside`` is open
    beside.close()
    assert drawer not in ro._WORKER_SCENES


def test_close_releases_the_kitchens_of_scenes_the_lru_dropped(monkeypatch):
    """A scene the worker LRU dropped left its compiled kitchen in the kitchen cache, which close() then kept."""
    import floaff_zoo.sim.kitchen as kitchen
    import floaff_zoo.sim.rollout as ro

    monkeypatch.setattr(ro, "WORKER_SCENES_SIZE", 1)
    first, second = SceneSpec(0, 0, 21, "CloseDrawer"), SceneSpec(0, 0, 22, "CloseDrawer")
    svc = RolloutService(workers=1)
    svc.run([(first, (9.0, 9.0, 0.0)), (second, (9.0, 9.0, 0.0))])
    assert first not in ro._WORKER_SCENES and (0, 0, 21) in kitchen._CACHE  # dropped scene, kitchen still cached
    svc.close()
    assert (0, 0, 21) not in kitchen._CACHE and (0, 0, 22) not in kitchen._CACHE
