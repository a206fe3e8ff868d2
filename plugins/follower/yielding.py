"""The follower's safety layer around other robots: forecasts, stopping checks, yielding, detours.

Three pieces, each usable on its own (`guard.Guard` strings them together):

- `Forecast`: where a neighbour's centre can be at a future time. A neighbour with a plan is
  on its plan (linear between samples, from its current position to the first sample; after
  the last sample it stays there), or, since it may brake at any tick, anywhere between
  there and its braking trajectory. One without a plan is somewhere on the segment from its
  position to where it would stop after one more step (`reach`), plus the drift one step of
  unknown acceleration adds: it brakes too, so that is as far as it gets.
- `braking_path` and `stops_clear`: rule 1, the robot may send a command only if, after it,
  full braking along the line of travel keeps clear of every neighbour's forecast.
- `must_yield`: rule 2, a lower-priority robot waits while a higher one's plan comes near its
  own path before (or when) the robot itself would be there.
- `Detour`: rule 3, a floor and planners with deadlocked blockers as temporary obstacles.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

import shapely
from shapely.geometry import Polygon

from fleet.floor import Floor, convex_pieces
from fleet.floor.build import GRID
from fleet.paths import PathPlanner
from fleet.plugins import Neighbour, RobotSpec
from fleet.plugins.robot import brake_input, stray_between, unseen_step

__all__ = [
    "DEFAULT_MARGIN_M",
    "unseen_step",
    "DEFAULT_YIELD_S",
    "Sample",
    "Forecast",
    "braking_path",
    "stops_clear",
    "must_yield",
    "behind",
    "bounds",
    "Detour",
]

#: Default gap (m) kept between two robots' footprints on top of the sum of their radii.
DEFAULT_MARGIN_M = 0.1
#: Default look-ahead (s), beyond its own braking time, over which a robot yields.
DEFAULT_YIELD_S = 2.0

#: A trajectory sample: time (s), x, y (m).
Sample = tuple[float, float, float]

_REST = 1e-9  # per-axis speed (m/s) that counts as at rest
_PARKED = 1e-6  # m: a plan that moves less than this over the yield window stands still
_MAX_BRAKE_STEPS = 10_000  # a guard only: braking from any finite speed ends long before
#: m: a neighbour this much further than the gap from a path's bounding box is out of reach
#: for sure (the distances measured round by far less: a few 1e-14 m on a floor of 100 m).
_SURE_M = 1e-6


def braking_path(
    t: float, x: float, y: float, vx: float, vy: float, dt: float, a_max: float
) -> list[Sample]:
    """Samples of full braking along the line of travel from state (x, y, vx, vy) at time `t`.

    Starts with ``(t, x, y)`` and applies `fleet.plugins.robot.brake_input` each step (the double
    integrator: the position moves with the velocity held over the step) until the robot is at
    rest; the last sample is where it stops.
    """
    out = [(t, x, y)]
    for _ in range(_MAX_BRAKE_STEPS):
        if abs(vx) <= _REST and abs(vy) <= _REST:
            break
        bx, by = brake_input(vx, vy, dt, a_max)
        t, x, y = t + dt, x + dt * vx, y + dt * vy
        vx, vy = vx + dt * bx, vy + dt * by
        out.append((t, x, y))
    return out


@dataclass(frozen=True, slots=True)
class Forecast:
    """Where one neighbour's centre can be from the observation's time on.

    Build it with `Forecast.of`. `samples` is the neighbour's plan from its current position on
    (empty without a plan); `brake` is where it would be if it braked now instead, from its
    position now on (a robot may give up its plan at any tick and brake, as this layer does;
    starting later, it lies between the two). A neighbour without a plan lies anywhere on the
    segment `reach` (``(x0, y0, x1, y1)``: from its position to where one more step and then
    braking take it) grown by `slack` metres. One with a plan decides in the same tick as the
    observer, and the command it sends then can take it `lead` metres off what it planned
    before the observer sees the new plan (`stops_clear` adds it to the gap). `box` is
    ``(x_min, y_min, x_max, y_max)`` of every point the forecast can name (`Forecast.of` sets
    it; None: worked out when asked, `Forecast.bounds`): the checks pass over a neighbour out
    of reach.
    """

    robot: str
    radius: float
    priority: int
    x: float
    y: float
    samples: tuple[Sample, ...] = ()
    brake: tuple[Sample, ...] = ()
    reach: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)
    slack: float = 0.0
    lead: float = 0.0
    box: tuple[float, float, float, float] | None = None

    @classmethod
    def of(
        cls, n: Neighbour, t: float, dt: float, a_max: float, v_max: float = math.inf
    ) -> Forecast:
        """The forecast of neighbour `n` seen at time `t` by a robot of period `dt`,
        acceleration bound `a_max` and speed bound `v_max`. The neighbour brakes, and strays
        unseen (`stray_between`), by its own limits where the observation gives them
        (`Neighbour.limits`; a fleet may mix robots), by the observer's where not."""
        own = RobotSpec(v_max, a_max, n.radius, dt)
        theirs = n.limits(own)
        slack = stray_between(own, theirs)
        dt, a_max = theirs.period, theirs.a_max
        if n.plan:
            # Its plan from where it is now (a plan that has ended holds it where it is). The
            # command it sends in this same tick (setting off from rest, say) is not in that
            # plan yet: `lead`.
            future = [(float(a), float(b), float(c)) for a, b, c in n.plan if a > t + 1e-9]
            samples = ((t, n.x, n.y), *future)
            # It may brake in this same tick too: braking from the next tick on instead ends
            # one step further, and a robot behind it counting on that came too close.
            now = tuple(braking_path(t, n.x, n.y, n.vx, n.vy, dt, a_max))
            box = bounds(samples + now)
            return cls(n.robot, n.radius, n.priority, n.x, n.y, samples, now, lead=slack, box=box)
        # No plan: one more step at its velocity, then braking (it brakes too), plus the slack.
        brake = braking_path(t + dt, n.x + dt * n.vx, n.y + dt * n.vy, n.vx, n.vy, dt, a_max)
        reach = (n.x, n.y, brake[-1][1], brake[-1][2])
        box = (min(n.x, reach[2]), min(n.y, reach[3]), max(n.x, reach[2]), max(n.y, reach[3]))
        return cls(n.robot, n.radius, n.priority, n.x, n.y, (), (), reach, slack, box=box)

    def bounds(self) -> tuple[float, float, float, float]:
        """``(x_min, y_min, x_max, y_max)`` of every point `at` and `distance` measure from:
        the plan's and the braking samples, or the `reach` segment (without its `slack`)."""
        if self.box is not None:
            return self.box
        if self.samples:
            return bounds(self.samples + self.brake)
        x0, y0, x1, y1 = self.reach
        return min(x0, x1), min(y0, y1), max(x0, x1), max(y0, y1)

    @property
    def has_plan(self) -> bool:
        """Whether the neighbour sent a plan (one that has ended holds it where it is)."""
        return bool(self.samples)

    def at(self, t: float) -> tuple[float, float]:
        """The neighbour's planned position at time `t` (its current one without a plan)."""
        return _along_samples(self.samples, t) if self.samples else (self.x, self.y)

    def distance(self, t: float, x: float, y: float) -> float:
        """Distance (m) from (x, y) to the nearest place the neighbour's centre can be at `t`:
        on its plan, braking now, or in between."""
        if self.samples:
            px, py = _along_samples(self.samples, t)
            if t <= self.brake[0][0]:
                return math.hypot(x - px, y - py)
            bx, by = _along_samples(self.brake, t)
            return _to_segment(x, y, px, py, bx, by)
        x0, y0, x1, y1 = self.reach
        return max(_to_segment(x, y, x0, y0, x1, y1) - self.slack, 0.0)


