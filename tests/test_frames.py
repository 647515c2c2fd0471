"""Property tests (hypothesis) and known cases for fwsim.interface.frames."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fwsim.interface import frames as F
SETTINGS = settings(max_examples=120, deadline=None)
PI = math.pi

# ---------------------------------------------------------------- strategies

angle = st.floats(-PI, PI, allow_nan=False, allow_infinity=False)
pitch = st.floats(-PI / 2 + 1e-3, PI / 2 - 1e-3, allow_nan=False, allow_infinity=False)
euler = st.tuples(angle, pitch, angle).map(np.array)
# Pitch well away from gimbal lock, for the finite-difference check (errors scale like 1/cos^k).
euler_moderate = st.tuples(angle, st.floats(-1.4, 1.4), angle).map(np.array)
rate = st.floats(-3.0, 3.0, allow_nan=False, allow_infinity=False)
rates = st.tuples(rate, rate, rate).map(np.array)
vec = st.tuples(*[st.floats(-100.0, 100.0, allow_nan=False)] * 3).map(np.array)


@st.composite
def unit_quat(draw):
    q = np.array(draw(st.tuples(*[st.floats(-1.0, 1.0, allow_nan=False)] * 4)))
    if np.linalg.norm(q) < 0.1:
        q = np.array([1.0, 0.0, 0.0, 0.0]) + q
    return q / np.linalg.norm(q)


def ang_diff(a, b):
    return np.abs(F.wrap_pi(np.asarray(a) - np.asarray(b)))


def skew(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def expm_so3(w):
    """Rodrigues: exp([w]x)."""
    th = np.linalg.norm(w)
    K = skew(w)
    if th < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + math.sin(th) / th * K + (1 - math.cos(th)) / th**2 * K @ K


def assert_rotation(R):
    assert R.shape == (3, 3)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert abs(np.linalg.det(R) - 1.0) < 1e-12


# ---------------------------------------------------------------- wrap_pi, headings


@SETTINGS
@given(st.floats(-1e4, 1e4, allow_nan=False))
def test_wrap_pi_range_and_equivalence(a):
    w = F.wrap_pi(a)
    assert -PI <= w < PI
    k = (a - w) / (2 * PI)
    assert abs(k - round(k)) < 1e-9
    wa = F.wrap_pi(np.array([a, a]))
    assert np.all((wa >= -PI) & (wa < PI))
    np.testing.assert_allclose(wa, w, atol=1e-9)


def test_wrap_pi_edges():
    assert F.wrap_pi(PI) == -PI
    assert F.wrap_pi(-PI) == -PI
    assert F.wrap_pi(0.0) == 0.0
    assert F.wrap_pi(np.nextafter(-PI, -4.0)) < PI  # must not round up to +pi
    assert F.wrap_pi(np.array([PI, -PI, 3 * PI]))[0] == -PI


def test_course_heading_known():
    assert F.course_enu_from_heading_ned(0.0) == pytest.approx(PI / 2)  # North
    assert F.course_enu_from_heading_ned(PI / 2) == pytest.approx(0.0)  # East
    assert F.course_enu_from_heading_ned(PI) == pytest.approx(-PI / 2)  # South
    assert F.heading_ned_from_course_enu(PI / 2) == pytest.approx(0.0)


@SETTINGS
@given(angle)
def test_course_heading_inverse(psi):
    back = F.heading_ned_from_course_enu(F.course_enu_from_heading_ned(psi))
    assert ang_diff(back, psi) < 1e-12


# ---------------------------------------------------------------- ENU / NED


def test_ned_from_enu_known():
    np.testing.assert_array_equal(F.ned_from_enu([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0])
    np.testing.assert_array_equal(F.enu_from_ned([2.0, 1.0, -3.0]), [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(F.R_NED_FROM_ENU @ [1.0, 2.0, 3.0], [2.0, 1.0, -3.0])
    assert_rotation(F.R_NED_FROM_ENU)
    np.testing.assert_array_equal(F.ned_from_enu(np.ones((4, 3)))[:, 2], -np.ones(4))


@SETTINGS
@given(vec)
def test_ned_enu_involution(v):
    np.testing.assert_array_equal(F.enu_from_ned(F.ned_from_enu(v)), v)
    np.testing.assert_array_equal(F.ned_from_enu(v), F.R_NED_FROM_ENU @ v)
    np.testing.assert_allclose(
        F.quat_rotate(F.Q_ENU_FROM_NED, F.ned_from_enu(v)), v, atol=1e-12
    )


# ---------------------------------------------------------------- passive rotations


def test_rot_passive_signs():
    a = 0.3
    c, s = math.cos(a), math.sin(a)
    np.testing.assert_allclose(F.rot_x(a), [[1, 0, 0], [0, c, s], [0, -s, c]])
    # Frame turned +90 deg about z: the old x axis is seen along -y of the new frame.
    np.testing.assert_allclose(F.rot_z(PI / 2) @ [1, 0, 0], [0, -1, 0], atol=1e-15)
    np.testing.assert_allclose(F.rot_x(PI / 2) @ [0, 1, 0], [0, 0, -1], atol=1e-15)
    np.testing.assert_allclose(F.rot_y(PI / 2) @ [0, 0, 1], [-1, 0, 0], atol=1e-15)
    # Passive rot = transpose of the active rotation (axis-angle).
    for rot, axis in ((F.rot_x, [1, 0, 0]), (F.rot_y, [0, 1, 0]), (F.rot_z, [0, 0, 1])):
        np.testing.assert_allclose(
            rot(a), F.dcm_from_quat(F.quat_from_axis_angle(axis, a)).T, atol=1e-15
        )


@SETTINGS
@given(euler)
def test_paper_eq1_ordering(e):
    phi, theta, psi = e
    R_frd_from_ned = F.rot_x(phi) @ F.rot_y(theta) @ F.rot_z(psi)
    np.testing.assert_allclose(F.dcm_ned_from_frd(e).T, R_frd_from_ned, atol=1e-12)
    # eq. (1): B_R_G = Rx Ry Rz NED_R_ENU, the world being ENU.
    np.testing.assert_allclose(
        F.dcm_enu_from_frd(e).T, R_frd_from_ned @ F.R_NED_FROM_ENU, atol=1e-12
    )


# ---------------------------------------------------------------- DCMs and Euler angles


@SETTINGS
@given(euler, unit_quat(), angle)
def test_every_dcm_is_a_rotation(e, q, a):
    for R in (
        F.dcm_ned_from_frd(e),
        F.dcm_enu_from_frd(e),
        F.dcm_from_quat(q),
        F.rot_x(a),
        F.rot_y(a),
        F.rot_z(a),
        F.R_NED_FROM_ENU,
        F.R_FRD_FROM_CAM,
    ):
        assert_rotation(R)


@SETTINGS
@given(euler)
def test_euler_dcm_euler_round_trip(e):
    back = F.euler_from_dcm_ned_from_frd(F.dcm_ned_from_frd(e))
    assert np.all(ang_diff(back, e) < 1e-9)
    assert -PI <= back[0] < PI and -PI <= back[2] < PI


@SETTINGS
@given(euler)
def test_euler_quat_euler_round_trip(e):
    q = F.quat_ned_from_frd(e)
    assert abs(np.linalg.norm(q) - 1.0) < 1e-12
    np.testing.assert_allclose(F.dcm_from_quat(q), F.dcm_ned_from_frd(e), atol=1e-12)
    back = F.euler_from_quat_ned_from_frd(q)
    assert np.all(ang_diff(back, e) < 1e-9)


def test_euler_from_dcm_clips_asin():
    R = F.dcm_ned_from_frd([0.0, PI / 2, 0.0])
    R[2, 0] = -1.0 - 1e-12  # slightly outside asin's domain after rounding
    e = F.euler_from_dcm_ned_from_frd(R)
    assert e[1] == pytest.approx(PI / 2)


@SETTINGS
@given(euler)
def test_quat_enu_from_frd_matches_dcm(e):
    np.testing.assert_allclose(
        F.dcm_from_quat(F.quat_enu_from_frd(e)), F.dcm_enu_from_frd(e), atol=1e-12
    )


# ---------------------------------------------------------------- quaternions


@SETTINGS
@given(unit_quat())
def test_quat_dcm_quat_round_trip(q):
    back = F.quat_from_dcm(F.dcm_from_quat(q))
    assert back[0] >= 0.0
    assert abs(np.linalg.norm(back) - 1.0) < 1e-12
    assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-9


@pytest.mark.parametrize("axis", [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -1, 1]])
def test_quat_from_dcm_half_turns(axis):
    # 180 deg rotations: trace = -1, w = 0; exercises the non-trace pivots.
    q = F.quat_from_axis_angle(axis, PI)
    back = F.quat_from_dcm(F.dcm_from_quat(q))
    assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-12


@SETTINGS
@given(unit_quat(), unit_quat())
def test_quat_mul_is_dcm_product(q1, q2):
    np.testing.assert_allclose(
        F.dcm_from_quat(F.quat_mul(q1, q2)),
        F.dcm_from_quat(q1) @ F.dcm_from_quat(q2),
        atol=1e-12,
    )
    np.testing.assert_allclose(F.quat_mul(q1, F.quat_conj(q1)), [1, 0, 0, 0], atol=1e-12)


@SETTINGS
@given(unit_quat(), vec)
def test_quat_rotate_is_dcm_times_v(q, v):
    np.testing.assert_allclose(F.quat_rotate(q, v), F.dcm_from_quat(q) @ v, atol=1e-10)
    # and the Hamilton sandwich q v q*
    qv = F.quat_mul(F.quat_mul(q, np.r_[0.0, v]), F.quat_conj(q))
    np.testing.assert_allclose(F.quat_rotate(q, v), qv[1:], atol=1e-10)


def test_quat_misc():
    q = F.quat_from_axis_angle([0, 0, 2.0], PI / 2)  # axis normalized inside
    np.testing.assert_allclose(F.quat_rotate(q, [1, 0, 0]), [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(F.quat_normalize([2.0, 0, 0, 0]), [1, 0, 0, 0])
    np.testing.assert_array_equal(F.quat_to_xyzw([1.0, 2.0, 3.0, 4.0]), [2, 3, 4, 1])
    with pytest.raises(ValueError):
        F.quat_normalize([0.0, 0.0, 0.0, 0.0])


# ---------------------------------------------------------------- known attitudes


def test_yaw_90_points_east():
    R = F.dcm_enu_from_frd([0.0, 0.0, PI / 2])
    np.testing.assert_allclose(R @ [1, 0, 0], [1, 0, 0], atol=1e-15)  # nose East
    np.testing.assert_allclose(R @ [0, 0, 1], [0, 0, -1], atol=1e-15)  # body down is down
    np.testing.assert_allclose(R @ [0, 1, 0], [0, -1, 0], atol=1e-15)  # right wing South
    q = F.quat_enu_from_frd([0.0, 0.0, PI / 2])
    np.testing.assert_allclose(F.quat_rotate(q, [1, 0, 0]), [1, 0, 0], atol=1e-15)


def test_yaw_0_points_north():
    np.testing.assert_allclose(F.dcm_enu_from_frd([0, 0, 0]) @ [1, 0, 0], [0, 1, 0], atol=1e-15)


def test_pitch_up_climbs():
    nose = F.dcm_enu_from_frd([0.0, math.radians(30), 0.0]) @ [1, 0, 0]
    assert nose[2] > 0.0
    np.testing.assert_allclose(nose, [0, math.cos(math.radians(30)), 0.5], atol=1e-15)


def test_roll_right_drops_right_wing():
    wing = F.dcm_enu_from_frd([PI / 2, 0.0, 0.0]) @ [0, 1, 0]
    np.testing.assert_allclose(wing, [0, 0, -1], atol=1e-15)


def test_camera_constant():
    np.testing.assert_array_equal(F.R_FRD_FROM_CAM @ [0, 0, 1], [1, 0, 0])  # optical axis
    np.testing.assert_array_equal(F.R_FRD_FROM_CAM @ [1, 0, 0], [0, 1, 0])  # image right
    np.testing.assert_array_equal(F.R_FRD_FROM_CAM @ [0, 1, 0], [0, 0, 1])  # image down


# ---------------------------------------------------------------- kinematics


@SETTINGS
@given(euler, rates)
def test_euler_rate_functions_are_inverses(e, w):
    np.testing.assert_allclose(
        F.body_rates_from_euler_rates(e, F.euler_rates_from_body_rates(e, w)), w, atol=1e-9
    )
    np.testing.assert_allclose(
        F.euler_rates_from_body_rates(e, F.body_rates_from_euler_rates(e, w)),
        w,
        atol=1e-9 / math.cos(e[1]) ** 2,
    )


@SETTINGS
@given(euler_moderate, rates)
def test_euler_rates_match_dcm_finite_difference(e, w):
    # R_dot = R [omega]x with R = R_ned_from_frd; exact step R exp([omega]x dt), central difference.
    dt = 1e-5
    R = F.dcm_ned_from_frd(e)
    e_plus = F.euler_from_dcm_ned_from_frd(R @ expm_so3(w * dt))
    e_minus = F.euler_from_dcm_ned_from_frd(R @ expm_so3(-w * dt))
    fd = F.wrap_pi(e_plus - e_minus) / (2 * dt)
    np.testing.assert_allclose(F.euler_rates_from_body_rates(e, w), fd, atol=1e-6)


# ---------------------------------------------------------------- geodetic


@SETTINGS
@given(
    st.floats(-80.0, 80.0),
    st.floats(-180.0, 180.0),
    st.floats(-10_000.0, 10_000.0),
    st.floats(-10_000.0, 10_000.0),
    st.floats(0.0, 3000.0),
)
def test_geodetic_round_trip(lat0, lon0, x, y, z):
    o = F.GeoOrigin(lat0, lon0)
    p = np.array([x, y, z])
    lat, lon, alt = o.geodetic_from_enu(p)
    assert -PI <= lon < PI
    np.testing.assert_allclose(o.enu_from_geodetic(lat, lon, alt), p, atol=1e-6)
    p2 = o.enu_from_geodetic(lat, lon, alt)
    lat2, lon2, alt2 = o.geodetic_from_enu(p2)
    assert abs(lat2 - lat) < 1e-12 and ang_diff(lon2, lon) < 1e-12 and alt2 == alt


def test_geodetic_known():
    o = F.GeoOrigin(45.0, 179.99)  # near the antimeridian: the longitude wrap matters
    np.testing.assert_array_equal(
        o.enu_from_geodetic(math.radians(45.0), math.radians(179.99), 0.0), [0, 0, 0]
    )
    p = o.enu_from_geodetic(math.radians(45.0), math.radians(-179.99), 12.5)
    assert 1500.0 < p[0] < 1600.0 and p[1] == 0.0 and p[2] == 12.5  # 0.02 deg East, sea at z = 0
    # 1 arc-minute of latitude at 45 deg is about 1852 m.
    p = o.enu_from_geodetic(math.radians(45.0 + 1 / 60), math.radians(179.99), 0.0)
    assert p[1] == pytest.approx(1852.0, abs=2.0)
    with pytest.raises(Exception):
        o.lat0_deg = 1.0  # frozen
    assert o == F.GeoOrigin(45.0, 179.99)


@given(st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3), st.lists(st.floats(-1e3, 1e3), min_size=3, max_size=3))
def test_cross3_matches_numpy(a, b):
    from fwsim.interface.frames import cross3
    np.testing.assert_allclose(cross3(a, b), np.cross(a, b), rtol=1e-12, atol=1e-9)
