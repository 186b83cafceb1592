"""Statistics that decide a claim: a 95% bootstrap CI on the *difference* between two sides, and a verdict.

A claim says side A beats side B (the paper's direction). Each side is one score per seed (independent
runs; seeds are not paired across methods). The difference of means A - B gets a 95% percentile
bootstrap CI from ``scipy.stats.bootstrap`` resampling each side within itself (rliable's "stratified"
bootstrap with one stratum per side), seeded so tables are reproducible. The probability of
improvement P(A > B) (+ half the ties) is the Mann-Whitney U statistic over n_A n_B, as in rliable.

Verdicts:

* **reproduced**: the CI excludes 0 in the paper's direction;
* **contradicted**: the CI excludes 0 the other way;
* **no difference larger than X**: the CI lies within +-X, where X is the claim's stated margin of
  practical equivalence;
* **inconclusive**: none of these; we also say how many seeds per side would likely decide it, from the
  observed spread (normal approximation: the n at which the CI half-width would clear 0 at the observed
  difference, or fit inside +-X, whichever comes first).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

REPRODUCED = "reproduced"
CONTRADICTED = "contradicted"
EQUIVALENT = "no difference larger than"
INCONCLUSIVE = "inconclusive"
MIN_SEEDS = 3            # fewer per side: no CI is computed (a bootstrap of 2 values is just their range)
MAX_SEEDS_ADVICE = 1000  # above this, "more seeds" is no advice


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
    seeds_to_decide: Optional[int]   # per side, for an inconclusive verdict

    def verdict_text(self) -> str:
        if self.verdict == EQUIVALENT:
            return f"{EQUIVALENT} {self.margin:.3g}"
        if self.verdict == INCONCLUSIVE:
            if self.n_a < MIN_SEEDS or self.n_b < MIN_SEEDS:
                return f"{INCONCLUSIVE} (needs >= {MIN_SEEDS} seeds per side)"
            more = f"~{self.seeds_to_decide} seeds per side would likely decide it" \
                if self.seeds_to_decide is not None else "more seeds would not decide it at this spread"
            return f"{INCONCLUSIVE} ({more})"
        return self.verdict


def diff_ci(a: Sequence[float], b: Sequence[float], resamples: int = 10_000, seed: int = 0):
    """95% percentile bootstrap CI of mean(a) - mean(b), each side resampled within itself."""
    from scipy.stats import bootstrap

    a, b = np.asarray(a, float), np.asarray(b, float)
    if np.ptp(a) == 0 and np.ptp(b) == 0:  # every resample gives the same difference
        d = float(a.mean() - b.mean())
        return d, d
    import inspect
    seeded = {"rng" if "rng" in inspect.signature(bootstrap).parameters else "random_state":
              np.random.default_rng(seed)}  # scipy >= 1.15 names it rng
    res = bootstrap((a, b), lambda x, y, axis: x.mean(axis) - y.mean(axis), vectorized=True, paired=False,
                    n_resamples=resamples, confidence_level=0.95, method="percentile", **seeded)
    return float(res.confidence_interval.low), float(res.confidence_interval.high)


def prob_improvement(a: Sequence[float], b: Sequence[float]) -> float:
    """P(A > B) + 0.5 P(A = B) over all pairs of runs (rliable's probability of improvement)."""
    a, b = np.asarray(a, float)[:, None], np.asarray(b, float)[None, :]
    return float(((a > b) + 0.5 * (a == b)).mean())


def seeds_to_decide(a: np.ndarray, b: np.ndarray, margin: float) -> Optional[int]:
    """Seeds per side at which a normal-approximation 95% CI would likely clear 0 or fit in +-margin."""
    var = a.var(ddof=1) + b.var(ddof=1)
    if var == 0:
        return None
    d = abs(a.mean() - b.mean())
    cands = []
    if d > 0:
        cands.append(1.96 ** 2 * var / d ** 2)            # half-width < |d|: excludes 0
    if margin > d:
        cands.append(1.96 ** 2 * var / (margin - d) ** 2)  # |d| + half-width < margin: equivalent
    if not cands:
        return None
    n = int(math.ceil(min(cands)))
    n = max(n, max(len(a), len(b)) + 1)
    return n if n <= MAX_SEEDS_ADVICE else None


def compare(a: Sequence[float], b: Sequence[float], margin: float, resamples: int = 10_000,
            seed: int = 0) -> Comparison:
    """Does A beat B? The difference A - B with its CI, and one verdict (see the module doc)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if len(a) == 0 or len(b) == 0:
        raise ValueError("compare needs at least one value per side")
    mean_a, mean_b = float(a.mean()), float(b.mean())
    diff = mean_a - mean_b
    if min(len(a), len(b)) < MIN_SEEDS:
        return Comparison(len(a), len(b), mean_a, mean_b, diff, math.nan, math.nan, prob_improvement(a, b),
                          margin, INCONCLUSIVE, None)
    lo, hi = diff_ci(a, b, resamples, seed)
    if lo > 0:
        verdict = REPRODUCED
    elif hi < 0:
        verdict = CONTRADICTED
    elif -margin <= lo and hi <= margin:
        verdict = EQUIVALENT
    else:
        verdict = INCONCLUSIVE
    need = seeds_to_decide(a, b, margin) if verdict == INCONCLUSIVE else None
    return Comparison(len(a), len(b), mean_a, mean_b, diff, lo, hi, prob_improvement(a, b), margin, verdict, need)
