"""Many runs from one batch spec: a local process pool, or Ray tasks.

A batch spec (YAML) lists scenario files and what to sweep::

    name: airspeed_sweep                 # optional; defaults to the spec's file name
    runs:
      - scenario: ../scenarios/autopilot_checkout.yaml   # relative to this file
        seeds: [1, 2, 3]                 # or {range: [1, 9]} (Python's range: 1..8),
                                         # or omitted: the scenario's own seed
        grid:                            # cartesian product, by scenario field path
          initial.airspeed_m_s: [20, 24]
          initial.heading_deg: [0, 90]
        set: {duration_s: 20}            # fixed overrides for every run of this entry
      - generator: fwsim.batch.cases:terminal_case   # or a generated scenario: a function -> scenario dict
        cases:                           # one run per case: the function's keyword arguments
          - {theta_f_deg: -30, psi_f_deg: 30, ship_heading_deg: 0, ship_speed_m_s: 5}
        args: {duration_s: 90}           # keyword arguments for every case
        seeds: [1]
      - scenario: ../scenarios/paper_mission.yaml   # or Monte Carlo draws (fwsim.batch.dispersions)
        samples: 100                     # sample k flies the scenario's seed + k
        dispersions: {target.speed_m_s: {uniform: [0, 10]}, target.heading_deg: {uniform_angle_deg: true}}

The spec's top-level ``seed:`` seeds the dispersions' draws. Every run gets
a stable id ``<scenario name>-s<seed>-<hash>``, where the hash
is the first 8 hex digits of the SHA-256 of its overrides (``set`` + one grid
point, canonical JSON; for a generated scenario its arguments too), and writes
its log to ``OUT/logs/<id>.mcap``. A generated run's arguments are columns
``case.<name>`` of the summary. Each run
becomes one summary row (:data:`BASE_COLUMNS`, one ``set.<path>`` column per
override, then every metric of :func:`fwsim.analysis.metrics.compute_metrics`); a run
that raises is a failed row with its error, never a lost batch. The summary is
written as ``OUT/summary.csv``, ``OUT/summary.json`` and, when pyarrow is
importable, ``OUT/summary.parquet``.

Runs go to a local process pool (spawn context) or, with ``ray_address``, to
Ray remote tasks running the same :func:`run_one`.
"""
from __future__ import annotations

import copy
import csv
import ctypes
import hashlib
import itertools
import json
import math
import multiprocessing
import os
import re
import signal
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Callable

import fwsim
from fwsim.scenario.model import ScenarioError, load_scenario
from fwsim.scenario.yamlfile import load_yaml_file

#: Columns every summary row has, in this order; ``set.<path>`` override
#: columns follow, then the metrics.
BASE_COLUMNS = ("id", "scenario", "seed", "overrides", "status", "reason", "error", "wall_time_s", "log",
                "resumed")
#: Statuses of a finished log that ``--resume`` keeps.
FINISHED_STATUSES = ("completed", "failed")
_SPEC_KEYS = {"name", "runs", "seed"}
_RUN_KEYS = {"scenario", "generator", "cases", "args", "seeds", "grid", "set", "dispersions", "samples"}


class BatchSpecError(ScenarioError):
    """A batch spec that cannot be used; ``str()`` is one line per problem."""


@dataclass(frozen=True)
class RunJob:
    """One run of a batch: everything a worker needs (picklable, no live objects)."""

    id: str
    scenario: str  # scenario name (after overrides)
    scenario_file: str  # absolute path ("" for a generated scenario)
    seed: int
    overrides: dict[str, Any]  # every override except the seed
    log_path: str  # absolute path of its MCAP log
    generator: str = ""  # "module:function" making the scenario (a dict) from the case's arguments
    case: dict[str, Any] = field(default_factory=dict)  # those arguments
    dispersed: tuple[str, ...] = ()  # the override paths drawn from distributions (fwsim.batch.dispersions)

    def all_overrides(self) -> dict[str, Any]:
        return {**self.overrides, "seed": self.seed}

    def scenario_text(self) -> str:
        """The scenario's YAML as the run reads it (before the overrides)."""
        return _load(self.scenario_file, self.generator, self.case, self.all_overrides())[1]

    def load(self):
        """(scenario, text) of this run, the overrides applied."""
        return _load(self.scenario_file, self.generator, self.case, self.all_overrides())


