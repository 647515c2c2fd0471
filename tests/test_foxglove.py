"""Logs that third-party readers take as they are: every JSON message valid against its own JSON Schema, log
times at a real date, Foxglove's own message types for the 3D panel, the map and the image boxes."""
import json

import numpy as np
import pytest
from jsonschema import Draft202012Validator
from mcap.reader import make_reader

from fwsim import SCENARIO_DIR
from fwsim.log import read_log
from fwsim.sim.loop import run
from fwsim.scenario.model import ScenarioError, load_scenario

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
    names = {t: log.schema_name(t) for t in ("/scene", "/scene/paths", "/uav/fix", "/camera/annotations",
                                             "/camera/image", "/tf")}
    assert names == {"/scene": "foxglove.SceneUpdate", "/scene/paths": "foxglove.SceneUpdate",
                     "/uav/fix": "foxglove.LocationFix",
                     "/camera/annotations": "foxglove.ImageAnnotations", "/camera/image": "foxglove.CompressedImage",
                     "/tf": "foxglove.FrameTransform"}


def test_the_navigation_estimate_is_posed_beside_the_truth(paper_typical, paper_log):
    """On a sensor profile the INS's estimate is a second pose for the 3D panel: /tf frame uav_estimate (beside
    uav, in world) and /nav/pose, one per /nav/estimate once initialised, within a few metres of the truth at
    the same time stamp. The ideal profile has neither."""
    from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
    log = read_log(paper_typical)
    assert log.schema_name("/nav/pose") == "foxglove.PoseInFrame"
    tfs = [FrameTransform.FromString(d) for _, d in log.raw("/tf")]
    truth = {(tf.timestamp.seconds, tf.timestamp.nanos): tf for tf in tfs if tf.child_frame_id == "uav"}
    est = [tf for tf in tfs if tf.child_frame_id == "uav_estimate"]
    nav = log.table("/nav/estimate")
    assert len(est) == log.topics["/nav/pose"] == int(np.sum(nav["mode"] != "initialising")) > 1000
    assert {tf.parent_frame_id for tf in est} == {"world"}
    err_m = [np.linalg.norm([a.translation.x - b.translation.x, a.translation.y - b.translation.y,
                             a.translation.z - b.translation.z])
             for a in est for b in [truth[(a.timestamp.seconds, a.timestamp.nanos)]]]
    assert max(err_m) < 5.0 and np.median(err_m) < 2.0, (max(err_m), np.median(err_m))
    poses = [PoseInFrame.FromString(d) for _, d in log.raw("/nav/pose")]
    assert [(p.pose.position.x, p.pose.position.y, p.pose.position.z) for p in poses] == \
        [(tf.translation.x, tf.translation.y, tf.translation.z) for tf in est]
    ideal = read_log(paper_log)
    assert "/nav/pose" not in ideal.topics
    assert not any(FrameTransform.FromString(d).child_frame_id == "uav_estimate" for _, d in ideal.raw("/tf"))


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


def test_the_flown_paths_are_line_strips_that_join_up(paper_log):
    from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
    log = read_log(paper_log)
    updates = [SceneUpdate.FromString(d) for _, d in log.raw("/scene/paths")]
    assert len(updates) >= 13  # a segment a second, and the last part at the end
    uav = [next(e for e in u.entities if e.id.startswith("uav_path_")) for u in updates]
    assert len({e.id for e in uav}) == len(uav) and all(e.frame_id == "world" for e in uav)
    for a, b in zip(uav, uav[1:]):
        end, start = a.lines[0].points[-1], b.lines[0].points[0]
        assert (end.x, end.y, end.z) == (start.x, start.y, start.z)
    st = log.table("/uav/state")
    first, last = uav[0].lines[0].points[0], uav[-1].lines[0].points[-1]
    np.testing.assert_allclose([first.x, first.y, first.z], st["pos_enu_m"][0])
    np.testing.assert_allclose([last.x, last.y, last.z], st["pos_enu_m"][-1])


def test_what_rerun_makes_of_the_mcap_directly(paper_log, tmp_path):
    """docs/guide/logs.md 'Opening the MCAP in Rerun': Rerun's own MCAP loader turns the Foxglove topics into its
    archetypes; the JSON topics stay raw message blobs (the plots come through `fwsim replay`)."""
    import re
    import shutil
    import subprocess
    import sys
    from pathlib import Path
    rerun = shutil.which("rerun", path=str(Path(sys.executable).parent)) or shutil.which("rerun")
    assert rerun, "the rerun command comes with rerun-sdk"
    rrd = tmp_path / "direct.rrd"
    subprocess.run([rerun, "mcap", "convert", str(paper_log), "-o", str(rrd)], check=True, capture_output=True,
                   timeout=300)
    out = subprocess.run([rerun, "rrd", "print", str(rrd)], check=True, capture_output=True, text=True,
                         timeout=300).stdout
    columns: dict[str, set] = {}
    for entity, cols in re.findall(r" - (/[\w/]+) - data columns: \[([^\]]*)\]", out):
        columns.setdefault(entity, set()).update(cols.split())
    expected = {"/tf": "Transform3D:translation", "/uav/pose": "InstancePoses3D:translations",
                "/uav/fix": "GeoPoints:positions", "/camera/image": "EncodedImage:blob",
                "/camera/calibration": "Pinhole:image_from_camera", "/events": "TextLog:text",
                "/uav/state": "McapMessage:data", "/fsw/status": "McapMessage:data",
                "/scene": "foxglove.SceneUpdate:message", "/camera/annotations": "foxglove.ImageAnnotations:message"}
    for entity, column in expected.items():
        assert column in columns.get(entity, set()), (entity, sorted(columns.get(entity, ())))
