"""Per-sample transforms: resampling, yaw perturbation, jitter, lateral mirroring, MoMa-Kitchen's normalisation.

A transform is a small class with typed constructor args (so LightningCLI/jsonargparse builds it
from ``class_path``) and ``__call__(sample, rng) -> sample``; ``rng`` is a seeded
``numpy.random.Generator`` the DataModule supplies (fresh per draw in training, fixed per sample
index in evaluation). Samples are validated contract samples (torch tensors, masks present).

Config example (a DataModule's ``train_transforms``)::

    train_transforms:
      - class_path: floaff_zoo.data.transforms.YawPerturb
        init_args: {max_deg: 5.0}
      - class_path: floaff_zoo.data.transforms.Jitter
        init_args: {sigma: 0.005}

Method-specific transforms (e.g. a CFAR crop/canonicalisation) plug in the same way: subclass
:class:`SampleTransform` anywhere, put its ``class_path`` in the list.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import Any, Literal

import numpy as np
import torch

from floaff_zoo.checks import check_integer, check_number
from floaff_zoo.contract import FULL_CLOUD_KEY, Sample, SampleError, yaw_matrix


class SampleTransform:
    """Base class: ``__call__(sample, rng) -> sample`` (must not modify the input dict in place)."""

    def __call__(self, sample: Sample, rng: np.random.Generator) -> Sample:
        return sample

    def config(self) -> dict[str, Any]:
        """JSON-able description (class + public attributes): part of the cache key when used as a pre-transform.

        Raises:
            TypeError: an attribute that cannot be keyed (override ``config`` to describe it): dropping it would serve
                samples cached under other settings.
        """
        name = f"{type(self).__module__}.{type(self).__qualname__}"
        args = {k: _keyable(v, f"{name}.{k}") for k, v in vars(self).items() if not k.startswith("_")}
        return {"class": name, **args}

    def __repr__(self) -> str:
        args = ", ".join(f"{k}={v!r}" for k, v in vars(self).items() if not k.startswith("_"))
        return f"{type(self).__name__}({args})"


def _keyable(value: Any, where: str) -> Any:
    """``value`` as JSON-able data (tuples as lists, numpy scalars and arrays as Python numbers and lists)."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (np.ndarray, torch.Tensor)):
        return value.tolist()
    if isinstance(value, (list, tuple)):
        return [_keyable(v, f"{where}[{i}]") for i, v in enumerate(value)]
    if isinstance(value, dict) and all(isinstance(k, str) for k in value):
        return {k: _keyable(v, f"{where}.{k}") for k, v in value.items()}
    if isinstance(value, os.PathLike):
        return os.fspath(value)
    raise TypeError(
        f"{where}: a {type(value).__name__} cannot be part of a sample-cache key; override the transform's config() "
        "to describe it (or make it a private attribute, _name, when it does not change the samples)"
    )


def _sample_name(sample: Sample) -> str:
    """``sample <id>`` for messages, with the file it was read from (``meta['path']``, set while a dataset parses and
    pre-transforms it) when known: the file is what a user can look at."""
    meta = sample.get("meta") or {}
    name = f"sample {meta.get('sample_id')}"
    return f"{name} ({meta['path']})" if meta.get("path") else name


def fps_indices(xyz: np.ndarray, k: int, start: int = 0) -> np.ndarray:
    """Farthest point sampling: xyz [n, 3] -> k indices [k] (n >= k), starting at ``start``.

    Raises:
        ValueError: for xyz not [n, 3] or not finite (NaN picked ``start`` k times), k not in [0, n] (k > n repeated
            the first point), ``start`` not in [0, n) (-1 was returned as an index).
    """
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"fps_indices: xyz must be [n, 3], got {list(xyz.shape)}")
    if not np.isfinite(xyz).all():
        raise ValueError("fps_indices: xyz contains NaN/Inf")
    n = xyz.shape[0]
    check_integer("k", k, 0, n, owner="fps_indices")
    if k:
        check_integer("start", start, 0, n - 1, owner="fps_indices")
    out = np.empty(k, dtype=np.int64)
    dist = np.full(n, np.inf)
    cur = start
    for i in range(k):
        out[i] = cur
        d = ((xyz - xyz[cur]) ** 2).sum(1)
        np.minimum(dist, d, out=dist)
        cur = int(dist.argmax())
    return out


