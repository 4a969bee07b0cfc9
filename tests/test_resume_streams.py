"""A fit resumed from last.ckpt goes on with the data stream an uninterrupted fit draws: the shuffle order and the
augmentation noise of the next epochs, not the first epoch's again; validation does not move that stream."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import pytest
import torch

from floaff_zoo.cli import run_lightning
from tests.conftest import quiet_trainer_args

DATA = "configs/data/synthetic_tiny.yaml"
MODEL = "configs/models/tiny_pointnet.yaml"
JITTER = '[{"class_path": "floaff_zoo.data.transforms.Jitter", "init_args": {"sigma": 0.05}}]'


class BatchRecorder(L.Callback):
    """Records (epoch, the batch's first cloud coordinate) of every training batch: order and jitter in one number."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: list[tuple[int, float]] = []

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        self.seen.append((trainer.current_epoch, round(float(batch["scene_xyz"][0, 0, 0]), 6)))


def _fit(out: Path, epochs: int, *extra: str):
    args = [
        "fit",
        "--config",
        DATA,
        "--config",
        MODEL,
        "--data.init_args.train_transforms",
        JITTER,
        "--trainer.max_epochs",
        str(epochs),
        "--trainer.callbacks+=tests.test_resume_streams.BatchRecorder",
        *quiet_trainer_args(out),
        *extra,
    ]
    cli = run_lightning(args)
    (rec,) = [c for c in cli.trainer.callbacks if isinstance(c, BatchRecorder)]
    return cli, [x for _, x in rec.seen], rec.seen


def _epoch(seen, k):
    return [x for e, x in seen if e == k]


def test_a_resumed_fit_draws_the_next_epochs_not_the_first_again(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    _, _, whole = _fit(tmp_path / "whole", 3)
    cli, _, _ = _fit(tmp_path / "cut", 2)
    last = Path(cli.trainer.checkpoint_callback.last_model_path)
    _, _, resumed = _fit(tmp_path / "cut", 3, "--ckpt_path", str(last))
    assert _epoch(resumed, 2) == _epoch(whole, 2)  # the uninterrupted fit's third epoch, order and noise
    assert _epoch(resumed, 2) != _epoch(whole, 0)  # it used to replay the first


def test_a_resumed_fit_with_loader_workers_draws_the_next_epochs_too(tmp_path, root, monkeypatch):
    """Persistent train workers took their seeds once per fit from the shuffle generator: a fit resumed with
    num_workers > 0 took them again from the restored state, so its next epochs drew another order and other noise
    (configs/data/floaff_layouts.yaml runs 2 workers)."""
    monkeypatch.chdir(root)
    workers = ("--data.init_args.num_workers", "2")
    _, _, whole = _fit(tmp_path / "whole", 3, *workers)
    cli, _, _ = _fit(tmp_path / "cut", 2, *workers)
    last = Path(cli.trainer.checkpoint_callback.last_model_path)
    _, _, resumed = _fit(tmp_path / "cut", 3, "--ckpt_path", str(last), *workers)
    assert _epoch(resumed, 2) == _epoch(whole, 2)


class KilledFit(Exception):
    """Stands for a kill (Lightning re-raises it after its own exception hooks)."""


class StepRecorder(L.Callback):
    """Records (global step, the batch's scene ids, its first cloud coordinate) of every training batch; ``kill_at``
    kills the fit at the start of that step, after the checkpoint of the validation before it."""

    def __init__(self, kill_at: int = -1) -> None:
        super().__init__()
        self.kill_at = kill_at
        self.seen: list[tuple[int, tuple[str, ...], float]] = []

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        if trainer.global_step == self.kill_at:
            raise KilledFit
        ids = tuple(m["scene_id"] for m in batch["meta"])
        self.seen.append((trainer.global_step, ids, round(float(batch["scene_xyz"][0, 0, 0]), 6)))


def _steps(out: Path, workers: int, kill: int, *extra: str) -> list[tuple[int, tuple[str, ...], float]]:
    """The steps a fit of 12 steps trains (3 epochs of 4 batches, a validation every 2), killed at step ``kill``."""
    args = ["fit", "--config", DATA, "--config", MODEL, "--data.init_args.train_transforms", JITTER]
    args += ["--data.init_args.num_workers", str(workers), "--trainer.max_epochs", "-1"]
    args += ["--trainer.max_steps", "12", "--trainer.val_check_interval", "2"]
    args += ["--trainer.callbacks+=tests.test_resume_streams.StepRecorder", "--trainer.callbacks.kill_at"]
    cli = run_lightning([*args, str(kill), *quiet_trainer_args(out), *extra])
    (rec,) = [c for c in cli.trainer.callbacks if isinstance(c, StepRecorder)]
    return rec.seen


@pytest.mark.parametrize(("workers", "kill_at"), [(0, 3), (0, 4), (2, 3), (2, 4)])
def test_a_fit_resumed_from_any_validation_goes_on_with_the_uninterrupted_order(
    tmp_path, root, monkeypatch, workers, kill_at
):
    """A validation every 2 of the 4 batches of an epoch (as the dense budget's max_steps runs validate), killed in
    step 3 (last.ckpt half-way through epoch 0) or 4 (last.ckpt from the validation at epoch 0's last batch).
    Lightning restarts the first with a new loader iterator and takes the epoch's remaining batch count from it: the
    first batches of a new permutation (samples trained twice, others not at all); it restarts the second with two
    iterators, and the second one's seed draw moved every later permutation."""
    monkeypatch.chdir(root)

    def steps(out: Path, kill: int = -1, *extra: str) -> list[tuple[int, tuple[str, ...], float]]:
        return _steps(out, workers, kill, *extra)

    whole = steps(tmp_path / "whole")
    with pytest.raises(KilledFit):
        steps(tmp_path / "cut", kill_at)
    (last,) = (tmp_path / "cut").rglob("last.ckpt")
    resumed = steps(tmp_path / "cut", -1, "--ckpt_path", str(last))
    saved = kill_at - kill_at % 2  # the step of the last validation (and last.ckpt) before the kill
    assert [ids for _, ids, _ in resumed] == [ids for _, ids, _ in whole[saved:]]  # the same samples, step by step
    if workers == 0:
        assert resumed == whole[saved:]  # and the same augmentation noise
    else:  # workers take their seeds when an epoch starts: from the next epoch on, the uninterrupted fit's noise
        assert resumed[8 - saved :] == whole[8:]


@pytest.mark.parametrize("workers", [0, 2])
def test_a_fit_killed_again_before_it_trains_keeps_the_uninterrupted_order(tmp_path, root, monkeypatch, workers):
    """Resumed from the validation at epoch 0's last batch, Lightning ends that epoch again and writes last.ckpt again
    at the same step, before the resumed fit trains: it saved the position the pinned epoch had not reached, so a
    second kill there and a second resume drew another order for every later step."""
    monkeypatch.chdir(root)

    def steps(out: Path, kill: int = -1, *extra: str) -> list[tuple[int, tuple[str, ...], float]]:
        return _steps(out, workers, kill, *extra)

    whole = steps(tmp_path / "whole")
    with pytest.raises(KilledFit):
        steps(tmp_path / "cut", 4)
    (last,) = (tmp_path / "cut").rglob("last.ckpt")
    with pytest.raises(KilledFit):  # killed in its first step, after last.ckpt was written again
        steps(tmp_path / "cut", 5, "--ckpt_path", str(last))
    (again,) = set((tmp_path / "cut").rglob("last.ckpt")) - {last}  # the second run's (the curriculum pins one folder)
    resumed = steps(tmp_path / "cut", -1, "--ckpt_path", str(again))
    assert [ids for _, ids, _ in resumed] == [ids for _, ids, _ in whole[4:]]


def test_a_resumed_fit_of_the_recipe_prior_draws_the_next_epochs(tmp_path, root, monkeypatch):
    """CFAR's prior residual (the recipe) averages the training labels in a pass over a train loader when a fit starts;
    a resumed fit made that pass again (adding nothing: its prior is the checkpoint's), and it drew an epoch from the
    restored shuffle generator and augmentation stream, so the resumed stage trained another order and noise."""
    monkeypatch.chdir(root)
    recipe = ("--config", "tests/configs/cfar_tiny.yaml", "--model.init_args.prior_residual", "true")
    cli_whole, _, whole = _fit(tmp_path / "whole", 3, *recipe)
    cli, _, _ = _fit(tmp_path / "cut", 2, *recipe)
    last = Path(cli.trainer.checkpoint_callback.last_model_path)
    cli_resumed, _, resumed = _fit(tmp_path / "cut", 3, "--ckpt_path", str(last), *recipe)
    assert _epoch(resumed, 2) == _epoch(whole, 2)
    assert torch.equal(cli_resumed.model.prior.sums, cli_whole.model.prior.sums)  # the checkpoint's prior, whole


def test_validation_does_not_move_the_training_stream(tmp_path, root, monkeypatch):
    """Each validation's loader iterator drew its base seed from torch's global generator, which the augmentation
    draws from: validating every epoch or every other one gave different training noise from the second epoch on."""
    monkeypatch.chdir(root)
    _, every, _ = _fit(tmp_path / "a", 3, "--trainer.check_val_every_n_epoch", "1")
    _, sparse, _ = _fit(tmp_path / "b", 3, "--trainer.check_val_every_n_epoch", "2")
    assert every == sparse


def test_resuming_restores_the_generators_only_in_fit(tmp_path, root, monkeypatch):
    """Loading a checkpoint to evaluate must not reset the caller's random generators."""
    from floaff_zoo.models.base import RNG_KEY

    monkeypatch.chdir(root)
    cli, _, _ = _fit(tmp_path / "run", 1)
    checkpoint = torch.load(cli.trainer.checkpoint_callback.best_model_path, weights_only=True)  # as fits read it
    assert set(checkpoint[RNG_KEY]) == {"torch", "numpy", "python"}
    model = type(cli.model)()  # no trainer: a model loaded to test or predict with
    torch.manual_seed(123)
    expected = torch.rand(3)
    torch.manual_seed(123)
    model.on_load_checkpoint(checkpoint)
    assert torch.equal(torch.rand(3), expected)
    # a validation from the checkpoint (a trainer, but not a fit) leaves them as a validation without it does
    after = []
    for ckpt_path in (None, cli.trainer.checkpoint_callback.best_model_path):
        torch.manual_seed(123)
        trainer = L.Trainer(accelerator="cpu", logger=False, enable_progress_bar=False, enable_model_summary=False)
        trainer.validate(cli.model, datamodule=cli.datamodule, ckpt_path=ckpt_path, verbose=False)
        after.append(torch.rand(3))
    assert torch.equal(*after)


class OrderRecorder(L.Callback):
    """Records (epoch, the batch's scene ids) of every training batch: the shuffle order alone."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: list[tuple[int, tuple[str, ...]]] = []

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        self.seen.append((trainer.current_epoch, tuple(m["scene_id"] for m in batch["meta"])))


def test_reloading_the_train_loader_goes_on_with_its_shuffle(tmp_path, root, monkeypatch):
    """With ``reload_dataloaders_every_n_epochs`` each reloaded train loader got a generator seeded anew (or set to a
    resumed checkpoint's state again): every reloaded epoch drew the same shuffle order."""
    monkeypatch.chdir(root)

    def orders(out: Path, epochs: int, *extra: str) -> dict[int, list[tuple[str, ...]]]:
        args = ["fit", "--config", DATA, "--config", MODEL, "--trainer.max_epochs", str(epochs)]
        args += ["--trainer.reload_dataloaders_every_n_epochs", "1"]
        args += ["--trainer.callbacks+=tests.test_resume_streams.OrderRecorder", *quiet_trainer_args(out), *extra]
        cli = run_lightning(args)
        (rec,) = [c for c in cli.trainer.callbacks if isinstance(c, OrderRecorder)]
        return {e: [ids for k, ids in rec.seen if k == e] for e in range(epochs)}

    whole = orders(tmp_path / "whole", 4)
    assert len({tuple(whole[e]) for e in range(4)}) == 4, whole  # every epoch its own order
    cut = tmp_path / "cut"
    orders(cut, 2)
    last = sorted(cut.rglob("last.ckpt"))[-1]
    resumed = orders(cut, 4, "--ckpt_path", str(last))
    assert [resumed[2], resumed[3]] == [whole[2], whole[3]]


def test_a_fit_on_a_gpu_saves_and_restores_each_devices_generator(tmp_path, root, monkeypatch):
    """GPU dropout and sampling draw from each CUDA device's generator, which a resumed fit did not restore. (No GPU
    here: torch.cuda's state functions are stood in for.)"""
    from floaff_zoo.models.base import RNG_KEY

    monkeypatch.chdir(root)
    cli, _, _ = _fit(tmp_path / "run", 1)
    model = cli.model
    saved = [torch.arange(4, dtype=torch.uint8), torch.arange(4, 8, dtype=torch.uint8)]
    monkeypatch.setattr(torch.cuda, "is_initialized", lambda: True)
    monkeypatch.setattr(torch.cuda, "get_rng_state_all", lambda: saved)
    checkpoint: dict = {}
    model.on_save_checkpoint(checkpoint)
    assert checkpoint[RNG_KEY]["cuda"] == saved

    restored = []
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)  # resumed on one GPU of the two
    monkeypatch.setattr(torch.cuda, "set_rng_state_all", restored.extend)
    monkeypatch.setattr(model._trainer.state, "fn", "fit")
    model.on_load_checkpoint(checkpoint)
    assert restored == saved[:1]
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)  # a GPU checkpoint resumed on a CPU
    model.on_load_checkpoint(checkpoint)
    assert restored == saved[:1]
    # under DDP rank 0's checkpoint holds no other rank's stream: none is saved, none restored
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(type(model._trainer), "world_size", property(lambda self: 2))
    ddp: dict = {}
    model.on_save_checkpoint(ddp)
    model.on_load_checkpoint(checkpoint)
    assert "cuda" not in ddp[RNG_KEY] and restored == saved[:1]


def test_persistent_train_workers_live_across_epochs_and_a_resume_with_them_warns(tmp_path, root, monkeypatch):
    """``data.persistent_train_workers`` keeps the train workers (no restart per epoch, costly under ``spawn``): the
    first epoch is the restarted workers' one, the next are not (no new worker seeds drawn from the shuffle stream);
    a fit resumed with them is not the uninterrupted one, and says so."""
    monkeypatch.chdir(root)
    workers = ("--data.init_args.num_workers", "1")
    keep = (*workers, "--data.init_args.persistent_train_workers", "true")
    _, _, restarted = _fit(tmp_path / "restarted", 2, *workers)
    cli, _, kept = _fit(tmp_path / "kept", 2, *keep)
    assert cli.datamodule.train_dataloader().persistent_workers
    assert _epoch(kept, 0) == _epoch(restarted, 0) and _epoch(kept, 1) != _epoch(restarted, 1)
    last = Path(cli.trainer.checkpoint_callback.last_model_path)
    with pytest.warns(UserWarning, match="persistent_train_workers: the resumed fit"):
        _fit(tmp_path / "kept", 3, "--ckpt_path", str(last), *keep)


def test_persistent_train_workers_must_be_a_bool(tmp_path, root, monkeypatch):
    from floaff_zoo.data.base import DataConfigError
    from floaff_zoo.data.synthetic import SyntheticDataModule

    with pytest.raises(DataConfigError, match="data.persistent_train_workers must be true or false, got 'false'"):
        SyntheticDataModule(persistent_train_workers="false")
