"""One scripted rollout from a base pose, and a cached, optionally parallel rollout service.

``rollout`` = refuse a pose the annotation would have filtered (``pose_filter``: out of reach, behind the
target's front plane, outside the room, base footprint or robot overlapping the kitchen; a failure with
the annotation's reason, nothing simulated), reset the task (rng from ``seed``), teleport the base, tuck the arm,
run the policy at
20 Hz (25 x 2 ms physics substeps per tick) until success (early exit, as in the paper: "the
rollout terminates once the task succeeds"), give-up (policy reason) or the task horizon.
Results are deterministic: the same (scene spec, pose, seed) gives the same result in any process.
"""

from __future__ import annotations

import concurrent.futures as cf
import os
import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field

import mujoco
import numpy as np

from floaff_zoo import floor
from floaff_zoo.checks import check_integer, check_number
from floaff_zoo.frames import ROLLOUT_POSE_DECIMALS, heading_to
from floaff_zoo.runtime import THREAD_ENV, exit_with_parent, one_thread_children
from floaff_zoo.sim.controllers import CTRL_DT, Policy, default_policy
from floaff_zoo.sim.kitchen import SceneSpec, SimScene, TargetInfo, build_scene, kitchen_key, lru_put, release_scene
from floaff_zoo.sim.tasks import target_frame


@dataclass
class RolloutResult:
    success: bool
    reason: str  # "success" or a failure reason (ik_unreachable, collision, grasp_failed, not_closed, ...)
    sim_seconds: float
    wall_seconds: float
    state: dict = field(default_factory=dict)


def heading_to_target(scene_or_target: SimScene | TargetInfo, x: float, y: float) -> float:
    """Yaw (rad) of a base at (x, y) facing the target centre's floor projection."""
    t = scene_or_target.target if isinstance(scene_or_target, SimScene) else scene_or_target
    return heading_to(x, y, t.pos)


#: a pose this close to the target's front plane (m, target frame) is on it: poses are rounded to 1e-6 m
FRONT_PLANE_TOL = 1e-4


def pose_filter(scene: SimScene, x: float, y: float, yaw: float, seed: int = 0, r_arm: float | None = None) -> str:
    """The annotation's feasibility filters for one base pose: "" when feasible, else the annotation's reason.

    In the annotation's order: ``filtered_reach`` (base centre at ``r_arm`` or more from the target, default the
    task's), ``filtered_collision`` (on or behind the target's front plane, a wall between base and target, the
    N2M footprint over a furniture footprint, or the tucked robot touching the scene in the task's reset state
    for ``seed``). The robot check, when reached, leaves the scene in that reset state with the base at the pose.
    ``rollout`` passes no ``r_arm``: a dataset generated with a preset's own ``r_arm`` is evaluated with the task's.
    A non-finite pose raises ``ValueError`` (it was reported ``filtered_collision``: every comparison with a NaN fails),
    so do a ``seed`` that is no integer >= 0 and an ``r_arm`` that is no number > 0 (a NaN one filtered nothing).
    """
    x, y, yaw = floor.check_pose((x, y, yaw), "pose_filter")
    check_integer("seed", seed, owner="pose_filter")  # 2.5 reset as seed 2 did, -1 failed in numpy's rng unnamed
    check_number("r_arm", r_arm, strict=True, owner="pose_filter", none_means="the task's")
    task, c = scene.task, scene.target.pos[:2]
    r_arm = task.r_arm if r_arm is None else float(r_arm)
    if float(np.hypot(x - c[0], y - c[1])) >= r_arm:
        return "filtered_reach"
    front = float(target_frame(scene.target, np.array([x, y]))[1]) > -FRONT_PLANE_TOL
    if front or scene.wall_between(x, y, c) or not scene.footprint_free(x, y, yaw):
        return "filtered_collision"
    scene.robot.set_base_pose(scene.data, x, y, yaw)
    scene.reset_task(np.random.default_rng(int(seed)))
    return "filtered_collision" if scene.robot_collides() else ""


def start_rollout(scene: SimScene, base_pose, policy: Policy, seed: int = 0) -> None:
    """Reset the task with rng(seed), teleport the base, tuck the arm, reset the policy (may set policy.reason)."""
    x, y, yaw = floor.check_pose(base_pose, "start_rollout", "base_pose")
    check_integer("seed", seed, owner="start_rollout")
    scene.robot.set_base_pose(scene.data, x, y, yaw)
    scene.reset_task(np.random.default_rng(int(seed)))
    mujoco.mj_forward(scene.model, scene.data)
    policy.reset(scene)


