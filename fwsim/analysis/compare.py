"""Compare the metrics of two runs with tolerances; regression baselines.

A metrics source is a run log (``.mcap``: metrics computed with
:func:`fwsim.analysis.metrics.compute_metrics`), a metrics file (``.json`` from
``fwsim metrics --json``) or a baseline file (``.yaml``, below).

Tolerances, per metric (``TOLERANCE_KEYS``)::

    roll_rate_err_rms_deg_s: {rel: 1.0e-5}          # |run - base| <= 1e-5 * |base|
    height_min_m: {abs: 1.0e-3}                     # |run - base| <= 1 mm
    sideslip_abs_max_deg: {abs: 1.0e-3, rel: 1.0e-5}  # within the larger of the two
    bank_abs_max_deg: {min: 0, max: 45}             # bounds on the run's value only
    end_reason: {ignore: true}                      # not compared
    default: {rel: 1.0e-5}                          # every metric without its own entry

``abs``/``rel`` give the allowed difference ``max(abs, rel * |baseline|)``;
``min``/``max`` bound the run's value whatever the baseline; with bounds but
no ``abs``/``rel`` only the bounds are checked; with neither the values must
be equal. Text metrics (``status``, ``end_reason``) must match exactly unless
ignored. A missing value (NaN, ``null``) equals a missing value.

Verdicts. A change beyond the tolerance is labelled by the metric's better
direction (``fwsim.analysis.metrics.METRICS``: lower, higher, nearer zero, or neither):

* ``ok``: within the tolerance;
* ``improved``: beyond it in the better direction (reported; fails only with
  ``strict``, as the baseline tests and ``tools/refresh_baselines.py --check``
  use it: a baseline records behaviour, and a change for the better is
  refreshed on purpose too);
* ``REGRESSION``: beyond it in the worse direction, or outside ``min``/``max``;
* ``CHANGED``: beyond it for a metric with no better direction, text that
  differs, or a value on one side only;
* ``missing`` (in the baseline, not in the run), ``new`` (in the run only),
  ``ignored``.

A comparison fails on any REGRESSION, CHANGED or missing metric (and, strict,
on an improved one).

A/B (``fwsim compare A B --ab``, :func:`ab_compare`): two runs of the same
flight with something changed (a filter, a gain). Per metric, which run is
better by the metric's direction and by how much (B minus A, and relative to
A); "same" within the tolerance (default ``AB_SAME``: equal to rounding, or
the ``--tolerances`` file's); it ends with a count (B better on N, worse on M,
same on K).

A baseline file (``tests/baselines/<scenario>.yaml``) holds the tolerances
inside it, under ``tolerances:``, beside the scenario it flies and its
metrics::

    description: ...
    scenario: ../../scenarios/autopilot_checkout.yaml   # relative to this file
    overrides: {duration_s: 60}                         # dotted scenario paths
    tolerances: {...}
    # ---- written by tools/refresh_baselines.py ... ----
    recorded: {fwsim: 0.1.0, jsbsim: ..., date: ...}
    metrics: {...}

Everything from the marker line to the end is rewritten by
:func:`write_baseline_metrics` (``tools/refresh_baselines.py``); everything
above it, comments included, is kept.
"""
from __future__ import annotations

import json
import math
import platform
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import yaml

from fwsim.scenario.model import ScenarioError
from fwsim.scenario.yamlfile import load_yaml_file

TOLERANCE_KEYS = ("abs", "rel", "min", "max", "ignore")
DEFAULT_KEY = "default"
BASELINE_KEYS = ("description", "scenario", "overrides", "tolerances", "recorded", "metrics")
REFRESH_MARKER = ("# ---- written by tools/refresh_baselines.py from here to the end of the file; "
                  "edit above this line ----")
FAILING = ("REGRESSION", "CHANGED", "missing")
TEXT_WIDTH = 40  # text values (a note, an end reason) are cut to this in the tables
AB_SAME_REL = 1e-9  # A/B: "same" within this relative difference (rounding) unless the tolerances say otherwise


