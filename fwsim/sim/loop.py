"""The simulation loop: ``run(scenario) -> RunResult``.

One fixed-rate loop (JSBSim + autopilot at ``rates.sim_hz``), other blocks at
their own rates, one line per block in signal order (docs/design/architecture.md, "Two rules"):

    meas  = sensors.sample(truth)         # harness: what the UAV can know
    out   = flight_software.step(meas)    # controllers/: the paper's algorithms
    act   = autopilot.actuate(cmd, truth) # inner loops (PX4 on the airframe)
    truth = airframe.step(act)            # JSBSim
    log.write(...)                        # observes, never feeds back

    frame = world.look()                  # camera at its own rate -> detector

The autopilot stands for PX4 on the aircraft and reads the airframe state as
PX4's own estimator would give it; the flight software only sees
``Measurements``.
"""
from __future__ import annotations

import math
import platform
import signal
import threading
import time
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable, Iterable

import numpy as np
import yaml

import fwsim
from controllers.mission import flight_software
from fwsim.interface import topics
from fwsim._entry import STOP_SIGNALS, Signalled
from fwsim.world.airframe import aircraft_file, aircraft_hash
from fwsim.autopilot import Autopilot, load_autopilot_params
from fwsim.sensors.camera import Detector
from fwsim.world.events import EventRunner
from fwsim.interface.frames import quat_from_dcm
from fwsim.log import LogWriter
from fwsim.log.writer import Listener
from fwsim.interface.messages import ActuatorCommand, GimbalCommand
from fwsim.sim.profiling import BlockTimer, time_flight_software, time_harness, time_onboard_navigation
from fwsim.scenario.model import Scenario, start_epoch_ns
from fwsim.sensors.onboard import Sensors, rng_for
from fwsim.world.world import World
from fwsim.scenario.yamlfile import FAST_SAFE_DUMPER


@dataclass(frozen=True)
class RunResult:
    log_path: Path
    status: str  # completed | failed | interrupted
    reason: str
    sim_time_s: float
    wall_time_s: float
    blocks: list | None = None  # fwsim.sim.profiling.BlockTime per block, with run(..., profile=BlockTimer())
    #: the log's RESULT_TOPICS as a RunLog held in memory (fwsim.analysis.metrics.terminal_metrics scores it
    #: without reading the file back)
    result_log: Any = None

    @property
    def real_time_factor(self) -> float:
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else math.inf


class RunStopped(Exception):
    """The run ended early for a reason the scenario defines (sea contact, ...)."""


class Interrupted(Signalled):
    """The run was stopped by a signal (``signum``: SIGINT for Ctrl-C, SIGTERM from a scheduler, SIGHUP from a
    closed terminal); the log is complete and says so."""


class _StopOnSigint:
    """Turns Ctrl-C (SIGINT) and SIGTERM (what a batch scheduler, a container or Ray sends) into a flag the
    loop checks once per tick, so a signal never lands in the middle of writing the log; a second one
    interrupts at once, unless the log is already being finished (``closing``: a process pool that breaks
    as its first worker stops sends SIGTERM to the others, which may be closing their logs after the
    first signal; their logs still get their footers). Main thread only."""

    _SIGNALS = STOP_SIGNALS  # SIGINT, SIGTERM and (where there is one) SIGHUP

    def __init__(self):
        self.requested = False
        self.closing = False  # the loop is finishing the log after a signal: later ones wait for it
        self.signum = signal.SIGINT
        self._previous: dict[int, object] = {}

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in self._SIGNALS:
                self._previous[sig] = signal.getsignal(sig)
                signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame):
        if self.requested and not self.closing:
            raise Interrupted(signum)
        self.requested, self.signum = True, signum

    @property
    def description(self) -> str:
        return "Ctrl-C" if self.signum == signal.SIGINT else signal.Signals(self.signum).name

    def __exit__(self, *exc):
        for sig, previous in self._previous.items():
            signal.signal(sig, previous)
        return False


def _log_render(log: LogWriter, world: World, t_s: float, frame, detection) -> None:
    """A rendered camera image, and over it (foxglove.ImageAnnotations, same time stamp) the box of the ship's
    visible pixels (truth, green) and the detector's latest box (orange), in the render's pixels."""
    cam = world.camera
    log.write_image(topics.CAMERA_IMAGE, t_s, topics.CAMERA_FRAME_ID, cam.encode_jpeg(world.render()))
    rc, full = cam.cfg.render, cam.cfg
    scale = np.array([rc.width_px / full.width_px, rc.height_px / full.height_px] * 2)
    boxes = []
    if frame is not None and np.all(np.isfinite(frame.bbox_px)):
        boxes.append((frame.bbox_px * scale, (0.0, 1.0, 0.0), "ship (truth)"))
    if detection is not None and detection.detected and np.all(np.isfinite(detection.bbox_px)):
        boxes.append((detection.bbox_px * scale, (1.0, 0.55, 0.0), f"detection t = {detection.exposure_t_s:.2f} s"))
    log.write_image_annotations(topics.CAMERA_ANNOTATIONS, t_s, boxes)


