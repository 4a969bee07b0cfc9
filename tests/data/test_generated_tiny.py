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
    base = [
        "--config",
        "configs/data/floaff_tiny.yaml",
        "--config",
        "configs/models/tiny_pointnet.yaml",
        "--data.init_args.root",
        str(tiny_root),
        *quiet_trainer_args(tmp_path),
    ]
    cli = run_lightning(["fit", *base, "--trainer.max_epochs", "1"])
    ckpt = cli.trainer.checkpoint_callback.best_model_path
    res = run_lightning(["test", *base, "--ckpt_path", ckpt]).trainer.callback_metrics
    assert torch.isfinite(res["test_rmse"])
