"""Overlapping Allan deviation and the analytic Allan variance of the IMU error terms.

For rate samples y_k (each the mean rate over dt, e.g. an IMU's delta angle / dt) the
"phase" is x_0 = 0, x_j = dt * (y_0 + ... + y_{j-1}), and for an averaging time tau = m dt

    AVAR(tau) = sum_i (x_{i+2m} - 2 x_{i+m} + x_i)^2 / (2 tau^2 (L - 2m)),

over all L - 2m overlapping starting points of the L = N + 1 phase points: half the mean
squared difference of consecutive tau-averages (IEEE Std 952's overlapping estimator).

Analytic curves (each term adds its variance):

* white rate noise of density N (angle / velocity random walk): N^2 / tau (N at tau = 1 s);
* bias random walk of density K (rate random walk): K^2 tau / 3;
* first-order Gauss-Markov bias driven by K with correlation time T (steady sigma
  K sqrt(T / 2)): (K^2 T^3 / tau^2) (x - 3/2 + 2 e^-x - e^-2x / 2), x = tau / T, which is
  K^2 tau / 3 for tau << T and K^2 T^2 / tau for tau >> T;
* a constant bias: nothing.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ["overlapping_adev", "avar_white", "avar_random_walk", "avar_gauss_markov"]


def overlapping_adev(rates: np.ndarray, dt_s: float, taus_s) -> tuple[np.ndarray, np.ndarray]:
    """Overlapping Allan deviation of rate samples ``rates`` ((N,) or (N, k): k series at once).

    Returns ``(taus, adev)``: the averaging times actually used (each a whole number m >= 1 of
    samples, at most N // 2; duplicates dropped) and the deviation at each, shape (len(taus),)
    or (len(taus), k).
    """
    y = np.asarray(rates, dtype=float)
    n = y.shape[0]
    ms = sorted({int(round(t / dt_s)) for t in np.atleast_1d(taus_s)} & set(range(1, n // 2 + 1)))
    if not ms:
        raise ValueError(f"no averaging time fits {n} samples of {dt_s} s")
    x = np.concatenate([np.zeros((1,) + y.shape[1:]), np.cumsum(y, axis=0) * dt_s])
    out = []
    for m in ms:
        d = x[2 * m:] - 2.0 * x[m:-m] + x[:-2 * m]
        out.append(np.sqrt(np.mean(d * d, axis=0) / (2.0 * (m * dt_s) ** 2)))
    return np.array(ms, dtype=float) * dt_s, np.array(out)


def avar_white(density: float, tau_s):
    """Allan variance of white rate noise of density N (unit/sqrt(Hz)): N^2 / tau."""
    return density ** 2 / np.asarray(tau_s, dtype=float)


def avar_random_walk(density: float, tau_s):
    """Allan variance of a bias random walk of density K (unit/s/sqrt(Hz)): K^2 tau / 3."""
    return density ** 2 * np.asarray(tau_s, dtype=float) / 3.0


def _gm_bracket(x: float) -> float:
    """x - 3/2 + 2 e^-x - e^-2x / 2, by its series where the closed form cancels (x^3/3 - x^4/4 + ...)."""
    if x > 0.05:
        return x - 1.5 + 2.0 * math.exp(-x) - 0.5 * math.exp(-2.0 * x)
    # 2 e^-x - e^-2x / 2 = sum_n (-x)^n (2 - 2^(n-1)) / n!; the terms of order 0..2 cancel x - 3/2
    return sum((-x) ** n * (2.0 - 2.0 ** (n - 1)) / math.factorial(n) for n in range(3, 14))


def avar_gauss_markov(density: float, tau_c_s: float, tau_s):
    """Allan variance of a first-order Gauss-Markov bias driven by white noise of density K (unit/s/sqrt(Hz))
    with correlation time T: (K^2 T^3 / tau^2) (x - 3/2 + 2 e^-x - e^-2x / 2), x = tau / T."""
    taus = np.atleast_1d(np.asarray(tau_s, dtype=float))
    out = np.array([density ** 2 * tau_c_s ** 3 / t ** 2 * _gm_bracket(t / tau_c_s) for t in taus])
    return out if np.ndim(tau_s) else float(out[0])
