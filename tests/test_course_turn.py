"""A turning ship through the paper's constant-velocity UKF (controllers.estimation.course_turn,
controllers.turn_from_course).

Oracles: the analytic circle of a ship turning at 1-1.5 deg/s seen from an
orbiting camera (tests/test_manoeuvre_estimator.py's TurningShip), the UKF's own
lag measured against it, a straight line, and synthetic course histories with a
known slope.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_manoeuvre_estimator import TurningShip, orbit_measurements
from test_ukf import CAM, MOUNT

from controllers.config import TurnFromCourseConfig
from controllers.estimation.course_turn import CourseTurn, CourseTurnStatus, fit_periodic, lag_matrices
from controllers.estimation.estimation import Estimation
from controllers.estimation.ukf import CameraMotion, UkfConfig, UkfTargetEstimator, fix_from_measurements
from controllers.navigation.camera_model import closing_time_s, held_while_closing
from fwsim import SCENARIO_DIR
from fwsim.interface import topics
from fwsim.scenario.model import ScenarioError, load_scenario, parse_scenario
from fwsim.world.target import Ship, TargetConfig

ON = TurnFromCourseConfig(enabled=True)


def fly(turn_deg_s: float, duration_s: float = 120.0, seed: int = 3, ship_speed: float = 5.0):
    """The UKF and a CourseTurn on 30 Hz measurements of a ship turning at ``turn_deg_s`` -> rows after 60 s:
    (t, the UKF's velocity error (2), its lag model's (2), position error (2), its model's (2), the corrected
    state's position and velocity errors, the UKF's, the turn in use), and the CourseTurn."""
    truth = TurningShip(turn_deg_s=turn_deg_s, ship_speed=ship_speed)
    ukf = UkfTargetEstimator(CAM, UkfConfig())
    turn = CourseTurn(ON)
    rows = []
    for t, meas, cam in orbit_measurements(truth, duration_s, seed):
        est = ukf.step(meas, cam)
        turn.observe(t, est.pos_enu_m, est.vel_enu_m_s, float(max(est.vel_std_m_s[:2])), ukf.pos_vel_cov)
        if t < 60.0:
            continue
        p_true, v_true = truth.ship(t)[:2], truth.ship_vel(t)[:2]
        a = truth.w_enu * np.array([-v_true[1], v_true[0]])
        mv, mp = lag_matrices(ukf.pos_vel_cov)
        state = turn.state(t)
        p, v = (est.pos_enu_m, est.vel_enu_m_s) if state is None else state[:2]
        rows.append(np.concatenate([[t], v_true - est.vel_enu_m_s[:2], mv @ a, p_true - est.pos_enu_m[:2], mp @ a,
                                    [np.linalg.norm(p[:2] - p_true), np.linalg.norm(v[:2] - v_true),
                                     np.linalg.norm(est.pos_enu_m[:2] - p_true),
                                     np.linalg.norm(est.vel_enu_m_s[:2] - v_true), turn.turn_rad_s]]))
    return np.array(rows), turn


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


@pytest.mark.parametrize("turn_deg_s", [1.5, -1.0])
def test_the_covariance_gives_the_ukfs_own_lag_in_a_steady_turn(turn_deg_s):
    """The UKF trails a turning ship by a constant angle; lag_matrices(P) predicts the trailing velocity and
    position from the acceleration w x v: the model's error against the measured lag is a fraction of it."""
    r, _ = fly(turn_deg_s)
    ev, ev_model, ep, ep_model = r[:, 1:3], r[:, 3:5], r[:, 5:7], r[:, 7:9]
    lag_v = rms(np.linalg.norm(ev, axis=1))
    assert lag_v > 0.25  # the lag is there to model: 5 m/s at 1-1.5 deg/s, 3-6 deg behind
    assert rms(np.linalg.norm(ev - ev_model, axis=1)) < 0.3 * lag_v
    # the position's lag is noisier (the pixel noise is of its size): the model takes most of it
    assert rms(np.linalg.norm(ep - ep_model, axis=1)) < 0.75 * rms(np.linalg.norm(ep, axis=1))


