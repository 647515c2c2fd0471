"""The Python API (fwsim.fly, fwsim.batch, Flight) and the guide's page, whose code blocks are run here."""
from __future__ import annotations

import gc
import re
import subprocess
import sys

import pytest

import fwsim
from fwsim import PROJECT_ROOT, SCENARIO_DIR
from fwsim.scenario.model import ScenarioError, load_scenario

CHECKOUT = SCENARIO_DIR / "autopilot_checkout.yaml"


def test_import_fwsim_is_light():
    """``import fwsim`` loads neither JSBSim, CasADi, numpy nor the flight software."""
    code = ("import sys, fwsim; heavy = [m for m in sys.modules if m.split('.')[0] in "
            "('jsbsim', 'casadi', 'numpy', 'pydantic', 'controllers')]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=PROJECT_ROOT)
    assert out.stdout.strip() == "[]", out.stdout
    assert callable(fwsim.fly) and callable(fwsim.batch) and fwsim.PROJECT_ROOT == PROJECT_ROOT


def test_fly_a_path_with_overrides_and_a_temporary_log_it_owns(monkeypatch):
    monkeypatch.chdir(PROJECT_ROOT)
    f = fwsim.fly("scenarios/autopilot_checkout.yaml", duration_s=3, seed=5, **{"initial.airspeed_m_s": 23})
    assert f.status == "completed" and f.reason == "duration reached"
    assert f.scenario.seed == 5 and f.scenario.initial.airspeed_m_s == 23
    assert abs(f.metrics["flight_time_s"] - 3.0) < 0.05
    with pytest.raises(TypeError):
        f.metrics["x"] = 1  # a read-only mapping
    path = f.log_path
    assert path.is_file() and f.log.status == "completed"
    f.close()
    assert not path.exists() and not path.parent.exists()
    assert f.metrics["flight_time_s"] > 0  # read before: kept
    g = fwsim.fly("scenarios/autopilot_checkout.yaml", duration_s=1)
    gone = g.log_path
    del g
    gc.collect()
    assert not gone.exists()  # garbage-collected: removed too


def test_fly_a_dict_or_a_scenario_and_keep_the_log(tmp_path):
    scenario, _ = load_scenario(CHECKOUT, {"duration_s": 2})
    kept = tmp_path / "kept.mcap"
    with fwsim.fly(scenario, log=kept, seed=9) as f:
        assert f.scenario.seed == 9 and "seed: 9" in f.log.effective_scenario_text
    assert kept.is_file()  # a log given to fly is the caller's
    data = scenario.model_dump(mode="json")
    a = fwsim.fly(data)
    assert a.scenario == scenario and a.status == "completed"


def test_bad_input_raises_a_one_line_scenario_error():
    with pytest.raises(ScenarioError, match=r"initial.airspeed_m_s: Input should be greater than 0"):
        fwsim.fly(CHECKOUT, **{"initial.airspeed_m_s": -3})
    with pytest.raises(ScenarioError, match="expected a scenario file's path, a dict or a Scenario"):
        fwsim.fly(42)
    with pytest.raises(ScenarioError, match="workers: expected 1 or more"):
        fwsim.batch({"runs": []}, workers=0)


def test_batch_takes_a_dict_spec(tmp_path, monkeypatch):
    monkeypatch.chdir(PROJECT_ROOT)  # a dict's scenario paths are relative to the current folder
    rows = fwsim.batch({"runs": [{"scenario": "scenarios/autopilot_checkout.yaml", "seeds": [1, 2],
                                  "set": {"duration_s": 1}}]}, workers=1, out=tmp_path / "b")
    assert [r["seed"] for r in rows] == [1, 2] and all(r["status"] == "completed" for r in rows)
    assert (tmp_path / "b" / "summary.json").is_file()


def _python_blocks(page):
    return re.findall(r"```python\n(.*?)```", page.read_text(encoding="utf-8"), flags=re.S)


def test_the_api_page_runs(tmp_path, monkeypatch):
    """docs/guide/api.md's python blocks, in order, in one namespace, as a notebook runs them (from a folder
    where ``scenarios`` is the project's, so the batch's output lands in the test's folder)."""
    (tmp_path / "scenarios").symlink_to(SCENARIO_DIR)
    monkeypatch.chdir(tmp_path)
    blocks = _python_blocks(PROJECT_ROOT / "docs" / "guide" / "api.md")
    assert len(blocks) >= 5
    namespace: dict = {}
    for i, code in enumerate(blocks):
        exec(compile(code, f"docs/guide/api.md (python block {i + 1})", "exec"), namespace)  # noqa: S102
    assert namespace["flight"].status == "completed"
    assert len(namespace["rows"]) == 2 and (tmp_path / "runs" / "api_demo" / "summary.csv").is_file()


def test_the_issue_one_liner_works():
    code = ("import fwsim; f = fwsim.fly('scenarios/autopilot_checkout.yaml', duration_s=10); "
            "print(f.metrics['flight_time_s'], f.log_path)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=PROJECT_ROOT,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    t, path = out.stdout.split()
    assert abs(float(t) - 10.0) < 0.05 and path.endswith(".mcap")
