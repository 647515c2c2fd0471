"""Logs that third-party readers take as they are: every JSON message valid against its own JSON Schema, log
times at a real date, Foxglove's own message types for the 3D panel, the map and the image boxes."""
import json

import numpy as np
import pytest
from jsonschema import Draft202012Validator
from mcap.reader import make_reader

from fwsim import SCENARIO_DIR
from fwsim.log import read_log
from fwsim.loop import run
from fwsim.scenario import ScenarioError, load_scenario

START = "2026-05-01T09:30:00Z"
START_NS = 1777627800 * 10**9


@pytest.fixture(scope="module")
def paper_log(tmp_path_factory):
    """14 s of the paper mission: NaN-holding messages (no lock yet, no detection), images, the scene."""
    scenario, text = load_scenario(SCENARIO_DIR / "paper_mission.yaml", {"duration_s": 14, "start_time": START})
    return run(scenario, text, tmp_path_factory.mktemp("fox") / "paper.mcap").log_path


def test_every_json_message_validates_against_its_schema(paper_log):
    validators, checked, bad = {}, 0, []
    with open(paper_log, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.message_encoding != "json":
                continue
            if schema.id not in validators:
                validators[schema.id] = Draft202012Validator(json.loads(schema.data))
            checked += 1
            bad += [(channel.topic, e.message) for e in validators[schema.id].iter_errors(json.loads(message.data))]
    assert checked > 4000 and not bad, bad[:5]


def test_nan_fields_are_left_out_and_read_back_as_nan(paper_log):
    log = read_log(paper_log)
    raw = [json.loads(d) for _, d in log.raw("/fsw/status")]
    assert any("lock_t_s" not in r for r in raw)  # before lock: NaN, so left out
    st = log.table("/fsw/status")
    assert np.isnan(st["lock_t_s"][0]) and len(st["lock_t_s"]) == len(raw)
    det = log.table("/camera/detection")
    assert det["bbox_px"].shape == (len(det["t_s"]), 4)
    row = log.rows("/fsw/status")[0]
    assert np.isnan(row["lock_t_s"])


def test_log_times_start_at_the_scenario_start_time_and_messages_keep_sim_time(paper_log):
    with open(paper_log, "rb") as f:
        reader = make_reader(f)
        stats = reader.get_summary().statistics
        assert stats.message_start_time == START_NS
        _, _, first_tf = next(reader.iter_messages(topics=["/tf"]))
    log = read_log(paper_log)
    assert log.epoch_ns == START_NS and log.metadata["fwsim"]["log_time_epoch_utc"].startswith("2026-05-01T09:30")
    assert log.raw("/uav/state")[0][0] == 0 and log.table("/uav/state")["t_s"][0] == 0.0
    t, _, _ = log.poses()
    assert t[0] == 0.0 and t[-1] == pytest.approx(14.0, abs=0.05)
    assert first_tf.log_time == START_NS
    assert log.events()[0][0] == 0.0


def test_foxglove_types_are_there(paper_log):
    log = read_log(paper_log)
    names = {t: log.schema_name(t) for t in ("/scene", "/uav/fix", "/camera/annotations", "/camera/image", "/tf")}
    assert names == {"/scene": "foxglove.SceneUpdate", "/uav/fix": "foxglove.LocationFix",
                     "/camera/annotations": "foxglove.ImageAnnotations", "/camera/image": "foxglove.CompressedImage",
                     "/tf": "foxglove.FrameTransform"}


@pytest.mark.parametrize("value, words", [("yesterday", "not an ISO 8601"), ("1850-01-01T00:00:00", "1970-2200")])
def test_a_bad_start_time_is_one_line(value, words):
    with pytest.raises(ScenarioError, match=words):
        load_scenario(SCENARIO_DIR / "paper_mission.yaml", {"start_time": value})


def test_without_start_time_the_log_starts_at_the_wall_clock(tmp_path):
    import time
    scenario, text = load_scenario(SCENARIO_DIR / "autopilot_checkout.yaml", {"duration_s": 1})
    before = time.time_ns()
    log = read_log(run(scenario, text, tmp_path / "now.mcap").log_path)
    assert before - 10**6 <= log.epoch_ns <= time.time_ns()
