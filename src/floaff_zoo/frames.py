"""Robot-base frame <-> world frame in the plane (numpy only).

A generated view stores its robot's base pose in the world as ``(x, y, yaw)``
(``meta['sim']['base_pose_world']``); points and poses of the sample contract are in that base
frame. The rollout callback (to run the task) and the report figures (to draw over the kitchen) both
need the world pose, so the conversion lives here, below both of them. So do the yaw sources that read the
simulator's target yaw (``PRIVILEGED_YAW``): the models offer them, the tables mark the runs that used one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from floaff_zoo.floor import check_pose

Pose = tuple[float, float, float]

#: decimals (m, rad) to which a base pose is rounded before it is rolled out (and its rollout cached): the
#: annotation's and the evaluation's. Coarser rounding changes outcomes: some CloseDoubleDoor rollouts flip
#: when the pose moves by 3e-5 m / 4e-6 rad (docs/background.md §5, "How exact a pose must be").
ROLLOUT_POSE_DECIMALS = 6

#: yaw sources (``floaff_zoo.models.yaw.YawSource``) that read a simulator field: allowed in training; at test time
#: ``floaff-zoo table`` marks the rows of runs that used one "(simulator yaw)"
PRIVILEGED_YAW = frozenset({"gt"})


def facing_pose(pose: Pose, target_world: Sequence[float]) -> Pose:
    """A world pose facing the target, as the annotation simulates a candidate cell: (x, y) rounded to
    ``ROLLOUT_POSE_DECIMALS``, the yaw toward the target's world (x, y) from that rounded position, in float64.

    A pose chosen from a view's float32 base-frame points rounds to the cell's (x, y), but its yaw can differ from
    the annotated one by 1e-6 rad, enough to flip the sixth decimal and, at a knife edge, the rollout
    (docs/background.md §5).
    """
    x, y, _ = check_pose(pose, "facing_pose")
    x, y = round(x, ROLLOUT_POSE_DECIMALS), round(y, ROLLOUT_POSE_DECIMALS)
    return x, y, heading_to(x, y, target_world)


def heading_to(x: float, y: float, target_world: Sequence[float]) -> float:
    """Yaw (rad, float64) of a base at world (x, y) facing the target's world (x, y): the annotation's and the
    evaluation's one formula."""
    try:
        tx, ty = float(target_world[0]), float(target_world[1])
    except (IndexError, TypeError, ValueError):  # one value was an IndexError, a text a bare ValueError
        msg = f"heading_to: target_world must hold the target's world (x, y), got {target_world!r}"
        raise ValueError(msg) from None
    if not all(math.isfinite(v) for v in (x, y, tx, ty)):  # atan2 of a NaN is a NaN yaw, of an inf a wrong one
        raise ValueError(f"heading_to: the base (x, y) and target_world must be finite, got {(x, y)} and {(tx, ty)}")
    return math.atan2(ty - y, tx - x)


def base_to_world(xyz: np.ndarray, base_pose_world: Sequence[float]) -> np.ndarray:
    """Points in the view's robot base frame -> world. xyz [K, 2+] -> same shape (z untouched)."""
    # a NaN pose made every point NaN, an infinite yaw failed in math.cos naming nothing
    x0, y0, yaw = check_pose(base_pose_world, "base_to_world", "base_pose_world")
    p = np.array(xyz, dtype=np.float64, copy=True)
    c, s = math.cos(yaw), math.sin(yaw)
    px, py = p[..., 0].copy(), p[..., 1].copy()
    p[..., 0] = c * px - s * py + x0
    p[..., 1] = s * px + c * py + y0
    return p


def pose_to_world(pose: Pose, base_pose_world: Sequence[float]) -> Pose:
    """An SE(2) pose (x, y, yaw) in the base frame -> world (yaw wrapped to (-pi, pi])."""
    pose = check_pose(pose, "pose_to_world")  # a NaN yaw came back as a NaN world yaw
    base = check_pose(base_pose_world, "pose_to_world", "base_pose_world")
    xy = base_to_world(np.array([[pose[0], pose[1]]]), base)[0]
    yaw = math.atan2(math.sin(pose[2] + base[2]), math.cos(pose[2] + base[2]))
    if yaw <= -math.pi:  # atan2 gives -pi for a sine of -0.0: the interval is (-pi, pi]
        yaw += 2.0 * math.pi
    return float(xy[0]), float(xy[1]), float(yaw)


def pose_to_base(pose: Pose, base_pose_world: Sequence[float]) -> Pose:
    """A world SE(2) pose (x, y, yaw) -> the base frame: the inverse of :func:`pose_to_world`."""
    x0, y0, b = check_pose(base_pose_world, "pose_to_base", "base_pose_world")
    pose = check_pose(pose, "pose_to_base")
    dx, dy = pose[0] - x0, pose[1] - y0
    c, s = math.cos(b), math.sin(b)
    yaw = math.atan2(math.sin(pose[2] - b), math.cos(pose[2] - b))
    if yaw <= -math.pi:
        yaw += 2.0 * math.pi
    return c * dx + s * dy, -s * dx + c * dy, float(yaw)
