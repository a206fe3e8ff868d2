"""Conformance kit for plugin authors: run a controller, dispatcher or charging policy for real,
check its contract.

`check_controller` drives a plugin in closed loop on the paper's discrete double integrator
over a small built-in floor (`conformance_floor`: a 20 x 10 m hall with a press in the middle and
a 0.4 m/s zone) with the real path layer, `check_dispatcher` feeds a dispatcher seeded
random fleets on the same floor, and `check_charging_policy` asks a charging policy about
seeded random battery states there. Each raises `ConformanceError` (an `AssertionError`, so pytest
reports it as an ordinary failure) whose message names the broken rule (`CONTROLLER_RULES`,
`DISPATCHER_RULES`, `CHARGING_RULES`), the plugin, and the tick or case where it broke.

Use it from your plugin's own test suite, next to a check that your entry point is found::

    # tests/test_conformance.py in your plugin's repository
    from fleet.plugins import discover, load_controller
    from fleet.plugins.testing import check_controller, check_dispatcher

    from my_package.control import MyController
    from my_package.dispatch import MyDispatcher


    def test_controller_conforms():
        check_controller(MyController, options={"horizon": 20})


    def test_dispatcher_conforms():
        check_dispatcher(MyDispatcher)


    def test_entry_point_is_found():
        # pyproject.toml: [project.entry-points."fleet.controllers"]
        #                 my_controller = "my_package.control:MyController"
        info = {p.name: p for p in discover("controller")}["my_controller"]
        assert info.error is None, info.error
        assert isinstance(load_controller("my_controller"), MyController)

The checks are deterministic (fixed trips, a seeded generator) and need no network or files.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any, NoReturn

import numpy as np
from shapely.geometry import box

from fleet.bus.schema import command_from_wire, command_to_wire
from fleet.errors import MessageError
from fleet.floor import Floor, FloorSpec, Obstacle, SpeedZone, Station
from fleet.paths import PathPlanner
from fleet.plugins import (
    Assignment,
    BatteryStatus,
    Charger,
    ChargingPolicy,
    Command,
    Controller,
    ControllerContext,
    ControlStatus,
    DispatchContext,
    Dispatcher,
    Job,
    Observation,
    RobotSpec,
    RobotStatus,
)
from fleet.plugins.robot import brake_input

__all__ = [
    "ConformanceError",
    "CONTROLLER_RULES",
    "DISPATCHER_RULES",
    "CONFORMANCE_SPEC",
    "conformance_floor",
    "check_controller",
    "check_dispatcher",
    "CHARGING_RULES",
    "check_charging_policy",
]

#: The rules `check_controller` enforces, by name (the name appears in every failure).
CONTROLLER_RULES: dict[str, str] = {
    "instantiate": "the factory accepts the options and returns a fleet.plugins.Controller",
    "reset": "reset accepts the ControllerContext without raising",
    "command": "compute returns a Command the bus carries (command_to_wire accepts it: finite "
    "real ax, ay, a ControlStatus, a plan of finite (t, x, y) tuples or lists), with a status "
    "other than ERROR (the agent's to set)",
    "accel-bound": "|ax| and |ay| are at most the spec's a_max (tolerance 1e-9)",
    "idle": "with no goal the status is IDLE, a robot at rest gets zero acceleration, and a "
    "moving one is brought to rest within |v|/a_max + 2 s",
    "free-space": "every step p[k] -> p[k+1] = p[k] + dt*v[k] stays in the free space",
    "speed-limit": "on every step |v[k].x|, |v[k].y| are within the per-axis limit "
    "planner.speed_limit gives for that step (tolerance 1e-6 m/s)",
    "reach-goal": "each goal is reached (within 0.05 m, speed below 0.01 m/s) within three times "
    "the reference duration plus 20 s, also after the engine substituted braking for a few "
    "ticks, and the robot stays there while the goal holds",
    "determinism": "two fresh instances fed the same observations give identical commands (as "
    "the bus delivers them)",
}

#: The rules `check_dispatcher` enforces, by name.
DISPATCHER_RULES: dict[str, str] = {
    "instantiate": "the factory accepts the options and returns a fleet.plugins.Dispatcher",
    "returns": "assign returns a list of fleet.plugins.Assignment",
    "empty": "no jobs or no robots gives no assignments",
    "open-jobs": "every assigned job is one of the open jobs passed in",
    "idle-robots": "every assigned robot is one of the robots passed in, and idle",
    "unique": "no job and no robot appears in two assignments",
    "progress": "with open jobs and idle robots on one connected floor, at least one job is "
    "assigned (a dispatcher that never assigns stalls the fleet)",
    "deterministic": "two fresh instances given the same cases in the same order return equal "
    "assignments",
    "no-mutation": "assign leaves its job list, robot list and context.extra unchanged",
}

#: The rules `check_charging_policy` enforces, by name.
CHARGING_RULES: dict[str, str] = {
    "instantiate": "the factory accepts the options and returns a fleet.plugins.ChargingPolicy",
    "returns": "go_charge returns a charger name or None; leave and takes_jobs return a bool",
    "known-charger": "go_charge names only chargers it was given",
    "no-flat-battery": "a robot with no charge left and no job is sent to a charger",
    "full-leaves": "a robot standing at its charger with a full battery leaves it",
    "deterministic": "two fresh instances given the same statuses in the same order answer alike",
    "no-mutation": "the statuses are left unchanged (they are frozen; the chargers too)",
}

#: The robot the controller check drives: the project's default robot.
CONFORMANCE_SPEC = RobotSpec(v_max=1.0, a_max=0.5, radius=0.4, period=0.25)

ACCEL_TOL = 1e-9  # m/s^2: the brief of the contract, commands are exact numbers
SPEED_TOL = 1e-6  # m/s: as fleet.engine.safety, forgives a solver's feasibility tolerance
GOAL_RADIUS = 0.05  # m
GOAL_SPEED = 0.01  # m/s
REST_SPEED = 1e-9  # m/s per axis: "at rest" for the zero-acceleration rule
HOLD_TICKS = 8  # ticks a robot must stay at a reached goal
REST_SLACK = 2.0  # s: allowed beyond |v|/a_max to bring a robot to rest when the goal goes

_SOURCE = "fleet.plugins.testing:conformance_floor"


class ConformanceError(AssertionError):
    """A plugin broke a rule of its contract.

    Attributes
    ----------
    rule:
        The rule's name, a key of `CONTROLLER_RULES` or `DISPATCHER_RULES`.
    plugin:
        How the plugin was named in the message (its class or factory).
    detail:
        What happened, with the values that broke the rule.
    """

    def __init__(self, plugin: str, rule: str, rules: Mapping[str, str], detail: str) -> None:
        self.plugin = plugin
        self.rule = rule
        self.detail = detail
        super().__init__(f"{plugin}: rule {rule!r} broken ({rules[rule]}): {detail}")


def conformance_floor() -> Floor:
    """The floor both checks run on: a 20 x 10 m hall, a 4 x 4 m press, a 0.4 m/s corner.

    Free space, as hand-made convex rectangles (x0, y0, x1, y1)::

        west   (0, 0, 8, 10)   1.0 m/s       north  (8, 7, 12, 10)  1.0 m/s
        south  (8, 0, 12, 3)   1.0 m/s       east   (12, 4, 20, 10) 1.0 m/s
        gate   (12, 0, 14, 4)  1.0 m/s       slow   (14, 0, 20, 4)  0.4 m/s (zone "slow")

    The press occupies (8, 3, 12, 7), so the west and east halls connect through the north and
    the south corridor. Stations: ``depot`` (2, 5), ``east`` (18, 7), ``slow`` (17, 1.5),
    ``southwest`` (2, 2), ``northwest`` (2, 8).
    """
    fast, slow = (1.0, 1.0), (0.4, 0.4)
    spec = FloorSpec(
        source=_SOURCE,
        name="conformance hall",
        boundary=box(0, 0, 20, 10),
        default_v_max=fast,
        obstacles=(Obstacle("press", box(8, 3, 12, 7)),),
        zones=(SpeedZone("slow", box(14, 0, 20, 4), slow),),
        stations=(
            Station("depot", 2.0, 5.0, kind="depot"),
            Station("east", 18.0, 7.0),
            Station("slow", 17.0, 1.5),
            Station("southwest", 2.0, 2.0),
            Station("northwest", 2.0, 8.0),
        ),
    )
    pieces = [
        (box(0, 0, 8, 10), fast, None),
        (box(8, 0, 12, 3), fast, None),
        (box(8, 7, 12, 10), fast, None),
        (box(12, 4, 20, 10), fast, None),
        (box(12, 0, 14, 4), fast, None),
        (box(14, 0, 20, 4), slow, "slow"),
    ]
    return Floor.from_regions(spec, pieces)


# --- controllers ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Phase:
    """Part of the controller drill: hold `goal` (None: idle) for the given ticks or until done.

    On the phase's ticks in `brakes` (counted from its start) the robot gets the engine's braking
    input instead of the controller's command, as when an answer is missing or late.
    """

    goal: tuple[float, float] | None
    ticks: int | None = None  # None: until the goal is reached (or the robot rests, when idle)
    brakes: range = range(0)


# From rest at the depot: stand idle, cross the hall around the press, drive into the slow zone,
# head for the south-west and change its mind half-way to the north-west; head south again and
# lose the goal at speed; cross the hall again while the engine brakes for 1 s, and stop.
_START = (2.0, 5.0)
_DRILL = (
    _Phase(None, ticks=4),
    _Phase((18.0, 7.0)),
    _Phase((17.0, 1.5)),
    _Phase((2.0, 2.0), ticks=16),
    _Phase((2.0, 8.0)),
    _Phase((2.0, 2.0), ticks=12),
    _Phase(None),
    _Phase((18.0, 7.0), brakes=range(12, 16)),
    _Phase(None),
)


def check_controller(
    factory: Callable[..., Controller], *, options: Mapping[str, Any] | None = None
) -> None:
    """Check a controller plugin against its contract by driving it in closed loop.

    The drill (fixed, on `conformance_floor` with `CONFORMANCE_SPEC` and a real
    `fleet.paths.PathPlanner`): from rest at (2, 5) stand idle, drive to (18, 7) around the
    press, into the slow zone at (17, 1.5), towards (2, 2) and after 4 s to (2, 8) instead;
    towards (2, 2) again until the goal is withdrawn after 3 s, at about 0.9 m/s (the robot
    must come to rest); to (18, 7) again, with the controller's commands replaced by the engine's
    braking input (`fleet.plugins.robot.brake_input`) for 1 s from 3 s into the trip; and stop.
    The robot is the double integrator ``p += dt*v; v += dt*clip(u, -a_max, a_max)``.
    Every command is checked as the bus delivers it (``command_from_wire(command_to_wire(c))``)
    and every tick against `CONTROLLER_RULES`; then a second fresh instance replays the same
    observations and must answer identically.

    Parameters
    ----------
    factory:
        The plugin class (or any callable returning a `Controller`), called as
        ``factory(**options)``.
    options:
        Keyword options, as a scenario's ``[controller.options]`` would pass them.

    Raises
    ------
    ConformanceError
        At the first broken rule, naming it.
    """
    label = _label(factory)
    floor = conformance_floor()
    first = _instantiate(factory, options, Controller, label, CONTROLLER_RULES)
    run = _Drill(first, floor, label)
    run.drive()
    second = _instantiate(factory, options, Controller, label, CONTROLLER_RULES)
    replay = _Drill(second, floor, label)  # a fresh planner too: no state shared with `first`
    for i, (obs, expected) in enumerate(run.log):
        got = replay.ask(obs)
        # Solve times are wall-clock measurements, never reproducible; the outcome must be.
        if _without_times(got) != _without_times(expected):
            _fail_controller(
                label,
                "determinism",
                f"at tick {obs.tick} (observation {i}) the first instance answered "
                f"{expected!r} and a fresh one {got!r}",
            )


class _Drill:
    """One controller, one simulated robot, every tick checked."""

    def __init__(self, controller: Controller, floor: Floor, label: str) -> None:
        self.spec = CONFORMANCE_SPEC
        self.controller = controller
        self.floor = floor
        self.label = label
        self.planner = PathPlanner(floor, self.spec.v_max, self.spec.a_max)
        self.p = np.array(_START, dtype=float)
        self.v = np.zeros(2)
        self.tick = 0
        self.log: list[tuple[Observation, Command]] = []
        self.braked: list[int] = []  # ticks of the current phase on which the kit braked
        try:
            controller.reset(ControllerContext("conformance", self.spec, floor, self.planner))
        except Exception as exc:
            _fail_controller(label, "reset", f"reset raised {type(exc).__name__}: {exc}")

    @property
    def t(self) -> float:
        return self.tick * self.spec.period

    def drive(self) -> None:
        for phase in _DRILL:
            self.braked = []
            if phase.goal is None:
                self._idle(phase)
            else:
                self._go(phase)

    def _idle(self, phase: _Phase) -> None:
        speed = float(np.hypot(*self.v))
        if phase.ticks is not None:
            limit = phase.ticks
        else:  # braking at a_max takes |v|/a_max; the slack forgives gentler braking
            limit = math.ceil((speed / self.spec.a_max + REST_SLACK) / self.spec.period)
        for _ in range(limit):
            at_rest = self._at_rest()
            obs, cmd = self.step(None)
            if cmd.status is not ControlStatus.IDLE:
                self._fail("idle", obs, f"status {cmd.status} with goal None, expected IDLE")
            if at_rest and max(abs(cmd.ax), abs(cmd.ay)) > ACCEL_TOL:
                self._fail(
                    "idle", obs, f"robot at rest with no goal got (ax, ay) = ({cmd.ax}, {cmd.ay})"
                )
            if phase.ticks is None and at_rest:
                return
        if phase.ticks is None and not self._at_rest():
            self._fail(
                "idle",
                self.log[-1][0],
                f"still moving at v = {_vec(self.v)} after {limit} ticks "
                f"({limit * self.spec.period:g} s) with no goal, from {speed:.3g} m/s when the "
                f"goal was withdrawn",
            )

    def _at_rest(self) -> bool:
        return bool(np.max(np.abs(self.v)) <= REST_SPEED)

    def _go(self, phase: _Phase) -> None:
        goal = phase.goal
        assert goal is not None
        if phase.ticks is not None:
            for i in range(phase.ticks):
                self.step(goal, brake=i in phase.brakes)
            return
        # The time allowed scales with what the path layer needs from a standstill here.
        ref = self.planner.reference(tuple(self.p), goal, dt=self.spec.period, t0=self.t)
        limit = math.ceil((3.0 * ref.duration + 20.0) / self.spec.period)
        for i in range(limit):
            if self._arrived(goal):
                break
            self.step(goal, brake=i in phase.brakes)
        else:
            self._fail(
                "reach-goal",
                self.log[-1][0],
                f"after {limit} ticks ({limit * self.spec.period:g} s) towards {_vec(goal)} the "
                f"robot is at {_vec(self.p)}, {_dist(self.p, goal):.3f} m away, moving at "
                f"{_vec(self.v)}",
            )
        for _ in range(HOLD_TICKS):
            self.step(goal)
            if not self._arrived(goal):
                self._fail(
                    "reach-goal",
                    self.log[-1][0],
                    f"left the reached goal {_vec(goal)}: now at {_vec(self.p)} moving at "
                    f"{_vec(self.v)}",
                )

    def _arrived(self, goal: tuple[float, float]) -> bool:
        return _dist(self.p, goal) <= GOAL_RADIUS and float(np.hypot(*self.v)) < GOAL_SPEED

    def ask(self, obs: Observation) -> Command:
        """The controller's command for `obs` as the bus delivers it, checked."""
        try:
            cmd = self.controller.compute(obs)
        except Exception as exc:
            self._fail("command", obs, f"compute raised {type(exc).__name__}: {exc}")
        return self._as_sent(cmd, obs)

    def _as_sent(self, cmd: object, obs: Observation) -> Command:
        """`cmd` as the bus delivers it (encoded, then decoded), checked against the rules."""
        if not isinstance(cmd, Command):
            self._fail("command", obs, f"compute returned {cmd!r}, not a Command")
        try:
            sent = command_from_wire(command_to_wire(cmd))
        except MessageError as exc:
            self._fail("command", obs, f"the bus rejects the command: {exc}")
        except Exception as exc:  # e.g. a numpy array as the plan: its truth value is ambiguous
            self._fail(
                "command",
                obs,
                f"the bus cannot encode the command (plan of type {type(cmd.plan).__name__}): "
                f"{type(exc).__name__}: {exc}",
            )
        if sent.status is ControlStatus.ERROR:
            self._fail("command", obs, "status = ERROR, which only the agent may set")
        a_max = self.spec.a_max
        if max(abs(sent.ax), abs(sent.ay)) > a_max + ACCEL_TOL:
            self._fail(
                "accel-bound", obs, f"(ax, ay) = ({sent.ax!r}, {sent.ay!r}) with a_max = {a_max}"
            )
        return sent

    def step(
        self, goal: tuple[float, float] | None, *, brake: bool = False
    ) -> tuple[Observation, Command]:
        """Observe, command, check this tick's step, integrate.

        With `brake` the controller is still asked (and checked) but the robot gets the engine's
        braking input instead, as when the controller's answer is lost or late.
        """
        obs = Observation(
            robot="conformance",
            tick=self.tick,
            t=self.t,
            x=float(self.p[0]),
            y=float(self.p[1]),
            vx=float(self.v[0]),
            vy=float(self.v[1]),
            goal=goal,
            job=None if goal is None else f"drill-{_vec(goal)}",
        )
        cmd = self.ask(obs)
        self.log.append((obs, cmd))
        # The step of this tick runs on the velocity already set by the previous command.
        dt, a_max = self.spec.period, self.spec.a_max
        p_next = self.p + dt * self.v
        self._check_step(obs, self.p, p_next, self.v)
        if brake:
            u = np.array(brake_input(float(self.v[0]), float(self.v[1]), dt, a_max))
            self.braked.append(self.tick)
        else:
            u = np.clip([cmd.ax, cmd.ay], -a_max, a_max)
        self.p, self.v = p_next, self.v + dt * u
        self.tick += 1
        return obs, cmd

    def _check_step(self, obs: Observation, p: np.ndarray, q: np.ndarray, v: np.ndarray) -> None:
        if not np.any(v):
            if not self.floor.is_free(float(p[0]), float(p[1])):
                self._fail("free-space", obs, f"robot at rest at {_vec(p)}, outside free space")
            return
        limit = self.planner.speed_limit(tuple(p), tuple(q))
        if limit is None:
            self._fail("free-space", obs, f"step {_vec(p)} -> {_vec(q)} leaves the free space")
        if abs(v[0]) > limit[0] + SPEED_TOL or abs(v[1]) > limit[1] + SPEED_TOL:
            self._fail(
                "speed-limit",
                obs,
                f"step {_vec(p)} -> {_vec(q)} at v = {_vec(v)}, limit {_vec(limit)} per axis",
            )

    def _fail(self, rule: str, obs: Observation, detail: str) -> NoReturn:
        if self.braked:
            detail += (
                f" (the kit substituted the engine's braking for the commands of ticks "
                f"{self.braked[0]}-{self.braked[-1]}, as the engine does when answers are lost)"
            )
        _fail_controller(self.label, rule, f"tick {obs.tick} (t = {obs.t:g} s): {detail}")


