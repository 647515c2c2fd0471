"""Per-call cost of the INS (controllers.navigation.ins) at its flight rates: a timing script, not a test.

A level flight at 20 m/s heading north-east, made up on the spot (no truth side): IMU at 120 Hz with white
noise and turn-on biases, GNSS at 5 Hz (0.15 s latency), baro at 24 Hz, magnetometer at 40 Hz, airspeed at
20 Hz (baro, mag and airspeed averaged over the default 0.1 s before fusion). Each public call and each
internal stage is timed with ``time.perf_counter_ns`` around it; medians and 99th percentiles (microseconds)
are printed, with the filter's whole share of one IMU tick.

    python tools/bench_ins.py            # 120 s of flight
    python tools/bench_ins.py --seconds 30
"""
from __future__ import annotations

import argparse
import math
import time
from collections import defaultdict

import numpy as np

from controllers.config import InsConfig
from controllers.navigation.ins import GRAVITY_M_S2, Ins
from fwsim.interface.messages import AirspeedSample, BaroSample, GnssFix, ImuSample, MagSample

STAGES = {"ekf predict (nominal + 21x21 covariance)": "_predict_ekf", "gnss fusion (pos + vel, 6 scalars)":
          "_fuse_gnss_now", "baro fusion": "_fuse_baro_now", "mag fusion (field, the default: 3 axes)": "_fuse_mag_now",
          "airspeed + sideslip fusion": "_fuse_airspeed_now"}


def _timed(store: list, fn):
    def wrapper(*args):
        t0 = time.perf_counter_ns()
        out = fn(*args)
        store.append(time.perf_counter_ns() - t0)
        return out
    return wrapper


def _stream(seconds: float, rng):
    """(time, kind, message) in time order for a level flight north-east at 20 m/s, 500 m."""
    dt, v = 1.0 / 120.0, 20.0 * np.array([math.sqrt(0.5), math.sqrt(0.5), 0.0])
    field_frd = np.array([0.25 * math.sqrt(0.5), -0.25 * math.sqrt(0.5), 0.433])  # 0.5 G, 60 deg, heading 45 deg
    out = []
    for k in range(1, int(seconds * 120)):
        t = k * dt
        out.append((t, "imu", ImuSample(t, dt, rng.normal(0, 3.4e-4 * math.sqrt(dt), 3) + 0.003 * dt,
                                        np.array([0.0, 0.0, -GRAVITY_M_S2]) * dt + rng.normal(0, 4e-3 * dt ** .5, 3))))
        if k % 24 == 0:
            tf = t - 0.15
            out.append((t + 1e-6, "gnss", GnssFix(t, tf, v * tf + rng.normal(0, 0.8, 3) + [0, 0, 500], v, 0.8, 1.5,
                                                   0.15)))
        if k % 5 == 0:
            out.append((t + 2e-6, "baro", BaroSample(t, 500.0 + rng.normal(0, 0.3))))
        if k % 3 == 0:
            out.append((t + 3e-6, "mag", MagSample(t, field_frd + rng.normal(0, 0.003, 3))))
        if k % 6 == 0:
            out.append((t + 4e-6, "airspeed", AirspeedSample(t, 20.0 + rng.normal(0, 0.3))))
    return sorted(out, key=lambda e: e[0])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=120.0)
    args = ap.parse_args()
    ins = Ins(InsConfig(mag_declination_deg=0.0))
    stages: dict[str, list] = defaultdict(list)
    for label, name in STAGES.items():
        setattr(ins, name, _timed(stages[label], getattr(ins, name)))
    ins._fusers = ((ins._queues["gnss"], ins._fuse_gnss_now), (ins._queues["baro"], ins._fuse_baro_now),
                   (ins._queues["mag"], ins._fuse_mag_now), (ins._queues["airspeed"], ins._fuse_airspeed_now))
    ins._out.step = _timed(stages["output predictor step"], ins._out.step)
    ins._out.correct = _timed(stages["output predictor correction"], ins._out.correct)
    calls: dict[str, list] = defaultdict(list)
    feed = {"imu": ins.predict, "gnss": ins.fuse_gnss, "baro": ins.fuse_baro, "mag": ins.fuse_mag,
            "airspeed": ins.fuse_airspeed}
    stream = _stream(args.seconds, np.random.default_rng(0))
    wall0 = time.perf_counter()
    for _, kind, msg in stream:
        t0 = time.perf_counter_ns()
        feed[kind](msg)
        calls[kind].append(time.perf_counter_ns() - t0)
        if kind == "imu" and ins.initialised:
            t0 = time.perf_counter_ns()
            ins.estimate()
            calls["estimate"].append(time.perf_counter_ns() - t0)
            ins.drain_aid_status()
    wall = time.perf_counter() - wall0
    print(f"{args.seconds:.0f} s of flight in {wall:.2f} s wall ({args.seconds / wall:.0f}x real time, "
          "incl. estimate())")
    print(f"{'call':48s} {'n':>7s} {'median us':>10s} {'p99 us':>8s}")
    for label, xs in list(calls.items()) + list(stages.items()):
        a = np.array(xs[len(xs) // 10:]) / 1e3  # skip the initialisation's share
        print(f"{label:48s} {len(a):7d} {np.median(a):10.1f} {np.percentile(a, 99):8.1f}")
    per_tick = sum(np.sum(x) for x in calls.values()) / 1e3 / len(calls["imu"])
    print(f"the filter's whole cost per IMU tick (every call, incl. estimate()): {per_tick:.1f} us")


if __name__ == "__main__":
    main()
