"""The statistics of a study's comparisons: Student t intervals from scipy, paired on common seeds.

A study replicates every grid point over the same seeds, and a scenario's seed alone draws its
job arrivals: the arms of a comparison (the series of one setting) see the same arrivals seed by
seed, *common random numbers*. Their difference is then best measured seed by seed:

- `mean_ci`: the mean of one arm across seeds with its two-sided Student t interval,
  ``mean ± t(1 - α/2, n-1) · s / √n``;
- `difference`: the mean difference of two arms. When both ran the same seeds (each once) it is
  the *paired t* interval of the per-seed differences, with ``n - 1`` degrees of freedom: the
  variation the seeds share (busy hours, lucky arrivals) cancels. When the seeds differ (a failed
  run, a cell not run yet) pairing is impossible and it falls back to *Welch's t*, unpaired and
  unequal variances, with Welch-Satterthwaite's degrees of freedom; the method is named;
- `compare`: the leader of several arms (highest mean) and its difference to each other arm;
- `replications_needed`: the seeds an interval needs to reach a given half-width, iterating
  ``n = ceil((t(1 - α/2, n-1) · s / h)²)`` until it is stable.

Every interval is cut to what is physically possible, its `bounds` (good parts per hour cannot be
negative: ``NON_NEGATIVE``; a share lies in ``SHARE``, [0, 1]); a difference ``a - b`` of arms
bounded by ``[lo, hi]`` lies in ``[lo - hi, hi - lo]``. Cutting an interval to where the true
value must lie keeps its coverage. Quantiles are scipy's (`scipy.special.stdtrit`, the quantile
function of `scipy.stats.t`; tests/test_stats.py checks them against `scipy.stats` itself).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np

# scipy.stats.t's quantile function (its ppf calls it), without importing all of scipy.stats:
# that import alone took 0.3-0.9 s on this 2-core machine, more than the report's statistics.
from scipy.special import stdtrit

__all__ = [
    "CONFIDENCE",
    "UNBOUNDED",
    "NON_NEGATIVE",
    "SHARE",
    "Bounds",
    "Interval",
    "Method",
    "Difference",
    "Verdict",
    "Comparison",
    "t_quantile",
    "mean_ci",
    "difference",
    "compare",
    "replications_needed",
]

#: The confidence level of every interval unless told otherwise.
CONFIDENCE = 0.95

#: (low, high): where a quantity can lie.
Bounds = tuple[float, float]
UNBOUNDED: Bounds = (-math.inf, math.inf)
NON_NEGATIVE: Bounds = (0.0, math.inf)
SHARE: Bounds = (0.0, 1.0)

# The fixed-point iteration of `replications_needed` settles in a handful of steps; this only
# guards against a cycle between two neighbours.
_MAX_ITERATIONS = 100


def t_quantile(df: float, confidence: float = CONFIDENCE) -> float:
    """The two-sided Student t quantile ``t(1 - α/2, df)`` for ``α = 1 - confidence``.

    `df` may be fractional (Welch). scipy's Student t quantile function,
    `scipy.special.stdtrit`, which `scipy.stats.t.ppf` calls.

    Raises
    ------
    ValueError
        `df` is not a positive number or `confidence` not in (0, 1).
    """
    if isinstance(df, bool) or not isinstance(df, int | float) or not df > 0:
        raise ValueError(f"degrees of freedom must be a positive number, got {df!r}")
    _check_confidence(confidence)
    return float(stdtrit(df, 0.5 + confidence / 2))


def _check_confidence(confidence: float) -> None:
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must lie in (0, 1), got {confidence!r}")


def _percent(confidence: float) -> str:
    return f"{100 * confidence:g} %"


def _clip(value: float, bounds: Bounds) -> float:
    return min(max(value, bounds[0]), bounds[1])


@dataclass(frozen=True)
class Interval:
    """A mean across seeds with its two-sided Student t confidence interval.

    Attributes
    ----------
    mean:
        The sample mean.
    half_width:
        ``t(1 - α/2, n-1) * s / sqrt(n)`` before any cut to `bounds`, or None for a single
        value (no interval).
    n:
        How many values (seeds).
    bounds:
        Where the quantity can lie; `low` and `high` are cut to them.
    sd:
        The sample standard deviation (None for a single value).
    confidence:
        The interval's confidence level.
    """

    mean: float
    half_width: float | None
    n: int
    bounds: Bounds = UNBOUNDED
    sd: float | None = None
    confidence: float = CONFIDENCE

    @property
    def low(self) -> float:
        """Lower end of the interval, cut to `bounds` (the mean itself without an interval)."""
        return _clip(self.mean - (self.half_width or 0.0), self.bounds)

    @property
    def high(self) -> float:
        """Upper end of the interval, cut to `bounds` (the mean itself without an interval)."""
        return _clip(self.mean + (self.half_width or 0.0), self.bounds)

    @property
    def clipped(self) -> bool:
        """A bound cut the interval: it is no longer symmetric about the mean."""
        if self.half_width is None:
            return False
        return self.low > self.mean - self.half_width or self.high < self.mean + self.half_width

    @property
    def df(self) -> int | None:
        """Degrees of freedom, ``n - 1`` (None for a single value)."""
        return None if self.half_width is None else self.n - 1

    def text(self) -> str:
        """``"mean ± half-width (n=…)"`` with two decimals; a cut interval as
        ``"mean [low, high] (n=…)"``; a single value as ``"mean (n=1)"``."""
        if self.half_width is None:
            return f"{self.mean:.2f} (n={self.n})"
        if self.clipped:
            return f"{self.mean:.2f} [{self.low:.2f}, {self.high:.2f}] (n={self.n})"
        return f"{self.mean:.2f} ± {self.half_width:.2f} (n={self.n})"


def mean_ci(
    values: Iterable[float], *, bounds: Bounds = UNBOUNDED, confidence: float = CONFIDENCE
) -> Interval:
    """The mean of `values` with its two-sided Student t interval (n-1 degrees of freedom), cut
    to `bounds`.

    Raises
    ------
    ValueError
        `values` is empty or `confidence` not in (0, 1).
    """
    _check_confidence(confidence)
    a = np.asarray(list(values), dtype=float)
    if a.size == 0:
        raise ValueError("mean_ci needs at least one value")
    mean = float(a.mean())
    if a.size == 1:
        return Interval(mean, None, 1, bounds, None, confidence)
    s = float(a.std(ddof=1))
    hw = t_quantile(a.size - 1, confidence) * s / math.sqrt(a.size)
    return Interval(mean, hw, int(a.size), bounds, s, confidence)


class Method(enum.Enum):
    """How a `Difference`'s interval was computed."""

    PAIRED = "paired t"
    """Both arms ran the same seeds: the t interval of the per-seed differences, df n-1."""
    WELCH = "Welch t"
    """The seeds differ: unpaired, unequal variances, Welch-Satterthwaite df."""
    NONE = "no interval"
    """An arm has a single value: no spread to build an interval from."""


