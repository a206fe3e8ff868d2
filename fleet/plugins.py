"""Plugin contracts (controllers, dispatchers) and their discovery through entry points.

A plugin is a class registered under an entry-point group in its distribution's
``pyproject.toml``; the built-in ones in ``plugins/`` register exactly the same way::

    [project.entry-points."fleet.controllers"]
    my_controller = "my_package.module:MyController"

    [project.entry-points."fleet.dispatchers"]
    my_dispatcher = "my_package.module:MyDispatcher"

The class is instantiated with the keyword options from the scenario
(``[controller.options]`` / ``[dispatcher.options]``).

Data flows one way: the engine builds an `Observation` per robot per control tick, sends it
over the bus to the robot's agent, whose `Controller` answers with a `Command`. Dispatchers run
in the engine and turn open `Job`s and `RobotStatus`es into `Assignment`s.
"""

from __future__ import annotations

import enum
import importlib
import importlib.metadata
import sys
import threading
import warnings
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, ClassVar

from fleet.auction import estimate_completion
from fleet.errors import PluginError

if TYPE_CHECKING:
    from fleet.floor import Floor
    from fleet.paths import PathPlanner

__all__ = [
    "CONTROLLER_GROUP",
    "DISPATCHER_GROUP",
    "CAP_LOOKAHEAD_S",
    "ControlStatus",
    "SolverOutcome",
    "SolveReport",
    "RobotSpec",
    "Neighbour",
    "Observation",
    "Command",
    "ControllerContext",
    "Controller",
    "Job",
    "RobotStatus",
    "Assignment",
    "DispatchContext",
    "Dispatcher",
    "Announcement",
    "Bid",
    "Handback",
    "PluginWarning",
    "PluginInfo",
    "discover",
    "load_controller",
    "load_dispatcher",
]

CONTROLLER_GROUP = "fleet.controllers"
DISPATCHER_GROUP = "fleet.dispatchers"

#: How far ahead (s) of its time an observation lists the print's speed-cap pieces: a
#: controller whose horizon reaches further must treat what lies beyond as unknown.
CAP_LOOKAHEAD_S = 60.0


class ControlStatus(enum.Enum):
    """What a controller did this tick."""

    OK = "ok"
    """The command follows the controller's plan."""
    IDLE = "idle"
    """No goal: the command holds the robot (brakes to rest)."""
    FALLBACK = "fallback"
    """The controller's normal method failed (e.g. no solver answer); the command is a safe
    backup."""
    BLOCKED = "blocked"
    """The controller cannot bring the robot to its goal (no path, or stuck behind robots it
    cannot get round); the command holds the robot and its agent hands the job back, so the
    engine announces it again."""
    ERROR = "error"
    """The controller raised; the engine substituted braking. Set by the agent, not by plugins."""


class SolverOutcome(enum.Enum):
    """How an optimising controller's solve of one step ended (reported in `SolveReport`)."""

    OPTIMAL = "optimal"
    """Solved to optimality (within the solver's gap tolerance)."""
    FEASIBLE = "feasible"
    """Stopped at a limit (time, nodes) with a feasible solution, which is used."""
    NO_SOLUTION = "no_solution"
    """Stopped at a limit without any feasible solution: the controller fell back."""
    INFEASIBLE = "infeasible"
    """The problem has no solution (e.g. the state left the modelled set): fell back."""
    ERROR = "error"
    """The solver failed (numerical trouble, exception): fell back."""

    @property
    def usable(self) -> bool:
        """Whether the step's command came from the solver's solution."""
        return self in (SolverOutcome.OPTIMAL, SolverOutcome.FEASIBLE)


@dataclass(frozen=True, slots=True)
class SolveReport:
    """What an optimising controller says about one step's solve; the engine aggregates these
    into ``summary.json`` ``solver``.

    Attributes
    ----------
    outcome:
        How the solve ended.
    solver_s:
        Wall time (s) spent inside the solver itself this step.
    step_s:
        Wall time (s) of the whole controller step (model updates, solve, reading the
        solution); ``step_s / solver_s`` is the modelling layer's overhead.
    """

    outcome: SolverOutcome
    solver_s: float
    step_s: float


