"""Tests of fwsim.log: the MCAP run log (writer + reader)."""
from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pytest
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.Log_pb2 import Log
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from fwsim.log import LogWriter, RunLog, read_log
from fwsim.log.schema import describe_field, json_schema
from fwsim.interface.messages import AccelCommand, AirframeState, AutopilotStatus, NavEstimate, RateCommand

META = {"fwsim_version": "0.1.0", "jsbsim_version": "1.2.1", "seed": "42",
        "aircraft_hash": "abc123", "scenario": "unit-test"}
SCENARIO = "name: unit-test\nduration_s: 2.0\ntarget:\n  speed_m_s: 5.0  # knots? no, m/s\n"


def quat_enu_from_frd(euler):
    from fwsim.interface.frames import quat_enu_from_frd as f

    return f(euler)


def make_state(i: int) -> AirframeState:
    t = i / 120.0
    return AirframeState(
        t_s=t,
        pos_enu_m=np.array([10.0 + i, -5.0 + 0.5 * i, 100.0 - 0.1 * i]),
        vel_enu_m_s=np.array([0.0, 20.0, -1.0]),
        euler_ned_rad=np.array([0.1 * np.sin(t), 0.05, 0.3 + 0.01 * i]),
        body_rates_frd_rad_s=np.array([0.01, -0.02, 0.03 * i]),
        airspeed_m_s=20.0 + 0.01 * i,
        alpha_rad=0.04,
        beta_rad=np.nan if i % 3 == 0 else 0.001 * i,
        specific_force_frd_m_s2=np.array([0.1, np.nan, -9.81]),
        throttle_norm=0.6,
        surfaces_rad=np.array([0.0, -0.02, 0.001]),
        height_above_sea_m=100.0 - 0.1 * i,
    )


def write_run(path, n=50, **close):
    states = [make_state(i) for i in range(n)]
    with LogWriter(path, metadata=META, scenario_text=SCENARIO) as log:
        for s in states:
            log.write_state(s)
        log.write_event(0.1, "phase: cruise")
        log.write_event(0.2, "something odd", level="WARNING")
    return states


