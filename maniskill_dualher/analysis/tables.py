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
from ..experiment import registry
from ..methods import METHOD_SPECS
from .paper import PAPER_TABLE4, PAPER_TABLE5, PAPER_TARGET
from .stats import mean_ci, rate_ci  # noqa: F401  (the intervals; evaluate.py reads mean_ci here too)

TABLE_COLUMNS = ["experiment", "arm", "task", "chain", "method", "variant", "role", "metric", "n_seeds", "seeds",
                 "mean", "std", "ci95_low", "ci95_high", "paper"]
ADAPT_METRICS = ["successful_train_episodes", "final_eval_success_rate", "mean_eval_success_rate",
                 "train_success_rate", "steps_to_10_successes", "step0_eval_success_rate",
                 "dip_depth", "dip_length"]
SINGLE_METRICS = ["final_eval_success_rate", "mean_eval_success_rate", "successful_train_episodes",
                  "steps_to_10_successes"]
GROUP_KEYS = ("experiment", "arm", "task", "chain", "method", "variant", "role")


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


def feeds(table: str):
    """A row's test: its cell (experiment, arm) feeds ``table`` (``registry.feeds_of``: declared, not inferred)."""
    cells = set(registry.arms_feeding(table))
    return lambda r: (r["experiment"], r["arm"]) in cells


def paper_number(key: tuple, metric: str) -> str:
    """The paper's number beside a row of its chain and target: Table 4 for an experiment feeding
    table4_sampling_ratio.csv, Table 5 for a chain experiment feeding table5_multitask.csv."""
    exp, arm, task, chain, method, variant, role = key
    if task != PAPER_TARGET or chain != registry.chain_name(registry.PAPER_CHAIN) or metric != "successful_train_episodes" or role != "adapt":
        return ""
    fed = registry.feeds_of(exp, arm)
    if registry.TABLE4_CSV in fed:
        return next((v for r, v in PAPER_TABLE4.items() if format_ratio(r) == variant), "")
    if registry.TABLE5_CSV in fed and registry.EXPERIMENTS[exp].kind == "chain":
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


# each table: its rows' role and metrics; which experiments and arms it holds is theirs to declare (feeds)
TABLES = {
    registry.TABLE5_CSV: ("adapt", ADAPT_METRICS),
    registry.TABLE4_CSV: ("adapt", ["successful_train_episodes"]),
    registry.SINGLE_TASK_CSV: ("single", SINGLE_METRICS),
    registry.ABLATIONS_CSV: ("adapt", ADAPT_METRICS),
}


def build_tables(scores: Sequence[Dict[str, str]]) -> Dict[str, List[dict]]:
    out = {}
    for name, (role, metrics) in TABLES.items():
        fed = feeds(name)
        out[name] = table(scores, metrics, lambda r, role=role, fed=fed: r["role"] == role and fed(r))
    return out
