"""The dive's entry ring (``switch.entry_depression_margin_deg``): the loiter descends before the switch so that
the ship's depression from the ring is no steeper than the impact angle asks."""
import math

import numpy as np
import pytest

from controllers.config import NmpcConfig, SwitchConfig
from controllers.guidance.nmpc import Nmpc
from controllers.messages import TargetState
from controllers.phases.phases import PhaseState, Ring, entry_altitude_m, next_phase

SHIP = TargetState(0.0, "estimator", np.zeros(3), np.zeros(3), 0.1, 0.0)


def test_entry_altitude_puts_the_ship_at_the_impact_angle_less_the_margin():
    ring = Ring(500.0, 500.0)  # the ship 45 deg below the horizon
    # on by default, 5 deg: the ship 5 deg shallower than the impact angle below the horizon (R tan 25 deg)
    assert entry_altitude_m(ring, SwitchConfig(), -30.0) == pytest.approx(500.0 * math.tan(math.radians(25.0)))
    no_margin = SwitchConfig(entry_depression_margin_deg=0.0)  # the ship at the impact angle (R tan 30 deg)
    assert entry_altitude_m(ring, no_margin, -30.0) == pytest.approx(500.0 * math.tan(math.radians(30.0)))
    assert entry_altitude_m(ring, SwitchConfig(entry_depression_margin_deg=None), -30.0) is None  # the paper's
    sw = SwitchConfig(entry_depression_margin_deg=5.0)
    h = entry_altitude_m(ring, sw, -30.0)
    assert h == pytest.approx(500.0 * math.tan(math.radians(25.0)))
    assert math.degrees(math.atan2(h, ring.radius_m)) == pytest.approx(25.0)
    # never below the floor, never above H, and no descent when the ring at H is already as shallow
    assert entry_altitude_m(Ring(300.0, 800.0), sw, -20.0) == sw.entry_min_altitude_m
    assert entry_altitude_m(ring, sw, -60.0) is None  # 55 deg would be above H
    assert entry_altitude_m(Ring(500.0, 240.0), sw, -30.0) is None  # within the altitude tolerance of H
    assert entry_altitude_m(None, sw, -30.0) is None


def _fly(state, t0, t1, height_m, ring, sw, entry, approach_deg=0.0):
    """next_phase ticks at 10 Hz on the ring (radius R, the given height), south of the ship: the bearing to it
    0 deg (in the window of ``approach_deg`` 0)."""
    events = []
    for t in np.round(np.arange(t0, t1, 0.1), 6):
        state, ev = next_phase(state, t, np.array([0.0, -ring.radius_m, height_m]), np.array([22.0, 0.0, 0.0]),
                               height_m, SHIP, True, ring, sw, approach_deg, "nmpc", entry)
        events += ev
        if state.phase == 3:
            break
    return state, events


def test_the_first_switch_starts_the_descent_and_the_switch_is_armed_at_the_entry_ring():
    sw = SwitchConfig(dwell_s=5, min_loiter_s=5, approach_window_deg=None, entry_depression_margin_deg=5.0)
    ring = Ring(500.0, 500.0)
    entry = entry_altitude_m(ring, sw, -30.0)
    state, events = _fly(PhaseState(), 0.0, 20.0, 500.0, ring, sw, entry)
    assert state.phase == 2 and state.descending and state.descent_t_s == pytest.approx(5.0)
    assert any("descends from 500 m to the dive's entry ring at 233 m" in e for e in events)
    assert not any(e.startswith("phase 2 -> 3") for e in events)  # still at H: the switch waits
    state, events = _fly(state, 20.0, 40.0, entry + 3.0, ring, sw, entry)  # at the entry ring
    assert state.phase == 3 and state.phase3_t_s == pytest.approx(25.0)  # its dwell counted afresh
    assert any(e.startswith("phase 2 -> 3") and "altitude error +3.0 m" in e for e in events)
    # without the option the same loiter switches at H, at its first chance
    state, _ = _fly(PhaseState(), 0.0, 20.0, 500.0, ring, sw.model_copy(update={"entry_depression_margin_deg": None}),
                    None)
    assert state.phase == 3 and state.phase3_t_s == pytest.approx(5.0)


