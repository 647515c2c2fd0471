"""The target UKF (controllers.estimation.ukf) and the feature kinematics / depth model
(controllers.navigation.camera_model).

Oracles: finite differences of the projection (feature kinematics), the
paper's on-axis depth formula, a linear Kalman filter (filterpy) on a linear
case, and a synthetic constant-velocity ship seen from an orbiting camera
(truth pointing from fwsim.interface.frames.pan_tilt_pointing_at, used only by the test).
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter
from pydantic import ValidationError

from controllers.blocks import TargetEstimator, resolve_class
from controllers.estimation.ukf import CameraMotion, TargetEstimate, UkfConfig, UkfTargetEstimator, UnscentedCore
from controllers.navigation.camera_model import PinholeCamera, depth_on_plane, feature_rates, interaction_matrix
from fwsim.interface import frames as F
from fwsim.interface.messages import Measurements


def exp_so3(w, t):
    """Rotation exp([w]x t) via scipy-free Rodrigues (independent of the module's helper)."""
    th = np.linalg.norm(w) * t
    if th == 0.0:
        return np.eye(3)
    k = np.asarray(w) / np.linalg.norm(w)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(th) * K + (1 - math.cos(th)) * K @ K


def random_rotation(rng):
    q = rng.normal(size=4)
    return F.dcm_from_quat(q / np.linalg.norm(q))


# ---------------------------------------------------------------- feature kinematics


def test_feature_rates_match_finite_differences_of_the_projection():
    """A moving, accelerating point seen by a translating, rotating camera: 20 random geometries."""
    rng = np.random.default_rng(1)
    for _ in range(20):
        R0 = random_rotation(rng)  # R_enu_from_cam at t = 0
        w = rng.normal(scale=0.5, size=3)  # camera angular velocity, camera frame (constant)
        c0, Vc, ac = rng.normal(scale=50, size=3), rng.normal(scale=20, size=3), rng.normal(scale=3, size=3)
        # target in front of the camera, off-axis
        P0 = np.array([rng.uniform(-0.4, 0.4), rng.uniform(-0.3, 0.3), 1.0]) * rng.uniform(50, 800)
        q0 = c0 + R0 @ P0
        Vq, aq = rng.normal(scale=8, size=3), rng.normal(scale=1, size=3)

        def features(t):
            R = R0 @ exp_so3(w, t)
            P = R.T @ ((q0 + Vq * t + 0.5 * aq * t * t) - (c0 + Vc * t + 0.5 * ac * t * t))
            return P[:2] / P[2]

        h = 1e-4
        fd = (features(h) - features(-h)) / (2 * h)
        x1, x2 = P0[:2] / P0[2]
        v = R0.T @ (Vq - Vc)
        got = feature_rates(x1, x2, P0[2], v, w)
        assert np.allclose(got, fd, rtol=1e-6, atol=1e-9 * (1 + np.abs(fd).max())), (got, fd)
        # the matrix form and the batched form agree
        L = interaction_matrix(x1, x2, P0[2])
        assert np.allclose(L @ np.concatenate([v, w]), got, rtol=1e-12, atol=1e-15)
        batch = feature_rates(np.array([x1, x1]), np.array([x2, x2]), np.array([P0[2]] * 2), np.array([v, v]), w)
        assert batch.shape == (2, 2) and np.allclose(batch[1], got)
        # the paper's L1 (rotational block)
        assert np.allclose(L[:, 3:], [[x1 * x2, -(1 + x1 ** 2), x2], [1 + x2 ** 2, -x1 * x2, -x1]])


def test_camera_motion_from_measurements_matches_the_pan_tilt_pose_derivatives():
    """V_c and omega_cam built from Measurements equal the derivatives of fwsim.interface.frames.camera_pose_world."""
    rng = np.random.default_rng(2)
    m = np.array([0.3, -0.1, 0.15])
    for _ in range(10):
        e0, de = rng.uniform([-0.5, -0.4, -3], [0.5, 0.4, 3]), rng.normal(scale=0.3, size=3)
        pt0, dpt = np.array([rng.uniform(-3, 3), rng.uniform(-1.2, 1.2)]), rng.normal(scale=0.5, size=2)
        p0, vp = rng.normal(scale=100, size=3), rng.normal(scale=20, size=3)

        def pose(t):
            return F.camera_pose_world(p0 + vp * t, e0 + de * t, m, *(pt0 + dpt * t))

        rates = F.body_rates_from_euler_rates(e0, de)
        meas = Measurements(0.0, p0, vp, e0, rates, 22.0, p0[2], pan_rad=pt0[0], tilt_rad=pt0[1],
                            pan_rate_rad_s=dpt[0], tilt_rate_rad_s=dpt[1])
        mo = CameraMotion.from_measurements(meas, m)
        c, R = pose(0.0)
        assert np.allclose(mo.pos_enu_m, c) and np.allclose(mo.R_enu_from_cam, R)
        assert math.isclose(mo.height_m, c[2], abs_tol=1e-9)
        h = 1e-5
        (cp, Rp), (cm, Rm) = pose(h), pose(-h)
        assert np.allclose(mo.vel_enu_m_s, (cp - cm) / (2 * h), atol=1e-6)
        W = R.T @ (Rp - Rm) / (2 * h)  # [omega]x in the camera frame
        assert np.allclose(mo.omega_cam_rad_s, [W[2, 1], W[0, 2], W[1, 0]], atol=1e-6)


# ---------------------------------------------------------------- depth model


def test_depth_on_the_optical_axis_is_the_papers_h_over_cos_alpha():
    rng = np.random.default_rng(3)
    e3 = np.array([0.0, 0.0, 1.0])
    for _ in range(20):
        R = random_rotation(rng)
        c3 = R[:, 2]
        if -c3[2] < 0.05:
            R = R @ np.diag([1.0, -1.0, -1.0])  # flip the optical axis down
            c3 = R[:, 2]
        h = rng.uniform(50, 1500)
        alpha = math.acos(-e3 @ c3)
        assert math.isclose(depth_on_plane(0.0, 0.0, R, h), h / math.cos(alpha), rel_tol=1e-12)


def test_depth_off_axis_lands_on_the_plane_and_rejects_upward_rays():
    rng = np.random.default_rng(4)
    R = F.R_ENU_FROM_NED @ F.R_frd_from_cam(0.0, -math.pi / 2)  # level UAV, camera straight down
    x1, x2 = rng.uniform(-0.5, 0.5, 50), rng.uniform(-0.3, 0.3, 50)
    Z = depth_on_plane(x1, x2, R, 400.0, 12.5)
    pts = np.array([0.0, 0.0, 400.0]) + Z[:, None] * (np.stack([x1, x2, np.ones(50)], 1) @ R.T)
    assert np.allclose(pts[:, 2], 12.5)
    assert np.allclose(Z, 387.5)  # looking straight down every ray has the same camera-frame depth
    R_up = F.R_ENU_FROM_NED @ F.R_frd_from_cam(0.0, 0.3)  # optical axis above the horizon
    assert math.isnan(depth_on_plane(0.0, 0.0, R_up, 400.0))
    assert math.isnan(depth_on_plane(0.0, 0.0, R, -5.0))  # camera below the plane


# ---------------------------------------------------------------- generic machinery vs linear KF


@pytest.mark.parametrize("alpha,beta,kappa", [(1.0, 2.0, 0.0), (0.5, 2.0, 1.0), (0.3, 0.0, 3.0)])
def test_unscented_core_equals_a_linear_kalman_filter_on_a_linear_case(alpha, beta, kappa):
    """3-D constant-velocity target, direct position measurements, 50 steps: same x and P as filterpy's KF."""
    rng = np.random.default_rng(5)
    dt = 0.1
    Fm = np.eye(6)
    Fm[0:3, 3:6] = dt * np.eye(3)
    H = np.hstack([np.eye(3), np.zeros((3, 3))])
    A = rng.normal(size=(6, 6))
    Q = 0.01 * A @ A.T + 1e-3 * np.eye(6)
    B = rng.normal(size=(3, 3))
    R = B @ B.T + 0.5 * np.eye(3)
    C = rng.normal(size=(6, 6))
    x0, P0 = rng.normal(size=6), C @ C.T + np.eye(6)

    kf = KalmanFilter(dim_x=6, dim_z=3)
    kf.x, kf.P, kf.F, kf.Q, kf.H, kf.R = x0.copy(), P0.copy(), Fm, Q, H, R
    core = UnscentedCore(6, 3, alpha, beta, kappa)
    core.set_state(x0, P0)
    truth = np.array([0.0, 0, 0, 1, -2, 0.5])
    for k in range(50):
        truth = Fm @ truth
        z = H @ truth + rng.normal(size=3)
        kf.predict()
        core.predict(dt, lambda S, dt_: S @ Fm.T, Q)
        assert np.allclose(core.x, kf.x, rtol=1e-8, atol=1e-10)
        assert np.allclose(core.P, kf.P, rtol=1e-8, atol=1e-10)
        if k % 7 != 3:  # some steps without a measurement
            kf.update(z)
            y = core.update(z, lambda X: X @ H.T, R)
            assert np.allclose(y, kf.y, rtol=1e-8, atol=1e-10)
        assert np.allclose(core.x, kf.x, rtol=1e-8, atol=1e-10)
        assert np.allclose(core.P, kf.P, rtol=1e-8, atol=1e-10)
    assert core.numerical_resets == 0


def test_unscented_core_resets_a_broken_covariance_to_its_diagonal():
    core = UnscentedCore(2, 1)
    core.set_state([0.0, 0.0], [[1.0, 2.0], [2.0, 1.0]])  # indefinite
    assert core.numerical_resets == 1
    assert np.allclose(core.P, np.eye(2))
    core.predict(0.1, lambda S, dt: S, np.zeros((2, 2)))
    assert np.all(np.isfinite(core.P)) and core.numerical_resets == 1


def test_config_defaults_and_strictness():
    cfg = UkfConfig.model_validate({})
    assert cfg.pixel_noise_px == 2.0 and cfg.target_plane_height_m == 0.0
    with pytest.raises(ValidationError):
        UkfConfig.model_validate({"pixel_noise": 1.0})
    with pytest.raises(ValidationError):
        UkfConfig(pixel_noise_px=-1.0)
    with pytest.raises(ValidationError):
        cfg.pixel_noise_px = 3.0  # frozen


# ---------------------------------------------------------------- synthetic mission


CAM = PinholeCamera.from_fov(1280, 720, 60.0)
MOUNT = np.array([0.0, 0.0, 0.10])
G = 9.80665


class OrbitTruth:
    """A 5 m/s ship on the sea and a UAV circling it (R, H, airspeed) with the camera pointed at it."""

    def __init__(self, radius=500.0, height=500.0, speed=22.0, ship_speed=5.0, ship_heading_deg=30.0):
        self.R, self.H, self.V = radius, height, speed
        self.Om = speed / radius  # counter-clockwise seen from above (left turn)
        hd = math.radians(ship_heading_deg)
        self.Vq = ship_speed * np.array([math.sin(hd), math.cos(hd), 0.0])
        self.roll = -math.atan(speed * self.Om / G)

    def ship(self, t):
        return self.Vq * t

    def uav(self, t):
        a = math.pi + self.Om * t
        pos = self.ship(t) + np.array([self.R * math.cos(a), self.R * math.sin(a), self.H])
        vel = self.Vq + self.R * self.Om * np.array([-math.sin(a), math.cos(a), 0.0])
        euler = np.array([self.roll, 0.0, math.atan2(vel[0], vel[1])])
        return pos, vel, euler

    def joints(self, t):
        """Pan/tilt at the target plus a slow few-degree wobble so the target moves in the image."""
        pos, _, euler = self.uav(t)
        R_ef = F.dcm_enu_from_frd(euler)
        cam = pos + R_ef @ MOUNT
        pan, tilt = F.pan_tilt_pointing_at(R_ef.T @ (self.ship(t) - cam))
        return np.array([pan + 0.05 * math.sin(0.3 * t), tilt + 0.04 * math.cos(0.23 * t)])

    def sample(self, t, rng, detect=True, px=2.0, gnss=0.5, att=0.002, gyro=0.003, height=0.5, enc=0.0005,
               gnss_err=None):
        """Measurements at t (sensor noise as fwsim.sensors.onboard' defaults); gnss_err: a held GNSS error (3,)."""
        pos, vel, euler = self.uav(t)
        h = 1e-3
        de = F.wrap_pi(self.uav(t + h)[2] - self.uav(t - h)[2]) / (2 * h)
        rates = F.body_rates_from_euler_rates(euler, de)
        pt = self.joints(t)
        dpt = F.wrap_pi(self.joints(t + h) - self.joints(t - h)) / (2 * h)
        cam, R = F.camera_pose_world(pos, euler, MOUNT, pt[0], pt[1])
        P = R.T @ (self.ship(t) - cam)
        u = CAM.fx * P[0] / P[2] + CAM.cx + rng.normal(0, px)
        v = CAM.fy * P[1] / P[2] + CAM.cy + rng.normal(0, px)
        assert P[2] > 0 and 0 <= u <= 1280 and 0 <= v <= 720
        dp = rng.normal(0, gnss, 3) if gnss_err is None else gnss_err
        kw = dict(det_new=True, det_valid=True, det_exposure_t_s=t, det_u_px=u, det_v_px=v) if detect else {}
        return Measurements(
            t, pos + dp, vel + rng.normal(0, 0.05, 3), euler + rng.normal(0, att, 3),
            rates + rng.normal(0, gyro, 3), self.V, pos[2] + rng.normal(0, height),
            pan_rad=pt[0] + rng.normal(0, enc), tilt_rad=pt[1] + rng.normal(0, enc),
            pan_rate_rad_s=dpt[0], tilt_rate_rad_s=dpt[1], cam_pos_enu_m=cam + dp, **kw)


def run_orbit(duration_s=75.0, gap=(45.0, 48.0), seed=7):
    truth = OrbitTruth()
    rng = np.random.default_rng(seed)
    ukf = UkfTargetEstimator(CAM, UkfConfig())
    rows = []
    for k in range(int(duration_s * 30) + 1):
        t = k / 30.0
        if k % 3 == 0:  # GNSS at 10 Hz, held in between (as fwsim.sensors.onboard does): correlated over 3 updates
            gnss_err = rng.normal(0, 0.5, 3)
        meas = truth.sample(t, rng, detect=not (gap[0] <= t < gap[1]), gnss_err=gnss_err)
        est = ukf.step(meas, CameraMotion.from_measurements(meas, MOUNT))
        assert est is not None and isinstance(est, TargetEstimate)
        rows.append((t, np.linalg.norm(est.pos_enu_m - truth.ship(t)), np.linalg.norm(est.vel_enu_m_s - truth.Vq),
                     np.linalg.norm(est.pos_std_m), np.abs(est.innovation_px).max()))
    return ukf, np.array(rows)


def settle_time(t, err, bar):
    """First time after which err stays below bar."""
    above = np.nonzero(err >= bar)[0]
    return t[0] if above.size == 0 else t[min(above[-1] + 1, len(t) - 1)]


def test_ukf_tracks_a_constant_velocity_ship_from_an_orbit_and_survives_a_dropout():
    ukf, r = run_orbit()
    t, pe, ve = r[:, 0], r[:, 1], r[:, 2]
    assert isinstance(ukf, TargetEstimator)  # the estimator Protocol a user's filter implements too
    assert resolve_class("controllers.estimation.ukf:UkfTargetEstimator", "estimator") is UkfTargetEstimator
    before, gap = t < 45.0, (t >= 45.0) & (t < 48.0)
    # converged within 60 s: position < 8 m (the paper's bar), velocity < 1 m/s, and it stays there
    assert settle_time(t[before], pe[before], 8.0) < 60.0
    assert settle_time(t[before], ve[before], 1.0) < 60.0
    assert pe[(t >= 30) & before].max() < 8.0 and ve[(t >= 30) & before].max() < 1.0
    # the 3 s dropout: predicted only, no innovation, error bounded
    assert np.all(np.isnan(r[gap, 4]))
    assert pe[gap].max() < 15.0
    # and back under the bar after it
    assert pe[t >= 50].max() < 8.0 and ve[t >= 55].max() < 1.0
    assert ukf.numerical_resets == 0 and ukf.rejected_updates == 0
    # innovations are of the size of the pixel noise once converged
    assert np.sqrt(np.nanmean(r[t > 20, 4] ** 2)) < 8.0


def test_ukf_step_before_any_detection_and_the_initial_guess():
    truth = OrbitTruth()
    rng = np.random.default_rng(8)
    ukf = UkfTargetEstimator(CAM)
    m0 = truth.sample(0.0, rng, detect=False)
    assert ukf.step(m0, CameraMotion.from_measurements(m0, MOUNT)) is None and not ukf.initialised
    m1 = truth.sample(1 / 30, rng)
    est = ukf.step(m1, CameraMotion.from_measurements(m1, MOUNT))
    assert ukf.initialised and est.t_s == m1.t_s
    # first guess on the sea along the detection's ray: within a few percent of the ~700 m range
    assert np.linalg.norm(est.pos_enu_m - truth.ship(m1.t_s)) < 30.0
    assert est.pos_enu_m[2] == 0.0 and np.all(est.vel_enu_m_s == 0.0)
    assert np.allclose(est.vel_std_m_s[:2], 10.0)
    assert ukf.cov.shape == (8, 8) and ukf.pos_vel_cov.shape == (6, 6)


def vel_error_after_burst(cfg, bias_px=6.0, seed=3):
    """Velocity error (m/s) of an orbit's estimate 1 s before and just after 2 s of detections bias_px off
    (6 px: ~4 m at the orbit's 700 m slant range)."""
    truth = OrbitTruth()
    rng = np.random.default_rng(seed)
    ukf = UkfTargetEstimator(CAM, cfg)
    before = math.nan
    for k in range(int(50.0 * 30) + 1):
        t = k / 30.0
        if k % 3 == 0:
            gnss_err = rng.normal(0, 0.5, 3)
        meas = truth.sample(t, rng, gnss_err=gnss_err)
        if t >= 48.0:
            meas = dataclasses.replace(meas, det_u_px=meas.det_u_px + bias_px)
        est = ukf.step(meas, CameraMotion.from_measurements(meas, MOUNT))
        if k == 47 * 30:
            before = float(np.linalg.norm(est.vel_enu_m_s - truth.Vq))
    return before, float(np.linalg.norm(est.vel_enu_m_s - truth.Vq))


def test_a_short_burst_of_biased_detections_barely_moves_the_velocity():
    """The dive sees the ship from fast-changing angles, and the box-centre correction then errs by metres for
    a second or two; the last seconds coast on the estimated velocity, so such a burst must shift the position
    estimate rather than the velocity (a ship holds its velocity: small target_accel_noise_m_s2)."""
    before, after = vel_error_after_burst(UkfConfig())
    assert before < 0.5
    assert after < 0.7, f"velocity error {after:.2f} m/s after the burst (before {before:.2f})"
    # a nervous process model lets the same burst through into the velocity
    _, nervous = vel_error_after_burst(UkfConfig(target_accel_noise_m_s2=0.2))
    assert nervous > after + 0.3


@pytest.mark.parametrize("dt, omega", [(1 / 30, [0.01, -0.02, 0.03]), (0.12, [0.3, 0.1, -0.2]),
                                       (1 / 30, [0.0, 0.0, 0.0])])
def test_the_compiled_process_model_equals_the_numpy_one(dt, omega):
    """The filter integrates its sigma points with a CasADi function (controllers.compiled): the same RK4 of the
    same model as the numpy form to rounding, over one substep and several (dt > max_substep_s), rotating or not."""
    from controllers.estimation.ukf import _fx_batch, _fx_compiled
    rng = np.random.default_rng(3)
    S = np.column_stack([rng.normal(0, 0.2, (17, 2)), rng.normal([100.0, 50.0, 3.75], 20, (17, 3)),
                         rng.normal(0, 3, (17, 3))])
    _, R = F.camera_pose_world(np.array([-500.0, 10.0, 500.0]), np.array([0.1, -0.05, 0.4]), MOUNT, -0.3, -0.6)
    args = (dt, np.array([-500.0, 10.0, 500.0]), R, np.array([3.0, 22.0, -1.0]), np.array(omega), 0.05)
    ref, got = _fx_batch(S, *args), _fx_compiled(S, *args)
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)
    assert not np.array_equal(ref, S)


