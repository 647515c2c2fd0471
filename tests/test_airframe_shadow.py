"""The flight software's model of its own airframe (controllers.perception.airframe) against the harness's ray-cast
camera: the pixels it hides, and the ship boxes it cuts."""
import math

import numpy as np
import pytest

from controllers.config import AirframeConfig, Controllers
from controllers.navigation.camera_model import PinholeCamera
from controllers.perception.airframe import AirframeShadow
from controllers.config import ShipModelConfig
from controllers.perception.ship_outline import ShipOutline, predicted_box_px, projected_points_px
from fwsim.sensors.camera import Camera, CameraConfig, Pose
from fwsim.interface.frames import R_frd_from_cam, dcm_enu_from_frd, pan_tilt_pointing_at
from fwsim.world.geometry import uav_mesh
from fwsim.world.gimbal import camera_pose_world
from fwsim.world.target import Ship, TargetConfig

CAM_CFG = CameraConfig(hfov_deg=60.0)
MOUNT = np.array(CAM_CFG.gimbal.mount_offset_frd_m)


def _shadow() -> AirframeShadow:
    return AirframeShadow(AirframeConfig(enabled=True), PinholeCamera.from_config(CAM_CFG), MOUNT)


def test_the_hidden_pixels_are_the_ray_cast_airframes():
    """Over gimbal angles all round, the rays the model says meet the airframe are those that meet the
    harness's mesh: none it misses; a sliver it takes for hidden along the fuselage's edge (the mesh's
    fuselage is a 16-sided prism inside the 0.06 m cylinder, the model's a 24-sided one round it: 1 mm
    seen from 4 cm below)."""
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    mesh = uav_mesh("fwuav")
    rays = RayMeshIntersector(mesh)
    shadow, cam = _shadow(), PinholeCamera.from_config(CAM_CFG)
    us, vs = np.meshgrid(np.arange(0.0, cam.width_px, 40.0), np.arange(0.0, cam.height_px, 40.0))
    rng = np.random.default_rng(3)
    missed = extra = hidden = 0
    for _ in range(12):
        R = R_frd_from_cam(rng.uniform(-math.pi, math.pi), rng.uniform(-1.5, 0.4))
        mine = shadow.hidden(R, us, vs)
        d = np.stack([(us - cam.cx) / cam.fx, (vs - cam.cy) / cam.fy, np.ones_like(us)], -1).reshape(-1, 3) @ R.T
        truth = rays.intersects_any(np.tile(MOUNT, (len(d), 1)), d).reshape(us.shape)
        missed += int((truth & ~mine).sum())
        extra += int((mine & ~truth).sum())
        hidden += int(truth.sum())
    assert hidden > 300  # the draws look through the airframe often
    assert missed <= 0.01 * hidden
    assert extra <= 0.05 * hidden


def test_a_box_whose_rays_all_climb_too_little_is_never_cut():
    """``may_hide`` is exact where it says no: none of the box's rays meets the airframe."""
    shadow, cam = _shadow(), PinholeCamera.from_config(CAM_CFG)
    rng = np.random.default_rng(4)
    cleared = 0
    for _ in range(200):
        R = R_frd_from_cam(rng.uniform(-math.pi, math.pi), rng.uniform(-1.5, 0.4))
        u0, v0 = rng.uniform(0, cam.width_px - 50), rng.uniform(0, cam.height_px - 50)
        box = np.array([u0, v0, u0 + rng.uniform(10, 400), v0 + rng.uniform(10, 300)])
        if not shadow.may_hide(R, box):
            cleared += 1
            us, vs = np.meshgrid(np.linspace(box[0], box[2], 30), np.linspace(box[1], box[3], 30))
            assert not shadow.hidden(R, us, vs).any()
    assert cleared > 20


