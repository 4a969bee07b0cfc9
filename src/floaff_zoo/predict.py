"""Predict API: a floor-affordance map and a base pose from one RGB-D view or a point cloud.

``predict(model, rgb, depth, intrinsics, camera_pose, target_mask, robot)`` back-projects the
depth image with the pinhole model into the robot base frame, flags the target pixels and calls
``predict_from_points``, which scores candidate floor points and returns a :class:`Prediction`.

Conventions:

* ``intrinsics`` = (fx, fy, cx, cy) in pixels (pixel centres at +0.5), or a 3x3 K (its skew applied);
  ``depth`` [H, W] metres along the optical axis (<= 0, NaN/Inf or >= ``max_depth`` = invalid, e.g. the far
  plane; default :data:`MAX_DEPTH`, the generator's cut, 4 m).
* ``camera_pose`` = 4x4 camera-to-base transform. ``convention="opengl"`` (default, MuJoCo):
  the camera looks along its -z, x right, y up; ``"opencv"``: looks along +z, x right, y down.
* The base frame is the contract's: x forward, y left, z up, floor at z = 0.
* ``floor_xyz=None``: the **observed floor cells** of the given cloud, by the rule of the generated
  benchmark's views (format v2, ``floaff_zoo.floor``): cells of ``cell`` m (default
  :data:`DEFAULT_FLOOR_CELL`) of a lattice centred on the target's floor projection and aligned with
  its front (``target_yaw``), inside ``window`` (default the benchmark's label window, |x°| <= 1.0 m
  along the front, |y°| <= 1.2 m along its normal) and, when given, within ``grid_radius`` of the
  target, that hold at least one ground point (z < ``FLOOR_Z_MAX`` = 0.02 m). Nothing else is
  needed: no simulator field, no free-space guess. Pass the cell of the model's training data
  (the generator's ``--cell``; 0.1 m for the demo/small presets) when it differs.
* ``target_yaw=None``: the target's front is assumed to face the observing camera, i.e. the yaw of
  the direction from the target to the base origin.
"""

from __future__ import annotations

import itertools
import math
import sys
import types
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from floaff_zoo import runtime
from floaff_zoo.contract import (
    TARGET_FLAG_VALUES,
    FloorGrid,
    NonFiniteError,
    SampleError,
    best_pose,
    collate_samples,
    validate_sample,
)
from floaff_zoo.floor import CANDIDATE_WINDOW, FLOOR_Z_MAX, FloorLattice, footprint_blocked, observed_cells

Pose = tuple[float, float, float]
#: m: default floor cell, the grid of the demo/small generation presets the shipped models were trained on
DEFAULT_FLOOR_CELL = 0.1
#: depth (m) beyond which pixels are dropped: the generator's ``depth_max`` (every preset), so a model is given no
#: farther points than it was trained on
MAX_DEPTH = 4.0
#: largest deviation of camera_pose's rotation from orthonormal (R R^T - I, elementwise)
RIGID_TOLERANCE = 1e-3
#: most cells of the default grid's lattice or of the returned raster (2000 x 2000: 20 m x 20 m at 1 cm); a finer
#: cell or candidates spread wider are refused instead of allocating gigabytes for one map
MAX_RASTER_CELLS = 4_000_000
#: m: farthest the target point may lie from the nearest target-flagged point. The generated fixtures keep every
#: target pixel within about 1 m of the front's centre (the widest, a 0.9 m double door, swung open), MoMa-Kitchen's
#: target is its points' centroid; a target farther off is in another frame or unit (millimetres, the world frame)
TARGET_MAX_OFFSET = 2.0


@dataclass
class Prediction:
    """Output of :func:`predict` / :func:`predict_from_points` (robot base frame).

    floor_xyz [M, 3] candidates; scores [M] in [0, 1]; grid/raster: the map rasterised on a
    FloorGrid (raster [H, W], NaN where no candidate); best_pose (x, y, yaw facing the target; with ``free_k`` > 1
    the best of the top ``free_k`` whose footprint the cloud shows free);
    top_poses: the ``k`` best poses, best first (ties: contract.best_pose's seeded random tie-break).
    The raster is a preview on an axis-aligned grid of the candidates' cell: candidates of a lattice turned by the
    target's yaw can share a raster cell (their scores averaged) and leave others empty, so choose poses from
    ``scores`` / ``best_pose``, not from the raster.
    """

    floor_xyz: np.ndarray
    scores: np.ndarray
    grid: FloorGrid
    raster: np.ndarray
    best_pose: Pose
    top_poses: list[Pose]
    target_xyz: np.ndarray
    target_yaw: float


# ------------------------------------------------------------------------------------------ model
def module_device(module: torch.nn.Module) -> torch.device:
    """Where a module lives: its first parameter's device, else its first buffer's (the canonical prior without an
    AxisNet has buffers only: reading parameters alone said cpu for a prior on the GPU), else the CPU."""
    first = next(itertools.chain(module.parameters(), module.buffers()), None)
    return first.device if first is not None else torch.device("cpu")


