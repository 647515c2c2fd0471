"""The ray-cast camera: projection, self-occlusion from geometry, ROI vs full frame, detector noise."""
import math

import cv2
import numpy as np
import pytest
from flight import Flight

from fwsim.sensors.camera import Camera, CameraConfig, Detector, DetectorConfig, FrameGeometry, Pose
from fwsim.interface.frames import dcm_enu_from_frd
from fwsim.world.geometry import uav_mesh
from fwsim.world.gimbal import camera_pose_world, pan_tilt_pointing_at
from fwsim.interface.messages import RateCommand
from fwsim.world.target import Ship, TargetConfig

MOUNT = np.array([0.0, 0.0, 0.10])
SHIP = Ship(TargetConfig())
SHIP_POSE = Pose(*reversed(SHIP.pose(0.0)))  # Pose(R, t)
AIM = np.array([0.0, 0.0, 8.0])  # a point on the hull


@pytest.fixture(scope="module")
def cam():
    return Camera(CameraConfig(), uav_mesh("fwuav"), SHIP.mesh)


def pointed_camera(pos, euler):
    """Camera pose with the gimbal pointed exactly at the ship (a test oracle)."""
    R = dcm_enu_from_frd(euler)
    rel_b = R.T @ (AIM - (pos + R @ MOUNT))
    pan, tilt = pan_tilt_pointing_at(rel_b)
    cam_pos, R_cam = camera_pose_world(pos, euler, MOUNT, pan, tilt)
    return cam_pos, R_cam, Pose(R, np.asarray(pos, float)), tilt


def frame_at_bank(cam, bank_deg, **kw):
    # UAV 700 m west of the ship at 500 m heading south: the ship is on its left
    pos = np.array([-700.0, 0.0, 500.0])
    euler = np.array([math.radians(bank_deg), 0.03, math.pi])
    cam_pos, R_cam, uav, tilt = pointed_camera(pos, euler)
    det = (cam.detect_full_frame if kw.get("full") else cam.detect)(0.0, cam_pos, R_cam, uav, SHIP_POSE)
    return det, tilt


def test_projection_matches_opencv(cam):
    pts = np.random.default_rng(1).uniform([-80, -40, 50], [80, 40, 2000], (200, 3))
    ours = cam.K.project(pts)
    ref, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), cam.K.K, None)
    np.testing.assert_allclose(ours, ref[:, 0, :], atol=1e-9)
    # the paper's principal point for 1280 x 720
    assert (cam.K.cx, cam.K.cy) == (640.0, 360.0)


def test_rays_and_projection_are_inverse(cam):
    u = np.array([0.0, 640.0, 1279.0, 13.5])
    v = np.array([0.0, 360.0, 719.0, 700.25])
    np.testing.assert_allclose(cam.K.project(cam.K.rays(u, v)), np.stack([u, v], 1), atol=1e-9)


def test_level_wings_see_the_whole_ship(cam):
    det, tilt = frame_at_bank(cam, 0.0)
    assert det.in_fov and det.occluded_fraction == 0.0 and det.visible_px > 500
    # pointed at the ship: the box is around the image centre
    assert abs(det.centre_px[0] - 640) < 40 and abs(det.centre_px[1] - 360) < 40


def test_bank_toward_the_ship_hides_it_behind_the_wing(cam):
    """Banking left (toward the ship) lifts it above the wing plane: fully occluded, still in view."""
    det, tilt = frame_at_bank(cam, -50.0)
    assert tilt > 0  # the camera now looks above the mount plane
    assert det.in_fov and det.ship_px > 500
    assert det.visible_px == 0 and det.occluded_fraction == 1.0
    assert np.all(np.isnan(det.bbox_px))