def test_round_trip_states_and_messages(tmp_path):
    path = tmp_path / "run.mcap"
    states = [make_state(i) for i in range(60)]
    rate = [RateCommand(t_s=s.t_s, airspeed_m_s=20.0, roll_rate_rad_s=0.1 * k,
                        pitch_rate_rad_s=np.nan) for k, s in enumerate(states[:30])]
    accel = [AccelCommand(t_s=s.t_s, airspeed_m_s=21.0,
                          accel_enu_m_s2=np.array([1.0, np.nan, 2.0 + k]))
             for k, s in enumerate(states[30:])]
    status = [AutopilotStatus(t_s=s.t_s, mode="rates", airspeed_sp_m_s=20.0, airspeed_m_s=19.5,
                              body_rates_sp_frd_rad_s=np.array([0.1, 0.2, 0.3]), body_rates_frd_rad_s=np.zeros(3),
                              bank_sp_rad=np.nan) for s in states[::2]]
    with LogWriter(path, metadata=META, scenario_text=SCENARIO) as log:
        for s in states:
            log.write_state(s)
        for m in rate + accel:  # both command types on one topic
            log.write("/autopilot/command", m)
        for m in status:
            log.write("/autopilot/status", m)

    run = read_log(path)
    assert isinstance(run, RunLog)
    assert run.status == "completed" and run.reason == "" and not run.truncated
    assert run.topics["/uav/state"] == 60
    assert run.topics["/tf"] == 60 and run.topics["/uav/pose"] == 60
    assert run.topics["/autopilot/command"] == 60 and run.topics["/autopilot/status"] == 30

    tab = run.table("/uav/state")
    np.testing.assert_array_equal(tab["t_s"], [s.t_s for s in states])
    for name in ("pos_enu_m", "vel_enu_m_s", "euler_ned_rad", "body_rates_frd_rad_s",
                 "specific_force_frd_m_s2", "surfaces_rad"):
        assert tab[name].shape == (60, 3)
        np.testing.assert_array_equal(tab[name], np.array([getattr(s, name) for s in states]))
    for name in ("airspeed_m_s", "alpha_rad", "beta_rad", "throttle_norm", "height_above_sea_m"):
        assert tab[name].shape == (60,) and tab[name].dtype == float
        np.testing.assert_array_equal(tab[name], [getattr(s, name) for s in states])
    assert np.isnan(tab["beta_rad"][0]) and np.isnan(tab["specific_force_frd_m_s2"][:, 1]).all()

    cmd = run.table("/autopilot/command")
    assert list(cmd["mode"][:30]) == ["rates"] * 30 and list(cmd["mode"][30:]) == ["accel"] * 30
    assert np.isnan(cmd["pitch_rate_rad_s"]).all()
    np.testing.assert_array_equal(cmd["roll_rate_rad_s"][:30], [m.roll_rate_rad_s for m in rate])
    assert np.isnan(cmd["roll_rate_rad_s"][30:]).all()  # field absent from AccelCommand
    assert cmd["accel_enu_m_s2"].shape == (60, 3) and np.isnan(cmd["accel_enu_m_s2"][:30]).all()
    np.testing.assert_array_equal(cmd["accel_enu_m_s2"][30:], [m.accel_enu_m_s2 for m in accel])

    st = run.table("/autopilot/status")
    assert np.isnan(st["bank_sp_rad"]).all() and np.isnan(st["accel_sp_enu_m_s2"]).all()
    np.testing.assert_array_equal(st["body_rates_sp_frd_rad_s"], np.tile([0.1, 0.2, 0.3], (30, 1)))

    t, pos, quat = run.poses()
    np.testing.assert_allclose(t, tab["t_s"], rtol=0, atol=1e-9)  # ns stamps
    np.testing.assert_array_equal(pos, tab["pos_enu_m"])
    expected = np.array([quat_enu_from_frd(s.euler_ned_rad) for s in states])
    np.testing.assert_allclose(quat, expected, atol=1e-15)


def test_json_is_valid_and_schema_generated(tmp_path):
    path = tmp_path / "run.mcap"
    write_run(path, n=3)
    with open(path, "rb") as f:
        reader = make_reader(f)
        schema, channel, message = next(reader.iter_messages(topics=["/uav/state"]))
    assert channel.message_encoding == "json" and schema.encoding == "jsonschema"
    doc = json.loads(message.data)  # strict JSON: a NaN number is left out, a partly NaN array has null
    assert "beta_rad" not in doc and doc["specific_force_frd_m_s2"][1] is None
    assert b"NaN" not in message.data
    sch = json.loads(schema.data)
    assert sch["description"].startswith("Truth state of the UAV")
    props = sch["properties"]
    assert props["vel_enu_m_s"]["type"] == "array" and props["vel_enu_m_s"]["items"] == {"type": "number"}
    assert props["vel_enu_m_s"]["description"].startswith("metres per second")
    assert props["alpha_rad"] == {"type": "number", "description": "radians"}
    assert props["throttle_norm"]["description"] == "normalised"
    assert props["specific_force_frd_m_s2"]["description"].startswith("metres per second squared")
    assert json_schema(RateCommand)["properties"]["mode"] == {
        "type": "string", "enum": ["rates"], "description": "mode"}
    assert describe_field("body_rates_frd_rad_s") == "radians per second, body frame (FRD)"


