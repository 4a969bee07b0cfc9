"""The predict API: back-projection conventions, default grid, outputs, bad input."""

import math

import numpy as np
import pytest
import torch

from floaff_zoo.contract import FloorGrid, SampleError
from floaff_zoo.floor import FloorLattice
from floaff_zoo.models.tiny import TinyPointNetModule
from floaff_zoo.predict import (
    DEFAULT_FLOOR_CELL,
    Prediction,
    backproject_depth,
    default_floor_grid,
    predict,
    predict_from_points,
)
from tests.report._fake_world import ConstantModule


def _cam_pose():
    """A camera 1.2 m up looking forward (+x base) and pitched 20 deg down, OpenGL axes (looks along -z)."""
    p = math.radians(20)
    fwd = np.array([math.cos(p), 0.0, -math.sin(p)])
    right = np.array([0.0, -1.0, 0.0])
    up = np.cross(-fwd, right)  # camera axes: x = right, z = -forward, y = z cross x
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = right, up, -fwd, [0.0, 0.0, 1.2]
    return m


def _floor_depth(h=48, w=64, f=50.0):
    """Depth image of the plane z = 0 seen by _cam_pose (ray casting), intrinsics (f, f, w/2, h/2)."""
    pose = _cam_pose()
    uu, vv = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    dirs = np.stack([(uu - w / 2) / f, -(vv - h / 2) / f, -np.ones_like(uu)], -1)  # camera frame, depth 1
    world = dirs @ pose[:3, :3].T
    t = -pose[2, 3] / world[..., 2]
    depth = np.where(world[..., 2] < 0, t, 0.0)  # rays above the horizon: invalid
    return depth, (f, f, w / 2, h / 2), pose


def test_backprojection_lands_on_the_floor_in_both_conventions():
    depth, k, pose = _floor_depth()
    pts, valid = backproject_depth(depth, k, pose, "opengl", max_depth=20.0)
    assert valid.sum() > 1000 and np.abs(pts[valid, 2]).max() < 1e-6
    assert (pts[valid, 0] > 0).all()  # in front of the robot
    cv_pose = pose @ np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV axes: y down, looks along +z
    pts_cv, _ = backproject_depth(depth, k, cv_pose, "opencv", max_depth=20.0)
    assert np.allclose(pts_cv[valid], pts[valid], atol=1e-9)


def test_backprojection_matches_the_simulator_renderer():
    from floaff_zoo.sim import render

    depth, _, pose = _floor_depth(h=48, w=48)
    f, cx, cy = render.camera_intrinsics(48, 48, 60.0)
    ours, v1 = backproject_depth(depth, (f, f, cx, cy), pose, "opengl", max_depth=5.0)
    theirs, v2 = render.backproject(depth, 60.0, pose[:3, 3], pose[:3, :3], depth_max=5.0)
    assert (v1 == v2).all() and np.allclose(ours[v1], theirs[v2])


def _scene():
    """A counter (x in [1.7, 2.3], z in [0.05, 0.85]) with the target on its front edge, and the floor the robot
    sees in front of it: x in [0.5, 1.65], y in [-0.8, 0.9], z = 0 (a strip y in [0.3, 0.5] is occluded)."""
    rng = np.random.default_rng(0)
    t = np.array([1.6, 0.2, 0.9])
    counter = np.c_[rng.uniform(1.7, 2.3, 300), rng.uniform(-1, 1, 300), rng.uniform(0.05, 0.85, 300)]
    blob = t + rng.normal(scale=0.03, size=(60, 3))
    floor = np.c_[rng.uniform(0.5, 1.65, 3000), rng.uniform(-0.8, 0.9, 3000), np.zeros(3000)]
    floor = floor[(floor[:, 1] < 0.3) | (floor[:, 1] > 0.5)]
    xyz = np.r_[counter, blob, floor].astype(np.float32)
    feat = np.r_[np.zeros(300), np.ones(60), np.zeros(len(floor))].astype(np.float32)[:, None]
    return xyz, feat, t


