"""The NMPC solved ahead (``nmpc.solve_ahead_s``) and where it runs (``controllers.guidance.nmpc_worker``)."""
import dataclasses
import math

import numpy as np
import pytest

from controllers.config import NmpcConfig
from controllers.guidance.guidance import NmpcLoiter
from controllers.guidance.nmpc import Nmpc, NmpcStatus, predict_state, state_from_measurements
from controllers.guidance.nmpc_worker import ENV, InlineSolver, ProcessSolver, WorkerError, make_solver
from controllers.messages import TargetState
from fwsim.interface.messages import Measurements

FSW_DT = 1.0 / 30.0
SHIP_V = np.array([0.0, 5.0, 0.0])


class _Recorder:
    def __init__(self):
        self.logs, self.events = [], []

    def log(self, topic, msg):
        self.logs.append(msg)

    def event(self, text):
        self.events.append(text)


def _meas(t: float, x: np.ndarray) -> Measurements:
    """The measurements of an NMPC-convention state x (level flight at 22 m/s along psi)."""
    psi = float(x[5])
    vel = 22.0 * np.array([math.cos(psi), math.sin(psi), 0.0])
    return Measurements(t, x[:3].copy(), vel, np.array([x[3], x[4], 0.5 * math.pi - psi]), np.zeros(3), 22.0,
                        float(x[2]))


def _fly(loiter: NmpcLoiter, seconds: float) -> list:
    """A kinematic loop at the flight software's rate: the model's own state under the loiter's commands."""
    x = np.array([-700.0, 0.0, 480.0, 0.0, 0.0, 0.5 * math.pi])
    cmds = []
    for k in range(int(round(seconds / FSW_DT))):
        t = k * FSW_DT
        target = TargetState(t, "estimator", SHIP_V * t, SHIP_V.copy(), 0.5, 3.75)
        g = loiter.step(_meas(t, x), target)
        c = g.command
        cmds.append((t, c.airspeed_m_s, c.roll_rate_rad_s, c.pitch_rate_rad_s))
        x = predict_state(x, np.array([c.airspeed_m_s, c.roll_rate_rad_s, c.pitch_rate_rad_s]), FSW_DT,
                          loiter.cfg)
    return cmds


def _numbers(status: NmpcStatus) -> dict:
    """An NMPC status without its wall-clock time."""
    d = dataclasses.asdict(status)
    d.pop("solve_ms")
    return {k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else v) for k, v in d.items()}


