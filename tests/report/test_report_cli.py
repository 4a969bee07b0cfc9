"""`floaff-zoo test` with the report callbacks, through the real CLI, on the synthetic tiny data."""

import json
from pathlib import Path

import pytest
import torch

from floaff_zoo.cli import run_lightning
from floaff_zoo.report.table import main as table_main
from tests.conftest import quiet_trainer_args

DATA = "configs/data/synthetic_tiny.yaml"
MODEL = "configs/models/tiny_pointnet.yaml"


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    root = Path(__file__).resolve().parents[2]
    tmp = tmp_path_factory.mktemp("fit")
    mp = pytest.MonkeyPatch()
    mp.chdir(root)
    try:
        base = ["--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp)]
        cli = run_lightning(["fit", *base, "--trainer.max_epochs", "1"])
        yield base, cli.trainer.checkpoint_callback.best_model_path, root
    finally:
        mp.undo()


def test_test_writes_report_with_every_metric(fitted, monkeypatch):
    base, ckpt, root = fitted
    monkeypatch.chdir(root)
    cli = run_lightning(
        [
            "test",
            *base,
            "--config",
            "configs/trainer/eval_sr.yaml",
            "--ckpt_path",
            ckpt,
            "--trainer.callbacks.figures_per_group",
            "1",
        ]
    )
    run_dir = Path(cli.trainer.log_dir)
    rep = json.loads((run_dir / "report.json").read_text())
    configured = [f"test_{k}" for k in cli.model.test_metrics.keys(keep_base=True)]
    assert len(configured) >= 4 and set(rep["configured_metrics"]) == set(configured)
    for k in configured:
        assert isinstance(rep["metrics"][k], float), k
        assert rep["metrics"][k] == pytest.approx(float(cli.trainer.callback_metrics[k]))
    assert rep["sr"]["available"] is False and "meta['sim']" in rep["sr"]["reason"]
    assert rep["model"]["name"] == "TinyPointNetModule" and rep["model"]["hparams"]["width"] == 32
    assert rep["checkpoint"]["path"] == str(Path(ckpt).resolve()) and len(rep["checkpoint"]["sha256"]) == 64
    assert rep["seed"] == 0 and rep["config"]["model"]["init_args"]["width"] == 32
    assert rep["data"]["dataset"] == "synthetic" and rep["data"]["num_samples"] == 4
    assert rep["sim_variant"] == "cosine" and rep["metric_reduction"] == "per_sample"
    # how many maps PCC averaged (a constant map has no Pearson r and is left out of its mean)
    assert rep["map_elements"] == {
        "maps": 4,
        "empty": 0,
        "pcc_undefined": cli.model.test_metrics["pcc"].num_undefined,
    }
    assert rep["versions"]["torch"] and rep["versions"]["lightning"]
    md = (run_dir / "report.md").read_text()
    assert "SR: n/a" in md and "| RMSE |" in md
    assert rep["figures"] and all((run_dir / f).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for f in rep["figures"])
    # the table command reads the new report
    assert table_main(["--runs", str(run_dir), "--out", str(run_dir / "t.md")]) == 0
    assert "TinyPointNetModule" in (run_dir / "t.md").read_text()


def test_report_without_callbacks_in_config_is_opt_in(fitted, monkeypatch, tmp_path):
    base, ckpt, root = fitted
    monkeypatch.chdir(root)
    args = [a if a != str(Path(base[base.index("--trainer.default_root_dir") + 1])) else str(tmp_path) for a in base]
    cli = run_lightning(
        [
            "test",
            *args,
            "--ckpt_path",
            ckpt,
            "--trainer.callbacks+=floaff_zoo.callbacks.TestReport",
            "--trainer.callbacks.figures",
            "false",
            "--trainer.callbacks.label",
            "w/o SDL",
        ]
    )
    rep = json.loads((Path(cli.trainer.log_dir) / "report.json").read_text())
    assert rep["label"] == "w/o SDL" and rep["figures"] == []
    assert "no RolloutSuccessRate" in rep["sr"]["reason"]
    assert torch.isfinite(torch.tensor(rep["metrics"]["test_rmse"]))


def test_the_report_says_over_how_many_maps_pcc_is_a_mean():
    """Constant maps (C2F-Exp's all-zero ones, say) are left out of PCC's mean: the report said nothing of it."""
    from floaff_zoo.callbacks.report import render_markdown

    rep = {
        "label": "x",
        "model": {"class_path": "m.M"},
        "metrics": {"test_pcc": 0.5},
        "map_elements": {"maps": 10, "empty": 1, "pcc_undefined": 6},
    }
    assert "PCC over 3 of 10 maps: 6 constant (Pearson r undefined), 1 without a floor point." in render_markdown(rep)
    rep["map_elements"] = {"maps": 10, "empty": 0, "pcc_undefined": 0}
    assert "PCC over" not in render_markdown(rep)


def test_official_batchwise_counts_chunks_not_maps(tmp_path):
    """Under official_batchwise the metrics average 64-sample chunks: 5 samples are one chunk, which the report
    called "1 maps"."""
    from floaff_zoo.callbacks.report import TestReport
    from floaff_zoo.models.base import FloAffModule, FloAffTrainConfig
    from tests.report._fake_world import ConstantModule, loader, make_samples, quiet_trainer

    class Batchwise(ConstantModule):
        def __init__(self) -> None:
            FloAffModule.__init__(self, train=FloAffTrainConfig(metric_reduction="official_batchwise"))

    quiet_trainer([TestReport(figures=False, out_dir=str(tmp_path))]).test(
        Batchwise(), dataloaders=loader(make_samples(5), batch_size=2), verbose=False
    )
    rep = json.loads((tmp_path / "report.json").read_text())
    assert rep["data"]["num_samples"] == 5
    assert rep["map_elements"] == {"chunks": 1, "chunk_size": 64, "empty": 0, "pcc_undefined": 1}
    md = (tmp_path / "report.md").read_text()
    assert "PCC over 0 of 1 chunks of 64 samples: 1 constant (Pearson r undefined)" in md


def test_pcc_of_constant_maps_only_is_null_and_not_ranked(tmp_path):
    """A model whose every map is constant has no Pearson r anywhere: the report wrote test_pcc 0.0, which the table
    then showed (and ranked) as a value."""
    from floaff_zoo.callbacks.report import TestReport
    from tests.report._fake_world import ConstantModule, LabelModule, loader, make_samples, quiet_trainer

    for name, module in (("constant", ConstantModule()), ("labels", LabelModule()), ("labels2", LabelModule())):
        report = TestReport(figures=False, out_dir=str(tmp_path / name), label=name)
        quiet_trainer([report]).test(module, dataloaders=loader(make_samples(4)), verbose=False)
    rep = json.loads((tmp_path / "constant" / "report.json").read_text())
    assert rep["metrics"]["test_pcc"] is None and rep["map_elements"]["pcc_undefined"] == 4
    assert "| n/a |" in (tmp_path / "constant" / "report.md").read_text()
    assert table_main(["--runs", str(tmp_path), "--preset", "ablation", "--out", str(tmp_path / "t.md")]) == 0
    lines = [line.split("|") for line in (tmp_path / "t.md").read_text().splitlines() if line.startswith("|")]
    pcc = next(i for i, c in enumerate(lines[0]) if c.strip().startswith("PCC"))
    cells = {row[1].strip(): row[pcc].strip() for row in lines}
    assert cells["constant"] == "n/a" and cells["labels"] == "**1.000**"  # the constant maps are no rival
