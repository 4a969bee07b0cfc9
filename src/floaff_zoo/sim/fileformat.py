"""On-disk format of a generated FloAff benchmark (see docs/data_format.md), with atomic writers and checked readers.

Layout::

    <root>/manifest.json
    <root>/<benchmark>/<scene_id>/scene.json          # committed last: a scene exists iff scene.json has status "ok"
    <root>/<benchmark>/<scene_id>/views/<view_id>.npz
    <root>/<benchmark>/<scene_id>/{topdown,front,side}.png

A scene is built in ``<root>/<benchmark>/.staging/<scene_id>/`` (scene.json written last there) and moved into place
with one ``os.replace`` of the directory, so a killed run never leaves a half-written scene directory behind.

Versions (``format_version`` in scene.json and manifest.json; the readers here take both):

* 1 (generator 1.x): every view stores the scene's candidate cells on free floor (``candidates.on_floor``) with the
  smoothed label: the same set in every view, shaped by the annotation filters.
* 2 (generator 2.x): every view stores the label-grid cells its own cloud observes as ground
  (``floaff_zoo.floor.observed_cells``) with the per-cell labels of ``annotate.cell_labels``, plus ``floor_known``
  and ``floor_index``. A v1 view reads with ``floor_known`` all true.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from floaff_zoo import atomic
from floaff_zoo.atomic import atomic_write
from floaff_zoo.checks import check_number
from floaff_zoo.names import BENCHMARKS as BENCHMARKS  # defined once there; re-exported (the scripts read it here)
from floaff_zoo.names import TASKS

__all__ = [
    "FORMAT_VERSION",
    "MANIFEST",
    "SCENE_JSON",
    "STAGING",
    "SUPPORTED_FORMAT_VERSIONS",
    "V2_VIEW_FIELDS",
    "VIEW_FIELDS",
    "CorruptFileError",
    "FormatError",
    "NonFiniteFieldError",
    "atomic_save_npz",
    "atomic_write_bytes",
    "atomic_write_json",
    "check_format_version",
    "commit_scene_dir",
    "committed",
    "committed_record",
    "iter_scenes",
    "labels_digest",
    "labels_version",
    "read_json",
    "read_manifest",
    "read_sample",
    "read_scene",
    "read_view",
    "retire_scene",
    "scene_dir",
    "scene_is_done",
    "staging_dir",
    "validate_view",
]

FORMAT_VERSION = 2
SUPPORTED_FORMAT_VERSIONS = (1, 2)
MANIFEST = "manifest.json"
SCENE_JSON = "scene.json"
STAGING = ".staging"
RETIRED = ".retired"  # scene folders a rerun replaced or could not replace (kept, never read)
SPLITS = ("train", "test")  # scene.json's "split"

# name -> (dtype, shape pattern); "N"/"M"/"H"/"W" are free sizes shared across fields of one view
VIEW_FIELDS: dict[str, tuple[str, tuple[Any, ...]]] = {
    "scene_xyz": ("float32", ("N", 3)),
    "scene_feat": ("float32", ("N", 4)),
    "floor_xyz": ("float32", ("M", 3)),
    "floor_label": ("float32", ("M",)),
    "robot": ("float32", (2,)),
    "target_xyz": ("float32", (3,)),
    "target_yaw": ("float32", ()),
    "base_pose_world": ("float32", (3,)),
}
#: required from format 2 on (optional, and absent, in format 1 files)
V2_VIEW_FIELDS: dict[str, tuple[str, tuple[Any, ...]]] = {
    "floor_known": ("bool", ("M",)),
    "floor_index": ("int32", ("M",)),
}
OPTIONAL_VIEW_FIELDS: dict[str, tuple[str, tuple[Any, ...]]] = {
    "rgb": ("uint8", ("H", "W", 3)),
    "depth": ("float32", ("H", "W")),
}


class FormatError(ValueError):
    """A dataset file is missing, corrupt or does not follow the format; the message names the file and field."""


class CorruptFileError(FormatError):
    """A file that cannot be decoded (cut-off npz, invalid JSON): readers count it apart from a field problem."""


class NonFiniteFieldError(FormatError):
    """A field holding NaN or Inf: readers count it apart from other field problems."""


# ------------------------------------------------------------------------------------------------ atomic writes
def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write bytes to path via a temp file in the same directory + os.replace (never a partial file)."""
    atomic_write(path, lambda f: f.write(data), durable=True)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def atomic_write_json(path: str | Path, obj: Any) -> None:
    """A benchmark's JSON (indent 1, sorted keys, numpy arrays as lists) written atomically and durably (as
    :func:`atomic_write_bytes`); ``runs.data_fingerprint`` hashes these bytes, so the layout stays as it is."""
    atomic.atomic_write_json(path, obj, indent=1, sort_keys=True, default=_json_default, durable=True)


