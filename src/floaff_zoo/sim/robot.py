"""PandaOmron robot model, joint bookkeeping, base teleport and a small DLS IK.

The robot MJCF comes from robosuite's model API (``create_robot("PandaOmron")`` ->
``add_base(OmronMobileBase)`` -> ``add_gripper(PandaGripper)``; docs/background.md §5). We only use
robosuite for the model; control is our own:

* the 7 arm torque motors are turned into MuJoCo position actuators (joint impedance with
  implicit damping) and the arm bodies get gravity compensation, so no per-substep Python loop
  is needed (docs/background.md §5);
* the torso motor becomes a stiff position actuator;
* the base keeps robosuite's velocity actuators, held at 0 (its joints also carry frictionloss 250).

The base yaw joint pivots 0.21 m behind the base-frame origin: :func:`RobotIndex.set_base_pose`
compensates so that ``(x, y, yaw)`` is always the pose of the base-frame origin (the point the
arm is mounted above).
"""

from __future__ import annotations

import functools
import math
import os
from dataclasses import dataclass

import mujoco
import numpy as np

from floaff_zoo.checks import check_integer, check_number
from floaff_zoo.floor import check_pose
from floaff_zoo.quiet import quiet_robosuite

ARM_JOINTS: tuple[str, ...] = tuple(f"robot0_joint{i}" for i in range(1, 8))
TORSO_JOINT = "mobilebase0_joint_torso_height"
BASE_JOINTS: tuple[str, str, str] = (
    "mobilebase0_joint_mobile_forward",
    "mobilebase0_joint_mobile_side",
    "mobilebase0_joint_mobile_yaw",
)
FINGER_JOINTS: tuple[str, str] = ("gripper0_finger_joint1", "gripper0_finger_joint2")
GRIP_SITE = "gripper0_grip_site"
HAND_BODY = "gripper0_right_gripper"
BASE_BODY = "mobilebase0_base"
EGO_CAMERA = "floaff_ego"

#: arm rest pose used for collision filtering and as the rollout start: folded low and close to the torso so that
#: it stays out of the ego camera. It is not inside the base footprint: the hand reaches ~0.25 m past the footprint's
#: front at 1.1-1.2 m height (the footprint checks ignore it; the pose filter's robot-collision test uses the real
#: geoms).
TUCK_ARM = np.array([0.0, -0.75, 0.0, -2.85, 0.0, 2.15, math.pi / 4])
TUCK_TORSO = 0.10
#: joint stiffness / damping of the arm position actuators (N m / rad, N m s / rad)
ARM_KP = np.array([900.0, 900.0, 700.0, 700.0, 300.0, 200.0, 80.0])
ARM_KV = np.array([90.0, 90.0, 70.0, 70.0, 25.0, 16.0, 6.0])
ARM_FORCE = np.array([87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0])
#: N2M footprint (docs/background.md §3): 0.63 m long, 0.5 m wide, 0.83 L behind / 0.17 L in front
FOOTPRINT_LENGTH = 0.63
FOOTPRINT_WIDTH = 0.50
FOOTPRINT_FRONT = 0.17 * FOOTPRINT_LENGTH
FOOTPRINT_BACK = 0.83 * FOOTPRINT_LENGTH


@functools.lru_cache(maxsize=1)
def robot_xml() -> str:
    """PandaOmron MJCF string from robosuite's model API (cached per process, ~0.6-1.5 s once)."""
    os.environ.setdefault("MUJOCO_GL", "egl")  # robosuite forces egl at import unless set
    quiet_robosuite()  # its import-time macro notices, once per (worker) process, unless --verbose
    from robosuite.models.bases import robot_base_factory
    from robosuite.models.grippers import gripper_factory
    from robosuite.models.robots import create_robot

    robot = create_robot("PandaOmron")
    robot.add_base(robot_base_factory("OmronMobileBase"))
    robot.add_gripper(gripper_factory("PandaGripper"))
    return robot.get_xml()


