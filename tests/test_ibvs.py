"""Tests for controllers.pointing.ibvs: feature kinematics, the law vs the paper's form, limits, singularity,
closed loop.

The closed-loop tests fly a kinematic world (no JSBSim): a UAV on a straight line
or a circle at 22 m/s, the harness's Gimbal integrating the commanded rates with
its rate and joint limits, a ship at 5 m/s, and a perfect pinhole projection
(detections at 30 Hz, the controller at 120 Hz).
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from pydantic import ValidationError

from controllers.pointing import ibvs as I
from fwsim.interface import frames as F
from fwsim.world.gimbal import Gimbal, GimbalConfig
from fwsim.interface.messages import Measurements

PI = math.pi
W_PX, H_PX = 1280, 720
FX = FY = 0.5 * W_PX / math.tan(math.radians(30.0))  # 60 deg horizontal FOV
CX, CY = 0.5 * W_PX, 0.5 * H_PX
MOUNT = np.array([0.0, 0.0, 0.1])
G = 9.81
V_UAV = 22.0
DT = 1.0 / 120.0
DET_EVERY = 4  # detections at 30 Hz


# --------------------------------------------------------------------------- configuration


def test_config_defaults_and_validation():
    cfg = I.IbvsConfig.model_validate({})
    assert cfg.lambda_1_s == 1.5 and cfg.feedforward and cfg.singularity_damping == 0.1
    assert cfg.pan_limits_rad == [-PI, PI] and cfg.tilt_limits_rad == [-PI / 2, PI / 2]
    assert cfg.max_pan_rate_rad_s == cfg.max_tilt_rate_rad_s == pytest.approx(2 * PI / 3)
    assert cfg.hold_timeout_s == 1.0
    with pytest.raises(ValidationError):
        I.IbvsConfig.model_validate({"lamda_1_s": 2.0})  # typo: unknown key
    with pytest.raises(ValidationError):
        I.IbvsConfig.model_validate({"lambda_1_s": -1.0})
    with pytest.raises(ValidationError):
        I.IbvsConfig.model_validate({"tilt_limits_rad": [0.5, -0.5]})
    with pytest.raises(ValidationError):
        cfg.lambda_1_s = 3.0  # frozen


# --------------------------------------------------------------------------- feature kinematics


def _rot_active(w, h):
    n = float(np.linalg.norm(w))
    return np.eye(3) if n == 0.0 else F.dcm_from_quat(F.quat_from_axis_angle(w, n * h))


def test_feature_kinematics_match_finite_differences():
    rng = np.random.default_rng(3)
    for _ in range(25):
        pos = rng.uniform(-300, 300, 3) + np.array([0, 0, 400.0])
        vel = rng.uniform(-25, 25, 3)
        euler = np.array([rng.uniform(-0.6, 0.6), rng.uniform(-0.3, 0.3), rng.uniform(-PI, PI)])
        w_p = rng.uniform(-0.8, 0.8, 3)
        pan, tilt = rng.uniform(-2.5, 2.5), rng.uniform(-1.4, 0.3)
        pan_rate, tilt_rate = rng.uniform(-1, 1, 2)
        # put the target somewhere in the field of view, 150..600 m away
        R_ec0 = F.dcm_enu_from_frd(euler) @ F.R_frd_from_cam(pan, tilt)
        cam0 = pos + F.dcm_enu_from_frd(euler) @ MOUNT
        ray = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.3), 1.0])
        q0 = cam0 + R_ec0 @ (ray * rng.uniform(150, 600))
        vq = rng.uniform(-8, 8, 3)

        def features(h):
            R_ef = F.dcm_enu_from_frd(euler) @ _rot_active(w_p, h)
            R_ec = R_ef @ F.R_frd_from_cam(pan + pan_rate * h, tilt + tilt_rate * h)
            P = R_ec.T @ (q0 + vq * h - (pos + vel * h + R_ef @ MOUNT))
            return np.array([P[0] / P[2], P[1] / P[2]]), P[2]

        h = 1e-5
        fd = (features(h)[0] - features(-h)[0]) / (2 * h)
        s, Z = features(0.0)
        R_ef = F.dcm_enu_from_frd(euler)
        v_c = vel + R_ef @ np.cross(w_p, MOUNT)
        v_rel = R_ec0.T @ (vq - v_c)
        omega = F.camera_angular_velocity(pan, tilt, pan_rate, tilt_rate, w_p)
        model = I.feature_rates(s[0], s[1], Z, v_rel, omega)
        np.testing.assert_allclose(model, fd, rtol=1e-5, atol=1e-7)
        # the joint Jacobian form: J [tilt_dot, pan_dot] + L1 R_cam_from_frd w_p + T
        R_cf = F.R_frd_from_cam(pan, tilt).T
        split = (I.joint_jacobian(s[0], s[1], tilt) @ [tilt_rate, pan_rate]
                 + I.l1_matrix(s[0], s[1]) @ (R_cf @ w_p) + I.translational_feature_rates(s[0], s[1], Z, v_rel))
        np.testing.assert_allclose(split, model, rtol=1e-12, atol=1e-12)


def test_joint_jacobian_determinant_closed_form():
    rng = np.random.default_rng(4)
    for _ in range(50):
        x1, x2, t = rng.uniform(-0.6, 0.6), rng.uniform(-0.4, 0.4), rng.uniform(-PI / 2, PI / 2)
        det = np.linalg.det(I.joint_jacobian(x1, x2, t))
        assert det == pytest.approx((1 + x1 * x1 + x2 * x2) * (math.cos(t) + x2 * math.sin(t)), abs=1e-12)


# --------------------------------------------------------------------------- the law vs the paper's form


def _paper_joint_rates(x1, x2, tilt, lam, known):
    w = I.camera_rates_paper(x1, x2, lam, known)
    return F.joint_rates_from_camera_rates(tilt, w[0], w[1], cos_min=1e-9)


def test_direct_joint_rates_equal_paper_two_step_at_zero_tilt():
    rng = np.random.default_rng(5)
    for _ in range(50):
        x1, x2 = rng.uniform(-0.6, 0.6), rng.uniform(-0.35, 0.35)
        for known in ((0.0, 0.0), tuple(rng.uniform(-0.3, 0.3, 2))):
            direct = I.joint_rates_direct(x1, x2, 0.0, 1.5, known)
            np.testing.assert_allclose(direct, _paper_joint_rates(x1, x2, 0.0, 1.5, known), rtol=1e-10, atol=1e-12)


def test_direct_equals_paper_for_a_centred_target_at_any_tilt():
    """At x = 0 the third column of L1 vanishes: both laws agree (away from the damped zone)."""
    for tilt in np.linspace(-1.4, 1.4, 15):
        known = (0.07, -0.11)
        np.testing.assert_allclose(I.joint_rates_direct(0.0, 0.0, tilt, 1.5, known),
                                   _paper_joint_rates(0.0, 0.0, tilt, 1.5, known), rtol=1e-10, atol=1e-12)


def test_direct_law_realises_the_wanted_error_rate_where_the_paper_form_does_not():
    """Off-centre at large tilt the paper's form drops the -sin(t) L1[:, 2] pan_dot term."""
    x1, x2, tilt, lam = 0.4, -0.25, -1.2, 1.5
    e = np.array([x1, x2])

    def edot_error(pan_rate, tilt_rate):
        omega = F.camera_angular_velocity(0.3, tilt, pan_rate, tilt_rate, np.zeros(3))
        return float(np.linalg.norm(I.l1_matrix(x1, x2) @ omega + lam * e))

    assert edot_error(*I.joint_rates_direct(x1, x2, tilt, lam)) < 1e-12
    assert edot_error(*_paper_joint_rates(x1, x2, tilt, lam, (0.0, 0.0))) > 0.05


