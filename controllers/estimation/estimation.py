"""Estimation: the target estimator's life cycle around any filter that implements the estimator Protocol.

Per tick the flight software calls :meth:`Estimation.predict` (the estimate
brought to now: the perception's prior) and then :meth:`Estimation.update`
with the perception's fix. The filter itself (the paper's UKF, or a user's
class, ``controllers.blocks.TargetEstimator``) only predicts, fuses and
estimates; this block decides when it starts and restarts:

* it starts at the lock, from the detection that made it;
* a filter that resets itself (non-finite state: the target left the
  camera's front half-space, where x1 = X/Z blows up) is restarted by the
  next detection, unless the last estimate, carried on at its velocity, is
  closer than ``detection_gate.min_range_m`` (the detections the gate
  distrusts would restart it); meanwhile that extrapolated estimate stands in.
* with ``controllers.turn_from_course`` (on by default) a constant-velocity
  filter's fused estimates feed :class:`controllers.estimation.course_turn.CourseTurn`;
  once it finds a steady turn (or, with ``periodic``, a zigzag's periodic
  course), the state handed on has the filter's lag in the turn taken out
  and the turn rate (carried along the turn or the fitted course between
  fused detections), while ``/fsw/estimate`` stays the filter's own.

Its output, :class:`~controllers.messages.TargetState`, is what the phase
logic, the guidance and the pointing read. It writes ``/fsw/estimate``, one
``/fsw/detection_fusion`` per detection received (the perception's decision and
the filter's answer) and ``/fsw/estimator_status`` when a counter changes.

Nothing here imports the truth side of the harness (docs/design/architecture.md, "Two rules").
"""
from __future__ import annotations

import dataclasses
import functools
import math
import operator

import numpy as np

from controllers.estimation.course_turn import CourseTurn
from controllers.messages import DetectionFix, DetectionFusion, FusionReason, FusionResult, TargetEstimate, TargetState
from controllers.navigation.camera_model import CameraMotion, closing_time_s
from fwsim.interface import topics
from fwsim.interface.messages import Measurements

__all__ = ["Estimation"]

_NAN3 = np.full(3, np.nan)
_NAN3.setflags(write=False)