def _without_times(cmd: Command) -> Command:
    if cmd.solve is None:
        return cmd
    return replace(cmd, solve=replace(cmd.solve, solver_s=0.0, step_s=0.0))


def _fail_controller(label: str, rule: str, detail: str) -> NoReturn:
    raise ConformanceError(label, rule, CONTROLLER_RULES, detail)


# --- dispatchers ----------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Case:
    name: str
    jobs: tuple[Job, ...]
    robots: tuple[RobotStatus, ...]
    t: float


def check_dispatcher(
    factory: Callable[..., Dispatcher], *, options: Mapping[str, Any] | None = None
) -> None:
    """Check a dispatcher plugin against its contract on seeded random fleets.

    Cases (on `conformance_floor`, with a real `fleet.paths.PathPlanner` in the context): empty
    inputs; jobs with every robot busy; a job right next to a busy robot; a busy robot listed
    first; and 24 random fleets (1-6 jobs, 1-6 robots, some busy) from a fixed seed. Every
    answer is checked against `DISPATCHER_RULES`; then a second fresh instance is given the
    same cases in the same order (a dispatcher may keep state between calls) and must answer
    identically.

    Parameters
    ----------
    factory:
        The plugin class (or any callable returning a `Dispatcher`), called as
        ``factory(**options)``.
    options:
        Keyword options, as a scenario's ``[dispatcher.options]`` would pass them.

    Raises
    ------
    ConformanceError
        At the first broken rule, naming it and the case.
    """
    label = _label(factory)
    floor = conformance_floor()
    cases = _dispatch_cases(floor)
    first = _instantiate(factory, options, Dispatcher, label, DISPATCHER_RULES)
    planner = PathPlanner(floor, CONFORMANCE_SPEC.v_max, CONFORMANCE_SPEC.a_max)
    answers = []
    for case in cases:
        out = _assign(first, case, floor, planner, label)
        _check_assignments(out, case, label)
        answers.append(out)
    second = _instantiate(factory, options, Dispatcher, label, DISPATCHER_RULES)
    planner = PathPlanner(floor, CONFORMANCE_SPEC.v_max, CONFORMANCE_SPEC.a_max)  # nothing shared
    for case, out in zip(cases, answers, strict=True):
        again = _assign(second, case, floor, planner, label)
        if again != out:
            _fail_dispatcher(
                label,
                "deterministic",
                f"case {case.name!r}: the first instance answered {out!r}, a second fresh one "
                f"given the same cases in the same order {again!r}",
            )


