"""Sweep the terminal phase over impact angles and ship courses/speeds (JSBSim, full flight software).

Each case is :func:`fwsim.cases.terminal_case` (from the loiter ring, ~35 s of
flight); cases run on a process pool. Prints one row per case and a summary
against the bounds (hit, miss <= 3 m, both impact-angle errors <= 3 deg), and
writes the rows as CSV. The same sweep is the slow test
``tests/test_terminal_sweep.py`` (``pytest -m slow``).

    python tools/terminal_sweep.py --workers 2 --csv runs/terminal_sweep.csv
    python tools/terminal_sweep.py --quick            # every fifth case
    python tools/terminal_sweep.py --set "world.wind_enu_m_s=[5, -4, 0]"   # every case in a wind
"""
from __future__ import annotations

import argparse
import csv
import itertools
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from fwsim.cases import case_line, fly_case, sweep_cases
from fwsim.scenario import parse_sets


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="every fifth case only")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default="runs/terminal_sweep", help="folder for the logs")
    ap.add_argument("--csv", help="write the rows here")
    ap.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                    help="override a field of every case, e.g. --set \"world.wind_enu_m_s=[5, -4, 0]\" "
                         "(repeatable)")
    args = ap.parse_args(argv)
    overrides = parse_sets(args.set)
    todo = sweep_cases(args.quick)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    rows = []
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        for row in pool.map(fly_case, todo, itertools.repeat(args.out), itertools.repeat(args.seed),
                            itertools.repeat((3.0, 3.0)), itertools.repeat(overrides)):
            rows.append(row)
            print(case_line(row), flush=True)
    n_ok = sum(r["ok"] for r in rows)
    n_hit = sum(r["hit"] == 1.0 for r in rows)
    print(f"{n_ok}/{len(rows)} within 3 m / 3 deg; {n_hit}/{len(rows)} hit the ship; "
          f"wall {time.perf_counter() - t0:.0f} s on {args.workers} workers")
    if args.csv:
        Path(args.csv).parent.mkdir(parents=True, exist_ok=True)
        with open(args.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
        print(args.csv)
    return 0 if n_ok == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
