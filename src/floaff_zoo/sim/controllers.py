"""Deterministic scripted policies: DLS IK (torso + 7 arm DOF) + MuJoCo joint position control.

Each task policy plans Cartesian key points from the target fixture's geometry, checks them with
IK before moving (early exit ``ik_unreachable``: the pose is labelled a failure without simulating,
docs/background.md §5) and then executes segments at a 20 Hz control rate:

* ``_Joint``: smoothstep interpolation in joint space (approach from the tuck pose);
* ``_Cart``: a Cartesian path p(s), s in [0,1], IK re-solved every control tick warm-started;
* ``_Grip``: open/close the gripper, optionally switching the grasp assist.

Failure reasons: ``ik_unreachable`` (key point or path not reachable), ``collision`` (the hand is
blocked > 8 cm away from its last 0.2 s of commands for 0.6 s, or the base is shoved > 5 cm / 0.1 rad),
``grasp_failed`` (closed fingers not around the handle/object), plus the task's own
``not_closed`` / ``not_open`` / ``not_placed`` when the script ends without success.

Grasp assist (documented simplification): finger-friction grasps are slow to tune robustly, so
when the gripper closes with the grip site within a tolerance of the object centre
(PnPCounterToCab, 3 cm laterally / 4 cm vertically) or of the microwave handle (OpenSingleDoor,
4 cm), an equality constraint is activated: a weld hand<->object, or a connect (ball-joint, the
door can rotate about the hand) hand<->door. It is released when the gripper opens. Reach,
collisions and approach direction still decide the label.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Protocol, runtime_checkable

import mujoco
import numpy as np

from floaff_zoo.checks import check_integer
from floaff_zoo.sim import robot as _robot

CTRL_DT = 0.05  # s, 20 Hz control / IK rate
KEY_TOL = 0.02  # m, IK error allowed at planned key points
TRACK_TOL = 0.035  # m, IK error allowed while following a path
BLOCK_DIST = 0.08  # m, hand-to-command distance counted as "blocked"
BLOCK_TIME = 0.6  # s
BLOCK_LAG = 4  # control ticks of command history compared with the hand (impedance lag)
DOWN = np.array([0.0, 0.0, -1.0])


@runtime_checkable
class Policy(Protocol):
    """A controller. ``act`` returns False to give up; the reason is in ``reason``; ``done`` ends the script."""

    reason: str
    done: bool

    def reset(self, scene) -> None: ...

    def act(self, scene, t: float) -> bool: ...


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    return v / max(1e-12, math.sqrt(float(v @ v)))


def _smooth(s: float) -> float:
    s = min(1.0, max(0.0, s))
    return s * s * (3.0 - 2.0 * s)


@dataclass
class _Joint:
    duration: float
    q_to: np.ndarray
    opened: bool = True
    q_from: np.ndarray | None = None


@dataclass
class _Cart:
    duration: float
    path: Callable[[float], np.ndarray]  # s in [0,1] -> world point [3]
    approach: Callable[[float], np.ndarray] | np.ndarray | None = None
    opened: bool = True
    w_rot: float = 0.3


@dataclass
class _Grip:
    duration: float
    opened: bool
    on_end: Callable[[object], bool] | None = None  # returns False to fail (reason set by callback)


def _ik_for(scene) -> _robot.DLSIK:
    ik = getattr(scene, "_ik", None)
    if ik is None or ik.m is not scene.model:
        ik = _robot.DLSIK(scene.model, scene.robot)
        scene._ik = ik
    return ik


def _door_point(hinge: np.ndarray, yaw: float, e: int, q: float, p_local: np.ndarray) -> np.ndarray:
    """Point p_local [3] in a door's frame (x outward when closed) -> world, door at angle q about axis e*z."""
    a = yaw + e * q
    c, s = math.cos(a), math.sin(a)
    return np.array(
        [hinge[0] + c * p_local[0] - s * p_local[1], hinge[1] + s * p_local[0] + c * p_local[1], hinge[2] + p_local[2]]
    )


def _door_normal(yaw: float, e: int, q: float) -> np.ndarray:
    a = yaw + e * q
    return np.array([math.cos(a), math.sin(a), 0.0])


