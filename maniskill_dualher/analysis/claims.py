"""Claims as data: the paper's (a)-(h) and our ablations' questions, each "side A > side B" on one metric.

A side names its cell explicitly: experiment, arm, method, task and role (``runs.CELL_KEYS``); its values
are one score per seed from ``scores.csv``. ``claim_rows`` decides each claim with ``stats.compare``.

Add a claim: one ``Claim(...)`` in ``CLAIMS``; it is "not measured" until a sweep runs both sides.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..config import TASKS
from . import stats
from .paper import PAPER_TARGET

RATE_MARGIN = 0.1      # success rates and sparse returns per episode (in [0, 1]): 10 percentage points
COUNT_MARGIN = 0.1     # counts and env steps: 10% of the larger side's mean


@dataclass(frozen=True)
class Side:
    experiment: str
    arm: str
    method: str
    task: str = PAPER_TARGET
    role: str = "adapt"            # "adapt" (a chain's last stage, or scratch), "source" or "single"

    def label(self) -> str:
        return f"{self.method} {self.experiment}/{self.arm}"


@dataclass(frozen=True)
class Claim:
    key: str
    text: str                      # "A > B on ...": the paper's direction, or the ablation's question
    paper: str                     # what the paper reports ("" for our ablations)
    metric: str                    # a runs.METRICS key
    a: Side
    b: Side
    relative_margin: bool = False  # margin = 10% of the larger mean (counts) instead of an absolute 0.1
    group: str = "paper"           # "paper" or "ablation"
    explains: str = ""             # ablations: what this claim tells about the dual buffer's gap (summary.md)
    paper_ratio: Optional[float] = None  # the A/B the paper reports (a lower bound for "< x"): stats' size test


def _t(method: str, arm: str = "paper", experiment: str = "transfer") -> Side:
    return Side(experiment, arm, method)


DUAL, HER = "dual_buffer", "sac_her_per"
N = "successful_train_episodes"
R = "mean_eval_return"
S = "mean_eval_success_rate"

CLAIMS: List[Claim] = [
    # ------------------------------------------------------------------ the paper's claims
    Claim("a", f"dual_buffer > sac_her_per: successful {PAPER_TARGET} adaptation episodes", "Table 5: 250 vs <45",
          N, _t(DUAL), _t(HER), relative_margin=True, paper_ratio=250 / 45),
    Claim("b", f"dual_buffer > sac_her_per: {PAPER_TARGET} adaptation evaluation return (mean over the curve)",
          "Fig. 5: dual buffer's curve above", R, _t(DUAL), _t(HER)),
    Claim("c", f"ratio 0.6/0.4 > 0.5/0.5: successful {PAPER_TARGET} adaptation episodes", "Table 4: 250 vs 154",
          N, Side("ratios", "0.6/0.4", DUAL), Side("ratios", "0.5/0.5", DUAL), relative_margin=True,
          paper_ratio=250 / 154),
    Claim("d", f"ratio 0.5/0.5 > 0.7/0.3: successful {PAPER_TARGET} adaptation episodes", "Table 4: 154 vs <75",
          N, Side("ratios", "0.5/0.5", DUAL), Side("ratios", "0.7/0.3", DUAL), relative_margin=True,
          paper_ratio=154 / 75),
    *[Claim(key, f"dual_buffer > sac: {task} single-task evaluation return (mean over the curve)",
            "Fig. 4: dual buffer's curve above SAC's", R, Side("single", "paper", DUAL, task, "single"),
            Side("single", "paper", "sac", task, "single"))
      for key, task in (("e", "ReachTarget-v1"), ("f", "CloseBox-v1"), ("g", "CloseMicrowave-v1")) if task in TASKS],
    Claim("h", f"transfer > from scratch: dual_buffer's successful {PAPER_TARGET} episodes in the adaptation budget",
          "assumed (section 3.1), never tested", N, _t(DUAL), Side("scratch", "paper", DUAL), relative_margin=True),
    Claim("h'", f"transfer > from scratch: sac_her_per's successful {PAPER_TARGET} episodes in the adaptation "
                "budget", "not in the paper", N, _t(HER), Side("scratch", "paper", HER), relative_margin=True),
    # ------------------------------------------------------------------ why the dual buffer loses (ablations)
    Claim("prior", "the priors differ: sac_her_per's prior > dual_buffer's, evaluated on the target before "
                   "adaptation (zero-shot)", "", "step0_eval_success_rate", _t(HER), _t(DUAL), group="ablation",
          explains="the priors: SAC+HER+PER's prior minus the dual buffer's, zero-shot success on the target, is"),
    Claim("e_off", "same prior, E off in adaptation (ratio 1/0) > the paper's dual buffer (0.6/0.4): successful "
                   "episodes", "", N, Side("e_share", "e_off", DUAL), _t(DUAL), relative_margin=True,
          group="ablation", explains="E's share of the updates, same prior: switching E off in adaptation changes "
                                     "the dual buffer's count by"),
    Claim("e_off_vs_her", "the dual buffer's prior with E off > sac_her_per: successful episodes (what is left "
                          "of the gap without E)", "", N, Side("e_share", "e_off", DUAL), _t(HER),
          relative_margin=True, group="ablation", explains="what is left without E (the dual buffer's prior and "
                                                            "source-stage training): E off minus SAC+HER+PER is"),
    Claim("shared_a", "with one shared prior (SAC+HER+PER's networks and R), dual_buffer > sac_her_per: "
                      "successful episodes (claim a with the prior held fixed)", "", N,
          Side("shared_prior", "shared", DUAL), Side("shared_prior", "shared", HER), relative_margin=True,
          group="ablation", explains="claim (a) with the prior held fixed (both adapt from SAC+HER+PER's prior): "
                                     "dual buffer minus SAC+HER+PER is"),
    Claim("shared_prior", "SAC+HER+PER's prior > the dual buffer's own, for the dual buffer's adaptation: "
                          "successful episodes", "", N, Side("shared_prior", "shared", DUAL), _t(DUAL),
          relative_margin=True, group="ablation",
          explains="the prior's share of the gap: the dual buffer adapting from SAC+HER+PER's prior instead of its "
                   "own changes its count by"),
    Claim("split", "E's share inside every batch (split) > whole batches from E (choose, Alg. 1): successful "
                   "episodes", "", N, Side("e_share", "split", DUAL), _t(DUAL), relative_margin=True,
          group="ablation", explains="how E is mixed in: E's 40% inside every batch instead of whole batches "
                                     "changes the count by"),
    Claim("r_matched", "as many R updates as sac_her_per (1/0.6 updates per step) > the paper's dual buffer: "
                       "successful episodes", "", N, Side("e_share", "r_matched", DUAL), _t(DUAL),
          relative_margin=True, group="ablation",
          explains="E's share as missing R updates: 1/0.6 updates per env step (as many from R as SAC+HER+PER) "
                   "changes the dual buffer's count by"),
    Claim("e_target", "E holding only target-task successes > E carried from the source tasks: successful "
                      "episodes", "", N, Side("e_content", "e_target_only", DUAL), _t(DUAL), relative_margin=True,
          group="ablation", explains="what E holds: E with only the target task's successes (not carried from the "
                                     "source tasks) changes the count by"),
    Claim("e_episodes", "E of whole successful episodes (section 4.2) > E of reward-1 transitions (Alg. 1): "
                        "successful episodes", "", N, Side("e_content", "e_episodes", DUAL), _t(DUAL),
          relative_margin=True, group="ablation", explains="what E holds: E of whole successful episodes instead "
                                                            "of reward-1 transitions changes the count by"),
    Claim("warm_dual", "warm start (no random steps) > the paper's adaptation, dual_buffer: mean evaluation "
                       "success", "", S, Side("warm_start", "warm", DUAL), _t(DUAL), group="ablation",
          explains="fine-tuning collapse, dual buffer: a warm start changes mean evaluation success by"),
    Claim("warm_her", "warm start > the paper's adaptation, sac_her_per: mean evaluation success", "", S,
          Side("warm_start", "warm", HER), _t(HER), group="ablation",
          explains="fine-tuning collapse, SAC+HER+PER: a warm start changes mean evaluation success by"),
    Claim("warm_a", "with a warm start, dual_buffer > sac_her_per: successful episodes (claim a without the "
                    "collapse)", "", N, Side("warm_start", "warm", DUAL), Side("warm_start", "warm", HER),
          relative_margin=True, group="ablation", explains="claim (a) without the collapse (both warm): dual "
                                                            "buffer minus SAC+HER+PER is"),
    Claim("warm_h", "with a warm start, transfer > from scratch, dual_buffer: successful episodes (claim h "
                    "without the collapse)", "", N, Side("warm_start", "warm", DUAL), Side("scratch", "paper", DUAL),
          relative_margin=True, group="ablation"),
    Claim("warm_h'", "with a warm start, transfer > from scratch, sac_her_per: successful episodes", "", N,
          Side("warm_start", "warm", HER), Side("scratch", "paper", HER), relative_margin=True, group="ablation"),
    Claim("her_episode_a", "with Algorithm 1's HER ('episode') in every stage, dual_buffer > sac_her_per: "
                           "successful episodes", "", N, Side("her_episode", "her_episode", DUAL),
          Side("her_episode", "her_episode", HER), relative_margin=True, group="ablation",
          explains="claim (a) with Algorithm 1's HER in every stage: dual buffer minus SAC+HER+PER is"),
    Claim("long_a", "with a 4x adaptation budget, dual_buffer > sac_her_per: successful episodes", "", N,
          Side("regime", "long", DUAL), Side("regime", "long", HER), relative_margin=True, group="ablation",
          explains="claim (a) with 4x the adaptation budget: dual buffer minus SAC+HER+PER is"),
    Claim("long_episode_a", "with a 4x adaptation budget and one update per episode (Algorithm 1), dual_buffer > "
                            "sac_her_per: successful episodes", "", N, Side("regime", "long_episode", DUAL),
          Side("regime", "long_episode", HER), relative_margin=True, group="ablation",
          explains="claim (a) in Algorithm 1's regime (4x budget, one update per episode: scarce updates): dual "
                   "buffer minus SAC+HER+PER is"),
    Claim("warm_low_lr_a", "with a warm start at lr 3e-4, dual_buffer > sac_her_per: successful episodes", "", N,
          Side("warm_start", "warm_low_lr", DUAL), Side("warm_start", "warm_low_lr", HER), relative_margin=True,
          group="ablation", explains="claim (a) with a warm start at a lower learning rate: dual buffer minus "
                                     "SAC+HER+PER is"),
]

CLAIM_COLUMNS = ["claim", "group", "statement", "paper", "metric", "side_a", "side_b", "n_a", "n_b", "mean_a",
                 "mean_b", "diff", "diff_ci95_low", "diff_ci95_high", "welch_ci95_low", "welch_ci95_high",
                 "prob_improvement", "margin", "verdict", "seeds_to_decide", "paired", "paper_ratio",
                 "a_minus_paper_ratio_b_ci95_high", "machines"]


def _in_arm(r: Dict[str, str], side: Side) -> bool:
    return r["experiment"] == side.experiment and r["arm"] == side.arm and r["method"] == side.method


def _side_rows(scores: Sequence[Dict[str, str]], side: Side, metric: str) -> Dict[int, Dict[str, str]]:
    by_seed: Dict[int, Dict[str, str]] = {}
    for r in scores:
        if r["metric"] == metric and _in_arm(r, side) and r["task"] == side.task and r["role"] == side.role:
            by_seed.setdefault(int(r["seed"]), r)
    return by_seed


def side_values(scores: Sequence[Dict[str, str]], side: Side, metric: str) -> List[float]:
    """One value per seed (ascending seed) of a side's cell and metric."""
    by_seed = _side_rows(scores, side, metric)
    return [float(by_seed[s]["value"]) for s in sorted(by_seed)]


