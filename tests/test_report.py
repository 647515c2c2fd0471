"""fwsim report: the statistics of a batch, checked against hand-computed cases."""
from __future__ import annotations

import json
import math

import pytest

from fwsim.cli import main
from fwsim.analysis.report import ReportError, summarise, wilson_interval, worst_runs, write_report


def test_wilson_interval_against_hand_computed_values():
    # 8 of 10, z = 1.96: centre (0.8 + 1.96^2/20) / (1 + 1.96^2/10), half-width
    # 1.96 sqrt(0.8 * 0.2 / 10 + 1.96^2 / 400) / (1 + 1.96^2/10)
    lo, hi = wilson_interval(8, 10, z=1.96)
    assert lo == pytest.approx(0.4902, abs=1e-4) and hi == pytest.approx(0.9433, abs=1e-4)
    lo, hi = wilson_interval(10, 10)  # all hits: the interval still has width
    assert hi == pytest.approx(1.0) and lo == pytest.approx(0.7225, abs=1e-4)
    assert wilson_interval(0, 20)[0] == 0.0 and all(math.isnan(v) for v in wilson_interval(0, 0))


def _rows():
    rows = []
    for i, miss in enumerate([0.5, 1.0, 2.0, 4.0]):
        rows.append({"id": f"r{i}", "status": "completed", "reason": "hit the ship at t = 1 s", "hit": 1.0,
                     "miss_distance_m": miss, "miss_bow_m": miss, "miss_port_m": 0.0,
                     "impact_fpa_error_deg": [-1.0, 1.0, -2.0, 2.0][i], "impact_heading_error_deg": 0.5,
                     "target_in_fov_fraction_after_lock": [1.0, 1.0, 0.98, 1.0][i],
                     "target_visible_fraction_after_lock": [1.0, 0.97, 0.98, 1.0][i],
                     "target_hidden_longest_s_after_lock": [0.0, 5.2, 3.0, 0.0][i],
                     "estimator_pos_err_max_after_convergence_m": [3.0, 5.0, 9.0, 7.0][i],
                     "estimator_pos_err_within_2std_fraction": [0.9, 0.5, 0.2, 0.7][i],
                     "set.target.speed_m_s": float(i), "log": f"/tmp/logs/r{i}.mcap"})
    rows.append({"id": "r4", "status": "completed", "reason": "duration reached", "hit": 0.0,
                 "miss_distance_m": 30.0, "target_in_fov_fraction_after_lock": 0.5,
                 "target_visible_fraction_after_lock": 0.5, "target_hidden_longest_s_after_lock": 100.0,
                 "set.target.speed_m_s": 9.0, "log": "/tmp/logs/r4.mcap"})
    rows.append({"id": "r5", "status": "failed", "reason": "", "error": "AirframeError: trim failed",
                 "set.target.speed_m_s": 2.0})
    return rows


def test_summary_statistics_by_hand():
    rep = summarise(_rows(), "t", ["target.speed_m_s"])
    assert (rep.runs, rep.completed, rep.hits) == (6, 5, 4)
    assert rep.hit_probability == pytest.approx(4 / 6)
    assert rep.hit_interval_95 == pytest.approx(wilson_interval(4, 6))
    assert rep.cep50_m == pytest.approx(2.0)  # median of 0.5, 1, 2, 4, 30
    e = rep.estimator_error_m
    assert e["within_2std_median"] == pytest.approx(0.6) and e["within_2std_min"] == pytest.approx(0.2)
    assert dict(rep.headline())["estimator consistency (error within 2 std)"].startswith("median 60 %")
    assert rep.cep90_m == pytest.approx(4.0 + 0.6 * 26.0)  # numpy's linear percentile
    fpa = rep.angle_errors["flight-path"]
    assert fpa["mean"] == pytest.approx(0.0) and fpa["std"] == pytest.approx(math.sqrt(10 / 3))
    assert rep.in_view_after_lock["share_99"] == pytest.approx(3 / 5) and rep.in_view_after_lock["min"] == 0.5
    # seen (in view and not behind the airframe): r1 was in view all along but hidden 3 % of the time
    seen = rep.visible_after_lock
    assert seen["share_99"] == pytest.approx(2 / 5) and seen["min"] == 0.5 and seen["longest_hidden_s"] == 100.0
    assert dict(rep.headline())["ship seen after lock (in view, not behind the airframe)"].startswith("mean 89.0 %")
    old_rows = [{k: v for k, v in r.items() if not k.startswith("target_visible") and not k.startswith("target_hidden")}
                for r in _rows()]
    assert math.isnan(summarise(old_rows).visible_after_lock["share_99"])  # rows scored before the metric
    assert rep.estimator_error_m["share_8m"] == pytest.approx(3 / 4)
    # a run whose estimate never converged counts against the share, it does not drop out of it
    never = dict(_rows()[0], id="r6", estimator_pos_rmse_m=12.0)
    del never["estimator_pos_err_max_after_convergence_m"]
    assert summarise(_rows() + [never]).estimator_error_m["share_8m"] == pytest.approx(3 / 5)
    assert rep.within_3m_3deg == pytest.approx(3 / 6)  # r0, r1, r2 (r3 misses by 4 m; r4, r5 no hit)
    assert rep.outcomes == {"hit": 4, "no hit: duration reached": 1, "failed: AirframeError: trim failed": 1}
    # a dive that went round (switch.go_around_m) and then hit is told apart
    rows = _rows()
    rows[0] = dict(rows[0], go_arounds=1.0)
    assert summarise(rows).outcomes == {"hit": 3, "hit after going round": 1, "no hit: duration reached": 1,
                                        "failed: AirframeError: trim failed": 1}
    assert [r["id"] for r in worst_runs(_rows(), 3)] == ["r5", "r4", "r3"]


