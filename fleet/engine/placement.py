"""Placement: where a run's robots start, and whether they can reach every job's stations.

Robots start on free spots around their start stations (ring by ring on a grid, clear of each
other); a job destination, via station or shuttle that some robot could never reach is refused
before the run, with the scenario entry named, instead of leaving the job assigned forever.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Iterator
from typing import Any

from fleet.errors import ScenarioError
from fleet.floor import Floor, Station
from fleet.scenario import Scenario, ScriptedJob

__all__ = ["Placement", "start_spacing"]

#: Gap (m) between the footprints of robots that start side by side.
START_GAP_M = 0.2
#: Of the step a robot may take unseen in one period, this much (m) fits in `START_GAP_M`.
UNSEEN_IN_GAP_M = 0.05


def start_spacing(scenario: Scenario) -> float:
    """How far apart (m) the robots' start spots are: two radii plus `START_GAP_M`, widened at
    coarse periods by the step a robot may take unseen in one period (``sqrt(2) a_max dt**2``)
    beyond `UNSEEN_IN_GAP_M`. Robots keep that step clear of their neighbours (the follower
    keeps radii + 0.1 m + the step); packed closer, a robot that left its start spot (to make
    way) could never drive back between the others: at a period of 1 s and a_max 0.68 the
    step is 0.96 m, and robots stood 0.6 to 2.8 m from home to the end of the run.
    """
    groups = scenario.robots
    unseen = max(math.sqrt(2.0) * g.a_max * g.period_s**2 for g in groups)
    return 2.0 * max(g.radius for g in groups) + START_GAP_M + max(0.0, unseen - UNSEEN_IN_GAP_M)


class Placement:
    """The start spots of a scenario's robots on its floor, and the reachability checks."""

    def __init__(self, scenario: Scenario, floor: Floor) -> None:
        self.scenario = scenario
        self.floor = floor

    def start_positions(self) -> list[tuple[float, float]]:
        """Distinct start positions around each group's start stations (cycled), clear of each
        other, in robot order."""
        stations = self.floor.stations
        depots = [s.name for s in self.floor.spec.stations if s.kind == "depot"]
        spacing = start_spacing(self.scenario)
        taken: dict[tuple[int, int], list[tuple[float, float]]] = defaultdict(list)
        spots: dict[str, Any] = {}
        out: list[tuple[float, float]] = []
        for g, group in enumerate(self.scenario.robots):
            where = "robots" if len(self.scenario.robots) == 1 else f"robots[{g}]"
            for i, name in enumerate(group.start):
                if name not in stations:
                    raise ScenarioError(
                        self.scenario.source,
                        f"{where}.start[{i}]",
                        name,
                        f"no such station on {self.floor.source} "
                        f"(known: {', '.join(sorted(stations))})",
                    )
            names = list(group.start) or depots or [self.floor.spec.stations[0].name]
            for i in range(group.count):
                name = names[i % len(names)]
                if name not in spots:
                    spots[name] = self._spots_around(stations[name], spacing)
                out.append(self._claim(spots[name], taken, spacing, name, where, group.count))
        return out

    def check_reachable(self, homes: list[tuple[float, float]], destinations: list[str]) -> None:
        """Every job destination must be reachable from every robot's start: a job no robot can
        reach would sit assigned forever."""
        starts = {self._part(*h) for h in homes}
        jobs = self.scenario.jobs
        if jobs.mode == "scripted":
            targets = []
            for i, j in enumerate(jobs.scripted):
                targets.append((f"jobs.scripted[{i}].station", j.station))
                targets += [(f"jobs.scripted[{i}].via[{k}]", name) for k, name in enumerate(j.via)]
                self._check_shuttle(i, j)
        else:
            targets = [("jobs.stations", name) for name in destinations]
        for field_name, name in targets:
            s = self.floor.station(name)
            part = self._part(s.x, s.y)
            if starts != {part}:
                raise ScenarioError(
                    self.scenario.source,
                    field_name,
                    name,
                    f"station {name!r} on {self.floor.source} cannot be reached from every "
                    "robot's start (the floor is split into unconnected parts)",
                )

    def _check_shuttle(self, i: int, job: ScriptedJob) -> None:
        """A shuttle needs a print to last for, and two via stations apart, or it never moves."""
        if not job.shuttle:
            return
        src = self.scenario.source
        if not (job.tasks or job.part):
            raise ScenarioError(
                src, f"jobs.scripted[{i}].shuttle", True, "a shuttle needs a part or print"
            )
        points = [self.floor.station(name) for name in job.via]
        apart = 2.0 * self.scenario.arrival_tolerance_m
        if all(math.hypot(p.x - points[0].x, p.y - points[0].y) <= apart for p in points):
            raise ScenarioError(
                src,
                f"jobs.scripted[{i}].via",
                list(job.via),
                "a shuttle needs at least two via stations at different places",
            )

    def _claim(
        self,
        spots: Iterator[tuple[float, float]],
        taken: dict[tuple[int, int], list[tuple[float, float]]],
        spacing: float,
        name: str,
        where: str,
        count: int,
    ) -> tuple[float, float]:
        """The next of `spots` at least `spacing` from every spot already taken."""
        for p in spots:
            cx, cy = int(p[0] // spacing), int(p[1] // spacing)
            cells = [(cx + dx, cy + dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)]
            if all(
                math.hypot(p[0] - q[0], p[1] - q[1]) >= spacing - 1e-9
                for c in cells
                for q in taken.get(c, ())
            ):
                taken[cx, cy].append(p)
                return p
        s = self.floor.station(name)
        raise ScenarioError(
            self.scenario.source,
            f"{where}.count",
            count,
            f"no free start position left near {name} ({s.x:g}, {s.y:g}); "
            "use fewer robots or more start stations",
        )

    def _part(self, x: float, y: float) -> int | None:
        """The connected part of the floor the point lies in; None off the free floor."""
        region = self.floor.locate(x, y)
        return None if region is None else int(self.floor.components[region])

    def _spots_around(self, station: Station, spacing: float) -> Iterator[tuple[float, float]]:
        """Free spots on a square grid around `station`, ring by ring, reachable from it."""
        components = self.floor.components
        home = self._part(station.x, station.y)
        for ring in range(0, 60):
            for dx in range(-ring, ring + 1):
                for dy in range(-ring, ring + 1):
                    if max(abs(dx), abs(dy)) != ring:
                        continue
                    p = (station.x + dx * spacing, station.y + dy * spacing)
                    region = self.floor.locate(*p)
                    if region is not None and components[region] == home:
                        yield p
