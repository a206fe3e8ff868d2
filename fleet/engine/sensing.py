"""Sensing: what each robot observes at its tick.

An observation holds the robot's state, its goal, the print caps ahead, its priority and its
neighbours: the nearest robots within the sensing radius, each with the part of its latest plan
still ahead (thinned to `PLAN_SPACING_S`). Sensing also watches each robot's progress towards its
goal: a robot that has made none for `Scenario.deadlock_after_s` with robots close by is blocked
by them; its observation names them and its priority is raised, and the robots in its way that
would never leave by themselves are asked to step aside (`fleet.engine.makeway`).
"""

from __future__ import annotations

import bisect
import logging
import math
from collections.abc import Mapping, Sequence

import numpy as np
from scipy.spatial import cKDTree

from fleet.engine.homes import trade_home
from fleet.engine.jobs import JobRecord
from fleet.engine.makeway import MakeWay
from fleet.engine.motion import RobotState, Turning, at_rest_near
from fleet.engine.recorder import Recorder
from fleet.errors import NoPathError
from fleet.plugins import CAP_LOOKAHEAD_S, Neighbour, Observation
from fleet.scenario import Scenario

__all__ = ["Sensing", "nearest_within", "thin_plan", "PLAN_SPACING_S"]

log = logging.getLogger("fleet.engine")

#: At most this many neighbours (the nearest) go into one observation.
MAX_NEIGHBOURS = 8
#: A robot that got no closer to its goal than this (m) over `Scenario.deadlock_after_s` has
#: made no progress.
PROGRESS_M = 0.25
#: Robots closer than the sum of their radii plus this (m), plus the stalled robot's
#: sqrt(2)*a_max*period**2, to a stalled robot may block it.
BLOCKING_GAP_M = 1.0
#: A robot going home that is stuck this close (m) to it asks idle robots to make way (plus
#: its sqrt(2)*a_max*period**2: at a coarse period start spots are that much further apart).
HOME_REACH_M = 3.0
#: A robot going home (or to its charger) that made no progress for this many deadlock periods
#: asks idle robots to make way however far from home it is.
HOME_ASK_FACTOR = 2.0
#: A robot with a job that made no progress for this long (s), but less than a deadlock
#: period, sends the idle robots on its route close by aside (`MakeWay.idle_on_route`).
IDLE_ASK_S = 5.0
#: A broken-down robot's priority is its rank plus this many times the fleet's size: above
#: every robot in service (at most rank + 3 * size).
BROKEN_RANKS = 4
#: How long (s) a plan stays news: a neighbour whose latest plan ended longer ago than this is
#: shown without one (assume it stays where it is).
PLAN_STALE_S = 1.0
#: Neighbours see plans thinned to samples this far apart (s): each plan goes into up to
#: `MAX_NEIGHBOURS` observations, and between samples a robot at most 0.5 m/s^2 strays
#: a * dt^2 / 8 = 0.016 m from the chord.
PLAN_SPACING_S = 0.5
#: Fleets up to this size compare every pair in `nearest_within`; larger ones use a k-d tree.
_TREE_BELOW = 24
#: Relative distance a hair beyond which `nearest_within` keeps the tree's candidates: far
#: more than the tree's rounding (a few 1e-16), far less than any distance that matters.
_SLACK = 1e-9
#: Points `nearest_within` asks the tree for beyond the k nearest, so that a tie with the k-th
#: rarely needs a second query.
_SPARE = 4


