"""The study report: figures and a Markdown summary of a finished sweep (`fleet report DIR`).

Everything is read from the study directory `fleet sweep` wrote (``study.json``,
``results.csv`` and each cell's run directory under ``cells/``); nothing is re-run.
`write_report` writes, into the output directory:

- ``throughput.png``: good parts per hour against the arrival rate, one line per series, one
  panel per fleet size; the mean across seeds with its 95 % Student t interval (cut at zero),
  and the offered rate as a dashed ceiling;
- ``lead_time.png``: box plots of lead times (``delivered_s - released_s`` of every delivered
  job in the runs' ``jobs.csv``), per series and arrival rate, one panel per fleet size;
- ``defects.png``: the defect rate, (defective + failed prints) / judged prints pooled over
  seeds, per series and arrival rate, one panel per fleet size;
- ``report.md``: what was run (failed runs listed with their errors), a table of good parts
  per hour per fleet size with the leader of every setting and whether it is clearly ahead, the
  leader's paired differences to the other series with the method named, which intervals need
  more seeds for a target half-width (and how many), defect rates, median lead times, safety
  violations, and the figures linked.

How the study's axes are used. The conventional axes have roles: ``controller`` names the
series (what is compared), ``rate_per_h`` is the x axis, ``robots`` the panels. Any other axis
with more than one label splits the series further: a series is named
``"<controller>, axis=label, ..."`` (or ``"axis=label, ..."`` without a controller axis, or
``"all runs"`` when nothing splits). An axis with a single label is a constant of the study and
only listed. Without a rate axis, throughput and defects are grouped bars (one group), without a
robots axis there is one panel.

Statistics use the runs whose status is ``"ok"``; failed runs are listed and left out; the
computations are `fleet.study.stats`' (quantiles from scipy's t distribution). A series' mean across
seeds has a two-sided 95 % Student t interval with n-1 degrees of freedom, cut at zero (good
parts per hour cannot be negative); a single seed has none. In each setting the series with the
highest mean, the leader, is compared with every other series by their difference: a sweep runs
every grid point on the same seeds and a seed alone draws the job arrivals (common random
numbers), so where both series' ok runs have the same seeds the difference is paired seed by
seed (t on the per-seed differences, n-1 df); where they differ (a failed run) Welch's unpaired
t with Welch-Satterthwaite's df is used instead, and the report names which. The leader is
*clearly ahead* when the interval of its difference to every other series lies above zero; else
it is a tie. For a target half-width (`HalfWidth`, by default 5 % of the mean) the report says
which intervals are wider and how many seeds they need (`fleet.study.stats.replications_needed`).

Figures are drawn on `matplotlib.figure.Figure` with an Agg canvas, never pyplot, as in
`fleet.view.figures`.
"""

from __future__ import annotations

import csv
import hashlib
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib import colormaps
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from fleet.errors import InputError
from fleet.study.stats import (
    CONFIDENCE,
    NON_NEGATIVE,
    Difference,
    Interval,
    Method,
    Verdict,
    compare,
    mean_ci,
    replications_needed,
    t_quantile,
)
from fleet.study.warmup import warmup_lines
from fleet.view.figures import csv_number

__all__ = [
    "THROUGHPUT_PNG",
    "LEAD_TIME_PNG",
    "DEFECTS_PNG",
    "REPORT_MD",
    "CONTROLLER_AXIS",
    "RATE_AXIS",
    "ROBOTS_AXIS",
    "VIOLATION_KINDS",
    "Run",
    "JobStats",
    "Study",
    "Interval",
    "Verdict",
    "Ranking",
    "HalfWidth",
    "DEFAULT_HALF_WIDTH",
    "Advice",
    "Summary",
    "ReportResult",
    "t_quantile",
    "mean_ci",
    "compare",
    "method_summary",
    "load_study",
    "load_jobs",
    "summarise",
    "throughput_figure",
    "lead_time_figure",
    "defects_figure",
    "report_markdown",
    "write_report",
]

#: File names `write_report` writes into the output directory.
THROUGHPUT_PNG = "throughput.png"
LEAD_TIME_PNG = "lead_time.png"
DEFECTS_PNG = "defects.png"
REPORT_MD = "report.md"

#: Axis names with a role in the report (see the module docstring).
CONTROLLER_AXIS = "controller"
RATE_AXIS = "rate_per_h"
ROBOTS_AXIS = "robots"

#: Kinds of safety violation, as the ``violations_<kind>`` columns of ``results.csv``.
VIOLATION_KINDS = ("obstacle", "speed_zone", "print_speed", "collision")

_RESULTS = "results.csv"
_STUDY = "study.json"
_GOOD = "throughput_good_per_h"
_FIXED_COLUMNS = ("cell", "index", "seed", "status", "error", "run_dir")
_REQUIRED_COLUMNS = (*_FIXED_COLUMNS, _GOOD, *(f"violations_{k}" for k in VIOLATION_KINDS))
_JOB_COLUMNS = ("released_s", "delivered_s", "outcome")
_OUTCOMES = ("good", "defective", "failed")
_DPI = 150
_NO_DATA = "–"


@dataclass(frozen=True)
class HalfWidth:
    """The half-width the report asks of an interval of good parts per hour, to say how many
    seeds it needs (`fleet report --half-width`).

    Attributes
    ----------
    value:
        A share of the mean (``relative``: 0.05 is 5 % of the mean) or good parts per hour.
    relative:
        Whether `value` is a share of the mean. A difference's target is the same share of the
        leader's mean.
    """

    value: float
    relative: bool = True

    def __post_init__(self) -> None:
        if not (math.isfinite(self.value) and self.value > 0):
            raise ValueError(f"a half-width must be a positive number, got {self.value!r}")

    def of(self, mean: float) -> float:
        """The target half-width for an interval about `mean`."""
        return self.value * abs(mean) if self.relative else self.value

    def text(self) -> str:
        """``"5 % of the mean"`` or ``"0.5 good parts/h"``."""
        if self.relative:
            return f"{100 * self.value:g} % of the mean"
        return f"{self.value:g} good parts/h"

    @classmethod
    def parse(cls, text: str) -> HalfWidth:
        """``"5%"`` (a share of the mean) or ``"0.5"`` (good parts per hour).

        Raises
        ------
        ValueError
            Not a positive number, with or without a trailing ``%``.
        """
        raw = text.strip()
        relative = raw.endswith("%")
        try:
            value = float(raw[:-1] if relative else raw)
            return cls(value / 100 if relative else value, relative)
        except ValueError:
            raise ValueError(
                "must be a positive number of good parts/h (0.5) or a share of the mean (5%)"
            ) from None


#: What the report asks of an interval unless told: a half-width of 5 % of the mean.
DEFAULT_HALF_WIDTH = HalfWidth(0.05)


