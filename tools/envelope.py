"""The envelope sweep's verdict: issue 16's four bars, estimator by estimator, from a batch's summary.

    fwsim batch scenarios/batches/envelope.yaml --workers 2 --out runs/envelope
    fwsim batch scenarios/batches/envelope_ct_ukf.yaml --workers 2 --out runs/envelope_ct_ukf  # same draws
    python tools/envelope.py runs/envelope runs/envelope_ct_ukf   # a Markdown table: each bar, each estimator
    python tools/envelope.py runs/envelope --by set.target.motion  # split another way
    fwsim batch scenarios/batches/envelope.yaml --workers 2 --hold world --out runs/no_wind  # a factor held
    python tools/envelope.py runs/envelope runs/no_wind --by folder  # one row per folder: what wind costs
    python tools/envelope.py runs/envelope --why   # and each run outside 3 m / 3 deg: why (from its log)
    python tools/envelope.py runs/envelope --why-estimate   # and each run failing the estimate bar: why
    python tools/envelope.py runs/envelope runs/envelope_ct_ukf --paired   # and run by run: what moved
    python tools/envelope.py runs/envelope runs/envelope_ct_ukf --loiter   # and the loiter's errors by motion

The bars, over the runs of each group: every run hits the ship; >= 95 % hit within 3 m of the aim point
and 3 deg of both impact angles; >= 95 % keep the ship in view >= 99 % of the time after the lock (seen:
in the field of view and not hidden behind the UAV's own airframe, ``target_visible_fraction_after_lock``;
a further column gives the field of view alone, the bar as this tool counted it before 2026-11-26; rows
scored before then lack the first: ``fwsim batch SPEC --out DIR --resume`` scores a batch's logs again
without flying them); >= 90 %
keep the estimator's horizontal error within 8 m after it has converged (its own std under 5 m; a run
whose estimate never converges counts against this bar). A last
column says whether that std is honest: the median run's share of estimates whose error is within twice
it (about 86 % or more for a consistent filter). The statistics are fwsim report's (fwsim.analysis.report.summarise).
Exit code 0 when every group meets every bar.

``--why-estimate`` adds, for each run failing the estimate bar, whether it never converged (its std at the
end and at the last fused box, which tells whether the std went over 5 m with the dive's boxes or in the coast
after them, and the largest error from the dive's start: what the bar would have counted had the std fallen
under 5 m there) or went over 8 m after converging (how long after, in the loiter or the dive, the std then, and
for how long), with a tally: an excursion within 5 s of convergence came as the std crossed 5 m, the error
then near twice it or more.

``--paired`` (two folders of the same draws: the same spec and ``--seed``, another estimator, a ``--set`` or
``--hold``, or the code before and after a change) adds the comparison run by run: for each bar the runs that
met it in one folder only, how many miss distances went down or up by over 1 m, and a row for each run that
moved (its miss distance and its four bars in each). Runs are matched by their scenario and seed.

``--loiter [COLUMN]`` adds, per value of COLUMN (the ship's motion by default), the median over the runs of
each run's median horizontal position and velocity error in the loiter, from 60 s after the lock to the
dive: how well an estimator follows the ship's motion, apart from the dive's close-in errors.

``--why`` adds, for each run outside 3 m / 3 deg, what its log says: which bar it fails (distance, an
angle, both; or no hit), the estimate's horizontal error in the ship's frame (towards the bow, to port)
5 s and 2 s before the end and at the end (the dive steers on it: a miss the estimate shares is the
perception's or the estimator's, one it does not is the guidance's), its error 150 m out along and across
the horizontal line of sight (a height error of the point the box centre stands for lands along it), and
what became of the detections of the last 5 s (the share fused and the commonest reason for the rest;
those of the planned coast of the last ~120 m, ``too_close``, left out). The ship's motion, type and speed
come from the summary's dispersed columns, and so does the longest stretch without the ship seen after the
lock (out of view or behind the airframe). Its last columns name the course model ``turn_from_course`` handed
on into the dive, and the ship's heading the shape correction used at the dive's start with its error against
the truth (from the estimated course or, for a slow ship, from the box shapes: an error near 180 deg is the
bow and stern swapped), and the ship's length, beam and height as the size fit had them at the dive's start,
over the ship's own (a height read 1.5 times the ship's puts the estimate along the line of sight in a
dive).
"""
from __future__ import annotations

import argparse
import math
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from fwsim.analysis.report import row_value, summarise, within

#: seconds before the end of a run at which --why gives the estimate's error (the end itself too)
WHY_TIMES_S = (5.0, 2.0)
WHY_WINDOW_S = 5.0  # --why: the detections of the last this many seconds
#: --why: the aim line's offset is the median over the dive's ticks this far (m) from the point it steers to
AIM_LINE_RANGES_M = (50.0, 80.0)
#: --why: the estimate's error along and across the line of sight when the UAV was last this far (m) from the
#: ship (before the planned coast of the last 80-120 m)
LOS_RANGE_M = 150.0
ESTIMATE_BAR_M = 8.0  # the estimate bar: the horizontal error after convergence within this (m)
#: --why-estimate's tally: an excursion over the bar this soon after convergence (s) came as the std crossed
#: the threshold (the error then near twice the std or more), not later in a converged filter
NEAR_CONVERGENCE_S = 5.0
#: --loiter: the estimate is scored from this long (s) after the lock (its start) to the dive
LOITER_SETTLE_S = 60.0
#: --paired: a run's miss distance changed by more than this (m) counts as better or worse
PAIR_MARGIN_M = 1.0

BARS = (("hits", 1.0), ("within 3 m / 3 deg", 0.95), ("seen >= 99 % (in view, not behind the airframe)", 0.95),
        ("estimate <= 8 m", 0.90))


