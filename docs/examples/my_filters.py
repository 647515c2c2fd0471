"""A target estimator written from scratch: an alpha-beta filter on the sea plane.

Fly it in the paper mission (from this folder, so that ``my_filters`` imports)::

    fwsim run ../../scenarios/paper_mission.yaml --set controllers.estimator=my_filters:AlphaBeta

or name it in a scenario::

    controllers:
      estimator:
        use: my_filters:AlphaBeta
        options: {alpha: 0.3, beta: 0.02}

Each detection's ray (the box centre, already corrected for the ship's shape) is met with the plane of the
tracked point; the filter blends that point into a constant-velocity position with two fixed gains.
docs/guide/plugins.md explains each method and when the flight software calls it.
"""
from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from controllers.navigation.camera_model import depth_on_plane
from controllers.messages import EstimatorStatus, FusionReason, FusionResult, TargetEstimate

NAN2 = np.full(2, np.nan)


class AlphaBeta:
    """The ship's position and velocity (world ENU) from the detections' rays, with fixed gains."""

    class Config(BaseModel):  # the scenario's options, validated before anything flies
        model_config = ConfigDict(extra="forbid")
        alpha: float = Field(0.3, gt=0, le=1, description="share of a position residual taken into the position")
        beta: float = Field(0.02, gt=0, le=1, description="share of a residual taken into the velocity (per update)")
        gate_m: float = Field(60.0, gt=0, description="a point farther than this from the prediction is not fused")
        pos_std_m: float = Field(8.0, gt=0, description="the position's reported standard deviation")

    def __init__(self, options: Config, context):
        self.cfg = options
        self.camera = context.camera                              # pinhole intrinsics: fx, fy, cx, cy
        self.label = "alpha-beta filter"                          # its name in /events (optional)
        # the Protocol's data members may be plain attributes set here
        self.initialised = False
        self.tracked_height_m = context.config.ukf.target_plane_height_m   # the point it tracks, above the waterline
        self.pos = np.full(3, np.nan)
        self.vel = np.zeros(3)
        self.t_s = math.nan
        self.last_fused_t_s = math.nan
        self.innovation_px = NAN2
        self.innovation_t_s = math.nan
        self.counts = {"updates": 0, "gated": 0, "rejected": 0, "initialisations": 0}

    # -- geometry
    def _point(self, fix, camera):
        """Where the detection's ray meets the plane of the tracked point (None when it does not)."""
        x1, x2 = (float(a) for a in self.camera.normalised(fix.u_px, fix.v_px))
        depth = depth_on_plane(x1, x2, camera.R_enu_from_cam, camera.height_m, self.tracked_height_m)
        if not math.isfinite(depth):
            return None
        point = camera.pos_enu_m + depth * (camera.R_enu_from_cam @ np.array([x1, x2, 1.0]))
        point[2] = self.tracked_height_m
        return point

    def _pixel(self, point, camera):
        """The pixel where ``point`` is seen (NaN behind the camera)."""
        p = camera.R_enu_from_cam.T @ (point - camera.pos_enu_m)
        if p[2] <= 0.0:
            return NAN2
        return np.array([self.camera.fx * p[0] / p[2] + self.camera.cx, self.camera.fy * p[1] / p[2] + self.camera.cy])

    # -- the Protocol (controllers.blocks.TargetEstimator)
    def initialise(self, fix, camera) -> None:
        point = self._point(fix, camera)
        if point is None:
            raise ValueError("the detection's ray does not meet the sea")   # the estimation tries the next one
        self.pos, self.vel = point, np.zeros(3)
        self.t_s = self.last_fused_t_s = float(fix.t_s)
        self.initialised = True
        self.counts["initialisations"] += 1

    def predict(self, t_s: float, camera) -> None:
        dt = float(t_s) - self.t_s
        if dt > 0.0:
            self.pos = self.pos + self.vel * dt
            self.t_s = float(t_s)

    def update(self, fix, camera) -> FusionResult:
        self.predict(fix.t_s, camera)
        point = self._point(fix, camera)
        if point is None:
            self.counts["rejected"] += 1
            return FusionResult(False, FusionReason.REJECTED)
        residual = point - self.pos
        ratio = float(np.linalg.norm(residual[:2])) / self.cfg.gate_m
        innovation = np.array([fix.u_px, fix.v_px]) - self._pixel(self.pos, camera)
        if ratio > 1.0:
            self.counts["gated"] += 1
            return FusionResult(False, FusionReason.INNOVATION_GATE, NAN2, ratio)
        dt = max(self.t_s - self.last_fused_t_s, 1e-3)
        self.pos = self.pos + self.cfg.alpha * residual
        self.vel = self.vel + (self.cfg.beta / dt) * residual
        self.vel[2] = 0.0                                          # a ship stays on the sea
        self.last_fused_t_s = self.t_s
        self.innovation_px, self.innovation_t_s = innovation, self.t_s
        self.counts["updates"] += 1
        return FusionResult(True, FusionReason.USED, innovation, ratio)

    def estimate(self) -> TargetEstimate:
        n = self.counts["updates"]
        vel_std = max(0.5, 5.0 / math.sqrt(n + 1.0))               # a crude confidence that grows with the updates
        innovation = self.innovation_px if self.innovation_t_s == self.t_s else NAN2
        return TargetEstimate(self.t_s, self.pos.copy(), self.vel.copy(), np.full(3, self.cfg.pos_std_m),
                              np.full(3, vel_std), math.nan, math.nan, innovation)

    def status(self, t_s: float) -> EstimatorStatus:
        c = self.counts
        return EstimatorStatus(t_s, c["updates"], c["gated"], c["rejected"], 0, 0, c["initialisations"])
