"""What the flight software knows of the target's shape: where a detector's box centre lies.

A detector (YOLO in the paper) returns the box around the ship's visible
silhouette. The UKF (paper eq. 9) treats the box centre as the image of one
point of the ship. It is not: the box centre moves over the ship with the view.
For the paper's ship class (superstructure and mast aft of midships, tapered
bow), rays through the box centre pass 2-3 m aft of midships on average, and
up to ~13 m aft when the ship is seen from astern at 20-30 deg elevation (measured
with the harness's ray-cast camera over elevations 20-75 deg, ranges 250-1500 m).
Close in, perspective adds to it. A terminal dive that trusts the box centre
hits where the box centre points, not the aim point.

This module removes that bias before the UKF sees the detection. The flight
software carries a coarse outline of the ship class (:class:`ShipModelConfig`:
the corner points of hull, deckhouse, wheelhouse, funnel and mast, scaled by
the class's length, width and height). With the current estimate of the
tracked point ``r_q`` (the point ``ukf.target_plane_height_m`` above the ship's
waterline centre) and the ship's course (from the estimated velocity), it
projects the outline into the camera, takes the box of the projected points
(clipped to the image, as the detector's box is) and its centre, and subtracts
that centre's offset from the projection of ``r_q``::

    (u, v)_corrected = (u, v)_detected - [centre(box(project(outline))) - project(r_q)]

so that the corrected pixel is (to first order) the image of ``r_q`` itself,
which is what the UKF's measurement model assumes. When the course is unknown
(estimated speed below ``min_speed_for_course_m_s``) the offset is averaged
over ``headings_when_unknown`` headings: the part that does not depend on the
course (the height of the box centre) is still removed.

What it does not model: the UAV's own wing hiding part of the ship (the box
shrinks; the correction then over- or under-shoots until the wing clears),
and a ship of another class than configured. ``enabled: false`` turns it off
(the paper's plain point model).

The outline is a priori knowledge of the target class (the paper's ship is a
known 55 x 25 x 25 m vessel), configured with the flight software; nothing
here reads the simulated ship (DESIGN.md section 1).
"""
from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from controllers.camera_model import PinholeCamera

__all__ = ["ShipModelConfig", "ShipOutline", "box_centre_offset_px", "predicted_box_px"]

#: points closer than this in front of the camera make the projection meaningless: no correction
_MIN_DEPTH_M = 0.5


class ShipModelConfig(BaseModel):
    """The flight software's outline of the ship class (ship frame: x bow, y port, z up, origin at the
    waterline centre)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    enabled: bool = Field(True, description="correct each detection's box centre for the ship's shape "
                                            "before the UKF update")
    length_m: float = Field(55.0, gt=0, le=500, description="length of the ship class, m (paper: 55)")
    width_m: float = Field(25.0, gt=0, le=200, description="beam of the ship class, m (paper: 25)")
    height_m: float = Field(25.0, gt=0, le=200, description="height above the waterline to the mast top, m "
                                                            "(paper: 25)")
    min_speed_for_course_m_s: float = Field(
        1.5, ge=0, le=50, description="below this estimated speed the ship's course is taken as unknown")
    max_vel_std_for_course_m_s: float = Field(
        1.0, gt=0, le=50, description="above this standard deviation of the estimated velocity the course is "
                                      "taken as unknown")
    headings_when_unknown: int = Field(8, ge=1, le=72, description="headings the offset is averaged over "
                                                                   "when the course is unknown")


class ShipOutline:
    """Corner points of the ship class, ship frame, shape (n, 3).

    Fractions of length L, beam W and height H: hull 0.3 H high with a bow
    tapering to a point over the front 20 % and a chamfered transom; a
    deckhouse (0.32 L .. 0.04 L aft of midships, to 0.5 H), a wheelhouse on it
    (to 0.65 H), a funnel (to 0.85 H) and a mast (to H). The box around a
    silhouette is the box around these points' projections.
    """

    def __init__(self, cfg: ShipModelConfig):
        L, W, H = cfg.length_m, cfg.width_m, cfg.height_m
        hh = 0.3 * H
        pts = []
        hull_xy = [(-0.5 * L, -0.42 * W), (-0.46 * L, -0.5 * W), (0.3 * L, -0.5 * W), (0.5 * L, 0.0),
                   (0.3 * L, 0.5 * W), (-0.46 * L, 0.5 * W), (-0.5 * L, 0.42 * W)]
        for z in (0.0, hh):
            pts += [(x, y, z) for x, y in hull_xy]

        def box(x0, x1, y0, y1, z0, z1):
            return [(x, y, z) for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)]

        solids = [(-0.32 * L, -0.04 * L, -0.36 * W, 0.36 * W, hh, 0.5 * H),  # deckhouse
                  (-0.20 * L, -0.07 * L, -0.42 * W, 0.42 * W, 0.5 * H, 0.65 * H),  # wheelhouse
                  (-0.30 * L, -0.23 * L, -0.08 * W, 0.08 * W, 0.5 * H, 0.85 * H)]  # funnel
        for b in solids:
            pts += box(*b)
        pts += box(-0.145 * L, -0.125 * L, -0.015 * W, 0.015 * W, 0.65 * H, H)  # mast
        self.points_ship_m = np.array(pts, dtype=float)
        #: boxes (lo, hi) a dive can strike: the hull (its bow taper ignored) and the solid superstructure
        #: (the mast is too thin to count on)
        self.solid_boxes_ship_m = [(np.array([-0.5 * L, -0.5 * W, 0.0]), np.array([0.5 * L, 0.5 * W, hh]))] + [
            (np.array([b[0], b[2], b[4]]), np.array([b[1], b[3], b[5]])) for b in solids]

    def entry_depth_m(self, point_ship_m, dir_ship) -> float:
        """How far before ``point_ship_m`` a straight path along ``dir_ship`` (unit, ship frame) first meets
        the ship's solid outline: 0 when the point lies outside it and nothing is in the way."""
        p = np.asarray(point_ship_m, dtype=float)
        d = np.asarray(dir_ship, dtype=float)
        depth = 0.0
        for lo, hi in self.solid_boxes_ship_m:  # slabs: the ray p - s d, s >= 0, inside the box for s in [a, b]
            with np.errstate(divide="ignore", invalid="ignore"):
                t0, t1 = (p - lo) / d, (p - hi) / d  # s where p - s d crosses each face
            inside = (p >= lo) & (p <= hi)
            par = d == 0.0
            if np.any(par & ~inside):
                continue
            a = float(np.max(np.where(par, -np.inf, np.minimum(t0, t1))))
            b = float(np.min(np.where(par, np.inf, np.maximum(t0, t1))))
            if b >= max(a, 0.0):
                depth = max(depth, b)
        return depth


