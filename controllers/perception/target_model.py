"""What the flight software knows of the target's shape: where a detector's box centre lies.

A detector (YOLO in the paper) returns the box around the ship's visible
silhouette. The UKF (paper eq. 9) treats the box centre as the image of one
point of the ship. It is not: the box centre moves over the ship with the view.
For the paper's ship class (superstructure and mast aft of midships, tapered
bow), rays through the box centre pass 2-3 m aft of midships on average, and
up to ~13 m aft when the ship is seen from astern at 20-30 deg elevation (measured
with the harness's ray-cast camera over elevations 20-75 deg, ranges 250-1500 m).
Close in, perspective adds to it. A terminal dive that trusts the box centre
hits where the box centre points, not the aim point.

This module removes that bias before the UKF sees the detection. The flight
software carries a coarse outline of the ship class (:class:`ShipModelConfig`:
the corner points of hull, deckhouse, wheelhouse, funnel and mast, scaled by
the class's length, width and height). With the current estimate of the
tracked point ``r_q`` (the point ``ukf.target_plane_height_m`` above the ship's
waterline centre) and the ship's course (from the estimated velocity), it
projects the outline into the camera, takes the box of the projected points
(clipped to the image, as the detector's box is) and its centre, and subtracts
that centre's offset from the projection of ``r_q``::

    (u, v)_corrected = (u, v)_detected - [centre(box(project(outline))) - project(r_q)]

so that the corrected pixel is (to first order) the image of ``r_q`` itself,
which is what the UKF's measurement model assumes. When the course is unknown
(estimated speed below ``min_speed_for_course_m_s``) the offset is averaged
over the headings the box shapes allow (:class:`ShapeHeading`: a still ship's
heading from the sizes of its boxes seen from round the loiter ring), or before
they tell, over ``headings_when_unknown`` headings: the part that does not
depend on the course (the height of the box centre) is still removed. The same
headings drive the box-size check (a detection no plausible heading explains is
skipped), and a ship's axis from the shapes vetoes an estimated velocity
across it (the UKF's error, not a course: ships move along their axis).

A ship of the class's layout but another size is learnt from its boxes
(:class:`ShipSize`, ``size_fit``): its length, beam and height scale the
outline the correction projects once enough boxes have been seen at a known
heading. The UAV's own airframe hiding part of the ship is modelled by the
perception (``controllers.perception.airframe``: the predicted boxes are cut as the
detector's are, :func:`projected_points_px` and :attr:`ShipOutline.parts` give
it the silhouette). What it does not model: a ship of another layout than the
class's (the fit then finds the sizes that best explain the boxes with the
class's layout).
``enabled: false`` turns it off (the paper's plain point model).

The outline is a priori knowledge of the target class (the paper's ship is a
known 55 x 25 x 25 m vessel), configured with the flight software; nothing
here reads the simulated ship (docs/design/architecture.md, "Two rules").
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controllers.config import ShipModelConfig
from controllers.navigation.camera_model import PinholeCamera
from controllers.perception.layout_fit import LayoutFit
from controllers.perception.shape_heading import ShapeHeading, course_likelihood, plausible
from controllers.perception.ship_outline import ShipOutline
from controllers.perception.size_fit import ShipSize
from fwsim.interface.frames import dcm_ship_from_enu, heading_deg_from_course_enu

__all__ = ["ShipModel", "ShipHeadingStatus"]


#: the size fit takes a box only when the box shapes' heading weights (a known course fused in) are this
#: concentrated (mean resultant length; 0.98: a circular std of about 11 deg; a bow / stern ambiguity is far
#: below)
_SIZE_FIT_MIN_RESULTANT = 0.98


@dataclass(frozen=True, slots=True)
class ShipHeadingStatus:
    """The ship's heading as the box shapes tell it (:class:`ShapeHeading`), for the log."""

    t_s: float
    best_heading_deg: float  # the most likely heading, clockwise from North (the scenario's convention)
    best_weight: float  # its posterior weight (of all candidate headings)
    reverse_weight: float  # the weight of the opposite heading (bow and stern swapped)
    updates: int  # detections used so far
    in_use: bool  # it alone gives the heading (course unknown, shapes ready); with a course the two are fused
    course_deg: float  # the course from the estimated velocity when known (clockwise from North), else NaN
    size_scale: np.ndarray  # (3,) the ship's length, beam, height over the class's as fitted (ShipSize)
    size_updates: int  # boxes the size fit has taken
    size_in_use: bool  # the correction uses the fitted outline
    layout_other_end: float  # the probability that the superstructure stands at the other end (LayoutFit)
    layout_in_use: str  # the layout the correction uses: "class" or "other_end"
    turn_rate_deg_s: float  # the most likely of heading_from_shape.turn_rates_deg_s (clockwise seen from above)
    layout_shape_log_odds: float  # the box shapes' part of layout_other_end's log-odds (LayoutFit.shape_evidence)


