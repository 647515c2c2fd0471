"""A user's blocks: the examples of docs/guide/plugins.md fly, and an error in a user's code says where it is
(the block, the method, the user's file:line), whatever kind of error it is."""
from __future__ import annotations

import math

import numpy as np
import pytest

import fwsim
from controllers.blocks import SLOTS, BlockContext, BlockError, PluginError, guarded, resolve_class
from controllers.messages import TargetState
from fwsim import PROJECT_ROOT, SCENARIO_DIR
from fwsim.batch.cases import terminal_case
from fwsim.cli import main
from fwsim.log import read_log
from fwsim.interface.messages import Measurements
from fwsim.scenario.model import ScenarioError, parse_scenario

EXAMPLES = PROJECT_ROOT / "docs" / "examples"
PAPER = str(SCENARIO_DIR / "paper_mission.yaml")


@pytest.fixture
def in_examples(monkeypatch):
    monkeypatch.chdir(EXAMPLES)  # as the guide runs them: from the folder that holds the modules


def test_the_alpha_beta_example_locks_and_tracks_the_paper_mission_ship(in_examples):
    """The estimator written from scratch (its data members set in __init__) flies the paper mission's first
    25 s: it starts at the lock, fuses the detections and its estimate is within metres of the ship."""
    with fwsim.fly(PAPER, duration_s=25, **{"controllers.estimator": "my_filters:AlphaBeta"}) as f:
        assert f.status == "completed", f.reason
        assert any("alpha-beta filter initialised" in e[2] for e in f.log.events())
        assert f.metrics["fusion_used"] > 200
        est, truth = f.log.table("/fsw/estimate"), f.log.table("/target/state")
        i = np.searchsorted(truth["t_s"], est["t_s"][-1])
        assert np.linalg.norm(est["pos_enu_m"][-1, :2] - truth["pos_enu_m"][i, :2]) < 15.0


def test_the_pure_pursuit_example_flies_the_dive_and_hits(in_examples):
    """The terminal law with no ``...`` left in it: from the loiter ring to the ship."""
    with fwsim.fly(terminal_case(-30, 30, 0, 5), **{"controllers.terminal": "my_guidance:PurePursuit"}) as f:
        assert f.reason.startswith("hit the ship"), f.reason
        names = {r["phase_name"] for r in f.log.rows("/fsw/status")}
        assert "terminal:pursuit" in names, names


BAD = '''
from controllers.estimation.ukf import UkfTargetEstimator


class Oops:
    def __init__(self, options, context):
        self.inner = UkfTargetEstimator(context.camera, context.config.ukf)
        self.initialised = False
        self.tracked_height_m = 0.0

    def initialise(self, fix, camera):
        self.inner.initialise(fix, camera)
        self.initialised = True

    def predict(self, t_s, camera):
        self.inner.predict(t_s, camera)

    def update(self, fix, camera):
        return self._look_up({})

    def _look_up(self, table):
        return table["oops in my filter"]

    def estimate(self):
        return self.inner.estimate()

    def status(self, t_s):
        return self.inner.status(t_s)


class ReturnsDict(Oops):
    def update(self, fix, camera):
        return {"used": True}


class NoHeight(Oops):
    def __init__(self, options, context):
        super().__init__(options, context)
        del self.tracked_height_m


class HeightMethod(Oops):
    def tracked_height_m(self):
        return 0.0
'''


@pytest.fixture
def user_module(tmp_path, monkeypatch, request):
    """A user's module in the current folder, under a name of its own for each test."""
    name = f"user_filters_{request.node.name.split('[')[0][-20:]}"
    (tmp_path / f"{name}.py").write_text(BAD)
    monkeypatch.chdir(tmp_path)
    return name, BAD.splitlines().index('        return table["oops in my filter"]') + 1


def _run(capsys, tmp_path, use, *extra):
    log = tmp_path / "run.mcap"
    rc = main(["run", PAPER, "--set", "duration_s=20", "--set", f"controllers.estimator={use}", "--log", str(log),
               "--quiet", *extra])
    return rc, capsys.readouterr().err, read_log(log)