def default_log_path(scenario: Scenario, out_dir: Path) -> Path:
    stamp = datetime.now(timezone.utc).strftime("%Y%m%d-%H%M%S")
    return Path(out_dir) / f"{scenario.name}-seed{scenario.seed}-{stamp}.mcap"


def run_metadata(scenario: Scenario) -> dict[str, str]:
    import jsbsim
    return {
        "scenario": scenario.name,
        "seed": str(scenario.seed),
        "fwsim_version": fwsim.__version__,
        "jsbsim_version": jsbsim.__version__,
        "python_version": platform.python_version(),
        "aircraft": scenario.aircraft.name,
        "aircraft_file": aircraft_file(scenario.aircraft.name).relative_to(fwsim.PROJECT_ROOT).as_posix(),
        "aircraft_sha256": aircraft_hash(scenario.aircraft.name),
        "sim_hz": f"{scenario.rates.sim_hz:g}",
        "flight_software_hz": f"{scenario.rates.flight_software_hz:g}",
        "log_hz": f"{scenario.rates.log_hz:g}",
        "camera_width_px": str(scenario.camera.width_px),
        "camera_height_px": str(scenario.camera.height_px),
        "camera_hfov_deg": f"{scenario.camera.hfov_deg:g}",
    }


class _Trails:
    """The flown paths of the UAV and the ship for Foxglove's 3D panel (/scene/paths): the logged positions,
    sent as one line-strip entity per path and second, each segment starting where the last one ended."""

    EVERY_S = 1.0
    COLOURS = {"uav": (0.95, 0.35, 0.2, 1.0), "ship": (0.25, 0.55, 0.95, 1.0)}

    def __init__(self):
        self.points: dict[str, list] = {"uav": [], "ship": []}
        self.t_sent = 0.0
        self.count = 0

    def add(self, log: LogWriter, t_s: float, uav_pos, ship_pos) -> None:
        self.points["uav"].append(tuple(uav_pos.tolist()))  # (positions as arrays: Python floats)
        self.points["ship"].append(tuple(ship_pos.tolist()))
        if t_s - self.t_sent >= self.EVERY_S:
            self.flush(log, t_s)

    def flush(self, log: LogWriter, t_s: float) -> None:
        if len(self.points["uav"]) < 2:
            return
        log.write_scene_lines(topics.SCENE_PATHS, t_s, [
            (f"{name}_path_{self.count}", topics.WORLD_FRAME, pts, self.COLOURS[name], 2.0)
            for name, pts in self.points.items()])
        self.points = {name: pts[-1:] for name, pts in self.points.items()}
        self.t_sent, self.count = t_s, self.count + 1


def _log_truth(log: LogWriter, truth, origin, trails: _Trails) -> None:
    """Truth at one tick: UAV state, pose and geodetic fix (through the world's ``origin``), ship, gimbal, the
    camera and ship frames, and the paths' next points."""
    t = truth.uav.t_s
    trails.add(log, t, truth.uav.pos_enu_m, truth.target.pos_enu_m)
    log.write_state(truth.uav)
    lat, lon, alt = origin.geodetic_from_enu(truth.uav.pos_enu_m)
    log.write_location(t, topics.UAV_FRAME, math.degrees(lat), math.degrees(lon), alt)
    log.write(topics.TARGET_STATE, truth.target)
    log.write(topics.GIMBAL_STATE, truth.gimbal)
    log.write_transform(t, topics.CAMERA_FRAME_ID, truth.cam_pos_enu_m, quat_from_dcm(truth.R_enu_from_cam))
    h = truth.target.heading_ned_rad
    half = 0.5 * (math.pi / 2 - h)  # ship frame (bow, port, up) is the ENU frame turned by the course
    log.write_transform(t, topics.SHIP_FRAME_ID, truth.target.pos_enu_m, (math.cos(half), 0.0, 0.0, math.sin(half)))


