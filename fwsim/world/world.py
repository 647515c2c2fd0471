"""The truth world: JSBSim airframe, ship target, pan-tilt gimbal and camera.

``World.step`` advances everything by one tick; ``World.look`` takes one
camera frame (the geometric truth of what the camera sees). Only the harness
uses this module; the flight software sees its ``Measurements``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fwsim.world.airframe import Airframe
from fwsim.sensors.camera import Camera, FrameGeometry, Pose
from fwsim.interface.frames import GeoOrigin, dcm_enu_from_frd
from fwsim.world.geometry import uav_mesh
from fwsim.world.gimbal import Gimbal, GimbalState, camera_pose_world
from fwsim.interface.messages import ActuatorCommand, AirframeState, AirState, GimbalCommand
from fwsim.scenario.model import Scenario
from fwsim.sensors.onboard import rng_for
from fwsim.world.target import HullVolume, Ship, TargetState, r_enu_from_ship

#: the UAV farther than this from the ship's origin cannot be inside it (uav_inside_ship's quick test)
_NEAR_SHIP_M = 60.0


@dataclass(slots=True)
class Truth:
    """Everything true at one tick (harness side only).

    The camera pose is computed on first use: most ticks (120 Hz) never need it.
    """

    uav: AirframeState
    target: TargetState
    gimbal: GimbalState
    mount_offset_frd_m: np.ndarray
    #: the camera as built against the nominal one (R_nominal_from_actual: a boresight misalignment); None: none
    R_nominal_from_actual: np.ndarray | None = None
    _cam: tuple | None = None

    def _camera(self) -> tuple:
        if self._cam is None:
            pos, R = camera_pose_world(self.uav.pos_enu_m, self.uav.euler_ned_rad, self.mount_offset_frd_m,
                                       self.gimbal.pan_rad, self.gimbal.tilt_rad)
            if self.R_nominal_from_actual is not None:
                R = R @ self.R_nominal_from_actual
            self._cam = (pos, R)
        return self._cam

    @property
    def cam_pos_enu_m(self) -> np.ndarray:
        return self._camera()[0]

    @property
    def R_enu_from_cam(self) -> np.ndarray:
        return self._camera()[1]


class World:
    def __init__(self, scenario: Scenario, mount_error=None):
        """``mount_error``: the camera's boresight and focal length as built
        (:class:`fwsim.sensors.errors.CameraMountError`; None: as designed)."""
        self.scenario = scenario
        dt = 1.0 / scenario.rates.sim_hz
        self.dt_s = dt
        w = scenario.world
        self.airframe = Airframe(scenario.aircraft.name, dt_s=dt, origin=GeoOrigin(w.origin_lat_deg, w.origin_lon_deg),
                                 wind_enu_m_s=w.wind_enu_m_s)
        self.ship = Ship(scenario.target)
        self.gimbal = Gimbal(scenario.camera.gimbal, dt)
        self.camera = Camera(scenario.camera, uav_mesh(scenario.aircraft.name), self.ship.mesh,
                             focal_scale=1.0 if mount_error is None else mount_error.focal_scale)
        self._R_mount = None if mount_error is None else mount_error.dcm_nominal_from_actual()
        self._mount = np.asarray(scenario.camera.gimbal.mount_offset_frd_m, dtype=float)
        self._hull = HullVolume(scenario.target)
        self.truth: Truth | None = None

    def _compose(self, uav: AirframeState, g: GimbalState) -> Truth:
        self.truth = Truth(uav, self.ship.state(uav.t_s), g, self._mount, self._R_mount)
        return self.truth

    def reset(self) -> Truth:
        ini = self.scenario.initial
        uav = self.airframe.reset(ini.pos_enu_m, ini.airspeed_m_s, math.radians(ini.heading_deg),
                                  math.radians(ini.flight_path_deg), trim=ini.trim)
        turb = self.scenario.world.turbulence
        if turb is not None:  # after the trim, which wants still air; its own stream, from the scenario's seed
            seed = int(rng_for(self.scenario.seed, "turbulence").integers(1, 2**31 - 1))
            self.airframe.set_turbulence(*turb.jsbsim_settings(), seed=seed)
        return self._compose(uav, self.gimbal.reset())

    def manoeuvre_ship(self, t_s: float, ev) -> float:
        """Start a target_manoeuvre event (fwsim.world.events) at ``t_s``; how long it takes."""
        return self.ship.manoeuvre(t_s, ev.course_deg, ev.speed_m_s, ev.turn_rate_deg_s, ev.accel_m_s2)

    @property
    def disturbed(self) -> bool:
        """The air moves other than the steady wind (turbulence or gusts): the log then has /world/air."""
        return self.scenario.world.turbulence is not None or any(
            ev.kind == "wind_gust" for ev in self.scenario.events)

    def air(self) -> AirState:
        """The air at the UAV now (truth)."""
        wind, turb = self.airframe.air()
        return AirState(self.truth.uav.t_s, wind, turb)

    def step(self, act: ActuatorCommand, gimbal_cmd: GimbalCommand) -> Truth:
        uav = self.airframe.step(act)
        g = self.gimbal.step(uav.t_s, gimbal_cmd.pan_rate_rad_s, gimbal_cmd.tilt_rate_rad_s)
        return self._compose(uav, g)

    def uav_inside_ship(self) -> bool:
        """True once the UAV's centre of gravity is inside the ship's hull or superstructure."""
        tr = self.truth
        ux, uy, _ = tr.uav.pos_enu_m.tolist()
        sx, sy, _ = tr.target.pos_enu_m.tolist()  # the ship's state of this tick, already computed
        if abs(ux - sx) > _NEAR_SHIP_M or abs(uy - sy) > _NEAR_SHIP_M:  # then rel @ rel is above its square too
            return False
        rel = tr.uav.pos_enu_m - tr.target.pos_enu_m
        if rel @ rel > _NEAR_SHIP_M ** 2:  # far from the ship: skip the exact test
            return False
        return self._hull.contains(r_enu_from_ship(tr.target.heading_ned_rad).T @ rel)

    def poses(self) -> tuple[Pose, Pose]:
        """Current poses of the UAV (body FRD) and the ship (ship frame) in the world."""
        tr = self.truth
        uav = Pose(dcm_enu_from_frd(tr.uav.euler_ned_rad), tr.uav.pos_enu_m)
        ship = tr.target  # Ship.pose of this tick, from the state already computed
        return uav, Pose(r_enu_from_ship(ship.heading_ned_rad), ship.pos_enu_m)

    def look(self) -> FrameGeometry:
        """One camera frame: what the camera sees of the ship right now."""
        uav, ship = self.poses()
        return self.camera.detect(self.truth.uav.t_s, self.truth.cam_pos_enu_m, self.truth.R_enu_from_cam, uav, ship)

    def render(self, bbox_px=None) -> np.ndarray:
        uav, ship = self.poses()
        return self.camera.render(self.truth.cam_pos_enu_m, self.truth.R_enu_from_cam, uav, ship, bbox_px)
