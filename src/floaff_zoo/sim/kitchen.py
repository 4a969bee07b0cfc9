"""Procedural kitchens (MjSpec) with the PandaOmron robot: layouts x styles x seed.

A scene is fully determined by :class:`SceneSpec` ``(layout_id, style_id, seed, task)``. Every kitchen
contains all four task fixtures (a top drawer, a double-door base cabinet, a microwave on the
counter, a wall cabinet with an object on the counter below it); ``task`` selects which one is the
target and its reset state. Layout families place counter runs along walls differently (one-wall,
L, galley, U, island, G/wraparound); styles change counter height/depth, module widths, drawer
height, wall-cabinet height, handle type/position, colours and procedural textures; the seed
shuffles the fixture order along the runs, aisle widths and the object's spot.

Frames. Every fixture has a local frame whose +x is the front's outward normal (world yaw =
``TargetInfo.yaw``), z is up and the front face is at local x = 0 (module fronts) - the
"target frame" of the paper's candidate region uses the same yaw (see ``tasks.target_frame``).

Geom groups: scene geoms group 2 (collide with the robot), robot visuals group 1, robot collision
meshes group 0 (hide them when rendering, docs/background.md §5). Lights cast no shadows.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from floaff_zoo.checks import check_number
from floaff_zoo.floor import check_pose
from floaff_zoo.names import TASKS as TASKS  # defined once there; re-exported here
from floaff_zoo.sim import robot as _robot
from floaff_zoo.sim.tasks import TASK_REGISTRY
from floaff_zoo.sim.tasks import TargetInfo as TargetInfo  # defined with the tasks; re-exported here

LAYOUTS: dict[int, str] = {
    0: "one_wall",
    1: "l_shaped",
    2: "galley",
    3: "u_shaped",
    4: "island",
    5: "g_shaped",
}
STYLES: dict[int, str] = {
    0: "industrial",
    1: "scandinavian",
    2: "coastal",
    3: "modern",
    4: "traditional",
    5: "farmhouse",
    6: "rustic",
    7: "mediterranean",
}
SCENE_GROUP = 2
#: where the robot waits outside the kitchen (static scene renders, success-state tests)
PARK_POSE: tuple[float, float, float] = (0.0, -7.0, math.pi / 2)
#: task -> fixture kind that is its target
TASK_FIXTURE: dict[str, str] = {
    "PnPCounterToCab": "wall_cab",
    "OpenSingleDoor": "microwave",
    "CloseDrawer": "drawer",
    "CloseDoubleDoor": "double_door",
}


@dataclass(frozen=True)
class SceneSpec:
    """Identity of one generated scene; ``scene_id`` is e.g. ``L2_S5_s17_CloseDrawer``."""

    layout_id: int
    style_id: int
    seed: int
    task: str

    def __post_init__(self) -> None:
        # stored as Python ints: a seed 1.7 built seed 1's kitchen under the id ``s1.7``, True was layout 1, and 3.0
        # named its scene ``s3.0`` (another id, another cache key) for seed 3's kitchen
        for name in ("layout_id", "style_id", "seed"):
            value = getattr(self, name)
            whole = _whole_number(value)
            if whole is None:
                raise ValueError(f"SceneSpec: {name} must be a whole number, got {value!r}")
            object.__setattr__(self, name, whole)
        if self.layout_id not in LAYOUTS:
            raise ValueError(f"unknown layout_id {self.layout_id!r}; valid ids: {sorted(LAYOUTS)} ({LAYOUTS})")
        if self.style_id not in STYLES:
            raise ValueError(f"unknown style_id {self.style_id!r}; valid ids: {sorted(STYLES)} ({STYLES})")
        if self.task not in TASKS:
            raise ValueError(f"unknown task {self.task!r}; valid tasks: {list(TASKS)}")
        if self.seed < 0:
            raise ValueError(f"seed must be >= 0, got {self.seed}")

    @property
    def scene_id(self) -> str:
        return f"L{self.layout_id}_S{self.style_id}_s{self.seed}_{self.task}"

    def to_dict(self) -> dict:
        return {
            "layout_id": int(self.layout_id),
            "style_id": int(self.style_id),
            "seed": int(self.seed),
            "task": self.task,
        }

    @classmethod
    def from_dict(cls, d: dict) -> "SceneSpec":
        if not isinstance(d, Mapping):  # None failed with "argument of type 'NoneType' is not iterable"
            raise ValueError(f"SceneSpec.from_dict expects a mapping of the spec's fields, got {d!r}")
        missing = [k for k in ("layout_id", "style_id", "seed", "task") if k not in d]
        if missing:
            raise ValueError(f"SceneSpec.from_dict: missing field(s) {missing} in {d!r}")
        return cls(*(_spec_int(d, k) for k in ("layout_id", "style_id", "seed")), str(d["task"]))


def _spec_int(d: dict, key: str) -> int:
    """``d[key]`` as an int; a value that is not a whole number (``int`` cut 17.5 to seed 17's kitchen and read ``true``
    as 1) or not a number at all is a ValueError naming the field and the record."""
    v = d[key]
    i = _whole_number(v)
    if i is None:
        raise ValueError(f"SceneSpec.from_dict: {key} must be a whole number, got {v!r} in {d!r}")
    return i


def _whole_number(v: object) -> int | None:
    """``v`` as an int when it is a whole number (an int, a float such as 17.0, a text of digits only), else None (a
    bool, numpy's too, 17.5, NaN, "1_7" or " 17 ", anything ``int`` refuses)."""
    if isinstance(v, (bool, np.bool_)) or (isinstance(v, str) and not (v.isascii() and v.isdigit())):
        return None
    try:
        i = int(v)  # type: ignore[call-overload]
    except (TypeError, ValueError, OverflowError):
        return None
    return i if isinstance(v, str) or i == v else None


# ----------------------------------------------------------------------------------------------
# styles
# ----------------------------------------------------------------------------------------------
_STYLE_TABLE: dict[int, dict] = {
    0: dict(
        counter_h=0.92,
        depth=0.62,
        carcass=(0.35, 0.36, 0.38),
        door=(0.55, 0.56, 0.58),
        top=(0.20, 0.20, 0.22),
        handle="bar",
        handle_rgb=(0.8, 0.8, 0.82),
        floor=((0.45, 0.45, 0.45), (0.40, 0.40, 0.41)),
        wall=(0.75, 0.73, 0.70),
        drawer_h=0.20,
        wall_bottom=1.42,
        width_scale=1.00,
        handle_z=0.5,
        door_hinge=1,
    ),
    1: dict(
        counter_h=0.90,
        depth=0.60,
        carcass=(0.92, 0.92, 0.90),
        door=(0.95, 0.95, 0.93),
        top=(0.78, 0.66, 0.50),
        handle="slim",
        handle_rgb=(0.55, 0.42, 0.30),
        floor=((0.82, 0.74, 0.62), (0.78, 0.70, 0.58)),
        wall=(0.96, 0.96, 0.96),
        drawer_h=0.18,
        wall_bottom=1.40,
        width_scale=0.95,
        handle_z=0.8,
        door_hinge=-1,
    ),
    2: dict(
        counter_h=0.91,
        depth=0.58,
        carcass=(0.70, 0.80, 0.86),
        door=(0.60, 0.74, 0.84),
        top=(0.93, 0.93, 0.90),
        handle="knob",
        handle_rgb=(0.85, 0.85, 0.80),
        floor=((0.85, 0.82, 0.74), (0.70, 0.66, 0.58)),
        wall=(0.90, 0.94, 0.96),
        drawer_h=0.19,
        wall_bottom=1.38,
        width_scale=1.05,
        handle_z=0.6,
        door_hinge=1,
    ),
    3: dict(
        counter_h=0.93,
        depth=0.64,
        carcass=(0.12, 0.12, 0.13),
        door=(0.18, 0.18, 0.19),
        top=(0.88, 0.88, 0.88),
        handle="slim",
        handle_rgb=(0.15, 0.15, 0.15),
        floor=((0.60, 0.60, 0.62), (0.55, 0.55, 0.57)),
        wall=(0.85, 0.85, 0.86),
        drawer_h=0.22,
        wall_bottom=1.45,
        width_scale=1.10,
        handle_z=0.9,
        door_hinge=-1,
    ),
    4: dict(
        counter_h=0.89,
        depth=0.60,
        carcass=(0.45, 0.28, 0.16),
        door=(0.52, 0.33, 0.19),
        top=(0.30, 0.26, 0.22),
        handle="knob",
        handle_rgb=(0.72, 0.60, 0.30),
        floor=((0.55, 0.38, 0.24), (0.48, 0.32, 0.20)),
        wall=(0.92, 0.86, 0.74),
        drawer_h=0.17,
        wall_bottom=1.40,
        width_scale=0.92,
        handle_z=0.5,
        door_hinge=1,
    ),
    5: dict(
        counter_h=0.91,
        depth=0.63,
        carcass=(0.94, 0.93, 0.88),
        door=(0.96, 0.95, 0.90),
        top=(0.45, 0.34, 0.24),
        handle="bar",
        handle_rgb=(0.20, 0.20, 0.20),
        floor=((0.62, 0.48, 0.34), (0.56, 0.42, 0.30)),
        wall=(0.88, 0.90, 0.84),
        drawer_h=0.21,
        wall_bottom=1.44,
        width_scale=1.00,
        handle_z=0.7,
        door_hinge=-1,
    ),
    6: dict(
        counter_h=0.90,
        depth=0.61,
        carcass=(0.40, 0.30, 0.22),
        door=(0.46, 0.35, 0.25),
        top=(0.55, 0.54, 0.52),
        handle="bar",
        handle_rgb=(0.10, 0.10, 0.10),
        floor=((0.42, 0.36, 0.30), (0.36, 0.30, 0.26)),
        wall=(0.80, 0.72, 0.62),
        drawer_h=0.23,
        wall_bottom=1.41,
        width_scale=1.05,
        handle_z=0.5,
        door_hinge=1,
    ),
    7: dict(
        counter_h=0.92,
        depth=0.59,
        carcass=(0.30, 0.45, 0.55),
        door=(0.25, 0.42, 0.55),
        top=(0.95, 0.92, 0.85),
        handle="knob",
        handle_rgb=(0.75, 0.55, 0.25),
        floor=((0.75, 0.45, 0.30), (0.95, 0.90, 0.80)),
        wall=(0.98, 0.95, 0.88),
        drawer_h=0.19,
        wall_bottom=1.39,
        width_scale=0.98,
        handle_z=0.6,
        door_hinge=-1,
    ),
}


def style_params(style_id: int) -> dict:
    """Copy of the style's parameters (colours, dimensions, handle type)."""
    sid = _whole_number(style_id)  # int() read 1.5 (or True) as style 1 without a word
    if sid not in _STYLE_TABLE:
        raise ValueError(f"unknown style_id {style_id!r}; valid ids: {sorted(STYLES)}")
    return dict(_STYLE_TABLE[sid])


# ----------------------------------------------------------------------------------------------
# builder
# ----------------------------------------------------------------------------------------------
def _yaw_quat(yaw: float) -> list[float]:
    return [math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)]


