"""Timed events (fwsim.world.events): each kind does what it says, in one short flight of the paper mission."""
from __future__ import annotations

import numpy as np
import pytest

from fwsim import SCENARIO_DIR

from fwsim.interface import topics
from fwsim.world.events import EventRunner
from fwsim.log import read_log
from fwsim.sim.loop import run
from fwsim.scenario.model import ScenarioError, load_scenario
from fwsim.sensors.onboard import Sensors, rng_for

PAPER = SCENARIO_DIR / "paper_mission.yaml"
EVENTS = [
    {"kind": "gimbal_stuck", "after_phase": 2, "delay_s": 3, "duration_s": 2},
    {"kind": "detector_blackout", "t_s": 22, "duration_s": 3},
    {"kind": "wind_gust", "t_s": 28, "duration_s": 4, "velocity_enu_m_s": [0, 6, 0]},
    {"kind": "false_detections", "t_s": 34, "duration_s": 4, "rate_hz": 10},
    {"kind": "target_manoeuvre", "t_s": 15, "course_deg": 30, "speed_m_s": 7},
]


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    scenario, text = load_scenario(PAPER, {"duration_s": 40, "events": EVENTS})
    r = run(scenario, text, tmp_path_factory.mktemp("events") / "events.mcap")
    return read_log(r.log_path)


def _window(log, text):
    starts = [t for t, _, m in log.events() if m.startswith(f"event started: {text}")]
    ends = [t for t, _, m in log.events() if m == f"event ended: {text}"]
    assert len(starts) == 1 and len(ends) == 1, log.events()
    return starts[0], ends[0]


def test_every_event_starts_and_ends_in_the_log(flight):
    lock = next(t for t, _, m in flight.events() if m.startswith("phase 1 -> 2"))
    t0, t1 = _window(flight, "gimbal_stuck")
    assert t0 == pytest.approx(lock + 3, abs=0.01) and t1 == pytest.approx(t0 + 2, abs=0.01)
    for kind, (a, b) in (("detector_blackout", (22, 25)), ("wind_gust", (28, 32)), ("false_detections", (34, 38)),
                         ("target_manoeuvre", (15, 35))):
        t0, t1 = _window(flight, kind)
        assert (t0, t1) == (pytest.approx(a, abs=0.01), pytest.approx(b, abs=0.01))


def test_blackout_no_detections_and_the_target_is_lost(flight):
    d = flight.table(topics.CAMERA_DETECTION)
    inside = (d["exposure_t_s"] >= 22.0) & (d["exposure_t_s"] < 25.0)
    assert inside.sum() >= 80 and not d["detected"][inside].any()
    assert d["detected"][(d["exposure_t_s"] > 25.5) & (d["exposure_t_s"] < 28)].mean() > 0.9  # back after it
    assert any(22 < t < 25 and m.startswith("target lost") for t, _, m in flight.events())
    assert any(25 < t < 26 and m.startswith("target reacquired") for t, _, m in flight.events())


def test_stuck_gimbal_does_not_move(flight):
    t0, t1 = _window(flight, "gimbal_stuck")
    g = flight.table(topics.GIMBAL_STATE)
    w = (g["t_s"] > t0 + 0.05) & (g["t_s"] < t1 - 0.01)
    assert w.sum() > 30
    assert np.ptp(g["pan_rad"][w]) < 1e-9 and np.ptp(g["tilt_rad"][w]) < 1e-9
    moving = (g["t_s"] > t1 + 0.5) & (g["t_s"] < t1 + 3)
    assert np.ptp(g["pan_rad"][moving]) + np.ptp(g["tilt_rad"][moving]) > 1e-3  # tracking again


def test_gust_is_one_minus_cosine(flight):
    a = flight.table(topics.WORLD_AIR)
    north = a["wind_enu_m_s"][:, 1]
    assert np.abs(north[a["t_s"] < 27.9]).max() < 1e-9 and np.abs(north[a["t_s"] > 32.1]).max() < 1e-6
    assert north[np.argmin(np.abs(a["t_s"] - 30.0))] == pytest.approx(6.0, rel=0.02)
    quarter = north[np.argmin(np.abs(a["t_s"] - 29.0))]
    assert quarter == pytest.approx(3.0, rel=0.05)  # 1 - cos: half the peak a quarter of the way through


