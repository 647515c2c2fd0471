"""Timed faults and disturbances of a scenario (``events:``): the harness's side of a harsher world.

Each event starts at ``t_s``, or ``delay_s`` after the flight software first
enters phase ``after_phase``, and lasts ``duration_s`` (a ship manoeuvre: until
its new course and speed are reached)::

    events:
      - {kind: detector_blackout, t_s: 60, duration_s: 3}        # no detections
      - {kind: false_detections, t_s: 70, duration_s: 5, rate_hz: 10}   # clutter boxes
      - {kind: gnss_outage, after_phase: 2, delay_s: 5, duration_s: 10} # no new GNSS fix
      - {kind: gnss_jump, t_s: 80, duration_s: 15, offset_enu_m: [50, 0, 0]}  # the fixes step off
      - {kind: mag_interference, t_s: 85, duration_s: 10, offset_frd_gauss: [0.3, 0, 0]}
      - {kind: imu_bias_step, t_s: 95, gyro_frd_rad_s: [0, 0, 0.01]}        # and stays
      - {kind: baro_drift, t_s: 100, duration_s: 30, rate_m_s: 0.5}         # and stays
      - {kind: gimbal_stuck, t_s: 90, duration_s: 2}              # the joints do not move
      - {kind: wind_gust, after_phase: 3, delay_s: 2, duration_s: 3, velocity_enu_m_s: [0, 6, 0]}
      - {kind: target_manoeuvre, after_phase: 3, course_deg: 90, speed_m_s: 8}   # 1.5 deg/s, 0.5 m/s^2

Every event's start and end are lines on ``/events``. The flight software is
never told: it sees only what its sensors then give it. Random parts (the
clutter boxes) draw from their own stream of the scenario's seed.
"""
from __future__ import annotations

import math
from typing import Annotated, Literal, Union

import numpy as np
from pydantic import Field, model_validator

from fwsim.interface.configbase import StrictModel

__all__ = ["Event", "EventRunner", "EVENT_KINDS", "NAV_FAULT_KINDS"]

_Vec3 = Annotated[list[float], Field(min_length=3, max_length=3)]


class _Start(StrictModel):
    t_s: float | None = Field(None, ge=0.0, le=1e5, description="start time (s); or after_phase")
    after_phase: Literal[1, 2, 3] | None = Field(
        None, description="start when the flight software first enters this phase (plus delay_s)")
    delay_s: float = Field(0.0, ge=0.0, le=1e5, description="with after_phase: how long after it")

    @model_validator(mode="after")
    def _one_start(self):
        if (self.t_s is None) == (self.after_phase is None):
            raise ValueError("give the start as t_s or as after_phase (with delay_s), not both or neither")
        if self.t_s is not None and self.delay_s:
            raise ValueError("delay_s goes with after_phase")
        return self


class _Timed(_Start):
    duration_s: float = Field(gt=0.0, le=1e5, description="how long the event lasts")


class DetectorBlackout(_Timed):
    """The detector reports nothing (its frames still run, its noise stream unchanged)."""

    kind: Literal["detector_blackout"] = Field(description="detector_blackout: the detector sees nothing for a while")


class FalseDetections(_Timed):
    """Clutter: at ``rate_hz`` (on average) a frame's detection is a box somewhere else in the image."""

    kind: Literal["false_detections"] = Field(description="false_detections: the detector reports boxes where no "
                                                          "ship is")
    rate_hz: float = Field(gt=0.0, le=240.0, description="clutter boxes per second, on average")
    box_px: tuple[float, float] = Field((12.0, 120.0), description="range of the boxes' side, px")

    @model_validator(mode="after")
    def _box(self):
        if not 1.0 <= self.box_px[0] <= self.box_px[1]:
            raise ValueError(f"box_px: expected [smallest, largest] side >= 1 px (got {list(self.box_px)})")
        return self


class GnssOutage(_Timed):
    """The receiver gives no new fix: the last one is held (with its time), the flight software dead-reckons."""

    kind: Literal["gnss_outage"] = Field(description="gnss_outage: no GNSS fix for a while")


class GnssJump(_Timed):
    """The receiver's position steps by ``offset_enu_m`` (a multipath or spoofed fix) for a while; the
    navigation filter's gate should turn it away, then reset to it if it lasts (needs a sensor profile)."""

    kind: Literal["gnss_jump"] = Field(description="gnss_jump: the GNSS position steps off for a while")
    offset_enu_m: _Vec3 = Field(description="the step added to every fix, world ENU (m)")


