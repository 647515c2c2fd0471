"""The ship target: configuration, motion (truth) and mesh.

This is the truth side of the harness (docs/design/architecture.md, "Two rules"): the flight
software never sees a :class:`Ship`; the camera ray-casts its mesh and the log
records its :class:`TargetState` for scoring.

Frames (docs/design/architecture.md, "Frames and conventions"):
  * world: ENU, metres; the ship floats on the sea plane z = 0;
  * ship body frame: x = bow (forward), y = port (left), z = up, origin at the
    waterline centre of the hull (midships, on the centre line, z = 0). Its
    bounding box is x in [-L/2, L/2], y in [-W/2, W/2], z in [0, H];
  * headings: ``heading_deg`` in the config and ``heading_ned_rad`` in the
    state are clockwise from North. The ship moves along its heading (no
    current, no drift), so heading = course over ground.

Motion models (``TargetConfig.motion``, discriminated on ``model``):
  * ``constant_velocity`` (the paper's): straight line at ``speed_m_s``; exact.
  * ``constant_turn``: heading(t) = heading + turn_rate * t, constant speed;
    the path is a circle of radius v / |omega|; exact closed form (chord of
    the arc). Positive turn rate turns clockwise seen from above (heading
    increases): a ship heading North with omega > 0 swings to the East.
  * ``zigzag``: heading(t) = heading + amplitude * sin(2 pi t / period),
    constant speed. The sine is smooth (finite heading acceleration), starts on
    the base heading at t = 0 and turns first to starboard (heading increasing)
    when amplitude > 0. Over every whole period the displacement points exactly
    along the base heading (the cross-track part of the velocity is odd in
    time), and its mean speed along it is v * J0(amplitude). Position is
    integrated numerically (see below); velocity and heading are exact.
  * ``speed_changes``: heading fixed; the commanded speed is ``speed_m_s``
    before ``times_s[0]`` and ``speeds_m_s[i]`` from ``times_s[i]`` on; the
    actual speed ramps toward the commanded one at ``accel_m_s2`` (a new
    command in the middle of a ramp turns the ramp around from the speed
    reached). Speed is piecewise linear in time, so the distance travelled is
    piecewise quadratic: computed exactly from breakpoints prepared once.

Numerical integration (zigzag): positions are stored at the nodes
t = k * ``INTEGRATION_STEP_S`` (Gauss-Legendre, 3 points per step, error far
below a millimetre), extended incrementally as later times are asked for and
kept, so calls in increasing time (the loop's 120 Hz) are cheap, and a call at
an earlier time just reads the stored node before it. A state between nodes is
the node plus the same quadrature over the partial step. The result is
therefore a pure function of t: calling out of order gives bit-identical
results to calling in order.

Motion is defined for t >= 0 (simulation time); earlier times raise ValueError.

Mesh: :func:`ship_mesh` (trimesh, ship frame). Ray casting should transform
the rays into the ship frame with :meth:`Ship.pose` and intersect the mesh
built once, rather than transform the mesh every tick (:meth:`Ship.mesh_world`
is for rendering).
"""
from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Annotated, Literal, get_args

import numpy as np
from pydantic import Field, ValidationInfo, field_validator

from fwsim.interface.configbase import StrictModel
from fwsim.interface.frames import wrap_pi

if TYPE_CHECKING:  # trimesh is imported lazily: the scenario schema imports this module
    import trimesh

__all__ = [
    "ConstantTurn",
    "ConstantVelocity",
    "INTEGRATION_STEP_S",
    "Motion",
    "SHIP_TYPES",
    "Ship",
    "SpeedChanges",
    "TargetConfig",
    "TargetState",
    "Zigzag",
    "aim_point_ship_m",
    "hull_height_m",
    "ship_mesh",
    "ship_mesh_parts",
]

#: fixed step (s) of the numerical position integration (zigzag)
INTEGRATION_STEP_S = 0.05

