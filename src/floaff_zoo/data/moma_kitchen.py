"""MoMa-Kitchen (ICCV 2025) in the official on-disk layout.

Layout (official ``dataset.py``; see docs/background.md §1.1)::

    <rgbd_root>/RGBD-<scene6>-target_<k>_<obj>_barrier_<NN>/position_<x>_<y>_0_orientation_<q>/
        point_cloud_transformed/world_pcd_transformed.ply          global cloud
        point_cloud_transformed/filtered_pcd_z_less_than_0_02.ply  floor cloud (z < 0.02)
        point_cloud_transformed/target_pcd_transformed.ply         target points
        point_cloud_transformed/barrier_{0,1}_pcd_transformed.ply  optional obstacles (1 only if 0 exists)
        filtered_transformed_results_with_gaussian_success_rate.txt  CSV, column 3 = label per floor point
    <info_root>/<scene6>-target_<k>_<obj>_barrier_<NN>/trial_info.json     {"robot_name": ...}
    <split_dir>/kitchen_train.txt, kitchen_test.txt                         one sample dir per line

Semantics kept from the official loader: label = CSV column 3, one row per floor point, in
order; flag channel +1 within ``flag_radius`` (0.031 m) of a target point, -1 within it of a
barrier point (barriers override the target); robot descriptor from a table keyed by
``robot_name``; eval order = split-file order (``meta['index']`` = position in the delivered
split, ``meta['split_line']`` = line in the split file). Faithful sizes: ``collate_mode: pad``,
``num_points: 16647``, ``num_floor: 10701`` (truncate longer clouds, zero-pad + mask shorter).

Deliberate differences (documented):
* ``scene_xyz`` stays in metres (the contract's base frame). The official global cloud is
  normalised (minus centroid, / max radius): add ``OfficialNormalize`` to ``pre_transforms`` to
  reproduce it.
* The clouds are taken as given in the ``point_cloud_transformed`` frame, read as the robot base
  frame (z up, floor at z = 0; inferred, the official code uses them as is).
* ``target_yaw`` is not in the data. It is estimated (``yaw_estimator``): ``toward_origin``
  (default) = direction from the target centroid toward the frame origin (the robot) projected on
  the floor, i.e. "the front faces the robot that observes it"; ``toward_view`` = toward the view
  position parsed from the folder name (that position is a world position: the option assumes the
  clouds are in that same world frame, which contradicts the base-frame reading above, where the
  view is the origin and ``toward_origin`` is the same estimate; use it only for a copy whose clouds
  are in world coordinates); ``label_centroid`` = toward the label-weighted centroid of the floor
  points (where successful bases stand; uses labels, so never feed it to a model at test time:
  setting up the test split with it warns).
* The official release is incomplete (MoMaKitchen/MoMaKitchen#2): samples with missing or
  unreadable files are skipped and counted, as is a sample whose flags mark no scene point as the target
  (``target_not_in_scene``); setup prints one summary (``strict: true`` raises).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from pathlib import Path
from typing import Any, Literal

import numpy as np
from lightning.pytorch.utilities import rank_zero_warn
from lightning.pytorch.utilities.exceptions import MisconfigurationException

from floaff_zoo.checks import check_number
from floaff_zoo.contract import Sample
from floaff_zoo.data.base import (
    DataConfigError,
    FloAffDataModule,
    check_choice,
    check_flag,
    check_fraction,
    check_size,
    check_transforms,
)
from floaff_zoo.data.cache import RecordDataset, SampleCache, code_digest
from floaff_zoo.data.readers import DataError, SampleRecord, SkipLog, check_finite_arrays
from floaff_zoo.data.transforms import SampleTransform, transforms_config

OFFICIAL_ROBOTS: dict[str, list[float]] = {
    "ur5e": [0.85, 1.03],
    "xarm": [0.7, 0.33],
    "flexiv": [0.78, 1.03],
    "panda": [0.85, 1.03],
}
FLOOR_MAX = 10701
GLOBAL_MAX = 16647
FLAG_RADIUS = 0.031
PCD_DIR = "point_cloud_transformed"
GLOBAL_PLY = "world_pcd_transformed.ply"
FLOOR_PLY = "filtered_pcd_z_less_than_0_02.ply"
TARGET_PLY = "target_pcd_transformed.ply"
BARRIER_PLY = ("barrier_0_pcd_transformed.ply", "barrier_1_pcd_transformed.ply")
LABEL_TXT = "filtered_transformed_results_with_gaussian_success_rate.txt"
INFO_JSON = "trial_info.json"
CONFIG_RE = re.compile(r"^RGBD-(?P<scene>\d+)-target_(?P<k>\d+)_(?P<obj>.+)_barrier_(?P<nb>\d+)$")
VIEW_RE = re.compile(r"^position_(?P<x>-?[\d.eE+-]+?)_(?P<y>-?[\d.eE+-]+?)_(?P<z>-?[\d.eE+-]+?)_orientation_")
YawEstimator = Literal["toward_origin", "toward_view", "label_centroid"]


def _view_xy(name: str) -> list[float] | None:
    """The (x, y) a view folder's name records, or None when the name does not parse (as for a folder without a
    position: only ``yaw_estimator: toward_view`` needs it, and it skips such a sample as ``no_view_position``)."""
    v = VIEW_RE.match(name)
    try:
        return [float(v["x"]), float(v["y"])] if v else None
    except ValueError:  # e.g. "position_3.1.5_..."
        return None


def _check_robot_table(table: dict[str, Any], field: str) -> None:
    """Every entry a list of numbers, all of one length (name -> [arm reach m, base height m, ...])."""
    if not table:
        raise ValueError(f"MoMaKitchenDataModule: {field}: the robot table is empty")
    for name, desc in table.items():
        if not isinstance(name, str):  # the reader matches robot_name case-insensitively: an int key failed there
            raise ValueError(f"MoMaKitchenDataModule: {field}: robot names must be texts, got {name!r}")
        if not isinstance(desc, (list, tuple)) or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in desc
        ):  # a NaN entry made every sample of that robot a 'NaN field robot' skip naming the samples, not the table
            raise ValueError(
                f"MoMaKitchenDataModule: {field}: robot {name!r} needs a list of finite numbers, got {desc!r}"
            )
        if not desc:  # every sample of that robot got an empty descriptor (robot [B, 0]), without a word
            raise ValueError(f"MoMaKitchenDataModule: {field}: robot {name!r} has an empty descriptor")
    lengths = {len(d) for d in table.values()}
    if len(lengths) > 1:
        raise ValueError(f"MoMaKitchenDataModule: {field}: robot entries must all have the same length, got {table}")


def scene_draw(seed: int, scene_id: str) -> float:
    """A scene's seeded uniform draw in [0, 1), a function of (seed, scene id) only."""
    digest = hashlib.sha256(f"{seed}/{scene_id}".encode()).digest()
    return int.from_bytes(digest[:8], "big") / 2.0**64


