"""The study statistics (fleet.study.stats) against scipy's own tests, computed independently, and
against a printed t table: paired and Welch intervals, cuts to what is possible, the seeds a
half-width needs."""

import math
import random

import numpy as np
import pytest
from scipy import stats as sps

from fleet.study.stats import (
    NON_NEGATIVE,
    SHARE,
    Method,
    Verdict,
    compare,
    difference,
    mean_ci,
    replications_needed,
    t_quantile,
)

# Two-sided 95 % t quantiles from a printed table (independent of scipy).
T975 = {1: 12.706, 2: 4.303, 3: 3.182, 4: 2.776, 9: 2.262, 30: 2.042, 120: 1.980}

# Good parts per hour of two arms on seeds 1..5: a large seed-to-seed spread that both share
# (common random numbers), and B about one part/h below A on every seed.
A = {1: 12.0, 2: 18.0, 3: 9.0, 4: 15.0, 5: 21.0}
B = {1: 11.0, 2: 16.5, 3: 8.0, 4: 14.2, 5: 19.6}


def test_t_quantiles_are_the_printed_table_and_take_fractional_df():
    for df, q in T975.items():
        assert t_quantile(df) == pytest.approx(q, abs=5e-4)
    assert t_quantile(4, 0.90) == pytest.approx(2.132, abs=5e-4)
    assert T975[3] > t_quantile(3.5) > T975[4]  # Welch's df are fractional
    for bad in (0, -1, True, "3", math.nan):
        with pytest.raises(ValueError, match="degrees of freedom"):
            t_quantile(bad)
    with pytest.raises(ValueError, match="confidence"):
        t_quantile(3, 1.0)


def test_t_quantiles_are_scipy_stats_t_ppf():
    for df in (1, 2, 3.5, 4, 9, 17.25, 30, 31, 120, 1e5):
        for confidence in (0.8, 0.9, 0.95, 0.99):
            expected = sps.t.ppf(0.5 + confidence / 2, df)
            assert t_quantile(df, confidence) == pytest.approx(expected, rel=1e-12)


def student_t_cdf(x: float, df: int) -> float:
    """P(T <= x) for x >= 0 by Simpson integration of the density (independent of scipy)."""
    grid = np.linspace(0.0, x, 20001)
    c = math.exp(math.lgamma((df + 1) / 2) - math.lgamma(df / 2)) / math.sqrt(df * math.pi)
    pdf = c * (1 + grid**2 / df) ** (-(df + 1) / 2)
    h = grid[1] - grid[0]
    simpson = h / 3 * (pdf[0] + pdf[-1] + 4 * pdf[1:-1:2].sum() + 2 * pdf[2:-1:2].sum())
    return 0.5 + simpson


@pytest.mark.parametrize("df", [1, 2, 4, 7, 30, 31, 60])
def test_every_quantile_leaves_two_and_a_half_percent_in_the_tail(df):
    # Above 30 df the old hand-written table used 1.96, 4 % too narrow at 31 df.
    assert student_t_cdf(t_quantile(df), df) == pytest.approx(0.975, abs=2e-5)


def test_mean_ci_is_scipys_t_interval_with_n_minus_1_df():
    values = list(A.values())
    c = mean_ci(values)
    low, high = sps.t.interval(0.95, len(values) - 1, loc=np.mean(values), scale=sps.sem(values))
    assert (c.low, c.high) == pytest.approx((low, high), rel=1e-12)
    assert c.n == 5 and c.df == 4 and c.sd == pytest.approx(np.std(values, ddof=1))
    assert c.text() == f"{np.mean(values):.2f} ± {(high - low) / 2:.2f} (n=5)"
    one = mean_ci([5.0])
    assert one.half_width is None and one.df is None and one.low == one.high == 5.0
    assert one.text() == "5.00 (n=1)"
    with pytest.raises(ValueError):
        mean_ci([])


def test_paired_difference_is_scipys_ttest_rel_interval_paired_by_seed():
    # B given in another order: pairs are matched by seed, not by position.
    shuffled = dict(sorted(B.items(), reverse=True))
    d = difference(A, shuffled)
    a, b = [A[s] for s in sorted(A)], [B[s] for s in sorted(A)]
    res = sps.ttest_rel(a, b)
    ci = res.confidence_interval(0.95)
    assert d.method is Method.PAIRED and d.df == res.df == 4 and d.seeds == (1, 2, 3, 4, 5)
    assert (d.low, d.high) == pytest.approx((ci.low, ci.high), rel=1e-12)
    assert d.mean == pytest.approx(np.mean(a) - np.mean(b))
    assert d.method_text() == "95 % CI, paired t on 5 common seeds, df 4"
    # By hand: t(0.975, 4) from the table times the standard error of the differences.
    diffs = np.subtract(a, b)
    assert d.half_width == pytest.approx(
        2.776 * diffs.std(ddof=1) / math.sqrt(5), abs=1e-3 * d.half_width
    )