class ScriptedPolicy:
    """Base class: subclasses implement ``plan(scene) -> (key points, segments builder)``."""

    task: str = ""

    def __init__(self, precheck: bool = True, ik_iters: int = 8) -> None:
        # ik_iters -1 ran no IK iteration at a tick (every path step a 1e9 m error), 1.5 failed mid-rollout in range()
        check_integer("ik_iters", ik_iters, 1, owner=type(self).__name__)
        if not isinstance(precheck, (bool, np.bool_)):  # "no" or "False" read as true: the IK exits stayed on
            raise ValueError(f"{type(self).__name__}: precheck must be a bool, got {precheck!r}")
        self.precheck = precheck
        self.ik_iters = ik_iters
        self.reason = ""
        self.done = False

    # -- subclass API ------------------------------------------------------------------------
    def keypoints(self, scene) -> list[tuple[np.ndarray, np.ndarray | None]]:
        """Key (point [3], approach [3] | None) that must be reachable; the first is the approach target."""
        raise TypeError(f"{type(self).__name__} must implement keypoints()")

    def segments(self, scene, q_first: np.ndarray) -> list:
        raise TypeError(f"{type(self).__name__} must implement segments()")

    # -- common machinery --------------------------------------------------------------------
    def _seeds(self, scene, point: np.ndarray) -> list[np.ndarray]:
        x, y, yaw = scene.base_pose()
        rel = math.atan2(point[1] - y, point[0] - x) - yaw
        rel = (rel + math.pi) % (2 * math.pi) - math.pi
        q1 = float(np.clip(rel, -2.8, 2.8))
        torso = float(np.clip(point[2] - 0.75, 0.0, 0.34))
        ready = np.array([torso, q1, 0.2, 0.0, -1.9, 0.0, 2.1, math.pi / 4])
        low = np.array([torso, q1, 0.6, 0.0, -1.6, 0.0, 2.4, math.pi / 4])
        return [ready, low]

    def reset(self, scene) -> None:
        self.reason = ""
        self.done = False
        self.ik = _ik_for(scene)
        self.ik.sync(scene.data)
        self._q_cmd = scene.robot.ik_q(scene.data)
        self._opened = True
        self._seg_i = 0
        self._seg_t0 = 0.0
        self._blocked = 0.0
        self._recent: list[tuple[float, float, float]] = []  # last BLOCK_LAG commanded points
        self._base0 = np.array(scene.base_pose())
        self._assist = None
        kps = self.keypoints(scene)
        sols = []
        q_prev = None
        for p, a in kps:
            seeds = ([q_prev] if q_prev is not None else []) + self._seeds(scene, p)
            best = (None, 1e9)
            for sd in seeds:
                q, err = self.ik.solve(p, sd, a, iters=60, tol=0.004)
                if err < best[1]:
                    best = (q, err)
                if err < 0.006:
                    break
            if best[1] > KEY_TOL and self.precheck:
                self.reason = "ik_unreachable"
                return
            sols.append(best[0])
            q_prev = best[0]
        self.key_q = sols  # IK solutions [8] of the key points (segments may move to them in joint space)
        self._segs = self.segments(scene, sols[0])
        self.feasible = True

    def _write(self, scene, q: np.ndarray, opened: bool) -> None:
        scene.robot.hold(scene.data, q[1:], float(q[0]), opened)
        self._q_cmd = q
        self._opened = opened

    def act(self, scene, t: float) -> bool:
        if self.reason:
            return False
        if self.done:
            self._write(scene, self._q_cmd, self._opened)
            return True
        d = scene.data
        # base shoved by contact -> collision
        bx, by, byaw = scene.base_pose()
        if math.hypot(bx - self._base0[0], by - self._base0[1]) > 0.05 or abs(byaw - self._base0[2]) > 0.1:
            self.reason = "collision"
            return False
        seg = self._segs[self._seg_i]
        s = (t - self._seg_t0) / seg.duration if seg.duration > 0 else 1.0
        if isinstance(seg, _Joint):
            if seg.q_from is None:
                seg.q_from = self._q_cmd.copy()
            q = seg.q_from + _smooth(s) * (seg.q_to - seg.q_from)
            self._write(scene, q, seg.opened)
        elif isinstance(seg, _Cart):
            sc = min(1.0, max(0.0, s))
            p = seg.path(sc)
            a = seg.approach(sc) if callable(seg.approach) else seg.approach
            self.ik.sync(d)
            q, err = self.ik.solve(p, self._q_cmd, a, w_rot=seg.w_rot, iters=self.ik_iters, tol=0.003)
            if err > TRACK_TOL:
                q2, err2 = self.ik.solve(p, q, a, w_rot=seg.w_rot, iters=40, tol=0.003)
                if err2 < err:
                    q, err = q2, err2
            if err > TRACK_TOL and self.precheck:
                self.reason = "ik_unreachable"
                return False
            self._write(scene, q, seg.opened)
            hx, hy, hz = d.site_xpos[scene.robot.grip_site].tolist()
            # the joint impedance lags a moving command by ~0.1 s: compare with the recent commands too
            self._recent = self._recent[-(BLOCK_LAG - 1) :] + [(float(p[0]), float(p[1]), float(p[2]))]
            if min(math.sqrt((hx - x) ** 2 + (hy - y) ** 2 + (hz - z) ** 2) for x, y, z in self._recent) > BLOCK_DIST:
                self._blocked += CTRL_DT
                if self._blocked > BLOCK_TIME:
                    self.reason = "collision"
                    return False
            else:
                self._blocked = 0.0
        else:  # _Grip
            self._write(scene, self._q_cmd, seg.opened)
        if s >= 1.0 - 1e-9:
            if isinstance(seg, _Grip) and seg.on_end is not None and not seg.on_end(scene):
                return False
            self._seg_i += 1
            self._seg_t0 = t
            if self._seg_i >= len(self._segs):
                self.done = True
        return True

    # -- grasp assist ---------------------------------------------------------------------------
    def _activate(self, scene, eq_name: str, body2: str) -> None:
        m, d = scene.model, scene.data
        eq = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_EQUALITY, eq_name)
        b1 = scene.robot.hand_body
        b2 = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, body2)
        mujoco.mj_kinematics(m, d)
        R1 = d.xmat[b1].reshape(3, 3)
        p1 = d.xpos[b1]
        if m.eq_type[eq] == mujoco.mjtEq.mjEQ_WELD:
            # keep the current relative pose: body2 = body1 * relpose
            m.eq_data[eq, 0:3] = 0.0
            m.eq_data[eq, 3:6] = R1.T @ (d.xpos[b2] - p1)
            q1inv = np.zeros(4)
            mujoco.mju_negQuat(q1inv, d.xquat[b1])
            rel = np.zeros(4)
            mujoco.mju_mulQuat(rel, q1inv, d.xquat[b2])
            m.eq_data[eq, 6:10] = rel
            m.eq_data[eq, 10] = 1.0
        else:  # connect at the grip site: anchor in body1 frame and the same point in body2 frame
            ps = d.site_xpos[scene.robot.grip_site]
            m.eq_data[eq, 0:3] = R1.T @ (ps - p1)
            R2 = d.xmat[b2].reshape(3, 3)
            m.eq_data[eq, 3:6] = R2.T @ (ps - d.xpos[b2])
        d.eq_active[eq] = 1
        self._assist = eq

    def _release(self, scene) -> bool:
        if self._assist is not None:
            scene.data.eq_active[self._assist] = 0
            self._assist = None
        return True


