"""Mission phases: a pure decision from the flight software's state of knowledge.

1. Acquisition: the initial path and the gimbal search, until the lock.
2. Loiter (``controllers.after_lock``: ``orbit``, ``nmpc`` or a user's loiter
   guidance) round the estimated target on its ring (R, H); ``path`` keeps the
   initial path (no Phase 2).
3. Terminal (``controllers.terminal``) once the switch condition holds
   (:class:`~controllers.config.SwitchConfig`): radius and altitude held within
   tolerances for ``dwell_s`` and at least ``min_loiter_s`` in Phase 2 (the two
   side by side), and the bearing from the UAV to the target within
   ``approach_window_deg`` of the approach bearing plus the lead. The
   approach bearing is the mission's impact heading (``switch.approach_from``),
   or the bearing the UAV closes on the target in at the end of the dive
   (:func:`approach_bearing_deg`: its ground velocity along the impact
   direction, at the dive's airspeed in the estimated wind, less the target's
   estimated velocity), by default only after a go-around.
   A dive that does not close goes round: once the range to the target
   estimate has grown ``go_around_m`` above its least since the switch, or
   ``go_around_stall_s`` after the switch it has not fallen
   ``go_around_stall_fraction`` below its value at the switch, the
   mission returns to Phase 2 (the loiter takes the UAV back to its ring) and
   the switch is armed again, its dwell and minimum loiter counted afresh.
   With ``switch.entry_depression_margin_deg`` (5° by default; the paper
   mission's file sets it to null, the paper's dive from H) the first
   time the loiter has settled on its ring at H (the switch condition but
   the window: :func:`settled_on_ring`) it descends on its ring to the
   dive's entry ring (:func:`entry_altitude_m`: the ship ``|theta_f|`` less
   the margin below the horizon), and the switch is armed there, its dwell
   counted afresh, to dive at the first approach window once settled there;
   a go-around keeps the entry ring.

:func:`next_phase` takes the previous :class:`PhaseState` and this tick's
inputs and returns the next state and why it changed; it keeps nothing of its
own, so it can be tested (and replayed) on any sequence of inputs.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from controllers.config import BpngConfig, SwitchConfig
from controllers.messages import TargetState

__all__ = ["PhaseState", "Ring", "approach_bearing_deg", "entry_altitude_m", "in_approach_window", "next_phase",
           "radial_error_m", "settled_on_ring", "window_bearing_deg"]


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
    closest_m: float = math.nan  # in Phase 3: the least range to the target estimate since the switch
    phase3_t_s: float = math.nan  # when Phase 3 started
    switch_m: float = math.nan  # in Phase 3: the range to the target estimate at its first tick
    go_arounds: int = 0  # dives that did not close and went back to the loiter
    descent_t_s: float = math.nan  # since when the loiter descends to the dive's entry ring (NaN: it does not)

    @property
    def descending(self) -> bool:
        """The loiter has left H for the dive's entry ring (``switch.entry_depression_margin_deg``)."""
        return not math.isnan(self.descent_t_s)


def radial_error_m(pos_enu_m, target: TargetState, radius_m: float) -> float:
    """Horizontal distance from the UAV to the target estimate minus R."""
    q = target.pos_enu_m
    return float(np.hypot(pos_enu_m[0] - q[0], pos_enu_m[1] - q[1])) - radius_m


def _wrap360(deg: float) -> float:
    b = float(deg) % 360.0
    return 0.0 if b >= 360.0 else b  # a tiny negative angle rounds to 360.0


def approach_bearing_deg(impact_heading_deg: float, impact_fpa_deg: float, airspeed_m_s: float,
                         wind_enu_m_s, target_vel_enu_m_s) -> float:
    """The bearing (deg, clockwise from North, in [0, 360)) along which the UAV closes on the target horizontally at the
    end of the dive.

    The UAV's ground velocity then points along the impact direction V_f (``impact_heading_deg``,
    ``impact_fpa_deg``) and its air velocity, ground velocity less the wind, has the dive's airspeed:
    ``|Vg V_f - wind| = airspeed``, the larger root. Relative to the target it moves along
    ``Vg V_f - V_target``; that vector's horizontal bearing is returned. A still target in still air gives
    the impact heading; a fast ship and a steep dive into a headwind can turn it by tens of degrees, or round
    (the UAV's ground speed along the ship's course below the ship's: it must come from ahead). The impact
    heading is returned where no ground speed meets the airspeed (a wind stronger than it) or the closing is
    nearly vertical (under 0.5 m/s horizontally: any bearing will do).
    """
    psi, th = math.radians(impact_heading_deg), math.radians(impact_fpa_deg)
    d = (math.cos(th) * math.sin(psi), math.cos(th) * math.cos(psi), math.sin(th))
    w = [float(x) for x in wind_enu_m_s]
    b = d[0] * w[0] + d[1] * w[1] + d[2] * w[2]
    disc = b * b - (w[0] ** 2 + w[1] ** 2 + w[2] ** 2) + airspeed_m_s ** 2
    vg = b + math.sqrt(disc) if disc >= 0.0 else -1.0
    if not vg > 0.0 or not all(math.isfinite(float(x)) for x in target_vel_enu_m_s[:2]):
        return _wrap360(impact_heading_deg)
    e = vg * d[0] - float(target_vel_enu_m_s[0])
    n = vg * d[1] - float(target_vel_enu_m_s[1])
    if math.hypot(e, n) < 0.5:
        return _wrap360(impact_heading_deg)
    return _wrap360(math.degrees(math.atan2(e, n)))


