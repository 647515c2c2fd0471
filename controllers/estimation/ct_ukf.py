"""Target estimation for manoeuvring ships: the paper's UKF with the ship's turn rate and along-track acceleration.

The paper's UKF (:mod:`controllers.estimation.ukf`) models the ship at constant velocity. A
ship that turns (up to ~1.5 deg/s), zigzags or changes speed (~0.5 m/s^2) is
then followed with a lag: the velocity trails the turn by the filter's time
constant, and the position by the velocity's error times that. This filter
keeps everything of the UKF (image features, measurement model, noise, gate,
start, the life cycle) and adds two states to the ship's motion.

State ``x = [x1, x2, r_q (3), V_q (3), omega (rad/s), a (m/s^2)]`` (10):

  * ``x1, x2, r_q, V_q`` as in the UKF;
  * ``omega``: the turn rate of the ship's course, about world up (ENU z,
    counter-clockwise positive: minus the ship's heading rate);
  * ``a``: its acceleration along its track (the speed's rate).

Process model (continuous, RK4 over each predict, as the UKF's)::

    x1_dot, x2_dot     = the UKF's feature kinematics (controllers.estimation.ukf._sx_feature_rates, shared)
    r_q_dot            = V_q
    V_q_dot            = omega e_z x V_q + a V_q / max(|V_q,h|, min_speed_m_s)     (horizontal)
    omega_dot          = -omega (1 / turn_rate_time_s + f / fade_time_s)   + white noise
    a_dot              = -a (1 / accel_time_s + f / fade_time_s)           + white noise
    f                  = max(0, 1 - |V_q,h| / fade_speed_m_s)   (0 when fade_speed_m_s = 0)

i.e. a coordinated turn with a varying speed ("CTRA"), turn rate and
acceleration each a first-order Gauss-Markov process with std
``turn_rate_std_deg_s`` / ``accel_std_m_s2`` in the long run. Why this and not
an IMM of a CV and a CT model: a zigzag or a helm order is a continuous
change of the turn rate, which one mean-reverting state follows without a
mode switch; a straight-running ship has omega, a ~ 0, where the model is the
UKF's CV model and the extra states cost little (tests: not worse than the
UKF on a straight line). On ships unlike the class they cost more: the box
centres' errors make the turn rate wander on a straight ship (envelope, seed
1648: velocity error in the loiter 0.48 m/s at the median run against the
UKF's 0.16), which :mod:`controllers.estimation.imm` (an IMM of the two) avoids.
Paper missions (seeds 21, 22; tuned on 11-13), UKF -> this: a 1.5 deg/s
turn, miss 3.35/2.90 -> 0.75/2.19 m, estimate error at impact 6.4/5.2 ->
0.8/2.9 m; speed steps at 0.5 m/s^2, loiter position error 2.6/2.7 ->
0.7/0.8 m RMS (miss ~0.9 m either way); a +-30 deg, 60 s zigzag, no better
(miss ~6 m either way: the turn rate changes within the dive); a straight
line, loiter error 0.41/0.53 -> 0.65/0.76 m (all hit).

The hold (``hold_tgo_s``). Extra states make the velocity less stiff: a
burst of biased box centres (the dive's fast-changing view; a detection the
perception passes after a run of skipped ones) is taken for a turn or a
speed change, and the last seconds, which coast without detections, fly it
out (paper missions: the estimate 5-10 m off at impact, against ~2 m for the
UKF). So while the camera closes on the ship within ``hold_tgo_s`` (a dive,
not a loiter: there the range holds), the manoeuvre learnt in the loiter is
held: the turn rate kept (a ship holds its rudder for a turn's time), the
acceleration set to zero (a speed change ends at the ordered speed within
seconds; extrapolated through a dive it overshoots), and their uncertainty
set aside, so the filter is the UKF on a turning track. Released (with the
covariance it had) when the camera recedes.

The fade (``manoeuvre_fade_speed_m_s``, ``manoeuvre_fade_time_s``). A turn rate
turns the velocity and an acceleration moves it along itself, so near zero speed
neither moves anything: the detections cannot correct them, and a deceleration
makes zero speed an attractor (``V_q_dot = (a / min_speed) V_q``). A slow ship's
estimate that fell to zero speed with a < 0 stayed there for tens of seconds
(envelope, seed 1602: 0.0-0.3 m/s against 1.8 m/s true, the turn rate wandering to
5 deg/s), and the loiter chased it. Below the fade speed both states also revert
to zero within about the fade time, fully at rest: a slow ship is the UKF's
constant-velocity ship.

Process noise over dt: the UKF's (feature random walk, white-noise
acceleration on r_q / V_q with ``target_accel_noise_m_s2`` horizontally) plus
``std^2 (1 - exp(-2 dt / T))`` on omega and a (the exact discrete
Gauss-Markov variance).

Measurement: the UKF's, unchanged (``z = [u, v, r_c]``, pinhole + flat-sea
depth, paper eq. 9; the compiled update :class:`controllers.estimation.ukf._CompiledUpdate`
works on any state that starts ``[x1, x2, r_q, ...]``).

Output: a :class:`ManoeuvreEstimate` (a :class:`~controllers.messages.TargetEstimate`
with the turn rate and acceleration and their stds; it is logged on
``/fsw/estimate`` with those fields added), and :func:`controllers.ship_motion.predict_ctra`, the
ship's predicted position and velocity ahead along the turn, for a guidance
law that wants the ship's future rather than its present velocity.

Nothing here imports the truth side of the harness (docs/design/architecture.md, "Two rules").
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controllers.config import CtUkfConfig, UkfConfig
from controllers.estimation.ukf import UkfTargetEstimator, _CompiledProcess, _process_noise_of
from controllers.messages import TargetEstimate
from controllers.navigation.camera_model import PinholeCamera, closing_time_s, held_while_closing
from controllers.ship_motion import predict_ctra

__all__ = ["CtUkfConfig", "CtUkfTargetEstimator", "ManoeuvreEstimate"]

#: the indices of the two states beyond the UKF's eight
I_TURN, I_ACCEL = 8, 9


@dataclass(frozen=True, slots=True)
class ManoeuvreEstimate(TargetEstimate):
    """A :class:`TargetEstimate` with the ship's manoeuvre: the turn rate of its course (ENU, counter-clockwise
    positive, i.e. minus the heading rate) and its acceleration along its track, with their stds.

    Every consumer of ``TargetEstimate`` reads it as one (the fields are added at the end)."""

    turn_rate_rad_s: float = math.nan
    turn_rate_std_rad_s: float = math.nan
    accel_along_m_s2: float = math.nan
    accel_along_std_m_s2: float = math.nan
    manoeuvre_held: bool = False  # the manoeuvre is held (hold_tgo_s): the held states' stds are as when held


class _CtProcess(_CompiledProcess):
    """The process model of :class:`CtUkfTargetEstimator`, compiled: the UKF's RK4 and feature rates
    (:class:`controllers.estimation.ukf._CompiledProcess`) with the coordinated turn and along-track acceleration.
    ``params = (turn_rate_time_s, accel_time_s, min_speed_m_s)``."""

    dim_x = 10
    function_name = "ct_ukf_rk4_step"
    _cache: dict[tuple, "_CtProcess"] = {}

    @staticmethod
    def _target_rates(Xs, m: int, turn_rate_time_s: float, accel_time_s: float, min_speed_m_s: float,
                      fade_speed_m_s: float = 0.0, fade_time_s: float = math.inf):
        """``[r_q_dot, V_q_dot, omega_dot, a_dot]`` (SX (m, 8)): the module's process model."""
        import casadi as ca
        vx, vy = Xs[:, 5], Xs[:, 6]
        w, a = Xs[:, I_TURN], Xs[:, I_ACCEL]
        speed = ca.sqrt(vx * vx + vy * vy)
        a_per_speed = a / ca.fmax(speed, min_speed_m_s)
        kw, ka = 1.0 / turn_rate_time_s, 1.0 / accel_time_s
        if fade_speed_m_s > 0.0 and math.isfinite(fade_time_s):
            fade = ca.fmax(0.0, 1.0 - speed / fade_speed_m_s) / fade_time_s
            kw, ka = kw + fade, ka + fade
        return ca.horzcat(Xs[:, 5:8], -w * vy + a_per_speed * vx, w * vx + a_per_speed * vy, ca.SX.zeros(m, 1),
                          -w * kw, -a * ka)


