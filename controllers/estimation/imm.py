"""Target estimation by an interacting multiple model (IMM): the paper's UKF and the manoeuvring-ship UKF, mixed.

The paper's UKF (:mod:`controllers.estimation.ukf`, constant velocity: "CV") holds a
steady ship's velocity stiffly, but trails a turning one. The manoeuvring-ship
UKF (:mod:`controllers.estimation.ct_ukf`, a turn rate and an along-track acceleration:
"CT") follows turns and zigzags, but on a steady ship its turn rate wanders
with the box centres' errors (envelope, seed 1648, straight ships over 2 m/s
in the loiter: turn rate 0.3-1.2 deg/s RMS, the course 1.4-7 deg off; the
median run's velocity error 0.48 m/s against the UKF's 0.16; on turning and
zigzagging ships the other way round, 0.45 and 0.50 against 0.63 and 0.75).
This filter runs both on the same detections and weighs them by how well each
predicted them: the interacting multiple model estimator of Bar-Shalom, Li and
Kirubarajan, "Estimation with Applications to Tracking and Navigation":

* **Mode switching.** A two-state Markov chain: over ``dt`` the ship leaves
  its mode with probability ``1 - exp(-dt / switch_time_s)``.
* **Interaction** (before each predict). Each model starts from the mixture of
  both, weighted by the probability that the ship was in the other mode and
  switched: ``x0_j = sum_i mu_i|j x_i``, ``P0_j = sum_i mu_i|j (P_i + (x_i -
  x0_j)(x_i - x0_j)^T)``. The CV state is the CT state's first eight; for the
  mixing it is taken with zero turn rate and acceleration, their variances the
  CT model's own (so that mixing does not shrink the CT model's uncertainty
  of a manoeuvre it has not seen). While the CT model holds its manoeuvre
  (``ct_ukf.hold_tgo_s``, the dive) the models do not interact: the hold keeps
  what the loiter learnt, and mixing would pull it toward the CV model's zero;
  with ``hold_with_manoeuvre`` (the default) their probabilities are held too,
  as the loiter left them (the dive's box-centre errors, which the hold keeps
  out of the turn rate, would otherwise reweigh the models: on the envelope's
  steadily turning ships the steady model took over in the last 80-150 m, and
  the estimate went with its trailing one).
* **Model probabilities** (each detection). ``mu_j ~ c_j L_j``, ``L_j`` the
  detection's likelihood under model j's prediction (the Gaussian density of
  its pixel innovation, whether its gate took the detection or not:
  :attr:`controllers.estimation.ukf.UkfTargetEstimator.last_log_likelihood`), each kept at
  least ``min_probability``.
* **Output.** The moment-matched combination: position, velocity, the turn rate
  and acceleration (the CV model's being zero), their stds with the models'
  spread; the box centre's systematic error added to the reported position std
  as the UKF does. :class:`ImmEstimate` adds the manoeuvring model's
  probability, logged on ``/fsw/estimate`` (``manoeuvre_probability``).

Over the envelope (docs/results/envelope.md, "A fresh seed, 1649; an interacting multiple
model") its loiter is the better of the two models' or close to it for each
motion, but it lands no more runs within 3 m / 3 deg than the UKF: the last
150 m are set by the box centres' errors up close, not by the ship's motion.
It is an option; the UKF stays the default.

A detection is used when either model used it; its innovation in the log is
the more probable model's. Either model resetting itself (the target left the
camera's front half-space) resets both: the estimation block restarts them.

Nothing here imports the truth side of the harness (docs/design/architecture.md, "Two rules").
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controllers.config import CtUkfConfig, ImmConfig, UkfConfig
from controllers.estimation.ct_ukf import I_ACCEL, I_TURN, CtUkfTargetEstimator, ManoeuvreEstimate
from controllers.estimation.ukf import UkfTargetEstimator, step_on_measurements
from controllers.messages import DetectionFix, EstimatorStatus, FusionReason, FusionResult
from controllers.navigation.camera_model import CameraMotion, PinholeCamera

__all__ = ["ImmEstimate", "ImmTargetEstimator", "mix", "transition", "update_probabilities"]

N_CV = UkfTargetEstimator.dim_x  # the CV model's states: the CT model's first ones
N_CT = CtUkfTargetEstimator.dim_x


@dataclass(frozen=True, slots=True)
class ImmEstimate(ManoeuvreEstimate):
    """A :class:`ManoeuvreEstimate` of the mixed models, with the probability of the manoeuvring one."""

    manoeuvre_probability: float = math.nan


def transition(dt_s: float, switch_time_s: float) -> np.ndarray:
    """The Markov chain's transition matrix over ``dt_s``: ``T[i, j]`` = P(mode j now | mode i before)."""
    p = -math.expm1(-max(dt_s, 0.0) / switch_time_s)
    return np.array([[1.0 - p, p], [p, 1.0 - p]])


