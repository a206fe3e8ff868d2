"""The paper's robot model: a discrete-time double integrator with box input bounds.

State ``x = [px, py, vx, vy]``, input ``u = [ax, ay]``, and ``x[k+1] = A x[k] + B u[k]`` with::

    A = [[1, 0, dt, 0],        B = [[0,  0],
         [0, 1, 0, dt],             [0,  0],
         [0, 0, 1,  0],             [dt, 0],
         [0, 0, 0,  1]]             [0, dt]]

so the position moves with the velocity of the current step and the input takes effect on the
next one. Between samples the robot moves on the straight segment ``p[k] -> p[k+1]`` at constant
velocity ``v[k]``; the safety checker judges exactly that segment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fleet.plugins.contracts import Neighbour, RobotSpec

__all__ = [
    "DoubleIntegrator",
    "brake_input",
    "clip",
    "neighbour_stray",
    "stray_between",
    "unseen_step",
]


def clip(value: float, bound: float) -> float:
    """`value` limited to [-bound, bound]."""
    return bound if value > bound else -bound if value < -bound else value


def brake_input(vx: float, vy: float, dt: float, a_max: float) -> tuple[float, float]:
    """The input that slows the robot toward rest as fast as the bound allows.

    Both axes are scaled by one factor, so the robot brakes along its line of travel: braking each
    axis on its own would stop the faster axis last and bend the path (possibly into an obstacle).
    """
    fastest = max(abs(vx), abs(vy))
    if fastest == 0.0:
        return 0.0, 0.0
    scale = min(1.0, a_max * dt / fastest)
    return -vx / dt * scale, -vy / dt * scale


@dataclass(frozen=True)
class DoubleIntegrator:
    """The discrete double integrator with period `dt` (s) and per-axis bound `a_max` (m/s^2)."""

    dt: float
    a_max: float

    def __post_init__(self) -> None:
        if not self.dt > 0:
            raise ValueError(f"period dt must be positive, got {self.dt!r}")
        if not self.a_max > 0:
            raise ValueError(f"acceleration bound a_max must be positive, got {self.a_max!r}")

    @property
    def A(self) -> np.ndarray:
        dt = self.dt
        return np.array(
            [[1.0, 0.0, dt, 0.0], [0.0, 1.0, 0.0, dt], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
        )

    @property
    def B(self) -> np.ndarray:
        dt = self.dt
        return np.array([[0.0, 0.0], [0.0, 0.0], [dt, 0.0], [0.0, dt]])

    def step(
        self, x: float, y: float, vx: float, vy: float, ax: float, ay: float
    ) -> tuple[float, float, float, float]:
        """One step from (x, y, vx, vy) under input (ax, ay), clipped to the input bound.

        Written on plain floats: the engine calls it once per robot per tick.
        """
        dt, a = self.dt, self.a_max
        ax, ay = clip(ax, a), clip(ay, a)
        return x + dt * vx, y + dt * vy, vx + dt * ax, vy + dt * ay


def unseen_step(dt: float, a_max: float, v_max: float = math.inf) -> float:
    """How far (m) a robot can stray in one step of unknown acceleration from where braking or
    its plan put it: its velocity changes by at most ``a_max * dt`` per axis, and, bounded by
    ``v_max`` per axis, by at most ``v_max`` beyond braking to rest, so the step ends at most
    ``min(a_max * dt, v_max) * dt`` per axis further. At a coarse period the speed bound is the
    tighter one (period 1 s, a_max 1.96, v_max 0.73: 1.03 m instead of 2.77 m): followers kept
    2.77 m more than the radii from every neighbour, froze face to face metres apart in open
    floor, and jobs waited to the end of the run (fuzz s21-0388, s21-0691). The follower keeps
    it from its neighbours, and the engine's making way allows for it (`fleet.engine.makeway`)."""
    return math.sqrt(2.0) * min(a_max * dt, v_max) * dt


def stray_between(own: RobotSpec, theirs: RobotSpec) -> float:
    """How far (m) a robot with spec `theirs` may stray unseen, between two looks of a robot
    with spec `own`, from where its plan or braking puts it: `unseen_step` with its own limits
    over the longer of the two periods. A robot of a shorter period steps several times between
    two looks; its velocity still changes by at most ``a_max`` per second, so its position by at
    most ``a_max * T**2`` over a window ``T``. For robots of one kind this is
    ``unseen_step(own.period, own.a_max, own.v_max)``."""
    return unseen_step(max(own.period, theirs.period), theirs.a_max, theirs.v_max)


def neighbour_stray(n: Neighbour, own: RobotSpec) -> float:
    """`stray_between` for neighbour `n` as seen by a robot with spec `own`, by the limits the
    observation gives (`Neighbour.limits`: the observer's where not known)."""
    return stray_between(own, n.limits(own))
