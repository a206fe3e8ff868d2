"""Running one scenario from code, and reading a run directory back as typed tables.

`simulate` is the one way a built World runs and writes its run directory: `fleet run`,
`fleet serve` and `run` here all go through it, and `fresh_run_dir` decides for all of them
whether a folder may take a run.
"""

from __future__ import annotations

import json
import logging
import shutil
import tempfile
import weakref
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fleet.api.tables import Tables, rows_of
from fleet.errors import InputError
from fleet.scenario import Scenario

if TYPE_CHECKING:
    from fleet.engine import World

__all__ = [
    "RunResult",
    "TemporaryFolder",
    "run",
    "open_run",
    "simulate",
    "fresh_run_dir",
    "run_problems",
    "progress_hook",
]

log = logging.getLogger("fleet.api")

#: What `run` takes as `progress`: False, True (a bar on stderr) or a callable given the
#: simulated seconds done, about 200 times over the run.
Progress = bool | Callable[[float], None]


class TemporaryFolder:
    """A fresh temporary folder, removed with the last reference to this object (or at exit)."""

    def __init__(self, prefix: str) -> None:
        self.path = Path(tempfile.mkdtemp(prefix=prefix))
        weakref.finalize(self, shutil.rmtree, str(self.path), ignore_errors=True)

    @classmethod
    def unless(cls, out_dir: str | Path | None, name: str) -> tuple[Path, TemporaryFolder | None]:
        """`out_dir` if given, else a fresh temporary folder named after `name` (and the object
        that keeps it: whoever holds it holds the folder)."""
        if out_dir is not None:
            return Path(out_dir), None
        tmp = cls(f"fleet-{name}-")
        return tmp.path, tmp


@dataclass
class RunResult:
    """A finished run: its summary, its run directory and the tables in it.

    ``pandas.DataFrame(result.table("jobs"))`` is a data frame of the run's jobs; so for every
    table `table_names` lists (every CSV the run directory holds).
    """

    #: The run directory (a temporary one, removed with this object, when `run` made it).
    out_dir: Path
    #: summary.json's object.
    summary: dict[str, Any]
    #: The scenario that ran (None for a run directory read with `open_run`).
    scenario: Scenario | None = None
    #: Every CSV table of the run directory, by name, read on first use.
    tables: Tables = field(init=False, repr=False)
    _tmp: TemporaryFolder | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.tables = Tables(self.out_dir)

    def __repr__(self) -> str:
        # What a notebook shows for the result: a line, not the whole summary.
        jobs = self.summary.get("jobs") or {}
        name = self.scenario.name if self.scenario is not None else self.out_dir.name
        return (
            f"RunResult({name!r}: {jobs.get('completed')} of {jobs.get('released')} jobs "
            f"completed, tables {', '.join(self.table_names)}; out_dir={str(self.out_dir)!r})"
        )

    @property
    def table_names(self) -> tuple[str, ...]:
        """The tables of the run directory, e.g. ``("caps", "events", "jobs", ...)``."""
        return self.tables.names()

    def table(self, name: str) -> dict[str, list[Any]]:
        """Table `name` (``"jobs"``, ``"events"``, ...) as typed columns ``{column: [value,
        ...]}`` (see `fleet.api.tables`); raises `TableNotFound` listing the tables there are."""
        return self.tables[name]

    def rows(self, name: str) -> list[dict[str, Any]]:
        """Table `name` as one dict per row."""
        return rows_of(self.tables[name])

    def path(self, name: str) -> Path:
        """The file of table `name` (for ``pandas.read_csv`` or a spreadsheet)."""
        return self.tables.path(name)

    @property
    def complete(self) -> bool:
        """False when the run was stopped before its end."""
        return bool(self.summary.get("complete", True))

    @property
    def problems(self) -> list[str]:
        """What makes the run's figures doubtful (broken job accounting, robots that could
        never move); empty for a sound run. `fleet run` exits 1 on any of them."""
        return run_problems(self.summary, self.out_dir)


def run(
    scenario: Scenario | str | Path,
    out_dir: str | Path | None = None,
    *,
    force: bool = False,
    figures: bool = False,
    progress: Progress = False,
    workers: int = 0,
) -> RunResult:
    """Run a scenario and write its run directory, as ``fleet run`` does.

    Parameters
    ----------
    scenario:
        A `Scenario` (`load_scenario`, `scenario_from_dict`, `change`) or a scenario file.
    out_dir:
        The run directory; None: a temporary one, removed when the result is no longer used
        (give a folder to keep the files).
    force:
        Clear an earlier run's files in `out_dir` first (without it such a folder is refused).
    figures:
        Also draw trajectory.png, speed.png and gantt.png.
    progress:
        True: a progress bar on stderr; a callable: called with the simulated seconds done.
        Nothing is printed on stdout either way.
    workers:
        Worker processes hosting the robots' agents (0: all in this process). They start
        afresh and import the main module: a script (not a notebook) that asks for them keeps
        its code under ``if __name__ == "__main__":``.

    Raises
    ------
    ScenarioError
        If the scenario breaks a rule across its fields (`fleet.scenario.check_fleet`).
    InputError
        If `out_dir` is a file or holds files a run did not write, or an earlier run without
        `force`.
    """
    from fleet.api.scenarios import load_scenario
    from fleet.engine import World

    if not isinstance(scenario, Scenario):
        scenario = load_scenario(scenario)
    out, tmp = TemporaryFolder.unless(out_dir, scenario.name)
    if tmp is None:
        fresh_run_dir(out, force, source="fleet.api.run", field="out_dir")
    world = World(scenario, workers=workers)
    count = "{task.completed:>7,.0f} / {task.total:,.0f} s"
    with progress_hook(progress, scenario.duration_s, scenario.name, count, float) as advance:
        summary = simulate(world, out, progress=advance, figures=figures)
    result = RunResult(out, summary, scenario, tmp)
    for problem in result.problems:
        log.warning("%s", problem)
    return result


