"""Headless MuJoCo rendering: RGB, metric depth, geom segmentation and back-projection.

The OpenGL back end is chosen once per process: ``MUJOCO_GL`` if set (``egl`` or ``osmesa``), else EGL with an OSMesa
fallback. ``MUJOCO_GL=egl`` is exported before mujoco is imported (when unset) because mujoco and robosuite read it
at import time (docs/background.md §5). The GL context is created here directly (not via ``mujoco.Renderer``), so
rendering works even when mujoco was imported earlier with an unusable default (glfw) back end.

Back-projection follows docs/background.md §5 (depth to points): the camera looks along its -z with x right, y up;
depth is metric along the viewing axis; background pixels return the far plane and are masked with ``depth_max``.
"""

from __future__ import annotations

import atexit
import importlib.util
import os
import sys
import weakref

os.environ.setdefault("MUJOCO_GL", "egl")

from dataclasses import dataclass  # noqa: E402

import numpy as np  # noqa: E402

from floaff_zoo.checks import check_flag, check_integer, check_number, is_number  # noqa: E402

try:
    import mujoco  # noqa: E402
except (ImportError, AttributeError) as _exc:  # e.g. MUJOCO_GL=osmesa without libosmesa6: PyOpenGL finds no GL
    raise ImportError(
        f"importing mujoco failed with MUJOCO_GL={os.environ.get('MUJOCO_GL')!r} ({type(_exc).__name__}: {_exc}). "
        "Use MUJOCO_GL=egl (Debian package libegl1, plus libegl-mesa0 without a GPU) or MUJOCO_GL=osmesa "
        "(Debian package libosmesa6)."
    ) from _exc

__all__ = [
    "GLBackendError",
    "RenderResult",
    "Renderer",
    "backproject",
    "camera_intrinsics",
    "gl_backend",
    "near_clip",
]

_BACKENDS = ("egl", "osmesa")
#: geom group that is never drawn; ``render(hide_geoms=...)`` moves geoms there for one frame
HIDDEN_GROUP = 5
_chosen_backend: str | None = None
_live_renderers: "weakref.WeakSet[Renderer]" = weakref.WeakSet()


_atexit_registered = False


def _close_all() -> None:
    # free GL contexts before the back end's own atexit (eglTerminate) runs; atexit is LIFO, so this is registered
    # after the first context exists (otherwise EGLError noise from GLContext.__del__ at interpreter teardown)
    for r in list(_live_renderers):
        r.close()


class GLBackendError(RuntimeError):
    """No headless OpenGL back end could create a context."""


def _context_class(name: str) -> type:
    """Import the GLContext class of one back end (import may fail when its library is missing)."""
    if name == "egl":
        from mujoco.egl import GLContext
    elif name == "osmesa":
        from mujoco.osmesa import GLContext
    else:
        raise GLBackendError(f"MUJOCO_GL={name!r} is not a headless back end; use MUJOCO_GL=egl or MUJOCO_GL=osmesa")
    return GLContext


def _candidate_backends() -> list[str]:
    """Back ends to try, in order: an explicit MUJOCO_GL (egl/osmesa) first, then the other one."""
    env = os.environ.get("MUJOCO_GL", "").strip().lower()
    if env in _BACKENDS:
        return [env] + [b for b in _BACKENDS if b != env]
    return list(_BACKENDS)


def _load_triton_first() -> None:
    """Import Triton, where it is installed, before the first GL context. Mesa's software drivers (EGL without a GPU,
    OSMesa) load the system's libLLVM into the process, and Triton's own LLVM, loaded after it, crashes the process
    with a segfault in ``import triton``, which ``torch._dynamo`` (so Lightning) runs when first imported: rendering
    and then training in one process died. Loaded the other way round, both work."""
    if "triton" in sys.modules or importlib.util.find_spec("triton") is None:
        return
    try:
        import triton  # noqa: F401
    except Exception:  # noqa: BLE001 - a broken Triton install is for whoever uses it to report, not the renderer
        pass


