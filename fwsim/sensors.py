"""Onboard sensors: what the mission computer can know.

For now the navigation sensors are ideal (the truth state, sampled at the
flight software's rate); noise models, the gimbal encoders and the camera
detection arrive with the seen world (README status). Every noise source will
take its own generator seeded from the scenario.
"""
from __future__ import annotations

from fwsim.messages import AirframeState, Measurements


class Sensors:
    """Samples the truth into a ``Measurements`` message."""

    def __init__(self, seed: int = 0):
        self.seed = seed

    def sample(self, truth: AirframeState) -> Measurements:
        return Measurements(
            t_s=truth.t_s,
            pos_enu_m=truth.pos_enu_m.copy(),
            vel_enu_m_s=truth.vel_enu_m_s.copy(),
            euler_ned_rad=truth.euler_ned_rad.copy(),
            body_rates_frd_rad_s=truth.body_rates_frd_rad_s.copy(),
            airspeed_m_s=truth.airspeed_m_s,
            height_above_sea_m=truth.height_above_sea_m,
        )
