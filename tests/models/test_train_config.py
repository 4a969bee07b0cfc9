"""The shared model machinery: the ``train`` group, checkpoints with the old flat training arguments,
``save_pretrained``/``from_pretrained`` for every model, and the step outputs callbacks read."""

from __future__ import annotations

import json
from pathlib import Path

import lightning
import pytest
import torch
import yaml
from lightning.pytorch.utilities.exceptions import MisconfigurationException

from floaff_zoo.contract import collate_samples
from floaff_zoo.data.synthetic import make_synthetic_sample
from floaff_zoo.hub.io import import_model_class
from floaff_zoo.models.axisnet import AxisNetModule
from floaff_zoo.models.base import FloAffTrainConfig, TrainConfig, ZooModule
from floaff_zoo.models.navaff import NavAffModule
from floaff_zoo.models.tiny import TinyPointNetModule
from tests.conftest import quiet_trainer_args

ROOT = Path(__file__).resolve().parents[2]
#: one small config per model class
TINY_CONFIGS = sorted(
    [
        *ROOT.glob("tests/configs/models/*.yaml"),
        ROOT / "tests/configs/axisnet_tiny.yaml",
        ROOT / "tests/configs/cfar_tiny.yaml",
        ROOT / "configs/models/tiny_pointnet.yaml",
    ]
)
TINY = "floaff_zoo.models.tiny.TinyPointNetModule"
INSTANTIATOR = "lightning.pytorch.cli.instantiate_module"


def build(cfg_path: Path) -> ZooModule:
    cfg = yaml.safe_load(cfg_path.read_text())["model"]
    cls = import_model_class(cfg["class_path"], str(cfg_path))
    return cls(**cfg.get("init_args", {}))


@pytest.fixture(scope="module")
def batch():
    return collate_samples([make_synthetic_sample(i, num_points=256, floor_cells=8) for i in range(2)])


def old_style_ckpt(model: ZooModule, path: Path, flat: dict, cli: bool = True) -> Path:
    """A checkpoint as the code before the ``train`` group wrote it: training args flat in the hparams."""
    hp = {
        **flat,
        **(
            {"_class_path": f"{type(model).__module__}.{type(model).__name__}", "_instantiator": INSTANTIATOR}
            if cli
            else {}
        ),
    }
    torch.save(
        {
            "state_dict": model.state_dict(),
            "hyper_parameters": hp,
            "hparams_name": "kwargs",
            "pytorch-lightning_version": lightning.__version__,
            "epoch": 0,
            "global_step": 0,
        },
        path,
    )
    return path


#: what the old FloAffModule recorded for every model (flat)
OLD_SHARED = {
    "feat_channels": 1,
    "robot_dim": 2,
    "loss": "mse",
    "sdl_beta": 1.0,
    "optimizer": "adam",
    "weight_decay": 0.0,
    "metric_reduction": "per_sample",
    "weights": None,
}


# --------------------------------------------------------------------------- the train group
def test_train_defaults_are_per_model_and_partial_dicts_keep_them():
    nav = NavAffModule(npoints=[32, 16, 8], nsamples=[[4, 8, 8], [4, 8], [4, 8]], train={"lr": 1e-3})
    assert nav.train_cfg == FloAffTrainConfig(loss="navaff", lr=1e-3, weight_decay=1e-3)  # loss, wd: NavAff's
    assert isinstance(nav.hparams["train"], dict)  # stored as a dict: checkpoints stay weights_only
    axis = AxisNetModule(widths=[8], head=[8])
    assert axis.train_cfg == TrainConfig(lr=1e-4, scheduler="none") and type(axis.train_cfg) is TrainConfig
    tiny = TinyPointNetModule(train=FloAffTrainConfig(optimizer="adamw", lr=0.01, weight_decay=0.1))
    opt = tiny.configure_optimizers()["optimizer"]
    assert isinstance(opt, torch.optim.AdamW) and opt.defaults["lr"] == 0.01 and opt.defaults["weight_decay"] == 0.1


