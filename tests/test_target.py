"""Ship target: motion models against closed forms, config validation, mesh geometry."""
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from fwsim.interface.frames import wrap_pi
from fwsim.world.target import (
    INTEGRATION_STEP_S,
    Ship,
    TargetConfig,
    aim_point_ship_m,
    hull_height_m,
    ship_mesh,
    ship_mesh_parts,
)


def ship(**kw) -> Ship:
    return Ship(TargetConfig.model_validate(kw))


# --------------------------------------------------------------------------- config


def test_defaults_are_the_papers_ship():
    cfg = TargetConfig.model_validate({})
    assert (cfg.length_m, cfg.width_m, cfg.height_m) == (55.0, 25.0, 25.0)
    assert cfg.kind == "ship" and cfg.motion.model == "constant_velocity"
    assert cfg.initial_pos_enu_m == [0.0, 0.0, 0.0]


def _error_locs(data) -> list[tuple]:
    with pytest.raises(ValidationError) as exc:
        TargetConfig.model_validate(data)
    return [e["loc"] for e in exc.value.errors()]


@pytest.mark.parametrize("data, field", [
    ({"colour": "grey"}, "colour"),
    ({"initial_pos_enu_m": [10, 20, 1]}, "initial_pos_enu_m"),
    ({"initial_pos_enu_m": [0, 0]}, "initial_pos_enu_m"),
    ({"speed_m_s": -1}, "speed_m_s"),
    ({"speed_m_s": 30}, "speed_m_s"),
    ({"length_m": 0}, "length_m"),
    ({"motion": {"model": "constant_turn"}}, "turn_rate_deg_s"),
    ({"motion": {"model": "zigzag", "amplitude_deg": 10, "period_s": 60, "phase": 1}}, "phase"),
    ({"motion": {"model": "speed_changes", "times_s": [5, 5], "speeds_m_s": [1, 2]}}, "times_s"),
    ({"motion": {"model": "speed_changes", "times_s": [5, 6], "speeds_m_s": [1]}}, "speeds_m_s"),
    ({"motion": {"model": "hover"}}, "motion"),
])
def test_bad_config_error_names_the_field(data, field):
    locs = _error_locs(data)
    assert any(field in loc for loc in locs), locs


def test_nonzero_initial_z_message():
    with pytest.raises(ValidationError) as exc:
        TargetConfig.model_validate({"initial_pos_enu_m": [0, 0, 3]})
    (err,) = exc.value.errors()
    assert err["loc"] == ("initial_pos_enu_m",) and "z must be 0" in err["msg"]


def test_config_is_frozen():
    cfg = TargetConfig()
    with pytest.raises(ValidationError):
        cfg.speed_m_s = 3.0


# --------------------------------------------------------------------------- motion


def test_constant_velocity_closed_form():
    s = ship(initial_pos_enu_m=[100, -50, 0], heading_deg=30, speed_m_s=7)
    psi = math.radians(30)
    for t in (0.0, 0.5, 17.25, 1234.5):
        st_ = s.state(t)
        assert st_.t_s == t
        np.testing.assert_allclose(st_.pos_enu_m, [100 + 7 * t * math.sin(psi), -50 + 7 * t * math.cos(psi), 0],
                                   atol=1e-9)
        np.testing.assert_allclose(st_.vel_enu_m_s, [7 * math.sin(psi), 7 * math.cos(psi), 0], atol=1e-12)
        assert st_.heading_ned_rad == pytest.approx(psi) and st_.speed_m_s == 7


def test_heading_east_moves_plus_x():
    s = ship(heading_deg=90, speed_m_s=10)
    np.testing.assert_allclose(s.state(10.0).pos_enu_m, [100, 0, 0], atol=1e-9)
    pos, R = s.pose(10.0)
    np.testing.assert_allclose(R @ [1, 0, 0], [1, 0, 0], atol=1e-12)  # bow East
    np.testing.assert_allclose(R @ [0, 1, 0], [0, 1, 0], atol=1e-12)  # port North
    np.testing.assert_allclose(R @ [0, 0, 1], [0, 0, 1], atol=1e-12)


