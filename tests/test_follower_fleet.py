"""The follower among other robots: it stops in time, yields by priority, routes round blockers.

Most tests drive real `PathFollower`s on the double integrator in a small loop that plays the
engine's part: each tick every robot observes the others (position, velocity, radius, priority,
and the part of their latest plan from now on), answers, and moves. Scripted robots, which
follow a fixed straight line whatever happens and announce it as their plan, stand in for
robots that do not give way.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import pytest
import shapely
from hypothesis import given, settings
from hypothesis import strategies as st

from fleet.engine.safety import check_steps
from fleet.engine.world import World
from fleet.errors import NoPathError
from fleet.floor import Obstacle, compile_floor, parse_spec
from fleet.paths import PathPlanner
from fleet.plugins import (
    Command,
    ControllerContext,
    ControlStatus,
    Neighbour,
    Observation,
    RobotSpec,
)
from fleet.scenario import REPO_ROOT, Scenario, load_scenario
from fleet_plugins.follower import PathFollower
from fleet_plugins.follower.controller import FACE_OFF_S
from fleet_plugins.follower.yielding import (
    Detour,
    Forecast,
    _polygon,
    braking_path,
    must_yield,
    stops_clear,
)

SPEC = RobotSpec(v_max=1.0, a_max=0.5, radius=0.4, period=0.25)
DT, A_MAX, RADIUS = SPEC.period, SPEC.a_max, SPEC.radius
MARGIN = 0.1
GAP = 2 * RADIUS + MARGIN  # what the follower keeps between two robots' centres

# Two 14 x 12 m rooms joined by one corridor, 1.6 m wide (0.8 m for a robot's centre).
MAP = """
[floor]
name = "two rooms"
rect = [0, 0, 30, 12]
default_v_max = 1.0
clearance = 0.4

[[obstacles]]
name = "wall_south"
rect = [14, 0, 16, 5.2]

[[obstacles]]
name = "wall_north"
rect = [14, 6.8, 16, 12]
"""
FLOOR = compile_floor(parse_spec(tomllib.loads(MAP), "two_rooms.toml"))
PLANNER = PathPlanner(FLOOR, SPEC.v_max, SPEC.a_max)

XY = tuple[float, float]


# --- the loop that plays the engine ---------------------------------------------------------------


@dataclass
class Bot:
    """A simulated robot: a follower on the double integrator, and what happened to it."""

    name: str
    p: np.ndarray
    goal: XY | None
    priority: int = 0
    controller: PathFollower = field(default_factory=PathFollower)
    v: np.ndarray = field(default_factory=lambda: np.zeros(2))
    plan: tuple[tuple[float, float, float], ...] = ()
    blockers: tuple[str, ...] = ()
    xy: list[np.ndarray] = field(default_factory=list)
    vel: list[np.ndarray] = field(default_factory=list)
    commands: list[Command] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.p = np.asarray(self.p, dtype=float)
        self.controller.reset(ControllerContext(self.name, SPEC, FLOOR, PLANNER))

    def arrived(self) -> bool:
        return (
            self.goal is not None
            and math.hypot(*(self.p - self.goal)) <= 1e-6
            and not np.any(np.abs(self.v) > 1e-9)
        )


@dataclass
class Scripted:
    """A robot that drives a straight line at constant velocity from `t_start` for `duration`
    seconds and stands still before and after, whatever happens; its plan says exactly that."""

    name: str
    start: XY
    velocity: XY
    priority: int = 0
    t_start: float = 0.0
    duration: float = math.inf
    radius: float = RADIUS
    send_plan: bool = True

    def state(self, t: float) -> tuple[float, float, float, float]:
        s = min(max(t - self.t_start, 0.0), self.duration)
        moving = self.t_start <= t < self.t_start + self.duration
        vx, vy = self.velocity if moving else (0.0, 0.0)
        return self.start[0] + s * self.velocity[0], self.start[1] + s * self.velocity[1], vx, vy

    def neighbour(self, t: float) -> Neighbour:
        x, y, vx, vy = self.state(t)
        plan = ()
        if self.send_plan:
            plan = tuple((t + i, *self.state(t + i)[:2]) for i in range(6))
        return Neighbour(self.name, x, y, vx, vy, self.radius, self.priority, plan)


def future(plan: tuple[tuple[float, float, float], ...], t: float) -> tuple:
    """The part of a plan from `t` on (what the engine passes on)."""
    return tuple(s for s in plan if s[0] >= t - 1e-9)


def simulate(
    bots: list[Bot],
    ticks: int,
    scripted: tuple[Scripted, ...] = (),
    *,
    until: Callable[[], bool] | None = None,
    blockers: Callable[[Bot, int], tuple[str, ...]] | None = None,
) -> int:
    """Run `ticks` ticks (or until `until()`); return the ticks run. Checks every command is
    within the acceleration bound on each axis."""
    start = len(bots[0].xy) if bots else 0  # the clock goes on from the previous call
    for tick in range(start, start + ticks):
        if until is not None and until():
            return tick - start
        t = tick * DT
        others = [s.neighbour(t) for s in scripted]
        observations = []
        for b in bots:
            near = [
                Neighbour(o.name, *map(float, o.p), *map(float, o.v), RADIUS, o.priority,
                          future(o.plan, t))
                for o in bots
                if o is not b
            ] + others  # fmt: skip
            held = b.blockers if blockers is None else blockers(b, tick)
            observations.append(
                Observation(
                    b.name,
                    tick,
                    t,
                    *map(float, b.p),
                    *map(float, b.v),
                    goal=b.goal,
                    neighbours=tuple(near),
                    priority=b.priority,
                    blockers=held,
                )  # fmt: skip
            )
        for b, obs in zip(bots, observations, strict=True):
            cmd = b.controller.compute(obs)
            assert abs(cmd.ax) <= A_MAX + 1e-12 and abs(cmd.ay) <= A_MAX + 1e-12, cmd
            if cmd.plan:
                b.plan = cmd.plan
            b.commands.append(cmd)
            b.xy.append(b.p.copy())
            b.vel.append(b.v.copy())
            b.p = b.p + DT * b.v
            b.v = b.v + DT * np.array([cmd.ax, cmd.ay])
    return ticks


def closest(bot: Bot, other: Bot | Scripted) -> float:
    """The smallest distance between the two robots' centres at the ticks both recorded."""
    ours = np.array([*bot.xy, bot.p])
    if isinstance(other, Scripted):
        theirs = np.array([other.state(k * DT)[:2] for k in range(len(ours))])
    else:
        theirs = np.array([*other.xy, other.p])
    n = min(len(ours), len(theirs))
    ours, theirs = ours[:n], theirs[:n]
    return float(np.min(np.hypot(*(ours - theirs).T)))


