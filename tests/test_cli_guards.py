"""Guards of the trainer commands: ``--ckpt_path best|last`` carries the checkpoint's hyper-parameters, a bad
``weights`` is one error line, and evaluation refuses weights that leave part of the model untrained."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import lightning as L
import pytest
import torch
from lightning.pytorch.utilities.exceptions import MisconfigurationException

from floaff_zoo.cli import CLIError, main, run_lightning
from floaff_zoo.models.tiny import TinyPointNetModule
from floaff_zoo.runs import RunError
from tests.conftest import ROOT, console, quiet_trainer_args

DATA = "configs/data/synthetic_tiny.yaml"
MODEL = "configs/models/tiny_pointnet.yaml"  # width 32
#: a typo of a shipped hub name (the shipped index is read in every test environment)
TYPO = "pointnet2-ssg.floaff-demo-layouts.v9"


def _fit(tmp_path, *extra: str) -> list[str]:
    return [
        "fit",
        "--config",
        DATA,
        "--config",
        MODEL,
        "--trainer.max_epochs",
        "1",
        *quiet_trainer_args(tmp_path),
        *extra,
    ]


@pytest.fixture(scope="module")
def width16_run(tmp_path_factory):
    """A one-epoch fit of the tiny model with width 16 and lr 0.01 (the config says 32 and 0.003)."""
    out = tmp_path_factory.mktemp("run16")
    with pytest.MonkeyPatch.context() as mp:
        mp.chdir(ROOT)
        cli = run_lightning(_fit(out, "--model.init_args.width", "16", "--model.init_args.train.lr", "0.01"))
    return out, Path(cli.trainer.checkpoint_callback.best_model_path)


@pytest.mark.parametrize("alias", ["best", "last"])
def test_ckpt_alias_applies_the_checkpoint_hparams(width16_run, root, monkeypatch, alias):
    """`--ckpt_path best` used to be resolved after Lightning's hparams step: a shape mismatch traceback, and the
    config's hparams silently replacing the checkpoint's."""
    monkeypatch.chdir(root)
    out, best = width16_run
    cli = run_lightning(["test", "--config", DATA, "--config", MODEL, *quiet_trainer_args(out), "--ckpt_path", alias])
    assert cli.model.hparams.width == 16
    assert cli.model.train_cfg.lr == 0.01  # not a shape: it was replaced by the config's 0.003 silently
    if alias == "best":
        assert Path(cli.config_init["test"]["ckpt_path"]).resolve() == best.resolve()


def test_ckpt_alias_without_a_run_is_a_run_error(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    with pytest.raises(RunError, match="no last.ckpt"):
        main(["test", "--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path), "--ckpt_path", "best"])


def _other_model_run(src: Path, root: Path) -> Path:
    """A newer run of another model class under ``root``: ``src`` with its recorded class changed."""
    ckpt = torch.load(src, map_location="cpu", weights_only=True)
    ckpt["hyper_parameters"]["_class_path"] = "floaff_zoo.models.cfar.CFARModule"
    dest = root / "cfarmodule" / "version_0" / "checkpoints" / "last.ckpt"
    dest.parent.mkdir(parents=True)
    torch.save(ckpt, dest)
    return dest


@pytest.mark.parametrize("alias", ["best", "last"])
def test_ckpt_alias_skips_the_runs_of_other_models(width16_run, tmp_path, root, monkeypatch, alias):
    """Without a run's own config, ``best``/``last`` search ``trainer.default_root_dir``: they took the newest
    last.ckpt of any model there, and the model it recorded was evaluated instead of the configured one."""
    monkeypatch.chdir(root)
    out, best = width16_run
    shutil.copytree(out, tmp_path / "runs")
    mine = next((tmp_path / "runs").rglob("last.ckpt"))
    other = _other_model_run(mine, tmp_path / "runs")
    os.utime(mine, (1, 1))  # the other model's run is the newer one
    cli = run_lightning(["test", "--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path / "runs"),
                         "--ckpt_path", alias])  # fmt: skip
    chosen = Path(cli.config_init["test"]["ckpt_path"])
    assert chosen != other and chosen.name == (best.name if alias == "best" else mine.name)
    assert isinstance(cli.model, TinyPointNetModule) and cli.model.hparams.width == 16


def test_ckpt_alias_with_only_other_models_is_a_run_error(width16_run, tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    other = _other_model_run(next(width16_run[0].rglob("last.ckpt")), tmp_path)
    with pytest.raises(RunError, match="no last.ckpt of TinyPointNetModule") as info:
        main(["test", "--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path), "--ckpt_path", "best"])
    assert f"{other} (CFARModule)" in str(info.value)


@pytest.mark.parametrize("command", ["fit", "validate", "test", "predict"])
def test_unknown_hub_name_is_one_line_with_suggestions(tmp_path, root, monkeypatch, command):
    monkeypatch.chdir(root)
    args = [command, "--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path)]
    with pytest.raises(CLIError) as info:
        main([*args, "--model.init_args.weights", TYPO])
    message = str(info.value)
    assert "\n" not in message and TYPO in message and "did you mean" in message
    assert "pointnet2-ssg.floaff-demo-layouts.v2" in message


def test_corrupt_weights_file_is_one_line_on_stderr(tmp_path, root):
    bad = tmp_path / "x.ckpt"
    bad.write_bytes(b"\x80\x02not a pickle at all" * 10)
    run = subprocess.run(
        [sys.executable, "-m", "floaff_zoo", "test", "--config", DATA, "--config", MODEL]
        + [*quiet_trainer_args(tmp_path), "--model.init_args.weights", str(bad)],
        capture_output=True,
        text=True,
        cwd=root,
    )
    assert run.returncode == 2
    lines = [line for line in run.stderr.splitlines() if line.strip()]
    # the whole of stderr, log handlers bound to the real stream included (the in-process tests see sys.stderr only)
    assert len(lines) == 1, run.stderr
    assert lines[0].startswith("floaff-zoo: error: --model.init_args.weights") and str(bad) in lines[0]


@pytest.fixture
def width16_weights(tmp_path):
    """Exported weights of a width-16 tiny model (the config builds width 32)."""
    torch.manual_seed(0)
    return TinyPointNetModule(width=16).save_pretrained(tmp_path / "w16")


@pytest.mark.parametrize("command", ["validate", "test", "predict"])
def test_evaluation_refuses_weights_that_do_not_fit(width16_weights, tmp_path, root, monkeypatch, command):
    monkeypatch.chdir(root)
    args = [command, "--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path)]
    with pytest.warns(UserWarning, match="skipped"), pytest.raises(CLIError) as info:
        main([*args, "--model.init_args.weights", str(width16_weights)])
    message = str(info.value)
    assert str(width16_weights) in message and "not loaded" in message
    assert "net.head.0.bias: (32,) vs (64,)" in message  # shape in the weights vs the model's
    assert not list(tmp_path.rglob("report.json"))


def test_fit_still_starts_from_weights_that_do_not_fit(width16_weights, tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    args = ["fit", "--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path), "--trainer.fast_dev_run", "1"]
    with pytest.warns(UserWarning, match="skipped"):
        cli = run_lightning([*args, "--model.init_args.weights", str(width16_weights)])
    assert cli.model.weights_not_loaded  # recorded, not refused: initialising a fit is what weights are for


def test_evaluation_accepts_weights_that_fit(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    weights = TinyPointNetModule(width=32).save_pretrained(tmp_path / "w32")
    args = ["validate", "--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path)]
    cli = run_lightning([*args, "--model.init_args.weights", str(weights)])
    assert cli.model.weights_not_loaded == []


def test_predict_names_the_task_a_prior_needs():
    """The README's predict snippet passed no task: a CFAR/prior model failed deep inside with "task '' has no
    grid"; predict now says which argument to pass and the tasks the model knows."""
    import numpy as np

    from floaff_zoo.models.prior import CanonicalPriorModule
    from floaff_zoo.predict import predict_from_points

    model = CanonicalPriorModule(tasks=["CloseDrawer"]).eval()
    rng = np.random.default_rng(0)
    xyz = rng.uniform(-1, 2, (200, 3)).astype(np.float32)
    xyz[:100, 2] = 0
    xyz[100:110] = [1.0, 0.0, 0.5] + rng.normal(scale=0.02, size=(10, 3))  # the target's points, flagged +1
    feat = np.zeros((200, 1), np.float32)
    feat[100:110] = 1.0
    args = (model, xyz, feat, None, [0.85, 1.03], [1.0, 0.0, 0.5])
    with pytest.raises(ValueError, match=r"pass task= one of \['CloseDrawer'\].*got ''"):
        predict_from_points(*args, cell=0.2)
    assert predict_from_points(*args, cell=0.2, task="CloseDrawer").scores.size


