"""The self-occlusion CBF (controllers/guidance/cbf.py): geometry, signs, derivative, and the NMPC keeping h >= 0."""
import math

import numpy as np
import pytest

from controllers.guidance.cbf import (
    CbfConfig,
    alpha_right,
    body_z_component,
    cbf_rows,
    h_sides,
    h_value,
    lateral_offset,
)
from controllers.guidance.nmpc import Nmpc, NmpcConfig, continuous_dynamics, kinematic_closed_loop
from fwsim.interface.frames import dcm_enu_from_frd, heading_ned_from_course_enu

RNG = np.random.default_rng(7)


def body_frame(phi, psi_enu, theta=0.0):
    """R_enu_from_frd of an NMPC state's attitude, through fwsim.interface.frames (the harness's convention)."""
    return dcm_enu_from_frd([phi, theta, heading_ned_from_course_enu(psi_enu)])


def test_config_defaults_validate():
    cfg = CbfConfig.model_validate({})
    assert cfg.enabled and cfg.beta > 0 and cfg.sides == "both"
    with pytest.raises(Exception):
        CbfConfig.model_validate({"betta": 1.0})


@pytest.mark.parametrize("psi_enu", [0.0, 0.5 * math.pi, 2.0, -2.5, math.pi])
def test_target_on_the_right_gives_positive_lateral_offset(psi_enu):
    """R_p > 0 for a target along the body's right wing (FRD +y from fwsim.interface.frames), < 0 on the left."""
    x = np.array([100.0, -50.0, 500.0, 0.0, 0.0, psi_enu])
    right = body_frame(0.0, psi_enu)[:, 1]  # body y (right wing) in ENU
    assert right[2] == pytest.approx(0.0, abs=1e-12)
    for side, sign in ((1.0, 1.0), (-1.0, -1.0)):
        target = x[:3] + side * 300.0 * right - np.array([0.0, 0.0, 500.0])  # on the sea, abeam
        assert sign * lateral_offset(x, target) == pytest.approx(300.0, rel=1e-12)
    # the explicit case: flying east, a target to the south is on the right
    assert lateral_offset([0, 0, 500, 0, 0, 0.0], [0, -100, 0]) == pytest.approx(100.0)
    assert lateral_offset([0, 0, 500, 0, 0, 0.5 * math.pi], [100, 0, 0]) == pytest.approx(100.0)


def test_body_z_sign_is_the_sign_of_h_at_zero_pitch():
    """z_b (body-z component of r_q/p from fwsim.interface.frames) >= 0 exactly when h = min(h_R, h_L) >= 0."""
    n_pos = n_neg = 0
    for _ in range(4000):
        phi = RNG.uniform(-1.2, 1.2)
        psi = RNG.uniform(-math.pi, math.pi)
        x = np.array([*RNG.uniform(-500, 500, 2), RNG.uniform(20, 1000), phi, 0.0, psi])
        target = np.array([*RNG.uniform(-1500, 1500, 2), 0.0])
        r = target - x[:3]
        zb = float(body_frame(phi, psi)[:, 2] @ r)
        assert body_z_component(x, target) == pytest.approx(zb, abs=1e-9 * np.linalg.norm(r))
        hR, hL = h_sides(x, target)
        assert hR + hL == pytest.approx(math.pi, abs=1e-12)
        rho = math.hypot(lateral_offset(x, target), x[2] - target[2])
        assert zb == pytest.approx(rho * math.sin(hR), abs=1e-9 * rho)
        if abs(zb) < 1e-6 * rho:
            continue
        assert (zb >= 0.0) == (h_value(x, target) >= 0.0)
        n_pos += zb >= 0
        n_neg += zb < 0
    assert n_pos > 500 and n_neg > 500


def test_h_is_the_papers_h_on_the_targets_side():
    """Paper eq. (21): h = atan(-z_q/p / R_p) - phi for R_p > 0; for R_p < 0 its h is -h_L (eq. (24))."""
    for _ in range(500):
        x = np.array([*RNG.uniform(-500, 500, 2), RNG.uniform(50, 800), RNG.uniform(-0.6, 0.6), 0.0,
                      RNG.uniform(-math.pi, math.pi)])
        target = np.array([*RNG.uniform(-1500, 1500, 2), 0.0])
        Rp = lateral_offset(x, target)
        paper = math.atan(-(target[2] - x[2]) / Rp) - x[3]
        hR, hL = h_sides(x, target)
        assert (hR if Rp > 0 else -hL) == pytest.approx(paper, abs=1e-12)


def _flight(x, u, q, v, dt):
    """UAV (eq. (17), RK4) and constant-velocity target moved by dt (negative: backwards)."""
    f = lambda s: np.asarray(continuous_dynamics(s, u), dtype=float).ravel()  # noqa: E731
    k1 = f(x)
    k2 = f(x + 0.5 * dt * k1)
    k3 = f(x + 0.5 * dt * k2)
    k4 = f(x + dt * k3)
    return x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4), q + v * dt


