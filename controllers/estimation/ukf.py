"""Target state estimation: the paper's 8-state UKF (section "UKF").

State ``x = [x1, x2, r_q (3, world ENU, m), V_q (3, m/s)]``:

  * ``x1 = X/Z``, ``x2 = Y/Z``: normalised image features of the target
    (``[X, Y, Z]`` = target relative to the camera, camera frame);
  * ``r_q``, ``V_q``: the target's position and velocity in the world.

Process model (continuous, integrated with RK4 over each predict):
  * ``x1_dot, x2_dot`` from :func:`controllers.navigation.camera_model.feature_rates`
    (derived from the pinhole model; replaces the paper's eq. 6/8, which have
    typos), with ``Z`` = camera-frame depth of ``r_q`` (z-component of
    ``R_cam_from_enu (r_q - r_c)``), ``v = R_cam_from_enu (V_q - V_c)`` and the
    camera's total angular velocity; this keeps x1, x2 consistent with r_q;
  * ``r_q_dot = V_q``, ``V_q_dot = 0`` (constant velocity) + white-noise
    acceleration; x1, x2 get a small random walk (``feature_process_noise``).
  The camera motion over the interval: pose of the previous call, camera
  velocity and angular velocity the mean of the previous and the new ones,
  held constant (the pose is rotated/translated by them inside the interval).

Measurement (paper eq. 9), on every new valid detection:
  ``z = [u, v, r_c]``, ``h(x) = [fx x1 + cx, fy x2 + cy, r_q - d_w Z]`` with
  ``d_w = R_enu_from_cam [x1, x2, 1]`` and ``Z`` from the flat-sea depth model
  (:func:`controllers.navigation.camera_model.depth_on_plane`, the plane
  ``z = target_plane_height_m``; camera height from the altimeter). The
  r_c rows carry GNSS noise plus the attitude and altimeter errors projected
  over the range.

Pointing bias: the camera's pointing error (its boresight and encoder offsets as built, and the
navigation's attitude error) is slowly varying, not white: fused as white noise it would average away in
the filter while the error stays. While the navigation reports its attitude std
(``CameraMotion.att_var_rad2``, an INS does), two more states ``b = (b1, b2)`` after the target's hold it:
where the believed boresight appears in the image (normalised units, :func:`through_pointing_bias`), so the
pixel rows are ``f (x + b) / (1 - b . x) + c`` to first order in ``b``. Its prior is the mount's calibration
(``pointing_bias_std_rad``) with the navigation's attitude variance; it random-walks, takes on each new low
of the navigation's attitude variance as the navigation corrects itself, and a turning camera's rate error
(``pointing_rate_error_frac``) is added to the features' random walk. It is observable as the view turns
round the ship (an orbit) and as the range closes (the dive). Without that report (the ideal sensors) the
filter is the 8-state one.

Reported uncertainty: the box centre, corrected for the ship class's shape,
is still off by what the class cannot know of the real ship (its size, its
layout). That error is systematic, not noise: fused as noise it averages
away and the filter's std collapses to decimetres while its error stays at
metres (measured on the envelope sweep: 8 % of a median run's estimates
within twice the std). It is not fused; the estimate's reported position std
(``TargetEstimate.pos_std_m``, horizontal axes) adds ``J diag(s^2) J^T``, a
consider covariance: ``s`` is ``box_centre_bias_frac`` of the latest box's
width and height (px) and ``J`` the pixel-to-plane Jacobian of that view
(:func:`controllers.navigation.camera_model.ground_from_pixel_jacobian`). While the ship's heading is not known the
shape correction is a weighted mean over the headings it may have, and the
detection carries the spread of that mean (``DetectionFix.offset_spread_px2``,
px^2): another error common to consecutive frames, added to ``diag(s^2)``
(``consider_heading_spread``). A third such error is the height on the ship
the corrected box centre stands for (the real ship's height is not the
class's): a point seen higher or lower meets the target plane displaced along
the line of sight by its height error over tan of the elevation, so far out
at a shallow elevation it dominates (``box_centre_height_std_m``:
:func:`height_consider_cov`). The state and the filter's covariance (``cov``)
are unchanged by any of them. The three are those of the latest fused box's
view alone.

Interfaces: :class:`UkfTargetEstimator` implements the flight software's
estimator Protocol (``controllers.blocks.TargetEstimator``), so a second filter
can be swapped in from the scenario and compared on the same logs; it takes the
perception's :class:`~controllers.messages.DetectionFix` (the box centre
corrected for the ship's shape) and answers each update with a
:class:`~controllers.messages.FusionResult` (used, or why not, with the
innovation and its test ratio); :class:`UnscentedCore` is the
generic unscented machinery (filterpy's equations, batched over the sigma
points, with covariance hygiene), reusable with any ``fx``/``hx`` (the tests run it on a linear case
against a linear Kalman filter).

Timing: the detection is used at the tick it arrives, with the camera pose of
that tick (``det_exposure_t_s`` is not used: correct for zero detector
latency, the scenario default).

Nothing here imports the truth side of the harness (docs/design/architecture.md, "Two rules").
"""
from __future__ import annotations

import math

import numpy as np
from scipy.linalg.lapack import dpotrf as _dpotrf

from controllers.navigation.camera_model import MIN_RAY_DOWN as _CAMERA_MIN_RAY_DOWN
from controllers.navigation.camera_model import (CameraMotion, PinholeCamera, depth_on_plane, feature_rates,
                                                 ground_jacobian_rows)
from controllers.config import UkfConfig
from controllers.messages import DetectionFix, EstimatorStatus, FusionReason, FusionResult, TargetEstimate
from fwsim.interface.messages import Measurements

__all__ = ["UkfConfig", "CameraMotion", "TargetEstimate", "UnscentedCore", "UkfTargetEstimator",
           "fix_from_measurements", "height_consider_cov", "through_pointing_bias"]

MIN_DEPTH_M = 1.0  # process model: camera-frame depth of a sigma point is floored here
_MIN_RAY_DOWN = 1e-3  # measurement model: -d_w,z of a sigma point's ray is floored here (|d_w| >= 1)
_VAR_FLOOR = 1e-12  # numerical reset: smallest variance kept on the diagonal
_INIT_VERTICAL_POS_STD_M = 1.0
_INIT_VERTICAL_VEL_STD_M_S = 0.5
_NAN2 = np.full(2, np.nan)  # (copied: an estimate's innovation without an update at its time)
_NAN2.setflags(write=False)
_LOG_2PI = math.log(2.0 * math.pi)  # a 2-D Gaussian density's constant


def _exp_so3(w: np.ndarray, t: float) -> np.ndarray:
    """Rotation matrix exp([w]x t) (Rodrigues)."""
    wx, wy, wz = float(w[0]) * t, float(w[1]) * t, float(w[2]) * t
    th2 = wx * wx + wy * wy + wz * wz
    K = np.array([[0.0, -wz, wy], [wz, 0.0, -wx], [-wy, wx, 0.0]])
    if th2 < 1e-16:
        return np.eye(3) + K + 0.5 * (K @ K)
    th = math.sqrt(th2)
    return np.eye(3) + (math.sin(th) / th) * K + ((1.0 - math.cos(th)) / th2) * (K @ K)


