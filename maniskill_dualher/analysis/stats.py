"""Statistics that decide a claim: a 95% CI on the *difference* between two sides, and a verdict.

A claim says side A beats side B (the paper's direction). Each side is one score per seed, typically
n = 3..30 per side and skewed (counts of successes, steps to a threshold). Sides are independent runs unless
the claim says they are *paired* (below). P(A > B) (+ half the ties) is the Mann-Whitney U statistic over n_A n_B, as in
rliable.

The interval: symmetric bootstrap-t, floored at Welch
------------------------------------------------------
The difference of means d = mean(A) - mean(B) has Welch's standard error se = sqrt(s_A^2/n_A + s_B^2/n_B).
Each side is resampled within itself (rliable's "stratified" bootstrap, one stratum per side), B = 10,000
seeded resamples, and each resample is studentized with its own Welch standard error,
t* = (d* - d) / se*. The interval is d +- q se, where q is the 95% quantile of |t*| (the *symmetric*
bootstrap-t, Hall 1988), but never less than Welch's t quantile t_{0.975, df} (Welch-Satterthwaite df):
at n = 3..4 per side |t*| takes few distinct values, and an interval narrower than Welch's would be
overconfidence we cannot check. A Welch t interval is reported beside it (``welch_low``/``welch_high``).

Why not the percentile bootstrap (what this module used before): it ignores that the spread itself is
estimated from a handful of seeds, so at small n it is too narrow. Equal-tailed bootstrap-t and BCa were
measured too (table below): BCa is no better than the percentile interval on lognormal or exponential
seeds and only slightly better on counts; the equal-tailed bootstrap-t undercovers on lognormal and
exponential seeds (down to 0.905), as its two tails follow the few seeds' skewness, which is noise at
this n; the symmetric one only borrows the size of |t*| from the resamples.

Coverage of the true mean difference, 2000 simulated pairs of samples per cell, 2000 resamples inside
each interval, n seeds per side (``null``: both sides from the same distribution; ``diff``: A from a
wider member of the family: lognormal(0.5, 1) vs lognormal(0, 1),
exponential mean 2 vs 1, zero-inflated Poisson 30% zeros lambda 8 vs 5, and "learned or not" success
counts out of 20, a mixture of Binomial(20, 0.7) and Binomial(20, 0.1), 70% vs 50% learned); measured
with ``python bench/ci_coverage.py --reps 2000 --resamples 2000``::

    case  data                  n         pct        BCa      welch     boot-t sym boot-t  | median width / Welch's
    null  lognormal             4       0.846      0.817      0.982      0.978      0.989  | 0.60 0.63 1.00 1.25 1.35
    null  lognormal             6       0.889      0.846      0.981      0.958      0.990  | 0.75 0.78 1.00 1.10 1.17
    null  lognormal            16       0.918      0.868      0.970      0.916      0.979  | 0.92 0.95 1.00 1.05 1.08
    null  exponential           4       0.854      0.835      0.975      0.976      0.985  | 0.62 0.64 1.00 1.21 1.27
    null  exponential           6       0.901      0.880      0.973      0.960      0.982  | 0.77 0.79 1.00 1.09 1.12
    null  exponential          16       0.913      0.899      0.961      0.922      0.969  | 0.92 0.93 1.00 1.02 1.03
    null  zero-infl. Poisson    4       0.887      0.895      0.954      0.966      0.973  | 0.65 0.68 1.00 1.15 1.18
    null  zero-infl. Poisson    6       0.910      0.918      0.952      0.965      0.964  | 0.79 0.79 1.00 1.06 1.06
    null  zero-infl. Poisson   16       0.935      0.937      0.945      0.949      0.947  | 0.92 0.93 1.00 1.00 1.01
    null  learned or not /20    4       0.879      0.886      0.968      0.991      0.991  | 0.66 0.67 1.00 1.19 1.21
    null  learned or not /20    6       0.906      0.936      0.956      0.994      0.990  | 0.79 0.79 1.00 1.08 1.08
    null  learned or not /20   16       0.942      0.953      0.955      0.974      0.958  | 0.93 0.93 1.00 1.01 1.01
    diff  lognormal             4       0.806      0.784      0.957      0.945      0.973  | 0.60 0.63 1.00 1.26 1.36
    diff  lognormal             6       0.868      0.840      0.949      0.923      0.962  | 0.77 0.79 1.00 1.14 1.21
    diff  lognormal            16       0.904      0.862      0.948      0.905      0.962  | 0.91 0.95 1.00 1.06 1.11
    diff  exponential           4       0.801      0.795      0.941      0.931      0.966  | 0.61 0.63 1.00 1.26 1.34
    diff  exponential           6       0.863      0.853      0.939      0.928      0.954  | 0.75 0.78 1.00 1.11 1.16
    diff  exponential          16       0.908      0.906      0.938      0.927      0.944  | 0.92 0.94 1.00 1.05 1.06
    diff  zero-infl. Poisson    4       0.857      0.866      0.954      0.965      0.970  | 0.63 0.65 1.00 1.16 1.20
    diff  zero-infl. Poisson    6       0.897      0.905      0.942      0.959      0.960  | 0.78 0.78 1.00 1.07 1.08
    diff  zero-infl. Poisson   16       0.934      0.942      0.948      0.962      0.950  | 0.92 0.92 1.00 1.01 1.01
    diff  learned or not /20    4       0.853      0.882      0.968      0.976      0.983  | 0.65 0.66 1.00 1.22 1.25
    diff  learned or not /20    6       0.894      0.917      0.949      0.986      0.979  | 0.79 0.79 1.00 1.10 1.09
    diff  learned or not /20   16       0.929      0.944      0.950      0.971      0.955  | 0.93 0.93 1.00 1.01 1.01

At n = 6 the chosen interval covers 0.954-0.990 in every case above, percentile 0.863-0.910, Welch t
0.939-0.981 (Welch alone would also clear 93%, but drifts to 0.94 when a skewed side dominates; the floor
makes ours cover at least as often as Welch's). Width: the median interval at n = 6 is 1.06-1.21x Welch's
(percentile: 0.75-0.79x). Its tail is wider where one seed sits far above the rest: at n = 6 the 90th
percentile of the width ratio to Welch is 2.1-2.3x on lognormal seeds, 1.5-1.7x on exponential ones,
<= 1.4x on the count data; such a sample cannot support a narrow interval. Seeded (``seed``); across seeds the endpoints move by ~0.5-1%
of the width at B = 10,000. Cost: ~3 ms per comparison at n = 6, ~17 ms at n = 30 (10,000 resamples).

Degenerate inputs: fewer than MIN_SEEDS per side gives no interval (NaN, inconclusive); no spread on
either side gives the zero-width interval [d, d] (every resample has the same difference); when 5% or
more of the resamples have no spread on either side (e.g. a side of mostly zeros), |t*| is infinite for
them and the bootstrap cannot studentize, so the Welch t interval is used (``ci_method`` says so).

Verdicts follow the interval and nothing else:

* **reproduced**: the CI excludes 0 in the paper's direction;
* **contradicted**: the CI excludes 0 the other way;
* **no difference larger than X**: the CI lies within +-X, where X is the claim's stated margin of
  practical equivalence;
* **uninformative**: the CI lies within +-X, but both sides are non-negative with means below X, so no
  difference as large as X could appear (a floor, e.g. every run at 0 success): not counted as decided;
* **inconclusive**: none of these.

For an inconclusive claim we say how many seeds per side would likely decide it, at 80% power:
taking the observed difference d and variances as the truth, a two-sided 5% test of d = 0 with n seeds
per side has 80% power when n = (z_0.975 + z_0.8)^2 (s_A^2 + s_B^2) / d^2 (~7.85 (s_A^2 + s_B^2) / d^2);
for the equivalence direction the same with margin - |d| in place of d (the CI half-width must clear
margin - |d|). The smaller of the two, at least max(n_A, n_B) + 1, and none above MAX_SEEDS_ADVICE. (The
old rule, 1.96^2 (s_A^2 + s_B^2) / d^2, only makes the CI *expected* to clear 0: about 50% power.) It is
a normal approximation, so at small n it is optimistic; it is advice, never a verdict.

Paired sides
------------
Two kinds of claims are paired by seed (``claims.paired_seeds`` decides which seeds, from the definition and
the source stages, never from the outcome). (1) Both sides adapt one prior for each seed: the same
source-stage runs (run identity and every recorded source-stage score equal: one shared folder, or the same
config and seed trained again on one kind of CPU), e.g. the ratio arms, or an ablation arm beside the paper's
arm. The prior's seed-to-seed spread is common to both and cancels in the per-seed differences. (2) Both sides
start from nothing (a ``scratch`` experiment, or single-task runs) and ran on the same kind of CPU: a seed fixes
a run's initial networks, its random streams and every episode's reset seed, so the same seed starts both sides
from the same point (issue 39; their outcomes correlate, ``pair_corr`` in ``claims.csv``). A seed pairs only when
both sides have it; when the seeds that pair are at least half of the smaller side's (and at least
``MIN_SEEDS``), the claim is decided on them alone, paired, and the other seeds are left out; otherwise it is
decided on every seed, unpaired. For the per-seed differences x_s = A_s - B_s, ``compare(..., paired=True)``
gives the same symmetric bootstrap-t on the one sample x (resampling seeds, studentized by sd(x*)/sqrt(n)),
floored at the paired t interval, and the advice counts pairs, exactly (``pairs_to_decide``: the noncentral t
power of the paired t test at the observed mean and sd of x). Below ``MIN_PAIRS`` (5) pairs no paired interval
is computed (neither this one, nor the paired t, nor a paired ratio interval; the sign-flip p stays): at 4 pairs,
near-equal differences make resamples of tiny spread and |t*| a huge quantile. From 5 pairs on, beside
it, as sensitivity analyses that never set the verdict: the paired t interval (``paired_t_low``/``_high``)
and the exact sign-flip permutation p (``signflip_p``); the Welch columns stay the two-sample interval that
ignores the pairing. It is the same code path as the two-sample interval with B = 0 (one stratum, df = n - 1); when
every difference is 0 (the identity check ``scratch_e_off``) the interval is [0, 0].
Pairing is decided from the data (``claims.paired``), never by the outcome. Coverage, measured as above with
a shared prior term per seed (``python bench/ci_coverage.py --paired --reps 1000 --resamples
1000 --n 6 16 32 --methods percentile welch-t "symmetric bootstrap-t"``, CPU B): the chosen interval covers
0.959-0.989 at n = 6, 0.936-0.980 at n = 16 and 0.936-0.976 at n = 32 over the same 8 cases (paired t:
0.929-0.971; percentile 0.839-0.942); the lowest, 0.936, is the exponential "diff" case, where the
unpaired interval also sits at 0.944. Median width 1.01-1.15x the paired t interval's at n >= 16.

p-values, and the correction for many claims
--------------------------------------------
Each claim's verdict is read off its 95% interval. Its p-value (``Comparison.p_value``) is that same
interval inverted: the smallest alpha at which the 1 - alpha interval (same resamples, same Welch floor)
no longer reaches 0. As the interval is d +- max(q_boot, q_welch) se, it is the larger of Welch's two-sided
p (paired: the paired t test's) and the bootstrap-t p, the share of resamples with |t*| >= |d| / se (both
``_p_sym``); so p < 0.05 exactly when the 95% interval excludes 0 (tested). ``p_equivalence`` inverts the
equivalence verdict the same way (the level at which the interval just fits inside +-margin).

``claims.claim_rows`` adjusts the p-values within each family of claims, the paper's (a)-(h') and the
ablations, by Holm (``holm``: step-down, controls the chance of any false "excludes 0" in the family at
5%) and by Benjamini-Hochberg (``benjamini_hochberg``: scipy's ``false_discovery_control``, controls the
expected share of false ones). The verdict column stays the 95% interval's; ``survives_holm`` says whether
a decided verdict still holds after Holm (direction verdicts: Holm-adjusted p < 0.05; an equivalence
verdict: its own p times the family's size, Bonferroni, which is never less strict than Holm). The README
leans only on verdicts that survive Holm.

The paper's numbers
-------------------
Where the paper reports both sides' numbers (Tables 4 and 5: one run per side, no spread) the claim
carries the paper's ratio rho = A/B (a lower bound where the paper says "< x"), and ``ratio_ci`` puts our
ratio of means beside it: mean(A)/mean(B) with the ratios r whose contrast mean(A) - r mean(B) the same
symmetric bootstrap-t interval does not exclude (paired: on a - r b), a Fieller-type inversion of the
claim's own interval (same resamples for every r, so the ends are found by root search). Its upper end
below rho says an effect of the paper's size is excluded in this setting; that is a statement about size,
not a verdict: the direction verdict stays the difference's ("small telescopes", Simonsohn 2015). A ratio is
our closest scale-free reading of the paper's numbers; it is not budget-free (the paper's counts come from
a far larger budget, and the ratio moves with the budget: ``budget.py``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Dict, Optional, Sequence, Tuple

import numpy as np

REPRODUCED = "reproduced"
CONTRADICTED = "contradicted"
EQUIVALENT = "no difference larger than"
INCONCLUSIVE = "inconclusive"
# an equivalence read off a floor: both sides non-negative with means below the margin, so no difference as large
# as the margin could appear whatever the methods did (e.g. every run at 0 evaluation success); not "decided"
UNINFORMATIVE = "uninformative"
ALPHA = 0.05            # 1 - the intervals' level: what an adjusted p-value is held to
MIN_SEEDS = 3            # fewer per side: no CI is computed (a bootstrap of 2 values is just their range)
# fewer pairs: no paired bootstrap-t interval. At 4 pairs a near-tie of the differences gives resamples of
# tiny spread and |t*| a huge quantile ([-7620, 7540] once, where the paired t said [-158, 71])
MIN_PAIRS = 5
MAX_SEEDS_ADVICE = 1000  # above this, "more seeds" is no advice
POWER = 0.8              # seeds_to_decide: power of a two-sided 5% test at the observed difference

BOOT_T = "symmetric bootstrap-t"   # ci_method values
WELCH = "welch-t"
WELCH_FALLBACK = "welch-t (bootstrap-t degenerate)"
NO_SPREAD = "exact (no spread)"
CI_METHOD = ("symmetric bootstrap-t: resampled Welch t statistics, never narrower than Welch's t interval; for "
             "paired claims, resampled one-sample t statistics of the per-seed differences, never narrower than "
             "the paired t interval")

# Relative to the data's magnitude: below this a resample's spread or shift is floating-point noise.
_TOL = 1e-10


@dataclass
class Comparison:
    n_a: int
    n_b: int
    mean_a: float
    mean_b: float
    diff: float
    ci_low: float
    ci_high: float
    prob_improvement: float
    margin: float
    verdict: str
    seeds_to_decide: Optional[int]   # per side (paired: pairs), for an inconclusive verdict
    welch_low: float = math.nan      # two-sample Welch t interval (ignores any pairing), a cross-check
    welch_high: float = math.nan
    ci_method: str = BOOT_T          # what produced ci_low/ci_high (see the module doc)
    paired: bool = False
    p_value: float = math.nan        # two-sided test of A = B: the interval at level 1 - p just reaches 0
    p_equivalence: float = math.nan  # the interval at level 1 - p just reaches +-margin (1: |diff| >= margin)
    # paired only, sensitivity analyses beside the interval (never the verdict): the paired t interval and the
    # exact two-sided sign-flip permutation p of the mean difference
    paired_t_low: float = math.nan
    paired_t_high: float = math.nan
    signflip_p: float = math.nan

    def verdict_text(self) -> str:
        if self.verdict == EQUIVALENT:
            return f"{EQUIVALENT} {self.margin:.3g}"
        if self.verdict == UNINFORMATIVE:
            why = "every run at 0 on both sides" if self.mean_a == 0 == self.mean_b else \
                f"both means below the margin {self.margin:.3g}, so no difference that large could appear"
            return f"{UNINFORMATIVE} ({why})"
        if self.verdict == INCONCLUSIVE:
            if self.n_a < MIN_SEEDS or self.n_b < MIN_SEEDS:
                return f"{INCONCLUSIVE} (needs >= {MIN_SEEDS} seeds per side)"
            if self.paired and math.isnan(self.ci_low) and self.n_a < MIN_PAIRS:
                return f"{INCONCLUSIVE} (interval not computed below {MIN_PAIRS} pairs)"
            unit = "pairs" if self.paired else "seeds per side"
            more = f"~{self.seeds_to_decide} {unit} would likely decide it (80% power)" \
                if self.seeds_to_decide is not None else "more seeds would not decide it at this spread"
            return f"{INCONCLUSIVE} ({more})"
        return self.verdict


def _welch(a: np.ndarray, b: np.ndarray, level: float) -> Tuple[float, float, float, float]:
    """(low, high, se, t quantile) of Welch's t interval for mean(a) - mean(b); se = 0 means no spread."""
    from scipy.stats import t as t_dist

    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    d, se = float(a.mean() - b.mean()), math.sqrt(va + vb)
    if se == 0:
        return d, d, 0.0, math.nan
    # Welch-Satterthwaite; a side without spread contributes no term (df = the other side's n - 1)
    df = (va + vb) ** 2 / ((va ** 2 / (len(a) - 1) if va else 0.0) + (vb ** 2 / (len(b) - 1) if vb else 0.0))
    q = float(t_dist.ppf(0.5 + level / 2, df))
    return d - q * se, d + q * se, se, q


