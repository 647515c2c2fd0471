"""The INS's output predictor: the state at the newest IMU sample, kept on the delayed EKF (PX4 EKF2's scheme).

The EKF (``controllers.navigation.ins``) runs ``fusion_horizon_s`` behind the newest IMU sample so that every
measurement is fused at its own time of validity. Here a strapdown integration of the same IMU samples, with the
EKF's bias estimates, runs at the newest sample; each output state is buffered, and when the EKF has processed a
sample its state is compared with the output state buffered for that sample:

* attitude: the body-frame rotation ``delta`` from the buffered output to the EKF attitude is added, times
  ``0.5 dt / (t_now - t_delayed)``, to each following delta angle (tracking without overshoot whatever the
  horizon's length);
* velocity and position: the errors ``e`` become corrections ``e g + sum(e) g^2 / 10``, ``g = dt / tau``,
  added to the output and to every buffered output state (so the next comparison sees them).

The buffered states are corrected in O(1): each carries the sum of the corrections made before it was stored,
and reads back as stored plus the corrections made since. A reset of the EKF (position or velocity set to a
GNSS fix) is passed on as it is (:meth:`OutputPredictor.shift`), as EKF2 does, not tracked through ``tau``.
Vectors are tuples of floats here (3-vector arithmetic in Python floats is several times cheaper than in numpy).
"""
from __future__ import annotations

from collections import deque

from controllers.navigation.ins_math import strapdown

__all__ = ["OutputPredictor"]

_ZERO3 = (0.0, 0.0, 0.0)


def _add(a, b) -> tuple[float, float, float]:
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


class OutputPredictor:
    """Strapdown INS at the current time, pulled onto the delayed EKF with complementary gains."""

    def __init__(self, tau_s: float, gravity_m_s2: float):
        self.tau_s = tau_s
        self.g = gravity_m_s2
        self.q: tuple = (1.0, 0.0, 0.0, 0.0)  # q_enu_from_frd at the newest sample
        self.v: tuple = _ZERO3
        self.p: tuple = _ZERO3
        self._buf: deque = deque()  # (sample index, q, v, p, corrections of v and p before it was stored)
        self._cv, self._cp = _ZERO3, _ZERO3  # running sums of the velocity and position corrections
        self._dang_corr = _ZERO3
        self._v_int, self._p_int = _ZERO3, _ZERO3

    def reset(self, k: int, q, v, p) -> None:
        """Start from the EKF state at sample ``k`` (the newer samples are then replayed through :meth:`step`)."""
        self.q, self.v, self.p = tuple(map(float, q)), tuple(map(float, v)), tuple(map(float, p))
        self._buf.clear()
        self._cv, self._cp, self._dang_corr, self._v_int, self._p_int = _ZERO3, _ZERO3, _ZERO3, _ZERO3, _ZERO3
        self._buf.append((k, self.q, self.v, self.p, self._cv, self._cp))

    def step(self, k: int, dt: float, dang, dvel) -> None:
        """Integrate one IMU sample (bias-corrected delta angle and velocity, sequences of 3 floats) and buffer
        the state as sample ``k``."""
        c = self._dang_corr
        q, _, dv = strapdown(self.q, (dang[0] + c[0], dang[1] + c[1], dang[2] + c[2]), dvel)
        v0 = self.v
        v1 = (v0[0] + dv[0], v0[1] + dv[1], v0[2] + dv[2] - self.g * dt)
        h = 0.5 * dt
        p = self.p
        self.p = (p[0] + h * (v0[0] + v1[0]), p[1] + h * (v0[1] + v1[1]), p[2] + h * (v0[2] + v1[2]))
        self.v, self.q = v1, q
        self._buf.append((k, q, v1, self.p, self._cv, self._cp))

    def correct(self, k: int, delay_s: float, dt: float, q_ekf, v_ekf, p_ekf) -> None:
        """Pull the output toward the EKF state at sample ``k``, ``delay_s`` behind the newest sample."""
        buf = self._buf
        while buf and buf[0][0] < k:
            buf.popleft()
        if not buf or buf[0][0] != k:
            return
        _, (w, x, y, z), v, p, cv, cp = buf[0]
        a, b, c, d = q_ekf  # delta = 2 vec(conj(q) * q_ekf): the body-frame rotation from the output to the EKF
        gain = (1.0 if (w * a + x * b + y * c + z * d) >= 0.0 else -1.0) * dt / max(delay_s, dt)
        self._dang_corr = ((w * b - x * a - y * d + z * c) * gain, (w * c + x * d - y * a - z * b) * gain,
                           (w * d - x * c + y * b - z * a) * gain)
        g = dt / max(self.tau_s, dt)
        gi = 0.1 * g * g
        Cv, Cp = self._cv, self._cp
        ev = tuple(v_ekf[i] - (v[i] + Cv[i] - cv[i]) for i in range(3))
        ep = tuple(p_ekf[i] - (p[i] + Cp[i] - cp[i]) for i in range(3))
        self._v_int, self._p_int = _add(self._v_int, ev), _add(self._p_int, ep)
        dv = tuple(ev[i] * g + self._v_int[i] * gi for i in range(3))
        dp = tuple(ep[i] * g + self._p_int[i] * gi for i in range(3))
        self.v, self.p = _add(self.v, dv), _add(self.p, dp)
        self._cv, self._cp = _add(Cv, dv), _add(Cp, dp)

    def shift(self, dv, dp) -> None:
        """Pass a reset of the EKF's velocity and position (its change) on to the output and its buffer."""
        dv, dp = tuple(map(float, dv)), tuple(map(float, dp))
        self.v, self.p = _add(self.v, dv), _add(self.p, dp)
        self._cv, self._cp = _add(self._cv, dv), _add(self._cp, dp)
        self._v_int, self._p_int = _ZERO3, _ZERO3
