"""The fresh-probability cache of sim.repeat: written atomically, and a damaged file is a clear error."""

from __future__ import annotations

import numpy as np
import pytest

from floaff_zoo.sim import repeat

SETTING = {"episodes": 2, "sigma_xy": 0.03, "sigma_yaw_deg": 3.0, "seed": 0}
SCENES = {"a": {"candidates": {"xy": [[0, 0], [1, 0], [2, 0]]}}}


def test_round_trip_and_a_cut_off_file_names_itself(tmp_path):
    path = tmp_path / "probs.npz"
    repeat.write_probs(path, SETTING, {"a": np.array([0.0, 0.5, 1.0])})
    assert repeat.read_probs(path, SETTING, SCENES)["a"].tolist() == [0.0, 0.5, 1.0]
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(ValueError, match="probs.npz is not a fresh-probability cache"):
        repeat.read_probs(path, SETTING, SCENES)


def test_a_write_killed_midway_keeps_the_previous_cache(tmp_path, monkeypatch):
    path = tmp_path / "probs.npz"
    repeat.write_probs(path, SETTING, {"a": np.array([0.0, 0.5, 1.0])})
    before = path.read_bytes()

    def dies(file, **arrays):
        file.write(b"PK\x03\x04 half a zip")
        raise KeyboardInterrupt("killed")

    monkeypatch.setattr(repeat.np, "savez", dies)
    with pytest.raises(KeyboardInterrupt):
        repeat.write_probs(path, SETTING, {"a": np.array([1.0, 1.0, 1.0])})
    assert path.read_bytes() == before and [p.name for p in tmp_path.iterdir()] == ["probs.npz"]


def test_a_scene_cached_from_another_generator_version_is_refused(tmp_path):
    """The cache matched scenes by id and size only: probabilities rolled out on generator-2.0 data (the old
    double-door push) were reused on a 2.1 copy of the same kitchens without a word."""
    path = tmp_path / "probs.npz"
    repeat.write_probs(path, SETTING, {"a": np.array([0.0, 0.5, 1.0])}, {"a": "2.0.0"})
    same = {"a": {**SCENES["a"], "generator_version": "2.0.0"}}
    assert repeat.read_probs(path, SETTING, same)["a"].tolist() == [0.0, 0.5, 1.0]
    newer = {"a": {**SCENES["a"], "generator_version": "2.1.0"}}
    with pytest.raises(ValueError, match="scene a was cached from generator 2.0.0 data, this copy is 2.1.0"):
        repeat.read_probs(path, SETTING, newer)
    patch = {"a": {**SCENES["a"], "generator_version": "2.0.1"}}  # a patch release changes no rollout
    assert repeat.read_probs(path, SETTING, patch)["a"].tolist() == [0.0, 0.5, 1.0]
    repeat.write_probs(path, SETTING, {"a": np.array([0.0, 0.5, 1.0])})  # an older cache: nothing to compare
    assert repeat.read_probs(path, SETTING, newer)["a"].tolist() == [0.0, 0.5, 1.0]


def _scene(sid: str, version: str) -> dict:
    return {
        "scene_id": sid,
        "generator_version": version,
        "spec": {"layout_id": 0, "style_id": 0, "seed": 0, "task": "CloseDrawer"},
        "candidates": {"xy": [[0, 0], [1, 0]], "yaw": [0.0, 0.0], "valid": [True, False]},
    }


def test_a_cache_shared_by_two_runs_keeps_every_scenes_version(tmp_path, monkeypatch):
    """A run over other scenes rewrote the cache with only its own scenes' versions: the earlier scenes lost theirs,
    and with them the refusal of a cache made from another generator's data."""
    path = tmp_path / "probs.npz"
    setting = {"episodes": 1, "sigma_xy": 0.0, "sigma_yaw_deg": 0.0, "seed": 0}
    monkeypatch.setattr(repeat, "service_runner", lambda workers: lambda seed, jobs: [True] * len(jobs))
    repeat.scene_probabilities({"a": _scene("a", "2.0.0")}, setting, path)
    repeat.scene_probabilities({"b": _scene("b", "2.0.0")}, setting, path)  # the same file, another split
    versions: dict = {}
    repeat.read_probs(path, setting, {}, versions)
    assert versions == {"a": "2.0.0", "b": "2.0.0"}
    with pytest.raises(ValueError, match="scene a was cached from generator 2.0.0 data, this copy is 2.1.0"):
        repeat.scene_probabilities({"a": _scene("a", "2.1.0")}, setting, path)


