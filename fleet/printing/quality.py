"""Print quality: the paper's quality-speed profiles (QSP) and a prediction of each part's error.

A MAMbot prints while it drives, and driving spoils the print in two ways this module models:

- **Speed** (the paper's QSP, case study 1): the dimensional error grows with the base's speed,
  ``q(v) = a v + b`` (mm against m/s), one line per task kind and measured axis, fitted by least
  squares to |error|. A task's profile is the *largest* of its axes' lines, because the paper
  judges a part by its largest deviation across axes.
- **Vibration** (case study 2): crossing a bump kicks the part. A kick is
  ``severity * c * exp(k * speed)`` mm at the crossing speed; a kick of ``failure_mm`` or more
  ends the print (the paper's safety warnings and AM process failure at 0.8 and 1.0 m/s).

`QualityModel.predict` judges one finished print from the robot's samples: each task's error is the
QSP at the task's (time-weighted mean) speed plus the largest kick of any rough-area crossing during
the task; the part passes when every task is within its tolerance. `default_model` fits the paper's
Table 1 and Table 2 (shipped as ``fleet/printing/data/*.csv``); `QualityModel.from_csv` fits a
user's own calibration. The model, its choices and every fitted figure are in ``docs/quality.md``.

Semantics of a sample, as in the engine: the velocity ``v[k]`` is held over ``[t_k, t_{k+1})``
and the robot moves along the straight segment ``p[k] -> p[k+1]`` meanwhile.
"""

from __future__ import annotations

import csv
import dataclasses
import functools
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import Any, Protocol

import numpy as np
import shapely

from fleet.errors import CalibrationError
from fleet.floor.spec import RoughArea
from fleet.printing import PAPER_CAPS, TASK_KINDS

__all__ = [
    "QSP",
    "TaskProfile",
    "Vibration",
    "QualityModel",
    "Outcome",
    "Crossing",
    "TaskQuality",
    "QualityPrediction",
    "RunCheck",
    "TaskLike",
    "ALL",
    "SPEED_METRICS",
    "DEFAULT_TOLERANCE_MM",
    "DEFAULT_TOLERANCES",
    "RUN_OUTCOMES",
    "fit_qsp",
    "load_calibration",
    "fit_vibration",
    "check_runs",
    "data_file",
    "default_model",
]

#: Profile key for rows that hold for every task kind (and the fallback of kinds without rows).
ALL = "all"

#: How a task's speed history becomes the one speed its QSP is read at. "mean": the
#: time-weighted mean of |v| over the task (standing still counts as 0); "max": the largest |v|.
SPEED_METRICS = ("mean", "max")

#: The paper's tolerance: +-0.05 mm in every axis, for every task kind.
DEFAULT_TOLERANCE_MM = 0.05

#: Tolerance (mm) per task kind unless configured. Nozzle travel deposits nothing, so it has no
#: tolerance of its own (its time still counts for bump crossings, which can fail the print).
DEFAULT_TOLERANCES: Mapping[str, float] = MappingProxyType(
    {kind: (math.inf if kind == "travel" else DEFAULT_TOLERANCE_MM) for kind in TASK_KINDS}
)

#: Outcomes a run may have in a vibration calibration file (``table2_runs.csv``).
RUN_OUTCOMES = ("pass", "defect", "fail")
#: A motion step must reach this far (m) into a rough area to cross it: closer to the edge is
#: rounding of a step that ends on it.
EDGE_MARGIN_M = 1e-6

_CALIBRATION_REQUIRED = ("speed_mps", "error_mm")
_CALIBRATION_OPTIONAL = ("task", "axis", "sample")
_RUNS_COLUMNS = (
    "run",
    "speed_mps",
    "crossing_mps",
    "distance_m",
    "turn_rad",
    "print_s",
    "outcome",
)
_ERRORS_COLUMNS = ("run", "sample", "axis", "error_mm")


class Outcome(StrEnum):
    """What became of a print. A `StrEnum`: it compares equal to, and serialises as, its value."""

    GOOD = "good"
    """Every task's predicted error is within its tolerance."""
    DEFECTIVE = "defective"
    """The print finished, but at least one task's error exceeds its tolerance."""
    FAILED = "failed"
    """A rough-area crossing kicked the part by ``failure_mm`` or more: the print was lost."""


# Paper outcome words (table2_runs.csv) -> the model's outcomes.
_RUN_OUTCOME = {"pass": Outcome.GOOD, "defect": Outcome.DEFECTIVE, "fail": Outcome.FAILED}