def _assign(
    dispatcher: Dispatcher, case: _Case, floor: Floor, planner: PathPlanner, label: str
) -> list[Assignment]:
    jobs, robots = list(case.jobs), list(case.robots)
    extra = {"case": case.name, "note": "read only"}
    context = DispatchContext(t=case.t, floor=floor, planner=planner, extra=extra)
    try:
        out = dispatcher.assign(jobs, robots, context)
    except Exception as exc:
        _fail_dispatcher(
            label, "returns", f"case {case.name!r}: assign raised {type(exc).__name__}: {exc}"
        )
    if (
        jobs != list(case.jobs)
        or robots != list(case.robots)
        or extra != {"case": case.name, "note": "read only"}
    ):
        _fail_dispatcher(label, "no-mutation", f"case {case.name!r}: an input was changed")
    return out


def _check_assignments(out: object, case: _Case, label: str) -> None:
    where = f"case {case.name!r}"
    if not isinstance(out, list) or not all(isinstance(a, Assignment) for a in out):
        _fail_dispatcher(label, "returns", f"{where}: assign returned {out!r}")
    assert isinstance(out, list)
    job_ids = {j.id for j in case.jobs}
    robots = {r.robot: r for r in case.robots}
    idle = [r for r in case.robots if r.idle]
    if (not case.jobs or not case.robots) and out:
        _fail_dispatcher(
            label,
            "empty",
            f"{where}: {len(case.jobs)} jobs, {len(case.robots)} robots, yet assigned {out!r}",
        )
    for a in out:
        if a.job not in job_ids:
            _fail_dispatcher(
                label, "open-jobs", f"{where}: job {a.job!r} is not open ({sorted(job_ids)})"
            )
        if a.robot not in robots:
            _fail_dispatcher(label, "idle-robots", f"{where}: robot {a.robot!r} is unknown")
        if not robots[a.robot].idle:
            _fail_dispatcher(
                label,
                "idle-robots",
                f"{where}: robot {a.robot!r} is busy with {robots[a.robot].job!r} "
                f"but got job {a.job!r}",
            )
    for what, ids in (("job", [a.job for a in out]), ("robot", [a.robot for a in out])):
        twice = sorted({i for i in ids if ids.count(i) > 1})
        if twice:
            _fail_dispatcher(label, "unique", f"{where}: {what}(s) {twice} assigned twice: {out!r}")
    if case.jobs and idle and not out:
        _fail_dispatcher(
            label,
            "progress",
            f"{where}: {len(case.jobs)} open jobs and {len(idle)} idle robots, nothing assigned",
        )


