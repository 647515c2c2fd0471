"""fwsim run --rerun: the live Rerun view, fed by the LogWriter as the run flies."""
import logging
import re
import shutil
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import rerun as rr
from rerun.chunk import RrdReader

from controllers.estimation.ukf import TargetEstimate
from fwsim import SCENARIO_DIR
from fwsim.log import LogWriter, read_log
from fwsim.log.rerun_export import TIMELINE, export_rrd
from fwsim.log.rerun_live import DEFAULT_URL, LiveTarget, LiveViewError, RerunLive, parse_target
from fwsim.sim.loop import run
from fwsim.interface.messages import AirframeState, FlightSoftwareStatus
from fwsim.scenario.model import load_scenario
from fwsim.world.target import TargetState

CHECKOUT = SCENARIO_DIR / "autopilot_checkout.yaml"
DURATION_S = 4.0


def checkout(**overrides):
    """The checkout, short, with a fixed log epoch so that two runs' logs can be compared byte for byte."""
    return load_scenario(CHECKOUT, {"duration_s": DURATION_S, "start_time": "2026-01-01T00:00:00Z", **overrides})


@pytest.fixture(scope="module")
def live_run(tmp_path_factory):
    """A short closed-loop run through the CLI with --rerun save=..., and the replay of its log."""
    from fwsim.cli import main
    tmp = tmp_path_factory.mktemp("live")
    log, rrd = tmp / "run.mcap", tmp / "live.rrd"
    code = main(["run", str(CHECKOUT), "--log", str(log), "--set", f"duration_s={DURATION_S:g}", "--quiet",
                 "--set", "start_time=2026-01-01T00:00:00Z",
                 "--rerun", f"save={rrd}"])
    assert code == 0
    replay = tmp / "replay.rrd"
    export_rrd(log, replay)
    return log, rrd, replay


def rerun_cli() -> str:
    exe = Path(sys.executable).with_name("rerun")
    exe = str(exe) if exe.is_file() else shutil.which("rerun")
    if not exe:
        pytest.fail("the `rerun` command of rerun-sdk is not installed beside this Python")
    return exe


def entities(rrd: Path) -> set[str]:
    return set(RrdReader(rrd).store().schema().entity_paths())


def rows(rrd: Path, entity: str, column: str) -> int:
    """Rows of ``column`` on ``entity``, summed over its chunks."""
    n = 0
    for line in RrdReader(rrd).store().summary().splitlines():
        if line.split()[0] == entity and column in line:
            assert f"'{TIMELINE}'" in line, line
            n += int(re.search(r"rows=(\d+)", line).group(1))
    return n


def views(rrd: Path) -> list[tuple]:
    """(kind, name, origin) of each view in the recording's default blueprint."""
    reader = RrdReader(rrd)
    (bp,) = reader.blueprints()
    out = []
    for chunk in RrdReader(rrd).store(store=bp).stream():
        if chunk.entity_path.startswith("/view/") and "ViewContents" not in chunk.entity_path:
            batch = chunk.to_record_batch()
            out.append(tuple(str(batch.column(f).to_pylist()) for f in batch.schema.names if "ViewBlueprint" in f))
    return sorted(out)