class CompareError(ScenarioError):
    """A metrics, baseline or tolerance file that cannot be used (one line per problem)."""


@dataclass(frozen=True)
class Tolerance:
    abs: float | None = None
    rel: float | None = None
    min: float | None = None
    max: float | None = None
    ignore: bool = False

    @property
    def closeness(self) -> bool:
        return self.abs is not None or self.rel is not None

    @property
    def bounds(self) -> bool:
        return self.min is not None or self.max is not None

    def allowed(self, baseline: float) -> float:
        """The allowed |run - baseline| (0 without abs/rel)."""
        return max(self.abs or 0.0, (self.rel or 0.0) * abs(baseline))

    def describe(self) -> str:
        if self.ignore:
            return "ignored"
        parts = []
        if self.abs is not None:
            parts.append(f"abs {self.abs:g}")
        if self.rel is not None:
            parts.append(f"rel {self.rel:g}")
        if self.bounds:
            lo = "-inf" if self.min is None else f"{self.min:g}"
            hi = "inf" if self.max is None else f"{self.max:g}"
            parts.append(f"in [{lo}, {hi}]")
        return ", ".join(parts) or "exact"


EXACT = Tolerance()


def _number(value: Any, where: str) -> float:
    # PyYAML reads 1e-5 (no dot) as a string: accept any text float() takes.
    try:
        if isinstance(value, bool):
            raise ValueError
        return float(value)
    except (TypeError, ValueError):
        raise CompareError(f"{where}: expected a number (got {value!r})") from None


def parse_tolerances(data: Any, source: str) -> dict[str, Tolerance]:
    """``{metric: {abs, rel, min, max, ignore}}`` -> ``{metric: Tolerance}``; unknown keys rejected."""
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise CompareError(f"{source}: tolerances: expected a mapping of metric -> {{abs, rel, min, max, ignore}}")
    out = {}
    for metric, spec in data.items():
        where = f"{source}: tolerances.{metric}"
        if not isinstance(spec, dict):
            raise CompareError(f"{where}: expected a mapping with keys {list(TOLERANCE_KEYS)} (got {spec!r})")
        unknown = set(spec) - set(TOLERANCE_KEYS)
        if unknown:
            raise CompareError(f"{where}.{sorted(unknown)[0]}: unknown key (allowed: {list(TOLERANCE_KEYS)})")
        kw: dict[str, Any] = {k: _number(spec[k], f"{where}.{k}") for k in ("abs", "rel", "min", "max")
                              if spec.get(k) is not None}
        for k in ("abs", "rel"):
            if kw.get(k, 0.0) < 0:
                raise CompareError(f"{where}.{k}: must be >= 0 (got {kw[k]:g})")
        if "ignore" in spec:
            if not isinstance(spec["ignore"], bool):
                raise CompareError(f"{where}.ignore: expected true or false (got {spec['ignore']!r})")
            kw["ignore"] = spec["ignore"]
        out[str(metric)] = Tolerance(**kw)
    return out


# -- comparing --------------------------------------------------------------

@dataclass(frozen=True)
class Check:
    metric: str
    baseline: Any  # None when the metric is new
    run: Any  # None when the metric is missing
    tolerance: Tolerance
    verdict: str  # ok | improved | REGRESSION | CHANGED | missing | new | ignored
    detail: str = ""  # why (difference, bound) for humans

    @property
    def failed(self) -> bool:
        return self.verdict in FAILING

    def fails(self, strict: bool) -> bool:
        return self.failed or (strict and self.verdict == "improved")


def _is_nan(v: Any) -> bool:
    return isinstance(v, float) and math.isnan(v)


def _direction(better: str, base: float, run: float) -> int:
    """+1 when ``run`` is better than ``base`` by the direction ``better``, -1 worse, 0 neither / no direction."""
    if better == "lower":
        return int(run < base) - int(run > base)
    if better == "higher":
        return int(run > base) - int(run < base)
    if better == "zero":
        return int(abs(run) < abs(base)) - int(abs(run) > abs(base))
    return 0


