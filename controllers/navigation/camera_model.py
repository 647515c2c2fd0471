"""Pinhole camera and image-feature kinematics for the flight software (UKF, IBVS).

A small, dependency-free module (numpy only) shared by ``controllers.estimation.ukf`` and
the IBVS controller. The harness has its own camera (``fwsim.sensors.camera``), which
flight software must not import; this one holds only what a mission computer
knows: the intrinsics and the geometry.

Conventions (docs/design/architecture.md, "Frames and conventions"):
  * camera frame C: z along the optical axis, x right, y down;
  * pinhole (OpenCV): ``u = fx X/Z + cx``, ``v = fy Y/Z + cy``;
  * normalised features ``x1 = X/Z``, ``x2 = Y/Z`` where ``P = [X, Y, Z]`` is
    the target relative to the camera, in the camera frame;
  * world ENU, metres, z up; the sea is the plane z = 0.

API:
  * :class:`PinholeCamera` -- intrinsics; ``normalised(u, v)``, ``pixel(x1, x2)``;
  * :func:`feature_rates` -- ``[x1_dot, x2_dot]`` of a moving point seen by a
    moving, rotating camera;
  * :func:`interaction_matrix` -- the same as a (2, 6) matrix ``[Lv | Lw]``;
  * :func:`depth_on_plane` -- depth Z of the point on a horizontal plane seen
    along the ray through (x1, x2) (the paper's flat-sea depth model).

All functions broadcast: scalars, or arrays with a leading batch dimension
(``x1`` of shape (n,), vectors of shape (n, 3) or (3,)).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fwsim.interface.frames import R_frd_from_cam, camera_angular_velocity, camera_pose_world, cross3, dcm_enu_from_frd
from fwsim.interface.messages import Measurements

__all__ = ["PinholeCamera", "CameraMotion", "camera_motion", "feature_rates", "rotation_matrix",
           "translation_rates", "interaction_matrix", "depth_on_plane", "closing_time_s", "held_while_closing"]

#: rays whose downward component (-d_z / |d|) is below this are treated as not meeting the sea
MIN_RAY_DOWN = 1e-6


@dataclass(frozen=True, slots=True)
class PinholeCamera:
    """Pinhole intrinsics in pixels (OpenCV: u right, v down, principal point (cx, cy))."""

    fx: float
    fy: float
    cx: float
    cy: float
    width_px: int = 0  # 0: unknown (only needed for field-of-view checks)
    height_px: int = 0

    @classmethod
    def from_fov(cls, width_px: int, height_px: int, hfov_deg: float) -> "PinholeCamera":
        """Square pixels, principal point at the image centre (same as ``fwsim.sensors.camera.Intrinsics.from_fov``)."""
        f = (width_px / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(f, f, width_px / 2.0, height_px / 2.0, int(width_px), int(height_px))

    @classmethod
    def from_config(cls, camera_cfg) -> "PinholeCamera":
        """From a scenario's ``camera`` section (anything with ``width_px``, ``height_px``, ``hfov_deg``)."""
        return cls.from_fov(camera_cfg.width_px, camera_cfg.height_px, camera_cfg.hfov_deg)

    def normalised(self, u_px, v_px):
        """(x1, x2) = ((u - cx) / fx, (v - cy) / fy) (paper eq. 10)."""
        return (np.asarray(u_px, dtype=float) - self.cx) / self.fx, (np.asarray(v_px, dtype=float) - self.cy) / self.fy

    def pixel(self, x1, x2):
        """(u, v) = (fx x1 + cx, fy x2 + cy)."""
        return self.fx * np.asarray(x1, dtype=float) + self.cx, self.fy * np.asarray(x2, dtype=float) + self.cy


def rotation_matrix(x1, x2) -> np.ndarray:
    """L1 (2, 3), the rotational part of the feature kinematics: ``[x1_dot, x2_dot] = L1 w_cam + T``
    (:func:`feature_rates`); ``(..., 2, 3)`` for arrays."""
    if isinstance(x1, (float, np.floating)) and isinstance(x2, (float, np.floating)):  # one feature: quickly
        a = _rotation_entries(float(x1), float(x2))
        return np.array([a[:3], a[3:]])
    a = _rotation_entries(np.asarray(x1, dtype=float), np.asarray(x2, dtype=float))
    return np.stack([np.stack(a[:3], axis=-1), np.stack(a[3:], axis=-1)], axis=-2)


def _rotation_entries(x1, x2):
    """The six entries of L1, row by row (the one place they are written)."""
    x12 = x1 * x2
    return x12, -(1.0 + x1 * x1), x2, 1.0 + x2 * x2, -x12, -x1


