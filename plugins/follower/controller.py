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

from fleet.errors import NoPathError
from fleet.plugins import Command, Controller, ControllerContext, ControlStatus, Observation
from fleet.robot import brake_input, clip

if TYPE_CHECKING:
    from fleet.paths import PathPlanner, Reference

__all__ = [
    "PathFollower",
    "REST_SPEED",
    "FEEDBACK_DEADBAND",
    "REPLAN_ERROR",
    "PLAN_HORIZON",
    "PLAN_SAMPLE",
]

#: Per-axis speed (m/s) below which the robot counts as at rest (rounding, not motion).
REST_SPEED = 1e-9
#: Position error (m) below which no feedback is added: exact tracking leaves only rounding.
FEEDBACK_DEADBAND = 1e-6
#: Position error (m) from the reference above which tracking is abandoned (brake, replan).
REPLAN_ERROR = 1e-3
#: How far ahead (s) the `Command.plan` reaches.
PLAN_HORIZON = 5.0
#: Spacing (s) of the `Command.plan` samples.
PLAN_SAMPLE = 1.0


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
    - **print speed caps** (``obs.speed_caps``, the caps of the coming
      `fleet.plugins.CAP_LOOKAHEAD_S` seconds, and ``obs.speed_cap``): plans with a planner whose
      robot speed is the tightest of them, so a cap never starts while the robot drives faster.
      When that tightest cap changes the robot brakes to rest and replans (the planner plans
      from rest): a tighter cap entering the window is met long before it starts (braking takes
      ``v_max / a_max`` seconds, the window is a minute); a looser one costs a stop of
      ``cap / a_max`` seconds. Conservative: the robot drives at the pace of the slowest task
      of the coming minute. A cap of zero holds the robot.
    - **no path** (`NoPathError`): hold at rest with `ControlStatus.FALLBACK`, retrying only when
      the goal, the position or the cap changes.

    `Command.plan` carries the next `PLAN_HORIZON` seconds of reference samples ``(t, x, y)``
    about every `PLAN_SAMPLE` seconds (sent on the ticks that fall on a sample; the others carry
    no plan, meaning the previous one holds),
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
        self._samples: tuple[list[float], ...] = ([], [], [], [])
        self._plan_steps = 0
        self._plan_stride = 1
        self._planners: dict[float, PathPlanner] = {}
        self._clear()

    def __repr__(self) -> str:
        return f"PathFollower(gain={self.gain!r})"

    def reset(self, context: ControllerContext) -> None:
        """Keep the context and forget any reference from a previous run."""
        super().reset(context)
        dt = context.spec.period
        self._plan_steps = math.ceil(PLAN_HORIZON / dt)
        # About one plan sample per second: enough for neighbours and the replay, and cheap
        # to send every tick.
        self._plan_stride = max(1, round(PLAN_SAMPLE / dt))
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
        if obs.goal is None:
            self._clear()
            return self._brake(obs, ControlStatus.IDLE)
        goal = (float(obs.goal[0]), float(obs.goal[1]))
        cap = spec.v_max if obs.speed_cap is None else min(spec.v_max, float(obs.speed_cap))
        for _, _, piece_cap in obs.speed_caps:
            cap = min(cap, float(piece_cap))
        if cap <= REST_SPEED:
            self._ref = None
            return self._brake(obs, ControlStatus.OK)

        stale = goal != self._goal or cap != self._cap
        if self._ref is not None and (stale or self._off_track(obs)):
            self._ref = None
        if self._ref is None:
            if max(abs(obs.vx), abs(obs.vy)) > REST_SPEED:
                return self._brake(obs, ControlStatus.OK)
            if obs.x == goal[0] and obs.y == goal[1]:
                return Command(0.0, 0.0, ControlStatus.OK)  # already there: nothing to plan
            attempt = (goal, obs.x, obs.y, cap)
            if self._failed == attempt:
                return self._brake(obs, ControlStatus.FALLBACK)
            try:
                self._ref = self._planner(cap).reference(
                    start=(obs.x, obs.y), goal=goal, dt=spec.period, t0=obs.t
                )
            except NoPathError:
                self._failed = attempt
                return self._brake(obs, ControlStatus.FALLBACK)
            self._goal, self._cap, self._failed = goal, cap, None
            ref = self._ref
            self._samples = (
                ref.positions[:, 0].tolist(),
                ref.positions[:, 1].tolist(),
                ref.velocities[:, 0].tolist(),
                ref.velocities[:, 1].tolist(),
            )
        return self._track(obs, self._ref)

    def _track(self, obs: Observation, ref: Reference) -> Command:
        # Plain floats on this path: it runs once per robot per tick, and numpy's per-call
        # overhead on 2-vectors would dominate.
        dt, a_max = self.context.spec.period, self.context.spec.a_max
        xs, ys, vxs, vys = self._samples
        last = len(xs) - 1
        k = ref.index(obs.t)
        nxt = min(k + 1, last)
        tx, ty = vxs[nxt], vys[nxt]
        # Where p[k+1] lands versus where it should be.
        ex = xs[nxt] - (obs.x + dt * obs.vx)
        ey = ys[nxt] - (obs.y + dt * obs.vy)
        if max(abs(ex), abs(ey)) > FEEDBACK_DEADBAND:
            # v[k+1] = v_ref[k+1] + gain*e/dt leaves (1 - gain)*e at the step after next.
            tx += self.gain / dt * ex
            ty += self.gain / dt * ey
        bx, by = abs(vxs[nxt]), abs(vys[nxt])
        ux = clip((clip(tx, bx) - obs.vx) / dt, a_max)
        uy = clip((clip(ty, by) - obs.vy) / dt, a_max)
        stride = self._plan_stride
        if k % stride:
            # The plan is sent about once per PLAN_SAMPLE; between, the last one still holds.
            return Command(ux, uy, ControlStatus.OK)
        stop = min(last, k + self._plan_steps)
        plan = tuple((ref.t0 + i * dt, xs[i], ys[i]) for i in range(k, stop + 1, stride))
        return Command(ux, uy, ControlStatus.OK, plan)

    def _brake(self, obs: Observation, status: ControlStatus) -> Command:
        """Slow down along the current direction of travel at the full per-axis bound."""
        dt, a_max = self.context.spec.period, self.context.spec.a_max
        if obs.vx == 0.0 and obs.vy == 0.0:
            return Command(0.0, 0.0, status)
        ax, ay = brake_input(obs.vx, obs.vy, dt, a_max)
        # The predicted stop, so neighbours and the replay see where the robot will halt.
        t, x, y, vx, vy = obs.t, obs.x, obs.y, obs.vx, obs.vy
        plan = [(t, x, y)]
        while max(abs(vx), abs(vy)) > REST_SPEED and t - obs.t < PLAN_HORIZON:
            bx, by = brake_input(vx, vy, dt, a_max)
            t, x, y, vx, vy = t + dt, x + dt * vx, y + dt * vy, vx + dt * bx, vy + dt * by
            plan.append((t, x, y))
        return Command(ax, ay, status, tuple(plan))

    # -- helpers --------------------------------------------------------------------------------
    def _off_track(self, obs: Observation) -> bool:
        assert self._ref is not None
        k = self._ref.index(obs.t)
        xs, ys = self._samples[0], self._samples[1]
        return max(abs(xs[k] - obs.x), abs(ys[k] - obs.y)) > REPLAN_ERROR

    def _planner(self, cap: float) -> PathPlanner:
        """The context's planner, or one for a robot capped at `cap` m/s (built once per cap)."""
        spec = self.context.spec
        if cap >= spec.v_max:
            return self.context.planner
        if cap not in self._planners:
            from fleet.paths import PathPlanner  # only speed caps need a planner of our own

            self._planners[cap] = PathPlanner(self.context.floor, v_max=cap, a_max=spec.a_max)
        return self._planners[cap]
