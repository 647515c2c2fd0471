"""The interacting multiple model estimator (controllers.estimation.imm: the paper's UKF and the CT-UKF, mixed).

Oracles: the IMM's equations by hand on small cases (the Markov chain, the
interaction, the model probabilities); the analytic circle and straight line of
tests/test_manoeuvre_estimator.py's synthetic ship, seen from an orbiting camera,
where the IMM must follow the better of its two models: the CT-UKF on the turn,
the UKF on the straight line.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from test_manoeuvre_estimator import CAM, MOUNT, TurningShip, ct_ukf, fly, rms

from controllers.blocks import TargetEstimator, builtin_names
from controllers.config import CtUkfConfig, ImmConfig
from controllers.estimation.imm import ImmEstimate, ImmTargetEstimator, mix, transition, update_probabilities
from controllers.estimation.ukf import CameraMotion, UkfConfig, UkfTargetEstimator
from fwsim import SCENARIO_DIR
from fwsim.scenario.model import ScenarioError, load_scenario, parse_scenario


def test_the_markov_chain_by_hand():
    """Over dt the ship leaves its mode with probability 1 - exp(-dt / T); rows sum to one; dt = 0 stays."""
    T = transition(6.0, 60.0)
    p = 1.0 - math.exp(-0.1)
    np.testing.assert_allclose(T, [[1.0 - p, p], [p, 1.0 - p]], rtol=1e-12)
    np.testing.assert_allclose(transition(0.0, 60.0), np.eye(2))
    np.testing.assert_allclose(transition(1e6, 60.0).sum(axis=1), [1.0, 1.0])


def test_the_interaction_by_hand():
    """Two one-state models, mu = (0.8, 0.2), a switch probability of 0.1: c = (0.74, 0.26); model 1 starts
    from the mixture with weights 0.72 / 0.74 and 0.02 / 0.74, and its covariance has the spread term."""
    T = np.array([[0.9, 0.1], [0.1, 0.9]])
    mu = np.array([0.8, 0.2])
    xs = [np.array([0.0]), np.array([10.0])]
    Ps = [np.array([[1.0]]), np.array([[4.0]])]
    c, x0, P0 = mix(mu, T, xs, Ps)
    np.testing.assert_allclose(c, [0.74, 0.26])
    w = np.array([0.72, 0.02]) / 0.74  # mu_i|1
    x1 = w[1] * 10.0
    assert x0[0][0] == pytest.approx(x1)
    assert P0[0][0, 0] == pytest.approx(w[0] * (1.0 + x1 ** 2) + w[1] * (4.0 + (10.0 - x1) ** 2))
    w2 = np.array([0.08, 0.18]) / 0.26  # mu_i|2
    assert x0[1][0] == pytest.approx(w2[1] * 10.0)


def test_the_model_probabilities_by_hand():
    """mu ~ c L: likelihoods 2:1 from (0.5, 0.5) give (2/3, 1/3); a floor keeps a losing model alive; a
    missing likelihood leaves c as it is."""
    np.testing.assert_allclose(update_probabilities(np.array([0.5, 0.5]), [math.log(2.0), 0.0], 1e-3),
                               [2.0 / 3.0, 1.0 / 3.0])
    mu = update_probabilities(np.array([0.5, 0.5]), [0.0, -200.0], 1e-3)
    assert mu[1] == pytest.approx(1e-3 / (1.0 + 1e-3)) and mu.sum() == pytest.approx(1.0)
    np.testing.assert_allclose(update_probabilities(np.array([0.3, 0.7]), [0.0, math.nan], 1e-3), [0.3, 0.7])


def imm():
    return ImmTargetEstimator(CAM, UkfConfig())


def test_it_follows_the_ct_ukf_on_a_turn_and_the_ukf_on_a_straight_line():
    """The 1.5 deg/s turn: after 30 s the IMM's position and velocity errors are within 15 % of the
    CT-UKF's (and well under the UKF's, which trails the turn), the manoeuvring model the more probable at
    the end. The straight line: within 20 % (+5 cm, +2 cm/s) of the UKF's, far under the CT-UKF's velocity
    error (whose turn rate wanders with the pixel noise), the steady model the more probable. Measured
    (position / velocity RMS, m, m/s; seeds 1, 2): the turn 0.59 / 0.29 and 0.57 / 0.29 against the CT-UKF's
    0.60 / 0.29 and 0.58 / 0.30 and the UKF's 1.10 / 0.53 and 1.06 / 0.54; the straight line 0.44 / 0.11
    and 0.39 / 0.10 against the UKF's 0.42 / 0.08 and 0.37 / 0.08 and the CT-UKF's 0.61 / 0.28 and
    0.59 / 0.29."""
    for turn in (1.5, 0.0):
        ship = TurningShip(turn_deg_s=turn)
        for seed in (1, 2):
            est = imm()
            mm = fly(est, ship, seed=seed)
            ct = fly(ct_ukf(), ship, seed=seed)
            cv = fly(UkfTargetEstimator(CAM, UkfConfig()), ship, seed=seed)
            late = mm[:, 0] >= 30.0
            pos = [rms(r[late, 1]) for r in (mm, ct, cv)]
            vel = [rms(r[late, 2]) for r in (mm, ct, cv)]
            if turn:
                assert pos[0] < 1.15 * pos[1] and vel[0] < 1.15 * vel[1], (seed, pos, vel)
                assert pos[0] < 0.7 * pos[2] and vel[0] < 0.7 * vel[2], (seed, pos, vel)
                assert est.manoeuvre_probability > 0.5
            else:
                assert pos[0] < 1.2 * pos[2] + 0.05 and vel[0] < 1.2 * vel[2] + 0.02, (seed, pos, vel)
                assert vel[0] < 0.6 * vel[1], (seed, pos, vel)
                assert est.manoeuvre_probability < 0.5


def test_the_estimate_message_the_protocol_and_a_reset():
    """An ImmEstimate (a ManoeuvreEstimate with the manoeuvring model's probability) from the first detection;
    it implements the Protocol; either model resetting itself takes the other down too."""
    f = imm()
    assert isinstance(f, TargetEstimator)
    ship = TurningShip()
    rng = np.random.default_rng(5)
    meas = ship.sample(0.0, rng)
    est = f.step(meas, CameraMotion.from_measurements(meas, MOUNT))
    assert isinstance(est, ImmEstimate) and est.manoeuvre_probability == pytest.approx(0.5)
    assert est.turn_rate_rad_s == 0.0 and np.isfinite(est.pos_std_m).all()
    assert f.status(0.0).initialisations == 1
    f.ct.reset()  # as a model does when its state is no longer finite
    assert not f.initialised and f.cv.initialised
    meas = ship.sample(1 / 30, rng)
    f.predict(meas.t_s, CameraMotion.from_measurements(meas, MOUNT))
    assert not f.cv.initialised  # the other model went down with it
    assert math.isnan(f.estimate().pos_enu_m[0])
    est = f.step(meas, CameraMotion.from_measurements(meas, MOUNT))  # the next detection starts both again
    assert f.cv.initialised and f.ct.initialised and f.status(0.0).initialisations == 2
    assert est.manoeuvre_probability == pytest.approx(0.5)


def test_the_scenario_selects_it_and_its_settings():
    scenario, _ = load_scenario(SCENARIO_DIR / "paper_mission.yaml", {
        "controllers.estimator": "imm", "controllers.imm.switch_time_s": 30.0,
        "controllers.ct_ukf.turn_rate_std_deg_s": 2.0})
    assert "imm" in builtin_names("estimator")
    from controllers.mission import FlightSoftware
    fsw = FlightSoftware(scenario.controllers, scenario.initial, scenario.camera)
    fsw.close()  # (its NMPC worker: only the estimator is looked at)
    f = fsw.estimation.filter
    assert type(f) is ImmTargetEstimator and fsw.estimation.label == "IMM"
    assert f.cfg.switch_time_s == 30.0 and f.ct.ct_cfg.turn_rate_std_deg_s == 2.0
    assert f.tracked_height_m == scenario.controllers.ukf.target_plane_height_m == 3.75
    base = "name: x\nduration_s: 10\ninitial: {pos_enu_m: [0, 0, 500], airspeed_m_s: 22, heading_deg: 0}\n" \
           "controllers: {estimator: imm}\n"
    for override, message in (({"controllers.imm.switch_time_s": 0.0}, "controllers.imm.switch_time_s"),
                              ({"controllers.imm.prior_manoeuvring": 1.0}, "controllers.imm.prior_manoeuvring")):
        with pytest.raises(ScenarioError) as exc:
            parse_scenario(base, "x.yaml", override)
        assert "\n" not in str(exc.value) and str(exc.value).startswith("x.yaml: " + message), str(exc.value)
    for name, field in ImmConfig.model_fields.items():
        assert field.description, name


def test_the_models_probabilities_are_held_with_the_manoeuvre():
    """While the CT-UKF holds its manoeuvre (the dive), the models neither mix nor reweigh
    (hold_with_manoeuvre, the default): the probabilities stay as they were over 3 s of detections; with the
    option off the detections reweigh them."""
    ship = TurningShip()
    for hold in (True, False):
        # (hold_tgo_s 0: the CT-UKF neither holds nor releases by itself; the test holds it)
        f = ImmTargetEstimator(CAM, UkfConfig(), CtUkfConfig(hold_tgo_s=0.0), ImmConfig(hold_with_manoeuvre=hold))
        rng = np.random.default_rng(3)
        for k in range(20 * 30):  # 20 s: the models weighed
            meas = ship.sample(k / 30.0, rng)
            f.step(meas, CameraMotion.from_measurements(meas, MOUNT))
        f.ct._hold()  # as its predict does when the camera closes in
        mu0 = f.mu.copy()
        for k in range(20 * 30, 23 * 30):
            meas = ship.sample(k / 30.0, rng)
            f.step(meas, CameraMotion.from_measurements(meas, MOUNT))
            assert f.ct.held
        assert np.array_equal(f.mu, mu0) == hold, (hold, mu0, f.mu)