def _dive_views():
    """A ship seen from 120-400 m out of a dive or a steep bank, the gimbal on it, the UAV in the rays' way:
    (cam_pos, R_enu_cam, R_frd_cam, ray-cast frame, ship course)."""
    ship = Ship(TargetConfig(heading_deg=30.0))
    cam = Camera(CAM_CFG, uav_mesh("fwuav"), ship.mesh)
    pos_ship, R_ship = ship.pose(0.0)
    course = math.radians(90.0 - 30.0)
    look = np.array([0.0, 0.0, 6.0])
    for rng_m in (120.0, 200.0, 400.0):
        for dep in (25.0, 40.0):
            for az in range(0, 360, 60):
                e, a = math.radians(dep), math.radians(az)
                d = np.array([math.cos(e) * math.sin(a), math.cos(e) * math.cos(a), math.sin(e)])
                pos = look + rng_m * d
                yaw = math.atan2(-d[0], -d[1])
                for roll, pitch in ((0.0, -dep - 8.0), (0.0, -dep - 14.0), (-70.0, -dep), (75.0, -10.0)):
                    euler = np.radians([roll, pitch, 0.0]) + np.array([0.0, 0.0, yaw])
                    R = dcm_enu_from_frd(euler)
                    pan, tilt = pan_tilt_pointing_at(R.T @ (look - (pos + R @ MOUNT)))
                    cp, Rc = camera_pose_world(pos, euler, MOUNT, pan, tilt)
                    frame = cam.detect(0.0, cp, Rc, Pose(R, pos), Pose(R_ship, pos_ship))
                    yield cp, Rc, R_frd_from_cam(pan, tilt), frame, course


def _detection(cp, Rc, R_fc, box, h):
    """A detection of ``box`` from that camera pose, as the flight software gets it (the gimbal's angles from
    the camera's rotation in the body frame), the camera's motion, and the image of the tracked point ``h``
    above the ship's waterline centre (the origin)."""
    from controllers.estimation.ukf import CameraMotion
    from fwsim.interface.messages import Measurements

    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    pan = math.atan2(R_fc[1, 2], R_fc[0, 2])  # the optical axis (camera z) in the body frame
    tilt = math.atan2(-R_fc[2, 2], math.hypot(R_fc[0, 2], R_fc[1, 2]))
    meas = Measurements(0.0, cp, np.zeros(3), np.zeros(3), np.zeros(3), 22.0, float(cp[2]), pan_rad=pan,
                        tilt_rad=tilt, det_new=True, det_valid=True, det_u_px=float(0.5 * (box[0] + box[2])),
                        det_v_px=float(0.5 * (box[1] + box[3])), det_bbox_px=box)
    motion = CameraMotion(0.0, cp, np.zeros(3), Rc, np.zeros(3), float(cp[2]))
    p = Rc.T @ (np.array([0.0, 0.0, h]) - cp)
    return meas, motion, np.array([fsw_cam.fx * p[0] / p[2] + fsw_cam.cx, fsw_cam.fy * p[1] / p[2] + fsw_cam.cy])


def test_a_box_the_airframe_cuts_is_predicted_cut():
    """Where the airframe hides 5-90 % of the ship, the cut prediction is the ray-cast box to within a few
    of the ray cast's strides (the truth's mesh is the class's, the outline coarse); the whole ship's box
    is off by far more. Where it hides none, the prediction is the whole ship's box, unchanged."""
    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    outline = ShipOutline(ShipModelConfig())
    shadow = _shadow()
    cut_err, whole_err, untouched = [], [], 0
    for cp, Rc, R_fc, frame, course in _dive_views():
        if not frame.visible_px:
            continue
        whole = predicted_box_px(outline, fsw_cam, cp, Rc, np.zeros(3), course)
        pts = projected_points_px(outline, fsw_cam, cp, Rc, np.zeros(3), course)
        cut = shadow.cut(R_fc, whole, [pts[s] for s in outline.parts])[0]
        occ = frame.occluded_fraction
        if occ == 0.0 and not shadow.may_hide(R_fc, whole):
            assert np.array_equal(cut, whole)
            untouched += 1
        if 0.05 <= occ <= 0.9:
            scale = frame.stride_px + 1.0
            centre = lambda b: 0.5 * (b[:2] + b[2:])  # noqa: E731
            cut_err.append(np.linalg.norm(centre(cut) - centre(frame.bbox_px)) / scale)
            whole_err.append(np.linalg.norm(centre(whole) - centre(frame.bbox_px)) / scale)
    cut_err, whole_err = np.array(cut_err), np.array(whole_err)
    assert len(cut_err) >= 15 and untouched >= 10
    assert np.median(cut_err) < 2.0, np.sort(cut_err)
    assert np.median(whole_err) > 3.0 * np.median(cut_err)
    assert np.mean(cut_err < whole_err) >= 0.9