def test_the_compiled_update_equals_the_numpy_one():
    """The UKF's measurement update is one CasADi function: the same innovation, chi-square statistic, state and
    covariance as UnscentedCore.update with the batched pinhole + flat-sea measurement model in numpy, to
    rounding, the determinant of the pixel rows' innovation covariance, and the gain's horizontal position rows
    for the pixel columns (the state's move per pixel of the detection)."""
    from controllers.estimation.ukf import _CompiledUpdate, _hx_batch
    x = np.array([0.05, -0.02, 100.0, 40.0, 3.75, 2.0, 1.0, 0.0])
    # a covariance as the filter has them (the pixel and r_c rows of S are nearly dependent: S's condition
    # number is ~1e5 here, so both solves agree to ~1e-11 relative)
    P = np.diag([1e-4, 1e-4, 25, 25, 1, 4, 4, 0.25])
    P[2, 5] = P[5, 2] = P[3, 6] = P[6, 3] = 1.0
    _, R = F.camera_pose_world(np.array([-400.0, 10.0, 480.0]), np.array([0.1, -0.05, 0.4]), MOUNT, -0.3, -0.6)
    args = dict(f_u=CAM.fx, f_v=CAM.fy, c_u=CAM.cx, c_v=CAM.cy, R_ec=R, cam_h=480.0, plane_z=3.75)
    r = np.array([4.0, 4.0, 0.6, 0.6, 0.6])
    ref = UnscentedCore(8, 5, 1.0, 2.0, 0.0)
    ref.set_state(x, P)
    z = _hx_batch(x[None, :], **args)[0] + np.array([3.0, -2.0, 0.5, -0.4, 0.2])
    y_ref = ref.update(z, _hx_batch, np.diag(r), gate=(math.inf, [0, 1]), **args)
    core = UnscentedCore(8, 5, 1.0, 2.0, 0.0)
    core.set_state(x, P)
    sigmas = core.current_sigma_points()
    upd = _CompiledUpdate.for_core(core)
    y, nis, x_new, P_new, det, K_h = upd(sigmas, x, core.P, z, r, **args)
    for i in (0, 1):  # the gain's position rows for a pixel column: the update is linear in z
        x_i = upd(sigmas, x, core.P, z + np.eye(5)[i], r, **args)[2]
        np.testing.assert_allclose(K_h[:, i], (x_i - x_new)[2:4], rtol=1e-6, atol=1e-9)
    S = core.moments(sigmas, x, _hx_batch(sigmas, **args))[1] + np.diag(r)  # the innovation covariance
    assert det == pytest.approx(np.linalg.det(S[:2, :2]), rel=1e-10)  # its pixel rows' (the likelihood's)
    np.testing.assert_allclose(y, y_ref, rtol=1e-10, atol=1e-9)
    assert nis == pytest.approx(ref.last_nis, rel=1e-10)
    np.testing.assert_allclose(x_new, ref.x, rtol=1e-10, atol=1e-9)
    np.testing.assert_allclose(P_new, ref.P, rtol=1e-8, atol=1e-10)


