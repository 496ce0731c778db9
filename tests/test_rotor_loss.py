"""The three-rotor law of a quad (controllers.rotor_loss): its relaxed hover balances the spin's
gyroscopic torque, its LQR closes the reduced-attitude loop, and on a rigid body (Euler's
equations, the motors' first-order lag, the rotors' yaw damping) it holds a spinning quad and
lands it below 1 m/s."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controllers.rotor_loss import RelaxedHover, expm

A = 0.3164  # the M350's rotor offset along x and y (m)
XY = [(A, -A), (A, A), (-A, A), (-A, -A)]
SPIN = [1, -1, 1, -1]
K_YAW, F_MAX, MASS, G = 0.016, 31.735, 7.8, 9.81
J = np.array([0.2817, 0.3048, 0.5648]) * MASS / 6.47
TAU_M, GAMMA = 0.04, 0.0088


def _law() -> RelaxedHover:
    return RelaxedHover(XY, 0, F_MAX, J, TAU_M, MASS, G)


@pytest.mark.parametrize("r", [-30.0, -12.0, 8.0, 25.0])
def test_the_relaxed_hover_balances_the_gyroscopic_torque(r):
    law = _law()
    tau, w, n, f_sum = law.hover(MASS * G, r)
    om = np.array([w[0], w[1], r])
    gyro = np.cross(om, J * om)
    assert tau == pytest.approx(gyro[:2], abs=1e-9)            # J ω̇ = τ − ω × Jω = 0
    assert np.cross(n, om) == pytest.approx(np.zeros(3), abs=1e-9) and n[2] > 0.8
    f3 = law.allocate(f_sum, tau)
    xy = np.array(XY)[law.live]
    assert f3.sum() == pytest.approx(f_sum)
    assert [xy[:, 1] @ f3, -(xy[:, 0] @ f3)] == pytest.approx(list(tau))
    assert f3.max() <= F_MAX and f3.min() >= 0.0


def test_the_opposite_rotor_is_the_stopped_ones_diagonal():
    law = RelaxedHover(XY, 2, F_MAX, J, TAU_M, MASS, G)
    assert law.opp == 0 and sorted(law.pair) == [1, 3]


@pytest.mark.parametrize("r", [-40.0, -15.0, -4.0, 6.0, 30.0])
def test_the_lqr_closes_the_reduced_attitude_loop(r):
    law = _law()
    n = law.hover(MASS * G, r)[2]
    K = law.gain(r, float(n[2]), 0.01)
    # the same discretisation the law uses, closed with its gain: every pole inside the circle
    Ad, Bd = _discrete(law, r, float(n[2]), 0.01)
    assert np.abs(np.linalg.eigvals(Ad - Bd @ K)).max() < 0.999


def _discrete(law: RelaxedHover, r: float, nz: float, dt: float) -> tuple[np.ndarray, ...]:
    Ix, Iy, Iz = J
    Ac = np.zeros((6, 6))
    Ac[0, 1], Ac[0, 4], Ac[1, 0], Ac[1, 5] = (Iy - Iz) * r / Ix, 1 / Ix, (Iz - Ix) * r / Iy, 1 / Iy
    Ac[2, 3], Ac[2, 1], Ac[3, 0], Ac[3, 2] = r, -nz, nz, -r
    Ac[4, 4] = Ac[5, 5] = -1 / TAU_M
    Z = np.zeros((8, 8))
    Z[:6, :6] = Ac * dt
    Z[4, 6] = Z[5, 7] = dt / TAU_M
    E = expm(Z)
    assert np.allclose(expm(np.diag([0.3, -2.0])), np.diag(np.exp([0.3, -2.0])))
    return E[:6, :6], E[:6, 6:]


def _skew(x: np.ndarray) -> np.ndarray:
    return np.array([[0, -x[2], x[1]], [x[2], 0, -x[0]], [-x[1], x[0], 0]])


def _fly(law: RelaxedHover, r0: float, z0: float, seconds: float, descend: bool,
         kick: float = 0.4) -> dict:
    """A rigid quad, rotor 0 stopped, from the relaxed hover at spin ``r0`` with a rate kick;
    the reference holds ``z0`` or descends as the engine's landing does (0.7 m/s, 0.3 m/s over
    the last 1.5 m). Returns the worst tilt, the height error and the touchdown speed."""
    dt, h = 0.01, 0.002
    tau_b, w_b, n_b, f_sum = law.hover(MASS * G, r0)
    w = np.array([w_b[0] + kick, w_b[1] - kick, r0])
    x = np.cross([0.0, 1.0, 0.0], n_b)
    x /= np.linalg.norm(x)
    R = np.array([x, np.cross(n_b, x), n_b])  # body → world, its third row n̄: R^T e_z = n̄
    f = np.zeros(4)
    f[law.live] = law.allocate(f_sum, tau_b)
    law.tau_est[:] = tau_b
    p, v, zr = np.array([0.0, 0.0, z0]), np.zeros(3), z0
    out = {"tilt": 0.0, "dz": 0.0, "touchdown": None}
    xy = np.array(XY)
    for _ in range(round(seconds / dt)):
        if descend:
            zr = max(zr - (0.7 if zr > 1.5 else 0.3) * dt, -0.5)
        vr = -(0.7 if zr > 1.5 else 0.3) if descend and zr > -0.5 else 0.0
        cmd = law.update(np.r_[[0.0, 0.0, zr] - p, [0.0, 0.0, vr] - v], dt, R.ravel(), w)
        for _ in range(round(dt / h)):
            f += (cmd - f) * h / TAU_M
            tau = np.array([xy[:, 1] @ f, -(xy[:, 0] @ f),
                            K_YAW * (np.array(SPIN) @ f) - GAMMA * w[2]])
            v = v + (R[:, 2] * f.sum() / MASS - [0.0, 0.0, G]) * h
            p = p + v * h
            w = w + (tau - np.cross(w, J * w)) / J * h
            U, _, Vt = np.linalg.svd(R @ (np.eye(3) + _skew(w) * h))
            R = U @ Vt
        out["tilt"] = max(out["tilt"], math.degrees(math.acos(min(1.0, R[2, 2]))))
        out["dz"] = max(out["dz"], abs(p[2] - zr))
        if p[2] <= 0.0:
            out["touchdown"] = -v[2]
            break
    return out


def test_the_law_holds_a_spinning_quad():
    """The natural spin of rotor 0 stopped is negative (the pair's yaw torque wins)."""
    o = _fly(_law(), -15.0, 10.0, 4.0, descend=False)
    assert o["tilt"] < 20.0 and o["dz"] < 0.3 and o["touchdown"] is None


def test_the_law_lands_a_spinning_quad_below_1_mps():
    o = _fly(_law(), -15.0, 6.0, 20.0, descend=True)
    assert o["touchdown"] is not None and o["touchdown"] < 1.0 and o["tilt"] < 25.0


def test_spinning_up_the_opposite_rotor_only_brakes_and_the_pair_spins_the_quad():
    """Before the spin balances the opposite rotor's least share, its push would only add
    momentum about the pair's diagonal: it pushes only against a body rate, no more than that
    rate's momentum over its lag; the pair flies at its share of the limit (the yaw torque)."""
    law = _law()
    law.hover(MASS * G, 0.5)
    assert not law.spun
    u = law.u_o
    assert law.opposite_cap(0.5 * u, 0.01) == 0.0
    i_u = J[0] * u[0] ** 2 + J[1] * u[1] ** 2
    assert law.opposite_cap(-0.5 * u, 0.01) == pytest.approx(
        i_u * 0.5 / (law.arm_o * (TAU_M + 0.01)))
    f = law.update(np.zeros(6), 0.01, np.eye(3).ravel(), [0.3 * u[0], 0.3 * u[1], 0.5])
    assert f[law.opp] == 0.0 and f[law.failed] == 0.0
    assert f[law.pair].sum() == pytest.approx(2 * law.F_SHARE * F_MAX)
    law.hover(MASS * G, -15.0)
    assert law.spun and law.opposite_cap(0.5 * u, 0.01) == F_MAX