def test_no_episode_and_a_negative_noise_seed_are_named():
    """episodes 0 gave NaN probabilities (0 / 0), which the cache kept; a negative seed failed inside numpy."""
    run = lambda seed, jobs: [True] * len(jobs)  # noqa: E731
    with pytest.raises(ValueError, match="episodes must be >= 1"):
        repeat.fresh_probability(_scene("a", "2.0.0"), run, 0, 0.0, 0.0, 0)
    with pytest.raises(ValueError, match="parking-noise seed must be an integer >= 0, got -1"):
        repeat.fresh_probability(_scene("a", "2.0.0"), run, 1, 0.0, 0.0, -1)
    assert repeat.fresh_probability(_scene("a", "2.0.0"), run, 1, 0.0, 0.0, 0).tolist() == [1.0, 0.0]


def test_each_scene_closes_its_service_when_done_or_failed(monkeypatch):
    """One service for the whole run kept every scene it built (~80 MB each, in this process or in each pool worker)
    until the run ended; now each scene's service is closed after it, also when its rollouts fail."""
    setting = {"episodes": 1, "sigma_xy": 0.0, "sigma_yaw_deg": 0.0, "seed": 0}
    events: list[str] = []

    def runner(workers):
        n = sum(e.startswith("open") for e in events)
        events.append(f"open{n}")

        def run(seed, jobs):
            if n == 2:
                raise RuntimeError("worker died")
            return [True] * len(jobs)

        run.close = lambda: events.append(f"close{n}")
        return run

    monkeypatch.setattr(repeat, "service_runner", runner)
    scenes = {k: _scene(k, "2.0.0") for k in "abc"}
    with pytest.raises(RuntimeError, match="worker died"):
        repeat.scene_probabilities(scenes, setting)
    assert events == ["open0", "close0", "open1", "close1", "open2", "close2"]


@pytest.mark.parametrize("value", [np.nan, 1.5, -0.25])
def test_a_cached_probability_outside_0_1_names_the_file_and_scene(tmp_path, value):
    """read_probs checked a cached scene's shape only: a NaN or 1.5 was handed on as a probability (fresh_sr averaged
    it into its SR; fresh_labels stopped in probability_label naming neither the cache nor the scene)."""
    path = tmp_path / "probs.npz"
    repeat.write_probs(path, SETTING, {"a": np.array([0.0, value, 1.0]), "other": np.array([0.5])})
    with pytest.raises(ValueError, match=r"probs\.npz: scene a has 1 probabilities that are not in \[0, 1\]"):
        repeat.read_probs(path, SETTING, SCENES)
    repeat.write_probs(path, SETTING, {"a": np.array([0.0, 0.5, 1.0]), "other": np.array([value])})
    with pytest.raises(ValueError, match="scene other has 1 probabilities"):  # a scene this run does not read too
        repeat.read_probs(path, SETTING, SCENES)


def test_a_runner_giving_another_number_of_outcomes_is_an_error():
    """One outcome for every rollout of an episode: a single one was broadcast over every valid cell."""
    scene = _scene("a", "2.0.0")
    scene["candidates"] = {"xy": [[0, 0], [1, 0], [2, 0]], "yaw": [0.0] * 3, "valid": [True, True, False]}
    with pytest.raises(RuntimeError, match="scene a, episode 0: the runner gave 1 outcomes for 2 rollouts"):
        repeat.fresh_probability(scene, lambda seed, jobs: [True], 1, 0.0, 0.0, 0)


