"""Settings of the sensor error models (fwsim.sensors.errors) and their three profiles.

One sub-model per sensor, every field with its unit in its name. ``typical()`` is the
defaults; ``ideal()`` zeroes every error term (the models then give the truth exactly);
``degraded()`` is consumer-grade MEMS and a poor GNSS. ``resolve(profile, overrides)``
merges a partial dict of overrides into a profile.

Where the typical values come from (docs/design/sensor_errors.md has the table):

* IMU: the Gazebo Classic IMU plugin's settings in the plane model behind PX4 SITL: gyro
  noise density 3.394e-4 rad/s/sqrt(Hz), bias random walk 3.8785e-5 rad/s^2/sqrt(Hz) with
  a 1000 s correlation time, turn-on bias sigma 0.0087 rad/s; accelerometer noise density
  0.004 m/s^2/sqrt(Hz), bias random walk 0.006 m/s^3/sqrt(Hz) with a 300 s correlation time,
  turn-on bias sigma 0.196 m/s^2. That plugin makes the in-run bias a first-order
  Gauss-Markov process driven by the random-walk density K with correlation time tau, whose
  steady-state sigma is K * sqrt(tau / 2) (8.7e-4 rad/s, 0.073 m/s^2): the same here.
  Scale factor and misalignment are not in that plugin: our choice.
* GNSS: rate 5 Hz and delay 0.12 s from the same PX4 SITL (its GPS plugin); position error
  a Gauss-Markov process with tau = 1100 s and sigma 0.21 m horizontal, 0.40 m vertical
  from mavsim_python (the uavbook's simulator). There 0.21 m and 0.40 m are the driving
  noise of each 1 s step, whose steady state would be about 4.9 m and 9.4 m; here they are
  the steady-state sigma (a good receiver over a short flight). The PX4 plugin's "60 s
  correlation time" decays its bias by 1/60 per physics step, not per second, so it is not
  used as a time constant here.
* Baro, magnetometer, pitot, encoders, camera mount: our choice (see the page).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any, Literal

from pydantic import Field

from fwsim.interface.configbase import StrictModel

__all__ = [
    "GyroErrorsConfig", "AccelErrorsConfig", "ImuErrorsConfig", "GnssErrorsConfig", "BaroErrorsConfig",
    "MagErrorsConfig", "PitotErrorsConfig", "EncoderErrorsConfig", "CameraMountErrorsConfig", "SensorErrorsConfig",
    "ideal", "typical", "degraded", "PROFILES", "resolve",
]

BiasModel = Literal["gauss_markov", "random_walk"]
_DEG = math.pi / 180.0


class GyroErrorsConfig(StrictModel):
    """Rate gyro error terms (per axis, body FRD)."""

    noise_density_rad_s_sqrt_hz: float = Field(
        3.394e-4, ge=0, le=0.1, description="white rate noise (angle random walk), rad/s/sqrt(Hz)")
    bias_model: BiasModel = Field(
        "gauss_markov", description="in-run bias: gauss_markov (driven by the random walk, bias_tau_s) or random_walk")
    bias_random_walk_rad_s2_sqrt_hz: float = Field(
        3.8785e-5, ge=0, le=0.01, description="in-run bias driving noise, rad/s^2/sqrt(Hz) (rad/s per sqrt(s))")
    bias_tau_s: float = Field(
        1000.0, gt=0, le=1e6, description="in-run bias correlation time (gauss_markov); steady sigma K*sqrt(tau/2)")
    turn_on_bias_sigma_rad_s: float = Field(
        0.0087, ge=0, le=1, description="bias drawn once at power-on, sigma per axis")
    scale_factor_sigma_frac: float = Field(
        0.005, ge=0, le=0.2, description="scale factor error drawn once, sigma per axis (0.005: 0.5 %)")
    misalignment_sigma_rad: float = Field(
        0.003, ge=0, le=0.1, description="axis cross-coupling drawn once, sigma of each off-diagonal term")


class AccelErrorsConfig(StrictModel):
    """Accelerometer error terms (per axis, body FRD)."""

    noise_density_m_s2_sqrt_hz: float = Field(
        0.004, ge=0, le=1, description="white specific-force noise (velocity random walk), m/s^2/sqrt(Hz)")
    bias_model: BiasModel = Field(
        "gauss_markov", description="in-run bias: gauss_markov (driven by the random walk, bias_tau_s) or random_walk")
    bias_random_walk_m_s3_sqrt_hz: float = Field(
        0.006, ge=0, le=1, description="in-run bias driving noise, m/s^3/sqrt(Hz) (m/s^2 per sqrt(s))")
    bias_tau_s: float = Field(
        300.0, gt=0, le=1e6, description="in-run bias correlation time (gauss_markov); steady sigma K*sqrt(tau/2)")
    turn_on_bias_sigma_m_s2: float = Field(
        0.196, ge=0, le=10, description="bias drawn once at power-on, sigma per axis")
    scale_factor_sigma_frac: float = Field(
        0.003, ge=0, le=0.2, description="scale factor error drawn once, sigma per axis (0.003: 0.3 %)")
    misalignment_sigma_rad: float = Field(
        0.003, ge=0, le=0.1, description="axis cross-coupling drawn once, sigma of each off-diagonal term")


class ImuErrorsConfig(StrictModel):
    """The IMU: a gyro triad and an accelerometer triad, one sample per simulation step."""

    gyro: GyroErrorsConfig = Field(default_factory=GyroErrorsConfig, description="rate gyro error terms")
    accel: AccelErrorsConfig = Field(default_factory=AccelErrorsConfig, description="accelerometer error terms")


class GnssErrorsConfig(StrictModel):
    """GNSS receiver: fixes at a rate, late by a latency, with a slowly wandering position error."""

    rate_hz: float = Field(5.0, gt=0, le=50, description="fixes per second")
    latency_s: float = Field(0.12, ge=0, le=2, description="a fix arrives this long after its time of fix")
    pos_horizontal_sigma_m: float = Field(
        0.21, ge=0, le=100, description="steady-state sigma of the Gauss-Markov position error, east and north each")
    pos_vertical_sigma_m: float = Field(
        0.40, ge=0, le=200, description="steady-state sigma of the Gauss-Markov position error, up")
    pos_horizontal_tau_s: float = Field(
        1100.0, gt=0, le=1e6, description="correlation time of the east and north position error")
    pos_vertical_tau_s: float = Field(1100.0, gt=0, le=1e6, description="correlation time of the up position error")
    vel_horizontal_sigma_m_s: float = Field(
        0.05, ge=0, le=10, description="white velocity noise per fix, east and north each")
    vel_vertical_sigma_m_s: float = Field(0.10, ge=0, le=10, description="white velocity noise per fix, up")
    accuracy_scale_ratio: float = Field(
        1.0, gt=0, le=10, description="reported h_acc, v_acc, s_acc = this times the configured sigmas (1: honest)")


class BaroErrorsConfig(StrictModel):
    """Barometric altimeter: white noise and a slow Gauss-Markov drift from zero at power-on."""

    rate_hz: float = Field(20.0, gt=0, le=1000, description="samples per second")
    noise_sigma_m: float = Field(0.3, ge=0, le=100, description="white height noise per sample")
    drift_sigma_m: float = Field(1.0, ge=0, le=1000, description="steady-state sigma of the drift (weather, heating)")
    drift_tau_s: float = Field(600.0, gt=0, le=1e6, description="correlation time of the drift")


class MagErrorsConfig(StrictModel):
    """Magnetometer: the earth's field rotated into the body, a hard-iron bias, white noise."""

    rate_hz: float = Field(50.0, gt=0, le=1000, description="samples per second")
    field_strength_gauss: float = Field(0.5, gt=0, le=1, description="earth field magnitude (not an error term)")
    inclination_deg: float = Field(60.0, ge=-90, le=90, description="field dip below the horizontal (+: down)")
    declination_deg: float = Field(0.0, ge=-180, le=180, description="field east of true north")
    noise_sigma_gauss: float = Field(0.005, ge=0, le=1, description="white noise per sample, per axis")
    hard_iron_sigma_gauss: float = Field(
        0.01, ge=0, le=2, description="body-fixed offset drawn once (the hard iron left after calibration), sigma per "
                                      "axis")