def test_default_floor_is_the_observed_floor_cells():
    xyz, _, t = _scene()
    yaw = math.pi  # the counter front faces -x, toward the robot
    floor = default_floor_grid(t, xyz, yaw, cell=0.1)
    assert floor.dtype == np.float32 and floor.shape[1] == 3 and (floor[:, 2] == 0).all()
    # cells of the target-aligned lattice (centred on the target): each holds a ground point ...
    lat = FloorLattice.target_window(t[:2], yaw, 0.1, 1.0, 1.2)
    idx, inside = lat.index_of(floor)
    assert inside.all() and np.allclose(lat.centers()[idx], floor[:, :2], atol=1e-5)
    ground = xyz[xyz[:, 2] < 0.02]
    gidx, gin = lat.index_of(ground)
    assert set(idx.tolist()) == set(gidx[gin].tolist())  # ... and every cell with a ground point is asked
    # the occluded strip and the counter are not asked; the observed floor is, out to the window's edge
    assert not ((floor[:, 1] > 0.33) & (floor[:, 1] < 0.47)).any() and floor[:, 0].max() < 1.7
    assert floor[:, 0].min() < 0.6 and abs(np.abs(floor[:, 1] - t[1]).max() - 1.0) < 1e-5
    assert len(default_floor_grid(t, xyz, yaw, cell=0.1, radius=0.5)) < len(floor)
    # without a yaw the front faces the robot: the same lattice here (yaw ~ atan2(-0.2, -1.6))
    assert len(default_floor_grid(t, xyz, None, cell=0.1)) > 0.8 * len(floor)


def test_predict_from_points_outputs_and_default_grid():
    torch.manual_seed(0)
    xyz, feat, t = _scene()
    model = TinyPointNetModule(width=16)
    out = predict_from_points(model, xyz, feat, None, [0.85, 1.03], t, target_yaw=math.pi, k=4, num_points=256)
    assert isinstance(out, Prediction)
    m = len(out.floor_xyz)
    assert out.scores.shape == (m,) and ((out.scores >= 0) & (out.scores <= 1)).all()
    assert np.allclose(out.floor_xyz, default_floor_grid(t, xyz, math.pi, cell=DEFAULT_FLOOR_CELL), atol=1e-5)
    assert isinstance(out.grid, FloorGrid) and out.raster.shape == out.grid.shape
    assert np.nanmax(out.raster) == pytest.approx(out.scores.max(), abs=1e-6)
    top = [int(np.argmin(np.hypot(out.floor_xyz[:, 0] - p[0], out.floor_xyz[:, 1] - p[1]))) for p in out.top_poses]
    assert len(top) == 4 and list(out.scores[top]) == sorted(out.scores[top], reverse=True)
    assert out.best_pose == out.top_poses[0] and out.scores[top[0]] == out.scores.max()
    x, y, yaw = out.best_pose
    assert yaw == pytest.approx(math.atan2(t[1] - y, t[0] - x))
    assert out.target_yaw == pytest.approx(math.pi)
    plain = predict_from_points(ConstantModule(), xyz, feat, None, [0.85, 1.03], t)
    assert plain.target_yaw == pytest.approx(math.atan2(-t[1], -t[0]))  # default: front faces the robot


def test_constant_prediction_uses_the_tie_break():
    xyz, feat, t = _scene()
    floor = np.array([[0.2, 0.0, 0.0], [1.0, 0.1, 0.0], [0.6, -0.5, 0.0]], np.float32)
    out = predict_from_points(ConstantModule(), xyz, feat, floor, [0.85, 1.03], t, k=3)
    again = predict_from_points(ConstantModule(), xyz, feat, floor, [0.85, 1.03], t, k=3)
    assert out.best_pose == again.best_pose  # the seeded tie-break is repeatable
    assert sorted(p[:2] for p in out.top_poses) == sorted(tuple(map(float, f[:2])) for f in floor)


