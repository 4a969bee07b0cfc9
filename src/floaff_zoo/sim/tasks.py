"""The four RoboCasa-v0.2-style tasks: target, reset, success check (docs/background.md §4).

* PnPCounterToCab: target = a wall cabinet (door opened 90-100 %) and an object on the counter below;
  reset: object on the counter; success: all 8 object-box corners inside the cabinet interior box
  (tol 0.05 m) and the grip site > 0.25 m from the object.
* OpenSingleDoor: target = the microwave door; reset: closed; success: door q / (pi/2) >= 0.90.
* CloseDrawer: target = the top drawer of a drawer module; reset: 90-100 % open; success:
  q / (0.55 * drawer depth) <= 0.05.
* CloseDoubleDoor: target = a double-door base cabinet; reset: both doors 90-100 % open; success: both
  q / (pi/2) <= 0.05.

Every reset opening is lowered where the part would overlap other furniture (``_open_clear``); a kitchen where a
part cannot open past ``MIN_RESET_FRACTION`` of its travel is refused by the generator (``Task.blocked_parts``).

Candidate region (paper eq. "supp_candidate"), in the TARGET frame: origin at ``TargetInfo.pos``
projected on the floor, ``x°`` along the front (lateral, = fixture-local +y), ``y°`` = minus the
distance along the outward normal, so the open floor in front of the target has ``y° < 0`` (the
paper's front view is ``y° < -r_f^y``). Cells with ``|x°| <= r_x`` and ``|y°| <= r_y`` are candidates;
the half behind the front is inside furniture and is removed by collision filtering.
"""

from __future__ import annotations

import abc
import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import mujoco
import numpy as np

from floaff_zoo.sim.robot import subtree_bodies

HALF_PI = math.pi / 2


class TaskScene(Protocol):
    """What a task reads and writes of a compiled scene (``floaff_zoo.sim.kitchen.SimScene`` provides it).

    Typed structurally so this module does not import the kitchen builder, which imports the tasks.
    """

    spec: Any
    model: mujoco.MjModel
    data: mujoco.MjData
    fixtures: dict
    robot: Any

    def part_overlaps(self, part: np.ndarray, depth: float) -> bool:
        """A part's geoms (bool [ngeom]) reach deeper than ``depth`` (m) into other furniture, as posed now."""
        ...


@dataclass
class TargetInfo:
    """The task's target fixture.

    pos [3] world: centre of the target's front (drawer front / door plane / cabinet opening) in
    its reset-independent closed geometry; yaw: world yaw of the front's outward normal.
    ``extra`` holds the fixture geometry the tasks/controllers need (all world frame unless noted).
    """

    pos: np.ndarray
    yaw: float
    kind: str
    body_names: list[str]
    geom_ids: np.ndarray
    joint_names: list[str]
    extra: dict = field(default_factory=dict)

    def to_local(self, p: np.ndarray) -> np.ndarray:
        """World points [..., 2 or 3] -> fixture frame (x = outward normal, y lateral)."""
        p = np.asarray(p, dtype=np.float64)
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        dx = p[..., 0] - self.pos[0]
        dy = p[..., 1] - self.pos[1]
        out = np.stack([c * dx + s * dy, -s * dx + c * dy], axis=-1)
        if p.shape[-1] == 3:
            out = np.concatenate([out, (p[..., 2] - self.pos[2])[..., None]], axis=-1)
        return out

    def to_world(self, q: np.ndarray) -> np.ndarray:
        """Fixture-frame points [..., 2 or 3] -> world."""
        q = np.asarray(q, dtype=np.float64)
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        x = self.pos[0] + c * q[..., 0] - s * q[..., 1]
        y = self.pos[1] + s * q[..., 0] + c * q[..., 1]
        out = np.stack([x, y], axis=-1)
        if q.shape[-1] == 3:
            out = np.concatenate([out, (self.pos[2] + q[..., 2])[..., None]], axis=-1)
        return out


def _jq(scene: "TaskScene", joint: str) -> int:
    j = mujoco.mj_name2id(scene.model, mujoco.mjtObj.mjOBJ_JOINT, joint)
    if j < 0:
        raise KeyError(f"joint {joint!r} not in scene {scene.spec.scene_id}")
    return int(scene.model.jnt_qposadr[j])


def _body_geoms(scene: "TaskScene", bodies: list[str]) -> np.ndarray:
    m = scene.model
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in bodies]
    return np.array([g for g in range(m.ngeom) if m.geom_bodyid[g] in ids], dtype=np.int64)


