"""Bad input of every kind ends in one short line and exit code 2, never a traceback (scenario files, --set,
log files)."""
from __future__ import annotations

import subprocess
import sys

import pytest

from fwsim import SCENARIO_DIR
from fwsim.cli import main
from fwsim.scenario.model import ScenarioError, load_scenario, parse_scenario, parse_sets
from fwsim.scenario.yamlfile import MAX_VALUES, load_yaml_text

PAPER = SCENARIO_DIR / "paper_mission.yaml"
PAPER_TEXT = PAPER.read_text()


def _bomb(levels: int = 9) -> str:
    text = "a: &a [" + ", ".join(['"lol"'] * 9) + "]\n"
    prev = "a"
    for name in "bcdefghijk"[:levels]:
        text += f"{name}: &{name} [" + ", ".join([f"*{prev}"] * 9) + "]\n"
        prev = name
    return text


BAD_YAML = {
    "deep nesting": ("a: " + "[" * 3000 + "]" * 3000, "nested too deeply"),
    "huge integer": ("seed: " + "9" * 5000, "bad value"),
    "bad !!float": ("seed: !!float abc", "bad value"),
    "bad !!bool": ("seed: !!bool 3", "bad value"),
    "python tag": ("name: !!python/object/apply:os.system [ls]", "YAML error"),
    "duplicate key": ("name: a\nname: b", "appears twice"),
    "alias bomb": (_bomb(), "too large"),
    "syntax": ("seed: [1", "YAML syntax error"),
}


@pytest.mark.parametrize("name", list(BAD_YAML))
def test_bad_yaml_is_one_short_line(name):
    text, words = BAD_YAML[name]
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(text, "x.yaml")
    msg = str(exc.value)
    assert words in msg and "\n" not in msg and len(msg) < 300 and msg.startswith("x.yaml")


def test_a_date_is_text_and_merge_keys_still_work():
    assert load_yaml_text("name: 2024-02-30", "x", ScenarioError) == {"name": "2024-02-30"}
    data = load_yaml_text("base: &b {x: 1, y: 2}\nother:\n  <<: *b\n  y: 3\n", "x", ScenarioError)
    assert data["other"] == {"x": 1, "y": 3}


def test_aliases_below_the_limit_load():
    data = load_yaml_text(_bomb(levels=3), "x", ScenarioError)  # 9**4 values: well under the limit
    assert len(data["d"]) == 9 and 9 ** 5 < MAX_VALUES


def test_a_huge_file_is_refused_before_it_is_read(tmp_path):
    from fwsim.scenario.yamlfile import MAX_FILE_BYTES
    p = tmp_path / "huge.yaml"
    p.write_bytes(b"# " + b"x" * MAX_FILE_BYTES + b"\nname: a\n")
    with pytest.raises(ScenarioError, match="too large for a scenario file"):
        load_scenario(p)


def test_non_utf8_file(tmp_path):
    p = tmp_path / "latin.yaml"
    p.write_bytes(b"name: caf\xe9\n")
    with pytest.raises(ScenarioError, match="not UTF-8"):
        load_scenario(p)


@pytest.mark.parametrize("override, words", [
    ({"world.wind_enu_m_s": [float("nan"), 0, 0]}, "world.wind_enu_m_s.0: Input should be a finite number"),
    ({"camera.detector.latency_s": float("inf")}, "finite number"),
    ({"initial.airspeed_m_s": True}, "airspeed_m_s: a number is expected here, not true/false"),
    ({"seed": False}, "seed: a number is expected"),
    ({"initial.pos_enu_m": [0, True, 100]}, "not true/false"),
])
def test_non_finite_numbers_and_booleans_are_rejected(override, words):
    with pytest.raises(ScenarioError, match=words.replace(".", r"\.")):
        load_scenario(PAPER, override)


@pytest.mark.parametrize("override, words", [
    ({"controllers.nmpc.airspeed_min_m_s": 30, "controllers.nmpc.airspeed_max_m_s": 20}, "must be below"),
    ({"controllers.nmpc.airspeed_ref_m_s": 40}, "must lie within"),
    ({"aircraft.name": "nope"}, "no aircraft 'nope'"),
    ({"aircraft.autopilot_gains": {"nope": 1}}, "unknown autopilot gain 'nope'"),
    ({"aircraft.autopilot_gains": {"airspeed_kp": 1e9}}, "outside its range"),
    ({"initial.pos_enu_m": [900_000, 0, 1000]}, "900 km from the world origin"),
])
def test_settings_that_cannot_fly_fail_validation(override, words):
    with pytest.raises(ScenarioError, match=words):
        load_scenario(PAPER, override)


def test_booleans_still_go_where_booleans_belong():
    s, _ = load_scenario(PAPER, {"controllers.switch.enabled": False})
    assert s.controllers.switch.enabled is False


def test_long_inputs_are_not_echoed():
    text = PAPER_TEXT.replace("name: paper_mission", "name: paper_mission\nseed: '" + "y" * 100_000 + "'", 1)
    text = text.replace("seed: 7\n", "", 1)
    with pytest.raises(ScenarioError) as exc:
        parse_scenario(text, "x.yaml")
    assert len(str(exc.value)) < 400


