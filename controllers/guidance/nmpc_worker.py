"""Where the NMPC's solves run: on the flight software's own thread, or in a worker process of its own.

The loiter (``controllers.guidance.guidance.NmpcLoiter``) hands each solve to a solver with ``submit`` and takes
the result with ``result``; with ``nmpc.solve_ahead_s`` it submits that long before the result is
due, so a worker process has that time to solve in while the loop goes on (a mission computer
with the NMPC on a core of its own). Both solvers run the same ``Nmpc`` on the same inputs in the same
order, so they give the same numbers, bit for bit: where a solve runs is a matter of speed, never of the
flight.

* :class:`InlineSolver` solves at ``submit`` on the caller's thread.
* :class:`ProcessSolver` solves in a process of its own (a fresh interpreter, ``python -m
  controllers.guidance.nmpc_worker``, on a socket pair), one request at a time. The process ignores the terminal's
  and a scheduler's signals (the loop decides when a run stops) and ends when its socket closes, so it
  never outlives its flight software.

``FWSIM_NMPC_WORKER`` chooses: ``inline``, ``process``, or unset (``auto``: a process when the loiter
solves ahead and the machine has a second core). ``fwsim batch`` sets ``inline`` in its workers when they
fill the machine, and in Ray tasks (one CPU each).
"""
from __future__ import annotations

import os
import signal

__all__ = ["ENV", "InlineSolver", "ProcessSolver", "WorkerError", "make_solver", "solver_kind", "worker_choice"]

ENV = "FWSIM_NMPC_WORKER"


def worker_choice() -> str:
    """``FWSIM_NMPC_WORKER``: auto (unset or empty), inline or process; ValueError for anything else."""
    choice = os.environ.get(ENV, "").strip().lower() or "auto"
    if choice not in ("auto", "inline", "process"):
        raise ValueError(f"must be auto, inline or process (got {os.environ.get(ENV)!r})")
    return choice


def solver_kind(cfg) -> str:
    """inline or process: where a loiter of this configuration solves (``FWSIM_NMPC_WORKER``, see the module
    text; auto: a process when there is a solve ahead to overlap and a second core to run it on)."""
    try:
        choice = worker_choice()
    except ValueError as exc:
        raise ValueError(f"{ENV} {exc}") from None
    if choice == "auto":
        choice = "process" if cfg.solve_ahead_s > 0.0 and (os.cpu_count() or 1) >= 2 else "inline"
    return choice


def make_solver(cfg):
    """The solver of :func:`solver_kind` (inline when a worker process cannot be started: the same numbers)."""
    if solver_kind(cfg) == "process":
        try:
            return ProcessSolver(cfg)
        except OSError as exc:
            import warnings
            warnings.warn(f"the NMPC's worker process could not start ({exc}); solving on this thread",
                          RuntimeWarning, stacklevel=2)
    return InlineSolver(cfg)


class InlineSolver:
    """Solves at ``submit``, on the caller's thread; ``result`` returns it."""

    kind = "inline"

    def __init__(self, cfg):
        from controllers.guidance.nmpc import Nmpc  # CasADi: loaded only when the NMPC flies

        self.nmpc = Nmpc(cfg)
        self._out = None

    def submit(self, t_s: float, x0, target_pos, target_vel) -> None:
        nmpc = self.nmpc
        self._out = (nmpc.solve(t_s, x0, target_pos, target_vel), nmpc.fallback_count)

    def result(self):
        """(NmpcResult, fallback count) of the last submission."""
        out, self._out = self._out, None
        return out

    def close(self) -> None:
        pass


class WorkerError(RuntimeError):
    """The NMPC's worker process failed or went away."""


