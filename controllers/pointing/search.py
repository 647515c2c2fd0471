"""Phase 1 acquisition: sweep the gimbal until the detector locks on the target.

The search is a raster in joint space: pan sweeps across ``pan_deg`` at each
tilt of ``tilt_deg`` in turn, back and forth, at ``rate_deg_s`` (limited by the
gimbal's own rate limit). The lock (``lock_detections`` consecutive frames
with a detection) is the perception's (``controllers.perception.perception.Lock``).
"""
from __future__ import annotations

import math

from controllers.config import AcquisitionConfig
from fwsim.interface.messages import GimbalCommand, Measurements


class GimbalSearch:
    """Drives the joints through the raster."""

    def __init__(self, cfg: AcquisitionConfig):
        self.cfg = cfg
        self.rate = math.radians(cfg.rate_deg_s)
        pans = [math.radians(p) for p in cfg.pan_deg]
        self.waypoints = []
        for i, tilt in enumerate(cfg.tilt_deg):
            row = pans if i % 2 == 0 else pans[::-1]
            self.waypoints += [(row[0], math.radians(tilt)), (row[1], math.radians(tilt))]
        self.index = 0

    def step(self, meas: Measurements) -> GimbalCommand:
        if math.isnan(meas.pan_rad):
            return GimbalCommand(meas.t_s, math.nan, math.nan)
        pan_sp, tilt_sp = self.waypoints[self.index]
        e_pan, e_tilt = pan_sp - meas.pan_rad, tilt_sp - meas.tilt_rad
        if abs(e_pan) < math.radians(2.0) and abs(e_tilt) < math.radians(2.0):
            self.index = (self.index + 1) % len(self.waypoints)
            pan_sp, tilt_sp = self.waypoints[self.index]
            e_pan, e_tilt = pan_sp - meas.pan_rad, tilt_sp - meas.tilt_rad
        # move at the sweep rate, slowing down over the last few degrees
        k = self.rate / math.radians(5.0)
        pan_rate = max(-self.rate, min(self.rate, k * e_pan))
        tilt_rate = max(-self.rate, min(self.rate, k * e_tilt))
        return GimbalCommand(meas.t_s, pan_rate, tilt_rate)
