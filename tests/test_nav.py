"""Navigation between GNSS fixes (controllers/navigation/nav.py)."""
import math

import numpy as np
import pytest

from controllers.navigation.nav import Navigation, NavigationConfig
from fwsim.interface.messages import Measurements
from fwsim.sensors.onboard import Sensors, SensorsConfig


def _truth(t, v=np.array([30.0, -40.0, -20.0])):
    return np.array([100.0, 200.0, 500.0]) + v * t, v


def _fly(nav, sigma_m, seconds=20.0, fsw_hz=30.0, gnss_hz=10.0, seed=3):
    """A straight flight sampled like the loop does: fixes at gnss_hz held, read at fsw_hz."""
    rng = np.random.default_rng(seed)
    errs_nav, errs_held = [], []
    fix = None
    for k in range(int(seconds * fsw_hz)):
        t = k / fsw_hz
        if fix is None or t + 1e-9 >= fix[0] + 1.0 / gnss_hz:
            p, v = _truth(t)
            fix = (t, p + rng.normal(0.0, sigma_m, 3), v)
        meas = Measurements(t, fix[1], fix[2], np.zeros(3), np.zeros(3), 22.0, 500.0, nav_t_s=fix[0])
        out = nav.step(meas)
        errs_nav.append(np.linalg.norm(out.pos_enu_m - _truth(t)[0]))
        errs_held.append(np.linalg.norm(meas.pos_enu_m - _truth(t)[0]))
    return np.array(errs_nav[30:]), np.array(errs_held[30:])


def test_propagation_removes_the_hold_lag():
    """Noise-free fixes at 10 Hz held (54 m/s, read at 30 Hz) lag up to 3.6 m; propagated with the velocity:
    none."""
    nav, held = _fly(Navigation(), 0.0)
    assert held.max() > 3.5
    assert nav.max() < 1e-9


def test_blending_smooths_fix_noise_as_predicted():
    """White fix noise sigma per axis: the blended error per axis is sigma sqrt(K / (2 - K))."""
    sigma, k = 0.5, 0.1
    nav, held = _fly(Navigation(NavigationConfig(fix_gain=k)), sigma, seconds=120.0)
    per_axis = np.sqrt(np.mean(nav**2) / 3.0)
    assert per_axis == pytest.approx(sigma * math.sqrt(k / (2.0 - k)), rel=0.25)
    assert per_axis < 0.3 * np.sqrt(np.mean(held**2) / 3.0)


def test_off_passes_the_fix_through_and_a_gap_restarts():
    meas = Measurements(1.0, np.array([1.0, 2.0, 3.0]), np.array([10.0, 0.0, 0.0]), np.zeros(3), np.zeros(3),
                        22.0, 3.0, nav_t_s=0.9)
    assert Navigation(NavigationConfig(propagate=False)).step(meas) is meas
    nav = Navigation()
    nav.step(meas)
    later = Measurements(5.0, np.array([50.0, 2.0, 3.0]), np.array([10.0, 0.0, 0.0]), np.zeros(3), np.zeros(3),
                         22.0, 3.0, nav_t_s=5.0)
    assert nav.step(later).pos_enu_m == pytest.approx([50.0, 2.0, 3.0])  # 4 s without a fix: restart


def test_sensors_stamp_the_fix_time():
    from fwsim.interface.messages import AirframeState
    s = Sensors(SensorsConfig(gnss_rate_hz=10.0), seed=1)
    fields = {n: 0.0 for n in AirframeState.__dataclass_fields__}
    stamps = []
    for k in range(12):
        t = k / 30.0
        st = AirframeState(**{**fields, "t_s": t, "pos_enu_m": np.zeros(3), "vel_enu_m_s": np.zeros(3),
                              "euler_ned_rad": np.zeros(3), "body_rates_frd_rad_s": np.zeros(3),
                              "specific_force_frd_m_s2": np.zeros(3)})
        stamps.append(s.sample(st).nav_t_s)
    assert stamps[:4] == pytest.approx([0.0, 0.0, 0.0, 0.1])


def _turn(seconds=6.0, fsw_hz=30.0, gnss_hz=10.0, speed=50.0, rate=0.5, bank=math.radians(60.0)):
    """A steady banked turn (heading rate ``rate`` rad/s, clockwise seen from above) read like the loop does."""
    fix = None
    for k in range(int(seconds * fsw_hz)):
        t = k / fsw_hz
        psi = rate * t
        v = speed * np.array([math.sin(psi), math.cos(psi), 0.0])
        p = (speed / rate) * np.array([1.0 - math.cos(psi), math.sin(psi), 0.0])
        if fix is None or t + 1e-9 >= fix[0] + 1.0 / gnss_hz:
            fix = (t, p, v)
        rates = np.array([0.0, rate * math.sin(bank), rate * math.cos(bank)])  # FRD: a level turn, banked
        yield t, p, v, Measurements(t, fix[1], fix[2], np.array([bank, 0.0, psi]), rates, speed, 500.0,
                                    nav_t_s=fix[0])


