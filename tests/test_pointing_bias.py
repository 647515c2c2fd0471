"""The target UKF's pointing-bias states (``controllers.ukf.pointing_bias_std_rad``).

The camera's pointing error (boresight, encoder offsets, the navigation's attitude error) is estimated as
two states while the navigation reports its attitude uncertainty; without that report the filter is the
paper's 8-state UKF, unchanged."""
from __future__ import annotations

import math

import numpy as np
import pytest

from controllers.config import UkfConfig
from controllers.estimation.ukf import UkfTargetEstimator, through_pointing_bias
from controllers.messages import DetectionFix
from controllers.navigation.camera_model import CameraMotion, PinholeCamera

CAM = PinholeCamera.from_fov(1280, 720, 60.0)


def _look_at(cam: np.ndarray, tgt: np.ndarray) -> np.ndarray:
    """R_enu_from_cam of a camera (x right, y down, z forward) looking from cam at tgt."""
    f = tgt - cam
    f = f / np.linalg.norm(f)
    r = np.cross(f, [0.0, 0.0, 1.0])
    r = r / np.linalg.norm(r)
    return np.column_stack([r, np.cross(f, r), f])


def _small_rotation(ax: float, ay: float) -> np.ndarray:
    cx, sx, cy, sy = math.cos(ax), math.sin(ax), math.cos(ay), math.sin(ay)
    return np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]]) @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])


def _fix(t: float, u: float, v: float, first: bool) -> DetectionFix:
    box = np.array([u - 20.0, v - 10.0, u + 20.0, v + 10.0])
    return DetectionFix(t, True, t, u, v, box, u, v, np.full(4, np.nan), True, "", "", True, first, 0.0, t)


def _orbit(att_var_rad2: float, duration_s: float = 150.0, bias_rad=(0.006, -0.004), seed: int = 1):
    """A camera circling a still target (R 700 m, 300 m up, 22 m/s) whose real frame is turned by
    ``bias_rad`` from the one the filter is told; the filter's horizontal errors and stds over the last
    half, and the filter."""
    rng = np.random.default_rng(seed)
    ukf = UkfTargetEstimator(CAM, UkfConfig(box_centre_bias_frac=0.0, box_centre_height_std_m=0.0,
                                            consider_heading_spread=False))
    R, H, V, dt = 700.0, 300.0, 22.0, 1.0 / 30.0
    w, tgt, turn = V / R, np.zeros(3), _small_rotation(*bias_rad)
    errs, stds = [], []
    n = int(duration_s / dt)
    for k in range(n):
        t, a = k * dt, w * k * dt
        p = np.array([R * math.cos(a), R * math.sin(a), H])
        v = np.array([-V * math.sin(a), V * math.cos(a), 0.0])
        Rec = _look_at(p, tgt)
        motion = CameraMotion(t, p, v, Rec, Rec.T @ np.array([0.0, 0.0, w]), H, att_var_rad2)
        X = (Rec @ turn).T @ (tgt - p)
        fix = _fix(t, CAM.fx * X[0] / X[2] + CAM.cx + rng.normal(0.0, 2.0),
                   CAM.fy * X[1] / X[2] + CAM.cy + rng.normal(0.0, 2.0), k == 0)
        if k == 0:
            ukf.initialise(fix, motion)
            continue
        ukf.predict(t, motion)
        ukf.update(fix, motion)
        if k > n // 2:
            est = ukf.estimate()
            errs.append(float(np.linalg.norm(est.pos_enu_m[:2] - tgt[:2])))
            stds.append(float(np.max(est.pos_std_m[:2])))
    return np.array(errs), np.array(stds), ukf


def test_through_pointing_bias_is_the_turned_camera_to_first_order():
    """The image point of a feature seen by the camera turned so that its old boresight appears at (b1, b2)
    against the exact rotation: the difference is second order in the bias."""
    for x1, x2 in [(0.0, 0.0), (0.3, -0.2), (-0.5, 0.4)]:
        for b in (1e-3, 2e-3):
            b1, b2 = b, -0.5 * b
            turn = _small_rotation(b2, -b1)  # the real frame in the believed one: turn^T [0, 0, 1] ~ [b1, b2, 1]
            d = turn.T @ np.array([x1, x2, 1.0])
            approx = through_pointing_bias(x1, x2, b1, b2)
            assert approx[0] == pytest.approx(d[0] / d[2], abs=3.0 * b * b)
            assert approx[1] == pytest.approx(d[1] / d[2], abs=3.0 * b * b)


def test_without_the_navigations_attitude_uncertainty_the_filter_is_the_8_state_ukf():
    errs, _, ukf = _orbit(math.nan, duration_s=10.0)
    assert ukf.dim_x == 8 and ukf.cov.shape == (8, 8)
    assert np.all(ukf.pointing_bias_rad == 0.0)


def test_a_pointing_bias_is_estimated_round_an_orbit_and_the_std_owns_it():
    """A 0.4 deg camera-frame bias at 760 m of range over one orbit: the 8-state filter's error stays at
    metres and its std claims far less; with the bias states the bias is found and the std covers the error."""
    err8, std8, _ = _orbit(math.nan, duration_s=200.0)
    err10, std10, ukf = _orbit(1e-6, duration_s=200.0)
    assert ukf.dim_x == 10
    assert np.mean(err8) > 3.0 * np.mean(std8) / 2.0  # overconfident: its 2-sigma does not cover the error
    assert np.mean(err10) < 0.75 * np.mean(err8)
    assert np.mean(err10 <= 2.0 * std10) > 0.9
    truth = np.array([0.004, 0.006])  # where the believed boresight appears in the real camera (_orbit's turn)
    assert float(ukf.pointing_bias_rad @ truth) > 0.3 * float(truth @ truth)


def test_the_prior_grows_with_the_navigations_attitude_uncertainty():
    _, _, calm = _orbit(1e-6, duration_s=1.0)
    _, _, unsure = _orbit(0.02 ** 2 * 2.0, duration_s=1.0)
    assert unsure.cov[8, 8] > 4.0 * calm.cov[8, 8]


def test_imm_and_ct_ukf_keep_their_states():
    from controllers.config import CtUkfConfig
    from controllers.estimation.ct_ukf import CtUkfTargetEstimator
    from controllers.estimation.imm import ImmTargetEstimator
    cfg = UkfConfig(pointing_bias_std_rad=0.005)
    ct = CtUkfTargetEstimator(CAM, cfg, CtUkfConfig())
    imm = ImmTargetEstimator(CAM, cfg)
    Rec = _look_at(np.array([700.0, 0.0, 300.0]), np.zeros(3))
    motion = CameraMotion(0.0, np.array([700.0, 0.0, 300.0]), np.zeros(3), Rec, np.zeros(3), 300.0, 1e-4)
    fix = _fix(0.0, CAM.cx, CAM.cy, True)
    ct.initialise(fix, motion)
    imm.initialise(fix, motion)
    assert ct.cov.shape == (10, 10) and imm.cv.cov.shape == (8, 8) and imm.ct.cov.shape == (10, 10)
