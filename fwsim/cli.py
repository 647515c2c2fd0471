"""Command line: ``fwsim run | scenario | metrics | bench | batch | compare | plot | replay | report``.

    fwsim run scenarios/paper_mission.yaml [--out runs] [--set initial.airspeed_m_s=24]
                                           [--rerun spawn|connect[=ADDR]|save=PATH.rrd] [--debug]
    fwsim scenario show SCENARIO [--set ...]    # the scenario as the run sees it, every default filled in
    fwsim scenario schema                       # its JSON Schema (for an editor)
    fwsim scenario reference [--out FILE]       # the field reference page
    fwsim metrics runs/<log>.mcap [--json]
    fwsim run SCENARIO --profile                # plus where the wall time went, block by block
    fwsim bench [--json] [--quick] [SCENARIO]
    fwsim batch SPEC.yaml [--workers N] [--out DIR] [--resume] [--ray auto|local|ADDRESS]
    fwsim compare BASELINE RUN [--tolerances FILE] [--strict]
    fwsim compare A B --ab                      # which run is better, metric by metric
    fwsim plot LOG [--out DIR] [--only a,b]
    fwsim replay LOG [--rrd OUT.rrd]
    fwsim report BATCH_OUT                      # a batch's statistics: report.html and a headline
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from fwsim.scenario.model import ScenarioError, load_scenario, parse_sets
from fwsim.scenario.yamlfile import short


def _console(**kwargs) -> Console:
    """A rich console; off a terminal (a pipe, a file, CI) lines are not wrapped at 80 columns, so paths stay
    whole and copyable."""
    con = Console(**kwargs)
    return con if con.is_terminal else Console(width=200, soft_wrap=True, **kwargs)


console = _console(stderr=True)


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _log_exists(path: Path) -> bool:
    """True if the log file exists; otherwise says so on stderr."""
    if path.is_file():
        return True
    console.print(f"[red]{path}: is a folder, expected an MCAP log[/]" if path.is_dir()
                  else f"[red]{path}: no such log file[/]")
    return False


def _flight_log(path: Path):
    """The log at ``path`` if it holds a flight, else None after a one-line error (missing, not MCAP,
    corrupted, or no UAV state in it)."""
    from fwsim.log.reader import LogError, read_flight_log
    if not _log_exists(path):
        return None
    try:
        return read_flight_log(path)
    except (LogError, OSError) as exc:
        print(f"error: {short(exc, 300)}", file=sys.stderr)
        return None


def _writable_dir(path: Path, option: str) -> Path:
    """The folder ``path`` for a command's output, made if missing; a ScenarioError (exit code 2, one line
    naming ``option``) when it cannot be made or written in, so nothing is flown or computed first for
    output that has nowhere to go."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise ScenarioError(f"{option} {path}: is a file, expected a folder to write in")
    _no_file_above(path, option)
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / f".fwsim-write-check-{os.getpid()}"
        probe.touch()
        probe.unlink()
    except OSError as exc:
        raise ScenarioError(f"{option} {path}: cannot write there ({exc.strerror or exc})") from None
    return path


def _no_file_above(path: Path, option: str) -> None:
    """A ScenarioError when the nearest existing folder above ``path`` is a file (nothing can be made in it)."""
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise ScenarioError(f"{option} {path}: {parent} is a file, not a folder")
            return


def _writable_file(path: Path, option: str) -> Path:
    """:func:`_writable_dir` for an output file: its folder made, the file opened for appending (and removed
    again if it was not there); an existing folder at ``path`` itself is refused."""
    path = Path(path)
    if path.is_dir():
        raise ScenarioError(f"{option} {path}: is a folder, expected a file to write")
    existed = path.exists()
    _no_file_above(path, option)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "ab"):
            pass
    except OSError as exc:
        raise ScenarioError(f"{option} {path}: cannot write there ({exc.strerror or exc})") from None
    if not existed:
        path.unlink()
    return path