class ShipModel:
    """What the flight software knows of the ship: the class outline (a priori) and its heading (learnt).

    The heading comes from the estimated velocity (a ship's bow points along its course) and from the
    shapes of its boxes (:class:`ShapeHeading`). The perception feeds it each detection
    (:meth:`observe_box`) and asks it for the possible headings (:meth:`headings`) for the box-centre
    correction and the box-size gate; the terminal guidance asks it where an approach meets the hull
    (:meth:`entry_depth_m`).
    """

    def __init__(self, cfg: ShipModelConfig, camera: PinholeCamera, edge_px: float = 6.0):
        self.cfg = cfg
        self.outlines = (ShipOutline(cfg), ShipOutline(cfg, other_end=True))  # the class's layout, the other end
        self.shape = ShapeHeading(cfg.heading_from_shape, self.outlines[0], camera, edge_px)
        #: the size fit, which goes on with the layout in use (:meth:`follow_layout`)
        self.size = ShipSize(cfg.size_fit, self.outlines[0], camera, edge_px)
        self.layout = LayoutFit(cfg.layout_fit, self.outlines, camera, cfg.layout_fit.pixel_noise_px, edge_px)
        self._course_known_since = math.nan  # since when the course has been known without a break
        self._now = math.nan  # the time of the latest box (observe_box)
        self._held = (math.nan, math.nan)  # the course last followed and when (held_course_spread_deg_s)

    @property
    def outline(self) -> ShipOutline:
        """The outline the correction, the size gate and the size fit use: the class's, or its superstructure at
        the other end once the box centres say so (:class:`LayoutFit`)."""
        return self.outlines[1] if self.layout.other_end else self.outlines[0]

    def course(self, vel_enu, vel_std_m_s: float = 0.0) -> float | None:
        """The ship's course (bow direction, counter-clockwise from East) from its estimated velocity, or None
        when it is unknown: slower than ``min_speed_for_course_m_s`` or less sure than
        ``max_vel_std_for_course_m_s``, or off the ship's axis as the box shapes tell it (a ship moves along
        its axis: such a velocity is the estimate's error)."""
        cfg = self.cfg
        if math.hypot(float(vel_enu[0]), float(vel_enu[1])) < cfg.min_speed_for_course_m_s \
                or vel_std_m_s > cfg.max_vel_std_for_course_m_s:
            return None
        course = math.atan2(float(vel_enu[1]), float(vel_enu[0]))
        if self.shape.ready and \
                self.shape.off_axis_rad(course) > math.radians(cfg.heading_from_shape.max_course_off_axis_deg):
            return None
        return course

    def headings(self, vel_enu, vel_std_m_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        return self.headings_and_course(vel_enu, vel_std_m_s)[:2]

    def headings_and_course(self, vel_enu, vel_std_m_s: float = 0.0) -> tuple[np.ndarray, np.ndarray, float | None]:
        """The ship's possible headings (bow direction, counter-clockwise from East) and their weights, from
        its estimated velocity (std ``vel_std_m_s``) and the box shapes:

        * course known (:meth:`course`) and shapes ready: the shapes' posterior times the course's
          likelihood (a ship's bow points along its course; the course's std is the velocity's over the
          speed, at least ``fuse_min_course_std_deg``), so each sharpens the other;
        * course known, shapes not ready: the course alone;
        * course unknown: the headings the shapes allow (weighed by the course last followed while it is
          recent), else ``headings_when_unknown`` equal ones.
        """
        course = self.course(vel_enu, vel_std_m_s)
        sh = self.cfg.heading_from_shape
        if course is not None:
            if not (self.shape.ready and sh.fuse_with_course):
                return np.array([course]), np.ones(1), course
            speed = max(math.hypot(float(vel_enu[0]), float(vel_enu[1])), 1e-6)  # min_speed_for_course may be 0
            sig = max(vel_std_m_s / speed, math.radians(sh.fuse_min_course_std_deg))
            w = self.shape.weights() * course_likelihood(self.shape.courses_enu_rad, course, sig)
            if not w.sum() > 0.0:
                return np.array([course]), np.ones(1), course
            return (*plausible(self.shape.courses_enu_rad, w, sh.min_weight), course)
        held = self._held_course_weights()
        if held is not None:  # the shapes' headings weighed by the course last followed
            w = self.shape.heading_weights() * held
            if w.sum() > 0.0:
                return (*plausible(self.shape.courses_enu_rad, w, sh.min_weight), None)
        shaped = self.shape.headings()
        if shaped is not None:
            return shaped[0], shaped[1], None
        n = self.cfg.headings_when_unknown
        return 2.0 * math.pi * np.arange(n) / n, np.full(n, 1.0 / n), None

    def _held_course_weights(self) -> np.ndarray | None:
        """The likelihood of the shapes' headings (:attr:`ShapeHeading.courses_enu_rad`) under the course last
        followed, its std ``fuse_min_course_std_deg`` plus ``held_course_spread_deg_s`` per second since; None
        when off, before the shapes are ready, when no course has been followed, or once the std spans the
        circle (180 deg)."""
        sh = self.cfg.heading_from_shape
        course, t = self._held
        if sh.held_course_spread_deg_s <= 0.0 or not math.isfinite(course) or not self.shape.ready:
            return None
        sig = sh.fuse_min_course_std_deg + sh.held_course_spread_deg_s * max(self._now - t, 0.0)
        if not sig < 180.0:  # (also NaN)
            return None
        return course_likelihood(self.shape.courses_enu_rad, course, math.radians(sig))

    def learn_size(self, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, courses, weights, box_px,
                   t_s: float | None = None) -> bool:
        """Feed one detected box to the size fit (:class:`ShipSize`) at the weighted circular mean of the
        headings ``courses`` (weights ``weights``, :meth:`headings_and_course`; finer than their 5-deg grid)
        when the heading is sure: the box
        shapes' posterior (with a known course fused in) concentrated to a mean resultant length of at least
        ``_SIZE_FIT_MIN_RESULTANT``. Never a course alone: a still ship's estimated velocity gives one for
        seconds after the lock, any way round. True when the box moved the fit."""
        if not self.shape.ready or len(courses) == 1 or not self.size.takes_boxes(t_s):
            return False  # (the rate first: the heading's concentration is not worked out for nothing)
        resultant = complex(np.dot(weights, np.exp(1j * np.asarray(courses))))
        if abs(resultant) < _SIZE_FIT_MIN_RESULTANT:
            return False
        course = math.atan2(resultant.imag, resultant.real)
        return self.size.update(cam_pos_enu_m, R_enu_from_cam, ref_enu_m, course, box_px, t_s)

    def follow_layout(self) -> None:
        """After the layout in use has changed: the size fit goes on with it from where it stands."""
        self.size.outline = self.outline

    def observe_box(self, t_s: float, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, box_px, vel_enu,
                    vel_std_m_s: float, tracked_height_m: float = 0.0) -> ShipHeadingStatus | None:
        """Feed one detected box to the heading-from-shapes posterior and the layout fit (``ref_enu_m``: the
        estimated waterline centre; ``tracked_height_m``: the estimator's tracked point above it); the state
        for the log when the shapes took the box, else None."""
        if self.cfg.enabled and self.layout.observe(t_s, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, box_px,
                                                    lambda: self.course(vel_enu, vel_std_m_s), tracked_height_m,
                                                    self.size.scale, vel_enu, self.shape.reverse_log_ratio):
            self.follow_layout()
        sh = self.shape
        self._now = float(t_s)
        follow = self._course_to_follow(t_s, vel_enu, vel_std_m_s)
        if follow is not None:
            self._held = (follow, float(t_s))
        if not sh.update(t_s, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, box_px, follow):
            return None
        w = sh.weights()
        k = int(np.argmax(w))
        course = self.course(vel_enu, vel_std_m_s)
        sz = self.size
        return ShipHeadingStatus(t_s, heading_deg_from_course_enu(float(sh.courses_enu_rad[k])), float(w[k]),
                                 float(w[(k + len(w) // 2) % len(w)]), sh.updates, bool(course is None and sh.ready),
                                 math.nan if course is None else heading_deg_from_course_enu(course),
                                 np.exp(sz.theta), sz.updates, sz.scale is not None, self.layout.p_other_end,
                                 "other_end" if self.layout.other_end else "class",
                                 float(sh.cfg.turn_rates_deg_s[int(np.argmax(sh.rate_weights()))]),
                                 self.layout.shape_evidence())

    def _course_to_follow(self, t_s: float, vel_enu, vel_std_m_s: float) -> float | None:
        """The estimated velocity's course when the box shapes' posterior may follow it
        (:attr:`ShapeHeadingConfig.follow_course`): known by speed and std (as in :meth:`course`, but whatever
        the shapes say: they are what is being turned) for ``follow_course_settle_s`` without a break."""
        cfg, sh = self.cfg, self.cfg.heading_from_shape
        if not sh.follow_course:
            return None
        speed = math.hypot(float(vel_enu[0]), float(vel_enu[1]))
        if speed < max(cfg.min_speed_for_course_m_s, 1e-6) or not vel_std_m_s <= cfg.max_vel_std_for_course_m_s:
            self._course_known_since = math.nan
            return None
        if math.isnan(self._course_known_since):
            self._course_known_since = float(t_s)
        if t_s - self._course_known_since < sh.follow_course_settle_s:
            return None
        return math.atan2(float(vel_enu[1]), float(vel_enu[0]))

    def entry_depth_m(self, point_enu_m, ship_enu_m, dir_enu, vel_enu) -> float:
        """How far before ``point_enu_m`` a straight path along ``dir_enu`` (unit) first meets the outline of
        the ship at ``ship_enu_m`` (its waterline centre), the deepest over the headings it may have
        (:meth:`headings` of ``vel_enu``); 0 when nothing is in the way."""
        depth = 0.0
        for c in self.headings(vel_enu)[0]:
            R_se = dcm_ship_from_enu(float(c))
            depth = max(depth, self.outline.entry_depth_m(R_se @ (point_enu_m - ship_enu_m), R_se @ dir_enu))
        return depth
