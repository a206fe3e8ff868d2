"""`PathPlanner`, the room's public face: paths and references for one robot on one floor, cached.

It builds the room's parts once per robot type and floor, and keeps their answers: the zones'
`SpeedLimits` (`fleet.paths.limits`), the `PortalGraph` that finds a path
(`fleet.paths.graph`), and the `Timing` that turns a path into a `Reference`
(`fleet.paths.timing`). Both caches are keyed on the start and goal rounded to `KEY_DECIMALS`
decimals, and planning uses the rounded points, so a cached answer is the answer.
"""

from __future__ import annotations

__all__ = ["PathPlanner", "CacheInfo"]

import functools
import math
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from fleet.errors import NoPathError
from fleet.floor.compiled import Floor
from fleet.paths.graph import XY, PortalGraph
from fleet.paths.limits import OVERLAP_TOL, SpeedLimits
from fleet.paths.results import Path, Reference, make_path
from fleet.paths.timing import Timing

#: Decimals kept of start and goal; planning uses the rounded points, so the cache is exact.
KEY_DECIMALS = 9
#: Goals whose cost-to-go `PathPlanner.estimate_time` keeps.
TO_GOAL_CACHE = 64


class CacheInfo(NamedTuple):
    """Hit and miss counts of the planner's two caches (each a `functools` cache info)."""

    path: functools._CacheInfo
    reference: functools._CacheInfo