class Sensing:
    """Builds the robots' observations; `turning` holds a robot that turns on the spot."""

    def __init__(
        self,
        scenario: Scenario,
        robots: Mapping[str, RobotState],
        recorder: Recorder,
        turning: Turning,
        make_way: MakeWay,
    ) -> None:
        self.scenario = scenario
        self.robots = robots
        self.recorder = recorder
        self.turning = turning
        self.make_way = make_way

    def observe(self, robots: list[RobotState], t: float) -> list[Observation]:
        """The observations of `robots` (due at `t`), from one snapshot of the floor."""
        radius = self.scenario.sensing_radius_m
        priority = self._priorities(t)
        near = (
            self._neighbours(robots, radius, t, priority)
            if radius > 0 and len(self.robots) > 1
            else {}
        )
        out = []
        tol = self.scenario.arrival_tolerance_m
        self.make_way.queue.snapshot()
        for r in robots:
            goal = self.make_way.goal_of(r, t)
            aside = r.aside
            # Waiting its turn short of a station, it still waits for the station: stuck there
            # as if beside it (a robot printing on it may have to let it go first).
            self._watch_progress(r, self.make_way.queue.station_of(r) or goal, t, tol, priority)
            if r.aside is not None and r.aside is not aside:
                # Sent aside by its own watch (it gave way, or backs off): it heads for the
                # spot from this tick on, and the robots that blocked its way to `goal` block
                # nothing there. Shown that goal with them, a follower found no way round them
                # and handed its job back in the very tick it stepped aside (fuzz s31-0025,
                # s31-0047: 5 of 13 hand-backs), and the print began anew elsewhere.
                goal, r.blockers = r.aside.spot, ()
            if (
                r.turn_rate is not None
                and goal is not None
                and self.turning.turns_first(r, goal, t, tol)
            ):
                goal = (r.x, r.y)  # turning on the spot: hold here until the turn is done
            caps = r.job.caps if r.job is not None else None
            cap = None
            window: tuple[tuple[float, float, float], ...] = ()
            if caps:
                window = caps.window(t, t + CAP_LOOKAHEAD_S).pieces
                over = caps.cap_over(t, t + r.spec.period)
                cap = None if math.isinf(over) else over
            out.append(
                Observation(
                    robot=r.id,
                    tick=r.tick,
                    t=t,
                    x=r.x,
                    y=r.y,
                    vx=r.vx,
                    vy=r.vy,
                    goal=goal,
                    job=None if r.job is None else r.job.job.id,
                    speed_cap=cap,
                    neighbours=near.get(r.id, ()),
                    speed_caps=window,
                    print_end_s=None if r.job is None else r.job.print_end_s,
                    priority=priority[r.id],
                    blockers=r.blockers,
                    queued=len(r.queue),
                )
            )
        return out

    def _priorities(self, t: float) -> dict[str, int]:
        """Each robot's priority now: broken-down robots first (they cannot give way: every
        controller keeps clear of them), then robots freed from a deadlock, then robots with a
        job, then the rest; smaller ids first within each class (unique, higher goes first)."""
        n = len(self.robots)
        return {
            r.id: r.rank + BROKEN_RANKS * n
            if r.broken
            else r.rank + (2 * n if t < r.boosted_until else 0) + (n if r.job is not None else 0)
            for r in self.robots.values()
        }

    def _watch_progress(
        self,
        r: RobotState,
        goal: tuple[float, float] | None,
        t: float,
        tol: float,
        priority: Mapping[str, int],
    ) -> None:
        """Deadlock detection: a robot that has got no closer to its goal for
        `Scenario.deadlock_after_s` while other robots stand close is blocked by them; its
        observation names them (its controller routes round them) and its priority is raised."""
        after = self.scenario.deadlock_after_s
        if goal is None or after is None or not r.in_service:
            r.watched_goal, r.blockers, r.stalled = None, (), False
            return
        if (r.x, r.y) != r.still_at:
            r.still_at, r.still_since = (r.x, r.y), t
        gap = math.hypot(goal[0] - r.x, goal[1] - r.y)
        on_route = t - r.progress_s >= after / 2 - 1e-9 and self._gained_on_route(r, goal)
        if goal != r.watched_goal or gap <= tol or gap < r.best_gap - PROGRESS_M or on_route:
            # Progress along the route was made by the time the robot came to stand here.
            now = r.still_since if on_route else t
            r.watched_goal, r.best_gap, r.progress_s, r.blockers = goal, gap, now, ()
            r.stalled = False
            r.progress_at, r.route_then, r.route_seen = (r.x, r.y), None, (r.x, r.y)
            return
        # Held up on its way home: it may trade homes with a parked robot of its group
        # (`homes`); the new home is watched from the next tick.
        held = goal == r.home and t - r.progress_s >= IDLE_ASK_S
        if held and trade_home(r, self.robots.values(), tol):
            return
        # At a coarse period robots stand further off (a step of a_max*dt**2 per axis that a
        # neighbour may take unseen is kept clear of): such a stand-off counts too.
        reach = BLOCKING_GAP_M + math.sqrt(2.0) * r.spec.a_max * r.spec.period**2
        # A follower at rest sets off only if it could stop again clear of the others: the
        # step it sets off with and the step braking takes, each up to
        # period * min(v_max, a_max * period), are kept clear too. At a coarse period they
        # span metres: two robots facing each other froze 4.5 m apart, beyond `reach`, and no
        # deadlock was ever reported (fuzz s21-0455: period 0.91 s, 125 s to the end).
        spec = r.spec
        set_off = 2.0 * spec.period * min(spec.v_max, spec.a_max * spec.period)
        if t - r.progress_s < after - 1e-9:
            # Idle robots never leave by themselves: one on the route of a robot with a job
            # that has made no progress for `IDLE_ASK_S` is sent aside then, not a whole
            # deadlock period later (fuzz s21-0566, s21-0827: robots parked at home round a
            # depot by a door cost 30 s to each robot with a job that came through).
            # So, once this one's part is done, does a robot standing on its goal to print a
            # part done later there for a younger job: a robot served at a station took each
            # next job there and printed it on the station while one with an older job and a
            # finished part waited its turn beside it (fuzz s21-0366), each print shorter than
            # the deadlock period. (One there first, for an older job, keeps its turn: moved
            # off the end of a dead end it came back 40 s later.)
            if r.job is not None and r.aside is None and t - r.progress_s >= IDLE_ASK_S:
                idle = self.make_way.idle_on_route(r, goal, reach + set_off, t)
                if _part_ready(r, t):
                    idle += [
                        o
                        for o in self.make_way.queue.bound_for(goal)
                        if o is not r
                        and o.aside is None
                        and o.in_service
                        and _prints_on_longer(o, r, goal, t, tol)
                        and _younger(o, r)
                    ]
                if idle:
                    self.make_way.ask(r, goal, idle, t)
            return
        # Close by, or standing on its goal however far off this one stopped (the MPC keeps a
        # square round a parked robot, and may stop short of it by more than `reach`).
        near = [
            o
            for o in self.robots.values()
            if o is not r
            and (
                math.hypot(o.x - r.x, o.y - r.y) <= spec.radius + o.spec.radius + reach + set_off
                or math.hypot(o.x - goal[0], o.y - goal[1]) <= r.spec.radius + o.spec.radius
            )
        ]
        if not near and r.job is not None:
            near = self.make_way.in_the_way(r, goal, t)
        # A robot standing on this one's goal with a job of its own is no deadlock: this one
        # waits its turn there. The controller routes round the others (not round its goal).
        blockers = tuple(
            o.id
            for o in near
            if math.hypot(o.x - goal[0], o.y - goal[1]) > r.spec.radius + o.spec.radius
        )
        # An idle robot never leaves by itself, on the goal or not, nor do robots with jobs
        # that wait for each other: a robot with a job asks the idle ones, and stuck ones of
        # lower priority that are not at their own goals, to step aside. A robot going home
        # asks only once it is within `HOME_REACH_M` of it, shut out by the robots parked
        # round it (a robot that stepped aside could not get back); asking from further off
        # moved idle robots round and round the crowded depots for nothing. So does a robot
        # going to its charger. At a coarse period robots keep the unseen step from a parked
        # one, and one 4 m from home between homes 3.6 m apart never asked (fuzz s21-0507).
        # One stuck for `HOME_ASK_FACTOR` deadlock periods asks wherever it is: robots parked
        # round its home, kept clear by the gap a follower keeps at a coarse period, held it
        # off further out than that (fuzz s91-0638: 5.1 m from home, still for the last 90 s).
        asks = r.job is not None or (
            goal in (r.home, r.charger_at)
            and (
                math.hypot(goal[0] - r.x, goal[1] - r.y) <= HOME_REACH_M + reach - BLOCKING_GAP_M
                or t - r.progress_s >= HOME_ASK_FACTOR * after - 1e-9
            )
        )
        queue = self.make_way.queue
        # The station this one is bound for: robots waiting for it are its rivals, not robots
        # in its way (fuzz s91-0106 with the queue: two robots bound for one station sent each
        # other aside, and both held their spots for the whole hold).
        mine = r.goal if r.job is not None else None
        movable = [
            o
            for o in near
            if o.in_service
            and (
                # A robot waiting its turn for a station will not leave by itself either.
                queue.station_of(o) not in (None, mine)
                or (
                    asks
                    # Idle robots ask one way only (two going home asked each other in turn),
                    # but any robot asks one parked for good, which would never give way
                    # otherwise.
                    and (r.job is not None or priority[o.id] < priority[r.id] or _parked(o, tol))
                    and (
                        o.job is None
                        or (
                            _no_progress(o, t, after / 2)
                            and priority[o.id] < priority[r.id]
                            and o.goal is not None
                            and math.hypot(o.goal[0] - o.x, o.goal[1] - o.y) > tol
                        )
                        or _prints_on_longer(o, r, goal, t + after, tol)
                    )
                )
            )
        ]
        stalled = bool(blockers or movable)
        if stalled and not r.stalled:
            r.boosted_until = t + after
        if stalled and not r.stalled and r.reported_at != r.progress_s:
            # Counted once until it makes progress: a robot waiting beside a station came and
            # went from `stalled` as robots passed within reach, and was reported up to 9
            # times in one wait (80 MPC robots, seed 1: 63 reports, 25 counted once each).
            r.reported_at = r.progress_s
            self.recorder.stats["deadlocks"] += 1
            named = sorted({*blockers, *(o.id for o in movable)})
            self.recorder.event(
                t, "deadlock", "" if r.job is None else r.job.job.id, r.id, " ".join(named)
            )
            log.info("t = %.2f s: robot %s stuck behind %s", t, r.id, named)
        if movable:
            self.make_way.ask(r, goal, movable, t)
        elif (r.job is not None or goal == r.home) and r.aside is None and gap > tol:
            self._give_way(r, [o for o in near if o.id in blockers], t, after, priority)
        # Robots sent aside for this one leave its route: for a deadlock period it waits for
        # them on its own route rather than routing round them. Named as blockers, a follower
        # found no way round one in a door or beside a station and handed its job back in the
        # very tick it was asked to step aside (fuzz seed 21: 44 of 61 hand-backs), and the job
        # began again elsewhere, often to be handed back again.
        r.blockers = tuple(
            b
            for b in blockers
            if not self.make_way.steps_aside_for(b, r.id, t)
            and not (r.aside is not None and r.aside.made_way_for == b)
        )
        r.stalled = stalled

    def _give_way(
        self,
        r: RobotState,
        blockers: Sequence[RobotState],
        t: float,
        after: float,
        priority: Mapping[str, int],
    ) -> None:
        """`r`, stuck with a job or on its way home, steps aside for the first of its
        `blockers` that is stuck too, with a job or on its way home, and goes first (higher
        priority): that one would send `r` aside once it is reported, but `r` was reported
        first, found no way round it (a corridor, a door) and handed its job back in the same
        tick (fuzz s21-0677: two robots face to face in a corridor, both jobs handed back).
        Two idle robots going home face to face never asked each other (only robots near home
        ask) and stood for good (fuzz s31-0463: three robots, the last 110 s)."""
        for o in blockers:
            if (
                o.in_service
                and (o.job is not None or o.watched_goal == o.home)
                and priority[o.id] > priority[r.id]
                and o.watched_goal is not None
                and _no_progress(o, t, after / 2)
            ):
                self.make_way.ask(o, o.watched_goal, [r], t)
                if r.aside is not None:
                    return

    def _gained_on_route(self, r: RobotState, goal: tuple[float, float]) -> bool:
        """Whether `r` is now `PROGRESS_M` nearer `goal` along its route (the path layer's,
        robots ignored) than where it last made progress. A route round a wall leads away
        from the goal as the crow flies: a robot driving it for a deadlock period was taken
        for a stuck one, and the first robot it met in a door became a blocker it could not
        route round, so it handed its job back at once (fuzz s21-0204, s21-0677). Asked from
        half a deadlock period without progress on (a robot stuck then is reported at most
        half a period late), and measured only once the robot has moved `PROGRESS_M` since
        it last made progress or was last measured (a stuck robot costs nothing, and one
        that moved less cannot have gained that much)."""
        here = (r.x, r.y)
        if (
            r.progress_at is None
            or r.route_seen is None
            or math.dist(here, r.route_seen) <= PROGRESS_M
        ):
            return False
        r.route_seen = here
        if r.route_then is None:
            r.route_then = self._route_length(r, r.progress_at, goal)
        return self._route_length(r, here, goal) < r.route_then - PROGRESS_M

    def _route_length(
        self, r: RobotState, start: tuple[float, float], goal: tuple[float, float]
    ) -> float:
        """The length (m) of the path layer's route from `start` to `goal` for `r` (as the crow
        flies where there is none)."""
        try:
            return self.make_way.planner_for(r.spec).path(start, goal).length
        except NoPathError:
            return math.dist(start, goal)

    def _future_plan(self, r: RobotState, t: float) -> tuple[tuple[float, float, float], ...]:
        """The part of `r`'s latest plan from `t` on, starting with where it puts `r` at `t`;
        empty when it has none or it ended more than `PLAN_STALE_S` ago."""
        plan = r.thinned_plan
        if not plan or plan[-1][0] < t - PLAN_STALE_S:
            return ()
        i = bisect.bisect_right(plan, t, key=_sample_time)
        if i == len(plan):
            return ((t, plan[-1][1], plan[-1][2]),)
        if i == 0:
            return plan
        (t0, x0, y0), (t1, x1, y1) = plan[i - 1], plan[i]
        f = (t - t0) / (t1 - t0) if t1 > t0 else 1.0
        return ((t, x0 + f * (x1 - x0), y0 + f * (y1 - y0)), *plan[i:])

    def _neighbours(
        self, robots: list[RobotState], radius: float, t: float, priority: dict[str, int]
    ) -> dict[str, tuple]:
        """Each of `robots`' nearest robots within `radius` (at most `MAX_NEIGHBOURS`), with
        their plans from `t` on: nearest first, equal distances by id (`nearest_within`)."""
        everyone = list(self.robots.values())
        at = {o.id: i for i, o in enumerate(everyone)}
        found = nearest_within(
            [o.x for o in everyone],
            [o.y for o in everyone],
            [o.id for o in everyone],
            [at[r.id] for r in robots],
            radius,
            MAX_NEIGHBOURS,
        )
        out = {}
        # A robot looks the same to all who see it this instant: one (frozen) Neighbour each.
        seen: dict[int, Neighbour] = {}
        for r, near_idx in zip(robots, found, strict=True):
            near = []
            for j in near_idx:
                nb = seen.get(j)
                if nb is None:
                    o = everyone[j]
                    plan = self._future_plan(o, t)
                    spec = o.spec
                    nb = seen[j] = Neighbour(
                        o.id,
                        o.x,
                        o.y,
                        o.vx,
                        o.vy,
                        spec.radius,
                        priority[o.id],
                        plan,
                        spec.v_max,
                        spec.a_max,
                        spec.period,
                    )
                near.append(nb)
            out[r.id] = tuple(near)
        return out