@dataclass
class _Rect:
    """Oriented floor rectangle: centre [2], half sizes [2], yaw."""

    c: np.ndarray
    h: np.ndarray
    yaw: float
    wall: bool = False

    def corners(self) -> np.ndarray:
        """[4,2] world corners, counter-clockwise."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        ex = np.array([c, s]) * self.h[0]
        ey = np.array([-s, c]) * self.h[1]
        return np.stack([self.c - ex - ey, self.c + ex - ey, self.c + ex + ey, self.c - ex + ey])


class _Builder:
    """Adds kitchen bodies to a robot MjSpec. All geoms of the kitchen go to SCENE_GROUP."""

    def __init__(self, spec: mujoco.MjSpec, style: dict, rng: np.random.Generator, style_id: int) -> None:
        self.spec = spec
        self.st = style
        self.rng = rng
        self.rects: list[_Rect] = []
        self.fixtures: dict[str, dict] = {}
        self.excludes: list[tuple[str, str]] = []
        self.n = 0
        self._materials(style_id)

    # -- materials / textures ------------------------------------------------------------
    def _mat(self, name: str, rgb, tex: str | None = None, repeat=(1.0, 1.0), spec_=0.3) -> str:
        m = self.spec.add_material(name=name)
        m.rgba = [rgb[0], rgb[1], rgb[2], 1.0]
        m.specular = spec_
        if tex is not None:
            m.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = tex
            m.texrepeat = list(repeat)
            m.rgba = [1.0, 1.0, 1.0, 1.0]
        return name

    def _materials(self, style_id: int) -> None:
        st = self.st
        f1, f2 = st["floor"]
        t = self.spec.add_texture(name="floor_tex", type=mujoco.mjtTexture.mjTEXTURE_2D)
        t.builtin = mujoco.mjtBuiltin.mjBUILTIN_CHECKER
        t.rgb1, t.rgb2 = list(f1), list(f2)
        t.width = t.height = 256
        t.mark = mujoco.mjtMark.mjMARK_EDGE
        t.markrgb = [0.25, 0.25, 0.25]
        t2 = self.spec.add_texture(name="top_tex", type=mujoco.mjtTexture.mjTEXTURE_2D)
        t2.builtin = mujoco.mjtBuiltin.mjBUILTIN_FLAT
        t2.rgb1 = list(st["top"])
        t2.rgb2 = list(st["top"])
        t2.mark = mujoco.mjtMark.mjMARK_RANDOM
        t2.random = 0.08 + 0.02 * (style_id % 3)
        t2.markrgb = [min(1.0, c + 0.25) for c in st["top"]]
        t2.width = t2.height = 128
        t3 = self.spec.add_texture(name="door_tex", type=mujoco.mjtTexture.mjTEXTURE_2D)
        t3.builtin = mujoco.mjtBuiltin.mjBUILTIN_GRADIENT
        t3.rgb1 = list(st["door"])
        t3.rgb2 = [0.85 * c for c in st["door"]]
        t3.width = t3.height = 64
        self.m_floor = self._mat("floor_mat", f1, "floor_tex", (6.0, 6.0), 0.1)
        self.m_top = self._mat("top_mat", st["top"], "top_tex", (2.0, 2.0), 0.5)
        self.m_carcass = self._mat("carcass_mat", st["carcass"])
        self.m_door = self._mat("door_mat", st["door"], "door_tex", (1.0, 1.0))
        self.m_handle = self._mat("handle_mat", st["handle_rgb"], spec_=0.8)
        self.m_wall = self._mat("wall_mat", st["wall"], spec_=0.05)
        self.m_steel = self._mat("steel_mat", (0.70, 0.71, 0.73), spec_=0.9)
        self.m_dark = self._mat("dark_mat", (0.08, 0.08, 0.09), spec_=0.6)
        self.m_glass = self._mat("glass_mat", (0.15, 0.17, 0.2), spec_=1.0)
        self.m_object = self._mat("object_mat", (0.85, 0.15, 0.12), spec_=0.4)

    # -- primitives -----------------------------------------------------------------------
    def box(self, body, lo, hi, mat: str, name: str | None = None, density: float = 500.0):
        """Axis-aligned (in body frame) box from corner lo [3] to hi [3]."""
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        g = body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=list((hi - lo) / 2), pos=list((hi + lo) / 2))
        g.material = mat
        g.group = SCENE_GROUP
        g.density = density
        if name:
            g.name = name
        return g

    def body(self, parent, name: str, pos, yaw: float = 0.0):
        return parent.add_body(name=name, pos=list(map(float, pos)), quat=_yaw_quat(yaw))

    def handle(self, body, x: float, y: float, z: float, vertical: bool, length: float, name: str):
        """Handle on a front at local x (outer face), centred at (y, z). Returns grasp point (local)."""
        kind = self.st["handle"]
        if kind == "knob":
            self.box(body, [x, y - 0.006, z - 0.006], [x + 0.025, y + 0.006, z + 0.006], self.m_handle)
            g = body.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.018, 0, 0], pos=[x + 0.035, y, z])
            g.material, g.group = self.m_handle, SCENE_GROUP
            if name:
                g.name = name
            return np.array([x + 0.035, y, z])
        thick = 0.008 if kind == "bar" else 0.005
        off = 0.035 if kind == "bar" else 0.025
        half = length / 2
        if vertical:
            self.box(
                body,
                [x + off - thick, y - thick, z - half],
                [x + off + thick, y + thick, z + half],
                self.m_handle,
                name,
            )
            for sz in (-0.8 * half, 0.8 * half):
                self.box(
                    body, [x, y - 0.005, z + sz - 0.005], [x + off - thick, y + 0.005, z + sz + 0.005], self.m_handle
                )
        else:
            self.box(
                body,
                [x + off - thick, y - half, z - thick],
                [x + off + thick, y + half, z + thick],
                self.m_handle,
                name,
            )
            for sy in (-0.8 * half, 0.8 * half):
                self.box(
                    body, [x, y + sy - 0.005, z - 0.005], [x + off - thick, y + sy + 0.005, z + 0.005], self.m_handle
                )
        return np.array([x + off, y, z])

    def _name(self, base: str) -> str:
        self.n += 1
        return f"{base}{self.n}"

    def rect_local(self, origin, yaw, lo, hi, wall: bool = False) -> None:
        """Footprint rectangle given in a module frame (x in [lo0,hi0], y in [lo1,hi1])."""
        c, s = math.cos(yaw), math.sin(yaw)
        cx, cy = (lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2
        wc = np.array([origin[0] + c * cx - s * cy, origin[1] + s * cx + c * cy])
        self.rects.append(_Rect(wc, np.array([(hi[0] - lo[0]) / 2, (hi[1] - lo[1]) / 2]), yaw, wall))

    # -- carcasses ------------------------------------------------------------------------
    def counter_top(self, body, w: float, D: float) -> None:
        H = self.st["counter_h"]
        self.box(body, [-D, -w / 2, H - 0.04], [0.025, w / 2, H], self.m_top)

    def solid_base(self, body, w: float, D: float, fronts: int = 1, drawer_row: bool = True) -> None:
        """Static base cabinet with ``fronts`` decorative doors and, with ``drawer_row``, a drawer row, with handles
        (``fronts`` 0 and no drawer row: the bare carcass front, no handle: a corner filler)."""
        H = self.st["counter_h"]
        self.box(body, [-D, -w / 2, 0.10], [0.0, w / 2, H - 0.04], self.m_carcass)
        self.box(body, [-D, -w / 2, 0.0], [-0.06, w / 2, 0.10], self.m_dark)
        self.counter_top(body, w, D)
        top = H - 0.04
        if drawer_row:
            zc = top - self.st["drawer_h"]
            self.box(body, [0.0, -w / 2 + 0.003, zc + 0.003], [0.02, w / 2 - 0.003, top - 0.003], self.m_door)
            self.handle(body, 0.02, 0.0, (zc + top) / 2, False, min(0.3, 0.5 * w), None)
            top = zc
        fw = w / max(fronts, 1)
        for i in range(fronts):
            y0 = -w / 2 + i * fw
            self.box(body, [0.0, y0 + 0.003, 0.103], [0.02, y0 + fw - 0.003, top - 0.003], self.m_door)
            hy = y0 + (fw - 0.05 if i % 2 == 0 and fronts > 1 else 0.05) if fronts > 1 else y0 + fw - 0.05
            self.handle(body, 0.02, hy, top - 0.12, True, 0.14, None)

    def hollow_base(self, body, w: float, D: float) -> float:
        """Carcass with an open front; returns the top of the carcass box (under the counter)."""
        H = self.st["counter_h"]
        top = H - 0.04
        t = 0.018
        m = self.m_carcass
        self.box(body, [-D, -w / 2, 0.10], [0.0, -w / 2 + t, top], m)
        self.box(body, [-D, w / 2 - t, 0.10], [0.0, w / 2, top], m)
        self.box(body, [-D, -w / 2, 0.10], [-D + t, w / 2, top], m)
        self.box(body, [-D, -w / 2, 0.10], [0.0, w / 2, 0.10 + t], m)
        self.box(body, [-D, -w / 2, 0.0], [-0.06, w / 2, 0.10], self.m_dark)
        self.counter_top(body, w, D)
        return top

    # -- jointed fixtures -----------------------------------------------------------------
    def hinged_door(
        self,
        parent,
        carcass_name: str,
        name: str,
        hinge_local,
        e: int,
        wd: float,
        z0: float,
        z1: float,
        thick: float = 0.02,
        qmax: float = math.pi / 2 + 0.02,
        damping: float = 2.0,
        friction: float = 0.5,
        vertical_handle: bool = True,
    ) -> dict:
        """Door hinged at its side edge ``hinge_local`` (on the front plane), opening outward for q > 0.

        e = +1: hinge on local +y side (door extends toward -y); e = -1 the mirror.
        """
        b = self.body(parent, name, hinge_local)
        jn = f"{name}_hinge"
        b.add_joint(
            name=jn,
            type=mujoco.mjtJoint.mjJNT_HINGE,
            axis=[0, 0, e],
            range=[0.0, qmax],
            damping=damping,
            frictionloss=friction,
            armature=0.02,
        )
        lo_y, hi_y = sorted([-e * 0.004, -e * wd])
        self.box(b, [-thick, lo_y, z0], [0.0, hi_y, z1], self.m_door, f"{name}_panel", density=600.0)
        hz = z0 + (z1 - z0) * (0.25 + 0.5 * self.st["handle_z"])
        hy = -e * (wd - 0.05)
        grasp = self.handle(
            b, 0.0, hy, min(hz, z1 - 0.1), vertical_handle, min(0.16, 0.5 * (z1 - z0)), f"{name}_handle"
        )
        self.excludes.append((carcass_name, name))
        return dict(
            body=name,
            joint=jn,
            e=e,
            width=wd,
            z0=z0,
            z1=z1,
            grasp_local=grasp,
            hinge_local=np.asarray(hinge_local, float),
        )

    # -- modules --------------------------------------------------------------------------
    def module(self, kind: str, origin, yaw: float, w: float, D: float) -> None:
        """One base module with its front-bottom-centre at world ``origin`` and outward normal ``yaw``."""
        name = self._name(f"mod_{kind}_")
        b = self.body(self.spec.worldbody, name, [origin[0], origin[1], 0.0], yaw)
        self.rect_local(origin, yaw, (-D, -w / 2), (0.03, w / 2))
        st = self.st
        if kind == "drawer":
            top = self.hollow_base(b, w, D)
            dh = st["drawer_h"]
            zdiv = top - dh
            self.box(b, [-D, -w / 2, zdiv - 0.018], [0.0, w / 2, zdiv], self.m_carcass)
            db = self.body(b, "drawer_target", [0.0, 0.0, 0.0])
            Db = D - 0.06
            travel = 0.55 * Db
            db.add_joint(
                name="drawer_target_slide",
                type=mujoco.mjtJoint.mjJNT_SLIDE,
                axis=[1, 0, 0],
                range=[0.0, travel],
                damping=40.0,
                frictionloss=4.0,
                armature=0.2,
            )
            self.box(
                db,
                [0.0, -w / 2 + 0.003, zdiv + 0.003],
                [0.02, w / 2 - 0.003, top - 0.003],
                self.m_door,
                "drawer_target_front",
                600.0,
            )
            self.box(
                db, [-Db, -w / 2 + 0.03, zdiv + 0.01], [0.0, w / 2 - 0.03, zdiv + 0.02], self.m_carcass, None, 600.0
            )
            for sy in (-1, 1):
                self.box(
                    db,
                    [-Db, sy * (w / 2 - 0.03) - 0.006, zdiv + 0.01],
                    [0.0, sy * (w / 2 - 0.03) + 0.006, top - 0.04],
                    self.m_carcass,
                    None,
                    600.0,
                )
            self.box(
                db,
                [-Db, -w / 2 + 0.03, zdiv + 0.01],
                [-Db + 0.012, w / 2 - 0.03, top - 0.04],
                self.m_carcass,
                None,
                600.0,
            )
            grasp = self.handle(db, 0.02, 0.0, (zdiv + top) / 2, False, min(0.3, 0.5 * w), "drawer_target_handle")
            self.excludes.append((name, "drawer_target"))
            # lower single door (real hinge, not a task target)
            dn = self._name("door_low_")
            self.hinged_door(
                b,
                name,
                dn,
                [0.02, st["door_hinge"] * (w / 2 - 0.002), 0.0],
                st["door_hinge"],
                w - 0.008,
                0.103,
                zdiv - 0.021,
            )
            c, s = math.cos(yaw), math.sin(yaw)
            zc = (zdiv + top) / 2
            self.fixtures["drawer"] = dict(
                module=name,
                body="drawer_target",
                joint="drawer_target_slide",
                travel=travel,
                width=w,
                front=np.array([origin[0] + 0.02 * c, origin[1] + 0.02 * s, zc]),
                yaw=yaw,
                z0=zdiv,
                z1=top,
                grasp_local=grasp,
                bodies=["drawer_target"],
            )
        elif kind == "double_door":
            top = self.hollow_base(b, w, D)
            wd = w / 2 - 0.006
            left = self.hinged_door(b, name, "ddoor_pos", [0.02, w / 2 - 0.002, 0.0], 1, wd, 0.103, top - 0.003)
            right = self.hinged_door(b, name, "ddoor_neg", [0.02, -w / 2 + 0.002, 0.0], -1, wd, 0.103, top - 0.003)
            c, s = math.cos(yaw), math.sin(yaw)
            self.fixtures["double_door"] = dict(
                module=name,
                doors=[left, right],
                width=w,
                yaw=yaw,
                origin=np.array([origin[0], origin[1]]),
                front=np.array([origin[0] + 0.02 * c, origin[1] + 0.02 * s, (0.103 + top) / 2]),
                bodies=["ddoor_pos", "ddoor_neg"],
            )
        elif kind == "microwave":
            self.solid_base(b, w, D, fronts=2)
            self._microwave(b, origin, yaw, w, D)
        elif kind == "wall_cab":
            self.solid_base(b, w, D, fronts=1)
            self._wall_cab(b, name, origin, yaw, w, D)
        elif kind == "stove":
            self.solid_base(b, w, D, fronts=1, drawer_row=True)
            H = st["counter_h"]
            self.box(b, [-D + 0.04, -w / 2 + 0.02, H], [-0.02, w / 2 - 0.02, H + 0.012], self.m_dark)
            for bx in (-0.17, -0.42):
                for by in (-0.17, 0.17):
                    g = b.add_geom(
                        type=mujoco.mjtGeom.mjGEOM_CYLINDER,
                        size=[0.08, 0.006, 0],
                        pos=[bx * D / 0.6, by * w / 0.76, H + 0.016],
                    )
                    g.material, g.group = self.m_steel, SCENE_GROUP
        elif kind == "sink":
            self.solid_base(b, w, D, fronts=2, drawer_row=False)
            H = st["counter_h"]
            self.box(b, [-D + 0.12, -w / 2 + 0.08, H], [-0.08, w / 2 - 0.08, H + 0.004], self.m_steel)
            self.box(b, [-D + 0.05, -0.015, H], [-D + 0.09, 0.015, H + 0.32], self.m_steel)
            self.box(b, [-D + 0.05, -0.015, H + 0.30], [-D + 0.25, 0.015, H + 0.33], self.m_steel)
        elif kind == "fridge":
            self.box(b, [-0.72, -w / 2 + 0.01, 0.0], [0.0, w / 2 - 0.01, 1.85], self.m_steel)
            self.box(b, [0.0, -w / 2 + 0.01, 0.02], [0.02, w / 2 - 0.01, 1.2], self.m_steel)
            self.box(b, [0.0, -w / 2 + 0.01, 1.22], [0.02, w / 2 - 0.01, 1.83], self.m_steel)
            self.handle(b, 0.02, w / 2 - 0.08, 0.9, True, 0.4, None)
            self.rects.pop()  # replace the base-module footprint by the deeper fridge one
            self.rect_local(origin, yaw, (-0.72, -w / 2), (0.04, w / 2))
        elif kind == "corner":  # a blind filler: the side run stands in front of it (generator 2.3; its handles
            # reached 7-9 mm into the side run's closed doors and drawers, whose contact forces then moved them)
            self.solid_base(b, w, D, fronts=0, drawer_row=False)
        elif kind == "plain":
            self.solid_base(b, w, D, fronts=2 if w > 0.7 else 1, drawer_row=True)
        else:  # a misspelt kind was built as a plain module without a word
            raise ValueError(f"unknown module kind {kind!r}; valid kinds: {sorted(_WIDTHS) + ['corner']}")
        if kind not in ("fridge", "wall_cab", "microwave") and self.rng.random() < 0.6:
            self.static_wall_cab(b, w, D)

    def static_wall_cab(self, body, w: float, D: float) -> None:
        zb = self.st["wall_bottom"] + 0.05
        Dw = 0.34
        self.box(body, [-D, -w / 2, zb], [-D + Dw, w / 2, zb + 0.72], self.m_carcass)
        self.box(body, [-D + Dw, -w / 2 + 0.003, zb + 0.003], [-D + Dw + 0.02, w / 2 - 0.003, zb + 0.717], self.m_door)

    def _microwave(self, b, origin, yaw: float, w: float, D: float) -> None:
        H = self.st["counter_h"]
        Wm, Dm, Hm = 0.56, 0.40, 0.31
        lat = float(self.rng.uniform(-0.5, 0.5) * max(0.0, w - Wm - 0.04))
        x_front = -0.06
        mw = self.body(b, "microwave", [x_front, lat, H])
        m = self.m_steel
        t = 0.015
        self.box(mw, [-Dm, -Wm / 2, 0.0], [0.0, Wm / 2, t], m)
        self.box(mw, [-Dm, -Wm / 2, Hm - t], [0.0, Wm / 2, Hm], m)
        self.box(mw, [-Dm, -Wm / 2, 0.0], [-Dm + t, Wm / 2, Hm], m)
        self.box(mw, [-Dm, -Wm / 2, 0.0], [0.0, -Wm / 2 + t, Hm], m)
        panel = 0.13
        self.box(mw, [-Dm, Wm / 2 - panel, 0.0], [0.0, Wm / 2, Hm], m)
        self.box(mw, [-0.004, Wm / 2 - panel + 0.01, 0.03], [0.002, Wm / 2 - 0.01, Hm - 0.03], self.m_dark)
        wd = Wm - panel - 0.004
        door = self.body(mw, "microwave_door", [0.0, -Wm / 2, 0.0])
        door.add_joint(
            name="microwave_door_hinge",
            type=mujoco.mjtJoint.mjJNT_HINGE,
            axis=[0, 0, -1],
            range=[0.0, 1.75],
            damping=0.6,
            frictionloss=0.25,
            armature=0.01,
        )
        self.box(door, [0.0, 0.004, 0.004], [0.03, wd, Hm - 0.004], self.m_dark, "microwave_door_panel", 400.0)
        self.box(door, [0.03, 0.05, 0.05], [0.032, wd - 0.08, Hm - 0.05], self.m_glass)
        # vertical bar handle near the free edge (viewer's right)
        hy = wd - 0.04
        self.box(door, [0.03, hy - 0.008, 0.06], [0.065, hy + 0.008, 0.08], self.m_handle)
        self.box(door, [0.03, hy - 0.008, Hm - 0.08], [0.065, hy + 0.008, Hm - 0.06], self.m_handle)
        self.box(door, [0.055, hy - 0.01, 0.06], [0.075, hy + 0.01, Hm - 0.06], self.m_handle, "microwave_handle")
        self.excludes.append(("microwave", "microwave_door"))
        c, s = math.cos(yaw), math.sin(yaw)
        hinge_l = np.array([x_front, lat - Wm / 2])
        hinge_w = np.array(
            [origin[0] + c * hinge_l[0] - s * hinge_l[1], origin[1] + s * hinge_l[0] + c * hinge_l[1], H]
        )
        fl = np.array([x_front + 0.03, lat])
        self.fixtures["microwave"] = dict(
            body="microwave_door",
            joint="microwave_door_hinge",
            yaw=yaw,
            hinge=hinge_w,
            e=-1,
            width=wd,
            front=np.array([origin[0] + c * fl[0] - s * fl[1], origin[1] + s * fl[0] + c * fl[1], H + Hm / 2]),
            grasp_local=np.array([0.065, hy, Hm / 2]),
            height=Hm,
            base_z=H,
            bodies=["microwave_door", "microwave"],
        )

    def _wall_cab(self, b, module_name: str, origin, yaw: float, w: float, D: float) -> None:
        st = self.st
        zb = st["wall_bottom"]
        Dw, Hc = 0.36, 0.70
        Wc = min(w, 0.62)
        cab = self.body(b, "wallcab", [-D + Dw, 0.0, zb])
        t = 0.018
        m = self.m_carcass
        self.box(cab, [-Dw, -Wc / 2, 0.0], [0.0, Wc / 2, t], m)
        self.box(cab, [-Dw, -Wc / 2, Hc - t], [0.0, Wc / 2, Hc], m)
        self.box(cab, [-Dw, -Wc / 2, 0.0], [-Dw + t, Wc / 2, Hc], m)
        self.box(cab, [-Dw, -Wc / 2, 0.0], [0.0, -Wc / 2 + t, Hc], m)
        self.box(cab, [-Dw, Wc / 2 - t, 0.0], [0.0, Wc / 2, Hc], m)
        e = -st["door_hinge"]
        door = self.hinged_door(
            cab, "wallcab", "wallcab_door", [0.02, e * (Wc / 2 - 0.002), 0.0], e, Wc - 0.006, 0.003, Hc - 0.003
        )
        c, s = math.cos(yaw), math.sin(yaw)
        fx = -D + Dw + 0.02
        front = np.array([origin[0] + c * fx, origin[1] + s * fx, zb + Hc / 2])
        ix = -D + Dw - Dw / 2
        interior_c = np.array([origin[0] + c * ix, origin[1] + s * ix, zb + Hc / 2])
        # object on the counter in front of the cabinet
        H = st["counter_h"]
        ox, oy = -0.20 - 0.06 * float(self.rng.random()), float(self.rng.uniform(-0.12, 0.12))
        ow = np.array([origin[0] + c * ox - s * oy, origin[1] + s * ox + c * oy])
        half = np.array([0.024, 0.024, 0.045])
        ob = self.spec.worldbody.add_body(
            name="pnp_object", pos=[ow[0], ow[1], H + half[2] + 0.001], quat=_yaw_quat(yaw)
        )
        ob.add_freejoint(name="pnp_object_joint")
        g = ob.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=list(half), name="pnp_object_geom")
        g.material, g.group, g.mass = self.m_object, SCENE_GROUP, 0.15
        g.friction = [1.2, 0.01, 0.001]
        door.update(cabinet="wallcab")
        self.fixtures["wall_cab"] = dict(
            body="wallcab",
            door=door,
            yaw=yaw,
            front=front,
            interior_center=interior_c,
            interior_half=np.array([Dw / 2 - t, Wc / 2 - t, Hc / 2 - t]),
            bottom_z=zb + t,
            object="pnp_object",
            object_half=half,
            bodies=["wallcab", "wallcab_door"],
            counter_h=H,
        )


# ----------------------------------------------------------------------------------------------
# layouts: runs of modules along walls
# ----------------------------------------------------------------------------------------------
_WIDTHS = {
    "drawer": (0.50, 0.60),
    "double_door": (0.78, 0.90),
    "microwave": (0.72, 0.84),
    "wall_cab": (0.64, 0.72),
    "plain": (0.45, 0.75),
    "stove": (0.76, 0.76),
    "sink": (0.80, 0.90),
    "fridge": (0.80, 0.86),
}


def _widths(kinds: list[str], rng: np.random.Generator, scale: float, D: float) -> list[float]:
    out = []
    for k in kinds:
        if k == "corner":
            out.append(D + 0.04)
        else:
            lo, hi = _WIDTHS[k]
            w = float(rng.uniform(lo, hi))
            out.append(w * (scale if k in ("plain", "double_door", "drawer") else 1.0))
    return out


#: gap (m), left empty, between a side run and the back run's front line: flush, a door of the side run opened at
#: the corner, or its drawer pulled out, ran into the fronts and handles of the back run, and the contact forces of
#: the reset state then moved it (generator 2.3)
CORNER_GAP = 0.08


def _plan(layout_id: int, rng: np.random.Generator) -> list[dict]:
    """Runs for a layout family: each {'kinds': [...], 'side': 'back'|'left'|'right'|'front'|'island'|'peninsula'}."""
    fixtures = ["drawer", "double_door", "microwave", "wall_cab"]
    rng.shuffle(fixtures)
    fill = ["plain", "stove", "sink", "plain"]
    rng.shuffle(fill)
    L = int(layout_id)
    if L == 0:  # one wall: everything on the back wall, fridge at one end
        kinds = [fixtures[0], fill[0], fixtures[1], fill[1], fixtures[2], fill[2], fixtures[3]]
        kinds = ["fridge"] + kinds if rng.random() < 0.5 else kinds + ["fridge"]
        return [dict(side="back", kinds=kinds)]
    if L == 1:  # L-shaped: back + left
        return [
            dict(side="back", kinds=["corner", fill[0], fixtures[0], fill[1], fixtures[1], "fridge"]),
            dict(side="left", kinds=[fixtures[2], fill[2], fixtures[3], fill[3]]),
        ]
    if L == 2:  # galley: back + opposite run
        return [
            dict(side="back", kinds=[fill[0], fixtures[0], fill[1], fixtures[1], "fridge"]),
            dict(side="front", kinds=[fixtures[2], fill[2], fixtures[3], fill[3]]),
        ]
    if L == 3:  # U: back + left + right
        return [
            dict(side="back", kinds=["corner", fixtures[0], fill[0], fixtures[1], "corner"]),
            dict(side="left", kinds=[fill[1], fixtures[2]]),
            dict(side="right", kinds=[fixtures[3], fill[2], "fridge"]),
        ]
    if L == 4:  # one wall + island
        kinds = [fixtures[0], fill[0], fixtures[1], fill[1], fixtures[2], fixtures[3], "fridge"]
        return [dict(side="back", kinds=kinds), dict(side="island", kinds=["plain", "sink", "plain"])]
    # G-shaped / wraparound: U + peninsula on the right run
    return [
        dict(side="back", kinds=["corner", fixtures[0], fill[0], fixtures[1], "corner"]),
        dict(side="left", kinds=[fill[1], fixtures[2], "fridge"]),
        dict(side="right", kinds=[fixtures[3], fill[2]]),
        dict(side="peninsula", kinds=["plain", fill[3]]),
    ]


def _build_spec(spec_: SceneSpec) -> tuple[mujoco.MjSpec, dict, list[_Rect], dict]:
    st = style_params(spec_.style_id)
    rng = np.random.default_rng([int(spec_.layout_id), int(spec_.style_id), int(spec_.seed), 7919])
    spec = _robot.robot_spec()
    spec.modelname = f"floaff_L{spec_.layout_id}_S{spec_.style_id}_s{spec_.seed}"
    bld = _Builder(spec, st, rng, int(spec_.style_id))
    D = st["depth"]
    aisle = float(rng.uniform(1.25, 1.65))
    plans = _plan(spec_.layout_id, rng)
    widths = {i: _widths(p["kinds"], rng, st["width_scale"], D) for i, p in enumerate(plans)}
    Lback = sum(widths[0])
    X0 = -Lback / 2  # back run centred on x = 0; back wall at y = 0
    runs = []
    for i, p in enumerate(plans):
        ws, side = widths[i], p["side"]
        L = sum(ws)
        if side == "back":
            start, yaw = np.array([X0, -D]), -math.pi / 2
        elif side == "left":  # ends CORNER_GAP in front of the back run's front line, before its corner filler
            start, yaw = np.array([X0 + D, -D - CORNER_GAP - L]), 0.0
        elif side == "right":
            start, yaw = np.array([X0 + Lback - D, -D - CORNER_GAP]), math.pi
        elif side == "front":
            start, yaw = np.array([X0 + Lback, -D - aisle]), math.pi / 2
        elif side == "island":
            start, yaw = np.array([L / 2, -D - aisle]), math.pi / 2
        else:  # peninsula: attached to the far end of the right run, facing the back wall
            right_len = sum(widths[2])
            start, yaw = np.array([X0 + Lback, -D - CORNER_GAP - right_len]), math.pi / 2
        runs.append((start, yaw, p["kinds"], ws, side))
    for start, yaw, kinds, ws, side in runs:
        n = np.array([math.cos(yaw), math.sin(yaw)])
        u = np.array([-n[1], n[0]])
        s = 0.0
        for k, w in zip(kinds, ws):
            centre = start + (s + w / 2) * u
            bld.module(k, centre, yaw, w, D)
            s += w
        if side == "island":  # back half of the island: a solid block behind the front run
            c = start + (sum(ws) / 2) * u - n * (D + 0.35)
            ib = bld.body(spec.worldbody, bld._name("island_back"), [c[0], c[1], 0.0], yaw)
            bld.box(ib, [-0.35, -sum(ws) / 2, 0.1], [0.35, sum(ws) / 2, st["counter_h"] - 0.04], bld.m_carcass)
            bld.box(ib, [-0.37, -sum(ws) / 2, st["counter_h"] - 0.04], [0.35, sum(ws) / 2, st["counter_h"]], bld.m_top)
            bld.rect_local(c, yaw, (-0.37, -sum(ws) / 2), (0.35, sum(ws) / 2))
        if side in ("back", "left", "right", "front"):
            L = sum(ws)
            wc = start + (L / 2) * u - n * (D + 0.05)
            wb = bld.body(spec.worldbody, bld._name("wall"), [wc[0], wc[1], 0.0], yaw)
            ext = 0.6 if side == "back" else 0.3
            bld.box(wb, [-0.05, -L / 2 - ext, 0.0], [0.05, L / 2 + ext, 2.6], bld.m_wall)
            bld.rect_local(wc, yaw, (-0.05, -L / 2 - ext), (0.05, L / 2 + ext), wall=True)
    floor = spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[8, 8, 0.1], name="floor")
    floor.material, floor.group = bld.m_floor, SCENE_GROUP
    for i, (lx, ly) in enumerate(((0.0, -1.5), (X0, -3.0))):
        light = spec.worldbody.add_light(name=f"light{i}", pos=[lx, ly, 3.0], dir=[0, 0.2, -1])
        light.castshadow = False
        light.diffuse = [0.55, 0.55, 0.55]
        light.specular = [0.1, 0.1, 0.1]
    # grasp assist constraints (inactive until a scripted grasp succeeds, see controllers.py)
    weld = spec.add_equality(
        name="assist_object",
        type=mujoco.mjtEq.mjEQ_WELD,
        objtype=mujoco.mjtObj.mjOBJ_BODY,
        name1=_robot.HAND_BODY,
        name2="pnp_object",
    )
    weld.active = False
    conn = spec.add_equality(
        name="assist_door",
        type=mujoco.mjtEq.mjEQ_CONNECT,
        objtype=mujoco.mjtObj.mjOBJ_BODY,
        name1=_robot.HAND_BODY,
        name2="microwave_door",
    )
    conn.active = False
    for door in ("ddoor_pos", "ddoor_neg"):
        eqd = spec.add_equality(
            name=f"assist_{door}",
            type=mujoco.mjtEq.mjEQ_CONNECT,
            objtype=mujoco.mjtObj.mjOBJ_BODY,
            name1=_robot.HAND_BODY,
            name2=door,
        )
        eqd.active = False
    for a, bname in bld.excludes:
        spec.add_exclude(bodyname1=a, bodyname2=bname)
    meta = dict(style=st, aisle=aisle, plans=plans)
    return spec, bld.fixtures, bld.rects, meta


# ----------------------------------------------------------------------------------------------
# compiled scene
# ----------------------------------------------------------------------------------------------
class SimScene:
    """A compiled kitchen + robot: model, data, target, collision helpers.

    Attributes: spec (SceneSpec), model, data, target (TargetInfo), robot (robot.RobotIndex),
    scene_geom_ids / robot_geom_ids (int arrays), floor_geom_id, fixtures (dict of raw fixture info).
    """

    def __init__(self, spec: SceneSpec, model: mujoco.MjModel, fixtures: dict, rects: list[_Rect], meta: dict) -> None:
        self.spec = spec
        self.model = model
        self.data = mujoco.MjData(model)
        self.fixtures = fixtures
        self.meta = meta
        self._rects = rects
        self.robot = _robot.RobotIndex.from_model(model)
        self.robot_geom_ids = self.robot.geom_ids
        robot_bodies = set(self.robot.body_ids.tolist())
        self.floor_geom_id = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, "floor")
        self.scene_geom_ids = np.array(
            [g for g in range(model.ngeom) if model.geom_bodyid[g] not in robot_bodies], dtype=np.int64
        )
        self._scene_mask = np.zeros(model.ngeom, dtype=bool)
        self._scene_mask[self.scene_geom_ids] = True
        self._scene_mask[self.floor_geom_id] = False
        self._robot_mask = np.zeros(model.ngeom, dtype=bool)
        self._robot_mask[self.robot_geom_ids] = True
        self.task = TASK_REGISTRY[spec.task]
        self.target = self.task.target_info(self)
        self._rect_corners = [r.corners() for r in rects]
        self._wall_corners = [r.corners() for r in rects if r.wall]
        self.robot.set_base_pose(self.data, *PARK_POSE)
        self.reset_task(None)

    # -- state -----------------------------------------------------------------------------
    def reset_task(self, rng: np.random.Generator | None = None) -> None:
        """mj_resetData, robot tucked at its current base pose, task reset state (rng=None: deterministic midpoint)."""
        if rng is not None and not isinstance(rng, np.random.Generator):  # a seed failed in the task, or was ignored
            raise TypeError(f"reset_task: rng must be a numpy Generator or None, got {type(rng).__name__}")
        pose = self.base_pose()
        mujoco.mj_resetData(self.model, self.data)
        self.robot.set_base_pose(self.data, *pose)
        self.robot.set_tuck(self.data)
        self.task.reset(self, rng)
        mujoco.mj_forward(self.model, self.data)

    def set_base_pose(self, x: float, y: float, yaw: float) -> None:
        """Teleport the base origin to (x, y, yaw) (yaw pivot compensated); runs mj_kinematics. A non-finite pose raises
        ``ValueError`` (it was written into qpos: the robot and its ego camera were posed at NaN)."""
        x, y, yaw = check_pose((x, y, yaw), "set_base_pose")
        self.robot.set_base_pose(self.data, x, y, yaw)
        mujoco.mj_kinematics(self.model, self.data)

    def base_pose(self) -> tuple[float, float, float]:
        return self.robot.base_pose(self.data)

    # -- collision ---------------------------------------------------------------------------
    def robot_collides(self, margin: float = 0.0) -> bool:
        """True if robot collision geoms (base, torso, arm, gripper as posed now) touch scene geoms.

        The floor is excluded. ``margin`` > 0 also reports pairs closer than margin (m); a NaN or negative one is a
        ValueError.
        """
        # a NaN margin reported no collision at any pose, a negative one let the robot sink that deep into furniture
        check_number("margin", margin, owner="SimScene.robot_collides")
        m, d = self.model, self.data
        ids = self.robot_geom_ids
        old = m.geom_margin[ids].copy()
        if margin > 0:
            m.geom_margin[ids] = margin
        try:
            mujoco.mj_kinematics(m, d)
            mujoco.mj_collision(m, d)
        finally:
            m.geom_margin[ids] = old
        return self._touching(self._robot_mask, self._scene_mask, margin)

    def part_overlaps(self, part: np.ndarray, depth: float) -> bool:
        """True if a geom of ``part`` (bool [ngeom]: a door and its handle, say), as posed now, reaches deeper than
        ``depth`` (m) into another scene geom; the robot and the floor do not count. A NaN or negative depth, or a
        ``part`` that is no bool [ngeom] mask, raises ``ValueError`` (a NaN depth reported no overlap at any opening; an
        int mask indexed geoms 0 and 1 instead, a short one failed in numpy naming neither)."""
        check_number("depth", depth, owner="SimScene.part_overlaps")
        part = np.asarray(part)
        if part.dtype != np.bool_ or part.shape != (self.model.ngeom,):
            raise ValueError(
                f"SimScene.part_overlaps: part must be a bool [ngeom] = [{self.model.ngeom}] geom mask, got "
                f"{part.dtype} {part.shape}"
            )
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_collision(self.model, self.data)
        return self._touching(part, self._scene_mask & ~part, -depth)

    def _touching(self, a: np.ndarray, b: np.ndarray, below: float) -> bool:
        """True if the last collision pass holds a contact closer than ``below`` (m; < 0: that deep) between a geom of
        mask ``a`` and one of mask ``b`` (bool [ngeom] each)."""
        d = self.data
        n = d.ncon
        if n == 0:
            return False
        g1, g2 = d.contact.geom1[:n], d.contact.geom2[:n]
        pair = (a[g1] & b[g2]) | (a[g2] & b[g1])
        return bool((pair & (d.contact.dist[:n] < below)).any())

    def robot_contacts(self) -> list[tuple[str, str, float]]:
        """Robot-scene contacts as posed now, by name: (robot body, scene body, distance m < 0), deepest first.

        The pairs ``robot_collides`` reduces to a bool (floor excluded); for tracing why a pose or a rollout failed.
        """
        m, d = self.model, self.data
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        out = []
        for k in range(d.ncon):
            g1, g2, dist = int(d.contact.geom1[k]), int(d.contact.geom2[k]), float(d.contact.dist[k])
            if self._robot_mask[g2] and self._scene_mask[g1]:
                g1, g2 = g2, g1
            if dist >= 0 or not (self._robot_mask[g1] and self._scene_mask[g2]):
                continue
            names = (mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.geom_bodyid[g])) for g in (g1, g2))
            out.append((*(n or "?" for n in names), dist))
        return sorted(out, key=lambda c: c[2])

    def footprint_free(self, x: float, y: float, yaw: float) -> bool:
        """N2M footprint (0.63 x 0.5 m, 0.83 L behind / 0.17 L in front of the origin) vs furniture/wall footprints.

        A non-finite pose raises ``ValueError`` (the overlap test found no separating axis for it: "not free")."""
        x, y, yaw = check_pose((x, y, yaw), "footprint_free")
        c, s = math.cos(yaw), math.sin(yaw)
        cx = 0.5 * (_robot.FOOTPRINT_FRONT - _robot.FOOTPRINT_BACK)
        fp = _Rect(
            np.array([x + c * cx, y + s * cx]), np.array([_robot.FOOTPRINT_LENGTH / 2, _robot.FOOTPRINT_WIDTH / 2]), yaw
        )
        fc = fp.corners()
        for rc in self._rect_corners:
            if _sat_overlap(fc, rc):
                return False
        return True

    def wall_between(self, x: float, y: float, point_xy) -> bool:
        """True if the floor segment from (x, y) to point_xy [2] crosses a wall footprint (the pose is outside the
        room). A non-finite point raises ``ValueError`` (the overlap test found no separating axis for it: a wall)."""
        a = np.array([float(x), float(y)])
        b = np.asarray(point_xy, dtype=np.float64)
        b = b[:2] if b.ndim == 1 else b.reshape(-1)[:0]  # [1] or [2,2] failed in numpy's stack naming neither
        if not (np.isfinite(a).all() and b.shape == (2,) and np.isfinite(b).all()):
            raise ValueError(f"wall_between: the segment must be finite, got {a.tolist()} -> {b.tolist()}")
        seg = np.stack([a, b, b, a])  # degenerate quad: the SAT test works on the segment
        return any(_sat_overlap(seg, rc) for rc in self._wall_corners)

    def floor_outline(self) -> list[np.ndarray]:
        """Furniture/wall footprints as [4,2] world polygons (for top-down pictures / occupancy)."""
        return [c.copy() for c in self._rect_corners]


def _sat_overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Separating-axis test for two convex quads [4,2] (a degenerate quad, e.g. a segment, is allowed)."""
    for poly in (a, b):
        for i in range(4):
            e = poly[(i + 1) % 4] - poly[i]
            if abs(e[0]) + abs(e[1]) < 1e-12:
                continue
            ax = np.array([-e[1], e[0]])
            pa = a @ ax
            pb = b @ ax
            if pa.max() <= pb.min() + 1e-9 or pb.max() <= pa.min() + 1e-9:
                return False
    return True


