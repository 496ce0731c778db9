"""Off-screen camera frames (JPEG) with MuJoCo's Renderer through EGL.

    r = Renderer(model, width=320, height=240, cameras=("chase", "down"))  # RenderUnavailable
    jpg = r.jpeg(data, "chase", quality=80)             # bytes
    pos, quat_wxyz = r.camera_pose(data, "chase")       # optical frame for /tf
    log.frame(t, "chase", jpg, r.width, r.height, r.fovy("chase"), pose=(pos, quat_wxyz))

Backend: MuJoCo picks its OpenGL backend from ``MUJOCO_GL`` when ``mujoco`` is first imported.
This module sets ``MUJOCO_GL=egl`` (and ``PYOPENGL_PLATFORM=egl``) as defaults *before* importing
mujoco, so import ``ag_uav.record.render`` (or set the variables yourself) before anything imports
mujoco.  If mujoco was already imported without a backend choice, the Renderer is switched to
EGL here when it is first constructed; an explicit other choice (``osmesa``, ``glfw``) is
respected.  On this kind of machine EGL is Mesa llvmpipe (CPU): no install needed.  In parallel
workers set ``LP_NUM_THREADS=1`` (llvmpipe uses every core otherwise).

``fast=True`` (default) turns off shadows, reflections, skybox and multisampling, the costly
parts on llvmpipe (what a frame costs: docs/speed.md, "Camera frames").  If the GL context
cannot be created,
:class:`RenderUnavailable` carries a one-line reason; the simulation then runs without frames.
"""

from __future__ import annotations

import io
import math
import os
from collections.abc import Sequence

os.environ.setdefault("MUJOCO_GL", "egl")
if os.environ["MUJOCO_GL"].lower() == "egl":
    os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from numkit.geometry import quat_mul  # noqa: E402

__all__ = ["RenderThread", "Renderer", "RenderUnavailable", "optical_quat"]


class RenderUnavailable(RuntimeError):
    """Off-screen rendering cannot start here; ``str(exc)`` is a one-line reason."""


def _ensure_backend() -> None:
    """Make mujoco's Renderer use EGL when MUJOCO_GL says egl but mujoco chose otherwise."""
    want = os.environ.get("MUJOCO_GL", "").lower().strip()
    try:
        from mujoco.rendering.classic import gl_context
    except ImportError:  # older layout: mujoco.gl_context
        from mujoco import gl_context  # type: ignore[no-redef]
    chosen = getattr(gl_context, "_MUJOCO_GL", want)
    if want == "egl" and chosen != "egl":
        try:
            from mujoco.egl import GLContext
        except Exception as e:  # noqa: BLE001
            raise RenderUnavailable(f"EGL backend unavailable: {type(e).__name__}: {e}") from e
        gl_context.GLContext = GLContext


# MuJoCo cameras look along -z with y up; the optical convention (Foxglove, ROS) looks along +z
# with y down: rotate 180 degrees about the camera's x axis.
_FLIP_X = np.array([0.0, 1.0, 0.0, 0.0])


