"""Perception: the detector's boxes in, a fix for the estimator out, with the decision that goes with it.

Per tick (:meth:`Perception.step`):

1. **Lock.** Before the lock, ``acquisition.lock_detections`` frames in a row
   with a box make it; every box before counts toward it (``acquiring``).
2. **Gates** (:class:`~controllers.config.DetectionGateConfig`), once the
   estimator runs: a target closer than ``min_range_m`` (``too_close``: close
   in, the box centre no longer follows the ship model; ``moving_min_range_m``
   for a ship estimated to move at ``moving_speed_m_s`` or more, whose
   velocity the coast after the last box flies) and a box that spans the
   whole image (``overflowing_box``) are skipped.
3. **The ship's heading and layout** (:class:`~controllers.perception.target_model.ShipModel`):
   each box (unless too close) feeds the heading-from-shapes posterior and,
   while the course is known, the layout fit (``target_model.layout_fit``:
   whether the superstructure stands at the other end from the class's; an
   event says when the correction takes the other end, or goes back).
4. **Box-centre correction** (``controllers.perception.target_model``): the box centre
   moves over the ship with the view; the offset the ship model predicts for
   the estimated position and the plausible headings is removed, so that the
   fix is the image of the point the estimator tracks. The
   predicted boxes are those a detector would see: clipped to the image, and
   (``controllers.perception.airframe``, unless ``airframe.enabled`` is false), when the
   detected box touches the UAV's own airframe in the image, less the part of
   the ship the airframe hides from the camera, so that a box the fuselage or
   wing cuts is corrected by the centre of the cut box (and sized against it),
   not of the whole ship. While the ship's course is unknown (its heading from
   the box shapes alone) the ship is cut where the detection puts it in the
   image, not where the estimate does (``airframe.align_iterations``), and a
   detection of which the airframe hides more than ``airframe.max_hidden_share``
   is skipped (``airframe_hidden``). Such a box teaches the heading, layout and
   size fits nothing (as one at the image border does not). A box whose width or
   height no plausible heading explains (``size_mismatch``) is, with
   ``size_mismatch_action: own_headings`` (the default), corrected over the
   headings all round whose size explains it, their spread as its pixel
   variance (the log says ``overridden: size_mismatch``), when it cannot be
   a box cut short: when it is larger than every estimated heading's (no
   occlusion does that; a turn the estimate missed does), or when the
   estimated ship lies ``airframe_clearance_deg`` below the wing plane (the
   barrier's self-occlusion model: the airframe is not in the way there).
   Otherwise (part of the ship may be hidden) it is used with its centre's
   doubt (``maybe_cut_action: deweight``, the default: the pixel variance of
   half the size difference from the predicted box, where a box cut short on
   one side puts its centre) or skipped (``maybe_cut_action: skip``). With
   ``size_mismatch_action: skip`` every such box is skipped; with
   ``deweight`` every one is used with its centre's doubt.
5. **Latency.** A detection arrives ``latency`` after its exposure; its box
   centre is brought to now (``propagate_feature``) before anything else, so
   that it goes with the camera pose of now.
6. **Decision.** After ``max_skipped_in_a_row`` skips in a row (bar
   ``too_close``) the next detection is used anyway: the estimate the checks
   rely on may be what is wrong (``overridden`` names the gate passed over).
7. **The class check.** The correction and the size gate trust the configured
   ship class. When ``class_mismatch_enter`` of the last
   ``class_check_window`` size-checked boxes (with ``class_check_clear_only``,
   the default, only those whose ship lies ``airframe_clearance_deg`` below
   the wing plane: a box the airframe may have cut says nothing of the
   ship's size) or more are off in size, the
   boxes disagree with the class (a ship of another size or layout than
   configured, not a passing occlusion): from then on the size gate compares
   a box with the class's prediction scaled by the median size ratio of the
   last boxes (a box cut short still stands out), until the share
   falls to ``class_mismatch_exit``. Both switches are events in the log.

What the estimator then does with the fix (fused, innovation gate, ...) is
decided there; the flight software logs the two together as one
``/fsw/detection_fusion`` message per detection.

Nothing here imports the truth side of the harness (docs/design/architecture.md, "Two rules").
"""
from __future__ import annotations

