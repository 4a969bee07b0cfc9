"""scripts/fixed_cell_ceiling.py: the ranking rule, the target-frame cells, and reading a dataset in the format."""

import math

import numpy as np
import pytest

from floaff_zoo.sim import fileformat as ff
from tests._scripts import load_script

fcc = load_script("fixed_cell_ceiling")

A, B, C = (5, 0), (6, 0), (4, 1)


def test_ranking_and_rule():
    train = [{A: True, B: True}, {A: True, B: False}, {B: True, C: False}]
    assert fcc.cell_ranking(train)[:3] == [A, B, C]  # A 2/2, B 2/3, C 0/1
    test = [{A: True}, {A: False, B: True}, {B: True}, {C: True}, {}]
    # standing on the best-ranked observed cell: A, A (fails), B, C, nothing (fails)
    assert fcc.rule_sr([A, B, C], test) == pytest.approx(3 / 5)
    assert fcc.rule_sr([B, C, A], test) == pytest.approx(4 / 5)


def test_a_single_cell_fails_where_the_view_does_not_observe_it():
    """The 'fixed cell' columns were a ranking with fallback to the next observed cell: two views seeing different
    successful cells scored 1.0, where one fixed cell scores 0.5."""
    views = [{A: True}, {B: True}]
    assert fcc.rule_sr(fcc.cell_ranking(views), views) == 1.0  # the ranking falls back to the observed cell
    assert fcc.best_single_cell(views) == A  # one success each: the lowest cell wins the tie
    assert fcc.single_cell_sr(fcc.best_single_cell(views), views) == 0.5
    assert fcc.single_cell_sr(B, [{A: True, B: True}, {A: True}, {B: False}]) == pytest.approx(1 / 3)


def test_canonical_cells_follow_the_target_frame():
    yaw, cell, target = 0.5, 0.1, np.array([1.0, 2.0, 0.9])
    grid = [(i, j) for i in range(-2, 3) for j in range(0, 4)]
    n = np.array([math.cos(yaw), math.sin(yaw)])
    lat = np.array([-n[1], n[0]])
    # target frame (x^o along lat, y^o = -distance along the front normal), as the generator defines it
    xy = [target[:2] + cell * (i * lat - j * n) for i, j in grid]
    scene = {"candidates": {"xy": np.array(xy).tolist(), "cell": cell}, "target": {"pos": target.tolist(), "yaw": yaw}}
    assert fcc.canonical_cells(scene) == grid


def _scene(root, task, split, k, success, views):
    sid = f"{task}-{split}{k}"
    d = ff.scene_dir(root, "layouts", sid)
    xy = [[0.1 * i, 0.0] for i in range(len(success))]
    files = []
    for v, idx in enumerate(views):
        m = len(idx)
        arrays = {
            "scene_xyz": np.zeros((4, 3), np.float32),
            "scene_feat": np.zeros((4, 4), np.float32),
            "floor_xyz": np.zeros((m, 3), np.float32),
            "floor_label": np.zeros(m, np.float32),
            "robot": np.array([0.85, 1.03], np.float32),
            "target_xyz": np.zeros(3, np.float32),
            "target_yaw": np.float32(0.0),
            "base_pose_world": np.zeros(3, np.float32),
            "floor_known": np.ones(m, bool),
            "floor_index": np.asarray(idx, np.int32),
        }
        ff.atomic_save_npz(d / "views" / f"front_{v:04d}.npz", arrays)
        files.append({"view_id": f"front_{v:04d}", "view": "front", "file": f"views/front_{v:04d}.npz"})
    ff.atomic_write_json(
        d / ff.SCENE_JSON,
        {
            "format_version": ff.FORMAT_VERSION,
            "benchmark": "layouts",
            "split": split,
            "scene_id": sid,
            "spec": {},
            "task": task,
            "target": {"pos": [0.0, 0.0, 0.9], "yaw": -math.pi / 2},
            "candidates": {"xy": xy, "cell": 0.1},
            "labels": {"success": success, "label": [float(s) for s in success]},
            "views": files,
            "status": "ok",
        },
    )
    return d


def test_reads_a_dataset_and_names_a_corrupt_view(tmp_path):
    _scene(tmp_path, "CloseDrawer", "train", 0, [0, 1, 0], [[0, 1], [1, 2]])
    _scene(tmp_path, "CloseDrawer", "train", 1, [0, 1, 1], [[1, 2]])
    test = _scene(tmp_path, "CloseDrawer", "test", 0, [1, 0, 1], [[0, 1], [1, 2], [2]])
    views, counts = fcc.read_views(tmp_path, "layouts")
    assert counts[("CloseDrawer", "train")] == [1, 2] and len(views[("CloseDrawer", "test")]) == 3
    rows = fcc.ceiling(views, counts)
    assert [r["task"] for r in rows] == ["CloseDrawer", "all"]
    # train ranks cell 1 first (3/3 views): it fails in the two test views that see it; the third sees only
    # cell 2, which succeeds; hindsight ranks cells 0 and 2 (2/2 each) first and wins every view
    assert rows[0]["train_ranking_test_sr"] == pytest.approx(1 / 3)
    assert rows[0]["hindsight_test_sr"] == pytest.approx(1.0)
    (test / "views" / "front_0001.npz").write_bytes(b"not a zip")
    with pytest.raises(ff.FormatError, match="front_0001.npz"):
        fcc.read_views(tmp_path, "layouts")


def test_an_unknown_benchmark_is_a_usage_error_naming_the_argument(tmp_path, capsys):
    """--benchmarks took any name and the reader's ValueError ended the script with a traceback."""
    with pytest.raises(SystemExit) as done:
        fcc.main(["--root", str(tmp_path), "--benchmarks", "layout"])
    assert done.value.code == 2 and "--benchmarks: invalid choice: 'layout'" in capsys.readouterr().err
    with pytest.raises(SystemExit) as done:  # merged into one table silently
        fcc.main(["--root", str(tmp_path), "--benchmarks", "layouts", "layouts"])
    assert done.value.code == 2 and "a benchmark is given twice: layouts" in capsys.readouterr().err


def test_a_task_without_train_or_test_scenes_is_said_and_no_task_is_an_error(tmp_path, capsys):
    """Such a task was dropped without a word; a root with test scenes only printed an empty table, exit 0."""
    _scene(tmp_path, "OpenSingleDoor", "test", 0, [1, 0, 1], [[0, 1]])
    with pytest.raises(SystemExit, match=r"fixed_cell_ceiling: no task under .*layouts has both train and test"):
        fcc.main(["--root", str(tmp_path), "--benchmarks", "layouts"])
    _scene(tmp_path, "CloseDrawer", "train", 0, [0, 1, 0], [[0, 1]])
    _scene(tmp_path, "CloseDrawer", "test", 0, [1, 1, 0], [[0, 1]])
    assert fcc.main(["--root", str(tmp_path), "--benchmarks", "layouts"]) == 0
    out = capsys.readouterr()
    assert "| layouts | CloseDrawer |" in out.out and "OpenSingleDoor" not in out.out
    assert "layouts: left out OpenSingleDoor (no train or no test scene)" in out.err
