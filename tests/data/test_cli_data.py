"""Both file DataModules through the real CLI: shipped data configs + tiny model, fit then test --ckpt_path."""

import json
from pathlib import Path

import pytest
import torch
from lightning.pytorch.utilities.exceptions import MisconfigurationException

from floaff_zoo.cli import main, run_lightning
from tests.conftest import quiet_trainer_args

MODEL = "configs/models/tiny_pointnet.yaml"
DATA_CONFIGS = sorted(
    str(p.relative_to(Path(__file__).resolve().parents[2]))
    for p in (Path(__file__).resolve().parents[2] / "configs" / "data").glob("*.yaml")
)


def _round_trip(tmp_path, data_cfg, root, extra):
    base = [
        "--config",
        data_cfg,
        "--config",
        MODEL,
        "--data.init_args.root",
        str(root),
        "--data.init_args.num_workers",
        "0",
        "--data.init_args.num_points",
        "256",
        "--data.init_args.batch_size",
        "2",
        *extra,
        *quiet_trainer_args(tmp_path / "runs"),
    ]
    cli = run_lightning(["fit", *base, "--trainer.max_epochs", "1"])
    ckpt = cli.trainer.checkpoint_callback.best_model_path
    assert Path(ckpt).is_file() and "val_rmse" in cli.trainer.callback_metrics
    assert [type(t).__name__ for t in cli.datamodule.train_transforms] == ["YawPerturb", "Jitter"]
    res = run_lightning(["test", *base, "--ckpt_path", ckpt]).trainer.callback_metrics
    for k in ("test_rmse", "test_pcc", "test_sim"):
        assert k in res and torch.isfinite(res[k])
    return cli


def test_moma_kitchen_cli(tmp_path, root, monkeypatch, moma_root):
    monkeypatch.chdir(root)
    cli = _round_trip(tmp_path, "configs/data/moma_kitchen.yaml", moma_root[0], [])
    assert len(cli.datamodule.datasets["val"]) >= 1
    assert list((moma_root[0] / ".cache").rglob("*.pt"))
    (report,) = (tmp_path / "runs").rglob("report.json")  # the test split file's skips, not train's
    skipped = json.loads(report.read_text())["data"]["skipped_at_setup"]
    assert skipped["log"] == "moma_kitchen test" and skipped["total"] == sum(skipped["counts"].values())


def test_floaff_styles_cli(tmp_path, root, monkeypatch, floaff_root):
    monkeypatch.chdir(root)
    cli = _round_trip(
        tmp_path,
        "configs/data/floaff_styles.yaml",
        floaff_root[0],
        ["--data.init_args.tasks", "[CloseDrawer, PnPCounterToCab]"],
    )
    assert {m for m in cli.datamodule.tasks} == {"CloseDrawer", "PnPCounterToCab"}
    # the test's report names the labels of every scene it read, so tables can refuse to mix copies of the data
    (report,) = (tmp_path / "runs").rglob("report.json")
    digests = json.loads(report.read_text())["data"]["labels_sha256"]
    assert digests == cli.datamodule.labels_digests and digests
    assert all(s.startswith(("CloseDrawer", "PnPCounterToCab")) for s in digests)


