"""scripts/predict_sr.py: SR of the predict API's default floor vs the dataset's floor points, on test views."""

import json
import re

import pytest

from tests._scripts import load_script

ps = load_script("predict_sr")


def test_a_benchmark_without_test_scenes_exits_naming_it(tmp_path, monkeypatch):
    """No test scene (a benchmark not generated, a typo) printed a table of nan and exited 0."""

    def never(model, where):
        raise AssertionError("the model was loaded before the data were checked")

    monkeypatch.setattr(ps, "floor_model", never)
    (tmp_path / "layouts").mkdir()
    with pytest.raises(SystemExit, match=r"no finished test scene under .*styles"):
        ps.main(["--root", str(tmp_path), "--benchmark", "styles", "--model", "m"])
    with pytest.raises(SystemExit) as exc:  # a typo: argparse names the choices
        ps.main(["--root", str(tmp_path), "--benchmark", "layout", "--model", "m"])
    assert exc.value.code == 2


def test_a_model_without_a_floor_map_exits_naming_it(tmp_path):
    """An AxisNet checkpoint reached predict_from_points, whose TypeError (or an earlier check's) was a traceback."""
    from tests.data.floaff_fixture import make_floaff_dataset
    from tests.test_val_sr import axisnet_ckpt

    make_floaff_dataset(tmp_path / "data", problems=False, version=2)
    ckpt = axisnet_ckpt(tmp_path / "axisnet.ckpt")
    match = rf"predict_sr: --model {re.escape(str(ckpt))}: .*AxisNetModule predicts no floor map"
    with pytest.raises(SystemExit, match=match):
        ps.main(["--root", str(tmp_path / "data"), "--benchmark", "layouts", "--model", str(ckpt)])


@pytest.mark.parametrize("cell", ["0", "-0.1", "nan", "inf"])
def test_a_cell_that_is_no_size_is_named(cell, tmp_path, capsys):
    """predict refused it with a ValueError traceback at the first view, after the model was loaded."""
    with pytest.raises(SystemExit) as exc:
        ps.main(["--root", str(tmp_path), "--model", "m", "--cell", cell])
    assert exc.value.code == 2 and "--cell: predict: cell must be a finite size > 0 m" in capsys.readouterr().err


def test_a_json_in_a_missing_folder_is_written(tmp_path, monkeypatch):
    """Path.write_text failed with a FileNotFoundError traceback after every rollout; the other scripts' writer makes
    the folder."""
    from types import SimpleNamespace

    import numpy as np

    from tests.data.floaff_fixture import make_floaff_dataset

    class Rollouts:  # every other job succeeds
        def run(self, jobs):
            return [SimpleNamespace(success=i % 2 == 0) for i in range(len(jobs))]

    make_floaff_dataset(tmp_path / "data", problems=False, version=2)
    monkeypatch.setattr(ps, "floor_model", lambda model, where: object())
    monkeypatch.setattr(ps, "predict_from_points", lambda *a, **k: SimpleNamespace(best_pose=np.zeros(3)))
    monkeypatch.setattr(ps, "RolloutService", Rollouts)
    out = tmp_path / "new" / "sr.json"
    assert ps.main(["--root", str(tmp_path / "data"), "--model", "m", "--json", str(out)]) == 0
    half = {"OpenSingleDoor": 0.5, "all": 0.5}  # 4 views of one task, every other one succeeds
    assert json.loads(out.read_text()) == {"default": half, "dataset": half}
