"""Observed floor cells: the floor queries a robot can ask from its own view (numpy only, no torch).

One home for the rule shared by the benchmark generator (``floaff_zoo.sim``, format v2 view floor points) and by the
predict API's default floor queries (``floaff_zoo.predict``), so that a model is asked the same kind of cells at
deployment as in its data:

* a **ground point** is an observed point with z < :data:`FLOOR_Z_MAX` (robot base frame or world, floor at z = 0):
  MoMa-Kitchen's floor points are the points below 2 cm;
* a :class:`FloorLattice` is a square raster of ``cell`` m cells, centred on a point (the target's floor projection)
  and turned by ``angle``; the generator's lattice is exactly the annotation grid (``annotate.candidate_grid``);
* a cell is **observed** when at least ``min_points`` ground points fall into its square.

Nothing here needs privileged (simulator) information: the point cloud, a centre and an orientation are enough.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from floaff_zoo.checks import check_integer, check_number, check_numbers

__all__ = [
    "CANDIDATE_WINDOW",
    "FLOOR_Z_MAX",
    "FOOTPRINT",
    "FloorLattice",
    "check_footprint",
    "check_z_range",
    "footprint_blocked",
    "footprint_coverage",
    "grown_footprint",
    "ground_mask",
    "observed_cells",
]

#: metres: points below this height are ground points (MoMa-Kitchen: "points below 2 cm")
FLOOR_Z_MAX = 0.02
#: (r_x, r_y) m: the generated benchmark's label window around the target, |x°| <= r_x along the front and
#: |y°| <= r_y along its normal (every task's ``floaff_zoo.sim.tasks.Task.r_x / r_y``; a test keeps them equal)
CANDIDATE_WINDOW = (1.0, 1.2)
#: (length, width, front) m: the mobile base's footprint (N2M's 0.63 x 0.5 m), ``front`` of its length ahead of the
#: base origin along the heading, the rest behind (the simulated robot's, ``floaff_zoo.sim.robot``; a test keeps
#: them equal)
FOOTPRINT = (0.63, 0.50, 0.17 * 0.63)


@dataclass(frozen=True)
class FloorLattice:
    """A square floor raster. Cell (i, j), i in [-ny, ny], j in [-nx, nx], has its centre at
    ``centre + j * cell * u + i * cell * v`` with ``u = (cos angle, sin angle)`` and ``v`` = u turned by +90 deg.

    Flat cell index = ``(i + ny) * (2 nx + 1) + (j + nx)`` (row-major (i, j)): the order of the annotation grid, whose
    lattice is :meth:`target_window` (x° along u, y° along v).
    """

    centre: tuple[float, float]
    angle: float
    cell: float
    half: tuple[int, int]  # (ny, nx)

    def __post_init__(self) -> None:
        if not (self.cell > 0 and math.isfinite(self.cell)):
            raise ValueError(f"FloorLattice: cell must be a finite value > 0, got {self.cell}")
        half = np.asarray(self.half)
        if half.shape != (2,) or half.dtype.kind not in "iu":
            # (1.5, 2) made a lattice of 4.0 rows whose centres sat half a cell off its centre, without a word
            raise ValueError(f"FloorLattice: half must be two integers (ny, nx), got {self.half!r}")
        if half.min() < 0:
            raise ValueError(f"FloorLattice: half sizes (ny, nx) must be >= 0, got {self.half}")
        if np.shape(self.centre) != (2,):  # one value broadcast as (c, c), three failed far off in centers()
            raise ValueError(f"FloorLattice: centre must be two values (x, y), got {self.centre!r}")
        if not (np.isfinite(self.centre).all() and math.isfinite(self.angle)):
            raise ValueError(f"FloorLattice: centre {self.centre} and angle {self.angle} must be finite")

    @classmethod
    def target_window(
        cls, target_xy: np.ndarray, target_yaw: float, cell: float, r_x: float, r_y: float
    ) -> FloorLattice:
        """The annotation grid: target-centred, |x°| <= r_x, |y°| <= r_y, front (outward normal ``target_yaw``)
        along -y° (``floaff_zoo.sim.views`` target frame), so u = normal turned by +90 deg and v = -normal."""
        ny, nx = math.floor(r_y / cell + 1e-9), math.floor(r_x / cell + 1e-9)
        t = np.asarray(target_xy, dtype=np.float64).reshape(-1)[:2]
        return cls((float(t[0]), float(t[1])), float(target_yaw) + math.pi / 2, float(cell), (ny, nx))

    @classmethod
    def around(cls, centre_xy: np.ndarray, angle: float, cell: float, radius: float) -> FloorLattice:
        """The smallest lattice covering the disc of ``radius`` around ``centre_xy`` (use :meth:`within` to cut it)."""
        n = math.floor(radius / cell + 1e-9)
        c = np.asarray(centre_xy, dtype=np.float64).reshape(-1)[:2]
        return cls((float(c[0]), float(c[1])), float(angle), float(cell), (n, n))

    @property
    def shape(self) -> tuple[int, int]:
        """(rows H, columns W)."""
        return 2 * self.half[0] + 1, 2 * self.half[1] + 1

    def _axes(self) -> tuple[np.ndarray, np.ndarray]:
        u = np.array([math.cos(self.angle), math.sin(self.angle)])
        return u, np.array([-u[1], u[0]])

    def centers(self) -> np.ndarray:
        """Cell centres [H*W, 2] in flat index order."""
        ny, nx = self.half
        ii, jj = np.meshgrid(np.arange(-ny, ny + 1), np.arange(-nx, nx + 1), indexing="ij")
        u, v = self._axes()
        loc = np.stack([jj.ravel(), ii.ravel()], axis=1) * self.cell  # [M, 2] (along u, along v)
        return np.asarray(self.centre) + loc[:, :1] * u + loc[:, 1:] * v

    def index_of(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points [K, 2+] -> (flat cell index [K] int64, inside [K] bool); the index is -1 outside the lattice."""
        p = np.asarray(xy, dtype=np.float64)
        p = p.reshape(-1, p.shape[-1])[:, :2] - np.asarray(self.centre)
        u, v = self._axes()
        j = np.floor(p @ u / self.cell + 0.5).astype(np.int64)
        i = np.floor(p @ v / self.cell + 0.5).astype(np.int64)
        ny, nx = self.half
        inside = (np.abs(i) <= ny) & (np.abs(j) <= nx)
        flat = np.where(inside, (i + ny) * (2 * nx + 1) + (j + nx), -1)
        return flat, inside

    def within(self, radius: float) -> np.ndarray:
        """bool [H*W]: cell centres within ``radius`` of the lattice centre."""
        d = self.centers() - np.asarray(self.centre)
        return np.hypot(d[:, 0], d[:, 1]) <= radius + 1e-9