# --------------------------------------------------------------------------- singularity and limits


def _meas(t=0.0, pan=0.0, tilt=-0.5, u=CX, v=CY, valid=True, rates=(0.0, 0.0, 0.0), euler=(0.0, 0.0, 0.0),
          vel=(V_UAV, 0.0, 0.0), pan_rate=0.0, tilt_rate=0.0, exposure=None):
    return Measurements(
        t_s=t, pos_enu_m=np.array([0.0, 0.0, 500.0]), vel_enu_m_s=np.array(vel, float),
        euler_ned_rad=np.array(euler, float), body_rates_frd_rad_s=np.array(rates, float),
        airspeed_m_s=V_UAV, height_above_sea_m=500.0, pan_rad=pan, tilt_rad=tilt,
        pan_rate_rad_s=pan_rate, tilt_rate_rad_s=tilt_rate, det_new=valid, det_valid=valid,
        det_exposure_t_s=t if exposure is None else exposure, det_u_px=u if valid else math.nan,
        det_v_px=v if valid else math.nan)


def test_singularity_gives_finite_bounded_rates():
    mu, lam = 0.1, 1.5
    rng = np.random.default_rng(6)
    # the raw damped solution is bounded by |b| / mu, continuous through tilt = -90 deg
    prev = None
    for tilt in np.linspace(-1.3, -PI / 2, 400):
        for x1, x2 in ((0.0, 0.0), (0.004, -0.002), (0.05, 0.0), (-0.02, 0.01)):
            J = I.joint_jacobian(x1, x2, tilt)
            b = -lam * np.array([x1, x2]) + np.array([0.03, -0.02])
            q, smin = I.damped_solve(J, b, mu)
            assert np.all(np.isfinite(q)) and np.linalg.norm(q) <= np.linalg.norm(b) / mu + 1e-12
        q0, _ = I.damped_solve(I.joint_jacobian(0.004, -0.002, tilt), [0.03, -0.02], mu)
        if prev is not None:
            assert np.linalg.norm(q0 - prev) < 0.05  # no jump across the damping threshold
        prev = q0
    # exactly the paper's singular case: target centred, camera straight down, UAV rolling
    ctl = I.Ibvs(I.IbvsConfig(), FX, FY, CX, CY)
    for k in range(60):
        m = _meas(t=k / 30, pan=0.2, tilt=-PI / 2, u=CX + rng.normal(0, 2), v=CY + rng.normal(0, 2),
                  rates=rng.uniform(-0.5, 0.5, 3))
        cmd, st = ctl.step(m, np.array([3.0, 4.0, 0.0]), 500.0, MOUNT)
        assert st.mode == "track" and st.sigma_min < mu
        assert math.isfinite(cmd.pan_rate_rad_s) and math.isfinite(cmd.tilt_rate_rad_s)
        assert abs(cmd.pan_rate_rad_s) <= 2 * PI / 3 + 1e-12 and abs(cmd.tilt_rate_rad_s) <= 2 * PI / 3 + 1e-12
        assert cmd.tilt_rate_rad_s >= 0.0  # tilt is at its -90 deg limit: never pushed further down