@pytest.mark.parametrize("heading_deg", [0.0, 45.0, -120.0, 200.0])
def test_pose_is_a_rotation_with_bow_along_velocity(heading_deg):
    s = ship(heading_deg=heading_deg, motion={"model": "constant_turn", "turn_rate_deg_s": 3})
    for t in (0.0, 11.0):
        pos, R = s.pose(t)
        v = s.state(t).vel_enu_m_s
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(R[:, 0] * np.linalg.norm(v), v, atol=1e-12)  # bow along the motion
        np.testing.assert_allclose(np.cross([0, 0, 1], R[:, 0]), R[:, 1], atol=1e-12)  # port is left of bow


@pytest.mark.parametrize("rate_deg_s", [2.0, -5.0])
def test_constant_turn_circle(rate_deg_s):
    v, om = 6.0, math.radians(rate_deg_s)
    s = ship(speed_m_s=v, motion={"model": "constant_turn", "turn_rate_deg_s": rate_deg_s})
    r = v / abs(om)
    # heading North; centre of the turn to the East (right) for om > 0, West for om < 0
    centre = np.array([math.copysign(r, om), 0.0, 0.0])
    for t in np.linspace(0, 400, 57):
        st_ = s.state(float(t))
        assert np.linalg.norm(st_.pos_enu_m - centre) == pytest.approx(r, abs=1e-8)
        assert st_.heading_ned_rad == pytest.approx(float(wrap_pi(om * t)), abs=1e-12)
        assert np.linalg.norm(st_.vel_enu_m_s) == pytest.approx(v)
    # positive turn rate: heading increases clockwise and the ship swings to the East
    p = s.state(5.0).pos_enu_m
    assert (p[0] > 0) == (om > 0) and p[1] > 0


def test_constant_turn_zero_rate_is_a_line():
    a = ship(heading_deg=20, motion={"model": "constant_turn", "turn_rate_deg_s": 0})
    b = ship(heading_deg=20)
    for t in (0.0, 3.0, 100.0):
        np.testing.assert_allclose(a.state(t).pos_enu_m, b.state(t).pos_enu_m, atol=1e-9)


def test_zigzag_heading_and_mean_direction():
    base, amp, period, v = 60.0, 25.0, 40.0, 8.0
    s = ship(heading_deg=base, speed_m_s=v, motion={"model": "zigzag", "amplitude_deg": amp, "period_s": period})
    ts = np.arange(0.0, 3 * period, 0.25)
    dev = np.degrees([wrap_pi(s.state(float(t)).heading_ned_rad - math.radians(base)) for t in ts])
    assert dev.max() == pytest.approx(amp, abs=0.05) and dev.min() == pytest.approx(-amp, abs=0.05)
    assert dev.max() <= amp + 1e-9 and dev.min() >= -amp - 1e-9
    # periodic with the given period
    for t in (3.0, 17.5, 31.0):
        assert s.state(t + period).heading_ned_rad == pytest.approx(s.state(t).heading_ned_rad, abs=1e-9)
    # displacement over whole periods: along the base heading, at mean speed v * J0(amp)
    d = s.state(3 * period).pos_enu_m - s.state(0.0).pos_enu_m
    b = math.radians(base)
    along = d[0] * math.sin(b) + d[1] * math.cos(b)
    across = d[0] * math.cos(b) - d[1] * math.sin(b)
    assert abs(across) < 1e-6
    a = math.radians(amp)
    j0 = sum((-1) ** k * (a / 2) ** (2 * k) / math.factorial(k) ** 2 for k in range(20))
    assert along == pytest.approx(v * 3 * period * j0, rel=1e-9)
    assert np.all(np.stack([s.state(float(t)).pos_enu_m for t in ts])[:, 2] == 0)