def _make_context(width: int, height: int):
    """Create and make current a headless GL context; remembers the back end that worked."""
    global _chosen_backend
    _load_triton_first()
    order = [_chosen_backend] if _chosen_backend else _candidate_backends()
    errors: list[str] = []
    for name in order:
        try:
            ctx = _context_class(name)(width, height)
            ctx.make_current()
        except Exception as exc:  # noqa: BLE001 - any failure means "try the next back end"
            errors.append(f"{name}: {type(exc).__name__}: {exc}")
            continue
        _chosen_backend = name
        global _atexit_registered
        if not _atexit_registered:
            atexit.register(_close_all)
            _atexit_registered = True
        return ctx
    raise GLBackendError(
        "No headless OpenGL back end works for MuJoCo rendering (tried "
        + ", ".join(order)
        + "). Set MUJOCO_GL=egl (needs the Debian package libegl1, plus libegl-mesa0 without a GPU) or "
        "MUJOCO_GL=osmesa (needs the Debian package libosmesa6) before starting Python. Errors: " + "; ".join(errors)
    )


def gl_backend() -> str | None:
    """Name of the back end in use (``'egl'``/``'osmesa'``), or None before the first renderer was created."""
    return _chosen_backend


@dataclass
class RenderResult:
    """One rendered camera frame.

    rgb [H,W,3] uint8 (row 0 = top of the image); depth [H,W] float32 metric along the viewing axis;
    geom_id [H,W] int32 (-1 = background / non-geom); cam_pos [3], cam_mat [3,3] camera pose in world (columns = camera
    x right, y up, z backwards); fovy in degrees.
    """

    rgb: np.ndarray
    depth: np.ndarray
    geom_id: np.ndarray
    cam_pos: np.ndarray
    cam_mat: np.ndarray
    fovy: float


def near_clip(model: mujoco.MjModel) -> float:
    """Distance (m) of the near clipping plane every camera of ``model`` renders with: ``vis.map.znear`` is a fraction
    of the model's extent (MuJoCo's convention); a surface nearer the camera than this is cut away."""
    return float(model.vis.map.znear * model.stat.extent)


def camera_intrinsics(height: int, width: int, fovy_deg: float) -> tuple[float, float, float]:
    """Pinhole intrinsics (f, cx, cy) in pixels for square pixels: f = (H/2)/tan(fovy/2), principal point at centre.

    A fovy outside (0, 180) degrees raises ``ValueError`` (a NaN one made every back-projected point NaN, and each
    was still reported valid; 0 put every point on the camera's axis, 180 made them infinite, a negative one mirrored
    the image). A height or width that is not an integer >= 1 raises ``ValueError`` too (NaN gave a NaN focal length,
    a negative one a mirrored image)."""
    if not (is_number(fovy_deg) and 0.0 < fovy_deg < 180.0):
        raise ValueError(f"camera_intrinsics: fovy_deg must be a finite number > 0 and < 180, got {fovy_deg}")
    check_integer("height", height, 1, owner="camera_intrinsics")
    check_integer("width", width, 1, owner="camera_intrinsics")
    f = (height / 2.0) / np.tan(np.deg2rad(fovy_deg) / 2.0)
    return float(f), width / 2.0, height / 2.0