class TaskLike(Protocol):
    """Anything with a print task's kind and absolute times (`fleet.printing.PrintTask` fits)."""

    @property
    def kind(self) -> str: ...
    @property
    def start_s(self) -> float: ...
    @property
    def end_s(self) -> float: ...


# -- profiles ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class QSP:
    """One quality-speed line, ``q(v) = a v + b``: predicted |error| (mm) at base speed v (m/s)."""

    a: float
    b: float

    def error(self, v: float | np.ndarray) -> float | np.ndarray:
        """Predicted error (mm) at speed `v` (m/s), never below 0 (a falling line fitted to
        a user's data must not predict negative errors at speed); elementwise for arrays."""
        return np.maximum(self.a * v + self.b, 0.0) if np.ndim(v) else max(self.a * v + self.b, 0.0)

    def max_speed(self, tol: float) -> float:
        """The largest speed v >= 0 such that the error stays within `tol` all over ``[0, v]``.

        A cap, not a root: standing still must be acceptable too. Returns 0 when even standing
        still exceeds `tol` (``b > tol``) and ``inf`` when the error never grows past `tol`
        (slope <= 0 and ``b <= tol``).
        """
        tol = _check_tolerance(tol)
        if self.b > tol:
            return 0.0
        if self.a <= 0.0:
            return math.inf
        return (tol - self.b) / self.a


@dataclass(frozen=True)
class TaskProfile:
    """A task kind's QSP: one line per measured axis; the task's error is their largest.

    ``error(v) = max over axes (a_axis v + b_axis)``, the paper's "largest deviation across
    axes". Being a maximum of lines it is convex, so it stays within a tolerance over ``[0, v]``
    exactly when it does at both ends; `max_speed` relies on that.
    """

    lines: Mapping[str, QSP]

    def __post_init__(self) -> None:
        if not self.lines:
            raise ValueError("a TaskProfile needs at least one line")
        object.__setattr__(self, "lines", MappingProxyType(dict(self.lines)))

    def error(self, v: float | np.ndarray) -> float | np.ndarray:
        """Predicted error (mm) at speed `v` (m/s): the largest of the axes' lines."""
        if np.ndim(v) == 0:
            return max(float(line.error(float(v))) for line in self.lines.values())
        return np.max([line.error(np.asarray(v, dtype=float)) for line in self.lines.values()], 0)

    def max_speed(self, tol: float) -> float:
        """The largest speed v >= 0 with the error within `tol` over ``[0, v]`` (see `QSP`)."""
        return min(line.max_speed(tol) for line in self.lines.values())

    def worst_axis(self, v: float) -> str:
        """The axis whose line is largest at speed `v` (the one that sets the error)."""
        return max(self.lines, key=lambda axis: float(self.lines[axis].error(v)))


def fit_qsp(speeds: Sequence[float] | np.ndarray, errors: Sequence[float] | np.ndarray) -> QSP:
    """Fit ``|error| = a v + b`` by ordinary least squares (closed form).

    Parameters
    ----------
    speeds:
        Base speeds (m/s), one per measurement; at least two distinct values.
    errors:
        Signed dimensional errors (mm); the fit is to their magnitude.

    Raises
    ------
    ValueError
        Lengths differ, a value is not finite, or fewer than two distinct speeds.

    Examples
    --------
    >>> fit_qsp([0.0, 1.0, 2.0], [0.5, -1.0, 1.5])
    QSP(a=0.5, b=0.5)
    """
    x = np.asarray(speeds, dtype=float)
    y = np.abs(np.asarray(errors, dtype=float))
    if x.shape != y.shape or x.ndim != 1:
        raise ValueError(f"speeds {x.shape} and errors {y.shape} must be 1-D of the same length")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("speeds and errors must be finite numbers")
    if np.unique(x).size < 2:
        raise ValueError(f"a line needs at least 2 distinct speeds, got {sorted(set(x.tolist()))}")
    dx = x - x.mean()
    a = float(dx @ (y - y.mean()) / (dx @ dx))
    return QSP(a, float(y.mean() - a * x.mean()))


