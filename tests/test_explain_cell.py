"""scripts/explain_cell.py: a cell's verdict checked again filter by filter, and a rollout of a feasible cell."""

import json
from pathlib import Path

import numpy as np
import pytest

from floaff_zoo.sim.annotate import candidate_grid
from floaff_zoo.sim.kitchen import SceneSpec, build_scene
from floaff_zoo.sim.rollout import heading_to_target, pose_filter
from tests._scripts import load_script

ec = load_script("explain_cell")


@pytest.fixture(scope="module")
def record(tmp_path_factory) -> Path:
    """A scene.json of the unit-test double-door kitchen on the 0.1 m grid, every cell's reason written 'success'
    except one marked infeasible (the script re-checks; it does not trust the reasons)."""
    spec = SceneSpec(0, 0, 0, "CloseDoubleDoor")
    sc = build_scene(spec)
    xy, shape, _ = candidate_grid(sc, 0.1, *sc.task.candidate_region())
    xy = np.round(xy, 6)
    m = len(xy)
    reasons = ["success"] * m
    reasons[0] = "filtered_collision"
    rec = {
        "format_version": 2,
        "scene_id": spec.scene_id,
        "benchmark": "layouts",
        "split": "test",
        "task": spec.task,
        "spec": {"layout_id": 0, "style_id": 0, "seed": 0, "task": spec.task},
        "target": {"pos": sc.target.pos.tolist(), "yaw": float(sc.target.yaw)},
        "candidates": {
            "cell": 0.1,
            "grid_shape": list(shape),
            "xy": xy.tolist(),
            "yaw": [round(heading_to_target(sc, x, y), 6) for x, y in xy],
        },
        "labels": {"reasons": reasons, "label": [1.0] * m, "success": [1] * m},
        "views": [],
        "robot": [0.85, 1.03],
        "sigma": 1.0,
        "status": "ok",
    }
    d = tmp_path_factory.mktemp("scene")
    (d / "scene.json").write_text(json.dumps(rec))
    return d


def test_feasible_band_cell_rolls_out_to_success(record):
    scene = ec.ff.read_scene(record)
    i = ec.nearest_candidate(scene, 0.02, -0.68)  # snaps to the band cell (0, -0.7)
    assert np.allclose(ec.candidates_in_target_frame(scene)[i], [0.0, -0.7], atol=1e-6)
    out = dict(ec.explain(scene, i))
    assert out["verdict"] == "feasible" and out["tucked robot in the reset state"] == "ok"
    assert out["rollout"].startswith("success") and "door_pos_open" in out["rollout"]


def test_cells_the_filters_refuse_say_which_filter(record):
    scene = ec.ff.read_scene(record)
    behind = dict(ec.explain(scene, ec.nearest_candidate(scene, 0.0, 0.3)))
    assert behind["front plane"].startswith("REFUSED") and behind["verdict"] == "filtered_collision"
    assert "rollout" not in behind
    far = dict(ec.explain(scene, ec.nearest_candidate(scene, 1.0, -1.2)))
    assert far["verdict"] == "filtered_reach"  # 1.56 m from the target, the task's reach is 1.25 m


def test_reason_map_and_errors(record, capsys):
    scene = ec.ff.read_scene(record)
    rows = ec.reason_map(scene)
    h, w = scene["candidates"]["grid_shape"]
    assert len(rows) == (h - 1) // 2 and all(len(r) == w for r in rows)  # only rows in front of the target
    assert rows[0][0] == "#" and set("".join(rows)) == {"#", "O"}
    front = next(i for i, yo in enumerate(ec.candidates_in_target_frame(scene)[:, 1]) if yo < -1e-6)
    scene["labels"]["reasons"][front] = "skipped_budget"  # a budgeted preset's cell, never rolled out
    assert "-" in "".join(ec.reason_map(scene)) and "c" not in "".join(ec.reason_map(scene))
    with pytest.raises(ValueError, match="no candidate cell near"):
        ec.nearest_candidate(scene, 5.0, -5.0)
    with pytest.raises(SystemExit, match="explain_cell: .*missing"):
        ec.main([str(record.parent / "missing"), "--grid"])
    assert ec.main([str(record), "--grid"]) == 0
    assert "|#" in capsys.readouterr().out


def test_step_by_step_verdict_agrees_with_the_annotation_filter(record):
    """explain_cell re-runs the filters one at a time; its verdict must stay the one ``pose_filter`` gives."""
    scene = ec.ff.read_scene(record)
    sim = build_scene(SceneSpec.from_dict(scene["spec"]))
    for xo, yo in ((0.0, -0.7), (0.0, 0.3), (1.0, -1.2), (-0.9, -0.1), (0.5, -0.4)):
        i = ec.nearest_candidate(scene, xo, yo)
        x, y = scene["candidates"]["xy"][i]
        yaw = scene["candidates"]["yaw"][i]
        steps = dict(ec.check_pose(sim, x, y, yaw, 0))
        assert steps["verdict"] == (pose_filter(sim, x, y, yaw, 0) or "feasible"), (xo, yo, steps)


def test_a_negative_seed_is_a_usage_error(record, capsys):
    """--seed -1 reached numpy's generator after the map was printed and ended the script with a ValueError
    traceback."""
    with pytest.raises(SystemExit) as done:
        ec.main([str(record), "--cell", "0,-0.7", "--seed", "-1"])
    assert done.value.code == 2 and "--seed must be >= 0, got -1" in capsys.readouterr().err


@pytest.mark.parametrize("cell", ["nan,0", "0,inf"])
def test_a_cell_that_is_no_point_is_a_usage_error(cell, capsys):
    """NaN is nearest to no cell: the argmin took cell #0, explained it and exited 0."""
    with pytest.raises(SystemExit) as done:
        ec.main(["any_scene", "--cell", cell])
    assert done.value.code == 2 and f"finite metres (target frame), got '{cell}'" in capsys.readouterr().err
