"""Guidance blocks: the built-in laws of each phase behind one small interface.

Every guidance block has ``step(nav, target) -> Guidance``: the navigation
solution (``Measurements`` with the flight software's own position) and the
target state (``TargetState``) in, the autopilot command and its set-points
out. A loiter block also says where its ring is (``radius_m``, ``altitude_m``)
for the phase switch. The built-ins:

* Phase 1, :class:`PathGuidance`: the initial path (``controllers.guidance.path``);
* Phase 2 (``controllers.after_lock``), :class:`OrbitLoiter` (a circle
  follower) and :class:`NmpcLoiter` (the paper's NMPC with the CBF,
  ``controllers.guidance.nmpc``, solved at ``nmpc.step_s`` and held between solves);
* Phase 3 (``controllers.terminal``), :class:`BpngTerminal`: the paper's
  quaternion BPNG (``controllers.guidance.bpng``), steering to where the approach meets
  the ship's outline.

A user's class takes their place from the scenario (``controllers.blocks``).
Each block writes its own log (``/fsw/nmpc``, ``/fsw/bpng``) through the
recorder it is given.

Nothing here imports the truth side of the harness (docs/design/architecture.md, "Two rules").
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from controllers.guidance.bpng import Bpng
from controllers.guidance.path import OrbitFollower, PathFollower
from controllers.messages import Guidance, TargetState
from fwsim.interface import topics
from fwsim.interface.messages import Measurements

if TYPE_CHECKING:  # the perception's ship model, handed in by the mission
    from controllers.perception.target_model import ShipModel

__all__ = ["PathGuidance", "OrbitLoiter", "NmpcLoiter", "BpngTerminal"]


class PathGuidance:
    """Phase 1: straight lines from the start through the waypoints (``initial_path``)."""

    def __init__(self, path_cfg, initial_cfg):
        self.follower = PathFollower(path_cfg.airspeed_m_s, initial_cfg.pos_enu_m,
                                     math.radians(initial_cfg.heading_deg), path_cfg.waypoints_enu_m,
                                     path_cfg.max_bank_deg)

    def step(self, nav: Measurements, target: TargetState) -> Guidance:
        cmd, st = self.follower.step(nav)
        return Guidance(cmd, "path", st.course_sp_rad, st.bank_sp_rad, st.altitude_sp_m, st.cross_track_m)


class OrbitLoiter:
    """Phase 2: a circle of radius R at altitude H round the target estimate (``orbit``)."""

    def __init__(self, orbit_cfg, max_bank_deg: float):
        o = orbit_cfg
        self.follower = OrbitFollower(o.airspeed_m_s, o.radius_m, o.altitude_m, o.clockwise, max_bank_deg)
        self.radius_m, self.altitude_m = o.radius_m, o.altitude_m
        self.altitude_offset_m = 0.0  # flown this far below H (the dive's entry ring: controllers.phases.phases)

    def step(self, nav: Measurements, target: TargetState) -> Guidance:
        self.follower.altitude_m = self.altitude_m - self.altitude_offset_m
        cmd, chi_c, _ = self.follower.step(nav, target.pos_enu_m)
        return Guidance(cmd, "loiter:orbit", course_sp_rad=chi_c, altitude_sp_m=self.follower.altitude_m)


class NmpcLoiter:
    """Phase 2: the paper's NMPC with the CBF round the target estimate (``nmpc``).

    It solves every ``step_s`` (the first time at its first step) and holds the command between solves;
    each solve goes to ``/fsw/nmpc`` and a fallback to the events. With ``nmpc.solve_ahead_s`` every solve
    after a loiter's first starts that long before its time (at the first tick within it), from the state
    carried to that time by the model under the command held and the target carried by its estimated
    velocity, and is applied at that time: a mission computer's compute delay, in which the solve can run
    in a process of its own while the loop goes on (``controllers.guidance.nmpc_worker``; where it runs never
    changes its numbers).
    """

    def __init__(self, nmpc_cfg, recorder):
        from controllers.guidance.nmpc import Nmpc, NmpcStatus, predict_state, state_from_measurements  # CasADi: loaded
        from controllers.guidance.nmpc_worker import make_solver  # only when the NMPC flies

        self._status = NmpcStatus.from_result
        self._from_meas, self._predict = state_from_measurements, predict_state
        self._command, self._command_input = Nmpc.command, Nmpc.command_input
        self.cfg = nmpc_cfg
        self.solver = make_solver(nmpc_cfg)
        self.radius_m, self.altitude_m = nmpc_cfg.radius_m, nmpc_cfg.altitude_m
        self._record = recorder
        self._cmd = None
        self._next_t = -math.inf
        self._psi = None  # the last state's psi (its unwrapping)
        self._ahead = float(nmpc_cfg.solve_ahead_s)
        self._pending = None  # the time of a solve submitted ahead
        # flown this far below H (the dive's entry ring: controllers.phases.phases): the solver is given the UAV and
        # the target both raised by it, so that it holds its ring at H with every relative quantity (the
        # radius, the barrier's geometry) as flown; the model knows no absolute height but H
        self.altitude_offset_m = 0.0

    def step(self, nav: Measurements, target: TargetState) -> Guidance:
        t = nav.t_s
        if self._pending is not None and t + 1e-9 >= self._pending:
            res = self.solver.result()
            if t - self._pending < self.cfg.step_s:  # else the loiter was left meanwhile: a stale plan
                self._take(*res)
            self._pending = None
        if t + 1e-9 >= self._next_t:  # (a solve ahead is for _next_t: it was taken or dropped above)
            self.solver.submit(t, self._state(nav), self._raised(target.pos_enu_m),
                               self._target_velocity(nav, target))
            self._take(*self.solver.result())
        elif self._pending is None and self._ahead > 0.0 and t + self._ahead + 1e-9 >= self._next_t:
            self._solve_ahead(nav, target, self._next_t)
        c = self._cmd
        cmd = type(c)(t, c.airspeed_m_s, c.roll_rate_rad_s, c.pitch_rate_rad_s)
        return Guidance(cmd, "loiter:nmpc", altitude_sp_m=self.altitude_m - self.altitude_offset_m)

    def close(self) -> None:
        """Stop the solver's worker (if it has one)."""
        self.solver.close()

    def _state(self, nav: Measurements) -> np.ndarray:
        x0 = self._from_meas(nav, self.cfg.pitch_from, self._psi)
        self._psi = float(x0[5])
        if self.altitude_offset_m:
            x0[2] += self.altitude_offset_m
        return x0

    def _raised(self, pos_enu_m: np.ndarray) -> np.ndarray:
        """The target's position as the solver is given it (raised by ``altitude_offset_m``)."""
        if not self.altitude_offset_m:
            return pos_enu_m
        p = np.array(pos_enu_m, dtype=float)
        p[2] += self.altitude_offset_m
        return p

    def _target_velocity(self, nav: Measurements, target: TargetState) -> np.ndarray:
        v_q = target.vel_enu_m_s
        if self.cfg.air_relative and np.isfinite(nav.wind_enu_m_s).all():
            v_q = v_q - nav.wind_enu_m_s  # the model flies in the air: the target drifts by minus the wind
        return v_q

    def _solve_ahead(self, nav: Measurements, target: TargetState, t_solve: float) -> None:
        """Submit the solve for t_solve: the state carried there by the model under the command now held,
        the target by its estimated velocity."""
        dt = t_solve - nav.t_s
        x0 = self._predict(self._state(nav), self._command_input(self._cmd), dt, self.cfg)
        self.solver.submit(t_solve, x0, self._raised(target.pos_enu_m + dt * target.vel_enu_m_s),
                           self._target_velocity(nav, target))
        self._pending = t_solve

    def _take(self, res, fallback_count: int) -> None:
        self._cmd = self._command(res)
        self._next_t = res.t_s + self.cfg.step_s
        self._record.log(topics.FSW_NMPC, self._status(res, fallback_count))
        if res.fallback:
            self._record.event(f"NMPC fallback at t = {res.t_s:.2f} s: {res.status}")


