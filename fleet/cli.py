"""The `fleet` command line: run scenarios and studies, draw and replay runs, list and start
plugins, make keys, inspect floor maps and G-code files.

Exit status, the same for every command (`fleet --help` says it too):

- 0: done;
- 1: bad input (a file, a field or an option value; the message names it and the value) or a
  failed run (a sweep with failed cells, broken job accounting, an agent refused);
- 2: usage (an unknown command or option, a missing argument, a value of the wrong form);
- 130: interrupted (Ctrl-C); `fleet run` and `fleet sweep` first save what they have, marked
  incomplete.

Errors are one paragraph on stderr naming the file, field or option and the bad value; a
traceback only with ``--debug``. Off a terminal (a pipe, a file, CI) the output is plain: no
colour, no progress bar, no wrapping.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import re
import signal
import sys
import time
import tomllib
import traceback
import warnings
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.progress import (
    BarColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)
from rich.table import Table

from fleet import __version__
from fleet.errors import FleetError, InputError

__all__ = ["main", "EXIT_OK", "EXIT_FAILED", "EXIT_USAGE", "EXIT_INTERRUPTED"]

#: Exit status: done.
EXIT_OK = 0
#: Exit status: bad input, or a run that failed.
EXIT_FAILED = 1
#: Exit status: the command line itself is wrong (argparse's usage errors).
EXIT_USAGE = 2
#: Exit status: interrupted by Ctrl-C (128 + SIGINT, as shells report it).
EXIT_INTERRUPTED = 130

_EXIT_CODES = """exit status: 0 done; 1 bad input or a failed run; 2 usage (unknown option,
missing argument); 130 interrupted (Ctrl-C; run and sweep save what they have, marked
incomplete). --debug shows the traceback of an error."""

# Off a terminal rich would wrap at 80 columns; lines this long are never wrapped.
_PLAIN_WIDTH = 4096


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `fleet` console script; returns the exit status."""
    parser = _parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version (0) and usage errors (2)
        return exc.code if isinstance(exc.code, int) else EXIT_USAGE
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    if args.command == "serve":
        # The engine's operator sees agents join and leave, not only refusals and losses.
        logging.getLogger("fleet.bus").setLevel(logging.INFO)
    errors = _console(stderr=True)
    try:
        return args.handler(args, _console(stderr=False), errors)
    except KeyboardInterrupt:
        _debug_traceback(args)
        errors.print("interrupted", highlight=False)
        return EXIT_INTERRUPTED
    except FleetError as exc:
        _debug_traceback(args)
        _error(errors, str(exc))
        return EXIT_FAILED
    except OSError as exc:  # a disk full, a folder not writable: the user's to fix, not ours
        _debug_traceback(args)
        where = f"{exc.filename}: " if exc.filename else ""
        _error(errors, f"{where}{exc.strerror or exc}")
        return EXIT_FAILED
    except Exception as exc:
        if args.debug:
            raise
        _error(
            errors,
            f"unexpected {type(exc).__name__}: {exc}. This is a bug in mambot-fleet: run the "
            "command again with --debug for the traceback, and report it with the command",
        )
        return EXIT_FAILED


def _debug_traceback(args: argparse.Namespace) -> None:
    if args.debug:
        traceback.print_exc()


def _error(errors: Console, message: str) -> None:
    # Escape: messages quote TOML like "[floor]" that rich would take for markup.
    errors.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)


def _warn(errors: Console, message: str) -> None:
    errors.print(f"[yellow]warning:[/] {escape(message)}", highlight=False, soft_wrap=True)


