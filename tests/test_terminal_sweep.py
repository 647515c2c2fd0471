"""The terminal sweep (slow: ~2-3 min on 2 cores; run with ``pytest -m slow``).

Impact angles theta_f -20..-60 deg, six impact headings all round, ship courses all round at 0, 5 and
10 m/s, each flown from the loiter ring with the full flight software: the batch spec
scenarios/batches/terminal_sweep.yaml, flown with fwsim.batch.runner. Every case must hit within 3 m of the aim
point and 3 deg of both impact angles. A failure lists every failing case.
"""
import os

import pytest

from fwsim.batch.runner import run_batch
from fwsim.batch.cases import case_line, sweep_rows, sweep_spec


@pytest.mark.slow
def test_every_terminal_case_hits_within_3_m_and_3_deg(tmp_path):
    result = run_batch(sweep_spec(tmp_path), tmp_path, workers=min(4, os.cpu_count() or 1))
    rows = sweep_rows(result.rows)
    assert len(rows) == 42
    bad = [case_line(r) for r in rows if not r["ok"]]
    assert not bad, f"{len(bad)} of {len(rows)} cases outside 3 m / 3 deg:\n" + "\n".join(bad)
