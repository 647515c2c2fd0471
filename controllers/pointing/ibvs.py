"""IBVS control of the pan-tilt camera (paper section "Phase 1: Controller design of the PT camera System").

Goal: keep the target's image feature ``s = [x1, x2] = [X/Z, Y/Z]`` (camera frame
z = optical axis, x right, y down; ``x1 = (u - cx)/fx``, ``x2 = (v - cy)/fy``) at
``s* = 0`` (the image centre), i.e. make ``e = s - s*`` obey ``edot = -lambda e``.

Feature kinematics (derived from the pinhole model, docs/design/algorithms.md; the
paper's eq. 6/8 have typos). The target P = [X, Y, Z] in the camera frame moves as
``Pdot = v - omega x P`` with

  * ``v = R_cam_from_enu (V_q - V_c)``: target velocity relative to the camera,
    ``V_c = V_p + R_enu_from_frd (omega_p x r_c/p)`` (camera velocity, world ENU);
  * ``omega = omega_rel + R_cam_from_frd omega_p``: camera angular velocity
    w.r.t. the world in the camera frame, ``omega_rel = M(tilt) [tilt_dot, pan_dot]``
    with ``M(t) = [[1, 0], [0, cos t], [0, -sin t]]`` (paper eq. (13)),

hence ``edot = L1 omega + T`` with::

    L1 = [[x1 x2, -(1 + x1^2),  x2],        T = [(v_x - x1 v_z) / Z,
          [1 + x2^2,   -x1 x2, -x1]]             (v_y - x2 v_z) / Z]

(``controllers.navigation.camera_model``'s, the UKF's too; ``tests/test_ibvs.py`` checks
them against finite differences of the projection).

The law. Everything in ``edot`` that the joints do not cause is "known"
(the paper's ``L2 [V_p - V_q; omega_p]``):
``k = L1 R_cam_from_frd omega_p + T``. With ``q = [tilt_dot, pan_dot]``::

    edot = J q + k,    J = L1 M(tilt)
         = [[x1 x2,    -cos t (1 + x1^2) - sin t x2],
            [1 + x2^2, -cos t x1 x2      + sin t x1]]

and ``q = J^+ (-lambda e - k)`` gives ``edot = -lambda e``.

Relation to the paper. Eq. (12) computes ``[w_cx, w_cy] = L1hat^-1 (-k - lambda e)``
with ``L1hat`` the first two columns of L1, then eq. (14) converts
``tilt_dot = w_cx``, ``pan_dot = w_cy / cos(tilt)``. Substituting, the paper
solves ``[L1[:, 0], cos t L1[:, 1]] q = -k - lambda e``: the same law as above
with the third-column term ``-sin t L1[:, 2] pan_dot`` dropped (the image
rotation ``w_cz = -sin t pan_dot`` that panning brings along, eq. (13)). The two
coincide when ``tilt = 0`` or at the goal ``x = 0`` (where ``L1[:, 2] = [x2, -x1]
= 0``); off-centre at large tilt the paper's law does not realise
``edot = -lambda e`` exactly, this one does. ``camera_rates_paper`` gives the
paper's form for comparison. Solving for the joint rates directly is the
paper's two steps combined, and it moves the singularity to where it really is:
``det J = (1 + x1^2 + x2^2)(cos t + x2 sin t)`` vanishes when the line of sight to
the TARGET is along the pan axis (body z), e.g. the target centred while the
camera looks straight down (tilt = -90 deg): panning then only spins the image
about the target. The paper's two-step form is singular at tilt = +-90 deg for
any target position. Singularity handling (the paper leaves it open): a
damped least-squares inverse ``q = (J^T J + rho^2 I)^-1 J^T b`` with adaptive
damping ``rho^2 = mu^2 - sigma_min^2`` when the smallest singular value
``sigma_min`` of J is below ``mu`` (``singularity_damping``) and ``rho = 0``
otherwise: the law is exact away from the singularity, continuous across the
threshold, and ``|q| <= |b| / mu`` everywhere (for a centred target
``sigma_min = |cos t|``, so damping starts at ``|tilt| > acos(mu)``, 84.3 deg
for mu = 0.1).

Keyhole: the target near the pan axis. The joint limits are the paper's: tilt
within +-90 deg (the optical axis reaches the pan axis, body z, but cannot pass
it) and pan within [-pi, pi] (the pan cannot follow the target's azimuth across
+-180 deg). Both bite when the line of sight passes close to the pan axis: the
pan that faces the target, its azimuth ``phi = atan2(d_y, d_x)`` for the
target direction d in the body, then turns fast (as 1/sin of the angle alpha
off the axis), and
  * if the target passes the axis, or the pan (rate-limited) falls more than
    90 deg behind its azimuth, the target is on the far side of the axis: the
    tilt would have to go past -90 deg and the law stalls (at 180 deg the pan
    column of J only turns the image about its centre, at right angles to e).
    Flying straight and level over a still ship at 300 m with a lateral miss
    of 0 or 5 m, the pan stayed put, the target slid to the bottom edge of the
    image and left it 4.4 s after passing under the UAV, for good (kinematic
    test below);
  * if the azimuth crosses +-180 deg, the pan is pinned at its stop while the
    target goes on. In the paper mission (seed 7) the bank reversal on entering
    Phase 2 (-35 -> +35 deg, nose 15 deg down, 880 m above the ship) sweeps the
    pan axis past the ship 6-13 deg away, its azimuth running -75 -> -180 ->
    +98 deg in 2 s: the pan chased it at its 120 deg/s limit, stopped at -180
    deg at 29.8 s while the tilt swung up, the ship left the image at 30.1 s
    and was back only at 32.8 s, after the mission's predictive pointing had
    turned the pan the long way round (target_in_fov_fraction_after_lock
    0.979; the other seeds alike).
The way out is the keyhole: a target within alpha_k of the pan axis stays in
the image for ANY pan while the tilt is at its limit on that side, with
``tan alpha_k = min(cx/fx, cy/fy)`` (principal point to the nearer image edge:
18.0 deg for 1280 x 720 px, 60 deg horizontal field of view), times
``keyhole_fov_fraction``, less what the tilt limit falls short of +-90 deg.
While the target is in it the pan may swing round, through a full relative
turn if need be. A swing (``IbvsStatus.swing``, the direction): the pan at its
full rate, the tilt by least squares for the image error given that pan rate,
``tilt_dot = J[:, 0] . (b - J[:, 1] pan_dot) / |J[:, 0]|^2`` (it goes toward
the axis as the target goes round to the far side and comes back up as the
pan catches up), each joint then cut at its own limits. It starts, with the
target in the keyhole, when
  (a) the target is on the far side of the axis (azimuth more than 90 deg from
      the pan): toward its azimuth, the shorter way the pan limits allow; or
  (b) the target is on the near side, but its azimuth will pass a pan limit
      (by 5 deg: a dead band against noise at the seam) while still in the
      keyhole, within one full-range swing time (pan range / rate limit, 3 s):
      the pan unwinds AWAY from that limit, round the other side of the axis,
      and meets the azimuth once it has come past the seam. The prediction
      (``predict_limit_crossing``) moves the target's gnomonic projection on
      the plane normal to the pan axis, ``p = (d_x, d_y) / |d_z|`` (|p| = tan
      alpha), along a straight line at its present rate (the UAV's rotation
      from the gyros, the relative translation from the depth and velocities
      the feed-forward uses). Only for a pan range that covers the full circle
      (bar at most the 30 deg exit angle), else the azimuths past the limit are
      out of reach from the other side as well.
It ends when the target, having been on the far side, is within 30 deg of the
pan in azimuth (the law takes over from there), when the pan reaches its stop,
when the target leaves the keyhole without having reached the far side (the
prediction was wrong), or after one full-range swing time plus 1 s. Outside
these cases the law runs untouched (``keyhole_swing: false`` gives the same
commands, bit for bit, wherever no swing fires; tested).
Measured with it: in the paper mission (seed 7) the swing starts at 28.8 s
(pan -104 deg, ship 13 deg off the axis) and ends at 30.3 s (pan +83 deg); the
ship stays in the image, the pan never reaches a stop:
target_in_fov_fraction_after_lock 0.979 -> 1.000, pixel_err_rms u/v 36.7/11.7
-> 27.0/9.2 px, pixel_err_max 628 -> 373 px (seeds 1-3: likewise 0.979 ->
1.000). Kinematic tests (``tests/test_ibvs.py``): the 300 m overflight keeps the
target in the image at 0, +-5 and 30 m lateral miss (within 71 px; at 30 m no
swing is needed), and a bank reversal like the mission's keeps it at 5 and
0.3 deg closest approach to the axis (the plain law: lost). Limits of the
handling: the target must still be in the keyhole when the pan has swung it
past the far side; with a faster bank reversal (70 deg/s peak at the same
height, the ship 8-10 deg from the axis) the target is still lost for up to
1 s in a kinematic sweep, and a curving path (e.g. a roll rate still building
up) is only caught once the straight-line prediction says so.

Limits (what the flight software knows of the gimbal): a joint at a limit is
not pushed further, and within one step of it the rate is cut so that it lands
on the limit; then both rates are scaled by the same factor to the rate limits
(the direction of the joint-rate vector is kept). During a keyhole swing each
joint is limited on its own (the pan is at its rate limit by construction).

Modes (``IbvsStatus.mode``):
  * ``"track"``: the newest detection found the target and is at most
    ``max_detection_age_s`` old: feedback ``-lambda e`` plus feed-forward;
  * ``"coast"``: no fresh detection, for up to ``hold_timeout_s`` after the
    track was lost: feed-forward only (UAV rotation, UAV and target motion) at
    the predicted feature, which keeps the target where it was in the image
    (zero rates when ``feedforward`` is off);
  * ``"hold"``: nothing to track (never seen, lost for longer, or no joint
    angles): the command is NaN ("hold", GimbalCommand's convention).

Between detections (the loop may call ``step`` faster than the detector) and
from the detection's exposure to now, the feature is propagated with the
kinematics above using the measured joint rates (encoders; the last command if
they are NaN) and gyros (``propagate_feature``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controllers.config import IbvsConfig
from controllers.navigation.camera_model import feature_rates, rotation_matrix, translation_rates  # noqa: F401
from fwsim.interface.frames import R_frd_from_cam, cross3, dcm_enu_from_frd, finite3, wrap_pi
from fwsim.interface.messages import GimbalCommand, Measurements

_PI = math.pi
_HALF_PI = 0.5 * math.pi
_FEATURE_CAP = 3.0  # |x1|, |x2| of a propagated feature (about 72 deg off axis): numerical guard only
_SWING_FAR_RAD = 0.5 * _PI  # target azimuth this far from the pan: on the far side of the pan axis
_SWING_EXIT_RAD = math.radians(30.0)  # a swing ends with the pan this close to the target's azimuth
_SWING_DEADBAND_RAD = math.radians(5.0)  # an unwind needs the azimuth to go this far past a pan limit


# --------------------------------------------------------------------------- feature kinematics

#: The rotational (L1) and translational (T) parts of the feature kinematics: controllers.navigation.camera_model's,
#: the UKF's too (one implementation; ``tests/test_ibvs.py`` checks them against finite differences).
l1_matrix = rotation_matrix
translational_feature_rates = translation_rates


def joint_jacobian(x1: float, x2: float, tilt_rad: float) -> np.ndarray:
    """J (2x2) with ``sdot = J @ [tilt_dot, pan_dot] + (UAV rotation + translation)``; J = L1 M(tilt).

    Finite everywhere; ``det J = (1 + x1^2 + x2^2)(cos t + x2 sin t)``.
    """
    a, c, d, f = _jacobian_entries(x1, x2, tilt_rad)
    return np.array([[a, c], [d, f]])


def _jacobian_entries(x1, x2, tilt_rad: float) -> tuple:
    """J's entries, row by row (the one place they are written)."""
    ct, st = math.cos(tilt_rad), math.sin(tilt_rad)
    return x1 * x2, -ct * (1.0 + x1 * x1) - st * x2, 1.0 + x2 * x2, -ct * x1 * x2 + st * x1


