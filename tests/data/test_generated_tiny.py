"""FloAffKitchenDataModule on real `floaff-zoo generate --preset tiny` output (slow: ~2 min to generate)."""

import pytest
import torch

from floaff_zoo.cli import main, run_lightning
from tests.conftest import quiet_trainer_args

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def tiny_root(tmp_path_factory):
    out = tmp_path_factory.mktemp("floaff_tiny")
    assert main(["generate", "--preset", "tiny", "--out", str(out), "--workers", "2", "--quiet"]) == 0
    return out


def _cli_args(tiny_root, tmp_path) -> list[str]:
    """The tiny data and model over the generated root, quiet, under tmp_path."""
    data = ["--config", "configs/data/floaff_tiny.yaml", "--data.init_args.root", str(tiny_root)]
    return [*data, "--config", "configs/models/tiny_pointnet.yaml", *quiet_trainer_args(tmp_path)]


def test_generated_tiny_reads_and_round_trips(tiny_root, tmp_path, root, monkeypatch):
    from floaff_zoo.data.floaff_kitchen import FloAffKitchenDataModule

    dm = FloAffKitchenDataModule(root=str(tiny_root), tasks=["CloseDrawer", "OpenSingleDoor"], cache=False)
    dm.setup("fit")
    dm.setup("test")
    assert dm.skips.total == 0
    assert len(dm.datasets["train"]) and len(dm.datasets["val"]) and len(dm.datasets["test"])
    s = dm.datasets["test"][0]
    assert s["scene_feat"].shape[1] == 4 and s["meta"]["sim"]["scene_dir"].startswith(str(tiny_root))
    assert {r.meta["view"] for r in dm.datasets["test"].records} == {"front", "side"}
    monkeypatch.chdir(root)
    base = _cli_args(tiny_root, tmp_path)
    cli = run_lightning(["fit", *base, "--trainer.max_epochs", "1"])
    ckpt = cli.trainer.checkpoint_callback.best_model_path
    res = run_lightning(["test", *base, "--ckpt_path", ckpt]).trainer.callback_metrics
    assert torch.isfinite(res["test_rmse"])


def test_full_cloud_footprint_check_through_the_cli(tiny_root, tmp_path, root, monkeypatch):
    """`floaff-zoo test` with eval_sr_top10_full.yaml over a run's config: the data override reaches the DataModule,
    the callback checks footprints in the stored cloud, and the report says so."""
    import json
    from pathlib import Path

    monkeypatch.chdir(root)
    base = [*_cli_args(tiny_root, tmp_path), "--data.init_args.tasks", '["CloseDrawer"]']
    ckpt = run_lightning(["fit", *base, "--trainer.max_epochs", "1"]).trainer.checkpoint_callback.best_model_path
    cli = run_lightning(["test", *base, "--config", "configs/trainer/eval_sr_top10_full.yaml", "--ckpt_path", ckpt])
    assert cli.datamodule.full_cloud is True
    rep = json.loads((Path(cli.trainer.log_dir) / "report.json").read_text())
    assert rep["sr"]["free_space"] == "full_cloud" and rep["sr"]["top_k"] == 10
    assert rep["sr"]["n_evaluated"] == len(cli.datamodule.datasets["test"]) > 0
