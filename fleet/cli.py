"""The `fleet` command line: run scenarios and studies, draw and replay runs, list plugins,
inspect floor maps and G-code files."""

from __future__ import annotations

import argparse
import logging
import math
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
    if args.command == "serve":
        # The engine's operator sees agents join and leave, not only refusals and losses.
        logging.getLogger("fleet.bus").setLevel(logging.INFO)
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
    _scenario_arguments(run)
    _output_arguments(run)
    run.add_argument(
        "--workers",
        type=_non_negative_int,
        default=0,
        help="worker processes hosting the robots' agents (0: all in this process); they talk "
        "to the engine over the scenario's [bus] address, or a private ipc:// socket",
    )
    run.set_defaults(handler=_cmd_run)

    serve = sub.add_parser(
        "serve",
        help="run a scenario whose robot agents join from elsewhere (`fleet agent --connect`)",
    )
    _scenario_arguments(serve)
    _output_arguments(serve)
    serve.add_argument(
        "--bind", required=True, help="where agents connect, e.g. tcp://*:5555 or ipc:///tmp/f"
    )
    serve.add_argument(
        "--key", type=Path, help="the engine's secret key file (`fleet keys`): turns on CURVE"
    )
    serve.add_argument(
        "--authorized", type=Path, help="directory of the agents' public key files (with --key)"
    )
    serve.add_argument(
        "--wait",
        type=_positive_float,
        default=300.0,
        help="seconds to wait for agents (default 300)",
    )
    serve.set_defaults(handler=_cmd_serve)

    agent = sub.add_parser("agent", help="host robot agents for a run started by `fleet serve`")
    agent.add_argument("scenario", nargs="?", help="the run's scenario TOML (same as the engine's)")
    agent.add_argument("--map", help="floor map TOML, as given to the engine")
    agent.add_argument("--robots", type=int, help="number of robots, as given to the engine")
    agent.add_argument("--controller", help="controller plugin name, as given to the engine")
    agent.add_argument("--connect", required=True, help="the engine's address, tcp://HOST:PORT")
    agent.add_argument("--only", help="host these robots, e.g. r01,r02 (default: all)")
    agent.add_argument("--share", help="host the K-th of N even shares of the robots, e.g. 1/2")
    agent.add_argument("--name", help="agent name (default agent-<pid>-1)")
    agent.add_argument("--key", type=Path, help="this agent's secret key file (`fleet keys`)")
    agent.add_argument("--server-key", type=Path, help="the engine's public key file (with --key)")
    agent.add_argument(
        "--wait",
        type=_positive_float,
        default=300.0,
        help="give up after this many seconds without a word from the engine (default 300)",
    )
    agent.set_defaults(handler=_cmd_agent)

    keys = sub.add_parser("keys", help="make a CURVE key pair for `fleet serve` / `fleet agent`")
    keys.add_argument("directory", type=Path, help="where to write NAME.key and NAME.key_secret")
    keys.add_argument("--name", default="fleet", help="file name stem (default: fleet)")
    keys.set_defaults(handler=_cmd_keys)

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

    schema = sub.add_parser(
        "schema",
        help="print the JSON Schema of scenario or map files, for editors (docs/schema.md)",
    )
    schema.add_argument("kind", choices=("scenario", "map"), help="which files the schema is of")
    schema.add_argument("--out", type=Path, help="write the schema to this file instead")
    schema.set_defaults(handler=_cmd_schema)
    return p