def _dispatch_cases(floor: Floor) -> list[_Case]:
    """Fixed cases first (the easy ways to get it wrong), then seeded random fleets."""
    rng = np.random.default_rng(20250607)

    def job(i: str, x: float, y: float, released: float) -> Job:
        return Job(id=i, station=f"st-{i}", x=x, y=y, released_s=released)

    def robot(i: str, x: float, y: float, idle: bool) -> RobotStatus:
        return RobotStatus(i, x, y, 0.0, 0.0, idle=idle, job=None if idle else f"busy-{i}")

    near = (
        job("j1", 17.0, 8.0, 5.0),
        job("j2", 3.0, 3.0, 1.0),
    )
    cases = [
        _Case("no jobs, no robots", (), (), 0.0),
        _Case("no jobs", (), (robot("r1", 2.0, 5.0, True),), 10.0),
        _Case("no robots", near, (), 10.0),
        _Case("all busy", near, (robot("r1", 17, 7.5, False), robot("r2", 3, 3.5, False)), 10.0),
        _Case(
            "busy robot nearest and first",
            near,
            (robot("r2", 17.0, 7.8, False), robot("r1", 2.0, 9.0, True)),
            10.0,
        ),
    ]
    for n in range(24):
        n_jobs, n_robots = int(rng.integers(1, 7)), int(rng.integers(1, 7))
        jobs = tuple(
            job(f"job-{int(k):02d}", *_free_point(rng, floor), float(rng.integers(0, 8)) * 2.5)
            for k in rng.permutation(n_jobs)
        )
        idle = rng.random(n_robots) < 0.6
        if n % 2 == 0:
            idle[0] = False  # a busy robot first in the list catches "take the first robot"
        robots = tuple(
            robot(f"r{int(k)}", *_free_point(rng, floor), bool(idle[i]))
            for i, k in enumerate(rng.permutation(n_robots))
        )
        cases.append(_Case(f"random #{n}", jobs, robots, 30.0))
    return cases


