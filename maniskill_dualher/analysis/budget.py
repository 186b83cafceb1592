"""The budget curve: the two methods' adaptation at 1x, 2x, 4x and 8x the adaptation budget, from scores.

At each budget (``budgets()``: the cells that hold it, first one wins per seed) the ratio of mean successful
adaptation episodes, dual buffer / SAC+HER+PER, with its 95% interval (``stats.ratio_ci``, unpaired: the two
methods adapt their own priors), and the difference in final evaluation success with ``stats.compare``'s
interval. A count ratio drifts toward 1 once both policies saturate, so the count alone cannot show the
methods trading places; the final success difference can.

No trend is claimed (issue 39): at the reference's settings both methods solve the task by 4x, so a count
measured at a longer budget measures speed, not success.
"""
from __future__ import annotations

import math
from typing import Dict, List, Sequence, Tuple

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