def floor_violations(bot: Bot) -> list[str]:
    t = DT * np.arange(len(bot.xy) + 1)
    xy = np.array([*bot.xy, bot.p])
    v = np.array([*bot.vel, bot.v])
    return [f"{x.kind} at t={x.t}: {x.detail}" for x in check_steps(FLOOR, t, xy, v, bot.name)]


def assert_plans_honest(bot: Bot) -> None:
    """Rule 4: until the next plan is sent, the robot is where its latest plan puts it at each of
    the plan's sample times, and after the last sample it stays there."""
    sent = [k for k, c in enumerate(bot.commands) if c.plan]
    xy = np.array([*bot.xy, bot.p])
    for i, k in enumerate(sent):
        end = sent[i + 1] if i + 1 < len(sent) else len(xy) - 1
        plan = bot.commands[k].plan
        for t, x, y in plan:
            j = round(t / DT)
            if j <= end:
                assert math.hypot(*(xy[j] - (x, y))) <= 1e-6, (bot.name, k, t, xy[j], (x, y))
        last = round(plan[-1][0] / DT)
        for j in range(last, end + 1):
            assert math.hypot(*(xy[j] - plan[-1][1:])) <= 1e-6, (bot.name, k, j)


def arrival(bot: Bot) -> int:
    """The tick at which the robot came to rest on its goal (and stayed)."""
    xy = np.array([*bot.xy, bot.p])
    away = np.flatnonzero(np.hypot(*(xy - bot.goal).T) > 1e-6)
    assert len(away) and away[-1] < len(xy) - 1, bot.p
    return int(away[-1] + 1)


def moving(v: np.ndarray) -> bool:
    return bool(np.max(np.abs(v)) > 1e-9)


# --- rule 1: it can always stop in time -----------------------------------------------------------


