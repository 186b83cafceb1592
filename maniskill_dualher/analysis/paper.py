"""The paper (Beyene & Han, Electronics 2022) as data: its numbers, its settings and its claims.

One home for what the paper says, so the report can put it beside ours: Tables 3, 4 and 5 and its
settings. Its claims (a)-(h), with our ablations, are in ``claims.py``. Method names here are the paper's
methods (registered in ``methods.py``).
"""
from __future__ import annotations

from maniskill_dualher.experiment import registry
from maniskill_dualher.methods import METHOD_SPECS

PAPER_TABLE4 = {(0.6, 0.4): "250", (0.5, 0.5): "154", (0.7, 0.3): "<75"}   # successful CloseMicrowave attempts
PAPER_TABLE5 = {"sac_her_per": "<45", "dual_buffer": "250"}                # same metric, ours at 0.6/0.4
PAPER_TARGET = registry.PAPER_TARGET                  # CloseMicrowave (the chain is experiment data: registry)
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
