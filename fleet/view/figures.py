"""Figures of a finished run, drawn from its run directory (never by re-running anything).

The two figures of the MAMbot paper, for any scenario, and a Gantt chart of the prints:

- ``trajectory.png``: the floor (speed zones shaded by their limit, machines, stations) with
  each robot's path over it;
- ``speed.png``: each robot's vx and vy against time with the limit in force at every step,
  ``min(zone limit, print cap)``, and its print tasks shaded by kind;
- ``gantt.png``: one row per robot, its print tasks as bars coloured by kind, the time each
  job was in hand and when it was delivered; attempts handed back (``attempts.csv``) hatched
  grey, scrapped, with a cross where the robot handed the job back.

Everything is drawn on `matplotlib.figure.Figure` objects with an Agg canvas, never pyplot: no
display is needed and no global figure state leaks between callers (the CLI, tests, notebooks).
The readers (`load_run`, `load_tracks`, `load_caps`, `load_tasks`, `load_events`, `load_jobs`,
`load_attempts`)
and the drawing helpers (`plot_floor`, `zone_colours`, `KIND_COLOURS`) are public so further
views (`fleet.view.replay`) share them.

Semantics of a step, as in the engine and `fleet.engine.safety`: the velocity ``v[k]`` is held over
``[t_k, t_{k+1})``; the step's zone limit is ``min(v_zone[k], v_zone[k+1])`` (a step that
straddles a zone boundary is bound by both sides) and its print cap is the tightest cap of any
print task overlapping the interval.
"""

from __future__ import annotations

import csv
import json
import math
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import shapely
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_hex
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, PathPatch, Rectangle
from matplotlib.path import Path as MplPath
from shapely.geometry.base import BaseGeometry

from fleet.errors import InputError
from fleet.floor import Floor, load_floor
from fleet.view.kpi_figures import save_kpi_figures

__all__ = [
    "Track",
    "PrintCap",
    "TaskSpan",
    "RunEvent",
    "JobRow",
    "AttemptRow",
    "RunData",
    "SCRAPPED_COLOUR",
    "KIND_COLOURS",
    "TRAJECTORY_PNG",
    "SPEED_PNG",
    "GANTT_PNG",
    "load_tracks",
    "read_csv_rows",
    "csv_number",
    "load_caps",
    "load_tasks",
    "load_events",
    "load_jobs",
    "load_attempts",
    "scrapped_attempts",
    "load_run",
    "step_limits",
    "zone_colours",
    "zone_label",
    "plot_floor",
    "trajectory_figure",
    "speed_figure",
    "gantt_figure",
    "save_run_figures",
]

#: File names `save_run_figures` writes into the run directory.
TRAJECTORY_PNG = "trajectory.png"
SPEED_PNG = "speed.png"
GANTT_PNG = "gantt.png"

#: One colour per print-task kind, shared by every figure that shows print tasks.
KIND_COLOURS: Mapping[str, str] = {
    "contour": "#d62728",
    "infill": "#ff7f0e",
    "support": "#2ca02c",
    "travel": "#7f7f7f",
    "other": "#9467bd",
}

_TRACK_COLUMNS = ("t", "robot", "x", "y", "vx", "vy", "region", "v_zone")
_CAP_COLUMNS = ("robot", "job", "kind", "start_s", "end_s", "cap")
_TASK_COLUMNS = ("robot", "job", "kind", "start_s", "end_s")
_EVENT_COLUMNS = ("t", "event", "job", "robot", "station")
_JOB_COLUMNS = ("id", "robot", "released_s", "started_s", "finished_s", "delivered_s")
_ATTEMPT_COLUMNS = ("job", "attempt", "robot", "assigned_s", "ended_s", "result")
#: Fill of the print of an attempt handed back (scrapped), drawn hatched in its kind's colour;
#: the cross where the job was handed back.
SCRAPPED_COLOUR = "#d9d9d9"
_HANDBACK_COLOUR = "#b00000"
_OBSTACLE_COLOUR = "#6b0f0f"
_CLEARANCE_COLOUR = "#cfcfcf"
_DPI = 150
# Margin (s) so that a task ending on a step boundary does not cap the neighbouring step:
# trajectories.csv rounds times to the millisecond, so half of that.
_EPS_S = 5e-4


# -- what a run directory holds ---------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Track:
    """One robot's samples from ``trajectories.csv``, in time order.

    Attributes
    ----------
    robot:
        Robot id.
    t:
        Sample times (s), shape (n,).
    xy:
        Positions (m), shape (n, 2).
    v:
        Velocities (vx, vy) in m/s, shape (n, 2); ``v[k]`` is held over ``[t[k], t[k+1])``.
    region:
        Index into ``floor.regions`` at each sample, -1 outside the free space.
    v_zone:
        Per-axis zone limit at each sample (m/s; 0 outside the free space).
    """

    robot: str
    t: np.ndarray
    xy: np.ndarray
    v: np.ndarray
    region: np.ndarray
    v_zone: np.ndarray


@dataclass(frozen=True)
class PrintCap:
    """One print task of one robot from ``caps.csv``: the per-axis cap on ``[start_s, end_s)``.

    `cap` is ``inf`` for a task whose kind carries no cap (it is still drawn). `attempt` is the
    attempt at the job it belongs to (``attempts.csv``); `scrapped`: that attempt was handed back.
    """

    robot: str
    job: str
    kind: str
    start_s: float
    end_s: float
    cap: float
    attempt: int = 1
    scrapped: bool = False


@dataclass(frozen=True)
class TaskSpan:
    """One print task of one robot on the clock (absolute seconds), capped or not; in attempt
    `attempt` at the job, `scrapped` when that attempt was handed back (its part scrapped)."""

    robot: str
    job: str
    kind: str
    start_s: float
    end_s: float
    attempt: int = 1
    scrapped: bool = False


@dataclass(frozen=True)
class RunEvent:
    """One row of ``events.csv``: what happened to `job` at `t` (empty strings: not known)."""

    t: float
    event: str
    job: str
    robot: str
    station: str