class LoadError(DataError):
    """A sample file problem; ``kind`` is the skip-summary category."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message, kind)


#: bytes read to find a PLY header's end (headers are a few hundred bytes)
_PLY_HEADER_MAX = 65536
#: bytes of each PLY scalar type (the PLY format's names and their sized aliases)
_PLY_SIZES = {
    **dict.fromkeys(("char", "uchar", "int8", "uint8"), 1),
    **dict.fromkeys(("short", "ushort", "int16", "uint16"), 2),
    **dict.fromkeys(("int", "uint", "int32", "uint32", "float", "float32"), 4),
    **dict.fromkeys(("double", "float64"), 8),
}


def check_ply_complete(path: str | Path, kind: str = "corrupt_ply") -> None:
    """LoadError when the file is shorter than its header's vertex block: open3d reads a truncated PLY with the
    header's point count and fills the missing points from uninitialised memory, without an error.

    Binary files: the file's size after the header must hold ``vertices x record size`` (only the header is read;
    elements declared before the vertices, and vertex list properties, make the size unknowable: not checked).
    ASCII files: the first ``vertices`` non-empty lines each hold one number per vertex property (a row cut short,
    or a word that is no number, was read by open3d from memory too). A header this function cannot parse is left
    to open3d.
    """
    try:
        with open(path, "rb") as f:
            head = f.read(_PLY_HEADER_MAX)
            end = head.find(b"end_header")
            if not head.startswith(b"ply") or end < 0 or b"\n" not in head[end:]:
                return
            start = head.index(b"\n", end) + 1  # the first byte of the data
            fmt, count, record, n_props = _ply_vertex_block(head[:end].decode("ascii", "replace"))
            if not count:
                return
            if fmt.startswith("binary"):
                size = os.fstat(f.fileno()).st_size - start
                if record and size < count * record:
                    raise LoadError(
                        kind,
                        f"{path}: truncated PLY (its header declares {count} vertices of {record} bytes, "
                        f"{count * record} bytes; the file holds {size} after the header)",
                    )
            elif fmt == "ascii":
                f.seek(start)
                _check_ascii_rows(f, count, n_props, path, kind)
    except OSError as exc:
        raise LoadError(kind, f"{path}: unreadable PLY ({exc})") from exc


def _check_ascii_rows(rows: Any, count: int, n_props: int, path: str | Path, kind: str) -> None:
    """LoadError unless the first ``count`` non-empty ``rows`` (bytes lines) each hold ``n_props`` numbers."""
    seen = 0
    for row in rows:
        words = row.split()
        if not words:
            continue
        if seen >= count:
            return
        try:
            [float(w) for w in words]
        except ValueError:
            raise LoadError(kind, f"{path}: corrupt PLY (vertex row {seen} holds a word that is no number)") from None
        if len(words) != n_props:
            raise LoadError(
                kind,
                f"{path}: truncated PLY (its header declares {count} vertices of {n_props} properties; vertex row "
                f"{seen} holds {len(words)})",
            )
        seen += 1
    if seen < count:
        raise LoadError(kind, f"{path}: truncated PLY (its header declares {count} vertices, {seen} lines follow)")


def _ply_vertex_block(header: str) -> tuple[str, int | None, int, int]:
    """(format, vertex count, bytes per vertex record, properties per vertex) of a PLY header; count None when the
    vertex block's place or size cannot be known (another element first, a list property)."""
    fmt, count, record, n_props, seen_other = "", None, 0, 0, False
    for line in header.splitlines():
        words = line.split()
        if words[:1] == ["format"] and len(words) > 1:
            fmt = words[1]
        elif words[:1] == ["element"] and len(words) == 3:
            if words[1] == "vertex" and not seen_other and words[2].isdigit():
                count = int(words[2])
            elif count is None:
                seen_other = True
            else:
                break  # the vertex block is complete before the next element
        elif words[:1] == ["property"] and count is not None:
            if len(words) != 3 or words[1] not in _PLY_SIZES:
                return fmt, None, 0, 0  # a list property: records of varying size
            record += _PLY_SIZES[words[1]]
            n_props += 1
    return fmt, count, record, n_props