def _generator(path: str) -> Callable[..., dict]:
    """The scenario generator at ``module:function``; BatchSpecError if there is none."""
    import importlib
    module, _, name = path.partition(":")
    try:
        fn = getattr(importlib.import_module(module), name, None)
    except ImportError as exc:
        raise BatchSpecError(f"generator {path!r}: cannot import {module!r}: {exc}") from None
    if not callable(fn):
        raise BatchSpecError(f"generator {path!r}: {module!r} has no function {name!r}")
    return fn


@dataclass
class BatchResult:
    rows: list[dict[str, Any]]  # in spec order
    out_dir: Path
    files: list[Path] = field(default_factory=list)  # summary files written
    resumed: int = 0  # rows recomputed from existing logs
    interrupted: bool = False

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [r for r in self.rows if r["status"] != "completed"]


# -- the spec ---------------------------------------------------------------

def _canonical(overrides: dict[str, Any]) -> str:
    return json.dumps(overrides, sort_keys=True, separators=(",", ":"))


def run_id(scenario_name: str, seed: int, overrides: dict[str, Any]) -> str:
    """``<name>-s<seed>-<8 hex>``: stable across machines and spec edits that keep the run."""
    digest = hashlib.sha256(_canonical(overrides).encode()).hexdigest()[:8]
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", scenario_name)
    return f"{safe}-s{seed}-{digest}"


def _seeds(value: Any, where: str) -> list[int] | None:
    if value is None:
        return None
    if isinstance(value, dict):
        if set(value) != {"range"}:
            raise BatchSpecError(f"{where}.seeds: expected a list of seeds or {{range: [start, stop]}}")
        r = value["range"]
        if not (isinstance(r, list) and 2 <= len(r) <= 3 and all(isinstance(x, int) for x in r)):
            raise BatchSpecError(f"{where}.seeds.range: expected [start, stop] or [start, stop, step] "
                                 f"integers (got {r!r})")
        seeds = list(range(*r))
    elif isinstance(value, list):
        seeds = value
    else:
        seeds = [value]
    if not seeds or not all(isinstance(s, int) and not isinstance(s, bool) and s >= 0 for s in seeds):
        raise BatchSpecError(f"{where}.seeds: expected a non-empty list of integers >= 0 (got {value!r})")
    return seeds


@dataclass(frozen=True)
class SpecChanges:
    """Changes to a spec from the command line (``fwsim batch --seed/--set/--hold``), applied to every entry.

    ``seed``: the dispersions' draws' seed instead of the spec's (the same envelope, other draws).
    ``sets``: fixed overrides added to each entry's ``set``; a dispersed field set here is no longer drawn.
    ``hold``: dispersed fields no longer drawn (they keep the scenario's value); a path holds every
    dispersed field at or under it (``camera.detector`` holds its noise, misses and latency). The other
    fields' draws are as they were (each field draws from its own stream), so the batch flies the same
    draws with one factor held: what that factor costs.
    ``only``: fly only the runs of these scenario seeds (``fwsim batch --only``; sample k of a dispersed entry
    flies the scenario's seed plus k): the draws are made for the whole spec first, so each run kept is the
    same draw as in the whole batch, flown again (with ``sets``: flown with a change) in a fraction of the time.
    """

    seed: int | None = None
    sets: dict[str, Any] = field(default_factory=dict)
    hold: tuple[str, ...] = ()
    only: tuple[int, ...] = ()

    def __bool__(self) -> bool:
        return self.seed is not None or bool(self.sets) or bool(self.hold) or bool(self.only)

    def describe(self) -> dict[str, Any]:
        """For the summary's ``batch`` info (empty parts left out)."""
        return {k: v for k, v in (("seed", self.seed), ("set", self.sets), ("hold", list(self.hold)),
                                  ("only", list(self.only)))
                if v is not None and v != {} and v != []}


def _under(path: str, prefix: str) -> bool:
    return path == prefix or path.startswith(prefix + ".")


