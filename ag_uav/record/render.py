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

``fast=True`` (default) turns off shadows, reflections, skybox and multisampling: ~110 frames/s
instead of ~15-19 at 320x240 on llvmpipe.  If the GL context cannot be created,
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

__all__ = ["Renderer", "RenderUnavailable", "optical_quat"]


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


def _quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


# MuJoCo cameras look along -z with y up; the optical convention (Foxglove, ROS) looks along +z
# with y down: rotate 180 degrees about the camera's x axis.
_FLIP_X = np.array([0.0, 1.0, 0.0, 0.0])


def optical_quat(cam_xmat: np.ndarray) -> np.ndarray:
    """World orientation (wxyz) of the optical frame of a MuJoCo camera with ``cam_xmat``."""
    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.asarray(cam_xmat, dtype=float).reshape(9))
    return _quat_mul(q, _FLIP_X)


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