def test_stops_short_of_a_robot_parked_on_its_path_and_waits_until_it_leaves() -> None:
    bot = Bot("r1", (3.0, 3.0), goal=(12.0, 3.0))
    parked = Scripted("r2", (8.0, 3.0), (0.0, 0.0), priority=7, send_plan=False)
    simulate([bot], 160, (parked,))
    # It braked to rest short of the parked robot, more than the gap away, and stayed there:
    # it does not creep closer by setting off and braking again (`Guard.keeps_going`), which
    # cost a new plan every third tick.
    assert not moving(bot.v) and bot.p[0] < 8.0
    assert GAP < closest(bot, parked) < GAP + 0.15
    rest = next(k for k in range(len(bot.vel)) if k > 0 and not moving(bot.vel[k]))
    assert all(np.array_equal(p, bot.p) for p in bot.xy[rest:])
    assert all(np.array_equal(p, bot.p) for p in bot.xy[40:])
    assert all((c.ax, c.ay) == (0.0, 0.0) for c in bot.commands[40:])
    assert all(c.status is ControlStatus.OK for c in bot.commands)
    # Gone: the way is clear and it drives on to its goal.
    simulate([bot], 200, until=bot.arrived)
    assert bot.arrived()
    assert floor_violations(bot) == []
    assert_plans_honest(bot)


def test_brakes_for_a_lower_priority_robot_that_crosses_its_path_without_yielding() -> None:
    start, goal = (3.0, 3.0), (12.0, 3.0)
    ref = PLANNER.reference(start, goal, dt=DT)
    # When the reference reaches x = 8, the crossing robot is there too, heading north.
    t_cross = float(ref.times[np.argmax(ref.positions[:, 0] >= 8.0)])
    crosser = Scripted("r2", (8.0, 3.0 - 0.5 * t_cross), (0.0, 0.5), priority=0)
    bot = Bot("r1", start, goal=goal, priority=5)
    searched = PLANNER.cache_info().path.misses
    simulate([bot], 200, (crosser,), until=bot.arrived)
    assert bot.arrived()
    assert closest(bot, crosser) > GAP - 1e-9
    # It lost time against its reference: it braked, then drove on from rest along the rest of
    # the same path, without searching it again.
    assert len(bot.xy) > ref.steps + 4
    assert PLANNER.cache_info().path.misses == searched
    resumed = bot.controller._track.ref.path.waypoints
    assert resumed[0][0] > start[0] and np.array_equal(resumed[-1], goal)
    assert floor_violations(bot) == []
    assert_plans_honest(bot)


def test_a_robot_at_rest_whose_way_is_not_clear_stays_at_rest() -> None:
    bot = Bot("r1", (3.0, 3.0), goal=(12.0, 3.0))
    # Right in front, closer than the gap: any step forward brings them closer.
    close = Scripted("r2", (3.85, 3.0), (0.0, 0.0), send_plan=False)
    simulate([bot], 20, (close,))
    assert np.array_equal(bot.p, (3.0, 3.0)) and not moving(bot.v)
    assert all((c.ax, c.ay) == (0.0, 0.0) for c in bot.commands)
    # The hold is announced at once, and again about once a second.
    assert [k for k, c in enumerate(bot.commands) if c.plan] == [0, 4, 8, 12, 16]
    assert all({s[1:] for s in c.plan} == {(3.0, 3.0)} for c in bot.commands if c.plan)


def test_a_robot_too_close_may_still_move_away() -> None:
    bot = Bot("r1", (3.0, 3.0), goal=(1.0, 3.0))
    close = Scripted("r2", (3.85, 3.0), (0.0, 0.0), send_plan=False)
    simulate([bot], 80, (close,), until=bot.arrived)
    assert bot.arrived()


# --- rule 2: priorities ---------------------------------------------------------------------------


def crossing(priority: int) -> tuple[Bot, Scripted]:
    """A robot at rest at (5, 3) heading east, and a priority-3 robot crossing its way at
    x = 6 northwards at 0.5 m/s, passing y = 3 at t = 3 s."""
    bot = Bot("r1", (5.0, 3.0), goal=(12.0, 3.0), priority=priority)
    other = Scripted("r2", (6.0, 1.5), (0.0, 0.5), priority=3, duration=16.0)
    return bot, other


def test_a_lower_priority_robot_waits_at_rest_for_a_crossing_higher_one() -> None:
    bot, other = crossing(priority=1)
    simulate([bot], 200, (other,), until=bot.arrived)
    assert bot.arrived()
    first_move = next(k for k, v in enumerate(bot.vel) if moving(v))
    # It waited until the crossing robot was past its path, by more than the gap...
    assert other.state(first_move * DT)[1] > 3.0 + GAP
    # ...at rest, announcing so at once.
    assert all((c.ax, c.ay) == (0.0, 0.0) for c in bot.commands[: first_move - 1])
    assert {s[1:] for s in bot.commands[0].plan} == {(5.0, 3.0)}
    assert closest(bot, other) > GAP
    assert_plans_honest(bot)