def _console(*, stderr: bool) -> Console:
    """A console for stdout or stderr: rich on a terminal, plain text anywhere else."""
    stream = sys.stderr if stderr else sys.stdout
    if stream.isatty():
        return Console(stderr=stderr)
    return Console(
        stderr=stderr,
        width=_PLAIN_WIDTH,
        no_color=True,
        highlight=False,
        emoji=False,
        soft_wrap=True,
    )


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="fleet",
        description="Simulate fleets of MAMbots on a shop floor.",
        epilog=_EXIT_CODES,
    )
    p.add_argument("--version", action="version", version=f"mambot-fleet {__version__}")
    p.add_argument("--debug", action="store_true", help="show the traceback of an error")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def command(name: str, help: str, handler: Callable[..., int]) -> argparse.ArgumentParser:
        cmd = sub.add_parser(name, help=help, description=help, epilog=_EXIT_CODES)
        # SUPPRESS: a subcommand's default would overwrite `fleet --debug CMD`'s.
        cmd.add_argument(
            "--debug",
            action="store_true",
            default=argparse.SUPPRESS,
            help="show the traceback of an error",
        )
        cmd.set_defaults(handler=handler)
        return cmd

    run = command("run", "run a scenario and write its run directory", _cmd_run)
    _scenario_arguments(run)
    _output_arguments(run)
    run.add_argument(
        "--workers",
        type=_non_negative_int,
        default=0,
        help="worker processes hosting the robots' agents (0: all in this process); they talk "
        "to the engine over the scenario's [bus] address, or a private ipc:// socket",
    )
    _threads_argument(run, "each agent host (this process's, each worker's)")
    _json_argument(run, "the run's summary.json object and its run directory")

    serve = command(
        "serve",
        "run a scenario whose robot agents join from elsewhere (`fleet agent --connect`)",
        _cmd_serve,
    )
    _scenario_arguments(serve)
    _output_arguments(serve)
    serve.add_argument(
        "--bind",
        required=True,
        type=_address("tcp://*:5555 or ipc:///tmp/fleet"),
        help="where agents connect, e.g. tcp://*:5555 or ipc:///tmp/f",
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

    agent = command("agent", "host robot agents for a run started by `fleet serve`", _cmd_agent)
    agent.add_argument("scenario", nargs="?", help="the run's scenario TOML (same as the engine's)")
    agent.add_argument("--map", help="floor map TOML, as given to the engine")
    agent.add_argument(
        "--robots", type=_positive_int, help="number of robots, as given to the engine"
    )
    agent.add_argument("--controller", help="controller plugin name, as given to the engine")
    _set_argument(agent, "as given to the engine")
    agent.add_argument(
        "--connect",
        required=True,
        type=_address("tcp://HOST:5555 or ipc:///tmp/fleet"),
        help="the engine's address, tcp://HOST:PORT",
    )
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
    _threads_argument(agent, "this agent")

    keys = command(
        "keys",
        "make a CURVE key pair for `fleet serve` / `fleet agent`, by default in your user "
        "configuration folder, never in a git work tree unless forced",
        _cmd_keys,
    )
    keys.add_argument(
        "directory",
        type=Path,
        nargs="?",
        help=f"where to write NAME.key and NAME.key_secret (default: {_display(_key_home())}; "
        "the folder is made owner-only, 0700, the secret file 0600)",
    )
    keys.add_argument("--name", default="fleet", help="file name stem (default: fleet)")
    keys.add_argument(
        "--force",
        action="store_true",
        help="write into DIRECTORY even inside a git work tree (keep the secret out of commits)",
    )

    sweep = command(
        "sweep", "run a study: a grid of scenario values over seeds, cells in parallel", _cmd_sweep
    )
    sweep.add_argument("study", type=Path, help="study TOML (see studies/throughput.toml)")
    sweep.add_argument(
        "--out", type=Path, help="study directory (default: runs/<study name>); resumes there"
    )
    sweep.add_argument(
        "-j",
        "--jobs",
        type=_positive_int,
        help="cells run at once, each in a local process (default: one per CPU core)",
    )
    # --workers means agent processes on `fleet run`; here it was the cells run at once.
    sweep.add_argument("--workers", dest="old_workers", type=_positive_int, help=argparse.SUPPRESS)
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
    _json_argument(sweep, "the sweep's counts, where its results are, and every cell's record")

    report = command(
        "report", "plot a study's results and write a Markdown summary (report.md)", _cmd_report
    )
    report.add_argument("study_dir", type=Path, help="a directory written by `fleet sweep`")
    report.add_argument("--out", type=Path, help="where to write (default: the study directory)")
    report.add_argument(
        "--half-width",
        default="5%",
        metavar="H",
        help="the 95 %% interval half-width to aim for: a share of the mean (5%%, the default) "
        "or good parts/h (0.5); the report says which intervals are wider and how many seeds "
        "they need",
    )
    _json_argument(
        report, "the files written, good parts per hour, the differences and the seeds needed"
    )

    plot = command(
        "plot",
        "draw a run's figures: trajectories, speed against limits, print Gantt",
        _cmd_plot,
    )
    plot.add_argument("run_dir", type=Path, help="a run directory written by `fleet run`")

    replay = command("replay", "write a self-contained HTML page that animates a run", _cmd_replay)
    replay.add_argument("run_dir", type=Path, help="a run directory written by `fleet run`")
    replay.add_argument(
        "--out", type=Path, help="HTML file or directory (default: RUN_DIR/replay.html)"
    )

    command("plugins", "list the controller and dispatcher plugins found", _cmd_plugins)

    from fleet.plugins.scaffold import KINDS

    new_plugin = command(
        "new-plugin",
        "write a plugin package that installs, is found by `fleet plugins` and passes the "
        "conformance kit as written (docs/tutorial.md)",
        _cmd_new_plugin,
    )
    new_plugin.add_argument("name", help="the plugin's name, e.g. slow_follower")
    new_plugin.add_argument("--kind", required=True, choices=tuple(KINDS), help="plugin kind")
    new_plugin.add_argument(
        "--out", type=Path, default=Path("."), help="folder to write NAME/ into (default: .)"
    )

    floor = command("map", "compile a floor map and describe its regions", _cmd_map)
    floor.add_argument("file", type=Path, help="a floor map TOML (maps/README.md)")

    gcode = command("gcode", "time a G-code file and split it into print tasks", _cmd_gcode)
    gcode.add_argument("file", type=Path, help="G-code from PrusaSlicer, SuperSlicer or Cura")
    gcode.add_argument("--json", action="store_true", help="print the analysis as JSON")
    gcode.add_argument(
        "--min-task",
        type=_non_negative_float,
        default=10.0,
        metavar="S",
        help="minimum task duration in seconds; shorter segments merge (default 10)",
    )
    gcode.add_argument(
        "--classify",
        action="append",
        default=[],
        metavar="NAME=KIND",
        help="classify slicer feature NAME as KIND (contour, infill, support, travel, other); "
        "repeatable, e.g. --classify 'Gap fill=contour' (as [print] classify in a scenario)",
    )
    # --map names a floor map everywhere else; here it was --classify.
    gcode.add_argument("--map", dest="old_map", action="append", default=[], help=argparse.SUPPRESS)

    schema = command(
        "schema",
        "print the JSON Schema of scenario or map files, for editors (docs/schema.md)",
        _cmd_schema,
    )
    schema.add_argument("kind", choices=("scenario", "map"), help="which files the schema is of")
    schema.add_argument("--out", type=Path, help="write the schema to this file instead")
    return p


def _scenario_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", nargs="?", help="scenario TOML (default: scenarios/default.toml)")
    p.add_argument("--map", help="floor map TOML, overriding the scenario's")
    p.add_argument("--robots", type=_positive_int, help="number of robots")
    p.add_argument("--controller", help="controller plugin name (see `fleet plugins`)")
    p.add_argument("--dispatcher", help="dispatcher plugin name (see `fleet plugins`)")
    p.add_argument("--duration", type=_positive_float, help="simulated seconds")
    p.add_argument("--seed", type=_non_negative_int, help="random seed")
    _set_argument(p, "checked as the file's own values are")
    p.add_argument(
        "--latency",
        metavar="none|measured|SECONDS",
        help="compute latency: a command takes effect this long after its tick (default: the "
        "scenario's [scenario] latency, else none). 'measured' uses each solve's measured step "
        "time, so the run depends on this machine and its digest is not reproducible; a "
        "number of seconds is reproducible. Meant for the MPC: the follower is not "
        "latency-tolerant (docs/fleet.md)",
    )


def _set_argument(p: argparse.ArgumentParser, how: str) -> None:
    p.add_argument(
        "--set",
        dest="settings",
        action="append",
        default=[],
        type=_setting,
        metavar="KEY=VALUE",
        help="set one scenario value by its dotted key, e.g. --set robots.count=8 or --set "
        "controller.options.horizon=20; repeatable; VALUE is read as TOML (8, 0.5, true, "
        f'"text"; a bare word is text), {how}; file names are relative to the current folder',
    )


def _output_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, help="run directory (default: runs/<scenario>-seed<seed>)")
    p.add_argument(
        "--force",
        action="store_true",
        help="write into an --out that holds an earlier run, clearing that run's files first "
        "(without it such a directory is refused, so no stale file survives; the default "
        "runs/<scenario>-seed<seed> is always replaced)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar or table")
    p.add_argument(
        "--no-figures",
        dest="figures",
        action="store_false",
        help="skip trajectory.png, speed.png, gantt.png, states.png and wip.png (they take about "
        "two seconds for an hour of a few robots; `fleet plot RUN_DIR` draws them later)",
    )


