"""The flight software: ``Measurements`` in, autopilot and gimbal commands out.

Phases (paper, "Simulation"):

1. Acquisition: the UAV flies its initial path while the gimbal sweeps a
   raster (controllers/search.py) until the detector reports the target on
   ``lock_detections`` frames in a row. At lock the UKF is initialised from the
   detection and IBVS takes the gimbal.
2. Loiter (``after_lock``): ``nmpc`` (the paper's NMPC with the CBF,
   controllers/nmpc.py) or ``orbit`` (a simple circle follower) around the
   estimated target at R, H; ``path`` keeps the initial path (no Phase 2).
3. Terminal: quaternion BPNG (controllers/bpng.py) through the autopilot's
   acceleration mode, once the switch condition holds (``switch``: radius and
   altitude held within tolerances for ``dwell_s``, at least ``min_loiter_s``
   in Phase 2 (the two run side by side), and the bearing from the UAV to the
   target within ``approach_window_deg`` of the impact heading). The reason is
   logged as an event.

IBVS runs in every phase once locked. The UKF predicts every step and updates
on each new detection. A scripted command list can stand in for the mission.

Nothing here imports the truth side of the harness (DESIGN.md section 1).
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np

from pydantic import BaseModel, ConfigDict, Field

from controllers.bpng import Bpng
from controllers.camera_model import PinholeCamera, depth_on_plane
from controllers.nav import Navigation
from controllers.nmpc import Nmpc
from controllers.ibvs import Ibvs
from controllers.path import OrbitFollower, PathFollower
from controllers.script import ScriptedCommands
from controllers.search import GimbalSearch
from controllers.target_model import ShapeHeading, ShipOutline, box_centre_offset_px, predicted_boxes_px
from controllers.ukf import CameraMotion, UkfTargetEstimator
from fwsim.frames import dcm_enu_from_frd, pan_tilt_pointing_at, wrap_pi
from fwsim.messages import AutopilotCommand, FlightSoftwareStatus, GimbalCommand, Measurements

_TOO_CLOSE = "target closer than min_range_m"  # a gate the max_skipped_in_a_row escape does not lift
GIMBAL_ANGLE_GAIN_1_S = 3.0  # scripted gimbal angles: joint rate per rad of encoder error


class ReacquireConfig(BaseModel):
    """What the gimbal does when the target is lost after the lock (predictive pointing)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    after_s: float = Field(0.7, ge=0, le=60, description="no detection this long: point at the estimate instead")
    search_after_s: float = Field(20.0, gt=0, le=3600,
                                  description="no detection this long: restart the raster search")
    gain_1_s: float = Field(4.0, gt=0, le=50, description="joint rate per rad of pointing error")


class DetectionGateConfig(BaseModel):
    """Which detections the UKF does not use: those a known cause has cut short (the box then lies)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    box_size_tolerance: float = Field(
        0.1, ge=0, le=10,
        description="skip a detection whose box width or height differs from the one the ship model predicts "
                    "(for the course, or for every heading the box shapes allow) by more than this fraction plus "
                    "box_size_tolerance_px: part of the ship is "
                    "hidden (e.g. by the UAV's own airframe) or the box is wrong; a large value: never")
    box_size_tolerance_px: float = Field(6.0, ge=0, le=1000, description="see box_size_tolerance, px")
    skip_overflowing_box: bool = Field(
        True, description="skip a detection whose box spans the whole image width or height (the ship is "
                          "larger than the frame: the box centre says little)")
    edge_px: float = Field(6.0, ge=0, le=100, description="a box edge this close to the image border touches it")
    min_range_m: float = Field(
        120.0, ge=0, le=10000,
        description="skip detections while the estimated range to the target is below this: close in the box "
                    "centre no longer follows the ship model (perspective, parts of the ship out of the image) "
                    "and the estimate coasts on its velocity; 0: never")
    max_skipped_in_a_row: int = Field(
        30, ge=1, le=100000, description="after this many skipped detections in a row the next one is used anyway "
                                         "(the estimate the checks rely on may be what is wrong)")


class SwitchConfig(BaseModel):
    """The Phase 2 -> 3 (loiter -> terminal) switch; the paper gives it only loosely."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    enabled: bool = Field(True, description="false: loiter until the run ends")
    radius_tol_m: float = Field(25.0, gt=0, le=1000, description="|distance to the estimate - R| below this")
    altitude_tol_m: float = Field(15.0, gt=0, le=1000, description="|altitude - H| below this")
    dwell_s: float = Field(10.0, ge=0, le=3600, description="both tolerances held this long (counted from Phase "
                                                             "2's start on, alongside min_loiter_s)")
    min_loiter_s: float = Field(20.0, ge=0, le=3600, description="no switch before this long in Phase 2")
    approach_window_deg: float | None = Field(
        5.0, gt=0, le=180,
        description="bearing from the UAV to the target within this of the impact heading plus the lead "
                    "(none: any bearing)")
    approach_lead_deg: float = Field(
        5.0, ge=-90, le=90,
        description="the window's centre lies this far past the impact heading in the direction the UAV goes "
                    "round the target: the middle of the terminal law's capture region from a loiter, which "
                    "reaches from 10 deg before to 20 deg past (controllers/bpng.py)")


