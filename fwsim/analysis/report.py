"""``fwsim report BATCH_OUT``: the statistics of a batch (a Monte Carlo study) as one self-contained HTML page.

Reads ``summary.json`` of a ``fwsim batch`` output folder and writes
``report.html`` beside it (figures embedded as PNG data, no network needed to
view it). The headline, also printed:

* runs, completed, failed;
* hits, and the hit probability with its 95 % Wilson score interval;
* CEP50 / CEP90: the 50th and 90th percentiles of the miss distance (the
  closest approach to the aim point, ``fwsim.analysis.metrics``; the median and 90th
  percentile radius, not a fitted distribution);
* the impact flight-path and heading errors: mean, standard deviation and the
  95th percentile of their magnitude;
* the time in view after the lock (in the field of view) and the time the ship
  was seen (in view and not hidden behind the UAV's own airframe), and the
  estimator's worst error after convergence;
* failures and non-hits by reason; the runs that never dived (never reached
  the terminal phase: no miss distance, not a hit), how many and why; the
  miss and angle statistics are over the runs that dived;
* what was flown: the fwsim version, the spec (its path, SHA-256 and text as
  the batch recorded them), the seeds and the dates the batch and the report
  were made.

Figures: the miss in the ship's frame, histograms, each metric against each
dispersed input (``summary.json``'s ``batch.dispersed``), and the worst runs
with the command that replays each one in Rerun.
"""
from __future__ import annotations

import base64
import html
import io
import json
import math
import re
from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

__all__ = ["wilson_interval", "Report", "summarise", "within", "write_report", "ReportError", "never_dived",
           "row_value", "provenance", "seed_ranges"]

Z95 = 1.959963984540054  # the standard normal's 97.5th percentile


class ReportError(ValueError):
    """A folder that holds no batch summary to report on."""


