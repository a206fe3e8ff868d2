"""How fast a follower plans: the speed it drives at, and a path planner for each speed.

The speed (`speed_limit`) is the robot's own limit, lowered by the ``speed`` option and by the
print caps as the ``caps`` option takes them. Each speed gets a planner of its own (`Planners`),
on the map's floor or, with ``rough_v_max``, on a floor whose rough areas are speed zones.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from fleet.plugins import ControllerContext, Observation, RobotSpec

if TYPE_CHECKING:
    from fleet.floor import Floor
    from fleet.paths import PathPlanner

__all__ = ["speed_limit", "Planners"]


def speed_limit(obs: Observation, spec: RobotSpec, speed: float | None, caps: str) -> float:
    """The speed (m/s per axis) to plan at, from the robot, `speed` and the print caps."""
    pace = spec.v_max if speed is None else min(spec.v_max, speed)
    if caps == "ignore":
        return pace
    cap = pace if obs.speed_cap is None else min(pace, float(obs.speed_cap))
    # "ahead": long enough to brake to rest from the fastest the robot can be going before
    # a tighter cap starts (pace/a_max rounded up to whole periods; the velocity of the step
    # in progress is already fixed).
    ahead = obs.t + pace / spec.a_max + 2.0 * spec.period
    until = math.inf if caps == "window" else ahead
    for start, _, piece_cap in obs.speed_caps:
        if start < until:
            cap = min(cap, float(piece_cap))
    return cap


class Planners:
    """The planners of one robot: the context's, or one per speed cap (built once per cap).

    Parameters
    ----------
    context:
        The robot's context: its spec, floor and planner.
    rough_v_max:
        Plan with the floor's rough areas as zones of this speed (m/s); None: the floor as is.

    Attributes
    ----------
    floor:
        The floor planned on (the context's, or its copy slowed on rough areas).
    """

    def __init__(self, context: ControllerContext, rough_v_max: float | None) -> None:
        self.context = context
        self.floor = context.floor
        if rough_v_max is not None and context.floor.spec.rough_areas:
            self.floor = _rough_floor(context.floor, rough_v_max)
        self._by_cap: dict[float, PathPlanner] = {}

    def at(self, cap: float) -> PathPlanner:
        """The context's planner, or one for a robot capped at `cap` m/s."""
        spec = self.context.spec
        if cap >= spec.v_max and self.floor is self.context.floor:
            return self.context.planner
        cap = min(cap, spec.v_max)
        if cap not in self._by_cap:
            from fleet.paths import PathPlanner  # only speed caps need a planner of our own

            self._by_cap[cap] = PathPlanner(self.floor, v_max=cap, a_max=spec.a_max)
        return self._by_cap[cap]


# Floors with slow rough areas, shared by every robot of a run: (floor, v) -> floor.
_ROUGH_FLOORS: dict[tuple[int, float], tuple[Floor, Floor]] = {}


def _rough_floor(floor: Floor, v_max: float) -> Floor:
    key = (id(floor), v_max)
    if key not in _ROUGH_FLOORS or _ROUGH_FLOORS[key][0] is not floor:
        from fleet.floor import slow_on_rough

        _ROUGH_FLOORS.clear()  # one run's floor at a time: no growth over a long study
        _ROUGH_FLOORS[key] = (floor, slow_on_rough(floor.spec, v_max))
    return _ROUGH_FLOORS[key][1]
