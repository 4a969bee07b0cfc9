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
    repeat.write_probs(path, SETTING, {"a": np.array([0.0, 0.5, 1.0])})  # an older cache: nothing to compare
    assert repeat.read_probs(path, SETTING, newer)["a"].tolist() == [0.0, 0.5, 1.0]
