"""scripts/target_inputs.py: the floor queries' lattice angle and the target point's estimates."""

import math

import numpy as np
import pytest

from tests._scripts import load_script

ti = load_script("target_inputs")


@pytest.mark.parametrize("deg", [0.0, 17.0, 63.0, 100.0, -30.0])
def test_lattice_angle_is_the_grid_orientation_modulo_90(deg):
    a = math.radians(deg)
    g = np.stack(np.meshgrid(np.arange(5) * 0.1, np.arange(4) * 0.1), -1).reshape(-1, 2)
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    got = ti.lattice_angle(g @ rot.T + np.array([1.3, -0.4]))
    assert ti.angle_error_deg(got, a) == pytest.approx(0.0, abs=1e-6)
    assert ti.lattice_angle(g[:2]) is None


def test_target_estimates_centroid_and_nearest_band():
    xyz = np.array([[1.0, 0.0, 0.5], [1.02, 0.0, 0.7], [1.5, 0.0, 0.5], [3.0, 0.0, 0.0]])
    flag = np.array([1.0, 1.0, 1.0, 0.0])
    est = ti.target_estimates(xyz, flag)
    np.testing.assert_allclose(est["centroid"], xyz[:3].mean(axis=0))
    np.testing.assert_allclose(est["nearest_0.03"], xyz[:2].mean(axis=0))  # within 3 cm of the nearest point
    assert ti.target_estimates(xyz, np.zeros(4)) is None
    assert ti.angle_error_deg(math.radians(89.0), 0.0) == pytest.approx(1.0)


def test_a_root_without_views_is_named(tmp_path):
    with pytest.raises(SystemExit, match="no layouts test view under"):
        ti.main(["--root", str(tmp_path), "--benchmark", "layouts"])


def test_views_with_nothing_to_measure_are_not_called_missing(tmp_path, monkeypatch):
    """A root whose views have too few floor points and no flagged target point was said to hold no view."""
    from tests.data.floaff_fixture import make_floaff_dataset

    make_floaff_dataset(tmp_path, problems=False, version=2)
    monkeypatch.setattr(ti, "lattice_angle", lambda xy: None)
    monkeypatch.setattr(ti, "target_estimates", lambda xyz, flag: None)
    with pytest.raises(SystemExit, match=r"none of the \d+ layouts test view\(s\) read under .* has 3 or more floor"):
        ti.main(["--root", str(tmp_path), "--benchmark", "layouts"])
