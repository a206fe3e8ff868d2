"""Breakdowns: robots fail at random, stop where they are and are repaired there.

With ``[breakdowns]`` (`BreakdownsConfig`) each robot runs for a time drawn with mean `mtbf_s`
(from the start, or from its last repair), breaks down, and is repaired after a time drawn with
mean `mttr_s`, again and again until the run ends.

Every robot draws from two random streams of its own: ``numpy.random.default_rng([seed, STREAM,
kind, index])`` with the run's seed, `FAILURES` or `REPAIRS`, and the robot's place in the
fleet. Its failure times thus depend on nothing else: not on the order the engine visits
robots, not on the repair times, not on the job arrivals (those come from the run's own
generator, which this never touches), so switching breakdowns on leaves every job arrival as
it was (common random numbers across the arms of a study), and a scenario without breakdowns
runs as it did before.

At a failure the robot is `RobotState.broken` (out of service) until repaired: its jobs, the
current one and any queued, are handed back with the reason ``"breakdown"`` and offered to the
other robots at once (the part it was printing is scrapped: the next robot prints it anew; such
hand-backs are no fault of the job's and do not count towards ``[jobs] max_handbacks``);
the bus round brakes it to rest whatever its controller says; dispatch and making way leave it
out; and the other robots see it with no plan and the highest priority, an obstacle that does
not move. Events ``breakdown`` and ``repaired`` go to events.csv; `Breakdowns.summary` is
summary.json's ``breakdowns`` object (availability, breakdowns, repair time, jobs handed back).
"""

from __future__ import annotations

import math
from collections.abc import Generator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import simpy

from fleet.engine.dispatch import Dispatch
from fleet.engine.motion import RobotState
from fleet.engine.recorder import Recorder
from fleet.errors import ScenarioError
from fleet.scenario import BreakdownsConfig, Scenario

__all__ = ["Breakdowns", "Outages", "STREAM", "FAILURES", "REPAIRS", "draw", "REASON"]

#: The stream number of breakdown draws (the run's seed alone seeds the job arrivals).
STREAM = 0x627264  # "brd"
#: The two kinds of draw, each a stream of its own per robot.
FAILURES = 0
REPAIRS = 1
#: The reason jobs taken off a broken-down robot are handed back with.
REASON = "breakdown"


def draw(rng: np.random.Generator, mean: float, kind: str, cv: float = 0.5) -> float:
    """One time (s) of distribution `kind` with mean `mean`: "exponential", "fixed", or
    "lognormal" with coefficient of variation `cv`."""
    if kind == "fixed":
        return mean
    if kind == "exponential":
        return float(rng.exponential(mean))
    if kind == "lognormal":
        sigma2 = math.log1p(cv * cv)
        return float(rng.lognormal(math.log(mean) - sigma2 / 2.0, math.sqrt(sigma2)))
    raise ValueError(f"unknown distribution {kind!r}")


@dataclass(slots=True)
class Outages:
    """One robot's breakdowns: when each began and ended (None: still under repair), and what
    they cost in jobs handed back and print time scrapped."""

    mtbf_s: float
    mttr_s: float
    spans: list[tuple[float, float | None]] = field(default_factory=list)
    jobs_handed_back: int = 0
    print_scrapped_s: float = 0.0

    def down_s(self, now: float) -> float:
        """Seconds broken down up to `now` (a repair under way counts up to `now`)."""
        return sum(min(now, now if end is None else end) - start for start, end in self.spans)


