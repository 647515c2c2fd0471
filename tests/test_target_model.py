"""The flight software's ship-class outline (controllers.target_model) against the harness's ray-cast camera,
and the detection gates that keep cut-short boxes out of the UKF."""
import math

import numpy as np
import pytest

from controllers.camera_model import PinholeCamera
from controllers.target_model import ShipModelConfig, ShipOutline, box_centre_offset_px, predicted_box_px
from controllers.ukf import UkfConfig, UnscentedCore
from fwsim.camera import Camera, CameraConfig, Pose
from fwsim.frames import dcm_enu_from_frd
from fwsim.geometry import uav_mesh
from fwsim.gimbal import camera_pose_world, pan_tilt_pointing_at
from fwsim.target import Ship, TargetConfig

CAM_CFG = CameraConfig(hfov_deg=60.0)
FAR_UAV = Pose(np.eye(3), np.array([1e5, 1e5, 1e5]))  # the UAV out of every ray's way


def views(ship_heading_deg: float):
    """Camera poses around the ship: elevations 20-75 deg, azimuths all round, ranges 150-1200 m."""
    ship = Ship(TargetConfig(heading_deg=ship_heading_deg))
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    pos_ship, R_ship = ship.pose(0.0)
    mount = np.array(CAM_CFG.gimbal.mount_offset_frd_m)
    for rng in (150.0, 400.0, 1200.0):
        for el in (20.0, 45.0, 75.0):
            for az in range(0, 360, 45):
                e, a = math.radians(el), math.radians(az)
                look = np.array([0.0, 0.0, 6.0])
                d = np.array([math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e)])
                pos = look + rng * d
                euler = np.array([0.0, 0.0, math.atan2(-d[0], -d[1])])
                R = dcm_enu_from_frd(euler)
                pan, tilt = pan_tilt_pointing_at(R.T @ (look - (pos + R @ mount)))
                cp, Rc = camera_pose_world(pos, euler, mount, pan, tilt)
                frame = cam.detect(0.0, cp, Rc, FAR_UAV, Pose(R_ship, pos_ship))
                if frame.visible_px:
                    yield cp, Rc, frame


@pytest.mark.parametrize("ship_heading_deg", [0.0, 130.0])
def test_outline_box_matches_the_ray_cast_box(ship_heading_deg):
    """The flight software's outline predicts the detector's (noise-free) box from every view to within
    the ray cast's pixel stride (its box edges are quantised to it). The one known exception: the mast
    (0.75 m thick) falls between sampled rays at some strides and then does not set the box's top."""
    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    outline = ShipOutline(ShipModelConfig())
    course = math.radians(90.0 - ship_heading_deg)
    errs = []  # in units of the stride
    for cp, Rc, frame in views(ship_heading_deg):
        box = predicted_box_px(outline, fsw_cam, cp, Rc, np.zeros(3), course)
        assert box is not None
        errs.append(float(np.max(np.abs(box - frame.bbox_px))) / (frame.stride_px + 1.0))
    errs = np.array(errs)
    assert errs.size > 50
    assert np.mean(errs < 1.5) >= 0.9, np.sort(errs)[-10:]
    assert np.max(errs) < 4.0


def _centre_error_px(use_model: bool) -> tuple[float, float]:
    """Largest distance (px, and in ray-cast strides) between the (corrected) box centre and the image of
    the tracked point (midships, half the hull height), over all views."""
    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    outline = ShipOutline(ShipModelConfig())
    h = 3.75
    worst_px, worst_strides = 0.0, 0.0
    for cp, Rc, frame in views(0.0):
        uv = np.array(frame.centre_px, dtype=float)
        if use_model:
            uv = uv - box_centre_offset_px(outline, fsw_cam, cp, Rc, np.zeros(3), math.radians(90.0), h)
        p = Rc.T @ (np.array([0.0, 0.0, h]) - cp)
        aim = np.array([fsw_cam.fx * p[0] / p[2] + fsw_cam.cx, fsw_cam.fy * p[1] / p[2] + fsw_cam.cy])
        err = float(np.linalg.norm(uv - aim))
        worst_px = max(worst_px, err)
        worst_strides = max(worst_strides, err / (frame.stride_px + 1.0))
    return worst_px, worst_strides