def test_rates_never_exceed_limits_and_direction_is_kept():
    cfg = I.IbvsConfig(max_pan_rate_rad_s=1.0, max_tilt_rate_rad_s=0.5)
    ctl = I.Ibvs(cfg, FX, FY, CX, CY)
    rng = np.random.default_rng(7)
    for k in range(300):
        m = _meas(t=k / 30, pan=rng.uniform(-PI, PI), tilt=rng.uniform(-PI / 2, PI / 2),
                  u=rng.uniform(0, W_PX), v=rng.uniform(0, H_PX), rates=rng.uniform(-2, 2, 3),
                  euler=(rng.uniform(-0.7, 0.7), rng.uniform(-0.3, 0.3), rng.uniform(-PI, PI)))
        cmd, st = ctl.step(m, rng.uniform(-8, 8, 3), rng.uniform(50, 2000), MOUNT)
        assert abs(cmd.pan_rate_rad_s) <= 1.0 + 1e-12 and abs(cmd.tilt_rate_rad_s) <= 0.5 + 1e-12
    # direction kept when only the rate limits act
    pr, tr, scale = I.limit_joint_rates(0.0, 0.0, 3.0, -1.0, cfg, 1 / 30)
    assert scale < 1.0 and pr == pytest.approx(1.0) and tr / pr == pytest.approx(-1.0 / 3.0)


def test_joint_at_limit_is_not_pushed_further():
    cfg = I.IbvsConfig()
    ctl = I.Ibvs(cfg, FX, FY, CX, CY)
    # target right of centre needs positive pan; pan is at +pi
    cmd, _ = ctl.step(_meas(pan=PI, tilt=-0.5, u=CX + 300, v=CY + 150), None, None, MOUNT)
    assert cmd.pan_rate_rad_s == 0.0 and cmd.tilt_rate_rad_s < 0.0  # tilt still works (target below: down)
    ctl.reset()
    cmd, _ = ctl.step(_meas(pan=-PI, tilt=-0.5, u=CX - 300, v=CY), None, None, MOUNT)
    assert cmd.pan_rate_rad_s == 0.0
    ctl.reset()  # within one step of the limit: the step lands on it
    cmd, _ = ctl.step(_meas(pan=PI - 0.01, tilt=-0.5, u=CX + 300, v=CY), None, None, MOUNT)
    assert 0.0 < cmd.pan_rate_rad_s <= 0.01 / cfg.nominal_dt_s + 1e-12
    ctl.reset()  # tilt at +90 deg with the target above centre
    cmd, _ = ctl.step(_meas(pan=0.0, tilt=PI / 2, u=CX, v=CY - 200), None, None, MOUNT)
    assert cmd.tilt_rate_rad_s <= 0.0
    # away from the limit the same target moves the pan
    ctl.reset()
    cmd, _ = ctl.step(_meas(pan=0.0, tilt=-0.5, u=CX + 300, v=CY), None, None, MOUNT)
    assert cmd.pan_rate_rad_s > 0.0


