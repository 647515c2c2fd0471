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
over the headings the box shapes allow (:class:`ShapeHeading`: a still ship's
heading from the sizes of its boxes seen from round the loiter ring), or before
they tell, over ``headings_when_unknown`` headings: the part that does not
depend on the course (the height of the box centre) is still removed. The same
headings drive the box-size check (a detection no plausible heading explains is
skipped), and a ship's axis from the shapes vetoes an estimated velocity
across it (the UKF's error, not a course: ships move along their axis).

A ship of the class's layout but another size is learnt from its boxes
(:class:`ShipSize`, ``size_fit``): its length, beam and height scale the
outline the correction projects once enough boxes have been seen at a known
heading. The UAV's own airframe hiding part of the ship is modelled by the
perception (``controllers.perception.airframe``: the predicted boxes are cut as the
detector's are, :func:`projected_points_px` and :attr:`ShipOutline.parts` give
it the silhouette). What it does not model: a ship of another layout than the
class's (the fit then finds the sizes that best explain the boxes with the
class's layout).
``enabled: false`` turns it off (the paper's plain point model).

The outline is a priori knowledge of the target class (the paper's ship is a
known 55 x 25 x 25 m vessel), configured with the flight software; nothing
here reads the simulated ship (DESIGN.md section 1).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.special

from controllers.config import LayoutFitConfig, ShapeHeadingConfig, ShipModelConfig, SizeFitConfig
from controllers.navigation.camera_model import PinholeCamera, depth_on_plane, ground_from_pixel_jacobian
from fwsim.frames import dcm_ship_from_enu, heading_deg_from_course_enu

__all__ = ["ShipModelConfig", "ShapeHeadingConfig", "ShapeHeading", "ShipModel", "ShipHeadingStatus", "ShipSize",
           "ShipOutline", "box_centre_offset_px",
           "predicted_box_px", "predicted_boxes_px", "projected_points_px"]

#: points closer than this in front of the camera make the projection meaningless: no correction
_MIN_DEPTH_M = 0.5
#: predicted boxes for up to this many courses at once come from a compiled function (beyond, numpy is faster)
_COMPILED_MAX_COURSES = 8
#: the size fit takes a box only when the box shapes' heading weights (a known course fused in) are this
#: concentrated (mean resultant length; 0.98: a circular std of about 11 deg; a bow / stern ambiguity is far
#: below)
_SIZE_FIT_MIN_RESULTANT = 0.98
_ONES3 = np.ones(3)
_ONES3.setflags(write=False)


@dataclass(frozen=True)
class _Points:
    """Corner points (n, 3), ship frame: what :func:`predicted_box_px` projects."""

    points_ship_m: np.ndarray


class ShipOutline:
    """Corner points of the ship class, ship frame, shape (n, 3).

    Fractions of length L, beam W and height H: hull 0.3 H high with a bow
    tapering to a point over the front 20 % and a chamfered transom; a
    deckhouse (0.32 L .. 0.04 L aft of midships, to 0.5 H), a wheelhouse on it
    (to 0.65 H), a funnel (to 0.85 H) and a mast (to H). The box around a
    silhouette is the box around these points' projections. ``other_end``: the
    superstructure (deckhouse, wheelhouse, funnel, mast) mirrored to the other
    end, forward of midships, on the same hull (:class:`LayoutFit`).
    """

    def __init__(self, cfg: ShipModelConfig, other_end: bool = False):
        L, W, H = cfg.length_m, cfg.width_m, cfg.height_m
        hh = 0.3 * H
        pts = []
        hull_xy = [(-0.5 * L, -0.42 * W), (-0.46 * L, -0.5 * W), (0.3 * L, -0.5 * W), (0.5 * L, 0.0),
                   (0.3 * L, 0.5 * W), (-0.46 * L, 0.5 * W), (-0.5 * L, 0.42 * W)]
        for z in (0.0, hh):
            pts += [(x, y, z) for x, y in hull_xy]
        n_hull = len(pts)

        def box(x0, x1, y0, y1, z0, z1):
            return [(x, y, z) for x in (x0, x1) for y in (y0, y1) for z in (z0, z1)]

        solids = [(-0.32 * L, -0.04 * L, -0.36 * W, 0.36 * W, hh, 0.5 * H),  # deckhouse
                  (-0.20 * L, -0.07 * L, -0.42 * W, 0.42 * W, 0.5 * H, 0.65 * H),  # wheelhouse
                  (-0.30 * L, -0.23 * L, -0.08 * W, 0.08 * W, 0.5 * H, 0.85 * H)]  # funnel
        mast = (-0.145 * L, -0.125 * L, -0.015 * W, 0.015 * W, 0.65 * H, H)
        if other_end:  # x -> -x: the superstructure forward of midships
            solids = [(-b[1], -b[0], *b[2:]) for b in solids]
            mast = (-mast[1], -mast[0], *mast[2:])
        for b in solids:
            pts += box(*b)
        n_body = len(pts)
        pts += box(*mast)
        self.points_ship_m = np.array(pts, dtype=float)
        #: the rows of each convex solid (hull, deckhouse, wheelhouse, funnel, mast): a silhouette is the union
        #: of their projections' convex hulls (``controllers.perception.airframe``)
        self.parts = [slice(0, n_hull)] + [slice(k, k + 8) for k in range(n_hull, len(pts), 8)]
        #: the outline without the mast (a detector's box often leaves a thin mast out: the size fit's boxes)
        self.body = _Points(self.points_ship_m[:n_body])
        #: boxes (lo, hi) a dive can strike: the hull (its bow taper ignored) and the solid superstructure
        #: (the mast is too thin to count on)
        self.solid_boxes_ship_m = [(np.array([-0.5 * L, -0.5 * W, 0.0]), np.array([0.5 * L, 0.5 * W, hh]))] + [
            (np.array([b[0], b[2], b[4]]), np.array([b[1], b[3], b[5]])) for b in solids]
        self._solid_lo = np.array([lo for lo, _ in self.solid_boxes_ship_m])  # (k, 3): all the boxes at once
        self._solid_hi = np.array([hi for _, hi in self.solid_boxes_ship_m])

    def entry_depth_m(self, point_ship_m, dir_ship) -> float:
        """How far before ``point_ship_m`` a straight path along ``dir_ship`` (unit, ship frame) first meets
        the ship's solid outline: 0 when the point lies outside it and nothing is in the way."""
        p = np.asarray(point_ship_m, dtype=float)
        d = np.asarray(dir_ship, dtype=float)
        lo, hi = self._solid_lo, self._solid_hi  # a row per box (the boxes' elementwise maths at once)
        # slabs: the ray p - s d, s >= 0, inside the box for s in [a, b]
        with np.errstate(divide="ignore", invalid="ignore"):
            t0, t1 = (p - lo) / d, (p - hi) / d  # s where p - s d crosses each face
        inside = (p >= lo) & (p <= hi)
        par = d == 0.0
        missed = (par & ~inside).any(axis=1)  # parallel to a face pair and outside it
        a = np.where(par, -np.inf, np.minimum(t0, t1)).max(axis=1)
        b = np.where(par, np.inf, np.maximum(t0, t1)).min(axis=1)
        depth = 0.0
        for miss, ak, bk in zip(missed.tolist(), a.tolist(), b.tolist()):
            if not miss and bk >= max(ak, 0.0):
                depth = max(depth, bk)
        return depth


def predicted_box_px(outline: ShipOutline, camera: PinholeCamera, cam_pos_enu_m, R_enu_from_cam, ref_enu_m,
                     course_enu_rad: float, scale=None) -> np.ndarray | None:
    """The box (u0, v0, u1, v1) around the outline's projection, clipped to the image, or None.

    ``ref_enu_m``: the ship's waterline centre; ``course_enu_rad``: direction of
    the bow, counter-clockwise from East. None when a point is not in front of
    the camera or the box misses the image. ``scale``: the outline's length, beam
    and height multiplied by these (3,) (None: the class's).
    """
    uv = projected_points_px(outline, camera, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, course_enu_rad, scale)
    if uv is None:
        return None
    u, v = uv[:, 0], uv[:, 1]
    W = camera.width_px if camera.width_px > 0 else math.inf
    H = camera.height_px if camera.height_px > 0 else math.inf
    u0, u1 = max(float(u.min()), 0.0), min(float(u.max()), W - 1.0)
    v0, v1 = max(float(v.min()), 0.0), min(float(v.max()), H - 1.0)
    if u0 > u1 or v0 > v1:
        return None
    return np.array([u0, v0, u1, v1])


def projected_points_px(outline: ShipOutline, camera: PinholeCamera, cam_pos_enu_m, R_enu_from_cam, ref_enu_m,
                        course_enu_rad: float, scale=None) -> np.ndarray | None:
    """The outline's corner points in the image, (n, 2) pixels (not clipped), or None when one is not in front
    of the camera (as :func:`predicted_box_px`)."""
    R_ce = np.asarray(R_enu_from_cam, dtype=float).T
    cs, sn = math.cos(course_enu_rad), math.sin(course_enu_rad)
    R_es = np.array([[cs, -sn, 0.0], [sn, cs, 0.0], [0.0, 0.0, 1.0]])  # ship x (bow) along the course
    pts = outline.points_ship_m if scale is None else outline.points_ship_m * np.asarray(scale, dtype=float)
    p = (pts @ R_es.T + (np.asarray(ref_enu_m, float) - np.asarray(cam_pos_enu_m, float))) @ R_ce.T
    if (p[:, 2] < _MIN_DEPTH_M).any():
        return None
    return np.stack([camera.fx * p[:, 0] / p[:, 2] + camera.cx, camera.fy * p[:, 1] / p[:, 2] + camera.cy], axis=1)


def predicted_boxes_px(outline: ShipOutline, camera: PinholeCamera, cam_pos_enu_m, R_enu_from_cam, ref_enu_m,
                       courses_enu_rad, scale=None) -> np.ndarray:
    """:func:`predicted_box_px` for many courses at once: (n, 4), a row of NaN where that function gives None.

    A few courses (the perception's, every detection) go through one compiled function
    (:class:`_CompiledBoxes`), many (the heading posterior's 72) through numpy, which is faster for them:
    :func:`predicted_boxes_px_numpy`, the same numbers to rounding. ``scale``: as :func:`predicted_box_px`."""
    c = np.asarray(courses_enu_rad, dtype=float)
    if c.size == 0 or c.size > _COMPILED_MAX_COURSES:
        return predicted_boxes_px_numpy(outline, camera, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, c, scale)
    W = camera.width_px if camera.width_px > 0 else math.inf
    H = camera.height_px if camera.height_px > 0 else math.inf
    return _CompiledBoxes.for_outline(outline)(c, (camera.fx, camera.fy, camera.cx, camera.cy, W - 1.0, H - 1.0),
                                              cam_pos_enu_m, R_enu_from_cam, ref_enu_m,
                                              _ONES3 if scale is None else scale)


class _CompiledBoxes:
    """The predicted boxes of one outline as CasADi functions (one per number of courses, built on first use)."""

    _cache: dict[int, "_CompiledBoxes"] = {}

    @classmethod
    def for_outline(cls, outline: ShipOutline) -> "_CompiledBoxes":
        key = id(outline)
        hit = cls._cache.get(key)
        if hit is None or hit.outline is not outline:
            hit = cls._cache[key] = cls(outline)
        return hit

    def __init__(self, outline: ShipOutline):
        self.outline = outline
        self._funs: dict[int, object] = {}

    def _function(self, n: int):
        fun = self._funs.get(n)
        if fun is None:
            import casadi as ca

            from controllers.compiled import Buffered
            pts = self.outline.points_ship_m
            c, k = ca.SX.sym("c", n), ca.SX.sym("k", 6)  # courses; fx, fy, cx, cy, W - 1, H - 1
            cam, R, ref = ca.SX.sym("cam", 3), ca.SX.sym("R", 3, 3), ca.SX.sym("ref", 3)
            sc = ca.SX.sym("s", 3)  # the outline's scale (length, beam, height); times 1 is exact
            rel = ref - cam
            px, py, pz = ca.DM(pts[:, 0]) * sc[0], ca.DM(pts[:, 1]) * sc[1], ca.DM(pts[:, 2]) * sc[2]
            rows = []
            for i in range(n):  # one course: the outline turned, moved, seen by the camera
                cs, sn = ca.cos(c[i]), ca.sin(c[i])
                e0 = cs * px - sn * py + rel[0]
                e1 = sn * px + cs * py + rel[1]
                e2 = pz + rel[2]
                p = [e0 * R[0, j] + e1 * R[1, j] + e2 * R[2, j] for j in range(3)]  # (enu @ R_ce.T)[:, j]
                ok = ca.mmin(p[2]) >= _MIN_DEPTH_M
                zs = ca.if_else(p[2] >= _MIN_DEPTH_M, p[2], 1.0)
                u = k[0] * p[0] / zs + k[2]
                v = k[1] * p[1] / zs + k[3]
                box = ca.vertcat(ca.fmax(ca.mmin(u), 0.0), ca.fmax(ca.mmin(v), 0.0),
                                 ca.fmin(ca.mmax(u), k[4]), ca.fmin(ca.mmax(v), k[5]))
                ok = ca.logic_and(ok, ca.logic_and(box[0] <= box[2], box[1] <= box[3]))
                rows.append(ca.if_else(ok, box, ca.DM.nan(4, 1)))
            fun = self._funs[n] = Buffered(ca.Function(f"ship_boxes_{n}", [c, k, cam, R, ref, sc],
                                                       [ca.horzcat(*rows)]))
        return fun

    def __call__(self, courses, k, cam_pos, R_enu_from_cam, ref, scale=_ONES3) -> np.ndarray:
        out = self._function(len(courses))(courses, k, cam_pos, np.asarray(R_enu_from_cam, dtype=float).T.ravel(),
                                           ref, scale)[0]
        return out.reshape(len(courses), 4).copy()


def predicted_boxes_px_numpy(outline: ShipOutline, camera: PinholeCamera, cam_pos_enu_m, R_enu_from_cam, ref_enu_m,
                             courses_enu_rad, scale=None) -> np.ndarray:
    """:func:`predicted_boxes_px` in numpy."""
    c = np.asarray(courses_enu_rad, dtype=float)
    R_ce = np.asarray(R_enu_from_cam, dtype=float).T
    pts = outline.points_ship_m if scale is None else outline.points_ship_m * np.asarray(scale, dtype=float)
    cs, sn = np.cos(c)[:, None], np.sin(c)[:, None]
    rel = np.asarray(ref_enu_m, float) - np.asarray(cam_pos_enu_m, float)
    px, py = pts[:, 0], pts[:, 1]
    # the outline turned and moved, (n, m, 3), written in place (the elementwise operations of
    # cs px - sn py + rel_e, sn px + cs py + rel_n, pz + rel_u)
    enu = np.empty((len(c), len(pts), 3))
    np.subtract(cs * px, sn * py, out=enu[..., 0])
    enu[..., 0] += rel[0]
    np.add(sn * px, cs * py, out=enu[..., 1])
    enu[..., 1] += rel[1]
    enu[..., 2] = pts[:, 2] + rel[2]
    p = enu @ R_ce.T
    z = p[..., 2]
    front = z >= _MIN_DEPTH_M
    ok = front.all(axis=1)
    zs = np.where(front, z, 1.0)
    u = camera.fx * p[..., 0]  # fx x / z + cx, in place
    u /= zs
    u += camera.cx
    v = camera.fy * p[..., 1]
    v /= zs
    v += camera.cy
    W = camera.width_px if camera.width_px > 0 else math.inf
    H = camera.height_px if camera.height_px > 0 else math.inf
    box = np.empty((len(c), 4))
    np.maximum(u.min(axis=1), 0.0, out=box[:, 0])
    np.maximum(v.min(axis=1), 0.0, out=box[:, 1])
    np.minimum(u.max(axis=1), W - 1.0, out=box[:, 2])
    np.minimum(v.max(axis=1), H - 1.0, out=box[:, 3])
    ok &= (box[:, 0] <= box[:, 2]) & (box[:, 1] <= box[:, 3])
    box[~ok] = np.nan
    return box


class ShapeHeading:
    """The ship's heading from the sizes of its detected boxes: a posterior over ``cfg.headings`` headings.

    The width and height of the box around the silhouette depend on the ship's heading relative to the line
    of sight, so a loiter round the ship, which sees it from many bearings, tells its heading (often up to
    bow or stern: where the two differ in the model's box sizes, the fit picks the right one). Each used
    detection adds, for every candidate heading, the robust (Cauchy) log-likelihood of its box sides against
    :func:`predicted_boxes_px` for that heading, for each of a grid of size biases (the detected widths, and
    apart the heights, off the model's by one unknown fraction, ``size_bias_range``), which each heading's
    likelihood is marginalised over; the posterior is tempered so that it never counts more than
    ``max_effective_updates`` detections. A detection whose box touches the image border says nothing of the
    size and is not used; nor is one taken less than ``1 / rate_hz`` after the last used one.

    A ship may turn while its course is unknown (a slow ship turning or zigzagging: nothing to follow). Each
    of ``turn_rates_deg_s`` is a hypothesis with evidence of its own, each box weighed at the heading that rate
    would have turned the ship to since the first (to the grid's step); the posterior over the heading now
    sums them, weighted by their likelihoods and a prior (``turn_rate_prior_zero`` on rate 0). ``memory_s``
    fades the evidence meanwhile, so that a turn no one rate fits (a zigzag) is weighed at the headings of
    late. Once the course is followed again, the likeliest rate's evidence is kept alone (the
    course turns the posterior from then on).

    The box sizes come from the flight software's coarse outline (a priori knowledge of the ship class) and
    its own estimate of where the ship is: nothing here reads the simulated ship.
    """

    def __init__(self, cfg: ShapeHeadingConfig, outline: ShipOutline, camera: PinholeCamera, edge_px: float = 6.0):
        self.cfg = cfg
        self.outline = outline
        self.camera = camera
        self.edge_px = float(edge_px)
        self.courses_enu_rad = 2.0 * math.pi * np.arange(cfg.headings) / cfg.headings
        lo, hi = cfg.size_bias_range
        self.size_biases = np.linspace(lo, hi, cfg.size_bias_steps) if hi > lo else np.array([lo])
        # the turn rates while the course is unknown (turn_rates_deg_s), as course rates (counter-clockwise,
        # rad/s), their a priori log weights, and how far each has turned the ship since the first box (rad):
        # rate j's evidence at grid index k is for the course courses[k] + _rot[j] now
        rates = np.asarray(cfg.turn_rates_deg_s, dtype=float)
        self.turn_rates_rad_s = -np.radians(rates)
        zero = rates == 0.0
        if zero.any() and len(rates) > 1:
            prior = np.where(zero, cfg.turn_rate_prior_zero, (1.0 - cfg.turn_rate_prior_zero) / (len(rates) - 1))
        else:
            prior = np.full(len(rates), 1.0 / len(rates))
        self._log_rate_prior = np.log(np.maximum(prior, 1e-300))
        self._rot = np.zeros(len(rates))
        self._one_rate = True  # every rate's evidence is the same, turned alike (_keep_likeliest_rate)
        # per rate: bias, heading, (width, height): bias-major, so that the marginalisation's reductions over
        # the biases run down whole rows
        self._loglik_bias = [np.zeros((len(self.size_biases), cfg.headings, 2)) for _ in rates]
        self._loglik_rate = np.zeros((len(rates), cfg.headings))  # marginalised over the size bias
        self.updates = 0
        self._count = 0.0  # the updates the evidence holds (fewer than updates when it fades, memory_s)
        self._last_t = -math.inf
        self._weights = None  # weights() of the current loglik (it is asked for several times per detection)
        self._axis = None  # axis_enu_rad() of the current loglik
        self._course = None  # the estimated course at the last used detection (None: not followed then)

    def update(self, t_s: float, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, box_px,
               course_enu_rad: float | None = None) -> bool:
        """Use one detected box (u0, v0, u1, v1); True when it was used. ``course_enu_rad``: the ship's
        estimated course now when it is sure enough to follow (``follow_course``), else None: the posterior
        turns by the course's change since the last used detection before this box is added."""
        c = self.cfg
        b = np.asarray(box_px, dtype=float)
        if not c.enabled or t_s - self._last_t < 1.0 / c.rate_hz - 1e-9 or not np.all(np.isfinite(b)):
            return False
        cam = self.camera
        if _at_image_border(cam, b, self.edge_px):
            return False
        pred = predicted_boxes_px(self.outline, cam, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, self.courses_enu_rad)
        if not np.all(np.isfinite(pred)):
            return False
        self._move_on(t_s - self._last_t if self.updates else 0.0, course_enu_rad)
        size_det = np.array([b[2] - b[0], b[3] - b[1]])
        size_now = np.stack([pred[:, 2] - pred[:, 0], pred[:, 3] - pred[:, 1]], axis=1)
        for j, (lb, shift) in enumerate(zip(self._loglik_bias, self._shifts())):
            # rate j's evidence at grid index k is for the heading courses[k + shift] now (to the grid's step)
            size_pred = size_now if not shift else np.roll(size_now, -shift, axis=0)
            scaled = size_pred[None, :, :] * (1.0 + self.size_biases)[:, None, None]  # (biases, headings, 2)
            r = (size_det[None, None, :] - scaled) / (c.sigma_fraction * scaled + c.sigma_px)
            lb -= np.log1p(0.5 * r * r)
            self._loglik_rate[j] = np.sum(_logsumexp_rows(lb), axis=1)
        self.updates += 1
        self._count += 1.0
        self._weights = self._axis = None
        self._last_t = t_s
        return True

    def _move_on(self, dt: float, course_enu_rad: float | None) -> None:
        """Before a box ``dt`` after the last one: turn the posterior with the followed course, or (the course
        not followed) turn each rate's evidence by its rate and fade it (``memory_s``)."""
        c = self.cfg
        if c.follow_course:
            if course_enu_rad is not None and self._course is not None and self.updates:
                most = math.radians(c.follow_course_max_rate_deg_s) * dt
                d = (course_enu_rad - self._course + math.pi) % (2.0 * math.pi) - math.pi
                self.turn(min(max(d, -most), most))
            self._course = None if course_enu_rad is None else float(course_enu_rad)
        if course_enu_rad is not None and len(self._rot) > 1 and not self._one_rate:
            self._keep_likeliest_rate()  # the course turns the ship now: no rate of its own to tell apart
        if course_enu_rad is None and dt > 0.0:
            # the course is not followed: each rate turns the ship on by itself, and the evidence fades
            self._one_rate = False
            self._rot += self.turn_rates_rad_s * dt
            if c.memory_s is not None:
                f = math.exp(-dt / c.memory_s)
                for lb in self._loglik_bias:
                    lb *= f
                self._count *= f

    def turn(self, angle_rad: float) -> None:
        """The ship has turned by ``angle_rad`` (counter-clockwise): the evidence for each heading moves to the
        heading that much further round (linear interpolation between the grid's neighbours)."""
        s = float(angle_rad) / (2.0 * math.pi / self.cfg.headings)
        if not s:
            return
        i = math.floor(s)
        f = s - i
        # evidence that was at heading k - s now belongs to heading k
        for j, lb in enumerate(self._loglik_bias):
            a = _roll_headings(lb, i)
            self._loglik_bias[j] = a if f == 0.0 else (1.0 - f) * a + f * _roll_headings(lb, i + 1)
            self._loglik_rate[j] = np.sum(_logsumexp_rows(self._loglik_bias[j]), axis=1)
        self._weights = self._axis = None

    def weights(self) -> np.ndarray:
        """Posterior weight of each candidate heading (sums to 1; uniform before any update). Unless
        ``tell_bow_from_stern``, a heading and its opposite share their summed weight equally."""
        if self._weights is None:
            self._weights = self._posterior()
        return self._weights.copy()

    def _keep_likeliest_rate(self) -> None:
        """Once the course is followed, the ship's turn is the course's: every rate's evidence becomes the most
        likely rate's (moved to the headings now), with no turn of its own, until the course is lost again.
        (A ship whose course is known most of the time is then weighed as with the one rate 0, bar the boxes
        of the seconds before its course was known.)"""
        j = int(np.argmax(self.rate_weights()))
        best = np.roll(self._loglik_bias[j], self._shifts()[j], axis=1)
        self._loglik_bias = [best.copy() for _ in self._loglik_bias]
        self._loglik_rate[:] = np.sum(_logsumexp_rows(best), axis=1)
        self._rot[:] = 0.0
        self._one_rate = True
        self._weights = self._axis = None

    def _shifts(self) -> list[int]:
        """How many grid steps each rate has turned the ship since the first box (to the nearest step)."""
        return [int(k) for k in np.rint(self._rot / (2.0 * math.pi / self.cfg.headings))]

    def _now_rows(self) -> np.ndarray:
        """Each rate's log-likelihood row moved to the headings now (:meth:`_shifts`)."""
        shifts = self._shifts()
        if not any(shifts):
            return self._loglik_rate
        return np.stack([np.roll(row, s) for row, s in zip(self._loglik_rate, shifts)])

    def _tempered_log_weights(self) -> np.ndarray:
        """(rates, headings now): each rate's a priori log weight plus its tempered log-likelihood (the
        posterior never counts more than ``max_effective_updates`` detections), less the largest."""
        lr = self._now_rows()
        scale = min(1.0, self.cfg.max_effective_updates / max(self._count, 1.0))
        lw = self._log_rate_prior[:, None] + scale * (lr - np.max(lr))
        return lw - np.max(lw)

    def rate_weights(self) -> np.ndarray:
        """Posterior weight of each of ``turn_rates_deg_s`` (tempered as the headings' are)."""
        w = np.sum(np.exp(self._tempered_log_weights()), axis=1)
        return w / np.sum(w)

    def _posterior(self) -> np.ndarray:
        w = np.sum(np.exp(self._tempered_log_weights()), axis=0)
        w = w / np.sum(w)
        n = len(w)
        if not self.cfg.tell_bow_from_stern and n % 2 == 0:
            w = 0.5 * _with_opposite(w)
        return w

    def axis_enu_rad(self) -> float:
        """Direction of the ship's fore-aft axis (counter-clockwise from East, in [0, pi)): the most likely
        heading folded onto its opposite (kept until the next update)."""
        if self._weights is None or self._axis is None:
            w = self.weights()
            n = len(w)
            k = int(np.argmax(_with_opposite(w)[: n // 2])) if n % 2 == 0 else int(np.argmax(w))
            self._axis = float(self.courses_enu_rad[k]) % math.pi
        return self._axis

    @property
    def ready(self) -> bool:
        return self.cfg.enabled and self.updates >= self.cfg.min_updates

    def headings(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(courses, weights) of the plausible headings (weights renormalised), or None while not ready."""
        w = self.heading_weights()
        return None if w is None else _plausible(self.courses_enu_rad, w, self.cfg.min_weight)

    def heading_weights(self) -> np.ndarray | None:
        """The weight of every heading of the grid (:attr:`courses_enu_rad`), or None while not ready."""
        if not self.ready:
            return None
        return self.weights()

    def reverse_log_ratio(self, course_enu_rad: float) -> float | None:
        """The log of the posterior's weight at the reverse of ``course_enu_rad`` over its weight at it (the
        grid's nearest heading), or None while not ready or when bow and stern share their weight
        (``tell_bow_from_stern`` off). Worked out with the class's layout, whose outline turned end for end is
        the other end's (:class:`ShipOutline` ``other_end``; the hull is the same either way round): with the
        course known, it is the shapes' evidence that the superstructure stands at the other end."""
        n = self.cfg.headings
        if not self.ready or not self.cfg.tell_bow_from_stern or n % 2:
            return None
        lw = _logsumexp_rows(self._tempered_log_weights())  # (headings,): the posterior's log, unnormalised
        k = int(round(float(course_enu_rad) / (2.0 * math.pi / n))) % n
        return float(lw[(k + n // 2) % n] - lw[k])

    def off_axis_rad(self, course_enu_rad: float) -> float:
        """How far (rad, 0..pi/2) a direction lies off the ship's axis."""
        d = (course_enu_rad - self.axis_enu_rad()) % math.pi
        return min(d, math.pi - d)


def _at_image_border(camera: PinholeCamera, b: np.ndarray, e: float) -> bool:
    """A box ``b`` (u0, v0, u1, v1) within ``e`` px of the image's border (the ship may be cut there: its size
    and centre are not the whole ship's); never for a camera without an image size."""
    return camera.width_px > 0 and bool(b[0] <= e or b[1] <= e or b[2] >= camera.width_px - 1.0 - e
                                        or b[3] >= camera.height_px - 1.0 - e)


def _pixel_on_plane(camera: PinholeCamera, uv, cam_pos: np.ndarray, R: np.ndarray, plane_z: float):
    """(the point (3,) where pixel ``uv``'s ray meets the plane z = ``plane_z``, its normalised image
    coordinates x1, x2), or None where the ray does not come down to it
    (:func:`~controllers.navigation.camera_model.depth_on_plane`)."""
    x1, x2 = (float(uv[0]) - camera.cx) / camera.fx, (float(uv[1]) - camera.cy) / camera.fy
    Z = depth_on_plane(x1, x2, R, float(cam_pos[2]), plane_z)
    if not math.isfinite(Z):
        return None
    return cam_pos + Z * (R @ np.array([x1, x2, 1.0])), x1, x2


def _course_likelihood(courses: np.ndarray, course: float, sig_rad: float) -> np.ndarray:
    """The Gaussian likelihood (unnormalised) of each of ``courses`` under ``course`` with std ``sig_rad``,
    the difference taken round the circle."""
    d = (courses - course + math.pi) % (2.0 * math.pi) - math.pi
    return np.exp(-0.5 * (d / sig_rad) ** 2)


def _with_opposite(w: np.ndarray) -> np.ndarray:
    """Each heading's weight plus its opposite's (bow and stern swapped), on a grid of an even count of headings
    all round."""
    return w + np.roll(w, len(w) // 2)


def _plausible(courses: np.ndarray, w: np.ndarray, min_weight: float) -> tuple[np.ndarray, np.ndarray]:
    """(courses, weights) of the headings with at least ``min_weight`` of the largest weight, renormalised (the
    array methods: np.max's and np.sum's numbers, without their wrappers)."""
    keep = w >= min_weight * w.max()
    wk = w[keep]
    return courses[keep], wk / wk.sum()


def _roll_headings(a: np.ndarray, k: int) -> np.ndarray:
    """``np.roll(a, k, axis=1)`` (the same array) by two slices, without its general-case overhead."""
    n = a.shape[1]
    k %= n
    return np.concatenate((a[:, n - k:], a[:, :n - k]), axis=1)


def _logsumexp_rows(a: np.ndarray) -> np.ndarray:
    """``scipy.special.logsumexp(a, axis=0)``: for finite ``a`` its very operations (the same numbers, bit for
    bit: the largest entries of a column taken out, counted and added back in log) without its array-API
    dispatch, which costs most of its time on the posterior's few thousand entries; else scipy's own."""
    if np.isfinite(a).all():
        a_max = a.max(axis=0)
        top = a == a_max
        m = top.sum(axis=0, dtype=float)
        e = np.exp(a - a_max)
        e[top] = 0.0  # (scipy's exp(-inf - a_max))
        s = e.sum(axis=0)
        s = np.where(s == 0, s, s / m)
        out = np.log1p(s) + np.log(m) + a_max
        if np.isfinite(out).all():
            return out
    return scipy.special.logsumexp(a, axis=0)


def _weighted_mean_rows(a: np.ndarray, weights) -> np.ndarray:
    """``np.average(a, axis=0, weights=weights)`` for rows ``a`` (n, k), with its very reductions (the same
    numbers, bit for bit) but not its argument checks, which cost most of its time on a few rows.
    ``weights=None``: the plain mean (np.average's own: the array's mean)."""
    if weights is None:
        return a.mean(axis=(0,))
    w = np.asarray(weights, dtype=float).reshape(-1, 1)
    scl = w.sum(axis=(0,))
    if not scl.all():
        raise ZeroDivisionError("Weights sum to zero, can't be normalized")
    return np.multiply(a, w).sum(axis=(0,)) / scl


def _weighted_cov_rows(a: np.ndarray, weights, mean: np.ndarray) -> np.ndarray:
    """Weighted covariance (k x k) of the rows ``a`` (n, k) about ``mean`` (weights None: equal; normalised
    by their sum, not debiased: the spread of a known discrete set, not an estimate from samples)."""
    d = a - mean[None, :]
    w = np.full(a.shape[0], 1.0 / a.shape[0]) if weights is None else np.asarray(weights, dtype=float) / float(
        np.asarray(weights).sum())
    return (d * w[:, None]).T @ d


def box_centre_offset_px(outline: ShipOutline, camera: PinholeCamera, cam_pos_enu_m, R_enu_from_cam,
                         ref_enu_m, course_enu_rad: float | None, tracked_height_m: float,
                         headings_when_unknown: int = 8, boxes_px: np.ndarray | None = None,
                         courses_weights: tuple[np.ndarray, np.ndarray] | None = None,
                         spread: bool = False, scale=None):
    """Expected (detected box centre - image of the tracked point), pixels (2,), or None.

    ``ref_enu_m``: the ship's waterline centre (estimated); the tracked point is
    ``ref + [0, 0, tracked_height_m]``. ``course_enu_rad``: direction of the
    bow, counter-clockwise from East (``atan2(v_n, v_e)``), or None when
    unknown (then the offset is averaged over ``headings_when_unknown``
    headings). None when the ship (or the tracked point) is not wholly in front
    of the camera, or no part of it falls in the image. ``boxes_px``: the caller's
    :func:`predicted_boxes_px` rows for the courses used (``course_enu_rad``, or those of
    ``courses_weights``), so that they are not projected twice. ``courses_weights``:
    with an unknown course, the headings to average over and their weights (:meth:`ShapeHeading.headings`)
    instead of ``headings_when_unknown`` equal ones. ``spread``: return ``(offset, cov)`` instead, ``cov``
    (2 x 2, px^2) the weighted covariance of the offsets over those headings: how far the averaged offset can
    be from the one of the ship's real heading (zeros for one known course); ``None`` as above. ``scale``:
    the outline's (:func:`predicted_box_px`; ``boxes_px`` must be of it too).
    """
    R_ce = np.asarray(R_enu_from_cam, dtype=float).T
    ref = np.asarray(ref_enu_m, dtype=float)
    tracked = R_ce @ (ref + np.array([0.0, 0.0, tracked_height_m]) - np.asarray(cam_pos_enu_m, dtype=float))
    if tracked[2] < _MIN_DEPTH_M:
        return None
    uv_tracked = np.array([camera.fx * tracked[0] / tracked[2] + camera.cx,
                           camera.fy * tracked[1] / tracked[2] + camera.cy])
    weights = None
    if course_enu_rad is None and courses_weights is not None:
        weights = np.asarray(courses_weights[1], dtype=float)
    if boxes_px is not None:  # all at once (the same numbers as one by one below)
        b = np.asarray(boxes_px, dtype=float)
        if not np.isfinite(b).all():
            return None
        offsets = 0.5 * (b[:, 0:2] + b[:, 2:4]) - uv_tracked  # (n, 2): the box centres' (u, v) offsets
        mean = _weighted_mean_rows(offsets, weights)
        return (mean, _weighted_cov_rows(offsets, weights, mean)) if spread else mean
    if course_enu_rad is not None:
        courses = [course_enu_rad]
    elif courses_weights is not None:
        courses = list(courses_weights[0])
    else:
        courses = [2.0 * math.pi * k / headings_when_unknown for k in range(headings_when_unknown)]
    offsets = []
    for i, course in enumerate(courses):
        box = boxes_px[i] if boxes_px is not None else \
            predicted_box_px(outline, camera, cam_pos_enu_m, R_enu_from_cam, ref, course, scale)
        if box is None or not np.all(np.isfinite(box)):
            return None
        offsets.append((0.5 * (box[0] + box[2]) - uv_tracked[0],
                        0.5 * (box[1] + box[3]) - uv_tracked[1]))
    offsets = np.array(offsets)
    mean = _weighted_mean_rows(offsets, weights)
    return (mean, _weighted_cov_rows(offsets, weights, mean)) if spread else mean


class ShipSize:
    """The ship's length, beam and height as multiples of the class's, fitted to the sizes of its boxes.

    The box-centre correction is only as good as the outline it projects: a ship 30 % taller than the class
    has its box centre higher than the class's, and the corrected point, taken for the tracked point on the
    sea, lies that height over the tangent of the view's depression farther along the line of sight (in a
    -30 deg dive, 4 m for a 25 m class). The boxes tell the real sizes: seen from round the loiter ring
    their widths and heights mix the length, beam and height differently with every relative heading.

    Each box seen at a sure heading (the box shapes' headings with a known course fused in, their weighted
    mean; at most ``rate_hz`` boxes a second, consecutive frames being nearly alike) updates the log scales
    ``theta = log(L / L_class, W / W_class, H / H_class)`` with an extended Kalman step on
    ``log(box width, height) - log(predicted width, height at theta)``, the prediction midway (in log) between
    the outline without its mast and with it, half their difference in the box's noise (a thin mast is not
    in a far box; close in it shows: fitted to the outline with it a ship exactly of the class came out 8 %
    low, to the one without it up to 22 % tall in a shallow dive), its Jacobian by finite differences, prior
    N(0, prior_std^2) per axis, a chi-square gate against boxes cut short (the UAV's own airframe in view),
    and a fresh start from the prior when it has turned ``max_gated_in_a_row`` boxes away in a row (then the
    fit is off, not the boxes); a box's noise grows as it gets small (``box_px_std`` over its size); a box at
    the image's edge is not taken at all. After ``min_updates`` boxes the perception corrects with the fitted
    outline (:attr:`scale`, the whole outline scaled); before, with the class's, and for good once the fit has
    started again ``class_after_restarts`` times (:attr:`retired`).

    The ranges come from the estimate, so the fitted scale carries its range error (1 % at 500 m for 5 m):
    harmless to the correction, which scales with it.
    """

    _STEP = 0.02  # finite-difference step of the log scales
    _STEP_FACTORS = np.exp(_STEP * np.eye(3))  # a step in each log scale, as factors of the scales

    def __init__(self, cfg: SizeFitConfig, outline: ShipOutline, camera: PinholeCamera, edge_px: float = 6.0):
        self.cfg = cfg
        self.outline = outline
        self.camera = camera
        self.edge_px = edge_px
        self.x = np.zeros(3)
        self.P = np.eye(3) * cfg.prior_std ** 2
        self.updates = 0
        self.gated = 0
        self.gated_in_a_row = 0
        self.restarts = 0
        self.retired = False  # the class's outline for good (class_after_restarts)
        self._last_t = -math.inf  # when the last box was weighed

    def takes_boxes(self, t_s: float | None = None) -> bool:
        """Whether a box at ``t_s`` would be looked at: the fit on, not retired, ``1 / rate_hz`` after the last
        box weighed (None: no rate limit)."""
        return self.cfg.enabled and not self.retired and (
            t_s is None or t_s - self._last_t >= 1.0 / self.cfg.rate_hz - 1e-9)

    @property
    def theta(self) -> np.ndarray:
        """The log scales (length, beam, height)."""
        return self.x[:3]

    @property
    def scale(self) -> np.ndarray | None:
        """The fitted (length, beam, height) multipliers once in use, else None (the class's outline)."""
        if not self.cfg.enabled or self.retired or self.updates < self.cfg.min_updates:
            return None
        return np.exp(self.x[:3])

    def update(self, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, course_enu_rad: float, box_px,
               t_s: float | None = None) -> bool:
        """Take one detected box seen with the ship on ``course_enu_rad`` (its waterline centre ``ref_enu_m``,
        estimated) at ``t_s`` (None: whenever, no rate limit); True when it moved the fit. A box within
        ``1 / rate_hz`` of the last one weighed (taken or gated) is not looked at."""
        cfg = self.cfg
        if not self.takes_boxes(t_s):
            return False
        b = np.asarray(box_px, dtype=float)
        cam = self.camera
        if b.shape != (4,) or not np.isfinite(b).all() or b[2] - b[0] < 2.0 or b[3] - b[1] < 2.0:
            return False
        if _at_image_border(cam, b, self.edge_px):
            return False  # a box at the image's edge is cut: not the ship's size
        d = np.asarray(ref_enu_m, float) - np.asarray(cam_pos_enu_m, float)
        if math.sqrt(d.dot(d)) < cfg.min_range_m:  # (np.linalg.norm's numbers, without its wrapper)
            return False
        s0 = np.exp(self.x[:3])
        # the fit and a step in each log scale (the outline without its mast), and the fit with its mast
        scales = np.vstack([s0, s0 * self._STEP_FACTORS, s0])
        outlines = [self.outline.body] * 4 + [self.outline]
        sizes = np.empty((len(scales), 2))
        for i, (sc, o) in enumerate(zip(scales, outlines)):
            pb = predicted_box_px(o, cam, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, course_enu_rad, sc)
            if pb is None or not np.isfinite(pb).all():
                return False
            if cam.width_px > 0 and (pb[0] <= 0.0 or pb[1] <= 0.0 or pb[2] >= cam.width_px - 1.0
                                     or pb[3] >= cam.height_px - 1.0):
                return False  # the predicted box is clipped: its size is not the outline's
            sizes[i] = (pb[2] - pb[0], pb[3] - pb[1])
        sizes *= cfg.box_scale  # what the detector draws round that silhouette
        if (sizes <= 1.0).any():
            return False
        logs = np.log(sizes)
        J = (logs[1:4] - logs[0]).T / self._STEP  # (2, 3): d log(width, height) / d log scales
        det_size = np.array([b[2] - b[0], b[3] - b[1]])
        # the detector's box may or may not take in the thin mast (close in it shows): midway, +- half of it
        mast = 0.5 * (logs[4] - logs[0])
        y = np.log(det_size) - logs[0] - mast
        Rn = np.diag(cfg.box_std ** 2 + (cfg.box_px_std / det_size) ** 2)  # small far boxes weigh less
        Rn = Rn + np.outer(mast, mast)
        S = J @ self.P @ J.T + Rn
        det = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
        if not det > 0.0:
            return False
        if t_s is not None:
            self._last_t = float(t_s)
        Si = np.array([[S[1, 1], -S[0, 1]], [-S[1, 0], S[0, 0]]]) / det
        if float(y @ Si @ y) > cfg.gate:
            self.gated += 1
            self.gated_in_a_row += 1
            if self.gated_in_a_row >= cfg.max_gated_in_a_row:  # the fit, not the boxes, is off: start again
                self.x = np.zeros(3)
                self.P = np.eye(3) * cfg.prior_std ** 2
                self.updates = 0
                self.gated_in_a_row = 0
                self.restarts += 1
                self.retired = 0 < cfg.class_after_restarts <= self.restarts
            return False
        self.gated_in_a_row = 0
        K = self.P @ J.T @ Si
        I_KJ = np.eye(3) - K @ J
        self.P = I_KJ @ self.P @ I_KJ.T + K @ Rn @ K.T  # Joseph form
        lim = math.log(cfg.max_scale)
        self.x = (self.x + K @ y).clip(-lim, lim)  # (np.clip's call)
        self.updates += 1
        return True


class LayoutFit:
    """Which end of the ship its superstructure stands at: the class's layout or the other end
    (:class:`ShipOutline` ``other_end``), from where the box centres fall while the ship's course is known.

    Each layout corrects a box centre differently (a superstructure aft pulls the box aft and up, more so
    the more it is seen end on): the corrected centre's ray, met with the tracked point's plane, is where that
    layout puts the ship. Over the last ``window_s`` the ground points of the right layout lie on one smooth
    track; the wrong layout's wander off it as the view goes round the ship, by up to twice the box centre's
    pull. The points are taken relative to the estimated velocity integrated over time (which follows a
    manoeuvre), and each layout's are fitted by a track of constant acceleration (weighted least squares:
    each point's error is the pixel noise seen through its view, with a floor, ``point_floor_m``); what the
    fit leaves, divided by the better layout's reduced chi-square when that is above 1 (a misfit both
    share, a manoeuvre the track does not follow or a size not yet learnt, is no evidence) and tempered to
    ``max_effective`` boxes, weighs the two layouts against the prior (``prior_other_end``). The box shapes
    add their say (``shape_weight``): the heading-from-shapes posterior is worked out with the class's
    outline, which turned end for end is the other end's, so its log ratio at the reverse of the course over
    the course (:meth:`ShapeHeading.reverse_log_ratio`; each box's clipped to ``shape_clip``), averaged over
    the window, is added to the log-odds. Once the other
    end's probability reaches ``switch_probability`` the correction takes it (and back once the class's
    does). The course comes from the estimated velocity: a still ship's
    two layouts are its two headings, which the box shapes weigh (:class:`ShapeHeading`); nothing is learnt
    while the course is unknown, and the fit stops learning at the terminal switch (:meth:`hold`), where the
    airframe starts to cut the boxes.

    Nothing here reads the simulated ship: only the flight software's outline and its own estimate."""

    def __init__(self, cfg: LayoutFitConfig, outlines: tuple[ShipOutline, ShipOutline], camera: PinholeCamera,
                 pixel_noise_px: float = 2.0, edge_px: float = 6.0):
        self.cfg = cfg
        self.outlines = outlines  # (the class's, the other end)
        self.camera = camera
        self.pixel_noise_px = float(pixel_noise_px)
        self.edge_px = float(edge_px)
        # the window's points, oldest first, in rows [lo, hi) of arrays that are compacted when full: time, each
        # layout's ground point (east, north; relative to the dead reckoning), its weight (2 x 2)
        cap = int(math.ceil(cfg.window_s * cfg.rate_hz)) + 16
        self._t, self._g, self._w = np.zeros(cap), np.zeros((2, cap, 2)), np.zeros((cap, 2, 2))
        self._s = np.full(cap, math.nan)  # the box shapes' log ratio for the other end (shape_weight), clipped
        self._lo = self._hi = 0
        self._last_t = -math.inf
        self._dr = (0.0, 0.0)  # the estimated velocity integrated (dead reckoning), east, north, m
        self._dr_t, self._dr_v = math.nan, (0.0, 0.0)  # (on Python floats: this runs with every box)
        self.other_end = False  # the correction uses the other end's layout
        self.p_other_end = float(cfg.prior_other_end)
        self.held = False
        self.switches = 0
        self.misfit_per_dof = math.nan  # the better layout's reduced chi-square about its track

    def hold(self) -> None:
        """Stop learning (the terminal switch): the layout stays as it is."""
        self.held = True

    def observe(self, t_s: float, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, box_px, course_enu_rad,
                tracked_height_m: float, scale=None, vel_enu=None, shape_log_ratio=None) -> bool:
        """Take one box (the ship's waterline centre estimated at ``ref_enu_m``, on ``course_enu_rad``: a float,
        None when unknown, or a function that gives it, asked only when the box is taken; its estimated
        velocity ``vel_enu``, which the ground points are taken relative to; ``shape_log_ratio``: a function of
        the course that gives the box shapes' log ratio for the other end, or None, :meth:`ShapeHeading.
        reverse_log_ratio`); ``scale``: the sizes both layouts are projected at (None: the class's); True when
        the layout in use changed."""
        c = self.cfg
        if vel_enu is not None and c.enabled and not self.held:
            ve, vn = float(vel_enu[0]), float(vel_enu[1])
            if math.isfinite(ve) and math.isfinite(vn):
                if math.isfinite(self._dr_t) and t_s > self._dr_t:  # the trapezoid since the last box
                    dt = t_s - self._dr_t
                    self._dr = (self._dr[0] + 0.5 * (self._dr_v[0] + ve) * dt,
                                self._dr[1] + 0.5 * (self._dr_v[1] + vn) * dt)
                self._dr_t, self._dr_v = float(t_s), (ve, vn)
        if not c.enabled or self.held or course_enu_rad is None or t_s - self._last_t < 1.0 / c.rate_hz - 1e-9:
            return False
        if callable(course_enu_rad):
            course_enu_rad = course_enu_rad()
            if course_enu_rad is None:
                return False
        b = np.asarray(box_px, dtype=float)
        cam = self.camera
        if b.shape != (4,) or not np.isfinite(b).all() or _at_image_border(cam, b, self.edge_px):
            return False
        ref = np.asarray(ref_enu_m, dtype=float)
        cam_pos = np.asarray(cam_pos_enu_m, dtype=float)
        R = np.asarray(R_enu_from_cam, dtype=float)
        uv = 0.5 * np.array([b[0] + b[2], b[1] + b[3]])
        det = np.array([b[2] - b[0], b[3] - b[1]])
        plane = float(ref[2]) + tracked_height_m
        points = []
        for outline in self.outlines:
            box = predicted_boxes_px(outline, cam, cam_pos, R, ref, [course_enu_rad], scale)[0]
            if not np.isfinite(box).all():
                return False
            size = box[2:4] - box[0:2]
            if not ((det > 0.5 * size).all() and (det < 2.0 * size).all()):  # cut short, or not this ship
                return False
            off = box_centre_offset_px(outline, cam, cam_pos, R, ref, course_enu_rad, tracked_height_m,
                                       boxes_px=box[None, :], scale=scale)
            if off is None:
                return False
            g = self._ground(uv - off, cam_pos, R, plane)
            if g is None:
                return False
            points.append(g)
        g0, J = points[0][0], np.column_stack([points[0][1], points[0][2]])  # d(ground)/d(u, v), m per px
        cov = (self.pixel_noise_px ** 2) * (J @ J.T) + (c.point_floor_m ** 2) * np.eye(2)
        self._last_t = float(t_s)
        dr = np.array(self._dr)
        shape = shape_log_ratio(course_enu_rad) if shape_log_ratio is not None and c.shape_weight > 0.0 else None
        shape = math.nan if shape is None else max(-c.shape_clip, min(c.shape_clip, shape))
        self._append(float(t_s), g0 - dr, points[1][0] - dr, np.linalg.inv(cov), shape)
        while self._lo < self._hi and self._t[self._lo] < t_s - c.window_s:
            self._lo += 1
        return self._decide()

    @property
    def boxes(self) -> int:
        """The boxes in the fit's window."""
        return self._hi - self._lo

    def _append(self, t_s: float, g_class: np.ndarray, g_other: np.ndarray, w: np.ndarray,
                shape: float = math.nan) -> None:
        if self._hi == len(self._t):  # full: the window's rows to the front
            n, lo = self._hi - self._lo, self._lo
            hi = self._hi
            self._t[:n], self._g[:, :n], self._w[:n] = self._t[lo:hi], self._g[:, lo:hi], self._w[lo:hi]
            self._s[:n] = self._s[lo:hi]
            self._lo, self._hi = 0, n
            if n == len(self._t):  # (a rate above rate_hz cannot happen; grow rather than lose a point)
                self._t = np.concatenate([self._t, np.zeros(n)])
                self._g = np.concatenate([self._g, np.zeros((2, n, 2))], axis=1)
                self._w = np.concatenate([self._w, np.zeros((n, 2, 2))])
                self._s = np.concatenate([self._s, np.full(n, math.nan)])
        k = self._hi
        self._t[k], self._g[0, k], self._g[1, k], self._w[k], self._s[k] = t_s, g_class, g_other, w, shape
        self._hi += 1

    def shape_evidence(self) -> float:
        """The box shapes' log-odds for the other end over the window: ``shape_weight`` times the mean of the
        boxes' clipped log ratios (those that had one); 0 when none did."""
        s = self._s[self._lo:self._hi]
        s = s[np.isfinite(s)]
        return self.cfg.shape_weight * float(s.mean()) if s.size else 0.0

    def _ground(self, uv: np.ndarray, cam_pos: np.ndarray, R: np.ndarray, plane_z: float):
        """(the ground point of pixel ``uv`` on the plane z = ``plane_z``, its derivative by u and by v: m per px,
        :func:`controllers.navigation.camera_model.ground_from_pixel_jacobian`) or None where the ray does not come down to it
        (:func:`~controllers.navigation.camera_model.depth_on_plane`)."""
        hit = _pixel_on_plane(self.camera, uv, cam_pos, R, plane_z)
        if hit is None:
            return None
        g, x1, x2 = hit
        cam = self.camera
        J = ground_from_pixel_jacobian(x1, x2, R, float(cam_pos[2]), plane_z, cam.fx, cam.fy)
        return g[:2], J[:2, 0], J[:2, 1]

    def misfits(self) -> tuple[float, float, int] | None:
        """(each layout's weighted sum of squares about its best track, the boxes in the window), or None."""
        n = self._hi - self._lo
        if n < max(self.cfg.min_boxes, 4):
            return None
        lo, hi = self._lo, self._hi
        t = self._t[lo:hi]
        tau = t - 0.5 * (t[0] + t[-1])
        basis = np.stack([np.ones(n), tau, 0.5 * tau * tau], axis=1)  # (n, 3): position, velocity, acceleration
        W = self._w[lo:hi]  # (n, 2, 2)
        # the normal equations of g_i = theta^T basis_i (theta 3 x 2: [p; v; a] in east, north), each point
        # weighted by W_i: sum (b b^T) (x) W  and  sum b (x) W g
        A = np.einsum("ij,ik,iab->jakb", basis, basis, W).reshape(6, 6)
        out = []
        for k in (0, 1):
            g = self._g[k, lo:hi]  # (n, 2)
            Wg = np.einsum("iab,ib->ia", W, g)
            y = np.einsum("ij,ia->ja", basis, Wg).reshape(6)
            try:
                theta = np.linalg.solve(A, y).reshape(3, 2)
            except np.linalg.LinAlgError:
                return None
            r = g - basis @ theta
            out.append(float(np.einsum("ia,iab,ib->", r, W, r)))
        return out[0], out[1], n

    def _decide(self) -> bool:
        fit = self.misfits()
        if fit is None:
            return False
        ss_class, ss_other, n = fit
        c = self.cfg
        k = min(1.0, c.max_effective / n)
        # the points' errors scaled so that the better layout's track fits them as their noise says (its
        # reduced chi-square, when above 1: a manoeuvre the track does not follow, a size the fit has not
        # learnt): a misfit both layouts share is no evidence for either
        self.misfit_per_dof = min(ss_class, ss_other) / max(2.0 * n - 6.0, 1.0)
        k /= max(self.misfit_per_dof, 1.0)
        logit = math.log(c.prior_other_end / (1.0 - c.prior_other_end)) + 0.5 * k * (ss_class - ss_other) \
            + self.shape_evidence()
        self.p_other_end = float(scipy.special.expit(logit))
        was = self.other_end
        if not was and self.p_other_end >= c.switch_probability:
            self.other_end = True
        elif was and self.p_other_end <= 1.0 - c.switch_probability:
            self.other_end = False
        if self.other_end != was:
            self.switches += 1
            return True
        return False


@dataclass(frozen=True, slots=True)
class ShipHeadingStatus:
    """The ship's heading as the box shapes tell it (:class:`ShapeHeading`), for the log."""

    t_s: float
    best_heading_deg: float  # the most likely heading, clockwise from North (the scenario's convention)
    best_weight: float  # its posterior weight (of all candidate headings)
    reverse_weight: float  # the weight of the opposite heading (bow and stern swapped)
    updates: int  # detections used so far
    in_use: bool  # it alone gives the heading (course unknown, shapes ready); with a course the two are fused
    course_deg: float  # the course from the estimated velocity when known (clockwise from North), else NaN
    size_scale: np.ndarray  # (3,) the ship's length, beam, height over the class's as fitted (ShipSize)
    size_updates: int  # boxes the size fit has taken
    size_in_use: bool  # the correction uses the fitted outline
    layout_other_end: float  # the probability that the superstructure stands at the other end (LayoutFit)
    layout_in_use: str  # the layout the correction uses: "class" or "other_end"
    turn_rate_deg_s: float  # the most likely of heading_from_shape.turn_rates_deg_s (clockwise seen from above)
    layout_shape_log_odds: float  # the box shapes' part of layout_other_end's log-odds (LayoutFit.shape_evidence)


class ShipModel:
    """What the flight software knows of the ship: the class outline (a priori) and its heading (learnt).

    The heading comes from the estimated velocity (a ship's bow points along its course) and from the
    shapes of its boxes (:class:`ShapeHeading`). The perception feeds it each detection
    (:meth:`observe_box`) and asks it for the possible headings (:meth:`headings`) for the box-centre
    correction and the box-size gate; the terminal guidance asks it where an approach meets the hull
    (:meth:`entry_depth_m`).
    """

    def __init__(self, cfg: ShipModelConfig, camera: PinholeCamera, edge_px: float = 6.0):
        self.cfg = cfg
        self.outlines = (ShipOutline(cfg), ShipOutline(cfg, other_end=True))  # the class's layout, the other end
        self.shape = ShapeHeading(cfg.heading_from_shape, self.outlines[0], camera, edge_px)
        #: the size fit, which goes on with the layout in use (:meth:`follow_layout`)
        self.size = ShipSize(cfg.size_fit, self.outlines[0], camera, edge_px)
        self.layout = LayoutFit(cfg.layout_fit, self.outlines, camera, cfg.layout_fit.pixel_noise_px, edge_px)
        self._course_known_since = math.nan  # since when the course has been known without a break
        self._now = math.nan  # the time of the latest box (observe_box)
        self._held = (math.nan, math.nan)  # the course last followed and when (held_course_spread_deg_s)

    @property
    def outline(self) -> ShipOutline:
        """The outline the correction, the size gate and the size fit use: the class's, or its superstructure at
        the other end once the box centres say so (:class:`LayoutFit`)."""
        return self.outlines[1] if self.layout.other_end else self.outlines[0]

    def course(self, vel_enu, vel_std_m_s: float = 0.0) -> float | None:
        """The ship's course (bow direction, counter-clockwise from East) from its estimated velocity, or None
        when it is unknown: slower than ``min_speed_for_course_m_s`` or less sure than
        ``max_vel_std_for_course_m_s``, or off the ship's axis as the box shapes tell it (a ship moves along
        its axis: such a velocity is the estimate's error)."""
        cfg = self.cfg
        if math.hypot(float(vel_enu[0]), float(vel_enu[1])) < cfg.min_speed_for_course_m_s \
                or vel_std_m_s > cfg.max_vel_std_for_course_m_s:
            return None
        course = math.atan2(float(vel_enu[1]), float(vel_enu[0]))
        if self.shape.ready and \
                self.shape.off_axis_rad(course) > math.radians(cfg.heading_from_shape.max_course_off_axis_deg):
            return None
        return course

    def headings(self, vel_enu, vel_std_m_s: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        return self.headings_and_course(vel_enu, vel_std_m_s)[:2]

    def headings_and_course(self, vel_enu, vel_std_m_s: float = 0.0) -> tuple[np.ndarray, np.ndarray, float | None]:
        """The ship's possible headings (bow direction, counter-clockwise from East) and their weights, from
        its estimated velocity (std ``vel_std_m_s``) and the box shapes:

        * course known (:meth:`course`) and shapes ready: the shapes' posterior times the course's
          likelihood (a ship's bow points along its course; the course's std is the velocity's over the
          speed, at least ``fuse_min_course_std_deg``), so each sharpens the other;
        * course known, shapes not ready: the course alone;
        * course unknown: the headings the shapes allow (weighed by the course last followed while it is
          recent), else ``headings_when_unknown`` equal ones.
        """
        course = self.course(vel_enu, vel_std_m_s)
        sh = self.cfg.heading_from_shape
        if course is not None:
            if not (self.shape.ready and sh.fuse_with_course):
                return np.array([course]), np.ones(1), course
            speed = max(math.hypot(float(vel_enu[0]), float(vel_enu[1])), 1e-6)  # min_speed_for_course may be 0
            sig = max(vel_std_m_s / speed, math.radians(sh.fuse_min_course_std_deg))
            w = self.shape.weights() * _course_likelihood(self.shape.courses_enu_rad, course, sig)
            if not w.sum() > 0.0:
                return np.array([course]), np.ones(1), course
            return (*_plausible(self.shape.courses_enu_rad, w, sh.min_weight), course)
        held = self._held_course_weights()
        if held is not None:  # the shapes' headings weighed by the course last followed
            w = self.shape.heading_weights() * held
            if w.sum() > 0.0:
                return (*_plausible(self.shape.courses_enu_rad, w, sh.min_weight), None)
        shaped = self.shape.headings()
        if shaped is not None:
            return shaped[0], shaped[1], None
        n = self.cfg.headings_when_unknown
        return 2.0 * math.pi * np.arange(n) / n, np.full(n, 1.0 / n), None

    def _held_course_weights(self) -> np.ndarray | None:
        """The likelihood of the shapes' headings (:attr:`ShapeHeading.courses_enu_rad`) under the course last
        followed, its std ``fuse_min_course_std_deg`` plus ``held_course_spread_deg_s`` per second since; None
        when off, before the shapes are ready, when no course has been followed, or once the std spans the
        circle (180 deg)."""
        sh = self.cfg.heading_from_shape
        course, t = self._held
        if sh.held_course_spread_deg_s <= 0.0 or not math.isfinite(course) or not self.shape.ready:
            return None
        sig = sh.fuse_min_course_std_deg + sh.held_course_spread_deg_s * max(self._now - t, 0.0)
        if not sig < 180.0:  # (also NaN)
            return None
        return _course_likelihood(self.shape.courses_enu_rad, course, math.radians(sig))

    def learn_size(self, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, courses, weights, box_px,
                   t_s: float | None = None) -> bool:
        """Feed one detected box to the size fit (:class:`ShipSize`) at the weighted circular mean of the
        headings ``courses`` (weights ``weights``, :meth:`headings_and_course`; finer than their 5-deg grid)
        when the heading is sure: the box
        shapes' posterior (with a known course fused in) concentrated to a mean resultant length of at least
        ``_SIZE_FIT_MIN_RESULTANT``. Never a course alone: a still ship's estimated velocity gives one for
        seconds after the lock, any way round. True when the box moved the fit."""
        if not self.shape.ready or len(courses) == 1 or not self.size.takes_boxes(t_s):
            return False  # (the rate first: the heading's concentration is not worked out for nothing)
        resultant = complex(np.dot(weights, np.exp(1j * np.asarray(courses))))
        if abs(resultant) < _SIZE_FIT_MIN_RESULTANT:
            return False
        course = math.atan2(resultant.imag, resultant.real)
        return self.size.update(cam_pos_enu_m, R_enu_from_cam, ref_enu_m, course, box_px, t_s)

    def follow_layout(self) -> None:
        """After the layout in use has changed: the size fit goes on with it from where it stands."""
        self.size.outline = self.outline

    def observe_box(self, t_s: float, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, box_px, vel_enu,
                    vel_std_m_s: float, tracked_height_m: float = 0.0) -> ShipHeadingStatus | None:
        """Feed one detected box to the heading-from-shapes posterior and the layout fit (``ref_enu_m``: the
        estimated waterline centre; ``tracked_height_m``: the estimator's tracked point above it); the state
        for the log when the shapes took the box, else None."""
        if self.cfg.enabled and self.layout.observe(t_s, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, box_px,
                                                    lambda: self.course(vel_enu, vel_std_m_s), tracked_height_m,
                                                    self.size.scale, vel_enu, self.shape.reverse_log_ratio):
            self.follow_layout()
        sh = self.shape
        self._now = float(t_s)
        follow = self._course_to_follow(t_s, vel_enu, vel_std_m_s)
        if follow is not None:
            self._held = (follow, float(t_s))
        if not sh.update(t_s, cam_pos_enu_m, R_enu_from_cam, ref_enu_m, box_px, follow):
            return None
        w = sh.weights()
        k = int(np.argmax(w))
        course = self.course(vel_enu, vel_std_m_s)
        sz = self.size
        return ShipHeadingStatus(t_s, heading_deg_from_course_enu(float(sh.courses_enu_rad[k])), float(w[k]),
                                 float(w[(k + len(w) // 2) % len(w)]), sh.updates, bool(course is None and sh.ready),
                                 math.nan if course is None else heading_deg_from_course_enu(course),
                                 np.exp(sz.theta), sz.updates, sz.scale is not None, self.layout.p_other_end,
                                 "other_end" if self.layout.other_end else "class",
                                 float(sh.cfg.turn_rates_deg_s[int(np.argmax(sh.rate_weights()))]),
                                 self.layout.shape_evidence())

    def _course_to_follow(self, t_s: float, vel_enu, vel_std_m_s: float) -> float | None:
        """The estimated velocity's course when the box shapes' posterior may follow it
        (:attr:`ShapeHeadingConfig.follow_course`): known by speed and std (as in :meth:`course`, but whatever
        the shapes say: they are what is being turned) for ``follow_course_settle_s`` without a break."""
        cfg, sh = self.cfg, self.cfg.heading_from_shape
        if not sh.follow_course:
            return None
        speed = math.hypot(float(vel_enu[0]), float(vel_enu[1]))
        if speed < max(cfg.min_speed_for_course_m_s, 1e-6) or not vel_std_m_s <= cfg.max_vel_std_for_course_m_s:
            self._course_known_since = math.nan
            return None
        if math.isnan(self._course_known_since):
            self._course_known_since = float(t_s)
        if t_s - self._course_known_since < sh.follow_course_settle_s:
            return None
        return math.atan2(float(vel_enu[1]), float(vel_enu[0]))

    def entry_depth_m(self, point_enu_m, ship_enu_m, dir_enu, vel_enu) -> float:
        """How far before ``point_enu_m`` a straight path along ``dir_enu`` (unit) first meets the outline of
        the ship at ``ship_enu_m`` (its waterline centre), the deepest over the headings it may have
        (:meth:`headings` of ``vel_enu``); 0 when nothing is in the way."""
        depth = 0.0
        for c in self.headings(vel_enu)[0]:
            R_se = dcm_ship_from_enu(float(c))
            depth = max(depth, self.outline.entry_depth_m(R_se @ (point_enu_m - ship_enu_m), R_se @ dir_enu))
        return depth
