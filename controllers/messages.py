"""Typed messages between the flight software's blocks, and what they put in the log.

``fwsim.interface.messages`` holds the boundary (``Measurements`` in, commands out);
these are the flight software's own: each a frozen dataclass whose first
field is ``t_s``, vectors as float64 arrays, NaN for a field that does not
apply (PX4's convention). In signal order::

    nav (Measurements) -> CameraMotion -> TargetState (prior) -> DetectionFix
        -> TargetState (posterior) -> PhaseState -> Guidance, GimbalCommand

and, for the log: :class:`TargetEstimate` (``/fsw/estimate``),
:class:`DetectionFusion` (``/fsw/detection_fusion``, one per detection
received, in the style of PX4's estimator aid-source messages) and
:class:`EstimatorStatus` (``/fsw/estimator_status``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

import numpy as np

from fwsim.interface.messages import AutopilotCommand

_NAN2 = lambda: np.full(2, np.nan)  # noqa: E731


class FusionReason(StrEnum):
    """What became of one detection (``DetectionFusion.reason``)."""

    USED = "used"  # fused into the estimate
    INITIALISED = "initialised"  # started (or restarted) the estimator
    ACQUIRING = "acquiring"  # before the lock: it counts toward it
    NOT_INITIALISED = "not_initialised"  # the estimator is down and this detection did not start it
    NO_CAMERA_POSE = "no_camera_pose"  # no gimbal encoders: the ray is unknown
    TOO_CLOSE = "too_close"  # the target is closer than detection_gate.min_range_m
    OVERFLOWING_BOX = "overflowing_box"  # the box spans the image: the ship is larger than the frame
    SIZE_MISMATCH = "size_mismatch"  # no heading of the ship model explains the box's size
    AIRFRAME_HIDDEN = "airframe_hidden"  # course unknown, over airframe.max_hidden_share of the ship hidden
    INNOVATION_GATE = "innovation_gate"  # the estimator's chi-square test rejected it
    REJECTED = "rejected"  # the estimator could not use it (e.g. its ray misses the sea plane)
    ESTIMATOR_RESET = "estimator_reset"  # the estimator diverged on it and reset itself


#: reasons whose detection went into the estimate
FUSED = (FusionReason.USED, FusionReason.INITIALISED)


@dataclass(frozen=True, slots=True)
class TargetEstimate:
    """A target estimator's output at ``t_s``, for the log and the controllers."""

    t_s: float
    pos_enu_m: np.ndarray  # (3,) r_q
    vel_enu_m_s: np.ndarray  # (3,) V_q
    pos_std_m: np.ndarray  # (3,) sqrt of the diagonal of the r_q covariance as reported (the UKFs: plus the box bias)
    vel_std_m_s: np.ndarray  # (3,)
    x1: float  # normalised image features (NaN if the estimator has none)
    x2: float
    innovation_px: np.ndarray  # (2,) pixel innovation of an update at t_s; NaN when no update at t_s


@dataclass(frozen=True, slots=True)
class TargetState:
    """What the flight software believes of the target at ``t_s`` (the estimation block's output).

    ``source``: ``"estimator"`` (the estimator's estimate), ``"extrapolated"`` (the
    estimator is down: its last estimate carried on at its velocity) or ``"none"``
    (never estimated: positions NaN).
    """

    t_s: float
    source: str
    pos_enu_m: np.ndarray  # (3,) the tracked point (tracked_height_m above the waterline)
    vel_enu_m_s: np.ndarray  # (3,)
    vel_std_m_s: float  # horizontal velocity std, the larger axis (NaN unless from the estimator)
    tracked_height_m: float  # height of the tracked point above the ship's waterline, m
    # the ship's manoeuvre, when the estimator estimates one (controllers.estimation.ct_ukf) or a steady turn or a
    # zigzag's periodic course is found in a constant-velocity estimate's course (controllers.estimation.course_turn;
    # the periodic course's rate now); 0 otherwise: the turn rate of its course (ENU, counter-clockwise positive) and
    # its acceleration along its track
    turn_rate_rad_s: float = 0.0
    accel_along_m_s2: float = 0.0

    @property
    def known(self) -> bool:
        return self.source != "none"

    @property
    def from_estimator(self) -> bool:
        return self.source == "estimator"