@pytest.mark.parametrize(
    ("train", "match"),
    [
        ({"lrr": 0.1}, r"TinyPointNetModule: train has no field\(s\) \['lrr'\]"),
        ({"lr": 0.0}, "train.lr must be a finite number > 0, got 0.0"),
        ({"lr": True}, "train.lr must be a finite number > 0, got True"),  # trained at lr 1
        ({"weight_decay": "0.1"}, r"train.weight_decay must be a finite number >= 0, got '0.1'"),  # a TypeError
        ({"sdl_beta": None}, "train.sdl_beta must be a finite number >= 0, got None"),  # a TypeError
        ({"optimizer": "sgd"}, "train.optimizer: 'sgd' is not one of"),
        ({"loss": "bce"}, "train.loss: 'bce' is not one of"),
        ({"rank_weight": -0.5}, "train.rank_weight must be a finite number >= 0"),
        ({"rank_temperature": 0.0}, "train.rank_temperature must be a finite number > 0"),
    ],
)
def test_bad_train_values_name_the_field(train, match):
    with pytest.raises(ValueError, match=match):
        TinyPointNetModule(train=train)


def test_axisnet_train_has_no_floor_map_fields():
    with pytest.raises(ValueError, match=r"AxisNetModule: train has no field\(s\) \['loss'"):
        AxisNetModule(train={"loss": "mse"})


def test_cli_train_group_partial_override(tmp_path, root, monkeypatch):
    from floaff_zoo.cli import run_lightning

    monkeypatch.chdir(root)
    cli = run_lightning(
        [
            "fit",
            "--config",
            "configs/data/synthetic_tiny.yaml",
            "--config",
            "tests/configs/models/navaff_tiny.yaml",
            "--model.init_args.train.lr",
            "0.0001",
            "--trainer.fast_dev_run",
            "1",
            *quiet_trainer_args(tmp_path),
        ]
    )
    assert cli.model.train_cfg == FloAffTrainConfig(loss="navaff", lr=1e-4, weight_decay=1e-3)


def test_cli_rank_weight_adds_the_listwise_term(tmp_path, root, monkeypatch):
    from floaff_zoo.cli import run_lightning
    from floaff_zoo.losses import listwise_rank_loss, masked_mse

    monkeypatch.chdir(root)
    args = ["--config", "configs/data/synthetic_tiny.yaml", "--config", "configs/models/tiny_pointnet.yaml"]
    cli = run_lightning(
        ["fit", *args, "--model.init_args.train.rank_weight", "0.5", "--trainer.fast_dev_run", "1"]
        + quiet_trainer_args(tmp_path)
    )
    assert cli.model.train_cfg.rank_weight == 0.5 and cli.model.train_cfg.loss == "mse"
    p, g = torch.rand(2, 9), torch.rand(2, 9)
    m = torch.ones(2, 9, dtype=torch.bool)
    want = masked_mse(p, g, m) + 0.5 * listwise_rank_loss(p, g, m)
    assert float(cli.model.criterion(p, g, m)) == pytest.approx(float(want))


# --------------------------------------------------------------------------- old checkpoints
@pytest.mark.parametrize("cli", [True, False])
def test_old_flat_checkpoint_loads(tmp_path, batch, cli):
    torch.manual_seed(0)
    ref = TinyPointNetModule(width=8).eval()
    flat = {"width": 8, **OLD_SHARED, "lr": 0.005, "scheduler": "none", "sim_variant": "hist"}
    ckpt = old_style_ckpt(ref, tmp_path / "old.ckpt", flat, cli=cli)
    m = TinyPointNetModule.load_from_checkpoint(ckpt, weights_only=True).eval()
    assert m.train_cfg == FloAffTrainConfig(lr=0.005, scheduler="none", sim_variant="hist")
    assert "lr" not in m.hparams and m.hparams["width"] == 8
    with torch.no_grad():
        assert torch.equal(m(batch), ref(batch))
    # old-style keyword overrides still work too
    assert TinyPointNetModule.load_from_checkpoint(ckpt, weights_only=True, lr=0.02).train_cfg.lr == 0.02