def test_predict_from_rgbd(tmp_path):
    depth, k, pose = _floor_depth()
    mask = np.zeros(depth.shape, bool)
    mask[20:24, 30:34] = True  # a patch on the floor plays the target
    rgb = np.full(depth.shape + (3,), 128, np.uint8)
    model = TinyPointNetModule(width=16, feat_channels=4)
    out = predict(model, rgb, depth, k, pose, mask, [0.85, 1.03], num_points=512, max_depth=20.0)
    assert out.scores.shape == (len(out.floor_xyz),) and np.isfinite(out.scores).all()
    assert abs(out.target_xyz[2]) < 1e-5 and out.target_xyz[0] > 0
    with pytest.raises(ValueError, match="target_mask"):
        predict(model, rgb, depth, k, pose, mask[:-1], [0.85, 1.03])
    with pytest.raises(Exception, match="no pixel"):
        predict(model, rgb, depth, k, pose, np.zeros_like(mask), [0.85, 1.03])
    # a 0/255 mask marks the same pixels; a label map (several objects) was read as one target without a word
    byte_mask = mask.astype(np.uint8) * 255
    again = predict(model, rgb, depth, k, pose, byte_mask, [0.85, 1.03], num_points=512, max_depth=20.0)
    assert np.array_equal(again.target_xyz, out.target_xyz)
    labels = mask.astype(np.uint8) * 3
    labels[0:4, 0:4] = 7  # another object
    with pytest.raises(ValueError, match="target_mask holds 2 different nonzero values"):
        predict(model, rgb, depth, k, pose, labels, [0.85, 1.03])


def test_checkpoint_of_another_model_class_is_a_clear_error(tmp_path):
    m = TinyPointNetModule(width=16)
    ckpt = tmp_path / "tiny.ckpt"
    hp = dict(m.hparams, _class_path="floaff_zoo.models.tiny.TinyPointNetModule")
    torch.save({"state_dict": m.state_dict(), "hyper_parameters": hp}, ckpt)
    xyz, feat, t = _scene()
    out = predict_from_points(
        str(ckpt), xyz, feat, None, [0.85, 1.03], t, num_points=128, model_class="TinyPointNetModule"
    )
    assert np.isfinite(out.scores).all()
    with pytest.raises(TypeError, match="expected a PointNet2Module .* TinyPointNetModule"):
        predict_from_points(str(ckpt), xyz, feat, None, [0.85, 1.03], t, model_class="PointNet2Module")
    with pytest.raises(FileNotFoundError, match="no_such.ckpt"):
        predict_from_points(str(tmp_path / "no_such.ckpt"), xyz, feat, None, [0.85, 1.03], t)
    from floaff_zoo.contract import SampleError

    with pytest.raises(SampleError, match="robot"):
        predict_from_points(m, xyz, feat, None, [0.85, 1.03, 0.5], t)


def test_default_grid_without_observed_floor_is_named():
    g = np.arange(-2.0, 2.0, 0.05)
    top = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    xyz = np.c_[top, np.full(len(top), 0.5)]  # furniture everywhere around the target: no ground point
    with pytest.raises(SampleError, match="no observed floor cell"):
        default_floor_grid(np.array([0.0, 0.0, 0.9]), xyz)
    xyz[:, 2] = 0.0  # all floor: the whole window (|x°| <= 5, |y°| <= 6 cells of 0.2 m), or its disc
    assert len(default_floor_grid(np.array([0.0, 0.0, 0.9]), xyz, 0.3, cell=0.2)) == 11 * 13
    assert len(default_floor_grid(np.array([0.0, 0.0, 0.9]), xyz, 0.3, cell=0.2, radius=0.5)) == 21


def test_package_level_call():
    import floaff_zoo
    import floaff_zoo.predict  # noqa: F401  (the submodule import must not break floaff_zoo.predict(...))

    xyz, feat, t = _scene()
    depth, k, pose = _floor_depth()
    mask = np.zeros(depth.shape, bool)
    mask[20:24, 30:34] = True
    out = floaff_zoo.predict(ConstantModule(), None, depth, k, pose, mask, [0.85, 1.03], max_depth=20.0)
    assert isinstance(out, Prediction) and callable(floaff_zoo.predict.predict_from_points)


def test_seed_breaks_ties_and_a_known_target_replaces_the_mask_centroid():
    """predict's ``seed`` did not reach the tie-break (every seed chose the same of equal cells), and an RGB-D call
    could only use the centroid of the mask's points as the target, not the target point the models learnt."""
    xyz, feat, t = _scene()
    floor = np.array([[0.2 + 0.1 * i, 0.3 * (i % 3) - 0.3, 0.0] for i in range(8)], np.float32)
    picks = {
        predict_from_points(ConstantModule(), xyz, feat, floor, [0.85, 1.03], t, seed=s).best_pose for s in range(6)
    }
    assert len(picks) > 1
    depth, k, pose = _floor_depth()
    mask = np.zeros(depth.shape, bool)
    mask[20:24, 30:34] = True
    known = np.array([2.5, 0.2, 0.0], np.float32)
    out = predict(ConstantModule(), None, depth, k, pose, mask, [0.85, 1.03], target_xyz=known, max_depth=20.0)
    np.testing.assert_allclose(out.target_xyz, known)
    assert out.best_pose[2] == pytest.approx(math.atan2(known[1] - out.best_pose[1], known[0] - out.best_pose[0]))
    with pytest.raises(ValueError, match="intrinsics must be finite"):
        predict(ConstantModule(), None, depth, (float("nan"), 50.0, 32.0, 24.0), pose, mask, [0.85, 1.03])