def _label(value) -> str:
    if isinstance(value, dict):
        return str(value.get("model", value))
    return "(the scenario's)" if value is None or (isinstance(value, float) and math.isnan(value)) else str(value)


def verdict(rows: list[dict], by: str) -> list[tuple[str, int, list[float], float, float]]:
    """(group, runs, [share per bar], the median run's share of estimates within 2 std of their error, the
    share in the field of view >= 99 % of the time, the airframe's shadow not counted) for each value of the
    column ``by``."""
    groups: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        groups[_label(r.get(by))].append(r)
    out = []
    for name, rs in (groups.items() if by == "folder" else sorted(groups.items())):  # folders as given
        rep = summarise(rs, name)
        out.append((name, rep.runs, [rep.hits / rep.runs if rep.runs else math.nan, rep.within_3m_3deg,
                                     rep.visible_after_lock["share_99"], rep.estimator_error_m["share_8m"]],
                    rep.estimator_error_m["within_2std_median"], rep.in_view_after_lock["share_99"]))
    return out


def _latest_errors(t_s, est_xy, truth_t_s, truth_xy, at_s) -> list[tuple[np.ndarray, float] | None]:
    """For each time of ``at_s``: (the latest finite estimate at or before it minus the truth interpolated to
    that estimate's time (east, north), that estimate's time), or None when no estimate came before."""
    from fwsim.log.truth import interp_at
    t = np.asarray(t_s, dtype=float)
    est = np.asarray(est_xy, dtype=float)
    ok = np.isfinite(est).all(axis=1)
    t, est = t[ok], est[ok]
    truth = np.asarray(truth_xy, dtype=float)
    out = []
    for a in at_s:
        k = int(np.searchsorted(t, a, side="right")) - 1
        out.append(None if k < 0 else (est[k] - interp_at(t[k:k + 1], truth_t_s, truth)[0], float(t[k])))
    return out


def ship_frame_errors(t_s, est_xy, truth_t_s, truth_xy, truth_heading_ned_rad, at_s) -> list[tuple[float, float]]:
    """The estimate's horizontal error (estimate - truth) at each time of ``at_s``, in the ship's frame:
    (towards the bow, to port), m. ``est_xy`` / ``truth_xy``: east, north; the ship's heading from north,
    clockwise (its bow along (sin, cos) in east, north; port along (-cos, sin)). The latest estimate at or
    before each time (NaN when there is none); the truth interpolated to that estimate's time."""
    tt = np.asarray(truth_t_s, dtype=float)
    out = []
    for got in _latest_errors(t_s, est_xy, tt, truth_xy, at_s):
        if got is None:
            out.append((math.nan, math.nan))
            continue
        e, tk = got
        # the heading interpolated through its unwrapped angle (a ship turning through north)
        yaw = float(np.interp(tk, tt, np.unwrap(np.asarray(truth_heading_ned_rad, dtype=float))))
        bow, port = (math.sin(yaw), math.cos(yaw)), (-math.cos(yaw), math.sin(yaw))
        out.append((float(e[0] * bow[0] + e[1] * bow[1]), float(e[0] * port[0] + e[1] * port[1])))
    return out


def line_of_sight_error(t_s, est_xy, truth_t_s, truth_pos_enu_m, uav_t_s, uav_pos_enu_m,
                        range_m: float = LOS_RANGE_M) -> tuple[float, float]:
    """The estimate's horizontal error (estimate - truth) when the UAV was last ``range_m`` or more from the
    ship (truth, 3-D range), split along the horizontal line of sight from the UAV to the ship (+: beyond the
    ship) and across it (+: to the left, looking along it), m. An error in the height of the point the box
    centre stands for lands along the line of sight (the height over the tangent of the elevation); one in
    the ship's layout or heading mostly across it. The latest estimate at or before that time, the truth
    interpolated to it; NaN where the UAV never was that far or no estimate came before."""
    from fwsim.log.truth import interp_at
    ut = np.asarray(uav_t_s, dtype=float)
    up = np.asarray(uav_pos_enu_m, dtype=float)
    truth = np.asarray(truth_pos_enu_m, dtype=float)
    ship = interp_at(ut, truth_t_s, truth)
    far = np.flatnonzero(np.linalg.norm(ship - up, axis=1) >= range_m)
    if not far.size:
        return math.nan, math.nan
    i = int(far[-1])
    los = ship[i, :2] - up[i, :2]
    n = float(np.hypot(los[0], los[1]))
    got = _latest_errors(t_s, est_xy, truth_t_s, truth[:, :2], [ut[i]])[0]
    if got is None or not n > 1e-9:
        return math.nan, math.nan
    e, u = got[0], los / n
    return float(e @ u), float(-e[0] * u[1] + e[1] * u[0])


def last_detections(t_s, reasons, end_s: float, window_s: float = WHY_WINDOW_S) -> tuple[float, str]:
    """(share of the detections of the last ``window_s`` before ``end_s`` that were fused, the commonest
    reason among the others with its count, e.g. "size_mismatch 40"; "" when none was left out). The
    detections of the planned coast (``too_close``) are left out of both: they say where the coast began,
    not how the estimate came to it. NaN when no other detection falls in the window."""
    from collections import Counter

    from controllers.messages import FUSED, FusionReason
    t = np.asarray(t_s, dtype=float)
    last = [str(r) for r, ti in zip(reasons, t.tolist())
            if ti >= end_s - window_s and str(r) != FusionReason.TOO_CLOSE]
    if not last:
        return math.nan, ""
    fused = {str(f) for f in FUSED}
    used = sum(r in fused for r in last)
    rest = Counter(r for r in last if r not in fused)
    top = rest.most_common(1)
    return used / len(last), (f"{top[0][0]} {top[0][1]}" if top else "")


