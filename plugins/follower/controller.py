"""`PathFollower`: drive along `PathPlanner.reference` without any optimisation.

The path layer's `Reference` is exact for the discrete double integrator (``p[k+1] = p[k] +
dt*v[k]``, ``v[k+1] = v[k] + dt*u[k]``) and already respects obstacles, zone speed limits and
the acceleration bound. Starting from rest where the reference starts, commanding
``u[k] = (v_ref[k+1] - v[k]) / dt`` therefore reproduces it to rounding, and the follower needs
no model of the floor of its own. Everything else here is about the moments when the robot is
*not* on a fresh reference: a new goal while moving, no goal, a speed cap, or a disturbance,
and about other robots (`fleet_plugins.follower.yielding`): with neighbours in sight every
command is checked before it is sent, and a deadlock is answered with a detour.
"""

from __future__ import annotations

import math
import numbers
from typing import TYPE_CHECKING

from fleet.errors import NoPathError
from fleet.plugins import Command, Controller, ControllerContext, ControlStatus, Observation
from fleet.plugins.robot import brake_input, clip
from fleet_plugins.follower.yielding import (
    DEFAULT_MARGIN_M,
    DEFAULT_YIELD_S,
    Detour,
    Forecast,
    Sample,
    braking_path,
    must_yield,
    stops_clear,
)

if TYPE_CHECKING:
    from fleet.floor import Floor
    from fleet.paths import PathPlanner, Reference

