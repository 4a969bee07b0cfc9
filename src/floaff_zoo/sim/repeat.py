"""Fresh episodes of a scene's candidate cells: the task's randomness drawn again and the base parked with noise.

The generated labels roll every feasible cell out once, with the annotation's task seed (the same initial door or
drawer opening) at the exact cell pose. :func:`fresh_probability` rolls each feasible cell out ``episodes`` more
times, each with a fresh task seed and the pose perturbed by N(0, sigma_xy) per axis and N(0, sigma_yaw), and
returns the success fraction: the cell's *fresh success probability*. Cells the generator's collision and reach
filters refused (``candidates.valid`` false) keep 0: ``pose_filter`` refuses them in every episode. Cells its IK
pre-filter refused (``valid`` true, status ``FILTERED``) are rolled out: the arm's key points depend on the task's
draw (how far a door or drawer is open), which a fresh episode makes again, and the rollout fails there
(``ik_unreachable``) whenever the new draw still has no solution. ``probability_label`` still sets those cells to
0 (it zeroes every ``FILTERED`` cell, as the generated labels do), so ``scripts/fresh_labels.py``'s labels keep
them at 0 whatever their fresh probability.
``scripts/fresh_sr.py`` scores chosen poses with it; ``scripts/fresh_labels.py`` turns it into training labels.
Probabilities are cached in ``.npz`` files (:func:`read_probs` / :func:`write_probs`) tagged with their setting.
"""

from __future__ import annotations

import json
import zipfile
import zlib
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from floaff_zoo.atomic import atomic_write
from floaff_zoo.checks import check_integer, check_number
from floaff_zoo.frames import ROLLOUT_POSE_DECIMALS
from floaff_zoo.sim.fileformat import labels_version

__all__ = [
    "FRESH_SEED0",
    "Runner",
    "fresh_probability",
    "perturbed_poses",
    "read_probs",
    "scene_probabilities",
    "service_runner",
    "write_probs",
]

#: first task seed of the fresh episodes (the annotation uses 0)
FRESH_SEED0 = 1000

Runner = Callable[[int, list[tuple[object, tuple[float, float, float]]]], list[bool]]


def perturbed_poses(
    xy: np.ndarray, yaw: np.ndarray, episode: int, sigma_xy: float, sigma_yaw: float, seed: int
) -> np.ndarray:
    """Candidate poses with parking noise for one episode: xy [M, 2], yaw [M] -> [M, 3] (x, y, yaw).

    A NaN or negative sigma, or a seed or episode that is not an integer >= 0, raises ``ValueError``: a NaN sigma made
    every pose NaN, a seed 1.5 (or episode 0.5) drew seed 1's (episode 0's) noise without a word."""
    check_number("sigma_xy", sigma_xy, owner="perturbed_poses")
    check_number("sigma_yaw", sigma_yaw, owner="perturbed_poses")
    check_integer("seed", seed, owner="perturbed_poses")
    check_integer("episode", episode, owner="perturbed_poses")
    xy, yaw = np.asarray(xy, float), np.asarray(yaw, float)
    if xy.ndim != 2 or xy.shape[1] != 2 or yaw.shape != (len(xy),):  # numpy's concatenate error named neither
        raise ValueError(f"perturbed_poses: xy must be [M, 2] and yaw [M], got {xy.shape} and {yaw.shape}")
    rng = np.random.default_rng([int(seed), int(episode)])
    noise = rng.normal(size=(len(xy), 3)) * np.array([sigma_xy, sigma_xy, sigma_yaw])
    return np.concatenate([xy, yaw[:, None]], axis=1) + noise


