import pytest

from floaff_zoo.sim.kitchen import TASKS
from floaff_zoo.sim.tasks import TASK_REGISTRY, candidate_region, get_task


@pytest.mark.parametrize("task", TASKS)
def test_success_state_true_reset_false(scene_factory, task):
    import numpy as np

    sc = scene_factory(task)
    sc.reset_task(np.random.default_rng(3))
    assert not TASK_REGISTRY[task].success(sc)
    TASK_REGISTRY[task].set_success_state(sc)
    assert TASK_REGISTRY[task].success(sc), TASK_REGISTRY[task].state(sc)
    sc.reset_task(None)
    assert not TASK_REGISTRY[task].success(sc)


def test_reset_ranges(scene_factory):
    import numpy as np

    sc = scene_factory("CloseDrawer")
    for s in range(5):
        sc.reset_task(np.random.default_rng(s))
        assert 0.9 <= sc.task.state(sc)["drawer_open"] <= 1.0
    sc = scene_factory("OpenSingleDoor")
    sc.reset_task(np.random.default_rng(0))
    assert sc.task.state(sc)["door_open"] == 0.0


def test_candidate_region_and_unknown():
    for t in TASKS:
        rx, ry = candidate_region(t)
        assert rx > 0 and ry > 0
    with pytest.raises(ValueError, match="valid tasks"):
        get_task("Nope")
