"""Several processes and other devices: DDP on CPU (gloo) gives the single-process metrics; CUDA where present.

DDP relaunches the command line in each process, so the fit runs as a real ``floaff-zoo`` subprocess.
"""

from __future__ import annotations

import copy
import csv
import importlib
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
import yaml
from torch import Tensor

from floaff_zoo.cli import main as cli_main
from floaff_zoo.cli import run_lightning
from floaff_zoo.contract import collate_samples
from floaff_zoo.data.synthetic import make_synthetic_sample
from floaff_zoo.nn import _fps_ext, ops
from floaff_zoo.nn.pointnet2 import PointNet2Seg
from tests.conftest import quiet_trainer_args

DATA = "configs/data/synthetic_tiny.yaml"
MODEL = "configs/models/tiny_pointnet.yaml"
METRICS = ("val_rmse", "val_logmse", "val_pcc", "val_sim", "val_mae", "val_loss")


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


def _metric_batch() -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """11 samples of 30 floor points, some padded, one all-padded: preds, target, mask [11, 30], index [11]."""
    gen = torch.Generator().manual_seed(0)
    pred, target = torch.rand(11, 30, generator=gen), torch.rand(11, 30, generator=gen)
    mask = torch.rand(11, 30, generator=gen) > 0.3
    mask[4] = False
    return pred, target, mask, torch.arange(11)


def _metric_collections() -> dict[str, torch.nn.Module]:
    from floaff_zoo.metrics import affordance_metrics

    return {
        "per_sample": affordance_metrics(),
        "official_batchwise": affordance_metrics("hist", "official_batchwise", chunk_size=4),
    }


def _angle_metric() -> torch.nn.Module:
    from floaff_zoo.models.axisnet import AngleErrorDeg

    return AngleErrorDeg()


def _angle_batch() -> tuple[Tensor, Tensor, Tensor]:
    """AxisNet's metric's inputs for 5 samples: predicted and true yaw [5] (rad), index [5]."""
    gen = torch.Generator().manual_seed(1)
    return torch.rand(5, generator=gen) * 6 - 3, torch.rand(5, generator=gen) * 6 - 3, torch.arange(5)


def _one_rank_updates(rank: int, port: int, out: str) -> None:
    """Worker of a 2-process gloo group in which only rank 0 updates the metrics; each rank saves what it computes."""
    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    torch.distributed.init_process_group("gloo", rank=rank, world_size=2)
    try:
        results = {}
        for name, metrics in _metric_collections().items():
            if rank == 0:
                metrics.update(*_metric_batch())
            results[name] = {k: float(v) for k, v in metrics.compute().items()}
        angle = _angle_metric()
        if rank == 0:
            angle.update(*_angle_batch())
        results["angle"] = {"AngleErrorDeg": float(angle.compute())}
        torch.save(results, f"{out}.{rank}")
    finally:
        torch.distributed.destroy_process_group()


def test_metrics_sync_when_a_process_saw_no_batch(tmp_path):
    """A process that never updated gathered a 1-D stand-in for its [S, width] rows and the collective aborted (the
    floor metrics, and AxisNet's angle error)."""
    import socket
    import warnings

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    out = str(tmp_path / "metrics.pt")
    torch.multiprocessing.spawn(_one_rank_updates, args=(port, out), nprocs=2, join=True)
    single = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for name, metrics in _metric_collections().items():
            metrics.update(*_metric_batch())
            single[name] = {k: float(v) for k, v in metrics.compute().items()}
        angle = _angle_metric()
        angle.update(*_angle_batch())
        single["angle"] = {"AngleErrorDeg": float(angle.compute())}
    for rank in (0, 1):
        got = torch.load(f"{out}.{rank}")
        for name, values in single.items():
            assert got[name] == pytest.approx(values, rel=1e-6, abs=1e-9), (rank, name)


