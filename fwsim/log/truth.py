"""The truth at another message's times: one interpolation for the metrics, the figures and both Rerun views.

Truth topics (``/target/state``, ``/uav/state``) are logged at ``rates.log_hz``;
an estimate or a detection comes at its own times. Everything that compares
the two interpolates the truth linearly between its samples (held beyond the
first and the last), with :func:`interp_at` on whole columns or
:class:`TruthStream` as messages arrive (the live view: a value waits until
the truth after its time has arrived, so both give the same numbers).
"""
from __future__ import annotations

import numpy as np

from fwsim.interface import topics
__all__ = ["interp_at", "truth_at", "TruthStream"]


def interp_at(t_query, t_src: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values`` (n,) or (n, k) sampled at ``t_src`` (increasing), linearly interpolated at ``t_query``."""
    v = np.asarray(values, dtype=float)
    if v.ndim == 1:
        return np.interp(t_query, t_src, v)
    return np.column_stack([np.interp(t_query, t_src, v[:, k]) for k in range(v.shape[1])])


def truth_at(log, t_query, field: str = "pos_enu_m", topic: str = topics.TARGET_STATE) -> np.ndarray:
    """A truth field of the log at ``t_query`` (e.g. the ship's position at each estimate's time)."""
    table = log.table(topic)
    return interp_at(t_query, table["t_s"], table[field])


class TruthStream:
    """:func:`interp_at` for messages as they come: ``push`` each truth sample, ``add`` each value to compare
    with it; ``ready()`` returns the (t, value, truth at t) whose truth is known (``final``: all of them, the
    truth held after its last sample)."""

    def __init__(self):
        self._t: list[float] = []  # the last two truth samples
        self._v: list[np.ndarray] = []
        self._pending: list[tuple[float, np.ndarray]] = []

    def push(self, t_s: float, truth) -> None:
        self._t = (self._t + [float(t_s)])[-2:]
        self._v = (self._v + [np.asarray(truth, dtype=float)])[-2:]

    def add(self, t_s: float, value) -> None:
        self._pending.append((float(t_s), np.asarray(value, dtype=float)))

    def ready(self, final: bool = False) -> list[tuple[float, np.ndarray, np.ndarray]]:
        if not self._t:
            return []
        out, keep = [], []
        for t, value in self._pending:
            if t <= self._t[-1] or final:
                out.append((t, value, interp_at(np.array([t]), np.array(self._t), np.array(self._v))[0]))
            else:
                keep.append((t, value))
        self._pending = keep
        return out