class Estimation:
    """The estimator's life cycle (see the module text); ``filter`` implements ``TargetEstimator``."""

    def __init__(self, filter, min_range_m: float, lock_detections: int, recorder, turn_from_course=None):
        self.filter = filter
        self.label = getattr(filter, "label", type(filter).__name__)  # its name in the events
        self.min_range_m = float(min_range_m)
        self.lock_detections = int(lock_detections)
        self._record = recorder
        self._running = False  # the filter ran at the start of this tick (it may reset itself in it)
        self._last: tuple[float, np.ndarray, np.ndarray] | None = None  # (t_s, pos, vel) of its last estimate
        self._status = None
        # a turning ship through a constant-velocity filter (controllers.estimation.course_turn); None: off
        self._turn_cfg = turn_from_course if turn_from_course is not None and turn_from_course.enabled else None
        self.turn = CourseTurn(self._turn_cfg) if self._turn_cfg is not None else None

    # ------------------------------------------------------------------ steps
    def predict(self, nav: Measurements, cam: CameraMotion | None) -> TargetState:
        """Bring the estimate to now (the filter's predict); the prior for the perception."""
        self._running = bool(self.filter.initialised) and cam is not None
        if self._running:
            self.filter.predict(nav.t_s, cam)
        return self._state(nav.t_s)[0]

    def update(self, nav: Measurements, cam: CameraMotion | None, fix: DetectionFix) -> TargetState:
        """Start, fuse or restart on this tick's fix; the posterior estimate."""
        t = nav.t_s
        result = None
        if fix.lock_now and cam is not None:
            why = self._initialise(fix, cam)
            self._record.event(f"target locked after {self.lock_detections} detections; "
                               + (f"{self.label} initialised" if not why else f"{self.label} not initialised yet "
                                                                              f"({why})"))
            result = FusionResult(not why, FusionReason.NOT_INITIALISED if why else FusionReason.INITIALISED)
        elif self._running:
            if fix.new:
                result = self.filter.update(fix, cam) if fix.use else FusionResult(False, fix.reason)
            if not self.filter.initialised:
                self._record.event(f"{self.label} reset itself at t = {t:.2f} s (non-finite prediction: the "
                                   "target left the camera's front half-space); extrapolating the last estimate")
        elif fix.locked and cam is not None and fix.new:
            result = self._restart(nav, fix, cam)
        est = self.filter.estimate() if self.filter.initialised else None
        if self.turn is not None and est is not None and result is not None and result.used:
            self._observe_turn(t, cam, est)
        state, est = self._state(t, est)
        if est is not None:
            self._last = (t, np.array(est.pos_enu_m, float), np.array(est.vel_enu_m_s, float))
            self._record.log(topics.FSW_ESTIMATE, est)
        if fix.new:
            self._record.log(topics.FSW_DETECTION_FUSION, _fusion(fix, result, cam))
        self._log_status(t)
        return state

    # ------------------------------------------------------------------ internals
    def _observe_turn(self, t_s: float, cam: CameraMotion, est) -> None:
        """Give the course-turn finder this fused estimate and the time to go of the camera closing on it (a
        filter that estimates the turn itself: skipped)."""
        if hasattr(est, "turn_rate_rad_s"):
            return
        vel_std = _larger_of_first_two(np.asarray(est.vel_std_m_s, dtype=float))
        pos, vel = np.asarray(est.pos_enu_m, dtype=float), np.asarray(est.vel_enu_m_s, dtype=float)
        self.turn.observe(t_s, pos, vel, vel_std, getattr(self.filter, "pos_vel_cov", None),
                          closing_time_s(pos, vel, cam.pos_enu_m, cam.vel_enu_m_s))
        if self.turn.fitted:
            self._record.log(topics.FSW_COURSE_TURN, self.turn.status(t_s))

    def _initialise(self, fix: DetectionFix, cam: CameraMotion) -> str:
        """Start the filter from this detection; '' when it did, else why not (e.g. the ray misses the sea)."""
        if self._turn_cfg is not None:
            self.turn = CourseTurn(self._turn_cfg)  # a new start: no history of its course
        try:
            self.filter.initialise(fix, cam)
        except ValueError as exc:
            return str(exc)
        return ""

    def _restart(self, nav: Measurements, fix: DetectionFix, cam: CameraMotion) -> FusionResult:
        """The filter is down: restart it from this detection unless the target is too close for that."""
        if self._too_close_to_restart(nav):
            return FusionResult(False, FusionReason.TOO_CLOSE)
        if self._initialise(fix, cam):
            return FusionResult(False, FusionReason.NOT_INITIALISED)
        self._record.event(f"{self.label} re-initialised from a detection at t = {nav.t_s:.2f} s")
        return FusionResult(True, FusionReason.INITIALISED)

    def _too_close_to_restart(self, nav: Measurements) -> bool:
        """The last estimate (extrapolated) is nearer than min_range_m: a restart would take the close-in
        detections the perception's gate distrusts, so it keeps extrapolating."""
        if self.min_range_m <= 0.0 or self._last is None:
            return False
        return float(np.linalg.norm(self._extrapolated(nav.t_s)[0] - nav.pos_enu_m)) < self.min_range_m

    def _extrapolated(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        t0, pos, vel = self._last
        return pos + vel * (t_s - t0), vel

    def _state(self, t_s: float, est: TargetEstimate | None = None) -> tuple[TargetState, TargetEstimate | None]:
        """The target state now: the filter's estimate (``est`` when the caller has it already), else the last
        one extrapolated, else none."""
        h = float(self.filter.tracked_height_m)
        if self.filter.initialised:
            if est is None:
                est = self.filter.estimate()
            vel_std = _larger_of_first_two(np.asarray(est.vel_std_m_s, dtype=float))
            turn, accel = float(getattr(est, "turn_rate_rad_s", 0.0)), float(getattr(est, "accel_along_m_s2", 0.0))
            turned = self.turn.state(t_s) if self.turn is not None else None
            if turned is not None:  # the turn found in the course, the filter's lag taken out
                return TargetState(t_s, "estimator", turned[0], turned[1], vel_std, h, turned[2], 0.0), est
            return TargetState(t_s, "estimator", est.pos_enu_m, est.vel_enu_m_s, vel_std, h,
                               turn if math.isfinite(turn) else 0.0, accel if math.isfinite(accel) else 0.0), est
        if self._last is not None:
            pos, vel = self._extrapolated(t_s)
            return TargetState(t_s, "extrapolated", pos, vel, math.nan, h), None
        return TargetState(t_s, "none", _NAN3, _NAN3, math.nan, h), None

    def _log_status(self, t_s: float) -> None:
        status = self.filter.status(t_s)
        key = _counters_of(type(status))(status)
        if key != self._status:
            self._status = key
            self._record.log(topics.FSW_ESTIMATOR_STATUS, status)


def _larger_of_first_two(v: np.ndarray) -> float:
    """``float(v[:2].max())`` (the larger horizontal std); numpy's reduction only for a tie or a NaN."""
    if len(v) >= 2:
        a, b = v[0], v[1]
        if a > b:
            return float(a)
        if b > a:
            return float(b)
    return float(v[:2].max())


@functools.cache
def _counters_of(status_type: type):
    """A status message's counters (its fields after ``t_s``) as one getter: status -> tuple."""
    names = [f.name for f in dataclasses.fields(status_type)[1:]]
    return operator.attrgetter(*names) if len(names) > 1 else lambda status: tuple(getattr(status, n) for n in names)


def _fusion(fix: DetectionFix, result: FusionResult | None, cam) -> DetectionFusion:
    """The log's record of one detection: the perception's decision and the estimator's answer."""
    if result is None:  # nothing decided beyond the perception (e.g. before the lock)
        reason = fix.reason or (FusionReason.NO_CAMERA_POSE if cam is None else FusionReason.NOT_INITIALISED)
        result = FusionResult(False, reason)
    return DetectionFusion(fix.t_s, fix.exposure_t_s, fix.raw_u_px, fix.raw_v_px, fix.u_px, fix.v_px, fix.bbox_px,
                           fix.predicted_box_px, bool(result.used), str(result.reason), fix.overridden,
                           result.innovation_px, result.test_ratio)