def _apply_changes(data: dict, path: Path, changes: SpecChanges) -> None:
    """``changes`` applied to a parsed spec in place (BatchSpecError naming the option on a mismatch)."""
    if changes.seed is not None:
        data["seed"] = changes.seed
    held: set[str] = set()
    for i, entry in enumerate(data["runs"]):
        if not isinstance(entry, dict):
            continue  # reported by _entry_jobs
        if changes.sets:
            fixed = entry.get("set") or {}
            if not isinstance(fixed, dict):
                continue  # reported by _entry_jobs
            entry["set"] = {**fixed, **changes.sets}
        disp = entry.get("dispersions")
        if not isinstance(disp, dict):
            continue
        drop = {p for p in disp if any(_under(str(p), h) for h in (*changes.hold, *changes.sets))}
        held |= {h for h in changes.hold for p in drop if _under(str(p), h)}
        if drop and drop == set(disp):
            raise BatchSpecError(f"{path}: runs.{i}: --hold/--set leave none of its dispersions to draw "
                                 f"({', '.join(sorted(map(str, drop)))})")
        entry["dispersions"] = {p: d for p, d in disp.items() if p not in drop}
    for h in changes.hold:
        if h not in held:
            raise BatchSpecError(f"--hold {h}: no entry of {path.name} disperses a field at or under it")


def load_spec(path: str | Path | dict, out_dir: str | Path, changes: SpecChanges | None = None
              ) -> tuple[str, list[RunJob]]:
    """Read a batch spec and expand it into jobs (validating every scenario once).

    Returns ``(batch name, jobs)`` in spec order: entries in order, then grid
    points (cartesian product in the order the keys are written), then seeds.
    ``changes``: the command line's changes to every entry (:class:`SpecChanges`).
    Raises :class:`BatchSpecError` (or ScenarioError for a bad scenario) with
    one line per problem.
    """
    if isinstance(path, dict):  # a spec given as data (fwsim.batch): its scenario paths from the current folder
        data, path = copy.deepcopy(path), Path("<spec>")
    else:
        path = Path(path)
        data = load_yaml_file(path, "batch spec", BatchSpecError)
    if not isinstance(data, dict) or not isinstance(data.get("runs"), list) or not data["runs"]:
        raise BatchSpecError(f"{path}: expected a mapping with a non-empty 'runs:' list")
    unknown = set(data) - _SPEC_KEYS
    if unknown:
        raise BatchSpecError(f"{path}: {sorted(unknown)[0]}: unknown key (allowed: {sorted(_SPEC_KEYS)})")
    if changes:
        _apply_changes(data, path, changes)
    name = str(data.get("name") or path.stem)
    seed = data.get("seed", 0)
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise BatchSpecError(f"{path}: seed: expected an integer >= 0 for the dispersions' draws (got {seed!r})")
    logs = Path(out_dir).resolve() / "logs"
    jobs: list[RunJob] = []
    for i, entry in enumerate(data["runs"]):
        jobs += _entry_jobs(path, i, entry, logs, seed)
    if changes is not None and changes.only:
        flown = {j.seed for j in jobs}
        absent = [s for s in changes.only if s not in flown]
        if absent:
            raise BatchSpecError(f"--only {absent[0]}: no run of {path.name} flies that scenario seed (its "
                                 f"seeds: {_seed_ranges(sorted(flown))})")
        keep = set(changes.only)
        jobs = [j for j in jobs if j.seed in keep]
    seen: dict[str, int] = {}
    for j in jobs:
        seen[j.id] = seen.get(j.id, 0) + 1
    dup = [k for k, n in seen.items() if n > 1]
    if dup:
        raise BatchSpecError(f"{path}: {len(dup)} run id(s) appear more than once (same scenario name, seed and "
                             f"overrides), e.g. {dup[0]}")
    return name, jobs


def _seed_ranges(seeds: list[int]) -> str:
    """Sorted seeds as ranges: [7, 8, 9, 12] -> "7-9, 12"."""
    runs: list[list[int]] = []
    for s in seeds:
        if runs and s == runs[-1][1] + 1:
            runs[-1][1] = s
        else:
            runs.append([s, s])
    return ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in runs)


def _cases(entry: dict, where: str) -> list[dict[str, Any]]:
    """The generator's keyword arguments of each case (``cases``, each with ``args``); [{}] for a file."""
    if "generator" not in entry:
        if "cases" in entry or "args" in entry:
            raise BatchSpecError(f"{where}: 'cases' and 'args' go with a 'generator'")
        return [{}]
    cases, args = entry.get("cases") or [{}], entry.get("args") or {}
    if not isinstance(cases, list) or not all(isinstance(c, dict) for c in cases) or not isinstance(args, dict):
        raise BatchSpecError(f"{where}: 'cases' must be a list of argument mappings and 'args' a mapping")
    return [{**args, **c} for c in cases]


