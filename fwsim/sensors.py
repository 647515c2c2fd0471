"""Onboard sensors: what the mission computer can know.

Each sensor adds white Gaussian noise with its own ``numpy.random.Generator``,
seeded from the scenario seed and the sensor's name (so adding a sensor never
shifts another's noise). Sampled at the flight software's rate; the camera
detection arrives through ``Detector`` (fwsim.camera) at the camera's rate,
with its own latency.
"""
from __future__ import annotations

import zlib

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from fwsim.messages import AirframeState, Measurements


class SensorsConfig(BaseModel):
    """Noise standard deviations (zero: ideal)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    position_noise_m: float = Field(0.5, ge=0, le=100, description="GNSS/INS position, per axis")
    velocity_noise_m_s: float = Field(0.05, ge=0, le=10, description="GNSS/INS velocity, per axis")
    attitude_noise_rad: float = Field(0.002, ge=0, le=0.2, description="AHRS roll, pitch, yaw")
    gyro_noise_rad_s: float = Field(0.003, ge=0, le=1, description="body rates, per axis")
    airspeed_noise_m_s: float = Field(0.2, ge=0, le=10, description="pitot airspeed")
    height_noise_m: float = Field(0.5, ge=0, le=100, description="height above the sea")
    encoder_noise_rad: float = Field(0.0005, ge=0, le=0.1, description="gimbal pan and tilt encoders")


def rng_for(seed: int, name: str) -> np.random.Generator:
    """A generator for one named noise source, fixed by the scenario seed."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), zlib.crc32(name.encode())]))


class Sensors:
    """Samples the truth into a ``Measurements`` message."""

    def __init__(self, cfg: SensorsConfig, seed: int):
        self.cfg = cfg
        names = ("position", "velocity", "attitude", "gyro", "airspeed", "height", "encoders")
        self._rng = {n: rng_for(seed, "sensor/" + n) for n in names}

    def _n(self, name: str, sigma: float, size=None):
        if sigma == 0.0:
            return np.zeros(size) if size else 0.0
        return self._rng[name].normal(0.0, sigma, size)

    def sample(self, uav: AirframeState, gimbal=None, cam_pos_enu_m=None, detection=None,
               last_detection=None) -> Measurements:
        """``detection``: the one arriving this tick (or None); ``last_detection``: the newest so far."""
        c = self.cfg
        kw = {}
        if gimbal is not None:
            e = self._n("encoders", c.encoder_noise_rad, 2)
            kw.update(pan_rad=gimbal.pan_rad + e[0], tilt_rad=gimbal.tilt_rad + e[1],
                      pan_rate_rad_s=gimbal.pan_rate_rad_s, tilt_rate_rad_s=gimbal.tilt_rate_rad_s)
        pos_noise = self._n("position", c.position_noise_m, 3)
        if cam_pos_enu_m is not None:  # r_c from the navigation solution and the known mount: same error
            kw["cam_pos_enu_m"] = cam_pos_enu_m + pos_noise
        det = detection if detection is not None else last_detection
        if det is not None:
            kw.update(det_new=detection is not None, det_valid=det.detected, det_exposure_t_s=det.exposure_t_s,
                      det_u_px=det.u_px, det_v_px=det.v_px, det_bbox_px=det.bbox_px)
        return Measurements(
            t_s=uav.t_s,
            pos_enu_m=uav.pos_enu_m + pos_noise,
            vel_enu_m_s=uav.vel_enu_m_s + self._n("velocity", c.velocity_noise_m_s, 3),
            euler_ned_rad=uav.euler_ned_rad + self._n("attitude", c.attitude_noise_rad, 3),
            body_rates_frd_rad_s=uav.body_rates_frd_rad_s + self._n("gyro", c.gyro_noise_rad_s, 3),
            airspeed_m_s=uav.airspeed_m_s + self._n("airspeed", c.airspeed_noise_m_s),
            height_above_sea_m=uav.height_above_sea_m + self._n("height", c.height_noise_m),
            **kw,
        )
