"""Synthetic truth and sensors for the INS tests (tests/test_ins.py): a scripted fixed-wing flight with exact
kinematics, simple sensor error models with known noise, biases and latency, and a runner that feeds
``controllers.navigation.ins.Ins`` in time order and records its errors against the truth.

The flight is kinematic in the air: airspeed ``V``, air-relative course ``chi`` (clockwise from North), flight
path ``gamma`` and bank ``mu`` about the air velocity, with ``chi' = g tan(mu) / V`` and smooth (cosine) ramps
of ``mu`` and ``gamma`` between scripted segments. The body is the wind frame pitched up by a constant angle
of attack, so the sideslip is exactly zero; the ground velocity is the air's plus a constant wind. Everything
is evaluated on a fine grid (10 points per IMU interval) and integrated there (trapezoids), so the IMU's
delta angles and velocities are the integrals of the exact body rates and specific force.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from controllers.navigation.ins import GRAVITY_M_S2, Ins
from controllers.navigation.ins_math import dcm_from_quat, euler_ned_from_dcm_enu_from_frd
from fwsim.interface.frames import R_ENU_FROM_NED, rot_y, wrap_pi
from fwsim.interface.messages import AirspeedSample, BaroSample, GnssFix, ImuSample, MagSample

IMU_HZ = 120.0
FINE = 10  # fine-grid points per IMU interval


@dataclass(frozen=True)
class Segment:
    """Hold bank and flight-path angle (deg) for ``duration_s``, reached by a cosine ramp of ``ramp_s``."""

    duration_s: float
    bank_deg: float = 0.0
    gamma_deg: float = 0.0
    ramp_s: float = 4.0


@dataclass
class Truth:
    """The truth at the IMU sample times (index k at t = k / IMU_HZ), with the exact IMU increments."""

    t: np.ndarray  # (n,)
    pos: np.ndarray  # (n, 3) ENU
    vel: np.ndarray  # (n, 3)
    R: np.ndarray  # (n, 3, 3) R_enu_from_frd
    euler: np.ndarray  # (n, 3) NED roll, pitch, yaw
    dang: np.ndarray  # (n, 3) integral of the body rates over (t[k-1], t[k]] (row 0 unused)
    dvel: np.ndarray  # (n, 3) integral of the specific force
    airspeed: float
    wind: np.ndarray  # (3,)
    fine_t: np.ndarray = field(repr=False, default=None)
    fine_pos: np.ndarray = field(repr=False, default=None)
    fine_vel: np.ndarray = field(repr=False, default=None)


def _profile(t: np.ndarray, segments, attr: str) -> tuple[np.ndarray, np.ndarray]:
    """A segment attribute (deg) as a smooth function of time (rad) and its derivative (rad/s)."""
    val, der = np.zeros_like(t), np.zeros_like(t)
    prev, start = 0.0, 0.0
    for seg in segments:
        target = math.radians(getattr(seg, attr))
        x = np.clip((t - start) / seg.ramp_s, 0.0, 1.0)
        val += (target - prev) * (0.5 - 0.5 * np.cos(math.pi * x))
        inside = (t > start) & (t < start + seg.ramp_s)
        der += np.where(inside, (target - prev) * 0.5 * math.pi / seg.ramp_s * np.sin(math.pi * x), 0.0)
        prev, start = target, start + seg.duration_s
    return val, der


def _cumtrapz(y: np.ndarray, dt: float) -> np.ndarray:
    out = np.zeros_like(y)
    out[1:] = np.cumsum(0.5 * dt * (y[1:] + y[:-1]), axis=0)
    return out


def _dcm_ned_from_euler(phi, theta, psi) -> np.ndarray:
    """(n, 3, 3) R_ned_from_frd from 3-2-1 Euler angle arrays."""
    cf, sf, ct, st, cp, sp = np.cos(phi), np.sin(phi), np.cos(theta), np.sin(theta), np.cos(psi), np.sin(psi)
    return np.stack([np.stack([ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp], -1),
                     np.stack([ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp], -1),
                     np.stack([-st, sf * ct, cf * ct], -1)], -2)


def fly(segments, airspeed_m_s: float = 20.0, wind_en_m_s=(3.0, -2.0), heading0_deg: float = 30.0,
        alpha_deg: float = 3.0, pos0=(100.0, -200.0, 500.0)) -> Truth:
    """The scripted flight's truth (see the module text)."""
    dur = sum(s.duration_s for s in segments)
    n = int(round(dur * IMU_HZ)) + 1
    dtf = 1.0 / (IMU_HZ * FINE)
    tf = np.arange((n - 1) * FINE + 1) * dtf
    mu, mu_d = _profile(tf, segments, "bank_deg")
    gam, gam_d = _profile(tf, segments, "gamma_deg")
    V = airspeed_m_s
    chi_d = GRAVITY_M_S2 * np.tan(mu) / V
    chi = math.radians(heading0_deg) + _cumtrapz(chi_d, dtf)
    cg, sg, cc, sc = np.cos(gam), np.sin(gam), np.cos(chi), np.sin(chi)
    wind = np.array([wind_en_m_s[0], wind_en_m_s[1], 0.0])
    vel = V * np.stack([cg * sc, cg * cc, sg], -1) + wind
    acc = V * np.stack([-sg * gam_d * sc + cg * cc * chi_d, -sg * gam_d * cc - cg * sc * chi_d, cg * gam_d], -1)
    pos = np.asarray(pos0, float) + _cumtrapz(vel, dtf)
    r_body_from_wind = rot_y(math.radians(alpha_deg))
    R = R_ENU_FROM_NED @ _dcm_ned_from_euler(mu, gam, chi) @ r_body_from_wind.T
    w_wind = np.stack([mu_d - chi_d * sg, gam_d * np.cos(mu) + chi_d * np.sin(mu) * cg,
                       -gam_d * np.sin(mu) + chi_d * np.cos(mu) * cg], -1)
    rates = w_wind @ r_body_from_wind.T
    f_enu = acc + np.array([0.0, 0.0, GRAVITY_M_S2])
    fb = np.einsum("nji,nj->ni", R, f_enu)
    ca, cf = _cumtrapz(rates, dtf)[::FINE], _cumtrapz(fb, dtf)[::FINE]
    dang, dvel = np.zeros((n, 3)), np.zeros((n, 3))
    dang[1:], dvel[1:] = np.diff(ca, axis=0), np.diff(cf, axis=0)
    Rk = R[::FINE]
    euler = np.array([euler_ned_from_dcm_enu_from_frd(r) for r in Rk])
    return Truth(tf[::FINE], pos[::FINE], vel[::FINE], Rk, euler, dang, dvel, V, wind, tf, pos, vel)


