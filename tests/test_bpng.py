"""BPNG terminal guidance (controllers/guidance/bpng.py): geometry, sign, guards, kinematic closed loop."""
from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from controllers.guidance.bpng import Bpng, BpngConfig, BpngStatus, body_rates_from_accel, bpng_accel, vf_enu
from fwsim.interface.frames import dcm_enu_from_frd, enu_from_ned
from fwsim.interface.messages import AccelCommand

CFG = BpngConfig()
GAINS = dict(n_sigma=CFG.n_sigma, n_f=CFG.n_f, min_tgo_s=CFG.min_tgo_s, max_accel_m_s2=CFG.max_accel_m_s2,
             bias_angle_cap_rad=math.radians(CFG.bias_angle_cap_deg))  # the cap, without the capture guard
PRINTED = dict(GAINS, bias_angle_cap_rad=math.inf)  # the law as printed (no cap on the bias angle)
GUARD = dict(GAINS, capture_turn_rad_s=math.radians(CFG.capture_turn_deg_s))  # the defaults: the guard too


def _angle(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return math.atan2(np.linalg.norm(np.cross(a, b)), float(a @ b))


def _rotate_velocity(v, a, dt):
    """Exact constant-speed turn of v (..., 3) under the perpendicular acceleration a for dt."""
    vv = np.sum(v * v, axis=-1, keepdims=True)
    w = np.cross(v, a) / vv  # V_dot = w x V
    wn = np.linalg.norm(w, axis=-1, keepdims=True)
    k = w / np.where(wn > 0, wn, 1.0)
    ang = wn * dt
    along = k * np.sum(k * v, -1, keepdims=True)
    return v * np.cos(ang) + np.cross(k, v) * np.sin(ang) + along * (1 - np.cos(ang))


# --------------------------------------------------------------------------- config and geometry


def test_config_defaults_and_validation():
    cfg = BpngConfig.model_validate({})
    assert (cfg.n_sigma, cfg.n_f) == (6.0, 2.0)
    assert (cfg.impact_flight_path_deg, cfg.impact_heading_deg) == (-30.0, 30.0)
    assert cfg.aim_height_m == 0.0 and cfg.min_tgo_s == 0.5
    with pytest.raises(ValidationError):
        BpngConfig.model_validate({"no_such_key": 1})
    with pytest.raises(ValidationError):
        BpngConfig(impact_flight_path_deg=10.0)  # climbing impact: out of bounds
    with pytest.raises(ValidationError):
        cfg.n_f = 3.0  # frozen


def test_vf_enu_paper_case_points_down_and_north_north_east():
    vf = vf_enu(-30.0, 30.0)
    assert np.linalg.norm(vf) == pytest.approx(1.0)
    assert vf[2] < 0.0  # diving
    assert vf[1] > vf[0] > 0.0  # more North than East: between N and NE
    assert math.degrees(math.atan2(vf[0], vf[1])) == pytest.approx(30.0)  # heading clockwise from North
    assert math.degrees(math.asin(vf[2])) == pytest.approx(-30.0)
    th, ps = math.radians(-30.0), math.radians(30.0)
    paper_ned = [math.cos(th) * math.cos(ps), math.cos(th) * math.sin(ps), -math.sin(th)]
    np.testing.assert_allclose(vf, enu_from_ned(paper_ned), atol=1e-15)


# --------------------------------------------------------------------------- the law, by hand


def test_on_course_along_vf_gives_zero_command():
    vf = vf_enu(-30.0, 30.0)
    p, v = np.array([10.0, -20.0, 500.0]), 25.0 * vf
    q = p + 800.0 * vf  # target straight ahead along V = V_f, not moving: Omega = 0, theta = 0
    cmd, st = Bpng(CFG).step(0.0, p, v, q, np.zeros(3))
    np.testing.assert_allclose(cmd.accel_enu_m_s2, 0.0, atol=1e-12)
    np.testing.assert_allclose(st.los_rate_rad_s, 0.0, atol=1e-15)
    assert st.theta_err_rad == pytest.approx(0.0, abs=1e-7)
    assert st.range_m == pytest.approx(800.0) and st.t_go_s == pytest.approx(32.0)


def test_pn_term_crossing_geometry_by_hand():
    # UAV at the origin flying East at 20 m/s; target at (600, 800, 0) moving East at 10 m/s.
    # r = (600, 800, 0), r_dot = (-10, 0, 0): r x r_dot = (0, 0, 8000), |r|^2 = 1e6 -> Omega = (0, 0, 0.008)
    # Omega x V = (0, 0, 0.008) x (20, 0, 0) = (0, 0.16, 0); N_sigma = 6 -> (0, 0.96, 0)
    t = bpng_accel([600.0, 800.0, 0.0], [-10.0, 0.0, 0.0], [20.0, 0.0, 0.0], [1.0, 0.0, 0.0], **GAINS)
    np.testing.assert_allclose(t.los_rate_rad_s, [0.0, 0.0, 0.008], atol=1e-15)
    np.testing.assert_allclose(t.accel_pn, [0.0, 0.96, 0.0], atol=1e-12)
    np.testing.assert_allclose(t.accel_bias, 0.0, atol=1e-15)  # V already along V_f
    np.testing.assert_allclose(t.accel_cmd, [0.0, 0.96, 0.0], atol=1e-12)
    assert t.t_go_s == pytest.approx(1000.0 / 20.0)


def test_bias_term_turns_velocity_away_from_vf_as_printed_in_the_paper():
    """The sign of eq. (26)'s bias term (module docstring): V_p x n turns V AWAY from V_f.

    Finite difference: a short constant-speed step under the bias acceleration
    changes theta = angle(V, V_f) at d theta/dt = +N_f theta / t_go; the PN term
    is zero here (stationary target straight ahead: no LOS rate).
    """
    vf = vf_enu(-30.0, 30.0)
    v = 25.0 * np.array([math.sin(math.radians(80.0)), math.cos(math.radians(80.0)), 0.0])  # level, heading 80
    r = 1000.0 * v / 25.0
    t = bpng_accel(r, -v, v, vf, **GAINS)
    np.testing.assert_allclose(t.accel_pn, 0.0, atol=1e-12)
    theta0 = _angle(v, vf)
    assert t.theta_err_rad == pytest.approx(theta0)
    rate = CFG.n_f * theta0 / t.t_go_s
    assert np.linalg.norm(t.accel_bias) == pytest.approx(rate * 25.0)
    assert abs(t.accel_bias @ v) < 1e-12
    dt = 1e-4
    theta1 = _angle(_rotate_velocity(v, t.accel_bias, dt), vf)
    assert (theta1 - theta0) / dt == pytest.approx(+rate, rel=1e-3)  # away from V_f
    # the flipped ("toward V_f") sign would give -rate; the optimal law is the printed one:
    n = np.cross(v, vf) / np.linalg.norm(np.cross(v, vf))
    np.testing.assert_allclose(t.accel_bias, (CFG.n_f * theta0 / t.t_go_s) * np.cross(v, n), atol=1e-12)


def test_planar_small_angles_equal_the_energy_optimal_impact_angle_law():
    """Eq. (26) with N = 6, N_f = 2 is the linear optimal law a = -(6y + 4 y' T + 2 V gamma_f T) / T^2."""
    V, R = 25.0, 1000.0
    T = R / V
    for y0, gam, gam_f in [(3.0, 2e-3, -4e-3), (-2.0, -1e-3, 3e-3), (1.0, 4e-3, 1e-3), (0.0, 0.0, 5e-3)]:
        p = np.array([0.0, y0, 500.0])  # horizontal plane: x downrange (East), y lateral (North)
        q = np.array([R, 0.0, 500.0])
        v = V * np.array([math.cos(gam), math.sin(gam), 0.0])
        vf = np.array([math.cos(gam_f), math.sin(gam_f), 0.0])
        t = bpng_accel(q - p, -v, v, vf, **GAINS)
        a_opt = -(6.0 * y0 + 4.0 * V * gam * T + 2.0 * V * gam_f * T) / T**2
        assert abs(t.accel_cmd[2]) < 1e-12
        assert t.accel_cmd[1] == pytest.approx(a_opt, rel=2e-2, abs=1e-5), (y0, gam, gam_f)


# --------------------------------------------------------------------------- guards


def _rand_inputs(rng, n):
    r = rng.normal(size=(n, 3)) * rng.choice([1e-4, 1.0, 100.0, 2000.0], size=(n, 1))
    v = rng.normal(size=(n, 3)) * 25.0
    vq = rng.normal(size=(n, 3)) * 5.0
    vf = rng.normal(size=(n, 3))
    return r, vq - v, v, vf


def test_command_is_perpendicular_finite_and_capped_on_random_inputs():
    rng = np.random.default_rng(7)
    r, rdot, v, vf = _rand_inputs(rng, 5000)
    t = bpng_accel(r, rdot, v, vf, **GAINS)
    a = t.accel_cmd
    assert np.all(np.isfinite(a)) and np.all(np.isfinite(t.t_go_s)) and np.all(np.isfinite(t.los_rate_rad_s))
    speed = np.linalg.norm(v, axis=-1)
    assert np.max(np.abs(np.sum(a * v, -1)) / speed) < 1e-9
    mag = np.linalg.norm(a, axis=-1)
    assert np.max(mag) <= CFG.max_accel_m_s2 * (1 + 1e-12)
    assert np.all(t.t_go_s >= CFG.min_tgo_s)
    # the cap keeps the direction of the (perpendicular) sum
    s = t.accel_pn + t.accel_bias
    s -= (np.sum(s * v, -1) / speed**2)[:, None] * v
    sat = t.saturated
    assert sat.any() and (~sat).any()
    np.testing.assert_allclose(a[~sat], s[~sat], atol=1e-9)
    cosang = np.sum(a[sat] * s[sat], -1) / (mag[sat] * np.linalg.norm(s[sat], axis=-1))
    assert np.min(cosang) > 1 - 1e-12


def test_guards_parallel_antiparallel_tgo_and_range():
    v = np.array([25.0, 0.0, 0.0])
    # parallel: V along V_f with a LOS rate: bias exactly 0
    t = bpng_accel([500.0, 100.0, -50.0], -v, v, [1.0, 0.0, 0.0], **GAINS)
    np.testing.assert_allclose(t.accel_bias, 0.0, atol=0.0)
    assert np.linalg.norm(t.accel_pn) > 0
    # anti-parallel: n in the vertical plane containing V -> a level turn, toward the target side
    for side in (+1.0, -1.0):
        t = bpng_accel([500.0, side * 50.0, -100.0], -v, v, [-1.0, 0.0, 0.0], **GAINS)
        assert t.theta_err_rad == pytest.approx(math.pi)
        b = t.accel_bias
        assert np.all(np.isfinite(b)) and abs(b[2]) < 1e-12 and abs(b[0]) < 1e-12  # horizontal, perpendicular
        assert np.sign(b[1]) == side  # toward the target's side
        cap = min(math.pi, math.radians(CFG.bias_angle_cap_deg))
        assert np.linalg.norm(b) == pytest.approx(CFG.n_f * cap / t.t_go_s * 25.0)
        assert np.linalg.norm(t.accel_cmd) <= CFG.max_accel_m_s2 + 1e-12
    # anti-parallel with a vertical velocity (dive straight down, V_f straight up): still finite and level
    vd = np.array([0.0, 0.0, -25.0])
    t = bpng_accel([3.0, 4.0, -500.0], -vd, vd, [0.0, 0.0, 1.0], **GAINS)
    assert np.all(np.isfinite(t.accel_cmd)) and abs(t.accel_cmd[2]) < 1e-12
    # t_go -> 0 and r -> 0: t_go floored, Omega 0 at r = 0, command finite and capped
    for r in ([1e-2, 1e-3, 0.0], [1e-9, 0.0, 0.0], [0.0, 0.0, 0.0]):
        t = bpng_accel(r, [-25.0, 3.0, 1.0], v, vf_enu(-30.0, 30.0), **GAINS)
        assert t.t_go_s == CFG.min_tgo_s
        assert np.all(np.isfinite(t.accel_cmd)) and np.linalg.norm(t.accel_cmd) <= CFG.max_accel_m_s2 + 1e-12
        assert np.all(np.isfinite(t.los_rate_rad_s))
    # V_p -> 0: no direction, no command
    t = bpng_accel([100.0, 0.0, -50.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], **GAINS)
    np.testing.assert_allclose(t.accel_cmd, 0.0, atol=0.0)
    assert np.isfinite(t.t_go_s)


# --------------------------------------------------------------------------- the block and the body rates


def test_bpng_step_matches_the_law_and_fills_the_messages():
    cfg = BpngConfig(aim_height_m=5.0, airspeed_m_s=21.0)
    g = Bpng(cfg)
    p, v = np.array([-900.0, 300.0, 480.0]), np.array([22.0, -3.0, -4.0])
    q, vq = np.array([10.0, -5.0, 0.0]), np.array([4.0, 3.0, 0.0])
    cmd, st = g.step(12.5, p, v, q, vq)
    t = bpng_accel(q + [0, 0, 5.0] - p, vq - v, v, vf_enu(-30.0, 30.0), n_sigma=6, n_f=2, min_tgo_s=0.5,
                   max_accel_m_s2=25.0)
    assert isinstance(cmd, AccelCommand) and cmd.mode == "accel"
    assert cmd.t_s == 12.5 and cmd.airspeed_m_s == 21.0
    np.testing.assert_allclose(cmd.accel_enu_m_s2, t.accel_cmd)
    assert isinstance(st, BpngStatus) and st.t_s == 12.5
    np.testing.assert_allclose(st.accel_cmd, cmd.accel_enu_m_s2)
    np.testing.assert_allclose(st.accel_pn, t.accel_pn)
    np.testing.assert_allclose(st.accel_bias, t.accel_bias)
    assert st.range_m == pytest.approx(np.linalg.norm(q + [0, 0, 5.0] - p))
    assert st.theta_err_rad == pytest.approx(_angle(v, vf_enu(-30.0, 30.0)))
    # an estimate that is not valid yet: fly straight, say so with NaN
    cmd, st = g.step(13.0, p, v, np.full(3, np.nan), vq)
    np.testing.assert_array_equal(cmd.accel_enu_m_s2, 0.0)
    assert math.isnan(st.range_m)


def test_body_rates_from_accel_is_the_papers_decomposition():
    V = 20.0
    # level, heading North: body y (right) = East, body z = down
    np.testing.assert_allclose(body_rates_from_accel([5.0, 0.0, 0.0], [0.0, 0.0, 0.0], V), [0, 0, 5.0 / V],
                               atol=1e-12)  # u_r = u_y / V: turn right
    np.testing.assert_allclose(body_rates_from_accel([0.0, 0.0, 5.0], [0.0, 0.0, 0.0], V), [0, 5.0 / V, 0],
                               atol=1e-12)  # u_q = -u_z / V: pull up
    # any attitude: omega x [V, 0, 0] reproduces the perpendicular acceleration in the body frame
    rng = np.random.default_rng(3)
    for _ in range(20):
        eul = rng.uniform([-1.0, -1.2, -3.0], [1.0, 1.2, 3.0])
        R = dcm_enu_from_frd(eul)
        u_b = np.array([0.0, *rng.normal(size=2) * 5.0])
        w = body_rates_from_accel(R @ u_b, eul, V)
        assert w[0] == 0.0
        np.testing.assert_allclose(np.cross(w, [V, 0.0, 0.0]), u_b, atol=1e-12)


# --------------------------------------------------------------------------- kinematic closed loop

V_UAV = 25.0
DT = 0.02
H0 = 500.0  # every start is 500 m above the sea
D0 = 1100.0  # "pointing" starts: 1100 m horizontally from the ship (slant range 1208 m)
R_LOITER = 500.0  # "loiter" starts: on the paper's 500 m loiter circle, velocity along the circle
THETA_FS = (-20.0, -30.0, -45.0, -60.0)
PSI_FS = (0.0, 60.0, 120.0, 180.0, 240.0, 300.0)
# Start geometry. The law's capture region is limited (module docstring): from an approach direction far
# from the impact heading the bias drives V to -V_f and the UAV flies away. Phase 3 starts from the loiter
# around the ship, so the mission picks where (the phase switch). Starts, each as (horizontal distance,
# velocity heading minus bearing to the ship, delta = bearing to the ship minus psi_f), all level at 25 m/s:
STARTS = (
    (D0, 0.0, -30.0), (D0, 0.0, 0.0), (D0, 0.0, 30.0),  # pointing at the ship, bearing within 30 deg of psi_f
    (R_LOITER, 90.0, -10.0), (R_LOITER, 90.0, 10.0),  # on the loiter circle, counter-clockwise orbit
    (R_LOITER, -90.0, -10.0), (R_LOITER, -90.0, 10.0),  # on the loiter circle, clockwise orbit
)
SHIPS = {"10mps_east": (10.0, 90.0), "6mps_ssw": (6.0, 200.0)}  # speed m/s, heading deg clockwise from N
MISS_M, ANGLE_DEG = 3.0, 3.0


def _fly(p, v, q, vq, vf, bias_sign=1.0, t_max_s=250.0, gains=None):
    """Point-mass UAV at constant speed turned by the BPNG command (gravity compensated by the autopilot)."""
    gains = GAINS if gains is None else gains
    n = len(p)
    done = np.zeros(n, bool)
    miss = np.full(n, np.inf)
    v_imp = np.zeros((n, 3))
    min_h = np.full(n, np.inf)  # lowest height above the ship's plane while > 10 m from it
    for _ in range(int(t_max_s / DT)):
        t = bpng_accel(q - p, vq - v, v, vf, **gains)
        a = t.accel_cmd
        if bias_sign != 1.0:  # the flipped bias, with the same perpendicular projection and cap
            a = t.accel_pn + bias_sign * t.accel_bias
            a = a - (np.sum(a * v, -1) / np.sum(v * v, -1))[:, None] * v
            m = np.linalg.norm(a, axis=-1)
            a = a * np.minimum(1.0, CFG.max_accel_m_s2 / np.maximum(m, 1e-12))[:, None]
        v1 = _rotate_velocity(v, a, DT)
        p1 = p + 0.5 * (v + v1) * DT
        q1 = q + vq * DT
        r0, r1 = q - p, q1 - p1  # closest approach inside the step (relative motion ~ linear)
        d = r1 - r0
        s = np.clip(-np.sum(r0 * d, -1) / np.maximum(np.sum(d * d, -1), 1e-12), 0.0, 1.0)
        dist = np.linalg.norm(r0 + s[:, None] * d, axis=-1)
        active = ~done
        better = active & (dist < miss)
        miss = np.where(better, dist, miss)
        v_imp = np.where(better[:, None], v + s[:, None] * (v1 - v), v_imp)
        far = active & (np.linalg.norm(r0, axis=-1) > 10.0)
        min_h = np.where(far, np.minimum(min_h, p[:, 2] - q[:, 2]), min_h)
        done |= active & (np.linalg.norm(r1, axis=-1) < 60.0) & (np.sum(r1 * (vq - v1), -1) > 0.0)  # receding
        p, v, q = p1, v1, q1
        if done.all():
            break
    gam = np.degrees(np.arcsin(v_imp[:, 2] / np.maximum(np.linalg.norm(v_imp, axis=-1), 1e-12)))
    hdg = np.degrees(np.arctan2(v_imp[:, 0], v_imp[:, 1]))
    return miss, gam, hdg, min_h, done


def _sweep_cases(ship):
    cases = [(th, ps, *st) for th in THETA_FS for ps in PSI_FS for st in STARTS]
    th, ps, dist, off, de = (np.array(c) for c in zip(*cases))
    chi = np.radians(ps + de)  # horizontal direction UAV -> ship
    los = np.stack([np.sin(chi), np.cos(chi), np.zeros_like(chi)], -1)
    hv = chi + np.radians(off)
    p = -dist[:, None] * los + [0.0, 0.0, H0]
    v = V_UAV * np.stack([np.sin(hv), np.cos(hv), np.zeros_like(hv)], -1)
    spd, hdg = SHIPS[ship]
    vq = np.tile([spd * math.sin(math.radians(hdg)), spd * math.cos(math.radians(hdg)), 0.0], (len(cases), 1))
    vf = np.stack([vf_enu(a, b) for a, b in zip(th, ps)])
    start = [f"dist={d:.0f} m vel-vs-bearing={o:+.0f} delta={e:+.0f}" for d, o, e in zip(dist, off, de)]
    return th, ps, dist, start, p, v, np.zeros_like(p), vq, vf


@pytest.mark.parametrize("guard", [False, True])
@pytest.mark.parametrize("ship", sorted(SHIPS))
def test_closed_loop_sweep_hits_with_the_impact_angle(ship, guard):
    th, ps, dist, start, p, v, q, vq, vf = _sweep_cases(ship)
    miss, gam, hdg, min_h, done = _fly(p, v, q, vq, vf, gains=GUARD if guard else GAINS)
    e_gam = np.abs(gam - th)
    e_hdg = np.abs((hdg - ps + 180.0) % 360.0 - 180.0)
    # Sea clearance (not one of the 3 m / 3 deg bars; a sanity check of the path): the UAV stays above the sea
    # until 10 m from the aim point. Known limit, exempt: from the loiter circle the LOS is 45 deg down, and
    # an impact much shallower than that (-20 deg) makes the optimal path bow under the LOS; with the ship
    # crossing the impact heading it levels off a few metres below the sea hundreds of metres short.
    exempt = (dist == R_LOITER) & (th > -30.0)
    print(f"\n[{ship}] {len(th)} cases: max miss {miss.max():.2e} m, max flight-path error {e_gam.max():.2f} deg, "
          f"max heading error {e_hdg.max():.2f} deg, lowest height before the target {min_h[~exempt].min():.1f} m "
          f"({min_h[exempt].min():.1f} m in the exempt shallow-from-loiter cases)")
    bad = ~done | (miss > MISS_M) | (e_gam > ANGLE_DEG) | (e_hdg > ANGLE_DEG) | ((min_h < 0.0) & ~exempt)
    lines = [f"theta_f={th[i]:.0f} psi_f={ps[i]:.0f} start: {start[i]} ship={ship}: miss={miss[i]:.2f} m "
             f"flight-path err={e_gam[i]:.2f} deg heading err={e_hdg[i]:.2f} deg min height={min_h[i]:.1f} m "
             f"done={done[i]}" for i in np.flatnonzero(bad)]
    assert not lines, "failing cases:\n" + "\n".join(lines)


def test_flipped_bias_sign_misses_the_impact_angle():
    """The 'toward V_f' variant of the bias term (a proposed correction of eq. (26)) fails the paper case."""
    th, ps = -30.0, 30.0
    chi = math.radians(ps)
    d = np.array([[math.sin(chi), math.cos(chi), 0.0]])
    p, v, vf = -D0 * d + [0.0, 0.0, H0], V_UAV * d, vf_enu(th, ps)[None]
    q, vq = np.zeros((1, 3)), np.zeros((1, 3))
    miss, gam, hdg, _, _ = _fly(p, v, q, vq, vf)
    assert miss[0] < MISS_M and abs(gam[0] - th) < 1.0 and abs(hdg[0] - ps) < 1.0
    miss, gam, hdg, _, _ = _fly(p, v, q, vq, vf, bias_sign=-1.0)
    err = max(abs(gam[0] - th), abs((hdg[0] - ps + 180.0) % 360.0 - 180.0))
    assert err > 2.0 * ANGLE_DEG, (miss[0], gam[0], hdg[0])  # ~11 deg: arrives at -19 deg instead of -30


def test_bias_angle_cap_only_acts_past_it():
    v = np.array([20.0, 0.0, 0.0])
    for ang, same in ((60.0, True), (89.0, True), (120.0, False)):
        vf = [math.cos(math.radians(ang)), math.sin(math.radians(ang)), 0.0]
        capped = bpng_accel([500.0, 50.0, -100.0], -v, v, vf, **GAINS)
        printed = bpng_accel([500.0, 50.0, -100.0], -v, v, vf, **PRINTED)
        assert np.allclose(capped.accel_bias, printed.accel_bias) == same
        np.testing.assert_allclose(capped.accel_pn, printed.accel_pn)
        if not same:  # the bias keeps its 90-degree value, direction unchanged
            np.testing.assert_allclose(capped.accel_bias, printed.accel_bias * (90.0 / ang), rtol=1e-9)
    assert BpngConfig(bias_angle_cap_deg=None).bias_angle_cap_deg is None


def test_from_a_loiter_round_a_fast_ship_the_cap_keeps_the_ship_in_the_capture_region():
    """The loiter round a 10 m/s ship crossing the impact heading (theta_f -30, psi_f 30, ship heading 270):
    at the switch (bearing to the ship = psi_f) the ground velocity is ~100 deg off V_f. The printed law's
    bias cancels the PN term and the UAV flies away; with the cap it turns in and hits at the impact angle."""
    from fwsim.batch.cases import _orbit_heading_deg
    th, ps, ship_hdg, ship_speed = -30.0, 30.0, 270.0, 10.0
    b = math.radians(ps)  # bearing UAV -> ship at the switch
    p = np.array([[-500.0 * math.sin(b), -500.0 * math.cos(b), 500.0]])
    h = math.radians(_orbit_heading_deg(b, ship_hdg, ship_speed, 22.0))
    vq = ship_speed * np.array([[math.sin(math.radians(ship_hdg)), math.cos(math.radians(ship_hdg)), 0.0]])
    v = np.array([[22.0 * math.sin(h), 22.0 * math.cos(h), 0.0]]) + vq  # ground velocity on the orbit
    v = V_UAV * v / np.linalg.norm(v)
    vf = vf_enu(th, ps)[None]
    assert math.degrees(_angle(v[0], vf[0])) > 90.0
    miss, gam, hdg, _, done = _fly(p, v, np.zeros((1, 3)), vq, vf, gains=PRINTED, t_max_s=120.0)
    assert not (done[0] and miss[0] < MISS_M)  # the printed law does not get there
    miss, gam, hdg, _, done = _fly(p, v, np.zeros((1, 3)), vq, vf)
    assert done[0] and miss[0] < MISS_M, miss[0]
    assert abs(gam[0] - th) < ANGLE_DEG and abs((hdg[0] - ps + 180.0) % 360.0 - 180.0) < ANGLE_DEG, (gam, hdg)


# Dive starts from loiters round fast ships in wind, taken from flights whose dives held their range (the UAV's
# ground velocity and the ship's at the switch; r from the UAV to the steering point; theta_f, psi_f): far off
# the nose (look angles 77-104 deg) with a LOS rate of 0.010-0.012 rad/s, where the bias cancels the PN term.
STALLS = {
    "range_held": ([-386.4, 532.5, -747.1], [-9.97, -14.43, 0.2], [-1.68, -8.52, 0.0], -39.5, 324.2),
    "flies_away": ([474.1, -354.6, -425.6], [-15.07, -8.99, 0.4], [-9.72, -2.27, 0.0], -41.3, 126.5),
    "slow_close": ([742.6, 5.1, -721.3], [5.61, -16.6, 0.02], [5.56, -5.81, 0.0], -47.6, 89.4),
}


def _range_after(r, v, vq, vf, gains, t_s):
    p, v, q, vq = -np.array([r]), np.array([v]), np.zeros((1, 3)), np.array([vq])
    for _ in range(int(t_s / DT)):
        v1 = _rotate_velocity(v, bpng_accel(q - p, vq - v, v, vf, **gains).accel_cmd, DT)
        p, v, q = p + 0.5 * (v + v1) * DT, v1, q + vq * DT
    return float(np.linalg.norm(q - p))


def test_the_capture_guard_turns_a_stalled_dive_toward_the_ship():
    """The three stalls: the printed law (with the bias cap) holds the range for 20 s or flies away; with the
    capture guard every one closes (5 % or more of its range in 20 s) and hits within 3 m and 3 deg."""
    for name, (r, v, vq, th, ps) in STALLS.items():
        vf = vf_enu(th, ps)[None]
        r0 = float(np.linalg.norm(r))
        off = _range_after(r, v, vq, vf, GAINS, 20.0)
        on = _range_after(r, v, vq, vf, GUARD, 20.0)
        assert on < 0.95 * r0, (name, r0, on)
        miss, gam, hdg, _, done = _fly(-np.array([r]), np.array([v]), np.zeros((1, 3)), np.array([vq]), vf,
                                       gains=GUARD, t_max_s=300.0)
        assert done[0] and miss[0] < MISS_M, (name, miss)
        assert abs(gam[0] - th) < ANGLE_DEG and abs((hdg[0] - ps + 180.0) % 360.0 - 180.0) < ANGLE_DEG, (name, gam)
        if name != "slow_close":  # without it: the range held (the go-around's 2 %) or growing
            assert off > 0.98 * r0, (name, r0, off)
    miss, *_, done = _fly(-np.array([STALLS["flies_away"][0]]), np.array([STALLS["flies_away"][1]]),
                          np.zeros((1, 3)), np.array([STALLS["flies_away"][2]]),
                          vf_enu(*STALLS["flies_away"][3:])[None], gains=GAINS, t_max_s=300.0)
    assert not (done[0] and miss[0] < MISS_M)  # the printed law does not get there


def test_the_capture_guard_only_acts_far_off_the_nose_where_the_bias_cancels_pn():
    """The guard's share of the bias: 1 wherever the command already turns V toward the line of sight at the
    guard's rate, or the look angle is under capture_look_deg; below 1 only in the stall, where it lifts the
    turn toward the line of sight to exactly the guard's rate."""
    rate = math.radians(3.0)
    r, v, vq, th, ps = STALLS["range_held"]
    k = bpng_accel(r, np.subtract(vq, v), v, vf_enu(th, ps), **GUARD)
    assert 0.0 < float(k.bias_scale) < 1.0
    off = bpng_accel(r, np.subtract(vq, v), v, vf_enu(th, ps), **GAINS)
    assert float(off.bias_scale) == 1.0 and np.allclose(off.accel_pn, k.accel_pn)
    r_hat, v_hat = np.asarray(r) / np.linalg.norm(r), np.asarray(v) / np.linalg.norm(v)
    e = r_hat - (r_hat @ v_hat) * v_hat
    e /= np.linalg.norm(e)
    assert float(k.accel_cmd @ e) == pytest.approx(rate * np.linalg.norm(v), rel=1e-6)
    assert float(off.accel_cmd @ e) < 0.5 * rate * np.linalg.norm(v)
    # the kinematic sweep's starts pointing at the ship: never held back
    for ship in SHIPS:
        _, _, dist, _, p, v0, q, vq0, vf = _sweep_cases(ship)
        assert np.all(bpng_accel(q - p, vq0 - v0, v0, vf, **GUARD).bias_scale[dist == D0] == 1.0)
    # near the nose nothing changes, whatever the bias (look angle 30 deg, a bias far larger than PN)
    r2, v2 = [1000.0, 577.0, -50.0], [25.0, 0.0, 0.0]
    k2 = bpng_accel(r2, [-25.0, 0.0, 0.0], v2, vf_enu(-60.0, 300.0), **GUARD)
    assert float(k2.bias_scale) == 1.0
    assert BpngConfig(capture_turn_deg_s=None).capture_turn_deg_s is None


def test_endgame_flies_straight_and_the_caller_may_place_the_aim():
    """Inside endgame_tgo_s of the steering point (endgame_align_s none) the command is zero, to the impact;
    ``aim_enu`` replaces the aim point."""
    b = Bpng(BpngConfig(endgame_tgo_s=0.25, endgame_align_s=None))
    v = np.array([0.0, 40.0, -20.0])
    aim = np.array([3.0, 9.0, -2.0])  # 9.7 m ahead, off the velocity: PN would command a large turn
    cmd, st = b.step(0.0, np.zeros(3), v, np.zeros(3), np.zeros(3), aim_enu=aim)
    assert st.endgame and np.all(cmd.accel_enu_m_s2 == 0.0)
    assert st.aim_enu_m == pytest.approx(aim)
    far = np.array([30.0, 90.0, -60.0])
    cmd, st = b.step(0.1, np.zeros(3), v, np.zeros(3), np.zeros(3), aim_enu=far)
    assert st.endgame and np.all(cmd.accel_enu_m_s2 == 0.0)  # latched: past the point the LOS turns round
    b = Bpng(BpngConfig(endgame_tgo_s=0.25, endgame_align_s=None))
    cmd, st = b.step(0.0, np.zeros(3), v, np.zeros(3), np.zeros(3), aim_enu=far)
    assert not st.endgame and np.linalg.norm(cmd.accel_enu_m_s2) > 1.0
    _, st = b.step(0.0, np.zeros(3), v, np.array([100.0, 0.0, 0.0]), np.zeros(3))
    assert st.aim_enu_m == pytest.approx(b.aim_point([100.0, 0.0, 0.0]))


def test_endgame_turns_the_velocity_onto_v_f_whatever_the_los_does():
    """With endgame_align_s the endgame ignores the LOS (which a near hit spins) and turns V onto V_f: the
    command is perpendicular to V, in the plane of V and V_f, toward V_f, of size |V| theta / tau (capped);
    integrated, the angle decays like exp(-t / tau) and no LOS is needed."""
    tau = 0.25
    b = Bpng(BpngConfig(impact_flight_path_deg=-30.0, impact_heading_deg=30.0, endgame_tgo_s=0.4,
                        endgame_align_s=tau))
    vf = vf_enu(-30.0, 30.0)
    # 4 deg above V_f (shallower), 40 m/s, the steering point 10 m ahead and 2 m to the side
    axis = np.cross(vf, [0.0, 0.0, 1.0])
    axis /= np.linalg.norm(axis)
    th = math.radians(4.0)
    vhat = vf * math.cos(th) + np.cross(axis, vf) * math.sin(th) + axis * (axis @ vf) * (1 - math.cos(th))
    v = 40.0 * vhat
    theta0 = math.acos(float(np.clip(vhat @ vf, -1, 1)))
    aim = 10.0 * vhat + 2.0 * axis
    cmd, st = b.step(0.0, np.zeros(3), v, np.zeros(3), np.zeros(3), aim_enu=aim)
    a = cmd.accel_enu_m_s2
    assert st.endgame
    assert abs(a @ v) < 1e-9 * np.linalg.norm(a) * 40.0
    assert np.linalg.norm(a) == pytest.approx(40.0 * theta0 / tau, rel=1e-9)
    assert np.linalg.det(np.stack([v, vf, a])) == pytest.approx(0.0, abs=1e-6)  # in the plane of V and V_f
    assert a @ vf > 0.0  # toward V_f
    # fly it as a point mass (speed kept): the angle decays like exp(-t / tau)
    p, dt = np.zeros(3), 0.002
    for k in range(100):
        cmd, st = b.step(k * dt, p, v, np.zeros(3), np.zeros(3), aim_enu=aim)
        v = v + cmd.accel_enu_m_s2 * dt
        v *= 40.0 / np.linalg.norm(v)
        p = p + v * dt
    theta = math.acos(float(np.clip(v @ vf / 40.0, -1, 1)))
    assert theta == pytest.approx(theta0 * math.exp(-0.2 / tau), rel=0.02)