def check_metric(metric: str, baseline: Any, run: Any, tol: Tolerance, better: str | None = None) -> Check:
    """One metric's verdict (see the module docstring for the rules); ``better``: the metric's direction
    (default: from fwsim.analysis.metrics' table)."""
    if tol.ignore:
        return Check(metric, baseline, run, tol, "ignored")
    if baseline is None:
        return Check(metric, baseline, run, tol, "new", "not in the baseline")
    if run is None:
        return Check(metric, baseline, run, tol, "missing", "not in the run")
    if isinstance(baseline, str) or isinstance(run, str):
        same = baseline == run
        return Check(metric, baseline, run, tol, "ok" if same else "CHANGED", "" if same else "text differs")
    b, r = float(baseline), float(run)
    if math.isnan(b) or math.isnan(r):
        same = math.isnan(b) and math.isnan(r)
        return Check(metric, baseline, run, tol, "ok" if same else "CHANGED",
                     "" if same else f"no value in the {'run' if math.isnan(r) else 'baseline'}")
    bounds = []
    if tol.min is not None and r < tol.min:
        bounds.append(f"below min {tol.min:g}")
    if tol.max is not None and r > tol.max:
        bounds.append(f"above max {tol.max:g}")
    diff, change = r - b, ""
    if tol.closeness and not abs(diff) <= tol.allowed(b):
        change = f"|diff| {abs(diff):.3g} > allowed {tol.allowed(b):.3g}"
    elif not tol.closeness and not tol.bounds and diff != 0:
        change = "not equal"
    if bounds:
        return Check(metric, baseline, run, tol, "REGRESSION", "; ".join(bounds + ([change] if change else [])))
    if not change:
        return Check(metric, baseline, run, tol, "ok")
    if better is None:
        from fwsim.analysis.metrics import better_of
        better = better_of(metric)
    way = _direction(better, b, r)
    verdict = "improved" if way > 0 else "REGRESSION" if way < 0 else "CHANGED"
    return Check(metric, baseline, run, tol, verdict, change)


def _fmt(v: Any) -> str:
    if v is None:
        return "-"
    if isinstance(v, float) and math.isnan(v):
        return "—"
    if isinstance(v, float):
        return f"{v:.10g}"
    text = str(v)
    return text if len(text) <= TEXT_WIDTH else text[:TEXT_WIDTH - 1] + "…"  # a long note: its start


def _fmt_diff(c: Check) -> str:
    if isinstance(c.baseline, str) or isinstance(c.run, str) or c.baseline is None or c.run is None:
        return ""
    b, r = float(c.baseline), float(c.run)
    if not (math.isfinite(b) and math.isfinite(r)):
        return ""
    d = r - b
    return f"{d:+.3g}" + (f" ({d / abs(b):+.2e} rel)" if b != 0 else "")


