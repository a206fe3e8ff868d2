"""An agent's answers: each hosted robot's command, bids and handbacks for one OBSERVE.

The `Responder` calls the robots' controllers and never lets one break the host: a controller
that raises, or returns something that is not a valid `Command`, gets its robot a braking
command (`braking_command`) with `ControlStatus.ERROR`; a bid that fails or is not a finite
number of seconds >= 0 is dropped. Each robot's first trouble is logged with its traceback,
later ones only at debug level (they are counted in `AgentHost.stats`), so a failing plugin
cannot flood the log. A controller answering `ControlStatus.BLOCKED` while its robot has a job
hands that job back, once per robot and job.

With `threads` > 1 the robots' steps and bids run in a pool of threads, each through the plugin
gate (`fleet.plugins.gate`): plugin Python runs one call at a time, and the parts a plugin runs
outside the gate (the MPC's HiGHS solves) overlap. The answers are collected in the
observations' order, so the reply is the one a single thread gives.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

from fleet.bus.schema import command_to_wire
from fleet.plugins import (
    Announcement,
    Bid,
    Command,
    Controller,
    ControlStatus,
    Handback,
    Observation,
    in_gate,
)
from fleet.plugins.robot import brake_input

__all__ = ["Responder", "braking_command"]


def braking_command(controller: Controller, obs: Observation) -> Command:
    """The command substituted when `controller` failed: brake along the line of travel.

    `fleet.plugins.robot.brake_input` with ``dt`` and ``a_max`` from the robot's spec in the
    controller's context (set by `Controller.reset`): the acceleration points against the
    velocity, as hard as ``a_max`` allows on the faster axis (stopping within one step if
    that suffices), so the robot slows down on a straight line instead of veering (braking each
    axis on its own stops the slower axis first and bends the path). Zero acceleration if there
    is no context or spec.
    """
    spec = getattr(getattr(controller, "context", None), "spec", None)
    if spec is None or not spec.period > 0:
        return Command(0.0, 0.0, ControlStatus.ERROR)
    ax, ay = brake_input(obs.vx, obs.vy, spec.period, spec.a_max)
    # -0.0 would print oddly in logs and traces; a robot at rest gets exactly zero.
    return Command(ax + 0.0, ay + 0.0, ControlStatus.ERROR)


class Responder:
    """Answers OBSERVEs on behalf of the controllers of one host.

    Parameters
    ----------
    name:
        The host's name, for the logs.
    controllers:
        Robot id to its controller, already `reset`.
    stats:
        The host's counters (`AGENT_STATS`); calls that failed are counted into them.
    log:
        Where failures are logged.
    threads:
        Robots' steps computed at once (see the module); 1 computes them one after the other
        in the calling thread.
    """

    def __init__(
        self,
        name: str,
        controllers: Mapping[str, Controller],
        stats: dict[str, int],
        log: logging.Logger,
        threads: int = 1,
    ) -> None:
        self.name = name
        self.controllers = controllers
        self.stats = stats
        self.log = log
        self.threads = threads
        self._pool: ThreadPoolExecutor | None = None
        self._failed: set[str] = set()
        self._bid_failed: set[str] = set()
        self._handed_back: dict[str, str] = {}  # robot -> the job it last handed back

    def answer(
        self,
        tick: int,
        observations: Sequence[Observation],
        announcements: Sequence[Announcement],
        accepted: frozenset[str],
        between_robots: Callable[[], None],
    ) -> tuple[dict[str, dict], list[Bid], list[Handback]]:
        """The commands (wire form, by robot), bids and handbacks for one OBSERVE.

        Only robots in `accepted` are answered, each once; the others are counted and logged.
        `between_robots` is called after each robot's answer (the host heartbeats there).
        """
        commands: dict[str, dict] = {}
        bids: list[Bid] = []
        handbacks: list[Handback] = []
        ahead = self._in_threads(observations, announcements, accepted)
        for obs in observations:
            robot = obs.robot
            if robot not in accepted or robot in commands:
                self.stats["unknown_robots"] += 1
                self.log.warning(
                    "agent %s: tick %d: observation of robot %s, which %s",
                    self.name,
                    tick,
                    robot,
                    "appears twice" if robot in commands else "this host does not serve",
                )
                continue
            done = ahead.get(robot)
            (wire, status), answers = (
                done.result() if done is not None else self._step(robot, obs, announcements)
            )
            commands[robot] = wire
            job = obs.job
            last = self._handed_back.get(robot)
            if last is not None and last != job:
                del self._handed_back[robot]  # it has moved on: a new job may be handed back
                last = None
            if status is ControlStatus.BLOCKED and job is not None and last is None:
                handbacks.append(Handback(robot, job, "blocked"))
                self._handed_back[robot] = job
            bids.extend(bid for bid in answers if bid is not None)
            between_robots()
        return commands, bids, handbacks

    def close(self) -> None:
        """Let the pool's threads go (a later `answer` starts a new pool). Idempotent."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def _in_threads(
        self,
        observations: Sequence[Observation],
        announcements: Sequence[Announcement],
        accepted: frozenset[str],
    ) -> dict[str, Future]:
        """With threads, each accepted robot's step and bids started in the pool (its first
        observation only); without, nothing: `answer` computes them in turn."""
        if self.threads <= 1:
            return {}
        if self._pool is None:
            self._pool = ThreadPoolExecutor(self.threads, thread_name_prefix=f"{self.name}-step")
        out: dict[str, Future] = {}
        for obs in observations:
            if obs.robot in accepted and obs.robot not in out:
                out[obs.robot] = self._pool.submit(
                    in_gate, self._step, obs.robot, obs, announcements
                )
        return out

    def _step(
        self, robot: str, obs: Observation, announcements: Sequence[Announcement]
    ) -> tuple[tuple[dict, ControlStatus], list[Bid | None]]:
        """The robot's command (wire form and status) and its answer to each announcement."""
        return self._compute(robot, obs), [self._bid(robot, obs, a) for a in announcements]

    def _compute(self, robot: str, obs: Observation) -> tuple[dict, ControlStatus]:
        """The command's wire form and status; braking (ERROR) if the controller failed."""
        controller = self.controllers[robot]
        try:
            command = controller.compute(obs)
            return command_to_wire(command), command.status
        except Exception as exc:  # a plugin may raise anything; the fleet must keep running
            self.stats["controller_errors"] += 1
            first = robot not in self._failed
            self._failed.add(robot)
            # Once per robot with the traceback; later failures only at debug level (they are
            # counted in `stats` and in the run summary), so a failing plugin cannot flood the log.
            self.log.log(
                logging.WARNING if first else logging.DEBUG,
                "agent %s: robot %s: controller %s failed at tick %d (%s: %s); braking%s",
                self.name,
                robot,
                type(controller).__name__,
                obs.tick,
                type(exc).__name__,
                exc,
                " (further failures of this robot are logged at debug level)" if first else "",
                exc_info=first,
            )
            return command_to_wire(braking_command(controller, obs)), ControlStatus.ERROR

    def _bid(self, robot: str, obs: Observation, job: Announcement) -> Bid | None:
        """The robot's bid for `job`, or None (declined, failed or not a valid estimate)."""
        controller = self.controllers[robot]
        try:
            estimate: Any = controller.bid(obs, job)
        except Exception as exc:  # a plugin may raise anything; the fleet must keep running
            self.stats["bid_errors"] += 1
            self._bid_trouble(
                robot,
                f"controller {type(controller).__name__} failed to bid for job {job.job} at"
                f" tick {obs.tick} ({type(exc).__name__}: {exc}); no bid",
                exc_info=True,
            )
            return None
        if estimate is None:
            self.stats["bids_declined"] += 1
            return None
        try:
            value = float(estimate) if not isinstance(estimate, bool | str) else math.nan
        except (TypeError, ValueError, OverflowError):
            value = math.nan
        if not (math.isfinite(value) and value >= 0.0):
            self.stats["bids_dropped"] += 1
            self._bid_trouble(
                robot,
                f"controller {type(controller).__name__} bid {estimate!r} for job {job.job} at"
                f" tick {obs.tick}: a bid must be a finite number of seconds >= 0 (or None to"
                " decline); dropped",
            )
            return None
        return Bid(job.job, robot, value)

    def _bid_trouble(self, robot: str, what: str, exc_info: bool = False) -> None:
        # Once per robot at warning level; later ones at debug level (they are counted).
        first = robot not in self._bid_failed
        self._bid_failed.add(robot)
        self.log.log(
            logging.WARNING if first else logging.DEBUG,
            "agent %s: robot %s: %s%s",
            self.name,
            robot,
            what,
            " (further bid trouble of this robot is logged at debug level)" if first else "",
            exc_info=exc_info and first,
        )
