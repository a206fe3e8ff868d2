"""Contract-net job exchange: what a robot bids for an announced job.

The engine announces each open job on the bus (`fleet.plugins.Announcement`); every robot's
agent answers with a bid (`Controller.bid`, by default `estimate_completion`); the dispatcher
(`fleet_plugins.auction`) awards the job. See `fleet.engine.dispatch` for the engine's side.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from fleet.errors import NoPathError

if TYPE_CHECKING:
    # Names only: the contracts (fleet.plugins) call this module for their default bid, so
    # importing them at run time would close an import circle.
    from fleet.paths import PathPlanner
    from fleet.plugins import Announcement, Observation

__all__ = ["estimate_completion"]


def estimate_completion(planner: PathPlanner, obs: Observation, job: Announcement) -> float | None:
    """Seconds from ``obs.t`` until the robot of `obs` could deliver `job`.

    The robot first finishes its current job (drives to its goal, and waits there for the
    print if that lasts longer), then drives to the job's station while printing it: the
    delivery waits for whichever of trip and print ends last. Robots that already have a job
    queued decline (None), as do robots with no path to the station. Trip times are the path
    layer's `PathPlanner.estimate_time` (the graph's time, cached per goal; a bid for every
    robot and job would otherwise cost a path search each).
    """
    if obs.queued > 0:
        return None
    here = (obs.x, obs.y)
    busy = 0.0
    try:
        if obs.job is not None and obs.goal is not None:
            busy = planner.estimate_time(here, obs.goal)
            if obs.print_end_s is not None:
                busy = max(busy, obs.print_end_s - obs.t)
            here = obs.goal
        travel = planner.estimate_time(here, (job.x, job.y))
    except NoPathError:
        return None
    return float(busy + max(travel, job.print_s))