def _scenario_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", nargs="?", help="scenario TOML (default: scenarios/default.toml)")
    p.add_argument("--map", help="floor map TOML, overriding the scenario's")
    p.add_argument("--robots", type=int, help="number of robots")
    p.add_argument("--controller", help="controller plugin name (see `fleet plugins`)")
    p.add_argument("--dispatcher", help="dispatcher plugin name (see `fleet plugins`)")
    p.add_argument("--duration", type=float, help="simulated seconds")
    p.add_argument("--seed", type=int, help="random seed")
    p.add_argument(
        "--latency",
        metavar="none|measured|SECONDS",
        help="compute latency: a command takes effect this long after its tick (default: the "
        "scenario's [scenario] latency, else none). 'measured' uses each solve's measured step "
        "time, so the run depends on this machine and its digest is not reproducible; a "
        "number of seconds is reproducible. Meant for the MPC: the follower is not "
        "latency-tolerant (docs/fleet.md)",
    )


def _output_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, help="run directory (default: runs/<scenario>-seed<seed>)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or table")
    p.add_argument(
        "--no-figures",
        dest="figures",
        action="store_false",
        help="skip trajectory.png, speed.png and gantt.png (they take about two seconds for an "
        "hour of a few robots; `fleet plot RUN_DIR` draws them later)",
    )


def _scenario(args: argparse.Namespace):
    from fleet.scenario import default_scenario, load_scenario

    scenario = load_scenario(args.scenario) if args.scenario else default_scenario()
    return scenario.override(
        map=args.map,
        robots=args.robots,
        controller=args.controller,
        dispatcher=getattr(args, "dispatcher", None),
        duration=getattr(args, "duration", None),
        seed=getattr(args, "seed", None),
        latency=getattr(args, "latency", None),
    )


def _cmd_run(args: argparse.Namespace, console: Console) -> int:
    from fleet.engine import World

    scenario = _scenario(args)
    return _simulate(args, console, scenario, lambda: World(scenario, workers=args.workers))


def _cmd_serve(args: argparse.Namespace, console: Console) -> int:
    from dataclasses import replace

    from fleet.bus.security import ServerCurve
    from fleet.engine import World

    scenario = replace(_scenario(args), bus_address=args.bind)
    curve = None
    if args.key is not None or args.authorized is not None:
        if args.key is None or args.authorized is None:
            raise FleetError("fleet serve: CURVE needs both --key and --authorized")
        curve = ServerCurve(args.key, args.authorized)
    if not args.quiet:
        console.print(f"waiting up to {args.wait:g} s for agents to connect to {args.bind}")
    return _simulate(
        args,
        console,
        scenario,
        lambda: World(scenario, remote=True, curve=curve, agent_wait_s=args.wait),
    )


def _cmd_agent(args: argparse.Namespace, console: Console) -> int:
    from fleet.bus.security import ClientCurve
    from fleet.engine.agents import parse_robot_selection, serve_agent

    scenario = _scenario(args)
    robots = parse_robot_selection(scenario, args.only, args.share)
    curve = None
    if args.key is not None or args.server_key is not None:
        if args.key is None or args.server_key is None:
            raise FleetError("fleet agent: CURVE needs both --key and --server-key")
        curve = ClientCurve(args.key, args.server_key)
    console.print(f"hosting {len(robots)} robots for {args.connect}")
    report = serve_agent(
        scenario, args.connect, robots, name=args.name, curve=curve, idle_timeout_s=args.wait
    )
    errors = Console(stderr=True)
    if report.accepted is None:
        errors.print(
            f"[bold red]error:[/] no answer from an engine at {escape(args.connect)} within "
            f"{args.wait:g} s (not running, or it refused this agent's key)"
        )
        return 1
    if report.rejected:
        reasons = "; ".join(f"{r}: {why}" for r, why in sorted(report.rejected.items()))
        errors.print(f"[bold red]error:[/] the engine refused robots: {escape(reasons)}")
        if not report.accepted:
            return 1
    stats = report.stats
    console.print(
        f"{'run finished' if report.finished else 'engine went silent'}: answered "
        f"{stats['observations']} observations ({stats['controller_errors']} controller errors)"
    )
    return 0 if report.finished and not report.rejected else 1