def read_ply(path: str | Path, kind: str = "corrupt_ply") -> np.ndarray:
    """xyz [n, 3] float64 of a PLY point cloud (open3d); LoadError naming the file when unreadable, truncated
    (``check_ply_complete``) or empty."""
    import open3d as o3d  # heavy import kept out of module import

    check_ply_complete(path, kind)
    o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    try:
        pcd = o3d.io.read_point_cloud(str(path), format="ply")
    except Exception as exc:  # noqa: BLE001 - open3d raises assorted RuntimeErrors
        raise LoadError(kind, f"{path}: unreadable PLY ({exc})") from exc
    xyz = np.asarray(pcd.points, dtype=np.float64)
    if xyz.ndim != 2 or xyz.shape[0] == 0:
        raise LoadError(kind, f"{path}: unreadable or empty PLY (0 points)")
    if not np.isfinite(xyz).all():
        raise LoadError("nan_coordinates", f"{path}: {int((~np.isfinite(xyz)).any(1).sum())} point(s) with NaN/Inf")
    return xyz


def read_labels(path: str | Path) -> np.ndarray:
    """Column 3 of the comma-separated label file: [M] float32 (LoadError when unreadable)."""
    try:
        lab = np.loadtxt(path, delimiter=",", usecols=3, ndmin=1, dtype=np.float64)
    except (ValueError, IndexError, OSError) as exc:
        raise LoadError("corrupt_labels", f"{path}: cannot read column 3 of the label CSV ({exc})") from exc
    if not np.isfinite(lab).all():
        raise LoadError("nan_labels", f"{path}: {int((~np.isfinite(lab)).sum())} NaN/Inf label(s)")
    return lab.astype(np.float32)


def target_flags(scene: np.ndarray, target: np.ndarray, barriers: list[np.ndarray], radius: float) -> np.ndarray:
    """Flag per scene point: +1 within ``radius`` of a target point, -1 of a barrier point (overrides), else 0.

    scene [N, 3], target [T, 3], barriers list of [K, 3] -> [N] float32.
    """
    from scipy.spatial import cKDTree

    flag = np.zeros(scene.shape[0], dtype=np.float32)
    near_t = cKDTree(target).query(scene, k=1, distance_upper_bound=radius)[0] <= radius
    flag[near_t] = 1.0
    for b in barriers:
        near_b = cKDTree(b).query(scene, k=1, distance_upper_bound=radius)[0] <= radius
        flag[near_b] = -1.0
    return flag