def test_fit_without_validation_keeps_the_last_checkpoint(tmp_path, root, monkeypatch, floaff_root):
    """val_scenes 0: every train scene trains, no validation loop, last.ckpt is the checkpoint 'best' resolves to."""
    monkeypatch.chdir(root)
    base = [
        "--config",
        "configs/data/floaff_styles.yaml",
        "--config",
        MODEL,
        "--data.init_args.root",
        str(floaff_root[0]),
        "--data.init_args.tasks",
        "[CloseDrawer, PnPCounterToCab]",
        "--data.init_args.num_points",
        "256",
        "--data.init_args.batch_size",
        "2",
        "--data.init_args.val_scenes",
        "0",
        *quiet_trainer_args(tmp_path / "runs"),
    ]
    cli = run_lightning(["fit", *base, "--trainer.max_epochs", "2"])
    assert not any(k.startswith("val_") for k in cli.trainer.callback_metrics)
    ckpts = sorted(p.name for p in (tmp_path / "runs").rglob("*.ckpt"))
    assert ckpts == ["last.ckpt"]  # no monitored top-k file without a validation metric
    last = next((tmp_path / "runs").rglob("last.ckpt"))
    assert torch.load(last, map_location="cpu", weights_only=True)["global_step"] == cli.trainer.global_step
    res = run_lightning(["test", *base, "--ckpt_path", "best"])
    assert Path(res.config_init["test"]["ckpt_path"]).resolve() == last.resolve()
    # a scheduler that follows the validation metric cannot run: said before training
    with pytest.raises(MisconfigurationException, match="'plateau' follows val_rmse.*val_scenes 0"):
        run_lightning(["fit", *base, "--trainer.max_epochs", "1", "--model.init_args.train.scheduler", "plateau"])


@pytest.mark.parametrize("cfg", DATA_CONFIGS)
def test_every_data_config_parses(cfg, root, monkeypatch, capsys):
    monkeypatch.chdir(root)
    with pytest.raises(SystemExit) as ex:
        main(["fit", "--config", cfg, "--config", MODEL, "--print_config"])
    assert ex.value.code in (0, None)
    assert "class_path: floaff_zoo.data." in capsys.readouterr().out


def test_a_view_that_breaks_after_setup_is_replaced_counted_and_reported(
    tmp_path, root, monkeypatch, floaff_root, capsys
):
    """A file that breaks between setup and the test loop: the next sample stands in, the report names the broken
    one and counts every evaluated sample once, and the DataModule prints a summary at the end."""
    from floaff_zoo.data.cache import RecordDataset

    monkeypatch.chdir(root)
    base = [
        "--config", "configs/data/floaff_styles.yaml", "--config", MODEL,
        "--data.init_args.root", str(floaff_root[0]), "--data.init_args.tasks", "[CloseDrawer]",
        "--data.init_args.num_points", "256", "--data.init_args.batch_size", "2", "--data.init_args.val_scenes", "0",
        *quiet_trainer_args(tmp_path / "runs"),
    ]  # fmt: skip
    run_lightning(["fit", *base, "--trainer.max_epochs", "1"])
    real_get = RecordDataset.get

    def get(self, i):  # the test split's first view is unreadable once the loop runs (setup checked it fine)
        if "test" in self.name and i == 0:  # (in a loader worker, when the config asks for workers)
            raise OSError(f"{self.records[0].key}: truncated file")
        return real_get(self, i)

    monkeypatch.setattr(RecordDataset, "get", get)
    cli = run_lightning(["test", *base, "--ckpt_path", "best"])
    test_set = cli.datamodule.datasets["test"]
    n_test, broken = len(test_set), test_set.records[0].key
    assert n_test > 1
    (report,) = (tmp_path / "runs").rglob("report.json")
    data = json.loads(report.read_text())["data"]
    assert data["samples_replaced"] == [broken]
    assert data["num_samples"] == n_test - 1  # the stand-in sample counts once
    assert "1 test sample(s) failed at load time and were replaced by the next sample" in capsys.readouterr().out
    assert "failed at load time" in (report.parent / "report.md").read_text()
    # the fixture's corrupt and missing files, skipped at setup: the report said nothing of them (console only)
    skipped, log = data["skipped_at_setup"], cli.datamodule.skips
    assert skipped["total"] == log.total > 0 and skipped["counts"] == dict(log.counts)
    assert skipped["log"] == "floaff_kitchen styles" and all(skipped["examples"][k] for k in skipped["counts"])
    assert f"{log.total} record(s) skipped at setup" in (report.parent / "report.md").read_text()
