"""Scenario validation: one-line errors that name the field; shipped scenarios load."""
import subprocess
import sys

import pytest
import yaml

from fwsim import SCENARIO_DIR
from fwsim.scenario.model import ScenarioError, load_scenario, parse_scenario

GOOD = """
name: t
duration_s: 10
initial: {pos_enu_m: [0, 0, 500], airspeed_m_s: 22, heading_deg: 90}
"""


def error_of(text: str) -> str:
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(text, "s.yaml")
    return str(exc.value)


def test_good_scenario_has_defaults():
    s = parse_scenario(GOOD)
    assert s.rates.sim_hz == 120 and s.aircraft.name == "fwuav" and s.seed == 0
    assert s.controllers.kind == "mission"


@pytest.mark.parametrize("text, field, words", [
    (GOOD.replace("airspeed_m_s: 22", "airspeed_m_s: -5"), "initial.airspeed_m_s", "greater than 0"),
    (GOOD + "colour: blue\n", "colour", "unknown key"),
    (GOOD.replace("heading_deg: 90", "heading_deg: 90, extra: 1"), "initial.extra", "unknown key"),
    (GOOD.replace("[0, 0, 500]", "[0, 500]"), "initial.pos_enu_m", "at least 3"),
    (GOOD.replace("duration_s: 10", "duration_s: ten"), "duration_s", "valid number"),
    (GOOD + "rates: {log_hz: 7}\n", "rates", "divide sim_hz"),
    (GOOD + "controllers: {kind: script}\n", "controllers", "non-empty 'script'"),
    (GOOD.replace("[0, 0, 500]", "[0, 0, -1]"), "initial", "above the sea"),
])
def test_errors_are_one_line_naming_the_field(text, field, words):
    msg = error_of(text)
    assert "\n" not in msg
    assert msg.startswith(f"s.yaml: {field}: ")
    assert words in msg


def test_yaml_syntax_error_names_line():
    msg = error_of("name: x\nduration_s: [1\n")
    assert msg.startswith("s.yaml:3:") and "YAML syntax error" in msg


def test_missing_fields_each_get_a_line():
    msg = error_of("name: x\n")
    lines = msg.splitlines()
    assert {ln.split(": ")[1] for ln in lines} == {"duration_s", "initial"}


def test_overrides_by_path():
    s = parse_scenario(GOOD, overrides={"initial.airspeed_m_s": 25, "seed": 4})
    assert s.initial.airspeed_m_s == 25 and s.seed == 4


BATCH_DIR = SCENARIO_DIR / "batches"


@pytest.mark.parametrize("path", sorted(p for p in SCENARIO_DIR.rglob("*.yaml") if BATCH_DIR not in p.parents),
                         ids=lambda p: p.name)
def test_shipped_scenarios_validate(path):
    scenario, text = load_scenario(path)
    assert scenario.name == path.stem and text


@pytest.mark.parametrize("path", sorted(BATCH_DIR.glob("*.yaml")), ids=lambda p: p.name)
def test_shipped_batch_specs_validate(path, tmp_path):
    from fwsim.batch.runner import load_spec
    name, jobs = load_spec(path, tmp_path)
    assert name and jobs


