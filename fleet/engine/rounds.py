"""Bus rounds: every robot due at an instant is served by one round of the bus.

A robot's process asks for its command (`BusRounds.request`); the first request at an instant
schedules the round after every robot due then has asked. The round runs a dispatch requested at
this instant, brings the robots' jobs up to date, builds their observations from one snapshot,
exchanges them (and the auction's announcements) with the agents, and applies the commands: a
robot whose agent did not answer, or that has broken down, brakes, a command with a compute
latency waits its turn. Then come what the round brought besides: hand-backs, agents lost,
left or (re)joined, and bids.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping

import simpy

from fleet.bus import Exchange
from fleet.bus.exchange import BusEvent
from fleet.engine.dispatch import Dispatch
from fleet.engine.jobs import JobRecord
from fleet.engine.lifecycle import JobLifecycle
from fleet.engine.motion import RobotState
from fleet.engine.recorder import Recorder
from fleet.engine.sensing import PLAN_SPACING_S, Sensing, thin_plan
from fleet.plugins import Announcement, Command, ControlStatus, Observation
from fleet.plugins.robot import brake_input
from fleet.scenario import Latency

__all__ = ["BusRounds"]

log = logging.getLogger("fleet.engine")


class BusRounds:
    """Serves the robots' requests for commands, one bus round per instant."""

    def __init__(
        self,
        env: simpy.Environment,
        exchange: Exchange,
        latency: Latency,
        robots: Mapping[str, RobotState],
        jobs: list[JobRecord],
        recorder: Recorder,
        lifecycle: JobLifecycle,
        sensing: Sensing,
        dispatch: Dispatch,
    ) -> None:
        self.env = env
        self.exchange = exchange
        self.latency = latency
        self.robots = robots
        self.jobs = jobs
        self.recorder = recorder
        self.lifecycle = lifecycle
        self.sensing = sensing
        self.dispatch = dispatch
        #: Rounds run so far (the round number the exchange sends).
        self.count = 0
        self._pending: list[tuple[RobotState, simpy.Event]] = []

    def request(self, robot: RobotState) -> simpy.Event:
        """The event that brings `robot` its command from the bus round at this instant."""
        ev = self.env.event()
        self._pending.append((robot, ev))
        if len(self._pending) == 1:
            # Runs after every robot due at this instant has registered (later event id).
            self.env.timeout(0).callbacks.append(self._run)
        return ev

    def _run(self, _event: simpy.Event) -> None:
        """One bus round: observe the robots due now, exchange, apply what came back."""
        # A job released (or a robot freed) at this instant is assigned before the robots
        # observe, so a job released at t starts being served at t, not one period later.
        self.dispatch.run_pending()
        pending, self._pending = self._pending, []
        pending.sort(key=lambda p: p[0].id)
        t = self.env.now
        robots = [r for r, _ in pending]
        for robot in robots:
            self.lifecycle.prepare(robot, t)
        observations = self.sensing.observe(robots, t)
        self.count += 1
        announcements = self.dispatch.announcements(t)
        commands = self.exchange.round(self.count, t, observations, announcements)
        for (robot, ev), obs in zip(pending, observations, strict=True):
            ev.succeed(self.apply(robot, obs, commands.get(robot.id), t))
        self._after_round(t, announcements)

    def apply(
        self, robot: RobotState, obs: Observation | None, cmd: Command | None, t: float
    ) -> Command:
        """The command `robot` steps with from `t`: its controller's answer `cmd` to `obs`, or a
        brake (no answer, or broken down), queued with its compute latency; its plan, solve
        report and counters kept. `obs` None: nothing was asked (a pipelined round's first
        tick), so a missing answer is no fault."""
        if robot.broken:
            cmd = None  # broken down: braked to rest whatever its controller says
        elif cmd is None and obs is not None:
            self.recorder.stats["commands_missing"] += 1
        from_controller = cmd is not None
        if cmd is None:
            ax, ay = brake_input(robot.vx, robot.vy, robot.spec.period, robot.spec.a_max)
            cmd = Command(ax, ay, ControlStatus.ERROR)
            robot.plan = robot.thinned_plan = ()  # braking, not following its plan
        elif cmd.status is not ControlStatus.OK:
            self.recorder.stats[f"commands_{cmd.status.value}"] += 1
        if obs is not None and obs.goal is not None:
            robot.goal_commands += 1
            robot.goal_errors += cmd.status is ControlStatus.ERROR
        latency = self.latency
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
            robot.thinned_plan = thin_plan(cmd.plan, PLAN_SPACING_S)
            self.recorder.plan(robot.id, t, cmd.plan)
        if cmd.solve is not None:
            self.recorder.solves.append(cmd.solve)
        a = robot.spec.a_max
        if abs(cmd.ax) > a + 1e-12 or abs(cmd.ay) > a + 1e-12:
            self.recorder.stats["commands_clipped"] += 1
        job = robot.job
        if job is not None and job.started_s is None and obs is not None and obs.goal is not None:
            job.started_s = t
            self.recorder.event(t, "started", job.job.id, robot.id, job.job.station)
        return cmd

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