def test_load_from_checkpoint_overrides_training_fields_one_by_one(tmp_path):
    """A partial train override was completed from the class defaults (the checkpoint's recipe lost: lr 0.001, loss
    mse), and a flat override lost to the saved train without a word."""
    recipe = {"lr": 3e-4, "loss": "aff", "sdl_beta": 0.5}
    ckpt = old_style_ckpt(TinyPointNetModule(width=8), tmp_path / "new.ckpt", {"width": 8, "train": recipe})
    for override in ({"train": {"metric_reduction": "official_batchwise"}}, {"metric_reduction": "official_batchwise"}):
        m = TinyPointNetModule.load_from_checkpoint(ckpt, weights_only=True, **override)
        assert m.train_cfg == FloAffTrainConfig(**recipe, metric_reduction="official_batchwise"), override
    assert TinyPointNetModule.load_from_checkpoint(ckpt, weights_only=True).train_cfg == FloAffTrainConfig(**recipe)


def test_old_axisnet_checkpoint_drops_unused_shared_args(tmp_path, batch):
    torch.manual_seed(0)
    ref = AxisNetModule(widths=[8], head=[8]).eval()
    flat = {
        "crop_radius": 1.3,
        "widths": [8],
        "head": [8],
        "rot_aug_deg": 90.0,
        "jitter_sigma": 0.005,
        **OLD_SHARED,
        "lr": 3e-3,
        "scheduler": "none",
        "sim_variant": "cosine",
    }
    m = AxisNetModule.load_from_checkpoint(old_style_ckpt(ref, tmp_path / "axis.ckpt", flat), weights_only=True).eval()
    assert m.train_cfg == TrainConfig(lr=3e-3, scheduler="none") and "loss" not in m.hparams
    with torch.no_grad():
        assert torch.equal(m(batch), ref(batch))


def test_old_flat_checkpoint_through_cli_and_hub(tmp_path, root, monkeypatch):
    from floaff_zoo.cli import run_lightning
    from floaff_zoo.hub.export import export_checkpoint

    monkeypatch.chdir(root)
    torch.manual_seed(0)
    flat = {"width": 8, **OLD_SHARED, "lr": 0.005, "scheduler": "none", "sim_variant": "hist"}
    ckpt = old_style_ckpt(TinyPointNetModule(width=8), tmp_path / "old.ckpt", flat)
    cli = run_lightning(
        [
            "test",
            "--config",
            "configs/data/synthetic_tiny.yaml",
            "--model",
            "TinyPointNetModule",
            "--ckpt_path",
            str(ckpt),
            *quiet_trainer_args(tmp_path),
        ]
    )
    assert (
        cli.model.hparams["width"] == 8
        and cli.model.train_cfg.sim_variant == "hist"
        and cli.model.train_cfg.lr == 0.005
    )
    _, out = export_checkpoint(ckpt, "tiny.old-flat.v1", directory=tmp_path / "hub")
    init_args = json.loads((out / "config.json").read_text())["init_args"]
    assert init_args["train"]["lr"] == 0.005 and "lr" not in init_args  # exports are written in today's form


# --------------------------------------------------------------------------- save_pretrained / from_pretrained
@pytest.mark.parametrize("cfg", TINY_CONFIGS, ids=lambda p: p.stem)
def test_save_pretrained_from_pretrained_round_trip(cfg, tmp_path, batch):
    torch.manual_seed(0)
    model = build(cfg).eval()
    out = model.save_pretrained(tmp_path / "export")
    config = json.loads((out / "config.json").read_text())
    assert (out / config["weights"]).is_file() and "weights" not in config["init_args"]
    assert config["init_args"]["train"] == model.hparams["train"]
    loaded = type(model).from_pretrained(out)
    assert type(loaded) is type(model) and not loaded.training
    with torch.no_grad():
        assert torch.equal(loaded(batch), model(batch))
    assert ZooModule.from_pretrained(str(out)).hparams == loaded.hparams


def test_exported_directory_as_weights(tmp_path, batch):
    torch.manual_seed(0)
    model = TinyPointNetModule(width=8).eval()
    out = model.save_pretrained(tmp_path / "tiny")
    with torch.no_grad():
        assert torch.equal(TinyPointNetModule(width=8, weights=str(out)).eval()(batch), model(batch))


# --------------------------------------------------------------------------- step outputs for callbacks
def test_test_step_returns_the_prediction(batch):
    floor = TinyPointNetModule(width=8).eval()
    out = floor.test_step(batch, 0)
    assert set(out) == {"loss", "scores"} and out["scores"].shape == batch["floor_mask"].shape
    axis = AxisNetModule(widths=[8], head=[8]).eval()
    out = axis.test_step(batch, 0)
    assert set(out) == {"loss", "yaw"} and out["yaw"].shape == (2,)
    assert not hasattr(floor, "last_test_scores")