class PathPlanner:
    """Paths and references for one robot type on one floor.

    The portal graph is built once here; queries are cached (LRU) on the start and goal rounded
    to `KEY_DECIMALS` decimals, and planning uses those rounded points, so a cached answer is the
    answer. Safe to share between threads (graph queries take a lock).

    Parameters
    ----------
    floor:
        The compiled floor.
    v_max:
        The robot's own per-axis speed limit (m/s), applied on top of the zone limits.
    a_max:
        The robot's per-axis acceleration bound (m/s^2).
    spacing:
        Wanted gap (m) between graph nodes along a portal (at most
        `fleet.paths.graph.MAX_PORTAL_NODES` per portal); the waypoints are then slid along
        their portals, so this mostly matters for which way around things the search goes.
    margin:
        Waypoints on a portal stay this far (m) from its end points, which are often obstacle
        corners: a small safety margin on top of the floor's clearance.
    cache_size:
        Entries kept in each of the path and reference caches.
    """

    def __init__(
        self,
        floor: Floor,
        v_max: float = 1.0,
        a_max: float = 0.5,
        *,
        spacing: float = 2.0,
        margin: float = 0.05,
        cache_size: int = 1024,
    ) -> None:
        for name, value in (("v_max", v_max), ("a_max", a_max), ("spacing", spacing)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"PathPlanner {name} must be a positive number, got {value!r}")
        if not (math.isfinite(margin) and margin >= 0):
            raise ValueError(f"PathPlanner margin must be >= 0, got {margin!r}")
        if not floor.regions:
            raise ValueError(f"floor {floor.name!r} ({floor.source}) has no free-space regions")
        self.floor = floor
        self.v_max = float(v_max)
        self.a_max = float(a_max)
        self.spacing = float(spacing)
        self.margin = float(margin)

        self._limits = SpeedLimits(floor, self.v_max)
        self._portal_graph = PortalGraph(floor, self._limits, self.spacing, self.margin)
        self._timing = Timing(self._limits, self.a_max)
        self._path_cached = functools.lru_cache(maxsize=cache_size)(self._portal_graph.find_path)
        self._ref_cached = functools.lru_cache(maxsize=cache_size)(self._plan_reference)
        # A few kB each (a time per graph node): goals asked about are mostly stations.
        self._to_goal_cached = functools.lru_cache(maxsize=TO_GOAL_CACHE)(
            self._portal_graph.cost_to_go
        )

    # -- public queries -----------------------------------------------------------------------
    def path(self, start: Sequence[float], goal: Sequence[float]) -> Path:
        """The fastest path found from `start` to `goal`.

        Raises
        ------
        NoPathError
            When the start or the goal is outside the free space, or no path joins them.
        """
        return self._path_cached(
            self._key(start, "start", start, goal), self._key(goal, "goal", start, goal)
        )

    def travel_time(self, start: Sequence[float], goal: Sequence[float]) -> float:
        """``path(start, goal).travel_time`` (cached)."""
        return self.path(start, goal).travel_time

    def estimate_time(self, start: Sequence[float], goal: Sequence[float]) -> float:
        """The fastest time (s) from `start` to `goal` over the portal graph, without refining
        the path: at least `travel_time`, and far cheaper for a goal asked about again (each
        goal's cost-to-go over the graph is cached). For ranking robots and jobs.

        Raises
        ------
        NoPathError
            As `path`.
        """
        s = self._key(start, "start", start, goal)
        g = self._key(goal, "goal", start, goal)
        return self._portal_graph.estimate_time(s, g, self._to_goal_cached(g))

    def reference(
        self, start: Sequence[float], goal: Sequence[float], dt: float, t0: float = 0.0
    ) -> Reference:
        """A reference from rest at `start` to rest at `goal`, sampled every `dt` from `t0`.

        Raises
        ------
        NoPathError
            As `path`.
        FleetError
            If no safe timing was found (a bug: the method always has a feasible fallback).
        """
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"reference dt must be a positive number of seconds, got {dt!r}")
        s = self._key(start, "start", start, goal)
        g = self._key(goal, "goal", start, goal)
        ref = self._ref_cached(s, g, float(dt))
        return ref if t0 == 0.0 else ref.shifted(t0)

    def reference_along(
        self, start: Sequence[float], waypoints: Sequence[Sequence[float]], dt: float, t0: float
    ) -> Reference:
        """A reference from rest at `start` through `waypoints` to rest at the last of them,
        sampled every `dt` from `t0`: the rest of an earlier path, driven again from where the
        robot stopped on it, without searching the graph (not cached).

        Raises
        ------
        NoPathError
            When a leg of ``start, *waypoints`` leaves the free space (or there is none).
        """
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"reference dt must be a positive number of seconds, got {dt!r}")
        if not waypoints:
            raise NoPathError(_safe(start), _safe(start), "no waypoints to drive along")
        goal = waypoints[-1]
        pts = [self._key(start, "start", start, goal)]
        for w in waypoints:
            q = self._key(w, "waypoint", start, goal)
            # No zero-length legs (as `find_path`): a stop right on a waypoint drops it.
            if math.hypot(q[0] - pts[-1][0], q[1] - pts[-1][1]) > OVERLAP_TOL:
                pts.append(q)
        if len(pts) == 1:
            pts.append(pts[0])
        total = 0.0
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            t = self._limits.segment_time(np.asarray(a), np.asarray(b))
            if t is None:
                raise NoPathError(
                    pts[0], pts[-1], f"leg {a} -> {b} leaves the free space of {self.floor.name!r}"
                )
            total += t
        ref = self._timing.reference(make_path(np.asarray(pts), total), float(dt))
        return ref if t0 == 0.0 else ref.shifted(t0)

    def speed_limit(self, p: Sequence[float], q: Sequence[float]) -> tuple[float, float] | None:
        """Per-axis limit (vx, vy) for a step along the segment ``p -> q``.

        The component-wise minimum of `v_max` over every region the segment overlaps with
        positive length (a point touch does not count), and of the robot's own `v_max`; None if
        the segment leaves the free space for more than `fleet.paths.limits.GAP_TOL` metres.
        For a zero-length segment, the regions containing the point count.
        """
        lim, ok = self._limits.of_segments(
            np.asarray([p], dtype=float), np.asarray([q], dtype=float)
        )
        if not ok[0]:
            return None
        return float(lim[0, 0]), float(lim[0, 1])

    def cache_info(self) -> CacheInfo:
        """Hits and misses of the path and reference caches."""
        return CacheInfo(self._path_cached.cache_info(), self._ref_cached.cache_info())

    def cache_clear(self) -> None:
        """Forget every cached path and reference."""
        self._path_cached.cache_clear()
        self._ref_cached.cache_clear()
        self._to_goal_cached.cache_clear()

    # -- the caches' keys and misses ----------------------------------------------------------
    def _key(self, point: Sequence[float], which: str, start, goal) -> XY:
        try:
            x, y = (float(c) for c in point)
        except (TypeError, ValueError):
            raise NoPathError(
                _safe(start), _safe(goal), f"{which} {point!r} is not an (x, y) point"
            ) from None
        if not (math.isfinite(x) and math.isfinite(y)):
            raise NoPathError(
                _safe(start), _safe(goal), f"{which} ({x}, {y}) is not a finite point"
            )
        return round(x, KEY_DECIMALS) + 0.0, round(y, KEY_DECIMALS) + 0.0

    def _plan_reference(self, start: XY, goal: XY, dt: float) -> Reference:
        """A reference cache miss: the path, through its own cache, timed."""
        return self._timing.reference(self._path_cached(start, goal), dt)


def _safe(point) -> tuple[float, float]:
    """A best-effort (x, y) for error messages about malformed points."""
    try:
        x, y = (float(c) for c in point)
        return x, y
    except (TypeError, ValueError):
        return (math.nan, math.nan)