def test_modes_track_coast_hold():
    cfg = I.IbvsConfig(hold_timeout_s=0.5)
    ctl = I.Ibvs(cfg, FX, FY, CX, CY)
    cmd, st = ctl.step(_meas(t=0.0, valid=False), None, None, MOUNT)
    assert st.mode == "hold" and math.isnan(cmd.pan_rate_rad_s)
    modes = []
    for k in range(1, 60):
        t = k / 30
        cmd, st = ctl.step(_meas(t=t, u=CX + 40, v=CY - 30, valid=t < 0.5, rates=(0.0, 0.0, 0.2)), None, None, MOUNT)
        modes.append(st.mode)
        if st.mode == "coast":  # feed-forward only: cancels the UAV's yaw rate in the image
            assert math.isfinite(cmd.pan_rate_rad_s) and cmd.pan_rate_rad_s < 0.0
        if st.mode == "hold":
            assert math.isnan(cmd.pan_rate_rad_s) and math.isnan(cmd.tilt_rate_rad_s)
    assert modes[0] == "track" and "coast" in modes and modes[-1] == "hold"
    n_coast = modes.count("coast")
    assert abs(n_coast / 30 - cfg.hold_timeout_s) <= 1 / 30 + 1e-9
    # a stale (old) valid detection does not count as tracking
    ctl.reset()
    _, st = ctl.step(_meas(t=5.0, exposure=4.0), None, None, MOUNT)
    assert st.mode == "coast" and st.detection_age_s == pytest.approx(1.0)
    # no joint angles: hold
    _, st = ctl.step(_meas(t=5.1, pan=math.nan), None, None, MOUNT)
    assert st.mode == "hold"


# --------------------------------------------------------------------------- closed loop (kinematic world)


class StraightUav:
    def __init__(self, p0, heading_ned):
        self.p0, self.psi = np.asarray(p0, float), heading_ned
        c = F.course_enu_from_heading_ned(heading_ned)
        self.vel = V_UAV * np.array([math.cos(c), math.sin(c), 0.0])

    def state(self, t):
        return self.p0 + self.vel * t, self.vel, np.array([0.0, 0.0, self.psi]), np.zeros(3)


class CircleUav:
    """Right-hand (clockwise seen from above) level turn of radius r about centre c."""

    def __init__(self, centre, radius, height, theta0):
        self.c, self.r, self.h, self.th0 = np.asarray(centre, float), radius, height, theta0
        self.w = V_UAV / radius
        self.phi = math.atan(V_UAV * self.w / G)

    def state(self, t):
        th = self.th0 - self.w * t
        pos = np.array([self.c[0] + self.r * math.cos(th), self.c[1] + self.r * math.sin(th), self.h])
        vel = self.r * self.w * np.array([math.sin(th), -math.cos(th), 0.0])
        euler = np.array([self.phi, 0.0, F.wrap_pi(PI - th)])
        return pos, vel, euler, F.body_rates_from_euler_rates(euler, [0.0, 0.0, self.w])


SHIP_VEL = 5.0 * np.array([math.cos(0.6), math.sin(0.6), 0.0])


def _project(pos, euler, pan, tilt, q):
    cam, R_ec = F.camera_pose_world(pos, euler, MOUNT, pan, tilt)
    P = R_ec.T @ (q - cam)
    return FX * P[0] / P[2] + CX, FY * P[1] / P[2] + CY, P[2]


def _angles_putting_target_at(pos, euler, q, u, v):
    """(pan, tilt) with the target imaged at pixel (u, v): Newton on the projection."""
    d_frd = F.dcm_enu_from_frd(euler).T @ (q - pos)
    pt = np.array(F.pan_tilt_pointing_at(d_frd))
    for _ in range(30):
        r = np.array(_project(pos, euler, *pt, q)[:2]) - [u, v]
        if np.linalg.norm(r) < 1e-6:
            break
        Jn = np.empty((2, 2))
        for j in range(2):
            d = np.zeros(2)
            d[j] = 1e-6
            Jn[:, j] = (np.array(_project(pos, euler, *(pt + d), q)[:2]) - _project(pos, euler, *pt, q)[:2]) / 1e-6
        pt = pt - np.linalg.solve(Jn, r)
    return float(pt[0]), float(pt[1])


