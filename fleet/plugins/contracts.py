"""The plugin contracts: what a controller or dispatcher is given and must give back.

Data flows one way: the engine builds an `Observation` per robot per control tick, sends it
over the bus to the robot's agent, whose `Controller` answers with a `Command`. Dispatchers run
in the engine and turn open `Job`s and `RobotStatus`es into `Assignment`s, or award announced
jobs (`Announcement`) to the robots' `Bid`s. `fleet.plugins.discovery` finds the classes that
implement these contracts.
"""

from __future__ import annotations

import enum
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

from fleet.plugins.bidding import estimate_completion

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
    """Stopped at a work limit (e.g. branch-and-bound nodes) with a feasible solution, which is
    used."""
    NO_SOLUTION = "no_solution"
    """Stopped at a work limit without any feasible solution: the controller fell back."""
    TIME_LIMIT = "time_limit"
    """Stopped by the wall-clock guard: what the solver had found by then depends on the
    machine's speed, so it is not used and the controller fell back. The run may not be
    reproducible (the summary's ``solver.time_limit_hits`` counts these)."""
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
    times; empty when it has sent none (assume it may stay where it is). `v_max`, `a_max` and
    `period` are its own limits and control period (a fleet may mix robots), None where not
    known; `limits` fills those in from the observer's own.
    """

    robot: str
    x: float
    y: float
    vx: float
    vy: float
    radius: float = 0.4
    priority: int = 0
    plan: tuple[tuple[float, float, float], ...] = ()
    v_max: float | None = None
    a_max: float | None = None
    period: float | None = None

    def limits(self, own: RobotSpec) -> RobotSpec:
        """Its limits and period as a `RobotSpec`, each one not known taken from `own` (the
        observer's: in a fleet of one kind they are the same)."""
        return RobotSpec(
            own.v_max if self.v_max is None else self.v_max,
            own.a_max if self.a_max is None else self.a_max,
            self.radius,
            own.period if self.period is None else self.period,
        )


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

        The default is `fleet.plugins.bidding.estimate_completion` with the context's path planner
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
