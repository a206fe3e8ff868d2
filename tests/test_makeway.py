"""Making way (fleet.engine.makeway): where an idle robot that blocks a stuck one goes, judged
with shapely from the map file, and how long it stays there."""

from __future__ import annotations

import math
import tomllib
from dataclasses import replace
from pathlib import Path

import pytest
from hypothesis import event, example, given, settings
from hypothesis import strategies as st
from shapely.geometry import LineString, Point, box

from fleet.engine import World
from fleet.engine.makeway import AWAY_M, HOLD_FACTOR, OTHERS_M, Aside, MakeWay, kept_gap
from fleet.scenario import load_scenario, sensing_needed

CASE = Path(__file__).resolve().parent / "cases" / "via_parked_robot"


@pytest.fixture(scope="module")
def world() -> World:
    w = World(load_scenario(CASE / "scen.toml"))
    yield w
    w._close_bus()


def fresh(world: World) -> MakeWay:
    """A MakeWay of the world's own with nothing asked yet."""
    w = world
    return MakeWay(w.floor, w.robots, w.recorder, w.planner_for, w.scenario.deadlock_after_s)


def hall_from_map() -> tuple[box, float]:
    """The hall the map file describes, shrunk by its clearance: where centres may be."""
    spec = tomllib.loads((CASE / "floor.toml").read_text())["floor"]
    x0, y0, x1, y1 = spec["rect"]
    c = spec["clearance"]
    return box(x0 + c, y0 + c, x1 - c, y1 - c), c


@settings(max_examples=40, deadline=None)
@given(
    idle_xy=st.tuples(st.floats(1.0, 29.0), st.floats(1.0, 19.0)),
    stuck_xy=st.tuples(st.floats(1.0, 29.0), st.floats(1.0, 19.0)),
)
def test_the_spot_aside_is_free_off_the_route_and_reached_without_closing_in(
    world: World, idle_xy, stuck_xy
) -> None:
    idle, stuck = world.robots["r01"], world.robots["r02"]
    hall, _ = hall_from_map()
    if not (hall.covers(Point(idle_xy)) and hall.covers(Point(stuck_xy))):
        return
    if math.dist(idle_xy, stuck_xy) < idle.spec.radius + stuck.spec.radius:
        return
    idle.x, idle.y = idle_xy
    stuck.x, stuck.y = stuck_xy
    idle.aside = None
    goal = (idle.x, idle.y)  # the worst case: the idle robot stands on the stuck one's goal
    fresh(world).ask(stuck, goal, [idle], t=0.0)
    assert idle.aside is not None  # an empty hall always has room aside
    spot = idle.aside.spot
    assert hall.covers(Point(spot))
    away = idle.spec.radius + stuck.spec.radius + AWAY_M
    route = LineString([stuck_xy, goal])  # an empty hall: the route is the straight line
    assert route.distance(Point(spot)) >= away - 1e-9
    start_gap = math.dist(idle_xy, stuck_xy)
    leg = LineString([idle_xy, spot])
    reach = idle.spec.radius + stuck.spec.radius + OTHERS_M
    assert leg.distance(Point(stuck_xy)) >= min(start_gap, reach) - 1e-6


def test_an_empty_hall_always_has_a_spot(world: World) -> None:
    idle, stuck = world.robots["r01"], world.robots["r02"]
    idle.x, idle.y, stuck.x, stuck.y = 5.0, 10.0, 5.96, 10.0
    idle.aside = None
    fresh(world).ask(stuck, (5.0, 10.0), [idle], t=3.0)
    assert idle.aside is not None
    assert idle.aside.made_way_for == "r02"
    assert idle.aside.until == pytest.approx(3.0 + HOLD_FACTOR * world.scenario.deadlock_after_s)