def _quat_from_mat(mat: np.ndarray) -> np.ndarray:
    """3x3 rotation -> quaternion (w, x, y, z)."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.asarray(mat, dtype=np.float64).reshape(9))
    return q


def robot_spec() -> mujoco.MjSpec:
    """MjSpec of the robot with position-controlled arm/torso, gravity compensation and the ego camera."""
    spec = mujoco.MjSpec.from_string(robot_xml())
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    for i in range(len(ARM_JOINTS)):
        act = spec.actuator(f"robot0_torq_j{i + 1}")
        act.set_to_position(kp=float(ARM_KP[i]), kv=float(ARM_KV[i]))
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-ARM_FORCE[i], ARM_FORCE[i]]
    torso = spec.actuator("mobilebase0_actuator_torso_height")
    torso.set_to_position(kp=2.0e5, kv=2.0e4)
    torso.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
    torso.ctrlrange = [0.0, 0.34]
    torso.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    torso.forcerange = [-1.0e4, 1.0e4]
    for body in spec.bodies:
        if (
            body.name.startswith("robot0_link")
            or body.name.startswith("gripper0_")
            or body.name
            in (
                "robot0_right_hand",
                "manipulator_mount",
            )
        ):
            body.gravcomp = 1.0
    base = spec.body(BASE_BODY)
    pitch = math.radians(38.0)
    # camera looks along its -z; x right, y up. Forward = +x of the base, pitched down.
    xaxis = np.array([0.0, -1.0, 0.0])
    yaxis = np.array([math.sin(pitch), 0.0, math.cos(pitch)])
    zaxis = np.cross(xaxis, yaxis)
    cam = base.add_camera(name=EGO_CAMERA)
    cam.pos = [0.32, 0.0, 1.55]
    cam.quat = _quat_from_mat(np.stack([xaxis, yaxis, zaxis], axis=1))
    cam.fovy = 70.0
    return spec


@dataclass
class RobotIndex:
    """Addresses of the robot's joints/actuators/geoms in one compiled model."""

    base_qadr: np.ndarray  # [3] qpos of forward, side, yaw
    base_dadr: np.ndarray  # [3]
    torso_qadr: int
    torso_dadr: int
    arm_qadr: np.ndarray  # [7]
    arm_dadr: np.ndarray  # [7]
    finger_qadr: np.ndarray  # [2]
    ik_dadr: np.ndarray  # [8] torso + arm dofs (IK variables)
    ik_qadr: np.ndarray  # [8]
    ik_lo: np.ndarray  # [8]
    ik_hi: np.ndarray  # [8]
    arm_act: np.ndarray  # [7]
    torso_act: int
    base_act: np.ndarray  # [3]
    finger_act: np.ndarray  # [2]
    grip_site: int
    hand_body: int
    base_body: int
    pivot: np.ndarray  # [2] yaw pivot in the base frame (x, y), e.g. (-0.21, 0)
    geom_ids: np.ndarray  # robot collision geoms (contype/conaffinity != 0)
    body_ids: np.ndarray  # all robot bodies

    @classmethod
    def from_model(cls, m: mujoco.MjModel) -> "RobotIndex":
        def jid(name: str) -> int:
            return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)

        def aid(name: str) -> int:
            return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, name)

        base_j = [jid(n) for n in BASE_JOINTS]
        arm_j = [jid(n) for n in ARM_JOINTS]
        torso_j = jid(TORSO_JOINT)
        ik_j = [torso_j] + arm_j
        root = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "robot0_base")
        bodies = np.flatnonzero(subtree_bodies(m, root)).tolist()
        geoms = [
            g for g in range(m.ngeom) if m.geom_bodyid[g] in bodies and (m.geom_contype[g] or m.geom_conaffinity[g])
        ]
        return cls(
            base_qadr=m.jnt_qposadr[base_j].copy(),
            base_dadr=m.jnt_dofadr[base_j].copy(),
            torso_qadr=int(m.jnt_qposadr[torso_j]),
            torso_dadr=int(m.jnt_dofadr[torso_j]),
            arm_qadr=m.jnt_qposadr[arm_j].copy(),
            arm_dadr=m.jnt_dofadr[arm_j].copy(),
            finger_qadr=m.jnt_qposadr[[jid(n) for n in FINGER_JOINTS]].copy(),
            ik_dadr=m.jnt_dofadr[ik_j].copy(),
            ik_qadr=m.jnt_qposadr[ik_j].copy(),
            ik_lo=m.jnt_range[ik_j, 0] + 1e-3,
            ik_hi=m.jnt_range[ik_j, 1] - 1e-3,
            arm_act=np.array([aid(f"robot0_torq_j{i}") for i in range(1, 8)]),
            torso_act=aid("mobilebase0_actuator_torso_height"),
            base_act=np.array([aid(f"mobilebase0_actuator_mobile_{n}") for n in ("forward", "side", "yaw")]),
            finger_act=np.array([aid("gripper0_gripper_finger_joint1"), aid("gripper0_gripper_finger_joint2")]),
            grip_site=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, GRIP_SITE),
            hand_body=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, HAND_BODY),
            base_body=mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, BASE_BODY),
            pivot=m.jnt_pos[base_j[2], :2].copy(),
            geom_ids=np.array(geoms, dtype=np.int64),
            body_ids=np.array(bodies, dtype=np.int64),
        )

    # ---- base pose ------------------------------------------------------------------------
    def set_base_pose(self, data: mujoco.MjData, x: float, y: float, yaw: float) -> None:
        """Teleport: write the 3 base qpos so the base-frame origin is at (x, y) with heading yaw.

        The yaw hinge rotates about ``pivot`` (base frame), so origin = slide + p - R(yaw) p. A non-finite pose raises
        ``ValueError`` (it was written into qpos).
        """
        x, y, yaw = check_pose((x, y, yaw), "RobotIndex.set_base_pose")
        c, s = math.cos(yaw), math.sin(yaw)
        px, py = float(self.pivot[0]), float(self.pivot[1])
        data.qpos[self.base_qadr[0]] = x - px + (c * px - s * py)
        data.qpos[self.base_qadr[1]] = y - py + (s * px + c * py)
        data.qpos[self.base_qadr[2]] = yaw
        data.qvel[self.base_dadr] = 0.0

    def base_pose(self, data: mujoco.MjData) -> tuple[float, float, float]:
        """Inverse of :meth:`set_base_pose` from qpos (no forward kinematics needed)."""
        yaw = float(data.qpos[self.base_qadr[2]])
        c, s = math.cos(yaw), math.sin(yaw)
        px, py = float(self.pivot[0]), float(self.pivot[1])
        x = float(data.qpos[self.base_qadr[0]]) + px - (c * px - s * py)
        y = float(data.qpos[self.base_qadr[1]]) + py - (s * px + c * py)
        return x, y, yaw

    def set_tuck(self, data: mujoco.MjData) -> None:
        """Arm in its rest pose, torso at TUCK_TORSO, gripper open; ctrl matches."""
        data.qpos[self.arm_qadr] = TUCK_ARM
        data.qpos[self.torso_qadr] = TUCK_TORSO
        data.qpos[self.finger_qadr] = (0.04, -0.04)
        data.qvel[self.arm_dadr] = 0.0
        self.hold(data, TUCK_ARM, TUCK_TORSO, opened=True)

    def hold(self, data: mujoco.MjData, arm_q: np.ndarray, torso: float, opened: bool) -> None:
        """Write actuator targets: arm [7] joint positions, torso height, gripper, base velocity 0."""
        data.ctrl[self.arm_act] = arm_q
        data.ctrl[self.torso_act] = torso
        data.ctrl[self.base_act] = 0.0
        data.ctrl[self.finger_act] = (0.04, -0.04) if opened else (0.0, 0.0)

    def ik_q(self, data: mujoco.MjData) -> np.ndarray:
        """Current IK variables [8] = torso + 7 arm joints."""
        return data.qpos[self.ik_qadr].copy()