@pytest.mark.parametrize("turn_deg_s", [1.5, 1.0, -1.0])
def test_the_turn_is_found_and_the_lag_taken_out(turn_deg_s):
    r, _ = fly(turn_deg_s)
    used = r[:, 13]
    # the turn rate (ENU, counter-clockwise; the ship's turn_deg_s is clockwise): within 0.2 deg/s all along
    err = np.degrees(used) + turn_deg_s
    assert np.all(np.abs(err) < 0.2) and rms(err) < 0.1
    pos_c, vel_c, pos_u, vel_u = r[:, 9], r[:, 10], r[:, 11], r[:, 12]
    assert rms(vel_c) < 0.4 * rms(vel_u)
    assert rms(pos_c) < 0.7 * rms(pos_u)


def test_a_straight_ship_is_left_alone():
    r, turn = fly(0.0)
    assert np.all(r[:, 13] == 0.0)
    assert turn.state(120.0) is None
    assert abs(math.degrees(turn.fit_rad_s)) < 0.2  # the slope was fitted, and found to be no turn


def test_a_slow_ship_gets_no_turn():
    """Under min_speed_m_s the course says nothing: no history, no turn."""
    r, turn = fly(1.5, duration_s=90.0, ship_speed=2.0)
    assert np.all(r[:, 13] == 0.0) and math.isnan(turn.fit_rad_s)


def feed(turn: CourseTurn, slope_rad_s: float, noise_rad: float, n_s: float = 60.0, seed: int = 0):
    rng = np.random.default_rng(seed)
    for t in np.arange(0.0, n_s, 0.1):
        c = 0.3 + slope_rad_s * t + rng.normal(0.0, noise_rad)
        turn.observe(t, np.zeros(3), 6.0 * np.array([math.cos(c), math.sin(c), 0.0]), 0.2, None)


def test_the_slope_must_stand_out_of_the_courses_scatter():
    """The same slope is a turn in a quiet course and not in a noisy one; a slope under min_turn_deg_s is none;
    the rate is capped at max_turn_deg_s; across the +-180 deg wrap the course is unwrapped."""
    quiet, noisy, small, fast = (CourseTurn(ON) for _ in range(4))
    feed(quiet, math.radians(0.8), math.radians(0.5))
    feed(noisy, math.radians(0.8), math.radians(20.0))
    feed(small, math.radians(0.2), 0.0)
    feed(fast, math.radians(5.0), math.radians(0.5))
    assert quiet.turn_rad_s == pytest.approx(math.radians(0.8), abs=math.radians(0.05))
    assert noisy.turn_rad_s == 0.0 and math.isfinite(noisy.fit_rad_s)
    assert small.turn_rad_s == 0.0 and small.fit_rad_s == pytest.approx(math.radians(0.2), rel=1e-6)
    assert fast.turn_rad_s == pytest.approx(math.radians(ON.max_turn_deg_s))
    # no covariance given: the turn is found, but no lag to take out, so the estimate stands
    assert quiet.state(60.0) is None


def test_a_zigzags_swing_is_not_a_steady_turn():
    """A +-30 deg, 60 s zigzag's course: each swing's slope stands out, but the fits of the last steady_s do not
    agree, so no turn is used (a swing's rate held into a dive would lead the guidance the wrong way); without
    the steadiness test the swings are taken for turns."""
    share = {}
    for steady in (ON.steady_s, 0.0):
        turn, on = CourseTurn(ON.model_copy(update={"steady_s": steady})), []
        for t in np.arange(0.0, 300.0, 0.1):
            c = 0.3 + math.radians(30.0) * math.sin(2.0 * math.pi * t / 60.0)
            turn.observe(t, np.zeros(3), 6.0 * np.array([math.cos(c), math.sin(c), 0.0]), 0.2, None)
            if t >= 60.0:
                on.append(turn.turn_rad_s != 0.0)
        share[steady] = float(np.mean(on))
    assert share[ON.steady_s] < 0.1 and share[0.0] > 0.5, share


