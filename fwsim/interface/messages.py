"""Typed messages passed between the blocks of the loop.

Every message is a frozen dataclass whose first field is ``t_s`` (simulation
time in seconds). Vectors are numpy arrays of float64; field names carry their
frame and unit (``pos_enu_m``, ``body_rates_frd_rad_s``). NaN marks a field
that is not valid in this message (PX4's convention).

Frames (docs/design/architecture.md, "Frames and conventions"):
  * world: ENU, metres, origin on the sea surface where the target starts;
  * body: FRD; Euler angles roll, pitch, yaw are the aerospace ones relative to
    NED (yaw clockwise from North).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Literal

import numpy as np

_NAN3 = lambda: np.full(3, np.nan)  # noqa: E731


@dataclass(frozen=True, slots=True)
class AirframeState:
    """Truth state of the UAV as JSBSim integrates it (harness side only)."""

    t_s: float
    pos_enu_m: np.ndarray  # (3,) position in the world frame
    vel_enu_m_s: np.ndarray  # (3,) inertial velocity in the world frame
    euler_ned_rad: np.ndarray  # (3,) roll, pitch, yaw (yaw clockwise from North)
    body_rates_frd_rad_s: np.ndarray  # (3,) p, q, r
    airspeed_m_s: float  # true airspeed
    alpha_rad: float  # angle of attack
    beta_rad: float  # sideslip angle
    specific_force_frd_m_s2: np.ndarray  # (3,) what an accelerometer at the CG reads
    throttle_norm: float  # throttle position, 0..1
    surfaces_rad: np.ndarray  # (3,) aileron, elevator, rudder positions
    height_above_sea_m: float  # altitude above the sea surface (world z)


@dataclass(frozen=True, slots=True)
class RateCommand:
    """Autopilot mode (a): what the NMPC sends (paper eq. NMPCinput).

    ``roll_rate_rad_s`` and ``pitch_rate_rad_s`` are the paper's u_p and u_q:
    body rates with the yaw rate neglected (eq. (16)). The autopilot adds
    the yaw-rate part of a coordinated turn itself (see fwsim.autopilot).
    """

    t_s: float
    airspeed_m_s: float
    roll_rate_rad_s: float
    pitch_rate_rad_s: float
    mode: Literal["rates"] = "rates"


@dataclass(frozen=True, slots=True)
class AccelCommand:
    """Autopilot mode (b): what BPNG needs.

    ``accel_enu_m_s2`` is the wanted acceleration of the UAV perpendicular to
    its velocity, in the world frame, gravity not included (the autopilot
    compensates gravity). A component along the velocity is ignored.
    """

    t_s: float
    airspeed_m_s: float
    accel_enu_m_s2: np.ndarray  # (3,)
    mode: Literal["accel"] = "accel"


AutopilotCommand = RateCommand | AccelCommand


@dataclass(frozen=True, slots=True)
class ActuatorCommand:
    """Normalised surface and throttle commands sent to JSBSim's FCS.

    Signs follow JSBSim: positive aileron rolls right, positive elevator
    pitches nose down (trailing edge down), positive rudder yaws nose left
    (trailing edge left); throttle 0..1.
    """

    t_s: float
    aileron_norm: float
    elevator_norm: float
    rudder_norm: float
    throttle_norm: float


@dataclass(frozen=True, slots=True)
class AutopilotStatus:
    """The inner loops' set-points and what they track, for the log and metrics."""

    t_s: float
    mode: str  # "rates" or "accel"
    airspeed_sp_m_s: float
    airspeed_m_s: float  # what the airspeed loop saw
    body_rates_sp_frd_rad_s: np.ndarray  # (3,) p, q, r set-points of the rate loops
    body_rates_frd_rad_s: np.ndarray  # (3,) what the rate loops saw
    bank_sp_rad: float  # accel mode: bank wanted about the velocity (NaN in rate mode)
    accel_sp_enu_m_s2: np.ndarray = field(default_factory=_NAN3)  # accel mode: commanded accel
    accel_enu_m_s2: np.ndarray = field(default_factory=_NAN3)  # accel mode: achieved accel (perp. part)