def _cmd_keys(args: argparse.Namespace, console: Console) -> int:
    from fleet.bus.security import make_keypair

    public, secret = make_keypair(args.directory, args.name)
    console.print(f"public key: {public}\nsecret key: {secret} (keep it private)")
    return 0


def _simulate(args: argparse.Namespace, console: Console, scenario, make_world) -> int:
    """Build the World, run it with a progress bar, write the run directory, show key figures."""
    out = args.out or Path("runs") / f"{scenario.name}-seed{scenario.seed}"
    world = make_world()
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
        from fleet.view.figures import save_run_figures

        save_run_figures(out, world.floor)
    if not args.quiet:
        _kpi_table(console, result.summary)
        console.print(f"run directory: {out}")
    jobs = result.summary["jobs"]
    if not jobs["accounted"]:
        Console(stderr=True).print(
            f"[bold red]error:[/] job accounting broken: {jobs['released']} released, "
            f"{jobs['completed']} completed, {jobs['failed']} failed, "
            f"{jobs['in_progress']} in progress (see {out / 'events.csv'})"
        )
        return 1
    return 0


def _cmd_sweep(args: argparse.Namespace, console: Console) -> int:
    from contextlib import nullcontext

    from fleet.study.sweep import dask_executor, load_study, run_study

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
    from fleet.study.report import write_report

    if args.out is not None and args.out.exists() and not args.out.is_dir():
        raise FleetError(f"--out {args.out}: is a file; the report needs a directory")
    result = write_report(args.study_dir, args.out)
    for path in result.paths:
        console.print(f"wrote {escape(str(path))}", soft_wrap=True)
    return 0


def _cmd_plot(args: argparse.Namespace, console: Console) -> int:
    from fleet.view.figures import save_run_figures

    for path in save_run_figures(args.run_dir):
        console.print(f"wrote {escape(str(path))}", soft_wrap=True)
    return 0


def _cmd_replay(args: argparse.Namespace, console: Console) -> int:
    from fleet.view.replay import REPLAY_HTML, write_replay

    out = args.out
    if out is not None and out.is_dir():
        out = out / REPLAY_HTML
    path = write_replay(args.run_dir, out)
    console.print(
        f"wrote {escape(str(path))} (open it in a browser; it needs no server or network)",
        soft_wrap=True,
    )
    return 0


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: must be a number > 0")
    return value


def _non_negative_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: must be a whole number >= 0")
    return value


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
        ("jobs failed / in progress", f"{jobs['failed']} / {jobs['in_progress']}"),
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
    latency = s.get("latency") or {}
    if latency.get("commands"):
        rows[-1:-1] = [
            (
                f"latency ({latency['mode']}) median / p95 / max",
                f"{latency['median_ms']:.1f} / {latency['p95_ms']:.1f} / "
                f"{latency['max_ms']:.1f} ms",
            ),
            ("commands later than their period", str(latency["late"])),
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
    from fleet.printing.gcode import analyze

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


def _cmd_schema(args: argparse.Namespace, console: Console) -> int:
    import msgspec

    from fleet.floor import MapFile
    from fleet.scenario import ScenarioFile

    structure = ScenarioFile if args.kind == "scenario" else MapFile
    text = msgspec.json.format(msgspec.json.encode(msgspec.json.schema(structure))).decode()
    if args.out is None:
        sys.stdout.write(text + "\n")  # plain: no markup or wrapping, so it pipes to a file
    else:
        try:
            args.out.write_text(text + "\n", encoding="utf-8")
        except OSError as exc:
            raise FleetError(f"--out {args.out}: cannot write the schema: {exc.strerror}") from None
        console.print(f"wrote the {args.kind} schema to {args.out}", highlight=False)
    return 0


def _hms(seconds: float) -> str:
    m, s = divmod(seconds, 60.0)
    h, m = divmod(int(m), 60)
    return f"{h}h {m:02d}m {s:04.1f}s" if h else f"{m}m {s:04.1f}s"


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