def predicted_box_px(outline: ShipOutline, camera: PinholeCamera, cam_pos_enu_m, R_enu_from_cam, ref_enu_m,
                     course_enu_rad: float) -> np.ndarray | None:
    """The box (u0, v0, u1, v1) around the outline's projection, clipped to the image, or None.

    ``ref_enu_m``: the ship's waterline centre; ``course_enu_rad``: direction of
    the bow, counter-clockwise from East. None when a point is not in front of
    the camera or the box misses the image.
    """
    R_ce = np.asarray(R_enu_from_cam, dtype=float).T
    cs, sn = math.cos(course_enu_rad), math.sin(course_enu_rad)
    R_es = np.array([[cs, -sn, 0.0], [sn, cs, 0.0], [0.0, 0.0, 1.0]])  # ship x (bow) along the course
    p = (outline.points_ship_m @ R_es.T + (np.asarray(ref_enu_m, float) - np.asarray(cam_pos_enu_m, float))) @ R_ce.T
    if np.any(p[:, 2] < _MIN_DEPTH_M):
        return None
    u = camera.fx * p[:, 0] / p[:, 2] + camera.cx
    v = camera.fy * p[:, 1] / p[:, 2] + camera.cy
    W = camera.width_px if camera.width_px > 0 else math.inf
    H = camera.height_px if camera.height_px > 0 else math.inf
    u0, u1 = max(float(u.min()), 0.0), min(float(u.max()), W - 1.0)
    v0, v1 = max(float(v.min()), 0.0), min(float(v.max()), H - 1.0)
    if u0 > u1 or v0 > v1:
        return None
    return np.array([u0, v0, u1, v1])


def box_centre_offset_px(outline: ShipOutline, camera: PinholeCamera, cam_pos_enu_m, R_enu_from_cam,
                         ref_enu_m, course_enu_rad: float | None, tracked_height_m: float,
                         headings_when_unknown: int = 8, box_px: np.ndarray | None = None) -> np.ndarray | None:
    """Expected (detected box centre - image of the tracked point), pixels (2,), or None.

    ``ref_enu_m``: the ship's waterline centre (estimated); the tracked point is
    ``ref + [0, 0, tracked_height_m]``. ``course_enu_rad``: direction of the
    bow, counter-clockwise from East (``atan2(v_n, v_e)``), or None when
    unknown (then the offset is averaged over ``headings_when_unknown``
    headings). None when the ship (or the tracked point) is not wholly in front
    of the camera, or no part of it falls in the image. ``box_px``: the
    :func:`predicted_box_px` for ``course_enu_rad`` when the caller already has it.
    """
    R_ce = np.asarray(R_enu_from_cam, dtype=float).T
    ref = np.asarray(ref_enu_m, dtype=float)
    tracked = R_ce @ (ref + np.array([0.0, 0.0, tracked_height_m]) - np.asarray(cam_pos_enu_m, dtype=float))
    if tracked[2] < _MIN_DEPTH_M:
        return None
    uv_tracked = np.array([camera.fx * tracked[0] / tracked[2] + camera.cx,
                           camera.fy * tracked[1] / tracked[2] + camera.cy])
    courses = [course_enu_rad] if course_enu_rad is not None else \
        [2.0 * math.pi * k / headings_when_unknown for k in range(headings_when_unknown)]
    offsets = []
    for course in courses:
        box = box_px if box_px is not None and course_enu_rad is not None else \
            predicted_box_px(outline, camera, cam_pos_enu_m, R_enu_from_cam, ref, course)
        if box is None:
            return None
        offsets.append((0.5 * (box[0] + box[2]) - uv_tracked[0], 0.5 * (box[1] + box[3]) - uv_tracked[1]))
    return np.mean(np.array(offsets), axis=0)
