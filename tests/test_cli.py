"""The CLI through its real entry points, on the synthetic tiny data."""

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from floaff_zoo.cli import CLIError, main, run_lightning
from tests.conftest import console, quiet_trainer_args

DATA = "configs/data/synthetic_tiny.yaml"
MODEL = "configs/models/tiny_pointnet.yaml"


def test_help_lists_subcommands(monkeypatch, capsys):
    rc, out, _ = console(monkeypatch, capsys, ["--help"])
    assert rc == 0
    # the command lists: lines indented by two spaces, the command first ("fit" also appears in prose lines)
    listed = {line.split()[0] for line in out.splitlines() if line.startswith("  ") and line[2:3].isalpha()}
    assert {"fit", "validate", "test", "predict", "generate", "curriculum", "table", "hub"} <= listed, out
    assert console(monkeypatch, capsys, ["--version"])[:2] == (0, "0.1.0\n")


def test_fit_help_titles_the_model_and_data_groups_for_users(root, monkeypatch, capsys):
    """The --model and --data groups of ``fit --help`` were titled by the base classes' first docstring lines, which
    spoke to developers ("Shared machinery: ``setup`` fills ``self.datasets[split]``...")."""
    monkeypatch.chdir(root)
    with pytest.raises(SystemExit) as done:  # argparse's --help exits 0 after printing
        console(monkeypatch, capsys, ["fit", "--help"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    titles = [line for line in out.splitlines() if line.endswith(":") and not line.startswith(" ")]
    assert "The model: any model of the zoo; --model.help CLASS lists one's arguments:" in titles, titles
    assert "The data: any data module of the zoo; --data.help CLASS lists one's arguments:" in titles, titles


def test_fit_test_predict_round_trip(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    base = ["--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path)]
    cli = run_lightning(["fit", *base, "--trainer.max_epochs", "2"])
    ckpt = cli.trainer.checkpoint_callback.best_model_path
    assert Path(ckpt).is_file()
    # last.ckpt is the final state whichever epoch was the best (LatestCheckpoint, tests/test_checkpoint.py)
    last = torch.load(Path(ckpt).parent / "last.ckpt", map_location="cpu", weights_only=True)
    assert last["global_step"] == cli.trainer.global_step
    assert "val_rmse" in cli.trainer.callback_metrics
    state = torch.load(ckpt, map_location="cpu", weights_only=True)  # primitives only
    assert state["hyper_parameters"]["width"] == 32
    # the saved config can be rerun and 'best' resolves in the run dir
    cli_t = run_lightning(["test", *base, "--ckpt_path", "best"])
    res = cli_t.trainer.callback_metrics
    for k in ("test_rmse", "test_logmse", "test_pcc", "test_sim"):
        assert k in res and torch.isfinite(res[k])
    cli_p = run_lightning(["predict", *base, "--ckpt_path", ckpt])
    preds = cli_p.trainer.predict_loop.predictions
    assert preds and preds[0]["scores"].shape[0] == 2
    assert ((preds[0]["scores"] >= 0) & (preds[0]["scores"] <= 1)).all()
    # what predict computed is in the run's folder (Lightning kept it in memory only): every sample, in order
    run_dir = Path(cli_p.trainer.log_dir)
    saved = np.load(run_dir / "predictions.npz")
    index = json.loads((run_dir / "predictions.json").read_text())
    n = sum(len(p["scores"]) for p in preds)
    assert saved["scores"].shape[0] == n == index["n"] == len(index["meta"])
    assert index["arrays"]["scores"] == list(saved["scores"].shape)
    mask = saved["floor_mask"]
    first = preds[0]["scores"].numpy()
    np.testing.assert_array_equal(
        saved["scores"][: len(first), : first.shape[1]][mask[: len(first), : first.shape[1]]],
        first[preds[0]["floor_mask"].numpy()],
    )
    assert np.isnan(saved["scores"][~mask]).all() and index["meta"][0] == preds[0]["meta"][0]
    # a newer run in the same root: `--config <first run>/config.yaml --ckpt_path best` still picks the first run's
    run_lightning(["fit", *base, "--trainer.max_epochs", "1", "--model.init_args.width", "16"])
    first_cfg = Path(ckpt).parents[1] / "config.yaml"
    cli_r = run_lightning(["test", "--config", str(first_cfg), *quiet_trainer_args(tmp_path), "--ckpt_path", "best"])
    assert Path(cli_r.config_init["test"]["ckpt_path"]).resolve() == Path(ckpt).resolve()
    # same checkpoint loads outside the CLI
    from floaff_zoo.models.tiny import TinyPointNetModule

    m = TinyPointNetModule.load_from_checkpoint(ckpt, weights_only=True)
    assert m.hparams.width == 32


def test_command_line_model_args_beat_checkpoint_hparams(tmp_path, root, monkeypatch):
    """With --ckpt_path <file> Lightning takes the model config from the checkpoint; explicit evaluation-time
    overrides on the command line must still apply (they used to be dropped silently)."""
    monkeypatch.chdir(root)
    base = ["--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path)]
    cli = run_lightning(["fit", *base, "--trainer.max_epochs", "1", "--model.init_args.width", "16"])
    ckpt = cli.trainer.checkpoint_callback.best_model_path
    plain = run_lightning(
        ["test", "--config", DATA, *quiet_trainer_args(tmp_path), "--model", "TinyPointNetModule", "--ckpt_path", ckpt]
    )
    assert plain.model.hparams.width == 16 and plain.model.train_cfg.sim_variant == "cosine"  # from the checkpoint
    over = run_lightning(
        [
            "test",
            "--config",
            DATA,
            *quiet_trainer_args(tmp_path),
            "--model",
            "TinyPointNetModule",
            "--ckpt_path",
            ckpt,
            "--model.init_args.train.sim_variant=hist",
        ]
    )
    assert over.model.hparams.width == 16 and over.model.train_cfg.sim_variant == "hist"
    assert over.model.train_cfg.lr == 0.003  # the rest of the train group still comes from the checkpoint


def test_test_without_checkpoint_refuses(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    with pytest.raises(CLIError, match="needs trained weights"):
        main(["test", "--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path)])


@pytest.mark.parametrize(
    "bad, named",
    [
        (["--model.init_args.widht", "8"], "Option 'widht' is not accepted"),
        (["--trainer.max_epoch", "3"], "unrecognized arguments: --trainer.max_epoch 3"),
        (["--model", "NoSuchModule"], "NoSuchModule"),
    ],
)
def test_a_config_typo_is_one_line_naming_the_field(tmp_path, root, monkeypatch, capsys, bad, named):
    """jsonargparse printed a 50-line usage of the whole trainer before the line that names the field."""
    monkeypatch.chdir(root)
    args = ["fit", "--config", DATA, "--config", MODEL, *bad, *quiet_trainer_args(tmp_path)]
    with pytest.raises(CLIError, match=re.escape(named)) as err:
        main(args)
    assert "\n" not in str(err.value) and "`floaff-zoo fit --help` lists the options" in str(err.value)
    assert "usage:" not in capsys.readouterr().err
    rc, _, lines = console(monkeypatch, capsys, args)  # at the console: printed, exit 2
    assert rc == 2 and len(lines) == 1 and named in lines[0], lines


@pytest.mark.parametrize(
    "text, named",
    [
        (
            "model:\n  init_args:\n    widht: 8\n",
            "(did you mean 'width' or 'weights'?; model.init_args.widht is set in {f})",
        ),
        (
            "model:\n  init_args:\n    train:\n      lrr: 0.1\n",
            "(did you mean 'lr'?; model.init_args.train.lrr is set in {f})",
        ),
        (
            "trainer:\n  max_epoch: 3\n",
            "(did you mean 'max_epochs' or 'min_epochs' or 'max_steps'?; trainer.max_epoch is set in {f})",
        ),
        ("data:\n  init_args:\n    batchsize: 2\n", "did you mean 'batch_size' or 'eval_batch_size'?"),
        # a key the model config sets rightly, set under data by mistake: only the file that misplaced it is named
        ("data:\n  init_args:\n    width: 8\n", "(data.init_args.width is set in {f})"),
        ("data: {init_args: {width: 8}}\n", "(data.init_args.width is set in {f})"),  # flow style too
    ],
)
def test_a_config_file_typo_names_close_keys_and_the_file(tmp_path, root, monkeypatch, text, named):
    """The parser names an unknown key but neither the file among several ``--config`` files that set it nor the
    key meant; a model's, its ``train`` group's, the trainer's and the data module's keys each get both."""
    monkeypatch.chdir(root)
    typo = tmp_path / "typo.yaml"
    typo.write_text(text)
    with pytest.raises(CLIError, match=re.escape(named.format(f=typo))):
        main(["fit", "--config", DATA, "--config", MODEL, "--config", str(typo), *quiet_trainer_args(tmp_path)])


@pytest.mark.parametrize(
    "command, text, field",
    [
        ("fit", 'trainer:\n  max_epochs: "x"\n', "trainer.max_epochs"),
        ("test", 'trainer:\n  max_epochs: "x"\n', "trainer.max_epochs"),
        ("fit", "model:\n  init_args:\n    train:\n      lr: notanumber\n", "model.init_args.train.lr"),
        ("predict", "data:\n  init_args:\n    batch_size: x\n", "data.init_args.batch_size"),
    ],
)
def test_a_wrong_type_in_a_config_file_names_the_field_and_the_file(
    tmp_path, root, monkeypatch, capsys, command, text, field
):
    """A value of the wrong type is one line (exit 2, no usage) naming the key; among several ``--config`` files
    jsonargparse did not say which one set it."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    args = [command, "--config", DATA, "--config", MODEL, "--config", str(bad), *quiet_trainer_args(tmp_path)]
    monkeypatch.chdir(root)
    rc, _, lines = console(monkeypatch, capsys, args)
    err = "\n".join(lines)
    assert rc == 2 and "usage:" not in err and len(lines) == 1, err
    assert f"({field} is set in {bad}) (`floaff-zoo {command} --help` lists the options)" in err, err


def test_a_wrong_type_on_the_command_line_names_the_field_and_no_file(tmp_path, root, monkeypatch, capsys):
    """The refused value came from a flag: a file setting the same key to a good value is not named."""
    good = tmp_path / "good.yaml"
    good.write_text("trainer:\n  max_epochs: 3\n")
    args = ["fit", "--config", DATA, "--config", MODEL, "--config", str(good), "--trainer.max_epochs", "abc"]
    monkeypatch.chdir(root)
    rc, _, lines = console(monkeypatch, capsys, args)
    err = "\n".join(lines)
    assert rc == 2 and "usage:" not in err and len(lines) == 1, err
    assert 'Parser key "trainer.max_epochs"' in err and "is set in" not in err, err


def test_a_flag_typo_names_close_keys_and_no_file(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    with pytest.raises(CLIError, match=r"\(did you mean 'width' or 'weights'\?\) \(`floaff-zoo fit --help`"):
        main(
            ["fit", "--config", DATA, "--config", MODEL, "--model.init_args.widht", "8", *quiet_trainer_args(tmp_path)]
        )


def test_unknown_command():
    with pytest.raises(CLIError, match="unknown command"):
        main(["fitt"])


def test_robot_dim_mismatch_is_clear(tmp_path, root, monkeypatch):
    monkeypatch.chdir(root)
    from floaff_zoo.contract import SampleError

    with pytest.raises(SampleError, match="robot_dim"):
        main(
            [
                "fit",
                "--config",
                DATA,
                "--config",
                MODEL,
                "--model.init_args.robot_dim",
                "3",
                "--trainer.fast_dev_run",
                "1",
                *quiet_trainer_args(tmp_path),
            ]
        )


def test_a_batch_limit_of_1_is_one_batch(tmp_path, root, monkeypatch):
    """Lightning types limit_*_batches float-first, so `--trainer.limit_train_batches 1` was read as 1.0, a
    fraction: every batch ran. An integer literal now means that many batches; 1.0 still means all of them."""
    monkeypatch.chdir(root)
    base = ["fit", "--config", DATA, "--config", MODEL, *quiet_trainer_args(tmp_path), "--trainer.max_epochs", "1"]
    one = run_lightning([*base, "--trainer.limit_train_batches", "1", "--trainer.limit_val_batches=1"])
    assert one.trainer.global_step == 1 and one.trainer.num_val_batches == [1]
    saved = Path(one.trainer.log_dir) / "config.yaml"  # the run's own config keeps the integer (it said 1.0)
    limits = yaml.safe_load(saved.read_text())["trainer"]
    assert (limits["limit_train_batches"], limits["limit_val_batches"]) == (1, 1)
    assert type(limits["limit_train_batches"]) is int and limits["limit_test_batches"] is None
    again = ["fit", "--config", str(saved), "--trainer.default_root_dir", str(tmp_path / "again")]
    assert run_lightning(again).trainer.global_step == 1
    every = run_lightning([*base, "--trainer.limit_train_batches", "1.0"])
    assert every.trainer.global_step == every.trainer.num_training_batches > 1
    cfg = tmp_path / "one_batch.yaml"
    cfg.write_text("trainer:\n  limit_train_batches: 1\n")  # a config file's int means one batch too
    assert run_lightning([*base, "--config", str(cfg)]).trainer.global_step == 1
    assert run_lightning([*base, f"--config={cfg}"]).trainer.global_step == 1  # the '=' spelling too
    # --config also takes YAML text, which was never read here: its 1 ran every batch
    inline = run_lightning([*base, "--config", "{trainer: {limit_train_batches: 1, limit_val_batches: 1}}"])
    assert inline.trainer.global_step == 1 and inline.trainer.num_val_batches == [1]


def test_integer_limits_follow_the_parsers_order(tmp_path):
    """The last of the command line and the --config files decides; a YAML int counts as an integer."""
    from floaff_zoo.cli import integer_limits

    cfg = tmp_path / "limits.yaml"
    cfg.write_text("trainer:\n  limit_val_batches: 1\n  limit_test_batches: 0.5\n  limit_train_batches: 1.0\n")
    assert integer_limits(["--trainer.limit_val_batches=2", "--config", str(cfg)]) == {"val": 1}
    args = ["--config", str(cfg), "--trainer.limit_val_batches", "1.0", "--trainer.limit_test_batches=3"]
    assert integer_limits(args) == {"test": 3}
    assert integer_limits(["--config", str(tmp_path / "missing.yaml"), "--trainer.limit_predict_batches", "1"]) == {
        "predict": 1
    }
    assert integer_limits(["--config", "trainer:\n  limit_val_batches: 2\n"]) == {"val": 2}  # YAML text
    assert integer_limits(["--config", "x" * 5000]) == {}  # no path (too long for one): text that is no mapping


def test_only_a_non_finite_model_output_is_a_one_line_error(monkeypatch, capsys):
    """Every FloatingPointError printed as a user error without a traceback, a bug's (numpy's) too: only the zoo's
    NonFiniteError (a diverged loss, NaN scores) is one line now."""
    from floaff_zoo import cli
    from floaff_zoo.contract import NonFiniteError

    for exc, one_line in (
        (NonFiniteError("train loss is nan on samples ['s0']"), True),
        (FloatingPointError("x"), False),
    ):

        def boom(args, exc=exc):
            raise exc

        monkeypatch.setattr(cli, "run_lightning", boom)
        monkeypatch.setattr(sys, "argv", ["floaff-zoo", "fit"])
        if one_line:
            assert cli.main() == 2 and "train loss is nan" in capsys.readouterr().err
        else:
            with pytest.raises(FloatingPointError):
                cli.main()
