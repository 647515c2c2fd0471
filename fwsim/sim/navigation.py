"""The aircraft's knowledge of itself as flown: the sensors' error models feeding the onboard INS.

With ``sensors.profile`` ``typical`` or ``degraded`` the loop builds an :class:`OnboardNavigation`:

* every simulation tick the truth side's error models (:mod:`fwsim.sensors.errors`) make the raw
  samples a real aircraft's sensors would give (IMU delta angles and velocities, GNSS fixes late by
  the receiver's latency, barometric height, magnetometer, pitot), and the onboard INS
  (:class:`controllers.navigation.ins.Ins`, flight software) fuses them;
* the autopilot closes its loops on the INS's estimate and the pitot
  (:meth:`OnboardNavigation.autopilot_view`): angle of attack and sideslip are worked out from the
  estimated velocity, attitude and wind, as no sensor on the airframe measures them;
* the flight software's :class:`~fwsim.interface.messages.Measurements` carry the estimate, the pitot,
  the gimbal encoders with their errors, and the camera's position from the estimate and the mount
  offset it knows a priori (:meth:`OnboardNavigation.measurements`).

Faults from the scenario's events (``gnss_outage``, ``gnss_jump``, ``mag_interference``,
``imu_bias_step``, ``baro_drift``) act on the error models here; what the INS did about them reaches
the log as its events. With ``sensors.profile: ideal`` none of this is built: the autopilot reads
the truth and the sensors add white noise (:class:`fwsim.sensors.onboard.Sensors`), as before.
"""
from __future__ import annotations

import math

import numpy as np

from controllers.navigation.ins import Ins
from fwsim.interface.frames import camera_pose_world, dcm_enu_from_frd
from fwsim.interface.messages import ActuatorCommand, AirframeState, Measurements, NavEstimate
from fwsim.sensors.error_config import resolve
from fwsim.sensors.errors import SensorErrorModels

__all__ = ["OnboardNavigation"]

_NAN3 = np.full(3, np.nan)


