"""Two-group statistics as the FSM source reports them: mean ± SD, 95 % t-CI, Welch's t, Hedges' g.

Every test has a form taking raw samples and one taking summary statistics (mean, SD, n), so published
tables can be checked from their numbers alone. SD is the sample standard deviation (ddof = 1).
References: Welch (1947) with the Welch–Satterthwaite degrees of freedom; Hedges & Olkin (1985) for g with
the small-sample correction J = 1 - 3 / (4 (n1 + n2) - 9).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class Describe:
    """Mean, SD and the t confidence interval of one sample."""

    n: int
    mean: float
    sd: float  # sample SD (ddof = 1); nan for n < 2
    ci_low: float
    ci_high: float
    confidence: float = 0.95


@dataclass(frozen=True)
class Welch:
    """Welch's unequal-variance t-test (group 1 minus group 2)."""

    t: float
    df: float
    p: float  # two-sided


@dataclass(frozen=True)
class Comparison:
    """Two groups side by side with Welch's t and Hedges' g (positive: group 1 larger)."""

    a: Describe
    b: Describe
    welch: Welch
    hedges_g: float


def _finite(values: Sequence[float | None]) -> list[float]:
    return [float(v) for v in values if v is not None and math.isfinite(float(v))]


def mean_sd(values: Sequence[float | None]) -> tuple[float, float, int]:
    """Mean, sample SD and n of the finite values (nan where undefined)."""
    xs = _finite(values)
    n = len(xs)
    if n == 0:
        return math.nan, math.nan, 0
    mean = sum(xs) / n
    sd = math.sqrt(sum((x - mean) ** 2 for x in xs) / (n - 1)) if n > 1 else math.nan
    return mean, sd, n


def t_interval(mean: float, sd: float, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Two-sided t confidence interval of a mean from summary statistics (nan for n < 2)."""
    # deferred: scipy.stats (about 0.5 s) loads only when an interval is computed
    from scipy import stats

    if n < 2 or not math.isfinite(sd):
        return math.nan, math.nan
    half = float(stats.t.ppf(0.5 + confidence / 2, n - 1)) * sd / math.sqrt(n)
    return mean - half, mean + half


def describe_summary(mean: float, sd: float, n: int, confidence: float = 0.95) -> Describe:
    """`Describe` from published numbers."""
    low, high = t_interval(mean, sd, n, confidence)
    return Describe(n, mean, sd, low, high, confidence)


def describe(
    values: Sequence[float | None],
    confidence: float = 0.95,
    bounds: tuple[float | None, float | None] = (None, None),
) -> Describe:
    """Mean ± SD and t-CI of a sample (None and non-finite values are dropped).

    `bounds`: the metric's range; the interval is cut to it (see `clip_interval`).
    """
    mean, sd, n = mean_sd(values)
    d = describe_summary(mean, sd, n, confidence)
    if bounds == (None, None):
        return d
    low, high = clip_interval(d.ci_low, d.ci_high, bounds)
    return Describe(d.n, d.mean, d.sd, low, high, confidence)


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> tuple[float, float]:
    """Wilson's score interval of a rate (Wilson 1927): always inside [0, 1], sensible at 0/n and n/n.

    The t interval of 0/1 outcomes reaches below 0 and above 1 for small n, and is a single point at
    0/n or n/n; Wilson's never leaves the rate's range. (nan, nan) for n = 0.
    """
    # deferred: scipy.stats (about 0.5 s) loads only when an interval is computed
    from scipy import stats

    if n <= 0:
        return math.nan, math.nan
    z = float(stats.norm.ppf(0.5 + confidence / 2))
    p = successes / n
    denominator = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / denominator
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denominator
    return max(0.0, centre - half), min(1.0, centre + half)


def clip_interval(
    low: float, high: float, bounds: tuple[float | None, float | None] = (None, None)
) -> tuple[float, float]:
    """An interval cut to a metric's range (a score is never below 0, a length never negative)."""
    lowest, highest = bounds
    if lowest is not None and math.isfinite(low):
        low, high = max(low, lowest), max(high, lowest)
    if highest is not None and math.isfinite(high):
        low, high = min(low, highest), min(high, highest)
    return low, high


def welch_summary(mean1: float, sd1: float, n1: int, mean2: float, sd2: float, n2: int) -> Welch:
    """Welch's t, Welch–Satterthwaite df and two-sided p from summary statistics."""
    # deferred: scipy.stats (about 0.5 s) loads only when groups are compared
    from scipy import stats

    if n1 < 2 or n2 < 2:
        return Welch(math.nan, math.nan, math.nan)
    v1, v2 = sd1**2 / n1, sd2**2 / n2
    se = math.sqrt(v1 + v2)
    if se == 0.0:  # two constant samples: no spread to test against
        return Welch(math.nan, math.nan, math.nan)
    t = (mean1 - mean2) / se
    df = (v1 + v2) ** 2 / (v1**2 / (n1 - 1) + v2**2 / (n2 - 1))
    p = float(2.0 * stats.t.sf(abs(t), df))
    return Welch(t, df, p)


def hedges_g_summary(mean1: float, sd1: float, n1: int, mean2: float, sd2: float, n2: int) -> float:
    """Hedges' g: the mean difference over the pooled SD, times J = 1 - 3/(4(n1+n2)-9)."""
    if n1 < 2 or n2 < 2:
        return math.nan
    pooled = math.sqrt(((n1 - 1) * sd1**2 + (n2 - 1) * sd2**2) / (n1 + n2 - 2))
    if pooled == 0.0:
        return math.nan
    correction = 1.0 - 3.0 / (4.0 * (n1 + n2) - 9.0)
    return (mean1 - mean2) / pooled * correction


def compare_summary(
    mean1: float, sd1: float, n1: int, mean2: float, sd2: float, n2: int, confidence: float = 0.95
) -> Comparison:
    """Both groups described, Welch's t and Hedges' g, from summary statistics."""
    return Comparison(
        describe_summary(mean1, sd1, n1, confidence),
        describe_summary(mean2, sd2, n2, confidence),
        welch_summary(mean1, sd1, n1, mean2, sd2, n2),
        hedges_g_summary(mean1, sd1, n1, mean2, sd2, n2),
    )


def compare(a: Sequence[float | None], b: Sequence[float | None], confidence: float = 0.95) -> Comparison:
    """Both samples described, Welch's t and Hedges' g (None and non-finite values are dropped)."""
    m1, s1, n1 = mean_sd(a)
    m2, s2, n2 = mean_sd(b)
    return compare_summary(m1, s1, n1, m2, s2, n2, confidence)