def points_n3(xyz: np.ndarray, who: str) -> np.ndarray:
    """``xyz`` as float64 [N, 3]; ValueError naming ``who`` otherwise (a reshape read a [3, N] or [N, 2] array as
    other points without a word)."""
    p = np.asarray(xyz, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"{who}: xyz must be [N, 3], got {list(p.shape)}")
    return p


def check_pose(pose: Any, who: str, what: str = "pose") -> tuple[float, float, float]:
    """A robot base pose ``pose`` as three finite floats (x, y, yaw); ValueError naming ``who`` (the caller) and
    ``what`` (its argument) otherwise. The one check of a base pose, the simulator's included: a NaN pose put no
    point inside the footprint (called it free), was reported ``filtered_collision`` by the rollout's filter, and
    was written into the robot's qpos."""
    try:
        p = np.asarray(pose, dtype=np.float64).reshape(-1)
        if any(isinstance(v, (bool, np.bool_)) for v in np.asarray(pose, dtype=object).reshape(-1)):
            p = np.empty(0)  # True is not x = 1 m: a flag passed where the pose belongs
    except (TypeError, ValueError):  # not numbers (a string, a ragged list): named like any other bad pose
        p = np.empty(0)
    if p.size != 3 or not np.isfinite(p).all():
        raise ValueError(f"{who}: {what} must be 3 finite values (x, y, yaw), got {pose!r}")
    return float(p[0]), float(p[1]), float(p[2])