@dataclass(frozen=True)
class Advice:
    """Whether an interval (an arm's mean, or a difference to the leader) meets the target
    half-width, and how many seeds it would need.

    Attributes
    ----------
    panel, x:
        The setting.
    series:
        The arm, or ``"<leader> − <other>"`` for a difference.
    n:
        Seeds now (pairs, for a paired difference).
    half_width:
        The interval's half-width now (None with one seed).
    target:
        The half-width asked for.
    needed:
        Seeds needed in all (`fleet.study.stats.replications_needed`); None when unknown (one
        seed: no spread yet; a target of zero).
    """

    panel: str | None
    x: str | None
    series: str
    n: int
    half_width: float | None
    target: float
    needed: int | None

    @property
    def enough(self) -> bool:
        """The interval already meets the target."""
        return self.half_width is not None and self.half_width <= self.target


@dataclass(frozen=True)
class Ranking:
    """The leader of one setting (fleet size, arrival rate) by mean good parts per hour, and its
    difference to every other series (leader minus series, paired on common seeds)."""

    panel: str | None
    x: str | None
    leader: str
    runner_up: str | None
    verdict: Verdict
    differences: Mapping[str, Difference] = field(default_factory=dict)


# -- what a study directory holds -------------------------------------------------------------
@dataclass(frozen=True)
class Run:
    """One row of ``results.csv``: one cell (grid point and seed) of the study.

    `good_per_h` and `violations` are None / empty for a failed run; `run_dir` is the cell's run
    directory (None when neither the recorded path nor ``cells/<cell>`` exists); `line` is the
    row's line in ``results.csv`` (the header is line 1).
    """

    cell: str
    index: int
    seed: int
    params: Mapping[str, str]
    status: str
    error: str
    run_dir: Path | None
    line: int
    good_per_h: float | None = None
    violations: Mapping[str, int] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """The run finished (status ``"ok"``); only these enter the statistics."""
        return self.status == "ok"


@dataclass(frozen=True)
class JobStats:
    """What one run's ``jobs.csv`` says: lead times of delivered jobs and judged prints, and a
    digest of the jobs released (``arrivals``: id, part and release time of each job, each once;
    two runs of one seed with common random numbers have the same)."""

    lead_times_s: tuple[float, ...]
    judged: int
    defective: int  # defective + failed outcomes
    arrivals: str = ""


@dataclass(frozen=True, eq=False)
class Study:
    """A study directory as read by `load_study`.

    Attributes
    ----------
    path:
        The study directory.
    name:
        The study's name (``study.json``; the directory name without one).
    axes:
        Axis name -> labels in grid order (``study.json``; else the order of ``results.csv``),
        completed by any label found only in ``results.csv``.
    seeds:
        Seeds of the study (``study.json``; else those found in ``results.csv``).
    runs:
        Every row of ``results.csv``, ok or failed, in file order.
    not_run:
        Cell ids listed in ``study.json`` without a row in ``results.csv``.
    file:
        The study file the sweep ran (``study.json``'s ``"file"``; empty without one).
    """

    path: Path
    name: str
    axes: dict[str, tuple[str, ...]]
    seeds: tuple[int, ...]
    runs: tuple[Run, ...]
    not_run: tuple[str, ...] = ()
    file: str = ""

    @property
    def ok(self) -> tuple[Run, ...]:
        """The runs that enter the statistics."""
        return tuple(r for r in self.runs if r.ok)

    @property
    def failed(self) -> tuple[Run, ...]:
        """The runs left out of the statistics (listed in the report with their errors)."""
        return tuple(r for r in self.runs if not r.ok)

    @property
    def x_axis(self) -> str | None:
        """The axis on the x axis (``rate_per_h``), or None."""
        return RATE_AXIS if RATE_AXIS in self.axes else None

    @property
    def panel_axis(self) -> str | None:
        """The axis giving one panel per label (``robots``), or None."""
        return ROBOTS_AXIS if ROBOTS_AXIS in self.axes else None

    @property
    def series_axes(self) -> tuple[str, ...]:
        """Axes whose labels name the series: ``controller`` and any other axis that varies."""
        roles = (RATE_AXIS, ROBOTS_AXIS, CONTROLLER_AXIS)
        extra = tuple(a for a, labels in self.axes.items() if a not in roles and len(labels) > 1)
        return ((CONTROLLER_AXIS,) if CONTROLLER_AXIS in self.axes else ()) + extra

    def series_of(self, run: Run) -> str:
        """The series `run` belongs to (see the module docstring for the naming)."""
        parts = [
            run.params[a] if a == CONTROLLER_AXIS else f"{a}={run.params[a]}"
            for a in self.series_axes
        ]
        return ", ".join(parts) or "all runs"

    def x_of(self, run: Run) -> str | None:
        """`run`'s label on the x axis, or None without a rate axis."""
        return None if self.x_axis is None else run.params[self.x_axis]

    def panel_of(self, run: Run) -> str | None:
        """`run`'s panel label, or None without a robots axis."""
        return None if self.panel_axis is None else run.params[self.panel_axis]


def load_study(study_dir: Path) -> Study:
    """Read ``results.csv`` (and ``study.json`` when present) of a study directory.

    Raises
    ------
    InputError
        ``results.csv`` is missing or malformed (a column missing, an index or seed that is not
        an integer, a status other than ok/failed, an ok row whose good parts per hour or
        violation counts are not numbers), ``study.json`` is malformed or names an axis that
        ``results.csv`` lacks, or no run is ok.
    """
    study_dir = Path(study_dir)
    results = study_dir / _RESULTS
    if not results.is_file():
        raise InputError(
            str(results),
            "(file)",
            "missing",
            f"a study directory written by `fleet sweep` holds {_RESULTS}; is {study_dir} one?",
        )
    meta = _read_study_json(study_dir / _STUDY)
    header, rows = _read_csv(results)

    missing = [c for c in _REQUIRED_COLUMNS if c not in header]
    if missing:
        raise InputError(
            str(results),
            "header",
            ",".join(header),
            f"lacks column(s) {', '.join(missing)}; needs {','.join(_REQUIRED_COLUMNS)}",
        )
    if "axes" in meta:
        axis_names = list(meta["axes"])
        absent = [a for a in axis_names if a not in header]
        if absent:
            raise InputError(
                str(results),
                "header",
                ",".join(header),
                f"lacks the axis column(s) {', '.join(absent)} that {_STUDY} lists",
            )
    else:  # axis columns sit between seed and status (the order fleet sweep writes)
        i, j = header.index("seed"), header.index("status")
        axis_names = header[i + 1 : j] if i < j else []
    axes: dict[str, list[str]] = {a: list(meta.get("axes", {}).get(a, [])) for a in axis_names}

    runs = []
    for line, row in rows:
        status = (row["status"] or "").strip()
        if status not in ("ok", "failed"):
            raise InputError(
                str(results), f"line {line}, status", row["status"], 'must be "ok" or "failed"'
            )
        params = {a: row[a] or "" for a in axis_names}
        for a, label in params.items():
            if label not in axes[a]:
                axes[a].append(label)
        good: float | None = None
        violations: dict[str, int] = {}
        if status == "ok":
            good = _number(results, line, _GOOD, row[_GOOD])
            for kind in VIOLATION_KINDS:
                column = f"violations_{kind}"
                violations[kind] = _integer(results, line, column, row[column])
        cell = row["cell"] or ""
        runs.append(
            Run(
                cell=cell,
                index=_integer(results, line, "index", row["index"]),
                seed=_integer(results, line, "seed", row["seed"]),
                params=params,
                status=status,
                error=row["error"] or "",
                run_dir=_run_dir(study_dir, cell, row["run_dir"] or ""),
                line=line,
                good_per_h=good,
                violations=violations,
            )
        )
    if not any(r.ok for r in runs):
        raise InputError(
            str(results),
            "status",
            f"{len(runs)} row(s), none ok",
            "a report needs at least one run with status ok; run the study (again) with "
            "`fleet sweep`",
        )
    seeds = meta.get("seeds") or sorted({r.seed for r in runs})
    cells = meta.get("cells", {})
    have = {r.cell for r in runs}
    return Study(
        path=study_dir,
        name=str(meta.get("name") or study_dir.name),
        axes={a: tuple(labels) for a, labels in axes.items()},
        seeds=tuple(int(s) for s in seeds),
        runs=tuple(runs),
        not_run=tuple(c for c in cells if c not in have),
        file=str(meta.get("file") or ""),
    )


