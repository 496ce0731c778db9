"""Off-screen JPEG frames through EGL (skipped with the reason where EGL cannot start)."""

from __future__ import annotations

import io

import mujoco
import numpy as np
import pytest
from PIL import Image

from ag_uav.record.render import Renderer, RenderUnavailable, optical_quat

XML = """
<mujoco>
  <worldbody>
    <light pos="0 0 20" dir="0 0 -1" directional="true"/>
    <geom type="plane" size="50 50 0.1" rgba=".3 .6 .3 1"/>
    <body name="drone" pos="0 0 3">
      <freejoint/>
      <geom type="box" size=".5 .5 .15" rgba=".1 .1 .9 1"/>
      <camera name="down" pos="0 0 -.2" xyaxes="0 -1 0 1 0 0" fovy="70"/>
    </body>
    <camera name="chase" mode="trackcom" pos="-5 0 5" xyaxes="0 -1 0 .7 0 .7" fovy="60"/>
  </worldbody>
</mujoco>"""


@pytest.fixture(scope="module")
def rig():
    m = mujoco.MjModel.from_xml_string(XML)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    try:
        r = Renderer(m, 160, 120, ("chase", "down"))
    except RenderUnavailable as e:
        pytest.skip(f"no off-screen rendering here: {e}")
    yield m, d, r
    r.close()


def _img(jpg: bytes) -> np.ndarray:
    return np.asarray(Image.open(io.BytesIO(jpg)).convert("RGB")).astype(int)


def test_jpeg_size_and_content(rig):
    m, d, r = rig
    jpg = r.jpeg(d, "chase", quality=80)
    assert jpg[:2] == b"\xff\xd8"
    img = _img(jpg)
    assert img.shape == (120, 160, 3)
    blue = (img[..., 2] > 150) & (img[..., 0] < 90) & (img[..., 1] < 90)
    assert blue.sum() > 30  # the drone's blue box is in view of the chase camera
    ys, xs = np.nonzero(blue)
    assert 40 < xs.mean() < 120  # ... near the middle of the image
    down = _img(r.jpeg(d, "down"))
    assert down[..., 1].mean() > down[..., 2].mean()  # green ground below
    assert r.fovy("down") == pytest.approx(70.0)


def test_frames_follow_the_body(rig):
    m, d, r = rig
    a = _img(r.jpeg(d, "down"))
    d.qpos[2] = 1.0  # lower: the ground fills more of the down view
    d.qpos[0] = 0.37
    mujoco.mj_forward(m, d)
    pos, q = r.camera_pose(d, "down")
    assert pos[2] == pytest.approx(0.8, abs=1e-9) and pos[0] == pytest.approx(0.37)
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, q)
    z_axis = R.reshape(3, 3)[:, 2]
    assert z_axis == pytest.approx([0, 0, -1], abs=1e-9)  # optical z looks down
    d.qpos[:3] = [0, 0, 3]
    mujoco.mj_forward(m, d)
    assert np.abs(_img(r.jpeg(d, "down")) - a).max() <= 10  # same pose, same frame (JPEG)


def test_optical_quat_of_identity_camera_looks_along_minus_z():
    q = optical_quat(np.eye(3))
    R = np.zeros(9)
    mujoco.mju_quat2Mat(R, q)
    R = R.reshape(3, 3)
    assert R[:, 2] == pytest.approx([0, 0, -1]) and R[:, 1] == pytest.approx([0, -1, 0])


def test_unknown_camera_and_unavailable_backend(monkeypatch):
    m = mujoco.MjModel.from_xml_string(XML)
    with pytest.raises(ValueError, match="not in model"):
        Renderer(m, 32, 24, ("nope",))

    def boom(*a, **k):
        raise RuntimeError("eglInitialize failed\nsecond line")

    monkeypatch.setattr(mujoco, "Renderer", boom)
    with pytest.raises(RenderUnavailable) as ei:
        Renderer(m, 32, 24, ("chase",))
    assert "\n" not in str(ei.value) and "eglInitialize failed" in str(ei.value)


def test_real_model_cameras_see_ground_and_drone():
    """Regression: MuJoCo's clip planes are relative to the model extent; unpinned, the down
    camera saw only sky and the chase camera lost the drone and the near ground. The field
    outline is scenery drawn into the scene, not part of the physics model."""
    import mujoco
    import numpy as np

    from ag_uav.config import Config
    from ag_uav.record.render import Renderer, RenderUnavailable
    from ag_uav.vehicle.mjcf import build_vehicle
    from ag_uav.world.mission import build_field, field_outline

    cfg = Config()
    veh = build_vehicle(cfg)
    scenery = field_outline(build_field(cfg))
    d = mujoco.MjData(veh.model)
    d.qpos[:3] = (20.0, 30.0, 3.0)
    d.qpos[3] = 1.0
    mujoco.mj_forward(veh.model, d)
    try:
        r = Renderer(veh.model, 160, 120, ("chase", "down"), scenery=scenery)
    except RenderUnavailable as e:
        pytest.skip(str(e))
    down, chase = r.rgb(d, "down"), r.rgb(d, "chase")
    r.close()
    # crop rows below: green-dominant, textured; chase: ground in the lower half, drone centred
    assert down[..., 1].mean() > down[..., 2].mean() and down.std() > 10
    assert chase[60:].mean() > 40
    # hide the drone's geoms: the centre of the chase view must change (the drone is there)
    veh.model.geom_rgba[veh.model.geom_bodyid == veh.body_id, 3] = 0.0
    hidden = Renderer(veh.model, 160, 120, ("chase",))
    empty = hidden.rgb(d, "chase")
    hidden.close()
    assert np.abs(chase[50:70, 70:90].astype(int) - empty[50:70, 70:90]).mean() > 10


