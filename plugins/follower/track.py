"""One reference being tracked: the follower's tracking law and the plan it announces.

The path layer's `Reference` is exact for the discrete double integrator, so commanding
``u[k] = (v_ref[k+1] - v[k]) / dt`` reproduces it to rounding; a feedback acts only on errors
past `FEEDBACK_DEADBAND`, and past `REPLAN_ERROR` the robot is off track (it brakes and plans
again). The samples are kept as plain floats: the law runs once per robot per tick, and
numpy's per-call overhead on 2-vectors would dominate.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from fleet.plugins import Command, ControlStatus, Observation
from fleet.plugins.robot import clip
from fleet_plugins.follower.yielding import Sample

XY = tuple[float, float]

if TYPE_CHECKING:
    from fleet.paths import Reference

__all__ = ["Track", "FEEDBACK_DEADBAND", "REPLAN_ERROR"]

#: Position error (m) below which no feedback is added: exact tracking leaves only rounding.
FEEDBACK_DEADBAND = 1e-6
#: Position error (m) from the reference above which tracking is abandoned (brake, replan).
REPLAN_ERROR = 1e-3


class Track:
    """A reference and its samples ``x, y, vx, vy`` as lists of floats.

    Parameters
    ----------
    ref:
        The reference tracked.
    samples:
        Its positions' and velocities' columns as lists; taken from `ref` when None.
    """

    def __init__(
        self,
        ref: Reference,
        samples: tuple[list[float], list[float], list[float], list[float]] | None = None,
    ) -> None:
        self.ref = ref
        if samples is None:
            samples = (
                ref.positions[:, 0].tolist(),
                ref.positions[:, 1].tolist(),
                ref.velocities[:, 0].tolist(),
                ref.velocities[:, 1].tolist(),
            )
        self.samples = samples

    def shifted(self, t0: float) -> Track:
        """The same track, starting at `t0` (for a robot that waited before it set off)."""
        return Track(self.ref.shifted(t0), self.samples)

    def command(
        self, obs: Observation, *, dt: float, a_max: float, gain: float, steps: int, stride: int
    ) -> Command:
        """The tracking command at the observation's time, with the next `steps` samples (every
        `stride`-th, and the last) as its plan on the ticks that fall on a stride."""
        xs, ys, vxs, vys = self.samples
        ref = self.ref
        last = len(xs) - 1
        k = ref.index(obs.t)
        nxt = min(k + 1, last)
        tx, ty = vxs[nxt], vys[nxt]
        # Where p[k+1] lands versus where it should be.
        ex = xs[nxt] - (obs.x + dt * obs.vx)
        ey = ys[nxt] - (obs.y + dt * obs.vy)
        if max(abs(ex), abs(ey)) > FEEDBACK_DEADBAND:
            # v[k+1] = v_ref[k+1] + gain*e/dt leaves (1 - gain)*e at the step after next.
            tx += gain / dt * ex
            ty += gain / dt * ey
        bx, by = abs(vxs[nxt]), abs(vys[nxt])
        ux = clip((clip(tx, bx) - obs.vx) / dt, a_max)
        uy = clip((clip(ty, by) - obs.vy) / dt, a_max)
        if k % stride:
            # The plan is sent every `stride` ticks (about once per PLAN_SAMPLE); between, the
            # last one still holds.
            return Command(ux, uy, ControlStatus.OK)
        stop = min(last, k + steps)
        # The last sample always: near the goal it is where the robot will rest.
        indices = [*range(k, stop, stride), stop]
        plan = tuple((ref.t0 + i * dt, xs[i], ys[i]) for i in indices)
        return Command(ux, uy, ControlStatus.OK, plan)

    def off_track(self, obs: Observation) -> bool:
        """Whether the robot is more than `REPLAN_ERROR` from where the reference has it now."""
        k = self.ref.index(obs.t)
        xs, ys = self.samples[0], self.samples[1]
        return max(abs(xs[k] - obs.x), abs(ys[k] - obs.y)) > REPLAN_ERROR

    def rest_of_path(self, obs: Observation) -> tuple[tuple[float, float], list[XY]] | None:
        """Where a robot braking now along its line of travel leaves the path: the direction of
        the leg it is on and the waypoints after that leg (the goal last); None when the
        robot is not on a leg of the path, moving along it.

        A robot held while moving brakes to rest on that leg's line and drives the rest of the
        same path from there (`PathPlanner.reference_along`) instead of searching it again.
        """
        wp = self.ref.path.waypoints.tolist()
        x, y, vx, vy = obs.x, obs.y, obs.vx, obs.vy
        for j in reversed(range(len(wp) - 1)):
            (ax, ay), (bx, by) = wp[j], wp[j + 1]
            dx, dy = bx - ax, by - ay
            length = math.hypot(dx, dy)
            if length == 0.0 or dx * vx + dy * vy <= 0.0:
                continue
            ux, uy = dx / length, dy / length
            along = (x - ax) * ux + (y - ay) * uy
            off = abs((x - ax) * uy - (y - ay) * ux)
            if -REPLAN_ERROR <= along <= length + REPLAN_ERROR and off <= REPLAN_ERROR:
                return (ux, uy), [(float(p[0]), float(p[1])) for p in wp[j + 1 :]]
        return None

    def ahead(self, obs: Observation, dt: float, horizon: float) -> list[Sample]:
        """The reference's samples over the next `horizon` seconds: where the robot would be."""
        xs, ys = self.samples[0], self.samples[1]
        last = len(xs) - 1
        k = self.ref.index(obs.t)
        n = math.ceil(horizon / dt - 1e-9)
        return [(obs.t + i * dt, xs[min(k + i, last)], ys[min(k + i, last)]) for i in range(n + 1)]
