"""Verdicts from bootstrap CIs on differences (maniskill_dualher/stats.py)."""
import numpy as np
import pytest
from scipy.stats import mannwhitneyu

from maniskill_dualher import stats


def test_verdicts_follow_the_ci_of_the_difference():
    assert stats.compare([9, 10, 11, 12], [1, 2, 3, 4], margin=1).verdict == stats.REPRODUCED
    assert stats.compare([1, 2, 3, 4], [9, 10, 11, 12], margin=1).verdict == stats.CONTRADICTED
    eq = stats.compare([0.9, 1.0, 1.0, 0.95], [1.0, 0.95, 0.9, 1.0], margin=0.1)
    assert eq.verdict == stats.EQUIVALENT and -0.1 <= eq.ci_low <= eq.ci_high <= 0.1
    assert eq.verdict_text() == "no difference larger than 0.1"
    inc = stats.compare([1, 5, 9, 3], [0, 4, 8, 2], margin=0.5)
    assert inc.verdict == stats.INCONCLUSIVE and inc.ci_low < 0 < inc.ci_high
    assert inc.seeds_to_decide is not None and inc.seeds_to_decide > 4
    assert "seeds per side would likely decide it" in inc.verdict_text()
    few = stats.compare([9, 10], [1, 2], margin=1)
    assert few.verdict == stats.INCONCLUSIVE and "needs >= 3 seeds" in few.verdict_text()


def test_ci_is_seeded_and_brackets_the_difference():
    rng = np.random.default_rng(0)
    a, b = rng.normal(1.0, 1.0, 8), rng.normal(0.0, 1.0, 8)
    c1, c2 = stats.compare(a, b, 0.1), stats.compare(a, b, 0.1)
    assert (c1.ci_low, c1.ci_high) == (c2.ci_low, c2.ci_high)
    assert c1.ci_low < a.mean() - b.mean() < c1.ci_high
    # roughly the normal-theory interval at this n (a percentile bootstrap is a bit narrower)
    half = 1.96 * np.sqrt(a.var(ddof=1) / 8 + b.var(ddof=1) / 8)
    assert 0.6 * half < (c1.ci_high - c1.ci_low) / 2 < 1.2 * half


def test_probability_of_improvement_is_the_mann_whitney_statistic():
    a, b = [3, 1, 4, 1, 5], [2, 7, 1, 8]
    u = mannwhitneyu(a, b).statistic
    assert stats.prob_improvement(a, b) == pytest.approx(u / (len(a) * len(b)))
