"""The flight software: ``Measurements`` in, autopilot command and status out.

Phases (paper, "Simulation"): 1 initial path flight and target acquisition,
2 NMPC loiter, 3 BPNG terminal guidance. Today only Phase 1's initial path
exists (README status); the target search, lock and the later phases arrive
with their issues. A scripted command list can stand in for the mission.

Nothing here imports the truth side of the harness (DESIGN.md section 1).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from controllers.path import PathFollower
from controllers.script import ScriptedCommands
from fwsim.messages import AutopilotCommand, FlightSoftwareStatus, GimbalCommand, Measurements

GIMBAL_ANGLE_GAIN_1_S = 3.0  # scripted gimbal angles: joint rate per rad of encoder error


@dataclass(frozen=True, slots=True)
class FlightSoftwareOutput:
    command: AutopilotCommand
    gimbal: GimbalCommand
    status: FlightSoftwareStatus


class FlightSoftware:
    """One object at the boundary: measurements in, commands out."""

    def __init__(self, controllers_cfg, initial_cfg):
        self.kind = controllers_cfg.kind
        if self.kind == "script":
            self._script = ScriptedCommands(controllers_cfg.script)
        else:
            path = controllers_cfg.initial_path
            self._path = PathFollower(path.airspeed_m_s, initial_cfg.pos_enu_m,
                                      math.radians(initial_cfg.heading_deg), path.waypoints_enu_m,
                                      path.max_bank_deg)

    def step(self, meas: Measurements) -> FlightSoftwareOutput:
        if self.kind == "script":
            cmd = self._script.step(meas)
            return FlightSoftwareOutput(cmd, self._scripted_gimbal(meas),
                                        FlightSoftwareStatus(meas.t_s, 0, "script", cmd.mode))
        cmd, status = self._path.step(meas)
        # The target search and IBVS pointing arrive with Phase 1's acquisition; until then hold.
        return FlightSoftwareOutput(cmd, GimbalCommand(meas.t_s, math.nan, math.nan), status)

    def _scripted_gimbal(self, meas: Measurements) -> GimbalCommand:
        sp = self._script.gimbal_setpoint_rad(meas.t_s)
        if sp is None or math.isnan(meas.pan_rad):
            return GimbalCommand(meas.t_s, math.nan, math.nan)
        return GimbalCommand(meas.t_s, GIMBAL_ANGLE_GAIN_1_S * (sp[0] - meas.pan_rad),
                             GIMBAL_ANGLE_GAIN_1_S * (sp[1] - meas.tilt_rad))