def _no_target_problem(pcd: Path, scene: np.ndarray, target: np.ndarray, radius: float) -> str:
    """Why no scene point of a sample is flagged +1: its target lies away from the scene cloud, or barriers cover
    every scene point near it (barriers override the target)."""
    from scipy.spatial import cKDTree

    nearest = float(cKDTree(scene).query(target, k=1)[0].min())
    if nearest > radius:
        return (
            f"{pcd / TARGET_PLY}: no point of {GLOBAL_PLY} lies within flag_radius {radius} m of the "
            f"{target.shape[0]} target points (nearest {nearest:.3f} m), so no scene point is flagged as the target"
        )
    return f"{pcd / TARGET_PLY}: every scene point within flag_radius {radius} m of the target is flagged as a barrier"


def estimate_target_yaw(
    method: str, target_c: np.ndarray, floor: np.ndarray, label: np.ndarray, view_xy: tuple[float, float] | None
) -> float:
    """Front-normal yaw estimate (module docstring): target_c [3], floor [M, 3], label [M] -> rad."""
    if method == "toward_origin":
        d = -target_c[:2]
    elif method == "toward_view":
        if view_xy is None:
            raise LoadError("no_view_position", "yaw_estimator toward_view needs position_<x>_<y>_... folder names")
        d = np.asarray(view_xy) - target_c[:2]
    elif method == "label_centroid":
        w = label.astype(np.float64)
        d = (floor[:, :2] * w[:, None]).sum(0) / w.sum() - target_c[:2] if w.sum() > 0 else -target_c[:2]
    else:
        raise ValueError(f"unknown yaw_estimator {method!r}; valid: toward_origin, toward_view, label_centroid")
    return math.atan2(float(d[1]), float(d[0])) if np.hypot(*d) > 1e-9 else 0.0


def scene_of(config_dir: str) -> str:
    """A sample's scene id: the digits of ``RGBD-<scene>-target_...``, or the config folder when it does not parse."""
    m = CONFIG_RE.match(config_dir)
    return m["scene"] if m else config_dir


def split_scenes(text: str) -> set[str]:
    """The scene ids (:func:`scene_of`) of a split file's sample lines."""
    return {scene_of(Path(line.strip()).parts[0]) for line in text.splitlines() if line.strip()}


def read_split_file(path: Path) -> str:
    """The text of a split file; ValueError naming it when it is not UTF-8 text or cannot be read."""
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"split file {path} is unreadable ({type(exc).__name__}: {exc})") from exc