def wilson_interval(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """The Wilson score interval of a binomial proportion (95 % by default); (nan, nan) for n = 0."""
    if n <= 0:
        return math.nan, math.nan
    p = successes / n
    denom = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1.0 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def row_value(row: dict, key: str):
    """A row's metric; a summary written before the estimator metrics were renamed has them as ``ukf_*``."""
    if key in row or not key.startswith("estimator_"):
        return row.get(key)
    return row.get("ukf_" + key.removeprefix("estimator_"))


def never_dived(row: dict) -> bool:
    """A completed run that never reached the terminal phase (no miss distance: ``terminal_note``; in a summary
    from before that note, no switch time and an end other than an impact)."""
    if row.get("status") != "completed":
        return False
    note = row.get("terminal_note")
    if note is not None:
        return str(note).startswith("no terminal phase")
    return ("switch_time_s" in row and not _finite([row], "switch_time_s").size
            and not str(row.get("reason") or "").startswith(("hit the ship", "sea contact")))


def _why_no_dive(row: dict) -> str:
    """Where a run that never dived ended, without its times (so that runs group): e.g. ``ended in phase 2
    (loiter:nmpc), duration reached``."""
    note = str(row.get("terminal_note") or "")
    if not note:
        return f"ended without a switch ({str(row.get('reason') or '')[:60]})"
    text = re.sub(r" (after|at t =) [0-9.]+ s", "", note.split(": ", 1)[-1].removeprefix("the run "))
    return re.sub(r" \(([^()]*)\)$", r", \1", text)  # the end reason after a comma


def _finite(rows: list[dict], key: str) -> np.ndarray:
    vals = [row_value(r, key) for r in rows]
    return np.array([float(v) for v in vals if isinstance(v, (int, float)) and not isinstance(v, bool)
                     and math.isfinite(v)], dtype=float)


def _pct(x: np.ndarray, q: float) -> float:
    return float(np.percentile(x, q)) if x.size else math.nan


@dataclass
class Report:
    """The headline statistics of a batch (see the module text)."""

    name: str
    runs: int
    completed: int
    hits: int
    hit_probability: float
    hit_interval_95: tuple[float, float]
    cep50_m: float
    cep90_m: float
    angle_errors: dict[str, dict[str, float]]  # fpa / heading -> mean, std, p95_abs
    in_view_after_lock: dict[str, float]  # mean, min, share of runs >= 0.99
    # median, p90, share of the runs with an estimate <= 8 m (never converged: not <= 8 m); consistency (the median
    # run's share of estimates within 2 std of their error, the worst run's)
    estimator_error_m: dict[str, float]
    outcomes: dict[str, int]  # failures and non-hits by reason
    dispersed: list[str] = field(default_factory=list)
    within_3m_3deg: float = math.nan  # share of runs that hit within 3 m of the aim point and 3 deg of both angles
    # in view and not behind the airframe: mean, min, share of runs >= 0.99, the longest stretch hidden (worst run,
    # s); NaN where the rows predate target_visible_fraction_after_lock
    visible_after_lock: dict[str, float] = field(default_factory=dict)
    dived: int = 0  # completed runs that reached the terminal phase (the miss and angle statistics are over them)
    never_dived: dict[str, int] = field(default_factory=dict)  # why (where they ended) -> runs
    flown: list[tuple[str, str]] = field(default_factory=list)  # what was flown: (name, value) rows

    def _miss_rows(self) -> list[tuple[str, str]]:
        n_never = sum(self.never_dived.values())
        if not self.dived:
            return [("miss distance CEP50 / CEP90", "— (no run dived)")]
        over = f" over the {self.dived} runs that dived" if n_never else ""
        return [("miss distance CEP50 / CEP90", f"{_f(self.cep50_m)} m / {_f(self.cep90_m)} m{over}")]

    def _never_rows(self) -> list[tuple[str, str]]:
        n = sum(self.never_dived.values())
        if not n:
            return []
        why = "; ".join(f"{k} ({v})" for k, v in self.never_dived.items())
        return [("never dived (no miss distance, not a hit)", f"{n} of {self.runs} runs: {why}")]

    def headline(self) -> list[tuple[str, str]]:
        """(name, value) rows of the headline table."""
        lo, hi = self.hit_interval_95
        rows = [("runs", f"{self.runs} ({self.completed} completed)"),
                ("hits", f"{self.hits} of {self.runs}: P(hit) = {_f(self.hit_probability, '{:.3f}')} "
                         f"(95 % Wilson interval {_f(lo, '{:.3f}')} to {_f(hi, '{:.3f}')})"),
                *self._never_rows(), *self._miss_rows(),
                ("hits within 3 m and 3 deg of both impact angles",
                 f"{_f(100 * self.within_3m_3deg, '{:.0f}')} % of runs "
                 f"({round(self.within_3m_3deg * self.runs) if self.runs else 0} of {self.runs})")]
        for name, s in self.angle_errors.items():
            rows.append((f"impact {name} error", "— (no run dived)" if not self.dived else
                         f"mean {_f(s['mean'], '{:+.2f}')} deg, std {_f(s['std'])} deg, "
                         f"|error| p95 {_f(s['p95_abs'])} deg"))
        v = self.in_view_after_lock
        rows.append(("ship in view after lock", f"mean {_f(100 * v['mean'], '{:.1f}')} %, worst "
                                                f"{_f(100 * v['min'], '{:.1f}')} %, "
                                                f"{_f(100 * v['share_99'], '{:.0f}')} % of runs >= 99 %"))
        v = self.visible_after_lock
        if math.isfinite(v.get("mean", math.nan)):
            rows.append(("ship seen after lock (in view, not behind the airframe)",
                         f"mean {100 * v['mean']:.1f} %, worst {100 * v['min']:.1f} %, "
                         f"{100 * v['share_99']:.0f} % of runs >= 99 %; longest hidden "
                         f"{_f(v['longest_hidden_s'], '{:.1f}')} s"))
        e = self.estimator_error_m
        rows.append(("estimator error after convergence (worst per run)",
                     f"median {_f(e['median'], '{:.1f}')} m, p90 {_f(e['p90'], '{:.1f}')} m, "
                     f"{_f(100 * e['share_8m'], '{:.0f}')} % of runs <= 8 m"))
        if math.isfinite(e.get("within_2std_median", math.nan)):
            rows.append(("estimator consistency (error within 2 std)",
                         f"median {100 * e['within_2std_median']:.0f} % of a run's estimates, worst run "
                         f"{100 * e['within_2std_min']:.0f} % (an honest filter: about 86 % or more)"))
        rows.append(("outcomes", ", ".join(f"{k}: {n}" for k, n in self.outcomes.items()) or "none"))
        return rows


def _f(x: float, fmt: str = "{:.2f}") -> str:
    """A statistic as text; "—" when there is none (NaN)."""
    return fmt.format(x) if isinstance(x, (int, float)) and math.isfinite(x) else "—"


def _outcome(row: dict) -> str:
    if row.get("status") != "completed":
        return f"{row.get('status')}: {str(row.get('error') or row.get('reason') or '')[:80]}"
    if never_dived(row):
        return f"no dive: {_why_no_dive(row)}"
    if row.get("hit") == 1.0:
        return "hit after going round" if (row.get("go_arounds") or 0) > 0 else "hit"
    reason = str(row.get("reason") or "")
    return "no hit: " + ("sea contact" if reason.startswith("sea contact") else reason[:80])


def summarise(rows: list[dict], name: str = "", dispersed: list[str] | None = None) -> Report:
    """The headline statistics of a batch's rows (``summary.json``'s ``rows``)."""
    n = len(rows)
    dived = [r for r in rows if r.get("status") == "completed" and not never_dived(r)]
    hits = sum(1 for r in dived if r.get("hit") == 1.0)  # a run that never dived is not a hit
    miss = _finite(dived, "miss_distance_m")
    angles = {}
    for label, key in (("flight-path", "impact_fpa_error_deg"), ("heading", "impact_heading_error_deg")):
        x = _finite(dived, key)
        angles[label] = {"mean": float(x.mean()) if x.size else math.nan,
                         "std": float(x.std(ddof=1)) if x.size > 1 else math.nan,
                         "p95_abs": _pct(np.abs(x), 95)}
    view = _finite(rows, "target_in_fov_fraction_after_lock")
    seen = _finite(rows, "target_visible_fraction_after_lock")
    hidden = _finite(rows, "target_hidden_longest_s_after_lock")
    est = _finite(rows, "estimator_pos_err_max_after_convergence_m")
    cover = _finite(rows, "estimator_pos_err_within_2std_fraction")
    # the runs with an estimate: one whose estimate never converged (its own std never stayed under 5 m) has no
    # error after convergence, and counts against the share within 8 m instead of dropping out of it
    estimated = sum(1 for r in rows if _finite([r], "estimator_pos_err_max_after_convergence_m").size
                    or _finite([r], "estimator_pos_rmse_m").size)
    return Report(
        name=name, runs=n, completed=sum(1 for r in rows if r.get("status") == "completed"), hits=hits,
        hit_probability=hits / n if n else math.nan, hit_interval_95=wilson_interval(hits, n),
        cep50_m=_pct(miss, 50), cep90_m=_pct(miss, 90), angle_errors=angles,
        in_view_after_lock=_view_shares(view),
        estimator_error_m={"median": _pct(est, 50), "p90": _pct(est, 90),
                           "share_8m": float(np.sum(est <= 8.0)) / estimated if estimated else math.nan,
                           "within_2std_median": _pct(cover, 50),
                           "within_2std_min": float(cover.min()) if cover.size else math.nan},
        outcomes=dict(Counter(_outcome(r) for r in rows).most_common()), dispersed=list(dispersed or []),
        within_3m_3deg=sum(1 for r in rows if within(r, 3.0, 3.0)) / n if n else math.nan,
        visible_after_lock=dict(_view_shares(seen),
                                longest_hidden_s=float(hidden.max()) if hidden.size else math.nan),
        dived=len(dived), never_dived=dict(Counter(_why_no_dive(r) for r in rows if never_dived(r)).most_common()))


def _view_shares(x: np.ndarray) -> dict[str, float]:
    """mean, min and the share of runs >= 0.99 of per-run fractions of the time (NaN without any)."""
    return {"mean": float(x.mean()) if x.size else math.nan, "min": float(x.min()) if x.size else math.nan,
            "share_99": float(np.mean(x >= 0.99)) if x.size else math.nan}


def within(row: dict, miss_m: float, angle_deg: float) -> bool:
    """A hit within ``miss_m`` of the aim point and ``angle_deg`` of both commanded impact angles."""
    try:
        return (row.get("hit") == 1.0 and float(row["miss_distance_m"]) <= miss_m
                and abs(float(row["impact_fpa_error_deg"])) <= angle_deg
                and abs(float(row["impact_heading_error_deg"])) <= angle_deg)
    except (KeyError, TypeError, ValueError):
        return False


# -- figures ------------------------------------------------------------------

def _png(fig) -> str:
    import matplotlib.pyplot as plt
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _view_limit(values: np.ndarray, floor: float) -> float:
    """A plotting range that shows the bulk of ``values`` (3x their 90th percentile of magnitude, at least
    ``floor``): the outliers go to the border, marked, instead of squeezing the rest into a dot."""
    v = np.abs(values[np.isfinite(values)])
    return max(floor, 3.0 * float(np.percentile(v, 90))) if v.size else floor


def _miss_scatter(rows: list[dict], rep: Report) -> str:
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(5.5, 5.0))
    pts = [(r.get("miss_port_m"), r.get("miss_bow_m"), r.get("hit") == 1.0) for r in _dived(rows)]
    pts = np.array([(-x, y, h) for x, y, h in pts if isinstance(x, (int, float)) and isinstance(y, (int, float))
                    and math.isfinite(x) and math.isfinite(y)], dtype=float).reshape(-1, 3)
    lim = 1.1 * max(_view_limit(np.hypot(pts[:, 0], pts[:, 1]), 3.0), rep.cep90_m if math.isfinite(rep.cep90_m)
                    else 0.0)
    off = np.maximum(np.abs(pts[:, 0]), np.abs(pts[:, 1])) > lim
    for hit, colour, label in ((1.0, "tab:blue", "hit"), (0.0, "tab:red", "no hit")):
        sel = (pts[:, 2] == hit) & ~off
        if sel.any():
            ax.scatter(pts[sel, 0], pts[sel, 1], s=14, c=colour, label=label)
    for r, style, label in ((rep.cep50_m, "-", "CEP50"), (rep.cep90_m, "--", "CEP90")):
        if math.isfinite(r):
            ax.add_patch(plt.Circle((0, 0), r, fill=False, ls=style, color="k", label=f"{label} {r:.2f} m"))
    if off.any():
        edge = np.clip(pts[off, :2], -lim * 0.97, lim * 0.97)
        ax.scatter(edge[:, 0], edge[:, 1], marker="x", c="tab:red", label=f"{int(off.sum())} beyond the frame")
    ax.set(xlim=(-lim, lim), ylim=(-lim, lim), aspect="equal", xlabel="starboard (m)", ylabel="towards the bow (m)",
           title="closest approach to the aim point, ship frame")
    ax.axhline(0, color="0.8", lw=0.8)
    ax.axvline(0, color="0.8", lw=0.8)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="upper right", fontsize=8)
    return _png(fig)


