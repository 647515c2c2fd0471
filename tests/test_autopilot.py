"""Closed-loop inner loops: step responses and the acceleration mode."""
import math

import numpy as np
import pytest
from flight import Flight, flight_path_rad

from controllers.guidance.script import perpendicular_axes
from fwsim.autopilot import Autopilot, bank_from_specific_force, load_autopilot_params
from fwsim.interface.messages import AccelCommand, RateCommand

DEG = math.pi / 180.0


def level(V=22.0):
    return lambda s: RateCommand(s.t_s, V, 0.0, 0.0)


def test_gains_file_checks_ranges():
    with pytest.raises(ValueError, match="outside its range"):
        load_autopilot_params("fwuav", overrides={"roll_rate_kp": 100.0})
    with pytest.raises(ValueError, match="unknown autopilot gain"):
        load_autopilot_params("fwuav", overrides={"no_such_gain": 1.0})


def test_airspeed_step_settles():
    """22 -> 26 m/s: within 0.5 m/s of the set-point after 12 s, overshoot under 1 m/s."""
    f = Flight()
    f.fly(2.0, level(22.0))
    tr = f.fly(25.0, level(26.0))
    V = tr.arr("airspeed_m_s")
    settled = tr.window(14.0, 27.0)
    assert np.all(np.abs(V[settled] - 26.0) < 0.5), (V[settled].min(), V[settled].max())
    assert V.max() < 27.0


def test_roll_rate_step_settles():
    """Roll rate step 0 -> 20 deg/s: 90 % within 0.3 s, then within 1.5 deg/s of the set-point."""
    f = Flight()
    f.fly(1.0, level())
    tr = f.fly(1.5, lambda s: RateCommand(s.t_s, 22.0, 20 * DEG, 0.0))
    t = np.array(tr.t)
    p = tr.arr("body_rates_frd_rad_s")[:, 0]
    p_sp = tr.sp("body_rates_sp_frd_rad_s")[:, 0]
    rise = t[np.argmax(p >= 0.9 * p_sp)]
    assert 0.0 < rise < 0.3, f"rise time {rise:.3f} s"
    after = (t > 0.5) & (t < 1.5)
    assert np.max(np.abs(p[after] - p_sp[after])) < 1.5 * DEG


def test_pitch_rate_step_settles():
    """Pitch rate step 0 -> 5 deg/s: 90 % within 0.4 s, then within 0.5 deg/s."""
    f = Flight()
    f.fly(1.0, level())
    tr = f.fly(2.0, lambda s: RateCommand(s.t_s, 22.0, 0.0, 5 * DEG))
    t = np.array(tr.t)
    q = tr.arr("body_rates_frd_rad_s")[:, 1]
    rise = t[np.argmax(q >= 0.9 * 5 * DEG)]
    assert 0.0 < rise < 0.4, f"rise time {rise:.3f} s"
    after = (t > 0.6) & (t < 2.0)
    assert np.max(np.abs(q[after] - 5 * DEG)) < 0.5 * DEG


def test_rate_mode_turn_is_coordinated():
    """Roll into 30 deg with u_p, hold u_p = u_q = 0: the autopilot adds the turn's
    yaw and pitch rates itself (psi_dot = g tan(phi) cos(theta) / V), sideslip stays
    under 1.5 deg throughout and the altitude within 5 m."""
    f = Flight()
    f.fly(1.0, level())
    f.fly(2.0, lambda s: RateCommand(s.t_s, 22.0, 15 * DEG, 0.0))
    tr = f.fly(8.0, level())
    beta = np.degrees(tr.arr("beta_rad"))
    assert np.max(np.abs(beta)) < 1.5
    z = tr.arr("pos_enu_m")[:, 2]
    assert np.max(np.abs(z - 500.0)) < 5.0
    w = tr.window(3.0, 8.0)
    phi = tr.arr("euler_ned_rad")[w, 0]
    psi = np.unwrap(tr.arr("euler_ned_rad")[w, 2])
    turn_rate = (psi[-1] - psi[0]) / 5.0
    expected = 9.80665 * math.tan(phi.mean()) / 22.0
    assert turn_rate == pytest.approx(expected, rel=0.1)


def _accel(right, up, V=22.0):
    def cmd(s):
        u, r = perpendicular_axes(s.vel_enu_m_s)
        return AccelCommand(s.t_s, V, right * r + up * u)
    return cmd