@dataclass(frozen=True)
class JobRow:
    """One row of ``jobs.csv``; None where the run left the cell empty (not happened)."""

    id: str
    robot: str | None
    released_s: float | None
    started_s: float | None
    finished_s: float | None
    delivered_s: float | None
    part: str | None = None
    due_s: float | None = None
    outcome: str | None = None
    passed: bool | None = None
    predicted_error_mm: float | None = None


@dataclass(frozen=True)
class AttemptRow:
    """One row of ``attempts.csv``: one robot's try at a job and how it ended (`result`:
    delivered, handed_back, failed or unfinished); None where the cell is empty."""

    job: str
    attempt: int
    robot: str
    assigned_s: float
    ended_s: float | None
    result: str
    reason: str | None = None
    started_s: float | None = None
    print_start_s: float | None = None
    printed_s: float = 0.0
    scrapped_s: float = 0.0

    @property
    def scrapped(self) -> bool:
        """Handed back (also the last time, failing the job): its print is scrapped."""
        return self.result in ("handed_back", "failed")


@dataclass(frozen=True, eq=False)
class RunData:
    """Everything the figures need from one run directory.

    `tasks`, `events`, `jobs` and `attempts` are empty when the run directory lacks their
    files.
    """

    run_dir: Path
    summary: dict[str, Any]
    floor: Floor
    tracks: dict[str, Track]
    caps: tuple[PrintCap, ...]
    tasks: tuple[TaskSpan, ...] = ()
    events: tuple[RunEvent, ...] = ()
    jobs: tuple[JobRow, ...] = ()
    attempts: tuple[AttemptRow, ...] = ()

    @property
    def t_end(self) -> float:
        """The run's end (s): ``sim_time_s`` from the summary, else the last sample's time."""
        end = self.summary.get("sim_time_s")
        if isinstance(end, int | float) and math.isfinite(end) and end > 0:
            return float(end)
        return max((float(tr.t[-1]) for tr in self.tracks.values() if len(tr.t)), default=0.0)

    @property
    def title(self) -> str:
        """``scenario: controller + dispatcher`` from the summary (what the figures are titled)."""
        s = self.summary
        plugins = " + ".join(str(s[k]) for k in ("controller", "dispatcher") if s.get(k))
        name = str(s.get("scenario", self.run_dir.name))
        return f"{name}: {plugins}" if plugins else name


def load_tracks(path: Path) -> dict[str, Track]:
    """Read ``trajectories.csv``; one `Track` per robot, robots in id order.

    Raises
    ------
    InputError
        The file is missing, lacks a column, or holds a value that is not a number.
    """
    path = Path(path)
    rows = read_csv_rows(path, _TRACK_COLUMNS)
    by_robot: dict[str, list[list[float]]] = {}
    numeric = ("t", "x", "y", "vx", "vy", "region", "v_zone")
    for line, row in rows:
        values = [csv_number(path, line, col, row[col]) for col in numeric]
        by_robot.setdefault(row["robot"], []).append(values)
    tracks = {}
    for robot in sorted(by_robot):
        a = np.asarray(by_robot[robot], dtype=float)
        a = a[np.argsort(a[:, 0], kind="stable")]
        tracks[robot] = Track(
            robot=robot,
            t=a[:, 0],
            xy=a[:, 1:3],
            v=a[:, 3:5],
            region=a[:, 5].astype(np.int64),
            v_zone=a[:, 6],
        )
    return tracks


def load_caps(
    path: Path, scrapped: Collection[tuple[str, int]] = frozenset()
) -> tuple[PrintCap, ...]:
    """Read ``caps.csv``; an absent file means no print tasks (an empty tuple).

    An empty `cap` cell (or ``inf``) is a task without a cap; a missing or empty ``attempt``
    column is the first attempt. Caps of the ``(job, attempt)`` pairs in `scrapped` (attempts
    handed back, `load_attempts`) are marked scrapped.

    Raises
    ------
    InputError
        A column is missing, a value is not a number, a task ends before it starts, or a cap
        is negative.
    """
    path = Path(path)
    if not path.is_file():
        return ()
    caps = []
    for line, row in read_csv_rows(path, _CAP_COLUMNS):
        start = csv_number(path, line, "start_s", row["start_s"])
        end = csv_number(path, line, "end_s", row["end_s"])
        cap = math.inf if row["cap"].strip() == "" else csv_number(path, line, "cap", row["cap"])
        if not end > start:
            raise InputError(
                str(path), f"line {line}, end_s", row["end_s"], f"must be after start_s {start:g}"
            )
        if not cap >= 0:
            raise InputError(
                str(path), f"line {line}, cap", row["cap"], "must be >= 0 m/s (empty: no cap)"
            )
        n = _attempt(path, line, row)
        caps.append(
            PrintCap(
                row["robot"],
                row["job"],
                row["kind"],
                start,
                end,
                cap,
                n,
                (row["job"], n) in scrapped,
            )
        )
    return tuple(sorted(caps, key=lambda c: (c.robot, c.start_s)))


def load_tasks(
    run_dir: Path, scrapped: Collection[tuple[str, int]] | None = None
) -> tuple[TaskSpan, ...]:
    """Every print task of a run directory, sorted by robot then start.

    Read from ``tasks.csv`` (every task, capped or not) when it holds rows, else from
    ``caps.csv`` (only the tasks of capped kinds: what runs written before ``tasks.csv``
    existed recorded); no file means no tasks. Tasks of the ``(job, attempt)`` pairs in
    `scrapped` are marked scrapped; None: the attempts handed back in ``attempts.csv``.

    Raises
    ------
    InputError
        A column is missing, a time is not a number, or a task ends before it starts.
    """
    run_dir = Path(run_dir)
    if scrapped is None:
        scrapped = scrapped_attempts(load_attempts(run_dir / "attempts.csv"))
    path = run_dir / "tasks.csv"
    tasks = []
    if path.is_file():
        for line, row in read_csv_rows(path, _TASK_COLUMNS):
            start = csv_number(path, line, "start_s", row["start_s"])
            end = csv_number(path, line, "end_s", row["end_s"])
            if not end > start:
                raise InputError(
                    str(path),
                    f"line {line}, end_s",
                    row["end_s"],
                    f"must be after start_s {start:g}",
                )
            n = _attempt(path, line, row)
            tasks.append(
                TaskSpan(
                    row["robot"],
                    row["job"],
                    row["kind"],
                    start,
                    end,
                    n,
                    (row["job"], n) in scrapped,
                )
            )
    if not tasks:
        tasks = [
            TaskSpan(c.robot, c.job, c.kind, c.start_s, c.end_s, c.attempt, c.scrapped)
            for c in load_caps(run_dir / "caps.csv", scrapped)
        ]
    return tuple(sorted(tasks, key=lambda k: (k.robot, k.start_s)))


