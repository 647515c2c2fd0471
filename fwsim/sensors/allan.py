"""The analytic Allan variance of the IMU error terms (the sensor-model tests measure the simulated IMU's
Allan deviation with allantools' overlapping estimator and hold it against these).

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

__all__ = ["avar_white", "avar_random_walk", "avar_gauss_markov"]


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