def _samples(entry: dict, where: str, batch_seed: int, index: int) -> list[dict[str, Any]]:
    """The drawn overrides of each sample (``dispersions`` with ``samples``); [{}] without dispersions."""
    from fwsim.batch.dispersions import draw, parse_dispersions
    if "dispersions" not in entry:
        if "samples" in entry:
            raise BatchSpecError(f"{where}: 'samples' goes with 'dispersions'")
        return [{}]
    n = entry.get("samples")
    if not isinstance(n, int) or isinstance(n, bool) or not 1 <= n <= 100_000:
        raise BatchSpecError(f"{where}.samples: expected the number of draws, 1 to 100000 (got {n!r})")
    return draw(parse_dispersions(entry["dispersions"], f"{where}.dispersions", BatchSpecError), n, batch_seed,
                index)


def _entry_jobs(path: Path, i: int, entry: Any, logs: Path, batch_seed: int = 0) -> list[RunJob]:
    """The runs of one entry of a spec: cases x grid points x samples x seeds (each validated). A sample
    without ``seeds`` flies the scenario's seed plus its index (sensor noise differs from sample to
    sample)."""
    where = f"{path}: runs.{i}"
    if not isinstance(entry, dict) or ("scenario" in entry) == ("generator" in entry):
        raise BatchSpecError(f"{where}: expected a mapping with a 'scenario:' file or a 'generator:'")
    unknown = set(entry) - _RUN_KEYS
    if unknown:
        raise BatchSpecError(f"{where}.{sorted(unknown)[0]}: unknown key (allowed: {sorted(_RUN_KEYS)})")
    scenario_file, generator = "", str(entry.get("generator", ""))
    if generator:
        _generator(generator)
    else:
        scenario_file = str((path.parent / str(entry["scenario"])).resolve())
        if Path(scenario_file).is_dir():
            raise BatchSpecError(f"{where}.scenario: {scenario_file} is a folder, expected a scenario file (YAML)")
        if not Path(scenario_file).is_file():
            raise BatchSpecError(f"{where}.scenario: no such scenario file {scenario_file}")
    fixed = entry.get("set") or {}
    grid = entry.get("grid") or {}
    if not isinstance(fixed, dict) or not isinstance(grid, dict):
        raise BatchSpecError(f"{where}: 'set' and 'grid' must map field paths to values")
    for key, values in grid.items():
        if not isinstance(values, list) or not values:
            raise BatchSpecError(f"{where}.grid.{key}: expected a non-empty list of values (got {values!r})")
    seeds = _seeds(entry.get("seeds"), where)
    if seeds is not None and ("seed" in fixed or "seed" in grid):
        raise BatchSpecError(f"{where}: give the seed in 'seeds' or in 'set'/'grid', not both")
    keys = list(grid)
    samples = _samples(entry, where, batch_seed, i)
    dispersed = tuple(sorted(samples[0]))
    if "seed" in dispersed:
        raise BatchSpecError(f"{where}.dispersions.seed: the seed is not drawn (each sample takes the scenario's "
                             "seed plus its index, or 'seeds')")
    jobs = []
    combos = itertools.product(_cases(entry, where), list(itertools.product(*(grid[k] for k in keys))),
                               enumerate(samples))
    for case, point, (k, drawn) in combos:
        overrides = {**fixed, **dict(zip(keys, point)), **drawn}
        base_seed = overrides.pop("seed", None)
        if drawn and seeds is None:
            base_seed = (base_seed if base_seed is not None else _scenario_seed(scenario_file, generator, case)) + k
        for seed in seeds if seeds is not None else [base_seed]:
            ov = dict(overrides) if seed is None else {**overrides, "seed": seed}
            try:
                scenario, _ = _load(scenario_file, generator, case, ov)
            except ScenarioError as exc:
                if _fails_alone(scenario_file, generator, case, fixed):  # a bad 'set' (or --set): name it alone,
                    raise BatchSpecError(f"{where}.set: {exc}") from None  # not with the draw it spoiled first
                raise BatchSpecError(f"{where} ({_canonical({**case, **ov})}): {exc}") from None
            except Exception as exc:  # noqa: BLE001 - a generator that raises on these arguments
                raise BatchSpecError(f"{where} ({_canonical(case)}): {generator}: {type(exc).__name__}: "
                                     f"{exc}") from None
            rid = run_id(scenario.name, scenario.seed, {**overrides, **({"case": case} if generator else {})})
            jobs.append(RunJob(rid, scenario.name, scenario_file, scenario.seed, overrides,
                               str(logs / f"{rid}.mcap"), generator, case, dispersed))
    return jobs


