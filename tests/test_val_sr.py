"""scripts/val_sr.py: rollout SR of several models on the validation scenes."""

import re
from pathlib import Path

import pytest
import torch

from tests._scripts import load_script

vs = load_script("val_sr")


def axisnet_ckpt(path: Path) -> Path:
    """An AxisNetModule checkpoint as LightningCLI writes it: a zoo model that predicts no floor map."""
    from floaff_zoo.models.axisnet import AxisNetModule

    net = AxisNetModule()
    hp = {**dict(net.hparams), "_class_path": "floaff_zoo.models.axisnet.AxisNetModule"}
    torch.save({"state_dict": net.state_dict(), "hyper_parameters": hp, "callbacks": {}, "epoch": 1}, path)
    return path


def test_a_model_without_a_floor_map_exits_naming_it(tmp_path):
    """An AxisNet checkpoint's output was read as floor scores: an IndexError in the pose choice, after the setup."""
    from tests.data.floaff_fixture import make_floaff_dataset

    make_floaff_dataset(tmp_path / "data", problems=False, version=2)
    ckpt = axisnet_ckpt(tmp_path / "axisnet.ckpt")
    with pytest.raises(SystemExit, match=rf"val_sr: {re.escape(str(ckpt))}: .*AxisNetModule predicts no floor map"):
        vs.main(["--root", str(tmp_path / "data"), "--benchmark", "styles", str(ckpt)])


@pytest.mark.parametrize("radius", ["0", "-1", "nan"])
def test_a_crop_radius_that_is_no_radius_is_named(radius, capsys):
    """TargetCrop refused it with a ValueError traceback, after the models were loaded."""
    with pytest.raises(SystemExit) as exc:
        vs.main(["--root", "nowhere", "m", "--crop-first", radius])
    assert exc.value.code == 2 and "--crop-first must be a radius > 0" in capsys.readouterr().err


def test_a_model_given_twice_is_named(capsys):
    """One row per model: `m m` was merged into one row, before anything told the user."""
    with pytest.raises(SystemExit) as exc:
        vs.main(["--root", "nowhere", "m", "n", "m"])
    assert exc.value.code == 2 and "a model is given twice: m" in capsys.readouterr().err