def test_speed_changes_ramp_at_the_accel_limit():
    a = 0.5
    s = ship(speed_m_s=5, heading_deg=90,
             motion={"model": "speed_changes", "times_s": [10, 40, 60], "speeds_m_s": [10, 4, 4.5], "accel_m_s2": a})
    sp = lambda t: s.state(t).speed_m_s  # noqa: E731
    assert sp(0.0) == 5 and sp(10.0) == 5  # config speed before the first time
    assert sp(15.0) == pytest.approx(7.5)  # ramping up at a
    assert sp(20.0) == pytest.approx(10.0) and sp(39.9) == pytest.approx(10.0)  # reached and held
    assert sp(45.0) == pytest.approx(7.5)  # ramping down at a
    assert sp(52.0) == pytest.approx(4.0) and sp(59.0) == pytest.approx(4.0)
    assert sp(61.0) == pytest.approx(4.5) and sp(500.0) == pytest.approx(4.5)
    # |dv/dt| never exceeds the limit
    ts = np.arange(0.0, 80.0, 0.01)
    v = np.array([sp(float(t)) for t in ts])
    assert np.abs(np.diff(v) / 0.01).max() <= a * (1 + 1e-9)
    # distance is the integral of the speed
    x = np.array([s.state(float(t)).pos_enu_m[0] for t in ts])
    np.testing.assert_allclose(x[1:] - x[:-1], 0.5 * (v[1:] + v[:-1]) * 0.01, atol=1e-9)


def test_speed_change_interrupted_ramp_turns_around():
    s = ship(speed_m_s=0, motion={"model": "speed_changes", "times_s": [0, 4], "speeds_m_s": [10, 0],
                                  "accel_m_s2": 1.0})
    assert s.state(4.0).speed_m_s == pytest.approx(4.0)  # 10 not reached by t = 4
    assert s.state(6.0).speed_m_s == pytest.approx(2.0)
    assert s.state(8.0).speed_m_s == pytest.approx(0.0) and s.state(20.0).speed_m_s == 0.0
    assert s.state(20.0).pos_enu_m[1] == pytest.approx(16.0)  # triangle: 0.5 * 8 s * 4 m/s


MOTIONS = [
    {"model": "constant_velocity"},
    {"model": "constant_turn", "turn_rate_deg_s": 4.0},
    {"model": "constant_turn", "turn_rate_deg_s": -1.5},
    {"model": "zigzag", "amplitude_deg": 30.0, "period_s": 20.0},
    {"model": "zigzag", "amplitude_deg": -10.0, "period_s": 90.0},
    {"model": "speed_changes", "times_s": [2.0, 9.0], "speeds_m_s": [12.0, 1.0], "accel_m_s2": 2.0},
]


@settings(max_examples=40, deadline=None)
@given(motion=st.sampled_from(MOTIONS), heading=st.sampled_from([0.0, 77.0, -150.0]),
       speed=st.sampled_from([0.0, 3.0, 15.0]), t=st.floats(0.01, 200.0))
def test_velocity_is_the_derivative_of_position(motion, heading, speed, t):
    s = ship(heading_deg=heading, speed_m_s=speed, motion=motion)
    h = 1e-4
    fd = (s.state(t + h).pos_enu_m - s.state(t - h).pos_enu_m) / (2 * h)
    # a speed ramp's corner inside [t - h, t + h] shifts the central difference by at most accel * h
    np.testing.assert_allclose(fd, s.state(t).vel_enu_m_s, atol=5e-4)
    hd = wrap_pi(s.state(t + h).heading_ned_rad - s.state(t - h).heading_ned_rad) / (2 * h)
    vel = s.state(t).vel_enu_m_s
    if s.state(t).speed_m_s > 0:
        assert math.atan2(vel[0], vel[1]) == pytest.approx(s.state(t).heading_ned_rad, abs=1e-9)
    if motion["model"] == "constant_turn":
        assert hd == pytest.approx(math.radians(motion["turn_rate_deg_s"]), abs=1e-6)