@dataclass
class Comparison:
    checks: list[Check]
    baseline_label: str = "baseline"
    run_label: str = "run"
    strict: bool = False  # an improvement beyond the tolerance fails too

    @property
    def ok(self) -> bool:
        return not self.failures

    @property
    def failures(self) -> list[Check]:
        return [c for c in self.checks if c.fails(self.strict)]

    def count(self, verdict: str) -> int:
        return sum(c.verdict == verdict for c in self.checks)

    def summary_line(self) -> str:
        improved = self.count("improved")
        if self.ok:
            extra = (f", {improved} improved (beyond the tolerance in the better direction; --strict fails on "
                     "them)" if improved else "") + (f", {self.count('new')} new" if self.count("new") else "")
            return f"OK: {self.count('ok')} metrics within tolerance{extra}"
        counts = [f"{self.count('REGRESSION')} regression(s)", f"{self.count('CHANGED')} changed",
                  f"{self.count('missing')} missing", f"{improved} improved" + (" (strict: failing)" if self.strict
                                                                               else "")]
        return f"FAIL: {', '.join(counts)} (baseline {self.baseline_label}, run {self.run_label})"

    def rows(self) -> list[tuple[str, str, str, str, str, str]]:
        """(metric, baseline, run, diff, tolerance, verdict + detail) as text."""
        return [(c.metric, _fmt(c.baseline), _fmt(c.run), _fmt_diff(c), c.tolerance.describe(),
                 c.verdict + (f": {c.detail}" if c.detail and c.verdict not in ("ok", "new", "ignored") else ""))
                for c in self.checks]

    def format_text(self, failures_only: bool = False) -> str:
        """A fixed-width table (for test failures and logs), then the summary line."""
        head = ("metric", "baseline", "run", "diff", "tolerance", "verdict")
        rows = [r for r, c in zip(self.rows(), self.checks) if c.fails(self.strict) or not failures_only]
        widths = [max(len(x) for x in col) for col in zip(head, *rows)]
        lines = [f"baseline: {self.baseline_label}", f"run:      {self.run_label}",
                 "  ".join(h.ljust(w) for h, w in zip(head, widths)),
                 "  ".join("-" * w for w in widths)]
        lines += ["  ".join(x.ljust(w) for x, w in zip(r, widths)).rstrip() for r in rows]
        lines.append(self.summary_line())
        return "\n".join(lines)


def compare_metrics(baseline: dict[str, Any], run: dict[str, Any], tolerances: dict[str, Tolerance] | None = None,
                    baseline_label: str = "baseline", run_label: str = "run", strict: bool = False) -> Comparison:
    """Every metric of either side, in the baseline's order then the run's new ones."""
    checks = [check_metric(name, baseline.get(name), run.get(name), _tolerance_of(name, baseline, run, tolerances))
              for name in dict.fromkeys([*baseline, *run])]
    return Comparison(checks, baseline_label, run_label, strict)


def _tolerance_of(name: str, a: dict[str, Any], b: dict[str, Any], tolerances: dict[str, Tolerance] | None,
                  default: Tolerance = EXACT) -> Tolerance:
    """The metric's own tolerance, else exact for text, else the ``default`` entry (else ``default``)."""
    tolerances = tolerances or {}
    if name in tolerances:
        return tolerances[name]
    if isinstance(a.get(name), str) or isinstance(b.get(name), str):
        return EXACT
    return tolerances.get(DEFAULT_KEY, default)


# -- A/B --------------------------------------------------------------------

AB_SAME = Tolerance(rel=AB_SAME_REL)


@dataclass(frozen=True)
class ABRow:
    metric: str
    a: Any  # None: not in A
    b: Any
    verdict: str  # B better | B worse | same | differs | value in A only | value in B only | only in A | only in B

    @property
    def diff(self) -> float | None:
        """B minus A (None unless both are numbers with a value)."""
        if not all(isinstance(v, (int, float)) and not _is_nan(v) for v in (self.a, self.b)):
            return None
        return float(self.b) - float(self.a)


def _ab_verdict(name: str, a: Any, b: Any, tol: Tolerance) -> str:
    from fwsim.analysis.metrics import better_of
    if a is None or b is None:
        return "only in B" if a is None else "only in A"
    if isinstance(a, str) or isinstance(b, str):
        return "same" if a == b else "differs"
    x, y = float(a), float(b)
    if math.isnan(x) or math.isnan(y):
        return "same" if math.isnan(x) and math.isnan(y) else f"value in {'A' if math.isnan(y) else 'B'} only"
    if abs(y - x) <= tol.allowed(x):
        return "same"
    way = _direction(better_of(name), x, y)
    return "B better" if way > 0 else "B worse" if way < 0 else "differs"


