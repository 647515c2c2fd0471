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
from typing import TYPE_CHECKING

from fwsim import SCENARIO_DIR

from fwsim.interface import topics
if TYPE_CHECKING:
    from fwsim.sim.loop import RunResult


def _best_of(fn, repeats: int) -> float:
    return min(fn() for _ in range(repeats))


def jsbsim_raw_steps_per_s(seconds: float = 30.0, repeats: int = 3) -> float:
    """JSBSim alone: ``fdm.run()`` in a loop with the trimmed controls held."""
    from fwsim.world.airframe import Airframe
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
    from fwsim.world.airframe import Airframe
    from fwsim.interface.messages import ActuatorCommand
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


def detection_frame_ms(frames: int = 600) -> tuple[float, float]:
    """(median, p99) milliseconds of one detection frame: ROI ray casting against the
    UAV and the ship, the ship about 900 m away (a loiter at R = H = 500 m), the
    camera pointed at it, the pose varying a little every frame."""
    import numpy as np

    from fwsim.sensors.camera import Camera, CameraConfig, Pose
    from fwsim.interface.frames import dcm_enu_from_frd
    from fwsim.world.geometry import uav_mesh
    from fwsim.world.gimbal import camera_pose_world, pan_tilt_pointing_at
    from fwsim.world.target import Ship, TargetConfig
    ship = Ship(TargetConfig())
    cam = Camera(CameraConfig(), uav_mesh("fwuav"), ship.mesh)
    R_s, t_s = ship.pose(0.0)[1], ship.pose(0.0)[0]
    mount = np.array([0.0, 0.0, 0.1])
    times = []
    for k in range(frames):
        a = 2 * math.pi * k / frames
        pos = np.array([500 * math.cos(a), 500 * math.sin(a), 500.0])
        euler = np.array([-0.2, 0.02, (math.pi - a) % (2 * math.pi) - math.pi])
        R = dcm_enu_from_frd(euler)
        pan, tilt = pan_tilt_pointing_at(R.T @ (np.array([0, 0, 8.0]) - pos - R @ mount))
        cp, Rc = camera_pose_world(pos, euler, mount, pan, tilt)
        t0 = time.perf_counter()
        cam.detect(0.0, cp, Rc, Pose(R, pos), Pose(R_s, t_s))
        times.append(time.perf_counter() - t0)
    ms = np.array(times) * 1e3
    return float(np.median(ms)), float(np.percentile(ms, 99))


def nmpc_vs_ipopt(duration_s: float = 60.0) -> dict[str, float]:
    """NMPC solve times at the paper's sizes (N = 50, CBF active), the fast solver and a fully
    converged IPOPT solve of the same problem in the same run, each flying the NMPC's own model
    in closed loop from 800 m out at 600 m around a ship at 5 m/s (controllers.guidance.nmpc)."""
    import numpy as np

    from controllers.guidance.nmpc import Nmpc, NmpcConfig, kinematic_closed_loop
    x0 = [-800.0, 0.0, 600.0, 0.0, 0.0, math.pi / 2]
    out = {}
    for label, over in (("nmpc", {}), ("ipopt", {"solver": "ipopt"})):
        cfg = NmpcConfig.model_validate({**over, "max_solve_ms": 1e5})
        run = kinematic_closed_loop(Nmpc(cfg), x0, [0.0, 0.0, 0.0], [0.0, 5.0, 0.0], duration_s)
        warm = run.solve_ms[1:]  # the first (cold) solve is not a loop step
        out[f"{label}_solve_ms_median"] = float(np.median(warm))
        out[f"{label}_solve_ms_p99"] = float(np.percentile(warm, 99))
        last = run.t_s >= duration_s - 30.0
        out[f"{label}_radius_rmse_last30_m"] = float(np.sqrt(np.mean(np.square(run.radius_err_m[last]))))
    return out