def load_jobs(path: Path) -> JobStats:
    """Lead times and judged prints from one run's ``jobs.csv``.

    A lead time is ``delivered_s - released_s`` of a delivered job (non-empty ``delivered_s``);
    a judged print is a row whose ``outcome`` is good, defective or failed (defective counts
    defective and failed).

    Raises
    ------
    InputError
        The file is missing, lacks a column, or holds a time that is not a number or an outcome
        not in good/defective/failed/empty.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(str(path), "(file)", "missing", "a run directory holds jobs.csv")
    header, rows = _read_csv(path)
    missing = [c for c in _JOB_COLUMNS if c not in header]
    if missing:
        raise InputError(
            str(path),
            "header",
            ",".join(header),
            f"lacks column(s) {', '.join(missing)}; needs {','.join(_JOB_COLUMNS)}",
        )
    leads: list[float] = []
    judged = defective = 0
    jobs_released = set()
    for line, row in rows:
        when = (row["released_s"] or "").strip()
        jobs_released.add((row.get("id") or "", row.get("part") or "", when))
        if (row["delivered_s"] or "").strip():
            delivered = _number(path, line, "delivered_s", row["delivered_s"])
            released = _number(path, line, "released_s", row["released_s"])
            leads.append(delivered - released)
        outcome = (row["outcome"] or "").strip()
        if outcome:
            if outcome not in _OUTCOMES:
                raise InputError(
                    str(path),
                    f"line {line}, outcome",
                    row["outcome"],
                    f"must be one of {', '.join(_OUTCOMES)} or empty",
                )
            judged += 1
            defective += outcome != "good"
    arrivals = hashlib.sha256(repr(sorted(jobs_released)).encode()).hexdigest()[:16]
    return JobStats(tuple(leads), judged, defective, arrivals)


# -- the numbers the report shows -------------------------------------------------------------
Key = tuple[str | None, str, str | None]  # (panel, series, x)


@dataclass(frozen=True, eq=False)
class Summary:
    """Every number of the report, computed once from a `Study` (figures and text share it).

    Attributes
    ----------
    study:
        The study summarised.
    panels, series, xs:
        Labels in display order (``[None]`` for a missing panel or x axis); x labels sort
        numerically when all are numbers.
    throughput:
        (panel, series, x) -> `Interval` of good parts per hour across the ok seeds.
    lead_times:
        (panel, series, x) -> lead times (s) of delivered jobs, pooled over the ok seeds.
    defects:
        (panel, series, x) -> (defective + failed, judged) prints, pooled over the ok seeds.
    violations:
        series -> kind -> violations summed over its ok runs.
    rankings:
        The leader of every (panel, x) with data, panels then x in display order, with its
        paired differences to the other series.
    no_jobs:
        Ok cells whose run directory has no ``jobs.csv`` (left out of lead times and defects).
    samples:
        (panel, series, x) -> (seed, good parts per hour) of the ok runs, in file order.
    arrivals_checked, arrivals_differ:
        Pairs of runs of a paired difference (one seed, leader and series) whose ``jobs.csv``
        were compared for common random numbers, and those whose released jobs differ.
    target:
        The half-width asked of the intervals (`HalfWidth`).
    advice:
        For each series' mean and each difference to the leader, setting by setting: whether
        its interval meets `target` and how many seeds it needs.
    """

    study: Study
    panels: tuple[str | None, ...]
    series: tuple[str, ...]
    xs: tuple[str | None, ...]
    throughput: dict[Key, Interval]
    lead_times: dict[Key, tuple[float, ...]]
    defects: dict[Key, tuple[int, int]]
    violations: dict[str, dict[str, int]]
    rankings: tuple[Ranking, ...]
    no_jobs: tuple[str, ...]
    samples: dict[Key, tuple[tuple[int, float], ...]] = field(default_factory=dict)
    target: HalfWidth = DEFAULT_HALF_WIDTH
    advice: tuple[Advice, ...] = ()
    arrivals_checked: int = 0
    arrivals_differ: tuple[str, ...] = ()

    @property
    def differences(self) -> tuple[Difference, ...]:
        """Every difference of a leader to another series, in the order of `rankings`."""
        return tuple(d for r in self.rankings for d in r.differences.values())

    @property
    def x_values(self) -> tuple[float, ...] | None:
        """The x labels as numbers (offered jobs per hour), or None when any is not a number."""
        if self.study.x_axis is None:
            return None
        values = [_float_or_none(x) for x in self.xs]
        return None if any(v is None for v in values) else tuple(values)  # type: ignore[misc]


def summarise(
    study: Study,
    jobs: Mapping[str, JobStats | None] | None = None,
    *,
    half_width: HalfWidth = DEFAULT_HALF_WIDTH,
) -> Summary:
    """Compute the report's numbers from the ok runs of `study`.

    Parameters
    ----------
    study:
        As `load_study` returns it.
    jobs:
        Cell id -> `JobStats` (None: no ``jobs.csv``); None reads every ok run's ``jobs.csv``
        with `load_jobs` (a missing file counts as None, a malformed one raises).
    half_width:
        The half-width asked of every interval, for `Summary.advice`.

    Raises
    ------
    InputError
        A ``jobs.csv`` is malformed (see `load_jobs`).
    """
    ok = study.ok
    if jobs is None:
        jobs = {r.cell: _jobs_or_none(r) for r in ok}
    series = _ordered({study.series_of(r) for r in ok}, _series_order(study))
    panels: tuple[str | None, ...] = (None,)
    if study.panel_axis is not None:
        panels = _ordered({study.panel_of(r) for r in ok}, study.axes[study.panel_axis])
    xs: tuple[str | None, ...] = (None,)
    if study.x_axis is not None:
        xs = _ordered({study.x_of(r) for r in ok}, study.axes[study.x_axis])
        if all(_float_or_none(x) is not None for x in xs):
            xs = tuple(sorted(xs, key=lambda x: float(x)))  # type: ignore[arg-type]

    good: dict[Key, list[tuple[int, float]]] = {}
    leads: dict[Key, list[float]] = {}
    defects: dict[Key, list[int]] = {}
    violations = {s: dict.fromkeys(VIOLATION_KINDS, 0) for s in series}
    no_jobs = []
    cell_of: dict[tuple[Key, int], str] = {}
    for r in ok:
        key = (study.panel_of(r), study.series_of(r), study.x_of(r))
        cell_of[(key, r.seed)] = r.cell
        good.setdefault(key, []).append((r.seed, float(r.good_per_h)))  # type: ignore[arg-type]
        for kind, count in r.violations.items():
            violations[key[1]][kind] += count
        stats = jobs.get(r.cell)
        if stats is None:
            no_jobs.append(r.cell)
            continue
        leads.setdefault(key, []).extend(stats.lead_times_s)
        counts = defects.setdefault(key, [0, 0])
        counts[0] += stats.defective
        counts[1] += stats.judged

    # Good parts per hour cannot be negative: intervals are cut at zero.
    throughput = {
        k: mean_ci((v for _, v in pairs), bounds=NON_NEGATIVE) for k, pairs in good.items()
    }
    rankings = []
    advice = []
    checked, differ = 0, []
    for p in panels:
        for x in xs:
            here = {s: good[(p, s, x)] for s in series if (p, s, x) in good}
            if not here:
                continue
            c = compare(here, bounds=NON_NEGATIVE)
            rankings.append(Ranking(p, x, c.leader, c.runner_up, c.verdict, c.differences))
            for s in here:
                iv = throughput[(p, s, x)]
                advice.append(_advice(p, x, s, iv.n, iv.half_width, iv.sd, half_width.of(iv.mean)))
            target = half_width.of(throughput[(p, c.leader, x)].mean)
            for s, d in c.differences.items():
                if d.method is Method.PAIRED:
                    for seed in d.seeds:
                        pair = [jobs.get(cell_of[((p, name, x), seed)]) for name in (c.leader, s)]
                        if pair[0] is None or pair[1] is None:
                            continue
                        checked += 1
                        if pair[0].arrivals != pair[1].arrivals:
                            where = _setting(study, p, x)
                            differ.append(f"{where}: {c.leader} and {s}, seed {seed}")
                n = len(d.seeds) if d.method is Method.PAIRED else min(d.n_a, d.n_b)
                advice.append(_advice(p, x, f"{c.leader} − {s}", n, d.half_width, d.sd, target))
    return Summary(
        study=study,
        panels=panels,
        series=series,
        xs=xs,
        throughput=throughput,
        lead_times={k: tuple(v) for k, v in leads.items()},
        defects={k: (v[0], v[1]) for k, v in defects.items()},
        violations=violations,
        rankings=tuple(rankings),
        no_jobs=tuple(no_jobs),
        samples={k: tuple(v) for k, v in good.items()},
        target=half_width,
        advice=tuple(advice),
        arrivals_checked=checked,
        arrivals_differ=tuple(differ),
    )


def _advice(
    panel: str | None,
    x: str | None,
    series: str,
    n: int,
    hw: float | None,
    sd: float | None,
    target: float,
) -> Advice:
    """How many seeds an interval with spread `sd` needs for `target` (None: not known)."""
    needed = None if sd is None or target <= 0 else replications_needed(sd, target)
    return Advice(panel, x, series, n, hw, target, needed)


# -- figures ----------------------------------------------------------------------------------
def throughput_figure(summary: Summary) -> Figure:
    """Good parts per hour against the arrival rate: one line per series, panel per fleet size.

    Markers are means across seeds, error bars 95 % t intervals (none for one seed); series are
    nudged sideways a little so their bars do not hide each other. A dashed line marks the
    offered rate (jobs/h), the ceiling of good parts per hour. Without a numeric rate axis each
    panel shows grouped bars with the same error bars.

    Returns
    -------
    Figure
        One axes per panel; each series' errorbar line (or bar container) has gid
        ``"series:<name>"``, the offered-rate line gid ``"offered"``.
    """
    fig, axes = _panels(summary, "Good parts per hour (mean across seeds, 95 % t interval)")
    xv = summary.x_values
    colours = _colours(summary.series)
    for ax, p in zip(axes, summary.panels, strict=True):
        if xv is not None:
            span = (max(xv) - min(xv)) or 1.0
            k = len(summary.series)
            for i, s in enumerate(summary.series):
                pts = [
                    (v, summary.throughput[(p, s, x)])
                    for v, x in zip(xv, summary.xs, strict=True)
                    if (p, s, x) in summary.throughput
                ]
                if not pts:
                    continue
                dodge = 0.012 * span * (i - (k - 1) / 2)
                ax.errorbar(
                    [v + dodge for v, _ in pts],
                    [c.mean for _, c in pts],
                    yerr=_yerr([c for _, c in pts]),
                    marker="o",
                    ms=5,
                    capsize=3,
                    lw=1.4,
                    color=colours[s],
                    label=s,
                    gid=f"series:{s}",
                )
            ax.plot(xv, xv, ls="--", lw=1.0, color="0.4", label="offered rate", gid="offered")
            ax.set_xlabel(f"{RATE_AXIS} (offered jobs/h)")
        else:
            _bars(
                ax,
                summary,
                p,
                lambda key: (
                    (summary.throughput[key].mean, _yerr([summary.throughput[key]]))
                    if key in summary.throughput
                    else None
                ),
                colours,
            )
        ax.set_ylabel("good parts/h")
        ax.grid(alpha=0.3)
    # Once all panels are drawn: the panels share y, and a limit set in the loop would freeze
    # the top at the first panel's data and cut a later panel's error bars.
    axes[0].set_ylim(bottom=0)
    handles: list[Any]
    if xv is not None:
        handles = [Line2D([], [], color=colours[s], marker="o", label=s) for s in summary.series]
        handles.append(Line2D([], [], ls="--", color="0.4", label="offered rate"))
    else:
        handles = [Patch(facecolor=colours[s], label=s) for s in summary.series]
    fig.legend(handles=handles, loc="outside lower center", ncols=_legend_cols(summary.series))
    return fig


def lead_time_figure(summary: Summary) -> Figure:
    """Box plots of lead times (delivered jobs, pooled over seeds) per series and arrival rate.

    One panel per fleet size; within it one group of boxes per arrival rate, one box per series
    in the series' colour. Whiskers at 1.5 IQR; every job is also drawn as a point.

    Returns
    -------
    Figure
        One axes per panel; each drawn box's patch has gid ``"box:<series>@<x>"``.
    """
    fig, axes = _panels(summary, "Lead time of delivered jobs (released to delivered)")
    colours = _colours(summary.series)
    k = len(summary.series)
    width = 0.8 / max(k, 1)
    for ax, p in zip(axes, summary.panels, strict=True):
        drawn = False
        for j, x in enumerate(summary.xs):
            for i, s in enumerate(summary.series):
                data = summary.lead_times.get((p, s, x), ())
                if not data:
                    continue
                pos = j + (i - (k - 1) / 2) * width
                box = ax.boxplot(
                    [data],
                    positions=[pos],
                    widths=width * 0.85,
                    patch_artist=True,
                    manage_ticks=False,
                    showfliers=False,  # every job is drawn as a point below
                )
                for patch in box["boxes"]:
                    patch.set(facecolor=colours[s], alpha=0.35, gid=f"box:{s}@{x}")
                for median in box["medians"]:
                    median.set(color="black")
                # The jobs themselves, spread across the box: with a few seeds there are few
                # of them, and a box of equal values has no height to show its colour.
                spread = np.linspace(-0.25, 0.25, len(data)) * width if len(data) > 1 else [0.0]
                ax.scatter(pos + np.asarray(spread), data, s=9, color=colours[s], zorder=3, lw=0)
                drawn = True
        _group_ticks(ax, summary)
        ax.set_ylabel("lead time (s)")
        ax.grid(axis="y", alpha=0.3)
        if not drawn:
            ax.text(0.5, 0.5, "no delivered jobs", ha="center", va="center", transform=ax.transAxes)
    handles = [Patch(facecolor=colours[s], alpha=0.6, label=s) for s in summary.series]
    fig.legend(handles=handles, loc="outside lower center", ncols=_legend_cols(summary.series))
    return fig


def defects_figure(summary: Summary) -> Figure:
    """Defect rate per series and arrival rate, pooled over seeds, one panel per fleet size.

    The rate is (defective + failed prints) / judged prints from the runs' ``jobs.csv``; each
    bar is labelled ``defective/judged``; a setting without judged prints shows no bar.

    Returns
    -------
    Figure
        One axes per panel; bars as in `throughput_figure` (gid ``"series:<name>"``).
    """
    fig, axes = _panels(
        summary, "Defect rate = (defective + failed prints) / judged prints, pooled over seeds"
    )
    colours = _colours(summary.series)

    def value(key: Key) -> tuple[float, None] | None:
        bad, judged = summary.defects.get(key, (0, 0))
        return (100.0 * bad / judged, None) if judged else None

    for ax, p in zip(axes, summary.panels, strict=True):
        containers = _bars(ax, summary, p, value, colours)
        for key, bars in containers:
            bad, judged = summary.defects[key]
            ax.bar_label(bars, labels=[f"{bad}/{judged}"], fontsize=7, padding=2)
        ax.set_ylabel("defect rate (%)")
        ax.set_ylim(0, 105)
        ax.grid(axis="y", alpha=0.3)
    handles = [Patch(facecolor=colours[s], label=s) for s in summary.series]
    fig.legend(handles=handles, loc="outside lower center", ncols=_legend_cols(summary.series))
    return fig


# -- Markdown ---------------------------------------------------------------------------------
def report_markdown(summary: Summary) -> str:
    """The report's Markdown text (see the module docstring); figures linked by file name."""
    st = summary.study
    ok, failed = st.ok, st.failed
    points = {tuple(sorted(r.params.items())) for r in st.runs}
    out = [f"# Study report: {st.name}", ""]
    if st.file:
        out.append(f"Study file: `{st.file}`.")
    axes = "; ".join(f"{a} ({', '.join(labels)})" for a, labels in st.axes.items()) or "none"
    out += [
        f"{len(st.runs)} runs in `{_RESULTS}`: {len(points)} grid point(s) × seeds "
        f"{', '.join(map(str, st.seeds))}; {len(ok)} ok, {len(failed)} failed.",
        f"Axes: {axes}.",
        "Statistics use the ok runs only. Good parts per hour: the mean across seeds with its "
        "two-sided 95 % Student t interval (scipy's t quantiles, n-1 degrees of freedom), shown as "
        "± half-width, or as [low, high] where it is cut at 0 (no negative throughput); none "
        "for a single seed. Series are compared by the leader's difference to each other "
        "series, paired seed by seed where both ran the same seeds (see Comparisons).",
    ]
    if st.not_run:
        out.append(
            f"{len(st.not_run)} cell(s) listed in `{_STUDY}` have no row in `{_RESULTS}` "
            f"(not run yet): {', '.join(st.not_run)}."
        )
    if summary.no_jobs:
        shown = ", ".join(summary.no_jobs[:10]) + (", …" if len(summary.no_jobs) > 10 else "")
        out.append(
            f"{len(summary.no_jobs)} ok run(s) have no `jobs.csv` and are left out of lead "
            f"times and defect rates: {shown}."
        )

    # Every ok run lacking jobs.csv: one sentence instead of tables of dashes.
    jobs = len(summary.no_jobs) < len(ok)
    no_jobs = "No ok run has a `jobs.csv`: nothing to show."
    out += ["", "## Failed runs", ""]
    if failed:
        out += ["| cell | seed | parameters | error |", "|---|---|---|---|"]
        for r in failed:
            params = ", ".join(f"{a}={v}" for a, v in r.params.items())
            out.append(f"| {r.cell} | {r.seed} | {_md(params)} | {_md(r.error, 300) or '?'} |")
    else:
        out.append("None.")

    out += ["", "## Good parts per hour", ""]
    out += _tables(summary, lambda key: _cell(summary.throughput.get(key)), leader=True)
    out += [""] + _winners(summary)
    out += ["", "## Comparisons", ""] + _comparisons(summary)
    out += ["", "## Replications", ""] + _replications(summary)

    out += [
        "",
        "## Defect rates",
        "",
        "(defective + failed prints) / judged prints, from each ok run's `jobs.csv`, pooled "
        "over seeds.",
        "",
    ]
    out += _tables(summary, lambda key: _rate(summary.defects.get(key))) if jobs else [no_jobs]

    out += [
        "",
        "## Lead times",
        "",
        "Median of delivered_s − released_s over delivered jobs, pooled over seeds "
        "(n = delivered jobs).",
        "",
    ]
    out += _tables(summary, lambda key: _median(summary.lead_times.get(key))) if jobs else [no_jobs]

    out += ["", "## Safety violations", ""]
    total = sum(sum(v.values()) for v in summary.violations.values())
    if total == 0:
        out.append(f"None: all {len(ok)} ok runs have zero violations of every kind.")
    else:
        runs_with = sum(1 for r in ok if any(r.violations.values()))
        out += [
            f"{total} violation(s) in {runs_with} of {len(ok)} ok runs (sums over ok runs):",
            "",
            "| series | " + " | ".join(VIOLATION_KINDS) + " |",
            "|---|" + "---:|" * len(VIOLATION_KINDS),
        ]
        for s in summary.series:
            counts = summary.violations[s]
            out.append(
                f"| {_md(s)} | " + " | ".join(str(counts[k]) for k in VIOLATION_KINDS) + " |"
            )

    out += warmup_lines(r.run_dir for r in ok)  # MSER-5's suggestions (fleet.study.warmup)
    out += [
        "",
        "## Figures",
        "",
        f"![Good parts per hour]({THROUGHPUT_PNG})",
        "",
        f"![Lead times]({LEAD_TIME_PNG})",
        "",
        f"![Defect rates]({DEFECTS_PNG})",
        "",
    ]
    return "\n".join(out)