# ----------------------------------------------------------------------------------------------- sensors


@dataclass
class SensorSpec:
    """Sensor error models (1 sigma). Bias steps: (time, 3-vector) added from that time on."""

    seed: int = 1
    gyro_noise: float = 3.4e-4  # rad/s/sqrt(Hz)
    accel_noise: float = 4.0e-3  # m/s^2/sqrt(Hz)
    gyro_bias: tuple = (0.004, -0.003, 0.005)  # turn-on, rad/s
    accel_bias: tuple = (0.15, -0.10, 0.20)  # turn-on, m/s^2
    gyro_bias_rw: float = 3.9e-5
    accel_bias_rw: float = 1.0e-3
    gyro_bias_step: tuple | None = None  # (t_s, (3,))
    accel_bias_step: tuple | None = None
    gnss_hz: float = 5.0
    gnss_latency_s: float = 0.15
    gnss_pos_sigma: tuple = (0.8, 1.5)  # horizontal, vertical
    gnss_vel_sigma: float = 0.15
    gnss_outage: tuple | None = None  # (t_start, t_end): no fixes valid in between
    gnss_offsets: tuple = ()  # ((t_start, t_end, (3,) offset), ...): added to the fixes valid in between
    baro_hz: float = 25.0
    baro_sigma: float = 0.3
    baro_offset_m: float = 3.0
    baro_drift: tuple | None = None  # (t_start, rate m/s)
    mag_hz: float = 50.0
    mag_sigma: float = 0.003  # gauss per axis
    mag_decl_deg: float = 5.0
    mag_incl_deg: float = 60.0
    mag_strength: float = 0.5
    mag_interference: tuple | None = None  # (t_start, t_end, (3,) body-frame offset gauss)
    airspeed_hz: float = 20.0
    airspeed_sigma: float = 0.3


def earth_field_enu(spec: SensorSpec) -> np.ndarray:
    d, i, b = math.radians(spec.mag_decl_deg), math.radians(spec.mag_incl_deg), spec.mag_strength
    return np.array([b * math.cos(i) * math.sin(d), b * math.cos(i) * math.cos(d), -b * math.sin(i)])