@dataclass(frozen=True)
class Difference:
    """The mean difference ``a - b`` of two arms with its confidence interval.

    Attributes
    ----------
    mean:
        Mean of the per-seed differences (paired), or difference of the means (Welch, none).
    half_width:
        The t half-width before any cut to `bounds`; None without an interval.
    df:
        Degrees of freedom: ``n - 1`` paired, Welch-Satterthwaite's (fractional) for Welch;
        None without an interval or when neither arm varies (Welch).
    method:
        `Method.PAIRED`, `Method.WELCH` or `Method.NONE`.
    seeds:
        The common seeds the pairs are on (paired); the seeds only one arm has (Welch).
    n_a, n_b:
        Values in each arm.
    sd:
        Standard deviation of the per-seed differences (paired), else None.
    bounds:
        Where the difference can lie, from the arms' bounds.
    confidence:
        The interval's confidence level.
    """

    mean: float
    half_width: float | None
    df: float | None
    method: Method
    seeds: tuple[int, ...]
    n_a: int
    n_b: int
    sd: float | None = None
    bounds: Bounds = UNBOUNDED
    confidence: float = CONFIDENCE

    @property
    def low(self) -> float:
        """Lower end, cut to `bounds` (the mean itself without an interval)."""
        return _clip(self.mean - (self.half_width or 0.0), self.bounds)

    @property
    def high(self) -> float:
        """Upper end, cut to `bounds` (the mean itself without an interval)."""
        return _clip(self.mean + (self.half_width or 0.0), self.bounds)

    @property
    def clipped(self) -> bool:
        """A bound cut the interval."""
        if self.half_width is None:
            return False
        return self.low > self.mean - self.half_width or self.high < self.mean + self.half_width

    def text(self) -> str:
        """``"+d ± h"`` (``"+d [low, high]"`` when cut; ``"+d"`` without an interval)."""
        if self.half_width is None:
            return f"{self.mean:+.2f}"
        if self.clipped:
            return f"{self.mean:+.2f} [{self.low:+.2f}, {self.high:+.2f}]"
        return f"{self.mean:+.2f} ± {self.half_width:.2f}"

    def method_text(self) -> str:
        """The method named, e.g. ``"95 % CI, paired t on 5 common seeds, df 4"``."""
        ci = f"{_percent(self.confidence)} CI"
        if self.method is Method.PAIRED:
            return f"{ci}, paired t on {len(self.seeds)} common seeds, df {self.df:g}"
        if self.method is Method.WELCH:
            why = "seeds differ" + (
                f": {', '.join(map(str, self.seeds))} in one arm only" if self.seeds else ""
            )
            df = "n/a (no spread)" if self.df is None else f"{self.df:.1f}"
            return f"{ci}, Welch t ({why}; n {self.n_a} and {self.n_b}), df {df}"
        return f"no interval: {min(self.n_a, self.n_b)} seed in one arm"


