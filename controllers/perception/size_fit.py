"""A ship of the class's layout but another size, learnt from its boxes (:class:`ShipSize`, ``size_fit``)."""
from __future__ import annotations

import math

import numpy as np

from controllers.config import SizeFitConfig
from controllers.navigation.camera_model import PinholeCamera
from controllers.perception.ship_outline import ShipOutline, at_image_border, predicted_box_px

__all__ = ["ShipSize"]


class ShipSize:
    """The ship's length, beam and height as multiples of the class's, fitted to the sizes of its boxes.

    The box-centre correction is only as good as the outline it projects: a ship 30 % taller than the class
    has its box centre higher than the class's, and the corrected point, taken for the tracked point on the
    sea, lies that height over the tangent of the view's depression farther along the line of sight (in a
    -30 deg dive, 4 m for a 25 m class). The boxes tell the real sizes: seen from round the loiter ring
    their widths and heights mix the length, beam and height differently with every relative heading.

    Each box seen at a sure heading (the box shapes' headings with a known course fused in, their weighted
    mean; at most ``rate_hz`` boxes a second, consecutive frames being nearly alike) updates the log scales
    ``theta = log(L / L_class, W / W_class, H / H_class)`` with an extended Kalman step on
    ``log(box width, height) - log(predicted width, height at theta)``, the prediction midway (in log) between
    the outline without its mast and with it, half their difference in the box's noise (a thin mast is not
    in a far box; close in it shows: fitted to the outline with it a ship exactly of the class came out 8 %
    low, to the one without it up to 22 % tall in a shallow dive), its Jacobian by finite differences, prior
    N(0, prior_std^2) per axis, a chi-square gate against boxes cut short (the UAV's own airframe in view),
    and a fresh start from the prior when it has turned ``max_gated_in_a_row`` boxes away in a row (then the
    fit is off, not the boxes); a box's noise grows as it gets small (``box_px_std`` over its size); a box at
    the image's edge is not taken at all. After ``min_updates`` boxes the perception corrects with the fitted
    outline (:attr:`scale`, the whole outline scaled); before, with the class's, and for good once the fit has
    started again ``class_after_restarts`` times (:attr:`retired`).

    The ranges come from the estimate, so the fitted scale carries its range error (1 % at 500 m for 5 m):
    harmless to the correction, which scales with it.
    """

    _STEP = 0.02  # finite-difference step of the log scales
    _STEP_FACTORS = np.exp(_STEP * np.eye(3))  # a step in each log scale, as factors of the scales

    def __init__(self, cfg: SizeFitConfig, outline: ShipOutline, camera: PinholeCamera, edge_px: float = 6.0):
        self.cfg = cfg
        self.outline = outline
        self.camera = camera
        self.edge_px = edge_px
        self.x = np.zeros(3)
        self.P = np.eye(3) * cfg.prior_std ** 2
        self.updates = 0
        self.gated = 0
        self.gated_in_a_row = 0
        self.restarts = 0
        self.retired = False  # the class's outline for good (class_after_restarts)
        self._last_t = -math.inf  # when the last box was weighed

    def takes_boxes(self, t_s: float | None = None) -> bool:
        """Whether a box at ``t_s`` would be looked at: the fit on, not retired, ``1 / rate_hz`` after the last
        box weighed (None: no rate limit)."""
        return self.cfg.enabled and not self.retired and (
            t_s is None or t_s - self._last_t >= 1.0 / self.cfg.rate_hz - 1e-9)

    @property
    def theta(self) -> np.ndarray:
        """The log scales (length, beam, height)."""
        return self.x[:3]

    @property
    def scale(self) -> np.ndarray | None:
        """The fitted (length, beam, height) multipliers once in use, else None (the class's outline)."""
        if not self.cfg.enabled or self.retired or self.updates < self.cfg.min_updates:
            return None
        return np.exp(self.x[:3])

    def update(self, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, course_enu_rad: float, box_px,
               t_s: float | None = None) -> bool:
        """Take one detected box seen with the ship on ``course_enu_rad`` (its waterline centre ``ref_enu_m``,
        estimated) at ``t_s`` (None: whenever, no rate limit); True when it moved the fit. A box within
        ``1 / rate_hz`` of the last one weighed (taken or gated) is not looked at."""
        cfg = self.cfg
        if not self.takes_boxes(t_s):
            return False
        b = np.asarray(box_px, dtype=float)
        cam = self.camera
        if b.shape != (4,) or not np.isfinite(b).all() or b[2] - b[0] < 2.0 or b[3] - b[1] < 2.0:
            return False
        if at_image_border(cam, b, self.edge_px):
            return False  # a box at the image's edge is cut: not the ship's size
        d = np.asarray(ref_enu_m, float) - np.asarray(cam_pos_enu_m, float)
        if math.sqrt(d.dot(d)) < cfg.min_range_m:  # (np.linalg.norm's numbers, without its wrapper)
            return False
        logs = self._predicted_log_sizes(cam_pos_enu_m, R_enu_from_cam, ref_enu_m, course_enu_rad)
        if logs is None:
            return False
        J = (logs[1:4] - logs[0]).T / self._STEP  # (2, 3): d log(width, height) / d log scales
        det_size = np.array([b[2] - b[0], b[3] - b[1]])
        # the detector's box may or may not take in the thin mast (close in it shows): midway, +- half of it
        mast = 0.5 * (logs[4] - logs[0])
        y = np.log(det_size) - logs[0] - mast
        Rn = np.diag(cfg.box_std ** 2 + (cfg.box_px_std / det_size) ** 2)  # small far boxes weigh less
        Rn = Rn + np.outer(mast, mast)
        S = J @ self.P @ J.T + Rn
        det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
        if not det > 0.0:
            return False
        if t_s is not None:
            self._last_t = float(t_s)
        Si = np.array([[S[1, 1], -S[0, 1]], [-S[1, 0], S[0, 0]]]) / det
        if float(y @ Si @ y) > cfg.gate:
            self._gate_away()
            return False
        self.gated_in_a_row = 0
        K = self.P @ J.T @ Si
        I_KJ = np.eye(3) - K @ J
        self.P = I_KJ @ self.P @ I_KJ.T + K @ Rn @ K.T  # Joseph form
        lim = math.log(cfg.max_scale)
        self.x = (self.x + K @ y).clip(-lim, lim)  # (np.clip's call)
        self.updates += 1
        return True

    def _predicted_log_sizes(self, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, course_enu_rad: float):
        """log(width, height) (5, 2) of the boxes the detector would draw round the outline at the fit, at a
        step in each log scale (those four without the mast) and at the fit with its mast; None where one is
        not seen whole (off the view, clipped by the image) or comes out a pixel or less."""
        cam = self.camera
        s0 = np.exp(self.x[:3])
        # the fit and a step in each log scale (the outline without its mast), and the fit with its mast
        scales = np.vstack([s0, s0 * self._STEP_FACTORS, s0])
        outlines = [self.outline.body] * 4 + [self.outline]
        sizes = np.empty((len(scales), 2))
        for i, (sc, o) in enumerate(zip(scales, outlines)):
            pb = predicted_box_px(o, cam, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, course_enu_rad, sc)
            if pb is None or not np.isfinite(pb).all():
                return None
            if cam.width_px > 0 and (pb[0] <= 0.0 or pb[1] <= 0.0 or pb[2] >= cam.width_px - 1.0
                                     or pb[3] >= cam.height_px - 1.0):
                return None  # the predicted box is clipped: its size is not the outline's
            sizes[i] = (pb[2] - pb[0], pb[3] - pb[1])
        sizes *= self.cfg.box_scale  # what the detector draws round that silhouette
        if (sizes <= 1.0).any():
            return None
        return np.log(sizes)

    def _gate_away(self) -> None:
        """A box the gate turned away; after ``max_gated_in_a_row`` in a row the fit, not the boxes, is off:
        start again from the prior (and retire after ``class_after_restarts`` restarts)."""
        cfg = self.cfg
        self.gated += 1
        self.gated_in_a_row += 1
        if self.gated_in_a_row >= cfg.max_gated_in_a_row:
            self.x = np.zeros(3)
            self.P = np.eye(3) * cfg.prior_std ** 2
            self.updates = 0
            self.gated_in_a_row = 0
            self.restarts += 1
            self.retired = 0 < cfg.class_after_restarts <= self.restarts