def atomic_save_npz(path: str | Path, arrays: dict[str, np.ndarray]) -> None:
    """np.savez_compressed to a temp file + os.replace. Path must end in .npz."""
    path = Path(path)
    if path.suffix != ".npz":
        raise ValueError(f"{path}: view files must end in .npz")
    pickled = [k for k, a in arrays.items() if _pickled(a)]
    if pickled:
        raise ValueError(f"{path}: field {pickled[0]!r} is an object or ragged array, which readers refuse (pickled)")
    # durable as atomic_write_bytes: after a power loss a committed scene holds whole views
    atomic_write(path, lambda f: np.savez_compressed(f, **arrays), durable=True)


def _pickled(a: Any) -> bool:
    """Whether numpy would store ``a`` pickled (an object array: dicts, None) or refuse it (a ragged list): written
    without a word, such a view was refused by every reader (``allow_pickle=False``)."""
    try:
        return np.asarray(a).dtype.hasobject
    except ValueError:
        return True


def read_json(path: str | Path) -> Any:
    """Load a JSON file; FormatError naming the file when missing or corrupt."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise FormatError(f"{path}: file not found") from exc
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CorruptFileError(f"{path}: corrupt JSON ({exc})") from exc
    except OSError as exc:  # a directory in its place, no permission, a failing disk
        raise FormatError(f"{path}: unreadable ({type(exc).__name__}: {exc})") from exc


# ------------------------------------------------------------------------------------------------ scene dirs
def _folder(who: str, what: str, name: Any) -> str:
    """``name`` when it is one folder's name; ValueError naming ``who``'s ``what`` otherwise. A scene_id read from a
    hand-edited manifest ("", "..", an absolute path) made ``retire_scene`` delete a folder outside the dataset."""
    if not isinstance(name, str) or name in ("", ".", "..") or "/" in name or os.sep in name:
        raise ValueError(f"{who}: {what} must be one folder name (not empty, '.' or '..', no '/'), got {name!r}")
    return name


def scene_dir(root: str | Path, benchmark: str, scene_id: str) -> Path:
    """Final directory of one scene; ValueError when ``benchmark`` or ``scene_id`` is not one folder name."""
    return Path(root) / _folder("scene_dir", "benchmark", benchmark) / _folder("scene_dir", "scene_id", scene_id)


def retire_scene(root: str | Path, benchmark: str, scene_id: str) -> Path | None:
    """Move a committed scene folder out of the readers' way into ``<benchmark>/.retired/`` (kept for inspection;
    a folder retired before under the same id is replaced). Returns the new place, or None when there was none."""
    src = scene_dir(root, benchmark, scene_id)
    if not src.is_dir():
        return None
    dst = Path(root) / benchmark / RETIRED / scene_id
    dst.parent.mkdir(parents=True, exist_ok=True)
    if dst.exists():
        shutil.rmtree(dst)
    os.replace(src, dst)
    return dst


def staging_dir(root: str | Path, benchmark: str, scene_id: str) -> Path:
    """Work directory of one scene while it is generated (removed or moved on commit); names checked as in
    :func:`scene_dir`."""
    return scene_dir(root, benchmark, STAGING) / _folder("staging_dir", "scene_id", scene_id)


def committed_record(root: str | Path, benchmark: str, scene_id: str) -> dict[str, Any] | None:
    """The scene.json of a committed scene (it parses and has status "ok"), read once; None for any other."""
    try:
        rec = read_json(scene_dir(root, benchmark, scene_id) / SCENE_JSON)
    except FormatError:
        return None
    return committed(rec)


def committed(rec: Any) -> dict[str, Any] | None:
    """A parsed scene.json ``rec`` when it is a committed scene's (an object with status "ok"), else None."""
    return rec if isinstance(rec, dict) and rec.get("status") == "ok" else None


