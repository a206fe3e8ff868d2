"""The World: one SimPy environment owning the floor, the robots, the jobs, the clock and the
single seeded random generator of a run; the loop, and the wiring of its collaborators.

Each robot is a SimPy process with its own control period. At a tick it integrates the command
of the previous tick (the paper's double integrator), records its sample, checks arrival and asks
the bus for a new command. All robots due at the same instant are served by one bus round
(`fleet.engine.rounds`): the engine builds their observations from one consistent snapshot
(`fleet.engine.sensing`), the `Exchange` sends them to the agents (in this process over
``inproc://`` by default) and the commands come back. Dispatching (`fleet.engine.dispatch`) runs
in the engine whenever a job is released or a robot falls idle; `fleet.engine.lifecycle` takes
each job from its release to its delivery. The World builds these collaborators, each given what
it needs, starts the processes and, at the end, has the summary made (`fleet.engine.summary`).
"""

from __future__ import annotations

import logging
import tempfile
import time
from collections.abc import Callable, Generator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import simpy

from fleet.bus import AgentHost, Exchange
from fleet.engine.activity import Activity
from fleet.engine.agents import WorkerPool, build_controllers, load_run_floor, scenario_fingerprint
from fleet.engine.breakdowns import Breakdowns
from fleet.engine.collector import fewer_collections
from fleet.engine.dispatch import Dispatch
from fleet.engine.energy import Energy
from fleet.engine.jobs import JobRecord, JobSource
from fleet.engine.kpis import STATES_CSV, WIP_CSV, wip_rows
from fleet.engine.lifecycle import JobLifecycle, analyse_parts, quality_model
from fleet.engine.makeway import MakeWay
from fleet.engine.motion import RobotState, Turning, at_rest_near, build_robots
from fleet.engine.pipeline import PipelinedRounds
from fleet.engine.placement import Placement
from fleet.engine.recorder import Recorder, write_rows
from fleet.engine.rounds import BusRounds
from fleet.engine.safety import SafetyReport
from fleet.engine.sensing import Sensing
from fleet.engine.summary import (
    attempt_rows,
    cap_rows,
    check_safety,
    job_rows,
    summarise,
    task_rows,
)
from fleet.errors import FleetError, MessageError, PluginError
from fleet.floor import Floor
from fleet.paths import PathPlanner
from fleet.plugins import RobotSpec, SolveReport, load_charging_policy, load_dispatcher
from fleet.scenario import Scenario, check_fleet, check_lockstep, check_warmup, parse_latency

__all__ = ["World", "RunResult"]