def test_world_yaw_is_in_the_half_open_interval():
    from floaff_zoo.frames import pose_to_world

    assert pose_to_world((0.0, 0.0, -math.pi / 2), (0.0, 0.0, -math.pi / 2))[2] == pytest.approx(math.pi)
    assert pose_to_world((0.0, 0.0, math.pi / 2), (0.0, 0.0, math.pi / 2))[2] == pytest.approx(math.pi)


def test_bad_arguments_are_named_before_the_model_loads():
    """A NaN target_yaw, a negative window or radius, NaN points and an unavailable device failed later with
    messages naming something else (FloorLattice, the floor, the sample contract) or a bare AssertionError."""
    xyz, feat, t = _scene()
    robot = [0.85, 1.03]
    cases = [
        ({"target_yaw": float("nan")}, "target_yaw must be a finite angle"),
        # a text or two values failed in float() naming no argument
        ({"target_yaw": "a"}, "target_yaw must be a finite angle"),
        ({"target_yaw": [0.1, 0.2]}, "target_yaw must be a finite angle"),
        ({"window": (1.0, -1.2)}, "window must be two finite half-sizes"),
        ({"grid_radius": 0.0}, "grid_radius must be a finite radius"),
        # texts and several values failed in float() or numpy naming no argument
        ({"grid_radius": "x"}, "grid_radius must be a finite radius"),
        ({"window": "ab"}, "window must be two finite half-sizes"),
        ({"cell": [0.1, 0.2]}, "cell must be a finite size > 0 m"),
        ({"device": "cuda:99"}, "device 'cuda:99' is not available"),
        # k 0 or -1 returned one pose, 2.5 failed as a slice index; num_points -5 failed inside torch, 0 fed all
        ({"k": 0}, r"k \(top poses returned\) must be an int >= 1, got 0"),
        ({"k": -1}, r"k \(top poses returned\) must be an int >= 1, got -1"),
        ({"k": 2.5}, r"k \(top poses returned\) must be an int >= 1, got 2.5"),
        ({"num_points": -5}, "num_points must be an int >= 1, or None for every point, got -5"),
        ({"num_points": 0}, "num_points must be an int >= 1, or None for every point, got 0"),
    ]
    for kwargs, message in cases:
        with pytest.raises(ValueError, match=message):
            predict_from_points("no-such-model-is-loaded", xyz, feat, None, robot, t, **kwargs)
    with pytest.raises(ValueError, match="robot must be the robot's descriptor numbers, got 'ur5e'"):
        predict_from_points("no-such-model-is-loaded", xyz, feat, None, "ur5e", t)
    bad = xyz.copy()
    bad[:3] = np.nan
    with pytest.raises(ValueError, match="3 of .* points with NaN/Inf coordinates"):
        predict_from_points("no-such-model-is-loaded", bad, feat, None, robot, t)


def test_the_default_depth_cut_is_the_generators():
    """predict kept pixels up to 5 m while every generation preset drops depth beyond 4 m: a deployed model was given
    points farther than any it was trained on."""
    from floaff_zoo.predict import MAX_DEPTH
    from floaff_zoo.sim.presets import PRESETS

    assert {p.depth_max for p in PRESETS.values()} == {MAX_DEPTH}
    depth, k, pose = _floor_depth()
    far = np.full_like(depth, 4.5)
    _, valid = backproject_depth(far, k, pose)
    assert not valid.any()


