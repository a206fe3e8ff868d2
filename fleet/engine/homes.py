"""Homes: idle robots of one group trade home spots when that gets a held-up one home sooner.

Robots start on spots packed round their depots (`fleet.engine.placement`), and each spot is a
robot's home. Packed that close, no robot fits between two parked ones: a robot whose home is an
inner spot gets back only once the robots parked between it and the open floor make way for it,
one after the other. 20 followers round a depot in a corner (tests/liveness_cases/packed_depot)
were all home 574 s into the run, their 20 jobs long done; of 40 robots with jobs for the first
120 s of 600 (`bench_fleet.py --release-until`), 6 followers and 13 MPC robots were still short
of home at the end. The spots of one group (a `[[robots]]` table: the same start stations) are
alike, so a robot held up on its way home takes the home of an idle robot of its group parked
there, which takes its home in turn, when that lowers the sum of the two squared distances to
home: a robot parked next to the empty inner spot slides into it and leaves its own, nearer the
open floor, to the one held up (a plain sum of distances does not tell that from one long trip
and one nil). Only a parked robot trades: homes traded between robots still on their way went
from one to the next (seven trades of one home among five robots in 100 s), and a job was late.
"""

from __future__ import annotations

from collections.abc import Iterable

from fleet.engine.motion import RobotState, at_rest_near

__all__ = ["trade_home"]


def trade_home(robot: RobotState, robots: Iterable[RobotState], tol: float) -> RobotState | None:
    """Swap `robot`'s home with the idle robot of its group parked at its own (at rest within
    `tol`) whose home, traded, lowers the sum of the two robots' squared distances to home the
    most, by at least a footprint's width squared; the robot traded with, or None."""
    if not _idle_going_home(robot):
        return None
    mine = _d2(robot, robot.home)
    best, gain = None, (2.0 * robot.spec.radius) ** 2
    for other in robots:
        if other is robot or other.group != robot.group or other.home == robot.home:
            continue
        if not _idle_going_home(other) or not at_rest_near(other, other.home, tol):
            continue
        before = mine + _d2(other, other.home)
        after = _d2(robot, other.home) + _d2(other, robot.home)
        if before - after > gain:
            best, gain = other, before - after
    if best is not None:
        robot.home, best.home = best.home, robot.home
    return best


def _idle_going_home(robot: RobotState) -> bool:
    """Idle, nothing queued, in service, not aside nor bound for a charger, and homing."""
    return (
        robot.return_home
        and robot.job is None
        and not robot.queue
        and robot.in_service
        and robot.aside is None
        and robot.charger_at is None
    )


def _d2(robot: RobotState, spot: tuple[float, float]) -> float:
    return (robot.x - spot[0]) ** 2 + (robot.y - spot[1]) ** 2
