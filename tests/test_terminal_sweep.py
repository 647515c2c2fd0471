"""The terminal sweep of issue 6 (slow: ~2-3 min on 2 cores; run with ``pytest -m slow``).

Impact angles theta_f -20..-60 deg, six impact headings all round, ship courses all round at 0, 5 and
10 m/s, each flown from the loiter ring with the full flight software (fwsim.cases): every case must hit
within 3 m of the aim point and 3 deg of both impact angles. A failure lists every failing case.
"""
import itertools
import os
from concurrent.futures import ProcessPoolExecutor

import pytest

from fwsim.cases import case_line, fly_case, sweep_cases


@pytest.mark.slow
def test_every_terminal_case_hits_within_3_m_and_3_deg(tmp_path):
    cases = sweep_cases()
    with ProcessPoolExecutor(min(4, os.cpu_count() or 1)) as pool:
        rows = list(pool.map(fly_case, cases, itertools.repeat(str(tmp_path))))
    bad = [case_line(r) for r in rows if not r["ok"]]
    assert not bad, f"{len(bad)} of {len(rows)} cases outside 3 m / 3 deg:\n" + "\n".join(bad)