def test_scenery_is_drawn_for_the_cameras_and_is_not_in_the_physics_model():
    """The field boundary is decor in the camera's scene: a down camera over a boundary edge sees
    yellow strips with ``scenery`` and none without, and the physics model of two fields is the
    same size (one MjData layout serves a batch over fields)."""
    import mujoco
    import numpy as np

    from ag_uav.config import Config
    from ag_uav.record.render import Renderer, RenderUnavailable
    from ag_uav.vehicle.mjcf import build_vehicle
    from ag_uav.world.mission import build_field, field_outline

    cfg = Config()
    veh = build_vehicle(cfg)
    outline = field_outline(build_field(cfg))
    a, b = np.asarray(outline[0])[:2]
    d = mujoco.MjData(veh.model)
    d.qpos[:2] = (a[:2] + b[:2]) / 2
    d.qpos[2], d.qpos[3] = 4.0, 1.0
    mujoco.mj_forward(veh.model, d)
    try:
        with_ = Renderer(veh.model, 160, 120, ("down",), scenery=outline)
    except RenderUnavailable as e:
        pytest.skip(str(e))
    without = Renderer(veh.model, 160, 120, ("down",))
    img_w, img_0 = with_.rgb(d, "down").astype(int), without.rgb(d, "down").astype(int)
    with_.close()
    without.close()

    def yellow(img):
        return int(((img[..., 0] > 180) & (img[..., 1] > 180) & (img[..., 2] < 120)).sum())

    assert yellow(img_w) > 50 and yellow(img_0) == 0
    other = Config()
    other.mission.field = "hole"
    m2 = build_vehicle(other).model
    assert (m2.ngeom, m2.nbody, m2.nq) == (veh.model.ngeom, veh.model.nbody, veh.model.nq)


def _state(m: mujoco.MjModel, d: mujoco.MjData) -> np.ndarray:
    s = np.empty(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(m, d, s, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    return s


#: a body whose centre of mass is off its frame, tracked by a camera (as the spray tank's
#: liquid moves the drone's centre of mass and its chase camera with it)
TRACKED = """
<mujoco>
  <worldbody>
    <light pos="0 0 20" dir="0 0 -1" directional="true"/>
    <geom type="plane" size="50 50 0.1" rgba=".3 .6 .3 1"/>
    <body name="drone" pos="0 0 3">
      <freejoint/>
      <inertial pos="0.2 0 0" mass="2" diaginertia=".1 .1 .1"/>
      <geom type="box" size=".5 .5 .15" rgba=".1 .1 .9 1" mass="0"/>
      <camera name="chase" mode="trackcom" pos="-4 0 2" xyaxes="0 -1 0 .5 0 .9"/>
    </body>
  </worldbody>
</mujoco>"""


def test_render_thread_gives_the_calling_thread_s_frames_in_order(rig):
    from ag_uav.record.render import RenderThread

    m = mujoco.MjModel.from_xml_string(TRACKED)
    r = Renderer(m, 160, 120, ("chase",))
    rt = RenderThread(m, 160, 120, ("chase",), body=1, depth=2)
    assert rt.cameras == ("chase",) and rt.fovy("chase") == pytest.approx(45.0)
    want, got = [], []
    d = mujoco.MjData(m)
    poses = set()
    for k in range(6):  # more moments than the queue holds: submit waits, nothing is lost
        d.qpos[:3] = (0.4 * k, -0.2 * k, 3.0 + 0.1 * k)
        mujoco.mj_forward(m, d)
        want.append((0.5 * k, [(c, r.jpeg(d, c), r.camera_pose(d, c)) for c in r.cameras]))
        poses.add(tuple(d.cam_xpos[0] - d.xpos[1]))
        rt.submit(0.5 * k, _state(m, d), d.ctrl, np.zeros(3))
        m.body_ipos[1, 0] += 0.5  # the centre of mass moves after the moment: not in its frame
        got += rt.done()
    got += rt.close()
    r.close()
    assert len(poses) == 6  # the camera followed the centre of mass: each moment differs
    assert [t for t, _ in got] == [t for t, _ in want]
    for (_, shots), (_, ref) in zip(got, want, strict=True):
        for (c, jpg, (pos, quat)), (c0, jpg0, (pos0, quat0)) in zip(shots, ref, strict=True):
            assert c == c0 and jpg == jpg0
            np.testing.assert_array_equal(pos, pos0)
            np.testing.assert_array_equal(quat, quat0)
    assert rt.close() == []


def test_render_thread_raises_what_the_renderer_raises(rig):
    from ag_uav.record.render import RenderThread

    m, _, _ = rig
    with pytest.raises(ValueError, match="camera 'nope' not in model"):
        RenderThread(m, 160, 120, ("nope",))