def test_an_exception_in_a_plugin_names_the_block_the_method_and_the_users_line(user_module, tmp_path, capsys):
    name, line = user_module
    rc, err, log = _run(capsys, tmp_path, f"{name}:Oops")
    want = f"controllers.estimator: Oops.update failed at {name}.py:{line}: KeyError: 'oops in my filter'"
    assert rc == 1 and f"run failed: {want}" in err, err
    assert "Traceback" not in err and "--debug" in err
    assert log.status == "failed" and log.reason.startswith(want), log.reason


def test_debug_prints_the_whole_traceback(user_module, tmp_path, capsys):
    name, line = user_module
    rc, err, _ = _run(capsys, tmp_path, f"{name}:Oops", "--debug")
    assert rc == 1 and "Traceback (most recent call last)" in err and f"line {line}, in _look_up" in err, err
    assert "KeyError: 'oops in my filter'" in err and "run failed: controllers.estimator: Oops.update" in err


def test_a_wrong_return_type_is_caught_at_the_block_boundary(user_module, tmp_path, capsys):
    name, _ = user_module
    rc, err, log = _run(capsys, tmp_path, f"{name}:ReturnsDict")
    want = "controllers.estimator: ReturnsDict.update returned dict, expected FusionResult"
    assert rc == 1 and f"run failed: {want}" in err, err
    assert log.reason.startswith(want)


def test_data_members_may_be_set_in_init_and_are_checked_once_built(user_module, tmp_path, capsys):
    name, _ = user_module
    # accepted when the scenario is read: initialised and tracked_height_m exist only on an instance
    parse_scenario(open(PAPER).read(), PAPER, {"controllers.estimator": f"{name}:Oops"})
    rc, err, log = _run(capsys, tmp_path, f"{name}:NoHeight")
    assert rc == 1 and "controllers.estimator: NoHeight has no tracked_height_m once built" in err, err
    with pytest.raises(ScenarioError, match="tracked_height_m must be a property or an attribute, not a method"):
        parse_scenario(open(PAPER).read(), PAPER, {"controllers.estimator": f"{name}:HeightMethod"})


class _Law:
    def __init__(self, options, context):
        self.out = options["out"]

    def step(self, nav, target):
        if self.out == "raise":
            return math.sqrt(-1.0)  # ValueError: math domain error
        return self.out


class _Start:
    initialised, tracked_height_m = False, 0.0

    def __init__(self, options, context):
        pass

    def initialise(self, fix, camera):
        raise ValueError("the ray misses the sea")

    predict = update = estimate = status = initialise


def test_the_guard_checks_guidance_commands_and_lets_the_protocols_value_error_through():
    nav = Measurements(1.0, np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3), 22.0, 100.0)
    target = TargetState(1.0, "none", np.zeros(3), np.zeros(3), math.nan, 0.0)
    from controllers.messages import Guidance
    law = guarded("terminal", _Law)
    assert law.__name__ == "_Law" and issubclass(law, _Law)
    with pytest.raises(PluginError, match=r"^controllers.terminal: _Law.step returned a Guidance whose command is "
                                          r"dict, expected AccelCommand or RateCommand$"):
        law({"out": Guidance({"a": 1}, "x")}, None).step(nav, target)
    with pytest.raises(PluginError, match=r"^controllers.terminal: _Law.step returned NoneType, expected Guidance"):
        law({"out": None}, None).step(nav, target)
    with pytest.raises(PluginError, match=r"_Law.step failed at tests/test_plugins.py:\d+: ValueError: math domain"):
        law({"out": "raise"}, None).step(nav, target)
    with pytest.raises(PluginError, match=r"^controllers.terminal: _Law.__init__ failed at .*KeyError: 'out'"):
        law({}, None)
    with pytest.raises(ValueError, match="misses the sea") as exc:  # the estimation block catches this one
        guarded("estimator", _Start)({}, None).initialise(None, None)
    assert not isinstance(exc.value, PluginError)
    with pytest.raises(PluginError, match="_Start.predict failed"):
        guarded("estimator", _Start)({}, None).predict(0.0, None)


def test_resolve_class_still_returns_the_users_class_and_names_a_missing_method():
    assert resolve_class("my_guidance:PurePursuit", "terminal", [EXAMPLES]).__name__ == "PurePursuit"
    with pytest.raises(BlockError, match="no step"):
        resolve_class("test_plugins:_Start", "terminal")
    assert SLOTS["estimator"].data == ("initialised", "tracked_height_m")
    assert isinstance(BlockContext(None, None, np.zeros(3), None), BlockContext)
