"""`PathFollower`: drive along `PathPlanner.reference` without any optimisation.

The path layer's `Reference` is exact for the discrete double integrator (``p[k+1] = p[k] +
dt*v[k]``, ``v[k+1] = v[k] + dt*u[k]``) and already respects obstacles, zone speed limits and
the acceleration bound. Starting from rest where the reference starts, commanding
``u[k] = (v_ref[k+1] - v[k]) / dt`` therefore reproduces it to rounding, and the follower needs
no model of the floor of its own. Everything else here is about the moments when the robot is
*not* on a fresh reference: a new goal while moving, no goal, a speed cap, or a disturbance.
"""

from __future__ import annotations

import math
import numbers
from typing import TYPE_CHECKING

import numpy as np

from fleet.errors import NoPathError
from fleet.plugins import Command, Controller, ControllerContext, ControlStatus, Observation

if TYPE_CHECKING:
    from fleet.paths import PathPlanner, Reference

__all__ = ["PathFollower", "REST_SPEED", "FEEDBACK_DEADBAND", "REPLAN_ERROR", "PLAN_HORIZON"]

#: Per-axis speed (m/s) below which the robot counts as at rest (rounding, not motion).
REST_SPEED = 1e-9
#: Position error (m) below which no feedback is added: exact tracking leaves only rounding.
FEEDBACK_DEADBAND = 1e-6
#: Position error (m) from the reference above which tracking is abandoned (brake, replan).
REPLAN_ERROR = 1e-3
#: How far ahead (s) the `Command.plan` reaches.
PLAN_HORIZON = 5.0


