"""The onboard INS: an error-state EKF fusing the IMU with GNSS, barometer, magnetometer and airspeed
(the PX4 EKF2 / ArduPilot EKF3 family), for a fixed-wing UAV over a few km.

Navigation frame: flat-earth world ENU (z up), gravity ``g_enu = [0, 0, -9.80665]`` (the world's constant);
body FRD; attitude ``q = q_enu_from_frd`` (Hamilton ``[w, x, y, z]``), ``R = R_enu_from_frd``.

State. Nominal: ``q, v (ENU m/s), p (ENU m), b_g (FRD rad/s), b_a (FRD m/s^2), w (horizontal wind E, N, m/s),
b_h (barometer height bias, m), b_m (magnetometer body-frame bias, gauss)``. Error state (21), the EKF's
covariance ``P`` is over it::

    0-2 dtheta  attitude error, a small rotation in the world frame: q_true = Exp(dtheta) * q
    3-5 dv      velocity error            6-8  dp    position error
    9-11 db_g   gyro bias error           12-14 db_a accelerometer bias error
    15-16 dw    wind error (E, N)         17    db_h barometer bias error
    18-20 db_m  magnetometer bias error (hard iron, body frame)

The world-frame attitude error keeps tilt (``dtheta`` E, N) and heading (``dtheta`` U) apart, and its
dynamics do not depend on the body rates.

Prediction, per IMU sample (delta angle ``da``, delta velocity ``dv_m`` over ``dt``, body frame)::

    da' = da - b_g dt,   dv' = dv_m - b_a dt
    q  <- q * Exp(da')                                   (coning ignored)
    v  <- v + R (dv' + da' x dv' / 2) + g_enu dt          (first-order rotation of the delta velocity)
    p  <- p + (v_old + v_new) dt / 2
    P  <- Phi P Phi^T + Q dt,  Phi = I + F dt:
          dtheta' = -R db_g,  dv' = -[R dv'/dt]x dtheta - R db_a,  dp' = dv;  the biases and wind random walks
    Q  = diag(sigma_g^2 I3, sigma_a^2 I3, 0, sigma_bg^2 I3, sigma_ba^2 I3, sigma_w^2 I2, sigma_bh^2, sigma_bm^2 I3)
         (noise densities: the continuous white noise integrated over dt; R R^T = I keeps them diagonal)

Fusion (sequential scalar updates, ``K = P h / s``, ``s = h P h^T + r``, covariance ``P <- P - u u^T`` with
``u = P h / sqrt(s)``: symmetric by construction; variances floored to keep ``P`` positive definite). The
error is injected into the nominal state after each source (``q <- Exp(dtheta) q``) and reset to zero.

==============  ==========================================  ==============================================
source          observation model                           gate (PX4 EKF2 default)
==============  ==========================================  ==============================================
gnss_pos (3)    p (fix moved to the EKF's sample time)      5 SD, per axis, all or none
gnss_vel (3)    v                                           5 SD
baro            p_U + b_h                                   5 SD
mag (field, 3)  R^T m_earth + b_m                           3 SD, all or none; strength, inclination checks
mag (heading)   heading of R m_body = declination (yaw)     2.6 SD; the same checks (mag_fusion: heading)
airspeed        |v - w|                                     3 SD (above airspeed_min_m_s)
sideslip        (R^T (v - w))_y / (R^T (v - w))_x = 0       5 SD (synthetic, with each airspeed sample)
==============  ==========================================  ==============================================

The magnetometer is fused against the earth field configured a priori (declination, inclination, strength).
By default its three axes are (EKF2's 3-axis fusion without the earth-field states): ``d/d dtheta = R^T [m]x``,
and the body-frame bias states take an uncalibrated hard iron, observable as the body turns in the field.
With ``mag_fusion: heading`` it is fused as a heading (EKF2's heading fusion, at its heading noise of 0.3 rad):
the measured field turned into the world frame with the estimated attitude should point at the declination,
fused as an observation of the yaw alone (``h = [0, 0, 1]``), so that a compass error cannot tilt the attitude
(the exact Jacobian, ``ins_models.mag_heading``, also carries the tilt through the vertical field); nothing
observes the magnetometer bias states then.

Fusion horizon (PX4 EKF2's scheme, not rewind-and-replay). The IMU samples are buffered and the EKF runs
``fusion_horizon_s`` behind the newest one; a GNSS fix, valid ``time_of_fix_s`` (its arrival less the
receiver's latency), waits in its buffer until the EKF's time reaches it and is fused at the EKF sample
nearest its time of validity (the position moved by ``v (t_sample - t_fix)``). Baro, mag and airspeed are
fused at their sample times in the same way. A strapdown output predictor (``ins_output``) integrates every
IMU sample at the current time and is pulled onto the delayed EKF with complementary gains, so the estimate
delivered is at the newest IMU sample and smooth. This costs one EKF prediction per IMU sample; rewinding
to a stored state and replaying some 20 samples per fix would cost about twice that, and the output would
jump at each fix. A measurement older than the horizon when it arrives is fused late (at the next sample),
with an event. Baro, magnetometer and airspeed samples are averaged over ``sample_average_s`` (EKF2 downsamples
its observations too) and fused at the window's mean time, so the horizon must also cover half a window.

Cost (tools/bench_ins.py, one core of a shared 2-core machine, medians): ``predict`` 25-31 us per IMU
sample (the compiled EKF prediction 9-16 us, the output predictor 9 us), GNSS fusion 70 us per fix, the
magnetometer 25-30 us as a heading (50-75 us as a field), airspeed and sideslip 50-60 us, baro 20 us,
``estimate`` 16 us: some 60 us per 120 Hz tick with every sensor (baro, mag and airspeed averaged to 10 Hz)
and an estimate each tick.

Initialisation (in flight): an in-motion alignment (``ins_align``) over ``init_alignment_s`` between two GNSS
fixes gives the attitude (tilt from the accelerometers against the GNSS change of velocity, heading from the
magnetometer or else the GNSS course); position and velocity from the second fix, wind from the airspeed and
heading, the baro bias from a baro sample, the biases zero, each with an honest (large) std. Mode
``initialising`` until then.

Faults, as PX4 handles them, each reported as an event (:meth:`Ins.drain_events`):

* GNSS outage: no GNSS fused for ``dead_reckoning_after_s``: mode ``dead_reckoning`` (airspeed, sideslip, baro
  and mag still fused; the covariance grows); ``aided`` again at the first fix fused;
* GNSS jump: the innovations fail the gate (``rejected``); rejected for ``gnss_reset_after_s`` in a row, the
  position (or velocity) is reset to the fix, its covariance to the fix's, and the output predictor shifted;
* magnetometer interference: the heading innovation or the field checks reject it; the heading is held by the
  gyros and by the GNSS velocity in manoeuvres;
* IMU bias step: the bias states absorb it (their random walks);
* barometer drift: the baro bias state follows it against the GNSS height; a jump is gated.

A source's rejections raise an event once they have lasted 1 s (a lone rejection by noise raises none), and
its return another. Not done: a yaw reset (EKF2's GSF yaw estimator) when the heading is lost, magnetometer
bias states, the covariance's reset Jacobian at injection, earth rotation and curvature.

Flight software: imports only ``fwsim.interface`` and the navigation block (docs/design/architecture.md).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from controllers.config import InsConfig
from controllers.navigation.ins_align import InMotionAlignment
from controllers.navigation.ins_compiled import build_predict
from controllers.navigation.ins_models import airspeed, mag_field, mag_heading, sideslip
from controllers.navigation.ins_math import (dcm_from_quat, euler_jacobian, euler_ned_from_dcm_enu_from_frd, quat_exp,
                                             quat_mul)
from controllers.navigation.ins_output import OutputPredictor
from fwsim.interface.frames import quat_from_dcm, wrap_pi
from fwsim.interface.messages import (AidSourceStatus, AirspeedSample, BaroSample, GnssFix, ImuSample, MagSample,
                                      NavEstimate)

__all__ = ["InsConfig", "Ins", "HorizonState", "GRAVITY_M_S2", "N_STATES"]

GRAVITY_M_S2 = 9.80665  # fwsim.world.airframe.G0_M_S2
N_STATES = 21
_VEL, _POS = 3, 6  # offsets in the error state (attitude 0, gyro bias 9, accel bias 12, wind 15, baro bias 17,
#                    mag bias 18)
_IDX_BARO = np.array([8, 17])
_IDX_MAG = np.array([0, 1, 2])
_IDX_MAG_FIELD = np.array([0, 1, 2, 18, 19, 20])
_IDX_TAS = np.array([3, 4, 5, 15, 16])
_IDX_BETA = np.array([0, 1, 2, 3, 4, 5, 15, 16])
_H_BARO = np.array([1.0, 1.0])
_VAR_MIN = np.array([1e-12] * 3 + [1e-8] * 6 + [1e-16] * 3 + [1e-12] * 3 + [1e-8] * 3 + [1e-12] * 3)  # P's floors
_REPORT_AFTER_S = 1.0  # a source's rejections raise an event once they have lasted this long
_ALIGN_RESTART_FACTOR = 3.0  # a window this many times init_alignment_s without a fix to close it starts again


_YAW_ONLY = np.array([0.0, 0.0, 1.0])  # the heading fusion's observation row over dtheta
_YAW_ONLY.setflags(write=False)


@dataclass(frozen=True, slots=True)
class HorizonState:
    """The EKF's state at its delayed time horizon, with its covariance (for logs, tests and integrators)."""

    t_s: float
    quat_enu_from_frd: np.ndarray  # (4,)
    pos_enu_m: np.ndarray
    vel_enu_m_s: np.ndarray
    gyro_bias_frd_rad_s: np.ndarray
    accel_bias_frd_m_s2: np.ndarray
    wind_en_m_s: np.ndarray  # (2,) east, north
    baro_bias_m: float
    mag_bias_frd_gauss: np.ndarray  # (3,)
    covariance: np.ndarray  # (21, 21) over the error state of the module text