@dataclass
class ABComparison:
    rows: list[ABRow]
    a_label: str = "A"
    b_label: str = "B"

    def count(self, verdict: str) -> int:
        return sum(r.verdict == verdict for r in self.rows)

    def summary_line(self) -> str:
        one_sided = sum(r.verdict.startswith(("value in", "only in")) for r in self.rows)
        return (f"B better on {self.count('B better')}, worse on {self.count('B worse')}, same on "
                f"{self.count('same')}; {self.count('differs')} differ with no better direction"
                + (f", {one_sided} have a value in one run only" if one_sided else ""))

    def text_rows(self) -> list[tuple[str, str, str, str, str, str]]:
        """(metric, A, B, B - A, relative, verdict) as text."""
        out = []
        for r in self.rows:
            d = r.diff
            rel = f"{100 * d / abs(float(r.a)):+.3g} %" if d is not None and float(r.a) != 0 else ""
            out.append((r.metric, _fmt(r.a), _fmt(r.b), "" if d is None else f"{d:+.4g}", rel, r.verdict))
        return out


def ab_compare(a: dict[str, Any], b: dict[str, Any], tolerances: dict[str, Tolerance] | None = None,
               a_label: str = "A", b_label: str = "B") -> ABComparison:
    """Per metric (in the metrics table's order), which of two runs is better, by the metric's direction."""
    from fwsim.analysis.metrics import ordered
    names = list(ordered(dict.fromkeys([*a, *b])))
    tols = {n: _tolerance_of(n, a, b, tolerances, AB_SAME) for n in names}
    rows = [ABRow(n, a.get(n), b.get(n), "same" if tols[n].ignore else _ab_verdict(n, a.get(n), b.get(n), tols[n]))
            for n in names]
    return ABComparison(rows, a_label, b_label)


# -- metrics sources --------------------------------------------------------

@dataclass
class MetricsSource:
    metrics: dict[str, Any]
    tolerances: dict[str, Tolerance] = field(default_factory=dict)
    label: str = ""
    flown: dict[str, Any] | None = None  # what was flown (scenario name, seed, duration), when the source says


def _flown(scenario_data: Any) -> dict[str, Any] | None:
    """The identity of a flight for comparability: scenario name, seed and duration (None if unknown)."""
    if not isinstance(scenario_data, dict):
        return None
    return {"scenario": scenario_data.get("name"), "seed": scenario_data.get("seed"),
            "duration_s": scenario_data.get("duration_s")}


def _describe_flown(f: dict[str, Any]) -> str:
    return f"{f['scenario']} seed {f['seed']} for {f['duration_s']:g} s" if isinstance(
        f.get("duration_s"), (int, float)) else f"{f['scenario']} seed {f['seed']}"


def check_comparable(base: MetricsSource, run: MetricsSource) -> None:
    """CompareError (one line) when both sources say what they flew and it is not the same flight."""
    if base.flown is None or run.flown is None or base.flown == run.flown:
        return
    hints = [f"{k}={base.flown[k]:g}" if isinstance(base.flown[k], float) else f"{k}={base.flown[k]}"
             for k in ("seed", "duration_s") if base.flown[k] != run.flown[k]]
    hint = f" (fly it with --set {' --set '.join(hints)})" if hints and base.flown["scenario"] == run.flown[
        "scenario"] else ""
    raise CompareError(f"not comparable: the baseline is {_describe_flown(base.flown)}, the run "
                       f"{_describe_flown(run.flown)}{hint}; --any compares them anyway")


def _clean(metrics: dict[str, Any], source: str) -> dict[str, Any]:
    out = {}
    for k, v in metrics.items():
        if v is None:
            v = math.nan  # null in JSON/YAML, None from compute_metrics: no value
        elif isinstance(v, bool):
            pass  # hit: true or false (compared as 1 / 0)
        elif not isinstance(v, (int, float, str)):
            raise CompareError(f"{source}: metrics.{k}: expected a number, true/false or text (got {v!r})")
        elif isinstance(v, int):
            v = float(v)
        out[str(k)] = v
    return out