def test_generic_dataclass_types(tmp_path):
    @dataclass(frozen=True)
    class Probe:
        """A test message."""

        t_s: float
        count: int
        ok: bool
        label: str
        gain: float | None = None

    path = tmp_path / "run.mcap"
    with LogWriter(path, metadata=META, scenario_text=SCENARIO) as log:
        log.write("/probe", Probe(0.0, np.int64(3), np.bool_(True), "a"))
        log.write("/probe", Probe(0.5, 4, False, "b", float("inf")))
    tab = read_log(path).table("/probe")
    np.testing.assert_array_equal(tab["t_s"], [0.0, 0.5])
    np.testing.assert_array_equal(tab["count"], [3, 4])
    assert tab["ok"].dtype == bool and list(tab["ok"]) == [True, False]
    assert list(tab["label"]) == ["a", "b"]
    assert np.isnan(tab["gain"]).all()  # None and inf are both null in JSON

    @dataclass(frozen=True)
    class Bad:
        t_s: float
        obj: dict

    with LogWriter(tmp_path / "bad.mcap", metadata=META, scenario_text="") as log:
        with pytest.raises(TypeError, match="Bad.obj"):
            log.write("/bad", Bad(0.0, {}))


def test_foxglove_topics_decode(tmp_path):
    path = tmp_path / "run.mcap"
    states = write_run(path, n=5)
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        tfs = [(s, c, m) for s, c, m in reader.iter_messages(topics=["/tf"])]
    assert len(tfs) == 5
    schema, channel, message = tfs[-1]
    assert schema.name == "foxglove.FrameTransform" and schema.encoding == "protobuf"
    assert channel.message_encoding == "protobuf"
    tf = FrameTransform.FromString(message.data)
    assert tf.parent_frame_id == "world" and tf.child_frame_id == "uav"
    s = states[-1]
    assert (tf.translation.x, tf.translation.y, tf.translation.z) == tuple(s.pos_enu_m)
    q = quat_enu_from_frd(s.euler_ned_rad)
    np.testing.assert_allclose([tf.rotation.w, tf.rotation.x, tf.rotation.y, tf.rotation.z], q)
    assert tf.timestamp.seconds * 10**9 + tf.timestamp.nanos == message.log_time == int(s.t_s * 1e9)

    with open(path, "rb") as f:  # the schema alone (FileDescriptorSet) is enough to decode
        decoded = [d for *_, d in make_reader(f, decoder_factories=[DecoderFactory()])
                   .iter_decoded_messages(topics=["/uav/pose", "/events"])]
    pose = [d for d in decoded if d.DESCRIPTOR.full_name == "foxglove.PoseInFrame"][-1]
    assert PoseInFrame.FromString(pose.SerializeToString()).frame_id == "world"
    logs = [Log.FromString(d.SerializeToString()) for d in decoded
            if d.DESCRIPTOR.full_name == "foxglove.Log"]
    assert [lg.message for lg in logs][:2] == ["phase: cruise", "something odd"]
    assert logs[1].level == Log.WARNING

    ev = read_log(path).events()
    assert ev[0] == (pytest.approx(0.1), "INFO", "phase: cruise")
    assert ev[1][1:] == ("WARNING", "something odd")
    assert ev[-1][1:] == ("INFO", "run completed")


def nav_estimate_of(s: AirframeState, initialised: bool = True) -> NavEstimate:
    """A navigation estimate equal to the truth ``s`` (NaN while initialising, as the INS gives it)."""
    if not initialised:
        nan3 = np.full(3, np.nan)
        return NavEstimate(s.t_s, *[nan3] * 11, "initialising", np.inf)
    z = np.zeros(3)
    return NavEstimate(s.t_s, s.pos_enu_m, s.vel_enu_m_s, s.euler_ned_rad, s.body_rates_frd_rad_s, z, z, z,
                       np.full(3, np.nan), np.ones(3), np.ones(3), np.ones(3), "aided", 0.0)


