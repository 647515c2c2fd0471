"""fwsim replay: a log becomes a Rerun recording (.rrd) that Rerun loads back."""
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from rerun.chunk import RrdReader

from fwsim import SCENARIO_DIR
from fwsim.log import LogWriter, read_log
from fwsim.log.rerun_export import LAYERS, TIMELINE, export_rrd
from fwsim.sim.loop import run
from fwsim.interface.messages import AirframeState
from fwsim.scenario.model import load_scenario

RERUN = Path(sys.executable).with_name("rerun")


@pytest.fixture(scope="module")
def mission_log(tmp_path_factory):
    scenario, text = load_scenario(SCENARIO_DIR / "paper_mission.yaml", {"duration_s": 10})
    return run(scenario, text, tmp_path_factory.mktemp("replay") / "mission.mcap").log_path


def rerun_cli() -> str:
    exe = RERUN if RERUN.is_file() else shutil.which("rerun")
    if not exe:
        pytest.fail("the `rerun` command of rerun-sdk is not installed beside this Python")
    return str(exe)


def entities(rrd: Path) -> set[str]:
    return set(RrdReader(rrd).store().schema().entity_paths())


def test_replay_writes_an_rrd_that_rerun_loads(mission_log, tmp_path):
    rrd = tmp_path / "mission.rrd"
    res = export_rrd(mission_log, rrd)
    assert rrd.stat().st_size > 10_000
    assert set(res.layers) >= {"uav", "flight_plots", "inner_loops", "events", "target", "camera"}
    proc = subprocess.run([rerun_cli(), "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr

    reader = RrdReader(rrd)
    (recording,) = reader.recordings()
    assert recording.application_id == "fwsim"
    assert reader.blueprints(), "no default blueprint"
    store = reader.store()
    paths = set(store.schema().entity_paths())
    for p in ("/world/uav", "/world/uav/body", "/world/uav/axes", "/world/uav_path",
              "/plots/airspeed/truth", "/plots/airspeed/setpoint", "/plots/altitude/height",
              "/plots/attitude/roll", "/plots/attitude/pitch", "/plots/rates/p/actual", "/plots/rates/p/setpoint",
              "/plots/rates/q/actual", "/plots/rates/q/setpoint", "/events", "/scenario",
              "/world/target", "/world/camera"):
        assert p in paths, p
    summary = store.summary()
    uav = next(ln for ln in summary.splitlines() if ln.startswith("/world/uav ") and "Transform3D:translation" in ln)
    assert f"timelines=['{TIMELINE}']" in uav and "rows=301" in uav  # 10 s at 30 Hz + the first state
    # The default layout: a 3D view and time-series views.
    bp = RrdReader(rrd).store(store=reader.blueprints()[0]).summary()
    assert sum(ln.startswith("/view/") and "/ViewContents" not in ln.split()[0] for ln in bp.splitlines()) >= 6


def state_only_log(path, n=60):
    with LogWriter(path, metadata={"scenario": "state-only", "seed": "0"}, scenario_text="name: state-only\n") as log:
        for i in range(n):
            t = i / 30.0
            log.write_state(AirframeState(
                t_s=t, pos_enu_m=np.array([22.0 * t, 0.0, 500.0]), vel_enu_m_s=np.array([22.0, 0.0, 0.0]),
                euler_ned_rad=np.array([0.0, 0.0, np.pi / 2]), body_rates_frd_rad_s=np.zeros(3), airspeed_m_s=22.0,
                alpha_rad=0.04, beta_rad=0.0, specific_force_frd_m_s2=np.array([0, 0, -9.81]), throttle_norm=0.3,
                surfaces_rad=np.zeros(3), height_above_sea_m=500.0))
    return path


def test_replay_skips_layers_without_their_topics(tmp_path):
    rrd = tmp_path / "state.rrd"
    res = export_rrd(state_only_log(tmp_path / "state.mcap"), rrd)
    assert set(res.layers) == {"uav", "flight_plots", "events"}  # no inner loops, target, camera, estimate
    skipped = dict(res.skipped)
    assert skipped["inner_loops"] == "no /autopilot/status in this log"
    assert set(skipped) == set(LAYERS) - set(res.layers)
    paths = entities(rrd)
    assert "/world/uav" in paths and not any(p.startswith("/plots/rates") or p.startswith("/world/camera")
                                             for p in paths)


def test_the_navigation_estimate_is_drawn_beside_the_truth(paper_typical, mission_log, tmp_path):
    """The nav_estimate layer: the INS's position as a second point and path beside the UAV's, and its error
    per axis against the truth; a log without /nav/estimate (the ideal profile) skips it."""
    res = export_rrd(paper_typical, tmp_path / "typical.rrd")
    assert "nav_estimate" in res.layers and "uav" in res.layers
    summary = RrdReader(tmp_path / "typical.rrd").store().summary().splitlines()
    n_nav = read_log(paper_typical).topics["/nav/pose"]  # the initialised estimates
    for entity, column in (("/world/uav_estimate", "Points3D:positions"),
                           ("/world/uav_estimate_path", "LineStrips3D:strips"),
                           ("/plots/nav/position_error/east", "Scalars:scalars"),
                           ("/plots/nav/position_error/up", "Scalars:scalars")):
        assert any(ln.split()[0] == entity and column in ln for ln in summary), entity
    points = next(ln for ln in summary if ln.split()[0] == "/world/uav_estimate" and "Points3D:labels" in ln)
    assert f"rows={n_nav}" in points and f"timelines=['{TIMELINE}']" in points

    ideal = export_rrd(mission_log, tmp_path / "ideal.rrd")
    assert dict(ideal.skipped)["nav_estimate"] == "no /nav/estimate in this log"
    assert not any("uav_estimate" in p or p.startswith("/plots/nav") for p in entities(tmp_path / "ideal.rrd"))


def test_cli_replay(mission_log, tmp_path, capsys):
    from fwsim.cli import main
    rrd = tmp_path / "cli.rrd"
    code = main(["replay", str(mission_log), "--rrd", str(rrd)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert out.strip() == str(rrd) and f"rerun {rrd}" in err
    assert "/world/uav" in entities(rrd)


def test_an_rrd_path_that_cannot_be_written_is_refused(mission_log, tmp_path, capsys):
    from fwsim.cli import main
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    assert main(["replay", str(mission_log), "--rrd", str(a_file / "x.rrd")]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: --rrd {a_file / 'x.rrd'}: {a_file} is a file, not a folder"
    assert main(["replay", str(mission_log), "--rrd", str(tmp_path)]) == 2
    assert "is a folder, expected a file" in capsys.readouterr().err
    assert a_file.read_text() == "x"
