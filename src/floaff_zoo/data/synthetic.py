"""SyntheticDataModule: a seeded, analytic floor-affordance dataset for tests and smoke runs.

Each sample is a kitchen wall with a counter and a target object on it, seen from a random robot
pose. The ground-truth map is analytic: success is likely on a ring of radius ``0.8 x reach``
around the target, in front of the counter (a soft half-plane), so the map depends on the scene
geometry, the target and the robot descriptor, as in the real benchmarks.
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np
from torch.utils.data import Dataset

from floaff_zoo.contract import TASKS, Sample, validate_sample
from floaff_zoo.data.base import DataConfigError, FloAffDataModule, check_size
from floaff_zoo.data.readers import check_names
from floaff_zoo.data.transforms import SampleTransform

ROBOTS = np.array([[0.85, 1.03], [0.7, 0.33], [0.78, 1.03]], dtype=np.float32)
#: split k's sample i is seeded by seed + k * SPLIT_STRIDE + i (train, val, test)
SPLIT_STRIDE = 100_000


def check_split_sizes(num_train: int, num_val: int) -> None:
    """DataConfigError when the train or val split holds more than ``SPLIT_STRIDE`` samples: the next split's seeds
    would be some of its own (validation scoring training samples, silently)."""
    for name, value in (("num_train", num_train), ("num_val", num_val)):
        if value > SPLIT_STRIDE:
            raise DataConfigError(
                f"data.{name} must be <= {SPLIT_STRIDE} (the next split's seeds start {SPLIT_STRIDE} further), "
                f"got {value}"
            )


def make_synthetic_sample(seed: int, num_points: int = 512, floor_cells: int = 16, task: str = "CloseDrawer") -> Sample:
    """One analytic sample in the robot base frame (see module docstring).

    Returns:
        a validated sample with ``scene_feat`` [N, 1] (flag) and ``floor_xyz`` [floor_cells**2, 3].
    """
    rng = np.random.default_rng(seed)
    robot = ROBOTS[rng.integers(len(ROBOTS))]
    # Target in front of the robot; the counter front faces back toward the robot +- 60 deg.
    dist, bearing = rng.uniform(1.4, 2.2), rng.uniform(-0.6, 0.6)
    t = np.array([dist * math.cos(bearing), dist * math.sin(bearing), rng.uniform(0.8, 1.0)])
    front_yaw = math.pi + bearing + rng.uniform(-1.0, 1.0)
    n = np.array([math.cos(front_yaw), math.sin(front_yaw)])  # outward normal of the counter front
    tang = np.array([-n[1], n[0]])
    # Scene: counter front face, counter top, wall behind, target blob, some floor.
    k = num_points // 4
    u = rng.uniform(-1.5, 1.5, size=(k, 1))
    front = np.c_[t[:2] + 0.05 * n + u * tang, rng.uniform(0.0, t[2] - 0.05, size=(k, 1))]
    u2, d2 = rng.uniform(-1.5, 1.5, size=(k, 1)), rng.uniform(-0.6, 0.05, size=(k, 1))
    top = np.c_[t[:2] + d2 * n + u2 * tang, np.full((k, 1), t[2] - 0.05)]
    u3 = rng.uniform(-1.5, 1.5, size=(k, 1))
    wall = np.c_[t[:2] - 0.65 * n + u3 * tang, rng.uniform(t[2], 2.2, size=(k, 1))]
    kt = num_points - 3 * k
    blob = t + rng.normal(scale=[0.04, 0.04, 0.04], size=(kt, 3))
    xyz = np.concatenate([front, top, wall, blob]).astype(np.float32)
    flag = np.concatenate([np.zeros(3 * k), np.ones(kt)]).astype(np.float32)[:, None]
    # Floor candidates: a grid in front of the target.
    g = np.linspace(-1.2, 1.2, floor_cells)
    a, b = np.meshgrid(g, np.linspace(0.1, 1.5, floor_cells))
    floor_xy = t[:2] + a.reshape(-1, 1) * tang + b.reshape(-1, 1) * n
    floor = np.c_[floor_xy, np.zeros(len(floor_xy))].astype(np.float32)
    rel = floor_xy - t[:2]
    d = np.linalg.norm(rel, axis=1)
    ahead = rel @ n
    ring = np.exp(-((d - 0.8 * robot[0]) ** 2) / (2 * 0.15**2))
    label = (ring / (1 + np.exp(-(ahead - 0.35) / 0.08))).astype(np.float32)
    if task == "PnPCounterToCab":  # a second task: the same ring, narrowed sideways (a lateral decay)
        label = label * np.exp(-np.abs(rel @ tang) / 0.5).astype(np.float32)
    sample = {
        "scene_xyz": xyz,
        "scene_feat": flag,
        "floor_xyz": floor,
        "floor_label": np.clip(label, 0, 1),
        "robot": robot,
        "target_xyz": t.astype(np.float32),
        "target_yaw": np.float32(math.atan2(n[1], n[0])),
        "meta": {
            "dataset": "synthetic",
            "task": task,
            "view": "front",
            "scene_id": f"syn{seed}",
            "layout_id": -1,
            "style_id": -1,
            "sample_id": f"syn{seed}",
        },
    }
    return validate_sample(sample)


class SyntheticDataset(Dataset):
    """``length`` analytic samples, seeded by ``seed + index``."""

    def __init__(self, length: int, seed: int, num_points: int, floor_cells: int, tasks: list[str]) -> None:
        self.length, self.seed, self.num_points, self.floor_cells, self.tasks = (
            length,
            seed,
            num_points,
            floor_cells,
            tasks,
        )

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, i: int) -> Sample:
        if not 0 <= i < self.length:
            raise IndexError(i)
        s = make_synthetic_sample(self.seed + i, self.num_points, self.floor_cells, self.tasks[i % len(self.tasks)])
        s["meta"]["index"] = i
        return s


class SyntheticDataModule(FloAffDataModule):
    """Seeded analytic data (no files): fast CLI round trips before any real data exists.

    Args:
        num_train / num_val / num_test: split sizes; train and val at most ``SPLIT_STRIDE`` (100000), the seed
            offset between splits.
        points_per_sample: raw scene points generated per sample.
        floor_cells: the floor grid is ``floor_cells x floor_cells``.
        tasks: task names cycled over samples (labels differ per task).
        (the rest: see :class:`FloAffDataModule`)
    """

    def __init__(
        self,
        num_train: int = 64,
        num_val: int = 16,
        num_test: int = 16,
        points_per_sample: int = 512,
        floor_cells: int = 16,
        tasks: list[str] | None = None,
        batch_size: int = 8,
        eval_batch_size: int | None = None,
        num_workers: int = 0,
        num_points: int | None = 512,
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
        for name, value, least in (
            ("num_train", num_train, 0),
            ("num_val", num_val, 0),
            ("num_test", num_test, 0),
            ("points_per_sample", points_per_sample, 1),
            ("floor_cells", floor_cells, 1),
        ):  # numpy's messages at the sanity check named no field
            check_size(name, value, least)
        check_split_sizes(num_train, num_val)
        self.sizes = {"train": num_train, "val": num_val, "test": num_test}
        self.points_per_sample = points_per_sample
        self.floor_cells = floor_cells
        self.tasks = check_names("tasks", ["CloseDrawer"] if tasks is None else tasks, TASKS)

    def setup(self, stage: str | None = None) -> None:
        offsets = {"train": 0, "val": SPLIT_STRIDE, "test": 2 * SPLIT_STRIDE}
        for split, n in self.sizes.items():
            self.datasets[split] = SyntheticDataset(
                n, self.seed + offsets[split], self.points_per_sample, self.floor_cells, self.tasks
            )
        self.datasets["predict"] = self.datasets["test"]
