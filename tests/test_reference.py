"""The field reference: fwsim scenario show / schema / reference, and the generated page kept up to date."""
from __future__ import annotations

import json

import jsonschema
import pytest
import yaml

from fwsim import PROJECT_ROOT, SCENARIO_DIR
from fwsim.cli import main
from fwsim.scenario.reference import REGENERATE, reference_markdown, scenario_schema, sections, unit_of
from fwsim.scenario.model import load_scenario, parse_scenario

SHIPPED = sorted(SCENARIO_DIR.glob("*.yaml")) + sorted((SCENARIO_DIR / "ablation").glob("*.yaml"))


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_show_loads_back_to_the_same_scenario(path, capsys):
    """Every default filled in, and the text reads back to the scenario it came from (with a --set too)."""
    assert main(["scenario", "show", str(path), "--set", "seed=11"]) == 0
    text = capsys.readouterr().out
    scenario, _ = load_scenario(path, {"seed": 11})
    assert parse_scenario(text, "shown") == scenario
    data = yaml.safe_load(text)
    assert data["seed"] == 11 and "rates" in data and "sim_hz" in data["rates"]  # defaults written out
    assert "pixel_noise_px" in data["controllers"]["ukf"]


@pytest.mark.parametrize("args, message", [
    (["scenario", "show", "no/such.yaml"], "no/such.yaml: no such scenario file"),
    (["scenario", "show", str(SCENARIO_DIR / "paper_mission.yaml"), "--set", "initial.airspeed_m_s=-3"],
     "initial.airspeed_m_s: Input should be greater than 0 (got -3)"),
    (["scenario", "show", str(SCENARIO_DIR / "paper_mission.yaml"), "--set", "nope"], "--set nope: expected"),
])
def test_show_on_bad_input_is_one_line_and_exit_code_2(args, message, capsys):
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_the_schema_validates_the_shipped_scenarios_and_catches_a_bad_one(capsys):
    assert main(["scenario", "schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    assert schema == json.loads(json.dumps(scenario_schema()))
    validator = jsonschema.Draft202012Validator(schema)
    for path in SHIPPED:  # (a block named by its short form, estimator: ukf, is valid too)
        assert not list(validator.iter_errors(yaml.safe_load(path.read_text()))), path
    bad = yaml.safe_load((SCENARIO_DIR / "paper_mission.yaml").read_text())
    bad["initial"]["airspeed_m_s"] = -3
    bad["rates"]["no_such_rate"] = 1
    found = {tuple(e.absolute_path) for e in validator.iter_errors(bad)}
    assert ("initial", "airspeed_m_s") in found and ("rates",) in found, found


def test_units_come_from_the_names():
    assert unit_of("airspeed_m_s") == "m/s" and unit_of("accel_m_s2") == "m/s²" and unit_of("hfov_deg") == "deg"
    assert unit_of("duration_s") == "s" and unit_of("sim_hz") == "Hz" and unit_of("box_px_std") == "px"
    assert unit_of("max_pan_rate_rad_s") == "rad/s" and unit_of("pos_enu_m") == "m" and unit_of("seed") == ""


def test_every_field_is_on_the_page_with_its_default_and_bounds():
    rows = {r.path: r for s in sections() for r in s.rows}
    scenario, _ = load_scenario(SCENARIO_DIR / "paper_mission.yaml")
    leaves = _leaf_paths(scenario.model_dump(mode="json"))
    missing = [p for p in leaves if p not in rows]
    assert not missing, missing[:10]
    r = rows["initial.airspeed_m_s"]
    assert (r.type, r.unit, r.default, r.bounds) == ("float", "m/s", "required", "> 0, ≤ 60")
    r = rows["rates.sim_hz"]
    assert (r.default, r.bounds, r.description) == ("120.0", "> 0, ≤ 2000", "JSBSim and autopilot rate")
    assert "events[].t_s" in rows and "target.motion.period_s" in rows


def _leaf_paths(data, prefix=""):
    """The dotted paths of a dumped scenario's values (a list's items as [], mappings of free keys skipped)."""
    out = []
    for k, v in data.items():
        p = f"{prefix}{k}"
        if isinstance(v, dict) and v and k not in ("options", "autopilot_gains"):
            out += _leaf_paths(v, p + ".")
        elif isinstance(v, list) and v and isinstance(v[0], dict):
            for item in v:
                out += _leaf_paths(item, p + "[].")
        else:
            out.append(p)
    return list(dict.fromkeys(out))


def test_the_reference_page_is_up_to_date():
    page = PROJECT_ROOT / "docs" / "guide" / "reference.md"
    assert page.is_file(), f"docs/guide/reference.md is missing; write it with: {REGENERATE}"
    assert page.read_text(encoding="utf-8") == reference_markdown(), (
        f"docs/guide/reference.md is stale (a field changed in the models); regenerate it with: {REGENERATE}")
    assert "# yaml-language-server: $schema=fwsim.schema.json" in page.read_text(encoding="utf-8")


def test_reference_writes_the_page(tmp_path, capsys):
    out = tmp_path / "ref.md"
    assert main(["scenario", "reference", "--out", str(out)]) == 0
    assert out.read_text(encoding="utf-8") == reference_markdown()