def nearest_within(
    xs: Sequence[float],
    ys: Sequence[float],
    ids: Sequence[str],
    queries: Sequence[int],
    radius: float,
    k: int,
) -> list[list[int]]:
    """For each point index in `queries`, the indices of the at most `k` other points within
    `radius` of it, nearest first and equal distances by id.

    The answer is exactly that of sorting every other point by ``((x - x0) ** 2 + (y - y0) ** 2,
    id)`` in Python floats and keeping those within ``radius ** 2``: a k-d tree only picks the
    candidates. Its distances may differ from those by a rounding error, so it keeps every
    point up to a hair beyond its own k-th nearest (ties included, however many), and the
    exact squared distances rank those few.
    """
    n = len(xs)
    if not queries:
        return []
    r2 = radius * radius
    reach = radius * (1.0 + _SLACK)
    if n <= _TREE_BELOW:
        near_of = [range(n)] * len(queries)
    else:
        tree = cKDTree(np.column_stack([xs, ys]))
        q = np.array([(xs[i], ys[i]) for i in queries], dtype=float)
        m = min(n, k + 1 + _SPARE)  # the point itself comes back too
        dist, idx = tree.query(q, k=m, distance_upper_bound=reach)
        # Cut a hair beyond the (k+1)-th distance (the point itself is one of the first k+1).
        kth = dist[:, k] if m > k else np.full(len(queries), np.inf)
        cut = np.minimum(kth * (1.0 + _SLACK), reach)
        keep = dist <= cut[:, None]
        # Ties reach past the m found where the last one is kept: ask for all within the cut.
        full = keep[:, -1].tolist()
        near_of = []
        for row, (i, found_row, kept) in enumerate(
            zip(queries, idx.tolist(), keep.tolist(), strict=True)
        ):
            if full[row]:
                near_of.append(tree.query_ball_point((xs[i], ys[i]), float(cut[row])))
            else:
                near_of.append([j for j, ok in zip(found_row, kept, strict=True) if ok])
    out = []
    for i, near in zip(queries, near_of, strict=True):
        x0, y0 = xs[i], ys[i]
        found = []
        for j in near:
            d2 = (xs[j] - x0) ** 2 + (ys[j] - y0) ** 2
            if j != i and d2 <= r2:
                found.append((d2, ids[j], j))
        found.sort()
        out.append([j for _, _, j in found[:k]])
    return out