def test_live_rrd_verifies_and_has_the_flight(live_run):
    log, rrd, _ = live_run
    proc = subprocess.run([rerun_cli(), "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    (recording,) = RrdReader(rrd).recordings()
    assert recording.application_id == "fwsim"
    # Poses and scalars thinned to <= 20 Hz of sim time (30 Hz logged: every other one), plus the last pose.
    n_state = read_log(log).topics["/uav/state"]
    n_uav = rows(rrd, "/world/uav", "Transform3D:translation")
    assert DURATION_S * 10 <= n_uav <= DURATION_S * 20 + 2 and n_uav < n_state
    assert DURATION_S * 10 <= rows(rrd, "/plots/airspeed/truth", "Scalars:scalars") <= DURATION_S * 20 + 1
    for entity in ("/plots/rates/p/actual", "/plots/gimbal/pan", "/plots/target/distance"):
        assert rows(rrd, entity, "Scalars:scalars") > DURATION_S * 10, entity
    for entity in ("/world/camera", "/world/target"):
        assert rows(rrd, entity, "Transform3D:translation") > DURATION_S * 10, entity
    assert rows(rrd, "/camera/image", "EncodedImage:blob") == read_log(log).topics["/camera/image"]


def test_live_view_matches_the_replay(live_run):
    _, rrd, replay = live_run
    assert entities(rrd) == entities(replay)
    assert {"/world/uav", "/world/uav_path", "/plots/airspeed/truth", "/plots/altitude/height",
            "/plots/rates/q/setpoint", "/events", "/scenario", "/run"} <= entities(rrd)
    assert views(rrd) == views(replay)  # the same default blueprint


def test_the_log_is_the_same_with_a_live_view(live_run, tmp_path):
    log, _, _ = live_run
    scenario, text = checkout()
    plain = read_log(run(scenario, text, tmp_path / "plain.mcap").log_path)
    with_view = read_log(log)
    assert with_view.status == "completed" and with_view.topics == plain.topics
    for topic in plain.topics:
        assert with_view.raw(topic) == plain.raw(topic), topic


def test_a_failing_live_view_is_detached_and_the_run_goes_on(tmp_path, caplog):
    scenario, text = checkout()
    live = RerunLive(f"save={tmp_path / 'live.rrd'}", scenario=scenario, scenario_text=text)
    on_pose = live._handlers["/uav/pose"]

    def viewer_gone(t_s, msg):
        if t_s > 1.0:
            raise RuntimeError("viewer closed")
        on_pose(t_s, msg)

    live._handlers["/uav/pose"] = viewer_gone
    seen: dict[str, int] = {}

    def count(topic, t_s, msg):
        seen[topic] = seen.get(topic, 0) + 1

    def broken(topic, t_s, msg):
        raise ValueError("bad listener")

    with caplog.at_level(logging.WARNING, logger="fwsim.log"):
        try:
            result = run(scenario, text, tmp_path / "run.mcap", listeners=[broken, live, count])
        finally:
            live.close()
    assert result.status == "completed" and result.sim_time_s == pytest.approx(DURATION_S)
    log = read_log(result.log_path)
    assert log.status == "completed" and not log.truncated
    assert log.topics["/uav/state"] == DURATION_S * 30 + 1
    assert seen == log.topics  # the healthy listener saw every record, the end-of-run line included
    warnings = [r.getMessage() for r in caplog.records]
    assert len(warnings) == 2, warnings  # one each
    assert any("Rerun live view (save" in w and "t = 1.0" in w and "viewer closed" in w for w in warnings)
    assert live.failed


def test_listeners_see_protobuf_and_dataclass_records(tmp_path):
    """The live sink as a plain LogWriter listener: a mission-like stream with phases and a target estimate."""
    rrd = tmp_path / "synthetic.rrd"
    live = RerunLive(LiveTarget("save", str(rrd)))
    with LogWriter(tmp_path / "s.mcap", metadata={}, scenario_text="name: s\n", listeners=[live]) as log:
        for i in range(91):
            t = i / 30.0
            phase = 1 if t < 1.5 else 2
            log.write(
                "/fsw/status", FlightSoftwareStatus(t, phase, "acquisition" if phase == 1 else "loiter", "rates"))
            log.write_state(AirframeState(
                t, np.array([22.0 * t, 0.0, 500.0]), np.array([22.0, 0.0, 0.0]), np.array([0.0, 0.0, np.pi / 2]),
                np.zeros(3), 22.0, 0.04, 0.0, np.array([0, 0, -9.81]), 0.3, np.zeros(3), 500.0))
            ship = np.array([5.0 * t, 100.0, 0.0])
            log.write("/target/state", TargetState(t, ship, np.array([5.0, 0, 0]), np.pi / 2, 5.0))
            log.write("/fsw/estimate", TargetEstimate(t, ship + [3.0, 4.0, 0.0], np.zeros(3), np.ones(3),
                                                      np.ones(3), 0.0, 0.0, np.full(2, np.nan)))
        log.write_event(2.0, "phase: loiter")
    live.close()
    assert not live.failed
    paths = entities(rrd)
    assert {"/world/uav", "/world/uav_path", "/world/target_path", "/world/target_estimate",
            "/plots/estimate/position_error", "/plots/target/distance", "/events"} <= paths
    assert rows(rrd, "/world/target_estimate", "Points3D:positions") == 46  # 91 at 30 Hz -> every other
    strips = [c for c in RrdReader(rrd).store().stream() if c.entity_path == "/world/uav_path"][-1]  # the latest
    labels = strips.to_record_batch().column("LineStrips3D:labels").to_pylist()[-1]
    assert labels == ["phase 1: acquisition", "phase 2: loiter"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_connect_to_a_running_viewer():
    port = free_port()
    server = rr.RecordingStream("fwsim-test-viewer")
    server.serve_grpc(grpc_port=port)  # stands in for a viewer
    try:
        live = RerunLive(f"connect={port}", send_every_s=0.0)
        live("/uav/state", 0.0, AirframeState(0.0, np.array([0.0, 0, 500]), np.zeros(3), np.zeros(3), np.zeros(3),
                                               22.0, 0.0, 0.0, np.zeros(3), 0.3, np.zeros(3), 500.0))
        live.close()
        assert not live.failed and live.target.address == f"rerun+http://127.0.0.1:{port}/proxy"
    finally:
        server.disconnect()
    port = free_port()  # nobody listens there
    with pytest.raises(LiveViewError, match=f"--rerun connect: no Rerun viewer at rerun\\+http://127.0.0.1:{port}/"):
        RerunLive(f"connect={port}")


@pytest.mark.parametrize("text, expected", [
    ("spawn", LiveTarget("spawn", DEFAULT_URL)),
    ("connect", LiveTarget("connect", DEFAULT_URL)),
    ("connect=9877", LiveTarget("connect", "rerun+http://127.0.0.1:9877/proxy")),
    ("connect=viewer.local:9000", LiveTarget("connect", "rerun+http://viewer.local:9000/proxy")),
    ("connect=rerun+https://example.org:443/proxy", LiveTarget("connect", "rerun+https://example.org:443/proxy")),
    ("save=out/run.rrd", LiveTarget("save", "out/run.rrd")),
])
def test_parse_rerun_values(text, expected):
    assert parse_target(text) == expected


@pytest.mark.parametrize("value", ["", "bogus", "spawn=1", "save=", "save=run.mcap", "connect=x", "connect=99999",
                                   "connect=http://h:1/proxy", "connect=rerun+http://h:1/other"])
def test_cli_bad_rerun_value_is_one_line_and_exit_2(value, tmp_path, capsys):
    from fwsim.cli import main
    code = main(["run", str(CHECKOUT), "--log", str(tmp_path / "x.mcap"), "--rerun", value])
    out, err = capsys.readouterr()
    assert code == 2
    assert err.startswith("error: --rerun") and err.count("\n") == 1, err
    assert not (tmp_path / "x.mcap").exists()  # nothing flown


def test_cli_unwritable_rrd_is_one_line_and_exit_2(tmp_path, capsys):
    from fwsim.cli import main
    (tmp_path / "file").write_text("")
    code = main(["run", str(CHECKOUT), "--log", str(tmp_path / "x.mcap"), "--rerun", f"save={tmp_path}/file/x.rrd"])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: --rerun save: cannot write") and err.count("\n") == 1, err


def _series(rrd: Path, entity: str) -> dict[int, float]:
    """{sim time in microseconds: value} of one scalar series."""
    out = {}
    for chunk in RrdReader(rrd).store().stream():
        if chunk.entity_path != entity:
            continue
        b = chunk.to_record_batch()
        names = b.schema.names
        tc = [n for n in names if n.endswith(TIMELINE)]
        sc = [n for n in names if "Scalars:scalars" in n]
        if tc and sc:
            times = b.column(names.index(tc[0])).cast("int64").to_pylist()
            for t, v in zip(times, b.column(names.index(sc[0])).to_pylist()):
                out[round(t / 1000)] = v[0] if isinstance(v, list) else v
    return out


def test_live_and_replay_plot_the_same_values_from_one_signal_table(tmp_path):
    """Both views come from rerun_export.SIGNALS: at the times both have, every series agrees, those relative to
    the truth (the estimate's error, the distance to the ship) included: both interpolate the truth the same way
    (the live view waits for the truth after each value's time)."""
    from fwsim.cli import main
    from fwsim.log.rerun_export import SIGNALS
    log, live, replay = tmp_path / "r.mcap", tmp_path / "live.rrd", tmp_path / "replay.rrd"
    assert main(["run", str(SCENARIO_DIR / "paper_mission.yaml"), "--log", str(log), "--set", "duration_s=20",
                 "--quiet", "--rerun", f"save={live}"]) == 0
    export_rrd(log, replay)
    for sig in SIGNALS:
        a, b = _series(live, "/" + sig.series.path), _series(replay, "/" + sig.series.path)
        common = sorted(set(a) & set(b))
        assert len(common) >= 0.9 * len(a) and len(a) > 50, (sig.series.path, len(a), len(common))
        worst = max(abs(a[t] - b[t]) for t in common if np.isfinite(a[t]) or np.isfinite(b[t]))
        assert worst < 1e-9, (sig.series.path, worst)
