"""Write docs/guide/metrics.md from the metrics table in fwsim/analysis/metrics.py (METRICS).

    python tools/gen_metrics_doc.py            # regenerate the page
    python tools/gen_metrics_doc.py --check    # exit 1 if the page is stale (what the test checks)
"""
from __future__ import annotations

import argparse
import sys

from fwsim import PROJECT_ROOT
from fwsim.analysis.metrics import metrics_doc

PAGE = PROJECT_ROOT / "docs" / "guide" / "metrics.md"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--check", action="store_true", help="write nothing; exit 1 if the page differs")
    args = p.parse_args(argv)
    text = metrics_doc() + "\n"
    if args.check:
        same = PAGE.is_file() and PAGE.read_text(encoding="utf-8") == text
        print(f"{PAGE}: {'up to date' if same else 'stale: run python tools/gen_metrics_doc.py'}")
        return 0 if same else 1
    PAGE.parent.mkdir(parents=True, exist_ok=True)
    PAGE.write_text(text, encoding="utf-8")
    print(f"wrote {PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