@dataclass(frozen=True, slots=True)
class RobotSpec:
    """Physical parameters of one robot (the paper's double integrator).

    Attributes
    ----------
    v_max:
        The robot's own per-axis speed limit (m/s), applied on top of zone limits.
    a_max:
        Per-axis acceleration bound (m/s^2): the input set U = [-a_max, a_max]^2.
    radius:
        Footprint radius (m), used for robot-robot separation.
    period:
        Control period dt (s): one observation and one command per period.
    """

    v_max: float = 1.0
    a_max: float = 0.5
    radius: float = 0.4
    period: float = 0.25


@dataclass(frozen=True, slots=True)
class Neighbour:
    """Another robot as seen in an observation.

    `radius` is its footprint radius (m). `priority` is its current priority (the engine's; the
    higher one goes first where two robots' plans conflict). `plan` is the part of its latest
    plan (`Command.plan`) from the observation's time on, ``(t, x, y)`` samples with absolute
    times; empty when it has sent none (assume it may stay where it is).
    """

    robot: str
    x: float
    y: float
    vx: float
    vy: float
    radius: float = 0.4
    priority: int = 0
    plan: tuple[tuple[float, float, float], ...] = ()


@dataclass(frozen=True, slots=True)
class Observation:
    """What a robot's agent receives at control tick `tick` (time `t`, seconds).

    The state follows the paper's discrete double integrator: position (x, y) and velocity
    (vx, vy). The velocity chosen by the command of this tick takes effect from the next tick:
    ``p[k+1] = p[k] + dt * v[k]`` and ``v[k+1] = v[k] + dt * u[k]``.

    `goal` is where the current job wants the robot (None when idle). Print tasks cap the
    robot's per-axis speed on top of zone limits: `speed_caps` lists the cap pieces
    ``(start_s, end_s, cap)`` (absolute times, sorted, cropped to the engine's look-ahead
    window, `CAP_LOOKAHEAD_S` from `t`) and `speed_cap` is the tightest cap
    over this tick's step ``[t, t + period)``, None when no piece overlaps it. A velocity held
    over a step must respect every piece that overlaps the step
    (`fleet.printing.CapSchedule` computes per-step caps). `print_end_s` is when the current
    job's print ends (None: no print, or not started yet); a strategy that prints standing
    before it drives waits for it.
    """

    robot: str
    tick: int
    t: float
    x: float
    y: float
    vx: float
    vy: float
    goal: tuple[float, float] | None = None
    job: str | None = None
    speed_cap: float | None = None
    neighbours: tuple[Neighbour, ...] = ()
    speed_caps: tuple[tuple[float, float, float], ...] = ()
    print_end_s: float | None = None
    priority: int = 0
    blockers: tuple[str, ...] = ()
    queued: int = 0


@dataclass(frozen=True, slots=True)
class Command:
    """A controller's answer: the acceleration to apply over the next period.

    `plan` optionally carries the controller's intended trajectory as ``(t, x, y)`` samples
    (the MPC's horizon, the follower's next seconds) so other robots and the replay can see it.
    An empty plan means "no news": the latest plan sent still holds. Optimising controllers
    attach a `SolveReport` (`solve`) so the run's summary can report solver statistics.
    """

    ax: float
    ay: float
    status: ControlStatus = ControlStatus.OK
    plan: tuple[tuple[float, float, float], ...] = ()
    solve: SolveReport | None = None


@dataclass(frozen=True)
class ControllerContext:
    """What a controller gets once, before its first observation."""

    robot: str
    spec: RobotSpec
    floor: Floor
    planner: PathPlanner


class Controller(ABC):
    """Base class of controller plugins: observation in, command out.

    Override `compute` (required) and `reset` (to prepare per-robot state). One instance serves
    one robot. `compute` must be deterministic given the observations so far: the same seed must
    give the same run in one process or many.
    """

    #: Short name shown by ``fleet plugins``; defaults to the entry-point name.
    name: ClassVar[str] = ""

    def __init__(self, **options: Any) -> None:
        if options:
            raise TypeError(f"{type(self).__name__} takes no options, got {sorted(options)}")

    def reset(self, context: ControllerContext) -> None:
        """Called once before the first `compute`; keep what you need from `context`."""
        self.context = context

    @abstractmethod
    def compute(self, obs: Observation) -> Command:
        """Return the command for this tick. Must not block for longer than one period."""

    def bid(self, obs: Observation, job: Announcement) -> float | None:
        """This robot's bid for an announced job: seconds from ``obs.t`` until it could deliver
        it, after the work it already has; None declines.

        The default is `fleet.auction.estimate_completion` with the context's path planner
        (finish the current job, then drive to the job's station, waiting for its print).
        """
        return estimate_completion(self.context.planner, obs, job)


