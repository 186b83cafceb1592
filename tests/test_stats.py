"""Verdicts from CIs on differences (maniskill_dualher/analysis/stats.py)."""
import math

import numpy as np
import pytest
from scipy.stats import mannwhitneyu, norm

from maniskill_dualher.analysis import stats


def test_verdicts_follow_the_ci_of_the_difference():
    assert stats.compare([9, 10, 11, 12], [1, 2, 3, 4], margin=1).verdict == stats.REPRODUCED
    assert stats.compare([1, 2, 3, 4], [9, 10, 11, 12], margin=1).verdict == stats.CONTRADICTED
    eq = stats.compare([0.9, 1.0, 1.0, 0.95], [1.0, 0.95, 0.9, 1.0], margin=0.1)
    assert eq.verdict == stats.EQUIVALENT and -0.1 <= eq.ci_low <= eq.ci_high <= 0.1
    assert eq.verdict_text() == "no difference larger than 0.1"
    inc = stats.compare([1, 5, 9, 3], [0, 4, 8, 2], margin=0.5)
    assert inc.verdict == stats.INCONCLUSIVE and inc.ci_low < 0 < inc.ci_high
    assert inc.seeds_to_decide is not None and inc.seeds_to_decide > 4
    assert "seeds per side would likely decide it (80% power)" in inc.verdict_text()
    few = stats.compare([9, 10], [1, 2], margin=1)
    assert few.verdict == stats.INCONCLUSIVE and "needs >= 3 seeds" in few.verdict_text()
    # the verdict is read off the CI alone, whatever the means, P(A > B) or the Welch interval say
    for c in (stats.compare(*np.random.default_rng(s).lognormal(0, 1, (2, 5)), margin=0.5) for s in range(20)):
        expect = (stats.REPRODUCED if c.ci_low > 0 else stats.CONTRADICTED if c.ci_high < 0 else
                  stats.EQUIVALENT if -c.margin <= c.ci_low and c.ci_high <= c.margin else stats.INCONCLUSIVE)
        assert c.verdict == expect


def test_ci_is_seeded_and_brackets_the_difference():
    rng = np.random.default_rng(0)
    a, b = rng.normal(1.0, 1.0, 8), rng.normal(0.0, 1.0, 8)
    c1, c2 = stats.compare(a, b, 0.1), stats.compare(a, b, 0.1)
    assert (c1.ci_low, c1.ci_high) == (c2.ci_low, c2.ci_high)
    assert stats.compare(a, b, 0.1, seed=1).ci_high != c1.ci_high  # the seed is what fixes it
    assert c1.ci_low < a.mean() - b.mean() < c1.ci_high
    assert c1.ci_method == stats.BOOT_T
    # symmetric about the difference, never narrower than Welch's t interval, and not much wider on normal data
    assert c1.ci_high - c1.diff == pytest.approx(c1.diff - c1.ci_low)
    assert c1.ci_low <= c1.welch_low < c1.welch_high <= c1.ci_high
    half = 1.96 * np.sqrt(a.var(ddof=1) / 8 + b.var(ddof=1) / 8)
    assert half < (c1.ci_high - c1.ci_low) / 2 < 1.4 * half
    assert stats.diff_ci(a, b) == (c1.ci_low, c1.ci_high)


def test_welch_cross_check_is_the_textbook_interval():
    from scipy.stats import ttest_ind
    a, b = [3.0, 1.0, 4.0, 1.0, 5.0, 9.0], [2.0, 6.0, 5.0, 3.0]
    ci = ttest_ind(a, b, equal_var=False).confidence_interval(0.95)
    c = stats.compare(a, b, 0.1)
    assert (c.welch_low, c.welch_high) == pytest.approx((ci.low, ci.high))


def test_probability_of_improvement_is_the_mann_whitney_statistic():
    a, b = [3, 1, 4, 1, 5], [2, 7, 1, 8]
    u = mannwhitneyu(a, b).statistic
    assert stats.prob_improvement(a, b) == pytest.approx(u / (len(a) * len(b)))


