"""What the planner answers with: a `Path` (a polyline) and a `Reference` (samples in time).

Both are frozen and hold read-only arrays, since the planner's caches hand the same answer to
every caller; `make_path` and `make_reference` build them so.
"""

from __future__ import annotations

__all__ = ["Path", "Reference", "make_path", "make_reference"]

import math
from dataclasses import dataclass, replace

import numpy as np


@dataclass(frozen=True, eq=False)
class Path:
    """A collision-free polyline from start to goal.

    Attributes
    ----------
    waypoints:
        ``(n, 2)`` read-only array; row 0 is the start, row ``n-1`` the goal (``n >= 2``). Each leg
        between consecutive rows lies in the free space (`PathPlanner.speed_limit` is not None).
    length:
        Total length in metres.
    travel_time:
        Estimate in seconds: every stretch of every leg driven at its own speed limit (along the
        leg's direction, per-axis limits), ignoring acceleration. A lower bound on the time of
        the matching `Reference`, and what dispatchers compare robots by.
    """

    waypoints: np.ndarray
    length: float
    travel_time: float


@dataclass(frozen=True, eq=False)
class Reference:
    """A time-parameterised reference that the discrete double integrator tracks exactly.

    Sample ``k`` is at time ``t0 + k*dt``. Between samples the robot moves on the straight chord
    ``p[k] -> p[k+1] = p[k] + dt*v[k]`` at constant velocity ``v[k]``. The samples start at rest
    at the path's start (``v[0] = 0``, so ``p[1] = p[0]``) and end at rest at its goal
    (``v[K] = 0``). Every chord lies in the free space and respects the speed limit of every
    region it overlaps; ``|v[k+1] - v[k]| <= a_max*dt`` on each axis.

    Attributes
    ----------
    t0:
        Time (s) of sample 0.
    dt:
        Sample period (s), the robot's control period.
    positions:
        ``(K+1, 2)`` read-only array, ``p[0]`` = start, ``p[K]`` = goal.
    velocities:
        ``(K+1, 2)`` read-only array; ``v[k]`` is held over ``[t_k, t_{k+1}]``.
    path:
        The polyline the samples follow.
    """

    t0: float
    dt: float
    positions: np.ndarray
    velocities: np.ndarray
    path: Path

    @property
    def steps(self) -> int:
        """K, the number of steps (samples minus one)."""
        return len(self.positions) - 1

    @property
    def duration(self) -> float:
        """``K * dt`` seconds from the first sample to the last."""
        return self.steps * self.dt

    @property
    def t_end(self) -> float:
        """Time of the last sample, when the robot is at rest at the goal."""
        return self.t0 + self.duration

    @property
    def times(self) -> np.ndarray:
        """Sample times ``t0 + k*dt``, shape ``(K+1,)``."""
        return self.t0 + self.dt * np.arange(len(self.positions))

    def index(self, t: float) -> int:
        """The sample nearest to time `t`, clamped to ``[0, K]``."""
        k = round((t - self.t0) / self.dt)
        return int(min(max(k, 0), self.steps))

    def sample(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Position and velocity at time `t`, following the step semantics.

        The position is interpolated linearly between samples; the velocity is the one held over
        the step (``v[k]`` on ``[t_k, t_{k+1})``), so ``p(t + h) = p(t) + h*v(t)`` within a step.
        Before `t0` the robot waits at the start, after `t_end` at the goal, both at rest.
        """
        x = (t - self.t0) / self.dt
        if x <= 0.0:
            return self.positions[0].copy(), np.zeros(2)
        if x >= self.steps:
            return self.positions[-1].copy(), np.zeros(2)
        # A time a hair before a sample (rounding) belongs to that sample's step.
        k = min(int(math.floor(x + 1e-9)), self.steps - 1)
        frac = max(x - k, 0.0)
        p = self.positions[k] + frac * (self.positions[k + 1] - self.positions[k])
        return p, self.velocities[k].copy()

    def shifted(self, t0: float) -> Reference:
        """The same samples starting at time `t0` (arrays are shared, not copied)."""
        return replace(self, t0=float(t0))


def _readonly(a: np.ndarray) -> np.ndarray:
    """`a` as a contiguous float array nobody can write to (answers are shared by the caches)."""
    a = np.ascontiguousarray(a, dtype=float)
    a.setflags(write=False)
    return a


def make_path(waypoints: np.ndarray, travel_time: float) -> Path:
    """A `Path` along `waypoints` (made read-only), its length summed over its legs."""
    legs = np.diff(waypoints, axis=0)
    length = float(np.hypot(legs[:, 0], legs[:, 1]).sum())
    return Path(_readonly(waypoints), length, float(travel_time))


def make_reference(dt: float, pos: np.ndarray, vel: np.ndarray, path: Path) -> Reference:
    """A `Reference` whose sample 0 is at time 0 (`Reference.shifted` moves it), read-only."""
    return Reference(0.0, float(dt), _readonly(pos), _readonly(vel), path)
