"""Phase 2: the NMPC loiter around the ship (paper "Phase 2: NMPC for the tracking phase"), with the CBF.

Model (the paper's NMPC state and input, eqs. (15)-(17)). State and input::

    X = [x, y, z (ENU, m), phi, theta, psi]      U = [V_U (m/s), u_p, u_q (rad/s)]

phi, theta are the aerospace roll and pitch; **psi is the ENU yaw, counter-clockwise from
East** (``psi = pi/2 - psi_ned``), the convention of the paper's eq. (17). With it,
positive roll (right wing down) turns right, i.e. decreases psi::

    r_dot     = V_U [cos psi cos theta, sin psi cos theta, sin theta]
    phi_dot   = u_p + u_q sin(phi) tan(theta)
    theta_dot = u_q cos(phi)
    psi_dot   = -(g / V_U) tan(phi) cos(theta)

Discretisation: Euler forward ``X_{k+1} = X_k + T_s Xdot(X_k, U_k)`` (paper); ``integrator:
rk4`` is available. Euler is kept: its prediction drifts from an exact flight of the same plan by
at most ~3 m at the end of the 5 s horizon in a 35 deg bank (tools/bench_nmpc.py prints it), and
on the continuous model as plant the loop still settles to ~0.2 m radius RMS.

Cost, summed over the horizon (paper eq. NMPC with f1..f4)::

    f1 = w1 (|r_p,k - r_q,k|_xy - R)^2           k = 1..N (X_0 is fixed; X_N is included so
    f2 = w2 (z_k - H)^2                          k = 1..N  the last input is not free)
    f3 = (Q_{k+1} - Q_k)^T W3 (Q_{k+1} - Q_k)    k = 0..N-1, Q = [phi, theta, psi]
    f4 = w4 |[u_p, u_q]_0 - [u_p, u_q]*_{-1}|^2   the previously applied input
    reg = w_V (V_U,k - V_ref)^2 + w_rate (u_p,k^2 + u_q,k^2)     (ours, small)
    f5 = w5 (r_dot_k / V_ref + tanh((r_k - R) / L))^2            k = 0..N-1 (ours, ``w5_approach``)

``r_q,k = r_q + V_q k T_s``: the target's constant-velocity future from the UKF estimate at
solve time (with ``air_relative``, V_q minus the navigation's wind estimate: the model's
kinematics are the air's, so the target is predicted in the air mass, where the relative
geometry is exact).

f5 (not in the paper; ``w5_approach`` = 0 leaves it out) shapes the approach to the ring:
``r_k = |r_p,k - r_q,k|_xy`` and ``r_dot_k = (r_{k+1} - r_k) / T_s`` through the step, so the
wanted closing rate falls from V_ref far out to zero on the ring over the length L
(``approach_length_m``). It is zero on a steady orbit in either direction. Without it the cost
sees only the radius error of the next 5 s: arriving head-on at the ring it banks in at the
limit, overshoots, and in the JSBSim loop (wind, the airframe's lags) can keep looping at full
bank round a point near the ring, the ship passing behind the UAV each loop (the pan's seam).

``Q_{k+1} - Q_k`` is written as ``Q(F(X_k, U_k)) - Q(X_k)`` (F the discrete step), equal on the
dynamics and stage-separable, which the structured solvers need. The input regularisation makes V_U
(which only enters through the kinematics) and the rates strictly convex in the QP (its weights are
1e-4 of the tracking terms' scale). The CBF slack
(controllers/guidance/cbf.py) is a 4th control per stage, penalised linearly and quadratically. Weights
are per stage; the defaults put the cost at O(100) for the paper's start (300 m, 100 m off).

Bounds (eq. limits): |phi| <= phi_max, |theta| <= theta_max on X_1..X_N; V_U, u_p, u_q boxes.
If the measured attitude is already outside its box, the state bound of stage k is widened to
what the rate limits can reach by then (a funnel), so the problem stays feasible.

Solvers (``NmpcConfig.solver``):
  * ``rti_hpipm`` (default): SQP in real-time-iteration form. Per call: shift the previous plan
    by the elapsed steps, embed the measured X_0 through the QP bounds, evaluate one expanded SX
    function (Hessian blocks, gradient, constraint Jacobian; evaluated on preallocated numpy
    buffers, ``Function.buffer``), solve one structure-exploiting QP with HPIPM (variables
    [x0, u0, x1, u1, ..., xN], constraints [gap0, cbf0, gap1, cbf1, ...]) and take the full step.
    The QP Hessian (``hessian: exact``) is the Hessian of the Lagrangian with the gap multipliers
    from an adjoint recursion, made convex by flooring the eigenvalues of each stage block (on its
    structurally independent groups: [x, y, z, angles, inputs] and the slack). The Gauss-Newton
    Hessian (``hessian: gauss_newton``, cheaper) drops the curvature of the turn dynamics
    (psi_dot ~ tan(phi)/V times large multipliers on big radius errors) and its real-time
    iteration then oscillates period-2 in u_p during the approach. ``rti_iterations`` QPs per call
    (default 1); a cold start (first call, after a reset) iterates up to ``cold_start_iterations``
    (with ``budget: wall_clock``, also within 90 % of ``max_solve_ms``). A call at the same t_s as the
    previous one does not shift, so repeated calls keep iterating toward the optimum.
  * ``rti_qrqp``: the same with CasADi's sparse active-set qrqp (far slower here and unreliable on
    this QP: kept for comparison only).
  * ``fatrop``: the full NLP with the structure-exploiting interior point Fatrop (exact Hessian).
  * ``ipopt``: the full NLP with IPOPT (exact Hessian, converged to ``ipopt_tol``): the reference.

A failed or (``budget: wall_clock`` only) late (``solve_ms > max_solve_ms``) solve never raises: the result carries the
previous successful plan's input for this time (the shifted plan's first input), ``fallback``
is true and ``status`` says why; ``Nmpc.fallback_count`` counts them.

Nothing here imports the truth side of the harness (docs/design/architecture.md, "Two rules").
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from controllers.compiled import Buffered
from controllers.config import NmpcConfig
from controllers.guidance.cbf import G, cbf_rows, cbf_terms
from fwsim.interface.frames import wrap_pi
from fwsim.interface.messages import Measurements, RateCommand

__all__ = ["NmpcConfig", "NmpcResult", "NmpcStatus", "Nmpc", "continuous_dynamics", "NX", "KinematicRun",
           "kinematic_closed_loop"]

NX = 6  # [x, y, z, phi, theta, psi]
_TWO_PI = 2.0 * math.pi
_DIST_EPS2 = 1.0  # m^2 inside the planar-distance sqrt (smooth at the target)
_HESS_REG = 1e-8  # diagonal added to the QP Hessian
_FUNNEL = 0.5  # fraction of the rate limit used to widen a violated attitude bound per second
_CBF_ACTIVE_TOL = 1e-3  # rad/s: a CBF row closer than this to its bound counts as active


@dataclass(frozen=True, slots=True)
class NmpcResult:
    t_s: float
    u0: np.ndarray  # (3,) [V_U m/s, u_p rad/s, u_q rad/s] to apply now
    status: str  # "ok", "fallback:late", "fallback:failed:<why>", ...
    solve_ms: float
    iterations: int
    fallback: bool
    cost: float  # cost of the returned plan (nan on a fallback)
    predicted: np.ndarray  # (N+1, 6) predicted states (psi continuous with the x0 given)
    cbf_active: bool  # a CBF row is (nearly) binding somewhere on the horizon
    min_h: float  # min over the predicted states of controllers.guidance.cbf.h_value (rad)
    inputs: np.ndarray  # (N, 3) the plan's inputs [V_U, u_p, u_q] (on a late solve: the new, unapplied plan)


@dataclass(frozen=True, slots=True)
class NmpcStatus:
    """One NMPC solve, for the log (``/fsw/nmpc``; the horizon's positions decimated to every 5th step)."""

    t_s: float
    status: str
    solve_ms: float
    iterations: int
    fallback: bool
    cost: float
    cbf_active: bool
    min_h_rad: float
    u0: np.ndarray  # (3,) V_U, u_p, u_q applied
    predicted_xyz_m: np.ndarray  # flattened (k, 3) predicted positions
    fallback_count: int = 0  # fallbacks since the start (this one included)

    @classmethod
    def from_result(cls, res: "NmpcResult", fallback_count: int) -> "NmpcStatus":
        return cls(res.t_s, res.status, res.solve_ms, res.iterations, res.fallback, res.cost, res.cbf_active,
                   res.min_h, np.asarray(res.u0, float), np.asarray(res.predicted[::5, :3], float).ravel(),
                   int(fallback_count))


def continuous_dynamics(x, u):
    """Xdot of the paper's eq. (17) (psi ENU, counter-clockwise from East); casadi or numbers."""
    phi, theta, psi = x[3], x[4], x[5]
    V, up, uq = u[0], u[1], u[2]
    ct = ca.cos(theta)
    return ca.vertcat(V * ca.cos(psi) * ct, V * ca.sin(psi) * ct, V * ca.sin(theta),
                      up + uq * ca.sin(phi) * ca.tan(theta), uq * ca.cos(phi), -(G / V) * ca.tan(phi) * ct)


def _discrete_step(x, u, dt: float, integrator: str, dynamics=continuous_dynamics):
    """X_{k+1} from X_k under U_k held for dt: Euler forward (the paper's) or RK4; on casadi symbols
    (``continuous_dynamics``) or on numbers (``_np_dyn``, the same model in numpy)."""
    if integrator == "euler":
        return x + dt * dynamics(x, u)
    k1 = dynamics(x, u)
    k2 = dynamics(x + 0.5 * dt * k1, u)
    k3 = dynamics(x + 0.5 * dt * k2, u)
    k4 = dynamics(x + dt * k3, u)
    return x + dt / 6.0 * (k1 + 2 * k2 + 2 * k3 + k4)


class _Problem:
    """The stage-structured NLP in CasADi SX, and the functions the solvers need."""

    def __init__(self, cfg: NmpcConfig):
        self.cfg = cfg
        N = cfg.horizon_steps
        self.N = N
        self.use_cbf = cfg.cbf.enabled
        self.nu = 4 if self.use_cbf else 3
        self.ng_stage = 2 if self.use_cbf else 0
        nu, ns = self.nu, NX + self.nu
        self.ns = ns
        self.nw = N * ns + NX
        # w is stage-major, [x_0, u_0, x_1, u_1, ..., x_N]: Nmpc._shifted and Nmpc._bounds move it by slices
        self.ix = np.array([k * ns + np.arange(NX) for k in range(N + 1)])
        self.iu = np.array([k * ns + NX + np.arange(nu) for k in range(N)])
        # parameters: target position (3), velocity (3), previous input [u_p, u_q] (2), f4 on/off (1)
        self.np_ = 9
        w = ca.SX.sym("w", self.nw)
        p = ca.SX.sym("p", self.np_)
        X = [w[self.ix[k]] for k in range(N + 1)]
        U = [w[self.iu[k]] for k in range(N)]
        r, c, lin, steps = self._stages(X, U, p)
        J = ca.sumsqr(r) + lin
        self.w, self.p, self.J, self.c = w, p, J, c
        self.nc = c.shape[0]
        self._constraint_bounds()
        self.eval_fun = self._outputs(X, U, p)
        self.r, self.lin_grad = r, ca.gradient(lin, w) if self.use_cbf else ca.DM.zeros(self.nw)
        self.steps, self.X = steps, X
        # Hessian blocks: stage k owns [x_k, u_k] (contiguous in w), the last block is x_N
        self.blocks = [np.concatenate([self.ix[k], self.iu[k]]) for k in range(N)] + [self.ix[N]]

    def _stages(self, X, U, p):
        """(residuals r with J = |r|^2 + lin, constraints c, the linear slack cost lin, the steps F(x_k, u_k))."""
        cfg, N, dt = self.cfg, self.N, self.cfg.step_s
        rq, vq, uprev, f4_on = p[0:3], p[3:6], p[6:8], p[8]
        sw1, sw2 = math.sqrt(cfg.w1_radius), math.sqrt(cfg.w2_altitude)
        sw3 = ca.DM([math.sqrt(v) for v in cfg.w3_attitude])
        sw4, swV, swr = math.sqrt(cfg.w4_continuity), math.sqrt(cfg.w_airspeed), math.sqrt(cfg.w_rates)
        sws = math.sqrt(cfg.cbf.slack_weight_quadratic)
        R, H = cfg.radius_m, cfg.altitude_m

        def dist(x, k):
            tq = rq + vq * (k * dt)
            return ca.sqrt((x[0] - tq[0]) ** 2 + (x[1] - tq[1]) ** 2 + _DIST_EPS2)

        def track(x, k):
            return [sw1 * (dist(x, k) - R), sw2 * (x[2] - H)]

        sw5, L5 = math.sqrt(cfg.w5_approach), cfg.approach_length_m

        res, cons, lin, steps = [], [], 0, []
        step_fun = ca.Function("F", [X[0], U[0]], [_discrete_step(X[0], U[0][0:3], dt, cfg.integrator)])
        for k in range(N):
            x, u = X[k], U[k]
            xn = step_fun(x, u)
            steps.append(xn)
            if k >= 1:
                res += track(x, k)
            res.append(sw3 * (xn[3:6] - x[3:6]))  # f3 through the step: stage-separable
            if sw5 > 0.0:  # the approach rate, also through the step
                dk = dist(x, k)
                res.append(sw5 * ((dist(xn, k + 1) - dk) / (dt * cfg.airspeed_ref_m_s) + ca.tanh((dk - R) / L5)))
            res.append(ca.vertcat(swV * (u[0] - cfg.airspeed_ref_m_s), swr * u[1], swr * u[2]))
            if k == 0:
                res.append(sw4 * f4_on * (u[1:3] - uprev))
            cons.append(X[k + 1] - xn)  # gap x_{k+1} - F(x_k, u_k) (Fatrop's form; HPIPM takes it too)
            if self.use_cbf:
                res.append(sws * u[3])
                lin = lin + cfg.cbf.slack_weight_linear * u[3]
                cons.append(cbf_rows(x, u, rq + vq * (k * dt), vq, cfg.cbf.beta, u[3]))
        res += track(X[N], N)
        return ca.vertcat(*res), ca.vertcat(*cons), lin, steps

    def _constraint_bounds(self) -> None:
        """Bounds of the constraints (the CBF rows' upper bounds are set per solve for sides = solve_time)."""
        N = self.N
        self.lbc = np.zeros(self.nc)
        self.ubc = np.zeros(self.nc)
        self.icbf = np.zeros((N, 2), dtype=int)
        if self.use_cbf:
            per = NX + 2
            for k in range(N):
                self.icbf[k] = k * per + NX + np.arange(2)
            self.lbc[self.icbf.ravel()] = -np.inf

    def _outputs(self, X, U, p) -> ca.Function:
        """(w, p) -> (cost, CBF rows without slack, h per stage), for the results."""
        cfg, N, dt = self.cfg, self.N, self.cfg.step_s
        rq, vq = p[0:3], p[3:6]
        rows, hmin = [], []
        for k in range(N + 1):
            tq = rq + vq * (k * dt)
            uk = U[min(k, N - 1)]
            hR, hL, _, _ = cbf_terms(X[k], uk, tq, vq)
            hmin.append(ca.fmin(hR, hL))
            if k < N and self.use_cbf:
                rows.append(cbf_rows(X[k], uk, tq, vq, cfg.cbf.beta, 0.0))
        rows = ca.vertcat(*rows) if rows else ca.DM.zeros(0, 1)
        return ca.Function("nmpc_eval", [self.w, p], [self.J, rows, ca.vertcat(*hmin)])

    def qp_function(self) -> ca.Function:
        """(w, p) -> (stage Hessian blocks (ns x ns N), terminal block (6 x 6), g, A, c) at w.

        ``hessian = gauss_newton``: 2 J_r^T J_r. ``hessian = exact``: the Hessian of the Lagrangian
        ``J + sum_k lambda_k^T (x_{k+1} - F(x_k, u_k))`` with the gap multipliers from the adjoint recursion
        at w (stationarity in x_1..x_N with the inequality multipliers taken as zero):
        ``lambda_{N-1} = -dJ/dx_N``, ``lambda_k = A_{k+1}^T lambda_{k+1} - dJ/dx_{k+1}``. (The QP plugin's
        own gap multipliers are not usable; adding its CBF and bound multipliers did not help.) The caller
        makes each block convex.
        """
        w, N = self.w, self.N
        if self.cfg.hessian == "gauss_newton":
            Jr = ca.jacobian(self.r, w)
            Hfull = 2.0 * ca.mtimes(Jr.T, Jr)
        else:
            gJ = ca.gradient(self.J, w)
            lam = [None] * N
            lam[N - 1] = -gJ[self.ix[N]]
            for k in range(N - 2, -1, -1):
                Ak = ca.jacobian(self.steps[k + 1], self.X[k + 1])
                lam[k] = ca.mtimes(Ak.T, lam[k + 1]) - gJ[self.ix[k + 1]]
            lam_sym = ca.SX.sym("lam", NX, N)
            L = self.J + sum(ca.dot(lam_sym[:, k], self.X[k + 1] - self.steps[k]) for k in range(N))
            Hfull = ca.hessian(L, w)[0]
            Hfull = ca.substitute(Hfull, ca.vec(lam_sym), ca.vec(ca.horzcat(*lam)))
        blk = [Hfull[[int(i) for i in b], [int(i) for i in b]] for b in self.blocks]
        # structurally independent groups of variables in a block (e.g. [x, y] | z | angles + inputs | slack):
        # the per-block convexification works on each group alone (smaller eigenproblems)
        self.stage_groups = _components(sum(np.array(ca.DM(b.sparsity(), 1)) for b in blk[:N]))
        self.term_groups = _components(np.array(ca.DM(blk[N].sparsity(), 1)))
        blk = [ca.densify(b) for b in blk]
        g = ca.gradient(self.J, w)
        A = ca.jacobian(self.c, w)
        return ca.Function("nmpc_qp", [w, self.p], [ca.horzcat(*blk[:N]), blk[N], g, A, self.c])

    def hessian_sparsity(self) -> ca.Sparsity:
        """Block-diagonal pattern of the QP Hessian: dense (ns x ns) per stage, (6 x 6) for x_N."""
        sp = [ca.Sparsity.dense(len(b), len(b)) for b in self.blocks]
        return ca.diagcat(*sp)

    def rollout(self, x0: np.ndarray, U: np.ndarray) -> np.ndarray:
        """States (N+1, 6) from x0 under the inputs U (N, >=3) with the model's discrete step."""
        X = np.empty((U.shape[0] + 1, NX))
        X[0] = x0
        for k in range(U.shape[0]):
            X[k + 1] = _np_step(X[k], U[k], self.cfg.step_s, self.cfg.integrator)
        return X


def _components(pattern: np.ndarray) -> list[np.ndarray]:
    """Connected components (index arrays) of the graph of a symmetric sparsity pattern."""
    n = pattern.shape[0]
    adj = (pattern != 0) | (pattern.T != 0)
    seen = np.zeros(n, dtype=bool)
    groups = []
    for i in range(n):
        if seen[i]:
            continue
        stack, comp = [i], []
        seen[i] = True
        while stack:
            j = stack.pop()
            comp.append(j)
            for k in np.nonzero(adj[j])[0]:
                if not seen[k]:
                    seen[k] = True
                    stack.append(int(k))
        groups.append(np.array(sorted(comp)))
    return groups


def _np_dyn(x, u):
    phi, theta, psi = x[3], x[4], x[5]
    V, up, uq = u[0], u[1], u[2]
    ct = math.cos(theta)
    return np.array([V * math.cos(psi) * ct, V * math.sin(psi) * ct, V * math.sin(theta),
                     up + uq * math.sin(phi) * math.tan(theta), uq * math.cos(phi), -(G / V) * math.tan(phi) * ct])


def _np_step(x, u, dt, integrator):
    """:func:`_discrete_step` on numbers."""
    return _discrete_step(x, u, dt, integrator, _np_dyn)


def state_from_measurements(meas: Measurements, pitch_from: str, psi_prev: float | None) -> np.ndarray:
    """x0 = [pos_enu (3), phi, theta, psi_enu] with psi_enu = pi/2 - psi_ned, on the 2 pi branch nearest
    ``psi_prev`` (the last call's psi; None: within [-pi, pi]); theta per ``NmpcConfig.pitch_from``."""
    phi, theta, psi_ned = map(float, meas.euler_ned_rad)
    if pitch_from == "flight_path":
        v = meas.vel_enu_m_s
        theta = math.atan2(float(v[2]), max(math.hypot(float(v[0]), float(v[1])), 1e-3))
    psi = 0.5 * math.pi - psi_ned
    psi = wrap_pi(psi) if psi_prev is None else psi_prev + wrap_pi(psi - psi_prev)
    return np.array([*map(float, meas.pos_enu_m), phi, theta, psi])


def predict_state(x0: np.ndarray, u: np.ndarray, dt: float, cfg: NmpcConfig) -> np.ndarray:
    """x0 (NMPC convention) carried dt ahead by the model under the input u ([V_U, u_p, u_q]): one step of the
    model's integrator (the solve-ahead's start, a fraction of ``step_s``)."""
    return _np_step(np.asarray(x0, dtype=float), np.asarray(u, dtype=float), dt, cfg.integrator)


class Nmpc:
    """The Phase 2 NMPC: ``solve`` at 10 Hz, ``command`` to turn a result into a RateCommand."""

    def __init__(self, cfg: NmpcConfig | None = None):
        self.cfg = cfg = cfg if cfg is not None else NmpcConfig()
        if cfg.airspeed_min_m_s >= cfg.airspeed_max_m_s:
            raise ValueError("airspeed_min_m_s must be below airspeed_max_m_s")
        self._is_rti = cfg.solver.startswith("rti_")
        self.problem = pb = _Problem(cfg)
        self._build_solver()
        self._init_bounds()
        self._eval = Buffered(pb.eval_fun)
        self.fallback_count = 0
        self.reset()

    def _build_solver(self) -> None:
        """The QP solver of the real-time iterations, or the NLP solver."""
        cfg, pb = self.cfg, self.problem
        N = pb.N
        if self._is_rti:
            qp_fun = pb.qp_function()
            self._qp_fun = Buffered(qp_fun)
            self._h_sp = pb.hessian_sparsity()
            # _HESS_REG on the diagonal entries of the block-diagonal pattern (column-major within blocks)
            self._h_reg = np.concatenate([(_HESS_REG * np.eye(len(b))).reshape(-1) for b in pb.blocks])
            self._hessian_maps()
            qp_sp = {"h": self._h_sp, "a": qp_fun.sparsity_out(3)}
            if cfg.solver == "rti_hpipm":
                opts = {"N": N, "nx": [NX] * (N + 1), "nu": [pb.nu] * N + [0],
                        "ng": [pb.ng_stage] * N + [0], "error_on_fail": False,
                        "inf": 1e5,
                        "hpipm": {"mode": "speed_abs", "iter_max": 50, "res_g_max": 1e-8, "res_b_max": 1e-8,
                                  "res_d_max": 1e-8, "res_m_max": 1e-8}}
                qp = ca.conic("nmpc_qp_solver", "hpipm", qp_sp, opts)
            else:
                opts = {"error_on_fail": False, "print_iter": False, "print_header": False,
                        "print_info": False, "max_iter": 1000}
                qp = ca.conic("nmpc_qp_solver", "qrqp", qp_sp, opts)
            self._qp = Buffered(qp, rebind=True)
        else:
            nlp = {"x": pb.w, "p": pb.p, "f": pb.J, "g": pb.c}
            if cfg.solver == "ipopt":
                opts = {"expand": True, "print_time": False, "error_on_fail": False,
                        "ipopt": {"print_level": 0, "tol": cfg.ipopt_tol, "sb": "yes", "max_iter": 500}}
            else:
                opts = {"expand": True, "print_time": False, "error_on_fail": False,
                        "structure_detection": "auto", "equality": [bool(e) for e in pb.lbc == pb.ubc],
                        "fatrop": {"print_level": 0, "tol": 1e-6, "max_iter": 200}}
            self._nlp = ca.nlpsol("nmpc_nlp", cfg.solver, nlp, opts)

    def _init_bounds(self) -> None:
        """Bounds of w (x0 filled per solve) and of the inputs."""
        cfg, pb = self.cfg, self.problem
        self._lbw = np.full(pb.nw, -np.inf)
        self._ubw = np.full(pb.nw, np.inf)
        ulo = [cfg.airspeed_min_m_s, -cfg.roll_rate_max_rad_s, -cfg.pitch_rate_max_rad_s]
        uhi = [cfg.airspeed_max_m_s, cfg.roll_rate_max_rad_s, cfg.pitch_rate_max_rad_s]
        if pb.use_cbf:
            ulo.append(0.0)
            uhi.append(np.inf)
        for k in range(pb.N):
            self._lbw[pb.iu[k]] = ulo
            self._ubw[pb.iu[k]] = uhi
        self._phi_max = math.radians(cfg.roll_max_deg)
        self._theta_max = math.radians(cfg.pitch_max_deg)
        self._u_lo, self._u_hi = np.array(ulo), np.array(uhi)
        # the attitude bounds of X_1..X_N: (state index, limit, what the funnel's rate reaches by each stage,
        # the bounds' positions in w)
        t = np.arange(1, pb.N + 1) * cfg.step_s
        self._funnels = tuple((j, lim, _FUNNEL * rate * t, pb.ix[1:, j].copy())
                              for j, lim, rate in ((3, self._phi_max, cfg.roll_rate_max_rad_s),
                                                   (4, self._theta_max,
                                                    cfg.pitch_rate_max_rad_s * math.cos(self._phi_max))))

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the warm start, the previous input and the psi unwrapping."""
        self._w = None  # warm start (internal psi frame)
        self._t_prev = None
        self._plan = None  # (t_s, U (N, 3)) of the last successful solve, for fallbacks
        self._u_applied = None  # [u_p, u_q] of the last returned input (f4)
        self._psi_meas = None  # unwrapping of state_from_measurements
        self._failures = 0

    def state_from_measurements(self, meas: Measurements) -> np.ndarray:
        """x0 = [pos_enu (3), phi, theta, psi_enu] with psi_enu = pi/2 - psi_ned, unwrapped across calls."""
        x0 = state_from_measurements(meas, self.cfg.pitch_from, self._psi_meas)
        self._psi_meas = float(x0[5])
        return x0

    @staticmethod
    def command_input(cmd: RateCommand) -> np.ndarray:
        """[V_U, u_p, u_q] of a rate command (the inverse of :meth:`command`)."""
        return np.array([cmd.airspeed_m_s, cmd.roll_rate_rad_s, cmd.pitch_rate_rad_s])

    @staticmethod
    def command(result: NmpcResult) -> RateCommand:
        """The autopilot's rate command (mode a) for a result."""
        return RateCommand(result.t_s, float(result.u0[0]), float(result.u0[1]), float(result.u0[2]))

    # ------------------------------------------------------------------ internals
    def _initial_guess(self, x0: np.ndarray) -> np.ndarray:
        pb = self.problem
        U = np.zeros((pb.N, pb.nu))
        U[:, 0] = min(max(self.cfg.airspeed_ref_m_s, self.cfg.airspeed_min_m_s), self.cfg.airspeed_max_m_s)
        # roll to wings level over the first second, then hold
        phi = x0[3]
        k_roll = max(1, int(round(1.0 / self.cfg.step_s)))
        U[:k_roll, 1] = np.clip(-phi / (k_roll * self.cfg.step_s), -self.cfg.roll_rate_max_rad_s,
                                self.cfg.roll_rate_max_rad_s)
        X = pb.rollout(x0, U)
        return self._pack(X, U)

    def _pack(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        pb = self.problem
        w = np.empty(pb.nw)
        w[pb.ix.ravel()] = X.ravel()
        w[pb.iu.ravel()] = U.ravel()
        return w

    def _shifted(self, w: np.ndarray, m: int) -> np.ndarray:
        """The plan w moved on by m steps: stages m..N become 0..N-m (w is stage-major, [x_k, u_k] per
        stage, so that is one slice), the last input held and the states after it rolled out."""
        pb = self.problem
        if m <= 0:
            return w.copy()
        N, ns = pb.N, pb.ns
        ws = np.empty_like(w)
        ws[: (N - m) * ns + NX] = w[m * ns:]
        u_last = w[(N - 1) * ns + NX: N * ns]
        for k in range(N - m, N):
            ws[k * ns + NX: (k + 1) * ns] = u_last
            ws[(k + 1) * ns: (k + 1) * ns + NX] = _np_step(ws[k * ns: k * ns + NX], u_last, self.cfg.step_s,
                                                           self.cfg.integrator)
        return ws

    def _bounds(self, x0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        lbw, ubw = self._lbw.copy(), self._ubw.copy()
        lbw[:NX] = x0  # x_0 leads w
        ubw[:NX] = x0
        for j, lim, reach, idx in self._funnels:
            ubw[idx] = np.maximum(lim, x0[j] - reach)
            lbw[idx] = np.minimum(-lim, x0[j] + reach)
        return lbw, ubw

    def _cbf_bounds(self, x0: np.ndarray, target_pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pb = self.problem
        ubc = pb.ubc
        if pb.use_cbf and self.cfg.cbf.sides == "solve_time":
            ubc = ubc.copy()
            psi = x0[5]
            Rp = (target_pos[0] - x0[0]) * math.sin(psi) - (target_pos[1] - x0[1]) * math.cos(psi)
            drop = pb.icbf[:, 1] if Rp >= 0.0 else pb.icbf[:, 0]  # keep the target's side only
            ubc[drop] = np.inf
        return pb.lbc, ubc

    def _hessian_maps(self) -> None:
        """Flat indices (into [Hs, HN] and the QP Hessian's nonzeros, the same layout) of each convexification
        group of every block: the singletons of all blocks together, and per multi-variable group its entries
        (batch, i, j) and their transposes (batch, j, i)."""
        pb = self.problem
        singles, groups = [], []
        for off, nb, n, grp in ((0, pb.N, pb.ns, pb.stage_groups), (pb.N * pb.ns * pb.ns, 1, NX, pb.term_groups)):
            base = off + n * n * np.arange(nb)[:, None, None]
            for g in grp:
                if len(g) == 1:
                    singles.append((base + g[0] * (n + 1)).ravel())
                else:
                    groups.append((base + g[:, None] * n + g[None, :], base + g[None, :] * n + g[:, None]))
        self._h_single = np.concatenate(singles) if singles else np.zeros(0, dtype=int)
        self._h_groups = groups
        self._h_conv = np.zeros(self._h_reg.size)  # entries outside the groups stay zero

    def _hessian(self, Hs: np.ndarray, HN: np.ndarray) -> np.ndarray:
        """Nonzeros of the QP Hessian from the blocks: symmetrised, eigenvalues floored per group (exact).

        The blocks come column-major (transposed); the symmetric part is taken on the groups' entries only,
        the rest of the Hessian being zero (plus the regularisation)."""
        raw = np.concatenate((Hs, HN))
        if self.cfg.hessian != "exact":
            return raw + self._h_reg
        floor = self.cfg.hessian_min_eig
        out = self._h_conv
        d = raw.take(self._h_single)
        out[self._h_single] = np.maximum(0.5 * (d + d), floor)
        for ia, ib in self._h_groups:
            lam, V = np.linalg.eigh(0.5 * (raw.take(ia) + raw.take(ib)))
            np.maximum(lam, floor, out=lam)
            out[ia] = (V * lam[:, None, :]) @ V.transpose(0, 2, 1)
        return out + self._h_reg

    def _rti(self, w, p, lbw, ubw, lbc, ubc, iters: int, converge: bool, deadline: float):
        """Up to ``iters`` full SQP steps, fewer if the next one would end after ``deadline``
        (perf_counter seconds) or, with ``converge``, once the largest input step is below
        ``cold_start_tol``; returns (w, n_iter, ok, why)."""
        pb = self.problem
        iu = pb.iu[:, :3].ravel() if converge else None
        n = 0
        for n in range(1, iters + 1):
            t_it = time.perf_counter()
            Hs, HN, g, A, c = self._qp_fun(w, p)
            h = self._hessian(Hs, HN)
            dw = self._qp(h, g, A, lbc - c, ubc - c, lbw - w, ubw - w)[0]
            st = self._qp.stats()
            if not st.get("success", False) or not np.isfinite(dw).all():
                return w, n, False, "qp:" + str(st.get("return_status", "failed"))
            w = w + dw
            if converge and np.max(np.abs(dw[iu])) < self.cfg.cold_start_tol:
                break
            now = time.perf_counter()
            if now + (now - t_it) > deadline:
                break
        return w, n, True, "ok"

    def _nlp_solve(self, w, p, lbw, ubw, lbc, ubc):
        kw = {"x0": w, "p": p, "lbx": lbw, "ubx": ubw, "lbg": lbc, "ubg": ubc}
        sol = self._nlp(**kw)
        st = self._nlp.stats()
        w_new = np.asarray(sol["x"]).ravel()
        ok = bool(st.get("success", False)) and np.isfinite(w_new).all()
        return w_new, int(st.get("iter_count", -1)), ok, "ok" if ok else "nlp:" + str(st.get("return_status"))

    # ------------------------------------------------------------------ solve
    def solve(self, t_s: float, x0, target_pos_enu, target_vel_enu, u_prev=None) -> NmpcResult:
        """One NMPC solve at time t_s from state x0 (NMPC convention) for the target's estimate.

        ``u_prev`` ([u_p, u_q], optional) overrides the previously applied input of f4
        (default: the u0 this object returned last; none on the first call, f4 then off).
        Never raises on a solver failure: see ``NmpcResult.fallback``.
        """
        t_start = time.perf_counter()
        cfg, pb = self.cfg, self.problem
        x0_in = np.asarray(x0, dtype=float).reshape(NX)
        q = np.asarray(target_pos_enu, dtype=float).reshape(3)
        v = np.asarray(target_vel_enu, dtype=float).reshape(3)
        w0, x0, psi_offset, cold = self._warm_start(t_s, x0_in)
        p = self._parameters(q, v, u_prev)
        lbw, ubw = self._bounds(x0)
        lbc, ubc = self._cbf_bounds(x0, q)
        try:
            if self._is_rti:
                # iterate within 90 % of the budget (always at least one QP)
                deadline = t_start + 0.9e-3 * cfg.max_solve_ms if cfg.budget == "wall_clock" else math.inf
                n_it = cfg.cold_start_iterations if cold else cfg.rti_iterations
                w, iters, ok, why = self._rti(w0, p, lbw, ubw, lbc, ubc, n_it, cold, deadline)
            else:
                w, iters, ok, why = self._nlp_solve(w0, p, lbw, ubw, lbc, ubc)
        except Exception as exc:  # noqa: BLE001 - a solver must never take the flight software down
            w, iters, ok, why = w0, 0, False, f"exception:{type(exc).__name__}"
        cost, min_h, cbf_active = self._keep(t_s, w, w0, p, ubc, ok)
        solve_ms = (time.perf_counter() - t_start) * 1e3
        late = cfg.budget == "wall_clock" and solve_ms > cfg.max_solve_ms
        X, U = w[pb.ix], w[pb.iu]
        if ok and not late:
            u0 = U[0, :3].clip(self._u_lo[:3], self._u_hi[:3])
            self._plan = (t_s, U[:, :3].copy())
            status, fallback = "ok", False
        else:
            status = "fallback:late" if ok else f"fallback:failed:{why}"
            fallback = True
            self.fallback_count += 1
            u0 = self._fallback_input(t_s)
            if not ok:
                U = np.tile(u0, (pb.N, 1))
                X = pb.rollout(x0, U)
        self._u_applied = u0[1:3].copy()
        predicted = X.copy()
        predicted[:, 5] += psi_offset
        return NmpcResult(t_s, u0, status, solve_ms, iters, fallback, cost, predicted, cbf_active, min_h,
                          U[:, :3].copy())

    def _warm_start(self, t_s: float, x0_in: np.ndarray):
        """(w0, x0, psi offset, cold): the previous plan shifted to this time (else the initial guess), and x0
        with psi on the warm start's 2 pi branch (the internal frame kept near [-pi, pi])."""
        pb = self.problem
        cold = True
        w0 = None
        if self._w is not None and self._t_prev is not None:
            m = int(round((t_s - self._t_prev) / self.cfg.step_s))
            if 0 <= m < pb.N:
                w0 = self._shifted(self._w, m)
                cold = False
        x0 = x0_in.copy()
        if w0 is not None:
            x0[5] = w0[pb.ix[0, 5]] + wrap_pi(x0[5] - w0[pb.ix[0, 5]])
        else:
            x0[5] = wrap_pi(x0[5])
        if abs(x0[5]) > _TWO_PI:
            turns = _TWO_PI * math.floor((x0[5] + math.pi) / _TWO_PI)
            x0[5] -= turns
            if w0 is not None:
                w0[pb.ix[:, 5]] -= turns
        psi_offset = x0_in[5] - x0[5]
        if w0 is None:
            w0 = self._initial_guess(x0)
        return w0, x0, psi_offset, cold

    def _parameters(self, q: np.ndarray, v: np.ndarray, u_prev) -> np.ndarray:
        """p = [target position, velocity, f4's previous input, f4 on/off]."""
        if u_prev is not None:
            up, f4_on = np.asarray(u_prev, dtype=float).reshape(2), 1.0
        elif self._u_applied is not None:
            up, f4_on = self._u_applied, 1.0
        else:
            up, f4_on = np.zeros(2), 0.0
        return np.concatenate([q, v, up, [f4_on]])

    def _keep(self, t_s: float, w, w0, p, ubc, ok: bool) -> tuple[float, float, bool]:
        """Keep a solved plan as the next warm start (a failed one: the shifted plan, or none after
        reset_after_failures); (cost, min h, CBF active) of the plan, NaN/False when it failed."""
        cfg, pb = self.cfg, self.problem
        if not ok:
            self._failures += 1
            if self._failures >= cfg.reset_after_failures:
                self._w, self._t_prev = None, None  # next call rebuilds the warm start (cold)
            else:
                self._w, self._t_prev = w0, t_s  # keep the shifted plan as the warm start
            return math.nan, math.nan, False
        J, rows, hmin = self._eval(w, p)  # the evaluator's buffers: read here, not kept
        if pb.use_cbf and cfg.cbf.sides == "solve_time":
            rows = np.where(np.isfinite(ubc[pb.icbf.ravel()]), rows, -np.inf)
        self._w, self._t_prev = w, t_s
        self._failures = 0
        return float(J[0]), float(hmin.min()), bool(rows.size and rows.max() > -_CBF_ACTIVE_TOL)

    def plan_cost(self, x0, target_pos_enu, target_vel_enu, inputs, u_prev=None) -> float:
        """The NLP cost of an input sequence (N, >=3) flown from x0 on the model (the dynamics then hold exactly).

        CBF slacks are set to the smallest that makes the plan feasible, so plans from different solvers are
        compared on the same, honest footing. ``u_prev``: f4's previous input (None: f4 off).
        """
        pb = self.problem
        U = np.zeros((pb.N, pb.nu))
        U[:, :3] = np.asarray(inputs, dtype=float)[:, :3]
        X = pb.rollout(np.asarray(x0, dtype=float), U)
        f4 = np.zeros(2) if u_prev is None else np.asarray(u_prev, dtype=float)
        p = np.concatenate([np.asarray(target_pos_enu, float), np.asarray(target_vel_enu, float), f4,
                            [0.0 if u_prev is None else 1.0]])
        w = self._pack(X, U)
        if pb.use_cbf:
            rows = self._eval(w, p)[1].reshape(pb.N, 2)
            U[:, 3] = np.maximum(rows.max(axis=1), 0.0)
            w = self._pack(X, U)
        return float(self._eval(w, p)[0][0])

    def _fallback_input(self, t_s: float) -> np.ndarray:
        if self._plan is not None:
            t0, U = self._plan
            m = int(round((t_s - t0) / self.cfg.step_s))
            if 0 <= m:
                return U[min(m, U.shape[0] - 1)].copy()
        return np.array([self.cfg.airspeed_ref_m_s, 0.0, 0.0])


@dataclass(frozen=True, slots=True)
class KinematicRun:
    """A closed loop of the NMPC on its own model (see ``kinematic_closed_loop``)."""

    t_s: np.ndarray  # (K,) solve times
    states: np.ndarray  # (K, 6) plant state at each solve
    target: np.ndarray  # (K, 3) target position at each solve
    inputs: np.ndarray  # (K, 3) applied inputs
    radius_err_m: np.ndarray  # (K,) planar distance to the target minus R
    altitude_err_m: np.ndarray  # (K,) z - H
    h: np.ndarray  # (K,) realised CBF h (controllers.guidance.cbf.h_value) of the plant state
    min_h_pred: np.ndarray  # (K,) min h over each predicted horizon
    solve_ms: np.ndarray  # (K,) wall time of each solve (NmpcResult.solve_ms)
    cpu_ms: np.ndarray  # (K,) process CPU time of each solve call
    iterations: np.ndarray  # (K,)
    fallbacks: int
    results: list  # the NmpcResults

    def rms_after(self, t0_s: float) -> tuple[float, float]:
        """(radius RMS, altitude RMS) in m over t >= t0_s."""
        m = self.t_s >= t0_s
        return (float(np.sqrt(np.mean(self.radius_err_m[m] ** 2))),
                float(np.sqrt(np.mean(self.altitude_err_m[m] ** 2))))


def kinematic_closed_loop(nmpc: Nmpc, x0, target_pos0, target_vel, duration_s: float,
                          substeps: int = 10, keep_results: bool = False, observer=None) -> KinematicRun:
    """Fly the NMPC on its own continuous model (RK4, ``substeps`` per step, input held) as the plant.

    One solve per T_s; the target moves at constant velocity and its exact state is given to the NMPC
    (no estimator). ``observer(t_s, x, target_pos, target_vel, result, u_prev)`` is called after each
    solve (``u_prev``: the [u_p, u_q] applied before, None at the first step). For tuning, tests and
    tools/bench_nmpc.py; the JSBSim closed loop lives in the harness.
    """
    from controllers.guidance.cbf import h_value  # local: keeps the module's import surface small

    dt = nmpc.cfg.step_s
    K = int(round(duration_s / dt))
    x = np.asarray(x0, dtype=float).copy()
    q0 = np.asarray(target_pos0, dtype=float)
    v = np.asarray(target_vel, dtype=float)
    rec = {k: [] for k in ("t", "x", "q", "u", "h", "mh", "ms", "cpu", "it")}
    results = []
    fb = 0
    u_prev = None
    for k in range(K):
        t = k * dt
        q = q0 + v * t
        c0 = time.process_time()
        r = nmpc.solve(t, x, q, v)
        rec["cpu"].append((time.process_time() - c0) * 1e3)
        if observer is not None:
            observer(t, x.copy(), q, v, r, u_prev)
        fb += int(r.fallback)
        rec["t"].append(t), rec["x"].append(x.copy()), rec["q"].append(q), rec["u"].append(r.u0.copy())
        rec["h"].append(h_value(x, q)), rec["mh"].append(r.min_h), rec["ms"].append(r.solve_ms)
        rec["it"].append(r.iterations)
        if keep_results:
            results.append(r)
        u_prev = r.u0[1:3].copy()
        for _ in range(substeps):
            x = _np_step(x, r.u0, dt / substeps, "rk4")
    X, Q = np.array(rec["x"]), np.array(rec["q"])
    d = np.hypot(X[:, 0] - Q[:, 0], X[:, 1] - Q[:, 1])
    cfg = nmpc.cfg
    return KinematicRun(np.array(rec["t"]), X, Q, np.array(rec["u"]), d - cfg.radius_m, X[:, 2] - cfg.altitude_m,
                        np.array(rec["h"]), np.array(rec["mh"]), np.array(rec["ms"]), np.array(rec["cpu"]),
                        np.array(rec["it"]), fb, results)