def test_rows_from_before_the_estimator_rename_still_count():
    """A summary written when the estimator metrics were named ukf_*: the same statistics."""
    old = [{(k.replace("estimator_", "ukf_", 1) if k.startswith("estimator_") else k): v for k, v in r.items()}
           for r in _rows()]
    assert "ukf_pos_err_max_after_convergence_m" in old[0]
    assert summarise(old).estimator_error_m == summarise(_rows()).estimator_error_m


def _no_dive(i: int, phase: str = "phase 2 (loiter:nmpc)") -> dict:
    """A run that never reached the terminal phase, as compute_metrics scores it: no miss, a note why."""
    return {"id": f"n{i}", "status": "completed", "reason": "duration reached", "hit": False, "seed": 20 + i,
            "terminal_note": f"no terminal phase: the run ended in {phase} after {30.0 + i:.1f} s (duration reached)",
            "switch_time_s": None, "miss_distance_m": None, "impact_fpa_error_deg": None,
            "impact_heading_error_deg": None, "target_in_fov_fraction_after_lock": 1.0}


def test_runs_that_never_dived_are_counted_and_explained_not_scored():
    rows = _rows() + [_no_dive(0), _no_dive(1), _no_dive(2, "phase 1 (acquisition:search)")]
    rep = summarise(rows)
    assert rep.runs == 9 and rep.hits == 4 and rep.dived == 5  # the 4 hits and r4 (dived, missed by 30 m)
    assert rep.cep50_m == pytest.approx(2.0)  # over the runs that dived only: the same as without them
    assert rep.never_dived == {"ended in phase 2 (loiter:nmpc), duration reached": 2,
                               "ended in phase 1 (acquisition:search), duration reached": 1}
    head = dict(rep.headline())
    assert head["never dived (no miss distance, not a hit)"].startswith("3 of 9 runs: ended in phase 2")
    assert head["miss distance CEP50 / CEP90"].endswith("over the 5 runs that dived")
    assert rep.outcomes["no dive: ended in phase 2 (loiter:nmpc), duration reached"] == 2
    # none dived: no CEP of 1000 m, no mean nan: a dash and why
    only = summarise([_no_dive(0), _no_dive(1)])
    head = dict(only.headline())
    assert head["miss distance CEP50 / CEP90"] == "— (no run dived)"
    assert head["impact flight-path error"] == "— (no run dived)" and "nan" not in str(only.headline())
    assert only.hits == 0 and only.hit_probability == 0.0
    # a summary from before the note: a never-dived run had a miss distance (its closest pass) and no switch
    old = dict(_no_dive(3), miss_distance_m=1000.89)
    del old["terminal_note"]
    assert summarise(_rows() + [old]).cep50_m == pytest.approx(2.0)


def test_seed_ranges():
    from fwsim.analysis.report import seed_ranges
    assert seed_ranges([3, 1, 2, 2, 8, 10, 9, 5]) == "1-3, 5, 8-10" and seed_ranges([]) == "—"


