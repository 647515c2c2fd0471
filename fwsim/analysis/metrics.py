"""Scores computed from a log (never from the objects of a live run).

Every metric is listed once in :data:`METRICS` (name, group, unit, which way is
better, a one-line definition): ``fwsim metrics`` prints them grouped in that
order, ``docs/guide/metrics.md`` is generated from it
(``python tools/gen_metrics_doc.py``), and ``fwsim compare`` takes the
better direction from it. A metric without a value for the run (the ship never
locked, the run never dived) is ``None`` (``null`` in JSON, ``—`` in tables).

Inner-loop tracking errors are RMS over every logged tick of the
``/autopilot/status`` topic (set-point minus what the loop saw).

Target estimation (``/fsw/estimate`` against ``/target/state``, truth
interpolated to the estimate's times): errors are horizontal (x, y), as in the
paper's figures; the filter estimates a point on the ship at its configured
height, the truth is the waterline centre. Convergence is defined from the
estimator's own reported uncertainty, not from truth: the first time after
which the estimate's horizontal position standard deviation (as logged:
for the UKFs the filter's covariance plus the box centre's systematic
error, ``controllers.estimation.ukf``) stays below ``CONVERGED_STD_M``. So that std is
checked against the truth too: ``estimator_pos_err_within_2std_fraction`` is the
share of estimates whose horizontal error is within twice that std. For an honest (consistent) filter it is about
86 % or more (1 - exp(-2) for a round two-dimensional Gaussian error; more when
one axis's std is the larger); well below, the filter is overconfident, and its
"convergence" comes too early.

Terminal phase: scored when the flight software reached Phase 3 (or, flying a
script with no phases, when the run ended at an impact); otherwise the terminal
metrics are ``None`` and ``terminal_note`` says why (the phase the run ended
in). ``miss_distance_m`` is the closest approach of the UAV's
centre of gravity to the ship's aim point (target.aim_point_ship_m: midships,
half-way up the hull, inside it), with the path continued straight along the
final velocity for ``MISS_EXTENSION_S`` past an impact: a run ends when the
UAV reaches the hull or the sea, and the miss distance should measure where
the guidance was taking it; ``miss_bow_m``, ``miss_port_m`` and ``miss_up_m``
are that closest approach's offset in the ship's frame (towards the bow, to
port, up). The ship's aim point comes from the logged ship states
(/target/state), so a ship moved by an event scores where it really was. ``hit`` is true when the run's last
state is inside the hull or superstructure. ``switch_time_s`` is the start of the last
Phase 3 (the dive that ended the run); ``go_arounds`` counts the dives before
it that did not close and went back to the loiter (``switch.go_around_m``,
``switch.go_around_stall_s``).

The ship after the lock (``/camera/frame``, the ray-cast truth of each
frame): ``target_in_fov_fraction_after_lock`` is the share of frames with
the ship in the field of view; ``target_visible_fraction_after_lock`` the
share in which it was also seen, some of its pixels not hidden by the UAV's
own airframe (a bank or a pull that lifts the wing over the line of sight
hides a ship that is in the field of view); ``target_hidden_longest_s_after_lock``
the longest stretch between frames that saw it.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fwsim.interface import topics
from fwsim.log import RunLog, read_log
from fwsim.log.truth import interp_at
from fwsim.scenario.yamlfile import short

CONVERGED_STD_M = 5.0
MISS_EXTENSION_S = 3.0  # path continued past the impact when scoring the miss distance
PIXEL_SETTLE_S = 5.0  # pixel errors are scored from lock + this (IBVS recentres the target after the lock)
#: loiter errors are scored from Phase 2 start + this, to the switch (or to the descent to the dive's entry ring)
LOITER_SETTLE_S = 60.0
TERMINAL_PHASE = 3

#: which way is better: a smaller value, a larger one, a value nearer zero (a signed error), or no way
BETTER = ("lower", "higher", "zero", "neither")


@dataclass(frozen=True)
class MetricSpec:
    """One metric: its name, group, unit ("" for text), which way is better (:data:`BETTER`), a one-line
    definition."""

    name: str
    group: str
    unit: str
    better: str
    description: str


def _specs(group: str, *rows: tuple[str, str, str, str]) -> tuple[MetricSpec, ...]:
    return tuple(MetricSpec(name, group, unit, better, text) for name, unit, better, text in rows)


_FUSION_REASONS = (
    ("used", "neither", "fused into the estimate"),
    ("initialised", "neither", "started (or restarted) the estimator"),
    ("acquiring", "neither", "before the lock: counted toward it"),
    ("not_initialised", "lower", "the estimator was down and this detection did not start it"),
    ("no_camera_pose", "lower", "no gimbal encoders: the ray was unknown"),
    ("too_close", "neither", "the ship was closer than detection_gate.min_range_m"),
    ("overflowing_box", "neither", "the box spanned the image: the ship was larger than the frame"),
    ("size_mismatch", "lower", "no heading of the ship model explained the box's size"),
    ("airframe_hidden", "lower", "course unknown and too much of the ship hidden by the airframe"),
    ("innovation_gate", "lower", "the estimator's chi-square test rejected it"),
    ("rejected", "lower", "the estimator could not use it (e.g. its ray missed the sea plane)"),
    ("estimator_reset", "lower", "the estimator diverged on it and reset itself"),
)

#: every metric, grouped, in the order ``fwsim metrics`` prints them
METRICS: tuple[MetricSpec, ...] = (
    *_specs("outcome",
            ("status", "", "neither", "how the run ended: completed, failed or interrupted"),
            ("end_reason", "", "neither", "why the run ended, e.g. `hit the ship at t = 176.88 s`, `duration reached`"),
            ("hit", "bool", "higher", "the UAV's last state is inside the ship's hull or superstructure"),
            ("flight_time_s", "s", "neither", "simulated time from the first to the last UAV state")),
    *_specs("terminal",
            ("terminal_note", "", "neither", "why the terminal metrics have no value (no terminal phase, or a dive "
                                             "that did not end at an impact); absent when they all have one"),
            ("impact_metrics", "", "neither", "set only when the log's scenario does not read with this fwsim "
                                              "version: why the miss, hit and angles are left out"),
            ("switch_time_s", "s", "neither", "start of the last Phase 3 (the dive that ended the run)"),
            ("go_arounds", "count", "lower", "dives before the last one that did not close and went back to "
                                              "the loiter"),
            ("impact_time_s", "s", "neither", "time of the impact (hull or sea contact) that ended the run"),
            ("miss_distance_m", "m", "lower", "closest approach of the UAV's centre of gravity to the ship's aim "
                                              "point, the path continued straight for 3 s past an impact"),
            ("miss_bow_m", "m", "zero", "that closest approach's offset towards the bow (ship frame)"),
            ("miss_port_m", "m", "zero", "that closest approach's offset to port (ship frame)"),
            ("miss_up_m", "m", "zero", "that closest approach's offset upwards (ship frame)"),
            ("impact_fpa_deg", "deg", "neither", "flight-path angle of the velocity at impact (negative: descending)"),
            ("impact_heading_deg", "deg", "neither", "course of the velocity at impact, from north clockwise, "
                                                     "0 to 360"),
            ("impact_fpa_error_deg", "deg", "zero", "impact flight-path angle minus the commanded one "
                                                    "(controllers.bpng.impact_flight_path_deg)"),
            ("impact_heading_error_deg", "deg", "zero", "impact course minus the commanded one "
                                                        "(controllers.bpng.impact_heading_deg), wrapped to ±180")),
    *_specs("tracking",
            ("camera_frames", "count", "neither", "camera frames rendered"),
            ("target_in_fov_fraction", "fraction", "higher", "share of the frames with the ship in the field of view"),
            ("target_visible_fraction", "fraction", "higher", "share of the frames with some of the ship's pixels not "
                                                              "hidden by the UAV's own airframe"),
            ("occluded_frames", "count", "lower", "frames with the ship in view but wholly hidden by the airframe"),
            ("partly_occluded_frames", "count", "lower", "frames with the ship seen but partly hidden by the airframe"),
            ("detections", "count", "neither", "detector outputs that found the ship"),
            ("lock_time_s", "s", "lower", "time of the first flight-software tick with the target locked"),
            ("target_in_fov_fraction_after_lock", "fraction", "higher", "share of the frames after the lock with the "
                                                                        "ship in the field of view"),
            ("occluded_frames_after_lock", "count", "lower", "frames after the lock with the ship in view but hidden "
                                                             "by the airframe"),
            ("target_visible_fraction_after_lock", "fraction", "higher", "share of the frames after the lock that saw "
                                                                         "the ship (in view, not behind the airframe)"),
            ("target_hidden_longest_s_after_lock", "s", "lower", "longest stretch after the lock between frames "
                                                                 "that saw the ship"),
            ("pixel_err_rms_px_u", "px", "lower", "RMS horizontal offset of the detection from the image centre, "
                                                  "from lock + 5 s"),
            ("pixel_err_rms_px_v", "px", "lower", "RMS vertical offset of the detection from the image centre, "
                                                  "from lock + 5 s"),
            ("pixel_err_max_px", "px", "lower", "largest offset of the detection from the image centre, "
                                                "from lock + 5 s"),
            ("ibvs_recentre_time_s", "s", "lower", "time from the lock until the detection stays within 20 px of "
                                                   "the image centre")),
    *_specs("estimator",
            ("estimator_pos_rmse_m", "m", "lower", "RMS horizontal position error of the target estimate, from its "
                                                   "first estimate"),
            ("estimator_vel_rmse_m_s", "m/s", "lower", "RMS horizontal velocity error of the target estimate"),
            ("estimator_pos_err_within_2std_fraction", "fraction", "higher", "share of estimates whose horizontal "
             "error is within twice their own reported std (an honest filter: about 0.86 or more)"),
            ("estimator_convergence_time_s", "s", "lower", "time from the lock until the estimate's own horizontal "
                                                           "std stays under 5 m"),
            ("estimator_pos_err_max_after_convergence_m", "m", "lower", "largest horizontal position error after "
                                                                        "convergence"),
            ("estimator_pos_rmse_after_convergence_m", "m", "lower", "RMS horizontal position error after convergence"),
            ("estimator_vel_rmse_after_convergence_m_s", "m/s", "lower", "RMS horizontal velocity error after "
                                                                         "convergence"),
            ("estimator_updates", "count", "neither", "measurement updates, at the end of the run"),
            ("estimator_innovation_rejected", "count", "lower", "detections its innovation gate rejected"),
            ("estimator_rejected", "count", "lower", "detections it could not use"),
            ("estimator_resets", "count", "lower", "resets after a divergence"),
            ("estimator_numerical_resets", "count", "lower", "resets after a numerical failure (e.g. a covariance "
                                                             "that lost its positive definiteness)"),
            ("estimator_initialisations", "count", "neither", "times it was started")),
    *_specs("fusion",
            ("fusion_detections", "count", "neither", "detections the flight software received"),
            *((f"fusion_{r}", "count", better, f"detections {text}") for r, better, text in _FUSION_REASONS)),
    *_specs("loiter",
            ("loiter_settle_s", "s", "neither", "the loiter errors are scored from Phase 2's start plus this"),
            ("dive_after_lock_s", "s", "lower", "time from the lock to the start of the dive that ended the run"),
            ("dive_wait_orbits", "orbits", "lower", "time from the loiter settling on the ring it dived from (the "
                                                    "switch's tolerances, dwell and minimum loiter met) to the dive, "
                                                    "in orbits of that ring"),
            ("loiter_radius_rmse_m", "m", "lower", "RMS horizontal distance to the true ship minus the ring's radius"),
            ("loiter_alt_rmse_m", "m", "lower", "RMS altitude minus the ring's altitude"),
            ("occluded_frames_phase2", "count", "lower", "frames in Phase 2 with the ship in view but hidden by the "
                                                         "airframe"),
            ("nmpc_solves", "count", "neither", "NMPC solves"),
            ("nmpc_solve_ms_median", "ms", "lower", "median wall time of an NMPC solve (machine-dependent)"),
            ("nmpc_solve_ms_p99", "ms", "lower", "99th percentile wall time of an NMPC solve (machine-dependent)"),
            ("nmpc_fallbacks", "count", "lower", "NMPC solves that failed and fell back"),
            ("nmpc_cbf_active_fraction", "fraction", "neither", "share of the NMPC solves with the visibility "
                                                                "barrier (CBF) active")),
    *_specs("navigation",
            ("nav_roll_pitch_err_rms_deg", "deg", "lower", "RMS of the navigation filter's roll and pitch errors "
                                                           "(both axes together), against the truth"),
            ("nav_heading_err_rms_deg", "deg", "lower", "RMS of the navigation filter's heading (yaw) error"),
            ("nav_pos_err_rms_m", "m", "lower", "RMS of the navigation filter's 3-D position error"),
            ("nav_vel_err_rms_m_s", "m/s", "lower", "RMS of the navigation filter's 3-D velocity error"),
            ("nav_nees_within_fraction", "fraction", "higher", "share of estimates whose attitude and position errors, "
             "normalised by their own stds, lie inside the 95 % chi-square bound (honest: about 0.95)")),
    *_specs("gimbal",
            ("tilt_positive_s", "s", "lower", "time with the gimbal tilted upwards (above the body's x-y plane)")),
    *_specs("autopilot",
            ("airspeed_err_rms_m_s", "m/s", "lower", "RMS airspeed set-point minus airspeed"),
            ("roll_rate_err_rms_deg_s", "deg/s", "lower", "RMS roll-rate set-point minus roll rate"),
            ("pitch_rate_err_rms_deg_s", "deg/s", "lower", "RMS pitch-rate set-point minus pitch rate"),
            ("accel_err_rms_m_s2", "m/s²", "lower", "RMS magnitude of the acceleration set-point minus the "
                                                    "acceleration, over the ticks in acceleration mode")),
    *_specs("flight",
            ("airspeed_min_m_s", "m/s", "neither", "lowest airspeed"),
            ("airspeed_max_m_s", "m/s", "neither", "highest airspeed"),
            ("bank_abs_max_deg", "deg", "neither", "largest bank angle, either side"),
            ("sideslip_abs_max_deg", "deg", "lower", "largest sideslip angle, either side"),
            ("height_min_m", "m", "neither", "lowest height above the sea")),
)

METRIC = {s.name: s for s in METRICS}
GROUPS = tuple(dict.fromkeys(s.group for s in METRICS))
#: the terminal metrics that are None when there is no terminal phase (or no impact)
TERMINAL_VALUES = ("switch_time_s", "impact_time_s", "miss_distance_m", "miss_bow_m", "miss_port_m", "miss_up_m",
                   "impact_fpa_deg", "impact_heading_deg", "impact_fpa_error_deg", "impact_heading_error_deg")
IMPACT_ONLY = ("impact_time_s", "impact_fpa_deg", "impact_heading_deg", "impact_fpa_error_deg",
               "impact_heading_error_deg")


def better_of(name: str) -> str:
    """Which way is better for a metric (:data:`BETTER`); "neither" for a name not in the table."""
    spec = METRIC.get(name)
    return spec.better if spec is not None else "neither"


def ordered(m: dict[str, Any]) -> dict[str, Any]:
    """The metrics in the table's order (names not in it last, in their own order); NaN as None."""
    keys = [s.name for s in METRICS if s.name in m] + [k for k in m if k not in METRIC]
    return {k: (None if isinstance(m[k], float) and math.isnan(m[k]) else m[k]) for k in keys}


