"""`analyze`: a G-code file in, a `GcodeAnalysis` (timed, classified, merged tasks) out."""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fleet.errors import GcodeError
from fleet.printing import TASK_KINDS, PrintTask
from fleet.printing.gcode.features import feature_table
from fleet.printing.gcode.parse import EXTRUDE, TRAVEL, read_program
from fleet.printing.gcode.tasks import GcodeTask, merge, segments
from fleet.printing.gcode.timing import move_times

__all__ = ["GcodeAnalysis", "analyze"]

log = logging.getLogger("fleet.printing.gcode")


@dataclass(frozen=True)
class GcodeAnalysis:
    """What a G-code file asks of a MAMbot: how long it prints, and which task kind when.

    `by_kind_s` is the true time per kind (before merging); `tasks` are merged so none is
    shorter than `min_task_s` (unless the whole print is), contiguous from 0 to `total_s`.
    """

    file: str
    slicer: str | None
    total_s: float
    by_kind_s: dict[str, float]
    tasks: tuple[GcodeTask, ...]
    layers: int
    slicer_estimate_s: float | None
    warnings: tuple[str, ...] = ()
    min_task_s: float = 10.0
    #: Unknown feature names found in the file (classified "other").
    unknown_features: tuple[str, ...] = field(default=())

    @property
    def estimate_ratio(self) -> float | None:
        """Our total over the slicer's own estimate (None when the file has no estimate)."""
        if not self.slicer_estimate_s:
            return None
        return self.total_s / self.slicer_estimate_s

    def print_tasks(self) -> tuple[PrintTask, ...]:
        """The merged tasks as `fleet.printing.PrintTask`s, ready for a `PrintSchedule`."""
        return tuple(PrintTask(t.kind, t.start_s, t.end_s) for t in self.tasks)

    def to_json(self) -> dict[str, Any]:
        """A JSON-ready dict: file, slicer, total_s, by_kind_s, tasks (kind, start_s, end_s,
        layer), layers, slicer_estimate_s, estimate_ratio, min_task_s, warnings."""
        return {
            "file": self.file,
            "slicer": self.slicer,
            "total_s": self.total_s,
            "by_kind_s": dict(self.by_kind_s),
            "tasks": [
                {"kind": t.kind, "start_s": t.start_s, "end_s": t.end_s, "layer": t.layer}
                for t in self.tasks
            ],
            "layers": self.layers,
            "slicer_estimate_s": self.slicer_estimate_s,
            "estimate_ratio": self.estimate_ratio,
            "min_task_s": self.min_task_s,
            "warnings": list(self.warnings),
        }


def analyze(
    path: str | Path,
    *,
    min_task_s: float = 10.0,
    classification: Mapping[str, str] | None = None,
) -> GcodeAnalysis:
    """Time and classify a slicer's G-code and merge it into print tasks.

    Parameters
    ----------
    path:
        A text G-code file from PrusaSlicer, SuperSlicer, Cura or similar.
    min_task_s:
        Minimum task duration (s); shorter segments merge (see `fleet.printing.gcode.tasks`).
    classification:
        Feature name -> task kind, merged over `FEATURE_KINDS` (names case-insensitive),
        e.g. ``{"Gap fill": "contour"}``.

    Returns
    -------
    GcodeAnalysis

    Raises
    ------
    GcodeError
        Missing, binary, truncated or non-G-code file; no extrusion; a bad number (the message
        names the line); a bad `min_task_s` or a kind not in `fleet.printing.TASK_KINDS`.

    Examples
    --------
    >>> from fleet.scenario import REPO_ROOT
    >>> a = analyze(REPO_ROOT / "parts" / "prism_40x20x2.gcode")
    >>> a.slicer, a.layers
    ('PrusaSlicer 2.5.0', 182)
    >>> 0.9 < a.estimate_ratio < 1.1
    True
    """
    source = str(path)
    if not (isinstance(min_task_s, int | float) and math.isfinite(min_task_s) and min_task_s >= 0):
        raise GcodeError(source, "min_task_s", min_task_s, "a finite number of seconds >= 0")
    table = feature_table(classification, source)
    program = read_program(path)
    if not (program.motion == EXTRUDE).any():
        raise GcodeError(
            source,
            "(file)",
            f"{len(program.motion)} moves",
            "the file extrudes nothing (no move raises E while the head moves): nothing to print",
        )
    times = move_times(
        program.delta,
        program.length,
        program.feed,
        program.limits,
        list(program.limit_sets),
        program.dwell,
    )

    # Kind codes: index into TASK_KINDS. Extrusion takes its feature's kind; travel is travel;
    # everything else (extruder or Z alone, dwell) is other.
    code_of = {kind: i for i, kind in enumerate(TASK_KINDS)}
    unknown: list[str] = []
    feature_codes = []
    for name in program.features:
        kind = table.get(name.strip().lower())
        if kind is None:
            unknown.append(name)
            kind = "other"
        feature_codes.append(code_of[kind])
    by_feature = np.array([*feature_codes, code_of["other"]], dtype=np.int8)  # [-1] -> other
    codes = np.where(
        program.motion == EXTRUDE,
        by_feature[program.feature],
        np.where(program.motion == TRAVEL, code_of["travel"], code_of["other"]),
    )
    sums = np.bincount(codes, weights=times, minlength=len(TASK_KINDS))
    by_kind = {kind: float(sums[i]) for i, kind in enumerate(TASK_KINDS)}

    warnings: list[str] = []
    if unknown:
        msg = (
            f"{source}: {len(unknown)} unknown feature name(s) classified 'other': "
            + ", ".join(repr(u) for u in unknown)
            + "; map them with classification={name: kind} (CLI: --map NAME=KIND)"
        )
        log.warning(msg)
        warnings.append(msg)

    parts = segments(TASK_KINDS, codes, times, program.layer)
    tasks = merge(parts, float(min_task_s))
    total = tasks[-1].end_s if tasks else 0.0
    return GcodeAnalysis(
        file=source,
        slicer=program.slicer,
        total_s=total,
        by_kind_s=by_kind,
        tasks=tasks,
        layers=program.layers,
        slicer_estimate_s=program.slicer_estimate_s,
        warnings=tuple(warnings),
        min_task_s=float(min_task_s),
        unknown_features=tuple(unknown),
    )