def test_partial_occlusion_shrinks_and_shifts_the_box(cam):
    full, _ = frame_at_bank(cam, 0.0)
    partial = [frame_at_bank(cam, b)[0] for b in np.arange(-40.0, -45.0, -0.5)]
    partial = [d for d in partial if 0.05 < d.occluded_fraction < 0.95]
    assert partial, "no bank angle gave a partly hidden ship"
    for d in partial:
        assert d.visible_px < full.visible_px
        height = d.bbox_px[3] - d.bbox_px[1]
        assert height < full.bbox_px[3] - full.bbox_px[1]
        # the wing edge cuts the box from one side: the box stays within the unoccluded one (+ stride)
        assert np.all(d.bbox_px[:2] >= full.bbox_px[:2] - 2) and np.all(d.bbox_px[2:] <= full.bbox_px[2:] + 2)
    fr = [d.occluded_fraction for d in partial]
    assert fr == sorted(fr)  # steeper bank, more hidden


@pytest.mark.parametrize("bank_deg", [0.0, -42.0, -50.0, 20.0])
def test_roi_detection_equals_full_frame(bank_deg):
    cam1 = Camera(CameraConfig(max_roi_rays=4_000_000), uav_mesh("fwuav"), SHIP.mesh)  # stride 1
    roi, _ = frame_at_bank(cam1, bank_deg)
    full, _ = frame_at_bank(cam1, bank_deg, full=True)
    assert roi.stride_px == 1
    assert roi.visible_px == full.visible_px and roi.ship_px == full.ship_px
    np.testing.assert_array_equal(roi.bbox_px, full.bbox_px)
    assert roi.rays_cast < full.rays_cast / 50


def test_out_of_view_is_not_in_fov(cam):
    pos = np.array([-700.0, 0.0, 500.0])
    euler = np.array([0.0, 0.0, math.pi])
    cam_pos, R_cam = camera_pose_world(pos, euler, MOUNT, 0.0, -0.3)  # looking south, ship to the east
    det = cam.detect(0.0, cam_pos, R_cam, Pose(dcm_enu_from_frd(euler), pos), SHIP_POSE)
    assert not det.in_fov and det.visible_px == 0 and det.rays_cast == 0


def test_strided_roi_stays_within_budget_close_up(cam):
    """A ship filling the view: at most max_roi_rays rays, box still found."""
    pos = np.array([-90.0, 0.0, 60.0])
    euler = np.array([0.0, -0.3, math.pi / 2])
    cam_pos, R_cam, uav, _ = pointed_camera(pos, euler)
    det = cam.detect(0.0, cam_pos, R_cam, uav, SHIP_POSE)
    assert det.rays_cast <= cam.cfg.max_roi_rays and det.stride_px > 1
    assert det.visible_px > 50_000


def _frames(seed):
    det = Detector(DetectorConfig(miss_probability=0.2, latency_s=0.1), np.random.default_rng(seed), 1280, 720)
    out = []
    for k in range(60):
        t = k / 30
        det.observe(FrameGeometry(t, True, 900.0, 900.0, 0.0, np.array([600.0, 340, 680, 380]),
                                  np.array([640.0, 360]), 1, 900))
        a = det.arrived(t)
        out.append(None if a is None else (a.detected, a.u_px, a.v_px))
    return out


def test_detector_same_seed_same_detections():
    assert _frames(3) == _frames(3)
    assert _frames(3) != _frames(4)


def test_detector_latency_and_misses():
    out = _frames(5)
    assert out[:3] == [None, None, None]  # 0.1 s latency at 30 Hz: first arrival on the 4th frame
    got = [o for o in out if o is not None]
    misses = sum(1 for o in got if not o[0])
    assert 3 <= misses <= 25  # 20 % of ~57
    hits = np.array([(o[1], o[2]) for o in got if o[0]])
    assert np.all(np.abs(hits - [640, 360]) < 10) and hits.std(axis=0).min() > 0.5