@dataclass(frozen=True, slots=True)
class NmpcStatus:
    """One NMPC solve, for the log (the horizon's positions decimated to every 5th step)."""

    t_s: float
    status: str
    solve_ms: float
    iterations: int
    fallback: bool
    cost: float
    cbf_active: bool
    min_h_rad: float
    u0: np.ndarray  # (3,) V_U, u_p, u_q applied
    predicted_xyz_m: np.ndarray  # flattened (k, 3) predicted positions


@dataclass(frozen=True, slots=True)
class ShipHeadingStatus:
    """The ship's heading as the box shapes tell it (controllers.target_model.ShapeHeading), for the log."""

    t_s: float
    best_heading_deg: float  # the most likely heading, clockwise from North (the scenario's convention)
    best_weight: float  # its posterior weight (of all candidate headings)
    reverse_weight: float  # the weight of the opposite heading (bow and stern swapped)
    updates: int  # detections used so far
    in_use: bool  # it alone gives the heading (course unknown, shapes ready); with a course the two are fused
    course_deg: float  # the course from the estimated velocity when known (clockwise from North), else NaN


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
        self._nav = Navigation(controllers_cfg.navigation)
        path = controllers_cfg.initial_path
        self._path = PathFollower(path.airspeed_m_s, initial_cfg.pos_enu_m, math.radians(initial_cfg.heading_deg),
                                  path.waypoints_enu_m, path.max_bank_deg)
        o = controllers_cfg.orbit
        self._orbit = OrbitFollower(o.airspeed_m_s, o.radius_m, o.altitude_m, o.clockwise, path.max_bank_deg)
        self._nmpc = Nmpc(controllers_cfg.nmpc) if controllers_cfg.after_lock == "nmpc" else None
        self._nmpc_cmd = None
        self._nmpc_next_t = -math.inf
        self._bpng = Bpng(controllers_cfg.bpng)
        self._last_det_t = math.nan
        self._last_est = None  # (t_s, pos, vel) of the last UKF estimate
        self._lost_reported = False
        self.phase = 1
        self._phase2_t = math.nan
        self._in_tol_since = math.nan
        self.camera = PinholeCamera.from_config(camera_cfg)
        self._search = GimbalSearch(controllers_cfg.acquisition)
        self._ukf = UkfTargetEstimator(self.camera, controllers_cfg.ukf)
        self._outline = ShipOutline(controllers_cfg.target_model)
        self._shape = ShapeHeading(controllers_cfg.target_model.heading_from_shape, self._outline, self.camera,
                                   controllers_cfg.detection_gate.edge_px)
        self.gated: dict[str, int] = {}  # detections the UKF did not use, by reason
        self._gated_in_a_row = 0
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

    def _target(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Target position and velocity: the UKF's, or (while it is down) the last estimate extrapolated."""
        if self._ukf.initialised:
            return np.asarray(self._ukf.pos_enu_m, float), np.asarray(self._ukf.vel_enu_m_s, float)
        t0, pos, vel = self._last_est
        return pos + vel * (t_s - t0), vel

    def _point_at_estimate(self, meas: Measurements, motion: CameraMotion) -> GimbalCommand:
        """Drive the joints toward the direction of the estimated target (atan2 gives the pan
        within [-pi, pi], so the joint swings the long way round instead of pushing a stop)."""
        R_ef = dcm_enu_from_frd(meas.euler_ned_rad)
        pan_sp, tilt_sp = pan_tilt_pointing_at(R_ef.T @ (self._target(meas.t_s)[0] - motion.pos_enu_m))
        lim = self.cfg.ibvs
        tilt_sp = min(max(tilt_sp, lim.tilt_limits_rad[0]), lim.tilt_limits_rad[1])
        k = self.cfg.reacquire.gain_1_s
        e_pan = pan_sp - meas.pan_rad  # not wrapped: the joint cannot pass its stops
        return GimbalCommand(meas.t_s, k * e_pan, k * (tilt_sp - meas.tilt_rad))

    def _loiter_radius_altitude(self) -> tuple[float, float]:
        if self.cfg.after_lock == "nmpc":
            return self.cfg.nmpc.radius_m, self.cfg.nmpc.altitude_m
        return self.cfg.orbit.radius_m, self.cfg.orbit.altitude_m

    def _radial_error(self, meas: Measurements) -> float:
        rel = meas.pos_enu_m[:2] - self._target(meas.t_s)[0][:2]
        return float(np.hypot(rel[0], rel[1])) - self._loiter_radius_altitude()[0]

    def _switch_reason(self, meas: Measurements) -> str:
        """Why Phase 3 starts now, or "" while the switch condition does not hold."""
        sw = self.cfg.switch
        if not sw.enabled:
            return ""
        R, H = self._loiter_radius_altitude()
        radial = self._radial_error(meas)
        alt_err = float(meas.height_above_sea_m) - H
        if abs(radial) > sw.radius_tol_m or abs(alt_err) > sw.altitude_tol_m:
            self._in_tol_since = math.nan
            return ""
        if math.isnan(self._in_tol_since):
            self._in_tol_since = meas.t_s
        # the dwell and the minimum loiter run side by side (the dwell may start before min_loiter_s is up)
        if meas.t_s - self._in_tol_since < sw.dwell_s or meas.t_s - self._phase2_t < sw.min_loiter_s:
            return ""
        target, target_vel = self._target(meas.t_s)
        rel = target[:2] - meas.pos_enu_m[:2]
        bearing = math.degrees(math.atan2(rel[0], rel[1]))  # clockwise from North
        off = (bearing - self.cfg.bpng.impact_heading_deg + 180.0) % 360.0 - 180.0
        rel_vel = np.asarray(meas.vel_enu_m_s, float)[:2] - target_vel[:2]
        clockwise = float(rel[0] * rel_vel[1] - rel[1] * rel_vel[0]) > 0.0  # the bearing grows
        lead = sw.approach_lead_deg if clockwise else -sw.approach_lead_deg
        if sw.approach_window_deg is not None and abs(off - lead) > sw.approach_window_deg:
            return ""
        return (f"radius error {radial:+.1f} m (tol {sw.radius_tol_m:g}), altitude error {alt_err:+.1f} m "
                f"(tol {sw.altitude_tol_m:g}) for {meas.t_s - self._in_tol_since:.1f} s; bearing to target "
                f"{bearing % 360:.1f} deg, {off:+.1f} deg from the impact heading "
                f"({'clockwise' if clockwise else 'counter-clockwise'} round the target, lead {lead:+g} deg)")

    def _course(self, vel_enu, vel_std_m_s: float = 0.0) -> float | None:
        """The ship's course (bow direction, counter-clockwise from East) from its estimated velocity, or None
        when it is unknown: slower than ``min_speed_for_course_m_s`` or less sure than
        ``max_vel_std_for_course_m_s`` (controllers.target_model), or off the ship's axis as the box shapes
        tell it (a ship moves along its axis: such a velocity is the estimate's error)."""
        tm = self.cfg.target_model
        if math.hypot(float(vel_enu[0]), float(vel_enu[1])) < tm.min_speed_for_course_m_s \
                or vel_std_m_s > tm.max_vel_std_for_course_m_s:
            return None
        course = math.atan2(float(vel_enu[1]), float(vel_enu[0]))
        if self._shape.ready and \
                self._shape.off_axis_rad(course) > math.radians(tm.heading_from_shape.max_course_off_axis_deg):
            return None
        return course

    def _headings(self, vel_enu, vel_std_m_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """The ship's possible headings (bow direction, counter-clockwise from East) and their weights, from
        its estimated velocity (std ``vel_std_m_s``) and the box shapes (:class:`ShapeHeading`):

        * course known (:meth:`_course`) and shapes ready: the shapes' posterior times the course's
          likelihood (a ship's bow points along its course; the course's std is the velocity's over the
          speed, at least ``fuse_min_course_std_deg``), so each sharpens the other;
        * course known, shapes not ready: the course alone;
        * course unknown: the headings the shapes allow, else ``headings_when_unknown`` equal ones.
        """
        course = self._course(vel_enu, vel_std_m_s)
        sh = self.cfg.target_model.heading_from_shape
        if course is not None:
            if not (self._shape.ready and sh.fuse_with_course):
                return np.array([course]), np.ones(1)
            speed = max(math.hypot(float(vel_enu[0]), float(vel_enu[1])), 1e-6)  # min_speed_for_course may be 0
            sig = max(vel_std_m_s / speed, math.radians(sh.fuse_min_course_std_deg))
            d = (self._shape.courses_enu_rad - course + math.pi) % (2.0 * math.pi) - math.pi
            w = self._shape.weights() * np.exp(-0.5 * (d / sig) ** 2)
            if not np.sum(w) > 0.0:
                return np.array([course]), np.ones(1)
            keep = w >= sh.min_weight * np.max(w)
            return self._shape.courses_enu_rad[keep], w[keep] / np.sum(w[keep])
        shaped = self._shape.headings()
        if shaped is not None:
            return shaped
        n = self.cfg.target_model.headings_when_unknown
        return 2.0 * math.pi * np.arange(n) / n, np.full(n, 1.0 / n)

    def _contact_aim(self, meas: Measurements, target: np.ndarray, target_vel: np.ndarray) -> np.ndarray | None:
        """Where the approach through the aim point along the impact direction (relative to the moving ship)
        first meets the ship's outline, ``contact_standoff_m`` farther out; None: steer to the aim point.

        The ship's heading comes from the estimated course; when the course is unknown the deepest entry
        over the headings the box shapes allow (or, before they tell, ``headings_when_unknown`` headings) is
        taken (the steering point then lies in the air at worst, and the last metres are flown in the
        endgame, along V_f)."""
        b = self.cfg.bpng
        if not b.aim_at_contact:
            return None
        aim = self._bpng.aim_point(target)
        speed = max(float(np.linalg.norm(meas.vel_enu_m_s)), 1.0)
        d = speed * self._bpng.v_f_enu - np.asarray(target_vel, float)  # impact velocity relative to the ship
        d = d / max(float(np.linalg.norm(d)), 1e-9)
        depth = 0.0
        for c in self._headings(target_vel)[0]:
            cs, sn = math.cos(c), math.sin(c)
            R_se = np.array([[cs, sn, 0.0], [-sn, cs, 0.0], [0.0, 0.0, 1.0]])  # ENU -> ship (x bow, y port)
            depth = max(depth, self._outline.entry_depth_m(R_se @ (aim - target), R_se @ d))
        return aim - (depth + b.contact_standoff_m) * d

    def _initialise(self, meas: Measurements, motion: CameraMotion) -> str:
        """Start the UKF from this detection; '' when it did, else why not (e.g. the ray misses the sea)."""
        try:
            self._ukf.initialise(meas, motion)
        except ValueError as exc:
            return str(exc)
        return ""

    def _too_close_to_restart(self, meas: Measurements) -> bool:
        """After a reset, the last estimate (extrapolated) is nearer than the detection gate's min_range_m:
        a restart would take the close-in detections the gate distrusts, so it keeps extrapolating."""
        g = self.cfg.detection_gate
        if g.min_range_m <= 0.0 or self._last_est is None:
            return False
        return float(np.linalg.norm(self._target(meas.t_s)[0] - meas.pos_enu_m)) < g.min_range_m

    def _gate(self, meas: Measurements) -> str:
        """Why the UKF should not use this detection ('' to use it); see :class:`DetectionGateConfig`."""
        g = self.cfg.detection_gate
        if g.min_range_m > 0.0 and self._ukf.initialised and np.all(np.isfinite(meas.cam_pos_enu_m)):
            if float(np.linalg.norm(np.asarray(self._ukf.pos_enu_m, float) - meas.cam_pos_enu_m)) < g.min_range_m:
                return _TOO_CLOSE
        b = np.asarray(meas.det_bbox_px, dtype=float)
        cam = self.camera
        e = g.edge_px
        if g.skip_overflowing_box and np.all(np.isfinite(b)) and cam.width_px > 0 and (
                (b[0] <= e and b[2] >= cam.width_px - 1.0 - e) or (b[1] <= e and b[3] >= cam.height_px - 1.0 - e)):
            return "box spans the image"
        return ""

    def _vel_std(self) -> float:
        """The UKF's horizontal velocity std (the larger axis), m/s."""
        return math.sqrt(max(float(np.max(np.diag(self._ukf.pos_vel_cov)[3:5])), 0.0))

    def _shape_update(self, meas: Measurements, motion: CameraMotion, logs: dict) -> None:
        """Feed the detected box to the ship-heading-from-shape estimator; log its state when it took it."""
        pos = self._ukf.pos_enu_m
        ref = np.array([pos[0], pos[1], pos[2] - self.cfg.ukf.target_plane_height_m])
        if not self._shape.update(meas.t_s, motion.pos_enu_m, motion.R_enu_from_cam, ref, meas.det_bbox_px):
            return
        w = self._shape.weights()
        k = int(np.argmax(w))
        std = self._vel_std()
        course = self._course(self._ukf.vel_enu_m_s, std)
        logs["/fsw/ship_heading"] = ShipHeadingStatus(
            meas.t_s, (90.0 - math.degrees(float(self._shape.courses_enu_rad[k]))) % 360.0, float(w[k]),
            float(w[(k + len(w) // 2) % len(w)]), self._shape.updates,
            bool(course is None and self._shape.ready),
            math.nan if course is None else (90.0 - math.degrees(course)) % 360.0)

    def _debiased(self, meas: Measurements, motion: CameraMotion) -> tuple[Measurements, str]:
        """The detection with the ship's box-centre offset removed (controllers.target_model), so that it
        is the image of the point the UKF tracks; unchanged when the model is off or does not apply.
        Second item: why not to use it ('' to use it) when its box disagrees with the model's."""
        tm = self.cfg.target_model
        if not tm.enabled:
            return meas, ""
        pos, vel = self._ukf.pos_enu_m, self._ukf.vel_enu_m_s
        std = self._vel_std()
        course = self._course(vel, std)
        h = self.cfg.ukf.target_plane_height_m
        ref = np.array([pos[0], pos[1], pos[2] - h])
        g = self.cfg.detection_gate
        b = np.asarray(meas.det_bbox_px, dtype=float)
        courses, weights = self._headings(vel, std)
        single = len(courses) == 1
        boxes = None
        if (course is not None or self._shape.ready) and np.all(np.isfinite(b)):
            boxes = predicted_boxes_px(self._outline, self.camera, motion.pos_enu_m, motion.R_enu_from_cam, ref,
                                       courses)
            if not np.all(np.isfinite(boxes)):
                boxes = None
            else:
                pred = np.stack([boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]], axis=1)
                det = np.array([b[2] - b[0], b[3] - b[1]])
                off = np.abs(det[None, :] - pred) > g.box_size_tolerance * pred + g.box_size_tolerance_px
                if np.all(np.any(off, axis=1)):  # no heading the ship may have explains this box
                    return meas, f"box {'width' if off[int(np.argmax(weights)), 0] else 'height'} off the model's"
        off = box_centre_offset_px(self._outline, self.camera, motion.pos_enu_m, motion.R_enu_from_cam, ref,
                                   float(courses[0]) if single else None, h, tm.headings_when_unknown,
                                   boxes_px=boxes,
                                   courses_weights=None if single else (courses, weights))
        if off is None:
            return meas, ""
        return dataclasses.replace(meas, det_u_px=float(meas.det_u_px) - float(off[0]),
                                   det_v_px=float(meas.det_v_px) - float(off[1])), ""

    def step(self, meas: Measurements) -> FlightSoftwareOutput:
        if self.kind == "script":
            return self._scripted(meas)
        meas = self._nav.step(meas)  # the UAV's position between GNSS fixes
        events = []
        logs = {}
        motion = CameraMotion.from_measurements(meas, self.mount) if math.isfinite(meas.pan_rad) else None
        # Phase 1 acquisition: lock, then start the estimator
        if self._search.observe(meas) and motion is not None:
            why = self._initialise(meas, motion)
            events.append(f"target locked after {self._search.cfg.lock_detections} detections; "
                          + ("UKF initialised" if not why else f"UKF not initialised yet ({why})"))
        elif self._ukf.initialised and motion is not None:
            self._ukf.predict(meas.t_s, motion)
            if meas.det_new and meas.det_valid:
                gate = self._gate(meas)
                if gate != _TOO_CLOSE:
                    self._shape_update(meas, motion, logs)
                used, why = self._debiased(meas, motion)
                why = gate or why
                if why and (why == _TOO_CLOSE or self._gated_in_a_row < self.cfg.detection_gate.max_skipped_in_a_row):
                    self.gated[why] = self.gated.get(why, 0) + 1
                    self._gated_in_a_row += 1
                else:
                    self._gated_in_a_row = 0
                    self._ukf.update(used, motion)
            if not self._ukf.initialised:
                events.append(f"UKF reset itself at t = {meas.t_s:.2f} s (non-finite prediction: the target left "
                              "the camera's front half-space); extrapolating the last estimate")
        elif self._search.locked and motion is not None and meas.det_new and meas.det_valid \
                and not self._too_close_to_restart(meas) and not self._initialise(meas, motion):
            events.append(f"UKF re-initialised from a detection at t = {meas.t_s:.2f} s")
        if self._ukf.initialised:
            est = self._ukf.estimate()
            self._last_est = (meas.t_s, np.array(est.pos_enu_m, float), np.array(est.vel_enu_m_s, float))
            logs["/fsw/estimate"] = est
        # gimbal: search until lock, IBVS after; predictive pointing at the estimate when the target is lost
        if meas.det_new and meas.det_valid:
            self._last_det_t = meas.t_s
        locked = self._search.locked
        lost_s = meas.t_s - self._last_det_t if locked else 0.0
        rq = self.cfg.reacquire
        if not locked or motion is None:
            gimbal = self._search.step(meas)
        elif lost_s > rq.search_after_s:
            gimbal = self._search.step(meas)
        elif lost_s > rq.after_s and self._last_est is not None:
            gimbal = self._point_at_estimate(meas, motion)
        else:
            vel = self._ukf.vel_enu_m_s if self._ukf.initialised else None
            gimbal, ibvs_status = self._ibvs.step(meas, vel, self._depth(meas, motion), self.mount)
            logs["/fsw/ibvs"] = ibvs_status
        if locked and lost_s > rq.after_s and self._lost_reported is False:
            events.append(f"target lost at t = {meas.t_s:.2f} s (no detection for {lost_s:.1f} s): "
                          "pointing at the estimate")
            self._lost_reported = True
        elif lost_s <= rq.after_s:
            self._lost_reported = False
        # phase switches
        if locked and self.phase == 1 and self.cfg.after_lock != "path" and self._last_est is not None:
            self.phase, self._phase2_t = 2, meas.t_s
            events.append(f"phase 1 -> 2 at t = {meas.t_s:.2f} s: target locked, loiter ({self.cfg.after_lock})")
        if self.phase == 2:
            why = self._switch_reason(meas)
            if why:
                self.phase = 3
                events.append(f"phase 2 -> 3 at t = {meas.t_s:.2f} s: {why}")
        # the UAV
        if self.phase == 3:
            target, target_vel = self._target(meas.t_s)
            target = target.copy()
            target[2] = 0.0  # the estimate's plane height is a camera-model detail; BPNG adds its aim height
            cmd, bstat = self._bpng.step(meas.t_s, meas.pos_enu_m, meas.vel_enu_m_s, target, target_vel,
                                         self._contact_aim(meas, target, target_vel))
            logs["/fsw/bpng"] = bstat
            status = FlightSoftwareStatus(meas.t_s, 3, "terminal", "accel", locked=True, lock_t_s=self._search.lock_t_s,
                                          radial_err_m=self._radial_error(meas))
        elif self.phase == 2 and self._nmpc is not None:
            if meas.t_s + 1e-9 >= self._nmpc_next_t:
                pos, vel = self._target(meas.t_s)
                res = self._nmpc.solve(meas.t_s, self._nmpc.state_from_measurements(meas), pos, vel)
                self._nmpc_cmd = self._nmpc.command(res)
                self._nmpc_next_t = meas.t_s + self.cfg.nmpc.step_s
                logs["/fsw/nmpc"] = NmpcStatus(meas.t_s, res.status, res.solve_ms, res.iterations, res.fallback,
                                               res.cost, res.cbf_active, res.min_h, np.asarray(res.u0, float),
                                               np.asarray(res.predicted[::5, :3], float).ravel())
                if res.fallback:
                    events.append(f"NMPC fallback at t = {meas.t_s:.2f} s: {res.status}")
            cmd = type(self._nmpc_cmd)(meas.t_s, self._nmpc_cmd.airspeed_m_s, self._nmpc_cmd.roll_rate_rad_s,
                                       self._nmpc_cmd.pitch_rate_rad_s)
            status = FlightSoftwareStatus(meas.t_s, 2, "loiter:nmpc", "rates", altitude_sp_m=self.cfg.nmpc.altitude_m,
                                          locked=True, lock_t_s=self._search.lock_t_s,
                                          radial_err_m=self._radial_error(meas))
        elif self.phase == 2:
            cmd, chi_c, radial = self._orbit.step(meas, self._target(meas.t_s)[0])
            status = FlightSoftwareStatus(meas.t_s, 2, "loiter:orbit", "rates", course_sp_rad=chi_c,
                                          altitude_sp_m=self._orbit.altitude_m, locked=True,
                                          lock_t_s=self._search.lock_t_s, radial_err_m=radial)
        else:
            cmd, st = self._path.step(meas)
            status = FlightSoftwareStatus(meas.t_s, 1, "acquisition:" + ("path" if locked else "search"), "rates",
                                          course_sp_rad=st.course_sp_rad, bank_sp_rad=st.bank_sp_rad,
                                          altitude_sp_m=st.altitude_sp_m, cross_track_m=st.cross_track_m,
                                          locked=locked, lock_t_s=self._search.lock_t_s)
        return FlightSoftwareOutput(cmd, gimbal, status, logs, tuple(events))
