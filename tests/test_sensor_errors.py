"""Sensor error models (fwsim.sensors.errors): the statistics of each term, timing, determinism, faults."""
import math
from dataclasses import fields

import allantools
import annotated_types as at
import numpy as np
import pytest
from pydantic import BaseModel, ValidationError

from fwsim.interface.frames import dcm_ned_from_frd
from fwsim.interface.messages import AirframeState
from fwsim.sensors.allan import avar_gauss_markov, avar_random_walk, avar_white
from fwsim.sensors.errors import (
    PROFILES, BaroModel, CameraMountError, EncoderModel, GaussMarkov, GnssModel, ImuModel, MagModel, PitotModel,
    RandomWalk, SensorErrorModels, SensorErrorsConfig, WhiteNoise, degraded, ideal, resolve, typical)
from fwsim.sensors.onboard import rng_for

SIM_DT = 1.0 / 120.0
ALLAN_DT = 0.01  # 100 Hz
ALLAN_STEPS = int(2.5 * 3600 / ALLAN_DT)  # 2.5 h of samples


def truth(t, w=(0.0, 0.0, 0.0), f=(0.0, 0.0, -9.81), pos=(0.0, 0.0, 100.0), vel=(0.0, 0.0, 0.0),
          euler=(0.0, 0.0, 0.0), airspeed=20.0):
    a = np.asarray
    return AirframeState(t, a(pos, float), a(vel, float), a(euler, float), a(w, float), airspeed, 0.05, 0.0,
                         a(f, float), 0.5, np.zeros(3), float(pos[2]))


def moving_truth(t):
    """A truth that moves, turns and accelerates, smooth in t."""
    return truth(t, w=(0.3 * math.sin(t), 0.1 * math.cos(2 * t), 0.05 + 0.02 * t),
                 f=(1.0 + math.sin(t), 0.2 * math.cos(t), -9.81 + 0.5 * math.sin(3 * t)),
                 pos=(10.0 * t, -5.0 * t, 100.0 + 0.5 * t), vel=(10.0, -5.0, 0.5),
                 euler=(0.2 * math.sin(t), 0.05, 0.1 * t), airspeed=18.0 + math.sin(t))


# --------------------------------------------------------------------------- Allan deviation


def stationary_imu(cfg, seed=11):
    """2.5 h of a still IMU at 100 Hz: (gyro rate, accel specific force) samples, (N, 3) each."""
    imu = ImuModel(cfg, seed)
    w = np.zeros((ALLAN_STEPS + 1, 3))
    f = np.tile([0.0, 0.0, -9.81], (ALLAN_STEPS + 1, 1))
    dth, dv = imu.integrate(ALLAN_DT, w, f)
    return dth / ALLAN_DT, dv / ALLAN_DT


def pooled_adev(rates, taus):
    """Overlapping Allan deviation (allantools) at each tau, the three axes' variances pooled (they are
    independent and alike)."""
    avar = []
    for k in range(rates.shape[1]):
        t, adev, _, _ = allantools.oadev(rates[:, k], rate=1.0 / ALLAN_DT, data_type="freq", taus=list(taus))
        avar.append(adev ** 2)
    return np.asarray(t), np.sqrt(np.mean(avar, axis=0))


def test_allan_deviation_at_one_second_is_the_noise_density():
    """In-run biases off (a constant turn-on bias does not show): the Allan deviation at 1 s is the noise density."""
    cfg = resolve("typical", {"imu.gyro.bias_random_walk_rad_s2_sqrt_hz": 0.0,
                              "imu.accel.bias_random_walk_m_s3_sqrt_hz": 0.0})
    gyro, accel = stationary_imu(cfg.imu)
    _, g = pooled_adev(gyro, [1.0])
    _, a = pooled_adev(accel, [1.0])
    assert g[0] == pytest.approx(cfg.imu.gyro.noise_density_rad_s_sqrt_hz, rel=0.2)
    assert a[0] == pytest.approx(cfg.imu.accel.noise_density_m_s2_sqrt_hz, rel=0.2)


