"""The manoeuvring-ship estimator (controllers.estimation.ct_ukf: the UKF with turn rate and along-track acceleration).

Oracles: the analytic circle of a ship turning at 1.5 deg/s (and the straight
line of tests/test_ukf.py's constant-velocity ship), seen from a camera
orbiting it (synthetic poses and pixels, as tests/test_ukf.py drives the
UKF); the paper's UKF on the same measurements as the reference to beat (turn)
or to match within a stated margin (straight line). The closed loop (whole paper
missions against turning ships) is behind ``-m slow``.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from test_ukf import CAM, MOUNT, OrbitTruth

from controllers.blocks import TargetEstimator, builtin_names
from controllers.config import CtUkfConfig
from controllers.estimation.ct_ukf import CtUkfTargetEstimator, ManoeuvreEstimate, fx_ct_batch
from controllers.estimation.ukf import CameraMotion, UkfConfig, UkfTargetEstimator
from controllers.messages import TargetEstimate
from controllers.ship_motion import predict_ctra
from fwsim import SCENARIO_DIR
from fwsim.interface import frames as F
from fwsim.scenario.model import ScenarioError, load_scenario, parse_scenario

TURN_DEG_S = 1.5  # the ship's heading rate (clockwise seen from above, as fwsim.world.target's constant_turn)


class TurningShip(OrbitTruth):
    """OrbitTruth's ship on a circle: 5 m/s, heading 30 deg + 1.5 deg/s * t; the UAV circles it (R, H)."""

    def __init__(self, turn_deg_s: float = TURN_DEG_S, **kw):
        super().__init__(**kw)
        self.w_enu = -math.radians(turn_deg_s)  # counter-clockwise about up
        self.speed = float(np.linalg.norm(self.Vq))
        self.course0 = math.atan2(self.Vq[1], self.Vq[0])  # ENU course angle at t = 0

    def ship(self, t):
        if self.w_enu == 0.0:
            return self.Vq * t
        c0, c = self.course0, self.course0 + self.w_enu * t
        return self.speed / self.w_enu * np.array([math.sin(c) - math.sin(c0), math.cos(c0) - math.cos(c), 0.0])

    def ship_vel(self, t):
        c = self.course0 + self.w_enu * t
        return self.speed * np.array([math.cos(c), math.sin(c), 0.0])

    def uav(self, t):
        a = math.pi + self.Om * t
        pos = self.ship(t) + np.array([self.R * math.cos(a), self.R * math.sin(a), self.H])
        vel = self.ship_vel(t) + self.R * self.Om * np.array([-math.sin(a), math.cos(a), 0.0])
        return pos, vel, np.array([self.roll, 0.0, math.atan2(vel[0], vel[1])])


def orbit_measurements(truth, duration_s, seed):
    """30 Hz measurements of ``truth`` (a detection each tick, the GNSS error held over 3 ticks):
    yields (t, measurements, camera motion)."""
    rng = np.random.default_rng(seed)
    for k in range(int(duration_s * 30) + 1):
        t = k / 30.0
        if k % 3 == 0:
            gnss_err = rng.normal(0, 0.5, 3)
        meas = truth.sample(t, rng, gnss_err=gnss_err)
        yield t, meas, CameraMotion.from_measurements(meas, MOUNT)


def fly(estimator, truth, duration_s=75.0, seed=7):
    """Feed the estimator 30 Hz measurements (a detection each tick, GNSS held over 3) -> rows (t, position
    error, velocity error, turn rate estimate or NaN), horizontal."""
    rows = []
    for t, meas, cam in orbit_measurements(truth, duration_s, seed):
        est = estimator.step(meas, cam)
        rows.append((t, np.linalg.norm(est.pos_enu_m[:2] - truth.ship(t)[:2]),
                     np.linalg.norm(est.vel_enu_m_s[:2] - truth.ship_vel(t)[:2]),
                     getattr(est, "turn_rate_rad_s", math.nan)))
    return np.array(rows)


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