def _points_2d(name: str, p: np.ndarray) -> np.ndarray:
    """``p`` as float64 [...,2]; another last axis is a ValueError naming ``name`` (a 1-D array of 5 values was read
    as one point, [N,3] or [N,4] points lost their other coordinates, one value failed with an IndexError)."""
    p = np.asarray(p, dtype=np.float64)
    if p.ndim == 0 or p.shape[-1] != 2:
        raise ValueError(f"{name}: expects points of shape [..., 2], got shape {p.shape}")
    return p


def target_frame(target: "TargetInfo", xy: np.ndarray) -> np.ndarray:
    """World xy [...,2] -> paper target frame (x° lateral, y° = -outward distance) [...,2]."""
    loc = target.to_local(_points_2d("target_frame", xy))
    return np.stack([loc[..., 1], -loc[..., 0]], axis=-1)


def target_frame_to_world(target: "TargetInfo", xo: np.ndarray) -> np.ndarray:
    """Paper target frame [...,2] -> world xy [...,2]."""
    xo = _points_2d("target_frame_to_world", xo)
    return target.to_world(np.stack([-xo[..., 1], xo[..., 0]], axis=-1))


@dataclass(frozen=True)
class Task(abc.ABC):
    """Base class: one subclass per task. Times are simulated seconds."""

    name: str = ""
    fixture: str = ""
    horizon: float = 5.0
    r_x: float = 1.0
    r_y: float = 1.2
    r_arm: float = 1.25  # reach filter radius (m) between base origin and target centre (floor projection)
    fail_reason: str = "task_failed"

    def candidate_region(self) -> tuple[float, float]:
        return (self.r_x, self.r_y)

    def target_info(self, scene: "TaskScene") -> "TargetInfo":
        """The target of this task: its fixture's front centre, outward yaw, bodies and joints."""
        f = scene.fixtures[self.fixture]
        return TargetInfo(
            pos=f["front"].copy(),
            yaw=float(f["yaw"]),
            kind=self.fixture,
            body_names=list(f["bodies"]),
            geom_ids=_body_geoms(scene, f["bodies"]),
            joint_names=self.joint_names(f),
            extra=self.target_extra(scene, f),
        )

    def joint_names(self, fixture: dict) -> list[str]:
        """The fixture joints this task moves."""
        return [fixture["joint"]]

    def target_extra(self, scene: "TaskScene", fixture: dict) -> dict:
        """Fixture facts the controller needs, carried in ``TargetInfo.extra``."""
        return dict(fixture)

    def opened_parts(self, scene: "TaskScene") -> list[tuple[str, float]]:
        """[(joint, full travel)] of the parts the reset opens, in the order the reset draws their openings."""
        return []

    def blocked_parts(self, scene: "TaskScene") -> dict[str, float]:
        """{joint: fraction} of the opened parts the furniture stops below MIN_RESET_FRACTION of their travel, opened
        as a reset opens them (from closed, in order) to the smallest opening it draws; empty for a kitchen the task
        can be reset in. The scene's state is left as it was."""
        qpos = scene.data.qpos.copy()
        parts = self.opened_parts(scene)
        for joint, _ in parts:  # closed, as after the reset's mj_resetData
            adr = _jq(scene, joint)
            scene.data.qpos[adr] = scene.model.qpos0[adr]
        blocked = {}
        for joint, full in parts:
            fraction = _open_clear(scene, joint, RESET_OPENING_MIN, full)
            if fraction < MIN_RESET_FRACTION:
                blocked[joint] = round(fraction, 4)
        scene.data.qpos[:] = qpos
        mujoco.mj_forward(scene.model, scene.data)
        return blocked

    @abc.abstractmethod
    def reset(self, scene: "TaskScene", rng: np.random.Generator | None) -> None:
        """Task-specific; see the module table."""

    @abc.abstractmethod
    def state(self, scene: "TaskScene") -> dict:
        """Task-specific; see the module table."""

    @abc.abstractmethod
    def success(self, scene: "TaskScene") -> bool:
        """Task-specific; see the module table."""

    @abc.abstractmethod
    def set_success_state(self, scene: "TaskScene") -> None:
        """Task-specific; see the module table."""


#: the smallest reset opening drawn (fraction of the full travel); the largest is 1.0
RESET_OPENING_MIN = 0.90
#: a part the furniture stops below this fraction of its travel leaves a task that is half done at reset (a
#: closing task) or an object that cannot be placed: the generator draws the next seed's kitchen instead
MIN_RESET_FRACTION = 0.5