def stops_clear(
    path: Sequence[Sample],
    forecasts: Sequence[Forecast],
    radius: float,
    margin: float,
    now: tuple[float, float, float],
    gaps: Mapping[str, float] | None = None,
    *,
    prune: bool = True,
) -> bool:
    """Rule 1: whether braking trajectory `path` keeps clear of every neighbour.

    Clear means more than ``radius + n.radius + margin`` plus the neighbour's `Forecast.lead`
    (or ``gaps[n.robot]``, for lower-priority robots the caller routes round) from each forecast
    at every sample: the neighbour's command of this tick is not in its plan yet, and one step
    of it can close the gap by the lead before the next tick shows it (a few centimetres at a
    period of 0.25 s, 0.7 m at 1 s; without it followers collided at coarse periods). A
    neighbour already closer than that (robots start close, or two set off in the same tick)
    is kept from coming any closer:
    the path may not move towards its current position at all (no sample behind the line
    through ``now = (t, x, y)`` square to the direction away from it). Two robots that both keep
    this rule never close in, whatever they do at the same time, and a robot can always move
    away.

    With `prune` (the default) a neighbour whose `Forecast.bounds` lie further than the gap
    from the path's on some axis is passed over without measuring each sample: no distance
    measured could be within the gap (`_SURE_M` covers the rounding), so the answer is the
    same as without.
    """
    _, x, y = now
    box = bounds(path) if prune and path else None
    for f in forecasts:
        if gaps is not None and f.robot in gaps:
            # Lower in priority and closer than its own gap plus lead, it keeps the half-plane
            # rule below towards this robot: its move of this tick cannot come closer.
            need = gaps[f.robot]
        else:
            need = radius + f.radius + margin + f.lead
        ux, uy = x - f.x, y - f.y
        if ux * ux + uy * uy < need * need:
            for _, sx, sy in path:
                if (sx - x) * ux + (sy - y) * uy < -1e-12:
                    return False
            continue
        if box is not None and _apart(box, f.bounds()) > need + f.slack + _SURE_M:
            continue
        for ts, sx, sy in path:
            if f.distance(ts, sx, sy) <= need:
                return False
    return True