@pytest.mark.parametrize("triad, tau_bias_s", [("gyro", 60.0), ("accel", 30.0)])
def test_allan_deviation_follows_the_noise_and_gauss_markov_bias_curve(triad, tau_bias_s):
    """The typical IMU: at 1 s the white noise (plus what little the bias adds), at tau_bias_s the Gauss-Markov
    bias (over 90 % of the Allan variance there), each within 20 % of the analytic curve."""
    cfg = typical().imu
    c = getattr(cfg, triad)
    density = c.noise_density_rad_s_sqrt_hz if triad == "gyro" else c.noise_density_m_s2_sqrt_hz
    k = c.bias_random_walk_rad_s2_sqrt_hz if triad == "gyro" else c.bias_random_walk_m_s3_sqrt_hz
    rates = stationary_imu(cfg)[0 if triad == "gyro" else 1]
    taus, adev = pooled_adev(rates, [1.0, tau_bias_s])
    white, bias = avar_white(density, taus), avar_gauss_markov(k, c.bias_tau_s, taus)
    assert bias[1] > 0.9 * (white[1] + bias[1])  # the bias dominates at tau_bias_s
    assert np.allclose(adev, np.sqrt(white + bias), rtol=0.2), (adev, np.sqrt(white + bias))
    if triad == "gyro":  # at 1 s the gyro's curve is its noise density (the bias adds 0.4 % of the variance)
        assert adev[0] == pytest.approx(density, rel=0.2)


def test_allan_deviation_of_a_random_walk_bias():
    """bias_model random_walk: the rate-random-walk slope K sqrt(tau / 3) where it dominates."""
    cfg = resolve("typical", {"imu.gyro.bias_model": "random_walk"}).imu
    gyro, _ = stationary_imu(cfg)
    taus, adev = pooled_adev(gyro, [100.0])
    k = cfg.gyro.bias_random_walk_rad_s2_sqrt_hz
    expected = np.sqrt(avar_white(cfg.gyro.noise_density_rad_s_sqrt_hz, taus) + avar_random_walk(k, taus))
    assert adev[0] == pytest.approx(expected[0], rel=0.2)
    assert avar_random_walk(k, 100.0) > 0.9 * expected[0] ** 2


def test_gauss_markov_allan_variance_limits():
    """The closed form and its small-x series agree, and the curve has its two asymptotes."""
    k, tc = 0.01, 100.0
    below, above = avar_gauss_markov(k, tc, 0.05 * tc * (1 - 1e-9)), avar_gauss_markov(k, tc, 0.05 * tc * (1 + 1e-9))
    assert below == pytest.approx(above, rel=1e-6)
    assert avar_gauss_markov(k, tc, 0.01) == pytest.approx(avar_random_walk(k, 0.01), rel=1e-3)
    assert avar_gauss_markov(k, tc, 1e6) == pytest.approx(k ** 2 * tc ** 2 / 1e6, rel=1e-3)


# --------------------------------------------------------------------------- error processes


def test_gauss_markov_process_statistics_and_batch_equals_steps():
    tau, sigma, dt = 2.0, 1.5, 0.1
    gm = GaussMarkov(tau, sigma, rng_for(3, "test/gm"), n=4, stationary_start=True)
    x = gm.propagate(dt, 400_000)
    assert np.allclose(x.std(axis=0), sigma, rtol=0.05)
    lag = int(round(tau / dt))
    xc = x - x.mean(axis=0)
    acf = np.mean(xc[lag:] * xc[:-lag], axis=0) / np.mean(xc * xc, axis=0)
    assert np.allclose(acf, math.exp(-1.0), atol=0.03)
    a = GaussMarkov(tau, sigma, rng_for(4, "test/gm"), n=3, stationary_start=True)
    b = GaussMarkov(tau, sigma, rng_for(4, "test/gm"), n=3, stationary_start=True)
    steps = np.array([a.propagate(dt) for _ in range(50)])
    assert np.allclose(steps, b.propagate(dt, 50), rtol=0, atol=1e-12)


