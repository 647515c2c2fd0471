"""Navigation as flown: the paper mission on the typical sensors, everything onboard on the INS's estimate; the
ideal profile untouched; the navigation faults."""
import math

import numpy as np
import pytest

from fwsim import SCENARIO_DIR
from fwsim.analysis.metrics import compute_metrics
from fwsim.log import read_log
from fwsim.scenario.model import ScenarioError, load_scenario
from fwsim.sim.loop import run

PAPER = SCENARIO_DIR / "paper_mission.yaml"
CHECKOUT = SCENARIO_DIR / "autopilot_checkout.yaml"


def test_the_paper_mission_on_the_typical_sensors_hits_and_its_navigation_is_honest(paper_typical):
    m = compute_metrics(paper_typical)
    assert m["hit"] and m["miss_distance_m"] < 3.0, m["miss_distance_m"]
    assert abs(m["impact_fpa_error_deg"]) < 3.0 and abs(m["impact_heading_error_deg"]) < 3.0
    assert m["target_visible_fraction_after_lock"] >= 0.99
    assert m["nav_roll_pitch_err_rms_deg"] <= 0.5 and m["nav_heading_err_rms_deg"] <= 1.5
    assert m["nav_pos_err_rms_m"] <= 2.5 and m["nav_nees_within_fraction"] >= 0.85
    assert m["dive_wait_orbits"] <= 1.0


def test_the_typical_log_carries_the_estimate_and_every_aid_source(paper_typical):
    log = read_log(paper_typical)
    for topic in ("/nav/estimate", "/nav/aid/gnss_pos", "/nav/aid/gnss_vel", "/nav/aid/baro", "/nav/aid/mag",
                  "/nav/aid/airspeed"):
        assert log.topics.get(topic), topic
    aid = log.table("/nav/aid/gnss_pos")
    assert aid["fused"].mean() > 0.95 and np.all(aid["fused"] != aid["rejected"])
    assert any(e.startswith("navigation: ins: initialised") for _, _, e in log.events())


def test_the_ideal_profile_has_no_navigation_filter(tmp_path):
    scenario, text = load_scenario(CHECKOUT, {"duration_s": 3})
    assert scenario.sensors.profile == "ideal"
    log = read_log(run(scenario, text, tmp_path / "ideal.mcap").log_path)
    assert not [t for t in log.topics if t.startswith("/nav")]


def test_a_navigation_fault_on_the_ideal_profile_is_a_one_line_error():
    with pytest.raises(ScenarioError) as exc:
        load_scenario(CHECKOUT, {"events": [{"kind": "gnss_jump", "t_s": 5, "duration_s": 5,
                                             "offset_enu_m": [50, 0, 0]}]})
    assert "\n" not in str(exc.value) and "events[0].kind: gnss_jump acts on the sensors' error models" in str(exc.value)
    with pytest.raises(ScenarioError) as exc:
        load_scenario(CHECKOUT, {"sensors.profile": "typical", "sensors.errors": {"gnss": {"latncy_s": 0.1}}})
    assert "sensors.errors.gnss.latncy_s: unknown key" in str(exc.value) and "\n" not in str(exc.value)


def _fly_checkout(tmp_path, name, events, duration_s=60.0):
    over = {"sensors.profile": "typical", "duration_s": duration_s, "events": events}
    scenario, text = load_scenario(CHECKOUT, over)
    log = read_log(run(scenario, text, tmp_path / f"{name}.mcap").log_path)
    nav, st = log.table("/nav/estimate"), log.table("/uav/state")
    return log, nav, st


def _pos_err(nav, st, t):
    i, j = np.searchsorted(nav["t_s"], t), np.searchsorted(st["t_s"], t)
    return float(np.linalg.norm(nav["pos_enu_m"][i] - st["pos_enu_m"][j]))


def test_a_gnss_outage_dead_reckons_and_recovers(tmp_path):
    """20 s without GNSS: the filter says it dead-reckons, its position std grows, and it is aided again after."""
    log, nav, st = _fly_checkout(tmp_path, "outage", [{"kind": "gnss_outage", "t_s": 20, "duration_s": 20}])
    texts = [e for _, _, e in log.events()]
    assert any("dead_reckoning" in e or "dead reckoning" in e for e in texts), texts
    i_end = np.searchsorted(nav["t_s"], 39.9)
    assert nav["mode"][i_end] == "dead_reckoning"
    assert nav["pos_std_m"][i_end][0] > 2.0 * nav["pos_std_m"][np.searchsorted(nav["t_s"], 19.0)][0]
    assert _pos_err(nav, st, 39.9) < 20.0  # twenty seconds on the IMU alone
    assert nav["mode"][-1] == "aided" and _pos_err(nav, st, 59.0) < 3.0


def test_a_gnss_jump_is_rejected_then_reset_to(tmp_path):
    log, nav, st = _fly_checkout(tmp_path, "jump", [{"kind": "gnss_jump", "t_s": 20, "duration_s": 30,
                                                     "offset_enu_m": [50.0, 0.0, 0.0]}])
    aid = log.table("/nav/aid/gnss_pos")
    during = (aid["t_s"] > 20.5) & (aid["t_s"] < 25.0)
    assert aid["rejected"][during].all()  # the gate turns the stepped fixes away
    assert _pos_err(nav, st, 24.0) < 3.0  # and the estimate stays on the truth
    texts = [e for _, _, e in log.events()]
    assert any("reset" in e for e in texts), texts  # rejected for long: reset to the fixes, as EKF2 does