def _positive_number(text: str) -> float:
    """An option's value that must be a finite number above zero (argparse prints the ArgumentTypeError's text
    in its one-line error, exit code 2)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number above zero (got {short(text, 40)!r})") from None
    if not (math.isfinite(value) and value > 0.0):
        raise argparse.ArgumentTypeError(f"expected a number above zero (got {short(text, 40)!r})")
    return value


def _print_table(title: str, rows: dict) -> None:
    table = Table(title=title)
    table.add_column("name")
    table.add_column("value", justify="right")
    for k, v in rows.items():
        table.add_row(k, _fmt(v))
    _console().print(table)


def cmd_run(args) -> int:
    from fwsim.sim.loop import default_log_path
    target = None
    if args.rerun is not None:  # a bad value fails before the scenario is even read
        from fwsim.log.rerun_live import LiveViewError, RerunLive, parse_target
        try:
            target = parse_target(args.rerun)
        except LiveViewError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
    scenario, text = load_scenario(args.scenario, parse_sets(args.set))
    log_path = Path(args.log) if args.log else default_log_path(scenario, Path(args.out))
    if args.log:
        _writable_file(log_path, "--log")
    else:
        _writable_dir(Path(args.out), "--out")
    if target is None:
        return _fly(args, scenario, text, log_path, None)
    try:  # spawn the viewer, check the one to connect to, or open the file
        live = RerunLive(target, scenario=scenario, scenario_text=text, log_path=log_path,
                         recording_id=f"{log_path.stem} (live)")
    except LiveViewError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        return _fly(args, scenario, text, log_path, live)
    finally:
        live.close()
        if target.kind == "save":
            done = "incomplete (see the warning above)" if live.failed else "saved"
            console.print(f"live view {done}: {target.address} (open it with: rerun {target.address})")


def _fly(args, scenario, text: str, log_path: Path, live) -> int:
    from fwsim.sim.loop import run
    console.print(f"[bold]fwsim[/] flying [cyan]{scenario.name}[/] (seed {scenario.seed}, "
                  f"{scenario.duration_s:g} s) -> {log_path}" + (f"; live view: {live.target}" if live else ""))
    with Progress(TextColumn("sim {task.completed:>7.1f} / {task.total:.0f} s"), BarColumn(),
                  TextColumn("{task.percentage:>3.0f}%"), TimeElapsedColumn(),
                  console=console, disable=args.quiet, transient=True) as bar:
        task = bar.add_task("run", total=scenario.duration_s)
        timer = None
        if getattr(args, "profile", False):
            from fwsim.sim.profiling import BlockTimer
            timer = BlockTimer()
        try:
            result = run(scenario, text, log_path, progress=lambda t, T: bar.update(task, completed=t),
                         listeners=[live] if live is not None else (), profile=timer)
        except KeyboardInterrupt as exc:
            bar.stop()
            console.print(f"[yellow]interrupted[/]; the log is complete: {log_path}")
            return 128 + int(getattr(exc, "signum", 2))
        except Exception as exc:
            bar.stop()
            _run_failed(exc, log_path, getattr(args, "debug", False))
            return 1
        # A run that ends early (the ship hit, sea contact) ends the bar at 100 %, not at its share of duration_s.
        bar.update(task, total=max(result.sim_time_s, 1e-9), completed=result.sim_time_s, refresh=True)
    colour = "green" if result.status == "completed" else "red"
    console.print(f"[{colour}]{result.status}[/]: {result.reason}")
    console.print(f"sim time {result.sim_time_s:.1f} s, wall time {result.wall_time_s:.2f} s, "
                  f"real-time factor {result.real_time_factor:.1f}x")
    console.print(f"log: {result.log_path}")
    console.print(f"result: {_result(result.result_log or result.log_path)}")
    if result.blocks is not None:
        _print_blocks(f"where the time went: {scenario.name}", result.blocks, result.wall_time_s, result.sim_time_s)
    return 0 if result.status == "completed" else 1


def _result(log) -> str:
    """The one-line result of a flown run (``fwsim.analysis.metrics.result_line``), from its log (a path or the
    run's ``result_log``)."""
    from fwsim.analysis.metrics import result_line, terminal_metrics
    try:
        return result_line(terminal_metrics(log))
    except Exception as exc:  # noqa: BLE001 - a log that cannot be scored: say so, the run itself is done
        return f"not scored ({type(exc).__name__}: {short(exc, 120)})"


def _run_failed(exc: Exception, log_path: Path, debug: bool) -> None:
    """A run that ended on an error: one line saying what and where (a user's block: the slot, the method and
    the line of the user's file), the whole traceback with ``--debug``."""
    from fwsim.sim.loop import failure_text
    if debug:
        import traceback
        console.print("".join(traceback.format_exception(exc)).rstrip(), markup=False, highlight=False)
    from rich.markup import escape
    console.print(f"[red]run failed[/]: {escape(failure_text(exc))}", highlight=False)
    console.print(f"the log says why: {escape(str(log_path))}" + ("" if debug else " (the whole traceback: --debug)"),
                  highlight=False)


def _print_blocks(title: str, blocks, wall_s: float, sim_s: float) -> None:
    """The per-block wall-time table of a profiled run (fwsim.sim.profiling)."""
    table = Table(title=title, caption=f"{sim_s:.1f} s simulated in {wall_s:.2f} s of wall time "
                                       f"({sim_s / wall_s if wall_s > 0 else float('nan'):.1f}x real time, "
                                       "timers included)")
    for col in ("block", "share", "ms per sim s", "calls", "us per call"):
        table.add_column(col, justify="left" if col == "block" else "right")
    for b in blocks:
        per_call = f"{1e6 * b.seconds / b.calls:.1f}" if b.calls else ""
        table.add_row(b.name, f"{100 * b.share:.1f} %", f"{b.ms_per_sim_s:.2f}", str(b.calls or ""), per_call)
    _console().print(table)


def _to_stdout(text: str) -> None:
    """``text`` on stdout; a reader that closes the pipe early (``| head``) ends it quietly."""
    try:
        sys.stdout.write(text)
        sys.stdout.flush()
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # (no second error at exit)


def cmd_scenario(args) -> int:
    """``fwsim scenario show | schema | reference``: a scenario resolved, the JSON Schema, the field reference."""
    if args.action == "show":
        from fwsim.scenario.model import dump_scenario
        scenario, _ = load_scenario(args.scenario, parse_sets(args.set))
        _to_stdout(dump_scenario(scenario))
        return 0
    if args.action == "schema":
        from fwsim.scenario.reference import scenario_schema
        _to_stdout(json.dumps(scenario_schema(), indent=2, ensure_ascii=False) + "\n")
        return 0
    from fwsim.scenario.reference import reference_markdown
    text = reference_markdown()
    if args.out is None:
        _to_stdout(text)
        return 0
    out = _writable_file(Path(args.out), "--out")
    out.write_text(text, encoding="utf-8")
    console.print(f"wrote {out}")
    return 0


def cmd_metrics(args) -> int:
    from fwsim.analysis.metrics import compute_metrics, metrics_json
    path = Path(args.log)
    log = _flight_log(path)
    if log is None:
        return 2
    try:
        m = compute_metrics(log)
    except (ValueError, KeyError) as exc:  # e.g. a message that does not decode: the file is damaged
        print(f"error: {path}: not a readable fwsim log: {short(exc, 200)}", file=sys.stderr)
        return 2
    if args.json:
        print(metrics_json(m))
        return 0
    _print_metrics(f"metrics: {path.name}", m)
    return 0


NOTES = ("terminal_note", "impact_metrics")  # text that explains a group's missing values: on its heading line


def _print_metrics(title: str, m: dict) -> None:
    """The metrics grouped as the table in fwsim.analysis.metrics lists them, with their units; "—" for no value, and a
    group's note (why its values are missing) on the group's heading line."""
    from fwsim.analysis.metrics import METRIC, format_value, grouped
    groups = grouped(m)
    width = max((len(k) for _, rows in groups for k, _ in rows), default=0) + 2
    lines = [title]
    for group, rows in groups:
        notes = [str(v) for k, v in rows if k in NOTES and v]
        lines.append(f"{group}" + "".join(f" — {n}" for n in notes))
        for name, value in rows:
            if name in NOTES:
                continue
            unit = METRIC[name].unit if name in METRIC else ""
            text = format_value(value)
            cell = f"{text:>12}" if isinstance(value, (int, float)) or value is None else f"  {text}"
            lines.append(f"  {name:<{width}}{cell}" + (f" {unit}" if unit not in ("", "bool") else ""))
    print("\n".join(lines))


def cmd_bench(args) -> int:
    from fwsim.sim.bench import block_breakdown, blocks_json, run_bench
    if args.scenario is not None:  # one scenario, profiled block by block
        scenario, text = load_scenario(args.scenario, parse_sets(args.set))
        console.print(f"flying {scenario.name} ({scenario.duration_s:g} s) with a timer on every block ...")
        result, blocks = block_breakdown(scenario, text)
        if args.json:
            print(json.dumps({"scenario": scenario.name, "status": result.status, "sim_s": result.sim_time_s,
                              "wall_s": result.wall_time_s, "real_time_factor": result.real_time_factor,
                              "blocks": blocks_json(blocks)}, indent=2))
            return 0
        _print_blocks(f"fwsim bench {args.scenario}", blocks, result.wall_time_s, result.sim_time_s)
        return 0
    console.print("measuring (JSBSim raw, airframe wrapper, closed loops, detection frames, "
                  "the paper mission block by block) ...")
    res = run_bench(quick=args.quick)
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    blocks = res.pop("paper_mission_blocks")
    _print_table("fwsim bench", res)
    from fwsim.sim.profiling import BlockTime
    rows = [BlockTime(k, v["seconds"], v["calls"], v["share"], v["ms_per_sim_s"]) for k, v in blocks.items()]
    wall = sum(b.seconds for b in rows)
    _print_blocks("paper mission, block by block (a separate, profiled run)", rows, wall,
                  res["paper_mission_sim_s"])
    return 0


_ONLY_MAX_RANGE = 100_000  # --only's ranges: at most this many seeds (a batch of more is not a retry)


def _only_seeds(values: list[str]) -> tuple[int, ...]:
    """``--only`` values ("30", "30,59", "s30", "10-14"; repeatable) as scenario seeds, in order, once each."""
    seeds: list[int] = []
    for value in values:
        for part in value.split(","):
            p = part.strip().removeprefix("s")
            lo, sep, hi = p.partition("-")
            if not (lo.isdigit() and (not sep or hi.isdigit())) or (sep and int(hi) < int(lo)):
                raise ScenarioError(f"--only {part.strip()!r}: expected scenario seeds, e.g. 30, s30, 30,59 or 10-14")
            if sep and int(hi) - int(lo) >= _ONLY_MAX_RANGE:
                raise ScenarioError(f"--only {part.strip()!r}: a range of at most {_ONLY_MAX_RANGE} seeds")
            seeds.extend(range(int(lo), int(hi if sep else lo) + 1))
    return tuple(dict.fromkeys(seeds))


def cmd_batch(args) -> int:
    from rich.progress import TimeRemainingColumn

    from fwsim.batch.runner import SpecChanges, run_batch
    if args.workers is not None and args.workers < 1:
        raise ScenarioError(f"--workers: expected the number of parallel runs, 1 or more (got {args.workers})")
    if args.seed is not None and args.seed < 0:
        raise ScenarioError(f"--seed: expected an integer >= 0 for the dispersions' draws (got {args.seed})")
    changes = _spec_changes(args, SpecChanges)
    out = Path(args.out) if args.out else Path("runs") / Path(args.spec).stem
    failed = 0
    # the bar starts with the first run, not before: a spec refused before any run flies leaves its one-line
    # error alone on stderr (a bar stopped before it began would put an empty line ahead of it)
    bar = Progress(TextColumn("runs {task.completed:>4.0f} / {task.total:.0f}"), BarColumn(),
                   TextColumn("[red]{task.fields[failed]} failed[/]"), TimeElapsedColumn(), TimeRemainingColumn(),
                   console=console, disable=args.quiet, transient=True)
    task = bar.add_task("batch", total=0, failed=0)

    def stop_bar() -> None:
        if bar.live.is_started:  # (Progress.stop prints a line off a terminal, started or not)
            bar.stop()

    try:
        def on_start(total: int, resumed: int) -> None:
            bar.start()
            bar.update(task, total=total, completed=resumed)
            console.print(f"[bold]fwsim batch[/] {args.spec}: {total} runs -> {out}"
                          + (f" ({resumed} read back from their logs with --resume)" if resumed else ""))

        def on_row(row: dict) -> None:
            nonlocal failed
            failed += row["status"] != "completed"
            bar.update(task, advance=1, failed=failed)

        try:
            result = run_batch(args.spec, out, workers=args.workers, resume=args.resume, ray_address=args.ray,
                               on_start=on_start, on_row=on_row, changes=changes)
        except KeyboardInterrupt as exc:
            from fwsim._entry import exit_code
            stop_bar()
            console.print(f"[yellow]interrupted[/]: the summary of the finished runs is in {out}; "
                          "continue with --resume")
            return exit_code(exc)
    finally:
        stop_bar()
    return _batch_summary(result)


def _spec_changes(args, SpecChanges):
    """The command line's changes to a batch spec (--seed, --set, --hold, --only), checked."""
    bad = [h for h in args.hold if not h.strip() or any(not p for p in h.strip().split("."))]
    if bad:
        raise ScenarioError(f"--hold {bad[0]!r}: expected a dotted field path (e.g. world.wind_enu_m_s)")
    only = _only_seeds(args.only)
    return SpecChanges(args.seed, parse_sets(args.set), tuple(h.strip() for h in args.hold), only)


def _batch_summary(result) -> int:
    """Print a finished batch's failed runs, its counts and its files; the command's exit code."""
    bad = result.failed
    if bad:
        table = Table(title=f"{len(bad)} of {len(result.rows)} runs did not complete")
        table.add_column("id")
        table.add_column("status")
        table.add_column("reason")
        for row in bad[:20]:
            table.add_row(row["id"], row["status"], row.get("error") or row["reason"])
        console.print(table)
    walls = [r["wall_time_s"] for r in result.rows if isinstance(r.get("wall_time_s"), float)
             and r["wall_time_s"] == r["wall_time_s"]]
    console.print(f"[{'red' if bad else 'green'}]{len(result.rows) - len(bad)} completed, {len(bad)} failed[/]"
                  + (f", {result.resumed} resumed" if result.resumed else "")
                  + (f"; {sum(walls):.1f} s of run time" if walls else ""))
    for f in result.files:
        print(f)
    return 1 if bad else 0


def cmd_compare(args) -> int:
    from fwsim.analysis.compare import ab_files, compare_files
    try:
        if args.ab:
            return _print_ab(ab_files(args.baseline, args.run, args.tolerances, any_runs=args.any))
        cmp = compare_files(args.baseline, args.run, args.tolerances, any_runs=args.any, strict=args.strict)
    except (ValueError, KeyError) as exc:  # a file that is not a readable log, metrics file or baseline
        print(f"error: {short(exc, 300)}", file=sys.stderr)
        return 2
    out = _console()
    table = Table(title=f"baseline {cmp.baseline_label}\nrun {cmp.run_label}")
    for name, justify in (("metric", "left"), ("baseline", "right"), ("run", "right"), ("diff", "right"),
                          ("tolerance", "left"), ("verdict", "left")):
        table.add_column(name, justify=justify, no_wrap=name != "verdict")
    colours = {"ok": "green", "improved": "cyan", "REGRESSION": "bold red", "CHANGED": "bold red",
               "missing": "bold red", "new": "yellow", "ignored": "dim"}
    for row, check in zip(cmp.rows(), cmp.checks):
        colour = "bold red" if check.fails(cmp.strict) else colours[check.verdict]
        table.add_row(*row[:5], f"[{colour}]{row[5]}[/]")
    out.print(table)
    out.print(cmp.summary_line())
    return 0 if cmp.ok else 1


def _print_ab(ab) -> int:
    """The A/B table: per metric A, B, B - A, relative, which is better; then the count. Exit 0."""
    out = _console()
    table = Table(title=f"A {ab.a_label}\nB {ab.b_label}")
    for name in ("metric", "A", "B", "B - A", "relative", "verdict"):
        table.add_column(name, justify="left" if name in ("metric", "verdict") else "right", no_wrap=True)
    colours = {"B better": "green", "B worse": "red", "same": "dim"}
    for row in ab.text_rows():
        colour = colours.get(row[5], "yellow")
        table.add_row(*row[:5], f"[{colour}]{row[5]}[/]")
    out.print(table)
    out.print(ab.summary_line())
    return 0


def cmd_plot(args) -> int:
    from fwsim.analysis.plot import plot_log
    path = Path(args.log)
    log = _flight_log(path)
    if log is None:
        return 2
    out = Path(args.out) if args.out else path.with_name(f"{path.stem}_plots")
    _writable_dir(out, "--out")
    try:
        res = plot_log(log, out, only=args.only.split(",") if args.only else None)
    except ValueError as exc:
        console.print(f"[red]error[/]: {exc}")
        return 2
    for name, why in res.skipped:
        console.print(f"skipped {name}: {why}")
    for name, err in res.failed:
        console.print(f"[red]failed {name}[/]: {err}")
    for f in res.written:
        print(f)
    return 1 if res.failed else 0


def cmd_report(args) -> int:
    from fwsim.analysis.report import ReportError, write_report
    try:
        rep, path = write_report(args.out_dir)
    except ReportError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    _print_table(f"fwsim report: {rep.name}", dict(rep.headline()))
    _print_table("what was flown", dict(rep.flown))
    console.print(f"report: {path}")
    return 0


def cmd_replay(args) -> int:
    from fwsim.log.rerun_export import ReplayOptions, export_rrd
    path = Path(args.log)
    log = _flight_log(path)
    if log is None:
        return 2
    rrd = Path(args.rrd) if args.rrd else path.with_suffix(".rrd")
    _writable_file(rrd, "--rrd")
    from google.protobuf.message import DecodeError
    try:
        res = export_rrd(log, rrd, ReplayOptions(marker_scale=args.marker_scale))
    except (ValueError, KeyError, IndexError, DecodeError) as exc:  # bad options, or damage inside a message
        damage = "" if type(exc) is ValueError else f"{path}: corrupted: a message does not decode: "
        print(f"error: {damage}{short(f'{type(exc).__name__}: {exc}' if damage else exc, 300)}", file=sys.stderr)
        return 2
    console.print(f"logged: {', '.join(res.layers)}")
    for name, why in res.skipped:
        console.print(f"skipped {name}: {why}")
    console.print(f"open it with: rerun {rrd}")
    print(rrd)
    return 0


def _add_scenario_parser(sub) -> None:
    sc = sub.add_parser("scenario", help="a scenario with every default filled in, the JSON Schema, the field "
                                         "reference")
    acts = sc.add_subparsers(dest="action", required=True)
    show = acts.add_parser("show", help="print the scenario as the run sees it (YAML, every default filled in)")
    show.add_argument("scenario", help="scenario YAML file")
    show.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                      help="override a scenario field, as fwsim run takes it (repeatable)")
    acts.add_parser("schema", help="print the scenario's JSON Schema (for an editor: docs/guide/reference.md)")
    ref = acts.add_parser("reference", help="print the field reference page (Markdown)")
    ref.add_argument("--out", help="write it to this file instead (docs/guide/reference.md)")
    sc.set_defaults(func=cmd_scenario)


