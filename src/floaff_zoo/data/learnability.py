"""CanonicalProbeDataModule: data whose label is a fixed function of the canonical floor position.

A probe of what a canonical representation buys (issue "the method must learn what its canonical frame
gives it"): every sample is a counter with a target on its front face, random clutter boxes and floor
points, seen from a random robot pose. The target's position and front yaw in the robot frame are random
(the front faces the robot within +-``max_yaw_deg``); the floor queries are a random subset of the cells of a
disc around the target, on a 0.1 m lattice aligned with the canonical frame and on the front half only, so their
arrangement tells a model where the front is (it is not hidden from the w/o-Align model: its held-out PCC is an
upper bound of what it learns without the frame). The label depends **only** on where a
floor point lies in the canonical frame (target at the origin, its front normal along -y):

    label(x, y) = exp(-((x - 0.35)^2 + (y + 0.75)^2) / (2 * 0.25^2))

a blob in front of the target and offset to one side, so a model that knows the canonical frame only has
to learn one fixed map, and a model without the rotation has to infer the front from the geometry.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from torch.utils.data import Dataset

from floaff_zoo.checks import check_integer, check_number
from floaff_zoo.contract import Sample, validate_sample
from floaff_zoo.data.base import DataConfigError, FloAffDataModule, check_size
from floaff_zoo.data.synthetic import SPLIT_STRIDE, check_split_sizes
from floaff_zoo.data.transforms import SampleTransform

#: canonical centre (m) and width (m) of the label blob
BLOB_XY = (0.35, -0.75)
BLOB_SIGMA = 0.25


def canonical_label(xy: np.ndarray) -> np.ndarray:
    """The probe's label at canonical floor points [M, 2] -> [M] in [0, 1]."""
    d2 = (xy[:, 0] - BLOB_XY[0]) ** 2 + (xy[:, 1] - BLOB_XY[1]) ** 2
    return np.exp(-d2 / (2 * BLOB_SIGMA**2)).astype(np.float32)


def _box_points(rng: np.random.Generator, centre: np.ndarray, size: np.ndarray, yaw: float, n: int) -> np.ndarray:
    """n points [n, 3] on the surface of a box (centre [3], size [3], turned by yaw about z)."""
    u = rng.uniform(-0.5, 0.5, size=(n, 3))
    axis = rng.integers(0, 3, size=n)
    u[np.arange(n), axis] = np.sign(u[np.arange(n), axis]) * 0.5  # push onto a face
    p = u * size
    c, s = math.cos(yaw), math.sin(yaw)
    return np.c_[c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1], p[:, 2]] + centre