def mix(mu: np.ndarray, T: np.ndarray, xs: list[np.ndarray], Ps: list[np.ndarray]
        ) -> tuple[np.ndarray, list[np.ndarray], list[np.ndarray]]:
    """The IMM's interaction: (the predicted model probabilities ``c``, each model's mixed initial state and
    covariance), from the probabilities ``mu``, the transition matrix ``T`` and the models' states and
    covariances, all of one dimension."""
    c = T.T @ mu
    xs0, Ps0 = [], []
    for j in range(len(mu)):
        w = T[:, j] * mu / c[j]  # mu_i|j
        x0 = sum(w[i] * xs[i] for i in range(len(mu)))
        P0 = sum(w[i] * (Ps[i] + np.outer(xs[i] - x0, xs[i] - x0)) for i in range(len(mu)))
        xs0.append(x0)
        Ps0.append(0.5 * (P0 + P0.T))
    return c, xs0, Ps0


def update_probabilities(c: np.ndarray, log_likelihoods, floor: float) -> np.ndarray:
    """``mu_j ~ c_j L_j``, each at least ``floor``; ``c`` as it is when a likelihood is missing (NaN: the
    detection was not weighed by every model)."""
    ll = np.asarray(log_likelihoods, dtype=float)
    if not np.isfinite(ll).all():
        return np.asarray(c, dtype=float).copy()
    w = c * np.exp(ll - ll.max())
    mu = w / w.sum()
    mu = np.maximum(mu, floor)
    return mu / mu.sum()


