"""The UAV's own airframe in its camera's image: which pixels it hides, and the boxes it cuts.

A belly camera looking at a ship above its wing plane sees part of the ship
through the fuselage, wing or tail: the detector's box is then the box of the
ship's pixels the airframe leaves, not of the whole ship, and its centre moves
off the ship's by up to half the part hidden. The dive is where this happens
(BPNG turns the lift toward a ship abeam; docs/results/envelope.md, "The ship seen, not only in
the field of view"), at the ranges that decide the miss.

:class:`AirframeShadow` predicts the same cut. It knows the airframe a priori,
as the flight software knows the ship class (:class:`~controllers.config.AirframeConfig`:
a fuselage cylinder along the body x axis and boxes for wing and tails, body
FRD, origin at the CG), and the camera's place on it (the gimbal's mount
offset and encoders). Each part is a convex solid, so its silhouette is the
convex hull of its corners' projections (:meth:`AirframeShadow.silhouettes`;
a part reaching behind the camera is cut at a plane just in front of it
first). :meth:`AirframeShadow.cut` takes a predicted ship box and the
ship's projected parts (convex solids too), draws them and the airframe's
silhouettes on a grid over the box, and returns the box of the ship's cells
the airframe leaves (and the share of the ship it hides): the box a detector
would report had the ship been where the estimate puts it.
:meth:`AirframeShadow.aligned_cut` first moves the ship onto the detected box,
so that the cut is the one where the camera sees the ship. The perception
(``controllers.perception.perception``) does this when the detected box touches the
silhouette (:meth:`AirframeShadow.touches`), and its box-centre correction
then subtracts the centre of the cut box, as it
already does for a box cut by the image border
(:func:`controllers.perception.ship_outline.predicted_box_px` clips to the image). A box
no ray of which can meet the airframe is returned unchanged at the cost of a
few dot products (:meth:`AirframeShadow.may_hide`): the airframe lies above
the camera, so it hides only rays that climb in the body frame, and for the
fwuav none that climbs less than 3.5 deg.

Nothing here reads the simulated airframe (docs/design/architecture.md, "Two rules").
"""
from __future__ import annotations

import math

import numpy as np

from controllers.config import AirframeConfig
from controllers.navigation.camera_model import PinholeCamera

__all__ = ["AirframeShadow"]

_SHIFT = 4  # cv2.fillConvexPoly's fractional bits: vertices placed to 1/16 of a grid cell
_FAR = float(2**26)  # polygon coordinates (in 1/16 cells) clamped to this: int32 with room to spare
_NEAR_M = 0.005  # a part reaching behind the camera is cut this far in front of it
_FUSELAGE_SIDES = 24  # the fuselage cylinder as a prism of this many sides