def test_free_k_stands_on_the_best_pose_whose_footprint_is_free():
    """predict returned the raw argmax while `floaff-zoo test` (the benchmark's protocol) stands on the best of the
    top 10 poses whose footprint the view's cloud shows free: a robot builder could not get the evaluated choice."""
    from floaff_zoo.floor import footprint_blocked

    xyz, feat, t = _scene()
    floor = np.array([[1.0, -0.5, 0.0], [0.9, 0.6, 0.0], [0.7, 0.0, 0.0]], np.float32)

    class Ranked(ConstantModule):
        def forward(self, batch):  # the first candidate scores best, then the second, then the third
            return torch.tensor([[0.9, 0.8, 0.7]]) + 0.0 * self.net.weight.sum()

    box = np.c_[np.random.default_rng(1).uniform(-0.15, 0.15, (50, 2)) + [1.0, -0.5], np.full(50, 0.3)]
    cloud = np.r_[xyz, box].astype(np.float32)  # furniture where the first candidate's base would stand
    flags = np.r_[feat, np.zeros((50, 1), np.float32)]
    raw = predict_from_points(Ranked(), cloud, flags, floor, [0.85, 1.03], t, num_points=None)
    assert footprint_blocked(cloud, raw.best_pose) and raw.best_pose[:2] == pytest.approx((1.0, -0.5))
    free = predict_from_points(Ranked(), cloud, flags, floor, [0.85, 1.03], t, num_points=None, free_k=3)
    assert not footprint_blocked(cloud, free.best_pose) and free.best_pose[:2] == pytest.approx((0.9, 0.6))
    assert free.top_poses == raw.top_poses  # the ranking itself does not change
    with pytest.raises(ValueError, match="free_k must be an int >= 1"):
        predict_from_points(Ranked(), cloud, flags, floor, [0.85, 1.03], t, free_k=0)


@pytest.mark.parametrize("base", [(0.0, 0.0, 0.0), (1.3, -0.4, 2.9), (-2.0, 0.5, -1.2)])
def test_pose_to_base_inverts_pose_to_world(base):
    from floaff_zoo.frames import pose_to_base, pose_to_world

    for pose in [(0.5, -0.2, 0.3), (1.5, 0.5, -3.0), (0.0, 0.0, math.pi)]:
        back = pose_to_base(pose_to_world(pose, base), base)
        assert back[:2] == pytest.approx(pose[:2], abs=1e-9)
        assert math.cos(back[2] - pose[2]) == pytest.approx(1.0)


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_frames_refuse_a_non_finite_pose_naming_it(bad):
    """A NaN base yaw turned every point NaN and a NaN pose came back with a NaN yaw; an infinite yaw failed in
    math.cos as "math domain error"; a NaN target gave a NaN heading."""
    from floaff_zoo.frames import base_to_world, facing_pose, heading_to, pose_to_base, pose_to_world

    good, worse = (1.0, 2.0, 0.5), (1.0, 2.0, bad)
    with pytest.raises(ValueError, match="base_to_world: base_pose_world must be 3 finite values"):
        base_to_world(np.zeros((2, 3)), worse)
    with pytest.raises(ValueError, match="pose_to_world: pose must be 3 finite values"):
        pose_to_world(worse, good)
    with pytest.raises(ValueError, match="pose_to_world: base_pose_world must be 3 finite values"):
        pose_to_world(good, worse)
    with pytest.raises(ValueError, match="pose_to_base: pose must be 3 finite values"):
        pose_to_base(worse, good)
    with pytest.raises(ValueError, match="pose_to_base: base_pose_world must be 3 finite values"):
        pose_to_base(good, worse)
    with pytest.raises(ValueError, match="facing_pose: pose must be 3 finite values"):
        facing_pose((bad, 0.0, 0.0), (1.0, 1.0))
    with pytest.raises(ValueError, match="heading_to: the base .* and target_world must be finite"):
        heading_to(0.0, 0.0, (bad, 1.0))
    for target in ((1.0,), "xy", None):  # an IndexError, a bare ValueError of float('x'), a TypeError
        with pytest.raises(ValueError, match="heading_to: target_world must hold the target's world"):
            facing_pose(good, target)
    assert pose_to_world(good, (0.0, 0.0, 0.0)) == pytest.approx(good)


