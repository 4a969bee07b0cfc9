"""Several processes and other devices: DDP on CPU (gloo) gives the single-process metrics; CUDA where present.

DDP relaunches the command line in each process, so the fit runs as a real ``floaff-zoo`` subprocess.
"""

from __future__ import annotations

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from floaff_zoo.cli import run_lightning
from tests.conftest import quiet_trainer_args

DATA = "configs/data/synthetic_tiny.yaml"
MODEL = "configs/models/tiny_pointnet.yaml"
METRICS = ("val_rmse", "val_logmse", "val_pcc", "val_sim", "val_mae")


def test_ddp_on_cpu_matches_a_single_process_evaluation(tmp_path, root, monkeypatch):
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    cmd = [sys.executable, "-m", "floaff_zoo", "fit", "--config", DATA, "--config", MODEL,
           *quiet_trainer_args(tmp_path), "--trainer.strategy", "ddp", "--trainer.devices", "2",
           "--trainer.max_epochs", "1", "--seed_everything", "0"]  # fmt: skip
    done = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "GLOBAL_RANK: 1" in done.stdout + done.stderr  # two processes really ran
    run = next(tmp_path.rglob("metrics.csv")).parent
    rows = [r for r in csv.DictReader((run / "metrics.csv").open()) if r.get("val_rmse")]
    ddp = {k: float(rows[-1][k]) for k in METRICS}
    monkeypatch.chdir(root)
    single = run_lightning(["validate", "--config", str(run / "config.yaml"), "--ckpt_path", "best",
                            "--trainer.devices", "1", "--trainer.strategy", "auto",
                            "--trainer.logger", "false", "--trainer.enable_progress_bar", "false"])  # fmt: skip
    got = {k: float(single.trainer.callback_metrics[k]) for k in METRICS}
    for k in METRICS:
        assert got[k] == pytest.approx(ddp[k], rel=1e-5, abs=1e-6), (k, got[k], ddp[k])


#: every model's tiny config (the CFAR one in its PFAL-free form); each fits and validates on CUDA
CUDA_MODELS = sorted(
    [MODEL, "tests/configs/cfar_tiny.yaml", "tests/configs/axisnet_tiny.yaml"]
    + [
        p.relative_to(Path(__file__).resolve().parents[1]).as_posix()
        for p in (Path(__file__).parent / "configs/models").glob("*.yaml")
    ]
)
NO_CUDA = "no CUDA device on this machine"


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason=NO_CUDA)
@pytest.mark.parametrize("model", CUDA_MODELS, ids=lambda m: Path(m).stem)
def test_models_and_metrics_run_on_cuda(model, tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    args = [*quiet_trainer_args(tmp_path), "--trainer.accelerator", "cuda", "--trainer.devices", "1"]
    if "c2f_exp" in model:  # training-free: validated directly
        cli = run_lightning(["validate", "--config", DATA, "--config", model, *args])
    else:
        cli = run_lightning(["fit", "--config", DATA, "--config", model, *args, "--trainer.max_epochs", "1"])
    metrics = cli.trainer.callback_metrics
    assert metrics, model
    assert all(torch.isfinite(v).all() for v in metrics.values()), (model, metrics)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason=NO_CUDA)
def test_point_ops_on_cuda_match_the_cpu_kernels():
    """The torch path (what CUDA runs) picks the CPU kernels' neighbours and centres."""
    from floaff_zoo.nn import cfar, ops

    g = torch.Generator().manual_seed(0)
    xyz = torch.rand(2, 500, 3, generator=g)
    mask = torch.ones(2, 500, dtype=torch.bool)
    mask[1, 400:] = False
    dev = torch.device("cuda")
    idx = ops.farthest_point_sample(xyz, mask, 64)
    assert torch.equal(ops.farthest_point_sample(xyz.to(dev), mask.to(dev), 64).cpu(), idx)
    centres = ops.index_points(xyz, idx)
    assert torch.equal(
        ops.ball_query(0.2, 16, xyz.to(dev), centres.to(dev), mask.to(dev)).cpu(),
        ops.ball_query(0.2, 16, xyz, centres, mask),
    )
    d_cpu, _ = ops.three_nn(xyz, centres)
    d_gpu, _ = ops.three_nn(xyz.to(dev), centres.to(dev))
    assert torch.allclose(d_gpu.cpu(), d_cpu, atol=1e-6)
    assert torch.equal(cfar.tolerant_fps(xyz.to(dev), mask.to(dev), 32).cpu(), cfar.tolerant_fps(xyz, mask, 32))