# --------------------------------------------------------------------------- config

_Coord = Annotated[float, Field(ge=-1e6, le=1e6, allow_inf_nan=False)]


class ConstantVelocity(StrictModel):
    """Straight line at constant speed (the paper's target)."""

    model: Literal["constant_velocity"] = Field("constant_velocity", description="motion model")


class ConstantTurn(StrictModel):
    """Steady turn: constant speed and heading rate, the path is a circle of radius v / |omega|."""

    model: Literal["constant_turn"] = Field(description="motion model")
    turn_rate_deg_s: float = Field(ge=-10, le=10,
                                   description="heading rate; positive turns clockwise seen from above "
                                               "(heading increases), 0 is a straight line")


class Zigzag(StrictModel):
    """Sinusoidal weave: heading = heading_deg + amplitude_deg * sin(2 pi t / period_s), constant speed."""

    model: Literal["zigzag"] = Field(description="motion model")
    amplitude_deg: float = Field(ge=-90, le=90,
                                 description="heading swing either side of the base heading; "
                                             "positive turns to starboard first")
    period_s: float = Field(ge=2, le=3600, description="period of the heading oscillation")


class SpeedChanges(StrictModel):
    """Straight line with commanded speed steps, each reached at a finite acceleration."""

    model: Literal["speed_changes"] = Field(description="motion model")
    times_s: list[Annotated[float, Field(ge=0, le=1e5)]] = Field(
        min_length=1, description="times at which the commanded speed switches, strictly increasing")
    speeds_m_s: list[Annotated[float, Field(ge=0, le=25)]] = Field(
        min_length=1, description="commanded speed from the matching time on (one per time)")
    accel_m_s2: float = Field(0.5, gt=0, le=10, description="magnitude of the acceleration while the speed ramps")

    @field_validator("times_s")
    @classmethod
    def _increasing(cls, v: list[float]) -> list[float]:
        if any(b <= a for a, b in zip(v, v[1:])):
            raise ValueError("times must be strictly increasing")
        return v

    @field_validator("speeds_m_s")
    @classmethod
    def _same_length(cls, v: list[float], info: ValidationInfo) -> list[float]:
        times = info.data.get("times_s")
        if times is not None and len(times) != len(v):
            raise ValueError(f"needs one speed per time in times_s ({len(times)} times, {len(v)} speeds)")
        return v


Motion = Annotated[ConstantVelocity | ConstantTurn | Zigzag | SpeedChanges, Field(discriminator="model")]

#: the ship layouts (:func:`ship_mesh_parts`)
ShipType = Literal["bridge_aft", "bridge_forward", "patrol_boat", "ferry"]
SHIP_TYPES: tuple[str, ...] = get_args(ShipType)


class TargetConfig(StrictModel):
    """The ship (scenario section ``target:``); ``TargetConfig.model_validate({})`` is the paper's ship."""

    kind: Literal["ship"] = Field("ship", description="target type")
    type: ShipType = Field("bridge_aft", description="the ship's layout, scaled to length_m, width_m, height_m: "
                                                     "bridge_aft (the paper's ship), bridge_forward (superstructure "
                                                     "forward), patrol_boat (cabin amidships), ferry (decks over "
                                                     "most of the length)")
    length_m: float = Field(55.0, gt=0, le=500, description="overall length (bow to stern)")
    width_m: float = Field(25.0, gt=0, le=100, description="beam (overall width)")
    height_m: float = Field(25.0, gt=0, le=100, description="height of the highest point above the waterline")
    initial_pos_enu_m: list[_Coord] = Field(
        default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3,
        description="waterline centre of the hull at t = 0, world ENU; z must be 0 (sea surface)")
    heading_deg: float = Field(0.0, ge=-360, le=360, description="initial heading, clockwise from North")
    speed_m_s: float = Field(5.0, ge=0, le=25, description="initial speed over ground")
    motion: Motion = Field(default_factory=ConstantVelocity, description="motion model, chosen by 'model'")

    @field_validator("initial_pos_enu_m")
    @classmethod
    def _on_sea(cls, v: list[float]) -> list[float]:
        if v[2] != 0.0:
            raise ValueError(f"the ship floats on the sea plane: z must be 0 (got z = {v[2]:g})")
        return v