def fx_ct_batch(S: np.ndarray, dt: float, r_c0, R_ec0, V_c, omega, max_step: float, turn_rate_time_s: float,
                accel_time_s: float, min_speed_m_s: float, fade_speed_m_s: float = 0.0,
                fade_time_s: float = math.inf) -> np.ndarray:
    """The sigma points ``S`` (m, 10) over dt (:class:`_CtProcess`)."""
    return _CtProcess.for_points(len(S), turn_rate_time_s, accel_time_s, min_speed_m_s, fade_speed_m_s,
                                 fade_time_s)(S, dt, r_c0, R_ec0, V_c, omega, max_step)


def ct_process_noise(dt: float, ukf_cfg: UkfConfig, cfg: CtUkfConfig, held: tuple[int, ...] = ()) -> np.ndarray:
    """Q over dt (10 x 10): the UKF's with ``cfg.target_accel_noise_m_s2`` horizontally, and the exact discrete
    Gauss-Markov variances of the turn rate and the acceleration (those whose index is in ``held``: of their
    held stds, :data:`HELD_STD_FRACTION` of the model's)."""
    Q = np.zeros((10, 10))
    Q[:8, :8] = _process_noise_of(dt, ukf_cfg.model_copy(update={"target_accel_noise_m_s2":
                                                                 cfg.target_accel_noise_m_s2}))
    for i, std, tau in ((I_TURN, math.radians(cfg.turn_rate_std_deg_s), cfg.turn_rate_time_s),
                        (I_ACCEL, cfg.accel_std_m_s2, cfg.accel_time_s)):
        f = HELD_STD_FRACTION if i in held else 1.0
        Q[i, i] = (f * std) ** 2 * -math.expm1(-2.0 * dt / tau)
    return Q


