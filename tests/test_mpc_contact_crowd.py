"""MPC robots in a crowd: a solve keeps clear of every robot its plan runs into, not only of
the `max_neighbours` nearest (issue 16).

80 MPC robots on the fleet scenario (``scripts/bench_fleet.py --sweep 80 --duration 120``) had
13 contacts. Twelve began the same way: a lower robot's optimal plan ran through a higher robot
that was the fourth to sixth nearest of those it had to keep clear of, so not in its solve
(``max_neighbours = 3``); by the time that robot was among the three nearest, braking could no
longer keep them apart. At 52.0 s, for instance, r54 (priority 107) kept clear of r46, r22 and
r52 (0.90-1.05 m away) and planned to pass 0.28 m from r50 (1.27 m away, fourth) and 0.16 m
from r44 (1.95 m, sixth); it met r50 at 52.75 s (0.37 m, radii 0.4). Now a usable plan is
checked against every robot it must keep clear of and solved again with those it runs into
(`crowd.solve_clear`).

The run below is that situation made small: a robot with a job drives out of a lane of idle
robots parked on both sides (each nearer than the robot parked beyond the lane end, on its
route), so the parked robot on its route is not among the three nearest until it is too late to
stop for it.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from shapely.geometry import box

from fleet.engine import World
from fleet.engine.sensing import thin_plan
from fleet.floor import Floor, FloorSpec, Station, compile_floor
from fleet.paths import PathPlanner
from fleet.plugins import ControllerContext, Neighbour, Observation, RobotSpec
from fleet.scenario import (
    JobsConfig,
    PluginChoice,
    RobotsConfig,
    Scenario,
    ScriptedJob,
    sensing_needed,
)
from fleet_plugins.mpc.controller import MPCController
from fleet_plugins.mpc.crowd import intrudes
from fleet_plugins.mpc.neighbours import closest_approach, must_hold
from fleet_plugins.mpc.separation import Obstacle, at_rest, predict

RADIUS = 0.4


def lane_floor() -> Floor:
    """An open floor: "j", where the robot with the job starts, in a lane of 8 parking spots
    1 m to either side (x = 5..8), "d" on its route 2 m beyond the lane's end, "v" farther on."""
    lane = [Station(f"w{i}", 5.0 + i // 2, 4.5 + 2.0 * (i % 2)) for i in range(8)]
    return compile_floor(
        FloorSpec(
            source="<mpc contact: lane>",
            name="lane",
            boundary=box(0, 0, 16, 11),
            default_v_max=(1.0, 1.0),
            clearance=0.4,
            stations=(
                Station("j", 5.0, 5.5, kind="depot"),
                *lane,
                Station("d", 10.0, 5.5),
                Station("v", 13.0, 5.5),
            ),
        )
    )


def run_lane(options: dict | None = None) -> tuple[dict, World]:
    """r01 at "j" goes via "v" and back; r02..r09 idle in the lane, r10 idle at "d"."""
    floor = lane_floor()
    group = RobotsConfig(
        count=10,
        start=("j", *(f"w{i}" for i in range(8)), "d"),
        radius=RADIUS,
        period_s=0.25,
    )
    scenario = Scenario(
        name="mpc-contact-lane",
        source="<tests/test_mpc_contact_crowd.py>",
        map=Path("<lane floor>"),
        duration_s=40.0,
        robots=(group,),
        controller=PluginChoice("mpc", options or {}),
        dispatcher=PluginChoice("greedy"),
        jobs=JobsConfig(mode="scripted", scripted=(ScriptedJob(0.0, "j", via=("v",)),)),
        sensing_radius_m=math.ceil(100 * sensing_needed(group, group)) / 100,
        deadlock_after_s=5.0,
    )
    world = World(scenario, floor)
    return world.run().summary, world


def closest_centres(world: World) -> float:
    """The least centre distance of any two robots over the run, between the samples too."""
    ids = sorted(world.robots)
    paths = [world.recorder.trajectories[r].arrays()[1] for r in ids]
    n = min(len(p) for p in paths)
    return min(
        closest_approach(paths[i][:n], paths[j][:n])
        for i in range(len(ids))
        for j in range(i + 1, len(ids))
    )


def test_an_mpc_robot_leaving_a_lane_of_parked_robots_never_runs_into_the_one_beyond() -> None:
    # Before: r01 kept clear of the three nearest lane robots only and planned straight through
    # r10 at "d"; r10 was among the three nearest only 1.5 m away, at 1 m/s: contact.
    summary, world = run_lane()
    assert summary["violations"]["collision"] == 0
    assert closest_centres(world) >= 2 * RADIUS
    assert summary["violations"]["obstacle"] == 0
    # Not vacuous: r01 left the lane and drove up to r10 (which had to make way).
    t, xy, _ = world.recorder.trajectories["r01"].arrays()
    assert np.max(xy[:, 0]) > 8.5
    assert summary["jobs"]["completed"] == 1


def test_a_plan_intrudes_on_a_box_between_samples_and_not_beside_it() -> None:
    # Two robots head-on along one line, 0.5 s steps: no sample inside the box, yet they pass
    # through each other between samples.
    k = np.arange(6)[:, None]
    plan = np.hstack([1.25 * 0.5 * k, np.zeros((6, 1))])
    centres = np.hstack([6.25 - 1.25 * 0.5 * k - 0.625, np.zeros((6, 1))])
    ob = Obstacle.square("r2", centres, 0.9, 0.1)
    assert np.all(np.max(np.abs(plan - centres), axis=1) >= 0.6)
    assert intrudes(ob, plan)
    # 0.85 m to the side: inside the margin, outside contact (0.8 m): not an intrusion.
    assert not intrudes(Obstacle.square("r2", centres + [0.0, 0.85], 0.9, 0.1), plan)
    assert intrudes(Obstacle.square("r2", centres + [0.0, 0.75], 0.9, 0.1), plan)
    # Standing still inside the box from the start is an intrusion too.
    still = np.zeros((6, 2))
    assert intrudes(Obstacle.square("r2", np.tile([0.5, 0.0], (6, 1)), 0.9, 0.1), still)


def test_a_held_mpc_robot_at_rest_says_it_stays() -> None:
    # 80 MPC robots, fleet scenario, after the fix above: r52 (priority 269) stood still, held
    # by r58 (lower, close and moving), and braked at rest without a plan; an empty plan leaves
    # the last one in force, which had r52 move 0.2 m away at 71 s. r58 kept 0.90 m from where
    # that plan put r52 and came within 0.727 m of where it stood (radii 0.4) at 72.8 s. Now the
    # held robot's command says it stays, and its neighbours see it parked.
    spec = RobotSpec(v_max=1.0, a_max=0.5, radius=RADIUS, period=0.25)
    floor = lane_floor()
    lower = Neighbour("r58", 6.0, 5.5, -0.5, 0.0, RADIUS, 103, ((20.0, 6.0, 5.5), (21.0, 5.8, 5.5)))
    obs = Observation("r52", 80, 20.0, 5.0, 5.5, 0.0, 0.0, goal=(2.0, 5.5), job="j1",
                      neighbours=(lower,), priority=269)  # fmt: skip
    assert must_hold(obs, spec, 25, 0.1)  # r58 is lower, moving and close: r52 holds
    controller = MPCController()
    controller.reset(ControllerContext("r52", spec, floor, PathPlanner(floor, 1.0, 0.5)))
    cmd = controller.compute(obs)
    assert (cmd.ax, cmd.ay) == (0.0, 0.0) and cmd.solve is None  # held: braked, no solve
    assert cmd.plan, "an empty plan would leave the robot's last plan in force"
    plan = np.array(cmd.plan)
    assert plan[0, 0] == 20.0 and plan[-1, 0] >= 20.0 + 25 * spec.period - 1e-9
    assert np.all(plan[:, 1:] == [5.0, 5.5])  # where it stands, for the whole horizon
    # As r58 sees it (the engine thins and cuts plans at the tick): parked, kept clear of.
    seen = Neighbour("r52", 5.0, 5.5, 0.0, 0.0, RADIUS, 269, thin_plan(cmd.plan, 0.5))
    assert at_rest(predict(seen, 20.25, spec.period, 25))
