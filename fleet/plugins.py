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
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

if TYPE_CHECKING:
    from fleet.floor import Floor
    from fleet.paths import PathPlanner

__all__ = [
    "CONTROLLER_GROUP",
    "DISPATCHER_GROUP",
    "ControlStatus",
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
]

CONTROLLER_GROUP = "fleet.controllers"
DISPATCHER_GROUP = "fleet.dispatchers"


class ControlStatus(enum.Enum):
    """What a controller did this tick."""

    OK = "ok"
    """The command follows the controller's plan."""
    IDLE = "idle"
    """No goal: the command holds the robot (brakes to rest)."""
    FALLBACK = "fallback"
    """The controller's normal method failed (e.g. no solver answer); the command is a safe backup."""
    ERROR = "error"
    """The controller raised; the engine substituted braking. Set by the agent, not by plugins."""


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
    """Another robot as seen in an observation."""

    robot: str
    x: float
    y: float
    vx: float
    vy: float


@dataclass(frozen=True, slots=True)
class Observation:
    """What a robot's agent receives at control tick `tick` (time `t`, seconds).

    The state follows the paper's discrete double integrator: position (x, y) and velocity
    (vx, vy). The velocity chosen by the command of this tick takes effect from the next tick:
    ``p[k+1] = p[k] + dt * v[k]`` and ``v[k+1] = v[k] + dt * u[k]``.

    `goal` is where the current job wants the robot (None when idle); `speed_cap` is a
    time-varying per-axis cap (e.g. from the print schedule) on top of zone limits, None when
    there is none.
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


@dataclass(frozen=True, slots=True)
class Command:
    """A controller's answer: the acceleration to apply over the next period.

    `plan` optionally carries the controller's intended trajectory as ``(t, x, y)`` samples
    (the MPC's horizon, the follower's next seconds) so other robots and the replay can see it.
    """

    ax: float
    ay: float
    status: ControlStatus = ControlStatus.OK
    plan: tuple[tuple[float, float, float], ...] = ()


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
            raise TypeError(
                f"{type(self).__name__} takes no options, got {sorted(options)}"
            )

    def reset(self, context: ControllerContext) -> None:
        """Called once before the first `compute`; keep what you need from `context`."""
        self.context = context

    @abstractmethod
    def compute(self, obs: Observation) -> Command:
        """Return the command for this tick. Must not block for longer than one period."""


@dataclass(frozen=True, slots=True)
class Job:
    """A unit of work: for now, "go to station X" (print content comes later)."""

    id: str
    station: str
    x: float
    y: float
    released_s: float
    due_s: float | None = None


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


@dataclass(frozen=True, slots=True)
class Assignment:
    job: str
    robot: str


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

    def __init__(self, **options: Any) -> None:
        if options:
            raise TypeError(
                f"{type(self).__name__} takes no options, got {sorted(options)}"
            )

    @abstractmethod
    def assign(
        self, jobs: Sequence[Job], robots: Sequence[RobotStatus], context: DispatchContext
    ) -> list[Assignment]:
        """Choose which idle robot takes which open job (oldest jobs first is customary)."""


# --- discovery -----------------------------------------------------------------------------------
# (entry-point discovery, validation and listing live below)
