"""The fwuav JSBSim model: loading, JSBSim's trim, and its flight envelope."""
import math
import os

import numpy as np
import pytest
from flight import Flight, flight_path_rad

from fwsim.world.airframe import Airframe, AirframeError, aircraft_hash
from fwsim.interface.messages import ActuatorCommand, RateCommand


def test_loads_from_any_working_directory(tmp_path):
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        a = Airframe("fwuav")
        st = a.reset([-1000.0, 0.0, 1000.0], 22.0, math.radians(90.0))
    finally:
        os.chdir(cwd)
    np.testing.assert_allclose(st.pos_enu_m, [-1000.0, 0.0, 1000.0], atol=1e-6)
    assert 4.0 < a.mass_kg < 5.0


def test_unknown_aircraft_is_a_clear_error():
    with pytest.raises(AirframeError, match="aircraft 'nope' not found"):
        Airframe("nope")


def test_aircraft_hash_is_stable():
    assert aircraft_hash("fwuav") == aircraft_hash("fwuav")
    assert len(aircraft_hash("fwuav")) == 64


@pytest.mark.parametrize("airspeed", [16.0, 18.0, 20.0, 22.0, 25.0, 28.0, 30.0])
@pytest.mark.parametrize("altitude", [500.0, 1000.0])
def test_trims_level_and_stays_there(airspeed, altitude):
    """JSBSim's own trim balances level flight from 16 to 30 m/s; with the
    trimmed controls held, the aircraft stays put for 3 s."""
    a = Airframe("fwuav")
    st0 = a.reset([0.0, 0.0, altitude], airspeed, math.radians(45.0))
    trim = a.trim
    assert 0.0 < trim.throttle_norm < 1.0
    assert math.radians(-4) < trim.alpha_rad < math.radians(10)  # attached flow, below stall (11 deg)
    hold = ActuatorCommand(0.0, 0.0, 0.0, 0.0, trim.throttle_norm)
    for _ in range(360):
        st = a.step(hold)
    assert abs(st.pos_enu_m[2] - altitude) < 1.0
    assert abs(st.airspeed_m_s - airspeed) < 0.2
    assert abs(math.degrees(st.euler_ned_rad[0])) < 0.5
    # moved along the heading (north-east) at the airspeed
    dist = np.linalg.norm(st.pos_enu_m[:2] - st0.pos_enu_m[:2])
    assert dist == pytest.approx(3.0 * airspeed, rel=0.02)


def test_trim_fails_loudly_below_the_stall():
    a = Airframe("fwuav")
    with pytest.raises(AirframeError, match="trim failed at 9.0 m/s"):
        a.reset([0.0, 0.0, 500.0], 9.0, 0.0)


def test_climbs_at_least_3_m_s():
    """A trimmed 10 deg climb at 20 m/s (3.5 m/s vertical) needs less than full throttle,
    and the aircraft keeps climbing at that rate."""
    a = Airframe("fwuav")
    a.reset([0.0, 0.0, 500.0], 20.0, 0.0, flight_path_rad=math.radians(10.0))
    assert a.trim.throttle_norm < 1.0
    hold = ActuatorCommand(0.0, 0.0, 0.0, 0.0, a.trim.throttle_norm)
    for _ in range(600):
        st = a.step(hold)
    climb = st.vel_enu_m_s[2]
    assert climb >= 3.0, f"climb rate {climb:.2f} m/s"


def _bank_and_altitude_hold(bank_rad, altitude_m):
    def cmd(s):
        gamma_c = max(-0.1, min(0.1, 0.01 * (altitude_m - s.pos_enu_m[2])))
        return RateCommand(s.t_s, 22.0, 2.0 * (bank_rad - s.euler_ned_rad[0]),
                           1.5 * (gamma_c - flight_path_rad(s)) / math.cos(s.euler_ned_rad[0]))
    return cmd


def test_holds_a_45_degree_bank():
    """A coordinated 45 deg bank at 22 m/s, altitude held: bank within 2 deg,
    sideslip under 1 deg, altitude within 10 m, airspeed within 1.5 m/s."""
    f = Flight(22.0, 500.0)
    tr = f.fly(40.0, _bank_and_altitude_hold(math.radians(45.0), 500.0))
    w = tr.window(15.0, 40.0)
    bank = np.degrees(tr.arr("euler_ned_rad")[w, 0])
    assert np.all(np.abs(bank - 45.0) < 2.0), (bank.min(), bank.max())
    assert np.max(np.abs(np.degrees(tr.arr("beta_rad")[w]))) < 1.0
    assert np.max(np.abs(tr.arr("pos_enu_m")[w, 2] - 500.0)) < 10.0
    assert np.max(np.abs(tr.arr("airspeed_m_s")[w] - 22.0)) < 1.5
    # and it turns: the heading goes all the way round at about g tan(phi) / V
    psi = np.unwrap(tr.arr("euler_ned_rad")[w, 2])
    rate = (psi[-1] - psi[0]) / 25.0
    assert rate == pytest.approx(9.80665 * math.tan(math.radians(45.0)) / 22.0, rel=0.1)


@pytest.mark.parametrize("gamma_deg", [-30.0, -45.0, -60.0])
def test_idle_dive_stays_bounded(gamma_deg):
    """Diving from 1000 m at -30 to -60 deg with the throttle at idle: the
    flight path is held, speed levels off (windmilling propeller plus airframe
    drag) below 65 m/s and the angle of attack stays in attached flow."""
    f = Flight(22.0, 1000.0)
    g = math.radians(gamma_deg)
    tr = f.fly(120.0, lambda s: RateCommand(s.t_s, 15.0, -2.0 * s.euler_ned_rad[0], 1.0 * (g - flight_path_rad(s))),
               stop=lambda s: s.pos_enu_m[2] < 50.0)
    assert tr.states[-1].pos_enu_m[2] < 50.0  # reached the bottom of the dive
    thr = np.array([a.throttle_norm for a in tr.acts])
    assert np.all(thr[600:] == 0.0)  # idle after the first 5 s
    V = tr.arr("airspeed_m_s")
    assert V.max() < 65.0
    assert abs(V[-1] - V[-120]) < 1.0  # levelled off: less than 1 m/s gained in the last second
    alpha = np.degrees(tr.arr("alpha_rad"))
    assert alpha.min() > -10.0 and alpha.max() < 10.0
    assert math.degrees(flight_path_rad(tr.states[-1])) == pytest.approx(gamma_deg, abs=1.0)


def test_adverse_yaw_from_roll_rate_scales_with_lift():
    """Cnp = -CL/8 (strip theory): the yaw moment per unit of roll rate follows the wing's lift
    coefficient, so it is the cruise value when lifting and near zero when the wing does not lift."""
    a = Airframe("fwuav")
    s = a.reset([0.0, 0.0, 500.0], 22.0, 0.0, 0.0)
    for elevator in (0.0, 0.25):  # trimmed, then pushed toward zero lift
        for _ in range(30):
            s = a.step(ActuatorCommand(s.t_s, 0.5, elevator, 0.0, a.trim.throttle_norm))
        p = a.property("velocities/p-aero-rad_sec")
        qs = a.property("aero/qbar-area")
        cl = a.property("aero/force/lift-alpha") / qs
        cnp = a.property("aero/moment/yaw-p") / (qs * a.property("metrics/bw-ft") * a.property("aero/bi2vel") * p)
        assert abs(p) > 0.2
        assert cnp == pytest.approx(-cl / 8.0, rel=1e-6)
    assert abs(cl) < 0.3  # the push really unloaded the wing


def _open_loop(wind_enu, seconds=3.0):
    """Trimmed at 22 m/s heading 30 deg, controls held at the trim: (states every second, airframe)."""
    a = Airframe("fwuav", wind_enu_m_s=wind_enu)
    states = [a.reset(np.array([0.0, 0.0, 500.0]), 22.0, math.radians(30.0))]
    tr = a.trim
    for k in range(int(seconds * 120)):
        s = a.step(ActuatorCommand(0.0, 0.0, tr.elevator_norm, 0.0, tr.throttle_norm))
        if (k + 1) % 120 == 0:
            states.append(s)
    return states, a


def test_the_scenario_wind_moves_the_aircraft_and_nothing_else():
    """In a constant wind the ground velocity is the still-air one plus the wind, and the air-relative
    flight (airspeed, attitude, height) is the same (the wind once did nothing: JSBSim's run_ic() zeroed it)."""
    wind = np.array([6.0, -5.0, 0.0])
    calm, _ = _open_loop((0.0, 0.0, 0.0))
    windy, a = _open_loop(tuple(wind))
    assert a.property("atmosphere/wind-east-fps") * 0.3048 == pytest.approx(6.0)
    assert a.property("atmosphere/wind-north-fps") * 0.3048 == pytest.approx(-5.0)
    for c, w in zip(calm, windy):
        np.testing.assert_allclose(w.vel_enu_m_s, c.vel_enu_m_s + wind, atol=0.05)
        assert w.airspeed_m_s == pytest.approx(c.airspeed_m_s, abs=0.02)
        np.testing.assert_allclose(w.euler_ned_rad, c.euler_ned_rad, atol=1e-3)
        assert w.pos_enu_m[2] == pytest.approx(c.pos_enu_m[2], abs=0.05)
    drift = windy[-1].pos_enu_m[:2] - calm[-1].pos_enu_m[:2]
    np.testing.assert_allclose(drift, 3.0 * wind[:2], atol=0.2)  # 3 s of drift