def ct_ukf():
    return CtUkfTargetEstimator(CAM, UkfConfig(), CtUkfConfig())


# ---------------------------------------------------------------- the process model


def test_the_process_model_flies_the_analytic_circle():
    """Sigma points with a turn rate and no acceleration (compiled RK4, the filter's process model) and
    predict_ctra both follow the exact circle over 20 s; the acceleration moves the speed along the track."""
    ship = TurningShip()
    w = ship.w_enu
    x = np.concatenate([[0.01, -0.02], ship.ship(0.0), ship.ship_vel(0.0), [w, 0.0]])
    _, R = F.camera_pose_world(np.array([-500.0, 0.0, 500.0]), np.zeros(3), MOUNT, 0.0, -0.7)
    S = np.tile(x, (21, 1))
    for _ in range(20):  # 20 s in 1 s predicts, correlation times long: the rate barely decays
        S = fx_ct_batch(S, 1.0, np.array([-500.0, 0.0, 500.0]), R, np.zeros(3), np.zeros(3), 0.05, 1e9, 1e9, 0.5)
    np.testing.assert_allclose(S[0, 2:5], ship.ship(20.0), atol=1e-6)
    np.testing.assert_allclose(S[0, 5:8], ship.ship_vel(20.0), atol=1e-7)
    p, v = predict_ctra(ship.ship(0.0), ship.ship_vel(0.0), w, 0.0, 20.0)
    np.testing.assert_allclose(p, ship.ship(20.0), atol=1e-5)
    np.testing.assert_allclose(v, ship.ship_vel(20.0), atol=1e-6)
    # along-track acceleration: straight ahead, speed 5 -> 7 m/s in 4 s at 0.5 m/s^2, 24 m covered
    p, v = predict_ctra(np.zeros(3), [3.0, 4.0, 0.0], 0.0, 0.5, 4.0)
    np.testing.assert_allclose(v, [0.6 * 7.0, 0.8 * 7.0, 0.0], atol=1e-9)
    np.testing.assert_allclose(p, [0.6 * 24.0, 0.8 * 24.0, 0.0], atol=1e-9)


def test_the_manoeuvre_fades_near_rest_and_not_above_the_fade_speed():
    """A slow ship's estimate with a deceleration: without the fade, zero speed attracts it (V_dot = a V /
    min_speed) and the deceleration, which then moves nothing, stays for its 20 s correlation time; with the
    fade (default 2 m/s, 2 s) the turn rate and the deceleration revert within seconds and the speed stays
    up. Above the fade speed the two models are the same."""
    from controllers.config import CtUkfConfig
    c = CtUkfConfig()
    assert c.manoeuvre_fade_speed_m_s > 0.0
    _, R = F.camera_pose_world(np.array([-500.0, 0.0, 500.0]), np.zeros(3), MOUNT, 0.0, -0.7)

    def fly(v0, fade_speed, seconds=10):
        x = np.array([0.01, -0.02, 0.0, 0.0, 0.0, v0, 0.0, 0.0, math.radians(3.0), -0.3])
        S = np.tile(x, (21, 1))
        for _ in range(seconds):
            S = fx_ct_batch(S, 1.0, np.array([-500.0, 0.0, 500.0]), R, np.zeros(3), np.zeros(3), 0.05,
                            c.turn_rate_time_s, c.accel_time_s, c.min_speed_m_s, fade_speed,
                            c.manoeuvre_fade_time_s)
        return S[0]

    no_fade, fade = fly(1.0, 0.0), fly(1.0, c.manoeuvre_fade_speed_m_s)
    assert np.hypot(*no_fade[5:7]) < 0.05 and no_fade[9] < -0.15  # stuck at rest, still decelerating
    assert np.hypot(*fade[5:7]) > 0.3 and abs(fade[9]) < 0.02 and abs(fade[8]) < math.radians(0.2)
    fast_no_fade, fast_fade = fly(8.0, 0.0, 3), fly(8.0, c.manoeuvre_fade_speed_m_s, 3)  # 8 -> 7.1 m/s
    np.testing.assert_allclose(fast_fade, fast_no_fade, rtol=0, atol=1e-12)
    # predict_ctra is the same model
    p, v = predict_ctra(np.zeros(3), [1.0, 0.0, 0.0], math.radians(3.0), -0.3, 10.0, c.turn_rate_time_s,
                        c.accel_time_s, c.min_speed_m_s, c.manoeuvre_fade_speed_m_s, c.manoeuvre_fade_time_s)
    np.testing.assert_allclose(v[:2], fade[5:7], atol=1e-3)


