"""A turning ship seen through a constant-velocity estimator: its turn rate from the estimate's course history,
and the estimator's lag in the turn taken out (``controllers.turn_from_course``).

The paper's UKF models the ship at constant velocity. In a steady turn (turn
rate ``w``, so an acceleration ``a = w x v`` across the track) such a filter
settles behind the ship: its velocity trails by a constant angle and its
position by a constant distance. For a Kalman filter that measures position
(the UKF, linearised about the ship: its pixels are the ship's position seen
from a known camera) the steady state of the error ``e = truth - estimate``
under a constant ``a`` is, with the gains ``K_p = P_pp R^-1`` and
``K_v = P_vp R^-1``,

    e_p = K_v^-1 a,   e_v = K_p e_p = P_pp P_vp^-1 a = M a,

and the filter's own steady-state Riccati equation for the position block
(``P_pv + P_vp = P_pp R^-1 P_pp``) gives ``R`` from ``P``, so that
``e_p = P_pp (P_pv + P_vp)^-1 P_pp P_vp^-1 a`` (``~ M M a / 2`` when ``P_pv``
is symmetric). ``M`` is a time: ``tr(P_pp) / tr(P_pv)`` is the filter's lag,
about 4 s for the UKF's default tuning in a loiter (velocity 4-6 deg behind
a ship turning at 1-1.5 deg/s, tests/test_course_turn.py against the
analytic circle).

The turn rate itself is the slope of the estimate's course over the last
``window_s`` (a lagging course turns at the ship's rate): a weighted
straight-line fit, taken only while the ship is fast enough for its course to
mean something (``min_speed_m_s``), and only when the slope stands out of the
course's scatter about the line (``significance``, with one independent
residual per ``residual_corr_s``) and is at least ``min_turn_deg_s``: a
straight ship keeps the filter's estimate untouched.

While the camera closes on the ship within ``hold_tgo_s`` (a dive) the turn
rate found before is held, not fitted: the dive's fast-changing view brings
box-centre errors that turn the estimate's course (as
``controllers.estimation.ct_ukf``'s hold, for the same reason). The lag is still taken
from the filter's covariance of the moment.

A zigzag's course swings to and fro: its rate never holds for ``steady_s``,
and a swing's rate held into a dive leads the guidance the wrong way. With
``periodic`` on, the course history of the last ``periodic.window_s`` is also
fitted with a line plus one sinusoid (the period searched over
``periodic.min_period_s``-``max_period_s``). When the sinusoid is large
(``min_amplitude_deg``), explains most of what the line leaves
(``min_explained``), and its period lies inside the range searched (at least
a step short of the history's span: a smooth bend of the course, such as a
turn's estimate settling, fits best with the longest period), the course
is taken from it: the estimate's course trails the ship's by the filter's lag
``tau = tr(M) / 2`` (the lag of a ramp's velocity, ``e_v = M a``, as a time),
so the ship's course now is the fitted course ``tau`` ahead, and its turn rate
that course's slope. The velocity's direction is that course, the position's
lag ``e_p`` is taken out for the acceleration it implies, and the state is
carried along the fitted course (held, like the turn rate, in a dive).

With a turn found, :meth:`CourseTurn.state` gives the estimate with the lag
taken out, carried along the turn from the last fused detection (the coast of
the last seconds follows the turn, not the trailing straight line), and the
turn rate, for the guidance's prediction of where the ship will be
(``controllers.guidance.guidance``) and the perception's heading of the ship.

Nothing here reads the truth (docs/design/architecture.md, "Two rules").
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from controllers.navigation.camera_model import held_while_closing

__all__ = ["CourseTurn", "CourseTurnStatus", "PeriodicCourse", "fit_periodic", "lag_matrices"]


@dataclass(frozen=True, slots=True)
class CourseTurnStatus:
    """The course-turn finder after a fit, for the log (``/fsw/course_turn``)."""

    t_s: float
    turn_rate_deg_s: float  # in use: clockwise seen from above (the scenario's convention); 0: none
    fit_deg_s: float  # the newest fit's slope, clockwise (NaN: no fit: too slow, or too short a history)
    held: bool  # the turn rate is held (hold_tgo_s)
    lag_vel_m_s: float  # the velocity's lag taken out, m/s (0 when none)
    lag_pos_m: float  # the position's lag taken out, m (0 when none)
    period_s: float = math.nan  # the periodic course in use (a zigzag): its period, s (NaN: none)
    amplitude_deg: float = math.nan  # its amplitude, deg (NaN: none)


def lag_matrices(pos_vel_cov) -> tuple[np.ndarray, np.ndarray] | None:
    """(the velocity's and the position's steady-state lag per unit acceleration, horizontal 2 x 2: ``e_v = Mv
    a``, ``e_p = Mp a``, s and s^2) from a constant-velocity filter's position-velocity covariance (6 x 6:
    position then velocity, ENU); None when the cross-covariance is not invertible or the lags not finite."""
    P = np.asarray(pos_vel_cov, dtype=float)
    Ppp, Ppv = P[0:2, 0:2], P[0:2, 3:5]
    Pvp = Ppv.T
    try:
        mv = Ppp @ np.linalg.inv(Pvp)
        mp = Ppp @ np.linalg.inv(Ppv + Pvp) @ mv
    except np.linalg.LinAlgError:
        return None
    if not (np.isfinite(mv).all() and np.isfinite(mp).all()):
        return None
    return mv, mp


@dataclass(frozen=True, slots=True)
class PeriodicCourse:
    """A course fitted as ``c0 + c1 x + a cos(W x) + b sin(W x)``, ``x = t - t_ref`` (rad, ENU: counter-clockwise
    from east), with how well it fits."""

    t_ref: float
    coef: tuple[float, float, float, float]  # c0, c1, a, b
    omega_rad_s: float  # W
    amplitude_rad: float  # hypot(a, b)
    explained: float  # the share of the line's weighted residual the sinusoid takes out
    residual_rad: float  # the fit's weighted RMS residual

    @property
    def period_s(self) -> float:
        return 2.0 * math.pi / self.omega_rad_s

    def course(self, t_s: float) -> float:
        c0, c1, a, b = self.coef
        x = t_s - self.t_ref
        return c0 + c1 * x + a * math.cos(self.omega_rad_s * x) + b * math.sin(self.omega_rad_s * x)

    def rate(self, t_s: float) -> float:
        c0, c1, a, b = self.coef
        x, w = t_s - self.t_ref, self.omega_rad_s
        return c1 + w * (b * math.cos(w * x) - a * math.sin(w * x))


def fit_periodic(t, y, w, periods_s) -> PeriodicCourse | None:
    """The weighted least-squares fit of a line plus a sinusoid to the course samples ``y`` (rad, unwrapped) at
    ``t`` with weights ``w``, the period the best of ``periods_s`` refined between its neighbours (a parabola
    through the three residuals); None when there are too few samples or no period."""
    t, y, w = (np.asarray(v, dtype=float) for v in (t, y, w))
    periods = np.asarray(periods_s, dtype=float)
    if t.size < 8 or periods.size == 0:
        return None
    t_ref = float(t[-1])
    x = t - t_ref
    syy = float((w * y * y).sum())
    sw, swx, swxx = float(w.sum()), float((w * x).sum()), float((w * x * x).sum())
    wx, wy = w * x, w * y
    swy, swxy = float(wy.sum()), float((w * x * y).sum())

    def solve(omegas):
        om = np.asarray(omegas, dtype=float)[:, None] * x[None, :]
        cs, sn = np.cos(om), np.sin(om)
        a = np.empty((om.shape[0], 4, 4))
        a[:, 0, 0], a[:, 0, 1], a[:, 1, 1] = sw, swx, swxx
        a[:, 0, 2], a[:, 0, 3] = cs @ w, sn @ w
        a[:, 1, 2], a[:, 1, 3] = cs @ wx, sn @ wx
        a[:, 2, 2], a[:, 2, 3], a[:, 3, 3] = (cs * cs) @ w, (cs * sn) @ w, (sn * sn) @ w
        a[:, 1, 0], a[:, 2, 0], a[:, 3, 0], a[:, 2, 1], a[:, 3, 1], a[:, 3, 2] = (
            a[:, 0, 1], a[:, 0, 2], a[:, 0, 3], a[:, 1, 2], a[:, 1, 3], a[:, 2, 3])
        b = np.empty((om.shape[0], 4))
        b[:, 0], b[:, 1], b[:, 2], b[:, 3] = swy, swxy, cs @ wy, sn @ wy
        try:
            c = np.linalg.solve(a, b[..., None])[..., 0]
        except np.linalg.LinAlgError:
            return None, None
        return c, syy - (c * b).sum(axis=1)

    a2 = np.array([[sw, swx], [swx, swxx]])
    b2 = np.array([swy, swxy])
    try:
        ss_line = syy - float(np.linalg.solve(a2, b2) @ b2)
    except np.linalg.LinAlgError:
        return None
    omegas = 2.0 * math.pi / periods
    c, ss = solve(omegas)
    if c is None:
        return None
    k = int(np.argmin(ss))
    om = float(omegas[k])
    if 0 < k < len(omegas) - 1:  # the parabola's vertex through the best and its neighbours
        x0, x1, x2 = omegas[k - 1:k + 2]
        y0, y1, y2 = ss[k - 1:k + 2]
        den = (x0 - x1) * (x0 - x2) * (x1 - x2) or math.inf
        aa = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den
        bb = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / den
        if aa > 0.0:
            om = float(np.clip(-bb / (2.0 * aa), min(x0, x2), max(x0, x2)))
    c, ss = solve([om])
    if c is None:
        return None
    cf, res = c[0], max(float(ss[0]), 0.0)
    explained = 1.0 - res / ss_line if ss_line > 0.0 else 0.0
    return PeriodicCourse(t_ref, (float(cf[0]), float(cf[1]), float(cf[2]), float(cf[3])), om,
                          math.hypot(float(cf[2]), float(cf[3])), float(explained), math.sqrt(res / float(w.sum())))


class CourseTurn:
    """The turn rate from an estimate's course history and the lag-corrected estimate (see the module text).

    Feed it every fused estimate with :meth:`observe`; :meth:`state` gives the state to use at any time."""

    def __init__(self, cfg):
        self.cfg = cfg
        self._hist: deque[tuple[float, float, float]] = deque()  # (t, unwrapped course, weight)
        self._last_t = -math.inf
        self.turn_rad_s = 0.0  # the turn rate in use (ENU, counter-clockwise positive); 0: none found
        self.fit_rad_s = math.nan  # the last fit's slope (NaN: no fit), whether or not in use
        self._fused: tuple[float, np.ndarray, np.ndarray] | None = None  # (t, corrected pos, corrected vel)
        self.held = False  # the turn rate is held (hold_tgo_s: the camera closes in)
        self.fitted = False  # observe() sampled the course (and fitted) this time: a status to log
        self._lag = (0.0, 0.0)  # (velocity, position) lag taken out at the last fused estimate
        self._fits: deque[tuple[float, float]] = deque()  # (t, slope) of the fits over the last steady_s
        self._long: deque[tuple[float, float, float]] = deque()  # the course history of periodic.window_s
        self.periodic: PeriodicCourse | None = None  # the periodic course in use (a zigzag); None: none
        self._tau = 0.0  # the filter's lag as a time at the last fused estimate (the periodic course), s
        self._period_guess: float | None = None  # the periodic fit's last period (refined between searches), s
        self._last_search = -math.inf  # when the whole period range was last searched

    def observe(self, t_s: float, pos_enu, vel_enu, vel_std_m_s: float, pos_vel_cov,
                tgo_s: float = math.inf) -> None:
        """A fused estimate at ``t_s``: its position, velocity, horizontal velocity std and position-velocity
        covariance (6 x 6, or None when the filter has none); ``tgo_s``: the time in which the camera closes on
        it (range over closing speed; inf when it does not close), for the hold (``hold_tgo_s``)."""
        c = self.cfg
        vel = np.asarray(vel_enu, dtype=float)
        speed = math.hypot(float(vel[0]), float(vel[1]))
        if c.hold_tgo_s > 0.0:
            self.held = held_while_closing(self.held, tgo_s, c.hold_tgo_s)
        self.fitted = not self.held and t_s - self._last_t >= c.sample_s
        if self.fitted:
            self._last_t = t_s
            if speed < c.min_speed_m_s or not math.isfinite(speed):
                self._hist.clear()  # a course that means nothing breaks the history
                self._long.clear()
            else:
                course = math.atan2(float(vel[1]), float(vel[0]))
                if self._hist:
                    prev = self._hist[-1][1]
                    course = prev + (course - prev + math.pi) % (2.0 * math.pi) - math.pi
                sig = max(float(vel_std_m_s) / speed, 1e-3) if math.isfinite(vel_std_m_s) else 1.0
                self._hist.append((t_s, course, 1.0 / (sig * sig)))
                if c.periodic.enabled:
                    self._long.append(self._hist[-1])
            while self._hist and self._hist[0][0] < t_s - c.window_s:
                self._hist.popleft()
            while self._long and self._long[0][0] < t_s - c.periodic.window_s:
                self._long.popleft()
            self.turn_rad_s = self._steady(t_s, self._fit())
            self.periodic = self._fit_periodic() if c.periodic.enabled else None
        self._fused = None
        self._lag = (0.0, 0.0)
        if self.periodic is not None and pos_vel_cov is not None:
            self._observe_periodic(t_s, pos_enu, vel, pos_vel_cov)
        elif self.turn_rad_s != 0.0 and pos_vel_cov is not None:
            lags = lag_matrices(pos_vel_cov)
            if lags is not None:
                pos = np.array(pos_enu, dtype=float)
                mv, mp = lags
                a = self.turn_rad_s * np.array([-vel[1], vel[0]])  # w x v, horizontal
                dv, dp = mv @ a, mp @ a
                cap = c.max_lag_s
                if math.hypot(*dv) <= cap * math.hypot(*a) and math.hypot(*dp) <= 0.5 * cap * cap * math.hypot(*a):
                    v2 = vel.copy()
                    v2[:2] += dv
                    pos[:2] += dp
                    self._fused = (t_s, pos, v2)
                    self._lag = (math.hypot(*dv), math.hypot(*dp))

    def _fit_periodic(self) -> PeriodicCourse | None:
        """The periodic course of the last periodic.window_s when it passes the tests (see the module text)."""
        pc = self.cfg.periodic
        if len(self._long) < 8:
            return None
        h = np.array(self._long)
        span = float(h[-1, 0] - h[0, 0])
        top = min(pc.max_period_s, span)
        if span < pc.min_span_s or top < pc.min_period_s:
            return None
        t_s = float(h[-1, 0])
        g = self._period_guess
        if g is not None and t_s - self._last_search < pc.search_every_s and pc.min_period_s <= g <= top:
            # between searches, the period found last time and its neighbours (the period drifts slowly)
            periods = np.clip(g + pc.period_step_s * np.array([-1.0, 0.0, 1.0]), pc.min_period_s, top)
        else:
            periods = np.arange(pc.min_period_s, top + 1e-9, pc.period_step_s)
            self._last_search = t_s
        fit = fit_periodic(h[:, 0], h[:, 1], h[:, 2], periods)
        self._period_guess = fit.period_s if fit is not None else None
        # the period must lie inside the range searched, a step from its ends: a smooth bend of the course
        # (a turn's settling, a slow change of course) fits best with the longest period the span allows
        inside = pc.min_period_s + pc.period_step_s <= fit.period_s <= top - pc.period_step_s if fit else False
        if (not inside or fit.amplitude_rad < math.radians(pc.min_amplitude_deg)
                or fit.explained < pc.min_explained):
            return None
        return fit

    def _observe_periodic(self, t_s: float, pos_enu, vel: np.ndarray, pos_vel_cov) -> None:
        """The fused estimate with the periodic course: its velocity along the course ``tau`` ahead of the
        fitted one, its position's lag for that course's turn taken out."""
        lags = lag_matrices(pos_vel_cov)
        if lags is None:
            return
        mv, mp = lags
        tau = 0.5 * float(np.trace(mv))
        if not 0.0 <= tau <= self.cfg.max_lag_s:
            return
        speed = math.hypot(float(vel[0]), float(vel[1]))
        course, w = self.periodic.course(t_s + tau), self.periodic.rate(t_s + tau)
        v2 = vel.copy()
        v2[0], v2[1] = speed * math.cos(course), speed * math.sin(course)
        a = w * np.array([-v2[1], v2[0]])
        dp = mp @ a
        if math.hypot(*dp) > 0.5 * self.cfg.max_lag_s ** 2 * math.hypot(*a):
            return
        pos = np.array(pos_enu, dtype=float)
        pos[:2] += dp
        self._tau = tau
        self._fused = (t_s, pos, v2)
        self._lag = (math.hypot(float(v2[0] - vel[0]), float(v2[1] - vel[1])), math.hypot(*dp))

    def status(self, t_s: float) -> CourseTurnStatus:
        """The finder now, for the log."""
        p = self.periodic
        if p is not None and self._fused is not None:
            turn = p.rate(t_s + self._tau)
            return CourseTurnStatus(t_s, 0.0 - math.degrees(turn), 0.0 - math.degrees(self.fit_rad_s), self.held,
                                    *self._lag, p.period_s, math.degrees(p.amplitude_rad))
        return CourseTurnStatus(t_s, 0.0 - math.degrees(self.turn_rad_s), 0.0 - math.degrees(self.fit_rad_s), self.held,
                                *self._lag)

    def _fit(self) -> float:
        """The course's slope over the window when it stands out (else 0), rad/s."""
        c = self.cfg
        self.fit_rad_s = math.nan
        n = len(self._hist)
        if n < 3:
            return 0.0
        h = np.array(self._hist)
        t, y, w = h[:, 0], h[:, 1], h[:, 2]
        span = float(t[-1] - t[0])
        if span < c.min_span_frac * c.window_s:
            return 0.0
        sw = w.sum()
        tm, ym = (w * t).sum() / sw, (w * y).sum() / sw
        stt = (w * (t - tm) ** 2).sum()
        if not stt > 0.0:
            return 0.0
        slope = float((w * (t - tm) * (y - ym)).sum() / stt)
        self.fit_rad_s = slope
        res = y - ym - slope * (t - tm)
        # the slope's std from the residuals' weighted variance, with one independent residual per
        # residual_corr_s (the estimate's course is smooth: its neighbours' errors are one error)
        n_eff = min(max(span / c.residual_corr_s, 3.0), float(n))
        var = float((w * res * res).sum() / sw) * n_eff / (n_eff - 2.0)
        slope_std = math.sqrt(var / (n_eff * stt / sw))
        turn = abs(slope)
        if turn < math.radians(c.min_turn_deg_s) or turn < c.significance * slope_std:
            return 0.0
        return math.copysign(min(turn, math.radians(c.max_turn_deg_s)), slope)

    def _steady(self, t_s: float, turn: float) -> float:
        """``turn`` when the fits of the last ``steady_s`` all found a turn within ``steady_tol_deg_s`` (or
        ``steady_tol_frac`` of it) of it: a steady turn, not a zigzag's swing; else 0."""
        c = self.cfg
        if c.steady_s <= 0.0:
            return turn
        self._fits.append((t_s, turn))
        while self._fits and self._fits[0][0] < t_s - c.steady_s:
            self._fits.popleft()
        if turn == 0.0 or self._fits[0][0] > t_s - c.steady_s + c.sample_s + 1e-9:
            return 0.0
        tol = max(math.radians(c.steady_tol_deg_s), c.steady_tol_frac * abs(turn))
        return turn if all(w != 0.0 and abs(w - turn) <= tol for _, w in self._fits) else 0.0

    def state(self, t_s: float) -> tuple[np.ndarray, np.ndarray, float] | None:
        """(position, velocity, turn rate) at ``t_s``: the last fused estimate with the lag taken out, carried
        along the turn (or the periodic course); None when no turn is in use (the estimate stands as it is)."""
        if self._fused is None:
            return None
        if self.periodic is not None:
            return self._periodic_state(t_s)
        if self.turn_rad_s == 0.0:
            return None
        t0, pos, vel = self._fused
        w = self.turn_rad_s
        dt = t_s - t0
        # the circle at constant speed: v(t) = R(w t) v0, p(t) = p0 + (sin(w t) / w) v0 + ((1 - cos(w t)) / w) z x v0
        s, k = math.sin(w * dt), math.cos(w * dt)
        vx, vy = float(vel[0]), float(vel[1])
        p, v = pos.copy(), vel.copy()
        p[0] += (s * vx - (1.0 - k) * vy) / w
        p[1] += (s * vy + (1.0 - k) * vx) / w
        p[2] += float(vel[2]) * dt
        v[0], v[1] = k * vx - s * vy, s * vx + k * vy
        return p, v, w

    def _periodic_state(self, t_s: float) -> tuple[np.ndarray, np.ndarray, float]:
        """The last fused estimate carried along the periodic course to ``t_s`` (midpoint steps of at most
        0.5 s at the fused speed)."""
        t0, pos, vel = self._fused
        pc, tau = self.periodic, self._tau
        speed = math.hypot(float(vel[0]), float(vel[1]))
        dt = t_s - t0
        n = max(1, math.ceil(abs(dt) / 0.5))
        h = dt / n
        p = pos.copy()
        for i in range(n):
            course = pc.course(t0 + (i + 0.5) * h + tau)
            p[0] += speed * math.cos(course) * h
            p[1] += speed * math.sin(course) * h
        p[2] += float(vel[2]) * dt
        course = pc.course(t_s + tau)
        v = vel.copy()
        v[0], v[1] = speed * math.cos(course), speed * math.sin(course)
        return p, v, pc.rate(t_s + tau)