def test_ground_from_pixel_jacobian_against_finite_differences():
    """d(point on the plane)/d(u, v): the analytic form against central differences of the ray's meeting point
    with the plane, for oblique and steep views."""
    from controllers.navigation.camera_model import ground_from_pixel_jacobian
    for euler, pan, tilt, px in (((0.1, -0.05, 0.4), -0.3, -0.6, (700.0, 300.0)),
                                 ((-0.5, 0.1, 2.0), 1.2, -1.2, (100.0, 650.0)),
                                 ((0.0, 0.0, 0.0), 0.0, -0.25, (640.0, 360.0))):
        cam_pos, R = F.camera_pose_world(np.array([-400.0, 10.0, 480.0]), np.array(euler), MOUNT, pan, tilt)

        def ground(u, v):
            x1, x2 = (float(a) for a in CAM.normalised(u, v))
            Z = depth_on_plane(x1, x2, R, cam_pos[2], 3.75)
            return cam_pos + Z * (R @ np.array([x1, x2, 1.0]))

        u, v = px
        h = 1e-3
        fd = np.stack([(ground(u + h, v) - ground(u - h, v)) / (2 * h),
                       (ground(u, v + h) - ground(u, v - h)) / (2 * h)], axis=1)
        x1, x2 = (float(a) for a in CAM.normalised(u, v))
        J = ground_from_pixel_jacobian(x1, x2, R, cam_pos[2], 3.75, CAM.fx, CAM.fy)
        np.testing.assert_allclose(J, fd, rtol=1e-6, atol=1e-9)
        assert abs(J[2]).max() < 1e-9  # the point stays on the plane
    # a ray that does not come down to the plane
    assert np.all(np.isnan(ground_from_pixel_jacobian(0.0, -2.0, np.eye(3), 100.0, 0.0, CAM.fx, CAM.fy)))