class ResamplePoints(SampleTransform):
    """Resample the valid scene points to exactly ``num_points`` (all valid afterwards).

    Args:
        num_points: output size N.
        method: ``random`` (seeded subset) or ``fps`` (farthest point sampling, seeded start;
            O(N_in * N) in NumPy, ~0.2 s for 16k -> 4k points: use it as a cached pre-transform).
    When fewer valid points exist, all are kept and random repeats fill the rest.
    """

    def __init__(self, num_points: int = 4096, method: Literal["random", "fps"] = "random") -> None:
        # True ran as 1 point; 2.5 or NaN failed in numpy at the first sample
        check_integer("num_points", num_points, 1, owner=type(self).__name__)
        if method not in ("random", "fps"):
            raise ValueError(f"ResamplePoints: method must be 'random' or 'fps', got {method!r}")
        self.num_points = num_points
        self.method = method

    def __call__(self, sample: Sample, rng: np.random.Generator) -> Sample:
        valid = sample["scene_mask"].nonzero().squeeze(1).numpy()
        n = valid.size
        if n == 0:
            raise SampleError(f"ResamplePoints: {_sample_name(sample)} has no valid point")
        if n >= self.num_points:
            if self.method == "fps":
                pick = fps_indices(sample["scene_xyz"][valid].double().numpy(), self.num_points, int(rng.integers(n)))
            else:
                pick = rng.choice(n, self.num_points, replace=False)
        else:
            pick = np.concatenate([np.arange(n), rng.integers(0, n, self.num_points - n)])
        idx = torch.from_numpy(valid[pick])
        out = dict(sample)
        out["scene_xyz"] = sample["scene_xyz"][idx]
        out["scene_feat"] = sample["scene_feat"][idx]
        out["scene_mask"] = torch.ones(self.num_points, dtype=torch.bool)
        return out


class TargetCrop(SampleTransform):
    """Keep the scene points within ``radius`` of the target centre, before the loader samples ``num_points``.

    The loader draws its fixed number of points from what is left, so the points a target-centred model
    (CFAR) keeps after its own crop are denser: the same input size, spent on the target's surroundings.
    Uses only ``target_xyz``, which the robot is given. When fewer than ``min_points`` valid points lie
    within the radius, the nearest ``min_points`` valid points are kept (all of them if there are fewer).

    Args:
        radius: sphere radius around the target centre (m); keep it >= the model's own crop radius.
        min_points: fewest points kept.
    """

    def __init__(self, radius: float = 1.2, min_points: int = 64) -> None:
        check_number("radius", radius, strict=True, owner=type(self).__name__)  # inf kept every point: no crop
        # NaN kept no point at all when the radius held too few; 2.5 failed in torch at the first such sample
        check_integer("min_points", min_points, 1, owner=type(self).__name__)
        self.radius = radius
        self.min_points = min_points

    def __call__(self, sample: Sample, rng: np.random.Generator) -> Sample:
        valid = sample["scene_mask"].nonzero().squeeze(1)
        if valid.numel() == 0:
            raise SampleError(f"TargetCrop: {_sample_name(sample)} has no valid point")
        d2 = ((sample["scene_xyz"][valid] - sample["target_xyz"]) ** 2).sum(-1)  # [n_valid]
        keep = valid[d2 <= self.radius**2]
        if keep.numel() < self.min_points:
            keep = valid[torch.argsort(d2)[: self.min_points]]
        out = dict(sample)
        out["scene_xyz"] = sample["scene_xyz"][keep]
        out["scene_feat"] = sample["scene_feat"][keep]
        out["scene_mask"] = torch.ones(keep.numel(), dtype=torch.bool)
        return out


def rotate_sample(sample: Sample, angle: float) -> Sample:
    """Rotate scene, floor and target (and the stored cloud ``full_xyz`` when present) about the robot origin's
    z axis by ``angle`` (rad).

    ``target_yaw`` turns by the same angle; ``meta['sim']['base_pose_world']`` is updated so the
    base frame -> world mapping stays right (the virtual robot turned by ``-angle``).
    """
    check_number("angle", angle, low=-math.inf, owner="rotate_sample")  # NaN made every coordinate NaN, silently
    rot = yaw_matrix(angle)
    out = dict(sample)
    out["scene_xyz"] = sample["scene_xyz"] @ rot.T
    out["floor_xyz"] = sample["floor_xyz"] @ rot.T
    if FULL_CLOUD_KEY in sample:
        out[FULL_CLOUD_KEY] = sample[FULL_CLOUD_KEY] @ rot.T
    out["target_xyz"] = rot @ sample["target_xyz"]
    yaw = float(sample["target_yaw"]) + angle
    out["target_yaw"] = torch.tensor(math.atan2(math.sin(yaw), math.cos(yaw)), dtype=torch.float32)
    meta = dict(sample.get("meta") or {})
    if isinstance(meta.get("sim"), dict) and meta["sim"].get("base_pose_world") is not None:
        sim = dict(meta["sim"])
        x, y, byaw = sim["base_pose_world"]
        sim["base_pose_world"] = [x, y, byaw - angle]
        meta["sim"] = sim
    out["meta"] = meta
    return out


class YawPerturb(SampleTransform):
    """Random yaw in [-max_deg, +max_deg] about the robot origin, applied to scene, floor and target pose.

    Args:
        max_deg: half-range in degrees (FloAff paper: 5).
    """

    def __init__(self, max_deg: float = 5.0) -> None:
        check_number("max_deg", max_deg, owner=type(self).__name__)  # NaN / inf failed in numpy mid-epoch
        self.max_deg = max_deg

    def __call__(self, sample: Sample, rng: np.random.Generator) -> Sample:
        return rotate_sample(sample, math.radians(float(rng.uniform(-self.max_deg, self.max_deg))))