def scene_is_done(root: str | Path, benchmark: str, scene_id: str) -> bool:
    """True when the scene's scene.json exists, parses and has status "ok" (resume skips such scenes)."""
    return committed_record(root, benchmark, scene_id) is not None


def commit_scene_dir(stage: Path, final: Path) -> None:
    """Move a finished staging directory into place (scene.json must already be in it).

    A stale final directory (a previous run died before committing, or the scene is being regenerated) is moved
    aside first and deleted after the new one is in place.
    """
    if not (stage / SCENE_JSON).is_file():
        raise FormatError(f"{stage}: refusing to commit a scene directory without {SCENE_JSON}")
    final.parent.mkdir(parents=True, exist_ok=True)
    trash = None
    if final.exists():
        trash = final.parent / STAGING / f"{final.name}.old.{os.getpid()}"
        if trash.exists():
            shutil.rmtree(trash)
        os.replace(final, trash)
    os.replace(stage, final)
    if trash is not None:
        shutil.rmtree(trash, ignore_errors=True)


# ------------------------------------------------------------------------------------------------ validation
def _check_shape(path: Path, name: str, arr: np.ndarray, dtype: str, pattern: tuple[Any, ...], sizes: dict) -> None:
    if arr.dtype != np.dtype(dtype):
        raise FormatError(f"{path}: field {name!r} has dtype {arr.dtype}, expected {dtype}")
    if arr.ndim != len(pattern):
        raise FormatError(f"{path}: field {name!r} has shape {arr.shape}, expected {pattern}")
    for dim, want in zip(arr.shape, pattern):
        if isinstance(want, str):
            if sizes.setdefault(want, dim) != dim:
                raise FormatError(f"{path}: field {name!r} has {want}={dim}, other fields have {want}={sizes[want]}")
        elif dim != want:
            raise FormatError(f"{path}: field {name!r} has shape {arr.shape}, expected {pattern}")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        raise NonFiniteFieldError(f"{path}: field {name!r} contains NaN or inf")


def labels_version(version: str) -> tuple[str, ...]:
    """'2.1.0' -> ('2', '1'): the part of a generator version that labels depend on (a patch release changes none)."""
    return tuple(version.split(".")[:2])


def check_format_version(version: Any, path: str | Path) -> int:
    """The format version as an int; FormatError naming the file when this reader does not know it."""
    if isinstance(version, bool) or version not in SUPPORTED_FORMAT_VERSIONS:  # true == 1 in Python
        raise FormatError(
            f"{path}: format_version {version!r} is not supported by this reader "
            f"(supported: {list(SUPPORTED_FORMAT_VERSIONS)}); update floaff-zoo"
        )
    return int(version)


#: largest |z| (m) of a view's floor points, which the format puts at z = 0 in the base frame
FLOOR_Z_TOLERANCE = 1e-3


