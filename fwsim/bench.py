"""``fwsim bench``: speed figures measured in one process, printed as a table.

Figures are rates and ratios on the machine at hand (shared machines are
noisy); they are measurements, not test assertions.
"""
from __future__ import annotations

import math
import os
import platform
import tempfile
import time
from pathlib import Path

from fwsim import SCENARIO_DIR


def _best_of(fn, repeats: int) -> float:
    return min(fn() for _ in range(repeats))


def jsbsim_raw_steps_per_s(seconds: float = 30.0, repeats: int = 3) -> float:
    """JSBSim alone: ``fdm.run()`` in a loop with the trimmed controls held."""
    from fwsim.airframe import Airframe
    a = Airframe("fwuav")
    n = int(seconds / a.dt_s)

    def once():
        a.reset([0.0, 0.0, 1000.0], 22.0, 0.0)
        fdm = a._fdm  # the wrapper's JSBSim instance: raw stepping only, nothing read back
        t0 = time.perf_counter()
        for _ in range(n):
            fdm.run()
        return time.perf_counter() - t0
    return n / _best_of(once, repeats)


def wrapper_steps_per_s(seconds: float = 30.0, repeats: int = 3) -> float:
    """``Airframe.step``: commands in, the full truth state out, per tick."""
    from fwsim.airframe import Airframe
    from fwsim.messages import ActuatorCommand
    a = Airframe("fwuav")
    n = int(seconds / a.dt_s)

    def once():
        a.reset([0.0, 0.0, 1000.0], 22.0, 0.0)
        act = ActuatorCommand(0.0, 0.0, 0.0, 0.0, a.trim.throttle_norm)
        t0 = time.perf_counter()
        for _ in range(n):
            a.step(act)
        return time.perf_counter() - t0
    return n / _best_of(once, repeats)


def closed_loop(scenario_path: Path, repeats: int = 2) -> tuple[float, float, float]:
    """(sim seconds, best wall seconds, real-time factor) of a full run with logging."""
    from fwsim.loop import run
    from fwsim.scenario import load_scenario
    scenario, text = load_scenario(scenario_path)
    walls = []
    sim = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(repeats):
            r = run(scenario, text, Path(tmp) / f"bench{i}.mcap")
            walls.append(r.wall_time_s)
            sim = r.sim_time_s
    wall = min(walls)
    return sim, wall, sim / wall


def run_bench(quick: bool = False) -> dict[str, float | str]:
    seconds = 10.0 if quick else 30.0
    repeats = 1 if quick else 3
    raw = jsbsim_raw_steps_per_s(seconds, repeats)
    wrap = wrapper_steps_per_s(seconds, repeats)
    sim, wall, rtf = closed_loop(SCENARIO_DIR / "autopilot_checkout.yaml", 1 if quick else 2)
    return {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
        "jsbsim_raw_steps_per_s": raw,
        "jsbsim_raw_real_time_factor": raw / 120.0,
        "airframe_step_steps_per_s": wrap,
        "checkout_sim_s": sim,
        "checkout_wall_s": wall,
        "checkout_real_time_factor": rtf,
        "checkout_share_of_raw_rate": rtf * 120.0 / raw if raw > 0 else math.nan,
    }