@dataclass(frozen=True, slots=True)
class Job:
    """A unit of work: print `part` (a name from the scenario's ``[parts]``; None: nothing to
    print) while driving to `station`, due by `due_s` (None: no due time)."""

    id: str
    station: str
    x: float
    y: float
    released_s: float
    due_s: float | None = None
    part: str | None = None


@dataclass(frozen=True, slots=True)
class RobotStatus:
    """A robot as a dispatcher sees it."""

    robot: str
    x: float
    y: float
    vx: float
    vy: float
    idle: bool
    job: str | None = None
    #: Jobs awarded to the robot that wait behind its current one (auctions only).
    queued: int = 0


@dataclass(frozen=True, slots=True)
class Assignment:
    job: str
    robot: str


@dataclass(frozen=True, slots=True)
class Announcement:
    """A job the engine offers the fleet over the bus (contract net): agents bid for it.

    `print_s` is how long its print lasts (0: nothing to print); the robot prints while it
    drives, and delivers once both the trip and the print are done.
    """

    job: str
    x: float
    y: float
    print_s: float
    released_s: float
    due_s: float | None = None


@dataclass(frozen=True, slots=True)
class Bid:
    """A robot's offer for an announced job: `estimate_s` seconds from the announcement's tick
    until it could deliver the job."""

    job: str
    robot: str
    estimate_s: float


@dataclass(frozen=True, slots=True)
class Handback:
    """A robot's agent gives a job back (it cannot finish it); the engine announces it again."""

    robot: str
    job: str
    reason: str


@dataclass(frozen=True)
class DispatchContext:
    """What a dispatcher may consult besides jobs and robots."""

    t: float
    floor: Floor
    planner: PathPlanner
    extra: Mapping[str, Any] = field(default_factory=dict)


class Dispatcher(ABC):
    """Base class of dispatcher plugins: open jobs + robot states -> assignments.

    Override `assign`. Return only assignments of open jobs to idle robots, at most one job per
    robot and one robot per job; the engine rejects (and logs) anything else.
    """

    name: ClassVar[str] = ""
    #: True for a contract-net dispatcher: the engine announces open jobs on the bus, the
    #: robots' agents bid (`Controller.bid`) and `award` picks the winners; `assign` is then
    #: only asked when no bids came (e.g. every agent declined).
    announces: ClassVar[bool] = False

    def __init__(self, **options: Any) -> None:
        if options:
            raise TypeError(f"{type(self).__name__} takes no options, got {sorted(options)}")

    def award(
        self,
        bids: Sequence[Bid],
        jobs: Sequence[Job],
        robots: Sequence[RobotStatus],
        context: DispatchContext,
    ) -> list[Assignment]:
        """Award announced `jobs` from the robots' `bids` (announcing dispatchers only).

        Return assignments of announced jobs to robots that bid for them, at most one per job;
        a robot may be awarded a job while busy (it queues behind its current one). The engine
        rejects (and logs) anything else and announces unawarded jobs again later.
        """
        raise NotImplementedError(f"{type(self).__name__} does not take bids")

    @abstractmethod
    def assign(
        self, jobs: Sequence[Job], robots: Sequence[RobotStatus], context: DispatchContext
    ) -> list[Assignment]:
        """Choose which idle robot takes which open job (oldest jobs first is customary)."""


# --- discovery -----------------------------------------------------------------------------------
# Each kind: its entry-point group, the base class a plugin must subclass, and the one method it
# must implement. Validation checks exactly these, so the error can name the broken one.
_KINDS: dict[str, tuple[str, type, str]] = {
    "controller": (CONTROLLER_GROUP, Controller, "compute"),
    "dispatcher": (DISPATCHER_GROUP, Dispatcher, "assign"),
}

