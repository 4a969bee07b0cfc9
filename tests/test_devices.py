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


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")
def test_models_and_metrics_run_on_cuda(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    args = [*quiet_trainer_args(tmp_path), "--trainer.accelerator", "cuda", "--trainer.devices", "1"]
    cli = run_lightning(["fit", "--config", DATA, "--config", MODEL, *args, "--trainer.max_epochs", "1"])
    assert torch.isfinite(cli.trainer.callback_metrics["val_rmse"])
    assert Path(cli.trainer.checkpoint_callback.best_model_path).is_file()
