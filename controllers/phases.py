"""Mission phases: a pure decision from the flight software's state of knowledge.

1. Acquisition: the initial path and the gimbal search, until the lock.
2. Loiter (``controllers.after_lock``: ``orbit``, ``nmpc`` or a user's loiter
   guidance) round the estimated target on its ring (R, H); ``path`` keeps the
   initial path (no Phase 2).
3. Terminal (``controllers.terminal``) once the switch condition holds
   (:class:`~controllers.config.SwitchConfig`): radius and altitude held within
   tolerances for ``dwell_s`` and at least ``min_loiter_s`` in Phase 2 (the two
   side by side), and the bearing from the UAV to the target within
   ``approach_window_deg`` of the mission's impact heading plus the lead.

:func:`next_phase` takes the previous :class:`PhaseState` and this tick's
inputs and returns the next state and why it changed; it keeps nothing of its
own, so it can be tested (and replayed) on any sequence of inputs.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from controllers.config import SwitchConfig
from controllers.messages import TargetState

__all__ = ["PhaseState", "Ring", "next_phase", "radial_error_m", "switch_reason"]


@dataclass(frozen=True, slots=True)
class Ring:
    """The loiter's circle round the target: radius R (horizontal) and altitude H (world z)."""

    radius_m: float
    altitude_m: float


@dataclass(frozen=True, slots=True)
class PhaseState:
    """The mission phase and the times the switch condition counts from."""

    phase: int = 1
    phase2_t_s: float = math.nan  # when Phase 2 started
    in_tol_since_s: float = math.nan  # since when radius and altitude are within tolerance (NaN: not now)


def radial_error_m(pos_enu_m, target: TargetState, radius_m: float) -> float:
    """Horizontal distance from the UAV to the target estimate minus R."""
    rel = pos_enu_m[:2] - target.pos_enu_m[:2]
    return float(np.hypot(rel[0], rel[1])) - radius_m


def next_phase(state: PhaseState, t_s: float, pos_enu_m, vel_enu_m_s, height_m: float, target: TargetState,
               locked: bool, ring: Ring | None, switch: SwitchConfig, impact_heading_deg: float,
               loiter_name: str = "") -> tuple[PhaseState, tuple[str, ...]]:
    """The phase after this tick and the events that say why it changed (none: it did not).

    ``ring``: the loiter's (None: no Phase 2); ``impact_heading_deg``: the mission's, clockwise from North.
    """
    events = []
    if state.phase == 1 and locked and ring is not None and target.known:
        state = PhaseState(2, t_s)
        events.append(f"phase 1 -> 2 at t = {t_s:.2f} s: target locked, loiter ({loiter_name})")
    if state.phase == 2:
        state, why = switch_reason(state, t_s, pos_enu_m, vel_enu_m_s, height_m, target, ring, switch,
                                   impact_heading_deg)
        if why:
            state = replace(state, phase=3)
            events.append(f"phase 2 -> 3 at t = {t_s:.2f} s: {why}")
    return state, tuple(events)


def switch_reason(state: PhaseState, t_s: float, pos_enu_m, vel_enu_m_s, height_m: float, target: TargetState,
                  ring: Ring, sw: SwitchConfig, impact_heading_deg: float) -> tuple[PhaseState, str]:
    """(state with the dwell's start updated, why Phase 3 starts now or "" while the condition does not hold)."""
    if not sw.enabled:
        return state, ""
    radial = radial_error_m(pos_enu_m, target, ring.radius_m)
    alt_err = float(height_m) - ring.altitude_m
    if abs(radial) > sw.radius_tol_m or abs(alt_err) > sw.altitude_tol_m:
        return replace(state, in_tol_since_s=math.nan), ""
    if math.isnan(state.in_tol_since_s):
        state = replace(state, in_tol_since_s=t_s)
    # the dwell and the minimum loiter run side by side (the dwell may start before min_loiter_s is up)
    if t_s - state.in_tol_since_s < sw.dwell_s or t_s - state.phase2_t_s < sw.min_loiter_s:
        return state, ""
    rel = target.pos_enu_m[:2] - pos_enu_m[:2]
    bearing = math.degrees(math.atan2(rel[0], rel[1]))  # clockwise from North
    off = (bearing - impact_heading_deg + 180.0) % 360.0 - 180.0
    rel_vel = np.asarray(vel_enu_m_s, float)[:2] - target.vel_enu_m_s[:2]
    clockwise = float(rel[0] * rel_vel[1] - rel[1] * rel_vel[0]) > 0.0  # the bearing grows
    lead = sw.approach_lead_deg if clockwise else -sw.approach_lead_deg
    if sw.approach_window_deg is not None and abs(off - lead) > sw.approach_window_deg:
        return state, ""
    return state, (f"radius error {radial:+.1f} m (tol {sw.radius_tol_m:g}), altitude error {alt_err:+.1f} m "
                   f"(tol {sw.altitude_tol_m:g}) for {t_s - state.in_tol_since_s:.1f} s; bearing to target "
                   f"{bearing % 360:.1f} deg, {off:+.1f} deg from the impact heading "
                   f"({'clockwise' if clockwise else 'counter-clockwise'} round the target, lead {lead:+g} deg)")
