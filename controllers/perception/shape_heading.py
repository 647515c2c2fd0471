"""A still ship's heading from the shapes of its boxes (:class:`ShapeHeading`, ``heading_from_shape``): the
headings and turn rates the box sizes seen from round the loiter ring allow, weighed against the outline's
predicted boxes (``controllers.perception.ship_outline``)."""
from __future__ import annotations

import math

import numpy as np

from controllers.config import ShapeHeadingConfig
from controllers.navigation.camera_model import PinholeCamera
from controllers.perception.ship_outline import ShipOutline, at_image_border, predicted_boxes_px

__all__ = ["ShapeHeading"]


class ShapeHeading:
    """The ship's heading from the sizes of its detected boxes: a posterior over ``cfg.headings`` headings.

    The width and height of the box around the silhouette depend on the ship's heading relative to the line
    of sight, so a loiter round the ship, which sees it from many bearings, tells its heading (often up to
    bow or stern: where the two differ in the model's box sizes, the fit picks the right one). Each used
    detection adds, for every candidate heading, the robust (Cauchy) log-likelihood of its box sides against
    :func:`predicted_boxes_px` for that heading, for each of a grid of size biases (the detected widths, and
    apart the heights, off the model's by one unknown fraction, ``size_bias_range``), which each heading's
    likelihood is marginalised over; the posterior is tempered so that it never counts more than
    ``max_effective_updates`` detections. A detection whose box touches the image border says nothing of the
    size and is not used; nor is one taken less than ``1 / rate_hz`` after the last used one.

    A ship may turn while its course is unknown (a slow ship turning or zigzagging: nothing to follow). Each
    of ``turn_rates_deg_s`` is a hypothesis with evidence of its own, each box weighed at the heading that rate
    would have turned the ship to since the first (to the grid's step); the posterior over the heading now
    sums them, weighted by their likelihoods and a prior (``turn_rate_prior_zero`` on rate 0). ``memory_s``
    fades the evidence meanwhile, so that a turn no one rate fits (a zigzag) is weighed at the headings of
    late. Once the course is followed again, the likeliest rate's evidence is kept alone (the
    course turns the posterior from then on).

    The box sizes come from the flight software's coarse outline (a priori knowledge of the ship class) and
    its own estimate of where the ship is: nothing here reads the simulated ship.
    """

    def __init__(self, cfg: ShapeHeadingConfig, outline: ShipOutline, camera: PinholeCamera, edge_px: float = 6.0):
        self.cfg = cfg
        self.outline = outline
        self.camera = camera
        self.edge_px = float(edge_px)
        self.courses_enu_rad = 2.0 * math.pi * np.arange(cfg.headings) / cfg.headings
        lo, hi = cfg.size_bias_range
        self.size_biases = np.linspace(lo, hi, cfg.size_bias_steps) if hi > lo else np.array([lo])
        # the turn rates while the course is unknown (turn_rates_deg_s), as course rates (counter-clockwise,
        # rad/s), their a priori log weights, and how far each has turned the ship since the first box (rad):
        # rate j's evidence at grid index k is for the course courses[k] + _rot[j] now
        rates = np.asarray(cfg.turn_rates_deg_s, dtype=float)
        self.turn_rates_rad_s = -np.radians(rates)
        zero = rates == 0.0
        if zero.any() and len(rates) > 1:
            prior = np.where(zero, cfg.turn_rate_prior_zero, (1.0 - cfg.turn_rate_prior_zero) / (len(rates) - 1))
        else:
            prior = np.full(len(rates), 1.0 / len(rates))
        self._log_rate_prior = np.log(np.maximum(prior, 1e-300))
        self._rot = np.zeros(len(rates))
        self._one_rate = True  # every rate's evidence is the same, turned alike (_keep_likeliest_rate)
        # per rate: bias, heading, (width, height): bias-major, so that the marginalisation's reductions over
        # the biases run down whole rows
        self._loglik_bias = [np.zeros((len(self.size_biases), cfg.headings, 2)) for _ in rates]
        self._loglik_rate = np.zeros((len(rates), cfg.headings))  # marginalised over the size bias
        self.updates = 0
        self._count = 0.0  # the updates the evidence holds (fewer than updates when it fades, memory_s)
        self._last_t = -math.inf
        self._weights = None  # weights() of the current loglik (it is asked for several times per detection)
        self._axis = None  # axis_enu_rad() of the current loglik
        self._course = None  # the estimated course at the last used detection (None: not followed then)

    def update(self, t_s: float, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, box_px,
               course_enu_rad: float | None = None) -> bool:
        """Use one detected box (u0, v0, u1, v1); True when it was used. ``course_enu_rad``: the ship's
        estimated course now when it is sure enough to follow (``follow_course``), else None: the posterior
        turns by the course's change since the last used detection before this box is added."""
        c = self.cfg
        b = np.asarray(box_px, dtype=float)
        if not c.enabled or t_s - self._last_t < 1.0 / c.rate_hz - 1e-9 or not np.all(np.isfinite(b)):
            return False
        cam = self.camera
        if at_image_border(cam, b, self.edge_px):
            return False
        pred = predicted_boxes_px(self.outline, cam, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, self.courses_enu_rad)
        if not np.all(np.isfinite(pred)):
            return False
        self._move_on(t_s - self._last_t if self.updates else 0.0, course_enu_rad)
        size_det = np.array([b[2] - b[0], b[3] - b[1]])
        size_now = np.stack([pred[:, 2] - pred[:, 0], pred[:, 3] - pred[:, 1]], axis=1)
        for j, (lb, shift) in enumerate(zip(self._loglik_bias, self._shifts())):
            # rate j's evidence at grid index k is for the heading courses[k + shift] now (to the grid's step)
            size_pred = size_now if not shift else np.roll(size_now, -shift, axis=0)
            scaled = size_pred[None, :, :] * (1.0 + self.size_biases)[:, None, None]  # (biases, headings, 2)
            r = (size_det[None, None, :] - scaled) / (c.sigma_fraction * scaled + c.sigma_px)
            lb -= np.log1p(0.5 * r * r)
            self._loglik_rate[j] = np.sum(_logsumexp_rows(lb), axis=1)
        self.updates += 1
        self._count += 1.0
        self._weights = self._axis = None
        self._last_t = t_s
        return True

    def _move_on(self, dt: float, course_enu_rad: float | None) -> None:
        """Before a box ``dt`` after the last one: turn the posterior with the followed course, or (the course
        not followed) turn each rate's evidence by its rate and fade it (``memory_s``)."""
        c = self.cfg
        if c.follow_course:
            if course_enu_rad is not None and self._course is not None and self.updates:
                most = math.radians(c.follow_course_max_rate_deg_s) * dt
                d = (course_enu_rad - self._course + math.pi) % (2.0 * math.pi) - math.pi
                self.turn(min(max(d, -most), most))
            self._course = None if course_enu_rad is None else float(course_enu_rad)
        if course_enu_rad is not None and len(self._rot) > 1 and not self._one_rate:
            self._keep_likeliest_rate()  # the course turns the ship now: no rate of its own to tell apart
        if course_enu_rad is None and dt > 0.0:
            # the course is not followed: each rate turns the ship on by itself, and the evidence fades
            self._one_rate = False
            self._rot += self.turn_rates_rad_s * dt
            if c.memory_s is not None:
                f = math.exp(-dt / c.memory_s)
                for lb in self._loglik_bias:
                    lb *= f
                self._count *= f

    def turn(self, angle_rad: float) -> None:
        """The ship has turned by ``angle_rad`` (counter-clockwise): the evidence for each heading moves to the
        heading that much further round (linear interpolation between the grid's neighbours)."""
        s = float(angle_rad) / (2.0 * math.pi / self.cfg.headings)
        if not s:
            return
        i = math.floor(s)
        f = s - i
        # evidence that was at heading k - s now belongs to heading k
        for j, lb in enumerate(self._loglik_bias):
            a = _roll_headings(lb, i)
            self._loglik_bias[j] = a if f == 0.0 else (1.0 - f) * a + f * _roll_headings(lb, i + 1)
            self._loglik_rate[j] = np.sum(_logsumexp_rows(self._loglik_bias[j]), axis=1)
        self._weights = self._axis = None

    def weights(self) -> np.ndarray:
        """Posterior weight of each candidate heading (sums to 1; uniform before any update). Unless
        ``tell_bow_from_stern``, a heading and its opposite share their summed weight equally."""
        if self._weights is None:
            self._weights = self._posterior()
        return self._weights.copy()

    def _keep_likeliest_rate(self) -> None:
        """Once the course is followed, the ship's turn is the course's: every rate's evidence becomes the most
        likely rate's (moved to the headings now), with no turn of its own, until the course is lost again.
        (A ship whose course is known most of the time is then weighed as with the one rate 0, bar the boxes
        of the seconds before its course was known.)"""
        j = int(np.argmax(self.rate_weights()))
        best = np.roll(self._loglik_bias[j], self._shifts()[j], axis=1)
        self._loglik_bias = [best.copy() for _ in self._loglik_bias]
        self._loglik_rate[:] = np.sum(_logsumexp_rows(best), axis=1)
        self._rot[:] = 0.0
        self._one_rate = True
        self._weights = self._axis = None

    def _shifts(self) -> list[int]:
        """How many grid steps each rate has turned the ship since the first box (to the nearest step)."""
        return [int(k) for k in np.rint(self._rot / (2.0 * math.pi / self.cfg.headings))]

    def _now_rows(self) -> np.ndarray:
        """Each rate's log-likelihood row moved to the headings now (:meth:`_shifts`)."""
        shifts = self._shifts()
        if not any(shifts):
            return self._loglik_rate
        return np.stack([np.roll(row, s) for row, s in zip(self._loglik_rate, shifts)])

    def _tempered_log_weights(self) -> np.ndarray:
        """(rates, headings now): each rate's a priori log weight plus its tempered log-likelihood (the
        posterior never counts more than ``max_effective_updates`` detections), less the largest."""
        lr = self._now_rows()
        scale = min(1.0, self.cfg.max_effective_updates / max(self._count, 1.0))
        lw = self._log_rate_prior[:, None] + scale * (lr - np.max(lr))
        return lw - np.max(lw)

    def rate_weights(self) -> np.ndarray:
        """Posterior weight of each of ``turn_rates_deg_s`` (tempered as the headings' are)."""
        w = np.sum(np.exp(self._tempered_log_weights()), axis=1)
        return w / np.sum(w)

    def _posterior(self) -> np.ndarray:
        w = np.sum(np.exp(self._tempered_log_weights()), axis=0)
        w = w / np.sum(w)
        n = len(w)
        if not self.cfg.tell_bow_from_stern and n % 2 == 0:
            w = 0.5 * _with_opposite(w)
        return w

    def axis_enu_rad(self) -> float:
        """Direction of the ship's fore-aft axis (counter-clockwise from East, in [0, pi)): the most likely
        heading folded onto its opposite (kept until the next update)."""
        if self._weights is None or self._axis is None:
            w = self.weights()
            n = len(w)
            k = int(np.argmax(_with_opposite(w)[: n // 2])) if n % 2 == 0 else int(np.argmax(w))
            self._axis = float(self.courses_enu_rad[k]) % math.pi
        return self._axis

    @property
    def ready(self) -> bool:
        return self.cfg.enabled and self.updates >= self.cfg.min_updates

    def headings(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(courses, weights) of the plausible headings (weights renormalised), or None while not ready."""
        w = self.heading_weights()
        return None if w is None else plausible(self.courses_enu_rad, w, self.cfg.min_weight)

    def heading_weights(self) -> np.ndarray | None:
        """The weight of every heading of the grid (:attr:`courses_enu_rad`), or None while not ready."""
        if not self.ready:
            return None
        return self.weights()

    def reverse_log_ratio(self, course_enu_rad: float) -> float | None:
        """The log of the posterior's weight at the reverse of ``course_enu_rad`` over its weight at it (the
        grid's nearest heading), or None while not ready or when bow and stern share their weight
        (``tell_bow_from_stern`` off). Worked out with the class's layout, whose outline turned end for end is
        the other end's (:class:`ShipOutline` ``other_end``; the hull is the same either way round): with the
        course known, it is the shapes' evidence that the superstructure stands at the other end."""
        n = self.cfg.headings
        if not self.ready or not self.cfg.tell_bow_from_stern or n % 2:
            return None
        lw = _logsumexp_rows(self._tempered_log_weights())  # (headings,): the posterior's log, unnormalised
        k = int(round(float(course_enu_rad) / (2.0 * math.pi / n))) % n
        return float(lw[(k + n // 2) % n] - lw[k])

    def off_axis_rad(self, course_enu_rad: float) -> float:
        """How far (rad, 0..pi/2) a direction lies off the ship's axis."""
        d = (course_enu_rad - self.axis_enu_rad()) % math.pi
        return min(d, math.pi - d)


def course_likelihood(courses: np.ndarray, course: float, sig_rad: float) -> np.ndarray:
    """The Gaussian likelihood (unnormalised) of each of ``courses`` under ``course`` with std ``sig_rad``,
    the difference taken round the circle."""
    d = (courses - course + math.pi) % (2.0 * math.pi) - math.pi
    return np.exp(-0.5 * (d / sig_rad) ** 2)


def _with_opposite(w: np.ndarray) -> np.ndarray:
    """Each heading's weight plus its opposite's (bow and stern swapped), on a grid of an even count of headings
    all round."""
    return w + np.roll(w, len(w) // 2)


def plausible(courses: np.ndarray, w: np.ndarray, min_weight: float) -> tuple[np.ndarray, np.ndarray]:
    """(courses, weights) of the headings with at least ``min_weight`` of the largest weight, renormalised (the
    array methods: np.max's and np.sum's numbers, without their wrappers)."""
    keep = w >= min_weight * w.max()
    wk = w[keep]
    return courses[keep], wk / wk.sum()


def _roll_headings(a: np.ndarray, k: int) -> np.ndarray:
    """``np.roll(a, k, axis=1)`` (the same array) by two slices, without its general-case overhead."""
    n = a.shape[1]
    k %= n
    return np.concatenate((a[:, n - k:], a[:, :n - k]), axis=1)


def _logsumexp_rows(a: np.ndarray) -> np.ndarray:
    """``scipy.special.logsumexp(a, axis=0)``: for finite ``a`` its very operations (the same numbers, bit for
    bit: the largest entries of a column taken out, counted and added back in log) without its array-API
    dispatch, which costs most of its time on the posterior's few thousand entries; else scipy's own."""
    if np.isfinite(a).all():
        a_max = a.max(axis=0)
        top = a == a_max
        m = top.sum(axis=0, dtype=float)
        e = np.exp(a - a_max)
        e[top] = 0.0  # (scipy's exp(-inf - a_max))
        s = e.sum(axis=0)
        s = np.where(s == 0, s, s / m)
        out = np.log1p(s) + np.log(m) + a_max
        if np.isfinite(out).all():
            return out
    import scipy.special  # only here: its import is a fifth of a second of every run's start
    return scipy.special.logsumexp(a, axis=0)
