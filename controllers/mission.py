"""The flight software: ``Measurements`` in, autopilot and gimbal commands out.

Phases (paper, "Simulation"):

1. Acquisition: the UAV flies its initial path while the gimbal sweeps a
   raster (controllers/search.py) until the detector reports the target on
   ``lock_detections`` frames in a row. At lock the UKF is initialised from the
   detection and IBVS takes the gimbal. After lock the UAV keeps to its path,
   or (``after_lock: orbit``) circles the estimated target at R, H: a simple
   stand-in until the NMPC loiter (Phase 2) exists.
2. NMPC loiter with the CBF, and 3. BPNG terminal guidance: later issues.

IBVS runs in every phase once locked. The UKF predicts every step and updates
on each new detection. A scripted command list can stand in for the mission.

Nothing here imports the truth side of the harness (DESIGN.md section 1).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from controllers.camera_model import PinholeCamera, depth_on_plane
from controllers.ibvs import Ibvs
from controllers.path import OrbitFollower, PathFollower
from controllers.script import ScriptedCommands
from controllers.search import GimbalSearch
from controllers.ukf import CameraMotion, UkfTargetEstimator
from fwsim.messages import AutopilotCommand, FlightSoftwareStatus, GimbalCommand, Measurements

GIMBAL_ANGLE_GAIN_1_S = 3.0  # scripted gimbal angles: joint rate per rad of encoder error


@dataclass(frozen=True, slots=True)
class FlightSoftwareOutput:
    command: AutopilotCommand
    gimbal: GimbalCommand
    status: FlightSoftwareStatus
    logs: dict = field(default_factory=dict)  # topic -> message, for the log only
    events: tuple = ()  # text lines for the log's /events (phase switches, lock)


class FlightSoftware:
    """One object at the boundary: measurements in, commands out."""

    def __init__(self, controllers_cfg, initial_cfg, camera_cfg):
        self.cfg = controllers_cfg
        self.kind = controllers_cfg.kind
        self.mount = np.asarray(camera_cfg.gimbal.mount_offset_frd_m, dtype=float)
        if self.kind == "script":
            self._script = ScriptedCommands(controllers_cfg.script)
            return
        path = controllers_cfg.initial_path
        self._path = PathFollower(path.airspeed_m_s, initial_cfg.pos_enu_m, math.radians(initial_cfg.heading_deg),
                                  path.waypoints_enu_m, path.max_bank_deg)
        o = controllers_cfg.orbit
        self._orbit = OrbitFollower(o.airspeed_m_s, o.radius_m, o.altitude_m, o.clockwise, path.max_bank_deg)
        self.camera = PinholeCamera.from_config(camera_cfg)
        self._search = GimbalSearch(controllers_cfg.acquisition)
        self._ukf = UkfTargetEstimator(self.camera, controllers_cfg.ukf)
        self._ibvs = Ibvs(controllers_cfg.ibvs, self.camera.fx, self.camera.fy, self.camera.cx, self.camera.cy)

    # ------------------------------------------------------------------ scripted
    def _scripted(self, meas: Measurements) -> FlightSoftwareOutput:
        cmd = self._script.step(meas)
        sp = self._script.gimbal_setpoint_rad(meas.t_s)
        if sp is None or math.isnan(meas.pan_rad):
            g = GimbalCommand(meas.t_s, math.nan, math.nan)
        else:
            g = GimbalCommand(meas.t_s, GIMBAL_ANGLE_GAIN_1_S * (sp[0] - meas.pan_rad),
                              GIMBAL_ANGLE_GAIN_1_S * (sp[1] - meas.tilt_rad))
        return FlightSoftwareOutput(cmd, g, FlightSoftwareStatus(meas.t_s, 0, "script", cmd.mode))

    # ------------------------------------------------------------------ mission
    def _depth(self, meas: Measurements, motion: CameraMotion) -> float | None:
        """Depth of the target along the optical axis: from the estimate, else flat-sea geometry."""
        if self._ukf.initialised:
            z = float((motion.R_enu_from_cam.T @ (self._ukf.pos_enu_m - motion.pos_enu_m))[2])
            return z if z > 1.0 else None
        if meas.det_valid:
            x1, x2 = self.camera.normalised(meas.det_u_px, meas.det_v_px)
            z = depth_on_plane(x1, x2, motion.R_enu_from_cam, motion.height_m, self.cfg.ukf.target_plane_height_m)
            return float(z) if np.isfinite(z) else None
        return None

    def step(self, meas: Measurements) -> FlightSoftwareOutput:
        if self.kind == "script":
            return self._scripted(meas)
        events = []
        logs = {}
        motion = CameraMotion.from_measurements(meas, self.mount) if math.isfinite(meas.pan_rad) else None
        # Phase 1 acquisition: lock, then start the estimator
        if self._search.observe(meas) and motion is not None:
            self._ukf.initialise(meas, motion)
            events.append(f"target locked after {self._search.cfg.lock_detections} detections; UKF initialised")
        elif self._ukf.initialised and motion is not None:
            self._ukf.predict(meas.t_s, motion)
            if meas.det_new and meas.det_valid:
                self._ukf.update(meas, motion)
        if self._ukf.initialised:
            logs["/fsw/estimate"] = self._ukf.estimate()
        # gimbal: search until lock, IBVS after
        locked = self._search.locked
        if not locked or motion is None:
            gimbal = self._search.step(meas)
        else:
            vel = self._ukf.vel_enu_m_s if self._ukf.initialised else None
            gimbal, ibvs_status = self._ibvs.step(meas, vel, self._depth(meas, motion), self.mount)
            logs["/fsw/ibvs"] = ibvs_status
        # the UAV: initial path, or the orbit stand-in around the estimate after lock
        if locked and self.cfg.after_lock == "orbit" and self._ukf.initialised:
            cmd, chi_c, radial = self._orbit.step(meas, self._ukf.pos_enu_m)
            status = FlightSoftwareStatus(meas.t_s, 1, "acquisition:orbit", "rates", course_sp_rad=chi_c,
                                          altitude_sp_m=self._orbit.altitude_m, locked=True,
                                          lock_t_s=self._search.lock_t_s, radial_err_m=radial)
        else:
            cmd, st = self._path.step(meas)
            status = FlightSoftwareStatus(meas.t_s, 1, "acquisition:" + ("path" if locked else "search"), "rates",
                                          course_sp_rad=st.course_sp_rad, bank_sp_rad=st.bank_sp_rad,
                                          altitude_sp_m=st.altitude_sp_m, cross_track_m=st.cross_track_m,
                                          locked=locked, lock_t_s=self._search.lock_t_s)
        return FlightSoftwareOutput(cmd, gimbal, status, logs, tuple(events))
