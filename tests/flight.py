"""Closed-loop flight helpers for the tests: JSBSim + autopilot, no logging."""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from fwsim.world.airframe import Airframe
from fwsim.autopilot import Autopilot, load_autopilot_params


@dataclass
class Trace:
    """Per-tick arrays of a closed-loop flight."""

    t: list = field(default_factory=list)
    states: list = field(default_factory=list)
    status: list = field(default_factory=list)
    acts: list = field(default_factory=list)

    def arr(self, name: str) -> np.ndarray:
        return np.array([getattr(s, name) for s in self.states])

    def sp(self, name: str) -> np.ndarray:
        return np.array([getattr(s, name) for s in self.status])

    def window(self, t0: float, t1: float) -> np.ndarray:
        t = np.array(self.t)
        return (t >= t0) & (t < t1)


class Flight:
    """An aircraft with its autopilot; ``fly(seconds, command_fn)`` appends to ``trace``."""

    def __init__(self, airspeed_m_s: float = 22.0, altitude_m: float = 500.0, heading_deg: float = 90.0,
                 flight_path_deg: float = 0.0):
        self.airframe = Airframe("fwuav")
        self.state = self.airframe.reset([0.0, 0.0, altitude_m], airspeed_m_s, math.radians(heading_deg),
                                         math.radians(flight_path_deg))
        self.autopilot = Autopilot(load_autopilot_params("fwuav"), self.airframe.dt_s,
                                   self.airframe.trim.throttle_norm)
        self.trace = Trace()

    def fly(self, seconds: float, command_fn, stop=None) -> Trace:
        """Fly ``seconds``; returns this segment's trace (times relative to its start)."""
        self.trace = Trace()
        t0 = self.state.t_s
        for _ in range(int(round(seconds / self.airframe.dt_s))):
            cmd = command_fn(self.state)
            act, status = self.autopilot.step(cmd, self.state)
            self.state = self.airframe.step(act)
            self.trace.t.append(self.state.t_s - t0)
            self.trace.states.append(self.state)
            self.trace.status.append(status)
            self.trace.acts.append(act)
            if stop is not None and stop(self.state):
                break
        return self.trace


def flight_path_rad(state) -> float:
    v = state.vel_enu_m_s
    return math.asin(max(-1.0, min(1.0, v[2] / max(float(np.linalg.norm(v)), 1e-6))))