# --------------------------------------------------------------------------- generic unscented machinery


def _safe_cholesky(M: np.ndarray) -> np.ndarray:
    """Upper Cholesky factor (LAPACK potrf, as ``scipy.linalg.cholesky``); the diagonal's square root if M is
    not positive definite or not finite.

    The fallback only keeps the sigma points finite; the covariance itself is repaired (and counted) by
    ``UnscentedCore._guard``.
    """
    if np.isfinite(M).all():
        c, info = _dpotrf(M, lower=0, clean=1)
        if info == 0:
            return c
    return np.diag(np.sqrt(np.maximum(np.abs(np.nan_to_num(np.diag(M))), _VAR_FLOOR)))


class UnscentedCore:
    """Generic UKF: Van der Merwe's scaled sigma points and the unscented transform, with covariance hygiene.

    The equations are filterpy's (``UnscentedKalmanFilter`` with ``MerweScaledSigmaPoints``; the same
    operations in the same order, so the same numbers), without its per-call overhead:

    * ``predict(dt, fx_batch, Q, **kw)``: ``fx_batch(sigmas (2n+1, n), dt, **kw) -> (2n+1, n)``;
    * ``update(z, hx_batch, R, **kw) -> innovation``: ``hx_batch(sigmas (2n+1, n), **kw) -> (2n+1, dim_z)``;
      the sigma points are drawn from the current (x, P), so updates may follow each other or an
      initialisation without a predict in between;
    * after each step P is symmetrised; if it is not positive definite (Cholesky fails) it is replaced by
      its diagonal (absolute values, floored) and ``numerical_resets`` counts it. Non-finite state raises
      ``FloatingPointError``.
    """

    def __init__(self, dim_x: int, dim_z: int, alpha: float = 1.0, beta: float = 2.0, kappa: float = 0.0):
        if dim_x + kappa <= 0:
            raise ValueError(f"dim_x + kappa must be > 0 (dim_x={dim_x}, kappa={kappa})")
        n = dim_x
        lambda_ = alpha ** 2 * (n + kappa) - n
        c = .5 / (n + lambda_)
        self.Wc = np.full(2 * n + 1, c)
        self.Wm = np.full(2 * n + 1, c)
        self.Wc[0] = lambda_ / (n + lambda_) + (1 - alpha ** 2 + beta)
        self.Wm[0] = lambda_ / (n + lambda_)
        self._diag_wc = np.diag(self.Wc)
        self._wc_col = self.Wc[:, None]
        self._scale = lambda_ + n
        self.n, self.dim_z = n, dim_z
        self._x = np.zeros(n)
        self._P = np.eye(n)
        self._guarded = False  # P was checked (and symmetrised) since it last changed
        self.numerical_resets = 0
        self.last_nis = math.nan  # normalised innovation squared of the last update over its gate rows

    @property
    def x(self) -> np.ndarray:
        return self._x.copy()

    @property
    def P(self) -> np.ndarray:
        return self._P.copy()

    def sigma_points(self, x: np.ndarray, P: np.ndarray) -> np.ndarray:
        """(2n+1, n): x, then x plus and minus the rows of the upper Cholesky factor of (lambda + n) P."""
        n = self.n
        U = _safe_cholesky(self._scale * P)
        sigmas = np.empty((2 * n + 1, n))
        sigmas[0] = x
        np.add(x, U, out=sigmas[1:n + 1])  # x - (-U), the same in IEEE arithmetic
        np.subtract(x, U, out=sigmas[n + 1:])
        return sigmas

    def set_state(self, x, P) -> None:
        self._x = np.array(x, dtype=float)
        self._P = np.array(P, dtype=float)
        self._guarded = False
        self._guard()

    def predict(self, dt: float, fx_batch, Q, **fx_args) -> None:
        self._guard()
        sigmas = self.sigma_points(self._x, self._P)
        sigmas_f = np.asarray(fx_batch(sigmas, dt, **fx_args), dtype=float).reshape(sigmas.shape)
        # the unscented transform: x = sum W_m X, P = sum W_c (X - x)(X - x)^T + Q
        x = np.dot(self.Wm, sigmas_f)
        y = sigmas_f - x[np.newaxis, :]
        P = np.dot(y.T, np.dot(self._diag_wc, y))
        P += Q
        self._x, self._P, self._guarded = x, P, False
        self._guard()

    def update(self, z, hx_batch, R, gate: tuple[float, list[int]] | None = None,
               **hx_args) -> np.ndarray | None:
        """Unscented update. ``gate = (threshold, rows)``: if the normalised innovation squared over ``rows``
        (``y' S^-1 y``, kept in ``last_nis``) exceeds the threshold (``inf``: never), the update is not applied
        and None is returned; otherwise the innovation."""
        self._guard()
        x = self._x
        sigmas = self.sigma_points(x, self._P)
        z = np.asarray(z, dtype=float)
        zp, Szz, Pxz = self.moments(sigmas, x, hx_batch(sigmas, **hx_args))
        S = Szz + np.asarray(R, dtype=float)
        y = z - zp
        self.last_nis = math.nan
        if gate is not None:
            rows = gate[1]
            Sg = S[np.ix_(rows, rows)]
            self.last_nis = float(y[rows] @ np.linalg.solve(Sg, y[rows]))
            if self.last_nis > gate[0]:
                return None
        K = np.linalg.solve(S.T, Pxz.T).T  # Pxz S^-1 (S symmetric)
        self._x = x + K @ y
        self._P = self._P - K @ S @ K.T
        self._guarded = False
        self._guard()
        return y.copy()

    def current_sigma_points(self) -> np.ndarray:
        """The sigma points of the current (checked) state and covariance."""
        self._guard()
        return self.sigma_points(self._x, self._P)

    def set_posterior(self, x: np.ndarray, P: np.ndarray) -> None:
        """Take an update computed elsewhere (e.g. compiled): the state and covariance, then checked."""
        self._x, self._P, self._guarded = np.asarray(x, dtype=float), np.asarray(P, dtype=float), False
        self._guard()

    def moments(self, sigmas: np.ndarray, x: np.ndarray, sig_h) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(z_pred, P_zz, P_xz) of the sigma points' measurements ``sig_h`` (the unscented transform)."""
        sig_h = np.asarray(sig_h, dtype=float)
        zp = self.Wm @ sig_h
        dz = sig_h - zp
        wdz = self._wc_col * dz
        return zp, dz.T @ wdz, (sigmas - x).T @ wdz

    def _guard(self) -> None:
        if self._guarded:  # checked since it last changed (symmetrising a symmetric P changes nothing)
            return
        if not all(map(math.isfinite, self._x.tolist())):  # (a short vector: cheaper on floats than in numpy)
            raise FloatingPointError("UKF state is not finite")
        P = 0.5 * (self._P + self._P.T)
        ok = bool(np.isfinite(P).all()) and _dpotrf(P, lower=1, clean=0)[1] == 0
        if not ok:
            d = np.abs(np.nan_to_num(np.diag(P), nan=1.0, posinf=1.0))
            P = np.diag(np.maximum(d, _VAR_FLOOR))
            self.numerical_resets += 1
        self._P = P
        self._guarded = True