def load_events(path: Path) -> tuple[RunEvent, ...]:
    """Read ``events.csv`` in time order (stable: same-time events keep the file's order).

    An absent file means no events.

    Raises
    ------
    InputError
        A column is missing or a time is not a number.
    """
    path = Path(path)
    if not path.is_file():
        return ()
    events = [
        RunEvent(
            csv_number(path, line, "t", row["t"]),
            row["event"],
            row["job"],
            row["robot"] or "",
            row["station"] or "",
        )
        for line, row in read_csv_rows(path, _EVENT_COLUMNS)
    ]
    return tuple(sorted(events, key=lambda e: e.t))


def load_jobs(path: Path) -> tuple[JobRow, ...]:
    """Read ``jobs.csv``, in the file's order; an absent file means no jobs.

    Empty cells become None; ``part``, ``due_s``, ``outcome``, ``passed`` and
    ``predicted_error_mm`` may be missing as columns (None then).

    Raises
    ------
    InputError
        A required column is missing, a time is not a number, or ``passed`` is not
        ``true``/``false``/empty.
    """
    path = Path(path)
    if not path.is_file():
        return ()

    def text(row: dict[str, str], column: str) -> str | None:
        return row.get(column) or None

    jobs = []
    for line, row in read_csv_rows(path, _JOB_COLUMNS):
        passed_text = (row.get("passed") or "").strip().lower()
        if passed_text not in ("", "true", "false"):
            raise InputError(
                str(path), f"line {line}, passed", row["passed"], "must be true, false or empty"
            )
        jobs.append(
            JobRow(
                id=row["id"],
                robot=text(row, "robot"),
                released_s=_optional_number(path, line, row, "released_s"),
                started_s=_optional_number(path, line, row, "started_s"),
                finished_s=_optional_number(path, line, row, "finished_s"),
                delivered_s=_optional_number(path, line, row, "delivered_s"),
                part=text(row, "part"),
                due_s=_optional_number(path, line, row, "due_s"),
                outcome=text(row, "outcome"),
                passed=None if passed_text == "" else passed_text == "true",
                predicted_error_mm=_optional_number(path, line, row, "predicted_error_mm"),
            )
        )
    return tuple(jobs)


def _optional_number(path: Path, line: int, row: dict[str, str], column: str) -> float | None:
    """`row`'s `column` as a number, None when the cell is empty or the column missing."""
    text = row.get(column) or ""
    return None if text.strip() == "" else csv_number(path, line, column, text)


def load_attempts(path: Path) -> tuple[AttemptRow, ...]:
    """Read ``attempts.csv``, in the file's order; an absent file means no attempts recorded
    (a run written before attempts were).

    Raises
    ------
    InputError
        A required column is missing, a time is not a number or an attempt not a whole number.
    """
    path = Path(path)
    if not path.is_file():
        return ()

    return tuple(
        AttemptRow(
            job=row["job"],
            attempt=_attempt(path, line, row),
            robot=row["robot"],
            assigned_s=csv_number(path, line, "assigned_s", row["assigned_s"]),
            ended_s=_optional_number(path, line, row, "ended_s"),
            result=row["result"],
            reason=row.get("reason") or None,
            started_s=_optional_number(path, line, row, "started_s"),
            print_start_s=_optional_number(path, line, row, "print_start_s"),
            printed_s=_optional_number(path, line, row, "printed_s") or 0.0,
            scrapped_s=_optional_number(path, line, row, "scrapped_s") or 0.0,
        )
        for line, row in read_csv_rows(path, _ATTEMPT_COLUMNS)
    )


def scrapped_attempts(attempts: Iterable[AttemptRow]) -> frozenset[tuple[str, int]]:
    """The ``(job, attempt)`` pairs of the attempts handed back: their prints are scrapped."""
    return frozenset((a.job, a.attempt) for a in attempts if a.scrapped)


def _attempt(path: Path, line: int, row: dict[str, str]) -> int:
    """The ``attempt`` cell of a row: a whole number >= 1; 1 when missing or empty."""
    text = (row.get("attempt") or "").strip()
    if not text:
        return 1
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise InputError(str(path), f"line {line}, attempt", text, "must be a whole number >= 1")
    return n