def test_random_walk_and_white_noise_scale_with_dt():
    """Random walk: variance K^2 T after T seconds; white noise: N / sqrt(dt) as a rate, N sqrt(dt) integrated."""
    k, dt, steps = 0.2, 0.05, 200
    rw = RandomWalk(k, rng_for(5, "test/rw"), n=20_000)
    end = rw.propagate(dt, steps)[-1]
    assert end.std() == pytest.approx(k * math.sqrt(dt * steps), rel=0.03)
    wn = WhiteNoise(0.1, rng_for(6, "test/wn"), n=3)
    assert wn.rate(0.01, 100_000).std() == pytest.approx(0.1 / math.sqrt(0.01), rel=0.02)
    assert wn.integrated(0.01, 100_000).std() == pytest.approx(0.1 * math.sqrt(0.01), rel=0.02)


def test_turn_on_bias_scale_factor_and_misalignment_are_drawn_at_their_sigmas():
    cfg = typical().imu
    models = [ImuModel(cfg, seed) for seed in range(600)]
    turn_on = np.array([m.gyro.turn_on for m in models])
    scale = np.array([np.diag(m.gyro.matrix) - 1.0 for m in models])
    off = np.array([m.accel.matrix[~np.eye(3, dtype=bool)] for m in models])  # (I + M)(I + S): M (1 + s) ~ M
    assert turn_on.std() == pytest.approx(cfg.gyro.turn_on_bias_sigma_rad_s, rel=0.1)
    assert scale.std() == pytest.approx(cfg.gyro.scale_factor_sigma_frac, rel=0.1)
    assert off.std() == pytest.approx(cfg.accel.misalignment_sigma_rad, rel=0.1)
    imu = models[0]  # and the matrix is what a constant rate meets
    w = np.array([0.5, -0.2, 0.1])
    matrix_only = resolve("ideal", {"imu.gyro.scale_factor_sigma_frac": cfg.gyro.scale_factor_sigma_frac,
                                    "imu.gyro.misalignment_sigma_rad": cfg.gyro.misalignment_sigma_rad})
    only_matrix = ImuModel(matrix_only.imu, 0)
    dth, _ = only_matrix.integrate(0.01, np.tile(w, (3, 1)), np.zeros((3, 3)))
    assert np.allclose(dth, only_matrix.gyro.matrix @ w * 0.01, rtol=0, atol=1e-15)
    assert np.array_equal(only_matrix.gyro.matrix, imu.gyro.matrix)  # its own generators: same draws


# --------------------------------------------------------------------------- IMU


def test_imu_step_equals_integrate_and_times_its_samples():
    ts = np.arange(201) * SIM_DT
    states = [moving_truth(t) for t in ts]
    a, b = ImuModel(typical().imu, 9), ImuModel(typical().imu, 9)
    samples = [a.step(s) for s in states]
    assert samples[0] is None
    dth, dv = b.integrate(SIM_DT, np.array([s.body_rates_frd_rad_s for s in states]),
                          np.array([s.specific_force_frd_m_s2 for s in states]))
    assert np.allclose([s.delta_angle_frd_rad for s in samples[1:]], dth, rtol=0, atol=1e-12)
    assert np.allclose([s.delta_velocity_frd_m_s for s in samples[1:]], dv, rtol=0, atol=1e-12)
    assert [s.t_s for s in samples[1:]] == list(ts[1:])
    assert np.allclose([s.dt_s for s in samples[1:]], SIM_DT, rtol=1e-9)


# --------------------------------------------------------------------------- GNSS


def run_gnss(model, t_end, hz=120.0, truth_at=moving_truth, on_step=None):
    """(step time, fix) for every fix delivered while stepping the model at hz up to t_end."""
    out = []
    for k in range(int(round(t_end * hz)) + 1):
        t = k / hz
        if on_step is not None:
            on_step(t, model)
        out += [(t, fix) for fix in model.step(truth_at(t))]
    return out


