"""Quiet by default: the CLI hides known third-party noise and prints one line per stage; --verbose shows it all."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys

from floaff_zoo import quiet

#: lines Lightning prints around every fit; none of them may reach the user by default
LIGHTNING_NOISE = (
    "GPU available:",
    "TPU available:",
    "Tip: For seamless",
    "Seed set to",
    "Total estimated model params size",
    "is smaller than the logging interval",
)


def _run(args: list[str], cwd, verbose_env: bool = False) -> str:
    env = {k: v for k, v in os.environ.items() if k != quiet.VERBOSE_ENV}
    env["OMP_NUM_THREADS"] = "1"
    if verbose_env:
        env[quiet.VERBOSE_ENV] = "1"
    out = subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=cwd, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout + out.stderr


def test_fit_is_quiet_by_default_and_verbose_shows_everything(tmp_path, root):
    fit = [
        "-m",
        "floaff_zoo",
        "fit",
        "--config",
        "configs/data/synthetic_tiny.yaml",
        "--config",
        "configs/models/tiny_pointnet.yaml",
        "--trainer.max_epochs",
        "1",
        "--trainer.default_root_dir",
        str(tmp_path),
    ]
    out = _run(fit, root)
    assert not [n for n in LIGHTNING_NOISE if n in out], out[-3000:]
    assert "floaff-zoo fit: TinyPointNetModule" in out and "floaff-zoo fit: done after 1 epoch(s)" in out
    assert "Epoch 0" in out  # the progress bar stays

    loud = _run([*fit[:2], "--verbose", *fit[2:]], root)
    shown = [n for n in LIGHTNING_NOISE if n in loud]
    assert "GPU available:" in shown and "Seed set to" in shown, loud[-3000:]
    assert "floaff-zoo fit: done after 1 epoch(s)" in loud


def test_robosuite_import_notices_only_with_verbose(root):
    code = "from floaff_zoo.sim.robot import robot_xml; robot_xml()"
    out = _run(["-c", code], root)
    assert "No private macro file" not in out and "robosuite_models" not in out, out
    if importlib.util.find_spec("robosuite.macros_private") is None:  # robosuite prints them only then
        loud = _run(["-c", code], root, verbose_env=True)
        assert "No private macro file" in loud


def test_the_no_optimiser_warning_of_a_fit_without_parameters_is_dropped():
    """The canonical prior's fit makes Lightning warn that configure_optimizers returned None: noise, dropped."""
    import warnings

    import lightning.pytorch as pl
    from lightning.pytorch.core.optimizer import _init_optimizers_and_lr_schedulers

    class NoOptimiser(pl.LightningModule):
        def configure_optimizers(self) -> None:
            return None

    module = NoOptimiser()
    module.trainer = pl.Trainer(logger=False, enable_progress_bar=False, enable_checkpointing=False)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        quiet.quiet_lightning()
        _init_optimizers_and_lr_schedulers(module)  # where Lightning warns, with its own text
    assert not [str(w.message) for w in seen if "configure_optimizers" in str(w.message)]


def test_lightnings_own_verbose_option_of_test_keeps_its_value(tmp_path, root, monkeypatch, capsys):
    """``test --verbose false`` (Lightning's: print the results table or not) lost its flag to the zoo's --verbose
    and failed on 'unrecognized arguments: false'; a bare --verbose is still the zoo's."""
    import pytest
    import yaml

    from floaff_zoo.cli import _take_verbose, main

    monkeypatch.chdir(root)
    monkeypatch.delenv(quiet.VERBOSE_ENV, raising=False)
    base = ["test", "--config", "configs/data/synthetic_tiny.yaml", "--config", "configs/models/tiny_pointnet.yaml"]
    for value in ("false", "True"):
        with pytest.raises(SystemExit) as done:
            main([*base, "--verbose", value, "--trainer.default_root_dir", str(tmp_path), "--print_config"])
        assert done.value.code in (0, None)
        assert yaml.safe_load(capsys.readouterr().out)["verbose"] is (value == "True")
    assert not quiet.verbose()
    assert _take_verbose(["--verbose", "fit", "--config", "a.yaml"]) == (["fit", "--config", "a.yaml"], True)
    assert _take_verbose(["test", "--verbose", "false", "--verbose"]) == (["test", "--verbose", "false"], True)
