"""The budget curve: the two methods' adaptation at 1x, 2x, 4x and 8x the adaptation budget, from scores.

At each budget (``budgets()``: the cells that hold it, first one wins per seed) the ratio of mean successful
adaptation episodes, dual buffer / SAC+HER+PER, with its 95% interval (``stats.ratio_ci``, unpaired: the two
methods adapt their own priors), and the difference in final evaluation success with ``stats.compare``'s
interval. A count ratio drifts toward 1 once both policies saturate, so the count alone cannot show the
methods trading places; the final success difference can.

The trend claim (``trend``): the least-squares slope of log2(ratio) against log2(budget) over every budget
measured with >= MIN_SEEDS seeds per method (>= MIN_BUDGETS budgets), with a 95% percentile interval from a
cluster bootstrap: each method's seeds are resampled with replacement (a seed is a cluster: its runs at
every budget stay together, as budgets may adapt one prior), the slope recomputed on every resample. It
decides whether the dual buffer's count *relative to* SAC+HER+PER's rises with the budget (slope > 0:
supported; < 0: contradicted). It does not decide whether the ratio reaches 1: the per-budget intervals
say that (``order_sentence``).
"""
from __future__ import annotations

import math
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..experiment import registry
from . import stats

DUAL, HER = "dual_buffer", "sac_her_per"
COUNT, FINAL = "successful_train_episodes", "final_eval_success_rate"


def budgets() -> Tuple[Tuple[float, Tuple[Tuple[str, str], ...]], ...]:
    """Budget factor -> the (experiment, arm) cells adapting at it, in registry order (the order of preference
    per seed): every arm that feeds budget.csv (registry ``feeds``), at its ``Arm.adapt_steps_factor``."""
    by_factor: Dict[float, List[Tuple[str, str]]] = {}
    for exp, arm in registry.arms_feeding(registry.BUDGET_CSV):
        by_factor.setdefault(float(registry.EXPERIMENTS[exp].arm(arm).adapt_steps_factor), []).append((exp, arm))
    return tuple((f, tuple(cells)) for f, cells in sorted(by_factor.items()))

MIN_BUDGETS = 3
RATE_MARGIN = 0.1   # final evaluation success: 10 percentage points (claims.RATE_MARGIN)
AHEAD_DUAL, AHEAD_HER, UNDECIDED = "dual_buffer ahead", "sac_her_per ahead", "undecided"
EQUAL = f"equal within {RATE_MARGIN:g}"   # final success: the difference's interval lies within +-RATE_MARGIN
BUDGET_COLUMNS = ["budget_factor", "cells", "n_dual", "n_her", "mean_dual", "mean_her", "ratio", "ratio_ci95_low",
                  "ratio_ci95_high", "final_success_dual", "final_success_her", "final_success_diff",
                  "final_success_diff_ci95_low", "final_success_diff_ci95_high", "count_order", "final_order"]


def budget_values(scores: Sequence[Dict[str, str]], cells: Sequence[Tuple[str, str]], method: str,
                  metric: str) -> Dict[int, float]:
    """seed -> value of the method's adaptation at one budget (the first of ``cells`` with that seed)."""
    out: Dict[int, float] = {}
    for exp, arm in cells:
        for r in scores:
            if (r["experiment"], r["arm"], r["method"], r["metric"], r["role"]) == (exp, arm, method, metric, "adapt"):
                out.setdefault(int(r["seed"]), float(r["value"]))
    return out


def _fmt_factor(f: float) -> str:
    return f"{f:g}x"


def _order(low: float, high: float, one: float) -> str:
    if math.isnan(low):
        return ""
    return AHEAD_DUAL if low > one else AHEAD_HER if high < one else UNDECIDED


def budget_rows(scores: Sequence[Dict[str, str]], resamples: int = 10_000) -> List[dict]:
    """One row per budget at which both methods have an adaptation count."""
    rows = []
    for factor, cells in budgets():
        d, h = budget_values(scores, cells, DUAL, COUNT), budget_values(scores, cells, HER, COUNT)
        if not d or not h:
            continue
        a, b = [d[s] for s in sorted(d)], [h[s] for s in sorted(h)]
        ratio, lo, hi = stats.ratio_ci(a, b, resamples)
        fd, fh = budget_values(scores, cells, DUAL, FINAL), budget_values(scores, cells, HER, FINAL)
        row = {"budget_factor": factor, "cells": " or ".join(f"{e}/{m}" for e, m in cells), "n_dual": len(a),
               "n_her": len(b), "mean_dual": float(np.mean(a)), "mean_her": float(np.mean(b)), "ratio": ratio,
               "ratio_ci95_low": lo, "ratio_ci95_high": hi, "count_order": _order(lo, hi, 1.0)}
        if fd and fh:
            c = stats.compare([fd[s] for s in sorted(fd)], [fh[s] for s in sorted(fh)], RATE_MARGIN, resamples)
            row.update(final_success_dual=c.mean_a, final_success_her=c.mean_b, final_success_diff=c.diff,
                       final_success_diff_ci95_low=c.ci_low, final_success_diff_ci95_high=c.ci_high,
                       final_order=EQUAL if c.verdict == stats.EQUIVALENT else _order(c.ci_low, c.ci_high, 0.0))
        rows.append(row)
    return rows


