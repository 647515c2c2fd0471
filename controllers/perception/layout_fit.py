"""Which end of the ship its superstructure stands at, from where the box centres fall (:class:`LayoutFit`,
``layout_fit``)."""
from __future__ import annotations

import math

import numpy as np

from controllers.config import LayoutFitConfig
from controllers.navigation.camera_model import PinholeCamera, depth_on_plane, ground_from_pixel_jacobian
from controllers.perception.ship_outline import ShipOutline, at_image_border, box_centre_offset_px, predicted_boxes_px

__all__ = ["LayoutFit"]


def _pixel_on_plane(camera: PinholeCamera, uv, cam_pos: np.ndarray, R: np.ndarray, plane_z: float):
    """(the point (3,) where pixel ``uv``'s ray meets the plane z = ``plane_z``, its normalised image
    coordinates x1, x2), or None where the ray does not come down to it
    (:func:`~controllers.navigation.camera_model.depth_on_plane`)."""
    x1, x2 = (float(uv[0]) - camera.cx) / camera.fx, (float(uv[1]) - camera.cy) / camera.fy
    Z = depth_on_plane(x1, x2, R, float(cam_pos[2]), plane_z)
    if not math.isfinite(Z):
        return None
    return cam_pos + Z * (R @ np.array([x1, x2, 1.0])), x1, x2


