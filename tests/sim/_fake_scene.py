"""A throwaway MjSpec scene implementing the SimScene interface used by views.py (no robosuite, builds in ms).

Room 6 x 6 m; a counter (box) against the +x wall whose front face is at x = 1.0; a red handle (the target) on the
counter front at height 0.8 facing -x (target yaw = pi); a 'robot' = planar x/y/yaw joints carrying a box body
(collision geom in group 0, a visual 'arm' box in group 1 right in the camera's view) and the ego camera
'floaff_ego' looking forward, pitched down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import mujoco
import numpy as np

ROOM = 3.0  # half size
COUNTER_X = 1.0  # front face
FOOT_HALF = (0.3, 0.25)  # robot footprint half length/width


@dataclass
class FakeTarget:
    pos: np.ndarray
    yaw: float
    geom_ids: list[int]


class FakeScene:
    def __init__(self) -> None:
        s = mujoco.MjSpec()
        s.visual.global_.offwidth = 128
        s.visual.global_.offheight = 128
        w = s.worldbody
        w.add_light(pos=[0, 0, 3], dir=[0, 0, -1])
        w.add_geom(
            name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[ROOM, ROOM, 0.1], rgba=[0.6, 0.6, 0.6, 1], group=1
        )
        w.add_geom(
            name="counter",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            pos=[COUNTER_X + 0.3, 0, 0.45],
            size=[0.3, 1.5, 0.45],
            rgba=[0.8, 0.8, 0.7, 1],
            group=1,
        )
        w.add_geom(
            name="handle",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            pos=[COUNTER_X - 0.03, 0, 0.6],
            size=[0.03, 0.15, 0.08],
            rgba=[1, 0, 0, 1],
            group=1,
            contype=0,
            conaffinity=0,
        )
        w.add_geom(
            name="wall",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            pos=[ROOM, 0, 1.0],
            size=[0.05, ROOM, 1.0],
            rgba=[0.9, 0.9, 0.9, 1],
            group=1,
        )
        b = w.add_body(name="robot_base")
        b.add_joint(name="bx", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[1, 0, 0])
        b.add_joint(name="by", type=mujoco.mjtJoint.mjJNT_SLIDE, axis=[0, 1, 0])
        b.add_joint(name="byaw", type=mujoco.mjtJoint.mjJNT_HINGE, axis=[0, 0, 1])
        b.add_geom(
            name="robot_col",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            pos=[0, 0, 0.3],
            size=[FOOT_HALF[0], FOOT_HALF[1], 0.28],
            rgba=[0, 1, 0, 1],
            group=0,
        )
        b.add_geom(
            name="robot_vis",
            type=mujoco.mjtGeom.mjGEOM_BOX,
            pos=[0.35, 0, 0.9],
            size=[0.08, 0.08, 0.08],
            rgba=[0.2, 0.2, 0.2, 1],
            group=1,
            contype=0,
            conaffinity=0,
        )
        pitch = math.radians(35.0)
        xaxis = np.array([0.0, -1.0, 0.0])
        yaxis = np.array([math.sin(pitch), 0.0, math.cos(pitch)])
        zaxis = np.cross(xaxis, yaxis)
        q = np.zeros(4)
        mujoco.mju_mat2Quat(q, np.stack([xaxis, yaxis, zaxis], axis=1).reshape(9))
        b.add_camera(name="floaff_ego", pos=[0.0, 0, 1.4], quat=q, fovy=70.0)
        self.model = s.compile()
        self.data = mujoco.MjData(self.model)
        gid = lambda n: mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, n)  # noqa: E731
        self.robot_geom_ids = [gid("robot_col"), gid("robot_vis")]
        self.scene_geom_ids = [gid(n) for n in ("floor", "counter", "handle", "wall")]
        self.floor_id = self.floor_geom_id = gid("floor")
        self.counter_id = gid("counter")
        self.target = FakeTarget(pos=np.array([COUNTER_X, 0.0, 0.6]), yaw=math.pi, geom_ids=[gid("handle")])
        mujoco.mj_forward(self.model, self.data)

    # ---- SimScene interface used by views.py / pictures
    def set_base_pose(self, x: float, y: float, yaw: float) -> None:
        self.data.qpos[:3] = (x, y, yaw)
        mujoco.mj_forward(self.model, self.data)

    def base_pose(self) -> tuple[float, float, float]:
        return tuple(float(v) for v in self.data.qpos[:3])

    def reset_task(self, rng: np.random.Generator) -> None:
        self.data.qpos[:] = 0.0
        mujoco.mj_forward(self.model, self.data)

    def footprint_corners(self, x: float, y: float, yaw: float) -> np.ndarray:
        c, s = math.cos(yaw), math.sin(yaw)
        loc = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]]) * np.array(FOOT_HALF)
        return loc @ np.array([[c, s], [-s, c]]) + np.array([x, y])

    def footprint_free(self, x: float, y: float, yaw: float) -> bool:
        p = self.footprint_corners(x, y, yaw)
        inside_room = np.all(np.abs(p) < ROOM - 0.05)
        clear_counter = np.all(p[:, 0] < COUNTER_X - 0.02)
        return bool(inside_room and clear_counter)

    def robot_collides(self) -> bool:
        mujoco.mj_forward(self.model, self.data)
        rob = set(self.robot_geom_ids)
        for i in range(self.data.ncon):
            c = self.data.contact[i]
            pair = {c.geom1, c.geom2}
            if pair & rob and self.floor_id not in pair and c.dist < -1e-3:
                return True
        return False

    def wall_between(self, x: float, y: float, point_xy) -> bool:
        # the one wall (x in [ROOM - 0.05, ROOM + 0.05]) spans the room's depth: crossed iff an end is at or past it
        return max(float(x), float(point_xy[0])) >= ROOM - 0.05

    def floor_outline(self) -> list[np.ndarray]:
        room = np.array([[-ROOM, -ROOM], [ROOM, -ROOM], [ROOM, ROOM], [-ROOM, ROOM]])
        counter = np.array([[COUNTER_X, -1.5], [COUNTER_X + 0.6, -1.5], [COUNTER_X + 0.6, 1.5], [COUNTER_X, 1.5]])
        return [room, counter]
