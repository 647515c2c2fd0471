"""The ship class's outline as the flight software knows it, and the boxes it predicts: the projected corner
points of hull, deckhouse, wheelhouse, funnel and mast, their box as the detector draws it (clipped to the
image), for one course or many at once (compiled), and the box centre's offset from the tracked point's
image that the perception removes (``controllers.perception.target_model``)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controllers.config import ShipModelConfig
from controllers.navigation.camera_model import PinholeCamera

__all__ = ["ShipOutline", "box_centre_offset_px", "predicted_box_px", "predicted_boxes_px", "projected_points_px"]


#: points closer than this in front of the camera make the projection meaningless: no correction
_MIN_DEPTH_M = 0.5


#: predicted boxes for up to this many courses at once come from a compiled function (beyond, numpy is faster)
_COMPILED_MAX_COURSES = 8


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


def at_image_border(camera: PinholeCamera, b: np.ndarray, e: float) -> bool:
    """A box ``b`` (u0, v0, u1, v1) within ``e`` px of the image's border (the ship may be cut there: its size
    and centre are not the whole ship's); never for a camera without an image size."""
    return camera.width_px > 0 and bool(b[0] <= e or b[1] <= e or b[2] >= camera.width_px - 1.0 - e
                                        or b[3] >= camera.height_px - 1.0 - e)


def weighted_mean_rows(a: np.ndarray, weights) -> np.ndarray:
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


def weighted_cov_rows(a: np.ndarray, weights, mean: np.ndarray) -> np.ndarray:
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
        mean = weighted_mean_rows(offsets, weights)
        return (mean, weighted_cov_rows(offsets, weights, mean)) if spread else mean
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
    mean = weighted_mean_rows(offsets, weights)
    return (mean, weighted_cov_rows(offsets, weights, mean)) if spread else mean
