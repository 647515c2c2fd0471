"""Pan-tilt (PT) camera gimbal: kinematics, joint limits and rate limits.

Conventions (docs/design/architecture.md, "Frames and conventions", paper "PT Camera Model"):
  * body frame FRD; the mount frame M has the body axes and its origin at the
    mount offset ``r_c/p`` (``GimbalConfig.mount_offset_frd_m``, body FRD, m);
  * pan-then-tilt. Pan ``theta_p`` rotates about the mount z axis (down):
    positive pan is clockwise seen from above (body x turns toward body y).
    Tilt ``theta_t`` rotates about the panned y axis: positive tilt is UPWARD
    (the optical axis rises toward body -z). Pan = tilt = 0 looks along body +x;
  * ``R_frd_from_tilt = Rz_active(pan) @ Ry_active(tilt)`` (right-handed active
    rotations; ``Ry_active(+a)`` takes x toward -z, hence tilt up), and
    ``R_frd_from_cam = R_frd_from_tilt @ R_TILT_FROM_CAM`` with
    ``R_TILT_FROM_CAM = frames.R_FRD_FROM_CAM`` (camera z = optical axis,
    x = image right, y = image down). Written out::

        R_frd_from_cam = [[-sp, cp*st, cp*ct],
                          [ cp, sp*st, sp*ct],
                          [  0,    ct,   -st]]     (cp = cos pan, st = sin tilt, ...)

    so the optical axis in the body is ``[cp*ct, sp*ct, -st]``;
  * camera angular velocity relative to the body, in the camera frame
    (paper eq. (13)): ``[tilt_dot, cos(tilt)*pan_dot, -sin(tilt)*pan_dot]``;
    inverse (eq. (14)): ``tilt_dot = w_cx``, ``pan_dot = w_cy / cos(tilt)``,
    singular at tilt = +-90 deg (see ``joint_rates_from_camera_rates``).

The pure functions below run at 30-120 Hz inside a Python loop: they use
``math`` on scalars and build each result array once (no ``np.cross``).
Pan is a bounded joint (clamped at ``pan_limits_rad``, default [-pi, pi]), not a
continuous slip ring: a target crossing behind the aircraft makes the pan swing
the long way round, as the paper's table implies.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Annotated

from pydantic import Field, model_validator

from fwsim.interface.configbase import StrictModel

# The pan-tilt kinematics live in fwsim.interface.frames (the flight software needs them too);
# re-exported here for the harness.
from fwsim.interface.frames import (  # noqa: F401
    R_frd_from_cam,
    camera_angular_velocity,
    camera_pose_world,
    dcm_enu_from_frd,
    joint_rates_from_camera_rates,
    pan_tilt_pointing_at,
)

_PI = math.pi
_HALF_PI = 0.5 * math.pi

# --------------------------------------------------------------------------- configuration

_Offset = Annotated[float, Field(ge=-5.0, le=5.0)]
_PanAngle = Annotated[float, Field(ge=-2.0 * _PI, le=2.0 * _PI)]
_TiltAngle = Annotated[float, Field(ge=-_HALF_PI, le=_HALF_PI)]


class GimbalConfig(StrictModel):
    """Pan-tilt gimbal parameters (paper's gimbal table; docs/design/algorithms.md). All angles in rad."""


    mount_offset_frd_m: list[_Offset] = Field(
        default_factory=lambda: [0.0, 0.0, 0.10], min_length=3, max_length=3,
        description="camera rotation centre r_c/p relative to the CG, body FRD metres (default: under the fuselage)",
    )
    pan_limits_rad: list[_PanAngle] = Field(
        default_factory=lambda: [-_PI, _PI], min_length=2, max_length=2,
        description="[min, max] pan angle, rad; positive pan is clockwise seen from above",
    )
    tilt_limits_rad: list[_TiltAngle] = Field(
        default_factory=lambda: [-_HALF_PI, _HALF_PI], min_length=2, max_length=2,
        description="[min, max] tilt angle, rad, within [-pi/2, pi/2]; positive tilt looks up",
    )
    max_pan_rate_rad_s: float = Field(2.0 * _PI / 3.0, gt=0.0, le=20.0, description="pan rate limit, rad/s")
    max_tilt_rate_rad_s: float = Field(2.0 * _PI / 3.0, gt=0.0, le=20.0, description="tilt rate limit, rad/s")
    initial_pan_rad: float = Field(0.0, ge=-2.0 * _PI, le=2.0 * _PI, description="pan angle at start, rad")
    initial_tilt_rad: float = Field(-0.5, ge=-_HALF_PI, le=_HALF_PI,
                                    description="tilt angle at start, rad (negative: looking down)")

    @model_validator(mode="after")
    def _limits_consistent(self):
        for name, lim, init in (("pan", self.pan_limits_rad, self.initial_pan_rad),
                                ("tilt", self.tilt_limits_rad, self.initial_tilt_rad)):
            if not lim[0] < lim[1]:
                raise ValueError(f"{name}_limits_rad must be ordered [min, max] with min < max (got {lim})")
            if not lim[0] <= init <= lim[1]:
                raise ValueError(f"initial_{name}_rad = {init:g} is outside {name}_limits_rad {lim}")
        return self


# --------------------------------------------------------------------------- state and joint model


@dataclass(frozen=True)
class GimbalState:
    """Gimbal joint state at ``t_s``; the rates are those achieved over the last step (rad/s)."""

    t_s: float
    pan_rad: float
    tilt_rad: float
    pan_rate_rad_s: float
    tilt_rate_rad_s: float
    at_pan_limit: bool
    at_tilt_limit: bool


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else (hi if x > hi else x)


class Gimbal:
    """Rate-commanded pan-tilt joints: rate limits, explicit Euler integration, joint-limit clamping.

    ``step(t_s, pan_rate_cmd, tilt_rate_cmd)`` clips the commands to the rate
    limits (NaN means "hold", i.e. 0), integrates one ``dt_s``, clamps at the
    joint limits and returns the new state stamped ``t_s`` (pass the time at
    the END of the step). The reported rates are what actually moved,
    ``(new - old) / dt_s``: 0 while pinned against a limit. A joint leaves a
    limit as soon as the command points away from it.
    """

    def __init__(self, cfg: GimbalConfig, dt_s: float):
        dt_s = float(dt_s)
        if not (math.isfinite(dt_s) and dt_s > 0.0):
            raise ValueError(f"Gimbal: dt_s must be positive and finite, got {dt_s}")
        self.cfg = cfg
        self.dt_s = dt_s
        self._pan_lo, self._pan_hi = float(cfg.pan_limits_rad[0]), float(cfg.pan_limits_rad[1])
        self._tilt_lo, self._tilt_hi = float(cfg.tilt_limits_rad[0]), float(cfg.tilt_limits_rad[1])
        self._max_pan_rate = float(cfg.max_pan_rate_rad_s)
        self._max_tilt_rate = float(cfg.max_tilt_rate_rad_s)
        self._state: GimbalState
        self.reset(cfg.initial_pan_rad, cfg.initial_tilt_rad)

    @property
    def state(self) -> GimbalState:
        """The current state (as returned by the last ``step`` or ``reset``)."""
        return self._state

    def reset(self, pan_rad: float | None = None, tilt_rad: float | None = None, t_s: float = 0.0) -> GimbalState:
        """Put the joints at (pan, tilt) with zero rates (None: the configured initial angle).

        Raises ValueError if an angle is not finite or outside its joint limits.
        """
        pan = float(self.cfg.initial_pan_rad if pan_rad is None else pan_rad)
        tilt = float(self.cfg.initial_tilt_rad if tilt_rad is None else tilt_rad)
        if not (math.isfinite(pan) and self._pan_lo <= pan <= self._pan_hi):
            raise ValueError(f"Gimbal.reset: pan {pan} outside [{self._pan_lo}, {self._pan_hi}]")
        if not (math.isfinite(tilt) and self._tilt_lo <= tilt <= self._tilt_hi):
            raise ValueError(f"Gimbal.reset: tilt {tilt} outside [{self._tilt_lo}, {self._tilt_hi}]")
        self._state = GimbalState(
            t_s=float(t_s), pan_rad=pan, tilt_rad=tilt, pan_rate_rad_s=0.0, tilt_rate_rad_s=0.0,
            at_pan_limit=pan in (self._pan_lo, self._pan_hi),
            at_tilt_limit=tilt in (self._tilt_lo, self._tilt_hi),
        )
        return self._state

    def step(self, t_s: float, pan_rate_cmd_rad_s: float, tilt_rate_cmd_rad_s: float) -> GimbalState:
        """Advance one ``dt_s`` under the commanded joint rates (rad/s); returns the new state at ``t_s``."""
        dt = self.dt_s
        s = self._state
        pr = float(pan_rate_cmd_rad_s)
        tr = float(tilt_rate_cmd_rad_s)
        pr = 0.0 if math.isnan(pr) else _clip(pr, -self._max_pan_rate, self._max_pan_rate)
        tr = 0.0 if math.isnan(tr) else _clip(tr, -self._max_tilt_rate, self._max_tilt_rate)
        pan = _clip(s.pan_rad + pr * dt, self._pan_lo, self._pan_hi)
        tilt = _clip(s.tilt_rad + tr * dt, self._tilt_lo, self._tilt_hi)
        self._state = GimbalState(  # the fields in order (positional: a quarter of the call's cost, at 120 Hz)
            float(t_s), pan, tilt,  # t_s, pan_rad, tilt_rad
            (pan - s.pan_rad) / dt, (tilt - s.tilt_rad) / dt,  # pan_rate_rad_s, tilt_rate_rad_s
            pan == self._pan_lo or pan == self._pan_hi,  # at_pan_limit
            tilt == self._tilt_lo or tilt == self._tilt_hi,  # at_tilt_limit
        )
        return self._state