def grouped(m: dict[str, Any]) -> list[tuple[str, list[tuple[str, Any]]]]:
    """(group, [(name, value)]) in the table's order; names not in the table under "other"."""
    out = [(g, [(s.name, m[s.name]) for s in METRICS if s.group == g and s.name in m]) for g in GROUPS]
    other = [(k, v) for k, v in m.items() if k not in METRIC]
    return [(g, rows) for g, rows in out + [("other", other)] if rows]


def format_value(value: Any) -> str:
    """A metric's value as text for a table: "—" for none, yes/no for a bool, 4 significant digits."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def metrics_json(m: dict[str, Any]) -> str:
    """Strict JSON of a metrics dict (``null`` for a missing or NaN value; never a bare NaN)."""
    clean = {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in m.items()}
    return json.dumps(clean, indent=2, allow_nan=False, ensure_ascii=False)


_BETTER_TEXT = {"lower": "lower", "higher": "higher", "zero": "nearer 0", "neither": "—"}


def metrics_doc() -> str:
    """The metrics reference page (docs/guide/metrics.md), generated from :data:`METRICS`."""
    lines = ["# Metrics reference", "",
             "<!-- generated from fwsim/analysis/metrics.py (METRICS) by `python tools/gen_metrics_doc.py`; "
             "edit the table there, not this page -->", "",
             "`fwsim metrics LOG` computes these from a run's log (never from the live run) and prints them "
             "grouped, in this order; `fwsim metrics LOG --json` prints them as strict JSON. A metric with no "
             "value for the run (the ship never locked, the run never dived) prints as `—` (`null` in JSON); "
             "a group whose topics the log lacks is left out. *Better* is the direction `fwsim compare` "
             "calls an improvement (`--ab`: which run is better).", ""]
    for group in GROUPS:
        lines += [f"## {group}", "", "| metric | unit | better | definition |", "|---|---|---|---|"]
        lines += [f"| `{s.name}` | {s.unit or 'text'} | {_BETTER_TEXT[s.better]} | {s.description} |"
                  for s in METRICS if s.group == group]
        lines.append("")
    return "\n".join(lines + list(_DOC_NOTES))


_DOC_NOTES = (
    "## How they are scored", "",
    "- **Terminal phase.** The terminal metrics are scored when the flight software reached Phase 3 (or, flying "
    "a script with no phases, when the run ended at an impact). A run that never did has no miss distance and "
    "no impact angles (`—`, `null`), counts as not hit, and `terminal_note` says where it ended, e.g. `no "
    "terminal phase: the run ended in phase 2 (loiter:nmpc) after 30.0 s (duration reached)`. A dive that "
    "did not end at an impact keeps its miss distance (the closest approach so far) but has no impact angles.",
    "- **Miss distance.** The closest approach of the UAV's centre of gravity to the ship's aim point (midships, "
    f"half-way up the hull), with the path continued straight along the final velocity for {MISS_EXTENSION_S:g} s "
    "past an impact, so that it says where the guidance was taking the UAV, not where the hull or the sea "
    "stopped it. The ship's pose comes from the logged ship states.",
    f"- **Estimator convergence.** From the estimator's own reported uncertainty, not from truth: the first "
    f"estimate after which the larger horizontal position std stays under {CONVERGED_STD_M:g} m. "
    "`estimator_pos_err_within_2std_fraction` checks that std against the truth: about 0.86 or more for an "
    "honest filter; well below, the filter is overconfident and its convergence comes too early.",
    f"- **Pixel errors** are scored from the lock plus {PIXEL_SETTLE_S:g} s (the camera recentres the ship after "
    f"the lock); **loiter errors** from Phase 2's start plus {LOITER_SETTLE_S:g} s to the switch.", "",
    "## Comparing runs", "",
    "`fwsim compare BASELINE RUN` checks a run against a baseline's tolerances. A change beyond the tolerance "
    "is *improved* in the better direction (reported; it fails only with `--strict`), a *REGRESSION* in the "
    "worse one or outside a bound, and *CHANGED* for a metric with no better direction, a text that differs or a "
    "value on one side only. The regression baselines (`tests/baselines/`) are checked strictly: a baseline "
    "records behaviour, so an improvement is refreshed on purpose with `python tools/refresh_baselines.py`.", "",
    "`fwsim compare A B --ab` says, per metric, whether B is better or worse than A, by how much (B − A, and "
    "relative to A), and ends with a count: `B better on N, worse on M, same on K`. Same means equal to rounding "
    "(or within `--tolerances`).", "",
)


def convergence_index(std_m) -> int:
    """The index of the first estimate after which the reported std (``std_m``, one per estimate: the larger
    horizontal axis's) stays below ``CONVERGED_STD_M``: convergence; ``len(std_m)`` when the last one is not
    below it (never converged)."""
    above = np.flatnonzero(np.asarray(std_m, dtype=float) >= CONVERGED_STD_M)
    return 0 if above.size == 0 else int(above[-1]) + 1


def estimate_errors_m(t_s, est_xy, std_xy, truth_t_s, truth_xy) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(the estimates with a finite horizontal position, as a mask; their horizontal error against the truth
    interpolated to their times, m; the larger of their horizontal stds, m). ``est_xy`` / ``std_xy`` /
    ``truth_xy``: east, north (more columns are ignored)."""
    est = np.asarray(est_xy, dtype=float)[:, :2]
    valid = np.all(np.isfinite(est), axis=1)
    t = np.asarray(t_s, dtype=float)[valid]
    err = np.linalg.norm(est[valid] - interp_at(t, truth_t_s, np.asarray(truth_xy, dtype=float)[:, :2]), axis=1)
    return valid, err, np.max(np.asarray(std_xy, dtype=float)[valid, :2], axis=1)


def lock_time_s(log: RunLog) -> float:
    """The time of the first ``/fsw/status`` tick with the target locked; NaN if it never locked."""
    if topics.FSW_STATUS in log.topics:
        fs = log.table(topics.FSW_STATUS)
        if "locked" in fs:
            locked = fs["locked"].astype(bool)
            if locked.any():
                return float(fs["t_s"][np.argmax(locked)])
    return math.nan


def seen_frames(frames) -> tuple[np.ndarray, np.ndarray]:
    """(in the field of view, seen: in it and some of the ship's pixels not hidden by the UAV) per frame of a
    ``/camera/frame`` table."""
    in_fov = frames["in_fov"].astype(bool)
    return in_fov, in_fov & (frames["visible_px"] > 0)


def longest_gap_s(t_s, seen) -> float:
    """The longest stretch, s, over which ``seen`` is false: from the last frame that saw (or the first
    frame) to the next frame that sees (or the last frame). 0 when every frame sees."""
    t = np.asarray(t_s, dtype=float)
    ok = np.asarray(seen, dtype=bool)
    if t.size == 0 or ok.all():
        return 0.0
    marks = np.concatenate(([t[0]], t[ok], [t[-1]]))
    return float(np.max(np.diff(marks)))


def _rms(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x**2))) if x.size else math.nan