@dataclass(frozen=True, slots=True)
class AirState:
    """The air the UAV flies in (truth, harness side): logged when the scenario has turbulence or gusts."""

    t_s: float
    wind_enu_m_s: np.ndarray  # (3,) the air's velocity at the UAV: steady wind + gusts + turbulence
    turbulence_enu_m_s: np.ndarray  # (3,) the turbulence alone


@dataclass(frozen=True, slots=True)
class Measurements:
    """What the mission computer receives in one tick (flight software input).

    Everything the paper's block diagram lists (d, r_p, r_c, V_p, omega_p,
    omega_c, u, v), each from its own sensor with its own noise. Detection
    fields describe the newest detection that has arrived (``det_new`` is
    true on the tick it arrives); they are NaN / false before the first one.
    """

    t_s: float
    pos_enu_m: np.ndarray  # (3,) GNSS/INS position r_p
    vel_enu_m_s: np.ndarray  # (3,) GNSS/INS velocity V_p
    euler_ned_rad: np.ndarray  # (3,) attitude (AHRS)
    body_rates_frd_rad_s: np.ndarray  # (3,) gyroscopes omega_p
    airspeed_m_s: float  # pitot
    height_above_sea_m: float  # altimeter (h in the depth model d = h / cos alpha)
    nav_t_s: float = math.nan  # when the position and velocity fix was taken (they are held between fixes)
    pan_rad: float = math.nan  # gimbal encoders
    tilt_rad: float = math.nan
    pan_rate_rad_s: float = math.nan
    tilt_rate_rad_s: float = math.nan
    cam_pos_enu_m: np.ndarray = field(default_factory=_NAN3)  # (3,) camera position r_c
    det_new: bool = False  # a detection arrived this tick
    det_valid: bool = False  # the newest detection found the target
    det_exposure_t_s: float = math.nan  # when that frame was exposed
    det_u_px: float = math.nan  # bounding-box centre (YOLO feature Q_t(u, v))
    det_v_px: float = math.nan
    det_bbox_px: np.ndarray = field(default_factory=lambda: np.full(4, np.nan))  # u_min, v_min, u_max, v_max
    wind_enu_m_s: np.ndarray = field(default_factory=_NAN3)  # (3,) the navigation's wind estimate (not a sensor's)
    att_std_rad: np.ndarray = field(default_factory=_NAN3)  # (3,) the navigation's attitude std (NaN: not reported)


@dataclass(frozen=True, slots=True)
class GimbalCommand:
    """Pan and tilt rates the flight software asks of the gimbal (NaN: hold)."""

    t_s: float
    pan_rate_rad_s: float
    tilt_rate_rad_s: float


@dataclass(frozen=True, slots=True)
class FlightSoftwareStatus:
    """The flight software's internal state for the log (never fed back)."""

    t_s: float
    phase: int  # 1 acquisition/initial path, 2 loiter, 3 terminal; 0 scripted
    phase_name: str
    command_mode: str  # "rates" or "accel"
    course_sp_rad: float = math.nan  # initial path: course set-point (ENU, counter-clockwise from East)
    bank_sp_rad: float = math.nan  # initial path: bank set-point
    altitude_sp_m: float = math.nan  # initial path: altitude set-point
    cross_track_m: float = math.nan  # initial path: signed distance right of the path
    locked: bool = False  # the target is locked (acquisition done)
    lock_t_s: float = math.nan  # when it was locked
    radial_err_m: float = math.nan  # Phase 2 and 3: distance to the estimated target minus the loiter radius
    loiter_radius_m: float = math.nan  # Phase 2 and 3: the loiter ring's radius R round the target
    loiter_altitude_m: float = math.nan  # Phase 2 and 3: the loiter ring's altitude H