def test_false_detections_are_boxes_away_from_the_ship(flight):
    d, f = flight.table(topics.CAMERA_DETECTION), flight.table(topics.CAMERA_FRAME)
    centre = np.stack([d["u_px"], d["v_px"]], axis=1)
    truth = np.array([f["centre_px"][np.argmin(np.abs(f["t_s"] - t))] for t in d["exposure_t_s"]])
    far = d["detected"].astype(bool) & (np.linalg.norm(centre - truth, axis=1) > 60.0)
    inside = (d["exposure_t_s"] >= 34.0) & (d["exposure_t_s"] < 38.0)
    assert 20 <= far[inside].sum() <= 60  # 10 boxes/s of 30 frames/s over 4 s: 40 expected
    assert far[~inside & (d["exposure_t_s"] > 14)].sum() == 0


def test_target_manoeuvre_turns_the_ship(flight):
    t0, t1 = _window(flight, "target_manoeuvre")
    assert t0 == pytest.approx(15.0, abs=0.01) and t1 == pytest.approx(35.0, abs=0.05)  # 30 deg at 1.5 deg/s
    tg = flight.table(topics.TARGET_STATE)
    heading = np.degrees(tg["heading_ned_rad"])
    assert np.all(np.abs(heading[tg["t_s"] < 15.0]) < 1e-9)
    assert heading[np.argmin(np.abs(tg["t_s"] - 25.0))] == pytest.approx(15.0, abs=0.1)
    assert np.all(np.abs(heading[tg["t_s"] > 35.1] - 30.0) < 1e-6)
    assert tg["speed_m_s"][np.argmin(np.abs(tg["t_s"] - 19.5))] == pytest.approx(7.0)
    step = np.linalg.norm(np.diff(tg["pos_enu_m"], axis=0), axis=1)
    assert step.max() < 7.0 / 30.0 * 1.05  # no jump: the path is continuous


def test_gnss_outage_holds_the_last_fix():
    from fwsim.interface.messages import AirframeState
    from fwsim.sensors.onboard import SensorsConfig
    s = Sensors(SensorsConfig(), seed=1)

    def state(t):
        return AirframeState(t, np.array([t * 20.0, 0, 500]), np.array([20.0, 0, 0]), np.zeros(3), np.zeros(3),
                             20.0, 0.0, 0.0, np.zeros(3), 0.3, np.zeros(3), 500.0)
    m0 = s.sample(state(0.0))
    held = [s.sample(state(t), gnss_held=True) for t in np.arange(0.1, 1.0, 1 / 30)]
    assert all(m.nav_t_s == m0.nav_t_s and np.array_equal(m.pos_enu_m, m0.pos_enu_m) for m in held)
    assert s.sample(state(1.0)).nav_t_s == pytest.approx(1.0)


def test_after_phase_waits_for_the_phase():
    scenario, _ = load_scenario(PAPER, {"events": [{"kind": "detector_blackout", "after_phase": 3,
                                                      "duration_s": 1}]})
    runner, said = EventRunner(scenario.events, rng_for(1, "events")), []
    for t, phase in ((0.0, 1), (10.0, 2), (50.0, 2), (60.0, 3), (60.5, 3), (61.0, 3)):
        runner.step(t, phase, lambda t, text: said.append((t, text)), None)
        assert runner.blackout == (t == 60.0 or t == 60.5)
    assert [t for t, _ in said] == [60.0, 61.0]


@pytest.mark.parametrize("event, words", [
    ({"kind": "earthquake", "t_s": 1, "duration_s": 1}, "earthquake"),
    ({"kind": "detector_blackout", "duration_s": 1}, "give the start as t_s or as after_phase"),
    ({"kind": "detector_blackout", "t_s": 1, "after_phase": 2, "duration_s": 1}, "not both"),
    ({"kind": "detector_blackout", "t_s": 1}, "duration_s"),
    ({"kind": "false_detections", "t_s": 1, "duration_s": 1}, "rate_hz"),
    ({"kind": "wind_gust", "t_s": 1, "duration_s": 1, "velocity_enu_m_s": [0, 0, 0]}, "between 0 and 40"),
    ({"kind": "detector_blackout", "t_s": 1, "duration_s": 1, "delay_s": 2}, "delay_s goes with after_phase"),
    ({"kind": "target_manoeuvre", "t_s": 1}, "give course_deg, speed_m_s or both"),
])
def test_bad_events_are_one_line(event, words):
    with pytest.raises(ScenarioError, match=words) as exc:
        load_scenario(PAPER, {"events": [event]})
    assert "\n" not in str(exc.value)
