"""When a solve gives no usable plan: the previous plan one step on, or braking.

The previous plan ends at rest inside the regions it was planned in, so a run of fallbacks that
follow it (`follow_previous`) walks it down to a stop. Otherwise the robot brakes along its
line of travel (`brake`); with other robots about, the braking path is its plan
(`braking_path`), so that they avoid where it stops rather than where it was heading. Given
the floor, a braking path that would leave the free space (a robot skimming a wall at an angle)
is replaced by one that brakes the axes at other rates and stays in it (`BRAKE_RATES`); a
fallback's brake, likewise, by one that keeps clear of the other robots.
A usable plan that keeps the robot where it is, off its goal with nobody about but robots
standing still, is a trap of the same kind: `stays_put` tells the controller to plan a new trip.
"""

from __future__ import annotations

import functools
import itertools
import math
from collections.abc import Callable, Sequence

import numpy as np
import shapely
from shapely.geometry import LineString, Point
from shapely.geometry.base import BaseGeometry

from fleet.floor import BOUNDARY_BAND, Floor
from fleet.paths.limits import SpeedLimits
from fleet.plugins import (
    Command,
    ControlStatus,
    Neighbour,
    Observation,
    RobotSpec,
    SolveReport,
)
from fleet.plugins.robot import DoubleIntegrator, brake_input
from fleet_plugins.mpc.model import Solution

__all__ = [
    "REST_SPEED",
    "follow_previous",
    "shifted",
    "plan_points",
    "brake",
    "free_brake",
    "within_zones",
    "leaves_floor",
    "braking_path",
    "stays_put",
    "park",
]

#: Per-axis speed (m/s) below which the robot counts as at rest.
REST_SPEED = 1e-9
#: Fractions of a_max each axis may brake at when braking along the line of travel would leave
#: the free space: every pair with one axis at the full rate is tried, hardest first. A pair
#: kept from tick to tick follows the same path, so once one is found it stays available.
BRAKE_RATES = (1.0, 0.75, 0.5, 0.25)
_RATE_PAIRS = sorted(
    {(a, b) for a, b in itertools.product(BRAKE_RATES, repeat=2) if max(a, b) == 1.0},
    key=lambda r: (-(r[0] + r[1]), r),
)
#: Steps enough for any braking path to reach rest (checked to the end, not the horizon).
_TO_REST = 100_000
#: A plan whose every point is within this (m) of the robot keeps it where it is.
STILL_M = 1e-6
#: m/s: a braking step this little over a zone's limit is rounding (`within_zones`).
ZONE_TOL = 1e-9


def follow_previous(
    obs: Observation,
    last: Solution,
    dt: float,
    report: SolveReport | None,
    status: ControlStatus = ControlStatus.FALLBACK,
) -> tuple[Command, Solution]:
    """The previous plan's next input, as a command (FALLBACK unless `status` says otherwise)
    whose plan is the rest of it; and that plan moved one step on, to be followed again should
    the next solve fail too."""
    assert last.u is not None
    later = shifted(last)
    assert later.p is not None
    u = last.u[1]
    plan = plan_points(obs.t, later.p, dt)
    return Command(float(u[0]), float(u[1]), status, plan, report), later


def shifted(last: Solution) -> Solution:
    """`last` moved one step on: its last point repeated, at rest (no input)."""
    assert last.p is not None and last.v is not None
    assert last.u is not None and last.regions is not None
    return Solution(
        last.outcome,
        last.solver_s,
        p=np.vstack([last.p[1:], last.p[-1:]]),
        v=np.vstack([last.v[1:], np.zeros((1, 2))]),
        u=np.vstack([last.u[1:], np.zeros((1, 2))]),
        regions=np.concatenate([last.regions[1:], last.regions[-1:]]),
        objective=last.objective,
    )


def plan_points(t: float, p: np.ndarray, dt: float) -> tuple[tuple[float, float, float], ...]:
    """A plan's positions `p` (one per step from `t`) as a command's plan: (t, x, y) each."""
    return tuple((t + k * dt, float(p[k, 0]), float(p[k, 1])) for k in range(len(p)))


def park(obs: Observation, spec: RobotSpec, horizon: int) -> Command:
    """Stay at rest on the goal without a solve (the optimum there is to stay): the plan says
    the robot stays for the whole horizon, so others keep clear of it as of a parked robot. A
    speed left from the solver's tolerances is cancelled within the step."""
    dt = spec.period
    end = obs.t + horizon * dt
    plan = ((obs.t, obs.x, obs.y), (end, obs.x + dt * obs.vx, obs.y + dt * obs.vy))
    return Command(-obs.vx / dt + 0.0, -obs.vy / dt + 0.0, ControlStatus.OK, plan)


