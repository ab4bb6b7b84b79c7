"""Statistics: source C's Table 6 (e_pos, eta) from its published numbers, and hand-computed cases."""

from __future__ import annotations

import math

import pytest

from llmnav.scoring.stats import compare, compare_summary, describe, hedges_g_summary, mean_sd, welch_summary

# Source C, Table 6, e_pos: FSM 0.246 ± 0.078 vs FSM+LLM 0.159 ± 0.069 m, N = 60 each; published
# t = 6.52, g = 1.18. The inputs are rounded to 3 decimals, so each lies within ± 0.0005 of its printed
# value; t and g are monotone in every input (up in mean1, down in mean2, down in both SDs), so their
# extremes over that box are reached at two corners.
EPOS_HALF_STEP = 0.0005  # half a unit in the last published digit [m]


def _corners() -> tuple[tuple[float, ...], tuple[float, ...]]:
    h = EPOS_HALF_STEP
    low = (0.246 - h, 0.078 + h, 60, 0.159 + h, 0.069 + h, 60)
    high = (0.246 + h, 0.078 - h, 60, 0.159 - h, 0.069 - h, 60)
    return low, high


def test_table6_epos_rounding_envelope_contains_the_published_t() -> None:
    low, high = _corners()
    t_low, t_high = welch_summary(*low).t, welch_summary(*high).t  # type: ignore[arg-type]
    assert t_low <= 6.52 <= t_high
    # By hand, the corners give 0.086 / sqrt((0.0785² + 0.0695²) / 60) = 6.354 and
    # 0.088 / sqrt((0.0775² + 0.0685²) / 60) = 6.590: the envelope is this narrow, so a wrong formula fails.
    assert t_low == pytest.approx(6.354, abs=2e-3) and t_high == pytest.approx(6.590, abs=2e-3)


def test_table6_epos_rounding_envelope_contains_the_published_g() -> None:
    low, high = _corners()
    g_low, g_high = hedges_g_summary(*low), hedges_g_summary(*high)  # type: ignore[arg-type]
    # Published g = 1.18 means 1.175 <= g < 1.185; the envelope must overlap it.
    assert g_low <= 1.185 and g_high >= 1.175
    # By hand: J = 1 - 3 / 471 = 0.993631; 0.086 / sqrt((0.0785² + 0.0695²) / 2) * J = 1.1527,
    # 0.088 / sqrt((0.0775² + 0.0685²) / 2) * J = 1.1956.
    assert g_low == pytest.approx(1.1527, abs=1e-3) and g_high == pytest.approx(1.1956, abs=1e-3)


def test_table6_epos_welch_df_and_p() -> None:
    w = welch_summary(0.246, 0.078, 60, 0.159, 0.069, 60)
    # By hand: v1 = 0.078²/60 = 1.014e-4, v2 = 0.069²/60 = 7.935e-5;
    # df = (v1 + v2)² / (v1²/59 + v2²/59) = 3.2671e-8 / 2.8099e-10 = 116.27
    assert w.df == pytest.approx(116.27, abs=0.05)
    assert w.p < 1e-8  # t ≈ 6.5 on ~116 df: p ≈ 2e-9


@pytest.mark.parametrize("share", [0.3, 0.5, 0.7])
def test_table6_eta_published_t_and_g_agree(share: float) -> None:
    # eta: FSM 0.821 vs FSM+LLM 0.901, N = 60 each; published t = 10.51, g = 1.91; SDs not published.
    # With equal N, t fixes s1² + s2² = 60 (Δ / t)², and then g = t * J / sqrt(30) whatever Δ and the split
    # (share) of the variance: the two published numbers must agree through the library's g. Over the
    # rounding of t (10.505-10.515) g = 1.9057-1.9075 by hand, inside the published 1.905-1.915.
    for t_published in (10.505, 10.515):
        total = 60 * ((0.901 - 0.821) / t_published) ** 2
        sd1, sd2 = math.sqrt(share * total), math.sqrt((1 - share) * total)
        g = hedges_g_summary(0.901, sd1, 60, 0.821, sd2, 60)
        assert 1.905 <= g <= 1.915, (t_published, g)
        assert g == pytest.approx(t_published * (1 - 3 / 471) / math.sqrt(30), abs=1e-9)


def test_hand_computed_welch_and_g() -> None:
    # a = [1, 2, 3, 4] (mean 2.5, var 5/3), b = [2, 4, 6] (mean 4, var 4)
    # se = sqrt(5/12 + 4/3) = sqrt(1.75); t = -1.5 / 1.3229 = -1.1339
    # df = 1.75^2 / ((5/12)^2/3 + (4/3)^2/2) = 3.0625 / (0.0578704 + 0.8888889) = 3.2348
    # pooled var = (3*5/3 + 2*4)/5 = 2.6; d = -1.5/1.61245 = -0.93026; J = 1 - 3/19; g = -0.78338
    c = compare([1, 2, 3, 4], [2, 4, 6])
    assert c.welch.t == pytest.approx(-1.1339, abs=1e-4)
    assert c.welch.df == pytest.approx(3.2348, abs=1e-4)
    assert c.hedges_g == pytest.approx(-0.78338, abs=1e-5)
    from scipy import stats

    ref = stats.ttest_ind([1, 2, 3, 4], [2, 4, 6], equal_var=False)
    assert c.welch.p == pytest.approx(ref.pvalue)


def test_describe_mean_sd_ci() -> None:
    d = describe([2.0, 4.0, 6.0, None, float("nan")])
    assert (d.n, d.mean, d.sd) == (3, 4.0, 2.0)
    # t(0.975, 2) = 4.302653; half width = 4.302653 * 2 / sqrt(3) = 4.968275
    assert d.ci_low == pytest.approx(4 - 4.968275, abs=1e-5)
    assert d.ci_high == pytest.approx(4 + 4.968275, abs=1e-5)


def test_degenerate_samples_give_nan() -> None:
    assert mean_sd([])[2] == 0
    assert math.isnan(describe([1.0]).sd)
    c = compare([1.0], [2.0, 3.0])
    assert math.isnan(c.welch.t) and math.isnan(c.hedges_g)
    assert math.isnan(compare_summary(1.0, 0.0, 5, 1.0, 0.0, 5).welch.t)
