"""Dispatch: the engine's side of giving jobs to robots.

The dispatcher plugin chooses; this collaborator asks it when a job is released or a robot is
freed (assigners) or announces open jobs on the bus and lets it award them from the bids
(auctions), checks every assignment it makes before applying it, and takes jobs back from robots
that hand them back or lose their agent, offering them again until a job has been handed back
too often.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping
from collections.abc import Set as AbstractSet
from typing import Any

import simpy

from fleet.engine.jobs import JobRecord
from fleet.engine.motion import RobotState
from fleet.engine.recorder import Recorder
from fleet.floor import Floor
from fleet.paths import PathPlanner
from fleet.plugins import Announcement, Assignment, Bid, DispatchContext, RobotStatus
from fleet.printing import CapSchedule
from fleet.scenario import Scenario

__all__ = ["Dispatch", "HANDBACK_HOLD_S", "REANNOUNCE_S"]

log = logging.getLogger("fleet.engine")

#: How often (s) open jobs nobody won are announced again (auctions).
REANNOUNCE_S = 5.0
#: How long (s) a robot that handed a job back as blocked is not given it again, when the
#: scenario detects no deadlocks (otherwise `Scenario.deadlock_after_s`, the time over which
#: the block was judged).
HANDBACK_HOLD_S = 30.0
#: A job whose first stop is this close (m) to where a robot was blocked on its way to is
#: not given to that robot during the hold.
BLOCKED_SAME_M = 1e-6


class Dispatch:
    """Hands the run's open jobs to its robots through the scenario's dispatcher plugin.

    Parameters
    ----------
    dispatcher:
        The loaded plugin: an assigner (``assign``) or, when it ``announces``, an auctioneer
        (``award``).
    jobs:
        The run's job records, shared with the rest of the engine (released jobs are appended).
    """

    def __init__(
        self,
        env: simpy.Environment,
        scenario: Scenario,
        floor: Floor,
        planner: PathPlanner,
        robots: Mapping[str, RobotState],
        jobs: list[JobRecord],
        recorder: Recorder,
        dispatcher: Any,
    ) -> None:
        self.env = env
        self.scenario = scenario
        self.floor = floor
        self.planner = planner
        self.robots = robots
        self.jobs = jobs
        self.recorder = recorder
        self.dispatcher = dispatcher
        # Duck-typed dispatchers (not subclassing Dispatcher) are plain assigners.
        self._auction = bool(getattr(dispatcher, "announces", False))
        self._scheduled = False
        #: Jobs to announce at the next bus round (auctions), and when each was last announced.
        self._announce: set[str] = set()
        self._announced_s: dict[str, float] = {}
        #: Robots the charging policy keeps from new jobs (`fleet.engine.energy`).
        self.off_duty: set[str] = set()
        #: Robots that handed a job back as blocked: where they were blocked on their way to,
        #: and until when they are not given a job whose first stop is that place.
        self._blocked_to: dict[str, tuple[tuple[float, float], float]] = {}
        #: Jobs queued behind a busy robot's current one (auctions), to the robots that were
        #: idle when it was queued: a robot freed since may deliver it sooner (`_reoffer`).
        self._queued_idle: dict[str, frozenset[str]] = {}

    def held_off(self, rec: JobRecord) -> set[str]:
        """The robots not to be given `rec` now: those that handed it back lately, and those
        blocked lately on their way to its first stop. Several jobs to one station went round
        the robots stuck in front of it: each took the next job there, was blocked at once on
        the same way and handed it back in the same tick (fuzz seed 7, s7-0123)."""
        t = self.env.now
        first = (rec.via[0][1], rec.via[0][2]) if rec.via else (rec.job.x, rec.job.y)
        return rec.held_off(t) | {
            robot
            for robot, (where, until) in self._blocked_to.items()
            if t < until and math.dist(where, first) <= BLOCKED_SAME_M
        }

    def available(self, robot: RobotState) -> bool:
        """Whether `robot` may be given jobs: in service and not kept off duty to charge."""
        return robot.in_service and robot.id not in self.off_duty

    def request(self) -> None:
        """Ask for a dispatch: at this instant (assigners), or at the next bus round (auctions)."""
        if self._auction:
            # Contract net: open jobs are announced in the next bus round and awarded from bids.
            self._announce.update(rec.job.id for rec in self.jobs if rec.open)
            return
        if not self._scheduled:
            self._scheduled = True
            self.env.timeout(0).callbacks.append(self._run)

    def run_pending(self) -> None:
        """Run a dispatch requested at this instant now, ahead of its callback (which then
        finds nothing to do)."""
        self._run(None)  # a no-op unless a dispatch is scheduled

    def _run(self, _event: simpy.Event | None) -> None:
        """Ask the assigner to give the open jobs to the idle robots (the SimPy callback of
        `request`)."""
        if not self._scheduled:
            return  # already run at this instant, before a bus round
        self._scheduled = False
        open_jobs = [rec for rec in self.jobs if rec.open]
        idle = [r for r in self.robots.values() if r.job is None and self.available(r)]
        if not open_jobs or not idle:
            return
        if not self._apply_assignments(open_jobs, self.dispatcher.assign):
            return
        # The dispatcher paired a job with a robot that had handed that job back (it does not
        # know who did). That robot is excluded from that job only: ask again for each job
        # still open, oldest first and alone, without the robots that handed it back, so no
        # job waits while a robot that may take it stands idle.
        for rec in open_jobs:
            if not rec.open:
                continue
            held = self.held_off(rec)
            free = {
                r.id
                for r in self.robots.values()
                if r.job is None and self.available(r) and r.id not in held
            }
            if free:
                self._apply_assignments(
                    [rec], self.dispatcher.assign, exclude=set(self.robots) - free
                )

    def _statuses(self, exclude: AbstractSet[str] = frozenset()) -> list[RobotStatus]:
        """The robots as dispatchers see them (robots out of service or off duty are left out:
        they take no jobs, and so are those in `exclude`)."""
        return [
            RobotStatus(
                r.id, r.x, r.y, r.vx, r.vy, r.job is None, r.job and r.job.job.id, len(r.queue)
            )
            for r in self.robots.values()
            if self.available(r) and r.id not in exclude
        ]

    def announcements(self, t: float) -> list[Announcement]:
        """Open jobs to offer in this round: new or handed back ones, and every `REANNOUNCE_S`
        the ones nobody won."""
        if not self._auction:
            return []
        self._reoffer(t)
        out = []
        for rec in self.jobs:
            jid = rec.job.id
            if not rec.open:
                continue
            if jid not in self._announce and t < self._announced_s.get(jid, -math.inf) + (
                REANNOUNCE_S - 1e-9
            ):
                continue
            self._announced_s[jid] = t
            job = rec.job
            print_s = rec.tasks[-1].end_s if rec.tasks else 0.0
            out.append(Announcement(jid, job.x, job.y, print_s, job.released_s, job.due_s))
        self._announce.clear()
        self.recorder.stats["announcements"] += len(out)
        return out

    def _idle(self) -> set[str]:
        """The robots that may take a job and have none."""
        return {r.id for r in self.robots.values() if r.job is None and self.available(r)}

    def _reoffer(self, t: float) -> None:
        """Take back each job queued behind a busy robot's current one while a robot that was
        not idle when it was queued stands idle now and may take it (or any idle robot, while
        the holder is stalled), and announce it again: the lowest bid wins it anew, its
        holder's too unless stalled. Queued jobs were otherwise never offered again, and
        waited behind a robot that was blocked or slow while others stood idle (fuzz
        s21-0854, s21-0998)."""
        idle = self._idle()
        if not idle:
            return
        for robot in self.robots.values():
            for rec in list(robot.queue):
                jid = rec.job.id
                # A stalled holder (`RobotState.stalled`: no progress for a deadlock period)
                # gives its queued jobs up to any idle robot; it wins none while stalled.
                known = frozenset() if robot.stalled else self._queued_idle.get(jid, frozenset())
                if not idle - known - self.held_off(rec):
                    continue
                robot.queue.remove(rec)
                rec.robot = rec.assigned_s = None
                self._queued_idle.pop(jid, None)
                self._announce.add(jid)
                self.recorder.stats["jobs_reoffered"] += 1
                self.recorder.event(t, "reoffered", jid, robot.id, rec.job.station)

    def award(self, bids: list[Bid]) -> None:
        """Let the dispatcher award announced jobs from this round's bids."""
        open_jobs = {rec.job.id: rec for rec in self.jobs if rec.open}
        valid = [
            b
            for b in bids
            if b.job in open_jobs
            # A robot that gave a job back lately does not win it again yet.
            and b.robot not in self.held_off(open_jobs[b.job])
            and b.robot in self.robots
            and self.available(self.robots[b.robot])
            and not self.robots[b.robot].queue
            # A robot stalled on its way to its job takes on no more (`_reoffer`).
            and not (self.robots[b.robot].job is not None and self.robots[b.robot].stalled)
        ]
        self.recorder.stats["bids"] += len(bids)
        if not valid:
            return
        wanted = sorted({b.job for b in valid})
        self._apply_assignments(
            [open_jobs[j] for j in wanted],
            lambda jobs, statuses, context: self.dispatcher.award(valid, jobs, statuses, context),
            queue=True,
        )

    def _apply_assignments(
        self,
        open_jobs: list[JobRecord],
        choose: Callable[..., Any],
        queue: bool = False,
        exclude: AbstractSet[str] = frozenset(),
    ) -> list[tuple[JobRecord, str]]:
        """Ask `choose(jobs, statuses, context)` for assignments and apply the valid ones; with
        `queue`, a busy robot may take a job behind its current one. Returns the assignments
        declined because the robot had handed that job back."""
        by_id = {rec.job.id: rec for rec in open_jobs}
        context = DispatchContext(self.env.now, self.floor, self.planner)
        name = self.scenario.dispatcher.name
        try:
            assignments = list(
                choose([rec.job for rec in open_jobs], self._statuses(exclude), context)
            )
        except Exception:  # a plugin may raise anything; jobs stay open for the next try
            self.recorder.stats["dispatcher_errors"] += 1
            first = self.recorder.stats["dispatcher_errors"] == 1
            log.log(
                logging.WARNING if first else logging.DEBUG,
                "dispatcher %r raised at t = %.3f s; jobs stay open",
                name,
                self.env.now,
                exc_info=first,
            )
            return []
        taken_jobs: set[str] = set()
        declined: list[tuple[JobRecord, str]] = []
        for a in assignments:
            valid = isinstance(a, Assignment)
            rec = by_id.get(a.job) if valid else None
            robot = self.robots.get(a.robot) if valid else None
            # A robot takes a job when idle, or (auctions) behind its current one if none waits.
            busy = robot is not None and (
                not self.available(robot)
                or (robot.job is not None and (not queue or bool(robot.queue)))
            )
            if rec is None or robot is None or busy or a.job in taken_jobs:
                self.recorder.stats["assignments_rejected"] += 1
                log.warning("dispatcher %r made an invalid assignment %r; ignored", name, a)
                continue
            if robot.id in self.held_off(rec):
                # It gave this job back as blocked lately: the job goes to another robot.
                self.recorder.stats["assignments_declined"] += 1
                declined.append((rec, robot.id))
                continue
            taken_jobs.add(a.job)
            rec.robot, rec.assigned_s = robot.id, self.env.now
            self._announce.discard(rec.job.id)
            if robot.job is None:
                robot.job = rec
            else:
                robot.queue.append(rec)
                self._queued_idle[rec.job.id] = frozenset(self._idle())
            self.recorder.event(self.env.now, "assigned", rec.job.id, robot.id, rec.job.station)
        return declined

    def hand_back(
        self,
        robot: RobotState,
        rec: JobRecord,
        reason: str,
        blocked: bool = False,
        counted: bool = True,
    ) -> None:
        """Take `rec` off `robot` and offer it again (or give up on it after too many tries).

        A print under way is lost with the hand-back: the next robot prints the part anew. A
        robot that gave the job back because it is `blocked` is not given this job again for
        `Scenario.deadlock_after_s` (or `HANDBACK_HOLD_S`): what blocked it may have cleared by
        then, and it may take any other job at once. The job is offered again when that hold
        ends. A job handed back more than `[jobs] max_handbacks` times fails, so a job nobody
        can deliver does not loop; a hand-back that is not `counted` (a breakdown: no fault of
        the job's) does not count towards that.

        Any caller may hand a job back (the bus rounds for blocked robots and lost agents;
        breakdowns...): the attempt ends on the job's record (`JobRecord.attempts`) with
        `reason` as given, and its print is scrapped; `reason` is what attempts.csv and
        summary.json's ``handbacks.by_reason`` show, so keep it short and alike for alike
        causes (``"breakdown"``, ``"handed back: blocked"``).
        """
        t = self.env.now
        if rec is robot.job:
            robot.job = robot.queue.pop(0) if robot.queue else None
        elif rec in robot.queue:
            robot.queue.remove(rec)
        else:
            return
        # The caps the robot printed under stay on its record for the safety check.
        robot.past_caps.extend(rec.caps.window(-math.inf, t).pieces)
        # The attempt is kept, with what it printed (scrapped) and why it ended.
        counts = rec.handbacks - rec.excused_handbacks + counted
        failing = counted and counts > self.scenario.jobs.max_handbacks
        rec.end_attempt(t, "failed" if failing else "handed_back", reason)
        rec.robot = rec.assigned_s = rec.started_s = rec.arrived_s = rec.print_start_s = None
        rec.caps = CapSchedule()
        rec.leg = 0
        rec.turned_rad = 0.0
        rec.quality = None
        rec.handbacks += 1
        rec.excused_handbacks += not counted
        if blocked:
            rec.handed_back_by.add(robot.id)
            hold = self.scenario.deadlock_after_s or HANDBACK_HOLD_S
            rec.held_until[robot.id] = t + hold
            if robot.watched_goal is not None:
                self._blocked_to[robot.id] = (robot.watched_goal, t + hold)
            # Offer it again when the hold ends, in case nobody else took it meanwhile.
            self.env.timeout(hold).callbacks.append(lambda _event: self.request())
        self.recorder.stats["jobs_handed_back"] += 1
        self.recorder.event(t, "handed_back", rec.job.id, robot.id, reason)
        if failing:
            rec.failed_s, rec.failure = t, reason
            self.recorder.event(t, "failed", rec.job.id, robot.id, reason)
            log.warning("job %s failed at t = %.2f s: %s", rec.job.id, t, reason)
        # The robot is free (and the job open again unless it failed): offer the open jobs.
        self.request()
