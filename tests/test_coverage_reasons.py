"""scripts/coverage_reasons.py: free cells binned by how much of their footprint the view shows, on a handmade scene."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from floaff_zoo.sim import fileformat as ff
from tests._scripts import load_script

cr = load_script("coverage_reasons")


def _scene(root: Path, cloud: np.ndarray) -> Path:
    """A target at the origin facing -y; cells 1 m in front at x = -1, 0, 1 and one behind its front; one view
    from a robot at the world origin (base frame = world) storing ``cloud``."""
    d = ff.scene_dir(root, "layouts", "s0")
    xy = [[-1.0, -1.0], [0.0, -1.0], [1.0, -1.0], [2.0, 0.5]]
    yaw = [math.atan2(-y, -x) for x, y in xy]  # facing the target
    arrays = {
        "scene_xyz": cloud.astype(np.float32),
        "scene_feat": np.zeros((len(cloud), 4), np.float32),
        "floor_xyz": np.zeros((1, 3), np.float32),
        "floor_label": np.zeros(1, np.float32),
        "robot": np.array([0.85, 1.03], np.float32),
        "target_xyz": np.zeros(3, np.float32),
        "target_yaw": np.float32(0.0),
        "base_pose_world": np.zeros(3, np.float32),
    }
    ff.atomic_save_npz(d / "views" / "front_0000.npz", arrays)
    ff.atomic_write_json(
        d / ff.SCENE_JSON,
        {
            "format_version": ff.FORMAT_VERSION,
            "benchmark": "layouts",
            "split": "train",
            "scene_id": "s0",
            "spec": {},
            "task": "CloseDrawer",
            "target": {"pos": [0.0, 0.0, 0.9], "yaw": -math.pi / 2},
            "candidates": {"xy": xy, "yaw": yaw, "cell": 0.1},
            "labels": {
                "success": [1, 0, 1, 0],
                "label": [1.0, 0.0, 1.0, 0.0],
                "reasons": ["success", "filtered_collision", "success", "filtered_collision"],
            },
            "views": [{"view_id": "front_0000", "view": "front", "file": "views/front_0000.npz"}],
            "status": "ok",
        },
    )
    return d


def test_free_cells_are_binned_by_the_footprint_the_view_shows(tmp_path, capsys):
    # floor seen densely around the cell at x = -1, nothing at x = 0, furniture on the cell at x = +1
    g = np.arange(-0.6, 0.61, 0.03)
    floor = np.array([[-1.0 + a, -1.0 + b, 0.0] for a in g for b in g])
    furniture = np.array([[1.0, -1.0, 0.5], [1.05, -1.0, 0.6]])
    _scene(tmp_path, np.concatenate([floor, furniture]))
    out = tmp_path / "out.json"
    assert cr.main(["--root", str(tmp_path), "--every", "1", "--json", str(out)]) == 0
    counts = {
        b: {k: v for k, v in c.items() if v}
        for b, c in json.loads(out.read_text())["counts"]["layouts/CloseDrawer"].items()
    }
    # the blocked cell and the one behind the target's front are not counted
    assert counts == {">=0.75": {"n": 1, "success": 1}, "<0.25": {"n": 1, "filtered_collision": 1}}
    assert "| layouts/CloseDrawer | <0.25 | 1 | 1.00 | 0.00 |" in capsys.readouterr().out
    assert [cr.coverage_bin(c) for c in (0.0, 0.25, 0.6, 1.0)] == ["<0.25", "<0.5", "<0.75", ">=0.75"]


def test_bad_input_exits_with_a_message(tmp_path):
    with pytest.raises(SystemExit, match="coverage_reasons: .*dataset root not found"):
        cr.main(["--root", str(tmp_path / "missing")])
    d = _scene(tmp_path, np.zeros((4, 3)))
    (d / "views" / "front_0000.npz").write_bytes(b"not a zip")
    with pytest.raises(SystemExit, match="front_0000.npz"):
        cr.main(["--root", str(tmp_path), "--every", "1"])


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda c: c.update(cell=float("nan")), r"candidates\.cell must be a finite number > 0"),
        (lambda c: c.update(cell=0), r"candidates\.cell must be a finite number > 0"),
        (lambda c: c["xy"].__setitem__(0, [float("nan"), -1.0]), r"candidates\.xy holds NaN"),
        (lambda c: c["xy"].__setitem__(0, [-1.0, -1.0, 0.0]), r"candidates\.xy must"),
    ],
)
def test_a_candidate_grid_that_is_no_grid_is_named(tmp_path, edit, match):
    """A NaN spacing or cell centre was read on (fixed_cell_ceiling cast NaN cell indices, the others binned or skipped
    the cell) and every script exited 0: the scene reader refuses it, naming the file."""
    d = _scene(tmp_path, np.zeros((4, 3)))
    rec = json.loads((d / ff.SCENE_JSON).read_text())
    edit(rec["candidates"])
    (d / ff.SCENE_JSON).write_text(json.dumps(rec))
    with pytest.raises(SystemExit, match=rf"scene\.json: {match}"):
        cr.main(["--root", str(tmp_path), "--every", "1"])


def test_scenes_without_a_free_cell_are_not_called_missing(tmp_path):
    """A root whose views block every cell in front of the target exited saying it has no finished train scene."""
    _scene(tmp_path, np.array([[x, -1.0, 0.5] for x in (-1.0, -0.95, 0.0, 0.05, 1.0, 1.05)]))
    with pytest.raises(SystemExit, match=r"no view of the 1 train scene\(s\) under .* shows a cell in front"):
        cr.main(["--root", str(tmp_path), "--every", "1"])
    with pytest.raises(SystemExit, match="coverage_reasons: no finished test scene under"):
        cr.main(["--root", str(tmp_path), "--split", "test"])
