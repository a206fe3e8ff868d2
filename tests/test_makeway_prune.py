"""Making way among many robots: the spot aside is chosen as if every robot were measured.

`MakeWay._spot` and `MakeWay._reachable` measure only the robots near a candidate spot and
the way there (on both axes within the gap, a hair more: `makeway._SURE_M`). These tests
place a crowd at random (hypothesis) and compare the spots found with those found measuring
every robot (`_SURE_M` set to infinity, so that no robot is passed over).
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import fleet.engine.makeway as makeway
from fleet.engine import World
from fleet.engine.makeway import MakeWay
from fleet.scenario import REPO_ROOT, load_scenario

ROBOTS = 30


@pytest.fixture(scope="module")
def world() -> World:
    base = load_scenario(REPO_ROOT / "scenarios" / "default.toml")
    w = World(replace(base.override(robots=ROBOTS, duration=10.0), parts={}, print_caps={}))
    yield w
    w._close_bus()


def fresh(world: World) -> MakeWay:
    w = world
    return MakeWay(w.floor, w.robots, w.recorder, w.planner_for, w.scenario.deadlock_after_s)


# A crowd round a point of the shop floor's hall (80 x 50 m): some robots within the gaps
# measured, most not.
offsets = st.lists(
    st.tuples(st.floats(-5.0, 5.0), st.floats(-5.0, 5.0)), min_size=ROBOTS, max_size=ROBOTS
)


@settings(max_examples=60, deadline=None)
@given(
    centre=st.tuples(st.floats(20.0, 60.0), st.floats(15.0, 40.0)),
    crowd=offsets,
    goal=st.tuples(st.floats(2.0, 78.0), st.floats(2.0, 48.0)),
    past=st.booleans(),
)
def test_the_spot_aside_is_the_one_measuring_every_robot_gives(
    world: World, centre, crowd, goal, past: bool
) -> None:
    robots = list(world.robots.values())
    for r, (dx, dy) in zip(robots, crowd, strict=True):
        r.x, r.y = centre[0] + dx, centre[1] + dy
    stuck, robot = robots[0], robots[1]
    way = fresh(world)
    route = way._route(stuck, goal)
    spot = way._spot(robot, stuck, route, past)
    reach = [way._reachable(robot, stuck, (r.x + 0.3, r.y - 0.2), past) for r in robots[2:8]]
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(makeway, "_SURE_M", math.inf)
        assert way._spot(robot, stuck, route, past) == spot
        assert [
            way._reachable(robot, stuck, (r.x + 0.3, r.y - 0.2), past) for r in robots[2:8]
        ] == reach


@settings(max_examples=150, deadline=None)
@given(
    start=st.tuples(st.floats(20.0, 60.0), st.floats(15.0, 40.0)),
    # Along an axis most often: there the way's bounding box is thin and prunes most.
    heading=st.one_of(
        st.sampled_from([0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi]),
        st.floats(0.0, 2.0 * math.pi),
    ),
    length=st.floats(0.5, 6.0),
    # One robot beside the way: how far along it, and how far off it (within the gap kept,
    # a little beyond, or further); the others well off it.
    along=st.floats(-0.5, 1.5),
    off=st.floats(-1.6, 1.6),
    past=st.booleans(),
)
def test_a_way_is_clear_as_measuring_every_robot_says(
    world: World, start, heading: float, length: float, along: float, off: float, past: bool
) -> None:
    robots = list(world.robots.values())
    robot, stuck = robots[0], robots[1]
    ux, uy = math.cos(heading), math.sin(heading)
    robot.x, robot.y = start
    spot = (start[0] + length * ux, start[1] + length * uy)
    stuck.x, stuck.y = start[0] - 3.0 * ux, start[1] - 3.0 * uy
    for i, r in enumerate(robots[2:]):
        side = off if i == 0 else 4.0 + 0.5 * i
        r.x = start[0] + along * length * ux - side * uy
        r.y = start[1] + along * length * uy + side * ux
    way = fresh(world)
    reachable = way._reachable(robot, stuck, spot, past)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(makeway, "_SURE_M", math.inf)
        assert way._reachable(robot, stuck, spot, past) == reachable
