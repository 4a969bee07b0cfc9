"""View sampling: regions, collision-freedom, target flags, base-frame transforms and shared labels."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from floaff_zoo.sim import views
from floaff_zoo.sim.render import Renderer

sys.path.insert(0, str(Path(__file__).parent))
from _fake_scene import COUNTER_X, FakeScene  # noqa: E402


@pytest.fixture(scope="module")
def fake():
    scene = FakeScene()
    r = Renderer(scene.model, 64, 64)
    yield scene, r
    r.close()


CFG = views.ViewConfig(image_size=64, max_points=4096, max_tries_per_view=40)


def test_target_frame_roundtrip_and_front_is_minus_y():
    t = np.array([1.0, 2.0])
    yaw = 0.7
    front = t + 1.5 * np.array([math.cos(yaw), math.sin(yaw)])  # 1.5 m in front of the target
    xo = views.world_to_target(front[None], t, yaw)[0]
    assert np.allclose(xo, [0.0, -1.5])
    pts = np.random.default_rng(0).normal(size=(20, 2))
    assert np.allclose(views.target_to_world(views.world_to_target(pts, t, yaw), t, yaw), pts)
    p3 = np.random.default_rng(1).normal(size=(10, 3))
    pose = np.array([0.3, -1.2, 2.5])
    assert np.allclose(views.base_to_world(views.world_to_base(p3, pose), pose), p3)
    # a point 1 m ahead of the robot is at x = 1 in its base frame
    ahead = np.array([[0.3 + math.cos(2.5), -1.2 + math.sin(2.5), 0.4]])
    assert np.allclose(views.world_to_base(ahead, pose), [[1.0, 0.0, 0.4]])


@pytest.mark.parametrize("kind", ["front", "side"])
def test_view_poses_in_region_and_collision_free(fake, kind):
    scene, r = fake
    got = views.sample_view_poses(scene, r, kind, 4, CFG, np.random.default_rng(3))
    assert len(got) == 4
    region = views.in_front_region if kind == "front" else views.in_side_region
    other = views.in_side_region if kind == "front" else views.in_front_region
    for pose, obs in got:
        xo = views.world_to_target(pose[None, :2], scene.target.pos[:2], scene.target.yaw)
        assert region(xo, CFG)[0] and not other(xo, CFG)[0]
        assert scene.footprint_free(*pose)
        scene.set_base_pose(*pose)
        assert not scene.robot_collides()
        # heading toward the target: it is straight ahead in the base frame
        t_base = views.world_to_base(scene.target.pos[None], pose)[0]
        assert t_base[0] > 0 and abs(t_base[1]) < 1e-6
        assert obs.n_target >= CFG.min_target_pixels


def test_flag_marks_target_points_and_floor_at_zero(fake):
    scene, r = fake
    ((pose, obs),) = views.sample_view_poses(scene, r, "front", 1, CFG, np.random.default_rng(5))
    world = views.base_to_world(obs.scene_xyz.astype(np.float64), pose)
    flag = obs.scene_feat[:, 0]
    assert set(np.unique(flag)) <= {0.0, 1.0} and flag.sum() > 0
    # handle box: x in [COUNTER_X-0.06, COUNTER_X], |y| <= 0.15, z in [0.52, 0.68]
    tgt = world[flag == 1]
    assert np.all(tgt[:, 0] > COUNTER_X - 0.07) and np.all(tgt[:, 0] < COUNTER_X + 1e-3)
    assert np.all(np.abs(tgt[:, 1]) < 0.16) and np.all((tgt[:, 2] > 0.51) & (tgt[:, 2] < 0.69))
    # the counter front around the handle is not flagged
    near = (np.abs(world[:, 0] - COUNTER_X) < 2e-3) & (np.abs(world[:, 1]) > 0.2) & (np.abs(world[:, 1]) < 0.6)
    assert near.sum() > 0 and np.all(flag[near] == 0)
    # base frame: floor at z = 0, no robot points (the robot_vis box sits at x ~ 0.35, z ~ 0.9)
    low = (obs.scene_xyz[:, 2] < 0.05) & (world[:, 0] < COUNTER_X - 0.02)  # floor, away from the counter's edge
    assert low.sum() > 10 and np.abs(obs.scene_xyz[low, 2]).max() < 2e-3
    assert not np.any((obs.scene_xyz[:, 0] < 0.5) & (obs.scene_xyz[:, 2] > 0.75))
    assert np.all((obs.scene_feat[:, 1:] >= 0) & (obs.scene_feat[:, 1:] <= 1))


def test_front_and_side_share_labels_in_world_frame(fake):
    scene, r = fake
    rng = np.random.default_rng(0)
    gx, gy = np.meshgrid(np.arange(-0.5, COUNTER_X - 0.3, 0.1), np.arange(-0.6, 0.61, 0.1))
    grid = np.stack([gx.ravel(), gy.ravel()], axis=1)
    label = rng.uniform(size=len(grid)).astype(np.float32)
    samples = []
    for kind in ("front", "side"):
        ((pose, obs),) = views.sample_view_poses(scene, r, kind, 1, CFG, np.random.default_rng(11))
        samples.append(views.make_view_sample(obs, pose, scene.target.pos, scene.target.yaw, grid, label))
    fr, sd = samples
    assert not np.allclose(fr["floor_xyz"], sd["floor_xyz"], atol=1e-2)  # different frames ...
    for s in samples:  # ... but the same world cells and labels
        w = views.base_to_world(s["floor_xyz"].astype(np.float64), s["base_pose_world"])
        assert np.allclose(w[:, :2], grid, atol=1e-4) and np.allclose(w[:, 2], 0.0)
        assert np.array_equal(s["floor_label"], label)
        tw = views.base_to_world(s["target_xyz"][None].astype(np.float64), s["base_pose_world"])[0]
        assert np.allclose(tw, scene.target.pos, atol=1e-4)
        yaw_w = views.wrap_angle(float(s["target_yaw"]) + float(s["base_pose_world"][2]))
        assert abs(views.wrap_angle(yaw_w - scene.target.yaw)) < 1e-5
        assert s["robot"].shape == (2,) and s["target_yaw"].shape == ()
    with pytest.raises(ValueError, match="label"):
        views.make_view_sample(obs, pose, scene.target.pos, scene.target.yaw, grid, label[:-1])


def test_robot_geoms_never_enter_the_cloud(fake):
    scene, r = fake
    pose = np.array([-0.5, 0.0, 0.0])
    near = {}
    for hide in (True, False):
        cfg = views.ViewConfig(image_size=64, max_points=100000, hide_robot=hide)
        obs = views.render_view(scene, r, pose, cfg, np.random.default_rng(0))
        assert not np.any((obs.scene_xyz[:, 0] < 0.5) & (obs.scene_xyz[:, 2] > 0.75))  # no 'arm' box points
        near[hide] = int(
            ((obs.scene_xyz[:, 0] < 1.5) & (np.abs(obs.scene_xyz[:, 1]) < 0.2) & (obs.scene_xyz[:, 2] < 0.01)).sum()
        )
    res = r.render(scene.data, views.EGO_CAMERA)
    assert np.any(res.geom_id == scene.robot_geom_ids[1])  # the 'arm' box is in the camera's view
    assert near[True] > near[False]  # hiding the robot reveals the floor it occludes