def test_a_box_the_airframe_cut_touches_its_silhouette():
    """Every ray-cast box the airframe cut touches the airframe's silhouette (the fits leave such boxes
    out); most whole ones do not."""
    shadow = _shadow()
    cut = clear = whole = 0
    for cp, Rc, R_fc, frame, course in _dive_views():
        if not frame.visible_px:
            continue
        if frame.occluded_fraction >= 0.02:
            assert shadow.touches(R_fc, frame.bbox_px, 6.0)
            cut += 1
        elif frame.occluded_fraction == 0.0:
            whole += 1
            clear += not shadow.touches(R_fc, frame.bbox_px, 6.0)
    assert cut >= 15 and whole >= 20
    assert clear >= 0.5 * whole


def test_the_airframe_settings_are_checked():
    with pytest.raises(ValueError, match="x0 < x1"):
        AirframeConfig(boxes_frd_m=[[0.1, 0.0, -1, 1, -1, 1]])
    with pytest.raises(ValueError, match="tail < nose"):
        AirframeConfig(fuselage_x_m=[0.3, -0.6])
    # the default (docs/results/envelope.mds cut, predicted")
    assert Controllers().airframe.enabled is True
    assert Controllers.model_validate({"airframe": {"enabled": False}}).airframe.enabled is False
    with pytest.raises(ValueError, match="align_iterations"):
        Controllers.model_validate({"airframe": {"align_iterations": -1}})


def test_the_perception_corrects_a_cut_box_by_the_cut():
    """A ship moving on a known course, seen out of a dive through the airframe's edge: the perception with
    the airframe model puts the fix near the image of the tracked point; without it the fix is off by the
    half of the ship the airframe hid. Whole boxes get the same fix either way."""
    from controllers.config import AcquisitionConfig, DetectionGateConfig
    from controllers.estimation.ukf import UkfConfig
    from controllers.messages import TargetState
    from controllers.perception.perception import Perception
    from controllers.perception.target_model import ShipModel

    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    h = UkfConfig().target_plane_height_m
    course = math.radians(90.0 - 30.0)
    vel = 6.0 * np.array([math.cos(course), math.sin(course), 0.0])
    prior = TargetState(0.0, "estimator", np.array([0.0, 0.0, h]), vel, 0.05, h)

    def perception(airframe):
        p = Perception(DetectionGateConfig(min_range_m=0.0, moving_min_range_m=0.0),
                       AcquisitionConfig(lock_detections=1), ShipModel(ShipModelConfig(), fsw_cam), fsw_cam,
                       airframe=airframe)
        p.lock.locked = True
        return p

    errs = {"cut": [], "whole": []}
    for cp, Rc, R_fc, frame, _ in _dive_views():
        if not frame.visible_px:
            continue
        kind = "cut" if 0.05 <= frame.occluded_fraction <= 0.9 else "whole" if frame.occluded_fraction == 0 else None
        if kind is None:
            continue
        meas, motion, truth = _detection(cp, Rc, R_fc, np.asarray(frame.bbox_px, dtype=float), h)
        row = []
        for air in (_shadow(), None):
            fix = perception(air).step(meas, motion, prior)
            row.append(float(np.hypot(fix.u_px - truth[0], fix.v_px - truth[1])) / (frame.stride_px + 1.0))
        errs[kind].append(row)
    cut, whole = np.array(errs["cut"]), np.array(errs["whole"])
    assert len(cut) >= 15 and len(whole) >= 15
    with_model, without = np.median(cut, axis=0)
    assert with_model < 3.0 and without > 3.0 * with_model, (with_model, without)
    assert np.allclose(whole[:, 0], whole[:, 1], atol=0.5)


