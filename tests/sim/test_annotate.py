import numpy as np
import pytest

from floaff_zoo.sim.annotate import FILTERED, ROLLED_OUT, SKIPPED, annotate_scene, probability_label
from floaff_zoo.sim.rollout import heading_to_target, rollout
from floaff_zoo.sim.tasks import target_frame, target_frame_to_world


def test_determinism_and_filtering(scene_factory):
    sc = scene_factory("CloseDrawer")
    a = annotate_scene(sc, cell=0.2)
    b = annotate_scene(sc, cell=0.2)
    assert a.label.tobytes() == b.label.tobytes()
    assert a.success.tobytes() == b.success.tobytes()
    H, W = a.grid_shape
    assert a.grid_xy.shape == (H * W, 2) and a.label.dtype == np.float32
    # candidates inside furniture never reach a rollout
    for i, (x, y) in enumerate(a.grid_xy):
        if not sc.footprint_free(x, y, a.yaw[i]):
            assert a.reasons[i] in ("filtered_collision", "filtered_reach")
            assert not a.valid[i] and not a.success[i]
    # cells behind the target's front plane (inside furniture / behind the wall) are filtered, never rolled out
    xo = target_frame(sc.target, a.grid_xy)
    behind = xo[:, 1] > 1e-6
    assert behind.any()
    assert all(a.reasons[i] in ("filtered_collision", "filtered_reach") for i in np.flatnonzero(behind))
    c = a.counts
    assert c["candidates"] == H * W
    assert (
        c["filtered_collision"] + c["filtered_reach"] + c["prefiltered_ik"] + c["rolled_out"] + c["skipped_budget"]
        == H * W
    )
    assert c["filtered_collision"] > 0
    assert a.label.max() == pytest.approx(1.0) if a.success.any() else a.label.max() == 0.0
    _check_status(a)


def _check_status(a) -> None:
    """Per-cell status: rolled out = the rollouts, skipped = over the budget, filtered = the rest (never successful)."""
    c = a.counts
    assert a.status.shape == a.label.shape and set(np.unique(a.status)) <= {FILTERED, ROLLED_OUT, SKIPPED}
    assert (a.status == ROLLED_OUT).sum() == c["rolled_out"] and (a.status == SKIPPED).sum() == c["skipped_budget"]
    assert not a.success[a.status != ROLLED_OUT].any()
    assert all(r == "skipped_budget" for r in np.asarray(a.reasons)[a.status == SKIPPED])


@pytest.mark.parametrize(
    "task,cell,budget",
    [
        ("CloseDrawer", 0.15, None),
        ("OpenSingleDoor", 0.15, 16),
        ("PnPCounterToCab", 0.2, 10),
    ],
)
def test_positive_and_negative(scene_factory, task, cell, budget):
    sc = scene_factory(task)
    a = annotate_scene(sc, cell=cell, max_candidates=budget)
    _check_status(a)
    assert a.counts["positives"] >= 1, a.counts
    assert (~a.success).sum() >= 1
    assert a.label.max() == pytest.approx(1.0)


def _dd_map(sc):
    a = annotate_scene(sc, cell=0.1)
    assert a.counts["positives"] >= 1, a.counts
    failed_rollouts = [
        r for r in a.reasons if r not in ("success", "filtered_collision", "filtered_reach", "ik_unreachable")
    ]
    assert len(failed_rollouts) >= 1, a.counts
    assert a.label.max() == pytest.approx(1.0)


def test_close_double_door_map(scene_factory):
    _dd_map(scene_factory("CloseDoubleDoor"))


@pytest.mark.slow
def test_close_double_door_map_other_scene(scene_factory):
    _dd_map(scene_factory("CloseDoubleDoor", layout=2, style=3, seed=1))


def _pose(sc, xo: float, yo: float) -> tuple[float, float, float]:
    """Base pose at target-frame (x°, y°), facing the target, rounded as the annotation rounds it."""
    p = target_frame_to_world(sc.target, np.array([xo, yo]))
    return (round(float(p[0]), 6), round(float(p[1]), 6), round(heading_to_target(sc, *p), 6))


def test_close_double_door_poses(scene_factory):
    """Centred 0.6 m in front both doors get swept shut; 0.8 m in front the arm cannot finish the second door."""
    sc = scene_factory("CloseDoubleDoor")
    ok = rollout(sc, _pose(sc, 0.0, -0.6))
    assert ok.success and max(ok.state.values()) <= 0.05, ok
    bad = rollout(sc, _pose(sc, 0.0, -0.8))
    assert not bad.success and bad.reason != "ik_unreachable", bad