@dataclass(frozen=True)
class ReportResult:
    """What `write_report` wrote.

    Attributes
    ----------
    out_dir:
        Where the files are.
    report:
        ``report.md``.
    figures:
        ``throughput.png``, ``lead_time.png``, ``defects.png``, in this order.
    markdown:
        The text of ``report.md``.
    summary:
        The numbers behind it.
    """

    out_dir: Path
    report: Path
    figures: tuple[Path, ...]
    markdown: str
    summary: Summary

    @property
    def paths(self) -> tuple[Path, ...]:
        """Every file written: the report, then the figures."""
        return (self.report, *self.figures)


def write_report(
    study_dir: Path,
    out_dir: Path | None = None,
    *,
    half_width: HalfWidth = DEFAULT_HALF_WIDTH,
) -> ReportResult:
    """Write the study report (three PNG figures and ``report.md``) for a study directory.

    Parameters
    ----------
    study_dir:
        A directory written by `fleet sweep` (``results.csv`` required, ``study.json`` and the
        cells' ``jobs.csv`` read when present).
    out_dir:
        Where to write; None writes into `study_dir`. Created when missing.
    half_width:
        The half-width asked of every interval: the report says which need more seeds, and
        how many.

    Returns
    -------
    ReportResult
        The paths written and the Markdown text.

    Raises
    ------
    InputError
        See `load_study` and `load_jobs`.
    """
    study = load_study(Path(study_dir))
    summary = summarise(study, half_width=half_width)
    out = Path(out_dir) if out_dir is not None else study.path
    out.mkdir(parents=True, exist_ok=True)
    figures = (
        (throughput_figure(summary), out / THROUGHPUT_PNG),
        (lead_time_figure(summary), out / LEAD_TIME_PNG),
        (defects_figure(summary), out / DEFECTS_PNG),
    )
    for fig, path in figures:
        fig.savefig(path, dpi=_DPI)
    text = report_markdown(summary)
    report = out / REPORT_MD
    report.write_text(text, encoding="utf-8")
    return ReportResult(out, report, tuple(p for _, p in figures), text, summary)


