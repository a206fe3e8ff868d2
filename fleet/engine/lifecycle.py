"""The job lifecycle on the floor: release, print start, via stations, arrival, delivery and
the judging of each printed part.

Jobs are released as the `JobSource` yields them; a robot's print starts at its first tick after
the assignment (or as soon as it could have braked), it passes its via stations (round and
round, for a shuttle, while the print lasts), and a job is delivered once its robot is at rest
at the destination and the print is done; the quality model then judges the part from the
robot's recorded samples while it printed.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Generator
from typing import TYPE_CHECKING

import numpy as np
import simpy

from fleet.engine.dispatch import Dispatch
from fleet.engine.jobs import JobRecord, JobSource
from fleet.engine.motion import RobotState
from fleet.engine.recorder import Recorder
from fleet.errors import GcodeError, ScenarioError
from fleet.floor import Floor
from fleet.printing import PrintSchedule, PrintTask
from fleet.scenario import Scenario

if TYPE_CHECKING:
    from fleet.printing.quality import QualityModel

__all__ = ["JobLifecycle", "analyse_parts", "quality_model"]


def analyse_parts(scenario: Scenario) -> dict[str, tuple[PrintTask, ...]]:
    """Each part's print tasks, analysed from its G-code (once per run)."""
    sc = scenario
    if not sc.parts:
        return {}
    from fleet.printing.gcode import analyze  # parsing G-code is only needed with parts

    out = {}
    for name, path in sc.parts.items():
        try:
            analysis = analyze(path, min_task_s=sc.min_task_s, classification=sc.classify or None)
        except (GcodeError, ValueError) as exc:
            # Name the scenario's entry too: the user may not know which file it points to.
            raise ScenarioError(sc.source, f"parts.{name}", str(path), str(exc)) from None
        out[name] = analysis.print_tasks()
    return out


def quality_model(scenario: Scenario) -> QualityModel | None:
    """The scenario's print-quality model (None when no job prints anything)."""
    jobs = scenario.jobs
    if not (scenario.parts or any(j.tasks for j in jobs.scripted)):
        return None
    return scenario.quality.model()