def log_writer_us(n: int = 3000) -> tuple[float, float]:
    """(microseconds per write_state, per JSON message) of the MCAP writer."""
    import numpy as np

    from fwsim.log import LogWriter
    from fwsim.interface.messages import ActuatorCommand, AirframeState
    st = AirframeState(0.0, np.array([1.0, 2, 3]), np.array([20.0, 1, 0]), np.array([0.1, 0.05, 1.0]),
                       np.zeros(3), 22.0, 0.05, 0.0, np.array([0, 0, -9.8]), 0.3, np.zeros(3), 3.0)
    act = ActuatorCommand(0.0, 0.1, -0.05, 0.0, 0.3)
    with tempfile.TemporaryDirectory() as tmp:
        with LogWriter(Path(tmp) / "w.mcap", metadata={}, scenario_text="") as log:
            t0 = time.perf_counter()
            for _ in range(n):
                log.write_state(st)
            t1 = time.perf_counter()
            for _ in range(n):
                log.write(topics.ACTUATORS, act)
            t2 = time.perf_counter()
    return (t1 - t0) / n * 1e6, (t2 - t1) / n * 1e6


def peak_memory_mb() -> float:
    """Peak resident memory of this process so far (Linux: ru_maxrss is in KiB)."""
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def closed_loop(scenario_path: Path, repeats: int = 2) -> tuple[float, float, float]:
    """(sim seconds, best wall seconds, real-time factor) of a full run with logging."""
    from fwsim.sim.loop import run
    from fwsim.scenario.model import load_scenario
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


def block_breakdown(scenario, text: str) -> tuple[RunResult, list]:
    """One profiled run of ``scenario`` (log in a temporary folder): its result and its blocks
    (:class:`fwsim.sim.profiling.BlockTime`, most expensive first)."""
    from fwsim.sim.loop import run
    from fwsim.sim.profiling import BlockTimer
    with tempfile.TemporaryDirectory() as tmp:
        r = run(scenario, text, Path(tmp) / "profiled.mcap", profile=BlockTimer())
    return r, r.blocks


def blocks_json(blocks) -> dict[str, dict[str, float]]:
    """Blocks as ``{name: {share, ms_per_sim_s, seconds, calls}}`` (the ``--json`` form)."""
    return {b.name: {"share": b.share, "ms_per_sim_s": b.ms_per_sim_s, "seconds": b.seconds, "calls": b.calls}
            for b in blocks}


def run_bench(quick: bool = False) -> dict[str, float | str | dict]:
    """Every figure of ``fwsim bench``. The paper mission flies unprofiled for its real-time factor (best
    of two) and once more under a :class:`fwsim.sim.profiling.BlockTimer` for ``paper_mission_blocks``."""
    from fwsim.scenario.model import load_scenario
    seconds = 10.0 if quick else 30.0
    repeats = 1 if quick else 3
    raw = jsbsim_raw_steps_per_s(seconds, repeats)
    wrap = wrapper_steps_per_s(seconds, repeats)
    sim, wall, rtf = closed_loop(SCENARIO_DIR / "autopilot_checkout.yaml", 1 if quick else 2)
    det_med, det_p99 = detection_frame_ms(200 if quick else 600)
    p_sim, p_wall, p_rtf = closed_loop(SCENARIO_DIR / "paper_mission.yaml", 1 if quick else 2)
    paper, paper_text = load_scenario(SCENARIO_DIR / "paper_mission.yaml")
    profiled, blocks = block_breakdown(paper, paper_text)
    state_us, msg_us = log_writer_us()
    nmpc = nmpc_vs_ipopt(30.0 if quick else 60.0)
    from controllers.guidance.nmpc_worker import solver_kind
    return {
        "machine": f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}",
        # where the paper mission's NMPC solved (controllers.guidance.nmpc_worker; FWSIM_NMPC_WORKER)
        "nmpc_worker": solver_kind(paper.controllers.nmpc),
        "jsbsim_raw_steps_per_s": raw,
        "jsbsim_raw_real_time_factor": raw / 120.0,
        "airframe_step_steps_per_s": wrap,
        "checkout_sim_s": sim,
        "checkout_wall_s": wall,
        "checkout_real_time_factor": rtf,
        "checkout_share_of_raw_rate": rtf * 120.0 / raw if raw > 0 else math.nan,
        "detection_frame_ms_median": det_med,
        "detection_frame_ms_p99": det_p99,
        "paper_mission_sim_s": p_sim,
        "paper_mission_real_time_factor": p_rtf,
        "paper_mission_profiled_real_time_factor": profiled.real_time_factor,
        "log_write_state_us": state_us,
        "log_write_message_us": msg_us,
        **nmpc,
        "peak_memory_mb": peak_memory_mb(),
        "paper_mission_blocks": blocks_json(blocks),
    }
