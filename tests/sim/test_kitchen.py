import math

import numpy as np
import pytest

from floaff_zoo.sim.kitchen import LAYOUTS, STYLES, TASKS, SceneSpec, build_scene


def test_spec_validation_lists_valid_ids():
    with pytest.raises(ValueError, match=r"valid ids: \[0, 1, 2, 3, 4, 5\]"):
        SceneSpec(99, 0, 0, "CloseDrawer")
    with pytest.raises(ValueError, match="valid ids"):
        SceneSpec(0, 42, 0, "CloseDrawer")
    with pytest.raises(ValueError, match="CloseDrawer"):
        SceneSpec(0, 0, 0, "FlyAway")


def test_spec_roundtrip_and_id():
    s = SceneSpec(2, 5, 17, "CloseDrawer")
    assert s.scene_id == "L2_S5_s17_CloseDrawer"
    assert SceneSpec.from_dict(s.to_dict()) == s
    with pytest.raises(ValueError, match="missing"):
        SceneSpec.from_dict({"layout_id": 1})
    assert SceneSpec.from_dict({**s.to_dict(), "seed": 17.0, "layout_id": np.int64(2), "style_id": "5"}) == s


@pytest.mark.parametrize(
    "field,value", [("seed", 17.5), ("layout_id", True), ("style_id", float("nan")), ("seed", "x")]
)
def test_spec_from_dict_refuses_a_value_that_is_not_a_whole_number(field, value):
    """from_dict cut a record's seed 17.5 to 17 (another scene's kitchen, without a word) and read true as layout 1; a
    NaN or a word failed inside int() naming neither the field nor the record."""
    d = {**SceneSpec(2, 5, 17, "CloseDrawer").to_dict(), field: value}
    with pytest.raises(ValueError, match=f"{field} must be a whole number"):
        SceneSpec.from_dict(d)


def test_variety_counts():
    assert len(LAYOUTS) >= 6 and len(STYLES) >= 8 and len(TASKS) == 4


@pytest.mark.parametrize("layout", sorted(LAYOUTS))
def test_every_layout_builds_with_all_targets(layout):
    for task in TASKS:
        sc = build_scene(SceneSpec(layout, layout % len(STYLES), 1, task))
        assert sc.target.geom_ids.size > 0
        assert np.isfinite(sc.target.pos).all()
        # target front faces open floor: a point 0.8 m in front is free for the robot footprint
        n = np.array([math.cos(sc.target.yaw), math.sin(sc.target.yaw)])
        p = sc.target.pos[:2] + 0.7 * n
        assert sc.footprint_free(p[0], p[1], sc.target.yaw + math.pi), (layout, task)


def test_compiled_kitchen_cache_keeps_only_the_most_recently_used(monkeypatch):
    """The per-process cache of compiled kitchens kept every kitchen it ever compiled (~70 MB each), so a long
    rollout service over many scenes grew without bound; it keeps the last CACHE_SIZE, and a kitchen compiled again
    is the same model."""
    from floaff_zoo.sim import kitchen

    monkeypatch.setattr(kitchen, "_CACHE", {})
    monkeypatch.setattr(kitchen, "CACHE_SIZE", 2, raising=False)
    first = build_scene(SceneSpec(0, 0, 1, "CloseDrawer"))
    build_scene(SceneSpec(0, 0, 2, "CloseDrawer"))
    build_scene(SceneSpec(0, 0, 1, "OpenSingleDoor"))  # the same kitchen, another task: a hit, now the most recent
    build_scene(SceneSpec(0, 0, 3, "CloseDrawer"))
    assert list(kitchen._CACHE) == [(0, 0, 1), (0, 0, 3)]  # (0, 0, 2), used longest ago, was dropped
    build_scene(SceneSpec(0, 0, 2, "CloseDrawer"))
    assert list(kitchen._CACHE) == [(0, 0, 3), (0, 0, 2)]
    again = build_scene(SceneSpec(0, 0, 1, "CloseDrawer"))  # compiled again after it was dropped
    np.testing.assert_array_equal(first.model.geom_pos, again.model.geom_pos)
    np.testing.assert_array_equal(first.target.pos, again.target.pos)