def side_machines(scores: Sequence[Dict[str, str]], c: Claim) -> str:
    """The CPUs both sides' runs ran on ("; "-joined, sorted)."""
    rows = list(_side_rows(scores, c.a, c.metric).values()) + list(_side_rows(scores, c.b, c.metric).values())
    return "; ".join(sorted({r.get("machine") or "unknown" for r in rows})) if rows else ""


def _source_runs(scores: Sequence[Dict[str, str]], side: Side) -> Dict[int, Tuple[str, ...]]:
    """Per seed, the run folders of the side's source stages (its prior); empty for single-task or scratch."""
    runs: Dict[int, set] = {}
    for r in scores:
        if r["role"] == "source" and _in_arm(r, side):
            runs.setdefault(int(r["seed"]), set()).add(r["run"])
    return {s: tuple(sorted(v)) for s, v in runs.items()}


def paired(scores: Sequence[Dict[str, str]], c: Claim) -> bool:
    """Both sides adapted the very same prior for every seed: the same seeds, each with the same source-stage
    run folders (one sweep trained it once for both). Decided from the data, never from the outcome."""
    seeds_a, seeds_b = set(_side_rows(scores, c.a, c.metric)), set(_side_rows(scores, c.b, c.metric))
    src_a, src_b = _source_runs(scores, c.a), _source_runs(scores, c.b)
    return (bool(seeds_a) and seeds_a == seeds_b
            and all(src_a.get(s) and src_a.get(s) == src_b.get(s) for s in seeds_a))