@pytest.mark.parametrize("item, words", [
    ("seed=[1", "YAML syntax error"),
    ("initial.pos_enu_m.7=1", "is a list of 3"),
    ("name.x=1", "has no fields"),
    ("=3", "dotted PATH"),
    ("a..b=1", "dotted PATH"),
    ("seed", "expected PATH=VALUE"),
])
def test_bad_set_items(item, words):
    with pytest.raises(ScenarioError, match=words):
        load_scenario(PAPER, parse_sets([item]))


def test_cli_bad_inputs_exit_2_without_a_traceback(tmp_path, capsys):
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 4)  # the magic, then noise
    text = tmp_path / "text.mcap"
    text.write_text("hello\n")
    cases = [["run", str(PAPER), "--set", "name.x=1"], ["metrics", str(junk)], ["metrics", str(text)],
             ["plot", str(junk)], ["replay", str(junk)], ["compare", str(junk), str(text)]]
    for argv in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.startswith("error") and "Traceback" not in err and len(err.splitlines()) == 1, (argv, err)


def test_version():
    proc = subprocess.run([sys.executable, "-m", "fwsim.cli", "--version"], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0 and proc.stdout.startswith("fwsim ")


def test_lz4_chunks_without_lz4_say_what_is_missing(tmp_path, monkeypatch):
    """fwsim writes zstd; a log from elsewhere with lz4 chunks needs the lz4 package: one line saying so, not
    'corrupted'."""
    pytest.importorskip("lz4")  # to write one
    from mcap.writer import CompressionType, Writer

    from fwsim.log.reader import LogError, read_log
    path = tmp_path / "lz4.mcap"
    with open(path, "wb") as f:
        w = Writer(f, compression=CompressionType.LZ4)
        w.start()
        channel = w.register_channel("/uav/state", "json", w.register_schema("x", "jsonschema", b"{}"))
        w.add_message(channel, 1, b"{}", 1)
        w.finish()
    monkeypatch.setitem(sys.modules, "lz4", None)
    monkeypatch.setitem(sys.modules, "lz4.frame", None)
    with pytest.raises(LogError, match="lz4-compressed, which needs the lz4 package"):
        read_log(path)
    assert main(["metrics", str(path)]) == 2


def _output_cases(tmp_path):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    a_folder = tmp_path / "a_folder"
    a_folder.mkdir()
    batch = tmp_path / "b.yaml"
    batch.write_text(f"runs:\n  - scenario: {PAPER}\n    set: {{duration_s: 1}}\n")
    return {
        "run --log into a file": (["run", str(PAPER), "--log", str(a_file / "x.mcap")], "is a file, not a folder"),
        "run --log a folder": (["run", str(PAPER), "--log", str(a_folder)], "is a folder"),
        "run --out a file": (["run", str(PAPER), "--out", str(a_file)], "is a file, expected a folder"),
        "batch --out a file": (["batch", str(batch), "--out", str(a_file)], "cannot write the batch's output"),
    }


@pytest.mark.parametrize("case", ["run --log into a file", "run --log a folder", "run --out a file",
                                  "batch --out a file"])
def test_output_that_cannot_be_written_is_refused_before_anything_flies(tmp_path, capsys, case):
    argv, words = _output_cases(tmp_path)[case]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and err.count("\n") == 0 and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a_file", "a_folder", "b.yaml"]  # nothing written
    assert not any((tmp_path / "a_folder").iterdir())



@pytest.mark.parametrize("value", ["-1", "0", "nan", "inf", "abc"])
def test_replay_marker_scale_must_be_a_number_above_zero(value, tmp_path, capsys):
    with pytest.raises(SystemExit) as exc:
        main(["replay", str(tmp_path / "x.mcap"), f"--marker-scale={value}"])
    assert exc.value.code == 2
    assert f"--marker-scale: expected a number above zero (got '{value}')" in capsys.readouterr().err


def test_compare_names_a_folder_given_for_a_file(tmp_path, capsys):
    assert main(["compare", str(tmp_path), str(tmp_path / "x.mcap")]) == 2
    assert capsys.readouterr().err.strip() == (f"error: {tmp_path}: is a folder, expected a .mcap log or a "
                                               ".json / .yaml metrics file")


def test_a_folder_given_for_a_scenario_or_a_log_is_named_as_one(tmp_path, capsys):
    with pytest.raises(ScenarioError, match="is a folder, expected a scenario file"):
        load_scenario(tmp_path)
    assert main(["run", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip() == f"error: {tmp_path}: is a folder, expected a scenario file (YAML)"
    assert main(["metrics", str(tmp_path)]) == 2
    out = capsys.readouterr()
    assert "is a folder, expected an MCAP log" in out.out + out.err


def test_a_batch_entry_naming_a_folder_for_its_scenario_says_so(tmp_path, capsys):
    (tmp_path / "d").mkdir()
    spec = tmp_path / "b.yaml"
    spec.write_text("runs:\n  - scenario: d\n")
    assert main(["batch", str(spec), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("error: ") and "is a folder, expected a scenario file" in err and "runs.0" in err


@pytest.mark.parametrize("text", ["runs: [1, 2\n", "- a\n- b\n", "runs: []\n"])
def test_a_batch_spec_refused_before_any_run_gives_one_line_and_nothing_else(tmp_path, capsys, text):
    spec = tmp_path / "b.yaml"
    spec.write_text(text)
    assert main(["batch", str(spec), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1, repr(err)  # no empty line ahead of it
