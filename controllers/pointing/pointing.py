"""Pointing: what the pan-tilt gimbal does in each state of the track.

* **search** (not locked yet, or no detection for ``reacquire.search_after_s``):
  the raster of ``controllers.pointing.search``;
* **track**: the pointing law (``controllers.pointing.pointing``: ``ibvs``, the paper's
  IBVS, :class:`IbvsPointing`; or a user's class, ``controllers.blocks``);
* **reacquire** (no detection for ``reacquire.after_s``): the joints driven
  toward the direction of the target estimate (predictive pointing), the
  first time with an event.

Nothing here imports the truth side of the harness (docs/design/architecture.md, "Two rules").
"""
from __future__ import annotations

import math

from controllers.config import IbvsConfig, ReacquireConfig
from controllers.messages import DetectionFix, TargetState
from controllers.navigation.camera_model import CameraMotion, PinholeCamera, depth_on_plane
from controllers.pointing.ibvs import Ibvs
from controllers.pointing.search import GimbalSearch
from fwsim.interface import topics
from fwsim.interface.frames import dcm_enu_from_frd, pan_tilt_pointing_at
from fwsim.interface.messages import GimbalCommand, Measurements

__all__ = ["Pointing", "IbvsPointing"]


class IbvsPointing:
    """The paper's IBVS as the tracking law (``controllers.pointing: ibvs``): the image feature held at the
    image centre, with the feed-forward of the UAV's and the target's motion (``controllers.pointing.ibvs``)."""

    def __init__(self, cfg: IbvsConfig, camera: PinholeCamera, mount_offset_frd_m, recorder):
        self.ibvs = Ibvs(cfg, camera.fx, camera.fy, camera.cx, camera.cy)
        self.camera = camera
        self.mount = mount_offset_frd_m
        self._record = recorder

    def step(self, nav: Measurements, cam: CameraMotion, target: TargetState) -> GimbalCommand:
        vel = target.vel_enu_m_s if target.from_estimator else None
        gimbal, status = self.ibvs.step(nav, vel, self.depth(nav, cam, target), self.mount)
        self._record.log(topics.FSW_IBVS, status)
        return gimbal

    def depth(self, nav: Measurements, cam: CameraMotion, target: TargetState) -> float | None:
        """Depth of the target along the optical axis: from the estimate, else flat-sea geometry."""
        if target.from_estimator:
            z = float((cam.R_enu_from_cam.T @ (target.pos_enu_m - cam.pos_enu_m))[2])
            return z if z > 1.0 else None
        if nav.det_valid:
            x1, x2 = self.camera.normalised(nav.det_u_px, nav.det_v_px)
            z = depth_on_plane(x1, x2, cam.R_enu_from_cam, cam.height_m, target.tracked_height_m)
            return float(z) if math.isfinite(z) else None
        return None


class Pointing:
    """Search, track or reacquire (see the module text): ``step(nav, cam, target, fix) -> GimbalCommand``."""

    def __init__(self, search: GimbalSearch, law, reacquire: ReacquireConfig, tilt_limits_rad, recorder):
        self.search = search
        self.law = law
        self.cfg = reacquire
        self.tilt_limits_rad = tuple(tilt_limits_rad)
        self._record = recorder
        self._lost_reported = False
        self._lost_t = 0.0  # when the loss was reported

    def step(self, nav: Measurements, cam: CameraMotion | None, target: TargetState,
             fix: DetectionFix) -> GimbalCommand:
        rq = self.cfg
        lost_s = nav.t_s - fix.last_detection_t_s if fix.locked else 0.0
        if not fix.locked or cam is None or lost_s > rq.search_after_s:
            gimbal = self.search.step(nav)
        elif lost_s > rq.after_s and target.known:
            gimbal = self.point_at(nav, cam, target)
        else:
            gimbal = self.law.step(nav, cam, target)
        if fix.locked and lost_s > rq.after_s and not self._lost_reported:
            self._record.event(f"target lost at t = {nav.t_s:.2f} s (no detection for {lost_s:.1f} s): "
                               "pointing at the estimate")
            self._lost_reported, self._lost_t = True, nav.t_s
        elif lost_s <= rq.after_s:
            if self._lost_reported:
                self._record.event(f"target reacquired at t = {nav.t_s:.2f} s (a detection after "
                                   f"{nav.t_s - self._lost_t:.1f} s of pointing at the estimate)")
            self._lost_reported = False
        return gimbal

    def point_at(self, nav: Measurements, cam: CameraMotion, target: TargetState) -> GimbalCommand:
        """Drive the joints toward the direction of the estimated target (atan2 gives the pan within
        [-pi, pi], so the joint swings the long way round instead of pushing a stop)."""
        R_ef = dcm_enu_from_frd(nav.euler_ned_rad)
        pan_sp, tilt_sp = pan_tilt_pointing_at(R_ef.T @ (target.pos_enu_m - cam.pos_enu_m))
        lo, hi = self.tilt_limits_rad
        tilt_sp = min(max(tilt_sp, lo), hi)
        k = self.cfg.gain_1_s
        e_pan = pan_sp - nav.pan_rad  # not wrapped: the joint cannot pass its stops
        return GimbalCommand(nav.t_s, k * e_pan, k * (tilt_sp - nav.tilt_rad))