@dataclass(frozen=True, slots=True)
class DetectionFix:
    """The newest detection as the perception hands it to the estimator (``new``: one arrived this tick)."""

    t_s: float
    new: bool  # a detection with a box arrived this tick
    exposure_t_s: float
    raw_u_px: float  # the detector's box centre
    raw_v_px: float
    bbox_px: np.ndarray  # (4,) u_min, v_min, u_max, v_max
    u_px: float  # the box centre corrected for the ship's shape (the raw one when not corrected)
    v_px: float
    predicted_box_px: np.ndarray  # (4,) the ship model's box for its most likely heading (NaN: none)
    use: bool  # perception's decision: give it to the estimator
    reason: str  # FusionReason of a skip ("" when use)
    overridden: str  # a gate reason passed over (detection_gate.max_skipped_in_a_row), else ""
    locked: bool  # the target is locked (acquisition done)
    lock_now: bool  # this tick made the lock
    lock_t_s: float  # when it was locked (NaN before)
    last_detection_t_s: float  # arrival of the newest detection with a box (NaN before any)
    # (2 x 2, px^2) the spread of the shape correction over the ship's possible headings (zeros: one heading,
    # or no correction): how far (u_px, v_px) may be off while the heading is not known
    offset_spread_px2: np.ndarray = field(default_factory=lambda: np.zeros((2, 2)))
    # (px^2, u and v) variance added to the box centre's pixel noise where the estimator fuses it: a box whose
    # size no heading explains, used with its doubt (detection_gate.size_mismatch_action: deweight)
    centre_noise_px2: tuple = (0.0, 0.0)


@dataclass(frozen=True, slots=True)
class FusionResult:
    """An estimator's answer to one ``update``."""

    used: bool
    reason: str  # FusionReason: used, innovation_gate, rejected or estimator_reset
    innovation_px: np.ndarray = field(default_factory=_NAN2)  # (2,) pixel innovation (NaN: none)
    test_ratio: float = math.nan  # normalised innovation squared over the gate (> 1: rejected; NaN: none)


@dataclass(frozen=True, slots=True)
class DetectionFusion:
    """One detection the flight software received and what became of it (``/fsw/detection_fusion``)."""

    t_s: float
    exposure_t_s: float
    raw_u_px: float
    raw_v_px: float
    corrected_u_px: float  # after the ship-shape correction (the raw centre when none applied)
    corrected_v_px: float
    bbox_px: np.ndarray  # (4,)
    predicted_box_px: np.ndarray  # (4,) the ship model's box (NaN: none)
    used: bool
    reason: str  # FusionReason
    overridden: str  # a gate reason passed over after max_skipped_in_a_row skips ("" otherwise)
    innovation_px: np.ndarray  # (2,) NaN when the estimator computed none
    test_ratio: float  # innovation test ratio (NaN when none)


@dataclass(frozen=True, slots=True)
class EstimatorStatus:
    """The estimator's counters since the start (``/fsw/estimator_status``, written when one changes)."""

    t_s: float
    updates: int  # detections fused
    innovation_rejected: int  # detections its innovation gate rejected
    rejected: int  # detections it could not use
    resets: int  # times it diverged and reset itself
    numerical_resets: int  # covariance repairs (not positive definite)
    initialisations: int  # times it was (re)started


@dataclass(frozen=True, slots=True)
class Guidance:
    """A guidance block's output: the autopilot command and its set-points for ``/fsw/status``."""

    command: AutopilotCommand
    name: str  # e.g. "loiter:nmpc"; the phase name in /fsw/status
    course_sp_rad: float = math.nan  # ENU, counter-clockwise from East
    bank_sp_rad: float = math.nan
    altitude_sp_m: float = math.nan
    cross_track_m: float = math.nan