def _tiny_loader() -> torch.utils.data.DataLoader:
    """Four synthetic samples in batches of 2: two steps per epoch."""
    return torch.utils.data.DataLoader(
        [make_synthetic_sample(i, num_points=64, floor_cells=4) for i in range(4)],
        batch_size=2,
        collate_fn=collate_samples,
    )


def _quiet_trainer(**kwargs) -> lightning.Trainer:
    return lightning.Trainer(
        accelerator="cpu",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        **kwargs,
    )


def _fit_lrs(**trainer_kwargs) -> tuple[list[float], lightning.Trainer]:
    """The learning rate at every training step of a tiny fit, and its trainer."""
    lrs: list[float] = []

    class Record(lightning.Callback):
        def on_train_batch_start(self, trainer, *_):
            lrs.append(trainer.optimizers[0].param_groups[0]["lr"])

    trainer = _quiet_trainer(callbacks=[Record()], **trainer_kwargs)
    trainer.fit(TinyPointNetModule(), _tiny_loader())
    return lrs, trainer


def test_cosine_schedule_anneals_over_max_steps_with_a_step_budget():
    """configs/trainer/dense_budget.yaml trains to max_steps with max_epochs -1: the cosine schedule decays over the
    steps. It took T_max = 1 epoch, so the learning rate fell to eta_min after the first epoch and rose again after
    the second."""
    lrs, _ = _fit_lrs(max_epochs=-1, max_steps=8)
    assert len(lrs) == 8
    assert all(b < a for a, b in zip(lrs, lrs[1:])), lrs  # no restart, no plateau at eta_min
    assert lrs[0] == pytest.approx(1e-3) and lrs[-1] > 1e-5, lrs
    # with no budget at all (a time limit only) the schedule had T_max 1 epoch: lr, 1e-6, lr, 1e-6, ...
    open_ended = lightning.Trainer(max_epochs=-1, max_time="00:00:00:30", accelerator="cpu", logger=False)
    with pytest.raises(MisconfigurationException, match="'cosine' anneals over trainer.max_epochs or trainer"):
        open_ended.fit(TinyPointNetModule(), _tiny_loader())


def test_cosine_anneals_over_the_steps_when_max_steps_ends_the_fit_before_max_epochs():
    """With both max_epochs and max_steps the schedule ran per epoch over max_epochs: a fit the step budget ended
    first kept nearly the base rate (0.0029 of 0.003 after 8 of 20 epochs' steps); it now anneals over the optimizer
    steps the fit takes."""
    lrs, trainer = _fit_lrs(max_epochs=20, max_steps=8)  # max_steps ends the fit in epoch 4 of 20
    assert len(lrs) == 8 and all(b < a for a, b in zip(lrs, lrs[1:])), lrs
    assert trainer.optimizers[0].param_groups[0]["lr"] == pytest.approx(1e-6, abs=1e-9)


def test_plateau_is_refused_when_validation_runs_by_steps():
    """plateau steps at epoch ends on the monitored metric; with validation every val_check_interval steps (the
    dense budget) the metric was missing there and the fit crashed mid-run, or read a stale value."""
    trainer = _quiet_trainer(max_epochs=-1, max_steps=4, val_check_interval=2, check_val_every_n_epoch=None)
    model = TinyPointNetModule(train=FloAffTrainConfig(scheduler="plateau"))
    with pytest.raises(MisconfigurationException, match="'plateau' steps at epoch ends on val_rmse"):
        trainer.fit(model, _tiny_loader(), _tiny_loader())