def aim_line_offset(t_s, aim_enu_m, range_m, uav_t_s, uav_pos_enu_m, truth_aim_at,
                    ranges_m: tuple[float, float] = AIM_LINE_RANGES_M) -> float:
    """Median, over the dive's ticks whose range to the point it steers to (``aim_enu_m``, ``range_m``: the
    log's /fsw/bpng) lies within ``ranges_m``, of the distance from the ship's true aim point
    (``truth_aim_at(t)`` -> (3,)) to the line from the UAV (``uav_pos_enu_m`` at ``uav_t_s``, interpolated)
    through that point. NaN when no tick is in the band or the line is undefined."""
    from fwsim.log.truth import interp_at
    t = np.asarray(t_s, dtype=float)
    rng = np.asarray(range_m, dtype=float)
    lo, hi = ranges_m
    band = np.flatnonzero((rng >= lo) & (rng <= hi))
    if not band.size:
        return math.nan
    p = interp_at(t[band], uav_t_s, uav_pos_enu_m)
    d = np.asarray(aim_enu_m, dtype=float)[band] - p
    n = np.linalg.norm(d, axis=1)
    ok = np.isfinite(n) & (n > 1e-6)
    if not ok.any():
        return math.nan
    u = d[ok] / n[ok, None]
    w = np.array([truth_aim_at(float(ti)) for ti in t[band][ok]], dtype=float) - p[ok]
    return float(np.median(np.linalg.norm(w - np.einsum("ij,ij->i", w, u)[:, None] * u, axis=1)))


def estimate_failure(t_s, est_xy, std_xy, truth_t_s, truth_xy, lock_t_s: float, switch_t_s: float,
                     bar_m: float = ESTIMATE_BAR_M, fused=None) -> dict | None:
    """Why a run's estimate fails the estimate bar (fwsim.analysis.metrics' definitions: the horizontal error, the
    larger horizontal std, convergence from :func:`fwsim.analysis.metrics.convergence_index`), or None when it meets
    it. ``est_xy`` / ``std_xy``: the estimate's east, north and their stds; the truth interpolated to the
    estimates' times; ``switch_t_s``: the last dive's start (NaN: none). Returns
    ``kind``: "never converged" (the last std at or over CONVERGED_STD_M) or "over 8 m" (after convergence);
    ``converged_s``: convergence after the lock (NaN when never); the largest error after convergence
    (``err_max_m``), how long after convergence it came (``err_max_after_s``), in which phase ("loiter" or
    "dive", from ``switch_t_s``) and the std then (``std_then_m``), and the time spent over ``bar_m`` after
    convergence (``over_s``: the estimates' spacing summed); for a run that never converged, the std at the end
    (``std_end_m``), the last time it was under CONVERGED_STD_M before the end (``under_last_s_before_end``,
    NaN: never after the lock), and the largest error from the dive's start (``err_max_dive_m``): what the bar
    would have counted had the std been under the threshold in the dive; with ``fused`` (per estimate: it fused
    a box), also the std at the last fused box (``std_last_box_m``) and how long before the end that box came
    (``last_box_s_before_end``), NaN without: a std already over the threshold there went over it with the
    boxes, not in the coast after them."""
    from fwsim.analysis.metrics import CONVERGED_STD_M, convergence_index, estimate_errors_m
    ok, err, std = estimate_errors_m(t_s, est_xy, std_xy, truth_t_s, truth_xy)
    if not ok.any():
        return None
    t = np.asarray(t_s, dtype=float)[ok]
    k = convergence_index(std)
    dive = t >= switch_t_s if math.isfinite(switch_t_s) else np.zeros(t.size, dtype=bool)
    dt = np.diff(t, append=t[-1])
    if k >= t.size:
        under = np.flatnonzero((std < CONVERGED_STD_M) & (t >= lock_t_s))
        boxes = np.flatnonzero(np.asarray(fused, dtype=bool)[ok]) if fused is not None else np.zeros(0, dtype=int)
        return {"kind": "never converged", "converged_s": math.nan, "std_end_m": float(std[-1]),
                "under_last_s_before_end": float(t[-1] - t[under[-1]]) if under.size else math.nan,
                "err_max_dive_m": float(np.max(err[dive])) if dive.any() else math.nan,
                "std_last_box_m": float(std[boxes[-1]]) if boxes.size else math.nan,
                "last_box_s_before_end": float(t[-1] - t[boxes[-1]]) if boxes.size else math.nan}
    after = err[k:]
    i = k + int(np.argmax(after))
    if not err[i] > bar_m:
        return None
    return {"kind": f"over {bar_m:g} m", "converged_s": float(t[k] - lock_t_s), "err_max_m": float(err[i]),
            "err_max_after_s": float(t[i] - t[k]), "phase": "dive" if dive[i] else "loiter",
            "std_then_m": float(std[i]), "over_s": float(np.sum(dt[k:][after > bar_m]))}


def _estimates(out_dir: Path, rows: list[dict]):
    """For each run that did not fail: (its row, (its /fsw/estimate and /target/state tables, the lock time,
    the last dive's start from the summary, NaN without one)), or (its row, the exception) when its log
    cannot be read."""
    from fwsim.interface import topics
    from fwsim.log.reader import read_log
    from fwsim.analysis.metrics import lock_time_s
    for r in rows:
        if r.get("status") == "failed":
            continue
        try:
            log = read_log(out_dir / r["log"])
            est, tru = log.table(topics.FSW_ESTIMATE), log.table(topics.TARGET_STATE)
            sw = r.get("switch_time_s")
            got = (est, tru, lock_time_s(log), float(sw) if isinstance(sw, (int, float)) else math.nan)
        except (OSError, KeyError, ValueError, IndexError) as exc:
            got = exc
        yield r, got


