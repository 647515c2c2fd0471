"""Command line: ``fwsim run | metrics | bench``.

    fwsim run scenarios/paper_mission.yaml [--out runs] [--set initial.airspeed_m_s=24]
    fwsim metrics runs/<log>.mcap [--json]
    fwsim bench [--json] [--quick]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import yaml
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from fwsim.scenario import ScenarioError, load_scenario

console = Console(stderr=True)


def _parse_sets(items: list[str]) -> dict:
    out = {}
    for item in items:
        if "=" not in item:
            raise ScenarioError(f"--set {item}: expected PATH=VALUE (e.g. initial.airspeed_m_s=24)")
        key, value = item.split("=", 1)
        out[key.strip()] = yaml.safe_load(value)
    return out


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _print_table(title: str, rows: dict) -> None:
    table = Table(title=title)
    table.add_column("name")
    table.add_column("value", justify="right")
    for k, v in rows.items():
        table.add_row(k, _fmt(v))
    Console().print(table)


def cmd_run(args) -> int:
    from fwsim.loop import default_log_path, run
    scenario, text = load_scenario(args.scenario, _parse_sets(args.set))
    log_path = Path(args.log) if args.log else default_log_path(scenario, Path(args.out))
    console.print(f"[bold]fwsim[/] flying [cyan]{scenario.name}[/] (seed {scenario.seed}, "
                  f"{scenario.duration_s:g} s) -> {log_path}")
    with Progress(TextColumn("sim {task.completed:>7.1f} / {task.total:.0f} s"), BarColumn(),
                  TextColumn("{task.percentage:>3.0f}%"), TimeElapsedColumn(),
                  console=console, disable=args.quiet, transient=True) as bar:
        task = bar.add_task("run", total=scenario.duration_s)
        try:
            result = run(scenario, text, log_path, progress=lambda t, T: bar.update(task, completed=t))
        except KeyboardInterrupt:
            bar.stop()
            console.print(f"[yellow]interrupted[/]; the log is complete: {log_path}")
            return 130
        except Exception as exc:
            bar.stop()
            console.print(f"[red]run failed[/]: {type(exc).__name__}: {exc}\nthe log says why: {log_path}")
            return 1
    colour = "green" if result.status == "completed" else "red"
    console.print(f"[{colour}]{result.status}[/]: {result.reason}")
    console.print(f"sim time {result.sim_time_s:.1f} s, wall time {result.wall_time_s:.2f} s, "
                  f"real-time factor {result.real_time_factor:.1f}x")
    console.print(f"log: {result.log_path}")
    return 0 if result.status == "completed" else 1


def cmd_metrics(args) -> int:
    from fwsim.metrics import compute_metrics
    path = Path(args.log)
    if not path.is_file():
        console.print(f"[red]{path}: no such log file[/]")
        return 2
    m = compute_metrics(path)
    if args.json:
        print(json.dumps(m, indent=2, allow_nan=True))
        return 0
    _print_table(f"metrics: {path.name}", m)
    return 0


def cmd_bench(args) -> int:
    from fwsim.bench import run_bench
    console.print("measuring (JSBSim raw, airframe wrapper, closed loops, detection frames) ...")
    res = run_bench(quick=args.quick)
    if args.json:
        print(json.dumps(res, indent=2))
        return 0
    _print_table("fwsim bench", res)
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="fwsim", description="Fixed-wing UAV tracking and terminal guidance harness "
                                                          "around JSBSim.")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run", help="fly a scenario and write its MCAP log")
    r.add_argument("scenario", help="scenario YAML file")
    r.add_argument("--out", default="runs", help="folder for the log (default: runs/)")
    r.add_argument("--log", help="exact log file path (overrides --out)")
    r.add_argument("--set", action="append", default=[], metavar="PATH=VALUE",
                   help="override a scenario field, e.g. --set seed=3 (repeatable)")
    r.add_argument("--quiet", action="store_true", help="no progress bar")
    r.set_defaults(func=cmd_run)
    m = sub.add_parser("metrics", help="print the metrics computed from a log")
    m.add_argument("log", help="MCAP log of a run")
    m.add_argument("--json", action="store_true", help="print JSON instead of a table")
    m.set_defaults(func=cmd_metrics)
    b = sub.add_parser("bench", help="measure simulation speed on this machine")
    b.add_argument("--json", action="store_true", help="print JSON instead of a table")
    b.add_argument("--quick", action="store_true", help="shorter measurement (noisier)")
    b.set_defaults(func=cmd_bench)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except ScenarioError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