def _approach_push(n: np.ndarray, down_deg: float = 45.0) -> np.ndarray:
    """Gripper axis pointing into the fixture (-n), tilted down by down_deg."""
    a = math.radians(down_deg)
    return _unit(-n * math.cos(a) + DOWN * math.sin(a))


class CloseDrawerPolicy(ScriptedPolicy):
    """Push the open drawer's front panel shut below its handle, 45 deg down approach."""

    task = "CloseDrawer"

    def _geom(self, scene):
        f = scene.fixtures["drawer"]
        yaw = f["yaw"]
        n = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        qa = scene.model.jnt_qposadr[mujoco.mj_name2id(scene.model, mujoco.mjtObj.mjOBJ_JOINT, f["joint"])]
        q = float(scene.data.qpos[qa])
        zc = f["front"][2] - 0.03
        face0 = np.array([f["front"][0], f["front"][1], zc])
        return n, face0, face0 + n * q

    def keypoints(self, scene):
        n, face0, face = self._geom(scene)
        a = _approach_push(n)
        return [(face + 0.10 * n, a), (face0 + 0.0 * n, a)]

    def segments(self, scene, q_first):
        n, face0, face = self._geom(scene)
        a = _approach_push(n)
        p0, p1 = face + 0.10 * n, face0 - 0.025 * n
        return [
            _Joint(1.1, q_first, opened=False),
            _Cart(1.7, lambda s: p0 + _smooth(s) * (p1 - p0), a, opened=False),
            _Cart(0.3, lambda s: p1, a, opened=False),
            _Cart(0.4, lambda s: p1 + 0.08 * s * n, a, opened=False),
        ]