# --------------------------------------------------------------------------- the paper's UKF


def _process_noise(dt: float, cfg: UkfConfig) -> np.ndarray:
    """Q over dt: random walk on x1, x2; continuous white-noise acceleration on each (r_q, V_q) axis (kept for
    the last dt, the flight software's period, as it is asked for every predict)."""
    key = (dt, id(cfg))
    if _Q_CACHE.get("key") != key:
        _Q_CACHE["key"], _Q_CACHE["Q"] = key, _process_noise_of(dt, cfg)
    return _Q_CACHE["Q"]


_Q_CACHE: dict = {}


def _process_noise_of(dt: float, cfg: UkfConfig) -> np.ndarray:
    Q = np.zeros((8, 8))
    Q[0, 0] = Q[1, 1] = cfg.feature_process_noise ** 2 * dt
    block = np.array([[dt ** 3 / 3.0, dt ** 2 / 2.0], [dt ** 2 / 2.0, dt]])
    for i, q in enumerate((cfg.target_accel_noise_m_s2, cfg.target_accel_noise_m_s2,
                           cfg.target_vertical_accel_noise_m_s2)):
        idx = np.array([2 + i, 5 + i])
        Q[np.ix_(idx, idx)] = q * q * block
    return Q


def _fx_batch(S: np.ndarray, dt: float, r_c0, R_ec0, V_c, omega, max_step: float) -> np.ndarray:
    """Integrate the process model for all sigma points S (m, 8) over dt with RK4 (numpy).

    Camera inside the interval (tau from its start): r_c = r_c0 + V_c tau,
    R_enu_from_cam = R_ec0 exp([omega]x tau), omega in the camera frame. The filter runs the same
    integration compiled (:class:`_CompiledProcess`); this form is its reference in the tests.
    """
    n = max(1, int(math.ceil(dt / max_step - 1e-9)))
    h = dt / n
    cache: dict[float, np.ndarray] = {}

    def R_ce(tau: float) -> np.ndarray:
        R = cache.get(tau)
        if R is None:
            R = cache[tau] = (R_ec0 @ _exp_so3(omega, tau)).T
        return R

    def deriv(X: np.ndarray, tau: float) -> np.ndarray:
        Rce = R_ce(tau)
        rel = X[:, 2:5] - (r_c0 + V_c * tau)
        Z = np.maximum(rel @ Rce[2], MIN_DEPTH_M)
        v = (X[:, 5:8] - V_c) @ Rce.T
        D = np.zeros_like(X)
        D[:, 0:2] = feature_rates(X[:, 0], X[:, 1], Z, v, omega)
        D[:, 2:5] = X[:, 5:8]
        return D

    X = np.array(S, dtype=float)
    for k in range(n):
        t0 = k * h
        k1 = deriv(X, t0)
        k2 = deriv(X + 0.5 * h * k1, t0 + 0.5 * h)
        k3 = deriv(X + 0.5 * h * k2, t0 + 0.5 * h)
        k4 = deriv(X + h * k3, t0 + h)
        X = X + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return X


class _CompiledProcess:
    """:func:`_fx_batch` as one CasADi function per RK4 substep (``controllers.compiled``): the same
    integration, one C call instead of some eighty numpy calls (~20 us against ~140 us for 17 sigma
    points); the results differ from numpy's by rounding only.

    The state is ``[x1, x2, r_q, V_q, ...]``: the features' rates (the camera part, shared) come from
    :func:`_sx_feature_rates`; :meth:`_target_rates` gives the rates of the rest (here the constant-velocity
    target). A subclass with another target model (``controllers.estimation.ct_ukf``) sets ``dim_x``, ``function_name``,
    its own ``_cache`` and overrides :meth:`_target_rates`; ``params`` are its model's constants (part of the
    cache key)."""

    dim_x = 8
    function_name = "ukf_rk4_step"
    _cache: dict[tuple, "_CompiledProcess"] = {}

    @classmethod
    def for_points(cls, m: int, *params: float) -> "_CompiledProcess":
        key = (m, *params)
        if key not in cls._cache:
            cls._cache[key] = cls(m, *params)
        return cls._cache[key]

    def __init__(self, m: int, *params: float):
        import casadi as ca

        from controllers.compiled import Buffered
        self.m = m
        X, h, t0 = ca.SX.sym("X", m, self.dim_x), ca.SX.sym("h"), ca.SX.sym("t0")
        r, R, V, w = ca.SX.sym("r", 3), ca.SX.sym("R", 3, 3), ca.SX.sym("V", 3), ca.SX.sym("w", 3)

        def deriv(Xs, tau):  # the process model of _fx_batch
            x1d, x2d = _sx_feature_rates(Xs, tau, r, R, V, w, m)
            return ca.horzcat(x1d, x2d, self._target_rates(Xs, m, *params))

        k1 = deriv(X, t0)
        k2 = deriv(X + 0.5 * h * k1, t0 + 0.5 * h)
        k3 = deriv(X + 0.5 * h * k2, t0 + 0.5 * h)
        k4 = deriv(X + h * k3, t0 + h)
        step = ca.Function(self.function_name, [X, h, t0, r, R, V, w],
                           [X + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)])
        self._step = Buffered(step)

    @staticmethod
    def _target_rates(Xs, m: int):
        """``[r_q_dot, V_q_dot] = [V_q, 0]`` (constant velocity), CasADi SX (m, 6)."""
        import casadi as ca
        return ca.horzcat(Xs[:, 5:8], ca.SX.zeros(m, 3))

    def __call__(self, S: np.ndarray, dt: float, r_c0, R_ec0, V_c, omega, max_step: float) -> np.ndarray:
        n = max(1, int(math.ceil(dt / max_step - 1e-9)))
        h = dt / n
        # the inputs written into the function's buffers (column-major, as CasADi stores them): one copy each
        step = self._step
        X, h_in, t0, r, R, V, w = step.inputs
        X.reshape(self.dim_x, self.m)[:] = np.asarray(S, dtype=float).T
        h_in[0] = h
        r[:] = r_c0
        R.reshape(3, 3)[:] = np.asarray(R_ec0, dtype=float).T
        V[:] = V_c
        w[:] = omega
        out = step.outputs[0]
        for k in range(n):
            if k:
                X[:] = out
            t0[0] = k * h
            step()  # (on the inputs written above)
        return out.reshape(self.dim_x, self.m).T.copy()  # (the buffer is the next call's output)


class _PointingBiasProcess(_CompiledProcess):
    """:class:`_CompiledProcess` with the camera's pointing bias as two more states, constant over the
    interval (their random walk is in Q)."""

    dim_x = 10
    function_name = "ukf_pointing_bias_rk4_step"
    _cache: dict[tuple, "_CompiledProcess"] = {}

    @staticmethod
    def _target_rates(Xs, m: int):
        """``[V_q, 0, 0]``: the constant-velocity target, then the bias (SX (m, 8))."""
        import casadi as ca
        return ca.horzcat(Xs[:, 5:8], ca.SX.zeros(m, 5))


