"""fwsim batch: spec expansion, process pool, failures as rows, resume, Ray."""
import csv
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fwsim import SCENARIO_DIR
from fwsim.batch.runner import BASE_COLUMNS, BatchSpecError, SpecChanges, load_spec, run_batch, run_id, run_one
from fwsim.log import read_log
from fwsim.scenario.model import ScenarioError, load_scenario

CHECKOUT = (SCENARIO_DIR / "autopilot_checkout.yaml").as_posix()


def write_spec(tmp_path: Path, text: str, name: str = "spec.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def assert_same_row(a: dict, b: dict, skip=()) -> None:
    """Equal rows (NaN equals NaN), apart from the ``skip`` columns."""
    assert set(a) - set(skip) == set(b) - set(skip)
    for k in set(a) - set(skip):
        same = a[k] == b[k] or (isinstance(a[k], float) and isinstance(b[k], float)
                                and math.isnan(a[k]) and math.isnan(b[k]))
        assert same, f"{a['id']}: {k}: {a[k]!r} != {b[k]!r}"


def crash_on_seed_2(job):
    """A run function whose worker process dies for seed 2 (as a segfault would)."""
    if job.seed == 2:
        os._exit(3)
    return run_one(job)


# -- the spec -------------------------------------------------------------------

def test_spec_expands_to_the_cartesian_product_with_stable_ids(tmp_path):
    (tmp_path / "sc").mkdir()
    (tmp_path / "sc" / "co.yaml").write_text(Path(CHECKOUT).read_text())
    spec = write_spec(tmp_path, """
runs:
  - scenario: sc/co.yaml            # relative to the spec
    seeds: {range: [1, 4]}          # 1, 2, 3
    grid: {initial.airspeed_m_s: [20, 24], initial.heading_deg: [0, 90]}
    set: {duration_s: 5}
  - scenario: sc/co.yaml
""")
    name, jobs = load_spec(spec, tmp_path / "out")
    assert name == "spec"
    assert len(jobs) == 3 * 2 * 2 + 1
    assert len({j.id for j in jobs}) == len(jobs)
    first = jobs[0]
    assert first.overrides == {"duration_s": 5, "initial.airspeed_m_s": 20, "initial.heading_deg": 0}
    assert [j.seed for j in jobs[:3]] == [1, 2, 3]
    assert first.scenario_file == str((tmp_path / "sc" / "co.yaml").resolve())
    assert first.log_path == str((tmp_path / "out" / "logs" / f"{first.id}.mcap").resolve())
    # The last entry: no seeds, no grid: the scenario's own seed (1) and no overrides.
    assert jobs[-1].seed == 1 and jobs[-1].overrides == {}
    # Ids are pinned: name, seed, SHA-256 of the canonical overrides (resume relies on it).
    assert first.id == run_id("autopilot_checkout", 1, {"initial.heading_deg": 0, "initial.airspeed_m_s": 20,
                                                          "duration_s": 5})
    assert run_id("autopilot_checkout", 3, {}) == "autopilot_checkout-s3-44136fa3"
    assert load_spec(spec, tmp_path / "out")[1] == jobs  # same spec, same ids


@pytest.mark.parametrize("body, message", [
    ("runs: []", "non-empty 'runs:'"),
    ("runs: [{scenario: SC}]\nfoo: 1", "foo: unknown key"),
    ("runs: [{scenario: SC, seed: [1]}]", "runs.0.seed: unknown key"),
    ("runs: [{scenario: nope.yaml}]", "runs.0.scenario: no such scenario file"),
    ("runs: [{scenario: SC, seeds: {range: [1]}}]", "runs.0.seeds.range"),
    ("runs: [{scenario: SC, seeds: [-1]}]", "runs.0.seeds"),
    ("runs: [{scenario: SC, grid: {initial.airspeed_m_s: 20}}]",
     "grid.initial.airspeed_m_s: expected a non-empty list"),
    ("runs: [{scenario: SC, seeds: [1], set: {seed: 2}}]", "not both"),
    ("runs: [{scenario: SC, grid: {initial.airspeed_m_s: [-5]}}]", "initial.airspeed_m_s: Input should be greater"),
    ("runs: [{scenario: SC, seeds: [1, 1]}]", "more than once"),
])
def test_spec_errors_are_one_line(tmp_path, body, message):
    spec = write_spec(tmp_path, body.replace("SC", CHECKOUT))
    with pytest.raises(BatchSpecError, match=message) as err:
        load_spec(spec, tmp_path / "out")
    assert "\n" not in str(err.value)


# -- flying a batch ---------------------------------------------------------------

SPEC = f"""
name: small
runs:
  - scenario: {CHECKOUT}
    seeds: [1, 2]
    grid: {{initial.airspeed_m_s: [20, 9]}}    # 9 m/s: JSBSim cannot trim, the run fails
    set: {{duration_s: 5}}
"""


@pytest.fixture(scope="module")
def pool_batch(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("batch")
    spec = write_spec(tmp, SPEC)
    rows_seen = []
    result = run_batch(spec, tmp / "out", workers=2, on_row=rows_seen.append)
    return spec, tmp / "out", result, rows_seen


def test_batch_rows_and_summary_files(pool_batch):
    spec, out, result, rows_seen = pool_batch
    assert len(result.rows) == 4 and len(rows_seen) == 4
    by_speed = {r["set.initial.airspeed_m_s"]: [] for r in result.rows}
    for r in result.rows:
        by_speed[r["set.initial.airspeed_m_s"]].append(r)
    for r in by_speed[20]:
        assert r["status"] == "completed" and r["error"] == "" and r["reason"] == "duration reached"
        assert r["flight_time_s"] == pytest.approx(5.0, abs=1e-6)
        assert r["wall_time_s"] > 0 and not r["resumed"]
        assert (out / r["log"]).is_file() and read_log(out / r["log"]).status == "completed"
    for r in by_speed[9]:  # a run that raised: a failed row with its error, the batch goes on
        assert r["status"] == "failed" and "trim failed" in r["error"] and "trim failed" in r["reason"]
        assert "trimmable" in r["error"]  # JSBSim's own message, in the error (not on the terminal)
        assert not (out / r["log"]).with_suffix(".console.txt").exists()  # (nothing else was printed)
    assert [r["id"] for r in result.rows] == [j.id for j in load_spec(spec, out)[1]]  # spec order
    assert {p.name for p in result.files} >= {"summary.csv", "summary.json"}

    with open(out / "summary.csv") as f:
        table = list(csv.DictReader(f))
    assert [r["id"] for r in table] == [r["id"] for r in result.rows]
    assert list(table[0])[: len(BASE_COLUMNS)] == list(BASE_COLUMNS)
    assert float(table[0]["roll_rate_err_rms_deg_s"]) == result.rows[0]["roll_rate_err_rms_deg_s"]  # full precision
    data = json.loads((out / "summary.json").read_text())
    assert data["batch"]["runs"] == 4 and data["batch"]["failed"] == 2 and data["batch"]["name"] == "small"
    assert [r["id"] for r in data["rows"]] == [r["id"] for r in result.rows]
    try:
        import pyarrow.parquet as pq
    except ImportError:
        assert not (out / "summary.parquet").exists()
    else:
        assert pq.read_table(out / "summary.parquet").num_rows == 4


def test_summary_hit_is_a_bool_and_runs_that_never_dived_are_told(pool_batch):
    """hit is true/false in every summary; the checkout never dives: no miss distance, a note why, not a hit; the
    summary records the spec it flew (path, SHA-256, text) for the report."""
    import hashlib

    from fwsim.analysis.report import summarise
    spec, out, result, _ = pool_batch
    done = [r for r in result.rows if r["status"] == "completed"]
    assert done and all(r["hit"] is False and r["miss_distance_m"] is None for r in done)
    assert all(r["terminal_note"].startswith("no terminal phase: the run ended in phase 0 (script)") for r in done)
    data = json.loads((out / "summary.json").read_text())
    assert [r.get("hit") for r in data["rows"] if r["status"] == "completed"] == [False] * len(done)
    assert data["batch"]["spec_sha256"] == hashlib.sha256(spec.read_bytes()).hexdigest()
    assert data["batch"]["spec_text"] == spec.read_text()
    with open(out / "summary.csv") as f:
        table = [r for r in csv.DictReader(f) if r["status"] == "completed"]
    assert {r["hit"] for r in table} == {"false"} and {r["miss_distance_m"] for r in table} == {""}
    rep = summarise(data["rows"])
    assert rep.hits == 0 and rep.hit_probability == 0.0 and rep.dived == 0
    assert rep.never_dived == {"ended in phase 0 (script), duration reached": len(done)}
    assert dict(rep.headline())["miss distance CEP50 / CEP90"] == "— (no run dived)"


def test_resume_keeps_finished_logs_and_flies_the_rest(pool_batch, tmp_path):
    spec, out, result, _ = pool_batch
    resumed_out = tmp_path / "out"
    # Copy the batch; then lose one completed log and cut another one short (a hard kill).
    (resumed_out / "logs").mkdir(parents=True)
    for f in (out / "logs").iterdir():
        (resumed_out / "logs" / f.name).write_bytes(f.read_bytes())
    (resumed_out / "summary.json").write_text((out / "summary.json").read_text())
    done = [r for r in result.rows if r["status"] == "completed"]
    (resumed_out / done[0]["log"]).unlink()
    cut = resumed_out / done[1]["log"]
    data = cut.read_bytes()
    cut.write_bytes(data[: data.index(b"run_status")])  # cut before the status record
    assert read_log(cut).status == "unknown"
    kept = {r["id"]: (resumed_out / r["log"]).stat().st_mtime_ns for r in result.rows if r["status"] == "failed"}

    flown = []
    again = run_batch(spec, resumed_out, workers=2, resume=True, on_row=lambda r: flown.append(r["id"]))
    assert sorted(flown) == sorted([done[0]["id"], done[1]["id"]])
    assert again.resumed == 2
    for old, new in zip(result.rows, again.rows):
        assert new["resumed"] == (new["id"] in kept)
        assert_same_row(new, old, skip=("wall_time_s", "resumed"))
        if new["resumed"]:
            assert new["wall_time_s"] == old["wall_time_s"]  # from the previous summary.json
    for rid, mtime in kept.items():
        assert (resumed_out / "logs" / f"{rid}.mcap").stat().st_mtime_ns == mtime


def test_a_dying_worker_is_a_failed_row(tmp_path):
    spec = write_spec(tmp_path, f"runs: [{{scenario: {CHECKOUT}, seeds: [1, 2], set: {{duration_s: 3}}}}]")
    result = run_batch(spec, tmp_path / "out", workers=2, run_fn=crash_on_seed_2)
    rows = {r["seed"]: r for r in result.rows}
    assert rows[1]["status"] == "completed"
    assert rows[2]["status"] == "failed" and "worker process died" in rows[2]["error"]
    assert len(json.loads((tmp_path / "out" / "summary.json").read_text())["rows"]) == 2


def test_cli_batch(tmp_path):
    spec = write_spec(tmp_path, f"runs: [{{scenario: {CHECKOUT}, seeds: [1, 2], set: {{duration_s: 3}}}}]")
    proc = subprocess.run([sys.executable, "-m", "fwsim.cli", "batch", str(spec), "--out", str(tmp_path / "o"),
                           "--workers", "2", "--quiet"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "2 completed, 0 failed" in proc.stderr and "summary.csv" in proc.stdout
    disp = write_spec(tmp_path, DISPERSED.replace("samples: 6", "samples: 2"), "disp.yaml")
    proc = subprocess.run([sys.executable, "-m", "fwsim.cli", "batch", str(disp), "--out", str(tmp_path / "o3"),
                           "--workers", "2", "--quiet", "--seed", "5", "--hold", "world", "--set", "duration_s=1"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    info = json.loads((tmp_path / "o3" / "summary.json").read_text())["batch"]
    assert info["changes"] == {"seed": 5, "set": {"duration_s": 1}, "hold": ["world"]}
    assert "world.wind_enu_m_s" not in info["dispersed"]
    for args, message in ((["--hold", "nothing.here"], "--hold nothing.here: no entry"),
                          (["--set", "duration_s"], "expected PATH=VALUE"), (["--seed", "-1"], "--seed: expected"),
                          (["--workers", "0"], "--workers: expected"),
                          # a bad --set value named on its own, not with the first draw it spoiled
                          (["--set", "camera.detector.miss_probability=abc"],
                           "runs.0.set: ")):
        proc = subprocess.run([sys.executable, "-m", "fwsim.cli", "batch", str(disp), "--out", str(tmp_path / "o4"),
                               *args], capture_output=True, text=True, timeout=300)
        assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
        assert args[-1].split("=")[0] in proc.stderr and "initial.heading_deg" not in proc.stderr, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr  # one line, no draw dumped
    bad = write_spec(tmp_path, "runs: [{scenario: nope.yaml}]", "bad.yaml")
    proc = subprocess.run([sys.executable, "-m", "fwsim.cli", "batch", str(bad), "--out", str(tmp_path / "o2")],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "no such scenario file" in proc.stderr and "Traceback" not in proc.stderr


def test_ray_rows_equal_process_pool_rows(pool_batch, tmp_path):
    ray = pytest.importorskip("ray", reason="ray is not installed (pip install 'fwsim[ray]')")
    _, _, pool_result, _ = pool_batch
    spec = write_spec(tmp_path, f"""
runs:
  - scenario: {CHECKOUT}
    seeds: [1, 2]
    grid: {{initial.airspeed_m_s: [20]}}
    set: {{duration_s: 5}}
""")
    ray.init(num_cpus=2, include_dashboard=False)
    try:
        result = run_batch(spec, tmp_path / "out", ray_address="auto")  # uses the instance started here
    finally:
        ray.shutdown()
    pool_rows = {r["id"]: r for r in pool_result.rows}
    assert len(result.rows) == 2
    for row in result.rows:
        assert row["status"] == "completed"
        assert_same_row(row, pool_rows[row["id"]], skip=("wall_time_s",))  # same overrides, same id
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["batch"]["executor"] == "ray (auto)"


GENERATED = """
name: gen
runs:
  - generator: fwsim.batch.cases:terminal_case
    args: {duration_s: 2}
    cases:
      - {theta_f_deg: -30, psi_f_deg: 30, ship_heading_deg: 0, ship_speed_m_s: 5}
      - {theta_f_deg: -40, psi_f_deg: 90, ship_heading_deg: 90, ship_speed_m_s: 0}
    seeds: [1, 2]
"""


def test_a_generated_scenario_entry_flies_each_case_and_resumes(tmp_path):
    """A generator entry: one run per case and seed, the case's arguments as columns, ids stable and
    distinct, and --resume keeps the finished runs (the generated text is what the log stores)."""
    spec = write_spec(tmp_path, GENERATED)
    name, jobs = load_spec(spec, tmp_path / "out")
    assert name == "gen" and len(jobs) == 4 and len({j.id for j in jobs}) == 4
    assert [j.case["theta_f_deg"] for j in jobs] == [-30, -30, -40, -40] and [j.seed for j in jobs] == [1, 2, 1, 2]
    assert load_spec(spec, tmp_path / "out")[1] == jobs
    res = run_batch(spec, tmp_path / "out", workers=2)
    assert [r["status"] for r in res.rows] == ["completed"] * 4, [r["reason"] for r in res.rows]
    assert [r["case.psi_f_deg"] for r in res.rows] == [30, 30, 90, 90]
    header = next(csv.reader(open(tmp_path / "out" / "summary.csv")))
    assert "case.theta_f_deg" in header and header.index("case.theta_f_deg") < header.index("flight_time_s")
    again = run_batch(spec, tmp_path / "out", workers=2, resume=True)
    assert again.resumed == 4 and all(r["resumed"] for r in again.rows)


@pytest.mark.parametrize("body, message", [
    ("runs: [{generator: fwsim.batch.cases:no_such}]", "has no function 'no_such'"),
    ("runs: [{generator: no_module_x:f}]", "cannot import 'no_module_x'"),
    ("runs: [{generator: fwsim.batch.cases:terminal_case, cases: [{theta_f_deg: -30}]}]", "TypeError"),
    ("runs: [{scenario: SC, cases: [{a: 1}]}]", "'cases' and 'args' go with a 'generator'"),
    ("runs: [{scenario: SC, generator: fwsim.batch.cases:terminal_case}]", "a 'scenario:' file or a 'generator:'"),
])
def test_generator_errors_are_one_line(tmp_path, body, message):
    spec = write_spec(tmp_path, body.replace("SC", str(SCENARIO_DIR / "autopilot_checkout.yaml")))
    with pytest.raises(BatchSpecError) as exc:
        load_spec(spec, tmp_path / "out")
    assert message in str(exc.value) and "\n" not in str(exc.value), str(exc.value)


# -- dispersions ------------------------------------------------------------------

DISPERSED = f"""
seed: 11
runs:
  - scenario: {CHECKOUT}
    samples: 6
    set: {{duration_s: 2}}
    dispersions:
      initial.airspeed_m_s: {{uniform: [19, 23]}}
      initial.heading_deg: {{uniform_angle_deg: true}}
      world.wind_enu_m_s: {{normal: [[0, 0, 0], [2, 2, 0]]}}
      camera.detector.pixel_noise_px: {{choice: [1.0, 3.0]}}
"""


def test_dispersions_draw_reproducibly_within_their_bounds(tmp_path):
    spec = write_spec(tmp_path, DISPERSED)
    _, jobs = load_spec(spec, tmp_path / "out")
    _, again = load_spec(spec, tmp_path / "elsewhere")
    assert [j.id for j in jobs] == [j.id for j in again] and [j.overrides for j in jobs] == [j.overrides for j in again]
    assert len(jobs) == 6 and len({j.id for j in jobs}) == 6
    base = load_spec(write_spec(tmp_path, f"runs: [{{scenario: {CHECKOUT}}}]", "plain.yaml"), tmp_path)[1][0].seed
    assert [j.seed for j in jobs] == [base + k for k in range(6)]  # each sample its own sensor noise
    for j in jobs:
        o = j.overrides
        assert 19 <= o["initial.airspeed_m_s"] <= 23 and 0 <= o["initial.heading_deg"] < 360
        assert len(o["world.wind_enu_m_s"]) == 3 and o["world.wind_enu_m_s"][2] == 0.0
        assert o["camera.detector.pixel_noise_px"] in (1.0, 3.0)
        assert j.dispersed == ("camera.detector.pixel_noise_px", "initial.airspeed_m_s", "initial.heading_deg",
                               "world.wind_enu_m_s")
    assert len({j.overrides["initial.airspeed_m_s"] for j in jobs}) == 6
    # another batch seed draws otherwise; dropping a field leaves the others' draws as they were
    other = load_spec(write_spec(tmp_path, DISPERSED.replace("seed: 11", "seed: 12"), "s12.yaml"), tmp_path)[1]
    assert other[0].overrides["initial.airspeed_m_s"] != jobs[0].overrides["initial.airspeed_m_s"]
    fewer = load_spec(write_spec(tmp_path, DISPERSED.replace(
        "      camera.detector.pixel_noise_px: {choice: [1.0, 3.0]}\n", ""), "fewer.yaml"), tmp_path)[1]
    assert [j.overrides["initial.airspeed_m_s"] for j in fewer] == [j.overrides["initial.airspeed_m_s"] for j in jobs]


def test_dispersed_values_are_summary_columns(tmp_path):
    spec = write_spec(tmp_path, DISPERSED.replace("samples: 6", "samples: 2"))
    res = run_batch(spec, tmp_path / "out", workers=2)
    assert [r["status"] for r in res.rows] == ["completed", "completed"]
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["batch"]["dispersed"] == ["camera.detector.pixel_noise_px", "initial.airspeed_m_s",
                                             "initial.heading_deg", "world.wind_enu_m_s"]
    for row, job in zip(summary["rows"], load_spec(spec, tmp_path / "out")[1]):
        assert row["set.initial.airspeed_m_s"] == job.overrides["initial.airspeed_m_s"]


@pytest.mark.parametrize("body, message", [
    ("dispersions: {initial.airspeed_m_s: {uniform: [23, 19]}}\n    samples: 2", "low must not exceed high"),
    ("dispersions: {initial.airspeed_m_s: {normal: [20, -1]}}\n    samples: 2", "standard deviation"),
    ("dispersions: {initial.airspeed_m_s: {beta: [1, 2]}}\n    samples: 2", "expected one of"),
    ("dispersions: {initial.airspeed_m_s: {uniform: [19, 23]}}", "samples: expected the number of draws"),
    ("samples: 3", "'samples' goes with 'dispersions'"),
    ("dispersions: {seed: {choice: [1, 2]}}\n    samples: 2", "the seed is not drawn"),
    ("dispersions: {initial.airspeed_m_s: {uniform: [100, 200]}}\n    samples: 2", "initial.airspeed_m_s"),
])
def test_dispersion_errors_are_one_line(tmp_path, body, message):
    spec = write_spec(tmp_path, f"runs:\n  - scenario: {CHECKOUT}\n    {body}\n")
    with pytest.raises(BatchSpecError, match=message) as exc:
        load_spec(spec, tmp_path)
    assert "\n" not in str(exc.value)


def test_command_line_changes_draw_hold_and_set(tmp_path):
    """--seed draws as the spec's own seed would; --hold keeps a field at the scenario's value (a prefix holds
    every field under it) and leaves the others' draws as they were; --set wins over a dispersion."""
    spec = write_spec(tmp_path, DISPERSED)
    jobs = load_spec(spec, tmp_path)[1]
    reseeded = load_spec(spec, tmp_path, SpecChanges(seed=12))[1]
    own = load_spec(write_spec(tmp_path, DISPERSED.replace("seed: 11", "seed: 12"), "s12.yaml"), tmp_path)[1]
    assert [j.overrides for j in reseeded] == [j.overrides for j in own] != [j.overrides for j in jobs]
    held = load_spec(spec, tmp_path, SpecChanges(hold=("world.wind_enu_m_s", "camera.detector")))[1]
    plain = load_scenario(CHECKOUT)[0]
    assert held[0].dispersed == ("initial.airspeed_m_s", "initial.heading_deg")
    for j, h in zip(jobs, held):
        assert "world.wind_enu_m_s" not in h.overrides and "camera.detector.pixel_noise_px" not in h.overrides
        assert h.overrides["initial.airspeed_m_s"] == j.overrides["initial.airspeed_m_s"]
        assert list(h.load()[0].world.wind_enu_m_s) == list(plain.world.wind_enu_m_s)  # the scenario's own
    fixed = load_spec(spec, tmp_path, SpecChanges(sets={"initial.airspeed_m_s": 21.5, "duration_s": 1}))[1]
    assert all(j.overrides["initial.airspeed_m_s"] == 21.5 and j.overrides["duration_s"] == 1 for j in fixed)
    assert "initial.airspeed_m_s" not in fixed[0].dispersed
    assert [j.overrides["initial.heading_deg"] for j in fixed] == [j.overrides["initial.heading_deg"] for j in jobs]


@pytest.mark.parametrize("changes, message", [
    (SpecChanges(hold=("target.speed_m_s",)), "--hold target.speed_m_s: no entry of spec.yaml disperses"),
    (SpecChanges(hold=("initial.air",)), "no entry"),  # a prefix is whole path segments
    (SpecChanges(hold=("initial.airspeed_m_s", "initial.heading_deg", "world", "camera")), "none of its dispersions"),
])
def test_command_line_change_errors_are_one_line(tmp_path, changes, message):
    with pytest.raises(BatchSpecError, match=message) as exc:
        load_spec(write_spec(tmp_path, DISPERSED), tmp_path, changes)
    assert "\n" not in str(exc.value)


def test_dispersing_inside_a_set_list_leaves_the_spec_alone(tmp_path):
    spec = write_spec(tmp_path, f"""
runs:
  - scenario: {CHECKOUT}
    samples: 3
    set:
      events: [{{kind: detector_blackout, t_s: 5.0, duration_s: 1.0}}]
    dispersions:
      events.0.t_s: {{uniform: [1.0, 2.0]}}
""")
    jobs = load_spec(spec, tmp_path)[1]
    assert all(j.overrides["events"][0]["t_s"] == 5.0 for j in jobs)
    drawn = [j.load()[0].events[0].t_s for j in jobs]
    assert drawn == [j.overrides["events.0.t_s"] for j in jobs] and all(1.0 <= t <= 2.0 for t in drawn)


def test_sigterm_to_a_batch_reaches_the_runs_in_flight(tmp_path):
    """A scheduler's SIGTERM stops the batch (exit 143) and its workers' runs: each log in flight closes as
    interrupted with the signal named."""
    import signal
    import time
    spec = write_spec(tmp_path, f"runs:\n  - scenario: {CHECKOUT}\n    seeds: [1, 2]\n    set: {{duration_s: 3000}}\n")
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "fwsim._entry", "batch", str(spec), "--out", str(out),
                             "--workers", "2", "--quiet"], stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while time.time() < deadline and sum(p.stat().st_size > 20_000 for p in out.glob("logs/*.mcap")) < 2:
        time.sleep(0.2)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    logs = [read_log(p) for p in sorted(out.glob("logs/*.mcap"))]
    assert len(logs) == 2
    for log in logs:
        assert log.status == "interrupted" and "SIGTERM" in log.reason and not log.truncated, log.reason


def test_only_flies_the_same_draws_of_the_chosen_seeds(tmp_path):
    """--only keeps the runs of the seeds named, each drawn as in the whole batch (also with a --set change),
    in the spec's order; a seed no run flies is a one-line error naming the seeds there are."""
    spec = write_spec(tmp_path, DISPERSED)
    jobs = load_spec(spec, tmp_path)[1]
    seeds = [j.seed for j in jobs]
    pick = (seeds[2], seeds[0])
    only = load_spec(spec, tmp_path, SpecChanges(only=pick))[1]
    assert [j.seed for j in only] == [seeds[0], seeds[2]]
    assert [j.overrides for j in only] == [jobs[0].overrides, jobs[2].overrides]
    changed = load_spec(spec, tmp_path, SpecChanges(sets={"duration_s": 1}, only=pick))[1]
    assert [j.overrides["initial.heading_deg"] for j in changed] == [j.overrides["initial.heading_deg"] for j in only]
    assert all(j.overrides["duration_s"] == 1 for j in changed)
    with pytest.raises(BatchSpecError, match=rf"--only 999: no run of spec.yaml flies that scenario seed \(its "
                                             rf"seeds: {seeds[0]}-{seeds[-1]}\)") as exc:
        load_spec(spec, tmp_path, SpecChanges(only=(999,)))
    assert "\n" not in str(exc.value)


@pytest.mark.parametrize("values, seeds", [(["30"], (30,)), (["s30,59"], (30, 59)), (["10-12", "11"], (10, 11, 12))])
def test_only_reads_seeds_lists_and_ranges(values, seeds):
    from fwsim.cli import _only_seeds
    assert _only_seeds(values) == seeds


@pytest.mark.parametrize("value", ["x", "12-10", "3-", "", "0-999999999"])
def test_only_bad_values_are_one_line_errors(value):
    from fwsim.cli import _only_seeds
    with pytest.raises(ScenarioError, match="--only .*(expected scenario seeds|a range of at most)") as exc:
        _only_seeds([value])
    assert "\n" not in str(exc.value)