def test_a_higher_priority_robot_sets_off_at_once() -> None:
    bot, other = crossing(priority=5)
    simulate([bot], 200, (other,), until=bot.arrived)
    assert bot.arrived()
    # It does not wait for the lower robot to pass (rule 2 is not for it): it sets off while
    # that one is still in its way, as soon as rule 1 lets it drive on (it does not set off
    # only to brake at the next tick).
    first_move = next(k for k, v in enumerate(bot.vel) if moving(v))
    assert other.state(first_move * DT)[1] < 3.0 + GAP
    # The crossing robot does not give way, so it may pass closer than the gap; no collision.
    assert closest(bot, other) > 2 * RADIUS
    assert_plans_honest(bot)


def test_no_yield_to_a_higher_robot_that_comes_from_behind() -> None:
    # The higher robot is faster and comes up behind: waiting would only block it.
    bot = Bot("r1", (4.0, 3.0), goal=(12.0, 3.0), priority=1)
    behind = Scripted("r2", (1.0, 3.0), (1.0, 0.0), priority=3, duration=2.0)
    simulate([bot], 4, (behind,))
    assert moving(bot.v)


@pytest.mark.parametrize("east_priority", [1, 2])
def test_two_followers_at_a_crossing_never_collide_and_the_higher_one_goes_first(
    east_priority: int,
) -> None:
    east = Bot("east", (3.0, 6.0), goal=(12.0, 6.0), priority=east_priority)
    north = Bot("north", (7.5, 1.0), goal=(7.5, 11.0), priority=3 - east_priority)
    simulate([east, north], 400, until=lambda: east.arrived() and north.arrived())
    assert east.arrived() and north.arrived()
    assert closest(east, north) > GAP - 1e-9
    # The lower one waited for the higher one at rest: the higher one is never held up.
    high, low = (east, north) if east_priority == 2 else (north, east)
    assert arrival(high) == PLANNER.reference(tuple(high.xy[0]), high.goal, dt=DT).steps
    assert arrival(low) > PLANNER.reference(tuple(low.xy[0]), low.goal, dt=DT).steps + 4
    for b in (east, north):
        assert floor_violations(b) == []
        assert_plans_honest(b)


@settings(max_examples=6, deadline=None)
@given(
    st.lists(
        st.tuples(st.integers(1, 13), st.integers(1, 11), st.integers(1, 13), st.integers(1, 11)),
        min_size=3,
        max_size=3,
    ),
    st.permutations([1, 2, 3]),
)
def test_three_followers_in_a_room_never_collide(
    trips: list[tuple[int, int, int, int]], priorities: list[int]
) -> None:
    starts = [(float(a), float(b)) for a, b, _, _ in trips]
    goals = [(float(c), float(d)) for _, _, c, d in trips]
    # Starts and goals apart, as the engine spreads robots and the dispatcher sends them.
    for pts in (starts, goals):
        for i in range(3):
            for j in range(i):
                if math.dist(pts[i], pts[j]) <= GAP + 0.2:
                    return
    bots = [
        Bot(f"r{i}", s, goal=g, priority=p)
        for i, (s, g, p) in enumerate(zip(starts, goals, priorities, strict=True))
    ]
    simulate(bots, 300, until=lambda: all(b.arrived() for b in bots))
    for i in range(3):
        assert floor_violations(bots[i]) == []
        assert_plans_honest(bots[i])
        for j in range(i):
            assert closest(bots[i], bots[j]) > 2 * RADIUS


# --- rule 3: deadlocks ----------------------------------------------------------------------------


def test_blockers_are_routed_round_with_the_gap() -> None:
    start, goal = (3.0, 6.0), (12.0, 6.0)
    bot = Bot("r1", start, goal=goal, blockers=("r2",))
    parked = Scripted("r2", (7.5, 6.0), (0.0, 0.0), priority=9, send_plan=False)
    simulate([bot], 400, (parked,), until=bot.arrived)
    assert bot.arrived()
    assert closest(bot, parked) >= GAP - 1e-6
    assert all(c.status is ControlStatus.OK for c in bot.commands)
    # Straight there was the normal way; the detour costs a little.
    assert len(bot.xy) > PLANNER.reference(start, goal, dt=DT).steps
    assert floor_violations(bot) == []
    assert_plans_honest(bot)


