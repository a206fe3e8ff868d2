"""Making way: a robot in the way steps aside for a stuck robot with a job.

An idle robot (no job, none queued) never leaves its spot by itself, and robots with jobs that
wait for each other (several crowding one station) never move either, so a robot whose route
runs through such a spot, or ends on it (a via station where an idle robot is parked), would
wait for good. When the deadlock watch (`fleet.engine.sensing`) finds, among the robots round a
stuck robot with a job, idle ones, stuck ones of lower priority not at their own goals, or
one printing on the stuck robot's goal whose part is done later than the stuck robot's,
`MakeWay` sends each to a spot off the stuck robot's route: the nearest of a few rings of
candidates round it that lies in the free space, keeps `AWAY_M` plus both radii from the route
and the stuck robot's goal, is clear of the other robots and of the spots others are sent to,
and is reached without closing in on the stuck robot. It holds the spot until the robot it
made way for has a new goal, is past (`PASSED_FACTOR`), is at rest at its goal (`ARRIVED_M`),
or lost its agent, for `HOLD_FACTOR` deadlock periods at most; then it goes on with its job,
or home as idle robots do (or stays, without `return_home`). A job assigned or taken away
meanwhile ends the wait. One that the robot it made way for names as a blocker (its route
changed) moves off the new route, or ends its wait.

A robot with no spot off the stuck robot's route (shut in by the stuck robot itself) has the
stuck robot back off its way instead (`MakeWay._back_off`). If that finds no spot either because
other robots box the two in (a station in a pocket with a crowd at its mouth), the robots
round it that may move for it (`yielders`: idle, already aside for either, or stuck on the way
to the same goal) are passed over in the search, and those in the two ways step aside too,
each off both ways; all of them or none.

Spots are found deterministically (no random draws), so a run stays reproducible.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import shapely
from shapely.geometry import LineString, Point

from fleet.engine.motion import RobotState, at_rest_near
from fleet.engine.queueing import StationQueue
from fleet.engine.recorder import Recorder
from fleet.errors import NoPathError
from fleet.floor import Floor
from fleet.paths import PathPlanner
from fleet.plugins import RobotSpec
from fleet.plugins.robot import stray_between

__all__ = [
    "MakeWay",
    "Spots",
    "Aside",
    "AWAY_M",
    "HOLD_FACTOR",
    "PASSED_FACTOR",
    "YIELD_M",
    "yielders",
]

log = logging.getLogger("fleet.engine")

#: Gap (m) kept between the robot aside's footprint and the stuck robot's, anywhere on the
#: stuck robot's route, on top of the two radii.
AWAY_M = 0.5
#: Gap (m) kept from every other robot, on top of the two radii.
OTHERS_M = 0.2
#: The gap (m) a controller keeps on top of the radii and the unseen step (the follower's
#: default margin): a way aside must keep it from the stuck robot, or it is not driven.
FOLLOWER_MARGIN_M = 0.1
#: A robot let out to a spot nearby, or one made way for, is at its goal this close (m): past.
ARRIVED_M = 0.1
#: The rings of candidate spots, in multiples of (both radii + `AWAY_M`) from the robot.
RINGS = (1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0)
#: Candidate directions on each ring.
DIRECTIONS = 24
#: How far along its route (m) a stuck robot with nobody close looks for idle robots in the way.
LOOK_AHEAD_M = 4.0
#: A robot holds its spot aside for at most this many deadlock periods.
HOLD_FACTOR = 4.0
#: m: a robot this much further off than the gap on an axis is out of reach for sure (the
#: distances measured round by far less).
_SURE_M = 1e-6
#: Robots within this distance (m) of a stuck robot that cannot back off from a blocker may be
#: sent aside for it to back off (`yielders`).
YIELD_M = 2.0 * LOOK_AHEAD_M
#: The robot made way for is past once it is this many times (both radii + `AWAY_M`) closer to
#: its goal than when it stuck, and as far from the spot aside.
PASSED_FACTOR = 2.0


@dataclass(frozen=True, slots=True)
class Aside:
    """Where a robot waits off another's route, for whom, and until when at most."""

    spot: tuple[float, float]
    #: The robot it made way for, that robot's goal then (once it changes, the way is free) and
    #: its distance to it (once it is `passed_m` closer and as far from the spot, it is past).
    made_way_for: str
    their_goal: tuple[float, float]
    their_gap: float
    passed_m: float
    until: float
    #: The job the robot had when it stepped aside (None: idle); another one ends the wait.
    job: str | None = None


