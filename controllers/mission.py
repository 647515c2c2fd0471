"""The flight software: ``Measurements`` in, autopilot and gimbal commands out, as the paper's block diagram.

    nav    = navigation.step(meas)              own position between GNSS fixes        (navigation.nav)
    cam    = camera_motion(nav, mount)          camera pose from attitude + encoders   (navigation.camera_model)
    prior  = estimation.predict(nav, cam)       the target estimate brought to now     (estimation.estimation)
    fix    = perception.step(nav, cam, prior)   detection -> corrected fix + decision  (perception.perception)
    est    = estimation.update(nav, cam, fix)   fuse it (start, restart)               (estimation.estimation)
    phase  = next_phase(phase, nav, est, ...)   pure decision, reason logged           (phases.phases)
    guide  = guidance[phase].step(nav, est)     path | loiter (orbit, NMPC) | BPNG     (guidance.guidance)
    gimbal = pointing.step(nav, cam, est, fix)  search | track (IBVS) | reacquire      (pointing.pointing)

Phases (paper, "Simulation"): 1 acquisition (the initial path while the gimbal
searches; the lock starts the estimator and IBVS takes the gimbal), 2 loiter
round the estimated ship (``after_lock``), 3 terminal guidance to the impact
angles once the switch condition holds (``controllers.phases.phases``). The
estimator, the Phase 2 and Phase 3 guidance and the pointing law are each a
built-in block or a user's class named in the scenario (``controllers.blocks``); a user's class is
guarded at its boundary (``controllers.blocks.guarded``): an exception in it, or a return value of the
wrong type, ends the run with a line naming the block, the method and the user's file:line.
Every block writes what it decided to the log through the tick's recorder;
``FlightSoftwareOutput`` carries it to the harness. A scripted command list can
stand in for the mission (``kind: script``).

Nothing here imports the truth side of the harness (docs/design/architecture.md, "Two rules").
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from controllers.blocks import NO_LOITER, BlockContext, Recorder, build_block
from controllers.config import Controllers
from controllers.estimation.estimation import Estimation
from controllers.guidance.guidance import PathGuidance
from controllers.guidance.script import ScriptedCommands
from controllers.messages import DetectionFix, Guidance, TargetState
from controllers.navigation.camera_model import PinholeCamera, camera_motion
from controllers.navigation.nav import Navigation
from controllers.perception.airframe import AirframeShadow
from controllers.perception.perception import Perception
from controllers.perception.target_model import ShipModel
from controllers.phases.phases import PhaseState, Ring, entry_altitude_m, next_phase, radial_error_m, window_bearing_deg
from controllers.pointing.pointing import Pointing
from controllers.pointing.search import GimbalSearch
from fwsim.interface.messages import AutopilotCommand, FlightSoftwareStatus, GimbalCommand, Measurements

__all__ = ["FlightSoftware", "FlightSoftwareOutput", "ScriptedFlightSoftware", "flight_software"]

_NO_RING = Ring(math.nan, math.nan)  # Phase 1's (no loiter yet)


@dataclass(frozen=True, slots=True)
class FlightSoftwareOutput:
    command: AutopilotCommand
    gimbal: GimbalCommand
    status: FlightSoftwareStatus
    logs: tuple = ()  # (topic, message) pairs, for the log only
    events: tuple = ()  # text lines for the log's /events (phase switches, lock, ...)


class FlightSoftware:
    """The mission: one object at the boundary, a pipeline of blocks inside (see the module text)."""

    def __init__(self, cfg: Controllers, initial_cfg, camera_cfg, search_dirs=()):
        self.cfg = cfg
        self.mount = np.asarray(camera_cfg.gimbal.mount_offset_frd_m, dtype=float)
        camera = PinholeCamera.from_config(camera_cfg)
        self.recorder = Recorder()
        ship = ShipModel(cfg.target_model, camera, cfg.detection_gate.edge_px)
        ctx = BlockContext(cfg, camera, self.mount, ship, self.recorder, initial_cfg)
        self.navigation = Navigation(cfg.navigation)
        airframe = AirframeShadow(cfg.airframe, camera, self.mount) if cfg.airframe.enabled else None
        self.perception = Perception(cfg.detection_gate, cfg.acquisition, ship, camera, self.recorder, airframe)
        self.estimation = Estimation(build_block("estimator", cfg.estimator, ctx, search_dirs),
                                     cfg.detection_gate.min_range_m, cfg.acquisition.lock_detections, self.recorder,
                                     cfg.turn_from_course)
        loiter = None if cfg.after_lock.use == NO_LOITER else \
            build_block("after_lock", cfg.after_lock, ctx, search_dirs)
        self.guidance = {1: PathGuidance(cfg.initial_path, initial_cfg), 2: loiter,
                         3: build_block("terminal", cfg.terminal, ctx, search_dirs)}
        self.ring = None if loiter is None else Ring(float(loiter.radius_m), float(loiter.altitude_m))
        # (a loiter that cannot fly below its ring is a scenario error: Controllers._entry_ring)
        self.entry_altitude_m = entry_altitude_m(self.ring, cfg.switch, cfg.bpng.impact_flight_path_deg)
        law = build_block("pointing", cfg.pointing, ctx, search_dirs)
        self.pointing = Pointing(GimbalSearch(cfg.acquisition), law, cfg.reacquire, cfg.ibvs.tilt_limits_rad,
                                 self.recorder)
        self.phase = PhaseState()

    def step(self, meas: Measurements) -> FlightSoftwareOutput:
        nav = self.navigation.step(meas)                                  # own position between GNSS fixes
        cam = camera_motion(nav, self.mount)                              # camera pose from attitude + encoders
        prior = self.estimation.predict(nav, cam)                         # the target estimate brought to now
        fix = self.perception.step(nav, cam, prior)                       # detection -> corrected fix + decision
        est = self.estimation.update(nav, cam, fix)                       # fuse it (start, restart); logged
        self._next_phase(nav, est, fix)                                   # pure decision, reason logged
        guide = self.guidance[self.phase.phase].step(nav, est)            # path | loiter | terminal
        gimbal = self.pointing.step(nav, cam, est, fix)                   # search | track | reacquire
        return self._output(nav, est, fix, guide, gimbal)

    def close(self) -> None:
        """Release what the blocks hold beyond the flight (the NMPC's worker process): a block with a
        ``close()`` has it called once, at the end of the run."""
        for block in (*self.guidance.values(), self.estimation.filter, self.pointing.law):
            close = getattr(block, "close", None)
            if callable(close):
                close()

    def _next_phase(self, nav: Measurements, est: TargetState, fix: DetectionFix) -> None:
        approach = window_bearing_deg(self.phase, self.cfg.switch, self.cfg.bpng, nav.wind_enu_m_s, est)
        self.phase, events = next_phase(self.phase, nav.t_s, nav.pos_enu_m, nav.vel_enu_m_s, nav.height_above_sea_m,
                                        est, fix.locked, self.ring, self.cfg.switch, approach,
                                        self.cfg.after_lock.use, self.entry_altitude_m)
        if self.phase.descending:  # the loiter's altitude ramps down to the entry ring's
            sw = self.cfg.switch
            self.guidance[2].altitude_offset_m = min(self.ring.altitude_m - self.entry_altitude_m,
                                                     sw.entry_descent_rate_m_s * (nav.t_s - self.phase.descent_t_s))
        for e in events:
            self.recorder.event(e)
        if events and self.phase.phase == 3:
            self.perception.ship.layout.hold()  # (the airframe starts to cut the boxes)

    def _output(self, nav: Measurements, est: TargetState, fix: DetectionFix, guide: Guidance,
                gimbal: GimbalCommand) -> FlightSoftwareOutput:
        phase = self.phase.phase
        name = "acquisition:" + ("path" if fix.locked else "search") if phase == 1 else guide.name
        ring = self.ring if phase > 1 else _NO_RING
        if phase > 1 and self.phase.descending:
            ring = Ring(ring.radius_m, self.entry_altitude_m)
        radial = radial_error_m(nav.pos_enu_m, est, ring.radius_m) if phase > 1 else math.nan
        status = FlightSoftwareStatus(nav.t_s, phase, name, guide.command.mode, guide.course_sp_rad,
                                      guide.bank_sp_rad, guide.altitude_sp_m, guide.cross_track_m, fix.locked,
                                      fix.lock_t_s, radial, ring.radius_m, ring.altitude_m)
        logs, events = self.recorder.drain()
        return FlightSoftwareOutput(guide.command, gimbal, status, logs, events)


class ScriptedFlightSoftware:
    """``kind: script``: a timed list of autopilot commands and gimbal angles stands in for the mission."""

    def __init__(self, cfg: Controllers):
        self.script = ScriptedCommands(cfg.script)

    def step(self, meas: Measurements) -> FlightSoftwareOutput:
        cmd = self.script.step(meas)
        return FlightSoftwareOutput(cmd, self.script.gimbal(meas), self.script.status(meas, cmd))

    def close(self) -> None:
        pass


def flight_software(cfg: Controllers, initial_cfg, camera_cfg):
    """The flight software a scenario's ``controllers`` section asks for. A user's block class is imported as
    the scenario's validation found it (the Python path, the scenario's folder or the current folder)."""
    if cfg.kind == "script":
        return ScriptedFlightSoftware(cfg)
    return FlightSoftware(cfg, initial_cfg, camera_cfg, (Path.cwd(),))