def test_build_is_deterministic():
    a = build_scene(SceneSpec(3, 2, 5, "CloseDrawer"))
    from floaff_zoo.sim import kitchen

    kitchen._CACHE.clear()
    b = build_scene(SceneSpec(3, 2, 5, "CloseDrawer"))
    assert a.model.ngeom == b.model.ngeom
    np.testing.assert_array_equal(a.model.geom_pos, b.model.geom_pos)
    np.testing.assert_array_equal(a.target.pos, b.target.pos)


def test_styles_change_geometry():
    a = build_scene(SceneSpec(0, 0, 0, "CloseDrawer"))
    b = build_scene(SceneSpec(0, 3, 0, "CloseDrawer"))
    assert a.fixtures["drawer"]["z1"] != b.fixtures["drawer"]["z1"]
    assert a.model.ngeom != b.model.ngeom or not np.allclose(a.model.geom_size, b.model.geom_size)


def test_base_pose_roundtrip_and_pivot(scene_factory):
    sc = scene_factory("CloseDrawer")
    for pose in [(0.3, -2.0, 0.0), (-0.5, -1.7, 1.2), (1.0, -2.2, -2.9)]:
        sc.set_base_pose(*pose)
        got = sc.base_pose()
        assert np.allclose(got, pose, atol=1e-9)
        # the base body origin is where we asked, despite the 0.21 m yaw pivot
        assert np.allclose(sc.data.xpos[sc.robot.base_body][:2], pose[:2], atol=1e-9)


def test_collision_and_footprint(scene_factory):
    sc = scene_factory("CloseDrawer")
    sc.reset_task(None)
    t = sc.target
    n = np.array([math.cos(t.yaw), math.sin(t.yaw)])
    inside = t.pos[:2] - 0.3 * n  # inside the cabinet
    assert not sc.footprint_free(inside[0], inside[1], t.yaw + math.pi)
    sc.set_base_pose(inside[0], inside[1], t.yaw + math.pi)
    assert sc.robot_collides()
    touched = sc.robot_contacts()  # the same contacts by name, deepest first
    assert touched and all(d < 0 for *_, d in touched) and [c[2] for c in touched] == sorted(c[2] for c in touched)
    robot_bodies = {sc.model.body(int(sc.model.geom_bodyid[g])).name for g in sc.robot_geom_ids}
    assert all(a in robot_bodies and b not in robot_bodies for a, b, _ in touched)
    free = t.pos[:2] + 1.1 * n
    assert sc.footprint_free(free[0], free[1], t.yaw + math.pi)
    sc.set_base_pose(free[0], free[1], t.yaw + math.pi)
    assert not sc.robot_collides() and sc.robot_contacts() == []
    outline = sc.floor_outline()
    assert outline and all(p.shape == (4, 2) for p in outline)


def test_ego_camera_and_groups(scene_factory):
    import mujoco

    sc = scene_factory("CloseDrawer")
    assert mujoco.mj_name2id(sc.model, mujoco.mjtObj.mjOBJ_CAMERA, "floaff_ego") >= 0
    assert (sc.model.geom_group[sc.scene_geom_ids] >= 1).all()
    assert not sc.model.light_castshadow.any()


def test_no_lazy_name_is_also_a_submodule():
    """`from floaff_zoo.sim import rollout` gave the function or the module depending on what was imported before."""
    import pkgutil

    import floaff_zoo.sim as sim

    submodules = {m.name for m in pkgutil.iter_modules(sim.__path__)}
    assert not submodules & set(sim._LAZY)


@pytest.mark.parametrize(
    "field,value",
    [
        ("seed", 1.7),
        ("seed", True),
        ("layout_id", 1.5),
        ("style_id", False),
        ("seed", float("nan")),
        ("seed", None),
        ("layout_id", np.True_),  # layout 1
        ("seed", "1_7"),  # int() read seed 17
        ("seed", " 17 "),
    ],
)
def test_spec_refuses_a_value_that_is_not_a_whole_number(field, value):
    """The constructor cut seed 1.7 to seed 1's kitchen under the id ``s1.7`` and built layout 1 for True (or 1.5)
    without a word; a NaN failed inside int() naming no field."""
    d = {**SceneSpec(2, 5, 17, "CloseDrawer").to_dict(), field: value}
    with pytest.raises(ValueError, match=f"SceneSpec: {field} must be a whole number"):
        SceneSpec(**d)