class MagInterference(_Timed):
    """A field added to the magnetometer's (a motor current, a payload) for a while (needs a sensor profile)."""

    kind: Literal["mag_interference"] = Field(description="mag_interference: a field added to the magnetometer's")
    offset_frd_gauss: _Vec3 = Field(description="the field added, body FRD (gauss)")


class ImuBiasStep(_Start):
    """The IMU's biases step and stay (a knock, a temperature jump); the filter's bias states should take it
    up (needs a sensor profile)."""

    kind: Literal["imu_bias_step"] = Field(description="imu_bias_step: the gyro and accelerometer biases step")
    gyro_frd_rad_s: _Vec3 = Field([0.0, 0.0, 0.0], description="the gyro bias step, body FRD (rad/s)")
    accel_frd_m_s2: _Vec3 = Field([0.0, 0.0, 0.0], description="the accelerometer bias step, body FRD (m/s^2)")


class BaroDrift(_Timed):
    """The barometer's height drifts at ``rate_m_s`` for a while (weather, a blocked port), and the drift
    stays (needs a sensor profile)."""

    kind: Literal["baro_drift"] = Field(description="baro_drift: the barometric height drifts for a while")
    rate_m_s: float = Field(ge=-20.0, le=20.0, description="the drift's rate (m/s)")


class GimbalStuck(_Timed):
    """The gimbal's joints stay where they are, whatever is commanded."""

    kind: Literal["gimbal_stuck"] = Field(description="gimbal_stuck: the gimbal's joints hold for a while")


class WindGust(_Timed):
    """A 1 - cos gust (JSBSim's cosine gust, local frame): up to ``velocity_enu_m_s`` at mid-duration, back
    to nothing at the end."""

    kind: Literal["wind_gust"] = Field(description="wind_gust: a gust added to the wind for a while")
    velocity_enu_m_s: _Vec3 = Field(description="the gust's peak air velocity, world ENU (m/s)")

    @model_validator(mode="after")
    def _strength(self):
        if not 0.0 < math.hypot(*self.velocity_enu_m_s) <= 40.0:
            raise ValueError("velocity_enu_m_s: the gust's peak must be between 0 and 40 m/s")
        return self


class TargetManoeuvre(_Start):
    """The ship leaves its motion model: it turns the short way to ``course_deg`` at ``turn_rate_deg_s`` and
    changes to ``speed_m_s`` at ``accel_m_s2`` (either may be left out), then holds them. The event ends
    when both are reached."""

    kind: Literal["target_manoeuvre"] = Field(description="target_manoeuvre: the ship changes its motion")
    course_deg: float | None = Field(None, ge=-360.0, le=360.0, description="new course, clockwise from North")
    speed_m_s: float | None = Field(None, ge=0.0, le=25.0, description="new speed over ground")
    turn_rate_deg_s: float = Field(1.5, gt=0.0, le=10.0, description="rate of the turn")
    accel_m_s2: float = Field(0.5, gt=0.0, le=5.0, description="magnitude of the speed change's acceleration")

    @model_validator(mode="after")
    def _something(self):
        if self.course_deg is None and self.speed_m_s is None:
            raise ValueError("give course_deg, speed_m_s or both")
        return self


Event = Annotated[Union[DetectorBlackout, FalseDetections, GnssOutage, GnssJump, MagInterference, ImuBiasStep,
                        BaroDrift, GimbalStuck, WindGust, TargetManoeuvre],
                  Field(discriminator="kind")]
EVENT_KINDS = ("detector_blackout", "false_detections", "gnss_outage", "gnss_jump", "mag_interference",
               "imu_bias_step", "baro_drift", "gimbal_stuck", "wind_gust", "target_manoeuvre")
#: the kinds that act on the sensors' error models (a sensor profile other than ideal)
NAV_FAULT_KINDS = ("gnss_jump", "mag_interference", "imu_bias_step", "baro_drift")


def _describe(ev, duration_s: float) -> str:
    extra = {"false_detections": lambda e: f", {e.rate_hz:g} boxes/s",
             "wind_gust": lambda e: f", peak {math.hypot(*e.velocity_enu_m_s):.1f} m/s",
             "target_manoeuvre": lambda e: "".join(
                 ([f", course {e.course_deg:g} deg"] if e.course_deg is not None else [])
                 + ([f", speed {e.speed_m_s:g} m/s"] if e.speed_m_s is not None else []))}.get(ev.kind)
    return f"{ev.kind} ({duration_s:g} s{extra(ev) if extra else ''})"