def _free_point(rng: np.random.Generator, floor: Floor) -> tuple[float, float]:
    x0, y0, x1, y1 = floor.bounds
    while True:
        x, y = round(float(rng.uniform(x0, x1)), 2), round(float(rng.uniform(y0, y1)), 2)
        if floor.is_free(x, y):
            return x, y


def _fail_dispatcher(label: str, rule: str, detail: str) -> NoReturn:
    raise ConformanceError(label, rule, DISPATCHER_RULES, detail)


# --- charging policies ------------------------------------------------------------------------


def check_charging_policy(
    factory: Callable[..., ChargingPolicy], *, options: Mapping[str, Any] | None = None
) -> None:
    """Check a charging-policy plugin against its contract on seeded random battery states.

    Each case is a robot's `BatteryStatus` on `conformance_floor` with two or three chargers
    (some taken by other robots): fixed ones (flat and idle; full at its charger; every charger
    taken) and 60 random ones from a fixed seed, asked `go_charge` (robots not at a charger) or
    `leave` and `takes_jobs` (robots at theirs). Every answer is checked against
    `CHARGING_RULES`; then a second fresh instance is given the same cases in the same order
    (a policy may keep state per robot) and must answer alike.

    Raises
    ------
    ConformanceError
        At the first broken rule, naming it and the case.
    """
    label = _label(factory)
    cases = _charging_cases()
    first = _instantiate(factory, options, ChargingPolicy, label, CHARGING_RULES)
    answers = [_ask_policy(first, name, status, label) for name, status in cases]
    second = _instantiate(factory, options, ChargingPolicy, label, CHARGING_RULES)
    for (name, status), want in zip(cases, answers, strict=True):
        got = _ask_policy(second, name, status, label)
        if got != want:
            _fail_charging(
                label,
                "deterministic",
                f"case {name!r}: the first instance answered {want!r}, a second fresh one "
                f"given the same cases in the same order {got!r}",
            )


