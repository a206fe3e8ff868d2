"""Robots in motion: the engine's state of each robot, its delayed inputs, turning in place.

`RobotState` is what the engine knows of a robot (it is authoritative over positions) and
blends the inputs of commands that take effect late (compute latency); `build_robots` places a
scenario's robots on their start spots; `Turning` keeps a robot's heading and holds it on the
spot while it turns (`RobotsConfig.turn_radius_m`); `at_rest_near` is the arrival test.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import simpy

from fleet.engine.agents import robot_specs
from fleet.engine.jobs import JobRecord
from fleet.engine.recorder import Recorder
from fleet.errors import NoPathError
from fleet.paths import PathPlanner
from fleet.plugins import RobotSpec
from fleet.plugins.robot import DoubleIntegrator, clip
from fleet.printing import CapSchedule
from fleet.scenario import Scenario

if TYPE_CHECKING:
    from fleet.engine.makeway import Aside

__all__ = ["RobotState", "Turning", "build_robots", "at_rest_near", "REST_SPEED", "EFFECT_EPS_S"]

#: A robot counts as stopped below this speed (m/s) per axis.
REST_SPEED = 1e-3
#: Course changes (rad) smaller than this need no turn in place.
TURN_EPSILON = 1e-3
#: Effect times (s) this close to a step's start or end count as at it (compute latency):
#: a latency of exactly one period takes effect at the next tick despite rounding.
EFFECT_EPS_S = 1e-9


@dataclass(slots=True)
class RobotState:
    """A robot as the engine knows it (the engine is authoritative over positions)."""

    id: str
    spec: RobotSpec
    model: DoubleIntegrator
    home: tuple[float, float]
    x: float
    y: float
    vx: float = 0.0
    vy: float = 0.0
    ax: float = 0.0
    ay: float = 0.0
    tick: int = 0
    job: JobRecord | None = None
    #: Jobs awarded while busy (auctions), taken up in order after the current one.
    queue: list[JobRecord] = field(default_factory=list)
    jobs_completed: int = 0
    return_home: bool = True
    #: Its `[[robots]]` group (position in `Scenario.robots`): its start stations, its kind.
    group: int = 0
    #: The latest plan the robot's controller sent, ``(t, x, y)`` samples (empty: none yet),
    #: and the same thinned to `sensing.PLAN_SPACING_S` for the neighbours' observations.
    plan: tuple[tuple[float, float, float], ...] = ()
    thinned_plan: tuple[tuple[float, float, float], ...] = ()
    #: Print caps of the jobs this robot has finished (the current job's are in `job.caps`).
    past_caps: list[tuple[float, float, float]] = field(default_factory=list)
    #: Turning in place (`RobotsConfig.turn_radius_m`): angular speed (rad/s; None: the robot
    #: is holonomic), settle time, current heading (None until it first sets off), the end of
    #: the turn in progress and the cumulative turning angle.
    turn_rate: float | None = None
    turn_settle_s: float = 0.0
    heading: float | None = None
    turning_until: float = -math.inf
    turned_rad: float = 0.0
    #: Unique rank among the robots (higher goes first), before deadlock boosts.
    rank: int = 0
    #: Its agent is gone (lost or left): the robot is braked and takes no jobs until an agent
    #: hosts it again. Also a robot whose battery ran flat (`[battery]`, stranded), for good.
    faulted: bool = False
    #: Broken down (`[breakdowns]`): braked where it stopped, takes no jobs until repaired.
    broken: bool = False
    #: Standing at a charger taking charge (`[battery]`); the charging policy says whether it
    #: may be given a job meanwhile.
    charging: bool = False
    #: The charger it heads for or stands at (`fleet.engine.energy`): its goal while it has no
    #: job, instead of home.
    charger_at: tuple[float, float] | None = None
    #: Progress watch for deadlock detection: closest distance to the current goal so far, and
    #: when it last improved by `PROGRESS_M`.
    best_gap: float = math.inf
    progress_s: float = 0.0
    watched_goal: tuple[float, float] | None = None
    #: Where it stood when it last made progress, the length of its route to the goal from
    #: there (worked out when first needed) and where it stood when the watch last measured
    #: its route (`fleet.engine.sensing`: progress along the route counts too).
    progress_at: tuple[float, float] | None = None
    route_then: float | None = None
    route_seen: tuple[float, float] | None = None
    #: Where it stands, and since when it has stood there (the watch's last sight of it moving).
    still_at: tuple[float, float] | None = None
    still_since: float = 0.0
    #: Commands it was sent while it had somewhere to go, and how many were errors (its
    #: controller failed, or no command came): all of them means it could never move.
    goal_commands: int = 0
    goal_errors: int = 0
    #: Robots found blocking this one (deadlock), and until when its priority is raised.
    blockers: tuple[str, ...] = ()
    boosted_until: float = -math.inf
    #: Stuck (blocked by robots, or by idle robots it waits for to step aside), reported once.
    stalled: bool = False
    #: `progress_s` when it was last reported stuck: until it makes progress again it is the
    #: same deadlock, however often robots come and go round it (`fleet.engine.sensing`).
    reported_at: float | None = None
    #: Where it waits off the route of a robot it blocked (`fleet.engine.makeway.Aside`).
    aside: Aside | None = None
    #: Compute latency (`Scenario.latency`): inputs waiting to take effect as ``(effect time,
    #: ax, ay)`` in order of effect (clipped to a_max), the input in force (the last one that
    #: took effect; 0 at the start), the latency (s) of each controller command that had one,
    #: and (measured latency) the commands without a solve report, applied at once.
    pending: list[tuple[float, float, float]] = field(default_factory=list)
    in_force: tuple[float, float] = (0.0, 0.0)
    latencies: array = field(default_factory=lambda: array("d"))
    instant: int = 0

    def delay(self, t: float, latency: float, ax: float, ay: float) -> None:
        """Queue input (`ax`, `ay`), computed at `t`, to take effect at ``t + latency``.

        Each axis is clipped to a_max first, so blends of inputs stay within the bounds. Pending
        inputs that would take effect no earlier are superseded: they never apply.
        """
        a = self.spec.a_max
        effect = t + latency
        while self.pending and self.pending[-1][0] >= effect - EFFECT_EPS_S:
            self.pending.pop()
        self.pending.append((effect, clip(ax, a), clip(ay, a)))

    def step_input(self, t: float, dt: float) -> tuple[float, float]:
        """The input for the step [`t`, `t` + `dt`): the time-weighted mean of the inputs in
        force during it (pending ones taking effect at their effect times).

        When one input holds over the whole step it is returned as it is (no arithmetic), so
        a latency of 0 moves the robot exactly as no latency does.
        """
        ax, ay = self.in_force
        sx = sy = 0.0
        at = 0.0  # offset into the step up to which (sx, sy) integrates
        while self.pending and self.pending[0][0] - t < dt - EFFECT_EPS_S:
            effect, nx, ny = self.pending.pop(0)
            offset = effect - t
            if offset > at + EFFECT_EPS_S:
                sx += ax * (offset - at)
                sy += ay * (offset - at)
                at = offset
            ax, ay = nx, ny
        self.in_force = (ax, ay)
        if at == 0.0:
            return ax, ay
        sx += ax * (dt - at)
        sy += ay * (dt - at)
        return sx / dt, sy / dt

    def caps(self) -> CapSchedule:
        """Every print-cap piece this robot has been under so far (for the safety checker)."""
        current = self.job.caps.pieces if self.job is not None else ()
        return CapSchedule(tuple(self.past_caps) + current)

    @property
    def in_service(self) -> bool:
        """Whether it can take jobs and move: its agent is there and it is not broken down."""
        return not (self.faulted or self.broken)

    @property
    def goal(self) -> tuple[float, float] | None:
        """Where the current job sends the robot next: a via station, or the destination."""
        rec = self.job
        if rec is None:
            return None
        if rec.leg < len(rec.via):
            _, x, y = rec.via[rec.leg]
            return (x, y)
        return (rec.job.x, rec.job.y)


def build_robots(scenario: Scenario, homes: list[tuple[float, float]]) -> dict[str, RobotState]:
    """The scenario's robots, group by group, numbered as `robot_specs` numbers them, each
    starting at its home in `homes` (in robot order) and ranked."""
    robots: dict[str, RobotState] = {}
    ids = iter(robot_specs(scenario))
    for g, group in enumerate(scenario.robots):
        spec = RobotSpec(group.v_max, group.a_max, group.radius, group.period_s)
        model = DoubleIntegrator(group.period_s, group.a_max)
        rate = None if group.turn_radius_m is None else group.v_max / group.turn_radius_m
        for _ in range(group.count):
            rid = next(ids)
            hx, hy = homes[len(robots)]
            robots[rid] = RobotState(
                rid,
                spec,
                model,
                (hx, hy),
                hx,
                hy,
                return_home=group.return_home,
                group=g,
                turn_rate=rate,
                turn_settle_s=group.turn_settle_s,
            )
    # Smaller ids go first among robots of equal standing.
    for n, r in enumerate(robots.values()):
        r.rank = len(robots) - n
    return robots


def at_rest_near(robot: RobotState, goal: tuple[float, float] | None, tol: float) -> bool:
    """Whether `robot` has stopped within `tol` of `goal` (it has arrived there)."""
    return (
        goal is not None
        and abs(robot.vx) <= REST_SPEED
        and abs(robot.vy) <= REST_SPEED
        and math.hypot(robot.x - goal[0], robot.y - goal[1]) <= tol
    )


class Turning:
    """Turning in place: a robot with a turn rate faces its direction of travel and, at rest,
    turns on the spot before it sets off in another direction. The angles turned are counted
    on the robot and, while it prints, on its job."""

    def __init__(
        self,
        env: simpy.Environment,
        recorder: Recorder,
        planner_for: Callable[[RobotSpec], PathPlanner],
    ) -> None:
        self.env = env
        self.recorder = recorder
        self.planner_for = planner_for

    def follow_heading(self, robot: RobotState) -> None:
        """While moving, the robot faces its direction of travel; count the angle it turns."""
        if max(abs(robot.vx), abs(robot.vy)) <= REST_SPEED:
            return
        course = math.atan2(robot.vy, robot.vx)
        if robot.heading is not None:
            self._turned(robot, abs(_wrap(course - robot.heading)))
        robot.heading = course

    def turns_first(
        self, robot: RobotState, goal: tuple[float, float], t: float, tol: float
    ) -> bool:
        """Whether `robot` must turn on the spot before it sets off towards `goal` (starting
        the turn if it is at rest and the way to the goal leaves in another direction)."""
        if t < robot.turning_until - 1e-9:
            return True
        if max(abs(robot.vx), abs(robot.vy)) > REST_SPEED:
            return False
        if math.hypot(goal[0] - robot.x, goal[1] - robot.y) <= tol:
            return False
        course = self._departure_course(robot, goal)
        if course is None:
            return False
        if robot.heading is None:  # the robot starts out facing its first way
            robot.heading = course
            return False
        angle = abs(_wrap(course - robot.heading))
        if angle <= TURN_EPSILON:
            return False
        assert robot.turn_rate is not None
        duration = angle / robot.turn_rate + robot.turn_settle_s
        # Whole control periods: the robot sets off at a tick.
        period = robot.spec.period
        robot.turning_until = t + math.ceil(duration / period - 1e-9) * period
        self._turned(robot, angle)
        robot.heading = course
        self.recorder.event(t, "turn", "" if robot.job is None else robot.job.job.id, robot.id)
        return True

    def _turned(self, robot: RobotState, angle: float) -> None:
        robot.turned_rad += angle
        if robot.job is not None and robot.job.printing(self.env.now):
            robot.job.turned_rad += angle

    def _departure_course(self, robot: RobotState, goal: tuple[float, float]) -> float | None:
        """The direction of the first leg of the path from the robot to `goal`."""
        try:
            waypoints = self.planner_for(robot.spec).path((robot.x, robot.y), goal).waypoints
        except NoPathError:
            return None
        for p in waypoints[1:]:
            dx, dy = float(p[0]) - robot.x, float(p[1]) - robot.y
            if math.hypot(dx, dy) > 1e-6:
                return math.atan2(dy, dx)
        return None


def _wrap(angle: float) -> float:
    """`angle` folded into [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi
