"""What a floor map file says, as typed values (before any geometry is compiled).

All lengths are metres, all speeds metres per second. A speed limit is per axis, as in the
paper: ``v_max = (vx, vy)`` means ``|vx_robot| <= vx`` and ``|vy_robot| <= vy``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from shapely.geometry import MultiPolygon, Polygon

__all__ = ["Obstacle", "SpeedZone", "Station", "RoughArea", "FloorSpec"]


@dataclass(frozen=True)
class Obstacle:
    """A machine or other area the robot's body must never overlap."""

    name: str
    polygon: Polygon


@dataclass(frozen=True)
class SpeedZone:
    """An area with a per-axis speed limit; where zones overlap the lowest limit wins."""

    name: str
    polygon: Polygon | MultiPolygon  # an `around` zone clipped by the floor may split
    v_max: tuple[float, float]


@dataclass(frozen=True)
class Station:
    """A named point robots drive to: a depot, a delivery point, a charger."""

    name: str
    x: float
    y: float
    kind: str = "delivery"


@dataclass(frozen=True)
class RoughArea:
    """Uneven floor (bumps, cable ducts); `severity` feeds the print-quality model."""

    name: str
    polygon: Polygon
    severity: float


@dataclass(frozen=True)
class FloorSpec:
    """A whole map file, validated but not yet decomposed into convex regions.

    `clearance` is the robot's footprint radius used to build the configuration space: the
    boundary is shrunk and obstacles are grown by it, so the robot is treated as a point.
    """

    source: str
    name: str
    boundary: Polygon
    default_v_max: tuple[float, float]
    clearance: float = 0.0
    obstacles: tuple[Obstacle, ...] = ()
    zones: tuple[SpeedZone, ...] = ()
    stations: tuple[Station, ...] = ()
    rough_areas: tuple[RoughArea, ...] = ()
    description: str = ""
    metadata: dict[str, object] = field(default_factory=dict)