def test_cli_reports_bad_scenario_in_one_line(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(GOOD.replace("airspeed_m_s: 22", "airspeed_m_s: 0"))
    proc = subprocess.run([sys.executable, "-m", "fwsim.cli", "run", str(bad), "--out", str(tmp_path)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    err = proc.stderr.strip()
    assert err == f"error: {bad}: initial.airspeed_m_s: Input should be greater than 0 (got 0)"
    assert "Traceback" not in proc.stderr


def test_parse_sets_reads_yaml_values_and_names_a_bad_item():
    from fwsim.scenario.model import ScenarioError, parse_sets
    assert parse_sets(["seed=3", "world.wind_enu_m_s=[5, -4, 0]", " a.b = x "]) == \
        {"seed": 3, "world.wind_enu_m_s": [5, -4, 0], "a.b": "x"}
    with pytest.raises(ScenarioError, match="--set seed3: expected PATH=VALUE"):
        parse_sets(["seed3"])


def test_a_terminal_case_in_wind_starts_on_the_steady_orbit():
    """fwsim.batch.cases.terminal_case with a wind: the start heading is the air heading whose ground motion,
    relative to the ship, runs along the loiter circle (no radial part), and the wind is the world's."""
    import math

    import numpy as np
    import yaml

    from fwsim.batch.cases import terminal_case
    from fwsim.scenario.model import parse_scenario
    wind = [5.0, -4.0, 0.0]
    for still_air in (True, False):
        d = terminal_case(-30.0, 30.0, 75.0, 10.0, wind_enu_m_s=None if still_air else wind)
        sc = parse_scenario(yaml.safe_dump(d))
        w = np.zeros(2) if still_air else np.array(wind[:2])
        assert np.allclose(sc.world.wind_enu_m_s[:2], w)
        h = math.radians(d["initial"]["heading_deg"])
        v_air = d["initial"]["airspeed_m_s"] * np.array([math.sin(h), math.cos(h)])
        v_ship = 10.0 * np.array([math.sin(math.radians(75.0)), math.cos(math.radians(75.0))])
        rel = v_air + w - v_ship
        radial = -np.array(d["initial"]["pos_enu_m"][:2]) / np.linalg.norm(d["initial"]["pos_enu_m"][:2])
        assert abs(rel @ radial) < 1e-6 * np.linalg.norm(rel)
        assert rel[0] * radial[1] - rel[1] * radial[0] < 0  # the ship on the right: clockwise round it


@pytest.mark.parametrize("overrides, message", [
    ({"controllers.ibvs.pan_limits_rad": [-4.0, 3.0]},
     "controllers.ibvs.pan_limits_rad: [-4, 3] reaches beyond the gimbal's camera.gimbal.pan_limits_rad"),
    ({"camera.gimbal.tilt_limits_rad": [-1.0, 1.0]},
     "controllers.ibvs.tilt_limits_rad: [-1.571, 1.571] reaches beyond the gimbal's camera.gimbal.tilt_limits_rad"),
    ({"camera.gimbal.max_pan_rate_rad_s": 1.0},
     "controllers.ibvs.max_pan_rate_rad_s: 2.0944 is faster than the gimbal's camera.gimbal.max_pan_rate_rad_s 1"),
])
def test_the_flight_softwares_gimbal_limits_must_lie_within_the_gimbals(overrides, message):
    """The IBVS law's joint and rate limits (the flight software's idea of the gimbal) against the gimbal's own:
    wider or faster is a one-line error; tighter (soft stops) is allowed."""
    text = "name: g\nduration_s: 5\ninitial: {pos_enu_m: [0, 0, 500], airspeed_m_s: 22, heading_deg: 0}\n"
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(text, "g.yaml", overrides)
    assert str(exc.value).startswith("g.yaml: " + message) and "\n" not in str(exc.value), str(exc.value)
    s = parse_scenario(text, "g.yaml", {"controllers.ibvs.tilt_limits_rad": [-1.2, 0.5],
                                        "controllers.ibvs.max_pan_rate_rad_s": 1.0})
    assert s.controllers.ibvs.tilt_limits_rad == [-1.2, 0.5]


def test_the_readmes_scenario_example_is_a_valid_scenario():
    from fwsim import PROJECT_ROOT
    text = (PROJECT_ROOT / "README.md").read_text()
    example = text.split("### Scenario files", 1)[1].split("```yaml", 1)[1].split("```", 1)[0]
    s = parse_scenario(example, "README.md")
    assert s.name == "my_case" and s.controllers.after_lock.use == "nmpc" and s.controllers.estimator.use == "ukf"


@pytest.mark.parametrize("name", ["paper_mission", "autopilot_checkout", "camera_demo", "paper_as_printed"])
def test_fast_yaml_loader_and_dumper_give_pyyamls_values_and_text(name):
    """The per-run YAML goes through libyaml where PyYAML has it (fwsim.scenario.yamlfile.FAST_SAFE_LOADER / DUMPER):
    the effective scenario it writes into every log is yaml.safe_dump's text, and the autopilot gains it reads
    are yaml.safe_load's values."""
    from fwsim import AIRCRAFT_DIR
    from fwsim.scenario.yamlfile import FAST_SAFE_DUMPER, FAST_SAFE_LOADER
    scenario, _ = load_scenario(SCENARIO_DIR / f"{name}.yaml")
    data = scenario.model_dump(mode="json")
    assert yaml.dump(data, Dumper=FAST_SAFE_DUMPER, sort_keys=False) == yaml.safe_dump(data, sort_keys=False)
    text = (AIRCRAFT_DIR / scenario.aircraft.name / "autopilot.yaml").read_text()
    assert yaml.load(text, Loader=FAST_SAFE_LOADER) == yaml.safe_load(text)  # noqa: S506 - a safe loader