def _values(arm: Mapping[int, float] | Iterable[tuple[int, float]]) -> list[tuple[int, float]]:
    items = arm.items() if isinstance(arm, Mapping) else arm
    return [(int(s), float(v)) for s, v in items]


def difference(
    a: Mapping[int, float] | Iterable[tuple[int, float]],
    b: Mapping[int, float] | Iterable[tuple[int, float]],
    *,
    bounds: Bounds = UNBOUNDED,
    confidence: float = CONFIDENCE,
) -> Difference:
    """The mean difference ``a - b`` of two arms, given as seed -> value (or (seed, value)
    pairs), with its two-sided t interval.

    Paired (`Method.PAIRED`, df ``n - 1``) when both arms hold the same seeds, each once, and
    at least two; else Welch's unpaired interval (`Method.WELCH`) when each arm has two values
    or more; else no interval (`Method.NONE`). `bounds` are the arms' bounds: the difference is
    cut to ``[bounds[0] - bounds[1], bounds[1] - bounds[0]]``.

    Raises
    ------
    ValueError
        An arm is empty or `confidence` not in (0, 1).
    """
    _check_confidence(confidence)
    va, vb = _values(a), _values(b)
    if not va or not vb:
        raise ValueError("difference needs at least one value in each arm")
    diff_bounds = (bounds[0] - bounds[1], bounds[1] - bounds[0])
    sa, sb = [s for s, _ in va], [s for s, _ in vb]
    xa = np.array([v for _, v in va])
    xb = np.array([v for _, v in vb])
    same = len(set(sa)) == len(sa) and len(set(sb)) == len(sb) and set(sa) == set(sb)
    if same and len(sa) >= 2:
        by_seed = dict(vb)
        seeds = tuple(sorted(sa))
        d = np.array([dict(va)[s] - by_seed[s] for s in seeds])
        sd = float(d.std(ddof=1))
        n = d.size
        hw = t_quantile(n - 1, confidence) * sd / math.sqrt(n)
        return Difference(
            float(d.mean()), hw, n - 1, Method.PAIRED, seeds, n, n, sd, diff_bounds, confidence
        )
    mean = float(xa.mean() - xb.mean())
    only_one = tuple(sorted(set(sa) ^ set(sb)))
    if xa.size < 2 or xb.size < 2:
        return Difference(
            mean, None, None, Method.NONE, only_one, xa.size, xb.size, None, diff_bounds,
            confidence,
        )  # fmt: skip
    qa, qb = float(xa.var(ddof=1)) / xa.size, float(xb.var(ddof=1)) / xb.size
    se = math.sqrt(qa + qb)
    if se == 0.0:  # neither arm varies: a zero-width interval, Welch's df undefined
        hw, df = 0.0, None
    else:
        df = float((qa + qb) ** 2 / (qa**2 / (xa.size - 1) + qb**2 / (xb.size - 1)))
        hw = t_quantile(df, confidence) * se
    return Difference(
        mean, hw, df, Method.WELCH, only_one, xa.size, xb.size, None, diff_bounds, confidence
    )