def kept_gap(robot: RobotState, other: RobotState | None = None) -> float:
    """The gap (m) `robot` keeps from neighbour `other` (None: one like itself) on top of the
    two radii: the follower's margin and the step the neighbour may take unseen between two of
    `robot`'s looks (`fleet.plugins.robot.stray_between`: by its own limits, over the longer of
    the two periods)."""
    spec = robot.spec
    return FOLLOWER_MARGIN_M + stray_between(spec, spec if other is None else other.spec)


class Spots:
    """The geometry of making way: a stuck robot's route, a robot's way to a spot, and spots
    off a route that a robot can reach without closing in on the others."""

    def __init__(
        self,
        floor: Floor,
        robots: Mapping[str, RobotState],
        planner_for: Callable[[RobotSpec], PathPlanner],
    ) -> None:
        self.floor = floor
        self.robots = robots
        self.planner_for = planner_for

    def _route(self, stuck: RobotState, goal: tuple[float, float]) -> shapely.Geometry:
        """The stuck robot's route as the path layer plans it: to its goal and, with a job,
        on through its later via stations to the destination (robots ignored)."""
        points = [(stuck.x, stuck.y), goal]
        rec = stuck.job
        if rec is not None and stuck.goal == goal:
            points += [(x, y) for _, x, y in rec.via[rec.leg + 1 :]]
            if rec.leg < len(rec.via):
                points.append((rec.job.x, rec.job.y))
        planner = self.planner_for(stuck.spec)
        lines = []
        for a, b in zip(points, points[1:], strict=False):
            if math.dist(a, b) < 1e-9:
                continue
            try:
                lines.append(planner.path(a, b).waypoints)
            except NoPathError:
                lines.append((a, b))
        if not lines:
            return Point(goal)
        return shapely.union_all([LineString(w) for w in lines] + [Point(goal)])

    def _spot(
        self,
        robot: RobotState,
        stuck: RobotState,
        route: shapely.Geometry,
        past: bool = False,
        ignore: frozenset[str] = frozenset(),
        avoid: Sequence[tuple[float, float, float]] = (),
    ) -> tuple[float, float] | None:
        """The nearest spot on `RINGS` round `robot` it can drive to that is off `route` and
        clear of the other robots (but those in `ignore`) and of the spots (x, y, radius) in
        `avoid`; on one ring, the one furthest from the route. With `past`, the way there may
        pass close to `stuck` (which backs off first)."""
        free = self.floor.free_space
        # Off the route by more than the stuck robot keeps from a neighbour, or it could not pass.
        kept = kept_gap(stuck, robot)
        away = robot.spec.radius + stuck.spec.radius + max(AWAY_M, kept + OTHERS_M)
        others = [
            (o.x, o.y, robot.spec.radius + o.spec.radius + OTHERS_M)
            for o in self.robots.values()
            if o is not robot and o is not stuck and o.id not in ignore
        ] + [(x, y, robot.spec.radius + r + OTHERS_M) for x, y, r in avoid]
        # Clear of the spots others are on their way to, too (fuzz s31-0698: r03, the parked
        # robot let out of a ring, was sent to a spot 0.66 m from the one r07 had just been
        # sent to; it never got there, and r01, backed off for it, waited out the hold).
        others += [
            (*o.aside.spot, robot.spec.radius + o.spec.radius + OTHERS_M)
            for o in self.robots.values()
            if o.aside is not None and o is not robot and o is not stuck and o.id not in ignore
        ]
        # Each candidate is compared only with the robots within its gap on both axes (a
        # hair more: `_SURE_M`); those further off on either axis cannot be within it.
        table = np.array(others, dtype=float).reshape(-1, 3)
        ox, oy, od = table[:, 0], table[:, 1], table[:, 2]
        for ring in RINGS:
            best, best_gap = None, -math.inf
            for k in range(DIRECTIONS):
                angle = 2.0 * math.pi * k / DIRECTIONS
                x = robot.x + ring * away * math.cos(angle)
                y = robot.y + ring * away * math.sin(angle)
                spot = Point(x, y)
                if not free.covers(spot):
                    continue
                gap = route.distance(spot)
                if gap < away or gap <= best_gap:
                    continue
                close = np.flatnonzero(
                    (np.abs(ox - x) < od + _SURE_M) & (np.abs(oy - y) < od + _SURE_M)
                ).tolist()
                if any(
                    math.hypot(x - others[i][0], y - others[i][1]) < others[i][2] for i in close
                ):
                    continue
                if not self._reachable(robot, stuck, (x, y), past, ignore):
                    continue
                best, best_gap = (x, y), gap
            if best is not None:
                return best
        return None

    def _way(self, robot: RobotState, spot: tuple[float, float]) -> LineString | None:
        """`robot`'s way to `spot`: the path layer's path, the one its controller tracks; None
        without one. Not the straight segment where that is free: zone limits hold per axis,
        so the quickest way into a slow zone may run diagonally, off to one side and back
        (fuzz s113-0449: a spot 1.42 m north, its path 0.58 m from the stuck robot east)."""
        try:
            return LineString(self.planner_for(robot.spec).path((robot.x, robot.y), spot).waypoints)
        except NoPathError:
            return None

    def _reachable(
        self,
        robot: RobotState,
        stuck: RobotState,
        spot: tuple[float, float],
        past: bool = False,
        ignore: frozenset[str] = frozenset(),
    ) -> bool:
        """Whether `robot` can drive to `spot` (`_way`) without coming within reach of `stuck`
        or any other robot but those in `ignore` (with `past`, it may pass `stuck`, which backs
        off first)."""
        leg = self._way(robot, spot)
        if leg is None:
            return False
        # Robots stuck together may already stand closer than that: then never any closer.
        # Besides the gap, a robot keeps clear of the step a neighbour may take unseen within
        # one period (a_max*dt**2 per axis): a way that passes closer is one its controller
        # refuses to drive, and the robot would hold where it stands for good.
        # The same holds for every other robot on the way (a robot packed in among others at a
        # depot was sent to a spot past one of them, 0.54 m from it, and never moved).
        spec = robot.spec
        x0, y0, x1, y1 = leg.bounds
        for o in self.robots.values():
            if o is robot or (past and o is stuck) or o.id in ignore:
                continue
            gap = max(OTHERS_M, kept_gap(robot, o))
            # Robots further off the way's bounding box on some axis than the gap (and a hair:
            # `_SURE_M`) cannot be within it: they are passed over without measuring.
            far = spec.radius + o.spec.radius + gap + _SURE_M
            if o.x < x0 - far or o.x > x1 + far or o.y < y0 - far or o.y > y1 + far:
                continue
            there = Point(o.x, o.y)
            now = there.distance(Point(robot.x, robot.y))
            reach = min(spec.radius + o.spec.radius + gap, now)
            if leg.distance(there) < reach - 1e-6:
                return False
        return True