@pytest.mark.parametrize("motion", MOTIONS)
def test_out_of_order_equals_in_order(motion):
    ts = np.arange(0.0, 30.0, 1 / 120)
    a = ship(heading_deg=33, speed_m_s=6, motion=motion)
    b = ship(heading_deg=33, speed_m_s=6, motion=motion)
    in_order = [a.state(float(t)) for t in ts]
    rng = np.random.default_rng(0)
    for i in rng.permutation(len(ts))[:400]:
        sb = b.state(float(ts[i]))
        assert np.array_equal(sb.pos_enu_m, in_order[i].pos_enu_m)
        assert np.array_equal(sb.vel_enu_m_s, in_order[i].vel_enu_m_s)
        assert sb.heading_ned_rad == in_order[i].heading_ned_rad and sb.speed_m_s == in_order[i].speed_m_s


def test_zigzag_between_nodes_is_continuous():
    s = ship(speed_m_s=10, motion={"model": "zigzag", "amplitude_deg": 40, "period_s": 10})
    dt = INTEGRATION_STEP_S
    for k in (1, 7, 100):
        tk = k * dt
        left, right = s.state(tk - 1e-9).pos_enu_m, s.state(tk + 1e-9).pos_enu_m
        assert np.linalg.norm(right - left) < 1e-7


def test_negative_time_is_rejected():
    with pytest.raises(ValueError, match="t_s >= 0"):
        ship().state(-1.0)


# --------------------------------------------------------------------------- mesh


@pytest.mark.parametrize("dims", [(55.0, 25.0, 25.0), (120.0, 18.0, 30.0)])
def test_mesh_bounds_and_parts_are_closed(dims):
    L, W, H = dims
    cfg = TargetConfig(length_m=L, width_m=W, height_m=H)
    mesh = ship_mesh(cfg)
    np.testing.assert_allclose(mesh.bounds, [[-L / 2, -W / 2, 0], [L / 2, W / 2, H]], atol=1e-12)
    parts = dict(ship_mesh_parts(cfg))
    assert set(parts) >= {"hull", "mast"}
    for name, part in parts.items():
        assert part.is_watertight and part.is_winding_consistent and part.volume > 0, name
    # hull: 0.3 H high, full beam, bow tapering to a point
    hull = parts["hull"]
    assert hull.bounds[1, 2] == pytest.approx(hull_height_m(cfg)) == pytest.approx(0.3 * H)
    bow = hull.vertices[hull.vertices[:, 0] > L / 2 - 1e-9]
    np.testing.assert_allclose(bow[:, 1], 0.0, atol=1e-12)
    # superstructure: aft of midships, narrower than the beam; the mast reaches the full height
    for name in ("deckhouse", "wheelhouse"):
        b = parts[name].bounds
        assert b[1, 0] < 0 and b[1, 1] - b[0, 1] < W
    assert parts["mast"].bounds[1, 2] == pytest.approx(H)
    # the aim point lies inside the hull
    assert hull.contains([aim_point_ship_m(cfg)])[0]


def test_mesh_world_moves_with_the_ship():
    s = ship(heading_deg=90, speed_m_s=10, initial_pos_enu_m=[5, 5, 0])
    mw = s.mesh_world(2.0)
    np.testing.assert_allclose(mw.bounds, [[25 - 27.5, 5 - 12.5, 0], [25 + 27.5, 5 + 12.5, 25]], atol=1e-9)
    np.testing.assert_allclose(s.aim_point_enu_m(2.0), [25, 5, 0.5 * 7.5], atol=1e-12)
    assert s.mesh.bounds[0, 0] == pytest.approx(-27.5)  # the ship-frame mesh is untouched


def test_hull_volume_agrees_with_trimesh_point_in_mesh():
    import numpy as np

    from fwsim.world.target import HullVolume, TargetConfig, ship_mesh_parts
    cfg = TargetConfig()
    hull = HullVolume(cfg)
    pts = np.random.default_rng(0).uniform(hull.lo - 2.0, hull.hi + 2.0, (2000, 3))
    ours = np.array([hull.contains(p) for p in pts])
    ref = np.zeros(len(pts), bool)
    for _, part in ship_mesh_parts(cfg):
        ref |= part.contains(pts)
    assert 0.1 < ours.mean() < 0.9
    assert (ours == ref).mean() > 0.999


