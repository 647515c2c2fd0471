"""Onboard sensors: what the mission computer can know.

Each sensor adds white Gaussian noise with its own ``numpy.random.Generator``,
seeded from the scenario seed and the sensor's name (so adding a sensor never
shifts another's noise). Each sensor also has its own update rate: between
updates the mission computer holds the last sample (as it would hold the last
GNSS fix). The flight software reads them at its own rate; the camera
detection arrives through ``Detector`` (fwsim.sensors.camera) at the camera's rate,
with its own latency.
"""
from __future__ import annotations

import zlib
from typing import Any, Literal

import numpy as np
from pydantic import Field, model_validator

from fwsim.interface.configbase import StrictModel
from fwsim.interface.messages import AirframeState, Measurements

_NAN3 = np.full(3, np.nan)  # copied for each message's wind_enu_m_s (Measurements' default)


class SensorsConfig(StrictModel):
    """The onboard sensors: a profile of error models feeding the navigation filter (``typical``, ``degraded``),
    or ``ideal``: the truth with the white noise of the fields below, the autopilot on the truth."""

    profile: Literal["ideal", "typical", "degraded"] = Field(
        "ideal", description="ideal: truth plus the white noise below, autopilot on truth; typical: a PX4-class "
                             "small UAV through the onboard INS; degraded: consumer MEMS, a poor GNSS")
    errors: dict[str, Any] = Field(
        default_factory=dict, description="overrides of the profile's error terms, e.g. {gnss: {latency_s: 0.15}} "
                                          "(fields: docs/guide/sensors.md); not with ideal")

    position_noise_m: float = Field(0.5, ge=0, le=100, description="GNSS/INS position, per axis")
    velocity_noise_m_s: float = Field(0.05, ge=0, le=10, description="GNSS/INS velocity, per axis")
    attitude_noise_rad: float = Field(0.002, ge=0, le=0.2, description="AHRS roll, pitch, yaw")
    gyro_noise_rad_s: float = Field(0.003, ge=0, le=1, description="body rates, per axis")
    airspeed_noise_m_s: float = Field(0.2, ge=0, le=10, description="pitot airspeed")
    height_noise_m: float = Field(0.5, ge=0, le=100, description="height above the sea")
    encoder_noise_rad: float = Field(0.0005, ge=0, le=0.1, description="gimbal pan and tilt encoders")
    gnss_rate_hz: float = Field(10.0, gt=0, le=1000, description="position and velocity updates")
    ahrs_rate_hz: float = Field(100.0, gt=0, le=1000, description="attitude and gyro updates")
    air_data_rate_hz: float = Field(20.0, gt=0, le=1000, description="airspeed and height updates")
    encoder_rate_hz: float = Field(100.0, gt=0, le=1000, description="gimbal encoder updates")

    @model_validator(mode="after")
    def _errors_resolve(self) -> "SensorsConfig":
        if self.errors:
            if self.profile == "ideal":
                raise ValueError("errors: the ideal profile has no error models to override (profile: typical)")
            from pydantic import ValidationError

            from fwsim.sensors.error_config import resolve
            try:
                resolve(self.profile, self.errors)  # an unknown key or a value out of bounds: said here
            except ValidationError as exc:
                e = exc.errors()[0]
                where = ".".join(str(x) for x in e["loc"])
                why = "unknown key" if e["type"] == "extra_forbidden" else e["msg"]
                raise ValueError(f"sensors.errors.{where}: {why}") from None
            except ValueError as exc:
                raise ValueError(f"sensors.errors: {exc}") from None
        return self


