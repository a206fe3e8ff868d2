"""The World: one SimPy environment owning the floor, the robots, the jobs, the clock and the
single seeded random generator of a run.

Each robot is a SimPy process with its own control period. At a tick it integrates the command
of the previous tick (the paper's double integrator), records its sample, checks arrival and asks
the bus for a new command. All robots due at the same instant are served by one bus round: the
engine builds their observations from one consistent snapshot, the `Exchange` sends them to the
agents (in this process over ``inproc://`` by default) and the commands come back. Dispatching
runs in the engine whenever a job is released or a robot falls idle.
"""

from __future__ import annotations

import bisect
import logging
import math
import tempfile
import time
from collections import defaultdict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import simpy

from fleet.bus import AgentHost, Exchange
from fleet.bus.exchange import BusEvent
from fleet.engine.agents import (
    WorkerPool,
    build_controllers,
    load_run_floor,
    scenario_fingerprint,
)
from fleet.engine.dispatch import Dispatch
from fleet.engine.jobs import JobRecord, JobSource
from fleet.engine.lifecycle import JobLifecycle, analyse_parts, quality_model
from fleet.engine.motion import RobotState, Turning, at_rest_near, build_robots
from fleet.engine.placement import Placement
from fleet.engine.recorder import Recorder
from fleet.engine.safety import SafetyReport
from fleet.engine.summary import (
    cap_rows,
    check_safety,
    job_rows,
    summarise,
    task_rows,
)
from fleet.errors import (
    FleetError,
    MessageError,
    PluginError,
)
from fleet.floor import Floor
from fleet.paths import PathPlanner
from fleet.plugins import (
    CAP_LOOKAHEAD_S,
    Announcement,
    Command,
    ControlStatus,
    Neighbour,
    Observation,
    RobotSpec,
    SolveReport,
    load_dispatcher,
)
from fleet.plugins.robot import brake_input
from fleet.scenario import Scenario, parse_latency

if TYPE_CHECKING:
    pass

__all__ = ["World", "RunResult"]

log = logging.getLogger("fleet.engine")

#: At most this many neighbours (the nearest) go into one observation.
MAX_NEIGHBOURS = 8
#: A robot that got no closer to its goal than this (m) over `Scenario.deadlock_after_s` has
#: made no progress.
PROGRESS_M = 0.25
#: Robots closer than the sum of their radii plus this (m) to a stalled robot may block it.
BLOCKING_GAP_M = 1.0
#: How long (s) a plan stays news: a neighbour whose latest plan ended longer ago than this is
#: shown without one (assume it stays where it is).
PLAN_STALE_S = 1.0
#: Neighbours see plans thinned to samples this far apart (s): each plan goes into up to
#: `MAX_NEIGHBOURS` observations, and between samples a robot at most 0.5 m/s^2 strays
#: a * dt^2 / 8 = 0.016 m from the chord.
PLAN_SPACING_S = 0.5


@dataclass
class RunResult:
    """What `World.run` returns: the summary (as written to summary.json) and the safety report."""

    summary: dict[str, Any]
    safety: SafetyReport
    jobs: list[JobRecord] = field(default_factory=list)