def window_bearing_deg(state: PhaseState, sw: SwitchConfig, bpng: BpngConfig, wind_enu_m_s,
                       target: TargetState) -> float:
    """The approach bearing the switch's window is centred on (before the lead) this tick: the impact heading,
    or the closing bearing (:func:`approach_bearing_deg`) as ``sw.approach_from`` asks (by default once a
    dive has gone round), in Phase 2 with a target estimate."""
    closing = sw.approach_from == "closing_after_go_around" and state.go_arounds > 0
    if not (closing and state.phase == 2 and target.known):
        return float(bpng.impact_heading_deg)
    return approach_bearing_deg(bpng.impact_heading_deg, bpng.impact_flight_path_deg, bpng.airspeed_m_s,
                                wind_enu_m_s, target.vel_enu_m_s)


def next_phase(state: PhaseState, t_s: float, pos_enu_m, vel_enu_m_s, height_m: float, target: TargetState,
               locked: bool, ring: Ring | None, switch: SwitchConfig, approach_deg: float,
               loiter_name: str = "", entry_altitude_m: float | None = None) -> tuple[PhaseState, tuple[str, ...]]:
    """The phase after this tick and the events that say why it changed (none: it did not).

    ``ring``: the loiter's (None: no Phase 2); ``approach_deg``: the approach window's centre before the lead
    (:func:`approach_bearing_deg`, or the mission's impact heading), clockwise from North.
    ``entry_altitude_m``: the dive's entry ring's altitude (:func:`entry_altitude_m`; None: the dive starts
    at H): the first time the loiter has settled on its ring at H it starts its descent there (an event
    says so), and from then on the switch is armed at that altitude.
    """
    events = []
    if state.phase == 1 and locked and ring is not None and target.known:
        state = PhaseState(2, t_s)
        events.append(f"phase 1 -> 2 at t = {t_s:.2f} s: target locked, loiter ({loiter_name})")
    if state.phase == 2:
        armed = ring if entry_altitude_m is None or not state.descending else Ring(ring.radius_m, entry_altitude_m)
        state, held = settled_on_ring(state, t_s, pos_enu_m, height_m, target, armed, switch)
        if held and entry_altitude_m is not None and not state.descending:
            # on the ring at H: descend to the entry ring now, whatever the bearing, so that the dive can take
            # the first approach window once there (waiting for a window at H first cost an orbit)
            state = replace(state, descent_t_s=t_s, in_tol_since_s=math.nan)
            events.append(f"phase 2 at t = {t_s:.2f} s: on the ring ({held}); the loiter descends from "
                          f"{ring.altitude_m:.0f} m to the dive's entry ring at {entry_altitude_m:.0f} m "
                          f"(switch.entry_depression_margin_deg) and the switch is armed there")
        elif held:
            why = in_approach_window(pos_enu_m, vel_enu_m_s, target, switch, approach_deg)
            if why:
                state = replace(state, phase=3, closest_m=math.nan, phase3_t_s=t_s, switch_m=math.nan)
                events.append(f"phase 2 -> 3 at t = {t_s:.2f} s: {held}; {why}")
    elif state.phase == 3 and (switch.go_around_m is not None or switch.go_around_stall_s is not None) \
            and target.known:
        d = np.asarray(target.pos_enu_m, float) - np.asarray(pos_enu_m, float)
        rng = math.sqrt(d.dot(d))  # np.linalg.norm's own sum for a vector
        why = ""
        if math.isnan(state.switch_m):
            state = replace(state, switch_m=rng)
        if not rng >= state.closest_m:  # the first tick of Phase 3 (NaN), or closer than ever
            state = replace(state, closest_m=rng)
        elif switch.go_around_m is not None and rng - state.closest_m > switch.go_around_m:
            why = f"range {rng:.0f} m, {rng - state.closest_m:.0f} m above its least since the switch"
        if (not why and switch.go_around_stall_s is not None and t_s - state.phase3_t_s >= switch.go_around_stall_s
                and state.closest_m > (1.0 - switch.go_around_stall_fraction) * state.switch_m):
            why = (f"range {rng:.0f} m {t_s - state.phase3_t_s:.0f} s after the switch, its least "
                   f"{state.closest_m:.0f} m against {state.switch_m:.0f} m at the switch")
        if why and ring is not None:
            events.append(f"phase 3 -> 2 at t = {t_s:.2f} s: the dive is not closing ({why}): going round, "
                          f"back to the loiter ({loiter_name}), the switch armed again")
            state = PhaseState(2, t_s, go_arounds=state.go_arounds + 1, descent_t_s=state.descent_t_s)
    return state, tuple(events)


