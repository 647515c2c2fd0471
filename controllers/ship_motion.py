"""The ship's motion model without noise: constant turn rate and along-track acceleration (CTRA), each decaying
with its correlation time. Shared maths: the manoeuvring-ship estimator (``controllers.estimation.ct_ukf``) propagates
its estimate with it, and the terminal guidance (``controllers.guidance.guidance``) predicts the ship to t_go."""
from __future__ import annotations

import math

import numpy as np


def predict_ctra(pos_enu_m, vel_enu_m_s, turn_rate_rad_s: float, accel_along_m_s2: float, dt_s: float,
                 turn_rate_time_s: float = math.inf, accel_time_s: float = math.inf,
                 min_speed_m_s: float = 0.5, fade_speed_m_s: float = 0.0, fade_time_s: float = math.inf,
                 steps: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The ship's position and velocity ``dt_s`` ahead under the filter's process model without noise (the
    turn rate and acceleration decaying with their correlation times; ``inf``: held), horizontally; the
    vertical part moves at its velocity. RK4 in steps of at most 0.1 s (``steps`` to fix their number).

    For a guidance law: where the ship will be at t_go (BPNG's aim point), and its velocity then."""
    p = np.array(pos_enu_m, dtype=float)
    v = np.array(vel_enu_m_s, dtype=float)
    y = np.array([p[0], p[1], v[0], v[1], float(turn_rate_rad_s), float(accel_along_m_s2)])
    kw = 0.0 if math.isinf(turn_rate_time_s) else 1.0 / turn_rate_time_s
    ka = 0.0 if math.isinf(accel_time_s) else 1.0 / accel_time_s
    fading = fade_speed_m_s > 0.0 and math.isfinite(fade_time_s)

    def f(s: np.ndarray) -> np.ndarray:
        speed = math.hypot(s[2], s[3])
        k = s[5] / max(speed, min_speed_m_s)
        fade = max(0.0, 1.0 - speed / fade_speed_m_s) / fade_time_s if fading else 0.0
        return np.array([s[2], s[3], -s[4] * s[3] + k * s[2], s[4] * s[2] + k * s[3], -(kw + fade) * s[4],
                         -(ka + fade) * s[5]])

    n = steps if steps is not None else max(1, int(math.ceil(abs(dt_s) / 0.1)))
    h = dt_s / n
    for _ in range(n):
        k1 = f(y)
        k2 = f(y + 0.5 * h * k1)
        k3 = f(y + 0.5 * h * k2)
        k4 = f(y + h * k3)
        y = y + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return (np.array([y[0], y[1], p[2] + v[2] * dt_s]), np.array([y[2], y[3], v[2]]))