class OnboardNavigation:
    """Error models (truth side) and the onboard INS of one run (see the module text)."""

    def __init__(self, scenario):
        s = scenario.sensors
        self.errors = resolve(s.profile, s.errors)
        self.models = SensorErrorModels.build(self.errors, scenario.seed)
        self.ins = Ins(scenario.controllers.ins)
        self.mount_offset_frd_m = np.asarray(scenario.camera.gimbal.mount_offset_frd_m, dtype=float)
        self.estimate: NavEstimate | None = None
        self.airspeed_m_s = math.nan  # the pitot's latest
        self.encoders = None  # the latest EncoderSample
        self._gyro_step = np.zeros(3)  # imu_bias_step faults, added to the IMU's own errors
        self._accel_step = np.zeros(3)

    # ------------------------------------------------------------------ faults
    def fault(self, ev, on: bool) -> None:
        """A navigation fault of the scenario's events (:mod:`fwsim.world.events`) starting (``on``) or ending,
        acted out on the error models: an outage stops the fixes, a jump steps them off (and back at its end),
        interference adds a field, a bias step adds to the IMU's biases for good, a drift grows the barometer's
        error while it lasts (what it grew stays)."""
        kind, m = ev.kind, self.models
        if kind == "gnss_outage":
            m.gnss.outage(on)
        elif kind == "gnss_jump":
            m.gnss.jump(np.asarray(ev.offset_enu_m, dtype=float) * (1.0 if on else -1.0))
        elif kind == "mag_interference":
            m.mag.interference(ev.offset_frd_gauss if on else [0.0, 0.0, 0.0])
        elif kind == "imu_bias_step" and on:
            self._gyro_step = self._gyro_step + np.asarray(ev.gyro_frd_rad_s, dtype=float)
            self._accel_step = self._accel_step + np.asarray(ev.accel_frd_m_s2, dtype=float)
        elif kind == "baro_drift":
            m.baro.drift_fault(ev.rate_m_s if on else 0.0)

    # ------------------------------------------------------------------ each tick
    def step(self, uav: AirframeState, gimbal=None) -> NavEstimate | None:
        """The sensors sampled from the truth at this tick and fused; the INS's estimate (None while it aligns)."""
        m, ins = self.models, self.ins
        imu = m.imu.step(uav)
        if imu is not None:
            if self._gyro_step.any() or self._accel_step.any():
                imu = type(imu)(imu.t_s, imu.dt_s, imu.delta_angle_frd_rad + self._gyro_step * imu.dt_s,
                                imu.delta_velocity_frd_m_s + self._accel_step * imu.dt_s)
            ins.predict(imu)
        for fix in m.gnss.step(uav):
            ins.fuse_gnss(fix)
        baro = m.baro.step(uav)
        if baro is not None:
            ins.fuse_baro(baro)
        mag = m.mag.step(uav)
        if mag is not None:
            ins.fuse_mag(mag)
        pitot = m.pitot.step(uav)
        if pitot is not None:
            self.airspeed_m_s = pitot.airspeed_m_s
            ins.fuse_airspeed(pitot)
        if gimbal is not None:
            enc = m.encoders.step(uav.t_s, gimbal.pan_rad, gimbal.tilt_rad)
            if enc is not None:
                self.encoders = enc
        self.estimate = ins.estimate() if ins.initialised else None
        return self.estimate

    # ------------------------------------------------------------------ what the autopilot and the software see
    def autopilot_view(self, act: ActuatorCommand | None) -> AirframeState | None:
        """The aircraft as the autopilot knows it: the estimate, the pitot's airspeed, the angle of attack and
        sideslip of the estimated air-relative velocity in the estimated body frame, the actuators as
        commanded; None while the INS aligns."""
        est = self.estimate
        if est is None:
            return None
        wind = est.wind_enu_m_s if np.isfinite(est.wind_enu_m_s).all() else np.zeros(3)
        u, v, w = dcm_enu_from_frd(est.euler_ned_rad).T @ (np.asarray(est.vel_enu_m_s, float) - wind)
        speed = math.sqrt(u * u + v * v + w * w)
        alpha = math.atan2(w, u)
        beta = math.asin(max(-1.0, min(1.0, v / speed))) if speed > 1e-6 else 0.0
        airspeed = self.airspeed_m_s if math.isfinite(self.airspeed_m_s) else speed
        throttle = act.throttle_norm if act is not None else math.nan
        surfaces = np.array([act.aileron_norm, act.elevator_norm, act.rudder_norm]) if act is not None else _NAN3
        return AirframeState(est.t_s, est.pos_enu_m, est.vel_enu_m_s, est.euler_ned_rad, est.body_rates_frd_rad_s,
                             airspeed, alpha, beta, est.specific_force_frd_m_s2, throttle, surfaces,
                             float(est.pos_enu_m[2]))

    def measurements(self, t_s: float, gimbal, detection, last_detection) -> Measurements | None:
        """The flight software's inputs at ``t_s``: the estimate (brought to now: its time is the newest IMU
        sample's), the pitot, the encoders, the camera's position from the estimate and the mount offset, the
        newest detection; None while the INS aligns."""
        est = self.estimate
        if est is None:
            return None
        kw = {}
        enc = self.encoders
        if enc is not None and gimbal is not None:
            cam_pos, _ = camera_pose_world(est.pos_enu_m, est.euler_ned_rad, self.mount_offset_frd_m, enc.pan_rad,
                                           enc.tilt_rad)
            kw.update(pan_rad=enc.pan_rad, tilt_rad=enc.tilt_rad, pan_rate_rad_s=gimbal.pan_rate_rad_s,
                      tilt_rate_rad_s=gimbal.tilt_rate_rad_s, cam_pos_enu_m=cam_pos)
        det = detection if detection is not None else last_detection
        if det is not None:
            kw.update(det_new=detection is not None, det_valid=det.detected, det_exposure_t_s=det.exposure_t_s,
                      det_u_px=det.u_px, det_v_px=det.v_px, det_bbox_px=det.bbox_px)
        return Measurements(t_s=t_s, pos_enu_m=est.pos_enu_m, vel_enu_m_s=est.vel_enu_m_s,
                            euler_ned_rad=est.euler_ned_rad, body_rates_frd_rad_s=est.body_rates_frd_rad_s,
                            airspeed_m_s=self.airspeed_m_s, height_above_sea_m=float(est.pos_enu_m[2]),
                            nav_t_s=t_s, wind_enu_m_s=est.wind_enu_m_s, att_std_rad=est.att_std_rad, **kw)