class MakeWay(Spots):
    """Sends robots that block a stuck one for good to spots off its route, and back."""

    def __init__(
        self,
        floor: Floor,
        robots: Mapping[str, RobotState],
        recorder: Recorder,
        planner_for: Callable[[RobotSpec], PathPlanner],
        deadlock_after_s: float | None,
        arrival_m: float = ARRIVED_M,
        station_queue: bool = True,
    ) -> None:
        super().__init__(floor, robots, planner_for)
        self.recorder = recorder
        self.retry_s = deadlock_after_s or 0.0
        #: A robot made way for is at its goal this close (m): `ARRIVED_M`, or the run's own
        #: arrival tolerance if tighter (one that has not arrived still needs the way).
        self.arrival_m = min(ARRIVED_M, arrival_m)
        self.hold_s = HOLD_FACTOR * self.retry_s
        #: When each (robot, stuck robot) pair was last looked at: a stuck robot asks at every tick,
        #: and a search that found no spot, or a spot that did not help, waits a deadlock
        #: period before the next.
        self._asked: dict[tuple[str, str], float] = {}
        #: When each stuck robot last looked for idle robots further along its route, and the
        #: ones it found.
        self._looked: dict[str, tuple[float, tuple[str, ...]]] = {}
        #: What `idle_on_route` last found for each robot, and where everyone stood then.
        self._idle_seen: dict[str, tuple[tuple, tuple[str, ...]]] = {}
        #: Robots with a job wait their turn short of a station (`fleet.engine.queueing`).
        self.queue = StationQueue(floor, robots, station_queue)

    def goal_of(self, robot: RobotState, t: float) -> tuple[float, float] | None:
        """Where `robot` heads now: nowhere while broken down, its spot aside while it still
        holds one, else where its job sends it, else its charger (`RobotState.charger_at`), else
        home (or nowhere, idle without `return_home`)."""
        if robot.broken:
            return None  # broken down: it stays where it stopped
        aside = robot.aside
        if aside is not None and not self._still_needed(robot, aside, t):
            robot.aside = aside = None
        if aside is not None and self._in_their_way(robot, aside, t):
            aside = self._move_on(robot, aside, t)
        if aside is not None:
            return aside.spot
        return self.queue.goal_of(robot, self._own_goal(robot))

    def _in_their_way(self, robot: RobotState, aside: Aside, t: float) -> bool:
        """Whether `robot`, aside, is named a blocker by the robot it made way for (its route
        changed since: it backed off, or drove round), at most once a deadlock period."""
        other = self.robots[aside.made_way_for]
        return robot.id in other.blockers and t >= (
            self._asked.get((robot.id, other.id), -math.inf) + self.retry_s
        )

    def _move_on(self, robot: RobotState, aside: Aside, t: float) -> Aside | None:
        """Send `robot` to a spot off the route the robot it made way for takes now, or end its
        wait if there is none. Fuzz s101-0970: r02 and r03, aside for r07 going home, stood
        between it and home once r07 had backed off past them, and held their spots for the
        rest of the 120-s hold while r07 named them as blockers."""
        other = self.robots[aside.made_way_for]
        self._asked[(robot.id, other.id)] = t
        goal = other.watched_goal or aside.their_goal
        spot = self._spot(robot, other, self._route(other, goal))
        if spot is None:
            robot.aside = None
        else:
            job = "" if other.job is None else other.job.job.id
            self._send_aside(robot, other, spot, goal, job, t)
        return robot.aside

    @staticmethod
    def _own_goal(robot: RobotState) -> tuple[float, float] | None:
        """Where `robot` heads when not aside: where its job sends it, else its charger, else
        home (or nowhere, idle without `return_home`)."""
        if robot.goal is not None:
            return robot.goal
        if robot.charger_at is not None:
            return robot.charger_at
        return robot.home if robot.return_home else None

    def steps_aside_for(self, robot: str, stuck: str, t: float) -> bool:
        """Whether `robot` was sent aside for `stuck` less than a deadlock period ago and still
        goes there or waits there: `stuck` may wait for it on its own route. Once that period
        is out the robot aside is in the way like any other (it may be stuck itself)."""
        aside = self.robots[robot].aside
        return (
            aside is not None
            and aside.made_way_for == stuck
            and t < aside.until - self.hold_s + self.retry_s
        )

    def ask(
        self, stuck: RobotState, goal: tuple[float, float], movable: Sequence[RobotState], t: float
    ) -> None:
        """Send each of the `movable` robots blocking `stuck` (heading for `goal`) aside, unless it
        already is or was asked less than a deadlock period ago; a robot with no spot to go to
        stays (the deadlock stays reported)."""
        route = None
        for robot in movable:
            pair = (robot.id, stuck.id)
            if robot.aside is not None and robot.aside.made_way_for == stuck.id:
                # Sent aside, but it got no nearer its spot for a deadlock period: the way
                # there passes `stuck` itself (fuzz s61-0277: an idle robot standing on the
                # stuck one's station held its spot aside beyond it for the last 110 s, the
                # job undone). `stuck` backs off its way, as from a robot with no spot.
                if self._cannot_reach(robot, t) and t >= self._asked.get(pair, -math.inf) + (
                    self.retry_s
                ):
                    self._asked[pair] = t
                    if route is None:
                        route = self._route(stuck, goal)
                    self._back_off(stuck, robot, goal, route, t)
                continue
            if t < self._asked.get(pair, -math.inf) + self.retry_s:
                continue
            if stuck.aside is not None and stuck.aside.made_way_for == robot.id:
                # `stuck` waits aside for `robot` itself: sent aside in turn, each would hold its
                # spot for the other for the whole hold (two robots in a queue for one station).
                continue
            self._asked[pair] = t
            if route is None:
                route = self._route(stuck, goal)
            spot = self._spot(robot, stuck, route)
            job = "" if stuck.job is None else stuck.job.job.id
            if spot is None:
                self.recorder.stats["no_way_aside"] += 1
                log.info(
                    "t = %.2f s: robot %s blocks %s and has no spot off its route",
                    t,
                    robot.id,
                    stuck.id,
                )
                # Shut in (a dead end, a station in a pocket) by the stuck robot itself: that
                # one backs off the way the other has to leave by, and comes back once it is out.
                self._back_off(stuck, robot, goal, route, t)
                continue
            self._send_aside(robot, stuck, spot, goal, job, t)

    def _send_aside(
        self,
        robot: RobotState,
        stuck: RobotState,
        spot: tuple[float, float],
        goal: tuple[float, float],
        job: str,
        t: float,
        nearby: bool = False,
    ) -> None:
        """Send `robot` to `spot`, off the way of `stuck` (heading for `goal`); with `nearby`,
        `stuck` is past once it is at `goal` however near that is (a robot let out of a corner
        to a spot close by)."""
        away = robot.spec.radius + stuck.spec.radius + AWAY_M
        gap = math.hypot(goal[0] - stuck.x, goal[1] - stuck.y)
        passed = PASSED_FACTOR * away
        if nearby:
            passed = min(passed, max(gap - ARRIVED_M, 0.0))
        robot.aside = Aside(
            spot,
            stuck.id,
            goal,
            gap,
            passed,
            t + self.hold_s,
            None if robot.job is None else robot.job.job.id,
        )
        self.recorder.stats["made_way"] += 1
        self.recorder.event(t, "make_way", job, robot.id, stuck.id)
        log.info(
            "t = %.2f s: robot %s steps aside to (%.2f, %.2f) for %s",
            t,
            robot.id,
            spot[0],
            spot[1],
            stuck.id,
        )

    def _cannot_reach(self, robot: RobotState, t: float) -> bool:
        """Whether `robot`, sent aside, is short of its spot and got no nearer it for a
        deadlock period."""
        aside = robot.aside
        return (
            aside is not None
            and robot.watched_goal == aside.spot
            and t - robot.progress_s >= self.retry_s - 1e-9
            and math.hypot(aside.spot[0] - robot.x, aside.spot[1] - robot.y) > self.arrival_m
        )

    def _back_off(
        self,
        stuck: RobotState,
        blocker: RobotState,
        goal: tuple[float, float],
        route: shapely.Geometry,
        t: float,
    ) -> None:
        """`blocker` has no spot off `stuck`'s route (to `goal`) it can reach without closing in
        on `stuck`: send `stuck` off the blocker's own way instead. A blocker with somewhere to
        go is let go there; one parked for good (idle, not going home, or at rest at its goal) is
        sent to the spot off `stuck`'s route it would take were `stuck` not in the way, once
        `stuck` has backed off its way there."""
        if stuck.aside is not None or not stuck.in_service:
            return
        theirs = blocker.watched_goal
        # At rest at its goal as the run counts arrival, it will not leave by itself: a robot
        # 1.008e-9 m from home counted as one going there, the stuck robot backed off for
        # nothing and came back to it at once (fuzz s91-0045, on this branch).
        parked = theirs is None or at_rest_near(blocker, theirs, self.arrival_m)
        plan = self._back_off_plan(stuck, blocker, route, theirs, parked, frozenset())
        crowd: list[tuple[RobotState, tuple[float, float]]] = []
        if plan is None:
            # Boxed in by robots that never leave by themselves, or wait behind `stuck` for
            # the same place, they step aside too (fuzz s91-0106: an idle robot on a station
            # in a pocket, the robot with a job at its mouth and three more behind it, all
            # still for 130 s). Only if each of them in the ways has a spot off them.
            near = yielders(self.robots, stuck, blocker, goal, t, self.retry_s)
            if near:
                plan = self._back_off_plan(stuck, blocker, route, theirs, parked, near)
            if plan is None or (crowd := self._crowd_aside(stuck, blocker, plan, near)) is None:
                return
        theirs, way, spot = plan
        self.recorder.stats["backed_off"] += 1
        job = "" if blocker.job is None else blocker.job.job.id
        self._send_aside(stuck, blocker, spot, theirs, job, t, nearby=parked)
        for robot, aside in crowd:
            self._send_aside(robot, blocker, aside, theirs, job, t)
        if parked:
            sid = "" if stuck.job is None else stuck.job.job.id
            self._send_aside(blocker, stuck, theirs, goal, sid, t)

    def _back_off_plan(
        self,
        stuck: RobotState,
        blocker: RobotState,
        route: shapely.Geometry,
        theirs: tuple[float, float] | None,
        parked: bool,
        ignore: frozenset[str],
    ) -> tuple[tuple[float, float], shapely.Geometry, tuple[float, float]] | None:
        """Where `blocker` goes (its own goal, or with `parked` a spot off `route`), its way
        there and `stuck`'s spot off that way, the robots in `ignore` passed over; None if
        there is no such spot."""
        if parked:
            theirs = self._spot(blocker, stuck, route, past=True, ignore=ignore)
            if theirs is None:
                return None
            way = self._way(blocker, theirs)
        else:
            way = self._route(blocker, theirs)
        spot = self._spot(stuck, blocker, way, ignore=ignore)
        return None if spot is None or theirs is None else (theirs, way, spot)

    def _crowd_aside(
        self,
        stuck: RobotState,
        blocker: RobotState,
        plan: tuple[tuple[float, float], shapely.Geometry, tuple[float, float]],
        near: frozenset[str],
    ) -> list[tuple[RobotState, tuple[float, float]]] | None:
        """A spot for each robot in `near` within reach of the ways of the `plan` (`blocker`'s
        and `stuck`'s), off both and clear of the spots they go to; None if one has none."""
        theirs, way, spot = plan
        ways = shapely.union_all([way, self._way(stuck, spot) or Point(spot)])
        taken = [(*theirs, blocker.spec.radius), (*spot, stuck.spec.radius)]
        out = []
        for rid in sorted(near):
            o = self.robots[rid]
            gap = max(OTHERS_M, kept_gap(stuck, o), kept_gap(blocker, o))
            if ways.distance(Point(o.x, o.y)) >= o.spec.radius + stuck.spec.radius + gap:
                continue
            aside = self._spot(o, stuck, ways, avoid=taken)
            if aside is None:
                return None
            out.append((o, aside))
            taken.append((*aside, o.spec.radius))
        return out

    def in_the_way(
        self, stuck: RobotState, goal: tuple[float, float], t: float
    ) -> list[RobotState]:
        """Idle robots further off than the deadlock watch looks that stand on `stuck`'s route
        within `LOOK_AHEAD_M` of it: a controller may stop that far short of a robot parked in
        a passage (the MPC's square round it). Looked for at most once a deadlock period; the
        answer holds meanwhile."""
        looked = self._looked.get(stuck.id)
        if looked is None or t >= looked[0] + self.retry_s:
            route = None
            found = []
            for o in self.robots.values():
                if o is stuck or o.job is not None or not o.in_service:
                    continue
                if math.hypot(o.x - stuck.x, o.y - stuck.y) > LOOK_AHEAD_M:
                    continue
                if route is None:
                    route = self._route(stuck, goal)
                if route.distance(Point(o.x, o.y)) <= stuck.spec.radius + o.spec.radius + AWAY_M:
                    found.append(o.id)
            looked = self._looked[stuck.id] = (t, tuple(found))
        return [o for rid in looked[1] if (o := self.robots[rid]).job is None and o.in_service]

    def idle_on_route(
        self, stuck: RobotState, goal: tuple[float, float], reach: float, t: float
    ) -> list[RobotState]:
        """Idle robots in service within both radii plus `reach` of `stuck` that stand on its
        route (within both radii and `AWAY_M`) and were not asked for it less than a deadlock
        period ago: the route is planned only when there are such robots."""
        r = stuck.spec.radius + reach
        close = [
            o
            for o in self.robots.values()
            if o is not stuck
            and o.job is None
            and not o.queue
            and o.in_service
            and o.aside is None
            and math.hypot(o.x - stuck.x, o.y - stuck.y) <= r + o.spec.radius
            and t >= self._asked.get((o.id, stuck.id), -math.inf) + self.retry_s
        ]
        if not close:
            return []
        # Asked at every tick while the robot stands still: the route is planned again only
        # when the robot, its goal or the robots close by moved.
        key = (stuck.x, stuck.y, goal, tuple((o.id, o.x, o.y) for o in close))
        seen = self._idle_seen.get(stuck.id)
        if seen is None or seen[0] != key:
            route = self._route(stuck, goal)
            gap = stuck.spec.radius + AWAY_M
            on = tuple(
                o.id for o in close if route.distance(Point(o.x, o.y)) <= gap + o.spec.radius
            )
            seen = self._idle_seen[stuck.id] = (key, on)
        return [self.robots[rid] for rid in seen[1]]

    # -- helpers --------------------------------------------------------------------------------
    def _still_needed(self, robot: RobotState, aside: Aside, t: float) -> bool:
        """Whether `robot` still waits aside: the hold has not run out, it has the job it had,
        and the robot it made way for is still on its way to the same goal and not past."""
        job = None if robot.job is None else robot.job.job.id
        if t >= aside.until or job != aside.job:
            return False
        other = self.robots.get(aside.made_way_for)
        if other is None or not other.in_service:
            return False
        # The other may be aside itself, backing off to let this one or a third robot out
        # first: it still comes, and this one would stand in its way again. Fuzz s91-0723:
        # r07, aside for r05 (with a job via a depot ringed by parked robots), drove home
        # into the ring the moment r05 backed off to let the robot parked on the depot out,
        # and stood in that one's way out: the back-off came back to the same block every
        # 70 s, the job undone after 840 s.
        backing = other.aside is not None and (
            other.aside.made_way_for == robot.id or self._own_goal(other) == aside.their_goal
        )
        # Sent to that goal as a spot aside this very tick (a parked blocker let out of a
        # ring, its crowd sent aside with it), the deadlock watch still shows its old goal
        # (fuzz s31-0037: r06, sent aside for r01, gave up its spot at once, and r01 never
        # got past it to let the robot with a job onto its station).
        heading = other.watched_goal == aside.their_goal or (
            other.aside is not None and other.aside.spot == aside.their_goal
        )
        if not heading and not backing:
            return False
        gx, gy = aside.their_goal
        if at_rest_near(other, aside.their_goal, self.arrival_m):
            # There: a robot going home keeps that goal once home, and one stuck within
            # `passed_m` of it is never "past"; those aside stood out the whole hold (fuzz
            # seed 21: idle robots 1.4 to 3 m from home for the last 90 s of the run). At
            # rest there: one that drives through it (an MPC braking) is not there yet, and
            # the one aside came back into its way (fuzz s21-0607). Arrived as the run counts
            # it: an MPC robot stopped 0.057 m from its station (tolerance 0.05), kept out of
            # the last 7 mm by the robot it had sent aside, which came straight back and stood
            # there for 90 s (fuzz s61-0236).
            return False
        closer = math.hypot(gx - other.x, gy - other.y) < aside.their_gap - aside.passed_m
        sx, sy = aside.spot
        return not (closer and math.hypot(sx - other.x, sy - other.y) > aside.passed_m)


def yielders(
    robots: Mapping[str, RobotState],
    stuck: RobotState,
    blocker: RobotState,
    goal: tuple[float, float],
    t: float,
    retry_s: float,
) -> frozenset[str]:
    """The robots within `YIELD_M` of `stuck` that may step aside for it to back off from
    `blocker`: in service and idle (none leaves by itself), sent aside for either of them
    already, or with a job and stuck for half a deadlock period on the way to `goal` too
    (they wait behind `stuck` for the same place)."""
    out = []
    for o in robots.values():
        if o is stuck or o is blocker or not o.in_service:
            continue
        if math.hypot(o.x - stuck.x, o.y - stuck.y) > YIELD_M:
            continue
        aside = o.aside
        if (
            (o.job is None and not o.queue and aside is None)
            or (aside is not None and aside.made_way_for in (stuck.id, blocker.id))
            or (
                o.job is not None
                and aside is None
                and o.watched_goal == goal
                and t - o.progress_s >= retry_s / 2 - 1e-9
            )
        ):
            out.append(o.id)
    return frozenset(out)