def test_a_figure_without_its_kitchen_marks_the_rolled_out_pose():
    """A sim sample whose scene could not be rebuilt was drawn in the base frame with the argmax marked, under the
    title of the rolled-out pose's outcome (another pose with a top-k footprint check)."""
    from floaff_zoo.frames import pose_to_world
    from floaff_zoo.report.figures import FigureSample, drawn_pose

    base = (2.0, -1.0, 0.7)
    floor = np.array([[1.0, 0.0, 0.0], [1.5, 0.5, 0.0]])
    rolled = pose_to_world((1.5, 0.5, 0.2), base)  # not the argmax (the first cell scores higher)
    s = FigureSample(floor, np.zeros(2), np.array([0.9, 0.1]), np.array([2.0, 0.3, 0.5]), 0.0,
                     meta={"sim": {"base_pose_world": list(base)}}, chosen=rolled)  # fmt: skip
    assert drawn_pose(s, s.chosen, s.scores, None)[:2] == pytest.approx((1.5, 0.5))  # plain scatter: base frame
    assert drawn_pose(s, s.chosen, s.scores, base) == rolled  # over the kitchen: the world pose as given
    assert drawn_pose(s, None, s.scores, None)[:2] == pytest.approx((1.0, 0.0))  # nothing rolled out: the argmax


def test_a_figure_breaks_ties_as_predict_does():
    """Without a rolled-out pose the figure marked the first of equal scores (seed 0) for every sample, not the
    pose predict and the SR callback choose (their tie-break is seeded by the sample's index)."""
    from floaff_zoo.contract import best_pose
    from floaff_zoo.report.figures import FigureSample, drawn_pose

    rng = np.random.default_rng(0)
    floor = np.c_[rng.uniform(-1, 1, (50, 2)), np.zeros(50)]
    target, flat = np.array([2.0, 0.0, 0.5]), np.full(50, 0.5)
    marked = set()
    for index in (3, 7):
        s = FigureSample(floor, flat, flat, target, 0.0, meta={"index": index})
        chosen = best_pose(floor, flat, None, target, 1, seed=index)[0]
        assert drawn_pose(s, None, s.scores, None) == pytest.approx(chosen)
        marked.add(tuple(np.round(chosen[:2], 6)))
    assert len(marked) == 2


def test_figures_of_groups_whose_names_spell_one_file_name_are_all_kept(tmp_path):
    """write_figures counted per (task, view) but named files by their filename-safe spelling: "Close Drawer" and
    "Close_Drawer" (or task "a_b" view "c" and task "a" view "b_c") both wrote <prefix>_0.png, the later drawing over
    the earlier, and the report listed that file twice. A sample without meta raised AttributeError."""
    from floaff_zoo.report.figures import FigureSample, write_figures

    floor = np.c_[np.linspace(0, 1, 6), np.zeros(6), np.zeros(6)]
    groups = [("Close Drawer", "front"), ("Close_Drawer", "front"), ("a_b", "c"), ("a", "b_c")]
    samples = [FigureSample(floor, np.zeros(6), np.ones(6) * 0.5, np.array([2.0, 0, 0.5]), 0.0,
                            meta={"task": t, "view": v}) for t, v in groups]  # fmt: skip
    samples.append(FigureSample(floor, np.zeros(6), np.ones(6) * 0.5, np.array([2.0, 0, 0.5]), 0.0, meta=None))
    paths = write_figures(samples, tmp_path)
    names = ["Close_Drawer_front_0", "Close_Drawer_front_1", "a_b_c_0", "a_b_c_1", "task_view_0"]
    assert [p.stem for p in paths] == names
    assert sorted(p.stem for p in tmp_path.glob("*.png")) == sorted(names)


def test_a_figure_without_a_finite_score_is_drawn_without_a_pose(tmp_path):
    """A diverged model's NaN map (or a view without floor) raised best_pose's SampleError in write_figures, at the
    end of a finished test run, which then wrote no report; now the panel is drawn and says it marks no pose."""
    from floaff_zoo.report.figures import FigureSample, drawn_pose, write_figures

    floor, target = np.c_[np.linspace(0, 1, 6), np.zeros(6), np.zeros(6)], np.array([2.0, 0, 0.5])
    nan_map = FigureSample(floor, np.zeros(6), np.full(6, np.nan), target, 0.0, meta={"task": "T", "view": "front"})
    no_floor = FigureSample(np.zeros((0, 3)), np.zeros(0), np.zeros(0), target, 0.0, meta={"task": "T", "view": "side"})
    assert drawn_pose(nan_map, None, nan_map.scores, None) is None
    assert drawn_pose(nan_map, None, nan_map.label, None) is not None  # the ground truth still marks its best cell
    sim = {"base_pose_world": [0.0, 0.0, 0.0], "layout_id": 1, "style_id": 1}
    over_kitchen = FigureSample(floor, np.zeros(6), np.full(6, np.nan), target, 0.0, meta={"task": "T", "sim": sim})
    paths = write_figures([nan_map, no_floor, over_kitchen], tmp_path, outline_fn=lambda _: [np.eye(2)])
    assert [p.stem for p in paths] == ["T_front_0", "T_side_0", "T_view_0"]
    assert all(p.read_bytes()[:4] == b"\x89PNG" for p in paths)