def _fly(uav, cfg, duration_s, start_px=(100.0, 80.0), dropout=None, ship_vel=SHIP_VEL):
    """Closed loop; returns t, true pixel error norm, whether the target is in the image, modes, swing
    directions, commanded rates, joint angles, and the target's angle off the pan axis (deg)."""
    q0 = np.zeros(3)
    ship_vel = np.asarray(ship_vel, float)
    pos, vel, euler, w = uav.state(0.0)
    pan0, tilt0 = _angles_putting_target_at(pos, euler, q0, *start_px)
    gim = Gimbal(GimbalConfig(mount_offset_frd_m=list(MOUNT), initial_pan_rad=pan0, initial_tilt_rad=tilt0), DT)
    ctl = I.Ibvs(cfg, FX, FY, CX, CY)
    n = int(round(duration_s / DT))
    out = {k: np.empty(n) for k in ("t", "err", "in_image", "swing", "pan_cmd", "tilt_cmd", "pan", "tilt",
                                    "off_axis_deg")}
    modes = []
    det = (False, math.nan, math.nan, math.nan)
    for k in range(n):
        t = k * DT
        pos, vel, euler, w = uav.state(t)
        q = q0 + ship_vel * t
        g = gim.state
        u, v, Z = _project(pos, euler, g.pan_rad, g.tilt_rad, q)
        in_image = Z > 0 and 0 <= u < W_PX and 0 <= v < H_PX
        new = k % DET_EVERY == 0
        if new:
            visible = in_image
            if dropout is not None and dropout[0] <= t < dropout[1]:
                visible = False
            det = (visible, t, u, v)
        m = Measurements(t_s=t, pos_enu_m=pos, vel_enu_m_s=vel, euler_ned_rad=euler, body_rates_frd_rad_s=w,
                         airspeed_m_s=V_UAV, height_above_sea_m=pos[2], pan_rad=g.pan_rad, tilt_rad=g.tilt_rad,
                         pan_rate_rad_s=g.pan_rate_rad_s, tilt_rate_rad_s=g.tilt_rate_rad_s, det_new=new,
                         det_valid=det[0], det_exposure_t_s=det[1], det_u_px=det[2], det_v_px=det[3])
        cmd, st = ctl.step(m, ship_vel, Z, MOUNT)
        gim.step(t + DT, cmd.pan_rate_rad_s, cmd.tilt_rate_rad_s)
        d = F.dcm_enu_from_frd(euler).T @ (q - pos)
        out["t"][k], out["err"][k], out["in_image"][k] = t, math.hypot(u - CX, v - CY), in_image
        out["swing"][k] = st.swing
        out["pan_cmd"][k], out["tilt_cmd"][k] = cmd.pan_rate_rad_s, cmd.tilt_rate_rad_s
        out["pan"][k], out["tilt"][k] = g.pan_rad, g.tilt_rad
        out["off_axis_deg"][k] = math.degrees(math.atan2(math.hypot(d[0], d[1]), d[2]))
        modes.append(st.mode)
    out["modes"] = modes
    out["in_image"] = out["in_image"].astype(bool)
    return out


def _settle_time(r, px=5.0):
    """First time after which the error stays below px."""
    above = np.nonzero(r["err"] >= px)[0]
    if len(above) == 0:
        return 0.0
    return r["t"][above[-1] + 1] if above[-1] + 1 < len(r["t"]) else math.inf


def _decay_rate(r, hi=300.0, lo=15.0):
    """Slope of -ln(error) while it falls from hi to lo px."""
    sel = (r["err"] < hi) & (r["err"] > lo) & (r["t"] < _settle_time(r, lo) + 1e-9)
    return -np.polyfit(r["t"][sel], np.log(r["err"][sel]), 1)[0]


@pytest.mark.parametrize("uav", [StraightUav([-600.0, -100.0, 500.0], 0.0),
                                 CircleUav([-450.0, 250.0], 200.0, 500.0, theta0=PI)], ids=["straight", "circle"])