class CloseDoubleDoorPolicy(ScriptedPolicy):
    """Sweep each open door shut by pushing its outer face near the free edge, one door after the other.

    A door opened to ~90 deg sticks out of the cabinet with its outer (front) face turned sideways,
    away from the opening, so a closing push must come from outside the door pair. The closed fingers
    point into the face, tilted ``PUSH_DOWN_DEG`` below horizontal, and turn with the door as it
    closes: the fingertips touch the face at ``R_FRAC`` of the door width from the hinge and
    ``Z_BELOW_TOP`` below the top edge, and the hand stays outside the face. (Generator 2.0 pushed
    with the fingers pointing straight down and the hand above the door: as the door neared closed
    the hand ran into the cabinet top above it, and most rollouts ended blocked with the door a few
    degrees open.) The door nearer to the base goes first; the hand then rises above the door tops,
    pointing down, and goes around the other door's free edge. No grasp and no assist: contact forces
    alone move the doors.
    """

    task = "CloseDoubleDoor"
    R_FRAC = 0.80  # contact radius as a fraction of the door width
    Z_BELOW_TOP = 0.06  # m, grip site below the door's top edge
    STANDOFF = 0.08  # m outside the face before moving in
    PRESS = 0.004  # m, grip-site offset from the face while sweeping (fingers ~1 cm thick: they press)
    Q_END = -0.04  # rad, sweep target past closed (the hinge stops at 0)
    LIFT = 0.10  # m above the push height while moving between the doors
    PUSH_DOWN_DEG = 20.0  # gripper axis below horizontal while pushing (chosen on training scenes: 0-45 deg tried)

    def _doors(self, scene):
        """yaw, [(hinge world [3] at z=0, e, q, radius, z, width)] ordered nearest-to-the-base first."""
        f = scene.fixtures["double_door"]
        yaw = f["yaw"]
        c, s = math.cos(yaw), math.sin(yaw)
        bx, by, _ = scene.base_pose()
        out = []
        for dd in f["doors"]:
            hl = dd["hinge_local"]
            hinge = np.array([f["origin"][0] + c * hl[0] - s * hl[1], f["origin"][1] + s * hl[0] + c * hl[1], 0.0])
            qa = scene.model.jnt_qposadr[mujoco.mj_name2id(scene.model, mujoco.mjtObj.mjOBJ_JOINT, dd["joint"])]
            wd = float(dd["width"])
            out.append(
                (
                    hinge,
                    int(dd["e"]),
                    float(scene.data.qpos[qa]),
                    self.R_FRAC * wd,
                    float(dd["z1"]) - self.Z_BELOW_TOP,
                    wd,
                )
            )

        def dist(d):
            p = self._pt(yaw, d, d[2], 0.0)
            return (round(math.hypot(p[0] - bx, p[1] - by), 6), d[1])

        out.sort(key=dist)
        return yaw, out

    @staticmethod
    def _pt(yaw, door, q, off, r=None, dz=0.0):
        """Point ``off`` outside the door's outer face at radius r (default: contact radius), door at angle q."""
        hinge, e, _, rc, z, _ = door
        return _door_point(hinge, yaw, e, q, np.array([off, -e * (rc if r is None else r), z + dz]))

    def _path_points(self, yaw, doors):
        """Key points per door: (above-outside, outside, touching, half-closed, closed)."""
        out = []
        for d in doors:
            q0 = d[2]
            out.append(
                (
                    self._pt(yaw, d, q0, self.STANDOFF, dz=self.LIFT),
                    self._pt(yaw, d, q0, self.STANDOFF),
                    self._pt(yaw, d, q0, self.PRESS),
                    self._pt(yaw, d, 0.5 * q0, self.PRESS),
                    self._pt(yaw, d, 0.0, self.PRESS),
                )
            )
        return out

    def _push_axis(self, yaw, door, q):
        """Gripper axis [3] pushing door at angle q: into its outer face, tilted down."""
        return _approach_push(_door_normal(yaw, door[1], q), self.PUSH_DOWN_DEG)

    def keypoints(self, scene):
        yaw, doors = self._doors(scene)
        kps = []
        for k, (d, pts) in enumerate(zip(doors, self._path_points(yaw, doors))):
            q0 = d[2]
            axes = (DOWN, *(self._push_axis(yaw, d, q) for q in (q0, q0, 0.5 * q0, 0.0)))
            kps += list(zip(pts, axes))[1:] if k == 0 else list(zip(pts, axes))
        return kps

    def segments(self, scene, q_first):
        yaw, doors = self._doors(scene)
        segs: list = []

        def line(a, b):
            return lambda s: a + _smooth(s) * (b - a)

        def turn(a, b):
            return lambda s: _unit(a + _smooth(s) * (b - a))

        prev = None
        for k, (d, pts) in enumerate(zip(doors, self._path_points(yaw, doors))):
            above, out, touch = pts[0], pts[1], pts[2]
            q0 = d[2]
            axis0, axis_shut = self._push_axis(yaw, d, q0), self._push_axis(yaw, d, 0.0)
            if k == 0:
                segs.append(_Joint(1.0, q_first, opened=False))
            else:
                # around the free edge of the second door, above the door tops, pointing down
                wd = d[5]
                tip = self._pt(yaw, d, q0, -0.02, r=wd + 0.10, dz=self.LIFT)
                segs.append(_Cart(1.1, line(prev, tip), DOWN, opened=False))
                segs.append(_Cart(0.4, line(tip, above), DOWN, opened=False))
                segs.append(_Cart(0.5, line(above, out), turn(DOWN, axis0), opened=False))
            segs.append(_Cart(0.3, line(out, touch), axis0, opened=False))

            def arc(s, d=d, q0=q0):
                return self._pt(yaw, d, q0 + _smooth(s) * (self.Q_END - q0), self.PRESS)

            def arc_axis(s, d=d, q0=q0):
                return self._push_axis(yaw, d, q0 + _smooth(s) * (self.Q_END - q0))

            segs.append(_Cart(1.2, arc, arc_axis, opened=False))
            end = arc(1.0)
            back = self._pt(yaw, d, 0.0, self.STANDOFF + 0.06)  # out from the closed face, then up
            prev = back + np.array([0.0, 0.0, self.LIFT])
            segs.append(_Cart(0.3, line(end, back), axis_shut, opened=False))
            if k + 1 < len(doors):
                segs.append(_Cart(0.35, line(back, prev), turn(axis_shut, DOWN), opened=False))
        return segs