#: What the one-line result of a run reads (fwsim.analysis.metrics.terminal_metrics), kept in memory as the run
#: writes them.
RESULT_TOPICS = (topics.UAV_STATE, topics.TARGET_STATE, topics.FSW_STATUS)


def run(scenario: Scenario, scenario_text: str, log_path: Path,
        progress: Callable[[float, float], None] | None = None,
        listeners: Iterable[Listener] = (), profile: BlockTimer | None = None) -> RunResult:
    """Fly a scenario; always leaves a complete MCAP log at ``log_path``.

    ``progress(sim_t_s, duration_s)`` is called about once per simulated
    second. ``listeners`` go to the LogWriter and see every record as it is
    written (e.g. :class:`fwsim.log.rerun_live.RerunLive`, the live Rerun
    view); one that raises is detached and the run goes on. Ends at
    ``duration_s``, at sea contact (``stop.min_height_m``), or on an error
    (the log records why). KeyboardInterrupt is logged as 'interrupted' and
    re-raised. ``profile``: a :class:`fwsim.sim.profiling.BlockTimer` that times
    every block (``RunResult.blocks``).
    """
    log_path = Path(log_path)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    wall0 = time.perf_counter()
    flight = None
    status, reason = "completed", "duration reached"
    epoch_ns = start_epoch_ns(scenario.start_time) if scenario.start_time else time.time_ns() // 1_000_000 * 1_000_000
    with _StopOnSigint() as sigint, LogWriter(log_path, metadata=run_metadata(scenario), epoch_ns=epoch_ns,
                                              scenario_text=scenario_text, listeners=listeners,
                                              keep=RESULT_TOPICS) as log:
        fsw = None
        effective = yaml.dump(scenario.model_dump(mode="json"), Dumper=FAST_SAFE_DUMPER, sort_keys=False)
        log.add_attachment("scenario_effective.yaml", effective.encode(), "application/yaml")
        try:
            # the flight software first: a block may start a worker process (the NMPC's) that gets ready
            # while the harness is built
            fsw = flight_software(scenario.controllers, scenario.initial, scenario.camera)
            flight = _Flight(scenario, log, fsw, profile)
            status, reason = flight.fly(sigint, progress)
        except RunStopped as exc:
            status, reason = "failed", str(exc)
        except Exception as exc:  # any other error: the log says why, the caller sees it too
            log.close("failed", f"{failure_text(exc)} (t = {flight.sim_t if flight else 0.0:.2f} s)")
            raise
        finally:
            if fsw is not None:
                fsw.close()  # e.g. the NMPC's worker process
        log.close(status, reason)
    sim_t = flight.sim_t if flight is not None else 0.0
    if progress is not None:
        progress(sim_t, scenario.duration_s)
    wall = time.perf_counter() - wall0
    blocks = profile.report(wall, sim_t) if profile is not None else None
    kept = log.kept_log()
    kept.scenario = scenario  # (what its effective_scenario_text parses back to)
    return RunResult(log_path, status, reason, sim_t, wall, blocks, kept)


def failure_text(exc: BaseException) -> str:
    """How an error that ended a run reads in the log and on the command line: a user's block says where it
    failed (:class:`controllers.blocks.PluginError`), anything else is ``Type: message``."""
    from controllers.blocks import PluginError
    return str(exc) if isinstance(exc, PluginError) else f"{type(exc).__name__}: {exc}"


