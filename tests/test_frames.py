"""frames.py on hand-computed cases: the heading's argument order, the rounded position it is taken from, and the
half-open yaw interval of both pose conversions."""

import math

import pytest

from floaff_zoo.frames import facing_pose, heading_to, pose_to_base, pose_to_world


def test_heading_to_points_from_the_base_to_the_target():
    # targets off the diagonal: atan2 with its arguments swapped (x, y) gives another angle
    assert heading_to(1.0, 1.0, (1.0, 3.0)) == pytest.approx(math.pi / 2)
    assert heading_to(0.0, 0.0, (-2.0, 0.0)) == pytest.approx(math.pi)
    assert heading_to(0.0, 0.0, (2.0, 1.0)) == pytest.approx(math.atan2(1.0, 2.0))


def test_facing_pose_takes_the_yaw_from_the_rounded_position():
    """The annotation rounds (x, y) to 6 decimals, then faces the target from there: the yaw of the unrounded
    position differs by ~1e-7 rad, enough to flip the rounded yaw the rollout is cached under."""
    x, y, yaw = facing_pose((1.0000004, -0.4999996, 2.0), (3.0, 0.5))
    assert (x, y) == (1.0, -0.5)
    assert yaw == math.atan2(1.0, 2.0)  # exact: the same formula on the same rounded numbers


def test_both_pose_conversions_give_the_yaw_in_minus_pi_to_pi():
    """(-pi, pi]: a yaw of exactly -pi (atan2 of a -0.0 sine) comes back as +pi, from either direction."""
    assert pose_to_world((0.0, 0.0, -math.pi / 2), (0.0, 0.0, -math.pi / 2))[2] == pytest.approx(math.pi)
    assert pose_to_base((0.0, 0.0, -math.pi / 2), (0.0, 0.0, math.pi / 2))[2] == pytest.approx(math.pi)