#: every model's tiny config (the CFAR one in its PFAL-free form); each fits and validates on CUDA where there is
#: one, and on the portable path (what CUDA runs) everywhere
CUDA_MODELS = sorted(
    [MODEL, "tests/configs/cfar_tiny.yaml", "tests/configs/axisnet_tiny.yaml"]
    + [
        p.relative_to(Path(__file__).resolve().parents[1]).as_posix()
        for p in (Path(__file__).parent / "configs/models").glob("*.yaml")
    ]
)
NO_CUDA = "no CUDA device on this machine"


def _fit_or_validate(model: str, args: list[str]) -> None:
    """One epoch of ``model``'s tiny config on the tiny synthetic data (validated if training-free); finite metrics."""
    if "c2f_exp" in model:  # training-free: validated directly
        cli = run_lightning(["validate", "--config", DATA, "--config", model, *args])
    else:
        cli = run_lightning(["fit", "--config", DATA, "--config", model, *args, "--trainer.max_epochs", "1"])
    metrics = cli.trainer.callback_metrics
    assert metrics, model
    assert all(torch.isfinite(v).all() for v in metrics.values()), (model, metrics)


@pytest.mark.cuda
@pytest.mark.skipif(not torch.cuda.is_available(), reason=NO_CUDA)
@pytest.mark.parametrize("model", CUDA_MODELS, ids=lambda m: Path(m).stem)
def test_models_and_metrics_run_on_cuda(model, tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    _fit_or_validate(model, [*quiet_trainer_args(tmp_path), "--trainer.accelerator", "cuda", "--trainer.devices", "1"])


def _no_kernel():
    raise AssertionError("a C++ kernel was asked for on the portable path")


@pytest.fixture
def portable(monkeypatch):
    """CPU tensors run the device-independent code that CUDA runs; asking for a C++ kernel fails the test."""
    monkeypatch.setenv(ops.CPU_PATHS_ENV, "portable")
    monkeypatch.setattr(_fps_ext, "load_kernel", _no_kernel)


@pytest.mark.parametrize("model", CUDA_MODELS, ids=lambda m: Path(m).stem)
def test_models_and_metrics_run_on_the_portable_path(model, tmp_path, root, monkeypatch, portable):
    """What CUDA runs (no C++ kernels, no oneDNN calls, no chunks), checked on CPU through the CLI."""
    monkeypatch.chdir(root)
    assert not ops.cpu_fast_paths(torch.device("cpu"))
    _fit_or_validate(model, [*quiet_trainer_args(tmp_path), "--trainer.accelerator", "cpu", "--trainer.devices", "1"])


def _build(config: str, root: Path):
    cfg = yaml.safe_load((root / config).read_text())["model"]
    module, name = cfg["class_path"].rsplit(".", 1)
    return getattr(importlib.import_module(module), name)(**(cfg.get("init_args") or {}))


def _outputs(model, batch) -> tuple[Tensor, Tensor]:
    """(eval output, training loss) of a copy of ``model``, dropout seeded; a training-free model gives a zero loss."""
    model = copy.deepcopy(model)
    model.eval()
    with torch.no_grad():
        out = model(batch)
        if not model.trainable:
            return out, torch.zeros(())
        model.train()
        torch.manual_seed(1)
        loss, _, _ = model.model_step(batch)
    return out, loss


#: the tiny configs plus shipped-size PointNet++ and CFAR, whose predict takes the chunked and oneDNN paths
PARITY_MODELS = [*CUDA_MODELS, "configs/models/pointnet2_ssg.yaml", "configs/models/cfar.yaml"]


@pytest.mark.parametrize("model", PARITY_MODELS, ids=lambda m: Path(m).stem)
def test_the_portable_path_computes_what_the_cpu_fast_path_does(model, root, monkeypatch):
    """Same weights and inputs: the eval output and the training loss agree to 1e-4 (gradients: next test).

    The synthetic scenes are jittered by 1 mm: their exact grids and planes tie distances, and the two
    paths round a distance differently (a GEMM vs the kernels' fma chain), so a tie could pick another
    neighbour.
    """
    torch.manual_seed(0)
    net = _build(model, root)
    points = 2048 if model.startswith("configs/models/") else 256
    batch = collate_samples([make_synthetic_sample(i, num_points=points, floor_cells=8) for i in range(2)])
    g = torch.Generator().manual_seed(5)
    for key in ("scene_xyz", "floor_xyz"):
        batch[key] = batch[key] + 1e-3 * torch.randn(batch[key].shape, generator=g)
    fast = _outputs(net, batch)
    monkeypatch.setenv(ops.CPU_PATHS_ENV, "portable")
    monkeypatch.setattr(_fps_ext, "load_kernel", _no_kernel)
    slow = _outputs(net, batch)
    torch.testing.assert_close(slow[0], fast[0], rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(slow[1], fast[1], rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("xyz_first", [True, False], ids=["ssg", "msg"])
def test_the_portable_path_gives_the_fast_paths_gradients(xyz_first, monkeypatch):
    """Every gradient and running statistic of a PointNet++ training step, float64 (in float32 a near-tie
    of a max pool, which rounding decides, moves a weight gradient by a percent)."""
    cfg = dict(
        in_channels=1,
        npoints=[64, 16],
        radii=[[0.1, 0.2], [0.4]] if not xyz_first else [[0.2], [0.4]],
        nsamples=[[8, 16], [16]] if not xyz_first else [[16], [16]],
        mlps=[[[8, 16], [8, 16]], [[24, 32]]] if not xyz_first else [[[8, 16]], [[24, 32]]],
        fp_mlps=[[32, 32], [32, 16]],
        head=[8],
        xyz_first=xyz_first,
    )
    torch.manual_seed(0)
    net = PointNet2Seg(**cfg).double()
    g = torch.Generator().manual_seed(5)
    xyz = torch.rand(2, 256, 3, generator=g, dtype=torch.float64)
    feat = torch.randn(2, 256, 1, generator=g, dtype=torch.float64)
    target = torch.rand(2, 256, generator=g, dtype=torch.float64)

    def step(paths: str) -> list[Tensor]:
        monkeypatch.setenv(ops.CPU_PATHS_ENV, paths)
        m = copy.deepcopy(net).train()
        torch.nn.functional.binary_cross_entropy_with_logits(m(xyz, feat, None), target).backward()
        return [p.grad for p in m.parameters()] + [b.clone() for b in m.buffers()]

    fast = step("fast")
    monkeypatch.setattr(_fps_ext, "load_kernel", _no_kernel)
    for a, b in zip(step("portable"), fast, strict=True):
        # 1e-5: neighbour search and interpolation weights are float32 even for float64 features
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-7)


def test_cpu_paths_setting_is_checked(monkeypatch, capsys):
    monkeypatch.setenv(ops.CPU_PATHS_ENV, "portabel")
    with pytest.raises(ValueError, match="FLOAFF_ZOO_CPU_PATHS='portabel'"):
        ops.cpu_fast_paths(torch.device("cpu"))
    monkeypatch.setattr(sys, "argv", ["floaff-zoo", "--version"])  # the CLI refuses it before any work
    assert cli_main() == 2
    assert "FLOAFF_ZOO_CPU_PATHS='portabel'" in capsys.readouterr().err
    monkeypatch.setenv(ops.CPU_PATHS_ENV, "fast")
    assert ops.cpu_fast_paths(torch.device("cpu"))
    assert not ops.cpu_fast_paths(torch.device("meta"))


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
    # paper-size clouds (the Triton kernel's block of 4,096 points), padded tails, a regular grid full of ties
    assert ops.fps_backend(dev) == "triton"
    big = torch.rand(3, 4096, 3, generator=g)
    big_mask = torch.rand(3, 4096, generator=g) > 0.1
    on_gpu = ops.farthest_point_sample(big.to(dev), big_mask.to(dev), 1024).cpu()
    assert torch.equal(on_gpu, ops.farthest_point_sample(big, big_mask, 1024))
    side = torch.arange(32, dtype=torch.float32) * 0.05
    grid = torch.stack([*torch.meshgrid(side, side, indexing="ij"), torch.zeros(32, 32)], -1).reshape(1, -1, 3)
    assert torch.equal(cfar.tolerant_fps(grid.to(dev), None, 256).cpu(), cfar.tolerant_fps(grid, None, 256))
