"""Queueing at stations: a robot with a job waits its turn short of a station, not round it.

Robots bound for one station used to crowd round it, each as close as the others let it: the
robot on it could then not leave, and the deadlock watch took a back-off or two to let it out
(fuzz s101-0767, s101-0884: five to seven robots round one station in a small room, idle
robots kept aside or short of home for 90 s, jobs done a minute late). Now a robot with a job
for a station stops short of it while another robot with a job for the same station is nearer
it (on it, or queueing closer): it heads for where it can brake to rest at once, and waits
there until it is the nearest. The robot ahead thus has a footprint of room round it to leave
by (and `WAIT_GAP_M` more, braking as the robot behind may), and the one that waited goes next.
The deadlock watch (`fleet.engine.sensing`) still watches the station for a robot waiting its
turn (`StationQueue.station_of`), and such a robot steps aside, as an idle one does, for any
robot stuck beside it that is not bound for the same station: it will not leave by itself.

Spots are where the robot would stop, so a run stays reproducible (no random draws).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import shapely

from fleet.engine.motion import RobotState
from fleet.floor import Floor

__all__ = ["StationQueue", "WAIT_GAP_M"]

#: Room (m) a robot waiting its turn leaves round the robot ahead of it, on top of the two radii
#: and one more footprint of the robot ahead: a way out past the one waiting.
WAIT_GAP_M = 0.5


class StationQueue:
    """Holds robots with a job short of a station another robot with a job there is nearer."""

    def __init__(
        self, floor: Floor, robots: Mapping[str, RobotState], enabled: bool = True
    ) -> None:
        self.floor = floor
        self.robots = robots
        #: `Scenario.station_queue`: off, every robot heads straight for its goal.
        self.enabled = enabled
        #: The free space shrunk by each robot radius: where a robot may wait (`_in_the_open`).
        self._open: dict[float, shapely.Geometry] = {}
        #: Robots waiting their turn: the station each waits for and the spot it waits at.
        self._waits: dict[str, tuple[tuple[float, float], tuple[float, float]]] = {}
        #: The robots in service with a job, by where it sends them (`snapshot`): the ones a
        #: robot may be behind, without a pass over the whole fleet for each robot.
        self._bound: dict[tuple[float, float], list[RobotState]] = {}

    def snapshot(self) -> None:
        """Note where each robot's job sends it, once per round before its robots' goals are
        asked for (`fleet.engine.sensing`): jobs change between rounds, not within one."""
        self._bound = {}
        if not self.enabled:
            return
        for o in self.robots.values():
            goal = o.goal
            if goal is not None and o.in_service:
                self._bound.setdefault(goal, []).append(o)

    def goal_of(
        self, robot: RobotState, goal: tuple[float, float] | None
    ) -> tuple[float, float] | None:
        """Where `robot`, heading for `goal`, heads now: the spot it waits its turn at while a
        robot ahead of it goes to the same station, else `goal`."""
        if (
            not self.enabled
            or goal is None
            or robot.job is None
            or goal != robot.goal
            or not self._behind(robot, goal)
        ):
            self._waits.pop(robot.id, None)
            return goal
        waits = self._waits.get(robot.id)
        if waits is None or waits[0] != goal:
            spot = self._stop_at(robot)
            if not self._in_the_open(spot, robot.spec.radius):
                return goal  # in a door or a narrow way: it drives on to where it may wait
            waits = (goal, spot)
            self._waits[robot.id] = waits
        return waits[1]

    def station_of(self, robot: RobotState) -> tuple[float, float] | None:
        """The station `robot` waits its turn for (None: it does not wait)."""
        waits = self._waits.get(robot.id)
        return None if waits is None or robot.aside is not None else waits[0]

    def _behind(self, robot: RobotState, station: tuple[float, float]) -> bool:
        """Whether another robot with a job for `station` is nearer it than `robot`, and `robot`
        is within its reach (where braking to rest leaves `WAIT_GAP_M` plus a footprint of room
        round the other, were it on the station); the robot with the smaller id first when both
        are as near."""
        sx, sy = station
        gap = math.hypot(robot.x - sx, robot.y - sy)
        brake = _travel(robot)
        for o in self._bound.get(station, ()):
            if o is robot or o.aside is not None:
                continue  # itself, or one heading elsewhere for now
            reach = robot.spec.radius + 3.0 * o.spec.radius + WAIT_GAP_M
            if gap > reach + brake:
                continue
            theirs = math.hypot(o.x - sx, o.y - sy)
            if (theirs, o.id) < (gap, robot.id):
                return True
        return False

    def _in_the_open(self, spot: tuple[float, float], radius: float) -> bool:
        """Whether `spot` has a radius of free space (the robots' centres' space) all round it:
        a robot waiting in a door or a way one robot wide shuts it (fuzz s21-0301 with the
        queue: robots waiting their turn in the door 2 m from the station held the way out)."""
        shrunk = self._open.get(radius)
        if shrunk is None:
            shrunk = self.floor.free_space.buffer(-radius)
            shapely.prepare(shrunk)
            self._open[radius] = shrunk
        return bool(shrunk.contains(shapely.Point(spot)))

    def _stop_at(self, robot: RobotState) -> tuple[float, float]:
        """Where `robot` comes to rest braking straight on (each axis at a_max), if that lies in
        the free space; else where it stands."""
        a = robot.spec.a_max
        x = robot.x + robot.vx * abs(robot.vx) / (2.0 * a)
        y = robot.y + robot.vy * abs(robot.vy) / (2.0 * a)
        if self.floor.is_free(x, y):
            return (x, y)
        return (robot.x, robot.y)


def _travel(robot: RobotState) -> float:
    """How far (m) `robot` goes braking to rest (each axis at a_max, along the line of travel)."""
    speed = math.hypot(robot.vx, robot.vy)
    return speed * speed / (2.0 * robot.spec.a_max)
