"""Per-scene cell labels that replace a generated dataset's labels in training (e.g. fresh-episode success rates).

The generated labels come from one rollout per cell; ``scripts/fresh_labels.py`` rolls every feasible cell of the
training scenes out again with new task seeds and parking noise and writes the success *rates* as labels in this
file format, which ``FloAffKitchenDataModule(train_labels=...)`` reads for its train split (validation and test
keep the benchmark's labels, so checkpoint choice and every reported number stay on the benchmark).

File (``.npz``): ``setting`` (JSON text: how the labels were made) and, per scene id, ``<id>/xy`` [M, 2] (world xy
of the scene's candidate cells), ``<id>/label`` [M] in [0, 1] and ``<id>/cell`` (grid spacing, m). The setting's
``made_from`` maps each scene id to the ``labels_digest`` of the generated scene the labels were made from
(:func:`floaff_zoo.sim.fileformat.labels_digest`): copies of a preset differ in a few cells across CPUs, and the
file's name names no copy, so the data module refuses a file made from another copy (files written before the digest
was kept have none, and are used unchecked with a warning).
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from floaff_zoo.contract import Sample, SampleError
from floaff_zoo.data.transforms import SampleTransform
from floaff_zoo.frames import base_to_world

__all__ = ["MADE_FROM", "SceneLabels", "read_scene_labels", "write_scene_labels"]

#: the setting key holding {scene id: labels_digest of the generated scene the labels were made from}
MADE_FROM = "made_from"

#: a view's floor point belongs to a cell when it lies within this fraction of the spacing of the cell's centre
ON_GRID = 0.25


def write_scene_labels(
    path: str | Path, labels: dict[str, tuple[np.ndarray, np.ndarray, float]], setting: dict[str, Any]
) -> None:
    """Write ``{scene id: (xy [M, 2], label [M], cell)}`` and the ``setting`` that made them to ``path`` (.npz)."""
    arrays: dict[str, Any] = {"setting": json.dumps(setting, sort_keys=True)}
    for sid, (xy, label, cell) in labels.items():
        arrays[f"{sid}/xy"] = np.asarray(xy, np.float64)
        arrays[f"{sid}/label"] = np.asarray(label, np.float32)
        arrays[f"{sid}/cell"] = np.float64(cell)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **arrays)


def read_scene_labels(path: str | Path) -> tuple[dict[str, tuple[np.ndarray, np.ndarray, float]], dict[str, Any]]:
    """Read a scene-label file -> ({scene id: (xy [M, 2], label [M], cell)}, setting); bad content names the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"scene labels: {path} does not exist (make it with scripts/fresh_labels.py)")
    try:
        with np.load(path) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:  # a truncated file is a BadZipFile
        raise ValueError(f"scene labels: {path} is not a readable .npz file ({exc})") from exc
    if "setting" not in arrays:
        raise ValueError(f"scene labels: {path} has no 'setting' entry")
    try:
        setting = json.loads(str(arrays.pop("setting")))
    except json.JSONDecodeError as exc:
        raise ValueError(f"scene labels: {path}: its 'setting' entry is not JSON ({exc})") from exc
    made = setting.get(MADE_FROM) if isinstance(setting, dict) else None
    if not isinstance(setting, dict) or not (made is None or (isinstance(made, dict) and _all_str(made))):
        # a list setting failed the data module's check with an AttributeError naming no file, and a made_from of
        # another shape read as a file written before it was kept: used unchecked
        raise ValueError(
            f"scene labels: {path}: its 'setting' must be a JSON object whose {MADE_FROM!r} maps scene ids to digests,"
            f" got {str(setting)[:80]}"
        )
    ids = sorted({k.rsplit("/", 1)[0] for k in arrays})
    out: dict[str, tuple[np.ndarray, np.ndarray, float]] = {}
    for sid in ids:
        try:
            xy, label, cell = arrays[f"{sid}/xy"], arrays[f"{sid}/label"], arrays[f"{sid}/cell"]
        except KeyError as exc:
            raise ValueError(f"scene labels: {path}: scene {sid} lacks the entry {exc}") from None
        # one finite positive spacing and at least one cell: an inf spacing put every floor point on the grid, and
        # an empty scene failed at the first sample with numpy's 'argmin of an empty sequence'
        cell = float(cell) if cell.shape == () and cell.dtype.kind in "iuf" else float("nan")
        if xy.dtype.kind not in "iuf" or label.dtype.kind not in "iuf":  # complex parts were dropped with a warning
            raise ValueError(f"scene labels: {path}: scene {sid} has xy of {xy.dtype} and label of {label.dtype}")
        if xy.ndim != 2 or xy.shape[1] != 2 or not len(xy) or label.shape != (len(xy),) or not 0 < cell < np.inf:
            raise ValueError(
                f"scene labels: {path}: scene {sid} has xy {list(xy.shape)}, label {list(label.shape)}, cell {cell}"
            )
        finite = np.all(np.isfinite(xy)) and np.all(np.isfinite(label))
        if not finite or label.min(initial=0) < 0 or label.max(initial=0) > 1:
            raise ValueError(f"scene labels: {path}: scene {sid} has non-finite values or labels outside [0, 1]")
        if len(np.unique(xy, axis=0)) < len(xy):  # a floor point took the first of two cells' labels, silently
            raise ValueError(f"scene labels: {path}: scene {sid} lists a cell's xy twice")
        out[sid] = (xy.astype(np.float64), label.astype(np.float32), cell)
    if not out:
        raise ValueError(f"scene labels: {path} holds no scene")
    return out, setting


