"""scripts/prior_cells.py: the prior filled from label-lattice views, scored with and without a small yaw error."""

import json

import numpy as np
import pytest

from tests._scripts import load_script

pc = load_script("prior_cells")


def _views(split: str, n: int) -> list:
    """n views of task 0 observing a 0.1 m lattice in front of the target; one cell succeeds, its row is labelled."""
    i, j = np.meshgrid(np.arange(-6, 7), np.arange(-15, 0), indexing="ij")
    xy = np.stack([i.ravel(), j.ravel()], -1) * 0.1
    best = (np.abs(xy[:, 0] - 0.3) < 1e-9) & (np.abs(xy[:, 1] + 1.2) < 1e-9)  # 1.2 m out, 0.3 m aside
    row = np.abs(xy[:, 1] + 1.2) < 1e-9
    label = np.where(best, 1.0, np.where(row, 0.9, 0.0)).astype(np.float32)
    return [(0, split, xy, label, best) for _ in range(n)]


def test_turn_is_a_rotation_about_the_target():
    xy = np.array([[1.0, 0.0], [0.0, -2.0]])
    out = pc.turn(xy, np.pi / 2)
    assert np.allclose(np.linalg.norm(out, axis=1), [1.0, 2.0])
    assert np.allclose(pc.turn(out, -np.pi / 2), xy)
    assert np.allclose(out, [[0.0, 1.0], [2.0, 0.0]])  # counter-clockwise, as a positive yaw turns


@pytest.mark.parametrize("noise", [0.0, 0.3])
def test_centred_prior_stands_on_the_labelled_best_cell(noise):
    views = _views("train", 3) + _views("test", 20)
    sr = pc.success_rates(pc.fit_grid(views, centred=True), views, "test", noise, seed=0)
    assert sr["PnPCounterToCab"] == 1.0 and sr["all"] == 1.0


def test_edge_binned_prior_loses_the_cell_under_a_small_yaw_error():
    views = _views("train", 3) + _views("test", 40)
    grid = pc.fit_grid(views, centred=False)
    # the lattice points sit on the cell edges: a 0.3 deg error moves some of them into the neighbouring cells
    assert pc.success_rates(grid, views, "test", 0.3, seed=0)["all"] < 1.0


def test_the_views_a_one_scene_task_holds_out_are_validation_views(tmp_path):
    """A task with one training scene gives some of its views to validation, listed as "<scene> (views)": a scene id
    test never matched them, so they filled the grid, no view scored as validation and the table's row crashed."""
    from floaff_zoo.data.floaff_kitchen import FloAffKitchenDataModule
    from tests.data.floaff_fixture import make_floaff_dataset

    make_floaff_dataset(tmp_path, problems=False, version=2)
    views = pc.read_views(tmp_path, "styles")
    dm = FloAffKitchenDataModule(root=str(tmp_path), tasks=["PnPCounterToCab"], val_scenes=1, cache=False)
    dm.setup("fit")
    assert any(s.endswith(" (views)") for s in dm.split_scenes["val"])  # the fixture's PnP has one training scene
    pnp = pc.TASKS.index("PnPCounterToCab")
    splits = [split for t, split, *_ in views if t == pnp]
    assert splits.count("val") == len(dm.datasets["val"]) > 0 and "train" in splits
    assert pc.main(["--root", str(tmp_path), "--benchmarks", "styles"]) == 0  # tasks without views print n/a


def test_an_unknown_benchmark_is_named_before_the_table(tmp_path, capsys):
    """A typo printed the table's header, then the DataModule's ValueError traceback."""
    with pytest.raises(SystemExit) as exc:
        pc.main(["--root", str(tmp_path), "--benchmarks", "layouts", "layout"])
    out = capsys.readouterr()
    assert exc.value.code == 2 and "--benchmarks: invalid choice: 'layout'" in out.err and "| Benchmark" not in out.out
    with pytest.raises(SystemExit) as exc:
        pc.main(["--root", str(tmp_path), "--seed", "-1"])
    out = capsys.readouterr()
    assert exc.value.code == 2 and "--seed must be >= 0, got -1" in out.err and "| Benchmark" not in out.out
    with pytest.raises(SystemExit) as exc:  # its rows were printed twice
        pc.main(["--root", str(tmp_path), "--benchmarks", "styles", "layouts", "styles"])
    out = capsys.readouterr()
    assert exc.value.code == 2 and "a benchmark is given twice: styles" in out.err and "| Benchmark" not in out.out


@pytest.mark.parametrize("noise", ["nan", "inf", "-1"])
def test_a_noise_that_is_no_standard_deviation_is_a_usage_error(noise, tmp_path, capsys):
    """NaN or Inf turned every query into NaN and printed an SR of 0.00 as that noise's result, exit 0."""
    with pytest.raises(SystemExit) as exc:
        pc.main(["--root", str(tmp_path), "--noise-deg", noise])
    out = capsys.readouterr()
    assert exc.value.code == 2 and "--noise-deg must be a finite standard deviation >= 0" in out.err
    assert "| Benchmark" not in out.out


def test_a_json_in_a_missing_folder_is_written(tmp_path):
    """Path.write_text failed with a FileNotFoundError traceback after the whole table; the other scripts' writer
    makes the folder."""
    from tests.data.floaff_fixture import make_floaff_dataset

    make_floaff_dataset(tmp_path / "data", problems=False, version=2)
    out = tmp_path / "new" / "rows.json"
    assert pc.main(["--root", str(tmp_path / "data"), "--benchmarks", "styles", "--json", str(out)]) == 0
    rows = json.loads(out.read_text())
    assert len(rows) == 8 and {r["benchmark"] for r in rows} == {"styles"}