def _scenario_seed(scenario_file: str, generator: str, case: dict) -> int:
    """The seed a scenario (file or generated) flies without overrides."""
    try:
        return _load(scenario_file, generator, case, {})[0].seed
    except Exception as exc:  # noqa: BLE001 - reported in one line like any other entry problem
        raise BatchSpecError(f"{scenario_file or generator}: {type(exc).__name__}: {exc}") from None


def _fails_alone(scenario_file: str, generator: str, case: dict, fixed: dict) -> bool:
    """The entry's fixed overrides (``set``, with ``--set``) are refused on their own, without a draw."""
    if not fixed:
        return False
    try:
        _load(scenario_file, generator, case, fixed)
    except ScenarioError:
        return True
    except Exception:  # noqa: BLE001 - a generator's own failure is reported with its arguments instead
        return False
    return False


def _load(scenario_file: str, generator: str, case: dict, overrides: dict):
    """(scenario, text): a scenario file, or a generator's scenario for ``case``, with the overrides."""
    if generator:
        import yaml

        from fwsim.scenario.model import parse_scenario
        text = yaml.safe_dump(_generator(generator)(**case), sort_keys=False)
        return parse_scenario(text, f"{generator}({_canonical(case)})", overrides), text
    return load_scenario(scenario_file, overrides)


# -- one run (runs in a worker process or a Ray task) -------------------------

def _describe(exc: BaseException) -> str:
    from fwsim.log.writer import describe_exception
    return describe_exception(exc)


def _base_row(job: RunJob, wall_time_s: float, error: str) -> dict[str, Any]:
    row: dict[str, Any] = {
        "id": job.id, "scenario": job.scenario, "seed": job.seed, "overrides": _canonical(job.overrides),
        "status": "failed", "reason": error, "error": error, "wall_time_s": wall_time_s,
        "log": str(Path("logs") / Path(job.log_path).name), "resumed": False,
    }
    row.update({f"set.{k}": v for k, v in job.overrides.items()})
    row.update({f"case.{k}": v for k, v in job.case.items()})
    return row


def row_from_log(job: RunJob, wall_time_s: float = math.nan, error: str = "") -> dict[str, Any]:
    """The summary row of a job, from its log (status, reason, metrics) if it exists.

    ``error`` is the exception the run raised ("" if none): such a run is
    failed whatever its log says.
    """
    from fwsim.interface import topics
    from fwsim.log import read_log
    from fwsim.analysis.metrics import compute_metrics

    row = _base_row(job, wall_time_s, error)
    log_path = Path(job.log_path)
    if not log_path.is_file():
        row["reason"] = error or "no log was written"
        return row
    try:
        log = read_log(log_path)
    except Exception as exc:  # noqa: BLE001 - an unreadable log is a failed row
        row["reason"] = error or f"unreadable log: {_describe(exc)}"
        return row
    row["status"] = "failed" if error else log.status
    row["reason"] = log.reason or error
    if not log.topics.get(topics.UAV_STATE):  # failed before the first state (e.g. the trim): no metrics
        return row
    try:
        metrics = compute_metrics(log)
    except Exception as exc:  # noqa: BLE001 - a metric that cannot be computed: the row says why
        row["metrics_error"] = _describe(exc)
        return row
    metrics.pop("status", None)  # the row's status and reason come from the same log
    metrics.pop("end_reason", None)
    row.update(metrics)
    return row


@contextmanager
def _console_to(path: Path):
    """Send this process's stdout/stderr (file descriptors 1 and 2, so JSBSim's
    C++ output too) to ``path`` for the duration; the file is removed if empty."""
    libc = ctypes.CDLL(None)
    sys.stdout.flush()
    sys.stderr.flush()
    libc.fflush(None)
    saved = os.dup(1), os.dup(2)
    try:
        with open(path, "wb") as f:
            os.dup2(f.fileno(), 1)
            os.dup2(f.fileno(), 2)
            try:
                yield
            finally:
                sys.stdout.flush()
                sys.stderr.flush()
                libc.fflush(None)
                os.dup2(saved[0], 1)
                os.dup2(saved[1], 2)
    finally:
        os.close(saved[0])
        os.close(saved[1])
        if path.is_file() and path.stat().st_size == 0:
            path.unlink()