class _Flight:
    """One run's harness around its flight software, built and then flown tick by tick (``run``'s body)."""

    def __init__(self, scenario: Scenario, log: LogWriter, fsw, profile: BlockTimer | None):
        self.scenario, self.log, self.fsw = scenario, log, fsw
        rates = scenario.rates
        self.fsw_every = round(rates.sim_hz / rates.flight_software_hz)
        self.log_every = round(rates.sim_hz / rates.log_hz)
        self.cam_every = round(rates.sim_hz / scenario.camera.rate_hz)
        render_hz = scenario.camera.render.rate_hz
        self.render_every = round(rates.sim_hz / render_hz) if render_hz > 0 else 0
        self.sim_t = 0.0
        # sensors.profile typical / degraded: error models and the onboard INS (ideal: the truth, white noise)
        self.nav = None
        if scenario.sensors.profile != "ideal":
            from fwsim.sim.navigation import OnboardNavigation  # (the INS's modules: only where it flies)
            self.nav = OnboardNavigation(scenario)
        self.world = world = World(scenario, mount_error=self.nav.models.camera_mount if self.nav else None)
        self.origin = world.airframe.origin
        self.truth = world.reset()
        trim = world.airframe.trim
        log.write_event(0.0, f"trim: throttle {trim.throttle_norm:.3f}, elevator {trim.elevator_norm:.3f}, "
                             f"alpha {math.degrees(trim.alpha_rad):.2f} deg")
        self.autopilot = Autopilot(load_autopilot_params(scenario.aircraft.name,
                                                         overrides=scenario.aircraft.autopilot_gains),
                                   1.0 / rates.sim_hz, trim.throttle_norm)
        self.sensors = Sensors(scenario.sensors, scenario.seed)
        cam = self.cam = scenario.camera
        self.detector = Detector(cam.detector, rng_for(scenario.seed, "detector"), cam.width_px, cam.height_px)
        if profile is not None:
            time_harness(profile, sensors=self.sensors, detector=self.detector, autopilot=self.autopilot,
                         world=world, log=log)
            time_flight_software(profile, fsw)
            if self.nav is not None:
                time_onboard_navigation(profile, self.nav)
        log.write_calibration(topics.CAMERA_CALIBRATION, 0.0, topics.CAMERA_FRAME_ID, cam.width_px, cam.height_px,
                              world.camera.K.K)
        log.write_scene_models(topics.SCENE, 0.0, [
            ("uav", topics.UAV_FRAME, world.camera.caster.uav_mesh, (0.85, 0.2, 0.2, 1.0)),
            ("ship", topics.SHIP_FRAME_ID, world.ship.mesh, (0.55, 0.6, 0.65, 1.0))])
        self.trails = _Trails()
        _log_truth(log, self.truth, self.origin, self.trails)
        self.disturbed = world.disturbed
        self.events = EventRunner(scenario.events, rng_for(scenario.seed, "events")) if scenario.events else None
        self.phase = None
        if self.disturbed:
            log.write(topics.WORLD_AIR, world.air())
        self.last_det = None
        self.frame = None
        self.out = None
        # what the actuators hold until the autopilot has a command and (with a sensor profile) the INS an estimate
        self.act = ActuatorCommand(0.0, 0.0, 0.0, 0.0, trim.throttle_norm)
        self.flown = False  # the autopilot has run (its status can be logged)

    def fly(self, sigint: _StopOnSigint, progress) -> tuple[str, str]:
        """Tick to ``duration_s`` or an end (the ship hit, sea contact); (status, reason). RunStopped when the
        scenario's limits stop it, Interrupted (the log closed) on a signal."""
        scenario, log = self.scenario, self.log
        progress_every = max(int(scenario.rates.sim_hz), 1)
        why = "duration reached"
        for tick in range(int(round(scenario.duration_s * scenario.rates.sim_hz))):
            self._step(tick)
            ended = self._ended()
            if ended:
                why = ended
                break
            if progress is not None and tick % progress_every == 0:
                progress(self.sim_t, scenario.duration_s)
            if sigint.requested:
                sigint.closing = True
                _log_truth(log, self.truth, self.origin, self.trails)
                self.trails.flush(log, self.sim_t)
                log.close("interrupted", f"interrupted ({sigint.description}) at t = {self.sim_t:.2f} s")
                raise Interrupted(sigint.signum)
        self.trails.flush(log, self.sim_t)  # the last part of the paths
        return "completed", why

    def _step(self, tick: int) -> None:
        """One tick: events, the flight software (at its rate), the autopilot, the world, camera and log."""
        events, log = self.events, self.log
        t_now = self.truth.uav.t_s
        nav = self.nav
        if events is not None:
            events.step(t_now, self.phase, log.write_event, self.world.airframe.cosine_gust,
                        self.world.manoeuvre_ship, nav.fault if nav is not None else None)
        if tick % self.fsw_every == 0:
            self._flight_software(t_now)
        out = self.out
        act = self._actuate(t_now)
        gimbal_cmd = out.gimbal if out is not None else GimbalCommand(t_now, 0.0, 0.0)
        if events is not None and events.gimbal_stuck:
            gimbal_cmd = GimbalCommand(t_now, 0.0, 0.0)
        self.truth = truth = self.world.step(act, gimbal_cmd)
        self.sim_t = truth.uav.t_s
        if nav is not None:
            self._navigate(tick, truth)
        if (tick + 1) % self.cam_every == 0:
            self._look()
        if (tick + 1) % self.log_every == 0:
            _log_truth(log, truth, self.origin, self.trails)
            if self.flown:
                log.write(topics.AUTOPILOT_STATUS, self.autopilot.status())
            log.write(topics.ACTUATORS, act)
            if self.disturbed:
                log.write(topics.WORLD_AIR, self.world.air())
        if self.render_every and (tick + 1) % self.render_every == 0:
            _log_render(log, self.world, self.sim_t, self.frame, self.last_det)

    def _actuate(self, t_now: float) -> ActuatorCommand:
        """The autopilot's loops closed on what it knows of the aircraft (the truth with the ideal profile, else
        the INS's estimate and the pitot); the actuators held while it has no command or no estimate yet."""
        out, ap = self.out, self.autopilot
        view = self.truth.uav if self.nav is None else self.nav.autopilot_view(self.act)
        if out is None or view is None:
            self.act = replace(self.act, t_s=t_now)
            return self.act
        underspeed = ap.underspeed
        self.act = act = ap.actuate(out.command, view)
        self.flown = True
        if ap.underspeed != underspeed:
            self._underspeed_event(t_now, ap.underspeed)
        return act

    def _navigate(self, tick: int, truth) -> None:
        """The sensors sampled into the INS at this tick; its events, aid sources and (at the log rate) its
        estimate logged."""
        nav, log = self.nav, self.log
        est = nav.step(truth.uav, truth.gimbal)
        t = truth.uav.t_s
        for text in nav.ins.drain_events():
            log.write_event(t, f"navigation: {text}")
        for status in nav.ins.drain_aid_status():
            log.write(topics.NAV_AID_PREFIX + status.source, status)
        if est is not None and (tick + 1) % self.log_every == 0:
            log.write_nav_estimate(est)

    def _underspeed_event(self, t_s: float, engaged: bool) -> None:
        """An event where the autopilot's underspeed protection engages or lets go (fwsim.autopilot)."""
        uav = self.truth.uav
        if engaged:
            self.log.write_event(t_s, f"autopilot: underspeed at {uav.airspeed_m_s:.1f} m/s: the commanded path "
                                      "gives way to the airspeed (bent down until it recovers)", "WARNING")
        else:
            self.log.write_event(t_s, f"autopilot: airspeed back at {uav.airspeed_m_s:.1f} m/s: the commanded "
                                      "path is held again")

    def _flight_software(self, t_now: float) -> None:
        """The sensors sampled and the flight software stepped; its commands, status and topics logged."""
        log, truth, events = self.log, self.truth, self.events
        new_det = self.detector.arrived(t_now)
        self.last_det = new_det or self.last_det
        if self.nav is None:
            meas = self.sensors.sample(truth.uav, truth.gimbal, truth.cam_pos_enu_m, new_det, self.last_det,
                                       gnss_held=events is not None and events.gnss_held)
        else:
            meas = self.nav.measurements(t_now, truth.gimbal, new_det, self.last_det)
            if meas is None:  # the INS still aligns: the flight software waits for it
                return
        self.out = out = self.fsw.step(meas)
        self.phase = out.status.phase
        log.write(topics.AUTOPILOT_COMMAND, out.command)
        log.write(topics.FSW_GIMBAL_COMMAND, out.gimbal)
        log.write(topics.FSW_STATUS, out.status)
        for topic, msg in out.logs:
            log.write(topic, msg)
        for text in out.events:
            log.write_event(t_now, text)
        if new_det is not None:
            log.write(topics.CAMERA_DETECTION, new_det)

    def _look(self) -> None:
        """The camera's frame, handed to the detector (through the events' blackout and clutter) and logged."""
        events, cam = self.events, self.cam
        self.frame = frame = self.world.look()
        if events is None:
            self.detector.observe(frame)
        else:
            self.detector.observe(frame, events.blackout, events.clutter_box(cam.rate_hz, cam.width_px,
                                                                             cam.height_px))
        self.log.write(topics.CAMERA_FRAME, frame)

    def _ended(self) -> str:
        """Why the run ends at this tick ('' when it goes on); RunStopped above the airspeed limit."""
        truth, stop, t = self.truth, self.scenario.stop, self.sim_t
        if self.world.uav_inside_ship():
            why = f"hit the ship at t = {t:.2f} s"
        elif truth.uav.height_above_sea_m <= stop.min_height_m:
            why = f"sea contact at t = {t:.2f} s"
        elif truth.uav.airspeed_m_s > stop.max_airspeed_m_s:
            _log_truth(self.log, truth, self.origin, self.trails)
            raise RunStopped(f"airspeed {truth.uav.airspeed_m_s:.1f} m/s above the limit "
                             f"{stop.max_airspeed_m_s:g} m/s at t = {t:.2f} s")
        else:
            return ""
        _log_truth(self.log, truth, self.origin, self.trails)
        return why