class PathFollower(Controller):
    """Track the path layer's reference to the goal; brake to rest whenever that is not possible.

    Behaviour per observation:

    - **goal None**: brake to rest along the current direction of travel, then hold
      (`ControlStatus.IDLE`, zero acceleration once at rest).
    - **new goal, at rest**: ask ``planner.reference(start=(x, y), goal, dt=period, t0=t)`` and
      track it (`ControlStatus.OK`).
    - **new goal while moving**: brake to rest first, then plan from where the robot stopped.
    - **tracking**: at tick time t with ``k = ref.index(t)``, the command is
      ``u = (v_ref[k+1] - v) / dt`` plus, when the predicted error
      ``e = p_ref[k+1] - (p + dt*v)`` exceeds `FEEDBACK_DEADBAND`, a feedback ``gain * e / dt**2``
      that removes the fraction `gain` of the error per period. The next velocity is then
      clipped per axis to the reference's own speed at that step (never faster than the safe
      reference) and the acceleration to ``a_max`` per axis.
    - **off track** (more than `REPLAN_ERROR` from the reference, e.g. after the engine
      substituted braking): brake to rest, then plan again.
    - **speed cap** (``obs.speed_cap``): plans with a planner whose robot speed is the cap; a cap
      lower than the current reference's makes the robot brake and replan (the braking itself
      may exceed a cap that drops faster than ``a_max`` allows). A cap of zero holds the robot.
    - **no path** (`NoPathError`): hold at rest with `ControlStatus.FALLBACK`, retrying only when
      the goal, the position or the cap changes.

    `Command.plan` carries the next `PLAN_HORIZON` seconds of reference samples ``(t, x, y)``,
    or the predicted braking trajectory while braking. The follower ignores other robots.

    Parameters
    ----------
    gain:
        Fraction of a position error removed per period, in [0, 1]. With exact tracking the
        error is rounding only and the feedback never acts.

    Raises
    ------
    ValueError
        If `gain` is not a number in [0, 1].
    """

    name = "follower"

    def __init__(self, gain: float = 0.5) -> None:
        super().__init__()
        if (
            isinstance(gain, bool)
            or not isinstance(gain, numbers.Real)
            or not 0.0 <= float(gain) <= 1.0
        ):
            raise ValueError(
                f"PathFollower option gain = {gain!r}: must be a number in [0, 1] (the fraction "
                f"of a position error removed per period; 0 turns the feedback off)"
            )
        self.gain = float(gain)
        self._planners: dict[float, PathPlanner] = {}
        self._clear()

    def __repr__(self) -> str:
        return f"PathFollower(gain={self.gain!r})"

    def reset(self, context: ControllerContext) -> None:
        """Keep the context and forget any reference from a previous run."""
        super().reset(context)
        self._planners = {}
        self._clear()

    def _clear(self) -> None:
        self._ref: Reference | None = None
        self._goal: tuple[float, float] | None = None
        self._cap = math.inf
        self._failed: tuple[object, ...] | None = None

    # -- the control law ------------------------------------------------------------------------
    def compute(self, obs: Observation) -> Command:
        """The acceleration for this tick; see the class docstring for the behaviour."""
        spec = self.context.spec
        p = np.array([obs.x, obs.y], dtype=float)
        v = np.array([obs.vx, obs.vy], dtype=float)
        if obs.goal is None:
            self._clear()
            return self._brake(obs, v, ControlStatus.IDLE)
        goal = (float(obs.goal[0]), float(obs.goal[1]))
        cap = spec.v_max if obs.speed_cap is None else min(spec.v_max, float(obs.speed_cap))
        if cap <= REST_SPEED:
            self._ref = None
            return self._brake(obs, v, ControlStatus.OK)

        if self._ref is not None and (
            goal != self._goal or cap < self._cap or self._off_track(obs, p)
        ):
            self._ref = None
        if self._ref is None:
            if not _at_rest(v):
                return self._brake(obs, v, ControlStatus.OK)
            attempt = (goal, obs.x, obs.y, cap)
            if self._failed == attempt:
                return self._brake(obs, v, ControlStatus.FALLBACK)
            try:
                self._ref = self._planner(cap).reference(
                    start=(obs.x, obs.y), goal=goal, dt=spec.period, t0=obs.t
                )
            except NoPathError:
                self._failed = attempt
                return self._brake(obs, v, ControlStatus.FALLBACK)
            self._goal, self._cap, self._failed = goal, cap, None
        return self._track(obs, p, v, self._ref)

    def _track(self, obs: Observation, p: np.ndarray, v: np.ndarray, ref: Reference) -> Command:
        dt, a_max = self.context.spec.period, self.context.spec.a_max
        positions, velocities = ref.positions, ref.velocities
        last = len(positions) - 1
        k = ref.index(obs.t)
        nxt = min(k + 1, last)
        target = velocities[nxt]
        error = positions[nxt] - (p + dt * v)  # where p[k+1] lands versus where it should be
        if np.max(np.abs(error)) > FEEDBACK_DEADBAND:
            # v[k+1] = v_ref[k+1] + gain*e/dt leaves (1 - gain)*e at the step after next.
            target = target + (self.gain / dt) * error
        box = np.abs(velocities[nxt])
        v_next = np.clip(target, -box, box)
        u = np.clip((v_next - v) / dt, -a_max, a_max)
        stop = min(last, k + math.ceil(PLAN_HORIZON / dt))
        plan = tuple(
            (ref.t0 + i * dt, float(positions[i, 0]), float(positions[i, 1]))
            for i in range(k, stop + 1)
        )
        return Command(float(u[0]), float(u[1]), ControlStatus.OK, plan)

    def _brake(self, obs: Observation, v: np.ndarray, status: ControlStatus) -> Command:
        """Slow down along the current direction of travel at the full per-axis bound."""
        dt, a_max = self.context.spec.period, self.context.spec.a_max
        if not np.any(v):
            return Command(0.0, 0.0, status)
        v_next = _braked(v, a_max * dt)
        u = np.clip((v_next - v) / dt, -a_max, a_max)
        # The predicted stop, so neighbours and the replay see where the robot will halt.
        t, p, w = obs.t, np.array([obs.x, obs.y]), v
        plan = [(t, obs.x, obs.y)]
        while np.any(w) and t - obs.t < PLAN_HORIZON:
            t, p, w = t + dt, p + dt * w, _braked(w, a_max * dt)
            plan.append((t, float(p[0]), float(p[1])))
        return Command(float(u[0]), float(u[1]), status, tuple(plan))

    # -- helpers --------------------------------------------------------------------------------
    def _off_track(self, obs: Observation, p: np.ndarray) -> bool:
        assert self._ref is not None
        k = self._ref.index(obs.t)
        return bool(np.max(np.abs(self._ref.positions[k] - p)) > REPLAN_ERROR)

    def _planner(self, cap: float) -> PathPlanner:
        """The context's planner, or one for a robot capped at `cap` m/s (built once per cap)."""
        spec = self.context.spec
        if cap >= spec.v_max:
            return self.context.planner
        if cap not in self._planners:
            from fleet.paths import PathPlanner  # only speed caps need a planner of our own

            self._planners[cap] = PathPlanner(self.context.floor, v_max=cap, a_max=spec.a_max)
        return self._planners[cap]


def _at_rest(v: np.ndarray) -> bool:
    return bool(np.max(np.abs(v)) <= REST_SPEED)


def _braked(v: np.ndarray, dv: float) -> np.ndarray:
    """`v` reduced by at most `dv` per axis, keeping its direction (so the robot stays on the
    straight line it was driving along), and exactly zero once within `dv` of rest."""
    fastest = float(np.max(np.abs(v)))
    if fastest <= dv:
        return np.zeros(2)
    return v * (1.0 - dv / fastest)
