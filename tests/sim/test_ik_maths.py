import numpy as np

from floaff_zoo.sim.robot import _as_slice, _inv3_spd


def test_inv3_spd_matches_linalg():
    rng = np.random.default_rng(0)
    for _ in range(50):
        J = rng.normal(size=(3, 8)) * rng.uniform(0.01, 1.0)
        A = J @ J.T
        for lam2 in (0.04**2, 1.0):
            ref = np.linalg.inv(A + lam2 * np.eye(3))
            got = np.array(_inv3_spd(A, lam2))
            np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-12)
    # rank-deficient A: the damping alone keeps it invertible
    np.testing.assert_allclose(np.array(_inv3_spd(np.zeros((3, 3)), 0.25)), 4.0 * np.eye(3))


def test_as_slice():
    assert _as_slice(np.array([3, 4, 5])) == slice(3, 6)
    x = np.arange(10.0)
    assert np.array_equal(x[_as_slice(np.array([3, 4, 5]))], x[[3, 4, 5]])
    idx = np.array([1, 3, 4])
    assert isinstance(_as_slice(idx), np.ndarray) and np.array_equal(x[_as_slice(idx)], x[idx])