def subtree_bodies(m: mujoco.MjModel, root: int) -> np.ndarray:
    """Bool mask [nbody] of body ``root`` and every body below it (MuJoCo numbers a parent before its children)."""
    inside = np.zeros(m.nbody, dtype=bool)
    inside[root] = True
    for b in range(root + 1, m.nbody):
        inside[b] = inside[m.body_parentid[b]]
    return inside


class DLSIK:
    """Damped-least-squares IK for the grip site on torso + 7 arm DOF (8 variables).

    Position is the main task; an optional approach direction (gripper z axis) is a soft task
    weighted by ``w_rot``. Hand-written 3-vector maths, closed-form 3x3 inverses (no LAPACK calls)
    and slice views of the Jacobian keep an iteration at ~30 us. The solver works on its own
    scratch ``MjData`` so the simulation state is never touched.
    """

    def __init__(self, model: mujoco.MjModel, index: RobotIndex, damping: float = 0.04) -> None:
        # a NaN damping made every solution NaN (written into the arm's commands), 0 a singular inverse near the limits
        check_number("damping", damping, strict=True, owner="DLSIK")
        self.m = model
        self.ix = index
        self.d = mujoco.MjData(model)
        self.damping = damping
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))
        self._J = np.zeros((6, 8))
        self._eye8 = np.eye(8)
        # the 8 IK dofs are contiguous in qpos/qvel for PandaOmron: slices index without copies
        self._qsel = _as_slice(index.ik_qadr)
        self._dsel = _as_slice(index.ik_dadr)

    def sync(self, data: mujoco.MjData) -> None:
        """Copy the full configuration (base pose, fixtures) from the simulation into the scratch."""
        self.d.qpos[:] = data.qpos

    def site_pose(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Grip-site position [3] and rotation [3,3] for IK variables q [8]."""
        d = self.d
        d.qpos[self.ix.ik_qadr] = q
        mujoco.mj_kinematics(self.m, d)
        s = self.ix.grip_site
        return d.site_xpos[s].copy(), d.site_xmat[s].reshape(3, 3).copy()

    def solve(
        self,
        target: np.ndarray,
        q0: np.ndarray,
        approach: np.ndarray | None = None,
        w_rot: float = 0.3,
        iters: int = 40,
        tol: float = 0.004,
        max_step: float = 0.25,
    ) -> tuple[np.ndarray, float]:
        """Solve for q [8] from q0 [8] so the grip site reaches target [3] (world).

        Prioritised DLS: position first; the approach axis (desired gripper z, unit [3] world) is
        tracked in the position task's null space with gain ``w_rot``, so it never costs position
        accuracy. Returns (q, position error m).

        Raises:
            ValueError: a target, q0 or approach that is not finite numbers of its size (a NaN one gave a NaN q and
                error, which the controllers' ``err > tol`` let through into the arm's commands), a w_rot, tol or
                max_step that is no finite number (> 0 for the last two: a negative max_step stepped away from the
                target), or iters that is no integer >= 0 (1.5 failed in range()).
        """
        _check_vector("target", target, 3)
        _check_vector("q0", q0, 8)
        if approach is not None:
            _check_vector("approach", approach, 3)
        check_number("w_rot", w_rot, owner="DLSIK.solve")
        check_integer("iters", iters, 0, owner="DLSIK.solve")
        check_number("tol", tol, strict=True, owner="DLSIK.solve")
        check_number("max_step", max_step, strict=True, owner="DLSIK.solve")
        m, d, ix = self.m, self.d, self.ix
        lo, hi = ix.ik_lo, ix.ik_hi
        q = np.minimum(np.maximum(np.array(q0, dtype=np.float64), lo), hi)  # same values as np.clip
        site = ix.grip_site
        qsel, dsel = self._qsel, self._dsel
        jacp, jacr = self._jacp, self._jacr
        lam2 = self.damping**2
        tx, ty, tz = float(target[0]), float(target[1]), float(target[2])
        if approach is not None:
            ax, ay, az = float(approach[0]), float(approach[1]), float(approach[2])
        err = 1e9
        for it in range(iters + 1):
            d.qpos[qsel] = q
            mujoco.mj_kinematics(m, d)
            px, py, pz = d.site_xpos[site].tolist()
            ex, ey, ez = tx - px, ty - py, tz - pz
            err = math.sqrt(ex * ex + ey * ey + ez * ez)
            align = 1.0
            if approach is not None:
                R = d.site_xmat[site].tolist()
                zx, zy, zz = R[2], R[5], R[8]  # current gripper z axis (column 2)
                rx = zy * az - zz * ay  # rotation vector aligning z to approach: z x a
                ry = zz * ax - zx * az
                rz = zx * ay - zy * ax
                align = zx * ax + zy * ay + zz * az
                if align < 0:  # opposite: rotate about any perpendicular axis
                    rx, ry, rz = -rx, -ry, -rz
            if (err < tol and align > 0.97) or it == iters:
                break
            mujoco.mj_comPos(m, d)
            mujoco.mj_jacSite(m, d, jacp, jacr, site)
            Jp = jacp[:, dsel]
            Jp_pinv = Jp.T @ np.array(_inv3_spd(Jp @ Jp.T, lam2))
            dq = Jp_pinv @ np.array((ex, ey, ez))
            if approach is not None:
                Jr = jacr[:, dsel]
                N = self._eye8 - Jp_pinv @ Jp
                JrN = Jr @ N
                vx, vy, vz = (Jr @ dq).tolist()
                vx, vy, vz = w_rot * rx - vx, w_rot * ry - vy, w_rot * rz - vz
                (b00, b01, b02), (_, b11, b12), (_, _, b22) = _inv3_spd(JrN @ JrN.T, lam2)
                w = (b00 * vx + b01 * vy + b02 * vz, b01 * vx + b11 * vy + b12 * vz, b02 * vx + b12 * vy + b22 * vz)
                dq += N @ (JrN.T @ np.array(w))
            n = max(dq.max(), -dq.min())  # max |dq|
            if n > max_step:
                dq *= max_step / n
            q += dq
            np.maximum(q, lo, out=q)
            np.minimum(q, hi, out=q)
        if approach is not None and err > tol:
            # joint limits can break the null-space split: fall back to position only from here
            q2, err2 = self.solve(target, q, None, iters=iters, tol=tol, max_step=max_step)
            if err2 < err:
                return q2, err2
        return q, float(err)


def _check_vector(name: str, value: object, n: int) -> None:
    """Refuse a DLSIK.solve argument that is not n finite numbers (shape [n])."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        a = np.full(n, np.nan)
    if a.shape != (n,) or not np.isfinite(a).all():
        raise ValueError(f"DLSIK.solve: {name} must be {n} finite numbers, got {value!r}")


def _as_slice(idx: np.ndarray) -> slice | np.ndarray:
    """Contiguous increasing indices [k] -> slice (view, no copy); anything else is returned unchanged."""
    idx = np.asarray(idx)
    if len(idx) and np.all(np.diff(idx) == 1):
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


def _inv3_spd(A: np.ndarray, lam2: float) -> tuple[tuple[float, float, float], ...]:
    """(A + lam2 I)^-1 as nested tuples [3][3] for a symmetric positive semi-definite A [3,3], by cofactors.

    Closed form in Python floats instead of ``np.linalg.inv``/``solve``: on 3x3 arrays LAPACK's call
    overhead is ~10x the maths.
    """
    a, b, c, _, d, e, _, _, f = A.ravel().tolist()
    a += lam2
    d += lam2
    f += lam2
    i00 = d * f - e * e
    i01 = c * e - b * f
    i02 = b * e - c * d
    i11 = a * f - c * c
    i12 = b * c - a * e
    i22 = a * d - b * b
    r = 1.0 / (a * i00 + b * i01 + c * i02)
    return (i00 * r, i01 * r, i02 * r), (i01 * r, i11 * r, i12 * r), (i02 * r, i12 * r, i22 * r)
