"""Reading floor map files (TOML, metres, m/s) into a validated `FloorSpec`.

The format is described in ``maps/README.md``. Validation is strict: every problem raises a
`MapError` naming the file, the field (e.g. ``obstacles[2] (cnc_3).polygon``; list indices
count from 0), the bad value and what is allowed. Unknown keys are errors, so a typo never
silently drops a machine or a speed limit.

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

import math
import re
import tomllib
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

import shapely
from shapely.geometry import MultiPolygon, Point, Polygon, box
from shapely.geometry.base import BaseGeometry

from fleet.errors import MapError
from fleet.floor.spec import FloorSpec, Obstacle, RoughArea, SpeedZone, Station

__all__ = ["load_spec", "parse_spec", "grow", "MITRE_LIMIT", "AREA_TOLERANCE"]

#: Mitre limit for grown shapes (shapely's default): corners sharper than about 23 degrees are
#: bevelled instead of producing long spikes.
MITRE_LIMIT = 5.0

#: Area (m^2) a shape may stick out of the floor before it counts as "partly outside"; allows
#: for rounding of coordinates written in a map file.
AREA_TOLERANCE = 1e-9

_TOP_KEYS = ("floor", "obstacles", "zones", "stations", "rough_areas", "metadata")
_FLOOR_KEYS = ("name", "description", "boundary", "rect", "default_v_max", "clearance")
_OBSTACLE_KEYS = ("name", "polygon", "rect")
_ZONE_KEYS = ("name", "polygon", "rect", "around", "margin", "v_max")
_STATION_KEYS = ("name", "at", "kind")
_ROUGH_KEYS = ("name", "polygon", "rect", "severity")


class _Missing:
    """Stands for the value of a required key that is absent."""

    def __repr__(self) -> str:
        return "<missing>"


MISSING: Any = _Missing()


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
    return _Reader(source).read(data)


class _Reader:
    """One pass over one map file; remembers the file name for error messages."""

    def __init__(self, source: str) -> None:
        self.source = source
        self.names: dict[str, str] = {}  # name -> label of the entry that defined it

    # -- errors ---------------------------------------------------------------------------------
    def fail(self, field: str, value: Any, rule: str) -> MapError:
        return MapError(self.source, field, value, rule)

    # -- whole file -----------------------------------------------------------------------------
    def read(self, data: Mapping[str, Any]) -> FloorSpec:
        self.keys(data, "", _TOP_KEYS, ("floor",), where="at the top level")
        floor = self.table(data["floor"], "floor", "[floor]")
        self.keys(floor, "floor", _FLOOR_KEYS, ("name", "default_v_max"), where="in [floor]")
        name = self.string(floor["name"], "floor.name")
        description = self.string(floor.get("description", ""), "floor.description", empty=True)
        boundary = self.shape(floor, "floor", keys=("boundary", "rect"))
        default_v_max = self.speed(floor["default_v_max"], "floor.default_v_max")
        clearance = self.number(floor.get("clearance", 0.0), "floor.clearance")
        if clearance < 0:
            raise self.fail("floor.clearance", clearance, "must be >= 0 (metres)")
        metadata = data.get("metadata", {})
        if not isinstance(metadata, dict):
            raise self.fail("metadata", metadata, "must be a table ([metadata])")

        obstacles = []
        raw_obstacles = []
        for i, entry in self.entries(data, "obstacles"):
            label = self.named(entry, "obstacles", i, _OBSTACLE_KEYS, ("name",))
            obstacles.append(Obstacle(entry["name"], self.shape(entry, label)))
            raw_obstacles.append((label, entry))

        raw_zones: list[tuple[str, dict[str, Any], float | None]] = []
        for i, entry in self.entries(data, "zones"):
            label = self.named(entry, "zones", i, _ZONE_KEYS, ("name", "v_max"))
            self.speed(entry["v_max"], f"{label}.v_max")
            margin = None
            if "around" in entry:
                if "polygon" in entry or "rect" in entry:
                    key = "polygon" if "polygon" in entry else "rect"
                    raise self.fail(
                        f"{label}.{key}",
                        entry[key],
                        "give exactly one of polygon, rect or around (+ margin), not both "
                        f"{key} and around",
                    )
                self.string(entry["around"], f"{label}.around")
                if "margin" not in entry:
                    raise self.fail(
                        f"{label}.margin", MISSING, "required with around: the width (m) to grow by"
                    )
                margin = self.number(entry["margin"], f"{label}.margin")
                if margin <= 0:
                    raise self.fail(f"{label}.margin", margin, "must be > 0 (metres)")
            else:
                if "margin" in entry:
                    raise self.fail(
                        f"{label}.margin", entry["margin"], "margin is only allowed with around"
                    )
                self.shape(entry, label)
            raw_zones.append((label, entry, margin))

        stations = []
        for i, entry in self.entries(data, "stations"):
            label = self.named(entry, "stations", i, _STATION_KEYS, ("name", "at"))
            x, y = self.point(entry["at"], f"{label}.at")
            kind = self.string(entry.get("kind", "delivery"), f"{label}.kind")
            stations.append((label, Station(entry["name"], x, y, kind)))

        rough = []
        for i, entry in self.entries(data, "rough_areas"):
            label = self.named(entry, "rough_areas", i, _ROUGH_KEYS, ("name", "severity"))
            poly = self.shape(entry, label)
            severity = self.number(entry["severity"], f"{label}.severity")
            if severity < 0:
                raise self.fail(f"{label}.severity", severity, "must be >= 0")
            rough.append((label, entry, RoughArea(entry["name"], poly, severity)))

        # Cross-checks, now that every name is known.
        for (label, entry), o in zip(raw_obstacles, obstacles, strict=True):
            self.within(o.polygon, boundary, label, entry, "obstacle")
        zones = self.zones(raw_zones, obstacles, boundary)
        for label, entry, r in rough:
            self.within(r.polygon, boundary, label, entry, "rough area")
        for label, s in stations:
            self.station(label, s, boundary, obstacles, clearance)

        return FloorSpec(
            source=self.source,
            name=name,
            boundary=boundary,
            default_v_max=default_v_max,
            clearance=clearance,
            obstacles=tuple(obstacles),
            zones=tuple(zones),
            stations=tuple(s for _, s in stations),
            rough_areas=tuple(r for _, _, r in rough),
            description=description,
            metadata=dict(metadata),
        )

    # -- structure ------------------------------------------------------------------------------
    def keys(
        self,
        table: Mapping[str, Any],
        field: str,
        allowed: tuple[str, ...],
        required: tuple[str, ...],
        where: str,
    ) -> None:
        prefix = f"{field}." if field else ""
        for key, value in table.items():
            if key not in allowed:
                raise self.fail(
                    f"{prefix}{key}",
                    value,
                    f"unknown key {where}; allowed keys: {', '.join(allowed)}",
                )
        for key in required:
            if key not in table:
                raise self.fail(f"{prefix}{key}", MISSING, f"required key {where} is missing")

    def table(self, value: Any, field: str, how: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(field, value, f"must be a table: write it as {how}")
        return value

    def entries(self, data: Mapping[str, Any], kind: str) -> Iterator[tuple[int, dict[str, Any]]]:
        value = data.get(kind, [])
        if not isinstance(value, list) or not all(isinstance(e, dict) for e in value):
            raise self.fail(
                kind, value, f"must be an array of tables: write each entry as [[{kind}]]"
            )
        return enumerate(value)

    def named(
        self,
        entry: dict[str, Any],
        kind: str,
        i: int,
        allowed: tuple[str, ...],
        required: tuple[str, ...],
    ) -> str:
        """Check an entry's keys and name; return its label, e.g. ``obstacles[2] (cnc_3)``."""
        plain = f"{kind}[{i}]"
        label = plain
        if "name" in entry:
            label = f"{plain} ({self.string(entry['name'], f'{plain}.name')})"
        self.keys(entry, label, allowed, required, where=f"in [[{kind}]]")
        name = entry["name"]
        if name in self.names:
            raise self.fail(
                f"{plain}.name",
                name,
                f"duplicate name: already used by {self.names[name]}; names must be unique across "
                "obstacles, zones, stations and rough areas",
            )
        self.names[name] = label
        return label

    # -- values ---------------------------------------------------------------------------------
    def string(self, value: Any, field: str, empty: bool = False) -> str:
        if not isinstance(value, str):
            raise self.fail(field, value, "must be a string (in double quotes)")
        if not empty and not value.strip():
            raise self.fail(field, value, "must not be empty")
        return value

    def number(self, value: Any, field: str) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.fail(field, value, "must be a number")
        if not math.isfinite(value):
            raise self.fail(field, value, "must be a finite number (not nan or inf)")
        return float(value)

    def speed(self, value: Any, field: str) -> tuple[float, float]:
        rule = "must be a speed > 0 (m/s): one number for both axes or [vx, vy]"
        if isinstance(value, list):
            if len(value) != 2:
                raise self.fail(field, value, rule)
            v = (self.number(value[0], f"{field}[0]"), self.number(value[1], f"{field}[1]"))
        else:
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise self.fail(field, value, rule)
            s = self.number(value, field)
            v = (s, s)
        if min(v) <= 0:
            raise self.fail(field, value, rule)
        return v

    def point(self, value: Any, field: str) -> tuple[float, float]:
        if not isinstance(value, list) or len(value) != 2:
            raise self.fail(field, value, "must be a point [x, y] of two numbers (metres)")
        return self.number(value[0], f"{field}[0]"), self.number(value[1], f"{field}[1]")

    def shape(
        self, entry: Mapping[str, Any], label: str, keys: tuple[str, str] = ("polygon", "rect")
    ) -> Polygon:
        """The entry's area, from exactly one of its polygon key or ``rect``."""
        poly_key, rect_key = keys
        given = [k for k in keys if k in entry]
        if len(given) == 2:
            raise self.fail(
                f"{label}.{rect_key}",
                entry[rect_key],
                f"give exactly one of {poly_key} or {rect_key}",
            )
        if not given:
            raise self.fail(
                f"{label}.{poly_key}",
                MISSING,
                f"required: give {poly_key} = [[x, y], ...] "
                f"or {rect_key} = [xmin, ymin, xmax, ymax]",
            )
        if given[0] == rect_key:
            return self.rect(entry[rect_key], f"{label}.{rect_key}")
        return self.polygon(entry[poly_key], f"{label}.{poly_key}")

    def rect(self, value: Any, field: str) -> Polygon:
        rule = "must be [xmin, ymin, xmax, ymax] with xmin < xmax and ymin < ymax (metres)"
        if not isinstance(value, list) or len(value) != 4:
            raise self.fail(field, value, rule)
        x0, y0, x1, y1 = (self.number(v, f"{field}[{k}]") for k, v in enumerate(value))
        if not (x0 < x1 and y0 < y1):
            raise self.fail(field, value, rule)
        return shapely.orient_polygons(box(x0, y0, x1, y1))

    def polygon(self, value: Any, field: str) -> Polygon:
        if not isinstance(value, list):
            raise self.fail(
                field, value, "must be a list of [x, y] vertices, e.g. [[0, 0], [4, 0], [4, 3]]"
            )
        pts = [self.point(v, f"{field}[{k}]") for k, v in enumerate(value)]
        if len(pts) > 1 and pts[0] == pts[-1]:
            pts = pts[:-1]  # a closing vertex is allowed but not needed
        if len(pts) < 3:
            raise self.fail(field, value, f"a polygon needs at least 3 vertices, got {len(pts)}")
        poly = Polygon(pts)
        # Checked before validity: shapely reports collinear vertices as a self-intersection.
        # (A bow-tie's signed area can be zero too, so use the hull, not the polygon's area.)
        if poly.convex_hull.area <= 1e-12:
            raise self.fail(field, value, "polygon has zero area (its vertices are collinear)")
        reason = shapely.is_valid_reason(poly)
        if reason != "Valid Geometry":
            m = re.search(r"\[([-\d.eE+]+) ([-\d.eE+]+)\]", reason)
            where = f" at ({float(m.group(1)):g}, {float(m.group(2)):g})" if m else ""
            raise self.fail(
                field,
                value,
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
        raw: list[tuple[str, dict[str, Any], float | None]],
        obstacles: list[Obstacle],
        boundary: Polygon,
    ) -> list[SpeedZone]:
        by_name = {entry["name"]: (label, entry, margin) for label, entry, margin in raw}
        obstacle_polys = {o.name: o.polygon for o in obstacles}
        full: dict[str, BaseGeometry] = {}  # unclipped shapes, so rings grow from the real shape

        def resolve(name: str, chain: tuple[str, ...]) -> BaseGeometry:
            if name in full:
                return full[name]
            label, entry, margin = by_name[name]
            if margin is None:
                shape = self.shape(entry, label)
                self.within(shape, boundary, label, entry, "zone")
            else:
                target = entry["around"]
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
                shape = grow(base, margin)
            full[name] = shape
            return shape

        zones = []
        for label, entry, margin in raw:
            shape = resolve(entry["name"], ())
            if margin is not None:
                shape = shapely.orient_polygons(shape.intersection(boundary))
                if isinstance(shape, MultiPolygon) and len(shape.geoms) == 1:
                    shape = shape.geoms[0]
            v_max = self.speed(entry["v_max"], f"{label}.v_max")
            zones.append(SpeedZone(entry["name"], shape, v_max))
        return zones

    def station(
        self,
        label: str,
        s: Station,
        boundary: Polygon,
        obstacles: list[Obstacle],
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