# --------------------------------------------------------------------------- navigation: raw sensors in, estimate out
# What the onboard sensors deliver to the navigation filter (fwsim.sensors.errors makes them from the truth,
# controllers.navigation.ins fuses them), and what the filter gives everything onboard.


@dataclass(frozen=True, slots=True)
class ImuSample:
    """One IMU interval, as PX4's EKF2 takes it: the integrated rate and specific force over ``dt_s``
    (body FRD), ending at ``t_s``."""

    t_s: float
    dt_s: float
    delta_angle_frd_rad: np.ndarray  # (3,) integral of the body rates over the interval
    delta_velocity_frd_m_s: np.ndarray  # (3,) integral of the specific force over the interval


@dataclass(frozen=True, slots=True)
class GnssFix:
    """A GNSS fix as it arrives (``t_s``), valid at ``time_of_fix_s`` (``t_s`` less the receiver's latency),
    with the receiver's own accuracy figures (1 sigma)."""

    t_s: float
    time_of_fix_s: float
    pos_enu_m: np.ndarray  # (3,)
    vel_enu_m_s: np.ndarray  # (3,)
    h_acc_m: float  # horizontal position accuracy
    v_acc_m: float  # vertical position accuracy
    s_acc_m_s: float  # speed accuracy, per axis


@dataclass(frozen=True, slots=True)
class BaroSample:
    """Barometric height above the sea surface (m), as the altimeter reads it."""

    t_s: float
    height_m: float


@dataclass(frozen=True, slots=True)
class MagSample:
    """The magnetometer's field in the body frame (gauss)."""

    t_s: float
    field_frd_gauss: np.ndarray  # (3,)


@dataclass(frozen=True, slots=True)
class AirspeedSample:
    """The pitot's true airspeed (m/s)."""

    t_s: float
    airspeed_m_s: float


@dataclass(frozen=True, slots=True)
class NavEstimate:
    """The navigation filter's estimate: the only "self" the autopilot and the flight software know.
    Standard deviations are 1 sigma per axis; attitude std is (roll, pitch, yaw)."""

    t_s: float
    pos_enu_m: np.ndarray  # (3,)
    vel_enu_m_s: np.ndarray  # (3,)
    euler_ned_rad: np.ndarray  # (3,) roll, pitch, yaw (yaw clockwise from North)
    body_rates_frd_rad_s: np.ndarray  # (3,) the gyro less its estimated bias
    specific_force_frd_m_s2: np.ndarray  # (3,) the accelerometer less its estimated bias
    gyro_bias_frd_rad_s: np.ndarray  # (3,)
    accel_bias_frd_m_s2: np.ndarray  # (3,)
    wind_enu_m_s: np.ndarray  # (3,) NaN when the filter has no wind state
    pos_std_m: np.ndarray  # (3,)
    vel_std_m_s: np.ndarray  # (3,)
    att_std_rad: np.ndarray  # (3,) roll, pitch, yaw
    mode: str  # "initialising" | "aided" | "dead_reckoning"
    gnss_age_s: float  # time since the last GNSS fix was fused (inf before the first)


@dataclass(frozen=True, slots=True)
class AidSourceStatus:
    """One aid source's latest fusion attempt, in PX4's ``estimator_aid_src_*`` form (per component of the
    observation; a scalar source has one)."""

    t_s: float
    source: str  # "gnss_pos" | "gnss_vel" | "baro" | "mag" | "airspeed"
    time_of_observation_s: float
    observation: np.ndarray
    observation_variance: np.ndarray
    innovation: np.ndarray
    innovation_variance: np.ndarray
    test_ratio: np.ndarray  # innovation^2 / (gate^2 * innovation variance): above 1 is rejected
    fused: bool
    rejected: bool


def as_dict(msg) -> dict:
    """A message as a plain dict (arrays become lists), for JSON logs."""
    out = {}
    for f in fields(msg):
        v = getattr(msg, f.name)
        if isinstance(v, np.ndarray):
            v = [float(x) for x in v]
        elif isinstance(v, (np.floating, np.integer)):
            v = v.item()
        out[f.name] = v
    return out
