"""Parameter sweeps: a grid over scenario values, replicated over seeds, run in parallel.

A study file (TOML) names a base scenario, the seeds, and a ``[grid]`` whose keys are axes::

    [study]
    name = "throughput"                      # default: the file's stem
    scenario = "../scenarios/default.toml"   # base scenario, relative to the study file
    seeds = [1, 2, 3]                        # or an int n: seeds 1..n
    duration_s = 3600                        # optional: overrides scenario.duration_s

    [grid]
    robots = [2, 4]                          # robots.count
    rate_per_h = [6, 12]                     # jobs.rate_per_h
    map = ["../maps/shop_floor.toml"]        # scenario.map, relative to the STUDY file
    dispatcher = ["greedy"]                  # [dispatcher]: a plugin name or a table
    charging = ["threshold", "opportunity"]  # [charging] (with [battery]): the same
    controller = [                           # [controller]: a plugin name or a table
        "follower",                          #   (label: the name)
        { label = "fixed 0.2", name = "fixed_speed", options = { speed = 0.2 } },
    ]
    "quality.tolerance_mm" = [0.05, 0.08]    # any other key: a dotted path into the scenario

A cell's scenario is the base file's tables with, in this order, the study's ``duration_s``, each
axis's value and the seed written in. Plugin axes replace the whole ``[controller]``,
``[dispatcher]`` or ``[charging]`` table (the base's options are for the base's plugin); dotted
axes write their value as is, so relative paths in them resolve against the base scenario's
folder.

A *cell* is one point of the grid with one seed. `load_study` builds and validates every cell's
scenario before anything runs, so a bad value fails at once with a `StudyError` naming the study
file, the field (``grid.robots[1]``) and the value. `run_study` runs the cells on a process pool
(or any `concurrent.futures.Executor`, e.g. a Dask cluster's through `dask_executor`), writes
each cell's run directory under ``OUT/cells/<cell id>/`` and keeps ``OUT/results.csv`` current.

Cell ids are content addresses: the first 12 hex digits of a sha256 over the cell's fully
resolved scenario tables (seed included) with every referenced file (map, G-code parts, quality
calibration) replaced by the sha256 of its contents. Resuming therefore reuses a finished cell
exactly when the same scenario would run again: editing the base scenario, a grid value or a map
file gives new ids (new runs), while adding seeds or axis values leaves the finished cells'
ids, and so their results, as they were. The id does not cover the simulator's own code: after
upgrading mambot-fleet, sweep into a fresh directory.
"""

from __future__ import annotations

import copy
import csv
import enum
import hashlib
import itertools
import json
import math
import multiprocessing
import os
import shutil
import signal
import threading
import time
import tomllib
import traceback
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fleet.errors import FleetError, InputError, ScenarioError

if TYPE_CHECKING:
    from fleet.scenario import Scenario

__all__ = [
    "StudyError",
    "CellStatus",
    "AxisValue",
    "Axis",
    "Cell",
    "Study",
    "CellSpec",
    "SweepResult",
    "SweepInterrupted",
    "KPI_COLUMNS",
    "kpi_values",
    "load_study",
    "parse_study",
    "run_study",
    "run_cell",
    "dask_executor",
]

#: Grid keys with a meaning of their own; any other key is a dotted path into the scenario.
NAMED_AXES: dict[str, tuple[str, ...]] = {
    "robots": ("robots", "count"),
    "rate_per_h": ("jobs", "rate_per_h"),
    "map": ("scenario", "map"),
    "dispatcher": ("dispatcher",),
    "controller": ("controller",),
    "charging": ("charging",),
}

#: Results-table columns taken from each cell's summary.json, in order, with their place in it.
KPI_COLUMNS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("jobs_released", ("jobs", "released")),
    ("jobs_completed", ("jobs", "completed")),
    ("jobs_good", ("jobs", "good")),
    ("jobs_defective", ("jobs", "defective")),
    ("jobs_late", ("jobs", "late")),
    ("throughput_per_h", ("throughput_per_h",)),
    ("throughput_good_per_h", ("throughput_good_per_h",)),
    ("mean_lead_time_s", ("mean_lead_time_s",)),
    ("distance_m", ("distance_m",)),
    ("violations_obstacle", ("violations", "obstacle")),
    ("violations_speed_zone", ("violations", "speed_zone")),
    ("violations_print_speed", ("violations", "print_speed")),
    ("violations_collision", ("violations", "collision")),
    ("solver_median_ms", ("solver", "median_ms")),
    ("solver_fallbacks", ("solver", "fallbacks")),
    ("availability", ("breakdowns", "availability")),
    ("breakdowns", ("breakdowns", "breakdowns")),
    ("handed_back_breakdown", ("breakdowns", "jobs_handed_back")),
    ("handbacks", ("handbacks", "count")),
    ("scrapped_print_s", ("handbacks", "scrapped_print_s")),
    ("deadlocks", ("deadlocks",)),
    # Only with a [battery] table (empty otherwise).
    ("charging_share", ("battery", "charging_share")),
    ("min_charge_share", ("battery", "min_charge_share")),
    ("stranded", ("battery", "stranded")),
    ("digest", ("digest",)),
)