def test_a_solve_ahead_is_the_solve_of_the_state_predicted_to_its_time(monkeypatch):
    """With solve_ahead_s = 2 ticks the loiter solves at 0 (in place), then submits the solve for 0.1 s at
    the tick 2 ticks before it, from the state carried there by the model under the command held, and the
    target carried by its velocity; the command changes at the solve's time, not at the submission."""
    monkeypatch.setenv(ENV, "inline")
    cfg = NmpcConfig.model_validate({"solve_ahead_s": 0.067})
    rec = _Recorder()
    loiter = NmpcLoiter(cfg, rec)
    ref = Nmpc(cfg)  # the same solves, made by hand
    x = np.array([-700.0, 0.0, 480.0, 0.0, 0.0, 0.5 * math.pi])
    cmds, submitted = [], []
    psi = None
    for k in range(10):
        t = k * FSW_DT
        target = TargetState(t, "estimator", SHIP_V * t, SHIP_V.copy(), 0.5, 3.75)
        m = _meas(t, x)
        x_here = state_from_measurements(m, cfg.pitch_from, psi)
        psi = float(x_here[5])
        if k == 0:
            want = ref.solve(0.0, x_here, target.pos_enu_m, SHIP_V)
        elif k in (1, 4, 7):  # 2 ticks before 0.1, 0.2, 0.3 s
            t_solve = (submitted[-1] if submitted else want).t_s + cfg.step_s  # the loiter's own clock
            u_held = Nmpc.command_input(loiter._cmd)
            x_ahead = predict_state(x_here, u_held, t_solve - t, cfg)
            submitted.append(ref.solve(t_solve, x_ahead, target.pos_enu_m + (t_solve - t) * SHIP_V, SHIP_V))
        c = loiter.step(m, target).command
        cmds.append(np.array([c.airspeed_m_s, c.roll_rate_rad_s, c.pitch_rate_rad_s]))
        x = predict_state(x, cmds[-1], FSW_DT, cfg)
    solved = [want, *submitted]
    assert [round(s.t_s, 6) for s in rec.logs] == [0.0, 0.1, 0.2, 0.3]
    for status, res in zip(rec.logs, solved):
        np.testing.assert_array_equal(status.u0, res.u0)  # bit for bit: the same solves on the same inputs
        assert status.cost == res.cost
    for k, cmd in enumerate(cmds):  # the command of the latest solve whose time has come
        res = solved[min(k // 3, len(solved) - 1)]
        np.testing.assert_array_equal(cmd, res.u0)
    assert not np.array_equal(solved[0].u0, solved[1].u0)


def test_the_worker_process_gives_the_same_numbers_as_the_loop_thread(monkeypatch):
    """Where the NMPC solves is a matter of speed: a loiter solved in the worker process logs the same
    statuses and gives the same commands, bit for bit, as one solved on the caller's thread."""
    cfg = NmpcConfig.model_validate({"solve_ahead_s": 0.067})
    runs = {}
    for kind in ("inline", "process"):
        monkeypatch.setenv(ENV, kind)
        rec = _Recorder()
        loiter = NmpcLoiter(cfg, rec)
        assert loiter.solver.kind == kind
        try:
            cmds = _fly(loiter, 3.0)
        finally:
            loiter.close()
        runs[kind] = (cmds, [_numbers(s) for s in rec.logs])
    assert len(runs["inline"][1]) == 30
    assert runs["process"] == runs["inline"]


def test_without_solving_ahead_the_loiter_solves_at_its_time(monkeypatch):
    """solve_ahead_s = 0: every solve at its own time, from the state measured then (the paper's loop)."""
    monkeypatch.delenv(ENV, raising=False)
    cfg = NmpcConfig.model_validate({"solve_ahead_s": 0.0})
    rec = _Recorder()
    loiter = NmpcLoiter(cfg, rec)
    assert loiter.solver.kind == "inline"  # auto: nothing to overlap, so no process
    ref = Nmpc(cfg)
    x = np.array([-700.0, 0.0, 480.0, 0.0, 0.0, 0.5 * math.pi])
    for k in range(7):
        t = k * FSW_DT
        target = TargetState(t, "estimator", SHIP_V * t, SHIP_V.copy(), 0.5, 3.75)
        m = _meas(t, x)
        if k % 3 == 0:
            want = ref.solve(t, ref.state_from_measurements(m), target.pos_enu_m, SHIP_V)
        c = loiter.step(m, target).command
        np.testing.assert_array_equal([c.airspeed_m_s, c.roll_rate_rad_s, c.pitch_rate_rad_s], want.u0)
        x = predict_state(x, want.u0, FSW_DT, cfg)
    assert [round(s.t_s, 6) for s in rec.logs] == [0.0, 0.1, 0.2]


def test_the_worker_choice_and_a_bad_one(monkeypatch):
    cfg = NmpcConfig.model_validate({})
    monkeypatch.setenv(ENV, "inline")
    assert isinstance(make_solver(cfg), InlineSolver)
    monkeypatch.setenv(ENV, "threads")
    with pytest.raises(ValueError, match="FWSIM_NMPC_WORKER must be auto, inline or process"):
        make_solver(cfg)


def test_a_worker_that_dies_is_a_clear_error():
    solver = ProcessSolver(NmpcConfig.model_validate({}))
    try:
        solver._proc.kill()
        solver._proc.wait()
        with pytest.raises(WorkerError, match="worker process ended"):
            solver.submit(0.0, np.array([-700.0, 0.0, 480.0, 0.0, 0.0, 0.0]), np.zeros(3), SHIP_V)
    finally:
        solver.close()


def test_a_bad_worker_choice_is_one_line_and_exit_code_2(monkeypatch, capsys):
    from fwsim.cli import main

    monkeypatch.setenv(ENV, "gpu")
    assert main(["run", "scenarios/autopilot_checkout.yaml", "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "error: environment variable FWSIM_NMPC_WORKER: must be auto, inline or process (got 'gpu')"


def test_the_worker_ends_with_its_flight_software_even_when_that_is_killed():
    """The worker process ends when its socket closes: here its parent dies without closing anything."""
    import subprocess
    import sys
    import time

    code = ("import os, sys\n"
            "from controllers.config import NmpcConfig\n"
            "from controllers.guidance.nmpc_worker import ProcessSolver\n"
            "s = ProcessSolver(NmpcConfig.model_validate({}))\n"
            "s._recv()\n"  # ready: the NMPC is built
            "print(s._proc.pid, flush=True)\n"
            "os._exit(0)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60, check=True)
    pid = int(out.stdout.split()[0])
    def ended() -> bool:
        try:
            with open(f"/proc/{pid}/stat") as f:  # a zombie (Z) has ended; whether init reaps it is not ours
                return f.read().rsplit(")", 1)[1].split()[0] in ("Z", "X")
        except FileNotFoundError:
            return True

    for _ in range(100):
        if ended():
            return
        time.sleep(0.05)
    pytest.fail(f"the worker {pid} outlived its parent by 5 s")