class Jitter(SampleTransform):
    """Gaussian coordinate noise on the valid scene points (floor candidates stay put: labels are tied to them).

    Args:
        sigma: standard deviation in metres (FloAff paper: 0.005).
        clip: clip each offset to [-clip, clip] (``None`` = no clipping).
    """

    def __init__(self, sigma: float = 0.005, clip: float | None = None) -> None:
        check_number("sigma", sigma, owner=type(self).__name__)  # NaN made every point NaN, silently
        # clamp(c, -c) with c < 0 moved every point by -c
        check_number("clip", clip, strict=True, owner=type(self).__name__, none_means="no clipping")
        self.sigma = sigma
        self.clip = clip

    def __call__(self, sample: Sample, rng: np.random.Generator) -> Sample:
        xyz = sample["scene_xyz"]
        noise = torch.from_numpy(rng.normal(0.0, self.sigma, size=tuple(xyz.shape)).astype(np.float32))
        if self.clip is not None:
            noise = noise.clamp(-self.clip, self.clip)
        out = dict(sample)
        out["scene_xyz"] = xyz + noise * sample["scene_mask"][:, None]
        return out


class LateralMirror(SampleTransform):
    """Reflect the sample across the robot's x-z plane (y -> -y) with probability ``p``.

    The reflected sample is what the robot would see of the mirror-image kitchen from the mirror-image
    pose: scene (and ``full_xyz``), floor and target move to -y and ``target_yaw`` becomes ``-target_yaw``; labels
    stay with their floor points. In CFAR's canonical frame this flips the lateral axis, so a door hinged on the left
    becomes one hinged on the right. The labels are right only for a left-right symmetric robot and task; the
    generated OpenSingleDoor labels are not symmetric (docs/method.md). ``meta['sim']`` is dropped from a
    reflected sample (no simulator scene matches it) and ``meta['mirrored']`` is set, so a rollout can never
    be run from it: use it on the train split only.

    Args:
        p: probability of reflecting a sample (0 = never, 1 = always).
    """

    def __init__(self, p: float = 0.5) -> None:
        check_number("p", p, high=1.0, owner=type(self).__name__)  # True mirrored every sample
        self.p = p

    def __call__(self, sample: Sample, rng: np.random.Generator) -> Sample:
        if not float(rng.random()) < self.p:
            return sample
        flip = torch.tensor([1.0, -1.0, 1.0], dtype=sample["scene_xyz"].dtype)
        out = dict(sample)
        out["scene_xyz"] = sample["scene_xyz"] * flip
        out["floor_xyz"] = sample["floor_xyz"] * flip.to(sample["floor_xyz"].dtype)
        if FULL_CLOUD_KEY in sample:
            out[FULL_CLOUD_KEY] = sample[FULL_CLOUD_KEY] * flip.to(sample[FULL_CLOUD_KEY].dtype)
        out["target_xyz"] = sample["target_xyz"] * flip.to(sample["target_xyz"].dtype)
        out["target_yaw"] = -sample["target_yaw"]
        meta = {k: v for k, v in (sample.get("meta") or {}).items() if k != "sim"}
        meta["mirrored"] = True
        out["meta"] = meta
        return out


class OfficialNormalize(SampleTransform):
    """MoMa-Kitchen's ``pc_normalize`` of the global cloud: minus centroid, divided by the max radius.

    Only ``scene_xyz`` changes (as in the official loader, where the floor cloud stays in metres);
    the result is no longer metres in the base frame, so use it only to reproduce the official
    inputs, never with frame-dependent transforms after it.
    """

    def __call__(self, sample: Sample, rng: np.random.Generator) -> Sample:
        m = sample["scene_mask"]
        if not m.any():  # torch's max() of an empty tensor failed naming no sample
            raise SampleError(f"OfficialNormalize: {_sample_name(sample)} has no valid point")
        xyz = sample["scene_xyz"]
        c = xyz[m].mean(0)
        r = (xyz[m] - c).norm(dim=1).max().clamp_min(1e-12)
        out = dict(sample)
        out["scene_xyz"] = torch.where(m[:, None], (xyz - c) / r, xyz)
        return out


def apply_transforms(sample: Sample, transforms: Sequence[SampleTransform], rng: np.random.Generator) -> Sample:
    """Apply ``transforms`` in order with the shared generator."""
    for t in transforms:
        sample = t(sample, rng)
    return sample


def transforms_config(transforms: Sequence[SampleTransform] | None) -> list[dict[str, Any]]:
    """JSON-able list describing a transform pipeline (cache keys, logs)."""
    return [t.config() for t in (transforms or [])]


__all__ = [
    "Jitter",
    "LateralMirror",
    "OfficialNormalize",
    "ResamplePoints",
    "SampleTransform",
    "TargetCrop",
    "YawPerturb",
    "apply_transforms",
    "fps_indices",
    "rotate_sample",
    "transforms_config",
]
