"""The learner's diagnostics per arm: alpha, policy entropy, mean Q and |TD| on the batches it trained on,
from R and from E, averaged over each arm's runs (``diag_*`` scores; runs made before ``diagnostics.csv``
existed have none). The mechanism ablations read them: what an E batch (terminal reward-1 states only) does to
the critics, the actor and alpha, beside what an R batch does."""
from __future__ import annotations

import math
from typing import Dict, List, Sequence, Tuple

import numpy as np

from .runs import DIAG_SOURCES, DIAG_STATS

KEYS = ("experiment", "arm", "method", "task", "role")
DIAG_METRICS = tuple(f"diag_{src}_{stat}" for src in DIAG_SOURCES for stat in DIAG_STATS)
COLUMNS = list(KEYS) + ["n"] + list(DIAG_METRICS)


def diagnostic_rows(scores: Sequence[Dict[str, str]]) -> List[Dict[str, str]]:
    """One row per (experiment, arm, method, task, role) with diagnostics: each metric's mean over its runs."""
    groups: Dict[Tuple[str, ...], Dict[str, Dict[str, float]]] = {}
    for r in scores:
        if r["metric"] in DIAG_METRICS:
            groups.setdefault(tuple(r[k] for k in KEYS), {}).setdefault(r["metric"], {})[r["run"]] = float(r["value"])
    out = []
    for key, metrics in sorted(groups.items()):
        runs = {run for per_run in metrics.values() for run in per_run}
        row = dict(zip(KEYS, key), n=str(len(runs)))
        for m in DIAG_METRICS:
            v = list(metrics.get(m, {}).values())
            row[m] = f"{float(np.mean(v)):.4g}" if v and not math.isnan(float(np.mean(v))) else ""
        out.append(row)
    return out