def _bias_series(rng, n, dt, turn_on, rw, step) -> np.ndarray:
    b = np.asarray(turn_on, float) + np.cumsum(rng.normal(0.0, rw * math.sqrt(dt), (n, 3)), axis=0)
    if step is not None:
        b[np.arange(n) * dt >= step[0]] += np.asarray(step[1], float)
    return b


def imu_samples(truth: Truth, spec: SensorSpec, rng) -> tuple[list[ImuSample], np.ndarray, np.ndarray]:
    """IMU samples 1..n-1 and the true biases at each sample."""
    n, dt = len(truth.t), 1.0 / IMU_HZ
    bg = _bias_series(rng, n, dt, spec.gyro_bias, spec.gyro_bias_rw, spec.gyro_bias_step)
    ba = _bias_series(rng, n, dt, spec.accel_bias, spec.accel_bias_rw, spec.accel_bias_step)
    dang = truth.dang + bg * dt + rng.normal(0.0, spec.gyro_noise * math.sqrt(dt), (n, 3))
    dvel = truth.dvel + ba * dt + rng.normal(0.0, spec.accel_noise * math.sqrt(dt), (n, 3))
    return [ImuSample(float(truth.t[k]), dt, dang[k], dvel[k]) for k in range(1, n)], bg, ba


def _interp(truth: Truth, arr: np.ndarray, t: np.ndarray) -> np.ndarray:
    return np.stack([np.interp(t, truth.fine_t, arr[:, j]) for j in range(3)], -1)


def gnss_fixes(truth: Truth, spec: SensorSpec, rng, timing: str = "delayed") -> list[GnssFix]:
    """Fixes valid every 1 / gnss_hz s; ``timing``: "delayed" (arrive latency later, time_of_fix true),
    "naive" (arrive latency later, stamped as valid on arrival), "none" (arrive when valid), "unstamped"
    (arrive latency later, time_of_fix NaN)."""
    t_fix = np.arange(0.5, truth.t[-1] - 0.5, 1.0 / spec.gnss_hz) + 0.013
    pos, vel = _interp(truth, truth.fine_pos, t_fix), _interp(truth, truth.fine_vel, t_fix)
    sh, sv = spec.gnss_pos_sigma
    pos = pos + rng.normal(0.0, 1.0, pos.shape) * np.array([sh, sh, sv])
    vel = vel + rng.normal(0.0, spec.gnss_vel_sigma, vel.shape)
    for t0, t1, offset in spec.gnss_offsets:
        pos[(t_fix >= t0) & (t_fix < t1)] += np.asarray(offset, float)
    out = []
    for k, tv in enumerate(t_fix):
        if spec.gnss_outage is not None and spec.gnss_outage[0] <= tv < spec.gnss_outage[1]:
            continue
        arrive = tv if timing == "none" else tv + spec.gnss_latency_s
        stamp = {"naive": arrive, "unstamped": math.nan}.get(timing, tv)
        out.append(GnssFix(float(arrive), float(stamp), pos[k], vel[k], sh, sv, spec.gnss_vel_sigma))
    return out


def other_samples(truth: Truth, spec: SensorSpec, rng) -> list:
    """Baro, magnetometer and airspeed samples (no latency)."""
    out: list = []
    tb = np.arange(0.01, truth.t[-1], 1.0 / spec.baro_hz)
    h = np.interp(tb, truth.fine_t, truth.fine_pos[:, 2]) + spec.baro_offset_m + rng.normal(0, spec.baro_sigma, len(tb))
    if spec.baro_drift is not None:
        h += np.maximum(tb - spec.baro_drift[0], 0.0) * spec.baro_drift[1]
    out += [BaroSample(float(t), float(x)) for t, x in zip(tb, h)]
    m_enu = earth_field_enu(spec)
    for t in np.arange(0.005, truth.t[-1], 1.0 / spec.mag_hz) if spec.mag_hz > 0 else ():
        k = int(round(t * IMU_HZ))
        m = truth.R[k].T @ m_enu + rng.normal(0.0, spec.mag_sigma, 3)
        if spec.mag_interference is not None and spec.mag_interference[0] <= t < spec.mag_interference[1]:
            m = m + np.asarray(spec.mag_interference[2], float)
        out.append(MagSample(float(t), m))
    ta = np.arange(0.02, truth.t[-1], 1.0 / spec.airspeed_hz)
    out += [AirspeedSample(float(t), float(truth.airspeed + rng.normal(0, spec.airspeed_sigma))) for t in ta]
    return sorted(out, key=lambda m: m.t_s)


