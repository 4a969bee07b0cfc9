"""Headless rendering and depth back-projection (docs/background.md §5) on a throwaway scene with known geometry."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from floaff_zoo.sim import render

# camera at (0.5, 0, 0.5) looking along +x (camera -z = world +x, camera x = world -y, camera y = world +z);
# red box face at x = 1.7 (1.2 m away); blue marker box high up (image top) and green low (image bottom);
# a group-0 sphere right in front of the camera must be hidden
XML = """
<mujoco>
  <visual><global offwidth="96" offheight="96"/></visual>
  <worldbody>
    <light pos="0 0 3" castshadow="true"/>
    <geom name="floor" type="plane" size="5 5 .1" rgba=".5 .5 .5 1" group="1"/>
    <geom name="box" type="box" pos="2.0 0 0.5" size="0.3 0.25 0.2" rgba="1 0 0 1" group="1"/>
    <geom name="top" type="box" pos="1.6 0 1.2" size="0.05 0.3 0.1" rgba="0 0 1 1" group="1"/>
    <geom name="robotcol" type="sphere" pos="0.8 0 0.5" size="0.1" rgba="0 1 0 1" group="0"/>
    <camera name="cam" pos="0.5 0 0.5" xyaxes="0 -1 0 0 0 1" fovy="60"/>
  </worldbody>
