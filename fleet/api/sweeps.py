"""Running a study from code: its cells' KPIs as one typed table, and any run table of every
cell as one table with the cell's grid values in front."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from concurrent.futures import Executor
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from fleet.api.runs import RunResult, TemporaryFolder, open_run, progress_hook
from fleet.api.scenarios import as_toml
from fleet.errors import FleetError
from fleet.scenario import Scenario
from fleet.study.sweep import (
    Study,
    SweepInterrupted,
    SweepResult,
    load_study,
    parse_study,
    run_study,
)

if TYPE_CHECKING:
    from fleet.study.report import ReportResult

__all__ = ["SweepResults", "sweep"]

#: What `sweep` takes as `progress`: False, True (a bar on stderr) or a callable given
#: ``(record, done, total)`` per cell finished or reused.
SweepProgress = bool | Callable[[dict[str, Any], int, int], None]


@dataclass
class SweepResults:
    """A study's cells after `sweep`: one row per cell, its grid values and its KPIs.

    ``pandas.DataFrame(results.table())`` is the results table (one row per cell);
    ``pandas.DataFrame(results.table("jobs"))`` every cell's jobs, each row led by its cell's
    id, seed and grid values.
    """

    study: Study
    #: `fleet.study.sweep.run_study`'s own account (records, counts, results.csv).
    sweep: SweepResult
    _tmp: TemporaryFolder | None = field(default=None, repr=False)

    def __repr__(self) -> str:
        return (
            f"SweepResults({self.study.name!r}: {len(self.sweep.records)} cells, {self.ok} ok, "
            f"{self.failed} failed; out_dir={str(self.out_dir)!r})"
        )

    @property
    def out_dir(self) -> Path:
        """The study directory: results.csv, study.json and ``cells/<id>/`` per cell."""
        return self.sweep.out_dir

    @property
    def ok(self) -> int:
        """Cells that ran to the end (this time or in an earlier sweep into the folder)."""
        return self.sweep.ok

    @property
    def failed(self) -> int:
        """Cells whose run raised (their ``error`` column says what)."""
        return self.sweep.failed

    @property
    def rows(self) -> list[dict[str, Any]]:
        """One dict per cell in grid order: ``cell``, ``index``, ``seed``, one key per grid axis,
        ``status``, ``error``, ``wall_s``, ``run_dir``, then every KPI the cell's record holds.

        A grid axis of numbers, text or booleans keeps its values (``robots`` is 2, not "2");
        plugin, map and table axes give their labels.
        """
        rows = []
        for record in self.sweep.records:
            row: dict[str, Any] = {k: record[k] for k in ("cell", "index", "seed")}
            row.update(self._grid_values(record["params"]))
            row.update({k: record.get(k) for k in ("status", "error", "wall_s", "run_dir")})
            row.update(record.get("kpis") or {})
            rows.append(row)
        return rows

    def table(self, name: str = "results") -> dict[str, list[Any]]:
        """Typed columns ``{column: [value, ...]}``: ``"results"`` for `rows`; any other name
        (``"jobs"``, ``"events"``, ...) for that table of every cell that ran, one after the
        other, each row led by ``cell``, ``seed`` and the grid values. A cell without the table
        (no violations, say) adds no rows; columns only some cells have are None elsewhere."""
        if name == "results":
            return _columns(self.rows)
        rows = []
        for record in self.sweep.records:
            if record["status"] != "ok":
                continue
            run = self.run(record["cell"])
            if name not in run.tables:
                continue
            lead = {"cell": record["cell"], "seed": record["seed"]}
            lead.update(self._grid_values(record["params"]))
            rows += [lead | row for row in run.rows(name)]
        return _columns(rows)

    def run(self, cell: str | int) -> RunResult:
        """The run of one cell, by id or index, with its summary and tables.

        Raises
        ------
        FleetError
            If the study has no such cell, or it failed (its error is in the message).
        """
        for record in self.sweep.records:
            if cell in (record["cell"], record["index"]):
                if record["status"] != "ok":
                    raise FleetError(f"cell {record['cell']} failed: {record['error']}")
                cell_run = open_run(self.out_dir / record["run_dir"])
                cell_run._tmp = self._tmp  # a temporary study folder lives as long as its runs
                return cell_run
        raise FleetError(
            f"no cell {cell!r} in study {self.study.name!r} (ids: "
            f"{', '.join(r['cell'] for r in self.sweep.records)}; or an index from 0)"
        )

    def report(self, out_dir: str | Path | None = None) -> ReportResult:
        """Write the study's report as ``fleet report`` does (figures and report.md, into the
        study directory unless `out_dir`); its ``markdown`` is the report's text."""
        from fleet.study.report import write_report

        return write_report(self.out_dir, None if out_dir is None else Path(out_dir))

    def _grid_values(self, params: dict[str, str]) -> dict[str, Any]:
        values: dict[str, Any] = {}
        for axis in self.study.axes:
            label = params.get(axis.name)
            value = next((v.value for v in axis.values if v.label == label), label)
            plain = isinstance(value, int | float | bool | str) and axis.name != "map"
            values[axis.name] = value if plain else label
        return values