class Verdict(enum.Enum):
    """How the arm with the highest mean in one setting compares with the others."""

    CLEAR = "clearly ahead"
    """The interval of its difference to every other arm lies above zero."""
    TIE = "tie"
    """The interval of its difference to some arm reaches zero: the data do not separate them."""
    EQUAL = "equal means"
    """The two highest means are equal: there is no leader."""
    NO_INTERVAL = "no interval"
    """Some arm ran a single seed: there is no interval to decide with."""
    ALONE = "alone"
    """Only one arm: nothing to compare."""


@dataclass(frozen=True)
class Comparison:
    """The leader of several arms and its difference to each other arm (leader minus arm)."""

    leader: str
    runner_up: str | None
    verdict: Verdict
    differences: Mapping[str, Difference]


def compare(
    arms: Mapping[str, Mapping[int, float] | Iterable[tuple[int, float]]],
    *,
    bounds: Bounds = UNBOUNDED,
    confidence: float = CONFIDENCE,
) -> Comparison:
    """The leader (highest mean; equal means: first listed first) of `arms` (name -> seed ->
    value), its `difference` to every other arm, and the `Verdict`.

    Raises
    ------
    ValueError
        `arms` is empty, or an arm is.
    """
    if not arms:
        raise ValueError("compare needs at least one arm")
    values = {name: _values(arm) for name, arm in arms.items()}
    if any(not v for v in values.values()):
        raise ValueError("compare needs at least one value in each arm")
    means = {name: float(np.mean([x for _, x in v])) for name, v in values.items()}
    order = sorted(values, key=lambda name: -means[name])  # stable: first listed first
    leader = order[0]
    if len(order) == 1:
        return Comparison(leader, None, Verdict.ALONE, {})
    diffs = {
        name: difference(values[leader], values[name], bounds=bounds, confidence=confidence)
        for name in order[1:]
    }
    runner = order[1]
    if means[leader] == means[runner]:
        verdict = Verdict.EQUAL
    elif any(d.half_width is None for d in diffs.values()):
        verdict = Verdict.NO_INTERVAL
    else:
        verdict = Verdict.CLEAR if all(d.low > 0.0 for d in diffs.values()) else Verdict.TIE
    return Comparison(leader, runner, verdict, diffs)


def replications_needed(
    sd: float, half_width: float, *, confidence: float = CONFIDENCE, limit: int = 1_000_000
) -> int | None:
    """The fewest replications (seeds) for which a t interval of data with standard deviation
    `sd` has at most `half_width`: the smallest ``n >= 2`` with ``t(1 - α/2, n-1) · sd / √n <=
    half_width``.

    Found by iterating ``n = ceil((t(1 - α/2, n-1) · sd / half_width)²)`` from ``n = 2`` until it
    is stable, then stepping to the smallest n that holds. None when `half_width` is not
    positive or more than `limit` would be needed.

    Raises
    ------
    ValueError
        `sd` is negative or not finite, or `confidence` not in (0, 1).
    """
    _check_confidence(confidence)
    if not (math.isfinite(sd) and sd >= 0.0):
        raise ValueError(f"the standard deviation must be a finite number >= 0, got {sd!r}")
    if not half_width > 0.0:
        return None
    if sd == 0.0:
        return 2

    def width(n: int) -> float:
        return t_quantile(n - 1, confidence) * sd / math.sqrt(n)

    if (sd / half_width) ** 2 > limit:  # even the normal quantile would need more
        return None
    n = 2
    for _ in range(_MAX_ITERATIONS):
        nxt = max(2, math.ceil((t_quantile(n - 1, confidence) * sd / half_width) ** 2))
        if nxt == n or nxt > limit:
            break
        n = nxt
    n = min(n, limit)
    # The fixed point may sit one step off the smallest n (a ceil on a rounded product).
    while n < limit and width(n) > half_width:
        n += 1
    while n > 2 and width(n - 1) <= half_width:
        n -= 1
    return n if width(n) <= half_width else None