def rollout(
    scene: SimScene | SceneSpec,
    base_pose: tuple[float, float, float],
    policy: Policy | None = None,
    seed: int = 0,
    check_pose: bool = True,
) -> RolloutResult:
    """Run one rollout; see the module doc. ``policy`` defaults to the task's scripted policy.

    ``check_pose=False`` skips ``pose_filter`` (the annotation, which has filtered its candidates already).
    """
    t0 = time.perf_counter()
    check_integer("seed", seed, owner="rollout")
    if not isinstance(scene, (SimScene, SceneSpec)):
        raise TypeError(f"rollout: scene must be a SimScene or a SceneSpec, got {type(scene).__name__}")
    if isinstance(scene, SceneSpec):
        scene = build_scene(scene)
    if policy is None:
        policy = default_policy(scene.spec.task)
    task = scene.task
    if check_pose:
        refused = pose_filter(scene, *floor.check_pose(base_pose, "rollout", "base_pose"), seed=seed)
        if refused:
            return RolloutResult(False, refused, 0.0, time.perf_counter() - t0)  # nothing simulated, no state
    m, d = scene.model, scene.data
    nsub = max(1, int(round(CTRL_DT / m.opt.timestep)))
    start_rollout(scene, base_pose, policy, seed)
    t = 0.0
    reason = ""
    ok = False
    if getattr(policy, "reason", ""):
        reason = policy.reason
    else:
        while t < task.horizon - 1e-9:
            if not policy.act(scene, t):
                reason = policy.reason or "gave_up"
                break
            mujoco.mj_step(m, d, nsub)
            t += nsub * m.opt.timestep
            if _diverged(d):
                reason = "unstable"
                break
            if task.success(scene):
                ok, reason = True, "success"
                break
            if policy.done and t > 0 and _settled(scene):
                break
        if not reason:
            reason = task.fail_reason if policy.done else "timeout"
    return RolloutResult(
        success=ok,
        reason=reason,
        sim_seconds=round(t, 6),
        wall_seconds=time.perf_counter() - t0,
        state=task.state(scene),
    )


#: MuJoCo's warnings of a diverged simulation: on a bad qpos or qvel ``mj_step`` also resets the state to qpos0,
#: where drawers and doors stand closed, so the close tasks' success check would pass on the reset state
_DIVERGED = (mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL)


def hold_still(scene: SimScene, seconds: float) -> None:
    """Simulate ``seconds`` at the rollout's control rate with the base and arm held where they are (a part the reset
    put into furniture moves by itself here: ``scripts/reset_drift.py``)."""
    check_number("seconds", seconds, owner="hold_still")  # a negative one held nothing, a NaN failed in int()
    m, d = scene.model, scene.data
    nsub = max(1, int(round(CTRL_DT / m.opt.timestep)))
    q = scene.robot.ik_q(d)
    scene.robot.hold(d, q[1:], float(q[0]), True)  # actuator targets persist across steps
    for _ in range(int(round(seconds / (nsub * m.opt.timestep)))):
        mujoco.mj_step(m, d, nsub)


def _diverged(d: mujoco.MjData) -> bool:
    """Whether the simulation diverged since the rollout's reset (any of ``_DIVERGED`` raised)."""
    return any(d.warning[w].number > 0 for w in _DIVERGED)


def _settled(scene: SimScene) -> bool:
    """Fixture/object velocities small: nothing can still change the outcome."""
    return float(np.max(np.abs(scene.data.qvel))) < 0.02


# ----------------------------------------------------------------------------------------------
# service
# ----------------------------------------------------------------------------------------------
#: built scenes a process keeps for its next rollouts (least recently used dropped first; jobs come sorted by scene):
#: each holds its compiled kitchen (~70-80 MB) and is rebuilt in ~0.1 s, so a long-lived worker must not keep them all
WORKER_SCENES_SIZE = 8
_WORKER_SCENES: dict[SceneSpec, SimScene] = {}
#: the services that ran rollouts in this process and are not closed: a scene one of them ran stays built (weak: a
#: service dropped without close() stops holding its scenes)
_OPEN_SERVICES: weakref.WeakSet[RolloutService] = weakref.WeakSet()
Job = tuple[dict, tuple[float, float, float], int]  # (spec dict, rounded pose, seed): what a worker receives


