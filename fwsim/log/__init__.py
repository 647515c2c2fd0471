"""Run logs: one MCAP file per simulation run (see docs/guide/logs.md).

Write with :class:`LogWriter`, read back with :func:`read_log`, which returns a
:class:`RunLog`.
"""
from fwsim.log.reader import RunLog, read_log
from fwsim.log.writer import LogWriter

__all__ = ["LogWriter", "RunLog", "read_log"]