# -- helpers ----------------------------------------------------------------------------------
def _read_study_json(path: Path) -> dict[str, Any]:
    """``study.json`` checked for the keys the report uses; {} when absent."""
    if not path.is_file():
        return {}
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(str(path), "(file)", str(exc), "must be valid JSON") from exc
    if not isinstance(meta, dict):
        raise InputError(str(path), "(file)", meta, "must be a JSON object")
    if "axes" in meta:
        meta["axes"] = _axes(path, meta["axes"])
    seeds = meta.get("seeds", [])
    if not isinstance(seeds, list) or not all(
        isinstance(s, int) and not isinstance(s, bool) for s in seeds
    ):
        raise InputError(str(path), "seeds", seeds, "must be a list of integers")
    if not isinstance(meta.get("cells", {}), dict):
        raise InputError(str(path), "cells", meta["cells"], "must map cell ids to their cells")
    return meta


def _axes(path: Path, axes: Any) -> dict[str, list[str]]:
    """``study.json``'s axes as name -> labels, from either layout: a list of
    ``{"name": ..., "labels": [...]}`` (what `fleet.study.sweep` writes, grid order) or a mapping
    of name -> labels."""
    rule = 'must be a list of {"name": str, "labels": [str, ...]} (or map names to labels)'
    if isinstance(axes, dict):
        axes = [{"name": k, "labels": v} for k, v in axes.items()]
    if not isinstance(axes, list):
        raise InputError(str(path), "axes", axes, rule)
    out: dict[str, list[str]] = {}
    for i, axis in enumerate(axes):
        if (
            not isinstance(axis, dict)
            or not isinstance(axis.get("name"), str)
            or not isinstance(axis.get("labels"), list)
        ):
            raise InputError(str(path), f"axes[{i}]", axis, rule)
        out[axis["name"]] = [str(label) for label in axis["labels"]]
    return out


