"""An MPC controller put back into the state a fuzz run left a robot in, and driven on from
there (`tests/test_mpc_rejoin.py`, `tests/test_mpc_stand_still.py`): its trip planned where the
run planned it, then at rest elsewhere on a previous plan at rest, then ticked as the engine
steps the double integrator."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from fleet.floor import Floor
from fleet.paths import PathPlanner
from fleet.plugins import (
    ControllerContext,
    ControlStatus,
    Neighbour,
    Observation,
    RobotSpec,
    SolverOutcome,
)
from fleet_plugins.mpc.controller import MPCController
from fleet_plugins.mpc.model import Solution

Point = tuple[float, float]


def planned(
    floor: Floor,
    robot: str,
    spec: RobotSpec,
    start: Point,
    goal: Point,
    t: float,
    tick: int,
    job: str,
) -> MPCController:
    """A controller whose trip to `goal` was planned from rest at `start` at time `t`."""
    c = MPCController()
    c.reset(ControllerContext(robot, spec, floor, PathPlanner(floor, spec.v_max, spec.a_max)))
    first = c.compute(Observation(robot, tick, t, *start, 0.0, 0.0, goal=goal, job=job))
    assert first.solve is not None and first.solve.outcome.usable
    assert c._trip is not None
    return c


def at_rest_on_its_plan(c: MPCController, point: Point, t: float, progress: int) -> None:
    """Leave `c` as the run had it at `t`: at rest at `point` on its previous plan (solved a
    period before), a plan at rest there in the one region of its trip that holds `point`, its
    progress along the reference `progress`."""
    assert c._trip is not None
    here = c._trip.holding(np.array(point))
    assert len(here) == 1
    N, period = c.horizon, c.context.spec.period
    c._last = Solution(
        SolverOutcome.OPTIMAL,
        0.0,
        p=np.tile(point, (N + 1, 1)),
        v=np.zeros((N + 1, 2)),
        u=np.zeros((N, 2)),
        regions=np.full(N - 1, next(iter(here))),
    )
    c._last_t, c._last_model, c._progress = t - period, c._model, progress


def drive(
    c: MPCController,
    point: Point,
    t: float,
    tick: int,
    ticks: int,
    goal: Point,
    job: str,
    neighbours: Callable[[float], tuple[Neighbour, ...]],
) -> Point:
    """Where the robot is after `ticks` periods from rest at `point` at `t` (tick number
    `tick`), each command OK and applied as the engine steps the double integrator; each
    observation sees `neighbours(t)`."""
    spec = c.context.spec
    x, y, vx, vy = *point, 0.0, 0.0
    for k in range(ticks):
        obs = Observation(
            c.context.robot, tick + k, t, x, y, vx, vy, goal=goal, job=job, neighbours=neighbours(t)
        )
        cmd = c.compute(obs)
        assert cmd.status is ControlStatus.OK
        x, y = x + spec.period * vx, y + spec.period * vy
        vx, vy = vx + spec.period * cmd.ax, vy + spec.period * cmd.ay
        t += spec.period
    return x, y