@pytest.mark.parametrize("right", [5.0, -5.0])
def test_accel_mode_steady_turn(right):
    """5 m/s^2 sideways: after 3 s the achieved perpendicular acceleration is within
    0.3 m/s^2 of the command, sideslip under 1 deg, and the path stays level
    (vertical speed under 1 m/s: the command has no vertical part)."""
    f = Flight()
    f.fly(1.0, _accel(0.0, 0.0))
    tr = f.fly(10.0, _accel(right, 0.0))
    w = tr.window(3.0, 10.0)
    a_sp = tr.sp("accel_sp_enu_m_s2")[w]
    a = tr.sp("accel_enu_m_s2")[w]
    err = np.linalg.norm(a - a_sp, axis=1)
    assert np.max(err) < 0.3, np.max(err)
    assert np.max(np.abs(np.degrees(tr.arr("beta_rad")[w]))) < 1.0
    assert np.max(np.abs(tr.arr("vel_enu_m_s")[w, 2])) < 1.0
    # banked the right way: right turn -> right wing down (positive roll)
    assert np.sign(tr.arr("euler_ned_rad")[w, 0].mean()) == np.sign(right)


@pytest.mark.parametrize("up", [3.0, -3.0])
def test_accel_mode_pull_up_and_push_over(up):
    """3 m/s^2 up (pull-up) or down (push-over) for 2 s: after 0.7 s the normal
    acceleration is within 0.5 m/s^2 of the command and the bank stays level."""
    f = Flight()
    f.fly(1.0, _accel(0.0, 0.0))
    tr = f.fly(2.0, _accel(0.0, up))
    w = tr.window(0.7, 2.0)
    a = tr.sp("accel_enu_m_s2")[w]
    a_sp = tr.sp("accel_sp_enu_m_s2")[w]
    assert np.max(np.linalg.norm(a - a_sp, axis=1)) < 0.5
    assert np.max(np.abs(np.degrees(tr.arr("euler_ned_rad")[w, 0]))) < 2.0
    gamma_rate = np.diff(np.arcsin(tr.arr("vel_enu_m_s")[w, 2] / np.linalg.norm(tr.arr("vel_enu_m_s")[w], axis=1)))
    assert np.sign(gamma_rate.mean()) == np.sign(up)


def test_bank_from_specific_force_pull_push_and_no_flip():
    """The bank that points the lift along the wanted force: a positive load beyond 90 deg or a negative
    load nearer upright, whichever is nearer the present bank; never a flip between them as the force
    crosses the velocity's horizon."""
    mb = math.radians(137.0)
    assert bank_from_specific_force(9.8, 0.0, 0.0, mb) == pytest.approx(0.0)
    assert bank_from_specific_force(5.0, 5.0, 0.0, mb) == pytest.approx(math.radians(45.0))
    # left and down: pull past -90 deg when already banked left, push (bank right, negative load) from upright
    assert bank_from_specific_force(-3.0, -4.0, math.radians(-60.0), mb) == pytest.approx(math.atan2(-4.0, -3.0))
    assert bank_from_specific_force(-3.0, -4.0, math.radians(10.0), mb) == pytest.approx(math.atan2(4.0, 3.0))
    # a push the wing cannot make (more than max_push) is flown as a pull
    assert bank_from_specific_force(-3.0, -4.0, math.radians(10.0), mb, max_push_m_s2=4.9) == pytest.approx(
        math.atan2(-4.0, -3.0))
    # the force's up part goes from +3 to -3 while it points left: the set-point moves smoothly
    bank, prev = math.radians(-60.0), None
    for fl in np.linspace(3.0, -3.0, 61):
        bank = bank_from_specific_force(fl, -6.0, bank, mb)
        if prev is not None:
            assert abs(bank - prev) < math.radians(5.0)
        prev = bank