def _ask_policy(
    policy: ChargingPolicy, name: str, status: BatteryStatus, label: str
) -> tuple[object, ...]:
    where = f"case {name!r} ({status!r})"
    copy = replace(status)
    try:
        if status.charger is None:
            answer: tuple[object, ...] = (policy.go_charge(status),)
        else:
            answer = (policy.leave(status), policy.takes_jobs(status))
    except Exception as exc:
        _fail_charging(label, "returns", f"{where}: raised {type(exc).__name__}: {exc}")
    if status != copy:
        _fail_charging(label, "no-mutation", f"{where}: the status was changed")
    if status.charger is None:
        choice = answer[0]
        if choice is not None and not isinstance(choice, str):
            _fail_charging(label, "returns", f"{where}: go_charge returned {choice!r}")
        if choice is not None and choice not in {c.name for c in status.chargers}:
            _fail_charging(label, "known-charger", f"{where}: go_charge named {choice!r}")
        if choice is None and status.charge <= 0.0 and not status.has_job:
            _fail_charging(label, "no-flat-battery", f"{where}: go_charge returned None")
    else:
        if not all(isinstance(a, bool) for a in answer):
            _fail_charging(label, "returns", f"{where}: leave, takes_jobs returned {answer!r}")
        if status.charge >= 1.0 and status.charging and answer[0] is not True:
            _fail_charging(label, "full-leaves", f"{where}: leave returned {answer[0]!r}")
    return answer