class ImmTargetEstimator:
    """The IMM of the paper's UKF and the manoeuvring-ship UKF (``controllers.estimator: imm``); it implements
    ``controllers.blocks.TargetEstimator``. See the module text."""

    name = "imm"
    label = "IMM"  # its name in the flight software's events

    def __init__(self, camera: PinholeCamera, ukf_config: UkfConfig | None = None,
                 ct_config: CtUkfConfig | None = None, config: ImmConfig | None = None):
        self.cfg = config if config is not None else ImmConfig()
        if ukf_config is not None and ukf_config.pointing_bias_std_rad > 0.0:  # the models mix 8 and 10 states
            ukf_config = ukf_config.model_copy(update={"pointing_bias_std_rad": 0.0})
        self.cv = UkfTargetEstimator(camera, ukf_config)
        self.ct = CtUkfTargetEstimator(camera, ukf_config, ct_config)
        self.models = (self.cv, self.ct)
        self.mu = self._prior()
        self.updates = 0
        self.gated_updates = 0
        self.initialisations = 0

    def _prior(self) -> np.ndarray:
        p = self.cfg.prior_manoeuvring
        return np.array([1.0 - p, p])

    # ------------------------------------------------------------ the Protocol
    @property
    def initialised(self) -> bool:
        return self.cv.initialised and self.ct.initialised

    @property
    def tracked_height_m(self) -> float:
        return self.cv.tracked_height_m

    @property
    def t_s(self) -> float:
        return self.cv.t_s

    @property
    def manoeuvre_probability(self) -> float:
        return float(self.mu[1])

    def initialise(self, fix: DetectionFix, motion: CameraMotion) -> None:
        """Start both models from the detection (ValueError as the UKF's), at the prior probabilities."""
        self.cv.initialise(fix, motion)
        self.ct.initialise(fix, motion)
        self.mu = self._prior()
        self.initialisations += 1

    def predict(self, t_s: float, motion: CameraMotion) -> None:
        """Interact (unless the CT model holds its manoeuvre), then predict both models to ``t_s``."""
        if not self.initialised:
            self._check_resets()
            return
        dt = float(t_s) - self.cv.t_s
        if dt > 0.0 and not self._mode_held():
            T = transition(dt, self.cfg.switch_time_s)
            if self.ct.held:
                self.mu = T.T @ self.mu
            else:
                self.mu, (x_cv, x_ct), (P_cv, P_ct) = mix(self.mu, T, *self._common())
                self.cv.core.set_state(x_cv[:N_CV], P_cv[:N_CV, :N_CV])
                self.ct.core.set_state(x_ct, P_ct)
        for m in self.models:
            m.predict(t_s, motion)
        self._check_resets()

    def update(self, fix: DetectionFix, motion: CameraMotion) -> FusionResult:
        """Fuse the detection in both models and weigh them by its likelihood under each."""
        if self.initialised and fix.new and float(fix.t_s) > self.cv.t_s:
            self.predict(fix.t_s, motion)
        if not self.initialised:
            return FusionResult(False, FusionReason.NOT_INITIALISED if fix.new else FusionReason.REJECTED)
        results = [m.update(fix, motion) for m in self.models]
        if self._check_resets():
            return FusionResult(False, FusionReason.ESTIMATOR_RESET)
        if not self._mode_held():
            self.mu = update_probabilities(self.mu, [m.last_log_likelihood for m in self.models],
                                           self.cfg.min_probability)
        best = results[int(np.argmax(self.mu))]
        used = [r for r in results if r.used]
        if used:
            self.updates += 1
            r = best if best.used else used[0]
            return FusionResult(True, FusionReason.USED, r.innovation_px, r.test_ratio)
        if all(r.reason == FusionReason.INNOVATION_GATE for r in results):
            self.gated_updates += 1
        return best

    def estimate(self) -> ImmEstimate:
        """The moment-matched combination of the two models (NaN before the start)."""
        if not self.initialised:
            nan3 = np.full(3, np.nan)
            return ImmEstimate(self.t_s, nan3, nan3.copy(), nan3.copy(), nan3.copy(), math.nan, math.nan,
                               np.full(2, np.nan))
        xs, Ps = self._common()
        mu = self.mu
        x = mu[0] * xs[0] + mu[1] * xs[1]
        P = sum(mu[i] * (Ps[i] + np.outer(xs[i] - x, xs[i] - x)) for i in range(2))
        var = P.diagonal().copy()
        var[2:4] += mu[0] * self.cv._consider.diagonal() + mu[1] * self.ct._consider.diagonal()
        sd = np.sqrt(np.maximum(var, 0.0))
        best = self.models[int(np.argmax(mu))]  # its innovation, when it updated at this time
        innov = best._innov.copy() if best._innov_t == best.t_s else np.full(2, np.nan)
        return ImmEstimate(self.t_s, x[2:5].copy(), x[5:8].copy(), sd[2:5].copy(), sd[5:8].copy(), float(x[0]),
                           float(x[1]), innov,
                           float(x[I_TURN]), float(sd[I_TURN]), float(x[I_ACCEL]), float(sd[I_ACCEL]),
                           bool(self.ct.held), float(mu[1]))

    def status(self, t_s: float) -> EstimatorStatus:
        """The counters since the start: detections used by either model, gated by both; the models' own
        rejections (the CV model's: both check a detection alike), resets and covariance repairs."""
        return EstimatorStatus(t_s, self.updates, self.gated_updates, self.rejected_updates,
                               self.cv.divergence_resets + self.ct.divergence_resets,
                               self.cv.numerical_resets + self.ct.numerical_resets, self.initialisations)

    def step(self, meas, motion: CameraMotion) -> ImmEstimate | None:
        """One tick on raw measurements, as :meth:`controllers.estimation.ukf.UkfTargetEstimator.step`."""
        return step_on_measurements(self, meas, motion)

    @property
    def rejected_updates(self) -> int:
        """Detections not used (the models check a detection alike: the CV model's count)."""
        return self.cv.rejected_updates

    @rejected_updates.setter
    def rejected_updates(self, n: int) -> None:
        self.cv.rejected_updates = n

    # ------------------------------------------------------------ internals
    def _mode_held(self) -> bool:
        """The models' probabilities are held: the CT model holds its manoeuvre and ``hold_with_manoeuvre``."""
        return self.cfg.hold_with_manoeuvre and self.ct.held

    def _common(self) -> tuple[list[np.ndarray], list[np.ndarray]]:
        """Both models' states and covariances in the CT model's dimension: the CV model's with zero turn rate
        and acceleration, uncorrelated, their variances the CT model's."""
        P_ct = self.ct.core.P
        x_cv = np.zeros(N_CT)
        x_cv[:N_CV] = self.cv.core.x
        P_cv = np.zeros((N_CT, N_CT))
        P_cv[:N_CV, :N_CV] = self.cv.core.P
        for i in range(N_CV, N_CT):
            P_cv[i, i] = P_ct[i, i]
        return [x_cv, self.ct.core.x], [P_cv, P_ct]

    def _check_resets(self) -> bool:
        """One model reset itself: reset the other too (both restart together); True when that happened."""
        down = [not m.initialised for m in self.models]
        if any(down) and not all(down):
            for m in self.models:
                if m.initialised:
                    m.reset()
            return True
        return any(down)