def thin_plan(
    plan: tuple[tuple[float, float, float], ...], spacing: float
) -> tuple[tuple[float, float, float], ...]:
    """`plan` with samples at least `spacing` seconds apart (the first and last kept)."""
    if len(plan) <= 2:
        return plan
    out = [plan[0]]
    for sample in plan[1:-1]:
        if sample[0] - out[-1][0] >= spacing - 1e-9:
            out.append(sample)
    if plan[-1][0] - out[-1][0] < spacing / 2 and len(out) > 1:
        out.pop()  # keep the last sample, not one a moment before it
    out.append(plan[-1])
    return tuple(out)


def _prints_on_longer(
    o: RobotState, r: RobotState, goal: tuple[float, float], t: float, tol: float
) -> bool:
    """Whether `o` waits at `goal`, its destination too, for a print that ends after `t` and
    after `r` is done there (its part ready, or `goal` only a via station it passes): then
    `r` goes first and `o` steps aside meanwhile. Waiting its turn starved a finished part
    otherwise (fuzz s21-0607: 90 s, while the robot on the station was given two more jobs
    there and printed both standing on it)."""
    theirs, mine = o.job, r.job
    if theirs is None or mine is None or theirs.arrived_s is None or o.goal is None:
        return False
    if math.hypot(o.goal[0] - goal[0], o.goal[1] - goal[1]) > tol:
        return False
    end = theirs.print_end_s
    if end is None or end <= t:
        return False
    ready = _ready_s(mine)
    return ready is not None and ready < end


