"""fwsim plot: PNG figures from a log; figures whose topics are absent are skipped."""
import numpy as np
import pytest
from matplotlib.image import imread

from fwsim import SCENARIO_DIR
from fwsim.log import LogWriter, read_log
from fwsim.sim.loop import run
from fwsim.interface.messages import AirframeState
from fwsim.analysis.plot import FIGURES, plot_log
from fwsim.scenario.model import load_scenario

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


@pytest.fixture(scope="module")
def mission_log(tmp_path_factory):
    """10 s of the paper mission: state, inner loops, phases, target, gimbal, detections."""
    scenario, text = load_scenario(SCENARIO_DIR / "paper_mission.yaml", {"duration_s": 10})
    return run(scenario, text, tmp_path_factory.mktemp("plot") / "mission.mcap").log_path


def state_only_log(path, n=60):
    """A log with nothing but the UAV state (and its pose): no inner loops, no target."""
    with LogWriter(path, metadata={"scenario": "state-only", "seed": "0"}, scenario_text="name: state-only\n") as log:
        for i in range(n):
            t = i / 30.0
            log.write_state(AirframeState(
                t_s=t, pos_enu_m=np.array([22.0 * t, 0.0, 500.0 + t]), vel_enu_m_s=np.array([22.0, 0.0, 1.0]),
                euler_ned_rad=np.array([0.1 * np.sin(t), 0.05, np.pi / 2]), body_rates_frd_rad_s=np.zeros(3),
                airspeed_m_s=22.0, alpha_rad=0.04, beta_rad=0.0, specific_force_frd_m_s2=np.array([0, 0, -9.81]),
                throttle_norm=0.3, surfaces_rad=np.zeros(3), height_above_sea_m=500.0 + t))
    return path


def test_plots_of_a_short_run_are_real_pngs(mission_log, tmp_path):
    res = plot_log(mission_log, tmp_path / "plots")
    assert not res.failed, res.failed
    names = {p.stem for p in res.written}
    assert names >= {"trajectory_xy", "trajectory_xz", "altitude_airspeed", "attitude", "inner_loops",
                     "velocity_direction", "distance_to_target", "gimbal_angles"}
    for path in res.written:
        assert path.read_bytes()[:8] == PNG_MAGIC, path
        img = imread(path)
        assert img.shape[0] > 300 and img.shape[1] > 500, path
        assert img[..., :3].std() > 0.01, f"{path} is blank"
    skipped = dict(res.skipped)
    # No acceleration-mode ticks in this run: skipped on the data, with the reason.
    assert "acceleration" in skipped["accel_tracking"]
    assert names | set(skipped) == set(FIGURES) and not names & set(skipped)
    log = read_log(mission_log)
    for name, why in skipped.items():  # a figure skipped for a topic really lacks it
        if why.startswith("no /"):
            assert any(not log.topics.get(t) for t in FIGURES[name].needs), (name, why)


def test_a_log_missing_topics_skips_those_figures(tmp_path):
    res = plot_log(state_only_log(tmp_path / "state.mcap"), tmp_path / "plots")
    assert not res.failed, res.failed
    assert {p.stem for p in res.written} == {"trajectory_xy", "trajectory_xz", "altitude_airspeed", "attitude",
                                             "velocity_direction"}
    skipped = dict(res.skipped)
    assert skipped["inner_loops"] == "no /autopilot/status in this log"
    assert "/target/state" in skipped["distance_to_target"] and "/gimbal/state" in skipped["gimbal_angles"]
    assert "/camera/detection" in skipped["pixel_errors"]
    assert "/fsw/estimate" in skipped["target_estimate"] and "/fsw/estimate" in skipped["target_estimate_error"]