def why_estimate(out_dir: Path, rows: list[dict]) -> tuple[list[list[str]], dict]:
    """--why-estimate's table rows (strings), each run failing the estimate bar, from its log; and a tally:
    runs that never converged (and how many of them kept the error within the bar from the dive's start), and
    runs over the bar after convergence (how many within ``NEAR_CONVERGENCE_S`` of it, how many in the dive)."""
    from fwsim.analysis.metrics import CONVERGED_STD_M
    table, tally = [], defaultdict(int)
    for r, got in _estimates(out_dir, rows):
        f = got  # the log's exception, or the run's failure (None: it meets the bar)
        if not isinstance(got, BaseException):
            est, tru, lock_t, switch_t = got
            try:
                inn = est.get("innovation_px")  # a fused box's innovation; NaN on a tick without one
                fused = None if inn is None else np.all(np.isfinite(np.asarray(inn, dtype=float)), axis=1)
                f = estimate_failure(est["t_s"], est["pos_enu_m"][:, :2], est["pos_std_m"][:, :2], tru["t_s"],
                                     tru["pos_enu_m"][:, :2], lock_t, switch_t, fused=fused)
            except (KeyError, ValueError, IndexError) as exc:
                f = exc
        if isinstance(f, BaseException):
            table.append([str(r.get("id", "?")), f"(log: {type(f).__name__})"] + ["-"] * 10)
            continue
        if f is None:
            continue
        speed, fpa = r.get("set.target.speed_m_s"), r.get("set.controllers.bpng.impact_flight_path_deg")
        cells = [str(r.get("id", "?")), f["kind"], str(r.get("set.target.type", "-")),
                 f"{speed:.1f}" if isinstance(speed, (int, float)) else "-",
                 f"{fpa:.0f}" if isinstance(fpa, (int, float)) else "-"]
        if f["kind"] == "never converged":
            tally["never converged"] += 1
            tally["never converged, within the bar from the dive's start"] += f["err_max_dive_m"] <= ESTIMATE_BAR_M
            tally["never converged, the std over the threshold at the last fused box"] += \
                f["std_last_box_m"] >= CONVERGED_STD_M
            cells += ["-", "-", "-", f"{f['std_end_m']:.1f}",
                      f"{f['under_last_s_before_end']:.0f}" if math.isfinite(f["under_last_s_before_end"]) else "-",
                      f"{f['std_last_box_m']:.1f} ({f['last_box_s_before_end']:.1f} s before the end)"
                      if math.isfinite(f["std_last_box_m"]) else "-",
                      f"{f['err_max_dive_m']:.1f}" if math.isfinite(f["err_max_dive_m"]) else "-"]
        else:
            tally["over the bar"] += 1
            near = f["err_max_after_s"] <= NEAR_CONVERGENCE_S
            tally[f"over the bar, within {NEAR_CONVERGENCE_S:g} s of convergence"] += near
            tally["over the bar, in the dive"] += f["phase"] == "dive"
            cells += [f"{f['converged_s']:.0f}",
                      f"{f['err_max_m']:.1f} ({f['err_max_after_s']:.0f} s after, {f['phase']}, std "
                      f"{f['std_then_m']:.1f})", f"{f['over_s']:.1f}", "-", "-", "-", "-"]
        table.append(cells)
    return table, dict(tally)


def run_bars(row: dict) -> tuple[bool | None, ...]:
    """One run against each of :data:`BARS` (None: the bar does not count it, as fwsim report's statistics
    do not: a failed run has no view share; a run without an estimate is not in the estimate bar's count)."""
    def finite(key: str) -> float | None:
        v = row_value(row, key)  # (a summary from before the estimator metrics were renamed: ukf_*)
        return float(v) if isinstance(v, (int, float)) and math.isfinite(v) else None
    seen = finite("target_visible_fraction_after_lock")
    est = finite("estimator_pos_err_max_after_convergence_m")
    estimated = est is not None or finite("estimator_pos_rmse_m") is not None
    return (row.get("hit") == 1.0, within(row, 3.0, 3.0), None if seen is None else seen >= 0.99,
            None if not estimated else est is not None and est <= ESTIMATE_BAR_M)


def _pair_key(rows: list[dict]) -> dict[tuple, dict]:
    """Each row by (scenario, seed, its place among the rows of that scenario and seed): the same draw of
    the same spec in two folders (``fwsim batch`` names a draw by its scenario and seed; its id's hash also
    takes in the overrides, which --set and the estimator change)."""
    seen: dict[tuple, int] = defaultdict(int)
    out = {}
    for r in rows:
        k = (str(r.get("scenario", "")), r.get("seed"))
        out[k + (seen[k],)] = r
        seen[k] += 1
    return out


def paired(rows_a: list[dict], rows_b: list[dict], margin_m: float = PAIR_MARGIN_M) -> dict:
    """Two batches of the same draws, run by run (``--paired``): ``pairs`` (a, b) matched by
    :func:`_pair_key`; ``unmatched`` (runs of A without a counterpart in B, and of B in A); per bar of
    :data:`BARS` the runs that met it in A and not in B (``lost``) and the other way (``gained``); the runs
    whose miss distance went down (``better``) or up (``worse``) by more than ``margin_m`` (a run without a
    miss distance on one side counts as worse or better when the other has one), and the rest (``same``);
    ``differ``: the dispersed or --set columns (``set.*``) whose values differ in some pair, with an example
    (what was changed between the two, when the draws are the same)."""
    a, b = _pair_key(rows_a), _pair_key(rows_b)
    pairs = [(a[k], b[k]) for k in a if k in b]
    out = {"pairs": pairs, "unmatched": (sum(k not in b for k in a), sum(k not in a for k in b)),
           "lost": [[] for _ in BARS], "gained": [[] for _ in BARS], "better": [], "worse": [], "same": [],
           "differ": {}}
    for ra, rb in pairs:
        for i, (x, y) in enumerate(zip(run_bars(ra), run_bars(rb))):
            if x and y is False:
                out["lost"][i].append((ra, rb))
            elif x is False and y:
                out["gained"][i].append((ra, rb))
        ma, mb = _miss(ra), _miss(rb)
        if math.isnan(ma) and math.isnan(mb) or abs(mb - ma) <= margin_m:
            out["same"].append((ra, rb))
        else:
            worse = math.isnan(mb) or (math.isfinite(ma) and mb > ma)
            out["worse" if worse else "better"].append((ra, rb))
        for col in sorted(set(ra) | set(rb)):
            if col.startswith("set.") and col not in out["differ"] and ra.get(col) != rb.get(col):
                out["differ"][col] = (ra.get(col), rb.get(col))
    return out