def translation_rates(x1, x2, Z, v_cam) -> np.ndarray:
    """T = ``[(v_x - x1 v_z)/Z, (v_y - x2 v_z)/Z]``, the feature rates the target's velocity relative to the
    camera causes (``v_cam``: camera frame; ``Z``: depth along the optical axis). (2,) or (n, 2)."""
    if isinstance(x1, (float, np.floating)) and isinstance(x2, (float, np.floating)) and np.ndim(v_cam) == 1:
        v = v_cam
        return np.array(_translation(float(x1), float(x2), float(Z), (float(v[0]), float(v[1]), float(v[2]))))
    x1 = np.asarray(x1, dtype=float)
    x2 = np.asarray(x2, dtype=float)
    v = np.asarray(v_cam, dtype=float)
    return np.stack(np.broadcast_arrays(*_translation(x1, x2, Z, v)), axis=-1)


def _translation(x1, x2, Z, v):
    """The two entries of T (the one place they are written); ``v`` an array (..., 3) or a 3-tuple."""
    vx, vy, vz = (v[0], v[1], v[2]) if isinstance(v, tuple) else (v[..., 0], v[..., 1], v[..., 2])
    return (vx - x1 * vz) / Z, (vy - x2 * vz) / Z


def feature_rates(x1, x2, Z, v_cam, w_cam) -> np.ndarray:
    """Time derivative ``[x1_dot, x2_dot]`` of the normalised image features.

    Derived from the pinhole model: ``P = [X, Y, Z]`` is the target relative to
    the camera in the camera frame, ``x1 = X/Z``, ``x2 = Y/Z``, and
    ``P_dot = v - w x P``, with

      * ``v_cam`` = the target's velocity relative to the camera, in the camera
        frame: ``R_cam_from_enu (V_q - V_c)``, where ``V_c = V_p + omega_p x r_c/p``
        is the camera's velocity in the world (UAV velocity plus the lever arm);
      * ``w_cam`` = the camera's total angular velocity relative to the world
        (airframe + pan-tilt joints), in the camera frame.

    Result::

        x1_dot = (v_x - x1 v_z)/Z + x1 x2 w_x - (1 + x1^2) w_y + x2 w_z
        x2_dot = (v_y - x2 v_z)/Z + (1 + x2^2) w_x - x1 x2 w_y - x1 w_z

    i.e. ``[x1_dot, x2_dot] = T + L1 w`` with ``T`` = :func:`translation_rates` (``Lv v`` with
    ``Lv = [[1, 0, -x1], [0, 1, -x2]] / Z``) and ``L1`` = :func:`rotation_matrix`
    ``[[x1 x2, -(1 + x1^2), x2], [1 + x2^2, -x1 x2, -x1]]`` (the paper's L1). These three functions are
    the flight software's only statement of the kinematics: the UKF's process model and IBVS use them.

    This replaces the paper's eq. (6) and (8), which have typos:
      * eta_1 = (v_px x1 - v_px) x3 uses v_px twice; it must be
        (v_pz x1 - v_px) x3 (the camera's own velocity enters with a minus
        sign, v = V_q - V_c), and eta_2 = (v_px x2 - v_py) x3 likewise must be
        (v_pz x2 - v_py) x3;
      * zeta_1 ends in omega_cx x2 and zeta_2 in omega_cx x1 (zeta_2 repeats
        omega_cx); they must be omega_cz x2 and -omega_cz x1, and Omega_2
        starts with omega_pz where omega_px belongs (compare with L1 above);
      * the Omega terms with the mount offset m = r_c/p are the lever-arm
        velocity omega_p x r_c/p of V_c = V_p + omega_p x r_c/p written out in
        camera coordinates, plus the airframe's share of the rotation. Here
        V_c carries the lever arm and w_cam is the camera's total angular
        velocity (joints + airframe), so no m appears.
    The formula is checked against finite differences of the projection of a
    moving point seen by a moving, rotating camera in ``tests/test_ukf.py``.

    Shapes: ``x1, x2, Z`` scalars or (n,); ``v_cam, w_cam`` (3,) or (n, 3).
    Returns (2,) or (n, 2).
    """
    x1 = np.asarray(x1, dtype=float)
    x2 = np.asarray(x2, dtype=float)
    w = np.asarray(w_cam, dtype=float)
    t1, t2 = _translation(x1, x2, np.asarray(Z, dtype=float), np.asarray(v_cam, dtype=float))
    a00, a01, a02, a10, a11, a12 = _rotation_entries(x1, x2)
    wx, wy, wz = w[..., 0], w[..., 1], w[..., 2]
    x1d = t1 + a00 * wx + a01 * wy + a02 * wz
    x2d = t2 + a10 * wx + a11 * wy + a12 * wz
    return np.stack(np.broadcast_arrays(x1d, x2d), axis=-1)