# ----------------------------------------------------------------------------------------------- runner


@dataclass
class Run:
    """What a run recorded: per IMU sample (from initialisation on) errors of the delivered estimate, and every
    ``nees_every`` samples the horizon state's NEES; events and statuses."""

    t: np.ndarray
    pos_err: np.ndarray  # (m, 3)
    vel_err: np.ndarray
    att_err_deg: np.ndarray  # (m, 3) roll, pitch, yaw
    mode: list
    pos_std: np.ndarray
    nees_t: np.ndarray
    nees_att: np.ndarray
    nees_pos: np.ndarray
    bias_t: np.ndarray
    gyro_bias_err: np.ndarray  # (j, 3) horizon estimate minus truth
    accel_bias_err: np.ndarray
    baro_bias: np.ndarray
    events: list
    statuses: list
    ins: Ins

    def rms(self, arr: np.ndarray, after_s: float = 0.0) -> np.ndarray:
        sel = self.t >= after_s
        return np.sqrt(np.mean(arr[sel] ** 2, axis=0))

    def at(self, t_s: float) -> int:
        return int(np.searchsorted(self.t, t_s))


def run(truth: Truth, spec: SensorSpec, cfg=None, timing: str = "delayed", nees_every: int = 12) -> Run:
    """Feed one flight's sensors to a fresh Ins in time order and record its errors."""
    rng = np.random.default_rng(spec.seed)
    imu, bg, ba = imu_samples(truth, spec, rng)
    fixes = gnss_fixes(truth, spec, np.random.default_rng(spec.seed + 1), timing)
    others = sorted(fixes + other_samples(truth, spec, np.random.default_rng(spec.seed + 2)), key=lambda m: m.t_s)
    ins = Ins(cfg)
    feed = {GnssFix: ins.fuse_gnss, BaroSample: ins.fuse_baro, MagSample: ins.fuse_mag,
            AirspeedSample: ins.fuse_airspeed}
    rec: dict[str, list] = {k: [] for k in ("t", "pe", "ve", "ae", "mode", "ps", "nt", "na", "np", "bt", "bg", "ba",
                                            "bb")}
    statuses, events, j = [], [], 0
    for i, s in enumerate(imu):
        while j < len(others) and others[j].t_s <= s.t_s:
            feed[type(others[j])](others[j])
            j += 1
        ins.predict(s)
        if not ins.initialised:
            continue
        k = i + 1
        est = ins.estimate()
        rec["t"].append(s.t_s)
        rec["pe"].append(est.pos_enu_m - truth.pos[k])
        rec["ve"].append(est.vel_enu_m_s - truth.vel[k])
        rec["ae"].append(np.degrees(wrap_pi(est.euler_ned_rad - truth.euler[k])))
        rec["mode"].append(est.mode)
        rec["ps"].append(est.pos_std_m)
        if i % nees_every == 0:
            _record_horizon(ins, truth, bg, ba, rec)
        statuses += ins.drain_aid_status()
        events += ins.drain_events()
    a = {k: np.array(v) for k, v in rec.items() if k != "mode"}
    return Run(a["t"], a["pe"], a["ve"], a["ae"], rec["mode"], a["ps"], a["nt"], a["na"], a["np"], a["bt"], a["bg"],
               a["ba"], a["bb"], events, statuses, ins)


def _record_horizon(ins: Ins, truth: Truth, bg, ba, rec) -> None:
    """NEES of the horizon state's attitude and position errors (3 dof each), and its bias errors."""
    h = ins.horizon_state()
    k = int(round(h.t_s * IMU_HZ))
    dR = truth.R[k] @ dcm_from_quat(h.quat_enu_from_frd).T  # Exp(dtheta) = R_true R_est^T
    dth = 0.5 * np.array([dR[2, 1] - dR[1, 2], dR[0, 2] - dR[2, 0], dR[1, 0] - dR[0, 1]])
    dp = truth.pos[k] - h.pos_enu_m
    P = h.covariance
    rec["nt"].append(h.t_s)
    rec["na"].append(float(dth @ np.linalg.solve(P[0:3, 0:3], dth)))
    rec["np"].append(float(dp @ np.linalg.solve(P[6:9, 6:9], dp)))
    rec["bt"].append(h.t_s)
    rec["bg"].append(h.gyro_bias_frd_rad_s - bg[k])
    rec["ba"].append(h.accel_bias_frd_m_s2 - ba[k])
    rec["bb"].append(h.baro_bias_m)