class OpenSingleDoorPolicy(ScriptedPolicy):
    """Grasp the microwave handle (connect assist) and swing the door open along its arc."""

    task = "OpenSingleDoor"
    Q_END = 1.62

    def _geom(self, scene):
        f = scene.fixtures["microwave"]
        return f["hinge"], f["yaw"], int(f["e"]), np.asarray(f["grasp_local"], dtype=np.float64)

    def _approach(self, yaw, e, q):
        return _unit(-_door_normal(yaw, e, q) + 0.45 * DOWN)

    def keypoints(self, scene):
        hinge, yaw, e, g = self._geom(scene)
        pre = _door_point(hinge, yaw, e, 0.0, g + np.array([0.10, 0.0, 0.0]))
        kps = [(pre, self._approach(yaw, e, 0.0)), (_door_point(hinge, yaw, e, 0.0, g), self._approach(yaw, e, 0.0))]
        for q in (0.8, self.Q_END):
            kps.append((_door_point(hinge, yaw, e, q, g), self._approach(yaw, e, q)))
        return kps

    def _grasp_check(self, scene) -> bool:
        hinge, yaw, e, g = self._geom(scene)
        handle = _door_point(hinge, yaw, e, 0.0, g)
        hand = scene.data.site_xpos[scene.robot.grip_site]
        if float(np.linalg.norm(hand - handle)) > 0.04:
            self.reason = "grasp_failed"
            return False
        self._activate(scene, "assist_door", "microwave_door")
        return True

    def segments(self, scene, q_first):
        hinge, yaw, e, g = self._geom(scene)
        pre = _door_point(hinge, yaw, e, 0.0, g + np.array([0.10, 0.0, 0.0]))
        grasp = _door_point(hinge, yaw, e, 0.0, g)
        a0 = self._approach(yaw, e, 0.0)

        def arc(s):
            return _door_point(hinge, yaw, e, _smooth(s) * self.Q_END, g)

        def arc_a(s):
            return self._approach(yaw, e, _smooth(s) * self.Q_END)

        end = _door_point(hinge, yaw, e, self.Q_END, g)
        n_end = _door_normal(yaw, e, self.Q_END)
        return [
            _Joint(1.0, q_first, opened=True),
            _Cart(0.5, lambda s: pre + _smooth(s) * (grasp - pre), a0, opened=True),
            _Grip(0.3, opened=False, on_end=self._grasp_check),
            _Cart(2.2, arc, arc_a, opened=False),
            _Grip(0.2, opened=True, on_end=self._release),
            _Cart(0.4, lambda s: end + 0.10 * s * n_end, arc_a(1.0), opened=True),
        ]