def test_alpha_matches_finite_differences():
    """alpha_R = d/dt atan2(D, R_p) along the UAV's and the target's motion; h_dot = alpha -+ phi_dot."""
    eps = 1e-4
    for _ in range(200):
        x = np.array([*RNG.uniform(-800, 800, 2), RNG.uniform(50, 900), RNG.uniform(-0.6, 0.6),
                      RNG.uniform(-0.25, 0.25), RNG.uniform(-math.pi, math.pi)])
        u = np.array([RNG.uniform(18, 28), RNG.uniform(-0.8, 0.8), RNG.uniform(-0.3, 0.3)])
        q = np.array([*RNG.uniform(-1000, 1000, 2), RNG.uniform(-5, 5)])
        v = RNG.uniform(-8, 8, 3)
        xp, qp = _flight(x, u, q, v, eps)
        xm, qm = _flight(x, u, q, v, -eps)
        a = lambda xx, qq: math.atan2(xx[2] - qq[2], lateral_offset(xx, qq))  # noqa: E731
        fd = (a(xp, qp) - a(xm, qm)) / (2 * eps)
        # central differences: truncation ~ eps^2 |a'''| ~ 1e-9, well below the terms (0.01 - 1 rad/s)
        assert alpha_right(x, u, q, v) == pytest.approx(fd, rel=1e-6, abs=1e-8)
        phi_dot = u[1] + u[2] * math.sin(x[3]) * math.tan(x[4])
        hR_fd = (h_sides(xp, qp)[0] - h_sides(xm, qm)[0]) / (2 * eps)
        hL_fd = (h_sides(xp, qp)[1] - h_sides(xm, qm)[1]) / (2 * eps)
        assert hR_fd == pytest.approx(alpha_right(x, u, q, v) - phi_dot, rel=1e-6, abs=1e-7)
        assert hL_fd == pytest.approx(-alpha_right(x, u, q, v) + phi_dot, rel=1e-6, abs=1e-7)


def test_rows_are_the_papers_input_constraints():
    """Row <= 0 is u_p <= beta h_R + alpha - u_q s(phi) t(theta) (right), u_p >= -beta h_L - alpha_L - ... (left)."""
    beta = 0.7
    for _ in range(200):
        x = np.array([*RNG.uniform(-800, 800, 2), RNG.uniform(50, 900), RNG.uniform(-0.6, 0.6),
                      RNG.uniform(-0.25, 0.25), RNG.uniform(-math.pi, math.pi)])
        u = np.array([RNG.uniform(18, 28), RNG.uniform(-0.8, 0.8), RNG.uniform(-0.3, 0.3)])
        q, v = np.array([*RNG.uniform(-1000, 1000, 2), 0.0]), RNG.uniform(-8, 8, 3)
        hR, hL = h_sides(x, q)
        aR = alpha_right(x, u, q, v)
        coupling = u[2] * math.sin(x[3]) * math.tan(x[4])
        right, left = (float(r) for r in np.asarray(cbf_rows(x, u, q, v, beta)).ravel())
        assert right == pytest.approx(u[1] - (beta * hR + aR - coupling), abs=1e-12)
        assert left == pytest.approx((-beta * hL + aR - coupling) - u[1], abs=1e-12)


# --------------------------------------------------------------------------- closed loop

# The target on the inside of a tight turn, at low altitude: R = 200 m, H = 150 m, the UAV 600 m east of the
# ship, level at 150 m, heading north. To close on the circle the unconstrained NMPC banks 35 deg toward a
# ship only atan(150/600) = 14 deg below the horizon: the wing hides it.
CBF_CASE = dict(x0=np.array([600.0, 0.0, 150.0, 0.0, 0.0, 0.5 * math.pi]), q0=[0.0, 0.0, 0.0], v=[0.0, 5.0, 0.0])
H_TOL_RAD = 2e-3  # 0.1 deg: the CBF is imposed at the samples of an Euler model; the plant is continuous


def _cbf_run(enabled: bool, sides: str = "both"):
    cfg = NmpcConfig(radius_m=200.0, altitude_m=150.0, cbf={"enabled": enabled, "sides": sides})
    return kinematic_closed_loop(Nmpc(cfg), CBF_CASE["x0"], CBF_CASE["q0"], CBF_CASE["v"], 25.0, substeps=4)


def test_unconstrained_nmpc_hides_the_target_in_this_geometry():
    run = _cbf_run(False)
    assert run.h.min() < -0.3  # rad: about 20 deg above the wing plane
    assert np.nanmin(run.min_h_pred) < -0.3


@pytest.mark.parametrize("sides", ["both", "solve_time"])
def test_cbf_keeps_the_target_below_the_wing_plane(sides):
    run = _cbf_run(True, sides)
    assert run.fallbacks == 0
    assert run.h.min() >= -H_TOL_RAD  # realised, on the continuous plant
    assert np.nanmin(run.min_h_pred) >= -H_TOL_RAD  # predicted, over every horizon
    assert run.h.min() < 0.05  # and it was binding (the constraint did the work)
    assert abs(run.states[:, 3]).max() > math.radians(10)  # still turning toward the circle
