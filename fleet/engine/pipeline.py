"""Pipelined bus rounds (``[bus] lockstep = "pipelined"``): the agents compute while the world
steps.

In the strict lockstep (`fleet.engine.rounds.BusRounds`) a round at tick k sends the robots'
observations and waits for their commands, which drive the step from k to k+1: the engine idles
while the agents compute, and the agents idle while the engine steps. Here the commands answer
the observation of the *next* tick instead, and the round does not wait for them:

1. The commands sent in answer to the previous round are collected (`Exchange.collect`): they
   were computed for this tick, and each due robot steps with its own from now on (a robot
   without one, at the start of the run, after its agent was lost or when it has broken down,
   brakes, as in the strict lockstep).
2. Every due robot's state at its next tick follows exactly from its state now and that command
   (the double integrator). The world is moved there for a moment, and the robots observe it
   as at their next tick: position, velocity, the print caps of that step, a print starting then,
   the neighbours' predicted states and plans; then the world is moved back.
3. Those observations go out (`Exchange.send`) and the round ends; the robots step, and the
   agents compute while the engine integrates, records and judges the step.

So a command takes effect one tick after the state it answers was measured (one tick of
actuation latency), and it is right for that tick: the controller plans from the state the
robot will have when the command takes effect, with no change to any controller. What each agent
sees is fixed by the ticks, not by timing, so the same seed gives the same run with 0, 1 or 2
worker processes. A prediction is wrong only where the world changes at the next tick by
itself (a breakdown, a flat battery, a job released): the robot then observes that a tick late.
Robots of another period that are not due now are seen as they are (their state at their own
latest tick). The auction's bids come back with the commands, so jobs announced at one tick
are awarded at the next.

Compute latency (`Scenario.latency`) does not combine with this mode: the scenario is refused.
"""

from __future__ import annotations

from collections import defaultdict
from typing import Any

import simpy

from fleet.engine.motion import RobotState
from fleet.engine.rounds import BusRounds
from fleet.plugins import Announcement, Command, Observation

__all__ = ["PipelinedRounds"]


class PipelinedRounds(BusRounds):
    """Bus rounds whose commands take effect at the robots' next tick; the agents compute while
    the engine steps the world (see the module)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        #: Robot id -> the observation its agent is answering (of its next tick, sent in the
        #: open round) and, once collected, the answer (None: none came).
        self._asked: dict[str, tuple[Observation, Command | None]] = {}
        #: The open round's announcements (awarded when it is collected).
        self._announced: list[Announcement] = []

    def _run(self, _event: simpy.Event) -> None:
        """One pipelined round: collect the previous round's commands, apply them, observe the
        robots as at their next tick, send, and return without waiting."""
        self.dispatch.run_pending()
        pending, self._pending = self._pending, []
        pending.sort(key=lambda p: p[0].id)
        t = self.env.now
        if self.exchange.outstanding:
            commands = self.exchange.collect()
            for rid, (obs, _) in self._asked.items():
                self._asked[rid] = (obs, commands.get(rid))
            announced, self._announced = self._announced, []
            self._after_round(t, announced)
        robots = [r for r, _ in pending]
        in_force = []
        for robot in robots:
            obs, cmd = self._asked.pop(robot.id, (None, None))
            in_force.append(self.apply(robot, obs, cmd, t))
        observations = self._observe_next(robots, in_force, t)
        self.count += 1
        self._announced = self.dispatch.announcements(t)
        self.exchange.send(self.count, t, observations, self._announced)
        for obs in observations:
            self._asked[obs.robot] = (obs, None)
        for (_, ev), cmd in zip(pending, in_force, strict=True):
            ev.succeed(cmd)

    def _observe_next(
        self, robots: list[RobotState], in_force: list[Command], t: float
    ) -> list[Observation]:
        """The observations of `robots` at their next tick, each stepped with its command in
        force, in the order of `robots`; the robots' states are put back afterwards."""
        saved = [(r.x, r.y, r.vx, r.vy, r.tick) for r in robots]
        by_period: dict[float, list[RobotState]] = defaultdict(list)
        try:
            for r, cmd in zip(robots, in_force, strict=True):
                r.x, r.y, r.vx, r.vy = r.model.step(r.x, r.y, r.vx, r.vy, cmd.ax, cmd.ay)
                r.tick += 1
                by_period[r.spec.period].append(r)
            out: dict[str, Observation] = {}
            for period, group in sorted(by_period.items()):
                ahead = t + period
                for r in group:
                    self.lifecycle.prepare(r, ahead)
                for obs in self.sensing.observe(group, ahead):
                    out[obs.robot] = obs
        finally:
            for r, (x, y, vx, vy, tick) in zip(robots, saved, strict=True):
                r.x, r.y, r.vx, r.vy, r.tick = x, y, vx, vy, tick
        return [out[r.id] for r in robots]
