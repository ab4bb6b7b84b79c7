"""Statistics: source C's Table 6 (e_pos, eta) from its published numbers, and hand-computed cases."""

from __future__ import annotations

import math

import pytest

from llmnav.stats import compare, compare_summary, describe, hedges_g_summary, mean_sd, welch_summary


def test_table6_epos_from_published_numbers() -> None:
    # FSM 0.246 ± 0.078 vs FSM+LLM 0.159 ± 0.069, N = 60 each; published t = 6.52, g = 1.18.
    w = welch_summary(0.246, 0.078, 60, 0.159, 0.069, 60)
    assert round(w.t, 1) == 6.5
    assert w.p < 1e-8
    assert 116 < w.df < 118  # Welch–Satterthwaite, close to 2n - 2 for similar SDs
    g = hedges_g_summary(0.246, 0.078, 60, 0.159, 0.069, 60)
    assert 1.17 <= round(g, 2) <= 1.18


@pytest.mark.parametrize("share", [0.3, 0.5, 0.7])
def test_table6_eta_g_follows_from_the_published_t(share: float) -> None:
    # eta: FSM 0.821 vs FSM+LLM 0.901, N = 60 each; published t = 10.51, g = 1.91. The SDs are not
    # published, but with equal N Welch's t depends only on s1^2 + s2^2 and Hedges' g only on their mean,
    # so the published t fixes exactly what g needs: (0.901 - 0.821) / t = sqrt((s1^2 + s2^2) / 60).
    # Any split of that total (share) must give t = 10.51 back and g = 1.90-1.91.
    total = 60 * ((0.901 - 0.821) / 10.51) ** 2
    sd1, sd2 = math.sqrt(share * total), math.sqrt((1 - share) * total)
    w = welch_summary(0.901, sd1, 60, 0.821, sd2, 60)
    assert w.t == pytest.approx(10.51, abs=1e-9)
    assert 1.90 <= round(hedges_g_summary(0.901, sd1, 60, 0.821, sd2, 60), 2) <= 1.91


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