def _open_fraction(rng: np.random.Generator | None) -> float:
    """Reset opening in [RESET_OPENING_MIN, 1.00]; deterministic 0.95 without an rng."""
    return 0.95 if rng is None else float(rng.uniform(RESET_OPENING_MIN, 1.00))


#: deepest overlap (m) a reset's opened part may have with other furniture; deeper, the part is opened less
RESET_OVERLAP_TOL = 1e-4
#: step (fraction of the full opening) by which an obstructed reset opening is lowered
RESET_OPENING_STEP = 0.01


def _open_clear(scene: "TaskScene", joint: str, fraction: float, full: float) -> float:
    """Open ``joint`` to ``fraction`` of ``full`` (its travel), or less where the part would then overlap other
    furniture (a door beside a corner meets the perpendicular run: reset into it, the contact forces swing the door
    by themselves): lowered in RESET_OPENING_STEP steps until clear. Returns the fraction set."""
    m = scene.model
    adr = _jq(scene, joint)
    part = subtree_bodies(m, int(m.jnt_bodyid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, joint)]))
    part = part[m.geom_bodyid]  # the part's geoms (door and handle); the robot never counts: the reset state must
    # not depend on where the base stands
    while True:
        scene.data.qpos[adr] = fraction * full
        if fraction <= 0.0 or not scene.part_overlaps(part, RESET_OVERLAP_TOL):
            return fraction
        fraction = max(0.0, fraction - RESET_OPENING_STEP)


@dataclass(frozen=True)
class CloseDrawer(Task):
    name: str = "CloseDrawer"
    fixture: str = "drawer"
    horizon: float = 4.5
    r_x: float = 1.0
    r_y: float = 1.2
    r_arm: float = 1.2
    fail_reason: str = "not_closed"
    threshold: float = 0.05

    def opening(self, scene) -> float:
        f = scene.fixtures["drawer"]
        return float(scene.data.qpos[_jq(scene, f["joint"])]) / f["travel"]

    def opened_parts(self, scene):
        f = scene.fixtures["drawer"]
        return [(f["joint"], f["travel"])]

    def reset(self, scene, rng):
        ((joint, full),) = self.opened_parts(scene)
        _open_clear(scene, joint, _open_fraction(rng), full)

    def state(self, scene):
        return {"drawer_open": self.opening(scene)}

    def success(self, scene):
        return self.opening(scene) <= self.threshold

    def set_success_state(self, scene):
        scene.data.qpos[_jq(scene, scene.fixtures["drawer"]["joint"])] = 0.0
        mujoco.mj_forward(scene.model, scene.data)


@dataclass(frozen=True)
class CloseDoubleDoor(Task):
    name: str = "CloseDoubleDoor"
    fixture: str = "double_door"
    horizon: float = 7.5
    r_x: float = 1.0
    r_y: float = 1.2
    r_arm: float = 1.25
    fail_reason: str = "not_closed"
    threshold: float = 0.05

    def joint_names(self, fixture: dict) -> list[str]:
        return [d["joint"] for d in fixture["doors"]]

    def openings(self, scene) -> list[float]:
        return [
            float(scene.data.qpos[_jq(scene, d["joint"])]) / HALF_PI for d in scene.fixtures["double_door"]["doors"]
        ]

    def opened_parts(self, scene):
        return [(d["joint"], HALF_PI) for d in scene.fixtures["double_door"]["doors"]]

    def reset(self, scene, rng):
        parts = self.opened_parts(scene)
        fractions = [_open_fraction(rng) for _ in parts]  # the rng's draws first
        for (joint, full), fraction in zip(parts, fractions):
            _open_clear(scene, joint, fraction, full)

    def state(self, scene):
        a, b = self.openings(scene)
        return {"door_pos_open": a, "door_neg_open": b}

    def success(self, scene):
        return all(o <= self.threshold for o in self.openings(scene))

    def set_success_state(self, scene):
        for d in scene.fixtures["double_door"]["doors"]:
            scene.data.qpos[_jq(scene, d["joint"])] = 0.0
        mujoco.mj_forward(scene.model, scene.data)


@dataclass(frozen=True)
class OpenSingleDoor(Task):
    name: str = "OpenSingleDoor"
    fixture: str = "microwave"
    horizon: float = 6.0
    r_x: float = 1.0
    r_y: float = 1.2
    r_arm: float = 1.25
    fail_reason: str = "not_open"
    threshold: float = 0.90

    def opening(self, scene) -> float:
        return float(scene.data.qpos[_jq(scene, scene.fixtures["microwave"]["joint"])]) / HALF_PI

    def reset(self, scene, rng):
        scene.data.qpos[_jq(scene, scene.fixtures["microwave"]["joint"])] = 0.0

    def state(self, scene):
        return {"door_open": self.opening(scene)}

    def success(self, scene):
        return self.opening(scene) >= self.threshold

    def set_success_state(self, scene):
        scene.data.qpos[_jq(scene, scene.fixtures["microwave"]["joint"])] = HALF_PI
        mujoco.mj_forward(scene.model, scene.data)


