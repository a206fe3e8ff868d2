"""The `fleet` command line: run scenarios and studies, draw and replay runs, list plugins,
inspect floor maps and G-code files."""

from __future__ import annotations

import argparse
import logging
import sys
import warnings
from pathlib import Path

from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from fleet.errors import FleetError

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `fleet` console script; returns the exit status."""
    parser = _parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    console = Console(stderr=False)
    try:
        return args.handler(args, console)
    except FleetError as exc:
        # Escape: messages quote TOML like "[floor]" that rich would take for markup.
        Console(stderr=True).print(
            f"[bold red]error:[/] {escape(str(exc))}", highlight=False, soft_wrap=True
        )
        return 2


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="fleet", description="Simulate fleets of MAMbots on a shop floor."
    )
    sub = p.add_subparsers(dest="command", required=True)

    run = sub.add_parser("run", help="run a scenario and write its run directory")
    run.add_argument("scenario", nargs="?", help="scenario TOML (default: scenarios/default.toml)")
    run.add_argument("--map", help="floor map TOML, overriding the scenario's")
    run.add_argument("--robots", type=int, help="number of robots")
    run.add_argument("--controller", help="controller plugin name (see `fleet plugins`)")
    run.add_argument("--dispatcher", help="dispatcher plugin name (see `fleet plugins`)")
    run.add_argument("--duration", type=float, help="simulated seconds")
    run.add_argument("--seed", type=int, help="random seed")
    run.add_argument("--out", type=Path, help="run directory (default: runs/<scenario>-seed<seed>)")
    run.add_argument("--quiet", action="store_true", help="no progress bar or table")
    run.add_argument(
        "--no-figures",
        dest="figures",
        action="store_false",
        help="skip trajectory.png, speed.png and gantt.png (they take about two seconds for an "
        "hour of a few robots; `fleet plot RUN_DIR` draws them later)",
    )
    run.set_defaults(handler=_cmd_run)

    sweep = sub.add_parser(
        "sweep", help="run a study: a grid of scenario values over seeds, cells in parallel"
    )
    sweep.add_argument("study", type=Path, help="study TOML (see studies/throughput.toml)")
    sweep.add_argument(
        "--out", type=Path, help="study directory (default: runs/<study name>); resumes there"
    )
    sweep.add_argument(
        "--workers", type=_positive_int, help="local worker processes (default: one per CPU core)"
    )
    sweep.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="run the cells on this Dask scheduler instead (pip install 'mambot-fleet[dask]')",
    )
    sweep.add_argument(
        "--keep-failed",
        dest="retry_failed",
        action="store_false",
        help="do not run failed cells again when resuming",
    )
    sweep.add_argument("--quiet", action="store_true", help="no progress bar or table")
    sweep.set_defaults(handler=_cmd_sweep)

    report = sub.add_parser(
        "report", help="plot a study's results and write a Markdown summary (report.md)"
    )
    report.add_argument("study_dir", type=Path, help="a directory written by `fleet sweep`")
    report.add_argument("--out", type=Path, help="where to write (default: the study directory)")
    report.set_defaults(handler=_cmd_report)

    plot = sub.add_parser(
        "plot", help="draw a run's figures: trajectories, speed against limits, print Gantt"
    )
    plot.add_argument("run_dir", type=Path, help="a run directory written by `fleet run`")
    plot.set_defaults(handler=_cmd_plot)

    replay = sub.add_parser("replay", help="write a self-contained HTML page that animates a run")
    replay.add_argument("run_dir", type=Path, help="a run directory written by `fleet run`")
    replay.add_argument(
        "--out", type=Path, help="HTML file or directory (default: RUN_DIR/replay.html)"
    )
    replay.set_defaults(handler=_cmd_replay)

    plugins = sub.add_parser("plugins", help="list the controller and dispatcher plugins found")
    plugins.set_defaults(handler=_cmd_plugins)

    floor = sub.add_parser("map", help="compile a floor map and describe its regions")
    floor.add_argument("file", type=Path)
    floor.set_defaults(handler=_cmd_map)

    gcode = sub.add_parser("gcode", help="time a G-code file and split it into print tasks")
    gcode.add_argument("file", type=Path, help="G-code from PrusaSlicer, SuperSlicer or Cura")
    gcode.add_argument("--json", action="store_true", help="print the analysis as JSON")
    gcode.add_argument(
        "--min-task",
        type=float,
        default=10.0,
        metavar="S",
        help="minimum task duration in seconds; shorter segments merge (default 10)",
    )
    gcode.add_argument(
        "--map",
        action="append",
        default=[],
        metavar="NAME=KIND",
        help="classify slicer feature NAME as KIND (contour, infill, support, travel, other); "
        "repeatable, e.g. --map 'Gap fill=contour'",
    )
    gcode.set_defaults(handler=_cmd_gcode)
    return p


def _cmd_run(args: argparse.Namespace, console: Console) -> int:
    from fleet.engine import World
    from fleet.scenario import default_scenario, load_scenario

    scenario = load_scenario(args.scenario) if args.scenario else default_scenario()
    scenario = scenario.override(
        map=args.map,
        robots=args.robots,
        controller=args.controller,
        dispatcher=args.dispatcher,
        duration=args.duration,
        seed=args.seed,
    )
    out = args.out or Path("runs") / f"{scenario.name}-seed{scenario.seed}"
    world = World(scenario)
    if args.quiet:
        result = world.run()
    else:
        console.print(
            f"[bold]{scenario.name}[/]: {len(world.robots)} robots on {world.floor.name} "
            f"({len(world.floor.regions)} regions), {scenario.controller.name} + "
            f"{scenario.dispatcher.name}, {scenario.duration_s:g} s simulated, seed {scenario.seed}"
        )
        with Progress(
            TextColumn("simulating"),
            BarColumn(),
            TextColumn("{task.fields[now]:>8.0f} s"),
            TimeElapsedColumn(),
            console=console,
            transient=True,
        ) as bar:
            task = bar.add_task("run", total=scenario.duration_s, now=0.0)
            result = world.run(lambda now: bar.update(task, completed=now, now=now))
    world.write(out)
    if args.figures:
        from fleet.plots import save_run_figures

        save_run_figures(out, world.floor)
    if not args.quiet:
        _kpi_table(console, result.summary)
        console.print(f"run directory: {out}")
    return 0


def _cmd_sweep(args: argparse.Namespace, console: Console) -> int:
    from contextlib import nullcontext

    from fleet.study import dask_executor, load_study, run_study

    study = load_study(args.study)
    out = args.out or Path("runs") / study.name
    if out.exists() and not out.is_dir():
        raise FleetError(f"--out {out}: is a file; the study needs a directory")
    total = len(study.cells)
    where = f"Dask scheduler {args.scheduler}" if args.scheduler else "local processes"
    errors = Console(stderr=True, soft_wrap=True)
    if not args.quiet:
        console.print(
            f"[bold]{escape(study.name)}[/]: {total} cells ({len(study.seeds)} seeds) on "
            f"{where} into {escape(str(out))}",
            soft_wrap=True,
        )
    executor = dask_executor(args.scheduler) if args.scheduler else nullcontext(None)
    with (
        executor as ex,
        Progress(
            TextColumn("cells"),
            BarColumn(),
            TextColumn("{task.completed}/{task.total}"),
            TextColumn("{task.fields[failed]} failed"),
            TimeElapsedColumn(),
            console=console,
            disable=args.quiet,
        ) as bar,
    ):
        task = bar.add_task("sweep", total=total, failed=0)
        failed = 0

        def progress(record: dict, done: int, _total: int) -> None:
            nonlocal failed
            if record.get("status") == "failed":
                failed += 1
                params = ", ".join(f"{k}={v}" for k, v in (record.get("params") or {}).items())
                when = " (kept from an earlier sweep)" if record.get("skipped") else ""
                errors.print(
                    f"[red]cell {record.get('cell')} ({escape(params)}, seed "
                    f"{record.get('seed')}) failed{when}:[/] {escape(str(record.get('error')))}",
                    highlight=False,
                )
            bar.update(task, completed=done, failed=failed)

        result = run_study(
            study,
            out,
            executor=ex,
            workers=args.workers,
            progress=progress,
            retry_failed=args.retry_failed,
        )
    if not args.quiet:
        console.print(
            f"{result.ok} ok, {result.failed} failed ({result.skipped} of these cells reused "
            f"from an earlier sweep); results: {escape(str(result.results_path))}; "
            f"next: fleet report {escape(str(out))}",
            soft_wrap=True,
        )
    return 1 if result.failed else 0


def _cmd_report(args: argparse.Namespace, console: Console) -> int:
    from fleet.report import write_report

    if args.out is not None and args.out.exists() and not args.out.is_dir():
        raise FleetError(f"--out {args.out}: is a file; the report needs a directory")
    result = write_report(args.study_dir, args.out)
    for path in result.paths:
        console.print(f"wrote {escape(str(path))}", soft_wrap=True)
    return 0


def _cmd_plot(args: argparse.Namespace, console: Console) -> int:
    from fleet.plots import save_run_figures

    for path in save_run_figures(args.run_dir):
        console.print(f"wrote {escape(str(path))}", soft_wrap=True)
    return 0


def _cmd_replay(args: argparse.Namespace, console: Console) -> int:
    from fleet.replay import REPLAY_HTML, write_replay

    out = args.out
    if out is not None and out.is_dir():
        out = out / REPLAY_HTML
    path = write_replay(args.run_dir, out)
    console.print(
        f"wrote {escape(str(path))} (open it in a browser; it needs no server or network)",
        soft_wrap=True,
    )
    return 0


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: must be a whole number >= 1")
    return value


def _kpi_table(console: Console, s: dict) -> None:
    t = Table(title="Key figures", show_header=True, header_style="bold")
    t.add_column("figure")
    t.add_column("value", justify="right")
    jobs = s["jobs"]
    v = s["violations"]
    rows = [
        ("simulated time", f"{s['sim_time_s']:.0f} s"),
        ("wall time", f"{s['wall_time_s']:.1f} s"),
        ("robots", str(s["robots"])),
        ("jobs released / completed", f"{jobs['released']} / {jobs['completed']}"),
        ("parts good / defective / late", f"{jobs['good']} / {jobs['defective']} / {jobs['late']}"),
        ("throughput", f"{s['throughput_per_h']:.1f} jobs/h"),
        ("throughput of good parts", f"{s['throughput_good_per_h']:.1f} parts/h"),
        (
            "mean lead time",
            "-" if s["mean_lead_time_s"] is None else f"{s['mean_lead_time_s']:.1f} s",
        ),
        ("distance driven", f"{s['distance_m']:.1f} m"),
        ("violations: obstacle", str(v["obstacle"])),
        ("violations: zone speed", str(v["speed_zone"])),
        ("violations: print speed", str(v["print_speed"])),
        ("violations: collision", str(v["collision"])),
        ("digest", s["digest"][:16]),
    ]
    solver = s["solver"]
    if solver["steps"]:
        rows[-1:-1] = [
            (
                "solver median / p95 / max",
                f"{solver['median_ms']:.1f} / {solver['p95_ms']:.1f} / {solver['max_ms']:.1f} ms",
            ),
            ("solver fallbacks", str(solver["fallbacks"])),
        ]
    for robot, at in (s.get("arrivals") or {}).items():
        rows.insert(-1, (f"arrival {robot}", "-" if at is None else f"{at:.1f} s"))
    for name, value in rows:
        t.add_row(name, value)
    console.print(t)


def _cmd_plugins(args: argparse.Namespace, console: Console) -> int:
    from fleet.plugins import discover

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        found = discover()
    t = Table(title="Plugins", header_style="bold")
    t.add_column("kind")
    t.add_column("name")
    t.add_column("from", overflow="fold")
    t.add_column("status", overflow="fold")
    for info in found:
        dist = f"{info.distribution or '?'} {info.version or ''}".strip()
        where = f"{info.value}\n{dist}" + (f"\n{info.origin}" if info.origin else "")
        status = "ok" if info.error is None else f"[red]broken:[/] {escape(info.error)}"
        t.add_row(info.kind, info.name, escape(where), status)
    console.print(t)
    for w in caught:
        Console(stderr=True).print(f"[yellow]warning:[/] {escape(str(w.message))}", highlight=False)
    return 0


def _cmd_map(args: argparse.Namespace, console: Console) -> int:
    from fleet.floor import load_floor

    floor = load_floor(args.file)
    xmin, ymin, xmax, ymax = floor.bounds
    console.print(f"[bold]{floor.name}[/] ({floor.source})")
    console.print(
        f"{xmax - xmin:g} x {ymax - ymin:g} m, free area {floor.free_space.area:.1f} m2, "
        f"{len(floor.regions)} convex regions, {floor.graph.number_of_edges()} adjacencies"
    )
    t = Table(header_style="bold")
    for col in ("v_max (m/s)", "regions", "area (m2)"):
        t.add_column(col, justify="right")
    by_limit: dict[tuple[float, float], list] = {}
    for r in floor.regions:
        by_limit.setdefault(r.v_max, []).append(r)
    for limit in sorted(by_limit):
        rs = by_limit[limit]
        label = f"{limit[0]:g}" if limit[0] == limit[1] else f"{limit[0]:g} x {limit[1]:g}"
        t.add_row(label, str(len(rs)), f"{sum(r.polygon.area for r in rs):.1f}")
    console.print(t)
    console.print("stations: " + ", ".join(f"{s.name} ({s.kind})" for s in floor.spec.stations))
    return 0


def _cmd_gcode(args: argparse.Namespace, console: Console) -> int:
    import json

    from fleet.errors import GcodeError
    from fleet.gcode import analyze

    classification: dict[str, str] = {}
    for item in args.map:
        name, sep, kind = item.partition("=")
        if not sep or not name.strip():
            raise GcodeError(
                str(args.file), "--map", item, "write NAME=KIND, e.g. --map 'Gap fill=contour'"
            )
        classification[name.strip()] = kind.strip()
    a = analyze(args.file, min_task_s=args.min_task, classification=classification)
    if args.json:
        # Plain stdout, not rich: the output is for programs.
        sys.stdout.write(json.dumps(a.to_json(), indent=2) + "\n")
        return 0
    console.print(f"[bold]{escape(a.file)}[/] ({a.slicer or 'unknown slicer'}), {a.layers} layers")
    t = Table(header_style="bold")
    t.add_column("kind")
    t.add_column("time", justify="right")
    t.add_column("share", justify="right")
    for kind, seconds in a.by_kind_s.items():
        t.add_row(kind, _hms(seconds), f"{100 * seconds / a.total_s:.1f} %" if a.total_s else "-")
    t.add_row("[bold]total[/]", f"[bold]{_hms(a.total_s)}[/]", "100 %")
    console.print(t)
    if a.slicer_estimate_s is not None and a.estimate_ratio is not None:
        console.print(
            f"slicer estimate {_hms(a.slicer_estimate_s)}, ours / slicer = {a.estimate_ratio:.3f}"
        )
    else:
        console.print("slicer estimate: none in the file")
    console.print(f"{len(a.tasks)} tasks of at least {a.min_task_s:g} s; first tasks:")
    first = Table(header_style="bold")
    for col in ("kind", "start", "end", "layer"):
        first.add_column(col, justify="left" if col == "kind" else "right")
    for task in a.tasks[:8]:
        first.add_row(task.kind, _hms(task.start_s), _hms(task.end_s), str(task.layer))
    console.print(first)
    for w in a.warnings:
        Console(stderr=True).print(f"[yellow]warning:[/] {escape(w)}", highlight=False)
    return 0


def _hms(seconds: float) -> str:
    m, s = divmod(seconds, 60.0)
    h, m = divmod(int(m), 60)
    return f"{h}h {m:02d}m {s:04.1f}s" if h else f"{m}m {s:04.1f}s"


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