def _boot_means_vars(a, b, resamples, rng):
    """Each side resampled within itself: means and variances (ddof=1) of every resample, vectorized."""
    ra = a[rng.integers(0, len(a), (resamples, len(a)))]
    rb = b[rng.integers(0, len(b), (resamples, len(b)))]
    return ra.mean(1), ra.var(1, ddof=1), rb.mean(1), rb.var(1, ddof=1)


def _t_star(a, b, resamples, seed) -> np.ndarray:
    """The resamples' Welch t statistics t* = (d* - d) / se* (+-inf where a resample has no spread)."""
    d = float(a.mean() - b.mean())
    ma, va, mb, vb = _boot_means_vars(a, b, resamples, np.random.default_rng(seed))
    scale = max(float(np.abs(a).max()), float(np.abs(b).max()))
    dev = (ma - mb) - d
    se_star = np.sqrt(va / len(a) + vb / len(b))
    dev[np.abs(dev) <= _TOL * scale] = 0.0
    flat = se_star <= _TOL * scale  # a resample without spread: t* is 0 (no shift) or infinite
    t = np.zeros_like(dev)
    t[~flat] = dev[~flat] / se_star[~flat]
    t[flat & (dev != 0)] = np.copysign(np.inf, dev[flat & (dev != 0)])
    return t


