"""Which other robots a solve keeps clear of, and whether a plan keeps clear of them all.

A robot needs keeping clear of when its predicted square can come within reach of the plan
(the reachable boxes, narrowed to the regions each step may use) and, with
``respect_priority``, it outranks this one wherever it is, and only when parked for the whole
horizon, close (`close`), or settling into a queue at this one's goal (`settling`: it cannot
get out of the way) if this one outranks it. The higher one thus keeps its course unless the
lower one is close (when both yielded at any distance, both swerved alike and met again:
measured head-on). A moving robot may carry on with its plan or drop it at its next tick (to
brake when its solve fails, or to re-plan, as this one does at the same time), so the plan
keeps clear of the box round both its plan and its braking path; only a robot parked for the
horizon is a plain square. `separation` turns the chosen ones into rows.

Close means: should both robots keep their course one more tick and then brake, they could
meet. It is judged from both robots' real velocities and braking paths, not from one distance
for ``v_max`` along an axis: ``v_max`` bounds each axis, so a robot on a diagonal goes up to
sqrt(2) times as fast and brakes over up to sqrt(2) times the distance (a higher robot on a
diagonal kept its course from 4.17 m, thinking 3.7 m enough, and met the lower one:
tests/test_mpc_contact.py). With a close lower robot, the higher one does not
re-plan (`must_hold`): the lower one keeps clear of its plan and its braking path, so it only
follows its plan (while that keeps clear) or brakes; when both re-planned at once, both
swerved into the same gap. It re-plans after all when its braking path runs into a robot
standing still (`brake_runs_into`): that one may be held too, and never give way.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from fleet.plugins import Neighbour, Observation, RobotSpec
from fleet_plugins.mpc.fallback import REST_SPEED, braking_path, leaves_floor
from fleet_plugins.mpc.separation import Obstacle, at_rest, predict, reaches

if TYPE_CHECKING:
    from fleet.floor import Floor

__all__ = [
    "robots_to_avoid",
    "clear_of_neighbours",
    "closest_approach",
    "outranks",
    "close",
    "must_hold",
    "brake_runs_into",
    "paths_of",
    "brake_after",
    "must_announce",
    "shows_start",
    "settling",
    "ahead_in_queue",
    "SETTLING_M",
    "QUEUE_M",
    "AHEAD_M",
    "HEADING",
]


def robots_to_avoid(
    obs: Observation,
    spec: RobotSpec,
    horizon: int,
    p_lo: np.ndarray,
    p_hi: np.ndarray,
    *,
    margin: float,
    respect_priority: bool,
) -> list[Obstacle]:
    """The robots of `obs.neighbours` the plan must keep clear of, nearest first (on a tie,
    by robot id); `p_lo`, `p_hi` bound where each point of the plan can be."""
    N, dt = horizon, spec.period
    picked: list[tuple[float, str, Obstacle]] = []
    for n in obs.neighbours:
        centres = predict(n, obs.t, dt, N)
        half = spec.radius + float(n.radius) + margin
        distance = math.hypot(n.x - obs.x, n.y - obs.y)
        ob = Obstacle.square(n.robot, centres, half, margin)
        moving = not at_rest(centres)
        if moving:
            # A moving robot may carry on with its plan, or drop it at its next tick to brake
            # (a failed solve) or to re-plan: keep clear of the box round both, whichever robot
            # yields (against its plan alone, a robot tailed the other 0.7 m behind and met it
            # when that one braked; tests/test_mpc_contact.py).
            stop = brake_after(obs.t, (n.x, n.y), (n.vx, n.vy), dt, n.limits(spec).a_max, N)
            if (
                respect_priority
                and outranks(obs, n)
                and not shows_start(n)
                and not settling(n, centres, stop, obs.goal)
                and not ahead_in_queue(obs, n, centres)
                and not close(obs, n, spec, half)
            ):
                continue  # it yields to this robot (braking if it must); this one keeps its course
            ob = Obstacle.between(n.robot, centres, stop, half, margin)
        if not reaches(ob, p_lo, p_hi):
            continue
        picked.append((distance, n.robot, ob))
    picked.sort(key=lambda item: (item[0], item[1]))
    return [ob for _, _, ob in picked]


#: A lower robot whose plan and braking path both stay within this (m) of where it is can get
#: no farther out of the way: a higher robot keeps clear of it near its own goal (`settling`).
SETTLING_M = 1.0
#: How near (m) this robot's goal a lower robot's plan must end to count as settling there.
QUEUE_M = 3.0


def settling(
    n: Neighbour, centres: np.ndarray, stop: np.ndarray, goal: tuple[float, float] | None
) -> bool:
    """Whether moving robot `n` is settling into a queue at this robot's `goal`: its predicted
    `centres` and its braking path `stop` (``(N+1, 2)`` each) stay within `SETTLING_M` of it,
    along both axes, and its plan ends within `QUEUE_M` of the goal.

    A higher robot keeps its course past a moving lower one, which yields; but one settling
    into a queue at a station, boxed in by the robots parked there, cannot: the higher one,
    bound for the same station, planned to stop where the lower one stood or was stopping (the
    nearest free spot), and the lower one's solves were infeasible until it stood still: most
    of the fallbacks of 40 MPC robots on the fleet scenario (docs/mpc.md, "Queues")."""
    if goal is None:
        return False
    here = np.array([n.x, n.y])
    reach = max(np.max(np.abs(centres - here)), np.max(np.abs(stop - here)))
    end = centres[-1]
    return bool(reach <= SETTLING_M and math.hypot(end[0] - goal[0], end[1] - goal[1]) <= QUEUE_M)


#: How near (m) this robot's goal a lower robot's plan must end for it to count as ahead in
#: its queue (`ahead_in_queue`): 80 robots queued up to 6-9 m from a delivery point.
AHEAD_M = 8.0
#: The share of its plan's length by which a lower robot must close in on this robot's goal to
#: count as heading there (`ahead_in_queue`): within 45 degrees of it. A robot crossing this
#: one's way is not in its queue; it yields (tests/test_mpc_fleet.py).
HEADING = math.sqrt(0.5)


def ahead_in_queue(obs: Observation, n: Neighbour, centres: np.ndarray) -> bool:
    """Whether moving lower robot `n` is ahead of this one on the way to this one's goal: it is
    nearer the goal than this robot, its plan (`centres`) heads for the goal (it closes in on
    it by `HEADING` of its length) and ends within `AHEAD_M` of it.

    A higher robot keeps its course past a moving lower one, which yields; but one ahead of it
    in a queue to the same station can only yield backwards, into the higher one's way: at 80
    robots on the fleet scenario a stream of robots bound for printer_cell_in planned through
    the lower ones in front of them, which, boxed in between those plans and the robots ahead,
    had an infeasible solve (135 of the 198 fallbacks, seed 1). First come, first served."""
    goal = obs.goal
    if goal is None:
        return False
    gx, gy = goal
    mine = math.hypot(gx - obs.x, gy - obs.y)
    theirs = math.hypot(gx - n.x, gy - n.y)
    end = math.hypot(gx - centres[-1][0], gy - centres[-1][1])
    length = float(np.sum(np.hypot(*np.diff(centres, axis=0).T)))
    heading = length > 0.0 and theirs - end >= HEADING * length
    return bool(heading and theirs < mine and end <= AHEAD_M)


def shows_start(n: Neighbour) -> bool:
    """Whether `n`, at rest, shows a plan that sets it off (`start`: a lower robot shows its
    start a tick before it moves). `close` judges from velocities, which for such a robot say
    nothing of where it goes, so a higher robot keeps clear of its spot and its plan rather
    than keep its course (that planned through where the lower one stood, which then could
    not keep clear of that plan: 33 of the 121 fallbacks at 40 robots, `bench_fleet.py`)."""
    return max(abs(n.vx), abs(n.vy)) <= REST_SPEED and bool(n.plan)


def close(obs: Observation, n: Neighbour, spec: RobotSpec, half: float) -> bool:
    """Whether lower-priority robot `n` is close: should both robots keep their course for one
    more tick (each at its present velocity, its input then anything within the bound) and only
    then brake, their centres could come within `half` (between the samples too).

    A robot only sees another at its ticks, hence a tick for this one; the other, at this same
    tick, may re-plan against this one's last plan (not the one made now) before it brakes,
    hence a tick for it too (counting only its braking from now, a higher robot sped up towards
    a lower one that drove on one more tick: tests/test_mpc_contact.py). Braking runs along the
    line of travel, so a diagonal one runs up to sqrt(2) times as far as one along an axis at
    the same per-axis speed (`v_max` bounds each axis). `n` is assumed to have this robot's
    bounds (as for its braking path in `robots_to_avoid`)."""
    mine = _keep_course_paths(obs.x, obs.y, obs.vx, obs.vy, spec)
    theirs = _keep_course_paths(n.x, n.y, n.vx, n.vy, spec)
    # Far apart for any of these paths (each stays within its length of its start): not close.
    reach = _length(mine) + _length(theirs)
    if math.hypot(n.x - obs.x, n.y - obs.y) >= half + reach:
        return False
    k = max(mine.shape[1], theirs.shape[1])
    mine = np.concatenate([mine, np.repeat(mine[:, -1:], k - mine.shape[1], 1)], axis=1)
    theirs = np.concatenate([theirs, np.repeat(theirs[:, -1:], k - theirs.shape[1], 1)], axis=1)
    # Every pair of paths at once: their offsets (a, b, step, axis), nearest point per step.
    d = mine[:, None] - theirs[None, :]
    d0, step = d[:, :, :-1], np.diff(d, axis=2)
    length2 = np.einsum("abki,abki->abk", step, step)
    along = np.divide(
        -np.einsum("abki,abki->abk", d0, step), length2, out=np.zeros_like(length2),
        where=length2 > 0,
    )  # fmt: skip
    nearest = d0 + np.clip(along, 0.0, 1.0)[..., None] * step
    return bool(np.min(np.hypot(nearest[..., 0], nearest[..., 1])) < half)


def _keep_course_paths(x: float, y: float, vx: float, vy: float, spec: RobotSpec) -> np.ndarray:
    """Positions ``(5, K, 2)`` (from now, one per period, the last repeated) of a robot that
    keeps its course one tick, with no input or with an input at a corner of the bound, and
    then brakes along its line of travel until at rest (as `fallback.braking_path`: the
    fastest axis slows by ``a_max * period`` a period, the other in proportion)."""
    dt, a = spec.period, spec.a_max
    corners = np.array([[0.0, 0.0], [a, a], [a, -a], [-a, a], [-a, -a]])
    w = np.clip(np.array([vx, vy]) + dt * corners, -spec.v_max, spec.v_max)  # after the tick
    fastest = np.max(np.abs(w), axis=1)
    periods = int(np.ceil(np.max(fastest) / (a * dt) - 1e-12)) if np.max(fastest) > 0 else 0
    # The fastest axis's speed in each braking period, and the fraction of w it is.
    speeds = np.clip(fastest[:, None] - a * dt * np.arange(periods), 0.0, None)
    top = fastest[:, None]
    share = np.divide(speeds, top, out=np.zeros_like(speeds), where=top > 0)
    travel = dt * np.cumsum(share[:, :, None] * w[:, None, :], axis=1)
    start = np.array([x, y])
    after = start + dt * np.array([vx, vy])  # the next position does not depend on the input
    return np.concatenate(
        [np.tile(start, (5, 1, 1)), np.tile(after, (5, 1, 1)), after + travel], axis=1
    )


def _length(paths: np.ndarray) -> float:
    """The longest of `paths` ``(P, K, 2)``, along its steps."""
    steps = np.diff(paths, axis=1)
    return float(np.max(np.sum(np.hypot(steps[..., 0], steps[..., 1]), axis=1)))


#: Steps ahead in which a lower robot's plan that moves makes it rely on this one now: the
#: window a start from rest is shown in (`fleet_plugins.mpc.start`: steps 1 and 2).
SET_OFF_STEPS = 2


def must_hold(obs: Observation, spec: RobotSpec, horizon: int, margin: float) -> bool:
    """Whether a moving robot that this one outranks is `close` (their centres could come
    within ``r_i + r_j + margin``). Such a robot relies on this one's published plan or
    braking path: this one then only follows its plan (while `reuse.reusable_among`) or brakes,
    it does not re-plan.

    Moving: within the next two ticks (`SET_OFF_STEPS`). A robot at rest whose plan sets off
    later does not yet rely on this one: before it moves it solves again, and shows a start
    from rest a tick late (`fleet_plugins.mpc.start`), which holds this one then. Held for the
    whole horizon instead, this one stood on the other's way, which waited for it to leave
    (fuzz s73-0052: r08 planned round r02 from 2 s on at every solve; r02, sent aside for it,
    stood still for the last 90 s, both with jobs)."""
    window = min(horizon, SET_OFF_STEPS)
    for n in obs.neighbours:
        if not outranks(obs, n) or at_rest(predict(n, obs.t, spec.period, window)):
            continue
        if close(obs, n, spec, spec.radius + float(n.radius) + margin):
            return True
    return False


def must_announce(obs: Observation, spec: RobotSpec, margin: float) -> bool:
    """Whether this robot, at rest, must show a start from rest one tick before it moves: a
    robot that outranks it is `close` (why: `fleet_plugins.mpc.start`)."""
    if max(abs(obs.vx), abs(obs.vy)) > REST_SPEED:
        return False
    for n in obs.neighbours:
        if outranks(obs, n):
            continue
        if close(obs, n, spec, spec.radius + float(n.radius) + margin):
            return True
    return False


def brake_runs_into(
    obs: Observation, spec: RobotSpec, horizon: int, floor: Floor | None = None
) -> bool:
    """Whether braking along the line of travel would bring this robot into contact with a
    neighbour predicted at rest for the horizon, or with the plan or the braking path of a
    moving one that outranks it, between the samples too; or, given the
    `floor`, whether every brake of `fallback.free_brake` would leave its free space, or the
    one it takes break a zone's speed limit (`fallback.within_zones`). Such a
    robot may be held itself (`must_hold`: it only brakes, at rest it stays) and never give
    way, so a held robot solves instead (40 MPC robots on the fleet scenario: a higher robot
    whose plan curved round a robot held at rest braked straight on into it;
    tests/test_mpc_contact.py). A robot held in a door on a plan that turned there braked
    straight on, out of the free space, and never solved a feasible plan again (fuzz
    s31-0665: 270 fallbacks). So does one whose brake would cross into a slower zone faster
    than its limit: a brake knows no zones, and a robot held while heading for one entered it
    at 0.605 m/s against 0.52 (fuzz s21-0854)."""
    if max(abs(obs.vx), abs(obs.vy)) <= REST_SPEED:
        return False
    if leaves_floor(obs, spec, floor):
        return True
    dt = spec.period
    p = brake_after(obs.t, (obs.x, obs.y), (obs.vx, obs.vy), dt, spec.a_max, horizon)
    for n in obs.neighbours:
        centres = predict(n, obs.t, dt, horizon)
        reach = spec.radius + float(n.radius)
        if at_rest(centres):
            if closest_approach(p, centres) < reach:
                return True
        elif not outranks(obs, n):
            # A higher robot keeps its course or brakes, and counts on this one to keep clear
            # of both: so must this brake (found with a first version of the station queue:
            # three robots in a lane to one station, the middle one, held for the lowest,
            # braked into the way of the highest, which had stopped yielding to it to wait
            # its turn: 7 mm of contact).
            a_max = n.limits(spec).a_max
            theirs = brake_after(obs.t, (n.x, n.y), (n.vx, n.vy), dt, a_max, horizon)
            if min(closest_approach(p, centres), closest_approach(p, theirs)) < reach:
                return True
    return False


def paths_of(obs: Observation, n: Neighbour, spec: RobotSpec, horizon: int) -> list[np.ndarray]:
    """Where moving neighbour `n` may go, ``(horizon+1, 2)`` each from now: along its plan,
    braking along its line of travel now, or a tick on along its plan and braking from there
    (its velocity then taken as its input were constant over the tick: a double integrator,
    exact where its plan has a sample a tick on)."""
    dt, a_max = spec.period, n.limits(spec).a_max
    centres = predict(n, obs.t, dt, horizon)
    here, now = np.array([n.x, n.y]), np.array([n.vx, n.vy])
    later = np.clip(2.0 * (centres[1] - here) / dt - now, -spec.v_max, spec.v_max)
    return [
        centres,
        brake_after(obs.t, here, now, dt, a_max, horizon),
        np.vstack([here, brake_after(obs.t + dt, centres[1], later, dt, a_max, horizon - 1)]),
    ]


def brake_after(
    t: float,
    p: np.ndarray | tuple[float, float],
    v: np.ndarray | tuple[float, float],
    dt: float,
    a_max: float,
    steps: int,
) -> np.ndarray:
    """Positions ``(steps+1, 2)``, one a period from `t`, of braking along the line of travel
    from `p` at velocity `v` (`fallback.braking_path`), at rest once stopped."""
    path = braking_path(t, float(p[0]), float(p[1]), float(v[0]), float(v[1]), dt, a_max, steps)
    stop = np.asarray(path)[:, 1:]
    return np.vstack([stop, np.repeat(stop[-1:], steps + 1 - len(stop), axis=0)])


def clear_of_neighbours(obs: Observation, spec: RobotSpec, p: np.ndarray) -> bool:
    """Whether plan `p` (steps 0..N from now) keeps every neighbour's predicted disc out
    of its own from step 1 to step N, between the steps too (a fallback plan is checked
    before it is followed)."""
    for n in obs.neighbours:
        centres = predict(n, obs.t, spec.period, len(p) - 1)
        if closest_approach(p[1:], centres[1:]) < spec.radius + float(n.radius) - 1e-9:
            return False
    return True


def closest_approach(p: np.ndarray, q: np.ndarray) -> float:
    """The least distance between two robots moving in straight lines from sample to sample
    of `p` and `q` (``(K, 2)``, the same instants), between the samples too.

    Checking the samples alone lets two robots on one line pass through each other: head on
    at 1 m/s each and 0.5 s steps, each sample of one falls midway between two of the other,
    1.25 m apart, and the robots meet in between (found by the MPC fleet property test).
    """
    d = np.asarray(p, dtype=float) - np.asarray(q, dtype=float)  # their difference, per sample
    if len(d) == 1:
        return float(np.hypot(*d[0]))
    d0, step = d[:-1], np.diff(d, axis=0)
    length2 = np.einsum("ij,ij->i", step, step)
    # The point of each segment of the difference nearest the origin (clamped to the segment).
    s = np.divide(
        -np.einsum("ij,ij->i", d0, step), length2, out=np.zeros_like(length2), where=length2 > 0
    )
    nearest = d0 + np.clip(s, 0.0, 1.0)[:, None] * step
    return float(np.min(np.hypot(nearest[:, 0], nearest[:, 1])))


def outranks(obs: Observation, other: Neighbour) -> bool:
    """Whether the robot of `obs` goes before `other`: higher priority, or on a tie (an engine
    that sets none) the smaller robot id."""
    if obs.priority != other.priority:
        return obs.priority > other.priority
    return obs.robot < other.robot