def _read_csv(path: Path) -> tuple[list[str], list[tuple[int, dict[str, str]]]]:
    """Header and rows of a CSV file; each row with its line number (the header is line 1)."""
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            header = list(reader.fieldnames or [])
            return header, [(reader.line_num, row) for row in reader]
    except (UnicodeDecodeError, csv.Error) as exc:
        raise InputError(str(path), "(file)", str(exc), "must be UTF-8 text (CSV)") from None


def _run_dir(study_dir: Path, cell: str, recorded: str) -> Path | None:
    """The cell's run directory: the recorded path (relative to the study directory), else
    ``cells/<cell>`` (a study directory that was moved or copied)."""
    candidates = []
    if recorded.strip():
        p = Path(recorded)
        candidates.append(p if p.is_absolute() else study_dir / p)
    if cell:
        candidates.append(study_dir / "cells" / cell)
    return next((c for c in candidates if c.is_dir()), None)


def _jobs_or_none(run: Run) -> JobStats | None:
    if run.run_dir is None or not (run.run_dir / "jobs.csv").is_file():
        return None
    return load_jobs(run.run_dir / "jobs.csv")


def _number(path: Path, line: int, column: str, text: str | None) -> float:
    return csv_number(path, line, column, text, finite=True)


def _integer(path: Path, line: int, column: str, text: str | None) -> int:
    value = _number(path, line, column, text)
    if value != int(value):
        raise InputError(str(path), f"line {line}, {column}", text, "must be an integer")
    return int(value)


def _float_or_none(text: str | None) -> float | None:
    try:
        return float(text)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None


def _series_order(study: Study) -> list[str]:
    """Every series name in grid order (labels of the series axes, first axis slowest)."""
    names = [""]
    for a in study.series_axes:
        labels = [lab if a == CONTROLLER_AXIS else f"{a}={lab}" for lab in study.axes[a]]
        names = [f"{n}, {lab}" if n else lab for n in names for lab in labels]
    return [n or "all runs" for n in names]