def _boot_t(a, b, resamples, seed, level, symmetric=True) -> Tuple[float, float, str]:
    wl, wh, se, q_welch = _welch(a, b, level)
    d = float(a.mean() - b.mean())
    if se == 0:  # every resample gives the same difference
        return d, d, NO_SPREAD
    t = _t_star(a, b, resamples, seed)
    if symmetric:
        qs = np.abs(t)
        if np.mean(np.isinf(qs)) >= 1 - level:  # the quantile itself would be infinite
            return wl, wh, WELCH_FALLBACK
        q = max(float(np.quantile(qs[np.isfinite(qs)], _finite_rank(qs, level))), q_welch)
        return d - q * se, d + q * se, BOOT_T
    # equal-tailed bootstrap-t (measured in the module doc, not used by compare)
    p_lo, p_hi = (1 - level) / 2, (1 + level) / 2
    if np.mean(t == -np.inf) >= p_lo or np.mean(t == np.inf) >= p_lo:
        return wl, wh, WELCH_FALLBACK
    fin = np.sort(t[np.isfinite(t)])
    n_neg = int(np.sum(t == -np.inf))
    q_lo = float(np.quantile(fin, _finite_rank_at(p_lo, len(t), n_neg, len(fin))))
    q_hi = float(np.quantile(fin, _finite_rank_at(p_hi, len(t), n_neg, len(fin))))
    return d - q_hi * se, d - q_lo * se, "bootstrap-t"


