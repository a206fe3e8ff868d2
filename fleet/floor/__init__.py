"""Floor maps: the map-file format, validation, convex decomposition and the compiled floor.

`mapspec` describes the map file's structure (``fleet schema map`` prints it as JSON Schema) and
words what it refuses; `mapfile` checks a file against it and the geometry into a `FloorSpec`;
`decompose` and `build` make the compiled `Floor` (`compiled`): convex regions in
H-representation and their adjacency graph. This room imports only `fleet.errors`.
"""

from fleet.floor.build import compile_floor, load_floor, slow_on_rough
from fleet.floor.compiled import BOUNDARY_BAND, Floor, Region, halfspaces
from fleet.floor.decompose import convex_pieces
from fleet.floor.mapfile import load_spec, parse_spec
from fleet.floor.mapspec import MapFile
from fleet.floor.spec import FloorSpec, Obstacle, RoughArea, SpeedZone, Station

__all__ = [
    "BOUNDARY_BAND",
    "Floor",
    "Region",
    "halfspaces",
    "MapFile",
    "FloorSpec",
    "Obstacle",
    "RoughArea",
    "SpeedZone",
    "Station",
    "load_spec",
    "parse_spec",
    "compile_floor",
    "load_floor",
    "slow_on_rough",
    "convex_pieces",
]
