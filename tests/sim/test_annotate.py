import numpy as np
import pytest

from floaff_zoo.sim.annotate import annotate_scene


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
    c = a.counts
    assert c["candidates"] == H * W
    assert c["filtered_collision"] + c["filtered_reach"] + c["prefiltered_ik"] + c["rolled_out"] + c["skipped_budget"] == H * W
    assert c["filtered_collision"] > 0
    assert a.label.max() == pytest.approx(1.0) if a.success.any() else a.label.max() == 0.0


@pytest.mark.parametrize("task,cell,budget", [
    ("CloseDrawer", 0.15, None),
    ("OpenSingleDoor", 0.15, 16),
    ("PnPCounterToCab", 0.2, 10),
    pytest.param("CloseDoubleDoor", 0.15, 16, marks=pytest.mark.xfail(
        reason="scripted CloseDoubleDoor controller finds no successful pose yet (known gap, see report)", strict=False)),
])
def test_positive_and_negative(scene_factory, task, cell, budget):
    sc = scene_factory(task)
    a = annotate_scene(sc, cell=cell, max_candidates=budget)
    assert a.counts["positives"] >= 1, a.counts
    assert (~a.success).sum() >= 1
    assert a.label.max() == pytest.approx(1.0)