#: Columns before the axis columns, and between them and the KPI columns.
_LEAD_COLUMNS = ("cell", "index", "seed")
_STATUS_COLUMNS = ("status", "error", "wall_s", "run_dir")


class StudyError(InputError):
    """A study file is malformed, or one of its cells would not be a valid scenario."""


class CellStatus(enum.StrEnum):
    """How a cell's run ended (records and results.csv hold the value)."""

    #: The run finished and its run directory was written.
    OK = "ok"
    #: Something raised while building, running or recording the cell (see its ``error.txt``).
    FAILED = "failed"


@dataclass(frozen=True)
class AxisValue:
    """One value of a grid axis: its label (the results-table entry) and what is written."""

    label: str
    #: What goes into the scenario's tables at the axis's target path.
    value: Any


@dataclass(frozen=True)
class Axis:
    """One ``[grid]`` key: its name (also its results column), target path and values."""

    name: str
    #: Where in the scenario's TOML tables the values are written, e.g. ``("robots", "count")``.
    target: tuple[str, ...]
    values: tuple[AxisValue, ...]


@dataclass(frozen=True)
class Cell:
    """One grid point with one seed: its resolved scenario tables and content-addressed id."""

    index: int
    id: str
    seed: int
    #: Axis name -> label of this cell's value, in grid order.
    params: dict[str, str]
    #: The base scenario's tables with the study's and this cell's values written in.
    raw: dict[str, Any]


@dataclass(frozen=True)
class Study:
    """A validated study: the base scenario, the seeds, the axes and every cell.

    Cells are in grid order: the first axis varies slowest, the seed fastest.
    """

    name: str
    file: Path
    scenario: Path
    seeds: tuple[int, ...]
    duration_s: float | None
    axes: tuple[Axis, ...]
    cells: tuple[Cell, ...]

    @property
    def columns(self) -> tuple[str, ...]:
        """The results table's columns, in order."""
        return (
            _LEAD_COLUMNS
            + tuple(a.name for a in self.axes)
            + _STATUS_COLUMNS
            + tuple(name for name, _ in KPI_COLUMNS)
        )

    def spec(self, cell: Cell, out_dir: str | Path) -> CellSpec:
        """What a worker needs to run `cell` into ``out_dir/cells/<id>/`` (all picklable)."""
        out = Path(out_dir).resolve()
        return CellSpec(
            cell=cell.id,
            index=cell.index,
            seed=cell.seed,
            params=dict(cell.params),
            raw=copy.deepcopy(cell.raw),
            base=str(self.scenario),
            source=f"{self.file} cell {cell.id}",
            run_dir=str(out / "cells" / cell.id),
        )


@dataclass(frozen=True)
class CellSpec:
    """Everything `run_cell` needs, in plain picklable values."""

    cell: str
    index: int
    seed: int
    params: dict[str, str]
    #: The scenario's TOML tables, validated as if read from `base`.
    raw: dict[str, Any]
    base: str
    #: How errors and the summary name this cell's scenario.
    source: str
    #: The cell's run directory (absolute).
    run_dir: str


@dataclass
class SweepResult:
    """What `run_study` did.

    `ok` + `failed` is the number of cells; `skipped` counts the cells not run this time
    because a finished record was reused (and, with ``retry_failed=False``, failed ones kept).
    """

    out_dir: Path
    #: One record per cell in cell order (the dicts of ``cell.json``, plus ``skipped``).
    records: list[dict[str, Any]]
    ok: int
    failed: int
    skipped: int
    #: results.csv, then results.parquet when pyarrow is installed.
    results_paths: tuple[Path, ...] = field(default_factory=tuple)

    #: False when the sweep was interrupted before every cell had a record.
    complete: bool = True

    @property
    def results_path(self) -> Path:
        """The CSV results table."""
        return self.results_paths[0]


class SweepInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped `run_study`; `result` holds the cells finished until then.

    A KeyboardInterrupt still (whoever does not catch this stops as Ctrl-C always stops), with
    what was saved: results.csv lists the finished cells, study.json says ``"complete": false``,
    and running the sweep again runs only the cells without a record.
    """

    def __init__(self, result: SweepResult) -> None:
        super().__init__(f"sweep interrupted: {len(result.records)} cells have a record")
        self.result = result


# -- loading ------------------------------------------------------------------------------------
def load_study(path: str | Path) -> Study:
    """Read a study file and validate every cell's scenario before anything runs.

    Parameters
    ----------
    path:
        The study TOML; its ``scenario`` and ``map`` values are relative to its folder.

    Returns
    -------
    Study
        With one `Cell` per grid point and seed, each already validated by
        `fleet.scenario.parse_scenario` and its plugins known to be registered.

    Raises
    ------
    StudyError
        If the file cannot be read, has an unknown key, an empty or duplicate-labelled axis, a
        value its scenario field rejects, or names a plugin nobody registered. The message
        names the study file, the field (e.g. ``grid.robots[1]``) and the value.
    """
    path = Path(path)
    src = str(path)
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise StudyError(src, "(file)", src, "no such study file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise StudyError(src, "(file)", src, f"cannot read the study file: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise StudyError(src, "(syntax)", str(exc), "the file must be valid TOML") from None
    return parse_study(raw, path)


def parse_study(raw: dict[str, Any], path: Path, *, base_scenario: Scenario | None = None) -> Study:
    """Validate a study's tables `raw` as if read from the file `path` (`load_study`).

    With `base_scenario` (one that keeps the tables it was read from, as `fleet.api`'s do), its
    tables are the base and ``[study] scenario`` must be left out: how `fleet.api.sweep` sweeps
    a scenario made in code. Errors name `path`.
    """
    from fleet.scenario import parse_scenario

    src = str(path)
    _no_unknown(src, "", raw, ("study", "grid"))
    st = raw.get("study", {} if base_scenario is not None else None)
    if not isinstance(st, dict):
        raise StudyError(src, "study", st, "a [study] table with at least `scenario` is required")
    _no_unknown(src, "study.", st, ("name", "scenario", "seeds", "duration_s"))
    name = st.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise StudyError(src, "study.name", name, "must be a non-empty string")
    base_value = st.get("scenario")
    if base_scenario is not None:
        if base_value is not None or not base_scenario.tables or base_scenario.origin is None:
            why = "a study of a scenario in code takes no scenario file"
            if base_value is None:
                why = "the scenario has no tables to sweep (load it, or build it from a dict)"
            raise StudyError(src, "study.scenario", base_value, why)
        base_value = base_scenario.source
        base = base_scenario.origin.resolve()
        base_raw = copy.deepcopy(dict(base_scenario.tables))
    else:
        base, base_raw = _read_base(src, path, base_value)
    seeds = _seeds(src, st.get("seeds", 1))
    duration = st.get("duration_s")
    if duration is not None and not _is_positive(duration):
        raise StudyError(src, "study.duration_s", duration, "must be a positive number")

    grid = raw.get("grid", {})
    if not isinstance(grid, dict):
        raise StudyError(src, "grid", grid, "must be a table of axes: key = [values]")
    axes = tuple(_axis(src, path, key, values, base_raw) for key, values in grid.items())
    _no_overlap(src, axes, grid)
    available = _plugins()

    def resolved(seed: int, picks: tuple[tuple[Axis, AxisValue], ...]) -> dict[str, Any]:
        out = copy.deepcopy(base_raw)
        if duration is not None:
            _put(out, ("scenario", "duration_s"), duration)
        for axis, value in picks:
            _put(out, axis.target, copy.deepcopy(value.value))
        _put(out, ("scenario", "seed"), seed)
        return out

    # The base alone first, then each value on its own, so an error names what caused it.
    try:
        parse_scenario(resolved(seeds[0], ()), base, source=str(base))
    except ScenarioError as exc:
        raise StudyError(src, "study.scenario", base_value, _scenario_rule(exc)) from None
    for axis in axes:
        kinds = [axis.target[0]] if axis.target[0] in available else []
        for i, value in enumerate(axis.values):
            where = f"{_grid_field(axis.name)}[{i}]"
            try:
                sc = parse_scenario(resolved(seeds[0], ((axis, value),)), base, source=str(base))
            except ScenarioError as exc:
                raise StudyError(src, where, grid[axis.name][i], _scenario_rule(exc)) from None
            _check_plugins(src, where, grid[axis.name][i], sc, available, kinds)

    cells: list[Cell] = []
    by_id: dict[str, Cell] = {}
    digests: dict[Path, str] = {}
    for picks in itertools.product(*([(a, v) for v in a.values] for a in axes)):
        params = {axis.name: value.label for axis, value in picks}
        for seed in seeds:
            cell_raw = resolved(seed, picks)
            try:
                sc = parse_scenario(cell_raw, base, source=f"{src} cell {len(cells)}")
            except ScenarioError as exc:  # values that are fine alone but not together
                raise StudyError(
                    src, "grid", params, f"this combination fails: {_scenario_rule(exc)}"
                ) from None
            # Every axis value passed on its own, so a plugin unknown here is the base's.
            _check_plugins(src, "study.scenario", base_value, sc, available, list(available))
            cell_id = _cell_id(cell_raw, sc, digests)
            if cell_id in by_id:
                raise StudyError(
                    src,
                    "grid",
                    params,
                    f"gives the same scenario as {by_id[cell_id].params} (seed {seed}); "
                    "remove one of the values",
                )
            cell = Cell(len(cells), cell_id, seed, params, cell_raw)
            by_id[cell_id] = cell
            cells.append(cell)
    return Study(
        name=name,
        file=path,
        scenario=base,
        seeds=seeds,
        duration_s=None if duration is None else float(duration),
        axes=axes,
        cells=tuple(cells),
    )


def _read_base(src: str, path: Path, base_value: Any) -> tuple[Path, dict[str, Any]]:
    """The base scenario file ``[study] scenario`` names (relative to the study) and its tables."""
    if not isinstance(base_value, str):
        raise StudyError(
            src, "study.scenario", base_value, "is required: the base scenario file (a string)"
        )
    base = (path.parent / base_value).resolve()
    try:
        base_raw = tomllib.loads(base.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise StudyError(src, "study.scenario", base_value, f"no such file ({base})") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise StudyError(
            src, "study.scenario", base_value, f"cannot read the scenario: {exc}"
        ) from None
    except tomllib.TOMLDecodeError as exc:
        raise StudyError(
            src, "study.scenario", base_value, f"the scenario is not valid TOML: {exc}"
        ) from None
    return base, base_raw


def _no_unknown(src: str, prefix: str, table: dict[str, Any], allowed: tuple[str, ...]) -> None:
    for key in table:
        if key not in allowed:
            raise StudyError(
                src, prefix + key, table[key], f"unknown key (allowed here: {', '.join(allowed)})"
            )


def _seeds(src: str, value: Any) -> tuple[int, ...]:
    if _is_int(value):
        if value < 1:
            raise StudyError(src, "study.seeds", value, "a count of seeds must be at least 1")
        return tuple(range(1, value + 1))
    if not isinstance(value, list) or not value:
        raise StudyError(
            src, "study.seeds", value, "must be a non-empty list of seeds, or a count n (1..n)"
        )
    for i, seed in enumerate(value):
        if not _is_int(seed) or seed < 0:
            raise StudyError(src, f"study.seeds[{i}]", seed, "must be a whole number >= 0")
        if seed in value[:i]:
            raise StudyError(src, f"study.seeds[{i}]", seed, "is listed twice")
    return tuple(value)


def _axis(src: str, study: Path, key: str, values: Any, base_raw: dict[str, Any]) -> Axis:
    where = _grid_field(key)
    if not isinstance(values, list):
        raise StudyError(src, where, values, "must be a list of values, e.g. [1, 2]")
    if not values:
        raise StudyError(src, where, values, "needs at least one value")
    target = NAMED_AXES.get(key)
    if target is None:
        target = tuple(key.split("."))
        if any(not part for part in target):
            raise StudyError(src, where, key, "is not a dotted path like 'jobs.due_in_s'")
        if target == ("scenario", "seed"):
            raise StudyError(src, where, values, "seeds are set by [study] seeds")
        if target == ("scenario", "map"):
            raise StudyError(src, where, values, "use the `map` axis (relative to the study)")
    if key == "robots" and isinstance(base_raw.get("robots"), list):
        raise StudyError(
            src,
            where,
            values,
            f"the base scenario defines {len(base_raw['robots'])} [[robots]] groups and this "
            "axis needs one [robots] table; set each group's count in the scenario file",
        )
    out: list[AxisValue] = []
    for i, value in enumerate(values):
        at = f"{where}[{i}]"
        if key in ("controller", "dispatcher", "charging"):
            item = _plugin_value(src, at, value)
        elif key == "map":
            if not isinstance(value, str):
                raise StudyError(src, at, value, "must be a map file name (string)")
            # Written absolute: parse_scenario resolves against the base scenario's folder.
            item = AxisValue(value, str((study.parent / value).resolve()))
        elif isinstance(value, dict | list):
            item = AxisValue(json.dumps(value, sort_keys=True, default=str), value)
        else:
            item = AxisValue(str(value), value)
        for j, other in enumerate(out):
            if other.label == item.label:
                raise StudyError(
                    src, at, value, f"has the same label {item.label!r} as {where}[{j}]"
                )
        out.append(item)
    return Axis(key, target, tuple(out))


def _grid_field(key: str) -> str:
    """How messages name a grid key: quoted as in the file when it holds dots."""
    return f'grid."{key}"' if "." in key else f"grid.{key}"


def _plugin_value(src: str, at: str, value: Any) -> AxisValue:
    """A controller/dispatcher/charging axis value: a plugin name, or {name, options, label}."""
    if isinstance(value, str):
        return AxisValue(value, {"name": value})
    if not isinstance(value, dict):
        raise StudyError(
            src, at, value, "must be a plugin name or a table { name, options, label }"
        )
    _no_unknown(src, f"{at}.", value, ("name", "options", "label"))
    name = value.get("name")
    if not isinstance(name, str) or not name:
        raise StudyError(src, f"{at}.name", name, "is required: a plugin name (string)")
    options = value.get("options", {})
    if not isinstance(options, dict):
        raise StudyError(src, f"{at}.options", options, "must be a table of keyword options")
    label = value.get("label", name)
    if not isinstance(label, str) or not label:
        raise StudyError(src, f"{at}.label", label, "must be a non-empty string")
    return AxisValue(label, {"name": name, "options": dict(options)})


def _no_overlap(src: str, axes: tuple[Axis, ...], grid: dict[str, Any]) -> None:
    """Two axes writing the same place (or one inside the other) would fight over it."""
    for a, b in itertools.combinations(axes, 2):
        n = min(len(a.target), len(b.target))
        if a.target[:n] == b.target[:n]:
            raise StudyError(
                src,
                _grid_field(b.name),
                grid[b.name],
                f"writes {'.'.join(b.target)}, which axis {a.name!r} also sets; keep one",
            )


def _put(raw: dict[str, Any], target: tuple[str, ...], value: Any) -> None:
    """Write `value` at the dotted `target` in `raw`, creating tables on the way."""
    table = raw
    for depth, key in enumerate(target[:-1]):
        nxt = table.setdefault(key, {})
        if not isinstance(nxt, dict):
            where = ".".join(target[: depth + 1])
            raise ScenarioError(
                "(grid)",
                where,
                nxt,
                f"is not a table, so {'.'.join(target)} cannot be written",
            )
        table = nxt
    table[target[-1]] = value


def _scenario_rule(exc: ScenarioError) -> str:
    """A scenario error restated as the rule a study value broke."""
    return f"as scenario field {exc.field} = {exc.value!r}: {exc.rule}"


def _plugins() -> dict[str, set[str]]:
    from fleet.plugins import discover

    return {
        kind: {info.name for info in discover(kind) if info.ok}
        for kind in ("controller", "dispatcher", "charging")
    }


def _check_plugins(
    src: str,
    where: str,
    value: Any,
    scenario: Any,
    available: dict[str, set[str]],
    kinds: list[str],
) -> None:
    for kind in kinds:
        name = getattr(scenario, kind).name
        if name not in available[kind]:
            known = ", ".join(sorted(available[kind])) or "none"
            raise StudyError(
                src,
                where,
                value,
                f"no {kind} plugin named {name!r} is registered (available: {known}; "
                "`fleet plugins` lists them)",
            )
        # Build it once, so options the plugin rejects fail here and not in every cell.
        from fleet.errors import PluginError
        from fleet.plugins import load_charging_policy, load_controller, load_dispatcher

        loader = {
            "controller": load_controller,
            "dispatcher": load_dispatcher,
            "charging": load_charging_policy,
        }[kind]
        try:
            loader(name, getattr(scenario, kind).options)
        except PluginError as exc:
            raise StudyError(src, where, value, str(exc)) from None


def _cell_id(raw: dict[str, Any], scenario: Any, digests: dict[Path, str]) -> str:
    """sha256 of the scenario tables with each referenced file replaced by its contents' hash."""
    files = [scenario.map, *scenario.parts.values()]
    if scenario.quality.calibration is not None:
        files.append(scenario.quality.calibration)
    for f in files:
        if f not in digests:
            digests[f] = hashlib.sha256(Path(f).read_bytes()).hexdigest()
    body = copy.deepcopy(raw)
    body["scenario"]["map"] = digests[scenario.map]
    for part, f in scenario.parts.items():
        body["parts"][part] = digests[f]
    if scenario.quality.calibration is not None:
        body["quality"]["calibration"] = digests[scenario.quality.calibration]
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:12]