def test_the_velocity_turns_with_the_gyros_between_fixes():
    """In a 25 m/s^2 turn a held 10 Hz fix velocity read at 30 Hz is up to 1.7 m/s old; turned with the gyros it is
    within a few cm/s of the truth (the first order step), and the propagated position follows the turn."""
    for turn, limit in ((True, 0.1), (False, None)):
        nav = Navigation(NavigationConfig(turn_velocity=turn))
        v_err, p_err = [], []
        for t, p, v, meas in _turn():
            out = nav.step(meas)
            v_err.append(np.linalg.norm(out.vel_enu_m_s - v))
            p_err.append(np.linalg.norm(out.pos_enu_m - p))
        if turn:
            assert max(v_err) < limit, max(v_err)
            turned_p = max(p_err)
        else:
            assert max(v_err) > 1.5
            assert max(p_err) > 2.0 * turned_p


def test_without_gyros_the_velocity_is_the_fix():
    meas = Measurements(1.0, np.array([1.0, 2.0, 3.0]), np.array([10.0, 0.0, 0.0]), np.zeros(3),
                        np.full(3, np.nan), 22.0, 3.0, nav_t_s=0.9)
    assert Navigation().step(meas).vel_enu_m_s == pytest.approx([10.0, 0.0, 0.0])


def _turn_in_wind(nav, wind, speed=50.0, rate=0.5, bank=math.radians(60.0), level_s=10.0, turn_s=4.0,
                  fsw_hz=30.0, gnss_hz=10.0):
    """Level flight north for level_s, then a steady banked turn, in a constant wind: the largest error of
    the navigation's velocity during the turn."""
    fix, errs = None, []
    for k in range(int((level_s + turn_s) * fsw_hz)):
        t = k / fsw_hz
        tt = max(t - level_s, 0.0)
        psi = rate * tt
        v = speed * np.array([math.sin(psi), math.cos(psi), 0.0]) + wind
        if fix is None or t + 1e-9 >= fix[0] + 1.0 / gnss_hz:
            fix = (t, np.zeros(3), v)
        turning = t >= level_s
        rates = np.array([0.0, rate * math.sin(bank), rate * math.cos(bank)]) if turning else np.zeros(3)
        meas = Measurements(t, fix[1], fix[2], np.array([bank if turning else 0.0, 0.0, psi]), rates, speed,
                            500.0, nav_t_s=fix[0])
        out = nav.step(meas)
        if turning:
            errs.append(np.linalg.norm(out.vel_enu_m_s - v))
    return max(errs)


def test_in_wind_the_air_velocity_turns_and_the_wind_is_learnt_in_level_flight():
    """The airframe turns its air velocity: with an 8 m/s wind, turning the ground velocity errs by
    omega x wind (0.4 m/s after one fix period); with the wind learnt in the level leg it does not."""
    wind = np.array([6.0, -5.0, 0.0])
    nav = Navigation(NavigationConfig(wind_gain=0.05))
    learnt = _turn_in_wind(nav, wind)
    assert np.linalg.norm(nav.wind_enu_m_s - wind) < 0.3
    ignored = _turn_in_wind(Navigation(NavigationConfig(wind_gain=0.0)), wind)
    assert learnt < 0.1 and ignored > 0.25, (learnt, ignored)


def test_a_missing_attitude_or_airspeed_leaves_the_wind_and_velocity_finite():
    nav = Navigation()
    for k, (euler, airspeed) in enumerate([(np.zeros(3), 22.0), (np.full(3, np.nan), 22.0),
                                           (np.zeros(3), math.nan), (np.zeros(3), 22.0)]):
        t = 0.1 * k
        out = nav.step(Measurements(t, np.array([0.0, 2.2 * k, 500.0]), np.array([0.0, 22.0, 0.0]), euler,
                                    np.array([0.0, 0.0, 0.1]), airspeed, 500.0, nav_t_s=t))
        assert np.all(np.isfinite(out.vel_enu_m_s)) and np.all(np.isfinite(out.pos_enu_m))
    assert np.all(np.isfinite(nav.wind_enu_m_s))
