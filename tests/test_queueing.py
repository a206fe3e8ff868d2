"""Queueing at stations (fleet.engine.queueing): robots with a job for a station that another
robot with a job stands on wait their turn short of it, with room round it to leave by, and go
in turn. Real runs of both controllers on an open hall, judged from the recorded samples."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fleet.engine import JobRecord, World
from fleet.engine.queueing import StationQueue
from fleet.plugins import Job
from fleet.scenario import load_scenario

FLOOR = """\
[floor]
name = "open hall"
rect = [0, 0, 24, 14]
default_v_max = 1.0
clearance = 0.4

[[stations]]
name = "home_a"
at = [3, 3]
kind = "depot"

[[stations]]
name = "home_b"
at = [3, 7]
kind = "depot"

[[stations]]
name = "home_c"
at = [3, 11]
kind = "depot"

[[stations]]
name = "g"
at = [15, 7]
"""

# Three jobs to g at once, each printing for 40 s: the first robot there waits on g until its
# part is done, and the other two, there about as soon, wait for it.
SCENARIO = """\
[scenario]
name = "three robots, one station"
map = "floor.toml"
duration_s = 150
seed = 1
arrival_tolerance_m = 0.05
sensing_radius_m = 6.0
deadlock_after_s = 30
station_queue = {queue}

[robots]
count = 3
start = ["home_a", "home_b", "home_c"]
v_max = 1.0
a_max = 0.5
radius = 0.4
period_s = 0.25
return_home = true

[controller]
name = "{controller}"

[dispatcher]
name = "greedy"

[jobs]
mode = "scripted"
{jobs}
"""

PRINT = '[[jobs.scripted.print]]\nkind = "contour"\nstart_s = 0.0\nend_s = 40.0\n'
JOBS = "".join(f'\n[[jobs.scripted]]\nat_s = 0\nstation = "g"\n\n{PRINT}' for _ in range(3))
G = (15.0, 7.0)


def run(tmp_path: Path, controller: str, queue: bool) -> tuple[World, dict]:
    """The world after its run, and the run's summary."""
    (tmp_path / "floor.toml").write_text(FLOOR, encoding="utf-8")
    text = SCENARIO.format(queue=str(queue).lower(), controller=controller, jobs=JOBS)
    (tmp_path / "scen.toml").write_text(text, encoding="utf-8")
    world = World(load_scenario(tmp_path / "scen.toml"))
    return world, world.run().summary


def closest_while_taken(world: World) -> float:
    """The least room (m) between the footprint of a robot on g (at rest there with its job
    not yet delivered) and that of another robot whose job to g is not yet delivered."""
    delivered = {e.robot: e.t for e in world.recorder.events if e.event == "delivered"}
    tracks = {rid: world.recorder.trajectories[rid].arrays() for rid in world.robots}
    radius = {rid: r.spec.radius for rid, r in world.robots.items()}
    tol = world.scenario.arrival_tolerance_m
    least = math.inf
    for on, (t, xy, v) in tracks.items():
        at_g = (np.hypot(*(xy - G).T) <= tol) & (np.hypot(*v.T) == 0.0) & (t < delivered[on])
        for other, (t2, xy2, _) in tracks.items():
            if other == on:
                continue
            # The two robots share a period here, so samples line up by index.
            assert np.array_equal(t, t2)
            waiting = at_g & (t < delivered[other])
            if waiting.any():
                gap = np.hypot(*(xy2[waiting] - G).T) - radius[on] - radius[other]
                least = min(least, float(gap.min()))
    return least


@pytest.mark.parametrize("controller", ["follower", "mpc"])
def test_robots_wait_their_turn_with_room_round_the_station(tmp_path, controller) -> None:
    world, summary = run(tmp_path, controller, queue=True)
    assert summary["jobs"]["completed"] == summary["jobs"]["released"] == 3
    assert summary["violations"]["collision"] == 0
    # While one robot is on g, the others leave it at least a footprint of room to leave by
    # (they aim for that and `WAIT_GAP_M` more, braking as they may).
    room = closest_while_taken(world)
    assert room >= 2 * 0.4, room


def test_without_the_queue_robots_crowd_round_the_station(tmp_path) -> None:
    world, summary = run(tmp_path, "follower", queue=False)
    assert summary["jobs"]["completed"] == 3
    assert closest_while_taken(world) < 2 * 0.4


# g moved 1 m north, 1.2 m south of a wall across the hall at y = 9 with a door 1.2 m wide (x
# 14.4 to 15.6): a robot at rest in the door would wait its turn there and shut the way out.
G_DOOR = (15.0, 8.0)
WALL = """
[[obstacles]]
name = "wall_west"
polygon = [[0, 9], [14.4, 9], [14.4, 9.4], [0, 9.4]]

[[obstacles]]
name = "wall_east"
polygon = [[15.6, 9], [24, 9], [24, 9.4], [15.6, 9.4]]
"""


@pytest.mark.parametrize(
    ("wall", "where", "waits"),
    [
        (True, (15.0, 9.2), False),  # in the door: it drives on (in the door it would shut it)
        (False, (15.0, 9.2), True),  # the same spot with no wall: it waits there
        (True, (16.5, 7.6), True),  # beside g, in the open: it waits there
    ],
)
def test_a_robot_waits_its_turn_only_in_the_open(tmp_path, wall, where, waits) -> None:
    floor = FLOOR.replace("at = [15, 7]", "at = [15, 8]") + (WALL if wall else "")
    (tmp_path / "floor.toml").write_text(floor, encoding="utf-8")
    text = SCENARIO.format(queue="true", controller="follower", jobs=JOBS)
    (tmp_path / "scen.toml").write_text(text, encoding="utf-8")
    world = World(load_scenario(tmp_path / "scen.toml"))
    try:
        assert world.floor.is_free(*where)
        job = Job("j1", "g", *G_DOOR, released_s=0.0)
        ahead, behind = world.robots["r01"], world.robots["r02"]
        ahead.x, ahead.y = G_DOOR
        behind.x, behind.y = where  # at rest: it would wait where it stands
        ahead.job, behind.job = JobRecord(job), JobRecord(replace(job, id="j2"))
        queue = StationQueue(world.floor, {"r01": ahead, "r02": behind})
        queue.snapshot()
        assert queue.goal_of(ahead, G_DOOR) == G_DOOR  # the nearest goes on
        assert queue.goal_of(behind, G_DOOR) == (where if waits else G_DOOR)
        assert (queue.station_of(behind) == G_DOOR) is waits
    finally:
        world._close_bus()