def test_close_double_door_band(scene_factory):
    """The tilted push shuts both doors from a band of poses 0.7 m in front, on both sides of the centre.

    Generator 2.0 pushed with the fingers pointing down and the hand above the door; the hand met the cabinet top
    as the door closed, and this scene had one successful cell on the 0.1 m grid (0.6 m in front, centred).
    """
    sc = scene_factory("CloseDoubleDoor")
    for xo in (-0.2, -0.1, 0.0, 0.1, 0.2):
        r = rollout(sc, _pose(sc, xo, -0.7))
        assert r.success and max(r.state.values()) <= 0.05, (xo, r)


def test_probability_label_smooths_rates_like_the_binary_map():
    shape = (3, 4)
    prob = np.zeros(12)
    prob[0], prob[5], prob[6] = 0.8, 1.0, 0.5  # cell 0 is filtered: its rate must not survive
    status = np.full(12, ROLLED_OUT)
    status[0] = FILTERED
    lab = probability_label(prob, status, shape, sigma_cells=0.0)
    assert lab.dtype == np.float32 and lab.shape == (12,)
    assert lab[5] == 1.0 and lab[6] == pytest.approx(0.5) and lab[0] == 0.0  # max-normalised, filtered cell 0
    smooth = probability_label(prob, status, shape, sigma_cells=1.0)
    assert smooth.max() == pytest.approx(1.0) and 0 < smooth[1] < 1  # spread to the neighbours
    half = probability_label(prob * 0.5, status, shape, sigma_cells=1.0)
    assert half == pytest.approx(smooth)  # rates are relative: the map is normalised to its peak
    with pytest.raises(ValueError, match=r"need 12 .*grid \(3, 4\), got 11"):
        probability_label(prob[:11], status[:11], shape)
    bad = prob.copy()
    bad[2] = 1.5
    with pytest.raises(ValueError, match=r"0 not finite, range \[0, 1.5\]"):
        probability_label(bad, status, shape)
    bad[2] = np.nan
    with pytest.raises(ValueError, match="1 not finite"):
        probability_label(bad, status, shape)
    skipped = status.copy()
    skipped[3] = SKIPPED  # a status of another length failed in the smoothing's reshape, naming neither argument
    with pytest.raises(ValueError, match=r"status has 13 cells, prob has 12 \(grid \(3, 4\)\)"):
        probability_label(prob, np.append(skipped, ROLLED_OUT), shape)


def test_a_reach_other_than_the_tasks_is_refused(scene_factory):
    """A preset's r_arm labelled cells by another reach than the evaluation's pose filter (and than pool workers',
    which filter by the task's): labels and rollouts from a chosen pose disagreed."""
    sc = scene_factory("CloseDrawer")
    with pytest.raises(ValueError, match=r"r_arm=1\.9 differs from the CloseDrawer task's reach"):
        annotate_scene(sc, cell=0.2, r_arm=1.9)


def test_cells_skipped_for_the_budget_do_not_count_as_failures_in_the_smoothing():
    """With max_candidates, the cells over the budget entered the smoothing as failures: beside them the labels of
    rolled-out (known) cells dropped, by up to 0.28 in an OpenSingleDoor scene at a cap of 24."""
    from floaff_zoo.sim.annotate import _smooth

    shape = (7, 9)
    rng = np.random.default_rng(0)
    known = rng.random(63) > 0.4
    every = np.ones(63)  # every cell would succeed: the capped map must read success wherever it is known
    capped, full = _smooth(every * known, shape, 1.0, known), _smooth(every, shape, 1.0)
    assert np.allclose(capped[known], full[known], atol=1e-6)
    values = rng.random(63)  # and a scene without skipped cells keeps its map exactly
    assert np.array_equal(_smooth(values, shape, 1.0, np.ones(63, bool)), _smooth(values, shape, 1.0))


@pytest.mark.parametrize(("cell", "shown"), [(True, "True"), (float("nan"), "nan"), (0.0, "0.0"), ("0.1", "'0.1'")])
def test_a_cell_that_is_no_size_is_refused_by_name(cell, shown):
    """True was a cell of 1 m; a text met the comparison as a TypeError naming nothing."""
    from floaff_zoo.sim.annotate import candidate_grid

    with pytest.raises(ValueError, match=rf"candidate_grid: cell must be a finite number > 0, got {shown}"):
        candidate_grid(None, cell, 1.0, 1.0)  # refused before the scene is read


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"sigma_cells": float("nan")}, r"sigma_cells must be a finite number >= 0 \(0 = no smoothing\), got nan"),
        ({"sigma_cells": -1.0}, r"sigma_cells must be a finite number >= 0 \(0 = no smoothing\), got -1.0"),
        ({"max_candidates": -1}, r"max_candidates must be an integer >= 1 or null \(no cap\), got -1"),
        ({"max_candidates": 2.5}, r"max_candidates must be an integer >= 1 or null \(no cap\), got 2.5"),
        ({"max_candidates": True}, r"max_candidates must be an integer >= 1 or null \(no cap\), got True"),
        ({"seed": 1.5}, "seed must be an integer >= 0, got 1.5"),
        ({"workers": 1.5}, "workers must be an integer >= 0, got 1.5"),
    ],
)
def test_annotation_settings_out_of_range_are_refused_by_name_before_any_rollout(kwargs, message):
    """A NaN or negative sigma left the labels unsmoothed without a word; a negative or fractional budget failed in
    np.linspace after every filter had run, True was a budget of one rollout; a float seed failed in the first reset
    with numpy's SeedSequence message; 1.5 workers started a rollout pool."""
    with pytest.raises(ValueError, match=f"annotate_scene: {message}"):
        annotate_scene(None, cell=0.2, **kwargs)  # refused before the scene is read
    if "sigma_cells" in kwargs:
        with pytest.raises(ValueError, match=f"probability_label: {message}"):
            probability_label(np.ones(4), np.full(4, ROLLED_OUT), (2, 2), kwargs["sigma_cells"])


