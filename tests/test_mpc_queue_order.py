"""MPC robots in a stream to one station: a higher robot does not plan through a lower one
ahead of it on the way there (`neighbours.ahead_in_queue`).

80 MPC robots on the fleet scenario (``scripts/bench_fleet.py --sweep 80 --duration 120
--seed 1``) had 198 fallbacks, every one an infeasible solve, 135 of them of robots bound for
printer_cell_in. At 33 s, for instance, r48 (moving west at 0.5 m/s, 7.7 m from the station)
had r22 and r46 ahead of it and r24 and r26 (higher, ids first) 1-2 m behind, bound for the
same station: those took r48 for a moving lower robot that yields and planned through where it
was going, and r48, between their plans and the robots ahead, could keep clear of each one
alone but of no two together. It can only yield backwards, into their way. Now a higher robot
keeps clear of a lower one that is nearer its goal and drives nearer still (its plan ends within
`neighbours.AHEAD_M` of it): first come, first served.

The situation below is that one made small: one lower robot ahead, one higher behind.
"""

from __future__ import annotations

import math

import numpy as np
from shapely.geometry import box

from fleet.floor import Floor, FloorSpec
from fleet.paths import PathPlanner
from fleet.plugins import ControllerContext, ControlStatus, Neighbour, Observation, RobotSpec
from fleet_plugins.mpc.controller import MPCController
from fleet_plugins.mpc.neighbours import AHEAD_M, ahead_in_queue, closest_approach
from fleet_plugins.mpc.separation import predict

SPEC = RobotSpec(v_max=1.0, a_max=0.5, radius=0.4, period=0.25)
N = 25
T = 30.0
HALL = Floor.from_regions(
    FloorSpec(
        source="<test hall>", name="hall", boundary=box(0, 0, 20, 10), default_v_max=(1.0, 1.0)
    ),
    [(box(0, 0, 20, 10), (1.0, 1.0), None)],
)
STATION = (5.0, 5.0)
#: The lower robot, 2.6 m ahead of the higher one, at 0.5 m/s west; its plan slows it to rest
#: 1 m short of the station (a robot stands on it).
LOW = (8.4, 5.0)
HIGH = (11.0, 5.0)


def lower(priority: int = 40) -> Neighbour:
    x, y = LOW
    plan = [(T, x, y)]
    v, px = 0.5, x
    for k in range(1, N + 1):  # 0.5 m/s west, then braking at 0.25 m/s^2 to rest
        px -= v * SPEC.period
        v = max(0.0, v - 0.0625) if k > 12 else v
        plan.append((T + k * SPEC.period, px, y))
    return Neighbour("r48", x, y, -0.5, 0.0, 0.4, priority, tuple(plan))


def controller(robot: str) -> MPCController:
    c = MPCController(reuse_ticks=0)
    c.reset(ControllerContext(robot, SPEC, HALL, PathPlanner(HALL, 1.0, 0.5)))
    return c


def higher_plan() -> np.ndarray:
    """The higher robot, r24, bound for the station at 0.8 m/s west behind r48: its plan."""
    obs = Observation(
        "r24", 120, T, *HIGH, -0.8, 0.0, goal=STATION, job="j", neighbours=(lower(),),
        priority=60,
    )  # fmt: skip
    cmd = controller("r24").compute(obs)
    assert cmd.status is ControlStatus.OK and cmd.solve is not None
    return np.array(cmd.plan)[:, 1:]


def test_a_lower_robot_driving_to_this_ones_goal_ahead_of_it_is_ahead_in_its_queue() -> None:
    n = lower()
    centres = predict(n, T, SPEC.period, N)
    me = Observation("r24", 120, T, *HIGH, -0.8, 0.0, goal=STATION, priority=60)
    assert ahead_in_queue(me, n, centres)
    # Behind this robot, it is not ahead; nor is one driving away from the goal.
    assert not ahead_in_queue(Observation("r24", 120, T, 7.0, 5.0, 0.0, 0.0, goal=STATION), n,
                              centres)  # fmt: skip
    assert not ahead_in_queue(me, n, centres[::-1])
    # Nor one that stops farther than AHEAD_M from this robot's goal.
    far = (LOW[0] - AHEAD_M - 1.0, LOW[1])
    assert not ahead_in_queue(me, n, centres + np.subtract(far, STATION))
    assert not ahead_in_queue(Observation("r24", 120, T, *HIGH, 0.0, 0.0), n, centres)
    # Nor one crossing this robot's way (north, 3 m short of the goal): it yields.
    x, y = STATION[0] + 3.0, STATION[1] - 2.0
    across = Neighbour("r48", x, y, 0.0, 0.8, 0.4, 40, ((T, x, y), (T + 3.0, x, y + 2.4)))
    assert not ahead_in_queue(me, across, predict(across, T, SPEC.period, N))


def test_a_higher_robot_does_not_plan_through_a_lower_one_ahead_on_its_way() -> None:
    # Before: r24 took r48 for a moving lower robot that yields, and planned on to the station
    # through where r48 was going (contact with its predicted positions).
    plan = higher_plan()
    low = predict(lower(), T, SPEC.period, N)
    assert closest_approach(plan, low) >= 2 * SPEC.radius
    # Not vacuous: it drives on behind r48.
    assert math.dist(plan[-1], STATION) < math.dist(HIGH, STATION) - 1.0


def test_the_lower_robot_ahead_solves_against_the_higher_ones_plan() -> None:
    plan = higher_plan()
    up = Neighbour(
        "r24", *HIGH, -0.8, 0.0, 0.4, 60,
        tuple((T + k * SPEC.period, *map(float, plan[k])) for k in range(len(plan))),
    )  # fmt: skip
    obs = Observation(
        "r48", 120, T, *LOW, -0.5, 0.0, goal=STATION, job="k", neighbours=(up,), priority=40
    )
    cmd = controller("r48").compute(obs)
    assert cmd.status is ControlStatus.OK
    assert cmd.solve is not None and cmd.solve.outcome.usable