def test_a_perfect_navigation_estimate_is_posed_where_the_truth_is(tmp_path):
    """write_nav_estimate: /nav/estimate as before, and its pose on /tf (frame uav_estimate) and /nav/pose in the
    truth's own conventions, so that a perfect estimate coincides with the truth; none while initialising."""
    path = tmp_path / "nav.mcap"
    states = [make_state(i) for i in range(6)]
    with LogWriter(path, metadata=META, scenario_text=SCENARIO) as log:
        for i, s in enumerate(states):
            log.write_state(s)
            log.write_nav_estimate(nav_estimate_of(s, initialised=i > 0))
    run = read_log(path)
    assert run.topics["/nav/estimate"] == 6 and run.topics["/nav/pose"] == 5
    assert run.schema_name("/nav/pose") == "foxglove.PoseInFrame"
    tfs = [FrameTransform.FromString(d) for _, d in run.raw("/tf")]
    truth = {tf.timestamp.nanos: tf for tf in tfs if tf.child_frame_id == "uav"}
    est = [tf for tf in tfs if tf.child_frame_id == "uav_estimate"]
    assert len(est) == 5 and {tf.parent_frame_id for tf in est} == {"world"}
    for tf in est:
        assert tf.translation == truth[tf.timestamp.nanos].translation
        assert tf.rotation == truth[tf.timestamp.nanos].rotation
    poses = [PoseInFrame.FromString(d) for _, d in run.raw("/nav/pose")]
    truth_poses = [PoseInFrame.FromString(d) for _, d in run.raw("/uav/pose")][1:]
    assert [p.pose for p in poses] == [p.pose for p in truth_poses] and {p.frame_id for p in poses} == {"world"}
    assert [p.timestamp for p in poses] == [p.timestamp for p in truth_poses]


def test_metadata_and_attachment_round_trip(tmp_path):
    path = tmp_path / "run.mcap"
    write_run(path, n=2)
    run = read_log(path)
    epoch = {"log_time_epoch_ns": "0", "log_time_epoch_utc": "1970-01-01T00:00:00.000+00:00"}  # no epoch given
    assert run.metadata["fwsim"] == {**META, **epoch}
    assert run.metadata["run_status"] == {"status": "completed", "reason": ""}
    assert run.scenario_text == SCENARIO
    with open(path, "rb") as f:
        reader = make_reader(f)
        assert reader.get_header().profile == ""
        att = list(reader.iter_attachments())
        summary = reader.get_summary()
    assert [(a.name, a.media_type) for a in att] == [("scenario.yaml", "application/yaml")]
    assert summary is not None and summary.statistics.message_count == 2 * 3 + 3
    assert all(c.compression == "zstd" for c in summary.chunk_indexes)


def test_exception_in_with_block_marks_failed(tmp_path):
    path = tmp_path / "run.mcap"
    with pytest.raises(RuntimeError, match="solver diverged"):
        with LogWriter(path, metadata=META, scenario_text=SCENARIO) as log:
            for i in range(10):
                log.write_state(make_state(i))
            raise RuntimeError("solver diverged")
    assert log.closed
    run = read_log(path)
    assert run.status == "failed" and not run.truncated
    assert run.reason.startswith("RuntimeError: solver diverged")
    assert "test_log.py:" in run.reason
    assert run.topics["/uav/state"] == 10
    assert run.events()[-1][1] == "ERROR" and "RuntimeError" in run.events()[-1][2]


def test_keyboard_interrupt_marks_interrupted(tmp_path):
    path = tmp_path / "run.mcap"
    with pytest.raises(KeyboardInterrupt):
        with LogWriter(path, metadata=META, scenario_text=SCENARIO) as log:
            log.write_state(make_state(0))
            raise KeyboardInterrupt
    run = read_log(path)
    assert run.status == "interrupted" and "KeyboardInterrupt" in run.reason


