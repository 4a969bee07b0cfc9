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


@pytest.mark.parametrize("name", NAMES)
def test_a_batch_with_one_floor_point_trains(name):
    """One view with one floor point reaches the per-floor-point BatchNorm as a single row: NavAff's head
    (a plain ``nn.BatchNorm1d``) raised "Expected more than 1 value per channel when training"."""
    torch.manual_seed(0)
    batch = collate_samples([make_synthetic_sample(0, num_points=256, floor_cells=1)])
    assert int(batch["floor_mask"].sum()) == 1
    model = _train_without_dropout(_model(name))
    scores = model(batch)
    assert scores.shape == (1, 1) and torch.isfinite(scores).all()
    scores.sum().backward()
    for key, value in _running_stats(model).items():
        assert torch.isfinite(value).all(), key


def test_one_row_batch_norm_matches_the_fused_kernel_and_keeps_finite_statistics():
    """The non-fused train-mode path (GPU, autocast) took torch's kernel, which refuses one row (and would store
    a NaN running variance); it now gives what the fused CPU kernel gives."""
    from floaff_zoo.nn.pointnet2 import _batch_norm_absorbing_bias, _batch_norm_relu, _fused_bn_relu_ok

    torch.manual_seed(0)
    z, bias = torch.randn(1, 5), torch.randn(5)
    fused, plain = nn.BatchNorm1d(5), nn.BatchNorm1d(5)
    with torch.no_grad():
        for bn in (fused, plain):
            bn.weight.uniform_(0.5, 1.5)
            bn.bias.uniform_(-1.0, 1.0)
        plain.load_state_dict(fused.state_dict())
    out = torch.relu(_batch_norm_absorbing_bias(z, bias, plain))
    torch.testing.assert_close(out, torch.relu(plain.bias.detach()).expand(1, 5))
    assert torch.isfinite(plain.running_var).all() and int(plain.num_batches_tracked) == 1
    if _fused_bn_relu_ok(z):
        # the fused kernel divides a rounding residual by sqrt(eps): equal to about 1e-4
        torch.testing.assert_close(_batch_norm_relu(z.clone(), bias, fused), out, atol=1e-4, rtol=0)
        for key in ("running_mean", "running_var"):
            torch.testing.assert_close(getattr(fused, key), getattr(plain, key), msg=key)