def share_within(err: np.ndarray, std: np.ndarray, k: float = 2.0) -> float:
    """Share of the samples whose error magnitude ``err`` is within ``k`` times the estimator's own ``std``
    (NaN where either is not finite: left out; NaN if none is left). For a round two-dimensional Gaussian
    error and its true std, ``1 - exp(-k^2 / 2)``: 86.5 % at k = 2."""
    err, std = np.asarray(err, dtype=float), np.asarray(std, dtype=float)
    ok = np.isfinite(err) & np.isfinite(std)
    return float(np.mean(err[ok] <= k * std[ok])) if ok.any() else math.nan


def compute_metrics(log: RunLog | str | Path) -> dict[str, Any]:
    """Metrics of one run as a flat dict in the table's order (numbers, ``hit`` a bool, status and reason text;
    None for a metric with no value in this run)."""
    if not isinstance(log, RunLog):
        log = read_log(log)
    st = log.table(topics.UAV_STATE)
    m: dict[str, Any] = {"status": log.status, "end_reason": log.reason}
    t = st["t_s"]
    m["flight_time_s"] = float(t[-1] - t[0]) if t.size else 0.0
    m["airspeed_min_m_s"] = float(np.min(st["airspeed_m_s"]))
    m["airspeed_max_m_s"] = float(np.max(st["airspeed_m_s"]))
    m["bank_abs_max_deg"] = float(np.degrees(np.max(np.abs(st["euler_ned_rad"][:, 0]))))
    m["sideslip_abs_max_deg"] = float(np.degrees(np.max(np.abs(st["beta_rad"]))))
    m["height_min_m"] = float(np.min(st["height_above_sea_m"]))
    _autopilot_metrics(log, m)
    _camera_metrics(log, m)
    _acquisition_metrics(log, m)
    _fusion_metrics(log, m)
    _loiter_metrics(log, m)
    _impact_metrics(log, m)
    _navigation_metrics(log, m)
    if m.get("lock_time_s") is not None and m.get("switch_time_s") is not None:
        m["dive_after_lock_s"] = m["switch_time_s"] - m["lock_time_s"]
        m["dive_wait_orbits"] = _dive_wait_orbits(log, m["switch_time_s"])
    return ordered(m)


