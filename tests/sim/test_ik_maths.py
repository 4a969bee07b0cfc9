import numpy as np
import pytest

from floaff_zoo.sim.robot import DLSIK, _as_slice, _inv3_spd


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


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(target=np.array([np.nan, 0.0, 1.0])), "target must be 3 finite numbers"),  # NaN q and error
        (dict(target=np.zeros(2)), "target must be 3 finite numbers"),  # bare IndexError
        (dict(q0=np.full(8, np.nan)), "q0 must be 8 finite numbers"),
        (dict(q0=np.zeros(7)), "q0 must be 8 finite numbers"),  # numpy's broadcast error
        (dict(approach=np.array([np.nan, 0.0, -1.0])), "approach must be 3 finite numbers"),
        (dict(approach=np.array([0.0, 0.0, -1.0]), w_rot=float("nan")), "w_rot must be a finite number >= 0"),
        (dict(iters=1.5), "iters must be an integer >= 0"),  # failed in range()
        (dict(tol=float("nan")), "tol must be a finite number > 0"),  # ran every iteration, never converged
        (dict(max_step=-0.1), "max_step must be a finite number > 0"),  # stepped away from the target
    ],
)
def test_ik_solve_refuses_a_bad_argument_naming_it(scene_factory, kwargs, match):
    """A NaN target, start or approach gave a NaN q and a NaN error, which the controllers' `err > tol` test let
    through into the arm's commands."""
    scene = scene_factory("CloseDrawer")
    ik = DLSIK(scene.model, scene.robot)
    args = dict(target=np.array([0.0, -0.5, 1.0]), q0=scene.robot.ik_q(scene.data))
    assert np.isfinite(ik.solve(**args, iters=2)[1])
    with pytest.raises(ValueError, match=f"DLSIK.solve: {match}"):
        ik.solve(**{**args, **kwargs})


def test_robot_index_refuses_a_non_finite_base_pose(scene_factory):
    """It was written into qpos: the robot was posed at NaN."""
    scene = scene_factory("CloseDrawer")
    with pytest.raises(ValueError, match="RobotIndex.set_base_pose: pose must be 3 finite values"):
        scene.robot.set_base_pose(scene.data, float("nan"), 0.0, 0.0)
