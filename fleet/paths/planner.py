"""Reference paths on a compiled floor, and time-parameterised references that robots track.

Two layers, both cached per planner:

- `PathPlanner.path` finds a fast collision-free polyline: A* (networkx) over a static graph of
  points on the portals between convex regions, then string pulling and sliding each waypoint
  along its portal. Leg costs are travel times at each stretch's per-axis speed limit, so a path
  may go around a slow zone when that is quicker.
- `PathPlanner.reference` turns that polyline into a `Reference`: samples of the paper's discrete
  double integrator (``p[k+1] = p[k] + dt*v[k]``) from rest at the start to rest at the goal.
  Every corner and every speed-limit change falls exactly on a sample (very short stretches are
  merged into their slower neighbour, which is conservative), and a HiGHS LP picks the speeds,
  so the reference meets the project's step semantics exactly: each step's chord stays in
  the free space, every axis of ``v[k]`` respects the lowest limit of every region the chord
  overlaps with positive length, and ``|v[k+1] - v[k]| <= a_max*dt`` per axis.
"""

from __future__ import annotations

__all__ = ["PathPlanner", "CacheInfo"]

import functools
import math
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import highspy
import networkx as nx
import numpy as np
from shapely.geometry import Point
from shapely.ops import nearest_points

from fleet.errors import FleetError, NoPathError
from fleet.floor.compiled import Floor
from fleet.highs import SolverError, new_highs, solve
from fleet.paths.limits import (
    ON_LINE_TOL,
    OVERLAP_TOL,
    SpeedLimits,
    speed_along,
    speeds_along,
    speeds_along_rows,
)
from fleet.paths.results import Path, Reference, make_path, make_reference

CHECK_TOL = 1e-9
#: Relative tightening of the LP's bounds, so the solver's own tolerance can never show.
LP_MARGIN = 1e-7
#: Decimals kept of start and goal; planning uses the rounded points, so the cache is exact.
KEY_DECIMALS = 9
#: Most graph nodes on one portal (its two inset ends, its midpoint and evenly spaced points).
MAX_PORTAL_NODES = 7
#: Sweeps of sliding the path's waypoints along their portals after the graph search.
REFINE_SWEEPS = 3
#: Length (m) to which a waypoint's place on its portal is refined.
REFINE_RESOLUTION = 1e-3
#: Above this many steps the speed LP's second phase (calmest speeds) is skipped.
CALM_MAX_STEPS = 4000
#: Rounds of adding steps to pieces the speed LP cannot cover before stopping at every corner.
MAX_ROUNDS = 8

XY = tuple[float, float]


class CacheInfo(NamedTuple):
    """Hit and miss counts of the planner's two caches (each a `functools` cache info)."""

    path: functools._CacheInfo
    reference: functools._CacheInfo