def test_when_the_blockers_clear_it_goes_back_to_the_normal_route() -> None:
    start, goal = (3.0, 6.0), (12.0, 6.0)
    bot = Bot("r1", start, goal=goal)
    parked = Scripted("r2", (7.5, 6.0), (0.0, 0.0), duration=0.0, send_plan=False)
    simulate([bot], 30, (parked,), blockers=lambda b, k: ("r2",))
    assert moving(bot.v) and bot.p[1] != 6.0  # on the detour
    # The blocker has gone and so have the blockers: brake to rest, then the normal route.
    first = len(bot.xy)
    simulate([bot], 60, until=lambda: not moving(bot.v))
    rest = bot.p.copy()
    speeds = np.hypot(*np.array(bot.vel[first:]).T)
    assert np.all(np.diff(speeds) < 0)
    ref = PLANNER.reference(tuple(rest), goal, dt=DT)
    resumed = len(bot.xy)
    simulate([bot], 200, until=bot.arrived)
    assert bot.arrived()
    assert len(bot.xy) - resumed == ref.steps
    np.testing.assert_allclose(bot.xy[resumed:], ref.positions[:-1], atol=1e-9)


def test_blockers_no_longer_named_but_standing_where_they_stood_keep_the_detour() -> None:
    # The deadlock watch stops naming blockers once the robot is a little nearer its goal;
    # dropping the detour then braked it and sent it back against the same parked robot
    # (fuzz s21-0312). It keeps the detour, and arrives without stopping.
    start, goal = (3.0, 6.0), (12.0, 6.0)
    bot = Bot("r1", start, goal=goal)
    parked = Scripted("r2", (7.5, 6.0), (0.0, 0.0), send_plan=False)
    simulate([bot], 30, (parked,), blockers=lambda b, k: ("r2",))
    assert moving(bot.v) and bot.p[1] != 6.0  # on the detour
    first = len(bot.xy)
    simulate([bot], 400, (parked,), until=bot.arrived)
    assert bot.arrived()
    assert all(moving(v) for v in bot.vel[first:-1])  # never stopped on the way
    assert all(math.dist(p, (7.5, 6.0)) > 2 * RADIUS for p in bot.xy)
    # It moves: the detour is dropped, the normal route again (braking first).
    bot2 = Bot("r1", start, goal=goal)
    simulate([bot2], 30, (parked,), blockers=lambda b, k: ("r2",))
    moved = Scripted("r2", (7.5, 7.0), (0.0, 0.0), send_plan=False)
    simulate([bot2], 1, (moved,))
    assert bot2.commands[-1].ax * bot2.v[0] + bot2.commands[-1].ay * bot2.v[1] < 0


def test_held_face_to_face_by_a_lower_robot_at_rest_it_plans_round_it() -> None:
    # A lower-priority robot stands still on the way, no blockers named: after FACE_OFF_S at
    # rest the robot routes round it (rule 3 without the watch) and arrives, never closer
    # than the two radii.
    bot = Bot("r1", (3.0, 6.0), goal=(12.0, 6.0), priority=2)
    parked = Scripted("r2", (7.5, 6.0), (0.0, 0.0), priority=1)
    simulate([bot], 2000, (parked,), until=bot.arrived)
    assert bot.arrived()
    assert all(math.dist(p, (7.5, 6.0)) > 2 * RADIUS for p in bot.xy)
    # A higher one is waited for (it routes round this one), as before.
    bot = Bot("r1", (3.0, 6.0), goal=(12.0, 6.0), priority=1)
    higher = Scripted("r2", (7.5, 6.0), (0.0, 0.0), priority=2)
    simulate([bot], int(4 * FACE_OFF_S / DT), (higher,))
    assert not bot.arrived() and bot.p[1] == 6.0


def test_no_way_round_a_robot_at_rest_in_a_door_holds_without_a_hand_back() -> None:
    bot = Bot("r1", (10.0, 6.0), goal=(25.0, 6.0), priority=2)
    door = Scripted("r2", (15.0, 6.0), (0.0, 0.0), priority=1)
    simulate([bot], int(4 * FACE_OFF_S / DT), (door,))
    assert all(c.status is ControlStatus.OK for c in bot.commands)
    assert math.dist(bot.p, (15.0, 6.0)) > 2 * RADIUS
    # It went back to its own route: it sets off once the door is free.
    simulate([bot], 2000, until=bot.arrived)
    assert bot.arrived()