__all__ = [
    "PathFollower",
    "FixedSpeed",
    "QSPSpeed",
    "PrintFirst",
    "CAP_MODES",
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
#: How the follower takes print caps (option ``caps``): see `PathFollower`.
CAP_MODES = ("window", "ahead", "ignore")


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
    or the predicted braking trajectory while braking.

    **Other robots** (``obs.neighbours``; with none in sight nothing below applies). Each
    neighbour's whereabouts come from `Forecast`: on its plan or anywhere between that and its
    braking trajectory (it may brake at any tick); without a plan, within one step and its
    braking of where it is. The gap kept is ``R = radius + neighbour.radius + margin_m``.

    - **yield** (rule 2): to every *higher*-priority neighbour with a plan that is not a
      blocker, the robot compares its own path over its braking time from top speed (plus the
      time to reach that speed) plus `yield_s` with the neighbour's plan (`must_yield`); if the
      plan comes within R of that path where the neighbour would be first, the robot waits: it
      brakes to rest and stays at rest, its reference kept ready, until the plan has passed.
      A higher-priority robot does not wait for lower ones: towards them only the stopping
      check applies, so two robots never wait for each other.
    - **stopping check** (rule 1, every neighbour): the tracking command is sent only if, after
      it, full braking along the line of travel (`braking_path` from the next state), and then
      standing where that stops for `yield_s` more, keeps more than R from every neighbour's
      forecast (`stops_clear`); otherwise the robot brakes (and drops its reference, so it
      comes to rest and plans again), or stays at rest. A neighbour already closer than R (two
      robots set off in the same tick) may not be approached at all, only moved away from or
      passed square to: two followers never close in.
    - **deadlock** (rule 3, ``obs.blockers``): the robot plans round the blockers it sees, each
      a temporary obstacle of radius R (`Detour`, built once per set of blockers; less where
      the robot stands closer), and does not yield to them. With no such route it brakes and
      answers `ControlStatus.BLOCKED` (its agent hands the job back). When the blockers are
      cleared it brakes to rest and plans the normal route again.

    Braking and waiting send their plans at once (the stop, or the spot held for
    `PLAN_HORIZON` seconds), so neighbours never see a stale "moving on".

    Parameters
    ----------
    gain:
        Fraction of a position error removed per period, in [0, 1]. With exact tracking the
        error is rounding only and the feedback never acts.
    speed:
        Cruising speed (m/s per axis) below the robot's own limit; None: the robot's ``v_max``.
    caps:
        How print caps bind: ``"window"`` (default) plans at the tightest cap of the whole
        look-ahead window, as above; ``"ahead"`` at the tightest cap of the next
        ``v/a_max + 2 period`` seconds, just long enough to brake to rest before a tighter cap
        starts, so each task is driven at its own cap; ``"ignore"`` plans without print caps (a
        baseline for studies whose caps are advice, ``[print] enforce = false``; with enforced
        caps it breaks them).
    print_first:
        Stand still while the job's print lasts (``Observation.print_end_s``), then drive: the
        print-then-deliver strategy.
    rough_v_max:
        Drive over the map's rough areas (bumps, rough floor) at most this fast (m/s per axis),
        planning with them as speed zones: the paper's "varying" strategy. None: no such care.
    margin_m:
        Gap (m) kept between footprints on top of the sum of the radii (default 0.1).
    yield_s:
        How far (s) beyond its braking horizon a robot looks at higher-priority plans before it
        sets off or drives on, and how long the spot where it would stop must stay clear
        (default 2).

    Raises
    ------
    ValueError
        If `gain` is not a number in [0, 1], `speed` or `rough_v_max` not a positive number,
        `caps` not one of `CAP_MODES`, `print_first` not a boolean, or `margin_m` or `yield_s`
        not a number >= 0.
    """

    name = "follower"

    def __init__(
        self,
        gain: float = 0.5,
        speed: float | None = None,
        caps: str = "window",
        print_first: bool = False,
        rough_v_max: float | None = None,
        margin_m: float = DEFAULT_MARGIN_M,
        yield_s: float = DEFAULT_YIELD_S,
    ) -> None:
        super().__init__()
        cls = type(self).__name__
        if (
            isinstance(gain, bool)
            or not isinstance(gain, numbers.Real)
            or not 0.0 <= float(gain) <= 1.0
        ):
            raise ValueError(
                f"{cls} option gain = {gain!r}: must be a number in [0, 1] (the fraction "
                f"of a position error removed per period; 0 turns the feedback off)"
            )
        for option, value in (("speed", speed), ("rough_v_max", rough_v_max)):
            if value is not None and (
                isinstance(value, bool)
                or not isinstance(value, numbers.Real)
                or not 0.0 < float(value) < math.inf
            ):
                raise ValueError(
                    f"{cls} option {option} = {value!r}: must be a positive number (m/s)"
                )
        for option, value, unit in (("margin_m", margin_m, "m"), ("yield_s", yield_s, "s")):
            if (
                isinstance(value, bool)
                or not isinstance(value, numbers.Real)
                or not 0.0 <= float(value) < math.inf
            ):
                raise ValueError(
                    f"{cls} option {option} = {value!r}: must be a number >= 0 ({unit})"
                )
        if caps not in CAP_MODES:
            raise ValueError(f"{cls} option caps = {caps!r}: must be one of {CAP_MODES}")
        if not isinstance(print_first, bool):
            raise ValueError(f"{cls} option print_first = {print_first!r}: must be true or false")
        self.gain = float(gain)
        self.speed = None if speed is None else float(speed)
        self.caps = caps
        self.print_first = print_first
        self.rough_v_max = None if rough_v_max is None else float(rough_v_max)
        self.margin_m = float(margin_m)
        self.yield_s = float(yield_s)
        self._detour: Detour | None = None
        self._blockers: list[tuple[str, float, float, float]] = []
        self._samples: tuple[list[float], ...] = ([], [], [], [])
        self._plan_steps = 0
        self._plan_stride = 1
        self._hold_steps = 0
        self._planners: dict[float, PathPlanner] = {}
        self._clear()

    def __repr__(self) -> str:
        return (
            f"{type(self).__name__}(gain={self.gain!r}, speed={self.speed!r}, "
            f"caps={self.caps!r}, print_first={self.print_first!r}, "
            f"rough_v_max={self.rough_v_max!r}, margin_m={self.margin_m!r}, "
            f"yield_s={self.yield_s!r})"
        )

    def reset(self, context: ControllerContext) -> None:
        """Keep the context and forget any reference from a previous run."""
        super().reset(context)
        dt = context.spec.period
        self._plan_steps = math.ceil(PLAN_HORIZON / dt)
        # About one plan sample per second: enough for neighbours and the replay, and cheap
        # to send every tick.
        self._plan_stride = max(1, round(PLAN_SAMPLE / dt))
        self._hold_steps = math.ceil(self.yield_s / dt - 1e-9)
        self._planners = {}
        self._detour = None
        self._floor = context.floor
        if self.rough_v_max is not None and context.floor.spec.rough_areas:
            self._floor = _rough_floor(context.floor, self.rough_v_max)
        self._clear()

    def _clear(self) -> None:
        self._ref: Reference | None = None
        self._goal: tuple[float, float] | None = None
        self._cap = math.inf
        self._route_key: tuple[str, ...] | None = None
        self._failed: tuple[object, ...] | None = None
        self._waiting = False

    # -- the control law ------------------------------------------------------------------------
    def compute(self, obs: Observation) -> Command:
        """The acceleration for this tick; see the class docstring for the behaviour."""
        spec = self.context.spec
        if obs.goal is None:
            self._clear()
            return self._brake(obs, ControlStatus.IDLE)
        if self.print_first and obs.print_end_s is not None and obs.t < obs.print_end_s:
            self._ref = None
            return self._brake(obs, ControlStatus.OK)  # printing standing still
        goal = (float(obs.goal[0]), float(obs.goal[1]))
        cap = self._speed_limit(obs)
        if cap <= REST_SPEED:
            self._ref = None
            return self._brake(obs, ControlStatus.OK)

        route = self._route(obs)
        key = None if route is None else route.key
        stale = goal != self._goal or cap != self._cap or key != self._route_key
        if self._ref is not None and (stale or self._off_track(obs)):
            self._ref = None
        if self._ref is None:
            self._waiting = False
            if max(abs(obs.vx), abs(obs.vy)) > REST_SPEED:
                return self._brake(obs, ControlStatus.OK)
            if obs.x == goal[0] and obs.y == goal[1]:
                return Command(0.0, 0.0, ControlStatus.OK)  # already there: nothing to plan
            # Without a route round its blockers the robot cannot do its job: hand it back.
            failure = ControlStatus.FALLBACK if route is None else ControlStatus.BLOCKED
            attempt = (goal, obs.x, obs.y, cap, key)
            if self._failed == attempt:
                return self._brake(obs, failure)
            try:
                planner = self._planner(cap) if route is None else self._detour_planner(obs, cap)
                if planner is None:
                    raise NoPathError((obs.x, obs.y), goal, "the blockers close every route")
                self._ref = planner.reference(
                    start=(obs.x, obs.y), goal=goal, dt=spec.period, t0=obs.t
                )
            except NoPathError:
                self._failed = attempt
                return self._brake(obs, failure)
            self._goal, self._cap, self._route_key, self._failed = goal, cap, key, None
            ref = self._ref
            self._samples = (
                ref.positions[:, 0].tolist(),
                ref.positions[:, 1].tolist(),
                ref.velocities[:, 0].tolist(),
                ref.velocities[:, 1].tolist(),
            )
        cmd = self._track(obs, self._ref)
        if obs.neighbours:
            return self._guard(obs, self._ref, cmd)
        self._waiting = False
        return cmd

    # -- other robots -----------------------------------------------------------------------------
    def _guard(self, obs: Observation, ref: Reference, cmd: Command) -> Command:
        """`cmd` if the robot may go on (rules 1 and 2 of the class docstring), else a hold."""
        spec = self.context.spec
        dt, a_max = spec.period, spec.a_max
        forecasts = [Forecast.of(n, obs.t, dt, a_max) for n in obs.neighbours]
        # The next state is fixed but for this command's velocity; from there, full braking.
        vx, vy = obs.vx + dt * clip(cmd.ax, a_max), obs.vy + dt * clip(cmd.ay, a_max)
        stop = braking_path(obs.t + dt, obs.x + dt * obs.vx, obs.y + dt * obs.vy, vx, vy, dt, a_max)
        # Where it would stop must stay clear a while too: stopping right in the way of a
        # robot about to pass is no stop in time.
        t_stop, x_stop, y_stop = stop[-1]
        held = [(t_stop + i * dt, x_stop, y_stop) for i in range(1, self._hold_steps + 1)]
        blockers = set(obs.blockers)  # routed round: waiting for them would undo the detour
        higher = [
            f
            for f in forecasts
            if f.priority > obs.priority and f.has_plan and f.robot not in blockers
        ]
        if higher:
            # The braking horizon from the top speed, plus the time to get there: the window
            # then ends at the same spot while the robot speeds up, so a robot that set off
            # never sees a conflict it could not see at rest (no creeping start-stop-start).
            top = min(self._cap, spec.v_max)
            speed = min(max(abs(obs.vx), abs(obs.vy)), top)
            own = self._own_path(obs, ref, (2.0 * top - speed) / a_max + self.yield_s)
            for f in higher:
                if must_yield(own, f, spec.radius + f.radius + self.margin_m):
                    return self._hold(obs, ref)
        now = (obs.t, obs.x, obs.y)
        # Round lower-priority blockers the detour keeps what it could (less than the gap when
        # they were stuck close): hold it to that. Higher ones go first (they route round this
        # one): the robot only moves away from them while that close.
        gaps = None
        if self._detour is not None and obs.blockers:
            gaps = {
                f.robot: min(
                    spec.radius + f.radius + self.margin_m, self._detour.clearance[f.robot] - 1e-3
                )
                for f in forecasts
                if f.robot in self._detour.clearance and f.priority < obs.priority
            }
        if not stops_clear(stop + held, forecasts, spec.radius, self.margin_m, now, gaps):
            return self._hold(obs, ref)
        self._waiting = False
        return cmd

    def _own_path(self, obs: Observation, ref: Reference, horizon: float) -> list[Sample]:
        """The reference's samples over the next `horizon` seconds: where the robot would be."""
        dt = self.context.spec.period
        xs, ys = self._samples[0], self._samples[1]
        last = len(xs) - 1
        k = ref.index(obs.t)
        n = math.ceil(horizon / dt - 1e-9)
        return [(obs.t + i * dt, xs[min(k + i, last)], ys[min(k + i, last)]) for i in range(n + 1)]

    def _hold(self, obs: Observation, ref: Reference) -> Command:
        """Brake to rest (forgetting the reference), or stay at rest with it kept ready."""
        if max(abs(obs.vx), abs(obs.vy)) > REST_SPEED:
            # It stops: the plan it sends says so, and it plans again once at rest.
            self._ref = None
            self._waiting = False
            return self._brake(obs, ControlStatus.OK)
        if ref.index(obs.t) == 0:
            # Not started yet: start the reference again at the next tick.
            self._ref = ref.shifted(obs.t + self.context.spec.period)
        # The hold is news on its first tick, then sent about once per PLAN_SAMPLE like a route.
        send = not self._waiting or obs.tick % self._plan_stride == 0
        self._waiting = True
        if not send:
            return Command(0.0, 0.0, ControlStatus.OK)
        held = ((obs.t, obs.x, obs.y), (obs.t + PLAN_HORIZON, obs.x, obs.y))
        return Command(0.0, 0.0, ControlStatus.OK, held)

    def _route(self, obs: Observation) -> Detour | None:
        """The detour round this observation's blockers (those in sight), None without any."""
        if not obs.blockers:
            self._detour = None
            return None
        seen = {n.robot: n for n in obs.neighbours}
        blockers = [
            (n.robot, n.x, n.y, n.radius)
            for name in sorted(set(obs.blockers))
            if (n := seen.get(name)) is not None
        ]
        if not blockers:
            self._detour = None
            return None
        key = tuple(b[0] for b in blockers)
        if self._detour is None or self._detour.key != key:
            # Once per set of blockers: cutting them out of the floor and building a planner
            # take about 0.15 to 0.25 s on the shop floor.
            self._blockers = blockers
            self._detour = self._build_detour(obs)
        return self._detour

    def _build_detour(self, obs: Observation) -> Detour:
        spec = self.context.spec
        # Past the gap by the drift a parked robot is granted (`Forecast`), so that the
        # stopping check lets the robot drive the detour past a blocker that sends no plan.
        drift = math.sqrt(2.0) * spec.a_max * spec.period**2
        return Detour.build(
            self._floor,
            self._blockers,
            spec.radius,
            self.margin_m + drift,
            (obs.x, obs.y),
            spec.a_max,
        )

    def _detour_planner(self, obs: Observation, cap: float) -> PathPlanner | None:
        """The detour's planner at speed `cap`, rebuilt if the robot stands in a blocker's
        obstacle (it came closer than the margin since the detour was built)."""
        detour = self._detour
        assert detour is not None
        floor = detour.floor
        if floor is not None and not floor.is_free(obs.x, obs.y):
            detour = self._detour = self._build_detour(obs)
        return detour.planner(min(cap, self.context.spec.v_max))

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
        # The last sample always: near the goal it is where the robot will rest.
        steps = [*range(k, stop, stride), stop]
        plan = tuple((ref.t0 + i * dt, xs[i], ys[i]) for i in steps)
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
    def _speed_limit(self, obs: Observation) -> float:
        """The speed (m/s per axis) to plan at, from the robot, `speed` and the print caps."""
        spec = self.context.spec
        pace = spec.v_max if self.speed is None else min(spec.v_max, self.speed)
        if self.caps == "ignore":
            return pace
        cap = pace if obs.speed_cap is None else min(pace, float(obs.speed_cap))
        # "ahead": long enough to brake to rest from the fastest the robot can be going before
        # a tighter cap starts (pace/a_max rounded up to whole periods; the velocity of the step
        # in progress is already fixed).
        ahead = obs.t + pace / spec.a_max + 2.0 * spec.period
        until = math.inf if self.caps == "window" else ahead
        for start, _, piece_cap in obs.speed_caps:
            if start < until:
                cap = min(cap, float(piece_cap))
        return cap

    def _off_track(self, obs: Observation) -> bool:
        assert self._ref is not None
        k = self._ref.index(obs.t)
        xs, ys = self._samples[0], self._samples[1]
        return max(abs(xs[k] - obs.x), abs(ys[k] - obs.y)) > REPLAN_ERROR

    def _planner(self, cap: float) -> PathPlanner:
        """The context's planner, or one for a robot capped at `cap` m/s (built once per cap)."""
        spec = self.context.spec
        if cap >= spec.v_max and self._floor is self.context.floor:
            return self.context.planner
        cap = min(cap, spec.v_max)
        if cap not in self._planners:
            from fleet.paths import PathPlanner  # only speed caps need a planner of our own

            self._planners[cap] = PathPlanner(self._floor, v_max=cap, a_max=spec.a_max)
        return self._planners[cap]


# Floors with slow rough areas, shared by every robot of a run: (floor, v) -> floor.
_ROUGH_FLOORS: dict[tuple[int, float], tuple[Floor, Floor]] = {}


def _rough_floor(floor: Floor, v_max: float) -> Floor:
    key = (id(floor), v_max)
    if key not in _ROUGH_FLOORS or _ROUGH_FLOORS[key][0] is not floor:
        from fleet.floor import slow_on_rough

        _ROUGH_FLOORS.clear()  # one run's floor at a time: no growth over a long study
        _ROUGH_FLOORS[key] = (floor, slow_on_rough(floor.spec, v_max))
    return _ROUGH_FLOORS[key][1]


class FixedSpeed(PathFollower):
    """Print while driving at one fixed speed, whatever prints: the follower with a `speed`
    (required) and print caps ignored (``caps = "ignore"``). A baseline for throughput studies
    that judge parts by quality (``[print] enforce = false``)."""

    name = "fixed_speed"

    def __init__(
        self,
        speed: float,
        gain: float = 0.5,
        caps: str = "ignore",
        margin_m: float = DEFAULT_MARGIN_M,
        yield_s: float = DEFAULT_YIELD_S,
    ) -> None:
        super().__init__(gain=gain, speed=speed, caps=caps, margin_m=margin_m, yield_s=yield_s)


class QSPSpeed(PathFollower):
    """Rule-based quality-speed controller: drive each print task at its own cap (the follower
    with ``caps = "ahead"``) and cross rough floor at `rough_v_max` (default 0.2 m/s, the
    paper's speed over bumps; its vibration profile gives a 0.007 mm jolt there). With
    ``[print] caps = "quality"`` the caps are the QSP's fastest speeds within each kind's
    tolerance."""

    name = "qsp_speed"

    def __init__(
        self,
        gain: float = 0.5,
        speed: float | None = None,
        rough_v_max: float | None = 0.2,
        margin_m: float = DEFAULT_MARGIN_M,
        yield_s: float = DEFAULT_YIELD_S,
    ) -> None:
        super().__init__(
            gain=gain,
            speed=speed,
            caps="ahead",
            rough_v_max=rough_v_max,
            margin_m=margin_m,
            yield_s=yield_s,
        )


class PrintFirst(PathFollower):
    """Print-then-deliver: print standing where the job was given (at the depot, for a robot
    that returns home), then drive at full speed (the follower with ``print_first = true``)."""

    name = "print_first"

    def __init__(
        self,
        gain: float = 0.5,
        speed: float | None = None,
        margin_m: float = DEFAULT_MARGIN_M,
        yield_s: float = DEFAULT_YIELD_S,
    ) -> None:
        super().__init__(
            gain=gain, speed=speed, print_first=True, margin_m=margin_m, yield_s=yield_s
        )