def must_yield(
    own: Sequence[Sample],
    higher: Forecast,
    gap: float,
    own_box: tuple[float, float, float, float] | None = None,
    *,
    prune: bool = True,
) -> bool:
    """Rule 2: whether a robot should wait for the higher-priority neighbour `higher`.

    `own` is the robot's intended trajectory over the yield window (its path if it goes on,
    samples at its control period, from now); the neighbour's plan is sampled at the same
    times. The robot yields when the plan comes within `gap` metres of a point of its path at
    or before the time the robot would be there: the neighbour would reach that spot first (a
    crossing, or a robot ahead).

    Two cases are left to rule 1 (no yield): a neighbour that reaches the robot's path only
    after the robot has been there, or stands behind it now (`behind`), comes from behind,
    and waiting would only put the robot in its way; and a neighbour whose plan stands still
    over the whole window is parked, and waiting at a distance for it would hide the deadlock
    from the engine, which looks for robots stuck close together.

    With `prune` (the default) a plan whose `Forecast.bounds` lie further than `gap` from
    those of `own` (`own_box`, worked out when None) on some axis is no reason to yield,
    without sampling it: the same answer as sampling.
    """
    if not higher.has_plan:
        return False
    if prune and own:
        box = own_box if own_box is not None else bounds(own)
        if _apart(box, higher.bounds()) > gap + _SURE_M:
            return False
    if behind(own, higher):
        return False
    theirs = [higher.at(t) for t, _, _ in own]
    x0, y0 = theirs[0]
    if all(abs(x - x0) <= _PARKED and abs(y - y0) <= _PARKED for x, y in theirs):
        return False
    g2 = gap * gap
    for i, (_, ax, ay) in enumerate(own):
        for qx, qy in theirs[: i + 1]:
            if (ax - qx) ** 2 + (ay - qy) ** 2 < g2:
                return True
    return False


def behind(own: Sequence[Sample], other: Forecast) -> bool:
    """Whether neighbour `other` stands behind the robot: on the far side of the line through
    the start of `own` (the robot's path ahead) square to the way it sets off in (False when
    `own` stands still). Its plan then follows the robot's path, and in a row of robots as
    close as the gap (they set off together) every such plan came within the gap: the one
    ahead waited for the one behind, which could not come closer to it (fuzz s21-0998: both
    crept at 2 cm/s for 100 s)."""
    _, x0, y0 = own[0]
    for _, x, y in own[1:]:
        ux, uy = x - x0, y - y0
        if ux * ux + uy * uy > 1e-12:
            return (other.x - x0) * ux + (other.y - y0) * uy < 0.0
    return False