def test_no_route_round_the_blockers_is_blocked_and_holds_until_they_clear() -> None:
    bot = Bot("r1", (10.0, 6.0), goal=(25.0, 6.0))
    # Standing in the corridor, the only way east.
    stuck = Scripted("r2", (15.0, 6.0), (0.0, 0.0), send_plan=False)
    simulate([bot], 12, (stuck,), blockers=lambda b, k: ("r2",))
    assert all(c.status is ControlStatus.BLOCKED for c in bot.commands)
    assert all((c.ax, c.ay) == (0.0, 0.0) for c in bot.commands)
    assert np.array_equal(bot.p, (10.0, 6.0))
    # Cleared (the engine gave up on it, or the robot left): the normal route again.
    simulate([bot], 4, (stuck,))
    assert bot.commands[-1].status is ControlStatus.OK and moving(bot.v)


def test_blocked_while_moving_brakes_first() -> None:
    bot = Bot("r1", (3.0, 6.0), goal=(25.0, 6.0))
    simulate([bot], 12)
    assert moving(bot.v)
    stuck = Scripted("r2", (15.0, 6.0), (0.0, 0.0), send_plan=False)
    before = len(bot.xy)
    simulate([bot], 40, (stuck,), blockers=lambda b, k: ("r2",), until=lambda: False)
    statuses = [c.status for c in bot.commands[before:]]
    speeds = np.hypot(*np.array(bot.vel[before:]).T)
    stopped = int(np.argmax(speeds <= 1e-9))
    assert stopped > 0 and np.all(np.diff(speeds[: stopped + 1]) < 0)
    assert set(statuses[stopped + 1 :]) == {ControlStatus.BLOCKED}


# --- the pieces -----------------------------------------------------------------------------------


def test_braking_path_stops_along_the_line_of_travel() -> None:
    path = braking_path(0.0, 1.0, 2.0, 0.8, -0.4, DT, A_MAX)
    t, x, y = np.array(path).T
    assert np.allclose(np.diff(t), DT) and path[0] == (0.0, 1.0, 2.0)
    # On the line through the start along (2, -1), 0.8**2 / (2 * 0.5) m away, give or take
    # the sampling.
    assert np.allclose((x - 1.0) * -0.4 - (y - 2.0) * 0.8, 0.0, atol=1e-12)
    # The fast axis slows by a_max*dt a step: 0.8, 0.675, ..., 0.05, then rest.
    assert x[-1] - 1.0 == pytest.approx(DT * sum(0.8 - 0.125 * k for k in range(7)), abs=1e-12)
    assert len(path) == 8


def test_forecast_interpolates_a_plan_and_holds_its_last_sample() -> None:
    n = Neighbour("r2", 0.0, 0.0, 1.0, 0.0, plan=((1.0, 1.0, 0.0), (2.0, 1.0, 1.0)))
    f = Forecast.of(n, 0.0, DT, A_MAX)
    assert f.at(0.5) == (0.5, 0.0) and f.at(1.5) == (1.0, 0.5) and f.at(9.0) == (1.0, 1.0)
    assert f.distance(9.0, 4.0, 5.0) == pytest.approx(5.0)


def test_a_neighbour_with_a_plan_may_also_brake_at_any_tick() -> None:
    n = Neighbour("r2", 0.0, 0.0, 1.0, 0.0, plan=((5.0, 5.0, 0.0),))
    f = Forecast.of(n, 0.0, DT, A_MAX)
    # It decides in the same tick as the observer, so it may brake at once: 1.125 m on.
    stop = braking_path(0.0, 0.0, 0.0, 1.0, 0.0, DT, A_MAX)[-1][1]
    assert stop == pytest.approx(1.125)
    # At t = 3 s it is at x = 3 on its plan, or stopped at x = 1.125, or anywhere between.
    assert f.at(3.0) == (3.0, 0.0)
    for x in (stop, 2.0, 3.0):
        assert f.distance(3.0, x, 0.0) == pytest.approx(0.0, abs=1e-12)
    assert f.distance(3.0, stop - 0.5, 0.0) == pytest.approx(0.5)
    assert f.distance(3.0, 3.5, 0.0) == pytest.approx(0.5)