class _Health:
    """One aid source's run of rejections, for the events."""

    __slots__ = ("name", "last_fused_t", "since_t", "reported")

    def __init__(self, name: str):
        self.name = name
        self.last_fused_t = -math.inf
        self.since_t = math.nan  # the first rejection of the current run
        self.reported = False

    def fused(self, t: float) -> str | None:
        msg = None
        if self.reported:
            msg = f"{self.name} fused again at t = {t:.2f} s after {t - self.since_t:.1f} s of rejections"
        self.last_fused_t, self.since_t, self.reported = t, math.nan, False
        return msg

    def rejected(self, t: float, why: str) -> str | None:
        if math.isnan(self.since_t):
            self.since_t = t
        if not self.reported and t - self.since_t >= _REPORT_AFTER_S:
            self.reported = True
            return f"{self.name} rejected since t = {self.since_t:.2f} s ({why})"
        return None


class _Averager:
    """A sensor's samples averaged over a window (PX4 EKF2 downsamples its observations too): fewer fusions,
    much the same information. The window closes when one more sample would take it past ``interval_s``."""

    __slots__ = ("interval", "n", "t0", "t_prev", "t_sum", "v_sum")

    def __init__(self, interval_s: float):
        self.interval = interval_s
        self.n, self.t0, self.t_prev, self.t_sum, self.v_sum = 0, 0.0, 0.0, 0.0, 0.0

    def add(self, t: float, value):
        """The window's mean time and value when this sample closes it, else None."""
        if self.n == 0:
            self.t0, self.t_sum, self.v_sum = t, 0.0, 0.0
        self.n += 1
        self.t_sum += t
        self.v_sum = self.v_sum + value
        closes = self.interval <= 0.0 or (self.n > 1 and 2.0 * t - self.t_prev - self.t0 >= self.interval * 0.999)
        self.t_prev = t
        if not closes:
            return None
        n, self.n = self.n, 0
        return self.t_sum / n, self.v_sum / n