#: a held turn rate / acceleration keeps this fraction of its model std (not zero: the sigma points need a
#: positive definite covariance), without correlation to the other states
HELD_STD_FRACTION = 1e-3


class CtUkfTargetEstimator(UkfTargetEstimator):
    """The UKF with the ship's turn rate and along-track acceleration (``controllers.estimator: ct_ukf``).

    It implements ``controllers.blocks.TargetEstimator`` as the UKF does (it is one: the life cycle, the
    measurement update, the gate and the counters are the UKF's); only the ship's motion model differs (the
    module text). ``ukf_config`` gives the measurement model and the start, ``config`` the motion model.
    """

    name = "ct_ukf"
    label = "CT-UKF"  # its name in the flight software's events
    dim_x = 10
    estimates_pointing_bias = False  # its states 8 and 9 are the turn rate and the acceleration

    def __init__(self, camera: PinholeCamera, ukf_config: UkfConfig | None = None,
                 config: CtUkfConfig | None = None):
        self.ct_cfg = config if config is not None else CtUkfConfig()
        super().__init__(camera, ukf_config)
        c = self.ct_cfg
        self._params = (c.turn_rate_time_s, c.accel_time_s, c.min_speed_m_s, c.manoeuvre_fade_speed_m_s,
                        c.manoeuvre_fade_time_s)
        self._q_key: tuple[float, bool] | None = None
        self._q = np.zeros((10, 10))
        self._held_cov: np.ndarray | None = None  # the held states' covariance when they were held, else None
        self._hold_idx = (I_TURN, I_ACCEL) if c.hold_turn_rate else (I_ACCEL,)  # the states a hold holds
        self.holds = 0  # how often the manoeuvre was held (hold_tgo_s)

    # ------------------------------------------------------------ the target model
    def _fx(self, S, dt, r_c0, R_ec0, V_c, omega, max_step):
        return fx_ct_batch(S, dt, r_c0, R_ec0, V_c, omega, max_step, *self._params)

    def _process_noise(self, dt: float) -> np.ndarray:
        key = (dt, self.held)
        if key != self._q_key:  # the flight software's period: the same dt almost every call
            self._q_key, self._q = key, ct_process_noise(dt, self.cfg, self.ct_cfg, self.held_states)
        return self._q

    def _initial_state(self, x: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The UKF's start, no turn and no acceleration, each with its long-run std."""
        c = self.ct_cfg
        P10 = np.zeros((10, 10))
        P10[:8, :8] = P
        P10[I_TURN, I_TURN] = math.radians(c.turn_rate_std_deg_s) ** 2
        P10[I_ACCEL, I_ACCEL] = c.accel_std_m_s2 ** 2
        return np.concatenate([x, [0.0, 0.0]]), P10

    # ------------------------------------------------------------ steps
    def initialise(self, fix, motion) -> None:
        super().initialise(fix, motion)
        self._held_cov = None

    def predict(self, t_s: float, motion) -> None:
        """The UKF's predict, then hold or release the manoeuvre by the time to go (``hold_tgo_s``)."""
        super().predict(t_s, motion)
        if self._initialised and self.ct_cfg.hold_tgo_s > 0.0:
            hold = held_while_closing(self.held, self.time_to_go_s(motion), self.ct_cfg.hold_tgo_s)
            if hold and not self.held:
                self._hold()
            elif self.held and not hold:
                self._release()

    def time_to_go_s(self, motion) -> float:
        """Range from the camera to the estimate over the speed at which it closes (inf when it does not)."""
        x = self._core._x
        return closing_time_s(x[2:5], x[5:8], motion.pos_enu_m, motion.vel_enu_m_s)

    @property
    def held(self) -> bool:
        """The manoeuvre is held (``hold_tgo_s``): the acceleration, and the turn rate with ``hold_turn_rate``."""
        return self._held_cov is not None

    @property
    def held_states(self) -> tuple[int, ...]:
        """The indices of the states held now (none when not held)."""
        return self._hold_idx if self.held else ()

    def _hold(self) -> None:
        """Keep the turn rate (``hold_turn_rate``), and the speed (the acceleration to zero); set their
        uncertainty aside (uncorrelated, tiny): the detections no longer move them, and the filter's velocity is
        as stiff as the UKF's. A turn goes on for its time (a ship holds its rudder), while a speed change ends
        at the ordered speed within seconds: extrapolated over the dive, an acceleration overshoots it."""
        core = self._core
        x, P = core.x, core.P
        x[I_ACCEL] = 0.0
        idx = list(self._hold_idx)
        self._held_cov = P[np.ix_(idx, idx)].copy()
        P[idx, :] = 0.0
        P[:, idx] = 0.0
        cfg = self.ct_cfg
        for i, std in ((I_TURN, math.radians(cfg.turn_rate_std_deg_s)), (I_ACCEL, cfg.accel_std_m_s2)):
            if i in idx:
                P[i, i] = (HELD_STD_FRACTION * std) ** 2
        core.set_posterior(x, P)
        self.holds += 1

    def _release(self) -> None:
        """Learn the manoeuvre again: its covariance as when it was held (uncorrelated with the rest)."""
        core = self._core
        P = core.P
        idx = list(self._hold_idx)
        P[idx, :] = 0.0
        P[:, idx] = 0.0
        P[np.ix_(idx, idx)] = self._held_cov
        self._held_cov = None
        core.set_posterior(core.x, P)

    # ------------------------------------------------------------ the manoeuvre
    @property
    def turn_rate_rad_s(self) -> float:
        """The ship's course rate about world up (counter-clockwise positive), rad/s."""
        return float(self._core.x[I_TURN])

    @property
    def accel_along_m_s2(self) -> float:
        """The ship's acceleration along its track, m/s^2."""
        return float(self._core.x[I_ACCEL])

    def predict_ahead(self, dt_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The estimated ship's position and velocity ``dt_s`` ahead (:func:`predict_ctra`, the filter's model)."""
        x = self._core.x
        return predict_ctra(x[2:5], x[5:8], x[I_TURN], x[I_ACCEL], dt_s, *self._params)

    def estimate(self) -> ManoeuvreEstimate:
        fields = self._estimate_fields()  # the UKF's estimate
        if not self._initialised:
            return ManoeuvreEstimate(*fields)
        x = self._core._x  # read only
        var = self._core._P.diagonal().copy()
        if self.held:  # a held state's std is the one it had when it was held
            var[list(self._hold_idx)] = self._held_cov.diagonal()
        return ManoeuvreEstimate(*fields, float(x[I_TURN]), math.sqrt(max(var[I_TURN], 0.0)),
                                 float(x[I_ACCEL]), math.sqrt(max(var[I_ACCEL], 0.0)), self.held)