@pytest.fixture
def not_checkpoints(width16_run, tmp_path):
    """Files that are no Lightning checkpoint: a truncated real one, text, a bare state dict, a tensor."""
    files = {"truncated": tmp_path / "truncated.ckpt", "text": tmp_path / "text.ckpt"}
    files["truncated"].write_bytes(width16_run[1].read_bytes()[:5000])
    files["text"].write_text("hello, not a checkpoint\n")
    files["state_dict"] = tmp_path / "state_dict.ckpt"
    torch.save(TinyPointNetModule(width=16).state_dict(), files["state_dict"])
    files["tensor"] = tmp_path / "tensor.ckpt"
    torch.save(torch.zeros(3), files["tensor"])
    return files


@pytest.mark.parametrize("command", ["fit", "test"])
def test_ckpt_path_that_is_no_checkpoint_is_one_line_naming_it(not_checkpoints, tmp_path, root, monkeypatch, command):
    """Lightning's loaders failed with OSError, KeyError: 101, KeyError 'pytorch-lightning_version' or
    AttributeError tracebacks that never named the file."""
    monkeypatch.chdir(root)
    args = [command, "--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path), "--trainer.logger", "false"]
    for kind, path in not_checkpoints.items():
        with pytest.raises(CLIError) as info:
            main([*args, "--ckpt_path", str(path)])
        message = str(info.value)
        assert message.startswith(f"--ckpt_path {path}: ") and "\n" not in message, kind
    assert sorted(tmp_path.rglob("*.ckpt")) == sorted(not_checkpoints.values())  # no fit ran


def test_ckpt_path_that_is_no_checkpoint_exits_2_at_the_console(not_checkpoints, tmp_path, root, monkeypatch, capsys):
    monkeypatch.chdir(root)
    bad = not_checkpoints["text"]
    args = ["test", "--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path), "--ckpt_path", str(bad)]
    rc, _, lines = console(monkeypatch, capsys, args)
    assert rc == 2 and lines == [f"floaff-zoo: error: --ckpt_path {bad}: not a readable checkpoint (KeyError: 101)"]


def test_ckpt_best_with_a_truncated_last_ckpt_names_it(width16_run, tmp_path, root, monkeypatch):
    """`--ckpt_path best` reads last.ckpt for the best path: a truncated one was a raw OSError."""
    monkeypatch.chdir(root)
    last = tmp_path / "run" / "checkpoints" / "last.ckpt"
    last.parent.mkdir(parents=True)
    last.write_bytes(next(width16_run[0].rglob("last.ckpt")).read_bytes()[:5000])
    args = ["test", "--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path / "run"), "--ckpt_path", "best"]
    with pytest.raises(RunError) as info:
        main(args)
    assert str(info.value).startswith(f"--ckpt_path best: {last}: not a readable checkpoint")


@pytest.mark.parametrize(
    ("command", "config", "flags", "expected"),
    [
        (
            "fit",
            DATA,
            ["--model.init_args.train.lr", "-1"],
            "model (TinyPointNetModule): train.lr must be a finite number > 0",
        ),
        (
            "fit",
            "configs/data/floaff_tiny.yaml",  # the task names are checked before any data is read
            ["--data.init_args.tasks", "[CloseDrawr]"],
            "data (FloAffKitchenDataModule): unknown tasks ['CloseDrawr']",
        ),
        (
            "test",
            DATA,
            ["--trainer.callbacks+", "floaff_zoo.callbacks.TestReport", "--trainer.callbacks.figures_per_group", "-1"],
            "trainer.callbacks: TestReport: figures_per_group must be >= 0",
        ),
        # the rollout callback's sizes failed at the end of the test epoch (workers), or silently merged distinct
        # poses into one cached episode (cache_decimals < 0) or collected no validation episode
        *[
            (
                "fit",
                DATA,
                [
                    *("--trainer.max_steps", "1"),  # should the check go, the fit stays short
                    *("--trainer.callbacks+", "floaff_zoo.callbacks.RolloutSuccessRate", f"--trainer.callbacks.{k}", v),
                ],
                f"trainer.callbacks: RolloutSuccessRate: {k} must be an integer >= ",
            )
            for k, v in (("workers", "0"), ("cache_decimals", "-1"), ("max_val_samples", "0"))
        ],
        # a width of 0 built a model that ignores its input and trained it; a negative one named no argument
        (
            "fit",
            DATA,
            ["--model.init_args.width", "0", "--trainer.max_steps", "1"],
            "model (TinyPointNetModule): TinyPointNetModule: width must be an integer >= 1, got 0",
        ),
        (
            "fit",
            DATA,
            ["--model.init_args.width", "-3"],
            "model (TinyPointNetModule): TinyPointNetModule: width must be an integer >= 1, got -3",
        ),
    ],
)
def test_init_arg_rejected_by_a_class_is_one_line_naming_the_part(
    tmp_path, root, monkeypatch, command, config, flags, expected
):
    """A ValueError of a model/data/callback __init__ was buried in a 60-115 line jsonargparse traceback."""
    monkeypatch.chdir(root)
    with pytest.raises(CLIError) as info:
        main([command, "--config", config, "--config", MODEL, *quiet_trainer_args(tmp_path), *flags])
    assert str(info.value).startswith(expected) and "\n" not in str(info.value)


@pytest.mark.parametrize("field", ["axisnet", "teacher"])
def test_a_missing_frozen_net_file_is_one_line_naming_the_field(tmp_path, root, monkeypatch, capsys, field):
    """A missing AxisNet file was a FileNotFoundError traceback through jsonargparse's union types, a missing teacher
    one a traceback from the fit's setup."""
    monkeypatch.chdir(root)
    missing = tmp_path / "nosuch.ckpt"
    args = ["fit", "--config", DATA, "--config", "tests/configs/cfar_tiny.yaml", *quiet_trainer_args(tmp_path)]
    rc, _, err = console(monkeypatch, capsys, [*args, f"--model.init_args.{field}", str(missing)])
    errors = [line for line in err if line.startswith("floaff-zoo: error: ")]
    assert rc == 2 and len(errors) == 1 and f"{field} '{missing}'" in errors[0], err
    assert "no such file" in errors[0] and not any("Traceback" in line for line in err)


def test_init_error_exits_2_at_the_console_and_a_bug_keeps_its_traceback(tmp_path, root, monkeypatch, capsys):
    monkeypatch.chdir(root)
    args = ["fit", "--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path)]
    rc, _, lines = console(monkeypatch, capsys, [*args, "--model.init_args.train.lr", "-1"])
    expected = "floaff-zoo: error: model (TinyPointNetModule): train.lr must be a finite number > 0, got -1.0"
    assert rc == 2 and lines[-1] == expected

    def bug(self):
        raise TypeError("a bug, not a configuration error")

    monkeypatch.setattr(TinyPointNetModule, "configure_models", bug)
    with pytest.raises(Exception, match="a bug") as info:  # noqa: PT011 - jsonargparse's wrapping, unchanged
        main(args)
    assert not isinstance(info.value, CLIError)


def test_init_error_stays_one_line_when_jsonargparse_does_not_show_the_part(tmp_path, root, monkeypatch):
    """The config key is read from jsonargparse's own frames; should a release hide it, the message still comes out
    in one line, without the key, instead of the traceback of union types."""
    from floaff_zoo import cli

    monkeypatch.chdir(root)
    monkeypatch.setattr(cli, "_instantiated_part", lambda exc: None)
    args = ["fit", "--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path)]
    with pytest.raises(CLIError) as info:
        main([*args, "--model.init_args.train.lr", "-1"])
    assert str(info.value) == "train.lr must be a finite number > 0, got -1.0"


@pytest.mark.parametrize(
    ("flags", "expected"),
    [
        (["--model.init_args.npoints", "[64,0,8]"], "npoints: a level's centres must be an integer >= 1, got 0"),
        (
            ["--model.init_args.nsamples", "[[0],[8],[8]]"],
            "nsamples: a ball's neighbours must be an integer >= 1, got 0",
        ),
    ],
)
def test_pointnet2_sizes_are_checked_before_the_first_batch(tmp_path, root, monkeypatch, flags, expected):
    """A set-abstraction size below 1 failed at the first batch with a traceback naming no argument."""
    monkeypatch.chdir(root)
    model = "tests/configs/models/pointnet2_ssg_tiny.yaml"
    with pytest.raises(CLIError) as info:
        args = ["fit", "--config", DATA, "--config", model, "--trainer.max_steps=1", *quiet_trainer_args(tmp_path)]
        main([*args, *flags])
    assert str(info.value).startswith("model (PointNet2Module): ") and expected in str(info.value)


def test_a_data_config_without_class_path_is_named(tmp_path, root, monkeypatch):
    """It built the abstract base, which then said that no 'val' split was set up."""
    monkeypatch.chdir(root)
    cfg = tmp_path / "data.yaml"
    cfg.write_text("data:\n  init_args:\n    batch_size: 4\n")
    with pytest.raises(CLIError, match=r"no class_path: FloAffDataModule is the base class"):
        main(["fit", "--config", str(cfg), "--config", MODEL, *quiet_trainer_args(tmp_path)])


def test_fit_with_a_missing_ckpt_path_is_one_line_before_any_run_folder(tmp_path, root, monkeypatch):
    """Lightning failed with a traceback after the run folder was made."""
    monkeypatch.chdir(root)
    missing = tmp_path / "nope.ckpt"
    args = ["fit", "--config", DATA, "--config", MODEL, "--trainer.max_steps=1", *quiet_trainer_args(tmp_path)]
    with pytest.raises(CLIError, match=f"--ckpt_path {missing}: no such file"):
        main([*args, "--ckpt_path", str(missing)])
    assert not list(tmp_path.rglob("version_*"))


@pytest.mark.parametrize("precision", ["64-true", "bf16-true"])
def test_a_precision_that_converts_the_weights_is_one_line_before_the_first_step(
    tmp_path, root, monkeypatch, precision
):
    """Lightning converted the weights to float64 / bfloat16 and the first step failed with a dtype traceback deep
    in a linear layer (the point ops take float32 inputs)."""
    monkeypatch.chdir(root)
    args = ["fit", "--config", DATA, "--config", MODEL, "--trainer.max_steps=1", *quiet_trainer_args(tmp_path)]
    with pytest.raises(MisconfigurationException, match=rf"trainer.precision '{precision}': TinyPointNetModule runs"):
        main([*args, "--trainer.precision", precision])
    assert not list(tmp_path.rglob("*.ckpt"))
    main([*args, "--trainer.precision", "bf16-mixed"])  # autocast keeps float32 weights: it runs
    assert list(tmp_path.rglob("*.ckpt"))


def test_a_mistyped_fps_backend_fails_before_the_first_batch(tmp_path, root, monkeypatch, capsys):
    monkeypatch.chdir(root)
    monkeypatch.setenv("FLOAFF_ZOO_FPS_BACKEND", "torh")
    rc, _, lines = console(monkeypatch, capsys, ["fit", "--config", DATA, "--config", MODEL])
    assert rc == 2 and lines == ["floaff-zoo: error: FLOAFF_ZOO_FPS_BACKEND='torh': choose auto, cpp or torch"]


def test_outputs_that_cannot_be_written_are_one_line(tmp_path, root, monkeypatch, capsys):
    """table --out and curriculum --root under a file gave a raw OSError traceback."""
    from floaff_zoo import curriculum
    from floaff_zoo.report.table import main as table_main

    monkeypatch.chdir(root)
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    runs = root / "tests/report/fixtures/runs"
    assert table_main(["--runs", str(runs), "--out", str(blocker / "t.md")]) == 2
    assert f"--out {blocker / 't.md'}: cannot write" in capsys.readouterr().err
    with pytest.raises(curriculum.CurriculumError, match=f"--root {blocker / 'x'}: cannot create the run folder"):
        curriculum.main(["--config", "tests/configs/pfal_tiny.yaml", "--root", str(blocker / "x")])


def test_demo_refuses_epochs_below_one_before_generating(tmp_path):
    """--epochs 0 generated the whole benchmark and then blamed checkpointing; -1 trained without end."""
    from floaff_zoo import demo

    for epochs in ("0", "-1"):
        with pytest.raises(SystemExit) as info:
            demo.parse_args(["--epochs", epochs, "--data", str(tmp_path / "d")])
        assert info.value.code == 2
    assert not (tmp_path / "d").exists()


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"\xff\xfe", r"bad\.yaml: unreadable \('utf-8' codec"),  # a UnicodeDecodeError traceback
        (b"", r"bad\.yaml: empty file"),  # "Unexpected config: "
        (b"- a\n", r"bad\.yaml: expected a mapping of settings .* got a list"),
        (b"a:\n\tb: 1\n", r"bad\.yaml: not valid YAML"),  # a position in "<unicode string>", no file
        (b"trainer: null\n", r"trainer: expected a mapping of trainer settings, got None"),  # an AttributeError
        (b"model:\n  init_args:\n    train: 3\n", r"model\.init_args\.train: expected a mapping"),  # a TypeError
    ],
)
def test_a_bad_config_file_is_named_in_one_line(tmp_path, root, monkeypatch, content, message):
    monkeypatch.chdir(root)
    bad = tmp_path / "bad.yaml"
    bad.write_bytes(content)
    with pytest.raises(CLIError, match=message):
        main(_fit(tmp_path, "--config", str(bad)))


@pytest.mark.parametrize(
    ("flags", "hint"),
    [
        (["--model", "TinyPointNetModul"], "did you mean 'TinyPointNetModule'"),  # a bare class name
        (["--data.class_path", "floaff_zoo.data.synthetic.SynthDataModule"], "did you mean 'SyntheticDataModule'"),
        (["--model", "Zzzz"], r"model classes: \['AxisNetModule'"),  # nothing close: the known ones
    ],
)
def test_a_mistyped_model_or_data_class_names_the_classes_it_may_mean(tmp_path, root, monkeypatch, flags, hint):
    """jsonargparse said only that the name was no import path, among 300 characters of union subtypes."""
    monkeypatch.chdir(root)
    with pytest.raises(CLIError, match=hint) as info:
        main(_fit(tmp_path, *flags))
    assert "FloAffModule" not in str(info.value)  # a base class is no choice


def test_no_flag_is_read_from_a_prefix_of_it(tmp_path, root, monkeypatch):
    """argparse took --trainer.limit_train_batch 1 for --trainer.limit_train_batches, read as the fraction 1.0
    (only the exact flag is read as a batch count): every batch ran."""
    monkeypatch.chdir(root)
    with pytest.raises(CLIError, match="unrecognized arguments: --trainer.limit_train_batch 1"):
        main(_fit(tmp_path, "--trainer.limit_train_batch", "1"))


def test_a_seed_out_of_range_and_an_infinite_rate_are_named(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    with pytest.raises(CLIError, match=r"seed_everything: -1 is not a seed"):
        main(_fit(tmp_path, "--seed_everything", "-1"))
    with pytest.raises(CLIError, match=r"model \(TinyPointNetModule\): train\.lr must be a finite number > 0, got inf"):
        main(_fit(tmp_path, "--model.init_args.train.lr", ".inf"))


def test_a_diverged_fit_ends_in_one_line(tmp_path, root, monkeypatch, capsys):
    """A loss that is no longer finite stopped the fit with a 97-line traceback around the message."""
    monkeypatch.chdir(root)
    out = subprocess.run(
        [sys.executable, "-m", "floaff_zoo", *_fit(tmp_path, "--model.init_args.train.lr", "1e30")],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "MUJOCO_GL": "egl"},
    )
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert out.stderr.strip().splitlines()[-1].startswith("floaff-zoo: error: train loss is nan on samples")


@pytest.mark.parametrize(
    ("make", "kwargs", "message"),
    [
        ("YawPerturb", {"max_deg": float("nan")}, "max_deg"),
        ("Jitter", {"sigma": float("nan")}, "sigma"),
        ("Jitter", {"sigma": 0.01, "clip": -1.0}, "clip"),
        ("SyntheticDataModule", {"floor_cells": -1}, "floor_cells"),
        ("SyntheticDataModule", {"num_train": -1}, "num_train"),
        ("RolloutSuccessRate", {"n_bootstrap": -1}, "n_bootstrap"),
    ],
)
def test_bad_sizes_and_non_finite_settings_are_named_up_front(make, kwargs, message):
    """NaN / inf augmentation ranges failed in numpy mid-epoch or turned every point NaN; negative synthetic sizes
    failed in numpy at the sanity check; a negative bootstrap count read as std 0."""
    from floaff_zoo.callbacks import RolloutSuccessRate
    from floaff_zoo.data.synthetic import SyntheticDataModule
    from floaff_zoo.data.transforms import Jitter, YawPerturb

    classes = {c.__name__: c for c in (YawPerturb, Jitter, SyntheticDataModule, RolloutSuccessRate)}
    with pytest.raises(ValueError, match=message):
        classes[make](**kwargs)


def test_generate_refuses_an_empty_out_and_the_demo_a_preset_it_cannot_run(tmp_path, monkeypatch, capsys):
    from floaff_zoo import demo
    from floaff_zoo.sim import generate

    monkeypatch.chdir(tmp_path)
    assert generate.main(["--preset", "tiny", "--out", "", "--workers", "0"]) == 2
    assert "--out is empty" in capsys.readouterr().err and not list(tmp_path.iterdir())
    with pytest.raises(SystemExit):
        demo.parse_args(["--preset", "tiny"])  # found only after generating the data and starting the curriculum
    assert "needs the Layouts benchmark with all four tasks" in capsys.readouterr().err


def test_montage_names_an_unreadable_figure(tmp_path):
    from floaff_zoo.report.montage import MontageError, _read_image

    bad = tmp_path / "CloseDrawer_front_1.png"
    bad.write_text("garbage")
    with pytest.raises(MontageError, match=r"CloseDrawer_front_1\.png: not a readable image"):
        _read_image(bad)


def test_a_hub_dir_that_is_a_file_and_a_bad_clip_value_are_named(tmp_path, root, monkeypatch, capsys):
    from floaff_zoo.hub.cli import main as hub_main

    (tmp_path / "hubfile").write_text("x")
    assert hub_main(["list", "--hub-dir", str(tmp_path / "hubfile")]) == 2  # "[Errno 17] File exists" before
    assert "hubfile: is a file, not a hub folder" in capsys.readouterr().err
    monkeypatch.chdir(root)
    with pytest.raises(
        CLIError, match=r"trainer\.gradient_clip_val must be a finite number >= 0 or null \(no clipping\), got nan"
    ):
        main(_fit(tmp_path, "--trainer.gradient_clip_val", ".nan"))  # Lightning said "use only one of them"


def test_a_fit_whose_data_setup_fails_leaves_no_empty_run_folder(tmp_path, root, monkeypatch):
    """Lightning makes ``version_N`` before the data module's setup refuses its root: the folder stayed, empty, and
    the next run became ``version_1``. A run that wrote anything keeps its folder (the other test below)."""
    monkeypatch.chdir(root)
    out = tmp_path / "runs"
    args = ["fit", "--config", "configs/data/floaff_tiny.yaml", "--config", MODEL, *quiet_trainer_args(out)]
    with pytest.raises(MisconfigurationException, match="does not exist"):
        main([*args, "--data.init_args.root", str(tmp_path / "no_data")])
    assert out.is_dir() and not list(out.iterdir())


def test_a_file_in_place_of_the_next_run_folder_is_named(tmp_path, root, monkeypatch):
    """Lightning counts only folders when it picks ``version_N``: a file named ``version_0`` in the model's folder
    ended the fit in a ``FileExistsError`` traceback from its setup hook. It is refused, the file left as it was."""
    monkeypatch.chdir(root)
    out = tmp_path / "runs"
    blocker = out / "tinypointnetmodule" / "version_0"
    blocker.parent.mkdir(parents=True)
    blocker.write_text("a user's notes")
    args = ["fit", "--config", DATA, "--config", MODEL, *quiet_trainer_args(out)]
    with pytest.raises(CLIError, match=f"run folder {blocker}: a file or link is in its place; move it away"):
        main(args)
    assert blocker.read_text() == "a user's notes"


class WritesThenFails(L.Callback):
    """Writes a file into its run's folder, then stops the fit (a run that failed after writing something)."""

    def setup(self, trainer, pl_module, stage) -> None:
        (Path(trainer.log_dir) / "notes.txt").write_text("written before the failure")
        raise MisconfigurationException("stopped after writing")


def test_a_failed_run_that_wrote_files_keeps_its_folder(tmp_path, root, monkeypatch):
    """The clean-up removes empty folders only: a fit that fails after writing into its folder keeps it."""
    monkeypatch.chdir(root)
    out = tmp_path / "runs"
    args = ["fit", "--config", DATA, "--config", MODEL, *quiet_trainer_args(out)]
    with pytest.raises(MisconfigurationException, match="stopped after writing"):
        main([*args, "--trainer.callbacks+=tests.test_cli_guards.WritesThenFails"])
    (notes,) = out.rglob("notes.txt")
    assert notes.read_text() == "written before the failure" and notes.parent.name == "version_0"


@pytest.mark.parametrize(
    ("flag", "value", "message"),
    [
        ("--trainer.val_check_interval", "0", r"trainer\.val_check_interval must be a fraction of an epoch"),
        (
            "--trainer.check_val_every_n_epoch",
            "0",
            r"trainer\.check_val_every_n_epoch must be an integer >= 1 or null \(validate by val_check_interval",
        ),
        ("--trainer.accumulate_grad_batches", "0", r"trainer\.accumulate_grad_batches must be an integer >= 1, got 0"),
        ("--ckpt_path", "hpc", r"--ckpt_path hpc: not supported by floaff-zoo"),
        ("--ckpt_path", "registry", r"--ckpt_path registry: not supported by floaff-zoo"),
    ],
)
def test_a_zero_schedule_value_or_an_unsupported_resume_keyword_is_one_line(
    tmp_path, root, monkeypatch, flag, value, message
):
    """0 for these trainer settings was a ZeroDivisionError mid-fit; --ckpt_path hpc|registry a traceback that left
    a run folder holding only its config.yaml."""
    monkeypatch.chdir(root)
    with pytest.raises(CLIError, match=message):
        main(_fit(tmp_path, flag, value))
    assert not list(tmp_path.rglob("config.yaml"))


def test_a_resumed_fits_config_neither_resumes_nor_pins_its_log_folder(tmp_path, root, monkeypatch):
    """A resumed fit's config.yaml kept ckpt_path (``test --config`` of it then tested that older checkpoint without
    --ckpt_path) and a pinned logger version (a resumed curriculum stage's: ``test --config`` logged into the fit's
    own folder and replaced its metrics.csv and config.yaml)."""
    import json

    import yaml

    monkeypatch.chdir(root)
    first = run_lightning(_fit(tmp_path))
    run = Path(first.trainer.log_dir)
    last = run / "checkpoints" / "last.ckpt"
    init = {"save_dir": str(tmp_path), "name": run.parent.name, "version": run.name}
    pinned = json.dumps({"class_path": "lightning.pytorch.loggers.CSVLogger", "init_args": init})
    resumed = run_lightning(
        _fit(tmp_path, "--trainer.max_epochs", "2", "--ckpt_path", str(last), "--trainer.logger", pinned)
    )
    assert Path(resumed.trainer.log_dir) == run  # resumed into its own folder, as the curriculum does
    saved = yaml.safe_load((run / "config.yaml").read_text())
    assert saved["ckpt_path"] is None and saved["trainer"]["logger"]["init_args"]["version"] is None
    rows = (run / "metrics.csv").read_text()
    with pytest.raises(CLIError, match="needs trained weights"):
        main(["test", "--config", str(run / "config.yaml"), *quiet_trainer_args(tmp_path)])
    test = run_lightning(["test", "--config", str(run / "config.yaml"), "--ckpt_path", "best"])
    assert Path(test.trainer.log_dir) != run and (run / "metrics.csv").read_text() == rows


def test_fit_last_resumes_the_run_its_config_came_from(tmp_path, root, monkeypatch):
    """``fit --config <run>/config.yaml --ckpt_path last`` trained from scratch: Lightning looked for 'last' in the
    new run's folder, found nothing, warned and started at epoch 0."""
    monkeypatch.chdir(root)
    first = run_lightning(_fit(tmp_path))
    run = Path(first.trainer.log_dir)
    again = run_lightning(
        ["fit", "--config", str(run / "config.yaml"), "--trainer.max_epochs", "2", "--ckpt_path", "last"]
    )
    assert again.trainer.global_step == 2 * first.trainer.global_step  # one more epoch on top of the first
    assert again.trainer.ckpt_path == str((run / "checkpoints" / "last.ckpt").resolve())
    # without a run's config, 'last' would be the newest run of the class under default_root_dir, maybe another
    # experiment's: refused
    with pytest.raises(CLIError, match="fit --ckpt_path last resumes the run a --config <run>/config.yaml came from"):
        main(_fit(tmp_path, "--ckpt_path", "last"))


def test_model_settings_of_a_config_file_that_the_checkpoint_replaces_are_named(tmp_path, root, monkeypatch, capsys):
    """With --ckpt_path the checkpoint's hyper-parameters replace the model config: a setting in a later --config
    file (an evaluation-time choice) was dropped without a word, while the same flag on the command line is kept."""
    monkeypatch.chdir(root)
    run = Path(run_lightning(_fit(tmp_path)).trainer.log_dir)
    extra = tmp_path / "eval.yaml"
    extra.write_text("model:\n  init_args:\n    train:\n      lr: 0.5\n")
    base = ["validate", "--config", str(run / "config.yaml"), "--config", str(extra), "--ckpt_path", "best"]
    capsys.readouterr()
    run_lightning(base)
    err = capsys.readouterr().err
    assert "the --config value(s) of model train are replaced by those of" in err, err
    inline = ["validate", "--config", str(run / "config.yaml"), "--config", extra.read_text(), "--ckpt_path", "best"]
    run_lightning(inline)  # the same setting as YAML text
    assert "the --config value(s) of model train are replaced by those of" in capsys.readouterr().err
    run_lightning([*base, "--model.init_args.train", '{"lr": 0.5}'])
    assert "the --config value(s) of model" not in capsys.readouterr().err
    run_lightning([*base, "--model.init_args.train.lr", "0.5"])  # a nested flag is applied again too: no note
    assert "the --config value(s) of model" not in capsys.readouterr().err