def test_a_neighbour_setting_off_in_the_same_tick_is_kept_a_step_further_away() -> None:
    # At a period of 1 s a neighbour at rest, its plan "stay", may set off in this very tick:
    # a step of a_max*dt**2 = 0.5 m per axis before its next plan shows it.
    dt = 1.0
    f = Forecast.of(Neighbour("r2", 2.0, 0.0, 0.0, 0.0, plan=((0.0, 2.0, 0.0),)), 0.0, dt, A_MAX)
    assert f.lead == pytest.approx(math.sqrt(2.0) * A_MAX * dt * dt)
    towards = [(1.0, 0.0, 0.0), (2.0, 0.5, 0.0)]  # one step towards it, then at rest
    away = [(1.0, 0.0, 0.0), (2.0, -0.5, 0.0)]
    # 1.5 m apart after the step: more than the gap (0.9 m), less than the gap plus the lead.
    assert f.lead > 1.5 - GAP
    assert not stops_clear(towards, [f], RADIUS, MARGIN, (0.0, 0.0, 0.0))
    assert stops_clear(away, [f], RADIUS, MARGIN, (0.0, 0.0, 0.0))
    # Farther off the same step is clear; at a period of 0.25 s the lead is 4 cm.
    far = Forecast.of(Neighbour("r2", 3.0, 0.0, 0.0, 0.0, plan=((0.0, 3.0, 0.0),)), 0.0, dt, A_MAX)
    assert stops_clear(towards, [far], RADIUS, MARGIN, (0.0, 0.0, 0.0))
    fine = Forecast.of(Neighbour("r2", 2.0, 0.0, 0.0, 0.0, plan=((0.0, 2.0, 0.0),)), 0.0, DT, A_MAX)
    assert fine.lead < 0.05
    assert stops_clear(towards, [fine], RADIUS, MARGIN, (0.0, 0.0, 0.0))


def test_forecast_without_a_plan_covers_one_step_and_its_braking() -> None:
    n = Neighbour("r2", 0.0, 0.0, 1.0, 0.0)
    f = Forecast.of(n, 0.0, DT, A_MAX)
    stop = 0.25 + braking_path(0.0, 0.0, 0.0, 1.0, 0.0, DT, A_MAX)[-1][1]
    for t in (0.0, 1.0, 5.0):
        assert f.distance(t, stop, 0.0) == 0.0 and f.distance(t, -0.1, 0.0) > 0.05
        assert f.distance(t, stop + 1.0, 0.0) == pytest.approx(1.0 - f.slack)


def test_stops_clear_needs_more_than_the_gap_at_every_sample() -> None:
    f = Forecast.of(Neighbour("r2", 2.0, 0.0, 0.0, 0.0, plan=((0.0, 2.0, 0.0),)), 0.0, DT, A_MAX)
    # The gap and the step it may take in this same tick.
    need = GAP + f.lead
    far = [(0.25, 1.0, -1.0), (0.5, 2.0 - need - 0.01, 0.0)]
    near = [(0.25, 1.0, -1.0), (0.5, 2.0 - need + 0.01, 0.0)]
    assert stops_clear(far, [f], RADIUS, MARGIN, (0.0, 0.0, 0.0))
    assert not stops_clear(near, [f], RADIUS, MARGIN, (0.0, 0.0, 0.0))


def test_must_yield_only_where_the_higher_robot_comes_first_and_moves() -> None:
    own = [(0.25 * i, 0.25 * i, 0.0) for i in range(17)]  # 1 m/s east, 4 s
    ahead = Forecast.of(Neighbour("h", 3.0, -3.0, 0, 1, plan=((4.0, 3.0, 1.0),)), 0.0, DT, A_MAX)
    late = Forecast.of(Neighbour("h", 1.0, -3.0, 0, 1, plan=((4.0, 1.0, 1.0),)), 0.0, DT, A_MAX)
    parked = Forecast.of(Neighbour("h", 2.0, 0.5, 0, 0, plan=((0.0, 2.0, 0.5),)), 0.0, DT, A_MAX)
    assert must_yield(own, ahead, GAP)  # at x = 3 at t = 3 s, before the robot (t = 3 s)
    assert not must_yield(own, late, GAP)  # at x = 1 at t = 3 s: the robot passed it at 1 s
    assert not must_yield(own, parked, GAP)  # standing: rule 1's business


