"""The flight software's ship-class outline (controllers.perception.target_model) against the harness's ray-cast camera,
and the detection gates that keep cut-short boxes out of the UKF."""
import dataclasses
import math

import numpy as np
import pytest

from controllers.config import AcquisitionConfig, DetectionGateConfig, SizeFitConfig
from controllers.messages import FusionReason, TargetState
from controllers.navigation.camera_model import PinholeCamera
from controllers.perception.perception import Perception
from controllers.config import ShapeHeadingConfig, ShipModelConfig
from controllers.perception.shape_heading import ShapeHeading
from controllers.perception.ship_outline import ShipOutline, box_centre_offset_px, predicted_box_px, predicted_boxes_px
from controllers.perception.target_model import ShipModel
from controllers.estimation.ukf import UkfConfig, UnscentedCore
from fwsim.sensors.camera import Camera, CameraConfig, Pose
from fwsim.interface.frames import dcm_enu_from_frd
from fwsim.world.geometry import uav_mesh
from fwsim.world.gimbal import camera_pose_world, pan_tilt_pointing_at
from fwsim.interface.messages import Measurements
from fwsim.world.target import Ship, TargetConfig

CAM_CFG = CameraConfig(hfov_deg=60.0)
FAR_UAV = Pose(np.eye(3), np.array([1e5, 1e5, 1e5]))  # the UAV out of every ray's way


def _look_from(cam, ship_pose, rng_m: float, elevation_deg: float, azimuth_deg: float):
    """The camera ``rng_m`` from a point 6 m above the ship's centre, at that elevation and azimuth, the UAV
    heading at the ship and the gimbal on it: (cam_pos, R_enu_cam, ray-cast frame)."""
    look = np.array([0.0, 0.0, 6.0])
    mount = np.array(CAM_CFG.gimbal.mount_offset_frd_m)
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    d = np.array([math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e)])
    pos = look + rng_m * d
    euler = np.array([0.0, 0.0, math.atan2(-d[0], -d[1])])
    R = dcm_enu_from_frd(euler)
    pan, tilt = pan_tilt_pointing_at(R.T @ (look - (pos + R @ mount)))
    cp, Rc = camera_pose_world(pos, euler, mount, pan, tilt)
    return cp, Rc, cam.detect(0.0, cp, Rc, FAR_UAV, ship_pose)


def views(ship_heading_deg: float):
    """Camera poses around the ship: elevations 20-75 deg, azimuths all round, ranges 150-1200 m."""
    ship = Ship(TargetConfig(heading_deg=ship_heading_deg))
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    pos_ship, R_ship = ship.pose(0.0)
    for rng in (150.0, 400.0, 1200.0):
        for el in (20.0, 45.0, 75.0):
            for az in range(0, 360, 45):
                cp, Rc, frame = _look_from(cam, Pose(R_ship, pos_ship), rng, el, az)
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
    # its spread over those headings: their covariance (weighted: the weights' covariance), zero for one course
    avg2, cov = box_centre_offset_px(outline, fsw_cam, cp, Rc, np.zeros(3), None, 3.75, 8, spread=True)
    np.testing.assert_array_equal(avg2, avg)
    np.testing.assert_allclose(cov, np.cov(np.array(per).T, bias=True), atol=1e-9)
    assert np.trace(cov) > 1.0  # a few px: the heading matters from here
    courses = np.array([0.0, math.pi / 2, math.pi])
    w = np.array([0.5, 0.3, 0.2])
    per3 = np.array([box_centre_offset_px(outline, fsw_cam, cp, Rc, np.zeros(3), c, 3.75) for c in courses])
    avg3, cov3 = box_centre_offset_px(outline, fsw_cam, cp, Rc, np.zeros(3), None, 3.75,
                                      courses_weights=(courses, w), spread=True)
    np.testing.assert_allclose(avg3, w @ per3)
    np.testing.assert_allclose(cov3, np.cov(per3.T, aweights=w, bias=True), atol=1e-9)
    one, cov1 = box_centre_offset_px(outline, fsw_cam, cp, Rc, np.zeros(3), 0.3, 3.75, spread=True)
    assert np.array_equal(cov1, np.zeros((2, 2)))
    # behind the camera: no correction
    assert box_centre_offset_px(outline, fsw_cam, cp, Rc, cp - 50 * Rc[:, 2], None, 3.75) is None


def test_innovation_gate_rejects_an_outlier_and_keeps_the_state():
    core = UnscentedCore(2, 2, 1.0, 2.0, 0.0)
    core.set_state(np.zeros(2), np.eye(2))
    R = np.eye(2) * 0.01
    hx = lambda X: X  # noqa: E731  (a batch of sigma points)
    assert core.update(np.array([10.0, 0.0]), hx, R, gate=(13.8, [0, 1])) is None
    np.testing.assert_array_equal(core.x, np.zeros(2))
    y = core.update(np.array([1.0, 0.0]), hx, R, gate=(13.8, [0, 1]))
    assert y is not None and core.x[0] > 0.9
    # without a gate the update equals the linear Kalman update
    core.set_state(np.zeros(2), np.eye(2))
    core.update(np.array([10.0, 0.0]), hx, R)
    np.testing.assert_allclose(core.x, [10.0 / 1.01, 0.0], rtol=1e-9)


def test_the_gate_may_allow_for_the_box_centres_systematic_error():
    """``innovation_gate_box_bias``: a settled estimate, a large box (500 x 200 px) whose centre is 30 px off
    the prediction. Against noise alone the gate turns it away; allowing for the box centre's systematic
    error (4 % of the box's sides, 20 px across) it passes and is fused as before; 200 px off it is still
    turned away."""
    from controllers.estimation.ukf import CameraMotion, UkfTargetEstimator
    from controllers.messages import DetectionFix
    cam = PinholeCamera.from_config(CAM_CFG)
    cp = np.array([-400.0, 0.0, 300.0])
    p = np.array([0.0, 0.0, UkfConfig().target_plane_height_m]) - cp
    d = p / np.linalg.norm(p)
    x = np.cross(np.array([0.0, 0.0, 1.0]), d)
    x = x / np.linalg.norm(x)
    Rc = np.column_stack([x, np.cross(d, x), d])  # optical axis on the point
    box = np.array([cam.cx - 250, cam.cy - 100, cam.cx + 250, cam.cy + 100])
    used = {}
    for allow in (False, True):
        f = UkfTargetEstimator(cam, UkfConfig(innovation_gate_box_bias=allow))
        base = DetectionFix(0.0, True, 0.0, cam.cx, cam.cy, box, cam.cx, cam.cy, np.full(4, np.nan), True, "", "",
                            True, False, 0.0, 0.0)
        f.initialise(base, CameraMotion(0.0, cp, np.zeros(3), Rc, np.zeros(3), float(cp[2])))
        for k in range(1, 60):  # settle on the same view
            t = 0.1 * k
            assert f.update(dataclasses.replace(base, t_s=t),
                            CameraMotion(t, cp, np.zeros(3), Rc, np.zeros(3), float(cp[2]))).used
        motion = CameraMotion(6.0, cp, np.zeros(3), Rc, np.zeros(3), float(cp[2]))
        used[allow] = [f.update(dataclasses.replace(base, t_s=6.0 + 0.1 * i, u_px=cam.cx + off), motion).used
                       for i, off in enumerate((30.0, 200.0))]
    assert used[False] == [False, False]
    assert used[True] == [True, False]


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


def ring_views(ship_heading_deg: float, az_deg: range, elevation_deg: float = 45.0, rng_m: float = 707.0):
    """Ray-cast detections (noise-free boxes) from a loiter ring round a still ship: (cam_pos, R_enu_cam, box)."""
    ship = Ship(TargetConfig(heading_deg=ship_heading_deg))
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    pos_ship, R_ship = ship.pose(0.0)
    for az in az_deg:
        cp, Rc, frame = _look_from(cam, Pose(R_ship, pos_ship), rng_m, elevation_deg, az)
        yield cp, Rc, frame.bbox_px


def _shape_from(views_, cfg: ShapeHeadingConfig = ShapeHeadingConfig()) -> ShapeHeading:
    sh = ShapeHeading(cfg, ShipOutline(ShipModelConfig()), PinholeCamera.from_config(CAM_CFG))
    for k, (cp, Rc, box) in enumerate(views_):
        sh.update(float(k), cp, Rc, np.zeros(3), box)
    return sh


def _deg_off(a_deg: float, b_deg: float, period: float = 360.0) -> float:
    d = (a_deg - b_deg) % period
    return min(d, period - d)


def test_predicted_boxes_for_many_courses_match_the_single_course_function():
    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    outline = ShipOutline(ShipModelConfig())
    courses = np.radians([0.0, 33.0, 90.0, 211.0])
    n = 0
    for cp, Rc, _ in views(0.0):
        many = predicted_boxes_px(outline, fsw_cam, cp, Rc, np.zeros(3), courses)
        for c, row in zip(courses, many):
            one = predicted_box_px(outline, fsw_cam, cp, Rc, np.zeros(3), float(c))
            if one is None:
                assert np.all(np.isnan(row))
            else:
                np.testing.assert_allclose(row, one, atol=1e-9)
                n += 1
    assert n > 100
    behind = predicted_boxes_px(outline, fsw_cam, np.array([0.0, 0.0, 500.0]), np.eye(3), np.zeros(3), courses)
    assert np.all(np.isnan(behind))  # the camera looks up, away from the ship: no box


