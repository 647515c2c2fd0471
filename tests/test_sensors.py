"""Onboard sensors: seeded noise per source, sample-and-hold at each sensor's rate."""
import numpy as np

from fwsim.interface.messages import AirframeState
from fwsim.sensors.onboard import Sensors, SensorsConfig


def uav(t):
    return AirframeState(t, np.array([t, 2.0 * t, 100.0]), np.array([1.0, 2.0, 0.0]), np.zeros(3), np.zeros(3),
                         22.0, 0.05, 0.0, np.zeros(3), 0.3, np.zeros(3), 100.0)


def stream(cfg, seed, n=90, hz=30.0):
    s = Sensors(cfg, seed)
    return [s.sample(uav(k / hz)) for k in range(n)]


def test_same_seed_same_noise_and_sources_independent():
    a, b = stream(SensorsConfig(), 1), stream(SensorsConfig(), 1)
    assert all(np.array_equal(x.pos_enu_m, y.pos_enu_m) and x.airspeed_m_s == y.airspeed_m_s for x, y in zip(a, b))
    c = stream(SensorsConfig(), 2)
    assert not np.array_equal(a[0].pos_enu_m, c[0].pos_enu_m)
    # switching one source's noise off leaves every other source's draws unchanged
    d = stream(SensorsConfig(airspeed_noise_m_s=0.0), 1)
    assert all(x.airspeed_m_s == 22.0 for x in d)
    assert all(np.array_equal(x.pos_enu_m, y.pos_enu_m) and x.height_above_sea_m == y.height_above_sea_m
               for x, y in zip(a, d))


def test_noise_levels_match_the_config():
    cfg = SensorsConfig(position_noise_m=2.0, gnss_rate_hz=1000.0, airspeed_noise_m_s=0.5, air_data_rate_hz=1000.0)
    m = stream(cfg, 3, n=3000)
    err = np.array([x.pos_enu_m - uav(x.t_s).pos_enu_m for x in m])
    assert np.allclose(err.std(axis=0), 2.0, rtol=0.1) and np.allclose(err.mean(axis=0), 0.0, atol=0.15)
    assert abs(np.std([x.airspeed_m_s for x in m]) - 0.5) < 0.05


def test_gnss_holds_between_its_updates():
    """A 10 Hz GNSS read at 30 Hz: three identical readings per fix."""
    m = stream(SensorsConfig(gnss_rate_hz=10.0), 4, n=30)
    pos = np.array([x.pos_enu_m for x in m])
    fixes = np.unique(pos, axis=0)
    assert len(fixes) == 10
    assert np.array_equal(pos[0], pos[2]) and not np.array_equal(pos[2], pos[3])


def test_the_per_tick_messages_keep_the_field_order_their_positional_builders_use():
    """Sensors.sample, Airframe.state and Gimbal.step build their messages positionally (the per-tick path):
    a reordered message type must fail here, not mislabel a field in flight."""
    import dataclasses

    from fwsim.world.gimbal import GimbalState
    from fwsim.interface.messages import Measurements

    names = lambda cls: tuple(f.name for f in dataclasses.fields(cls))  # noqa: E731
    assert names(Measurements) == (
        "t_s", "pos_enu_m", "vel_enu_m_s", "euler_ned_rad", "body_rates_frd_rad_s", "airspeed_m_s",
        "height_above_sea_m", "nav_t_s", "pan_rad", "tilt_rad", "pan_rate_rad_s", "tilt_rate_rad_s",
        "cam_pos_enu_m", "det_new", "det_valid", "det_exposure_t_s", "det_u_px", "det_v_px", "det_bbox_px",
        "wind_enu_m_s", "att_std_rad")
    assert names(AirframeState) == (
        "t_s", "pos_enu_m", "vel_enu_m_s", "euler_ned_rad", "body_rates_frd_rad_s", "airspeed_m_s", "alpha_rad",
        "beta_rad", "specific_force_frd_m_s2", "throttle_norm", "surfaces_rad", "height_above_sea_m")
    assert names(GimbalState) == (
        "t_s", "pan_rad", "tilt_rad", "pan_rate_rad_s", "tilt_rate_rad_s", "at_pan_limit", "at_tilt_limit")