def test_the_idle_robot_holds_its_spot_until_the_stuck_robot_moves_on(world: World) -> None:
    idle, stuck = world.robots["r01"], world.robots["r02"]
    idle.x, idle.y, stuck.x, stuck.y = 15.0, 10.0, 13.5, 10.0
    idle.aside, idle.job, stuck.job = None, None, None
    stuck.return_home = True
    stuck.watched_goal = stuck.home  # what the deadlock watch saw it head for
    make_way = fresh(world)
    make_way.ask(stuck, stuck.home, [idle], t=0.0)  # stuck on its way home
    spot = idle.aside.spot
    assert make_way.goal_of(idle, 1.0) == spot
    # Past the hold it goes home, even if the other is still where it was.
    assert make_way.goal_of(idle, idle.aside.until + 1.0) == idle.home
    assert idle.aside is None
    make_way.ask(stuck, stuck.home, [idle], t=1.0)  # asked again within a deadlock period
    assert idle.aside is None
    make_way.ask(stuck, stuck.home, [idle], t=world.scenario.deadlock_after_s)
    assert idle.aside is not None
    # Driven on: nearer its goal by the passing distance, but still beside the spot.
    passed = idle.aside.passed_m
    stuck.x = idle.aside.spot[0] + 0.5 * passed
    assert make_way.goal_of(idle, 2.0) == idle.aside.spot
    stuck.x = idle.aside.spot[0] + passed + 0.1  # past: the way home is free
    assert make_way.goal_of(idle, 2.0) == idle.home
    stuck.x = 13.5
    make_way.ask(stuck, stuck.home, [idle], t=2 * world.scenario.deadlock_after_s)
    stuck.faulted = True  # the robot it made way for lost its agent: no need to wait
    try:
        assert make_way.goal_of(idle, 1.0) == idle.home
    finally:
        stuck.faulted = False


def aside_near_home(world: World, make_way: MakeWay):
    """r02, stuck 1 m from home (nearer than a robot must gain to be "past" the one aside),
    asks the idle r01, 2.5 m from it, to step aside: (r01, r02, r01's spot)."""
    idle, stuck = world.robots["r01"], world.robots["r02"]
    hx, hy = stuck.home
    idle.x, idle.y, stuck.x, stuck.y = hx + 2.5, hy, hx + 1.0, hy
    idle.aside, idle.job, stuck.job = None, None, None
    stuck.return_home = True
    stuck.watched_goal = stuck.home
    make_way.ask(stuck, stuck.home, [idle], t=0.0)
    return idle, stuck, idle.aside.spot


def test_the_wait_aside_ends_once_the_other_is_at_rest_on_its_goal_not_driving_through(
    world: World,
) -> None:
    # Fuzz s21-0607: an MPC robot braking into its station ran 0.07 m past it at 0.44 m/s;
    # the robot aside took that for "there", came back into its way, and the other stood
    # 0.37 m short of the station for 15 s.
    make_way = fresh(world)
    idle, stuck, spot = aside_near_home(world, make_way)
    hx, _ = stuck.home
    stuck.x, stuck.vx = hx - 0.07, -0.44  # through its goal, at speed
    try:
        assert make_way.goal_of(idle, 1.0) == spot
        stuck.vx = 0.0  # at rest there: it has arrived, and the way back is free
        assert make_way.goal_of(idle, 1.0) == idle.home
    finally:
        stuck.x, stuck.y, stuck.vx = 13.5, 10.0, 0.0


def test_the_wait_aside_lasts_until_the_other_has_arrived_as_the_run_counts_arrival(
    world: World,
) -> None:
    # Fuzz s61-0236: an MPC robot stopped 0.057 m from its station, inside `ARRIVED_M` but
    # outside the run's 0.05 m tolerance; the robot it had sent aside came straight back and
    # kept it out of the last 7 mm for 90 s.
    w = world
    make_way = MakeWay(w.floor, w.robots, w.recorder, w.planner_for, 10.0, arrival_m=0.05)
    assert make_way.arrival_m == 0.05
    idle, stuck, spot = aside_near_home(world, make_way)
    hx, _ = stuck.home
    try:
        stuck.x, stuck.vx = hx + 0.057, 0.0  # at rest, not yet arrived
        assert make_way.goal_of(idle, 1.0) == spot
        stuck.x = hx + 0.04  # arrived
        assert make_way.goal_of(idle, 1.0) == idle.home
    finally:
        stuck.x, stuck.y, stuck.vx = 13.5, 10.0, 0.0


@pytest.fixture(scope="module")
def world3() -> World:
    # At a period of 0.8 s the step a robot may take unseen is 0.45 m: the gaps are wider.
    sc = load_scenario(CASE / "scen.toml")
    group = replace(sc.robots[0], count=3, period_s=0.8)
    # Robots that see each other far enough to stop for each other (check_fleet's rule).
    sensing = math.ceil(sensing_needed(group, group) * 10) / 10
    w = World(replace(sc, robots=(group,), sensing_radius_m=sensing))
    yield w
    w._close_bus()


