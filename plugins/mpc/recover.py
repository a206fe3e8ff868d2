"""What the controller does when a solve gives no usable plan (`fall_back`).

The previous plan one step on, if the robot is on it and (with other robots about and
``avoid_robots``) that keeps clear of every neighbour's predicted position, between the steps
too; else braking (`fallback.brake`). Either way the controller then plans a new trip. It lives
apart from `fallback`, whose braking paths `neighbours` builds on, because it asks `neighbours`
whether the shifted plan keeps clear.
"""

from __future__ import annotations

import numpy as np

from fleet.floor import Floor
from fleet.plugins import Command, ControlStatus, Observation, RobotSpec, SolveReport
from fleet_plugins.mpc.fallback import brake, follow_previous
from fleet_plugins.mpc.model import Solution
from fleet_plugins.mpc.neighbours import clear_of_neighbours

__all__ = ["fall_back"]


def fall_back(
    obs: Observation,
    spec: RobotSpec,
    horizon: int,
    floor: Floor | None,
    last: Solution | None,
    on_plan: bool,
    avoid_robots: bool,
    report: SolveReport,
) -> tuple[Command, Solution | None]:
    """The FALLBACK command for a failed solve, carrying its `report`, and the plan to keep as
    the last one: `last` one step on when the robot is `on_plan` (it is where `last` said it
    would be now) and that keeps clear of the others, else None (the robot brakes)."""
    if on_plan and obs.neighbours and avoid_robots:
        assert last is not None and last.p is not None
        shifted_p = np.vstack([last.p[1:], last.p[-1:]])
        on_plan = clear_of_neighbours(obs, spec, shifted_p)
    if on_plan:
        assert last is not None
        return follow_previous(obs, last, spec.period, report)
    cmd = brake(obs, spec, horizon, ControlStatus.FALLBACK, floor)
    return Command(cmd.ax, cmd.ay, cmd.status, cmd.plan, report), None
