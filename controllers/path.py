"""Initial path flight (Phase 1): straight lines through waypoints.

Lateral: the straight-line follower of Beard & McLain (Small Unmanned
Aircraft, 2012, sec. 10.1): course set-point
    chi_c = chi_path + chi_inf (2 / pi) atan(k_path e_right)
(ENU course, counter-clockwise from East; e_right > 0 right of the path),
then bank_c = -k_chi (chi_c - chi) and u_p = k_phi (bank_c - phi).
Vertical: flight-path set-point gamma_c = k_h (h_c - h) (limited), then
u_q = k_gamma (gamma_c - gamma) / cos(phi) (eq. add_tran: theta_dot = u_q cos phi).
The outputs are the NMPC-style rate commands of autopilot mode (a).
"""
from __future__ import annotations

import math

import numpy as np

from fwsim.frames import wrap_pi
from fwsim.messages import FlightSoftwareStatus, Measurements, RateCommand

CHI_INF_RAD = math.radians(60.0)  # approach angle far from the path
K_PATH_1_M = 0.01  # 1/m
K_CHI = 1.2  # rad of bank per rad of course error
K_PHI_1_S = 2.0  # 1/s
K_H_RAD_M = 0.01  # rad of flight path per m of altitude error
GAMMA_MAX_RAD = math.radians(8.0)
K_GAMMA_1_S = 1.5  # 1/s


class PathFollower:
    """Flies the line from the start through each waypoint, then holds the last course."""

    def __init__(self, airspeed_m_s: float, start_enu_m, heading_ned_rad: float, waypoints_enu_m=(),
                 max_bank_deg: float = 35.0):
        self.airspeed_m_s = airspeed_m_s
        self.max_bank_rad = math.radians(max_bank_deg)
        start = np.asarray(start_enu_m, dtype=float)
        pts = [start] + [np.asarray(w, dtype=float) for w in waypoints_enu_m]
        if len(pts) == 1:  # hold the initial heading and altitude
            course = 0.5 * math.pi - heading_ned_rad
            pts.append(start + 1e5 * np.array([math.cos(course), math.sin(course), 0.0]))
        self.points = pts
        self.segment = 0

    def _segment(self, pos: np.ndarray):
        while self.segment < len(self.points) - 2:
            a, b = self.points[self.segment], self.points[self.segment + 1]
            d = b[:2] - a[:2]
            if float((pos[:2] - b[:2]) @ d) > 0.0:  # passed the half-plane at b
                self.segment += 1
            else:
                break
        return self.points[self.segment], self.points[self.segment + 1]

    def step(self, meas: Measurements) -> tuple[RateCommand, FlightSoftwareStatus]:
        pos, vel = meas.pos_enu_m, meas.vel_enu_m_s
        a, b = self._segment(pos)
        d = b[:2] - a[:2]
        length = max(float(np.linalg.norm(d)), 1e-6)
        u = d / length
        chi_path = math.atan2(u[1], u[0])
        rel = pos[:2] - a[:2]
        e_right = float(rel[0] * u[1] - rel[1] * u[0])  # right of the path is positive
        chi_c = chi_path + CHI_INF_RAD * (2.0 / math.pi) * math.atan(K_PATH_1_M * e_right)
        chi = math.atan2(vel[1], vel[0])
        bank_c = max(-self.max_bank_rad, min(self.max_bank_rad, -K_CHI * wrap_pi(chi_c - chi)))
        phi, _, _ = meas.euler_ned_rad
        u_p = K_PHI_1_S * (bank_c - phi)
        # altitude along the segment (waypoint altitudes interpolated)
        s = min(max(float(rel @ u) / length, 0.0), 1.0)
        h_c = float(a[2] + s * (b[2] - a[2]))
        gamma_c = max(-GAMMA_MAX_RAD, min(GAMMA_MAX_RAD, K_H_RAD_M * (h_c - meas.height_above_sea_m)))
        gamma = math.asin(max(-1.0, min(1.0, vel[2] / max(float(np.linalg.norm(vel)), 1.0))))
        u_q = K_GAMMA_1_S * (gamma_c - gamma) / max(math.cos(phi), 0.3)
        cmd = RateCommand(meas.t_s, self.airspeed_m_s, u_p, u_q)
        status = FlightSoftwareStatus(meas.t_s, 1, "initial_path", "rates", course_sp_rad=chi_c,
                                      bank_sp_rad=bank_c, altitude_sp_m=h_c, cross_track_m=e_right)
        return cmd, status
