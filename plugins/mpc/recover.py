"""What the controller does when a solve gives no usable plan (`fall_back`), or when it stops
with no solve: no goal, or no path to it (`stop`: braking, or the previous plan one step on
where braking would leave the floor).

The previous plan one step on, if the robot is on it, it keeps within this tick's print caps
and (with other robots about and ``avoid_robots``) clear of every neighbour's predicted
position, between the steps too, or no braking path stays in the free space; else braking
(`fallback.brake`), by the first of its brakes that keeps clear of the neighbours' predicted
positions where one does (straight on, a robot at rest stood in the way:
`fallback.free_brake`). Either way the controller then plans a new trip. It lives apart from
`fallback`, whose braking paths `neighbours` builds on, because it asks `neighbours` whether
the shifted plan keeps clear.

The previous plan was solved in the floor's regions, so it stays in the free space to rest;
a braking path need not: a plan that turns along a wall leaves the robot, one step on, where
braking straight on (or at any of `fallback.BRAKE_RATES`) runs into the wall. Dropping such
a plan for a neighbour drove the robot 3.7 mm into an obstacle's clearance, and its braking
path came no farther from that neighbour than the plan (fuzz s91-0042: a higher robot bound
for the station the robot had just left planned across its path; tests/test_mpc_recover.py).
A neighbour is a prediction, the obstacle is not: the plan is kept, and it is the plan the
others saw.

A plan solved before a print began knows nothing of its caps; a brake slows every axis and
keeps any cap the robot keeps now. A robot given a job at a station while driving off at
0.26 m/s, its solves infeasible for a neighbour, followed its plan home to 1.18 m/s against the
print's 0.28 m/s cap, 8 steps over (fuzz s97-0728; tests/test_mpc_recover.py).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from fleet.floor import Floor
from fleet.plugins import Command, ControlStatus, Observation, RobotSpec, SolveReport
from fleet_plugins.mpc.fallback import brake, follow_previous, free_brake, leaves_floor, shifted
from fleet_plugins.mpc.model import Solution
from fleet_plugins.mpc.neighbours import clear_of_neighbours
from fleet_plugins.mpc.reuse import within_caps

__all__ = ["fall_back", "stop"]


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
    would be now) and that keeps within this tick's print caps (`reuse.within_caps`) and clear
    of the others, or when no brake stays in the free space of the `floor`
    (`fallback.free_brake`); else None (the robot brakes)."""
    if on_plan:
        assert last is not None
        later = shifted(last)
        assert later.p is not None and later.v is not None
        keep = within_caps(obs, spec, later.v)
        if keep and obs.neighbours and avoid_robots:
            keep = clear_of_neighbours(obs, spec, later.p)
        on_plan = keep or (floor is not None and free_brake(obs, spec, floor) is None)
    if on_plan:
        assert last is not None
        return follow_previous(obs, last, spec.period, report)
    clear = _clear_of(obs, spec) if avoid_robots else None
    cmd = brake(obs, spec, horizon, ControlStatus.FALLBACK, floor, clear)
    return Command(cmd.ax, cmd.ay, cmd.status, cmd.plan, report), None


def _clear_of(obs: Observation, spec: RobotSpec) -> Callable[[np.ndarray], bool] | None:
    """Whether a braking path keeps clear of the neighbours' predicted positions
    (`neighbours.clear_of_neighbours`), for `fallback.free_brake`; None with none about."""
    if not obs.neighbours:
        return None
    return lambda path: clear_of_neighbours(obs, spec, path)


def stop(
    obs: Observation,
    spec: RobotSpec,
    horizon: int,
    floor: Floor | None,
    last: Solution | None,
    on_plan: bool,
    status: ControlStatus,
    avoid_robots: bool = False,
) -> tuple[Command, Solution | None]:
    """The command with `status` for a robot that is to stop with no solve (no goal, or no
    path to it), and the plan to keep as the last one: braking (`fallback.brake`, None kept;
    with `avoid_robots`, a brake clear of the neighbours first, as a failed solve's), unless
    braking leaves the `floor` (`fallback.leaves_floor`) while the robot is `on_plan`: then
    `last` one step on, which ends at rest in the regions and zone limits it was solved in. A
    robot whose job was handed back while its plan turned along an obstacle's face braked
    straight on into the obstacle's clearance and stood there (the state of fuzz s91-0042 with
    no goal; tests/test_mpc_stop.py); so did one given a goal it had no path to.
    """
    if on_plan and leaves_floor(obs, spec, floor):
        assert last is not None
        return follow_previous(obs, last, spec.period, None, status)
    clear = _clear_of(obs, spec) if avoid_robots else None
    return brake(obs, spec, horizon, status, floor, clear), None