# -- vibration --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Vibration:
    """What crossing rough floor does to a part.

    A crossing at speed s (m/s) of an area of severity w kicks the part by
    ``w * coef_mm * exp(rate_per_mps * s)`` mm; a kick of `failure_mm` or more fails the print.
    """

    coef_mm: float
    rate_per_mps: float
    failure_mm: float

    def __post_init__(self) -> None:
        if not (math.isfinite(self.coef_mm) and self.coef_mm >= 0):
            raise ValueError(f"Vibration.coef_mm = {self.coef_mm!r}: must be a number >= 0")
        if not math.isfinite(self.rate_per_mps):
            raise ValueError(f"Vibration.rate_per_mps = {self.rate_per_mps!r}: must be finite")
        if not self.failure_mm > 0:
            raise ValueError(f"Vibration.failure_mm = {self.failure_mm!r}: must be > 0 (or inf)")

    def kick(self, speed: float, severity: float = 1.0) -> float:
        """The error (mm) one crossing at `speed` (m/s) of an area of `severity` adds."""
        return float(severity * self.coef_mm * math.exp(self.rate_per_mps * speed))


@dataclass(frozen=True)
class RunCheck:
    """One run of a vibration calibration (the paper's Table 2) against the fitted model.

    Measured figures are NaN for failed runs (no part survived to be measured).
    """

    run: str
    outcome: str
    """The paper's outcome: "pass", "defect" or "fail"."""
    speed_mps: float
    """The run's nominal (top) speed."""
    crossing_mps: float
    mean_speed: float
    """distance_m / print_s: what the "mean" speed metric reads the QSP at."""
    measured_mm: float
    """Worst |error| over samples and axes."""
    qsp_mm: float
    """The QSP at the mean speed."""
    residual_mm: float
    """measured_mm - qsp_mm: what the vibration fit explains."""
    kick_mm: float
    """The fitted kick at the crossing speed (severity 1)."""
    predicted_mm: float
    """qsp_mm + kick_mm."""
    predicted: Outcome
    """The model's outcome with the "mean" metric."""
    predicted_mm_max: float
    """QSP at the top speed + kick: what the "max" speed metric would predict."""
    predicted_max: Outcome
    """The model's outcome with the "max" metric."""


@dataclass(frozen=True)
class _Run:
    run: str
    row: int
    speed: float
    crossing: float
    distance: float
    print_s: float
    outcome: str
    worst: float  # NaN for failed runs


def fit_vibration(
    runs_csv: str | os.PathLike[str], errors_csv: str | os.PathLike[str], profile: TaskProfile
) -> Vibration:
    """Fit the vibration model to a bump experiment (the paper's Table 2; bumps of severity 1).

    For each surviving run (outcome pass/defect) the residual is its worst |error| minus
    ``profile.error(distance_m / print_s)`` (the QSP at the run's mean speed). Then
    ``ln(residual) = ln c + k * crossing_mps`` is fitted by least squares over the runs with a
    positive residual, and ``failure_mm`` is the geometric mean of the largest error measured on
    a surviving part and the smallest kick the fit predicts for a failed run: between "it
    survived" and "it failed". Without failed runs nothing is known to fail: ``failure_mm`` is
    ``inf``.

    Parameters
    ----------
    runs_csv:
        Columns ``run, speed_mps, crossing_mps, distance_m, turn_rad, print_s, outcome``;
        outcome in ``pass/defect/fail``; failed runs may leave distance and turn empty.
    errors_csv:
        Columns ``run, sample, axis, error_mm``: the measurements of surviving runs' parts.
    profile:
        The QSP that explains the speed part of each error (the Table 1 ``all`` profile).

    Raises
    ------
    CalibrationError
        A file is missing or malformed, or fewer than two distinct crossing speeds have a
        positive residual.
    """
    runs = _load_runs(runs_csv, errors_csv)
    xs, ys = [], []
    for r in runs:
        if r.outcome == "fail":
            continue
        residual = r.worst - float(profile.error(r.distance / r.print_s))
        if residual > 0:
            xs.append(r.crossing)
            ys.append(math.log(residual))
    if len(set(xs)) < 2:
        raise CalibrationError(
            str(runs_csv),
            "column crossing_mps",
            sorted(set(xs)),
            "the fit needs surviving runs at 2 or more distinct crossing speeds whose worst "
            "error exceeds the QSP at their mean speed",
        )
    x, y = np.array(xs), np.array(ys)
    dx = x - x.mean()
    rate = float(dx @ (y - y.mean()) / (dx @ dx))
    coef = float(math.exp(y.mean() - rate * x.mean()))
    failed = [r.crossing for r in runs if r.outcome == "fail"]
    if failed:
        worst_survived = max(r.worst for r in runs if r.outcome != "fail")
        smallest_fatal = coef * math.exp(rate * min(failed))
        failure = math.sqrt(worst_survived * smallest_fatal)
    else:
        failure = math.inf
    return Vibration(coef, rate, failure)


