"""Learnability probe: when the label is a fixed function of the canonical position, CFAR must learn it.

The probe data (``floaff_zoo.data.learnability``) has random target poses, clutter and floor queries, and a
label that depends only on the canonical floor position. The yaw is the true one in training and test (this
probes the representation, not the yaw estimate). A tiny CFAR trained through the CLI must reach
held-out PCC >= 0.9 with the alignment, be clearly worse without it, and fail with a broken transform.
"""

import math

import pytest
import torch

import floaff_zoo.nn.cfar as cfar_ops
from floaff_zoo.cli import run_lightning
from tests.conftest import ROOT, quiet_trainer_args

PROBE = "configs/data/canonical_probe.yaml"
CFAR = "tests/configs/cfar_tiny.yaml"
EPOCHS = "5"


def held_out_pcc(tmp_path, *extra: str) -> float:
    """Fit the tiny CFAR on the probe, then test the last checkpoint on held-out samples: test PCC."""
    base = [
        "--config",
        PROBE,
        "--config",
        CFAR,
        *quiet_trainer_args(tmp_path),
        "--seed_everything",
        "0",
        "--model.init_args.yaw_jitter_deg",
        "0",
        "--model.init_args.eval_yaw_source",
        "gt",
        *extra,
    ]
    fit = run_lightning(["fit", *base, "--trainer.max_epochs", EPOCHS])
    last = fit.trainer.checkpoint_callback.last_model_path or fit.trainer.checkpoint_callback.best_model_path
    test = run_lightning(["test", *base, "--ckpt_path", last])
    return float(test.trainer.callback_metrics["test_pcc"])


@pytest.fixture(scope="module")
def aligned_pcc(tmp_path_factory):
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the function-scoped one-thread fixture does not cover module fixtures
    try:
        with pytest.MonkeyPatch.context() as mp:
            mp.chdir(ROOT)
            return held_out_pcc(tmp_path_factory.mktemp("aligned"))
    finally:
        torch.set_num_threads(threads)


def test_cfar_learns_the_canonical_function(aligned_pcc):
    assert aligned_pcc >= 0.9


def test_without_alignment_it_is_measurably_worse(aligned_pcc, tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    pcc = held_out_pcc(tmp_path, "--model.init_args.use_align", "false")
    assert pcc < aligned_pcc - 0.1, (pcc, aligned_pcc)


def test_a_broken_transform_is_caught(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)

    def wrong_sign(yaw, batch, device, dtype):  # the classic bug: +yaw instead of -yaw
        if yaw is None:
            return torch.zeros(batch, device=device, dtype=dtype)
        return -0.5 * math.pi + yaw.to(dtype).reshape(batch)

    monkeypatch.setattr(cfar_ops, "alignment_angle", wrong_sign)
    assert held_out_pcc(tmp_path) < 0.9
