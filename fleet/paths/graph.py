"""The portal graph: the fastest collision-free polyline from a start to a goal.

Nodes are points on the portals between the floor's convex regions; an edge joins two nodes of
one region, weighted by its travel time at the regions' per-axis speed limits, so a path may go
around a slow zone when that is quicker. A path is an A* (networkx) route from the start through
the graph to the goal, string pulled, with each waypoint then slid along its portal.
"""

from __future__ import annotations

__all__ = ["XY", "PortalGraph"]

import heapq
import math
import threading

import networkx as nx
import numpy as np
from shapely.geometry import Point
from shapely.ops import nearest_points

from fleet.errors import FleetError, NoPathError
from fleet.floor.compiled import Floor
from fleet.paths.limits import (
    ON_LINE_TOL,
    OVERLAP_TOL,
    SpeedLimits,
    speeds_along,
    speeds_along_rows,
)
from fleet.paths.results import Path, make_path

#: Most graph nodes on one portal (its two inset ends, its midpoint and evenly spaced points).
MAX_PORTAL_NODES = 7
#: Sweeps of sliding the path's waypoints along their portals after the graph search.
REFINE_SWEEPS = 3
#: Length (m) to which a waypoint's place on its portal is refined.
REFINE_RESOLUTION = 1e-3

#: A point (x, y) in metres.
XY = tuple[float, float]


class PortalGraph:
    """Points on the portals of one floor, joined by travel times; paths found through them.

    The graph is built once. `find_path` adds the start and the goal to it for the search, under
    a lock, so a graph can be shared between threads.

    Parameters
    ----------
    floor:
        The compiled floor.
    limits:
        Its speed limits for the robot.
    spacing:
        Wanted gap (m) between graph nodes along a portal (at most `MAX_PORTAL_NODES`).
    margin:
        Nodes on a portal stay this far (m) from its end points.
    """

    def __init__(self, floor: Floor, limits: SpeedLimits, spacing: float, margin: float) -> None:
        self.floor = floor
        self.spacing = spacing
        self.margin = margin
        self._limits = limits
        # Fastest possible speed along any direction: keeps the A* heuristic admissible.
        lim = limits.per_region
        self._top_speed = float(np.max(np.hypot(lim[:, 0], lim[:, 1])))
        self._component = floor.components

        self._lock = threading.Lock()
        self._pos, self._region_nodes, self._graph = self._build_graph()

    def find_path(self, start: XY, goal: XY) -> Path:
        """The fastest path found from `start` to `goal`: A*, string pulling, refinement.

        Raises
        ------
        NoPathError
            When the start or the goal is outside the free space, or no path joins them.
        """
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

    def cost_to_go(self, goal: XY) -> dict[int, float]:
        """Each graph node's fastest time to `goal` over the graph (Dijkstra from the goal's
        links; the graph's times are the same both ways). Nodes that cannot reach it are left out.

        Raises
        ------
        NoPathError
            When the goal is outside the free space.
        """
        rg = self._regions_at(goal, "goal", goal, goal)
        g = np.asarray(goal, dtype=float)
        best: dict[int, float] = {}
        heap = [(w, n) for n, w in self._links(g, rg)]
        heapq.heapify(heap)
        with self._lock:  # `_search` adds and removes its start and goal under it
            adj = self._graph.adj
            while heap:
                t, n = heapq.heappop(heap)
                if n in best:
                    continue
                best[n] = t
                for m, edge in adj[n].items():
                    if m not in best:
                        heapq.heappush(heap, (t + edge["weight"], m))
        return best

    def estimate_time(self, start: XY, goal: XY, to_goal: dict[int, float]) -> float:
        """The fastest time from `start` to `goal` over the graph, `to_goal` being
        ``cost_to_go(goal)``: what the search finds before string pulling and sliding, which
        only shorten it.

        Raises
        ------
        NoPathError
            As `find_path`.
        """
        rs = self._regions_at(start, "start", start, goal)
        s, g = np.asarray(start, dtype=float), np.asarray(goal, dtype=float)
        direct = self._limits.segment_time(s, g)
        best = math.inf if direct is None else direct
        for n, w in self._links(s, rs):
            best = min(best, w + to_goal.get(n, math.inf))
        if not math.isfinite(best):
            raise NoPathError(
                start,
                goal,
                f"no route through the portals of floor {self.floor.name!r} "
                f"({self.floor.source}) joins them",
            )
        return best

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
        """Node positions, the nodes on each region's portals, and the weighted graph.

        Also keeps each node's portal and each portal's span, for `_refine` to slide along.
        """
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
        # The route's time from i to j is inf if a leg in between is not free, else the sum of
        # its legs. (Summed as inf, past such a leg every later pair gave inf - inf = NaN, and
        # the pulling stopped there, with a RuntimeWarning.)
        cum = np.concatenate([[0.0], np.cumsum([0.0 if t is None else t for t in times])])
        unfree = np.concatenate([[0], np.cumsum([t is None for t in times])])
        keep = [0]
        last = len(pts) - 1
        while keep[-1] < last:
            i = keep[-1]
            j = last
            while j > i + 1:
                t = self._limits.segment_time(pts[i], pts[j])
                route = np.inf if unfree[j] > unfree[i] else cum[j] - cum[i]
                if t is not None and t <= route + 1e-12:
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