# -- the planner ------------------------------------------------------------------------------
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
        Wanted gap (m) between graph nodes along a portal (at most `MAX_PORTAL_NODES` per
        portal); the waypoints are then slid along their portals, so this mostly matters for
        which way around things the search goes.
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

        regions = floor.regions
        self._limits = SpeedLimits(floor, self.v_max)
        # Fastest possible speed along any direction: keeps the A* heuristic admissible.
        self._top_speed = float(
            np.max(np.hypot(self._limits.per_region[:, 0], self._limits.per_region[:, 1]))
        )
        self._component = np.zeros(len(regions), dtype=np.intp)
        for c, members in enumerate(nx.connected_components(floor.graph)):
            self._component[list(members)] = c

        self._lock = threading.Lock()
        self._pos, self._region_nodes, self._graph = self._build_graph()
        self._path_cached = functools.lru_cache(maxsize=cache_size)(self._plan_path)
        self._ref_cached = functools.lru_cache(maxsize=cache_size)(self._plan_reference)

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

    def speed_limit(self, p: Sequence[float], q: Sequence[float]) -> tuple[float, float] | None:
        """Per-axis limit (vx, vy) for a step along the segment ``p -> q``.

        The component-wise minimum of `v_max` over every region the segment overlaps with
        positive length (a point touch does not count), and of the robot's own `v_max`; None if
        the segment leaves the free space for more than `GAP_TOL` metres. For a zero-length
        segment, the regions containing the point count.
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

    # -- geometry on the H-representation -----------------------------------------------------
    # -- the portal graph ---------------------------------------------------------------------
    def _portal_offsets(self, length: float) -> np.ndarray:
        """Node positions (m from one end) on a portal: its inset ends, its midpoint and evenly
        spaced points in between; just the midpoint on a portal shorter than two margins."""
        usable = length - 2.0 * self.margin
        if usable <= OVERLAP_TOL:
            return np.array([0.5 * length])
        n = min(math.ceil(usable / self.spacing) + 1, MAX_PORTAL_NODES)
        n = max(n + 1 - n % 2, 3)  # odd, so the midpoint is a node
        return np.linspace(self.margin, length - self.margin, n)

    def _build_graph(self) -> tuple[np.ndarray, list[list[int]], nx.Graph]:
        floor = self.floor
        pos: list[np.ndarray] = []
        portal_of: list[int] = []
        region_nodes: list[list[int]] = [[] for _ in floor.regions]
        spans = []  # per portal: the stretch its waypoints may slide along
        for pid, (i, j, data) in enumerate(floor.graph.edges(data=True)):
            coords = np.asarray(data["portal"].coords, dtype=float)
            a, b = coords[0], coords[-1]
            length = float(np.hypot(*(b - a)))
            offsets = self._portal_offsets(length) if length > OVERLAP_TOL else np.array([])
            ends = offsets[[0, -1]] if len(offsets) else np.zeros(2)
            spans.append(
                (
                    a + (b - a) * (ends[0] / max(length, 1e-300)),
                    a + (b - a) * (ends[1] / max(length, 1e-300)),
                )
            )
            for t in offsets:
                k = len(pos)
                pos.append(a + (b - a) * (t / length))
                portal_of.append(pid)
                region_nodes[i].append(k)
                region_nodes[j].append(k)
        pos_arr = np.asarray(pos, dtype=float).reshape(-1, 2)
        portal_arr = np.asarray(portal_of, dtype=np.intp)
        self._portal_of = portal_arr
        self._portal_span = spans
        g = nx.Graph()
        g.add_nodes_from(range(len(pos_arr)))
        for r in floor.regions:
            ids = np.asarray(region_nodes[r.index], dtype=np.intp)
            if len(ids) < 2:
                continue
            iu, ju = np.triu_indices(len(ids), 1)
            keep = portal_arr[ids[iu]] != portal_arr[ids[ju]]
            iu, ju = iu[keep], ju[keep]
            P = pos_arr[ids]
            d = P[ju] - P[iu]
            L = np.hypot(d[:, 0], d[:, 1])
            on = np.abs(r.A @ P.T - r.b[:, None]) <= ON_LINE_TOL  # (rows, nodes)
            along_edge = (on[:, iu] & on[:, ju]).any(axis=0)
            # A chord between two portals that is not on a boundary line is inside the convex
            # region, so only this region's limit applies; chords along a boundary line may
            # overlap neighbours (or leave the free space) and get the exact treatment.
            u = d / np.where(L > 0, L, 1.0)[:, None]
            w = L / speeds_along(self._limits.per_region[r.index], u)
            edges = []
            for m in range(len(iu)):
                a, b = int(ids[iu[m]]), int(ids[ju[m]])
                weight: float | None = float(w[m])
                if along_edge[m]:
                    weight = self._limits.segment_time(pos_arr[a], pos_arr[b])
                if weight is None or L[m] <= 0:
                    continue
                old = g.get_edge_data(a, b)
                if old is None or old["weight"] > weight:
                    edges.append((a, b, weight))
            g.add_weighted_edges_from(edges)
        return pos_arr, region_nodes, g

    # -- planning -----------------------------------------------------------------------------
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

    def _regions_at(self, p: XY, which: str, start: XY, goal: XY) -> np.ndarray:
        P = np.asarray([p], dtype=float)
        _, _, _, _, contains, sel = self._limits.clip(P, P)
        inside = sel[contains[0]]
        if len(inside) == 0:
            near = nearest_points(self.floor.free_space, Point(p))[0]
            dist = near.distance(Point(p))
            raise NoPathError(
                start,
                goal,
                f"{which} ({p[0]:g}, {p[1]:g}) is outside the free space of floor "
                f"{self.floor.name!r} ({self.floor.source}): inside an obstacle, off the floor or "
                f"within the robot's clearance of a wall; nearest free point is "
                f"({near.x:.3f}, {near.y:.3f}), {dist:.3g} m away",
            )
        return inside

    def _plan_path(self, start: XY, goal: XY) -> Path:
        rs = self._regions_at(start, "start", start, goal)
        rg = self._regions_at(goal, "goal", start, goal)
        if not set(self._component[rs]) & set(self._component[rg]):
            raise NoPathError(
                start,
                goal,
                f"goal ({goal[0]:g}, {goal[1]:g}) lies in a part of floor {self.floor.name!r} "
                f"({self.floor.source}) that is not connected to the start's "
                f"(start in region(s) {rs.tolist()}, goal in region(s) {rg.tolist()})",
            )
        s, g = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
        if np.array_equal(s, g):
            return make_path(np.array([s, g]), 0.0)
        nodes = self._search(s, g, rs, rg)
        pts = [s, *(self._pos[n].copy() for n in nodes), g]
        tags = [-1, *(int(self._portal_of[n]) for n in nodes), -1]
        # A start or goal exactly on a graph node: drop the copy (no zero-length legs).
        kept_p, kept_t = [s], [-1]
        for p, t in zip(pts[1:-1], tags[1:-1], strict=True):
            if math.hypot(*(p - kept_p[-1])) > OVERLAP_TOL:
                kept_p.append(p)
                kept_t.append(t)
        while len(kept_p) > 1 and math.hypot(*(g - kept_p[-1])) <= OVERLAP_TOL:
            kept_p.pop()
            kept_t.pop()
        pts, tags = [*kept_p, g], [*kept_t, -1]
        keep = self._pull(pts)
        pts, tags = [pts[i] for i in keep], [tags[i] for i in keep]
        if len(pts) > 2:
            pts = self._refine(pts, tags)
            pts = [pts[i] for i in self._pull(pts)]
        total = 0.0
        for a, b in zip(pts[:-1], pts[1:], strict=True):
            t = self._limits.segment_time(a, b)
            if t is None:  # pragma: no cover - every leg was checked on the way
                raise FleetError(f"path leg {a} -> {b} leaves the free space (bug)")
            total += t
        return make_path(np.asarray(pts), total)

    def _links(self, p: np.ndarray, regions: np.ndarray) -> list[tuple[int, float]]:
        """Graph nodes reachable in a straight line from `p` (a start or goal) and the times."""
        ids = sorted({n for r in regions.tolist() for n in self._region_nodes[r]})
        if not ids:
            return []
        Q = self._pos[ids]
        P = np.broadcast_to(p, Q.shape)
        # p and the node share a convex region, so the segment is inside it: its limit is the
        # minimum over what it overlaps, and that is also its exact per-stretch limit.
        lim, ok = self._limits.of_segments(P, Q)
        d = Q - P
        L = np.hypot(d[:, 0], d[:, 1])
        u = d / np.where(L > 0, L, 1.0)[:, None]
        w = L / np.maximum(speeds_along_rows(lim, u), 1e-300)
        return [(n, float(t)) for n, t, good in zip(ids, w, ok, strict=True) if good]

    def _search(self, s: np.ndarray, g: np.ndarray, rs: np.ndarray, rg: np.ndarray) -> list[int]:
        """A* from `s` to `g` over the portal graph; the graph node ids in between."""
        S, G = "start", "goal"
        where = {S: s, G: g}
        top = self._top_speed
        pos = self._pos

        def heuristic(n, _target) -> float:
            p = where[n] if isinstance(n, str) else pos[n]
            return math.hypot(p[0] - g[0], p[1] - g[1]) / top

        with self._lock:
            graph = self._graph
            graph.add_edges_from((S, n, {"weight": w}) for n, w in self._links(s, rs))
            graph.add_edges_from((n, G, {"weight": w}) for n, w in self._links(g, rg))
            direct = self._limits.segment_time(s, g)
            if direct is not None:
                graph.add_edge(S, G, weight=direct)
            try:
                if S not in graph or G not in graph:
                    raise nx.NetworkXNoPath
                route = nx.astar_path(graph, S, G, heuristic=heuristic, weight="weight")
            except nx.NetworkXNoPath:
                raise NoPathError(
                    (float(s[0]), float(s[1])),
                    (float(g[0]), float(g[1])),
                    f"no route through the portals of floor {self.floor.name!r} "
                    f"({self.floor.source}) joins them",
                ) from None
            finally:
                for n in (S, G):
                    if n in graph:
                        graph.remove_node(n)
        return [int(n) for n in route[1:-1]]

    def _pull(self, pts: list[np.ndarray]) -> list[int]:
        """String pulling: the indices of the points to keep.

        From each kept point, jump to the farthest later point that can be reached in a straight
        line without being slower than the route through the points in between.
        """
        times = [self._limits.segment_time(a, b) for a, b in zip(pts[:-1], pts[1:], strict=True)]
        cum = np.concatenate([[0.0], np.cumsum([np.inf if t is None else t for t in times])])
        keep = [0]
        last = len(pts) - 1
        while keep[-1] < last:
            i = keep[-1]
            j = last
            while j > i + 1:
                t = self._limits.segment_time(pts[i], pts[j])
                if t is not None and t <= cum[j] - cum[i] + 1e-12:
                    break
                j -= 1
            keep.append(j)
        return keep

    def _refine(self, pts: list[np.ndarray], tags: list[int]) -> list[np.ndarray]:
        """Slide each waypoint along its portal to where its two legs are quickest.

        A few sweeps of coordinate descent: per waypoint, a coarse-to-fine grid search on the
        portal with vectorised leg times, and a move only when the exact leg times improve.
        """
        pts = [p.copy() for p in pts]
        legs = [self._limits.segment_time(a, b) for a, b in zip(pts[:-1], pts[1:], strict=True)]
        for _ in range(REFINE_SWEEPS):
            moved = False
            for i in range(1, len(pts) - 1):
                if tags[i] < 0 or legs[i - 1] is None or legs[i] is None:
                    continue
                a, b = self._portal_span[tags[i]]
                if np.array_equal(a, b):
                    continue
                prev, nxt = pts[i - 1], pts[i + 1]
                span = float(np.hypot(*(b - a)))
                lo, hi = 0.0, 1.0
                best_t = None
                # Coarse to fine: each level zooms on the best grid point and its neighbours.
                while True:
                    ts = np.linspace(lo, hi, 9)
                    X = a + ts[:, None] * (b - a)
                    P = np.concatenate([np.broadcast_to(prev, X.shape), X])
                    Q = np.concatenate([X, np.broadcast_to(nxt, X.shape)])
                    t, ok = self._limits.travel_times(P, Q)
                    total = np.where(ok[:9] & ok[9:], t[:9] + t[9:], np.inf)
                    k = int(np.argmin(total))
                    if not np.isfinite(total[k]):
                        break
                    best_t = float(ts[k])
                    lo, hi = float(ts[max(k - 1, 0)]), float(ts[min(k + 1, 8)])
                    if (hi - lo) * span <= REFINE_RESOLUTION:
                        break
                if best_t is None:
                    continue
                x = a + best_t * (b - a)
                t1, t2 = self._limits.segment_time(prev, x), self._limits.segment_time(x, nxt)
                if t1 is not None and t2 is not None and t1 + t2 < legs[i - 1] + legs[i] - 1e-9:
                    pts[i], legs[i - 1], legs[i] = x, t1, t2
                    moved = True
            if not moved:
                break
        return pts

    # -- timing -------------------------------------------------------------------------------
    def _plan_reference(self, start: XY, goal: XY, dt: float) -> Reference:
        path = self._path_cached(start, goal)
        pieces = self._pieces(path, dt)
        if not pieces:
            z = np.zeros((1, 2))
            return make_reference(dt, path.waypoints[:1].copy(), z, path)
        counts = self._step_counts(pieces, dt)
        for _ in range(MAX_ROUNDS):
            sigma, short = self._solve_speeds(pieces, counts, dt)
            if sigma is not None:
                break
            # Pieces the LP could not cover in their steps get more steps (never fewer, so the
            # reachable coverage only grows); the stop-and-go counts end the search for sure.
            counts = [
                n + max(1, math.ceil(gap / (p.speed * dt))) if gap > 0 else n
                for n, gap, p in zip(counts, short, pieces, strict=True)
            ]
        else:
            counts = self._stop_and_go_counts(pieces, dt)
            sigma, _ = self._solve_speeds(pieces, counts, dt)
            if sigma is None:  # pragma: no cover - the stop-and-go counts are always feasible
                raise FleetError(
                    f"no safe timing found from {start} to {goal} with dt={dt} (HiGHS found "
                    "the speed LP infeasible); please report this with the floor map"
                )
        ref = self._assemble(pieces, counts, sigma, dt, path)
        self._verify(ref)
        return ref

    def _pieces(self, path: Path, dt: float) -> list[_Piece]:
        """Straight pieces of constant limit: split at corners and where the limit changes."""
        pieces: list[_Piece] = []
        wp = path.waypoints
        for a, b in zip(wp[:-1], wp[1:], strict=True):
            d = b - a
            L = math.hypot(d[0], d[1])
            if L <= OVERLAP_TOL:
                continue
            u = d / L
            parts = self._limits.stretches(a, b)
            if parts is None:  # pragma: no cover - paths are checked when planned
                raise FleetError(f"path leg {a} -> {b} leaves the free space (bug)")
            spans = _merge_spans([[s0, s1, lim] for s0, s1, lim in parts], u, dt)
            accel = self.a_max / float(np.abs(u).max())
            for s0, s1, lim in spans:
                p0 = a if s0 == 0.0 else a + d * (s0 / L)
                p1 = b if s1 == L else a + d * (s1 / L)
                pieces.append(_Piece(p0, p1, u, s1 - s0, speed_along(lim, u), accel))
        return pieces

    def _step_counts(self, pieces: list[_Piece], dt: float) -> list[int]:
        """Steps per piece from a continuous forward/backward trapezoidal profile.

        Speeds and accelerations are shrunk like the LP's bounds, and a piece cannot be faster
        than one step over its whole length, so a piece driven at its limit gets the step it
        needs for the LP's margin.
        """
        J = len(pieces)
        shrink = 1.0 - 2 * LP_MARGIN
        cap = [min(p.speed * shrink, p.length / dt) for p in pieces]
        accel = [p.accel * shrink for p in pieces]
        junction = [0.0] * (J + 1)
        for j in range(1, J):
            turn = float(np.abs(pieces[j].u - pieces[j - 1].u).max())
            corner = self.a_max * dt * shrink / turn if turn > 0 else math.inf
            junction[j] = min(cap[j - 1], cap[j], corner)
        for j in range(J):
            reach = math.sqrt(junction[j] ** 2 + 2 * accel[j] * pieces[j].length)
            junction[j + 1] = min(junction[j + 1], reach)
        for j in reversed(range(J)):
            reach = math.sqrt(junction[j + 1] ** 2 + 2 * accel[j] * pieces[j].length)
            junction[j] = min(junction[j], reach)
        counts = []
        for j, p in enumerate(pieces):
            T = _trapezoid(p.length, junction[j], junction[j + 1], cap[j], accel[j])
            counts.append(max(1, math.ceil(T / dt - 1e-9)))
        return counts

    def _stop_and_go_counts(self, pieces: list[_Piece], dt: float) -> list[int]:
        """Steps per piece if the robot (nearly) stops at every piece boundary.

        Each piece starts and ends at a speed whose every axis is at most ``a_max*dt/2``, so any
        two pieces meet within the acceleration bound; the fewest steps that can cover the piece
        that way always give a feasible LP.
        """
        counts = []
        shrink = 1.0 - 2 * LP_MARGIN
        for p in pieces:
            edge = 0.5 * self.a_max * dt / float(np.abs(p.u).max()) * shrink
            top = p.speed * shrink
            step = p.accel * dt * shrink
            need = p.length / dt
            n = 1
            while True:
                i = np.arange(n)
                if np.minimum(top, edge + step * np.minimum(i, n - 1 - i)).sum() >= need:
                    break
                n = n + 1 if n < 64 else int(n * 1.25)
            counts.append(n)
        return counts

    def _solve_speeds(
        self, pieces: list[_Piece], counts: list[int], dt: float
    ) -> tuple[np.ndarray | None, list[float]]:
        """Along-piece speed of every moving step, from HiGHS.

        Constraints: speeds within each piece's limit, per-axis acceleration within
        ``a_max*dt`` between consecutive steps (also across corners), the first step reachable
        from rest and the last one able to stop, and each piece's steps covering at most its
        length. Phase 1 maximises the coverage; if every piece is covered, phase 2 fixes the
        coverage and minimises the total variation of the speeds (the calmest profile), warm
        started from phase 1.

        Returns
        -------
        sigma, short:
            The speeds, or None when some piece cannot be covered in its steps; `short` is the
            length (m) each piece lacks (all zero on success).
        """
        M = sum(counts)
        J = len(pieces)
        shrink = 1.0 - LP_MARGIN
        adt = self.a_max * dt * shrink
        piece_of = np.repeat(np.arange(J), counts)
        ub = np.array([pieces[j].speed for j in piece_of]) * shrink
        ub[0] = min(ub[0], adt / float(np.abs(pieces[0].u).max()))
        ub[-1] = min(ub[-1], adt / float(np.abs(pieces[-1].u).max()))
        n_tv = M - 1
        nvar = M + n_tv
        inf = highspy.kHighsInf
        target = np.array([p.length / dt for p in pieces])

        rows_lo: list[float] = []
        rows_hi: list[float] = []
        starts: list[int] = []
        index: list[int] = []
        value: list[float] = []

        def row(lo: float, hi: float, entries: list[tuple[int, float]]) -> None:
            starts.append(len(index))
            rows_lo.append(lo)
            rows_hi.append(hi)
            for i, c in entries:
                index.append(i)
                value.append(c)

        first = 0
        for j, n in enumerate(counts):
            row(0.0, float(target[j]), [(first + i, 1.0) for i in range(n)])
            first += n
        for i in range(n_tv):
            a, b = piece_of[i], piece_of[i + 1]
            if a == b:
                step = pieces[a].accel * dt * shrink
                row(-step, step, [(i, -1.0), (i + 1, 1.0)])
            else:
                ua, ub_ = pieces[a].u, pieces[b].u
                for axis in (0, 1):
                    if ua[axis] != 0.0 or ub_[axis] != 0.0:
                        row(-adt, adt, [(i, -float(ua[axis])), (i + 1, float(ub_[axis]))])
            row(-inf, 0.0, [(i, -1.0), (i + 1, 1.0), (M + i, -1.0)])
            row(0.0, inf, [(i, -1.0), (i + 1, 1.0), (M + i, 1.0)])

        h = new_highs({"primal_feasibility_tolerance": 1e-10, "dual_feasibility_tolerance": 1e-10})
        h.addVars(nvar, np.zeros(nvar), np.concatenate([ub, np.full(n_tv, inf)]))
        cols = np.arange(nvar, dtype=np.int32)
        # Phase 1: cover as much of every piece as the steps allow (relative to its length, so
        # a long piece cannot buy coverage with a short one's).
        h.changeColsCost(nvar, cols, np.concatenate([-1.0 / target[piece_of], np.zeros(n_tv)]))
        h.addRows(
            len(rows_lo),
            np.asarray(rows_lo),
            np.asarray(rows_hi),
            len(index),
            np.asarray(starts, dtype=np.int32),
            np.asarray(index, dtype=np.int32),
            np.asarray(value),
        )
        # A failed run raises SolverError (HiGHS's message): no timing can come from this LP.
        if solve(h, "reference timing LP").status != highspy.HighsModelStatus.kOptimal:
            return None, [p.length for p in pieces]  # pragma: no cover - x = 0 is feasible
        x = np.asarray(h.getSolution().col_value[:M], dtype=float)
        covered = np.bincount(piece_of, weights=x, minlength=J)
        short = np.maximum(target - covered, 0.0) * dt
        if np.any(short > 1e-9 * np.maximum(1.0, target * dt)):
            return None, [float(s) if s > 1e-9 else 0.0 for s in short]

        # Phase 2: exact coverage, calmest speeds. Only a refinement (phase 1 is already a
        # feasible timing) and it grows about with the square of the steps, so long, finely
        # sampled trips skip it.
        if M <= CALM_MAX_STEPS:
            h.changeRowsBounds(J, np.arange(J, dtype=np.int32), target, target)
            h.changeColsCost(nvar, cols, np.concatenate([np.zeros(M), np.ones(n_tv)]))
            try:
                calm = solve(h, "reference calming LP").status == highspy.HighsModelStatus.kOptimal
            except SolverError:  # logged; phase 1's timing stands
                calm = False
            if calm:
                x = np.asarray(h.getSolution().col_value[:M], dtype=float)
        sigma = np.clip(x, 0.0, ub)
        # Cover each piece exactly (removes the solver's last rounding in the sums).
        covered = np.bincount(piece_of, weights=sigma, minlength=J)
        if np.any(covered <= 0):
            return None, [p.length if c <= 0 else 0.0 for p, c in zip(pieces, covered, strict=True)]
        sigma *= (target / covered)[piece_of]
        return sigma, [0.0] * J

    def _assemble(
        self, pieces: list[_Piece], counts: list[int], sigma: np.ndarray, dt: float, path: Path
    ) -> Reference:
        K = sum(counts) + 1
        pos = np.zeros((K + 1, 2))
        vel = np.zeros((K + 1, 2))
        pos[0] = pos[1] = pieces[0].p0
        k = 1
        for piece, n in zip(pieces, counts, strict=True):
            # Place the samples by their cumulative share of the piece, not by adding steps up:
            # summing thousands of small steps would pile the rounding onto the last one.
            share = np.cumsum(sigma[k - 1 : k - 1 + n])
            pos[k + 1 : k + 1 + n] = piece.p0 + np.outer(share / share[-1], piece.p1 - piece.p0)
            pos[k + n] = piece.p1
            vel[k : k + n] = (pos[k + 1 : k + 1 + n] - pos[k : k + n]) / dt
            k += n
        return make_reference(dt, pos, vel, path)

    def _verify(self, ref: Reference) -> None:
        """Raise FleetError unless `ref` meets the step semantics to `CHECK_TOL`."""
        p, v, dt = ref.positions, ref.velocities, ref.dt
        wp = ref.path.waypoints
        problems = []
        if np.abs(p[0] - wp[0]).max() > CHECK_TOL or np.abs(p[-1] - wp[-1]).max() > CHECK_TOL:
            problems.append("does not start at the start and end at the goal")
        if np.abs(v[0]).max() > 0 or np.abs(v[-1]).max() > 0:
            problems.append("does not start and end at rest")
        drift = np.abs(p[1:] - p[:-1] - dt * v[:-1]).max()
        if drift > CHECK_TOL:
            problems.append(f"breaks p[k+1] = p[k] + dt*v[k] by {drift:.3g} m")
        dv = np.abs(np.diff(v, axis=0)).max()
        if dv > self.a_max * dt + CHECK_TOL:
            problems.append(f"changes velocity by {dv:.6g} m/s in one step (> a_max*dt)")
        lim, ok = self._limits.of_segments(p[:-1], p[1:])
        if not ok.all():
            k = int(np.flatnonzero(~ok)[0])
            problems.append(f"step {k} from {p[k]} to {p[k + 1]} leaves the free space")
        over = np.abs(v[:-1]) - lim
        if over.max() > CHECK_TOL:
            k = int(np.argmax(over.max(axis=1)))
            problems.append(f"step {k} at |v| = {np.abs(v[k])} exceeds its limit {lim[k]}")
        if problems:
            raise FleetError(
                "the reference failed its safety self-check (a bug; please report it with the "
                "floor map): " + "; ".join(problems)
            )


# -- helpers ----------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class _Piece:
    """A straight stretch of a path with one speed limit; samples land on both its ends."""

    p0: np.ndarray
    p1: np.ndarray
    u: np.ndarray  # unit direction
    length: float
    speed: float  # highest speed along u within the per-axis limit
    accel: float  # highest acceleration along u within the per-axis bound


def _merge_spans(spans: list[list], u: np.ndarray, dt: float) -> list[list]:
    """Join collinear stretches ``[from_m, to_m, limit]`` where a sample is not worth it.

    Two neighbours join when that costs nothing (the same speed along `u` before and after),
    and a stretch shorter than one step at its own speed joins its slower neighbour: otherwise a
    sample would have to land on both its ends, forcing a slowdown for nothing.
    """
    spans = [list(s) for s in spans]
    changed = True
    while changed and len(spans) > 1:
        changed = False
        for k in range(len(spans) - 1):
            a, b = spans[k], spans[k + 1]
            both = np.minimum(a[2], b[2])
            fastest = max(speed_along(a[2], u), speed_along(b[2], u))
            if speed_along(both, u) >= fastest * (1 - 1e-12):
                spans[k : k + 2] = [[a[0], b[1], both]]
                changed = True
                break
        if changed:
            continue
        for k, (s0, s1, lim) in enumerate(spans):
            speed = speed_along(lim, u)
            if s1 - s0 >= speed * dt:
                continue
            m = min(
                (m for m in (k - 1, k + 1) if 0 <= m < len(spans)),
                key=lambda m: speed_along(spans[m][2], u),
            )
            if speed_along(spans[m][2], u) > speed:
                continue
            lo, hi = min(k, m), max(k, m)
            spans[lo : hi + 1] = [[spans[lo][0], spans[hi][1], np.minimum(lim, spans[m][2])]]
            changed = True
            break
    return spans


def _trapezoid(length: float, entry: float, exit_: float, top: float, accel: float) -> float:
    """Time to drive `length` from speed `entry` to `exit_` with speed <= `top`, |acc| <= accel."""
    peak = math.sqrt(accel * length + 0.5 * (entry**2 + exit_**2))
    if peak <= top:
        return max((2 * peak - entry - exit_) / accel, 0.0)
    ramps = (top**2 - entry**2 + top**2 - exit_**2) / (2 * accel)
    return (2 * top - entry - exit_) / accel + max(length - ramps, 0.0) / top


def _safe(point) -> tuple[float, float]:
    """A best-effort (x, y) for error messages about malformed points."""
    try:
        x, y = (float(c) for c in point)
        return x, y
    except (TypeError, ValueError):
        return (math.nan, math.nan)