def _add_run_parser(sub) -> None:
    r = sub.add_parser("run", help="fly a scenario and write its MCAP log")
    r.add_argument("scenario", help="scenario YAML file")
    r.add_argument("--out", default="runs", help="folder for the log (default: runs/)")
    r.add_argument("--log", help="exact log file path (overrides --out)")
    r.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                   help="override a scenario field, e.g. --set seed=3 (repeatable)")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.add_argument("--profile", action="store_true",
                   help="time every block (sensors, the flight software's blocks, autopilot, JSBSim, camera, "
                        "renders, logging) and print where the wall time went")
    r.add_argument("--rerun", metavar="spawn|connect[=ADDR]|save=PATH.rrd",
                   help="also stream the run to Rerun as it flies (the MCAP log is written as always): "
                        "'spawn' a viewer, 'connect' to a running one (default rerun+http://127.0.0.1:9876/proxy; "
                        "ADDR: a port, HOST:PORT or a rerun+http:// URL), or 'save' into an .rrd file")
    r.add_argument("--debug", action="store_true", help="on an error, print the whole traceback")
    r.set_defaults(func=cmd_run)


def _add_batch_parser(sub) -> None:
    ba = sub.add_parser("batch", help="fly many runs from a batch spec (process pool or Ray); summary table")
    ba.add_argument("spec", help="batch spec YAML (docs/guide/batches.md)")
    ba.add_argument("--out", help="output folder: logs/, summary.csv/.json/.parquet (default: runs/<spec name>)")
    ba.add_argument("--workers", type=int, default=None, help="parallel runs (default: CPU count)")
    ba.add_argument("--resume", action="store_true",
                    help="keep runs whose log exists and is completed or failed; fly the rest")
    ba.add_argument("--ray", metavar="auto|local|ADDRESS",
                    help="run as Ray tasks: 'auto' (running cluster), 'local' (start one here) or an address")
    ba.add_argument("--quiet", action="store_true", help="no progress bar")
    ba.add_argument("--seed", type=int, default=None, metavar="N",
                    help="draw the dispersions with this seed instead of the spec's (the same envelope, new draws)")
    ba.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                    help="override a field in every run (repeatable); a dispersed field set here is not drawn")
    ba.add_argument("--hold", action="append", default=[], metavar="PATH",
                    help="do not draw this dispersed field, or those under it (repeatable): it keeps the "
                         "scenario's value and the other fields keep their draws, so the batch shows what "
                         "the field costs (e.g. --hold camera.detector)")
    ba.add_argument("--only", action="append", default=[], metavar="SEEDS",
                    help="fly only the runs of these scenario seeds (30, s30, 30,59, 10-14; repeatable), each the "
                         "same draw as in the whole batch: a batch's failing runs flown again with a --set change")
    ba.set_defaults(func=cmd_batch)