def damped_solve(J: np.ndarray, b, mu: float) -> tuple[np.ndarray, float]:
    """q = (J^T J + rho^2 I)^-1 J^T b with rho^2 = max(0, mu^2 - sigma_min^2); returns (q, sigma_min).

    Exact inverse while the smallest singular value sigma_min of the 2x2 J is at
    least mu; continuous across; ``|q| <= |b| / mu`` always.
    """
    q0, q1, sigma_min = _damped_solve(float(J[0, 0]), float(J[0, 1]), float(J[1, 0]), float(J[1, 1]),
                                      float(b[0]), float(b[1]), mu)
    return np.array([q0, q1]), sigma_min


def _damped_solve(a: float, c: float, d: float, f: float, b0: float, b1: float, mu: float
                  ) -> tuple[float, float, float]:
    """:func:`damped_solve` on J = [[a, c], [d, f]] and b = [b0, b1] as numbers: (q0, q1, sigma_min)."""
    # A = J^T J = [[p, r], [r, s]]
    p, r, s = a * a + d * d, a * c + d * f, c * c + f * f
    half_tr = 0.5 * (p + s)
    det_a = p * s - r * r
    sig2_min = max(0.0, half_tr - math.sqrt(max(0.0, half_tr * half_tr - det_a)))
    rho2 = max(0.0, mu * mu - sig2_min)
    p += rho2
    s += rho2
    g0, g1 = a * b0 + d * b1, c * b0 + f * b1  # J^T b
    det = p * s - r * r
    if det <= 0.0:  # only when mu = 0 and J is singular: no motion
        return 0.0, 0.0, math.sqrt(sig2_min)
    return (s * g0 - r * g1) / det, (p * g1 - r * g0) / det, math.sqrt(sig2_min)


