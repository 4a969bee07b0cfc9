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


def _idle(sc, seconds: float = 2.0) -> dict:
    """The task state after ``seconds`` of simulation with the robot parked and held still."""
    from floaff_zoo.sim.rollout import hold_still

    hold_still(sc, seconds)
    return sc.task.state(sc)


@pytest.mark.parametrize(("layout", "style", "seed"), [(3, 3, 0), (3, 4, 1), (5, 5, 0), (5, 7, 2), (1, 1, 0)])
def test_no_door_or_drawer_of_a_corner_layout_moves_by_itself(layout, style, seed):
    """U-, G- and L-shaped kitchens (generator 2.3): closed, and in every task's reset state, no door or drawer moves
    in 1 s with the robot parked away (the side run stood flush with the back run, whose corner filler had fronts and
    handles: a part reset into them was pushed by the contact forces, one double door shut by itself)."""
    import mujoco
    import numpy as np

    from floaff_zoo.sim.kitchen import PARK_POSE, SceneSpec, build_scene
    from floaff_zoo.sim.rollout import hold_still

    sc = build_scene(SceneSpec(layout, style, seed, "CloseDoubleDoor"))
    m = sc.model
    robot = set(sc.robot.body_ids.tolist())
    parts = [
        int(m.jnt_qposadr[j])
        for j in range(m.njnt)
        if m.jnt_type[j] in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE) and m.jnt_bodyid[j] not in robot
    ]
    assert parts, "a kitchen has doors and drawers"
    for name in ("CloseDoubleDoor", "CloseDrawer", "PnPCounterToCab", None):  # None: every part closed
        mujoco.mj_resetData(m, sc.data)
        sc.robot.set_base_pose(sc.data, *PARK_POSE)
        sc.robot.set_tuck(sc.data)
        if name is not None:
            TASK_REGISTRY[name].reset(sc, np.random.default_rng(0))
            sc.task = TASK_REGISTRY[name]
            assert min(v for k, v in sc.task.state(sc).items() if k.endswith("_open")) >= 0.8
        mujoco.mj_forward(m, sc.data)
        before = sc.data.qpos[parts].copy()
        hold_still(sc, 1.0)
        moved = np.abs(sc.data.qpos[parts] - before)
        assert moved.max() < 0.005, (
            name,
            [
                mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j)
                for j in range(m.njnt)
                if m.jnt_qposadr[j] in np.array(parts)[moved >= 0.005]
            ],
        )


def test_an_opened_part_stays_where_its_reset_left_it():
    """The Layouts test scene whose double door swung shut by itself after the reset (generator 2.1/2.2, 0.93 ->
    0.02 in 2 s), and a drawer whose drawn opening reaches into furniture: the reset lowers it until it is clear."""
    import numpy as np

    from floaff_zoo.sim.kitchen import PARK_POSE, SceneSpec, build_scene

    sc = build_scene(SceneSpec(5, 3, 1443886777, "CloseDoubleDoor"))
    sc.robot.set_base_pose(sc.data, *PARK_POSE)
    sc.reset_task(np.random.default_rng(0))
    before = sc.task.state(sc)
    assert min(before.values()) >= 0.9
    after = _idle(sc)
    assert all(abs(after[k] - before[k]) < 0.005 for k in before), (before, after)

    sc = build_scene(SceneSpec(5, 5, 117899901, "CloseDrawer"))
    sc.robot.set_base_pose(sc.data, *PARK_POSE)
    sc.reset_task(np.random.default_rng(0))
    drawn = float(np.random.default_rng(0).uniform(0.90, 1.00))
    opened = sc.task.state(sc)["drawer_open"]
    assert 0.5 < opened < drawn - 0.005  # lowered: the drawn opening reaches into the furniture in front
    assert abs(_idle(sc)["drawer_open"] - opened) < 0.005