</mujoco>
"""


@pytest.fixture(scope="module")
def scene():
    m = mujoco.MjModel.from_xml_string(XML)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    r = render.Renderer(m, 64, 64)
    yield m, d, r
    r.close()


def _gid(m, name):
    return mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, name)


def test_depth_and_backprojection_box_face(scene):
    m, d, r = scene
    res = r.render(d, "cam")
    assert res.rgb.shape == (64, 64, 3) and res.rgb.dtype == np.uint8
    assert res.depth.shape == (64, 64) and res.depth.dtype == np.float32
    # centre pixels see the red box face 1.2 m ahead (the group-0 sphere in between is hidden)
    c = res.depth[30:34, 30:34]
    assert np.allclose(c, 1.2, atol=2e-3), c
    assert np.all(res.geom_id[30:34, 30:34] == _gid(m, "box"))
    assert not np.any(res.geom_id == _gid(m, "robotcol"))
    pts, valid = render.backproject(res.depth, res.fovy, res.cam_pos, res.cam_mat, depth_max=5.0)
    p = pts.reshape(64, 64, 3)[30:34, 30:34]
    assert np.allclose(p[..., 0], 1.7, atol=2e-3)  # the face plane x = 2.0 - 0.3
    assert np.all(np.abs(p[..., 1]) < 0.1) and np.all(np.abs(p[..., 2] - 0.5) < 0.1)
    # every box pixel lands on the box surface
    box = (res.geom_id == _gid(m, "box")).reshape(-1) & valid
    q = pts[box]
    assert np.all(np.abs(q[:, 1]) <= 0.25 + 1e-2) and np.all(np.abs(q[:, 2] - 0.5) <= 0.2 + 1e-2)
    assert np.allclose(q[:, 0], 1.7, atol=1e-2)


def test_floor_points_at_zero_and_far_plane_masked(scene):
    m, d, r = scene
    res = r.render(d, "cam")
    pts, valid = render.backproject(res.depth, res.fovy, res.cam_pos, res.cam_mat, depth_max=5.0)
    floor = (res.geom_id == _gid(m, "floor")).reshape(-1) & valid
    assert floor.sum() > 50
    assert np.abs(pts[floor, 2]).max() < 2e-3  # MSAA off: no sub-pixel depth bias
    # background pixels (above the horizon, no geom) are beyond depth_max -> invalid
    bg = (res.geom_id == -1).reshape(-1)
    assert bg.sum() > 0 and not np.any(valid & bg)


def test_image_row_orientation(scene):
    m, d, r = scene
    res = r.render(d, "cam")
    rows_top = np.flatnonzero((res.geom_id == _gid(m, "top")).any(axis=1))
    rows_floor = np.flatnonzero((res.geom_id == _gid(m, "floor")).any(axis=1))
    assert rows_top.size and rows_floor.size
    # row 0 is the image top: the high box is above the floor in the image
    assert rows_top.max() < rows_floor.min() + 1 and rows_top.mean() < 32 < rows_floor.mean()
    # the blue box appears blue in RGB at its pixels (segmentation and RGB are aligned)
    px = res.rgb[res.geom_id == _gid(m, "top")].astype(float)
    assert px[:, 2].mean() > px[:, 0].mean() + 15 and px[:, 2].mean() > px[:, 1].mean() + 15


def test_bad_inputs(scene):
    m, d, r = scene
    with pytest.raises(KeyError, match="nope"):
        r.render(d, "nope")
    with pytest.raises(ValueError, match=r"\[H,W\]"):
        render.backproject(np.zeros(5), 60.0, np.zeros(3), np.eye(3))
    assert render.gl_backend() in ("egl", "osmesa")


def test_hide_geoms_for_one_frame(scene):
    m, d, r = scene
    top = _gid(m, "top")
    group = int(m.geom_group[top])
    res = r.render(d, "cam", hide_geoms=np.array([top]))
    assert not np.any(res.geom_id == top)
    assert int(m.geom_group[top]) == group  # restored
    assert np.any(r.render(d, "cam").geom_id == top)


def test_rendering_then_importing_lightning_keeps_the_process_alive():
    """Mesa's software GL loads the system libLLVM; Triton's LLVM loaded after it segfaulted the process on
    `import lightning` (torch._dynamo imports Triton), e.g. a generated view and then a fit in one Python session."""
    import subprocess
    import sys

    pytest.importorskip("triton")
    code = (
        "import mujoco\n"
        "from floaff_zoo.sim import render\n"
        "xml = \"<mujoco><worldbody><geom type='box' size='1 1 .1'/></worldbody></mujoco>\"\n"
        "m = mujoco.MjModel.from_xml_string(xml)\n"
        "render.Renderer(m, 16, 16)\n"
        "import lightning\n"
        "print('alive')\n"
    )
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and run.stdout.strip() == "alive", (run.returncode, run.stderr[-500:])


def test_closing_one_renderer_leaves_another_working(scene):
    """close() freed its GL objects in whichever context was current (another open Renderer's), whose renders then
    came back empty without an error."""
    m, d, r = scene
    before = r.render(d, "cam").depth
    other = render.Renderer(m, 64, 64)
    other.render(d, "cam")
    r.render(d, "cam")  # the module's renderer is current when the other one closes
    other.close()
    after = r.render(d, "cam").depth
    np.testing.assert_allclose(after, before, atol=1e-6)


@pytest.mark.parametrize("fovy", [float("nan"), 0.0, 180.0, -60.0, float("inf")])
def test_a_field_of_view_outside_0_180_is_refused(fovy):
    """A NaN fovy back-projected every pixel to NaN and reported each one valid; 0 or 180 made the points infinite,
    a negative one mirrored the image, all without a word."""
    with pytest.raises(ValueError, match="fovy_deg must be"):
        render.backproject(np.ones((4, 4)), fovy, np.zeros(3), np.eye(3))
    with pytest.raises(ValueError, match="fovy_deg must be"):
        render.camera_intrinsics(4, 4, fovy)


def test_a_nan_depth_max_is_refused():
    """It masked every point: an empty cloud without a word."""
    with pytest.raises(ValueError, match="depth_max must be"):
        render.backproject(np.ones((4, 4)), 60.0, np.zeros(3), np.eye(3), float("nan"))


@pytest.mark.parametrize(
    "kwargs,match",
    [
        (dict(height=float("nan")), "height must be an integer"),  # failed inside int() naming nothing
        (dict(height=1.5), "height must be an integer"),  # rendered one pixel row
        (dict(width=True), "width must be an integer"),
        (dict(hide_groups=(7,)), "hide_groups must be an integer >= 0 and <= 5"),  # bare IndexError
        (dict(hide_groups=(-1,)), "hide_groups must be an integer >= 0"),  # silently hid group 5
    ],
)
def test_renderer_refuses_a_bad_size_or_group(scene, kwargs, match):
    m = scene[0]
    with pytest.raises(ValueError, match=match):
        render.Renderer(m, **{"height": 16, "width": 16, **kwargs})


def test_render_refuses_a_bad_camera_index_or_hidden_geom(scene):
    """Camera 0.5 rendered camera 0 and True camera 1; hide_geoms -1 hid the last geom and 1.7 geom 1, without a word;
    one past the end failed with a bare IndexError. Every camera that is not one is a KeyError, as an unknown name."""
    m, d, r = scene
    for bad in (0.5, True, -1, m.ncam):
        with pytest.raises(KeyError, match=rf"camera must be an integer >= 0 and <= {m.ncam - 1}"):
            r.render(d, bad)
    for bad in ([-1], [1.7], [m.ngeom]):
        with pytest.raises(ValueError, match="hide_geoms must be geom ids"):
            r.render(d, "cam", hide_geoms=bad)
    assert r.render(d, "cam", hide_geoms=[]).rgb.shape == (64, 64, 3)


@pytest.mark.parametrize(
    "cam_pos,cam_mat",
    [
        (np.array([np.nan, 0.0, 0.0]), np.eye(3)),  # every point NaN, each reported valid
        (np.zeros(3), np.full((3, 3), np.inf)),
        (np.zeros(2), np.eye(3)),  # numpy's broadcast error named neither
        (np.zeros(3), np.eye(2)),  # numpy's reshape error
    ],
)
def test_backproject_refuses_a_camera_pose_that_is_not_finite_3d(cam_pos, cam_mat):
    with pytest.raises(ValueError, match="backproject: cam_(pos|mat) must be"):
        render.backproject(np.ones((4, 4)), 60.0, cam_pos, cam_mat)


def test_backproject_refuses_an_empty_depth_image():
    with pytest.raises(ValueError, match=r"non-empty \[H,W\]"):
        render.backproject(np.ones((0, 4)), 60.0, np.zeros(3), np.eye(3))


@pytest.mark.parametrize("size", [float("nan"), -5, 0, 2.5, True])
def test_camera_intrinsics_refuses_a_size_that_is_no_pixel_count(size):
    """NaN gave a NaN focal length, -5 a negative one (a mirrored cloud), 0 a zero one, without a word."""
    with pytest.raises(ValueError, match="camera_intrinsics: height must be an integer >= 1"):
        render.camera_intrinsics(size, 4, 60.0)
    with pytest.raises(ValueError, match="camera_intrinsics: width must be an integer >= 1"):
        render.camera_intrinsics(4, size, 60.0)