def optical_quat(cam_xmat: np.ndarray) -> np.ndarray:
    """World orientation (wxyz) of the optical frame of a MuJoCo camera with ``cam_xmat``."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.asarray(cam_xmat, dtype=float).reshape(9))
    out = np.empty(4)
    quat_mul(q, _FLIP_X, out)
    return out


#: scenery strips: half-width (m), height above the ground (m), colour
STRIP_RADIUS, STRIP_Z, STRIP_RGBA = 0.12, 0.02, np.array([0.95, 0.95, 0.2, 1.0], np.float32)


def _strips(lines: Sequence[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    """(from, to) 3-D points of every non-degenerate edge of the closed ``lines``."""
    out = []
    for line in lines:
        pts = np.asarray(line, dtype=float)
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            if math.hypot(b[0] - a[0], b[1] - a[1]) >= 1e-6:
                out.append((np.array([a[0], a[1], STRIP_Z]), np.array([b[0], b[1], STRIP_Z])))
    return out


def _add_strips(scene: mujoco.MjvScene, strips: list[tuple[np.ndarray, np.ndarray]]) -> None:
    """Append the scenery capsules to ``scene`` after ``mjv_updateScene`` (decor geoms)."""
    capsule = int(mujoco.mjtGeom.mjGEOM_CAPSULE)
    zero, eye = np.zeros(3), np.eye(3).ravel()
    for a, b in strips[:scene.maxgeom - scene.ngeom]:
        g = scene.geoms[scene.ngeom]
        mujoco.mjv_initGeom(g, capsule, zero, zero, eye, STRIP_RGBA)
        mujoco.mjv_connector(g, capsule, STRIP_RADIUS, a, b)
        g.category = int(mujoco.mjtCatBit.mjCAT_DECOR)
        scene.ngeom += 1


class Renderer:
    """JPEG frames from named MJCF cameras.

    :param model: the MjModel (its offscreen buffer is enlarged if smaller than the image).
    :param width, height: image size in pixels.
    :param cameras: camera names that must exist in the model.
    :param fast: shadows, reflections, skybox and MSAA off (quick on a CPU rasteriser).
    :param scenery: closed polylines (local ENU metres: the field boundary, holes, obstacles)
        drawn on the ground as thin yellow strips. They are decor added to the camera's scene
        each frame, not geoms of the physics model, so the model a vehicle flies with does not
        depend on its field.
    :raises RenderUnavailable: no GL context (reason in the message).
    :raises ValueError: unknown camera name.
    """

    def __init__(self, model: mujoco.MjModel, width: int = 320, height: int = 240,
                 cameras: tuple[str, ...] | list[str] = ("chase", "down"), fast: bool = True,
                 scenery: Sequence[np.ndarray] = ()):
        self.width, self.height = int(width), int(height)
        self._strips = _strips(scenery)
        self.model = model
        self.cam_ids: dict[str, int] = {}
        for name in cameras:
            cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, name)
            if cid < 0:
                have = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_CAMERA, i)
                        for i in range(model.ncam)]
                raise ValueError(f"camera {name!r} not in model; cameras: {have}")
            self.cam_ids[name] = cid
        vis = model.vis
        vis.global_.offwidth = max(vis.global_.offwidth, self.width)
        vis.global_.offheight = max(vis.global_.offheight, self.height)
        old_samples = vis.quality.offsamples
        if fast:
            vis.quality.offsamples = 0
        _ensure_backend()
        try:
            self._r = mujoco.Renderer(model, height=self.height, width=self.width,
                                      max_geom=10_000 + len(self._strips))
        except Exception as e:  # noqa: BLE001 - any GL failure means "no frames"
            msg = " ".join(str(e).split())[:200]
            raise RenderUnavailable(
                f"off-screen rendering unavailable (MUJOCO_GL={os.environ.get('MUJOCO_GL')}): "
                f"{type(e).__name__}: {msg}") from e
        finally:
            vis.quality.offsamples = old_samples
        self._opt = mujoco.MjvOption()
        self.fast = fast
        if fast:
            flags = self._r.scene.flags
            flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
            flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
            flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = False

    @property
    def cameras(self) -> tuple[str, ...]:
        return tuple(self.cam_ids)

    def fovy(self, camera: str) -> float:
        """Vertical field of view of ``camera`` in degrees."""
        return float(self.model.cam_fovy[self.cam_ids[camera]])

    def rgb(self, data: mujoco.MjData, camera: str) -> np.ndarray:
        """(height, width, 3) uint8 image from ``camera`` (needs ``mj_forward``/``mj_step``
        to have run so that camera poses are current)."""
        self._r.update_scene(data, camera=self.cam_ids[camera], scene_option=self._opt)
        _add_strips(self._r.scene, self._strips)
        return self._r.render()

    def jpeg(self, data: mujoco.MjData, camera: str, quality: int = 80) -> bytes:
        """JPEG bytes of one frame from ``camera``."""
        from PIL import Image

        buf = io.BytesIO()
        Image.fromarray(self.rgb(data, camera)).save(buf, format="JPEG", quality=int(quality))
        return buf.getvalue()

    def camera_pose(self, data: mujoco.MjData, camera: str) -> tuple[np.ndarray, np.ndarray]:
        """(position, quaternion wxyz) of the camera's optical frame (z forward, y down)."""
        cid = self.cam_ids[camera]
        return data.cam_xpos[cid].copy(), optical_quat(data.cam_xmat[cid])

    def intrinsics(self, camera: str) -> tuple[float, float, float, float]:
        """(fx, fy, cx, cy) in pixels for the pinhole camera (square pixels)."""
        fy = 0.5 * self.height / math.tan(math.radians(self.fovy(camera)) / 2)
        return fy, fy, 0.5 * self.width, 0.5 * self.height

    def close(self) -> None:
        r = getattr(self, "_r", None)
        if r is not None:
            r.close()
            self._r = None

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_FULLPHYSICS = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
#: the model fields a spray job writes in flight (the liquid's mass, inertia, centre of mass)
_MASS_FIELDS = ("body_mass", "body_inertia", "body_ipos", "body_subtreemass")