import math
from collections import deque

import numpy as np

from controllers.config import AcquisitionConfig, DetectionGateConfig, ShipModelConfig
from controllers.messages import DetectionFix, FusionReason, TargetState
from controllers.navigation.camera_model import CameraMotion, PinholeCamera
from controllers.perception.ship_outline import box_centre_offset_px, predicted_boxes_px, projected_points_px
from controllers.perception.target_model import ShipModel
from fwsim.interface import topics
from fwsim.interface.frames import R_frd_from_cam, dcm_ned_from_frd_rows
from fwsim.interface.messages import Measurements

__all__ = ["Perception", "Lock"]

_NAN4 = np.full(4, np.nan)
_ZERO22 = np.zeros((2, 2))
_ZERO22.setflags(write=False)
_NAN4.setflags(write=False)
_NO_NOISE = (0.0, 0.0)
_OWN_HEADINGS = 24  # size_mismatch_action own_headings: the headings all round a box is matched against


def _centre_doubt(det: np.ndarray, size: np.ndarray) -> tuple[float, float]:
    """(px^2, u and v) the doubt of the centre of a box of size ``det`` (width, height) where ``size`` was
    predicted: (half the difference)^2 in each, where a box cut short on one side puts its centre."""
    dw, dh = 0.5 * (float(det[0]) - float(size[0])), 0.5 * (float(det[1]) - float(size[1]))
    return dw * dw, dh * dh


#: the flight software's tick is at most this long (the poses kept for late detections are matched to half of it)
_POSE_MATCH_S = 1.0 / 20.0


class Lock:
    """Acquisition: ``lock_detections`` frames in a row with a box lock the target (for good)."""

    def __init__(self, cfg: AcquisitionConfig):
        self.cfg = cfg
        self.streak = 0
        self.locked = False
        self.lock_t_s = math.nan

    def observe(self, meas: Measurements) -> bool:
        """Count this tick's detection; True on the tick the lock is made."""
        if self.locked or not meas.det_new:
            return False
        self.streak = self.streak + 1 if meas.det_valid else 0
        if self.streak >= self.cfg.lock_detections:
            self.locked = True
            self.lock_t_s = meas.t_s
            return True
        return False