def load_run(run_dir: Path, floor: Floor | None = None) -> RunData:
    """Read a run directory written by `fleet run`.

    ``trajectories.csv`` is required; ``caps.csv``, ``tasks.csv``, ``events.csv``,
    ``jobs.csv`` and ``attempts.csv`` are read when present (see `load_caps`, `load_tasks`,
    `load_events`, `load_jobs`, `load_attempts`).

    Parameters
    ----------
    run_dir:
        The run directory.
    floor:
        The run's floor; None loads the map named by ``summary.json``'s ``"map"``.

    Raises
    ------
    InputError
        ``trajectories.csv`` is missing or malformed; `floor` is None and ``summary.json`` is
        missing, malformed or names no map.
    MapError
        The map file named in the summary is missing or invalid.
    """
    run_dir = Path(run_dir)
    tracks = load_tracks(run_dir / "trajectories.csv")
    summary_path = run_dir / "summary.json"
    summary: dict[str, Any] = {}
    if summary_path.is_file():
        try:
            summary = json.loads(summary_path.read_text(encoding="utf-8"))
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(str(summary_path), "(file)", str(exc), "must be valid JSON") from exc
        if not isinstance(summary, dict):
            raise InputError(str(summary_path), "(file)", summary, "must be a JSON object")
    if floor is None:
        if not summary_path.is_file():
            raise InputError(
                str(summary_path),
                "(file)",
                "missing",
                "a run directory written by `fleet run` has summary.json naming the map; "
                "or pass the floor explicitly",
            )
        map_file = summary.get("map")
        if not isinstance(map_file, str) or not map_file:
            raise InputError(
                str(summary_path), "map", map_file, "must be the path of the run's map file"
            )
        floor = load_floor(map_file)
    attempts = load_attempts(run_dir / "attempts.csv")
    scrapped = scrapped_attempts(attempts)
    return RunData(
        run_dir,
        summary,
        floor,
        tracks,
        load_caps(run_dir / "caps.csv", scrapped),
        load_tasks(run_dir, scrapped),
        load_events(run_dir / "events.csv"),
        load_jobs(run_dir / "jobs.csv"),
        attempts,
    )


def read_csv_rows(path: Path, columns: Sequence[str]) -> list[tuple[int, dict[str, str]]]:
    """Rows of a run directory's CSV file as ``(line number, row)``, after checking its header
    has `columns`; `InputError` naming the file when it is missing or lacks a column."""
    if not path.is_file():
        raise InputError(
            str(path),
            "(file)",
            "missing",
            f"a run directory written by `fleet run` has {path.name} with columns "
            + ",".join(columns),
        )
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            header = reader.fieldnames or []
            missing = [c for c in columns if c not in header]
            if missing:
                raise InputError(
                    str(path),
                    "header",
                    ",".join(header),
                    f"lacks {', '.join(missing)}; needs columns {','.join(columns)}",
                )
            # Line numbers as an editor shows them: the header is line 1.
            return [(reader.line_num, row) for row in reader]
    except (UnicodeDecodeError, csv.Error) as exc:
        raise InputError(
            str(path), "(file)", str(exc), f"must be the CSV text `fleet run` writes as {path.name}"
        ) from None


def csv_number(
    path: Path, line: int, column: str, text: str | None, *, finite: bool = False
) -> float:
    """The number in a CSV cell; `InputError` naming file, line, column and text otherwise.

    NaN is always refused; infinities only when `finite` (an infinite cap or zone limit is a
    legitimate "no limit", an infinite position is not).
    """
    try:
        value = float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(str(path), f"line {line}, {column}", text, "must be a number") from None
    if math.isnan(value):
        raise InputError(str(path), f"line {line}, {column}", text, "must be a number, not NaN")
    if finite and math.isinf(value):
        raise InputError(str(path), f"line {line}, {column}", text, "must be a finite number")
    return value


# -- limits -----------------------------------------------------------------------------------
def step_limits(track: Track, caps: Iterable[PrintCap] = ()) -> np.ndarray:
    """The per-axis speed limit in force over each step ``[t[k], t[k+1])`` of `track`.

    ``min(v_zone[k], v_zone[k+1], cap of every task of this robot overlapping the step)``;
    shape (n - 1,) for n samples.
    """
    t = track.t
    if len(t) < 2:
        return np.empty(0)
    limit = np.minimum(track.v_zone[:-1], track.v_zone[1:])
    t0, t1 = t[:-1], t[1:]
    for c in caps:
        if c.robot != track.robot or math.isinf(c.cap):
            continue
        overlaps = (c.start_s < t1 - _EPS_S) & (c.end_s > t0 + _EPS_S)
        limit = np.where(overlaps, np.minimum(limit, c.cap), limit)
    return limit


# -- drawing ----------------------------------------------------------------------------------
def zone_colours(floor: Floor) -> dict[tuple[float, float], str]:
    """The colour (``#rrggbb``) of each speed limit of `floor`'s regions, slowest first.

    The floor's default limit is white; slower (or otherwise different) limits get colours of
    one sequential map, the slowest darkest, stopping short of the red that marks obstacles.
    Every picture of a floor (`plot_floor`, the HTML replay) uses this one scale.
    """
    default = tuple(floor.spec.default_v_max)
    limits = sorted({r.v_max for r in floor.regions}, key=lambda v: (min(v), max(v)))
    shaded = [v for v in limits if v != default]
    cmap = colormaps["YlOrRd"]
    colours = {}
    for limit in limits:
        if limit == default:
            colours[limit] = "#ffffff"
            continue
        rank = shaded.index(limit)
        level = 0.55 - 0.4 * rank / max(1, len(shaded) - 1) if len(shaded) > 1 else 0.4
        colours[limit] = to_hex(cmap(level))
    return colours


def zone_label(limit: tuple[float, float]) -> str:
    """How figures name a zone's per-axis limit: ``"0.4 m/s"`` or ``"0.4 x 0.8 m/s"``."""
    return _limit_label(limit)


