"""Jobs: where they come from (scripted lists, Poisson arrivals) and what happened to each."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from fleet.errors import ScenarioError
from fleet.floor import Floor
from fleet.plugins import Job
from fleet.printing import CapSchedule, PrintTask
from fleet.scenario import JobsConfig, ScriptedJob

if TYPE_CHECKING:
    from fleet.printing.quality import QualityPrediction

__all__ = ["ATTEMPT_RESULTS", "Attempt", "JobRecord", "JobSource", "destination_stations"]

#: How an attempt at a job ended: delivered; handed back (the job was offered again); handed
#: back for the last time (the job failed: too many hand-backs); still under way at the run's end.
ATTEMPT_RESULTS = ("delivered", "handed_back", "failed", "unfinished")


@dataclass(frozen=True, slots=True)
class Attempt:
    """One robot's try at a job: from its assignment to how it ended.

    A job handed back (blocked, its robot's agent lost, a breakdown: any reason given to
    `Dispatch.hand_back`) has one attempt per robot that held it; the print of a handed-back
    attempt is scrapped and printed anew by the next one.
    """

    job: str
    #: 1 for the first attempt at the job, then 2, 3... (the ``attempt`` column of tasks.csv).
    number: int
    robot: str
    assigned_s: float
    #: When the robot set off for the job (None: it never did).
    started_s: float | None
    #: When its print started (None: it never did, or the job prints nothing).
    print_start_s: float | None
    #: When the attempt ended (None: unfinished at the run's end).
    ended_s: float | None
    #: One of `ATTEMPT_RESULTS`.
    result: str
    #: Why it was handed back (`Dispatch.hand_back`'s reason); None when it was not.
    reason: str | None
    #: The print tasks it printed, ``(kind, start_s, end_s)`` on the clock, cropped where the
    #: attempt ended (not cropped while unfinished: the print's plan goes on past the run).
    tasks: tuple[tuple[str, float, float], ...]

    def printed_s(self, now: float = math.inf) -> float:
        """Print time done in this attempt up to `now` (s): its tasks' lengths, cropped."""
        return float(sum(max(0.0, min(end, now) - start) for _, start, end in self.tasks))

    @property
    def scrapped(self) -> bool:
        """Handed back: whatever it printed is scrapped."""
        return self.result in ("handed_back", "failed")

    @property
    def scrapped_s(self) -> float:
        """Print time scrapped with the hand-back (s); 0 for an attempt not handed back."""
        return self.printed_s() if self.scrapped else 0.0


@dataclass(slots=True)
class JobRecord:
    """A job and the times of its life-cycle events (None until they happen)."""

    job: Job
    robot: str | None = None
    assigned_s: float | None = None
    started_s: float | None = None
    #: When the robot first came to rest at the destination (it may print there until done).
    arrived_s: float | None = None
    delivered_s: float | None = None
    #: What the robot prints on the way (times relative to the print's start).
    tasks: tuple[PrintTask, ...] = ()
    #: When printing started: the robot's first tick after assignment, or as soon as it could
    #: have braked to rest if it was moving (None: not yet, or nothing to print).
    print_start_s: float | None = None
    #: The print's speed caps on the simulation clock from `print_start_s`, cropped at delivery.
    caps: CapSchedule = field(default_factory=CapSchedule)
    #: Stations to pass through before the destination, ``(name, x, y)``, and whether to drive
    #: round them while the print lasts (`ScriptedJob.via`, `ScriptedJob.shuttle`).
    via: tuple[tuple[str, float, float], ...] = ()
    shuttle: bool = False
    #: Index into `via` of the next station to pass (``len(via)``: heading for the destination).
    leg: int = 0
    #: Angle (rad) the robot turned while printing this job (turns in place and course changes).
    turned_rad: float = 0.0
    #: The predicted quality of the printed part, once the print has finished.
    quality: QualityPrediction | None = None
    #: How often robots handed the job back (blocked, their agent failed, they broke down),
    #: and how many of these do not count towards `[jobs] max_handbacks` (breakdowns).
    handbacks: int = 0
    excused_handbacks: int = 0
    #: Robots that handed the job back as blocked.
    handed_back_by: set[str] = field(default_factory=set)
    #: Each robot that handed the job back as blocked, to the time until which it is not given
    #: the job again (`Dispatch.hand_back`): other robots are, it is not excluded from others.
    held_until: dict[str, float] = field(default_factory=dict)
    #: When and why the job was given up (too many hand-backs); None while it is not.
    failed_s: float | None = None
    failure: str | None = None
    #: The attempts that ended in a hand-back, in order (`end_attempt`); the attempt under way
    #: or delivered is the record's own fields (`all_attempts`).
    attempts: list[Attempt] = field(default_factory=list)

    def _attempt(self, end: float | None, result: str, reason: str | None) -> Attempt | None:
        """The attempt the record's fields describe, ending at `end` (None: no robot holds it)."""
        if self.robot is None or self.assigned_s is None:
            return None
        tasks: list[tuple[str, float, float]] = []
        start = self.print_start_s
        if start is not None:
            stop = math.inf if end is None else end
            for task in self.tasks:
                a, b = start + task.start_s, min(start + task.end_s, stop)
                if b > a:
                    tasks.append((task.kind, a, b))
        return Attempt(
            self.job.id,
            len(self.attempts) + 1,
            self.robot,
            float(self.assigned_s),
            None if self.started_s is None else float(self.started_s),
            None if start is None else float(start),
            None if end is None else float(end),
            result,
            reason,
            tuple(tasks),
        )

    def end_attempt(self, t: float, result: str, reason: str) -> Attempt | None:
        """Keep the attempt under way as ended at `t` by a hand-back (`result` "handed_back" or
        "failed", for `reason`); the caller then clears the record's fields for the next one."""
        attempt = self._attempt(t, result, reason)
        if attempt is not None:
            self.attempts.append(attempt)
        return attempt

    def all_attempts(self) -> list[Attempt]:
        """Every attempt at the job so far: the handed-back ones, then the one delivered or
        still under way ("unfinished")."""
        current = self._attempt(
            self.delivered_s,
            "unfinished" if self.delivered_s is None else "delivered",
            None,
        )
        return [*self.attempts, *([current] if current is not None else [])]

    @property
    def print_end_s(self) -> float | None:
        """When printing ends (None: not started, or nothing to print)."""
        if self.print_start_s is None or not self.tasks:
            return None
        return self.print_start_s + self.tasks[-1].end_s

    def printing_done(self, t: float) -> bool:
        """Whether nothing is left to print at time `t` (true for a job with no print)."""
        if not self.tasks:
            return True
        end = self.print_end_s
        return end is not None and t >= end - 1e-9

    def printing(self, t: float) -> bool:
        """Whether the print is under way at time `t`."""
        start = self.print_start_s
        return start is not None and start <= t and not self.printing_done(t)

    @property
    def late(self) -> bool:
        """Delivered after its due time."""
        due = self.job.due_s
        return due is not None and self.delivered_s is not None and self.delivered_s > due + 1e-9

    def held_off(self, t: float) -> set[str]:
        """The robots not to be given this job at time `t` (they handed it back lately)."""
        return {robot for robot, until in self.held_until.items() if t < until}

    @property
    def open(self) -> bool:
        """Released, not assigned, and not given up."""
        return self.robot is None and self.failed_s is None

    @property
    def lead_time_s(self) -> float | None:
        return None if self.delivered_s is None else self.delivered_s - self.job.released_s