def test_mag_interference_is_rejected(tmp_path):
    log, nav, st = _fly_checkout(tmp_path, "mag", [
        {"kind": "mag_interference", "t_s": 15, "duration_s": 10, "offset_frd_gauss": [0.3, 0.0, 0.0]}], 30.0)
    mag = log.table("/nav/aid/mag")
    during = (mag["t_s"] > 15.5) & (mag["t_s"] < 25.0)
    assert mag["rejected"][during].mean() > 0.9
    assert any("mag rejected" in e for _, _, e in log.events())


def test_an_imu_bias_step_is_taken_up(tmp_path):
    """An accelerometer bias step of 0.2 m/s^2 goes into the bias estimate; a gyro step of 0.003 rad/s about
    the yaw axis, which unaided would turn the heading 15 deg in the 90 s after it, keeps it within 5 deg."""
    log, nav, st = _fly_checkout(tmp_path, "imu", [
        {"kind": "imu_bias_step", "t_s": 30, "gyro_frd_rad_s": [0.0, 0.0, 0.003], "accel_frd_m_s2": [0.2, 0.0, 0.0]}],
        120.0)
    before, after = np.searchsorted(nav["t_s"], 29.0), np.searchsorted(nav["t_s"], 119.0)
    taken = nav["accel_bias_frd_m_s2"][after][0] - nav["accel_bias_frd_m_s2"][before][0]
    assert taken == pytest.approx(0.2, abs=0.08)
    t = nav["t_s"]
    truth = np.interp(t, st["t_s"], np.unwrap(st["euler_ned_rad"][:, 2]))
    heading_err = np.degrees((nav["euler_ned_rad"][:, 2] - truth + math.pi) % (2 * math.pi) - math.pi)
    assert np.abs(heading_err[t > 60.0]).max() < 5.0


def test_a_barometer_drift_does_not_pull_the_height_off(tmp_path):
    log, nav, st = _fly_checkout(tmp_path, "baro", [{"kind": "baro_drift", "t_s": 10, "duration_s": 30,
                                                     "rate_m_s": 0.5}])  # 15 m of drift
    i, j = np.searchsorted(nav["t_s"], 55.0), np.searchsorted(st["t_s"], 55.0)
    assert abs(nav["pos_enu_m"][i][2] - st["pos_enu_m"][j][2]) < 3.0  # GNSS holds the height


def test_on_a_sensor_profile_the_autopilot_never_reads_the_truth(tmp_path, monkeypatch):
    """The boundary, for the autopilot: every state its loops close on is the INS's view (built from the
    estimate and the pitot), never the airframe's true state."""
    from fwsim.autopilot import Autopilot
    from fwsim.world.world import World
    seen, truths, kept = [], set(), []  # (kept: the truths alive, so that no id is reused)
    actuate, step = Autopilot.actuate, World.step

    def spy_actuate(self, cmd, st):
        seen.append(st)
        return actuate(self, cmd, st)

    def spy_step(self, act, gimbal_cmd):
        truth = step(self, act, gimbal_cmd)
        truths.add(id(truth.uav))
        kept.append(truth.uav)
        return truth

    monkeypatch.setattr(Autopilot, "actuate", spy_actuate)
    monkeypatch.setattr(World, "step", spy_step)
    scenario, text = load_scenario(CHECKOUT, {"sensors.profile": "typical", "duration_s": 5})
    run(scenario, text, tmp_path / "boundary.mcap")
    assert len(seen) > 300  # flown from the INS's first estimate on (about 1.3 s of alignment first)
    assert not any(id(st) in truths for st in seen)
    truth_log = read_log(tmp_path / "boundary.mcap").table("/uav/state")
    assert not any(np.array_equal(st.pos_enu_m, p) for st in seen[::50] for p in truth_log["pos_enu_m"])


def test_the_navigation_error_is_drawn_with_its_band(paper_typical, tmp_path):
    from fwsim.analysis.plot import plot_log
    res = plot_log(paper_typical, tmp_path, only=["navigation_error"])
    assert [p.name for p in res.written] == ["navigation_error.png"] and not res.failed
    skipped = plot_log(read_log(paper_typical).path, tmp_path / "x", only=["target_estimate"])
    assert not skipped.failed


def test_the_block_breakdown_times_the_onboard_navigation(tmp_path):
    """``fwsim run --profile`` / ``fwsim bench`` on a profile with the INS: its cost has a row of its own."""
    from fwsim import SCENARIO_DIR
    from fwsim.scenario.model import load_scenario
    from fwsim.sim.loop import run
    from fwsim.sim.profiling import BlockTimer
    scenario, text = load_scenario(SCENARIO_DIR / "paper_mission.yaml", {"sensors.profile": "typical",
                                                                         "duration_s": 3.0})
    result = run(scenario, text, tmp_path / "p.mcap", profile=BlockTimer())
    rows = {b.name: b for b in result.blocks}
    assert rows["navigation (INS)"].calls > 300 and rows["navigation (INS)"].seconds > 0.0
    assert rows["sensor errors"].calls > 300
