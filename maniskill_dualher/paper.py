"""The paper (Beyene & Han, Electronics 2022) as data: its numbers, its settings and its claims.

One home for what the paper says, so the report can put it beside ours: Tables 3, 4 and 5, and the
claims (a)-(h) the sweep is built to decide, each as "side A > side B" on one metric. Method names here
are the paper's methods (registered in ``methods.py``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import List, Sequence, Tuple

from maniskill_dualher import protocol
from maniskill_dualher.config import format_ratio
from maniskill_dualher.methods import METHOD_SPECS

PAPER_RATIOS = ((0.5, 0.5), (0.6, 0.4), (0.7, 0.3))   # Table 4
SCRATCH = "from scratch"                              # the chain label of the from-scratch control
PAPER_RATIO = (0.6, 0.4)                                 # the ratio the paper reports as best
PAPER_TABLE4 = {(0.6, 0.4): "250", (0.5, 0.5): "154", (0.7, 0.3): "<75"}   # successful CloseMicrowave attempts
PAPER_TABLE5 = {"sac_her_per": "<45", "dual_buffer": "250"}                # same metric, ours at 0.6/0.4
PAPER_TARGET = "CloseMicrowave-v1"
PAPER_ADAPT_BUDGET = "120 epochs x 200 episodes x 150 steps = 3.6M env steps"
PAPER_ADAPT_STEPS = 120 * 200 * 150
PAPER_TABLE3 = [  # (hyperparameter, paper value, how to read ours from a RunConfig)
    ("learning rate", "0.0001", lambda c: c.sac.lr),
    ("replay memory size", "10^7", lambda c: c.replay.capacity),
    ("batch size", "256", lambda c: c.sac.batch_size),
    ("discount factor", "0.99", lambda c: c.sac.gamma),
    ("SAC entropy temperature alpha", "0.005 (fixed)",
     lambda c: f"{c.sac.alpha} ({'learned' if c.sac.resolved_learn_alpha() else 'fixed'})"),
    ("max steps per episode", "150", lambda c: c.max_episode_steps if c.max_episode_steps else "task default"),
    ("PER prioritization exponent (paper's beta)", "0.5", lambda c: c.replay.priority_exponent),
    ("HER goals per transition k", "4 single-task, 8 multi-task", lambda c: c.replay.her_k),
    ("HER goal strategy", "k random states of the episode (Alg. 1)", lambda c: c.replay.her_strategy),
    ("random-action steps", "100000", lambda c: c.sac.random_steps),
    ("env steps per run", "ReachTarget 500, CloseBox/CloseMicrowave 200, adaptation 120 epochs x 30000",
     lambda c: f"{c.env_id}: {c.total_steps}"),
    ("dual buffer sampling ratio P(R)/P(E)", "0.6/0.4 (best of Table 4)",
     lambda c: METHOD_SPECS[c.method].tag(c) or None if c.method in METHOD_SPECS else None),
    ("importance-sampling weights", "not used", lambda c: c.replay.is_weights),
    ("SAC variant", "twin Q + V with target V (Fig. 1)", lambda c: c.sac.variant),
    ("hidden layers", "not stated", lambda c: "x".join(map(str, c.sac.hidden))),
    ("gradient update schedule", "one update per episode (Alg. 1)",
     lambda c: f"{c.sac.updates_per_step:g} per env step" if c.sac.update_schedule == "step"
     else f"{c.sac.updates_per_episode:g} per episode"),
    ("episode ends on success", "yes (section 4.1)", lambda c: c.terminate_on_success),
    ("target network smoothing tau", "not stated", lambda c: c.sac.tau),
    ("dual buffer: what enters E", "real reward-1 transitions (Alg. 1)",
     lambda c: c.replay.success_buffer if c.method in METHOD_SPECS and METHOD_SPECS[c.method].sampling_ratio
     else None),
    ("evaluation", "every 300 steps", lambda c: f"every {c.eval_every} steps x {c.eval_episodes} episodes"),
]

@dataclass
class Claim:
    key: str
    text: str            # "A > B on ..." in the paper's direction
    paper: str           # what the paper reports
    metric: str          # a METRICS key
    side_a: Tuple[str, ...]  # group selector: (kind, task, chain, method, ratio)
    side_b: Tuple[str, ...]
    relative_margin: bool = False  # margin = 10% of the larger mean (counts) instead of an absolute 0.1


def paper_claims(target: str = PAPER_TARGET, tasks: Sequence[str] = protocol.TASKS) -> List[Claim]:
    """The paper's claims (a)-(h), each as side A > side B on one metric."""
    chain = " > ".join(protocol.TRANSFER_ORDER)
    r = format_ratio(PAPER_RATIO)
    dual = ("adaptation", target, chain, "dual_buffer", r)
    her = ("adaptation", target, chain, "sac_her_per", "")
    out = [
        Claim("a", f"dual_buffer > sac_her_per: successful {target} adaptation episodes",
              "Table 5: 250 vs <45", "successful_train_episodes", dual, her, relative_margin=True),
        Claim("b", f"dual_buffer > sac_her_per: {target} adaptation evaluation return (mean over the curve)",
              "Fig. 5: dual buffer's curve above", "mean_eval_return", dual, her),
        Claim("c", f"ratio 0.6/0.4 > 0.5/0.5: successful {target} adaptation episodes", "Table 4: 250 vs 154",
              "successful_train_episodes", dual, dual[:4] + ("0.5/0.5",), relative_margin=True),
        Claim("d", f"ratio 0.5/0.5 > 0.7/0.3: successful {target} adaptation episodes", "Table 4: 154 vs <75",
              "successful_train_episodes", dual[:4] + ("0.5/0.5",), dual[:4] + ("0.7/0.3",), relative_margin=True),
    ]
    for key, task in zip("efg", tasks):
        out.append(Claim(key, f"dual_buffer > sac: {task} single-task evaluation return (mean over the curve)",
                         "Fig. 4: dual buffer's curve above SAC's", "mean_eval_return",
                         ("single", task, "", "dual_buffer", r), ("single", task, "", "sac", "")))
    out.append(Claim("h", f"transfer > from scratch: dual_buffer's successful {target} episodes in the adaptation "
                          "budget", "assumed (section 3.1), never tested", "successful_train_episodes",
                     dual, ("adaptation", target, SCRATCH, "dual_buffer", r), relative_margin=True))
    out.append(Claim("h'", f"transfer > from scratch: sac_her_per's successful {target} episodes in the adaptation "
                           "budget", "not in the paper", "successful_train_episodes",
                     her, ("adaptation", target, SCRATCH, "sac_her_per", ""), relative_margin=True))
    return out