def backproject(
    depth: np.ndarray,
    fovy_deg: float,
    cam_pos: np.ndarray,
    cam_mat: np.ndarray,
    depth_max: float = 5.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Metric depth image -> world points.

    depth [H,W] metric along the camera axis; cam_pos [3]; cam_mat [3,3] (world-from-camera rotation).
    Returns points [H*W,3] float64 in world (row-major pixel order) and valid [H*W] bool
    (finite, 0 < d < depth_max: the far plane of background pixels is masked).
    A camera pose that is not a finite cam_pos [3] and cam_mat [3,3] raises ``ValueError`` (a NaN one made every point
    NaN, each still reported valid; a wrong shape failed in numpy naming neither).
    """
    # a NaN depth_max masked every point without a word
    check_number("depth_max", depth_max, strict=True, owner="backproject")
    depth = np.asarray(depth, dtype=np.float64)
    if depth.ndim != 2 or depth.size == 0:
        raise ValueError(f"depth must be a non-empty [H,W] image, got shape {depth.shape}")
    for name, value, shape in (("cam_pos", cam_pos, (3,)), ("cam_mat", cam_mat, (3, 3))):
        a = np.asarray(value)
        if a.shape != shape or a.dtype.kind not in "iuf" or not np.isfinite(a).all():
            raise ValueError(f"backproject: {name} must be {list(shape)} finite numbers, got {a.dtype} {a.shape}")
    h, w = depth.shape
    f, cx, cy = camera_intrinsics(h, w, fovy_deg)
    u = np.arange(w) + 0.5  # pixel centres
    v = np.arange(h) + 0.5
    uu, vv = np.meshgrid(u, v)
    xc = (uu - cx) * depth / f
    yc = -(vv - cy) * depth / f  # image rows grow downwards, camera y points up
    zc = -depth  # the camera looks along its -z
    pc = np.stack([xc, yc, zc], axis=-1).reshape(-1, 3)
    pw = pc @ np.asarray(cam_mat, dtype=np.float64).reshape(3, 3).T + np.asarray(cam_pos, dtype=np.float64)
    d = depth.reshape(-1)
    valid = np.isfinite(d) & (d > 0) & (d < depth_max)
    return pw, valid


class Renderer:
    """Offscreen renderer for one model: RGB + metric depth + geom segmentation from a named or indexed camera.

    ``hide_groups`` geom groups are not drawn (default: group 0 = robosuite's robot collision meshes,
    docs/background.md §5). Shadows and reflections are off (llvmpipe RGB is ~30x slower with shadows).
    """

    def __init__(
        self,
        model: mujoco.MjModel,
        height: int = 128,
        width: int = 128,
        hide_groups: tuple[int, ...] = (0,),
    ) -> None:
        # a NaN size failed inside int() naming nothing, 1.5 (or True) rendered a 1-pixel image
        check_integer("height", height, 1, owner="Renderer")
        check_integer("width", width, 1, owner="Renderer")
        groups = tuple(hide_groups)
        for g in groups:  # group 7 failed with a bare IndexError, -1 silently hid group 5 instead
            check_integer("hide_groups", g, 0, mujoco.mjNGROUP - 1, owner="Renderer")
        self.model = model
        self.height = int(height)
        self.width = int(width)
        # the offscreen buffer must be at least the image size
        if model.vis.global_.offwidth < width:
            model.vis.global_.offwidth = width
        if model.vis.global_.offheight < height:
            model.vis.global_.offheight = height
        self._gl = _make_context(self.width, self.height)
        # no multisampling: a resolved MSAA depth buffer holds one sub-sample (~0.4 px off the pixel centre), which
        # biases back-projection (floor points at z = 0.006 * distance instead of 0)
        samples = int(model.vis.quality.offsamples)
        model.vis.quality.offsamples = 0
        try:
            self._mjr = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150)
        finally:
            model.vis.quality.offsamples = samples
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._mjr)
        self._scene = mujoco.MjvScene(model, maxgeom=max(1000, 2 * model.ngeom + 100))
        self._opt = mujoco.MjvOption()
        for g in groups + (HIDDEN_GROUP,):
            self._opt.geomgroup[int(g)] = 0
        # sites (robosuite's grip-site cylinders, frames) are markers, not scene surfaces
        for g in range(len(self._opt.sitegroup)):
            self._opt.sitegroup[g] = 0
        self._cam = mujoco.MjvCamera()
        self._cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._pert = mujoco.MjvPerturb()
        self._rect = mujoco.MjrRect(0, 0, self.width, self.height)
        self._rgb = np.empty((self.height, self.width, 3), dtype=np.uint8)
        self._closed = False
        _live_renderers.add(self)

    # ------------------------------------------------------------------ helpers
    def _camera_id(self, camera: str | int) -> int:
        if isinstance(camera, str):
            cid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_CAMERA, camera)
            if cid < 0:
                raise KeyError(f"camera {camera!r} not found in the model")
            return int(cid)
        # one error type for every camera that is not one: 0.5 rendered camera 0 and True camera 1 without a word
        check_integer("camera", camera, 0, self.model.ncam - 1, owner="Renderer.render", error=KeyError)
        return int(camera)

    def _update(self, data: mujoco.MjData, cid: int, segment: bool) -> None:
        self._cam.fixedcamid = cid
        mujoco.mjv_updateScene(
            self.model, data, self._opt, self._pert, self._cam, mujoco.mjtCatBit.mjCAT_ALL, self._scene
        )
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = 0
        self._scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = 0
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = 0
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = int(segment)
        self._scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = int(segment)

    def _depth_to_metric(self, zbuf: np.ndarray) -> np.ndarray:
        """OpenGL depth buffer [H,W] in [0,1] -> metric distance along the camera axis (same as mujoco.Renderer)."""
        near = near_clip(self.model)
        far = self.model.vis.map.zfar * self.model.stat.extent
        return (near / (1.0 - zbuf * (1.0 - near / far))).astype(np.float32)

    # ------------------------------------------------------------------ API
    def render(
        self,
        data: mujoco.MjData,
        camera: str | int,
        segmentation: bool = True,
        hide_geoms: np.ndarray | None = None,
    ) -> RenderResult:
        """Render one frame. Call ``mj_forward`` (or step) first so cam_xpos/geom poses are current.

        hide_geoms [K] int: geom ids left out of this frame (e.g. the robot's own visual meshes), restored after.
        """
        if self._closed:
            raise RuntimeError("Renderer is closed")
        check_flag("segmentation", segmentation, owner="Renderer.render")  # the text "no" segmented
        cid = self._camera_id(camera)
        self._gl.make_current()
        hide = None if hide_geoms is None else self._geom_ids(hide_geoms)
        saved = None
        if hide is not None and hide.size:
            saved = self.model.geom_group[hide].copy()
            self.model.geom_group[hide] = HIDDEN_GROUP
        try:
            return self._render(data, cid, segmentation)
        finally:
            if saved is not None:
                self.model.geom_group[hide] = saved

    def _geom_ids(self, ids: np.ndarray) -> np.ndarray:
        """``hide_geoms`` [K] as int64 geom ids; one that is not a geom id of the model raises ``ValueError`` (-1 hid
        the last geom, 1.7 geom 1, one past the end failed with a bare IndexError)."""
        a = np.asarray(ids).reshape(-1)
        ok = a.dtype.kind in "iu" or (a.size == 0 and a.dtype.kind == "f")
        if not ok or ((a < 0) | (a >= self.model.ngeom)).any():
            raise ValueError(f"Renderer.render: hide_geoms must be geom ids in [0, {self.model.ngeom}), got {a[:8]}")
        return a.astype(np.int64)

    def _render(self, data: mujoco.MjData, cid: int, segmentation: bool) -> RenderResult:
        self._update(data, cid, segment=False)
        mujoco.mjr_render(self._rect, self._scene, self._mjr)
        zbuf = np.empty((self.height, self.width), dtype=np.float32)
        mujoco.mjr_readPixels(self._rgb, zbuf, self._rect, self._mjr)
        rgb = np.flipud(self._rgb).copy()  # OpenGL rows start at the bottom
        depth = np.flipud(self._depth_to_metric(zbuf)).copy()
        geom_id = np.full((self.height, self.width), -1, dtype=np.int32)
        if segmentation:
            geom_id = self._segment()
        return RenderResult(
            rgb=rgb,
            depth=depth,
            geom_id=geom_id,
            cam_pos=data.cam_xpos[cid].copy(),
            cam_mat=data.cam_xmat[cid].reshape(3, 3).copy(),
            fovy=float(self.model.cam_fovy[cid]),
        )

    def _segment(self) -> np.ndarray:
        """Geom id per pixel [H,W] int32 (-1 = none), from an ID-colour pass over the scene already updated."""
        self._update_segment_flags()
        seg = np.empty((self.height, self.width, 3), dtype=np.uint8)
        mujoco.mjr_render(self._rect, self._scene, self._mjr)
        mujoco.mjr_readPixels(seg, None, self._rect, self._mjr)
        seg = np.flipud(seg).astype(np.int64)
        idx = seg[..., 0] + (seg[..., 1] << 8) + (seg[..., 2] << 16) - 1  # scene-geom index, -1 = background
        # map visual-scene geom slots to model geom ids (only mjOBJ_GEOM entries)
        ng = self._scene.ngeom
        lut = np.full(ng + 1, -1, dtype=np.int32)
        for i in range(ng):
            g = self._scene.geoms[i]
            if g.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                lut[i] = g.objid
        idx = np.where((idx >= 0) & (idx < ng), idx, ng)
        return lut[idx].astype(np.int32)

    def _update_segment_flags(self) -> None:
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = 1
        self._scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = 1

    def close(self) -> None:
        """Free the GL resources (idempotent)."""
        if self._closed:
            return
        self._closed = True
        try:
            # the GL objects belong to this renderer's context: freed in another current context (another open
            # Renderer's) they would destroy that renderer's buffers, which then render empty clouds without an error
            self._gl.make_current()
            self._mjr.free()
        finally:
            try:
                self._gl.free()
            except Exception:  # noqa: BLE001 - freeing a context at shutdown may fail harmlessly
                # make the context's own __del__ a no-op so it does not raise again
                if hasattr(self._gl, "_context"):
                    self._gl._context = None

    def __enter__(self) -> "Renderer":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:  # noqa: BLE001
            pass
