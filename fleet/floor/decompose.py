"""Convex decomposition: split any polygonal area into a few convex polygons that tile it.

The MPC needs each free-space cell as convex polytopes in H-representation, and every extra
polytope costs a binary variable per time step, so the pieces should be few. We triangulate with
a constrained Delaunay triangulation and then merge triangles greedily (Hertel-Mehlhorn): a
diagonal between two pieces is dropped whenever the merged piece stays convex. Hertel-Mehlhorn
never uses more than four times the optimal number of convex pieces; in practice a rectangle
with a rectangular hole gives four pieces.

Merging is done on vertex indices, not with shapely unions, so merged pieces reuse the input
coordinates exactly and the pieces tile the input with no gaps or overlaps beyond float rounding.
"""

from __future__ import annotations

import math
from collections.abc import Iterable

import shapely
from shapely.geometry import GeometryCollection, MultiPolygon, Polygon
from shapely.geometry.base import BaseGeometry

__all__ = ["convex_pieces", "polygons_of", "MIN_PIECE_AREA"]

#: Pieces smaller than this (m^2) are floating-point slivers of set operations and are dropped.
MIN_PIECE_AREA = 1e-9

# Relative tolerance on sin(turn angle) below which a corner counts as straight. Exactly
# collinear grid points can give cross products of about 1e-17 of either sign; real corners on a
# floor plan are many orders of magnitude sharper.
_STRAIGHT = 1e-14

Point = tuple[float, float]


def polygons_of(geom: BaseGeometry) -> list[Polygon]:
    """The non-empty polygons in `geom` (a Polygon, MultiPolygon or GeometryCollection).

    Set operations can return lines and points where two areas touch; those carry no area and
    are left out.
    """
    if geom is None or geom.is_empty:
        return []
    if isinstance(geom, Polygon):
        return [geom]
    if isinstance(geom, MultiPolygon | GeometryCollection):
        out: list[Polygon] = []
        for g in geom.geoms:
            out.extend(polygons_of(g))
        return out
    return []


def convex_pieces(geom: BaseGeometry, *, min_area: float = MIN_PIECE_AREA) -> list[Polygon]:
    """Split a polygonal area into convex polygons that tile it exactly.

    Parameters
    ----------
    geom:
        A Polygon or MultiPolygon (holes allowed), or a GeometryCollection whose polygonal parts
        are used. It should be valid; coordinates snapped to a grid (as `compile_floor` does)
        avoid slivers.
    min_area:
        Pieces with a smaller area (m^2) are dropped as floating-point slivers.

    Returns
    -------
    list of Polygon
        Convex polygons, counter-clockwise, without holes and without repeated or collinear
        vertices. Their interiors are pairwise disjoint and their union is `geom`, up to the
        dropped slivers. The order is deterministic for a given input.

    Examples
    --------
    >>> from shapely.geometry import box
    >>> len(convex_pieces(box(0, 0, 10, 10).difference(box(4, 4, 6, 6))))
    4
    """
    out: list[Polygon] = []
    for part in polygons_of(geom):
        part = shapely.orient_polygons(part)
        if not part.interiors:
            ring = _clean(list(part.exterior.coords)[:-1])
            if len(ring) >= 3 and _is_convex(ring):
                if part.area >= min_area:
                    out.append(Polygon(ring))
                continue
        triangles = polygons_of(shapely.constrained_delaunay_triangles(part))
        for piece in _hertel_mehlhorn(triangles):
            if len(piece) >= 3:
                poly = Polygon(piece)
                if poly.area >= min_area:
                    out.append(poly)
    return out


def _cross(o: Point, a: Point, b: Point) -> float:
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _turn(prev: Point, at: Point, nxt: Point) -> int:
    """+1 for a left (convex, in a CCW ring) turn at `at`, -1 right, 0 straight."""
    c = _cross(prev, at, nxt)
    scale = math.dist(prev, at) * math.dist(at, nxt)
    if scale == 0.0 or abs(c) <= _STRAIGHT * scale:
        return 0
    return 1 if c > 0 else -1