def check_runs(
    model: QualityModel,
    runs_csv: str | os.PathLike[str] | None = None,
    errors_csv: str | os.PathLike[str] | None = None,
    kind: str = ALL,
) -> tuple[RunCheck, ...]:
    """What `model` says about each run of a bump experiment, from its summary figures alone.

    Each run is reduced to its mean speed (distance / print time), its top speed and its
    crossing speed (severity 1); the prediction is the QSP of `kind` at the mean (or top) speed
    plus one kick, judged against ``model.tolerance(kind)`` and ``failure_mm``. Defaults to the
    shipped Table 2 files.
    """
    runs_csv = runs_csv if runs_csv is not None else data_file("table2_runs.csv")
    errors_csv = errors_csv if errors_csv is not None else data_file("table2.csv")
    profile, tol, vib = model.profile(kind), model.tolerance(kind), model.vibration
    out = []
    for r in _load_runs(runs_csv, errors_csv):
        mean = r.distance / r.print_s if r.outcome != "fail" else math.nan
        kick = vib.kick(r.crossing)
        qsp = float(profile.error(mean)) if r.outcome != "fail" else math.nan
        q_top = float(profile.error(r.speed))
        predicted = _judge(qsp + kick if r.outcome != "fail" else math.nan, kick, tol, vib)
        out.append(
            RunCheck(
                run=r.run,
                outcome=r.outcome,
                speed_mps=r.speed,
                crossing_mps=r.crossing,
                mean_speed=mean,
                measured_mm=r.worst,
                qsp_mm=qsp,
                residual_mm=r.worst - qsp,
                kick_mm=kick,
                predicted_mm=qsp + kick,
                predicted=predicted,
                predicted_mm_max=q_top + kick,
                predicted_max=_judge(q_top + kick, kick, tol, vib),
            )
        )
    return tuple(out)


def _judge(error: float, kick: float, tol: float, vib: Vibration) -> Outcome:
    if kick >= vib.failure_mm:
        return Outcome.FAILED
    return Outcome.GOOD if error <= tol else Outcome.DEFECTIVE


# -- the model --------------------------------------------------------------------------------
@dataclass(frozen=True)
class Crossing:
    """One pass over a rough area: a maximal run of motion segments that intersect it."""

    area: str
    start_s: float
    """Start of the first segment touching the area."""
    end_s: float
    """End of the last one."""
    speed: float
    """The largest |v| over those segments (m/s)."""
    severity: float
    kick_mm: float


@dataclass(frozen=True)
class TaskQuality:
    """The predicted quality of one print task."""

    kind: str
    start_s: float
    end_s: float
    speed: float
    """The speed the QSP is read at (m/s): the task's mean or max |v| (`speed_metric`)."""
    qsp_mm: float
    vibration_mm: float
    """The largest kick of any crossing overlapping the task (0 if none)."""
    error_mm: float
    """qsp_mm + vibration_mm."""
    tolerance_mm: float
    passed: bool


@dataclass(frozen=True)
class QualityPrediction:
    """The predicted quality of one print: its tasks, its crossings and the verdict."""

    error_mm: float
    """The largest error of a judged task (one with a finite tolerance; 0 when none is):
    the skirt's or the nozzle travel's error does not describe the part."""
    outcome: Outcome
    passed: bool
    """True exactly when the outcome is good."""
    tasks: tuple[TaskQuality, ...] = ()
    crossings: tuple[Crossing, ...] = ()
    """Every rough-area crossing during the print, in time order."""