def brake(
    obs: Observation,
    spec: RobotSpec,
    horizon: int,
    status: ControlStatus,
    floor: Floor | None = None,
    clear: Callable[[np.ndarray], bool] | None = None,
) -> Command:
    """Brake along the line of travel; with other robots about, the braking path is the
    plan (else they would keep avoiding the last plan, which runs on past the stop), and at
    rest a plan that stays where it is (an empty plan leaves the last one in force: a robot
    held at rest went on being seen along its old plan, moving away, and a lower robot drove
    into where it stood, 0.73 m apart with radii 0.4, in the 80-robot fleet).

    Given the `floor`, a braking path that leaves its free space gives way to the first path
    braking the axes at `BRAKE_RATES` that stays in it (a robot held while skimming a wall
    at an angle braked straight on 0.6 mm into it, and stood there: fuzz s41-0109); with
    none, the robot brakes along its line of travel all the same. With `clear`, the brakes
    that keep clear of the other robots come first (`free_brake`).
    """
    if abs(obs.vx) <= REST_SPEED and abs(obs.vy) <= REST_SPEED:
        # A speed left from the solver's tolerances is cancelled within the step (as `park`
        # does): left alone it carried a robot across a region's edge over a minute (fuzz
        # s42-0010, -8.4e-10 m/s).
        dt = spec.period
        ax, ay = -obs.vx / dt + 0.0, -obs.vy / dt + 0.0
        if not obs.neighbours:
            return Command(ax, ay, status)
        end = obs.t + horizon * dt
        return Command(ax, ay, status, ((obs.t, obs.x, obs.y), (end, obs.x, obs.y)))
    found = free_brake(obs, spec, floor, clear)
    if found is None:  # none stays in: along the line of travel all the same
        dt, a_max = spec.period, spec.a_max
        path = braking_path(obs.t, obs.x, obs.y, obs.vx, obs.vy, dt, a_max, _TO_REST)
        found = (*brake_input(obs.vx, obs.vy, dt, a_max), path)
    ax, ay, path = found
    return Command(ax, ay, status, path[: horizon + 1] if obs.neighbours else ())


def free_brake(
    obs: Observation,
    spec: RobotSpec,
    floor: Floor | None,
    clear: Callable[[np.ndarray], bool] | None = None,
) -> tuple[float, float, tuple[tuple[float, float, float], ...]] | None:
    """The input of this tick and the path to rest of braking along the line of travel, or
    else of the first pair of `BRAKE_RATES` whose path stays in the `floor`'s free space (all
    checked to rest); None when none does. Without a floor, braking along the line of travel.

    Of those, the first that also keeps within the zones' limits (`within_zones`) comes first:
    a fallback brake straight on took a robot into a 0.4 m/s zone at 0.875 m/s (80 MPC robots
    on the fleet scenario, seed 1, r39 at 87 s), where braking both axes at the full rate
    stayed out of it.

    With `clear` (whether a path's positions ``(K, 2)`` keep clear of the other robots), a
    brake that keeps clear comes before any that does not, within the zones first: contact is
    the worse breach. A fallback brake straight on ran into a robot at rest (80 MPC robots,
    seed 2, r40 at 175.5 s: 0.7915 m, radii 0.4) where braking both axes at the full rate kept
    0.8276 m (tests/test_mpc_recover.py).
    """
    dt, a_max = spec.period, spec.a_max
    path = braking_path(obs.t, obs.x, obs.y, obs.vx, obs.vy, dt, a_max, _TO_REST)
    straight = (*brake_input(obs.vx, obs.vy, dt, a_max), path)
    if floor is None and clear is None:
        return straight
    # The best kind of brake found so far: (clear, within the zones), the first of each kind.
    best, rank = None, (False, False)
    for rates in (None, *_RATE_PAIRS):
        if rates is None:
            found = straight
        else:
            other = braking_path(obs.t, obs.x, obs.y, obs.vx, obs.vy, dt, a_max, _TO_REST, rates)
            found = (*_axis_brake(obs.vx, obs.vy, dt, a_max, rates), other)
        if floor is not None and not _stays_free(floor, found[2]):
            continue
        zones = floor is None or within_zones(floor, spec, found[2])
        here = (clear is None or clear(np.array([q[1:] for q in found[2]])), zones)
        if best is None or here > rank:
            best, rank = found, here
        if rank == (True, True):
            break
    return best


def stays_put(
    obs: Observation,
    p: np.ndarray,
    goal: tuple[float, float],
    radius: float,
    trip_start: np.ndarray | None = None,
) -> bool:
    """Whether plan `p` (``(N+1, 2)``) keeps the robot, at rest more than `radius` from its
    `goal` with every robot in sight standing still (at rest, its plan too) and no print cap
    holding it, where it is over this tick (its first input is nil: ``p[0] = p[1] = p[2]``).
    Nothing changes such a tick's solve, so it would stay for good (fuzz s41-0086: a robot
    pushed off its reference to the edge of a region from which the regions round its
    reference led nowhere within the horizon stood still, every solve optimal, for the last
    90 s): the caller plans a new trip from where the robot is. A plan that sets off only later
    is such a wait too: followed for a few ticks and solved again alike, it never set off
    (fuzz s91-0759: 3.3 m off its reference, the last 90 s of the run, each plan waiting 4
    steps or more). A robot standing still in sight is no reason to wait either (fuzz
    s51-0144: 100 s at a region's edge, 1.2 m off its reference, an idle robot 3.1 m away);
    one that moves may be, and so may one that stands where a trip planned from here (the
    trip's reference starts at `trip_start`) still stays: another would be the same."""
    if max(abs(obs.vx), abs(obs.vy)) > REST_SPEED:
        return False
    if any(not _standing(n) for n in obs.neighbours):
        return False
    if obs.neighbours and trip_start is not None and _within(trip_start, obs.x, obs.y):
        return False
    if obs.speed_cap is not None and obs.speed_cap <= 0.0:
        return False
    if math.hypot(goal[0] - obs.x, goal[1] - obs.y) <= radius:
        return False
    return bool(np.all(np.abs(np.asarray(p)[:3] - np.array([obs.x, obs.y])) <= STILL_M))