def _serve(conn, cfg_json: str) -> None:
    """The worker process: build the NMPC, then answer each (t, x0, q, v) with (result, fallback count). It ends
    quietly when the flight software has gone (its socket closed: a run that ended before the NMPC was built,
    or while a solve was under way)."""
    from controllers.config import NmpcConfig
    from controllers.guidance.nmpc import Nmpc

    try:
        nmpc = Nmpc(NmpcConfig.model_validate_json(cfg_json))
    except Exception as exc:  # noqa: BLE001 - said to the flight software, which raises it
        _send(conn, ("error", f"{type(exc).__name__}: {exc}"))
        return
    if not _send(conn, ("ready", None)):
        return
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        if msg is None:
            return
        try:
            out = ("ok", (nmpc.solve(*msg), nmpc.fallback_count))
        except Exception as exc:  # noqa: BLE001
            out = ("error", f"{type(exc).__name__}: {exc}")
        if not _send(conn, out):
            return


def _send(conn, msg) -> bool:
    """Send ``msg`` to the flight software; False when it has gone (the socket closed at its end)."""
    try:
        conn.send(msg)
    except OSError:  # BrokenPipeError, ConnectionResetError: the run is over
        return False
    return True


def _main(argv: list[str]) -> int:
    """``python -m controllers.guidance.nmpc_worker FD``: serve on the socket FD; the configuration comes first."""
    from multiprocessing.connection import Connection

    for sig in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", None)):
        if sig is not None:
            signal.signal(sig, signal.SIG_IGN)  # the loop stops the run; this process ends with its socket
    conn = Connection(int(argv[0]))
    try:
        cfg_json = conn.recv()
    except (EOFError, OSError):
        return 0
    _serve(conn, cfg_json)
    return 0


class ProcessSolver:
    """Solves in a worker process (see the module text); ``result`` waits for the last submission.

    The process is a fresh interpreter (``python -m controllers.guidance.nmpc_worker``) on a socket pair: it
    imports nothing of the caller's script, and finds this package where the caller found it."""

    kind = "process"

    def __init__(self, cfg):
        import socket
        import subprocess
        import sys
        from multiprocessing.connection import Connection
        from pathlib import Path

        ours, theirs = socket.socketpair()
        root = str(Path(__file__).resolve().parent.parent)  # the folder holding this package
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH", "")) if p)
        try:
            self._proc = subprocess.Popen([sys.executable, "-m", "controllers.guidance.nmpc_worker",
                                           str(theirs.fileno())],
                                          pass_fds=(theirs.fileno(),), env=env, stdin=subprocess.DEVNULL,
                                          start_new_session=False)
        finally:
            theirs.close()
        self._conn = Connection(ours.detach())
        self._conn.send(cfg.model_dump_json())
        self._ready = False
        self._busy = False

    def _recv(self):
        try:
            kind, value = self._conn.recv()
        except (EOFError, OSError) as exc:
            raise WorkerError(f"the NMPC's worker process ended (exit code {self._proc.poll()})") from exc
        if kind == "error":
            raise WorkerError(f"the NMPC's worker process: {value}")
        return value

    def submit(self, t_s: float, x0, target_pos, target_vel) -> None:
        if not self._ready:
            self._recv()  # "ready": the NMPC is built
            self._ready = True
        if self._busy:
            raise RuntimeError("an NMPC solve is already under way")
        self._conn.send((float(t_s), x0, target_pos, target_vel))
        self._busy = True

    def result(self):
        """(NmpcResult, fallback count) of the last submission."""
        self._busy = False
        return self._recv()

    def close(self) -> None:
        if self._proc is None:
            return
        try:
            if self._busy:
                self.result()
            self._conn.send(None)
        except (WorkerError, OSError, EOFError):
            pass
        self._conn.close()
        try:
            self._proc.wait(timeout=2.0)
        except Exception:  # noqa: BLE001 - a worker that does not end is stopped
            self._proc.kill()
            self._proc.wait()
        self._proc = None

    def __del__(self):
        try:
            self.close()
        except Exception:  # noqa: BLE001 - at interpreter exit
            pass


if __name__ == "__main__":
    import sys

    raise SystemExit(_main(sys.argv[1:]))