def _ordered(found: set[Any], order: Sequence[Any]) -> tuple[Any, ...]:
    """`found` in the order of `order` (anything not in it last, as first seen is unknown)."""
    rank_of = {v: i for i, v in enumerate(order)}
    return tuple(sorted(found, key=lambda v: (rank_of.get(v, len(rank_of)), str(v))))


def _colours(series: Sequence[str]) -> dict[str, Any]:
    cmap = colormaps["tab10"].colors
    return {s: cmap[i % len(cmap)] for i, s in enumerate(series)}


def _figure(size: tuple[float, float]) -> Figure:
    fig = Figure(figsize=size, layout="constrained")
    FigureCanvasAgg(fig)  # attaches itself: savefig renders with Agg, no pyplot involved
    return fig


def _panels(summary: Summary, title: str) -> tuple[Figure, list[Axes]]:
    """A figure with one axes per panel (fleet size), up to three in a row, shared y."""
    n = len(summary.panels)
    ncols = min(3, n)
    nrows = math.ceil(n / ncols)
    # Wide enough for a two-line title and a legend of long series names below the panels.
    legend_rows = math.ceil((len(summary.series) + 1) / _legend_cols(summary.series))
    fig = _figure((max(7.5, 4.2 * ncols + 0.6), 3.4 * nrows + 1.2 + 0.25 * legend_rows))
    grid = fig.subplots(nrows, ncols, sharey=True, squeeze=False)
    axes = list(grid.ravel())
    for ax in axes[n:]:
        ax.set_visible(False)
    axis = summary.study.panel_axis
    for ax, p in zip(axes, summary.panels, strict=False):
        if p is not None:
            ax.set_title(f"{axis} = {p}", fontsize=10)
    fig.suptitle(f"{summary.study.name}\n{title}", fontsize=11)
    return fig, axes[:n]


def _legend_cols(series: Sequence[str]) -> int:
    """Legend columns under the panels: fewer when series names are long."""
    longest = max((len(s) for s in series), default=0)
    return 4 if longest <= 14 else 2 if longest <= 36 else 1


def _yerr(intervals: Sequence[Interval]) -> np.ndarray:
    """Error bars below and above each mean, as cut to the bounds (NaN: no interval)."""
    return np.array(
        [
            [np.nan, np.nan] if c.half_width is None else [c.mean - c.low, c.high - c.mean]
            for c in intervals
        ]
    ).T


def _group_ticks(ax: Axes, summary: Summary) -> None:
    ax.set_xticks(range(len(summary.xs)))
    if summary.study.x_axis is None:
        ax.set_xticklabels(["all runs"])
    else:
        ax.set_xticklabels([str(x) for x in summary.xs])
        ax.set_xlabel(summary.study.x_axis)
    ax.set_xlim(-0.6, len(summary.xs) - 0.4)


def _bars(
    ax: Axes,
    summary: Summary,
    panel: str | None,
    value: Any,
    colours: Mapping[str, Any],
) -> list[tuple[Key, Any]]:
    """Grouped bars: one group per x label, one bar per series; `value(key)` gives (height,
    error bars below and above as a 2x1 array, or None) or None for no bar. Returns (key, bar
    container) per bar."""
    k = len(summary.series)
    width = 0.8 / max(k, 1)
    drawn = []
    for i, s in enumerate(summary.series):
        for j, x in enumerate(summary.xs):
            key = (panel, s, x)
            v = value(key)
            if v is None:
                continue
            height, err = v
            bars = ax.bar(
                j + (i - (k - 1) / 2) * width,
                height,
                width * 0.9,
                yerr=err,
                capsize=3,
                color=colours[s],
                gid=f"series:{s}",
            )
            drawn.append((key, bars))
    _group_ticks(ax, summary)
    return drawn


def _tables(summary: Summary, cell: Any, *, leader: bool = False) -> list[str]:
    """One Markdown table per panel: rows are x labels, columns series (+ the leader)."""
    st = summary.study
    out: list[str] = []
    first = st.x_axis or "setting"
    for p in summary.panels:
        if p is not None:
            out += [f"### {st.panel_axis} = {p}", ""]
        head = [first, *(_md(s) for s in summary.series)] + (["highest mean"] if leader else [])
        align = "|---|" + "---:|" * len(summary.series) + ("---|" if leader else "")
        out += ["| " + " | ".join(head) + " |", align]
        for x in summary.xs:
            row = [str(x) if x is not None else "all runs"]
            row += [cell((p, s, x)) for s in summary.series]
            if leader:
                found = [r for r in summary.rankings if r.panel == p and r.x == x]
                row.append(_verdict(found[0]) if found else _NO_DATA)
            out.append("| " + " | ".join(row) + " |")
        out.append("")
    return out[:-1]


def _verdict(r: Ranking) -> str:
    if r.verdict is Verdict.ALONE:
        return f"{_md(r.leader)} (only series with ok runs)"
    if r.verdict is Verdict.CLEAR:
        return f"**{_md(r.leader)}**, clearly ahead of {_md(r.runner_up or '')}"
    if r.verdict is Verdict.EQUAL:
        return f"none: {_md(r.leader)} and {_md(r.runner_up or '')} have equal means"
    if r.verdict is Verdict.NO_INTERVAL:
        return f"{_md(r.leader)}; no interval (one seed) to compare with {_md(r.runner_up or '')}"
    tied = [s for s, d in r.differences.items() if d.low <= 0]
    return f"{_md(r.leader)}; tie with {_md(', '.join(tied))} (difference's interval reaches 0)"


def _winners(summary: Summary) -> list[str]:
    """Sentences on which series leads where, counted from the rankings."""
    compared = [r for r in summary.rankings if r.verdict is not Verdict.ALONE]
    if len(summary.series) < 2 or not compared:
        return ["One series only: nothing to compare."]
    n = len(compared)
    out = []
    for s in summary.series:
        leads = [r for r in compared if r.leader == s and r.verdict is not Verdict.EQUAL]
        if not leads:
            continue
        clear = sum(r.verdict is Verdict.CLEAR for r in leads)
        out.append(
            f"- {_md(s)} has the highest mean in {len(leads)} of {n} setting(s), clearly ahead "
            f"in {clear}."
        )
    ties = sum(r.verdict is Verdict.TIE for r in compared)
    unsure = sum(r.verdict is Verdict.NO_INTERVAL for r in compared)
    equal = sum(r.verdict is Verdict.EQUAL for r in compared)
    if equal:
        out.append(f"- {equal} of {n} setting(s) have two series with equal highest means: "
                   "no leader.")  # fmt: skip
    if ties:
        out.append(f"- {ties} of {n} setting(s) are ties: the interval of the leader's "
                   "difference to another series reaches 0.")  # fmt: skip
    if unsure:
        out.append(f"- {unsure} of {n} setting(s) have a single seed for the leader or "
                   "another series: no interval to decide.")  # fmt: skip
    out.append(
        "- Clearly ahead means the 95 % interval of the leader's difference to every other "
        "series lies above 0 (Comparisons)."
    )
    return out


