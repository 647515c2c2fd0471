"""Flight software never reads truth (DESIGN.md section 1)."""
import ast
import math
from pathlib import Path

import numpy as np
import pytest

import controllers
from controllers.config import SwitchConfig
from controllers.messages import TargetState
from controllers.mission import FlightSoftware
from controllers.phases import PhaseState, Ring, next_phase
from fwsim.messages import Measurements, RateCommand
from fwsim.scenario import parse_scenario

TRUTH_MODULES = {"jsbsim", "fwsim.airframe", "fwsim.autopilot", "fwsim.loop", "fwsim.sensors", "fwsim.target",
                 "fwsim.camera", "fwsim.gimbal", "fwsim.world", "fwsim.log", "fwsim.metrics", "fwsim.cli"}
ALLOWED_FWSIM = {"fwsim.messages", "fwsim.frames", "fwsim.topics", "fwsim.configbase", "fwsim"}


def imported_modules(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            names.add(node.module)
    return names


def test_controllers_import_nothing_from_the_truth_side():
    pkg = Path(controllers.__file__).parent
    files = sorted(pkg.rglob("*.py"))
    assert files
    for f in files:
        for mod in imported_modules(f):
            assert not any(mod == t or mod.startswith(t + ".") for t in TRUTH_MODULES), f"{f.name} imports {mod}"
            if mod.startswith("fwsim"):
                assert mod in ALLOWED_FWSIM, f"{f.name} imports {mod}"


def test_flight_software_runs_on_measurements_alone():
    """A synthetic Measurements stream (no JSBSim, no harness) drives the flight software."""
    s = parse_scenario("""
name: b
duration_s: 10
initial: {pos_enu_m: [0, 0, 500], airspeed_m_s: 22, heading_deg: 0}
""")
    fsw = FlightSoftware(s.controllers, s.initial, s.camera)
    for k in range(30):
        t = k / 30
        # flying north, 20 m right (east) of the path and 10 m low
        meas = Measurements(t, np.array([20.0, 22.0 * t, 490.0]), np.array([0.0, 22.0, 0.0]),
                            np.array([0.0, 0.03, 0.0]), np.zeros(3), 22.0, 490.0)
        out = fsw.step(meas)
    assert isinstance(out.command, RateCommand)
    assert out.status.phase == 1
    assert out.status.cross_track_m == 20.0
    assert out.command.roll_rate_rad_s < 0  # roll left, back toward the path
    assert out.command.pitch_rate_rad_s > 0  # climb back to 500 m
    assert math.isclose(out.status.altitude_sp_m, 500.0)


def test_a_detection_above_the_horizon_does_not_stop_the_flight_software():
    """A lock whose detection ray misses the sea (the camera looking up) cannot start the UKF: the flight
    software says so in its events and goes on flying; a later detection below the horizon starts it."""
    s = parse_scenario("""
name: b
duration_s: 10
initial: {pos_enu_m: [0, 0, 500], airspeed_m_s: 22, heading_deg: 0}
controllers: {acquisition: {lock_detections: 1}}
camera: {gimbal: {initial_tilt_rad: 0.5}}
""")
    fsw = FlightSoftware(s.controllers, s.initial, s.camera)

    def meas(t, tilt):
        return Measurements(t, np.array([0.0, 22.0 * t, 500.0]), np.array([0.0, 22.0, 0.0]), np.zeros(3),
                            np.zeros(3), 22.0, 500.0, pan_rad=0.0, tilt_rad=tilt, pan_rate_rad_s=0.0,
                            tilt_rate_rad_s=0.0, cam_pos_enu_m=np.array([0.0, 22.0 * t, 499.9]), det_new=True,
                            det_valid=True, det_u_px=640.0, det_v_px=360.0,
                            det_bbox_px=np.array([600.0, 340.0, 680.0, 380.0]))
    out = fsw.step(meas(0.0, 0.5))  # tilted 29 deg up: the ray through the image centre never meets the sea
    assert any("not initialised" in e for e in out.events), out.events
    assert not fsw.estimation.filter.initialised
    assert [m.reason for topic, m in out.logs if topic == "/fsw/detection_fusion"] == ["not_initialised"]
    out = fsw.step(meas(1 / 30, -0.8))  # looking down: the next detection starts it
    assert fsw.estimation.filter.initialised and any("re-initialised" in e for e in out.events), out.events
    assert [m.reason for topic, m in out.logs if topic == "/fsw/detection_fusion"] == ["initialised"]


def test_the_switch_dwell_runs_alongside_the_minimum_loiter():
    """2 -> 3 needs the radius and altitude held for dwell_s and at least min_loiter_s in Phase 2; the two
    run side by side, so a UAV on the ring from the start may switch at min_loiter_s (the approach window
    is often only a few seconds wide, and counting the dwell only after the minimum loiter used to miss it);
    leaving the tolerance restarts the dwell."""
    sw = SwitchConfig(dwell_s=5, min_loiter_s=5, approach_window_deg=None)
    ship = TargetState(0.0, "estimator", np.zeros(3), np.zeros(3), 0.1, 0.0)
    ring = Ring(500.0, 500.0)

    def first_switch(off_ring_at=None):
        state = PhaseState()  # locked at t = 0 (Phase 1 -> 2 at once)
        for t in np.round(np.arange(0.0, 10.0, 0.1), 6):
            radius = 600.0 if t == off_ring_at else 500.0
            state, events = next_phase(state, t, np.array([0.0, -radius, 500.0]), np.array([22.0, 0.0, 0.0]), 500.0,
                                       ship, True, ring, sw, 30.0)
            if state.phase == 3:
                assert any(e.startswith("phase 2 -> 3") for e in events)
                return t
    assert first_switch() == pytest.approx(5.0)
    off_ring_at = 3.0
    assert first_switch(off_ring_at) == pytest.approx(off_ring_at + 0.1 + 5.0)


def test_the_phase_decision_is_a_pure_function_of_its_inputs():
    """The same state and inputs give the same answer, the input state is left as it was; Phase 2 needs a lock,
    a ring and a target estimate; without a ring (after_lock: path) the mission stays in Phase 1."""
    ship = TargetState(0.0, "estimator", np.zeros(3), np.zeros(3), 0.1, 0.0)
    unknown = TargetState(0.0, "none", np.full(3, np.nan), np.full(3, np.nan), math.nan, 0.0)
    args = (np.array([0.0, -500.0, 500.0]), np.array([22.0, 0.0, 0.0]), 500.0)
    s0 = PhaseState()
    a = next_phase(s0, 1.0, *args, ship, True, Ring(500.0, 500.0), SwitchConfig(), 30.0, "nmpc")
    assert a == next_phase(s0, 1.0, *args, ship, True, Ring(500.0, 500.0), SwitchConfig(), 30.0, "nmpc")
    assert s0 == PhaseState() and a[0].phase == 2 and a[0].phase2_t_s == 1.0 and "loiter (nmpc)" in a[1][0]
    assert next_phase(s0, 1.0, *args, ship, False, Ring(500.0, 500.0), SwitchConfig(), 30.0)[0].phase == 1
    assert next_phase(s0, 1.0, *args, unknown, True, Ring(500.0, 500.0), SwitchConfig(), 30.0)[0].phase == 1
    assert next_phase(s0, 1.0, *args, ship, True, None, SwitchConfig(), 30.0) == (s0, ())