def _coverage(method, draw_a, draw_b, truth, n=6, reps=1000, resamples=500):
    rng = np.random.default_rng(2024)
    hits = 0
    for i in range(reps):
        lo, hi = stats.diff_ci(draw_a(rng, n), draw_b(rng, n), resamples=resamples, seed=i, method=method)
        hits += lo <= truth <= hi
    return hits / reps


@pytest.mark.parametrize("case", ["null", "diff"])
def test_coverage_at_six_seeds_on_skewed_data(case):
    # lognormal(0, 1) seeds: no true difference, or A from lognormal(0.5, 1) (larger mean, larger spread:
    # the skewed side dominates the difference). Percentile bootstrap: ~0.89 / ~0.83 here (too narrow).
    draw_b = lambda r, n: r.lognormal(0.0, 1.0, n)
    draw_a = draw_b if case == "null" else (lambda r, n: r.lognormal(0.5, 1.0, n))
    truth = 0.0 if case == "null" else math.exp(1.0) - math.exp(0.5)
    ours = _coverage(stats.BOOT_T, draw_a, draw_b, truth)
    pct = _coverage("percentile", draw_a, draw_b, truth)
    assert ours >= 0.93, (ours, pct)
    assert pct < 0.91 and pct < ours - 0.04, (ours, pct)  # the test can fail: the old interval does


def test_coverage_on_zero_inflated_counts_at_six_seeds():
    zip_ = lambda lam: (lambda r, n: (r.random(n) >= 0.3) * r.poisson(lam, n).astype(float))
    assert _coverage(stats.BOOT_T, zip_(8.0), zip_(5.0), 0.7 * 3.0, reps=600) >= 0.93


def test_seeds_to_decide_is_80_percent_power_at_the_observed_difference():
    a, b = np.array([1.0, 5, 9, 3, 7]), np.array([0.0, 4, 8, 2, 1])
    d, var = a.mean() - b.mean(), a.var(ddof=1) + b.var(ddof=1)
    n = stats.seeds_to_decide(a, b, margin=0.0)

    def power(m):  # two-sided 5% z-test of 0 when the true difference is d, known variances, m per side
        se = math.sqrt(var / m)
        return norm.cdf(abs(d) / se - norm.ppf(0.975)) + norm.cdf(-abs(d) / se - norm.ppf(0.975))
    assert power(n) >= 0.8 > power(n - 1)
    assert n == math.ceil(7.848879 * var / d ** 2)
    # the old rule (1.96^2 var / d^2) is a coin flip
    assert power(math.ceil(1.96 ** 2 * var / d ** 2)) == pytest.approx(0.5, abs=0.03)
    # Monte Carlo of the same test: the mean difference at n per side, ~80% reject
    rng = np.random.default_rng(0)
    dh = rng.normal(d, math.sqrt(var / n), 100_000)
    assert np.mean(np.abs(dh) / math.sqrt(var / n) > norm.ppf(0.975)) == pytest.approx(0.8, abs=0.02)

    # equivalence direction: the 95% half-width must clear margin - |d|; at n, ~80% of CIs fit in +-margin
    a2, b2 = np.array([1.0, 1.2, 0.9, 1.1]), np.array([1.05, 0.95, 1.15, 0.85])
    d2, var2 = a2.mean() - b2.mean(), a2.var(ddof=1) + b2.var(ddof=1)
    m2 = stats.seeds_to_decide(a2, b2, margin=0.1)
    assert m2 == math.ceil(7.848879 * var2 / (0.1 - abs(d2)) ** 2)
    se2 = math.sqrt(var2 / m2)
    dh2 = rng.normal(d2, se2, 100_000)
    assert np.mean(np.abs(dh2) + norm.ppf(0.975) * se2 <= 0.1) == pytest.approx(0.8, abs=0.02)

    # at least one more seed than now; no advice above MAX_SEEDS_ADVICE or without spread
    assert stats.seeds_to_decide(np.array([0.0, 10, 0]), np.array([0.0, 1, 9]), margin=0.0) is None
    assert stats.seeds_to_decide(np.array([1.0, 1, 1]), np.array([0.0, 0, 0]), margin=0.0) is None
    assert stats.seeds_to_decide(np.array([0.0, 10, 0, 5]), np.array([10.0, 20, 0, 5]), margin=0.0) >= 5