def test_closed_loop_centres_the_target_exponentially(uav):
    cfg = I.IbvsConfig()
    lam = cfg.lambda_1_s
    r = _fly(uav, cfg, 8.0)
    e0 = r["err"][0]
    assert e0 == pytest.approx(math.hypot(100 - CX, 80 - CY), abs=1e-6)
    t5 = _settle_time(r, 5.0)
    t_pred = math.log(e0 / 5.0) / lam  # pure exp(-lambda t) from e0 to 5 px
    assert t5 <= 1.15 * t_pred, (t5, t_pred)
    assert _decay_rate(r) == pytest.approx(lam, rel=0.1)
    assert np.max(r["err"][r["t"] > t5]) < 5.0
    assert np.max(r["err"][r["t"] > 6.0]) < 0.5  # with feed-forward: no steady-state error
    assert all(m == "track" for m in r["modes"])
    assert np.max(np.abs(r["pan_cmd"])) <= 2 * PI / 3 + 1e-12 and np.max(np.abs(r["tilt_cmd"])) <= 2 * PI / 3 + 1e-12


def test_without_feedforward_a_steady_state_error_remains_while_circling():
    uav = CircleUav([-450.0, 250.0], 200.0, 500.0, theta0=PI)
    on = _fly(uav, I.IbvsConfig(), 12.0)
    off = _fly(uav, I.IbvsConfig(feedforward=False), 12.0)
    late = on["t"] > 6.0
    assert np.max(on["err"][late]) < 0.5
    assert np.mean(off["err"][late]) > 20.0 and np.min(off["err"][late]) > 5.0


def test_coast_keeps_the_target_through_a_detection_dropout():
    uav = CircleUav([-450.0, 250.0], 200.0, 500.0, theta0=PI)
    r = _fly(uav, I.IbvsConfig(), 9.0, dropout=(6.0, 6.8))
    sel = (r["t"] >= 6.0) & (r["t"] < 6.8)
    assert {r["modes"][i] for i in np.nonzero(sel)[0][2:]} == {"coast"}
    assert np.max(r["err"][sel]) < 2.0  # feed-forward of the UAV and ship motion holds the image
    assert r["modes"][-1] == "track" and r["err"][-1] < 1.0


# --------------------------------------------------------------------------- keyhole: target near the pan axis


def _line_crossing_by_walking(p, p_dot, pan, lims, beyond, t_end=100.0, n=100_001):
    """Reference for predict_limit_crossing: walk the line, unwrap the azimuth, follow it with the pan."""
    t = np.linspace(0.0, t_end, n)
    pts = np.asarray(p)[None, :] + t[:, None] * np.asarray(p_dot)[None, :]
    az = np.unwrap(np.arctan2(pts[:, 1], pts[:, 0]))
    follow = pan + F.wrap_pi(az[0] - pan) + (az - az[0])
    past = np.nonzero((follow > lims[1] + beyond) | (follow < lims[0] - beyond))[0]
    if len(past) == 0:
        return None
    k = past[0]
    return t[k], float(np.hypot(*pts[k])), 1 if follow[k] > lims[1] else -1


def test_predict_limit_crossing_geometry():
    lims = (-PI, PI)
    # target 11.3 deg off the axis at azimuth -90 deg drifting back and right: its azimuth sweeps
    # down through -180 deg, which the pan (at -90 deg) meets after 4 s, 21.8 deg off the axis
    t, s, sweep = I.predict_limit_crossing((0.0, -0.2), (-0.1, 0.05), -PI / 2, lims)
    assert (t, s, sweep) == (pytest.approx(4.0), pytest.approx(0.4), -1)
    assert I.predict_limit_crossing((0.0, -0.2), (-0.1, 0.05), -PI / 2, (-2 * PI, 2 * PI)) is None  # room to follow
    assert I.predict_limit_crossing((0.0, -0.2), (0.1, 0.05), -PI / 2, lims) is None  # sweeping away from -180 deg
    # already past the limit (pan pinned at +pi, azimuth 1 deg beyond and going on): now; not if 5 deg are required
    p = 0.2 * np.array([math.cos(-PI + 0.0175), math.sin(-PI + 0.0175)])
    t, s, sweep = I.predict_limit_crossing(p, (0.0, -0.05), PI, lims)
    assert t == 0.0 and s == pytest.approx(0.2) and sweep == 1
    assert I.predict_limit_crossing(p, (0.0, -0.05), PI, lims, math.radians(5.0))[0] > 0.0
    assert I.predict_limit_crossing(p, (0.0, 0.05), PI, lims) is None  # coming back: no
    # against a walk along the line
    rng = np.random.default_rng(11)
    checked = 0
    for _ in range(60):
        p = rng.uniform(-0.4, 0.4, 2)
        p_dot = rng.uniform(-0.2, 0.2, 2)
        if abs(p[0] * p_dot[1] - p[1] * p_dot[0]) / np.linalg.norm(p_dot) < 0.02:
            continue  # passes (almost) through the axis: the azimuth jumps, the walk would need a finer grid
        pan = float(np.clip(math.atan2(p[1], p[0]) + rng.uniform(-0.2, 0.2), -PI, PI))
        beyond = rng.choice([0.0, math.radians(5.0)])
        got = I.predict_limit_crossing(p, p_dot, pan, lims, beyond)
        ref = _line_crossing_by_walking(p, p_dot, pan, lims, beyond)
        if got is not None and got[0] > 75.0:
            continue  # beyond the walk
        assert (got is None) == (ref is None), (p, p_dot, pan, got, ref)
        if ref is not None:
            assert got[0] == pytest.approx(ref[0], abs=2e-3) and got[2] == ref[2]
            assert got[1] == pytest.approx(ref[1], rel=1e-3, abs=1e-3)
            checked += 1
    assert checked >= 5