class Perception:
    """Detections -> :class:`DetectionFix` (corrected box centre + decision); see the module text."""

    def __init__(self, gate: DetectionGateConfig, acquisition: AcquisitionConfig, ship: ShipModel,
                 camera: PinholeCamera, recorder=None, airframe=None):
        self.cfg = gate
        self.airframe = airframe  # an airframe.AirframeShadow, or None: boxes not cut by the airframe
        self.lock = Lock(acquisition)
        self.ship = ship
        self.camera = camera
        self._record = recorder
        self.skipped_in_a_row = 0
        self.last_detection_t_s = math.nan
        self._size_off: deque[bool] = deque(maxlen=gate.class_check_window)  # the class check's window
        self._size_off_count = 0  # how many of it are off
        self._ratios: deque = deque(maxlen=gate.class_check_window)  # log(detected / predicted) box sides
        self.class_mismatch = False
        self._taken_off_size = False  # this box, off in size, is used all the same (own headings, or its doubt)
        # camera poses (t, r_c, R_enu_from_cam) of the last ticks, for detections that arrive late
        self._poses: deque = deque(maxlen=max(2, int(math.ceil(gate.max_propagation_s / _POSE_MATCH_S)) + 2))

    @classmethod
    def from_config(cls, gate: DetectionGateConfig, acquisition: AcquisitionConfig, ship_cfg: ShipModelConfig,
                    camera: PinholeCamera, recorder=None) -> "Perception":
        return cls(gate, acquisition, ShipModel(ship_cfg, camera, gate.edge_px), camera, recorder)

    def step(self, nav: Measurements, cam: CameraMotion | None, prior: TargetState) -> DetectionFix:
        """This tick's fix. ``prior``: the estimate brought to now (before this detection)."""
        self.remember_pose(cam)
        lock_now = self.lock.observe(nav)
        new = bool(nav.det_new and nav.det_valid)
        if new:
            self.last_detection_t_s = nav.t_s
        u, v = nav.det_u_px, nav.det_v_px
        pred, use, reason, overridden = _NAN4, False, "", ""
        spread, noise = _ZERO22, _NO_NOISE
        if new and not self.lock.locked:
            reason = FusionReason.ACQUIRING
        elif new and cam is None:
            reason = FusionReason.NO_CAMERA_POSE
        elif new and prior.from_estimator and not lock_now:
            self._taken_off_size = False
            u, v, pred, reason, spread, doubt = self._judge(nav, cam, prior)
            if reason == FusionReason.SIZE_MISMATCH and self._taken_off_size:
                use, overridden, reason, noise = True, reason, "", doubt
                self.skipped_in_a_row = 0
            else:
                use, overridden = self._decide(reason)
                reason = "" if use else reason
        elif new:
            use = True  # the estimator is down: this detection may (re)start it
            u, v = self._to_now(nav, cam, prior)
        return DetectionFix(nav.t_s, new, nav.det_exposure_t_s, nav.det_u_px, nav.det_v_px, nav.det_bbox_px,
                            u, v, pred, use, reason, overridden, self.lock.locked, lock_now, self.lock.lock_t_s,
                            self.last_detection_t_s, spread, noise)

    # ------------------------------------------------------------------ the checks
    def _judge(self, nav: Measurements, cam: CameraMotion, prior: TargetState):
        """(u, v corrected, predicted box, gate reason or "", the correction's spread over the headings (2 x 2,
        px^2)) of a detection while the estimator runs."""
        gate = self._gate(nav, cam, prior)
        h = prior.tracked_height_m
        pos, vel = prior.pos_enu_m, prior.vel_enu_m_s
        ref = np.array([pos[0], pos[1], pos[2] - h])
        # a box the UAV's airframe may have cut says nothing sure of the ship's shape or size: the heading,
        # layout and size fits leave it out (as they leave out one at the image border)
        cut_R = self._touching_airframe(nav)  # the camera's rotation in the body frame, or None
        cut = cut_R is not None
        if gate != FusionReason.TOO_CLOSE and not cut:
            layout = self.ship.layout
            switches = layout.switches
            status = self.ship.observe_box(nav.t_s, cam.pos_enu_m, cam.R_enu_from_cam, ref, nav.det_bbox_px, vel,
                                           prior.vel_std_m_s, h)
            if status is not None and self._record is not None:
                self._record.log(topics.FSW_SHIP_HEADING, status)
            if layout.switches != switches:
                where = "at the other end from the class's" if layout.other_end else "where the class has it"
                self._event(f"perception: the box centres put the superstructure {where} "
                            f"(probability of the other end {layout.p_other_end:.2f}): correcting with that layout")
        u, v, pred, why, spread, doubt = self._corrected(nav, cam, prior, ref, fit_size=not gate and not cut,
                                                         cut_by_airframe=cut_R)
        return u, v, pred, gate or why, spread, doubt

    def _touching_airframe(self, nav: Measurements) -> np.ndarray | None:
        """The camera's rotation in the body frame (``R_frd_from_cam``) when the detected box touches (within
        ``edge_px``) the UAV's airframe in the image (:meth:`controllers.perception.airframe.AirframeShadow.touches`),
        else None (no airframe model, no gimbal angles, or clear of it)."""
        pan, tilt = float(nav.pan_rad), float(nav.tilt_rad)
        if self.airframe is None or not (math.isfinite(pan) and math.isfinite(tilt)):
            return None
        R = R_frd_from_cam(pan, tilt)
        return R if self.airframe.touches(R, nav.det_bbox_px, self.cfg.edge_px) else None

    def _gate(self, nav: Measurements, cam: CameraMotion, prior: TargetState) -> str:
        """``too_close``, ``overflowing_box`` or "" (see :class:`DetectionGateConfig`)."""
        g = self.cfg
        if g.min_range_m > 0.0 and np.isfinite(nav.cam_pos_enu_m).all():
            d = np.asarray(prior.pos_enu_m, float) - nav.cam_pos_enu_m
            if math.sqrt(d.dot(d)) < (g.moving_min_range_m if self._moving(prior) else g.min_range_m):  # (norm)
                return FusionReason.TOO_CLOSE
        b = np.asarray(nav.det_bbox_px, dtype=float)
        c, e = self.camera, g.edge_px
        if g.skip_overflowing_box and np.isfinite(b).all() and c.width_px > 0 and (
                (b[0] <= e and b[2] >= c.width_px - 1.0 - e) or (b[1] <= e and b[3] >= c.height_px - 1.0 - e)):
            return FusionReason.OVERFLOWING_BOX
        return ""

    def _moving(self, prior: TargetState) -> bool:
        """The estimated ship moves at ``moving_speed_m_s`` or more (its boxes are taken down to
        ``moving_min_range_m``)."""
        v = prior.vel_enu_m_s
        return math.hypot(float(v[0]), float(v[1])) >= self.cfg.moving_speed_m_s

    def _corrected(self, nav: Measurements, cam: CameraMotion, prior: TargetState, ref: np.ndarray,
                   fit_size: bool = False, cut_by_airframe: np.ndarray | None = None):
        """The box centre with the ship's box-centre offset removed (unchanged when the model is off or does
        not apply), the predicted box of the most likely heading, ``size_mismatch`` when no plausible
        heading explains the box's size (else ""), the offset's spread over the headings the ship may have
        (2 x 2, px^2; zeros when there is one, or no correction), and the centre's doubt ((u, v) px^2,
        :func:`_centre_doubt`; with ``size_mismatch_action: deweight``, else zeros). ``fit_size``: the box
        may teach the ship's size (:meth:`~controllers.perception.target_model.ShipModel.learn_size`, when the heading
        is sure); the correction and the size gate use the fitted outline once it is in use. ``cut_by_airframe``:
        the camera's rotation in the body frame when the detected box touches the UAV's airframe in the image
        (else None); the predicted boxes are then cut as the
        airframe would cut them (:meth:`_cut_by_airframe`; a box clear of it was not cut, whatever the
        prediction says)."""
        u, v = self._to_now(nav, cam, prior)
        if not self.ship.cfg.enabled:
            return u, v, _NAN4, "", _ZERO22, _NO_NOISE
        b = np.asarray(nav.det_bbox_px, dtype=float)
        courses, weights, course = self.ship.headings_and_course(prior.vel_enu_m_s, prior.vel_std_m_s)
        headings = (courses, weights, len(courses) == 1, None)
        if fit_size:
            self._learn_size(nav, cam, ref, courses, weights, b)
        scale = self.ship.size.scale
        pred, why, doubt, own_used = _NAN4, "", _NO_NOISE, False
        if (course is not None or self.ship.shape.ready) and np.isfinite(b).all():
            boxes = predicted_boxes_px(self.ship.outline, self.camera, cam.pos_enu_m, cam.R_enu_from_cam, ref,
                                       courses, scale)
            hidden = None
            if cut_by_airframe is not None and np.isfinite(boxes).all():
                boxes, hidden = self._cut_by_airframe(nav, cam, cut_by_airframe, ref, courses, scale, boxes,
                                                      course_known=course is not None)
            if np.isfinite(boxes).all():
                pred = boxes[int(weights.argmax())].copy()
                if hidden is not None and course is None and \
                        float(np.dot(weights, hidden)) > self.airframe.cfg.max_hidden_share:
                    # the course unknown and so much of the ship behind the airframe that the cut decides
                    # the fix, and the cut the box shapes' heading (tens of degrees off a turning ship's):
                    # the estimate coasts
                    return u, v, pred, FusionReason.AIRFRAME_HIDDEN, _ZERO22, _NO_NOISE
                judged = self._size_checked(nav, cam, prior, ref, b, scale, (*headings[:3], boxes), pred)
                if judged is None:  # skip, or own_headings with no heading of its own
                    return u, v, pred, FusionReason.SIZE_MISMATCH, _ZERO22, _NO_NOISE
                headings, pred, why, doubt, own_used = judged
        off = self._offset(cam, ref, prior, headings, scale, spread=True)
        if off is None:
            return u, v, pred, why, _ZERO22, doubt
        off, spread = off
        if own_used:  # the box's own headings: their spread is noise
            doubt = (float(spread[0, 0]), float(spread[1, 1]))
        return float(u) - float(off[0]), float(v) - float(off[1]), pred, why, spread, doubt

    def _learn_size(self, nav: Measurements, cam: CameraMotion, ref: np.ndarray, courses, weights,
                    b: np.ndarray) -> None:
        """Hand the box to the size fit (:meth:`~controllers.perception.target_model.ShipModel.learn_size`); an event
        when the fit starts again."""
        restarts = self.ship.size.restarts
        self.ship.learn_size(cam.pos_enu_m, cam.R_enu_from_cam, ref, courses, weights, b, nav.t_s)
        if self.ship.size.restarts != restarts:
            sf = self.ship.cfg.size_fit
            self._event(f"perception: the size fit turned {sf.max_gated_in_a_row} boxes away in a row and "
                        + ("keeps the class's outline from now on (size_fit.class_after_restarts)"
                           if self.ship.size.retired else "starts again from the class's outline"))

    def _size_checked(self, nav: Measurements, cam: CameraMotion, prior: TargetState, ref: np.ndarray,
                      b: np.ndarray, scale, headings, pred: np.ndarray):
        """The class check and the size gate on the box ``b`` against the predicted boxes of ``headings`` =
        (courses, weights, one course, boxes): (the headings to correct over, the predicted box, the reason,
        the centre's doubt, the box's own headings used) or None when the box is skipped."""
        g = self.cfg
        boxes, best = headings[3], int(headings[1].argmax())
        sizes = boxes[:, 2:4] - boxes[:, 0:2]  # (width, height) of each heading's box
        det = np.array([b[2] - b[0], b[3] - b[1]])
        mismatch = self._no_heading_fits(det, sizes)
        clear = self._clear_of_airframe(nav, cam, prior)
        if clear or not g.class_check_clear_only:  # a box the airframe may have cut is no size evidence
            ratio = det / np.maximum(sizes[best], 1.0)
            if (ratio > 0.0).all():
                self._ratios.append(np.log(ratio))
            self._class_check(nav.t_s, mismatch)
        off_against = self._off_against(det, sizes, mismatch)
        if off_against is None:
            return headings, pred, "", _NO_NOISE, False
        own = None
        if g.size_mismatch_action == "own_headings" and (self._larger_than_any(det, off_against) or clear):
            own = self._own_headings(cam, ref, det, scale, off_against[best] / np.maximum(sizes[best], 1.0))
        if own is not None:
            courses, weights, boxes = own
            self._taken_off_size = True
            return ((courses, weights, False, boxes), boxes[int(weights.argmax())].copy(), FusionReason.SIZE_MISMATCH,
                    _NO_NOISE, True)
        if g.size_mismatch_action == "deweight" or (
                g.size_mismatch_action == "own_headings" and g.maybe_cut_action == "deweight"):
            self._taken_off_size = True
            return headings, pred, FusionReason.SIZE_MISMATCH, _centre_doubt(det, off_against[best]), False
        return None

    def _off_against(self, det: np.ndarray, sizes: np.ndarray, mismatch: bool) -> np.ndarray | None:
        """The predicted sizes the box ``det`` is off when the size gate turns it away, else None: the
        headings' ``sizes`` while the boxes fit the class, else (the class check) those sizes scaled by the
        boxes' typical size ratio (a box cut short, by an occlusion, still stands out from the ship's usual
        boxes)."""
        if not self.class_mismatch:
            return sizes if mismatch else None
        if not self._ratios:
            return None
        scaled = sizes * np.exp(np.median(np.array(self._ratios), axis=0))[None, :]
        return scaled if self._no_heading_fits(det, scaled) else None

    def _offset(self, cam: CameraMotion, ref: np.ndarray, prior: TargetState, headings, scale, spread=False):
        """:func:`~controllers.perception.ship_outline.box_centre_offset_px` over ``headings`` = (courses, weights, one
        course, their predicted boxes): the one course's offset, or the weighted mean over the courses."""
        courses, weights, single, boxes = headings
        return box_centre_offset_px(self.ship.outline, self.camera, cam.pos_enu_m, cam.R_enu_from_cam, ref,
                                    float(courses[0]) if single else None, prior.tracked_height_m,
                                    self.ship.cfg.headings_when_unknown, boxes_px=boxes,
                                    courses_weights=None if single else (courses, weights), spread=spread,
                                    scale=scale)

    def _larger_than_any(self, det: np.ndarray, sizes: np.ndarray) -> bool:
        """The box (width, height) ``det`` is wider or taller than every one of the predicted ``sizes`` (n, 2)
        by more than the size gate's tolerance: more ship than the estimated headings show, which no
        occlusion makes (a hidden part only shrinks a box), but a turn the estimate has not followed does."""
        tol, tol_px = self.cfg.box_size_tolerance, self.cfg.box_size_tolerance_px
        big = np.asarray(sizes, dtype=float).max(axis=0)
        return bool(det[0] > big[0] * (1.0 + tol) + tol_px or det[1] > big[1] * (1.0 + tol) + tol_px)

    def _cut_by_airframe(self, nav: Measurements, cam: CameraMotion, R: np.ndarray, ref: np.ndarray, courses,
                         scale, boxes: np.ndarray, course_known: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """(The predicted ``boxes`` (one per course) less the part of the ship the UAV's airframe hides from
        the camera (:class:`controllers.perception.airframe.AirframeShadow`): the boxes a detector would see; the share
        of each course's ship hidden, 0 where its box is kept whole). A course whose whole ship the airframe
        would hide keeps its box (the detection says the ship is not where that predicts). ``R``: the
        camera's rotation in the body frame."""
        air = self.airframe
        b = np.asarray(nav.det_bbox_px, dtype=float)
        det = b[2:4] - b[0:2]  # the detected box's width and height
        aligned = air.cfg.align_iterations > 0 and not course_known
        # (aligned: AirframeShadow.cut checks each moved box itself)
        union = np.concatenate([boxes[:, 0:2].min(axis=0), boxes[:, 2:4].max(axis=0)])
        hidden = np.zeros(len(boxes))
        if not aligned and not air.may_hide(R, union):  # (no ray of any course's box can meet the airframe)
            return boxes, hidden
        out = boxes.copy()
        outline = self.ship.outline
        several = len(boxes) > 1
        for i, course in enumerate(np.asarray(courses, dtype=float).tolist()):
            if several and not aligned and not air.may_hide(R, boxes[i]):
                continue
            pts = projected_points_px(outline, self.camera, cam.pos_enu_m, cam.R_enu_from_cam, ref, course, scale)
            if pts is None:
                continue
            parts = [pts[s] for s in outline.parts]
            if aligned:
                cut, share = air.aligned_cut(R, boxes[i], parts, b, air.cfg.align_iterations)
            else:
                cut, share = air.cut(R, boxes[i], parts, checked=True)
            if np.isfinite(cut).all() and (not air.cfg.cut_only_if_closer or _closer_in_size(det, cut, boxes[i])):
                out[i], hidden[i] = cut, share
        return out, hidden

    def _clear_of_airframe(self, nav: Measurements, cam: CameraMotion, prior: TargetState) -> bool:
        """The estimated ship lies ``airframe_clearance_deg`` or more below the wing plane (the body x-y plane;
        the self-occlusion model of :mod:`controllers.guidance.cbf`), seen from the camera: the airframe is not in the
        way, so a box smaller than predicted is not one cut short (in the envelope's dives no box the airframe
        cut had its ship more than 1 deg below the plane; docs/results/envelope.md).
        With the full attitude, not :func:`controllers.guidance.cbf.h_value`, which neglects the pitch (the loiter's
        assumption; in the dive the nose is 30-60 deg down)."""
        clearance = self.cfg.airframe_clearance_deg
        euler = np.asarray(nav.euler_ned_rad, dtype=float)
        if clearance >= 90.0 or not np.isfinite(euler).all():
            return False
        # the line of sight in the body frame: R_enu_from_frd.T @ (ship - camera), with R_enu_from_frd's rows
        # (east, north, up) = (R_ned_from_frd's second, first, minus its third), written out
        n, e, d = dcm_ned_from_frd_rows(euler)
        p, c = prior.pos_enu_m, cam.pos_enu_m
        r0, r1, r2 = float(p[0]) - float(c[0]), float(p[1]) - float(c[1]), float(p[2]) - float(c[2])
        fwd, right, down = (e[k] * r0 + n[k] * r1 - d[k] * r2 for k in range(3))
        return math.atan2(down, math.hypot(fwd, right)) >= math.radians(clearance)

    def _own_headings(self, cam: CameraMotion, ref: np.ndarray, det: np.ndarray, scale, size_factor: np.ndarray):
        """(courses, weights, predicted boxes) of the headings all round (every 360 / _OWN_HEADINGS deg) whose
        predicted box size, times ``size_factor`` (the size gate's rescale, else ones), explains the box's
        size ``det`` (width, height) within the size gate's tolerance, weighted by how well (a Gaussian of the
        difference over the tolerance); None when none does."""
        courses = 2.0 * math.pi * np.arange(_OWN_HEADINGS) / _OWN_HEADINGS
        boxes = predicted_boxes_px(self.ship.outline, self.camera, cam.pos_enu_m, cam.R_enu_from_cam, ref, courses,
                                   scale)
        ok = np.isfinite(boxes).all(axis=1)
        if not ok.any():
            return None
        courses, boxes = courses[ok], boxes[ok]
        sizes = (boxes[:, 2:4] - boxes[:, 0:2]) * np.asarray(size_factor, dtype=float)[None, :]
        tol = self.cfg.box_size_tolerance * sizes + self.cfg.box_size_tolerance_px
        z = (det[None, :] - sizes) / tol
        fits = (np.abs(z) <= 1.0).all(axis=1)
        if not fits.any():
            return None
        w = np.exp(-0.5 * (z[fits] ** 2).sum(axis=1))
        return courses[fits], w / w.sum(), boxes[fits]

    def _no_heading_fits(self, det: np.ndarray, sizes: np.ndarray) -> bool:
        """True when the box's (width, height) ``det`` differs from every heading's predicted ``sizes`` (n, 2)
        by more than the tolerance in width or height: no heading the ship may have explains it."""
        g = self.cfg
        tol, tol_px = g.box_size_tolerance, g.box_size_tolerance_px
        dw, dh = det.tolist()
        for w, h in sizes.tolist():  # (a few headings: plain floats, the same IEEE operations as numpy's)
            if not (abs(dw - w) > tol * w + tol_px or abs(dh - h) > tol * h + tol_px):
                return False  # this heading explains the box
        return True

    def _to_now(self, nav: Measurements, cam: CameraMotion | None, prior: TargetState) -> tuple[float, float]:
        """The detection's box centre brought from its exposure to now (``propagate_feature``): its ray, from
        the camera pose at the exposure (kept from the ticks before), meets the target's plane; that point,
        moved on by the estimated velocity over the latency, is projected into the camera of now. Unchanged
        without latency, or when the exposure's pose is not at hand."""
        u, v = float(nav.det_u_px), float(nav.det_v_px)
        g, c = self.cfg, self.camera
        age = float(nav.t_s) - float(nav.det_exposure_t_s)
        if cam is None or not (g.propagate_feature and 0.0 < age <= g.max_propagation_s):
            return u, v
        t_exp = float(nav.det_exposure_t_s)
        past = min(self._poses, key=lambda p: abs(p[0] - t_exp), default=None)
        if past is None or abs(past[0] - t_exp) > 0.5 * _POSE_MATCH_S:
            return u, v
        _, c_exp, R_exp = past
        x1, x2 = c.normalised(u, v)
        d = R_exp @ np.array([float(x1), float(x2), 1.0])
        known = prior.known and np.all(np.isfinite(prior.pos_enu_m)) and np.all(np.isfinite(prior.vel_enu_m_s))
        plane = float(prior.pos_enu_m[2]) if known else 0.0
        if d[2] >= -1e-6:  # the ray does not come down to the plane
            return u, v
        point = c_exp + ((plane - c_exp[2]) / d[2]) * d
        if known:
            point = point + age * np.asarray(prior.vel_enu_m_s, dtype=float)
        q = np.asarray(cam.R_enu_from_cam, dtype=float).T @ (point - cam.pos_enu_m)
        if q[2] <= 1.0:
            return u, v
        return c.fx * q[0] / q[2] + c.cx, c.fy * q[1] / q[2] + c.cy

    def remember_pose(self, cam: CameraMotion | None) -> None:
        """Keep the camera pose of this tick for the detections exposed now that arrive later."""
        if cam is not None and self.cfg.propagate_feature:
            self._poses.append((float(cam.t_s), np.asarray(cam.pos_enu_m, dtype=float),
                                np.asarray(cam.R_enu_from_cam, dtype=float)))

    def _class_check(self, t_s: float, mismatch: bool) -> bool:
        """Record one size check; True while the boxes disagree with the ship class (see the module text)."""
        g, window = self.cfg, self._size_off
        if len(window) == window.maxlen:
            self._size_off_count -= window[0]  # the oldest leaves the window
        window.append(mismatch)
        self._size_off_count += mismatch
        if len(window) < window.maxlen:
            return self.class_mismatch
        share = self._size_off_count / len(window)
        if not self.class_mismatch and share >= g.class_mismatch_enter:
            self.class_mismatch = True
            self._event(f"perception: {100 * share:.0f} % of the last {len(window)} boxes are off the ship class's "
                        "size: rescale from now on")
        elif self.class_mismatch and share <= g.class_mismatch_exit:
            self.class_mismatch = False
            self._event(f"perception: the boxes fit the ship class again ({100 * share:.0f} % off): class "
                        "correction and size gate as configured")
        return self.class_mismatch

    def _event(self, text: str) -> None:
        if self._record is not None:
            self._record.event(text)

    def _decide(self, reason: str) -> tuple[bool, str]:
        """(use it, the gate passed over): skip on a gate reason until max_skipped_in_a_row (bar too_close)."""
        if reason and (reason == FusionReason.TOO_CLOSE or self.skipped_in_a_row < self.cfg.max_skipped_in_a_row):
            self.skipped_in_a_row += 1
            return False, ""
        self.skipped_in_a_row = 0
        return True, reason


def _closer_in_size(det: np.ndarray, cut: np.ndarray, whole: np.ndarray) -> bool:
    """The detected box's (width, height) ``det`` is nearer (in log ratio, both sides) to the cut box's than
    to the whole one's: the detection is the cut one (a box merely next to the airframe is whole)."""
    def misfit(box):
        size = np.maximum(box[2:4] - box[0:2], 1.0)
        return float(np.sum(np.log(np.maximum(det, 1.0) / size) ** 2))
    return misfit(cut) < misfit(whole)