def test_degenerate_inputs():
    # no spread on either side: every resample gives the same difference
    c = stats.compare([1, 1, 1], [0, 0, 0], margin=0.1)
    assert (c.ci_low, c.ci_high, c.welch_low, c.welch_high) == (1, 1, 1, 1) and c.verdict == stats.REPRODUCED
    same = stats.compare([2, 2, 2, 2], [2, 2, 2, 2], margin=0.1)
    assert (same.ci_low, same.ci_high) == (0, 0) and same.verdict == stats.EQUIVALENT
    # no spread on one side: Welch's df is the other side's n - 1, the bootstrap still studentizes
    one = stats.compare([0.2, 0.5, 0.9, 0.4, 0.7, 0.3], [0, 0, 0, 0, 0, 0], margin=0.1)
    assert one.ci_method == stats.BOOT_T and one.ci_low <= one.welch_low < one.welch_high <= one.ci_high
    from scipy.stats import t
    assert one.welch_high - one.diff == pytest.approx(t.ppf(0.975, 5) * np.std([.2, .5, .9, .4, .7, .3], ddof=1)
                                                      / math.sqrt(6))
    # mostly ties (successes in a handful of seeds): too many resamples without spread -> Welch t
    ties = stats.compare([0, 0, 0, 1], [0, 0, 0, 0], margin=0.1)
    assert ties.ci_method == stats.WELCH_FALLBACK and np.isfinite([ties.ci_low, ties.ci_high]).all()
    assert (ties.ci_low, ties.ci_high) == (ties.welch_low, ties.welch_high) and ties.verdict == stats.INCONCLUSIVE
    # a few flat resamples are fine: the interval stays finite and symmetric
    r = stats.compare([0, 0, 0, 0, 1, 2], [0, 0, 0, 0, 0, 1], margin=0.1)  # ~3% of resamples flat
    assert r.ci_method == stats.BOOT_T and np.isfinite([r.ci_low, r.ci_high]).all()
    # too few seeds: no interval
    for a, b in (([1, 2], [0, 1, 2]), ([5], [1, 2, 3])):
        f = stats.compare(a, b, margin=0.1)
        assert math.isnan(f.ci_low) and math.isnan(f.welch_high) and f.verdict == stats.INCONCLUSIVE
        assert f.seeds_to_decide is None
    assert all(math.isnan(x) for x in stats.diff_ci([1.0], [1.0, 2.0, 3.0]))
    with pytest.raises(ValueError):
        stats.compare([], [1, 2, 3], margin=0.1)
    with pytest.raises(ValueError):
        stats.compare([1, 2, float("nan")], [1, 2, 3], margin=0.1)
    # large offsets: floating-point noise in a flat resample is not spread
    big = stats.compare(np.array([1, 1, 1, 2.0]) + 1e9, np.array([1, 1, 1, 1.0]) + 1e9, margin=0.1)
    assert big.ci_method == stats.WELCH_FALLBACK


def test_multiplicity_note_and_bonferroni():
    note = stats.multiplicity_note(30)
    assert note.startswith("30 claims were tested, each at 95%") and "about 1.5 would exclude 0 by chance" in note
    assert "hence the adjusted p-values" in note and note.endswith(".")
    assert stats.bonferroni_level(10) == pytest.approx(0.995)
    assert stats.bonferroni_level(1) == pytest.approx(0.95)
    assert stats.multiplicity_note(1).startswith("1 claim was tested")