def run_one(job: RunJob) -> dict[str, Any]:
    """Fly one job and return its summary row (never raises for a failed run).

    What the run prints (JSBSim's messages) goes to ``logs/<id>.console.txt``
    (kept only when not empty), not to the terminal of the batch.
    """
    from fwsim.sim.loop import run

    t0 = time.perf_counter()
    error = ""
    interrupted = False
    log_path = Path(job.log_path)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with _console_to(log_path.with_suffix(".console.txt")):
        try:
            scenario, text = job.load()
            run(scenario, text, log_path)
        except KeyboardInterrupt:  # the log already says 'interrupted'
            interrupted = True
        except Exception as exc:  # noqa: BLE001 - a failed run is a row, not a lost batch
            error = _describe(exc)
    if interrupted:
        if _IN_POOL_WORKER:  # Ctrl-C reached the pool's workers too: leave, so no queued run starts
            os._exit(130)
        raise KeyboardInterrupt
    return row_from_log(job, time.perf_counter() - t0, error)


_IN_POOL_WORKER = False


def _pool_worker_init(nmpc_worker: str = "inline") -> None:
    global _IN_POOL_WORKER
    _IN_POOL_WORKER = True
    from controllers.guidance.nmpc_worker import ENV
    os.environ.setdefault(ENV, nmpc_worker)  # a user's FWSIM_NMPC_WORKER stands


def _nmpc_worker_for(workers: int) -> str:
    """Where a pool worker's NMPC solves (``controllers.guidance.nmpc_worker``): in a process of its own when the
    machine has a spare core for each worker's, else on the worker's thread (the same numbers either way)."""
    return "process" if (os.cpu_count() or 1) >= 2 * workers else "inline"


def failed_row(job: RunJob, error: str) -> dict[str, Any]:
    """A failed row for a job whose worker died or could not report."""
    return _base_row(job, math.nan, error)


# -- executors --------------------------------------------------------------

RowCallback = Callable[[dict[str, Any]], None]


def _run_pool(jobs: list[RunJob], workers: int, on_row: RowCallback, run_fn: Callable) -> None:
    """Local process pool (spawn). A worker that dies (segfault, os._exit) breaks
    the pool: the runs it took down are retried one by one in fresh processes,
    and the one that dies again becomes a failed row."""
    ctx = multiprocessing.get_context("spawn")
    casualties: list[RunJob] = []
    n = max(1, min(workers, len(jobs)))
    pool = ProcessPoolExecutor(max_workers=n, mp_context=ctx, initializer=_pool_worker_init,
                               initargs=(_nmpc_worker_for(n),))
    try:
        futures = {pool.submit(run_fn, j): j for j in jobs}
        for fut in as_completed(futures):
            job = futures[fut]
            try:
                on_row(fut.result())
            except BrokenProcessPool:
                casualties.append(job)
            except Exception as exc:  # noqa: BLE001 - e.g. a result that does not pickle
                on_row(failed_row(job, f"worker error: {_describe(exc)}"))
    except KeyboardInterrupt as exc:  # Ctrl-C reaches the workers by itself; SIGTERM and SIGHUP are passed on
        _pass_on(exc, pool)
        raise
    finally:  # on a stop: start nothing new (the runs in flight log 'interrupted')
        pool.shutdown(wait=True, cancel_futures=True)
    for job in casualties:  # one process per run: a crash takes down only itself
        with ProcessPoolExecutor(max_workers=1, mp_context=ctx, initializer=_pool_worker_init,
                                 initargs=(_nmpc_worker_for(1),)) as pool:
            try:
                on_row(pool.submit(run_fn, job).result())
            except BrokenProcessPool:
                on_row(failed_row(job, "worker process died (crashed twice; see its log if any)"))
            except Exception as exc:  # noqa: BLE001
                on_row(failed_row(job, f"worker error: {_describe(exc)}"))


def _pass_on(exc: KeyboardInterrupt, pool: ProcessPoolExecutor) -> None:
    """Send the signal that stopped the batch (SIGTERM from a scheduler, SIGHUP) to the pool's workers, so the
    runs in flight close their logs as 'interrupted' with the signal named. Ctrl-C (SIGINT) already went to
    the whole process group."""
    signum = getattr(exc, "signum", signal.SIGINT)
    if signum == signal.SIGINT:
        return
    procs = getattr(pool, "_processes", None) or {}  # the executor's workers, {pid: Process}
    for proc in list(procs.values()):
        try:
            os.kill(proc.pid, signum)
        except (OSError, AttributeError):  # already gone
            pass