class PitotErrorsConfig(StrictModel):
    """Pitot-static airspeed: white noise and a bias drawn once."""

    rate_hz: float = Field(20.0, gt=0, le=1000, description="samples per second")
    noise_sigma_m_s: float = Field(0.3, ge=0, le=10, description="white airspeed noise per sample")
    bias_sigma_m_s: float = Field(0.3, ge=0, le=10, description="airspeed bias drawn once, sigma")


class EncoderErrorsConfig(StrictModel):
    """Gimbal pan and tilt encoders: white noise and a zero offset drawn once."""

    rate_hz: float = Field(100.0, gt=0, le=1000, description="samples per second")
    noise_sigma_rad: float = Field(0.0005, ge=0, le=0.1, description="white angle noise per sample, pan and tilt")
    bias_sigma_rad: float = Field(0.002, ge=0, le=0.2, description="zero offset drawn once, sigma, pan and tilt")


class CameraMountErrorsConfig(StrictModel):
    """The camera's boresight and focal length as built, relative to the nominal ones."""

    boresight_sigma_rad: float = Field(
        0.25 * _DEG, ge=0, le=0.2, description="small rotation of the camera frame drawn once, sigma per axis")
    focal_scale_sigma_frac: float = Field(
        0.005, ge=0, le=0.2, description="focal length relative error drawn once, sigma (0.005: 0.5 %)")