def test_aggregates_across_tasks_rliable_style():
    """IQM (trimmed mean of the middle half), stratified bootstrap CI over seeds within tasks, run profile."""
    import numpy as np
    from maniskill_dualher.analysis import stats as st
    x = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 100.0])
    assert st.iqm(x) == pytest.approx(np.mean([2.0, 3.0, 4.0, 5.0]))
    m = np.array([[0.1, 0.5], [0.2, 0.7], [0.3, 0.9], [0.4, 0.6]])   # 4 seeds x 2 tasks
    boots = st.stratified_bootstrap({"m": m}, lambda b: b.mean(), 2_000)["m"]
    lo, hi = np.quantile(boots, [0.025, 0.975])
    assert lo < m.mean() < hi
    assert np.array_equal(st.stratified_bootstrap({"m": m}, lambda b: b.mean(), 2_000)["m"], boots)  # seeded
    # stratified: a resample never mixes tasks, so a constant task keeps its value in every resample
    flat = np.array([[0.5, 1.0], [0.5, 2.0], [0.5, 3.0]])
    assert set(st.stratified_bootstrap({"f": flat}, lambda b: b[:, 0].mean(), 500)["f"]) == {0.5}
    assert list(st.performance_profile(m, np.array([0.0, 0.45, 0.95]))) == [1.0, 0.5, 0.0]


def test_probability_of_improvement_interval_resamples_seeds_within_tasks():
    """fig7's P(a > b): the mean over tasks of the per-task probability, its stratified-bootstrap interval drawn
    from the generator it is given (one per figure, shared by its pairs)."""
    import numpy as np
    from maniskill_dualher.analysis import stats as st
    a = np.array([[0.9, 0.6], [0.8, 0.7], [0.7, 0.9]])
    b = np.array([[0.1, 0.5], [0.2, 0.7], [0.3, 0.4]])
    p, lo, hi = st.prob_improvement_ci(a, b, np.random.default_rng(3), 500)
    assert p == pytest.approx(np.mean([st.prob_improvement(a[:, t], b[:, t]) for t in range(2)]))
    assert 0 <= lo <= p <= hi <= 1
    assert st.prob_improvement_ci(a, b, np.random.default_rng(3), 500) == (p, lo, hi)   # seeded
    assert st.prob_improvement_ci(a[:, :1], b[:, :1], np.random.default_rng(0), 200) == (1.0, 1.0, 1.0)


def test_paired_interval_is_the_one_sample_interval_of_the_per_seed_differences():
    from scipy.stats import ttest_1samp
    rng = np.random.default_rng(3)
    prior = rng.lognormal(3, 1, 16)            # each seed's prior: a large spread both sides share
    a, b = prior + rng.normal(2, 1, 16), prior + rng.normal(0, 1, 16)
    unpaired, pair = stats.compare(a, b, 0.1), stats.compare(a, b, 0.1, paired=True)
    assert unpaired.verdict == stats.INCONCLUSIVE and pair.verdict == stats.REPRODUCED
    assert pair.ci_high - pair.ci_low < (unpaired.ci_high - unpaired.ci_low) / 5
    ci = ttest_1samp(a - b, 0).confidence_interval(0.95)   # the floor: the paired t interval, a sensitivity column
    assert (pair.paired_t_low, pair.paired_t_high) == pytest.approx((ci.low, ci.high))
    # the Welch columns stay the two-sample interval, which ignores the pairing (issue: it was the paired t)
    assert (pair.welch_low, pair.welch_high) == pytest.approx((unpaired.welch_low, unpaired.welch_high))
    assert pair.welch_high - pair.welch_low > 5 * (ci.high - ci.low)
    assert pair.ci_low <= ci.low and ci.high <= pair.ci_high and pair.ci_method.startswith("paired")
    assert pair.seeds_to_decide is None and (pair.mean_a, pair.mean_b) == (unpaired.mean_a, unpaired.mean_b)
    with pytest.raises(ValueError, match="paired sides need one value per seed"):
        stats.compare(a, b[:-1], 0.1, paired=True)


