"""MPC robots queueing at a station: a higher robot keeps clear of a lower one settling there.

40 MPC robots on the fleet scenario (``scripts/bench_fleet.py --sweep 40 --duration 120``) had
72 fallbacks, 62 of them within 3 m of the robot's goal, nearly all infeasible solves of robots
queueing at a station. At 102.75 s, for instance, r37 (priority 44) stood in the queue at
press_1_in, 0.9 m from r31 and r24 parked on two sides, and its plan crept 3 cm on: so it was
not at rest, and r33 (priority 48, 3.45 m away at 1 m/s, bound for the same station) took it
for a moving lower robot that yields, and planned to stop where r37 stood (0 m from it). r37,
boxed in, could not keep clear of that plan: infeasible, a fallback (it brakes and shows a plan
at rest), r33 then kept clear of it, r37 crept again, and so on. A robot cannot give way that
cannot get out of the way: now a higher robot keeps clear of a lower one whose plan and braking
path stay within `neighbours.SETTLING_M` of where it is and whose plan ends within
`neighbours.QUEUE_M` of the higher one's goal (`neighbours.settling`).

The situation below is that one made small: a station with robots parked round it and a lower
robot creeping in the last free spot next to it.
"""

from __future__ import annotations

import math

import numpy as np
from shapely.geometry import box

from fleet.floor import Floor, FloorSpec
from fleet.paths import PathPlanner
from fleet.plugins import ControllerContext, ControlStatus, Neighbour, Observation, RobotSpec
from fleet_plugins.mpc.controller import MPCController
from fleet_plugins.mpc.neighbours import QUEUE_M, SETTLING_M, closest_approach, settling
from fleet_plugins.mpc.separation import at_rest, predict

SPEC = RobotSpec(v_max=1.0, a_max=0.5, radius=0.4, period=0.25)
N = 25
T = 100.0
HALL = Floor.from_regions(
    FloorSpec(
        source="<test hall>", name="hall", boundary=box(0, 0, 20, 10), default_v_max=(1.0, 1.0)
    ),
    [(box(0, 0, 20, 10), (1.0, 1.0), None)],
)
STATION = (10.0, 5.0)
#: Robots parked round the station (on it, west, east and south of it), 0.9 m apart, and two
#: round the spot north of it (east and north of that spot).
PARKED = {
    "p1": (10.0, 5.0),
    "p2": (9.1, 5.0),
    "p3": (10.9, 5.0),
    "p4": (10.0, 4.1),
    "p5": (10.93, 5.9),
    "p6": (10.0, 6.8),
}
#: The lower robot in the spot north of the station, creeping 3 cm east (0.9 m from p5 then).
LOW = (10.0, 5.9)


def parked(robot: str, x: float, y: float) -> Neighbour:
    """A robot at rest that says it stays (as `fallback.park` does), priority above both."""
    return Neighbour(robot, x, y, 0.0, 0.0, 0.4, 90, ((T, x, y), (T + N * SPEC.period, x, y)))


def creeper(priority: int = 44) -> Neighbour:
    """The lower robot: 0.02 m/s east, its plan 3 cm on and at rest 1 s from now."""
    x, y = LOW
    plan = ((T, x, y), (T + 1.0, x + 0.03, y), (T + N * SPEC.period, x + 0.03, y))
    return Neighbour("r37", x, y, 0.02, 0.0, 0.4, priority, plan)


def controller(robot: str) -> MPCController:
    c = MPCController(reuse_ticks=0)
    c.reset(ControllerContext(robot, SPEC, HALL, PathPlanner(HALL, 1.0, 0.5)))
    return c


def higher_plan() -> tuple[MPCController, np.ndarray]:
    """The higher robot, r33, bound for the station from 3.5 m north-west at 1 m/s: its plan."""
    others = (*(parked(r, *xy) for r, xy in PARKED.items()), creeper())
    obs = Observation(
        "r33", 400, T, 7.0, 7.0, 0.7, -0.7, goal=STATION, job="j", neighbours=others,
        priority=48,
    )  # fmt: skip
    c = controller("r33")
    cmd = c.compute(obs)
    assert cmd.status is ControlStatus.OK and cmd.solve is not None
    return c, np.array(cmd.plan)[:, 1:]