def rng_for(seed: int, name: str) -> np.random.Generator:
    """A generator for one named noise source, fixed by the scenario seed."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(name.encode())]))


class _Held:
    """Sample-and-hold at a rate: ``due(t)`` is true when a new sample is due."""

    __slots__ = ("period", "next_t", "value")

    def __init__(self, rate_hz: float):
        self.period = 1.0 / rate_hz
        self.next_t = -1.0
        self.value = None

    def due(self, t_s: float) -> bool:
        if t_s + 1e-9 >= self.next_t:
            self.next_t = (t_s if self.next_t < 0 else self.next_t) + self.period
            if self.next_t <= t_s:  # sampled more slowly than the sensor's rate: catch up
                self.next_t = t_s + self.period
            return True
        return False


class Sensors:
    """Samples the truth into a ``Measurements`` message."""

    def __init__(self, cfg: SensorsConfig, seed: int):
        self.cfg = cfg
        names = ("position", "velocity", "attitude", "gyro", "airspeed", "height", "encoders")
        self._rng = {n: rng_for(seed, "sensor/" + n) for n in names}
        self._gnss = _Held(cfg.gnss_rate_hz)
        self._ahrs = _Held(cfg.ahrs_rate_hz)
        self._air = _Held(cfg.air_data_rate_hz)
        self._enc = _Held(cfg.encoder_rate_hz)

    def _n(self, name: str, sigma: float, size=None):
        if sigma == 0.0:
            return np.zeros(size) if size else 0.0
        return self._rng[name].normal(0.0, sigma, size)

    def sample(self, uav: AirframeState, gimbal=None, cam_pos_enu_m=None, detection=None,
               last_detection=None, gnss_held: bool = False) -> Measurements:
        """``detection``: the one arriving this tick (or None); ``last_detection``: the newest so far;
        ``gnss_held``: a GNSS outage, no new fix (the last one stays, with its time)."""
        c, t = self.cfg, uav.t_s
        if self._gnss.due(t) and not gnss_held:
            self._gnss.value = (uav.pos_enu_m + self._n("position", c.position_noise_m, 3),
                                uav.vel_enu_m_s + self._n("velocity", c.velocity_noise_m_s, 3),
                                uav.pos_enu_m, t)
        if self._ahrs.due(t):
            self._ahrs.value = (uav.euler_ned_rad + self._n("attitude", c.attitude_noise_rad, 3),
                                uav.body_rates_frd_rad_s + self._n("gyro", c.gyro_noise_rad_s, 3))
        if self._air.due(t):
            self._air.value = (uav.airspeed_m_s + self._n("airspeed", c.airspeed_noise_m_s),
                               uav.height_above_sea_m + self._n("height", c.height_noise_m))
        pos, vel, pos_true, nav_t = self._gnss.value
        euler, rates = self._ahrs.value
        airspeed, height = self._air.value
        enc = None
        if gimbal is not None:
            if self._enc.due(t):
                e = self._n("encoders", c.encoder_noise_rad, 2)
                self._enc.value = (gimbal.pan_rad + e[0], gimbal.tilt_rad + e[1], gimbal.pan_rate_rad_s,
                                   gimbal.tilt_rate_rad_s)
            enc = self._enc.value
        # r_c from the navigation solution and the known mount: it carries the same position error
        cam = None if cam_pos_enu_m is None else cam_pos_enu_m + (pos - pos_true)
        det = detection if detection is not None else last_detection
        if enc is not None and cam is not None and det is not None:  # the loop's case: every field, in order
            pan, tilt, pan_rate, tilt_rate = enc  # (positional: a third of the keyword call's cost)
            return Measurements(t, pos, vel, euler, rates, airspeed, height, nav_t, pan, tilt, pan_rate, tilt_rate,
                                cam, detection is not None, det.detected, det.exposure_t_s, det.u_px, det.v_px,
                                det.bbox_px, _NAN3.copy())  # (wind_enu_m_s: not a sensor's, NaN as the default)
        kw = {}
        if enc is not None:
            kw.update(zip(("pan_rad", "tilt_rad", "pan_rate_rad_s", "tilt_rate_rad_s"), enc))
        if cam is not None:
            kw["cam_pos_enu_m"] = cam
        if det is not None:
            kw.update(det_new=detection is not None, det_valid=det.detected, det_exposure_t_s=det.exposure_t_s,
                      det_u_px=det.u_px, det_v_px=det.v_px, det_bbox_px=det.bbox_px)
        return Measurements(t_s=t, pos_enu_m=pos, vel_enu_m_s=vel, euler_ned_rad=euler,
                            body_rates_frd_rad_s=rates, airspeed_m_s=airspeed, height_above_sea_m=height, nav_t_s=nav_t,
                            **kw)
