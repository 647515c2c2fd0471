"""The INS's prediction step (``controllers.navigation.ins``) as one CasADi function, and its numpy reference.

One call moves the nominal state and the 21 x 21 covariance over one IMU interval (the equations of the
``ins`` module text): a few thousand flops in CasADi's virtual machine, evaluated on preallocated buffers
(``controllers.compiled.Buffered``), so the 120 Hz prediction costs a few microseconds of Python instead of
some twenty for the same numpy. :func:`predict_reference` is the same step in numpy, for the tests.

Nominal state vector ``x`` (22): ``q_enu_from_frd (4), v (3), p (3), b_g (3), b_a (3), w (2), b_h (1),
b_m (3)``; IMU input ``u`` (7): ``delta_angle (3), delta_velocity (3), dt``; ``q_rate`` (21): the process noise's
variance per second of each error state.
"""
from __future__ import annotations

import numpy as np

from controllers.navigation.ins_math import strapdown

__all__ = ["N_NOMINAL", "build_predict", "predict_reference"]

N_NOMINAL = 22
N_ERR = 21
_FUNCTION = None  # the CasADi Function, built once per process (each filter has its own buffers)


def _sx_quat_exp(a):
    import casadi as ca
    a2 = a[0] * a[0] + a[1] * a[1] + a[2] * a[2]
    an = ca.sqrt(a2 + 1e-300)
    s = ca.if_else(a2 < 1e-12, 0.5 - a2 / 48.0, ca.sin(0.5 * an) / an)
    c = ca.if_else(a2 < 1e-12, 1.0 - 0.125 * a2, ca.cos(0.5 * an))
    return c, s * a[0], s * a[1], s * a[2]


def _sx_quat_mul(q1, q2):
    import casadi as ca
    w1, x1, y1, z1 = q1
    w2, x2, y2, z2 = q2
    q = ca.vertcat(w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                   w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2)
    n = ca.sqrt(ca.sumsqr(q))
    return ca.if_else(q[0] < 0.0, -q / n, q / n)  # unit, w >= 0 (as ins_math.quat_mul)


def _sx_dcm(q):
    import casadi as ca
    w, x, y, z = q[0], q[1], q[2], q[3]
    return ca.vertcat(ca.horzcat(1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)),
                      ca.horzcat(2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)),
                      ca.horzcat(2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)))


def _build(gravity_m_s2: float):
    """The CasADi Function. Only P's upper triangle is read and computed (then mirrored): 2400 instructions."""
    import casadi as ca
    x, P, u, qr = ca.SX.sym("x", N_NOMINAL), ca.SX.sym("P", N_ERR, N_ERR), ca.SX.sym("u", 7), ca.SX.sym("q", N_ERR)
    Ps = ca.triu(P) + ca.triu(P, False).T
    q, v, p, bg, ba = x[0:4], x[4:7], x[7:10], x[10:13], x[13:16]
    dt = u[6]
    a = u[0:3] - bg * dt
    dv_b = u[3:6] - ba * dt
    R = _sx_dcm(q)
    dv = ca.mtimes(R, dv_b + 0.5 * ca.cross(a, dv_b))
    v1 = v + dv - ca.vertcat(0, 0, gravity_m_s2 * dt)
    q1 = _sx_quat_mul([q[0], q[1], q[2], q[3]], _sx_quat_exp(a))
    x1 = ca.vertcat(q1, v1, p + 0.5 * dt * (v + v1), x[10:N_NOMINAL])
    phi = ca.SX.eye(N_ERR)
    phi[0:3, 9:12] = -R * dt
    phi[3:6, 0:3] = -ca.skew(dv)
    phi[3:6, 12:15] = -R * dt
    phi[6:9, 3:6] = ca.SX.eye(3) * dt
    A = ca.mtimes(ca.mtimes(phi, Ps), phi.T) + ca.diag(qr * dt)
    return ca.Function("ins_predict", [x, P, u, qr], [x1, ca.triu(A) + ca.triu(A, False).T])


def build_predict(gravity_m_s2: float):
    """A :class:`controllers.compiled.Buffered` prediction with its own buffers: ``inputs = [x, P, u, q_rate]``
    (P column-major: symmetric, so the same as row-major), ``outputs = [x', P']``."""
    global _FUNCTION
    from controllers.compiled import Buffered
    if _FUNCTION is None or _FUNCTION[0] != gravity_m_s2:
        _FUNCTION = (gravity_m_s2, _build(gravity_m_s2))
    return Buffered(_FUNCTION[1])


def predict_reference(x: np.ndarray, P: np.ndarray, u: np.ndarray, q_rate: np.ndarray,
                      gravity_m_s2: float) -> tuple[np.ndarray, np.ndarray]:
    """The same step in numpy (new arrays)."""
    dt = float(u[6])
    a = (u[0:3] - x[10:13] * dt).tolist()
    b = (u[3:6] - x[13:16] * dt).tolist()
    q1, rows, dv = strapdown(x[0:4].tolist(), a, b)
    R = np.array(rows)
    v0 = x[4:7]
    v1 = v0 + np.array(dv) - np.array([0.0, 0.0, gravity_m_s2 * dt])
    x1 = np.concatenate((q1, v1, x[7:10] + 0.5 * dt * (v0 + v1), x[10:]))
    phi = np.eye(N_ERR)
    phi[0:3, 9:12] = -R * dt
    phi[3:6, 12:15] = -R * dt
    phi[6:9, 3:6] = np.eye(3) * dt
    e, n, z = dv
    phi[3:6, 0:3] = np.array([[0.0, z, -n], [-z, 0.0, e], [n, -e, 0.0]])
    A = phi @ P @ phi.T
    return x1, 0.5 * (A + A.T) + np.diag(q_rate * dt)