class AirframeShadow:
    """The airframe's silhouette in the camera and the ship boxes it cuts (see the module text)."""

    def __init__(self, cfg: AirframeConfig, camera: PinholeCamera, mount_offset_frd_m):
        self.cfg = cfg
        self.camera = camera
        self.origin = np.asarray(mount_offset_frd_m, dtype=float).reshape(3)  # the camera, body FRD
        boxes = np.asarray(cfg.boxes_frd_m, dtype=float).reshape(-1, 6)
        # each part a convex solid given by its corners, body FRD: the boxes, and the fuselage as a prism of
        # _FUSELAGE_SIDES sides round the cylinder (its faces' midpoints on the cylinder: the prism holds it)
        self.parts: list[np.ndarray] = [np.array([(x, y, z) for x in b[0:2] for y in b[2:4] for z in b[4:6]])
                                        for b in boxes]
        x0, x1 = (float(x) for x in cfg.fuselage_x_m)
        r = float(cfg.fuselage_radius_m)
        if r > 0.0:
            a = 2.0 * math.pi * (np.arange(_FUSELAGE_SIDES) + 0.5) / _FUSELAGE_SIDES
            rc = r / math.cos(math.pi / _FUSELAGE_SIDES)  # the corners' radius
            ring = np.stack([rc * np.cos(a), rc * np.sin(a)], axis=1)
            self.parts.append(np.array([(x, y, z) for x in (x0, x1) for y, z in ring]))
        # the shallowest climb (tan of the elevation over the body x-y plane) from the camera to a corner: a
        # ray climbing less meets no part (each lies in the cone of its corners, and the rays climbing at
        # least that much form a convex cone round the body's up axis); 0 when a part is not above the camera
        with np.errstate(divide="ignore", invalid="ignore"):  # (a corner straight above: +inf; at the camera: 0)
            climbs = [float(np.nan_to_num((self.origin[2] - p[:, 2]) / np.hypot(p[:, 0] - self.origin[0],
                                                                                p[:, 1] - self.origin[1]),
                                          nan=0.0).min())
                      for p in self.parts]
        self._min_elevation = math.atan(max(0.0, min(climbs, default=math.inf)))  # rad
        self._last: tuple[bytes, list[np.ndarray]] = (b"", [])  # the last gimbal angles' silhouettes

    # ------------------------------------------------------------------ the silhouette
    def silhouettes(self, R_frd_from_cam: np.ndarray) -> list[np.ndarray]:
        """Each part's silhouette in the image, a convex polygon (k, 2) in pixels (parts wholly behind the
        camera left out). A convex solid's silhouette is the convex hull of its corners' projections; a part
        reaching behind the camera is first cut at a plane ``_NEAR_M`` in front of it (its corners in front,
        and where the segments between those and the ones behind cross the plane: the cut solid's corners
        are among them)."""
        R = np.asarray(R_frd_from_cam, dtype=float)
        key = R.tobytes()
        if key == self._last[0]:
            return self._last[1]
        c = self.camera
        R_cf = R.T
        out = []
        for part in self.parts:
            p = (part - self.origin) @ R_cf.T  # camera frame
            front = p[:, 2] >= _NEAR_M
            if not front.any():
                continue
            if not front.all():
                a, b = p[front], p[~front]
                t = (_NEAR_M - a[:, None, 2]) / (b[None, :, 2] - a[:, None, 2])  # (na, nb) along a -> b
                cross = a[:, None, :] + t[..., None] * (b[None, :, :] - a[:, None, :])
                p = np.vstack([a, cross.reshape(-1, 3)])
            uv = np.stack([c.fx * p[:, 0] / p[:, 2] + c.cx, c.fy * p[:, 1] / p[:, 2] + c.cy], axis=1)
            out.append(_hull(uv))
        self._last = (key, out)
        return out

    def hidden(self, R_frd_from_cam: np.ndarray, u_px, v_px) -> np.ndarray:
        """Whether the ray through each pixel (u_px, v_px: broadcast together) meets the airframe (bool, their
        broadcast shape): inside a part's silhouette."""
        u, v = np.broadcast_arrays(np.asarray(u_px, dtype=float), np.asarray(v_px, dtype=float))
        hit = np.zeros(u.shape, dtype=bool)
        for poly in self.silhouettes(R_frd_from_cam):
            hit |= _inside(poly, u, v)
        return hit

    def may_hide(self, R_frd_from_cam: np.ndarray, box_px) -> bool:
        """False when no ray through the box (u0, v0, u1, v1) climbs (over the body x-y plane) as steeply as
        the shallowest ray that meets the airframe: the airframe is then not in the way. Exact and cheap: a
        ray's elevation changes no faster than the angle it turns through, and every ray of the box lies
        within the angle of its farthest corner from the centre ray (the rays within an angle under 90 deg
        of one form a convex cone), so the centre's elevation plus that angle bounds the box's."""
        if not self.parts:
            return False
        c = self.camera
        u0, v0, u1, v1 = (float(x) for x in box_px)
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = np.asarray(R_frd_from_cam, dtype=float).tolist()
        cx, cy, fx, fy = c.cx, c.cy, c.fx, c.fy
        # the unit ray through a pixel, body FRD: (R @ [(u - cx) / fx, (v - cy) / fy, 1]) / its norm; the centre's
        # (m), then the cosine of its angle to each corner's (written out: this runs on every detection)
        x, y = (0.5 * (u0 + u1) - cx) / fx, (0.5 * (v0 + v1) - cy) / fy
        d0, d1, d2 = r00 * x + r01 * y + r02, r10 * x + r11 * y + r12, r20 * x + r21 * y + r22
        n = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
        m0, m1, m2 = d0 / n, d1 / n, d2 / n
        cos_far = math.inf
        for u in (u0, u1):
            x = (u - cx) / fx
            for v in (v0, v1):
                y = (v - cy) / fy
                d0, d1, d2 = r00 * x + r01 * y + r02, r10 * x + r11 * y + r12, r20 * x + r21 * y + r22
                n = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
                cos = m0 * (d0 / n) + m1 * (d1 / n) + m2 * (d2 / n)
                if cos < cos_far:
                    cos_far = cos
        if cos_far <= 0.0:  # (a box 90 deg or more across: no bound)
            return True
        spread = math.acos(min(1.0, cos_far))
        return math.asin(max(-1.0, min(1.0, -m2))) + spread >= self._min_elevation

    def touches(self, R_frd_from_cam: np.ndarray, box_px, margin_px: float = 0.0) -> bool:
        """Whether the airframe's silhouette overlaps the box (u0, v0, u1, v1) grown by ``margin_px``: a
        detected box it touches may be one the airframe cut (separating axes of each convex silhouette and
        the box)."""
        b = np.asarray(box_px, dtype=float)
        if not np.isfinite(b).all():
            return False
        g = b + np.array([-margin_px, -margin_px, margin_px, margin_px])
        if not self.may_hide(R_frd_from_cam, g):
            return False
        rect = np.array([[g[0], g[1]], [g[2], g[1]], [g[2], g[3]], [g[0], g[3]]])
        for poly in self.silhouettes(R_frd_from_cam):
            if len(poly) >= 3 and _overlap(poly, rect):
                return True
        return False

    # ------------------------------------------------------------------ boxes
    def cut(self, R_frd_from_cam: np.ndarray, box_px, parts_px: list[np.ndarray], checked: bool = False
            ) -> tuple[np.ndarray, float]:
        """(The box (u0, v0, u1, v1) of the ship's pixels in ``box_px`` that the airframe leaves, the share of
        the ship's pixels it hides).

        ``parts_px``: the projected corner points (m, 2) of each convex solid of the ship; ``box_px`` their
        box clipped to the image. Drawn on a grid of at most ``grid_cells`` cells across the box's longer
        side. The box itself (and 0) when the airframe cannot reach it or hides none of it; NaN (4,) (and 1)
        when it hides all of it."""
        b = np.asarray(box_px, dtype=float)
        if not np.isfinite(b).all() or not (checked or self.may_hide(R_frd_from_cam, b)):
            return b, 0.0
        u0, v0, u1, v1 = b
        polys = [q for q in self.silhouettes(R_frd_from_cam)
                 if q[:, 0].max() >= u0 and q[:, 0].min() <= u1 and q[:, 1].max() >= v0 and q[:, 1].min() <= v1]
        if not polys:
            return b, 0.0
        import cv2  # OpenCV only where a box is cut

        step = max(1.0, max(u1 - u0, v1 - v0) / float(self.cfg.grid_cells))
        nu, nv = int(math.floor((u1 - u0) / step)) + 1, int(math.floor((v1 - v0) / step)) + 1
        scale = float(1 << _SHIFT) / step

        def draw(shapes) -> np.ndarray:
            img = np.zeros((nv, nu), dtype=np.uint8)
            for pts in shapes:
                p = np.asarray(pts, dtype=float)
                if len(p) < 3 or not np.isfinite(p).all():
                    continue
                # (int32 room: a part cut _NEAR_M in front of the camera projects within about 3e5 px)
                q = np.clip((p - np.array([u0, v0])) * scale, -_FAR, _FAR)
                cv2.fillConvexPoly(img, cv2.convexHull(np.round(q).astype(np.int32)), 1, lineType=cv2.LINE_8,
                                   shift=_SHIFT)
            return img > 0

        drawn = draw(parts_px)
        if not drawn.any():  # (a box too thin for the grid: nothing drawn) the box as it was
            return b, 0.0
        air = draw(polys)
        if not (drawn & air).any():  # the airframe hides none of the ship drawn
            return b, 0.0
        seen = drawn & ~air
        if not seen.any():
            return np.full(4, np.nan), 1.0
        # each side moved by as much as the grid's seen part stands in from the grid's whole ship: the
        # grid's own rounding cancels
        return b + step * (_grid_box(seen) - _grid_box(drawn)), 1.0 - float(seen.sum()) / float(drawn.sum())

    def aligned_cut(self, R_frd_from_cam: np.ndarray, box_px, parts_px: list[np.ndarray], detected_px,
                    iterations: int) -> tuple[np.ndarray, float]:
        """:meth:`cut` of the ship moved across the image onto the detected box ``detected_px``, then
        moved back by as much: the cut where the ship is seen, not where the estimate puts it. Close in, the
        estimate's few metres are tens of pixels, as much as the cut itself, and the airframe's silhouette
        stays put in the image while the ship moves.

        The move starts with the whole box's centre on the detected box's and is corrected ``iterations``
        times, each axis by the sides the ship's own outline makes (neither cut by the airframe nor at the
        image border): one such side is put on the detected box's, two centre the boxes, none centre the cut
        box on the detected one. ``box_px``: the whole predicted box (clipped to the image); ``parts_px``: as
        :meth:`cut`. The whole ``box_px`` (and 0) when the ship, so moved, is not cut (the detection is
        then a whole ship); NaN (4,) (and 1) when it is hidden."""
        b = np.asarray(box_px, dtype=float)
        d = np.asarray(detected_px, dtype=float)
        if not (np.isfinite(b).all() and np.isfinite(d).all()):
            return b, 0.0
        cam = self.camera
        hi = np.array([cam.width_px - 1.0 if cam.width_px > 0 else math.inf,
                       cam.height_px - 1.0 if cam.height_px > 0 else math.inf])
        border = np.concatenate([d[0:2] <= 0.5, d[2:4] >= hi - 0.5])  # the detected box's sides at the border
        pts = np.vstack(parts_px)
        lo_all, hi_all = pts.min(axis=0), pts.max(axis=0)
        shift = 0.5 * (d[0:2] + d[2:4]) - 0.5 * (b[0:2] + b[2:4])
        cut, hidden = b, 0.0
        for _ in range(max(1, int(iterations))):
            box = np.concatenate([np.maximum(lo_all + shift, 0.0), np.minimum(hi_all + shift, hi)])
            if box[0] > box[2] or box[1] > box[3]:  # (moved out of the image)
                return b, 0.0
            cut, hidden = self.cut(R_frd_from_cam, box, [p + shift for p in parts_px])
            if not np.isfinite(cut).all():
                return cut, hidden
            if hidden == 0.0:  # not cut there
                return b, 0.0
            own = (cut == box) & ~border  # the sides the ship's own outline makes
            step = np.empty(2)
            for k in range(2):
                if own[k] != own[k + 2]:
                    side = k if own[k] else k + 2
                    step[k] = d[side] - cut[side]
                else:
                    step[k] = 0.5 * (d[k] + d[k + 2] - cut[k] - cut[k + 2])
            cut = cut - np.concatenate([shift, shift])
            shift = shift + step
        return cut, hidden