def plot_floor(ax: Axes, floor: Floor, *, labels: bool = True) -> list[Any]:
    """Draw `floor` on `ax`: zones shaded by limit, obstacles, boundary, rough areas, stations.

    Regions are grouped by speed limit and merged, so the picture shows zones rather than the
    convex decomposition; the floor's default limit stays white, slower limits get darker
    colours of one sequential map. Sets equal aspect and metre labels.

    Parameters
    ----------
    ax:
        The axes to draw on.
    floor:
        The compiled floor.
    labels:
        Write each station's name next to its marker.

    Returns
    -------
    list
        Legend handles (one per zone limit, obstacles, rough floor and station kind), for the
        caller to place.
    """
    spec = floor.spec
    handles: list[Any] = []
    # Grey under white free space: what shows grey is the clearance band the robot's centre
    # may not enter (the boundary shrunk and the obstacles grown by the footprint radius).
    ax.add_patch(_patch(spec.boundary, facecolor=_CLEARANCE_COLOUR, edgecolor="none", zorder=0))
    ax.add_patch(_patch(floor.free_space, facecolor="white", edgecolor="none", zorder=0.5))

    by_limit: dict[tuple[float, float], list[Any]] = {}
    for r in floor.regions:
        by_limit.setdefault(r.v_max, []).append(r.polygon)
    default = tuple(spec.default_v_max)
    colours = zone_colours(floor)
    for limit in (v for v in colours if v != default):
        colour = colours[limit]
        ax.add_patch(
            _patch(shapely.union_all(by_limit[limit]), facecolor=colour, edgecolor="none", zorder=1)
        )
        handles.append(Patch(facecolor=colour, label=_limit_label(limit)))
    if default in by_limit:
        handles.append(
            Patch(facecolor="white", edgecolor="0.6", label=f"{_limit_label(default)} (default)")
        )

    for area in spec.rough_areas:
        ax.add_patch(
            _patch(area.polygon, facecolor="none", edgecolor="0.45", hatch="///", lw=0, zorder=1.5)
        )
    if spec.rough_areas:
        handles.append(Patch(facecolor="white", edgecolor="0.45", hatch="///", label="rough floor"))
    for obstacle in spec.obstacles:
        ax.add_patch(
            _patch(obstacle.polygon, facecolor=_OBSTACLE_COLOUR, edgecolor="none", zorder=2)
        )
    if spec.obstacles:
        handles.append(Patch(facecolor=_OBSTACLE_COLOUR, label="obstacle"))
    if spec.clearance > 0:
        handles.append(
            Patch(facecolor=_CLEARANCE_COLOUR, label=f"clearance ({spec.clearance:g} m)")
        )
    ax.add_patch(_patch(spec.boundary, facecolor="none", edgecolor="black", lw=1.2, zorder=2))

    markers = {"depot": "s", "delivery": "^", "charger": "P"}
    spare = iter(("D", "v", "p", "h", "*", "<", ">", "d"))
    kinds_seen: set[str] = set()
    for s in spec.stations:
        if s.kind not in markers:  # kinds are free text in map files: one marker each
            markers[s.kind] = next(spare, "o")
        ax.plot(s.x, s.y, markers[s.kind], ms=6, mfc="#1f3b73", mec="white", mew=0.8, zorder=4)
        if labels:
            ax.annotate(
                s.name,
                (s.x, s.y),
                xytext=(4, 4),
                textcoords="offset points",
                fontsize=7,
                color="#1f3b73",
                zorder=4,
            )
        if s.kind not in kinds_seen:
            kinds_seen.add(s.kind)
            handles.append(
                Line2D(
                    [],
                    [],
                    ls="none",
                    marker=markers[s.kind],
                    mfc="#1f3b73",
                    mec="white",
                    label=f"station ({s.kind})",
                )
            )

    xmin, ymin, xmax, ymax = floor.bounds
    pad = 0.02 * max(xmax - xmin, ymax - ymin)
    ax.set_xlim(xmin - pad, xmax + pad)
    ax.set_ylim(ymin - pad, ymax + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    return handles


def trajectory_figure(
    floor: Floor,
    tracks: Mapping[str, Track],
    plans: Mapping[str, Sequence[tuple[float, float, float]]] | None = None,
    *,
    robots: int = 6,
    title: str | None = None,
) -> Figure:
    """The paper's trajectory figure: every robot's path over the zone map.

    Parameters
    ----------
    floor:
        The run's floor.
    tracks:
        Robot id -> `Track` (as `load_tracks` returns).
    plans:
        Optional robot id -> plan samples ``(t, x, y)`` (a controller's latest plan), drawn
        dashed in the robot's colour.
    robots:
        Up to this many robots each get a colour, start/end markers and a legend entry; with
        more, all paths are drawn thin in one colour without per-robot entries.
    title:
        Figure title.

    Returns
    -------
    Figure
        With one axes; each path is a `Line2D` whose gid is ``"path:<robot>"``.
    """
    fig = _figure(_floor_size(floor))
    ax = fig.add_subplot()
    handles = plot_floor(ax, floor)
    few = len(tracks) <= robots
    colours = colormaps["tab10"].colors
    for i, (rid, tr) in enumerate(tracks.items()):
        if len(tr.t) == 0:
            continue
        colour = colours[i % len(colours)] if few else "#1f3b73"
        (line,) = ax.plot(
            tr.xy[:, 0],
            tr.xy[:, 1],
            color=colour,
            lw=1.6 if few else 0.6,
            alpha=1.0 if few else 0.6,
            zorder=3,
            label=rid if few else "_nolegend_",
            gid=f"path:{rid}",
        )
        if few:
            handles.append(line)
        ms = 6 if few else 3
        ax.plot(*tr.xy[0], "o", ms=ms, mfc=colour, mec="black", mew=0.6, zorder=5)
        ax.plot(*tr.xy[-1], "X", ms=ms + 1, mfc=colour, mec="black", mew=0.6, zorder=5)
        plan = (plans or {}).get(rid)
        if plan:
            p = np.asarray(plan, dtype=float).reshape(-1, 3)
            ax.plot(p[:, 1], p[:, 2], ls="--", lw=1.0, color=colour, zorder=3)
    if not few:
        handles.append(Line2D([], [], color="#1f3b73", lw=0.6, label=f"paths ({len(tracks)})"))
    if any(len(tr.t) for tr in tracks.values()):
        handles += [
            Line2D([], [], ls="none", marker="o", mfc="white", mec="black", label="start"),
            Line2D([], [], ls="none", marker="X", mfc="white", mec="black", label="end"),
        ]
    fig.legend(handles=handles, loc="outside right upper", fontsize=8, frameon=False)
    if title:
        fig.suptitle(title)
    return fig


def speed_figure(
    tracks: Mapping[str, Track],
    caps: Sequence[PrintCap] = (),
    *,
    robots: int = 6,
    title: str | None = None,
    t_end: float | None = None,
    attempts: Sequence[AttemptRow] = (),
) -> Figure:
    """The paper's velocity figure: vx, vy and the limit in force against time, per robot.

    One panel per robot (the first `robots` in id order), on a shared time axis from 0 to
    `t_end` (default: the last sample), so the axis ends where the run ended. Velocities are
    drawn as steps (``v[k]`` held over ``[t[k], t[k+1])``); the limit of `step_limits` as a
    ``+/-`` step line; the robot's print tasks are shaded by kind, those of an attempt handed
    back (scrapped) hatched grey; a dotted red line marks each hand-back of one of `attempts`
    (`load_attempts`) by the robot.

    Returns
    -------
    Figure
        One axes per robot shown, in order, each titled with the robot id. Lines carry gids
        ``"vx"``, ``"vy"``, ``"limit+"`` and ``"limit-"`` (the limit lines' y-data holds one
        value per step plus the last one repeated, as `Axes.step` needs), hand-backs
        ``"handed_back:<job>:<attempt>"``; scrapped prints are patches with gid
        ``"scrapped:<job>:<kind>:<attempt>"``.
    """
    shown = list(tracks)[: max(0, robots)]
    fig = _figure((10.0, 1.2 + 2.0 * max(1, len(shown))))
    if not shown:
        ax = fig.add_subplot()
        ax.text(0.5, 0.5, "no trajectory samples", ha="center", va="center")
        ax.set_axis_off()
        return fig
    axes = fig.subplots(len(shown), 1, sharex=True, squeeze=False)[:, 0]
    kinds_seen: dict[str, Patch] = {}
    scrapped_seen = handed_back_seen = False
    for ax, rid in zip(axes, shown, strict=True):
        tr = tracks[rid]
        mine = [c for c in caps if c.robot == rid]
        for c in mine:
            colour = KIND_COLOURS.get(c.kind, KIND_COLOURS["other"])
            if c.scrapped:
                ax.axvspan(
                    c.start_s,
                    c.end_s,
                    facecolor=SCRAPPED_COLOUR,
                    edgecolor=colour,
                    hatch="////",
                    lw=0,
                    alpha=0.6,
                    zorder=0,
                    gid=f"scrapped:{c.job}:{c.kind}:{c.attempt}",
                )
                scrapped_seen = True
                continue
            ax.axvspan(c.start_s, c.end_s, color=colour, alpha=0.15, lw=0, zorder=0)
            if c.kind not in kinds_seen:
                kinds_seen[c.kind] = Patch(facecolor=colour, alpha=0.3, label=f"print: {c.kind}")
        for a in attempts:
            if a.robot == rid and a.scrapped and a.ended_s is not None:
                handed_back_seen = True
                ax.axvline(
                    a.ended_s,
                    color=_HANDBACK_COLOUR,
                    lw=1.0,
                    ls=":",
                    zorder=3,
                    gid=f"handed_back:{a.job}:{a.attempt}",
                )
        if len(tr.t):
            ax.step(tr.t, tr.v[:, 0], where="post", lw=1.0, color="#1f77b4", gid="vx")
            ax.step(tr.t, tr.v[:, 1], where="post", lw=1.0, color="#ff7f0e", gid="vy")
        limit = step_limits(tr, mine)
        if len(limit):
            held = np.append(limit, limit[-1])
            for sign, gid in ((1.0, "limit+"), (-1.0, "limit-")):
                ax.step(tr.t, sign * held, where="post", color="black", lw=0.9, ls="--", gid=gid)
        ax.axhline(0.0, color="0.8", lw=0.5, zorder=0)
        ax.set_title(rid, loc="left", fontsize=9)
        ax.set_ylabel("v (m/s)")
    axes[-1].set_xlabel("t (s)")
    if t_end is None:
        t_end = max((float(tracks[r].t[-1]) for r in shown if len(tracks[r].t)), default=0.0)
    # Without limits matplotlib pads the axis, and a print cap that outlasts the run (its task
    # was cut off by the end) would stretch it further.
    axes[-1].set_xlim(0.0, max(t_end, 1e-9))
    handles: list[Any] = [
        Line2D([], [], color="#1f77b4", lw=1.0, label="vx"),
        Line2D([], [], color="#ff7f0e", lw=1.0, label="vy"),
        Line2D([], [], color="black", lw=0.9, ls="--", label="limit (zone, print cap)"),
        *kinds_seen.values(),
        *_scrapped_handles(scrapped_seen, handed_back_seen, line=True),
    ]
    fig.legend(handles=handles, loc="outside lower center", ncols=len(handles), fontsize=8)
    heading = title or ""
    if len(tracks) > len(shown):
        heading = f"{heading}\n" if heading else ""
        heading += f"first {len(shown)} of {len(tracks)} robots"
    if heading:
        fig.suptitle(heading)
    return fig


def gantt_figure(
    tasks: Sequence[TaskSpan],
    events: Sequence[RunEvent] = (),
    jobs: Sequence[JobRow] = (),
    *,
    robots: Sequence[str] | None = None,
    t_end: float | None = None,
    title: str | None = None,
    attempts: Sequence[AttemptRow] = (),
) -> Figure:
    """A Gantt chart of the prints: one row per robot, its print tasks as bars over time.

    Each task is a bar coloured by `KIND_COLOURS`; behind the bars a thin grey band shows
    each job in hand from its assignment to its delivery (each of `attempts` in its robot's
    row, to its end; without attempts, from the ``assigned`` and ``delivered`` events); to
    the end when not delivered; a black triangle marks each delivery. The print of an attempt
    handed back is scrapped: its tasks are hatched grey bars, and a red cross marks the
    hand-back. A job's id is written over each attempt's print (first task's start to last
    task's end) when it fits there, in red when ``jobs.csv`` judged the part anything but good.

    Parameters
    ----------
    tasks:
        The print tasks (`load_tasks`).
    events:
        The run's events (`load_events`): assignments and deliveries.
    jobs:
        The run's jobs (`load_jobs`): outcomes for the label colour.
    attempts:
        The run's attempts at jobs (`load_attempts`): who held each job when, and the
        hand-backs; empty: the jobs in hand are read from `events`.
    robots:
        The rows, top to bottom; None: every robot named in `tasks` or `events`, in id order.
        Tasks of robots not listed are left out.
    t_end:
        Right end of the time axis (s); None: the last time in the data.
    title:
        Figure title.

    Returns
    -------
    Figure
        One axes, robot ids as y tick labels (row i at y = i, the first robot on top). Task bars
        are `Rectangle` patches with gid ``"task:<robot>:<job>:<kind>"`` (scrapped ones
        ``"scrapped:<robot>:<job>:<kind>:<attempt>"``), job bands ``"held:<job>"`` (a later
        attempt's ``"held:<job>:<attempt>"``), job labels are texts with gid ``"label:<job>"``
        (``"label:<job>:<attempt>"``; hidden when they do not fit), deliveries one `Line2D`
        with gid ``"delivered"`` and hand-backs one with gid ``"handed_back"`` (x: times, y:
        rows).
    """
    if robots is None:
        named = {t.robot for t in tasks} | {e.robot for e in events if e.robot}
        robots = sorted(named)
    rows = {rid: i for i, rid in enumerate(robots)}
    fig = _figure((10.0, 1.6 + 0.45 * max(2, len(rows))))
    ax = fig.add_subplot()
    ax.set_ylim(len(rows) - 0.5, -0.5)  # first robot on top
    ax.set_yticks(range(len(rows)), list(rows))
    ax.set_xlabel("t (s)")
    if title:
        fig.suptitle(title)

    shown = [t for t in tasks if t.robot in rows]
    # (robot, start, end or None, gid suffix) of each spell a job was in hand.
    held: list[tuple[str, float, float | None, str]] = []
    delivered: dict[str, tuple[str, float]] = {}
    handed_back: list[tuple[str, float]] = []
    if attempts:
        for a in attempts:
            if a.robot not in rows:
                continue
            held.append((a.robot, a.assigned_s, a.ended_s, _suffix(a.job, a.attempt)))
            if a.result == "delivered" and a.ended_s is not None:
                delivered[a.job] = (a.robot, a.ended_s)
            elif a.scrapped and a.ended_s is not None:
                handed_back.append((a.robot, a.ended_s))
    else:
        held_from: dict[str, tuple[str, float]] = {}
        for e in events:
            if e.event == "assigned" and e.robot in rows:
                held_from[e.job] = (e.robot, e.t)
            elif e.event == "delivered":
                robot = e.robot or held_from.get(e.job, ("", 0.0))[0]
                if robot in rows:
                    delivered[e.job] = (robot, e.t)
        held = [
            (robot, start, delivered[job][1] if job in delivered else None, job)
            for job, (robot, start) in held_from.items()
        ]
    times = [t.end_s for t in shown] + [e.t for e in events]
    end = t_end if t_end is not None else max(times, default=1.0)

    handles: list[Any] = []
    for robot, start, stop, suffix in held:
        stop = end if stop is None else stop
        ax.add_patch(
            Rectangle(
                (start, rows[robot] - 0.12),
                max(stop - start, 0.0),
                0.24,
                facecolor="0.8",
                edgecolor="none",
                zorder=1,
                gid=f"held:{suffix}",
            )
        )
    if held:
        handles.append(Patch(facecolor="0.8", label="job in hand (assigned to delivered)"))

    kinds_seen: set[str] = set()
    for t in shown:
        colour = KIND_COLOURS.get(t.kind, KIND_COLOURS["other"])
        if t.scrapped:
            # Printed, then scrapped with the hand-back: grey, hatched in its kind's colour.
            ax.add_patch(
                Rectangle(
                    (t.start_s, rows[t.robot] - 0.35),
                    t.end_s - t.start_s,
                    0.7,
                    facecolor=SCRAPPED_COLOUR,
                    edgecolor=colour,
                    hatch="////",
                    lw=0.4,
                    zorder=2,
                    gid=f"scrapped:{t.robot}:{t.job}:{t.kind}:{t.attempt}",
                )
            )
            continue
        kinds_seen.add(t.kind if t.kind in KIND_COLOURS else "other")
        ax.add_patch(
            Rectangle(
                (t.start_s, rows[t.robot] - 0.35),
                t.end_s - t.start_s,
                0.7,
                facecolor=colour,
                edgecolor="white",
                lw=0.4,
                zorder=2,
                gid=f"task:{t.robot}:{t.job}:{t.kind}",
            )
        )
    handles += [
        Patch(facecolor=colour, label=f"print: {kind}")
        for kind, colour in KIND_COLOURS.items()
        if kind in kinds_seen
    ]
    handles += _scrapped_handles(any(t.scrapped for t in shown), bool(handed_back))

    bad = {j.id for j in jobs if j.outcome not in (None, "good")}
    spans: dict[tuple[str, str, int], tuple[float, float]] = {}
    for t in shown:
        a, b = spans.get((t.robot, t.job, t.attempt), (t.start_s, t.end_s))
        spans[(t.robot, t.job, t.attempt)] = (min(a, t.start_s), max(b, t.end_s))
    labels = []
    for (robot, job, attempt), (a, b) in spans.items():
        text = ax.text(
            (a + b) / 2,
            rows[robot],
            job,
            ha="center",
            va="center",
            fontsize=7,
            color="#b00000" if job in bad else "black",
            zorder=4,
            gid=f"label:{_suffix(job, attempt)}",
            clip_on=True,
            bbox={"boxstyle": "round,pad=0.15", "fc": "white", "ec": "none", "alpha": 0.7},
        )
        labels.append((text, a, b))

    if delivered:
        xs = [t for _, t in delivered.values()]
        ys = [rows[r] - 0.42 for r, _ in delivered.values()]
        order = np.argsort(xs, kind="stable")
        ax.plot(
            np.asarray(xs)[order],
            np.asarray(ys)[order],
            ls="none",
            marker="v",
            ms=6,
            mfc="black",
            mec="white",
            mew=0.5,
            zorder=5,
            gid="delivered",
        )
        handles.append(
            Line2D([], [], ls="none", marker="v", mfc="black", mec="white", label="delivered")
        )
    if handed_back:
        handed_back.sort(key=lambda p: p[1])
        ax.plot(
            [t for _, t in handed_back],
            [rows[r] for r, _ in handed_back],
            ls="none",
            marker="X",
            ms=7,
            mfc=_HANDBACK_COLOUR,
            mec="white",
            mew=0.5,
            zorder=5,
            gid="handed_back",
        )
    ax.set_xlim(0.0, max(end, 1e-9))
    ax.grid(axis="x", color="0.9", lw=0.5, zorder=0)
    ax.set_axisbelow(True)
    if not shown and not held:
        ax.text(0.5, 0.5, "no print tasks", transform=ax.transAxes, ha="center", va="center")
    if handles:
        fig.legend(handles=handles, loc="outside lower center", ncols=len(handles), fontsize=8)

    if labels:
        # Whether a label fits is a question of pixels: lay the figure out, then measure.
        fig.draw_without_rendering()
        renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
        for text, a, b in labels:
            x0, x1 = ax.transData.transform([(a, 0.0), (b, 0.0)])[:, 0]
            text.set_visible(text.get_window_extent(renderer).width + 4.0 <= x1 - x0)
    return fig


def save_run_figures(run_dir: Path, floor: Floor | None = None, *, robots: int = 6) -> list[Path]:
    """Write ``trajectory.png``, ``speed.png``, ``gantt.png`` (and ``states.png``, ``wip.png``)
    into `run_dir`.

    Everything is read from the files there; nothing is re-run.

    Parameters
    ----------
    run_dir:
        A run directory written by `fleet run` (``trajectories.csv`` required; ``caps.csv``,
        ``tasks.csv``, ``events.csv``, ``jobs.csv``, ``attempts.csv`` optional;
        ``summary.json`` required when `floor` is None).
    floor:
        The run's floor; None loads the map named in ``summary.json``.
    robots:
        At most this many robots get their own colour and their own speed panel (the Gantt
        chart has a row for every robot).

    Returns
    -------
    list of Path
        The PNG files: trajectory, speed, Gantt, then ``states.png`` and ``wip.png`` when the
        run directory has ``states.csv`` and ``wip.csv`` (`fleet.view.kpi_figures`).

    Raises
    ------
    InputError
        See `load_run`.
    """
    run = load_run(Path(run_dir), floor)
    out = [run.run_dir / TRAJECTORY_PNG, run.run_dir / SPEED_PNG, run.run_dir / GANTT_PNG]
    figures = [
        trajectory_figure(run.floor, run.tracks, robots=robots, title=run.title),
        speed_figure(
            run.tracks,
            run.caps,
            robots=robots,
            title=run.title,
            t_end=run.t_end,
            attempts=run.attempts,
        ),
        gantt_figure(
            run.tasks,
            run.events,
            run.jobs,
            robots=list(run.tracks),
            t_end=run.t_end,
            title=run.title,
            attempts=run.attempts,
        ),
    ]
    for fig, path in zip(figures, out, strict=True):
        fig.savefig(path, dpi=_DPI)
    # states.png and wip.png, when the run directory has their CSVs.
    return out + save_kpi_figures(run.run_dir, title=run.title, t_end=run.t_end)


# -- helpers ----------------------------------------------------------------------------------
def _suffix(job: str, attempt: int) -> str:
    """A gid's job part: the job for its first attempt, ``job:attempt`` for later ones."""
    return job if attempt == 1 else f"{job}:{attempt}"


def _scrapped_handles(scrapped: bool, handed_back: bool, *, line: bool = False) -> list[Any]:
    """Legend entries for scrapped prints and hand-backs, when the figure shows any."""
    out: list[Any] = []
    if scrapped:
        out.append(
            Patch(facecolor=SCRAPPED_COLOUR, edgecolor="0.4", hatch="////", label="print scrapped")
        )
    if handed_back:
        style = (
            {"color": _HANDBACK_COLOUR, "ls": ":"}
            if line
            else {"ls": "none", "marker": "X", "mfc": _HANDBACK_COLOUR, "mec": "white"}
        )
        out.append(Line2D([], [], label="handed back", **style))
    return out


def _figure(size: tuple[float, float]) -> Figure:
    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)  # attaches itself: savefig renders with Agg, no pyplot involved
    return fig


