"""The INS's nonlinear observation models (``controllers.navigation.ins``) with their Jacobians over the error
state: attitude error ``dtheta`` a world-frame (ENU) rotation, ``R_true = Exp(dtheta) R``; velocity and wind
errors additive. Pure functions, checked against finite differences in tests/test_ins.py.
"""
from __future__ import annotations

import math

import numpy as np

from fwsim.interface.frames import cross3

__all__ = ["mag_heading", "mag_field", "airspeed", "sideslip"]


def mag_heading(R_enu_from_frd: np.ndarray, field_frd, earth_field_enu) -> tuple[float, np.ndarray, np.ndarray] | None:
    """The heading (rad, clockwise from North) of the measured field turned into the world frame with the
    estimated attitude, its Jacobian over ``dtheta`` (3,), and that world-frame field; None if the field is
    (nearly) vertical.

    With an attitude error the field reads ``m_w = Exp(-dtheta) m_earth``, so ``dm_w = m_w x dtheta``; the heading
    ``atan2(m_E, m_N)`` then moves by ``(|m_H|^2 dtheta_U - m_U (m_E dtheta_E + m_N dtheta_N)) / |m_H|^2``: the
    yaw error whole, and the tilt error through the vertical field. The Jacobian is taken at the predicted field
    (the configured earth field), not the measured one: the measurement's noise in it would correlate with the
    innovation's and walk the tilt away at high fusion rates."""
    mw = R_enu_from_frd @ np.asarray(field_frd, float)
    e, n = float(mw[0]), float(mw[1])
    ee, en, eu = float(earth_field_enu[0]), float(earth_field_enu[1]), float(earth_field_enu[2])
    mh2 = ee * ee + en * en
    if not (e * e + n * n > 1e-6 and mh2 > 1e-6):
        return None
    return math.atan2(e, n), np.array([-eu * ee / mh2, -eu * en / mh2, 1.0]), mw


def mag_field(R_enu_from_frd: np.ndarray, earth_field_enu, bias_frd) -> tuple[np.ndarray, np.ndarray]:
    """The field the magnetometer should read, ``R^T m_earth + b_m`` (body FRD), and its Jacobian (3, 6) over
    ``(dtheta (3), db_m (3))``: ``R_true^T m = R^T Exp(-dtheta) m ~ R^T (m + m x dtheta)``, so ``R^T [m]x`` and I."""
    e, n, u = float(earth_field_enu[0]), float(earth_field_enu[1]), float(earth_field_enu[2])
    Rt = R_enu_from_frd.T
    H = np.zeros((3, 6))
    H[:, 0:3] = Rt @ np.array([[0.0, -u, n], [u, 0.0, -e], [-n, e, 0.0]])
    H[0, 3] = H[1, 4] = H[2, 5] = 1.0
    return Rt @ np.array([e, n, u]) + np.asarray(bias_frd, float), H


def airspeed(v_enu, wind_en) -> tuple[float, np.ndarray]:
    """True airspeed ``|v - w|`` (wind horizontal) and its Jacobian over ``(dv (3), dw (2))``."""
    u = np.array([v_enu[0] - wind_en[0], v_enu[1] - wind_en[1], v_enu[2]], float)
    tas = float(np.linalg.norm(u))
    if tas == 0.0:
        return 0.0, np.zeros(5)
    return tas, np.array([u[0], u[1], u[2], -u[0], -u[1]]) / tas


def sideslip(R_enu_from_frd: np.ndarray, v_enu, wind_en) -> tuple[float, float, np.ndarray]:
    """Sideslip ``beta = u_y / u_x`` of the air velocity in the body frame ``u_b = R^T (v - w)``, its forward
    component ``u_x`` and the Jacobian of beta over ``(dtheta (3), dv (3), dw (2))``.

    ``u_b`` moves by ``R^T (u x dtheta) + R^T dv - R^T dw``; with ``a = R dbeta/du_b`` that is
    ``dbeta = (a x u) . dtheta + a . dv - a_EN . dw``."""
    u = np.array([v_enu[0] - wind_en[0], v_enu[1] - wind_en[1], v_enu[2]], float)
    ub = R_enu_from_frd.T @ u
    ux, uy = float(ub[0]), float(ub[1])
    if ux == 0.0:
        return math.nan, ux, np.zeros(8)
    a = R_enu_from_frd @ np.array([-uy / (ux * ux), 1.0 / ux, 0.0])
    return uy / ux, ux, np.concatenate((cross3(a, u), a, -a[0:2]))