class BpngTerminal:
    """Phase 3: the paper's quaternion BPNG to the impact angles (``bpng``).

    The target's waterline point is steered to, raised by ``aim_height_m``; with ``aim_at_contact`` the
    steering point is pulled back along the relative impact direction to where the approach first meets the
    ship's outline (the ship model's, over the headings it may have), ``contact_standoff_m`` farther out.
    """

    def __init__(self, bpng_cfg, ship: ShipModel, recorder):
        self.cfg = bpng_cfg
        self.law = Bpng(bpng_cfg)
        self.ship = ship
        self._record = recorder

    def step(self, nav: Measurements, target: TargetState) -> Guidance:
        pos = target.pos_enu_m.copy()
        pos[2] = 0.0  # the estimate's plane height is a camera-model detail; BPNG adds its aim height
        vel, vel_at_impact = self.ship_velocity(nav, pos, target)
        cmd, status = self.law.step(nav.t_s, nav.pos_enu_m, nav.vel_enu_m_s, pos, vel,
                                    self.contact_aim(nav, pos, vel_at_impact))
        self._record.log(topics.FSW_BPNG, status)
        return Guidance(cmd, "terminal")

    @staticmethod
    def ship_velocity(nav: Measurements, pos: np.ndarray, target: TargetState) -> tuple[np.ndarray, np.ndarray]:
        """(the velocity the law extrapolates the ship with, the ship's velocity at impact).

        A ship that turns or changes speed (an estimator that estimates it, ``controllers.estimation.ct_ukf``, or a
        steady turn or a zigzag's periodic course found in the estimate's course,
        ``controllers.estimation.course_turn``: the turn rate now, held constant to the time to go) is
        predicted along its turn to the time to go (the law's ``t_go = |r| / |V_p|``), and the law is given
        the chord's velocity, ``(p(t_go) - p) / t_go``: its constant-velocity extrapolation then meets the ship
        where the turn takes it. Without a manoeuvre, the estimated velocity, for both."""
        vel = np.asarray(target.vel_enu_m_s, dtype=float)
        if target.turn_rate_rad_s == 0.0 and target.accel_along_m_s2 == 0.0:
            return vel, vel
        from controllers.ship_motion import predict_ctra
        t_go = max(float(np.linalg.norm(pos - nav.pos_enu_m)) / max(float(np.linalg.norm(nav.vel_enu_m_s)), 1.0),
                   0.1)
        p_f, v_f = predict_ctra(pos, vel, target.turn_rate_rad_s, target.accel_along_m_s2, t_go)
        chord = (p_f - pos) / t_go
        chord[2] = vel[2]
        return chord, v_f

    def contact_aim(self, nav: Measurements, target: np.ndarray, target_vel: np.ndarray) -> np.ndarray | None:
        """Where the approach through the aim point along the impact direction (relative to the moving ship)
        first meets the ship's outline, ``contact_standoff_m`` farther out; None: steer to the aim point.

        The ship's heading comes from the estimated course; when the course is unknown the deepest entry
        over the headings the box shapes allow (or, before they tell, ``headings_when_unknown`` headings) is
        taken (the steering point then lies in the air at worst, and the last metres are flown in the
        endgame, along V_f)."""
        b = self.cfg
        if not b.aim_at_contact:
            return None
        aim = self.law.aim_point(target)
        v = np.asarray(nav.vel_enu_m_s, dtype=float)
        speed = max(math.sqrt(v.dot(v)), 1.0)  # |v| (np.linalg.norm's own sum)
        d = speed * self.law.v_f_enu - np.asarray(target_vel, float)  # impact velocity relative to the ship
        d = d / max(math.sqrt(d.dot(d)), 1e-9)
        depth = self.ship.entry_depth_m(aim, target, d, target_vel)
        return aim - (depth + b.contact_standoff_m) * d