def _grid_box(mask: np.ndarray) -> np.ndarray:
    """(first column, first row, last column, last row) of a mask's true cells."""
    cols = np.flatnonzero(mask.any(axis=0))
    rows = np.flatnonzero(mask.any(axis=1))
    return np.array([cols[0], rows[0], cols[-1], rows[-1]], dtype=float)


def _hull(uv: np.ndarray) -> np.ndarray:
    """The convex hull of points (n, 2), as its corners (k, 2) in order round it."""
    import cv2  # OpenCV only where the airframe may be in view

    return cv2.convexHull(uv.astype(np.float32)).reshape(-1, 2).astype(float)


def _inside(poly: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Whether points (u, v) lie in a convex polygon (k, 2), its corners in order either way round (edges
    included)."""
    inside = np.ones(u.shape, dtype=bool)
    k = len(poly)
    if k < 3:
        return np.zeros(u.shape, dtype=bool)
    x, y = poly[:, 0], poly[:, 1]
    turn = 1.0 if float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))) >= 0.0 else -1.0
    for i in range(k):
        a, b = poly[i], poly[(i + 1) % k]
        inside &= turn * ((b[0] - a[0]) * (v - a[1]) - (b[1] - a[1]) * (u - a[0])) >= 0.0
    return inside


def _overlap(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two convex polygons (k, 2) overlap (touching counts): no edge normal of either separates
    them."""
    for poly in (a, b):
        edges = np.roll(poly, -1, axis=0) - poly
        normals = np.stack([-edges[:, 1], edges[:, 0]], axis=1)
        pa, pb = a @ normals.T, b @ normals.T  # (ka, k), (kb, k): each polygon's extent along each normal
        if ((pa.max(axis=0) < pb.min(axis=0)) | (pb.max(axis=0) < pa.min(axis=0))).any():
            return False
    return True