# Per-process cache of `discover()`: kind -> plugins in entry-point order. None until first use.
_CACHE: dict[str, tuple[PluginInfo, ...]] | None = None
#: Held while the entry points are read (reentrant: a plugin's import may ask for plugins).
_CACHE_LOCK = threading.RLock()


class PluginWarning(UserWarning):
    """A registered plugin is broken (or shadowed) and was skipped; the message says why."""


@dataclass(frozen=True)
class PluginInfo:
    """One registered plugin as discovery found it, usable or not.

    Attributes
    ----------
    name:
        Entry-point name: what a scenario writes in ``[controller] name = ...``.
    kind:
        ``"controller"`` or ``"dispatcher"``.
    group:
        The entry-point group it was registered under (`CONTROLLER_GROUP`, `DISPATCHER_GROUP`).
    value:
        The entry point's target, ``"module:Class"``.
    distribution, version:
        The installed distribution that registered it (None if unknown).
    origin:
        The file the class lives in (None when it could not be imported).
    factory:
        The validated plugin class; None when the plugin is broken.
    error:
        Why the plugin cannot be used (import error, wrong base class, abstract method,
        shadowed by an earlier plugin of the same name); None when it is usable.
    """

    name: str
    kind: str
    group: str
    value: str
    distribution: str | None = None
    version: str | None = None
    origin: str | None = None
    factory: type | None = None
    error: str | None = None

    @property
    def ok(self) -> bool:
        """Whether the plugin loaded and passed validation."""
        return self.factory is not None and self.error is None

    def describe(self) -> str:
        """``name (group = module:Class from dist version)``, for messages and listings."""
        source = f" from {self.distribution} {self.version}" if self.distribution else ""
        return f"{self.kind} plugin {self.name!r} ({self.group} = {self.value}{source})"


def discover(kind: str | None = None, *, refresh: bool = False) -> list[PluginInfo]:
    """Every registered controller and/or dispatcher plugin, usable or broken.

    The entry points are read, imported and validated once per process; pass ``refresh=True``
    to read them again (after installing a plugin at runtime, or in tests). A broken plugin is
    listed with its `PluginInfo.error` and reported once per read with a `PluginWarning`; it
    never stops the others from loading. When two plugins of one kind share a name, the first
    found on ``sys.path`` wins and the other is listed as shadowed.

    Parameters
    ----------
    kind:
        ``"controller"``, ``"dispatcher"`` or None for both.
    refresh:
        Read the entry points again instead of using the per-process cache.

    Returns
    -------
    list[PluginInfo]
        Sorted by kind, then name (a winner before the plugins it shadows).

    Raises
    ------
    ValueError
        If `kind` is not one of the allowed values.
    """
    global _CACHE
    if kind is not None and kind not in _KINDS:
        raise ValueError(f"plugin kind {kind!r} is unknown; allowed: {', '.join(_KINDS)} or None")
    cache = _CACHE
    if cache is None or refresh:
        with _CACHE_LOCK:
            # Threads (a Dask worker's, say) may all find no cache: one reads, the others
            # wait and take its result. The registry is published whole, in one assignment,
            # so no thread ever sees one partly filled.
            cache = _CACHE
            if cache is None or refresh:
                # A plugin installed since the last read may live in a directory whose
                # listing the import system has cached.
                importlib.invalidate_caches()
                fresh = {}
                for k in _KINDS:  # a plain loop so the warnings' stacklevel points at our caller
                    fresh[k] = _scan(k)
                _CACHE = cache = fresh
    kinds = [kind] if kind is not None else sorted(_KINDS)
    # sorted() is stable, so among equal names the winner (found first) stays first.
    return [info for k in kinds for info in sorted(cache[k], key=lambda i: i.name)]


def load_controller(name: str, options: Mapping[str, Any] | None = None) -> Controller:
    """Instantiate the controller plugin registered as `name` with keyword `options`.

    Raises
    ------
    PluginError
        If no usable controller is registered as `name` (the message lists the available
        ones), if the plugin is broken (the message says why), or if its constructor rejects
        the options (the message names the plugin and the options).
    """
    return _load("controller", name, options)  # type: ignore[return-value]