@dataclass(frozen=True)
class QualityModel:
    """Quality-speed profiles, tolerances and vibration: everything needed to judge a print.

    Parameters
    ----------
    profiles:
        `TaskProfile` per task kind and/or ``"all"``; a kind without its own profile uses
        ``"all"`` (and, if there is none, the strictest of all lines given: the maximum over
        every profile's lines).
    tolerances:
        Tolerance (mm) per task kind; kinds not given take `DEFAULT_TOLERANCES` (0.05 mm, travel
        ``inf``), kinds unknown there 0.05 mm.
    vibration:
        The rough-floor model.
    speed_metric:
        "mean" (default) or "max": see `SPEED_METRICS`.
    """

    profiles: Mapping[str, TaskProfile]
    tolerances: Mapping[str, float] = field(default_factory=lambda: DEFAULT_TOLERANCES)
    vibration: Vibration = field(default_factory=lambda: Vibration(0.0, 0.0, math.inf))
    speed_metric: str = "mean"

    def __post_init__(self) -> None:
        if not self.profiles:
            raise ValueError("a QualityModel needs at least one profile")
        if self.speed_metric not in SPEED_METRICS:
            raise ValueError(
                f"speed_metric = {self.speed_metric!r}: must be one of {', '.join(SPEED_METRICS)}"
            )
        for kind, tol in self.tolerances.items():
            _check_tolerance(tol, f"tolerance of {kind!r}")
        object.__setattr__(self, "profiles", MappingProxyType(dict(self.profiles)))
        object.__setattr__(
            self, "tolerances", MappingProxyType({k: float(v) for k, v in self.tolerances.items()})
        )

    @classmethod
    def from_csv(
        cls,
        path: str | os.PathLike[str],
        tolerances: Mapping[str, float] | None = None,
        vibration: Vibration | None = None,
        speed_metric: str = "mean",
    ) -> QualityModel:
        """A model fitted to a user's calibration CSV (format: `load_calibration`).

        The vibration model defaults to the paper's (`default_model().vibration`): a QSP
        calibration says nothing about bumps.
        """
        return cls(
            load_calibration(path),
            DEFAULT_TOLERANCES if tolerances is None else tolerances,
            default_model().vibration if vibration is None else vibration,
            speed_metric,
        )

    def profile(self, kind: str) -> TaskProfile:
        """The profile that judges `kind`: its own, else ``"all"``, else the strictest."""
        if kind in self.profiles:
            return self.profiles[kind]
        if ALL in self.profiles:
            return self.profiles[ALL]
        return TaskProfile(
            {
                f"{k}/{axis}": line
                for k, p in self.profiles.items()
                for axis, line in p.lines.items()
            }
        )

    def tolerance(self, kind: str) -> float:
        """The tolerance (mm) of `kind`."""
        if kind in self.tolerances:
            return self.tolerances[kind]
        return DEFAULT_TOLERANCES.get(kind, DEFAULT_TOLERANCE_MM)

    def kinds(self) -> tuple[str, ...]:
        """Every task kind the model knows of: `TASK_KINDS`, then others it has figures for."""
        extra = sorted((set(self.profiles) | set(self.tolerances)) - set(TASK_KINDS) - {ALL})
        return (*TASK_KINDS, *extra)

    def caps(self, tolerances: Mapping[str, float] | None = None) -> dict[str, float]:
        """The speed cap (m/s) per task kind: the fastest speed that keeps it within tolerance.

        `tolerances` overrides the model's for the kinds it names.
        """
        tols = {} if tolerances is None else dict(tolerances)
        return {
            kind: self.profile(kind).max_speed(tols.get(kind, self.tolerance(kind)))
            for kind in self.kinds()
        }

    def implied_tolerances(self, caps: Mapping[str, float] = PAPER_CAPS) -> dict[str, float]:
        """The tolerance (mm) per kind that would make `caps` its speed caps: ``q_kind(cap)``.

        With Table 1 this shows what the paper's caps (contour 0.3, infill 0.5, support
        0.7 m/s) mean in millimetres.
        """
        return {kind: float(self.profile(kind).error(cap)) for kind, cap in caps.items()}

    def predict(
        self,
        tasks: Iterable[TaskLike],
        t: np.ndarray,
        xy: np.ndarray,
        v: np.ndarray,
        rough_areas: Sequence[RoughArea] = (),
    ) -> QualityPrediction:
        """Judge one finished print from the robot's samples.

        Parameters
        ----------
        tasks:
            The print's tasks with `kind`, `start_s`, `end_s` in absolute simulation seconds.
        t, xy, v:
            The robot's samples: times (n,), positions (n, 2), velocities (n, 2); ``v[k]`` is
            held over ``[t_k, t_{k+1})`` (the last one until the print ends). Samples may extend
            beyond the print: only its span ``[first start, last end)`` counts. Time a task
            spends before ``t[0]`` is not covered and does not count.
        rough_areas:
            The floor's rough areas (bumps, slow areas).

        Returns
        -------
        QualityPrediction
            Per task: speed (mean or max |v| per `speed_metric`), QSP error, vibration (largest
            kick of a crossing overlapping the task), error, tolerance, pass. The print fails
            when any crossing kicks ``failure_mm`` or more; else it is good when every task
            passes, defective otherwise. A print without tasks is good with error 0.

        Raises
        ------
        ValueError
            Arrays of the wrong shape, times decreasing, or a task ending before it starts.
        """
        task_list = list(tasks)
        for i, task in enumerate(task_list):
            if not task.end_s >= task.start_s:
                raise ValueError(
                    f"print task {i} ({task.kind}): end_s {task.end_s!r} must not be before "
                    f"start_s {task.start_s!r}"
                )
        if not task_list:
            return QualityPrediction(0.0, Outcome.GOOD, True)
        t, xy, v = _samples(t, xy, v)
        span0 = min(task.start_s for task in task_list)
        span1 = max(task.end_s for task in task_list)
        speeds = np.hypot(v[:, 0], v[:, 1])
        crossings = self._crossings(t, xy, speeds, rough_areas, span0, span1)

        judged = []
        for task in task_list:
            speed = _task_speed(t, speeds, task.start_s, task.end_s, self.speed_metric)
            qsp = float(self.profile(task.kind).error(speed))
            kicks = [
                c.kick_mm for c in crossings if c.start_s < task.end_s and c.end_s > task.start_s
            ]
            vib = max(kicks, default=0.0)
            tol = self.tolerance(task.kind)
            error = qsp + vib
            judged.append(
                TaskQuality(
                    task.kind,
                    float(task.start_s),
                    float(task.end_s),
                    speed,
                    qsp,
                    vib,
                    error,
                    tol,
                    error <= tol,
                )
            )
        if any(c.kick_mm >= self.vibration.failure_mm for c in crossings):
            outcome = Outcome.FAILED
        elif all(task.passed for task in judged):
            outcome = Outcome.GOOD
        else:
            outcome = Outcome.DEFECTIVE
        return QualityPrediction(
            max(
                (task.error_mm for task in judged if math.isfinite(task.tolerance_mm)), default=0.0
            ),
            outcome,
            outcome is Outcome.GOOD,
            tuple(judged),
            crossings,
        )

    def _crossings(
        self,
        t: np.ndarray,
        xy: np.ndarray,
        speeds: np.ndarray,
        rough_areas: Sequence[RoughArea],
        span0: float,
        span1: float,
    ) -> tuple[Crossing, ...]:
        if len(t) < 2 or not rough_areas:
            return ()
        # Segment k joins p[k] to p[k+1] over [t_k, t_{k+1}); only those within the print count.
        in_span = (t[:-1] < span1) & (t[1:] > span0)
        idx = np.flatnonzero(in_span)
        if idx.size == 0:
            return ()
        # Segments, not points: at 1 m/s and 0.25 s steps the robot jumps 25 cm, so a 10 cm
        # bump can lie between two samples.
        segments = shapely.linestrings(np.stack([xy[idx], xy[idx + 1]], axis=1))
        found = []
        for area in rough_areas:
            # Touching the edge is not crossing: a step that ends on the area's boundary, up to
            # rounding, was driven outside it (the path layer's chords keep to the limits of
            # the regions they enter, with the same margin).
            core = area.polygon.buffer(-EDGE_MARGIN_M)
            hit = shapely.intersects(segments, core) & ~shapely.touches(segments, core)
            for first, last in _runs(idx, hit):
                speed = float(speeds[first : last + 1].max())
                found.append(
                    Crossing(
                        area.name,
                        float(t[first]),
                        float(t[last + 1]),
                        speed,
                        float(area.severity),
                        self.vibration.kick(speed, area.severity),
                    )
                )
        found.sort(key=lambda c: (c.start_s, c.area))
        return tuple(found)


