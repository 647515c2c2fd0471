"""fwsim compare: tolerance rules, metrics sources, the CLI; regression baselines."""
import importlib.util
import json
import math
import shutil
import subprocess
import sys

import pytest
import yaml

from fwsim import PROJECT_ROOT, SCENARIO_DIR
from fwsim.analysis.compare import (
    REFRESH_MARKER,
    CompareError,
    Tolerance,
    check_baseline,
    check_metric,
    compare_files,
    compare_metrics,
    load_baseline,
    load_metrics,
    parse_tolerances,
    write_baseline_metrics,
)
from fwsim.sim.loop import run
from fwsim.scenario.model import load_scenario

BASELINE_DIR = PROJECT_ROOT / "tests" / "baselines"
BASELINES = sorted(BASELINE_DIR.glob("*.yaml"))
CHECKOUT = SCENARIO_DIR / "autopilot_checkout.yaml"


def fwsim_cli(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "fwsim.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


def fwsim_main(capsys, *args):
    """``fwsim ARGS`` in this process (faster than a subprocess): (exit code, stdout, stderr)."""
    from fwsim.cli import main
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def refresh_tool():
    spec = importlib.util.spec_from_file_location("refresh_baselines", PROJECT_ROOT / "tools" / "refresh_baselines.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# -- tolerance rules --------------------------------------------------------------

@pytest.mark.parametrize("tol, base, run_value, verdict", [
    (Tolerance(abs=0.1), 1.0, 1.09, "ok"),
    (Tolerance(abs=0.1), 1.0, 1.11, "REGRESSION"),  # lower is better: up is worse
    (Tolerance(abs=0.1), 1.0, 0.89, "improved"),  # ... and down is better: reported, not failing
    (Tolerance(rel=1e-3), 1000.0, 1000.9, "ok"),
    (Tolerance(rel=1e-3), 1000.0, 1001.1, "REGRESSION"),
    (Tolerance(rel=1e-3), 1000.0, 998.9, "improved"),
    (Tolerance(abs=1.0, rel=1e-3), 10.0, 10.9, "ok"),  # the larger of the two
    (Tolerance(abs=1e-3, rel=0.5), 10.0, 14.0, "ok"),
    (Tolerance(min=0.0, max=5.0), 1.0, 4.0, "ok"),  # bounds only: the baseline value does not matter
    (Tolerance(min=0.0, max=5.0), 1.0, 5.5, "REGRESSION"),
    (Tolerance(min=2.0), 3.0, 1.0, "REGRESSION"),  # out of bounds is a regression even in the better direction
    (Tolerance(abs=10.0, max=5.0), 1.0, 5.5, "REGRESSION"),  # both must hold
    (Tolerance(), 1.0, 1.0, "ok"),  # no tolerance: exact
    (Tolerance(), 1.0, 1.0 + 1e-15, "REGRESSION"),
    (Tolerance(abs=1.0), math.nan, math.nan, "ok"),  # no value on either side
    (Tolerance(abs=1.0), 1.0, math.nan, "CHANGED"),  # a value on one side only: neither better nor worse
    (Tolerance(abs=1.0), math.nan, 1.0, "CHANGED"),
    (Tolerance(), "completed", "completed", "ok"),
    (Tolerance(), "completed", "failed", "CHANGED"),
    (Tolerance(ignore=True), "a", "b", "ignored"),
    (Tolerance(abs=1.0), 1.0, None, "missing"),
    (Tolerance(abs=1.0), None, 1.0, "new"),
])
def test_check_metric_rules(tol, base, run_value, verdict):
    """The rules, for a metric where lower is better."""
    assert check_metric("m", base, run_value, tol, better="lower").verdict == verdict


@pytest.mark.parametrize("metric, base, run_value, verdict", [
    ("pixel_err_rms_px_u", 1.7346, 1.7237, "improved"),  # lower is better: not a regression
    ("pixel_err_rms_px_u", 1.7237, 1.7346, "REGRESSION"),
    ("target_in_fov_fraction_after_lock", 0.95, 0.99, "improved"),  # higher is better
    ("target_in_fov_fraction_after_lock", 0.99, 0.95, "REGRESSION"),
    ("impact_fpa_error_deg", -2.0, 1.0, "improved"),  # nearer zero is better, whatever the sign
    ("impact_fpa_error_deg", 1.0, -2.0, "REGRESSION"),
    ("hit", False, True, "improved"),
    ("hit", True, False, "REGRESSION"),
    ("flight_time_s", 60.0, 5.0, "CHANGED"),  # no better direction
    ("made_up_metric", 1.0, 2.0, "CHANGED"),  # not in the table: no direction
])
def test_verdicts_follow_the_metrics_table_direction(metric, base, run_value, verdict):
    check = check_metric(metric, base, run_value, Tolerance(rel=1e-5))
    assert check.verdict == verdict
    assert check.failed == (verdict != "improved")


def test_an_improvement_passes_unless_strict():
    base, run = {"pixel_err_rms_px_u": 1.7346}, {"pixel_err_rms_px_u": 1.7237}
    tol = {"default": Tolerance(rel=1e-5)}
    lenient = compare_metrics(base, run, tol)
    assert lenient.ok and "1 improved" in lenient.summary_line() and "REGRESSION" not in lenient.format_text()
    strict = compare_metrics(base, run, tol, strict=True)
    assert not strict.ok and strict.failures[0].verdict == "improved"
    assert strict.summary_line().startswith("FAIL") and "1 improved (strict: failing)" in strict.summary_line()


def test_default_tolerance_applies_to_numbers_not_text():
    tol = parse_tolerances({"default": {"rel": 0.1}, "x": {"abs": 0.0}}, "t")
    cmp = compare_metrics({"x": 1.0, "y": 1.0, "status": "completed"},
                          {"x": 1.05, "y": 1.05, "status": "failed"}, tol)
    verdicts = {c.metric: c.verdict for c in cmp.checks}
    assert verdicts == {"x": "CHANGED", "y": "ok", "status": "CHANGED"}  # x: no better direction
    assert not cmp.ok and len(cmp.failures) == 2


def test_new_metrics_do_not_fail_missing_ones_do():
    assert compare_metrics({"a": 1.0}, {"a": 1.0, "b": 2.0}).ok
    cmp = compare_metrics({"a": 1.0, "b": 2.0}, {"a": 1.0})
    assert not cmp.ok and cmp.failures[0].metric == "b" and cmp.failures[0].verdict == "missing"


def test_tolerance_file_errors_are_one_line_and_yaml_exponents_read():
    # PyYAML reads 1e-5 (no dot) as text: it must still be a number here.
    tol = parse_tolerances(yaml.safe_load("m: {rel: 1e-5, abs: 2}"), "t.yaml")
    assert tol["m"] == Tolerance(abs=2.0, rel=1e-5)
    for bad, what in [({"m": {"rle": 1}}, "tolerances.m.rle: unknown key"),
                      ({"m": {"rel": "x"}}, "tolerances.m.rel: expected a number"),
                      ({"m": {"abs": -1}}, "tolerances.m.abs: must be >= 0"),
                      ({"m": 3}, "tolerances.m: expected a mapping")]:
        with pytest.raises(CompareError, match=what):
            parse_tolerances(bad, "t.yaml")


def test_format_text_names_metric_values_and_tolerance():
    cmp = compare_metrics({"roll_rate_err_rms_deg_s": 3.5}, {"roll_rate_err_rms_deg_s": 3.9},
                          {"roll_rate_err_rms_deg_s": Tolerance(rel=1e-5)}, "base.yaml", "run.mcap")
    text = cmp.format_text()
    line = next(ln for ln in text.splitlines() if ln.startswith("roll_rate_err_rms_deg_s"))
    for part in ("3.5", "3.9", "+0.4", "rel 1e-05", "REGRESSION"):
        assert part in line
    assert "base.yaml" in text and "run.mcap" in text and text.splitlines()[-1].startswith("FAIL")


# -- metrics sources and the CLI ------------------------------------------------

@pytest.fixture(scope="module")
def short_logs(tmp_path_factory):
    """Two short checkout runs: the reference and one with a weak roll-rate loop."""
    tmp = tmp_path_factory.mktemp("compare")
    out = {}
    for name, extra in (("ref", {}), ("weak", {"aircraft.autopilot_gains.roll_rate_kp": 0.05})):
        scenario, text = load_scenario(CHECKOUT, {"duration_s": 15, **extra})
        out[name] = run(scenario, text, tmp / f"{name}.mcap").log_path
    return out


def test_sources_mcap_json_and_baseline_agree(short_logs, tmp_path):
    proc = fwsim_cli("metrics", short_logs["ref"], "--json")
    assert proc.returncode == 0, proc.stderr
    (tmp_path / "ref.json").write_text(proc.stdout)
    from_log = load_metrics(short_logs["ref"]).metrics
    from_json = load_metrics(tmp_path / "ref.json").metrics
    assert from_log.keys() == from_json.keys()
    for k, v in from_log.items():
        assert from_json[k] == v or (isinstance(v, float) and math.isnan(v) and math.isnan(from_json[k])), k
    assert compare_files(short_logs["ref"], tmp_path / "ref.json").ok
    (tmp_path / "ref.txt").write_text("{}")
    with pytest.raises(CompareError, match="unsupported file type"):
        load_metrics(tmp_path / "ref.txt")


def test_cli_compare_same_run_passes(short_logs, capsys):
    code, out, err = fwsim_main(capsys, "compare", short_logs["ref"], short_logs["ref"])
    assert code == 0, out + err
    assert "REGRESSION" not in out and "OK:" in out


def test_cli_compare_perturbed_run_fails_with_a_readable_table(short_logs, tmp_path):
    tol = tmp_path / "tol.yaml"
    tol.write_text("tolerances:\n  default: {rel: 1.0e-5}\n  end_reason: {ignore: true}\n")
    proc = fwsim_cli("compare", short_logs["ref"], short_logs["weak"], "--tolerances", tol)
    assert proc.returncode == 1, proc.stdout + proc.stderr
    row = next(ln for ln in proc.stdout.splitlines() if "roll_rate_err_rms_deg_s" in ln)
    assert "REGRESSION" in row and "rel 1e-05" in row
    assert "FAIL:" in proc.stdout


def test_cli_compare_missing_metric_fails_and_bad_input_is_exit_2(short_logs, tmp_path, capsys):
    base = dict(load_metrics(short_logs["ref"]).metrics, made_up_metric_m=1.0)
    (tmp_path / "base.json").write_text(json.dumps(base))
    code, out, _ = fwsim_main(capsys, "compare", tmp_path / "base.json", short_logs["ref"])
    assert code == 1 and "missing" in out
    code, _, err = fwsim_main(capsys, "compare", tmp_path / "nope.yaml", short_logs["ref"])
    assert code == 2 and "no such file" in err
    (tmp_path / "bad.mcap").write_text("not a log")
    code, _, err = fwsim_main(capsys, "compare", tmp_path / "bad.mcap", short_logs["ref"])
    assert code == 2 and "not an MCAP file" in err


def test_ab_says_which_run_is_better_and_by_how_much():
    from fwsim.analysis.compare import ab_compare
    a = {"status": "completed", "hit": False, "miss_distance_m": 4.0, "impact_fpa_error_deg": -2.0,
         "target_in_fov_fraction_after_lock": 0.9, "flight_time_s": 60.0, "camera_frames": 1800.0,
         "lock_time_s": math.nan, "pixel_err_rms_px_u": 1.7346}
    b = {"status": "completed", "hit": True, "miss_distance_m": 1.0, "impact_fpa_error_deg": 2.5,
         "target_in_fov_fraction_after_lock": 0.9 * (1 + 1e-12), "flight_time_s": 59.0, "camera_frames": 1800.0,
         "lock_time_s": 12.0, "pixel_err_rms_px_u": 1.7237}
    ab = ab_compare(a, b)
    verdicts = {r.metric: r.verdict for r in ab.rows}
    assert verdicts == {"status": "same", "hit": "B better", "flight_time_s": "differs", "miss_distance_m": "B better",
                        "impact_fpa_error_deg": "B worse", "camera_frames": "same", "lock_time_s": "value in B only",
                        "target_in_fov_fraction_after_lock": "same", "pixel_err_rms_px_u": "B better"}
    assert [r.metric for r in ab.rows][:3] == ["status", "hit", "flight_time_s"]  # the metrics table's order
    row = dict((r[0], r) for r in ab.text_rows())["miss_distance_m"]
    assert row[3] == "-3" and row[4] == "-75 %"  # B - A, and relative to A
    assert ab.summary_line() == ("B better on 3, worse on 1, same on 3; 1 differ with no better direction, "
                                 "1 have a value in one run only")
    # the tolerances widen "same"
    wide = ab_compare(a, b, {"pixel_err_rms_px_u": Tolerance(abs=0.1)})
    assert {r.metric: r.verdict for r in wide.rows}["pixel_err_rms_px_u"] == "same"


def test_cli_ab_mode(short_logs, capsys):
    code, out, err = fwsim_main(capsys, "compare", short_logs["ref"], short_logs["weak"], "--ab")
    assert code == 0, out + err  # A/B informs; it does not fail
    row = next(ln for ln in out.splitlines() if "roll_rate_err_rms_deg_s" in ln)
    assert "B worse" in row and "%" in row  # a weaker roll-rate loop tracks worse
    assert "B better on" in out.splitlines()[-1] and "worse on" in out.splitlines()[-1]


def test_cli_compare_reports_an_improvement_and_strict_fails_it(short_logs, tmp_path, capsys):
    """The weak run as the baseline, the reference as the run: the roll-rate error went down, an improvement,
    not a regression; --strict fails on it."""
    tol = tmp_path / "tol.yaml"
    tol.write_text("tolerances:\n  default: {rel: 1.0e-5}\n  end_reason: {ignore: true}\n"
                   "  sideslip_abs_max_deg: {ignore: true}\n  bank_abs_max_deg: {ignore: true}\n"
                   "  airspeed_err_rms_m_s: {ignore: true}\n  pitch_rate_err_rms_deg_s: {ignore: true}\n"
                   "  height_min_m: {ignore: true}\n  airspeed_min_m_s: {ignore: true}\n"
                   "  airspeed_max_m_s: {ignore: true}\n")
    code, out, _ = fwsim_main(capsys, "compare", short_logs["weak"], short_logs["ref"], "--tolerances", tol)
    row = next(ln for ln in out.splitlines() if "roll_rate_err_rms_deg_s" in ln)
    assert code == 0 and "improved" in row and "REGRESSION" not in out, out
    code, out, _ = fwsim_main(capsys, "compare", short_logs["weak"], short_logs["ref"], "--tolerances", tol,
                              "--strict")
    assert code == 1 and "1 improved (strict: failing)" in out


# -- regression baselines ---------------------------------------------------------

def test_baseline_files_are_complete():
    assert {p.stem for p in BASELINES} >= {"autopilot_checkout", "paper_mission"}
    for path in BASELINES:
        b = load_baseline(path)
        assert b.scenario.is_file(), path
        assert b.metrics.get("status") == "completed", path
        assert b.tolerances, f"{path}: no tolerances"
        assert REFRESH_MARKER in path.read_text().splitlines()
    assert load_baseline(BASELINE_DIR / "paper_mission.yaml").overrides == {"duration_s": 60}


@pytest.mark.parametrize("path", BASELINES, ids=[p.stem for p in BASELINES])
def test_baseline_still_holds(path, tmp_path):
    """Re-fly the baseline's scenario; every metric within its tolerance.

    If a change is intended, run `python tools/refresh_baselines.py` and
    commit the new numbers with the change.
    """
    cmp = check_baseline(load_baseline(path), tmp_path / f"{path.stem}.mcap")
    assert cmp.ok, ("\n" + cmp.format_text(failures_only=True)
                    + "\nIf intended: python tools/refresh_baselines.py " + str(path.relative_to(PROJECT_ROOT)))


def test_baseline_catches_a_gain_change(tmp_path):
    """The checkout baseline's tolerances see a 4 % roll-rate gain change (and say where)."""
    b = load_baseline(BASELINE_DIR / "autopilot_checkout.yaml")
    b.overrides = {**b.overrides, "aircraft.autopilot_gains.roll_rate_kp": 0.26}  # default 0.25
    cmp = check_baseline(b, tmp_path / "gain.mcap")
    assert not cmp.ok
    assert "roll_rate_err_rms_deg_s" in {c.metric for c in cmp.failures}
    assert "roll_rate_err_rms_deg_s" in cmp.format_text(failures_only=True)


def test_refresh_rewrites_metrics_and_keeps_the_rest(tmp_path, capsys):
    src = BASELINE_DIR / "autopilot_checkout.yaml"
    dst = tmp_path / "autopilot_checkout.yaml"
    shutil.copy(src, dst)
    # The scenario path is relative to the baseline file: point it at the real one.
    text = dst.read_text().replace("../../scenarios/", f"{SCENARIO_DIR.as_posix()}/")
    dst.write_text(text.replace("overrides: {}", "overrides: {duration_s: 5}"))
    head = dst.read_text().split(REFRESH_MARKER)[0]
    tool = refresh_tool()
    assert tool.main([str(dst)]) == 0
    out = capsys.readouterr().out
    # the table of what moved (5 s instead of 60 s: flight_time_s has no better direction, it changed)
    assert "CHANGED" in next(ln for ln in out.splitlines() if ln.startswith("flight_time_s")) and f"wrote {dst}" in out
    assert dst.read_text().split(REFRESH_MARKER)[0] == head  # comments and tolerances kept
    b = load_baseline(dst)
    assert b.metrics["flight_time_s"] == pytest.approx(5.0, abs=1e-6)
    assert b.tolerances == load_baseline(src).tolerances
    assert tool.main(["--check", str(dst)]) == 0
    assert "OK:" in capsys.readouterr().out


def test_write_baseline_metrics_round_trips(tmp_path):
    path = tmp_path / "b.yaml"
    path.write_text("scenario: x.yaml\ntolerances:\n  default: {rel: 1.0e-5}\n")
    metrics = {"status": "completed", "a": 1e-10, "b": 59.999999999997236, "c": math.nan, "d": 1e20}
    write_baseline_metrics(path, metrics, recorded={"fwsim": "test"})
    write_baseline_metrics(path, metrics, recorded={"fwsim": "test"})  # idempotent
    b = load_baseline(path)
    assert path.read_text().count(REFRESH_MARKER) == 1
    assert b.metrics["a"] == 1e-10 and b.metrics["b"] == 59.999999999997236 and b.metrics["d"] == 1e20
    assert math.isnan(b.metrics["c"]) and b.metrics["status"] == "completed"


def test_the_readmes_compare_example_works_as_written(tmp_path, monkeypatch, capsys):
    """README 'Using it': fly the checkout as the first line does, then compare its log with the baseline the
    compare line names; a healthy run passes (exit 0)."""
    import re

    from fwsim import PROJECT_ROOT
    from fwsim.cli import main
    text = (PROJECT_ROOT / "README.md").read_text()
    run_cmd = re.search(r"^fwsim run (scenarios/autopilot_checkout\.yaml)\s", text, re.M)
    cmp_cmd = re.search(r"^fwsim compare (\S+) runs/<log>\.mcap", text, re.M)
    assert run_cmd and cmp_cmd, "the README's run and compare examples moved"
    monkeypatch.chdir(PROJECT_ROOT)
    log = tmp_path / "checkout.mcap"
    assert main(["run", run_cmd.group(1), "--log", str(log), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["compare", cmp_cmd.group(1), str(log)]) == 0, capsys.readouterr()
