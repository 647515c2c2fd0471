"""Scaling figures for docs/results/speed.md: batch workers, and memory over a long loiter.

    python tools/scaling.py batch              # the 8-seed paper-mission spec on 1 worker, then on 2
    python tools/scaling.py loiter             # a 1-hour loiter (no switch): peak memory, log size
    python tools/scaling.py loiter --minutes 10

``batch`` flies ``scenarios/batches/paper_mission_seeds.yaml`` with ``fwsim.batch.runner``
twice (1 worker, then 2) and prints both wall times, their ratio, and paper
missions per hour per core. ``loiter`` flies the paper mission with
``controllers.switch.enabled: false`` for the given time (default 60 min) and
prints the process's peak resident memory at 10 minutes and at the end, the
log's size per simulated minute and the real-time factor. Measurements on the
machine at hand; they belong in notes, not in tests.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from fwsim import SCENARIO_DIR
from fwsim.sim.bench import peak_memory_mb


def batch(out: Path) -> int:
    from fwsim.batch.runner import run_batch
    spec_path = SCENARIO_DIR / "batches" / "paper_mission_seeds.yaml"
    walls = {}
    for workers in (1, 2):
        t0 = time.perf_counter()
        rows = run_batch(spec_path, out / f"workers{workers}", workers=workers).rows
        walls[workers] = time.perf_counter() - t0
        done = sum(r["status"] == "completed" for r in rows)
        print(f"{workers} worker(s): {len(rows)} runs ({done} completed) in {walls[workers]:.1f} s", flush=True)
    n = len(rows)
    print(f"speed-up 2 vs 1 worker: {walls[1] / walls[2]:.2f}x")
    print(f"paper missions per hour: {3600 * n / walls[1]:.0f} on 1 core, {3600 * n / walls[2]:.0f} on 2 cores")
    return 0


def loiter(minutes: float) -> int:
    from fwsim.sim.loop import run
    from fwsim.scenario.model import load_scenario
    overrides = {"controllers.switch.enabled": False, "duration_s": 60.0 * minutes}
    scenario, text = load_scenario(SCENARIO_DIR / "paper_mission.yaml", overrides)
    marks: dict[int, float] = {}

    def progress(t_s: float, _total: float) -> None:
        for m in (10, 30, 60):
            if t_s >= 60.0 * m and m not in marks:
                marks[m] = peak_memory_mb()
                print(f"  {m:3d} min simulated: peak memory {marks[m]:.0f} MB", flush=True)

    start_mb = peak_memory_mb()
    with tempfile.TemporaryDirectory() as tmp:
        log = Path(tmp) / "loiter.mcap"
        r = run(scenario, text, log, progress=progress)
        size_mb = log.stat().st_size / 1e6
    print(f"{r.status}: {r.reason}; {r.sim_time_s / 60:.1f} min simulated in {r.wall_time_s:.0f} s "
          f"({r.real_time_factor:.1f}x real time)")
    print(f"peak memory: {start_mb:.0f} MB before the run, {peak_memory_mb():.0f} MB at the end")
    print(f"log: {size_mb:.1f} MB, {size_mb / (r.sim_time_s / 60):.2f} MB per simulated minute")
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="what", required=True)
    b = sub.add_parser("batch", help="the 8-seed spec on 1 worker, then 2")
    b.add_argument("--out", default=None, help="folder for the batches' logs (default: a temporary folder)")
    lo = sub.add_parser("loiter", help="a long loiter: peak memory and log size")
    lo.add_argument("--minutes", type=float, default=60.0)
    args = ap.parse_args(argv)
    if args.what == "loiter":
        return loiter(args.minutes)
    if args.out:
        return batch(Path(args.out))
    with tempfile.TemporaryDirectory() as tmp:
        return batch(Path(tmp))


if __name__ == "__main__":
    sys.exit(main())