def test_a_figure_sample_out_of_step_is_named():
    """Scores of another length failed in matplotlib at the drawing, naming no sample; a [M, 1] label broadcast."""
    from floaff_zoo.report.figures import FigureSample

    floor, ok, target = np.zeros((4, 3)), np.zeros(4), np.array([2.0, 0.0, 0.5])
    for args, said in (
        ((floor, ok, np.zeros(5), target), r"scores must be \[M=4\], got \[5\]"),
        ((floor, ok[:, None], ok, target), r"label must be \[M=4\], got \[4, 1\]"),
        ((floor[:, :2], ok, ok, target), r"floor_xyz must be \[M, 3\], got \[4, 2\]"),
        ((floor, ok, ok, target[:2]), r"target_xyz must be \[3\], got \[2\]"),
    ):
        with pytest.raises(ValueError, match=f"figure sample s7: {said}"):
            FigureSample(*args, 0.0, meta={"sample_id": "s7"})


def test_a_model_without_a_floor_map_is_named():
    """AxisNet (a yaw estimator) given to predict_from_points ended in an unrelated IndexError in the raster."""
    from floaff_zoo.models.axisnet import AxisNetModule

    xyz, feat, t = _scene()
    floor = np.array([[0.2, 0.0, 0.0], [1.0, 0.1, 0.0], [0.6, -0.5, 0.0]], np.float32)
    with pytest.raises(TypeError, match="AxisNetModule predicts no floor map"):
        predict_from_points(AxisNetModule(), xyz, feat, floor, [0.85, 1.03], t)


def test_predict_gives_the_callers_model_back_in_its_training_mode():
    """predict put the caller's model in eval mode (every submodule) and left it there: a training loop that
    called it to look at a map went on training with BatchNorm and dropout frozen."""
    xyz, feat, t = _scene()
    model = TinyPointNetModule(width=16).train()
    frozen = next(m for m in model.modules() if m is not model)
    frozen.eval()  # a caller's frozen part stays frozen
    modes = [m.training for m in model.modules()]
    predict_from_points(model, xyz, feat, None, [0.85, 1.03], t, num_points=256)
    assert [m.training for m in model.modules()] == modes and model.training and not frozen.training

    def refuse(batch):
        raise ValueError("refused batch")

    model.check_inputs = refuse  # a call that fails once the model is in eval mode gives it back too
    with pytest.raises(ValueError, match="refused batch"):
        predict_from_points(model, xyz, feat, None, [0.85, 1.03], t, num_points=256)
    assert [m.training for m in model.modules()] == modes


def test_a_max_depth_that_is_no_distance_is_named():
    """max_depth=nan invalidated every pixel and was reported as a target mask without valid depth."""
    depth, k, pose = _floor_depth()
    mask = np.zeros(depth.shape, bool)
    mask[20:24, 30:34] = True
    for bad in (float("nan"), 0.0, "5", True):  # text failed inside numpy as a UFuncTypeError
        with pytest.raises(ValueError, match="max_depth must be a number > 0"):
            predict(TinyPointNetModule(width=16), None, depth, k, pose, mask, [0.85, 1.03], max_depth=bad)


