"""The print domain: print tasks and their speed caps, G-code analysis, part quality.

`schedule` (what a MAMbot prints when, and the speed cap of each task; re-exported here),
`gcode` (a slicer's G-code -> timed print tasks), `quality` (quality-speed profiles and a
printed part's predicted error; the paper's calibration tables ship in ``data/``). This room
imports `fleet.errors`, and `fleet.floor` for the quality model's bumps.
"""

from fleet.printing.schedule import PAPER_CAPS, TASK_KINDS, CapSchedule, PrintSchedule, PrintTask

__all__ = ["PrintTask", "PrintSchedule", "CapSchedule", "TASK_KINDS", "PAPER_CAPS"]