def _fly_with_an_80_by_30_box(cfg: UkfConfig, n: int):
    """The UKF on ``n`` frames of the orbit (seed 11), each detection with an 80 x 30 px box round its centre:
    (the last estimate, state, covariance, measurements, camera motion)."""
    truth, rng = OrbitTruth(), np.random.default_rng(11)
    ukf = UkfTargetEstimator(CAM, cfg)
    for i in range(n):
        meas = truth.sample(i / 30.0, rng)
        meas = dataclasses.replace(meas, det_bbox_px=np.array([meas.det_u_px - 40.0, meas.det_v_px - 15.0,
                                                              meas.det_u_px + 40.0, meas.det_v_px + 15.0]))
        motion = CameraMotion.from_measurements(meas, MOUNT)
        est = ukf.step(meas, motion)
    return est, ukf.x, ukf.cov, meas, motion


def test_the_box_centre_bias_widens_the_reported_std_only():
    """box_centre_bias_frac: the estimate's position std carries the systematic box-centre error through the
    latest view's geometry (J diag(s^2) J^T, s a fraction of the box's size); the state and the filter's own
    covariance are those of box_centre_bias_frac = 0."""
    from controllers.navigation.camera_model import ground_from_pixel_jacobian
    runs = {k: _fly_with_an_80_by_30_box(UkfConfig(box_centre_bias_frac=k, box_centre_height_std_m=0.0), 90)
            for k in (0.0, 0.1)}
    (e0, x0, P0, _, _), (e1, x1, P1, meas, motion) = runs[0.0], runs[0.1]
    assert np.array_equal(x0, x1) and np.array_equal(P0, P1)
    np.testing.assert_allclose(e0.pos_std_m, np.sqrt(np.diag(P0)[2:5]))
    n1, n2 = (float(a) for a in CAM.normalised(meas.det_u_px, meas.det_v_px))
    J = ground_from_pixel_jacobian(n1, n2, motion.R_enu_from_cam, motion.height_m, 0.0, CAM.fx, CAM.fy)[:2]
    C = (J * np.array([8.0, 3.0]) ** 2) @ J.T  # 10 % of the 80 x 30 px box
    np.testing.assert_allclose(e1.pos_std_m[:2] ** 2, np.diag(P0)[2:4] + np.diag(C), rtol=1e-9)
    assert e1.pos_std_m[2] == e0.pos_std_m[2] and np.all(e1.pos_std_m[:2] > e0.pos_std_m[:2])