def test_accel_mode_left_and_down_in_a_steep_dive_rolls_past_90_deg():
    """In a 45 deg dive, 8 m/s^2 left and 12 m/s^2 down (more than gravity's normal part): the autopilot
    rolls the lift past 90 deg and pulls; after 1 s the achieved acceleration is within 30 % of the
    command (which turns with the velocity as the dive steepens by ~15 deg/s), the bank set-point stays
    on the left side throughout, and the dive steepens."""
    f = Flight()
    f.fly(1.0, _accel(0.0, 0.0))
    f.fly(8.0, _accel(0.0, -6.0), stop=lambda s: flight_path_rad(s) < math.radians(-45.0))
    assert flight_path_rad(f.state) < math.radians(-44.0)
    gamma0 = flight_path_rad(f.state)
    tr = f.fly(2.0, _accel(-8.0, -12.0))
    bank_sp = tr.sp("bank_sp_rad")
    assert np.all(bank_sp < -math.radians(90.0)), np.degrees(bank_sp).max()
    w = tr.window(1.0, 2.0)
    err = np.linalg.norm(tr.sp("accel_enu_m_s2")[w] - tr.sp("accel_sp_enu_m_s2")[w], axis=1)
    assert np.max(err) < 0.3 * math.hypot(8.0, 12.0), np.max(err)
    assert flight_path_rad(tr.states[-1]) < gamma0 - math.radians(10.0)


@pytest.mark.parametrize("protected", [True, False])
def test_stall_protection_holds_alpha_below_the_stall(protected):
    """A sustained pull-up at idle power (the loiter's stall: the NMPC asked to climb, the aircraft could not)
    stalls the wing without the protection; with it the angle of attack stays near stall_alpha_rad."""
    f = Flight(airspeed_m_s=20.0)
    overrides = {} if protected else {"stall_pitch_rate_gain": 0.0}
    f.autopilot = Autopilot(load_autopilot_params("fwuav", overrides=overrides), f.airframe.dt_s,
                            f.airframe.trim.throttle_norm)
    tr = f.fly(25.0, lambda st: RateCommand(st.t_s, 12.0, 0.0, 0.3))  # airspeed 12 m/s wanted: throttle to idle
    alpha = np.degrees(tr.arr("alpha_rad"))
    limit = math.degrees(f.autopilot.p.v("stall_alpha_rad"))
    if protected:
        assert alpha.max() < limit + 2.5 and alpha[tr.window(10, 25)].mean() > limit - 2.0  # held, not avoided
    else:
        assert alpha.max() > 11.0  # past CLmax: the case the protection is for


@pytest.mark.parametrize("protected", [True, False])
def test_underspeed_protection_gives_the_airspeed_priority_over_a_held_climb(protected):
    """A climb held in acceleration mode (no acceleration asked: the path stays as it is) steeper than the
    engine can hold at 22 m/s: without the protection the airspeed bleeds toward the stall; with it the path
    bends down and the airspeed stays within the margin of its set-point (PX4's TECS: airspeed first)."""
    f = Flight()
    overrides = {} if protected else {"underspeed_accel_gain": 0.0}
    f.autopilot = Autopilot(load_autopilot_params("fwuav", overrides=overrides), f.airframe.dt_s,
                            f.airframe.trim.throttle_norm)
    f.fly(20.0, _accel(0.0, 0.6))  # pull up into a 30-deg climb
    tr = f.fly(120.0, _accel(0.0, 0.0))  # and hold it
    w = tr.window(40.0, 120.0)
    airspeed, alpha = tr.arr("airspeed_m_s")[w], np.degrees(tr.arr("alpha_rad")[w])
    margin = f.autopilot.p.v("underspeed_margin_m_s")
    if protected:
        assert airspeed.min() > 22.0 - margin - 1.0, airspeed.min()
        assert alpha.max() < math.degrees(f.autopilot.p.v("stall_alpha_rad")), alpha.max()
        assert f.autopilot.underspeed  # still climbing at full throttle, held at the margin
    else:
        assert airspeed.min() < 15.0, airspeed.min()


def test_status_is_the_last_actuate_s_and_step_gives_both():
    """The loop asks for the autopilot's status only at the log rate: status() describes the last actuate(),
    and step() is actuate() then status()."""
    f = Flight()
    ap = Autopilot(load_autopilot_params("fwuav"), f.airframe.dt_s, f.airframe.trim.throttle_norm)
    with pytest.raises(RuntimeError):
        ap.status()
    cmd = RateCommand(0.0, 22.0, 0.1, 0.02)
    act = ap.actuate(cmd, f.state)
    st = ap.status()
    assert st.t_s == f.state.t_s and st.airspeed_sp_m_s == 22.0 and st.mode == cmd.mode
    twin = Autopilot(load_autopilot_params("fwuav"), f.airframe.dt_s, f.airframe.trim.throttle_norm)
    act2, st2 = twin.step(cmd, f.state)
    assert act2 == act and np.array_equal(st2.body_rates_sp_frd_rad_s, st.body_rates_sp_frd_rad_s)