def _charging_cases() -> list[tuple[str, BatteryStatus]]:
    """Fixed cases first (the easy ways to get it wrong), then seeded random states."""
    rng = np.random.default_rng(20261127)
    floor = conformance_floor()
    spots = ((1.0, 1.0), (19.0, 9.0), (1.0, 9.0))

    def status(robot: str, x: float, y: float, charge: float, **kw: Any) -> BatteryStatus:
        kw.setdefault("chargers", tuple(Charger(f"c{i}", *p) for i, p in enumerate(spots[:2])))
        kw.setdefault("has_job", False)
        kw.setdefault("charger", None)
        kw.setdefault("charging", False)
        return BatteryStatus(
            robot, kw.pop("t", 100.0), x, y, charge, 200.0, **kw, drive_wh_per_m=0.05,
            print_w=60.0, idle_w=5.0, charge_w=200.0,
        )  # fmt: skip

    taken = tuple(Charger(f"c{i}", *p, occupant=f"other{i}") for i, p in enumerate(spots))
    cases = [
        ("flat and idle", status("r1", 2.0, 5.0, 0.0)),
        ("flat and idle, every charger taken", status("r1", 2.0, 5.0, 0.0, chargers=taken)),
        ("low with a job", status("r1", 17.0, 8.0, 0.05, has_job=True)),
        ("full at its charger", status("r1", *spots[0], 1.0, charger="c0", charging=True)),
        ("full, idle, next to a charger", status("r1", 1.5, 1.0, 1.0)),
    ]
    for n in range(60):
        x, y = _free_point(rng, floor)
        chargers = tuple(
            Charger(f"c{i}", *p, occupant=None if rng.random() < 0.6 else f"other{i}")
            for i, p in enumerate(spots[: int(rng.integers(1, 4))])
        )
        robot = f"r{int(rng.integers(1, 4))}"
        charge = round(float(rng.random()), 3)
        at = int(rng.integers(0, len(chargers))) if rng.random() < 0.4 else None
        if at is not None:
            chargers = tuple(
                replace(c, occupant=robot) if i == at else c for i, c in enumerate(chargers)
            )
        kwargs: dict[str, Any] = {
            "chargers": chargers,
            "has_job": at is None and bool(rng.random() < 0.4),
            "charger": None if at is None else chargers[at].name,
            "charging": at is not None and bool(rng.random() < 0.8),
            "t": 100.0 + 10.0 * n,
        }
        cases.append((f"random #{n}", status(robot, x, y, charge, **kwargs)))
    return cases