def load_metrics(path: str | Path) -> MetricsSource:
    """Metrics (and, for a baseline, its tolerances) from a .mcap, .json or .yaml file."""
    path = Path(path)
    if path.is_dir():
        raise CompareError(f"{path}: is a folder, expected a .mcap log or a .json / .yaml metrics file")
    if not path.is_file():
        raise CompareError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".mcap":
        from fwsim.log.reader import read_flight_log
        from fwsim.analysis.metrics import compute_metrics
        try:
            log = read_flight_log(path)
        except ValueError as exc:
            raise CompareError(str(exc)) from None
        meta = log.metadata.get("fwsim", {})
        label = f"{path} (scenario {meta.get('scenario', '?')}, seed {meta.get('seed', '?')})"
        flown = None
        if log.effective_scenario_text:
            try:
                flown = _flown(yaml.safe_load(log.effective_scenario_text))
            except yaml.YAMLError:
                flown = None
        return MetricsSource(_clean(compute_metrics(log), str(path)), {}, label, flown)
    if suffix == ".json":
        try:
            data = json.loads(path.read_text())
        except ValueError as exc:
            raise CompareError(f"{path}: not valid JSON: {exc}") from None
        if isinstance(data, dict) and isinstance(data.get("metrics"), dict):
            data = data["metrics"]
        if not isinstance(data, dict):
            raise CompareError(f"{path}: expected a JSON object of metric -> value (as `fwsim metrics --json`)")
        return MetricsSource(_clean(data, str(path)), {}, str(path))
    if suffix in (".yaml", ".yml"):
        b = load_baseline(path)
        return MetricsSource(b.metrics, b.tolerances, str(path), _baseline_flown(b))
    raise CompareError(f"{path}: unsupported file type {suffix!r} (use .mcap, .json or a baseline .yaml)")


def load_tolerance_file(path: str | Path) -> dict[str, Tolerance]:
    """A YAML file with a ``tolerances:`` mapping (or just the mapping)."""
    path = Path(path)
    data = load_yaml_file(path, "tolerance file", CompareError)
    if isinstance(data, dict) and "tolerances" in data:
        data = data["tolerances"]
    return parse_tolerances(data, str(path))


def _baseline_flown(b: "Baseline") -> dict[str, Any] | None:
    """What a baseline's run flies: its scenario file with its overrides (None if that file is gone)."""
    from fwsim.scenario.model import ScenarioError, load_scenario
    try:
        scenario, _ = load_scenario(b.scenario, b.overrides)
    except ScenarioError:
        return None
    return _flown(scenario.model_dump(mode="json"))


def _sources(baseline: str | Path, run: str | Path, tolerances: str | Path | None,
             any_runs: bool) -> tuple[MetricsSource, MetricsSource, dict[str, Tolerance]]:
    base, new = load_metrics(baseline), load_metrics(run)
    if not any_runs:
        check_comparable(base, new)
    tol = dict(base.tolerances)
    if tolerances is not None:
        tol.update(load_tolerance_file(tolerances))
    return base, new, tol


def compare_files(baseline: str | Path, run: str | Path, tolerances: str | Path | None = None,
                  any_runs: bool = False, strict: bool = False) -> Comparison:
    """``fwsim compare``: the baseline's own tolerances, overridden per metric by ``tolerances``. Unless
    ``any_runs``, two sources that say what they flew must have flown the same scenario, seed and duration."""
    base, new, tol = _sources(baseline, run, tolerances, any_runs)
    return compare_metrics(base.metrics, new.metrics, tol, base.label, new.label, strict)


def ab_files(a: str | Path, b: str | Path, tolerances: str | Path | None = None,
             any_runs: bool = False) -> ABComparison:
    """``fwsim compare A B --ab``: which of two runs is better, metric by metric (``same`` within A's baseline
    tolerances, if A is a baseline, overridden by ``tolerances``; else equal to rounding)."""
    sa, sb, tol = _sources(a, b, tolerances, any_runs)
    return ab_compare(sa.metrics, sb.metrics, tol, sa.label, sb.label)


# -- regression baselines -----------------------------------------------------

