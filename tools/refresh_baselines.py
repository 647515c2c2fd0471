"""Re-fly the regression baselines and rewrite their metrics, on purpose.

    python tools/refresh_baselines.py                    # every tests/baselines/*.yaml
    python tools/refresh_baselines.py tests/baselines/paper_mission.yaml
    python tools/refresh_baselines.py --check            # compare only, write nothing

For each baseline: fly its scenario with its overrides, print the comparison
with the stored metrics (what moved, by how much, against which tolerance),
then rewrite everything below the marker line (``recorded:`` and
``metrics:``). The description, scenario, overrides, tolerances and comments
above the marker are kept. Review the printed table (and the diff in git)
before committing the new numbers.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

from fwsim import PROJECT_ROOT
from fwsim.analysis.compare import compare_metrics, fly_baseline, load_baseline, write_baseline_metrics

BASELINE_DIR = PROJECT_ROOT / "tests" / "baselines"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("baselines", nargs="*", type=Path, help="baseline files (default: tests/baselines/*.yaml)")
    p.add_argument("--check", action="store_true",
                   help="compare only; exit 1 if any metric moved beyond its tolerance (improvements too)")
    args = p.parse_args(argv)
    paths = args.baselines or sorted(BASELINE_DIR.glob("*.yaml"))
    failed = 0
    with tempfile.TemporaryDirectory() as tmp:
        for path in paths:
            baseline = load_baseline(path, require_metrics=False)
            metrics = fly_baseline(baseline, Path(tmp) / f"{path.stem}.mcap")
            cmp = compare_metrics(baseline.metrics, metrics, baseline.tolerances, str(path), "re-flown now",
                                  strict=True)
            print(cmp.format_text(), end="\n\n")
            failed += not cmp.ok
            if not args.check:
                write_baseline_metrics(path, metrics)
                print(f"wrote {path}\n")
    return 1 if args.check and failed else 0


if __name__ == "__main__":
    sys.exit(main())