def _dive_wait_orbits(log: RunLog, switch_t_s: float) -> float | None:
    """How long the loiter waited for its dive while settled, in orbits: the time in the last Phase 2 before the
    switch during which the switch's condition but the approach window held (the radius and altitude, the truth
    against the ring the flight software flew, its status's radius and altitude, within the tolerances for the
    dwell, and the minimum loiter up); the descent to an entry ring is not settled and does not count. An orbit
    is the ring's circumference over the UAV's mean ground speed while settled."""
    if not log.topics.get(topics.FSW_STATUS):
        return None
    try:
        sw = (log.scenario if log.scenario is not None else _scenario_of(log)).controllers.switch
    except Exception:  # noqa: BLE001 - a log this version cannot read: no tolerances to score against
        return None
    fs, st = log.table(topics.FSW_STATUS), log.table(topics.UAV_STATE)
    t, phase = fs["t_s"], fs["phase"]
    before = np.flatnonzero((phase != 2) & (t < switch_t_s))
    first = before[-1] + 1 if before.size else 0  # the last Phase 2's first tick
    t, fs_r = t[first:], {k: fs[k][first:] for k in ("radial_err_m", "loiter_altitude_m", "loiter_radius_m")}
    keep = t < switch_t_s
    if not keep.any():
        return None
    t = t[keep]
    height = interp_at(t, st["t_s"], st["pos_enu_m"][:, 2])
    ok = (np.abs(fs_r["radial_err_m"][keep]) <= sw.radius_tol_m) & \
        (np.abs(height - fs_r["loiter_altitude_m"][keep]) <= sw.altitude_tol_m)
    since = np.full(t.size, np.nan)  # the start of each tick's stretch within tolerance
    for k in np.flatnonzero(ok):
        since[k] = since[k - 1] if k and ok[k - 1] else t[k]
    settled = ok & (t - since >= sw.dwell_s) & (t - t[0] >= sw.min_loiter_s)
    if not settled.any():
        return 0.0
    dt = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    speed = interp_at(t[settled], st["t_s"], np.hypot(st["vel_enu_m_s"][:, 0], st["vel_enu_m_s"][:, 1]))
    radius = float(fs_r["loiter_radius_m"][keep][-1])
    period = 2.0 * math.pi * radius / float(np.mean(speed))
    return float(np.count_nonzero(settled)) * dt / period if period > 0.0 else None