def _fail_charging(label: str, rule: str, detail: str) -> NoReturn:
    raise ConformanceError(label, rule, CHARGING_RULES, detail)


# --- shared ---------------------------------------------------------------------------------------


def _instantiate(
    factory: Callable[..., Any],
    options: Mapping[str, Any] | None,
    base: type,
    label: str,
    rules: Mapping[str, str],
) -> Any:
    opts = dict(options or {})
    try:
        plugin = factory(**opts)
    except Exception as exc:
        raise ConformanceError(
            label, "instantiate", rules, f"{label}(**{opts!r}) raised {type(exc).__name__}: {exc}"
        ) from exc
    if not isinstance(plugin, base):
        raise ConformanceError(
            label, "instantiate", rules, f"{label}(**{opts!r}) returned {plugin!r}"
        )
    return plugin


def _label(factory: Callable[..., Any]) -> str:
    module = getattr(factory, "__module__", None)
    name = getattr(factory, "__qualname__", None) or repr(factory)
    return f"{module}.{name}" if module else name


def _vec(v: Sequence[float] | np.ndarray) -> str:
    return f"({float(v[0]):.6g}, {float(v[1]):.6g})"


def _dist(p: np.ndarray, goal: tuple[float, float]) -> float:
    return float(math.hypot(p[0] - goal[0], p[1] - goal[1]))
