"""Guidance for Phase 1: straight lines through waypoints, and a circle around a point.

Both end in the same two loops (``rates_from_course_and_altitude``):
bank_c = -k_chi (chi_c - chi) then u_p = k_phi (bank_c - phi); flight-path set-point
gamma_c = k_h (h_c - h) (limited) then u_q = k_gamma (gamma_c - gamma) / cos(phi)
(eq. (16): theta_dot = u_q cos phi). The outputs are the NMPC-style rate
commands of autopilot mode (a). Courses are ENU (counter-clockwise from East).

Lines: Beard & McLain (Small Unmanned Aircraft, 2012, sec. 10.1):
    chi_c = chi_path + chi_inf (2 / pi) atan(k_path e_right)   (e_right > 0 right of the path)
Circles (sec. 10.2): for a centre c, radius R and direction lam (+1 counter-clockwise,
-1 clockwise, seen from above):
    chi_c = phi_c + lam (pi / 2 + atan(k_orbit (d - R) / R))   (phi_c: bearing from c to the UAV)
plus the turn's feed-forward bank atan(V^2 / (g R)) toward the centre.
"""
from __future__ import annotations

import math

import numpy as np

from fwsim.interface.frames import wrap_pi
from fwsim.interface.messages import FlightSoftwareStatus, Measurements, RateCommand

CHI_INF_RAD = math.radians(60.0)  # approach angle far from the path
K_PATH_1_M = 0.01  # 1/m
K_ORBIT = 3.0  # orbit capture gain
K_CHI = 1.2  # rad of bank per rad of course error
K_PHI_1_S = 2.0  # 1/s
K_H_RAD_M = 0.01  # rad of flight path per m of altitude error
GAMMA_MAX_RAD = math.radians(8.0)
K_GAMMA_1_S = 1.5  # 1/s
G = 9.80665


def rates_from_course_and_altitude(meas: Measurements, chi_c: float, h_c: float, airspeed_m_s: float,
                                   max_bank_rad: float, bank_ff_rad: float = 0.0,
                                   gamma_max_rad: float = GAMMA_MAX_RAD) -> tuple[RateCommand, float]:
    """Rate command holding a course and an altitude; returns (command, bank set-point)."""
    vel = meas.vel_enu_m_s
    chi = math.atan2(vel[1], vel[0])
    bank_c = bank_ff_rad - K_CHI * wrap_pi(chi_c - chi)
    bank_c = max(-max_bank_rad, min(max_bank_rad, bank_c))
    phi = meas.euler_ned_rad[0]
    u_p = K_PHI_1_S * (bank_c - phi)
    gamma_c = max(-gamma_max_rad, min(gamma_max_rad, K_H_RAD_M * (h_c - meas.height_above_sea_m)))
    gamma = math.asin(max(-1.0, min(1.0, vel[2] / max(float(np.linalg.norm(vel)), 1.0))))
    u_q = K_GAMMA_1_S * (gamma_c - gamma) / max(math.cos(phi), 0.3)
    return RateCommand(meas.t_s, airspeed_m_s, u_p, u_q), bank_c


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
        pos = meas.pos_enu_m
        a, b = self._segment(pos)
        d = b[:2] - a[:2]
        length = max(float(np.linalg.norm(d)), 1e-6)
        u = d / length
        chi_path = math.atan2(u[1], u[0])
        rel = pos[:2] - a[:2]
        e_right = float(rel[0] * u[1] - rel[1] * u[0])  # right of the path is positive
        chi_c = chi_path + CHI_INF_RAD * (2.0 / math.pi) * math.atan(K_PATH_1_M * e_right)
        # altitude along the segment (waypoint altitudes interpolated)
        s = min(max(float(rel @ u) / length, 0.0), 1.0)
        h_c = float(a[2] + s * (b[2] - a[2]))
        cmd, bank_c = rates_from_course_and_altitude(meas, chi_c, h_c, self.airspeed_m_s, self.max_bank_rad)
        status = FlightSoftwareStatus(meas.t_s, 1, "initial_path", "rates", course_sp_rad=chi_c,
                                      bank_sp_rad=bank_c, altitude_sp_m=h_c, cross_track_m=e_right)
        return cmd, status


class OrbitFollower:
    """A circle of radius R at altitude H around a (moving) centre."""

    def __init__(self, airspeed_m_s: float, radius_m: float, altitude_m: float, clockwise: bool,
                 max_bank_deg: float = 35.0):
        self.airspeed_m_s = airspeed_m_s
        self.radius_m = radius_m
        self.altitude_m = altitude_m
        self.lam = -1.0 if clockwise else 1.0
        self.max_bank_rad = math.radians(max_bank_deg)

    def step(self, meas: Measurements, centre_enu_m: np.ndarray) -> tuple[RateCommand, float, float]:
        """(command, course set-point, radial error d - R)."""
        rel = meas.pos_enu_m[:2] - np.asarray(centre_enu_m, dtype=float)[:2]
        d = float(np.hypot(rel[0], rel[1]))
        bearing = math.atan2(rel[1], rel[0])
        R = self.radius_m
        chi_c = bearing + self.lam * (0.5 * math.pi + math.atan(K_ORBIT * (d - R) / R))
        # counter-clockwise (lam = +1) turns left: negative bank
        bank_ff = -self.lam * math.atan(self.airspeed_m_s**2 / (G * R)) if d < 2.0 * R else 0.0
        cmd, _ = rates_from_course_and_altitude(meas, chi_c, self.altitude_m, self.airspeed_m_s,
                                                self.max_bank_rad, bank_ff)
        return cmd, chi_c, d - R