def test_gnss_position_error_is_gauss_markov_with_its_tau_and_sigma():
    """Lag-tau autocorrelation exp(-1), std sigma (short tau so that the run spans a thousand of them)."""
    cfg = resolve("typical", {"gnss": {"rate_hz": 10.0, "latency_s": 0.0,
                                       "pos_horizontal_tau_s": 2.0, "pos_vertical_tau_s": 2.0,
                                       "pos_horizontal_sigma_m": 2.0, "pos_vertical_sigma_m": 3.0}}).gnss
    fixes = run_gnss(GnssModel(cfg, 21), 2000.0, hz=10.0, truth_at=truth)  # a still truth at (0, 0, 100)
    err = np.array([f.pos_enu_m for _, f in fixes]) - [0.0, 0.0, 100.0]
    assert np.allclose(err.std(axis=0), [2.0, 2.0, 3.0], rtol=0.1)
    lag = 20  # 2 s at 10 Hz
    e = err - err.mean(axis=0)
    acf = np.mean(e[lag:] * e[:-lag], axis=0) / np.mean(e * e, axis=0)
    assert np.allclose(acf, math.exp(-1.0), atol=0.06), acf
    first = np.array([GnssModel(cfg, seed).step(truth(0.0))[0].pos_enu_m for seed in range(400)])
    assert first[:, :2].std() == pytest.approx(2.0, rel=0.1)  # stationary from the first fix on


def test_gnss_fix_is_the_truth_at_its_time_of_fix_and_arrives_latency_later():
    latency = 0.15
    cfg = resolve("ideal", {"gnss.latency_s": latency, "gnss.rate_hz": 5.0}).gnss
    fixes = run_gnss(GnssModel(cfg, 1), 10.0)
    assert len(fixes) == 50  # fixes taken at 0, 0.2, ..., 9.8 s have arrived by 10 s
    tof = np.array([f.time_of_fix_s for _, f in fixes])
    assert np.allclose(np.diff(tof), 0.2, atol=1e-9)
    for t, f in fixes:
        assert f.t_s - f.time_of_fix_s == pytest.approx(latency, abs=1e-12)
        assert f.t_s - 1e-9 <= t < f.t_s + SIM_DT  # delivered at the first step after its arrival
        assert np.array_equal(f.pos_enu_m, moving_truth(f.time_of_fix_s).pos_enu_m)
    noisy = resolve("typical", {"gnss": {"latency_s": latency, "pos_horizontal_sigma_m": 0.05,
                                         "pos_vertical_sigma_m": 0.05}}).gnss
    for _, f in run_gnss(GnssModel(noisy, 2), 5.0):  # the truth moves 1.7 m in the latency; the error is 0.05 m
        assert np.linalg.norm(f.pos_enu_m - moving_truth(f.time_of_fix_s).pos_enu_m) < 0.4
        assert np.linalg.norm(f.pos_enu_m - moving_truth(f.t_s).pos_enu_m) > 1.2
        assert (f.h_acc_m, f.v_acc_m, f.s_acc_m_s) == (0.05, 0.05, noisy.vel_horizontal_sigma_m_s)
    for rate in (7.0, 10.0):
        n = len(run_gnss(GnssModel(resolve("ideal", {"gnss.rate_hz": rate}).gnss, 1), 9.99))
        assert n == int(rate * 10.0)


# --------------------------------------------------------------------------- determinism


def record(models: SensorErrorModels, t_end=2.0):
    out = {"imu": [], "gnss": [], "baro": [], "mag": [], "pitot": [], "encoders": []}
    for k in range(int(t_end / SIM_DT) + 1):
        s = moving_truth(k * SIM_DT)
        imu = models.imu.step(s)
        if imu is not None:
            out["imu"].append(np.concatenate([imu.delta_angle_frd_rad, imu.delta_velocity_frd_m_s]))
        out["gnss"] += [np.concatenate([f.pos_enu_m, f.vel_enu_m_s]) for f in models.gnss.step(s)]
        for name, sample in (("baro", models.baro.step(s)), ("mag", models.mag.step(s)),
                             ("pitot", models.pitot.step(s)), ("encoders", models.encoders.step(s.t_s, 0.3, -0.4))):
            if sample is not None:
                out[name].append(values_of(sample))
    return {k: np.array(v) for k, v in out.items()}


def values_of(sample):
    """Every field of a sample but its time, as one float array."""
    return np.concatenate([np.atleast_1d(getattr(sample, f.name)) for f in fields(sample) if f.name != "t_s"])


