"""Flight software never reads truth (docs/design/architecture.md, "Two rules")."""
import ast
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import controllers
from controllers.config import BpngConfig, SwitchConfig
from controllers.messages import TargetState
from controllers.mission import FlightSoftware
from controllers.phases.phases import PhaseState, Ring, approach_bearing_deg, next_phase, window_bearing_deg
from fwsim.interface.messages import Measurements, RateCommand
from fwsim.scenario.model import parse_scenario

#: the harness's truth side: the flight software imports none of it
TRUTH_MODULES = {"jsbsim", "fwsim.world", "fwsim.sensors", "fwsim.sim", "fwsim.autopilot", "fwsim.log",
                 "fwsim.analysis", "fwsim.batch", "fwsim.scenario", "fwsim.cli"}
#: the one part of fwsim the flight software may import: the types both sides share
SHARED = "fwsim.interface"


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
            if mod == "fwsim" or mod.startswith("fwsim."):
                assert mod == SHARED or mod.startswith(SHARED + "."), f"{f.name} imports {mod}"


def test_the_shared_types_import_neither_side():
    """fwsim.interface (messages, frames, topics, the config base) is the one module both sides import: it imports
    nothing else of fwsim and nothing of the flight software, so no package-level cycle runs through it."""
    import fwsim.interface
    files = sorted(Path(fwsim.interface.__file__).parent.rglob("*.py"))
    assert len(files) >= 4
    for f in files:
        for mod in imported_modules(f):
            assert not mod.startswith("controllers"), f"{f.name} imports {mod}"
            if mod == "fwsim" or mod.startswith("fwsim."):
                assert mod.startswith(SHARED), f"{f.name} imports {mod}"


