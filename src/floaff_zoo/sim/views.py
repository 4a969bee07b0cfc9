"""Egocentric observation views around a manipulation target (paper appendix, "Multi-View Observation Collection").

Target frame (x^o, y^o): origin at the target's floor projection c, the target's FRONT (its outward normal, world yaw
``target.yaw``) points along -y^o, x^o is the lateral axis (outward normal rotated by +90 deg). View regions:

    V_front = {|x^o| < r_f^x, y^o < -r_f^y}        V_side = {|x^o| > r_s^x, |y^o| < r_s^y}

both capped at ``max_dist`` from c (tested on the base origin, not the camera). A view pose is collision-free
(``scene.footprint_free`` and ``robot_collides``), heads toward the target, has no wall between base and target
(``scene.wall_between``, as the annotation's pose filter) and its ego camera clear of every scene geom by the near
clipping plane (:func:`view_pose_clear`, generator 2.2), and its stored (subsampled) cloud must hold at least
``min_target_pixels`` target points.

Robot base frame: origin at the base pose (x, y) on the floor, x forward (yaw), y left, z up, floor at z = 0.
Every view of a scene shares the scene's per-cell floor labels; since format v2 each view stores the label-grid cells
its own cloud observes as ground (``floaff_zoo.floor.observed_cells``), so views differ in which cells they hold.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np

from floaff_zoo.checks import check_flag, check_integer, check_number, check_numbers
from floaff_zoo.floor import check_pose
from floaff_zoo.sim.presets import check_view_regions
from floaff_zoo.sim.render import Renderer, backproject, near_clip

__all__ = [
    "EGO_CAMERA",
    "ROBOT_DESCRIPTOR",
    "ViewConfig",
    "ViewObservation",
    "base_to_world",
    "camera_clearance",
    "candidates_in_target_frame",
    "heading_to",
    "in_front_region",
    "in_side_region",
    "make_view_sample",
    "render_view",
    "sample_view_poses",
    "target_to_world",
    "view_pose_clear",
    "world_to_base",
    "world_to_target",
    "wrap_angle",
]

EGO_CAMERA = "floaff_ego"
# [arm reach m, base height m] of the PandaOmron-like robot: MoMa-Kitchen's robot descriptor (docs/background.md §1.1)
ROBOT_DESCRIPTOR = np.array([0.85, 1.03], dtype=np.float32)

ViewKind = Literal["front", "side"]


@dataclass
class ViewConfig:
    """Where views are sampled and how they are rendered.

    front_rx/front_ry = r_f^x, r_f^y; side_rx/side_ry = r_s^x, r_s^y (m, paper values unknown: chosen so the robot
    footprint fits in front of a counter and the target stays in the ego camera's field of view).
    """

    front_rx: float = 0.45
    front_ry: float = 0.55
    side_rx: float = 0.75
    side_ry: float = 0.9
    max_dist: float = 2.4
    image_size: int = 128
    depth_max: float = 4.0
    max_points: int = 8192
    min_target_pixels: int = 4
    max_tries_per_view: int = 60
    hide_robot: bool = True

    def __post_init__(self) -> None:
        # as GenPreset checks its copies: a NaN region or depth_max, or a negative max_tries_per_view, sampled no view
        # without a word; a negative max_points failed mid-render with numpy's "negative dimensions"
        check_numbers({k: getattr(self, k) for k in ("front_rx", "front_ry", "side_rx", "side_ry")}, owner="ViewConfig")
        check_number("max_dist", self.max_dist, strict=True, owner="ViewConfig")
        check_number("depth_max", self.depth_max, strict=True, owner="ViewConfig")
        check_view_regions(self.front_rx, self.front_ry, self.side_rx, self.side_ry, self.max_dist, "ViewConfig")
        # the text "no" hid the robot
        check_flag("hide_robot", self.hide_robot, owner="ViewConfig")
        for name in ("image_size", "max_points", "max_tries_per_view"):
            check_integer(name, getattr(self, name), 1, owner="ViewConfig")
        # as GenPreset: 0 stored views whose cloud shows no target point, which the models and predict need
        check_integer("min_target_pixels", self.min_target_pixels, 1, owner="ViewConfig")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class ViewObservation:
    """One rendered view, already in the robot base frame.

    scene_xyz [N,3] f32, scene_feat [N,4] f32 (flag, r, g, b in [0,1]), rgb [H,W,3] u8, depth [H,W] f32,
    n_target int (target points kept).
    """

    scene_xyz: np.ndarray
    scene_feat: np.ndarray
    rgb: np.ndarray
    depth: np.ndarray
    n_target: int


# ---------------------------------------------------------------------------------------------------- frames
def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    """Wrap angles to [-pi, pi) (arrays stay arrays, scalars become float)."""
    if isinstance(a, np.ndarray):
        return (a + np.pi) % (2.0 * np.pi) - np.pi
    return (float(a) + math.pi) % (2.0 * math.pi) - math.pi


def world_to_target(xy: np.ndarray, target_xy: np.ndarray, target_yaw: float) -> np.ndarray:
    """World xy [K,2] -> target frame (x^o, y^o) [K,2]; the target's front direction maps to -y^o."""
    d = np.asarray(xy, dtype=np.float64).reshape(-1, 2) - np.asarray(target_xy, dtype=np.float64)[:2]
    n = np.array([math.cos(target_yaw), math.sin(target_yaw)])  # outward normal
    lat = np.array([-n[1], n[0]])  # normal rotated +90 deg
    return np.stack([d @ lat, -(d @ n)], axis=-1)


def candidates_in_target_frame(scene: dict) -> np.ndarray:
    """A scene record's (``scene.json``) candidate cells in its target frame, [M, 2] (analysis of the labels)."""
    cand, target = scene["candidates"], scene["target"]
    return world_to_target(np.asarray(cand["xy"], dtype=float), np.asarray(target["pos"]), float(target["yaw"]))


def target_to_world(xo: np.ndarray, target_xy: np.ndarray, target_yaw: float) -> np.ndarray:
    """Inverse of :func:`world_to_target`: [K,2] target frame -> [K,2] world."""
    xo = np.asarray(xo, dtype=np.float64).reshape(-1, 2)
    n = np.array([math.cos(target_yaw), math.sin(target_yaw)])
    lat = np.array([-n[1], n[0]])
    return np.asarray(target_xy, dtype=np.float64)[:2] + xo[:, :1] * lat - xo[:, 1:2] * n


def world_to_base(p: np.ndarray, base_pose: np.ndarray) -> np.ndarray:
    """World points [K,3] (or [K,2]) -> robot base frame; base_pose = (x, y, yaw) world."""
    p = np.asarray(p, dtype=np.float64)
    x, y, yaw = (float(v) for v in base_pose)
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = p[..., 0] - x, p[..., 1] - y
    out = p.copy()
    out[..., 0] = c * dx + s * dy
    out[..., 1] = -s * dx + c * dy
    return out


def base_to_world(p: np.ndarray, base_pose: np.ndarray) -> np.ndarray:
    """Robot base frame points [K,3] (or [K,2]) -> world; inverse of :func:`world_to_base`."""
    p = np.asarray(p, dtype=np.float64)
    x, y, yaw = (float(v) for v in base_pose)
    c, s = math.cos(yaw), math.sin(yaw)
    out = p.copy()
    out[..., 0] = c * p[..., 0] - s * p[..., 1] + x
    out[..., 1] = s * p[..., 0] + c * p[..., 1] + y
    return out


def in_front_region(xo: np.ndarray, cfg: ViewConfig) -> np.ndarray:
    """Target-frame points [K,2] -> bool [K]: inside V_front and within max_dist."""
    xo = np.asarray(xo).reshape(-1, 2)
    r = np.hypot(xo[:, 0], xo[:, 1])
    return (np.abs(xo[:, 0]) < cfg.front_rx) & (xo[:, 1] < -cfg.front_ry) & (r <= cfg.max_dist)


def in_side_region(xo: np.ndarray, cfg: ViewConfig) -> np.ndarray:
    """Target-frame points [K,2] -> bool [K]: inside V_side and within max_dist."""
    xo = np.asarray(xo).reshape(-1, 2)
    r = np.hypot(xo[:, 0], xo[:, 1])
    return (np.abs(xo[:, 0]) > cfg.side_rx) & (np.abs(xo[:, 1]) < cfg.side_ry) & (r <= cfg.max_dist)


def _propose(kind: ViewKind, rng: np.random.Generator, cfg: ViewConfig) -> np.ndarray:
    """One uniform proposal [2] in the target frame inside the bounding box of the region."""
    if kind == "front":
        return np.array([rng.uniform(-cfg.front_rx, cfg.front_rx), rng.uniform(-cfg.max_dist, -cfg.front_ry)])
    side = rng.choice([-1.0, 1.0])
    return np.array([side * rng.uniform(cfg.side_rx, cfg.max_dist), rng.uniform(-cfg.side_ry, cfg.side_ry)])


def heading_to(xy: np.ndarray, target_xy: np.ndarray) -> float:
    """Yaw (rad, world) of a base at xy [2] looking at target_xy [2]."""
    d = np.asarray(target_xy, dtype=np.float64)[:2] - np.asarray(xy, dtype=np.float64)[:2]
    return float(math.atan2(d[1], d[0]))


# ---------------------------------------------------------------------------------------------------- clearance
def _signed_distances(model: Any, data: Any, geom_ids: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Exact signed distance (m, < 0 inside) from the world point p [3] to each geom in geom_ids, as posed in data.

    Boxes, spheres and cylinders (every scene geom type the kitchen builder makes besides the floor plane); another
    type raises ValueError rather than being passed unchecked.
    """
    import mujoco

    geom_ids = np.asarray(geom_ids, dtype=np.int64).reshape(-1)
    types = model.geom_type[geom_ids]
    known = (mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_CYLINDER)
    bad = ~np.isin(types, [int(t) for t in known])
    if bad.any():
        g = int(geom_ids[np.flatnonzero(bad)[0]])
        kind = mujoco.mjtGeom(int(model.geom_type[g])).name
        raise ValueError(f"no camera clearance test for geom {g} of type {kind}")
    rot = data.geom_xmat[geom_ids].reshape(-1, 3, 3)
    loc = np.einsum("kji,kj->ki", rot, np.asarray(p, dtype=np.float64)[None] - data.geom_xpos[geom_ids])  # R^T (p - c)
    size = model.geom_size[geom_ids]
    out = np.empty(len(geom_ids))
    box = types == mujoco.mjtGeom.mjGEOM_BOX
    q = np.abs(loc[box]) - size[box]
    out[box] = np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
    sph = types == mujoco.mjtGeom.mjGEOM_SPHERE
    out[sph] = np.linalg.norm(loc[sph], axis=1) - size[sph, 0]
    cyl = types == mujoco.mjtGeom.mjGEOM_CYLINDER  # size = (radius, half height), axis local z
    q = np.stack([np.hypot(loc[cyl, 0], loc[cyl, 1]) - size[cyl, 0], np.abs(loc[cyl, 2]) - size[cyl, 1]], axis=1)
    out[cyl] = np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
    return out


def camera_clearance(scene: Any) -> tuple[float, int]:
    """Signed distance (m, < 0 inside) from the ego camera, with the robot as posed now, to the nearest scene geom
    (the robot's own geoms and the floor excluded), and that geom's id (-1 when there is none).

    Reads ``scene.data``'s body and geom poses (``mj_kinematics``, which ``scene.set_base_pose`` runs; the camera's
    own ``cam_xpos`` is only updated by ``mj_camlight``, so the camera is placed here from its body).
    """
    import mujoco

    m, d = scene.model, scene.data
    cid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_CAMERA, EGO_CAMERA)
    if cid < 0:
        raise KeyError(f"the scene has no camera {EGO_CAMERA!r}")
    if m.cam_mode[cid] != mujoco.mjtCamLight.mjCAMLIGHT_FIXED:
        raise ValueError(f"camera {EGO_CAMERA!r} is not fixed to its body (mode {int(m.cam_mode[cid])})")
    b = int(m.cam_bodyid[cid])
    cam = d.xpos[b] + d.xmat[b].reshape(3, 3) @ m.cam_pos[cid]
    ids = np.asarray(scene.scene_geom_ids, dtype=np.int64).reshape(-1)
    ids = ids[ids != int(scene.floor_geom_id)]
    if ids.size == 0:
        return math.inf, -1
    dist = _signed_distances(m, d, ids, cam)
    k = int(np.argmin(dist))
    return float(dist[k]), int(ids[k])


def view_pose_clear(scene: Any, pose: np.ndarray) -> bool:
    """The view sampler's tests of a base pose (world x, y, yaw) beyond the footprint and the robot's collision
    geometry: no wall between the base origin and the target's floor projection (``scene.wall_between``, as the
    annotation's pose filter), and the ego camera outside every scene geom by at least the near clipping plane
    (:func:`camera_clearance` >= :func:`floaff_zoo.sim.render.near_clip`; nearer, the render cuts the surface away or
    looks through it from inside). Leaves the robot's base at the pose when the wall test passes.
    """
    x, y, yaw = check_pose(pose, "view_pose_clear")
    if scene.wall_between(x, y, np.asarray(scene.target.pos, dtype=np.float64)[:2]):
        return False
    scene.set_base_pose(x, y, yaw)
    return camera_clearance(scene)[0] >= near_clip(scene.model)


# ---------------------------------------------------------------------------------------------------- rendering
def _check_image_size(renderer: Renderer, cfg: ViewConfig, who: str) -> None:
    """Refuse a renderer whose image is not cfg.image_size square: its own size was rendered and cfg's ignored."""
    if (renderer.height, renderer.width) != (cfg.image_size, cfg.image_size):
        raise ValueError(
            f"{who}: the renderer draws {renderer.height}x{renderer.width} images, cfg.image_size is {cfg.image_size}"
        )


def _check_rng(rng: Any, who: str) -> None:
    """Refuse an rng that is not a numpy Generator, as ``SimScene.reset_task`` does: a seed failed with an
    AttributeError, in render_view only when a view held more than max_points points (mid-generation)."""
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"{who}: rng must be a numpy Generator (np.random.default_rng(seed)), got {type(rng).__name__}")


def render_view(
    scene: Any,
    renderer: Renderer,
    base_pose: np.ndarray,
    cfg: ViewConfig,
    rng: np.random.Generator,
) -> ViewObservation:
    """Put the robot at base_pose (world x, y, yaw), render the ego camera and build the base-frame cloud.

    The robot's own geoms (all geoms not in scene.scene_geom_ids) are hidden when cfg.hide_robot (so its arm does not
    occlude the floor near the base; N2M moves the robot away for the same reason) and never enter the cloud;
    background (depth >= depth_max) is dropped; target pixels
    (scene.target.geom_ids) get flag +1, others 0. At most cfg.max_points points are kept (uniform, seeded by rng).
    """
    import mujoco  # local: render.py already chose the GL back end

    _check_rng(rng, "render_view")
    _check_image_size(renderer, cfg, "render_view")
    scene.set_base_pose(*check_pose(base_pose, "render_view", "base_pose"))  # a [2] pose failed with an IndexError
    mujoco.mj_forward(scene.model, scene.data)
    ng = scene.model.ngeom
    is_scene = np.zeros(ng + 1, dtype=bool)  # last slot: sentinel for "no geom" (-1)
    is_scene[np.asarray(scene.scene_geom_ids, dtype=np.int64).reshape(-1)] = True
    # robot geoms = everything that is not scene (robot_geom_ids holds only its collision geoms)
    robot_ids = np.flatnonzero(~is_scene[:ng])
    res = renderer.render(scene.data, EGO_CAMERA, segmentation=True, hide_geoms=robot_ids if cfg.hide_robot else None)
    pts, valid = backproject(res.depth, res.fovy, res.cam_pos, res.cam_mat, cfg.depth_max)
    gid = res.geom_id.reshape(-1)
    target = np.zeros(ng + 1, dtype=bool)
    target[np.asarray(scene.target.geom_ids, dtype=np.int64).reshape(-1)] = True
    gidx = np.where(gid >= 0, gid, ng)
    keep = valid & is_scene[gidx]  # background, sites and robot pixels are dropped
    idx = np.flatnonzero(keep)
    if idx.size > cfg.max_points:
        idx = np.sort(rng.choice(idx, size=cfg.max_points, replace=False))
    flag = target[gidx[idx]].astype(np.float32)
    rgb = res.rgb.reshape(-1, 3)[idx].astype(np.float32) / 255.0
    xyz = world_to_base(pts[idx], base_pose).astype(np.float32)
    feat = np.concatenate([flag[:, None], rgb], axis=1).astype(np.float32)
    return ViewObservation(scene_xyz=xyz, scene_feat=feat, rgb=res.rgb, depth=res.depth, n_target=int(flag.sum()))


def sample_view_poses(
    scene: Any,
    renderer: Renderer,
    kind: ViewKind,
    n: int,
    cfg: ViewConfig,
    rng: np.random.Generator,
    accept: Callable[[np.ndarray, ViewObservation], bool] | None = None,
) -> list[tuple[np.ndarray, ViewObservation]]:
    """Sample up to n collision-free view poses of one kind, each with its rendered observation.

    A pose must be in the region (base origin), its footprint free, :func:`view_pose_clear` (no wall between base and
    target, the camera clear of the scene by the near plane; since generator 2.2) and the robot touch nothing.
    accept(pose, obs): an extra test of a rendered view (e.g. "sees a floor cell with a positive label"); a rejected
    view costs one proposal, like one that sees too little of the target or fails any test above.
    Returns a list of (base_pose_world [3] float64, ViewObservation); fewer than n when the region has too little free
    floor (n * cfg.max_tries_per_view proposals in total). Deterministic for a given rng state and scene.
    """
    if kind not in ("front", "side"):
        raise ValueError(f"view kind must be 'front' or 'side', got {kind!r}")
    check_integer("n", n, 0, owner="sample_view_poses")  # a NaN n sampled no view without a word, 1.5 a bare TypeError
    _check_rng(rng, "sample_view_poses")
    _check_image_size(renderer, cfg, "sample_view_poses")
    in_region = in_front_region if kind == "front" else in_side_region
    tpos = np.asarray(scene.target.pos, dtype=np.float64)
    tyaw = float(scene.target.yaw)
    out: list[tuple[np.ndarray, ViewObservation]] = []
    for _ in range(max(0, n) * cfg.max_tries_per_view):
        if len(out) >= n:
            break
        xo = _propose(kind, rng, cfg)
        if not in_region(xo, cfg)[0]:
            continue
        xy = target_to_world(xo, tpos[:2], tyaw)[0]
        yaw = heading_to(xy, tpos[:2])
        if not scene.footprint_free(float(xy[0]), float(xy[1]), yaw):
            continue
        pose = np.array([xy[0], xy[1], yaw], dtype=np.float64)
        if not view_pose_clear(scene, pose):  # leaves the base at the pose
            continue
        if scene.robot_collides():
            continue
        obs = render_view(scene, renderer, pose, cfg, rng)
        if obs.n_target < cfg.min_target_pixels:
            continue
        if accept is not None and not accept(pose, obs):
            continue
        out.append((pose, obs))
    return out


def _cells_and_labels(grid_xy: Any, label: Any) -> tuple[np.ndarray, np.ndarray]:
    """make_view_sample's grid_xy as [M,2] float64 and label as [M] float64, finite, labels in [0, 1]; ValueError
    naming the argument otherwise (a NaN cell or label was written into the view's floor arrays, a [3] grid failed in
    numpy's reshape)."""
    cells = np.asarray(grid_xy)
    if cells.dtype.kind not in "iuf" or (cells.ndim != 2 or cells.shape[-1] != 2) and cells.size:
        raise ValueError(f"make_view_sample: grid_xy must be [M,2] cell centres, got {cells.dtype} {cells.shape}")
    cells = cells.astype(np.float64).reshape(-1, 2)
    lab = np.asarray(label)
    if lab.dtype.kind not in "biuf":
        raise ValueError(f"make_view_sample: label must be numbers in [0, 1], got {lab.dtype}")
    lab = lab.astype(np.float64).reshape(-1)
    bad = ~np.isfinite(cells).all(axis=1)
    if bad.any():
        raise ValueError(
            f"make_view_sample: grid_xy must be finite, got {cells[bad][0].tolist()} (cell {bad.argmax()})"
        )
    bad = ~(np.isfinite(lab) & (lab >= 0) & (lab <= 1))
    if bad.any():
        raise ValueError(
            f"make_view_sample: label must be finite numbers in [0, 1], got {lab[bad][0]} ({bad.argmax()})"
        )
    return cells, lab


def _check_floor_fields(floor_known: Any, floor_index: Any) -> None:
    """make_view_sample's format-v2 fields: floor_known bools (0.5 was stored as True), floor_index integers >= 0
    (1.7 was cut to cell 1, -3 stored as it is)."""
    if floor_known is not None:
        known = np.asarray(floor_known)
        if known.dtype.kind != "b" and not (known.dtype.kind in "iuf" and np.isin(known, (0, 1)).all()):
            raise ValueError(f"make_view_sample: floor_known must be bools, got {known.dtype} {known.reshape(-1)[:5]}")
    if floor_index is not None:
        idx = np.asarray(floor_index)
        if idx.size and (idx.dtype.kind not in "iu" or idx.min() < 0):
            raise ValueError(
                f"make_view_sample: floor_index must be integers >= 0, got {idx.dtype} {idx.reshape(-1)[:5]}"
            )


def make_view_sample(
    obs: ViewObservation,
    base_pose: np.ndarray,
    target_pos: np.ndarray,
    target_yaw: float,
    grid_xy: np.ndarray,
    label: np.ndarray,
    save_images: bool = False,
    floor_known: np.ndarray | None = None,
    floor_index: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """The per-view arrays stored in ``views/<view_id>.npz`` (sample-contract fields, robot base frame).

    grid_xy [M,2] world candidate cells, label [M] -> floor_xyz [M,3] (z = 0), floor_label [M];
    target_pos [3] world -> target_xyz [3]; target_yaw world -> base-frame yaw in [-pi, pi).
    Format v2 fields, stored when given: floor_known [M] bool (label from a rollout or a filter, not interpolated),
    floor_index [M] int (flat index of each cell in the scene's candidate grid).
    """
    # a NaN pose or target was written into every base-frame array of the view without a word
    check_pose(base_pose, "make_view_sample", "base_pose")
    target = np.asarray(target_pos, dtype=np.float64).reshape(-1)
    if target.shape != (3,) or not np.isfinite(target).all():
        raise ValueError(f"make_view_sample: target_pos must be 3 finite values (x, y, z), got {target_pos!r}")
    check_number("target_yaw", target_yaw, -math.inf, owner="make_view_sample")
    check_flag("save_images", save_images, owner="make_view_sample")  # the text "no" saved the images
    grid_xy, label = _cells_and_labels(grid_xy, label)
    _check_floor_fields(floor_known, floor_index)
    floor = np.concatenate([grid_xy, np.zeros((len(grid_xy), 1))], axis=1)
    out = {
        "scene_xyz": obs.scene_xyz.astype(np.float32),
        "scene_feat": obs.scene_feat.astype(np.float32),
        "floor_xyz": world_to_base(floor, base_pose).astype(np.float32),
        "floor_label": np.asarray(label, dtype=np.float32).reshape(-1),
        "robot": ROBOT_DESCRIPTOR.copy(),
        "target_xyz": world_to_base(np.asarray(target_pos, dtype=np.float64).reshape(1, 3), base_pose)[0].astype(
            np.float32
        ),
        "target_yaw": np.float32(wrap_angle(float(target_yaw) - float(base_pose[2]))),
        "base_pose_world": np.asarray(base_pose, dtype=np.float32).reshape(3),
    }
    if out["floor_label"].shape[0] != out["floor_xyz"].shape[0]:
        raise ValueError(f"label has {out['floor_label'].shape[0]} entries but the grid has {len(grid_xy)} cells")
    for name, arr, dtype in (("floor_known", floor_known, np.bool_), ("floor_index", floor_index, np.int32)):
        if arr is None:
            continue
        out[name] = np.asarray(arr).reshape(-1).astype(dtype)
        if out[name].shape[0] != len(grid_xy):
            raise ValueError(f"{name} has {out[name].shape[0]} entries but the grid has {len(grid_xy)} cells")
    if save_images:
        out["rgb"] = np.asarray(obs.rgb, dtype=np.uint8)
        out["depth"] = np.asarray(obs.depth, dtype=np.float32)
    return out
