"""A robot that is to stop with no solve (plugins/mpc/recover.py `stop`): its goal withdrawn
(IDLE: its job handed back mid-trip) or one it has no path to. Braking straight on from a plan
that turns along an obstacle's face leaves the free space; the previous plan does not.

The states are those of fuzz floor s91-0042 (tests/test_mpc_recover.py): r01 on a plan that
turns west along the slanted face of m00_irregular, where no brake stays in the free space.
"""

from __future__ import annotations

import math
from dataclasses import replace

import pytest

from fleet.floor import Floor
from fleet.paths import PathPlanner
from fleet.plugins import ControllerContext, ControlStatus
from fleet.plugins.robot import DoubleIntegrator
from fleet_plugins.mpc.controller import MPCController
from fleet_plugins.mpc.fallback import REST_SPEED, free_brake
from tests.test_mpc_recover import SPEC, TICKS, floor, in_free_space

__all__ = ["floor"]  # the module's fixture, shared

#: A goal inside m00_irregular: the planner finds no path to it (`NoPathError`).
IN_OBSTACLE = (-4.5, 27.0)


@pytest.mark.parametrize(
    ("goal", "status"), [(None, ControlStatus.IDLE), (IN_OBSTACLE, ControlStatus.FALLBACK)]
)
def test_a_robot_stopping_without_a_solve_keeps_its_plan_where_braking_leaves_the_floor(
    floor: Floor, goal: tuple[float, float] | None, status: ControlStatus
) -> None:
    c = MPCController()
    c.reset(ControllerContext("r01", SPEC, floor, PathPlanner(floor, v_max=1.42, a_max=0.34)))
    assert c.compute(TICKS[0]).status is c.compute(TICKS[1]).status is ControlStatus.OK
    obs = replace(TICKS[2], goal=goal, job=None if goal is None else "j00002")
    assert free_brake(obs, SPEC, floor) is None  # every brake leaves the free space here
    # Before: braked straight on, 3.7 mm into m00_irregular's clearance, and stood there.
    robot = DoubleIntegrator(SPEC.period, SPEC.a_max)
    x, y, vx, vy = obs.x, obs.y, obs.vx, obs.vy
    path, limit = [(x, y)], math.hypot(vx, vy) / SPEC.a_max + 2.0  # the contract's "idle"
    for k in range(40):
        now = replace(obs, tick=obs.tick + k, t=obs.t + k * SPEC.period, x=x, y=y, vx=vx, vy=vy)
        cmd = c.compute(now if k == 0 else replace(now, neighbours=()))
        assert cmd.status is status
        x, y, vx, vy = robot.step(x, y, vx, vy, cmd.ax, cmd.ay)
        path.append((x, y))
        if max(abs(vx), abs(vy)) <= REST_SPEED:
            break
    assert max(abs(vx), abs(vy)) <= REST_SPEED
    assert (len(path) - 1) * SPEC.period <= limit
    assert in_free_space(floor, path)