def validate_view(
    arrays: dict[str, np.ndarray],
    path: str | Path = "<view>",
    format_version: int | None = None,
    n_cells: int | None = None,
) -> None:
    """Check one view's arrays against VIEW_FIELDS (dtypes, shapes, shared N/M, finite, labels in [0,1], floor z 0).

    format_version >= 2 also requires V2_VIEW_FIELDS; None checks them only when present. n_cells: the size of the
    scene's candidate grid, which every ``floor_index`` entry must index (None: not checked).
    """
    path = Path(path)
    sizes: dict[str, int] = {}
    required = dict(VIEW_FIELDS, **(V2_VIEW_FIELDS if (format_version or 1) >= 2 else {}))
    for name, (dtype, pattern) in required.items():
        if name not in arrays:
            raise FormatError(f"{path}: missing field {name!r}")
        _check_shape(path, name, np.asarray(arrays[name]), dtype, pattern, sizes)
    for name, (dtype, pattern) in {**V2_VIEW_FIELDS, **OPTIONAL_VIEW_FIELDS}.items():
        if name in arrays and name not in required:
            _check_shape(path, name, np.asarray(arrays[name]), dtype, pattern, sizes)
    idx = np.asarray(arrays.get("floor_index", np.zeros(0, np.int32)))
    if idx.size and idx.min() < 0:
        raise FormatError(f"{path}: field 'floor_index' has negative entries")
    if idx.size > 1 and np.any(np.diff(idx) <= 0):  # the format's grid order, each cell once
        raise FormatError(f"{path}: field 'floor_index' is not strictly increasing (grid order, each cell once)")
    if idx.size and n_cells is not None and idx.max() >= n_cells:
        raise FormatError(
            f"{path}: field 'floor_index' reaches cell {idx.max()}, but the scene's candidate grid has {n_cells} cells"
        )
    floor_z = np.asarray(arrays["floor_xyz"])[:, 2]
    if floor_z.size and np.abs(floor_z).max() > FLOOR_Z_TOLERANCE:  # candidate base positions: on the floor
        raise FormatError(f"{path}: field 'floor_xyz' has z up to {np.abs(floor_z).max():.4g} m; the format's is 0")
    lab = np.asarray(arrays["floor_label"])
    if lab.size and (lab.min() < 0.0 or lab.max() > 1.0):
        raise FormatError(f"{path}: field 'floor_label' outside [0, 1] (min {lab.min()}, max {lab.max()})")
    flag = np.asarray(arrays["scene_feat"])[:, 0]
    if flag.size and not np.all(np.isin(flag, (-1.0, 0.0, 1.0))):
        raise FormatError(f"{path}: field 'scene_feat' channel 0 (target flag) must be -1, 0 or +1")