def _is_convex(ring: list[Point]) -> bool:
    n = len(ring)
    return all(_turn(ring[i - 1], ring[i], ring[(i + 1) % n]) >= 0 for i in range(n))


def _clean(ring: list[Point]) -> list[Point]:
    """Drop repeated vertices and vertices where the ring runs straight on."""
    pts = [p for i, p in enumerate(ring) if p != ring[i - 1]] if len(ring) > 1 else ring
    changed = True
    while changed and len(pts) > 3:
        changed = False
        for i in range(len(pts)):
            if _turn(pts[i - 1], pts[i], pts[(i + 1) % len(pts)]) == 0:
                del pts[i]
                changed = True
                break
    return pts


def _hertel_mehlhorn(triangles: Iterable[Polygon]) -> list[list[Point]]:
    """Merge triangles into convex pieces; tries a few diagonal orders and keeps the fewest."""
    ids: dict[Point, int] = {}
    coords: list[Point] = []
    tris: list[list[int]] = []
    for t in triangles:
        pts = [(float(x), float(y)) for x, y in list(t.exterior.coords)[:-1]]
        if len(pts) != 3:
            continue
        if _cross(pts[0], pts[1], pts[2]) < 0:
            pts.reverse()
        tri = []
        for p in pts:
            if p not in ids:
                ids[p] = len(coords)
                coords.append(p)
            tri.append(ids[p])
        if len(set(tri)) == 3:
            tris.append(tri)

    owner = {(t[i], t[(i + 1) % 3]): k for k, t in enumerate(tris) for i in range(3)}
    diagonals = sorted({(u, v) for (u, v) in owner if (v, u) in owner and u < v})

    def length(e: tuple[int, int]) -> float:
        return math.dist(coords[e[0]], coords[e[1]])

    orders = [
        diagonals,
        sorted(diagonals, key=length, reverse=True),
        sorted(diagonals, key=length),
    ]
    best: list[list[int]] | None = None
    for order in orders:
        pieces = _merge(tris, owner, order, coords)
        if best is None or len(pieces) < len(best):
            best = pieces
    return [_clean([coords[i] for i in piece]) for piece in best or []]


def _merge(
    tris: list[list[int]],
    owner0: dict[tuple[int, int], int],
    order: list[tuple[int, int]],
    coords: list[Point],
) -> list[list[int]]:
    """One greedy Hertel-Mehlhorn pass over the diagonals in `order`."""
    pieces: dict[int, list[int]] = {k: list(t) for k, t in enumerate(tris)}
    owner = dict(owner0)
    for u, v in order:
        p, q = owner.get((u, v)), owner.get((v, u))
        if p is None or q is None or p == q:
            continue
        cp, cq = pieces[p], pieces[q]
        # cp runs u -> v, cq runs v -> u; rotate cp to start at v and cq to start at u.
        i, j = cp.index(v), cq.index(u)
        rp = cp[i:] + cp[:i]
        rq = cq[j:] + cq[:j]
        merged = rp + rq[1:-1]
        if len(set(merged)) != len(merged):
            # The pieces touch at a second place (e.g. where a hole meets the shell); merging
            # would make a ring that visits a vertex twice.
            continue
        # Only the corners at u and v change; the rest were convex already.
        ok_u = _turn(coords[rp[-2]], coords[u], coords[rq[1]]) >= 0
        ok_v = _turn(coords[rq[-2]], coords[v], coords[rp[1]]) >= 0
        if not (ok_u and ok_v):
            continue
        pieces[p] = merged
        del pieces[q]
        for a in range(len(cq)):
            owner[(cq[a], cq[(a + 1) % len(cq)])] = p
        del owner[(u, v)]
        del owner[(v, u)]
    return [pieces[k] for k in sorted(pieces)]
