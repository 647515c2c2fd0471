"""The envelope sweep's verdict: issue 16's four bars, estimator by estimator, from a batch's summary.

    fwsim batch scenarios/batches/envelope.yaml --workers 2 --out runs/envelope
    fwsim batch scenarios/batches/envelope_ct_ukf.yaml --workers 2 --out runs/envelope_ct_ukf  # same draws
    python tools/envelope.py runs/envelope runs/envelope_ct_ukf   # a Markdown table: each bar, each estimator
    python tools/envelope.py runs/envelope --by set.target.motion  # split another way

The bars, over the runs of each group: every run hits the ship; >= 95 % hit within 3 m of the aim point
and 3 deg of both impact angles; >= 95 % keep the ship in view >= 99 % of the time after the lock; >= 90 %
keep the estimator's horizontal error within 8 m after it has converged (its own std under 5 m; a run
whose estimate never converges counts against this bar). A last
column says whether that std is honest: the median run's share of estimates whose error is within twice
it (about 86 % or more for a consistent filter). The statistics are fwsim report's (fwsim.report.summarise).
Exit code 0 when every group meets every bar.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from collections import defaultdict
from pathlib import Path

from fwsim.report import summarise

BARS = (("hits", 1.0), ("within 3 m / 3 deg", 0.95), ("in view >= 99 %", 0.95), ("estimate <= 8 m", 0.90))


def _label(value) -> str:
    if isinstance(value, dict):
        return str(value.get("model", value))
    return "(the scenario's)" if value is None or (isinstance(value, float) and math.isnan(value)) else str(value)


def verdict(rows: list[dict], by: str) -> list[tuple[str, int, list[float], float]]:
    """(group, runs, [share per bar], the median run's share of estimates within 2 std of their error) for
    each value of the column ``by``."""
    groups: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        groups[_label(r.get(by))].append(r)
    out = []
    for name, rs in sorted(groups.items()):
        rep = summarise(rs, name)
        out.append((name, rep.runs, [rep.hits / rep.runs if rep.runs else math.nan, rep.within_3m_3deg,
                                     rep.in_view_after_lock["share_99"], rep.estimator_error_m["share_8m"]],
                    rep.estimator_error_m["within_2std_median"]))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out_dirs", type=Path, nargs="+", help="output folders of fwsim batch (with summary.json)")
    ap.add_argument("--by", default="set.controllers.estimator",
                    help="the summary column to group by (default: the estimator)")
    args = ap.parse_args(argv)
    rows = []
    for out_dir in args.out_dirs:
        try:
            rows += json.loads((out_dir / "summary.json").read_text())["rows"]
        except (OSError, ValueError, KeyError, TypeError) as exc:
            print(f"error: {out_dir}/summary.json: {type(exc).__name__}: {exc}", file=sys.stderr)
            return 2
    table = verdict(rows, args.by)
    print(f"| {args.by} | runs | " + " | ".join(f"{name} (bar {100 * bar:.0f} %)" for name, bar in BARS)
          + " | estimate within 2 std, median run (honest: 86 % for a round error, up to 95 % for a long thin one) |")
    print("|---|---|" + "---|" * (len(BARS) + 1))
    ok = True
    for name, n, shares, cover in table:
        cells = []
        for share, (_, bar) in zip(shares, BARS):
            met = share >= bar - 1e-12
            ok &= met
            cells.append(f"{100 * share:.0f} %" + ("" if met else " (not met)"))
        cells.append(f"{100 * cover:.0f} %" if math.isfinite(cover) else "-")
        print(f"| {name} | {n} | " + " | ".join(cells) + " |")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
