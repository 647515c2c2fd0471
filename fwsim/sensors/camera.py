"""The pan-tilt camera: pinhole intrinsics, ray-cast detection, full-frame render.

What the camera sees comes from geometry, not a formula: rays from the
camera centre are cast (Embree, through embreex) against the posed UAV mesh
(fwsim.world.geometry) and the ship mesh (fwsim.world.target); a ship pixel is visible
when its ray hits the ship before any part of the UAV. The UAV's own wing
therefore hides the ship when a bank puts it above the wing plane.

Cost: rays are cast only over the region of interest where the ship's
bounding box projects (plus a margin), at a pixel stride chosen so that at
most ``max_roi_rays`` rays are cast; the UAV is tested only on rays that hit
the ship. Meshes stay in their own frames: rays are moved into each mesh's
frame instead of moving the meshes.

Image coordinates follow OpenCV: u right, v down, pixel (i, j) centred on the
integer coordinates; the principal point is the image centre (the paper's
(640, 360) for 1280x720).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pydantic import Field, model_validator

from fwsim.interface.configbase import StrictModel
from fwsim.world.gimbal import GimbalConfig

_MISS = 1e30  # embree reports a miss as a huge distance
# render colours (BGR) and the sun
_SKY = np.array([235.0, 206.0, 170.0], np.float32)
_SKY_FADE = np.array([60.0, 70.0, 90.0], np.float32)
_SEA = np.array([120.0, 80.0, 30.0], np.float32)
_HAZE = np.array([200.0, 180.0, 150.0], np.float32)
_HULL = np.array([150.0, 150.0, 160.0], np.float32)
_AIRFRAME = np.array([60.0, 60.0, 60.0], np.float32)
_SUN = np.array([0.4, 0.3, 0.86]) / np.linalg.norm([0.4, 0.3, 0.86])


class DetectorConfig(StrictModel):
    """Noise model standing in for YOLO (every draw from the scenario's seed)."""

    pixel_noise_px: float = Field(1.5, ge=0, le=50, description="std. dev. of the box centre noise, px")
    box_noise_px: float = Field(1.0, ge=0, le=50, description="std. dev. of each box edge's noise, px")
    miss_probability: float = Field(0.02, ge=0, le=1, description="chance a visible ship is not reported")
    min_visible_px: float = Field(12.0, ge=0, description="fewer visible ship pixels than this: no detection")
    latency_s: float = Field(0.0, ge=0, le=2, description="delay from exposure to the detection's arrival")


class RenderConfig(StrictModel):
    rate_hz: float = Field(1.0, ge=0, le=30, description="full-frame renders per second in the log (0: none)")
    width_px: int = Field(320, ge=16, le=1920, description="rendered image width, px")
    height_px: int = Field(180, ge=16, le=1080, description="rendered image height, px")
    jpeg_quality: int = Field(85, ge=10, le=100, description="JPEG quality of the logged image (10-100)")


class CameraConfig(StrictModel):
    width_px: int = Field(1280, ge=16, le=4096, description="image width, px")
    height_px: int = Field(720, ge=16, le=4096, description="image height, px")
    hfov_deg: float = Field(60.0, gt=1, lt=170, description="horizontal field of view; square pixels")
    rate_hz: float = Field(30.0, gt=0, le=240, description="frame rate of the detector")
    roi_margin_px: int = Field(8, ge=0, le=200, description="margin around the projected ship box")
    max_roi_rays: int = Field(2048, ge=64, le=4_000_000, description="ray budget of one detection frame")
    gimbal: GimbalConfig = Field(default_factory=GimbalConfig,
        description="the pan-tilt gimbal: mount, limits, start angles")
    detector: DetectorConfig = Field(default_factory=DetectorConfig,
        description="the simulated ship detector: noise, misses, latency")
    render: RenderConfig = Field(default_factory=RenderConfig,
        description="the rendered camera image logged for the viewers (rate_hz 0: none)")

    @model_validator(mode="after")
    def _rate(self):
        return self


@dataclass(frozen=True)
class Intrinsics:
    width_px: int
    height_px: int
    fx: float
    fy: float
    cx: float
    cy: float

    @classmethod
    def from_fov(cls, width_px: int, height_px: int, hfov_deg: float) -> "Intrinsics":
        f = (width_px / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(width_px, height_px, f, f, width_px / 2.0, height_px / 2.0)

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    def scaled(self, width_px: int, height_px: int) -> "Intrinsics":
        sx, sy = width_px / self.width_px, height_px / self.height_px
        return Intrinsics(width_px, height_px, self.fx * sx, self.fy * sy, self.cx * sx, self.cy * sy)

    def project(self, p_cam: np.ndarray) -> np.ndarray:
        """Points (n, 3) in the camera frame -> pixels (n, 2); u = fx X/Z + cx, v = fy Y/Z + cy."""
        p = np.atleast_2d(p_cam)
        return np.stack([self.fx * p[:, 0] / p[:, 2] + self.cx, self.fy * p[:, 1] / p[:, 2] + self.cy], axis=1)

    def rays(self, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Unit ray directions (n, 3) in the camera frame through pixels (u, v)."""
        d = np.stack([(u - self.cx) / self.fx, (v - self.cy) / self.fy, np.ones_like(u, dtype=float)], axis=1)
        return d / np.linalg.norm(d, axis=1)[:, None]


@dataclass(frozen=True, slots=True)
class FrameGeometry:
    """What one camera frame shows of the ship (ground truth, before detector noise)."""

    t_s: float
    in_fov: bool  # some ship pixel inside the image, whether hidden or not
    visible_px: float  # ship pixels not hidden by the UAV (ray count x stride^2)
    ship_px: float  # ship pixels inside the image, hidden or not
    occluded_fraction: float  # 1 - visible / ship (NaN when the ship is not in the image)
    bbox_px: np.ndarray  # (4,) u_min, v_min, u_max, v_max of the visible ship pixels (NaN if none)
    centre_px: np.ndarray  # (2,) centre of that box (NaN if none)
    stride_px: int  # pixel stride of the rays cast
    rays_cast: int


@dataclass(frozen=True, slots=True)
class Detection:
    """The detector's output as the mission computer receives it (the YOLO stand-in)."""

    t_s: float  # arrival time
    exposure_t_s: float  # when the frame was taken
    detected: bool
    u_px: float  # box centre (NaN when not detected)
    v_px: float
    bbox_px: np.ndarray  # (4,) u_min, v_min, u_max, v_max (NaN when not detected)


def _scene(mesh):
    """An Embree scene of the mesh's triangles (embreex is imported here: reading a scenario needs none)."""
    from embreex import rtcore_scene as rtcs
    from embreex.mesh_construction import TriangleMesh

    sc = rtcs.EmbreeScene()
    TriangleMesh(sc, np.ascontiguousarray(mesh.triangles, dtype=np.float32))
    return sc


def _first_hit(scene, origins_local: np.ndarray, dirs_local: np.ndarray) -> np.ndarray:
    """Distance along each ray to the first hit (inf on a miss)."""
    d = scene.run(np.ascontiguousarray(origins_local, dtype=np.float32),
                  np.ascontiguousarray(dirs_local, dtype=np.float32), query="DISTANCE")
    d = np.asarray(d, dtype=float)
    d[d > _MISS] = np.inf
    return d


#: the ship's bounding box's 12 edges: pairs of RayCaster.ship_corners (index bits 4, 2, 1: x, y, z high)
_BOX_EDGES = tuple((i, i | bit) for bit in (4, 2, 1) for i in range(8) if not i & bit)
#: corners closer than this in front of the camera plane count as behind it (their projection is meaningless)
_NEAR_Z_M = 1e-3


@dataclass
class Pose:
    """A rigid pose: p_world = R @ p_local + t."""

    R: np.ndarray
    t: np.ndarray

    def to_local(self, origins: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rays into the local frame; ``origins`` may be one point (3,) shared by all rays (returned as
        float32 rows, as the ray caster takes them)."""
        o = (origins - self.t) @ self.R
        if o.ndim == 1:  # one contiguous float32 row per ray (a broadcast view would be copied by the caster)
            o = np.repeat(o.astype(np.float32)[None, :], len(dirs), axis=0)  # (cheaper than a broadcast copy)
        return o, dirs @ self.R


@dataclass
class RayCaster:
    """The scene the camera sees: the UAV (body frame) and the ship (ship frame)."""

    uav_mesh: object
    ship_mesh: object
    _uav: object = field(init=False)  # embreex scenes
    _ship: object = field(init=False)
    ship_corners: np.ndarray = field(init=False)

    def __post_init__(self):
        self._uav = _scene(self.uav_mesh)
        self._ship = _scene(self.ship_mesh)
        lo, hi = self.ship_mesh.bounds
        self.ship_corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                                      for z in (lo[2], hi[2])])
        self.uav_lowest_z_m = float(self.uav_mesh.bounds[1][2])  # body z (down) of the UAV's lowest point

    def cast(self, origin_w: np.ndarray, dirs_w: np.ndarray, uav: Pose, ship: Pose,
             ship_rays: np.ndarray | None = None, uav_only_where_ship: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """First-hit distances to the ship and to the UAV for rays from one origin (world frame).

        ``ship_rays`` (indices) limits the ship test to rays that can reach it;
        the UAV is tested only on rays that hit the ship (``uav_only_where_ship``)
        or, otherwise, on every ray; either way only on rays that can reach the UAV
        at all: from a camera below the UAV's lowest point, a ray heading down
        (body z) cannot.
        """
        n = len(dirs_w)
        if ship_rays is None:
            d_ship = _first_hit(self._ship, *ship.to_local(origin_w, dirs_w)) if n else np.full(0, np.inf)
        else:
            d_ship = np.full(n, np.inf)
            if ship_rays.size:
                d_ship[ship_rays] = _first_hit(self._ship, *ship.to_local(origin_w, dirs_w[ship_rays]))
        d_uav = np.full(n, np.inf)
        below = ((origin_w - uav.t) @ uav.R[:, 2]) > self.uav_lowest_z_m  # the camera below the UAV's lowest point
        if uav_only_where_ship:
            idx = np.flatnonzero(np.isfinite(d_ship))
            if below and idx.size:  # then only a ray heading up (body z) can meet the UAV
                idx = idx[dirs_w[idx] @ uav.R[:, 2] < 0.0]
        else:
            idx = np.flatnonzero(dirs_w @ uav.R[:, 2] < 0.0) if below else np.arange(n)
        if idx.size:
            d_uav[idx] = _first_hit(self._uav, *uav.to_local(origin_w, dirs_w[idx]))
        return d_ship, d_uav


def _summarise(t_s, u, v, d_ship, d_uav, stride, rays) -> FrameGeometry:
    """The frame from the rays' first hits. ``u, v``: each ray's pixel, or (columns, rows) of a grid of
    rays cast row by row (the box is then found from the rows and columns that have a visible pixel)."""
    ship = np.isfinite(d_ship)
    vis = ship & ~(d_uav < d_ship)
    n_ship, n_vis = np.count_nonzero(ship), np.count_nonzero(vis)
    area = float(stride * stride)
    if n_vis and len(u) * len(v) == len(d_ship) and len(u) != len(d_ship):  # a grid: columns u, rows v
        grid = vis.reshape(len(v), len(u))
        cols, rows = u[grid.any(axis=0)], v[grid.any(axis=1)]
        bbox = np.array([cols[0], rows[0], cols[-1], rows[-1]], dtype=float)
        centre = np.array([(bbox[0] + bbox[2]) / 2, (bbox[1] + bbox[3]) / 2])
    elif n_vis:
        bbox = np.array([u[vis].min(), v[vis].min(), u[vis].max(), v[vis].max()], dtype=float)
        centre = np.array([(bbox[0] + bbox[2]) / 2, (bbox[1] + bbox[3]) / 2])
    else:
        bbox, centre = np.full(4, np.nan), np.full(2, np.nan)
    return FrameGeometry(t_s, n_ship > 0, n_vis * area, n_ship * area,
                         (1.0 - n_vis / n_ship) if n_ship else math.nan, bbox, centre, stride, rays)


class Camera:
    """Ray-cast detection of the ship, and full-frame renders for the log."""

    def __init__(self, cfg: CameraConfig, uav_mesh, ship_mesh, focal_scale: float = 1.0):
        """``focal_scale``: the focal length as built over the one ``cfg`` gives (the flight software's)."""
        self.cfg = cfg
        self.K = Intrinsics.from_fov(cfg.width_px, cfg.height_px, cfg.hfov_deg)
        if focal_scale != 1.0:
            k = self.K
            self.K = Intrinsics(k.width_px, k.height_px, k.fx * focal_scale, k.fy * focal_scale, k.cx, k.cy)
        self.caster = RayCaster(uav_mesh, ship_mesh)
        self._ray_table = self._table(self.K)  # unit ray of every pixel, camera frame (H, W, 3)
        rc = cfg.render
        self.K_render = self.K.scaled(rc.width_px, rc.height_px)
        self._render_rays = self._table(self.K_render).reshape(-1, 3)

    @staticmethod
    def _table(K: Intrinsics) -> np.ndarray:
        """``K.rays`` of every pixel (H, W, 3), built from the columns' and rows' terms: the same numbers
        (the norm's sum in its order, x^2 + y^2 + 1) at an eighth of the cost."""
        x = (np.arange(K.width_px, dtype=float) - K.cx) / K.fx
        y = (np.arange(K.height_px, dtype=float) - K.cy) / K.fy
        n = np.sqrt((x * x)[None, :] + (y * y)[:, None] + 1.0)
        out = np.empty((K.height_px, K.width_px, 3))
        out[..., 0] = x[None, :] / n
        out[..., 1] = y[:, None] / n
        out[..., 2] = 1.0 / n
        return out

    # ------------------------------------------------------------------ detection
    def rois(self, cam_pos: np.ndarray, R_enu_cam: np.ndarray, ship: Pose):
        """(box, tight box): pixel boxes (u0, v0, u1, v1 inclusive) where the ship can project, or (None, None)
        when it cannot. The two are the same unless the ship's bounding box straddles the camera plane: the box
        is then the whole image (the region a detection frame casts over, its stride with it), the tight box
        that of the part of the bounding box in front of the plane (its corners there, and where its edges
        cross it), or None when that part falls outside the image. The ship's surface within a millimetre of
        the camera plane is all the tight box leaves out."""
        corners_w = self.caster.ship_corners @ ship.R.T + ship.t
        # the corners in the camera frame as Python floats: the few scalar operations below cost less on them than
        # as numpy calls, and give the same numbers (each is one IEEE operation either way)
        pts = ((corners_w - cam_pos) @ R_enu_cam).tolist()
        front = [p[2] > _NEAR_Z_M for p in pts]
        if not any(front):
            return None, None
        if all(front):
            box = self._pixel_box(pts)
            return box, box
        inside = [p for p, f in zip(pts, front) if f]
        for i, j in _BOX_EDGES:
            if front[i] != front[j]:  # the edge crosses the plane z = _NEAR_Z_M: where
                (xa, ya, za), (xb, yb, zb) = pts[i], pts[j]
                f = (_NEAR_Z_M - za) / (zb - za)
                inside.append((xa + f * (xb - xa), ya + f * (yb - ya), _NEAR_Z_M))
        return (0, 0, self.cfg.width_px - 1, self.cfg.height_px - 1), self._pixel_box(inside)

    def _pixel_box(self, pts) -> tuple[int, int, int, int] | None:
        """The margin-widened pixel box of camera-frame points (x, y, z) in front of the camera, clipped to the
        image."""
        W, H, m = self.cfg.width_px, self.cfg.height_px, self.cfg.roi_margin_px
        K = self.K
        fx, fy, cx, cy = K.fx, K.fy, K.cx, K.cy
        us = [fx * x / z + cx for x, _, z in pts]  # K.project's pixels
        vs = [fy * y / z + cy for _, y, z in pts]
        u0, v0 = math.floor(min(us)) - m, math.floor(min(vs)) - m
        u1, v1 = math.ceil(max(us)) + m, math.ceil(max(vs)) + m
        u0, v0 = max(int(u0), 0), max(int(v0), 0)
        u1, v1 = min(int(u1), W - 1), min(int(v1), H - 1)
        if u0 > u1 or v0 > v1:
            return None
        return u0, v0, u1, v1

    def detect(self, t_s: float, cam_pos: np.ndarray, R_enu_cam: np.ndarray, uav: Pose, ship: Pose) -> FrameGeometry:
        """Visible ship pixels by ray casting over the region of interest."""
        box, tight = self.rois(cam_pos, R_enu_cam, ship)
        if tight is None:  # (the rays of the box, not the tight one, are cast: the stride goes with the box)
            return _summarise(t_s, np.empty(0), np.empty(0), np.empty(0), np.empty(0), 1, 0)
        u0, v0, u1, v1 = box
        area = (u1 - u0 + 1) * (v1 - v0 + 1)
        stride = max(1, math.ceil(math.sqrt(area / self.cfg.max_roi_rays)))
        us = np.arange(u0, u1 + 1, stride, dtype=float)  # the grid's columns and rows, cast row by row
        vs = np.arange(v0, v1 + 1, stride, dtype=float)
        dirs_w = self._ray_table[v0:v1 + 1:stride, u0:u1 + 1:stride].reshape(-1, 3) @ R_enu_cam.T
        d_ship, d_uav = self.caster.cast(cam_pos, dirs_w, uav, ship)
        return _summarise(t_s, us, vs, d_ship, d_uav, stride, len(us) * len(vs))

    def detect_full_frame(self, t_s, cam_pos, R_enu_cam, uav: Pose, ship: Pose) -> FrameGeometry:
        """The same measurement from every pixel of the image (the reference for ``detect``)."""
        uu, vv = np.meshgrid(np.arange(self.cfg.width_px, dtype=float), np.arange(self.cfg.height_px, dtype=float))
        u, v = uu.ravel(), vv.ravel()
        dirs_w = self._ray_table.reshape(-1, 3) @ R_enu_cam.T
        d_ship, d_uav = self.caster.cast(cam_pos, dirs_w, uav, ship)
        return _summarise(t_s, u, v, d_ship, d_uav, 1, len(u))

    # ------------------------------------------------------------------ rendering
    def render(self, cam_pos: np.ndarray, R_enu_cam: np.ndarray, uav: Pose, ship: Pose,
               bbox_px: np.ndarray | None = None) -> np.ndarray:
        """A shaded BGR image at the render resolution: sky, sea, ship, UAV parts in view."""
        rc = self.cfg.render
        dirs_w = self._render_rays @ R_enu_cam.T
        box = self.rois(cam_pos, R_enu_cam, ship)[1]  # full-resolution pixels where the ship can be
        ship_rays = np.empty(0, dtype=np.intp) if box is None else self._render_pixels_near(box)
        d_ship, d_uav = self.caster.cast(cam_pos, dirs_w, uav, ship, ship_rays=ship_rays, uav_only_where_ship=False)
        dz = dirs_w[:, 2].astype(np.float32)
        # sky: lighter toward the horizon; the sea plane z = 0, fading into haze with distance
        down = dz < -1e-6
        with np.errstate(divide="ignore"):
            d_sea = np.where(down, -np.float32(cam_pos[2]) / dz, np.float32(np.inf))
        elev = np.clip(dz, 0.0, 1.0)
        haze = np.clip(d_sea / 4000.0, 0.0, 1.0)
        # the ship's pixels (indices, ascending): only rays cast at the ship can have hit it (d_ship is inf
        # elsewhere)
        ds = d_ship[ship_rays]
        ship_px = ship_rays[np.isfinite(ds) & (ds < d_sea[ship_rays] + 1.0) & ~(d_uav[ship_rays] < ds)]
        shade = None
        if ship_px.size:
            shade = 0.45 + 0.55 * np.abs(self._normals(self.caster._ship, ship, cam_pos, dirs_w[ship_px]) @ _SUN)
            shade = shade.astype(np.float32)
        uav_px = np.flatnonzero(np.isfinite(d_uav))  # the UAV's pixels (indices): where it is hit before the ship
        uav_px = uav_px[~(d_ship[uav_px] < d_uav[uav_px])]
        # one colour plane at a time: numpy's loops run along the pixels (not along 3 channels), and each
        # plane goes into the interleaved image as it is done
        out = np.empty((len(dz), 3), dtype=np.uint8)
        fog = 1 - haze
        for c in range(3):
            plane = _SKY[c] - elev * _SKY_FADE[c]
            sea = _SEA[c] * fog
            sea += _HAZE[c] * haze
            np.copyto(plane, sea, where=down)
            if shade is not None:
                plane[ship_px] = _HULL[c] * shade
            plane[uav_px] = _AIRFRAME[c]
            out[:, c] = plane
        out = out.reshape(rc.height_px, rc.width_px, 3)
        if bbox_px is not None and np.all(np.isfinite(bbox_px)):
            s = np.array([rc.width_px / self.cfg.width_px, rc.height_px / self.cfg.height_px] * 2)
            b = np.round(bbox_px * s).astype(int)
            import cv2

            cv2.rectangle(out, (b[0], b[1]), (b[2], b[3]), (0, 255, 0), 1)
        return out

    def _render_pixels_near(self, box: tuple[int, int, int, int]) -> np.ndarray:
        """Indices (row by row) of the render's pixels within one render pixel of ``box`` (full-resolution
        pixels, scaled by the width ratio): the rows and columns of a rectangle, no per-pixel test."""
        W, H = self.cfg.render.width_px, self.cfg.render.height_px
        s = W / self.cfg.width_px
        c0, c1 = max(math.ceil(box[0] * s - 1), 0), min(math.floor(box[2] * s + 1), W - 1)
        r0, r1 = max(math.ceil(box[1] * s - 1), 0), min(math.floor(box[3] * s + 1), H - 1)
        if c0 > c1 or r0 > r1:
            return np.empty(0, dtype=np.intp)
        return (np.arange(r0, r1 + 1, dtype=np.intp)[:, None] * W + np.arange(c0, c1 + 1, dtype=np.intp)).ravel()

    @staticmethod
    def _normals(scene, pose: Pose, origin_w, dirs_w) -> np.ndarray:
        o, d = pose.to_local(np.broadcast_to(origin_w, dirs_w.shape), dirs_w)
        res = scene.run(np.ascontiguousarray(o, dtype=np.float32), np.ascontiguousarray(d, dtype=np.float32),
                        output=1)
        ng = np.asarray(res["Ng"], dtype=float) @ pose.R.T
        return ng / np.maximum(np.linalg.norm(ng, axis=1), 1e-12)[:, None]

    def encode_jpeg(self, img: np.ndarray) -> bytes:
        import cv2  # OpenCV only where an image is made

        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, self.cfg.render.jpeg_quality])
        if not ok:
            raise RuntimeError("JPEG encoding failed")
        return buf.tobytes()


class Detector:
    """YOLO stand-in: turns the geometric truth of a frame into a noisy detection.

    Pixel noise on the box edges and centre, missed detections, and latency
    (detections arrive ``latency_s`` after exposure), all drawn from ``rng``.
    """

    def __init__(self, cfg: DetectorConfig, rng: np.random.Generator, width_px: int, height_px: int):
        self.cfg = cfg
        self.rng = rng
        self.size = (width_px, height_px)
        self._box_lo = np.array([0, 0, 0, 0])  # a box's clip bounds (the image), made once
        self._box_hi = np.array([width_px - 1, height_px - 1, width_px - 1, height_px - 1])
        self._queue: list[Detection] = []

    def observe(self, frame: FrameGeometry, blackout: bool = False, clutter: np.ndarray | None = None) -> None:
        """One camera frame through the detector. ``blackout``: it reports nothing; ``clutter``: a false box
        (u0, v0, u1, v1) it reports instead of what it saw (fwsim.world.events)."""
        c = self.cfg
        t_arrive = frame.t_s + c.latency_s
        # draw every random number each frame, so one frame's outcome never shifts the next's stream
        miss_draw = self.rng.random()
        noise = self.rng.normal(size=6)
        if clutter is not None:
            b = np.asarray(clutter, dtype=float)
            det = Detection(t_arrive, frame.t_s, True, float(0.5 * (b[0] + b[2])), float(0.5 * (b[1] + b[3])), b)
        elif blackout or frame.visible_px < max(c.min_visible_px, 1e-9) or miss_draw < c.miss_probability:
            det = Detection(t_arrive, frame.t_s, False, math.nan, math.nan, np.full(4, np.nan))
        else:
            b = frame.bbox_px + c.box_noise_px * noise[:4]
            centre = frame.centre_px + c.pixel_noise_px * noise[4:]
            b = np.clip(b, self._box_lo, self._box_hi)
            det = Detection(t_arrive, frame.t_s, True, float(centre[0]), float(centre[1]), b)
        self._queue.append(det)

    def arrived(self, t_s: float) -> Detection | None:
        """The newest detection that has arrived by ``t_s`` (older arrivals are dropped)."""
        out = None
        while self._queue and self._queue[0].t_s <= t_s + 1e-9:
            out = self._queue.pop(0)
        return out
