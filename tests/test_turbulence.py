"""world.turbulence: JSBSim's own MIL-F-8785C turbulence, seeded from the scenario, in the log."""
from __future__ import annotations

import numpy as np
import pytest

from fwsim import SCENARIO_DIR

from fwsim.interface import topics
from fwsim.log import read_log
from fwsim.sim.loop import run
from fwsim.scenario.model import ScenarioError, load_scenario

CHECKOUT = SCENARIO_DIR / "autopilot_checkout.yaml"
FT = 0.3048
# MIL-F-8785C Fig. 7, the 1e-3 probability-of-exceedance curve ("moderate"): sigma in ft/s at 500 and 1750 ft
_MODERATE_CURVE = ((500.0, 8.6), (1750.0, 9.6))
_W20_MODERATE_FPS = 30.0 / 0.592484  # 30 kn


def fly(path, tmp_path, name, **overrides):
    scenario, text = load_scenario(path, overrides)
    return run(scenario, text, tmp_path / name)


def handbook_sigmas(h_ft: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sigma_u = sigma_v, sigma_w) in m/s at each height, MIL-F-8785C: low altitude below 1000 ft, the
    exceedance curve above 2000 ft, linear between."""
    h = np.maximum(h_ft, 10.0)
    sw_low = 0.1 * _W20_MODERATE_FPS
    su_low = sw_low / (0.177 + 0.000823 * np.minimum(h, 1000.0)) ** 0.4
    (h0, s0), (h1, s1) = _MODERATE_CURVE
    curve = s0 + (np.clip(h, h0, h1) - h0) / (h1 - h0) * (s1 - s0)
    blend = np.clip((h - 1000.0) / 1000.0, 0.0, 1.0)
    sw = np.where(h <= 1000.0, sw_low, sw_low + blend * (curve - sw_low))
    su = np.where(h <= 1000.0, su_low, sw)
    return su * FT, sw * FT


def _air(tmp_path, name, seed, duration=120.0, **extra):
    r = fly(CHECKOUT, tmp_path, name, duration_s=duration, seed=seed,
            **{"world.turbulence": {"severity": "moderate"}, "initial.pos_enu_m": [0.0, 0.0, 250.0], **extra})
    log = read_log(r.log_path)
    return log.table(topics.WORLD_AIR), log.table(topics.UAV_STATE)


def test_turbulence_has_the_handbook_intensity(tmp_path):
    air, st = _air(tmp_path, "t.mcap", seed=1)
    assert len(air["t_s"]) > 3000
    h_ft = np.interp(air["t_s"], st["t_s"], st["pos_enu_m"][:, 2]) / FT
    su, sw = handbook_sigmas(h_ft)
    turb = air["turbulence_enu_m_s"]
    horizontal = np.sqrt(np.mean(turb[:, 0] ** 2 + turb[:, 1] ** 2) / 2.0)
    vertical = np.sqrt(np.mean(turb[:, 2] ** 2))
    expect_h, expect_w = np.sqrt(np.mean(su ** 2)), np.sqrt(np.mean(sw ** 2))
    assert 0.5 < horizontal / expect_h < 2.0 and 0.5 < vertical / expect_w < 2.0, (horizontal, expect_h,
                                                                                   vertical, expect_w)
    # the air's velocity is the steady wind (none here) plus the turbulence
    np.testing.assert_allclose(air["wind_enu_m_s"], turb, atol=1e-9)


def test_same_seed_same_turbulence_other_seed_other(tmp_path):
    a, _ = _air(tmp_path, "a.mcap", seed=4, duration=10.0)
    b, _ = _air(tmp_path, "b.mcap", seed=4, duration=10.0)
    c, _ = _air(tmp_path, "c.mcap", seed=5, duration=10.0)
    assert np.array_equal(a["turbulence_enu_m_s"], b["turbulence_enu_m_s"])
    assert not np.allclose(a["turbulence_enu_m_s"], c["turbulence_enu_m_s"])
    assert np.std(a["turbulence_enu_m_s"]) > 0.1


def test_still_air_has_no_air_topic(tmp_path):
    r = fly(CHECKOUT, tmp_path, "still.mcap", duration_s=2.0)
    assert topics.WORLD_AIR not in read_log(r.log_path).topics


@pytest.mark.parametrize("value, words", [
    ({}, "give a severity"),
    ({"severity": "violent"}, "severity"),
    ({"wind_at_20ft_m_s": -1}, "wind_at_20ft_m_s"),
    ({"severity": "light", "model": "von_karman"}, "model"),
])
def test_bad_turbulence_settings(value, words):
    with pytest.raises(ScenarioError, match=words):
        load_scenario(CHECKOUT, {"world.turbulence": value})


def test_severity_and_wind_at_20ft_pick_jsbsim_settings():
    s, _ = load_scenario(CHECKOUT, {"world.turbulence": {"severity": "severe"}})
    assert s.world.turbulence.jsbsim_settings() == (3, 6, pytest.approx(23.15))
    s, _ = load_scenario(CHECKOUT, {"world.turbulence": {"wind_at_20ft_m_s": 10.0, "model": "tustin"}})
    assert s.world.turbulence.jsbsim_settings() == (4, 4, 10.0)  # 10 m/s = 19 kn: the moderate curve