def entry_altitude_m(ring: Ring | None, switch: SwitchConfig, impact_fpa_deg: float) -> float | None:
    """The dive's entry ring's altitude (``switch.entry_depression_margin_deg``): ``R tan(|theta_f| - margin)``,
    between ``entry_min_altitude_m`` and H; None when it is off, there is no ring, or the ring at H already
    lies within the altitude tolerance of it (no descent)."""
    if switch.entry_depression_margin_deg is None or ring is None:
        return None
    depression = max(abs(float(impact_fpa_deg)) - switch.entry_depression_margin_deg, 1.0)
    h = min(max(ring.radius_m * math.tan(math.radians(depression)), switch.entry_min_altitude_m), ring.altitude_m)
    return h if ring.altitude_m - h > switch.altitude_tol_m else None


def settled_on_ring(state: PhaseState, t_s: float, pos_enu_m, height_m: float, target: TargetState, ring: Ring,
                    sw: SwitchConfig) -> tuple[PhaseState, str]:
    """(state with the dwell's start updated, what holds or "" while it does not): the radius and the altitude
    within their tolerances for ``dwell_s``, and ``min_loiter_s`` since Phase 2 started (the two side by side:
    the dwell may start before the minimum loiter is up). The switch itself also waits for the approach window
    (:func:`in_approach_window`)."""
    if not sw.enabled:
        return state, ""
    radial = radial_error_m(pos_enu_m, target, ring.radius_m)
    alt_err = float(height_m) - ring.altitude_m
    if abs(radial) > sw.radius_tol_m or abs(alt_err) > sw.altitude_tol_m:
        if math.isnan(state.in_tol_since_s):
            return state, ""  # out of tolerance already (the state is immutable: no copy needed)
        return replace(state, in_tol_since_s=math.nan), ""
    if math.isnan(state.in_tol_since_s):
        state = replace(state, in_tol_since_s=t_s)
    if t_s - state.in_tol_since_s < sw.dwell_s or t_s - state.phase2_t_s < sw.min_loiter_s:
        return state, ""
    return state, (f"radius error {radial:+.1f} m (tol {sw.radius_tol_m:g}), altitude error {alt_err:+.1f} m "
                   f"(tol {sw.altitude_tol_m:g}) for {t_s - state.in_tol_since_s:.1f} s")


def in_approach_window(pos_enu_m, vel_enu_m_s, target: TargetState, sw: SwitchConfig, approach_deg: float) -> str:
    """Why the bearing from the UAV to the target lies in the switch's approach window (within
    ``approach_window_deg`` of ``approach_deg`` plus the lead, the lead taken in the direction the UAV goes round
    the target), or "" when it does not."""
    rel = target.pos_enu_m[:2] - pos_enu_m[:2]
    bearing = math.degrees(math.atan2(rel[0], rel[1]))  # clockwise from North
    off = (bearing - approach_deg + 180.0) % 360.0 - 180.0
    rel_vel = np.asarray(vel_enu_m_s, float)[:2] - target.vel_enu_m_s[:2]
    clockwise = float(rel[0] * rel_vel[1] - rel[1] * rel_vel[0]) > 0.0  # the bearing grows
    lead = sw.approach_lead_deg if clockwise else -sw.approach_lead_deg
    if sw.approach_window_deg is not None and abs(off - lead) > sw.approach_window_deg:
        return ""
    return (f"bearing to target {bearing % 360:.1f} deg, {off:+.1f} deg from the approach bearing "
            f"{approach_deg % 360:.1f} deg ({'clockwise' if clockwise else 'counter-clockwise'} round the target, "
            f"lead {lead:+g} deg)")