def test_report_records_what_was_flown(tmp_path):
    """The page names the fwsim version, the spec (path, SHA-256, its text), the seeds and the dates."""
    import hashlib
    spec = tmp_path / "spec.yaml"
    spec.write_text("name: demo\nruns:\n  - scenario: x.yaml\n    seeds: [1, 2, 3]\n")
    digest = hashlib.sha256(spec.read_bytes()).hexdigest()
    rows = [dict(r, seed=i + 1) for i, r in enumerate(_rows())] + [_no_dive(0)]
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "summary.json").write_text(json.dumps({"batch": {
        "name": "demo", "spec": str(spec), "spec_sha256": digest, "spec_text": spec.read_text(),
        "fwsim_version": "0.1.0", "written_utc": "2030-01-02T03:04:05+00:00"}, "rows": rows}))
    rep, path = write_report(tmp_path / "out")
    flown = dict(rep.flown)
    assert flown["spec"] == f"{spec} (SHA-256 {digest}, the file unchanged since)"
    assert flown["seeds"] == "1-6, 20 (7 runs)"
    assert flown["flown with"] == "fwsim 0.1.0, batch written 2030-01-02T03:04:05+00:00"
    assert flown["report made"].startswith("20") and "by fwsim" in flown["report made"]
    page = path.read_text()
    assert "What was flown" in page and digest in page and "seeds: [1, 2, 3]" in page and "1-6, 20" in page
    assert "never dived" in page and "1 of 7 runs: ended in phase 2 (loiter:nmpc)" in page
    spec.write_text("name: changed\n")  # the file edited after the batch: the page says so, shows the flown text
    rep, path = write_report(tmp_path / "out")
    assert "the file has changed since" in dict(rep.flown)["spec"] and "seeds: [1, 2, 3]" in path.read_text()


def test_report_html_and_cli(tmp_path, capsys):
    (tmp_path / "summary.json").write_text(json.dumps(
        {"batch": {"name": "demo", "dispersed": ["target.speed_m_s"]}, "rows": _rows()}))
    rep, path = write_report(tmp_path)
    page = path.read_text()
    assert page.count("data:image/png;base64,") == 3 and "Wilson" in page and "fwsim replay /tmp/logs/r4.mcap" in page
    assert "http" not in page.replace("http-equiv", "")  # self-contained: nothing fetched
    assert main(["report", str(tmp_path)]) == 0
    assert "P(hit) = 0.667" in capsys.readouterr().out
    with pytest.raises(ReportError):
        write_report(tmp_path / "nothing")
    assert main(["report", str(tmp_path / "nothing")]) == 2