@settings(max_examples=60, deadline=None)
@given(xy=st.lists(st.tuples(st.floats(1.0, 29.0), st.floats(1.0, 19.0)), min_size=3, max_size=3))
@example(xy=[(1.0, 1.0), (1.0, 2.0), (2.0, 1.0)])  # shut in a corner: the stuck robot backs off
def test_the_way_aside_keeps_the_followers_gap_from_every_robot(world3: World, xy) -> None:
    # A robot packed in among others at a depot was sent to a spot past one of them (0.54 m
    # from it, where the follower keeps 0.73 m) and never moved; at a period of 0.5 s one sent
    # 1.13 m off the stuck robot's goal, where that keeps 1.3 m, left it shut out (fuzz seed
    # 7, s7-0064). The way keeps radii + max(0.2, 0.1 + sqrt(2) a_max dt^2) from every robot
    # (or, already closer, never closes in), the spot that plus 0.2 m off the route.
    idle, stuck, third = (world3.robots[r] for r in ("r01", "r02", "r03"))
    hall, _ = hall_from_map()
    if not all(hall.covers(Point(p)) for p in xy):
        return
    for robot, p in zip((idle, stuck, third), xy, strict=True):
        robot.x, robot.y = p
        robot.aside, robot.watched_goal = None, None
    r = idle.spec.radius
    if any(math.dist(p, q) < 2 * r for i, p in enumerate(xy) for q in xy[i + 1 :]):
        return
    goal = (idle.x, idle.y)
    fresh(world3).ask(stuck, goal, [idle], t=0.0)
    event("spot found" if idle.aside is not None else "no spot")
    if idle.aside is None:
        return
    spot = idle.aside.spot
    spec = idle.spec
    kept = 0.1 + math.sqrt(2.0) * spec.a_max * spec.period**2
    leg = LineString([xy[0], spot])
    # Shut in by the stuck robot (no spot off its route it could reach), the idle robot is let
    # out past it once the stuck robot has backed off its way: that one's way is then kept.
    backs = stuck.aside is not None and stuck.aside.made_way_for == idle.id
    event("stuck robot backs off" if backs else "way kept from both")
    others = ((third, xy[2]),) if backs else ((stuck, xy[1]), (third, xy[2]))
    for other, p in others:
        reach = min(r + other.spec.radius + max(OTHERS_M, kept), math.dist(xy[0], p))
        assert leg.distance(Point(p)) >= reach - 1e-6
    route = LineString([xy[1], goal])
    assert route.distance(Point(spot)) >= 2 * r + kept + OTHERS_M - 1e-9
    if backs:
        back = LineString([xy[1], stuck.aside.spot])
        for p in (xy[0], xy[2]):
            reach = min(2 * r + max(OTHERS_M, kept), math.dist(xy[1], p))
            assert back.distance(Point(p)) >= reach - 1e-6


def test_the_wait_aside_outlasts_the_other_backing_off_for_a_third(world3: World) -> None:
    # Fuzz s91-0723: r07 stood aside for r05, whose job went via a depot ringed by parked
    # robots; r05 then backed off to let r01, parked on the depot, out, and r07's wait ended
    # at once (r05 headed elsewhere): it drove home into the ring, across r01's way out, and
    # the back-off came back to the same block every 70 s. The robot made way for still comes
    # back to the goal it was made way to, so the one aside holds its spot.
    idle, stuck, third = (world3.robots[r] for r in ("r01", "r02", "r03"))
    for robot in (idle, stuck, third):
        robot.aside, robot.job, robot.watched_goal = None, None, None
    hx, hy = stuck.home
    idle.x, idle.y, stuck.x, stuck.y, third.x, third.y = hx + 2.5, hy, hx + 6.0, hy, 25.0, 15.0
    stuck.return_home = True
    stuck.watched_goal = stuck.home
    make_way = fresh(world3)
    make_way.ask(stuck, stuck.home, [idle], t=0.0)  # stuck on its way home
    spot = idle.aside.spot
    # The stuck robot backs off for the third one: it heads for its own spot now.
    back = (hx + 6.0, hy + 3.0)
    stuck.aside = Aside(back, third.id, (third.x, third.y), 5.0, 2.0, 100.0)
    stuck.watched_goal = back
    try:
        assert make_way.goal_of(idle, 1.0) == spot
        # Once it would not come back to that goal (idle, not going home), the wait ends.
        stuck.return_home = False
        assert make_way.goal_of(idle, 1.0) == idle.home
    finally:
        stuck.return_home = True
        for robot in (idle, stuck, third):
            robot.aside, robot.watched_goal = None, None


