"""Tests for fwsim.world.gimbal: PT camera kinematics (paper eqs. (13)-(14)), rate and joint limits."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from fwsim.interface import frames as F
from fwsim.world import gimbal as G
SETTINGS = settings(max_examples=60, deadline=None)
PI = math.pi

pan_s = st.floats(-PI, PI, allow_nan=False, allow_infinity=False)
tilt_s = st.floats(-PI / 2, PI / 2, allow_nan=False, allow_infinity=False)
tilt_away = st.floats(-1.4, 1.4, allow_nan=False, allow_infinity=False)  # |cos| > 0.17
rate_s = st.floats(-3.0, 3.0, allow_nan=False, allow_infinity=False)
rates3 = st.tuples(rate_s, rate_s, rate_s).map(np.array)


def vee(S):
    """Vector of a (nearly) skew-symmetric matrix, antisymmetric part."""
    A = 0.5 * (S - S.T)
    return np.array([A[2, 1], A[0, 2], A[1, 0]])


def rel_part(tilt, pan_rate, tilt_rate):
    """Paper eq. (13), written as in the paper: P @ Ry_passive(tilt) @ [0,0,pan_dot] + P @ [0,tilt_dot,0]."""
    P = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]])
    return P @ F.rot_y(tilt) @ np.array([0.0, 0.0, pan_rate]) + P @ np.array([0.0, tilt_rate, 0.0])


# ---------------------------------------------------------------- config


def test_config_defaults_and_validation():
    cfg = G.GimbalConfig.model_validate({})
    assert cfg.mount_offset_frd_m == [0.0, 0.0, 0.10]
    assert cfg.pan_limits_rad == [-PI, PI] and cfg.tilt_limits_rad == [-PI / 2, PI / 2]
    assert cfg.max_pan_rate_rad_s == pytest.approx(2 * PI / 3) == cfg.max_tilt_rate_rad_s
    assert cfg.initial_pan_rad == 0.0 and cfg.initial_tilt_rad == -0.5
    for bad in ({"foo": 1}, {"pan_limits_rad": [1.0, -1.0]}, {"initial_tilt_rad": 1.0, "tilt_limits_rad": [-1.0, 0.5]},
                {"tilt_limits_rad": [-2.0, 0.0]}, {"max_pan_rate_rad_s": 0.0}, {"mount_offset_frd_m": [0.0, 0.0]}):
        with pytest.raises(ValidationError):
            G.GimbalConfig.model_validate(bad)
    with pytest.raises(ValidationError):
        cfg.initial_pan_rad = 1.0  # frozen
    assert all(f.description for f in G.GimbalConfig.model_fields.values())


# ---------------------------------------------------------------- rotation


@SETTINGS
@given(pan_s, tilt_s)
def test_R_frd_from_cam_orthonormal(pan, tilt):
    R = G.R_frd_from_cam(pan, tilt)
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-12)
    # definition: Rz_active(pan) @ Ry_active(tilt) @ R_TILT_FROM_CAM (active = transpose of frames' passive)
    assert np.allclose(R, F.rot_z(pan).T @ F.rot_y(tilt).T @ F.R_FRD_FROM_CAM, atol=1e-12)


def test_known_orientations():
    R0 = G.R_frd_from_cam(0.0, 0.0)
    assert np.allclose(R0[:, 2], [1, 0, 0])  # optical axis forward
    assert np.allclose(R0[:, 0], [0, 1, 0])  # image right = right wing
    assert np.allclose(R0[:, 1], [0, 0, 1])  # image down = body down
    assert np.allclose(G.R_frd_from_cam(0.0, -PI / 2)[:, 2], [0, 0, 1], atol=1e-12)  # straight down
    assert np.allclose(G.R_frd_from_cam(0.0, +0.3)[:, 2][2], -math.sin(0.3))  # positive tilt looks up
    Rp = G.R_frd_from_cam(PI / 2, 0.0)
    assert np.allclose(Rp[:, 2], [0, 1, 0], atol=1e-12)  # right wing
    assert np.allclose(Rp[:, 1], [0, 0, 1], atol=1e-12)  # image still upright


@SETTINGS
@given(pan_s, st.floats(-1.5, 1.5))
def test_pointing_round_trip(pan, tilt):
    d = G.R_frd_from_cam(pan, tilt)[:, 2]
    p2, t2 = G.pan_tilt_pointing_at(3.7 * d)
    assert abs(F.wrap_pi(p2 - pan)) < 1e-9 or abs(abs(pan) - PI) < 1e-9 and abs(abs(p2) - PI) < 1e-9
    assert t2 == pytest.approx(tilt, abs=1e-9)
    assert np.allclose(G.R_frd_from_cam(p2, t2)[:, 2], d, atol=1e-9)


@SETTINGS
@given(st.tuples(*[st.floats(-10.0, 10.0)] * 3).map(np.array))
def test_pointing_random_directions(v):
    n = np.linalg.norm(v)
    if n < 1e-3 or math.hypot(v[0], v[1]) < 1e-2 * n:  # away from straight up/down
        return
    pan, tilt = G.pan_tilt_pointing_at(v)
    assert np.allclose(G.R_frd_from_cam(pan, tilt)[:, 2], v / n, atol=1e-9)


# ---------------------------------------------------------------- angular velocity


@SETTINGS
@given(pan_s, tilt_s, rate_s, rate_s)
def test_relative_omega_matches_finite_difference(pan, tilt, pan_rate, tilt_rate):
    h = 1e-6
    Rm = G.R_frd_from_cam(pan - h * pan_rate, tilt - h * tilt_rate)
    Rp = G.R_frd_from_cam(pan + h * pan_rate, tilt + h * tilt_rate)
    R = G.R_frd_from_cam(pan, tilt)
    w_fd = vee(R.T @ (Rp - Rm) / (2 * h))
    w = G.camera_angular_velocity(pan, tilt, pan_rate, tilt_rate, np.zeros(3))
    assert np.allclose(w, w_fd, atol=1e-6)
    assert np.allclose(w, rel_part(tilt, pan_rate, tilt_rate), atol=1e-12)  # paper's eq. (13) literally


@SETTINGS
@given(pan_s, tilt_away, rate_s, rate_s, rates3)
def test_total_omega_matches_finite_difference(pan, tilt, pan_rate, tilt_rate, wb):
    """Body spinning at constant wb (FRD) in an inertial frame while the joints move."""
    h = 1e-6
    nb = float(np.linalg.norm(wb))

    def R_w_from_cam(t):
        R_w_from_b = F.dcm_from_quat(F.quat_from_axis_angle(wb if nb else [1, 0, 0], nb * t))
        return R_w_from_b @ G.R_frd_from_cam(pan + pan_rate * t, tilt + tilt_rate * t)

    w_fd = vee(R_w_from_cam(0.0).T @ (R_w_from_cam(h) - R_w_from_cam(-h)) / (2 * h))
    w = G.camera_angular_velocity(pan, tilt, pan_rate, tilt_rate, wb)
    assert np.allclose(w, w_fd, atol=1e-6)


@SETTINGS
@given(tilt_away, rate_s, rate_s)
def test_joint_rates_invert_omegac(tilt, pan_rate, tilt_rate):
    w = G.camera_angular_velocity(0.3, tilt, pan_rate, tilt_rate, np.zeros(3))
    pr, tr = G.joint_rates_from_camera_rates(tilt, w[0], w[1])
    assert pr == pytest.approx(pan_rate, abs=1e-9)
    assert tr == pytest.approx(tilt_rate, abs=1e-9)


@pytest.mark.parametrize("tilt", [PI / 2, -PI / 2, PI / 2 - 1e-9, -PI / 2 + 1e-12])
def test_joint_rates_finite_at_singularity(tilt):
    pr, tr = G.joint_rates_from_camera_rates(tilt, 0.4, 1.0, cos_min=0.05)
    assert math.isfinite(pr) and math.isfinite(tr)
    assert abs(pr) == pytest.approx(1.0 / 0.05) and tr == 0.4
    # sign kept: beyond 90 deg cos < 0 flips the pan rate
    assert G.joint_rates_from_camera_rates(PI / 2 + 1e-6, 0.0, 1.0)[0] < 0
    with pytest.raises(ValueError):
        G.joint_rates_from_camera_rates(0.0, 0.0, 1.0, cos_min=0.0)


# ---------------------------------------------------------------- joint model


def test_rate_limits_and_nan_hold():
    cfg = G.GimbalConfig(initial_tilt_rad=0.0)
    dt = 1 / 30
    g = G.Gimbal(cfg, dt)
    lim = 2 * PI / 3
    for k in range(1, 6):
        s = g.step(k * dt, 10.0, -10.0)
        assert s.pan_rad == pytest.approx(k * lim * dt)
        assert s.tilt_rad == pytest.approx(-k * lim * dt)
        assert s.pan_rate_rad_s == pytest.approx(lim) and s.tilt_rate_rad_s == pytest.approx(-lim)
        assert s.t_s == k * dt and not s.at_pan_limit and not s.at_tilt_limit
    before = g.state
    s = g.step(1.0, float("nan"), float("nan"))
    assert (s.pan_rad, s.tilt_rad, s.pan_rate_rad_s, s.tilt_rate_rad_s) == (before.pan_rad, before.tilt_rad, 0.0, 0.0)
    assert g.state is s


def test_joint_limits_pin_and_release():
    cfg = G.GimbalConfig()
    dt = 0.01
    g = G.Gimbal(cfg, dt)
    hi = PI / 2
    pinned_seen = False
    for k in range(1, 501):  # 5 s upward at 3 rad/s (clipped to 2pi/3): reaches +90 deg after ~1 s
        s = g.step(k * dt, 0.0, 3.0)
        assert s.tilt_rad <= hi
        if s.at_tilt_limit:
            assert s.tilt_rad == hi
            if pinned_seen:
                assert s.tilt_rate_rad_s == 0.0
            pinned_seen = True
    assert pinned_seen and g.state.at_tilt_limit and g.state.tilt_rate_rad_s == 0.0
    s = g.step(5.01, 0.0, -1.0)  # reverse: leaves the limit at once
    assert not s.at_tilt_limit
    assert s.tilt_rad == pytest.approx(hi - dt) and s.tilt_rate_rad_s == pytest.approx(-1.0)
    # pan limit too
    g.reset(PI - 0.001, 0.0)
    s = g.step(0.0, 1.0, 0.0)
    assert s.pan_rad == PI and s.at_pan_limit and s.pan_rate_rad_s == pytest.approx(0.1)
    s = g.step(0.0, 1.0, 0.0)
    assert s.pan_rad == PI and s.pan_rate_rad_s == 0.0


def test_reset_and_constructor_validation():
    g = G.Gimbal(G.GimbalConfig(), 0.01)
    assert (g.state.pan_rad, g.state.tilt_rad, g.state.t_s) == (0.0, -0.5, 0.0)
    s = g.reset(0.2, -PI / 2)
    assert s.at_tilt_limit and g.state is s
    with pytest.raises(ValueError):
        g.reset(4.0, 0.0)
    with pytest.raises(ValueError):
        g.reset(0.0, float("nan"))
    with pytest.raises(ValueError):
        G.Gimbal(G.GimbalConfig(), 0.0)


# ---------------------------------------------------------------- world pose


def test_camera_pose_world():
    pos = np.array([10.0, -20.0, 500.0])
    p, R = G.camera_pose_world(pos, [0.0, 0.0, 0.0], [0.0, 0.0, 0.1], 0.0, 0.0)
    assert np.allclose(p, [10.0, -20.0, 499.9])  # 0.1 m below the UAV
    assert np.allclose(R[:, 2], [0, 1, 0])  # heading North, level: looks North
    assert np.allclose(R[:, 0], [1, 0, 0]) and np.allclose(R[:, 1], [0, 0, -1])  # image right = East, down = down
    p, R = G.camera_pose_world(pos, [0.0, 0.0, PI / 2], [1.0, 0.0, 0.1], 0.0, 0.0)
    assert np.allclose(R[:, 2], [1, 0, 0], atol=1e-12)  # heading East: optical axis ENU +x
    assert np.allclose(p, [11.0, -20.0, 499.9])  # forward offset goes East
    p, R = G.camera_pose_world(pos, [0.0, 0.0, PI / 2], [0.0, 0.0, 0.1], 0.0, -PI / 2)
    assert np.allclose(R[:, 2], [0, 0, -1], atol=1e-12)  # tilt -90: straight down in the world


@SETTINGS
@given(st.tuples(pan_s, st.floats(-1.5, 1.5), pan_s).map(np.array), pan_s, tilt_s)
def test_camera_pose_world_composes(euler, pan, tilt):
    off = [0.3, -0.2, 0.1]
    p, R = G.camera_pose_world([1.0, 2.0, 3.0], euler, off, pan, tilt)
    R_ef = F.dcm_enu_from_frd(euler)
    assert np.allclose(R, R_ef @ G.R_frd_from_cam(pan, tilt), atol=1e-12)
    assert np.allclose(p, np.array([1.0, 2.0, 3.0]) + R_ef @ off, atol=1e-12)
