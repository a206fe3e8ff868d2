"""Which other robots a solve keeps clear of, and whether a plan keeps clear of them all.

A robot needs keeping clear of when its predicted square can come within reach of the plan
(the reachable boxes, narrowed to the regions each step may use) and, with
``respect_priority``, it outranks this one wherever it is, and only when parked for the whole
horizon or close (closer than two robots at full speed need to stop, plus a step each) if this
one outranks it. The higher one thus keeps its course unless the lower one is close (when
both yielded at any distance, both swerved alike and met again: measured head-on). A moving
robot may carry on with its plan or drop it at its next tick (to brake when its solve fails, or
to re-plan, as this one does at the same time), so the plan keeps clear of the box round both
its plan and its braking path; only a robot parked for the horizon is a plain square.
`separation` turns the chosen ones into rows.
"""

from __future__ import annotations

import math

import numpy as np

from fleet.plugins import Neighbour, Observation, RobotSpec
from fleet_plugins.mpc.fallback import braking_path
from fleet_plugins.mpc.separation import Obstacle, at_rest, predict, reaches

__all__ = ["robots_to_avoid", "clear_of_neighbours", "closest_approach", "outranks"]


def robots_to_avoid(
    obs: Observation,
    spec: RobotSpec,
    horizon: int,
    p_lo: np.ndarray,
    p_hi: np.ndarray,
    *,
    margin: float,
    respect_priority: bool,
) -> list[Obstacle]:
    """The robots of `obs.neighbours` the plan must keep clear of, nearest first (on a tie,
    by robot id); `p_lo`, `p_hi` bound where each point of the plan can be."""
    N, dt = horizon, spec.period
    # Within this, two robots at full speed could not stop before they met.
    near = spec.v_max**2 / spec.a_max + 2.0 * spec.v_max * dt
    picked: list[tuple[float, str, Obstacle]] = []
    for n in obs.neighbours:
        centres = predict(n, obs.t, dt, N)
        half = spec.radius + float(n.radius) + margin
        distance = math.hypot(n.x - obs.x, n.y - obs.y)
        ob = Obstacle.square(n.robot, centres, half, margin)
        moving = not at_rest(centres)
        if respect_priority and moving and outranks(obs, n) and distance >= half + near:
            continue  # it yields to this robot; this one keeps its course
        if moving:
            # A moving robot may carry on with its plan, or drop it at its next tick to brake
            # (a failed solve) or to re-plan: keep clear of the box round both, whichever robot
            # yields (against its plan alone, a robot tailed the other 0.7 m behind and met it
            # when that one braked; tests/test_mpc_contact.py).
            stop = np.array(braking_path(obs.t, n.x, n.y, n.vx, n.vy, dt, spec.a_max, N))
            stop = np.vstack([stop[:, 1:], np.repeat(stop[-1:, 1:], N + 1 - len(stop), 0)])
            ob = Obstacle.between(n.robot, centres, stop, half, margin)
        if not reaches(ob, p_lo, p_hi):
            continue
        picked.append((distance, n.robot, ob))
    picked.sort(key=lambda item: (item[0], item[1]))
    return [ob for _, _, ob in picked]


def clear_of_neighbours(obs: Observation, spec: RobotSpec, p: np.ndarray) -> bool:
    """Whether plan `p` (steps 0..N from now) keeps every neighbour's predicted disc out
    of its own from step 1 to step N, between the steps too (a fallback plan is checked
    before it is followed)."""
    for n in obs.neighbours:
        centres = predict(n, obs.t, spec.period, len(p) - 1)
        if closest_approach(p[1:], centres[1:]) < spec.radius + float(n.radius) - 1e-9:
            return False
    return True


def closest_approach(p: np.ndarray, q: np.ndarray) -> float:
    """The least distance between two robots moving in straight lines from sample to sample
    of `p` and `q` (``(K, 2)``, the same instants), between the samples too.

    Checking the samples alone lets two robots on one line pass through each other: head on
    at 1 m/s each and 0.5 s steps, each sample of one falls midway between two of the other,
    1.25 m apart, and the robots meet in between (found by the MPC fleet property test).
    """
    d = np.asarray(p, dtype=float) - np.asarray(q, dtype=float)  # their difference, per sample
    if len(d) == 1:
        return float(np.hypot(*d[0]))
    d0, step = d[:-1], np.diff(d, axis=0)
    length2 = np.einsum("ij,ij->i", step, step)
    # The point of each segment of the difference nearest the origin (clamped to the segment).
    s = np.divide(
        -np.einsum("ij,ij->i", d0, step), length2, out=np.zeros_like(length2), where=length2 > 0
    )
    nearest = d0 + np.clip(s, 0.0, 1.0)[:, None] * step
    return float(np.min(np.hypot(nearest[:, 0], nearest[:, 1])))


def outranks(obs: Observation, other: Neighbour) -> bool:
    """Whether the robot of `obs` goes before `other`: higher priority, or on a tie (an engine
    that sets none) the smaller robot id."""
    if obs.priority != other.priority:
        return obs.priority > other.priority
    return obs.robot < other.robot
