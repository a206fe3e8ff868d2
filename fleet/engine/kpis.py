"""KPIs over time: the queue and the WIP, waits for assignment, the lead-time distribution, and
the files that hold them (``wip.csv``, ``states.csv``).

The queue is the jobs released and not assigned (a job handed back joins it again), the WIP
(work in progress) the jobs released and neither delivered nor failed; both are read from the
run's events, so they change exactly when a job is released, assigned, handed back, delivered
or fails. The waits and lead times of the KPIs leave out the warm-up (`Scenario.warmup_s`): a
wait counts when its assignment came at or after it, a lead time when its delivery did.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from fleet.engine.jobs import JobRecord
from fleet.engine.recorder import Event
from fleet.engine.warmup import suggest_warmup

__all__ = [
    "queue_wip",
    "time_mean",
    "spread",
    "job_kpis",
    "wip_rows",
    "STATES_CSV",
    "WIP_CSV",
]

STATES_CSV = "states.csv"
WIP_CSV = "wip.csv"

#: How each event moves (queue, wip).
_STEPS = {
    "released": (1, 1),
    "assigned": (-1, 0),
    "handed_back": (1, 0),  # open again ...
    "reoffered": (1, 0),  # taken back from a busy robot's queue, open again
    "failed": (-1, -1),  # ... unless it was given up (its hand-back came first)
    "delivered": (0, -1),
}


def queue_wip(events: Iterable[Event]) -> list[tuple[float, int, int]]:
    """``(t, queue, wip)`` from t = 0 and at every time either changes (the values after all
    of that instant's events)."""
    rows: list[tuple[float, int, int]] = [(0.0, 0, 0)]
    queue = wip = 0
    for e in events:
        step = _STEPS.get(e.event)
        if step is None:
            continue
        queue += step[0]
        wip += step[1]
        if e.t == rows[-1][0]:
            rows[-1] = (e.t, queue, wip)
        elif (queue, wip) != rows[-1][1:]:
            rows.append((e.t, queue, wip))
    return rows


def time_mean(t: Sequence[float], v: Sequence[float], start: float, end: float) -> float | None:
    """The time-weighted mean over ``[start, end)`` of the step signal ``v[i]`` over ``[t[i],
    t[i+1])`` (None for an empty window)."""
    if end <= start:
        return None
    knots = np.clip(np.append(np.asarray(t, dtype=float), end), start, end)
    return float(np.sum(np.asarray(v, dtype=float) * np.diff(knots)) / (end - start))


def spread(values: Sequence[float]) -> dict[str, Any]:
    """n, mean, p50, p95 and max of `values` (None when there are none), rounded to the us."""
    if not values:
        return {"n": 0, "mean": None, "p50": None, "p95": None, "max": None}
    a = np.asarray(values, dtype=float)
    return {
        "n": int(a.size),
        "mean": round(float(a.mean()), 6),
        "p50": round(float(np.percentile(a, 50)), 6),
        "p95": round(float(np.percentile(a, 95)), 6),
        "max": round(float(a.max()), 6),
    }


def job_kpis(
    jobs: Iterable[JobRecord], events: Iterable[Event], start: float, end: float
) -> dict[str, Any]:
    """summary.json's KPIs over time: ``assign_wait_s`` (from release to first assignment),
    ``lead_time_s`` (release to delivery) spreads, the time-weighted ``queue_mean`` and
    ``wip_mean`` over ``[start, end)`` with their maxima over the run, and
    ``suggested_warmup_s`` (MSER-5 on the WIP over the whole run, `fleet.engine.warmup`) with
    ``suggested_warmup_at_limit`` (it is the longest the search allows: run longer)."""
    events = list(events)
    released = {rec.job.id: rec.job.released_s for rec in jobs}
    first: dict[str, float] = {}
    for e in events:
        if e.event == "assigned" and e.job not in first:
            first[e.job] = e.t
    waits = [t - released[j] for j, t in first.items() if t >= start and j in released]
    leads = [
        rec.delivered_s - rec.job.released_s
        for rec in jobs
        if rec.delivered_s is not None and rec.delivered_s >= start
    ]
    series = queue_wip(events)
    t = [r[0] for r in series]
    queue = [r[1] for r in series]
    wip = [r[2] for r in series]
    qm, wm = time_mean(t, queue, start, end), time_mean(t, wip, start, end)
    suggested, at_limit = suggest_warmup(t, wip, end) if end > 0 else (0.0, False)
    return {
        "assign_wait_s": spread(waits),
        "lead_time_s": spread(leads),
        "queue_mean": None if qm is None else round(qm, 6),
        "queue_max": max(queue),
        "wip_mean": None if wm is None else round(wm, 6),
        "wip_max": max(wip),
        "suggested_warmup_s": round(suggested, 6),
        "suggested_warmup_at_limit": at_limit,
    }


def wip_rows(events: Iterable[Event]) -> list[tuple[str, int, int]]:
    """``wip.csv`` rows: t, queue, wip (see `queue_wip`)."""
    return [(f"{t:.6f}", q, w) for t, q, w in queue_wip(events)]