# -- one cell -----------------------------------------------------------------------------------
def run_cell(spec: CellSpec) -> dict[str, Any]:
    """Run one cell into its run directory and return its record; never raises.

    The run directory holds what ``fleet run --no-figures`` writes (summary.json,
    trajectories.csv, events.csv, jobs.csv, attempts.csv, tasks.csv, caps.csv, plans.csv,
    violations.csv), plus
    ``cell.json`` (the record, written atomically) and, when the cell failed, ``error.txt`` (the
    traceback). Any exception (plugin options that do not suit the robots, a crash mid-run, a
    full disk) makes the record
    ``status = "failed"`` with ``error = "ExceptionType: message"``.
    """
    from fleet.engine import World
    from fleet.scenario import parse_scenario

    t0 = time.perf_counter()
    run_dir = Path(spec.run_dir)
    # A retried cell starts clean: no files left from the attempt that failed.
    shutil.rmtree(run_dir, ignore_errors=True)
    run_dir.mkdir(parents=True, exist_ok=True)
    try:
        scenario = parse_scenario(spec.raw, spec.base, source=spec.source)
        world = World(scenario)
        result = world.run()
        world.write(run_dir)  # the same files as `fleet run`, without figures
        record = _record(spec, CellStatus.OK, None, time.perf_counter() - t0, result.summary)
    except Exception as exc:
        (run_dir / "error.txt").write_text(traceback.format_exc(), encoding="utf-8")
        record = _record(spec, CellStatus.FAILED, _describe(exc), time.perf_counter() - t0)
    _write_json(run_dir / "cell.json", record)
    return record