def _miss(r: dict) -> float:
    """A run's miss distance, NaN when it has none."""
    m = r.get("miss_distance_m")
    return float(m) if isinstance(m, (int, float)) and math.isfinite(m) else math.nan


def _num(v) -> float:
    """A summary value as a float, NaN when it has none (null)."""
    return float(v) if isinstance(v, (int, float)) else math.nan


def _miss_cell(r: dict) -> str:
    m = _miss(r)
    return f"{m:.2f}" if math.isfinite(m) else "-"


def _bars_cell(r: dict) -> str:
    """A run's bars as four marks, in BARS' order: + met, - not, . not counted."""
    return "".join("." if x is None else "+" if x else "-" for x in run_bars(r))


def print_paired(dir_a: Path, rows_a: list[dict], dir_b: Path, rows_b: list[dict]) -> bool:
    """--paired's report; False when no run of one folder has a counterpart in the other."""
    p = paired(rows_a, rows_b)
    if not p["pairs"]:
        return False
    n = len(p["pairs"])
    print(f"\nRun by run, {dir_a} -> {dir_b}: {n} runs of the same scenario and seed in both"
          + (f" ({p['unmatched'][0]} of the first and {p['unmatched'][1]} of the second without a counterpart)"
             if any(p["unmatched"]) else "") + "\n")
    if p["differ"]:
        print("The set. columns that differ (one pair's values): "
              + "; ".join(f"{k}: {_label(x)} -> {_label(y)}" for k, (x, y) in p["differ"].items()) + "\n")
    print("| bar | met in the first | met in the second | lost (met in the first only) | "
          "gained (met in the second only) |")
    print("|---|---|---|---|---|")
    for i, (name, _) in enumerate(BARS):
        met = [sum(1 for pair in p["pairs"] if run_bars(pair[j])[i]) for j in (0, 1)]
        lost, gained = (", ".join(str(ra.get("id", "?")) for ra, _ in p[k][i]) for k in ("lost", "gained"))
        print(f"| {name} | {met[0]} | {met[1]} | {len(p['lost'][i])}{': ' + lost if lost else ''} | "
              f"{len(p['gained'][i])}{': ' + gained if gained else ''} |")
    print(f"\nMiss distance: better by over {PAIR_MARGIN_M:g} m in {len(p['better'])} runs, worse by over "
          f"{PAIR_MARGIN_M:g} m in {len(p['worse'])}, within {PAIR_MARGIN_M:g} m of each other in "
          f"{len(p['same'])}.\n")
    # each run that moved once (by its miss distance or a bar), best first; a miss distance lost last
    changed = {id(pair[0]): pair for pair in p["better"] + p["worse"]
               + [pair for i in range(len(BARS)) for pair in p["lost"][i] + p["gained"][i]]}

    def change(pair) -> float:
        d = _miss(pair[1]) - _miss(pair[0])
        return d if math.isfinite(d) else (math.inf if math.isnan(_miss(pair[1])) else -math.inf)
    if changed:
        print("| run (the first's id) | miss, m, first | miss, m, second | bars, first | bars, second | ship | "
              "motion | speed, m/s |")
        print("|---|---|---|---|---|---|---|---|")
        for ra, rb in sorted(changed.values(), key=change):
            speed = ra.get("set.target.speed_m_s")
            print(f"| {ra.get('id', '?')} | {_miss_cell(ra)} | {_miss_cell(rb)} | {_bars_cell(ra)} | "
                  f"{_bars_cell(rb)} | {ra.get('set.target.type', '-')} | "
                  f"{_label(ra.get('set.target.motion')) if ra.get('set.target.motion') is not None else '-'} | "
                  + (f"{speed:.1f}" if isinstance(speed, (int, float)) else "-") + " |")
        print("\n(bars: hits, within 3 m / 3 deg, seen >= 99 %, estimate <= 8 m; + met, - not, . not counted)")
    return True


def loiter_errors(t_s, est_pos_xy, est_vel_xy, truth_t_s, truth_pos_xy, truth_vel_xy, lock_t_s: float,
                  switch_t_s: float, settle_s: float = LOITER_SETTLE_S) -> tuple[float, float]:
    """(median horizontal position error, m; median horizontal velocity error, m/s) of the estimates from
    ``settle_s`` after the lock to the dive's start (``switch_t_s``; NaN: the run's end), the truth interpolated
    to their times; NaN when there is none."""
    from fwsim.log.truth import interp_at
    t = np.asarray(t_s, dtype=float)
    p, v = np.asarray(est_pos_xy, dtype=float), np.asarray(est_vel_xy, dtype=float)
    end = switch_t_s if math.isfinite(switch_t_s) else math.inf
    sel = (t >= lock_t_s + settle_s) & (t < end) & np.isfinite(p).all(axis=1) & np.isfinite(v).all(axis=1)
    if not sel.any():
        return math.nan, math.nan
    t = t[sel]
    pe = np.linalg.norm(p[sel] - interp_at(t, truth_t_s, np.asarray(truth_pos_xy, dtype=float)), axis=1)
    ve = np.linalg.norm(v[sel] - interp_at(t, truth_t_s, np.asarray(truth_vel_xy, dtype=float)), axis=1)
    return float(np.median(pe)), float(np.median(ve))


