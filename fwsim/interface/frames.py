"""Rotations, quaternions and frame helpers: every frame convention of the project.

Conventions (docs/design/architecture.md, "Frames and conventions"):
  * world frame: ENU (x East, y North, z Up), metres;
  * body frame: FRD (x forward, y right wing, z down);
  * camera frame: z along the optical axis, x right, y down;
  * Euler angles ``euler_ned_rad = [roll phi, pitch theta, yaw psi]`` are the
    aerospace 3-2-1 angles of the body relative to NED (yaw clockwise from North);
  * quaternions are Hamilton, scalar first ``[w, x, y, z]``, unit norm;
  * names say the direction: ``v_a = quat_rotate(q_a_from_b, v_b)`` and
    ``v_a = R_a_from_b @ v_b``.

Everything here works on single (3,) vectors with ``math`` on scalars, since it
runs at 120 Hz in a Python loop; only ``wrap_pi``, ``ned_from_enu`` and
``enu_from_ned`` also accept arrays of shape (..., 3) / (...).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

_TWO_PI = 2.0 * math.pi

# --------------------------------------------------------------------------- angles


def wrap_pi(a):
    """Wrap an angle (rad, scalar or array) to [-pi, pi)."""
    if isinstance(a, (float, int)):
        w = math.fmod(a + math.pi, _TWO_PI)
        if w < 0.0:
            w += _TWO_PI
        w -= math.pi
        return w - _TWO_PI if w >= math.pi else w  # guard against rounding to +pi
    w = np.mod(np.asarray(a, dtype=float) + math.pi, _TWO_PI) - math.pi
    return np.where(w >= math.pi, w - _TWO_PI, w)


def course_enu_from_heading_ned(psi_ned: float) -> float:
    """ENU course (rad, counter-clockwise from East) from a NED heading (clockwise from North)."""
    return wrap_pi(0.5 * math.pi - psi_ned)


def heading_ned_from_course_enu(course_enu: float) -> float:
    """NED heading (rad, clockwise from North) from an ENU course (counter-clockwise from East)."""
    return wrap_pi(0.5 * math.pi - course_enu)


def heading_deg_from_course_enu(course_enu_rad: float) -> float:
    """Compass heading in degrees, [0, 360) clockwise from North (the scenario's convention), from an ENU
    course in radians (counter-clockwise from East)."""
    return (90.0 - math.degrees(course_enu_rad)) % 360.0


def bearing_deg(from_enu, to_enu) -> float:
    """Compass bearing (degrees clockwise from North, (-180, 180]) from one point to another (ENU)."""
    return math.degrees(math.atan2(to_enu[0] - from_enu[0], to_enu[1] - from_enu[1]))


def dcm_ship_from_enu(course_enu_rad: float) -> np.ndarray:
    """R_ship_from_enu for a ship whose bow points along ``course_enu_rad`` (ship frame: x bow, y port, z up)."""
    cs, sn = math.cos(course_enu_rad), math.sin(course_enu_rad)
    return np.array([[cs, sn, 0.0], [-sn, cs, 0.0], [0.0, 0.0, 1.0]])


# --------------------------------------------------------------------------- ENU / NED

#: R_ned_from_enu: [e, n, u] -> [n, e, -u]. A proper rotation, its own inverse.
R_NED_FROM_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
R_ENU_FROM_NED = R_NED_FROM_ENU.copy()

#: q_enu_from_ned (= q_ned_from_enu up to sign): 180 deg about (1, 1, 0)/sqrt(2).
Q_ENU_FROM_NED = np.array([0.0, math.sqrt(0.5), math.sqrt(0.5), 0.0])

#: R_frd_from_cam for a camera looking along body x (cam z -> body x, x -> right, y -> down).
R_FRD_FROM_CAM = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

for _c in (R_NED_FROM_ENU, R_ENU_FROM_NED, Q_ENU_FROM_NED, R_FRD_FROM_CAM):
    _c.setflags(write=False)  # shared constants: callers must not modify them in place
del _c


def ned_from_enu(v) -> np.ndarray:
    """NED vector(s) from ENU vector(s), shape (..., 3): [e, n, u] -> [n, e, -u]."""
    v = np.asarray(v, dtype=float)
    if v.shape == (3,):
        return np.array([v[1], v[0], -v[2]])
    out = v[..., [1, 0, 2]]  # fancy indexing copies
    out[..., 2] *= -1.0
    return out


def enu_from_ned(v) -> np.ndarray:
    """ENU vector(s) from NED vector(s), shape (..., 3): [n, e, d] -> [e, n, -d]."""
    return ned_from_enu(v)


# --------------------------------------------------------------------------- DCMs


def rot_x(a: float) -> np.ndarray:
    """Passive (frame) rotation by a about x: R_new_from_old = [[1,0,0],[0,c,s],[0,-s,c]]."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, s], [0.0, -s, c]])


def rot_y(a: float) -> np.ndarray:
    """Passive (frame) rotation by a about y: R_new_from_old = [[c,0,-s],[0,1,0],[s,0,c]]."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])


def rot_z(a: float) -> np.ndarray:
    """Passive (frame) rotation by a about z: R_new_from_old = [[c,s,0],[-s,c,0],[0,0,1]]."""
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])


def _dcm_ned_from_frd_rows(euler_ned_rad):
    """Rows of R_ned_from_frd as three lists (shared by the two DCM builders)."""
    phi, theta, psi = float(euler_ned_rad[0]), float(euler_ned_rad[1]), float(euler_ned_rad[2])
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    return (
        [ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp],
        [ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp],
        [-st, sf * ct, cf * ct],
    )


#: the rows of R_ned_from_frd as three lists of floats (for a hot path that multiplies them out itself)
dcm_ned_from_frd_rows = _dcm_ned_from_frd_rows


def dcm_ned_from_frd(euler_ned_rad) -> np.ndarray:
    """R_ned_from_frd from 3-2-1 Euler angles; its transpose is rot_x(phi) @ rot_y(theta) @ rot_z(psi)."""
    return np.array(_dcm_ned_from_frd_rows(euler_ned_rad))


def dcm_enu_from_frd(euler_ned_rad) -> np.ndarray:
    """R_enu_from_frd (body FRD to world ENU) from NED 3-2-1 Euler angles (= R_ENU_FROM_NED @ R_ned_from_frd)."""
    n, e, d = _dcm_ned_from_frd_rows(euler_ned_rad)
    return np.array([e, n, [-d[0], -d[1], -d[2]]])


def euler_from_dcm_ned_from_frd(R) -> np.ndarray:
    """[roll, pitch, yaw] (rad, NED 3-2-1) from R_ned_from_frd; roll, yaw in [-pi, pi), pitch in [-pi/2, pi/2]."""
    s = -float(R[2][0])
    theta = math.asin(1.0 if s > 1.0 else (-1.0 if s < -1.0 else s))
    phi = math.atan2(float(R[2][1]), float(R[2][2]))
    psi = math.atan2(float(R[1][0]), float(R[0][0]))
    return np.array([wrap_pi(phi), theta, wrap_pi(psi)])


# --------------------------------------------------------------------------- quaternions


def quat_mul(q1, q2) -> np.ndarray:
    """Hamilton product q1 * q2 ([w,x,y,z]); q_a_from_c = quat_mul(q_a_from_b, q_b_from_c)."""
    w1, x1, y1, z1 = float(q1[0]), float(q1[1]), float(q1[2]), float(q1[3])
    w2, x2, y2, z2 = float(q2[0]), float(q2[1]), float(q2[2]), float(q2[3])
    return np.array(
        [
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        ]
    )


def quat_conj(q) -> np.ndarray:
    """Conjugate [w,-x,-y,-z]: the inverse of a unit quaternion (q_b_from_a from q_a_from_b)."""
    return np.array([float(q[0]), -float(q[1]), -float(q[2]), -float(q[3])])


def quat_normalize(q) -> np.ndarray:
    """Unit quaternion [w,x,y,z] with the same rotation; raises ValueError on a zero quaternion."""
    w, x, y, z = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if n == 0.0 or not math.isfinite(n):
        raise ValueError(f"cannot normalize quaternion {q!r}")
    return np.array([w / n, x / n, y / n, z / n])


def quat_rotate(q, v) -> np.ndarray:
    """v_a = q_a_from_b * v_b * conj(q_a_from_b) for a unit [w,x,y,z] quaternion (same as dcm_from_quat(q) @ v)."""
    w, x, y, z = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    vx, vy, vz = float(v[0]), float(v[1]), float(v[2])
    # t = 2 u x v ; v' = v + w t + u x t
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return np.array(
        [
            vx + w * tx + (y * tz - z * ty),
            vy + w * ty + (z * tx - x * tz),
            vz + w * tz + (x * ty - y * tx),
        ]
    )


def dcm_from_quat(q) -> np.ndarray:
    """R_a_from_b from a unit q_a_from_b ([w,x,y,z], Hamilton)."""
    w, x, y, z = float(q[0]), float(q[1]), float(q[2]), float(q[3])
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz = x * y, x * z, y * z
    wx, wy, wz = w * x, w * y, w * z
    return np.array(
        [
            [1.0 - 2.0 * (yy + zz), 2.0 * (xy - wz), 2.0 * (xz + wy)],
            [2.0 * (xy + wz), 1.0 - 2.0 * (xx + zz), 2.0 * (yz - wx)],
            [2.0 * (xz - wy), 2.0 * (yz + wx), 1.0 - 2.0 * (xx + yy)],
        ]
    )


def quat_from_dcm(R) -> np.ndarray:
    """Unit q_a_from_b ([w,x,y,z], w >= 0) from R_a_from_b, Shepperd/Markley (largest-pivot) method."""
    r00, r01, r02 = float(R[0][0]), float(R[0][1]), float(R[0][2])
    r10, r11, r12 = float(R[1][0]), float(R[1][1]), float(R[1][2])
    r20, r21, r22 = float(R[2][0]), float(R[2][1]), float(R[2][2])
    tr = r00 + r11 + r22
    # 4*[w^2, x^2, y^2, z^2] = 1 + [tr, ...]; pivot on the largest for stability.
    if tr >= r00 and tr >= r11 and tr >= r22:
        q = (1.0 + tr, r21 - r12, r02 - r20, r10 - r01)
    elif r00 >= r11 and r00 >= r22:
        q = (r21 - r12, 1.0 + 2.0 * r00 - tr, r01 + r10, r02 + r20)
    elif r11 >= r22:
        q = (r02 - r20, r01 + r10, 1.0 + 2.0 * r11 - tr, r12 + r21)
    else:
        q = (r10 - r01, r02 + r20, r12 + r21, 1.0 + 2.0 * r22 - tr)
    q = quat_normalize(q)
    return -q if q[0] < 0.0 else q


def quat_from_axis_angle(axis, angle: float) -> np.ndarray:
    """Unit quaternion of an active right-handed rotation by angle (rad) about axis (any frame, normalized here)."""
    ax, ay, az = float(axis[0]), float(axis[1]), float(axis[2])
    n = math.sqrt(ax * ax + ay * ay + az * az)
    if n == 0.0:
        if angle == 0.0:
            return np.array([1.0, 0.0, 0.0, 0.0])
        raise ValueError("quat_from_axis_angle: zero axis with non-zero angle")
    s = math.sin(0.5 * angle) / n
    return np.array([math.cos(0.5 * angle), ax * s, ay * s, az * s])


def quat_ned_from_frd(euler_ned_rad) -> np.ndarray:
    """q_ned_from_frd ([w,x,y,z]) from NED 3-2-1 Euler angles (= qz(psi) * qy(theta) * qx(phi))."""
    h0, h1, h2 = 0.5 * float(euler_ned_rad[0]), 0.5 * float(euler_ned_rad[1]), 0.5 * float(euler_ned_rad[2])
    cf, sf = math.cos(h0), math.sin(h0)
    ct, st = math.cos(h1), math.sin(h1)
    cp, sp = math.cos(h2), math.sin(h2)
    return np.array(
        [
            cf * ct * cp + sf * st * sp,
            sf * ct * cp - cf * st * sp,
            cf * st * cp + sf * ct * sp,
            cf * ct * sp - sf * st * cp,
        ]
    )


def quat_enu_from_frd(euler_ned_rad) -> np.ndarray:
    """q_enu_from_frd ([w,x,y,z], body FRD to world ENU) from NED 3-2-1 Euler angles."""
    return quat_mul(Q_ENU_FROM_NED, quat_ned_from_frd(euler_ned_rad))


def euler_from_quat_ned_from_frd(q) -> np.ndarray:
    """[roll, pitch, yaw] (rad, NED 3-2-1) from q_ned_from_frd ([w,x,y,z]; normalized here)."""
    return euler_from_dcm_ned_from_frd(dcm_from_quat(quat_normalize(q)))


def quat_to_xyzw(q) -> np.ndarray:
    """Reorder [w,x,y,z] to [x,y,z,w] (Foxglove / ROS order); same rotation."""
    return np.array([float(q[1]), float(q[2]), float(q[3]), float(q[0])])


# --------------------------------------------------------------------------- kinematics


def euler_rates_from_body_rates(euler_ned_rad, pqr) -> np.ndarray:
    """[phi_dot, theta_dot, psi_dot] from FRD body rates [p, q, r] (rad/s); singular at pitch = +-pi/2."""
    phi, theta = float(euler_ned_rad[0]), float(euler_ned_rad[1])
    p, q, r = float(pqr[0]), float(pqr[1]), float(pqr[2])
    cf, sf = math.cos(phi), math.sin(phi)
    ct = math.cos(theta)
    a = q * sf + r * cf
    return np.array([p + a * math.tan(theta), q * cf - r * sf, a / ct])


def body_rates_from_euler_rates(euler_ned_rad, euler_rates) -> np.ndarray:
    """FRD body rates [p, q, r] (rad/s) from NED 3-2-1 Euler-angle rates [phi_dot, theta_dot, psi_dot]."""
    phi, theta = float(euler_ned_rad[0]), float(euler_ned_rad[1])
    dphi, dtheta, dpsi = float(euler_rates[0]), float(euler_rates[1]), float(euler_rates[2])
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    return np.array([dphi - dpsi * st, dtheta * cf + dpsi * sf * ct, -dtheta * sf + dpsi * cf * ct])


# --------------------------------------------------------------------------- geodetic

WGS84_A_M = 6378137.0
WGS84_F = 1.0 / 298.257223563
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)


@dataclass(frozen=True)
class GeoOrigin:
    """Local flat-earth map between world ENU (m) and geodetic (lat, lon, alt), anchored at (lat0, lon0) on the sea.

    y = (lat - lat0) * M(lat0), x = wrap_pi(lon - lon0) * N(lat0) * cos(lat0), z = alt,
    with M, N the WGS84 meridian and prime-vertical radii at lat0. The two methods
    are exact inverses (to float rounding). z is the altitude above the WGS84
    ellipsoid, which the simulation takes as the sea surface, so the sea is
    exactly the plane z = 0 (earth curvature is "unrolled", not modelled).

    Accuracy: this is a curvilinear frame, not a Cartesian tangent plane, so
    Euclidean lengths in it carry a relative scale error of about
    (alt - y * tan(lat0)) / 6.37e6 along x and alt / 6.37e6 along y, i.e.
    about 1.6e-4 per km of altitude or of north offset (at lat0 = 45 deg).
    Measured against WGS84 chord lengths: 1 mm within 5 km at the equator on
    the sea, 0.16 m at 1 km and 1.4 m at 3 km from the origin at lat0 = 45 deg,
    plus about 0.5 m per km of distance at 3000 m altitude. (A true tangent
    plane would instead put the sea d^2 / (2 R) below z = 0: 8 cm at 1 km, 2 m
    at 5 km.) Good for guidance geometry over a few km, not for centimetre work.
    """

    lat0_deg: float
    lon0_deg: float
    _lat0: float = field(init=False, repr=False, compare=False)
    _lon0: float = field(init=False, repr=False, compare=False)
    _m: float = field(init=False, repr=False, compare=False)  # meridian radius M(lat0)
    _ncos: float = field(init=False, repr=False, compare=False)  # N(lat0) * cos(lat0)

    def __post_init__(self) -> None:
        if not -90.0 < self.lat0_deg < 90.0:
            raise ValueError(f"GeoOrigin: lat0_deg must be in (-90, 90), got {self.lat0_deg}")
        lat0 = math.radians(self.lat0_deg)
        s2 = math.sin(lat0) ** 2
        d = 1.0 - WGS84_E2 * s2
        object.__setattr__(self, "_lat0", lat0)
        object.__setattr__(self, "_lon0", wrap_pi(math.radians(self.lon0_deg)))
        object.__setattr__(self, "_m", WGS84_A_M * (1.0 - WGS84_E2) / (d * math.sqrt(d)))
        object.__setattr__(self, "_ncos", WGS84_A_M / math.sqrt(d) * math.cos(lat0))

    def enu_from_geodetic(self, lat_rad: float, lon_rad: float, alt_m: float) -> np.ndarray:
        """World ENU position (m) from geodetic latitude, longitude (rad) and altitude above the ellipsoid/sea (m)."""
        return np.array(
            [
                wrap_pi(float(lon_rad) - self._lon0) * self._ncos,
                (float(lat_rad) - self._lat0) * self._m,
                float(alt_m),
            ]
        )

    def geodetic_from_enu(self, pos_enu_m) -> tuple[float, float, float]:
        """(lat_rad, lon_rad in [-pi, pi), alt_m above the ellipsoid/sea) from a world ENU position (m)."""
        return (
            self._lat0 + float(pos_enu_m[1]) / self._m,
            wrap_pi(self._lon0 + float(pos_enu_m[0]) / self._ncos),
            float(pos_enu_m[2]),
        )


def finite3(v) -> bool:
    """Every component of the 3-vector finite (``np.isfinite(v).all()`` without its temporaries)."""
    return math.isfinite(v[0]) and math.isfinite(v[1]) and math.isfinite(v[2])


def cross3(a, b) -> np.ndarray:
    """Cross product of two 3-vectors (np.cross costs ~20 us per call on single vectors)."""
    a0, a1, a2 = float(a[0]), float(a[1]), float(a[2])
    b0, b1, b2 = float(b[0]), float(b[1]), float(b[2])
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


# --------------------------------------------------------------------------- pan-tilt camera
# Pan-then-tilt (paper "PT Camera Model"): pan about the mount z (down), positive
# clockwise seen from above; tilt about the panned y, positive UP; pan = tilt = 0
# looks along body +x. R_frd_from_cam = Rz_active(pan) Ry_active(tilt) R_FRD_FROM_CAM.


def R_frd_from_cam(pan_rad: float, tilt_rad: float) -> np.ndarray:
    """R_frd_from_cam = Rz_active(pan) @ Ry_active(tilt) @ R_TILT_FROM_CAM; column 2 is the optical axis in FRD."""
    cp, sp = math.cos(pan_rad), math.sin(pan_rad)
    ct, st = math.cos(tilt_rad), math.sin(tilt_rad)
    return np.array([[-sp, cp * st, cp * ct], [cp, sp * st, sp * ct], [0.0, ct, -st]])


def camera_pose_world(pos_enu_m, euler_ned_rad, mount_offset_frd_m, pan_rad: float, tilt_rad: float):
    """Camera position (world ENU, m) and R_enu_from_cam from the UAV pose and the joint angles.

    ``cam_pos = pos_enu + R_enu_from_frd @ mount_offset_frd`` and
    ``R_enu_from_cam = R_enu_from_frd @ R_frd_from_cam(pan, tilt)``; ``euler_ned_rad``
    are the NED 3-2-1 [roll, pitch, yaw] of the body. Returns ``(cam_pos_enu_m (3,), R (3,3))``.
    """
    R_ef = dcm_enu_from_frd(euler_ned_rad)
    ox, oy, oz = float(mount_offset_frd_m[0]), float(mount_offset_frd_m[1]), float(mount_offset_frd_m[2])
    e0, e1, e2 = R_ef.tolist()  # python floats: much faster to index than array rows
    cam_pos = np.array([
        float(pos_enu_m[0]) + e0[0] * ox + e0[1] * oy + e0[2] * oz,
        float(pos_enu_m[1]) + e1[0] * ox + e1[1] * oy + e1[2] * oz,
        float(pos_enu_m[2]) + e2[0] * ox + e2[1] * oy + e2[2] * oz,
    ])
    return cam_pos, R_ef @ R_frd_from_cam(pan_rad, tilt_rad)


def camera_angular_velocity(pan_rad: float, tilt_rad: float, pan_rate: float, tilt_rate: float,
                            body_rates_frd_rad_s) -> np.ndarray:
    """Total camera angular velocity (rad/s) relative to the world, expressed in the camera frame.

    ``omega_c = [tilt_rate, cos(tilt)*pan_rate, -sin(tilt)*pan_rate]`` (paper eq. (13),
    the joints' part) ``+ R_cam_from_frd @ body_rates_frd`` (the airframe's part).
    Pass zero body rates for the part relative to the body.
    """
    cp, sp = math.cos(pan_rad), math.sin(pan_rad)
    ct, st = math.cos(tilt_rad), math.sin(tilt_rad)
    p, q, r = float(body_rates_frd_rad_s[0]), float(body_rates_frd_rad_s[1]), float(body_rates_frd_rad_s[2])
    # rows of R_cam_from_frd = columns of R_frd_from_cam
    return np.array([
        tilt_rate + (-sp * p + cp * q),
        ct * pan_rate + (cp * st * p + sp * st * q + ct * r),
        -st * pan_rate + (cp * ct * p + sp * ct * q - st * r),
    ])


def joint_rates_from_camera_rates(tilt_rad: float, omega_cx: float, omega_cy: float,
                                  cos_min: float = 0.05) -> tuple[float, float]:
    """(pan_rate, tilt_rate) realising the camera-frame rates (omega_cx, omega_cy) relative to the body.

    Paper eq. (14): ``tilt_rate = omega_cx``, ``pan_rate = omega_cy / cos(tilt)``.
    Singularity at tilt = +-90 deg (optical axis along body z: pan only spins the
    image about the optical axis, it can no longer move it sideways). Handling:
    ``|cos(tilt)|`` is floored at ``cos_min`` keeping its sign, so the result is
    always finite, and within ``|tilt| > acos(cos_min)`` (about 87.1 deg for the
    default 0.05) ``|pan_rate|`` is at most ``|omega_cy| / cos_min`` and the
    commanded ``omega_cy`` is only partly realised (by the factor
    ``|cos(tilt)| / cos_min``). The Gimbal's rate limit clips further. The third
    component ``omega_cz`` cannot be commanded independently (2 joints, 3 rates).
    """
    if not 0.0 < cos_min <= 1.0:
        raise ValueError(f"cos_min must be in (0, 1], got {cos_min}")
    c = math.cos(tilt_rad)
    if abs(c) < cos_min:
        c = math.copysign(cos_min, c)
    return float(omega_cy) / c, float(omega_cx)


def pan_tilt_pointing_at(direction_frd) -> tuple[float, float]:
    """(pan, tilt) that put the optical axis along a body-frame (FRD) direction (any length).

    ``pan = atan2(dy, dx)`` in [-pi, pi], ``tilt = atan2(-dz, hypot(dx, dy))`` in [-pi/2, pi/2].
    Straight down/up (dx = dy = 0) gives pan = 0 and tilt = -+pi/2; the zero
    vector gives (0, 0). Joint limits are not applied here.
    """
    dx, dy, dz = float(direction_frd[0]), float(direction_frd[1]), float(direction_frd[2])
    return math.atan2(dy, dx), math.atan2(-dz, math.hypot(dx, dy))
