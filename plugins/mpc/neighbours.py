"""Which other robots a solve keeps clear of, and whether a plan keeps clear of them all.

A robot needs keeping clear of when its predicted square can come within reach of the plan
(the reachable boxes, narrowed to the regions each step may use) and, with
``respect_priority``, it outranks this one wherever it is, and only when parked for the whole
horizon or close (closer than two robots at full speed need to stop, plus a step each) if this
one outranks it; a close one may carry on or stop to let this one pass, so the plan keeps clear
of the box round both. The higher one thus keeps its course, and the lower one has a plan to
avoid that does not move away as it yields (when both yield, both swerve alike and meet again:
measured head-on). `separation` turns the chosen ones into rows.

Which ones, when more need it than a solve takes (``max_neighbours``): those the robot's
intended path (its reference window, its previous plan) comes nearest to, not the nearest now.
Robots parked 1 m apart in a depot are each other's nearest; ranked by distance now, they
crowded out a robot driving into a departing robot's way from 2.5 m (issue 16: 40 robots, r15
set off into r35 coming home, and they passed through each other).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from fleet.plugins import Neighbour, Observation, RobotSpec
from fleet_plugins.mpc.fallback import braking_path
from fleet_plugins.mpc.separation import Obstacle, at_rest, predict, reaches

__all__ = ["robots_to_avoid", "clear_of_neighbours", "outranks"]


def robots_to_avoid(
    obs: Observation,
    spec: RobotSpec,
    horizon: int,
    p_lo: np.ndarray,
    p_hi: np.ndarray,
    *,
    margin: float,
    respect_priority: bool,
    paths: Sequence[np.ndarray] = (),
) -> list[Obstacle]:
    """The robots of `obs.neighbours` the plan must keep clear of, most pressing first;
    `p_lo`, `p_hi` bound where each point of the plan can be.

    `paths` (each ``(N+1, 2)``, steps 0..N) are where the robot means to go: its reference
    window and previous plan. The robots whose box one of them enters come first, then the
    others by how near those paths come to their boxes (`path_gap`); ties by distance now,
    then robot id. Without `paths`, nearest first.
    """
    N, dt = horizon, spec.period
    # Within this, two robots at full speed could not stop before they met.
    near = spec.v_max**2 / spec.a_max + 2.0 * spec.v_max * dt
    picked: list[tuple[float, str, Obstacle]] = []
    for n in obs.neighbours:
        centres = predict(n, obs.t, dt, N)
        half = spec.radius + float(n.radius) + margin
        distance = math.hypot(n.x - obs.x, n.y - obs.y)
        ob = Obstacle.square(n.robot, centres, half, margin)
        if respect_priority and outranks(obs, n) and not at_rest(centres):
            if distance >= half + near:
                continue  # it yields to this robot; this one keeps its course
            # Close by: it may carry on with its plan or stop to let this one pass (it
            # changes its plan as this one's changes): keep clear of both.
            stop = np.array(braking_path(obs.t, n.x, n.y, n.vx, n.vy, dt, spec.a_max, N))
            stop = np.vstack([stop[:, 1:], np.repeat(stop[-1:, 1:], N + 1 - len(stop), 0)])
            ob = Obstacle.between(n.robot, centres, stop, half, margin)
        if not reaches(ob, p_lo, p_hi):
            continue
        picked.append((max(path_gap(ob, paths), 0.0), distance, n.robot, ob))
    picked.sort(key=lambda item: item[:3])
    return [item[3] for item in picked]


def path_gap(obstacle: Obstacle, paths: Sequence[np.ndarray]) -> float:
    """How far (m, per axis: negative inside) the nearest of `paths` keeps from `obstacle`'s
    box over steps 1..N (0 with no paths)."""
    if not paths:
        return 0.0
    c, h = obstacle.centres[1:], obstacle.half[1:]
    return min(float(np.min(np.max(np.abs(p[1:] - c) - h, axis=1))) for p in paths)


def clear_of_neighbours(obs: Observation, spec: RobotSpec, p: np.ndarray) -> bool:
    """Whether plan `p` (steps 0..N from now) keeps every neighbour's predicted disc out
    of its own at steps 1..N (a fallback plan is checked before it is followed)."""
    for n in obs.neighbours:
        centres = predict(n, obs.t, spec.period, len(p) - 1)
        gap = np.hypot(*(p[1:] - centres[1:]).T)
        if np.any(gap < spec.radius + float(n.radius) - 1e-9):
            return False
    return True


def outranks(obs: Observation, other: Neighbour) -> bool:
    """Whether the robot of `obs` goes before `other`: higher priority, or on a tie (an engine
    that sets none) the smaller robot id."""
    if obs.priority != other.priority:
        return obs.priority > other.priority
    return obs.robot < other.robot