def ground_mask(xyz: np.ndarray, z_max: float = FLOOR_Z_MAX) -> np.ndarray:
    """Points [N, 3] (floor at z = 0) -> bool [N]: ground points (z < z_max, finite)."""
    p = points_n3(xyz, "ground_mask")
    return np.isfinite(p).all(axis=1) & (p[:, 2] < z_max)


def observed_cells(
    xyz: np.ndarray, lattice: FloorLattice, z_max: float = FLOOR_Z_MAX, min_points: int = 1
) -> np.ndarray:
    """Cells of ``lattice`` that hold at least ``min_points`` ground points of the cloud.

    Args:
        xyz: [N, 3] observed points in the lattice's frame (z up, floor at z = 0).
        lattice: the raster; z_max: ground height threshold (m); min_points: >= 1.
    Returns:
        bool [H*W] in the lattice's flat index order.
    """
    if min_points < 1:
        raise ValueError(f"observed_cells: min_points must be >= 1, got {min_points}")
    p = points_n3(xyz, "observed_cells")
    flat, inside = lattice.index_of(p[ground_mask(p, z_max)])
    h, w = lattice.shape
    return np.bincount(flat[inside], minlength=h * w) >= min_points


def grown_footprint(margin: float, footprint: tuple[float, float, float] = FOOTPRINT) -> tuple[float, float, float]:
    """``footprint`` (length, width, front) m grown by ``margin`` m on every side: a clearance around the base."""
    check_number("margin", margin, owner="grown_footprint")  # a text failed in math.isfinite naming nothing
    check_footprint("grown_footprint", footprint)
    length, width, front = footprint
    return (length + 2 * margin, width + 2 * margin, front + margin)


def check_footprint(owner: str, footprint: object) -> None:
    """ValueError naming ``owner`` unless ``footprint`` is (length > 0, width > 0, front) finite m: a NaN or negative
    size put no point inside the base (every pose free)."""
    if not (isinstance(footprint, (tuple, list)) and len(footprint) == 3):
        raise ValueError(f"{owner}: footprint must be (length, width, front) m, got {footprint!r}")
    check_numbers({"footprint length": footprint[0], "footprint width": footprint[1]}, strict=True, owner=owner)
    check_number("footprint front", footprint[2], low=-math.inf, owner=owner)


def check_z_range(owner: str, z_range: object) -> None:
    """ValueError naming ``owner`` unless ``z_range`` is (low, high) finite m with low < high: an empty or NaN range
    counted no obstacle point (every pose free)."""
    if not (isinstance(z_range, (tuple, list)) and len(z_range) == 2):
        raise ValueError(f"{owner}: z_range must be (low, high) m, got {z_range!r}")
    check_numbers({"z_range low": z_range[0], "z_range high": z_range[1]}, low=-math.inf, owner=owner)
    if not z_range[0] < z_range[1]:
        raise ValueError(f"{owner}: z_range must have low < high, got {tuple(z_range)}")