class SensorErrorsConfig(StrictModel):
    """Error terms of every onboard sensor the navigation filter is fed (defaults: the typical profile)."""

    imu: ImuErrorsConfig = Field(default_factory=ImuErrorsConfig, description="gyro and accelerometer triads")
    gnss: GnssErrorsConfig = Field(default_factory=GnssErrorsConfig, description="GNSS receiver")
    baro: BaroErrorsConfig = Field(default_factory=BaroErrorsConfig, description="barometric altimeter")
    mag: MagErrorsConfig = Field(default_factory=MagErrorsConfig, description="magnetometer")
    pitot: PitotErrorsConfig = Field(default_factory=PitotErrorsConfig, description="pitot airspeed")
    encoders: EncoderErrorsConfig = Field(default_factory=EncoderErrorsConfig, description="gimbal encoders")
    camera_mount: CameraMountErrorsConfig = Field(
        default_factory=CameraMountErrorsConfig, description="camera boresight and focal length errors")


# --------------------------------------------------------------------------- profiles


def typical() -> SensorErrorsConfig:
    """A PX4-class small UAV (the defaults; sources in the module docstring)."""
    return SensorErrorsConfig()


def ideal() -> SensorErrorsConfig:
    """Every error term zero and no GNSS latency: each model returns the truth exactly (rates as typical)."""
    common = {"scale_factor_sigma_frac": 0.0, "misalignment_sigma_rad": 0.0}
    gyro = {"noise_density_rad_s_sqrt_hz": 0.0, "bias_random_walk_rad_s2_sqrt_hz": 0.0,
            "turn_on_bias_sigma_rad_s": 0.0, **common}
    accel = {"noise_density_m_s2_sqrt_hz": 0.0, "bias_random_walk_m_s3_sqrt_hz": 0.0,
             "turn_on_bias_sigma_m_s2": 0.0, **common}
    return SensorErrorsConfig.model_validate({
        "imu": {"gyro": gyro, "accel": accel},
        "gnss": {"latency_s": 0.0, "pos_horizontal_sigma_m": 0.0, "pos_vertical_sigma_m": 0.0,
                 "vel_horizontal_sigma_m_s": 0.0, "vel_vertical_sigma_m_s": 0.0},
        "baro": {"noise_sigma_m": 0.0, "drift_sigma_m": 0.0},
        "mag": {"noise_sigma_gauss": 0.0, "hard_iron_sigma_gauss": 0.0},
        "pitot": {"noise_sigma_m_s": 0.0, "bias_sigma_m_s": 0.0},
        "encoders": {"noise_sigma_rad": 0.0, "bias_sigma_rad": 0.0},
        "camera_mount": {"boresight_sigma_rad": 0.0, "focal_scale_sigma_frac": 0.0},
    })