class RolloutPoolError(RuntimeError):
    """A rollout could not be run by the worker pool: its worker kept dying, or no rollout finished in time."""


def _worker_init(driver: int) -> None:
    """A rollout worker's set-up; ``driver``: the pid of the process that started it."""
    for k in THREAD_ENV:
        os.environ[k] = "1"
    exit_with_parent(driver)  # else it outlives a killed driver, holding its scenes (~80 MB each) for ever


def _run_job(job: Job) -> RolloutResult:
    spec = SceneSpec.from_dict(job[0])
    scene = _WORKER_SCENES.get(spec)
    if scene is None:
        scene = build_scene(spec)
    lru_put(_WORKER_SCENES, spec, scene, WORKER_SCENES_SIZE)
    return rollout(scene, job[1], None, job[2])


class RolloutJobError(RuntimeError):
    """A rollout raised an exception (a scene that cannot be built, a simulator error); names the episode."""


def _run_one(job_fn: Callable[[Job], RolloutResult], job: Job) -> RolloutResult:
    """``job_fn(job)``; an exception it raises comes back as a RolloutJobError naming the episode (a pool's
    worker would otherwise hand back the bare exception, with no word of which of thousands of jobs raised it)."""
    try:
        return job_fn(job)
    except Exception as exc:
        raise RolloutJobError(f"rollout {_describe(job)} raised {type(exc).__name__}: {exc}") from exc


def _run_chunk(job_fn: Callable[[Job], RolloutResult], jobs: list[Job]) -> list[RolloutResult]:
    return [_run_one(job_fn, j) for j in jobs]


#: the most jobs one pool task runs: ``timeout_s`` measures progress in finished tasks, so a task must stay short
#: whatever the number of jobs (32 rollouts of 0.1-0.4 s each, against the default 900 s)
MAX_CHUNK_JOBS = 32


