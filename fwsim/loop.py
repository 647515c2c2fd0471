"""The simulation loop: ``run(scenario) -> RunResult``.

One fixed-rate loop (JSBSim + autopilot at ``rates.sim_hz``), other blocks at
their own rates, one line per block in signal order (DESIGN.md section 1):

    meas  = sensors.sample(truth)         # harness: what the UAV can know
    out   = flight_software.step(meas)    # controllers/: the paper's algorithms
    act   = autopilot.step(cmd, truth)    # inner loops (PX4 on the airframe)
    truth = airframe.step(act)            # JSBSim
    log.write(...)                        # observes, never feeds back

The autopilot stands for PX4 on the aircraft and reads the airframe state as
PX4's own estimator would give it; the flight software only sees
``Measurements``.
"""
from __future__ import annotations

import math
import platform
import time
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Callable

import numpy as np

import fwsim
from controllers.mission import FlightSoftware
from fwsim.airframe import Airframe, aircraft_file, aircraft_hash
from fwsim.autopilot import Autopilot, load_autopilot_params
from fwsim.frames import GeoOrigin
from fwsim.log import LogWriter
from fwsim.scenario import Scenario
from fwsim.sensors import Sensors

#: Topics written by the loop (besides LogWriter.write_state's /uav/state, /tf, /uav/pose).
COMMAND_TOPIC = "/autopilot/command"
AUTOPILOT_TOPIC = "/autopilot/status"
ACTUATOR_TOPIC = "/actuators"
FSW_TOPIC = "/fsw/status"


@dataclass(frozen=True)
class RunResult:
    log_path: Path
    status: str  # completed | failed | interrupted
    reason: str
    sim_time_s: float
    wall_time_s: float

    @property
    def real_time_factor(self) -> float:
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else math.inf


class RunStopped(Exception):
    """The run ended early for a reason the scenario defines (sea contact, ...)."""


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
    }


def run(scenario: Scenario, scenario_text: str, log_path: Path,
        progress: Callable[[float, float], None] | None = None) -> RunResult:
    """Fly a scenario; always leaves a complete MCAP log at ``log_path``.

    ``progress(sim_t_s, duration_s)`` is called about once per simulated
    second. Ends at ``duration_s``, at sea contact (``stop.min_height_m``), or
    on an error (the log records why). KeyboardInterrupt is logged as
    'interrupted' and re-raised.
    """
    log_path = Path(log_path)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    rates = scenario.rates
    dt = 1.0 / rates.sim_hz
    fsw_every = round(rates.sim_hz / rates.flight_software_hz)
    log_every = round(rates.sim_hz / rates.log_hz)
    n_ticks = int(round(scenario.duration_s * rates.sim_hz))
    progress_every = max(int(rates.sim_hz), 1)

    wall0 = time.perf_counter()
    sim_t = 0.0
    status, reason = "completed", "duration reached"
    with LogWriter(log_path, metadata=run_metadata(scenario), scenario_text=scenario_text) as log:
        try:
            ini = scenario.initial
            airframe = Airframe(scenario.aircraft.name, dt_s=dt,
                                origin=GeoOrigin(scenario.world.origin_lat_deg, scenario.world.origin_lon_deg),
                                wind_enu_m_s=scenario.world.wind_enu_m_s)
            truth = airframe.reset(ini.pos_enu_m, ini.airspeed_m_s, math.radians(ini.heading_deg),
                                   math.radians(ini.flight_path_deg), trim=ini.trim)
            log.write_event(0.0, f"trim: throttle {airframe.trim.throttle_norm:.3f}, "
                                 f"elevator {airframe.trim.elevator_norm:.3f}, "
                                 f"alpha {math.degrees(airframe.trim.alpha_rad):.2f} deg")
            autopilot = Autopilot(load_autopilot_params(scenario.aircraft.name,
                                                        overrides=scenario.aircraft.autopilot_gains),
                                  dt, airframe.trim.throttle_norm)
            sensors = Sensors(scenario.seed)
            flight_software = FlightSoftware(scenario.controllers, scenario.initial)
            log.write_state(truth)

            for tick in range(n_ticks):
                if tick % fsw_every == 0:
                    meas = sensors.sample(truth)
                    out = flight_software.step(meas)
                    log.write(COMMAND_TOPIC, out.command)
                    log.write(FSW_TOPIC, out.status)
                act, ap_status = autopilot.step(out.command, truth)
                truth = airframe.step(act)
                sim_t = truth.t_s
                if (tick + 1) % log_every == 0:
                    log.write_state(truth)
                    log.write(AUTOPILOT_TOPIC, ap_status)
                    log.write(ACTUATOR_TOPIC, act)
                if truth.height_above_sea_m <= scenario.stop.min_height_m:
                    log.write_state(truth)
                    status, reason = "completed", f"sea contact at t = {sim_t:.2f} s"
                    break
                if truth.airspeed_m_s > scenario.stop.max_airspeed_m_s:
                    log.write_state(truth)
                    raise RunStopped(f"airspeed {truth.airspeed_m_s:.1f} m/s above the limit "
                                     f"{scenario.stop.max_airspeed_m_s:g} m/s at t = {sim_t:.2f} s")
                if progress is not None and tick % progress_every == 0:
                    progress(sim_t, scenario.duration_s)
        except RunStopped as exc:
            status, reason = "failed", str(exc)
        except Exception as exc:  # any other error: the log says why, the caller sees it too
            log.close("failed", f"{type(exc).__name__}: {exc} (t = {sim_t:.2f} s)")
            raise
        log.close(status, reason)
    if progress is not None:
        progress(sim_t, scenario.duration_s)
    return RunResult(log_path, status, reason, sim_t, time.perf_counter() - wall0)