def test_same_seed_same_draws_other_seed_other_draws():
    a = record(SensorErrorModels.build(typical(), 7))
    b = record(SensorErrorModels.build(typical(), 7))
    c = record(SensorErrorModels.build(typical(), 8))
    for name in a:
        assert len(a[name]) > 5
        assert np.array_equal(a[name], b[name]), name
        assert not np.allclose(a[name], c[name]), name
    assert not np.array_equal(CameraMountError.draw(typical().camera_mount, 7).boresight_cam_rad,
                              CameraMountError.draw(typical().camera_mount, 8).boresight_cam_rad)


def test_one_sensor_or_term_never_moves_another_ones_draws():
    base = record(SensorErrorModels.build(typical(), 7))
    other = record(SensorErrorModels.build(resolve("typical", {"gnss.pos_horizontal_sigma_m": 3.0,
                                                               "baro.noise_sigma_m": 0.0}), 7))
    for name in ("imu", "mag", "pitot", "encoders"):
        assert np.array_equal(base[name], other[name]), name
    assert not np.allclose(base["gnss"], other["gnss"])
    alone = ImuModel(typical().imu, 7)  # the IMU on its own: as in the bundle
    assert np.array_equal([np.concatenate([s.delta_angle_frd_rad, s.delta_velocity_frd_m_s])
                           for s in map(alone.step, (moving_truth(k * SIM_DT) for k in range(241))) if s is not None],
                          base["imu"])
    # switching the gyro turn-on bias off leaves its other terms' draws: the deltas differ by that bias times dt
    full = ImuModel(typical().imu, 3)
    no_turn_on = ImuModel(resolve("typical", {"imu.gyro.turn_on_bias_sigma_rad_s": 0.0}).imu, 3)
    w = np.zeros((11, 3))
    diff = full.integrate(0.01, w, w)[0] - no_turn_on.integrate(0.01, w, w)[0]
    assert np.allclose(diff, full.gyro.turn_on * 0.01, rtol=0, atol=1e-15)


# --------------------------------------------------------------------------- ideal


def test_ideal_profile_gives_the_truth():
    models = SensorErrorModels.build(ideal(), 5)
    prev = None
    mag_ned = models.mag.earth_field_ned_gauss
    for k in range(241):
        s = moving_truth(k * SIM_DT)
        imu = models.imu.step(s)
        if prev is not None:
            half = 0.5 * (s.t_s - prev.t_s)
            np.testing.assert_allclose(imu.delta_angle_frd_rad, (prev.body_rates_frd_rad_s + s.body_rates_frd_rad_s)
                                       * half, rtol=0, atol=1e-12)
            np.testing.assert_allclose(imu.delta_velocity_frd_m_s,
                                       (prev.specific_force_frd_m_s2 + s.specific_force_frd_m_s2) * half,
                                       rtol=0, atol=1e-12)
        prev = s
        for f in models.gnss.step(s):
            assert f.t_s == f.time_of_fix_s == s.t_s  # no latency
            assert np.array_equal(f.pos_enu_m, s.pos_enu_m) and np.array_equal(f.vel_enu_m_s, s.vel_enu_m_s)
        if (b := models.baro.step(s)) is not None:
            assert b.height_m == s.height_above_sea_m
        if (m := models.mag.step(s)) is not None:
            assert np.array_equal(m.field_frd_gauss, dcm_ned_from_frd(s.euler_ned_rad).T @ mag_ned)
        if (p := models.pitot.step(s)) is not None:
            assert p.airspeed_m_s == s.airspeed_m_s
        if (e := models.encoders.step(s.t_s, 0.3, -0.4)) is not None:
            assert (e.pan_rad, e.tilt_rad) == (0.3, -0.4)
    assert np.array_equal(models.camera_mount.dcm_nominal_from_actual(), np.eye(3))
    assert models.camera_mount.focal_scale == 1.0


# --------------------------------------------------------------------------- faults