def joint_rates_direct(x1: float, x2: float, tilt_rad: float, lambda_1_s: float, known_rate=(0.0, 0.0),
                       mu: float = 0.1) -> tuple[float, float]:
    """(pan_rate, tilt_rate) making ``sdot = -lambda s`` (unlimited): ``q = J^+(-lambda e - known_rate)``.

    ``known_rate``: the part of ``sdot`` not caused by the joints (``L1 R_cam_from_frd omega_p + T``).
    """
    b = (-lambda_1_s * x1 - float(known_rate[0]), -lambda_1_s * x2 - float(known_rate[1]))
    q, _ = damped_solve(joint_jacobian(x1, x2, tilt_rad), b, mu)
    return float(q[1]), float(q[0])


def camera_rates_paper(x1: float, x2: float, lambda_1_s: float, known_rate=(0.0, 0.0)) -> np.ndarray:
    """The paper's eq. (12): ``[w_cx, w_cy] = -L1hat^-1 known_rate - lambda L1hat^-1 e`` (camera frame,
    relative to the body). ``L1hat`` = first two columns of L1 (det = 1 + x1^2 + x2^2 > 0, always invertible);
    ``known_rate`` is the paper's ``L2 [V_p - V_q; omega_p]``. Convert with eq. (14)
    (``fwsim.interface.frames.joint_rates_from_camera_rates``) for the joint rates.
    """
    a, c = x1 * x2, -(1.0 + x1 * x1)
    d, f = 1.0 + x2 * x2, -x1 * x2
    b0 = -lambda_1_s * x1 - float(known_rate[0])
    b1 = -lambda_1_s * x2 - float(known_rate[1])
    det = a * f - c * d
    return np.array([(f * b0 - c * b1) / det, (a * b1 - d * b0) / det])