def open_run(run_dir: str | Path) -> RunResult:
    """A run directory written earlier (by `run`, ``fleet run`` or a sweep's cell), read back.

    Raises
    ------
    InputError
        If `run_dir` holds no summary.json.
    """
    out = Path(run_dir)
    try:
        summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputError(
            str(out), "summary.json", str(out / "summary.json"), "not a run directory: no summary"
        ) from None
    except ValueError as exc:
        raise InputError(str(out), "summary.json", str(exc), "is not valid JSON") from None
    return RunResult(out, summary)


def simulate(
    world: World,
    out: Path,
    *,
    progress: Callable[[float], None] | None = None,
    stop: Callable[[], bool] | None = None,
    figures: bool = False,
) -> dict[str, Any]:
    """Run `world` (`World.run`'s `progress` and `stop`), write its run directory to `out`,
    draw its figures when asked and the run is complete; returns the summary."""
    summary = world.run(progress, stop=stop).summary
    world.write(out)
    if figures and summary["complete"]:
        from fleet.view.figures import save_run_figures

        save_run_figures(out, world.floor)
    return summary


def run_problems(summary: dict[str, Any], out: Path) -> list[str]:
    """Why a finished run's figures cannot be trusted, one sentence each (none: they can)."""
    problems = []
    jobs = summary["jobs"]
    if not jobs["accounted"]:
        problems.append(
            f"job accounting broken: {jobs['released']} released, {jobs['completed']} "
            f"completed, {jobs['failed']} failed, {jobs['in_progress']} in progress "
            f"(see {out / 'events.csv'})"
        )
    for stuck in summary.get("stuck_robots") or ():
        # A robot that could never move makes the run's figures meaningless.
        problems.append(f"robot {stuck['robot']} could never move: {stuck['reason']}")
    return problems


def fresh_run_dir(
    out: Path, force: bool, *, source: str = "command line", field: str = "--out"
) -> None:
    """Make sure `out` holds nothing from an earlier run: refuse it, or with `force` clear the
    run files in it (and nothing else: a folder with other files is never emptied). Errors
    name `source` and `field` (the option or argument that gave `out`)."""
    from fleet.engine.recorder import RUN_FILES
    from fleet.view.figures import GANTT_PNG, SPEED_PNG, TRAJECTORY_PNG
    from fleet.view.kpi_figures import STATES_PNG, WIP_PNG
    from fleet.view.replay import REPLAY_HTML

    if not out.exists():
        return
    if not out.is_dir():
        raise InputError(source, field, str(out), "is a file; a run directory must be a folder")
    found = sorted(out.iterdir())
    if not found:
        return
    names = ", ".join(p.name + ("/" if p.is_dir() else "") for p in found[:6])
    more = f" and {len(found) - 6} more" if len(found) > 6 else ""
    # How the caller asks to clear: the command line's option or the function's argument.
    clear = "--force" if field.startswith("--") else "force=True"
    if not force:
        raise InputError(
            source,
            field,
            str(out),
            f"already holds files ({names}{more}); a run directory is written fresh, so that "
            f"no figure or table of an earlier run survives: give another {field}, or {clear} "
            "to clear the earlier run's files first",
        )
    ours = {*RUN_FILES, TRAJECTORY_PNG, SPEED_PNG, GANTT_PNG, STATES_PNG, WIP_PNG, REPLAY_HTML}
    foreign = [p.name for p in found if p.name not in ours or not p.is_file()]
    if foreign:
        raise InputError(
            source,
            field,
            str(out),
            f"holds files no run writes ({', '.join(foreign[:6])}); {clear} clears only a "
            f"run's own files, so choose another {field}",
        )
    for path in found:
        path.unlink()


@contextmanager
def progress_hook(
    progress: bool | Callable[..., None],
    total: float,
    label: str,
    count: str,
    done: Callable[..., float],
) -> Iterator[Callable[..., None] | None]:
    """What a run or a sweep gets as its progress callback: nothing (`progress` False), the
    caller's callable, or (True) one that draws a bar on stderr, labelled `label`, showing
    `count` (a rich column format) and filled to ``done(*args)`` of `total` on each call."""
    if progress is False:
        yield None
    elif progress is True:
        from rich.console import Console
        from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

        with Progress(
            TextColumn(label),
            BarColumn(),
            TextColumn(count),
            TimeRemainingColumn(),
            console=Console(stderr=True),
            transient=True,
        ) as bar:
            task = bar.add_task(label, total=total)
            yield lambda *args: bar.update(task, completed=done(*args))
    elif callable(progress):
        yield progress
    else:
        raise TypeError(f"progress = {progress!r}: must be True, False or a callable")