class MoMaKitchenReader:
    """Indexes split files and loads samples in the official layout (picklable: used by worker processes).

    Args:
        rgbd_root / info_root: the two official roots.
        robots: robot_name -> descriptor [arm reach m, base height m].
        flag_radius: target/obstacle flag distance (official 0.031 m).
        yaw_estimator: see module docstring.
    """

    def __init__(
        self,
        rgbd_root: Path,
        info_root: Path,
        robots: dict[str, list[float]],
        flag_radius: float,
        yaw_estimator: str,
    ) -> None:
        self.rgbd_root, self.info_root = Path(rgbd_root), Path(info_root)
        self.robots = {k.lower(): [float(v) for v in vals] for k, vals in robots.items()}
        self.flag_radius = flag_radius
        self.yaw_estimator = yaw_estimator
        self._robot_of: dict[str, tuple[str, Any]] = {}

    def config(self) -> dict[str, Any]:
        return {
            "reader": "moma_kitchen",
            "robots": self.robots,
            "flag_radius": self.flag_radius,
            "yaw_estimator": self.yaw_estimator,
        }

    def _robot(self, info: Path) -> tuple[str, Any]:
        """(robot_name, descriptor | problem str) of one trial_info.json, memoised per configuration."""
        key = str(info)
        if key not in self._robot_of:
            try:
                name = json.loads(info.read_text())["robot_name"]
                desc: Any = self.robots.get(str(name).lower())
                if desc is None:
                    desc = (
                        f"unknown robot_name {name!r} (known: {sorted(self.robots)}; add it with robots/extra_robots)"
                    )
                self._robot_of[key] = (str(name), desc)
            except (OSError, ValueError, KeyError, TypeError) as exc:
                self._robot_of[key] = ("", f"unreadable trial_info.json ({type(exc).__name__}: {exc})")
        return self._robot_of[key]

    def index(
        self, split_file: Path, skips: SkipLog, dataset: str = "moma_kitchen", text: str | None = None
    ) -> list[SampleRecord]:
        """Records of one split file, in file order; missing files/unknown robots/repeated lines go to ``skips``.
        ``text``: the file's text when the caller has read it already (``read_split_file``).

        Raises:
            ValueError: the split file cannot be read as UTF-8 text (the message names it).
        """
        lines = [ln.strip() for ln in (read_split_file(split_file) if text is None else text).splitlines()]
        records: list[SampleRecord] = []
        first_line: dict[str, int] = {}
        for line_no, rel in enumerate(lines):
            if not rel:
                continue
            if rel in first_line:  # one sample twice would count twice in the metrics
                skips.add("duplicate_line", split_file, f"line {line_no + 1} repeats line {first_line[rel] + 1}: {rel}")
                continue
            first_line[rel] = line_no
            d = self.rgbd_root / rel
            pcd = d / PCD_DIR
            need = [
                ("missing_global", pcd / GLOBAL_PLY),
                ("missing_floor", pcd / FLOOR_PLY),
                ("missing_target", pcd / TARGET_PLY),
                ("missing_labels", d / LABEL_TXT),
            ]
            if not d.is_dir():
                skips.add("missing_dir", d, "sample directory listed in the split file does not exist")
                continue
            missing = [(k, p) for k, p in need if not p.is_file()]
            if missing:
                skips.add(missing[0][0], missing[0][1], "file missing")
                continue
            config_dir = Path(rel).parts[0]
            info = self.info_root / (config_dir[5:] if config_dir.startswith("RGBD-") else config_dir) / INFO_JSON
            if not info.is_file():
                skips.add("missing_info", info, "trial_info.json missing")
                continue
            robot_name, desc = self._robot(info)
            if isinstance(desc, str):
                skips.add("unknown_robot" if robot_name else "corrupt_info", info, desc)
                continue
            barriers = []
            if (pcd / BARRIER_PLY[0]).is_file():
                barriers.append(str(pcd / BARRIER_PLY[0]))
                if (pcd / BARRIER_PLY[1]).is_file():
                    barriers.append(str(pcd / BARRIER_PLY[1]))
            m = CONFIG_RE.match(config_dir)
            view_xy = _view_xy(Path(rel).name)
            sources = [str(p) for _, p in need] + barriers + [str(info)]
            meta = {
                "dataset": dataset,
                "task": "",
                "view": "",
                "scene_id": scene_of(config_dir),
                "layout_id": scene_of(config_dir),
                "style_id": -1,
                "sample_id": rel,
                "config_id": config_dir,
                "target": m["obj"] if m else "",
                "robot_name": robot_name,
                "split_line": line_no,
            }
            records.append(
                SampleRecord(
                    rel, sources, meta, {"dir": str(d), "barriers": barriers, "robot": desc, "view_xy": view_xy}
                )
            )
        return records

    def load(self, rec: SampleRecord) -> Sample:
        """Parse one sample (PLY + CSV + KD-tree flags); LoadError naming the file on bad data."""
        d = Path(rec.payload["dir"])
        pcd = d / PCD_DIR
        scene = read_ply(pcd / GLOBAL_PLY)
        floor = read_ply(pcd / FLOOR_PLY)
        target = read_ply(pcd / TARGET_PLY)
        barriers = [read_ply(p) for p in rec.payload["barriers"]]
        label = read_labels(d / LABEL_TXT)
        if label.shape[0] != floor.shape[0]:
            raise LoadError(
                "label_count",
                f"{d / LABEL_TXT}: {label.shape[0]} label rows but the floor cloud "
                f"{FLOOR_PLY} has {floor.shape[0]} points",
            )
        if label.min() < 0 or label.max() > 1:
            raise LoadError("label_range", f"{d / LABEL_TXT}: labels outside [0, 1] ({label.min()}, {label.max()})")
        flag = target_flags(scene, target, barriers, self.flag_radius)
        if not (flag > 0).any():  # no +1 point: the model would train on this sample without its target, silently
            raise LoadError("target_not_in_scene", _no_target_problem(pcd, scene, target, self.flag_radius))
        tc = target.mean(0)
        view_xy = tuple(rec.payload["view_xy"]) if rec.payload.get("view_xy") else None
        yaw = estimate_target_yaw(self.yaw_estimator, tc, floor, label, view_xy)
        sample = {
            "scene_xyz": scene.astype(np.float32),
            "scene_feat": flag[:, None],
            "floor_xyz": floor.astype(np.float32),
            "floor_label": label,
            "robot": np.asarray(rec.payload["robot"], dtype=np.float32),
            "target_xyz": tc.astype(np.float32),
            "target_yaw": np.float32(yaw),
            "meta": {},
        }
        check_finite_arrays(sample, str(d))
        return sample