class ZigzagShip(TurningShip):
    """TurningShip's camera and start, the ship on fwsim.world.target's zigzag (the truth side's own model): heading
    30 deg + amplitude sin(2 pi t / period) at constant speed (before t = 0, the start's velocity)."""

    def __init__(self, amplitude_deg: float = 30.0, period_s: float = 60.0, **kw):
        super().__init__(turn_deg_s=0.0, **kw)
        self.amp, self.om = math.radians(amplitude_deg), 2.0 * math.pi / period_s
        self._ship = Ship(TargetConfig(
            heading_deg=math.degrees(math.atan2(self.Vq[0], self.Vq[1])), speed_m_s=self.speed,
            motion={"model": "zigzag", "amplitude_deg": amplitude_deg, "period_s": period_s}))

    def ship(self, t):
        st = self._ship.state(max(t, 0.0))
        return st.pos_enu_m + st.vel_enu_m_s * min(t, 0.0)

    def ship_vel(self, t):
        return self._ship.state(max(t, 0.0)).vel_enu_m_s


def test_a_periodic_course_is_fitted_exactly():
    """A line plus a sinusoid, sampled and noised, is recovered: period, amplitude, course and rate."""
    rng = np.random.default_rng(4)
    t = np.arange(0.0, 150.0, 0.5)
    y = 0.2 + 0.004 * t + 0.5 * np.cos(2 * math.pi * t / 73.0 + 0.4) + rng.normal(0.0, 0.01, t.size)
    fit = fit_periodic(t, y, np.ones_like(t), np.arange(20.0, 150.0, 2.0))
    assert fit.period_s == pytest.approx(73.0, abs=0.3)
    assert fit.amplitude_rad == pytest.approx(0.5, abs=0.01) and fit.explained > 0.99
    for tq in (100.0, 149.5, 160.0):  # inside the history and 10 s past its end
        assert fit.course(tq) == pytest.approx(0.2 + 0.004 * tq + 0.5 * math.cos(2 * math.pi * tq / 73.0 + 0.4),
                                               abs=0.02)
        assert fit.rate(tq) == pytest.approx(0.004 - 0.5 * 2 * math.pi / 73.0 * math.sin(2 * math.pi * tq / 73.0
                                                                                          + 0.4), abs=0.002)
    line = fit_periodic(t, 0.2 + 0.004 * t + rng.normal(0.0, 0.01, t.size), np.ones_like(t), np.arange(20.0, 150.0))
    assert line.amplitude_rad < 0.01 and line.explained < 0.5  # noise: nothing for the sinusoid to explain


@pytest.mark.parametrize("amplitude_deg, period_s", [(30.0, 90.0), (-20.0, 60.0)])
def test_a_zigzags_course_is_found_and_followed(amplitude_deg, period_s):
    """A ship zigzagging at 6 m/s seen through the UKF: its periodic course is found once a period is seen
    (period and amplitude), and the state handed on (velocity along the fitted course one filter lag ahead,
    the position's lag taken out) is nearer the ship than the UKF's; held from 240 s on (a dive's 15 s and
    more), the fit still gives the ship's course."""
    truth = ZigzagShip(amplitude_deg, period_s, ship_speed=6.0)
    ukf = UkfTargetEstimator(CAM, UkfConfig())
    turn = CourseTurn(ON)
    rows = []
    for t, meas, cam in orbit_measurements(truth, 270.0, 5):
        est = ukf.step(meas, cam)
        turn.observe(t, est.pos_enu_m, est.vel_enu_m_s, float(max(est.vel_std_m_s[:2])), ukf.pos_vel_cov,
                     1.0 if t >= 240.0 else math.inf)
        if t < 150.0:
            continue
        assert turn.periodic is not None, t
        p, v, w = turn.state(t)
        p_true, v_true = truth.ship(t)[:2], truth.ship_vel(t)[:2]
        rows.append([np.linalg.norm(p[:2] - p_true), np.linalg.norm(v[:2] - v_true),
                     np.linalg.norm(est.pos_enu_m[:2] - p_true), np.linalg.norm(est.vel_enu_m_s[:2] - v_true),
                     w - float(-truth.amp * truth.om * math.cos(truth.om * t)), t >= 240.0])
    r = np.array(rows)
    assert turn.held and turn.periodic.period_s == pytest.approx(period_s, rel=0.05)
    assert math.degrees(turn.periodic.amplitude_rad) == pytest.approx(abs(amplitude_deg), abs=3.0)
    assert rms(r[:, 1]) < 0.2 * rms(r[:, 3])  # the velocity (0.6 -> 0.06 m/s when written)
    assert rms(r[:, 0]) < 0.65 * rms(r[:, 2])  # the position (1.2 -> 0.6 m)
    assert rms(r[:, 4]) < 0.25 * abs(truth.amp * truth.om)  # the turn rate, against its amplitude
    held = r[:, 5] == 1.0
    assert rms(r[held, 1]) < 0.2 * rms(r[held, 3])