def _all_str(d: dict[Any, Any]) -> bool:
    return all(isinstance(k, str) and isinstance(v, str) for k, v in d.items())


class SceneLabels(SampleTransform):
    """Replace a view's floor labels by its scene's labels from a scene-label file (module doc).

    Each floor point is taken to the world with the view's ``meta.sim.base_pose_world`` (rotations by other
    transforms keep that pose in step) and gets the label of the cell it lies on; a scene missing from the file
    or a floor point off its grid raises :class:`~floaff_zoo.contract.SampleError` naming both.

    Args:
        path: the scene-label file (.npz).
    """

    def __init__(self, path: str) -> None:
        self.path = str(path)
        self._table: dict[str, tuple[np.ndarray, np.ndarray, float]] | None = None
        self._setting: dict[str, Any] = {}

    def config(self) -> dict[str, Any]:
        """The path and a digest of the labels it holds: as a pre-transform, a file written again under the same
        name (``scripts/fresh_labels.py``) must miss the sample cache, whose entries hold the old labels (and skip
        markers the old file's errors). Reads the file: a missing or bad one fails here, naming it."""
        h = hashlib.sha256()
        for sid, (xy, label, cell) in sorted(self.table().items()):
            h.update(sid.encode() + b"\0" + xy.tobytes() + label.tobytes() + np.float64(cell).tobytes())
        return {**super().config(), "labels": h.hexdigest()[:16]}

    def table(self) -> dict[str, tuple[np.ndarray, np.ndarray, float]]:
        """The file's {scene id: (xy, label, cell)}, read once per process."""
        if self._table is None:
            self._table, self._setting = read_scene_labels(self.path)
        return self._table

    def made_from(self) -> dict[str, str] | None:
        """{scene id: labels_digest of the generated scene the labels were made from}; None for files written before
        it was kept (module doc)."""
        self.table()
        made = self._setting.get(MADE_FROM)
        return dict(made) if isinstance(made, dict) else None  # read_scene_labels checked: str to str

    def __getstate__(self) -> dict[str, Any]:  # worker processes read the file themselves
        return {"path": self.path, "_table": None, "_setting": {}}

    def __call__(self, sample: Sample, rng: np.random.Generator) -> Sample:
        meta = sample.get("meta") or {}
        sid = meta.get("scene_id")
        pose = (meta.get("sim") or {}).get("base_pose_world")
        where = meta.get("sample_id", sid)
        if sid not in self.table() or pose is None:
            raise SampleError(f"{where}: scene {sid} has no labels in {self.path} (or the sample has no base pose)")
        xy, label, cell = self.table()[sid]
        floor = base_to_world(sample["floor_xyz"][:, :2].numpy(), pose)  # [K, 2]
        d = np.linalg.norm(floor[:, None, :] - xy[None], axis=-1)  # [K, M]
        idx = d.argmin(axis=1)
        off = (d[np.arange(len(idx)), idx] > ON_GRID * cell) & sample["floor_mask"].numpy()
        if off.any():
            raise SampleError(f"{where}: {int(off.sum())} floor point(s) lie off scene {sid}'s grid in {self.path}")
        out = dict(sample)
        new = torch.from_numpy(label[idx]).to(sample["floor_label"].dtype)
        out["floor_label"] = torch.where(sample["floor_mask"], new, sample["floor_label"])
        return out
