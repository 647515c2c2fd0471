"""Speed and quality of the Phase 2 NMPC solvers, all in one run, against a converged IPOPT.

Each solver flies the same kinematic closed loop (controllers.guidance.nmpc.kinematic_closed_loop: the NMPC's
own continuous model as the plant, RK4, 10 Hz, exact target state):

  * ``paper``: ship at the origin sailing north at 5 m/s, UAV 800 m west of it at 600 m, heading
    north, R = H = 500 m, N = 50, T_s = 0.1 s, CBF on (the loiter geometry of the paper);
  * ``cbf``: a geometry where the CBF binds: R = 200 m, H = 150 m, UAV 600 m east of the ship at
    150 m heading north, so the unconstrained NMPC banks 35 deg toward a target only 14 deg below
    the horizon (the row ``unconstrained`` shows that violation).

For every step of a fast solver's loop, a shadow IPOPT (exact Hessian, tol 1e-8, warm-started from
its own previous solution) solves the very same problem (same state, target and previous input);
the cost gap compares the two plans' costs on the model (controllers.guidance.nmpc.Nmpc.plan_cost).

    python tools/bench_nmpc.py                 # both scenarios, 150 s / 60 s
    python tools/bench_nmpc.py --quick         # 60 s / 30 s, shadow IPOPT every 5th step
    python tools/bench_nmpc.py --json out.json

Columns: wall median / p99 of NmpcResult.solve_ms (what the 10 Hz loop sees), CPU median / p99
(process time of the call: the solver's own cost, without the machine's other load), mean QP/NLP
iterations, cost gap to IPOPT (median and max, %), closed-loop radius and altitude RMS (whole run
and last 60 s), realised and predicted min h, fallbacks.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import casadi  # noqa: E402

from controllers.guidance.nmpc import Nmpc, NmpcConfig, kinematic_closed_loop  # noqa: E402

SCENARIOS = {
    "paper": dict(cfg={}, x0=[-800.0, 0.0, 600.0, 0.0, 0.0, math.pi / 2], q0=[0.0, 0.0, 0.0],
                  v=[0.0, 5.0, 0.0], duration_s=150.0),
    "cbf": dict(cfg={"radius_m": 200.0, "altitude_m": 150.0}, x0=[600.0, 0.0, 150.0, 0.0, 0.0, math.pi / 2],
                q0=[0.0, 0.0, 0.0], v=[0.0, 5.0, 0.0], duration_s=60.0),
}

# (row label, config overrides, shadow IPOPT cost gap)
SOLVERS = [
    ("ipopt (reference)", {"solver": "ipopt"}, False),
    ("fatrop", {"solver": "fatrop"}, True),
    ("rti_hpipm exact-H x1", {"solver": "rti_hpipm"}, True),
    ("rti_hpipm exact-H x2", {"solver": "rti_hpipm", "rti_iterations": 2}, True),
    ("rti_hpipm gauss-newton x1", {"solver": "rti_hpipm", "hessian": "gauss_newton"}, True),
]


def _rms(a) -> float:
    return float(np.sqrt(np.mean(np.square(a)))) if len(a) else math.nan


def run_one(label, overrides, scen, duration_s, gap_every, no_budget=True):
    base = dict(scen["cfg"])
    budget = {"max_solve_ms": 1e5} if no_budget else {"budget": "wall_clock"}
    cfg = NmpcConfig.model_validate({**base, **overrides, **budget})
    nmpc = Nmpc(cfg)
    ref = Nmpc(NmpcConfig.model_validate({**base, "solver": "ipopt", "max_solve_ms": 1e5})) if gap_every else None
    gaps = []
    step = [0]

    def observer(t, x, q, v, r, u_prev):
        k = step[0]
        step[0] += 1
        if ref is None or r.fallback or (k % gap_every):
            return
        rr = ref.solve(t, x, q, v, u_prev=u_prev)
        if rr.fallback:
            return
        j_fast = nmpc.plan_cost(x, q, v, r.inputs, u_prev)
        j_ref = nmpc.plan_cost(x, q, v, rr.inputs, u_prev)
        gaps.append((j_fast - j_ref) / max(abs(j_ref), 1e-9))

    t0 = time.perf_counter()
    run = kinematic_closed_loop(nmpc, scen["x0"], scen["q0"], scen["v"], duration_s, observer=observer)
    wall_s = time.perf_counter() - t0
    warm = slice(1, None)  # the first (cold) solve is reported separately
    last = run.t_s >= duration_s - 60.0
    g = np.array(gaps) * 100.0
    return {
        "solver": label,
        "wall_median_ms": float(np.median(run.solve_ms[warm])),
        "wall_p99_ms": float(np.percentile(run.solve_ms[warm], 99)),
        "cpu_median_ms": float(np.median(run.cpu_ms[warm])),
        "cpu_p99_ms": float(np.percentile(run.cpu_ms[warm], 99)),
        "first_solve_ms": float(run.solve_ms[0]),
        "iterations_mean": float(np.mean(run.iterations[warm])),
        "cost_gap_median_pct": float(np.median(g)) if g.size else 0.0,
        "cost_gap_max_pct": float(np.max(g)) if g.size else 0.0,
        "radius_rmse_m": _rms(run.radius_err_m),
        "altitude_rmse_m": _rms(run.altitude_err_m),
        "radius_rmse_last60_m": _rms(run.radius_err_m[last]),
        "altitude_rmse_last60_m": _rms(run.altitude_err_m[last]),
        "min_h_deg": math.degrees(float(np.min(run.h))),
        "min_h_pred_deg": math.degrees(float(np.nanmin(run.min_h_pred))),
        "h_violations": int(np.sum(run.h < 0.0)),
        "fallbacks": run.fallbacks,
        "loop_wall_s": wall_s,
        "_run": run,
    }


def euler_vs_rk4(scen) -> float:
    """Largest position gap (m) over the horizon between the Euler prediction and an RK4 (10 substeps) flight
    of the same converged plan, at a point of the approach where the UAV banks hard."""
    from controllers.guidance.nmpc import _np_step  # the model's own numpy step

    cfg = NmpcConfig.model_validate({**scen["cfg"], "solver": "ipopt", "max_solve_ms": 1e5})
    nmpc = Nmpc(cfg)
    worst = 0.0
    run = kinematic_closed_loop(nmpc, scen["x0"], scen["q0"], scen["v"], 20.0, keep_results=True)
    for r in run.results[::20]:
        x = r.predicted[0].copy()
        for k, u in enumerate(r.inputs):
            for _ in range(10):
                x = _np_step(x, u, cfg.step_s / 10, "rk4")
            worst = max(worst, float(np.linalg.norm(x[:3] - r.predicted[k + 1, :3])))
    return worst


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="60 s / 30 s runs, shadow IPOPT every 5th step")
    ap.add_argument("--gap-every", type=int, default=None, help="shadow IPOPT every k-th step (default 1, quick 5)")
    ap.add_argument("--scenario", choices=sorted(SCENARIOS), action="append", help="default: all")
    ap.add_argument("--json", type=Path, help="write the table as JSON")
    ap.add_argument("--with-qrqp", action="store_true", help="also time rti_qrqp (slow: 20 s runs, no gap)")
    args = ap.parse_args(argv)
    gap_every = args.gap_every or (5 if args.quick else 1)
    load = os.getloadavg() if hasattr(os, "getloadavg") else (math.nan,) * 3
    print(f"casadi {casadi.__version__}, python {platform.python_version()}, {os.cpu_count()} cpus, "
          f"load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    out = {}
    for name in args.scenario or ["paper", "cbf"]:
        scen = SCENARIOS[name]
        dur = scen["duration_s"] if not args.quick else scen["duration_s"] / (2.5 if name == "paper" else 2.0)
        rows = []
        solvers = list(SOLVERS)
        if name == "cbf":
            solvers.append(("rti_hpipm unconstrained", {"solver": "rti_hpipm", "cbf": {"enabled": False}}, False))
        if args.with_qrqp:
            solvers.append(("rti_qrqp exact-H x1", {"solver": "rti_qrqp"}, False))
        for label, over, gap in solvers:
            d = 20.0 if "qrqp" in label else dur
            rows.append(run_one(label, over, scen, d, gap_every if gap else 0))
        ref = rows[0]
        for r in rows:
            r["radius_rmse_vs_ipopt_pct"] = 100.0 * (r["radius_rmse_m"] / ref["radius_rmse_m"] - 1.0)
            r["altitude_rmse_vs_ipopt_pct"] = 100.0 * (r["altitude_rmse_m"] / ref["altitude_rmse_m"] - 1.0)
        print(f"\nscenario {name}: {dur:.0f} s closed loop, N = 50, T_s = 0.1 s, CBF "
              f"{'on' if NmpcConfig.model_validate(scen['cfg']).cbf.enabled else 'off'}; cost gap vs. a shadow "
              f"IPOPT every {gap_every} step(s)")
        hdr = ("| solver | wall med ms | wall p99 ms | cpu med ms | cpu p99 ms | 1st solve ms | iters | "
               "cost gap med/max % | radius RMSE m (vs ipopt) | alt RMSE m (vs ipopt) | last 60 s R/H RMSE m | "
               "min h deg real/pred | h<0 steps | fallbacks |")
        print(hdr)
        print("|" + "---|" * (hdr.count("|") - 1))
        for r in rows:
            print(f"| {r['solver']} | {r['wall_median_ms']:.2f} | {r['wall_p99_ms']:.2f} | {r['cpu_median_ms']:.2f} | "
                  f"{r['cpu_p99_ms']:.2f} | {r['first_solve_ms']:.1f} | {r['iterations_mean']:.1f} | "
                  f"{r['cost_gap_median_pct']:.4f} / {r['cost_gap_max_pct']:.3f} | "
                  f"{r['radius_rmse_m']:.2f} ({r['radius_rmse_vs_ipopt_pct']:+.2f} %) | "
                  f"{r['altitude_rmse_m']:.2f} ({r['altitude_rmse_vs_ipopt_pct']:+.2f} %) | "
                  f"{r['radius_rmse_last60_m']:.2f} / {r['altitude_rmse_last60_m']:.3f} | "
                  f"{r['min_h_deg']:.2f} / {r['min_h_pred_deg']:.2f} | {r['h_violations']} | {r['fallbacks']} |")
        out[name] = [{k: v for k, v in r.items() if not k.startswith("_")} for r in rows]
    gap = euler_vs_rk4(SCENARIOS["paper"])
    print(f"\nEuler vs RK4 over the 5 s horizon (converged plans of the approach): max position gap {gap:.2f} m")
    out["euler_vs_rk4_max_gap_m"] = gap
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