def kpi_values(summary: dict[str, Any] | None) -> dict[str, Any]:
    """A run's KPI columns (`KPI_COLUMNS`) from its summary.json; None where it has no value."""
    kpis: dict[str, Any] = {}
    for name, keys in KPI_COLUMNS:
        value: Any = summary
        for key in keys:
            value = value.get(key) if isinstance(value, dict) else None
        kpis[name] = value
    return kpis


def _record(
    spec: CellSpec,
    status: CellStatus,
    error: str | None,
    wall_s: float,
    summary: dict[str, Any] | None = None,
) -> dict[str, Any]:
    kpis = kpi_values(summary)
    return {
        "cell": spec.cell,
        "index": spec.index,
        "seed": spec.seed,
        "params": dict(spec.params),
        "status": status.value,
        "error": error,
        "wall_s": round(wall_s, 3),
        "run_dir": f"cells/{spec.cell}",
        "kpis": kpis,
    }


def _describe(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {exc}"


# -- the sweep ----------------------------------------------------------------------------------
def run_study(
    study: Study,
    out_dir: str | Path,
    *,
    executor: Executor | None = None,
    workers: int | None = None,
    progress: Callable[[dict[str, Any], int, int], None] | None = None,
    retry_failed: bool = True,
) -> SweepResult:
    """Run every cell of `study` that has no finished result in `out_dir` yet.

    Parameters
    ----------
    study:
        From `load_study`.
    out_dir:
        The study's directory: ``study.json``, ``results.csv`` (and ``results.parquet`` when
        pyarrow is installed) and ``cells/<id>/`` per cell. Reusing it resumes the study.
    executor:
        Where cells run; None creates a spawn-context `ProcessPoolExecutor` (shut down at the
        end). A given executor (e.g. from `dask_executor`) is used as is and not shut down;
        its workers must see `out_dir` on the same path.
    workers:
        Processes of the pool created when `executor` is None (default: the CPU count); 0 runs
        the cells one after another in this process (`fleet.api.sweep`'s ``jobs=0``: no process
        to start, and no ``__main__`` guard needed in a script).
    progress:
        Called in this process as ``progress(record, done, total)`` per cell reused or
        finished; ``record["skipped"]`` tells which.
    retry_failed:
        Run cells whose previous attempt failed again (default); False keeps their records.

    Returns
    -------
    SweepResult
        Records in cell order and the counts. A failed cell never stops the others.

    Raises
    ------
    SweepInterrupted
        On Ctrl-C (KeyboardInterrupt): the cells still running are stopped (the local pool's
        workers are terminated), what finished is kept, study.json says ``"complete": false``.
    """
    if workers is not None and (not _is_int(workers) or workers < 0):
        raise ValueError(f"workers = {workers!r}: must be a whole number >= 0 (or None)")
    out = Path(out_dir).resolve()
    (out / "cells").mkdir(parents=True, exist_ok=True)
    # Incomplete until the last cell has its record: a sweep stopped in any way says so.
    _write_json(out / "study.json", _study_json(study, complete=False))
    total = len(study.cells)
    records: dict[int, dict[str, Any]] = {}
    todo: list[Cell] = []
    done = 0
    for cell in study.cells:
        previous = _finished(out, cell, retry_failed)
        if previous is None:
            todo.append(cell)
            continue
        # The record's index and labels come from this study: an earlier study may have
        # reached the same scenario through another grid.
        records[cell.index] = _current(previous, cell) | {"skipped": True}
        done += 1
        if progress is not None:
            progress(records[cell.index], done, total)
    paths = _write_results(out, study, records)

    def finished(cell: Cell, record: dict[str, Any]) -> None:
        nonlocal done, paths
        # Written here as well: the worker may have died first, or run on a machine whose
        # files this one does not see.
        _write_json(out / "cells" / cell.id / "cell.json", record)
        records[cell.index] = record | {"skipped": False}
        done += 1
        paths = _write_results(out, study, records)
        if progress is not None:
            progress(records[cell.index], done, total)

    try:
        _run_todo(executor, workers, todo, study, out, finished)
    except KeyboardInterrupt:
        raise SweepInterrupted(_result(out, records, paths, complete=False)) from None
    _write_json(out / "study.json", _study_json(study, complete=True))
    return _result(out, records, paths, complete=True)


def _result(
    out: Path, records: dict[int, dict[str, Any]], paths: tuple[Path, ...], *, complete: bool
) -> SweepResult:
    ordered = [records[i] for i in sorted(records)]
    ok = sum(1 for r in ordered if r["status"] == CellStatus.OK)
    return SweepResult(
        out_dir=out,
        records=ordered,
        ok=ok,
        failed=len(ordered) - ok,
        skipped=sum(1 for r in ordered if r["skipped"]),
        results_paths=paths,
        complete=complete,
    )


def _run_todo(
    executor: Executor | None,
    workers: int | None,
    todo: list[Cell],
    study: Study,
    out: Path,
    finished: Callable[[Cell, dict[str, Any]], None],
) -> None:
    """Run the cells of `todo` on `executor`, on local process pools, or (`workers` 0) here."""
    if executor is not None:
        _run_cells(executor, todo, study, out, finished, own=False)
    elif workers == 0:
        for cell in todo:
            finished(cell, run_cell(study.spec(cell, out)))
    elif todo:
        size = min(workers or os.cpu_count() or 1, len(todo))
        # A worker that dies (killed, out of memory) breaks the whole pool and every cell still
        # in it with BrokenProcessPool, not only its own: run those again in a fresh pool, and
        # cells that break a second one each alone, so only the culprit is recorded as failed.
        for attempt, pool_size in enumerate((size, size, 1)):
            last = attempt == 2
            if pool_size == 1:
                broken = []
                for cell in todo:
                    broken += _run_cells(_spawn_pool(1), [cell], study, out, finished, last=last)
            else:
                broken = _run_cells(_spawn_pool(pool_size), todo, study, out, finished, last=last)
            if not broken:
                break
            todo = broken


def _spawn_pool(size: int) -> ProcessPoolExecutor:
    return ProcessPoolExecutor(
        max_workers=size,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_ignore_interrupts,
    )


def _ignore_interrupts() -> None:
    """Ctrl-C reaches a terminal's whole process group; the sweeping process alone answers it
    (and stops the workers), so a worker never dies half-way through writing a record."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _run_cells(
    pool: Executor,
    cells: list[Cell],
    study: Study,
    out: Path,
    finished: Callable[[Cell, dict[str, Any]], None],
    *,
    own: bool = True,
    last: bool = True,
) -> list[Cell]:
    """Run `cells` on `pool`, reporting each to `finished`; returns the cells a broken process
    pool lost (recorded as failed instead when `last`). Shuts down `pool` when `own`."""
    futures: dict[Future, Cell] = {}
    broken: list[Cell] = []
    interrupted = False
    try:
        for cell in cells:
            spec = study.spec(cell, out)
            try:
                futures[pool.submit(run_cell, spec)] = cell
            except BrokenProcessPool as exc:
                if last:
                    finished(cell, _lost(spec, exc))
                else:
                    broken.append(cell)
            except Exception as exc:  # a closed executor, a spec it cannot send
                finished(cell, _lost(spec, exc))
        for future in as_completed(futures):
            cell = futures[future]
            try:
                record = future.result()
            except BrokenProcessPool as exc:
                if not last:
                    broken.append(cell)
                    continue
                record = _lost(study.spec(cell, out), exc)
            except Exception as exc:  # the executor could not run it
                record = _lost(study.spec(cell, out), exc)
            finished(cell, record)
    except KeyboardInterrupt:
        interrupted = True
        raise
    finally:
        for future in futures:
            future.cancel()
        if own:
            if interrupted:
                # Waiting for the running cells could take minutes; their runs are lost anyway
                # (no record: a resumed sweep runs them again).
                _terminate_workers(pool)
            pool.shutdown(wait=True, cancel_futures=True)
    return sorted(broken, key=lambda c: c.index)


def _terminate_workers(pool: Executor) -> None:
    """Stop a process pool's workers now (ProcessPoolExecutor has no public way before 3.14)."""
    processes = getattr(pool, "_processes", None) or {}
    for process in list(processes.values()):
        if process.is_alive():
            process.terminate()


def _lost(spec: CellSpec, exc: BaseException) -> dict[str, Any]:
    """The record of a cell whose worker never returned one; the traceback goes to error.txt."""
    run_dir = Path(spec.run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "error.txt").write_text("".join(traceback.format_exception(exc)), encoding="utf-8")
    return _record(spec, CellStatus.FAILED, _describe(exc), 0.0)


def _finished(out: Path, cell: Cell, retry_failed: bool) -> dict[str, Any] | None:
    """The cell's earlier record if it need not run again, else None."""
    run_dir = out / "cells" / cell.id
    try:
        record = json.loads((run_dir / "cell.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(record, dict) or record.get("cell") != cell.id:
        return None
    if record.get("status") == CellStatus.OK:
        # A result whose run directory lost its summary is no result.
        return record if (run_dir / "summary.json").is_file() else None
    if record.get("status") == CellStatus.FAILED and not retry_failed:
        return record
    return None


def _current(record: dict[str, Any], cell: Cell) -> dict[str, Any]:
    return record | {"index": cell.index, "seed": cell.seed, "params": dict(cell.params)}


def _study_json(study: Study, *, complete: bool) -> dict[str, Any]:
    return {
        "name": study.name,
        # Whether every cell has a record (false while sweeping, or after an interruption).
        "complete": complete,
        "file": str(study.file.resolve()),
        "scenario": str(study.scenario),
        "seeds": list(study.seeds),
        "duration_s": study.duration_s,
        "axes": [
            {
                "name": a.name,
                "target": ".".join(a.target),
                "labels": [v.label for v in a.values],
            }
            for a in study.axes
        ],
        "cells": {
            c.id: {"index": c.index, "seed": c.seed, "params": c.params} for c in study.cells
        },
    }


def _rows(study: Study, records: dict[int, dict[str, Any]]) -> list[dict[str, Any]]:
    rows = []
    for index in sorted(records):
        r = records[index]
        row: dict[str, Any] = {"cell": r["cell"], "index": r["index"], "seed": r["seed"]}
        row.update({a.name: r["params"].get(a.name) for a in study.axes})
        row.update({k: r.get(k) for k in _STATUS_COLUMNS})
        kpis = r.get("kpis") or {}
        row.update({name: kpis.get(name) for name, _ in KPI_COLUMNS})
        rows.append(row)
    return rows


def _write_results(out: Path, study: Study, records: dict[int, dict[str, Any]]) -> tuple[Path, ...]:
    """Rewrite results.csv (and results.parquet when pyarrow imports), each atomically."""
    rows = _rows(study, records)
    columns = study.columns
    path = out / "results.csv"
    tmp = _tmp(path)
    with open(tmp, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh)
        w.writerow(columns)
        for row in rows:
            w.writerow([_csv_cell(row[c]) for c in columns])
    os.replace(tmp, path)
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return (path,)
    parquet = out / "results.parquet"
    tmp = _tmp(parquet)
    pq.write_table(pa.Table.from_pylist(rows), tmp)
    os.replace(tmp, parquet)
    return (path, parquet)


def _csv_cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def _write_json(path: Path, data: Any) -> None:
    """Write JSON so a reader sees the old file or the new one, never half of one."""
    tmp = _tmp(path)
    tmp.write_text(json.dumps(data, indent=2) + "\n", encoding="utf-8")
    os.replace(tmp, path)


def _tmp(path: Path) -> Path:
    # Unique per process and thread: a worker and the parent may write the same cell.json.
    return path.with_name(f".{path.name}.{os.getpid()}.{threading.get_ident()}.tmp")


# -- Dask -----------------------------------------------------------------------------------
@contextmanager
def dask_executor(address: str, *, timeout_s: float = 10.0) -> Iterator[Executor]:
    """A `concurrent.futures.Executor` running on the Dask scheduler at `address`.

    Parameters
    ----------
    address:
        The scheduler, e.g. ``tcp://10.0.0.5:8786``.
    timeout_s:
        How long to try connecting before giving up.

    Raises
    ------
    FleetError
        If dask.distributed is not installed (the message says how to install it), or if no
        scheduler answers at `address` within `timeout_s`.
    """
    try:
        from distributed import Client
    except ImportError:
        raise FleetError(
            "sweeping on a Dask cluster needs dask.distributed: pip install 'mambot-fleet[dask]'"
        ) from None
    try:
        client = Client(address, timeout=timeout_s)
    except Exception as exc:  # OSError, TimeoutError, ValueError for a malformed address, ...
        raise FleetError(
            f"cannot connect to the Dask scheduler at {address!r} within {timeout_s:g} s: "
            f"{_describe(exc)}; start one with `dask scheduler` or check the address"
        ) from None
    try:
        # pure=False: a retried cell must run again, not come back from Dask's result cache.
        yield client.get_executor(pure=False)
    finally:
        client.close()


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_positive(value: Any) -> bool:
    return (
        isinstance(value, int | float)
        and not isinstance(value, bool)
        and math.isfinite(value)
        and value > 0
    )