def loiter(out_dir: Path, rows: list[dict], by: str) -> list[list[str]]:
    """--loiter's table rows: for each value of ``by``, the runs and the median over them of each run's median
    loiter position and velocity error (:func:`loiter_errors`), from the logs."""
    groups: dict[str, list[tuple[float, float]]] = defaultdict(list)
    for r, got in _estimates(out_dir, rows):
        if isinstance(got, BaseException):
            continue
        est, tru, lock_t, switch_t = got
        try:
            errs = loiter_errors(est["t_s"], est["pos_enu_m"][:, :2], est["vel_enu_m_s"][:, :2], tru["t_s"],
                                 tru["pos_enu_m"][:, :2], tru["vel_enu_m_s"][:, :2], lock_t, switch_t)
        except (KeyError, ValueError, IndexError):
            continue
        if all(math.isfinite(e) for e in errs):
            groups[_label(r.get(by))].append(errs)
    table = []
    for name, errs in sorted(groups.items()):
        a = np.array(errs)
        table.append([name, str(len(errs)), f"{np.median(a[:, 0]):.1f}", f"{np.median(a[:, 1]):.2f}"])
    return table


def _failed_bar(row: dict) -> str:
    """Which of 3 m / 3 deg a run that is not within them (:func:`fwsim.analysis.report.within`) fails."""
    if row.get("hit") != 1.0:
        return "no hit"
    far = not _num(row.get("miss_distance_m")) <= 3.0
    off = not max(abs(_num(row.get("impact_fpa_error_deg"))), abs(_num(row.get("impact_heading_error_deg")))) <= 3.0
    return "distance and angle" if far and off else "distance" if far else "angle"


def _log_cell(log, needs: tuple[str, ...], make) -> str:
    """One --why cell from a log: ``make()`` when the log has the topics ``needs``; "-" without them or when
    ``make`` cannot read the log (a cell of its own: the row's other cells stay as they are)."""
    if not set(needs) <= set(log.topics):
        return "-"
    try:
        return make()
    except (KeyError, ValueError, IndexError):  # ScenarioError is a ValueError
        return "-"


def _aim_line_cell(log) -> str:
    """--why's aim-line cell for one log ("-" without a dive or a readable scenario)."""
    from fwsim.interface import topics
    from fwsim.analysis.metrics import LoggedShip
    from fwsim.scenario.model import parse_scenario

    def make() -> str:
        scenario = parse_scenario(log.effective_scenario_text or log.scenario_text, check_plugins=False)
        b, uav = log.table(topics.FSW_BPNG), log.table(topics.UAV_STATE)
        off = aim_line_offset(b["t_s"], b["aim_enu_m"], b["range_m"], uav["t_s"], uav["pos_enu_m"],
                              LoggedShip(log, scenario).aim_point_enu_m)
        return f"{off:.1f}" if math.isfinite(off) else "-"
    return _log_cell(log, (topics.FSW_BPNG, topics.TARGET_STATE), make)


def course_model(course_turn: dict) -> str:
    """--why's course-model cell from a log's ``/fsw/course_turn`` table (``controllers.turn_from_course``):
    what the block handed on at its last fit, which a dive holds: a zigzag's periodic course ("periodic 60 s,
    20 deg"), a steady turn ("turn +1.50 deg/s", clockwise) or "none"; "-" without a fit."""
    t = course_turn.get("t_s")
    if t is None or len(t) == 0:
        return "-"
    period = course_turn.get("period_s")  # logs before the periodic course have no such field
    if period is not None and math.isfinite(float(period[-1])):
        return f"periodic {float(period[-1]):.0f} s, {float(course_turn['amplitude_deg'][-1]):.0f} deg"
    rate = float(course_turn["turn_rate_deg_s"][-1])
    return f"turn {rate:+.2f} deg/s" if rate != 0.0 else "none"


def _status_index(table: dict, at_s: float) -> int:
    """The row of a status table (its ``t_s``) in force at ``at_s``: the last at or before it; -1 before the
    first."""
    return int(np.searchsorted(np.asarray(table.get("t_s", ()), dtype=float), at_s, side="right")) - 1


def heading_in_use(ship_heading: dict, truth_t_s, truth_heading_ned_rad, at_s: float) -> str:
    """--why's heading cell from a log's ``/fsw/ship_heading`` table: the ship's heading the shape correction
    used at ``at_s`` (the dive's start) and its error against the truth (deg, wrapped to +-180: near 180 is the
    bow and stern swapped), with the layout it used: "course +3 deg", "shapes -172 deg", or "unknown" (the
    offset averaged over headings: no course and the box shapes not yet trusted); ", other end" when the
    correction took the superstructure at the other end from the class's; "-" before the first status."""
    k = _status_index(ship_heading, at_s)
    if k < 0:
        return "-"
    truth = math.degrees(float(np.interp(float(ship_heading["t_s"][k]), np.asarray(truth_t_s, dtype=float),
                                         np.unwrap(np.asarray(truth_heading_ned_rad, dtype=float)))))
    course = float(ship_heading["course_deg"][k])
    if math.isfinite(course):
        source, heading = "course", course
    elif bool(ship_heading["in_use"][k]):
        source, heading = "shapes", float(ship_heading["best_heading_deg"][k])
    else:
        return "unknown"
    err = (heading - truth + 180.0) % 360.0 - 180.0
    layout = ship_heading.get("layout_in_use")
    other = layout is not None and str(layout[k]) == "other_end"
    return f"{source} {err:+.0f} deg" + (", other end" if other else "")