_HISTOGRAMS = (("miss_distance_m", "miss distance (m)"), ("impact_fpa_error_deg", "impact flight-path error (deg)"),
               ("impact_heading_error_deg", "impact heading error (deg)"),
               ("estimator_pos_err_max_after_convergence_m", "estimator error after convergence, worst (m)"),
               ("target_hidden_longest_s_after_lock", "longest stretch unseen after lock (s)"))


def _dived(rows: list[dict]) -> list[dict]:
    return [r for r in rows if not never_dived(r)]


def _histograms(rows: list[dict]) -> str:
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(_HISTOGRAMS), figsize=(4.0 * len(_HISTOGRAMS), 3.0))
    for ax, (key, label) in zip(axes, _HISTOGRAMS):
        x = _finite(_dived(rows) if key.startswith(("miss", "impact")) else rows, key)
        if x.size:
            lim = _view_limit(x, 1.0)
            inside = x[np.abs(x) <= lim]
            ax.hist(inside, bins=min(30, max(5, inside.size // 3)), color="tab:blue", alpha=0.8)
            if inside.size < x.size:
                ax.set_title(f"{x.size - inside.size} beyond {lim:.3g}", fontsize=8)
        ax.set(xlabel=label, ylabel="runs")
    fig.tight_layout()
    return _png(fig)


def _input_columns(rows: list[dict], dispersed: list[str]) -> list[tuple[str, list[float]]]:
    """(label, value per row) of each dispersed input; a vector input gives one column per element."""
    out = []
    for path in dispersed:
        vals = [r.get(f"set.{path}") for r in rows]
        if all(isinstance(v, list) for v in vals) and vals:
            for i in range(min(len(v) for v in vals)):
                col = [float(v[i]) for v in vals]
                if np.ptp(col) > 0:
                    out.append((f"{path}[{i}]", col))
        elif all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in vals) and vals:
            out.append((path, [float(v) for v in vals]))
    return out


def _versus_inputs(rows: list[dict], dispersed: list[str]) -> str | None:
    import matplotlib.pyplot as plt
    inputs = _input_columns(rows, dispersed)
    if not inputs:
        return None
    metrics = (("miss_distance_m", "miss (m)"), ("impact_fpa_error_deg", "fpa err (deg)"),
               ("impact_heading_error_deg", "heading err (deg)"))
    fig, axes = plt.subplots(len(metrics), len(inputs), figsize=(3.2 * len(inputs), 2.6 * len(metrics)),
                             squeeze=False)
    hit = np.array([r.get("hit") == 1.0 for r in rows])
    for j, (label, x) in enumerate(inputs):
        x = np.asarray(x)
        for i, (key, ylabel) in enumerate(metrics):
            y = np.array([float(r[key]) if isinstance(r.get(key), (int, float)) else math.nan for r in rows])
            lim = _view_limit(y, 1.0)
            off = np.abs(y) > lim
            y = np.clip(y, -lim, lim)  # outliers at the border, marked x
            ax = axes[i][j]
            ax.scatter(x[hit & ~off], y[hit & ~off], s=10, c="tab:blue")
            ax.scatter(x[~hit & ~off], y[~hit & ~off], s=12, c="tab:red")
            ax.scatter(x[off], y[off], s=14, marker="x", c="tab:red" if (~hit[off]).any() else "tab:blue")
            if i == len(metrics) - 1:
                ax.set_xlabel(label, fontsize=8)
            if j == 0:
                ax.set_ylabel(ylabel)
    fig.tight_layout()
    return _png(fig)


def worst_runs(rows: list[dict], n: int = 10) -> list[dict]:
    """The n worst runs: failed first, then no hit, then the largest misses."""
    def badness(r: dict) -> tuple:
        miss = r.get("miss_distance_m")
        miss = float(miss) if isinstance(miss, (int, float)) and math.isfinite(miss) else math.inf
        return (r.get("status") == "completed", r.get("hit") == 1.0, -miss)
    return sorted(rows, key=badness)[:n]


# -- the page -----------------------------------------------------------------

_CSS = ("body{font-family:sans-serif;max-width:1200px;margin:2em auto;color:#222}"
        "table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #ccc;padding:4px 8px;text-align:left}"
        "th{background:#f3f3f3}code{background:#f6f6f6;padding:1px 4px}img{max-width:100%}")


def _table(header: list[str] | None, rows: list[list[str]]) -> str:
    head = "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>" if header else ""
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table>{head}{body}</table>"


def _page(rep: Report, rows: list[dict], figures: list[tuple[str, str]], out_dir: Path, spec_text: str = "") -> str:
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>fwsim report: {html.escape(rep.name)}"
             f"</title><style>{_CSS}</style></head><body>",
             f"<h1>fwsim report: {html.escape(rep.name)}</h1>",
             _table(None, [[f"<b>{html.escape(k)}</b>", html.escape(v)] for k, v in rep.headline()]),
             "<h2>What was flown</h2>",
             _table(None, [[f"<b>{html.escape(k)}</b>", html.escape(v)] for k, v in rep.flown])]
    if spec_text:
        parts.append(f"<details><summary>the spec as the batch read it</summary><pre>{html.escape(spec_text)}"
                     "</pre></details>")
    if rep.dispersed:
        parts.append("<p>Dispersed inputs: " + ", ".join(f"<code>{html.escape(p)}</code>" for p in rep.dispersed)
                     + "</p>")
    for title, png in figures:
        parts.append(f"<h2>{html.escape(title)}</h2><img alt='{html.escape(title)}' src='data:image/png;base64,{png}'>")
    worst = []
    for r in worst_runs(rows):
        log = str(r.get("log") or "")
        if log and not Path(log).is_absolute():  # the summary's paths are relative to its folder
            log = str((out_dir / log).resolve())
        rrd = str(Path(log).with_suffix(".rrd")) if log else ""
        cmd = f"fwsim replay {log} --rrd {rrd} && rerun {rrd}" if log else ""
        miss = None if never_dived(r) else r.get("miss_distance_m")
        worst.append([html.escape(str(r.get("id"))), html.escape(_outcome(r)),
                      f"{miss:.2f}" if isinstance(miss, (int, float)) and math.isfinite(miss) else "—",
                      f"<code>{html.escape(cmd)}</code>"])
    parts.append("<h2>Worst runs</h2>" + _table(["run", "outcome", "miss (m)", "replay in Rerun"], worst))
    parts.append(f"<p>From <code>{html.escape(str(out_dir / 'summary.json'))}</code>.</p></body></html>")
    return "\n".join(parts)


def load_summary(out_dir: str | Path) -> tuple[dict, list[dict]]:
    """(batch info, rows) of a batch output folder; ReportError (one line) if it has no usable summary."""
    path = Path(out_dir) / "summary.json"
    if not path.is_file():
        raise ReportError(f"{out_dir}: no summary.json (the output folder of `fwsim batch`)")
    try:
        data = json.loads(path.read_text())
        info, rows = data.get("batch") or {}, data["rows"]
    except (ValueError, KeyError, TypeError, AttributeError) as exc:
        raise ReportError(f"{path}: not a batch summary ({type(exc).__name__}: {str(exc)[:80]})") from None
    if not isinstance(rows, list) or not rows or not all(isinstance(r, dict) for r in rows):
        raise ReportError(f"{path}: holds no runs")
    return info, rows


def seed_ranges(seeds) -> str:
    """Integer seeds as sorted ranges: ``1-8, 10``."""
    vals = sorted({int(x) for x in seeds if isinstance(x, (int, float)) and not isinstance(x, bool)})
    parts, i = [], 0
    while i < len(vals):
        j = i
        while j + 1 < len(vals) and vals[j + 1] == vals[j] + 1:
            j += 1
        parts.append(str(vals[i]) if i == j else f"{vals[i]}-{vals[j]}")
        i = j + 1
    return ", ".join(parts) or "—"


def provenance(info: dict, rows: list[dict]) -> tuple[list[tuple[str, str]], str]:
    """(what was flown as (name, value) rows, the spec's text) from a summary's batch record: the versions, the
    spec (path, SHA-256, and whether the file still holds it), the seeds, the dates."""
    import hashlib

    import fwsim
    spec, text, digest = str(info.get("spec") or ""), str(info.get("spec_text") or ""), info.get("spec_sha256")
    now = ""
    if spec and Path(spec).is_file():
        data = Path(spec).read_bytes()
        now = hashlib.sha256(data).hexdigest()
        text = text or data.decode("utf-8", "replace")
    state = ("" if not digest or not now else ", the file unchanged since" if now == digest
             else ", the file has changed since (the text below is the one flown)")
    flown = [("spec", (spec or "—") + (f" (SHA-256 {digest or now}{state})" if digest or now else "")),
             ("seeds", f"{seed_ranges(r.get('seed') for r in rows)} ({len(rows)} runs)"),
             ("flown with", f"fwsim {info.get('fwsim_version') or '?'}, batch written "
                            f"{info.get('written_utc') or '?'}"),
             ("report made", f"{datetime.now(timezone.utc).isoformat(timespec='seconds')} by fwsim "
                             f"{fwsim.__version__}")]
    if info.get("changes"):
        flown.insert(2, ("changes to the spec", str(info["changes"])))
    return flown, text


def write_report(out_dir: str | Path) -> tuple[Report, Path]:
    """Summarise the batch in ``out_dir`` and write ``out_dir/report.html``; (report, path)."""
    import matplotlib
    matplotlib.use("Agg")
    out_dir = Path(out_dir)
    info, rows = load_summary(out_dir)
    rep = summarise(rows, str(info.get("name") or out_dir.name), info.get("dispersed") or [])
    rep.flown, spec_text = provenance(info, rows)
    figures = [("Where the misses go", _miss_scatter(rows, rep)), ("Distributions", _histograms(rows))]
    versus = _versus_inputs(rows, rep.dispersed)
    if versus is not None:
        figures.append(("Each metric against each dispersed input (red: no hit)", versus))
    path = out_dir / "report.html"
    path.write_text(_page(rep, rows, figures, out_dir, spec_text), encoding="utf-8")
    return rep, path
