"""From timed moves to print tasks a robot can follow: segments, then merging.

A *segment* is a maximal stretch of consecutive moves of the same kind. Slicers switch features
every few seconds (outer wall, inner wall, a short travel, infill...), and a robot cannot change
its speed that often, so segments shorter than a minimum task duration are merged. The rule is
safe: a merged stretch always takes the *strictest* kind it contains, so its speed cap never
loosens (strictness: contour > infill > support > other > travel, `STRICTNESS`).

Merging, with ``min_task_s`` the minimum task duration:

1. Every maximal run of consecutive segments each shorter than ``min_task_s`` becomes one task
   of the strictest kind in the run. Segments of at least ``min_task_s`` stay as they are.
2. A task from step 1 that is still shorter than ``min_task_s`` joins a neighbour (these are
   always segments of at least ``min_task_s``, or the ends of the print) and the stricter kind of
   the two wins. Of the two neighbours it joins the one that tightens the fewest seconds: joining
   a stricter neighbour tightens the short task's own seconds, joining a looser one tightens the
   whole neighbour, an equal kind tightens nothing; a tie goes to the earlier neighbour. Short
   tasks are handled in time order, each seeing the kinds its neighbours have by then.
3. Neighbouring tasks of the same kind join into one (the robot keeps its speed cap).
4. A print that is shorter than ``min_task_s`` altogether is one task.

Tasks are contiguous: each starts where the previous ends, the first at 0 and the last at the
print's total time. A task's layer is the layer at its start.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fleet.printing.gcode.features import STRICTNESS, stricter

__all__ = ["GcodeTask", "segments", "merge"]

_RANK = {kind: i for i, kind in enumerate(STRICTNESS)}


@dataclass(frozen=True, slots=True)
class GcodeTask:
    """One stretch of a print with a single task kind, in seconds after the first move."""

    kind: str
    start_s: float
    end_s: float
    #: 0-based layer index where the task starts.
    layer: int

    @property
    def duration_s(self) -> float:
        return self.end_s - self.start_s


def segments(
    kinds: Sequence[str], codes: np.ndarray, times: np.ndarray, layers: np.ndarray
) -> list[GcodeTask]:
    """Maximal runs of consecutive entries of one kind, timed by the entries' durations.

    Parameters
    ----------
    kinds:
        Kind names, indexed by `codes`.
    codes, times, layers:
        Per entry: kind code, seconds, layer. Entries that take no time are left out, so they
        never split a segment.
    """
    keep = times > 0
    codes, times, layers = codes[keep], times[keep], layers[keep]
    if len(codes) == 0:
        return []
    ends = np.cumsum(times)
    starts = np.concatenate([[0.0], ends[:-1]])
    first = np.flatnonzero(np.concatenate([[True], codes[1:] != codes[:-1]]))
    last = np.concatenate([first[1:] - 1, [len(codes) - 1]])
    return [
        GcodeTask(kinds[int(codes[i])], float(starts[i]), float(ends[j]), int(layers[i]))
        for i, j in zip(first.tolist(), last.tolist(), strict=True)
    ]


def merge(parts: Sequence[GcodeTask], min_task_s: float) -> tuple[GcodeTask, ...]:
    """Merge short segments into tasks of at least `min_task_s` (see the module docstring)."""
    if not math.isfinite(min_task_s) or min_task_s < 0:
        raise ValueError(f"min_task_s must be a finite number >= 0, got {min_task_s!r}")
    if not parts:
        return ()
    # Step 1: runs of short segments collapse; `short` marks the collapsed runs still short.
    out: list[GcodeTask] = []
    short: list[bool] = []
    run: list[GcodeTask] = []

    def close_run() -> None:
        if not run:
            return
        kind = run[0].kind
        for seg in run[1:]:
            kind = stricter(kind, seg.kind)
        task = GcodeTask(kind, run[0].start_s, run[-1].end_s, run[0].layer)
        out.append(task)
        short.append(task.duration_s < min_task_s)
        run.clear()

    for seg in parts:
        if seg.duration_s < min_task_s:
            run.append(seg)
        else:
            close_run()
            out.append(seg)
            short.append(False)
    close_run()
    if len(out) == 1:
        return tuple(out)

    # Step 2: each still-short task joins its cheaper neighbour, in time order.
    tasks: list[GcodeTask | None] = list(out)
    for i, is_short in enumerate(short):
        if not is_short:
            continue
        me = tasks[i]
        assert me is not None
        prev_i = next((k for k in range(i - 1, -1, -1) if tasks[k] is not None), None)
        next_i = i + 1 if i + 1 < len(tasks) else None
        options = [k for k in (prev_i, next_i) if k is not None]
        k = min(options, key=lambda k: (_tightened(me, tasks[k]), k != prev_i))  # type: ignore[arg-type]
        other = tasks[k]
        assert other is not None
        a, b = (other, me) if k == prev_i else (me, other)
        tasks[k] = GcodeTask(stricter(me.kind, other.kind), a.start_s, b.end_s, a.layer)
        tasks[i] = None
    return _coalesce([t for t in tasks if t is not None])


def _coalesce(tasks: list[GcodeTask]) -> tuple[GcodeTask, ...]:
    """Join neighbouring tasks of the same kind (no speed change happens between them)."""
    out: list[GcodeTask] = []
    for t in tasks:
        if out and out[-1].kind == t.kind:
            out[-1] = GcodeTask(t.kind, out[-1].start_s, t.end_s, out[-1].layer)
        else:
            out.append(t)
    return tuple(out)


def _tightened(short: GcodeTask, neighbour: GcodeTask) -> float:
    """Seconds whose cap gets stricter when `short` joins `neighbour`."""
    if _RANK[neighbour.kind] < _RANK[short.kind]:
        return short.duration_s
    if _RANK[neighbour.kind] > _RANK[short.kind]:
        return neighbour.duration_s
    return 0.0
