"""The map file's structure, described once, and how a value it refuses is worded.

`MapFile` is what `convert` checks a parsed TOML map against (with msgspec), and what
``fleet schema map`` prints as JSON Schema (each key's ``description`` is the help an editor
shows). The format is described for people in ``maps/README.md``. Rules that span keys or need
geometry (exactly one of polygon, rect or around; simple polygons within the boundary; unique
names; stations clear of obstacles) are checked by `fleet.floor.mapfile` after conversion.

A refusal becomes a `MapError` naming the field and quoting the value as written. A type may
carry ``Meta(extra={"rule": ...})``: the words the error uses when a value of that type is
refused. On a union the rule judges the value whole, so ``v_max = [0.5, -1]`` is one bad
speed, not a bad second number.
"""

from __future__ import annotations

import re
import sys
import types
from collections.abc import Mapping
from typing import Annotated, Any, Union, get_args, get_origin

import msgspec
from msgspec import Meta, Struct

from fleet.errors import MapError

__all__ = [
    "convert",
    "MISSING",
    "RECT_RULE",
    "MapFile",
    "FloorTable",
    "ObstacleEntry",
    "ZoneEntry",
    "StationEntry",
    "RoughAreaEntry",
]

# msgspec has no "finite" constraint; bounding by the largest float refuses TOML's inf, and nan
# fails every comparison.
_LARGEST = sys.float_info.max

#: Metres on the floor. Bounded well inside what geometry can square without overflow: at
#: 1e308 shapely fails with NaN/Inf, at 1e160 numpy overflows.
COORDINATE_LIMIT_M = 1e6
Coordinate = Annotated[
    float,
    Meta(
        ge=-COORDINATE_LIMIT_M,
        le=COORDINATE_LIMIT_M,
        extra={"rule": "must be a finite number of metres within ±1,000,000"},
    ),
]
NonNegative = Annotated[float, Meta(ge=0, le=_LARGEST)]
Positive = Annotated[float, Meta(gt=0, le=_LARGEST)]

Name = Annotated[
    str,
    Meta(
        pattern=r"\S",
        extra={"rule": "must be a string (in double quotes) and must not be empty"},
    ),
]

EntryName = Annotated[
    Name, Meta(description="Unique across obstacles, zones, stations and rough areas.")
]

Point = Annotated[
    tuple[Coordinate, Coordinate],
    Meta(extra={"rule": "must be a point [x, y] of two numbers (metres)"}),
]

Outline = Annotated[
    list[Point],
    Meta(
        description="A simple polygon [[x, y], ...] (m), at least 3 vertices; a closing vertex "
        "is allowed but not needed.",
        extra={"rule": "must be a list of [x, y] vertices, e.g. [[0, 0], [4, 0], [4, 3]]"},
    ),
]

RECT_RULE = "must be [xmin, ymin, xmax, ymax] with xmin < xmax and ymin < ymax (metres)"

Rect = Annotated[
    tuple[Coordinate, Coordinate, Coordinate, Coordinate],
    Meta(
        description="[xmin, ymin, xmax, ymax] (m), instead of a polygon.",
        extra={"rule": RECT_RULE},
    ),
]

# Not tuple[Positive, Positive]: msgspec 0.22.0 crashes on a union of a constrained float and
# a fixed-length tuple; a list of length 2 says the same.
Speed = Annotated[
    Positive | Annotated[list[Positive], Meta(min_length=2, max_length=2)],
    Meta(
        description="Per-axis speed limit (m/s): one number for both axes, or [vx, vy].",
        extra={"rule": "must be a speed > 0 (m/s): one number for both axes or [vx, vy]"},
    ),
]


class _Table(Struct, forbid_unknown_fields=True):
    """A TOML table: unknown keys refused (subclasses inherit this; keys go in any order)."""