def fresh_probability(
    scene: dict, run: Runner, episodes: int, sigma_xy: float, sigma_yaw: float, seed: int, seeds: Sequence[int] = ()
) -> np.ndarray:
    """Fresh success probability of every candidate cell of a scene record, [M] in [0, 1].

    ``run(task_seed, jobs)`` rolls ``(spec, pose)`` jobs out with that task seed. Episode k uses task seed
    ``seeds[k]`` (default ``FRESH_SEED0 + k``) and parking noise drawn from (``seed``, the scene id, k).
    Cells the collision and reach filters refused (``candidates.valid`` false) are 0 without a rollout; cells the IK
    pre-filter refused are rolled out (module docstring).
    """
    from floaff_zoo.sim.kitchen import SceneSpec

    cand = scene["candidates"]
    xy, yaw = np.asarray(cand["xy"], float), np.asarray(cand["yaw"], float)
    valid = np.flatnonzero(np.asarray(cand["valid"], bool))
    spec = SceneSpec.from_dict(scene["spec"])
    check_integer("episodes", episodes, owner="fresh_probability")  # 2.5 failed in range(), True was 1 episode
    task_seeds = list(seeds) or [FRESH_SEED0 + k for k in range(episodes)]
    if not task_seeds:  # 0 / 0 made every probability NaN, and the cache kept them
        raise ValueError(f"fresh_probability: episodes must be >= 1 (or seeds given), got {episodes}")
    for task_seed in task_seeds:  # a task seed 1.5 reset the task as seed 1 did, in the runner, without a word
        check_integer("task seed", task_seed, owner="fresh_probability")
    # 1.5 drew seed 1's noise without a word; numpy refused a negative one with a bare 'expected non-negative integer'
    check_integer("parking-noise seed", seed, owner="fresh_probability")
    scene_seed = zlib.crc32(scene["scene_id"].encode()) ^ int(seed)
    wins = np.zeros(len(xy))
    for k, task_seed in enumerate(task_seeds):
        poses = perturbed_poses(xy[valid], yaw[valid], k, sigma_xy, sigma_yaw, scene_seed)
        ok = np.asarray(run(task_seed, [(spec, tuple(float(v) for v in p)) for p in poses]), float).reshape(-1)
        if ok.size != len(poses):  # one outcome broadcast over every cell, or a short list, miscounted the wins
            raise RuntimeError(
                f"fresh_probability: scene {scene['scene_id']}, episode {k}: the runner gave {ok.size} outcomes "
                f"for {len(poses)} rollouts"
            )
        if not np.isin(ok, (0.0, 1.0)).all():  # 2.0 or NaN made a "probability" above 1 or NaN, averaged as one
            raise RuntimeError(
                f"fresh_probability: scene {scene['scene_id']}, episode {k}: the runner gave outcomes that are not "
                f"successes or failures: {ok[~np.isin(ok, (0.0, 1.0))][:5].tolist()}"
            )
        wins[valid] += ok
    return wins / len(task_seeds)


#: the cache entry recording which generator version made each cached scene
_MADE_FROM = "generator_versions"


def read_probs(
    path: Path, setting: dict, scenes: dict[str, dict], versions_out: dict[str, str] | None = None
) -> dict[str, np.ndarray]:
    """Cached fresh probabilities (scene id -> [M]) made with ``setting``; a mismatch, a scene cached from data of
    another generator minor version (a scene id names its kitchen, not its rollouts: 2.1 changed the double-door push;
    a patch release such as 2.3.1 changes no rollout), a probability outside [0, 1] or NaN, or a corrupt file is an
    error. Caches written before the versions were recorded are not checked for them. ``versions_out``: filled with the
    recorded {scene id: generator version} (a rewrite keeps them for the cached scenes a run does not read)."""
    try:
        with np.load(path) as z:
            made = json.loads(str(z["setting"]))
            versions = json.loads(str(z[_MADE_FROM])) if _MADE_FROM in z.files else {}
            probs = {k: z[k] for k in z.files if k not in ("setting", _MADE_FROM)}
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError) as exc:  # a cut-off file is a BadZipFile
        raise ValueError(f"{path} is not a fresh-probability cache ({exc}); delete it") from exc
    if made != setting:
        raise ValueError(f"{path} was made with {made}, not {setting}")
    for sid, p in probs.items():
        if sid in scenes and p.shape != (len(scenes[sid]["candidates"]["xy"]),):
            raise ValueError(f"{path}: scene {sid} has {p.shape} probabilities for its candidates")
        _check_probability_values(path, sid, p)
        now = scenes.get(sid, {}).get("generator_version")
        if sid in versions and now is not None and labels_version(versions[sid]) != labels_version(now):
            raise ValueError(
                f"{path}: scene {sid} was cached from generator {versions[sid]} data, this copy is {now}; delete it"
            )
    if versions_out is not None:
        versions_out.update(versions)
    return probs


