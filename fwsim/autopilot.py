"""Inner loops of a PX4-like fixed-wing autopilot: commands -> surfaces.

Two command modes, both used by the paper:

(a) ``RateCommand`` (what the NMPC sends, paper eq. NMPCinput): airspeed and the
    body rates u_p, u_q with the yaw rate neglected (eq. (16)). The paper's
    model turns the aircraft through ``psi_dot = (g / V) tan(phi) cos(theta)``
    (eq. (17), the turn of a coordinated bank), so the autopilot does what
    PX4's rate controller does: it takes the Euler rates of the paper's model,

        phi_dot   = u_p + u_q sin(phi) tan(theta)
        theta_dot = u_q cos(phi)
        psi_dot   = (g / V) tan(phi) cos(theta)        (NED, clockwise)

    and tracks the body rates that realise them (exact kinematics, with the
    yaw part going to the rudder). In wings-level flight p = u_p and q = u_q.

(b) ``AccelCommand`` (what BPNG needs, docs/design/algorithms.md): airspeed and an
    acceleration perpendicular to the velocity. Bank-to-turn: the specific
    force the wing must make is f = a_perp - g_perp (gravity compensated);
    the bank about the velocity is chosen so the lift points along f
    (``bank_from_specific_force``: a positive load, past 90 deg of bank when
    f points below the velocity's horizon, or a negative load nearer
    upright, whichever is nearer the present bank; limited to
    max_bank_rad), the aircraft rolls about the velocity (stability axis) to
    it, the pitch rate makes its size (feed-forward a/V plus a loop on the
    accelerometer's normal specific force), and the rudder only coordinates
    (sideslip to zero).

Loops are named output_from_input (mavsim style). Gains come from the
aircraft's ``autopilot.yaml``: feedback gains are scaled by (V_ref / V)^2,
feed-forwards by V_ref / V.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from fwsim import AIRCRAFT_DIR
from fwsim.interface.configbase import StrictModel
from fwsim.interface.frames import cross3, dcm_enu_from_frd, wrap_pi
from fwsim.interface.messages import AccelCommand, ActuatorCommand, AirframeState, AutopilotCommand, AutopilotStatus, RateCommand
from fwsim.scenario.yamlfile import FAST_SAFE_LOADER

G_M_S2 = 9.80665
_NAN3 = np.full(3, np.nan)
_GRAVITY_ENU = np.array([0.0, 0.0, -G_M_S2])
_UP_ENU = np.array([0.0, 0.0, 1.0])
for _c in (_GRAVITY_ENU, _UP_ENU):
    _c.setflags(write=False)  # shared constants
del _c


class Gain(StrictModel):
    value: float
    unit: str
    min: float
    max: float
    description: str


class AutopilotParams(StrictModel):
    """Every gain with unit, range and description (aircraft/<name>/autopilot.yaml)."""

    ref_airspeed_m_s: Gain
    airspeed_kp: Gain
    airspeed_ki: Gain
    airspeed_climb_ff: Gain
    roll_rate_kp: Gain
    roll_rate_ki: Gain
    roll_rate_ff: Gain
    pitch_rate_kp: Gain
    pitch_rate_ki: Gain
    pitch_rate_ff: Gain
    yaw_rate_kp: Gain
    sideslip_kp: Gain
    sideslip_ki: Gain
    bank_kp: Gain
    normal_accel_kp: Gain
    normal_accel_ki: Gain
    max_bank_rad: Gain
    max_roll_rate_rad_s: Gain
    max_roll_accel_rad_s2: Gain
    max_pitch_rate_rad_s: Gain
    max_load_factor: Gain
    min_load_factor: Gain
    stall_alpha_rad: Gain
    stall_pitch_rate_gain: Gain
    underspeed_margin_m_s: Gain
    underspeed_accel_gain: Gain

    def v(self, name: str) -> float:
        return getattr(self, name).value


def load_autopilot_params(aircraft: str, aircraft_dir: Path = AIRCRAFT_DIR,
                          overrides: dict[str, float] | None = None) -> AutopilotParams:
    """Read and range-check the gains; ``overrides`` replaces values by name."""
    path = Path(aircraft_dir) / aircraft / "autopilot.yaml"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: the aircraft has no autopilot parameter file")
    raw = yaml.load(path.read_text(), Loader=FAST_SAFE_LOADER)  # noqa: S506 - a safe loader
    for name, value in (overrides or {}).items():
        if name not in raw:
            raise ValueError(f"{path.name}: unknown autopilot gain '{name}'")
        raw[name] = {**raw[name], "value": float(value)}
    params = AutopilotParams.model_validate(raw)
    for name in AutopilotParams.model_fields:
        g = getattr(params, name)
        if not (g.min <= g.value <= g.max):
            raise ValueError(f"{path.name}: {name} = {g.value} outside its range [{g.min}, {g.max}] {g.unit}")
    return params


def _clip(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


@dataclass
class _PI:
    """PI with clamping anti-windup (the integrator freezes while the output saturates)."""

    kp: float
    ki: float
    lo: float
    hi: float
    integ: float = 0.0

    def step(self, err: float, dt: float, ff: float = 0.0, scale: float = 1.0) -> float:
        out = ff + scale * (self.kp * err + self.integ)
        lo, hi = self.lo, self.hi
        if lo < out < hi or (out >= hi and err < 0) or (out <= lo and err > 0):
            self.integ += self.ki * err * dt
        return lo if out < lo else hi if out > hi else out  # _clip


def bank_from_specific_force(fl: float, fr: float, bank: float, max_bank: float,
                             max_push_m_s2: float = math.inf) -> float:
    """Bank about the velocity that points the lift along the wanted specific force (fl up, fr right).

    Two ways give the force: a positive load with the lift along it (bank
    ``atan2(fr, fl)``, beyond 90 deg when the force points below the
    horizon of the velocity), or, when the force has a downward part, a
    negative load with the wing nearer upright (bank ``atan2(-fr, -fl)``).
    Their banks lie 180 deg apart; the one nearer the present bank is
    taken, so the set-point never flips between them while the aircraft
    rolls toward one (a flip costs a half roll in the last seconds of a
    dive). The negative load is an option only while the force is within
    ``max_push_m_s2`` (what the wing may push); both banks are limited to
    ``max_bank``.
    """
    pull = _clip(math.atan2(fr, fl), -max_bank, max_bank)
    if fl >= 0.0 or math.hypot(fl, fr) > max_push_m_s2:
        return pull
    push = _clip(math.atan2(-fr, -fl), -max_bank, max_bank)
    return pull if abs(wrap_pi(pull - bank)) <= abs(wrap_pi(push - bank)) else push


def _achieved_accel_perp(st: AirframeState, R: np.ndarray, vhat: np.ndarray) -> np.ndarray:
    """The acceleration the airframe achieves perpendicular to its velocity (ENU, m/s^2): its specific force in
    the world (``R``: ENU from body) plus gravity, less the part along the velocity's unit vector ``vhat``."""
    acc = R @ st.specific_force_frd_m_s2 + _GRAVITY_ENU
    return acc - (acc @ vhat) * vhat