def _samples(t: Any, xy: Any, v: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    t = np.asarray(t, dtype=float).reshape(-1)
    xy = np.asarray(xy, dtype=float)
    v = np.asarray(v, dtype=float)
    n = t.shape[0]
    if xy.shape != (n, 2) or v.shape != (n, 2):
        raise ValueError(
            f"samples: t has {n} entries, so xy and v must be ({n}, 2); got {xy.shape}, {v.shape}"
        )
    if n > 1 and np.any(np.diff(t) < 0):
        raise ValueError("samples: times t must not decrease")
    return t, xy, v


def _task_speed(t: np.ndarray, speeds: np.ndarray, start: float, end: float, metric: str) -> float:
    """Mean (time-weighted) or max |v| over ``[start, end)``; 0 when no sample covers it."""
    if t.size == 0:
        return 0.0
    t_next = np.append(t[1:], math.inf)
    overlap = np.minimum(end, t_next) - np.maximum(start, t)
    covered = overlap > 0
    if not covered.any():
        # A zero-length task, or one before the first sample: the speed in force at its start.
        k = int(np.searchsorted(t, start, side="right")) - 1
        return float(speeds[k]) if k >= 0 else 0.0
    if metric == "max":
        return float(speeds[covered].max())
    w = overlap[covered]
    return float(w @ speeds[covered] / w.sum())


def _runs(idx: np.ndarray, hit: np.ndarray) -> list[tuple[int, int]]:
    """Maximal runs of consecutive sample indices among ``idx[hit]``, as (first, last)."""
    chosen = idx[hit]
    if chosen.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(chosen) != 1)
    firsts = np.concatenate([[0], breaks + 1])
    lasts = np.concatenate([breaks, [chosen.size - 1]])
    return [(int(chosen[a]), int(chosen[b])) for a, b in zip(firsts, lasts, strict=True)]