def size_over_ship(ship_heading: dict, at_s: float, class_dims_m, ship_dims_m) -> str:
    """--why's size cell from a log's ``/fsw/ship_heading`` table: the length, beam and height the correction
    used at ``at_s`` (the dive's start: the size fit's once in use, else the class's) over the ship's own
    (``ship_dims_m``, the truth), "1.02, 0.72, 1.71"; " (the class's)" when the fit was not in use; "-" before
    the first status."""
    k = _status_index(ship_heading, at_s)
    if k < 0:
        return "-"
    fitted = bool(ship_heading["size_in_use"][k])
    scale = np.asarray(ship_heading["size_scale"][k], dtype=float) if fitted else np.ones(3)
    ratio = scale * np.asarray(class_dims_m, dtype=float) / np.asarray(ship_dims_m, dtype=float)
    return ", ".join(f"{x:.2f}" for x in ratio) + ("" if fitted else " (the class's)")


def _size_cell(log) -> str:
    """--why's size cell for one log, at the dive's start ("-" without a dive, the topics or the scenario)."""
    from fwsim.interface import topics
    from fwsim.scenario.model import parse_scenario

    def make() -> str:
        sc = parse_scenario(log.effective_scenario_text or log.scenario_text, check_plugins=False)
        tm = sc.controllers.target_model
        return size_over_ship(log.table(topics.FSW_SHIP_HEADING), float(log.table(topics.FSW_BPNG)["t_s"][0]),
                              (tm.length_m, tm.width_m, tm.height_m),
                              (sc.target.length_m, sc.target.width_m, sc.target.height_m))
    return _log_cell(log, (topics.FSW_SHIP_HEADING, topics.FSW_BPNG), make)


def _heading_cell(log) -> str:
    """--why's heading cell for one log, at the dive's start ("-" without a dive or the topics)."""
    from fwsim.interface import topics
    def make() -> str:
        tru = log.table(topics.TARGET_STATE)
        return heading_in_use(log.table(topics.FSW_SHIP_HEADING), tru["t_s"], tru["heading_ned_rad"],
                              float(log.table(topics.FSW_BPNG)["t_s"][0]))
    return _log_cell(log, (topics.FSW_SHIP_HEADING, topics.FSW_BPNG, topics.TARGET_STATE), make)


def _course_model_cell(log) -> str:
    """--why's course-model cell for one log ("-" when the block was off or the log predates it)."""
    from fwsim.interface import topics
    return _log_cell(log, (topics.FSW_COURSE_TURN,), lambda: course_model(log.table(topics.FSW_COURSE_TURN)))