def read_view(path: str | Path, format_version: int | None = None, n_cells: int | None = None) -> dict[str, np.ndarray]:
    """Load and validate one ``views/<view_id>.npz`` (see validate_view; n_cells: the scene's candidate count, so
    ``floor_index`` is checked against it); FormatError naming the file/field."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except FileNotFoundError as exc:
        raise FormatError(f"{path}: file not found") from exc
    except OSError as exc:  # the disk or the file system failed, maybe for the moment: not the file's content
        raise FormatError(f"{path}: unreadable ({type(exc).__name__}: {exc})") from exc
    except Exception as exc:  # noqa: BLE001 - zipfile.BadZipFile, EOFError, ValueError (pickled data), ...
        raise CorruptFileError(f"{path}: corrupt npz ({type(exc).__name__}: {exc})") from exc
    validate_view(arrays, path, format_version, n_cells)
    return arrays


_SCENE_KEYS = ("benchmark", "split", "spec", "task", "target", "candidates", "labels", "views", "status")


def read_scene(scene_path: str | Path) -> dict[str, Any]:
    """Load and check a scene.json (path to the file or its directory); adds key "dir" (the scene directory).

    A file without ``format_version`` is read as version 1 (and gets the key); an unknown version is a FormatError.
    """
    p = Path(scene_path)
    if p.is_dir():
        p = p / SCENE_JSON
    rec = read_json(p)
    if not isinstance(rec, dict):
        raise FormatError(f"{p}: expected a JSON object")
    for k in _SCENE_KEYS:
        if k not in rec:
            raise FormatError(f"{p}: missing key {k!r}")
    # a split 'Train' or a misspelt task matched no filter of iter_scenes, so the scene was left out without a word
    for k, known in (("split", SPLITS), ("task", TASKS), ("benchmark", BENCHMARKS)):
        if rec[k] not in known:
            raise FormatError(f"{p}: {k} {rec[k]!r} is not one of {list(known)}")
    if not isinstance(rec["spec"], dict):  # read_sample failed on it with an AttributeError naming no file
        raise FormatError(f"{p}: spec must be a record (layout_id, style_id, seed), got {rec['spec']!r:.80}")
    rec["format_version"] = check_format_version(rec.get("format_version", 1), p)
    # the generator's format 2 also keeps the per-cell label rule's inputs and result (docs/data_format.md): where a
    # file has them they must cover the grid like the labels
    keys = [("labels", "success"), ("labels", "label")]
    extra = [("labels", "cell_label"), ("labels", "known"), ("candidates", "status")]
    # the per-cell lists a script indexes by cell (fresh labels, repeat rollouts): a short one zeroed the cells past it
    extra += [("candidates", "yaw"), ("candidates", "valid"), ("candidates", "on_floor")]
    keys += [(a, b) for a, b in extra if isinstance(rec.get(a), dict) and b in rec[a]]
    try:
        m = len(rec["candidates"]["xy"])
        sizes = {f"{a}.{b}": len(rec[a][b]) for a, b in keys}
    except (KeyError, TypeError) as exc:  # e.g. candidates a list, labels without success
        names = ", ".join(f"{a}.{b}" for a, b in keys)
        raise FormatError(f"{p}: candidates.xy, {names} must be lists ({exc!r})") from exc
    for k, n in sizes.items():
        if n != m:
            raise FormatError(f"{p}: {k} has {n} entries, candidates.xy has {m}")
    shape = rec["candidates"].get("grid_shape")
    if shape is not None and (
        not isinstance(shape, list)
        or len(shape) != 2
        or not all(isinstance(v, int) for v in shape)
        or shape[0] * shape[1] != m
    ):  # the labels are smoothed and read on this grid: another shape mixes rows
        raise FormatError(f"{p}: candidates.grid_shape {shape} does not hold the {m} cells of candidates.xy")
    _check_grid(rec["candidates"], p)
    for k in ("label", "cell_label"):
        if k in rec["labels"]:
            _finite_numbers(rec["labels"][k], f"labels.{k}", p)
    rec["dir"] = str(p.parent)
    return rec


def _finite_numbers(value: Any, field: str, p: Path) -> np.ndarray:
    """``value`` as a float64 array; FormatError naming ``field`` of file ``p`` when it does not hold numbers,
    NonFiniteFieldError when one is NaN or Inf."""
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise FormatError(f"{p}: {field} must hold numbers ({exc})") from exc
    if not np.isfinite(a).all():
        raise NonFiniteFieldError(f"{p}: {field} holds NaN or Inf values")
    return a


def _check_grid(cand: dict[str, Any], p: Path) -> None:
    """Refuse a candidate grid the scripts would read wrong without a word: ``xy`` not [M, 2] finite numbers, or a
    ``cell`` spacing that is not a finite number > 0 (a NaN there made every cell index garbage, a NaN cell centre the
    nearest-cell lookups skip it)."""
    xy = _finite_numbers(cand["xy"], "candidates.xy", p)
    if xy.size and (xy.ndim != 2 or xy.shape[1] != 2):
        raise FormatError(f"{p}: candidates.xy must be [M, 2], got shape {list(xy.shape)}")
    check_number("candidates.cell", cand.get("cell"), strict=True, owner=str(p), error=FormatError, none_means="unset")


def labels_digest(rec: dict[str, Any]) -> str:
    """Short sha256 (16 hex) of a scene record's candidate cells and rollout labels.

    Rollouts are bit-reproducible on one machine but not across CPUs (docs/background.md), so two copies of a
    preset generated with the same code and seeds can differ in a few cells. Reports record this digest per scene,
    and ``floaff-zoo table`` refuses to put runs whose scenes carry different labels in one table.
    """
    keep = {
        "scene_id": rec.get("scene_id"),
        "candidates": {k: rec["candidates"].get(k) for k in ("xy", "yaw", "cell", "valid")},
        "labels": {k: rec["labels"].get(k) for k in ("success", "label", "known", "cell_label")},
    }
    blob = json.dumps(keep, sort_keys=True, default=_json_default).encode()
    return hashlib.sha256(blob).hexdigest()[:16]


def iter_scenes(
    root: str | Path,
    benchmark: str | None = None,
    split: str | None = None,
    task: str | None = None,
) -> Iterator[dict[str, Any]]:
    """Yield committed scenes (status "ok") under root, sorted by benchmark then scene_id, optionally filtered.

    Raises:
        ValueError: a benchmark, split or task filter that no generated scene can have (a misspelt name matched
            nothing without a word).
    """
    for what, value, known in (
        ("benchmark", benchmark, BENCHMARKS),
        ("split", split, SPLITS),
        ("task", task, TASKS),
    ):
        if value and value not in known:
            raise ValueError(f"iter_scenes: unknown {what} {value!r}; choose from {list(known)}")
    root = Path(root)
    if not root.is_dir():
        raise FormatError(f"{root}: dataset root {'is a file, not a folder' if root.exists() else 'not found'}")
    benches = [benchmark] if benchmark else list(BENCHMARKS)
    for b in benches:
        bdir = root / b
        if not bdir.is_dir():
            continue
        for d in sorted(p for p in bdir.iterdir() if p.is_dir() and not p.name.startswith(".")):
            if not (d / SCENE_JSON).is_file():
                continue
            rec = read_scene(d)
            if rec.get("status") != "ok":
                continue
            if split and rec["split"] != split:
                continue
            if task and rec["task"] != task:
                continue
            yield rec


def target_world(rec: dict[str, Any]) -> list[float] | None:
    """The world (x, y) of a scene record's target (``target.pos``), which the annotation's poses face; None where
    the record has none.

    Raises:
        FormatError: ``target.pos`` is there but not 2+ finite numbers.
    """
    target = rec.get("target")
    if target is not None and not isinstance(target, dict):
        raise FormatError(f"target must be a record with a 'pos', got {target!r:.80}")
    pos = None if target is None else target.get("pos")
    if pos is None:
        return None
    if not isinstance(pos, (list, tuple)):
        raise FormatError(f"target.pos must be a list of world coordinates, got {pos!r:.80}")
    try:
        xy = [float(v) for v in pos[:2]]
    except (TypeError, ValueError) as exc:
        raise FormatError(f"target.pos must hold world coordinates, got {pos!r:.80}") from exc
    if len(xy) != 2 or not all(np.isfinite(xy)):
        raise FormatError(f"target.pos must hold finite world coordinates, got {pos}")
    return xy


#: largest difference (m, rad) of a view's base pose between its npz (float32) and scene.json (float64)
POSE_TOLERANCE = 1e-4


def poses_agree(a: Any, b: Any) -> bool:
    """True when the base poses a and b [x, y, yaw] agree within ``POSE_TOLERANCE`` (yaw modulo 2 pi)."""
    dyaw = math.remainder(float(a[2]) - float(b[2]), math.tau)
    return (
        abs(float(a[0]) - float(b[0])) <= POSE_TOLERANCE
        and abs(float(a[1]) - float(b[1])) <= POSE_TOLERANCE
        and abs(dyaw) <= POSE_TOLERANCE
    )


def read_sample(scene: dict[str, Any], view: dict[str, Any], root: str | Path | None = None) -> dict[str, Any]:
    """Build one sample-contract dict (README, "The sample contract") from a scene record and one of its views.

    Masks are all True (no padding); meta carries dataset/task/view/scene ids, the file's format_version and a 'sim'
    dict to rebuild the scene. Extra key ``floor_known`` [M] bool: the label comes from a rollout or a filter (format
    2); all true for format 1 files (their smoothed labels are taken as given).
    """
    version = check_format_version(scene.get("format_version", 1), Path(scene["dir"]) / SCENE_JSON)
    cells = scene["candidates"]["xy"] if "candidates" in scene else None  # the DataModule's records carry none
    if not isinstance(view, dict) or not isinstance(view.get("file"), str):
        raise FormatError(f"{Path(scene['dir']) / SCENE_JSON}: a view record needs a 'file' name, got {view!r:.80}")
    # a view without its kind or id, a scene without its id, ended below in a bare KeyError naming no file
    if not (isinstance(view.get("view"), str) and isinstance(view.get("view_id"), str)):
        raise FormatError(
            f"{Path(scene['dir']) / SCENE_JSON}: a view record needs a 'view' and a 'view_id', got {view!r:.80}"
        )
    if not isinstance(scene.get("scene_id"), str):
        raise FormatError(f"{Path(scene['dir']) / SCENE_JSON}: the scene record needs a 'scene_id'")
    arr = read_view(Path(scene["dir"]) / view["file"], version, len(cells) if cells is not None else None)
    listed = view.get("base_pose_world")
    if listed is not None and _finite_numbers(
        listed, "the view's base_pose_world", Path(scene["dir"]) / SCENE_JSON
    ).shape != (3,):
        raise FormatError(
            f"{Path(scene['dir']) / SCENE_JSON}: view {view['view_id']!r}: base_pose_world must be [x, y, yaw]"
        )
    if listed is not None and not poses_agree(arr["base_pose_world"], listed):
        # the rollout parks the robot from scene.json's pose (float64); the view's points were taken at the npz's
        raise FormatError(
            f"{Path(scene['dir']) / view['file']}: base_pose_world {np.round(arr['base_pose_world'], 6).tolist()} "
            f"disagrees with {Path(scene['dir']) / SCENE_JSON}'s {[round(float(x), 6) for x in listed]} for view "
            f"{view.get('view_id')!r}: the view's points and its rollout would be in different places"
        )
    spec = scene["spec"]
    sim = {
        "layout_id": spec.get("layout_id"),
        "style_id": spec.get("style_id"),
        "seed": spec.get("seed"),
        "task": scene["task"],
        "base_pose_world": [float(v) for v in arr["base_pose_world"]],
        "root": str(root) if root is not None else str(Path(scene["dir"]).parent.parent),
    }
    try:
        target = target_world(scene)
    except FormatError as exc:
        raise FormatError(f"{Path(scene['dir']) / SCENE_JSON}: {exc}") from exc
    if target is not None:  # the rollout faces it as the annotation did (frames.facing_pose)
        sim["target_world"] = target
    meta = {
        "dataset": f"floaff_sim_{scene['benchmark']}",
        "task": scene["task"],
        "view": view["view"],
        "scene_id": scene["scene_id"],
        "layout_id": spec.get("layout_id"),
        "style_id": spec.get("style_id"),
        "sample_id": f"{scene['benchmark']}/{scene['scene_id']}/{view['view_id']}",
        "split": scene["split"],
        "format_version": version,
        "sim": sim,
    }
    return {
        "scene_xyz": arr["scene_xyz"],
        "scene_feat": arr["scene_feat"],
        "scene_mask": np.ones(len(arr["scene_xyz"]), dtype=bool),
        "floor_xyz": arr["floor_xyz"],
        "floor_label": arr["floor_label"],
        "floor_mask": np.ones(len(arr["floor_xyz"]), dtype=bool),
        "floor_known": np.asarray(arr.get("floor_known", np.ones(len(arr["floor_xyz"]), dtype=bool)), dtype=bool),
        "robot": arr["robot"],
        "target_xyz": arr["target_xyz"],
        "target_yaw": arr["target_yaw"],
        "meta": meta,
    }


def read_manifest(root: str | Path) -> dict[str, Any]:
    """Load <root>/manifest.json (FormatError when missing or corrupt, or when its 'scenes' is not a table of slot
    records)."""
    man = read_json(Path(root) / MANIFEST)
    if not isinstance(man, dict) or "scenes" not in man:
        raise FormatError(f"{Path(root) / MANIFEST}: not a FloAff manifest (no 'scenes')")
    scenes = man["scenes"]
    if not isinstance(scenes, dict):
        raise FormatError(f"{Path(root) / MANIFEST}: 'scenes' must map slots to records, got a {type(scenes).__name__}")
    bad = [k for k, s in scenes.items() if not isinstance(s, dict)]
    if bad:
        raise FormatError(f"{Path(root) / MANIFEST}: 'scenes' entry {bad[0]!r} is not a record")
    return man