#: compiled kitchens kept per process (least recently used dropped first): each holds ~70 MB and compiles again in
#: ~0.1 s to the same model, so a long rollout service over many scenes must not keep every one it ever built
CACHE_SIZE = 8
_CACHE: dict[tuple[int, int, int], tuple[mujoco.MjModel, dict, list[_Rect], dict]] = {}
_LOCK = threading.Lock()


def lru_put(cache: dict[Any, Any], key: Any, value: Any, size: int) -> None:
    """``cache[key] = value`` as its most recently used entry; the least recently used ones beyond ``size`` are
    dropped (a dict keeps insertion order, so its first key is the one used longest ago)."""
    cache.pop(key, None)
    cache[key] = value
    while len(cache) > max(1, size):
        del cache[next(iter(cache))]


def compile_scene(spec: SceneSpec) -> tuple[mujoco.MjModel, dict, list[_Rect], dict]:
    """Compiled model + fixture info for a spec (cached per process, the last ``CACHE_SIZE`` kitchens)."""
    if not isinstance(spec, SceneSpec):  # a dict failed with an AttributeError on ``layout_id``
        raise TypeError(f"compile_scene expects a SceneSpec, got {type(spec).__name__}")
    with _LOCK:
        key = kitchen_key(spec)
        hit = _CACHE.get(key)
        if hit is None:
            mspec, fixtures, rects, meta = _build_spec(SceneSpec(key[0], key[1], key[2], TASKS[0]))
            model = mspec.compile()
            hit = (model, fixtures, rects, meta)
        lru_put(_CACHE, key, hit, CACHE_SIZE)
        return hit


def kitchen_key(spec: SceneSpec) -> tuple[int, int, int]:
    """(layout, style, seed): what names a compiled kitchen; the kitchen does not depend on the task (only target and
    reset do), so the scenes of every task in it share one model."""
    return int(spec.layout_id), int(spec.style_id), int(spec.seed)


def release_scene(spec: SceneSpec) -> None:
    """Drop the compiled model of ``spec``'s kitchen from the per-process cache (its built scenes keep theirs)."""
    if not isinstance(spec, SceneSpec):  # a dict or a scene id failed with an AttributeError on ``layout_id``
        raise TypeError(f"release_scene expects a SceneSpec, got {type(spec).__name__}")
    with _LOCK:
        _CACHE.pop(kitchen_key(spec), None)


def build_scene(spec: SceneSpec) -> SimScene:
    """Build (or fetch the cached compiled model of) a scene; returns a fresh SimScene in the task's reset state."""
    if not isinstance(spec, SceneSpec):
        raise TypeError(f"build_scene expects a SceneSpec, got {type(spec).__name__}")
    model, fixtures, rects, meta = compile_scene(spec)
    return SimScene(spec, model, fixtures, rects, meta)