def test_navaff_evaluation_loss_repeats_and_draws_nothing():
    """NavAff's training loss draws Bernoulli weights; its val/test loss uses their expectation: the same value on
    every call, and torch's global generator (the training augmentation's) untouched."""
    torch.manual_seed(0)
    batch = collate_samples([make_synthetic_sample(i, num_points=256, floor_cells=6) for i in range(2)])
    batch["floor_label"] = torch.where(batch["floor_label"] < 0.3, 0.0, batch["floor_label"])
    assert ((batch["floor_label"] == 0) & batch["floor_mask"]).any()
    model = NavAffModule(npoints=[32, 16, 8], nsamples=[[4, 8, 8], [4, 8], [4, 8]]).eval()
    with torch.no_grad():
        state = torch.get_rng_state()
        losses = {float(model.model_step(batch)[0]) for _ in range(4)}
        assert torch.equal(state, torch.get_rng_state())
        assert len(losses) == 1, losses
        model.train()  # training keeps the paper's random weights
        state = torch.get_rng_state()
        model.model_step(batch)
        assert not torch.equal(state, torch.get_rng_state())


class _FloorsOfSeveralSizes(torch.utils.data.Dataset):
    """Synthetic samples whose floors keep 64, 52, 40, ... points: padded batches mix maps of different sizes."""

    def __init__(self, dataset: torch.utils.data.Dataset) -> None:
        self.dataset = dataset

    def __len__(self) -> int:
        return len(self.dataset)

    def __getitem__(self, i: int) -> dict:
        s, k = self.dataset[i], 64 - 12 * i
        return {**s, "floor_xyz": s["floor_xyz"][:k], "floor_label": s["floor_label"][:k]}


def _eval_losses(model: lightning.LightningModule, wrap: type, eval_batch_size: int) -> dict[str, float]:
    """Every ``*_loss`` that validating and testing ``model`` logs on synthetic val/test splits seen through ``wrap``
    (a dataset wrapper), at ``eval_batch_size``."""
    from floaff_zoo.data.synthetic import SyntheticDataModule

    class Data(SyntheticDataModule):
        def setup(self, stage: str | None = None) -> None:
            super().setup(stage)
            for split in ("val", "test"):
                self.datasets[split] = wrap(self.datasets[split])

    data = Data(2, 5, 5, 128, 8, batch_size=2, eval_batch_size=eval_batch_size, num_points=128, collate_mode="pad")
    trainer = lightning.Trainer(accelerator="cpu", logger=False, enable_progress_bar=False, enable_model_summary=False)
    logged = {**trainer.validate(model, data, verbose=False)[0], **trainer.test(model, data, verbose=False)[0]}
    return {key: value for key, value in logged.items() if key.endswith("_loss")}


@pytest.mark.parametrize("loss", ["mse", "aff"])
def test_eval_loss_does_not_depend_on_the_eval_batch_size(loss):
    """The eval loss was the MSE pooled over a batch's valid points, which Lightning then averaged over batches by
    sample count: the same five maps gave another val_loss/test_loss (and checkpoint choice) at another eval batch
    size. It is now the mean over maps of each map's loss."""
    lightning.seed_everything(0)
    model = TinyPointNetModule(width=16, train={"loss": loss})
    losses = [_eval_losses(model, _FloorsOfSeveralSizes, b) for b in (1, 4)]
    assert {"val_loss", "test_loss"} <= losses[0].keys()
    assert losses[1] == pytest.approx(losses[0], rel=1e-6)


class _SomeWithoutTarget(_FloorsOfSeveralSizes):
    """As :class:`_FloorsOfSeveralSizes`, and samples 1 and 3 have every label 0: no good position to vote for and no
    positive pose, so a batch mixes samples with and without a target."""

    def __getitem__(self, i: int) -> dict:
        s = super().__getitem__(i)
        return {**s, "floor_label": s["floor_label"] * 0} if i in (1, 3) else s


@pytest.mark.parametrize("name", ["votenet", "h3dnet", "n2m"])
def test_extra_eval_loss_terms_do_not_depend_on_the_eval_batch_size(name):
    """VoteNet's vote term and N2M's likelihood were means over a batch's samples with a target, which Lightning then
    averaged over batches by sample count: val/test losses moved with the eval batch size. In evaluation every term
    is now a mean over samples of each sample's own value (H3DNet's vote term already was one: checked alike)."""
    lightning.seed_everything(0)
    model = build(ROOT / f"tests/configs/models/{name}_tiny.yaml")
    losses = [_eval_losses(model, _SomeWithoutTarget, b) for b in (1, 4)]
    assert {"val_loss", "test_loss"} <= losses[0].keys()
    assert losses[1] == pytest.approx(losses[0], rel=1e-5, abs=1e-7)