# ---------------------------------------------------------------- tracking: turn and straight line


def test_it_tracks_a_turning_ship_where_the_ukf_lags():
    """A ship on a 1.5 deg/s turn (a 190 m circle), 75 s from an orbit at R = H = 500 m: after 30 s the
    position error is under 0.8 m RMS and at most 0.7 times the UKF's (which trails the turn: ~1.15 m RMS
    here), the velocity error at most 0.7 times the UKF's, and the turn rate is learnt to 0.3 deg/s."""
    ship = TurningShip()
    for seed in (1, 2):
        ct, cv = fly(ct_ukf(), ship, seed=seed), fly(UkfTargetEstimator(CAM, UkfConfig()), ship, seed=seed)
        late = ct[:, 0] >= 30.0
        pos_ct, pos_cv = rms(ct[late, 1]), rms(cv[late, 1])
        vel_ct, vel_cv = rms(ct[late, 2]), rms(cv[late, 2])
        assert pos_ct < 0.8 and pos_ct < 0.7 * pos_cv, (seed, pos_ct, pos_cv)
        assert vel_ct < 0.7 * vel_cv, (seed, vel_ct, vel_cv)
        assert pos_cv > 0.9  # the UKF does lag (the case tells the two apart)
        w_deg = np.degrees(np.mean(ct[ct[:, 0] >= 40.0, 3]))
        assert w_deg == pytest.approx(-TURN_DEG_S, abs=0.3), w_deg  # ENU: clockwise is negative


#: how much worse than the UKF it may be on the UKF's own case (a straight-running ship), after 30 s
STRAIGHT_POS_MARGIN_M = 0.4
STRAIGHT_VEL_MARGIN_M_S = 0.35


def test_on_a_straight_line_it_is_within_a_stated_margin_of_the_ukf():
    """The constant-velocity ship (the paper's case, the UKF's model): the turn-rate and acceleration states
    cost at most STRAIGHT_POS_MARGIN_M of position and STRAIGHT_VEL_MARGIN_M_S of velocity error (RMS after
    30 s; measured ~0.2 m and ~0.2 m/s), and it learns no turn."""
    ship = TurningShip(turn_deg_s=0.0)
    for seed in (1, 2):
        ct, cv = fly(ct_ukf(), ship, seed=seed), fly(UkfTargetEstimator(CAM, UkfConfig()), ship, seed=seed)
        late = ct[:, 0] >= 30.0
        assert rms(ct[late, 1]) < rms(cv[late, 1]) + STRAIGHT_POS_MARGIN_M, (seed, rms(ct[late, 1]),
                                                                            rms(cv[late, 1]))
        assert rms(ct[late, 2]) < rms(cv[late, 2]) + STRAIGHT_VEL_MARGIN_M_S
        assert abs(np.degrees(np.mean(ct[late, 3]))) < 0.3


# ---------------------------------------------------------------- the hold in a dive, the estimate message