def test_pairing_separates_what_the_arms_own_intervals_cannot():
    # The arms' intervals overlap widely (the seeds' spread), their paired difference does not.
    ia, ib = mean_ci(A.values()), mean_ci(B.values())
    assert ia.low < ib.high
    d = difference(A, B)
    assert d.low > 0
    welch = sps.ttest_ind(list(A.values()), list(B.values()), equal_var=False)
    assert welch.confidence_interval().low < 0 < d.low
    c = compare({"B": B, "A": A}, bounds=NON_NEGATIVE)
    assert (c.leader, c.runner_up, c.verdict) == ("A", "B", Verdict.CLEAR)
    assert set(c.differences) == {"B"}


def test_seeds_that_differ_fall_back_to_welch_as_scipy_computes_it_and_say_so():
    b = {s: v for s, v in B.items() if s != 3}  # a failed run of B on seed 3
    d = difference(A, b)
    res = sps.ttest_ind(list(A.values()), list(b.values()), equal_var=False)
    ci = res.confidence_interval(0.95)
    assert d.method is Method.WELCH and d.df == pytest.approx(res.df, rel=1e-12)
    assert (d.low, d.high) == pytest.approx((ci.low, ci.high), rel=1e-12)
    assert d.seeds == (3,)
    assert d.method_text() == (
        f"95 % CI, Welch t (seeds differ: 3 in one arm only; n 5 and 4), df {res.df:.1f}"
    )
    # The same seeds listed twice in one arm cannot be paired either.
    assert difference([(1, 1.0), (1, 2.0), (2, 3.0)], [(1, 1.0), (2, 2.0)]).method is Method.WELCH


def test_a_single_seed_gives_no_interval_and_no_verdict():
    d = difference({1: 3.0}, {1: 2.0})
    assert d.method is Method.NONE and d.half_width is None and d.low == d.high == 1.0
    assert d.method_text() == "no interval: 1 seed in one arm"
    assert compare({"a": {1: 3.0}, "b": {1: 2.0}}).verdict is Verdict.NO_INTERVAL
    assert compare({"a": A}).verdict is Verdict.ALONE
    assert compare({"a": A, "b": dict(A)}).verdict is Verdict.EQUAL


def test_intervals_are_cut_to_what_is_possible():
    # Good parts per hour near zero: the t interval reaches below 0, the cut one stops there.
    c = mean_ci([0.0, 0.0, 3.0], bounds=NON_NEGATIVE)
    raw = sps.t.interval(0.95, 2, loc=1.0, scale=sps.sem([0.0, 0.0, 3.0]))
    assert raw[0] < 0 and c.low == 0.0 and c.high == pytest.approx(raw[1])
    assert c.clipped and c.text() == f"1.00 [0.00, {raw[1]:.2f}] (n=3)"
    assert not mean_ci([5.0, 6.0, 7.0], bounds=NON_NEGATIVE).clipped
    # A share lies in [0, 1] at both ends.
    s = mean_ci([0.9, 1.0, 1.0, 0.6], bounds=SHARE)
    assert s.high == 1.0 and s.low == pytest.approx(s.mean - s.half_width)
    # A difference of shares lies in [-1, 1].
    d = difference({1: 1.0, 2: 0.0, 3: 1.0}, {1: 0.0, 2: 1.0, 3: 0.0}, bounds=SHARE)
    assert d.high == 1.0 and d.low == -1.0 and d.clipped
    assert d.text() == "+0.33 [-1.00, +1.00]"
    # Throughput differences have no finite bound: nothing to cut.
    assert difference({1: 0.0, 2: 9.0}, {1: 4.0, 2: 0.0}, bounds=NON_NEGATIVE).bounds == (
        -math.inf,
        math.inf,
    )


def smallest_n(sd: float, h: float) -> int:
    """The fewest seeds whose t interval is at most h wide, by counting up (no iteration)."""
    n = 2
    while sps.t.ppf(0.975, n - 1) * sd / math.sqrt(n) > h:
        n += 1
    return n


def test_replications_needed_on_known_data():
    # s = 1, h = 0.5: the normal quantile would say ceil((1.96 / 0.5)^2) = 16; t(0.975, 17) =
    # 2.110 gives 2.110 / sqrt(18) = 0.497 <= 0.5 while n = 17 gives 2.120 / sqrt(17) = 0.514.
    assert replications_needed(1.0, 0.5) == 18
    # The two arms above: s = 3.67 across seeds; 5 % of the mean 15 is 0.75.
    s = float(np.std(list(A.values()), ddof=1))
    assert replications_needed(s, 0.75) == smallest_n(s, 0.75)
    rng = random.Random(7)
    for _ in range(40):
        sd, h = rng.uniform(0.05, 5.0), rng.uniform(0.05, 3.0)
        assert replications_needed(sd, h) == smallest_n(sd, h), (sd, h)
    assert replications_needed(0.0, 0.1) == 2  # no spread: two seeds show it
    assert replications_needed(1.0, 1e-4) is None  # more than a million
    assert replications_needed(1.0, 0.0) is None
    with pytest.raises(ValueError, match="standard deviation"):
        replications_needed(-1.0, 0.5)
