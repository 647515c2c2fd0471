"""The ``fwsim`` command's entry point: signal handling first, then the command line.

SIGTERM (what a batch scheduler, a container or Ray sends) and SIGHUP (a closed terminal) end the command as
Ctrl-C does from the first instant, even while the heavy modules are still importing: one line, exit code
128 + the signal's number, no traceback. Once a run flies, :mod:`fwsim.sim.loop` takes the signals over so that
the log is closed with ``run_status: interrupted`` and the signal's name.
"""
from __future__ import annotations

import signal
import sys


class Signalled(KeyboardInterrupt):
    """A terminating signal, raised in the main thread like Ctrl-C's KeyboardInterrupt (``signum`` says which)."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


#: the signals that end a command as Ctrl-C does (SIGHUP only where the platform has it)
STOP_SIGNALS = tuple(s for s in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", None)) if s is not None)


def _raise(signum, frame):
    raise Signalled(signum)


def exit_code(exc: BaseException) -> int:
    """128 + the signal's number: 130 for Ctrl-C, 143 for SIGTERM, 129 for SIGHUP."""
    return 128 + int(getattr(exc, "signum", signal.SIGINT))


def main() -> int:
    try:
        for sig in STOP_SIGNALS[1:]:  # (inside the try: a signal may land as soon as its handler is in)
            signal.signal(sig, _raise)
        from fwsim.cli import main as cli_main

        return cli_main()
    except KeyboardInterrupt as exc:  # during start-up (the commands handle their own once they work)
        code = exit_code(exc)
        print(f"interrupted ({signal.Signals(code - 128).name}) before anything was written", file=sys.stderr)
        return code


if __name__ == "__main__":
    sys.exit(main())
