"""fwsim metrics: one table documents every metric; grouped output, strict JSON, a closed pipe, runs that never
dived, and fwsim run's one-line result."""
import json
import subprocess
import sys

import pytest

from fwsim import PROJECT_ROOT, SCENARIO_DIR
from fwsim.cli import main as main_cli
from fwsim.log import read_log
from fwsim.sim.loop import run
from fwsim.analysis.metrics import BETTER, GROUPS, METRIC, METRICS, compute_metrics, metrics_doc, result_line
from fwsim.scenario.model import load_scenario

CHECKOUT = SCENARIO_DIR / "autopilot_checkout.yaml"
PAPER = SCENARIO_DIR / "paper_mission.yaml"
#: a scripted straight descent into a stopped ship: the run ends at hull contact
INTO_THE_SHIP = {"initial.pos_enu_m": [-150.0, 0.0, 16.0], "initial.flight_path_deg": -4.0, "target.speed_m_s": 0.0,
                 "controllers.script": [{"t_s": 0, "rates": {"airspeed_m_s": 22}},
                                        {"t_s": 5, "accel": {"airspeed_m_s": 22}}],  # both modes
                 "duration_s": 12}


def fwsim_cli(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "fwsim.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout)


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    """A 30 s paper mission flown by `fwsim run` (search, lock, estimator, NMPC loiter; it never dives) and its
    output, and a scripted flight into the ship (a hit)."""
    tmp = tmp_path_factory.mktemp("metrics")
    proc = fwsim_cli("run", PAPER, "--set", "duration_s=30", "--log", tmp / "loiter.mcap", "--quiet")
    assert proc.returncode == 0, proc.stderr
    scenario, text = load_scenario(CHECKOUT, INTO_THE_SHIP)
    hit = run(scenario, text, tmp / "hit.mcap")
    assert hit.reason.startswith("hit the ship"), hit.reason
    return {"loiter": tmp / "loiter.mcap", "hit": hit.log_path, "run_output": proc.stderr}


def test_the_table_is_well_formed():
    names = [s.name for s in METRICS]
    assert len(names) == len(set(names)) == len(METRIC)
    for s in METRICS:
        assert s.better in BETTER, s
        assert s.description and "\n" not in s.description and "|" not in s.description, s.name
        assert len(s.description) <= 200, s.name
        assert s.group in GROUPS
    # a group's metrics sit together, in the group order
    assert [s.group for s in METRICS] == sorted((s.group for s in METRICS), key=GROUPS.index)
    assert not any(n.startswith("ukf_") for n in names)  # named for the block, whatever the estimator


def test_every_computed_metric_is_in_the_table_and_every_entry_is_computed(flights, paper_typical):
    loiter, hit = compute_metrics(flights["loiter"]), compute_metrics(flights["hit"])
    mission = compute_metrics(paper_typical)  # the navigation filter's, and the dive's after the lock
    unreadable = read_log(flights["hit"])
    unreadable.effective_scenario_text += "\nfrom_a_later_version: 1\n"  # the impact metrics left out, and why
    other = compute_metrics(unreadable)
    computed = set(loiter) | set(hit) | set(other) | set(mission)
    assert computed - set(METRIC) == set(), "computed but not in fwsim.analysis.metrics.METRICS"
    assert set(METRIC) - computed == set(), "in the table but computed by none of these flights"
    for m in (loiter, hit, other, mission):  # in the table's order
        assert list(m) == [s.name for s in METRICS if s.name in m]


def test_estimator_metrics_are_named_estimator(flights):
    m = compute_metrics(flights["loiter"])
    assert m["estimator_pos_rmse_m"] < 10.0 and m["estimator_convergence_time_s"] is not None
    assert not [k for k in m if k.startswith("ukf_")]


def test_a_run_that_never_dived_has_no_miss_distance_and_says_why(flights):
    m = compute_metrics(flights["loiter"])
    assert m["hit"] is False  # a bool
    assert m["terminal_note"] == ("no terminal phase: the run ended in phase 2 (loiter:nmpc) after 30.0 s "
                                  "(duration reached)")
    for k in ("miss_distance_m", "miss_bow_m", "switch_time_s", "impact_time_s", "impact_fpa_error_deg",
              "impact_heading_error_deg", "impact_fpa_deg"):
        assert m[k] is None, k
    assert result_line(m) == "no dive: ended in phase 2 (loiter:nmpc) after 30.0 s (duration reached)"


def test_a_hit_scores_miss_and_angles(flights):
    m = compute_metrics(flights["hit"])
    assert m["hit"] is True and "terminal_note" not in m
    assert m["miss_distance_m"] < 3.0 and m["impact_time_s"] is not None
    assert isinstance(m["impact_fpa_error_deg"], float) and isinstance(m["impact_heading_error_deg"], float)
    line = result_line(m)
    assert line.startswith(f"hit at {m['impact_time_s']:.2f} s, miss {m['miss_distance_m']:.2f} m, impact angles ")
    assert line.endswith("° off")


def test_fwsim_run_ends_with_a_one_line_result(flights):
    last = flights["run_output"].strip().splitlines()
    assert "result: no dive: ended in phase 2 (loiter:nmpc) after 30.0 s (duration reached)" in last


def test_the_table_output_is_grouped_in_the_tables_order(flights, capsys):
    assert main_cli(["metrics", str(flights["loiter"])]) == 0
    lines = capsys.readouterr().out.splitlines()
    heads = [ln.split(" — ")[0] for ln in lines[1:] if not ln.startswith(" ")]
    assert heads == [g for g in GROUPS if g in heads] and heads[:2] == ["outcome", "terminal"]
    assert next(ln for ln in lines if ln.startswith("terminal")) == (
        "terminal — no terminal phase: the run ended in phase 2 (loiter:nmpc) after 30.0 s (duration reached)")
    miss = next(ln for ln in lines if ln.strip().startswith("miss_distance_m"))
    assert miss.split()[1:] == ["—", "m"]
    assert next(ln for ln in lines if ln.strip().startswith("hit ")).split()[1] == "no"
    names = [ln.split()[0] for ln in lines if ln.startswith("  ")]
    assert names == [s.name for s in METRICS if s.name in names]


def _strict(text: str):
    def refuse(name):
        raise ValueError(f"not strict JSON: {name}")
    return json.loads(text, parse_constant=refuse)


def test_json_is_strict(flights):
    proc = fwsim_cli("metrics", flights["loiter"], "--json")
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    data = _strict(proc.stdout)
    assert data["miss_distance_m"] is None and data["hit"] is False and data["lock_time_s"] > 0
    assert "NaN" not in proc.stdout


def test_a_closed_pipe_ends_quietly(flights):
    proc = subprocess.run(f"{sys.executable} -m fwsim.cli metrics {flights['loiter']} --json | head -1",
                          shell=True, capture_output=True, text=True, timeout=120)
    assert proc.stdout == "{\n" and proc.stderr == ""
    # deterministic: the reader gone before the first write (the table output too)
    for extra in ([], ["--json"]):
        child = subprocess.Popen([sys.executable, "-m", "fwsim.cli", "metrics", str(flights["loiter"]), *extra],
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        child.stdout.close()
        err = child.stderr.read().decode()
        assert child.wait(timeout=120) == 141 and err == "", err


def test_the_metrics_page_is_generated_from_the_table():
    page = PROJECT_ROOT / "docs" / "guide" / "metrics.md"
    assert page.read_text(encoding="utf-8") == metrics_doc() + "\n", (
        "docs/guide/metrics.md is stale: regenerate it with `python tools/gen_metrics_doc.py`")
    text = page.read_text(encoding="utf-8")
    for s in METRICS:
        assert f"| `{s.name}` |" in text