def test_the_height_consider_term_is_the_planes_displacement_of_a_point_seen_higher():
    """height_consider_cov against finite differences: a point dz above the plane, seen from the camera, is where
    its ray meets the plane displaced by g dz (|g| = 1 / tan of the elevation): the covariance is
    height_std^2 g g^T; nothing for a ray that does not come down."""
    from controllers.estimation.ukf import height_consider_cov
    cam_pos = np.array([-3800.0, 900.0, 1000.0])
    for target in (np.array([0.0, 0.0, 0.0]), np.array([-3400.0, 1100.0, 0.0]), np.array([-3700.0, 920.0, 0.0])):
        rel = target - cam_pos
        # a camera looking straight at the target: its optical axis (camera z) along rel
        z = rel / np.linalg.norm(rel)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z], axis=1)  # columns: camera x, y, z in ENU
        dz = 1e-3
        p = target + np.array([0.0, 0.0, dz])
        d = p - cam_pos
        on_plane = cam_pos + d * (cam_pos[2] - target[2]) / -d[2]
        g = (on_plane[:2] - target[:2]) / dz
        c = R.T @ d
        C = height_consider_cov(c[0] / c[2], c[1] / c[2], R, 2.0)
        np.testing.assert_allclose(C, 4.0 * np.outer(g, g), rtol=1e-5)
        elev = math.atan2(-rel[2], np.hypot(rel[0], rel[1]))
        assert math.sqrt(np.trace(C)) == pytest.approx(2.0 / math.tan(elev), rel=1e-5)
    assert not height_consider_cov(0.0, 0.0, np.eye(3), 2.0).any()  # looking up


