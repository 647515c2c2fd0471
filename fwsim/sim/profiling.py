"""Where a run's wall time goes, block by block (``fwsim run --profile``, ``fwsim bench``).

:class:`BlockTimer` wraps the methods of the loop's blocks (sensors, the flight
software's blocks, the autopilot, JSBSim, the camera, the renders, the log
writer) with a wall-clock timer. Times are *exclusive*: a timed call inside
another (the log writer's ``write`` inside ``write_state``, a flight-software
block inside its ``step``) counts once, in the inner block. What no block
claims is ``loop``. Without a timer nothing is wrapped: a plain run pays
nothing. The timer's own cost (two ``perf_counter`` calls and a closure,
~1 us per timed call) is in the figures.
"""
from __future__ import annotations

import time
from collections import defaultdict
from dataclasses import dataclass
from typing import Any, Callable

__all__ = ["BlockTimer", "BlockTime"]


@dataclass(frozen=True)
class BlockTime:
    name: str
    seconds: float  # exclusive wall time
    calls: int
    share: float  # of the run's wall time
    ms_per_sim_s: float  # wall milliseconds per simulated second


class BlockTimer:
    """Exclusive wall time per named block (see the module text)."""

    def __init__(self):
        self.seconds: dict[str, float] = defaultdict(float)
        self.calls: dict[str, int] = defaultdict(int)
        self._stack: list[list] = []  # [name, start, time of timed children]

    def wrap(self, obj: Any, method: str, name: str) -> None:
        """Time ``obj.method`` as block ``name`` from now on (the instance's attribute is replaced)."""
        fn = getattr(obj, method)
        setattr(obj, method, self.timed(fn, name))

    def timed(self, fn: Callable, name: str) -> Callable:
        """``fn`` timed as block ``name``."""
        stack, seconds, calls, clock = self._stack, self.seconds, self.calls, time.perf_counter

        def call(*args, **kwargs):
            frame = [name, clock(), 0.0]
            stack.append(frame)
            try:
                return fn(*args, **kwargs)
            finally:
                stack.pop()
                elapsed = clock() - frame[1]
                seconds[name] += elapsed - frame[2]
                calls[name] += 1
                if stack:
                    stack[-1][2] += elapsed

        return call

    def report(self, wall_s: float, sim_s: float) -> list[BlockTime]:
        """The blocks, most expensive first, with ``loop`` (what no block claims) added."""
        rows = dict(self.seconds)
        rows["loop"] = max(wall_s - sum(rows.values()), 0.0)
        out = [BlockTime(k, v, self.calls.get(k, 0), v / wall_s if wall_s > 0 else 0.0,
                         1e3 * v / sim_s if sim_s > 0 else float("nan")) for k, v in rows.items()]
        return sorted(out, key=lambda b: -b.seconds)


def time_flight_software(timer: BlockTimer, fsw) -> None:
    """Time each block of the flight software (the mission's; a scripted one as a whole)."""
    if not hasattr(fsw, "estimation"):
        timer.wrap(fsw, "step", "fsw:script")
        return
    timer.wrap(fsw, "step", "fsw:glue")
    timer.wrap(fsw.navigation, "step", "fsw:navigation")
    timer.wrap(fsw.estimation, "predict", "fsw:estimator")
    timer.wrap(fsw.estimation, "update", "fsw:estimator")
    timer.wrap(fsw.perception, "step", "fsw:perception")
    timer.wrap(fsw.pointing, "step", "fsw:pointing")
    for phase, block in fsw.guidance.items():
        if block is not None:
            timer.wrap(block, "step", f"fsw:guidance:{phase}:{type(block).__name__}")


def time_onboard_navigation(timer: BlockTimer, nav) -> None:
    """Time the onboard navigation (``sensors.profile`` other than ideal): its sensors' error models and the
    INS."""
    m = nav.models
    for model in (m.imu, m.gnss, m.baro, m.mag, m.pitot, m.encoders):
        timer.wrap(model, "step", "sensor errors")
    for name in ("predict", "fuse_gnss", "fuse_baro", "fuse_mag", "fuse_airspeed", "estimate"):
        timer.wrap(nav.ins, name, "navigation (INS)")  # (the delayed fusions run inside predict)


def time_harness(timer: BlockTimer, *, sensors, detector, autopilot, world, log) -> None:
    """Time the harness's blocks: sensors, autopilot, JSBSim, the rest of the world step, camera, renders,
    logging."""
    timer.wrap(sensors, "sample", "sensors")
    timer.wrap(detector, "arrived", "sensors")
    timer.wrap(autopilot, "actuate", "autopilot")
    timer.wrap(autopilot, "status", "autopilot")
    timer.wrap(world.airframe, "step", "jsbsim")
    timer.wrap(world, "step", "world (ship, gimbal)")
    timer.wrap(world, "look", "camera")
    timer.wrap(detector, "observe", "camera")
    timer.wrap(world, "render", "renders")
    timer.wrap(world.camera, "encode_jpeg", "renders")
    for m in ("write", "write_state", "write_nav_estimate", "write_transform", "write_image", "write_event",
              "write_calibration", "write_location", "write_image_annotations"):
        timer.wrap(log, m, "logging")
