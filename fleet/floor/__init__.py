"""Floor maps: the map-file format, validation, convex decomposition and the compiled floor."""

from fleet.floor.build import compile_floor, load_floor, slow_on_rough
from fleet.floor.compiled import Floor, Region, halfspaces
from fleet.floor.decompose import convex_pieces
from fleet.floor.mapfile import load_spec, parse_spec
from fleet.floor.spec import FloorSpec, Obstacle, RoughArea, SpeedZone, Station

__all__ = [
    "Floor",
    "Region",
    "halfspaces",
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