def resolve_model(model: Any, model_class: type | str | None = None, device: str = "cpu") -> torch.nn.Module:
    """A ready-to-run module from a module, a checkpoint path or a hub name.

    Also asks glibc to keep freed memory for reuse (``runtime.keep_freed_memory``, as ``floaff-zoo``
    does at start): repeated predictions then reuse their activations' pages instead of faulting in
    fresh ones (docs/performance.md, predict latency). ``FLOAFF_ZOO_MALLOC=system`` leaves malloc alone.

    Args:
        model_class: when given, the resolved model must be an instance of it (class or class name);
            a checkpoint of another model class raises a TypeError naming both.
    """
    runtime.keep_freed_memory()
    if isinstance(model, (str, Path)):
        from floaff_zoo.hub import HubError, load_model

        try:  # a class given builds a checkpoint that does not record its own (a bare state dict, a plain fit's)
            model = load_model(
                str(model), map_location=device, expected=model_class if isinstance(model_class, type) else None
            )
        except HubError:
            raise  # a registered name whose file is missing / corrupt: the hub's message says what to do
        except FileNotFoundError as exc:
            raise FileNotFoundError(
                f"predict: model {str(model)!r} is neither a checkpoint file nor a known hub name ({exc})"
            ) from exc
    if not isinstance(model, torch.nn.Module):
        raise TypeError(
            f"predict: model must be a FloAffModule, a checkpoint path or a hub name, got {type(model).__name__}"
        )
    if model_class is not None:
        name = model_class if isinstance(model_class, str) else model_class.__name__
        ok = type(model).__name__ == name if isinstance(model_class, str) else isinstance(model, model_class)
        if not ok:
            raise TypeError(f"predict: expected a {name} but the checkpoint/model is a {type(model).__name__}")
    gap = model.weights_gap() if callable(getattr(model, "weights_gap", None)) else None
    if gap is not None:  # as `floaff-zoo predict` refuses it: part of the model would score with random weights
        raise ValueError(f"predict: {type(model).__name__} was built from weights that do not fit it: {gap}")
    return model.to(device).eval()


def named_models(specs: list[str]) -> dict[str, list[str]]:
    """Command-line ``[NAME=]MODEL`` specs -> {NAME: [MODEL, ...]} in order (a repeated NAME pools runs).

    A bare MODEL is its own NAME; so is a spec whose part before ``=`` holds a ``/`` or that names an existing
    file (a checkpoint path may hold ``=``: ``epoch=1-step=9.ckpt``). An empty NAME or MODEL is a ValueError.
    """
    if isinstance(specs, str):  # one text was read letter by letter: {"c": ["c"], "f": ["f"], ...}
        raise ValueError(f"bad model arguments {specs!r}: pass a list of [NAME=]MODEL texts")
    out: dict[str, list[str]] = {}
    for spec in specs:
        if not isinstance(spec, str):
            raise ValueError(f"bad model argument {spec!r}; use NAME=MODEL (a hub name or checkpoint)")
        name, sep, model = spec.partition("=")
        if not sep or "/" in name or Path(spec).exists():
            name, model = spec, spec
        if not name or not model:
            raise ValueError(f"bad model argument {spec!r}; use NAME=MODEL (a hub name or checkpoint)")
        out.setdefault(name, []).append(model)
    return out


# ------------------------------------------------------------------------------------------ inputs
def _finite(value: Any) -> float | None:
    """``value`` as a float when it is one finite real number (a Python or numpy number, a 0-d array), else None
    (a bool, a text, an array of several values, NaN or Inf): the checks name their argument instead of float()."""
    a = np.asarray(value) if not isinstance(value, (str, bytes)) else None
    if a is None or a.shape != () or a.dtype.kind not in "iuf" or not math.isfinite(float(a)):
        return None
    return float(a)