def predict_limit_crossing(p, p_dot, pan_rad: float, pan_limits_rad, beyond_rad: float = 0.0
                           ) -> tuple[float, float, int] | None:
    """When and how far from the pan axis the target's azimuth passes ``beyond_rad`` beyond a pan limit.

    ``p = (d_x, d_y) / |d_z|`` for the target's direction d (body FRD; z = the
    pan axis) is its gnomonic projection on the plane normal to the pan axis:
    ``|p|`` is the tangent of its angle off the axis and ``atan2(p_y, p_x)`` the
    pan that faces it. The target is extrapolated on the straight line
    ``p + p_dot t`` (exact for a target translating relative to a non-rotating
    UAV), along which the azimuth sweeps monotonically by less than pi. A pan
    following the azimuth from ``pan_rad`` (its representation nearest the
    pan) reaches the limit ahead after a sweep ``delta`` (plus ``beyond_rad``):
    returns ``(t, |p| there, sweep direction +1/-1)`` for that crossing
    (``t = 0`` when the azimuth is already that far past the limit), or None if
    the line never gets there.
    """
    px, py = float(p[0]), float(p[1])
    vx, vy = float(p_dot[0]), float(p_dot[1])
    cross = px * vy - py * vx
    if not math.isfinite(cross) or cross == 0.0:
        return None
    sweep = 1 if cross > 0.0 else -1
    phi = math.atan2(py, px)
    phi_u = pan_rad + wrap_pi(phi - pan_rad)
    delta = ((pan_limits_rad[1] - phi_u) if sweep > 0 else (phi_u - pan_limits_rad[0])) + beyond_rad
    if delta >= _PI:
        return None
    if delta <= 0.0:
        return 0.0, math.hypot(px, py), sweep
    psi = phi + sweep * delta
    ux, uy = math.cos(psi), math.sin(psi)
    den = ux * vy - uy * vx  # u x p_dot; p + p_dot t = s u
    if den == 0.0:
        return None
    t = (px * uy - py * ux) / den
    s = cross / den
    if t < 0.0 or s <= 0.0:
        return None
    return t, s, sweep


