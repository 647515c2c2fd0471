"""fwsim from Python: fly a scenario and read what happened, or fly a batch.

    import fwsim

    f = fwsim.fly("scenarios/paper_mission.yaml", seed=3, **{"controllers.ukf.pixel_noise_px": 3})
    f.status, f.reason                  # "completed", "hit the ship at t = 176.88 s"
    f.metrics["flight_time_s"]          # fwsim.analysis.metrics, computed from the log on first use
    f.log.table("/uav/state")           # the log (fwsim.log.RunLog), read on first use
    f.close()                           # (or ``with fwsim.fly(...) as f:``) removes a temporary log

    rows = fwsim.batch("scenarios/batches/paper_mission_seeds.yaml", workers=2)

The heavy modules (JSBSim, CasADi, the flight software) are imported by the
first call, not by ``import fwsim``. A scenario or spec that cannot be used
raises :class:`fwsim.scenario.model.ScenarioError` (one line per problem, as the
command line prints them); an error that ends a run raises too, after the log
has recorded it (a user's block: :class:`controllers.blocks.PluginError`,
naming the block, the method and the line of the user's file).
"""
from __future__ import annotations

import copy
import shutil
import tempfile
import weakref
from collections.abc import Mapping
from pathlib import Path
from types import MappingProxyType
from typing import Any

__all__ = ["fly", "batch", "Flight"]


def _resolve(scenario: Any, overrides: dict[str, Any]):
    """(Scenario, YAML text for the log) from a path, a dict or a Scenario, the overrides applied."""
    import yaml

    from fwsim.scenario.model import Scenario, ScenarioError, dump_scenario, load_scenario, parse_scenario
    if isinstance(scenario, (str, Path)):
        return load_scenario(scenario, overrides)  # a relative path from the current folder, as fwsim run
    if isinstance(scenario, Scenario):
        if not overrides:
            return scenario, dump_scenario(scenario)
        scenario = scenario.model_dump(mode="json")
    if not isinstance(scenario, Mapping):
        raise ScenarioError(f"fwsim.fly: expected a scenario file's path, a dict or a Scenario "
                            f"(got {type(scenario).__name__})")
    text = yaml.safe_dump(copy.deepcopy(dict(scenario)), sort_keys=False, allow_unicode=True)
    return parse_scenario(text, "<scenario>", overrides), text


def fly(scenario: Any, log: str | Path | None = None, **overrides: Any) -> Flight:
    """Fly a scenario (a file's path, a dict of its fields or a :class:`fwsim.scenario.model.Scenario`) and return
    its :class:`Flight`.

    ``overrides`` set fields by their dotted paths, as ``fwsim run --set`` does (``seed=3``,
    ``**{"controllers.ukf.pixel_noise_px": 3}``), with Python values. ``log``: where the MCAP log goes; without
    it a temporary file that the Flight owns and removes when it is closed or garbage-collected."""
    from fwsim.sim.loop import run

    sc, text = _resolve(scenario, overrides)
    folder = None
    if log is None:
        folder = Path(tempfile.mkdtemp(prefix="fwsim-"))
        path = folder / f"{sc.name}-seed{sc.seed}.mcap"
    else:
        path = Path(log)
    try:
        result = run(sc, text, path)
    except BaseException:
        if folder is not None:
            shutil.rmtree(folder, ignore_errors=True)  # nobody could read it: the exception says why
        raise
    return Flight(sc, result, folder)


class Flight:
    """One flown scenario: ``status`` and ``reason`` (how it ended), ``metrics`` (a read-only mapping,
    :func:`fwsim.analysis.metrics.compute_metrics`), ``log`` (:class:`fwsim.log.RunLog`), ``log_path``, ``scenario``,
    ``sim_time_s`` and ``wall_time_s``. A temporary log is removed by :meth:`close` (a context manager
    closes it too, and so does the garbage collector); ``metrics`` and ``log`` read before that stay."""

    def __init__(self, scenario, result, owned_folder: Path | None = None):
        self.scenario = scenario
        self.result = result
        self._metrics: Mapping[str, Any] | None = None
        self._log = None
        self._closed = False
        self._finalizer = (weakref.finalize(self, shutil.rmtree, str(owned_folder), True)
                           if owned_folder is not None else None)

    status = property(lambda self: self.result.status, doc="completed | failed (interrupted runs raise)")
    reason = property(lambda self: self.result.reason, doc="why it ended, e.g. 'hit the ship at t = 176.88 s'")
    log_path = property(lambda self: self.result.log_path, doc="the MCAP log")
    sim_time_s = property(lambda self: self.result.sim_time_s)
    wall_time_s = property(lambda self: self.result.wall_time_s)

    @property
    def log(self):
        """The run's log (:func:`fwsim.log.read_log`), read on first use."""
        if self._log is None:
            self._check_open("log")
            from fwsim.log import read_log
            self._log = read_log(self.log_path)
        return self._log

    @property
    def metrics(self) -> Mapping[str, Any]:
        """The run's metrics (:func:`fwsim.analysis.metrics.compute_metrics`), computed on first use."""
        if self._metrics is None:
            self._check_open("metrics")
            from fwsim.analysis.metrics import compute_metrics
            self._metrics = MappingProxyType(compute_metrics(self.log))
        return self._metrics

    def _check_open(self, what: str) -> None:
        if self._closed and self._finalizer is not None:
            raise ValueError(f"the flight is closed: its temporary log is gone ({what} was not read before)")

    def close(self) -> None:
        """Remove the temporary log (a log given to :func:`fly` stays). Idempotent."""
        self._closed = True
        if self._finalizer is not None:
            self._finalizer()

    def __enter__(self) -> Flight:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __repr__(self) -> str:
        return (f"<Flight {self.scenario.name} seed {self.scenario.seed}: {self.status}, {self.reason}; "
                f"log {self.log_path}{' (removed)' if self._closed and self._finalizer else ''}>")


def batch(spec: Any, workers: int | None = None, out: str | Path | None = None, resume: bool = False
          ) -> list[dict[str, Any]]:
    """Fly a batch (a spec file's path, or the spec as a dict: its scenario paths from the current folder) and
    return its summary rows, one dict per run in spec order (``fwsim batch``'s summary.json). ``workers``:
    parallel runs (default: the CPU count); ``out``: the folder for the logs and summary files (default
    ``runs/<the spec's name>``, as ``fwsim batch``); ``resume`` keeps runs whose log is already there."""
    from fwsim.batch.runner import run_batch
    if isinstance(spec, Mapping):
        spec = copy.deepcopy(dict(spec))
        spec.setdefault("name", "batch")
        name = str(spec["name"])
    else:
        name = Path(spec).stem
    if workers is not None and workers < 1:
        from fwsim.scenario.model import ScenarioError
        raise ScenarioError(f"fwsim.batch: workers: expected 1 or more parallel runs (got {workers})")
    result = run_batch(spec, Path(out) if out is not None else Path("runs") / name, workers=workers, resume=resume)
    return result.rows
