"""Compiling a floor spec into convex regions: configuration space, speed cells, decomposition.

The steps follow the paper. The configuration space comes first: the boundary is shrunk and
every obstacle grown by the robot's clearance (mitred, so polygons stay polygons), and the free
space is the shrunk boundary minus the grown obstacles. Speed zones then split the free space,
by set differences, into cells of constant per-axis limit (the component-wise minimum of all
zones covering a cell, the floor default where none does; cells with equal limits are merged).
Finally each cell is cut into convex pieces, which become the `Region`s of the `Floor`.

All set operations run on a fixed 1 micrometre grid (GEOS OverlayNG with a precision model):
edges that should coincide, such as a zone edge on a machine's edge, then coincide exactly and
leave no slivers, and the cells tile the free space exactly.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import shapely
from shapely.geometry import MultiPolygon, Point, Polygon
from shapely.geometry.base import BaseGeometry

from fleet.errors import MapError
from fleet.floor.compiled import GRID, Floor
from fleet.floor.decompose import convex_pieces, polygons_of
from fleet.floor.mapfile import grow, load_spec
from fleet.floor.spec import FloorSpec, SpeedZone

__all__ = ["compile_floor", "load_floor", "slow_on_rough", "free_space", "speed_cells", "GRID"]

_cache: dict[tuple[str, int, int], Floor] = {}


def load_floor(path: str | Path, *, cache: bool = True) -> Floor:
    """Read, validate and compile a map file.

    Compiled floors are cached by resolved path, modification time and size, so loading the
    same unchanged file again is free. The cached `Floor` is shared: treat it as read-only.

    Raises
    ------
    MapError
        If the file is missing or invalid (see `load_spec`), or a station lies outside the
        compiled free space.
    """
    try:
        resolved = Path(path).resolve()
        st = os.stat(resolved)
    except OSError:
        raise MapError(str(path), "(file)", str(path), "no such map file") from None
    key = (str(resolved), st.st_mtime_ns, st.st_size)
    if cache and key in _cache:
        return _cache[key]
    # The resolved path names the floor, so a cached floor never carries a stale relative path.
    floor = compile_floor(load_spec(resolved))
    if cache:
        _cache[key] = floor
    return floor


def compile_floor(spec: FloorSpec) -> Floor:
    """Compile a validated spec into a `Floor` of convex regions with speed limits.

    Returns
    -------
    Floor
        Regions are convex and pairwise interior-disjoint; their union is the floor's
        `free_space` (the configuration space up to grid snapping). Each carries the limit of
        the speed cell it came from and the name of the zone that set it (None for the
        floor default).

    Raises
    ------
    MapError
        If nothing is left of the floor once clearance is applied, or a station lies outside
        the free space (for instance in the mitred corner of a grown obstacle).
    """
    free = free_space(spec)
    if free.is_empty:
        raise MapError(
            spec.source,
            "floor.clearance",
            spec.clearance,
            "no free space is left once the boundary is shrunk and obstacles are grown by the "
            "clearance; use a smaller clearance or remove obstacles",
        )
    pieces = []
    for v_max, cell in speed_cells(free, spec.zones, spec.default_v_max):
        for piece in convex_pieces(cell):
            pieces.append((piece, v_max, _zone_name(piece, v_max, spec.zones)))
    # The free space is the union of the regions themselves: intersecting cells with zones on
    # the grid can move a vertex off the original free-space edge by up to ~1e-6 m, and the
    # safety checker must judge against exactly what the regions (and an MPC's A, b) allow.
    floor = Floor.from_regions(spec, pieces)
    for i, s in enumerate(spec.stations):
        if floor.locate(s.x, s.y) is None:
            raise MapError(
                spec.source,
                f"stations[{i}] ({s.name}).at",
                [s.x, s.y],
                f"the station is outside the free space the robot's centre can reach: "
                f"{_why_blocked(spec, s.x, s.y)}; move it further from obstacles and walls",
            )
    return floor


def slow_on_rough(spec: FloorSpec, v_max: float) -> Floor:
    """`spec` compiled with every rough area also a speed zone of `v_max` (m/s per axis): the
    paper's "varying" strategy, slow over bumps and rough floor."""
    v = (v_max, v_max)
    slow = tuple(SpeedZone(f"{r.name} (rough)", r.polygon, v) for r in spec.rough_areas)
    return compile_floor(replace(spec, zones=spec.zones + slow))