def test_ratio_of_means_interval_is_the_contrast_interval_inverted():
    rng = np.random.default_rng(4)
    a, b = rng.normal(100, 20, 32), rng.normal(100, 20, 32)     # no difference, sign undecided at this n
    r, lo, hi = stats.ratio_ci(a, b, 2000)
    assert r == pytest.approx(a.mean() / b.mean()) and lo < 1 < hi and lo < r < hi
    # at each end the contrast mean(A) - rho mean(B)'s interval just touches 0; inside it holds 0, outside not
    assert stats.diff_ci(a, lo * b, 2000)[0] == pytest.approx(0, abs=1e-3)
    assert stats.diff_ci(a, hi * b, 2000)[1] == pytest.approx(0, abs=1e-3)
    assert stats.diff_ci(a, 1.02 * hi * b, 2000)[1] < 0 < stats.diff_ci(a, 0.98 * hi * b, 2000)[1]
    # rho = 1 is the difference's own interval: it holds 1 exactly when the difference's holds 0
    c = stats.compare(a, b, 1, 2000)
    assert (lo < 1 < hi) == (c.ci_low < 0 < c.ci_high)
    # paired: the per-seed differences; a shared prior term narrows it
    prior = rng.normal(100, 30, 16)
    pa, pb = prior + rng.normal(5, 2, 16), prior + rng.normal(0, 2, 16)
    _, plo, phi = stats.ratio_ci(pa, pb, 2000, paired=True)
    _, ulo, uhi = stats.ratio_ci(pa, pb, 2000)
    assert phi - plo < (uhi - ulo) / 3 and plo > 1
    assert stats.diff_ci(pa - plo * pb, np.zeros(16), 2000)[0] == pytest.approx(0, abs=1e-3)
    # no positive mean on B, or too few seeds: no ratio
    assert all(math.isnan(v) for v in stats.ratio_ci([1, 2, 3], [0, 0, 0]))
    assert all(math.isnan(v) for v in stats.ratio_ci([1, 2], [1, 2]))
    # B's mean not clearly above 0: no ratio above some r is excluded
    assert stats.ratio_ci([5, 6, 7, 5], [0.1, -1, 2, 0.5], 2000)[2] == math.inf


def test_p_value_is_the_interval_inverted():
    """p < 1 - level exactly when the interval at that level excludes 0 (same resamples), paired or not."""
    rng = np.random.default_rng(5)
    checked = 0
    for i in range(150):
        a = rng.lognormal(0, 1, rng.integers(3, 12)) + rng.normal(0.8, 0.6)
        b = rng.lognormal(0, 1, rng.integers(3, 12))
        for x, y in ((a, b), (a[:3] - b[:3], np.zeros(3))):
            for level in (0.9, 0.95, 0.99):
                lo, hi = stats.diff_ci(x, y, 1000, seed=i, level=level)
                p, _ = stats._p_values(np.asarray(x), np.asarray(y), 1000, i, level, 0.1)
                if abs(p - (1 - level)) > 1e-3:   # at the boundary itself ties may go either way
                    assert (lo > 0 or hi < 0) == (p < 1 - level), (i, level, p, lo, hi)
                    checked += 1
    assert checked > 500
    c = stats.compare([9, 10, 11, 12], [1, 2, 3, 4], margin=1)
    assert c.p_value < 0.05 and c.p_equivalence == 1.0
    eq = stats.compare([0.9, 1.0, 1.0, 0.95], [1.0, 0.95, 0.9, 1.0], margin=0.1)
    assert eq.p_value > 0.5 and eq.p_equivalence < 0.05
    # the paired p is at least the paired t test's (the interval's floor)
    from scipy.stats import ttest_1samp
    x = rng.normal(1, 2, 12)
    pc = stats.compare(x + 5, np.full(12, 5.0), 0.1, paired=True)
    assert pc.p_value >= ttest_1samp(x, 0).pvalue - 1e-12
    assert stats.compare([1.0, 1, 1], [1.0, 1, 1], 0.1).p_value == 1.0      # no spread, no difference
    assert stats.compare([2.0, 2, 2], [1.0, 1, 1], 0.1).p_value == 0.0


def test_holm_and_benjamini_hochberg():
    p = [0.01, 0.04, 0.03, 0.005, math.nan]
    holm = stats.holm(p)
    # sorted 0.005, 0.01, 0.03, 0.04 times 4, 3, 2, 1, running maximum
    assert list(holm[:4]) == pytest.approx([0.03, 0.06, 0.06, 0.02]) and math.isnan(holm[4])
    bh = stats.benjamini_hochberg(p)
    assert list(bh[:4]) == pytest.approx([0.02, 0.04, 0.04, 0.02]) and math.isnan(bh[4])
    assert list(stats.holm([0.9, 0.8])) == [1.0, 1.0]
    assert stats.holm([]).size == 0