def _standing(n: Neighbour) -> bool:
    """Whether neighbour `n` is at rest and its plan (if any) keeps it where it is."""
    if max(abs(n.vx), abs(n.vy)) > REST_SPEED:
        return False
    return all(_within((x, y), n.x, n.y) for _, x, y in n.plan)


def _within(point: Sequence[float] | np.ndarray, x: float, y: float) -> bool:
    return abs(point[0] - x) <= STILL_M and abs(point[1] - y) <= STILL_M


def braking_path(
    t: float,
    x: float,
    y: float,
    vx: float,
    vy: float,
    dt: float,
    a_max: float,
    steps: int,
    rates: tuple[float, float] | None = None,
) -> tuple[tuple[float, float, float], ...]:
    """Samples ``(t, x, y)`` of braking along the line of travel until at rest (at most
    `steps` periods; a neighbour is assumed to brake as hard as this robot can); with
    `rates`, each axis brakes on its own at that fraction of `a_max`."""
    robot = DoubleIntegrator(dt, a_max)
    out = [(t, x, y)]
    for k in range(1, steps + 1):
        if rates is None:
            ax, ay = brake_input(vx, vy, dt, a_max)
        else:
            ax, ay = _axis_brake(vx, vy, dt, a_max, rates)
        x, y, vx, vy = robot.step(x, y, vx, vy, ax, ay)
        out.append((t + k * dt, x, y))
        if abs(vx) <= REST_SPEED and abs(vy) <= REST_SPEED:
            break
    return tuple(out)


def _axis_brake(
    vx: float, vy: float, dt: float, a_max: float, rates: tuple[float, float]
) -> tuple[float, float]:
    """Each axis braked on its own at its fraction of `a_max`, to rest and not past it."""
    bx, by = rates[0] * a_max, rates[1] * a_max
    return math.copysign(min(abs(vx) / dt, bx), -vx), math.copysign(min(abs(vy) / dt, by), -vy)


def _stays_free(floor: Floor, path: tuple[tuple[float, float, float], ...]) -> bool:
    """Whether the robot's centre stays in the floor's free space along `path`, within the
    band the safety checker allows (a robot skimming a wall stands on its edge)."""
    xy = [(x, y) for _, x, y in path]
    shape = Point(xy[0]) if len(xy) == 1 else LineString(xy)
    return bool(shapely.covers(_free_within_band(floor), shape))


def within_zones(
    floor: Floor, spec: RobotSpec, path: tuple[tuple[float, float, float], ...]
) -> bool:
    """Whether every step of `path` (samples ``(t, x, y)`` one period apart) keeps, on each
    axis, within the speed limit of every region it overlaps and the robot's own."""
    if len(path) < 2:
        return True
    xy = np.array([(x, y) for _, x, y in path], dtype=float)
    v = np.abs(np.diff(xy, axis=0)) / spec.period
    lim, _ = _limits(floor, spec.v_max).of_segments(xy[:-1], xy[1:])
    return bool(np.all(v <= lim + ZONE_TOL))


def leaves_floor(obs: Observation, spec: RobotSpec, floor: Floor | None) -> bool:
    """Whether braking from `obs` would leave the `floor`: every brake of `free_brake` leaves
    its free space, or the one `brake` takes breaks a zone's speed limit (`within_zones`).
    False at rest or without a floor (nothing is known of walls or zones then)."""
    if floor is None or max(abs(obs.vx), abs(obs.vy)) <= REST_SPEED:
        return False
    found = free_brake(obs, spec, floor)
    return found is None or not within_zones(floor, spec, found[2])


@functools.lru_cache(maxsize=8)
def _limits(floor: Floor, v_max: float) -> SpeedLimits:
    """The floor's zone limits for a robot of `v_max` (made once per floor and speed)."""
    return SpeedLimits(floor, v_max)


@functools.lru_cache(maxsize=8)
def _free_within_band(floor: Floor) -> BaseGeometry:
    """The floor's free space grown by `BOUNDARY_BAND` (made once per floor)."""
    free = floor.free_space.buffer(BOUNDARY_BAND, join_style="mitre")
    shapely.prepare(free)
    return free