def limit_joint_rates(pan_rad: float, tilt_rad: float, pan_rate: float, tilt_rate: float, cfg: IbvsConfig,
                      dt_s: float) -> tuple[float, float, float]:
    """Joint- and rate-limit aware command: returns (pan_rate, tilt_rate, scale).

    1. a rate pushing a joint into its limit is cut so that one step of ``dt_s``
       lands on the limit at most (zero when the joint is at or past it);
    2. both rates are scaled by one factor ``scale <= 1`` so that each is
       within its rate limit (the direction is kept).
    """
    pan_lo, pan_hi = cfg.pan_limits_rad
    tilt_lo, tilt_hi = cfg.tilt_limits_rad
    if pan_rate > 0.0:
        pan_rate = min(pan_rate, max(0.0, (pan_hi - pan_rad) / dt_s))
    elif pan_rate < 0.0:
        pan_rate = max(pan_rate, min(0.0, (pan_lo - pan_rad) / dt_s))
    if tilt_rate > 0.0:
        tilt_rate = min(tilt_rate, max(0.0, (tilt_hi - tilt_rad) / dt_s))
    elif tilt_rate < 0.0:
        tilt_rate = max(tilt_rate, min(0.0, (tilt_lo - tilt_rad) / dt_s))
    scale = 1.0
    if abs(pan_rate) > cfg.max_pan_rate_rad_s:
        scale = cfg.max_pan_rate_rad_s / abs(pan_rate)
    if abs(tilt_rate) * scale > cfg.max_tilt_rate_rad_s:
        scale = cfg.max_tilt_rate_rad_s / abs(tilt_rate)
    return pan_rate * scale, tilt_rate * scale, scale


# --------------------------------------------------------------------------- controller


@dataclass(frozen=True, slots=True)
class IbvsStatus:
    """What the IBVS controller did this tick (for the log; never fed back)."""

    t_s: float
    mode: str  # "track", "coast" or "hold"
    e: np.ndarray  # (2,) feature error [x1, x2] the law used (predicted to t_s); NaN in hold
    pixel_err_px: np.ndarray  # (2,) the same as pixels [u - cx, v - cy]
    pan_rate_cmd_rad_s: float  # the command sent (after limits); NaN in hold
    tilt_rate_cmd_rad_s: float
    detection_age_s: float  # t_s minus the exposure time of the newest valid detection (NaN: none yet)
    sigma_min: float  # smallest singular value of J (near 0: singular, damping active below mu)
    rate_scale: float  # factor applied by the rate limits (1: not saturated)
    swing: int = 0  # keyhole pan swing under way: its direction (+1 / -1), 0 when the law runs as is


def _finite(*xs) -> bool:
    return all(math.isfinite(float(x)) for x in xs)


