"""G-code analysis: a slicer's G-code becomes a timed sequence of print tasks.

The folder reads in the order data flows:

    parse.py     the file -> a Program (moves and dwells, with feature, layer, firmware limits)
    timing.py    a Program -> seconds per move (Marlin-style trapezoidal planner)
    features.py  the classification table: slicer feature name -> task kind
    tasks.py     timed, classified moves -> segments -> merged tasks (GcodeTask)
    analysis.py  `analyze(path)` -> GcodeAnalysis, tying the four together

The engine calls `analyze` once per part and prints `GcodeAnalysis.print_tasks()`; the CLI's
``fleet gcode FILE`` shows the same analysis. See docs/gcode.md.
"""

from __future__ import annotations

from fleet.printing.gcode.analysis import GcodeAnalysis, analyze
from fleet.printing.gcode.features import FEATURE_KINDS, STRICTNESS
from fleet.printing.gcode.tasks import GcodeTask
from fleet.printing.gcode.timing import DEFAULT_LIMITS, MachineLimits

__all__ = [
    "analyze",
    "GcodeAnalysis",
    "GcodeTask",
    "FEATURE_KINDS",
    "STRICTNESS",
    "MachineLimits",
    "DEFAULT_LIMITS",
]