def test_a_whole_box_next_to_the_airframe_keeps_the_whole_prediction():
    """``cut_only_if_closer``: a detected box that touches the airframe's silhouette but is the whole ship's
    (as when the estimate puts the ship a little into the silhouette and the ship is not there) is corrected
    with the whole ship's prediction; with the rule off it takes the cut one and the fix moves off."""
    from controllers.config import AcquisitionConfig, DetectionGateConfig
    from controllers.estimation.ukf import UkfConfig
    from controllers.messages import TargetState
    from controllers.perception.perception import Perception
    from controllers.perception.target_model import ShipModel

    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    outline = ShipOutline(ShipModelConfig())
    h = UkfConfig().target_plane_height_m
    course = math.radians(90.0 - 30.0)
    vel = 6.0 * np.array([math.cos(course), math.sin(course), 0.0])
    prior = TargetState(0.0, "estimator", np.array([0.0, 0.0, h]), vel, 0.05, h)
    errs = []
    for cp, Rc, R_fc, frame, _ in _dive_views():
        if not (frame.visible_px and 0.1 <= frame.occluded_fraction <= 0.8):
            continue
        box = predicted_box_px(outline, fsw_cam, cp, Rc, np.zeros(3), course)  # the whole ship's box
        meas, motion, truth = _detection(cp, Rc, R_fc, box, h)
        row = []
        for rule in (True, False):
            air = AirframeShadow(AirframeConfig(enabled=True, cut_only_if_closer=rule), fsw_cam, MOUNT)
            gate = DetectionGateConfig(min_range_m=0.0, moving_min_range_m=0.0, size_mismatch_action="deweight")
            per = Perception(gate, AcquisitionConfig(lock_detections=1), ShipModel(ShipModelConfig(), fsw_cam),
                             fsw_cam, airframe=air)
            per.lock.locked = True
            fix = per.step(meas, motion, prior)
            row.append(float(np.hypot(fix.u_px - truth[0], fix.v_px - truth[1])))
        errs.append(row)
    errs = np.array(errs)
    assert len(errs) >= 15
    with_rule, without = np.median(errs, axis=0)
    assert with_rule < 1.0 and without > 10.0 * with_rule, (with_rule, without)


def test_the_cut_gives_the_share_of_the_ship_hidden():
    """The share of the ship's pixels the cut says the airframe hides is the ray cast's, to within a few
    hundredths at the median (the outline is the class's convex parts, the mesh the ship's faces)."""
    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    outline = ShipOutline(ShipModelConfig())
    shadow = _shadow()
    diffs = []
    for cp, Rc, R_fc, frame, course in _dive_views():
        if not frame.visible_px:
            continue
        whole = predicted_box_px(outline, fsw_cam, cp, Rc, np.zeros(3), course)
        pts = projected_points_px(outline, fsw_cam, cp, Rc, np.zeros(3), course)
        box, share = shadow.cut(R_fc, whole, [pts[s] for s in outline.parts])
        if frame.occluded_fraction == 0.0 and share == 0.0:
            assert np.array_equal(box, whole)
        if 0.05 <= frame.occluded_fraction <= 0.9:
            diffs.append(share - frame.occluded_fraction)
    assert len(diffs) >= 15
    assert abs(np.median(diffs)) < 0.05 and np.median(np.abs(diffs)) < 0.1, np.round(np.sort(diffs), 2)


def _perception(airframe, fsw_cam):
    from controllers.config import AcquisitionConfig, DetectionGateConfig
    from controllers.perception.perception import Perception
    from controllers.perception.target_model import ShipModel

    p = Perception(DetectionGateConfig(min_range_m=0.0, moving_min_range_m=0.0),
                   AcquisitionConfig(lock_detections=1), ShipModel(ShipModelConfig(), fsw_cam), fsw_cam,
                   airframe=airframe)
    p.lock.locked = True
    return p