def test_manoeuvre_turns_at_its_rate_and_keeps_the_past():
    from fwsim.world.target import Ship, TargetConfig
    ship = Ship(TargetConfig.model_validate({"heading_deg": 0.0, "speed_m_s": 5.0}))
    before = ship.state(5.0)
    duration = ship.manoeuvre(10.0, course_deg=90.0, speed_m_s=None, turn_rate_deg_s=1.5, accel_m_s2=0.5)
    assert duration == pytest.approx(60.0)
    assert np.array_equal(ship.state(5.0).pos_enu_m, before.pos_enu_m)  # the past is not rewritten
    start = ship.state(10.0).pos_enu_m
    np.testing.assert_allclose(start, [0.0, 50.0, 0.0], atol=1e-12)
    assert math.degrees(ship.state(40.0).heading_ned_rad) == pytest.approx(45.0)
    R = 5.0 / math.radians(1.5)  # the arc of a constant-speed, constant-rate turn
    for tau in (10.0, 30.0, 60.0):
        a = math.radians(1.5) * tau
        np.testing.assert_allclose(ship.state(10.0 + tau).pos_enu_m - start,
                                   [R * (1 - math.cos(a)), R * math.sin(a), 0.0], atol=1e-6)
    end = ship.state(70.0)
    np.testing.assert_allclose(ship.state(80.0).pos_enu_m - end.pos_enu_m, [50.0, 0.0, 0.0], atol=1e-9)


def test_manoeuvre_changes_speed_and_turns_the_short_way():
    from fwsim.world.target import Ship, TargetConfig
    ship = Ship(TargetConfig.model_validate({"heading_deg": 10.0, "speed_m_s": 4.0}))
    duration = ship.manoeuvre(0.0, course_deg=340.0, speed_m_s=8.0, turn_rate_deg_s=2.0, accel_m_s2=0.5)
    assert duration == pytest.approx(max(30.0 / 2.0, 4.0 / 0.5))
    assert math.degrees(ship.state(5.0).heading_ned_rad) == pytest.approx(0.0, abs=1e-9)  # port, 30 deg away
    assert ship.state(4.0).speed_m_s == pytest.approx(6.0) and ship.state(20.0).speed_m_s == pytest.approx(8.0)
    # distance along the path: 4 t + t^2 / 4 over the 8 s ramp
    s = sum(ship.state(k * 0.01 + 0.01).speed_m_s * 0.01 for k in range(800))
    assert s == pytest.approx(4 * 8 + 64 / 4, rel=1e-3)


@pytest.mark.parametrize("kind", ["bridge_aft", "bridge_forward", "patrol_boat", "ferry"])
@pytest.mark.parametrize("dims", [(55.0, 25.0, 25.0), (28.0, 6.0, 9.0), (140.0, 24.0, 38.0)])
def test_every_ship_type_scales_and_is_closed(kind, dims):
    from fwsim.world.target import HULL_HEIGHT_FRAC, HullVolume
    L, W, H = dims
    cfg = TargetConfig(type=kind, length_m=L, width_m=W, height_m=H)
    np.testing.assert_allclose(ship_mesh(cfg).bounds, [[-L / 2, -W / 2, 0], [L / 2, W / 2, H]], atol=1e-9)
    parts = dict(ship_mesh_parts(cfg))
    for name, part in parts.items():
        assert part.is_watertight and part.is_winding_consistent and part.volume > 0, name
    assert parts["hull"].bounds[1, 2] == pytest.approx(HULL_HEIGHT_FRAC[kind] * H)
    hull = HullVolume(cfg)
    assert hull.contains(aim_point_ship_m(cfg))
    assert not hull.contains(np.array([0.0, 0.0, H + 0.1])) and not hull.contains(np.array([L / 2 + 0.1, 0, 0.1]))


def test_the_bridge_is_where_the_type_says():
    def house_x(kind):
        b = dict(ship_mesh_parts(TargetConfig(type=kind)))["wheelhouse"].bounds
        return 0.5 * (b[0, 0] + b[1, 0])
    assert house_x("bridge_aft") < 0 < house_x("bridge_forward")
    with pytest.raises(ValueError):
        TargetConfig(type="submarine")