class Autopilot:
    """Airspeed, body-rate and acceleration loops of a small fixed wing."""

    def __init__(self, params: AutopilotParams, dt_s: float, trim_throttle: float = 0.3):
        self.p = params
        self.dt_s = dt_s
        v = params.v
        self.v_ref = v("ref_airspeed_m_s")
        self._throttle_trim = trim_throttle
        self.airspeed_from_throttle = _PI(v("airspeed_kp"), v("airspeed_ki"), 0.0, 1.0)
        self.aileron_from_roll_rate = _PI(v("roll_rate_kp"), v("roll_rate_ki"), -1.0, 1.0)
        self.elevator_from_pitch_rate = _PI(v("pitch_rate_kp"), v("pitch_rate_ki"), -1.0, 1.0)
        self.rudder_from_sideslip = _PI(v("sideslip_kp"), v("sideslip_ki"), -1.0, 1.0)
        self._normal_accel_integ = 0.0
        self._p_sp = 0.0
        #: underspeed protection engaged at the last tick (acceleration mode: the airspeed more than
        #: underspeed_margin_m_s below its set-point; the commanded path is bent down until it recovers)
        self.underspeed = False
        self._last = None  # (command, state, set-points) of the last actuate, for status()
        gains = {name: v(name) for name in type(params).model_fields}  # looked up once, not per tick
        self._gain = gains.__getitem__
        self._tick_gains = tuple(gains[n] for n in (  # the gains every tick uses, unpacked at once
            "max_roll_rate_rad_s", "max_roll_accel_rad_s2", "max_pitch_rate_rad_s", "stall_alpha_rad",
            "stall_pitch_rate_gain", "roll_rate_ff", "pitch_rate_ff", "yaw_rate_kp", "airspeed_climb_ff"))

    # ------------------------------------------------------------------ modes
    def _rates_from_rate_command(self, cmd: RateCommand, st: AirframeState, V: float):
        phi, theta, _ = st.euler_ned_rad.tolist()  # Python floats: the same values, cheaper scalar maths
        sphi, cphi = math.sin(phi), math.cos(phi)
        sth, cth = math.sin(theta), math.cos(theta)
        # Euler rates of the paper's model (eq. (16), eq. (17))
        phi_dot = cmd.roll_rate_rad_s + cmd.pitch_rate_rad_s * sphi * math.tan(theta)
        theta_dot = cmd.pitch_rate_rad_s * cphi
        psi_dot = G_M_S2 / V * math.tan(_clip(phi, -1.4, 1.4)) * cth
        # body rates that realise them
        p = phi_dot - sth * psi_dot
        q = cphi * theta_dot + sphi * cth * psi_dot
        r = -sphi * theta_dot + cphi * cth * psi_dot
        return p, q, r, math.nan, None, None

    def _rates_from_accel_command(self, cmd: AccelCommand, st: AirframeState, V: float):
        pv = self._gain
        vel = st.vel_enu_m_s
        speed = math.sqrt(float(vel.dot(vel)))  # np.linalg.norm(vel): its own sum, without its wrapper
        if speed < 1.0:
            vel, speed = dcm_enu_from_frd(st.euler_ned_rad)[:, 0] * V, V
        vhat = vel / speed
        R = dcm_enu_from_frd(st.euler_ned_rad)
        x_b, y_b, z_b = R[:, 0], R[:, 1], R[:, 2]
        # zero-bank lift direction ("up" perpendicular to the velocity) and right
        up = _UP_ENU
        l0 = up - (up @ vhat) * vhat
        n_l0 = math.sqrt(float(l0.dot(l0)))  # np.linalg.norm(l0)
        l0 = l0 / n_l0 if n_l0 > 1e-3 else -z_b
        r0 = cross3(vhat, l0)
        a = np.asarray(cmd.accel_enu_m_s2, dtype=float)
        a_perp = a - (a @ vhat) * vhat
        deficit = cmd.airspeed_m_s - st.airspeed_m_s - pv("underspeed_margin_m_s")
        self.underspeed = deficit > 0.0
        if self.underspeed:  # the path cannot be held at this airspeed: bend it down until the airspeed comes back
            a_perp = a_perp - (pv("underspeed_accel_gain") * deficit) * l0
        g_vec = _GRAVITY_ENU
        g_perp = g_vec - (g_vec @ vhat) * vhat
        f_req = a_perp - g_perp  # specific force the wing must make
        fl, fr = float(f_req @ l0), float(f_req @ r0)
        max_bank = pv("max_bank_rad")
        lift_dir = -z_b
        bank = math.atan2(float(lift_dir @ r0), float(lift_dir @ l0))
        bank_sp = bank_from_specific_force(fl, fr, bank, max_bank, -pv("min_load_factor") * G_M_S2)
        # rotation of the velocity that the commanded acceleration asks for
        omega_v = cross3(vhat, a_perp) / speed
        p_ff, q_ff, r_ff = float(omega_v @ x_b), float(omega_v @ y_b), float(omega_v @ z_b)
        # bank about the velocity (stability axis), not the body x axis: a body-x roll turns the angle of
        # attack into sideslip (p sin(alpha)), which at a dive's dynamic pressure is a large side force
        roll_v = pv("bank_kp") * wrap_pi(bank_sp - bank)
        ca, sa = math.cos(st.alpha_rad), math.sin(st.alpha_rad)
        p = p_ff + roll_v * ca
        r_ff = r_ff + roll_v * sa
        # normal specific force: wanted along the current lift direction, measured by the accelerometer
        n_sp = _clip(float(f_req @ lift_dir), pv("min_load_factor") * G_M_S2, pv("max_load_factor") * G_M_S2)
        n_meas = -float(st.specific_force_frd_m_s2[2])
        n_err = (n_sp - n_meas) / max(V, 5.0)
        self._normal_accel_integ = _clip(self._normal_accel_integ + pv("normal_accel_ki") * n_err * self.dt_s,
                                         -0.5, 0.5)
        q = q_ff + pv("normal_accel_kp") * n_err + self._normal_accel_integ
        # the achieved acceleration perpendicular to the velocity is for the log: worked out when asked for
        # (status(), _achieved_accel_perp)
        return p, q, r_ff, bank_sp, a_perp, (R, vhat)

    # ------------------------------------------------------------------ step
    def step(self, cmd: AutopilotCommand, st: AirframeState) -> tuple[ActuatorCommand, AutopilotStatus]:
        """One tick: the actuator commands and the loops' status (:meth:`actuate`, then :meth:`status`)."""
        act = self.actuate(cmd, st)
        return act, self.status()

    def actuate(self, cmd: AutopilotCommand, st: AirframeState) -> ActuatorCommand:
        """One tick of the loops: the actuator commands. The loops' status of this tick is built only when
        asked for (:meth:`status`): the loop logs it at the log rate, a quarter of the ticks or fewer."""
        (max_p, max_roll_accel, max_q, stall_alpha, stall_gain, roll_ff, pitch_ff, yaw_kp,
         climb_ff) = self._tick_gains
        dt = self.dt_s
        V = max(st.airspeed_m_s, 5.0)
        fb = (self.v_ref / V) ** 2  # feedback scaling with dynamic pressure
        ff = self.v_ref / V  # feed-forward scaling

        if isinstance(cmd, RateCommand):
            p_sp, q_sp, r_sp, bank_sp, a_sp, a_ach = self._rates_from_rate_command(cmd, st, V)
            self._normal_accel_integ = 0.0
            self.underspeed = False
        else:
            p_sp, q_sp, r_sp, bank_sp, a_sp, a_ach = self._rates_from_accel_command(cmd, st, V)
        p_sp = _clip(p_sp, -max_p, max_p)
        dp = max_roll_accel * dt  # the roll-rate set-point slews: a step asks what no aileron gives
        p_sp = self._p_sp = _clip(p_sp, self._p_sp - dp, self._p_sp + dp)
        q_sp = _clip(q_sp, -max_q, max_q)
        excess = st.alpha_rad - stall_alpha
        if excess > 0.0:  # near the stall: no pitch-up, and nose down in proportion (both modes)
            q_sp = min(q_sp, -stall_gain * excess)
        p, q, r = st.body_rates_frd_rad_s.tolist()

        # (the loops' step(err, dt, ff, scale))
        aileron = self.aileron_from_roll_rate.step(p_sp - p, dt, roll_ff * ff * p_sp, fb)
        # positive elevator pitches nose down: the loop works on -elevator
        elevator = -self.elevator_from_pitch_rate.step(q_sp - q, dt, pitch_ff * ff * q_sp, fb)
        # rudder: yaw-rate damping toward the coordinated rate, sideslip to zero
        # (positive sideslip needs a yaw to the right, i.e. negative rudder)
        yaw_demand = yaw_kp * fb * (r_sp - r)
        rudder = -self.rudder_from_sideslip.step(st.beta_rad, dt, yaw_demand, fb)

        vel = st.vel_enu_m_s
        sin_gamma = float(vel[2]) / max(math.sqrt(float(vel.dot(vel))), 1.0)  # np.linalg.norm's own sum
        throttle = self.airspeed_from_throttle.step(
            cmd.airspeed_m_s - st.airspeed_m_s, dt, self._throttle_trim + climb_ff * sin_gamma)

        self._last = (cmd, st, p_sp, q_sp, r_sp, bank_sp, a_sp, a_ach)
        return ActuatorCommand(st.t_s, aileron, elevator, rudder, throttle)

    def status(self) -> AutopilotStatus:
        """The loops' set-points and state at the last :meth:`actuate`."""
        if self._last is None:
            raise RuntimeError("Autopilot.status() asked before the first actuate()")
        cmd, st, p_sp, q_sp, r_sp, bank_sp, a_sp, a_ach = self._last
        if a_ach is not None:
            a_ach = _achieved_accel_perp(st, *a_ach)
        return AutopilotStatus(
            t_s=st.t_s, mode=cmd.mode, airspeed_sp_m_s=cmd.airspeed_m_s, airspeed_m_s=st.airspeed_m_s,
            body_rates_sp_frd_rad_s=np.array([p_sp, q_sp, r_sp]), body_rates_frd_rad_s=st.body_rates_frd_rad_s,
            bank_sp_rad=bank_sp,
            accel_sp_enu_m_s2=_NAN3 if a_sp is None else a_sp,
            accel_enu_m_s2=_NAN3 if a_ach is None else a_ach,
        )