class Breakdowns:
    """Breaks robots down and repairs them, as the scenario's ``[breakdowns]`` says (nothing
    without it); `start` starts one SimPy process per robot that can break down."""

    def __init__(
        self,
        env: simpy.Environment,
        scenario: Scenario,
        robots: Mapping[str, RobotState],
        recorder: Recorder,
        dispatch: Dispatch,
    ) -> None:
        self.env = env
        self.config: BreakdownsConfig | None = scenario.breakdowns
        self.seed = scenario.seed
        self.robots = robots
        self.recorder = recorder
        self.dispatch = dispatch
        #: Each robot's breakdowns, by robot id (robots that cannot break down: none).
        self.outages: dict[str, Outages] = {}
        config = self.config
        if config is None:
            return
        if config.groups and len(config.groups) != len(scenario.robots):
            raise ScenarioError(
                scenario.source,
                "breakdowns.groups",
                list(config.groups),
                f"needs one entry per robot group ({len(scenario.robots)})",
            )
        ids = iter(robots)
        for g, group in enumerate(scenario.robots):
            mtbf, mttr = config.for_group(g)
            for _ in range(group.count):
                rid = next(ids)
                if mtbf > 0:
                    self.outages[rid] = Outages(mtbf, mttr)

    def start(self) -> None:
        """Start the failure and repair process of every robot that can break down."""
        index = {rid: i for i, rid in enumerate(self.robots)}
        for rid, outages in self.outages.items():
            i = index[rid]
            failures = np.random.default_rng([self.seed, STREAM, FAILURES, i])
            repairs = np.random.default_rng([self.seed, STREAM, REPAIRS, i])
            self.env.process(self._life(self.robots[rid], outages, failures, repairs))

    def _life(
        self,
        robot: RobotState,
        outages: Outages,
        failures: np.random.Generator,
        repairs: np.random.Generator,
    ) -> Generator[simpy.Event, None, None]:
        """One robot's process: run, break down, be repaired, over and over."""
        config = self.config
        assert config is not None
        while True:
            yield self.env.timeout(draw(failures, outages.mtbf_s, config.failures))
            self.fail(robot)
            yield self.env.timeout(draw(repairs, outages.mttr_s, config.repairs, config.repair_cv))
            self.repair(robot)

    def fail(self, robot: RobotState) -> None:
        """Break `robot` down now: out of service, its jobs handed back, its print scrapped."""
        t = self.env.now
        outages = self.outages[robot.id]
        outages.spans.append((t, None))
        robot.broken = True
        robot.aside = None
        robot.plan = robot.thinned_plan = ()  # braking where it is, not following a plan
        job = "" if robot.job is None else robot.job.job.id
        self.recorder.event(t, "breakdown", job, robot.id)
        for rec in [*robot.queue, *([robot.job] if robot.job is not None else [])]:
            start, end = rec.print_start_s, rec.print_end_s
            if start is not None and end is not None and start < t:
                outages.print_scrapped_s += min(t, end) - start
            outages.jobs_handed_back += 1
            self.dispatch.hand_back(robot, rec, REASON, counted=False)

    def repair(self, robot: RobotState) -> None:
        """End `robot`'s repair now: back in service, ready for jobs."""
        t = self.env.now
        outages = self.outages[robot.id]
        start, _ = outages.spans[-1]
        outages.spans[-1] = (start, t)
        robot.broken = False
        self.recorder.event(t, "repaired", "", robot.id)
        self.dispatch.request()

    def summary(self, now: float) -> dict[str, Any]:
        """summary.json's ``breakdowns`` object for a run that ended at `now`: per robot and for
        the fleet, availability (the share of the run in service: 1 - time broken down / run
        length), breakdowns, time under repair (a repair under way counts up to `now`), jobs
        handed back and print time scrapped by breakdowns."""
        per_robot = []
        for rid in self.robots:
            o = self.outages.get(rid)
            down = o.down_s(now) if o is not None else 0.0
            per_robot.append(
                {
                    "id": rid,
                    "availability": round(1.0 - down / now, 6) if now > 0 else 1.0,
                    "breakdowns": len(o.spans) if o is not None else 0,
                    "repair_s": round(down, 6),
                    "jobs_handed_back": o.jobs_handed_back if o is not None else 0,
                }
            )
        done = [
            end - start for o in self.outages.values() for start, end in o.spans if end is not None
        ]
        down_total = sum(p["repair_s"] for p in per_robot)
        robot_s = now * len(self.robots)
        config = self.config
        return {
            "configured": config is not None,
            "mtbf_s": None if config is None else config.mtbf_s,
            "mttr_s": None if config is None else config.mttr_s,
            "availability": round(1.0 - down_total / robot_s, 6) if robot_s > 0 else 1.0,
            "breakdowns": sum(p["breakdowns"] for p in per_robot),
            "repaired": len(done),
            "repair_s": round(down_total, 6),
            "mean_repair_s": round(float(np.mean(done)), 6) if done else None,
            "jobs_handed_back": sum(p["jobs_handed_back"] for p in per_robot),
            "print_scrapped_s": round(sum(o.print_scrapped_s for o in self.outages.values()), 6),
            "per_robot": per_robot,
        }