class RenderThread:
    """A :class:`Renderer` in a thread of its own, so that the frames render while the
    simulation goes on: MuJoCo's rendering and the JPEG encoder release the GIL.

    :meth:`submit` hands it one moment (the physics state, what the physics was handed and the
    bodies' mass properties, which a spray job changes in flight, as copies); the thread sets its
    own copy of the model and its own ``MjData`` from them, runs ``mj_forward`` and renders every
    camera. :meth:`done` returns the finished moments in the order they were submitted, each as
    ``(t, [(camera, jpeg, pose), ...])``; :meth:`close` waits for the rest and returns them.
    At most ``depth`` moments wait (then :meth:`submit` waits for the thread), so memory stays
    bounded and the frames never fall far behind. The images are those the same state gives
    :class:`Renderer` in the calling thread. The GL context is made in the thread, which is
    where it is used; construction raises :class:`RenderUnavailable` as :class:`Renderer` does.
    """

    def __init__(self, model: mujoco.MjModel, width: int = 320, height: int = 240,
                 cameras: tuple[str, ...] | list[str] = ("chase", "down"),
                 scenery: Sequence[np.ndarray] = (), body: int = 1, depth: int = 8):
        import copy
        import queue
        import threading

        self.model, self.width, self.height, self.body = model, int(width), int(height), body
        self._own = copy.copy(model)  # the thread's: the caller's may change as it renders
        self._todo: queue.Queue = queue.Queue(maxsize=max(1, depth))
        self._done: queue.Queue = queue.Queue()
        self._ready = threading.Event()
        self._error: BaseException | None = None
        self._fovy: dict[str, float] = {}
        self.cameras: tuple[str, ...] = ()
        self._thread = threading.Thread(target=self._run, args=(tuple(cameras), scenery),
                                        name="ag-uav-render", daemon=True)
        self._thread.start()
        self._ready.wait()
        if self._error is not None:
            self._thread.join()
            raise self._error
        self._pending = 0

    def _run(self, cameras: tuple[str, ...], scenery: Sequence[np.ndarray]) -> None:
        try:
            r = Renderer(self._own, self.width, self.height, cameras, scenery=scenery)
        except BaseException as e:  # noqa: BLE001 - handed to the constructor's caller
            self._error = e
            self._ready.set()
            return
        self.cameras = r.cameras
        self._fovy = {c: r.fovy(c) for c in r.cameras}
        self._ready.set()
        m = self._own
        d = mujoco.MjData(m)
        try:
            while (item := self._todo.get()) is not None:
                t, state, ctrl, xf, mass = item
                try:
                    for field, value in zip(_MASS_FIELDS, mass, strict=True):
                        getattr(m, field)[:] = value
                    mujoco.mj_setState(m, d, state, _FULLPHYSICS)
                    d.ctrl[:] = ctrl
                    d.xfrc_applied[self.body, :3] = xf
                    mujoco.mj_forward(m, d)
                    self._done.put((t, [(c, r.jpeg(d, c), r.camera_pose(d, c))
                                        for c in r.cameras]))
                except BaseException as e:  # noqa: BLE001 - reported by done()/close()
                    self._done.put(e)
        finally:
            r.close()

    def fovy(self, camera: str) -> float:
        """Vertical field of view of ``camera`` in degrees."""
        return self._fovy[camera]

    def submit(self, t: float, state: np.ndarray, ctrl: np.ndarray, xf: np.ndarray) -> None:
        """Render every camera at ``t`` from the full physics state ``state``
        (``mjSTATE_FULLPHYSICS``), with ``ctrl``, the body force ``xf`` and the model's mass
        properties now (all copied here)."""
        mass = tuple(np.array(getattr(self.model, f)) for f in _MASS_FIELDS)
        self._todo.put((t, np.array(state), np.array(ctrl), np.array(xf), mass))
        self._pending += 1

    def done(self) -> list[tuple[float, list]]:
        """The moments rendered so far, oldest first (without waiting)."""
        import queue

        out = []
        while self._pending:
            try:
                item = self._done.get_nowait()
            except queue.Empty:
                break
            out.append(self._take(item))
        return out

    def _take(self, item):
        self._pending -= 1
        if isinstance(item, BaseException):
            raise item
        return item

    def close(self) -> list[tuple[float, list]]:
        """Wait for the moments still rendering, end the thread, return them (oldest first)."""
        if not self._thread.is_alive():
            return []
        self._todo.put(None)
        out = [self._take(self._done.get()) for _ in range(self._pending)]
        self._thread.join()
        return out