def test_one_rollout_with_workers_runs_on_the_given_scene(scene_factory, monkeypatch):
    """With one job the service ran it in this process on a kitchen it built again, not the scene it was given."""
    import floaff_zoo.sim.annotate as annotate

    class NoService:
        def __init__(self, *args, **kwargs):
            raise AssertionError("a rollout service started for one job")

    sc = scene_factory("CloseDrawer")
    one = annotate_scene(sc, cell=0.2, max_candidates=1)
    monkeypatch.setattr(annotate, "RolloutService", NoService)
    again = annotate_scene(sc, cell=0.2, max_candidates=1, workers=2)
    assert again.counts["rolled_out"] == 1 and again.success.tobytes() == one.success.tobytes()


def test_candidate_grid_counts_cells_up_to_the_region_edge_in_the_target_frame():
    """|x°| <= r_x and |y°| <= r_y on the cell lattice, row-major (y°, x°); a region that is a whole number of cells
    keeps its edge cell though r / cell falls just below it in floating point (1.2 / 0.05 = 23.999999999999996:
    the default region lost its outer rows and labels moved by a row)."""
    from types import SimpleNamespace

    from floaff_zoo.sim.annotate import candidate_grid
    from floaff_zoo.sim.tasks import TargetInfo

    scene = SimpleNamespace(target=TargetInfo(np.zeros(3), 0.0, "drawer", [], np.zeros(0, np.int64), []))
    xy, shape, xo = candidate_grid(scene, 0.2, 0.5, 0.6)  # 0.5 / 0.2 = 2.5 -> 2; 0.6 / 0.2 = 2.9999999999999996 -> 3
    assert shape == (7, 5) and xo.shape == (35, 2)
    assert xo[0] == pytest.approx([-0.4, -0.6]) and xo[1] == pytest.approx([-0.2, -0.6])  # x° runs fastest
    assert xo[5] == pytest.approx([-0.4, -0.4]) and xo[-1] == pytest.approx([0.4, 0.6])
    assert xy[0] == pytest.approx([0.6, -0.4])  # target at the origin facing +x: world = (-y°, x°)
    assert candidate_grid(scene, 0.2, 0.6, 0.5)[1] == (5, 7)  # and the same rule along x°
    assert candidate_grid(scene, 0.05, 1.0, 1.2)[1] == (49, 41) and candidate_grid(scene, 0.05, 1.2, 1.0)[1] == (41, 49)


def test_probability_label_ignores_skipped_cells():
    """A skipped cell carries no rate: its value must not enter the map, nor count as a failure beside it."""
    shape = (1, 3)
    status = np.array([ROLLED_OUT, SKIPPED, ROLLED_OUT])
    lab = probability_label(np.array([1.0, 0.7, 1.0]), status, shape, sigma_cells=1.0)
    every = probability_label(np.ones(3), np.full(3, ROLLED_OUT), shape, sigma_cells=1.0)
    assert lab == pytest.approx(every, abs=1e-6)  # the known neighbourhood reads success everywhere
    lab = probability_label(np.array([1.0, 0.7, 0.0]), status, shape, sigma_cells=0.0)
    assert lab == pytest.approx([1.0, 0.0, 0.0])  # unsmoothed: the skipped cell's 0.7 is dropped
    one = np.full(9, SKIPPED)
    one[0] = ROLLED_OUT  # one known success: skipped cells within the kernel's reach read it, however weakly weighed
    every = probability_label(np.ones(9), np.full(9, ROLLED_OUT), (1, 9), sigma_cells=1.0)
    assert probability_label(np.eye(1, 9)[0], one, (1, 9), sigma_cells=1.0)[:4] == pytest.approx(every[:4], abs=1e-6)
    with pytest.raises(ValueError, match=r"range \[-0.1, 1\]"):
        probability_label(np.array([1.0, -0.1, 1.0]), status, shape)