def _sx_exp_so3(w, tau):
    """:func:`_exp_so3` in CasADi SX (``w`` a 3-vector symbol, ``tau`` a scalar expression)."""
    import casadi as ca
    wx, wy, wz = w[0] * tau, w[1] * tau, w[2] * tau
    th2 = wx * wx + wy * wy + wz * wz
    K = ca.vertcat(ca.horzcat(0, -wz, wy), ca.horzcat(wz, 0, -wx), ca.horzcat(-wy, wx, 0))
    KK = ca.mtimes(K, K)
    th = ca.sqrt(th2)
    return ca.if_else(th2 < 1e-16, ca.SX.eye(3) + K + 0.5 * KK,
                      ca.SX.eye(3) + (ca.sin(th) / th) * K + ((1.0 - ca.cos(th)) / th2) * KK)


def _sx_feature_rates(Xs, tau, r, R, V, w, m: int):
    """``(x1_dot, x2_dot)`` (each SX (m, 1)) of the sigma points ``Xs`` (rows ``[x1, x2, r_q, V_q, ...]``) at
    ``tau`` into the interval, as :func:`_fx_batch` (feature rates as
    :func:`controllers.navigation.camera_model.feature_rates`): camera at ``r + V tau``, ``R_enu_from_cam = R exp([w]x
    tau)``, depth floored at MIN_DEPTH_M. Every estimator with the UKF's feature states shares it."""
    import casadi as ca
    Rce = ca.mtimes(R, _sx_exp_so3(w, tau)).T
    rel = Xs[:, 2:5] - ca.repmat((r + V * tau).T, m, 1)
    Z = ca.fmax(ca.mtimes(rel, Rce[2, :].T), MIN_DEPTH_M)
    v = ca.mtimes(Xs[:, 5:8] - ca.repmat(V.T, m, 1), Rce.T)
    x1, x2 = Xs[:, 0], Xs[:, 1]
    x12 = x1 * x2
    x1d = (v[:, 0] - x1 * v[:, 2]) / Z + x12 * w[0] + (-(1.0 + x1 * x1)) * w[1] + x2 * w[2]
    x2d = (v[:, 1] - x2 * v[:, 2]) / Z + (1.0 + x2 * x2) * w[0] + (-x12) * w[1] + (-x1) * w[2]
    return x1d, x2d


class _CompiledUpdate:
    """The UKF's measurement update as one CasADi function: from the sigma points, the measurement model of
    :func:`_hx_batch`, the unscented moments (:meth:`UnscentedCore.moments`), the innovation, the chi-square
    statistic over the pixel rows and the updated state and covariance (``P - K S K^T``, ``K = P_xz S^-1``),
    in one C call. The gate's decision stays with the caller."""

    _cache: dict[tuple, "_CompiledUpdate"] = {}

    @classmethod
    def for_core(cls, core: "UnscentedCore", bias_col: int | None = None) -> "_CompiledUpdate":
        key = (core.n, tuple(core.Wm), tuple(core.Wc), bias_col)
        if key not in cls._cache:
            cls._cache[key] = cls(core, bias_col)
        return cls._cache[key]

    def __init__(self, core: "UnscentedCore", bias_col: int | None = None):
        import casadi as ca

        from controllers.compiled import Buffered
        m, n = 2 * core.n + 1, core.n
        X, x, P = ca.SX.sym("X", m, n), ca.SX.sym("x", n), ca.SX.sym("P", n, n)
        z, r = ca.SX.sym("z", 5), ca.SX.sym("r", 5)  # the measurement, its noise variances
        k = ca.SX.sym("k", 4)  # f_u, f_v, c_u, c_v
        R, hc = ca.SX.sym("R", 3, 3), ca.SX.sym("hc", 2)  # R_enu_from_cam; camera height, plane height
        x1, x2 = X[:, 0], X[:, 1]
        d = (ca.repmat(R[:, 0].T, m, 1) * ca.repmat(x1, 1, 3) + ca.repmat(R[:, 1].T, m, 1) * ca.repmat(x2, 1, 3)
             + ca.repmat(R[:, 2].T, m, 1))  # rays (m, 3), as _hx_batch
        Z = (hc[0] - hc[1]) / ca.fmax(-d[:, 2], _MIN_RAY_DOWN)
        # the pixel rows: the features, with bias_col seen through the camera's pointing bias (states bias_col,
        # bias_col + 1: :func:`through_pointing_bias`)
        p1, p2 = (x1, x2) if bias_col is None else through_pointing_bias(x1, x2, X[:, bias_col], X[:, bias_col + 1])
        H = ca.horzcat(k[0] * p1 + k[2], k[1] * p2 + k[3], X[:, 2:5] - d * ca.repmat(Z, 1, 3))
        Wm, Wc = ca.DM(core.Wm).T, ca.DM(core.Wc)
        zp = ca.mtimes(Wm, H)
        dz = H - ca.repmat(zp, m, 1)
        wdz = dz * ca.repmat(Wc, 1, 5)
        S = ca.mtimes(dz.T, wdz) + ca.diag(r)
        Pxz = ca.mtimes((X - ca.repmat(x.T, m, 1)).T, wdz)
        y = z - zp.T
        a, b, c, dd = S[0, 0], S[0, 1], S[1, 0], S[1, 1]  # the pixel rows' 2 x 2 block
        nis = (dd * y[0] * y[0] - (b + c) * y[0] * y[1] + a * y[1] * y[1]) / (a * dd - b * c)
        K = ca.solve(S.T, Pxz.T).T  # P_xz S^-1 (S symmetric)
        self._fun = Buffered(ca.Function("ukf_update", [X, x, P, z, r, k, R, hc],
                                         [y, nis, x + ca.mtimes(K, y), P - ca.mtimes(ca.mtimes(K, S), K.T),
                                          a * dd - b * c, K[2:4, 0:2]]))
        self._n = n

    def __call__(self, sigmas, x, P, z, r, f_u, f_v, c_u, c_v, R_ec, cam_h, plane_z):
        """(innovation (5,), chi-square over the pixel rows, updated x, updated P, the determinant of the
        pixel rows' innovation covariance (px^4: with the chi-square, the detection's likelihood), the gain's
        horizontal position rows for the pixel columns (2 x 2, m/px: how far a pixel's error moves the
        estimate))."""
        # the inputs written into the function's buffers (column-major, as CasADi stores them): one copy each
        fun, n = self._fun, self._n
        X_in, x_in, P_in, z_in, r_in, k, R, hc = fun.inputs
        X_in.reshape(n, -1)[:] = np.asarray(sigmas).T
        x_in[:] = x
        P_in.reshape(n, n)[:] = np.asarray(P).T
        z_in[:] = z
        r_in[:] = r
        k[0], k[1], k[2], k[3] = f_u, f_v, c_u, c_v
        R.reshape(3, 3)[:] = np.asarray(R_ec, dtype=float).T
        hc[0], hc[1] = cam_h, plane_z
        y, nis, x_new, P_new, det, K_h = fun()  # (on the inputs written above)
        return (y.copy(), float(nis[0]), x_new.copy(), P_new.reshape(n, n).T.copy(), float(det[0]),
                K_h.reshape(2, 2).T.copy())


def _fx_compiled(S: np.ndarray, dt: float, r_c0, R_ec0, V_c, omega, max_step: float) -> np.ndarray:
    """:func:`_fx_batch`, compiled (:class:`_CompiledProcess`)."""
    return _CompiledProcess.for_points(len(S))(S, dt, r_c0, R_ec0, V_c, omega, max_step)


def _fx_pointing_bias_compiled(S: np.ndarray, dt: float, r_c0, R_ec0, V_c, omega, max_step: float) -> np.ndarray:
    """:func:`_fx_batch` on the 10-state sigma points (the pointing bias last), compiled."""
    return _PointingBiasProcess.for_points(len(S))(S, dt, r_c0, R_ec0, V_c, omega, max_step)


def _hx_batch(X: np.ndarray, f_u: float, f_v: float, c_u: float, c_v: float, R_ec: np.ndarray, cam_h: float,
              plane_z: float) -> np.ndarray:
    """[u, v, r_c] predicted from each state (rows of X): pinhole + flat-sea depth along the ray through
    (x1, x2). Row by row the same operations as one state at a time."""
    x1, x2 = X[:, 0:1], X[:, 1:2]
    d = R_ec[:, 0] * x1 + R_ec[:, 1] * x2 + R_ec[:, 2]  # (m, 3) rays in the world
    Z = (cam_h - plane_z) / np.maximum(-d[:, 2:3], _MIN_RAY_DOWN)
    out = np.empty((X.shape[0], 5))
    out[:, 0:1] = f_u * x1 + c_u
    out[:, 1:2] = f_v * x2 + c_v
    out[:, 2:5] = X[:, 2:5] - d * Z
    return out


def through_pointing_bias(x1, x2, b1, b2):
    """The normalised image point where a camera turned by its pointing bias sees the feature ``(x1, x2)`` of
    the camera as believed (elementwise; floats, arrays or CasADi expressions). The bias ``(b1, b2)`` is where
    the believed boresight appears: to first order in the bias, the camera frame turned about its x and y axes
    so that ``[x1, x2, 1]`` is seen along ``[x1 + b1, x2 + b2, 1 - b1 x1 - b2 x2]`` (a point off the centre
    moves slightly more than the centre)."""
    den = 1.0 - b1 * x1 - b2 * x2
    return (x1 + b1) / den, (x2 + b2) / den