def free_space(spec: FloorSpec) -> Polygon | MultiPolygon:
    """The configuration space: shrunk boundary minus grown obstacles, snapped to `GRID`."""
    inner = grow(spec.boundary, -spec.clearance)
    grown = [grow(o.polygon, spec.clearance) for o in spec.obstacles]
    blocked = shapely.union_all(grown, grid_size=GRID) if grown else Polygon()
    return _polygonal(shapely.difference(inner, blocked, grid_size=GRID))


def speed_cells(
    free: BaseGeometry, zones: Sequence[SpeedZone], default_v_max: tuple[float, float]
) -> list[tuple[tuple[float, float], Polygon | MultiPolygon]]:
    """Split `free` into cells of constant per-axis limit, one (merged) cell per distinct limit.

    Where zones overlap, each axis takes the lowest limit of the zones covering the point;
    where no zone covers it, `default_v_max` applies (a zone may also raise the limit above
    the default). Returns ``(v_max, cell)`` pairs ordered by limit, slowest first.
    """
    # Key None marks "no zone yet": the default applies only where no zone covers a point.
    cells: dict[tuple[float, float] | None, BaseGeometry] = {None: free}
    for z in zones:
        split: dict[tuple[float, float] | None, list[BaseGeometry]] = {}
        for key, geom in cells.items():
            if not geom.intersects(z.polygon):
                split.setdefault(key, []).append(geom)
                continue
            inside = _polygonal(shapely.intersection(geom, z.polygon, grid_size=GRID))
            outside = _polygonal(shapely.difference(geom, z.polygon, grid_size=GRID))
            limit = z.v_max if key is None else (min(key[0], z.v_max[0]), min(key[1], z.v_max[1]))
            if not inside.is_empty:
                split.setdefault(limit, []).append(inside)
            if not outside.is_empty:
                split.setdefault(key, []).append(outside)
        cells = {k: _union(v) for k, v in split.items()}
    merged: dict[tuple[float, float], list[BaseGeometry]] = {}
    for key, geom in cells.items():
        merged.setdefault(default_v_max if key is None else key, []).append(geom)
    out = [(k, _union(v)) for k, v in merged.items()]
    out = [(k, g) for k, g in out if not g.is_empty]
    return sorted(out, key=lambda kv: (min(kv[0]), kv[0]))


def _union(geoms: list[BaseGeometry]) -> Polygon | MultiPolygon:
    if len(geoms) == 1:
        return _polygonal(geoms[0])
    return _polygonal(shapely.union_all(geoms, grid_size=GRID))


def _polygonal(geom: BaseGeometry) -> Polygon | MultiPolygon:
    """Only the areal part of an overlay result (touching areas can add lines and points)."""
    polys = polygons_of(geom)
    if not polys:
        return Polygon()
    if len(polys) == 1:
        return polys[0]
    return MultiPolygon(polys)


def _zone_name(
    piece: Polygon, v_max: tuple[float, float], zones: Sequence[SpeedZone]
) -> str | None:
    """The zone that set a piece's limit: the first covering zone with exactly that limit,
    else (when two zones set one axis each) the covering zone with the lowest limit."""
    rep = piece.representative_point()
    covering = [z for z in zones if z.polygon.covers(rep)]
    for z in covering:
        if z.v_max == v_max:
            return z.name
    if covering:
        return min(covering, key=lambda z: min(z.v_max)).name
    return None


def _why_blocked(spec: FloorSpec, x: float, y: float) -> str:
    pt = Point(x, y)
    for o in spec.obstacles:
        if grow(o.polygon, spec.clearance).covers(pt):
            return (
                f"it lies in obstacle {o.name!r} grown by clearance {spec.clearance:g} m "
                "(grown with mitred corners, which reach further than the clearance at corners)"
            )
    return f"it lies within clearance {spec.clearance:g} m of the floor boundary"