class LayoutFit:
    """Which end of the ship its superstructure stands at: the class's layout or the other end
    (:class:`ShipOutline` ``other_end``), from where the box centres fall while the ship's course is known.

    Each layout corrects a box centre differently (a superstructure aft pulls the box aft and up, more so
    the more it is seen end on): the corrected centre's ray, met with the tracked point's plane, is where that
    layout puts the ship. Over the last ``window_s`` the ground points of the right layout lie on one smooth
    track; the wrong layout's wander off it as the view goes round the ship, by up to twice the box centre's
    pull. The points are taken relative to the estimated velocity integrated over time (which follows a
    manoeuvre), and each layout's are fitted by a track of constant acceleration (weighted least squares:
    each point's error is the pixel noise seen through its view, with a floor, ``point_floor_m``); what the
    fit leaves, divided by the better layout's reduced chi-square when that is above 1 (a misfit both
    share, a manoeuvre the track does not follow or a size not yet learnt, is no evidence) and tempered to
    ``max_effective`` boxes, weighs the two layouts against the prior (``prior_other_end``). The box shapes
    add their say (``shape_weight``): the heading-from-shapes posterior is worked out with the class's
    outline, which turned end for end is the other end's, so its log ratio at the reverse of the course over
    the course (:meth:`ShapeHeading.reverse_log_ratio`; each box's clipped to ``shape_clip``), averaged over
    the window, is added to the log-odds. Once the other
    end's probability reaches ``switch_probability`` the correction takes it (and back once the class's
    does). The course comes from the estimated velocity: a still ship's
    two layouts are its two headings, which the box shapes weigh (:class:`ShapeHeading`); nothing is learnt
    while the course is unknown, and the fit stops learning at the terminal switch (:meth:`hold`), where the
    airframe starts to cut the boxes.

    Nothing here reads the simulated ship: only the flight software's outline and its own estimate."""

    def __init__(self, cfg: LayoutFitConfig, outlines: tuple[ShipOutline, ShipOutline], camera: PinholeCamera,
                 pixel_noise_px: float = 2.0, edge_px: float = 6.0):
        self.cfg = cfg
        self.outlines = outlines  # (the class's, the other end)
        self.camera = camera
        self.pixel_noise_px = float(pixel_noise_px)
        self.edge_px = float(edge_px)
        # the window's points, oldest first, in rows [lo, hi) of arrays that are compacted when full: time, each
        # layout's ground point (east, north; relative to the dead reckoning), its weight (2 x 2)
        cap = int(math.ceil(cfg.window_s * cfg.rate_hz)) + 16
        self._t, self._g, self._w = np.zeros(cap), np.zeros((2, cap, 2)), np.zeros((cap, 2, 2))
        self._s = np.full(cap, math.nan)  # the box shapes' log ratio for the other end (shape_weight), clipped
        self._lo = self._hi = 0
        self._last_t = -math.inf
        self._dr = (0.0, 0.0)  # the estimated velocity integrated (dead reckoning), east, north, m
        self._dr_t, self._dr_v = math.nan, (0.0, 0.0)  # (on Python floats: this runs with every box)
        self.other_end = False  # the correction uses the other end's layout
        self.p_other_end = float(cfg.prior_other_end)
        self.held = False
        self.switches = 0
        self.misfit_per_dof = math.nan  # the better layout's reduced chi-square about its track

    def hold(self) -> None:
        """Stop learning (the terminal switch): the layout stays as it is."""
        self.held = True

    def observe(self, t_s: float, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, box_px, course_enu_rad,
                tracked_height_m: float, scale=None, vel_enu=None, shape_log_ratio=None) -> bool:
        """Take one box (the ship's waterline centre estimated at ``ref_enu_m``, on ``course_enu_rad``: a float,
        None when unknown, or a function that gives it, asked only when the box is taken; its estimated
        velocity ``vel_enu``, which the ground points are taken relative to; ``shape_log_ratio``: a function of
        the course that gives the box shapes' log ratio for the other end, or None, :meth:`ShapeHeading.
        reverse_log_ratio`); ``scale``: the sizes both layouts are projected at (None: the class's); True when
        the layout in use changed."""
        c = self.cfg
        if vel_enu is not None and c.enabled and not self.held:
            ve, vn = float(vel_enu[0]), float(vel_enu[1])
            if math.isfinite(ve) and math.isfinite(vn):
                if math.isfinite(self._dr_t) and t_s > self._dr_t:  # the trapezoid since the last box
                    dt = t_s - self._dr_t
                    self._dr = (self._dr[0] + 0.5 * (self._dr_v[0] + ve) * dt,
                                self._dr[1] + 0.5 * (self._dr_v[1] + vn) * dt)
                self._dr_t, self._dr_v = float(t_s), (ve, vn)
        if not c.enabled or self.held or course_enu_rad is None or t_s - self._last_t < 1.0 / c.rate_hz - 1e-9:
            return False
        if callable(course_enu_rad):
            course_enu_rad = course_enu_rad()
            if course_enu_rad is None:
                return False
        b = np.asarray(box_px, dtype=float)
        cam = self.camera
        if b.shape != (4,) or not np.isfinite(b).all() or at_image_border(cam, b, self.edge_px):
            return False
        ref = np.asarray(ref_enu_m, dtype=float)
        cam_pos = np.asarray(cam_pos_enu_m, dtype=float)
        R = np.asarray(R_enu_from_cam, dtype=float)
        uv = 0.5 * np.array([b[0] + b[2], b[1] + b[3]])
        det = np.array([b[2] - b[0], b[3] - b[1]])
        plane = float(ref[2]) + tracked_height_m
        points = []
        for outline in self.outlines:
            box = predicted_boxes_px(outline, cam, cam_pos, R, ref, [course_enu_rad], scale)[0]
            if not np.isfinite(box).all():
                return False
            size = box[2:4] - box[0:2]
            if not ((det > 0.5 * size).all() and (det < 2.0 * size).all()):  # cut short, or not this ship
                return False
            off = box_centre_offset_px(outline, cam, cam_pos, R, ref, course_enu_rad, tracked_height_m,
                                       boxes_px=box[None, :], scale=scale)
            if off is None:
                return False
            g = self._ground(uv - off, cam_pos, R, plane)
            if g is None:
                return False
            points.append(g)
        g0, J = points[0][0], np.column_stack([points[0][1], points[0][2]])  # d(ground)/d(u, v), m per px
        cov = (self.pixel_noise_px ** 2) * (J @ J.T) + (c.point_floor_m ** 2) * np.eye(2)
        self._last_t = float(t_s)
        dr = np.array(self._dr)
        shape = shape_log_ratio(course_enu_rad) if shape_log_ratio is not None and c.shape_weight > 0.0 else None
        shape = math.nan if shape is None else max(-c.shape_clip, min(c.shape_clip, shape))
        self._append(float(t_s), g0 - dr, points[1][0] - dr, np.linalg.inv(cov), shape)
        while self._lo < self._hi and self._t[self._lo] < t_s - c.window_s:
            self._lo += 1
        return self._decide()

    @property
    def boxes(self) -> int:
        """The boxes in the fit's window."""
        return self._hi - self._lo

    def _append(self, t_s: float, g_class: np.ndarray, g_other: np.ndarray, w: np.ndarray,
                shape: float = math.nan) -> None:
        if self._hi == len(self._t):  # full: the window's rows to the front
            n, lo = self._hi - self._lo, self._lo
            hi = self._hi
            self._t[:n], self._g[:, :n], self._w[:n] = self._t[lo:hi], self._g[:, lo:hi], self._w[lo:hi]
            self._s[:n] = self._s[lo:hi]
            self._lo, self._hi = 0, n
            if n == len(self._t):  # (a rate above rate_hz cannot happen; grow rather than lose a point)
                self._t = np.concatenate([self._t, np.zeros(n)])
                self._g = np.concatenate([self._g, np.zeros((2, n, 2))], axis=1)
                self._w = np.concatenate([self._w, np.zeros((n, 2, 2))])
                self._s = np.concatenate([self._s, np.full(n, math.nan)])
        k = self._hi
        self._t[k], self._g[0, k], self._g[1, k], self._w[k], self._s[k] = t_s, g_class, g_other, w, shape
        self._hi += 1

    def shape_evidence(self) -> float:
        """The box shapes' log-odds for the other end over the window: ``shape_weight`` times the mean of the
        boxes' clipped log ratios (those that had one); 0 when none did."""
        s = self._s[self._lo:self._hi]
        s = s[np.isfinite(s)]
        return self.cfg.shape_weight * float(s.mean()) if s.size else 0.0

    def _ground(self, uv: np.ndarray, cam_pos: np.ndarray, R: np.ndarray, plane_z: float):
        """(the ground point of pixel ``uv`` on the plane z = ``plane_z``, its derivative by u and by v: m per px,
        :func:`controllers.navigation.camera_model.ground_from_pixel_jacobian`) or None where the ray does not come
        down to it (:func:`~controllers.navigation.camera_model.depth_on_plane`)."""
        hit = _pixel_on_plane(self.camera, uv, cam_pos, R, plane_z)
        if hit is None:
            return None
        g, x1, x2 = hit
        cam = self.camera
        J = ground_from_pixel_jacobian(x1, x2, R, float(cam_pos[2]), plane_z, cam.fx, cam.fy)
        return g[:2], J[:2, 0], J[:2, 1]

    def misfits(self) -> tuple[float, float, int] | None:
        """(each layout's weighted sum of squares about its best track, the boxes in the window), or None."""
        n = self._hi - self._lo
        if n < max(self.cfg.min_boxes, 4):
            return None
        lo, hi = self._lo, self._hi
        t = self._t[lo:hi]
        tau = t - 0.5 * (t[0] + t[-1])
        basis = np.stack([np.ones(n), tau, 0.5 * tau * tau], axis=1)  # (n, 3): position, velocity, acceleration
        W = self._w[lo:hi]  # (n, 2, 2)
        # the normal equations of g_i = theta^T basis_i (theta 3 x 2: [p; v; a] in east, north), each point
        # weighted by W_i: sum (b b^T) (x) W  and  sum b (x) W g
        A = np.einsum("ij,ik,iab->jakb", basis, basis, W).reshape(6, 6)
        out = []
        for k in (0, 1):
            g = self._g[k, lo:hi]  # (n, 2)
            Wg = np.einsum("iab,ib->ia", W, g)
            y = np.einsum("ij,ia->ja", basis, Wg).reshape(6)
            try:
                theta = np.linalg.solve(A, y).reshape(3, 2)
            except np.linalg.LinAlgError:
                return None
            r = g - basis @ theta
            out.append(float(np.einsum("ia,iab,ib->", r, W, r)))
        return out[0], out[1], n

    def _decide(self) -> bool:
        fit = self.misfits()
        if fit is None:
            return False
        ss_class, ss_other, n = fit
        c = self.cfg
        k = min(1.0, c.max_effective / n)
        # the points' errors scaled so that the better layout's track fits them as their noise says (its
        # reduced chi-square, when above 1: a manoeuvre the track does not follow, a size the fit has not
        # learnt): a misfit both layouts share is no evidence for either
        self.misfit_per_dof = min(ss_class, ss_other) / max(2.0 * n - 6.0, 1.0)
        k /= max(self.misfit_per_dof, 1.0)
        logit = math.log(c.prior_other_end / (1.0 - c.prior_other_end)) + 0.5 * k * (ss_class - ss_other) \
            + self.shape_evidence()
        self.p_other_end = _expit(logit)
        was = self.other_end
        if not was and self.p_other_end >= c.switch_probability:
            self.other_end = True
        elif was and self.p_other_end <= 1.0 - c.switch_probability:
            self.other_end = False
        if self.other_end != was:
            self.switches += 1
            return True
        return False


def _expit(x: float) -> float:
    """``scipy.special.expit`` of a float (the same number: 1 / (1 + exp(-x)), 0 where exp(-x) overflows),
    without importing scipy.special (a fifth of a second of every run's start)."""
    try:
        return 1.0 / (1.0 + math.exp(-x))
    except OverflowError:
        return 0.0