def test_box_centre_correction_removes_the_shape_bias():
    """Without the correction the box centre is tens of pixels off the aim point's image (superstructure
    aft, perspective close in); with it (estimate at the truth) it is within the ray-cast quantisation."""
    raw_px, _ = _centre_error_px(False)
    corrected_px, corrected_strides = _centre_error_px(True)
    assert raw_px > 30.0
    assert corrected_strides < 1.5, (corrected_px, corrected_strides)


def test_unknown_course_averages_over_headings():
    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    outline = ShipOutline(ShipModelConfig())
    cp = np.array([-400.0, -300.0, 500.0])
    R = dcm_enu_from_frd(np.array([0.0, 0.0, 0.0]))
    pan, tilt = pan_tilt_pointing_at(R.T @ (np.zeros(3) - cp))
    cp, Rc = camera_pose_world(cp, np.zeros(3), np.zeros(3), pan, tilt)
    per = [box_centre_offset_px(outline, fsw_cam, cp, Rc, np.zeros(3), 2 * math.pi * k / 8, 3.75) for k in range(8)]
    avg = box_centre_offset_px(outline, fsw_cam, cp, Rc, np.zeros(3), None, 3.75, 8)
    np.testing.assert_allclose(avg, np.mean(per, axis=0))
    # behind the camera: no correction
    assert box_centre_offset_px(outline, fsw_cam, cp, Rc, cp - 50 * Rc[:, 2], None, 3.75) is None


def test_innovation_gate_rejects_an_outlier_and_keeps_the_state():
    core = UnscentedCore(2, 2, 1.0, 2.0, 0.0)
    core.set_state(np.zeros(2), np.eye(2))
    R = np.eye(2) * 0.01
    hx = lambda x: x  # noqa: E731
    assert core.update(np.array([10.0, 0.0]), hx, R, gate=(13.8, [0, 1])) is None
    np.testing.assert_array_equal(core.x, np.zeros(2))
    y = core.update(np.array([1.0, 0.0]), hx, R, gate=(13.8, [0, 1]))
    assert y is not None and core.x[0] > 0.9
    # without a gate the update equals the linear Kalman update
    core.set_state(np.zeros(2), np.eye(2))
    core.update(np.array([10.0, 0.0]), hx, R)
    np.testing.assert_allclose(core.x, [10.0 / 1.01, 0.0], rtol=1e-9)


def test_ukf_gate_config_defaults_are_on():
    c = UkfConfig()
    assert c.innovation_gate > 0 and c.innovation_gate_max_rejects >= 1


def test_entry_depth_to_deck_side_superstructure_and_clear_air():
    """How far before the aim point (midships, 3.75 m up) a straight dive meets the outline: the deck from
    above, the side from abeam, the deckhouse when coming in low from astern; 0 from a point in clear air."""
    o = ShipOutline(ShipModelConfig())
    aim = np.array([0.0, 0.0, 3.75])
    assert o.entry_depth_m(aim, [0.0, 0.0, -1.0]) == pytest.approx(7.5 - 3.75)  # vertical: the deck (0.3 H)
    assert o.entry_depth_m(aim, [0.0, -1.0, 0.0]) == pytest.approx(12.5)  # level from port: the side
    th = math.radians(-20.0)
    from_astern = np.array([math.cos(th), 0.0, math.sin(th)])  # bow-wards and down
    depth = o.entry_depth_m(aim, from_astern)
    hit = aim - depth * from_astern
    assert -0.32 * 55.0 <= hit[0] <= -0.04 * 55.0 and hit[2] > 7.5  # on the deckhouse, aft of midships
    assert o.entry_depth_m([0.0, 0.0, 30.0], [0.0, 0.0, -1.0]) == 0.0
