"""The greedy dispatcher: oldest job first, nearest idle robot, by distance or by travel time."""

from __future__ import annotations

import pytest
from shapely.geometry import box

from fleet.errors import PluginError
from fleet.floor import Floor, FloorSpec
from fleet.paths import PathPlanner
from fleet.plugins import Assignment, DispatchContext, Job, RobotStatus, load_dispatcher
from fleet.plugins.testing import check_dispatcher, conformance_floor
from fleet_plugins.greedy import METRICS, GreedyDispatcher

FLOOR = conformance_floor()
CONTEXT = DispatchContext(t=0.0, floor=FLOOR, planner=PathPlanner(FLOOR, 1.0, 0.5))


def job(id: str, x: float, y: float, released: float = 0.0) -> Job:
    return Job(id=id, station=f"st-{id}", x=x, y=y, released_s=released)


def robot(id: str, x: float, y: float, idle: bool = True) -> RobotStatus:
    return RobotStatus(id, x, y, 0.0, 0.0, idle=idle, job=None if idle else "other")


def pairs(out: list[Assignment]) -> list[tuple[str, str]]:
    return [(a.job, a.robot) for a in out]


def test_oldest_job_first_takes_the_nearest_idle_robot() -> None:
    jobs = [job("late", 3.0, 2.0, released=9.0), job("early", 17.0, 8.0, released=1.0)]
    robots = [robot("r1", 2.0, 2.0), robot("r2", 15.0, 8.0), robot("r3", 17.0, 9.0, idle=False)]
    out = GreedyDispatcher().assign(jobs, robots, CONTEXT)
    # r3 is nearest to "early" but busy; r2 is next; "late" then gets r1.
    assert pairs(out) == [("early", "r2"), ("late", "r1")]


def test_the_oldest_job_may_take_the_robot_a_younger_job_wanted() -> None:
    jobs = [job("young", 2.0, 2.0, released=5.0), job("old", 6.0, 2.0, released=0.0)]
    robots = [robot("near-young", 2.5, 2.0), robot("far", 18.0, 9.0)]
    out = GreedyDispatcher().assign(jobs, robots, CONTEXT)
    assert pairs(out) == [("old", "near-young"), ("young", "far")]


def test_equal_release_times_go_by_job_id_and_equal_distances_by_robot_id() -> None:
    jobs = [job("b", 5.0, 5.0), job("a", 5.0, 5.0)]
    robots = [robot("zed", 5.0, 7.0), robot("amy", 5.0, 3.0), robot("bob", 3.0, 5.0)]
    out = GreedyDispatcher().assign(jobs, robots, CONTEXT)
    assert pairs(out) == [("a", "amy"), ("b", "bob")]  # all three are 2 m away


def test_more_jobs_than_idle_robots_leaves_the_youngest_open() -> None:
    jobs = [job(f"j{i}", 2.0 + i, 2.0, released=float(i)) for i in range(4)]
    robots = [robot("r1", 19.0, 9.0), robot("r2", 1.0, 1.0), robot("r3", 1.0, 9.0, idle=False)]
    out = GreedyDispatcher().assign(jobs, robots, CONTEXT)
    assert pairs(out) == [("j0", "r2"), ("j1", "r1")]


def test_travel_time_goes_around_the_press_where_distance_goes_through_it() -> None:
    # A job in the south corridor under the press: the robot in the north corridor is 6 m
    # away as the crow flies but must drive round the press; the one in the west hall is not.
    jobs = [job("under-press", 10.0, 1.5)]
    robots = [robot("north", 10.0, 8.5), robot("west", 2.0, 1.5)]
    by_distance = GreedyDispatcher("euclidean").assign(jobs, robots, CONTEXT)
    by_time = GreedyDispatcher(metric="travel_time").assign(jobs, robots, CONTEXT)
    assert pairs(by_distance) == [("under-press", "north")]
    assert pairs(by_time) == [("under-press", "west")]


def two_rooms() -> DispatchContext:
    spec = FloorSpec(
        source="test_greedy:two_rooms",
        name="two rooms",
        boundary=box(0, 0, 21, 10),
        default_v_max=(1.0, 1.0),
    )
    floor = Floor.from_regions(
        spec, [(box(0, 0, 10, 10), (1.0, 1.0), None), (box(11, 0, 21, 10), (1.0, 1.0), None)]
    )
    return DispatchContext(t=0.0, floor=floor, planner=PathPlanner(floor, 1.0, 0.5))


def test_travel_time_skips_robots_that_cannot_reach_the_job() -> None:
    context = two_rooms()
    jobs = [job("left", 9.0, 5.0, released=0.0), job("right", 20.0, 5.0, released=1.0)]
    robots = [robot("across-the-wall", 12.0, 5.0), robot("same-room", 1.0, 5.0)]
    out = GreedyDispatcher("travel_time").assign(jobs, robots, context)
    assert pairs(out) == [("left", "same-room"), ("right", "across-the-wall")]
    # Euclidean knows no walls: the robot 3 m away across the wall wins.
    out = GreedyDispatcher("euclidean").assign(jobs, robots, context)
    assert pairs(out)[0] == ("left", "across-the-wall")


def test_a_job_nobody_can_reach_stays_open_without_blocking_the_next() -> None:
    context = two_rooms()
    jobs = [job("unreachable", 20.0, 5.0, released=0.0), job("reachable", 2.0, 2.0, released=1.0)]
    out = GreedyDispatcher("travel_time").assign(jobs, [robot("r1", 1.0, 5.0)], context)
    assert pairs(out) == [("reachable", "r1")]


def test_inputs_are_left_as_they_were() -> None:
    jobs = [job("b", 5.0, 5.0, 2.0), job("a", 2.0, 2.0, 1.0)]
    robots = [robot("r2", 1.0, 1.0), robot("r1", 9.0, 9.0, idle=False)]
    before = (list(jobs), list(robots))
    GreedyDispatcher().assign(jobs, robots, CONTEXT)
    assert (jobs, robots) == before


@pytest.mark.parametrize("metric", METRICS)
def test_passes_the_conformance_check(metric: str) -> None:
    check_dispatcher(GreedyDispatcher, options={"metric": metric})


def test_an_unknown_metric_is_refused_naming_it_and_the_allowed_ones() -> None:
    with pytest.raises(ValueError, match=r"metric = 'manhattan'.*'euclidean', 'travel_time'"):
        GreedyDispatcher(metric="manhattan")
    with pytest.raises(PluginError, match=r"'greedy'.*'manhattan'"):
        load_dispatcher("greedy", {"metric": "manhattan"})


def test_is_registered_as_greedy() -> None:
    dispatcher = load_dispatcher("greedy", {"metric": "travel_time"})
    assert isinstance(dispatcher, GreedyDispatcher) and dispatcher.metric == "travel_time"