def test_signflip_p_is_exact_and_agrees_with_a_brute_force_count():
    import itertools
    x = np.array([-84.0, 17.0, 18.0, -124.0, 58.0, -96.0, -68.0, -63.0])
    brute = np.mean([abs(np.dot(s, x)) >= abs(x.sum()) - 1e-9 for s in itertools.product((-1, 1), repeat=len(x))])
    assert stats.signflip_p(x) == pytest.approx(brute)
    assert stats.signflip_p(np.array([5.0, 6.0, 7.0, 8.0, 9.0])) == pytest.approx(2 / 32)   # only all-+ and all--
    assert stats.signflip_p(np.zeros(6)) == 1.0


def test_pairs_to_decide_is_the_exact_paired_t_power():
    from scipy.stats import nct, t as t_dist
    x = np.array([-84.0, 17.0, 18.0, -124.0, 58.0, -96.0, -68.0, -63.0])
    n = stats.pairs_to_decide(x, margin=1.0)
    d, sd = abs(x.mean()), x.std(ddof=1)

    def power(k):
        q = t_dist.ppf(0.975, k - 1)
        return nct.sf(q, k - 1, d / sd * np.sqrt(k)) + nct.cdf(-q, k - 1, d / sd * np.sqrt(k))
    assert power(n) >= 0.8 > power(n - 1)
    c = stats.compare(x, np.zeros_like(x), 1.0, paired=True)
    assert c.seeds_to_decide == n and f"~{n} pairs would likely decide it" in c.verdict_text()


def test_no_paired_interval_below_five_pairs_the_paired_t_included():
    """The rule "no paired interval below 5 pairs" holds for every paired interval: the bootstrap-t that decides,
    the paired t beside it and the paired ratio interval; the exact sign-flip p (a test, not an interval) stays."""
    a, b = np.array([77.0, 371, 479, 298]), np.array([161.0, 354, 461, 422])
    c = stats.compare(a, b, 30.0, paired=True)
    assert np.isnan(c.ci_low) and np.isnan(c.ci_high) and c.verdict == stats.INCONCLUSIVE
    assert "not computed below 5 pairs" in c.verdict_text()
    assert np.isnan(c.paired_t_low) and np.isnan(c.paired_t_high) and np.isnan(c.p_value)
    assert c.signflip_p == pytest.approx(stats.signflip_p(a - b)) and 0 < c.signflip_p <= 1
    rho, lo, hi = stats.ratio_ci(a, b, 1000, paired=True)
    assert rho == pytest.approx(a.mean() / b.mean()) and np.isnan(lo) and np.isnan(hi)
    assert not np.isnan(stats.ratio_ci(a, b, 1000)[1])          # unpaired, 4 seeds per side: an interval
    five = stats.compare(np.append(a, 229.0), np.append(b, 171.0), 30.0, paired=True)
    assert not np.isnan(five.ci_low) and five.paired_t_low < five.diff < five.paired_t_high
    assert not np.isnan(stats.ratio_ci(np.append(a, 229.0), np.append(b, 171.0), 1000, paired=True)[1])


def test_the_methods_sentence_names_both_floors():
    """summary.md's methods text (stats.CI_METHOD): Welch's floor for two samples, the paired t for paired claims."""
    assert "never narrower than Welch's t interval" in stats.CI_METHOD
    assert "paired claims" in stats.CI_METHOD and "never narrower than the paired t interval" in stats.CI_METHOD


def test_an_equivalence_read_off_a_floor_is_uninformative_not_decided():
    zeros = np.zeros(8)
    assert stats.compare(zeros, zeros, 0.1, paired=True).verdict == stats.UNINFORMATIVE
    low = np.array([0.01, 0.02, 0.0, 0.01, 0.0, 0.01, 0.02, 0.01])
    c = stats.compare(low, low[::-1], 0.1)
    assert c.verdict == stats.UNINFORMATIVE and "below the margin" in c.verdict_text()
    # the same spread and difference well above the floor is an equivalence that could have failed
    assert stats.compare(low + 0.5, low[::-1] + 0.5, 0.1).verdict == stats.EQUIVALENT