def test_flight_software_runs_on_measurements_alone():
    """A synthetic Measurements stream (no JSBSim, no harness) drives the flight software."""
    s = parse_scenario("""
name: b
duration_s: 10
initial: {pos_enu_m: [0, 0, 500], airspeed_m_s: 22, heading_deg: 0}
controllers: {after_lock: path, switch: {enabled: false}}   # the initial path alone
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
controllers: {acquisition: {lock_detections: 1}, after_lock: path, switch: {enabled: false}}
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


def _closing_bearing_by_search(psi_f, theta_f, airspeed, wind, ship):
    """The same bearing without the closed form: the larger ground speed along V_f whose air speed is the
    dive's, found by bisection on |Vg V_f - wind| (convex in Vg)."""
    d = np.array([math.cos(math.radians(theta_f)) * math.sin(math.radians(psi_f)),
                  math.cos(math.radians(theta_f)) * math.cos(math.radians(psi_f)), math.sin(math.radians(theta_f))])
    w = np.asarray(wind, float)
    lo, hi = max(float(d @ w), 0.0), 500.0  # |Vg d - w| grows past its minimum at Vg = d.w
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if np.linalg.norm(mid * d - w) < airspeed else (lo, mid)
    rel = lo * d[:2] - np.asarray(ship, float)[:2]
    return math.degrees(math.atan2(rel[0], rel[1])), lo, np.linalg.norm(rel)


def test_the_approach_bearing_is_the_impact_heading_for_a_still_ship_in_still_air():
    for psi in (-170.0, 0.0, 30.0, 64.0, 300.0):
        for theta in (-20.0, -45.0, -60.0):
            assert approach_bearing_deg(psi, theta, 22.0, np.zeros(3), np.zeros(3)) == pytest.approx(psi % 360.0)


@settings(max_examples=200, deadline=None)
@given(psi=st.floats(-180, 360), theta=st.floats(-80, -5), airspeed=st.floats(15, 40),
       wind=st.tuples(st.floats(-9, 9), st.floats(-9, 9)), ship_deg=st.floats(0, 360), ship_speed=st.floats(0, 12))
def test_the_approach_bearing_is_the_closing_direction_at_the_end_of_the_dive(psi, theta, airspeed, wind, ship_deg,
                                                                             ship_speed):
    """Against a search for the ground speed: the bearing is that of the UAV's ground velocity along V_f (at the
    dive's airspeed in the wind) less the ship's, where that closing is more than 0.5 m/s horizontally."""
    ship = ship_speed * np.array([math.sin(math.radians(ship_deg)), math.cos(math.radians(ship_deg)), 0.0])
    w = np.array([wind[0], wind[1], 0.0])
    got = approach_bearing_deg(psi, theta, airspeed, w, ship)
    want, vg, closing = _closing_bearing_by_search(psi, theta, airspeed, w, ship)
    if closing > 0.6:
        assert (got - want + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=1e-6)
    elif closing < 0.4:
        assert got == pytest.approx(psi % 360.0) or got == 0.0
    assert 0.0 <= got < 360.0


def test_a_fast_ship_and_a_steep_dive_into_a_headwind_move_the_approach_round():
    """A 9.9 m/s ship heading 84.5 deg, a 59 deg dive to 64 deg into a 6.8 m/s wind from the south-east: at 22 m/s
    the UAV's ground velocity along the ship's course is about the ship's, so it closes from the south, ~70 deg
    round from the impact heading (placed by the impact heading, the window put the UAV behind the ship, where
    the dive never closed). A ship faster than the dive's ground speed along V_f is met from ahead."""
    ship = 9.9 * np.array([math.sin(math.radians(84.5)), math.cos(math.radians(84.5)), 0.0])
    b = approach_bearing_deg(64.35, -58.5, 22.0, np.array([-4.33, 5.30, 0.0]), ship)
    assert 340.0 < b < 360.0
    fast = 15.0 * np.array([math.sin(math.radians(64.35)), math.cos(math.radians(64.35)), 0.0])
    assert (approach_bearing_deg(64.35, -60.0, 22.0, np.zeros(3), fast) - (64.35 + 180.0) + 180) % 360 - 180 == \
        pytest.approx(0.0, abs=1e-9)
    # a wind stronger than the airspeed along V_f leaves no ground speed: the impact heading
    assert approach_bearing_deg(30.0, -30.0, 10.0, np.array([-20.0, -20.0, 0.0]), np.zeros(3)) == 30.0
    assert approach_bearing_deg(-30.0, -30.0, 22.0, np.zeros(3), np.array([math.nan, 0.0, 0.0])) == 330.0
    assert approach_bearing_deg(-30.0, -30.0, 22.0, np.full(3, np.nan), np.zeros(3)) == 330.0  # no wind estimate


def test_a_dive_that_does_not_close_goes_round_and_the_switch_is_armed_again():
    """In Phase 3 the range to the estimate may shrink or hold; once it has grown go_around_m above its least
    since the switch, the mission goes back to Phase 2 (one go-around counted, the dwell and minimum loiter
    afresh); go_around_m: none keeps Phase 3; without a ring there is no loiter to go back to."""
    ship = TargetState(0.0, "estimator", np.zeros(3), np.zeros(3), 0.1, 0.0)
    ring = Ring(500.0, 500.0)
    sw = SwitchConfig(go_around_m=100.0)
    vel = np.array([22.0, 0.0, 0.0])

    def fly(ranges, sw=sw, ring=ring):
        state, log = PhaseState(3, 0.0), []
        for k, r in enumerate(ranges):
            state, events = next_phase(state, 100.0 + k, np.array([0.0, -r, 0.0]), vel, 500.0, ship, True, ring,
                                       sw, 30.0, "nmpc")
            log += events
        return state, log

    state, log = fly([600.0, 550.0, 560.0, 640.0, 649.0])  # 99 m above the least (550 m)
    assert state.phase == 3 and state.closest_m == 550.0 and not log
    state, log = fly([600.0, 550.0, 560.0, 640.0, 651.0])
    assert state == PhaseState(2, 104.0, go_arounds=1)
    assert log and log[0].startswith("phase 3 -> 2 at t = 104.00 s: the dive is not closing (range 651 m, 101 m")
    assert fly([600.0, 550.0, 900.0], sw=SwitchConfig(go_around_m=None))[0].phase == 3
    assert fly([600.0, 550.0, 900.0], ring=None)[0].phase == 3
    # back in Phase 2 the switch waits for the dwell and the minimum loiter again
    again, _ = next_phase(state, 105.0, np.array([0.0, -500.0, 500.0]), vel, 500.0, ship, True, ring,
                          SwitchConfig(go_around_m=100.0, approach_window_deg=None), 30.0)
    assert again.phase == 2 and again.go_arounds == 1


def test_a_dive_that_holds_its_range_goes_round_after_the_stall_time():
    """go_around_stall_s after the switch, a dive whose least range has not fallen go_around_stall_fraction below
    its range at the switch goes round (the range need not grow); one that has closed that much by then stays
    in Phase 3 however slowly it goes on; go_around_stall_s: none never goes round for it."""
    ship = TargetState(0.0, "estimator", np.zeros(3), np.zeros(3), 0.1, 0.0)
    ring = Ring(500.0, 500.0)
    sw = SwitchConfig(go_around_stall_s=20.0, go_around_stall_fraction=0.02)
    vel = np.array([22.0, 0.0, 0.0])

    def fly(ranges, sw=sw):
        state, log = PhaseState(3, 0.0, phase3_t_s=100.0), []
        for k, r in enumerate(ranges):
            state, events = next_phase(state, 100.0 + k, np.array([0.0, -r, 0.0]), vel, 500.0, ship, True, ring,
                                       sw, 30.0, "nmpc")
            log += events
            if events:
                return state, log, 100.0 + k
        return state, log, None

    holding = [870.0 - 0.5 * k for k in range(30)]  # 15 m (1.7 %) closer after 30 s
    state, log, t = fly(holding)
    assert state == PhaseState(2, 120.0, go_arounds=1) and t == 120.0
    assert log[0].startswith("phase 3 -> 2 at t = 120.00 s: the dive is not closing (range 860 m 20 s after the "
                             "switch, its least 860 m against 870 m at the switch)"), log
    closing = [870.0 - 0.5 * k for k in range(19)] + [850.0] * 20  # 2.3 % closer by 20 s, then holding
    assert fly(closing)[0].phase == 3
    assert fly(holding, sw=SwitchConfig(go_around_stall_s=None))[0].phase == 3


def test_the_window_is_placed_by_the_closing_bearing_after_a_go_around():
    """approach_from: the impact heading always, or (the default) the impact heading until a dive has gone
    round and the closing bearing after it; the impact heading without an estimate."""
    bp = BpngConfig(impact_heading_deg=64.35, impact_flight_path_deg=-58.5, airspeed_m_s=22.0)
    ship_vel = 9.9 * np.array([math.sin(math.radians(84.5)), math.cos(math.radians(84.5)), 0.0])
    ship = TargetState(0.0, "estimator", np.zeros(3), ship_vel, 0.1, 0.0)
    unknown = TargetState(0.0, "none", np.full(3, np.nan), np.full(3, np.nan), math.nan, 0.0)
    wind = np.array([-4.33, 5.30, 0.0])
    closing = approach_bearing_deg(64.35, -58.5, 22.0, wind, ship_vel)
    first, later = PhaseState(2, 0.0), PhaseState(2, 0.0, go_arounds=1)
    default = SwitchConfig()
    assert default.approach_from == "closing_after_go_around"
    assert window_bearing_deg(first, default, bp, wind, ship) == 64.35
    assert window_bearing_deg(later, default, bp, wind, ship) == closing
    assert window_bearing_deg(later, default, bp, wind, unknown) == 64.35
    assert window_bearing_deg(later, SwitchConfig(approach_from="impact_heading"), bp, wind, ship) == 64.35


SHARED_CONTROLLERS = {"controllers", "controllers.config", "controllers.messages", "controllers.compiled",
          "controllers.ship_motion", "controllers.navigation.camera_model"}


def test_blocks_import_each_other_only_through_messages_config_and_shared_maths():
    """A block's subpackage imports its own modules and the shared ones, not another block's (a type named only
    for annotations, under TYPE_CHECKING, is allowed)."""
    pkg = Path(controllers.__file__).parent
    blocks = sorted(d.name for d in pkg.iterdir() if (d / "__init__.py").exists())
    assert blocks == ["estimation", "guidance", "navigation", "perception", "phases", "pointing"]
    for block in blocks:
        for f in sorted((pkg / block).glob("*.py")):
            tree = ast.parse(f.read_text())
            typing_only = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If)
                           and getattr(node.test, "id", None) == "TYPE_CHECKING" for n in ast.walk(node)}
            for node in ast.walk(tree):
                if isinstance(node, ast.ImportFrom) and node.module and id(node) not in typing_only:
                    mod = node.module
                    if mod.startswith("controllers"):
                        assert mod in SHARED_CONTROLLERS or mod.startswith(f"controllers.{block}."), f"{block}/{f.name}: {mod}"