def _json_argument(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument(
        "--json",
        action="store_true",
        help=f"print {what} as JSON on stdout, and nothing else there (messages go to stderr)",
    )


def _scenario(args: argparse.Namespace):
    from fleet.scenario import REPO_ROOT, load_scenario

    path = Path(args.scenario) if args.scenario else REPO_ROOT / "scenarios" / "default.toml"
    scenario = load_scenario(path, dict(args.settings))
    return scenario.override(
        map=args.map,
        robots=args.robots,
        controller=args.controller,
        dispatcher=getattr(args, "dispatcher", None),
        duration=getattr(args, "duration", None),
        seed=getattr(args, "seed", None),
        latency=getattr(args, "latency", None),
        controller_options=_options(args.settings, "controller.options."),
        threads=getattr(args, "steps_at_once", None),
    )


def _options(settings: list[tuple[str, Any]], prefix: str) -> dict[str, Any]:
    """The ``--set`` values under `prefix`, as a plugin's options (by their names)."""
    return {k.removeprefix(prefix): v for k, v in settings if k.startswith(prefix)}


def _threads_argument(cmd: argparse.ArgumentParser, who: str) -> None:
    cmd.add_argument(
        "--threads",
        dest="steps_at_once",
        metavar="N",
        type=_positive_int,
        help=f"robots' steps {who} computes at once, in threads (default: the scenario's "
        "[bus] threads, 1); the MPC's solves overlap on that many cores, the results unchanged",
    )


def _cmd_run(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from fleet.engine import World

    scenario = _scenario(args)
    return _simulate(args, console, errors, scenario, lambda: World(scenario, workers=args.workers))


def _cmd_serve(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from dataclasses import replace

    from fleet.bus.security import ServerCurve
    from fleet.engine import World

    args.json = False
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
        errors,
        scenario,
        lambda: World(scenario, remote=True, curve=curve, agent_wait_s=args.wait),
    )


def _cmd_agent(args: argparse.Namespace, console: Console, errors: Console) -> int:
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
    if report.accepted is None:
        _error(
            errors,
            f"no answer from an engine at {args.connect} within {args.wait:g} s (not running, "
            "or it refused this agent's key)",
        )
        return EXIT_FAILED
    if report.rejected:
        reasons = "; ".join(f"{r}: {why}" for r, why in sorted(report.rejected.items()))
        _error(errors, f"the engine refused robots: {reasons}")
        if not report.accepted:
            return EXIT_FAILED
    stats = report.stats
    console.print(
        f"{'run finished' if report.finished else 'engine went silent'}: answered "
        f"{stats['observations']} observations ({stats['controller_errors']} controller errors)"
    )
    return EXIT_OK if report.finished and not report.rejected else EXIT_FAILED


# -- keys -------------------------------------------------------------------------------------
def _key_home() -> Path:
    """Where `fleet keys` writes by default: the user's configuration folder, never a project."""
    base = os.environ.get("XDG_CONFIG_HOME") or ""
    root = Path(base) if Path(base).is_absolute() else Path.home() / ".config"
    return root / "mambot-fleet" / "keys"


def _display(path: Path) -> str:
    """`path` with the home folder written ~, as a user would type it."""
    try:
        return "~/" + path.relative_to(Path.home()).as_posix()
    except ValueError:
        return str(path)


def _work_tree(path: Path) -> Path | None:
    """The git work tree `path` (which need not exist yet) lies in, or None."""
    for folder in (path.resolve(), *path.resolve().parents):
        if (folder / ".git").exists():
            return folder
    return None


def _cmd_keys(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from fleet.bus.security import make_keypair

    default = args.directory is None
    directory = _key_home() if default else args.directory
    tree = _work_tree(directory)
    if tree is not None and not args.force:
        raise InputError(
            "command line",
            "DIRECTORY",
            str(directory),
            f"lies in the git work tree {tree}, where a secret key is one `git add` away from "
            f"being published; leave DIRECTORY out to use {_display(_key_home())}, choose a "
            "folder outside the work tree, or give --force (and keep the key out of commits)",
        )
    public, secret = make_keypair(directory, args.name)
    mode = directory.stat().st_mode & 0o777
    if mode & 0o077:
        if default:
            directory.chmod(0o700)  # ours: owner-only, whatever the umask made of it
        else:
            _warn(
                errors,
                f"{directory} is readable by others (mode {mode:04o}); the secret file itself is "
                f"0600, but `chmod 700 {directory}` keeps even its name private",
            )
    console.print(
        f"public key: {public} (give it to the other side)\n"
        f"secret key: {secret} (mode 0600; never copy it off this machine)",
        highlight=False,
    )
    return EXIT_OK


# -- running a scenario -----------------------------------------------------------------------
@contextmanager
def _stop_on_interrupt(errors: Console) -> Iterator[Callable[[], bool]]:
    """A first Ctrl-C asks the run to stop at its next step (`World.run`'s `stop`); a second
    one interrupts at once. Yields the question `stop` asks."""
    asked: list[bool] = []

    def handler(signum: int, frame: Any) -> None:
        if asked:
            raise KeyboardInterrupt
        asked.append(True)
        errors.print(
            "stopping at the next step to save what ran (Ctrl-C again to stop at once)",
            highlight=False,
        )

    try:
        previous = signal.signal(signal.SIGINT, handler)
    except ValueError:  # not the main thread: Ctrl-C keeps its usual meaning
        yield lambda: False
        return
    try:
        yield lambda: bool(asked)
    finally:
        signal.signal(signal.SIGINT, previous)


def _simulate(
    args: argparse.Namespace, console: Console, errors: Console, scenario, make_world
) -> int:
    """Build the World, run it with a progress bar, write the run directory, show key figures."""
    # The default folder is the run's own, by name and seed: running again replaces that run.
    # A folder the user names is refused when it holds a run, unless --force.
    from fleet.api.runs import fresh_run_dir, run_problems, simulate

    out = args.out or Path("runs") / f"{scenario.name}-seed{scenario.seed}"
    fresh_run_dir(out, args.force or args.out is None)
    talk = errors if args.json else console  # --json keeps stdout for the JSON
    world = make_world()
    if not args.quiet:
        talk.print(
            f"[bold]{escape(scenario.name)}[/]: {len(world.robots)} robots on "
            f"{escape(world.floor.name)} ({len(world.floor.regions)} regions), "
            f"{escape(scenario.controller.name)} + {escape(scenario.dispatcher.name)}, "
            f"{scenario.duration_s:g} s simulated, seed {scenario.seed}"
        )
    with _stop_on_interrupt(errors) as stop, _run_progress(errors, args.quiet) as progress:
        task = progress.add_task("run", total=scenario.duration_s, rtf="")
        wall0 = time.perf_counter()

        def advance(now: float) -> None:
            wall = time.perf_counter() - wall0
            rtf = f"{now / wall:,.1f}x real time" if wall > 0 and now > 0 else ""
            progress.update(task, completed=now, rtf=rtf)

        summary = simulate(world, out, progress=advance, stop=stop, figures=args.figures)
    complete = summary["complete"]
    if args.json:
        _print_json({"run_dir": str(out), "complete": complete, "summary": summary})
    elif not args.quiet:
        _kpi_table(console, summary)
        console.print(f"run directory: {escape(str(out))}", soft_wrap=True)
    if not complete:
        _error(
            errors,
            f"interrupted at {summary['sim_time_s']:g} s of {scenario.duration_s:g} s: {out} "
            'holds the run so far, and its summary.json says "complete": false (no figures; '
            f"`fleet plot {out}` draws them)",
        )
        return EXIT_INTERRUPTED
    problems = run_problems(summary, out)
    for problem in problems:
        _error(errors, problem)
    return EXIT_FAILED if problems else EXIT_OK


def _run_progress(errors: Console, quiet: bool) -> Progress:
    """The run's progress bar, on stderr and only on a terminal: simulated seconds done of the
    total, the estimated time left and how much faster than real time the run goes."""
    return Progress(
        TextColumn("simulating"),
        BarColumn(),
        TextColumn("{task.completed:>7,.0f} / {task.total:,.0f} s"),
        TextColumn("{task.fields[rtf]}"),
        TextColumn("left"),
        TimeRemainingColumn(),
        console=errors,
        transient=True,
        disable=quiet or not errors.is_terminal,
    )


def _print_json(data: Any) -> None:
    # Plain stdout, not rich: the output is for programs.
    sys.stdout.write(json.dumps(data, indent=2, default=str) + "\n")


# -- studies ----------------------------------------------------------------------------------
def _cmd_sweep(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from contextlib import nullcontext

    from fleet.study.sweep import SweepInterrupted, dask_executor, load_study, run_study

    jobs = args.jobs
    if args.old_workers is not None:
        _warn(
            errors,
            "fleet sweep --workers is now --jobs (-j): --workers means agent processes on "
            "`fleet run`; --workers here will go in a later release",
        )
        jobs = jobs if jobs is not None else args.old_workers
    study = load_study(args.study)
    out = args.out or Path("runs") / study.name
    if out.exists() and not out.is_dir():
        raise InputError(
            "command line", "--out", str(out), "is a file; the study needs a directory"
        )
    total = len(study.cells)
    where = f"Dask scheduler {args.scheduler}" if args.scheduler else "local processes"
    talk = errors if args.json else console
    if not args.quiet:
        talk.print(
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
            TextColumn("left"),
            TimeRemainingColumn(),
            console=errors,
            disable=args.quiet or not errors.is_terminal,
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
                    soft_wrap=True,
                )
            bar.update(task, completed=done, failed=failed)

        try:
            result = run_study(
                study,
                out,
                executor=ex,
                workers=jobs,
                progress=progress,
                retry_failed=args.retry_failed,
            )
        except SweepInterrupted as stopped:
            result = stopped.result
    if args.json:
        _print_json(
            {
                "study": study.name,
                "out_dir": str(result.out_dir),
                "complete": result.complete,
                "cells": total,
                "ok": result.ok,
                "failed": result.failed,
                "skipped": result.skipped,
                "results": [str(p) for p in result.results_paths],
                "records": result.records,
            }
        )
    elif not args.quiet:
        console.print(
            f"{result.ok} ok, {result.failed} failed ({result.skipped} of these cells reused "
            f"from an earlier sweep); results: {escape(str(result.results_path))}; "
            f"next: fleet report {escape(str(out))}",
            soft_wrap=True,
        )
    if not result.complete:
        _error(
            errors,
            f"interrupted: {len(result.records)} of {total} cells have a record in "
            f'{result.results_path}, and study.json says "complete": false; run the same '
            "command again to run the rest",
        )
        return EXIT_INTERRUPTED
    return EXIT_FAILED if result.failed else EXIT_OK


def _cmd_report(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from fleet.study.report import HalfWidth, method_summary, write_report

    if args.out is not None and args.out.exists() and not args.out.is_dir():
        raise InputError(
            "command line", "--out", str(args.out), "is a file; the report needs a directory"
        )
    try:
        target = HalfWidth.parse(args.half_width)
    except ValueError as exc:
        raise InputError("command line", "--half-width", args.half_width, str(exc)) from None
    result = write_report(args.study_dir, args.out, half_width=target)
    summary = result.summary
    if args.json:
        _print_json(
            {
                "study": summary.study.name,
                "out_dir": str(result.out_dir),
                "report": str(result.report),
                "figures": [str(p) for p in result.figures],
                "runs": len(summary.study.runs),
                "failed": len(summary.study.failed),
                "not_run": list(summary.study.not_run),
                # Good parts per hour: mean and 95 % interval across seeds, per setting.
                "throughput_good_per_h": [
                    {
                        "panel": panel,
                        "series": series,
                        "x": x,
                        "mean": iv.mean,
                        "low": iv.low,
                        "high": iv.high,
                        "n": iv.n,
                    }
                    for (panel, series, x), iv in summary.throughput.items()
                ],
                "method": method_summary(summary),
                # Leader minus each other series per setting, 95 % interval, method named.
                "differences": [
                    {
                        "panel": r.panel,
                        "x": r.x,
                        "leader": r.leader,
                        "series": series,
                        "mean": d.mean,
                        "low": d.low if d.half_width is not None else None,
                        "high": d.high if d.half_width is not None else None,
                        "method": d.method.value,
                        "df": d.df,
                        "seeds": list(d.seeds),
                        "text": d.method_text(),
                    }
                    for r in summary.rankings
                    for series, d in r.differences.items()
                ],
                "half_width_target": summary.target.text(),
                "seeds_needed": [
                    {
                        "panel": a.panel,
                        "x": a.x,
                        "interval": a.series,
                        "n": a.n,
                        "half_width": a.half_width,
                        "target": a.target,
                        "needed": a.needed,
                    }
                    for a in summary.advice
                    if not a.enough
                ],
            }
        )
        return EXIT_OK
    _print_comparisons(console, summary)
    for path in result.paths:
        console.print(f"wrote {escape(str(path))}", soft_wrap=True)
    return EXIT_OK


def _print_comparisons(console: Console, summary: Any, most: int = 12) -> None:
    """The leader's difference to each other series per setting, with the method named, and
    whether the intervals meet the target half-width."""
    lines = []
    for r in summary.rankings:
        where = ", ".join(
            f"{axis}={label}"
            for axis, label in ((summary.study.panel_axis, r.panel), (summary.study.x_axis, r.x))
            if label is not None
        )
        prefix = f"{where}: " if where else ""
        for series, d in r.differences.items():
            sep = "" if d.half_width is None else ", separated" if d.low > 0 else ", not separated"
            lines.append(
                f"{prefix}{r.leader} − {series} = {d.text()} good parts/h ({d.method_text()}){sep}"
            )
    for line in lines[:most]:
        console.print(escape(line), soft_wrap=True, highlight=False)
    if len(lines) > most:
        console.print(f"… {len(lines) - most} more differences in report.md (Comparisons)")
    short = [a for a in summary.advice if not a.enough]
    known = [a.needed for a in short if a.needed is not None]
    if short:
        more = f"; up to {max(known)} seeds needed" if known else ""
        console.print(
            f"{len(short)} of {len(summary.advice)} intervals are wider than "
            f"{escape(summary.target.text())}{more} (report.md, Replications)",
            soft_wrap=True,
            highlight=False,
        )


def _cmd_plot(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from fleet.view.figures import save_run_figures

    for path in save_run_figures(args.run_dir):
        console.print(f"wrote {escape(str(path))}", soft_wrap=True)
    return EXIT_OK


def _cmd_replay(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from fleet.view.replay import REPLAY_HTML, write_replay

    out = args.out
    if out is not None and out.is_dir():
        out = out / REPLAY_HTML
    path = write_replay(args.run_dir, out)
    console.print(
        f"wrote {escape(str(path))} (open it in a browser; it needs no server or network)",
        soft_wrap=True,
    )
    return EXIT_OK


def _cmd_new_plugin(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from fleet.plugins.scaffold import write_plugin

    made = write_plugin(args.name, args.kind, args.out)
    for path in made.files:
        console.print(f"wrote {escape(str(path))}", soft_wrap=True)
    root = escape(str(made.root))
    console.print(
        f"next: pip install -e {root} (into the environment fleet runs in); fleet plugins "
        f"lists {made.name}; python -m pytest {root}/tests runs the conformance kit; a "
        f'scenario uses it with [{made.kind}] name = "{made.name}"',
        soft_wrap=True,
        highlight=False,
    )
    return EXIT_OK


# -- option values ----------------------------------------------------------------------------
_KEY = re.compile(r"^[A-Za-z0-9_\-]+(\.[A-Za-z0-9_\-]+)*$")


def _setting(text: str) -> tuple[str, Any]:
    """``--set KEY=VALUE``: the dotted key and the value read as TOML (a bare word: text)."""
    key, sep, value = text.partition("=")
    key = key.strip()
    if not sep or not _KEY.match(key):
        raise argparse.ArgumentTypeError(
            f"{text!r}: write KEY=VALUE with a dotted scenario key, e.g. robots.count=8"
        )
    try:
        return key, tomllib.loads(f"value = {value.strip()}")["value"]
    except tomllib.TOMLDecodeError:
        return key, value.strip()


def _address(example: str) -> Callable[[str], str]:
    def check(text: str) -> str:
        if not re.match(r"^(tcp|ipc)://\S+$", text):
            raise argparse.ArgumentTypeError(f"{text!r}: must be a ZeroMQ address, e.g. {example}")
        return text

    return check


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r}: must be a number > 0")
    return value


def _non_negative_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"{text!r}: must be a number >= 0")
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


def _disruption_rows(s: dict) -> list[tuple[str, str]]:
    """The key figures of what went wrong: hand-backs (by reason) and the print time they
    scrapped, deadlocks and faults (a summary without them, from an older run: none shown)."""
    rows = []
    handbacks = s.get("handbacks")
    if isinstance(handbacks, dict):
        rows.append(
            (
                "hand-backs / scrapped print",
                f"{handbacks['count']} / {handbacks['scrapped_print_s']:.1f} s",
            )
        )
        rows += [(f"  hand-backs: {why}", str(n)) for why, n in handbacks["by_reason"].items()]
    if "deadlocks" in s:
        rows.append(("deadlocks", str(s["deadlocks"])))
    faults = s.get("faults")
    if isinstance(faults, dict):
        rows.append(
            (
                "faults: agents lost / left",
                f"{faults.get('agents_lost', 0)} / {faults.get('agents_left', 0)}",
            )
        )
        rows.append(
            (
                "faults: robots orphaned / rejoined",
                f"{faults.get('robots_orphaned', 0)} / {faults.get('robots_rejoined', 0)}",
            )
        )
    return rows


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
        *_disruption_rows(s),
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
        if solver.get("time_limit_hits"):
            rows[-1:-1] = [
                (
                    "solves cut by the wall clock",
                    f"{solver['time_limit_hits']} (the run may not be reproducible)",
                )
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
    breakdowns = s.get("breakdowns") or {}
    if breakdowns.get("configured"):
        rows[-1:-1] = [
            (
                "availability / breakdowns / repair",
                f"{100 * breakdowns['availability']:.1f} % / {breakdowns['breakdowns']} / "
                f"{breakdowns['repair_s']:.0f} s",
            ),
            ("jobs handed back by breakdowns", str(breakdowns["jobs_handed_back"])),
        ]
    battery = s.get("battery")
    if battery:  # [battery]: the fleet's time at the chargers, and robots that ran flat
        rows[-1:-1] = [
            (
                "charging time (fleet) / charges",
                f"{battery['charging_s'] / 3600:.2f} h ({battery['charging_share']:.0%}) / "
                f"{battery['charges']}",
            ),
            (
                "lowest charge / robots stranded",
                f"{battery['min_charge_share']:.0%} / {battery['stranded']}",
            ),
        ]
    for robot, at in (s.get("arrivals") or {}).items():
        rows.insert(-1, (f"arrival {robot}", "-" if at is None else f"{at:.1f} s"))
    rows[-1:-1] = _time_rows(s)
    for name, value in rows:
        t.add_row(name, value)
    console.print(t)


def _time_rows(s: dict) -> list[tuple[str, str]]:
    """The KPI table's rows of KPIs over time: waits, lead times, queue and WIP, the fleet's
    share of time in each state, the warm-up left out and the one MSER-5 suggests."""
    rows = []

    for key, what, stats in (
        ("assign_wait_s", "wait for assignment", ("mean", "p50", "p95")),
        ("lead_time_s", "lead time", ("p50", "p95")),
    ):
        d = s.get(key) or {}
        if d.get("n"):
            values = " / ".join(f"{d[k]:.1f}" for k in stats)
            rows.append((f"{what} {' / '.join(stats)}", f"{values} s"))
    if s.get("wip_mean") is not None:
        rows.append(("queue / WIP mean", f"{s['queue_mean']:.2f} / {s['wip_mean']:.2f} jobs"))
    shares = (s.get("states") or {}).get("shares")
    if shares:
        pct = {k: f"{100 * v:.0f}" for k, v in shares.items()}
        rows.append(
            (
                "robots' time idle / driving empty / blocked",
                f"{pct['idle']} / {pct['driving_empty']} / {pct['blocked']} %",
            )
        )
        rows.append(
            (
                "robots' time printing driving / at rest",
                f"{pct['printing_driving']} / {pct['printing_at_rest']} %",
            )
        )
        if shares["faulted"] or shares["charging"]:
            rows.append(
                ("robots' time faulted / charging", f"{pct['faulted']} / {pct['charging']} %")
            )
    if s.get("warmup_s"):
        rows.append(("warm-up left out of the KPIs", f"{s['warmup_s']:g} s"))
    if s.get("suggested_warmup_s") is not None:
        limit = " (limit: run longer)" if s.get("suggested_warmup_at_limit") else ""
        rows.append(("warm-up suggested (MSER-5, WIP)", f"{s['suggested_warmup_s']:.0f} s{limit}"))
    return rows


def _cmd_plugins(args: argparse.Namespace, console: Console, errors: Console) -> int:
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
        _warn(errors, str(w.message))
    return EXIT_OK


def _cmd_map(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from fleet.floor import load_floor

    floor = load_floor(args.file)
    xmin, ymin, xmax, ymax = floor.bounds
    console.print(f"[bold]{escape(floor.name)}[/] ({escape(str(floor.source))})")
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
    stations = ", ".join(f"{s.name} ({s.kind})" for s in floor.spec.stations)
    console.print(f"stations: {escape(stations)}", soft_wrap=True)
    return EXIT_OK


def _cmd_gcode(args: argparse.Namespace, console: Console, errors: Console) -> int:
    from fleet.errors import GcodeError
    from fleet.printing.gcode import analyze

    if args.old_map:
        _warn(
            errors,
            "fleet gcode --map is now --classify: --map names a floor map on the other "
            "commands; --map here will go in a later release",
        )
    classification: dict[str, str] = {}
    for item in [*args.old_map, *args.classify]:
        name, sep, kind = item.partition("=")
        if not sep or not name.strip():
            raise GcodeError(
                str(args.file),
                "--classify",
                item,
                "write NAME=KIND, e.g. --classify 'Gap fill=contour'",
            )
        classification[name.strip()] = kind.strip()
    a = analyze(args.file, min_task_s=args.min_task, classification=classification)
    if args.json:
        _print_json(a.to_json())
        return EXIT_OK
    console.print(
        f"[bold]{escape(a.file)}[/] ({escape(a.slicer or 'unknown slicer')}), {a.layers} layers"
    )
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
        _warn(errors, w)
    return EXIT_OK


def _cmd_schema(args: argparse.Namespace, console: Console, errors: Console) -> int:
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
            raise InputError(
                "command line", "--out", str(args.out), f"cannot write the schema: {exc.strerror}"
            ) from None
        console.print(f"wrote the {args.kind} schema to {escape(str(args.out))}", highlight=False)
    return EXIT_OK


def _hms(seconds: float) -> str:
    m, s = divmod(seconds, 60.0)
    h, m = divmod(int(m), 60)
    return f"{h}h {m:02d}m {s:04.1f}s" if h else f"{m}m {s:04.1f}s"


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