class MoMaKitchenDataModule(FloAffDataModule):
    """MoMa-Kitchen from the official layout (module docstring for semantics and differences).

    Args:
        root: dataset root; defaults below are relative to it.
        rgbd_root: sample directories (default ``<root>/rgbd``).
        info_root: ``trial_info.json`` directories (default ``<root>/info``).
        split_dir: split files (default ``<root>/data_split``).
        train_split / test_split: split file names.
        val_fraction: fraction of the train *scenes* (6-digit scene id) held out as val, each scene by its own
            draw seeded by ``seed`` (:meth:`_split_val`); 0 = validate on the test split each epoch, as the official
            code does.
        robots: robot table replacing the official one (name -> [arm reach m, base height m]).
        extra_robots: entries added to the table (e.g. the paper's Elephant/Realman once known).
        flag_radius: target/obstacle flag radius (m).
        yaw_estimator: ``toward_origin`` | ``toward_view`` | ``label_centroid`` (module docstring).
        max_samples: keep only the first N records of each split file (smoke runs; None = all).
        strict: raise on the first missing/corrupt file, unknown robot or bad label file.
        validate: load every sample at setup (fills the cache; bad ones are skipped and counted);
            False = only file-existence checks at setup, bad samples are replaced at load time.
        cache: keep preprocessed tensors on disk (``cache_dir`` or ``<root>/.cache``).
        cache_hash: ``stat`` (size+mtime) or ``content`` (bytes) signature of source files.
        pre_transforms: deterministic transforms applied once before caching (e.g. ``OfficialNormalize``,
            ``ResamplePoints(method=fps)``).
        (the rest: see :class:`FloAffDataModule`; fast mode = ``collate_mode: resample`` with
        ``num_points: 4096``; faithful mode = ``pad`` with 16647 / 10701 and ``eval_batch_size: 64``)
    """

    def __init__(
        self,
        root: str = "data/moma_kitchen",
        rgbd_root: str | None = None,
        info_root: str | None = None,
        split_dir: str | None = None,
        train_split: str = "kitchen_train.txt",
        test_split: str = "kitchen_test.txt",
        val_fraction: float = 0.05,
        robots: dict[str, list[float]] | None = None,
        extra_robots: dict[str, list[float]] | None = None,
        flag_radius: float = FLAG_RADIUS,
        yaw_estimator: YawEstimator = "toward_origin",
        max_samples: int | None = None,
        strict: bool = False,
        validate: bool = True,
        cache: bool = True,
        cache_dir: str | None = None,
        cache_hash: Literal["stat", "content"] = "stat",
        pre_transforms: list[SampleTransform] | None = None,
        batch_size: int = 8,
        eval_batch_size: int | None = None,
        num_workers: int = 0,
        num_points: int | None = 4096,
        num_floor: int | None = None,
        collate_mode: Literal["pad", "resample"] = "resample",
        seed: int = 0,
        train_transforms: list[SampleTransform] | None = None,
        eval_transforms: list[SampleTransform] | None = None,
        persistent_train_workers: bool = False,
    ) -> None:
        super().__init__(
            batch_size,
            eval_batch_size,
            num_workers,
            num_points,
            num_floor,
            collate_mode,
            seed,
            train_transforms,
            eval_transforms,
            persistent_train_workers,
        )
        check_fraction("val_fraction", val_fraction)  # False was 0 (validate on test), a text a bare TypeError
        for name, flag in (("strict", strict), ("validate", validate), ("cache", cache)):
            check_flag(name, flag)
        check_choice("cache_hash", cache_hash, ("stat", "content"))
        if yaw_estimator not in ("toward_origin", "toward_view", "label_centroid"):
            raise ValueError(
                f"unknown yaw_estimator {yaw_estimator!r}; valid: toward_origin, toward_view, label_centroid"
            )
        self.root = Path(root)
        self.rgbd_root = Path(rgbd_root) if rgbd_root else self.root / "rgbd"
        self.info_root = Path(info_root) if info_root else self.root / "info"
        self.split_dir = Path(split_dir) if split_dir else self.root / "data_split"
        self.split_files = {"train": train_split, "test": test_split}
        self.val_fraction = val_fraction
        table = dict(OFFICIAL_ROBOTS if robots is None else robots)
        table.update(extra_robots or {})
        _check_robot_table(table, "robots" if extra_robots is None else "robots / extra_robots")
        # 0, a negative or a NaN radius flagged no point at all, silently: every sample lost its target
        check_number("data.flag_radius", flag_radius, strict=True, error=DataConfigError, note="a distance in metres")
        self.reader = MoMaKitchenReader(self.rgbd_root, self.info_root, table, flag_radius, yaw_estimator)
        check_size("max_samples", max_samples, 1, "every record")  # 0 kept all, a negative one dropped the last
        self.max_samples = max_samples
        self.strict = strict
        self.validate = validate
        self.cache_dir = Path(cache_dir) if cache_dir else self.root / ".cache"
        self.use_cache = cache
        self.cache_hash = cache_hash
        self.pre_transforms = check_transforms("pre_transforms", pre_transforms)
        self.skips: dict[str, SkipLog] = {}

    def _split_text(self, split: str) -> str:
        """The text of ``split``'s split file; MisconfigurationException naming it when it is not a file, not UTF-8
        text or empty."""
        path = self.split_dir / self.split_files[split]
        if not path.is_file():
            what = "is not a file" if path.exists() else "not found"
            raise MisconfigurationException(f"MoMaKitchenDataModule: split file {path} {what}")
        try:
            text = read_split_file(path)
        except ValueError as exc:
            raise MisconfigurationException(f"MoMaKitchenDataModule: {exc}") from exc
        if not text.strip():
            raise MisconfigurationException(f"MoMaKitchenDataModule: split file {path} is empty")
        return text

    def _split_texts(self) -> dict[str, str]:
        """Split name -> text of each split file that is usable (:meth:`_split_text`), read once per setup: the
        unseen-scene check and the indexing share it (each read both files again). A file left out is named by
        :meth:`_records` when its split is set up."""
        texts: dict[str, str] = {}
        for split in self.split_files:
            try:
                texts[split] = self._split_text(split)
            except MisconfigurationException:
                continue
        return texts

    def _records(self, split: str, skips: SkipLog, texts: dict[str, str]) -> list[SampleRecord]:
        """``split``'s records from its text in ``texts`` (:meth:`_split_texts`); a split missing there is read
        again, for the exception that names its file."""
        text = texts[split] if split in texts else self._split_text(split)
        recs = self.reader.index(self.split_dir / self.split_files[split], skips, "moma_kitchen", text)
        return recs[: self.max_samples] if self.max_samples else recs

    def _check_unseen_test(self, texts: dict[str, str]) -> None:
        """MisconfigurationException naming both files when the train and test split files share a scene: the test
        split holds unseen scenes (docs/background.md), so a shared one tests the model on a kitchen it trained on.
        Checked only when both files' texts are in ``texts`` (``_records`` names a file that is not)."""
        if not all(s in texts for s in ("train", "test")):
            return
        paths = [self.split_dir / self.split_files[s] for s in ("train", "test")]
        shared = sorted(split_scenes(texts["train"]) & split_scenes(texts["test"]))
        if shared:
            raise MisconfigurationException(
                f"MoMaKitchenDataModule: {paths[0]} and {paths[1]} share {len(shared)} scene(s) "
                f"({', '.join(shared[:3])}{', ...' if len(shared) > 3 else ''}): the test split must hold unseen scenes"
            )

    def _split_val(self, train: list[SampleRecord]) -> tuple[list[SampleRecord], list[SampleRecord]]:
        """Scene-level seeded hold-out: (train, val) records, each in split-file order.

        A scene is held out when its own seeded draw (:func:`scene_draw`) is below ``val_fraction``, so whether it
        validates does not depend on which other scenes survived indexing or ``max_samples`` (a permutation of the
        surviving scenes moved scenes between train and val when one folder was missing). At least one scene is held
        out and one kept when there are two or more: the lowest draws, then the highest, decide those edge cases.
        """
        scenes = sorted({r.meta["scene_id"] for r in train}, key=lambda s: (scene_draw(self.seed, s), s))
        val_scenes = {s for s in scenes if scene_draw(self.seed, s) < self.val_fraction}
        if self.val_fraction > 0 and len(scenes) > 1:
            val_scenes = val_scenes or {scenes[0]}
            if len(val_scenes) == len(scenes):
                val_scenes.discard(scenes[-1])
        return (
            [r for r in train if r.meta["scene_id"] not in val_scenes],
            [r for r in train if r.meta["scene_id"] in val_scenes],
        )

    def _dataset(self, name: str, records: list[SampleRecord], skips: SkipLog) -> RecordDataset:
        cache = None
        if self.use_cache:
            cfg = {**self.reader.config(), "pre_transforms": transforms_config(self.pre_transforms), "seed": self.seed}
            code = code_digest([self.reader, *self.pre_transforms])
            if code is not None:  # a user's reader or pre-transform: its edits re-parse, as the package's do
                cfg["code"] = code
            cache = SampleCache(self.cache_dir, "moma_kitchen", cfg, self.cache_hash)
        ds = RecordDataset(
            records, self.reader.load, cache, self.pre_transforms, self.seed, f"moma_kitchen/{name}", self.strict
        )
        if self.validate:
            ds.build(skips, self.num_workers)
        return ds

    def setup(self, stage: str | None = None) -> None:
        for p, what in (
            (self.root, "root"),
            (self.rgbd_root, "rgbd_root"),
            (self.info_root, "info_root"),
            (self.split_dir, "split_dir"),
        ):
            if not p.is_dir():
                why = "is a file, not a folder" if p.exists() else "does not exist"
                raise MisconfigurationException(f"MoMaKitchenDataModule: {what} {p} {why}")
        want = {"fit": ["train", "val"], "validate": ["val"], "test": ["test"], "predict": ["test"]}.get(
            stage or "", ["train", "val", "test"]
        )
        if "val" in want and self.val_fraction == 0:
            want = [w for w in want if w != "val"] + ["test"]
        todo = [s for s in want if s not in self.datasets]
        if not todo:
            return
        texts = self._split_texts()
        self._check_unseen_test(texts)
        if "test" in todo and self.reader.yaw_estimator == "label_centroid":
            rank_zero_warn(
                "MoMaKitchenDataModule: yaw_estimator label_centroid estimates the test samples' target_yaw from "
                "their labels: a model that reads target_yaw (e.g. eval_yaw_source gt) sees the test labels"
            )
        if ("train" in todo or "val" in todo) and self.val_fraction > 0:
            skips = SkipLog("moma_kitchen train+val", self.strict)
            tr, va = self._split_val(self._records("train", skips, texts))
            self.datasets["train"] = self._dataset("train", tr, skips)
            self.datasets["val"] = self._dataset("val", va, skips)
            self.skips["train"] = self.skips["val"] = skips
            self._report(skips, ["train", "val"])
        elif "train" in todo:
            skips = SkipLog("moma_kitchen train", self.strict)
            self.datasets["train"] = self._dataset("train", self._records("train", skips, texts), skips)
            self.skips["train"] = skips
            self._report(skips, ["train"])
        if "test" in todo or (self.val_fraction == 0 and "val" in want and "test" not in self.datasets):
            skips = SkipLog("moma_kitchen test", self.strict)
            self.datasets["test"] = self._dataset("test", self._records("test", skips, texts), skips)
            self.skips["test"] = skips
            self._report(skips, ["test"])
        if self.val_fraction == 0 and "test" in self.datasets:
            self.datasets["val"] = self.datasets["test"]  # official: evaluate the test split every epoch
        if "test" in self.datasets:
            self.datasets["predict"] = self.datasets["test"]
        for split in todo:
            if split in self.datasets and len(self.datasets[split]) == 0:
                hint = " (val_fraction > 0 needs at least 2 train scenes)" if split == "val" else ""
                raise MisconfigurationException(
                    f"MoMaKitchenDataModule: the '{split}' split has no usable sample{hint}\n"
                    f"{self.skips[split].summary()}"
                )

    def skip_log(self, split: str) -> SkipLog | None:
        """What setup skipped from ``split``'s split file (train and val share one), for a report; None when that
        split was not set up."""
        return self.skips.get(split)

    def _report(self, skips: SkipLog, splits: list[str]) -> None:
        sizes = ", ".join(f"{s} {len(self.datasets[s])}" for s in splits)
        print(f"MoMaKitchenDataModule: {sizes} samples. {skips.summary()}")


__all__ = [
    "FLAG_RADIUS",
    "FLOOR_MAX",
    "GLOBAL_MAX",
    "OFFICIAL_ROBOTS",
    "LoadError",
    "MoMaKitchenDataModule",
    "MoMaKitchenReader",
    "estimate_target_yaw",
    "read_labels",
    "read_ply",
    "target_flags",
]