def ray_connect(address: str, workers: int) -> bool:
    """Make sure Ray is initialised; True if this call started it (and must shut it down).

    Uses the Ray instance already initialised in this process if there is
    one; otherwise ``address`` is ``local`` (start a local instance with
    ``workers`` CPUs), ``auto`` (connect to the cluster started with ``ray
    start``) or a cluster address (``ray://host:10001``, ``host:6379``).
    """
    try:
        import ray
    except ImportError:
        raise BatchSpecError("--ray needs Ray: pip install 'fwsim[ray]'") from None
    if ray.is_initialized():
        return False
    try:
        if address == "local":
            ray.init(num_cpus=workers, include_dashboard=False)
        else:
            ray.init(address=address)
    except (ConnectionError, ValueError, RuntimeError) as exc:
        raise BatchSpecError(f"--ray {address}: cannot connect to Ray: {exc}") from None
    return True


def _run_ray(jobs: list[RunJob], on_row: RowCallback, run_fn: Callable) -> None:
    """Ray remote tasks running ``run_fn`` (1 CPU each). Logs are written by the
    workers at ``OUT/logs``: on a multi-node cluster OUT must be a shared file
    system and fwsim installed on every node."""
    import ray

    from controllers.guidance.nmpc_worker import ENV

    # one CPU a run: its NMPC solves on its own thread (controllers.guidance.nmpc_worker; the same numbers either way)
    remote = ray.remote(num_cpus=1, max_retries=1,
                        runtime_env={"env_vars": {ENV: os.environ.get(ENV, "inline")}})(run_fn)
    refs = {remote.remote(j): j for j in jobs}
    pending = list(refs)
    try:
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            for ref in done:
                try:
                    row = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 - a lost worker or node: a failed row
                    row = failed_row(refs[ref], f"ray task failed: {type(exc).__name__}: {exc}")
                on_row(row)
    except KeyboardInterrupt:  # a stopped batch stops its tasks: each one's run logs 'interrupted'
        for ref in pending:
            ray.cancel(ref)
        raise


# -- the batch --------------------------------------------------------------

def _previous_rows(out_dir: Path) -> dict[str, dict[str, Any]]:
    try:
        data = json.loads((out_dir / "summary.json").read_text())
        return {r["id"]: r for r in data.get("rows", [])}
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return {}


def resumable(job: RunJob) -> bool:
    """True when the job's log exists, is finished (completed/failed) and was
    flown from the scenario file as it is now."""
    from fwsim.log import read_log

    log_path = Path(job.log_path)
    if not log_path.is_file():
        return False
    try:
        log = read_log(log_path)
    except Exception:  # noqa: BLE001 - unreadable: fly it again
        return False
    if log.status not in FINISHED_STATUSES:
        return False
    return log.scenario_text == job.scenario_text()


def _resumed(jobs: list[RunJob], out_dir: Path) -> tuple[dict[str, dict[str, Any]], list[RunJob]]:
    """(The rows of the runs a previous batch in ``out_dir`` finished, read from their logs; the jobs still to fly)."""
    previous = _previous_rows(out_dir)
    rows: dict[str, dict[str, Any]] = {}
    todo = []
    for job in jobs:
        if resumable(job):
            prev = previous.get(job.id, {})
            wall = prev.get("wall_time_s")
            row = row_from_log(job, float(wall) if isinstance(wall, (int, float)) else math.nan,
                               prev.get("error") or "")
            row["resumed"] = True
            rows[job.id] = row
        else:
            todo.append(job)
    return rows, todo