class FloorTable(_Table, kw_only=True):
    """[floor]: the hall's outline, its default speed limit and the robots' clearance."""

    name: Annotated[Name, Meta(description="The floor's name.")]
    description: Annotated[str, Meta(description="Free text.")] = ""
    boundary: Annotated[Outline | None, Meta(description="The hall outline (or rect).")] = None
    rect: Rect | None = None
    default_v_max: Annotated[Speed, Meta(description="The limit wherever no zone applies.")]
    clearance: Annotated[
        NonNegative,
        Meta(
            description="Robot footprint radius (m): the boundary is shrunk and obstacles grown "
            "by it."
        ),
    ] = 0.0


class ObstacleEntry(_Table, kw_only=True):
    """[[obstacles]]: a machine or other area robots must not enter."""

    name: EntryName
    polygon: Outline | None = None
    rect: Rect | None = None


class ZoneEntry(_Table, kw_only=True):
    """[[zones]]: an area with a per-axis speed limit; where zones overlap, the lowest wins."""

    name: EntryName
    polygon: Outline | None = None
    rect: Rect | None = None
    around: Annotated[
        Name | None,
        Meta(description="An obstacle or zone the zone grows around by margin (not with a shape)."),
    ] = None
    margin: Annotated[Positive | None, Meta(description="Width (m) to grow by, with around.")] = (
        None
    )
    v_max: Speed


class StationEntry(_Table, kw_only=True):
    """[[stations]]: a named point robots drive to."""

    name: EntryName
    at: Annotated[Point, Meta(description="[x, y] (m).")]
    kind: Annotated[Name, Meta(description='Free text, e.g. "depot", "delivery", "charger".')] = (
        "delivery"
    )


class RoughAreaEntry(_Table, kw_only=True):
    """[[rough_areas]]: bumps, cable ducts, floor joints."""

    name: EntryName
    polygon: Outline | None = None
    rect: Rect | None = None
    severity: Annotated[
        NonNegative, Meta(description="How hard the area shakes a printing robot (>= 0).")
    ]


def _entries(kind: str) -> Meta:
    """What an array of `kind` tables must look like, for its errors."""
    return Meta(extra={"rule": f"must be an array of tables: write each entry as [[{kind}]]"})


class MapFile(_Table, kw_only=True):
    """A floor map: the hall, its machines, speed zones, stations and rough areas (metres, m/s)."""

    floor: Annotated[FloorTable, Meta(extra={"rule": "must be a table: write it as [floor]"})]
    obstacles: Annotated[list[ObstacleEntry], _entries("obstacles")] = []
    zones: Annotated[list[ZoneEntry], _entries("zones")] = []
    stations: Annotated[list[StationEntry], _entries("stations")] = []
    rough_areas: Annotated[list[RoughAreaEntry], _entries("rough_areas")] = []
    metadata: Annotated[
        dict[str, Any],
        Meta(
            description="Any table; kept, otherwise ignored.",
            extra={"rule": "must be a table ([metadata])"},
        ),
    ] = {}


# -- what msgspec refused, restated ------------------------------------------------------------
# msgspec says where a value broke the structure ("... - at `$.zones[0].v_max`") but not the
# value, and in its own words. `_refusal` follows the path through the raw tables and the
# declared types together, to quote the value as written and say what its type allows: the
# rule the type carries, or msgspec's words in ours.


class _Missing:
    """Stands for the value of a required key that is absent."""

    def __repr__(self) -> str:
        return "<missing>"


#: What errors quote as the value of a required key that is absent.
MISSING: Any = _Missing()


def convert(raw: Mapping[str, Any], source: str) -> MapFile:
    """The parsed TOML map `raw` as a `MapFile`, or a `MapError` naming `source`, the field and
    the value as written."""
    try:
        return msgspec.convert(raw, MapFile)
    except msgspec.ValidationError as exc:
        raise _refusal(str(exc), raw, source) from None


_MESSAGE = re.compile(r"(?P<what>.*?)(?: - at `(?P<at>[^`]*)`)?")
_STEP = re.compile(r"\.(\w+)|\[(\d+)\]")
_FIELD = re.compile(r"Object (?P<kind>contains unknown|missing required) field `(?P<name>\w+)`")
_TYPES = re.compile(r"Expected `(?P<expected>[^`]+)`, got `\w+`")
_BOUND = re.compile(r"Expected `(?:int|float)` (?P<op>[<>]=?) (?P<bound>\S+)")
_TYPE_WORDS = {
    "str": "a string (in double quotes)",
    "float": "a number",
    "int": "a whole number",
    "bool": "true or false",
    "object": "a table",
    "array": "an array",
}


