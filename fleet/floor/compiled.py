"""A compiled floor: convex free-space regions in H-representation and their adjacency graph.

This is the paper's floor model: the obstacle-free space is partitioned into convex polytopes
``P_j = {p | A_j p <= b_j}``, each carrying a per-axis speed limit ``v_max_j``. Controllers use
(A, b, v_max) directly (the MPC's Big-M constraints); the path layer walks the adjacency graph.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import cached_property

import networkx as nx
import numpy as np
import shapely
from shapely.geometry import LineString, MultiPolygon, Polygon
from shapely.strtree import STRtree

from fleet.floor.spec import FloorSpec, Station

__all__ = ["Region", "Floor", "halfspaces", "BOUNDARY_BAND", "GRID"]

#: Geometric tolerance (m) for membership and shared-edge tests.
TOLERANCE = 1e-7
#: Grid (m) that the floor compiler's set operations snap to.
GRID = 1e-6
#: Distance (m) from a region's boundary within which a point counts as on it when deciding
#: which zone speed limits bind: the safety checker's depth (`fleet.engine.safety`) and the
#: band in which a planned leg is bound by the region beside it (`fleet.paths.limits`). A leg
#: that runs along a shared boundary is then bound by both sides, as the checker judges it.
BOUNDARY_BAND = 1e-6


@dataclass(frozen=True, eq=False)
class Region:
    """One convex piece of free space with a constant speed limit.

    Attributes
    ----------
    index:
        Position in `Floor.regions`; also the node id in `Floor.graph`.
    polygon:
        The convex polygon (counter-clockwise, no holes).
    A, b:
        H-representation: ``A @ p <= b`` for points inside; rows of `A` are unit outward normals.
    v_max:
        Per-axis speed limit (vx, vy) in m/s.
    zone:
        Name of the speed zone that set the limit, or None for the floor default.
    """

    index: int
    polygon: Polygon
    A: np.ndarray
    b: np.ndarray
    v_max: tuple[float, float]
    zone: str | None = None

    def contains(self, x: float, y: float, tol: float = TOLERANCE) -> bool:
        """Whether (x, y) lies in the closed region, with tolerance `tol` metres."""
        A, b = self.A, self.b
        return bool(np.all(A[:, 0] * x + A[:, 1] * y <= b + tol))


def halfspaces(polygon: Polygon) -> tuple[np.ndarray, np.ndarray]:
    """H-representation (A, b) of a convex polygon, with unit outward normals as rows of A."""
    ring = shapely.orient_polygons(polygon).exterior  # counter-clockwise exterior
    pts = np.asarray(ring.coords)[:-1]
    nxt = np.roll(pts, -1, axis=0)
    edges = nxt - pts
    lengths = np.hypot(edges[:, 0], edges[:, 1])
    keep = lengths > TOLERANCE
    pts, edges, lengths = pts[keep], edges[keep], lengths[keep]
    # Outward normal of a counter-clockwise edge (dx, dy) is (dy, -dx).
    A = np.column_stack([edges[:, 1], -edges[:, 0]]) / lengths[:, None]
    b = np.einsum("ij,ij->i", A, pts)
    return A, b


class Floor:
    """The compiled floor every other layer works on.

    Build one with `fleet.floor.load_floor` (from a map file) or `Floor.from_regions` (from
    convex polygons you already have, e.g. in tests). Regions must be convex, must not overlap
    and must together cover the free space.
    """

    def __init__(
        self, spec: FloorSpec, free_space: Polygon | MultiPolygon, regions: Sequence[Region]
    ):
        self.spec = spec
        self.free_space = free_space
        self.regions: list[Region] = list(regions)
        self._tree = STRtree([r.polygon for r in self.regions])
        self._cores: dict[float, np.ndarray] = {}
        shapely.prepare(self.free_space)
        self.graph: nx.Graph = nx.freeze(_adjacency(self.regions, self._tree))

    # -- construction -------------------------------------------------------------------------
    @classmethod
    def from_regions(
        cls,
        spec: FloorSpec,
        pieces: Iterable[tuple[Polygon, tuple[float, float], str | None]],
        free_space: Polygon | MultiPolygon | None = None,
    ) -> Floor:
        """Build a floor from convex pieces ``(polygon, v_max, zone_name)``.

        `free_space` defaults to the union of the pieces.
        """
        regions = []
        polys = []
        for i, (poly, v_max, zone) in enumerate(pieces):
            poly = shapely.orient_polygons(poly)
            A, b = halfspaces(poly)
            A.setflags(write=False)  # floors are shared (cached): nobody may change a region
            b.setflags(write=False)
            regions.append(Region(i, poly, A, b, (float(v_max[0]), float(v_max[1])), zone))
            polys.append(poly)
        if free_space is None:
            free_space = shapely.union_all(polys)
        return cls(spec, free_space, regions)

    # -- what the map file said ----------------------------------------------------------------
    @property
    def source(self) -> str:
        return self.spec.source

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def stations(self) -> dict[str, Station]:
        return {s.name: s for s in self.spec.stations}

    def station(self, name: str) -> Station:
        """The station called `name`; KeyError lists the known names."""
        for s in self.spec.stations:
            if s.name == name:
                return s
        known = ", ".join(s.name for s in self.spec.stations) or "none"
        raise KeyError(f"no station {name!r} on floor {self.name!r} (known: {known})")

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        return tuple(self.spec.boundary.bounds)  # type: ignore[return-value]

    @cached_property
    def components(self) -> np.ndarray:
        """Each region's connected part of the floor, numbered: regions of one part reach each
        other, regions of two parts never do (read-only)."""
        part = np.zeros(len(self.regions), dtype=np.intp)
        for n, members in enumerate(nx.connected_components(self.graph)):
            part[list(members)] = n
        part.flags.writeable = False
        return part

    @cached_property
    def free_space_tolerant(self) -> Polygon | MultiPolygon:
        """The free space grown by `TOLERANCE` (prepared): forgives rounding on its boundary."""
        grown = self.free_space.buffer(TOLERANCE, join_style="mitre")
        shapely.prepare(grown)
        return grown

    def region_cores(self, depth: float) -> np.ndarray:
        """Each region's polygon shrunk by `depth` metres (object array, cached per depth).

        What a step must reach to count as entering a region, so that rounding on the boundary
        does not (`fleet.engine.safety`).
        """
        cores = self._cores.get(depth)
        if cores is None:
            cores = np.array(
                [r.polygon.buffer(-depth, join_style="mitre") for r in self.regions], dtype=object
            )
            shapely.prepare(cores)
            self._cores[depth] = cores
        return cores

    @property
    def tree(self) -> STRtree:
        """Spatial index over the region polygons (item i is `regions[i]`)."""
        return self._tree

    # -- queries ------------------------------------------------------------------------------
    def locate(self, x: float, y: float, tol: float = TOLERANCE) -> int | None:
        """Index of a region containing (x, y); on a shared boundary, the one with the lowest
        ``min(v_max)``."""
        best: int | None = None
        for i in self._tree.query(
            shapely.points(x, y).buffer(tol) if tol > 0 else shapely.points(x, y)
        ):
            r = self.regions[int(i)]
            if r.contains(x, y, tol) and (
                best is None or min(r.v_max) < min(self.regions[best].v_max)
            ):
                best = r.index
        return best

    def locate_many(self, xy: np.ndarray) -> np.ndarray:
        """Region index for each row of `xy` (n, 2); -1 where a point is outside the free space.

        On a boundary shared by several regions the slowest one is reported.
        """
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        out = np.full(len(xy), -1, dtype=np.int64)
        if len(xy) == 0:
            return out
        speed = np.array([min(r.v_max) for r in self.regions])
        pts_idx, reg_idx = self._tree.query(
            shapely.points(xy), predicate="dwithin", distance=TOLERANCE
        )
        best = np.full(len(xy), np.inf)
        for p, r in zip(pts_idx.tolist(), reg_idx.tolist(), strict=True):
            if speed[r] < best[p] and self.regions[r].contains(xy[p, 0], xy[p, 1]):
                best[p] = speed[r]
                out[p] = r
        return out

    def is_free(self, x: float, y: float, tol: float = TOLERANCE) -> bool:
        """Whether (x, y) lies in the free space (configuration space)."""
        return self.locate(x, y, tol) is not None

    def v_max_at(self, x: float, y: float) -> tuple[float, float] | None:
        """Per-axis limit at (x, y), None outside the free space.

        On a boundary shared by several regions each axis gets its lowest limit among them.
        """
        limits = [
            r.v_max
            for i in self._tree.query(shapely.points(x, y), predicate="dwithin", distance=TOLERANCE)
            if (r := self.regions[int(i)]).contains(x, y)
        ]
        if not limits:
            return None
        return (min(v[0] for v in limits), min(v[1] for v in limits))

    def __repr__(self) -> str:
        return f"<Floor {self.name!r} from {self.source}: {len(self.regions)} regions>"


def _shared_boundary(a: Polygon, b: Polygon, grid: float = 0.0):
    """The boundary two polygons share (with `grid`, computed on that grid), merged."""
    shared = shapely.intersection(a.boundary, b.boundary, grid_size=grid or None)
    return shapely.line_merge(shared) if shared.geom_type == "MultiLineString" else shared


def _adjacency(regions: Sequence[Region], tree: STRtree) -> nx.Graph:
    """Region adjacency: an edge where two regions share a boundary piece of positive length.

    Each edge carries ``portal``, the shared segment, which the path layer crosses.
    """
    g = nx.Graph()
    for r in regions:
        g.add_node(r.index, v_max=r.v_max, zone=r.zone)
    for r in regions:
        for j in tree.query(r.polygon, predicate="intersects"):
            j = int(j)
            if j <= r.index:
                continue
            shared = _shared_boundary(r.polygon, regions[j].polygon)
            if shared.length <= TOLERANCE:
                # A vertex of one region on an edge of the other (a T-junction) lies off that
                # edge by rounding, and the exact intersection can be a point: snap-rounded on
                # the floor's grid, the shared piece is found (a detour carved round two
                # robots was cut in two: fuzz s21-0819).
                shared = _shared_boundary(r.polygon, regions[j].polygon, GRID)
            if shared.length <= TOLERANCE:
                continue
            if shared.geom_type != "LineString":
                # Convex polygons share at most one segment; take the longest if noise split it.
                shared = max(getattr(shared, "geoms", [shared]), key=lambda s: s.length)
                if shared.geom_type != "LineString":
                    continue
            g.add_edge(r.index, j, portal=LineString(shared.coords))
    return g