# --------------------------------------------------------------------------- state


@dataclass(frozen=True, slots=True)
class TargetState:
    """Truth state of the ship (harness side only; never given to the flight software)."""

    t_s: float
    pos_enu_m: np.ndarray  # (3,) waterline centre of the hull, world ENU (z = 0)
    vel_enu_m_s: np.ndarray  # (3,) velocity over ground, world ENU (z = 0)
    heading_ned_rad: float  # heading = course, clockwise from North, in [-pi, pi)
    speed_m_s: float  # speed over ground (>= 0)


# --------------------------------------------------------------------------- motion

# 3-point Gauss-Legendre on [0, 1]: nodes and weights
_GL_X = (0.5 - 0.5 * math.sqrt(0.6), 0.5, 0.5 + 0.5 * math.sqrt(0.6))
_GL_W = (5.0 / 18.0, 8.0 / 18.0, 5.0 / 18.0)


def _sinc(x: float) -> float:
    """sin(x) / x, 1 at 0 (series below 1e-4 avoids cancellation)."""
    if abs(x) < 1e-4:
        return 1.0 - x * x / 6.0
    return math.sin(x) / x


class Ship:
    """A ship moving on the sea plane: ``state(t)``, ``pose(t)`` and its mesh.

    Deterministic: ``state(t)`` is a pure function of ``t`` (and the config),
    whatever order it is called in.
    """

    def __init__(self, cfg: TargetConfig):
        self.cfg = cfg
        m = cfg.motion
        self._model = m.model
        self._x0 = float(cfg.initial_pos_enu_m[0])
        self._y0 = float(cfg.initial_pos_enu_m[1])
        self._psi0 = math.radians(cfg.heading_deg)
        self._v = float(cfg.speed_m_s)
        self._s0 = math.sin(self._psi0)
        self._c0 = math.cos(self._psi0)
        self._psi0_wrapped = wrap_pi(self._psi0)
        if m.model == "constant_turn":
            self._omega = math.radians(m.turn_rate_deg_s)
        elif m.model == "zigzag":
            self._amp = math.radians(m.amplitude_deg)
            self._w = 2.0 * math.pi / m.period_s
            self._nodes_e = [0.0]  # position offsets from the start at t = k * INTEGRATION_STEP_S
            self._nodes_n = [0.0]
        elif m.model == "speed_changes":
            self._knot_t, self._knot_v, self._knot_d = _speed_knots(self._v, m.times_s, m.speeds_m_s, m.accel_m_s2)
        self._manoeuvres: list[_Manoeuvre] = []  # fwsim.world.events target_manoeuvre, oldest first

    # ------------------------------------------------------------------ truth

    def state(self, t_s: float) -> TargetState:
        """Ship state at simulation time ``t_s`` (s, >= 0)."""
        t = float(t_s)
        if not t >= 0.0:
            raise ValueError(f"ship motion is defined for t_s >= 0 (got {t_s!r})")
        if self._manoeuvres and t >= self._manoeuvres[0].t0:
            return self._manoeuvred(t)
        return self._base_state(t)

    def manoeuvre(self, t_s: float, course_deg: float | None, speed_m_s: float | None,
                  turn_rate_deg_s: float, accel_m_s2: float) -> float:
        """From ``t_s`` on, leave the motion model: turn at ``turn_rate_deg_s`` the short way to
        ``course_deg`` and ramp at ``accel_m_s2`` to ``speed_m_s`` (None: keep it), then hold both. Times
        before ``t_s`` keep their states (a manoeuvre never rewrites the past); returns how long it takes."""
        start = self.state(t_s)
        m = _Manoeuvre(float(t_s), start, course_deg, speed_m_s, turn_rate_deg_s, accel_m_s2)
        self._manoeuvres = [mm for mm in self._manoeuvres if mm.t0 < m.t0] + [m]
        return m.duration

    def _manoeuvred(self, t: float) -> TargetState:
        m = next(mm for mm in reversed(self._manoeuvres) if t >= mm.t0)
        return m.state(t)

    def _base_state(self, t: float) -> TargetState:
        model = self._model
        if model == "constant_velocity":
            v = self._v
            d = v * t
            return TargetState(t, np.array([self._x0 + d * self._s0, self._y0 + d * self._c0, 0.0]),
                               np.array([v * self._s0, v * self._c0, 0.0]), self._psi0_wrapped, v)
        if model == "constant_turn":
            v, half = self._v, 0.5 * self._omega * t
            psi = self._psi0 + 2.0 * half
            psi_mid = self._psi0 + half
            chord = v * t * _sinc(half)  # straight-line distance along the mean heading of the arc
            sp, cp = math.sin(psi), math.cos(psi)
            return TargetState(t, np.array([self._x0 + chord * math.sin(psi_mid),
                                            self._y0 + chord * math.cos(psi_mid), 0.0]),
                               np.array([v * sp, v * cp, 0.0]), wrap_pi(psi), v)
        if model == "zigzag":
            de, dn = self._zigzag_offset(t)
            psi = self._zigzag_heading(t)
            v = self._v
            return TargetState(t, np.array([self._x0 + de, self._y0 + dn, 0.0]),
                               np.array([v * math.sin(psi), v * math.cos(psi), 0.0]), wrap_pi(psi), v)
        # speed_changes
        v, d = self._speed_and_distance(t)
        return TargetState(t, np.array([self._x0 + d * self._s0, self._y0 + d * self._c0, 0.0]),
                           np.array([v * self._s0, v * self._c0, 0.0]), self._psi0_wrapped, v)

    def pose(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        """``(pos_enu_m, R_enu_from_ship)``: the ship frame origin and orientation in the world.

        ``p_enu = pos_enu_m + R_enu_from_ship @ p_ship``; the columns of R are
        the bow, port and up directions in ENU (the ship stays level).
        """
        st = self.state(t_s)
        return st.pos_enu_m, r_enu_from_ship(st.heading_ned_rad)

    def aim_point_enu_m(self, t_s: float) -> np.ndarray:
        """World position of :func:`aim_point_ship_m` at ``t_s``."""
        pos, R = self.pose(t_s)
        return pos + R @ aim_point_ship_m(self.cfg)

    # ------------------------------------------------------------------ mesh

    @cached_property
    def mesh(self) -> trimesh.Trimesh:
        """The ship mesh in the ship frame (built once; see :func:`ship_mesh`)."""
        return ship_mesh(self.cfg)

    def mesh_world(self, t_s: float) -> trimesh.Trimesh:
        """A copy of the mesh moved to its world pose at ``t_s``, for rendering.

        Ray casting should not use this every tick: transform the rays into the
        ship frame with :meth:`pose` (``p_ship = R.T @ (p_enu - pos)``,
        ``d_ship = R.T @ d_enu``) and intersect :attr:`mesh`, whose ray
        acceleration structure is then built only once.
        """
        pos, R = self.pose(t_s)
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = pos
        out = self.mesh.copy()
        out.apply_transform(T)
        return out

    # ------------------------------------------------------------------ internals

    def _zigzag_heading(self, t: float) -> float:
        return self._psi0 + self._amp * math.sin(self._w * t)

    def _zigzag_integral(self, t0: float, t1: float) -> tuple[float, float]:
        """Displacement (east, north) between t0 and t1 by 3-point Gauss-Legendre."""
        h = t1 - t0
        de = dn = 0.0
        for x, w in zip(_GL_X, _GL_W):
            psi = self._zigzag_heading(t0 + x * h)
            de += w * math.sin(psi)
            dn += w * math.cos(psi)
        k = self._v * h
        return k * de, k * dn

    def _zigzag_offset(self, t: float) -> tuple[float, float]:
        dt = INTEGRATION_STEP_S
        k = int(t / dt)
        ne, nn = self._nodes_e, self._nodes_n
        while len(ne) <= k:  # extend the stored nodes up to k (incremental)
            j = len(ne) - 1
            de, dn = self._zigzag_integral(j * dt, (j + 1) * dt)
            ne.append(ne[j] + de)
            nn.append(nn[j] + dn)
        tk = k * dt
        if t == tk:
            return ne[k], nn[k]
        de, dn = self._zigzag_integral(tk, t)
        return ne[k] + de, nn[k] + dn

    def _speed_and_distance(self, t: float) -> tuple[float, float]:
        kt = self._knot_t
        i = bisect_right(kt, t) - 1  # kt[0] = 0 <= t
        if i == len(kt) - 1:
            v = self._knot_v[i]
            return v, self._knot_d[i] + v * (t - kt[i])
        v0, v1 = self._knot_v[i], self._knot_v[i + 1]
        tau = t - kt[i]
        v = v0 + (v1 - v0) * tau / (kt[i + 1] - kt[i])
        return v, self._knot_d[i] + 0.5 * (v0 + v) * tau


class _Manoeuvre:
    """A course and speed change from a ship state: heading at a constant rate the short way to the new
    course, speed at a constant acceleration to the new one (both from ``t0``), then constant. Positions
    are integrated (3-point Gauss-Legendre) from stored nodes every INTEGRATION_STEP_S."""

    def __init__(self, t0: float, start: TargetState, course_deg, speed_m_s, turn_rate_deg_s: float,
                 accel_m_s2: float):
        self.t0 = t0
        self.p0 = np.asarray(start.pos_enu_m, dtype=float).copy()
        self.psi0, self.v0 = float(start.heading_ned_rad), float(start.speed_m_s)
        dpsi = 0.0 if course_deg is None else wrap_pi(math.radians(course_deg) - self.psi0)
        dv = 0.0 if speed_m_s is None else float(speed_m_s) - self.v0
        self.rate = math.copysign(math.radians(turn_rate_deg_s), dpsi)
        self.t_turn = abs(dpsi) / math.radians(turn_rate_deg_s)
        self.acc = math.copysign(accel_m_s2, dv)
        self.t_speed = abs(dv) / accel_m_s2
        self.duration = max(self.t_turn, self.t_speed)
        self._nodes = [(0.0, 0.0)]  # displacement (east, north) at tau = k * INTEGRATION_STEP_S

    def _heading_speed(self, tau: float) -> tuple[float, float]:
        return (self.psi0 + self.rate * min(tau, self.t_turn), self.v0 + self.acc * min(tau, self.t_speed))

    def _integral(self, a: float, b: float) -> tuple[float, float]:
        h = b - a
        de = dn = 0.0
        for x, w in zip(_GL_X, _GL_W):
            psi, v = self._heading_speed(a + x * h)
            de += w * v * math.sin(psi)
            dn += w * v * math.cos(psi)
        return h * de, h * dn

    def _offset(self, tau: float) -> tuple[float, float]:
        dt = INTEGRATION_STEP_S
        if tau > self.duration:  # past the manoeuvre: a straight line from its end
            e, n = self._offset(self.duration)
            psi, v = self._heading_speed(self.duration)
            return e + v * math.sin(psi) * (tau - self.duration), n + v * math.cos(psi) * (tau - self.duration)
        k = int(tau / dt)
        nodes = self._nodes
        while len(nodes) <= k:
            j = len(nodes) - 1
            b = min((j + 1) * dt, self.duration)
            de, dn = self._integral(j * dt, b)
            nodes.append((nodes[j][0] + de, nodes[j][1] + dn))
        de, dn = self._integral(k * dt, tau) if tau > k * dt else (0.0, 0.0)
        return nodes[k][0] + de, nodes[k][1] + dn

    def state(self, t: float) -> TargetState:
        tau = t - self.t0
        e, n = self._offset(tau)
        psi, v = self._heading_speed(tau)
        return TargetState(t, np.array([self.p0[0] + e, self.p0[1] + n, 0.0]),
                           np.array([v * math.sin(psi), v * math.cos(psi), 0.0]), wrap_pi(psi), v)


def _speed_knots(v0: float, times: list[float], speeds: list[float], accel: float):
    """Breakpoints (t, speed, distance) of the piecewise-linear speed of ``speed_changes``.

    Between breakpoints the speed is linear in time; after the last one it is constant.
    """
    kt, kv = [0.0], [v0]
    t_cur, v_cur, target = 0.0, v0, v0
    for t_end, next_target in [*zip(times, speeds), (math.inf, None)]:
        if t_end > t_cur and v_cur != target:  # ramp toward the current target during [t_cur, t_end)
            t_reach = t_cur + abs(target - v_cur) / accel
            if t_reach <= t_end:
                t_cur, v_cur = t_reach, target
            else:
                v_cur += math.copysign(accel * (t_end - t_cur), target - v_cur)
                t_cur = t_end
            if t_cur > kt[-1]:
                kt.append(t_cur)
                kv.append(v_cur)
        if t_end > t_cur and t_end != math.inf:  # holding the target until t_end: a breakpoint there
            t_cur = t_end
            kt.append(t_cur)
            kv.append(v_cur)
        target = next_target
    kd = [0.0]
    for i in range(1, len(kt)):
        kd.append(kd[-1] + 0.5 * (kv[i - 1] + kv[i]) * (kt[i] - kt[i - 1]))
    return kt, kv, kd


def r_enu_from_ship(heading_ned_rad: float) -> np.ndarray:
    """R_enu_from_ship for a level ship: columns bow = [sin psi, cos psi, 0], port = [-cos psi, sin psi, 0], up."""
    s, c = math.sin(heading_ned_rad), math.cos(heading_ned_rad)
    return np.array([[s, -c, 0.0], [c, s, 0.0], [0.0, 0.0, 1.0]])


# --------------------------------------------------------------------------- mesh

#: proportions of the mesh (fractions of length L, width W, height H)
HULL_HEIGHT_FRAC = {"bridge_aft": 0.30, "bridge_forward": 0.30, "patrol_boat": 0.40, "ferry": 0.25}  # deck / H
BOW_FRAC = {"bridge_aft": 0.20, "bridge_forward": 0.15, "patrol_boat": 0.30, "ferry": 0.12}  # bow taper / L


def hull_height_m(cfg: TargetConfig) -> float:
    """Height of the hull deck above the waterline (m)."""
    return HULL_HEIGHT_FRAC[cfg.type] * cfg.height_m


def aim_point_ship_m(cfg: TargetConfig) -> np.ndarray:
    """The point a terminal dive aims at, in the ship frame: [0, 0, hull height / 2].

    Midships on the centre line, half-way up the hull: inside the hull, under
    the centre of the deck, so a dive converging on it from any direction meets
    the hull (or the superstructure above it) first.
    """
    return np.array([0.0, 0.0, 0.5 * hull_height_m(cfg)])


def _prism(polygon_xy, z0: float, z1: float) -> trimesh.Trimesh:
    """Closed prism: a convex polygon (counter-clockwise seen from +z) extruded from z0 to z1."""
    import trimesh

    p = np.asarray(polygon_xy, dtype=float)
    n = len(p)
    verts = np.vstack([np.column_stack([p, np.full(n, z0)]), np.column_stack([p, np.full(n, z1)])])
    faces = []
    for i in range(1, n - 1):
        faces.append([0, i + 1, i])  # bottom, normal -z
        faces.append([n, n + i, n + i + 1])  # top, normal +z
    for i in range(n):
        j = (i + 1) % n
        faces.append([i, j, n + j])  # sides, outward for a counter-clockwise polygon
        faces.append([i, n + j, n + i])
    return trimesh.Trimesh(verts, np.array(faces), process=True)


def _box(x0: float, x1: float, y0: float, y1: float, z0: float, z1: float) -> trimesh.Trimesh:
    return _prism([(x0, y0), (x1, y0), (x1, y1), (x0, y1)], z0, z1)


def _hull(cfg: TargetConfig) -> trimesh.Trimesh:
    """The hull: full beam, a bow tapering to a point, a transom stern with chamfered corners."""
    L, W = cfg.length_m, cfg.width_m
    xb = 0.5 * L - BOW_FRAC[cfg.type] * L  # where the bow taper starts
    xs = -0.5 * L  # transom
    return _prism([(xs, -0.42 * W), (xs + 0.04 * L, -0.5 * W), (xb, -0.5 * W), (0.5 * L, 0.0),
                   (xb, 0.5 * W), (xs + 0.04 * L, 0.5 * W), (xs, 0.42 * W)], 0.0, hull_height_m(cfg))


def _funnel(x0: float, x1: float, half_w: float, z0: float, z1: float) -> trimesh.Trimesh:
    """A funnel: an elongated octagon-ish prism from x0 (aft) to x1."""
    d = 0.3 * (x1 - x0)
    return _prism([(x0, -0.6 * half_w), (x0 + d, -half_w), (x1, -half_w), (x1, half_w), (x0 + d, half_w),
                   (x0, 0.6 * half_w)], z0, z1)


def ship_mesh_parts(cfg: TargetConfig) -> list[tuple[str, trimesh.Trimesh]]:
    """The closed convex parts of the ship, ``(name, mesh)``, in the ship frame, for its ``type``.

    Every layout has a hull (HULL_HEIGHT_FRAC of H high, the bow tapering to a point over BOW_FRAC of the
    length, a chamfered transom) and parts on it that reach the full height H; the parts touch but do not
    overlap, and the bounding box is exactly [-L/2, L/2] x [-W/2, W/2] x [0, H].

    * bridge_aft (the paper's ship): deckhouse and wheelhouse (the bridge) aft of midships, narrower than
      the beam, a funnel, and a mast to the full height.
    * bridge_forward: deckhouse and wheelhouse forward of midships, a mast on the wheelhouse, open deck aft.
    * patrol_boat: a high-sided hull, a cabin amidships and a mast on it.
    * ferry: two decks of superstructure over most of the length, a bridge deck forward, a funnel aft.
    """
    L, W, H = cfg.length_m, cfg.width_m, cfg.height_m
    hh = hull_height_m(cfg)
    hull = _hull(cfg)
    if cfg.type == "bridge_aft":
        z_house, z_wheel = 0.50 * H, 0.65 * H  # deckhouse and wheelhouse roofs
        return [("hull", hull),
                ("deckhouse", _box(-0.32 * L, -0.04 * L, -0.36 * W, 0.36 * W, hh, z_house)),
                ("wheelhouse", _box(-0.20 * L, -0.07 * L, -0.42 * W, 0.42 * W, z_house, z_wheel)),
                ("funnel", _prism([(-0.30 * L, -0.05 * W), (-0.28 * L, -0.08 * W), (-0.23 * L, -0.08 * W),
                                   (-0.23 * L, 0.08 * W), (-0.28 * L, 0.08 * W), (-0.30 * L, 0.05 * W)],
                                  z_house, 0.85 * H)),
                ("mast", _box(-0.145 * L, -0.125 * L, -0.015 * W, 0.015 * W, z_wheel, H))]
    if cfg.type == "bridge_forward":
        z_house, z_wheel = 0.55 * H, 0.75 * H
        return [("hull", hull),
                ("deckhouse", _box(0.08 * L, 0.33 * L, -0.40 * W, 0.40 * W, hh, z_house)),
                ("wheelhouse", _box(0.14 * L, 0.30 * L, -0.45 * W, 0.45 * W, z_house, z_wheel)),
                ("mast", _box(0.20 * L, 0.22 * L, -0.015 * W, 0.015 * W, z_wheel, H))]
    if cfg.type == "patrol_boat":
        z_cabin = 0.75 * H
        return [("hull", hull),
                ("deckhouse", _box(-0.18 * L, 0.12 * L, -0.30 * W, 0.30 * W, hh, z_cabin)),
                ("mast", _box(-0.04 * L, -0.01 * L, -0.03 * W, 0.03 * W, z_cabin, H))]
    # ferry
    z1, z2, z3 = 0.55 * H, 0.80 * H, 0.92 * H
    return [("hull", hull),
            ("deckhouse", _box(-0.44 * L, 0.30 * L, -0.47 * W, 0.47 * W, hh, z1)),
            ("upper_deck", _box(-0.36 * L, 0.24 * L, -0.44 * W, 0.44 * W, z1, z2)),
            ("wheelhouse", _box(0.08 * L, 0.22 * L, -0.46 * W, 0.46 * W, z2, z3)),
            ("funnel", _funnel(-0.30 * L, -0.20 * L, 0.10 * W, z2, H))]


_PART_RGBA = {"hull": (90, 95, 105, 255), "deckhouse": (225, 225, 220, 255), "wheelhouse": (235, 235, 230, 255),
              "upper_deck": (230, 230, 225, 255),
              "funnel": (40, 40, 45, 255), "mast": (60, 60, 60, 255)}


def ship_mesh(cfg: TargetConfig) -> trimesh.Trimesh:
    """The ship as one mesh in the ship frame (x bow, y port, z up, origin at the waterline centre).

    Bounding box exactly x in [-L/2, L/2], y in [-W/2, W/2], z in [0, H].
    Built by concatenating the closed convex parts of :func:`ship_mesh_parts`
    (no boolean union: that would need an extra dependency). Each part is
    watertight; the whole is a set of touching closed shells, which is what
    ray casting needs (only the first hit matters). Faces carry per-part colours.
    """
    import trimesh

    parts = []
    for name, part in ship_mesh_parts(cfg):
        part.visual.face_colors = _PART_RGBA[name]
        parts.append(part)
    return trimesh.util.concatenate(parts)


class HullVolume:
    """Point-in-ship test in the ship frame: inside any of the ship's closed convex parts.

    Each part is kept as its outward face planes (n . p <= d inside); a
    bounding-box test rejects most points first. Used to end a run when the UAV
    reaches the ship and to score a hit from a log.
    """

    def __init__(self, cfg: TargetConfig):
        self.parts = []
        for _, part in ship_mesh_parts(cfg):
            normals = np.asarray(part.face_normals, dtype=float)
            d = np.einsum("ij,ij->i", normals, np.asarray(part.triangles[:, 0], dtype=float))
            self.parts.append((np.asarray(part.bounds, dtype=float), normals, d))
        self.lo = np.min([b[0] for b, _, _ in self.parts], axis=0)
        self.hi = np.max([b[1] for b, _, _ in self.parts], axis=0)

    def contains(self, p_ship: np.ndarray) -> bool:
        p = np.asarray(p_ship, dtype=float)
        if np.any(p < self.lo) or np.any(p > self.hi):
            return False
        for (lo, hi), n, d in self.parts:
            if np.all(p >= lo) and np.all(p <= hi) and np.all(n @ p <= d + 1e-9):
                return True
        return False
