"""`PathFollower`: drive along `PathPlanner.reference` without any optimisation.

The path layer's `Reference` is exact for the discrete double integrator (``p[k+1] = p[k] +
dt*v[k]``, ``v[k+1] = v[k] + dt*u[k]``) and already respects obstacles, zone speed limits and
the acceleration bound. Starting from rest where the reference starts, commanding
``u[k] = (v_ref[k+1] - v[k]) / dt`` therefore reproduces it to rounding, and the follower needs
no model of the floor of its own. Everything else here is about the moments when the robot is
*not* on a fresh reference: a new goal while moving, no goal, a speed cap, or a disturbance,
and about other robots (`guard`, built on `yielding`): with neighbours in sight every command
is checked before it is sent, and a deadlock is answered with a detour. The tracking law is in
`track`, the choice of speed and planner in `pace`; the follower keeps the state from tick to
tick and decides, per observation, which of them acts.
"""

from __future__ import annotations

import math
import numbers
from typing import TYPE_CHECKING

from fleet.errors import NoPathError
from fleet.plugins import Command, Controller, ControllerContext, ControlStatus, Observation
from fleet.plugins.robot import brake_input
from fleet_plugins.follower.guard import Guard
from fleet_plugins.follower.pace import Planners, speed_limit
from fleet_plugins.follower.track import Track
from fleet_plugins.follower.yielding import DEFAULT_MARGIN_M, DEFAULT_YIELD_S

if TYPE_CHECKING:
    from fleet.paths import PathPlanner, Reference

__all__ = [
    "PathFollower",
    "FixedSpeed",
    "QSPSpeed",
    "PrintFirst",
    "CAP_MODES",
    "REST_SPEED",
    "PLAN_HORIZON",
    "PLAN_SAMPLE",
    "FACE_OFF_S",
]