def _check_tolerance(tol: float, what: str = "tolerance") -> float:
    tol = float(tol)
    if math.isnan(tol) or tol < 0:
        raise ValueError(f"{what} = {tol!r}: must be a number of mm >= 0 (or inf)")
    return tol


# -- calibration files ------------------------------------------------------------------------
def load_calibration(path: str | os.PathLike[str]) -> dict[str, TaskProfile]:
    """Fit one QSP line per (task, axis) of a calibration CSV; return a profile per task.

    The file has a header and one measurement per row. Columns: ``speed_mps`` (>= 0) and
    ``error_mm`` (signed; the fit is to |error|) are required; ``task`` (a kind of
    `fleet.printing.TASK_KINDS` or ``all``, the default), ``axis`` (free text, default ``all``)
    and ``sample`` (free text, not used by the fit) are optional. Keys of the result are the
    tasks present (kinds and/or ``"all"``).

    Raises
    ------
    CalibrationError
        Naming the file, the row (numbered as in a spreadsheet: the header is row 1), the
        column and the value: a missing file, a missing or unknown column, a value that is not
        a number, a negative speed, an unknown task, or fewer than two distinct speeds for a
        (task, axis).
    """
    source = str(path)
    rows = _read_csv(path, _CALIBRATION_REQUIRED, _CALIBRATION_OPTIONAL)
    groups: dict[tuple[str, str], list[tuple[int, float, float]]] = {}
    for row, cells in rows:
        speed = _number(source, row, "speed_mps", cells["speed_mps"], "a speed in m/s >= 0", 0.0)
        error = _number(source, row, "error_mm", cells["error_mm"], "an error in mm")
        task = cells.get("task", "").strip().lower() or ALL
        if task != ALL and task not in TASK_KINDS:
            raise CalibrationError(
                source,
                f"row {row} column task",
                cells["task"],
                f"must be one of {', '.join(TASK_KINDS)} or {ALL} (or empty for {ALL})",
            )
        axis = cells.get("axis", "").strip() or ALL
        groups.setdefault((task, axis), []).append((row, speed, error))

    lines: dict[str, dict[str, QSP]] = {}
    for (task, axis), points in groups.items():
        speeds = [p[1] for p in points]
        if len(set(speeds)) < 2:
            raise CalibrationError(
                source,
                f"column speed_mps (task {task}, axis {axis}: rows "
                f"{', '.join(str(p[0]) for p in points)})",
                sorted(set(speeds)),
                "a line needs measurements at 2 or more distinct speeds per (task, axis); add "
                "rows at another speed",
            )
        lines.setdefault(task, {})[axis] = fit_qsp(speeds, [p[2] for p in points])
    return {task: TaskProfile(by_axis) for task, by_axis in lines.items()}


def _load_runs(runs_csv: str | os.PathLike[str], errors_csv: str | os.PathLike[str]) -> list[_Run]:
    src, esrc = str(runs_csv), str(errors_csv)
    runs: dict[str, _Run] = {}
    for row, cells in _read_csv(runs_csv, _RUNS_COLUMNS, ()):
        name = cells["run"]
        if not name:
            raise CalibrationError(src, f"row {row} column run", name, "must name the run")
        if name in runs:
            raise CalibrationError(
                src, f"row {row} column run", name, f"duplicates row {runs[name].row}"
            )
        outcome = cells["outcome"].lower()
        if outcome not in RUN_OUTCOMES:
            raise CalibrationError(
                src, f"row {row} column outcome", cells["outcome"], f"must be one of {RUN_OUTCOMES}"
            )
        survived = outcome != "fail"
        speed = _number(src, row, "speed_mps", cells["speed_mps"], "a speed in m/s >= 0", 0.0)
        crossing = _number(
            src, row, "crossing_mps", cells["crossing_mps"], "a speed in m/s >= 0", 0.0
        )
        distance = print_s = math.nan
        if survived:
            distance = _number(
                src, row, "distance_m", cells["distance_m"], "a distance in m >= 0", 0.0
            )
            print_s = _number(src, row, "print_s", cells["print_s"], "a time in s > 0", 0.0)
            if print_s == 0:
                raise CalibrationError(
                    src, f"row {row} column print_s", cells["print_s"], "must be a time in s > 0"
                )
        runs[name] = _Run(name, row, speed, crossing, distance, print_s, outcome, math.nan)

    worst: dict[str, float] = {}
    for row, cells in _read_csv(errors_csv, _ERRORS_COLUMNS, ()):
        name = cells["run"]
        if name not in runs:
            raise CalibrationError(
                esrc, f"row {row} column run", name, f"must be a run of {src}: {sorted(runs)}"
            )
        if runs[name].outcome == "fail":
            raise CalibrationError(
                esrc,
                f"row {row} column run",
                name,
                f"is a failed run in {src}: a failed print has no measured part",
            )
        error = _number(esrc, row, "error_mm", cells["error_mm"], "an error in mm")
        worst[name] = max(worst.get(name, 0.0), abs(error))
    out = []
    for r in runs.values():
        if r.outcome != "fail" and r.run not in worst:
            raise CalibrationError(
                esrc, "column run", r.run, f"the surviving run of {src} row {r.row} needs rows"
            )
        out.append(dataclasses.replace(r, worst=worst.get(r.run, math.nan)))
    return out