@pytest.mark.parametrize("ship_heading_deg", [0.0, 37.0, 130.0, 250.0, 300.0])
def test_ship_heading_from_box_shapes_over_a_loiter_ring(ship_heading_deg):
    """A lap of the loiter ring (ray-cast boxes of the harness's ship mesh, the flight software's coarse
    outline) tells a still ship's heading, bow and stern included, to within one 5-degree bin."""
    sh = _shape_from(ring_views(ship_heading_deg, range(0, 360, 5)))
    assert sh.ready and sh.updates == 72
    w = sh.weights()
    best = 90.0 - math.degrees(float(sh.courses_enu_rad[int(np.argmax(w))]))
    assert _deg_off(best, ship_heading_deg) <= 5.0, best
    assert _deg_off(90.0 - math.degrees(sh.axis_enu_rad()), ship_heading_deg, 180.0) <= 5.0
    k = int(np.argmax(w))
    assert w[(k + len(w) // 2) % len(w)] < 0.5 * w[k]  # the opposite heading is less likely
    courses, weights = sh.headings()
    assert np.isclose(np.sum(weights), 1.0) and len(courses) < 10


@pytest.mark.parametrize("ship_heading_deg", [0.0, 37.0, 250.0])
def test_a_short_arc_tells_the_axis(ship_heading_deg):
    """60 degrees of arc are enough for the ship's axis (bow and stern may stay ambiguous)."""
    sh = _shape_from(ring_views(ship_heading_deg, range(0, 60, 5)))
    assert _deg_off(90.0 - math.degrees(sh.axis_enu_rad()), ship_heading_deg, 180.0) <= 5.0


def _shrunk(views_, fraction: float):
    """The views with each box shrunk about its centre by ``fraction`` (a detector that trims boxes)."""
    for cp, Rc, b in views_:
        c, half = 0.5 * (b[:2] + b[2:]), 0.5 * (b[2:] - b[:2]) * (1.0 - fraction)
        yield cp, Rc, np.concatenate([c - half, c + half])


def test_a_size_bias_does_not_pass_for_bow_or_stern():
    """From a short arc at the loiter's 45 deg the box sizes barely tell bow from stern; boxes trimmed by
    8 % (a detector's bias) then favour whichever heading predicts the smaller boxes. Marginalised over
    the size bias, the pair stays near even; without it, some arcs put 3 to 1 on the wrong end."""
    worst_marginalised, worst_plain = 1.0, 1.0
    for hd in (0.0, 90.0, 37.0):
        for arc in (range(0, 60, 5), range(180, 240, 5)):
            views_ = list(_shrunk(ring_views(hd, arc), 0.08))
            for marginalised in (True, False):
                cfg = ShapeHeadingConfig(size_bias_range=(-0.15, 0.05) if marginalised else (0.0, 0.0))
                w = _shape_from(views_, cfg).weights()
                k = int(round(((90.0 - hd) % 360.0) / (360.0 / len(w)))) % len(w)
                p_true = w[k] / (w[k] + w[(k + len(w) // 2) % len(w)])
                if marginalised:
                    worst_marginalised = min(worst_marginalised, p_true)
                    assert 0.35 < p_true < 0.65, (hd, arc.start, p_true)
                else:
                    worst_plain = min(worst_plain, p_true)
    assert worst_plain < 0.3 < worst_marginalised


def test_bow_and_stern_count_alike_unless_told_apart():
    views_ = list(ring_views(130.0, range(0, 360, 10)))
    told = _shape_from(views_).weights()
    folded = _shape_from(views_, ShapeHeadingConfig(tell_bow_from_stern=False)).weights()
    half = len(folded) // 2
    np.testing.assert_allclose(folded, np.roll(folded, half))
    assert not np.allclose(told, np.roll(told, half))
    np.testing.assert_allclose(folded, 0.5 * (told + np.roll(told, half)), rtol=0, atol=1e-12)


def turning_ship_views(rate_deg_s: float, h0_deg: float = 20.0, lap_s: float = 60.0, hz: float = 3.0):
    """A lap of the loiter ring round a ship turning at ``rate_deg_s`` (clockwise seen from above: its heading
    grows): (t, cam_pos, R_enu_cam, box, the ship's course counter-clockwise from East, rad) at ``hz``."""
    ship = Ship(TargetConfig())
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    n = int(lap_s * hz)
    for k in range(n):
        t = k / hz
        heading = h0_deg + rate_deg_s * t
        pos_ship, R_ship = Ship(TargetConfig(heading_deg=heading)).pose(0.0)
        cp, Rc, frame = _look_from(cam, Pose(R_ship, pos_ship), 707.0, 45.0, 360.0 * k / n)
        yield t, cp, Rc, frame.bbox_px, math.radians(90.0 - heading)


@pytest.mark.parametrize("rate_deg_s", [1.5, -1.0])
def test_the_shape_heading_follows_a_turning_ships_course(rate_deg_s):
    """Over a lap of the ring the ship turns 60-90 deg. Turned with the estimated course between boxes, the
    shapes' posterior ends at the heading the ship has then; left put, it is spread over the headings it had
    and ends elsewhere."""
    views_ = list(turning_ship_views(rate_deg_s))
    final = 90.0 - math.degrees(views_[-1][4])
    best = {}
    for follow in (True, False):
        sh = ShapeHeading(ShapeHeadingConfig(follow_course=follow), ShipOutline(ShipModelConfig()),
                          PinholeCamera.from_config(CAM_CFG))
        for t, cp, Rc, box, course in views_:
            assert sh.update(t, cp, Rc, np.zeros(3), box, course)
        best[follow] = 90.0 - math.degrees(float(sh.courses_enu_rad[int(np.argmax(sh.weights()))]))
    assert _deg_off(best[True], final) <= 5.0, best
    assert _deg_off(best[False], final, 180.0) > 15.0, best


def slow_turning_ship_views(rate_deg_s: float, h0_deg: float = 200.0, lap_s: float = 150.0, span_s: float = 180.0,
                            hz: float = 3.0, heading_deg_at=None):
    """A ship turning at ``rate_deg_s`` (or with the heading ``heading_deg_at(t)``, deg) too slowly for its
    course to be known, seen from the loiter ring (a lap in ``lap_s``) for ``span_s``: (t, cam_pos, R_enu_cam,
    box, its heading, deg)."""
    ship = Ship(TargetConfig())
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    for k in range(int(span_s * hz)):
        t = k / hz
        heading = (h0_deg + rate_deg_s * t if heading_deg_at is None else heading_deg_at(t)) % 360.0
        pos_ship, R_ship = Ship(TargetConfig(heading_deg=heading)).pose(0.0)
        cp, Rc, frame = _look_from(cam, Pose(R_ship, pos_ship), 707.0, 45.0, 360.0 * t / lap_s)
        yield t, cp, Rc, frame.bbox_px, heading


_RATES = (-2.0, -1.5, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5, 2.0)


@pytest.mark.parametrize("rate_deg_s", [1.2, -0.7])
def test_turn_rate_hypotheses_follow_a_slow_ship_that_turns(rate_deg_s):
    """A ship turning at a rate between the hypotheses' (its course unknown, nothing to follow): weighed at
    the headings each rate would have turned it to, with its evidence fading over 30 s, the posterior keeps
    within 12 deg of the ship's axis over the last two minutes (p90), the turn rate near the true one most likely;
    with the one rate 0 it is spread over the headings the ship had and lies tens of degrees off."""
    views_ = list(slow_turning_ship_views(rate_deg_s))
    worst = {}
    for rates, memory in (((0.0,), None), (_RATES, 30.0)):
        sh = ShapeHeading(ShapeHeadingConfig(turn_rates_deg_s=rates, memory_s=memory),
                          ShipOutline(ShipModelConfig()), PinholeCamera.from_config(CAM_CFG))
        off = []
        for t, cp, Rc, box, heading in views_:
            assert sh.update(t, cp, Rc, np.zeros(3), box, None)
            if t >= 60.0:
                best = 90.0 - math.degrees(float(sh.courses_enu_rad[int(np.argmax(sh.weights()))]))
                off.append(_deg_off(best, heading, 180.0))
        worst[rates] = float(np.percentile(off, 90))
        if len(rates) > 1:
            assert abs(rates[int(np.argmax(sh.rate_weights()))] - rate_deg_s) <= 0.5
            assert sh._count < 95.0  # faded: about 3 Hz x 30 s
    assert worst[_RATES] <= 12.0, worst
    assert worst[(0.0,)] > 30.0, worst


def test_with_the_course_followed_the_turn_rates_change_nothing():
    """A ship whose course is followed from its first box: the rates have nothing to weigh (the course turns
    the posterior), which is the one rate 0's to rounding. Lost for 20 s and found again, the rates' evidence
    becomes the likeliest rate's, whose turn the posterior then follows."""
    views_ = list(turning_ship_views(1.5))
    one, many = (ShapeHeading(ShapeHeadingConfig(turn_rates_deg_s=r, memory_s=30.0), ShipOutline(ShipModelConfig()),
                              PinholeCamera.from_config(CAM_CFG)) for r in ((0.0,), _RATES))
    for t, cp, Rc, box, course in views_:
        assert one.update(t, cp, Rc, np.zeros(3), box, course) and many.update(t, cp, Rc, np.zeros(3), box, course)
    np.testing.assert_allclose(many.weights(), one.weights(), rtol=1e-9, atol=1e-12)
    sh = ShapeHeading(ShapeHeadingConfig(turn_rates_deg_s=_RATES, memory_s=30.0), ShipOutline(ShipModelConfig()),
                      PinholeCamera.from_config(CAM_CFG))
    for t, cp, Rc, box, course in views_:
        sh.update(t, cp, Rc, np.zeros(3), box, None if 20.0 <= t < 40.0 else course)
        if 35.0 <= t < 40.0:
            assert not sh._one_rate and sh._rot.any()
    assert sh._one_rate and not sh._rot.any()
    final = 90.0 - math.degrees(views_[-1][4])
    assert _deg_off(90.0 - math.degrees(float(sh.courses_enu_rad[int(np.argmax(sh.weights()))])), final) <= 5.0


def test_turn_rate_hypotheses_leave_a_still_ship_where_it_is():
    """A still ship seen round the ring: the rates' posterior keeps the heading to a bin and favours rate 0."""
    sh = ShapeHeading(ShapeHeadingConfig(turn_rates_deg_s=_RATES, memory_s=30.0), ShipOutline(ShipModelConfig()),
                      PinholeCamera.from_config(CAM_CFG))
    for t, cp, Rc, box, heading in slow_turning_ship_views(0.0, h0_deg=37.0):
        sh.update(t, cp, Rc, np.zeros(3), box, None)
    best = 90.0 - math.degrees(float(sh.courses_enu_rad[int(np.argmax(sh.weights()))]))
    assert _deg_off(best, 37.0) <= 5.0
    assert _RATES[int(np.argmax(sh.rate_weights()))] == 0.0


def zigzagging_slow_ship_views(h0_deg: float, amplitude_deg: float = 30.0, period_s: float = 90.0):
    """The class's ship zigzagging (its heading h0 + amplitude sin(2 pi t / period)) too slowly for its course
    to be known, seen from the loiter ring for 240 s (:func:`slow_turning_ship_views`)."""
    return slow_turning_ship_views(0.0, span_s=240.0, heading_deg_at=lambda t: h0_deg + amplitude_deg * math.sin(
        2.0 * math.pi * t / period_s))


def test_turn_rates_must_be_distinct_and_bounded():
    from pydantic import ValidationError
    for bad in ((0.0, 0.0), (0.0, 45.0), ()):
        with pytest.raises(ValidationError, match="turn_rates_deg_s"):
            ShapeHeadingConfig(turn_rates_deg_s=bad)


def test_the_shape_posterior_turns_by_the_courses_change():
    sh = _shape_from(ring_views(37.0, range(0, 360, 10)))
    w0 = sh.weights()
    sh.turn(math.radians(-20.0))  # 20 deg clockwise: four 5-deg bins
    np.testing.assert_allclose(sh.weights(), np.roll(w0, -4), atol=1e-12)
    sh.turn(math.radians(2.5))  # half a bin: between the neighbours
    assert int(np.argmax(sh.weights())) in ((int(np.argmax(w0)) - 4) % 72, (int(np.argmax(w0)) - 3) % 72)
    sh.turn(math.radians(17.5))  # back where it was, up to the half-bin blur
    assert int(np.argmax(sh.weights())) == int(np.argmax(w0))


def test_shape_heading_skips_border_boxes_and_keeps_its_rate():
    sh = ShapeHeading(ShapeHeadingConfig(rate_hz=2.0), ShipOutline(ShipModelConfig()),
                      PinholeCamera.from_config(CAM_CFG))
    cp, Rc, box = next(ring_views(0.0, range(0, 5, 5)))
    assert sh.update(0.0, cp, Rc, np.zeros(3), box)
    assert not sh.update(0.3, cp, Rc, np.zeros(3), box)  # within 1 / rate_hz of the last one
    touching = box.copy()
    touching[0] = 2.0
    assert not sh.update(1.0, cp, Rc, np.zeros(3), touching)
    assert not sh.update(2.0, cp, Rc, np.zeros(3), np.full(4, np.nan))
    assert sh.update(3.0, cp, Rc, np.zeros(3), box) and sh.updates == 2
    assert not sh.ready and sh.headings() is None  # min_updates not reached


def _ship_with_shape(ship_heading_deg: float, elevations_deg=(45.0,), cfg: ShipModelConfig | None = None
                     ) -> ShipModel:
    """The flight software's ship model after seeing the ship from round loiter rings."""
    ship = ShipModel(cfg or ShipModelConfig(), PinholeCamera.from_config(CAM_CFG))
    k = 0
    for el in elevations_deg:
        for cp, Rc, box in ring_views(ship_heading_deg, range(0, 360, 10), elevation_deg=el):
            ship.shape.update(float(k), cp, Rc, np.zeros(3), box)
            k += 1
    return ship


def test_a_velocity_off_the_ship_axis_gives_no_course():
    """A ship moves along its axis: the flight software takes an estimated velocity across it for the
    estimate's error (a still ship's UKF can pick up a metre or two per second) and keeps the shape's heading."""
    ship = _ship_with_shape(30.0)  # bow 30 deg clockwise from North: course 60 deg counter-clockwise from East
    along = 3.0 * np.array([math.cos(math.radians(60.0)), math.sin(math.radians(60.0)), 0.0])
    assert math.isclose(ship.course(along), math.radians(60.0))
    assert math.isclose(ship.course(-along), math.radians(-120.0))  # astern is on the axis too
    across = 3.0 * np.array([math.cos(math.radians(150.0)), math.sin(math.radians(150.0)), 0.0])
    assert ship.course(across) is None
    courses, weights = ship.headings(np.zeros(3))
    best = math.degrees(float(courses[int(np.argmax(weights))]))
    assert _deg_off(best, 60.0) <= 5.0
    fresh = ShipModel(ShipModelConfig(), PinholeCamera.from_config(CAM_CFG))
    assert fresh.course(across) is not None  # before the shapes tell the axis, any direction is taken
    assert len(fresh.headings(np.zeros(3))[0]) == fresh.cfg.headings_when_unknown


def test_a_lost_course_holds_the_shapes_to_the_side_it_pointed():
    """A ship whose box shapes put its bow at its stern (here the class's own ship, its shapes saying 240 deg,
    counter-clockwise from East, while it moved along 60 deg: as a ship of the other layout looks to the
    class). While the course is followed the headings are the course's side; when it is lost (the speed dips
    under 1.5 m/s) they stay on that side, the held course's std 3 deg growing 1.5 deg/s, until it spans the
    circle (118 s), and then the shapes alone say 240 again. Off (0), the shapes alone at once."""
    from controllers.config import ShapeHeadingConfig

    def best(ship, vel):
        courses, weights, _ = ship.headings_and_course(vel)
        return math.degrees(float(courses[int(np.argmax(weights))])) % 360.0

    along = 3.0 * np.array([math.cos(math.radians(60.0)), math.sin(math.radians(60.0)), 0.0])
    for spread in (1.5, 0.0):
        cfg = ShipModelConfig(heading_from_shape=ShapeHeadingConfig(held_course_spread_deg_s=spread))
        ship = _ship_with_shape(210.0, cfg=cfg)  # the shapes: bow 210 deg from North, course 240 deg ENU
        assert _deg_off(best(ship, np.zeros(3)), 240.0) <= 5.0
        views_ = list(ring_views(210.0, range(0, 360, 10)))
        for k in range(20):  # moving along 60 deg: followed after 10 s
            cp, Rc, box = views_[k]
            ship.observe_box(100.0 + k, cp, Rc, np.zeros(3), box, along, 0.1)
        assert _deg_off(best(ship, along), 60.0) <= 5.0  # the course fused in
        slow = along / 3.0  # 1 m/s: the course lost
        cp, Rc, box = views_[20]
        ship.observe_box(140.0, cp, Rc, np.zeros(3), box, slow, 0.1)
        if spread:
            assert _deg_off(best(ship, slow), 60.0) <= 10.0  # 21 s on: the held course's side
            cp, Rc, box = views_[21]
            ship.observe_box(119.0 + 120.0, cp, Rc, np.zeros(3), box, slow, 0.1)
        assert _deg_off(best(ship, slow), 240.0) <= 10.0  # the shapes alone


def _perception(ship: ShipModel, size_mismatch_action: str = "skip") -> Perception:
    """The perception with that ship model, locked (its gates and correction at work). The size gate skips a
    box off in size however the ship lies (``skip``; the default, ``own_headings``, takes a smaller box too
    when the ship lies clear below the wing plane, as it does in these level views)."""
    p = Perception(DetectionGateConfig(size_mismatch_action=size_mismatch_action),
                   AcquisitionConfig(lock_detections=1), ship, PinholeCamera.from_config(CAM_CFG))
    p.lock.locked = True
    return p


def test_with_the_heading_from_shapes_a_cut_short_box_is_skipped_and_a_whole_one_corrected():
    """Course unknown (still ship): once the shapes tell the heading (here from rings at three elevations),
    the correction is as good as with the true heading, where averaging over all headings leaves several
    pixels; and the box-size gate works as with a known course."""
    import dataclasses

    from controllers.estimation.ukf import CameraMotion
    shaped = _perception(_ship_with_shape(0.0, (30.0, 45.0, 60.0)))  # (boxes at t = 0 add nothing to it)
    blind = _perception(ShipModel(ShipModelConfig(), PinholeCamera.from_config(CAM_CFG)))
    h = UkfConfig().target_plane_height_m
    prior = TargetState(0.0, "estimator", np.array([0.0, 0.0, h]), np.zeros(3), 0.1, h)  # the truth, no velocity
    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    outline = ShipOutline(ShipModelConfig())
    errs = []  # (shape, all headings, true heading), px
    spreads = []  # the fixes' heading spread (shape, all headings), px
    for cp, Rc, box in ring_views(0.0, range(0, 360, 30), elevation_deg=30.0, rng_m=400.0):
        motion = CameraMotion(0.0, cp, np.zeros(3), Rc, np.zeros(3), float(cp[2]))
        meas = Measurements(0.0, cp, np.zeros(3), np.zeros(3), np.zeros(3), 22.0, float(cp[2]), det_new=True,
                            det_valid=True, det_u_px=float(0.5 * (box[0] + box[2])),
                            det_v_px=float(0.5 * (box[1] + box[3])), det_bbox_px=box)
        p = Rc.T @ (np.array([0.0, 0.0, h]) - cp)
        truth = np.array([fsw_cam.fx * p[0] / p[2] + fsw_cam.cx, fsw_cam.fy * p[1] / p[2] + fsw_cam.cy])
        row = []
        for f in (shaped, blind):
            fix = f.step(meas, motion, prior)
            assert fix.use and fix.reason == "" and fix.overridden == ""
            row.append(float(np.hypot(fix.u_px - truth[0], fix.v_px - truth[1])))
            spreads.append(float(np.sqrt(np.trace(fix.offset_spread_px2))))
        off = box_centre_offset_px(outline, fsw_cam, cp, Rc, np.zeros(3), math.radians(90.0), h)
        row.append(float(np.hypot(meas.det_u_px - off[0] - truth[0], meas.det_v_px - off[1] - truth[1])))
        errs.append(row)
        cut = box.copy()
        cut[2] = cut[0] + 0.5 * (box[2] - box[0])  # the right half hidden
        fix = shaped.step(dataclasses.replace(meas, det_bbox_px=cut), motion, prior)
        assert not fix.use and fix.reason == FusionReason.SIZE_MISMATCH
        assert blind.step(dataclasses.replace(meas, det_bbox_px=cut), motion, prior).use  # nothing to compare
    shape, every, true = np.mean(np.array(errs), axis=0)
    assert shape < true + 0.5, errs
    assert every > 3.0 * shape, errs
    # the fixes say so: averaged over all headings the correction's spread is about its error; from the shapes
    # it is a fraction of that
    spread_shape, spread_every = np.mean(np.array(spreads).reshape(-1, 2), axis=0)
    assert 0.5 * every < spread_every < 2.0 * every, (spread_every, every)
    assert spread_shape < 0.3 * spread_every, (spread_shape, spread_every)


def test_a_known_course_and_the_shapes_sharpen_each_other():
    """A moving ship: the shapes' heading posterior times the course's likelihood. An uncertain course
    (velocity std 0.9 m/s at 5 m/s) 15 deg off the shapes' heading gives way to them; a sure one (std 0.05 m/s,
    floored at fuse_min_course_std_deg) pulls the result toward itself."""
    ship = _ship_with_shape(30.0)  # course 60 deg counter-clockwise from East
    off = math.radians(75.0)
    vel = 5.0 * np.array([math.cos(off), math.sin(off), 0.0])
    courses, weights = ship.headings(vel, 0.9)
    unsure = math.degrees(float(np.angle(np.sum(weights * np.exp(1j * courses)))))
    assert abs(unsure - 60.0) < 5.0, unsure
    courses, weights = ship.headings(vel, 0.05)
    sure = math.degrees(float(np.angle(np.sum(weights * np.exp(1j * courses)))))
    assert unsure + 2.0 < sure <= 75.0, (unsure, sure)
    plain = _ship_with_shape(30.0, cfg=ShipModelConfig(heading_from_shape=ShapeHeadingConfig(fuse_with_course=False)))
    courses, weights = plain.headings(vel, 0.9)
    assert len(courses) == 1 and math.isclose(float(courses[0]), off)


def test_size_bias_range_must_be_ordered_and_keep_boxes_positive():
    from pydantic import ValidationError
    for bad in ((0.1, -0.1), (-1.0, 0.0)):
        with pytest.raises(ValidationError, match="size_bias_range"):
            ShapeHeadingConfig(size_bias_range=bad)
    assert len(ShapeHeading(ShapeHeadingConfig(size_bias_range=(0.0, 0.0)), ShipOutline(ShipModelConfig()),
                            PinholeCamera.from_config(CAM_CFG)).size_biases) == 1


@pytest.mark.parametrize("n", [1, 2, 5, 8, 9, 72])
def test_the_compiled_boxes_equal_the_numpy_ones(n):
    """Predicted boxes for a few courses come from a compiled function, for many from numpy: the same boxes to
    rounding, invalid rows (a point behind the camera, a box off the image) NaN in both."""
    from controllers.perception.ship_outline import predicted_boxes_px_numpy
    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    outline = ShipOutline(ShipModelConfig())
    for cp, Rc, _ in list(views(0.0))[::9]:
        for ref in (np.zeros(3), np.array([30.0, -20.0, 0.0]), cp - 10.0 * Rc[:, 2]):
            courses = np.linspace(0.1, 6.2, n)
            a = predicted_boxes_px(outline, fsw_cam, cp, Rc, ref, courses)
            b = predicted_boxes_px_numpy(outline, fsw_cam, cp, Rc, ref, courses)
            np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
            np.testing.assert_allclose(a[np.isfinite(a)], b[np.isfinite(b)], rtol=1e-12, atol=1e-9)


def test_a_late_detection_is_brought_to_the_camera_pose_of_now():
    """Detector latency 0.1 s while the gimbal slews at 40 deg/s and the UAV flies on at 22 m/s: the box centre
    of the exposure, used with the camera pose of now, is off by tens of pixels; brought to now through the
    exposure's pose it lands on the target's image within a pixel (a still ship on the tracked plane)."""
    from controllers.estimation.ukf import CameraMotion
    from fwsim.interface.frames import dcm_enu_from_frd
    cam_model = PinholeCamera.from_config(CAM_CFG)
    p = _perception(ShipModel(ShipModelConfig(), cam_model))
    h = UkfConfig().target_plane_height_m
    target = np.array([1500.0, 200.0, h])

    def pose(t):  # the camera at 1000 m, flying east, its yaw slewing at 40 deg/s; pitched down at the target
        pos = np.array([22.0 * t, 0.0, 1000.0])
        rel = target - pos
        yaw = math.atan2(rel[0], rel[1]) + math.radians(40.0) * (t - 1.0)  # clockwise from North
        pitch = -math.atan2(-rel[2], math.hypot(rel[0], rel[1]))
        R_body = dcm_enu_from_frd(np.array([0.0, pitch, yaw]))
        R_cam = R_body @ np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # cam z fwd, x right, y down
        return CameraMotion(t, pos, np.array([22.0, 0.0, 0.0]), R_cam, np.zeros(3), 1000.0)

    def pixel(m):
        q = m.R_enu_from_cam.T @ (target - m.pos_enu_m)
        return np.array([cam_model.fx * q[0] / q[2] + cam_model.cx, cam_model.fy * q[1] / q[2] + cam_model.cy])

    t_exp, t_now = 0.9, 1.0
    for k in range(4):  # the ticks before: their poses are kept
        p.remember_pose(pose(t_exp - 1 / 30 * (3 - k) + 0.0))
    u, v = pixel(pose(t_exp))
    meas = Measurements(t_now, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), 22.0, 1000.0, det_new=True,
                        det_valid=True, det_u_px=float(u), det_v_px=float(v), det_exposure_t_s=t_exp)
    prior = TargetState(t_now, "estimator", target, np.zeros(3), 0.1, h)
    now = pose(t_now)
    stale = np.hypot(*(np.array([u, v]) - pixel(now)))
    moved = np.hypot(*(np.array(p._to_now(meas, now, prior)) - pixel(now)))
    assert stale > 30.0 and moved < 1.0, (stale, moved)
    p.cfg = p.cfg.model_copy(update={"propagate_feature": False})
    assert p._to_now(meas, now, prior) == (float(u), float(v))


def test_weighted_mean_of_rows_is_numpys_average_bit_for_bit():
    """The box-centre offset's weighted mean skips np.average's argument checks but keeps its reductions: the
    same numbers, bit for bit, for 1 to 80 headings (pairwise summation starts above 8)."""
    from controllers.perception.ship_outline import weighted_mean_rows
    rng = np.random.default_rng(3)
    for n in list(range(1, 81)) * 5:
        a, w = 50.0 * rng.normal(size=(n, 2)), rng.random(n)
        w /= w.sum()
        assert np.array_equal(weighted_mean_rows(a, w), np.average(a, axis=0, weights=w))
        assert np.array_equal(weighted_mean_rows(a, None), np.average(a, axis=0))  # equal headings
    with pytest.raises(ZeroDivisionError):
        weighted_mean_rows(np.ones((3, 2)), np.zeros(3))


@pytest.mark.parametrize("ship_type, dims", [("bridge_aft", (47.0, 20.0, 32.0)), ("ferry", (65.0, 27.0, 20.0))])
def test_the_size_fit_learns_a_ship_unlike_the_class_and_corrects_better(ship_type, dims):
    """A ship of another size seen from round a loiter ring at a known heading. With the class's layout the
    fitted height comes within 5 % (the class's is 22 % off) and the box centres corrected with the fitted
    outline land nearer the tracked point's image than with the class's, by more than half; a ferry (another
    layout, 20 % lower) comes out taller, not lower (its boxes are tall for its height), and its correction
    is about as good as with the class's outline."""
    from controllers.perception.size_fit import ShipSize
    L, W, H = dims
    heading = 40.0
    ship = Ship(TargetConfig(type=ship_type, heading_deg=heading, length_m=L, width_m=W, height_m=H))
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    pose = Pose(*reversed(ship.pose(0.0)))
    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    outline = ShipOutline(ShipModelConfig())
    fit = ShipSize(SizeFitConfig(min_updates=0), outline, fsw_cam)
    course = math.radians(90.0 - heading)
    rings = [(az, el) for el in (35.0, 40.0) for az in range(0, 360, 5)]
    for az, el in rings:
        cp, Rc, frame = _look_from(cam, pose, 700.0, el, az)
        assert fit.update(cp, Rc, np.zeros(3), course, frame.bbox_px)
    s = fit.scale
    if ship_type == "bridge_aft":  # the class's layout: the height most of the way there
        assert abs(s[2] * 25.0 / H - 1.0) < 0.05, s  # 22 % off with the class's height
    h = UkfConfig().target_plane_height_m
    errs = []  # (class outline, fitted outline), px
    for az in range(0, 360, 30):
        cp, Rc, frame = _look_from(cam, pose, 500.0, 30.0, az + 2.5)
        b = frame.bbox_px
        p = Rc.T @ (np.array([0.0, 0.0, h]) - cp)
        truth = np.array([fsw_cam.fx * p[0] / p[2] + fsw_cam.cx, fsw_cam.fy * p[1] / p[2] + fsw_cam.cy])
        centre = np.array([0.5 * (b[0] + b[2]), 0.5 * (b[1] + b[3])])
        row = []
        for sc in (None, s):
            off = box_centre_offset_px(outline, fsw_cam, cp, Rc, np.zeros(3), course, h, scale=sc)
            row.append(float(np.hypot(*(centre - off - truth))))
        errs.append(row)
    cls_err, fit_err = np.mean(np.array(errs), axis=0)
    if ship_type == "bridge_aft":
        assert fit_err < 0.5 * cls_err, errs  # 7.9 -> 2.8 px
    else:  # another layout: the sizes fitted with the class's layout move the centre little (3.0 -> 3.5 px)
        assert fit_err < cls_err + 1.0, errs


def test_the_size_fit_stays_near_the_class_in_a_shallow_dive_where_the_mast_shows():
    """The class's own ship approached from 600 to 160 m at 20 deg, from 12 bearings. Close in the ray-cast
    detector's box takes in the thin mast, which far boxes leave out: the fit predicts midway between the
    outline with and without it, the difference in the box's noise, and every scale ends within 13 % of 1,
    the height within 11 % (fitted against the outline without the mast alone: up to 1.22)."""
    from controllers.perception.size_fit import ShipSize
    ship = Ship(TargetConfig(heading_deg=40.0))
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    pose = Pose(*reversed(ship.pose(0.0)))
    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    course = math.radians(50.0)
    for az in range(0, 360, 30):
        fit = ShipSize(SizeFitConfig(min_updates=0), ShipOutline(ShipModelConfig()), fsw_cam)
        for rng in np.linspace(600.0, 160.0, 45):
            cp, Rc, frame = _look_from(cam, pose, float(rng), 20.0, float(az))
            assert fit.update(cp, Rc, np.zeros(3), course, frame.bbox_px)
        assert np.all(np.abs(fit.theta) < math.log(1.13)) and fit.scale[2] < 1.11, (az, fit.scale)


def test_the_size_fit_weighs_boxes_at_its_rate():
    """Consecutive frames carry nearly the same information: with times given, a box within 1 / rate_hz of the
    last one weighed is not looked at (without times, every box is)."""
    from controllers.perception.size_fit import ShipSize
    ship = Ship(TargetConfig(heading_deg=40.0, length_m=47.0, width_m=20.0, height_m=32.0))
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    cp, Rc, frame = _look_from(cam, Pose(*reversed(ship.pose(0.0))), 700.0, 35.0, 30.0)
    fit = ShipSize(SizeFitConfig(rate_hz=3.0), ShipOutline(ShipModelConfig()), PinholeCamera.from_config(CAM_CFG))
    course = math.radians(50.0)
    taken = [fit.update(cp, Rc, np.zeros(3), course, frame.bbox_px, t) for t in np.arange(0.0, 2.0, 1.0 / 30.0)]
    assert sum(taken) == 6 and fit.updates == 6  # at 0, 1/3, ..., 5/3 s
    assert fit.update(cp, Rc, np.zeros(3), course, frame.bbox_px) and fit.updates == 7


def test_a_size_fit_gone_wrong_starts_again():
    """A fit sure of a wrong size turns every box away; after max_gated_in_a_row of them it starts again from
    the prior and (``class_after_restarts: 0``) learns the ship."""
    from controllers.perception.size_fit import ShipSize
    ship = Ship(TargetConfig(heading_deg=40.0, length_m=47.0, width_m=20.0, height_m=32.0))
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    pose = Pose(*reversed(ship.pose(0.0)))
    fit = ShipSize(SizeFitConfig(enabled=True, min_updates=0, max_gated_in_a_row=10, class_after_restarts=0),
                   ShipOutline(ShipModelConfig()), PinholeCamera.from_config(CAM_CFG))
    fit.x = np.log(np.array([1.6, 1.6, 0.6]))
    fit.P = np.eye(3) * 1e-6
    course = math.radians(50.0)
    taken = []
    for az in range(0, 360, 3):
        cp, Rc, frame = _look_from(cam, pose, 700.0, 35.0, az)
        taken.append(fit.update(cp, Rc, np.zeros(3), course, frame.bbox_px))
    assert not any(taken[:10]) and fit.restarts == 1 and all(taken[10:])
    assert abs(fit.scale[2] * 25.0 / 32.0 - 1.0) < 0.1, fit.scale


def test_a_size_fit_that_started_again_gives_way_to_the_class_with_class_after_restarts():
    """``class_after_restarts: 1`` (the default): the same fit gone wrong, once it starts again, takes no more
    boxes and the correction keeps the class's outline (``scale`` None) for good; with 2 it learns again after
    the first restart, as with 0."""
    from controllers.perception.size_fit import ShipSize
    ship = Ship(TargetConfig(heading_deg=40.0, length_m=47.0, width_m=20.0, height_m=32.0))
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    pose = Pose(*reversed(ship.pose(0.0)))
    fits = {}
    for n in (0, 1, 2):
        fit = ShipSize(SizeFitConfig(enabled=True, min_updates=0, max_gated_in_a_row=10, class_after_restarts=n),
                       ShipOutline(ShipModelConfig()), PinholeCamera.from_config(CAM_CFG))
        fit.x = np.log(np.array([1.6, 1.6, 0.6]))
        fit.P = np.eye(3) * 1e-6
        assert fit.scale is not None
        taken = []
        for az in range(0, 360, 3):
            cp, Rc, frame = _look_from(cam, pose, 700.0, 35.0, az)
            taken.append(fit.update(cp, Rc, np.zeros(3), math.radians(50.0), frame.bbox_px))
        fits[n] = (fit, taken)
    assert SizeFitConfig().class_after_restarts == 1
    fit, taken = fits[1]
    assert fit.restarts == 1 and fit.retired and not any(taken) and fit.scale is None and not fit.takes_boxes()
    for n in (0, 2):
        fit, taken = fits[n]
        assert fit.restarts == 1 and not fit.retired and all(taken[10:]) and fit.scale is not None


class _Events:
    """The perception's event and log sink in these tests: the events' texts, in order."""

    def __init__(self):
        self.texts = []

    def event(self, text):
        self.texts.append(text)

    def log(self, *_):
        pass


def _moving_ship_scene(length_m: float, width_m: float, height_m: float, heading_deg: float = 40.0,
                       ship_type: str = "bridge_aft"):
    """A ship of that size (and type) on a 3 m/s course, its ray-cast camera and the flight software's: (camera,
    ship pose, flight software camera, tracked height, the prior's velocity)."""
    ship = Ship(TargetConfig(type=ship_type, heading_deg=heading_deg, length_m=length_m, width_m=width_m,
                             height_m=height_m))
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    course = math.radians(90.0 - heading_deg)
    return (cam, Pose(*reversed(ship.pose(0.0))), PinholeCamera.from_config(CAM_CFG),
            UkfConfig().target_plane_height_m, 3.0 * np.array([math.cos(course), math.sin(course), 0.0]))


def _nose_on(cam_pos_enu_m) -> np.ndarray:
    """NED Euler angles (level wings) of a UAV at ``cam_pos_enu_m`` with its nose on the origin: the ship there
    lies in the wing plane, where the airframe may hide part of it."""
    e, n, u = (float(x) for x in cam_pos_enu_m[:3])
    return np.array([0.0, math.atan2(-u, math.hypot(e, n)), math.atan2(-e, -n)])


def _ring_detection(cam, pose, t_s: float, az_deg: float, rng_m: float = 600.0, elevation_deg: float = 35.0):
    """The ship's ray-cast box seen from the ring at ``t_s``: (Measurements, CameraMotion, cam_pos, R_enu_cam)."""
    from controllers.estimation.ukf import CameraMotion
    cp, Rc, frame = _look_from(cam, pose, rng_m, elevation_deg, az_deg)
    box = frame.bbox_px
    motion = CameraMotion(t_s, cp, np.zeros(3), Rc, np.zeros(3), float(cp[2]))
    meas = Measurements(t_s, cp, np.zeros(3), np.zeros(3), np.zeros(3), 22.0, float(cp[2]), det_new=True,
                        det_valid=True, det_u_px=float(0.5 * (box[0] + box[2])),
                        det_v_px=float(0.5 * (box[1] + box[3])), det_bbox_px=box)
    return meas, motion, cp, Rc


def test_the_perception_corrects_with_the_fitted_size():
    """The perception feeds the size fit the boxes it sees at a sure heading (the box shapes', the course fused
    in) and, once the fit is in use, corrects with the fitted outline: round a ship 28 % taller and 15 %
    shorter than the class its corrected box centres land nearer the tracked point's image than with the fit
    off."""
    cam, pose, fsw_cam, h, vel = _moving_ship_scene(47.0, 20.0, 32.0)
    prior = TargetState(0.0, "estimator", np.array([0.0, 0.0, h]), vel, 0.1, h)  # (the ship held still here)
    percs = {fit: _perception(ShipModel(ShipModelConfig(size_fit=SizeFitConfig(enabled=fit)), fsw_cam))
             for fit in (False, True)}
    errs = {False: [], True: []}
    for k, az in enumerate(list(range(0, 360, 5)) * 2):
        t = 0.5 * k  # the box shapes take two a second
        meas, motion, cp, Rc = _ring_detection(cam, pose, t, az)
        p = Rc.T @ (np.array([0.0, 0.0, h]) - cp)
        truth = np.array([fsw_cam.fx * p[0] / p[2] + fsw_cam.cx, fsw_cam.fy * p[1] / p[2] + fsw_cam.cy])
        for fit, perc in percs.items():
            fix = perc.step(meas, motion, dataclasses.replace(prior, t_s=t))
            errs[fit].append(float(np.hypot(fix.u_px - truth[0], fix.v_px - truth[1])))
    fitted = percs[True].ship.size
    assert percs[False].ship.size.scale is None and fitted.scale is not None and fitted.scale[2] > 1.15
    n = len(errs[True]) // 2  # the second time round, the fit in use
    fit_err, class_err = np.mean(errs[True][n:]), np.mean(errs[False][n:])
    assert fit_err < 0.6 * class_err, (fit_err, class_err)


def test_the_perception_says_when_its_size_fit_gives_way_to_the_class():
    """A size fit sure of a wrong size, fed by the perception round the ring, turns the boxes away, starts again
    and (``class_after_restarts: 1``, the default) keeps the class's outline: an event says so, once."""
    cam, pose, fsw_cam, h, vel = _moving_ship_scene(47.0, 20.0, 32.0)
    prior = TargetState(0.0, "estimator", np.array([0.0, 0.0, h]), vel, 0.1, h)

    ship = ShipModel(ShipModelConfig(size_fit=SizeFitConfig(min_updates=0, max_gated_in_a_row=10)), fsw_cam)
    ship.size.x = np.log(np.array([1.6, 1.6, 0.6]))
    ship.size.P = np.eye(3) * 1e-6
    perc = Perception(DetectionGateConfig(size_mismatch_action="skip"), AcquisitionConfig(lock_detections=1), ship,
                      fsw_cam, _Events())
    perc.lock.locked = True
    for k, az in enumerate(range(0, 360, 5)):
        meas, motion, _, _ = _ring_detection(cam, pose, 0.5 * k, az)
        perc.step(meas, motion, dataclasses.replace(prior, t_s=0.5 * k))
    assert ship.size.restarts == 1 and ship.size.retired and ship.size.scale is None
    said = [e for e in perc._record.texts if "size fit" in e]
    assert len(said) == 1 and "keeps the class's outline" in said[0], said


def test_boxes_off_the_class_turn_the_class_check_on_with_the_size_fit_off():
    """With the size fit off, a ship 40 % bigger than the class makes most boxes disagree with the class's
    predicted size: after class_check_window boxes the perception says so (an event) and, with the default
    action, stops skipping boxes for their size."""
    cam, pose, fsw_cam, h, vel = _moving_ship_scene(77.0, 35.0, 35.0)
    rec = _Events()
    gate = DetectionGateConfig()
    perc = Perception(gate, AcquisitionConfig(lock_detections=1),
                      ShipModel(ShipModelConfig(size_fit=SizeFitConfig(enabled=False)), fsw_cam), fsw_cam, rec)
    perc.lock.locked = True
    reasons = []
    for k, az in enumerate(list(range(0, 360, 2))):
        t = 0.5 * k
        meas, motion, _, _ = _ring_detection(cam, pose, t, az)
        prior = TargetState(t, "estimator", np.array([0.0, 0.0, h]), vel, 0.1, h)
        fix = perc.step(meas, motion, prior)
        reasons.append(fix.reason or fix.overridden)
    n = gate.class_check_window
    assert perc.class_mismatch and any("off the ship class's size" in e for e in rec.texts), rec.texts
    assert reasons[:n].count(FusionReason.SIZE_MISMATCH) > n // 2  # skipped for their size until then
    assert reasons[-20:].count(FusionReason.SIZE_MISMATCH) < 5  # and taken after


def test_boxes_the_airframe_may_have_cut_do_not_turn_the_class_check_on():
    """A ship of the class, its boxes cut short (the right half hidden), as the UAV's airframe cuts them in a
    dive: with the ship in the wing plane (nose on) they are no evidence of another class and the class check
    stays off (``class_check_clear_only``, the default), where counting them turns it on and lets the
    rescaled size gate take cut boxes; with the ship clear below the wing plane (flown level) the same boxes
    do count."""
    cam, pose, fsw_cam, h, vel = _moving_ship_scene(55.0, 25.0, 25.0)

    def fly(clear_only: bool, nose_on: bool) -> Perception:
        perc = Perception(DetectionGateConfig(class_check_clear_only=clear_only),
                          AcquisitionConfig(lock_detections=1),
                          ShipModel(ShipModelConfig(size_fit=SizeFitConfig(enabled=False)), fsw_cam), fsw_cam)
        perc.lock.locked = True
        for k, az in enumerate(range(0, 360, 2)):
            t = 0.5 * k
            meas, motion, cp, _ = _ring_detection(cam, pose, t, az)
            cut = np.asarray(meas.det_bbox_px, dtype=float).copy()
            cut[2] = cut[0] + 0.5 * (cut[2] - cut[0])
            euler = _nose_on(cp)
            meas = dataclasses.replace(meas, det_bbox_px=cut, euler_ned_rad=euler if nose_on else np.zeros(3))
            perc.step(meas, motion, TargetState(t, "estimator", np.array([0.0, 0.0, h]), vel, 0.1, h))
        return perc

    assert not fly(True, nose_on=True).class_mismatch
    assert fly(False, nose_on=True).class_mismatch
    assert fly(True, nose_on=False).class_mismatch


def test_a_box_no_heading_explains_is_deweighted_not_skipped_when_asked():
    """size_mismatch_action: deweight: the box cut short is used, its corrected centre as a whole box's
    would be corrected, with the doubt (half the size difference from the predicted box)^2 in each axis; the
    log names the gate passed over. The default (skip) skips it."""
    from controllers.estimation.ukf import CameraMotion
    h = UkfConfig().target_plane_height_m
    prior = TargetState(0.0, "estimator", np.array([0.0, 0.0, h]), np.zeros(3), 0.1, h)
    ship = _ship_with_shape(0.0, (30.0, 45.0, 60.0))
    skip = _perception(ship)
    weigh = Perception(DetectionGateConfig(size_mismatch_action="deweight"), AcquisitionConfig(lock_detections=1),
                       ship, PinholeCamera.from_config(CAM_CFG))
    weigh.lock.locked = True
    for cp, Rc, box in ring_views(0.0, range(0, 360, 90), elevation_deg=30.0, rng_m=400.0):
        motion = CameraMotion(0.0, cp, np.zeros(3), Rc, np.zeros(3), float(cp[2]))
        cut = box.copy()
        cut[2] = cut[0] + 0.5 * (box[2] - box[0])  # the right half hidden
        meas = Measurements(0.0, cp, np.zeros(3), np.zeros(3), np.zeros(3), 22.0, float(cp[2]), det_new=True,
                            det_valid=True, det_u_px=float(0.5 * (cut[0] + cut[2])),
                            det_v_px=float(0.5 * (cut[1] + cut[3])), det_bbox_px=cut)
        skipped = skip.step(meas, motion, prior)
        assert not skipped.use and skipped.reason == FusionReason.SIZE_MISMATCH
        assert skipped.centre_noise_px2 == (0.0, 0.0)
        fix = weigh.step(meas, motion, prior)
        assert fix.use and fix.reason == "" and fix.overridden == FusionReason.SIZE_MISMATCH
        pred = fix.predicted_box_px
        dw = 0.5 * ((cut[2] - cut[0]) - (pred[2] - pred[0]))
        dh = 0.5 * ((cut[3] - cut[1]) - (pred[3] - pred[1]))
        assert fix.centre_noise_px2 == pytest.approx((dw * dw, dh * dh), rel=1e-12)
        assert fix.centre_noise_px2[0] > 50.0  # half of a box of 100s of px: tens of px of doubt
        # the centre corrected as for a whole box (the offset of the same view), not left raw
        whole = weigh.step(dataclasses.replace(meas, det_bbox_px=box, det_u_px=float(0.5 * (box[0] + box[2])),
                                               det_v_px=float(0.5 * (box[1] + box[3]))), motion, prior)
        assert whole.use and whole.overridden == "" and whole.centre_noise_px2 == (0.0, 0.0)
        off_cut = np.array([meas.det_u_px - fix.u_px, meas.det_v_px - fix.v_px])
        off_whole = np.array([whole.raw_u_px - whole.u_px, whole.raw_v_px - whole.v_px])
        np.testing.assert_allclose(off_cut, off_whole, atol=1e-9)


def test_a_box_that_may_be_cut_is_used_with_its_doubt_when_asked():
    """``own_headings`` with ``maybe_cut_action: deweight`` (the default): a box cut short (the right half
    hidden) while the ship lies in the wing plane (nose on), which ``maybe_cut_action: skip`` skips, is used
    with the doubt ``deweight`` gives it, (half its size difference from the predicted box)^2; a whole box is
    corrected as before."""
    from controllers.estimation.ukf import CameraMotion
    h = UkfConfig().target_plane_height_m
    prior = TargetState(0.0, "estimator", np.array([0.0, 0.0, h]), np.zeros(3), 0.1, h)
    ship = _ship_with_shape(0.0, (30.0, 45.0, 60.0))
    percs = {}
    for action in ("skip", "deweight"):
        percs[action] = Perception(DetectionGateConfig(maybe_cut_action=action), AcquisitionConfig(lock_detections=1),
                                   ship, PinholeCamera.from_config(CAM_CFG))
        percs[action].lock.locked = True
    for cp, Rc, box in ring_views(0.0, range(0, 360, 90), elevation_deg=30.0, rng_m=400.0):
        motion = CameraMotion(0.0, cp, np.zeros(3), Rc, np.zeros(3), float(cp[2]))
        nose_on = _nose_on(cp)
        cut = box.copy()
        cut[2] = cut[0] + 0.5 * (box[2] - box[0])
        meas = Measurements(0.0, cp, np.zeros(3), nose_on, np.zeros(3), 22.0, float(cp[2]), det_new=True,
                            det_valid=True, det_u_px=float(0.5 * (cut[0] + cut[2])),
                            det_v_px=float(0.5 * (cut[1] + cut[3])), det_bbox_px=cut)
        skipped = percs["skip"].step(meas, motion, prior)
        assert not skipped.use and skipped.reason == FusionReason.SIZE_MISMATCH
        fix = percs["deweight"].step(meas, motion, prior)
        assert fix.use and fix.overridden == FusionReason.SIZE_MISMATCH
        pred = fix.predicted_box_px
        dw = 0.5 * ((cut[2] - cut[0]) - (pred[2] - pred[0]))
        dh = 0.5 * ((cut[3] - cut[1]) - (pred[3] - pred[1]))
        assert fix.centre_noise_px2 == pytest.approx((dw * dw, dh * dh), rel=1e-12)
        whole = dataclasses.replace(meas, det_bbox_px=box, det_u_px=float(0.5 * (box[0] + box[2])),
                                    det_v_px=float(0.5 * (box[1] + box[3])))
        a, b = percs["skip"].step(whole, motion, prior), percs["deweight"].step(whole, motion, prior)
        assert a.use and b.use and (a.u_px, a.v_px, a.centre_noise_px2) == (b.u_px, b.v_px, b.centre_noise_px2)


def test_the_ukf_weighs_a_doubtful_box_less():
    """A fix with centre_noise_px2 moves the estimate less than the same fix without it."""
    from controllers.estimation.ukf import CameraMotion, UkfTargetEstimator
    from controllers.messages import DetectionFix
    cfg = UkfConfig()
    cam = PinholeCamera.from_config(CAM_CFG)
    cp = np.array([-400.0, 0.0, 300.0])
    p = np.array([0.0, 0.0, cfg.target_plane_height_m]) - cp
    d = p / np.linalg.norm(p)
    z = np.array([0.0, 0.0, 1.0])
    x = np.cross(z, d)
    x = np.array([0.0, -1.0, 0.0]) if np.linalg.norm(x) < 1e-9 else x / np.linalg.norm(x)
    Rc = np.column_stack([x, np.cross(d, x), d])  # optical axis on the point
    motion = CameraMotion(0.0, cp, np.zeros(3), Rc, np.zeros(3), float(cp[2]))
    moved = []
    for noise in ((0.0, 0.0), (400.0, 400.0)):
        f = UkfTargetEstimator(cam, cfg)
        base = DetectionFix(0.0, True, 0.0, cam.cx, cam.cy, np.array([cam.cx - 50, cam.cy - 20, cam.cx + 50,
                            cam.cy + 20]), cam.cx, cam.cy, np.full(4, np.nan), True, "", "", True, False, 0.0, 0.0)
        f.initialise(base, motion)
        before = f.estimate().pos_enu_m.copy()
        shifted = dataclasses.replace(base, t_s=0.1, u_px=cam.cx + 4.0, centre_noise_px2=noise)
        assert f.update(shifted, dataclasses.replace(motion, t_s=0.1)).used
        moved.append(float(np.linalg.norm(f.estimate().pos_enu_m[:2] - before[:2])))
    assert moved[1] < 0.5 * moved[0], moved


def test_a_box_the_estimated_course_cannot_explain_is_corrected_over_its_own_headings():
    """``size_mismatch_action: own_headings``. The ship points north while its estimated velocity says east
    (a turn the estimate has not followed): from a ring of views the boxes whose size the eastward course
    cannot explain are skipped (``skip``); with ``own_headings`` those larger than the course's box (no
    occlusion makes a box larger) are corrected over the headings all round whose predicted size does explain
    them: used, flagged, nearer the tracked point's image than the wrong course's correction, and within
    twice the pixel std their headings' spread gives them; a box cut short is still skipped. Here the UAV's
    nose is on the ship (it lies in the wing plane, where the airframe may hide part of it): a box smaller than
    the course's might be cut short, and is skipped; flown level, the ship lies 40 deg below the wing plane
    (airframe_clearance_deg), no part of it can be hidden, and those are corrected over their own headings
    too."""
    from controllers.estimation.ukf import CameraMotion
    cam = PinholeCamera.from_config(CAM_CFG)
    h = UkfConfig().target_plane_height_m
    prior = TargetState(0.0, "estimator", np.array([0.0, 0.0, h]), np.array([5.0, 0.0, 0.0]), 0.1, h)
    skip = _perception(ShipModel(ShipModelConfig(), cam))
    gate = DetectionGateConfig(size_mismatch_action="own_headings", maybe_cut_action="skip")  # (the default
    # uses a box that may be cut with its doubt: test_a_box_that_may_be_cut_is_used_with_its_doubt_when_asked)
    own = Perception(gate, AcquisitionConfig(lock_detections=1), ShipModel(ShipModelConfig(), cam), cam)
    own.lock.locked = True
    level = Perception(gate, AcquisitionConfig(lock_detections=1), ShipModel(ShipModelConfig(), cam), cam)
    level.lock.locked = True
    outline = ShipOutline(ShipModelConfig())
    errs = []  # (own headings, the eastward course's correction), px
    smaller = 0  # boxes smaller than the course's that some heading explains
    for cp, Rc, box in ring_views(0.0, range(0, 360, 30), elevation_deg=40.0, rng_m=400.0):
        motion = CameraMotion(0.0, cp, np.zeros(3), Rc, np.zeros(3), float(cp[2]))
        nose_on = _nose_on(cp)
        meas = Measurements(0.0, cp, np.zeros(3), nose_on, np.zeros(3), 22.0, float(cp[2]), det_new=True,
                            det_valid=True, det_u_px=float(0.5 * (box[0] + box[2])),
                            det_v_px=float(0.5 * (box[1] + box[3])), det_bbox_px=box)
        skipped = skip.step(meas, motion, prior)
        fix = own.step(meas, motion, prior)
        clear = level.step(dataclasses.replace(meas, euler_ned_rad=np.zeros(3)), motion, prior)
        if skipped.use:  # the eastward course explains this box: both correct it alike
            assert fix.use and fix.overridden == "" and fix.u_px == skipped.u_px and fix.v_px == skipped.v_px
            assert (clear.u_px, clear.v_px) == (fix.u_px, fix.v_px)
            continue
        assert skipped.reason == FusionReason.SIZE_MISMATCH
        if not fix.use:  # a box no larger than the eastward course's: it might be cut short, and is skipped
            assert fix.reason == FusionReason.SIZE_MISMATCH
            # clear of the airframe it is the ship's own size: corrected over the headings that explain it
            assert clear.use and clear.overridden == FusionReason.SIZE_MISMATCH, clear
            smaller += 1
            continue
        assert (clear.u_px, clear.v_px) == (fix.u_px, fix.v_px)
        assert fix.overridden == FusionReason.SIZE_MISMATCH, fix
        # a box with more ship than the course shows, and a cut-short one (the right half hidden) never taken
        cut = box.copy()
        cut[2] = cut[0] + 0.5 * (box[2] - box[0])
        assert not own.step(dataclasses.replace(meas, det_bbox_px=cut), motion, prior).use
        assert fix.centre_noise_px2[0] > 0.0 or fix.centre_noise_px2[1] > 0.0
        p = Rc.T @ (np.array([0.0, 0.0, h]) - cp)
        truth = np.array([cam.fx * p[0] / p[2] + cam.cx, cam.fy * p[1] / p[2] + cam.cy])
        off = box_centre_offset_px(outline, cam, cp, Rc, np.zeros(3), 0.0, h)  # the eastward course's
        errs.append((float(np.hypot(fix.u_px - truth[0], fix.v_px - truth[1])),
                     float(np.hypot(meas.det_u_px - off[0] - truth[0], meas.det_v_px - off[1] - truth[1]))))
        # what is left is the bow / stern doubt (both explain the size), and the fix's variance says so
        assert errs[-1][0] <= 2.0 * math.sqrt(sum(fix.centre_noise_px2)), (errs[-1], fix.centre_noise_px2)
    assert len(errs) >= 3, errs  # views where the ship turned 90 deg shows more of itself
    assert smaller >= 2, smaller  # and views where it shows less
    own_err, wrong_err = np.mean(np.array(errs), axis=0)
    assert own_err < 0.7 * wrong_err, errs  # 6.6 against 11.0 px


def test_a_moving_ship_s_boxes_are_taken_closer_in():
    """``detection_gate.moving_min_range_m``: a ship estimated to move at ``moving_speed_m_s`` or more has its
    boxes taken down to that range (the coast after the last box flies its velocity); a still or slow one's
    stop at ``min_range_m``; with the two ranges equal every ship's stop there, and min_range_m 0 gates
    none."""
    from types import SimpleNamespace
    cam = PinholeCamera.from_config(CAM_CFG)

    def gate_at(range_m: float, speed_m_s: float, **settings) -> str:
        p = Perception(DetectionGateConfig(**settings), AcquisitionConfig(lock_detections=1),
                       ShipModel(ShipModelConfig(), cam), cam)
        d = range_m / math.sqrt(2.0)
        nav = SimpleNamespace(cam_pos_enu_m=np.array([0.0, -d, d]), det_bbox_px=np.array([600.0, 300, 700, 400]))
        prior = TargetState(0.0, "estimator", np.zeros(3), np.array([0.6, 0.8, 0.0]) * speed_m_s, 0.1, 0.0)
        return p._gate(nav, None, prior)

    g = DetectionGateConfig()
    assert (g.min_range_m, g.moving_min_range_m, g.moving_speed_m_s) == (120.0, 80.0, 2.0)
    close = FusionReason.TOO_CLOSE
    assert gate_at(100.0, 5.0) == "" and gate_at(100.0, 2.0) == ""
    assert gate_at(100.0, 1.9) == close and gate_at(100.0, 0.0) == close
    assert gate_at(79.0, 5.0) == close and gate_at(121.0, 0.0) == ""
    assert gate_at(100.0, 5.0, moving_min_range_m=120.0) == close
    assert gate_at(10.0, 5.0, min_range_m=0.0) == "" and gate_at(10.0, 0.0, min_range_m=0.0) == ""


def _layout_fit_round(ship_type: str, course_known: bool = True, elevation_deg: float = 40.0):
    """A LayoutFit fed the ray-cast boxes of a still ship of ``ship_type`` seen from round a ring (700 m, a lap
    in 4 min at 1.5 boxes a second), the estimate on the ship, its course given (or None): the fit."""
    from controllers.config import LayoutFitConfig
    from controllers.perception.layout_fit import LayoutFit
    heading = 40.0
    ship = Ship(TargetConfig(type=ship_type, heading_deg=heading))
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    pose = Pose(*reversed(ship.pose(0.0)))
    cfg = ShipModelConfig()
    fit = LayoutFit(LayoutFitConfig(), (ShipOutline(cfg), ShipOutline(cfg, other_end=True)),
                    PinholeCamera.from_config(CAM_CFG))
    course = math.radians(90.0 - heading) if course_known else None
    for k, az in enumerate(np.arange(0.0, 360.0, 2.0)):
        cp, Rc, frame = _look_from(cam, pose, 700.0, elevation_deg, az)
        fit.observe(k / 1.5, cp, Rc, np.zeros(3), frame.bbox_px, course, UkfConfig().target_plane_height_m,
                    vel_enu=np.zeros(3))
    return fit


@pytest.mark.parametrize("elevation_deg", [25.0, 40.0, 50.0])
def test_the_layout_fit_tells_which_end_the_superstructure_stands_at(elevation_deg):
    """Round a ship whose superstructure stands forward (``bridge_forward``) the box centres corrected with the
    class's layout (bridge aft) wander off one track as the view goes round, the other end's do not: the fit
    takes the other end (probability >= 0.9; measured 0.985-1.0). Round the class's own layout it keeps the
    class (<= 0.1; measured 0.000-0.034). Neither moves without a known course (a still ship's two layouts are
    its two headings)."""
    fwd = _layout_fit_round("bridge_forward", elevation_deg=elevation_deg)
    assert fwd.other_end and fwd.p_other_end >= 0.9, fwd.p_other_end
    aft = _layout_fit_round("bridge_aft", elevation_deg=elevation_deg)
    assert not aft.other_end and aft.p_other_end <= 0.1, aft.p_other_end
    blind = _layout_fit_round("bridge_forward", course_known=False, elevation_deg=elevation_deg)
    assert not blind.other_end and blind.p_other_end == blind.cfg.prior_other_end and blind.misfits() is None


def test_the_other_end_s_outline_mirrors_the_superstructure_on_the_same_hull():
    """``ShipOutline(other_end=True)``: the hull's points as the class's, every superstructure point at minus its
    distance along the ship (x), beam and height as they were."""
    cfg = ShipModelConfig()
    a, b = ShipOutline(cfg), ShipOutline(cfg, other_end=True)
    n_hull = 14  # the hull's corners (7 at the waterline, 7 at the deck)
    assert np.array_equal(a.points_ship_m[:n_hull], b.points_ship_m[:n_hull])
    sa, sb = a.points_ship_m[n_hull:], b.points_ship_m[n_hull:]
    assert sa[:, 0].max() < 0.0 < sb[:, 0].min()  # aft of midships, and forward
    assert sorted(map(tuple, sb)) == sorted(map(tuple, sa * np.array([-1.0, 1.0, 1.0])))


def test_a_held_layout_fit_learns_nothing_more():
    """The terminal switch holds the fit (the airframe starts to cut the boxes): no box moves it after."""
    fit = _layout_fit_round("bridge_aft")
    p, n = fit.p_other_end, fit.boxes
    fit.hold()
    ship = Ship(TargetConfig(type="bridge_forward", heading_deg=40.0))
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    for k, az in enumerate(range(0, 360, 10)):
        cp, Rc, frame = _look_from(cam, Pose(*reversed(ship.pose(0.0))), 700.0, 40.0, az)
        assert not fit.observe(1e4 + k, cp, Rc, np.zeros(3), frame.bbox_px, math.radians(50.0), 3.75)
    assert (fit.p_other_end, fit.boxes, fit.other_end) == (p, n, False)


def test_the_perception_corrects_with_the_layout_the_box_centres_fit():
    """Round a ship with its bridge forward on a known course, the perception's ship model takes the other
    end's outline once the fit decides (an event says so), and its corrected box centres land nearer the
    tracked point's image than with the layout fit off, which keeps the class's bridge aft."""
    from controllers.config import LayoutFitConfig
    heading = 40.0
    ship = Ship(TargetConfig(type="bridge_forward", heading_deg=heading))
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    pose = Pose(*reversed(ship.pose(0.0)))
    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    h = UkfConfig().target_plane_height_m
    course = math.radians(90.0 - heading)
    vel = 3.0 * np.array([math.cos(course), math.sin(course), 0.0])
    prior = TargetState(0.0, "estimator", np.array([0.0, 0.0, h]), vel, 0.1, h)  # (the ship held still here)

    percs = {}
    for on in (False, True):
        cfg = ShipModelConfig(layout_fit=LayoutFitConfig(enabled=on))
        percs[on] = Perception(DetectionGateConfig(), AcquisitionConfig(lock_detections=1),
                               ShipModel(cfg, fsw_cam), fsw_cam, _Events())
        percs[on].lock.locked = True
    errs = {False: [], True: []}
    for k, az in enumerate(list(range(0, 360, 2)) * 2):
        t = k / 1.5
        meas, motion, cp, Rc = _ring_detection(cam, pose, t, az, rng_m=700.0, elevation_deg=40.0)
        p = Rc.T @ (np.array([0.0, 0.0, h]) - cp)
        truth = np.array([fsw_cam.fx * p[0] / p[2] + fsw_cam.cx, fsw_cam.fy * p[1] / p[2] + fsw_cam.cy])
        for on, perc in percs.items():
            fix = perc.step(meas, motion, dataclasses.replace(prior, t_s=t))
            errs[on].append(float(np.hypot(fix.u_px - truth[0], fix.v_px - truth[1])))
    on, off = percs[True], percs[False]
    assert on.ship.layout.other_end and on.ship.outline is on.ship.outlines[1]
    assert not off.ship.layout.other_end and off.ship.outline is off.ship.outlines[0]
    assert any("other end" in e for e in on._record.texts), on._record.texts
    n = len(errs[True]) // 2  # the second time round, the layout decided
    fit_err, class_err = np.mean(errs[True][n:]), np.mean(errs[False][n:])
    assert fit_err < 0.8 * class_err, (fit_err, class_err)


def _shapes_round(ship_type: str, elevation_deg: float = 40.0, heading: float = 40.0):
    """A ShapeHeading (the class's outline) fed the ray-cast boxes of a still ship of ``ship_type`` seen from round
    a ring (700 m, a lap in 4 min), its course given and followed: the posterior, and the course (ENU, rad)."""
    from controllers.config import ShapeHeadingConfig
    from controllers.perception.shape_heading import ShapeHeading
    ship = Ship(TargetConfig(type=ship_type, heading_deg=heading))
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    pose = Pose(*reversed(ship.pose(0.0)))
    shapes = ShapeHeading(ShapeHeadingConfig(), ShipOutline(ShipModelConfig()), PinholeCamera.from_config(CAM_CFG))
    course = math.radians(90.0 - heading)
    for k, az in enumerate(np.arange(0.0, 360.0, 2.0)):
        cp, Rc, frame = _look_from(cam, pose, 700.0, elevation_deg, az)
        shapes.update(k / 1.5, cp, Rc, np.zeros(3), frame.bbox_px, course)
    return shapes, course


@pytest.mark.parametrize("elevation_deg", [25.0, 40.0, 60.0])
def test_the_box_shapes_say_which_end_the_superstructure_stands_at(elevation_deg):
    """The box shapes' posterior is worked out with the class's layout (bridge aft), whose outline turned end
    for end is the other end's: round a ship with its bridge forward on a known course its weight at the
    reverse of the course outweighs its weight at the course (``reverse_log_ratio`` > 0; measured 21.5 and
    13.8 at 25 and 40 deg), round the class's own layout the other way (< 0; -15.1, -7.7). Seen steeply the
    shapes tell the two ends apart no more (60 deg: -0.6 and -0.4; from 50 deg on): the centres' fit decides
    there. Off when bow and stern share their weight, and before the shapes are ready."""
    from controllers.config import ShapeHeadingConfig
    from controllers.perception.shape_heading import ShapeHeading
    fwd, course = _shapes_round("bridge_forward", elevation_deg)
    aft, _ = _shapes_round("bridge_aft", elevation_deg)
    r_fwd, r_aft = fwd.reverse_log_ratio(course), aft.reverse_log_ratio(course)
    if elevation_deg < 45.0:
        assert r_fwd > 5.0 and r_aft < -5.0, (r_fwd, r_aft)
    else:
        assert abs(r_fwd) < 1.0 and abs(r_aft) < 1.0, (r_fwd, r_aft)
    # the reverse's ratio is the course's, negated (to the grid's step)
    assert fwd.reverse_log_ratio(course + math.pi) == pytest.approx(-r_fwd, abs=1e-9)
    cam = PinholeCamera.from_config(CAM_CFG)
    assert ShapeHeading(ShapeHeadingConfig(), ShipOutline(ShipModelConfig()), cam).reverse_log_ratio(0.0) is None
    fwd.cfg = ShapeHeadingConfig(tell_bow_from_stern=False)
    assert fwd.reverse_log_ratio(course) is None


def test_the_layout_fit_weighs_the_box_shapes_evidence_too():
    """``layout_fit.shape_weight``: the window's mean of the boxes' shape log ratios (clipped to
    ``shape_clip``) times the weight is added to the centres' log-odds. With the centres made no evidence (a
    point floor far above their misfits) the probability is the prior's moved by the shapes alone, each way;
    with the weight 0 it is the prior's."""
    from controllers.config import LayoutFitConfig
    from controllers.perception.layout_fit import LayoutFit
    heading = 40.0
    ship = Ship(TargetConfig(type="bridge_aft", heading_deg=heading))
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    pose = Pose(*reversed(ship.pose(0.0)))
    course = math.radians(90.0 - heading)
    cfg = ShipModelConfig()

    def fit_with(ratio: float, **settings) -> LayoutFit:
        fit = LayoutFit(LayoutFitConfig(point_floor_m=50.0, **settings),
                        (ShipOutline(cfg), ShipOutline(cfg, other_end=True)), PinholeCamera.from_config(CAM_CFG))
        for k, az in enumerate(np.arange(0.0, 240.0, 2.0)):
            cp, Rc, frame = _look_from(cam, pose, 700.0, 40.0, az)
            fit.observe(k / 1.5, cp, Rc, np.zeros(3), frame.bbox_px, course, UkfConfig().target_plane_height_m,
                        vel_enu=np.zeros(3), shape_log_ratio=lambda c: ratio)
        return fit

    prior = LayoutFitConfig().prior_other_end
    logit = lambda p: math.log(p / (1.0 - p))  # noqa: E731
    none = fit_with(3.0, shape_weight=0.0)
    assert none.shape_evidence() == 0.0 and abs(none.p_other_end - prior) < 0.01, none.p_other_end
    for ratio, weight in ((3.0, 1.0), (-2.0, 1.0), (30.0, 0.5)):
        fit = fit_with(ratio, shape_weight=weight)
        want = weight * max(-fit.cfg.shape_clip, min(fit.cfg.shape_clip, ratio))
        assert fit.shape_evidence() == pytest.approx(want)
        assert logit(fit.p_other_end) - logit(prior) == pytest.approx(want, abs=0.05), (ratio, fit.p_other_end)
    assert fit_with(4.0).other_end  # the default weight 1: -1.39 + 4 > logit(0.9) = 2.2