def _p_sym(a, b, resamples, seed, level, z: float) -> float:
    """The p-value of the symmetric bootstrap-t interval at distance z (in Welch standard errors) from the
    difference: the smallest alpha at which the 1 - alpha interval (``_boot_t``, same resamples) no longer
    reaches a point z se away. The interval is d +- max(q_boot, q_welch) se, so this is the larger of the
    two p-values, Welch's 2 P(T_df > z) and the share of resamples with |t*| >= z (numpy's linear quantile,
    inverted); where the interval at ``level`` falls back to Welch's (>= 1 - level of the |t*| infinite),
    Welch's alone. So p < 1 - level exactly when the interval at ``level`` excludes that point."""
    from scipy.stats import t as t_dist

    if z <= 0:
        return 1.0
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    df = (va + vb) ** 2 / ((va ** 2 / (len(a) - 1) if va else 0.0) + (vb ** 2 / (len(b) - 1) if vb else 0.0))
    p_welch = float(2 * t_dist.sf(z, df))
    qs = np.abs(_t_star(a, b, resamples, seed))
    frac_inf = float(np.mean(np.isinf(qs)))
    if frac_inf >= 1 - level:  # the interval at this level is Welch's
        return p_welch
    fin = np.sort(qs[np.isfinite(qs)])
    # the largest level L whose quantile of |t*| is still below z: its position in the sorted sample
    pos = float(np.interp(z, fin, np.arange(len(fin)))) if z <= fin[-1] else len(fin) - 1.0
    if z <= fin[0]:
        pos = 0.0
    p_boot = 1.0 - pos / max(len(qs) - 1, 1)
    return max(p_boot, p_welch)


