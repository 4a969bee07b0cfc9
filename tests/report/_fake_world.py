"""A fake simulator world for callback tests: success is a deterministic function of the world pose."""

from __future__ import annotations

import math
from dataclasses import dataclass

import lightning as L
import numpy as np
import torch

from floaff_zoo.contract import collate_samples, validate_sample
from floaff_zoo.models.base import FloAffModule
from tests.report._fake_jobs import fake_success

TASKS = ("CloseDrawer", "OpenSingleDoor")


@dataclass
class FakeResult:
    success: bool
    reason: str


class FakeService:
    """Stands in for floaff_zoo.sim.rollout.RolloutService; records every job it runs."""

    instances: list["FakeService"] = []

    def __init__(self, workers: int = 1, backend: str = "local", cache_decimals: int = 6) -> None:
        self.jobs: list = []
        self.closed = False
        FakeService.instances.append(self)

    def run(self, jobs, progress=False):
        self.jobs.extend(jobs)
        return [FakeResult(ok := fake_success(p[0], p[1]), "success" if ok else "not_closed") for _, p in jobs]

    def close(self) -> None:
        self.closed = True


def world_to_base(xy: np.ndarray, pose) -> np.ndarray:
    x0, y0, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    d = xy - np.array([x0, y0])
    return np.stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]], axis=1)


def make_samples(n: int, seed: int = 0, cell: float = 0.05, half: int = 6, target_world: bool = False) -> list[dict]:
    """n samples of a fake scene: a target in the world, a candidate grid around it, random robot views
    (``target_world``: ``meta['sim']`` also gives the target's world (x, y), as the FloAff DataModule does)."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        t_world = rng.uniform(-2, 2, size=2).round(2)
        g = np.arange(-half, half + 1) * cell
        gx, gy = np.meshgrid(g, g)
        cand = np.stack([gx.ravel(), gy.ravel()], 1) + t_world + np.array([0.0, 0.6])
        cand = cand.round(2)
        labels = np.array([fake_success(x, y) for x, y in cand], dtype=np.float32)
        base = (
            float(t_world[0] + rng.uniform(-2, 2)),
            float(t_world[1] + rng.uniform(1.5, 2.5)),
            float(rng.uniform(-math.pi, math.pi)),
        )
        floor_b = world_to_base(cand, base)
        t_b = world_to_base(t_world[None], base)[0]
        scene = np.c_[t_b + rng.normal(scale=0.05, size=(32, 2)), rng.uniform(0.8, 1.0, size=32)]
        task = TASKS[i % 2]
        sample = {
            "scene_xyz": scene.astype(np.float32),
            "scene_feat": np.ones((32, 1), np.float32),
            "floor_xyz": np.c_[floor_b, np.zeros(len(floor_b))].astype(np.float32),
            "floor_label": labels,
            "robot": np.array([0.85, 1.03], np.float32),
            "target_xyz": np.array([t_b[0], t_b[1], 0.9], np.float32),
            "target_yaw": np.float32(0.0),
            "meta": {
                "dataset": "fake_sim",
                "task": task,
                "view": ("front", "side")[(i // 2) % 2],
                "scene_id": f"fake{i}",
                "sample_id": f"fake{i}",
                "index": i,
                "sim": {"layout_id": i % 6, "style_id": i % 8, "seed": i, "task": task, "base_pose_world": list(base)},
            },
        }
        if target_world:
            sample["meta"]["sim"]["target_world"] = [float(v) for v in t_world]
        out.append(validate_sample(sample))
    return out


def loader(samples: list[dict], batch_size: int = 8):
    return torch.utils.data.DataLoader(samples, batch_size=batch_size, collate_fn=collate_samples)


class ConstantModule(FloAffModule):
    """Outputs the same score everywhere (a map with no information)."""

    value = 0.5

    def __init__(self) -> None:
        super().__init__()

    def configure_models(self) -> None:
        self.net = torch.nn.Linear(1, 1)

    def forward(self, batch):
        return torch.full_like(batch["floor_label"], self.value) + 0.0 * self.net.weight.sum()


class LabelModule(ConstantModule):
    """Predicts the ground truth (a perfect model)."""

    def forward(self, batch):
        return batch["floor_label"].clone() + 0.0 * self.net.weight.sum()


def quiet_trainer(callbacks: list, devices: int = 1, root: str | None = None) -> L.Trainer:
    """A CPU trainer without logger, progress bar, summary or checkpoints, with ``callbacks``; ``devices`` > 1 runs
    DDP processes (gloo), ``root`` is its default_root_dir."""
    return L.Trainer(
        accelerator="cpu",
        devices=devices,
        strategy="ddp" if devices > 1 else "auto",
        logger=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        enable_checkpointing=False,
        callbacks=callbacks,
        default_root_dir=root,
    )
