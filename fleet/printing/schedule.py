"""Print schedules: which task a MAMbot prints when, and the speed cap each task imposes.

A print is a sequence of `PrintTask`s (contour, infill, support, ...) with times relative to the
moment printing starts. Each task kind may carry a per-axis speed cap (m/s): motion spoils print
quality, so the robot must drive no faster than the cap of the task it is printing. Placed on the
simulation clock (`PrintSchedule.caps_from`), a schedule becomes a `CapSchedule`: absolute
``(start_s, end_s, cap)`` pieces that controllers honour over their horizon and the safety checker
judges.

Semantics (as for zone limits): the velocity ``v[k]`` of step k is held over
``[t_k, t_k + dt)``, so it must respect every cap piece that overlaps that interval.
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

__all__ = ["PrintTask", "PrintSchedule", "CapSchedule", "TASK_KINDS", "PAPER_CAPS"]

#: Task kinds the project knows (the G-code layer maps slicer features onto these).
TASK_KINDS = ("contour", "infill", "support", "travel", "other")

#: The per-axis caps (m/s) the paper's case study 3 uses for each print task.
PAPER_CAPS: Mapping[str, float] = {"contour": 0.3, "infill": 0.5, "support": 0.7}


@dataclass(frozen=True, slots=True)
class PrintTask:
    """One stretch of printing of one kind, in seconds after printing starts."""

    kind: str
    start_s: float
    end_s: float


@dataclass(frozen=True)
class PrintSchedule:
    """A part's print tasks plus the cap of each task kind (kinds without a cap are free).

    The tasks are sorted by start, non-overlapping; gaps between them carry no cap.
    """

    tasks: tuple[PrintTask, ...]
    caps: Mapping[str, float]

    def __post_init__(self) -> None:
        previous = -math.inf
        for i, task in enumerate(self.tasks):
            if not (math.isfinite(task.start_s) and math.isfinite(task.end_s)):
                raise ValueError(f"print task {i} ({task.kind}): times must be finite")
            if task.end_s <= task.start_s:
                raise ValueError(
                    f"print task {i} ({task.kind}): end_s {task.end_s:g} must be after "
                    f"start_s {task.start_s:g}"
                )
            if task.start_s < previous - 1e-9:
                raise ValueError(
                    f"print task {i} ({task.kind}) starts at {task.start_s:g} s, before the "
                    f"previous task ends ({previous:g} s): tasks must be in order, not overlapping"
                )
            previous = task.end_s

    @property
    def duration_s(self) -> float:
        """Seconds from the print's start to the end of its last task (0 for no tasks)."""
        return self.tasks[-1].end_s if self.tasks else 0.0

    def caps_from(self, t0: float) -> CapSchedule:
        """The capped tasks placed on the simulation clock with printing starting at `t0`."""
        return CapSchedule(
            tuple(
                (t0 + task.start_s, t0 + task.end_s, float(self.caps[task.kind]))
                for task in self.tasks
                if task.kind in self.caps
            )
        )


@dataclass(frozen=True)
class CapSchedule:
    """Absolute per-axis speed caps: sorted, non-overlapping ``(start_s, end_s, cap)`` pieces.

    Outside every piece there is no cap. An empty schedule caps nothing.
    """

    pieces: tuple[tuple[float, float, float], ...] = ()

    def __post_init__(self) -> None:
        previous = -math.inf
        for i, (start, end, cap) in enumerate(self.pieces):
            if not end > start or start < previous - 1e-9 or not cap >= 0:
                raise ValueError(
                    f"cap piece {i} = ({start!r}, {end!r}, {cap!r}): pieces must be in order, "
                    "non-overlapping, end after start, cap >= 0"
                )
            previous = end
        object.__setattr__(self, "_starts", [p[0] for p in self.pieces])

    @classmethod
    def from_pieces(cls, pieces: Iterable[Iterable[float]]) -> CapSchedule:
        return cls(tuple((float(a), float(b), float(c)) for a, b, c in pieces))

    def __bool__(self) -> bool:
        return bool(self.pieces)

    def cap_over(self, t0: float, t1: float) -> float:
        """The tightest cap of any piece overlapping ``[t0, t1)``; ``inf`` when none does."""
        starts: list[float] = self._starts  # type: ignore[attr-defined]
        i = max(0, bisect.bisect_right(starts, t0) - 1)
        best = math.inf
        for start, end, cap in self.pieces[i:]:
            if start >= t1:
                break
            if end > t0 and cap < best:
                best = cap
        return best

    def step_caps(self, t0: float, dt: float, n: int) -> np.ndarray:
        """Caps for the `n` steps ``[t0 + k dt, t0 + (k+1) dt)``, k = 0..n-1 (``inf``: none)."""
        # A piece boundary that falls on a step boundary up to rounding must not leak the
        # neighbouring piece's cap into the step.
        eps = 1e-9 * max(1.0, abs(t0))
        return np.array(
            [self.cap_over(t0 + k * dt + eps, t0 + (k + 1) * dt - eps) for k in range(n)]
        )

    def window(self, t0: float, t1: float) -> CapSchedule:
        """The pieces overlapping ``[t0, t1)``, cropped to it."""
        out = []
        for start, end, cap in self.pieces:
            if start >= t1:
                break
            if end > t0:
                out.append((max(start, t0), min(end, t1), cap))
        return CapSchedule(tuple(out))