@dataclass(frozen=True)
class PnPCounterToCab(Task):
    name: str = "PnPCounterToCab"
    fixture: str = "wall_cab"
    horizon: float = 9.0
    r_x: float = 1.0
    r_y: float = 1.2
    r_arm: float = 1.25
    fail_reason: str = "not_placed"
    tol: float = 0.05
    min_gripper_dist: float = 0.25

    def joint_names(self, fixture: dict) -> list[str]:
        return [fixture["door"]["joint"]]

    def target_extra(self, scene, fixture: dict) -> dict:
        return {**fixture, "object_geom_ids": _body_geoms(scene, [fixture["object"]])}

    def _obj(self, scene) -> tuple[int, int]:
        m = scene.model
        b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, scene.fixtures["wall_cab"]["object"])
        return b, _jq(scene, "pnp_object_joint")

    def opened_parts(self, scene):
        return [(scene.fixtures["wall_cab"]["door"]["joint"], HALF_PI)]

    def reset(self, scene, rng):
        ((joint, full),) = self.opened_parts(scene)
        _open_clear(scene, joint, _open_fraction(rng), full)

    def _corners_local(self, scene) -> np.ndarray:
        """Object-box corners [8,3] in the cabinet frame (x outward, y lateral, z up), relative to the interior
        centre."""
        f = scene.fixtures["wall_cab"]
        b, qa = self._obj(scene)
        pos = scene.data.qpos[qa : qa + 3]
        R = np.zeros(9)
        mujoco.mju_quat2Mat(R, scene.data.qpos[qa + 3 : qa + 7])
        R = R.reshape(3, 3)
        h = f["object_half"]
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
        world = pos + (signs * h) @ R.T
        c, s = math.cos(f["yaw"]), math.sin(f["yaw"])
        d = world - f["interior_center"]
        return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]], axis=1)

    def gripper_distance(self, scene) -> float:
        b, qa = self._obj(scene)
        site = scene.robot.grip_site
        mujoco.mj_kinematics(scene.model, scene.data)
        return float(np.linalg.norm(scene.data.site_xpos[site] - scene.data.qpos[qa : qa + 3]))

    def object_inside(self, scene) -> bool:
        half = scene.fixtures["wall_cab"]["interior_half"]
        return bool(np.all(np.abs(self._corners_local(scene)) <= half + self.tol))

    def state(self, scene):
        f = scene.fixtures["wall_cab"]
        return {
            "object_inside": self.object_inside(scene),
            "gripper_dist": self.gripper_distance(scene),
            "cab_door_open": float(scene.data.qpos[_jq(scene, f["door"]["joint"])]) / HALF_PI,
        }

    def success(self, scene):
        return self.object_inside(scene) and self.gripper_distance(scene) > self.min_gripper_dist

    def set_success_state(self, scene):
        f = scene.fixtures["wall_cab"]
        _, qa = self._obj(scene)
        p = f["interior_center"].copy()
        p[2] = f["bottom_z"] + f["object_half"][2] + 0.001
        scene.data.qpos[qa : qa + 3] = p
        scene.data.qpos[qa + 3 : qa + 7] = (math.cos(f["yaw"] / 2), 0.0, 0.0, math.sin(f["yaw"] / 2))
        mujoco.mj_forward(scene.model, scene.data)


TASK_REGISTRY: dict[str, Task] = {
    "PnPCounterToCab": PnPCounterToCab(),
    "OpenSingleDoor": OpenSingleDoor(),
    "CloseDrawer": CloseDrawer(),
    "CloseDoubleDoor": CloseDoubleDoor(),
}


def get_task(name: str) -> Task:
    if not isinstance(name, str) or name not in TASK_REGISTRY:  # a list failed with "unhashable type"
        raise ValueError(f"unknown task {name!r}; valid tasks: {list(TASK_REGISTRY)}")
    return TASK_REGISTRY[name]


def candidate_region(task: str) -> tuple[float, float]:
    """(r_x, r_y) in metres of the task's candidate region in the target frame (see module doc)."""
    return get_task(task).candidate_region()
