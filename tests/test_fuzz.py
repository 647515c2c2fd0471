"""Fuzzing: mutated scenario files, --set items and damaged logs never end in anything but acceptance or the
short error (exit code 2 at the command line).

The number of examples scales with the environment variable FWSIM_FUZZ (default 1: 2,000 scenario files,
600 --set items, 150 damaged logs for metrics and compare, 15 for plot and replay). A long local run:

    FWSIM_FUZZ=5 pytest tests/test_fuzz.py        # 10,000 scenario files, 750 damaged logs
"""
from __future__ import annotations

import contextlib
import copy
import io
import os
import tempfile
from pathlib import Path

import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fwsim import SCENARIO_DIR
from fwsim.cli import main
from fwsim.scenario.model import MAX_PROBLEMS, ScenarioError, load_scenario, parse_scenario, parse_sets

SCALE = float(os.environ.get("FWSIM_FUZZ", "1"))
PAPER = SCENARIO_DIR / "paper_mission.yaml"
SOURCES = sorted(p for p in SCENARIO_DIR.rglob("*.yaml") if "batches" not in p.parts)
DATA = {p.relative_to(SCENARIO_DIR).as_posix(): yaml.safe_load(p.read_text()) for p in SOURCES}


def _settings(n: int) -> settings:
    return settings(max_examples=max(1, int(n * SCALE)), deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.filter_too_much])


def _paths(node, prefix=()):
    """Every path into a YAML tree (keys and list indices), the root included."""
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, prefix + (i,))


def _parent(data, path):
    node = data
    for p in path[:-1]:
        node = node[p]
    return node


ODD_TEXT = ["", "nan", ".nan", ".inf", "-.inf", "1e400", "2024-02-30", "true", "~", "0x1F", "1_000", "[1, 2",
            "module:Class", "paper_ukf", "os:system", "\x00", "é" * 3, "9" * 5000]
VALUES = st.one_of(
    st.none(), st.booleans(), st.integers(-10**6, 10**6), st.integers(min_value=10**20, max_value=10**4000),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=20), st.sampled_from(ODD_TEXT),
    st.lists(st.floats(allow_nan=True), max_size=6), st.lists(st.integers(-5, 5), max_size=4),
    st.dictionaries(st.text(max_size=6), st.integers(), max_size=3), st.just([[[[[]]]]]),
)
YAML_JUNK = st.text(alphabet=list(":-[]{}&*!|>'\"#%@`,? \n\t0123456789aez."), max_size=12)


@st.composite
def mutated_scenarios(draw) -> str:
    """A project scenario with one to four tree edits (replace, delete, add a key, duplicate a list item) and
    sometimes a text edit (junk inserted, a slice deleted, cut short, a line repeated, a tag put in)."""
    data = copy.deepcopy(DATA[draw(st.sampled_from(sorted(DATA)))])
    for _ in range(draw(st.integers(1, 4))):
        paths = [p for p in _paths(data) if p]
        if not paths:
            break
        path = draw(st.sampled_from(paths))
        parent, key = _parent(data, path), path[-1]
        op = draw(st.sampled_from(["replace", "replace", "delete", "add", "dup"]))
        if op == "replace":
            parent[key] = copy.deepcopy(draw(VALUES))
        elif op == "delete":
            del parent[key]
        elif op == "add" and isinstance(parent, dict):
            parent[draw(st.text(min_size=1, max_size=12))] = copy.deepcopy(draw(VALUES))
        elif op == "dup" and isinstance(parent, list):
            parent.insert(key, copy.deepcopy(parent[key]))
    text = yaml.safe_dump(data, sort_keys=False, allow_unicode=True)
    edit = draw(st.sampled_from(["none", "none", "insert", "delete", "cut", "repeat", "tag"]))
    pos = draw(st.integers(0, len(text)))
    if edit == "insert":
        text = text[:pos] + draw(YAML_JUNK) + text[pos:]
    elif edit == "delete":
        text = text[:pos] + text[pos + draw(st.integers(1, 40)):]
    elif edit == "cut":
        text = text[:pos]
    elif edit == "repeat":
        lines = text.splitlines(keepends=True)
        i = draw(st.integers(0, max(len(lines) - 1, 0)))
        text = "".join(lines[: i + 1] + lines[i:])
    elif edit == "tag":
        tag = draw(st.sampled_from(["!!float ", "!!int ", "!!bool ", "!!str ", "!!binary ", "!!python/none ",
                                    "!!set ", "!!omap ", "&a ", "*a "]))
        text = text[:pos] + tag + text[pos:]
    return text


