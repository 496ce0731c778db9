"""The controllers' packed rows are what their Layouts say: the cascade's parameter and state
rows have the layouts' sizes, and each named field holds what the controller was built with and
what the last tick computed."""

from __future__ import annotations

import math

import numpy as np

from controllers import FPID, IT2FPID, PID
from controllers.attitude import (
    ATT_PARAMS,
    ATT_STATE,
    MIX_NMAX,
    MIX_PARAMS,
    MIX_STATE,
    WRENCH,
    GeometricAttitudeController,
    XMixer,
)
from controllers.axis import AX_NP, AX_NS, AXIS_PARAMS, AXIS_STATE, KIND_IT2, KIND_PID, KIND_T1
from controllers.cascade import ROW_PARAMS, ROW_STATE, PositionCascade
from controllers.fuzzy import HEIGHTS

A, S = AXIS_PARAMS.at, AXIS_STATE.at
ROTORS = [(0.2, -0.2), (-0.2, 0.2), (0.2, 0.2), (-0.2, -0.2)]
SPIN = [1, 1, -1, -1]


def _cascade() -> PositionCascade:
    axes = [PID(1.5, 0.25, 0.75, i_limit=2.0, u_limit=(-3.0, 4.0), d_tau=0.05),
            FPID(0.4, 0.3, 5.0, 1.2, cm=0.6, derivative="measurement"),
            IT2FPID(0.5, 0.2, 6.0, 0.8, cm=0.7, reducer="bmm", zeta=0.3,
                    heights=((0.3, 0.6, 0.9), (0.2, 0.5, 0.8)))]
    att = GeometricAttitudeController((0.02, 0.03, 0.05), wn=(9.0, 8.0, 3.0),
                                      zeta=(0.9, 0.8, 0.7))
    mix = XMixer(ROTORS, SPIN, 0.016, f_max=14.0)
    return PositionCascade(axes, 2.5, 9.81, att, mix, tilt_max=math.radians(25.0),
                           accel_feedforward=False, a_limit=5.5)


def test_the_blocks_have_the_sizes_the_kernels_index():
    assert AX_NP == AXIS_PARAMS.size == A.SIZE and AX_NS == AXIS_STATE.size == S.SIZE
    assert MIX_PARAMS.shape["ainv"] == (MIX_NMAX, WRENCH.size)
    assert ROW_PARAMS.shape["axes"] == (3, AX_NP) and ROW_STATE.shape["axes"] == (3, AX_NS)
    assert ROW_PARAMS.width["att"] == ATT_PARAMS.size and ROW_PARAMS.width["mix"] == MIX_PARAMS.size
    assert ROW_STATE.width["att"] == ATT_STATE.size and ROW_STATE.width["mix"] == MIX_STATE.size
    assert ROW_STATE.width["rd"] == 9 and HEIGHTS.SIZE == 6
    c = _cascade()
    assert c.params.shape == (ROW_PARAMS.size,) and c.state.shape == (ROW_STATE.size,)


def test_named_fields_hold_what_the_cascade_was_built_with():
    c = _cascade()
    P = c.params
    ax = P[ROW_PARAMS.slice("axes")].reshape(ROW_PARAMS.shape["axes"])
    assert [ax[k, A.TYPE] for k in range(3)] == [KIND_PID, KIND_T1, KIND_IT2]
    assert (ax[0, A.G0], ax[0, A.G1], ax[0, A.G3]) == (1.5, 0.75, 0.25)  # Kp, Kd, Ki
    assert (ax[0, A.ILIM], ax[0, A.UMIN], ax[0, A.UMAX], ax[0, A.DTAU]) == (2.0, -3.0, 4.0, 0.05)
    assert (ax[1, A.G0], ax[1, A.G1], ax[1, A.G2], ax[1, A.G3], ax[1, A.CM]) == (
        0.4, 0.3, 5.0, 1.2, 0.6)
    assert ax[1, A.ONMEAS] == 1.0 and ax[0, A.ONMEAS] == 0.0
    assert tuple(ax[2, A.HN1:A.HP2_END]) == (0.3, 0.6, 0.9, 0.2, 0.5, 0.8)
    assert (ax[2, A.RED], ax[2, A.ZETA]) == (2.0, 0.3)
    R = ROW_PARAMS.at
    assert (P[R.MASS], P[R.G], P[R.TILT], P[R.FF], P[R.ALIM]) == (
        2.5, 9.81, math.radians(25.0), 0.0, 5.5)
    att = P[ROW_PARAMS.slice("att")]
    assert tuple(att[ATT_PARAMS.slice("j")]) == (0.02, 0.03, 0.05)
    assert np.allclose(att[ATT_PARAMS.slice("kr")], [0.02 * 81, 0.03 * 64, 0.05 * 9], rtol=1e-15)
    mix = P[ROW_PARAMS.slice("mix")]
    M = MIX_PARAMS.at
    assert (mix[M.FMAX], mix[M.N]) == (14.0, 4.0)
    ainv = mix[M.AINV:M.AINV_END].reshape(MIX_PARAMS.shape["ainv"])[:4]
    assert np.allclose(ainv, np.linalg.inv(c.mixer.A), rtol=0, atol=1e-12)


def test_named_state_fields_hold_the_last_tick():
    c = _cascade()
    I = np.eye(3).ravel().tolist()  # noqa: E741
    f = c.update((0.0, 0.0, 1.0), (0.1, 0.0, 0.0), I, (0.0, 0.0, 0.0), (1.0, -2.0, 3.0),
                 (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 0.3, 0.01)
    St = c.state
    RS = ROW_STATE.at
    assert tuple(St[RS.ACMD:RS.ACMD_END]) == c.a_cmd
    assert (St[RS.THRUST], St[RS.TILT]) == (c.thrust, c.tilt)
    assert tuple(St[RS.RD:RS.RD_END]) == c.R_d
    ax = St[ROW_STATE.slice("axes")].reshape(ROW_STATE.shape["axes"])
    assert (ax[0, S.ERR], ax[1, S.ERR], ax[2, S.ERR]) == (1.0, -2.0, 2.0)  # e = p_ref − p
    assert ax[0, S.UOUT] == c.axes[0].u and ax[2, S.I] == c.axes[2].integral
    assert tuple(St[RS.ATT:RS.ATT_END][ATT_STATE.slice("er")]) == c.attitude.eR
    assert St[RS.MIX + MIX_STATE.at.SAT] == float(c.mixer.saturated)
    assert len(f) == 4 and all(v >= 0.0 for v in f)
