"""The sample contract: the one data schema every reader, transform, model and metric shares.

A **sample** is a ``dict`` of tensors (no batch dimension):

============  ===============  ==============================================================
key           dtype / shape    meaning
============  ===============  ==============================================================
scene_xyz     float32 [N, 3]   observation points in the robot *base* frame (metres; x forward,
                               y left, z up; floor at z = 0)
scene_feat    float32 [N, C]   per-point features; channel 0 is the target flag (+1 target,
                               -1 obstacle, 0 other, MoMa-Kitchen's visual alignment);
                               channels 1..3 are RGB in [0, 1] when present
scene_mask    bool    [N]      valid points (False marks padding)
floor_xyz     float32 [M, 3]   candidate base positions (robot base frame, z = 0)
floor_label   float32 [M]      probability in [0, 1] that the task succeeds from there
floor_mask    bool    [M]      valid floor points (False marks padding)
robot         float32 [R]      robot descriptor (MoMa-Kitchen: [arm reach m, base height m])
target_xyz    float32 [3]      target point (robot base frame): the centre of the fixture's front
                               on the generated benchmark, the target points' centroid on MoMa-Kitchen
target_yaw    float32 []       yaw of the target's front-facing outward normal (robot base frame);
                               CFAR rotates by R(-pi/2 - yaw) about the target so that every front
                               faces -y (the paper writes R(pi - theta_o) for its own angle origin)
meta          dict             dataset, task, view (front/side/''), scene_id, layout_id,
                               style_id, sample_id, index (position in the split) and, for
                               simulated data, ``sim`` (JSON-able, enough to rebuild the scene)
full_xyz      float32 [K, 3]   optional (``FULL_CLOUD_KEY``): every point the view stores, robot
                               base frame, before any crop or resampling; only when a DataModule
                               is asked for it (``full_cloud``), for the rollout callback's
                               footprint check. Models never read it.
============  ===============  ==============================================================

A **batch** has the same keys with a leading batch dimension ``B``; ``meta`` becomes a list of
dicts. Padded entries are zeros with their mask ``False``; models and metrics must ignore them.
``full_xyz`` is zero-padded to the batch's largest cloud (never resampled) with ``full_mask`` [B, K].
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import torch
from torch import Tensor

from floaff_zoo.checks import check_integer
from floaff_zoo.names import TASKS as TASKS  # defined once there (sim reads it without torch); re-exported

TENSOR_KEYS: tuple[str, ...] = (
    "scene_xyz",
    "scene_feat",
    "scene_mask",
    "floor_xyz",
    "floor_label",
    "floor_mask",
    "robot",
    "target_xyz",
    "target_yaw",
)
REQUIRED_KEYS: tuple[str, ...] = (
    "scene_xyz",
    "scene_feat",
    "floor_xyz",
    "floor_label",
    "robot",
    "target_xyz",
    "target_yaw",
)
#: optional key: every stored point of the view (module docstring); transforms that move the frame move it too
FULL_CLOUD_KEY = "full_xyz"
#: the values of ``scene_feat`` channel 0, the target flag: -1 obstacle, 0 other, +1 target
TARGET_FLAG_VALUES = (-1.0, 0.0, 1.0)
META_KEYS: tuple[str, ...] = (
    "dataset",
    "task",
    "view",
    "scene_id",
    "layout_id",
    "style_id",
    "sample_id",
)
VIEWS: tuple[str, ...] = ("front", "side")

Sample = dict[str, Any]
Batch = dict[str, Any]


class SampleError(ValueError):
    """A sample breaks the contract; the message names the sample and the field."""


class NonFiniteError(FloatingPointError):
    """A model's output went NaN/Inf (a diverged loss, NaN scores): a user-facing stop naming the samples, printed in
    one line by the CLI. Other FloatingPointErrors (numpy's, a bug's) keep their traceback."""


def _where(meta: dict | None) -> str:
    """Human-readable sample name for error messages."""
    if not meta:
        return "sample"
    name = meta.get("sample_id") or meta.get("scene_id") or "?"
    src = meta.get("path") or meta.get("dataset") or ""
    return f"sample {name!s}" + (f" ({src})" if src else "")


def validate_sample(sample: Sample) -> Sample:
    """Check keys, shapes, dtypes and finiteness of one sample; fill missing masks.

    Args:
        sample: a dict following the contract (masks optional).
    Returns:
        the same dict, with ``scene_mask``/``floor_mask`` added when absent and every tensor
        converted to its contract dtype.
    Raises:
        SampleError: naming the sample and the offending field.
    """
    if not isinstance(sample, Mapping):  # a list or a tensor failed on .get naming nothing
        raise SampleError(f"a sample must be a dict of the contract's fields, got {type(sample).__name__}")
    meta = sample.get("meta")
    if meta is not None and not isinstance(meta, Mapping):  # dict(meta) failed with a TypeError naming no sample
        raise SampleError(f"sample: meta must be a dict (or absent), got {type(meta).__name__}")
    where = _where(meta)
    missing = [k for k in REQUIRED_KEYS if k not in sample]
    if missing:
        raise SampleError(f"{where}: missing field(s) {missing}; required {list(REQUIRED_KEYS)}")
    out: Sample = dict(sample)
    for key in REQUIRED_KEYS:
        out[key] = torch.as_tensor(np.asarray(sample[key]) if not torch.is_tensor(sample[key]) else sample[key])
        out[key] = out[key].float()
    xyz, feat = out["scene_xyz"], out["scene_feat"]
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise SampleError(f"{where}: scene_xyz must be [N, 3], got {list(xyz.shape)}")
    if feat.ndim == 1:
        feat = out["scene_feat"] = feat[:, None]
    if feat.ndim != 2 or feat.shape[0] != xyz.shape[0] or feat.shape[1] < 1:
        raise SampleError(f"{where}: scene_feat must be [N={xyz.shape[0]}, C>=1], got {list(feat.shape)}")
    floor, label = out["floor_xyz"], out["floor_label"]
    if floor.ndim != 2 or floor.shape[1] not in (2, 3):
        raise SampleError(f"{where}: floor_xyz must be [M, 3], got {list(floor.shape)}")
    if floor.shape[1] == 2:
        floor = out["floor_xyz"] = torch.cat([floor, floor.new_zeros(floor.shape[0], 1)], dim=1)
    label = out["floor_label"] = _flat(label, where, "floor_label")
    if label.shape[0] != floor.shape[0]:
        raise SampleError(f"{where}: floor_label has {label.shape[0]} values but floor_xyz has {floor.shape[0]} points")
    out["robot"] = _flat(out["robot"], where, "robot")
    if out["target_xyz"].numel() != 3:
        raise SampleError(f"{where}: target_xyz must have 3 values, got {list(out['target_xyz'].shape)}")
    out["target_xyz"] = out["target_xyz"].reshape(3)
    if out["target_yaw"].numel() != 1:
        raise SampleError(f"{where}: target_yaw must be a scalar, got {list(out['target_yaw'].shape)}")
    out["target_yaw"] = out["target_yaw"].reshape(())
    for key in REQUIRED_KEYS:
        if not torch.isfinite(out[key]).all():
            bad = int((~torch.isfinite(out[key])).sum())
            raise SampleError(f"{where}: field {key} contains {bad} NaN/Inf value(s)")
    if xyz.shape[0] == 0:
        raise SampleError(f"{where}: scene_xyz is empty")
    if floor.shape[0] == 0:
        raise SampleError(f"{where}: floor_xyz is empty")
    if (label < 0).any() or (label > 1).any():
        raise SampleError(f"{where}: floor_label must lie in [0, 1] (min {label.min():.3g}, max {label.max():.3g})")
    out["scene_mask"] = _mask(sample.get("scene_mask"), xyz.shape[0], where, "scene_mask")
    out["floor_mask"] = _mask(sample.get("floor_mask"), floor.shape[0], where, "floor_mask")
    if FULL_CLOUD_KEY in sample:
        out[FULL_CLOUD_KEY] = _full_cloud(sample[FULL_CLOUD_KEY], where)
    out["meta"] = dict(sample.get("meta") or {})
    return out


def _full_cloud(value: Any, where: str) -> Tensor:
    """The optional stored cloud checked: float32 [K, 3], K >= 1, finite."""
    full = torch.as_tensor(np.asarray(value) if not torch.is_tensor(value) else value).float()
    if full.ndim != 2 or full.shape[1] != 3 or full.shape[0] == 0:
        raise SampleError(f"{where}: {FULL_CLOUD_KEY} must be [K >= 1, 3], got {list(full.shape)}")
    if not torch.isfinite(full).all():
        bad = int((~torch.isfinite(full)).sum())
        raise SampleError(f"{where}: field {FULL_CLOUD_KEY} contains {bad} NaN/Inf value(s)")
    return full


def _flat(t: Tensor, where: str, name: str) -> Tensor:
    """``t`` as a vector when it has at most one axis longer than 1 ([M], [M, 1], [1, M]); a [M, 2] label, a [2, 5]
    mask or a [2, 2] robot was flattened into twice as many values (matching a floor of that size) or a longer
    descriptor."""
    if sum(d > 1 for d in t.shape) > 1:
        raise SampleError(f"{where}: {name} must be a vector, got {list(t.shape)}")
    return t.reshape(-1)


def _mask(mask: Any, n: int, where: str, name: str) -> Tensor:
    if mask is None:
        return torch.ones(n, dtype=torch.bool)
    m = _flat(torch.as_tensor(np.asarray(mask) if not torch.is_tensor(mask) else mask).bool(), where, name)
    if m.shape[0] != n:
        raise SampleError(f"{where}: {name} has {m.shape[0]} entries, expected {n}")
    if not m.any():  # as an empty cloud: a model scored a sample it saw nothing of, or failed naming another cause
        raise SampleError(f"{where}: {name} marks no point valid (all {n} false)")
    return m


def resample_indices(n_valid: int, size: int, generator: torch.Generator | None = None) -> Tensor:
    """Indices that resample ``n_valid`` items to exactly ``size`` (random subset, or all + repeats).

    Returns:
        LongTensor [size].
    """
    if n_valid <= 0:
        raise SampleError("cannot resample an empty point set")
    if n_valid >= size:
        return torch.randperm(n_valid, generator=generator)[:size]
    extra = torch.randint(n_valid, (size - n_valid,), generator=generator)
    return torch.cat([torch.arange(n_valid), extra])


def _sample_generator(seed: int, index: int) -> torch.Generator:
    """A generator of its own for sample ``index`` under ``seed`` (distinct pairs give unrelated streams).

    The pair is mixed by an explicit formula (a 64-bit golden-ratio multiply), not Python's ``hash``, so the points
    of a sample do not depend on the interpreter.
    """
    return torch.Generator().manual_seed((int(seed) * 0x9E37_79B9_7F4A_7C15 + int(index)) % (1 << 63))


_TRUNCATION_WARNED = False


def _warn_truncation(n: int, n_max: int) -> None:
    """Warn once per process that ``pad`` cut a cloud to its first points: a stored cloud in image-row order (the
    generated views') then loses whole rows of the image, e.g. the near field with the target, not a random part."""
    global _TRUNCATION_WARNED
    if not _TRUNCATION_WARNED:
        _TRUNCATION_WARNED = True
        warnings.warn(
            f"collate_mode 'pad' keeps the first {n_max} of {n} valid points (MoMa-Kitchen's truncation); a cloud "
            "stored in image-row order loses whole image rows that way: use collate_mode 'resample' (a seeded "
            "random subset) or num_points >= the cloud size",
            stacklevel=3,
        )


def collate_samples(
    samples: Sequence[Sample],
    num_points: int | None = None,
    num_floor: int | None = None,
    mode: Literal["pad", "resample"] = "pad",
    generator: torch.Generator | None = None,
    seed: int | None = None,
) -> Batch:
    """Stack samples into a batch with fixed sizes and masks.

    Args:
        samples: validated samples (``validate_sample`` is applied again cheaply if masks are missing).
        num_points: scene size N; ``None`` = the largest in the batch.
        num_floor: floor size M; ``None`` = the largest in the batch.
        mode: ``pad`` keeps the first N valid points and zero-pads (official MoMa-Kitchen semantics:
            longer clouds are truncated); ``resample`` draws exactly N valid points (with repeats
            when short, every slot valid). Floor points are only padded/truncated, never resampled,
            so labels stay aligned with their points.
        generator: the random stream of ``resample`` (None: torch's global one).
        seed: instead of ``generator``, resample each sample with its own stream seeded by ``(seed, meta['index'])``
            (its position in the batch when meta has no index): the points then do not depend on the batch, the
            worker or the epoch, as repeatable evaluation needs.
    Returns:
        a batch dict: tensors with a leading dim B, ``meta`` a list of dicts.
    """
    if len(samples) == 0:
        raise SampleError("cannot collate an empty batch (0 samples)")
    samples = [s if "scene_mask" in s and "floor_mask" in s else validate_sample(s) for s in samples]
    n_max = num_points or max(int(s["scene_mask"].sum()) for s in samples)
    m_max = num_floor or max(s["floor_xyz"].shape[0] for s in samples)
    c = samples[0]["scene_feat"].shape[1]
    r = samples[0]["robot"].shape[0]
    for s in samples:
        if s["scene_feat"].shape[1] != c or s["robot"].shape[0] != r:
            raise SampleError(
                f"{_where(s.get('meta'))}: feature/robot sizes ({s['scene_feat'].shape[1]}, {s['robot'].shape[0]}) "
                f"differ from the batch's first sample ({c}, {r})"
            )
    b = len(samples)
    batch: Batch = {
        "scene_xyz": torch.zeros(b, n_max, 3),
        "scene_feat": torch.zeros(b, n_max, c),
        "scene_mask": torch.zeros(b, n_max, dtype=torch.bool),
        "floor_xyz": torch.zeros(b, m_max, 3),
        "floor_label": torch.zeros(b, m_max),
        "floor_mask": torch.zeros(b, m_max, dtype=torch.bool),
        "robot": torch.stack([s["robot"] for s in samples]),
        "target_xyz": torch.stack([s["target_xyz"] for s in samples]),
        "target_yaw": torch.stack([s["target_yaw"].reshape(()) for s in samples]),
        "meta": [dict(s.get("meta") or {}) for s in samples],
    }
    for i, s in enumerate(samples):
        valid = s["scene_mask"].nonzero().squeeze(1)
        if mode == "resample":
            gen = generator if seed is None else _sample_generator(seed, batch["meta"][i].get("index", i))
            valid = valid[resample_indices(valid.numel(), n_max, gen)]
        else:
            if valid.numel() > n_max:
                _warn_truncation(valid.numel(), n_max)
            valid = valid[:n_max]
        k = valid.numel()
        batch["scene_xyz"][i, :k] = s["scene_xyz"][valid]
        batch["scene_feat"][i, :k] = s["scene_feat"][valid]
        batch["scene_mask"][i, :k] = True
        m = min(s["floor_xyz"].shape[0], m_max)
        batch["floor_xyz"][i, :m] = s["floor_xyz"][:m]
        batch["floor_label"][i, :m] = s["floor_label"][:m]
        batch["floor_mask"][i, :m] = s["floor_mask"][:m]
    _collate_full_cloud(samples, batch)
    return batch


def _collate_full_cloud(samples: Sequence[Sample], batch: Batch) -> None:
    """Add ``full_xyz`` [B, K, 3] and ``full_mask`` [B, K] (K = the largest cloud, zero-padded) when every sample
    has a stored cloud; a batch where only some do is refused (a DataModule gives it to all or none)."""
    have = [FULL_CLOUD_KEY in s for s in samples]
    if not any(have):
        return
    if not all(have):
        missing = [_where(s.get("meta")) for s, h in zip(samples, have) if not h][:3]
        raise SampleError(f"{FULL_CLOUD_KEY} is in some samples of the batch but not in {missing}")
    k_max = max(s[FULL_CLOUD_KEY].shape[0] for s in samples)
    batch[FULL_CLOUD_KEY] = torch.zeros(len(samples), k_max, 3)
    batch["full_mask"] = torch.zeros(len(samples), k_max, dtype=torch.bool)
    for i, s in enumerate(samples):
        k = s[FULL_CLOUD_KEY].shape[0]
        batch[FULL_CLOUD_KEY][i, :k] = s[FULL_CLOUD_KEY]
        batch["full_mask"][i, :k] = True


def batch_item(batch: Batch, i: int) -> Batch:
    """Sample ``i`` of a collated batch as a one-sample batch (tensors sliced [i:i+1], other fields [value])."""
    # -1 sliced every tensor empty ([-1:0]) beside the last sample's meta
    check_integer("i", i, 0, len(next(iter(batch.values()))) - 1, owner="batch_item")
    return {k: (v[i : i + 1] if torch.is_tensor(v) else [v[i]]) for k, v in batch.items()}


#: the batch tensors every model reads, with the mask of their valid rows (None: every row); padding is not checked
_FINITE_FIELDS = {
    "scene_xyz": "scene_mask",
    "scene_feat": "scene_mask",
    "floor_xyz": "floor_mask",
    # a NaN label made the loss NaN and dropped its sample from the rank term silently (NaN > 0 is False)
    "floor_label": "floor_mask",
    "target_xyz": None,
    # H3DNet's target primitives, CFAR's `gt` yaw and AxisNet's loss read it; a NaN made maps and losses NaN silently
    "target_yaw": None,
    "robot": None,
}


def _check_shapes(batch: Batch) -> None:
    """Refuse a batch whose fields disagree on their sizes (the contract's shapes, module docstring of
    ``floaff_zoo.contract``): a collated batch always agrees, a user's collate or a batch built by hand need not.
    A 2-column ``target_xyz`` trained TinyPointNet silently; the rest failed inside torch naming no field.

    Raises:
        SampleError: ``"batch field {key} must be [B=2, M=64], got [2, 10]"``.
    """
    xyz = batch["scene_xyz"]
    if xyz.dim() != 3 or xyz.shape[-1] != 3:
        raise SampleError(f"batch field scene_xyz must be [B, N, 3], got {list(xyz.shape)}")
    b, n = xyz.shape[:2]
    floor = batch["floor_xyz"]
    m = floor.shape[1] if floor.dim() == 3 else "M"
    want: dict[str, tuple[tuple[int | None, ...], str]] = {
        "scene_feat": ((b, n, None), f"[B={b}, N={n}, C]"),
        "scene_mask": ((b, n), f"[B={b}, N={n}]"),
        "floor_xyz": ((b, None, 3), f"[B={b}, M, 3]"),
        "floor_label": ((b, m), f"[B={b}, M={m}]"),
        "floor_mask": ((b, m), f"[B={b}, M={m}]"),
        "robot": ((b, None), f"[B={b}, R]"),
        "target_xyz": ((b, 3), f"[B={b}, 3]"),
    }
    for key, (shape, words) in want.items():
        t = batch.get(key)
        if t is None and key in ("scene_mask", "floor_mask"):
            continue
        got = tuple(t.shape) if torch.is_tensor(t) else None
        if got is None or len(got) != len(shape) or any(w is not None and w != g for w, g in zip(shape, got)):
            raise SampleError(f"batch field {key} must be {words}, got {list(got) if got else type(t)}")
    yaw = batch["target_yaw"]
    if not torch.is_tensor(yaw) or yaw.numel() != b or yaw.dim() > 2:  # [B] (collated) or [B, 1]
        raise SampleError(f"batch field target_yaw must be [B={b}], got {list(getattr(yaw, 'shape', []))}")
    meta = batch.get("meta")
    if isinstance(meta, (list, tuple)) and len(meta) != b:  # predictions paired samples with the wrong meta
        raise SampleError(f"batch field meta must hold B={b} entries, got {len(meta)}")


#: ``check_batch``'s key for labels outside [0, 1] on a valid floor point
_LABEL_RANGE = "floor_label range"


def check_batch(batch: Batch) -> None:
    """Raise a clear error for an empty batch, one whose fields disagree on their sizes, one whose samples have no
    valid floor or scene point, one with a label outside [0, 1] on a valid floor point, or one with NaN/Inf on a
    valid point of the inputs every model reads (the readers refuse such files; a user's data module or a batch built
    by hand does not pass through them), naming the field and the samples. Every model of the zoo calls this before
    its step: CFAR, the prior and AxisNet cropped NaN points away without a word, the other models named them."""
    if batch["scene_xyz"].shape[0] == 0:
        raise SampleError("empty batch (0 samples)")
    _check_shapes(batch)
    # [B] per check; a sample with no valid scene point was scored from nothing (TinyPointNet) or failed naming another
    # cause (CFAR's crop)
    rows_of: dict[str, Tensor] = {"floor": ~batch["floor_mask"].any(dim=1), "scene": ~batch["scene_mask"].any(dim=1)}
    for key, mask_key in _FINITE_FIELDS.items():
        t = batch.get(key)
        if not torch.is_tensor(t) or not t.is_floating_point():
            continue
        bad = ~torch.isfinite(t)
        per_point = t.dim() > 2 or mask_key is not None  # [B, N, C] or a masked [B, M] (floor_label)
        bad = bad.reshape(*bad.shape[: 2 if per_point else 1], -1).any(dim=-1)  # [B, N] per point, or [B]
        if mask_key is not None and bad.dim() == 2 and torch.is_tensor(batch.get(mask_key)):
            bad = bad & batch[mask_key].bool()
        rows_of[key] = bad.reshape(bad.shape[0], -1).any(dim=1)  # [B]
    label = batch.get("floor_label")
    if torch.is_tensor(label) and label.is_floating_point() and torch.is_tensor(batch.get("floor_mask")):
        # a success probability: a label of 5 or -1 from a user's collate trained every model without a word
        outside = ((label < 0) | (label > 1)) & batch["floor_mask"].bool()
        rows_of[_LABEL_RANGE] = outside.reshape(outside.shape[0], -1).any(dim=1)
    if not bool(torch.stack(list(rows_of.values())).any()):  # one host sync per step; the details only on failure
        return
    meta = batch.get("meta") or []
    for key, rows in rows_of.items():
        bad_rows = rows.nonzero().squeeze(1).tolist()
        if bad_rows:
            names = [_where(meta[i] if i < len(meta) else None) for i in bad_rows[:3]]
            if key in ("floor", "scene"):
                raise SampleError(f"{len(bad_rows)} sample(s) in the batch have no valid {key} point: {names}")
            if key == _LABEL_RANGE:
                raise SampleError(f"floor_label holds values outside [0, 1] in {len(bad_rows)} sample(s): {names}")
            raise SampleError(f"{key} holds NaN/Inf values in {len(bad_rows)} sample(s) of the batch: {names}")


def yaw_matrix(yaw: Tensor | float) -> Tensor:
    """Rotation about +z. Returns [..., 3, 3] for yaw of shape [...]."""
    yaw = torch.as_tensor(yaw, dtype=torch.float32)
    c, s = torch.cos(yaw), torch.sin(yaw)
    z, o = torch.zeros_like(c), torch.ones_like(c)
    return torch.stack([c, -s, z, s, c, z, z, z, o], dim=-1).reshape(*yaw.shape, 3, 3)


@dataclass
class FloorGrid:
    """A regular floor raster (cells of ``cell`` metres) covering a set of floor points.

    Rasterising maps per-point values to an ``H x W`` image (mean of the points in a cell, NaN
    where no point falls); sampling maps a raster back to the points. Row ``i`` grows with y,
    column ``j`` with x; ``origin`` is the (x, y) of the centre of cell (0, 0).
    """

    origin: tuple[float, float]
    shape: tuple[int, int]
    cell: float = 0.05

    @classmethod
    def from_points(cls, xy: Tensor | np.ndarray, cell: float = 0.05, margin: int = 0) -> "FloorGrid":
        """Smallest grid containing ``xy`` [M, 2+] (extra columns ignored) plus ``margin`` cells."""
        pts = np.asarray(xy, dtype=np.float64)[:, :2]
        if pts.shape[0] == 0:
            raise SampleError("FloorGrid.from_points needs at least one floor point")
        lo = np.floor(pts.min(0) / cell + 0.5) - margin
        hi = np.floor(pts.max(0) / cell + 0.5) + margin
        shape = (int(hi[1] - lo[1] + 1), int(hi[0] - lo[0] + 1))
        return cls(origin=(float(lo[0] * cell), float(lo[1] * cell)), shape=shape, cell=cell)

    def cell_of(self, xy: Tensor | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Row, column and in-bounds flag of each point. xy: [M, 2+] -> three [M] arrays."""
        pts = np.asarray(xy, dtype=np.float64)[:, :2]
        j = np.floor((pts[:, 0] - self.origin[0]) / self.cell + 0.5).astype(np.int64)
        i = np.floor((pts[:, 1] - self.origin[1]) / self.cell + 0.5).astype(np.int64)
        ok = (i >= 0) & (i < self.shape[0]) & (j >= 0) & (j < self.shape[1])
        return i, j, ok

    def centers(self) -> np.ndarray:
        """World (x, y) of every cell centre: [H, W, 2]."""
        ys = self.origin[1] + self.cell * np.arange(self.shape[0])
        xs = self.origin[0] + self.cell * np.arange(self.shape[1])
        gx, gy = np.meshgrid(xs, ys)
        return np.stack([gx, gy], axis=-1)

    def rasterize(self, xy: Tensor | np.ndarray, values: Tensor | np.ndarray) -> np.ndarray:
        """Mean value per cell: xy [M, 2+], values [M] -> [H, W] float (NaN where empty)."""
        vals = np.asarray(values, dtype=np.float64).reshape(-1)
        i, j, ok = self.cell_of(xy)
        flat = i[ok] * self.shape[1] + j[ok]
        total = np.bincount(flat, weights=vals[ok], minlength=self.shape[0] * self.shape[1])
        count = np.bincount(flat, minlength=self.shape[0] * self.shape[1])
        with np.errstate(invalid="ignore", divide="ignore"):
            out = np.where(count > 0, total / np.maximum(count, 1), np.nan)
        return out.reshape(self.shape)

    def sample(self, raster: np.ndarray, xy: Tensor | np.ndarray) -> np.ndarray:
        """Raster value at each point (NaN outside the grid): [H, W], [M, 2+] -> [M]."""
        i, j, ok = self.cell_of(xy)
        out = np.full(i.shape[0], np.nan)
        out[ok] = raster[i[ok], j[ok]]
        return out


def best_pose(
    floor_xyz: Tensor | np.ndarray,
    scores: Tensor | np.ndarray,
    mask: Tensor | np.ndarray | None,
    target_xyz: Tensor | np.ndarray,
    k: int = 1,
    tie_break: Literal["random", "nearest"] = "random",
    seed: int = 0,
) -> list[tuple[float, float, float]]:
    """Top-``k`` SE(2) base poses (x, y, yaw facing the target) from per-point scores.

    Scores equal to 6 decimals are ties. ``tie_break="random"`` (default) orders tied candidates
    by a permutation of the valid points drawn from ``seed``, so a constant or all-zero map picks a uniformly
    random candidate (its success rate is then the base rate) and the same view always gives the same pose, however
    much padding its batch adds; ``"nearest"`` prefers the candidate closest to the target, then the lower index.

    Args:
        floor_xyz: [M, 3]; scores: [M]; mask: [M] bool or None; target_xyz: [3].
    Returns:
        up to ``k`` tuples (x, y, yaw), best first.
    """
    # k 0 or -1 returned no pose or all but the last, 2.5 failed as a slice; a negative seed failed inside numpy
    check_integer("k", k, 1, owner="best_pose")
    check_integer("seed", seed, 0, owner="best_pose")
    xyz = np.asarray(torch.as_tensor(floor_xyz).detach().cpu(), dtype=np.float64)
    sc = np.asarray(torch.as_tensor(scores).detach().cpu(), dtype=np.float64).reshape(-1)
    if xyz.ndim != 2 or xyz.shape[1] < 2:
        raise SampleError(f"best_pose: floor_xyz must be [M, 3] (or [M, 2]), got shape {list(xyz.shape)}")
    # fewer scores than points ranked only the first points, more failed as an index: one score per point
    valid = np.ones(sc.shape[0], bool) if mask is None else np.asarray(torch.as_tensor(mask).cpu()).reshape(-1)
    for name, n in (("scores", sc.shape[0]), ("mask", valid.shape[0])):
        if n != xyz.shape[0]:
            raise SampleError(f"best_pose: {name} has {n} entries for {xyz.shape[0]} floor points (one per point)")
    valid = valid.astype(bool) & np.isfinite(sc)
    if not np.isfinite(xyz[valid]).all():  # a NaN point gave a NaN pose
        raise SampleError("best_pose: floor_xyz holds NaN/Inf on a valid floor point")
    if not valid.any():
        raise SampleError("best_pose: no valid floor point with a finite score")
    t = np.asarray(torch.as_tensor(target_xyz).detach().cpu(), dtype=np.float64).reshape(-1)
    if t.shape != (3,) or not np.isfinite(t).all():  # a NaN gave every pose a NaN yaw
        raise SampleError(f"best_pose: target_xyz must be 3 finite values, got {t.tolist()[:9]}")
    idx = np.nonzero(valid)[0]
    if tie_break == "random":
        # over the valid points only: a batch pads a view's floor to its largest view, and a permutation of the
        # padded length would make the pick depend on which views share the batch
        secondary = np.random.default_rng(seed).permutation(idx.size)
    elif tie_break == "nearest":
        secondary = np.hypot(xyz[idx, 0] - t[0], xyz[idx, 1] - t[1])
    else:
        raise ValueError(f"tie_break must be 'random' or 'nearest', got {tie_break!r}")
    order = np.lexsort((idx, secondary, -np.round(sc[idx], 6)))
    poses = []
    for n in idx[order][:k]:
        yaw = math.atan2(t[1] - xyz[n, 1], t[0] - xyz[n, 0])
        poses.append((float(xyz[n, 0]), float(xyz[n, 1]), float(yaw)))
    return poses