def run_batch(spec_path: str | Path | dict, out_dir: str | Path, *, workers: int | None = None, resume: bool = False,
              ray_address: str | None = None, on_start: Callable[[int, int], None] | None = None,
              on_row: RowCallback | None = None, run_fn: Callable[[RunJob], dict] = run_one,
              changes: SpecChanges | None = None) -> BatchResult:
    """Expand a spec (a file or a dict; with ``changes``, :class:`SpecChanges`), fly what is needed, write the summary.

    ``on_start(total, resumed)`` is called once before flying and
    ``on_row(row)`` after each finished run (for a progress bar). ``run_fn``
    must be a module-level function (it is pickled by reference).
    Ctrl-C writes the summary of the runs finished so far, then re-raises.
    """
    out_dir = Path(out_dir)
    name, jobs = load_spec(spec_path, out_dir, changes)
    try:  # the spec is sound: now the folder its output goes to
        (out_dir / "logs").mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BatchSpecError(f"{out_dir}: cannot write the batch's output there ({exc.strerror or exc})") from None
    workers = workers or os.cpu_count() or 1
    rows, todo = _resumed(jobs, out_dir) if resume else ({}, jobs)
    if on_start is not None:
        on_start(len(jobs), len(rows))

    def collect(row: dict[str, Any]) -> None:
        rows[row["id"]] = row
        if on_row is not None:
            on_row(row)

    result = BatchResult([], out_dir, resumed=len(jobs) - len(todo))
    ray_started = bool(todo and ray_address and ray_connect(ray_address, workers))
    try:
        if todo:
            if ray_address:
                _run_ray(todo, collect, run_fn)
            else:
                _run_pool(todo, workers, collect, run_fn)
    except KeyboardInterrupt:
        result.interrupted = True
        raise
    finally:
        if ray_started:
            import ray
            ray.shutdown()
        result.rows = [rows[j.id] for j in jobs if j.id in rows]
        result.files = write_summary(result.rows, out_dir, {
            "name": name, **spec_record(spec_path),
            **({"changes": changes.describe()} if changes else {}), "fwsim_version": fwsim.__version__,
            "written_utc": datetime.now(timezone.utc).isoformat(timespec="seconds"),
            "runs": len(jobs), "finished": len(result.rows),
            "failed": sum(r["status"] != "completed" for r in result.rows),
            "dispersed": sorted({p for j in jobs for p in j.dispersed}),
            "interrupted": result.interrupted, "executor": f"ray ({ray_address})" if ray_address else
            f"process pool ({workers} workers)"})
    return result


# -- summary files ----------------------------------------------------------

def spec_record(spec_path: str | Path | dict) -> dict[str, Any]:
    """What the summary records of the spec flown (``fwsim report`` shows it): its path, SHA-256 and text (a
    spec given as a dict: the dict itself)."""
    import hashlib
    if isinstance(spec_path, dict):
        return {"spec": spec_path}
    path = Path(spec_path).resolve()
    try:
        data = path.read_bytes()
    except OSError:
        return {"spec": str(path)}
    return {"spec": str(path), "spec_sha256": hashlib.sha256(data).hexdigest(),
            "spec_text": data.decode("utf-8", "replace")}


def columns_of(rows: list[dict[str, Any]]) -> list[str]:
    """Base columns, then ``set.*`` override and ``case.*`` argument columns, then metric columns (first-seen
    order)."""
    seen: dict[str, None] = dict.fromkeys(BASE_COLUMNS)
    sets: dict[str, None] = {}
    rest: dict[str, None] = {}
    for r in rows:
        for k in r:
            if k in seen:
                continue
            (sets if k.startswith(("set.", "case.")) else rest).setdefault(k, None)
    return [*seen, *sets, *rest]


def _json_safe(v: Any) -> Any:
    if isinstance(v, float) and not math.isfinite(v):
        return None  # strict JSON: NaN/inf -> null
    if isinstance(v, list):
        return [_json_safe(x) for x in v]
    if isinstance(v, dict):
        return {k: _json_safe(x) for k, x in v.items()}
    return v


def _csv_cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return repr(v)  # shortest text that reads back to the same float
    if isinstance(v, (list, dict)):
        return json.dumps(v)
    return str(v)


def write_summary(rows: list[dict[str, Any]], out_dir: Path, info: dict[str, Any]) -> list[Path]:
    """summary.csv, summary.json and (pyarrow importable) summary.parquet; returns the files written."""
    out_dir = Path(out_dir)
    cols = columns_of(rows)
    files = [out_dir / "summary.csv"]
    with open(files[0], "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(cols)
        for r in rows:
            w.writerow([_csv_cell(r.get(c)) for c in cols])
    parquet = _write_parquet(rows, cols, out_dir / "summary.parquet", info)
    (out_dir / "summary.json").write_text(json.dumps(
        {"batch": info, "columns": cols, "rows": [_json_safe(r) for r in rows]}, indent=1, allow_nan=False))
    files.append(out_dir / "summary.json")
    return files + parquet


def _write_parquet(rows: list[dict[str, Any]], cols: list[str], path: Path, info: dict[str, Any]) -> list[Path]:
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return []
    table_rows = [{c: (json.dumps(r[c]) if isinstance(r.get(c), (list, dict)) else r.get(c)) for c in cols}
                  for r in rows]
    try:
        pq.write_table(pa.Table.from_pylist(table_rows), path)
    except (pa.ArrowException, TypeError, ValueError) as exc:
        path.unlink(missing_ok=True)
        info.setdefault("warnings", []).append(f"summary.parquet not written: {exc}")
        return []
    return [path]