def _p_values(x, y, resamples, seed, level, margin) -> Tuple[float, float]:
    """(p of A = B, p of equivalence within +-margin), both inverted from the interval ``compare`` uses."""
    d = float(x.mean() - y.mean())
    se = math.sqrt(x.var(ddof=1) / len(x) + y.var(ddof=1) / len(y))
    if se == 0:  # the interval is the point d
        return float(d == 0), float(abs(d) > margin)
    return (_p_sym(x, y, resamples, seed, level, abs(d) / se),
            _p_sym(x, y, resamples, seed, level, (margin - abs(d)) / se) if margin > abs(d) else 1.0)


def ratio_ci(a: Sequence[float], b: Sequence[float], resamples: int = 10_000, seed: int = 0,
             level: float = 0.95, paired: bool = False) -> Tuple[float, float, float]:
    """mean(A) / mean(B) and its interval: the ratios rho whose contrast mean(A) - rho mean(B) the
    symmetric bootstrap-t interval (paired: on a - rho b) does not exclude, a Fieller-type inversion of the
    difference's own interval (module doc). NaN without a positive mean(B) or with < MIN_SEEDS per side (paired:
    the ratio with a NaN interval below MIN_PAIRS pairs);
    an end is +-inf where no rho excludes it."""
    from scipy.optimize import brentq

    a, b = _as_scores(a), _as_scores(b)
    if min(len(a), len(b)) < MIN_SEEDS or not b.mean() > 0:
        return math.nan, math.nan, math.nan
    if paired and len(a) != len(b):
        raise ValueError(f"paired sides need one value per seed on each side (got {len(a)} and {len(b)})")
    rho = float(a.mean() / b.mean())
    if paired and len(a) < MIN_PAIRS:   # no paired interval below MIN_PAIRS pairs (compare's rule)
        return rho, math.nan, math.nan

    def bound(r: float, end: int) -> float:  # the contrast interval's low (0) or high (1) end at ratio r
        x, y = (a - r * b, np.zeros_like(a)) if paired else (a, r * b)
        return _diff_ci(x, y, resamples, seed, level, BOOT_T)[end]

    def limit(end: int, sign: int) -> float:
        # the contrast falls as r grows: below the interval its low end is > 0, above it its high end < 0;
        # step outward from rho (where the contrast is 0) until it is, then find the crossing
        inner, step = rho, max(abs(rho), 1.0) / 8
        for _ in range(40):
            outer = inner + sign * step
            if (bound(outer, end) > 0) if sign < 0 else (bound(outer, end) < 0):
                return float(brentq(lambda r: bound(r, end), min(inner, outer), max(inner, outer),
                                    xtol=1e-6 * max(abs(rho), 1.0)))
            inner, step = outer, step * 2
        return sign * math.inf
    return rho, limit(0, -1), limit(1, 1)


def holm(p: Sequence[float]) -> np.ndarray:
    """Holm's step-down adjusted p-values (NaN entries stay NaN and do not count)."""
    p = np.asarray(p, float)
    out = np.full_like(p, np.nan)
    ok = np.flatnonzero(np.isfinite(p))
    if ok.size:
        order = ok[np.argsort(p[ok], kind="stable")]
        m = ok.size
        out[order] = np.minimum(np.maximum.accumulate((m - np.arange(m)) * p[order]), 1.0)
    return out


def benjamini_hochberg(p: Sequence[float]) -> np.ndarray:
    """Benjamini-Hochberg adjusted p-values (scipy's ``false_discovery_control``; NaN entries stay NaN)."""
    from scipy.stats import false_discovery_control

    p = np.asarray(p, float)
    out = np.full_like(p, np.nan)
    ok = np.isfinite(p)
    if ok.any():
        out[ok] = false_discovery_control(p[ok], method="bh")
    return out


def _finite_rank(qs: np.ndarray, p: float) -> float:
    """The p quantile of qs (with +inf entries, all at the top) as a quantile of its finite part."""
    return _finite_rank_at(p, len(qs), 0, int(np.isfinite(qs).sum()))


def _finite_rank_at(p: float, n_all: int, n_below: int, n_fin: int) -> float:
    # position p (n_all - 1) in the full sorted sample, shifted past the -inf entries, as a fraction of
    # the finite part (numpy's default "linear" quantile definition)
    pos = p * (n_all - 1) - n_below
    return min(max(pos / max(n_fin - 1, 1), 0.0), 1.0)