def _chunks(n: int, workers: int) -> list[list[int]]:
    """Job indices 0..n-1 in consecutive chunks: about four per worker, at most ``MAX_CHUNK_JOBS`` jobs each."""
    size = max(1, min(MAX_CHUNK_JOBS, n // (4 * workers)))
    return [list(range(i, min(i + size, n))) for i in range(0, n, size)]


def _describe(job: Job) -> str:
    """``L0_S1_s2_CloseDrawer at (x, y, yaw)``: how errors name an episode."""
    d = job[0]
    return f"L{d['layout_id']}_S{d['style_id']}_s{d['seed']}_{d['task']} at ({job[1][0]}, {job[1][1]}, {job[1][2]})"


class RolloutService:
    """Evaluate many (spec, pose) jobs: per-process scene cache, result cache, optional workers.

    Results are cached by (spec, pose rounded to ``cache_decimals``); the pose actually simulated
    is the rounded one, so results do not depend on the worker count or on job order.
    backend: "local" (multiprocessing, spawn, OMP_NUM_THREADS=1 in workers) or "ray" (needs ray).

    The local pool survives its workers: when a worker process dies (killed, out of memory, a crash in
    MuJoCo) the unfinished jobs are run again on a fresh pool, ``max_retries`` times, then once more each
    alone; a job whose worker still dies, or a pool in which no job (chunk) finishes for ``timeout_s``
    seconds, raises :class:`RolloutPoolError` naming the episode; a pool never waits forever. With one worker
    (or one job) the jobs run in this process, with no timeout: a rollout ends at its task's horizon. A job that
    raises an exception ends the run with a :class:`RolloutJobError` naming the episode, on every backend.
    job_fn: the function a worker runs per job (module level, importable by spawned workers; tests use a
    fake one).
    """

    def __init__(
        self,
        workers: int = 1,
        backend: str = "local",
        cache_decimals: int = ROLLOUT_POSE_DECIMALS,
        seed: int = 0,
        max_retries: int = 2,
        timeout_s: float = 900.0,
        job_fn: Callable[[Job], RolloutResult] = _run_job,
    ) -> None:
        if backend not in ("local", "ray"):
            raise ValueError(f"backend must be 'local' or 'ray', got {backend!r}")
        if backend == "ray":
            try:
                import ray  # noqa: F401
            except ImportError as e:
                raise ImportError(
                    "RolloutService(backend='ray') needs the 'ray' package, which is not installed; use backend='local'"
                ) from e
        # 2.5 workers ran 2, True one, a text failed in a comparison; a negative cache_decimals cached by 10 m cells
        owner = "RolloutService"
        check_integer("workers", workers, 1, owner=owner)
        check_integer("cache_decimals", cache_decimals, owner=owner)
        check_integer("seed", seed, owner=owner)
        check_integer("max_retries", max_retries, owner=owner)
        check_number("timeout_s", timeout_s, strict=True, owner=owner)  # an infinite one waited for ever
        if not callable(job_fn):
            raise TypeError(f"{owner}: job_fn must be a function of a job, got {job_fn!r}")
        self.workers = int(workers)
        self.backend = backend
        self.cache_decimals = int(cache_decimals)
        self.seed = int(seed)
        self.max_retries = int(max_retries)
        self.timeout_s = float(timeout_s)
        self.job_fn = job_fn
        self.cache: dict[tuple, RolloutResult] = {}
        self._pool: cf.ProcessPoolExecutor | None = None
        self._ray_started = False  # this service called ray.init, so close() shuts it down
        self._built_here: set[SceneSpec] = set()  # scenes of rollouts this service ran in this process

    def _key(self, spec: SceneSpec, pose, seed: int) -> tuple:
        x, y, yaw = floor.check_pose(pose, "RolloutService.run", "the job's pose")
        r = self.cache_decimals
        return (spec, round(x, r), round(y, r), round(yaw, r), seed)

    def run(
        self,
        jobs: list[tuple[SceneSpec, tuple[float, float, float]]],
        progress: bool = False,
        seed: int | None = None,
    ) -> list[RolloutResult]:
        """Roll every (scene, pose) job out (cached); ``seed``: the task's reset seed for these jobs (default the
        service's), so one pool serves episodes of several seeds (``repeat.service_runner``)."""
        check_integer("seed", seed, owner="RolloutService.run", none_means="the service's")
        seed = self.seed if seed is None else int(seed)
        keys = [self._key(s, p, seed) for s, p in jobs]
        todo = sorted({k for k in keys if k not in self.cache}, key=lambda k: (k[0].scene_id, k[1:]))
        payload = [(k[0].to_dict(), (k[1], k[2], k[3]), k[4]) for k in todo]
        t0 = time.perf_counter()
        if self.workers == 1 or len(payload) <= 1:
            self._use_here({k[0] for k in todo})
            results = []
            for i, p in enumerate(payload):
                results.append(_run_one(self.job_fn, p))
                if progress and (i + 1) % 10 == 0:
                    print(
                        f"[RolloutService] {i + 1}/{len(payload)} rollouts, {time.perf_counter() - t0:.1f}s", flush=True
                    )
        elif self.backend == "ray":
            results = self._run_ray(payload)
        else:
            results = self._run_pool(payload)
        for k, r in zip(todo, results):
            self.cache[k] = r
        if progress:
            print(f"[RolloutService] {len(payload)} new rollouts in {time.perf_counter() - t0:.1f}s", flush=True)
        return [self.cache[k] for k in keys]

    def _new_pool(self) -> cf.ProcessPoolExecutor:
        import multiprocessing as mp

        return cf.ProcessPoolExecutor(
            self.workers, mp_context=mp.get_context("spawn"), initializer=_worker_init, initargs=(os.getpid(),)
        )

    def _run_pool(self, payload: list[Job]) -> list[RolloutResult]:
        """All jobs on the process pool, in order; see the class doc for dead workers and the timeout.

        Jobs go out in chunks of consecutive jobs (sorted by scene, so each worker builds few scenes; at most
        ``MAX_CHUNK_JOBS`` each, so ``timeout_s`` never has to cover a chunk that grows with the job count). A dead
        worker breaks the whole pool, so every unfinished job is lost with it, guilty or not: lost jobs go
        round again one per task on a fresh pool, and a job lost more than ``max_retries`` times finally runs
        alone, where a dead worker can only be its own doing.
        """
        results: list[RolloutResult | None] = [None] * len(payload)
        lost = [0] * len(payload)
        queue = _chunks(len(payload), self.workers)
        alone: list[int] = []
        while queue:
            again = self._run_round(payload, queue, results)
            queue = []
            for i in again:
                lost[i] += 1
                (alone.append(i) if lost[i] > self.max_retries else queue.append([i]))
        for i in alone:
            if self._run_round(payload, [[i]], results):
                raise RolloutPoolError(
                    f"rollout {_describe(payload[i])} killed its worker process {lost[i] + 1} times, the last time "
                    "running alone (killed from outside, out of memory, or a crash in MuJoCo)"
                )
        return results  # type: ignore[return-value]

    def _run_round(self, payload: list[Job], chunks: list[list[int]], results: list) -> list[int]:
        """Run ``chunks`` (lists of job indices) on the pool, filling ``results``; returns the indices lost
        with a dead worker (the broken pool is then shut down). Raises RolloutPoolError after ``timeout_s``
        without progress."""
        with one_thread_children():  # the workers start at these submits, not with the pool
            if self._pool is None:
                self._pool = self._new_pool()
            running = {self._pool.submit(_run_chunk, self.job_fn, [payload[i] for i in idx]): idx for idx in chunks}
        lost: list[int] = []
        while running:
            done, _ = cf.wait(running, timeout=self.timeout_s, return_when=cf.FIRST_COMPLETED)
            if not done:
                stuck = [_describe(payload[i]) for idx in running.values() for i in idx][:5]
                self._kill_pool()
                raise RolloutPoolError(
                    f"the rollout pool made no progress for {self.timeout_s:.0f} s (timeout_s): a worker hangs; "
                    f"still running: {stuck}"
                )
            for fut in done:
                idx = running.pop(fut)
                try:
                    for i, r in zip(idx, fut.result()):
                        results[i] = r
                except cf.process.BrokenProcessPool:  # a worker died: the pool takes no more work
                    lost += idx
                except RolloutJobError:  # the other chunks' results would be thrown away: stop them now
                    self._kill_pool()
                    raise
        if lost:
            self._kill_pool()
        return sorted(lost)

    def _kill_pool(self) -> None:
        """Stop the pool now, workers included (a hung worker would keep a normal shutdown waiting)."""
        pool, self._pool = self._pool, None
        if pool is None:
            return
        procs = list((getattr(pool, "_processes", None) or {}).values())  # no public API for this in 3.11
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in procs:
            if proc.is_alive():
                proc.kill()
        for proc in procs:
            proc.join(timeout=5)

    def _run_ray(self, payload):
        """Ray tasks (1 CPU each) on the connected cluster; without one, start a local ``workers``-CPU cluster
        that ``close()`` shuts down. Call ``ray.init(address=...)`` first to use a multi-machine cluster."""
        import ray

        if not ray.is_initialized():
            ray.init(num_cpus=self.workers, include_dashboard=False, log_to_driver=False)
            self._ray_started = True
        # one BLAS/OpenMP thread per worker, as in _worker_init (set before the worker process imports numpy)
        env = {"env_vars": dict.fromkeys(THREAD_ENV, "1")}
        remote = ray.remote(num_cpus=1, runtime_env=env)(_run_one)
        return ray.get([remote.remote(self.job_fn, p) for p in payload])

    def _use_here(self, specs: set[SceneSpec]) -> None:
        """Record that this service runs rollouts of ``specs`` in this process (their scenes are built here)."""
        self._built_here |= specs
        _OPEN_SERVICES.add(self)

    def _release_here(self) -> None:
        """Release the scenes (~80 MB each, for the life of a training process) and compiled kitchens of the rollouts
        this service ran in this process that no other open service uses: another's are left to it, built."""
        mine, self._built_here = self._built_here, set()
        _OPEN_SERVICES.discard(self)
        in_use = {spec for svc in _OPEN_SERVICES for spec in svc._built_here}  # read from the services themselves
        kitchens = {kitchen_key(spec) for spec in in_use}  # a kitchen is shared by the scenes of all its tasks
        for spec in mine - in_use:
            _WORKER_SCENES.pop(spec, None)
        for spec in mine:
            if kitchen_key(spec) not in kitchens:
                release_scene(spec)  # also where the scene LRU dropped the scene already

    def close(self) -> None:
        """Stop the pool (rollouts still queued by an interrupted ``run`` are dropped, not waited for) and release
        the scenes of the rollouts it ran in this process that no other open service ran (``_release_here``)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        self._release_here()
        if self._ray_started:
            import ray

            ray.shutdown()
            self._ray_started = False

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass
