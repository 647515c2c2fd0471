"""Self-occlusion control barrier function (paper "To prevent self-occlusion", eqs. (20)-(24)).

Geometry (docs/design/algorithms.md): the ship stays visible while it lies on the belly side of
the wing plane, i.e. the body-z (down) component of ``r_q/p = r_q - r_p`` is >= 0.

Conventions (the same as controllers/guidance/nmpc.py): world ENU; the NMPC state is
``x = [r_p (3, ENU m), phi, theta, psi]`` with phi, theta the aerospace roll and pitch and
**psi the ENU yaw, counter-clockwise from East** (``psi = pi/2 - psi_ned``). The paper's CBF
section writes psi clockwise from North; in our psi the same quantities read

    R_p = x_q/p sin(psi) - y_q/p cos(psi)      lateral offset, > 0 when the target is RIGHT
                                               of the UAV (= the paper's x cos psi - y sin psi
                                               with its clockwise-from-North psi)
    f_p = x_q/p cos(psi) + y_q/p sin(psi)      offset ahead of the UAV
    D   = -z_q/p                               depth of the target below the UAV (> 0)

Neglecting pitch (the paper's assumption for Phase 2), the body-z component is
``z_b = -R_p sin(phi) + D cos(phi) = rho sin(a_R - phi)`` with ``rho = hypot(R_p, D)`` and the
depression angle of the target seen from the right wing ``a_R = atan2(D, R_p)`` (= the paper's
``atan(-z_q/p / R_p)`` for R_p > 0). Hence, for D > 0 and |phi| < pi/2:

    h_R = atan2(D,  R_p) - phi      (paper eq. (21), target on the right)
    h_L = atan2(D, -R_p) + phi      (mirrored, target on the left; h_R + h_L = pi)
    z_b >= 0   <=>   h_R >= 0 and h_L >= 0,       z_b = rho sin(h_R) = rho sin(h_L).

``h_value = min(h_R, h_L)`` is the angle of the target below the wing plane, measured in the
body y-z plane. The atan2 form is smooth across R_p = 0 (the paper's atan(-z/R_p) jumps there).

CBF condition ``h_dot >= -beta h`` with ``phi_dot = u_p + u_q sin(phi) tan(theta)`` (eq. (16)):

    right:   u_p <= beta h_R + alpha_R - u_q sin(phi) tan(theta)          (eq. (23))
    left:    u_p >= -beta h_L - alpha_L - u_q sin(phi) tan(theta)         (eq. (24))

where alpha_R = d/dt atan2(D, R_p) along the predicted motion (UAV kinematics of eq.
dynamics and a constant-velocity target) and alpha_L = -alpha_R. With
``psi_dot = -(g/V) tan(phi) cos(theta)``:

    R_p_dot = v_qx sin(psi) - v_qy cos(psi) + psi_dot f_p     (the UAV's own velocity cancels)
    D_dot   = V sin(theta) - v_qz
    alpha_R = (R_p D_dot - D R_p_dot) / (R_p^2 + D^2)

The left constraint written in the paper's form (h = atan(-z/R_p) - phi < 0 for R_p < 0) is
the same inequality: atan(-z/R_p) = a_R - pi there, so beta (a_R - pi - phi) + alpha_R is our
``-beta h_L - alpha_L``.

Side selection (``CbfConfig.sides``):
  * ``"both"`` (default): both rows at every stage. On the target's side this is exactly the
    paper's constraint; the other side's h is pi minus it (>= 90 deg - |phi| >= 55 deg for the
    default 35 deg bank limit), so its row is loose and only binds when it should (it encodes
    the same z_b >= 0 condition seen from the other wing). No switch, nothing discontinuous, and
    a horizon that carries the target across the nose is handled at every stage.
  * ``"solve_time"``: the paper's literal choice, the side of the sign of R_p at the current
    state, kept for the whole horizon (the other row is dropped).

Each stage's pair of rows shares one slack ``sigma >= 0`` (a control of the NMPC, penalised
linearly and quadratically), so a state that already violates the condition (e.g. at a phase
switch) never makes the problem infeasible; the penalty is an exact one in practice (sigma is
zero whenever the hard constraint is feasible).
"""
from __future__ import annotations

import math

import casadi as ca
import numpy as np

from controllers.config import CbfConfig

__all__ = ["CbfConfig", "G", "cbf_terms", "cbf_rows", "h_sides", "h_value", "alpha_right", "lateral_offset",
           "body_z_component"]

G = 9.80665
_EPS2 = 1e-6  # m^2, keeps alpha finite when the target is level with the UAV and dead ahead


# --------------------------------------------------------------------------- symbolic (casadi)


def cbf_terms(x, u, target_pos, target_vel):
    """(h_R, h_L, alpha_R, phi_dot) as casadi expressions of the state, input and target.

    ``x = [px, py, pz, phi, theta, psi]`` (ENU, psi counter-clockwise from East),
    ``u = [V, u_p, u_q, ...]``; works on SX/MX symbols and on numbers.
    """
    phi, theta, psi = x[3], x[4], x[5]
    V, up, uq = u[0], u[1], u[2]
    rx, ry, rz = target_pos[0] - x[0], target_pos[1] - x[1], target_pos[2] - x[2]
    s, c = ca.sin(psi), ca.cos(psi)
    Rp = rx * s - ry * c
    fp = rx * c + ry * s
    D = -rz
    psi_dot = -(G / V) * ca.tan(phi) * ca.cos(theta)
    Rp_dot = target_vel[0] * s - target_vel[1] * c + psi_dot * fp
    D_dot = V * ca.sin(theta) - target_vel[2]
    alpha_R = (Rp * D_dot - D * Rp_dot) / (Rp * Rp + D * D + _EPS2)
    h_R = ca.atan2(D, Rp) - phi
    h_L = ca.atan2(D, -Rp) + phi
    phi_dot = up + uq * ca.sin(phi) * ca.tan(theta)
    return h_R, h_L, alpha_R, phi_dot


def cbf_rows(x, u, target_pos, target_vel, beta: float, slack=0.0):
    """The two CBF rows, each ``<= 0`` when satisfied: [right (eq. (23)), left (eq. (24))].

    right: ``phi_dot - beta h_R - alpha_R - slack``; left: ``-phi_dot - beta h_L + alpha_R - slack``
    (alpha_L = -alpha_R), with ``phi_dot = u_p + u_q sin(phi) tan(theta)``.
    """
    h_R, h_L, alpha_R, phi_dot = cbf_terms(x, u, target_pos, target_vel)
    return ca.vertcat(phi_dot - beta * h_R - alpha_R - slack, -phi_dot - beta * h_L + alpha_R - slack)


# --------------------------------------------------------------------------- numeric (numpy)


def lateral_offset(x, target_pos) -> float:
    """R_p (m): the target's offset to the RIGHT of the UAV's heading (psi ENU, counter-clockwise from East)."""
    psi = float(x[5])
    return float((target_pos[0] - x[0]) * math.sin(psi) - (target_pos[1] - x[1]) * math.cos(psi))


def h_sides(x, target_pos) -> tuple[float, float]:
    """(h_R, h_L) in rad for a state ``x`` (NMPC convention) and a target position (ENU)."""
    Rp = lateral_offset(x, target_pos)
    D = float(x[2] - target_pos[2])
    phi = float(x[3])
    return math.atan2(D, Rp) - phi, math.atan2(D, -Rp) + phi


def h_value(x, target_pos) -> float:
    """min(h_R, h_L) (rad): the target's angle below the wing plane; >= 0 iff it is on the belly side."""
    hr, hl = h_sides(x, target_pos)
    return min(hr, hl)


def alpha_right(x, u, target_pos, target_vel) -> float:
    """alpha_R = d/dt atan2(D, R_p) (rad/s) along the kinematics of eq. (17) and a constant-velocity target."""
    return float(cbf_terms(np.asarray(x, float), np.asarray(u, float), np.asarray(target_pos, float),
                           np.asarray(target_vel, float))[2])


def body_z_component(x, target_pos) -> float:
    """z_b = -R_p sin(phi) + D cos(phi) (m): body-z (down) component of r_q/p at zero pitch."""
    Rp = lateral_offset(x, target_pos)
    D = float(x[2] - target_pos[2])
    return -Rp * math.sin(float(x[3])) + D * math.cos(float(x[3]))