def test_a_straight_or_turning_ship_has_no_periodic_course():
    for turn_deg_s in (0.0, 1.0):
        r, turn = fly(turn_deg_s, duration_s=200.0)
        assert turn.periodic is None


def test_the_turn_rate_is_held_while_the_camera_closes_in_and_released_after():
    """Within hold_tgo_s of the ship the fit stops (the dive's view turns the course); past twice it, it resumes."""
    turn = CourseTurn(ON)
    feed(turn, math.radians(1.0), math.radians(0.3))
    held = turn.turn_rad_s
    assert held == pytest.approx(math.radians(1.0), abs=math.radians(0.05))
    for t in np.arange(60.0, 150.0, 0.1):  # the course now turns the other way, fast
        c = 0.3 + math.radians(60.0) - math.radians(2.0) * (t - 60.0)
        tgo = ON.hold_tgo_s - 1.0 if t < 80.0 else 1.5 * ON.hold_tgo_s if t < 90.0 else 2.5 * ON.hold_tgo_s
        turn.observe(t, np.zeros(3), 6.0 * np.array([math.cos(c), math.sin(c), 0.0]), 0.2, None, tgo)
        if t < 90.0:  # held from the first, and still at 1.5 x hold_tgo_s
            assert turn.held and turn.turn_rad_s == held
    assert not turn.held and turn.turn_rad_s == pytest.approx(math.radians(-2.0), abs=math.radians(0.1))


def test_the_state_is_carried_along_the_circle():
    """From the last fused estimate, state() follows the circle of the turn rate at constant speed."""
    turn = CourseTurn(ON)
    feed(turn, math.radians(1.2), math.radians(0.2))
    w = turn.turn_rad_s
    p0, v0 = np.array([10.0, -5.0, 3.0]), np.array([4.0, 3.0, 0.0])
    turn._fused = (40.0, p0, v0)  # a fused, lag-corrected state
    for dt in (0.0, 0.7, 5.0, 30.0):
        p, v, rate = turn.state(40.0 + dt)
        c0, speed = math.atan2(v0[1], v0[0]), 5.0
        c = c0 + w * dt
        exact = p0[:2] + speed / w * np.array([math.sin(c) - math.sin(c0), math.cos(c0) - math.cos(c)])
        assert np.allclose(p[:2], exact, atol=1e-9) and p[2] == 3.0
        assert np.allclose(v[:2], speed * np.array([math.cos(c), math.sin(c)]), atol=1e-12) and rate == w


class _Recorder:
    def __init__(self):
        self.events, self.logs = [], []

    def log(self, topic, msg):
        self.logs.append((topic, msg))

    def event(self, text):
        self.events.append(text)