def _vector(value: Any, name: str, what: str) -> np.ndarray:
    """``value`` flattened to float64 [n] when it holds numbers along at most one axis longer than 1 ([n], [1, n],
    [n, 1], [1, 1, n]: one point or descriptor, as a batch of one gives it); a ValueError naming ``name`` (which
    must be ``what``) and the shape for a 0-d number, a matrix, a text or ragged values (numpy named no argument)."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"predict: {name} must be {what}, got {value!r:.80} (ragged or non-numeric)") from None
    if a.ndim == 0 or sum(d > 1 for d in a.shape) > 1:
        raise ValueError(
            f"predict: {name} must be {what}, got shape {a.shape}" + (f": {a.tolist()}" if a.size <= 9 else "")
        )
    return a.reshape(-1)


def _finite32(a: np.ndarray) -> bool:
    """Every value finite, also as the float32 the model is fed (1e39 passed as float64 and became inf)."""
    return bool(np.isfinite(a).all() and (np.abs(a) <= np.finfo(np.float32).max).all())


def check_point(value: Any, name: str) -> np.ndarray:
    """``value`` as a float64 point [3] (any shape of one point, ``_vector``); ValueError naming ``name`` and the
    value given unless it is 3 finite values."""
    what = "3 finite values (x, y, z)"
    p = _vector(value, name, what)
    if p.size != 3 or not _finite32(p):
        raise ValueError(f"predict: {name} must be {what}, got shape {np.shape(value)}: {p.tolist()[:9]}")
    return p


def check_cell(cell: float | None) -> float | None:
    """``cell`` (m) as a float, or None (the default); a ValueError for 0, negative, NaN or Inf sizes."""
    if cell is None:
        return None
    c = _finite(cell)
    if c is None or c <= 0:  # a text or an array failed in float() naming no argument
        raise ValueError(
            f"predict: cell must be a finite size > 0 m (None: {DEFAULT_FLOOR_CELL} m for the default grid, "
            f"else the candidates' spacing), got {cell!r}"
        )
    return c


def check_window(
    target_yaw: float | None, window: Any, grid_radius: float | None, radius_name: str = "grid_radius"
) -> tuple[float, float]:
    """``window`` as (r_x, r_y); ValueError naming the argument for a non-finite ``target_yaw``, a ``window`` that is
    not two finite sizes > 0 m (any shape of one pair, ``_vector``), or a ``grid_radius`` (called ``radius_name``)
    that is not a finite size > 0 m (None: none); checked before the model is loaded."""
    if target_yaw is not None and _finite(target_yaw) is None:
        raise ValueError(f"predict: target_yaw must be a finite angle (rad) or None, got {target_yaw!r}")
    what = "two finite half-sizes > 0 m (along the front, its normal)"
    w = _vector(window, "window", what)
    if w.size != 2 or not (np.isfinite(w).all() and (w > 0).all()):
        raise ValueError(f"predict: window must be {what}, got {window!r} (shape {np.shape(window)})")
    if grid_radius is not None and not (_finite(grid_radius) or 0) > 0:
        raise ValueError(f"predict: {radius_name} must be a finite radius > 0 m or None, got {grid_radius!r}")
    return float(w[0]), float(w[1])


def check_device(device: str) -> None:
    """ValueError naming ``device`` when torch cannot use it (``cuda`` on a CPU-only build or without a GPU)."""
    try:
        torch.empty(0, device=device)
    except (RuntimeError, AssertionError) as exc:  # torch raises AssertionError on a build without CUDA
        raise ValueError(f"predict: device {device!r} is not available here ({exc})") from exc


def check_raster_size(shape: tuple[int, int], cell: float, what: str, other_fix: str) -> None:
    """Refuse a raster/lattice of [H, W] = ``shape`` beyond MAX_RASTER_CELLS cells; ``what`` names it and
    ``other_fix`` says what else than a coarser cell shrinks it."""
    n = int(shape[0]) * int(shape[1])
    if n > MAX_RASTER_CELLS:
        raise ValueError(
            f"predict: cell={cell:g} m makes {what} of {shape[0]} x {shape[1]} = {n:,} cells (limit "
            f"{MAX_RASTER_CELLS:,}); pass a coarser cell (the model's training cell, e.g. {DEFAULT_FLOOR_CELL} m) "
            f"or {other_fix}"
        )


def check_scene(scene_xyz: Any, scene_feat: Any) -> tuple[np.ndarray, np.ndarray]:
    """The observation as float32 arrays: scene_xyz [N, 3] and scene_feat [N, C] (a 1-D [N] flag becomes [N, 1]).

    Raises ValueError naming the argument for wrong shapes, for a channel 0 that is not the target flag
    (values -1, 0, +1, as the contract and the generated views store it) and for RGB channels (1-3) outside
    [0, 1] or not finite: RGB alone, a flag scaled to 0..255 or 8-bit colours would otherwise run and return
    another pose.
    """
    xyz = np.asarray(scene_xyz, dtype=np.float32)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or xyz.shape[0] == 0:
        hint = " (a [3, N] cloud: pass scene_xyz.T)" if xyz.ndim == 2 and xyz.shape[0] == 3 else ""
        raise ValueError(f"predict: scene_xyz must be [N, 3] points with N >= 1, got shape {xyz.shape}{hint}")
    nonfinite = ~np.isfinite(xyz).all(axis=1)
    if nonfinite.any():  # e.g. a depth sensor's invalid pixels kept in the cloud
        raise ValueError(
            f"predict: scene_xyz holds {int(nonfinite.sum())} of {len(xyz)} points with NaN/Inf coordinates; drop "
            "them (and their scene_feat rows) first"
        )
    feat = np.asarray(scene_feat, dtype=np.float32)
    if feat.ndim == 1:  # the flag alone
        feat = feat[:, None]
    if feat.ndim != 2 or feat.shape[0] != xyz.shape[0] or feat.shape[1] < 1:
        raise ValueError(
            f"predict: scene_feat must be [N, C] with N = {xyz.shape[0]} rows like scene_xyz {xyz.shape} and "
            f"C >= 1 (channel 0 = target flag), got shape {feat.shape}"
        )
    bad = ~np.isin(feat[:, 0], TARGET_FLAG_VALUES)
    if bad.any():
        seen = [float(f"{v:.4g}") for v in np.unique(feat[bad, 0])[:3]]
        rgb = " (3 channels: RGB without the flag?)" if feat.shape[1] == 3 else ""
        raise ValueError(
            f"predict: scene_feat channel 0 must be the target flag, -1 (obstacle), 0 (other) or +1 (target); "
            f"{int(bad.sum())} of {len(feat)} points hold other values (e.g. {seen}){rgb}: put the flag first, "
            "then RGB in [0, 1]"
        )
    rgb = feat[:, 1:4]  # the contract's colour channels, when present
    off = ~(np.isfinite(rgb) & (rgb >= 0.0) & (rgb <= 1.0))
    if off.any():
        seen = [float(f"{v:.4g}") for v in np.unique(rgb[off])[:3]]
        raise ValueError(
            f"predict: scene_feat channels 1-3 are RGB in [0, 1]; {int(off.any(axis=1).sum())} of {len(feat)} points "
            f"hold other values (e.g. {seen}): divide 8-bit colours by 255"
        )
    return xyz, feat


def check_target(xyz: np.ndarray, feat: np.ndarray, target: np.ndarray) -> None:
    """ValueError naming the argument when the cloud flags no point as the target (channel 0 = +1), or when
    ``target`` [3] lies more than TARGET_MAX_OFFSET from every flagged point: the models were trained on views that
    always show their target (the generator keeps >= 4 target points, both readers refuse a sample without one) and
    read the target point as a point of it; such input ran and returned a pose about nothing."""
    flagged = xyz[feat[:, 0] > 0]
    if len(flagged) == 0:
        raise ValueError(
            f"predict: scene_feat flags no point of the cloud as the target (channel 0 = +1 on none of {len(xyz)} "
            "points); flag the target's points (predict(): target_mask)"
        )
    gap = float(np.linalg.norm(flagged - target, axis=1).min())
    if gap > TARGET_MAX_OFFSET:
        raise ValueError(
            f"predict: target_xyz {np.round(target, 3).tolist()} lies {gap:.3g} m from the nearest of the "
            f"{len(flagged)} target-flagged points (at most {TARGET_MAX_OFFSET} m): give it in the cloud's frame "
            "(robot base, metres)"
        )


def check_floor_height(floor: np.ndarray) -> None:
    """ValueError naming ``floor_xyz`` when the candidates [M, 3] stand off the floor as a whole (their median |z| >
    FLOOR_Z_MAX): candidates are base positions at z = 0 (the contract), the models read their z, and candidates in a
    frame whose origin is above the floor (a base link) scored differently without a word. A median, so that a robot's
    segmented floor points with centimetres of sensor noise (as ``ground_mask`` keeps them) still pass."""
    if floor.ndim != 2 or floor.shape[1] != 3 or len(floor) == 0:
        return  # the sample check names the shape
    z = float(np.median(floor[:, 2]))
    if abs(z) > FLOOR_Z_MAX:
        raise ValueError(
            f"predict: floor_xyz stands off the floor (median z {z:.3g} m, |z| > {FLOOR_Z_MAX} m): candidates are base "
            "positions at z = 0 in the robot base frame (floor at z = 0); pass [M, 2] x, y or set z to 0"
        )


def check_model_inputs(net: torch.nn.Module, channels: int, robot: np.ndarray) -> None:
    """SampleError (a ValueError, as the model's own check raised) naming ``robot`` / ``scene_feat`` when they do not
    fit the model's ``robot_dim`` / ``feat_channels`` (its hparams): the model's check speaks of the training data
    and asks to change its config, which a pretrained model cannot."""
    hp = getattr(net, "hparams", {})
    want, size = hp.get("robot_dim"), int(np.asarray(robot).size)
    if want is not None and size != int(want):
        raise SampleError(
            f"predict: robot must be the {want} values of {type(net).__name__}'s robot descriptor"
            f"{' ([arm reach m, base height m])' if int(want) == 2 else ''}, got {size}: "
            f"{np.asarray(robot).reshape(-1).tolist()}"
        )
    need = int(hp.get("feat_channels", 1))
    if channels < need:
        raise SampleError(
            f"predict: {type(net).__name__} reads {need} scene_feat channels (target flag, then RGB in [0, 1]), got "
            f"{channels} (predict(): pass rgb)"
        )


# ------------------------------------------------------------------------------------------ geometry
def check_float_rgb(c: np.ndarray) -> None:
    """Raise ValueError unless the float colours [P, 3] of the points are finite and in [0, 1] (clipping made
    0..255 floats white)."""
    if not (np.isfinite(c) & (c >= 0.0) & (c <= 1.0)).all():
        raise ValueError(
            f"predict: a float rgb must hold values in [0, 1], got {float(np.nanmin(c)):.4g} to "
            f"{float(np.nanmax(c)):.4g}{' and NaN' if np.isnan(c).any() else ''}: pass uint8 or divide by 255"
        )


def backproject_depth(
    depth: np.ndarray,
    intrinsics: tuple[float, float, float, float] | np.ndarray,
    camera_pose: np.ndarray,
    convention: Literal["opengl", "opencv"] = "opengl",
    max_depth: float = MAX_DEPTH,
) -> tuple[np.ndarray, np.ndarray]:
    """Depth [H, W] -> base-frame points [H*W, 3] (row-major pixels) and valid [H*W] bool.

    ``intrinsics``: (fx, fy, cx, cy), or a 3x3 K ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` whose skew ``s`` is applied.
    """
    d = np.asarray(depth, dtype=np.float64)
    if d.ndim != 2:
        raise ValueError(f"predict: depth must be [H, W], got shape {d.shape}")
    what = "(fx, fy, cx, cy) or a 3x3 K"
    try:
        k = np.asarray(intrinsics, dtype=np.float64)
    except (TypeError, ValueError):  # a text, ragged rows: _vector names them
        k = None
    k = k.reshape(-1) if k is not None and k.shape == (3, 3) else _vector(intrinsics, "intrinsics", what)
    if k.size not in (4, 9):  # a [2, 2] array was read as (fx, fy, cx, cy)
        raise ValueError(f"predict: intrinsics must be {what}, got shape {np.shape(intrinsics)}: {k.tolist()[:9]}")
    skew = 0.0
    if k.size == 9:  # a 3x3 K matrix
        if np.isfinite(k).all() and not np.allclose(k[[3, 6, 7, 8]], [0.0, 0.0, 0.0, 1.0]):  # a transposed K
            raise ValueError(
                f"predict: a 3x3 intrinsics K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got rows "
                f"{np.asarray(intrinsics, dtype=np.float64).reshape(3, 3).tolist()} (transposed?)"
            )
        k, skew = np.array([k[0], k[4], k[2], k[5]]), float(k[1])
    if k.size != 4 or not np.isfinite(k).all() or not math.isfinite(skew) or k[0] <= 0 or k[1] <= 0:
        raise ValueError(
            f"predict: intrinsics must be finite (fx, fy, cx, cy) with fx, fy > 0 or a 3x3 K, got {intrinsics!r}"
        )
    pose = np.asarray(camera_pose, dtype=np.float64)
    if pose.shape != (4, 4) or not np.isfinite(pose).all():
        raise ValueError(f"predict: camera_pose must be a finite 4x4 camera-to-base matrix, got shape {pose.shape}")
    rot = pose[:3, :3]
    if not (
        np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6)
        and np.allclose(rot @ rot.T, np.eye(3), atol=RIGID_TOLERANCE)
        and np.linalg.det(rot) > 0
    ):  # a scaled or sheared pose moved every point (and the chosen base) without a word
        raise ValueError(
            "predict: camera_pose must be a rigid camera-to-base transform (a rotation with determinant +1 and a "
            f"translation, last row [0, 0, 0, 1]), got {np.round(pose, 4).tolist()}"
        )
    if convention not in ("opengl", "opencv"):
        raise ValueError(f"predict: convention must be 'opengl' or 'opencv', got {convention!r}")
    # NaN made every pixel invalid (named later as a target mask without depth), text failed inside numpy
    if not isinstance(max_depth, (int, float, np.number)) or isinstance(max_depth, bool) or not max_depth > 0:
        raise ValueError(f"predict: max_depth must be a number > 0 metres (inf: no cut), got {max_depth!r}")
    fx, fy, cx, cy = k
    h, w = d.shape
    uu, vv = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    # K's skew s (u = fx x / z + s y / z + cx): a camera with one was read as without it, every point off sideways
    x = (uu - cx) * d / fx if skew == 0.0 else (uu - cx - skew * (vv - cy) / fy) * d / fx
    y = (vv - cy) * d / fy
    if convention == "opengl":
        pc = np.stack([x, -y, -d], axis=-1)
    else:
        pc = np.stack([x, y, d], axis=-1)
    pc = pc.reshape(-1, 3)
    flat = d.reshape(-1)
    valid = np.isfinite(flat) & (flat > 0) & (flat < max_depth)
    pc[~valid] = 0.0
    return pc @ pose[:3, :3].T + pose[:3, 3], valid


def default_target_yaw(target_xyz: np.ndarray) -> float:
    """Front yaw assumed when none is given: the target faces the base origin (the observing robot)."""
    t = check_point(target_xyz, "target_xyz")
    return math.atan2(-float(t[1]), -float(t[0]))


def default_floor_grid(
    target_xyz: np.ndarray,
    scene_xyz: np.ndarray,
    target_yaw: float | None = None,
    cell: float = DEFAULT_FLOOR_CELL,
    window: tuple[float, float] = CANDIDATE_WINDOW,
    radius: float | None = None,
    z_max: float = FLOOR_Z_MAX,
    min_points: int = 1,
) -> np.ndarray:
    """The observed floor cells of a cloud around the target (module docstring): [M, 3] float32, z = 0.

    Args:
        target_xyz [3]; scene_xyz [N, 3] (robot base frame, floor at z = 0); target_yaw: front yaw
        (None: faces the base origin); cell (m); window (r_x, r_y) m in the target frame;
        radius: optional disc cut (m) around the target; z_max / min_points: ground rule.
    Raises:
        SampleError: the cloud shows no ground point in the window.
    """
    t = check_point(target_xyz, "target_xyz")
    rx, ry = check_window(target_yaw, window, radius, "radius")
    yaw = default_target_yaw(t) if target_yaw is None else float(target_yaw)
    lattice = FloorLattice.target_window(t[:2], yaw, float(cell), rx, ry)
    check_raster_size(lattice.shape, float(cell), f"the default grid's window {window}", "a smaller window")
    seen = observed_cells(scene_xyz, lattice, z_max, min_points)  # refuses a cloud that is not [N, 3]
    if radius is not None:
        seen &= lattice.within(float(radius))
    if not seen.any():
        raise SampleError(
            f"predict: no observed floor cell around the target {t.round(3).tolist()}: the cloud has no ground point "
            f"(z < {z_max} m) in the {rx} x {ry} m window; pass floor_xyz explicitly"
        )
    xy = lattice.centers()[seen]
    return np.c_[xy, np.zeros(len(xy))].astype(np.float32)


def candidate_spacing(floor_xyz: np.ndarray, default: float = 0.05) -> float:
    """Median nearest-neighbour distance of candidates [M, 2+] (their grid cell); ``default`` if < 2 points."""
    pts = np.asarray(floor_xyz, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] < 2:  # a 0-d or [M] array failed in numpy's indexing
        raise ValueError(f"predict: floor_xyz must be [M, 2] or [M, 3] candidates, got shape {pts.shape}")
    pts = pts[:, :2]
    if len(pts) < 2:
        return default
    from scipy.spatial import cKDTree

    d = cKDTree(pts).query(pts, k=2)[0][:, 1]
    step = float(np.median(d))
    return step if step > 1e-6 else default


# ------------------------------------------------------------------------------------------ predict
def check_task(net: torch.nn.Module, task: str) -> None:
    """Raise ValueError when ``net`` conditions on the task (a canonical prior: CFAR with a prior, the
    canonical-prior model) and ``task`` is not one it knows, naming the argument and the known tasks."""
    from floaff_zoo.nn.prior import CanonicalLabelGrid

    grid = next((m for m in net.modules() if isinstance(m, CanonicalLabelGrid)), None)
    if grid is not None and task not in grid.tasks:
        raise ValueError(
            f"predict: {type(net).__name__} conditions on the task (its canonical prior has a grid per task): "
            f"pass task= one of {grid.tasks} (a generated view's meta['task']), got {task!r}"
        )


def check_floor_model(net: torch.nn.Module) -> None:
    """Raise TypeError when ``net`` is a zoo model that predicts no floor map (AxisNet estimates the target's yaw):
    its output would be read as floor scores and fail somewhere unrelated."""
    from floaff_zoo.models.base import FloAffModule, ZooModule

    if isinstance(net, ZooModule) and not isinstance(net, FloAffModule):
        raise TypeError(
            f"predict: {type(net).__name__} predicts no floor map (it is no FloAffModule; AxisNet estimates the "
            "target's yaw): pass a floor-affordance model"
        )


def kept_state(model: Any) -> Callable[[], None]:
    """A function that gives a caller's module back as it came: ``resolve_model`` puts it in eval mode on the
    predict device, which must not change the caller's training (every submodule's mode) or move it for good.
    A no-op for a checkpoint path or hub name (predict loads its own copy)."""
    if not isinstance(model, torch.nn.Module):
        return lambda: None
    modes = [(m, m.training) for m in model.modules()]
    home = module_device(model)

    def restore() -> None:
        for m, training in modes:
            m.training = training
        model.to(home)

    return restore


def run_model(net: torch.nn.Module, batch: dict[str, Any]) -> np.ndarray:
    """Scores [M] of a one-sample batch (moved to the model's device), without gradients.

    Raises:
        ValueError: the model's output is not one score per floor point (another module's: a yaw, a pose).
    """
    dev = module_device(net)
    batch = {key: (v.to(dev) if torch.is_tensor(v) else v) for key, v in batch.items()}
    check = getattr(net, "check_inputs", None)
    if callable(check):
        check(batch)
    with torch.no_grad():
        scores = net(batch)[0].float().cpu().numpy()
    if scores.shape != tuple(batch["floor_xyz"].shape[1:2]):
        raise ValueError(
            f"predict: {type(net).__name__} gave {list(scores.shape)} per sample, not a score per floor point"
        )
    return scores


def _count(value: object) -> bool:
    """True for an int >= 1 (numpy ints too; not a bool)."""
    return not isinstance(value, bool) and isinstance(value, (int, np.integer)) and value >= 1


def predict_from_points(
    model: Any,
    scene_xyz: np.ndarray,
    scene_feat: np.ndarray,
    floor_xyz: np.ndarray | None,
    robot: np.ndarray | list[float],
    target_xyz: np.ndarray | list[float],
    target_yaw: float | None = None,
    k: int = 5,
    num_points: int | None = 4096,
    cell: float | None = None,
    grid_radius: float | None = None,
    model_class: type | str | None = None,
    device: str = "cpu",
    seed: int = 0,
    window: tuple[float, float] = CANDIDATE_WINDOW,
    task: str = "",
    free_k: int = 1,
) -> Prediction:
    """Score candidate floor points for one observation (robot base frame).

    Args:
        model: a FloAffModule, a ``.ckpt`` path or a hub name; a module is run in eval mode on ``device`` and given
            back in its own training modes, on its own device.
        scene_xyz [N, 3], scene_feat [N, C] (channel 0 = target flag, then RGB in [0, 1]).
        floor_xyz [M, 3] candidates, or None for the observed floor cells of the cloud (module docstring).
        robot [R] descriptor (default MoMa-Kitchen style: [arm reach m, base height m]).
        target_xyz [3]; target_yaw: yaw of the target's front normal (None: faces the robot).
        k: number of top poses returned.
        num_points: scene points fed to the model (random subset / repeats, seeded); None = all.
        seed: seeds that subset and the tie-break among equal scores (``contract.best_pose``).
        cell: cell (m, > 0) of the default grid and of the returned raster; None = DEFAULT_FLOOR_CELL for
            the default grid, else the candidates' own spacing (median nearest-neighbour distance). A grid or
            raster of more than MAX_RASTER_CELLS cells is refused.
        grid_radius / window: disc cut (m, None = none) and target-frame window (r_x, r_y) m of the
            default grid.
        task: the task asked (``meta['task']``; needed by models that condition on it, e.g. the
            canonical prior).
        free_k: > 1: ``best_pose`` is the best of the top ``free_k`` poses whose base footprint the given cloud
            shows free (fewer than two distinct obstacle points in it, ``floor.footprint_blocked``), the top pose
            when none is; what ``floaff-zoo test`` stands on with ``top_k`` and ``free_space: full_cloud`` (the
            benchmark's protocol, ``configs/trainer/eval_sr_top10_full.yaml``, uses 10). 1: the top-scored pose.
    Raises:
        ValueError: bad shapes, a channel 0 that is not the target flag or flags no point, a target_xyz more than
            TARGET_MAX_OFFSET from the flagged points, candidates off the floor or a bad cell (checked before the
            model is loaded), too large a grid or raster, a robot descriptor or scene_feat that does not fit the
            model (before it runs), each naming the argument.
        TypeError: a model that predicts no floor map (AxisNet).
    """
    xyz, feat = check_scene(scene_xyz, scene_feat)
    cell = check_cell(cell)
    if not _count(free_k):
        raise ValueError(f"predict: free_k must be an int >= 1 (1: no footprint check), got {free_k!r}")
    if not _count(k):  # 0 or less returned one pose, 2.5 failed as a slice index
        raise ValueError(f"predict: k (top poses returned) must be an int >= 1, got {k!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:  # numpy/torch named no argument
        raise ValueError(f"predict: seed must be an int >= 0, got {seed!r}")
    if num_points is not None and not _count(num_points):  # 0 fed every point, < 0 failed inside torch
        raise ValueError(f"predict: num_points must be an int >= 1, or None for every point, got {num_points!r}")
    check_window(target_yaw, window, grid_radius)
    check_device(device)
    t = check_point(target_xyz, "target_xyz").astype(np.float32)
    check_target(xyz, feat, t)
    if target_yaw is None:
        target_yaw = default_target_yaw(t)
    if floor_xyz is None:
        cell = DEFAULT_FLOOR_CELL if cell is None else cell
        floor_xyz = default_floor_grid(t, xyz, target_yaw, cell=cell, window=window, radius=grid_radius)
    floor = np.asarray(floor_xyz, dtype=np.float32)
    if floor.ndim != 2 or floor.shape[1] not in (2, 3) or len(floor) == 0:  # a 0-d one failed in len()
        raise ValueError(
            f"predict: floor_xyz must be [M, 3] (or [M, 2]) candidates with M >= 1, got shape {floor.shape}"
        )
    if floor.shape[1] == 2:
        floor = np.c_[floor, np.zeros(len(floor), np.float32)]
    check_floor_height(floor)
    # a 0-d number, or an [R1, R2] matrix flattened into one descriptor without a word; [1, R] is a batch of one
    robot = _vector(robot, "robot", "the robot's descriptor numbers").astype(np.float32)
    sample = validate_sample(
        {
            "scene_xyz": xyz,
            "scene_feat": feat,
            "floor_xyz": floor,
            "floor_label": np.zeros(len(floor), np.float32),  # unknown at inference; never read
            "robot": robot,
            "target_xyz": t,
            "target_yaw": np.float32(target_yaw),
            "meta": {"dataset": "predict", "task": task, "view": "", "sample_id": "predict"},
        }
    )
    # the raster's size is known from the candidates alone: refuse a huge one before running the model
    raster_cell = cell if cell is not None else candidate_spacing(floor)
    grid = FloorGrid.from_points(floor, cell=raster_cell)
    check_raster_size(grid.shape, raster_cell, "the returned raster", "candidates (floor_xyz) that cover less floor")
    gen = torch.Generator().manual_seed(seed)
    batch = collate_samples([sample], num_points=num_points, mode="resample" if num_points else "pad", generator=gen)
    restore = kept_state(model)  # a caller's module goes back as it came
    try:
        net = resolve_model(model, model_class, device)
        check_floor_model(net)
        check_task(net, task)
        check_model_inputs(net, feat.shape[1], robot)
        scores = run_model(net, batch)
    finally:
        restore()
    if not np.isfinite(scores).all():
        raise NonFiniteError(
            f"predict: {type(net).__name__} returned {int((~np.isfinite(scores)).sum())} NaN/Inf score(s)"
        )
    poses = best_pose(floor, scores, None, t, k=max(1, k), seed=seed)  # seed: the tie-break, as documented
    chosen = poses[0]
    if free_k > 1:
        ranked = best_pose(floor, scores, None, t, k=free_k, seed=seed)
        chosen = next((p for p in ranked if not footprint_blocked(xyz, p)), ranked[0])
    return Prediction(
        floor_xyz=floor,
        scores=scores,
        grid=grid,
        raster=grid.rasterize(floor, scores),
        best_pose=chosen,
        top_poses=poses,
        target_xyz=t,
        target_yaw=float(target_yaw),
    )


def predict(
    model: Any,
    rgb: np.ndarray | None,
    depth: np.ndarray,
    intrinsics: tuple[float, float, float, float] | np.ndarray,
    camera_pose: np.ndarray,
    target_mask: np.ndarray,
    robot: np.ndarray | list[float],
    floor_xyz: np.ndarray | None = None,
    target_yaw: float | None = None,
    convention: Literal["opengl", "opencv"] = "opengl",
    max_depth: float = MAX_DEPTH,
    k: int = 5,
    num_points: int | None = 4096,
    cell: float | None = None,
    grid_radius: float | None = None,
    model_class: type | str | None = None,
    device: str = "cpu",
    seed: int = 0,
    window: tuple[float, float] = CANDIDATE_WINDOW,
    task: str = "",
    target_xyz: np.ndarray | list[float] | None = None,
    free_k: int = 1,
) -> Prediction:
    """Floor affordance from one RGB-D view (see the module docstring for frames and defaults).

    Args:
        rgb [H, W, 3] uint8 or float in [0, 1] (None: no colour channels); depth [H, W] metres;
        target_mask [H, W] bool: the target's pixels (its points get flag +1, others 0); any one nonzero value
            marks them (0/255 masks), several different ones are refused (a label map, a soft mask);
        target_xyz [3] (base frame): the task's target point as the models learnt it, the centre of the fixture's
            front face on the generated benchmark (the middle of a drawer's or a door's front, the front of the
            cabinet a pick-and-place fills).
            None: the centroid of the mask's points, which lies behind that face (0.07-0.28 m off in the plane,
            median per task, on the dense preset's test views; docs/method.md, "The target point and the floor
            queries", with what it costs); pass it whenever the robot knows it better.
        the rest as in :func:`predict_from_points`.
    """
    check_cell(cell)  # before back-projecting: a bad cell fails at once
    d = np.asarray(depth)
    raw = np.asarray(target_mask)
    marks = np.unique(raw[raw != 0]) if raw.dtype != bool else ()
    if len(marks) > 1:  # a label map or a soft mask: every object, every faint pixel was read as the target
        raise ValueError(
            f"predict: target_mask holds {len(marks)} different nonzero values ({marks[:5].tolist()}...), as a label "
            "map or a soft mask does; pass the target's pixels only (e.g. labels == target_id, probs > 0.5)"
        )
    mask = raw.astype(bool)
    if mask.shape != d.shape:
        raise ValueError(f"predict: target_mask {mask.shape} and depth {d.shape} must have the same shape")
    xyz, valid = backproject_depth(d, intrinsics, camera_pose, convention, max_depth)
    flag = mask.reshape(-1).astype(np.float32)
    feats = [flag[:, None]]
    if rgb is not None:
        c = np.asarray(rgb)
        if c.shape[:2] != d.shape or c.ndim != 3 or c.shape[2] < 3:
            raise ValueError(f"predict: rgb must be [H, W, 3] like depth {d.shape}, got {c.shape}")
        c = c[..., :3].reshape(-1, 3).astype(np.float32)
        if np.asarray(rgb).dtype == np.uint8:
            c = c / 255.0
        else:  # only pixels with valid depth become points: a NaN colour where depth is invalid is never read
            check_float_rgb(c[valid])
        feats.append(c)
    feat = np.concatenate(feats, axis=1)
    tgt = valid & (flag > 0)
    if not tgt.any():
        why = ""
        marked = np.isfinite(d.reshape(-1)) & (d.reshape(-1) > 0) & (flag > 0)
        if marked.any():  # the depth is there but beyond the cut: often millimetres (a uint16 image) for metres
            why = (
                f" (its pixels' depth is {float(d.reshape(-1)[marked].min()):.4g} or more, at or beyond max_depth "
                f"{max_depth} m: depth must be in metres; divide a millimetre image by 1000)"
            )
        raise SampleError(f"predict: target_mask marks no pixel with valid depth{why}; cannot locate the target")
    if target_xyz is None:
        target_xyz = xyz[tgt].mean(axis=0)
    return predict_from_points(
        model,
        xyz[valid],
        feat[valid],
        floor_xyz,
        robot,
        target_xyz,
        target_yaw=target_yaw,
        k=k,
        num_points=num_points,
        cell=cell,
        grid_radius=grid_radius,
        model_class=model_class,
        device=device,
        seed=seed,
        window=window,
        task=task,
        free_k=free_k,
    )


class _CallableModule(types.ModuleType):
    """Makes ``floaff_zoo.predict(...)`` work however the package exposes it.

    Importing the submodule ``floaff_zoo.predict`` sets the package attribute ``predict`` to this
    module (the import system does so after any lazy re-export), so the module itself forwards
    calls to :func:`predict`.
    """

    def __call__(self, *args: Any, **kwargs: Any) -> Prediction:
        return predict(*args, **kwargs)


sys.modules[__name__].__class__ = _CallableModule
