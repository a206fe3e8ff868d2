"""The classification table: which print task kind each slicer feature belongs to.

Slicers mark each stretch of G-code with a feature comment (``;TYPE:External perimeter`` in
PrusaSlicer, SuperSlicer and OrcaSlicer, ``;TYPE:WALL-OUTER`` in Cura). The kinds are
`fleet.printing.TASK_KINDS`; each kind may carry a speed cap, so the table decides how fast a
MAMbot may drive while it prints that feature:

- ``contour``: what the eye sees and the caliper measures (outer and overhang perimeters).
- ``infill``: everything inside and on the flat skins (inner perimeters, all infill kinds,
  bridges, top and bottom skins, gap fill, ironing).
- ``support``: support material and its interfaces, thrown away after the print.
- ``other``: skirt, brim, wipe and prime towers, the slicer's custom start and end code.
- ``travel``: never in the table; a move that does not extrude is travel or other whatever its
  feature (see `fleet.printing.gcode.parse`).

Names match case-insensitively (surrounding blanks ignored). A name not in the table is
classified ``other`` and reported once per file.
"""

from __future__ import annotations

from collections.abc import Mapping
from types import MappingProxyType

from fleet.errors import GcodeError
from fleet.printing import TASK_KINDS

__all__ = ["FEATURE_KINDS", "STRICTNESS", "stricter", "feature_table"]

_TABLE: dict[str, str] = {
    # --- PrusaSlicer 2.x, SuperSlicer, Slic3r PE (";TYPE:" comments) ---
    "External perimeter": "contour",
    "Overhang perimeter": "contour",
    "Perimeter": "infill",
    "Internal perimeter": "infill",  # SuperSlicer
    "Thin wall": "contour",  # SuperSlicer: single-width walls are outer surface
    "Internal infill": "infill",
    "Solid infill": "infill",
    "Top solid infill": "infill",
    "Bridge infill": "infill",
    "Internal bridge infill": "infill",  # SuperSlicer
    "Gap fill": "infill",
    "Ironing": "infill",
    "Support material": "support",
    "Support material interface": "support",
    "Skirt/Brim": "other",
    "Skirt": "other",
    "Brim": "other",
    "Wipe tower": "other",
    "Custom": "other",
    "Mixed": "other",
    "Milling": "other",  # SuperSlicer
    # --- OrcaSlicer (";TYPE:" with its own names) ---
    "Outer wall": "contour",
    "Overhang wall": "contour",
    "Inner wall": "infill",
    "Sparse infill": "infill",
    "Internal solid infill": "infill",
    "Top surface": "infill",
    "Bottom surface": "infill",
    "Bridge": "infill",
    "Internal Bridge": "infill",
    "Gap infill": "infill",
    "Support": "support",
    "Support interface": "support",
    "Support transition": "support",
    "Prime tower": "other",
    # --- Cura ---
    "WALL-OUTER": "contour",
    "WALL-INNER": "infill",
    "SKIN": "infill",
    "FILL": "infill",
    "SUPPORT": "support",
    "SUPPORT-INTERFACE": "support",
    "SKIRT": "other",
    "PRIME-TOWER": "other",
}

#: The default table, feature name (lower case) -> task kind. Read-only.
FEATURE_KINDS: Mapping[str, str] = MappingProxyType({k.lower(): v for k, v in _TABLE.items()})

#: Task kinds from strictest to loosest: a stricter kind never has a looser cap in the paper's
#: case study 3 (contour 0.3 m/s < infill 0.5 < support 0.7 < uncapped).
STRICTNESS: tuple[str, ...] = ("contour", "infill", "support", "other", "travel")
_RANK = {kind: i for i, kind in enumerate(STRICTNESS)}
assert set(STRICTNESS) == set(TASK_KINDS), "STRICTNESS must order exactly TASK_KINDS"


def stricter(a: str, b: str) -> str:
    """The stricter of two task kinds (`a` when they are equal)."""
    return a if _RANK[a] <= _RANK[b] else b


def feature_table(overrides: Mapping[str, str] | None, source: str) -> dict[str, str]:
    """The default table with `overrides` merged over it (names matched case-insensitively).

    Raises
    ------
    GcodeError
        An override maps to a kind that is not in `fleet.printing.TASK_KINDS`, or names an
        empty feature.
    """
    table = dict(FEATURE_KINDS)
    for name, kind in (overrides or {}).items():
        key = str(name).strip().lower()
        if not key:
            raise GcodeError(source, "classification", name, "a feature name must not be empty")
        if kind not in TASK_KINDS:
            raise GcodeError(
                source,
                f"classification[{name!r}]",
                kind,
                f"a feature's kind is one of {', '.join(TASK_KINDS)}",
            )
        table[key] = kind
    return table