class World:
    """A whole simulated shop floor for one scenario.

    Parameters
    ----------
    scenario:
        The validated scenario.
    floor:
        A compiled floor; loaded from ``scenario.map`` when omitted.
    """

    def __init__(
        self,
        scenario: Scenario,
        floor: Floor | None = None,
        *,
        workers: int = 0,
        remote: bool = False,
        curve: Any = None,
        agent_wait_s: float = 120.0,
    ) -> None:
        if not isinstance(workers, int) or isinstance(workers, bool) or workers < 0:
            raise ValueError(f"workers = {workers!r}: must be an integer >= 0")
        if floor is not None and (workers or remote):
            # Agents elsewhere load the scenario's map file: they would not see this floor.
            raise ValueError("a World given its floor runs its agents in this process (workers=0)")
        if scenario.latency is not None:  # a Scenario built in code skipped the file's checks
            parse_latency(scenario.source, "scenario.latency", scenario.latency)
        self.scenario = scenario
        self.floor = load_run_floor(scenario, floor)
        self.rng = np.random.default_rng(scenario.seed)
        self.env = simpy.Environment()
        # One planner per distinct (v_max, a_max): references depend on both.
        self._planners: dict[tuple[float, float], PathPlanner] = {}
        placement = Placement(scenario, self.floor)
        homes = placement.start_positions()
        self.robots = build_robots(scenario, homes)
        #: The planner dispatchers get for travel-time estimates (the first group's limits).
        self.planner = self.planner_for(next(iter(self.robots.values())).spec)
        self.recorder = Recorder(list(self.robots))
        self.turning = Turning(self.env, self.recorder, self.planner_for)
        self.jobs: list[JobRecord] = []
        self.job_source = JobSource(self.floor, scenario.jobs, self.rng, scenario.source)
        placement.check_reachable(homes, self.job_source.stations)
        #: Each part's print tasks, analysed from its G-code once per run.
        self.part_tasks = analyse_parts(scenario)
        self.quality = quality_model(scenario)
        self.dispatcher = self._plugin("dispatcher", load_dispatcher)
        self.dispatch = Dispatch(
            self.env,
            scenario,
            self.floor,
            self.planner,
            self.robots,
            self.jobs,
            self.recorder,
            self.dispatcher,
        )
        self.lifecycle = JobLifecycle(
            self.env,
            scenario,
            self.floor,
            self.job_source,
            self.jobs,
            self.part_tasks,
            self.quality,
            self.recorder,
            self.dispatch,
        )

        self.workers: WorkerPool | None = None
        self.host: AgentHost | None = None
        self._tmpdir: tempfile.TemporaryDirectory | None = None
        fingerprint = scenario_fingerprint(scenario)
        address = scenario.bus_address
        if workers and (address is None or address.startswith("inproc://")):
            # Worker processes need a real socket: a private ipc path.
            self._tmpdir = tempfile.TemporaryDirectory(prefix="fleet-bus-")
            address = f"ipc://{self._tmpdir.name}/bus"
        bus = scenario.bus
        self.exchange = Exchange(
            address,
            timeout_s=bus.timeout_s,
            lost_after_s=bus.lost_after_s,
            scenario=fingerprint,
            **({"curve": curve} if curve is not None else {}),
        )
        try:
            if workers:
                # A controller whose options do not suit a robot fails here, with the scenario
                # named, instead of in a worker the engine would wait for in vain.
                firsts, seen = [], set()
                for rid, r in self.robots.items():
                    if r.spec not in seen:
                        seen.add(r.spec)
                        firsts.append(rid)
                build_controllers(scenario, self.floor, firsts, self.planner_for)
                self.workers = WorkerPool(scenario, self.exchange.address, workers)
            elif not remote:
                controllers = build_controllers(
                    scenario, self.floor, list(self.robots), self.planner_for
                )
                self.host = AgentHost(
                    self.exchange.address, controllers, name="local", scenario=fingerprint
                )
                self.exchange.add_local(self.host)
            self._wait_for_agents(agent_wait_s)
        except BaseException:
            self._close_bus()
            raise
        self.exchange.take_events()  # the agents joining before the start are no faults

        self._ran = False
        #: The run's outcome once `run` has returned.
        self.result: RunResult | None = None
        self._pending: list[tuple[RobotState, simpy.Event]] = []
        self._round = 0

    # -- set-up ---------------------------------------------------------------------------------
    def _wait_for_agents(self, wait_s: float) -> None:
        """Wait until every robot is hosted; with workers, give up as soon as one has died."""
        robots = list(self.robots)
        if self.workers is None:
            self.exchange.wait_for_agents(robots, wait_s)
            return
        deadline = time.monotonic() + wait_s
        while True:
            try:
                self.exchange.wait_for_agents(
                    robots, min(1.0, max(deadline - time.monotonic(), 0.01))
                )
                return
            except MessageError:
                dead = self.workers.dead()
                if dead:
                    raise FleetError(
                        "worker processes failed before the run started: "
                        + ", ".join(f"{name} (exit code {code})" for name, code in dead)
                        + "; their errors are printed above"
                    ) from None
                if time.monotonic() >= deadline:
                    raise

    def _plugin(self, kind: str, loader: Callable[..., Any]) -> Any:
        """Load the scenario's `kind` plugin; a failure names the scenario file and its table."""
        choice = getattr(self.scenario, kind)
        try:
            return loader(choice.name, choice.options)
        except PluginError as exc:
            raise PluginError(
                f"{self.scenario.source}: [{kind}] name = {choice.name!r}, "
                f"options = {choice.options!r}: {exc}"
            ) from None

    def planner_for(self, spec: RobotSpec) -> PathPlanner:
        """The shared path planner for robots with `spec`'s speed and acceleration limits."""
        key = (spec.v_max, spec.a_max)
        if key not in self._planners:
            self._planners[key] = PathPlanner(self.floor, v_max=spec.v_max, a_max=spec.a_max)
        return self._planners[key]

    # -- processes ------------------------------------------------------------------------------
    def _robot(self, robot: RobotState):
        env = self.env
        period = robot.spec.period
        tol = self.scenario.arrival_tolerance_m
        while True:
            if robot.tick > 0:
                robot.x, robot.y, robot.vx, robot.vy = robot.model.step(
                    robot.x, robot.y, robot.vx, robot.vy, robot.ax, robot.ay
                )
            self.recorder.sample(robot.id, env.now, robot.x, robot.y, robot.vx, robot.vy)
            if robot.turn_rate is not None:
                self.turning.follow_heading(robot)
            if robot.job is not None and at_rest_near(robot, robot.goal, tol):
                self.lifecycle.arrive(robot)
            command = yield self._request(robot)
            if self.scenario.latency is None:
                robot.ax, robot.ay = command.ax, command.ay
            else:
                # `_bus_round` queued the command with its latency: blend what is in force.
                robot.ax, robot.ay = robot.step_input(env.now, period)
            robot.tick += 1
            yield env.timeout(period)

    def _request(self, robot: RobotState) -> simpy.Event:
        ev = self.env.event()
        self._pending.append((robot, ev))
        if len(self._pending) == 1:
            # Runs after every robot due at this instant has registered (later event id).
            self.env.timeout(0).callbacks.append(self._bus_round)
        return ev

    def _bus_round(self, _event: simpy.Event) -> None:
        # A job released (or a robot freed) at this instant is assigned before the robots
        # observe, so a job released at t starts being served at t, not one period later.
        self.dispatch.run_pending()
        pending, self._pending = self._pending, []
        pending.sort(key=lambda p: p[0].id)
        t = self.env.now
        observations = self._observe([r for r, _ in pending], t)
        self._round += 1
        announcements = self.dispatch.announcements(t)
        commands = self.exchange.round(self._round, t, observations, announcements)
        latency = self.scenario.latency
        for (robot, ev), obs in zip(pending, observations, strict=True):
            cmd = commands.get(robot.id)
            from_controller = cmd is not None
            if cmd is None:
                self.recorder.stats["commands_missing"] += 1
                ax, ay = brake_input(robot.vx, robot.vy, robot.spec.period, robot.spec.a_max)
                cmd = Command(ax, ay, ControlStatus.ERROR)
                robot.plan = robot.thinned_plan = ()  # braking, not following its plan
            elif cmd.status is not ControlStatus.OK:
                self.recorder.stats[f"commands_{cmd.status.value}"] += 1
            if latency is not None:
                delay = 0.0  # commands the engine makes itself (brakes) apply at once
                if from_controller:
                    if latency != "measured":
                        delay = latency
                        robot.latencies.append(delay)
                    elif cmd.solve is not None:
                        delay = max(cmd.solve.step_s, 0.0)
                        robot.latencies.append(delay)
                    else:
                        robot.instant += 1  # reports no solve: counts as instant
                robot.delay(t, delay, cmd.ax, cmd.ay)
            if cmd.plan:
                robot.plan = cmd.plan  # an empty plan means the previous one still holds
                robot.thinned_plan = _thin(cmd.plan, PLAN_SPACING_S)
                self.recorder.plan(robot.id, t, cmd.plan)
            if cmd.solve is not None:
                self.recorder.solves.append(cmd.solve)
            a = robot.spec.a_max
            if abs(cmd.ax) > a + 1e-12 or abs(cmd.ay) > a + 1e-12:
                self.recorder.stats["commands_clipped"] += 1
            if robot.job is not None and robot.job.started_s is None and obs.goal is not None:
                robot.job.started_s = t
                self.recorder.event(t, "started", robot.job.job.id, robot.id, robot.job.job.station)
            ev.succeed(cmd)
        self._after_round(t, announcements)

    def _after_round(self, t: float, announcements: list[Announcement]) -> None:
        """Bids, hand-backs and agents coming and going, as the round brought them."""
        exchange = self.exchange
        for hb in exchange.handbacks:
            robot = self.robots.get(hb.robot)
            rec = next((r for r in self.jobs if r.job.id == hb.job), None)
            if robot is None or rec is None or rec.robot != robot.id:
                self.recorder.stats["handbacks_rejected"] += 1
                log.warning(
                    "agent handed back job %s of robot %s, not its own; ignored", hb.job, hb.robot
                )
                continue
            self.dispatch.hand_back(robot, rec, f"handed back: {hb.reason}", blocked=True)
        for event in exchange.take_events():
            self._bus_event(event)
        if announcements:
            self.dispatch.award(list(exchange.bids))

    def _bus_event(self, event: BusEvent) -> None:
        """An agent left, was lost or (re)joined: orphan its robots, or take them back."""
        t = self.env.now
        robots = [self.robots[r] for r in event.robots if r in self.robots]
        if event.kind in ("lost", "left"):
            self.recorder.faults["agents_lost" if event.kind == "lost" else "agents_left"] += 1
            log.warning(
                "t = %.2f s: agent %s %s (%s); braking robots %s",
                t,
                event.agent,
                event.kind,
                event.reason,
                [r.id for r in robots],
            )
            for robot in robots:
                if robot.faulted:
                    continue
                robot.faulted = True
                robot.plan = robot.thinned_plan = ()
                self.recorder.faults["robots_orphaned"] += 1
                self.recorder.event(t, "fault", "", robot.id, event.agent)
                for rec in [*robot.queue, *([robot.job] if robot.job else [])]:
                    self.dispatch.hand_back(robot, rec, f"agent {event.agent} {event.kind}")
        elif event.kind == "joined":
            for robot in robots:
                if robot.faulted:
                    robot.faulted = False
                    self.recorder.faults["robots_rejoined"] += 1
                    self.recorder.event(t, "rejoined", "", robot.id, event.agent)
            self.dispatch.request()

    def _observe(self, robots: list[RobotState], t: float) -> list[Observation]:
        radius = self.scenario.sensing_radius_m
        priority = self._priorities(t)
        near = (
            self._neighbours(robots, radius, t, priority)
            if radius > 0 and len(self.robots) > 1
            else {}
        )
        out = []
        tol = self.scenario.arrival_tolerance_m
        for r in robots:
            self.lifecycle.prepare(r, t)
            goal = r.goal
            if goal is None and r.return_home:
                goal = r.home
            self._watch_progress(r, goal, t, tol)
            if (
                r.turn_rate is not None
                and goal is not None
                and self.turning.turns_first(r, goal, t, tol)
            ):
                goal = (r.x, r.y)  # turning on the spot: hold here until the turn is done
            caps = r.job.caps if r.job is not None else None
            cap = None
            window: tuple[tuple[float, float, float], ...] = ()
            if caps:
                window = caps.window(t, t + CAP_LOOKAHEAD_S).pieces
                over = caps.cap_over(t, t + r.spec.period)
                cap = None if math.isinf(over) else over
            out.append(
                Observation(
                    robot=r.id,
                    tick=r.tick,
                    t=t,
                    x=r.x,
                    y=r.y,
                    vx=r.vx,
                    vy=r.vy,
                    goal=goal,
                    job=None if r.job is None else r.job.job.id,
                    speed_cap=cap,
                    neighbours=near.get(r.id, ()),
                    speed_caps=window,
                    print_end_s=None if r.job is None else r.job.print_end_s,
                    priority=priority[r.id],
                    blockers=r.blockers,
                    queued=len(r.queue),
                )
            )
        return out

    def _priorities(self, t: float) -> dict[str, int]:
        """Each robot's priority now: robots freed from a deadlock first, then robots with a job,
        then the rest; smaller ids first within each class (unique, higher goes first)."""
        n = len(self.robots)
        return {
            r.id: r.rank + (2 * n if t < r.boosted_until else 0) + (n if r.job is not None else 0)
            for r in self.robots.values()
        }

    def _watch_progress(
        self, r: RobotState, goal: tuple[float, float] | None, t: float, tol: float
    ) -> None:
        """Deadlock detection: a robot that has got no closer to its goal for
        `Scenario.deadlock_after_s` while other robots stand close is blocked by them; its
        observation names them (its controller routes round them) and its priority is raised."""
        after = self.scenario.deadlock_after_s
        if goal is None or after is None or r.faulted:
            r.watched_goal, r.blockers = None, ()
            return
        gap = math.hypot(goal[0] - r.x, goal[1] - r.y)
        if goal != r.watched_goal or gap <= tol or gap < r.best_gap - PROGRESS_M:
            r.watched_goal, r.best_gap, r.progress_s, r.blockers = goal, gap, t, ()
            return
        if t - r.progress_s < after - 1e-9:
            return
        # Robots standing on this one's goal are no deadlock: it waits its turn there.
        blockers = tuple(
            o.id
            for o in self.robots.values()
            if o is not r
            and math.hypot(o.x - r.x, o.y - r.y) <= r.spec.radius + o.spec.radius + BLOCKING_GAP_M
            and math.hypot(o.x - goal[0], o.y - goal[1]) > r.spec.radius + o.spec.radius
        )
        if blockers and not r.blockers:
            self.recorder.stats["deadlocks"] += 1
            r.boosted_until = t + after
            self.recorder.event(
                t, "deadlock", "" if r.job is None else r.job.job.id, r.id, " ".join(blockers)
            )
            log.info("t = %.2f s: robot %s stuck behind %s", t, r.id, list(blockers))
        r.blockers = blockers

    def _future_plan(self, r: RobotState, t: float) -> tuple[tuple[float, float, float], ...]:
        """The part of `r`'s latest plan from `t` on, starting with where it puts `r` at `t`;
        empty when it has none or it ended more than `PLAN_STALE_S` ago."""
        plan = r.thinned_plan
        if not plan or plan[-1][0] < t - PLAN_STALE_S:
            return ()
        i = bisect.bisect_right(plan, t, key=_sample_time)
        if i == len(plan):
            return ((t, plan[-1][1], plan[-1][2]),)
        if i == 0:
            return plan
        (t0, x0, y0), (t1, x1, y1) = plan[i - 1], plan[i]
        f = (t - t0) / (t1 - t0) if t1 > t0 else 1.0
        return ((t, x0 + f * (x1 - x0), y0 + f * (y1 - y0)), *plan[i:])

    def _neighbours(
        self, robots: list[RobotState], radius: float, t: float, priority: dict[str, int]
    ) -> dict[str, tuple]:
        cells: dict[tuple[int, int], list[RobotState]] = defaultdict(list)
        for r in self.robots.values():
            cells[(int(r.x // radius), int(r.y // radius))].append(r)
        out = {}
        plans: dict[str, tuple] = {}
        r2 = radius * radius
        for r in robots:
            cx, cy = int(r.x // radius), int(r.y // radius)
            found = []
            for dx in (-1, 0, 1):
                for dy in (-1, 0, 1):
                    for o in cells.get((cx + dx, cy + dy), ()):
                        d2 = (o.x - r.x) ** 2 + (o.y - r.y) ** 2
                        if o is not r and d2 <= r2:
                            found.append((d2, o.id, o))
            found.sort()
            near = []
            for _, _, o in found[:MAX_NEIGHBOURS]:
                if o.id not in plans:
                    plans[o.id] = self._future_plan(o, t)
                near.append(
                    Neighbour(
                        o.id, o.x, o.y, o.vx, o.vy, o.spec.radius, priority[o.id], plans[o.id]
                    )
                )
            out[r.id] = tuple(near)
        return out

    # -- jobs -----------------------------------------------------------------------------------
    # -- running --------------------------------------------------------------------------------
    def run(self, progress: Callable[[float], None] | None = None) -> RunResult:
        """Simulate `scenario.duration_s` seconds; returns the summary and the safety report.

        A World runs once: its bus is closed at the end. Build a new World for another run.
        """
        if self._ran:
            raise FleetError("this World has already run; build a new World for another run")
        self._ran = True
        duration = self.scenario.duration_s
        wall0 = time.perf_counter()
        self.env.process(self.lifecycle.release())
        for robot in self.robots.values():
            self.env.process(self._robot(robot))
        if progress is not None:
            self.env.process(self._progress(progress, duration))
        try:
            self.env.run(until=duration)
        finally:
            self._close_bus()
        wall = time.perf_counter() - wall0
        self.result = self._summarise(wall)
        return self.result

    def _close_bus(self) -> None:
        """Say BYE to the agents, let the workers go and remove the private socket's folder."""
        self.exchange.close()
        if self.host is not None:
            self.host.close()
        if self.workers is not None:
            self.workers.close()
        if self._tmpdir is not None:
            self._tmpdir.cleanup()
            self._tmpdir = None

    def _progress(self, progress: Callable[[float], None], duration: float):
        step = max(duration / 200.0, min(r.spec.period for r in self.robots.values()))
        while True:
            progress(self.env.now)
            yield self.env.timeout(step)

    def _summarise(self, wall_time: float) -> RunResult:
        safety = check_safety(
            self.floor, self.robots, self.recorder, self.scenario.enforce_print_caps
        )
        self.lifecycle.judge_finished()
        summary = summarise(
            self.scenario,
            self.floor,
            self.robots,
            self.jobs,
            self.recorder,
            safety,
            now=float(self.env.now),
            wall_time_s=wall_time,
            bus_rounds=self._round,
            bus_stats=self.exchange.stats,
        )
        return RunResult(summary, safety, list(self.jobs))

    def write(self, out: Path) -> None:
        """Write the run directory (see `fleet.engine.recorder`) after `run`."""
        if self.result is None:
            raise FleetError("write needs a finished run: call run() first")
        self.recorder.write(
            out,
            self.result.summary,
            self.floor,
            self.result.safety.examples,
            self.cap_rows(),
            self.job_rows(),
            self.task_rows(),
        )

    def task_rows(self) -> list[tuple[str, str, str, float, float]]:
        """Every print task that started, as ``tasks.csv`` rows (see `summary.task_rows`)."""
        return task_rows(self.jobs)

    def cap_rows(self) -> list[tuple[str, str, str, float, float, float]]:
        """Every print cap a robot was under, as ``caps.csv`` rows (see `summary.cap_rows`)."""
        return cap_rows(self.jobs, self.scenario.print_caps)

    def job_rows(self) -> list[dict[str, Any]]:
        """One row per job for ``jobs.csv`` (see `summary.job_rows`)."""
        return job_rows(self.jobs, self.env.now)

    @property
    def stats(self) -> dict[str, int]:
        """The engine's counters (summary.json's ``engine`` object), kept by the recorder."""
        return self.recorder.stats

    @property
    def solves(self) -> list[SolveReport]:
        """The solve reports controllers attached to their commands, kept by the recorder."""
        return self.recorder.solves

    @property
    def faults(self) -> dict[str, int]:
        """Faults seen on the bus (agents lost, left, robots orphaned, rejoined)."""
        return self.recorder.faults


def _thin(
    plan: tuple[tuple[float, float, float], ...], spacing: float
) -> tuple[tuple[float, float, float], ...]:
    """`plan` with samples at least `spacing` seconds apart (the first and last kept)."""
    if len(plan) <= 2:
        return plan
    out = [plan[0]]
    for sample in plan[1:-1]:
        if sample[0] - out[-1][0] >= spacing - 1e-9:
            out.append(sample)
    if plan[-1][0] - out[-1][0] < spacing / 2 and len(out) > 1:
        out.pop()  # keep the last sample, not one a moment before it
    out.append(plan[-1])
    return tuple(out)


def _sample_time(sample: tuple[float, float, float]) -> float:
    return sample[0]