def _add_bench_parser(sub) -> None:
    b = sub.add_parser("bench", help="measure simulation speed on this machine")
    b.add_argument("--json", action="store_true", help="print JSON instead of a table")
    b.add_argument("--quick", action="store_true", help="shorter measurement (noisier)")
    b.add_argument("scenario", nargs="?", help="only this scenario, profiled block by block")
    b.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                   help="override a field of SCENARIO (repeatable)")
    b.set_defaults(func=cmd_bench)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fwsim", description="Fixed-wing UAV tracking and terminal guidance harness "
                                                          "around JSBSim.")
    from fwsim import __version__
    p.add_argument("--version", action="version", version=f"fwsim {__version__}")
    sub = p.add_subparsers(dest="command", required=True)
    _add_run_parser(sub)
    _add_scenario_parser(sub)
    _add_metrics_parser(sub)
    _add_bench_parser(sub)
    _add_batch_parser(sub)
    _add_compare_parser(sub)
    pl = sub.add_parser("plot", help="PNG figures from a log")
    pl.add_argument("log", help="MCAP log of a run")
    pl.add_argument("--out", help="folder for the PNGs (default: <log>_plots/ beside the log)")
    pl.add_argument("--only", help="comma-separated figure names (default: all)")
    pl.set_defaults(func=cmd_plot)
    rep = sub.add_parser("report", help="statistics of a batch (hit probability, CEP, angle errors) as report.html")
    rep.add_argument("out_dir", help="the output folder of `fwsim batch` (with summary.json)")
    rep.set_defaults(func=cmd_report)
    rp = sub.add_parser("replay", help="turn a log into a Rerun recording (.rrd)")
    rp.add_argument("log", help="MCAP log of a run")
    rp.add_argument("--rrd", help="output .rrd (default: the log's path with .rrd)")
    rp.add_argument("--marker-scale", type=_positive_number, default=10.0,
                    help="draw the UAV this many times life size (default 10)")
    rp.set_defaults(func=cmd_replay)
    return p


