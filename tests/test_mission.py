"""The mission in JSBSim: Phase 2 NMPC loiter, the CBF ablation (real ray-cast occlusion)."""
import numpy as np
import pytest

from fwsim import SCENARIO_DIR
from fwsim.sim.loop import run
from fwsim.analysis.metrics import compute_metrics
from fwsim.scenario.model import load_scenario


def fly(path, tmp_path, **overrides):
    scenario, text = load_scenario(path, overrides)
    result = run(scenario, text, tmp_path / f"{scenario.name}.mcap")
    return result, compute_metrics(result.log_path)


@pytest.mark.parametrize("direction", ["ccw", "cw"])
def test_cbf_ablation_wing_hides_the_ship_only_without_the_cbf(direction, tmp_path):
    """The paper's ablation: without the CBF the NMPC banks the wing over the line of
    sight (frames fully and partly hidden by the UAV's own wing, from ray casting); with
    it, none. 35 s covers the turn-in where it happens."""
    _, off = fly(SCENARIO_DIR / "ablation" / f"{direction}_nocbf.yaml", tmp_path, duration_s=35)
    _, on = fly(SCENARIO_DIR / "ablation" / f"{direction}_cbf.yaml", tmp_path, duration_s=35)
    assert off["occluded_frames_phase2"] > 0 and off["partly_occluded_frames"] > 0
    assert on["occluded_frames_phase2"] == 0 and on["partly_occluded_frames"] == 0
    assert on["tilt_positive_s"] < off["tilt_positive_s"]
    # the ship behind the wing is in the field of view but not seen: the view bar's metric counts it
    assert off["target_visible_fraction_after_lock"] < off["target_in_fov_fraction_after_lock"]
    assert off["target_hidden_longest_s_after_lock"] > 0.1
    assert on["target_visible_fraction_after_lock"] == on["target_in_fov_fraction_after_lock"]
    for m in (on, off):
        assert m["lock_time_s"] < 1.0 and m["nmpc_fallbacks"] == 0


def test_paper_mission_phase2_settles_on_R_and_H(tmp_path):
    """Phase 1 then the NMPC loiter at R = H = 500 m around the moving ship: after the
    settling time the radius and altitude errors against the true ship stay small, the
    ship stays in view, and the NMPC never falls back."""
    result, m = fly(SCENARIO_DIR / "paper_mission.yaml", tmp_path, duration_s=150,
                    **{"controllers.after_lock": "nmpc", "controllers.switch.enabled": False})
    assert result.status == "completed"
    assert m["loiter_radius_rmse_m"] < 20.0
    assert m["loiter_alt_rmse_m"] < 10.0
    assert m["target_in_fov_fraction_after_lock"] > 0.95
    assert m["nmpc_fallbacks"] == 0


def test_terminal_dive_from_the_loiter_ring_meets_the_bounds(tmp_path):
    """The paper's terminal case (theta_f = -30, psi_f = 30 deg, ship at 5 m/s) from the loiter ring,
    full flight software (UKF with the ship-shape correction, logged switch, BPNG): it hits the ship
    within 3 m of the aim point and 3 deg of both impact angles."""
    import yaml

    from fwsim.batch.cases import terminal_case
    from fwsim.scenario.model import parse_scenario
    text = yaml.safe_dump(terminal_case(-30.0, 30.0, 0.0, 5.0), sort_keys=False)
    scenario = parse_scenario(text)
    result = run(scenario, text, tmp_path / "terminal.mcap")
    m = compute_metrics(result.log_path)
    case = {k: round(m[k], 2) for k in ("miss_distance_m", "impact_fpa_error_deg", "impact_heading_error_deg",
                                        "switch_time_s")}
    assert result.reason.startswith("hit the ship"), (result.reason, case)
    assert m["hit"] == 1.0 and m["miss_distance_m"] <= 3.0, case
    assert abs(m["impact_fpa_error_deg"]) <= 3.0 and abs(m["impact_heading_error_deg"]) <= 3.0, case
    assert m["estimator_pos_err_max_after_convergence_m"] < 8.0, case


def test_a_ship_unlike_the_class_still_converges_and_hits(tmp_path):
    """The flight software assumes the paper's class (55 x 25 x 25 m, bridge aft); the ship is a ferry 30 %
    longer and higher and 30 % narrower. The size fit learns it from the boxes (longer, higher, narrower than
    the class: 1.34 / 0.76 / 1.61 at this seed, the ferry's tall superstructure read as height), the boxes
    then fit the scaled outline, and the dive hits within 6 m and 3 deg (0.54 m at this seed). Before the size
    fit the boxes disagreed with the class, the perception said so (an event) and stopped skipping boxes for
    their size; the miss was the tall ship's depth error, 3.0-5.5 m over seeds 1-8 (README, "Beyond the
    paper's ship"). With the class check and the fit off the flight missed by more (4.5 m at this seed
    before the NMPC's approach term, 1,119 boxes skipped for their size)."""
    result, m = fly(SCENARIO_DIR / "paper_mission.yaml", tmp_path, **{
        "target.type": "ferry", "target.length_m": 71.5, "target.width_m": 17.5, "target.height_m": 32.5})
    from fwsim.log import read_log
    log = read_log(result.log_path)
    events = [text for _, _, text in log.events() if text.startswith("perception:")]
    size = log.table("/fsw/ship_heading")
    case = {k: round(m[k], 2) for k in ("miss_distance_m", "impact_fpa_error_deg", "impact_heading_error_deg",
                                        "estimator_pos_rmse_after_convergence_m", "fusion_size_mismatch")}
    in_use = np.flatnonzero(size["size_in_use"])
    scale = size["size_scale"][-1]
    assert in_use.size and scale[0] > 1.1 and scale[1] < 0.9 and scale[2] > 1.1, (scale, events)
    assert m["hit"] == 1.0 and m["miss_distance_m"] <= 6.0, case
    assert abs(m["impact_fpa_error_deg"]) <= 3.0 and abs(m["impact_heading_error_deg"]) <= 3.0, case
    assert m["estimator_pos_rmse_after_convergence_m"] < 8.0 and m["fusion_size_mismatch"] < 500, case