def test_the_manoeuvre_is_held_while_the_camera_closes_in_and_released_after():
    """Closing on the ship within hold_tgo_s: the turn rate is kept, the acceleration set to zero, and a
    detection moves neither; receding: released with the covariance it had."""
    ship = TurningShip()
    rng = np.random.default_rng(4)
    f = ct_ukf()
    g = CtUkfTargetEstimator(CAM, UkfConfig(), CtUkfConfig(hold_turn_rate=False))  # holds only the speed
    for k in range(int(40 * 30) + 1):
        t = k / 30.0
        meas = ship.sample(t, rng)
        f.step(meas, CameraMotion.from_measurements(meas, MOUNT))
        g.step(meas, CameraMotion.from_measurements(meas, MOUNT))
    assert not f.held and f.holds == 0  # an orbit does not close in
    w_before, std_before = f.turn_rate_rad_s, np.sqrt(np.diag(f.cov)[8:])
    t = 40.0 + 1 / 30
    meas = ship.sample(t, rng)
    motion = CameraMotion.from_measurements(meas, MOUNT)
    los = f.pos_enu_m - motion.pos_enu_m
    diving = dataclasses.replace(motion, vel_enu_m_s=ship.ship_vel(t) + 60.0 * los / np.linalg.norm(los))
    assert f.time_to_go_s(diving) < f.ct_cfg.hold_tgo_s
    f.predict(t, diving)
    assert f.held and f.holds == 1 and f.accel_along_m_s2 == 0.0
    assert f.turn_rate_rad_s == pytest.approx(w_before, abs=1e-4)
    est = f.estimate()  # the stds as when held (one predict on: within a percent)
    held_std = np.array([est.turn_rate_std_rad_s, est.accel_along_std_m_s2])
    assert est.manoeuvre_held and np.allclose(held_std, std_before, rtol=0.01)
    assert np.all(np.sqrt(np.diag(f.cov)[8:]) < 1e-2 * held_std)  # set aside: the detections cannot move them
    biased = dataclasses.replace(meas, det_u_px=meas.det_u_px + 8.0)
    from controllers.estimation.ukf import fix_from_measurements
    assert f.update(fix_from_measurements(biased), diving).used
    assert f.turn_rate_rad_s == pytest.approx(w_before, abs=1e-4) and abs(f.accel_along_m_s2) < 1e-6
    receding = dataclasses.replace(motion, vel_enu_m_s=ship.ship_vel(t) - 20.0 * los / np.linalg.norm(los))
    f.predict(t + 1 / 30, receding)
    assert not f.held
    np.testing.assert_allclose(np.sqrt(np.diag(f.cov)[8:]), held_std, rtol=1e-6)
    # hold_turn_rate false: only the speed is held, the turn rate goes on being learnt
    var_turn = g.cov[8, 8]
    g.predict(t, diving)
    assert g.held and g.held_states == (9,) and g.accel_along_m_s2 == 0.0
    assert g.cov[8, 8] == pytest.approx(var_turn, rel=0.01) and g.cov[9, 9] < 1e-6


def test_the_estimate_is_a_target_estimate_with_the_manoeuvre_and_logs():
    """Every consumer of TargetEstimate reads it (a subclass, fields added at the end); the log's JSON schema
    is made from it; it implements the Protocol as the UKF does."""
    from fwsim.log.schema import spec_for
    f = ct_ukf()
    assert isinstance(f, TargetEstimator) and isinstance(f, UkfTargetEstimator)
    ship = TurningShip()
    rng = np.random.default_rng(5)
    meas = ship.sample(0.0, rng)
    est = f.step(meas, CameraMotion.from_measurements(meas, MOUNT))
    assert isinstance(est, ManoeuvreEstimate) and isinstance(est, TargetEstimate)
    assert est.turn_rate_rad_s == 0.0 and est.turn_rate_std_rad_s == pytest.approx(math.radians(1.5))
    assert est.accel_along_std_m_s2 == pytest.approx(0.3)
    names = spec_for(ManoeuvreEstimate).names
    assert names[:8] == tuple(fl.name for fl in dataclasses.fields(TargetEstimate))
    assert "turn_rate_rad_s" in names and "accel_along_m_s2" in names
    assert f.status(0.0).initialisations == 1


# ---------------------------------------------------------------- the scenario