def interaction_matrix(x1: float, x2: float, Z: float) -> np.ndarray:
    """(2, 6) matrix ``[Lv | L1]`` with ``[x1_dot, x2_dot] = Lv v + L1 w`` (see :func:`feature_rates`):
    ``Lv`` is :func:`translation_rates` of the unit velocities, ``L1`` :func:`rotation_matrix`.

    Sign convention: ``v`` is the TARGET's velocity relative to the camera
    (``R_cam_from_enu (V_q - V_c)``), so ``Lv`` is minus the classical IBVS
    ``Lv`` written for the camera's own velocity; ``L1`` (columns for the
    camera's angular velocity w_x, w_y, w_z) is the classical one (paper's L1).
    """
    Lv = translation_rates(float(x1), float(x2), float(Z), np.eye(3)).T
    return np.hstack([Lv, rotation_matrix(float(x1), float(x2))])


def depth_on_plane(x1, x2, R_enu_from_cam, cam_z_m, plane_z_m: float = 0.0):
    """Depth Z (camera-frame z of the point) where the ray through (x1, x2) meets the plane z = plane_z_m.

    The ray in the world is ``d_w = R_enu_from_cam [x1, x2, 1]``; from the
    camera at height ``cam_z_m`` it meets the plane at
    ``Z = (cam_z_m - plane_z_m) / (-d_w,z)`` (the point is ``r_c + Z d_w``).
    On the optical axis (x1 = x2 = 0) this is the paper's ``d = h / cos(alpha)``
    with ``alpha = acos(-e3 . c3)``. The paper's depth model puts the target on
    the sea (plane_z_m = 0); a detector that reports the box centre sees a
    point above the waterline, which a positive plane_z_m models.

    NaN where the ray does not point down (``-d_w,z / |d_w| < MIN_RAY_DOWN``) or
    the camera is not above the plane. Shapes: x1, x2 scalars or (n,).
    """
    x1 = np.asarray(x1, dtype=float)
    x2 = np.asarray(x2, dtype=float)
    R = np.asarray(R_enu_from_cam, dtype=float)
    dz = R[2, 0] * x1 + R[2, 1] * x2 + R[2, 2]
    norm = np.sqrt(x1 * x1 + x2 * x2 + 1.0)
    h = float(cam_z_m) - float(plane_z_m)
    ok = (-dz / norm >= MIN_RAY_DOWN) & (h > 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        Z = np.where(ok, h / np.where(ok, -dz, 1.0), np.nan)
    return float(Z) if Z.ndim == 0 else Z


@dataclass(frozen=True, slots=True)
class CameraMotion:
    """The camera's pose and motion as the flight software knows it at ``t_s``."""

    t_s: float
    pos_enu_m: np.ndarray  # (3,) camera position r_c in the world
    vel_enu_m_s: np.ndarray  # (3,) camera velocity V_c = V_p + R_enu_from_frd (omega_p x r_c/p)
    R_enu_from_cam: np.ndarray  # (3, 3)
    omega_cam_rad_s: np.ndarray  # (3,) camera angular velocity relative to the world, camera frame
    height_m: float  # camera height above the sea (altimeter + lever arm), for the depth model
    att_var_rad2: float = math.nan  # the navigation's attitude variance, roll + pitch + yaw (NaN: not reported)

    @classmethod
    def from_measurements(cls, meas: Measurements, mount_offset_frd_m) -> "CameraMotion":
        """Build from one ``Measurements`` and the known mount offset r_c/p (body FRD, m).

        Pose from :func:`fwsim.interface.frames.camera_pose_world` (attitude + encoders);
        ``r_c`` is ``meas.cam_pos_enu_m`` when finite, else the pose's;
        ``omega`` from :func:`fwsim.interface.frames.camera_angular_velocity` (encoder
        rates, NaN taken as 0, plus gyros); height from the altimeter (the
        GNSS height of r_c if the altimeter is NaN). Raises ValueError without
        gimbal encoders.
        """
        pan, tilt = float(meas.pan_rad), float(meas.tilt_rad)
        if not (math.isfinite(pan) and math.isfinite(tilt)):
            raise ValueError("CameraMotion needs the gimbal encoders (pan_rad, tilt_rad are NaN)")
        m = np.asarray(mount_offset_frd_m, dtype=float)
        R_ef = dcm_enu_from_frd(meas.euler_ned_rad)
        R = R_ef @ R_frd_from_cam(pan, tilt)  # camera_pose_world's rotation, R_ef built once for both
        if np.isfinite(meas.cam_pos_enu_m).all():
            cam_pos = np.array(meas.cam_pos_enu_m, dtype=float)
        else:
            cam_pos = camera_pose_world(meas.pos_enu_m, meas.euler_ned_rad, m, pan, tilt)[0]
        vel = np.asarray(meas.vel_enu_m_s, dtype=float) + R_ef @ cross3(meas.body_rates_frd_rad_s, m)
        pan_rate = float(meas.pan_rate_rad_s) if math.isfinite(meas.pan_rate_rad_s) else 0.0
        tilt_rate = float(meas.tilt_rate_rad_s) if math.isfinite(meas.tilt_rate_rad_s) else 0.0
        omega = camera_angular_velocity(pan, tilt, pan_rate, tilt_rate, meas.body_rates_frd_rad_s)
        h = float(meas.height_above_sea_m)
        height = h + float(R_ef[2] @ m) if math.isfinite(h) else float(cam_pos[2])
        s = meas.att_std_rad
        att_var = float(s[0] * s[0] + s[1] * s[1] + s[2] * s[2])  # (NaN when not reported)
        return cls(float(meas.t_s), cam_pos, vel, R, omega, height, att_var)


def camera_motion(meas: Measurements, mount_offset_frd_m) -> CameraMotion | None:
    """:meth:`CameraMotion.from_measurements`, or None without gimbal encoders (pan or tilt NaN)."""
    return CameraMotion.from_measurements(meas, mount_offset_frd_m) if math.isfinite(meas.pan_rad) else None


def closing_time_s(point_enu_m, point_vel_enu_m_s, cam_pos_enu_m, cam_vel_enu_m_s) -> float:
    """The range from the camera to a moving point over the speed at which it closes (inf when it does not):
    the time to go of a dive on the point."""
    rel = point_enu_m - cam_pos_enu_m
    rng = math.sqrt(float(rel @ rel))
    closing = -float(rel @ (point_vel_enu_m_s - cam_vel_enu_m_s)) / max(rng, 1e-9)
    return rng / closing if closing > 0.0 else math.inf


def held_while_closing(held: bool, tgo_s: float, hold_tgo_s: float) -> bool:
    """A hold of what an estimator learnt, by the camera's time to go (:func:`closing_time_s`): taken once it is
    under ``hold_tgo_s`` (a dive), kept until it exceeds twice that (or the camera recedes)."""
    if not held:
        return tgo_s < hold_tgo_s
    return not tgo_s > 2.0 * hold_tgo_s


def ground_from_pixel_jacobian(x1: float, x2: float, R_enu_from_cam, cam_z_m: float, plane_z_m: float,
                               fx: float, fy: float) -> np.ndarray:
    """d(point on the plane)/d(u, v) (3 x 2, m per px) of the ray through the normalised pixel (x1, x2): the
    point is ``r_c + Z d`` with ``d = R [x1, x2, 1]`` and ``Z = (cam_z - plane_z) / -d_z``, so
    ``dG/dx_i = h (R[:, i] / -d_z + d R[2, i] / d_z^2)`` (h the camera's height above the plane); NaN where
    the ray does not come down to the plane. Tested against finite differences."""
    R = np.asarray(R_enu_from_cam, dtype=float)
    d = R @ np.array([x1, x2, 1.0])
    h = cam_z_m - plane_z_m
    if not (d[2] < -1e-9 and h > 0.0):
        return np.full((3, 2), np.nan)
    return np.array(ground_jacobian_rows(R.tolist(), d.tolist(), h, fx, fy, 3))


def ground_jacobian_rows(R: list, d: list, h: float, fx: float, fy: float, rows: int) -> list[list[float]]:
    """The first ``rows`` rows of :func:`ground_from_pixel_jacobian` (``R`` and the ray ``d`` as nested lists,
    the ray coming down, ``h > 0``): ``h (R[j, i] / -d_z + d_j R[2, i] / d_z^2) / f_i``, element by element
    (Python floats: a 2 x 2 block costs less than one numpy call on it)."""
    nd, dd = -d[2], d[2] * d[2]
    r2x, r2y = R[2][0], R[2][1]
    return [[h * (R[j][0] / nd + d[j] * r2x / dd) / fx, h * (R[j][1] / nd + d[j] * r2y / dd) / fy]
            for j in range(rows)]