class EventRunner:
    """Which events are on at each tick; starts and ends them and says so in the log.

    The loop asks it each tick (``step``) and reads its flags: ``blackout``,
    ``clutter_rate_hz``, ``gnss_held`` and ``gimbal_stuck``; a gust is handed to
    the airframe once, at its start.
    """

    def __init__(self, events: list, rng: np.random.Generator):
        self.events = list(events)
        self.rng = rng
        self._start = [ev.t_s for ev in self.events]  # None until an after_phase event's phase comes
        self._state = ["pending"] * len(self.events)  # pending | on | over
        self._phase_seen: dict[int, float] = {}
        self._duration = [getattr(ev, "duration_s", 0.0) for ev in self.events]  # a manoeuvre's: at its start
        self.blackout = False
        self.clutter_rate_hz = 0.0
        self.gnss_held = False
        self.gimbal_stuck = False
        self._clutter_box_px = None  # box size range of the first false_detections event on

    def step(self, t_s: float, phase: int | None, log_event, gust=None, manoeuvre=None, nav=None) -> None:
        """Advance to ``t_s`` (the flight software's phase now, if known): start and end events,
        ``log_event(t, text)`` for each, ``gust(velocity_enu_m_s, duration_s)`` at a gust's start,
        ``manoeuvre(t, event) -> duration_s`` at a ship manoeuvre's start, ``nav(event, on)`` at a
        navigation fault's start and end (:data:`NAV_FAULT_KINDS`; gnss_outage too)."""
        if phase is not None and phase not in self._phase_seen:
            self._phase_seen[phase] = t_s
        changed = False
        for i, ev in enumerate(self.events):
            if self._start[i] is None and ev.after_phase in self._phase_seen:
                self._start[i] = self._phase_seen[ev.after_phase] + ev.delay_s
            start = self._start[i]
            if start is None or self._state[i] == "over":
                continue
            if self._state[i] == "pending" and t_s >= start - 1e-9:
                self._state[i], changed = "on", True
                if ev.kind == "target_manoeuvre":
                    self._duration[i] = manoeuvre(t_s, ev)
                log_event(t_s, f"event started: {_describe(ev, self._duration[i])}")
                if ev.kind == "wind_gust":
                    gust(ev.velocity_enu_m_s, ev.duration_s)
                if nav is not None and (ev.kind in NAV_FAULT_KINDS or ev.kind == "gnss_outage"):
                    nav(ev, True)
            if self._state[i] == "on" and t_s >= start + self._duration[i] - 1e-9:
                self._state[i], changed = "over", True
                log_event(t_s, f"event ended: {ev.kind}")
                if nav is not None and (ev.kind in NAV_FAULT_KINDS or ev.kind == "gnss_outage"):
                    nav(ev, False)
        if changed:
            self._flags()

    def _flags(self) -> None:
        """The loop's flags from the events that are on (recomputed when one starts or ends)."""
        on = [ev for ev, s in zip(self.events, self._state) if s == "on"]
        self.blackout = any(ev.kind == "detector_blackout" for ev in on)
        self.clutter_rate_hz = sum(ev.rate_hz for ev in on if ev.kind == "false_detections")
        self.gnss_held = any(ev.kind == "gnss_outage" for ev in on)
        self.gimbal_stuck = any(ev.kind == "gimbal_stuck" for ev in on)
        self._clutter_box_px = next((ev.box_px for ev in on if ev.kind == "false_detections"), None)

    def clutter_box(self, frame_rate_hz: float, width_px: int, height_px: int) -> np.ndarray | None:
        """During false detections: a clutter box (u0, v0, u1, v1) for this frame, or None. Draws the same
        numbers every frame of the window, so one frame's outcome never shifts the next's."""
        if self.clutter_rate_hz <= 0.0:
            return None
        draw = self.rng.random(4)
        lo, hi = self._clutter_box_px
        if draw[0] >= min(1.0, self.clutter_rate_hz / frame_rate_hz):
            return None
        side = lo + draw[1] * (hi - lo)
        u0 = draw[2] * max(width_px - side, 1.0)
        v0 = draw[3] * max(height_px - side, 1.0)
        return np.array([u0, v0, min(u0 + side, width_px - 1.0), min(v0 + side, height_px - 1.0)])