def make_probe_sample(
    seed: int, num_points: int = 512, num_floor: int = 96, max_yaw_deg: float = 60.0, task: str = "CloseDrawer"
) -> Sample:
    """One probe sample in the robot base frame (see module docstring).

    Raises:
        ValueError: for num_points or num_floor not an integer >= 1 (num_floor -1 gave every cell but one), or
            max_yaw_deg not a finite number >= 0 (numpy's error named no argument).
    """
    check_integer("num_points", num_points, 1, owner="make_probe_sample")
    check_integer("num_floor", num_floor, 1, owner="make_probe_sample")
    check_number("max_yaw_deg", max_yaw_deg, owner="make_probe_sample")
    rng = np.random.default_rng(seed)
    dist, bearing = rng.uniform(1.3, 2.0), rng.uniform(-0.5, 0.5)
    t = np.array([dist * math.cos(bearing), dist * math.sin(bearing), rng.uniform(0.6, 1.0)])
    yaw = math.pi + bearing + math.radians(rng.uniform(-max_yaw_deg, max_yaw_deg))
    n = np.array([math.cos(yaw), math.sin(yaw)])
    tang = np.array([-n[1], n[0]])
    k = num_points // 5
    # counter: its front face contains the target, its body behind it
    body = np.r_[t[:2] - 0.3 * n, t[2] / 2]
    counter = _box_points(rng, body, np.array([2.4, 0.6, t[2]]), yaw + math.pi / 2, 2 * k)
    clutter = []
    for _ in range(2):
        off = t[:2] + rng.uniform(-1.2, 1.2) * tang + rng.uniform(0.6, 1.6) * n
        clutter.append(_box_points(rng, np.r_[off, 0.2], rng.uniform(0.15, 0.4, 3), rng.uniform(0, math.pi), k // 2))
    floor_pts = np.c_[t[:2] + rng.uniform(-1.5, 1.5, (k, 1)) * tang + rng.uniform(0.0, 1.8, (k, 1)) * n, np.zeros(k)]
    kt = max(8, num_points - len(counter) - sum(len(c) for c in clutter) - len(floor_pts))
    blob = t + rng.normal(scale=0.04, size=(kt, 3))
    xyz = np.concatenate([counter, *clutter, floor_pts, blob]).astype(np.float32)
    flag = np.concatenate([np.zeros(len(xyz) - kt), np.ones(kt)]).astype(np.float32)[:, None]
    # floor queries: a random subset of 0.1 m cells in a 1.6 m disc in front of the target
    g = np.arange(-1.6, 1.61, 0.1)
    cx, cy = np.meshgrid(g, g)
    cells = np.c_[cx.ravel(), cy.ravel()]
    cells = cells[(np.linalg.norm(cells, axis=1) <= 1.6) & (cells[:, 1] < -0.1)]  # canonical: in front
    cells = cells[rng.permutation(len(cells))[: min(num_floor, len(cells))]]
    label = canonical_label(cells)
    floor_xy = t[:2] + cells[:, :1] * tang - cells[:, 1:] * n  # canonical (x, y) -> robot frame
    return validate_sample(
        {
            "scene_xyz": xyz,
            "scene_feat": flag,
            "floor_xyz": np.c_[floor_xy, np.zeros(len(floor_xy))].astype(np.float32),
            "floor_label": label,
            "robot": np.array([0.85, 1.03], dtype=np.float32),
            "target_xyz": t.astype(np.float32),
            "target_yaw": np.float32(math.atan2(n[1], n[0])),
            "meta": {
                "dataset": "probe",
                "task": task,
                "view": "front",
                "scene_id": f"probe{seed}",
                "layout_id": -1,
                "style_id": -1,
                "sample_id": f"probe{seed}",
            },
        }
    )


class ProbeDataset(Dataset):
    """``length`` probe samples, seeded by ``seed + index``."""

    def __init__(self, length: int, seed: int, num_points: int, num_floor: int, max_yaw_deg: float) -> None:
        self.length, self.seed, self.num_points, self.num_floor = length, seed, num_points, num_floor
        self.max_yaw_deg = max_yaw_deg

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, i: int) -> Sample:
        if not 0 <= i < self.length:
            raise IndexError(i)
        s = make_probe_sample(self.seed + i, self.num_points, self.num_floor, self.max_yaw_deg)
        s["meta"]["index"] = i
        return s


class CanonicalProbeDataModule(FloAffDataModule):
    """The learnability probe (module docstring): held-out splits use other seeds.

    Args:
        num_train / num_val / num_test: split sizes; train and val at most ``SPLIT_STRIDE`` (100000), the seed
            offset between splits.
        points_per_sample: raw scene points per sample; floor_per_sample: floor queries per sample.
        max_yaw_deg: the target's front turns up to this far from facing the robot.
        (the rest: see :class:`FloAffDataModule`)
    """

    def __init__(
        self,
        num_train: int = 256,
        num_val: int = 32,
        num_test: int = 32,
        points_per_sample: int = 512,
        floor_per_sample: int = 96,
        max_yaw_deg: float = 60.0,
        batch_size: int = 8,
        eval_batch_size: int | None = None,
        num_workers: int = 0,
        num_points: int | None = 512,
        num_floor: int | None = None,
        collate_mode: Literal["pad", "resample"] = "pad",
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
        for name, value, least in (
            ("num_train", num_train, 0),
            ("num_val", num_val, 0),
            ("num_test", num_test, 0),
            ("points_per_sample", points_per_sample, 1),
            ("floor_per_sample", floor_per_sample, 1),
        ):  # failed in the first batch (a negative __len__, an empty floor) naming no field
            check_size(name, value, least)
        check_split_sizes(num_train, num_val)
        # NaN / inf failed in numpy at the first sample; a negative range drew from the positive one
        check_number("data.max_yaw_deg", max_yaw_deg, error=DataConfigError)
        self.sizes = {"train": num_train, "val": num_val, "test": num_test}
        self.points_per_sample, self.floor_per_sample, self.max_yaw_deg = (
            points_per_sample,
            floor_per_sample,
            max_yaw_deg,
        )

    def setup(self, stage: str | None = None) -> None:
        offsets = {"train": 0, "val": SPLIT_STRIDE, "test": 2 * SPLIT_STRIDE}
        for split, n in self.sizes.items():
            self.datasets[split] = ProbeDataset(
                n, self.seed + offsets[split], self.points_per_sample, self.floor_per_sample, self.max_yaw_deg
            )
        self.datasets["predict"] = self.datasets["test"]
