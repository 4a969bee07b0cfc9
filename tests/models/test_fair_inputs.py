"""Fair inputs: at test/predict time no deployable model reads privileged simulator fields.

A robot knows its cloud, the target's position and flag, its task and its own descriptor; it does not know
the simulator's ``target_yaw`` or ``meta['sim']``. Every model in its deployable configuration (the tiny
configs, CFAR and the prior without an AxisNet fall back to training-free yaw) must give the same output
when those fields are scrambled. A model configured to read them (``eval_yaw_source: gt``) must change.
"""

from __future__ import annotations

import copy
import importlib
from pathlib import Path

import pytest
import torch
import yaml

from floaff_zoo.contract import collate_samples
from floaff_zoo.data.synthetic import make_synthetic_sample

ROOT = Path(__file__).resolve().parents[2]
CONFIGS = sorted((ROOT / "tests" / "configs" / "models").glob("*_tiny.yaml")) + [
    ROOT / "tests" / "configs" / "cfar_tiny.yaml",
    ROOT / "configs" / "models" / "canonical_prior.yaml",
]


def build(path: Path, **override):
    cfg = yaml.safe_load(path.read_text())["model"]
    module, name = cfg["class_path"].rsplit(".", 1)
    cls = getattr(importlib.import_module(module), name)
    return cls(**{**cfg.get("init_args", {}), **override}).eval()


@pytest.fixture
def batch():
    torch.manual_seed(0)
    b = collate_samples([make_synthetic_sample(i, num_points=256, floor_cells=8) for i in range(2)])
    for i, m in enumerate(b["meta"]):
        m["sim"] = {"base_pose_world": [0.1 * i, 0.0, 0.0], "target_yaw_world": 1.0}
    return b


def scrambled(batch):
    out = copy.deepcopy(batch)
    out["target_yaw"] = batch["target_yaw"] + torch.tensor([1.3, -2.1]).reshape(batch["target_yaw"].shape)
    for m in out["meta"]:
        m["sim"] = {"base_pose_world": [9.0, 9.0, 3.0], "target_yaw_world": -2.0}
    return out


def fill_prior(model, batch):
    if hasattr(model.net, "add"):  # the canonical prior: give it something to read
        xy, _ = model.canonical_floor(batch, "gt")
        model.net.add(model.task_index(batch), xy, batch["floor_label"], batch["floor_mask"])


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.stem)
def test_outputs_ignore_privileged_fields(path, batch):
    model = build(path)
    fill_prior(model, batch)
    with torch.no_grad():
        torch.manual_seed(0)
        a = model(batch)
        torch.manual_seed(0)
        b = model(scrambled(batch))
    assert torch.allclose(a, b, atol=1e-6), f"{path.stem}: output depends on target_yaw / meta['sim']"


@pytest.mark.parametrize("name", ["cfar_tiny", "canonical_prior"])
def test_privileged_yaw_is_an_explicit_choice_and_detected(name, batch):
    path = next(p for p in CONFIGS if p.stem == name)
    model = build(path, eval_yaw_source="gt")
    fill_prior(model, batch)
    with torch.no_grad():
        a, b = model(batch), model(scrambled(batch))
    assert not torch.allclose(a, b, atol=1e-6)  # the test above would catch a model that reads it