def degraded() -> SensorErrorsConfig:
    """Consumer MEMS and a poor GNSS: about 3x the typical noise and biases, GNSS 1.5 m / 3 m, 0.2 s late."""
    return SensorErrorsConfig.model_validate({
        "imu": {
            "gyro": {"noise_density_rad_s_sqrt_hz": 1.0e-3, "bias_random_walk_rad_s2_sqrt_hz": 1.2e-4,
                     "turn_on_bias_sigma_rad_s": 0.026, "scale_factor_sigma_frac": 0.015,
                     "misalignment_sigma_rad": 0.009},
            "accel": {"noise_density_m_s2_sqrt_hz": 0.012, "bias_random_walk_m_s3_sqrt_hz": 0.018,
                      "turn_on_bias_sigma_m_s2": 0.59, "scale_factor_sigma_frac": 0.009,
                      "misalignment_sigma_rad": 0.009},
        },
        "gnss": {"rate_hz": 5.0, "latency_s": 0.2, "pos_horizontal_sigma_m": 1.5, "pos_vertical_sigma_m": 3.0,
                 "pos_horizontal_tau_s": 60.0, "pos_vertical_tau_s": 60.0,
                 "vel_horizontal_sigma_m_s": 0.25, "vel_vertical_sigma_m_s": 0.5},
        "baro": {"noise_sigma_m": 0.9, "drift_sigma_m": 3.0},
        "mag": {"noise_sigma_gauss": 0.015, "hard_iron_sigma_gauss": 0.04},
        "pitot": {"noise_sigma_m_s": 0.9, "bias_sigma_m_s": 0.9},
        "encoders": {"noise_sigma_rad": 0.0015, "bias_sigma_rad": 0.006},
        "camera_mount": {"boresight_sigma_rad": 0.75 * _DEG, "focal_scale_sigma_frac": 0.015},
    })


#: profile name -> the function returning its fully filled config
PROFILES: dict[str, Callable[[], SensorErrorsConfig]] = {"ideal": ideal, "typical": typical, "degraded": degraded}


def _nested(overrides: Mapping[str, Any]) -> dict[str, Any]:
    """Dotted keys (``"gnss.latency_s"``) spelt out as nested dicts; nested dicts kept."""
    out: dict[str, Any] = {}
    for key, value in overrides.items():
        *path, leaf = str(key).split(".")
        node = out
        for part in path:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ValueError(f"override {key!r}: {part!r} is given both as a value and as a section")
        node[leaf] = _nested(value) if isinstance(value, Mapping) else value
    return out


def _merge(base: dict[str, Any], overrides: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` with ``overrides`` laid over it, section by section."""
    out = dict(base)
    for key, value in overrides.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def resolve(profile: str = "typical", overrides: Mapping[str, Any] | None = None) -> SensorErrorsConfig:
    """The profile's config with ``overrides`` merged in (nested dicts or dotted keys, any depth).

    ``resolve("degraded", {"gnss": {"latency_s": 0.1}, "imu.gyro.bias_tau_s": 500})``. An unknown
    profile raises ValueError; an unknown key or an out-of-bounds value fails validation.
    """
    if profile not in PROFILES:
        raise ValueError(f"unknown sensor error profile {profile!r}; known: {', '.join(PROFILES)}")
    base = PROFILES[profile]().model_dump()
    return SensorErrorsConfig.model_validate(_merge(base, _nested(overrides or {})))