def _refusal(message: str, raw: Mapping[str, Any], source: str) -> MapError:
    """The `MapError` msgspec's `message` about the map `raw` means."""
    match = _MESSAGE.fullmatch(message)
    assert match is not None  # every message matches: its location is optional
    what = match["what"]
    steps = [name or index for name, index in _STEP.findall(match["at"] or "$")]
    declared: Any = MapFile
    value: Any = raw
    field = ""
    for step in steps:
        if _is_union(declared) and _own_rule(declared):
            break  # the union's rule judges the value whole, e.g. a speed [vx, vy]
        bare = _bare(_member(declared))
        if step.isdigit():
            items = get_args(bare)
            declared = items[int(step)] if get_origin(bare) is tuple else items[0]
            field, value = f"{field}[{step}]", value[int(step)]
        else:
            declared = _fields(bare)[step]
            field, value = f"{_label(field, value, step)}.{step}" if field else step, value[step]

    known = _FIELD.fullmatch(what)
    if known is None:
        return MapError(source, field, value, _rule(what, declared))
    name = known["name"]
    inner = f"{_label(field, value, name)}.{name}" if field else name
    where = (
        "at the top level"
        if not steps
        else f"in [[{steps[0]}]]"
        if len(steps) > 1
        else f"in [{steps[0]}]"
    )
    if known["kind"] == "missing required":
        return MapError(source, inner, MISSING, f"required key {where} is missing")
    allowed = ", ".join(_fields(_bare(declared)))
    return MapError(source, inner, value[name], f"unknown key {where}; allowed keys: {allowed}")


def _label(field: str, table: Any, key: str) -> str:
    """How errors name the entry `field` when pointing at its `key`: with the entry's name,
    e.g. ``obstacles[2] (cnc_3)``, once it has a usable one."""
    name = table.get("name") if isinstance(table, dict) else None
    if field.endswith("]") and key != "name" and isinstance(name, str) and name.strip():
        return f"{field} ({name})"
    return field


def _rule(what: str, declared: Any) -> str:
    """What `declared` allows, for a value msgspec refused with `what`."""
    rule = _own_rule(declared) or _own_rule(_member(declared))
    if rule:
        return rule
    if expected := _TYPES.fullmatch(what):
        words = [_TYPE_WORDS.get(t, t) for t in expected["expected"].split(" | ") if t != "null"]
        return f"must be {' or '.join(words)}"
    if bound := _BOUND.fullmatch(what):
        limit = float(bound["bound"])
        if abs(limit) == _LARGEST:
            return "must be a finite number (not nan or inf)"
        return f"must be {bound['op']} {limit:g}"
    return what


def _own_rule(declared: Any) -> str | None:
    """The rule `declared` carries in its ``Meta(extra={"rule": ...})``, if any."""
    for meta in getattr(declared, "__metadata__", ()):
        if isinstance(meta, msgspec.Meta) and meta.extra and "rule" in meta.extra:
            return meta.extra["rule"]
    return None


def _bare(declared: Any) -> Any:
    """`declared` without its `Annotated` metadata."""
    return get_args(declared)[0] if get_origin(declared) is Annotated else declared


def _is_union(declared: Any) -> bool:
    return get_origin(_bare(declared)) in (Union, types.UnionType)


def _member(declared: Any) -> Any:
    """An optional key's type without its None (TOML has no null, so a value is never None)."""
    if not _is_union(declared):
        return declared
    members = [m for m in get_args(_bare(declared)) if m is not type(None)]
    return members[0] if len(members) == 1 else declared


def _fields(struct: type[msgspec.Struct]) -> dict[str, Any]:
    """A struct's declared types by the keys the file uses, in the order it declares them."""
    return {f.encode_name: f.type for f in msgspec.structs.fields(struct)}