def test_the_cut_is_made_where_the_detection_puts_the_ship():
    """With the estimate 4-8 m off the ship (as it can be at the end of a dive), the cut made where the
    detection puts the ship in the image (``align_iterations``, while the course is unknown; here on the
    ship's own heading) fixes a cut box nearer the tracked point than the cut made where the estimate puts it,
    whose hidden part is not the one the camera saw; with the estimate on the ship the two agree."""
    from controllers.estimation.ukf import UkfConfig
    from controllers.perception.ship_outline import box_centre_offset_px, predicted_boxes_px

    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    h = UkfConfig().target_plane_height_m
    course = math.radians(90.0 - 30.0)
    views = [v for v in _dive_views() if v[3].visible_px and 0.05 <= v[3].occluded_fraction <= 0.5]
    assert len(views) >= 15

    def errors(off) -> np.ndarray:  # (views, [aligned, at the estimate]) fix errors, px
        ref = np.array([off[0], off[1], 0.0])
        out = []
        for cp, Rc, R_fc, frame, _ in views:
            meas, motion, truth = _detection(cp, Rc, R_fc, np.asarray(frame.bbox_px, dtype=float), h)
            row = []
            for n in (3, 0):
                perc = _perception(AirframeShadow(AirframeConfig(enabled=True, align_iterations=n), fsw_cam, MOUNT),
                                   fsw_cam)
                outline = perc.ship.outline
                boxes = predicted_boxes_px(outline, fsw_cam, cp, Rc, ref, [course])
                R = perc._touching_airframe(meas)
                if R is not None:  # cut as the perception cuts a box while the course is unknown
                    boxes, _ = perc._cut_by_airframe(meas, motion, R, ref, [course], None, boxes, course_known=False)
                o = box_centre_offset_px(outline, fsw_cam, cp, Rc, ref, course, h, boxes_px=boxes)
                row.append(float(np.hypot(meas.det_u_px - o[0] - truth[0], meas.det_v_px - o[1] - truth[1])))
            out.append(row)
        return np.array(out)

    on = np.median(errors([0.0, 0.0]), axis=0)
    assert abs(on[0] - on[1]) < 1.0, on
    off = np.vstack([errors(o) for o in ([4.0, 0.0], [8.0, 0.0], [0.0, 8.0], [-5.7, -5.7])])
    aligned, at_estimate = np.median(off, axis=0)
    assert aligned < 0.75 * at_estimate, (aligned, at_estimate)
    assert np.percentile(off[:, 0], 90) < 0.75 * np.percentile(off[:, 1], 90)


def test_a_mostly_hidden_ship_of_unknown_course_is_skipped():
    """A detection of which the cut says the airframe hides more than ``max_hidden_share`` is skipped
    (``airframe_hidden``) while the ship's course is unknown (its heading from the box shapes alone: the cut
    rests on it), and used when the course is known."""
    from controllers.estimation.ukf import UkfConfig
    from controllers.messages import FusionReason, TargetState

    fsw_cam = PinholeCamera.from_config(CAM_CFG)
    h = UkfConfig().target_plane_height_m
    course = math.radians(90.0 - 30.0)
    moving = 6.0 * np.array([math.cos(course), math.sin(course), 0.0])
    skipped = {"known": 0, "unknown": 0}
    heavy = 0
    for cp, Rc, R_fc, frame, _ in _dive_views():
        if not (frame.visible_px and frame.occluded_fraction >= 0.6):
            continue
        heavy += 1
        meas, motion, _ = _detection(cp, Rc, R_fc, np.asarray(frame.bbox_px, dtype=float), h)
        for kind, vel in (("known", moving), ("unknown", np.zeros(3))):
            prior = TargetState(0.0, "estimator", np.array([0.0, 0.0, h]), vel, 0.05, h)
            per = _perception(_shadow(), fsw_cam)
            if kind == "unknown":  # the heading from the box shapes' posterior (flat here)
                per.ship.shape.updates = per.ship.shape.cfg.min_updates
            fix = per.step(meas, motion, prior)
            skipped[kind] += fix.reason == FusionReason.AIRFRAME_HIDDEN
    assert heavy >= 4
    assert skipped["known"] == 0 and skipped["unknown"] >= 0.6 * heavy, (skipped, heavy)