def _read_csv(
    path: str | os.PathLike[str], required: Sequence[str], optional: Sequence[str]
) -> list[tuple[int, dict[str, str]]]:
    """Rows as (spreadsheet row number, {column: stripped text}); blank rows skipped."""
    source = str(path)
    allowed = f"columns {', '.join(required)}" + (
        f" (optional: {', '.join(optional)})" if optional else ""
    )
    try:
        with open(path, newline="", encoding="utf-8-sig") as f:
            reader = csv.reader(f)
            header: list[str] | None = None
            rows = []
            for cells in reader:
                if not any(c.strip() for c in cells):
                    continue
                if header is None:
                    header = [c.strip().lower() for c in cells]
                    _check_header(source, header, required, optional, allowed)
                    continue
                if len(cells) > len(header):
                    raise CalibrationError(
                        source,
                        f"row {reader.line_num}",
                        cells,
                        f"has {len(cells)} cells but the header has {len(header)} columns",
                    )
                padded = [c.strip() for c in cells] + [""] * (len(header) - len(cells))
                rows.append((reader.line_num, dict(zip(header, padded, strict=True))))
    except FileNotFoundError:
        raise CalibrationError(
            source, "(file)", source, f"no such file: give the path of a CSV with {allowed}"
        ) from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise CalibrationError(
            source, "(file)", source, f"is not a UTF-8 CSV file ({exc}); expected {allowed}"
        ) from None
    if header is None:
        raise CalibrationError(
            source, "(file)", source, f"is empty; expected a header with {allowed}"
        )
    if not rows:
        raise CalibrationError(source, "(file)", source, "has a header but no rows of data")
    return rows


def _check_header(
    source: str, header: list[str], required: Sequence[str], optional: Sequence[str], allowed: str
) -> None:
    missing = [c for c in required if c not in header]
    if missing:
        raise CalibrationError(
            source, "header (row 1)", header, f"misses {', '.join(missing)}: needs {allowed}"
        )
    unknown = [c for c in header if c not in required and c not in optional]
    if unknown:
        raise CalibrationError(
            source, "header (row 1)", header, f"has unknown {', '.join(unknown)}: allowed {allowed}"
        )
    duplicated = sorted({c for c in header if header.count(c) > 1})
    if duplicated:
        raise CalibrationError(
            source, "header (row 1)", header, f"repeats {', '.join(duplicated)}: name each once"
        )


def _number(
    source: str, row: int, column: str, text: str, what: str, minimum: float | None = None
) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or (minimum is not None and value < minimum):
        raise CalibrationError(source, f"row {row} column {column}", text, f"must be {what}")
    return value


# -- the paper's calibration ------------------------------------------------------------------
def data_file(name: str) -> Path:
    """Path of a data file shipped in ``fleet/printing/data`` (e.g. ``"table1.csv"``)."""
    return Path(str(resources.files("fleet.printing") / "data" / name))


@functools.lru_cache(maxsize=1)
def default_model() -> QualityModel:
    """The paper's model: Table 1's QSP, Table 2's vibration, 0.05 mm tolerances, mean speed.

    Fitted on first use from the shipped CSVs (a few milliseconds) and cached; the model is
    immutable, so sharing it is safe.
    """
    profiles = load_calibration(data_file("table1.csv"))
    vibration = fit_vibration(data_file("table2_runs.csv"), data_file("table2.csv"), profiles[ALL])
    return QualityModel(profiles, DEFAULT_TOLERANCES, vibration, "mean")