class PnPCounterToCabPolicy(ScriptedPolicy):
    """Top-down grasp (weld assist), lift out in front of the counter, insert into the open wall cabinet, release,
    retreat."""

    task = "PnPCounterToCab"

    def _geom(self, scene):
        f = scene.fixtures["wall_cab"]
        yaw = f["yaw"]
        n = np.array([math.cos(yaw), math.sin(yaw), 0.0])
        qa = scene.model.jnt_qposadr[mujoco.mj_name2id(scene.model, mujoco.mjtObj.mjOBJ_JOINT, "pnp_object_joint")]
        obj = scene.data.qpos[qa : qa + 3].copy()
        inside = f["interior_center"].copy()
        inside[2] = f["bottom_z"] + f["object_half"][2] + 0.02
        inside = inside + 0.02 * n
        front = f["front"]
        pre_place = inside + n * ((front - inside) @ n + 0.12)
        # lift-out point: 0.30 m out from the object along the cabinet's normal and 0.10 m above it
        out = obj + n * 0.30 + np.array([0.0, 0.0, 0.10])
        return n, obj, inside, pre_place, out, f

    def keypoints(self, scene):
        n, obj, inside, pre_place, out, f = self._geom(scene)
        return [
            (obj + np.array([0, 0, 0.10]), DOWN),
            (obj + np.array([0, 0, 0.005]), DOWN),
            (pre_place, DOWN),
            (inside, DOWN),
            (inside + 0.3 * n, DOWN),
        ]

    def _grasp_check(self, scene) -> bool:
        n, obj, *_ = self._geom(scene)
        hand = scene.data.site_xpos[scene.robot.grip_site]
        dxy = math.hypot(hand[0] - obj[0], hand[1] - obj[1])
        if dxy > 0.03 or abs(hand[2] - obj[2]) > 0.04:
            self.reason = "grasp_failed"
            return False
        self._activate(scene, "assist_object", scene.fixtures["wall_cab"]["object"])
        return True

    def segments(self, scene, q_first):
        n, obj, inside, pre_place, out, f = self._geom(scene)
        above = obj + np.array([0, 0, 0.10])
        grasp = obj + np.array([0, 0, 0.005])
        lift = obj + np.array([0, 0, 0.08])
        up = np.array([out[0], out[1], pre_place[2]])
        retreat = inside + 0.32 * n

        def line(a, b):
            return lambda s: a + _smooth(s) * (b - a)

        return [
            _Joint(1.0, q_first, opened=True),
            _Cart(0.5, line(above, grasp), DOWN, opened=True),
            _Grip(0.3, opened=False, on_end=self._grasp_check),
            _Cart(0.3, line(grasp, lift), DOWN, opened=False),
            _Cart(0.5, line(lift, out), DOWN, opened=False),
            _Cart(0.9, line(out, up), DOWN, opened=False),
            _Cart(0.5, line(up, pre_place), DOWN, opened=False),
            _Cart(0.8, line(pre_place, inside), DOWN, opened=False, w_rot=0.5),
            _Grip(0.3, opened=True, on_end=self._release),
            _Cart(0.8, line(inside, retreat), DOWN, opened=True),
        ]


POLICIES: dict[str, type[ScriptedPolicy]] = {
    "CloseDrawer": CloseDrawerPolicy,
    "CloseDoubleDoor": CloseDoubleDoorPolicy,
    "OpenSingleDoor": OpenSingleDoorPolicy,
    "PnPCounterToCab": PnPCounterToCabPolicy,
}


def default_policy(task: str, precheck: bool = True) -> ScriptedPolicy:
    """The scripted policy of a task."""
    if not isinstance(task, str) or task not in POLICIES:  # a list failed with "unhashable type"
        raise ValueError(f"unknown task {task!r}; valid tasks: {list(POLICIES)}")
    return POLICIES[task](precheck=precheck)
