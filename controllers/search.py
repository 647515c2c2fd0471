"""Phase 1 acquisition: sweep the gimbal until the detector locks on the target.

The search is a raster in joint space: pan sweeps across ``pan_deg`` at each
tilt of ``tilt_deg`` in turn, back and forth, at ``rate_deg_s`` (limited by the
gimbal's own rate limit). Lock: ``lock_detections`` consecutive frames with a
detection; a frame without one restarts the count.
"""
from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict, Field

from fwsim.messages import GimbalCommand, Measurements


class AcquisitionConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)
    pan_deg: list[float] = Field(default_factory=lambda: [-90.0, 90.0], min_length=2, max_length=2,
                                 description="pan sector swept during the search")
    tilt_deg: list[float] = Field(default_factory=lambda: [-15.0, -35.0, -55.0, -75.0], min_length=1,
                                  description="tilt rows of the raster, visited in order")
    rate_deg_s: float = Field(40.0, gt=0, le=360, description="sweep rate of the joints")
    lock_detections: int = Field(5, ge=1, le=300, description="consecutive detections that make a lock")


class GimbalSearch:
    """Drives the joints through the raster; ``locked`` once the detections are steady."""

    def __init__(self, cfg: AcquisitionConfig):
        self.cfg = cfg
        self.rate = math.radians(cfg.rate_deg_s)
        pans = [math.radians(p) for p in cfg.pan_deg]
        self.waypoints = []
        for i, tilt in enumerate(cfg.tilt_deg):
            row = pans if i % 2 == 0 else pans[::-1]
            self.waypoints += [(row[0], math.radians(tilt)), (row[1], math.radians(tilt))]
        self.index = 0
        self.streak = 0
        self.locked = False
        self.lock_t_s = math.nan

    def observe(self, meas: Measurements) -> bool:
        """Count the detections; True on the tick the lock is made."""
        if self.locked or not meas.det_new:
            return False
        self.streak = self.streak + 1 if meas.det_valid else 0
        if self.streak >= self.cfg.lock_detections:
            self.locked = True
            self.lock_t_s = meas.t_s
            return True
        return False

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