def _percentile(a, b, resamples, seed, level) -> Tuple[float, float, str]:
    d = float(a.mean() - b.mean())
    if np.ptp(a) == 0 and np.ptp(b) == 0:
        return d, d, NO_SPREAD
    ma, _, mb, _ = _boot_means_vars(a, b, resamples, np.random.default_rng(seed))
    lo, hi = np.quantile(ma - mb, [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi), "percentile"


def _bca(a, b, resamples, seed, level) -> Tuple[float, float, str]:
    from scipy.stats import bootstrap

    d = float(a.mean() - b.mean())
    if np.ptp(a) == 0 and np.ptp(b) == 0:
        return d, d, NO_SPREAD
    import inspect
    seeded = {"rng" if "rng" in inspect.signature(bootstrap).parameters else "random_state":
              np.random.default_rng(seed)}  # scipy >= 1.15 names it rng
    res = bootstrap((a, b), lambda x, y, axis: x.mean(axis) - y.mean(axis), vectorized=True, paired=False,
                    n_resamples=resamples, confidence_level=level, method="BCa", **seeded)
    return float(res.confidence_interval.low), float(res.confidence_interval.high), "BCa"


METHODS: Dict[str, Callable] = {
    BOOT_T: _boot_t,
    "bootstrap-t": lambda a, b, r, s, lv: _boot_t(a, b, r, s, lv, symmetric=False),
    "percentile": _percentile,
    "BCa": _bca,
    WELCH: lambda a, b, r, s, lv: _welch(a, b, lv)[:2] + (WELCH,),
}


def _as_scores(x: Sequence[float]) -> np.ndarray:
    x = np.asarray(x, float).ravel()
    if not np.isfinite(x).all():  # a NaN score is a broken run, not a data point
        raise ValueError("scores must be finite")
    return x


def diff_ci(a: Sequence[float], b: Sequence[float], resamples: int = 10_000, seed: int = 0,
            level: float = 0.95, method: str = BOOT_T) -> Tuple[float, float]:
    """CI of mean(a) - mean(b) (the module doc's symmetric bootstrap-t unless ``method`` says otherwise:
    one of METHODS, for comparison). NaN when a side has fewer than 2 values (no spread to estimate)."""
    return _diff_ci(_as_scores(a), _as_scores(b), resamples, seed, level, method)[:2]


def _diff_ci(a, b, resamples, seed, level, method) -> Tuple[float, float, str]:
    if min(len(a), len(b)) < 2:
        return math.nan, math.nan, method
    return METHODS[method](a, b, resamples, seed, level)


def prob_improvement(a: Sequence[float], b: Sequence[float]) -> float:
    """P(A > B) + 0.5 P(A = B) over all pairs of runs (rliable's probability of improvement)."""
    a, b = np.asarray(a, float)[:, None], np.asarray(b, float)[None, :]
    return float(((a > b) + 0.5 * (a == b)).mean())


def seeds_to_decide(a: np.ndarray, b: np.ndarray, margin: float, power: float = POWER) -> Optional[int]:
    """Seeds per side at which a two-sided 5% test would, with ``power``, exclude 0 at the observed
    difference, or fit the CI in +-margin (normal approximation; see the module doc)."""
    from scipy.stats import norm

    a, b = np.asarray(a, float), np.asarray(b, float)
    var = a.var(ddof=1) + b.var(ddof=1)
    if not var > 0:
        return None
    k = (norm.ppf(0.975) + norm.ppf(power)) ** 2   # 7.85 at 80% power (1.96^2 = 3.84 is 50% power)
    d = abs(a.mean() - b.mean())
    cands = []
    if d > 0:
        cands.append(k * var / d ** 2)             # excludes 0
    if margin > d:
        cands.append(k * var / (margin - d) ** 2)  # |d| + half-width < margin: equivalent
    if not cands:
        return None
    n = int(math.ceil(min(cands)))
    n = max(n, max(len(a), len(b)) + 1)
    return n if n <= MAX_SEEDS_ADVICE else None


def pairs_to_decide(x: np.ndarray, margin: float, power: float = POWER) -> Optional[int]:
    """Pairs at which the two-sided 5% paired t test would, with ``power``, exclude 0 at the observed mean
    difference, or fit the interval in +-margin: exact, from the noncentral t distribution, taking the observed
    mean and sd of the differences ``x`` as the truth. At least len(x) + 1; None above MAX_SEEDS_ADVICE."""
    from scipy.stats import nct, t as t_dist

    x = np.asarray(x, float)
    sd = float(x.std(ddof=1))
    if not sd > 0:
        return None
    d = abs(float(x.mean()))
    effects = [e for e in (d, margin - d) if e > 0]
    if not effects:
        return None

    def pw(n: int, e: float) -> float:
        q, ncp = t_dist.ppf(0.975, n - 1), e / sd * math.sqrt(n)
        return float(nct.sf(q, n - 1, ncp) + nct.cdf(-q, n - 1, ncp))

    best = None
    for e in effects:
        lo, hi = max(len(x) + 1, 2), MAX_SEEDS_ADVICE
        if pw(hi, e) < power:
            continue
        while lo < hi:   # power grows with n
            mid = (lo + hi) // 2
            lo, hi = (mid + 1, hi) if pw(mid, e) < power else (lo, mid)
        best = lo if best is None else min(best, lo)
    return best


def signflip_p(x: Sequence[float], reps: int = 200_000, seed: int = 0) -> float:
    """Two-sided sign-flip permutation p of mean(x) = 0 for paired differences x (under H0 each difference's
    sign is a fair coin): exact over all 2^n sign patterns up to n = 20, else ``reps`` seeded random patterns."""
    x = np.asarray(x, float)
    n = len(x)
    obs = abs(float(x.sum()))
    tol = 1e-9 * max(1.0, float(np.abs(x).sum()))
    if n <= 20:
        signs = ((np.arange(2 ** n)[:, None] >> np.arange(n)) & 1) * 2 - 1
    else:
        signs = np.random.default_rng(seed).integers(0, 2, (reps, n)) * 2 - 1
    return float(np.mean(np.abs(signs @ x) >= obs - tol))


def bonferroni_level(n_claims: int, level: float = 0.95) -> float:
    """Per-claim confidence level that keeps the chance of any false exclusion of 0 below 1 - level."""
    return 1 - (1 - level) / max(int(n_claims), 1)


def multiplicity_note(n_claims: int, level: float = 0.95) -> str:
    """One sentence for the report: how many of n_claims CIs would exclude 0 by chance alone."""
    n = int(n_claims)
    alpha = 1 - level
    tested = f"{n} claim was tested, at {level:.0%}" if n == 1 else f"{n} claims were tested, each at {level:.0%}"
    return (f"{tested}; with {n} independent test{'s' if n != 1 else ''} about {alpha * n:.2g} would exclude 0 "
            f"by chance if no difference existed, hence the adjusted p-values (Bonferroni over all of them "
            f"would use {bonferroni_level(n, level):.2%} per claim).")


def compare(a: Sequence[float], b: Sequence[float], margin: float, resamples: int = 10_000,
            seed: int = 0, level: float = 0.95, paired: bool = False) -> Comparison:
    """Does A beat B? The difference A - B with its CI, one verdict and the p-values of its tests (see the
    module doc). ``paired``: a[i] and b[i] adapted the same prior (same seed)."""
    a, b = _as_scores(a), _as_scores(b)
    if len(a) == 0 or len(b) == 0:
        raise ValueError("compare needs at least one value per side")
    if paired and len(a) != len(b):
        raise ValueError(f"paired sides need one value per seed on each side (got {len(a)} and {len(b)})")
    mean_a, mean_b = float(a.mean()), float(b.mean())
    diff = mean_a - mean_b
    p_imp = prob_improvement(a, b)
    if min(len(a), len(b)) < MIN_SEEDS:
        return Comparison(len(a), len(b), mean_a, mean_b, diff, math.nan, math.nan, p_imp, margin,
                          INCONCLUSIVE, None, ci_method="none (too few seeds)", paired=paired)
    # the two-sample Welch interval ignores any pairing: the cross-check of an unpaired reading
    wl, wh, _, _ = _welch(a, b, level)
    sens = {}
    if paired:
        x = a - b
        if len(x) < MIN_PAIRS:   # no paired interval at all, the paired t's included; the exact sign-flip p stays
            return Comparison(len(a), len(b), mean_a, mean_b, diff, math.nan, math.nan, p_imp, margin,
                              INCONCLUSIVE, pairs_to_decide(x, margin), wl, wh,
                              f"none (fewer than {MIN_PAIRS} pairs)", paired, signflip_p=signflip_p(x))
        tl, th, _, _ = _welch(x, np.zeros_like(x), level)   # one sample beside zeros: the paired t interval
        sens = dict(paired_t_low=tl, paired_t_high=th, signflip_p=signflip_p(x))
    # paired: the one sample of per-seed differences beside zeros, i.e. the two-sample code with B = 0
    x, y = (a - b, np.zeros_like(a)) if paired else (a, b)
    lo, hi, how = _diff_ci(x, y, resamples, seed, level, BOOT_T)
    p, p_eq = _p_values(x, y, resamples, seed, level, margin)
    if lo > 0:
        verdict = REPRODUCED
    elif hi < 0:
        verdict = CONTRADICTED
    elif -margin <= lo and hi <= margin:
        floor = min(a.min(), b.min()) >= 0 and max(mean_a, mean_b) < margin
        verdict = UNINFORMATIVE if floor else EQUIVALENT
    else:
        verdict = INCONCLUSIVE
    need = None
    if verdict == INCONCLUSIVE:
        need = pairs_to_decide(x, margin) if paired else seeds_to_decide(x, y, margin)
    return Comparison(len(a), len(b), mean_a, mean_b, diff, lo, hi, p_imp, margin, verdict, need, wl, wh,
                      ("paired " if paired else "") + how, paired, p, p_eq, **sens)


# --------------------------------------------------------------------------- a mean over seeds (tables, plots, evaluate)
def mean_ci(x: Sequence[float], level: float = 0.95) -> Tuple[float, float]:
    """Student-t interval of a mean over seeds (NaN below 2 seeds; the point if there is no spread)."""
    from scipy import stats as st
    x = np.asarray(x, float)
    if x.size < 2:
        return math.nan, math.nan
    se = x.std(ddof=1) / math.sqrt(x.size)
    if se == 0:
        return float(x.mean()), float(x.mean())
    h = float(st.t.ppf(0.5 + level / 2, x.size - 1) * se)
    return float(x.mean() - h), float(x.mean() + h)


def rate_ci(x: Sequence[float], level: float = 0.95, resamples: int = 10_000) -> Tuple[float, float]:
    """Percentile-bootstrap interval of a mean of rates over seeds (seeded: the report rebuilds byte-identically);
    inside the values' range, so inside [0, 1]. NaN below 2 seeds."""
    x = np.asarray(x, float)
    if x.size < 2:
        return math.nan, math.nan
    means = x[np.random.default_rng(0).integers(0, x.size, (resamples, x.size))].mean(axis=1)
    q = (1 - level) / 2
    return float(np.quantile(means, q)), float(np.quantile(means, 1 - q))


def boot_mean_ci(y: np.ndarray, level: float = 0.95, resamples: int = 2_000, seed: int = 0):
    """Percentile-bootstrap interval of the mean over rows (seeds) of ``y`` (seeds, points), per column: inside the
    values' range, so a success rate's band stays in [0, 1]. One seed: the point itself (the plots' bands)."""
    y = np.asarray(y, float)
    if y.shape[0] < 2:
        return y[0], y[0]
    idx = np.random.default_rng(seed).integers(0, y.shape[0], (resamples, y.shape[0]))
    means = y[idx].mean(axis=1)
    q = (1 - level) / 2
    return np.quantile(means, q, axis=0), np.quantile(means, 1 - q, axis=0)


# --------------------------------------------------------------------------- aggregates across tasks (rliable's)
def stratified_bootstrap(mats: Dict[str, np.ndarray], fn, resamples: int = 2_000,
                         seed: int = 0) -> Dict[str, np.ndarray]:
    """fn(resampled matrix) for each key's (seeds, tasks) matrix: rows (seeds) resampled within each column
    (task), seeded; one generator across the keys, in their order. Its quantiles are the plots' intervals."""
    rng = np.random.default_rng(seed)
    out = {}
    for m, x in mats.items():
        idx = rng.integers(0, x.shape[0], (resamples, x.shape[0], x.shape[1]))
        out[m] = np.array([fn(np.take_along_axis(x, idx[b], axis=0)) for b in range(resamples)])
    return out


def iqm(x: np.ndarray, axis=None) -> np.ndarray:
    """Interquartile mean: the mean of the middle 50% (rliable's robust aggregate; scipy's trim_mean)."""
    from scipy.stats import trim_mean
    return trim_mean(x, 0.25, axis=axis)


def prob_improvement_ci(xa: np.ndarray, xb: np.ndarray, rng: np.random.Generator, resamples: int = 500,
                        level: float = 0.95) -> Tuple[float, float, float]:
    """(point, low, high): P(a > b) averaged over tasks (``prob_improvement`` per column of two (seeds, tasks)
    matrices), with rliable's stratified-bootstrap interval: both sides' seeds resampled within each task,
    drawn from ``rng`` (the figure shares one generator across its pairs, in their order)."""
    tasks = range(xa.shape[1])
    p = float(np.mean([prob_improvement(xa[:, t], xb[:, t]) for t in tasks]))
    bs = []
    for _ in range(resamples):
        ia = rng.integers(0, xa.shape[0], xa.shape)
        ib = rng.integers(0, xb.shape[0], xb.shape)
        ra, rb = np.take_along_axis(xa, ia, 0), np.take_along_axis(xb, ib, 0)
        bs.append(np.mean([prob_improvement(ra[:, t], rb[:, t]) for t in tasks]))
    q = (1 - level) / 2
    lo, hi = np.quantile(bs, [q, 1 - q])
    return p, float(lo), float(hi)


def performance_profile(scores: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """Fraction of runs (all tasks and seeds) scoring above each threshold tau (rliable's run-score profile)."""
    return (scores.reshape(-1)[None, :] > taus[:, None]).mean(axis=1)


def wilson(successes: int, n: int, level: float = 0.95) -> Tuple[float, float]:
    """Wilson score interval of a binomial proportion successes/n: always inside [0, 1] (evaluate, plots)."""
    k, n = int(successes), int(n)
    if n < 1 or not 0 <= k <= n:
        raise ValueError(f"wilson needs 0 <= successes <= n and n >= 1, got {k}/{n}")
    from scipy.stats import binomtest
    ci = binomtest(k, n).proportion_ci(confidence_level=level, method="wilson")
    return float(ci.low), float(ci.high)


# --------------------------------------------------------------------------- a group-sequential look (paired t)
# results/paper_regime/AMENDMENT.md: looks at 8 and 16 pairs, two-sided Lan-DeMets O'Brien-Fleming critical
# values for the paired t (bench/group_sequential.py), a non-binding futility bound at the first look
SEQUENTIAL_LOOKS = ((8, 3.94), (16, 2.17))
SEQUENTIAL_FUTILITY = 0.5


def sequential_look(x: Sequence[float]) -> Dict[str, object]:
    """The amendment's decision on paired differences ``x`` (in seed order): at the last look they reach, its
    t, critical value, repeated confidence interval mean +- c se, the exact sign-flip p and the skewness of the
    differences (sensitivity), and the decision: "stop: A > B" / "stop: A < B" (|t| > c, and at the first look
    every difference of one sign), "may stop for futility" (first look, |t| < the futility bound), "continue",
    "decide at the final look" or "no look yet"."""
    from scipy.stats import skew

    x = np.asarray(x, float)
    looks = [(n, c) for n, c in SEQUENTIAL_LOOKS if len(x) >= n]
    if not looks:
        return {"pairs": len(x), "decision": f"no look yet ({len(x)} of {SEQUENTIAL_LOOKS[0][0]} pairs)"}
    n, c = looks[-1]
    first = n == SEQUENTIAL_LOOKS[0][0]
    d = x[:n]
    se = float(d.std(ddof=1)) / math.sqrt(n)
    m = float(d.mean())
    t = m / se if se > 0 else (math.copysign(math.inf, m) if m else 0.0)
    one_sign = bool(np.all(d > 0) or np.all(d < 0))
    if abs(t) > c and (one_sign or not first):
        decision = "stop: A > B" if t > 0 else "stop: A < B"
    elif first and abs(t) < SEQUENTIAL_FUTILITY:
        decision = "may stop for futility"
    elif first:
        decision = "continue"
    else:
        decision = "inconclusive at the final look"
    return {"pairs": n, "t": t, "critical": c, "rci_low": m - c * se, "rci_high": m + c * se,
            "signflip_p": signflip_p(d), "skewness": float(skew(d)) if se > 0 else 0.0, "decision": decision}
