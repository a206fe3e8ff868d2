"""A warm-up suggestion by MSER-5 (White 1997; White, Cobb and Spratt 2000).

A run starts empty: no job waits, every robot is home. Its first stretch is a start-up transient,
and averages over the whole run carry its bias. MSER-5 picks where to cut: the series is
averaged in batches of 5 observations, and the truncation ``d`` (in batches) is the one that
minimises the squared standard error of the mean of what remains,

    MSER(d) = sum_{j > d} (Y_j - mean_{j > d} Y)^2 / (n - d)^2,

searched over the first half of the batches only (beyond that the statistic rewards cutting
away nearly everything). Here the series is a piecewise-constant signal over time (the WIP of a
run), so it is first made into observations: its time-weighted means over a regular grid.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

__all__ = ["BATCH", "grid_means", "mser5", "suggest_warmup"]

#: Observations per batch (MSER-5).
BATCH = 5
#: Grid cells a run's series is averaged over before batching (so 200 batches of 5).
GRID_CELLS = 1000


def grid_means(
    t: Sequence[float], v: Sequence[float], end: float, cells: int = GRID_CELLS
) -> np.ndarray:
    """Time-weighted means of the step signal that is ``v[i]`` over ``[t[i], t[i+1])`` (the last
    value until `end`) on `cells` equal cells of ``[t[0], end)``."""
    times = np.asarray(t, dtype=float)
    values = np.asarray(v, dtype=float)
    if times.size == 0 or end <= times[0] or cells < 1:
        return np.zeros(0)
    edges = np.linspace(times[0], end, cells + 1)
    # Integral of the signal from t[0] up to each change, then up to each cell edge.
    knots = np.append(times, end)
    area = np.concatenate([[0.0], np.cumsum(values * np.diff(knots))])
    i = np.clip(np.searchsorted(times, edges, side="right") - 1, 0, times.size - 1)
    at_edges = area[i] + values[i] * (edges - times[i])
    return np.diff(at_edges) / np.diff(edges)


def mser5(series: Sequence[float], batch: int = BATCH) -> int:
    """The MSER-5 truncation: how many leading observations of `series` to drop (a multiple of
    `batch`; 0 for a series too short to batch twice)."""
    y = np.asarray(series, dtype=float)
    n = y.size // batch
    if n < 2:
        return 0
    means = y[: n * batch].reshape(n, batch).mean(axis=1)
    stats = [
        float(np.sum((means[d:] - means[d:].mean()) ** 2)) / (n - d) ** 2 for d in range(n // 2 + 1)
    ]
    return int(np.argmin(stats)) * batch  # ties keep the shorter warm-up (the first minimum)


def suggest_warmup(
    t: Sequence[float], v: Sequence[float], end: float, cells: int = GRID_CELLS
) -> tuple[float, bool]:
    """The warm-up (s) MSER-5 suggests for the step signal `v` at change times `t` (starting at
    ``t[0]``) over a run ending at `end` (the truncation in grid cells times the cell width),
    and whether it is the longest the search allows (about half the run: the series has not
    settled, or trends all along, and a longer run is needed to judge)."""
    means = grid_means(t, v, end, cells)
    n = means.size // BATCH
    if n < 2:
        return 0.0, False
    width = (end - float(t[0])) / means.size
    cut = mser5(means)
    return float(t[0]) + cut * width, cut == (n // 2) * BATCH