@dataclass
class Detour:
    """Planning round deadlocked robots (rule 3): each blocker becomes a temporary obstacle.

    Each blocker ``(name, x, y, radius)`` becomes a regular polygon of `SIDES` sides around its
    centre whose inradius in the configuration space (the map's clearance added) is
    ``radius + own_radius + margin``, shrunk where needed so that the robot's own position
    `start` stays outside (robots stuck together are closer than that). The floor is compiled
    once, cutting the blockers out of the regions they touch (`_carve`), and a planner is built
    per speed cap. Build once per distinct set of blockers: on the shop floor (100 regions) the
    cut takes 20 to 50 ms and the planner 110 to 175 ms, its first reference 10 to 40 ms.

    Attributes
    ----------
    key:
        The blockers' names, sorted: which deadlock this detour answers.
    clearance:
        Per blocker, the distance (m) its obstacle keeps the robot's centre from the blocker's
        centre: what rule 1 may then hold the robot to against that blocker.
    floor:
        The floor with the blockers as obstacles; None when nothing of it is left.
    """

    SIDES: ClassVar[int] = 16

    key: tuple[str, ...]
    clearance: dict[str, float]
    floor: Floor | None
    a_max: float
    planners: dict[float, PathPlanner] = field(default_factory=dict)

    @classmethod
    def build(
        cls,
        base: Floor,
        blockers: Sequence[tuple[str, float, float, float]],
        own_radius: float,
        margin: float,
        start: tuple[float, float],
        a_max: float,
    ) -> Detour:
        """The detour for a robot at `start` of radius `own_radius` round `blockers` on `base`,
        keeping `margin` metres between footprints where it can."""
        clearance = {}
        holes = []
        shrink = math.cos(math.pi / cls.SIDES)  # inradius / circumradius
        for name, x, y, radius in blockers:
            d = math.hypot(start[0] - x, start[1] - y)
            inradius = max(min(own_radius + radius + margin, d * shrink - 1e-3), 1e-3)
            clearance[name] = inradius
            holes.append(_polygon(x, y, inradius, cls.SIDES))
        return cls(tuple(sorted(clearance)), clearance, _carve(base, holes), a_max)

    def planner(self, v_max: float) -> PathPlanner | None:
        """The planner for a robot of speed `v_max` on the detour floor (None: no floor)."""
        if self.floor is None or not self.floor.regions:
            return None
        if v_max not in self.planners:
            self.planners[v_max] = PathPlanner(self.floor, v_max=v_max, a_max=self.a_max)
        return self.planners[v_max]


def _carve(base: Floor, holes: Sequence[Polygon]) -> Floor | None:
    """`base` with `holes` (configuration-space shapes) cut out of its free space.

    Only the regions the holes touch are cut and split again into convex pieces (on the floor
    compiler's grid, so shared edges stay shared); the others are kept as they are, which makes
    this several times cheaper than compiling the floor again. None when nothing is left.
    """
    hole = shapely.union_all(holes, grid_size=GRID)
    pieces = []
    for r in base.regions:
        if not r.polygon.intersects(hole):
            pieces.append((r.polygon, r.v_max, r.zone))
            continue
        rest = shapely.difference(r.polygon, hole, grid_size=GRID)
        pieces.extend((piece, r.v_max, r.zone) for piece in convex_pieces(rest))
    return Floor.from_regions(base.spec, pieces) if pieces else None


def _polygon(x: float, y: float, inradius: float, sides: int) -> Polygon:
    """The regular polygon with `sides` sides around (x, y) whose edges touch the circle of
    radius `inradius`."""
    corner = inradius / math.cos(math.pi / sides)
    step = 2.0 * math.pi / sides
    return Polygon(
        [
            (x + corner * math.cos((k + 0.5) * step), y + corner * math.sin((k + 0.5) * step))
            for k in range(sides)
        ]
    )


def _along_samples(s: Sequence[Sample], t: float) -> tuple[float, float]:
    """The position at time `t` on samples `s`: linear between them, held outside them."""
    if t <= s[0][0]:
        return s[0][1], s[0][2]
    for (t0, x0, y0), (t1, x1, y1) in zip(s[:-1], s[1:], strict=True):
        if t <= t1:
            f = (t - t0) / (t1 - t0) if t1 > t0 else 1.0
            return x0 + f * (x1 - x0), y0 + f * (y1 - y0)
    return s[-1][1], s[-1][2]


def bounds(samples: Sequence[Sample]) -> tuple[float, float, float, float]:
    """``(x_min, y_min, x_max, y_max)`` of `samples` (not empty)."""
    xs = [p[1] for p in samples]
    ys = [p[2] for p in samples]
    return min(xs), min(ys), max(xs), max(ys)


def _apart(a: tuple[float, float, float, float], b: tuple[float, float, float, float]) -> float:
    """How far apart boxes `a` and `b` lie on the axis where they lie furthest (<= 0 when
    they overlap): no point of one is closer than that to a point of the other."""
    return max(b[0] - a[2], a[0] - b[2], b[1] - a[3], a[1] - b[3])


def _to_segment(px: float, py: float, x0: float, y0: float, x1: float, y1: float) -> float:
    dx, dy = x1 - x0, y1 - y0
    L2 = dx * dx + dy * dy
    f = 0.0 if L2 == 0.0 else min(max(((px - x0) * dx + (py - y0) * dy) / L2, 0.0), 1.0)
    return math.hypot(px - x0 - f * dx, py - y0 - f * dy)