def test_explicit_task_seeds_are_part_of_the_cached_setting(tmp_path, monkeypatch):
    """The cache recorded the setting but not the explicit task seeds: a run with other seeds got the first run's
    probabilities back."""
    drawn: list[list[int]] = []

    def fake_probability(scene, run, n, sxy, yaw, seed, seeds):
        drawn.append(list(seeds))
        return np.full(3, 0.5 if seeds[0] == 1 else 1.0)

    monkeypatch.setattr(repeat, "fresh_probability", fake_probability)
    monkeypatch.setattr(repeat, "service_runner", lambda workers: lambda task_seed, jobs: [])
    monkeypatch.setattr("builtins.print", lambda *a, **k: None)
    path = tmp_path / "probs.npz"
    assert repeat.scene_probabilities(SCENES, SETTING, path, seeds=[1, 1])["a"].tolist() == [0.5] * 3
    assert repeat.scene_probabilities(SCENES, SETTING, path, seeds=[1, 1])["a"].tolist() == [0.5] * 3
    assert drawn == [[1, 1]]  # the second run read the cache
    with pytest.raises(ValueError, match=r"'task_seeds': \[1, 1\]"):
        repeat.scene_probabilities(SCENES, SETTING, path, seeds=[2, 2])
    with pytest.raises(ValueError, match="was made with"):
        repeat.scene_probabilities(SCENES, SETTING, path)  # the default seeds are other seeds too
    # a setting that names its seeds itself (fresh_sr --annotation-seed) is recorded as it is: its caches stay readable
    named = {**SETTING, "task_seed": "annotation"}
    repeat.write_probs(tmp_path / "named.npz", named, {"a": np.array([0.0, 0.25, 1.0])})
    got = repeat.scene_probabilities(SCENES, named, tmp_path / "named.npz", seeds=[3, 3])
    assert got["a"].tolist() == [0.0, 0.25, 1.0] and drawn == [[1, 1]]


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(sigma_xy=float("nan")), "sigma_xy must be a finite number >= 0"),  # every pose NaN
        (dict(sigma_yaw=-0.1), "sigma_yaw must be a finite number >= 0"),
        (dict(seed=1.5), "seed must be an integer >= 0"),  # seed 1's noise without a word
        (dict(episode=0.5), "episode must be an integer >= 0"),  # episode 0's noise
        (dict(yaw=np.zeros(2)), r"xy must be \[M, 2\] and yaw \[M\]"),  # numpy's concatenate error
    ],
)
def test_perturbed_poses_refuses_a_bad_noise_setting(kwargs, match):
    args = dict(xy=np.zeros((3, 2)), yaw=np.zeros(3), episode=0, sigma_xy=0.03, sigma_yaw=0.05, seed=7)
    with pytest.raises(ValueError, match=f"perturbed_poses: {match}"):
        repeat.perturbed_poses(**{**args, **kwargs})


def test_fresh_probability_refuses_a_bad_count_seed_or_outcome():
    """episodes 2.5 failed in range() and True counted as one episode; a noise seed 1.5 drew seed 1's noise and a task
    seed 1.5 went to the runner; a runner's outcome 2.0 or NaN became a probability above 1 or NaN."""
    run = lambda seed, jobs: [True] * len(jobs)  # noqa: E731
    scene = _scene("a", "2.0.0")
    for episodes in (2.5, True):
        with pytest.raises(ValueError, match="fresh_probability: episodes must be an integer >= 0"):
            repeat.fresh_probability(scene, run, episodes, 0.0, 0.0, 0)
    with pytest.raises(ValueError, match="parking-noise seed must be an integer >= 0, got 1.5"):
        repeat.fresh_probability(scene, run, 1, 0.0, 0.0, 1.5)
    with pytest.raises(ValueError, match="task seed must be an integer >= 0, got 1.5"):
        repeat.fresh_probability(scene, run, 1, 0.0, 0.0, 0, seeds=[3, 1.5])
    for outcome in (2.0, float("nan")):
        with pytest.raises(RuntimeError, match="scene a, episode 0: the runner gave outcomes that are not successes"):
            repeat.fresh_probability(scene, lambda seed, jobs, o=outcome: [o] * len(jobs), 1, 0.0, 0.0, 0)
    assert repeat.fresh_probability(scene, lambda s, jobs: [np.True_] * len(jobs), 1, 0.0, 0.0, 0).tolist() == [1, 0]


@pytest.mark.parametrize("bad", [1.5, True])
def test_scene_probabilities_refuses_a_task_seed_that_is_no_integer(tmp_path, bad):
    """int() cut a task seed 1.5 (or True) to 1 in the recorded setting: a cache made with seed 1 was read back as
    the probabilities of the seeds asked for, with no rollout and no word."""
    path = tmp_path / "probs.npz"
    repeat.write_probs(path, {**SETTING, "task_seeds": [1, 1]}, {"a": np.array([0.0, 0.5, 1.0])})
    assert repeat.scene_probabilities(SCENES, SETTING, path, seeds=[1, 1])["a"].tolist() == [0.0, 0.5, 1.0]
    with pytest.raises(ValueError, match="scene_probabilities: task seed must be an integer >= 0"):
        repeat.scene_probabilities(SCENES, SETTING, path, seeds=[bad, 1])