def claim_rows(scores: Sequence[Dict[str, str]], resamples: int = 10_000,
               claims: Optional[Sequence[Claim]] = None) -> List[dict]:
    rows = []
    for c in CLAIMS if claims is None else claims:
        a, b = side_values(scores, c.a, c.metric), side_values(scores, c.b, c.metric)
        row = {"claim": c.key, "group": c.group, "statement": c.text, "paper": c.paper, "metric": c.metric,
               "side_a": c.a.label(), "side_b": c.b.label()}
        if not a or not b:
            rows.append({**row, "verdict": "not measured (runs missing)"})
            continue
        margin = COUNT_MARGIN * max(abs(np.mean(a)), abs(np.mean(b)), 1.0) if c.relative_margin else RATE_MARGIN
        pair = paired(scores, c)
        cmp = stats.compare(a, b, margin, resamples, paired=pair, paper_ratio=c.paper_ratio)
        rows.append({**row, "n_a": cmp.n_a, "n_b": cmp.n_b, "mean_a": cmp.mean_a, "mean_b": cmp.mean_b,
                     "diff": cmp.diff, "diff_ci95_low": cmp.ci_low, "diff_ci95_high": cmp.ci_high,
                     "welch_ci95_low": getattr(cmp, "welch_low", math.nan),
                     "welch_ci95_high": getattr(cmp, "welch_high", math.nan),
                     "prob_improvement": cmp.prob_improvement, "margin": margin,
                     # our own questions are not reproductions: their "A > B" is "supported"
                     "verdict": cmp.verdict_text().replace(stats.REPRODUCED, "supported")
                     if c.group != "paper" else cmp.verdict_text(),
                     "seeds_to_decide": cmp.seeds_to_decide, "paired": "yes" if pair else "no",
                     "paper_ratio": c.paper_ratio if c.paper_ratio is not None else "",
                     "a_minus_paper_ratio_b_ci95_high": cmp.vs_paper_high if c.paper_ratio is not None else "",
                     "machines": side_machines(scores, c)})
    return rows


def explains(key: str) -> str:
    return next((c.explains for c in CLAIMS if c.key == key), "")