def _with_pointing_bias(x: np.ndarray, P: np.ndarray, std_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """The 8-state start with the pointing bias appended: zero, ``std_rad`` per axis. The detection gives the
    features plus the bias, so each feature starts anti-correlated with its bias (``Cov = -std^2``) and
    that much less certain."""
    n = len(x)
    Pb = np.zeros((n + 2, n + 2))
    Pb[:n, :n] = P
    v = std_rad * std_rad
    for i in (0, 1):
        Pb[i, i] += v
        Pb[n + i, n + i] = v
        Pb[i, n + i] = Pb[n + i, i] = -v
    return np.concatenate([x, [0.0, 0.0]]), Pb


def height_consider_cov(x1: float, x2: float, R_enu_from_cam, height_std_m: float) -> np.ndarray:
    """Horizontal covariance (2 x 2, m^2) on the target plane of an error ``height_std_m`` in the height of the
    point seen through the normalised pixel (x1, x2): along the ray ``d = R [x1, x2, 1]`` a point ``dz`` higher
    meets the plane ``dz / -d_z`` further on, horizontally ``dz d_h / -d_z`` (``|d_h| / -d_z`` = 1 / tan of the
    elevation), so the covariance is ``height_std^2 g g^T`` with ``g = d_h / -d_z``; zeros where the ray does
    not come down."""
    d = np.asarray(R_enu_from_cam, dtype=float) @ np.array([x1, x2, 1.0])
    if not d[2] < -1e-9:
        return np.zeros((2, 2))
    return np.array(_height_cov(d.tolist(), height_std_m))


def _height_cov(d: list, height_std_m: float) -> list[list[float]]:
    """:func:`height_consider_cov` of the ray ``d`` (a list, coming down), element by element: ``s^2 g_i g_j``,
    ``g = d_h / -d_z``."""
    nd = -d[2]
    g0, g1 = d[0] / nd, d[1] / nd
    s2 = height_std_m * height_std_m
    return [[s2 * (g0 * g0), s2 * (g0 * g1)], [s2 * (g1 * g0), s2 * (g1 * g1)]]


_ZERO23 = np.zeros((2, 3))
_ZERO23.flags.writeable = False


def _sqrt_spd2(a: float, b: float, c: float) -> tuple[float, float, float]:
    """The symmetric square root (its entries (0, 0), (0, 1), (1, 1)) of the symmetric positive
    semi-definite 2 x 2 matrix [[a, b], [b, c]]: ``(A + sqrt(det) I) / sqrt(trace + 2 sqrt(det))``."""
    sd = math.sqrt(max(a * c - b * b, 0.0))
    t = a + c + 2.0 * sd
    if not t > 0.0:
        return 0.0, 0.0, 0.0
    n = 1.0 / math.sqrt(t)
    return (a + sd) * n, b * n, (c + sd) * n


def _ray_meets_plane(x1: float, x2: float, R_enu_from_cam, cam_z_m: float, plane_z_m: float) -> bool:
    """:func:`controllers.navigation.camera_model.depth_on_plane` is finite (the ray through (x1, x2) meets the
    plane)."""
    R = R_enu_from_cam
    dz = float(R[2, 0]) * x1 + float(R[2, 1]) * x2 + float(R[2, 2])
    return -dz / math.sqrt(x1 * x1 + x2 * x2 + 1.0) >= _CAMERA_MIN_RAY_DOWN and cam_z_m - plane_z_m > 0.0


def _finite_and_any(values: list[float]) -> bool:
    """All finite and not all zero (``np.isfinite(a).all() and a.any()`` of the array they came from)."""
    return all(map(math.isfinite, values)) and any(values)


def step_on_measurements(estimator, meas: Measurements, motion: CameraMotion):
    """One tick of a target estimator on raw measurements (its ``step``): initialise on the first valid
    detection (one whose ray misses the plane counts in ``estimator.rejected_updates``), else predict to
    meas.t_s and update if one arrived. The estimate, or None while not initialised."""
    fix = fix_from_measurements(meas)
    if not estimator.initialised:
        if not fix.new:
            return None
        try:
            estimator.initialise(fix, motion)
        except ValueError:
            estimator.rejected_updates += 1
            return None
        return estimator.estimate()
    estimator.predict(meas.t_s, motion)
    if fix.new:
        estimator.update(fix, motion)
    return estimator.estimate() if estimator.initialised else None


def fix_from_measurements(meas: Measurements) -> DetectionFix:
    """The newest detection of ``meas`` as a :class:`DetectionFix`, uncorrected (the box centre as detected)."""
    new = bool(meas.det_new and meas.det_valid)
    return DetectionFix(meas.t_s, new, meas.det_exposure_t_s, meas.det_u_px, meas.det_v_px, meas.det_bbox_px,
                        meas.det_u_px, meas.det_v_px, np.full(4, np.nan), new, "", "", False, False, math.nan,
                        meas.t_s if new else math.nan)


class UkfTargetEstimator:
    """The paper's 8-state UKF: the flight software's built-in estimator (``controllers.estimator: ukf``).

    It implements ``controllers.blocks.TargetEstimator``. Use per tick::

        motion = CameraMotion.from_measurements(meas, mount_offset_frd_m)
        est = ukf.step(meas, motion)        # None until the first valid detection

    or call ``initialise`` / ``predict`` / ``update`` with the perception's :class:`DetectionFix`.
    """

    name = "ukf"
    label = "UKF"  # its name in the flight software's events
    dim_x = 8  # [x1, x2, r_q, V_q]; a subclass with more target states (controllers.estimation.ct_ukf) appends them

    estimates_pointing_bias = True  # False: a subclass's target model does not take the two bias states

    def __init__(self, camera: PinholeCamera, config: UkfConfig | None = None):
        self.cfg = config if config is not None else UkfConfig()
        self.camera = camera
        self._target_dim = self.dim_x
        self._bias_col: int | None = None  # the pointing bias's first state while it is estimated (_set_bias_states)
        self._q_bias: tuple[float, np.ndarray] | None = None
        self._att_var = math.nan  # the navigation's lowest attitude variance since the start (rad^2)
        self._set_bias_states(False)
        self._initialised = False
        self._t = math.nan
        self._motion: CameraMotion | None = None
        self._innov = np.full(2, np.nan)
        self._innov_t = math.nan
        self._consider = np.zeros((2, 2))  # horizontal covariance of the box centre's systematic error (m^2)
        self._consider_factor = _ZERO23  # its factor F (2 x 3, m): the covariance is F F^T
        self.rejected_updates = 0  # detections not used (ray misses the plane, non-finite pixels)
        self.divergence_resets = 0  # non-finite state: the filter de-initialised itself
        self.gated_updates = 0  # detections rejected by the innovation gate
        self._rejects_in_a_row = 0
        self.updates = 0
        self.initialisations = 0
        self._last_nis_det = (math.nan, math.nan)  # the last update's chi-square and pixel-rows determinant

    # ------------------------------------------------------------ properties
    @property
    def initialised(self) -> bool:
        return self._initialised

    @property
    def last_log_likelihood(self) -> float:
        """The last detection's log-likelihood under the filter's prediction: the Gaussian density of its
        pixel innovation, whether the gate took it or not (NaN when the last update computed none). A
        multiple-model filter (controllers.estimation.imm) weighs its models by it."""
        nis, det = self._last_nis_det
        if not (det > 0.0 and math.isfinite(nis)):
            return math.nan
        return -0.5 * nis - 0.5 * math.log(det) - _LOG_2PI

    @property
    def t_s(self) -> float:
        return self._t

    @property
    def tracked_height_m(self) -> float:
        """Height above the ship's waterline of the point it tracks (``target_plane_height_m``)."""
        return self.cfg.target_plane_height_m

    @property
    def x(self) -> np.ndarray:
        """The 8-state [x1, x2, r_q, V_q] (copy)."""
        return self._core.x

    @property
    def cov(self) -> np.ndarray:
        """The 8x8 covariance (copy)."""
        return self._core.P

    @property
    def pos_enu_m(self) -> np.ndarray:
        return self._core.x[2:5]

    @property
    def vel_enu_m_s(self) -> np.ndarray:
        return self._core.x[5:8]

    @property
    def pos_vel_cov(self) -> np.ndarray:
        return self._core.P[2:8, 2:8]

    @property
    def features(self) -> tuple[float, float]:
        x = self._core.x
        return float(x[0]), float(x[1])

    @property
    def numerical_resets(self) -> int:
        """How often P was not positive definite and was reset to its diagonal."""
        return self._core.numerical_resets

    @property
    def core(self) -> UnscentedCore:
        return self._core

    # ------------------------------------------------------------ the target model (a subclass's hooks)
    _fx = staticmethod(_fx_compiled)  # fx_batch of UnscentedCore.predict: the sigma points over dt

    def _set_bias_states(self, on: bool) -> None:
        """The filter with (``on``) or without the pointing bias's two states after the target's."""
        c = self.cfg
        self._bias_col = self._target_dim if on else None
        self.dim_x = self._target_dim + (2 if on else 0)
        if on:
            self._fx = _fx_pointing_bias_compiled
        else:
            self.__dict__.pop("_fx", None)  # the class's (the target model's)
        self._q_bias = None
        self._core = UnscentedCore(self.dim_x, 5, c.sigma_alpha, c.sigma_beta, c.sigma_kappa)
        self._update = _CompiledUpdate.for_core(self._core, self._bias_col)

    def _wants_bias_states(self, motion: CameraMotion) -> bool:
        """The pointing bias is estimated when it is configured and the navigation reports its attitude
        uncertainty (an INS does; a navigation that reports none is taken as exact, as the estimator always
        took it before)."""
        return (self.estimates_pointing_bias and self.cfg.pointing_bias_std_rad > 0.0
                and math.isfinite(motion.att_var_rad2))

    def _process_noise(self, dt: float) -> np.ndarray:
        """Q over dt (:func:`_process_noise`)."""
        return _process_noise(dt, self.cfg)

    def _bias_process_noise(self, dt: float, omega, motion: CameraMotion) -> np.ndarray:
        """Q over dt with the pointing bias estimated. The bias random-walks (``pointing_bias_walk_rad_rt_s``)
        and moves with the navigation's corrections to its attitude while that converges: a Kalman filter's
        correction has the covariance its update removes, so each fall of the navigation's attitude variance
        below its lowest since the start is added (over the image's two axes; its rises and falls about a
        steady level are the wander the random walk stands for). The features' random walk grows with the camera's
        rate error (``pointing_rate_error_frac`` of its angular rate ``omega``): a turning camera's feature
        rates are only that good, so a slew teaches the filter no more of the bias than that allows."""
        key = dt
        if self._q_bias is None or self._q_bias[0] != key:
            Qb = np.zeros((self.dim_x, self.dim_x))
            n = self._target_dim
            Qb[:n, :n] = self._process_noise(dt)
            Qb[n, n] = Qb[n + 1, n + 1] = self.cfg.pointing_bias_walk_rad_rt_s ** 2 * dt
            self._q_bias = (key, Qb)
        Q = self._q_bias[1].copy()
        w = float(np.linalg.norm(omega)) * self.cfg.pointing_rate_error_frac
        Q[0, 0] += w * w * dt
        Q[1, 1] += w * w * dt
        var = motion.att_var_rad2
        if math.isfinite(var) and var < self._att_var:  # a new low: the navigation has converged further
            n = self._bias_col
            Q[n, n] += 0.5 * (self._att_var - var)
            Q[n + 1, n + 1] += 0.5 * (self._att_var - var)
            self._att_var = var
        return Q

    @property
    def pointing_bias_rad(self) -> np.ndarray:
        """The estimated pointing bias (the image's x and y, normalised units ~ rad; zeros when not estimated)."""
        if self._bias_col is None or not self._initialised:
            return np.zeros(2)
        return self._core.x[self._bias_col:self._bias_col + 2]

    @staticmethod
    def _initial_state(x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The state and covariance to start from, given the 8-state ones :meth:`initialise` makes."""
        return x, P

    # ------------------------------------------------------------ steps
    def reset(self) -> None:
        """Forget the target: the next valid detection initialises again."""
        self._initialised = False
        self._consider = np.zeros((2, 2))
        self._consider_factor = _ZERO23
        self._motion = None
        self._innov = np.full(2, np.nan)
        self._innov_t = math.nan

    def initialise(self, fix: DetectionFix, motion: CameraMotion) -> None:
        """Start from one detection (its box centre ``u_px, v_px``): r_q on the plane along its ray, V_q = 0
        with a large variance.

        Raises ValueError if there is no detection or its ray does not meet the plane.
        """
        c, cam = self.cfg, self.camera
        if not (fix.new and math.isfinite(fix.u_px) and math.isfinite(fix.v_px)):
            raise ValueError("initialise needs a valid detection")
        x1, x2 = (float(a) for a in cam.normalised(fix.u_px, fix.v_px))
        Z = depth_on_plane(x1, x2, motion.R_enu_from_cam, motion.height_m, c.target_plane_height_m)
        if not math.isfinite(Z):
            raise ValueError("the detection's ray does not meet the target plane")
        d = motion.R_enu_from_cam @ np.array([x1, x2, 1.0])
        r_q = motion.pos_enu_m + Z * d
        r_q[2] = c.target_plane_height_m
        rng = Z * math.sqrt(1.0 + x1 * x1 + x2 * x2)
        sp = max(c.init_pos_std_frac * rng, c.cam_pos_noise_m)
        sv = c.init_vel_std_m_s
        P = np.diag([(c.pixel_noise_px / cam.fx) ** 2, (c.pixel_noise_px / cam.fy) ** 2, sp * sp, sp * sp,
                     _INIT_VERTICAL_POS_STD_M ** 2, sv * sv, sv * sv, _INIT_VERTICAL_VEL_STD_M_S ** 2])
        x0 = np.concatenate([[x1, x2], r_q, np.zeros(3)])
        bias = self._wants_bias_states(motion)
        if bias != (self._bias_col is not None):
            self._set_bias_states(bias)
        x0, P = self._initial_state(x0, P)
        if bias:  # the mount's calibration and the navigation's attitude, over the image's two axes
            self._att_var = motion.att_var_rad2
            x0, P = _with_pointing_bias(x0, P, math.sqrt(c.pointing_bias_std_rad ** 2 + 0.5 * self._att_var))
        self._core.set_state(x0, P)
        self.initialisations += 1
        self._t = float(fix.t_s)
        self._motion = motion
        self._innov = np.full(2, np.nan)
        self._innov_t = math.nan
        self._rejects_in_a_row = 0
        self._initialised = True
        self._set_consider(self._box_bias_factor(fix, motion)[0])

    def predict(self, t_s: float, motion: CameraMotion) -> None:
        """Propagate to t_s (no-op before initialisation or if t_s is not later than the filter's time)."""
        if not self._initialised:
            return
        dt = float(t_s) - self._t
        if dt <= 0.0:
            if dt == 0.0:
                self._motion = motion
            return
        m0 = self._motion if self._motion is not None else motion
        omega = 0.5 * (m0.omega_cam_rad_s + motion.omega_cam_rad_s)
        V_c = 0.5 * (m0.vel_enu_m_s + motion.vel_enu_m_s)
        try:
            # a target leaving the camera's front half-space makes x1, x2 = X/Z, Y/Z blow up: the
            # resulting non-finite state is caught below, so numpy's overflow warnings are noise here
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                Q = self._process_noise(dt) if self._bias_col is None else self._bias_process_noise(dt, omega, motion)
                self._core.predict(dt, self._fx, Q, r_c0=m0.pos_enu_m,
                                   R_ec0=m0.R_enu_from_cam, V_c=V_c, omega=omega, max_step=self.cfg.max_substep_s)
        except FloatingPointError:
            self.divergence_resets += 1
            self.reset()
            return
        self._t = float(t_s)
        self._motion = motion

    def update(self, fix: DetectionFix, motion: CameraMotion) -> FusionResult:
        """Fuse the detection's (corrected) box centre ``u_px, v_px`` (predicts to fix.t_s first)."""
        self._last_nis_det = (math.nan, math.nan)
        if not (self._initialised and fix.new):
            return FusionResult(False, FusionReason.NOT_INITIALISED if fix.new else FusionReason.REJECTED)
        if float(fix.t_s) > self._t:
            self.predict(fix.t_s, motion)
            if not self._initialised:
                return FusionResult(False, FusionReason.ESTIMATOR_RESET)
        c, cam = self.cfg, self.camera
        u, v = float(fix.u_px), float(fix.v_px)
        if not (math.isfinite(u) and math.isfinite(v)):
            self.rejected_updates += 1
            return FusionResult(False, FusionReason.REJECTED)
        if not _ray_meets_plane((u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, motion.R_enu_from_cam,
                                motion.height_m, c.target_plane_height_m):
            self.rejected_updates += 1
            return FusionResult(False, FusionReason.REJECTED)
        rel = self._core._x[2:5] - motion.pos_enu_m
        rng = math.sqrt(rel.dot(rel))
        h = max(motion.height_m - c.target_plane_height_m, 1.0)
        s2 = c.cam_pos_noise_m ** 2 + (c.attitude_noise_rad * rng) ** 2 + (c.height_noise_m * rng / h) ** 2
        r = [c.pixel_noise_px ** 2, c.pixel_noise_px ** 2, s2, s2, s2]  # (copied into the compiled update's input)
        extra_u, extra_v = fix.centre_noise_px2
        if extra_u or extra_v:  # a box used with its doubt (perception: size_mismatch_action deweight)
            r[0] += extra_u
            r[1] += extra_v
        z = [u, v, *motion.pos_enu_m]
        # the chi-square test on the pixel rows is always computed (for the log); it rejects only while
        # the gate is on and has not rejected innovation_gate_max_rejects detections in a row
        gating = c.innovation_gate > 0.0 and self._rejects_in_a_row < c.innovation_gate_max_rejects
        core = self._core
        try:
            y, nis, x_new, P_new, det, _ = self._update(core.current_sigma_points(), core._x, core._P, z, r,
                                                          cam.fx, cam.fy, cam.cx, cam.cy, motion.R_enu_from_cam,
                                                          motion.height_m, c.target_plane_height_m)
            core.last_nis = nis
            self._last_nis_det = (nis, det)
            rejected = gating and nis > c.innovation_gate
            if rejected and c.innovation_gate_box_bias:
                rejected = self._gate_box_bias_nis(fix, core, z, r, motion) > c.innovation_gate
            if not rejected:
                core.set_posterior(x_new, P_new)
        except FloatingPointError:
            self.divergence_resets += 1
            self.reset()
            return FusionResult(False, FusionReason.ESTIMATOR_RESET)
        ratio = nis / c.innovation_gate if c.innovation_gate > 0.0 else math.nan
        if rejected:
            self.gated_updates += 1
            self._rejects_in_a_row += 1
            return FusionResult(False, FusionReason.INNOVATION_GATE, np.full(2, np.nan), ratio)
        self._rejects_in_a_row = 0
        self._innov = y[:2].copy()
        self._innov_t = self._t
        self._motion = motion
        self._set_consider(self._box_bias_factor(fix, motion)[0])  # the latest fused box's view
        self.updates += 1
        return FusionResult(True, FusionReason.USED, self._innov.copy(), ratio)

    def _gate_box_bias_nis(self, fix: DetectionFix, core, z, r, motion: CameraMotion) -> float:
        """The normalised innovation squared with the box centre's systematic error (``box_centre_bias_frac``
        of the detected box's width and height) added to the pixel noise: for the gate alone."""
        b = np.asarray(fix.bbox_px, dtype=float)
        k = self.cfg.box_centre_bias_frac
        if b.shape != (4,) or not np.all(np.isfinite(b)) or k <= 0.0:
            return core.last_nis
        rg = list(r)
        rg[0] += (k * float(b[2] - b[0])) ** 2
        rg[1] += (k * float(b[3] - b[1])) ** 2
        cam = self.camera
        _, nis, _, _, _, _ = self._update(core.current_sigma_points(), core._x, core._P, z, rg, cam.fx, cam.fy,
                                          cam.cx, cam.cy, motion.R_enu_from_cam, motion.height_m,
                                          self.cfg.target_plane_height_m)
        return float(nis)

    def _set_consider(self, factor: np.ndarray) -> None:
        """The reported std's systematic part from its factor (2 x 3, m)."""
        self._consider_factor = factor
        self._consider = factor @ factor.T

    def _box_bias_factor(self, fix: DetectionFix, motion: CameraMotion) -> tuple[np.ndarray, tuple | None]:
        """(The factor ``F`` (2 x 3, m) of the horizontal covariance ``F F^T`` (m^2) on the target plane of a
        systematic box-centre error of ``box_centre_bias_frac`` of the box's width and height, plus
        (``consider_heading_spread``) the shape correction's spread over the headings the ship may have
        (``fix.offset_spread_px2``), plus (``box_centre_height_std_m``) the tracked point's height error, seen
        from this detection's view (zero without a box or where the ray misses the plane); ``J``). ``F`` is
        ``[J S^(1/2), s_h g]``: ``J`` the view's pixel-to-plane Jacobian (horizontal rows; nested tuples, None
        where ``F`` is zero for want of a view), ``S`` the box centre's systematic pixel covariance
        (``diag(s^2)`` plus the heading spread; its symmetric square root, so that factors of consecutive
        boxes blend without sign flips), ``g`` the plane's displacement of a point seen 1 m higher
        (:func:`height_consider_cov`) and ``s_h`` ``box_centre_height_std_m``."""
        cfg = self.cfg
        k, b = cfg.box_centre_bias_frac, np.asarray(fix.bbox_px, dtype=float)
        spread = np.asarray(fix.offset_spread_px2, dtype=float) if cfg.consider_heading_spread else None
        if spread is not None and not (spread.shape == (2, 2) and _finite_and_any(spread.ravel().tolist())):
            spread = None
        sh = cfg.box_centre_height_std_m
        box = b.tolist() if b.shape == (4,) else None
        if (k <= 0.0 and spread is None and sh <= 0.0) or box is None or not all(map(math.isfinite, box)):
            return _ZERO23, None
        # the view's geometry as ground_from_pixel_jacobian (horizontal rows) and height_consider_cov, from
        # one ray, on Python floats
        cam = self.camera
        x1, x2 = (float(fix.u_px) - cam.cx) / cam.fx, (float(fix.v_px) - cam.cy) / cam.fy  # cam.normalised
        R = np.asarray(motion.R_enu_from_cam, dtype=float)
        d = (R @ np.array([x1, x2, 1.0])).tolist()
        h = motion.height_m - cfg.target_plane_height_m
        if not (d[2] < -1e-9 and h > 0.0):  # the ray does not come down to the plane
            return _ZERO23, None
        J = ground_jacobian_rows(R.tolist(), d, h, cam.fx, cam.fy, 2)
        (j00, j01), (j10, j11) = J
        if not (math.isfinite(j00) and math.isfinite(j01) and math.isfinite(j10) and math.isfinite(j11)):
            return _ZERO23, None
        s0, s1 = k * (box[2] - box[0]), k * (box[3] - box[1])
        if spread is None:
            a, b, c = abs(s0), 0.0, abs(s1)  # diag(s)
        else:
            a, b, c = _sqrt_spd2(s0 * s0 + float(spread[0, 0]), float(spread[0, 1]), s1 * s1 + float(spread[1, 1]))
        nd = -d[2]
        g0, g1 = sh * d[0] / nd, sh * d[1] / nd  # (zero without a height error)
        return (np.array([[j00 * a + j01 * b, j00 * b + j01 * c, g0], [j10 * a + j11 * b, j10 * b + j11 * c, g1]]),
                ((j00, j01), (j10, j11)))

    def status(self, t_s: float) -> EstimatorStatus:
        """The counters since the start, as the log's ``/fsw/estimator_status``."""
        return EstimatorStatus(t_s, self.updates, self.gated_updates, self.rejected_updates, self.divergence_resets,
                               self.numerical_resets, self.initialisations)

    def step(self, meas: Measurements, motion: CameraMotion) -> TargetEstimate | None:
        """One tick on raw measurements (no shape correction): initialise on the first valid detection, else
        predict to meas.t_s and update if one arrived. Returns the estimate, or None while not initialised.
        """
        return step_on_measurements(self, meas, motion)

    def estimate(self) -> TargetEstimate:
        return TargetEstimate(*self._estimate_fields())

    def _estimate_fields(self) -> tuple:
        """The fields of :meth:`estimate`, in order (a subclass's estimate appends its own)."""
        if not self._initialised:
            nan3 = np.full(3, np.nan)
            return self._t, nan3, nan3.copy(), nan3.copy(), nan3.copy(), math.nan, math.nan, np.full(2, np.nan)
        x, P = self._core._x, self._core._P  # read only (what is returned is copied)
        var = P.diagonal().copy()
        var[2:4] += self._consider.diagonal()  # the box centre's systematic error, in the reported std only
        sd = np.sqrt(np.maximum(var, 0.0))
        innov = self._innov.copy() if self._innov_t == self._t else _NAN2.copy()
        return (self._t, x[2:5].copy(), x[5:8].copy(), sd[2:5].copy(), sd[5:8].copy(), float(x[0]), float(x[1]),
                innov)