def test_spec_stores_whole_numbers_as_ints():
    """seed 3.0 named its scene ``s3.0`` (another id, another cache key) for seed 3's kitchen; a text seed made a spec
    that was not equal to (nor hashed as) the int one."""
    s = SceneSpec(2, 5, 3, "CloseDrawer")
    for other in (SceneSpec(2.0, np.int64(5), 3.0, "CloseDrawer"), SceneSpec("2", 5, "3", "CloseDrawer")):
        assert other == s and hash(other) == hash(s) and other.scene_id == "L2_S5_s3_CloseDrawer"
        assert all(type(v) is int for v in (other.layout_id, other.style_id, other.seed))


def test_spec_from_dict_and_release_refuse_what_is_not_a_spec():
    from floaff_zoo.sim.kitchen import release_scene

    with pytest.raises(ValueError, match="expects a mapping"):
        SceneSpec.from_dict(None)
    with pytest.raises(TypeError, match="release_scene expects a SceneSpec, got dict"):
        release_scene(SceneSpec(0, 0, 0, "CloseDrawer").to_dict())


def test_scene_refuses_a_bad_margin_rng_or_ik_damping(scene_factory):
    """robot_collides with a NaN margin found no collision anywhere and with a negative one let the robot sink into
    furniture; reset_task failed inside the task on a seed (or, for a task that draws nothing, ignored it), and a
    NaN IK damping made every solution NaN."""
    from floaff_zoo.sim.robot import DLSIK

    sc = scene_factory("CloseDrawer")
    for margin in (float("nan"), -0.1):
        with pytest.raises(ValueError, match="robot_collides: margin must be a finite number >= 0"):
            sc.robot_collides(margin)
    for task in ("CloseDrawer", "OpenSingleDoor"):
        with pytest.raises(TypeError, match="rng must be a numpy Generator or None, got int"):
            scene_factory(task).reset_task(3)
    for damping in (float("nan"), 0.0):
        with pytest.raises(ValueError, match="DLSIK: damping must be a finite number > 0"):
            DLSIK(sc.model, sc.robot, damping)


def test_style_params_refuses_a_style_that_is_not_a_whole_number():
    """int() read style 1.5 (or True) as style 1 without a word."""
    from floaff_zoo.sim.kitchen import style_params

    assert style_params(np.int64(1)) == style_params(1.0) == style_params(1)
    for bad in (1.5, True, None):
        with pytest.raises(ValueError, match="unknown style_id"):
            style_params(bad)


def test_compile_scene_names_an_argument_that_is_no_scene_spec():
    """A spec's dict failed with an AttributeError on 'layout_id', as build_scene's did."""
    from floaff_zoo.sim.kitchen import compile_scene

    with pytest.raises(TypeError, match="compile_scene expects a SceneSpec, got dict"):
        compile_scene({"layout_id": 0, "style_id": 0, "seed": 1, "task": "CloseDrawer"})


def test_part_overlaps_and_wall_between_refuse_a_bad_argument(scene_factory):
    """part_overlaps with a NaN depth reported no overlap at any opening and with an int mask tested geoms 0 and 1
    instead of the part; wall_between's [1] or [2, 2] point failed in numpy's stack naming neither."""
    sc = scene_factory("CloseDrawer")
    part = np.zeros(sc.model.ngeom, dtype=bool)
    assert sc.part_overlaps(part, 0.01) is False
    for depth in (float("nan"), -0.01):
        with pytest.raises(ValueError, match="part_overlaps: depth must be a finite number >= 0"):
            sc.part_overlaps(part, depth)
    for bad in (part.astype(int), part[:3]):
        with pytest.raises(ValueError, match=r"part_overlaps: part must be a bool \[ngeom\]"):
            sc.part_overlaps(bad, 0.01)
    for point in ([1.0], [[1.0, 1.0], [2.0, 2.0]]):
        with pytest.raises(ValueError, match="wall_between: the segment must be finite"):
            sc.wall_between(0.0, 0.0, point)


def test_an_unknown_module_kind_is_refused_not_built_plain():
    """The builder's last branch built any kind it did not know (a misspelt one) as a plain module, without a word."""
    import mujoco

    from floaff_zoo.sim import kitchen

    bld = kitchen._Builder(mujoco.MjSpec(), kitchen.style_params(0), np.random.default_rng(0), 0)
    bld.module("plain", [0.0, 0.0], 0.0, 0.6, 0.6)
    with pytest.raises(ValueError, match="unknown module kind 'plian'"):
        bld.module("plian", [2.0, 0.0], 0.0, 0.6, 0.6)
