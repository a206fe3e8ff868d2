"""`GreedyDispatcher`: the baseline dispatcher, no look-ahead and no optimisation."""

from __future__ import annotations

import math
from collections.abc import Sequence

from fleet.errors import NoPathError
from fleet.plugins import Assignment, DispatchContext, Dispatcher, Job, RobotStatus

__all__ = ["GreedyDispatcher", "METRICS"]

#: The distance measures `GreedyDispatcher` accepts for its ``metric`` option.
METRICS: tuple[str, ...] = ("euclidean", "travel_time")


class GreedyDispatcher(Dispatcher):
    """Oldest open job first, each to the nearest idle robot not yet taken.

    Jobs are taken in order of release time (``released_s``, then id). Each goes to the
    nearest idle robot still free in this call; equal distances go to the smaller robot id.
    A job no idle robot can reach stays open for a later call.

    Parameters
    ----------
    metric:
        ``"euclidean"`` (straight-line distance, the default) or ``"travel_time"`` (the path
        layer's travel-time estimate, ``context.planner.estimate_time``; robots with no path to
        the job are skipped).

    Raises
    ------
    ValueError
        If `metric` is not one of `METRICS`.
    """

    name = "greedy"

    def __init__(self, metric: str = "euclidean") -> None:
        super().__init__()
        if metric not in METRICS:
            raise ValueError(
                f"GreedyDispatcher option metric = {metric!r}: allowed values are "
                f"{', '.join(repr(m) for m in METRICS)}"
            )
        self.metric = metric

    def assign(
        self, jobs: Sequence[Job], robots: Sequence[RobotStatus], context: DispatchContext
    ) -> list[Assignment]:
        """Pair open jobs with idle robots greedily; see the class docstring for the order."""
        free = sorted((r for r in robots if r.idle), key=lambda r: r.robot)
        out: list[Assignment] = []
        for job in sorted(jobs, key=lambda j: (j.released_s, j.id)):
            if not free:
                break
            best: tuple[float, RobotStatus] | None = None
            for robot in free:  # sorted by id, so a strict `<` keeps the smaller id on ties
                cost = self._cost(robot, job, context)
                if cost is not None and (best is None or cost < best[0]):
                    best = (cost, robot)
            if best is not None:
                out.append(Assignment(job=job.id, robot=best[1].robot))
                free.remove(best[1])
        return out

    def _cost(self, robot: RobotStatus, job: Job, context: DispatchContext) -> float | None:
        if self.metric == "euclidean":
            return math.hypot(job.x - robot.x, job.y - robot.y)
        try:
            return float(context.planner.estimate_time((robot.x, robot.y), (job.x, job.y)))
        except NoPathError:
            return None

    def __repr__(self) -> str:
        return f"GreedyDispatcher(metric={self.metric!r})"
