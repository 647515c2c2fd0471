"""Terminal guidance: quaternion-based biased PN with an impact-angle constraint.

Paper section "Phase 3: Biased proportional navigation for terminal guidance",
eq. (26) (after Kim, Park, Park & Ryoo, "Quaternion based three-dimensional
impact angle control guidance law", IEEE TAES 57, 2021)::

    u = N_sigma (Omega x V_p)  -  (N_f theta / t_go) (n x V_p)          (1)
      = N_sigma (Omega x V_p)  +  (N_f theta / t_go) (V_p x n)    (the paper's print)

with, all in the world frame (ENU, metres, seconds):

  * ``r = r_q - r_p`` the target (aim point) relative to the UAV,
    ``r_dot = V_q - V_p``;
  * ``Omega = (r x r_dot) / |r|^2`` the line-of-sight (LOS) rate vector;
  * ``t_go = |r| / |V_p|`` (paper; floored at ``min_tgo_s``);
  * ``theta = angle(V_p, V_f)`` the turn still to make, computed as
    ``atan2(|V_p x V_f|, V_p . V_f)`` (exact also near 0 and pi, unlike acos);
  * ``n = (V_p x V_f) / |V_p x V_f|`` the axis about which a positive rotation
    turns V_p toward V_f;
  * ``V_f`` the wanted terminal velocity direction (``vf_enu``).

``u`` is an acceleration perpendicular to V_p, gravity not included: exactly
what ``fwsim.interface.messages.AccelCommand`` carries.

The sign of the bias term: derived, and the paper's print is RIGHT
--------------------------------------------------------------------
It is tempting to "correct" the bias term to ``+(N_f theta/t_go) (n x V_p)``
("turn V toward V_f"; this was proposed during development). That flip is
wrong for the paper's gains; eq. (26) is correct as printed:

1. *Both terms are rotations of the velocity.* At constant speed a
   perpendicular acceleration ``a`` turns V about ``omega = V x a / |V|^2``:
   ``V_dot = omega x V``. For ``a = k (n x V)``::

       d/dt cos(theta) = (a . V_f) / (|V||V_f|) = k (n x V) . V_f / (|V||V_f|)
                       = k n . (V x V_f) / (|V||V_f|) = k sin(theta)

   (triple product), i.e. ``theta_dot = -k``: ``n x V`` turns V toward V_f,
   ``V x n = -(n x V)`` turns it away. Equivalently
   ``V x (V x V_f) = V (V . V_f) - V_f |V|^2``, whose part perpendicular to V
   is ``-|V|^2 V_f_perp``. The paper's ``(N_f V_p / t_go) x n theta`` is
   ``V_p x n``: it turns V AWAY from V_f at the rate ``N_f theta / t_go``.

2. *That is what the optimal law does.* Eq. (26) is the 3-D form of the
   energy-optimal impact-angle law (Ryoo's group, gains 6 and 2). Planar, small
   angles, target at the origin, UAV lateral offset y, ``y_ddot = a``, final
   conditions ``y(t_f) = 0`` and ``y_dot(t_f) = V gamma_f``, minimum
   ``integral a^2``: the solution (a linear in time, fitted to both end
   conditions) is::

       a = -(6 y + 4 y_dot T + 2 V gamma_f T) / T^2,         T = t_go
         = 6 V lambda_dot + 2 V (gamma - gamma_f) / T

   using ``lambda = -y/(V T)``, ``lambda_dot = -(y + y_dot T)/(V T^2)``,
   ``y_dot = V gamma``. The first term is PN with N_sigma = 6
   (``Omega x V`` in 3-D); the second turns gamma AWAY from gamma_f at
   ``N_f theta / t_go`` with N_f = 2: the paper's print. Intuition: flying level
   straight at a target at the same height and asked to arrive in a 30 deg
   dive, the optimal path first climbs (bows out away from V_f) so that it can come down steeply at
   the end; the N = 6 PN term over-steers toward the LOS, the bias balances it.

3. *Closed-loop check.* With ``z1 = y + y_dot T`` (zero-effort miss) and
   ``z2 = y_dot - V gamma_f``: ``z1' = a T``, ``z2' = a``. For
   ``a = -N z1/T^2 - K z2/T`` the solutions go as ``z1 ~ T^m``,
   ``z2 ~ T^(m-1)`` with ``m^2 - (1 + N + K) m + N = 0``. Paper sign
   (``K = -2``, N = 6): ``m = 2, 3``, miss and angle error both vanish with a
   finite command. Flipped sign (``K = +2``): ``m = 0.73, 8.27``; the angle
   error grows like ``T^-0.27`` and the command diverges at impact.

``tests/test_bpng.py`` pins all three: the bias term's finite-difference effect
(theta grows at ``N_f theta / t_go``), the planar equality with the optimal
law, and a closed loop in which the flipped sign misses the impact angle
(by 11 deg in the paper's case; in the kinematic sweep no case of the flipped
sign meets 3 deg, median error ~100 deg) while this sign meets it to < 1 deg.

Decomposition in the body frame (eq. IAC, bpngdot, bpng_cmd)
------------------------------------------------------------
Under coordinated flight (body x along V_p) ``B_u = R_frd_from_enu u =
[~0, u_y, u_z]`` and ``B_u = omega_cmd x [V, 0, 0]`` gives
``omega_cmd = [0, -u_z/V, u_y/V]`` (``body_rates_from_accel``). The paper
writes ``R_x(phi) R_y(theta) R_z(psi)``: that is R_frd_from_NED; with the
world in ENU it is ``R_frd_from_ned @ R_NED_FROM_ENU``. These rates are kept
for the log and the documentation only. A fixed wing cannot yaw directly, so
fwsim does not send them: ``Bpng.step`` returns an ``AccelCommand`` (autopilot
mode (b), docs/design/algorithms.md) and the autopilot realises ``u`` by bank-to-turn:
it banks so that lift points along ``u - g_perp`` (gravity compensated), so the
paper's yaw rate ``u_r = u_y/V`` becomes a bank toward ``+y`` body, and
``u_q = -u_z/V`` becomes the pitch rate (plus the load-factor loop); the
rudder only coordinates.

Guards
------
* ``theta < eps`` (V_p along V_f): the bias term is 0 (n undefined, theta = 0).
* ``theta ~ pi`` (V_p against V_f): n is undefined. Fallback: n is the part of
  world "up" perpendicular to V_p, i.e. n lies in the vertical plane that
  contains V_p, so the bias rotates V_p about a near-vertical axis: a level
  turn (the manoeuvre a fixed wing does best, never a loop). Its sign is
  chosen so that the bias term turns V_p toward the side the target is on
  (East-perpendicular if V_p is vertical). The turn direction has no preferred
  side here, so any choice is as good; this one is deterministic and bounded.
  NOTE: with the (correct) "away" sign, V_p = -V_f is where the bias term
  drives V_p when the geometry is far from a collision course with V_f; see
  "Capture region" below.
* ``t_go -> 0``: ``t_go = max(|r| / |V_p|, min_tgo_s)``.
* ``|r| -> 0``: below ``_MIN_RANGE_M`` the LOS rate is set to 0.
* ``|V_p| -> 0``: below ``_MIN_SPEED_M_S`` the command is 0 (no direction).
* Any part along V_p is removed (the command is perpendicular), then the
  magnitude is capped at ``max_accel_m_s2`` keeping the direction.
* Non-finite inputs (an estimate that is not valid yet): zero command,
  NaN status; the UAV flies straight (the autopilot holds 1 g).

Capture region (what the law cannot do)
---------------------------------------
Eq. (26) is the *linearised* optimal law: it assumes the UAV is not far
from a collision course whose direction is close to V_f. When phase 3 starts
with the UAV's approach direction far from the impact heading, the PN term
cannot hold a collision course against the bias, the bias turns V_p all the
way to ``-V_f`` (where it has no authority) and the UAV flies away from the
target with a small command (~2 m/s^2: not an acceleration-limit problem).
Kinematic sweeps (25 m/s, |u| <= 25 m/s^2, 500 m up, theta_f -20..-60 deg,
ship 0 or 10 m/s in any direction), with ``delta`` = bearing from the UAV to
the ship minus ``impact_heading_deg``:

  * start 1100 m out, level, pointing at the ship: every case hits within
    3 m / 3 deg for |delta| <= 45 deg; at 60 deg some fail (10 m/s ship
    moving against the impact heading); a still ship is fine to 120 deg;
  * start on the 500 m loiter circle, velocity along the circle: all hit for
    delta in [-20, +10] deg (counter-clockwise orbit) and [-10, +20] deg
    (clockwise); a still ship is fine from any bearing.

So the phase 2 -> 3 switch must start BPNG when the bearing to the target is
close to ``impact_heading_deg`` (within +-10 deg from the loiter; the orbit
passes it once a lap). A second limit: an impact much shallower than the LOS
at the switch (theta_f = -20 deg from the loiter's 45 deg LOS) makes the
optimal path bow under the LOS; with the ship crossing the impact heading it
can level off a few metres below the sea hundreds of metres short. The law
knows nothing of the sea: keep |theta_f| near or above the LOS angle, or
switch farther out.

The capture guard (``capture_turn_deg_s``, 3 deg/s by default; a departure from the printed law).
From a loiter round a fast ship in wind the UAV's ground velocity at the
switch can point 77-105 deg off the line of sight with a LOS rate of only
0.01 rad/s: the PN term is then ~1 m/s^2 and the bias term, under its cap,
~0.8-1 m/s^2 against it, so the UAV flies on beside the ship, its range held
for 20 s (the go-around's stall rule), lap after lap. Far off the nose (the
look angle above ``capture_look_deg``, 60) the guard requires the command to
turn V_p toward the line of sight at ``capture_turn_deg_s`` or more, and
scales the bias term down (to zero at most) where it would take that away;
elsewhere, and wherever PN already wins, the command is the law's.
``bias_scale`` in the status says how much of the bias is applied.

The bias angle cap (``bias_angle_cap_deg``, 90 by default; a departure from
the printed law). Around a fast ship the loiter's ground velocity at the
switch can point more than 90 deg off V_f (a 10 m/s ship crossing the impact
heading: 102 deg). There the bias term, ``N_f theta / t_go`` with theta past
90 deg, cancels the PN term and the UAV flies on with ~0.6 m/s^2 of command,
away from the ship. The law is the small-angle optimum; beyond 90 deg the
bias keeps its 90-deg value, the PN term turns the UAV onto a collision
course and the bias takes over as theta comes down. Below 90 deg nothing
changes. ``None`` restores the printed law; ``tests/test_bpng.py`` flies the
case both ways.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from controllers.config import BpngConfig
from fwsim.interface.frames import cross3, dcm_enu_from_frd
from fwsim.interface.messages import AccelCommand

_MIN_RANGE_M = 1e-3  # below: LOS rate undefined, set to 0
_MIN_SPEED_M_S = 1e-3  # below: velocity direction undefined, command 0
_PARALLEL_EPS = 1e-9  # |V_hat x V_f_hat| below: V_p (anti-)parallel to V_f


# --------------------------------------------------------------------------- geometry


def vf_enu(theta_f_deg: float, psi_f_deg: float) -> np.ndarray:
    """Unit terminal velocity direction V_f in ENU from the impact flight-path and heading angles.

    ``theta_f_deg``: flight-path angle, negative when diving; ``psi_f_deg``:
    heading clockwise from North (docs/design/architecture.md, "Frames and conventions"). The paper's
    ``[cos th cos psi, cos th sin psi, -sin th]`` is the same vector in NED; in
    ENU it is ``[cos th sin psi, cos th cos psi, sin th]``.
    """
    th, ps = math.radians(theta_f_deg), math.radians(psi_f_deg)
    return np.array([math.cos(th) * math.sin(ps), math.cos(th) * math.cos(ps), math.sin(th)])


def body_rates_from_accel(u_enu, euler_ned_rad, V: float) -> np.ndarray:
    """The paper's rate command (eq. bpng_cmd) ``[0, -u_z/V, u_y/V]`` (rad/s, FRD) for the log.

    ``B_u = R_frd_from_enu u`` (eq. IAC with the world in ENU); ``B_u =
    omega x [V, 0, 0]`` (eq. bpngdot) under coordinated flight. fwsim's
    autopilot does not fly these rates; it realises ``u`` by bank-to-turn
    (``AccelCommand``, autopilot mode (b)).
    """
    b_u = dcm_enu_from_frd(euler_ned_rad).T @ np.asarray(u_enu, dtype=float)
    v = max(float(V), _MIN_SPEED_M_S)
    return np.array([0.0, -b_u[2] / v, b_u[1] / v])


class BpngTerms(NamedTuple):
    """Every intermediate of eq. (1); arrays of shape (..., 3) or (...)."""

    los_rate_rad_s: np.ndarray  # Omega
    t_go_s: np.ndarray
    range_m: np.ndarray
    theta_err_rad: np.ndarray  # angle(V_p, V_f)
    accel_pn: np.ndarray  # N_sigma Omega x V_p
    accel_bias: np.ndarray  # -(N_f theta / t_go) n x V_p
    accel_cmd: np.ndarray  # perpendicular part of the sum, capped
    saturated: np.ndarray  # the cap was active
    bias_scale: np.ndarray  # the share of the bias term in the command (< 1: held back by the capture guard)


def _cross(a, b):
    """a x b over the last axis (fwsim.interface.frames.cross3 for two single vectors: the same products, without
    np.cross's overhead)."""
    if a.ndim == 1 and b.ndim == 1:
        return cross3(a, b)
    return np.cross(a, b)


def _dot(a, b):
    return np.sum(a * b, axis=-1)


def _norm(a):
    return np.sqrt(_dot(a, a))


def bpng_accel(r, r_dot, v_p, v_f, *, n_sigma: float, n_f: float, min_tgo_s: float,
               max_accel_m_s2: float, bias_angle_cap_rad: float = math.inf,
               capture_turn_rad_s: float | None = None, capture_look_rad: float = math.pi / 3) -> BpngTerms:
    """Eq. (1) with its guards, vectorised over leading axes (inputs (..., 3), world ENU).

    ``r = r_q - r_p``, ``r_dot = V_q - V_p``, ``v_p`` the UAV velocity, ``v_f``
    the wanted terminal direction (any length > 0). ``bias_angle_cap_rad``: the
    bias term takes ``min(theta, cap)`` (``BpngConfig.bias_angle_cap_deg``).
    ``capture_turn_rad_s``: the capture guard (``BpngConfig.capture_turn_deg_s``; None: off).
    """
    r = np.asarray(r, dtype=float)
    r_dot = np.asarray(r_dot, dtype=float)
    v_p = np.asarray(v_p, dtype=float)
    v_f = np.asarray(v_f, dtype=float)
    if v_f.shape != v_p.shape:
        v_f = np.broadcast_to(v_f, v_p.shape)

    rng = _norm(r)
    speed = _norm(v_p)
    moving = speed >= _MIN_SPEED_M_S
    spd = np.where(moving, speed, 1.0)
    v_hat = v_p / spd[..., None]
    vf_hat = v_f / _norm(v_f)[..., None]

    # LOS rate Omega = r x r_dot / |r|^2 (0 at the target)
    far = rng >= _MIN_RANGE_M
    rng_safe = np.where(far, rng, 1.0)
    omega = np.where(far[..., None], _cross(r, r_dot) / (rng_safe * rng_safe)[..., None], 0.0)
    t_go = np.maximum(rng / np.maximum(speed, _MIN_SPEED_M_S), min_tgo_s)

    # angle still to turn and the axis that turns V_p toward V_f
    c = _cross(v_hat, vf_hat)
    s = _norm(c)
    theta = np.arctan2(s, _dot(v_hat, vf_hat))
    regular = s > _PARALLEL_EPS
    n = np.where(regular[..., None], c / np.where(regular, s, 1.0)[..., None], 0.0)
    anti = ~regular & (theta > 0.5 * math.pi)
    if anti.any():
        n = np.where(anti[..., None], _antiparallel_axis(v_hat, r), n)

    a_pn = n_sigma * _cross(omega, v_p)
    a_bias = -(n_f * np.minimum(theta, bias_angle_cap_rad) / t_go)[..., None] * _cross(n, v_p)  # AWAY from V_f
    scale = np.ones(rng.shape)
    if capture_turn_rad_s is not None:
        scale = _capture_scale(r, rng, v_hat, spd, a_pn, a_bias, capture_turn_rad_s, capture_look_rad)
    a = a_pn + scale[..., None] * a_bias
    a = a - _dot(a, v_hat)[..., None] * v_hat  # perpendicular to V_p
    mag = _norm(a)
    saturated = mag > max_accel_m_s2
    a = a * np.where(saturated, max_accel_m_s2 / np.where(saturated, mag, 1.0), 1.0)[..., None]
    a = np.where(moving[..., None], a, 0.0)
    return BpngTerms(omega, t_go, rng, theta, a_pn, a_bias, a, saturated & moving, scale)


def _capture_scale(r, rng, v_hat, speed, a_pn, a_bias, turn_rad_s: float, look_min_rad: float):
    """The capture guard's share of the bias term (1: all of it). Far off the nose (the look angle, between
    V_p and the line of sight, above ``look_min_rad``) the command must turn V_p toward the line of sight at
    ``turn_rad_s`` or more; where the bias term takes that away from the PN term it is scaled down until it
    does not (to zero when PN alone falls short)."""
    r_hat = r / np.where(rng > 0.0, rng, 1.0)[..., None]
    c = _dot(r_hat, v_hat)
    e = r_hat - c[..., None] * v_hat  # the line of sight's part across V_p: the way toward it
    s = _norm(e)
    look = np.arctan2(s, c)
    e = e / np.where(s > 0.0, s, 1.0)[..., None]
    need = turn_rad_s * speed
    t_pn, t_b = _dot(a_pn, e), _dot(a_bias, e)
    short = (look > look_min_rad) & (s > 1e-9) & (t_b < 0.0) & (t_pn + t_b < need)
    return np.where(short, np.clip((t_pn - need) / np.where(t_b < 0.0, -t_b, 1.0), 0.0, 1.0), 1.0)


def _antiparallel_axis(v_hat, r):
    """Fallback n for V_p = -V_f: in the vertical plane containing V_p (a level turn), toward the target side."""
    up = np.broadcast_to(np.array([0.0, 0.0, 1.0]), v_hat.shape)
    east = np.broadcast_to(np.array([1.0, 0.0, 0.0]), v_hat.shape)
    m = up - _dot(up, v_hat)[..., None] * v_hat
    nm = _norm(m)
    vertical = nm < 1e-6  # V_p vertical: any perpendicular; take East's part
    e = east - _dot(east, v_hat)[..., None] * v_hat
    ne = _norm(e)
    e = e / np.where(ne > 0.0, ne, 1.0)[..., None]
    m = np.where(vertical[..., None], e, m / np.where(vertical, 1.0, nm)[..., None])
    # the bias is -k (n x V): it points along the target's side when n . (V x r) < 0
    side = _dot(m, _cross(v_hat, r))
    return np.where((side > 0.0)[..., None], -m, m)


# --------------------------------------------------------------------------- block


@dataclass(frozen=True, slots=True)
class BpngStatus:
    """BPNG internals at ``t_s`` for the log (world ENU)."""

    t_s: float
    t_go_s: float
    range_m: float  # |r| to the aim point
    los_rate_rad_s: np.ndarray  # (3,) Omega
    theta_err_rad: float  # angle between V_p and V_f
    accel_pn: np.ndarray  # (3,) N_sigma Omega x V_p, m/s^2
    accel_bias: np.ndarray  # (3,) -(N_f theta / t_go) n x V_p, m/s^2
    accel_cmd: np.ndarray  # (3,) commanded (perpendicular, capped), m/s^2
    saturated: bool = False  # the max_accel cap was active
    bias_scale: float = 1.0  # the share of the bias term in the command (< 1: held back by the capture guard)
    aim_enu_m: np.ndarray = field(default_factory=lambda: np.full(3, np.nan))  # (3,) the point steered to
    endgame: bool = False  # inside endgame_tgo_s: the law dropped (V turned onto V_f, or straight)


class Bpng:
    """Terminal guidance block: target estimate + UAV state -> ``AccelCommand``."""

    def __init__(self, cfg: BpngConfig | None = None):
        self.cfg = cfg if cfg is not None else BpngConfig()
        self.v_f_enu = vf_enu(self.cfg.impact_flight_path_deg, self.cfg.impact_heading_deg)
        self.v_f_enu.setflags(write=False)
        self._aim_offset = np.array([0.0, 0.0, self.cfg.aim_height_m])
        self._endgame = False  # latched: the endgame lasts to the impact

    def _endgame_accel(self, v: np.ndarray, theta_rad: float) -> np.ndarray:
        """The endgame's command: V turned onto V_f (``endgame_align_s``), or zero (fly straight)."""
        cfg = self.cfg
        speed = float(np.linalg.norm(v))
        if cfg.endgame_align_s is None or speed <= 1e-6:
            return np.zeros(3)
        vh = v / speed
        perp = self.v_f_enu - float(self.v_f_enu @ vh) * vh  # toward V_f, perpendicular to V
        n = float(np.linalg.norm(perp))
        if n <= 1e-12:
            return np.zeros(3)
        return perp / n * min(speed * theta_rad / cfg.endgame_align_s, cfg.max_accel_m_s2)

    def aim_point(self, target_pos_enu) -> np.ndarray:
        """The point BPNG steers to: the target position raised by ``aim_height_m``."""
        return np.asarray(target_pos_enu, dtype=float) + self._aim_offset

    def step(self, t_s: float, uav_pos_enu, uav_vel_enu, target_pos_enu,
             target_vel_enu, aim_enu=None) -> tuple[AccelCommand, BpngStatus]:
        """One guidance update (positions m, velocities m/s, world ENU).

        ``aim_enu``: the point to steer to, when the caller has placed it
        (e.g. on the ship's surface); by default :meth:`aim_point` of the target.
        """
        cfg = self.cfg
        p = np.asarray(uav_pos_enu, dtype=float)
        v = np.asarray(uav_vel_enu, dtype=float)
        q = self.aim_point(target_pos_enu) if aim_enu is None else np.asarray(aim_enu, dtype=float)
        vq = np.asarray(target_vel_enu, dtype=float)
        if not (np.isfinite(p).all() and np.isfinite(v).all() and np.isfinite(q).all()
                and np.isfinite(vq).all()):
            nan3 = np.full(3, np.nan)
            return (AccelCommand(t_s=t_s, airspeed_m_s=cfg.airspeed_m_s, accel_enu_m_s2=np.zeros(3)),
                    BpngStatus(t_s, math.nan, math.nan, nan3, math.nan, nan3, nan3, np.zeros(3), aim_enu_m=nan3))
        k = bpng_accel(q - p, vq - v, v, self.v_f_enu, n_sigma=cfg.n_sigma, n_f=cfg.n_f,
                       min_tgo_s=cfg.min_tgo_s, max_accel_m_s2=cfg.max_accel_m_s2,
                       bias_angle_cap_rad=math.inf if cfg.bias_angle_cap_deg is None
                       else math.radians(cfg.bias_angle_cap_deg),
                       capture_turn_rad_s=None if cfg.capture_turn_deg_s is None
                       else math.radians(cfg.capture_turn_deg_s),
                       capture_look_rad=math.radians(cfg.capture_look_deg))
        # once inside, stay inside: past the steering point the range grows again and the LOS turns round
        endgame = self._endgame = self._endgame or float(k.range_m) < cfg.endgame_tgo_s * math.sqrt(v.dot(v))
        a = self._endgame_accel(v, float(k.theta_err_rad)) if endgame else k.accel_cmd.copy()
        cmd = AccelCommand(t_s=t_s, airspeed_m_s=cfg.airspeed_m_s, accel_enu_m_s2=a)
        status = BpngStatus(t_s=t_s, t_go_s=float(k.t_go_s), range_m=float(k.range_m),
                            los_rate_rad_s=k.los_rate_rad_s, theta_err_rad=float(k.theta_err_rad),
                            accel_pn=k.accel_pn, accel_bias=k.accel_bias, accel_cmd=a,
                            saturated=bool(k.saturated) and not endgame, aim_enu_m=q.copy(), endgame=endgame,
                            bias_scale=float(k.bias_scale))
        return cmd, status