def test_the_descent_does_not_wait_for_the_approach_window():
    """Settled on the ring at H, the loiter descends at once, the bearing wherever it is; the dive then waits at
    the entry ring for the window (waiting for a window at H first cost a wide ring a whole orbit)."""
    sw = SwitchConfig(dwell_s=5, min_loiter_s=5, approach_window_deg=5.0, entry_depression_margin_deg=5.0)
    ring = Ring(500.0, 500.0)
    entry = entry_altitude_m(ring, sw, -30.0)
    state, events = _fly(PhaseState(), 0.0, 20.0, 500.0, ring, sw, entry, approach_deg=90.0)  # 90 deg off
    assert state.phase == 2 and state.descent_t_s == pytest.approx(5.0)
    state, events = _fly(state, 20.0, 40.0, entry, ring, sw, entry, approach_deg=90.0)
    assert state.phase == 2 and not any(e.startswith("phase 2 -> 3") for e in events)  # settled, out of the window
    state, events = _fly(state, 40.0, 41.0, entry, ring, sw, entry, approach_deg=0.0)
    assert state.phase == 3 and state.phase3_t_s == pytest.approx(40.0)  # the first window once there
    assert any("bearing to target 0.0 deg" in e for e in events)


def test_a_go_around_keeps_the_entry_ring():
    sw = SwitchConfig(dwell_s=5, min_loiter_s=5, approach_window_deg=None, entry_depression_margin_deg=5.0,
                      go_around_stall_s=None)
    ring = Ring(500.0, 500.0)
    entry = entry_altitude_m(ring, sw, -30.0)
    dive = PhaseState(3, 0.0, phase3_t_s=30.0, closest_m=100.0, switch_m=600.0, descent_t_s=10.0)
    far = TargetState(0.0, "estimator", np.array([0.0, 400.0, 0.0]), np.zeros(3), 0.1, 0.0)
    state, events = next_phase(dive, 40.0, np.array([0.0, -300.0, 150.0]), np.array([0.0, -22.0, 0.0]), 150.0,
                               far, True, ring, sw, 0.0, "nmpc", entry)
    assert state.phase == 2 and state.go_arounds == 1 and state.descent_t_s == 10.0
    assert any(e.startswith("phase 3 -> 2") for e in events)


def test_the_nmpc_flies_a_raised_ring_as_the_same_ring_lower():
    """The loiter flies the entry ring by giving its NMPC the UAV and the target both raised by the descent
    (``NmpcLoiter.altitude_offset_m``): the model knows no height but H, so the plan is the one for a ring at
    H - offset, the same commands and the same path, lowered."""
    dz = 267.0
    x0 = np.array([-700.0, 120.0, 520.0, 0.1, -0.05, 0.4 * math.pi])
    ship, ship_v = np.array([30.0, -20.0, 3.75]), np.array([2.0, 4.0, 0.0])
    raised = Nmpc(NmpcConfig(max_solve_ms=1e5)).solve(0.0, x0 + [0, 0, dz, 0, 0, 0], ship + [0, 0, dz], ship_v)
    lower = Nmpc(NmpcConfig(altitude_m=500.0 - dz, max_solve_ms=1e5)).solve(0.0, x0, ship, ship_v)
    assert not raised.fallback and not lower.fallback
    np.testing.assert_allclose(raised.u0, lower.u0, atol=1e-6)
    np.testing.assert_allclose(np.asarray(raised.predicted)[:, 2] - dz, np.asarray(lower.predicted)[:, 2], atol=1e-4)


class RingOnly:
    """A user's loiter with no altitude_offset_m: it cannot fly below its ring."""

    radius_m = 500.0
    altitude_m = 500.0

    def __init__(self, options, context):
        pass

    def step(self, nav, target):
        raise NotImplementedError


class RingAndOffset(RingOnly):
    altitude_offset_m = 0.0


def test_the_entry_ring_with_a_loiter_that_cannot_descend_is_a_one_line_scenario_error():
    from fwsim import SCENARIO_DIR
    from fwsim.scenario.model import ScenarioError, load_scenario

    entry = {"controllers.switch.entry_depression_margin_deg": 5.0}
    with pytest.raises(ScenarioError) as exc:
        load_scenario(SCENARIO_DIR / "paper_mission.yaml",
                      {**entry, "controllers.after_lock": "test_dive_entry:RingOnly"})
    text = str(exc.value)
    assert "\n" not in text and "switch.entry_depression_margin_deg: test_dive_entry:RingOnly has no " \
                                "altitude_offset_m" in text, text
    for fine in ({**entry, "controllers.after_lock": "test_dive_entry:RingAndOffset"},
                 {"controllers.after_lock": "test_dive_entry:RingOnly"},  # paper_mission.yaml: the paper's dive
                 {**entry, "controllers.after_lock": "orbit"}):
        load_scenario(SCENARIO_DIR / "paper_mission.yaml", fine)