def _seed_matrix(by_budget: List[Dict[int, float]]) -> np.ndarray:
    seeds = sorted(set().union(*by_budget))
    return np.array([[v.get(s, np.nan) for v in by_budget] for s in seeds])


def _resampled_means(m: np.ndarray, resamples: int, rng) -> np.ndarray:
    """(resamples, budgets) means over seeds drawn with replacement, rows of ``m`` kept whole (NaN: absent)."""
    n = m.shape[0]
    idx = rng.integers(0, n, (resamples, n))
    counts = np.zeros((resamples, n))
    np.add.at(counts, (np.repeat(np.arange(resamples), n), idx.ravel()), 1.0)
    present = ~np.isnan(m)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (counts @ np.where(present, m, 0.0)) / (counts @ present)


def _slope(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Least-squares slope of y (..., budgets) on x (budgets)."""
    xc = x - x.mean()
    return ((y - y.mean(axis=-1, keepdims=True)) * xc).sum(axis=-1) / (xc ** 2).sum()


def trend(scores: Sequence[Dict[str, str]], resamples: int = 10_000, seed: int = 0,
          level: float = 0.95) -> Optional[dict]:
    """The slope of log2(dual/HER count ratio) per doubling of the budget, its percentile interval and
    p-value (2 min(P*(slope <= 0), P*(slope >= 0)), the interval inverted); None below MIN_BUDGETS budgets."""
    used, dual, her = [], [], []
    for factor, cells in budgets():
        d, h = budget_values(scores, cells, DUAL, COUNT), budget_values(scores, cells, HER, COUNT)
        if min(len(d), len(h)) >= stats.MIN_SEEDS:
            used.append(factor)
            dual.append(d)
            her.append(h)
    if len(used) < MIN_BUDGETS:
        return None
    x = np.log2(np.array(used))
    md, mh = _seed_matrix(dual), _seed_matrix(her)
    means_d, means_h = np.nanmean(md, axis=0), np.nanmean(mh, axis=0)
    out = {"budgets": used, "n_dual": int(np.sum(~np.isnan(md))), "n_her": int(np.sum(~np.isnan(mh))),
           "ratio_first": float(means_d[0] / means_h[0]) if means_h[0] > 0 else math.nan,
           "ratio_last": float(means_d[-1] / means_h[-1]) if means_h[-1] > 0 else math.nan}
    if not (np.all(means_d > 0) and np.all(means_h > 0)):
        return {**out, "slope": math.nan, "low": math.nan, "high": math.nan, "p_value": math.nan}
    rng = np.random.default_rng(seed)
    bd, bh = _resampled_means(md, resamples, rng), _resampled_means(mh, resamples, rng)
    with np.errstate(invalid="ignore", divide="ignore"):
        slopes = _slope(x, np.log2(bd / bh))
    slopes = slopes[np.isfinite(slopes)]  # a resample without a seed at some budget, or with a zero mean
    lo, hi = np.quantile(slopes, [(1 - level) / 2, (1 + level) / 2])
    p = min(1.0, 2 * min(float(np.mean(slopes <= 0)), float(np.mean(slopes >= 0))))
    return {**out, "slope": float(_slope(x, np.log2(means_d / means_h))), "low": float(lo), "high": float(hi),
            "p_value": p, "resamples_used": int(slopes.size)}


def order_sentence(rows: Sequence[dict]) -> str:
    """Whether the order of the two methods changes within the budgets measured, on either metric."""
    if not rows:
        return "No budget has both methods' adaptation yet."
    parts = []
    for key, what in (("count_order", "successful adaptation episodes (ratio's 95% interval vs 1)"),
                      ("final_order", "final evaluation success (difference's 95% interval vs 0)")):
        orders = {_fmt_factor(r["budget_factor"]): r.get(key, "") for r in rows if r.get(key)}
        if not orders:
            continue
        seen = set(orders.values())
        at = lambda v: ", ".join(k for k, o in orders.items() if o == v)  # noqa: E731
        if {AHEAD_DUAL, AHEAD_HER} <= seen:
            verdict = "the order changes within the range measured"
        elif UNDECIDED in seen:
            verdict = f"the order is undecided at {at(UNDECIDED)}"
        elif seen == {EQUAL}:
            verdict = "the two are equal at every budget measured"
        else:
            lead = AHEAD_HER if AHEAD_HER in seen else AHEAD_DUAL
            name = "SAC+HER+PER" if lead == AHEAD_HER else "the dual buffer"
            verdict = (f"{name} is ahead at {at(lead)}" + (f" and the two are {EQUAL} at {at(EQUAL)}"
                                                           if EQUAL in seen else "")
                       + ": the order does not change within the range measured")
        parts.append(f"On {what}: {verdict} ({'; '.join(f'{k}: {v}' for k, v in orders.items())}).")
    return " ".join(parts)