@dataclass
class Baseline:
    path: Path
    scenario: Path  # resolved scenario file
    overrides: dict[str, Any]
    tolerances: dict[str, Tolerance]
    metrics: dict[str, Any]
    description: str = ""
    recorded: dict[str, Any] = field(default_factory=dict)


def load_baseline(path: str | Path, require_metrics: bool = True) -> Baseline:
    """Read a baseline file; ``require_metrics=False`` accepts a new one without metrics yet."""
    path = Path(path)
    data = load_yaml_file(path, "baseline file", CompareError)
    if not isinstance(data, dict):
        raise CompareError(f"{path}: expected a mapping with keys {list(BASELINE_KEYS)}")
    unknown = set(data) - set(BASELINE_KEYS)
    if unknown:
        raise CompareError(f"{path}: {sorted(unknown)[0]}: unknown key (allowed: {list(BASELINE_KEYS)})")
    if "scenario" not in data:
        raise CompareError(f"{path}: scenario: missing (the scenario file this baseline flies)")
    metrics = data.get("metrics")
    if metrics is None and not require_metrics:
        metrics = {}
    if not isinstance(metrics, dict):
        raise CompareError(f"{path}: metrics: missing; run tools/refresh_baselines.py {path}")
    overrides = data.get("overrides") or {}
    if not isinstance(overrides, dict):
        raise CompareError(f"{path}: overrides: expected a mapping of scenario field path -> value")
    return Baseline(path, (path.parent / str(data["scenario"])).resolve(), overrides,
                    parse_tolerances(data.get("tolerances"), str(path)), _clean(metrics, str(path)),
                    str(data.get("description") or ""), data.get("recorded") or {})


def fly_baseline(baseline: Baseline, log_path: str | Path) -> dict[str, Any]:
    """Fly the baseline's scenario with its overrides; the metrics of that run."""
    from fwsim.sim.loop import run
    from fwsim.analysis.metrics import compute_metrics
    from fwsim.scenario.model import load_scenario

    scenario, text = load_scenario(baseline.scenario, baseline.overrides)
    result = run(scenario, text, Path(log_path))
    return _clean(compute_metrics(result.log_path), str(log_path))


def check_baseline(baseline: Baseline, log_path: str | Path) -> Comparison:
    """Re-fly a baseline and compare the run's metrics with it, strictly (an improvement fails too: the baseline
    is refreshed on purpose)."""
    metrics = fly_baseline(baseline, log_path)
    return compare_metrics(baseline.metrics, metrics, baseline.tolerances, str(baseline.path),
                           f"{log_path} (re-flown)", strict=True)


def recorded_info() -> dict[str, str]:
    import jsbsim

    import fwsim
    return {"fwsim": fwsim.__version__, "jsbsim": jsbsim.__version__, "python": platform.python_version(),
            "machine": platform.machine(), "date": datetime.now(timezone.utc).date().isoformat()}


def write_baseline_metrics(path: str | Path, metrics: dict[str, Any], recorded: dict[str, Any] | None = None) -> None:
    """Rewrite the part of a baseline file after :data:`REFRESH_MARKER` with these metrics.

    The marker and the generated block are appended when the file has no
    marker yet (a new baseline: write its description, scenario, overrides
    and tolerances by hand, then refresh).
    """
    path = Path(path)
    text = path.read_text()
    lines = text.splitlines()
    if REFRESH_MARKER in lines:
        head = lines[: lines.index(REFRESH_MARKER)]
    else:
        if any(line.startswith(("metrics:", "recorded:")) for line in lines):
            raise CompareError(f"{path}: has metrics but no marker line; put {REFRESH_MARKER!r} above them")
        head = lines
    values = {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in metrics.items()}
    block = yaml.safe_dump({"recorded": recorded if recorded is not None else recorded_info(), "metrics": values},
                           sort_keys=False, default_flow_style=False, width=1000)
    path.write_text("\n".join(head).rstrip("\n") + "\n" + REFRESH_MARKER + "\n" + block)
    load_baseline(path)  # what was written must read back