class Ibvs:
    """IBVS pan-tilt controller: ``step(meas, target_vel, depth, mount_offset) -> (GimbalCommand, IbvsStatus)``."""

    def __init__(self, cfg: IbvsConfig, fx: float, fy: float, cx: float, cy: float):
        if not (fx > 0.0 and fy > 0.0 and _finite(fx, fy, cx, cy)):
            raise ValueError(f"Ibvs: focal lengths must be positive and finite (fx={fx}, fy={fy}, cx={cx}, cy={cy})")
        self.cfg = cfg
        self.fx, self.fy, self.cx, self.cy = float(fx), float(fy), float(cx), float(cy)
        # the keyhole (tangent of its radius) about the pan axis below and above the UAV: a target
        # closer than this to the axis stays in the image for ANY pan with the tilt at its limit
        # on that side (the principal point is taken as the image centre: half-sizes cx, cy)
        half_fov = math.atan(max(0.0, min(self.cx / self.fx, self.cy / self.fy))) * cfg.keyhole_fov_fraction
        tilt_lo, tilt_hi = cfg.tilt_limits_rad
        self._tan_keyhole = (math.tan(max(0.0, half_fov - (_HALF_PI + tilt_lo))),
                             math.tan(max(0.0, half_fov - (_HALF_PI - tilt_hi))))
        pan_span = cfg.pan_limits_rad[1] - cfg.pan_limits_rad[0]
        self._swing_horizon_s = pan_span / cfg.max_pan_rate_rad_s  # one swing over the whole pan range
        # unwinding ahead of a limit pays only if the azimuths beyond it are (nearly) all reachable
        # from the other side: the pan covers the full circle but for a gap of at most the exit angle
        self._can_unwind = pan_span >= 2.0 * _PI - _SWING_EXIT_RAD
        self.reset()

    def reset(self) -> None:
        """Forget the target (next step holds until a detection arrives)."""
        self._s: np.ndarray | None = None  # feature estimate at self._last_t
        self._last_t: float | None = None
        self._det_key = None  # (exposure, u, v) of the last detection consumed
        self._fix_t = math.nan  # exposure time of the newest valid detection
        self._lost_t: float | None = None  # when the track was lost (start of coast)
        self._last_cmd = (0.0, 0.0)  # (pan_rate, tilt_rate) last sent, 0 when holding
        self._swing = 0  # keyhole swing direction (+1/-1), 0: none
        self._swing_far = False  # the target has been on the far side of the pan axis during this swing
        self._swing_t0 = math.nan

    # ------------------------------------------------------------------ helpers

    def _sdot(self, s, tilt, R_cf, w_p, pan_rate, tilt_rate, T_fn) -> np.ndarray:
        """Feature rate with the given joint rates (for propagation)."""
        ct, st = math.cos(tilt), math.sin(tilt)
        omega = R_cf @ w_p + np.array([tilt_rate, ct * pan_rate, -st * pan_rate])
        out = l1_matrix(s[0], s[1]) @ omega
        T = T_fn(s)
        return out if T is None else out + T

    def _keyhole_swing(self, t: float, pan: float, s: np.ndarray, R_fc: np.ndarray, w_p: np.ndarray,
                       v_rel_body, z: float) -> int:
        """Direction of the keyhole pan swing to fly this tick (+1/-1), 0 for the plain law (module docstring).

        ``v_rel_body``: target velocity relative to the camera, body FRD (None: unknown); ``z``: depth.
        """
        cfg = self.cfg
        lo, hi = cfg.pan_limits_rad
        d = R_fc @ np.array([float(s[0]), float(s[1]), 1.0])  # target direction, body FRD (per unit depth)
        dx, dy, dz = d.tolist()
        tan_k = self._tan_keyhole[0 if dz > 0.0 else 1]
        rho = math.hypot(dx, dy) / abs(dz) if dz != 0.0 else math.inf  # tan(angle off the pan axis)
        w = wrap_pi(math.atan2(dy, dx) - pan)  # target azimuth relative to the pan

        def travel() -> float | None:
            """Pan motion that faces the target within the pan limits (shortest), None if none can."""
            best = None
            for c in (pan + w, pan + w - 2.0 * _PI, pan + w + 2.0 * _PI):
                if lo - 1e-9 <= c <= hi + 1e-9 and (best is None or abs(c - pan) < abs(best)):
                    best = c - pan
            return best

        def blocked(direction: int) -> bool:
            return pan >= hi - 1e-9 if direction > 0 else pan <= lo + 1e-9

        if self._swing:
            self._swing_far = self._swing_far or abs(w) > _SWING_FAR_RAD
            tr = travel()
            done = ((self._swing_far and tr is not None and abs(tr) <= _SWING_EXIT_RAD)
                    or blocked(self._swing)
                    or (not self._swing_far and not rho <= tan_k)  # left the keyhole on the near side
                    or t - self._swing_t0 > self._swing_horizon_s + 1.0)
            if not done:
                return self._swing
            self._swing = 0
        if not (tan_k > 0.0 and rho <= tan_k):
            return 0
        direction, far = 0, False
        if abs(w) > _SWING_FAR_RAD:  # far side of the axis: only a pan swing brings the target back
            tr = travel()
            if tr is not None and abs(tr) > _SWING_EXIT_RAD:
                direction, far = (1 if tr > 0.0 else -1), True
        elif self._can_unwind:  # near side: will the azimuth carry the pan into a limit within the keyhole?
            ddot = -cross3(w_p, d)
            if v_rel_body is not None:
                ddot = ddot + np.asarray(v_rel_body, dtype=float) / z
            sz = 1.0 if dz > 0.0 else -1.0
            p = d[:2] / abs(dz)
            p_dot = (ddot[:2] - p * sz * ddot[2]) / abs(dz)
            hit = predict_limit_crossing(p, p_dot, pan, (lo, hi), _SWING_DEADBAND_RAD)
            if hit is not None and hit[0] <= self._swing_horizon_s and hit[1] <= tan_k:
                direction = -hit[2]  # unwind away from that limit, round the other side of the axis
        if direction and not blocked(direction):
            self._swing, self._swing_far, self._swing_t0 = direction, far, t
        return self._swing

    def _hold(self, t: float, e=None, age=math.nan) -> tuple[GimbalCommand, IbvsStatus]:
        self._last_cmd = (0.0, 0.0)
        self._swing = 0
        e = np.full(2, np.nan) if e is None else e
        px = np.array([e[0] * self.fx, e[1] * self.fy])
        return (GimbalCommand(t, math.nan, math.nan),
                IbvsStatus(t, "hold", e, px, math.nan, math.nan, age, math.nan, 1.0))

    # ------------------------------------------------------------------ step

    def step(self, meas: Measurements, target_vel_enu_m_s, depth_m, mount_offset_frd_m
             ) -> tuple[GimbalCommand, IbvsStatus]:
        """One control tick.

        ``target_vel_enu_m_s``: target velocity estimate (world ENU, e.g. the
        UKF's); None: taken as 0. ``depth_m``: target depth Z along the optical
        axis (flat-sea geometry or the estimate); None: the translational
        feed-forward T is skipped. ``mount_offset_frd_m``: camera rotation centre
        r_c/p relative to the CG (body FRD, m).
        """
        cfg = self.cfg
        t = float(meas.t_s)
        dt = cfg.nominal_dt_s
        if self._last_t is not None and 0.0 < t - self._last_t <= 1.0:
            dt = t - self._last_t
        prev_t = self._last_t
        self._last_t = t
        pan, tilt = float(meas.pan_rad), float(meas.tilt_rad)
        if not (math.isfinite(pan) and math.isfinite(tilt)):
            self._s = None
            return self._hold(t)

        R_fc = R_frd_from_cam(pan, tilt)
        R_cf = R_fc.T
        w_p = np.asarray(meas.body_rates_frd_rad_s, dtype=float)
        if not finite3(w_p):
            w_p = np.zeros(3)
        v_rel, z = self._relative_velocity(meas, target_vel_enu_m_s, depth_m, mount_offset_frd_m, R_cf, w_p)

        def T_fn(s):
            return None if v_rel is None else translational_feature_rates(s[0], s[1], z, v_rel)

        valid = self._update_feature(meas, t, dt, prev_t, tilt, R_cf, w_p, T_fn)
        age = t - self._fix_t if math.isfinite(self._fix_t) else math.nan
        mode = self._mode(t, valid, age)
        if mode == "hold":
            return self._hold(t, age=age)
        pan_rate, tilt_rate, scale, sigma_min, swing = self._law(t, dt, pan, tilt, mode, R_fc, R_cf, w_p, v_rel,
                                                                 z, T_fn)
        self._last_cmd = (pan_rate, tilt_rate)
        s = self._s
        status = IbvsStatus(t, mode, s.copy(), np.array([float(s[0]) * self.fx, float(s[1]) * self.fy]), pan_rate,
                            tilt_rate, age, sigma_min, scale, swing)
        return GimbalCommand(t, pan_rate, tilt_rate), status

    def _relative_velocity(self, meas: Measurements, target_vel_enu_m_s, depth_m, mount_offset_frd_m, R_cf, w_p):
        """(target velocity relative to the camera in the camera frame, depth Z) for the translational term
        T(s); (None, NaN) without a depth, the attitude or the UAV's velocity."""
        v_rel = None
        if depth_m is not None and math.isfinite(float(depth_m)) and float(depth_m) > 0.0:
            vel = np.asarray(meas.vel_enu_m_s, dtype=float)
            eul = np.asarray(meas.euler_ned_rad, dtype=float)
            if finite3(vel) and finite3(eul):
                R_ef = dcm_enu_from_frd(eul)
                v_c = vel + R_ef @ cross3(w_p, mount_offset_frd_m)
                v_q = np.zeros(3) if target_vel_enu_m_s is None else np.asarray(target_vel_enu_m_s, dtype=float)
                if finite3(v_q):
                    v_rel = R_cf @ (R_ef.T @ (v_q - v_c))
        return v_rel, (float(depth_m) if v_rel is not None else math.nan)

    def _update_feature(self, meas: Measurements, t, dt, prev_t, tilt, R_cf, w_p, T_fn) -> bool:
        """Take a new detection as the feature (propagated from its exposure to now), or propagate the
        feature between detections with the measured joint rates; True when the newest detection is valid."""
        cfg = self.cfg
        # measured joint rates for the propagation (encoders; else the last command)
        pr_m, tr_m = float(meas.pan_rate_rad_s), float(meas.tilt_rate_rad_s)
        if not (math.isfinite(pr_m) and math.isfinite(tr_m)):
            pr_m, tr_m = self._last_cmd
        u, v = float(meas.det_u_px), float(meas.det_v_px)
        valid = bool(meas.det_valid) and math.isfinite(u) and math.isfinite(v)
        key = (float(meas.det_exposure_t_s), u, v)
        if valid and key != self._det_key:  # a new detection (NaN exposure: every tick is new)
            self._det_key = key
            exp_t = key[0]
            self._fix_t = exp_t if math.isfinite(exp_t) else t
            s = np.array([(u - self.cx) / self.fx, (v - self.cy) / self.fy])
            age = t - self._fix_t
            if cfg.propagate_feature and 0.0 < age <= cfg.max_detection_age_s:
                s = s + age * self._sdot(s, tilt, R_cf, w_p, pr_m, tr_m, T_fn)
            self._s = s
        elif self._s is not None and cfg.propagate_feature and prev_t is not None:
            self._s = self._s + dt * self._sdot(self._s, tilt, R_cf, w_p, pr_m, tr_m, T_fn)
        s = self._s
        if s is not None:
            x1, x2 = s.tolist()
            if not (-_FEATURE_CAP <= x1 <= _FEATURE_CAP and -_FEATURE_CAP <= x2 <= _FEATURE_CAP):  # else a no-op
                np.clip(s, -_FEATURE_CAP, _FEATURE_CAP, out=s)
        return valid

    def _mode(self, t: float, valid: bool, age: float) -> str:
        """``track``, ``coast`` or ``hold`` (the module text); forgets the feature after the coast."""
        if self._s is not None and valid and age <= self.cfg.max_detection_age_s:
            self._lost_t = None
            return "track"
        if self._s is None:
            return "hold"
        if self._lost_t is None:
            self._lost_t = t
        if t - self._lost_t > self.cfg.hold_timeout_s:
            self._s = None  # forget the target: hold until the next valid detection
            return "hold"
        return "coast"

    def _law(self, t, dt, pan, tilt, mode, R_fc, R_cf, w_p, v_rel, z, T_fn):
        """The joint rates: J [tilt_dot, pan_dot] = b (damped), or a keyhole swing; then the limits.
        Returns (pan_rate, tilt_rate, rate scale, sigma_min of J, swing direction)."""
        cfg = self.cfg
        s = self._s
        x1, x2 = s.tolist()
        b0 = b1 = 0.0  # b = -lambda e - known rate, term by term
        if mode == "track":
            lam = cfg.lambda_1_s
            b0, b1 = b0 - lam * x1, b1 - lam * x2
        if cfg.feedforward:
            r0, r1 = (l1_matrix(x1, x2) @ (R_cf @ w_p)).tolist()
            b0, b1 = b0 - r0, b1 - r1
            T = T_fn(s)
            if T is not None:
                T0, T1 = T.tolist()
                b0, b1 = b0 - T0, b1 - T1
        a, c, d, f = _jacobian_entries(x1, x2, tilt)
        q0, q1, sigma_min = _damped_solve(a, c, d, f, b0, b1, cfg.singularity_damping)
        swing = 0
        if cfg.keyhole_swing:
            v_rel_body = None if v_rel is None else R_fc @ v_rel
            swing = self._keyhole_swing(t, pan, s, R_fc, w_p, v_rel_body, z)
        if swing:
            # the pan at full rate; the tilt does what it can for the image error given that pan rate
            pan_rate = swing * cfg.max_pan_rate_rad_s
            J = np.array([[a, c], [d, f]])
            j0, j1 = J[:, 0], J[:, 1]
            tilt_rate = float(j0 @ (np.array([b0, b1]) - j1 * pan_rate)) / float(j0 @ j0)
            pan_rate = limit_joint_rates(pan, tilt, pan_rate, 0.0, cfg, dt)[0]
            tilt_rate, scale = limit_joint_rates(pan, tilt, 0.0, tilt_rate, cfg, dt)[1:]
        else:
            pan_rate, tilt_rate, scale = limit_joint_rates(pan, tilt, q1, q0, cfg, dt)
        return pan_rate, tilt_rate, scale, sigma_min, swing
