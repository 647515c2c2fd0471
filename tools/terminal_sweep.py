"""Sweep the terminal phase over impact angles and ship courses/speeds (JSBSim, full flight software).

Each case is :func:`fwsim.cases.terminal_case` (from the loiter ring, ~35 s of
flight); cases run on a process pool. Prints one row per case and a summary
against the bounds (hit, miss <= 3 m, both impact-angle errors <= 3 deg), and
writes the rows as CSV.

    python tools/terminal_sweep.py --workers 2 --csv runs/terminal_sweep.csv
    python tools/terminal_sweep.py --quick            # 8 cases
"""
from __future__ import annotations

import argparse
import csv
import itertools
import math
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import yaml

KEYS = ["hit", "miss_distance_m", "impact_fpa_error_deg", "impact_heading_error_deg", "switch_time_s",
        "impact_time_s", "ukf_pos_err_max_after_convergence_m", "target_in_fov_fraction_after_lock"]


def cases(quick: bool) -> list[tuple[float, float, float, float]]:
    """(theta_f, psi_f, ship heading, ship speed): impact angles x six headings, the ship's course and
    speed cycling through 0/5/10 m/s and six courses relative to psi_f; then the paper's angles against
    ship courses all round at 0, 5 and 10 m/s."""
    speeds, rel = [0.0, 5.0, 10.0], [0.0, 90.0, 180.0, 270.0, 45.0, 135.0]
    out = []
    for i, (tf, pf) in enumerate(itertools.product([-20.0, -30.0, -40.0, -50.0, -60.0], range(0, 360, 60))):
        out.append((tf, float(pf), (pf + rel[i % 6]) % 360.0, speeds[i % 3]))
    out += [(-30.0, 30.0, float(sh), v) for sh in (0, 90, 180, 270) for v in speeds]
    return out[::5] if quick else out


def fly(case, out_dir: str, seed: int) -> dict:
    from fwsim.cases import terminal_case
    from fwsim.loop import run
    from fwsim.metrics import compute_metrics
    from fwsim.scenario import parse_scenario
    d = terminal_case(*case, seed=seed)
    text = yaml.safe_dump(d, sort_keys=False)
    sc = parse_scenario(text)
    t0 = time.perf_counter()
    res = run(sc, text, Path(out_dir) / f"{sc.name}.mcap")
    m = compute_metrics(res.log_path)
    row = {"theta_f_deg": case[0], "psi_f_deg": case[1], "ship_heading_deg": case[2], "ship_speed_m_s": case[3],
           "wall_s": round(time.perf_counter() - t0, 2), "end": res.reason}
    row.update({k: m.get(k, math.nan) for k in KEYS})
    row["ok"] = bool(row["hit"] == 1.0 and row["miss_distance_m"] <= 3.0
                     and abs(row["impact_fpa_error_deg"]) <= 3.0 and abs(row["impact_heading_error_deg"]) <= 3.0)
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--quick", action="store_true", help="every fifth case only")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default="runs/terminal_sweep", help="folder for the logs")
    ap.add_argument("--csv", help="write the rows here")
    args = ap.parse_args(argv)
    todo = cases(args.quick)
    Path(args.out).mkdir(parents=True, exist_ok=True)
    rows = []
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        for row in pool.map(fly, todo, itertools.repeat(args.out), itertools.repeat(args.seed)):
            rows.append(row)
            print(f"{'ok ' if row['ok'] else 'BAD'} theta_f {row['theta_f_deg']:+4.0f} psi_f {row['psi_f_deg']:3.0f} "
                  f"ship {row['ship_heading_deg']:3.0f} deg @ {row['ship_speed_m_s']:4.1f} m/s | hit {row['hit']:.0f} "
                  f"miss {row['miss_distance_m']:7.2f} m  fpa err {row['impact_fpa_error_deg']:+6.2f}  "
                  f"heading err {row['impact_heading_error_deg']:+6.2f} deg | {row['end']}", flush=True)
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