def test_a_robot_at_rest_a_rounding_off_its_goal_is_parked_and_let_out(world3: World) -> None:
    # Fuzz s91-0045 (on the branch of s91-0723's fix): r04 stood at home 1.008e-9 m off it
    # (rounding), in the way of r03 going home; "parked" meant within 1e-9 m, so r03 backed
    # off to let r04 go where it already was, the back-off ended at once, and r04 was never
    # sent aside. At rest at its goal as the run counts arrival, it is parked for good.
    idle, stuck, third = (world3.robots[r] for r in ("r01", "r02", "r03"))
    for robot, p in zip((idle, stuck, third), ((1.0, 1.0), (1.0, 2.0), (2.0, 1.0)), strict=True):
        robot.x, robot.y = p
        robot.vx = robot.vy = 0.0
        robot.aside, robot.job = None, None
    idle.watched_goal = (1.0 + 1.5e-9, 1.0)  # home, off by a rounding
    stuck.watched_goal = third.watched_goal = None
    try:
        fresh(world3).ask(stuck, (idle.x, idle.y), [idle], t=0.0)  # shut in a corner
        assert stuck.aside is not None and stuck.aside.made_way_for == idle.id
        assert idle.aside is not None and idle.aside.made_way_for == stuck.id
    finally:
        for robot in (idle, stuck, third):
            robot.aside, robot.watched_goal = None, None


ZIGZAG = Path(__file__).resolve().parent / "liveness_cases" / "aside_by_a_zigzag"


def test_the_way_aside_is_the_path_the_robot_drives_not_the_straight_line() -> None:
    # Fuzz s113-0449 (MPC), the robots as they stood at 115.4 s: r01 (to st1) and r05 (west to
    # st2) stuck face to face south of a triangle with a 0.29 m/s zone round it, r02 west of
    # r01, the wall south. r05 had no spot off r01's route, so r01 backed off r05's: to a
    # spot 1.42 m north, judged by the straight leg there. Zone limits hold per axis, so the
    # path layer's quickest way there runs east to within 0.58 m of r05 and back on a
    # diagonal (4.76 s against 4.83 s straight); r01's controller tracked that way, set off
    # north and braked back every 2 s, and r05 stayed stuck until 200.6 s. A robot is now sent
    # only where the path it will track keeps clear of the others (here: nowhere, so the
    # deadlock stays reported).
    w = World(load_scenario(ZIGZAG / "scen.toml"))
    try:
        at = {
            "r01": (5.7445, 29.50),
            "r02": (4.67, 29.35),
            "r03": (7.78, 29.36),
            "r04": (-2.20, 32.59),
            "r05": (6.7605, 29.23),
            "r06": (8.79, 29.17),
        }
        for rid, (x, y) in at.items():
            w.robots[rid].x, w.robots[rid].y = x, y
        r01, r05 = w.robots["r01"], w.robots["r05"]
        st1, st2 = w.floor.station("st1"), w.floor.station("st2")
        r01.watched_goal, r05.watched_goal = (st1.x, st1.y), (st2.x, st2.y)
        fresh(w).ask(r01, (st1.x, st1.y), [r05], t=115.4)
        sent = [rid for rid in at if w.robots[rid].aside is not None]
        for rid in sent:
            robot = w.robots[rid]
            path = w.planner_for(robot.spec).path(at[rid], robot.aside.spot)
            way = LineString(path.waypoints)
            for other, p in at.items():
                if other == rid:
                    continue
                gap = max(OTHERS_M, kept_gap(robot, w.robots[other]))
                reach = min(2 * robot.spec.radius + gap, math.dist(at[rid], p))
                assert way.distance(Point(p)) >= reach - 1e-6, (rid, other, robot.aside.spot)
    finally:
        w._close_bus()