def test_a_part_the_furniture_blocks_is_reported_and_the_state_kept(scene_factory, monkeypatch):
    """Generator 2.3.1: a kitchen where a part the reset opens cannot pass half its travel is refused (a closing task
    half done at reset). ``blocked_parts`` names such parts and leaves the scene as it found it."""
    import numpy as np

    from floaff_zoo.sim.tasks import MIN_RESET_FRACTION

    sc = scene_factory("CloseDoubleDoor")
    sc.reset_task(np.random.default_rng(1))
    before = sc.data.qpos.copy()
    assert sc.task.blocked_parts(sc) == {}
    np.testing.assert_array_equal(sc.data.qpos, before)
    joints = [d["joint"] for d in sc.fixtures["double_door"]["doors"]]
    assert [j for j, _ in sc.task.opened_parts(sc)] == joints

    monkeypatch.setattr(type(sc), "part_overlaps", lambda self, part, depth: True)  # every opening meets furniture
    assert sc.task.blocked_parts(sc) == dict.fromkeys(joints, 0.0)
    np.testing.assert_array_equal(sc.data.qpos, before)

    def overlaps_past_0_4(self, part, depth):  # the furniture stops every part at 40 % of its travel
        return any(self.data.qpos[_part_qpos(self, j)] / full > 0.4 + 1e-9 for j, full in self.task.opened_parts(self))

    monkeypatch.setattr(type(sc), "part_overlaps", overlaps_past_0_4)
    assert sorted(sc.task.blocked_parts(sc)) == sorted(joints) and 0.4 < MIN_RESET_FRACTION
    assert all(abs(f - 0.4) < 1e-6 for f in sc.task.blocked_parts(sc).values())
    for task in ("CloseDrawer", "PnPCounterToCab"):
        other = scene_factory(task)
        ((joint, _),) = other.task.opened_parts(other)
        assert list(other.task.blocked_parts(other)) == [joint]
    closed = scene_factory("OpenSingleDoor")  # its reset opens nothing
    assert closed.task.opened_parts(closed) == [] and closed.task.blocked_parts(closed) == {}


def _part_qpos(sc, joint: str) -> int:
    import mujoco

    return int(sc.model.jnt_qposadr[mujoco.mj_name2id(sc.model, mujoco.mjtObj.mjOBJ_JOINT, joint)])


def test_a_task_name_that_is_not_text_is_named():
    """A list failed with a bare "unhashable type: 'list'" in get_task and default_policy."""
    from floaff_zoo.sim.controllers import default_policy

    with pytest.raises(ValueError, match="unknown task"):
        get_task(["CloseDrawer"])
    with pytest.raises(ValueError, match="unknown task"):
        default_policy(["CloseDrawer"])


@pytest.mark.parametrize("shape", [(5,), (2, 3), (2, 4), (1,), ()])
def test_target_frame_refuses_points_that_are_not_xy(shape):
    """A 1-D array of 5 values came back as one point, [N,3] and [N,4] points lost their other coordinates, one
    value failed with an IndexError."""
    import numpy as np

    from floaff_zoo.sim.tasks import TargetInfo, target_frame, target_frame_to_world

    target = TargetInfo(np.zeros(3), 0.0, "drawer", [], np.zeros(0, np.int64), [])
    for fn in (target_frame, target_frame_to_world):
        with pytest.raises(ValueError, match=rf"{fn.__name__}: expects points of shape \[\.\.\., 2\], got shape"):
            fn(target, np.zeros(shape))
    assert target_frame(target, target_frame_to_world(target, np.ones((3, 2)))).shape == (3, 2)


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(ik_iters=-1), "ik_iters must be an integer >= 1"),  # no IK iteration at a tick: every step 1e9 m off
        (dict(ik_iters=1.5), "ik_iters must be an integer >= 1"),  # failed mid-rollout in range()
        (dict(precheck="no"), "precheck must be a bool"),  # read as true
    ],
)
def test_a_policy_refuses_a_bad_setting(kwargs, match):
    from floaff_zoo.sim.controllers import CloseDrawerPolicy

    with pytest.raises(ValueError, match=f"CloseDrawerPolicy: {match}"):
        CloseDrawerPolicy(**kwargs)