def _scenario_of(log: RunLog):
    from fwsim.scenario.model import parse_scenario
    return parse_scenario(log.effective_scenario_text or log.scenario_text, check_plugins=False)


#: the 95 % point of the chi-square distribution with 6 degrees of freedom (attitude and position, 3 each)
_CHI2_95_6DOF = 12.591587243743977


def _navigation_metrics(log: RunLog, m: dict) -> None:
    """The navigation filter's errors against the truth (``/nav/estimate`` once initialised, against ``/uav/state``,
    the truth interpolated to the estimate's times, its yaw unwrapped first), and its consistency: the normalised
    error squared of attitude (roll, pitch, yaw) and position with the filter's own stds, per axis."""
    if not log.topics.get(topics.NAV_ESTIMATE):
        return
    nav, st = log.table(topics.NAV_ESTIMATE), log.table(topics.UAV_STATE)
    keep = nav["mode"] != "initialising"
    if not keep.any():
        return
    nav = {k: v[keep] for k, v in nav.items()}
    t = nav["t_s"]
    euler_true = np.array(st["euler_ned_rad"], dtype=float)
    euler_true[:, 2] = np.unwrap(euler_true[:, 2])
    att_err = np.asarray(nav["euler_ned_rad"], float) - interp_at(t, st["t_s"], euler_true)
    att_err = (att_err + math.pi) % (2.0 * math.pi) - math.pi
    pos_err = np.asarray(nav["pos_enu_m"], float) - interp_at(t, st["t_s"], st["pos_enu_m"])
    vel_err = np.asarray(nav["vel_enu_m_s"], float) - interp_at(t, st["t_s"], st["vel_enu_m_s"])
    m["nav_roll_pitch_err_rms_deg"] = math.degrees(_rms(att_err[:, :2].ravel()))
    m["nav_heading_err_rms_deg"] = math.degrees(_rms(att_err[:, 2]))
    m["nav_pos_err_rms_m"] = _rms(np.linalg.norm(pos_err, axis=1))
    m["nav_vel_err_rms_m_s"] = _rms(np.linalg.norm(vel_err, axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        nees = np.sum((att_err / nav["att_std_rad"]) ** 2, axis=1) + np.sum((pos_err / nav["pos_std_m"]) ** 2, axis=1)
    ok = np.isfinite(nees)
    m["nav_nees_within_fraction"] = float(np.mean(nees[ok] <= _CHI2_95_6DOF)) if ok.any() else None


def terminal_metrics(log: RunLog | str | Path) -> dict[str, Any]:
    """Only the outcome and terminal metrics (what ``fwsim run``'s result line needs), in the table's order."""
    if not isinstance(log, RunLog):
        log = read_log(log)
    st = log.table(topics.UAV_STATE)
    t = st["t_s"]
    m: dict[str, Any] = {"status": log.status, "end_reason": log.reason,
                         "flight_time_s": float(t[-1] - t[0]) if t.size else 0.0}
    _impact_metrics(log, m)
    return ordered(m)


def result_line(m: dict[str, Any]) -> str:
    """One line on how a run ended, from its metrics: ``hit at 176.88 s, miss 0.32 m, impact angles -0.64° /
    +0.25° off`` or ``no dive: ended in phase 2 (loiter:nmpc) after 30.0 s (duration reached)``."""
    note = m.get("terminal_note") or ""
    if m.get("miss_distance_m") is None:
        if note.startswith("no terminal phase"):
            return "no dive: " + note.split(": ", 1)[-1].removeprefix("the run ")
        return "no miss distance" + (f" ({note or m.get('impact_metrics') or 'not scored'})")
    what = "hit" if m.get("hit") else "no hit"
    when = m.get("impact_time_s")
    text = f"{what}{f' at {when:.2f} s' if when is not None else ''}, miss {m['miss_distance_m']:.2f} m"
    fpa, heading = m.get("impact_fpa_error_deg"), m.get("impact_heading_error_deg")
    if fpa is not None and heading is not None:
        text += f", impact angles {_signed(fpa)}° / {_signed(heading)}° off"
    elif note:
        text += f" ({note})"
    return text


def _signed(x: float) -> str:
    return f"{x:+.2f}".replace("-", "\u2212")


def _autopilot_metrics(log: RunLog, m: dict) -> None:
    if topics.AUTOPILOT_STATUS not in log.topics:
        return
    ap = log.table(topics.AUTOPILOT_STATUS)
    m["airspeed_err_rms_m_s"] = _rms(ap["airspeed_sp_m_s"] - ap["airspeed_m_s"])
    err = np.degrees(ap["body_rates_sp_frd_rad_s"] - ap["body_rates_frd_rad_s"])
    m["roll_rate_err_rms_deg_s"] = _rms(err[:, 0])
    m["pitch_rate_err_rms_deg_s"] = _rms(err[:, 1])
    accel = ap["mode"] == "accel"
    if np.any(accel):
        a_err = np.linalg.norm(ap["accel_sp_enu_m_s2"][accel] - ap["accel_enu_m_s2"][accel], axis=1)
        m["accel_err_rms_m_s2"] = _rms(a_err)


def _camera_metrics(log: RunLog, m: dict) -> None:
    if topics.CAMERA_FRAME in log.topics:
        fr = log.table(topics.CAMERA_FRAME)
        in_fov = fr["in_fov"].astype(bool)
        visible = fr["visible_px"] > 0
        m["camera_frames"] = float(len(in_fov))
        m["target_in_fov_fraction"] = float(np.mean(in_fov)) if len(in_fov) else math.nan
        m["target_visible_fraction"] = float(np.mean(visible)) if len(visible) else math.nan
        m["occluded_frames"] = float(np.sum(in_fov & ~visible))  # in view but hidden by the UAV
        m["partly_occluded_frames"] = float(np.sum(visible & (fr["occluded_fraction"] > 0)))
    if topics.CAMERA_DETECTION in log.topics:
        det = log.table(topics.CAMERA_DETECTION)
        m["detections"] = float(np.sum(det["detected"].astype(bool)))


def _fusion_metrics(log: RunLog, m: dict) -> None:
    """What became of the detections the flight software received (``/fsw/detection_fusion``): one count per
    reason (``fusion_<reason>``, every reason listed), and the estimator's counters at the end of the run."""
    from controllers.messages import FusionReason

    if topics.FSW_DETECTION_FUSION in log.topics:
        reasons = log.table(topics.FSW_DETECTION_FUSION)["reason"] if log.topics[topics.FSW_DETECTION_FUSION] else []
        m["fusion_detections"] = float(len(reasons))
        for r in FusionReason:
            m[f"fusion_{r.value}"] = float(sum(1 for x in reasons if x == r.value))
    if log.topics.get(topics.FSW_ESTIMATOR_STATUS):
        last = log.rows(topics.FSW_ESTIMATOR_STATUS)[-1]
        for k in ("updates", "innovation_rejected", "rejected", "resets", "numerical_resets", "initialisations"):
            m[f"estimator_{k}"] = float(last[k])


def _phases(log: RunLog, m: dict) -> str:
    """Switch time and go-arounds; "" when the terminal metrics are scored, else why not (``terminal_note``)."""
    reason = str(log.reason)
    ended = reason.startswith("hit the ship") or reason.startswith("sea contact")
    if topics.FSW_STATUS not in log.topics or not log.topics[topics.FSW_STATUS]:
        return "" if ended else f"no terminal phase: the log has no flight-software status ({reason})"
    fs = log.table(topics.FSW_STATUS)
    phase = fs["phase"]
    # the start of the last Phase 3 (the dive that ended the run; earlier ones went round)
    starts = np.flatnonzero((phase[1:] == TERMINAL_PHASE) & (phase[:-1] != TERMINAL_PHASE)) + 1
    if phase.size and phase[0] == TERMINAL_PHASE:
        starts = np.concatenate([[0], starts])
    m["switch_time_s"] = float(fs["t_s"][starts[-1]]) if starts.size else math.nan
    m["go_arounds"] = float(np.sum((phase[1:] == 2) & (phase[:-1] == TERMINAL_PHASE)))
    last = int(phase[-1]) if phase.size else 0
    name = str(fs["phase_name"][-1]) if "phase_name" in fs and phase.size else ""
    where = f"phase {last}" + (f" ({name})" if name else "")
    after = f"after {m.get('flight_time_s', float(fs['t_s'][-1])):.1f} s"
    if starts.size or (ended and not np.any(phase != 0)):  # dived, or a script (no phases) that ended at an impact
        return "" if ended else f"no impact: the run ended in {where} {after} ({reason}); the miss distance is " \
                                "the closest approach before the end"
    return f"no terminal phase: the run ended in {where} {after} ({reason})"


def _impact_metrics(log: RunLog, m: dict) -> None:
    """Terminal phase: switch time, impact time, miss distance to the aim point, hit, impact angles; None with a
    ``terminal_note`` (why) for those a run that never dived (or never hit anything) does not have."""
    from fwsim.scenario.model import parse_scenario
    note = _phases(log, m)
    ended = not note
    try:
        scenario = log.scenario if log.scenario is not None else \
            parse_scenario(log.effective_scenario_text or log.scenario_text, check_plugins=False)
    except Exception as exc:  # a log written by another version: no geometry to score against, and the user told
        why = short(exc, 160) or type(exc).__name__
        m["impact_metrics"] = f"left out: the log's scenario does not read with this fwsim version ({why})"
        return
    st = log.table(topics.UAV_STATE)
    ship = _ship(log, scenario)
    m["hit"] = _hit(st, ship, scenario)
    if note:
        m["terminal_note"] = note
        if note.startswith("no terminal phase"):
            m.update({k: None for k in TERMINAL_VALUES})
            return
    m["impact_time_s"] = float(st["t_s"][-1]) if ended else None
    _miss_metrics(st, ship, ended, m)
    bpng = getattr(scenario.controllers, "bpng", None)
    if ended and bpng is not None:
        v = st["vel_enu_m_s"][-1]
        fpa = math.degrees(math.asin(max(-1.0, min(1.0, v[2] / max(float(np.linalg.norm(v)), 1e-9)))))
        heading = math.degrees(math.atan2(v[0], v[1]))
        m["impact_fpa_deg"] = fpa
        m["impact_heading_deg"] = heading % 360.0
        m["impact_fpa_error_deg"] = fpa - bpng.impact_flight_path_deg
        m["impact_heading_error_deg"] = (heading - bpng.impact_heading_deg + 180.0) % 360.0 - 180.0
    else:
        m.update({k: None for k in IMPACT_ONLY})


def _ship(log: RunLog, scenario):
    from fwsim.world.target import Ship
    return LoggedShip(log, scenario) if topics.TARGET_STATE in log.topics else Ship(scenario.target)


def _hit(st, ship, scenario) -> bool:
    """The run's last state inside the hull or superstructure."""
    from fwsim.world.target import HullVolume
    p_ship, R = ship.pose(float(st["t_s"][-1]))
    return bool(HullVolume(scenario.target).contains(R.T @ (st["pos_enu_m"][-1] - p_ship)))


def _miss_metrics(st, ship, ended: bool, m: dict) -> None:
    """The closest approach to the aim point and its offset in the ship's frame."""
    t, pos = st["t_s"], st["pos_enu_m"]
    if ended:
        # Guidance accuracy: continue the path straight through the impact along the final
        # velocity for MISS_EXTENSION_S, so the miss distance says where the UAV was going,
        # not where the ship's skin or the sea stopped it.
        ext = np.linspace(0.0, MISS_EXTENSION_S, 61)[1:]
        t = np.concatenate([t, t[-1] + ext])
        pos = np.concatenate([pos, pos[-1] + ext[:, None] * st["vel_enu_m_s"][-1]])
    aims = np.array([ship.aim_point_enu_m(float(ti)) for ti in t])
    m["miss_distance_m"], miss, t_miss = _closest_approach(t, pos - aims)
    _, R_miss = ship.pose(t_miss)  # the miss in the ship's frame (bow, port, up): where the UAV was going
    m["miss_bow_m"], m["miss_port_m"], m["miss_up_m"] = (float(c) for c in R_miss.T @ miss)



def _loiter_metrics(log: RunLog, m: dict) -> None:
    """Phase 2: radius and altitude errors against the true ship, the tilt joint, the NMPC's solves."""
    if topics.GIMBAL_STATE in log.topics:
        g = log.table(topics.GIMBAL_STATE)
        dt = np.diff(g["t_s"], append=g["t_s"][-1])
        m["tilt_positive_s"] = float(np.sum(dt[g["tilt_rad"] > 0.0]))
    if topics.FSW_NMPC in log.topics:
        n = log.table(topics.FSW_NMPC)
        m["nmpc_solves"] = float(len(n["t_s"]))
        m["nmpc_solve_ms_median"] = float(np.median(n["solve_ms"]))
        m["nmpc_solve_ms_p99"] = float(np.percentile(n["solve_ms"], 99))
        m["nmpc_fallbacks"] = float(np.sum(n["fallback"].astype(bool)))
        m["nmpc_cbf_active_fraction"] = float(np.mean(n["cbf_active"].astype(bool)))
    if topics.FSW_STATUS not in log.topics or topics.TARGET_STATE not in log.topics:
        return
    fs = log.table(topics.FSW_STATUS)
    p2 = np.flatnonzero(fs["phase"] == 2)
    if not p2.size:
        return
    t2 = float(fs["t_s"][p2[0]])
    p3 = np.flatnonzero(fs["phase"] == 3)
    t_end = float(fs["t_s"][p3[0]]) if p3.size else float(fs["t_s"][-1])
    if "loiter_radius_m" in fs:  # the ring the loiter flew (whichever block flew it)
        R, H = float(fs["loiter_radius_m"][p2[0]]), float(fs["loiter_altitude_m"][p2[0]])
    else:  # a log from before the ring was logged: from its scenario
        from fwsim.scenario.model import parse_scenario
        try:
            sc = (log.scenario if log.scenario is not None else
                  parse_scenario(log.effective_scenario_text or log.scenario_text, check_plugins=False)).controllers
        except Exception:
            return
        loiter = sc.nmpc if sc.after_lock.use == "nmpc" else sc.orbit
        R, H = loiter.radius_m, loiter.altitude_m
    if topics.CAMERA_FRAME in log.topics:
        fr = log.table(topics.CAMERA_FRAME)
        wf = (fr["t_s"] >= t2) & (fr["t_s"] <= t_end)
        m["occluded_frames_phase2"] = float(np.sum(fr["in_fov"][wf].astype(bool) & (fr["visible_px"][wf] <= 0)))
    if "loiter_altitude_m" in fs:  # the ring's hold ends where the loiter leaves H for the dive's entry ring
        left = np.flatnonzero((fs["phase"] == 2) & (np.abs(fs["loiter_altitude_m"] - H) > 1e-6))
        if left.size:
            t_end = min(t_end, float(fs["t_s"][left[0]]))
    st, tg = log.table(topics.UAV_STATE), log.table(topics.TARGET_STATE)
    w = (st["t_s"] >= t2 + LOITER_SETTLE_S) & (st["t_s"] <= t_end)
    m["loiter_settle_s"] = LOITER_SETTLE_S
    if not w.any():
        m["loiter_radius_rmse_m"] = m["loiter_alt_rmse_m"] = math.nan
        return
    t = st["t_s"][w]
    q = interp_at(t, tg["t_s"], tg["pos_enu_m"][:, :2])
    radius = np.linalg.norm(st["pos_enu_m"][w, :2] - q, axis=1)
    m["loiter_radius_rmse_m"] = _rms(radius - R)
    m["loiter_alt_rmse_m"] = _rms(st["pos_enu_m"][w, 2] - H)


class LoggedShip:
    """The ship as the log recorded it (/target/state: whatever moved it, a model or an event's manoeuvre):
    its pose and aim point at a logged time, or carried on at its last velocity past the log's end."""

    def __init__(self, log: RunLog, scenario):
        from fwsim.world.target import aim_point_ship_m
        tg = log.table(topics.TARGET_STATE)
        self._t = tg["t_s"]
        self._pos, self._vel, self._heading = tg["pos_enu_m"], tg["vel_enu_m_s"], tg["heading_ned_rad"]
        self._index = {float(ti): i for i, ti in enumerate(self._t)}
        self._aim = aim_point_ship_m(scenario.target)

    def pose(self, t_s: float) -> tuple[np.ndarray, np.ndarray]:
        from fwsim.world.target import r_enu_from_ship
        i = self._index.get(float(t_s))
        if i is None:  # between or past the logged states
            i = max(int(np.searchsorted(self._t, t_s, side="right")) - 1, 0)
            pos = self._pos[i] + self._vel[i] * (float(t_s) - float(self._t[i]))
            return pos, r_enu_from_ship(float(self._heading[i]))
        return self._pos[i], r_enu_from_ship(float(self._heading[i]))

    def aim_point_enu_m(self, t_s: float) -> np.ndarray:
        pos, R = self.pose(t_s)
        return pos + R @ self._aim


def _closest_approach(t: np.ndarray, rel: np.ndarray) -> tuple[float, np.ndarray, float]:
    """(smallest |rel(t)|, rel there, t there) with rel linear between samples (rel: UAV minus aim point,
    (n, 3))."""
    i = int(np.argmin(np.linalg.norm(rel, axis=1)))
    best, vec, t_best = float(np.linalg.norm(rel[i])), rel[i], float(t[i])
    d = np.diff(rel, axis=0)
    if len(d):
        dd = np.einsum("ij,ij->i", d, d)
        s = np.clip(-np.einsum("ij,ij->i", rel[:-1], d) / np.maximum(dd, 1e-12), 0.0, 1.0)
        seg = rel[:-1] + s[:, None] * d
        norms = np.linalg.norm(seg, axis=1)
        j = int(np.argmin(norms))
        if float(norms[j]) < best:
            best, vec, t_best = float(norms[j]), seg[j], float(t[j] + s[j] * (t[j + 1] - t[j]))
    return best, np.asarray(vec, dtype=float), t_best


def _acquisition_metrics(log: RunLog, m: dict) -> None:
    lock_t = lock_time_s(log)
    m["lock_time_s"] = lock_t
    if math.isnan(lock_t):
        return
    meta = log.metadata.get("fwsim", {})
    if topics.CAMERA_FRAME in log.topics:
        fr = log.table(topics.CAMERA_FRAME)
        after = fr["t_s"] >= lock_t
        if after.any():
            in_fov, seen = (x[after] for x in seen_frames(fr))
            m["target_in_fov_fraction_after_lock"] = float(np.mean(in_fov))
            m["occluded_frames_after_lock"] = float(np.sum(in_fov & ~seen))
            m["target_visible_fraction_after_lock"] = float(np.mean(seen))
            m["target_hidden_longest_s_after_lock"] = longest_gap_s(fr["t_s"][after], seen)
    if topics.CAMERA_DETECTION in log.topics and "camera_width_px" in meta:
        det = log.table(topics.CAMERA_DETECTION)
        cx, cy = float(meta["camera_width_px"]) / 2, float(meta["camera_height_px"]) / 2
        err = np.hypot(det["u_px"] - cx, det["v_px"] - cy)
        detected = det["detected"].astype(bool)
        ok = detected & (det["exposure_t_s"] >= lock_t + PIXEL_SETTLE_S)
        m["pixel_err_rms_px_u"] = _rms(det["u_px"][ok] - cx)
        m["pixel_err_rms_px_v"] = _rms(det["v_px"][ok] - cy)
        m["pixel_err_max_px"] = float(np.max(err[ok])) if ok.any() else math.nan
        # the recentring after the lock: time until the error stays under 20 px
        after = detected & (det["exposure_t_s"] >= lock_t)
        big = np.flatnonzero(after & (err > 20.0))
        m["ibvs_recentre_time_s"] = float(det["exposure_t_s"][big[-1]] - lock_t) if big.size else 0.0
    if topics.FSW_ESTIMATE in log.topics and topics.TARGET_STATE in log.topics:
        est = log.table(topics.FSW_ESTIMATE)
        tru = log.table(topics.TARGET_STATE)
        valid, pe, std = estimate_errors_m(est["t_s"], est["pos_enu_m"], est["pos_std_m"], tru["t_s"],
                                           tru["pos_enu_m"])
        if not valid.any():
            return
        t, vel = est["t_s"][valid], est["vel_enu_m_s"][valid, :2]
        tv = interp_at(t, tru["t_s"], tru["vel_enu_m_s"][:, :2])
        ve = np.linalg.norm(vel - tv, axis=1)
        m["estimator_pos_rmse_m"] = _rms(pe)
        m["estimator_vel_rmse_m_s"] = _rms(ve)
        m["estimator_pos_err_within_2std_fraction"] = share_within(pe, std, 2.0)
        k = convergence_index(std)
        if k < len(t):
            m["estimator_convergence_time_s"] = float(t[k] - lock_t)
            m["estimator_pos_err_max_after_convergence_m"] = float(np.max(pe[k:]))
            m["estimator_pos_rmse_after_convergence_m"] = _rms(pe[k:])
            m["estimator_vel_rmse_after_convergence_m_s"] = _rms(ve[k:])
        else:
            m["estimator_convergence_time_s"] = math.nan
