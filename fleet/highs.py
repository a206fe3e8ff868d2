"""HiGHS, configured in one place: every HiGHS object the project solves in is set up here.

Why one place. Some of HiGHS's state belongs to the process, not to an object:

- Since highspy 1.16 the thread scheduler is global and is set up by the first solve; a later
  solve that asks for another thread count fails with an error (it does not fall back). So every
  solve asks for the same `THREADS`, and nothing else in the project sets ``threads``.
- highspy 1.16 writes HiGHS's banner ("Running HiGHS ...") on stdout when the first object is
  made, before any option can silence it; the banner is written once per process. Importing this
  module writes it to nowhere first (`_silence_banner`), so no banner reaches stdout.

Every object made or adopted here (`new_highs`, `configure`) keeps HiGHS's log off the console
and routes it into a `SolverLog` (its last lines), at debug level on the ``fleet.highs`` logger.
`solve` runs an object and turns a run that is not OK into a `SolverError` carrying HiGHS's
own message, logged at warning level; the callers map the other model statuses (infeasible,
time limit, ...) to their own outcomes, so nothing that fails does so silently.
"""

from __future__ import annotations

import collections
import logging
from collections.abc import Mapping
from dataclasses import dataclass

import highspy

from fleet.errors import FleetError

__all__ = [
    "THREADS",
    "SolverError",
    "SolverLog",
    "RunResult",
    "new_highs",
    "configure",
    "solve",
    "solver_log",
]

log = logging.getLogger("fleet.highs")

#: Threads of HiGHS's scheduler, the same for every solve of the process (see the module).
#: One: the project's MILPs are small and HiGHS's branch and bound is serial, and parallel
#: study cells and fleet agents are processes, which would otherwise oversubscribe the cores.
THREADS = 1

#: Options every object gets, before the caller's own: silent on the console, log to the
#: callback (`SolverLog`), the process-wide thread count, and HiGHS's random seed fixed (its
#: default, 0, stated so that no caller moves it: with one thread and a fixed seed a solve's
#: answer depends on its inputs and its stopping rule only).
BASE_OPTIONS: Mapping[str, object] = {
    "output_flag": True,
    "log_to_console": False,
    "log_file": "",
    "threads": THREADS,
    "random_seed": 0,
}

#: Options only this module may set: a caller asking for them is a defect, caught at once.
_RESERVED = frozenset(BASE_OPTIONS)

#: Lines of HiGHS's log kept per object (enough for a failed run's own explanation).
LOG_LINES = 20


class SolverError(FleetError):
    """HiGHS refused an option, or a run ended in error; the message is HiGHS's own."""


class SolverLog:
    """The last `LOG_LINES` lines HiGHS logged for one object, also passed to ``fleet.highs``."""

    def __init__(self) -> None:
        self.lines: collections.deque[str] = collections.deque(maxlen=LOG_LINES)

    def __call__(self, event: object) -> None:
        # Runs inside HiGHS's callback: never raise (an exception here would abort the solve).
        text = str(getattr(event, "message", "")).strip()
        if text:
            self.lines.append(text)
            log.debug("%s", text)

    def problems(self) -> str:
        """HiGHS's error and warning lines so far (or its last line), one string."""
        bad = [line for line in self.lines if line.startswith(("ERROR", "WARNING"))]
        return "; ".join(bad) if bad else (self.lines[-1] if self.lines else "no message")

    def clear(self) -> None:
        self.lines.clear()


@dataclass(frozen=True, slots=True)
class RunResult:
    """How one run of HiGHS ended."""

    status: highspy.HighsModelStatus
    """HiGHS's model status."""
    has_solution: bool
    """Whether HiGHS holds a feasible primal solution (possibly not optimal)."""


def configure(h: highspy.Highs, options: Mapping[str, object] | None = None) -> SolverLog:
    """Set the project's options and then `options` on `h` (made elsewhere, e.g. by Pyomo).

    Returns the object's `SolverLog` (also kept on the object, see `solver_log`).

    Raises
    ------
    SolverError
        HiGHS refused an option (unknown name, value of the wrong type or out of range).
    ValueError
        `options` sets one of the process-wide options (``threads``, output and log options).
    """
    options = dict(options or {})
    reserved = _RESERVED.intersection(options)
    if reserved:
        raise ValueError(f"HiGHS options {sorted(reserved)} are set by fleet.highs only")
    sink = getattr(h, "_fleet_log", None)
    if sink is None:
        sink = SolverLog()
        # Subscribe before any option: HiGHS logs refusals while options are being set.
        h.cbLogging.subscribe(sink)
        h._fleet_log = sink
    for name, value in {**BASE_OPTIONS, **options}.items():
        if h.setOptionValue(name, value) != highspy.HighsStatus.kOk:
            message = f"HiGHS refused option {name} = {value!r}: {sink.problems()}"
            log.warning("%s", message)
            raise SolverError(message)
    return sink


def new_highs(options: Mapping[str, object] | None = None) -> highspy.Highs:
    """A new HiGHS object with the project's options and then `options` (see `configure`)."""
    h = highspy.Highs()
    configure(h, options)
    return h


def solver_log(h: highspy.Highs) -> SolverLog:
    """The `SolverLog` of an object set up by `configure` (an empty one for any other)."""
    return getattr(h, "_fleet_log", None) or SolverLog()


def solve(h: highspy.Highs, what: str) -> RunResult:
    """Run `h`; a run HiGHS reports as failed raises `SolverError` with HiGHS's message.

    `what` names the solve in messages ("MPC step", "lower bound T=52", ...). A run that ends
    normally but not optimal (infeasible, time limit, ...) is returned for the caller to
    handle: which of those is an outcome and which a failure depends on the caller.
    """
    sink = solver_log(h)
    sink.clear()
    status = h.run()
    model_status = h.getModelStatus()
    if status == highspy.HighsStatus.kError or model_status in _FAILED:
        message = (
            f"HiGHS failed on {what}: run {status.name}, model status "
            f"{h.modelStatusToString(model_status)!r}: {sink.problems()}"
        )
        log.warning("%s", message)
        raise SolverError(message)
    has_solution = h.getInfo().primal_solution_status == 2  # kSolutionStatusFeasible
    return RunResult(model_status, has_solution)


#: Model statuses that mean the run itself failed, whatever the model.
_FAILED = frozenset(
    {
        highspy.HighsModelStatus.kNotset,
        highspy.HighsModelStatus.kLoadError,
        highspy.HighsModelStatus.kModelError,
        highspy.HighsModelStatus.kPresolveError,
        highspy.HighsModelStatus.kSolveError,
        highspy.HighsModelStatus.kPostsolveError,
    }
)


def _silence_banner() -> None:
    """Have HiGHS write its once-per-process banner to nowhere (see the module).

    A raw object (highspy's Python wrapper makes a call that logs before any option can be
    set) with its console log off writes the banner into the void and marks it written.
    """
    raw = getattr(getattr(highspy, "_core", None), "_Highs", None)
    h = raw() if raw is not None else highspy.Highs()
    h.setOptionValue("log_to_console", False)
    h.addVars(1, [0.0], [1.0])


_silence_banner()