def _target_off_the_pan_axis(off_axis_deg, azimuth_rad, height=500.0):
    """A UAV level at `height`, heading north, and a ship `off_axis_deg` off its pan axis at body azimuth."""
    r = height * math.tan(math.radians(off_axis_deg))
    # body FRD (heading north, level): x = north, y = east, z = down
    north, east = r * math.cos(azimuth_rad), r * math.sin(azimuth_rad)
    return np.array([east, north, -height])  # ship relative to the UAV, ENU


def test_far_side_target_near_the_axis_starts_a_swing():
    """A target on the far side of the pan axis cannot be centred by the tilt (it would have to pass -90 deg):
    the pan swings toward it at full rate, the shorter way the limits allow; farther from the axis, no swing."""
    cfg = I.IbvsConfig()
    cam_h = 500.0

    def step(pan, tilt, off_axis_deg, azimuth):
        rel = _target_off_the_pan_axis(off_axis_deg, azimuth, cam_h)
        euler = np.zeros(3)
        cam, R_ec = F.camera_pose_world(np.array([0.0, 0.0, cam_h]), euler, MOUNT, pan, tilt)
        P = R_ec.T @ (rel + np.array([0.0, 0.0, cam_h]) - cam)
        u, v = FX * P[0] / P[2] + CX, FY * P[1] / P[2] + CY
        ctl = I.Ibvs(cfg, FX, FY, CX, CY)
        return ctl.step(_meas(pan=pan, tilt=tilt, u=u, v=v), np.zeros(3), P[2], MOUNT)

    # pan -0.3 rad, tilt at -90 deg, target 8 deg off the axis almost behind the pan (azimuth -0.3 + pi - 0.2)
    cmd, st = step(-0.3, -PI / 2, 8.0, -0.3 + PI - 0.2)
    assert st.swing == 1 and cmd.pan_rate_rad_s == pytest.approx(cfg.max_pan_rate_rad_s)
    assert cmd.tilt_rate_rad_s >= 0.0  # never pushed past the tilt limit
    cmd, st = step(0.3, -PI / 2, 8.0, 0.3 - PI + 0.2)  # mirror image: the other way
    assert st.swing == -1 and cmd.pan_rate_rad_s == pytest.approx(-cfg.max_pan_rate_rad_s)
    # pan 1.0 rad, target at azimuth 1.0 + 2.4: the short way (+2.4 rad) would cross +pi, so the long way round
    cmd, st = step(1.0, -PI / 2, 8.0, 1.0 + 2.4)
    assert st.swing == -1
    # outside the keyhole (30 deg off the axis > 18 deg half field of view): the law as is
    cmd, st = step(0.3, -1.2, 30.0, 0.3 + PI - 0.2)
    assert st.swing == 0
    assert I.Ibvs(I.IbvsConfig(keyhole_swing=False), FX, FY, CX, CY).step(
        _meas(pan=0.3, tilt=-PI / 2, u=CX, v=CY + 100.0), np.zeros(3), 500.0, MOUNT)[1].swing == 0


@pytest.mark.parametrize("uav", [StraightUav([-600.0, -100.0, 500.0], 0.0),
                                 CircleUav([-450.0, 250.0], 200.0, 500.0, theta0=PI)], ids=["straight", "circle"])
def test_law_untouched_away_from_the_keyhole(uav):
    on = _fly(uav, I.IbvsConfig(), 8.0)
    off = _fly(uav, I.IbvsConfig(keyhole_swing=False), 8.0)
    assert np.all(on["swing"] == 0)
    np.testing.assert_array_equal(on["pan_cmd"], off["pan_cmd"])
    np.testing.assert_array_equal(on["tilt_cmd"], off["tilt_cmd"])