def test_the_envelope_verdict_splits_by_estimator():
    import importlib.util

    from fwsim import PROJECT_ROOT
    spec = importlib.util.spec_from_file_location("envelope_tool", PROJECT_ROOT / "tools" / "envelope.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    rows = [dict(r, **{"set.controllers.estimator": "ct_ukf"}) for r in _rows()] + _rows()[:4]
    table = {name: (n, shares, cover, fov)
             for name, n, shares, cover, fov in tool.verdict(rows, "set.controllers.estimator")}
    assert table["ct_ukf"][0] == 6 and table["(the scenario's)"][0] == 4
    assert table["(the scenario's)"][2] == pytest.approx(0.6)  # median of 0.9, 0.5, 0.2, 0.7
    assert table["ct_ukf"][1][0] == pytest.approx(4 / 6) and table["(the scenario's)"][1][0] == 1.0
    assert table["(the scenario's)"][1][1] == pytest.approx(3 / 4)  # r3 misses by 4 m
    # the view bar counts the ship seen (r1 hidden behind the airframe 3 % of the time), the last column the
    # field of view alone (r2 out of it 2 %)
    own = table["(the scenario's)"]
    assert own[1][2] == pytest.approx(2 / 4) and own[3] == pytest.approx(3 / 4)


def test_estimator_consistency_share_against_a_known_gaussian():
    """estimator_pos_err_within_2std_fraction's statistic: an honest std covers a round 2-D Gaussian error 86.5 %
    of the time at twice the std (1 - exp(-2)); a std three times too small covers far less."""
    import numpy as np

    from fwsim.analysis.metrics import share_within
    rng = np.random.default_rng(5)
    err = np.hypot(*rng.normal(0.0, 4.0, size=(2, 20000)))
    std = np.full(err.size, 4.0)
    assert share_within(err, std) == pytest.approx(1.0 - math.exp(-2.0), abs=0.01)
    assert share_within(err, std / 3.0) == pytest.approx(1.0 - math.exp(-2.0 / 9.0), abs=0.01)
    std[:10000] = np.nan  # samples without a std are left out
    assert share_within(err, std) == pytest.approx(1.0 - math.exp(-2.0), abs=0.015)
    assert math.isnan(share_within(err[:3], np.full(3, np.nan)))


def _envelope_tool():
    import importlib.util

    from fwsim import PROJECT_ROOT
    spec = importlib.util.spec_from_file_location("envelope_tool", PROJECT_ROOT / "tools" / "envelope.py")
    tool = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(tool)
    return tool


def test_the_envelope_why_gives_the_estimate_error_in_the_ships_frame():
    """--why's (bow, port) error, by hand: a ship heading east has its bow east and port north; one heading
    north, bow north and port west; the heading interpolated across north stays near north (not south,
    as a plain interpolation of 350 and 10 deg would give); no estimate yet: NaN."""
    import numpy as np
    tool = _envelope_tool()
    t, est = [1.0, 2.0, 3.0], np.array([[102.0, 51.0], [102.0, 51.0], [102.0, 51.0]])  # truth at (100, 50)
    truth_t, truth_xy = [0.0, 4.0], np.array([[100.0, 50.0], [100.0, 50.0]])
    east = tool.ship_frame_errors(t, est, truth_t, truth_xy, [math.pi / 2] * 2, [0.5, 2.5])
    assert math.isnan(east[0][0]) and east[1] == pytest.approx((2.0, 1.0))
    north = tool.ship_frame_errors(t, est, truth_t, truth_xy, [0.0, 0.0], [3.0])
    assert north[0] == pytest.approx((1.0, -2.0))
    across = tool.ship_frame_errors(t, est, truth_t, truth_xy, [math.radians(350.0), math.radians(370.0)], [2.0])
    assert across[0] == pytest.approx((1.0, -2.0))  # 360 deg at t = 2: north
    used, top = tool.last_detections([0.0, 6.0, 7.0, 8.0, 9.0, 10.0],
                                     ["size_mismatch", "used", "size_mismatch", "size_mismatch", "used",
                                      "too_close"], end_s=10.0)
    assert used == pytest.approx(0.5) and top == "size_mismatch 2"  # the coast's and the earlier one left out


def test_the_envelope_why_reads_a_flights_log(tmp_path, capsys):
    """--why on a real flight's log (the paper's terminal case, marked as a 4 m miss in its summary): its
    row lists the failed bar, finite estimate errors and the share of detections fused."""
    import yaml

    from fwsim.batch.cases import terminal_case
    from fwsim.sim.loop import run
    from fwsim.scenario.model import parse_scenario
    text = yaml.safe_dump(terminal_case(-30.0, 30.0, 0.0, 5.0), sort_keys=False)
    (tmp_path / "logs").mkdir()
    result = run(parse_scenario(text), text, tmp_path / "logs" / "t.mcap")
    assert result.reason.startswith("hit the ship")
    row = {"id": "t", "status": "completed", "hit": 1.0, "miss_distance_m": 4.0, "miss_bow_m": 4.0,
           "miss_port_m": 0.0, "impact_fpa_error_deg": 0.5, "impact_heading_error_deg": -0.5,
           "target_in_fov_fraction_after_lock": 1.0, "log": "logs/t.mcap", "set.target.speed_m_s": 5.0}
    (tmp_path / "summary.json").write_text(json.dumps({"rows": [row]}))
    assert _envelope_tool().main([str(tmp_path), "--why"]) == 1  # 0 of 1 within 3 m: a bar not met
    line = [x for x in capsys.readouterr().out.splitlines() if x.startswith("| t |")]
    assert len(line) == 1, line
    cells = [c.strip() for c in line[0].strip("|").split("|")]
    assert cells[1] == "distance" and cells[2] == "4.00"
    assert cells[7] == "-"  # the row predates target_hidden_longest_s_after_lock
    errs = [tuple(float(v) for v in c.split(",")) for c in cells[8:11]]
    assert all(math.isfinite(b) and math.isfinite(p) and math.hypot(b, p) < 8.0 for b, p in errs), cells
    along, across = (float(v) for v in cells[11].split(","))  # 150 m out, along / across the line of sight
    assert math.isfinite(along) and math.isfinite(across) and math.hypot(along, across) < 8.0, cells
    assert cells[12].endswith("%") and 0.0 < float(cells[12].rstrip(" %")) <= 100.0, cells
    assert 0.0 <= float(cells[14]) < 8.0, cells  # the aim line 80-50 m out: finite, the dive closed on the ship
    assert cells[15] == "none", cells  # a straight ship: no turn and no periodic course handed on
    source, err, unit = cells[16].split(" ")[:3]  # a 5 m/s ship: its heading from the estimated course
    assert source == "course" and unit == "deg" and abs(int(err)) <= 10, cells
    # --why-estimate on the same log: its section, and a row for the run only if its estimate fails the bar
    row["switch_time_s"] = 0.0
    (tmp_path / "summary.json").write_text(json.dumps({"rows": [row]}))
    _envelope_tool().main([str(tmp_path), "--why-estimate"])
    out = capsys.readouterr().out
    assert "Runs failing the estimate bar in" in out
    rows = [x for x in out.splitlines() if x.startswith("| t |")]
    assert rows == [] and out.rstrip().endswith("none") or \
        len(rows) == 1 and rows[0].split("|")[2].strip() in ("never converged", "over 8 m"), out


def test_the_envelope_why_names_the_topic_a_short_log_lacks(tmp_path, capsys):
    """A run that ended before its estimator began: --why's row says which topic its log lacks."""
    import yaml

    from fwsim import PROJECT_ROOT as root
    from fwsim.sim.loop import run
    from fwsim.scenario.model import parse_scenario
    data = yaml.safe_load((root / "scenarios" / "paper_mission.yaml").read_text())
    data["duration_s"] = 1.0  # over long before the lock
    text = yaml.safe_dump(data, sort_keys=False)
    (tmp_path / "logs").mkdir()
    run(parse_scenario(text), text, tmp_path / "logs" / "t.mcap")
    row = {"id": "t", "status": "completed", "hit": 0.0, "miss_distance_m": 900.0, "log": "logs/t.mcap",
           "target_in_fov_fraction_after_lock": 0.0}
    (tmp_path / "summary.json").write_text(json.dumps({"rows": [row]}))
    _envelope_tool().main([str(tmp_path), "--why"])
    line = [x for x in capsys.readouterr().out.splitlines() if x.startswith("| t |")]
    assert len(line) == 1, line
    cells = [c.strip() for c in line[0].strip("|").split("|")]
    assert cells[8] == "(log: no /fsw/estimate)" and set(cells[9:]) == {"-"}, cells


def test_the_envelope_why_course_model_by_hand():
    """--why's course-model cell from /fsw/course_turn's last record: a periodic course, a steady turn, none,
    a log from before the periodic course (no period field), no record."""
    model = _envelope_tool().course_model
    nan = math.nan
    assert model({"t_s": [1.0, 2.0], "period_s": [nan, 59.6], "amplitude_deg": [nan, 20.4],
                  "turn_rate_deg_s": [0.0, -1.2]}) == "periodic 60 s, 20 deg"
    assert model({"t_s": [1.0, 2.0], "period_s": [59.6, nan], "amplitude_deg": [20.4, nan],
                  "turn_rate_deg_s": [0.0, 1.5]}) == "turn +1.50 deg/s"
    assert model({"t_s": [1.0], "turn_rate_deg_s": [0.0]}) == "none"
    assert model({"t_s": []}) == "-" and model({}) == "-"


def test_the_envelope_why_heading_in_use_by_hand():
    """--why's heading cell: the status in force at the dive's start (the last at or before it), its heading
    against the truth's interpolated there (wrapped to +-180 deg across north), from the course when there is
    one, else from the shapes when they are in use, else unknown; the layout's other end named."""
    tool = _envelope_tool()
    nan = math.nan
    sh = {"t_s": [10.0, 20.0, 30.0], "course_deg": [nan, 5.0, nan], "in_use": [False, False, True],
          "best_heading_deg": [90.0, 0.0, 178.0], "layout_in_use": ["class", "other_end", "class"]}
    truth_t, truth_hdg = [0.0, 40.0], [math.radians(350.0), math.radians(370.0)]  # 350 -> 10 deg, across north
    assert tool.heading_in_use(sh, truth_t, truth_hdg, 15.0) == "unknown"
    assert tool.heading_in_use(sh, truth_t, truth_hdg, 25.0) == "course +5 deg, other end"  # truth 0 at t = 20
    assert tool.heading_in_use(sh, truth_t, truth_hdg, 30.0) == "shapes +173 deg"  # truth 5: bow and stern swapped
    assert tool.heading_in_use(sh, truth_t, truth_hdg, 5.0) == "-"


def test_the_envelope_why_size_by_hand():
    """--why's size cell: the status in force at the dive's start, the fitted scales times the class's sizes over
    the ship's own; the class's sizes over the ship's while the fit is not in use; "-" before any status."""
    tool = _envelope_tool()
    sh = {"t_s": [10.0, 20.0], "size_in_use": [False, True],
          "size_scale": [[1.3, 0.9, 1.1], [1.1, 0.8, 1.6]]}
    cls, ship = (55.0, 25.0, 25.0), (55.0, 20.0, 20.0)
    assert tool.size_over_ship(sh, 15.0, cls, ship) == "1.00, 1.25, 1.25 (the class's)"
    assert tool.size_over_ship(sh, 25.0, cls, ship) == "1.10, 1.00, 2.00"
    assert tool.size_over_ship(sh, 5.0, cls, ship) == "-"


def test_the_envelope_line_of_sight_error_by_hand():
    """--why's line-of-sight split: a UAV flying east along y = 0 towards a ship at (200, 0, 0) is last 150 m
    or more from it at x = 50 (t = 5); the estimate then, (203, 1), is 3 m beyond the ship along the line of
    sight and 1 m to its left (north); seen from the south instead it is 1 m beyond and 3 m to the right (the
    other view turns the same error); never that far: NaN."""
    import numpy as np
    tool = _envelope_tool()
    uav_t = np.arange(0.0, 11.0)
    east = np.column_stack([10.0 * uav_t, np.zeros(11), np.zeros(11)])  # x = 0 ... 100 m
    truth_t, ship = [0.0, 10.0], np.array([[200.0, 0.0, 0.0], [200.0, 0.0, 0.0]])
    est_t, est = [4.5, 5.5], np.array([[203.0, 1.0], [250.0, 50.0]])  # the second comes after: not used
    assert tool.line_of_sight_error(est_t, est, truth_t, ship, uav_t, east) == pytest.approx((3.0, 1.0))
    north = np.column_stack([np.full(11, 200.0), 10.0 * uav_t - 205.0, np.zeros(11)])  # 155 m out at t = 5
    assert tool.line_of_sight_error(est_t, est, truth_t, ship, uav_t, north) == pytest.approx((1.0, -3.0))
    near = east + np.array([150.0, 0.0, 0.0])  # 50 m out to at most 50 m past: never 150 m away
    assert all(math.isnan(v) for v in tool.line_of_sight_error(est_t, est, truth_t, ship, uav_t, near))


def test_the_envelope_why_estimate_by_hand():
    """--why-estimate's verdict on a run's estimate, by hand (one estimate a second, the truth at the origin):
    a std under 5 m from t = 3 s and one error of 9 m at t = 5 s: over 8 m 2 s after convergence, in the
    loiter (the dive starts at 8 s), for one estimate's spacing; the same run with the std over 5 m again from
    t = 8 s never converged, its std last under 5 m 3 s before the end, its largest error from the dive's start
    2 m; with boxes fused up to t = 8 s its std at the last fused box is the 6 m it went over with, 2 s before
    the end (with boxes fused to t = 7 s only: 3 m, 3 s before, the std's rise came in the coast); an error of
    8 m at most: it meets the bar."""
    import numpy as np
    tool = _envelope_tool()
    t = np.arange(0.0, 11.0)
    err = np.full(11, 2.0)
    err[5] = 9.0
    est = np.column_stack([err, np.zeros(11)])
    std = np.where(t < 3.0, 6.0, 3.0)
    stds = np.column_stack([std, std / 2.0])  # the larger axis counts
    truth_t, truth = [0.0, 20.0], np.zeros((2, 2))
    f = tool.estimate_failure(t, est, stds, truth_t, truth, lock_t_s=0.0, switch_t_s=8.0)
    assert f["kind"] == "over 8 m" and f["converged_s"] == 3.0 and f["err_max_m"] == pytest.approx(9.0)
    assert f["err_max_after_s"] == 2.0 and f["phase"] == "loiter" and f["std_then_m"] == 3.0 and f["over_s"] == 1.0
    std_late = np.column_stack([np.where(t >= 8.0, 6.0, std), std / 2.0])
    g = tool.estimate_failure(t, est, std_late, truth_t, truth, lock_t_s=0.0, switch_t_s=8.0)
    assert g["kind"] == "never converged" and math.isnan(g["converged_s"]) and g["std_end_m"] == 6.0
    assert g["under_last_s_before_end"] == 3.0 and g["err_max_dive_m"] == pytest.approx(2.0)
    assert math.isnan(g["std_last_box_m"]) and math.isnan(g["last_box_s_before_end"])  # no fused mask given
    for last_box, std_there, before in ((8.0, 6.0, 2.0), (7.0, 3.0, 3.0)):
        h = tool.estimate_failure(t, est, std_late, truth_t, truth, lock_t_s=0.0, switch_t_s=8.0, fused=t <= last_box)
        assert h["std_last_box_m"] == std_there and h["last_box_s_before_end"] == before
    est[5, 0] = 8.0
    assert tool.estimate_failure(t, est, stds, truth_t, truth, lock_t_s=0.0, switch_t_s=8.0) is None


def test_the_envelope_aim_line_offset_by_hand():
    """--why's aim line: a UAV at the origin steering to (60, 0, 0) (range 60 m, in the band) passes a true
    aim point at (30, 4, 3) by 5 m (the along-line error costs nothing); ticks out of the 50-80 m band are
    left out; none in the band: NaN."""
    import numpy as np
    tool = _envelope_tool()
    uav_t, uav_p = np.array([0.0, 10.0]), np.zeros((2, 3))
    aim = np.array([[60.0, 0.0, 0.0], [200.0, 50.0, 0.0]])  # the second tick 206 m out: not counted
    off = tool.aim_line_offset([1.0, 2.0], aim, [60.0, 206.2], uav_t, uav_p, lambda t: np.array([30.0, 4.0, 3.0]))
    assert off == pytest.approx(5.0)
    far = tool.aim_line_offset([1.0], aim[1:], [206.2], uav_t, uav_p, lambda t: np.zeros(3))
    assert math.isnan(far)


def test_longest_hidden_stretch_by_hand():
    """The longest stretch without a frame that sees the ship: from the last frame that saw it (or the first
    frame) to the next that sees it (or the last frame)."""
    from fwsim.analysis.metrics import longest_gap_s
    t = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    assert longest_gap_s(t, [True] * 7) == 0.0
    assert longest_gap_s(t, [True, False, False, True, True, False, True]) == 3.0  # seen at 0, then at 3
    assert longest_gap_s(t, [False, False, True, True, True, True, False]) == 2.0  # from the start to 2
    assert longest_gap_s(t, [True, True, True, True, False, False, False]) == 3.0  # 3 to the end
    assert longest_gap_s(t, [False] * 7) == 6.0 and longest_gap_s([], []) == 0.0


def test_the_envelope_verdict_by_folder(tmp_path, capsys):
    """--by folder: one row per output folder, in the order given (the envelope and its draws with a factor
    held, fwsim batch --hold), each scored on its own rows."""
    (tmp_path / "full").mkdir()
    (tmp_path / "held").mkdir()
    rows = _rows()
    (tmp_path / "full" / "summary.json").write_text(json.dumps({"rows": rows}))
    (tmp_path / "held" / "summary.json").write_text(json.dumps({"rows": rows[:4]}))
    _envelope_tool().main([str(tmp_path / "held"), str(tmp_path / "full"), "--by", "folder"])
    lines = [ln.split(" | ")[0:2] for ln in capsys.readouterr().out.splitlines() if str(tmp_path) in ln]
    assert lines == [[f"| {tmp_path / 'held'}", "4"], [f"| {tmp_path / 'full'}", str(len(rows))]]
    assert _envelope_tool().main([str(tmp_path / "full"), str(tmp_path)]) == 2  # not a batch's output folder
    assert capsys.readouterr().err.strip() == f"error: {tmp_path}: no summary.json (the output folder of `fwsim batch`)"


def test_the_envelope_paired_comparison_by_hand(tmp_path, capsys):
    """--paired: two folders of the same draws, matched by scenario and seed. The second's r0 misses by 5 m
    (within 3 m / 3 deg lost, worse by over 1 m), its r3 by 1.5 m (within gained, better), its r1 by 1.4 m
    instead of 1 m (neither); r5 flew in the first only; the changed estimator is named."""
    tool = _envelope_tool()
    first = [dict(r, scenario="e", seed=i) for i, r in enumerate(_rows())]
    second = [dict(r, **{"set.controllers.estimator": "ct_ukf"}) for r in first[:5]]
    second[0]["miss_distance_m"] = 5.0
    second[3]["miss_distance_m"] = 1.5
    second[1]["miss_distance_m"] = 1.4
    second[2]["estimator_pos_err_max_after_convergence_m"] = math.nan  # never converged: the estimate bar not met
    second[2]["estimator_pos_rmse_m"] = 6.0
    p = tool.paired(first, second)
    assert len(p["pairs"]) == 5 and p["unmatched"] == (1, 0)
    within_bar = [name for name, _ in tool.BARS].index("within 3 m / 3 deg")
    assert [ra["id"] for ra, _ in p["lost"][within_bar]] == ["r0"]
    assert [ra["id"] for ra, _ in p["gained"][within_bar]] == ["r3"]
    assert [ra["id"] for ra, _ in p["worse"]] == ["r0"] and [ra["id"] for ra, _ in p["better"]] == ["r3"]
    assert [ra["id"] for ra, _ in p["lost"][3]] == [] and [ra["id"] for ra, _ in p["gained"][3]] == []  # r2: 9 m
    assert p["differ"] == {"set.controllers.estimator": (None, "ct_ukf")}
    assert tool.run_bars(first[4]) == (False, False, False, None)  # no hit, no estimate: not counted
    assert tool.run_bars(first[5])[2] is None  # a failed run has no view share
    # the command line: two folders written as fwsim batch writes them
    for name, rows in (("a", first), ("b", second)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "summary.json").write_text(json.dumps({"rows": rows}))
    assert tool.main([str(tmp_path / "a"), str(tmp_path / "b"), "--paired"]) == 1  # bars not met
    out = capsys.readouterr().out
    assert "5 runs of the same scenario and seed in both (1 of the first and 0 of the second" in out
    assert "better by over 1 m in 1 runs, worse by over 1 m in 1, within 1 m of each other in 3" in out
    row = [x for x in out.splitlines() if x.startswith("| r0 |")]
    assert len(row) == 1 and "| 0.50 | 5.00 | ++++ | +-++ |" in row[0], out
    # one folder, or two without a common draw: a one-line error, exit code 2
    assert tool.main([str(tmp_path / "a"), "--paired"]) == 2
    other = [dict(r, seed=100 + i) for i, r in enumerate(first)]
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "summary.json").write_text(json.dumps({"rows": other}))
    capsys.readouterr()
    assert tool.main([str(tmp_path / "a"), str(tmp_path / "c"), "--paired"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --paired: no run of") and err.count("\n") == 1


def test_the_envelope_loiter_errors_by_hand():
    """--loiter's per-run numbers: the estimates from 60 s after the lock to the dive's start only, their
    horizontal errors against the truth interpolated to their times, the median of each."""
    import numpy as np
    tool = _envelope_tool()
    t = np.arange(0.0, 200.0, 1.0)
    truth_t = np.array([0.0, 200.0])
    truth_pos = np.array([[0.0, 0.0], [400.0, 0.0]])  # 2 m/s east
    truth_vel = np.array([[2.0, 0.0], [2.0, 0.0]])
    # 50 m off before 70 s (the lock at 10 s, then 60 s: not scored), 3 m to 120 s (50 estimates), 1 m after
    # (30 estimates to the dive at 150 s): the median 3 m
    pos = np.c_[2.0 * t, np.select([t < 70.0, t < 120.0], [50.0, 3.0], 1.0)]
    pos[100] = np.nan  # an estimate without a position is left out
    vel = np.c_[np.full(t.size, 2.0), np.where(t < 150.0, 0.5, 9.0)]  # 9 m/s off only in the dive
    pe, ve = tool.loiter_errors(t, pos, vel, truth_t, truth_pos, truth_vel, lock_t_s=10.0, switch_t_s=150.0)
    assert pe == pytest.approx(3.0) and ve == pytest.approx(0.5)
    pe, _ = tool.loiter_errors(t, pos, vel, truth_t, truth_pos, truth_vel, lock_t_s=10.0, switch_t_s=100.0)
    assert pe == pytest.approx(3.0)
    pe, _ = tool.loiter_errors(t, pos, vel, truth_t, truth_pos, truth_vel, lock_t_s=80.0, switch_t_s=math.nan)
    assert pe == pytest.approx(1.0)  # from 140 s to the end: 1 m
    assert all(math.isnan(x) for x in tool.loiter_errors(t, pos, vel, truth_t, truth_pos, truth_vel, 10.0, 50.0))