def test_a_robot_creeping_in_a_queue_is_settling_and_one_driving_on_is_not() -> None:
    n = creeper()
    centres = predict(n, T, SPEC.period, N)
    assert not at_rest(centres)  # it moves: 3 cm
    stop = np.tile(LOW, (N + 1, 1))
    assert settling(n, centres, stop, STATION)
    # A plan that goes on farther than SETTLING_M is no settling, nor a braking path that does.
    x, y = LOW
    on = SETTLING_M + 0.5
    farther = Neighbour("r37", x, y, 0.02, 0.0, 0.4, 44, ((T, x, y), (T + 3.0, x + on, y)))
    assert not settling(farther, predict(farther, T, SPEC.period, N), stop, STATION)
    assert not settling(n, centres, stop + [0.0, on], STATION)
    # Nor one that stops farther than QUEUE_M from this robot's goal (it is not in its queue).
    assert not settling(n, centres, stop, (LOW[0] + QUEUE_M + 0.1, LOW[1]))


def test_a_higher_robot_does_not_plan_into_a_lower_one_creeping_next_to_a_full_station() -> None:
    # Before: r33 took r37 for a moving lower robot that yields, and its plan ended on the spot
    # where r37 stood (0.0 m from it), the nearest free one to the station.
    _, plan = higher_plan()
    low = predict(creeper(), T, SPEC.period, N)
    assert closest_approach(plan, low) >= 2 * SPEC.radius
    for xy in PARKED.values():
        assert closest_approach(plan, np.tile(xy, (N + 1, 1))) >= 2 * SPEC.radius
    # Not vacuous: it drove on towards the station, and stopped short of the queue.
    assert math.dist(plan[-1], STATION) < math.dist((7.0, 7.0), STATION) - 1.0


def test_the_lower_robot_in_the_queue_solves_against_the_higher_ones_plan() -> None:
    # Before: boxed in by the parked robots, r37 could not keep clear of a plan ending where it
    # stood: every solve infeasible, a fallback, until r33 saw it at rest again.
    _, plan = higher_plan()
    up = Neighbour(
        "r33", 7.0, 7.0, 0.7, -0.7, 0.4, 48,
        tuple((T + k * SPEC.period, *map(float, plan[k])) for k in range(len(plan))),
    )  # fmt: skip
    others = (*(parked(r, *xy) for r, xy in PARKED.items()), up)
    obs = Observation(
        "r37", 400, T, *LOW, 0.02, 0.0, goal=STATION, job="k", neighbours=others, priority=44
    )
    cmd = controller("r37").compute(obs)
    assert cmd.status is ControlStatus.OK
    assert cmd.solve is not None and cmd.solve.outcome.usable


def test_a_higher_robot_keeps_clear_of_a_lower_one_arriving_in_the_last_free_spot() -> None:
    # The same, the lower robot still arriving (0.1 m/s, 0.4 m from its stop): not close, and
    # it could not get out of the way either.
    x, y = LOW[0] - 0.4, LOW[1]
    plan = ((T, x, y), (T + 4.0, *LOW), (T + N * SPEC.period, *LOW))
    arriving = Neighbour("r37", x, y, 0.1, 0.0, 0.4, 44, plan)
    others = (*(parked(r, *xy) for r, xy in PARKED.items()), arriving)
    obs = Observation(
        "r33", 400, T, 7.0, 7.0, 0.7, -0.7, goal=STATION, job="j", neighbours=others,
        priority=48,
    )  # fmt: skip
    cmd = controller("r33").compute(obs)
    assert cmd.status is ControlStatus.OK
    low = predict(arriving, T, SPEC.period, N)
    assert closest_approach(np.array(cmd.plan)[:, 1:], low) >= 2 * SPEC.radius