@pytest.mark.parametrize("lateral_miss_m", [0.0, 5.0, -5.0, 30.0])
def test_overflight_keeps_the_target_in_the_image(lateral_miss_m):
    """Straight and level over a still ship at 300 m: the line of sight passes (near) the pan axis and the
    azimuth turns through 180 deg faster than the pan can follow. The plain law stalls with the target on
    the far side of the axis (tilt pinned at -90 deg) and loses it; the swing keeps it in the image."""
    uav = StraightUav([lateral_miss_m, -250.0, 300.0], 0.0)
    on = _fly(uav, I.IbvsConfig(), 20.0, start_px=(CX, CY), ship_vel=np.zeros(3))
    off = _fly(uav, I.IbvsConfig(keyhole_swing=False), 20.0, start_px=(CX, CY), ship_vel=np.zeros(3))
    assert on["in_image"].all() and all(m == "track" for m in on["modes"])
    assert on["err"][-1] < 1.0  # recentred behind the UAV
    assert np.all(np.abs(on["pan"]) <= PI)
    if abs(lateral_miss_m) <= 5.0:
        assert on["swing"].any()
        assert not off["in_image"].all()  # what the handling fixes
    else:  # 5.7 deg off the axis at most: the pan keeps up, no swing, the law exactly as without the handling
        assert not on["swing"].any() and off["in_image"].all()
        np.testing.assert_array_equal(on["pan_cmd"], off["pan_cmd"])


class RollReversalUav:
    """Straight at V_UAV, nose 15 deg down, reversing its bank from -35 to +35 deg (cosine profile) from t0 over
    tr s: the pan axis (body z) sweeps across a ship below and behind, as in the paper mission's Phase 2 entry."""

    def __init__(self, p0, heading_ned, t0=1.0, tr=2.5):
        self.p0, self.psi = np.asarray(p0, float), heading_ned
        c = F.course_enu_from_heading_ned(heading_ned)
        self.vel = V_UAV * np.array([math.cos(c), math.sin(c), 0.0])
        self.t0, self.tr = t0, tr
        self.r0, self.r1, self.pitch = math.radians(-35.0), math.radians(35.0), math.radians(-15.0)

    def state(self, t):
        tau = min(max((t - self.t0) / self.tr, 0.0), 1.0)
        roll = self.r0 + (self.r1 - self.r0) * 0.5 * (1.0 - math.cos(PI * tau))
        roll_rate = (self.r1 - self.r0) * PI / (2.0 * self.tr) * math.sin(PI * tau)
        euler = np.array([roll, self.pitch, self.psi])
        return self.p0 + self.vel * t, self.vel, euler, F.body_rates_from_euler_rates(euler, [roll_rate, 0.0, 0.0])


@pytest.mark.parametrize("ship_north_m", [-300.0, -200.0])
def test_keyhole_pass_across_the_pan_limit_keeps_the_target_in_the_image(ship_north_m):
    """The paper-mission case: 880 m above a ship 450-500 m away (moving at 5 m/s), banked toward it, the
    ship 12 deg off the pan axis at body azimuth -107 deg (or 11 deg at -80 deg); the bank reversal sweeps
    the axis past it (closest 5 deg; 0.3 deg) and its azimuth runs round the back to about +100 deg.
    Followed by the plain law, the pan runs into its -180 deg stop (or stalls with the ship on the far side
    of the axis, tilt at -90 deg) and loses the ship. With the handling the pan unwinds the other way round
    while the ship is near the axis: in the image throughout (within 520 px of the centre)."""
    uav = RollReversalUav([-400.0, -ship_north_m, 880.0], 0.0)
    on = _fly(uav, I.IbvsConfig(), 7.0, start_px=(CX, CY))
    off = _fly(uav, I.IbvsConfig(keyhole_swing=False), 7.0, start_px=(CX, CY))
    assert on["in_image"].all() and all(m == "track" for m in on["modes"])
    assert np.max(np.abs(on["pan"])) < PI - 0.5  # never near a pan stop
    starts = np.nonzero(np.diff(on["swing"]) != 0)[0]
    assert len(starts) == 2 and on["swing"][starts[0] + 1] == 1  # one swing, unwinding away from -180 deg
    assert on["off_axis_deg"][starts[0] + 1] < 13.0  # started while the ship was near the axis
    assert on["err"][-1] < 1.0
    assert not off["in_image"].all()
    if ship_north_m == -300.0:
        assert np.min(off["pan"]) == -PI  # the plain law pins the pan at its stop