def _earth_field_enu(cfg: InsConfig) -> np.ndarray:
    d, i, b = math.radians(cfg.mag_declination_deg), math.radians(cfg.mag_inclination_deg), cfg.mag_strength_gauss
    return np.array([b * math.cos(i) * math.sin(d), b * math.cos(i) * math.cos(d), -b * math.sin(i)])


class Ins:
    """The INS/GNSS error-state EKF (see the module text).

    Feed it every IMU sample with :meth:`predict` and each other sensor's sample as it arrives with
    ``fuse_gnss`` / ``fuse_baro`` / ``fuse_mag`` / ``fuse_airspeed`` (they are queued and fused when the delayed
    EKF reaches their time of validity); read :meth:`estimate` (at the newest IMU sample), the aid sources'
    statuses (:meth:`drain_aid_status`, :meth:`latest_aid_status`) and the events (:meth:`drain_events`).
    """

    def __init__(self, cfg: InsConfig | None = None):
        self.cfg = cfg if cfg is not None else InsConfig()
        c = self.cfg
        self._predict_fn = build_predict(GRAVITY_M_S2)  # the compiled prediction, on its own buffers:
        self._x, self._P_flat, self._u, q_rate = self._predict_fn.inputs  # nominal state, P, IMU, process noise
        self._P = self._P_flat.reshape(N_STATES, N_STATES)  # (symmetric: column-major is row-major)
        self._Pdiag = self._P_flat[:: N_STATES + 1]  # a writable view of the diagonal
        q_rate[:] = ([c.gyro_noise_rad_s_rt_hz ** 2] * 3 + [c.accel_noise_m_s2_rt_hz ** 2] * 3 + [0.0] * 3
                     + [c.gyro_bias_rw_rad_s2_rt_hz ** 2] * 3 + [c.accel_bias_rw_m_s3_rt_hz ** 2] * 3
                     + [c.wind_rw_m_s2_rt_hz ** 2] * 2 + [c.baro_bias_rw_m_s_rt_hz ** 2]
                     + [c.mag_bias_rw_gauss_s_rt_hz ** 2] * 3)
        self._dx = np.zeros(N_STATES)
        x = self._x  # views of the nominal state (updated in place); x[18] is the baro bias b_h
        x[0] = 1.0
        self._q, self._v, self._p, self._bg, self._ba, self._w = x[0:4], x[4:7], x[7:10], x[10:13], x[13:16], x[16:18]
        self._bm = x[19:22]
        self._earth_field_enu = _earth_field_enu(c)
        self._tmp = np.zeros((N_STATES, N_STATES))
        self._imu_buf: deque = deque()  # (index, ImuSample) not yet processed by the EKF
        self._queues: dict[str, deque] = {k: deque() for k in ("gnss", "baro", "mag", "airspeed")}
        self._averagers = {k: _Averager(c.sample_average_s) for k in ("baro", "mag", "airspeed")}
        self._fusers = ((self._queues["gnss"], self._fuse_gnss_now), (self._queues["baro"], self._fuse_baro_now),
                        (self._queues["mag"], self._fuse_mag_now),
                        (self._queues["airspeed"], self._fuse_airspeed_now))
        self._out = OutputPredictor(c.output_tau_s, GRAVITY_M_S2)
        self._align = InMotionAlignment(GRAVITY_M_S2)
        self._health = {k: _Health(k) for k in ("gnss_pos", "gnss_vel", "baro", "mag", "airspeed", "sideslip")}
        self._n_imu = 0
        self._last_imu: ImuSample | None = None
        self._t_now = self._t_delayed = -math.inf
        self._initialised = False
        self._mode = "initialising"
        self._last_gnss_fused_t = -math.inf  # EKF time of the last GNSS fusion
        self._last_gnss_fix_t = -math.inf  # time of validity of the last GNSS fix fused
        self._last_baro: tuple[float, BaroSample] | None = None  # kept for the initialisation
        self._last_airspeed: tuple[float, AirspeedSample] | None = None
        self._late_reported = False
        self._statuses: deque[AidSourceStatus] = deque(maxlen=4096)
        self._latest: dict[str, AidSourceStatus] = {}
        self._events: list[str] = []
        self._estimate: NavEstimate | None = None  # estimate() of the newest IMU sample, once asked for

    # ----------------------------------------------------------------------------------------------- inputs

    def predict(self, imu: ImuSample) -> None:
        """Take one IMU sample: the output predictor moves to its time, the EKF up to ``fusion_horizon_s``
        before it (fusing what has become due on the way)."""
        k = self._n_imu
        self._n_imu += 1
        self._estimate = None
        self._t_now = imu.t_s
        self._last_imu = imu
        self._imu_buf.append((k, imu))
        if self._initialised:
            dt = imu.dt_s
            self._out.step(k, dt, (imu.delta_angle_frd_rad - self._bg * dt).tolist(),
                           (imu.delta_velocity_frd_m_s - self._ba * dt).tolist())
        horizon = imu.t_s - self.cfg.fusion_horizon_s + 1e-9
        buf = self._imu_buf
        while buf and buf[0][1].t_s <= horizon:
            j, s = buf.popleft()
            self._step_delayed(j, s)

    def fuse_gnss(self, fix: GnssFix) -> None:
        """Queue a GNSS fix, to be fused at its time of validity (``t_s - gnss_delay_s`` if it has none)."""
        tv = fix.time_of_fix_s if math.isfinite(fix.time_of_fix_s) else fix.t_s - self.cfg.gnss_delay_s
        self._queue("gnss", tv, fix)

    def fuse_baro(self, sample: BaroSample) -> None:
        """Take a barometric height: averaged over ``sample_average_s``, fused at the window's mean time."""
        avg = self._averagers["baro"].add(sample.t_s, sample.height_m)
        if avg is not None:
            self._queue("baro", avg[0], BaroSample(avg[0], avg[1]))

    def fuse_mag(self, sample: MagSample) -> None:
        """Take a magnetometer sample: averaged over ``sample_average_s``, fused (as a heading) at the window's
        mean time."""
        avg = self._averagers["mag"].add(sample.t_s, np.asarray(sample.field_frd_gauss, float))
        if avg is not None:
            self._queue("mag", avg[0], MagSample(avg[0], avg[1]))

    def fuse_airspeed(self, sample: AirspeedSample) -> None:
        """Take a true airspeed: averaged over ``sample_average_s``, fused (with the synthetic sideslip) at the
        window's mean time."""
        avg = self._averagers["airspeed"].add(sample.t_s, sample.airspeed_m_s)
        if avg is not None:
            self._queue("airspeed", avg[0], AirspeedSample(avg[0], avg[1]))

    def _queue(self, name: str, t_valid: float, msg) -> None:
        if not math.isfinite(t_valid):
            return
        if t_valid < self._t_delayed and self._initialised and not self._late_reported:
            self._late_reported = True
            self._event(f"{name} sample valid at t = {t_valid:.2f} s arrived behind the fusion horizon "
                        f"({self._t_now - t_valid:.2f} s old, horizon {self.cfg.fusion_horizon_s:.2f} s): fused late")
        self._queues[name].append((t_valid, msg))

    # ----------------------------------------------------------------------------------------------- outputs

    @property
    def initialised(self) -> bool:
        return self._initialised

    @property
    def mode(self) -> str:
        """"initialising" | "aided" | "dead_reckoning"."""
        return self._mode

    def drain_events(self) -> list[str]:
        """The events since the last call (oldest first)."""
        out, self._events = self._events, []
        return out

    def drain_aid_status(self) -> list[AidSourceStatus]:
        """Every fusion attempt's status since the last call (oldest first; the newest 4096 are kept)."""
        out = list(self._statuses)
        self._statuses.clear()
        return out

    def latest_aid_status(self, source: str) -> AidSourceStatus | None:
        """The newest status of one aid source ("gnss_pos", "gnss_vel", "baro", "mag", "airspeed", "sideslip")."""
        return self._latest.get(source)

    def horizon_state(self) -> HorizonState:
        """The EKF's state and covariance at its delayed time (copies)."""
        return HorizonState(self._t_delayed, self._q.copy(), self._p.copy(), self._v.copy(), self._bg.copy(),
                            self._ba.copy(), self._w.copy(), float(self._x[18]), self._bm.copy(), self._P.copy())

    def estimate(self) -> NavEstimate:
        """The estimate at the newest IMU sample (the output predictor), with the EKF's standard deviations;
        ``gnss_age_s`` is the time since the newest fused fix was valid. The same object until the next
        :meth:`predict` (treat its arrays as read-only)."""
        if self._estimate is not None:
            return self._estimate
        imu = self._last_imu
        t = imu.t_s if imu is not None else math.nan
        if not self._initialised:
            nan3 = np.full(3, np.nan)
            return NavEstimate(t, nan3, nan3.copy(), nan3.copy(), nan3.copy(), nan3.copy(), nan3.copy(), nan3.copy(),
                               nan3.copy(), nan3.copy(), nan3.copy(), nan3.copy(), "initialising", math.inf)
        o = self._out
        R = dcm_from_quat(o.q)
        euler = euler_ned_from_dcm_enu_from_frd(R)
        J = euler_jacobian(euler, R)
        att_std = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", J, self._P[0:3, 0:3], J), 0.0))
        std = np.sqrt(self._Pdiag)
        inv_dt = 1.0 / imu.dt_s
        bg, ba = self._bg.copy(), self._ba.copy()
        self._estimate = NavEstimate(
            t, np.array(o.p), np.array(o.v), euler, imu.delta_angle_frd_rad * inv_dt - bg,
            imu.delta_velocity_frd_m_s * inv_dt - ba, bg, ba, np.array([self._w[0], self._w[1], 0.0]),
            std[_POS:_POS + 3], std[_VEL:_VEL + 3], att_std, self._mode, t - self._last_gnss_fix_t)
        return self._estimate

    # ----------------------------------------------------------------------------------------------- the delayed EKF

    def _step_delayed(self, k: int, s: ImuSample) -> None:
        """The EKF at IMU sample ``k``: predict, fuse what is due, update the mode, correct the output."""
        self._t_delayed = s.t_s
        if not self._initialised:
            self._align_step(k, s)
            return
        self._predict_ekf(s)
        lim = s.t_s + 0.5 * s.dt_s
        for queue, fuse in self._fusers:
            while queue and queue[0][0] <= lim:
                tv, msg = queue.popleft()
                fuse(tv, msg)
        self._update_mode()
        x = self._x.tolist()
        self._out.correct(k, self._t_now - s.t_s, s.dt_s, x[0:4], x[4:7], x[7:10])

    def _predict_ekf(self, s: ImuSample) -> None:
        """Nominal-state strapdown step and covariance propagation (module text), one compiled call
        (``ins_compiled``)."""
        u = self._u
        u[0:3] = s.delta_angle_frd_rad
        u[3:6] = s.delta_velocity_frd_m_s
        u[6] = s.dt_s
        x1, P1 = self._predict_fn()
        self._x[:] = x1
        self._P_flat[:] = P1

    # ----------------------------------------------------------------------------------------------- update maths

    def _update_unit(self, i: int, innov: float, r: float) -> None:
        """Scalar update of state ``i`` observed directly (h = e_i), into the accumulated error ``_dx``."""
        P = self._P
        rs = 1.0 / math.sqrt(P[i, i] + r)
        u = P[:, i] * rs
        self._dx += u * ((innov - self._dx[i]) * rs)
        P -= np.multiply.outer(u, u)

    def _innovation_variance(self, idx: np.ndarray, h: np.ndarray, r: float) -> tuple[np.ndarray, float]:
        """P h^T and h P h^T + r for an observation row with nonzeros ``h`` at states ``idx``."""
        pht = self._P[:, idx] @ h
        return pht, float(pht[idx] @ h) + r

    def _update(self, idx: np.ndarray, h: np.ndarray, pht: np.ndarray, s: float, innov: float) -> None:
        """Scalar update with P h^T and s from :meth:`_innovation_variance`, into the accumulated error ``_dx``
        (the innovation less what earlier updates of the same step already explain)."""
        rs = 1.0 / math.sqrt(s)
        u = pht * rs
        self._dx += u * ((innov - float(self._dx[idx] @ h)) * rs)
        self._P -= np.multiply.outer(u, u)

    def _inject(self) -> None:
        """Move the accumulated error into the nominal state and zero it; floor P's diagonal."""
        dx = self._dx
        self._q[:] = quat_mul(quat_exp(dx[0:3]), self._q.tolist())
        self._x[4:22] += dx[3:21]  # v, p, b_g, b_a, w, b_h, b_m: the error state's order
        dx[:] = 0.0
        np.maximum(self._Pdiag, _VAR_MIN, out=self._Pdiag)

    def _reset_block(self, i0: int, var: np.ndarray) -> None:
        """Decorrelate states ``i0 .. i0 + len(var)`` and give them these variances (a reset to a measurement)."""
        n = len(var)
        self._P[i0:i0 + n, :] = 0.0
        self._P[:, i0:i0 + n] = 0.0
        self._Pdiag[i0:i0 + n] = var

    # ----------------------------------------------------------------------------------------------- aid sources

    def _fuse_gnss_now(self, tv: float, fix: GnssFix) -> None:
        """GNSS position and velocity, each gated as a whole; rejected for too long, reset to the fix."""
        c = self.cfg
        zp = fix.pos_enu_m + self._v * (self._t_delayed - tv)  # the fix moved to the EKF's sample time
        sh, sv = max(fix.h_acc_m, c.gnss_pos_noise_min_m), max(fix.v_acc_m, c.gnss_pos_noise_min_m)
        ss = max(fix.s_acc_m_s, c.gnss_vel_noise_min_m_s)
        fused_p = self._fuse_direct("gnss_pos", tv, zp, np.array([sh * sh, sh * sh, sv * sv]), _POS,
                                    c.gnss_pos_gate_sd)
        if fused_p:  # a receiver's error drifts slowly: its fixes do not average it away
            floor = np.array([fix.h_acc_m, fix.h_acc_m, fix.v_acc_m], dtype=float) ** 2
            d = self._Pdiag[_POS:_POS + 3]
            d += np.maximum(floor - d, 0.0)
        fused_v = self._fuse_direct("gnss_vel", tv, np.asarray(fix.vel_enu_m_s, float), np.full(3, ss * ss), _VEL,
                                    c.gnss_vel_gate_sd)
        if fused_p or fused_v:
            self._last_gnss_fused_t = self._t_delayed
            self._last_gnss_fix_t = max(self._last_gnss_fix_t, tv)

    def _fuse_direct(self, source: str, tv: float, z: np.ndarray, r: np.ndarray, i0: int, gate: float) -> bool:
        """Fuse a directly observed 3-vector (states i0..i0+2) axis by axis if every axis passes the gate."""
        x = self._p if i0 == _POS else self._v
        innov = z - x
        s = self._Pdiag[i0:i0 + 3] + r
        ratio = innov * innov / (gate * gate * s)
        ok = bool(np.all(ratio <= 1.0))
        if ok:
            for j in range(3):
                self._update_unit(i0 + j, float(innov[j]), float(r[j]))
            self._inject()
        self._status(source, tv, z, r, innov, s, ratio, ok)
        health = self._health[source]
        if ok:
            self._note(health.fused(self._t_delayed))
            return True
        self._note(health.rejected(self._t_delayed, f"test ratio {float(np.max(ratio)):.1f}"))
        if self._t_delayed - health.last_fused_t > self.cfg.gnss_reset_after_s:
            self._reset_to_gnss(source, z, r, i0)
            health.fused(self._t_delayed)
            return True
        return False

    def _reset_to_gnss(self, source: str, z: np.ndarray, r: np.ndarray, i0: int) -> None:
        """Set position (or velocity) to the fix, as EKF2 does after a run of rejections."""
        x = self._p if i0 == _POS else self._v
        delta = z - x
        self._reset_block(i0, r)
        if i0 == _POS:
            self._p[:] = z
            self._out.shift(np.zeros(3), delta)
        else:
            self._v[:] = z
            self._out.shift(delta, np.zeros(3))
        what, unit = ("position", "m") if i0 == _POS else ("velocity", "m/s")
        self._event(f"{what} reset to GNSS at t = {self._t_delayed:.2f} s after {self.cfg.gnss_reset_after_s:.1f} s "
                    f"of rejections (a step of {float(np.linalg.norm(delta)):.1f} {unit})")

    def _fuse_baro_now(self, tv: float, b: BaroSample) -> None:
        """Barometric height = p_U + b_h (the sample moved to the EKF's time with v_U)."""
        z = b.height_m + float(self._v[2]) * (self._t_delayed - tv)
        r = self.cfg.baro_noise_m ** 2
        innov = z - float(self._p[2] + self._x[18])
        obs = (_IDX_BARO, _H_BARO, *self._innovation_variance(_IDX_BARO, _H_BARO, r))
        self._scalar("baro", tv, z, r, innov, obs, self.cfg.baro_gate_sd)

    def _fuse_mag_now(self, tv: float, m: MagSample) -> None:
        """The magnetometer, less its estimated bias, checked for the configured earth field's strength and
        inclination (on the estimated tilt), then fused as a heading or a field (``mag_fusion``)."""
        c = self.cfg
        b = np.asarray(m.field_frd_gauss, float) - self._bm
        R = dcm_from_quat(self._q)
        mw = R @ b
        strength = float(np.linalg.norm(b))
        incl = math.degrees(math.atan2(-float(mw[2]), math.hypot(float(mw[0]), float(mw[1]))))
        why = None
        if abs(strength - c.mag_strength_gauss) > c.mag_strength_tol_gauss:
            why = f"field strength {strength:.2f} gauss"
        elif abs(incl - c.mag_inclination_deg) > c.mag_inclination_tol_deg:
            why = f"inclination {incl:.0f} deg"
        if c.mag_fusion == "field":
            self._fuse_mag_field(tv, np.asarray(m.field_frd_gauss, float), R, why)
            return
        model = mag_heading(R, b, self._earth_field_enu)
        if model is None:
            return
        z = model[0]
        # the yaw alone, as EKF2's heading fusion (the model's Jacobian also carries the tilt through the vertical
        # field): a compass's error, the hard iron a calibration leaves or interference, then cannot tilt the
        # attitude, which the accelerometers and GNSS hold (tilt-coupled, the typical profile's roll and pitch
        # errors were twice as large)
        r = c.mag_heading_noise_rad ** 2
        innov = wrap_pi(z - math.radians(c.mag_declination_deg))
        obs = (_IDX_MAG, _YAW_ONLY, *self._innovation_variance(_IDX_MAG, _YAW_ONLY, r))
        self._scalar("mag", tv, z, r, innov, obs, c.mag_gate_sd, why)

    def _fuse_mag_field(self, tv: float, z: np.ndarray, R: np.ndarray, why: str | None) -> None:
        """The field's 3 axes against ``R^T m_earth + b_m``, gated as a whole, fused in one vector update."""
        c = self.cfg
        pred, H = mag_field(R, self._earth_field_enu, self._bm)
        innov = z - pred
        r = c.mag_noise_gauss ** 2
        pht = self._P[:, _IDX_MAG_FIELD] @ H.T  # (21, 3)
        S = H @ pht[_IDX_MAG_FIELD] + r * np.eye(3)
        s = S.diagonal().copy()
        ratio = innov * innov / (c.mag_field_gate_sd ** 2 * s)
        if why is None and not np.all(ratio <= 1.0):
            why = f"test ratio {float(np.max(ratio)):.1f}"
        ok = why is None
        if ok:
            K = pht @ np.linalg.inv(S)
            self._dx += K @ innov
            P = self._P
            P -= K @ pht.T
            np.add(P, P.T, out=self._tmp)  # P - K S K^T is symmetric but for rounding: make it exactly so
            np.multiply(self._tmp, 0.5, out=P)
            self._inject()
        self._status("mag", tv, z, np.full(3, r), innov, s, ratio, ok)
        health = self._health["mag"]
        self._note(health.fused(self._t_delayed) if ok else health.rejected(self._t_delayed, why))

    def _fuse_airspeed_now(self, tv: float, a: AirspeedSample) -> None:
        """True airspeed = |v - w|, then the synthetic zero sideslip (fixed wing)."""
        c = self.cfg
        self._last_airspeed = (tv, a)
        if not a.airspeed_m_s >= c.airspeed_min_m_s:
            return
        tas, h = airspeed(self._v, self._w)
        if tas < c.airspeed_min_m_s:
            return
        r = c.airspeed_noise_m_s ** 2
        obs = (_IDX_TAS, h, *self._innovation_variance(_IDX_TAS, h, r))
        self._scalar("airspeed", tv, a.airspeed_m_s, r, a.airspeed_m_s - tas, obs, c.airspeed_gate_sd)
        if not c.fuse_sideslip:
            return
        beta, ux, h = sideslip(dcm_from_quat(self._q), self._v, self._w)
        if ux > c.airspeed_min_m_s:
            r = c.sideslip_noise_rad ** 2
            obs = (_IDX_BETA, h, *self._innovation_variance(_IDX_BETA, h, r))
            self._scalar("sideslip", tv, 0.0, r, -beta, obs, c.sideslip_gate_sd)

    def _scalar(self, source: str, tv: float, z: float, r: float, innov: float, obs: tuple, gate: float,
                why: str | None = None) -> bool:
        """Gate, fuse, inject and report one scalar observation; ``obs`` is ``(idx, h, P h^T, s)`` and ``why``
        a check that failed before the gate."""
        idx, h, pht, s = obs
        ratio = innov * innov / (gate * gate * s)
        if why is None and not ratio <= 1.0:
            why = f"test ratio {ratio:.1f}"
        ok = why is None
        if ok:
            self._update(idx, h, pht, s, innov)
            self._inject()
        self._status(source, tv, np.array([z]), np.array([r]), np.array([innov]), np.array([s]), np.array([ratio]),
                     ok)
        health = self._health[source]
        self._note(health.fused(self._t_delayed) if ok else health.rejected(self._t_delayed, why))
        return ok

    def _status(self, source: str, tv: float, z, r, innov, s, ratio, fused: bool) -> None:
        st = AidSourceStatus(self._t_now, source, tv, z, r, innov, s, ratio, fused, not fused)
        self._statuses.append(st)
        self._latest[source] = st

    # ----------------------------------------------------------------------------------------------- mode, events

    def _update_mode(self) -> None:
        lost = self._t_delayed - self._last_gnss_fused_t > self.cfg.dead_reckoning_after_s
        if lost and self._mode == "aided":
            self._mode = "dead_reckoning"
            self._event(f"dead reckoning at t = {self._t_delayed:.2f} s: no GNSS fused for "
                        f"{self.cfg.dead_reckoning_after_s:.1f} s")
        elif not lost and self._mode == "dead_reckoning":
            self._mode = "aided"
            self._event(f"aided again at t = {self._t_delayed:.2f} s: GNSS fused (fix age "
                        f"{self._t_delayed - self._last_gnss_fix_t:.2f} s)")

    def _event(self, msg: str) -> None:
        self._events.append(f"ins: {msg}")

    def _note(self, msg: str | None) -> None:
        if msg is not None:
            self._event(msg)

    # ----------------------------------------------------------------------------------------------- initialisation

    def _align_step(self, k: int, s: ImuSample) -> None:
        """Before the first attitude: accumulate the in-motion alignment, initialise when it closes."""
        al, lim, c = self._align, s.t_s + 0.5 * s.dt_s, self.cfg
        if al.active:
            al.add_imu(s.delta_angle_frd_rad, s.delta_velocity_frd_m_s)
        q = self._queues
        while q["baro"] and q["baro"][0][0] <= lim:
            self._last_baro = q["baro"].popleft()
        while q["airspeed"] and q["airspeed"][0][0] <= lim:
            self._last_airspeed = q["airspeed"].popleft()
        while q["mag"] and q["mag"][0][0] <= lim:
            m = np.asarray(q["mag"].popleft()[1].field_frd_gauss, float)
            if al.active and abs(float(np.linalg.norm(m)) - c.mag_strength_gauss) <= c.mag_strength_tol_gauss:
                al.add_mag(m)
        while q["gnss"] and q["gnss"][0][0] <= lim and not self._initialised:
            tv, fix = q["gnss"].popleft()
            span = s.t_s - al.t0
            if not al.active or span > _ALIGN_RESTART_FACTOR * c.init_alignment_s:
                al.start(s.t_s, fix.vel_enu_m_s)
            elif span >= c.init_alignment_s - 0.5 * s.dt_s:
                solved = al.solve(s.t_s, fix.vel_enu_m_s, self._earth_field_enu)
                if solved is None:
                    al.start(s.t_s, fix.vel_enu_m_s)
                else:
                    self._initialise(k, s, tv, fix, *solved)

    def _initialise(self, k: int, s: ImuSample, tv: float, fix: GnssFix, R: np.ndarray, used_mag: bool) -> None:
        """The first state (at EKF sample ``k``) and an honest covariance; the output predictor caught up."""
        c = self.cfg
        self._q[:] = quat_from_dcm(R)
        self._v[:] = fix.vel_enu_m_s
        self._p[:] = np.asarray(fix.pos_enu_m, float) + self._v * (s.t_s - tv)
        self._bg[:], self._ba[:], self._bm[:], self._dx[:] = 0.0, 0.0, 0.0, 0.0
        yaw_std = math.radians(c.init_yaw_std_deg if used_mag else c.init_yaw_std_course_deg)
        if used_mag and c.mag_fusion == "field":  # an unknown hard iron turns the field's heading too
            yaw_std = math.hypot(yaw_std, c.init_mag_bias_std_gauss / math.hypot(*self._earth_field_enu[0:2]))
        tilt_var = math.radians(c.init_tilt_std_deg) ** 2
        sh, sv = max(fix.h_acc_m, c.gnss_pos_noise_min_m), max(fix.v_acc_m, c.gnss_pos_noise_min_m)
        ss = max(fix.s_acc_m_s, c.gnss_vel_noise_min_m_s)
        wind_var = self._initial_wind(R, yaw_std)
        self._x[18], baro_var = 0.0, 100.0 ** 2
        if self._last_baro is not None:
            self._x[18] = self._last_baro[1].height_m - float(self._p[2])
            baro_var = c.baro_noise_m ** 2 + sv * sv
        self._P[:, :] = 0.0
        self._Pdiag[:] = ([tilt_var, tilt_var, yaw_std ** 2] + [ss * ss] * 3 + [sh * sh, sh * sh, sv * sv]
                          + [c.init_gyro_bias_std_rad_s ** 2] * 3 + [c.init_accel_bias_std_m_s2 ** 2] * 3
                          + [wind_var] * 2 + [baro_var] + [c.init_mag_bias_std_gauss ** 2] * 3)
        self._initialised, self._mode = True, "aided"
        self._last_gnss_fused_t, self._last_gnss_fix_t = s.t_s, tv
        for h in self._health.values():
            h.last_fused_t = s.t_s
        self._out.reset(k, self._q, self._v, self._p)
        for j, later in self._imu_buf:  # the samples between the horizon and now
            dt = later.dt_s
            self._out.step(j, dt, later.delta_angle_frd_rad.tolist(), later.delta_velocity_frd_m_s.tolist())
        euler = np.degrees(euler_ned_from_dcm_enu_from_frd(R))
        self._event(f"initialised at t = {s.t_s:.2f} s by in-motion alignment, heading from the "
                    f"{'magnetometer' if used_mag else 'GNSS course'} (roll {euler[0]:.1f}, pitch {euler[1]:.1f}, "
                    f"yaw {euler[2]:.1f} deg)")

    def _initial_wind(self, R: np.ndarray, yaw_std_rad: float) -> float:
        """Wind from the newest airspeed and the heading (zero sideslip) if there is one; its variance."""
        self._w[:] = 0.0
        if self._last_airspeed is None or not self._last_airspeed[1].airspeed_m_s >= self.cfg.airspeed_min_m_s:
            return self.cfg.init_wind_std_m_s ** 2
        tas = self._last_airspeed[1].airspeed_m_s
        nose = R[:, 0]
        horiz = math.hypot(float(nose[0]), float(nose[1]))
        if horiz < 0.3:
            return self.cfg.init_wind_std_m_s ** 2
        tas_h = math.sqrt(max(tas * tas - float(self._v[2]) ** 2, 0.0))
        self._w[:] = self._v[0:2] - tas_h * nose[0:2] / horiz
        return self.cfg.airspeed_noise_m_s ** 2 + (tas_h * yaw_std_rad) ** 2