def test_close_in_finally_and_idempotent(tmp_path):
    path = tmp_path / "run.mcap"
    log = LogWriter(path, metadata=META, scenario_text=SCENARIO)
    with pytest.raises(ValueError):
        try:
            log.write_state(make_state(0))
            raise ValueError("bad scenario")
        finally:
            log.close()  # default status: sees the exception in flight
    log.close()
    log.close("completed")  # no effect once closed
    with pytest.raises(ValueError, match="closed"):
        log.write_state(make_state(1))
    run = read_log(path)
    assert run.status == "failed" and run.reason.startswith("ValueError: bad scenario")
    assert len(run.metadata) == 2

    # Explicit close inside the with-block, then __exit__ is a no-op.
    path2 = tmp_path / "run2.mcap"
    with LogWriter(path2, metadata=META, scenario_text=SCENARIO) as log2:
        log2.write_state(make_state(0))
        log2.close("completed", "target hit")
    run2 = read_log(path2)
    assert (run2.status, run2.reason) == ("completed", "target hit")
    assert run2.events()[-1][2] == "run completed: target hit"


def test_truncated_file_reads_first_messages(tmp_path):
    path = tmp_path / "run.mcap"
    n = 1200  # 10 s at 120 Hz: several 256 KiB chunks
    with LogWriter(path, metadata=META, scenario_text=SCENARIO) as log:
        for i in range(n):
            s = make_state(i)
            log.write_state(s)
            log.write("/autopilot/command", RateCommand(s.t_s, 20.0, 0.1, np.nan))
    data = path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.7)])

    run = read_log(cut)
    assert run.truncated and run.status == "unknown"
    assert {k: run.metadata["fwsim"][k] for k in META} == META and run.scenario_text == SCENARIO
    tab = run.table("/uav/state")
    k = len(tab["t_s"])
    assert 0 < k < n
    np.testing.assert_array_equal(tab["t_s"], [i / 120.0 for i in range(k)])
    np.testing.assert_array_equal(tab["pos_enu_m"], [make_state(i).pos_enu_m for i in range(k)])
    t, pos, quat = run.poses()
    assert 0 < len(t) < n and np.allclose(np.linalg.norm(quat, axis=1), 1.0)

    # Cut inside the header / right after the magic: empty but no exception.
    for size in (8, 20):
        tiny = tmp_path / f"tiny{size}.mcap"
        tiny.write_bytes(data[:size])
        r = read_log(tiny)
        assert r.truncated and r.status == "unknown" and r.topics == {}


def test_not_mcap_raises(tmp_path):
    p = tmp_path / "x.mcap"
    p.write_bytes(b"hello world, not mcap")
    with pytest.raises(ValueError, match="not an MCAP"):
        read_log(p)


def test_fast_writer_file_is_mcaps_byte_for_byte():
    """The writer's own mcap Writer (records packed at once, chunks compressed on a worker thread) writes the
    file mcap's Writer writes: chunks, message indexes, attachments and metadata between chunks, summary."""
    import io

    from mcap.writer import CompressionType, Writer

    from fwsim.log.writer import _FastWriter

    def write(cls) -> bytes:
        out = io.BytesIO()
        w = cls(out, chunk_size=4096, compression=CompressionType.ZSTD)
        w.start(profile="", library="test")
        schema = w.register_schema(name="s", encoding="jsonschema", data=b"{}")
        channels = [w.register_channel(topic=f"/t{k}", message_encoding="json", schema_id=schema) for k in range(3)]
        for i in range(600):
            t = 1_000_000 * (i // 2)  # repeated times, as messages of one tick
            n = 2000 if i in (250, 400) else i % 7  # a message that fills a chunk: one is in compression below
            w.add_message(channels[i % 3], t, json.dumps({"i": i, "x": [i * 0.5] * n}).encode(), t, i)
            if i == 250:
                w.add_attachment(create_time=1, log_time=2, name="a.yaml", media_type="application/yaml", data=b"x")
            if i == 400:
                w.add_metadata("m", {"k": "v"})
                w.register_channel(topic="/late", message_encoding="json", schema_id=schema)
        w.add_metadata("end", {"status": "completed"})
        w.finish()
        return out.getvalue()

    fast = _FastWriter(io.BytesIO())
    assert fast.fast  # (else the test compares mcap with itself)
    assert write(_FastWriter) == write(Writer)
