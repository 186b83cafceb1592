"""Tables from per-seed scores: one row per cell (experiment, arm, task, chain, method, variant, role) and
metric, with n, seeds, mean, std and a 95% interval of the mean; the paper's number beside ours.

The interval is Student's t for counts and steps, and a percentile bootstrap over seeds for rates (metrics
ending in ``_rate``), which stays in [0, 1]. The evaluation return is not tabled: with a sparse reward and
episodes that end on success it equals the evaluation success rate (``scores.csv`` still holds it)."""
from __future__ import annotations

import math
from collections import defaultdict
from typing import Dict, List, Sequence, Tuple

import numpy as np

from ..config import TASKS, format_ratio
from ..experiment.registry import EXPERIMENTS, KINDS
from ..methods import METHOD_SPECS
from .paper import PAPER_CHAIN, PAPER_TABLE4, PAPER_TABLE5, PAPER_TARGET

TABLE_COLUMNS = ["experiment", "arm", "task", "chain", "method", "variant", "role", "metric", "n_seeds", "seeds",
                 "mean", "std", "ci95_low", "ci95_high", "paper"]
ADAPT_METRICS = ["successful_train_episodes", "final_eval_success_rate", "mean_eval_success_rate",
                 "train_success_rate", "steps_to_10_successes", "step0_eval_success_rate",
                 "dip_depth", "dip_length"]
SINGLE_METRICS = ["final_eval_success_rate", "mean_eval_success_rate", "successful_train_episodes",
                  "steps_to_10_successes"]
GROUP_KEYS = ("experiment", "arm", "task", "chain", "method", "variant", "role")


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


def _order(key: tuple) -> tuple:
    exp, arm, task, chain, method, variant, role = key
    names = list(METHOD_SPECS)
    return (TASKS.index(task) if task in TASKS else len(TASKS), exp, arm, chain,
            names.index(method) if method in names else len(names), variant, role)


def groups(scores: Sequence[Dict[str, str]], metric: str, where) -> Dict[tuple, Dict[int, float]]:
    out: Dict[tuple, Dict[int, float]] = defaultdict(dict)
    for r in scores:
        if r["metric"] == metric and where(r):
            out[tuple(r[k] for k in GROUP_KEYS)].setdefault(int(r["seed"]), float(r["value"]))
    return dict(sorted(out.items(), key=lambda kv: _order(kv[0])))


_SINGLE, _CHAIN, _SCRATCH = KINDS


def _paper_experiments(kind: str, many_arms: bool):
    """The registry's default experiments of one kind, with one arm (transfer) or several (the ratio study)."""
    return tuple(n for n, e in EXPERIMENTS.items() if e.default and e.kind == kind and (len(e.arms) > 1) == many_arms)


def paper_number(key: tuple, metric: str) -> str:
    exp, arm, task, chain, method, variant, role = key
    if task != PAPER_TARGET or chain != PAPER_CHAIN or metric != "successful_train_episodes" or role != "adapt":
        return ""
    if exp in _paper_experiments(_CHAIN, many_arms=True):
        return next((v for r, v in PAPER_TABLE4.items() if format_ratio(r) == variant), "")
    if exp in _paper_experiments(_CHAIN, many_arms=False):
        return PAPER_TABLE5.get(method, "")
    return ""


def table(scores, metrics: Sequence[str], where) -> List[dict]:
    rows = []
    for metric in metrics:
        for key, by_seed in groups(scores, metric, where).items():
            vals = [by_seed[s] for s in sorted(by_seed)]
            lo, hi = rate_ci(vals) if metric.endswith("_rate") else mean_ci(vals)
            rows.append({**dict(zip(GROUP_KEYS, key)), "metric": metric, "n_seeds": len(vals),
                         "seeds": " ".join(map(str, sorted(by_seed))), "mean": float(np.mean(vals)),
                         "std": float(np.std(vals, ddof=1)) if len(vals) > 1 else math.nan,
                         "ci95_low": lo, "ci95_high": hi, "paper": paper_number(key, metric)})
    rows.sort(key=lambda r: (_order(tuple(r[k] for k in GROUP_KEYS)), metrics.index(r["metric"])))
    return rows


def build_tables(scores: Sequence[Dict[str, str]], default_experiments: Sequence[str]) -> Dict[str, List[dict]]:
    adapt = lambda exps: (lambda r: r["role"] == "adapt" and r["experiment"] in exps)  # noqa: E731
    transfer = _paper_experiments(_CHAIN, many_arms=False) + _paper_experiments(_SCRATCH, many_arms=False)
    return {
        "table5_multitask.csv": table(scores, ADAPT_METRICS, adapt(transfer)),
        "table4_sampling_ratio.csv": table(scores, ["successful_train_episodes"],
                                           adapt(_paper_experiments(_CHAIN, many_arms=True))),
        "single_task.csv": table(scores, SINGLE_METRICS, lambda r: r["role"] == "single"),
        "ablations.csv": table(scores, ADAPT_METRICS,
                               lambda r: r["role"] == "adapt" and r["experiment"] not in default_experiments),
    }
