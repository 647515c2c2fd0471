"""Sweep the terminal phase over impact angles and ship courses/speeds (JSBSim, full flight software).

The cases are the batch spec ``scenarios/batches/terminal_sweep.yaml`` (each
:func:`fwsim.batch.cases.terminal_case`, from the loiter ring, ~35 s of flight),
flown with ``fwsim.batch.runner``. Prints one row per case and a summary against the
bounds (hit, miss <= 3 m, both impact-angle errors <= 3 deg); the batch's
summary (CSV, JSON, Parquet) and the logs go to ``--out``. The same sweep is
the slow test ``tests/test_terminal_sweep.py`` (``pytest -m slow``).

    python tools/terminal_sweep.py --workers 2
    python tools/terminal_sweep.py --quick            # every fifth case
    python tools/terminal_sweep.py --seed 3           # another seed
    python tools/terminal_sweep.py --set "world.wind_enu_m_s=[5, -4, 0]"   # every case in a wind
"""
from __future__ import annotations

import argparse
import sys
import time

from fwsim.batch.runner import run_batch
from fwsim.batch.cases import case_line, sweep_rows, sweep_spec
from fwsim.scenario.model import ScenarioError, parse_sets


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="every fifth case only")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default="runs/terminal_sweep", help="folder for the logs and the summary")
    ap.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                    help="override a field of every case, e.g. --set \"world.wind_enu_m_s=[5, -4, 0]\" "
                         "(repeatable)")
    args = ap.parse_args(argv)
    try:
        spec = sweep_spec(args.out, seed=args.seed, quick=args.quick, overrides=parse_sets(args.set))
    except ScenarioError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    result = run_batch(spec, args.out, workers=args.workers,
                       on_row=lambda r: print(case_line(sweep_rows([r])[0]), flush=True))
    rows = sweep_rows(result.rows)
    n_ok = sum(r["ok"] for r in rows)
    n_hit = sum(r["hit"] == 1.0 for r in rows)
    print(f"{n_ok}/{len(rows)} within 3 m / 3 deg; {n_hit}/{len(rows)} hit the ship; "
          f"wall {time.perf_counter() - t0:.0f} s on {args.workers} workers")
    for f in result.files:
        print(f)
    return 0 if n_ok == len(rows) else 1


if __name__ == "__main__":
    sys.exit(main())