def _add_metrics_parser(sub) -> None:
    m = sub.add_parser("metrics", help="print the metrics computed from a log, grouped (docs/guide/metrics.md)")
    m.add_argument("log", help="MCAP log of a run")
    m.add_argument("--json", action="store_true", help="print strict JSON instead of a table (null: no value)")
    m.set_defaults(func=cmd_metrics)


def _add_compare_parser(sub) -> None:
    c = sub.add_parser("compare", help="compare a run's metrics with a baseline (exit 1 on a regression), or two "
                                       "runs with --ab")
    c.add_argument("baseline", help="baseline (or A): a log (.mcap), metrics (.json) or baseline file (.yaml)")
    c.add_argument("run", help="run (or B): a log (.mcap), metrics (.json) or baseline file (.yaml)")
    c.add_argument("--tolerances", help="YAML of per-metric tolerances (overrides the baseline's own)")
    c.add_argument("--any", action="store_true",
                   help="compare even when the two flew different scenarios, seeds or durations")
    c.add_argument("--strict", action="store_true",
                   help="fail on an improvement beyond the tolerance too (by default it is reported, not failing)")
    c.add_argument("--ab", action="store_true",
                   help="A/B: say per metric which run is better (by the metric's direction) and by how much, "
                        "then count; no pass or fail")
    c.set_defaults(func=cmd_compare)


def _check_environment() -> None:
    """Environment variables fwsim reads, checked before anything flies (a bad one: exit code 2)."""
    from controllers.guidance.nmpc_worker import ENV, worker_choice
    try:
        worker_choice()
    except ValueError as exc:
        raise ScenarioError(f"environment variable {ENV}: {exc}") from None


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
        _check_environment()
        return args.func(args)
    except ScenarioError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:  # before a run started (a run's own interrupt is handled where it flies)
        from fwsim._entry import exit_code
        print("interrupted", file=sys.stderr)
        return exit_code(exc)
    except BrokenPipeError:  # the reader went away (`fwsim metrics LOG --json | head -1`): end quietly
        return _closed_pipe()


def _closed_pipe() -> int:
    """After a write to a closed stdout: point stdout at /dev/null (so the flush at exit does not fail again)
    and exit 141, as a shell reports a process ended by SIGPIPE."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError):
        pass
    return 128 + 13  # SIGPIPE


if __name__ == "__main__":
    sys.exit(main())