log = logging.getLogger("fleet.engine")


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
        check_fleet(scenario, self.floor.spec.clearance)
        if (n := sum(g.count for g in scenario.robots)) > 1 and scenario.sensing_radius_m == 0:
            log.warning(
                "%s: %d robots with sensing_radius_m = 0 cannot see each other: nothing keeps "
                "them apart (collisions are counted, not avoided)",
                scenario.source,
                n,
            )
        check_warmup(scenario)  # --duration or code may have made the run shorter than it
        check_lockstep(scenario)  # code may have set a latency or the lockstep
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
        #: Time per robot per state (`fleet.engine.activity`), counted step by step.
        self.activity = Activity(self.robots, scenario.arrival_tolerance_m, scenario.warmup_s)
        self.jobs: list[JobRecord] = []
        self.job_source = JobSource(self.floor, scenario.jobs, self.rng, scenario.source)
        placement.check_reachable(homes, self.job_source.stations)
        #: Each part's print tasks, analysed from its G-code once per run.
        self.part_tasks = analyse_parts(scenario)
        self.quality = quality_model(scenario)
        self.dispatcher = self._plugin("dispatcher", load_dispatcher)
        self.workers: WorkerPool | None = None
        self.host: AgentHost | None = None
        self._tmpdir: tempfile.TemporaryDirectory | None = None
        self._open_bus(workers, remote, curve, agent_wait_s)

        # The loop's collaborators, each given what it needs.
        self.turning = Turning(self.env, self.recorder, self.planner_for)
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
        #: Batteries, chargers and the charging policy (`[battery]`); None: no batteries.
        self.energy: Energy | None = None
        if scenario.battery is not None:
            policy = self._plugin("charging", load_charging_policy)
            self.energy = Energy(
                self.env,
                scenario.battery,
                scenario.source,
                self.floor,
                self.robots,
                self.recorder,
                self.dispatch,
                policy,
                scenario.charging.name,
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
        make_way = MakeWay(
            self.floor,
            self.robots,
            self.recorder,
            self.planner_for,
            scenario.deadlock_after_s,
            scenario.arrival_tolerance_m,
            scenario.station_queue,
        )
        self.sensing = Sensing(scenario, self.robots, self.recorder, self.turning, make_way)
        rounds = PipelinedRounds if scenario.bus.lockstep == "pipelined" else BusRounds
        self.rounds = rounds(
            self.env,
            self.exchange,
            scenario.latency,
            self.robots,
            self.jobs,
            self.recorder,
            self.lifecycle,
            self.sensing,
            self.dispatch,
        )

        self.breakdowns = Breakdowns(self.env, scenario, self.robots, self.recorder, self.dispatch)

        self._ran = False
        #: The run's outcome once `run` has returned.
        self.result: RunResult | None = None

    # -- set-up ---------------------------------------------------------------------------------
    def _open_bus(self, workers: int, remote: bool, curve: Any, agent_wait_s: float) -> None:
        """Open the run's exchange and start its agents: in this process, in `workers` worker
        processes, or none when they are `remote`; return once every robot is hosted."""
        scenario = self.scenario
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
            max_message_bytes=bus.max_message_bytes,
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
                    self.exchange.address,
                    controllers,
                    name="local",
                    scenario=fingerprint,
                    max_message_bytes=bus.max_message_bytes,
                    threads=bus.threads,
                )
                self.exchange.add_local(self.host)
            self._wait_for_agents(agent_wait_s)
        except BaseException:
            self._close_bus()
            raise
        self.exchange.take_events()  # the agents joining before the start are no faults

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
    def _robot(self, robot: RobotState) -> Generator[simpy.Event, Any, None]:
        """The SimPy process of one robot: a step, its sample, arrival, and the next command."""
        env = self.env
        period = robot.spec.period
        tol = self.scenario.arrival_tolerance_m
        while True:
            if robot.tick > 0:
                robot.x, robot.y, robot.vx, robot.vy = robot.model.step(
                    robot.x, robot.y, robot.vx, robot.vy, robot.ax, robot.ay
                )
            self.recorder.sample(robot.id, env.now, robot.x, robot.y, robot.vx, robot.vy)
            if self.energy is not None:
                self.energy.tick(robot)
            if robot.turn_rate is not None:
                self.turning.follow_heading(robot)
            if robot.job is not None and at_rest_near(robot, robot.goal, tol):
                self.lifecycle.arrive(robot)
            command = yield self.rounds.request(robot)
            if self.scenario.latency is None:
                robot.ax, robot.ay = command.ax, command.ay
            else:
                # The bus round queued the command with its latency: blend what is in force.
                robot.ax, robot.ay = robot.step_input(env.now, period)
            if self.energy is not None:
                self.energy.hold(robot)  # a flat battery brakes
            self.activity.step(robot, env.now)
            robot.tick += 1
            yield env.timeout(period)

    # -- running --------------------------------------------------------------------------------
    def run(
        self,
        progress: Callable[[float], None] | None = None,
        stop: Callable[[], bool] | None = None,
    ) -> RunResult:
        """Simulate `scenario.duration_s` seconds; returns the summary and the safety report.

        `progress` is called with the simulated time about 200 times over the run. `stop` is
        asked at every control tick of the fastest robot; once it answers True the run ends
        there, between two steps, and the summary says ``"complete": false`` (how `fleet run`
        stops on Ctrl-C and still writes what it has).

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
        self.breakdowns.start()
        if progress is not None or stop is not None:
            self.env.process(self._watch(progress, stop, duration))
        try:
            with fewer_collections():
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

    def _watch(
        self,
        progress: Callable[[float], None] | None,
        stop: Callable[[], bool] | None,
        duration: float,
    ) -> Generator[simpy.Event, None, None]:
        """Report the simulated time about 200 times over the run (at most once per tick), and
        end the run at the first tick `stop` asks to."""
        tick = min(r.spec.period for r in self.robots.values())
        every = max(duration / 200.0, tick)
        next_report = 0.0
        while True:
            if stop is not None and stop():
                # Stops env.run where it is: no process is half-way through a step.
                ending = self.env.event()
                ending.callbacks.append(simpy.core.StopSimulation.callback)
                ending.succeed()
                return
            if progress is not None and self.env.now >= next_report:
                progress(self.env.now)
                next_report += every
            yield self.env.timeout(tick if stop is not None else every)

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
            bus_rounds=self.rounds.count,
            bus_stats=self.exchange.stats,
            activity=self.activity,
        )
        summary["breakdowns"] = self.breakdowns.summary(float(self.env.now))
        if self.energy is not None:
            summary["battery"] = self.energy.summary(float(self.env.now))
        return RunResult(summary, safety, list(self.jobs))

    def write(self, out: Path) -> None:
        """Write the run directory (see `fleet.engine.recorder`) after `run`."""
        if self.result is None:
            raise FleetError("write needs a finished run: call run() first")
        tasks = self.task_rows()
        self.recorder.write(
            out,
            self.result.summary,
            self.floor,
            self.result.safety.examples,
            cap_rows(tasks, self.scenario.print_caps),
            self.job_rows(),
            tasks,
            self.attempt_rows(),
        )
        end = min(float(self.env.now), self.scenario.duration_s)
        states = self.activity.rows(end)
        write_rows(out / STATES_CSV, ("robot", "state", "seconds", "share"), states)
        write_rows(out / WIP_CSV, ("t", "queue", "wip"), wip_rows(self.recorder.events))
        if self.energy is not None:
            self.energy.write(out)

    def task_rows(self) -> list[tuple[str, str, str, float, float, int]]:
        """Every print task that started, in every attempt, as ``tasks.csv`` rows (see
        `summary.task_rows`)."""
        return task_rows(self.jobs)

    def cap_rows(self) -> list[tuple[str, str, str, float, float, float, int]]:
        """Every print cap a robot was under, as ``caps.csv`` rows (see `summary.cap_rows`)."""
        return cap_rows(self.task_rows(), self.scenario.print_caps)

    def job_rows(self) -> list[dict[str, Any]]:
        """One row per job for ``jobs.csv`` (see `summary.job_rows`)."""
        return job_rows(self.jobs, self.env.now)

    def attempt_rows(self) -> list[dict[str, Any]]:
        """One row per attempt at a job for ``attempts.csv`` (see `summary.attempt_rows`)."""
        return attempt_rows(self.jobs, self.env.now)

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
