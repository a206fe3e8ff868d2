"""Floor maps: the map-file format, validation, convex decomposition and the compiled floor."""

from fleet.floor.compiled import Floor, Region, halfspaces
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
]
