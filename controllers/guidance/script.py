"""Scripted commands: a timed list of autopilot commands (for checkouts and tests).

Accelerations are given perpendicular to the measured velocity, as ``right``
and ``up`` components; they become a world-frame ``AccelCommand`` each step.
"""
from __future__ import annotations

import bisect
import math

import numpy as np

from fwsim.interface.frames import cross3
from fwsim.interface.messages import (
    AccelCommand,
    AutopilotCommand,
    FlightSoftwareStatus,
    GimbalCommand,
    Measurements,
    RateCommand,
)

GIMBAL_ANGLE_GAIN_1_S = 3.0  # scripted gimbal angles: joint rate per rad of encoder error


def perpendicular_axes(vel_enu_m_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit 'up' and 'right' vectors perpendicular to a velocity (world ENU)."""
    v = np.asarray(vel_enu_m_s, dtype=float)
    vhat = v / max(float(np.linalg.norm(v)), 1e-6)
    up = np.array([0.0, 0.0, 1.0]) - vhat[2] * vhat
    n = float(np.linalg.norm(up))
    up = up / n if n > 1e-6 else np.array([1.0, 0.0, 0.0])
    return up, cross3(vhat, up)


class ScriptedCommands:
    """Holds each scripted command from its ``t_s`` until the next one."""

    def __init__(self, steps):
        self.steps = list(steps)
        self._times = [s.t_s for s in self.steps]

    def gimbal_setpoint_rad(self, t_s: float) -> tuple[float, float] | None:
        """Pan and tilt of the latest step up to ``t_s`` that set ``gimbal_deg`` (None: none yet)."""
        sp = None
        for s in self.steps:
            if s.t_s > t_s + 1e-9:
                break
            if s.gimbal_deg is not None:
                sp = (math.radians(s.gimbal_deg[0]), math.radians(s.gimbal_deg[1]))
        return sp

    def step(self, meas: Measurements) -> AutopilotCommand:
        i = max(bisect.bisect_right(self._times, meas.t_s + 1e-9) - 1, 0)
        s = self.steps[i]
        if s.rates is not None:
            return RateCommand(meas.t_s, s.rates.airspeed_m_s, math.radians(s.rates.roll_rate_deg_s),
                               math.radians(s.rates.pitch_rate_deg_s))
        up, right = perpendicular_axes(meas.vel_enu_m_s)
        return AccelCommand(meas.t_s, s.accel.airspeed_m_s, s.accel.right_m_s2 * right + s.accel.up_m_s2 * up)

    def gimbal(self, meas: Measurements) -> GimbalCommand:
        """Joint rates toward the scripted gimbal angles (hold: NaN, before any or without encoders)."""
        sp = self.gimbal_setpoint_rad(meas.t_s)
        if sp is None or math.isnan(meas.pan_rad):
            return GimbalCommand(meas.t_s, math.nan, math.nan)
        return GimbalCommand(meas.t_s, GIMBAL_ANGLE_GAIN_1_S * (sp[0] - meas.pan_rad),
                             GIMBAL_ANGLE_GAIN_1_S * (sp[1] - meas.tilt_rad))

    def status(self, meas: Measurements, cmd: AutopilotCommand) -> FlightSoftwareStatus:
        return FlightSoftwareStatus(meas.t_s, 0, "script", cmd.mode)