def test_cli_plot_lists_files_and_skips(mission_log, tmp_path, capsys):
    from fwsim.cli import main
    code = main(["plot", str(mission_log), "--out", str(tmp_path), "--only",
                 "trajectory_xy,inner_loops,accel_tracking"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert out.split() == [str(tmp_path / "trajectory_xy.png"), str(tmp_path / "inner_loops.png")]
    assert "skipped accel_tracking: no acceleration-mode ticks" in err
    assert main(["plot", str(mission_log), "--only", "nope"]) == 2
    assert "unknown figure" in capsys.readouterr().err


def test_phase_colouring_uses_fsw_status(mission_log):
    """Colours follow (phase, phase_name) from /fsw/status, held until the next status."""
    from fwsim.analysis.plot import _phases
    log = read_log(mission_log)
    fsw, st = log.table("/fsw/status"), log.table("/uav/state")
    index, labels = _phases(log, st["t_s"])
    pairs = list(dict.fromkeys(zip(fsw["phase"].astype(int).tolist(), fsw["phase_name"].tolist())))
    assert labels == {i: f"phase {p}: {n}" for i, (p, n) in enumerate(pairs)}
    assert len(index) == len(st["t_s"]) and index[0] == 0
    last = pairs.index((int(fsw["phase"][-1]), fsw["phase_name"][-1]))
    assert index[-1] == last


def test_headings_wrap_the_same_way_and_break_at_the_wrap():
    from fwsim.analysis.plot import _with_breaks
    t = np.arange(6.0)
    rad = np.radians([350.0, 355.0, -1.0, 5.0, 10.0, -100.0])  # yaw from JSBSim or atan2: either sign
    tt, deg = _with_breaks(t, rad)
    finite = deg[np.isfinite(deg)]
    assert np.all((finite >= 0) & (finite < 360))
    assert deg[2] == pytest.approx(359.0) and np.isnan(deg[3]) and np.isnan(tt[3])  # broken, not a drop to 0
    assert np.isnan(deg[6]) and deg[7] == pytest.approx(260.0) and len(deg) == 8
    assert np.nanmax(np.abs(np.diff(deg))) < 180.0


def test_estimate_axes_clip_the_lock_transient():
    from matplotlib.figure import Figure

    from fwsim.analysis.plot import _clip_transient
    ax = Figure().subplots()
    err = np.concatenate([np.full(3, 175.0), np.random.default_rng(0).normal(0.0, 2.0, 500)])
    ax.plot(err)
    _clip_transient(ax, err)
    lo, hi = ax.get_ylim()
    assert hi < 20.0 and lo > -20.0 and any("clipped" in t.get_text() for t in ax.texts)
    ax2 = Figure().subplots()
    _clip_transient(ax2, np.linspace(-1.0, 1.0, 100))  # nothing to clip: the axis is left alone
    assert not ax2.texts


def test_the_ship_visibility_figure_states_the_runs_seen_share(mission_log, tmp_path):
    """ship_visibility's title gives the share of the frames after the lock that saw the ship, as the metric
    target_visible_fraction_after_lock scores it, and its longest stretch unseen; before any lock, of all
    frames, and says so."""
    from fwsim.analysis.metrics import compute_metrics
    assert FIGURES["ship_visibility"].draw(read_log(mission_log)).axes[0].get_title().startswith("no lock")
    scenario, text = load_scenario(SCENARIO_DIR / "paper_mission.yaml", {"duration_s": 20})
    locked = run(scenario, text, tmp_path / "locked.mcap").log_path  # the search locks at ~13 s
    m = compute_metrics(locked)
    fig = FIGURES["ship_visibility"].draw(read_log(locked))
    title = fig.axes[0].get_title()
    assert title.startswith("after the lock"), title
    assert f"seen in {100 * m['target_visible_fraction_after_lock']:.1f} % of the frames" in title, title
    assert f"longest stretch unseen {m['target_hidden_longest_s_after_lock']:.1f} s" in title, title
    assert len(fig.axes) == 3  # the share seen; the angle below the wing plane and, twinned, the azimuth


def test_an_output_folder_that_cannot_be_made_is_refused(mission_log, tmp_path, capsys):
    from fwsim.cli import main
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    assert main(["plot", str(mission_log), "--out", str(a_file)]) == 2
    assert capsys.readouterr().err.strip() == f"error: --out {a_file}: is a file, expected a folder to write in"
    assert main(["plot", str(mission_log), "--out", str(a_file / "figs")]) == 2
    assert "is a file, not a folder" in capsys.readouterr().err
    assert a_file.read_text() == "x"
