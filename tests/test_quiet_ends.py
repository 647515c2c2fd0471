"""No traceback from the project's own code and no JSBSim chatter, however a run ends (the command line run as a
user runs it: a process of its own)."""
from __future__ import annotations

import os
import subprocess
import sys

from fwsim import PROJECT_ROOT, SCENARIO_DIR


def _fwsim(*args, env_extra=None):
    env = dict(os.environ, PYTHONPATH=str(PROJECT_ROOT), **(env_extra or {}))
    return subprocess.run([sys.executable, "-c", "import sys; from fwsim._entry import main; sys.exit(main())",
                           *args], capture_output=True, text=True, env=env, cwd=PROJECT_ROOT, timeout=300)


def test_a_mission_that_ends_before_the_nmpc_worker_is_ready_ends_quietly(tmp_path):
    """8 s of the paper mission: the run is over before the NMPC's worker process has built its solver; the
    worker finds its socket closed and leaves without a BrokenPipeError."""
    out = _fwsim("run", str(SCENARIO_DIR / "paper_mission.yaml"), "--set", "duration_s=8", "--log",
                 str(tmp_path / "short.mcap"), "--quiet", env_extra={"FWSIM_NMPC_WORKER": "process"})
    assert out.returncode == 0, out.stderr
    assert "Traceback" not in out.stderr and "BrokenPipe" not in out.stderr, out.stderr
    assert "completed: duration reached" in out.stderr


def test_a_trim_failure_is_our_one_line_with_jsbsims_reason_and_nothing_on_stdout(tmp_path):
    """An airspeed the aircraft cannot trim at: JSBSim's own "Sorry, ... doesn't appear to be trimmable" goes
    into the error line instead of onto stdout."""
    out = _fwsim("run", str(SCENARIO_DIR / "autopilot_checkout.yaml"), "--set", "initial.airspeed_m_s=59", "--log",
                 str(tmp_path / "trim.mcap"), "--quiet")
    assert out.returncode == 1
    assert "Sorry" not in out.stdout and "trimmable" not in out.stdout, out.stdout
    lines = [ln for ln in out.stderr.splitlines() if ln.startswith("run failed")]
    assert len(lines) == 1 and "JSBSim trim failed at 59.0 m/s" in lines[0], out.stderr
    assert "doesn't appear to be trimmable)" in lines[0] and "Traceback" not in out.stderr