def why(out_dir: Path, rows: list[dict]) -> list[list[str]]:
    """--why's table rows (strings): each run outside 3 m / 3 deg, from its log."""
    from fwsim.interface import topics
    from fwsim.log.reader import read_log
    table = []
    for r in sorted(rows, key=lambda r: -float(r.get("miss_distance_m") or 0.0)):
        if within(r, 3.0, 3.0) or r.get("status") == "failed":
            continue
        bar = _failed_bar(r)
        motion = r.get("set.target.motion")
        hidden = r.get("target_hidden_longest_s_after_lock")
        cells = [str(r.get("id", "?")), bar, _miss_cell(r),
                 f"{_num(r.get('miss_bow_m')):+.1f}, {_num(r.get('miss_port_m')):+.1f}",
                 str(r.get("set.target.type", "-")), _label(motion) if motion is not None else "-",
                 f"{r['set.target.speed_m_s']:.1f}" if isinstance(r.get("set.target.speed_m_s"), (int, float))
                 else "-",
                 f"{hidden:.1f}" if isinstance(hidden, (int, float)) and math.isfinite(hidden) else "-"]
        no_log = ["-"] * (len(WHY_TIMES_S) + 7)  # the cells after the first one that says why
        try:
            log = read_log(out_dir / r["log"])
            lacking = [t for t in (topics.FSW_ESTIMATE, topics.TARGET_STATE, topics.UAV_STATE,
                                   topics.FSW_DETECTION_FUSION) if t not in log.topics]
            if lacking:  # a run that ended before its estimator (or its detections) began: say which topic
                table.append(cells + [f"(log: no {lacking[0]})"] + no_log)
                continue
            est, tru, uav = log.table(topics.FSW_ESTIMATE), log.table(topics.TARGET_STATE), log.table(topics.UAV_STATE)
            end = float(uav["t_s"][-1])
            errs = ship_frame_errors(est["t_s"], est["pos_enu_m"][:, :2], tru["t_s"], tru["pos_enu_m"][:, :2],
                                     tru["heading_ned_rad"], [end - dt for dt in WHY_TIMES_S] + [end])
            cells += [f"{b:+.1f}, {p:+.1f}" if math.isfinite(b) else "-" for b, p in errs]
            along, across = line_of_sight_error(est["t_s"], est["pos_enu_m"][:, :2], tru["t_s"], tru["pos_enu_m"],
                                                uav["t_s"], uav["pos_enu_m"])
            cells.append(f"{along:+.1f}, {across:+.1f}" if math.isfinite(along) else "-")
            fu = log.table(topics.FSW_DETECTION_FUSION)
            share, top = last_detections(fu["t_s"], fu["reason"], end)
            cells += [f"{100 * share:.0f} %" if math.isfinite(share) else "-", top or "-"]
            cells.append(_aim_line_cell(log))
            cells.append(_course_model_cell(log))
            cells.append(_heading_cell(log))
            cells.append(_size_cell(log))
        except (OSError, KeyError, ValueError, IndexError) as exc:
            cells += [f"(log: {type(exc).__name__})"] + no_log
        table.append(cells)
    return table


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dirs", type=Path, nargs="+", help="output folders of fwsim batch (with summary.json)")
    ap.add_argument("--by", default="set.controllers.estimator",
                    help="the summary column to group by (default: the estimator), or 'folder': one row per "
                         "output folder (e.g. the envelope and the same draws with a factor held: "
                         "fwsim batch --hold)")
    ap.add_argument("--why", action="store_true",
                    help="also list each run outside 3 m / 3 deg with its estimate's error and its last "
                         "detections (reads the logs)")
    ap.add_argument("--why-estimate", action="store_true",
                    help="also list each run failing the estimate bar: never converged (the std at the end, "
                         "the largest error from the dive's start) or over 8 m after convergence (when, in "
                         "which phase, the std then, for how long) (reads the logs)")
    ap.add_argument("--paired", action="store_true",
                    help="two folders of the same draws (the same spec and --seed; another estimator, a --set "
                         "or --hold, or the code before and after a change): also compare them run by run, "
                         "each bar's runs lost and gained and the miss distances that moved")
    ap.add_argument("--loiter", metavar="COLUMN", nargs="?", const="set.target.motion", default=None,
                    help="also give, per value of COLUMN (default: the ship's motion), the median over the runs "
                         "of each run's median horizontal position and velocity error in the loiter (from 60 s "
                         "after the lock to the dive): how well each estimator follows the ship's motion, apart "
                         "from the dive's close-in errors (reads the logs)")
    args = ap.parse_args(argv)
    if args.paired and len(args.out_dirs) != 2:
        print(f"error: --paired compares two folders, got {len(args.out_dirs)}", file=sys.stderr)
        return 2
    from fwsim.analysis.report import ReportError, load_summary
    rows, per_dir = [], []
    for out_dir in args.out_dirs:
        try:
            these = load_summary(out_dir)[1]
        except (ReportError, OSError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        rows += [{**r, "folder": str(out_dir)} for r in these] if args.by == "folder" else these
        per_dir.append((out_dir, these))
    table = verdict(rows, args.by)
    print(f"| {args.by} | runs | " + " | ".join(f"{name} (bar {100 * bar:.0f} %)" for name, bar in BARS)
          + " | in the field of view >= 99 % (the airframe's shadow not counted)"
          + " | estimate within 2 std, median run (honest: 86 % for a round error, up to 95 % for a long thin one) |")
    print("|---|---|" + "---|" * (len(BARS) + 2))
    ok, unscored = True, False
    for name, n, shares, cover, in_fov in table:
        cells = []
        for share, (_, bar) in zip(shares, BARS):
            if not math.isfinite(share):
                ok, unscored = False, True
                cells.append("- (not scored)")
                continue
            met = share >= bar - 1e-12
            ok &= met
            cells.append(f"{100 * share:.0f} %" + ("" if met else " (not met)"))
        cells.append(f"{100 * in_fov:.0f} %" if math.isfinite(in_fov) else "-")
        cells.append(f"{100 * cover:.0f} %" if math.isfinite(cover) else "-")
        print(f"| {name} | {n} | " + " | ".join(cells) + " |")
    if unscored:
        print("\nnote: a bar is not scored: its rows predate the metric it needs (the ship seen: "
              "target_visible_fraction_after_lock); `fwsim batch SPEC --out DIR --resume` scores the logs again "
              "without flying them", file=sys.stderr)
    if args.paired and not print_paired(per_dir[0][0], per_dir[0][1], per_dir[1][0], per_dir[1][1]):
        print(f"error: --paired: no run of {per_dir[0][0]} has the scenario and seed of one of {per_dir[1][0]} "
              "(not the same spec and --seed?)", file=sys.stderr)
        return 2
    if args.loiter:
        for out_dir, these in per_dir:
            print(f"\nThe estimate in the loiter ({LOITER_SETTLE_S:g} s after the lock to the dive) in {out_dir}, "
                  f"by {args.loiter}:\n")
            print(f"| {args.loiter} | runs | position error, m (median run's median) | "
                  "velocity error, m/s (median run's median) |")
            print("|---|---|---|---|")
            for cells in loiter(out_dir, these, args.loiter):
                print("| " + " | ".join(cells) + " |")
    if args.why:
        head = ["run", "outside by", "miss, m", "miss (bow, port), m", "ship", "motion", "speed, m/s",
                "longest hidden after lock, s"] + [
            f"estimate error (bow, port) {dt:g} s before the end, m" for dt in WHY_TIMES_S] + [
            "estimate error (bow, port) at the end, m",
            f"estimate error (along, across the line of sight) {LOS_RANGE_M:g} m out, m",
            f"detections fused, last {WHY_WINDOW_S:g} s (the coast's left out)", "commonest reason for the rest",
            f"the line to the steered-to point passes the aim point by, {AIM_LINE_RANGES_M[1]:g}-"
            f"{AIM_LINE_RANGES_M[0]:g} m out, m",
            "the course model handed on into the dive (turn_from_course: a zigzag's periodic course, a steady "
            "turn, none)",
            "the ship's heading the shape correction used at the dive's start, its error (from the course, from "
            "the box shapes, or unknown)",
            "the length, beam and height the correction used at the dive's start, over the ship's own (the size "
            "fit's, or the class's)"]
        for out_dir, these in per_dir:
            print(f"\nRuns outside 3 m / 3 deg in {out_dir} (worst first):\n")
            print("| " + " | ".join(head) + " |")
            print("|" + "---|" * len(head))
            for cells in why(out_dir, these):
                print("| " + " | ".join(cells) + " |")
    if args.why_estimate:
        head = ["run", "fails by", "ship", "speed, m/s", "theta_f, deg", "converged, s after lock",
                "largest error after it, m (when, phase, the std then)", f"time over {ESTIMATE_BAR_M:g} m, s",
                "std at the end, m", "std last under 5 m, s before the end",
                "std at the last fused box, m (when)", "largest error from the dive's start, m"]
        for out_dir, these in per_dir:
            table, tally = why_estimate(out_dir, these)
            print(f"\nRuns failing the estimate bar in {out_dir}:\n")
            print("| " + " | ".join(head) + " |")
            print("|" + "---|" * len(head))
            for cells in table:
                print("| " + " | ".join(cells) + " |")
            print("\n" + "; ".join(f"{k}: {v}" for k, v in tally.items()) if tally else "\nnone")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