def method_summary(summary: Summary) -> str:
    """One sentence naming how the comparisons were computed, e.g. ``"95 % CI, paired t on 5
    common seeds, df 4 (3 differences)"``; each distinct method with its count."""
    diffs = summary.differences
    if not diffs:
        n = max((iv.n for iv in summary.throughput.values()), default=0)
        if n <= 1:
            return "one seed per series: no intervals (run at least 2 seeds)"
        return f"{_percent()} CI of each mean (t, n-1 df); one series per setting: no differences"
    counts: dict[str, int] = {}
    for d in diffs:
        counts[d.method_text()] = counts.get(d.method_text(), 0) + 1
    return "; ".join(f"{text} ({k} difference{'s' if k > 1 else ''})" for text, k in counts.items())


def _percent() -> str:
    return f"{100 * CONFIDENCE:g} %"


def _comparisons(summary: Summary) -> list[str]:
    """The leader's difference to each other series, per setting, with the method named."""
    if not summary.differences:
        return ["One series per setting: nothing to compare."]
    st = summary.study
    paired = [d for d in summary.differences if d.method is Method.PAIRED]
    out = [
        "Leader minus each other series, good parts per hour, per setting. A seed draws the "
        "same job arrivals in every series (common random numbers), so where two series ran "
        "the same seeds the difference is taken seed by seed (paired t, n-1 df), which cancels "
        "what the seeds share; where their seeds differ (failed runs) it falls back to Welch's "
        "unpaired t with Welch-Satterthwaite df. A difference whose interval lies above 0 "
        "separates the two.",
        "",
        f"Method: {method_summary(summary)}.",
    ]
    if paired and len(paired) == len(summary.differences):
        out.append("Every comparison is paired: the series of each setting ran the same seeds.")
    else:
        out.append(
            f"{len(summary.differences) - len(paired)} of {len(summary.differences)} "
            "comparisons are not paired: their series' ok seeds differ."
        )
    if summary.arrivals_differ:
        shown = "; ".join(summary.arrivals_differ[:5])
        more = ", …" if len(summary.arrivals_differ) > 5 else ""
        out.append(
            f"Common random numbers checked in the runs' `jobs.csv`: the released jobs differ "
            f"in {len(summary.arrivals_differ)} of {summary.arrivals_checked} pairs of runs "
            f"({shown}{more}): an axis that changes the arrivals; pairing holds but cancels less."
        )
    elif summary.arrivals_checked:
        out.append(
            "Common random numbers checked in the runs' `jobs.csv`: the released jobs (id, part, "
            f"release time) are the same in all {summary.arrivals_checked} pairs of runs."
        )
    first = st.x_axis or "setting"
    for p in summary.panels:
        rows = [r for r in summary.rankings if r.panel == p and r.differences]
        if not rows:
            continue
        out.append("")
        if p is not None:
            out += [f"### {st.panel_axis} = {p}", ""]
        out += [
            f"| {first} | leader − series | difference (good parts/h) | separated | method |",
            "|---|---|---:|---|---|",
        ]
        for r in rows:
            for s, d in r.differences.items():
                sep = "–" if d.half_width is None else "yes" if d.low > 0 else "no"
                out.append(
                    f"| {r.x if r.x is not None else 'all runs'} | {_md(r.leader)} − {_md(s)} | "
                    f"{d.text()} | {sep} | {d.method_text()} |"
                )
    return out


def _replications(summary: Summary) -> list[str]:
    """Whether each interval meets the target half-width, and the seeds it needs if not."""
    target = summary.target
    out = [
        f"Target half-width: {target.text()} (for a difference: of the leader's mean); set it "
        "with `fleet report --half-width` (a share such as `5%`, or good parts/h such as `0.5`). "
        "Seeds needed: the smallest n with t(0.975, n-1) · s / √n ≤ target, s the standard "
        "deviation across seeds (of the per-seed differences, for a paired difference), found by "
        "iterating n = ⌈(t(0.975, n-1) · s / target)²⌉ until it is stable.",
        "",
    ]
    advice = summary.advice
    if all(a.n <= 1 for a in advice):
        return out + [
            "One seed: no interval and no spread to estimate how many seeds are needed; run at "
            "least 2 (`[study] seeds`)."
        ]
    short = [a for a in advice if not a.enough]
    if not short:
        return out + [f"Every interval ({len(advice)}) meets the target."]
    out += [
        f"{len(short)} of {len(advice)} intervals are wider than the target:",
        "",
        "| setting | interval | n | half-width | target | seeds needed |",
        "|---|---|---:|---:|---:|---|",
    ]
    for a in short:
        out.append(
            f"| {_md(_setting(summary.study, a.panel, a.x))} | {_md(a.series)} | {a.n} | "
            f"{_NO_DATA if a.half_width is None else f'{a.half_width:.2f}'} | "
            f"{a.target:.2f} | {_needed(a)} |"
        )
    diffs = [a.needed for a in short if a.needed is not None and " − " in a.series]
    means = [a.needed for a in short if a.needed is not None and " − " not in a.series]
    needs = []
    if diffs:
        needs.append(f"{max(diffs)} seeds for every difference to the leader")
    if means:
        needs.append(f"{max(means)} for every mean")
    if needs:
        out += [
            "",
            f"To meet the target: {' and '.join(needs)} (`[study] seeds`; `fleet sweep` into "
            "the same directory reuses the finished cells).",
        ]
    return out


def _setting(study: Study, panel: str | None, x: str | None) -> str:
    parts = []
    if panel is not None:
        parts.append(f"{study.panel_axis}={panel}")
    if x is not None:
        parts.append(f"{study.x_axis}={x}")
    return ", ".join(parts) or "all runs"


def _needed(a: Advice) -> str:
    if a.needed is not None:
        return str(a.needed)
    if a.n <= 1:
        return "unknown: one seed, no spread yet (run at least 2)"
    if a.target <= 0:
        return "unknown: the mean is 0"
    if a.half_width is not None and " − " in a.series:
        return "unknown: seeds differ (run the missing seeds to pair)"
    return "unknown"


def _cell(c: Interval | None) -> str:
    return _NO_DATA if c is None else c.text()


def _rate(counts: tuple[int, int] | None) -> str:
    if counts is None or counts[1] == 0:
        return f"{_NO_DATA} (0 judged)"
    bad, judged = counts
    return f"{100.0 * bad / judged:.0f} % ({bad}/{judged})"


def _median(values: Sequence[float] | None) -> str:
    if not values:
        return f"{_NO_DATA} (n=0)"
    return f"{float(np.median(values)):.0f} s (n={len(values)})"


def _md(text: str, limit: int | None = None) -> str:
    """`text` safe inside a Markdown table cell (one line, pipes escaped), cut to `limit`."""
    text = " ".join(str(text).split()).replace("|", "\\|")
    if limit is not None and len(text) > limit:
        text = text[: limit - 1] + "…"
    return text