def sweep(
    study: Study | Scenario | str | Path,
    out_dir: str | Path | None = None,
    *,
    grid: Mapping[str, list[Any]] | None = None,
    seeds: int | list[int] | None = None,
    duration_s: float | None = None,
    name: str | None = None,
    jobs: int | None = None,
    progress: SweepProgress = False,
    retry_failed: bool = True,
    executor: Executor | None = None,
) -> SweepResults:
    """Run a study, as ``fleet sweep`` does: every cell without a finished result in `out_dir`.

    Parameters
    ----------
    study:
        A study file (see ``studies/throughput.toml``), a `Study` from
        `fleet.study.sweep.load_study`, or a `Scenario` (`load_scenario`, `change`, ...) to sweep
        over `grid` and `seeds`.
    grid, seeds, duration_s, name:
        With a `Scenario`: the study file's ``[grid]`` and ``[study]`` values, checked as a
        file's are (``grid={"robots": [2, 4], "jobs.rate_per_h": [60, 120]}``, ``seeds=3`` for
        seeds 1 to 3). The name defaults to the scenario's.
    out_dir:
        The study directory, resumed when it holds earlier cells; None: a temporary one,
        removed when the result is no longer used.
    jobs:
        Cells run at once, each in its own process (default: one per CPU core); 0: one after
        another in this process. The processes start afresh and import the main module, so a
        script (not a notebook) that sweeps with processes keeps its code under ``if __name__
        == "__main__":``; with 0 it need not.
    progress:
        True: a bar on stderr; a callable: ``progress(record, done, total)`` per cell.
    retry_failed:
        Run cells that failed in an earlier sweep again (default); False keeps their records.
    executor:
        Run the cells there instead (e.g. `fleet.study.sweep.dask_executor`'s).

    Raises
    ------
    StudyError
        If the study file is wrong, naming the file, the field and the value.
    SweepInterrupted
        On Ctrl-C (a notebook's stop): its ``results`` are the `SweepResults` of the cells
        that finished; the same call into the same `out_dir` runs the rest.
    """
    if isinstance(study, Scenario):
        study = _study_of(study, grid, seeds, duration_s, name)
    elif grid is not None or seeds is not None or duration_s is not None or name is not None:
        raise TypeError("grid, seeds, duration_s and name go with a Scenario, not a study")
    elif not isinstance(study, Study):
        study = load_study(study)
    out, tmp = TemporaryFolder.unless(out_dir, study.name)
    count = "{task.completed}/{task.total} cells"
    with progress_hook(
        progress, len(study.cells), study.name, count, lambda record, done, total: done
    ) as report:
        try:
            result = run_study(
                study,
                out,
                executor=executor,
                workers=jobs,
                progress=report,
                retry_failed=retry_failed,
            )
        except SweepInterrupted as stopped:
            # Interrupted (a notebook's stop button): the cells that finished stay readable.
            stopped.results = SweepResults(study, stopped.result, tmp)  # type: ignore[attr-defined]
            raise
    return SweepResults(study, result, tmp)


def _study_of(
    scenario: Scenario,
    grid: Mapping[str, list[Any]] | None,
    seeds: int | list[int] | None,
    duration_s: float | None,
    name: str | None,
) -> Study:
    """The study of `scenario` over `grid` and `seeds`, validated as a study file's tables."""
    name = name or scenario.name
    table: dict[str, Any] = {"name": name, "seeds": 1 if seeds is None else seeds}
    if duration_s is not None:
        table["duration_s"] = duration_s
    raw = {"study": table, "grid": as_toml(grid or {})}
    # Errors name the study as "sweep(<name>)"; `map` axis values are relative to this folder.
    return parse_study(raw, Path(f"sweep({name})"), base_scenario=scenario)


def _columns(rows: list[dict[str, Any]]) -> dict[str, list[Any]]:
    """Rows as columns; a key some rows lack is None in them."""
    names: dict[str, None] = {}
    for row in rows:
        names.update(dict.fromkeys(row))
    return {name: [row.get(name) for row in rows] for name in names}
