"""Two MPC robots at rest that set off at the same tick (issue 16, MPC fuzz case s41-0057).

r01 (priority 4) had been held at rest 1.77 m from r02 (priority 3), which stood on its via
station st6, r01's goal. At t = 60.8 s r02 got its next goal: both were at rest, so neither was
held (`neighbours.must_hold` holds a higher robot only for a close lower one that moves), and
each planned against the other's last plan, at rest. Both set off at once, r01 towards st6 and
r02 across r01's way: 0.578 m apart at 62.7 s with radii 0.378 (both next positions were fixed
at 61.75 s, too late for either to react). Now a lower robot at rest with a higher one close
shows its start a tick before it moves (`neighbours.must_announce`): the higher one sees it
moving, holds, and the lower one keeps clear of that. The case folder is
tests/contact_cases/both_start_from_rest (the fuzz case as found, 90 s, two robots).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from fleet.engine import World
from fleet.floor import load_floor
from fleet.paths import PathPlanner
from fleet.plugins import ControllerContext, ControlStatus, Neighbour, Observation, RobotSpec
from fleet.scenario import load_scenario
from fleet_plugins.mpc.controller import MPCController
from fleet_plugins.mpc.neighbours import (
    close,
    closest_approach,
    must_announce,
    must_hold,
    robots_to_avoid,
)

CASE = Path(__file__).resolve().parent / "contact_cases" / "both_start_from_rest"
SPEC = RobotSpec(v_max=0.79, a_max=1.49, radius=0.378, period=0.95)
T = 60.80000000000007
R01 = (42.3069397654574, 22.6423371882728)
R02 = (41.07599999999999, 21.367099999999997)
ST6 = (41.076, 21.3671)


def controller(robot: str) -> MPCController:
    floor = load_floor(CASE / "floor.toml")
    c = MPCController()
    c.reset(ControllerContext(robot, SPEC, floor, PathPlanner(floor, SPEC.v_max, SPEC.a_max)))
    return c


def test_a_lower_robot_at_rest_shows_its_start_a_tick_early_and_the_higher_one_holds() -> None:
    # r02 at t = 60.8 s as the engine observed it: at rest on st6, its next goal st4, r01 (higher)
    # at rest 1.77 m away, its plan (held, braking) at rest.
    r01_at_rest = Neighbour("r01", *R01, 0.0, 0.0, 0.378, 4, ((T, *R01), (T + 22.8, *R01)))
    obs = Observation("r02", 64, T, *R02, 0.0, 0.0, goal=(52.6587, 33.4276), job="j00003",
                      neighbours=(r01_at_rest,), priority=3)  # fmt: skip
    assert must_announce(obs, SPEC, 0.1)
    lower = controller("r02")
    cmd = lower.compute(obs)
    # It solved, stays at rest this tick, and its plan shows it moving from the tick after.
    assert cmd.status is ControlStatus.OK and cmd.solve is not None
    assert abs(cmd.ax) < 1e-9 and abs(cmd.ay) < 1e-9
    plan = np.array([s[1:] for s in cmd.plan])
    assert np.allclose(plan[:3], R02) and not np.allclose(plan[3:], R02, atol=1e-3)
    # r01 a tick later, set off towards st6: r02's plan now shows it moving, so r01 holds.
    moving = Neighbour("r02", *R02, 0.0, 0.0, 0.378, 3, cmd.plan)
    later = Observation("r01", 65, T + 0.95, *R01, -0.197, -0.671, goal=ST6, job="j00004",
                        neighbours=(moving,), priority=4)  # fmt: skip
    assert must_hold(later, SPEC, 25, 0.1)
    # And a robot higher than every neighbour never waits for one.
    higher = Observation("r01", 64, T, *R01, 0.0, 0.0, goal=ST6, job="j00004",
                         neighbours=(Neighbour("r02", *R02, 0.0, 0.0, 0.378, 3),),
                         priority=4)  # fmt: skip
    assert not must_announce(higher, SPEC, 0.1)


def test_a_lower_robot_that_showed_its_start_sets_off_at_the_next_tick() -> None:
    r01_at_rest = Neighbour("r01", *R01, 0.0, 0.0, 0.378, 4, ((T, *R01), (T + 22.8, *R01)))
    obs = Observation("r02", 64, T, *R02, 0.0, 0.0, goal=(52.6587, 33.4276), job="j00003",
                      neighbours=(r01_at_rest,), priority=3)  # fmt: skip
    lower = controller("r02")
    lower.compute(obs)
    r01 = Neighbour("r01", *R01, 0.0, 0.0, 0.378, 4, ((T + 0.95, *R01), (T + 23.75, *R01)))
    nxt = Observation("r02", 65, T + 0.95, *R02, 0.0, 0.0, goal=(52.6587, 33.4276),
                      job="j00003", neighbours=(r01,), priority=3)  # fmt: skip
    cmd = lower.compute(nxt)
    assert cmd.solve is not None and max(abs(cmd.ax), abs(cmd.ay)) > 0.1


def test_the_fuzz_case_where_both_set_off_at_once_never_touches() -> None:
    world = World(load_scenario(CASE / "scen.toml"))
    summary = world.run().summary
    assert summary["violations"]["collision"] == 0
    assert not summary["stuck_robots"] and summary["deadlocks"] == 0
    assert summary["jobs"]["completed"] >= 5  # as before the fix (the last one runs past 90 s)
    # Between the samples too: both robots move in straight lines over a step.
    t1, p1, _ = world.recorder.trajectories["r01"].arrays()
    t2, p2, _ = world.recorder.trajectories["r02"].arrays()
    assert np.array_equal(t1, t2)
    assert closest_approach(p1, p2) >= 2 * 0.378 - 1e-9


def test_a_higher_robot_keeps_clear_of_a_lower_one_that_shows_its_start() -> None:
    # r02 (lower) at rest at the origin shows its start: at rest this tick, then along +x. r01
    # (higher) at rest 4 m away on that line is not close by their velocities (both at rest),
    # yet it keeps clear of r02's spot and plan: keeping its course it planned through where
    # r02 stood, and r02, setting off next tick, could not keep clear of that plan (an
    # infeasible solve: 33 of the 121 fallbacks of the 40-robot sweep).
    spec = RobotSpec(v_max=1.0, a_max=1.0, radius=0.4, period=0.2)
    t, n = 10.0, 25
    shown = ((t, 0.0, 0.0), (t + 0.2, 0.0, 0.0)) + tuple(
        (t + 0.2 * k, 0.02 * (k - 1) ** 2, 0.0) for k in range(2, 8)
    )
    lower = Neighbour("r02", 0.0, 0.0, 0.0, 0.0, 0.4, 3, shown)
    obs = Observation("r01", 50, t, 4.0, 0.0, 0.0, 0.0, goal=(-4.0, 0.0), neighbours=(lower,),
                      priority=4)  # fmt: skip
    half = 2 * 0.4 + 0.1
    assert not close(obs, lower, spec, half) and not must_hold(obs, spec, n, 0.1)
    box = np.full((n + 1, 2), 10.0)
    picked = robots_to_avoid(obs, spec, n, -box, box, margin=0.1, respect_priority=True)
    assert [ob.robot for ob in picked] == ["r02"]
    # Its box holds r02's spot at every step, and its plan's last point from then on.
    ob = picked[0]
    assert np.all(np.abs(ob.centres) <= ob.half - half + 1e-9)
    assert np.all(np.abs(ob.centres[7:] - shown[-1][1:]) <= ob.half[7:] - half + 1e-9)
    # The same robot moving away along its plan, not close either, is left to yield as before.
    moving = Neighbour("r02", 0.0, 0.0, 0.2, 0.0, 0.4, 3, shown[1:])
    obs = Observation("r01", 50, t, 4.0, 0.0, 0.0, 0.0, goal=(-4.0, 0.0), neighbours=(moving,),
                      priority=4)  # fmt: skip
    assert not close(obs, moving, spec, half)
    assert robots_to_avoid(obs, spec, n, -box, box, margin=0.1, respect_priority=True) == []


def test_a_higher_robot_is_not_held_by_a_lower_one_at_rest_whose_plan_sets_off_later() -> None:
    # MPC fuzz case s73-0052 (8 robots, period 0.2 s), t = 98.0 s: r08 (priority 9), at rest,
    # planned round r02 (priority 15) from 2 s on at every solve; r02, at rest 0.80 m away (radii
    # 0.332, margin 0.1: close) and sent aside for r08, was held by that plan and stood still,
    # and r08 waited for it: both still, with jobs, for the last 90 s. r08 will solve again and
    # show its start a tick early before it moves, so r02 re-plans (keeping clear of r08's plan).
    spec = RobotSpec(v_max=1.23, a_max=1.94, radius=0.332, period=0.2)
    t, here, there = 98.0, (22.68, -37.209), (21.916, -37.45)
    later = ((t, *there), (t + 0.4, *there), (t + 1.6, *there), (t + 2.2, 21.782, -37.422),
             (t + 2.8, 21.465, -37.357), (t + 3.4, 21.148, -37.291))  # fmt: skip
    r08 = Neighbour("r08", *there, 0.0, 0.0, 0.332, 9, later)
    obs = Observation("r02", 490, t, *here, 0.0, 0.0, goal=(22.98, -36.08), job="j00007",
                      neighbours=(r08,), priority=15)  # fmt: skip
    assert close(obs, r08, spec, 2 * 0.332 + 0.1)
    assert not must_hold(obs, spec, 25, 0.1)
    # Setting off within two ticks (its start shown), it holds r02, as before.
    now = ((t, *there), (t + 0.4, there[0] - 0.05, there[1]), (t + 3.4, 21.148, -37.291))
    setting_off = replace(obs, neighbours=(replace(r08, plan=now),))
    assert must_hold(setting_off, spec, 25, 0.1)
