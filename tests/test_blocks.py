"""Swappable blocks (controllers.blocks): a user's class chosen in the scenario flies, a bad one is a one-line
scenario error before anything flies."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from pydantic import BaseModel, ConfigDict, Field

from controllers.blocks import BlockContext, TargetEstimator
from controllers.estimation.ukf import UkfTargetEstimator
from controllers.messages import Guidance
from fwsim import SCENARIO_DIR
from fwsim.cli import main
from fwsim.sim.loop import run
from fwsim.interface.messages import AccelCommand, GimbalCommand
from fwsim.analysis.metrics import compute_metrics
from fwsim.scenario.model import ScenarioError, load_scenario, parse_scenario

CALLS: dict[str, int] = {}  # what the last CountingUkf was asked to do, by method


class CountingUkf:
    """A user's estimator: the built-in UKF, wrapped, counting its calls (the docs' example)."""

    class Config(BaseModel):
        model_config = ConfigDict(extra="forbid")
        label: str = Field("counting UKF", description="its name in the events")

    def __init__(self, options: Config, context: BlockContext):
        self.inner = UkfTargetEstimator(context.camera, context.config.ukf)
        self.label = options.label
        CALLS.clear()

    def _count(self, name: str) -> None:
        CALLS[name] = CALLS.get(name, 0) + 1

    @property
    def initialised(self) -> bool:
        return self.inner.initialised

    @property
    def tracked_height_m(self) -> float:
        return self.inner.tracked_height_m

    def initialise(self, fix, camera) -> None:
        self._count("initialise")
        self.inner.initialise(fix, camera)

    def predict(self, t_s, camera) -> None:
        self._count("predict")
        self.inner.predict(t_s, camera)

    def update(self, fix, camera):
        self._count("update")
        return self.inner.update(fix, camera)

    def estimate(self):
        return self.inner.estimate()

    def status(self, t_s):
        return self.inner.status(t_s)


class StraightDive:
    """A user's terminal law: no guidance at all, wings level (for the plug-in check only)."""

    def __init__(self, options, context):
        self.airspeed = float(options.get("airspeed_m_s", 22.0))

    def step(self, nav, target):
        return Guidance(AccelCommand(nav.t_s, self.airspeed, np.zeros(3)), "terminal:straight")


class HoldGimbal:
    def __init__(self, options, context):
        pass

    def step(self, nav, camera, target):
        return GimbalCommand(nav.t_s, math.nan, math.nan)


class NoPredict:
    """Not an estimator: no predict."""

    def __init__(self, options, context):
        pass

    initialised = False
    tracked_height_m = 0.0

    def initialise(self, fix, camera): ...

    def update(self, fix, camera): ...

    def estimate(self): ...

    def status(self, t_s): ...


BASE = """
name: plug
duration_s: 20
initial: {pos_enu_m: [-1000, 0, 1000], airspeed_m_s: 22, heading_deg: 90}
"""


def test_a_user_estimator_from_the_scenario_flies_and_is_called(tmp_path):
    """The paper mission's first 25 s with the wrapped UKF from this module: it locks, the user's estimator
    is initialised once and then predicts every tick and fuses the detections, and the log says so."""
    scenario, text = load_scenario(SCENARIO_DIR / "paper_mission.yaml", {
        "duration_s": 25, "controllers.estimator": {"use": "test_blocks:CountingUkf",
                                                    "options": {"label": "my filter"}}})
    res = run(scenario, text, tmp_path / "plug.mcap")
    assert res.status == "completed"
    m = compute_metrics(res.log_path)
    assert CALLS["initialise"] == 1 and CALLS["predict"] > 300 and CALLS["update"] > 200, CALLS
    assert m["fusion_used"] == CALLS["update"] - m["fusion_innovation_gate"] - m["fusion_rejected"]
    from fwsim.log import read_log
    assert any("my filter initialised" in e[2] for e in read_log(res.log_path).events())
    assert isinstance(CountingUkf(CountingUkf.Config(), _ctx(scenario)), TargetEstimator)


def _ctx(scenario):
    from controllers.navigation.camera_model import PinholeCamera
    return BlockContext(scenario.controllers, PinholeCamera.from_config(scenario.camera), np.zeros(3), None)


def test_user_guidance_and_pointing_classes_are_accepted():
    s = parse_scenario(BASE + """controllers:
  terminal: {use: "test_blocks:StraightDive", options: {airspeed_m_s: 24}}
  pointing: test_blocks:HoldGimbal
""")
    assert s.controllers.terminal.use == "test_blocks:StraightDive"
    assert s.controllers.terminal.options == {"airspeed_m_s": 24}
    assert s.controllers.pointing.use == "test_blocks:HoldGimbal"


@pytest.mark.parametrize("value, message", [
    ("no_such_module_xyz:Thing", "controllers.estimator: cannot import 'no_such_module_xyz'"),
    ("test_blocks:Nothing", "controllers.estimator: 'test_blocks' has no 'Nothing'"),
    ("test_blocks:CALLS", "controllers.estimator: 'test_blocks:CALLS' is not a class"),
    ("test_blocks:NoPredict", "controllers.estimator: test_blocks:NoPredict does not implement TargetEstimator: "
                              "no predict"),
    ("ukff", "controllers.estimator: expected a built-in name (ukf, ct_ukf, imm) or an import path"),
    ({"use": "ukf", "options": {"a": 1}}, "controllers.estimator: options are for a user's class"),
    ({"use": "test_blocks:CountingUkf", "options": {"nope": 1}},
     "controllers.estimator: options.nope: Extra inputs are not permitted"),
])
def test_a_bad_block_is_a_one_line_scenario_error(value, message):
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(BASE, "x.yaml", {"controllers.estimator": value})
    text = str(exc.value)
    assert "\n" not in text and text.startswith("x.yaml: " + message), text
    assert text.count("got ") <= 1, text  # the value given said once (a validator's message may say it itself)


def test_a_bad_block_stops_fwsim_run_before_it_flies(tmp_path, capsys):
    """Exit code 2, one line, and no log written."""
    log = tmp_path / "x.mcap"
    rc = main(["run", str(SCENARIO_DIR / "paper_mission.yaml"), "--set", "controllers.terminal=nope.mod:Law",
               "--log", str(log), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "controllers.terminal: cannot import 'nope.mod'" in err[0], err
    assert not log.exists()


def test_the_built_in_names_need_no_import_and_read_back_from_a_log():
    s = parse_scenario(BASE + "controllers: {estimator: ukf, after_lock: nmpc, terminal: bpng, pointing: ibvs}")
    dumped = s.model_dump(mode="json")["controllers"]
    assert dumped["after_lock"] == {"use": "nmpc", "options": {}}
    # (written back as JSON, as a log holds it: JSON is YAML, and a None is null there)
    again = parse_scenario(BASE.replace("name: plug", "name: plug2") + "controllers: " + json.dumps(dumped))
    assert again.controllers.after_lock == s.controllers.after_lock
    # a log's scenario whose plug-in module is missing here still reads (for scoring)
    lost = parse_scenario(BASE, overrides={"controllers.estimator": "gone_module:Filter"}, check_plugins=False)
    assert lost.controllers.estimator.use == "gone_module:Filter"
