"""Small rotation helpers of the INS (``controllers.navigation.ins``), on single vectors with ``math``.

Conventions are the project's (``fwsim.interface.frames``): Hamilton quaternions ``[w, x, y, z]``,
``q_enu_from_frd`` maps body FRD vectors into the world ENU frame, Euler angles are NED 3-2-1.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["quat_exp", "quat_mul", "dcm_from_quat", "strapdown", "euler_ned_from_dcm_enu_from_frd",
           "euler_jacobian", "triad"]


def quat_exp(rv) -> tuple[float, float, float, float]:
    """The unit quaternion of a rotation vector (rad): angle |rv| about rv (second order below 1e-6 rad)."""
    x, y, z = float(rv[0]), float(rv[1]), float(rv[2])
    a2 = x * x + y * y + z * z
    if a2 < 1e-12:
        return (1.0 - 0.125 * a2, 0.5 * x, 0.5 * y, 0.5 * z)
    a = math.sqrt(a2)
    s = math.sin(0.5 * a) / a
    return (math.cos(0.5 * a), s * x, s * y, s * z)


def quat_mul(q1, q2) -> tuple[float, float, float, float]:
    """Hamilton product q1 * q2, normalised and with w >= 0 (the same rotation; the filter's quaternions stay
    unit and the output predictor's attitude error continuous)."""
    w1, x1, y1, z1 = q1[0], q1[1], q1[2], q1[3]
    w2, x2, y2, z2 = q2[0], q2[1], q2[2], q2[3]
    w = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2
    x = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2
    y = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2
    z = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2
    n = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
    if w < 0.0:
        n = -n
    return (w * n, x * n, y * n, z * n)


def dcm_from_quat(q) -> np.ndarray:
    """R_a_from_b from a unit q_a_from_b."""
    w, x, y, z = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    xx, yy, zz, xy, xz, yz, wx, wy, wz = x * x, y * y, z * z, x * y, x * z, y * z, w * x, w * y, w * z
    return np.array([[1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy)],
                     [2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx)],
                     [2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy)]])


def strapdown(q, dang, dvel) -> tuple[np.ndarray, tuple, tuple]:
    """One strapdown step from ``q`` (q_enu_from_frd) with a bias-corrected delta angle and delta velocity:
    ``(q * Exp(dang), rows of R(q), R(q) (dvel + dang x dvel / 2))``, the last the world-frame velocity
    change less gravity's (the cross term: the body's rotation over the interval, to first order)."""
    ax, ay, az = dang[0], dang[1], dang[2]
    ux, uy, uz = dvel[0], dvel[1], dvel[2]
    cx = ux + 0.5 * (ay * uz - az * uy)
    cy = uy + 0.5 * (az * ux - ax * uz)
    cz = uz + 0.5 * (ax * uy - ay * ux)
    w, x, y, z = q[0], q[1], q[2], q[3]
    xx, yy, zz, xy, xz, yz, wx, wy, wz = x * x, y * y, z * z, x * y, x * z, y * z, w * x, w * y, w * z
    r0 = (1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy))
    r1 = (2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx))
    r2 = (2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy))
    dv = (r0[0] * cx + r0[1] * cy + r0[2] * cz, r1[0] * cx + r1[1] * cy + r1[2] * cz,
          r2[0] * cx + r2[1] * cy + r2[2] * cz)
    return quat_mul((w, x, y, z), quat_exp((ax, ay, az))), (r0, r1, r2), dv


def euler_ned_from_dcm_enu_from_frd(R) -> np.ndarray:
    """[roll, pitch, yaw] (NED 3-2-1, yaw clockwise from North) from R_enu_from_frd.

    R_ned_from_frd is R_enu_from_frd with its first two rows swapped and its third negated."""
    s = float(R[2, 0])
    theta = math.asin(1.0 if s > 1.0 else (-1.0 if s < -1.0 else s))
    return np.array([math.atan2(-float(R[2, 1]), -float(R[2, 2])), theta, math.atan2(float(R[0, 0]), float(R[1, 0]))])


def euler_jacobian(euler_ned_rad, R_enu_from_frd) -> np.ndarray:
    """d(roll, pitch, yaw) / d(delta_theta): the Euler angles' response to a small world-frame (ENU) rotation.

    A world-frame error ``delta`` is the body-frame rotation ``R^T delta``, and the Euler angles move with a
    body rotation as with the body rates: ``E(roll, pitch) R^T`` (singular at pitch +-90 deg)."""
    phi, theta = float(euler_ned_rad[0]), float(euler_ned_rad[1])
    sf, cf, ct = math.sin(phi), math.cos(phi), max(math.cos(theta), 1e-6)
    tt = math.sin(theta) / ct
    e = np.array([[1.0, sf * tt, cf * tt], [0.0, cf, -sf], [0.0, sf / ct, cf / ct]])
    return e @ R_enu_from_frd.T


def triad(b1, b2, w1, w2) -> np.ndarray:
    """R_w_from_b from two vector pairs (TRIAD): b1 -> w1 exactly, b2 -> w2 about it. None if degenerate."""
    def frame(a, c):
        t1 = a / np.linalg.norm(a)
        t2 = np.cross(a, c)
        n = np.linalg.norm(t2)
        if not n > 1e-9 * np.linalg.norm(a) * np.linalg.norm(c):
            return None
        t2 = t2 / n
        return np.column_stack((t1, t2, np.cross(t1, t2)))

    fb, fw = frame(np.asarray(b1, float), np.asarray(b2, float)), frame(np.asarray(w1, float), np.asarray(w2, float))
    if fb is None or fw is None:
        return None
    return fw @ fb.T