def test_a_detour_floor_is_the_floor_compiled_with_the_blocker_as_an_obstacle() -> None:
    blocker = ("r2", 7.5, 6.0, RADIUS)
    detour = Detour.build(FLOOR, [blocker], RADIUS, MARGIN, (3.0, 6.0), A_MAX)
    assert detour.key == ("r2",) and detour.clearance == {"r2": pytest.approx(GAP)}
    # The same free space as compiling the map with the blocker's polygon (grown by the map's
    # clearance) among the obstacles, but only the regions it touches were cut again.
    hole = _polygon(7.5, 6.0, GAP - FLOOR.spec.clearance, Detour.SIDES)
    spec = replace(FLOOR.spec, obstacles=(*FLOOR.spec.obstacles, Obstacle("r2", hole)))
    compiled = compile_floor(spec)
    assert detour.floor is not None
    assert detour.floor.free_space.symmetric_difference(compiled.free_space).area < 1e-6
    kept = {r.polygon.wkt for r in FLOOR.regions} & {r.polygon.wkt for r in detour.floor.regions}
    assert 0 < len(kept) < len(FLOOR.regions)
    # Its paths keep the clearance from the blocker, and one in the corridor closes the way.
    path = detour.planner(SPEC.v_max).path((3.0, 6.0), (12.0, 6.0))
    line = shapely.LineString(path.waypoints)
    assert line.distance(shapely.Point(7.5, 6.0)) >= GAP - 1e-6
    corridor = Detour.build(FLOOR, [("r2", 15.0, 6.0, RADIUS)], RADIUS, MARGIN, (10, 6), A_MAX)
    with pytest.raises(NoPathError):
        corridor.planner(SPEC.v_max).path((10.0, 6.0), (25.0, 6.0))


# --- the whole engine -----------------------------------------------------------------------------
# These run the real engine (fleet.engine.World), which fills neighbours, priorities and blockers.

HALL = """
[floor]
name = "crossing hall"
rect = [0, 0, 24, 16]
default_v_max = 1.0
clearance = 0.4

[[obstacles]]
name = "press"
rect = [10, 6, 14, 10]

[[stations]]
name = "west"
at = [2, 8]
kind = "depot"

[[stations]]
name = "east"
at = [22, 8]
kind = "depot"

[[stations]]
name = "north"
at = [12, 14]

[[stations]]
name = "south"
at = [12, 2]
"""


def hall_scenario(
    tmp_path: Path, jobs: list[tuple[float, str]], count: int = 4, seconds: float = 240
) -> Scenario:
    (tmp_path / "hall.toml").write_text(HALL)
    lines = [
        "[scenario]",
        'map = "hall.toml"',
        f"duration_s = {seconds}",
        "sensing_radius_m = 6.0",
        "deadlock_after_s = 15",
        "[robots]",
        f"count = {count}",
        'start = ["west", "east"]',
        "return_home = true",
        "[dispatcher]",
        'name = "greedy"',
        "[jobs]",
        'mode = "scripted"',
    ]
    for at, station in jobs:
        lines += ["[[jobs.scripted]]", f"at_s = {at}", f'station = "{station}"']
    path = tmp_path / "run.toml"
    path.write_text("\n".join(lines) + "\n")
    return load_scenario(path)


def test_a_fleet_crossing_the_hall_never_collides_and_delivers(tmp_path: Path) -> None:
    # Four robots from both ends, jobs to the far ends and round the press both ways: they meet
    # head-on, cross and queue at the stations, then drive home through each other again.
    jobs = [(0, "east"), (0, "west"), (0, "north"), (0, "south"), (5, "north"), (5, "south")]
    scenario = hall_scenario(tmp_path, jobs)
    world = World(scenario)
    s = world.run().summary
    assert s["violations"] == {"obstacle": 0, "speed_zone": 0, "print_speed": 0, "collision": 0}
    assert s["jobs"]["completed"] == len(jobs)
    # They did meet: some came within half a metre of the gap.
    paths = [t.arrays()[1] for t in world.recorder.trajectories.values()]
    n = min(len(p) for p in paths)
    closest_pair = min(
        float(np.min(np.hypot(*(a[:n] - b[:n]).T))) for i, a in enumerate(paths) for b in paths[:i]
    )
    assert 2 * RADIUS < closest_pair < GAP + 0.5
    # Blind (no neighbours in the observations) the same fleet collides.
    blind = World(replace(scenario, sensing_radius_m=0.0)).run().summary
    assert blind["violations"]["collision"] > 0


def test_the_shipped_fleet_scenario_runs_ten_minutes_without_a_collision() -> None:
    scenario = load_scenario(REPO_ROOT / "scenarios" / "fleet.toml").override(duration=600.0)
    s = World(scenario).run().summary
    assert s["violations"]["collision"] == 0
    assert s["jobs"]["completed"] > 5
