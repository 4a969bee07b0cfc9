"""Padded floor points stay out of the training-mode BatchNorm statistics.

A batch pads every view's floor points to the batch's largest view. In training, the per-floor-point layers
(FP onto the floor, fusion MLPs, heads) must give the real floor points the same scores, and the BatchNorm
layers the same running statistics, however many padded rows the batch carries.
"""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import torch
import yaml
from torch import nn

from floaff_zoo.contract import collate_samples
from floaff_zoo.data.synthetic import make_synthetic_sample
from floaff_zoo.models.cfar import CFARModule
from floaff_zoo.nn.pointnet2 import SharedMLP, on_valid_rows
from tests.models.test_baselines import tiny_model

ROOT = Path(__file__).resolve().parents[2]
#: the models whose per-floor-point layers hold BatchNorm
NAMES = ["pointnet2_ssg", "pointnet2_msg", "votenet", "h3dnet", "navaff", "cfar"]


def _model(name: str) -> nn.Module:
    if name == "cfar":
        args = yaml.safe_load((ROOT / "tests/configs/cfar_tiny.yaml").read_text())["model"]["init_args"]
        return CFARModule(**args)
    return tiny_model(name)


def _pad_floor(batch: dict, extra: int, fill: float) -> dict:
    """The batch with ``extra`` more padded floor rows (xyz = ``fill``, mask False, label 0)."""
    out = dict(batch)
    b = batch["floor_xyz"].shape[0]
    out["floor_xyz"] = torch.cat([batch["floor_xyz"], torch.full((b, extra, 3), fill)], dim=1)
    out["floor_mask"] = torch.cat([batch["floor_mask"], torch.zeros(b, extra, dtype=torch.bool)], dim=1)
    out["floor_label"] = torch.cat([batch["floor_label"], torch.zeros(b, extra)], dim=1)
    return out


def _train_without_dropout(model: nn.Module) -> nn.Module:
    model.train()
    for m in model.modules():
        if isinstance(m, nn.Dropout):
            m.eval()
    return model


def _running_stats(model: nn.Module) -> dict[str, torch.Tensor]:
    return {k: v.clone() for k, v in model.state_dict().items() if k.endswith(("running_mean", "running_var"))}


@pytest.mark.parametrize("name", NAMES)
def test_training_scores_and_running_stats_ignore_floor_padding(name):
    torch.manual_seed(0)
    a = make_synthetic_sample(0, num_points=256, floor_cells=8)
    b = make_synthetic_sample(1, num_points=256, floor_cells=6)
    batch = collate_samples([a, b])
    first = _train_without_dropout(_model(name))
    second = copy.deepcopy(first)
    valid = batch["floor_mask"]
    torch.manual_seed(1)  # the same training draws (CFAR's yaw jitter) for both calls
    real = first(batch)[valid]
    torch.manual_seed(1)
    padded = second(_pad_floor(batch, 40, 3.0))[:, : valid.shape[1]][valid]
    torch.testing.assert_close(real, padded, atol=1e-5, rtol=1e-4)
    stats_a, stats_b = _running_stats(first), _running_stats(second)
    assert stats_a, "the model should have BatchNorm layers"
    for key in stats_a:
        torch.testing.assert_close(stats_a[key], stats_b[key], atol=1e-5, rtol=1e-4, msg=key)


def test_shared_mlp_mask_runs_valid_rows_only_with_batch_statistics():
    torch.manual_seed(0)
    mlp = SharedMLP(4, [8, 8])
    x = torch.randn(2, 5, 4)
    mask = torch.tensor([[True, True, True, False, False], [True, True, False, False, False]])
    out = mlp(x, mask)
    assert (out[~mask] == 0).all()
    torch.testing.assert_close(out[mask], copy.deepcopy(mlp)(x[mask]))
    mlp.eval()  # running statistics: each row on its own, every row runs
    torch.testing.assert_close(mlp(x, mask), mlp(x))


def test_on_valid_rows_all_valid_is_the_plain_call():
    x = torch.randn(3, 4, 2)
    calls = []

    def fn(t: torch.Tensor) -> torch.Tensor:
        calls.append(t.shape)
        return t.sum(-1)

    out = on_valid_rows(fn, x, torch.ones(3, 4, dtype=torch.bool))
    assert calls == [torch.Size([3, 4, 2])]
    torch.testing.assert_close(out, x.sum(-1))