def test_scripted_bank_in_jsbsim_hides_then_shows_the_ship(cam):
    """Closed loop in JSBSim: level, a fast roll to about -60 deg, hold, roll back, level.
    The ship sits 700 m abeam on the left at the middle of the steep bank (where a
    loiter keeps its target). With the camera kept on the ship, the detection
    vanishes while the bank lifts the ship above the wing plane (occluded, still in
    the field of view) and returns when the wings level."""
    f = Flight(24.0, 500.0, heading_deg=180.0)
    states = []
    for seconds, rate_deg_s in ((2.0, 0.0), (1.5, -40.0), (1.0, 0.0), (1.5, 40.0), (2.0, 0.0)):
        states += f.fly(seconds, lambda s, r=math.radians(rate_deg_s): RateCommand(s.t_s, 24.0, r, 0.0)).states
    states = states[::4]  # camera frames at 30 Hz
    banks = np.degrees([s.euler_ned_rad[0] for s in states])
    steep = np.flatnonzero(banks < -55.0)
    assert steep.size > 10
    mid = states[steep[steep.size // 2]]
    v = mid.vel_enu_m_s[:2] / np.linalg.norm(mid.vel_enu_m_s[:2])
    ship = Pose(np.eye(3), np.array([*(mid.pos_enu_m[:2] + 700.0 * np.array([-v[1], v[0]])), 0.0]))

    def look(s):
        R = dcm_enu_from_frd(s.euler_ned_rad)
        rel_b = R.T @ (ship.t + AIM - (s.pos_enu_m + R @ MOUNT))
        pan, tilt = pan_tilt_pointing_at(rel_b)
        cp, Rc = camera_pose_world(s.pos_enu_m, s.euler_ned_rad, MOUNT, pan, tilt)
        return cam.detect(s.t_s, cp, Rc, Pose(R, s.pos_enu_m), ship)

    t_mid = mid.t_s
    hidden = [look(s) for s in states if abs(s.t_s - t_mid) < 0.08]
    assert len(hidden) >= 4
    level_before = [look(s) for s in states[:30]]
    level_after = [look(s) for s in states[-15:]]
    assert all(abs(b) < 3.0 for b in banks[:30]) and all(abs(b) < 5.0 for b in banks[-15:])
    assert all(d.in_fov and d.ship_px > 300 and d.visible_px == 0 for d in hidden)
    assert all(d.visible_px > 300 and d.occluded_fraction == 0.0 for d in level_before + level_after)


def test_ray_table_is_the_rays_of_every_pixel():
    """The camera's table of pixel rays (built from column and row terms) is ``Intrinsics.rays`` of each
    pixel, bit for bit: the ROI's rays come from it, so a detection is the same either way."""
    from fwsim.sensors.camera import Camera, Intrinsics
    K = Intrinsics.from_fov(160, 90, 60.0)
    uu, vv = np.meshgrid(np.arange(K.width_px, dtype=float), np.arange(K.height_px, dtype=float))
    direct = K.rays(uu.ravel(), vv.ravel()).reshape(K.height_px, K.width_px, 3)
    assert np.array_equal(Camera._table(K), direct)


def test_tight_roi_holds_every_ship_pixel_when_the_ship_straddles_the_camera_plane():
    """Close to the ship, with its bounding box partly behind the camera, the tight box (the part in front,
    clipped at the camera plane) holds every pixel the full frame sees the ship in, and is None only when
    the full frame sees none: so rendering or detecting within it loses nothing."""
    cam = Camera(CameraConfig(width_px=320, height_px=180), uav_mesh("fwuav"), SHIP.mesh)
    rng = np.random.default_rng(3)
    straddling = {"in view": 0, "out of view": 0}
    for _ in range(200):
        pos = rng.uniform([-40.0, -25.0, 2.0], [40.0, 25.0, 40.0])
        euler = rng.uniform([-0.5, -0.8, -math.pi], [0.5, 0.8, math.pi])
        R = dcm_enu_from_frd(euler)
        cam_pos, R_cam = camera_pose_world(pos, euler, MOUNT, rng.uniform(-math.pi, math.pi), rng.uniform(-1.2, 0.2))
        uav = Pose(R, pos)
        box, tight = cam.rois(cam_pos, R_cam, SHIP_POSE)
        if box is None or box == tight:
            continue  # not straddling
        assert box == (0, 0, 319, 179)
        full = cam.detect_full_frame(0.0, cam_pos, R_cam, uav, SHIP_POSE)
        if full.visible_px == 0:
            straddling["out of view"] += tight is None
            continue
        straddling["in view"] += 1
        assert tight is not None
        u0, v0, u1, v1 = full.bbox_px
        assert tight[0] <= u0 and tight[1] <= v0 and u1 <= tight[2] and v1 <= tight[3]
    assert straddling["in view"] >= 5 and straddling["out of view"] >= 5, straddling