class JobLifecycle:
    """What happens to each job once released, up to its delivery and the judging of its part.

    Parameters
    ----------
    jobs:
        The run's job records, shared with the rest of the engine: released jobs are appended.
    part_tasks:
        Each part's print tasks (`analyse_parts`).
    quality:
        The quality model judging printed parts (None: nothing prints).
    dispatch:
        Asked for a dispatch whenever a job is released or a robot is freed.
    """

    def __init__(
        self,
        env: simpy.Environment,
        scenario: Scenario,
        floor: Floor,
        job_source: JobSource,
        jobs: list[JobRecord],
        part_tasks: dict[str, tuple[PrintTask, ...]],
        quality: QualityModel | None,
        recorder: Recorder,
        dispatch: Dispatch,
    ) -> None:
        self.env = env
        self.scenario = scenario
        self.floor = floor
        self.job_source = job_source
        self.jobs = jobs
        self.part_tasks = part_tasks
        self.quality = quality
        self.recorder = recorder
        self.dispatch = dispatch

    def release(self) -> Generator[simpy.Event, None, None]:
        """The SimPy process releasing the jobs as the job source yields them, until the end."""
        for t, job in self.job_source:
            if t > self.scenario.duration_s:
                return
            # Not below 0: the clock is a sum of waits, so a job at the time of the one before
            # may be due a rounding error in the past (fuzz s73-0109: -8.9e-16 s, a crash).
            yield self.env.timeout(max(t - self.env.now, 0.0))
            tasks = self.job_source.print_tasks.pop(job.id, ())
            if job.part is not None:
                tasks = self.part_tasks[job.part]
            item = self.job_source.scripted.pop(job.id, None)
            via: tuple[tuple[str, float, float], ...] = ()
            if item is not None:
                stations = [self.floor.station(name) for name in item.via]
                via = tuple((s.name, s.x, s.y) for s in stations)
            rec = JobRecord(job, tasks=tasks, via=via, shuttle=item is not None and item.shuttle)
            self.jobs.append(rec)
            self.recorder.event(t, "released", job.id, station=job.station)
            self.dispatch.request()

    def prepare(self, robot: RobotState, t: float) -> None:
        """Bring `robot`'s job up to `t` before the robot observes: a shuttle whose print is done
        heads for its destination, and a print starts at the first tick after assignment."""
        rec = robot.job
        if rec is not None and rec.shuttle and rec.printing_done(t) and rec.leg < len(rec.via):
            rec.leg = len(rec.via)  # the print is done: on to the destination
        if rec is not None and rec.tasks and rec.print_start_s is None:
            self._start_print(robot, t)

    def arrive(self, robot: RobotState) -> None:
        """At rest at the current goal: pass a via station, or deliver once the print is done."""
        rec = robot.job
        assert rec is not None
        t = self.env.now
        if rec.leg < len(rec.via):
            name = rec.via[rec.leg][0]
            self.recorder.event(t, "passed", rec.job.id, robot.id, name)
            rec.leg += 1
            if rec.shuttle and rec.leg == len(rec.via) and not rec.printing_done(t):
                rec.leg = 0  # round again while the print lasts
            return
        if rec.arrived_s is None:
            rec.arrived_s = t
            self.recorder.event(t, "arrived", rec.job.id, robot.id, rec.job.station)
        if rec.print_start_s is None and rec.tasks:
            return  # the print starts at the next tick
        if not rec.printing_done(t):
            return  # printing standing still at the destination until the part is done
        self._deliver(robot)

    def _deliver(self, robot: RobotState) -> None:
        """Hand the job over: judge its part, end its caps, free the robot for its next job."""
        rec = robot.job
        assert rec is not None
        rec.delivered_s = self.env.now
        self._judge(rec)
        # Printing ends with the delivery: the caps after it no longer bind the robot.
        rec.caps = rec.caps.window(-math.inf, self.env.now)
        robot.past_caps.extend(rec.caps.pieces)
        robot.jobs_completed += 1
        robot.job = robot.queue.pop(0) if robot.queue else None
        self.recorder.event(self.env.now, "delivered", rec.job.id, robot.id, rec.job.station)
        self.dispatch.request()

    def _start_print(self, robot: RobotState, t: float) -> None:
        """Start the job's print at the robot's first tick after assignment, or, if it is moving,
        as soon as it could have braked to rest: the velocity of the step in progress is already
        fixed, so no controller could meet a cap that started earlier."""
        rec = robot.job
        assert rec is not None
        spec = robot.spec
        fastest = max(abs(robot.vx), abs(robot.vy))
        steps = math.ceil(fastest / (spec.a_max * spec.period) - 1e-9) if fastest > 0 else 0
        rec.print_start_s = t + steps * spec.period
        rec.caps = PrintSchedule(rec.tasks, self.scenario.print_caps).caps_from(rec.print_start_s)

    def _judge(self, rec: JobRecord) -> None:
        """Predict the quality of a finished print from the robot's samples while printing."""
        end = rec.print_end_s
        if rec.quality is not None or end is None or rec.robot is None or self.quality is None:
            return
        start = rec.print_start_s
        assert start is not None
        tr = self.recorder.trajectories[rec.robot]
        # Samples from the last one at or before the start to the first one at or after the end.
        lo = max(0, bisect.bisect_right(tr.t, start + 1e-9) - 1)
        hi = bisect.bisect_left(tr.t, end - 1e-9) + 1
        t = np.asarray(tr.t[lo:hi], dtype=float)
        xy = np.column_stack([tr.x[lo:hi], tr.y[lo:hi]]).astype(float).reshape(-1, 2)
        v = np.column_stack([tr.vx[lo:hi], tr.vy[lo:hi]]).astype(float).reshape(-1, 2)
        tasks = [PrintTask(k.kind, start + k.start_s, start + k.end_s) for k in rec.tasks]
        if self.scenario.quality.scope == "print":
            strictest = min((k.kind for k in tasks), key=self.quality.tolerance)
            tasks = [PrintTask(strictest, start, end)]
        rec.quality = self.quality.predict(tasks, t, xy, v, self.floor.spec.rough_areas)

    def judge_finished(self) -> None:
        """Judge the prints that finished but were not delivered by now (the end of the run)."""
        for rec in self.jobs:
            if rec.print_end_s is not None and rec.print_end_s <= self.env.now + 1e-9:
                self._judge(rec)
