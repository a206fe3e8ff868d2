"""Reading floor map files (TOML, metres, m/s) into a validated `FloorSpec`.

The format is described in ``maps/README.md`` and, as types, in `fleet.floor.mapspec`, which
checks types, ranges and keys; the rules here span keys or need geometry. Validation is strict:
every problem raises a `MapError` naming the file, the field (e.g.
``obstacles[2] (cnc_3).polygon``; list indices count from 0), the bad value and what is
allowed. Unknown keys are errors, so a typo never silently drops a machine or a speed limit.

Semantics decided here:

- Names are unique across obstacles, zones, stations and rough areas, so ``around`` and error
  messages can refer to any of them unambiguously.
- A zone with ``around = NAME`` and ``margin = M`` covers the named obstacle *or zone* grown by
  M metres with mitred corners, clipped to the floor boundary. Rings stack: a 0.8 m/s ring
  ``around`` a 0.4 m/s zone covers that zone too, and since the lowest limit wins where zones
  overlap, the inner zone keeps 0.4 m/s. Growing a zone grows its full (unclipped) shape, so a
  ring around a zone around a machine is the machine grown by the sum of the margins.
- Zones and rough areas refer to the robot's reference point (the centre of its footprint),
  as the paper's speed-limited regions do; only obstacles and the boundary are adjusted by
  ``clearance``.
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import shapely
from shapely.geometry import MultiPolygon, Point, Polygon, box
from shapely.geometry.base import BaseGeometry

from fleet.errors import MapError
from fleet.floor.mapspec import MISSING, RECT_RULE, MapFile, ZoneEntry, convert
from fleet.floor.spec import FloorSpec, Obstacle, RoughArea, SpeedZone, Station

__all__ = ["load_spec", "parse_spec", "grow", "MITRE_LIMIT", "AREA_TOLERANCE"]

#: Mitre limit for grown shapes (shapely's default): corners sharper than about 23 degrees are
#: bevelled instead of producing long spikes.
MITRE_LIMIT = 5.0

#: Area (m^2) a shape may stick out of the floor before it counts as "partly outside"; allows
#: for rounding of coordinates written in a map file.
AREA_TOLERANCE = 1e-9


def grow(geom: BaseGeometry, distance: float) -> BaseGeometry:
    """`geom` grown (or shrunk, for negative `distance`) by `distance` metres, mitred corners.

    Mitred joins keep polygons polygons (no arcs) and are conservative: the grown shape
    contains the round-cornered one, so a robot kept outside it keeps at least `distance`
    metres from the original shape.
    """
    if distance == 0:
        return geom
    return geom.buffer(distance, join_style="mitre", mitre_limit=MITRE_LIMIT)


def load_spec(path: str | Path) -> FloorSpec:
    """Read and validate a floor map file.

    Parameters
    ----------
    path:
        A TOML map file (see ``maps/README.md``).

    Returns
    -------
    FloorSpec
        The validated map, with ``source`` set to `path` as given.

    Raises
    ------
    MapError
        If the file cannot be read, is not valid TOML, or breaks any rule of the format; the
        message names the file, the field and the bad value.
    """
    source = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise MapError(source, "(file)", source, "no such map file") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise MapError(source, "(file)", source, f"cannot read the map file: {exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        m = re.search(r"line (\d+), column (\d+)", str(exc))
        lines = text.splitlines()
        if m:
            line = int(m.group(1))
            shown = lines[line - 1] if 0 < line <= len(lines) else ""
            raise MapError(
                source, f"(TOML syntax, line {line})", shown, f"not valid TOML: {exc}"
            ) from None
        raise MapError(source, "(TOML syntax)", "", f"not valid TOML: {exc}") from None
    return parse_spec(data, source)


def parse_spec(data: Mapping[str, Any], source: str = "<map>") -> FloorSpec:
    """Validate an already-parsed map (the dict `tomllib` returns) into a `FloorSpec`.

    `source` is used in error messages and stored in the spec. Raises `MapError` as
    `load_spec` does.
    """
    return _Checks(source, data).spec(convert(data, source))


class _Checks:
    """The rules of one converted map that msgspec cannot state; errors quote the raw TOML."""

    def __init__(self, source: str, raw: Mapping[str, Any]) -> None:
        self.source = source
        self.raw = raw
        self.names: dict[str, str] = {}  # name -> label of the entry that defined it

    def fail(self, field: str, value: Any, rule: str) -> MapError:
        return MapError(self.source, field, value, rule)

    # -- whole file -----------------------------------------------------------------------------
    def spec(self, file: MapFile) -> FloorSpec:
        floor = file.floor
        boundary = self.shape(floor, self.raw["floor"], "floor", ("boundary", "rect"))

        obstacles = []
        for i, (entry, raw) in enumerate(self.entries(file.obstacles, "obstacles")):
            label = self.named("obstacles", i, entry.name)
            obstacles.append((label, raw, Obstacle(entry.name, self.shape(entry, raw, label))))

        zones = []
        for i, (entry, raw) in enumerate(self.entries(file.zones, "zones")):
            label = self.named("zones", i, entry.name)
            zones.append((label, raw, entry, self.zone_shape(entry, raw, label)))

        stations = []
        for i, (entry, _) in enumerate(self.entries(file.stations, "stations")):
            label = self.named("stations", i, entry.name)
            stations.append((label, Station(entry.name, *entry.at, entry.kind)))

        rough = []
        for i, (entry, raw) in enumerate(self.entries(file.rough_areas, "rough_areas")):
            label = self.named("rough_areas", i, entry.name)
            area = RoughArea(entry.name, self.shape(entry, raw, label), entry.severity)
            rough.append((label, raw, area))

        # Cross-checks, now that every name is known.
        for label, raw, o in obstacles:
            self.within(o.polygon, boundary, label, raw, "obstacle")
        solid = tuple(o for _, _, o in obstacles)
        speed_zones = self.zones(zones, solid, boundary)
        for label, raw, r in rough:
            self.within(r.polygon, boundary, label, raw, "rough area")
        for label, s in stations:
            self.station(label, s, boundary, solid, floor.clearance)

        return FloorSpec(
            source=self.source,
            name=floor.name,
            boundary=boundary,
            default_v_max=_speed(floor.default_v_max),
            clearance=floor.clearance,
            obstacles=solid,
            zones=tuple(speed_zones),
            stations=tuple(s for _, s in stations),
            rough_areas=tuple(r for _, _, r in rough),
            description=floor.description,
            metadata=file.metadata,
        )

    def entries(self, entries: list[Any], kind: str) -> Iterator[tuple[Any, Mapping[str, Any]]]:
        """Each converted entry of `kind` with its table as written."""
        return zip(entries, self.raw.get(kind, []), strict=True)

    def named(self, kind: str, i: int, name: str) -> str:
        """Register an entry's name; return its label, e.g. ``obstacles[2] (cnc_3)``."""
        if name in self.names:
            raise self.fail(
                f"{kind}[{i}].name",
                name,
                f"duplicate name: already used by {self.names[name]}; names must be unique across "
                "obstacles, zones, stations and rough areas",
            )
        self.names[name] = label = f"{kind}[{i}] ({name})"
        return label

    # -- shapes ---------------------------------------------------------------------------------
    def shape(
        self,
        entry: Any,
        raw: Mapping[str, Any],
        label: str,
        keys: tuple[str, str] = ("polygon", "rect"),
    ) -> Polygon:
        """The entry's area, from exactly one of its polygon key or ``rect``."""
        poly_key, rect_key = keys
        outline, rect = getattr(entry, poly_key), entry.rect
        if outline is not None and rect is not None:
            raise self.fail(
                f"{label}.{rect_key}",
                raw[rect_key],
                f"give exactly one of {poly_key} or {rect_key}",
            )
        if rect is not None:
            return self.rect(rect, f"{label}.{rect_key}", raw[rect_key])
        if outline is not None:
            return self.polygon(outline, f"{label}.{poly_key}", raw[poly_key])
        raise self.fail(
            f"{label}.{poly_key}",
            MISSING,
            f"required: give {poly_key} = [[x, y], ...] or {rect_key} = [xmin, ymin, xmax, ymax]",
        )

    def zone_shape(self, zone: ZoneEntry, raw: Mapping[str, Any], label: str) -> Polygon | None:
        """A zone's own area, or None for a zone ``around`` another shape."""
        if zone.around is None:
            if zone.margin is not None:
                raise self.fail(
                    f"{label}.margin", raw["margin"], "margin is only allowed with around"
                )
            return self.shape(zone, raw, label)
        for key in ("polygon", "rect"):
            if key in raw:
                raise self.fail(
                    f"{label}.{key}",
                    raw[key],
                    "give exactly one of polygon, rect or around (+ margin), not both "
                    f"{key} and around",
                )
        if zone.margin is None:
            raise self.fail(
                f"{label}.margin", MISSING, "required with around: the width (m) to grow by"
            )
        return None

    def rect(self, rect: tuple[float, float, float, float], field: str, raw: Any) -> Polygon:
        x0, y0, x1, y1 = rect
        if not (x0 < x1 and y0 < y1):
            raise self.fail(field, raw, RECT_RULE)
        return shapely.orient_polygons(box(x0, y0, x1, y1))

    def polygon(self, outline: list[tuple[float, float]], field: str, raw: Any) -> Polygon:
        pts = list(outline)
        if len(pts) > 1 and pts[0] == pts[-1]:
            pts = pts[:-1]  # a closing vertex is allowed but not needed
        if len(pts) < 3:
            raise self.fail(field, raw, f"a polygon needs at least 3 vertices, got {len(pts)}")
        poly = Polygon(pts)
        # Checked before validity: shapely reports collinear vertices as a self-intersection.
        # (A bow-tie's signed area can be zero too, so use the hull, not the polygon's area.)
        if poly.convex_hull.area <= 1e-12:
            raise self.fail(field, raw, "polygon has zero area (its vertices are collinear)")
        reason = shapely.is_valid_reason(poly)
        if reason != "Valid Geometry":
            m = re.search(r"\[([-\d.eE+]+) ([-\d.eE+]+)\]", reason)
            where = f" at ({float(m.group(1)):g}, {float(m.group(2)):g})" if m else ""
            raise self.fail(
                field,
                raw,
                f"polygon is not simple: its edges cross or touch{where} ({reason}); list the "
                "vertices in order around the outline",
            )
        return shapely.orient_polygons(poly)

    # -- cross-checks ---------------------------------------------------------------------------

    def within(
        self, geom: BaseGeometry, boundary: Polygon, label: str, entry: Mapping[str, Any], what: str
    ) -> None:
        """Fail unless `geom` (the entry's polygon or rect) lies within the floor boundary."""
        key = "rect" if "rect" in entry else "polygon"
        field, value = f"{label}.{key}", entry.get(key)
        outside = geom.difference(boundary)
        if outside.area <= AREA_TOLERANCE:
            return
        x0, y0, x1, y1 = boundary.bounds
        bounds = f"the floor spans x {x0:g}..{x1:g}, y {y0:g}..{y1:g}"
        if geom.intersection(boundary).area <= AREA_TOLERANCE:
            raise self.fail(field, value, f"the {what} lies outside the floor boundary ({bounds})")
        p = outside.representative_point()
        raise self.fail(
            field,
            value,
            f"the {what} lies partly outside the floor boundary ({outside.area:.4g} m^2 outside, "
            f"e.g. around ({p.x:.4g}, {p.y:.4g})); keep it within floor.boundary ({bounds})",
        )

    def zones(
        self,
        zones: list[tuple[str, Mapping[str, Any], ZoneEntry, Polygon | None]],
        obstacles: Sequence[Obstacle],
        boundary: Polygon,
    ) -> list[SpeedZone]:
        by_name = {zone.name: (label, raw, zone, own) for label, raw, zone, own in zones}
        obstacle_polys = {o.name: o.polygon for o in obstacles}
        full: dict[str, BaseGeometry] = {}  # unclipped shapes, so rings grow from the real shape

        def resolve(name: str, chain: tuple[str, ...]) -> BaseGeometry:
            if name in full:
                return full[name]
            label, raw, zone, shape = by_name[name]
            if shape is not None:
                self.within(shape, boundary, label, raw, "zone")
            else:
                target = zone.around
                field = f"{label}.around"
                if target in chain or target == name:
                    cycle = " -> ".join((*chain, name, target))
                    raise self.fail(
                        field, target, f"zones grow around each other in a cycle: {cycle}"
                    )
                if target in obstacle_polys:
                    base = obstacle_polys[target]
                elif target in by_name:
                    base = resolve(target, (*chain, name))
                elif target in self.names:
                    raise self.fail(
                        field,
                        target,
                        "around must name an obstacle or a zone; "
                        f"{target!r} is {self.names[target]}",
                    )
                else:
                    known = ", ".join(n for n in [*obstacle_polys, *by_name] if n != name) or "none"
                    raise self.fail(field, target, f"names no obstacle or zone (known: {known})")
                shape = grow(base, zone.margin)
            full[name] = shape
            return shape

        speed_zones = []
        for _, _, zone, own in zones:
            shape = resolve(zone.name, ())
            if own is None:
                shape = shapely.orient_polygons(shape.intersection(boundary))
                if isinstance(shape, MultiPolygon) and len(shape.geoms) == 1:
                    shape = shape.geoms[0]
            speed_zones.append(SpeedZone(zone.name, shape, _speed(zone.v_max)))
        return speed_zones

    def station(
        self,
        label: str,
        s: Station,
        boundary: Polygon,
        obstacles: Sequence[Obstacle],
        clearance: float,
    ) -> None:
        field = f"{label}.at"
        value = [s.x, s.y]
        pt = Point(s.x, s.y)
        if not boundary.covers(pt):
            x0, y0, x1, y1 = boundary.bounds
            raise self.fail(
                field,
                value,
                f"the station lies outside the floor (x {x0:g}..{x1:g}, y {y0:g}..{y1:g})",
            )
        for o in obstacles:
            d = o.polygon.distance(pt)
            where = f"obstacle {o.name!r} ({self.names[o.name]})"
            if d == 0:
                raise self.fail(
                    field, value, f"the station lies inside {where}; robots cannot reach it"
                )
            if d < clearance:
                raise self.fail(
                    field,
                    value,
                    f"the station is {d:.3g} m from {where}, less than floor.clearance = "
                    f"{clearance:g} m, so the robot's body would overlap it; move it at least "
                    f"{clearance:g} m away",
                )
        d = boundary.exterior.distance(pt)
        if d < clearance:
            raise self.fail(
                field,
                value,
                f"the station is {d:.3g} m from the floor boundary, less than floor.clearance = "
                f"{clearance:g} m; move it at least {clearance:g} m inside",
            )


def _speed(v_max: float | list[float]) -> tuple[float, float]:
    """A per-axis limit: one number for both axes, or [vx, vy]."""
    return (v_max, v_max) if isinstance(v_max, float) else (v_max[0], v_max[1])