def assert_short_error(exc: ScenarioError, source: str) -> None:
    lines = str(exc).splitlines()
    assert 1 <= len(lines) <= MAX_PROBLEMS + 1, str(exc)[:2000]
    for line in lines:
        assert len(line) < 400 and line.startswith(source) and "Traceback" not in line, line[:500]


@_settings(2000)
@given(mutated_scenarios())
def test_mutated_scenarios_are_accepted_or_a_short_error(text):
    try:
        parse_scenario(text, "fuzz.yaml")
    except ScenarioError as exc:
        assert_short_error(exc, "fuzz.yaml")


PAPER_PATHS = [".".join(str(p) for p in path) for path in _paths(DATA["paper_mission.yaml"]) if path]


@_settings(600)
@given(st.one_of(st.sampled_from(PAPER_PATHS), st.text(max_size=20),
                 st.sampled_from(PAPER_PATHS).map(lambda p: p + ".x"), st.sampled_from(PAPER_PATHS).map(
                     lambda p: p + ".7")),
       st.one_of(VALUES.map(lambda v: yaml.safe_dump(v, default_flow_style=True).strip()), YAML_JUNK),
       st.sampled_from(["=", "", "==", " = "]))
def test_set_items_are_accepted_or_a_short_error(path, value, sep):
    item = f"{path}{sep}{value}"
    try:
        load_scenario(PAPER, parse_sets([item]))
    except ScenarioError as exc:
        lines = str(exc).splitlines()
        assert 1 <= len(lines) <= MAX_PROBLEMS + 1 and all(len(line) < 400 for line in lines), str(exc)[:2000]


# -- damaged logs --------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def good_log_bytes(tmp_path_factory) -> bytes:
    from fwsim.sim.loop import run
    scenario, text = load_scenario(SCENARIO_DIR / "paper_mission.yaml", {"duration_s": 3, "camera.render.rate_hz": 2,
                                                                         "start_time": "2026-01-01T00:00:00Z"})
    return run(scenario, text, tmp_path_factory.mktemp("fuzzlog") / "good.mcap").log_path.read_bytes()


@st.composite
def damages(draw):
    """(kind, position fraction, bytes): flipped bytes, a cut, junk inserted, a zeroed range, a swapped slice."""
    return (draw(st.sampled_from(["flip", "flip", "cut", "insert", "zero", "swap"])), draw(st.floats(0, 1)),
            draw(st.binary(min_size=1, max_size=64)), draw(st.integers(1, 4096)))


def damage(data: bytes, how) -> bytes:
    kind, frac, junk, n = how
    pos = int(frac * (len(data) - 1))
    b = bytearray(data)
    if kind == "flip":
        for i, x in enumerate(junk):
            j = (pos + i * 997) % len(b)
            b[j] ^= x or 0xFF
    elif kind == "cut":
        del b[pos:]
    elif kind == "insert":
        b[pos:pos] = junk
    elif kind == "zero":
        b[pos:pos + n] = bytes(len(b[pos:pos + n]))
    elif kind == "swap":
        b[pos:pos + len(junk)] = junk
    return bytes(b)


def _cli(argv) -> tuple[int, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(argv)
    return code, err.getvalue()


def _check_tool(argv, tmp: Path) -> None:
    code, err = _cli(argv)
    assert code in (0, 1, 2), (argv, code, err[:500])
    assert "Traceback" not in err
    if code == 2:
        assert len(err.strip().splitlines()) == 1 and len(err) < 600, err[:1000]


def _with_damaged(good: bytes, how, fn) -> None:
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "damaged.mcap"
        path.write_bytes(damage(good, how))
        fn(path, Path(d))


@_settings(150)
@given(damages())
def test_metrics_and_compare_on_damaged_logs(good_log_bytes, how):
    def check(path, tmp):
        _check_tool(["metrics", str(path)], tmp)
        _check_tool(["compare", str(path), str(path)], tmp)
    _with_damaged(good_log_bytes, how, check)


@_settings(15)
@given(damages())
def test_plot_and_replay_on_damaged_logs(good_log_bytes, how):
    def check(path, tmp):
        _check_tool(["plot", str(path), "--out", str(tmp / "plots"), "--only", "trajectory_xy,target_estimate"], tmp)
        _check_tool(["replay", str(path), "--rrd", str(tmp / "r.rrd")], tmp)
    _with_damaged(good_log_bytes, how, check)