def test_the_scenario_selects_it_and_its_settings():
    scenario, _ = load_scenario(SCENARIO_DIR / "paper_mission.yaml", {
        "controllers.estimator": "ct_ukf", "controllers.ct_ukf.turn_rate_std_deg_s": 2.0})
    assert "ct_ukf" in builtin_names("estimator")
    from controllers.mission import FlightSoftware
    fsw = FlightSoftware(scenario.controllers, scenario.initial, scenario.camera)
    f = fsw.estimation.filter
    assert type(f) is CtUkfTargetEstimator and fsw.estimation.label == "CT-UKF"
    assert f.ct_cfg.turn_rate_std_deg_s == 2.0
    # the measurement model's settings are the scenario's ukf section (the paper mission's aim-point plane)
    assert f.tracked_height_m == scenario.controllers.ukf.target_plane_height_m == 3.75
    # the default stays the paper's UKF
    default, _ = load_scenario(SCENARIO_DIR / "paper_mission.yaml")
    assert default.controllers.estimator.use == "ukf"
    assert type(FlightSoftware(default.controllers, default.initial, default.camera).estimation.filter) \
        is UkfTargetEstimator


@pytest.mark.parametrize("override, message", [
    ({"controllers.ct_ukf.turn_rate_std_deg_s": -1.0}, "controllers.ct_ukf.turn_rate_std_deg_s"),
    ({"controllers.ct_ukf.turn_rate_time": 30.0}, "controllers.ct_ukf.turn_rate_time"),
    ({"controllers.estimator": {"use": "ct_ukf", "options": {"accel_std_m_s2": 0.2}}},
     "controllers.estimator: options are for a user's class"),
])
def test_a_bad_setting_is_a_one_line_scenario_error(override, message):
    base = "name: x\nduration_s: 10\ninitial: {pos_enu_m: [0, 0, 500], airspeed_m_s: 22, heading_deg: 0}\n" \
           "controllers: {estimator: ct_ukf}\n"
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(base, "x.yaml", override)
    text = str(exc.value)
    assert "\n" not in text and text.startswith("x.yaml: " + message), text


def test_config_defaults_ranges_and_descriptions():
    cfg = CtUkfConfig.model_validate({})
    assert cfg.turn_rate_std_deg_s == 1.5 and cfg.hold_tgo_s == 15.0
    for name, field in CtUkfConfig.model_fields.items():
        assert field.description and field.default is not None, name
        assert field.annotation is bool or any(hasattr(m, "gt") or hasattr(m, "ge") for m in field.metadata), name


# ---------------------------------------------------------------- closed loop (slow)


@pytest.mark.slow
def test_paper_mission_against_a_turning_ship_hits_with_both_estimators(tmp_path):
    """The whole paper mission against a ship turning at 1.5 deg/s: the UKF and the CT-UKF both hit, both
    estimates within the paper's 8 m (RMSE after convergence), the CT-UKF's within half as much again as the
    UKF's (seed 21, not tuned on). The CT-UKF's was the better one (2.4 against 6.2 m) until the box shapes
    followed the course and the size fit weighed its boxes at 3 Hz, which brought the UKF's to 2.0 m (the
    CT-UKF's stayed at 2.4 m; misses 2.9 and 2.6 m)."""
    from fwsim.sim.loop import run
    from fwsim.analysis.metrics import compute_metrics
    out = {}
    for est in ("ukf", "ct_ukf"):
        scenario, text = load_scenario(SCENARIO_DIR / "paper_mission.yaml", {
            "seed": 21, "controllers.estimator": est,
            "target.motion": {"model": "constant_turn", "turn_rate_deg_s": TURN_DEG_S}})
        res = run(scenario, text, tmp_path / f"{est}.mcap")
        out[est] = compute_metrics(res.log_path)
        assert out[est]["hit"] == 1.0, (est, out[est]["miss_distance_m"])
    rmse = {est: out[est]["estimator_pos_rmse_after_convergence_m"] for est in out}
    assert max(rmse.values()) < 8.0 and rmse["ct_ukf"] < 1.5 * rmse["ukf"], rmse
