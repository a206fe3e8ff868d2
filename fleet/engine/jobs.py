"""Jobs: where they come from (scripted lists, Poisson arrivals) and what happened to each."""

from __future__ import annotations

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

__all__ = ["JobRecord", "JobSource", "destination_stations"]


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
    names = [s.name for s in floor.spec.stations if s.kind != "depot"]
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