def destination_stations(floor: Floor, config: JobsConfig, source: str) -> list[str]:
    """The stations jobs may go to: the configured ones, else every station that is not a depot."""
    known = {s.name for s in floor.spec.stations}
    if config.stations:
        for i, name in enumerate(config.stations):
            if name not in known:
                raise ScenarioError(
                    source,
                    f"jobs.stations[{i}]",
                    name,
                    f"no such station on {floor.source} (known: {', '.join(sorted(known))})",
                )
        return list(config.stations)
    names = [s.name for s in floor.spec.stations if s.kind not in ("depot", "charger")]
    if not names:
        raise ScenarioError(
            source,
            "jobs.stations",
            [],
            f"{floor.source} has no non-depot station; list destinations",
        )
    return names


class JobSource:
    """Yields ``(release_time_s, Job)`` in time order, drawing randomness only from `rng`."""

    def __init__(self, floor: Floor, config: JobsConfig, rng: np.random.Generator, source: str):
        self.floor = floor
        self.config = config
        self.rng = rng
        self.source = source
        self.stations = destination_stations(floor, config, source)
        #: Print tasks of the jobs yielded so far that have any, by job id (the engine pops them).
        self.print_tasks: dict[str, tuple[PrintTask, ...]] = {}
        #: The scripted entry of each scripted job yielded so far, by job id (for `via`).
        self.scripted: dict[str, ScriptedJob] = {}
        known = {s.name for s in floor.spec.stations}
        for i, item in enumerate(config.scripted):
            if item.station not in known:
                raise ScenarioError(
                    source,
                    f"jobs.scripted[{i}].station",
                    item.station,
                    f"no such station on {floor.source}",
                )
            for j, name in enumerate(item.via):
                if name not in known:
                    raise ScenarioError(
                        source,
                        f"jobs.scripted[{i}].via[{j}]",
                        name,
                        f"no such station on {floor.source}",
                    )

    def __iter__(self) -> Iterator[tuple[float, Job]]:
        if self.config.mode == "scripted":
            ordered = sorted(enumerate(self.config.scripted), key=lambda p: (p[1].at_s, p[0]))
            for n, (_, item) in enumerate(ordered, start=1):
                job = self._job(n, item.station, item.at_s, item.due_s, item.part)
                if item.tasks:
                    self.print_tasks[job.id] = item.tasks
                self.scripted[job.id] = item
                yield item.at_s, job
            return
        mean_gap = 3600.0 / self.config.rate_per_h
        t = 0.0
        n = 0
        while True:
            t += float(self.rng.exponential(mean_gap))
            until = self.config.release_until_s
            if until is not None and t > until:
                return
            n += 1
            station = self.stations[int(self.rng.integers(len(self.stations)))]
            due = None if self.config.due_in_s is None else t + self.config.due_in_s
            parts = self.config.parts
            # No draw without parts, so scenarios without them keep their random sequence.
            part = parts[int(self.rng.integers(len(parts)))] if parts else None
            yield t, self._job(n, station, t, due, part)

    def _job(
        self, n: int, station: str, t: float, due: float | None, part: str | None = None
    ) -> Job:
        s = self.floor.station(station)
        return Job(
            id=f"j{n:05d}", station=station, x=s.x, y=s.y, released_s=t, due_s=due, part=part
        )
