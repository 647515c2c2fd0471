"""Sensor error models: the raw measurements a navigation filter is fed, made from the truth.

Each model turns ``AirframeState`` (or the gimbal's angles) into the shared messages of
fwsim.interface.messages (``ImuSample``, ``GnssFix``, ``BaroSample``, ``MagSample``,
``AirspeedSample``) with named error terms; settings and the ideal / typical / degraded
profiles are in fwsim.sensors.error_config (re-exported here), the sources of the typical
values and the test evidence in docs/design/sensor_errors.md.

Randomness: every error term of every model draws from its own generator,
``rng_for(seed, "errors/<model>/<term>")`` (fwsim.sensors.onboard), so switching one term
off, or adding a sensor, never changes another term's draws. A term whose size is zero draws
nothing and adds an exact zero: the ideal profile gives the truth to the last bit.

The error processes, each discretised exactly for a step dt (vectorised over axes):

* ``WhiteNoise``, density N (unit/sqrt(Hz)): the mean of the rate over dt has sigma
  N / sqrt(dt); its integral over dt (a delta angle or delta velocity) has sigma N sqrt(dt).
  ``SampledNoise``: white noise given directly as a sigma per sample (baro, mag, pitot...).
* ``RandomWalk``, density K (unit/s/sqrt(Hz)): x_k+1 = x_k + K sqrt(dt) w_k, w_k ~ N(0, 1).
* ``GaussMarkov``, correlation time tau, steady-state sigma s:
  x_k+1 = exp(-dt/tau) x_k + s sqrt(1 - exp(-2 dt/tau)) w_k, exact for any dt (variable dt
  allowed), the solution of dx/dt = -x/tau + sqrt(2 s^2/tau) w(t). Driven by a random-walk
  density K instead (``GaussMarkov.from_random_walk``, the Gazebo IMU plugin's form): s = K sqrt(tau/2).
* Constants drawn once at construction (``draw_constant``): turn-on biases, hard iron,
  scale factors; ``draw_misalignment``: the off-diagonal terms of a cross-coupling matrix M.
  A triad measures T u with T = (I + M) (I + diag(s)): s the scale factor errors, M the
  small-angle non-orthogonality and mounting misalignment (diagonal zero).

The models:

* ``ImuModel``, one sample per simulation step [t0, t1], dt = t1 - t0:
  delta_angle = T_g int(omega) + (b_g,on + b_g,in) dt + n_g, n_g ~ N(0, N_g^2 dt), and the same
  for delta_velocity with the specific force. int(.) is the trapezoid (u0 + u1) dt / 2 of the
  truth at the step's two ends (exact for a rate linear over the step; JSBSim gives no
  sub-step values). The in-run bias b_in (Gauss-Markov or random walk) is taken at the
  interval's end: it moves by about K sqrt(dt) within a step, far below the white noise.
* ``GnssModel``: fixes on the grid t0 + k / rate; a fix taken at time_of_fix (the truth's
  time) arrives at time_of_fix + latency (a queue). Position error: a Gauss-Markov process
  per axis (east and north share sigma and tau, up has its own), started from its stationary
  distribution and propagated exactly over the time between fixes (outages included), plus
  any injected jump; velocity: white noise per fix. h_acc, v_acc, s_acc: the configured
  position and horizontal velocity sigmas times ``accuracy_scale_ratio``. Faults:
  ``outage(active)``, ``jump(offset_enu_m)``.
* ``BaroModel``: height + Gauss-Markov drift (zero at power-on, when the altimeter is set)
  + white noise; fault ``drift_fault(rate_m_s)``: an offset growing at that rate from now on.
* ``MagModel``: the earth's field (fixed in NED: strength, inclination, declination)
  rotated into the body + hard-iron offset drawn once + white noise; fault
  ``interference(offset_frd_gauss)``: a body-frame offset held until changed.
* ``PitotModel``: airspeed + bias drawn once + white noise, floored at zero.
* ``EncoderModel``: gimbal pan and tilt + zero offsets drawn once + white noise.
* ``CameraMountError``: data only, the camera as built: a small boresight rotation and a
  focal-length scale, with the rotation matrix they make (not yet wired into the camera).

Sampled sensors hold a rate clock like the onboard sensors: ``step`` returns a sample when
one is due and None otherwise. Nothing here is wired into the simulation loop.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from fwsim.interface.frames import dcm_ned_from_frd
from fwsim.interface.messages import AirframeState, AirspeedSample, BaroSample, GnssFix, ImuSample, MagSample
from fwsim.sensors.error_config import (
    PROFILES, AccelErrorsConfig, BaroErrorsConfig, CameraMountErrorsConfig, EncoderErrorsConfig, GnssErrorsConfig,
    GyroErrorsConfig, ImuErrorsConfig, MagErrorsConfig, PitotErrorsConfig, SensorErrorsConfig, degraded, ideal,
    resolve, typical)
from fwsim.sensors.onboard import rng_for

__all__ = [
    "WhiteNoise", "SampledNoise", "RandomWalk", "GaussMarkov", "draw_constant", "draw_misalignment",
    "scale_misalignment_matrix", "ImuModel", "GnssModel", "BaroModel", "MagModel", "PitotModel", "EncoderModel",
    "EncoderSample", "CameraMountError", "SensorErrorModels",
    # settings (fwsim.sensors.error_config)
    "SensorErrorsConfig", "ImuErrorsConfig", "GyroErrorsConfig", "AccelErrorsConfig", "GnssErrorsConfig",
    "BaroErrorsConfig", "MagErrorsConfig", "PitotErrorsConfig", "EncoderErrorsConfig", "CameraMountErrorsConfig",
    "PROFILES", "ideal", "typical", "degraded", "resolve",
]

_EPS_T = 1e-9  # time comparisons (s): a sample due at t is taken at a step that lands within this of t


def _axes(value, n: int) -> np.ndarray:
    """A float array of shape (n,) from a scalar or an (n,) sequence (a copy)."""
    return np.array(np.broadcast_to(np.asarray(value, dtype=float), (n,)))


def _rng(seed: int, model: str, term: str) -> np.random.Generator:
    return rng_for(seed, f"errors/{model}/{term}")


# --------------------------------------------------------------------------- error processes


class _Gaussian:
    """Standard normal draws of shape (n,) or (steps, n) from one generator; none when disabled."""

    def __init__(self, rng: np.random.Generator, n: int, enabled: bool):
        self.rng, self.n, self.enabled = rng, n, enabled

    def _normal(self, steps: int | None) -> np.ndarray:
        shape = (self.n,) if steps is None else (steps, self.n)
        return self.rng.standard_normal(shape) if self.enabled else np.zeros(shape)


class WhiteNoise(_Gaussian):
    """White Gaussian noise of a continuous density (unit/sqrt(Hz)) on n axes."""

    def __init__(self, density, rng: np.random.Generator, n: int = 3):
        self.density = _axes(density, n)
        super().__init__(rng, n, bool(np.any(self.density)))

    def rate(self, dt_s: float, steps: int | None = None) -> np.ndarray:
        """Noise on the mean rate over dt: sigma = density / sqrt(dt). Shape (n,), or (steps, n)."""
        return self.density / math.sqrt(dt_s) * self._normal(steps)

    def integrated(self, dt_s: float, steps: int | None = None) -> np.ndarray:
        """Noise on the integral over dt (a delta angle or velocity): sigma = density * sqrt(dt)."""
        return self.density * math.sqrt(dt_s) * self._normal(steps)


class SampledNoise(_Gaussian):
    """White Gaussian noise given as a standard deviation per sample, on n axes."""

    def __init__(self, sigma, rng: np.random.Generator, n: int = 3):
        self.sigma = _axes(sigma, n)
        super().__init__(rng, n, bool(np.any(self.sigma)))

    def draw(self, steps: int | None = None) -> np.ndarray:
        """One sample (n,), or ``steps`` samples (steps, n)."""
        return self.sigma * self._normal(steps)


class RandomWalk(_Gaussian):
    """A random walk of density K (unit/s/sqrt(Hz)): x_k+1 = x_k + K sqrt(dt) w_k, from ``x0``."""

    def __init__(self, density, rng: np.random.Generator, n: int = 3, x0=0.0):
        self.density = _axes(density, n)
        self.value = _axes(x0, n)
        super().__init__(rng, n, bool(np.any(self.density)))

    def propagate(self, dt_s: float, steps: int | None = None) -> np.ndarray:
        """Move on by ``steps`` steps of dt (one when None); the values after each step, (n,) or (steps, n)."""
        if not self.enabled:
            return self.value.copy() if steps is None else np.tile(self.value, (steps, 1))
        inc = self.density * math.sqrt(dt_s) * self._normal(steps)
        if steps is None:
            self.value = self.value + inc
            return self.value.copy()
        path = np.cumsum(np.concatenate([self.value[None, :], inc]), axis=0)[1:]  # sequential sums, as step by step
        self.value = path[-1].copy()
        return path


class GaussMarkov(_Gaussian):
    """First-order Gauss-Markov process per axis: correlation time tau (s), steady-state sigma.

    x_k+1 = phi x_k + q w_k with phi = exp(-dt/tau), q = sigma sqrt(1 - exp(-2 dt/tau)): exact
    for any step dt. Starts at zero, or (``stationary_start``) at a draw from N(0, sigma^2).
    """

    def __init__(self, tau_s, sigma, rng: np.random.Generator, n: int = 3, stationary_start: bool = False):
        self.tau_s, self.sigma = _axes(tau_s, n), _axes(sigma, n)
        if np.any(self.tau_s <= 0.0):
            raise ValueError(f"GaussMarkov: tau_s must be > 0, got {self.tau_s}")
        super().__init__(rng, n, bool(np.any(self.sigma)))
        self.value = self.sigma * self._normal(None) if stationary_start else np.zeros(n)
        self._dt = math.nan
        self._phi = self._q = np.zeros(n)

    @classmethod
    def from_random_walk(cls, density, tau_s, rng: np.random.Generator, n: int = 3,
                         stationary_start: bool = False) -> GaussMarkov:
        """The process driven by white noise of density K (dx/dt = -x/tau + K w): sigma = K sqrt(tau / 2)."""
        sigma = _axes(density, n) * np.sqrt(_axes(tau_s, n) / 2.0)
        return cls(tau_s, sigma, rng, n, stationary_start)

    def _coefficients(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        if dt_s != self._dt:
            self._dt = dt_s
            self._phi = np.exp(-dt_s / self.tau_s)
            self._q = self.sigma * np.sqrt(-np.expm1(-2.0 * dt_s / self.tau_s))
        return self._phi, self._q

    def propagate(self, dt_s: float, steps: int | None = None) -> np.ndarray:
        """Move on by ``steps`` steps of dt (one when None); the values after each step, (n,) or (steps, n)."""
        if not self.enabled:
            return self.value.copy() if steps is None else np.tile(self.value, (steps, 1))
        phi, q = self._coefficients(dt_s)
        w = self._normal(steps)
        if steps is None:
            self.value = phi * self.value + q * w
            return self.value.copy()
        from scipy.signal import lfilter  # (only the batch path needs it)

        path = np.empty_like(w)
        for i in range(self.n):  # y_k = q w_k + phi y_k-1, with y_-1 the current value
            path[:, i] = lfilter([q[i]], [1.0, -phi[i]], w[:, i], zi=[phi[i] * self.value[i]])[0]
        self.value = path[-1].copy()
        return path


def draw_constant(sigma, rng: np.random.Generator, n: int = 3) -> np.ndarray:
    """A constant drawn once from N(0, sigma^2) per axis (turn-on bias, hard iron, scale factor...)."""
    s = _axes(sigma, n)
    return s * rng.standard_normal(n) if np.any(s) else np.zeros(n)


def draw_misalignment(sigma: float, rng: np.random.Generator) -> np.ndarray:
    """A 3x3 cross-coupling matrix drawn once: off-diagonal terms from N(0, sigma^2), diagonal zero."""
    m = np.zeros((3, 3))
    if sigma > 0.0:
        off = ~np.eye(3, dtype=bool)
        m[off] = sigma * rng.standard_normal(6)
    return m


def scale_misalignment_matrix(scale, misalignment) -> np.ndarray:
    """T = (I + M) (I + diag(s)): what a triad with scale errors s and cross-coupling M makes of a vector."""
    return (np.eye(3) + np.asarray(misalignment, dtype=float)) @ np.diag(1.0 + _axes(scale, 3))


def _in_run_bias(model: str, density: float, tau_s: float, rng: np.random.Generator) -> GaussMarkov | RandomWalk:
    if model == "gauss_markov":
        return GaussMarkov.from_random_walk(density, tau_s, rng)
    return RandomWalk(density, rng)


class _Clock:
    """Samples on the grid t0 + k / rate (t0: the first call's time); ``due(t)`` once per grid point reached."""

    def __init__(self, rate_hz: float):
        self.period = 1.0 / rate_hz
        self._t0: float | None = None
        self._k = 0

    def due(self, t_s: float) -> bool:
        if self._t0 is None:
            self._t0, self._k = t_s, 1
            return True
        if t_s + _EPS_T < self._t0 + self._k * self.period:
            return False
        self._k = int((t_s + _EPS_T - self._t0) / self.period) + 1  # a late call skips the points it missed
        return True


# --------------------------------------------------------------------------- IMU


class _Triad:
    """One triad (gyros or accelerometers): its error terms and what they make of an integrated truth."""

    def __init__(self, density: float, bias_model: str, bias_density: float, bias_tau_s: float,
                 turn_on_sigma: float, scale_sigma: float, misalignment_sigma: float, seed: int, name: str):
        self.noise = WhiteNoise(density, _rng(seed, name, "noise"))
        self.in_run = _in_run_bias(bias_model, bias_density, bias_tau_s, _rng(seed, name, "bias"))
        self.turn_on = draw_constant(turn_on_sigma, _rng(seed, name, "turn_on_bias"))
        self.matrix = scale_misalignment_matrix(draw_constant(scale_sigma, _rng(seed, name, "scale_factor")),
                                                draw_misalignment(misalignment_sigma, _rng(seed, name, "misalignment")))
        self._identity = bool(np.array_equal(self.matrix, np.eye(3)))

    def deltas(self, integral: np.ndarray, dt_s: float, steps: int | None = None) -> np.ndarray:
        """Measured increments from the truth's integrals over dt ((3,), or (steps, 3))."""
        bias = self.turn_on + self.in_run.propagate(dt_s, steps)
        measured = integral if self._identity else integral @ self.matrix.T
        return measured + bias * dt_s + self.noise.integrated(dt_s, steps)


class ImuModel:
    """Gyro and accelerometer triads: ``ImuSample`` deltas from the truth, one per simulation step.

    ``step(truth)`` takes the truth at each step and returns the sample over the interval since
    the previous call (None on the first call). ``integrate`` does the same for whole arrays at
    once (stationary runs, Allan deviation): it draws the same numbers in the same order.
    """

    def __init__(self, cfg: ImuErrorsConfig, seed: int, name: str = "imu"):
        g, a = cfg.gyro, cfg.accel
        self.cfg = cfg
        self.gyro = _Triad(g.noise_density_rad_s_sqrt_hz, g.bias_model, g.bias_random_walk_rad_s2_sqrt_hz,
                           g.bias_tau_s, g.turn_on_bias_sigma_rad_s, g.scale_factor_sigma_frac,
                           g.misalignment_sigma_rad, seed, f"{name}/gyro")
        self.accel = _Triad(a.noise_density_m_s2_sqrt_hz, a.bias_model, a.bias_random_walk_m_s3_sqrt_hz,
                            a.bias_tau_s, a.turn_on_bias_sigma_m_s2, a.scale_factor_sigma_frac,
                            a.misalignment_sigma_rad, seed, f"{name}/accel")
        self._prev: tuple[float, np.ndarray, np.ndarray] | None = None

    @property
    def gyro_bias_frd_rad_s(self) -> np.ndarray:
        """The gyros' true bias now (turn-on + in-run), what a filter's bias estimate should converge to."""
        return self.gyro.turn_on + self.gyro.in_run.value

    @property
    def accel_bias_frd_m_s2(self) -> np.ndarray:
        """The accelerometers' true bias now (turn-on + in-run)."""
        return self.accel.turn_on + self.accel.in_run.value

    def step(self, truth: AirframeState) -> ImuSample | None:
        """The IMU sample over [previous call's t_s, truth.t_s]; None on the first call."""
        t = float(truth.t_s)
        w = np.array(truth.body_rates_frd_rad_s, dtype=float)
        f = np.array(truth.specific_force_frd_m_s2, dtype=float)
        prev, self._prev = self._prev, (t, w, f)
        if prev is None:
            return None
        dt = t - prev[0]
        if not dt > 0.0:
            raise ValueError(f"ImuModel.step: time must increase (got {prev[0]} then {t})")
        half = 0.5 * dt
        return ImuSample(t, dt, self.gyro.deltas((prev[1] + w) * half, dt),
                         self.accel.deltas((prev[2] + f) * half, dt))

    def integrate(self, dt_s: float, body_rates_frd_rad_s: np.ndarray,
                  specific_force_frd_m_s2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Delta angles and delta velocities ((N, 3) each) from the truth at N + 1 instants dt apart ((N + 1, 3))."""
        w = np.asarray(body_rates_frd_rad_s, dtype=float)
        f = np.asarray(specific_force_frd_m_s2, dtype=float)
        if w.shape != f.shape or w.ndim != 2 or w.shape[1] != 3 or w.shape[0] < 2:
            raise ValueError(f"ImuModel.integrate: want two (N + 1, 3) arrays, N >= 1; got {w.shape}, {f.shape}")
        steps, half = w.shape[0] - 1, 0.5 * dt_s
        return (self.gyro.deltas((w[:-1] + w[1:]) * half, dt_s, steps),
                self.accel.deltas((f[:-1] + f[1:]) * half, dt_s, steps))


# --------------------------------------------------------------------------- GNSS


class GnssModel:
    """GNSS receiver: fixes at a rate, each arriving ``latency_s`` after its time of fix.

    ``step(truth)`` is called at every simulation step and returns the fixes that arrived by
    ``truth.t_s`` (usually none or one), oldest first.
    """

    def __init__(self, cfg: GnssErrorsConfig, seed: int, name: str = "gnss"):
        h, v = cfg.pos_horizontal_sigma_m, cfg.pos_vertical_sigma_m
        th, tv = cfg.pos_horizontal_tau_s, cfg.pos_vertical_tau_s
        vh, vv = cfg.vel_horizontal_sigma_m_s, cfg.vel_vertical_sigma_m_s
        self.cfg = cfg
        self._pos_error = GaussMarkov([th, th, tv], [h, h, v], _rng(seed, name, "position"), stationary_start=True)
        self._vel_noise = SampledNoise([vh, vh, vv], _rng(seed, name, "velocity"))
        s = cfg.accuracy_scale_ratio
        self._accuracy = (s * h, s * v, s * vh)
        self._clock = _Clock(cfg.rate_hz)
        self._queue: deque[GnssFix] = deque()
        self._jump = np.zeros(3)
        self._outage = False
        self._last_fix_t: float | None = None

    @property
    def position_error_enu_m(self) -> np.ndarray:
        """The error a fix taken now would carry (Gauss-Markov part at the last fix, plus any jump)."""
        return self._pos_error.value + self._jump

    def outage(self, active: bool) -> None:
        """Start (True) or end (False) an outage: no fix is taken or delivered meanwhile (those in flight are lost)."""
        self._outage = bool(active)
        if self._outage:
            self._queue.clear()

    def jump(self, offset_enu_m) -> None:
        """Add a step to the position error of every fix taken from now on (jumps add up; undo with the negative)."""
        self._jump = self._jump + _axes(offset_enu_m, 3)

    def _take_fix(self, truth: AirframeState) -> GnssFix:
        t = float(truth.t_s)
        if self._last_fix_t is not None:
            self._pos_error.propagate(t - self._last_fix_t)
        self._last_fix_t = t
        pos = np.asarray(truth.pos_enu_m, dtype=float) + (self._pos_error.value + self._jump)
        vel = np.asarray(truth.vel_enu_m_s, dtype=float) + self._vel_noise.draw()
        h_acc, v_acc, s_acc = self._accuracy
        return GnssFix(t + self.cfg.latency_s, t, pos, vel, h_acc, v_acc, s_acc)

    def step(self, truth: AirframeState) -> list[GnssFix]:
        """Take a fix if one is due (not in an outage); return the fixes whose arrival time has come."""
        t = float(truth.t_s)
        if self._clock.due(t) and not self._outage:
            self._queue.append(self._take_fix(truth))
        out = []
        while self._queue and self._queue[0].t_s <= t + _EPS_T:
            out.append(self._queue.popleft())
        return out


# --------------------------------------------------------------------------- baro, mag, pitot, encoders


class BaroModel:
    """Barometric altimeter: height + Gauss-Markov drift (zero at power-on) + white noise + injected drift."""

    def __init__(self, cfg: BaroErrorsConfig, seed: int, name: str = "baro"):
        self.cfg = cfg
        self._noise = SampledNoise(cfg.noise_sigma_m, _rng(seed, name, "noise"), n=1)
        self._drift = GaussMarkov(cfg.drift_tau_s, cfg.drift_sigma_m, _rng(seed, name, "drift"), n=1)
        self._clock = _Clock(cfg.rate_hz)
        self._last_sample_t: float | None = None
        self._now: float | None = None
        self._fault_rate_m_s = 0.0
        self._fault_m = 0.0
        self._fault_t: float | None = None  # time up to which the injected drift has been added up

    @property
    def drift_m(self) -> float:
        """The height error now, noise aside (natural drift at the last sample + injected drift)."""
        return float(self._drift.value[0]) + self._fault_m

    def _accrue(self, t_s: float) -> None:
        if self._fault_t is not None:
            self._fault_m += self._fault_rate_m_s * (t_s - self._fault_t)
        self._fault_t = t_s

    def drift_fault(self, rate_m_s: float) -> None:
        """From now on (the last step's time) the height error also grows at ``rate_m_s``; 0 stops it (it stays)."""
        if self._now is not None:
            self._accrue(self._now)
        self._fault_rate_m_s = float(rate_m_s)

    def step(self, truth: AirframeState) -> BaroSample | None:
        """A height sample when one is due (call at every simulation step), else None."""
        t = float(truth.t_s)
        self._now = t
        if not self._clock.due(t):
            return None
        if self._last_sample_t is not None:
            self._drift.propagate(t - self._last_sample_t)
        self._last_sample_t = t
        self._accrue(t)
        err = float(self._drift.value[0]) + self._fault_m + float(self._noise.draw()[0])
        return BaroSample(t, float(truth.height_above_sea_m) + err)


class MagModel:
    """Magnetometer: the earth's field rotated into the body + hard iron + white noise + injected interference."""

    def __init__(self, cfg: MagErrorsConfig, seed: int, name: str = "mag"):
        inc, dec = math.radians(cfg.inclination_deg), math.radians(cfg.declination_deg)
        f = cfg.field_strength_gauss
        self.cfg = cfg
        #: the earth's field in NED (gauss): north, east, down
        self.earth_field_ned_gauss = np.array([f * math.cos(inc) * math.cos(dec), f * math.cos(inc) * math.sin(dec),
                                               f * math.sin(inc)])
        #: the hard-iron offset drawn at construction (body FRD, gauss)
        self.hard_iron_frd_gauss = draw_constant(cfg.hard_iron_sigma_gauss, _rng(seed, name, "hard_iron"))
        self._noise = SampledNoise(cfg.noise_sigma_gauss, _rng(seed, name, "noise"))
        self._interference = np.zeros(3)
        self._clock = _Clock(cfg.rate_hz)

    def interference(self, offset_frd_gauss) -> None:
        """A body-frame offset (gauss) on every sample from now on, until set again (zeros: none)."""
        self._interference = _axes(offset_frd_gauss, 3)

    def step(self, truth: AirframeState) -> MagSample | None:
        """A body-frame field sample when one is due (call at every simulation step), else None."""
        t = float(truth.t_s)
        if not self._clock.due(t):
            return None
        field = dcm_ned_from_frd(truth.euler_ned_rad).T @ self.earth_field_ned_gauss
        return MagSample(t, field + self.hard_iron_frd_gauss + self._interference + self._noise.draw())


class PitotModel:
    """Pitot airspeed: true airspeed + bias drawn once + white noise, floored at zero."""

    def __init__(self, cfg: PitotErrorsConfig, seed: int, name: str = "pitot"):
        self.cfg = cfg
        self.bias_m_s = float(draw_constant(cfg.bias_sigma_m_s, _rng(seed, name, "bias"), n=1)[0])
        self._noise = SampledNoise(cfg.noise_sigma_m_s, _rng(seed, name, "noise"), n=1)
        self._clock = _Clock(cfg.rate_hz)

    def step(self, truth: AirframeState) -> AirspeedSample | None:
        """An airspeed sample when one is due (call at every simulation step), else None."""
        t = float(truth.t_s)
        if not self._clock.due(t):
            return None
        v = float(truth.airspeed_m_s) + self.bias_m_s + float(self._noise.draw()[0])
        return AirspeedSample(t, max(v, 0.0))


@dataclass(frozen=True, slots=True)
class EncoderSample:
    """The gimbal encoders' pan and tilt (rad) at ``t_s``."""

    t_s: float
    pan_rad: float
    tilt_rad: float


class EncoderModel:
    """Gimbal pan and tilt encoders: angle + zero offset drawn once + white noise."""

    def __init__(self, cfg: EncoderErrorsConfig, seed: int, name: str = "encoders"):
        self.cfg = cfg
        #: pan and tilt zero offsets drawn at construction (rad)
        self.bias_rad = draw_constant(cfg.bias_sigma_rad, _rng(seed, name, "bias"), n=2)
        self._noise = SampledNoise(cfg.noise_sigma_rad, _rng(seed, name, "noise"), n=2)
        self._clock = _Clock(cfg.rate_hz)

    def step(self, t_s: float, pan_rad: float, tilt_rad: float) -> EncoderSample | None:
        """Pan and tilt readings of the true joint angles when due, else None."""
        if not self._clock.due(float(t_s)):
            return None
        e = self.bias_rad + self._noise.draw()
        return EncoderSample(float(t_s), float(pan_rad) + float(e[0]), float(tilt_rad) + float(e[1]))


# --------------------------------------------------------------------------- camera mount


@dataclass(frozen=True)
class CameraMountError:
    """The camera as built against the nominal one (camera frame: z optical axis, x right, y down).

    ``boresight_cam_rad``: rotation vector (axis times angle, in the nominal camera frame) that
    turns the nominal camera frame into the actual one; ``focal_scale``: actual focal length /
    nominal. Wiring (later): ``R_frd_from_cam_actual = R_frd_from_cam(pan, tilt) @
    dcm_nominal_from_actual()``, and the camera renders with ``focal_scale`` times the focal
    length the flight software assumes.
    """

    boresight_cam_rad: np.ndarray  # (3,)
    focal_scale: float

    @classmethod
    def draw(cls, cfg: CameraMountErrorsConfig, seed: int, name: str = "camera_mount") -> CameraMountError:
        """Boresight angles and focal error drawn once from the config's sigmas."""
        rot = draw_constant(cfg.boresight_sigma_rad, _rng(seed, name, "boresight"))
        scale = draw_constant(cfg.focal_scale_sigma_frac, _rng(seed, name, "focal_scale"), n=1)
        return cls(rot, 1.0 + float(scale[0]))

    def dcm_nominal_from_actual(self) -> np.ndarray:
        """R_nominal_from_actual = exp([rho]x) (Rodrigues): a vector in the actual camera frame, in the nominal one."""
        rho = np.asarray(self.boresight_cam_rad, dtype=float)
        angle = float(np.linalg.norm(rho))
        if angle == 0.0:
            return np.eye(3)
        k = rho / angle
        kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        return np.eye(3) + math.sin(angle) * kx + (1.0 - math.cos(angle)) * (kx @ kx)


# --------------------------------------------------------------------------- all of them


@dataclass
class SensorErrorModels:
    """Every error model of one configuration and seed (each drawing from its own generators)."""

    imu: ImuModel
    gnss: GnssModel
    baro: BaroModel
    mag: MagModel
    pitot: PitotModel
    encoders: EncoderModel
    camera_mount: CameraMountError

    @classmethod
    def build(cls, cfg: SensorErrorsConfig, seed: int) -> SensorErrorModels:
        """Each model under its default name, all from one seed."""
        return cls(ImuModel(cfg.imu, seed), GnssModel(cfg.gnss, seed), BaroModel(cfg.baro, seed),
                   MagModel(cfg.mag, seed), PitotModel(cfg.pitot, seed), EncoderModel(cfg.encoders, seed),
                   CameraMountError.draw(cfg.camera_mount, seed))