#: Per-axis speed (m/s) below which the robot counts as at rest (rounding, not motion).
REST_SPEED = 1e-9
#: How far ahead (s) the `Command.plan` reaches.
PLAN_HORIZON = 5.0
#: Spacing (s) of the `Command.plan` samples.
PLAN_SAMPLE = 1.0
#: How long (s) a robot held at rest by lower-priority robots at rest on its way waits before
#: it plans round them (`PathFollower`, rule 3); the deadlock watch waits far longer
#: (``deadlock_after_s``, 20 to 30 s), and face-offs in the open floor cost that much each.
FACE_OFF_S = 3.0
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
      ``e = p_ref[k+1] - (p + dt*v)`` exceeds `track.FEEDBACK_DEADBAND`, a feedback
      ``gain * e / dt**2`` that removes the fraction `gain` of the error per period. The next
      velocity is then clipped per axis to the reference's own speed at that step (never
      faster than the safe reference) and the acceleration to ``a_max`` per axis.
    - **off track** (more than `track.REPLAN_ERROR` from the reference, e.g. after the engine
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
    braking trajectory (it may brake at any tick, this one included); without a plan, within
    one step and its braking of where it is. The gap kept is
    ``R = radius + neighbour.radius + margin_m``.

    - **yield** (rule 2): to every *higher*-priority neighbour with a plan that is not a
      blocker and not behind it (`yielding.behind`: on the far side of the line through the
      robot square to its way), the robot compares its own path over its braking time from
      top speed (plus the time to reach that speed) plus `yield_s` with the neighbour's plan
      (`must_yield`); if the plan comes within R of that path where the neighbour would be
      first, the robot waits: it brakes to rest and stays at rest, its reference kept
      ready, until the plan has passed.
      A higher-priority robot does not wait for lower ones: towards them only the stopping
      check applies, so two robots never wait for each other.
    - **stopping check** (rule 1, every neighbour): the tracking command is sent only if, after
      it, full braking along the line of travel (`braking_path` from the next state), and then
      standing where that stops for `yield_s` more, keeps more than R, plus the step a
      neighbour may take in this same tick (`Forecast.lead`), from every neighbour's
      forecast (`stops_clear`); a neighbour behind the robot counts by its braking from now
      only (it follows, and keeps its own braking clear: braking where its plan would pass
      held robots in a row creeping at 2 cm/s for good, fuzz s21-0998); otherwise the robot
      brakes along its line of travel and, at rest, drives the rest of the same path from
      where it stopped (timed anew from rest by `PathPlanner.reference_along`, not searched
      again), or stays at rest. A robot at rest
      sets off only if the check, made one tick ahead with each neighbour one step on at its
      velocity, would let it drive on (`Guard.keeps_going`): otherwise it crept, setting off,
      braking and timing a new reference every third tick. Robots routing round blockers
      (rule 3) still creep: that can be what frees the deadlock. A neighbour already closer
      than R (two robots set off in the same tick) may not be approached at all, only moved
      away from or passed square to: two followers never close in.
    - **deadlock** (rule 3, ``obs.blockers``): the robot plans round the blockers it sees, each
      a temporary obstacle of radius R (`Detour`, built once per set of blockers; less where
      the robot stands closer), and does not yield to them. With no such route it brakes and
      answers `ControlStatus.BLOCKED` (its agent hands the job back). Held at rest for
      `FACE_OFF_S` by lower-priority robots at rest on its way (`Guard.in_the_way`), it plans
      round them the same way without waiting for the watch; with no way round them it holds
      (no hand-back) and does not try again until one of them moves. When the blockers are
      cleared it keeps the detour it drives while each of them stands where it stood
      (`Guard.route`); once one moves or is out of sight it brakes to rest and plans the
      normal route again.

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
        self._plan_steps = 0
        self._plan_stride = 1
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
        self._planners = Planners(context, self.rough_v_max)
        hold_steps = math.ceil(self.yield_s / dt - 1e-9)
        self._guard = Guard(
            context.spec, self._planners.floor, self.margin_m, self.yield_s, hold_steps
        )
        #: Tracking commands held back because braking after them would leave the free space,
        #: or enter a region faster than its limit.
        self.brakes_for_walls = 0
        self.brakes_for_zones = 0
        self._clear()

    def _clear(self) -> None:
        self._track: Track | None = None
        self._goal: tuple[float, float] | None = None
        self._cap = math.inf
        self._route_key: tuple[str, ...] | None = None
        self._failed: tuple[object, ...] | None = None
        self._waiting = False
        # Since when it has been held at rest (None: it is not), the robots at rest in its way
        # it plans round (`_face_off_check`), and those it found no way round, where they stood.
        self._held_since: float | None = None
        self._face_off: tuple[str, ...] = ()
        self._tried: dict[str, tuple[float, float]] = {}
        # The planner of the current reference, and the rest of its path after a hold.
        self._planner: PathPlanner | None = None
        self._resume: tuple[tuple[float, float], list[tuple[float, float]]] | None = None

    # -- the control law ------------------------------------------------------------------------
    def compute(self, obs: Observation) -> Command:
        """The acceleration for this tick; see the class docstring for the behaviour."""
        spec = self.context.spec
        if obs.goal is None:
            self._clear()
            return self._brake(obs, ControlStatus.IDLE)
        if self.print_first and obs.print_end_s is not None and obs.t < obs.print_end_s:
            self._track = None
            return self._brake(obs, ControlStatus.OK)  # printing standing still
        goal = (float(obs.goal[0]), float(obs.goal[1]))
        cap = speed_limit(obs, spec, self.speed, self.caps)
        if cap <= REST_SPEED:
            self._track = None
            return self._brake(obs, ControlStatus.OK)

        # A detour it drives is kept after the watch stops naming its blockers (`Guard.route`).
        keep = goal == self._goal and self._route_key is not None and self._failed is None
        if obs.blockers or goal != self._goal or not self._guard.in_place(obs, self._face_off):
            self._face_off = ()
        route = self._guard.route(obs, keep, self._face_off)
        key = None if route is None else route.key
        stale = goal != self._goal or cap != self._cap or key != self._route_key
        if self._track is not None and (stale or self._track.off_track(obs)):
            self._track = None
        if stale:
            self._resume = None
        if self._track is None:
            self._waiting = False
            if max(abs(obs.vx), abs(obs.vy)) > REST_SPEED:
                return self._brake(obs, ControlStatus.OK)
            if obs.x == goal[0] and obs.y == goal[1]:
                return Command(0.0, 0.0, ControlStatus.OK)  # already there: nothing to plan
            # Without a route round its blockers the robot cannot do its job: hand it back.
            # A detour kept with no blockers named holds (OK) and is dropped by the attempt.
            failure = ControlStatus.FALLBACK if route is None else ControlStatus.BLOCKED
            if route is not None and not obs.blockers:
                failure = ControlStatus.OK
            attempt = (goal, obs.x, obs.y, cap, key)
            if self._failed == attempt:
                if route is None or not self._guard.blockers_moved(obs):
                    return self._brake(obs, failure)
                route = self._guard.rebuild(obs)  # a blocker moved: it may have freed a way
                key = None if route is None else route.key
            try:
                if route is None:
                    planner = self._planners.at(cap)
                else:
                    planner = self._guard.detour_planner(obs, cap)
                if planner is None:
                    raise NoPathError((obs.x, obs.y), goal, "the blockers close every route")
                ref = self._resumed(obs, planner) if planner is self._planner else None
                if ref is None:
                    ref = planner.reference(
                        start=(obs.x, obs.y), goal=goal, dt=spec.period, t0=obs.t
                    )
            except NoPathError:
                self._failed = attempt
                if self._face_off and not obs.blockers:
                    # No way round them: the normal route again, and these not tried again
                    # until one of them moves (the deadlock watch takes it from there).
                    self._tried = self._guard.where(obs, self._face_off)
                    self._face_off = ()
                return self._brake(obs, failure)
            self._goal, self._cap, self._route_key, self._failed = goal, cap, key, None
            self._track, self._planner, self._resume = Track(ref), planner, None
        track = self._track
        cmd = track.command(
            obs,
            dt=spec.period,
            a_max=spec.a_max,
            gain=self.gain,
            steps=self._plan_steps,
            stride=self._plan_stride,
        )
        stop = self._guard.braking_after(obs, cmd)
        if obs.neighbours and not self._guard.may_go(obs, track, stop, self._cap):
            return self._hold(obs, track)
        if not self._guard.stops_inside(obs, stop):
            self.brakes_for_walls += 1
            return self._hold(obs, track)
        if not self._guard.stops_within_limits(obs, stop):
            self.brakes_for_zones += 1
            return self._hold(obs, track)
        if (
            obs.neighbours
            and not obs.blockers
            and max(abs(obs.vx), abs(obs.vy)) <= REST_SPEED
            and not self._guard.keeps_going(obs, track, cmd, self._cap, self.gain)
        ):
            return self._hold(obs, track)  # no creeping: set off only to drive on
        self._waiting = False
        self._held_since = None
        return cmd

    def _hold(self, obs: Observation, track: Track) -> Command:
        """Brake to rest (forgetting the reference), or stay at rest with it kept ready."""
        if max(abs(obs.vx), abs(obs.vy)) > REST_SPEED:
            # It stops: the plan it sends says so, and once at rest it drives the rest of the
            # same path from there (its reference is timed anew, the path not searched again).
            self._resume = track.rest_of_path(obs)
            self._track = None
            self._waiting = False
            return self._brake(obs, ControlStatus.OK)
        k = track.ref.index(obs.t)
        if abs(track.samples[2][k]) <= REST_SPEED and abs(track.samples[3][k]) <= REST_SPEED:
            # Where the reference is at rest too (not started yet, or a first step at rest):
            # it resumes from this sample at the next tick. Left running, it had the robot
            # at rest a step behind and the tracking law caught up at once (fuzz s21-0766: 0.56
            # m/s, the reference's speed a step on, in a zone of 0.46 m/s).
            dt = self.context.spec.period
            self._track = track.shifted(obs.t + dt - k * dt)
        self._face_off_check(obs, track)
        # The hold is news on its first tick, then sent about once per PLAN_SAMPLE like a route.
        send = not self._waiting or obs.tick % self._plan_stride == 0
        self._waiting = True
        if not send:
            return Command(0.0, 0.0, ControlStatus.OK)
        held = ((obs.t, obs.x, obs.y), (obs.t + PLAN_HORIZON, obs.x, obs.y))
        return Command(0.0, 0.0, ControlStatus.OK, held)

    def _face_off_check(self, obs: Observation, track: Track) -> None:
        """Held at rest for `FACE_OFF_S` by lower-priority robots at rest on its way (two robots
        face to face, each keeping clear of the other: the higher one no longer waits for the
        deadlock watch), the robot plans round them as round blockers (rule 3), from the
        next tick; one that found no way round them is not tried again until one moves."""
        if self._held_since is None:
            self._held_since = obs.t
        if (
            obs.blockers
            or self._face_off
            or self._goal is None
            or obs.t - self._held_since < FACE_OFF_S - 1e-9
        ):
            return
        found = self._guard.in_the_way(obs, track, self._cap, self._goal)
        if found and not self._guard.same_places(obs, found, self._tried):
            self._face_off = found

    def _resumed(self, obs: Observation, planner: PathPlanner) -> Reference | None:
        """A reference along the rest of the path the robot was held on, from where it stopped;
        None without one (or if a leg of it leaves the free space: then it plans anew)."""
        if self._resume is None:
            return None
        (ux, uy), waypoints = self._resume
        # Waypoints that braking along the leg carried it onto or past are behind it now.
        k = 0
        while k < len(waypoints) - 1 and (
            (waypoints[k][0] - obs.x) * ux + (waypoints[k][1] - obs.y) * uy <= 1e-9
        ):
            k += 1
        try:
            return planner.reference_along(
                (obs.x, obs.y), waypoints[k:], self.context.spec.period, obs.t
            )
        except NoPathError:
            return None

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
