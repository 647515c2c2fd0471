"""A terminal guidance law written from scratch: pure pursuit (the velocity turned toward the target).

Fly it in the paper mission (from this folder, so that ``my_guidance`` imports)::

    fwsim run ../../scenarios/paper_mission.yaml --set controllers.terminal=my_guidance:PurePursuit

It ignores the mission's impact angles (``controllers.bpng.impact_flight_path_deg`` / ``impact_heading_deg``):
pure pursuit arrives along its line of sight, usually in a tail chase. docs/guide/plugins.md explains the
messages.
"""
from __future__ import annotations

import numpy as np

from controllers.messages import Guidance
from fwsim.interface.messages import AccelCommand


class PurePursuit:
    """Turn the UAV's velocity toward the estimated target: an acceleration perpendicular to the velocity,
    ``gain_1_s * speed * sin(angle off)`` in the plane of the velocity and the line of sight."""

    def __init__(self, options, context):                        # no Config model: options is a dict
        self.gain_1_s = float(options.get("gain_1_s", 1.5))
        self.max_accel_m_s2 = float(options.get("max_accel_m_s2", 15.0))
        self.airspeed_m_s = context.config.bpng.airspeed_m_s      # the mission's dive airspeed

    def step(self, nav, target) -> Guidance:
        los = np.asarray(target.pos_enu_m, float) - nav.pos_enu_m
        vel = np.asarray(nav.vel_enu_m_s, float)
        speed = float(np.linalg.norm(vel))
        if not (np.all(np.isfinite(los)) and speed > 1.0):      # no estimate (or no speed): fly straight
            return Guidance(AccelCommand(nav.t_s, self.airspeed_m_s, np.zeros(3)), "terminal:pursuit")
        v_hat, l_hat = vel / speed, los / np.linalg.norm(los)
        turn = l_hat - float(l_hat @ v_hat) * v_hat               # toward the line of sight, across the velocity
        accel = self.gain_1_s * speed * turn
        size = float(np.linalg.norm(accel))
        if size > self.max_accel_m_s2:
            accel *= self.max_accel_m_s2 / size
        return Guidance(AccelCommand(nav.t_s, self.airspeed_m_s, accel), "terminal:pursuit")
