"""In-motion alignment of the INS (``controllers.navigation.ins``): the first attitude, in flight, from the IMU
and two GNSS velocities ``init_alignment_s`` apart (a turn or a climb may be under way).

Between the two fixes the gyros give the body's rotation relative to its attitude at the first,
``R_rel(t)``; the accelerometers' delta velocities turned into that first body frame add up to
``dv_b0 = sum R_rel dv``, and the world saw the same change of velocity less gravity's::

    R0 dv_b0 = v1 - v0 - g_enu T        (g_enu = [0, 0, -g], T the time between the fixes)

so ``dv_b0 -> v1 - v0 - g_enu T`` fixes the tilt of R0 (the primary vector of a TRIAD) whatever the
manoeuvre, and the heading comes from the magnetometer (the mean field in the first body frame against the
configured earth field) or, without one, from the first velocity's course (body x along it: alpha, sideslip and
the wind's crab angle err, hence the larger yaw std). The attitude at the second fix is ``R0 R_rel(T)``.
Errors: about ``sqrt(2) sigma_v / (g T)`` of tilt from the GNSS velocity noise, ``b_a / g`` from an accelerometer
bias and ``b_g T`` from a gyro bias (0.5 to 1.5 deg for a small UAV over 1 s).
"""
from __future__ import annotations

import math

import numpy as np

from controllers.navigation.ins_math import dcm_from_quat, strapdown, triad

__all__ = ["InMotionAlignment"]


class InMotionAlignment:
    """Accumulates the IMU (and magnetometer) between two GNSS fixes and solves for the attitude."""

    def __init__(self, gravity_m_s2: float):
        self.g = gravity_m_s2
        self.active = False
        self.t0 = math.nan
        self.v0 = np.zeros(3)
        self._q_rel: tuple = (1.0, 0.0, 0.0, 0.0)  # body now -> body at the first fix
        self._dv_b0 = np.zeros(3)
        self._mag_b0 = np.zeros(3)
        self._n_mag = 0

    def start(self, t_s: float, vel_enu_m_s) -> None:
        """Open the window at the first fix (its time and velocity)."""
        self.active, self.t0, self.v0 = True, t_s, np.array(vel_enu_m_s, float)
        self._q_rel = (1.0, 0.0, 0.0, 0.0)
        self._dv_b0, self._mag_b0, self._n_mag = np.zeros(3), np.zeros(3), 0

    def add_imu(self, dang_frd_rad, dvel_frd_m_s) -> None:
        """One IMU interval inside the window."""
        self._q_rel, _, dv = strapdown(self._q_rel, dang_frd_rad, dvel_frd_m_s)
        self._dv_b0 += dv

    def add_mag(self, field_frd) -> None:
        """One magnetometer sample inside the window (already checked for its strength)."""
        self._mag_b0 += dcm_from_quat(self._q_rel) @ np.asarray(field_frd, float)
        self._n_mag += 1

    def solve(self, t_s: float, vel_enu_m_s, earth_field_enu) -> tuple[np.ndarray, bool] | None:
        """R_enu_from_frd at ``t_s`` (the second fix) and whether the heading came from the magnetometer; None
        when the geometry is degenerate (no motion to take a course from, say)."""
        T = t_s - self.t0
        dv_w = np.asarray(vel_enu_m_s, float) - self.v0
        dv_w[2] += self.g * T
        R0 = None
        use_mag = self._n_mag > 0
        if use_mag:
            R0 = triad(self._dv_b0, self._mag_b0 / self._n_mag, dv_w, earth_field_enu)
        if R0 is None:
            use_mag = False
            if math.hypot(self.v0[0], self.v0[1]) > 3.0:
                R0 = triad(self._dv_b0, np.array([1.0, 0.0, 0.0]), dv_w, self.v0)
        self.active = False
        if R0 is None:
            return None
        return R0 @ dcm_from_quat(self._q_rel), use_mag
