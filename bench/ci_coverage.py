"""Coverage of the difference-of-means intervals on skewed data (the table in ``analysis/stats.py``'s module
doc): simulated pairs of samples from skewed distributions, each interval method of ``stats.METHODS``, the
share of intervals that hold the true difference and their median width.

    python bench/ci_coverage.py --reps 2000 --resamples 2000              # unpaired, n = 4, 6, 16
    python bench/ci_coverage.py --paired --reps 1000 --resamples 1000 --n 6 16 32
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Callable, Dict, Sequence, Tuple

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from maniskill_dualher.analysis.stats import BOOT_T, WELCH, _diff_ci  # noqa: E402

# Each entry: (sampler of B's distribution, its mean, sampler of A's distribution in the "diff" case, its mean).
SKEWED: Dict[str, Tuple[Callable, float, Callable, float]] = {
    "lognormal": (lambda r, n: r.lognormal(0.0, 1.0, n), math.exp(0.5),
                  lambda r, n: r.lognormal(0.5, 1.0, n), math.exp(1.0)),
    "exponential": (lambda r, n: r.exponential(1.0, n), 1.0,
                    lambda r, n: r.exponential(2.0, n), 2.0),
    "zero-infl. Poisson": (lambda r, n: (r.random(n) >= 0.3) * r.poisson(5.0, n).astype(float), 0.7 * 5,
                           lambda r, n: (r.random(n) >= 0.3) * r.poisson(8.0, n).astype(float), 0.7 * 8),
    "learned or not /20": (lambda r, n: np.where(r.random(n) < 0.5, r.binomial(20, 0.7, n),
                                                 r.binomial(20, 0.1, n)).astype(float), 0.5 * 14 + 0.5 * 2,
                           lambda r, n: np.where(r.random(n) < 0.7, r.binomial(20, 0.7, n),
                                                 r.binomial(20, 0.1, n)).astype(float), 0.7 * 14 + 0.3 * 2),
}



def coverage(dist: str, n: int, methods: Sequence[str], reps: int, resamples: int, shift: bool = False,
             seed: int = 0, paired: bool = False) -> Dict[str, Tuple[float, float]]:
    """{method: (coverage of the true mean difference, median width)} over ``reps`` simulated pairs.
    ``paired``: seed s of both sides shares a prior term (3x a draw of B's distribution) and the interval is
    taken on the per-seed differences, as ``compare(paired=True)`` does."""
    gen_b, mu_b, gen_a, mu_a = SKEWED[dist]
    if not shift:
        gen_a, mu_a = gen_b, mu_b
    rng = np.random.default_rng(seed)
    pairs = [(gen_a(rng, n), gen_b(rng, n)) for _ in range(reps)]
    if paired:
        pairs = [(a - b, np.zeros(n)) for a, b in ((a + c, b + c) for (a, b), c in
                                                    zip(pairs, (3 * gen_b(rng, n) for _ in range(reps))))]
    out = {}
    for m in methods:
        cis = np.array([_diff_ci(a, b, resamples, i, 0.95, m)[:2] for i, (a, b) in enumerate(pairs)])
        out[m] = (float(np.mean((cis[:, 0] <= mu_a - mu_b) & (mu_a - mu_b <= cis[:, 1]))),
                  float(np.median(cis[:, 1] - cis[:, 0])))
    return out


def _main(argv=None) -> None:
    p = argparse.ArgumentParser(description="Coverage of the difference-of-means CIs on skewed data.")
    p.add_argument("--reps", type=int, default=2000)
    p.add_argument("--resamples", type=int, default=2000)
    p.add_argument("--n", type=int, nargs="+", default=[4, 6, 16])
    p.add_argument("--methods", nargs="+", default=["percentile", "BCa", WELCH, "bootstrap-t", BOOT_T])
    p.add_argument("--paired", action="store_true", help="both sides share each seed's prior (module doc)")
    args = p.parse_args(argv)
    short = {"percentile": "pct", "BCa": "BCa", WELCH: "welch", "bootstrap-t": "boot-t", BOOT_T: "sym boot-t"}
    print(f"{'case':<5} {'data':<19} {'n':>3}  " + " ".join(f"{short.get(m, m):>10}" for m in args.methods)
          + "  | median width / Welch's")
    for shift in (False, True):
        for dist in SKEWED:
            for n in args.n:
                res = coverage(dist, n, args.methods, args.reps, args.resamples, shift, paired=args.paired)
                w_welch = res[WELCH][1] if WELCH in res else math.nan
                print(f"{'diff' if shift else 'null':<5} {dist:<19} {n:>3}  "
                      + " ".join(f"{res[m][0]:>10.3f}" for m in args.methods)
                      + "  | " + " ".join(f"{res[m][1] / w_welch:.2f}" for m in args.methods), flush=True)


if __name__ == "__main__":
    _main()
