"""Navigation: the UAV's own position between GNSS fixes.

The GNSS/INS position and velocity arrive as fixes at ``sensors.gnss_rate_hz``
(10 Hz by default) with white noise, held between fixes. Held, the position
lags the aircraft by up to one fix period: 5 m at the 50 m/s of a terminal
dive, which the guidance would see as a line-of-sight jump every 0.1 s.

``Navigation`` does what a mission computer does with such a receiver: it
propagates the position with the fix's velocity between fixes, and blends
each new fix in with a complementary gain::

    p_hat(t) = p_hat(t_prev) + v_hat (t - t_prev)                (propagate)
    p_hat   <- p_hat + K (p_fix + v_hat (t - t_fix) - p_hat)      (new fix)

(``v_hat``: the fix velocity, turned with the gyros as below; the trapezoid of
its values at both ends of the step in the code).

With white fix noise sigma the blended error is about
``sigma sqrt(K / (2 - K))`` (0.11 m for 0.5 m and K = 0.1) and the response to
a real position change carried by the velocity has no lag. The fix time comes
with the measurement (``Measurements.nav_t_s``).

The fix velocity is held too: in a terminal dive turning at 25 m/s^2 it is up
to 2.5 m/s old, and the guidance's line-of-sight rate ``r x r_dot / |r|^2``
takes that error whole (at 25 m to go, 0.1 rad/s: a 30 m/s^2 PN command). The
airframe's flight path turns with the airframe, so between fixes the velocity
is turned with the gyros (attitude from the AHRS, both at their own rates)::

    v_hat <- v_fix + (omega_enu x v_fix) (t - t_fix)             (new fix)
    v_hat <- v_hat + (omega_enu x v_hat) dt                      (between fixes)

which leaves out only the change of speed along the path (gravity and drag,
~5 m/s^2 in a dive, a small part of the line-of-sight rate). It is the air
velocity that turns with the airframe, so in wind ``v_hat - wind`` turns; the
wind is estimated from the fixes in near-level flight (fix velocity minus the
airspeed along the nose, horizontal, blended with ``wind_gain``).

Nothing here imports the truth side of the harness (docs/design/architecture.md, "Two rules").
"""
from __future__ import annotations

import dataclasses
import math
import operator

import numpy as np

from controllers.config import NavigationConfig
from fwsim.interface.frames import cross3, dcm_enu_from_frd, finite3
from fwsim.interface.messages import Measurements

__all__ = ["NavigationConfig", "Navigation"]

_LEVEL_PITCH_RAD = math.radians(15.0)  # the wind is estimated only below this pitch
_LEVEL_BANK_RAD = math.radians(45.0)  # and this bank
_MEAS_FIELDS = tuple(f.name for f in dataclasses.fields(Measurements))
_meas_values = operator.attrgetter(*_MEAS_FIELDS)  # every field, in the constructor's order
_I_POS, _I_VEL, _I_WIND = (_MEAS_FIELDS.index(n) for n in ("pos_enu_m", "vel_enu_m_s", "wind_enu_m_s"))


def _with_navigation(meas: Measurements, pos, vel, wind) -> Measurements:
    """``dataclasses.replace(meas, pos_enu_m=pos, vel_enu_m_s=vel, wind_enu_m_s=wind)``, built positionally."""
    if type(meas) is not Measurements:
        return dataclasses.replace(meas, pos_enu_m=pos, vel_enu_m_s=vel, wind_enu_m_s=wind)
    values = list(_meas_values(meas))
    values[_I_POS], values[_I_VEL], values[_I_WIND] = pos, vel, wind
    return Measurements(*values)


class Navigation:
    """GNSS fixes in, a position at every flight-software tick out (see the module text)."""

    def __init__(self, cfg: NavigationConfig | None = None):
        self.cfg = cfg if cfg is not None else NavigationConfig()
        self._pos = None  # propagated position, ENU m
        self._t = math.nan  # time of _pos
        self._fix_t = math.nan  # time of the last fix blended in
        self._vel = None  # the fix velocity turned with the gyros
        self.wind_enu_m_s = np.zeros(3)  # running estimate of the (horizontal) wind
        self._v_out = None  # the velocity used at the last step

    def _update_wind(self, v_fix, R_enu_from_frd, meas: Measurements) -> None:
        """Blend this fix's horizontal wind into the estimate, in near-level, gently banked flight (where
        the air velocity lies along the nose to within the angle of attack)."""
        k = self.cfg.wind_gain
        phi, theta = float(meas.euler_ned_rad[0]), float(meas.euler_ned_rad[1])
        if k <= 0.0 or not math.isfinite(meas.airspeed_m_s) or abs(theta) > _LEVEL_PITCH_RAD \
                or abs(phi) > _LEVEL_BANK_RAD:
            return
        w = np.asarray(v_fix, dtype=float) - meas.airspeed_m_s * R_enu_from_frd[:, 0]
        w[2] = 0.0
        if not finite3(w):
            return
        self.wind_enu_m_s = self.wind_enu_m_s + k * (w - self.wind_enu_m_s)

    def step(self, meas: Measurements) -> Measurements:
        """The measurements with ``pos_enu_m`` replaced by the propagated, blended position (and
        ``vel_enu_m_s`` by the velocity turned with the gyros)."""
        if not self.cfg.propagate or not math.isfinite(meas.nav_t_s):
            return meas
        t = meas.t_s
        v = np.asarray(meas.vel_enu_m_s, dtype=float)
        if self.cfg.turn_velocity and finite3(meas.body_rates_frd_rad_s) and finite3(meas.euler_ned_rad):
            R = dcm_enu_from_frd(meas.euler_ned_rad)
            if meas.nav_t_s != self._fix_t:
                self._update_wind(v, R, meas)
            w = R @ np.asarray(meas.body_rates_frd_rad_s, float)
            if self._vel is None or meas.nav_t_s != self._fix_t or t - self._t > self.cfg.max_gap_s:
                self._vel = v + cross3(w, v - self.wind_enu_m_s) * (t - meas.nav_t_s)
            else:
                self._vel = self._vel + cross3(w, self._vel - self.wind_enu_m_s) * (t - self._t)
            v_now = self._vel
        else:
            v_now = v
        fix = np.asarray(meas.pos_enu_m, dtype=float) + 0.5 * (v + v_now) * (t - meas.nav_t_s)  # brought to now
        if self._pos is None or t - self._t > self.cfg.max_gap_s:
            self._pos = fix.copy()
        else:
            v_last = self._v_out if self._v_out is not None else v_now
            self._pos = self._pos + 0.5 * (v_last + v_now) * (t - self._t)  # p_hat += v dt
            if meas.nav_t_s != self._fix_t:  # a new fix: blend it in
                self._pos = self._pos + self.cfg.fix_gain * (fix - self._pos)
        self._t, self._fix_t, self._v_out = t, meas.nav_t_s, np.array(v_now, dtype=float)
        return _with_navigation(meas, self._pos.copy(), np.array(v_now, dtype=float), self.wind_enu_m_s.copy())
