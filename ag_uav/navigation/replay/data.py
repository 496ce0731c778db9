"""A recorded flight as the replay reads it, in the INS's own frames.

Every reader (:mod:`~ag_uav.navigation.replay.readers`) returns a :class:`FlightLog`:

* ``imu``: (n, 6) body-frame specific force f̃ (m/s²) and rate ω̃ (rad/s) at times ``imu_t``
  (s), in the INS's body axes **FLU** (x forward, y left, z up: +g on z at rest), as
  ``ag_uav/vehicle/imu.py`` reports them.  Autopilot logs are FRD (PX4, ArduPilot):
  ``frd_to_flu`` turns (x, y, z) into (x, −y, −z).
* ``gnss``: fixes at times ``gnss_t`` as local **ENU** metres about ``origin`` (lat °, lon °,
  h m; :func:`ag_uav.world.geodesy.lonlat_to_enu`, WGS-84), with the reported per-axis
  variances (m²) and, where the receiver gives it, the ENU velocity and its variance.
* ``reference`` (a track flown independently of the INS: an RTK record, a CSV's truth) and
  ``autopilot`` (the autopilot's own estimate: PX4 EKF2, ArduPilot EKF1): :class:`Track`.

World frames: a NED vector (n, e, d) is ENU (e, n, −d).  Attitudes are Hamilton quaternions
(w, x, y, z), FLU body → ENU world (MuJoCo's and the INS's); an autopilot's FRD → NED rotation
R_nf becomes R_ef = T R_nf T', T = ENU←NED = [[0,1,0],[1,0,0],[0,0,−1]], T' = FRD←FLU =
diag(1, −1, −1) (:func:`ned_frd_to_enu_flu`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from numkit import Layout, Z

#: an IMU row: specific force f̃ (m/s²) then rate ω̃ (rad/s), body FLU
IMU = Layout("acc:3 gyro:3").at
#: a row of the INS bank's output state (``BatchINS.x_out``): p, v (ENU), q (FLU → ENU), b_a, b_g
XOUT = Layout("pos:3 vel:3 quat:4 ba:3 bg:3").at
#: a processed fix (``ReplayResult.fix_events``): time, gate verdict, position and velocity NIS
EVENT = Layout("t verdict nis_pos nis_vel").at

__all__ = ["EVENT", "IMU", "XOUT", "ReplayError", "FlightLog", "Track", "frd_to_flu",
           "ned_frd_to_enu_flu"]

DEG = math.pi / 180.0
_T_EN = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
_T_FF = np.diag([1.0, -1.0, -1.0])


class ReplayError(ValueError):
    """A log the replay cannot use (one line naming the file and what is wrong; exit 2)."""


@dataclass
class Track:
    """A position/attitude track: ``t`` (n,), ``p`` (n, 3) ENU m (NaN where unknown), ``R`` (n,
    3, 3) FLU → ENU rotation (NaN where unknown), ``v`` (n, 3) ENU m/s or None; ``label``
    names it in tables; ``speed`` (n,) the horizontal speed the record logs beside its
    positions (m/s), or None."""

    t: np.ndarray
    p: np.ndarray
    R: np.ndarray | None = None
    v: np.ndarray | None = None
    label: str = "reference"
    speed: np.ndarray | None = None

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(p, R) linearly interpolated at ``t`` (NaN outside the track's span; R by the
        interpolated rotation matrix re-orthonormalised by SVD)."""
        t = np.asarray(t, dtype=float)
        out = np.full((t.size, 3), np.nan)
        inside = (t >= self.t[0]) & (t <= self.t[-1])
        for j in range(3):
            out[inside, j] = np.interp(t[inside], self.t, self.p[:, j])
        if self.R is None:
            return out, None
        R = np.full((t.size, 3, 3), np.nan)
        flat = self.R.reshape(-1, 9)
        M = np.stack([np.interp(t[inside], self.t, flat[:, j]) for j in range(9)], axis=1)
        M = M.reshape(-1, 3, 3)
        ok = np.all(np.isfinite(M), axis=(1, 2))
        if ok.any():
            u, _, vt = np.linalg.svd(M[ok])
            d = np.sign(np.linalg.det(u @ vt))
            u[:, :, Z] *= d[:, None]
            sub = np.full((int(inside.sum()), 3, 3), np.nan)
            sub[ok] = u @ vt
            R[inside] = sub
        return out, R


@dataclass
class FlightLog:
    """One recorded flight (module docstring).  ``imu_rate_hz``: the IMU's nominal rate;
    ``gnss_delay_s``: the age of a fix when it is time-stamped (0 when the stamp is the fix's
    own epoch); ``lever_arm``: IMU → GNSS antenna, body FLU (m), None = unknown (0 is used);
    ``notes``: what the reader did that a user should know."""

    source: str
    path: str
    imu_t: np.ndarray
    imu: np.ndarray
    gnss_t: np.ndarray
    gnss_p: np.ndarray
    gnss_var: np.ndarray
    gnss_v: np.ndarray | None = None
    gnss_var_v: np.ndarray | None = None
    origin: tuple[float, float, float] | None = None
    reference: Track | None = None
    autopilot: Track | None = None
    imu_rate_hz: float = 0.0
    gnss_delay_s: float = 0.0
    lever_arm: tuple[float, float, float] | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def duration_s(self) -> float:
        return float(self.imu_t[-1] - self.imu_t[0]) if self.imu_t.size else 0.0


def frd_to_flu(a: np.ndarray) -> np.ndarray:
    """Body FRD vectors (..., 3) → FLU: (x, −y, −z)."""
    a = np.array(a, dtype=float)
    a[..., 1:] *= -1.0
    return a






def ned_frd_to_enu_flu(R_nf: np.ndarray) -> np.ndarray:
    """An autopilot's attitude (FRD body → NED) → the INS's (FLU body → ENU): T R T'."""
    return _T_EN @ R_nf @ _T_FF