def test_gnss_outage_gives_no_fixes_until_it_ends():
    def faults(t, model):
        if abs(t - 5.05) < 1e-9:  # the fix of 5.0 s is on its way (due at 5.12 s)
            model.outage(True)
        if abs(t - 10.0) < 1e-9:
            model.outage(False)
    fixes = run_gnss(GnssModel(typical().gnss, 3), 15.0, on_step=faults)
    assert not [f for t, f in fixes if 5.05 <= t < 10.0]  # not even the one in flight when it began
    after = [f for t, f in fixes if t >= 10.0]
    assert after and min(f.time_of_fix_s for f in after) >= 10.0 - 1e-9
    assert len([f for t, f in fixes if t < 5.05]) == 25  # 5 Hz: taken at 0 ... 4.8 s, 0.12 s late
    assert len(after) == 25  # taken at 10.0 ... 14.8 s


def test_gnss_jump_shifts_the_error_by_the_offset_from_then_on():
    offset = np.array([3.0, -2.0, 1.0])
    plain = run_gnss(GnssModel(typical().gnss, 4), 8.0)
    jumped = run_gnss(GnssModel(typical().gnss, 4), 8.0, on_step=lambda t, m: m.jump(offset) if t == 4.0 else None)
    assert len(plain) == len(jumped)
    for (_, a), (_, b) in zip(plain, jumped):
        shift = offset if b.time_of_fix_s >= 4.0 else np.zeros(3)
        np.testing.assert_allclose(b.pos_enu_m - a.pos_enu_m, shift, rtol=0, atol=1e-12)
        assert np.array_equal(a.vel_enu_m_s, b.vel_enu_m_s)


def test_mag_interference_shifts_the_field():
    offset = np.array([0.1, 0.0, -0.05])
    plain, hit = MagModel(typical().mag, 6), MagModel(typical().mag, 6)
    for k in range(600):
        t = k * SIM_DT
        if t == 2.0:
            hit.interference(offset)
        if t == 4.0:
            hit.interference(np.zeros(3))
        a, b = plain.step(moving_truth(t)), hit.step(moving_truth(t))
        assert (a is None) == (b is None)
        if a is not None:
            expected = offset if 2.0 <= t < 4.0 else np.zeros(3)
            np.testing.assert_allclose(b.field_frd_gauss - a.field_frd_gauss, expected, rtol=0, atol=1e-15)


def test_baro_drift_fault_accumulates_and_stays():
    plain, hit = BaroModel(typical().baro, 8), BaroModel(typical().baro, 8)
    for k in range(1200):
        t = k * SIM_DT
        a, b = plain.step(truth(t)), hit.step(truth(t))
        if t == 3.0:
            hit.drift_fault(0.5)  # 0.5 m/s from t = 3 s
        if t == 6.0:
            hit.drift_fault(0.0)  # stops growing at 1.5 m
        if a is not None:
            expected = 0.5 * (min(t, 6.0) - 3.0) if t > 3.0 else 0.0
            assert b.height_m - a.height_m == pytest.approx(expected, abs=1e-9)
    assert hit.drift_m - plain.drift_m == pytest.approx(1.5, abs=1e-9)


# --------------------------------------------------------------------------- the other sensors


def test_mag_field_in_the_body_follows_the_attitude():
    cfg = resolve("ideal")
    mag = MagModel(cfg.mag, 1)
    f, inc = cfg.mag.field_strength_gauss, math.radians(cfg.mag.inclination_deg)
    north = mag.step(truth(0.0)).field_frd_gauss  # nose north, level: the field ahead and below
    np.testing.assert_allclose(north, [f * math.cos(inc), 0.0, f * math.sin(inc)], atol=1e-15)
    east = MagModel(cfg.mag, 1).step(truth(0.0, euler=(0.0, 0.0, math.pi / 2))).field_frd_gauss
    np.testing.assert_allclose(east, [0.0, -f * math.cos(inc), f * math.sin(inc)], atol=1e-15)  # north is to the left
    typ = MagModel(typical().mag, 1)
    assert np.linalg.norm(typ.hard_iron_frd_gauss) > 0 and typ.step(truth(0.0)).field_frd_gauss.shape == (3,)