def load_dispatcher(name: str, options: Mapping[str, Any] | None = None) -> Dispatcher:
    """Instantiate the dispatcher plugin registered as `name` with keyword `options`.

    Raises
    ------
    PluginError
        As for `load_controller`.
    """
    return _load("dispatcher", name, options)  # type: ignore[return-value]


def _load(kind: str, name: str, options: Mapping[str, Any] | None) -> Controller | Dispatcher:
    found = [info for info in discover(kind) if info.name == name]
    usable = [info for info in found if info.ok]
    if not usable:
        group = _KINDS[kind][0]
        if found:
            raise PluginError(f"{found[0].describe()} cannot be used: {found[0].error}")
        available = ", ".join(sorted({i.name for i in discover(kind) if i.ok})) or "none"
        raise PluginError(
            f"no {kind} plugin named {name!r} is registered under entry-point group {group!r}; "
            f"available: {available}"
        )
    info = usable[0]
    assert info.factory is not None
    opts = dict(options or {})
    try:
        return info.factory(**opts)
    except (TypeError, ValueError) as exc:
        # Options come from a user's scenario: say which plugin and which options, and pass on
        # the constructor's own words (they name the bad keyword or value).
        raise PluginError(
            f"{info.describe()} rejected options {opts!r}: {exc}; "
            f"see the plugin's documentation for the options it accepts"
        ) from exc


def _scan(kind: str) -> tuple[PluginInfo, ...]:
    """Read, import and validate every entry point of `kind`, warning about broken ones."""
    group = _KINDS[kind][0]
    found: list[PluginInfo] = []
    winners: dict[str, PluginInfo] = {}
    for ep in importlib.metadata.entry_points(group=group):
        dist = getattr(ep, "dist", None)
        base = PluginInfo(
            name=ep.name,
            kind=kind,
            group=group,
            value=ep.value,
            distribution=dist.name if dist is not None else None,
            version=dist.version if dist is not None else None,
        )
        first = winners.get(ep.name)
        if first is not None:
            if (first.value, first.distribution) == (base.value, base.distribution):
                continue  # the same distribution seen twice on sys.path: not a conflict
            info = replace(
                base,
                error=f"name already taken by {first.describe()}, which wins (found first on "
                f"sys.path); rename one of the entry points to use both",
            )
        else:
            info = _validate(base, ep)
            if info.ok:
                winners[ep.name] = info
        if info.error is not None:
            warnings.warn(f"skipping {info.describe()}: {info.error}", PluginWarning, stacklevel=3)
        found.append(info)
    return tuple(found)


def _validate(info: PluginInfo, ep: importlib.metadata.EntryPoint) -> PluginInfo:
    """Import the entry point and check it against its kind's contract."""
    _group, base_class, method = _KINDS[info.kind]
    contract = f"{base_class.__module__}.{base_class.__qualname__}"
    try:
        obj = ep.load()
    except Exception as exc:  # any failure inside a third party's import is that plugin's fault
        module = sys.modules.get(ep.module)
        return replace(
            info,
            origin=getattr(module, "__file__", None),
            error=f"cannot import {ep.value!r}: {type(exc).__name__}: {exc}",
        )
    info = replace(info, origin=_origin(obj, ep))
    if not isinstance(obj, type) or not issubclass(obj, base_class):
        return replace(
            info,
            error=f"{ep.value!r} is {_describe_object(obj)}, not a subclass of {contract}",
        )
    if not callable(getattr(obj, method, None)):
        return replace(info, error=f"{ep.value!r} has no callable method {method!r}")
    abstract = sorted(getattr(obj, "__abstractmethods__", ()))
    if abstract:
        return replace(
            info,
            error=f"{ep.value!r} does not implement the abstract method(s) "
            f"{', '.join(abstract)} of {contract}",
        )
    return replace(info, factory=obj)


def _origin(obj: object, ep: importlib.metadata.EntryPoint) -> str | None:
    """The file defining `obj` (falling back to the entry point's module)."""
    module = sys.modules.get(getattr(obj, "__module__", None) or ep.module)
    module = module or sys.modules.get(ep.module)
    path = getattr(module, "__file__", None)
    return str(path) if path else None


def _describe_object(obj: object) -> str:
    if isinstance(obj, type):
        return f"the class {obj.__module__}.{obj.__qualname__}"
    return f"a {type(obj).__name__} object"