def test_nan_colour_where_depth_is_invalid_is_not_read():
    """A float rgb with NaN at pixels without depth (never back-projected) was refused as out of [0, 1]."""
    depth, k, pose = _floor_depth()
    mask = np.zeros(depth.shape, bool)
    mask[20:24, 30:34] = True
    rgb = np.full(depth.shape + (3,), 0.5, np.float32)
    rgb[depth == 0] = np.nan
    model = TinyPointNetModule(width=16, feat_channels=4)
    assert np.isfinite(predict(model, rgb, depth, k, pose, mask, [0.85, 1.03], num_points=256).scores).all()
    rgb[depth > 0] = 2.0  # a colour that is read is still checked
    with pytest.raises(ValueError, match=r"must hold values in \[0, 1\]"):
        predict(model, rgb, depth, k, pose, mask, [0.85, 1.03], num_points=256)


def test_a_transposed_k_a_non_rigid_pose_and_millimetre_depth_are_named():
    """A transposed 3x3 K and a scaled camera pose were taken as given (the robot parked elsewhere, no word);
    millimetre depth was named as a target mask without depth; max_depth None and a negative seed failed as bare
    TypeError / numpy ValueError naming no argument."""
    depth, (f, _, cx, cy), pose = _floor_depth()
    K = np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    pts, valid = backproject_depth(depth, K, pose, max_depth=20.0)
    ref, _ = backproject_depth(depth, (f, f, cx, cy), pose, max_depth=20.0)
    assert np.allclose(pts[valid], ref[valid])  # a proper K reads as (fx, fy, cx, cy)
    with pytest.raises(ValueError, match=r"K must be \[\[fx, s, cx\], \[0, fy, cy\], \[0, 0, 1\]\].*transposed"):
        backproject_depth(depth, K.T, pose)
    for bad in (pose * 2.0, pose @ np.diag([1.0, 1.0, -1.0, 1.0])):  # scaled; a reflection (det -1)
        with pytest.raises(ValueError, match="camera_pose must be a rigid camera-to-base transform"):
            backproject_depth(depth, K, bad)
    with pytest.raises(ValueError, match="max_depth must be a number > 0 metres"):
        backproject_depth(depth, K, pose, max_depth=None)
    mask = np.zeros(depth.shape, bool)
    mask[40:44, 30:34] = True  # floor pixels near the robot: valid in metres
    mm = (depth * 1000).astype(np.uint16)
    with pytest.raises(SampleError, match="beyond max_depth 4.0 m: depth must be in metres"):
        predict(ConstantModule(), None, mm, K, pose, mask, [0.85, 1.03])
    xyz, feat, t = _scene()
    for seed in (-1, 0.0, True):  # a float passed to torch's manual_seed named no argument either
        with pytest.raises(ValueError, match=f"seed must be an int >= 0, got {seed}"):
            predict_from_points("no-such-model-is-loaded", xyz, feat, None, [0.85, 1.03], t, seed=seed)
    with pytest.raises(ValueError, match="intrinsics must be finite"):  # NaN is named as such, not as transposed
        backproject_depth(depth, np.full((3, 3), np.nan), pose)


def test_a_k_with_skew_back_projects_through_its_skew():
    """A 3x3 K [[fx, s, cx], [0, fy, cy], [0, 0, 1]] with a skew s != 0 was read as (fx, fy, cx, cy): every point
    moved sideways by s * (v - cy) / fy * depth / fx without a word."""
    h, w, f, s = 48, 64, 50.0, 4.0
    cx, cy = w / 2, h / 2
    K = np.array([[f, s, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])
    pose = _cam_pose() @ np.diag([1.0, -1.0, -1.0, 1.0])  # OpenCV axes
    uu, vv = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    y = (vv - cy) / f
    rays = np.stack([(uu - cx - s * y) / f, y, np.ones_like(uu)], -1) @ pose[:3, :3].T  # K^-1 [u, v, 1], depth 1
    down = rays[..., 2] < 0
    depth = np.zeros((h, w))
    depth[down] = -pose[2, 3] / rays[down][:, 2]  # where each pixel's ray meets the floor
    truth = (pose[:3, 3] + rays * depth[..., None]).reshape(-1, 3)
    pts, valid = backproject_depth(depth, K, pose, "opencv", max_depth=20.0)
    assert valid.sum() > 1000 and np.allclose(pts[valid], truth[valid], atol=1e-9)
    plain, _ = backproject_depth(depth, (f, f, cx, cy), pose, "opencv", max_depth=20.0)
    no_skew = K.copy()
    no_skew[0, 1] = 0.0
    assert np.array_equal(backproject_depth(depth, no_skew, pose, "opencv", max_depth=20.0)[0], plain)