def footprint_blocked(
    xyz: np.ndarray,
    pose: tuple[float, float, float],
    footprint: tuple[float, float, float] = FOOTPRINT,
    z_range: tuple[float, float] = (FLOOR_Z_MAX, 1.2),
    min_points: int = 2,
) -> bool:
    """Whether the observed cloud puts an obstacle where the base would stand: from the view alone.

    Args:
        xyz: [N, 3] observed points (floor at z = 0), same frame as ``pose``.
        pose: (x, y, yaw) of the base origin, heading ``yaw``.
        footprint: (length, width, front) of the base rectangle (``FOOTPRINT``).
        z_range: heights (m) of points that block the base: above the floor, below the tucked robot's top.
        min_points: distinct points inside the rectangle needed to call it blocked (a stray point is noise; a
            cloud padded to its sample size by repeating points must not make one point two).
    Returns:
        True when at least ``min_points`` distinct points with z in ``z_range`` lie inside the footprint. Unseen
        (occluded) space counts as free: the cloud can only rule a pose out.
    """
    p = points_n3(xyz, "footprint_blocked")
    pose = check_pose(pose, "footprint_blocked")
    check_footprint("footprint_blocked", footprint)
    check_z_range("footprint_blocked", z_range)
    check_integer("min_points", min_points, 1, owner="footprint_blocked")
    p = p[np.isfinite(p).all(axis=1) & (p[:, 2] > z_range[0]) & (p[:, 2] <= z_range[1])]
    inside = _footprint_frame(p, pose, footprint)[0]
    # distinct 3-D points: points stacked at one (x, y) are several obstacles, one point repeated is one
    return int(inside.sum()) >= min_points and len(np.unique(p[inside], axis=0)) >= min_points


def _footprint_frame(
    p: np.ndarray, pose: tuple[float, float, float], footprint: tuple[float, float, float]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(inside [N] bool, along [N], across [N]) for the points p [N, 3] and the base footprint parked at ``pose``:
    which points lie inside it, and each point's offset (m) along the heading and across it from the base origin."""
    length, width, front = footprint
    x, y, yaw = (float(v) for v in pose)
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = p[:, 0] - x, p[:, 1] - y
    along, across = c * dx + s * dy, -s * dx + c * dy
    return (along <= front) & (along >= front - length) & (np.abs(across) <= width / 2), along, across


def _in_footprint(p: np.ndarray, pose: tuple[float, float, float], footprint: tuple[float, float, float]) -> np.ndarray:
    """[K, 2] (along the heading from the footprint's back edge, across from its left edge) m of the points of
    p [N, 3] inside the base footprint parked at ``pose``."""
    length, width, front = footprint
    inside, along, across = _footprint_frame(p, pose, footprint)
    return np.stack([along[inside] - (front - length), across[inside] + width / 2], axis=1)


def footprint_coverage(
    xyz: np.ndarray,
    pose: tuple[float, float, float],
    footprint: tuple[float, float, float] = FOOTPRINT,
    cell: float = 0.1,
) -> float:
    """How much of the base footprint the observed cloud shows: the share of its ``cell`` m sub-squares holding a point.

    ``footprint_blocked`` can only rule a pose out; a footprint the view barely sees (occluded, or out of the
    camera's field) is free by default, and over the benchmark's candidate cells such footprints stand over furniture
    the view missed more often than well-seen ones (``scripts/coverage_reasons.py``). This measures what the view
    knows: floor and obstacle points (any height) both count as seen.

    Args:
        xyz: [N, 3] observed points, same frame as ``pose``; pose: (x, y, yaw) of the base origin;
        footprint: (length, width, front) (``FOOTPRINT``); cell: side (m) of the sub-squares.
    Returns:
        Share in [0, 1] of the ceil(length / cell) x ceil(width / cell) sub-squares with at least one point.
    """
    p = points_n3(xyz, "footprint_coverage")
    pose = check_pose(pose, "footprint_coverage")
    check_footprint("footprint_coverage", footprint)
    check_number("cell", cell, strict=True, owner="footprint_coverage")
    local = _in_footprint(p[np.isfinite(p).all(axis=1)], pose, footprint)
    length, width, _ = footprint
    na, nw = math.ceil(length / cell - 1e-9), math.ceil(width / cell - 1e-9)
    ia = np.clip((local[:, 0] / cell).astype(int), 0, na - 1)
    iw = np.clip((local[:, 1] / cell).astype(int), 0, nw - 1)
    return float(np.unique(ia * nw + iw).size) / (na * nw)