def _check_probability_values(path: Path, sid: str, p: np.ndarray) -> None:
    """Refuse a cached scene whose probabilities are not success fractions: [M] finite numbers in [0, 1]. A NaN
    (the 0 / 0 of an episode-less run) or a value outside was read as a probability: ``fresh_sr`` averaged it into
    its SR and ``fresh_labels`` stopped in ``probability_label`` with no word of the cache or the scene."""
    if p.ndim != 1 or p.dtype.kind not in "biuf":
        raise ValueError(f"{path}: scene {sid} has {p.dtype} probabilities of shape {p.shape}, not [M] numbers")
    bad = ~np.isfinite(p) | (p < 0) | (p > 1)
    if bad.any():
        raise ValueError(
            f"{path}: scene {sid} has {int(bad.sum())} probabilities that are not in [0, 1] "
            f"(first at cell {int(np.flatnonzero(bad)[0])}: {p[bad][0]}); delete it"
        )


def write_probs(
    path: Path, setting: dict, probs: dict[str, np.ndarray], versions: dict[str, str] | None = None
) -> None:
    """Cache ``probs`` (scene id -> [M]) made with ``setting`` (and ``versions``: scene id -> the generator version of
    its record) in ``path`` (.npz), atomically: a run killed while writing leaves the previous cache whole (it is
    rewritten after every scene)."""
    tags = {_MADE_FROM: json.dumps(versions)} if versions else {}
    atomic_write(path, lambda f: np.savez(f, setting=json.dumps(setting), **tags, **probs))


def service_runner(workers: int) -> Runner:
    """A Runner on the simulator's rollout service: one service (one worker pool, one result cache keyed by the task
    seed too) for every task seed. A service per seed kept a pool of ``workers`` processes alive per episode, each
    holding every scene it had built. ``run.close()`` stops the pool and frees the scenes it built."""
    from floaff_zoo.sim.rollout import RolloutService

    service = RolloutService(workers=workers, cache_decimals=ROLLOUT_POSE_DECIMALS)

    def run(task_seed: int, jobs: list) -> list[bool]:
        return [r.success for r in service.run(jobs, seed=task_seed)]

    run.close = service.close  # type: ignore[attr-defined]  # the pool and the scenes it built
    return run


def scene_probabilities(
    scenes: dict[str, dict], setting: dict, cache: Path | None = None, workers: int = 1, seeds: Sequence[int] = ()
) -> dict[str, np.ndarray]:
    """Fresh probabilities of scene records (scene id -> [M]) for ``setting``, through the cache ``cache`` (.npz).

    ``setting`` holds ``episodes``, ``sigma_xy``, ``sigma_yaw_deg`` (degrees) and ``seed``; ``seeds`` as in
    :func:`fresh_probability`. Scenes in the cache are not rolled out again; the cache is rewritten after every new
    scene (a killed run resumes). A cache made with another setting raises ``ValueError``. Explicit ``seeds`` are
    part of the setting (probabilities drawn with other task seeds are other numbers): recorded as ``task_seeds``
    unless ``setting`` names them itself under ``task_seed`` (``scripts/fresh_sr.py``'s ``annotation``, whose
    caches stay readable).
    """
    for task_seed in seeds:  # int() cut 1.5 to 1 (True too) in the setting: a cache made with seed 1 was read back
        check_integer("task seed", task_seed, owner="scene_probabilities")
    if seeds and "task_seed" not in setting:
        setting = {**setting, "task_seeds": [int(s) for s in seeds]}
    known: dict[str, str] = {}  # the versions of cached scenes not among ``scenes`` stay
    probs = read_probs(cache, setting, scenes, known) if cache is not None and cache.is_file() else {}
    for sid, scene in scenes.items():
        if sid in probs:
            continue
        # a service per scene: closing it frees the scene it built (~80 MB in this process or in each pool
        # worker), which one service for the whole run kept until the end, every scene of the split at once
        run = service_runner(workers)
        yaw = float(np.radians(setting["sigma_yaw_deg"]))
        n, sxy, seed = setting["episodes"], setting["sigma_xy"], setting["seed"]
        try:
            probs[sid] = fresh_probability(scene, run, n, sxy, yaw, seed, seeds)
        finally:
            getattr(run, "close", lambda: None)()
        print(f"{sid}: {int((probs[sid] > 0).sum())} cells with a fresh success", flush=True)
        if cache is not None:
            made = {k: scenes.get(k, {}).get("generator_version") or known.get(k) for k in probs}
            made = {k: v for k, v in made.items() if v}
            write_probs(cache, setting, probs, made)
    return probs