def _ready_s(job: JobRecord) -> float | None:
    """When `job`'s robot may leave its goal: -inf when it only passes it (a via station) or
    prints nothing, else when its print ends (None: not known yet)."""
    passing = job.leg < len(job.via)
    return -math.inf if passing or not job.tasks else job.print_end_s


def _younger(o: RobotState, r: RobotState) -> bool:
    """Whether `o`'s job was released after `r`'s (the larger id first when at once)."""
    assert o.job is not None and r.job is not None
    return (o.job.job.released_s, o.job.job.id) > (r.job.job.released_s, r.job.job.id)


def _part_ready(r: RobotState, t: float) -> bool:
    """Whether `r` has a job and could be done at its goal at `t` (`_ready_s`)."""
    ready = None if r.job is None else _ready_s(r.job)
    return ready is not None and ready <= t


def _parked(o: RobotState, tol: float) -> bool:
    """Whether `o` is parked for good: idle, nothing queued, not aside, and at rest with no goal
    or at its goal (home). It never leaves by itself, so asking it aside starts no back and
    forth: a robot going home with the lowest priority stood 6.7 m short of it, behind four
    robots parked at their homes round the depot, none of which it could ask (fuzz s21-0534:
    the last 109 s of the run)."""
    if o.job is not None or o.queue or o.aside is not None:
        return False
    goal = o.watched_goal
    return at_rest_near(o, (o.x, o.y) if goal is None else goal, tol)


def _no_progress(r: RobotState, t: float, after: float) -> bool:
    """Whether `r` has had a goal and got no closer to it for `after` seconds: stuck, whether
    or not it found anyone to blame (two robots stuck short of one station each take the other
    for one waiting its turn there, and neither would ever be asked to move)."""
    return r.watched_goal is not None and t - r.progress_s >= after - 1e-9


def _sample_time(sample: tuple[float, float, float]) -> float:
    return sample[0]