def test_pitot_encoders_and_camera_mount_errors():
    pitots = [PitotModel(typical().pitot, seed) for seed in range(400)]
    assert np.std([p.bias_m_s for p in pitots]) == pytest.approx(typical().pitot.bias_sigma_m_s, rel=0.1)
    assert PitotModel(typical().pitot, 1).step(truth(0.0, airspeed=0.0)).airspeed_m_s >= 0.0
    enc = EncoderModel(typical().encoders, 2)
    readings = np.array([[s.pan_rad, s.tilt_rad] for k in range(2000)
                         if (s := enc.step(k * 0.01, 0.0, 0.0)) is not None])
    assert len(readings) == 2000
    np.testing.assert_allclose(readings.mean(axis=0), enc.bias_rad, atol=4 * 0.0005 / math.sqrt(2000))
    assert readings.std(axis=0) == pytest.approx(typical().encoders.noise_sigma_rad, rel=0.1)
    mounts = [CameraMountError.draw(typical().camera_mount, seed) for seed in range(400)]
    rho = np.array([m.boresight_cam_rad for m in mounts])
    assert rho.std() == pytest.approx(typical().camera_mount.boresight_sigma_rad, rel=0.1)
    assert np.std([m.focal_scale for m in mounts]) == pytest.approx(typical().camera_mount.focal_scale_sigma_frac,
                                                                     rel=0.1)
    r = mounts[0].dcm_nominal_from_actual()
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-15)
    assert math.acos((np.trace(r) - 1.0) / 2.0) == pytest.approx(np.linalg.norm(rho[0]), rel=1e-9)
    np.testing.assert_allclose(r @ rho[0], rho[0], atol=1e-15)  # the rotation vector is its axis


# --------------------------------------------------------------------------- settings


def _fields(model: type[BaseModel], prefix=""):
    for name, field in model.model_fields.items():
        ann = field.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            yield from _fields(ann, f"{prefix}{name}.")
        else:
            yield f"{prefix}{name}", field


def test_every_setting_has_a_unit_bounds_and_a_short_description():
    units = {"m", "s", "s2", "hz", "rad", "gauss", "deg", "frac", "ratio"}
    fields = list(_fields(SensorErrorsConfig))
    assert len(fields) > 40
    for path, field in fields:
        assert field.description and len(field.description) <= 200, path
        if field.annotation is float:
            assert path.rsplit("_", 1)[-1] in units, path
            assert any(isinstance(m, (at.Ge, at.Gt)) for m in field.metadata), path
            assert any(isinstance(m, (at.Le, at.Lt)) for m in field.metadata), path


def test_profiles_rank_and_resolve_merges_overrides():
    """Every error size: ideal zero <= typical <= degraded; overrides nested or dotted; bad keys fail."""
    values = {name: dict((p, f) for p, f in _flat(fn().model_dump())) for name, fn in PROFILES.items()}
    sizes = [p for p in values["typical"] if any(w in p for w in ("sigma", "density", "random_walk", "latency"))]
    assert len(sizes) > 20
    for p in sizes:
        assert values["ideal"][p] == 0.0 and 0.0 < values["typical"][p] <= values["degraded"][p], p
    cfg = resolve("degraded", {"gnss": {"latency_s": 0.1}, "imu.gyro.bias_tau_s": 500.0})
    assert cfg.gnss.latency_s == 0.1 and cfg.imu.gyro.bias_tau_s == 500.0
    assert cfg.gnss.pos_horizontal_sigma_m == degraded().gnss.pos_horizontal_sigma_m == 1.5
    assert cfg.imu.accel == degraded().imu.accel
    assert resolve() == typical() == SensorErrorsConfig()
    with pytest.raises(ValidationError):
        resolve("typical", {"gnss.latency_ms": 100})
    with pytest.raises(ValidationError):
        resolve("typical", {"baro": {"noise_sigma_m": -1.0}})
    with pytest.raises(ValueError, match="unknown sensor error profile"):
        resolve("perfect")


def _flat(d, prefix=""):
    for k, v in d.items():
        if isinstance(v, dict):
            yield from _flat(v, f"{prefix}{k}.")
        else:
            yield f"{prefix}{k}", v