def _floor_size(floor: Floor) -> tuple[float, float]:
    """Figure size (inches): the floor at its own aspect, axis labels, a legend column right."""
    xmin, ymin, xmax, ymax = floor.bounds
    ratio = (ymax - ymin) / max(xmax - xmin, 1e-9)
    width = 8.0
    height = width * ratio
    if height > 8.0:  # a tall floor: fit the height, narrow the drawing
        width, height = 8.0 / ratio, 8.0
    return (max(width, 3.0) + 3.5, max(height, 2.5) + 1.2)


def _limit_label(v: tuple[float, float]) -> str:
    return f"{v[0]:g} m/s" if v[0] == v[1] else f"{v[0]:g} x {v[1]:g} m/s"


def _patch(geom: BaseGeometry, **kwargs: Any) -> PathPatch:
    """A patch for a (multi)polygon with holes; rings oriented so holes stay unfilled."""
    vertices: list[np.ndarray] = []
    codes: list[np.ndarray] = []
    for poly in shapely.get_parts(geom):
        if poly.geom_type != "Polygon" or poly.is_empty:
            continue  # a union can leave slivers of lower dimension: nothing to fill
        poly = shapely.orient_polygons(poly)
        for ring in (poly.exterior, *poly.interiors):
            xy = np.asarray(ring.coords)
            c = np.full(len(xy), MplPath.LINETO, dtype=np.uint8)
            c[0], c[-1] = MplPath.MOVETO, MplPath.CLOSEPOLY
            vertices.append(xy)
            codes.append(c)
    if not vertices:
        return PathPatch(MplPath(np.empty((0, 2))), **kwargs)
    return PathPatch(MplPath(np.concatenate(vertices), np.concatenate(codes)), **kwargs)