def test_the_estimation_block_gives_the_turned_state_to_its_readers():
    """Through the estimation block (as the flight software runs it): with the turn on, the state the
    perception and the guidance read has the turn rate and less error than the filter's; off, it is the
    filter's own, number for number."""
    truth = TurningShip(turn_deg_s=1.5)
    rows = []
    blocks = {on: Estimation(UkfTargetEstimator(CAM, UkfConfig()), 120.0, 5, _Recorder(),
                             TurnFromCourseConfig(enabled=on)) for on in (False, True)}
    rngs = {on: np.random.default_rng(5) for on in blocks}
    for k in range(int(120 * 30) + 1):
        t = k / 30.0
        row = [t]
        for on, block in blocks.items():
            meas = truth.sample(t, rngs[on])
            cam = CameraMotion.from_measurements(meas, MOUNT)
            fix = dataclasses.replace(fix_from_measurements(meas), locked=True, lock_now=k == 0)
            block.predict(meas, cam)
            state = block.update(meas, cam, fix)
            est = block.filter.estimate()
            row += [np.linalg.norm(state.vel_enu_m_s[:2] - truth.ship_vel(t)[:2]), state.turn_rate_rad_s,
                    float(np.max(np.abs(state.vel_enu_m_s - est.vel_enu_m_s)))]
        rows.append(row)
    r = np.array(rows)
    late = r[:, 0] >= 60.0
    off, on = r[late, 1:4], r[late, 4:7]
    assert np.all(off[:, 1] == 0.0) and np.all(off[:, 2] == 0.0)  # off: the filter's own state
    assert np.all(np.abs(np.degrees(on[:, 1]) + 1.5) < 0.2)
    assert rms(on[:, 0]) < 0.4 * rms(off[:, 0])
    # the log: /fsw/course_turn with the turn in the scenario's convention (clockwise) and the lag taken out
    status = [m for topic, m in blocks[True]._record.logs if topic == topics.FSW_COURSE_TURN]
    late = [m for m in status if m.t_s >= 60.0]
    assert 100 < len(status) and all(isinstance(m, CourseTurnStatus) for m in status)
    assert all(abs(m.turn_rate_deg_s - 1.5) < 0.2 and not m.held and 0.2 < m.lag_vel_m_s < 1.0 for m in late)
    assert not any(topic == topics.FSW_COURSE_TURN for topic, _ in blocks[False]._record.logs)


def test_it_is_on_by_default_the_scenario_turns_it_off_and_a_bad_setting_is_one_line():
    from controllers.mission import FlightSoftware
    default, _ = load_scenario(SCENARIO_DIR / "paper_mission.yaml")  # on by default
    fsw = FlightSoftware(default.controllers, default.initial, default.camera)
    assert fsw.estimation.turn is not None and fsw.estimation.turn.cfg.window_s == 15.0
    scenario, _ = load_scenario(SCENARIO_DIR / "paper_mission.yaml", {"controllers.turn_from_course.enabled": False,
                                                                      "controllers.turn_from_course.steady_s": 20})
    assert FlightSoftware(scenario.controllers, scenario.initial, scenario.camera).estimation.turn is None
    assert scenario.controllers.turn_from_course.steady_s == 20.0
    base = "name: x\nduration_s: 10\ninitial: {pos_enu_m: [0, 0, 500], airspeed_m_s: 22, heading_deg: 0}\n"
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(base, "x.yaml", {"controllers.turn_from_course.window_s": -3})
    text = str(exc.value)
    assert "\n" not in text and text.startswith("x.yaml: controllers.turn_from_course.window_s"), text


def test_the_time_to_go_and_the_hold_it_sets():
    """closing_time_s: range over closing speed, inf when the camera recedes; held_while_closing: taken under
    hold_tgo_s, kept up to twice it, and a time to go that is not a number changes nothing."""
    cam, cam_v = np.zeros(3), np.array([20.0, 0.0, 0.0])
    assert closing_time_s(np.array([300.0, 0.0, 0.0]), np.array([5.0, 0.0, 0.0]), cam, cam_v) == pytest.approx(20.0)
    assert closing_time_s(np.array([300.0, 0.0, 0.0]), np.array([25.0, 0.0, 0.0]), cam, cam_v) == math.inf
    assert held_while_closing(False, 14.9, 15.0) and not held_while_closing(False, 15.0, 15.0)
    assert held_while_closing(True, 30.0, 15.0) and not held_while_closing(True, 30.1, 15.0)
    assert held_while_closing(True, math.nan, 15.0) and not held_while_closing(False, math.nan, 15.0)