def test_the_height_error_widens_the_reported_std_along_the_line_of_sight_only():
    """box_centre_height_std_m goes into the reported std (not the state, not the filter's covariance) as
    height_consider_cov of the latest detection's view, beside the box fraction."""
    from controllers.estimation.ukf import height_consider_cov
    runs = {sh: _fly_with_an_80_by_30_box(UkfConfig(box_centre_bias_frac=0.0, box_centre_height_std_m=sh), 60)
            for sh in (0.0, 2.2)}
    (e0, x0, P0, _, _), (e1, x1, P1, meas, motion) = runs[0.0], runs[2.2]
    assert np.array_equal(x0, x1) and np.array_equal(P0, P1)
    n1, n2 = (float(a) for a in CAM.normalised(meas.det_u_px, meas.det_v_px))
    C = height_consider_cov(n1, n2, motion.R_enu_from_cam, 2.2)
    np.testing.assert_allclose(e1.pos_std_m[:2] ** 2, np.diag(P0)[2:4] + np.diag(C), rtol=1e-9)
    assert np.diag(C).max() > 0.1 and e1.pos_std_m[2] == e0.pos_std_m[2]


def test_the_heading_spread_of_the_shape_correction_widens_the_reported_std_only():
    """A fix's ``offset_spread_px2`` (the shape correction's spread over the headings the ship may have) goes
    into the reported position std through the view's geometry, beside box_centre_bias_frac:
    ``J (diag(s^2) + S) J^T``; the state and the filter's covariance are those without it, and
    ``consider_heading_spread: false`` reports the std without it."""
    from controllers.estimation.ukf import fix_from_measurements
    from controllers.navigation.camera_model import ground_from_pixel_jacobian
    truth = OrbitTruth()
    S = np.array([[9.0, 2.0], [2.0, 16.0]])  # px^2
    runs = {}
    for name, spread, use in (("none", np.zeros((2, 2)), True), ("spread", S, True), ("off", S, False)):
        rng = np.random.default_rng(11)
        ukf = UkfTargetEstimator(CAM, UkfConfig(box_centre_bias_frac=0.1, consider_heading_spread=use,
                                                box_centre_height_std_m=0.0))
        for i in range(60):
            meas = truth.sample(i / 30.0, rng)
            meas = dataclasses.replace(meas, det_bbox_px=np.array([meas.det_u_px - 40.0, meas.det_v_px - 15.0,
                                                                  meas.det_u_px + 40.0, meas.det_v_px + 15.0]))
            motion = CameraMotion.from_measurements(meas, MOUNT)
            fix = dataclasses.replace(fix_from_measurements(meas), offset_spread_px2=spread)
            if i == 0:
                ukf.initialise(fix, motion)
            else:
                ukf.predict(meas.t_s, motion)
                ukf.update(fix, motion)
        runs[name] = (ukf.estimate(), ukf.x, ukf.cov, meas, motion)
    (e0, x0, P0, _, _), (e1, x1, P1, meas, motion), (e2, x2, P2, _, _) = runs["none"], runs["spread"], runs["off"]
    assert np.array_equal(x0, x1) and np.array_equal(P0, P1) and np.array_equal(x0, x2) and np.array_equal(P0, P2)
    np.testing.assert_array_equal(e2.pos_std_m, e0.pos_std_m)
    n1, n2 = (float(a) for a in CAM.normalised(meas.det_u_px, meas.det_v_px))
    J = ground_from_pixel_jacobian(n1, n2, motion.R_enu_from_cam, motion.height_m, 0.0, CAM.fx, CAM.fy)[:2]
    C = J @ (np.diag(np.array([8.0, 3.0]) ** 2) + S) @ J.T
    np.testing.assert_allclose(e1.pos_std_m[:2] ** 2, np.diag(P0)[2:4] + np.diag(C), rtol=1e-9)
    assert e1.pos_std_m[2] == e0.pos_std_m[2] and np.all(e1.pos_std_m[:2] > e0.pos_std_m[:2])


def test_the_symmetric_square_root_of_a_2x2_covariance():
    """_sqrt_spd2: the symmetric root squares back to the matrix, for full-rank, singular and zero ones."""
    from controllers.estimation.ukf import _sqrt_spd2
    for a, b, c in ((9.0, 2.0, 16.0), (64.0, 0.0, 9.0), (4.0, 6.0, 9.0), (1e-6, 0.0, 5e3), (0.0, 0.0, 0.0)):
        r00, r01, r11 = _sqrt_spd2(a, b, c)
        S = np.array([[r00, r01], [r01, r11]])
        np.testing.assert_allclose(S @ S, [[a, b], [b, c]], rtol=1e-9, atol=1e-9)
        assert np.all(np.linalg.eigvalsh(S) >= -1e-12)

