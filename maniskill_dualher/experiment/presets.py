"""Presets as data: per-task step budgets, seeds, and dotted ``RunConfig`` settings.

A preset never has its own knobs: every setting is a ``RunConfig`` key (``experiment/overrides.py``), so
``sweep --set KEY=VALUE`` reaches anything a preset sets and anything it does not. Budgets are keyed by
task id; a task in ``config.TASKS`` that a preset does not name gets the preset's ``default_steps``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple

from ..config import TASKS, RunConfig
from . import overrides

PAPER_EPOCH_STEPS = 200 * 150   # paper: an epoch is 200 episodes of 150 steps (Table 3)
HER_K_SINGLE = 4                # paper 4.2.1
HER_K_MULTITASK = 8             # paper 4.2.2: "k ... was increased from 4 to 8" for transfer


@dataclass
class Preset:
    doc: str
    single_steps: Dict[str, int]              # single-task run, per task (paper Fig. 4)
    stage_steps: Dict[str, int]               # a transfer *source* stage, per task
    adaptation_steps: Dict[str, int]          # the chain's last stage (and scratch), per task
    seeds: Tuple[int, ...]                    # single-task experiments
    chain_seeds: Tuple[int, ...]              # chain and scratch experiments (transfer claims)
    settings: Tuple[str, ...] = ()            # dotted RunConfig overrides, e.g. "sac.lr=1e-3"
    default_steps: Optional[int] = None       # budget of a task the dicts above do not name
    # seeds per arm (``seed_count``'s keys), used when no --seeds/--chain-seeds is given; wins over max_seeds
    arm_seeds: Optional[Dict[str, int]] = None

    def steps(self, role: str, task: str) -> int:
        table = {"single": self.single_steps, "source": self.stage_steps, "adapt": self.adaptation_steps}[role]
        if task in table:
            return int(table[task])
        if self.default_steps is None:
            from ..config import ConfigError
            raise ConfigError(f"preset has no {role} budget for task {task!r}")
        return int(self.default_steps)

    def base_config(self, method: str, seed: int, extra: Tuple[overrides.Override, ...] = ()) -> RunConfig:
        """The preset's RunConfig for one method and seed (before per-experiment settings)."""
        cfg = RunConfig(method=method, seed=seed, torch_threads=1)
        cfg.replay.her_k = HER_K_SINGLE
        return overrides.apply(cfg, overrides.parse_all(self.settings) + tuple(extra))

    def single_config(self, method: str, seed: int, task: str) -> RunConfig:
        """A single-task run of this preset, as the sweep builds it (train --preset, benches, learning tests)."""
        cfg = self.base_config(method, seed)
        cfg.env_id, cfg.total_steps = task, self.steps("single", task)
        return cfg.validate()


def seed_key(table: Dict[str, int], experiment: str, arm: str, method: str, task: str) -> str:
    """The key of a seed table that decides one cell: the most specific one (``experiment:arm:method``,
    then ``experiment:arm:task``, then ``experiment:arm``)."""
    for key in (f"{experiment}:{arm}:{method}", f"{experiment}:{arm}:{task}", f"{experiment}:{arm}"):
        if key in table:
            return key
    from ..config import ConfigError
    raise ConfigError(f"the seed table has no entry for {experiment}:{arm} (add one to presets.REFERENCE_SEEDS)")


def _every_task(n: int, **per_task: int) -> Dict[str, int]:
    out = {t: n for t in TASKS}
    out.update({k.replace("_", "-"): v for k, v in per_task.items()})
    return out


# The quick preset's settings: close to rl-baselines3-zoo's goal-task values (modern SAC with learned alpha, 64x64,
# lr 1e-3, tau 0.05, gamma 0.95, batch 256) where the paper's (V network, fixed alpha 0.005, lr 1e-4,
# gamma 0.99) had 0/10 eval successes on ReachTarget at 20k env steps; 100-step episodes ending on success.
QUICK_SETTINGS = (
    "max_episode_steps=100", "eval_every=1000", "eval_episodes=10", "checkpoint_every=5000",
    "sac.variant=modern", "sac.hidden=64,64", "sac.lr=1e-3", "sac.gamma=0.95", "sac.tau=0.05",
    "sac.batch_size=256", "sac.random_steps=1000", "sac.learning_starts=1000", "replay.capacity=1000000",
)
QUICK_SINGLE = {"ReachTarget-v1": 10_000, "CloseBox-v1": 10_000, "CloseMicrowave-v1": 16_000}

# The seeds behind results/reference, per arm: key -> n (seeds 0..n-1; 0 = not in the reference). Keys are
# experiment:arm, or experiment:arm:method / experiment:arm:task where one arm has different counts per method
# or task (seed_count: method, then task, then arm). Every arm of the registry has an entry, and the plan of
# `sweep --preset reference --experiments all` is exactly the cells of results/reference/scores.csv
# (tests/test_sweep.py): add seeds to the reference, then edit this table in the same commit.
REFERENCE_SEEDS: Dict[str, int] = {
    "single:paper:sac_her_per": 0,
    "single:paper:ReachTarget-v1": 10,
    "single:paper:CloseBox-v1": 50,
    "single:paper:CloseMicrowave-v1": 20,
    "transfer:paper": 32,
    "transfer:paper:dual_buffer": 48,
    "ratios:0.5/0.5": 32,
    "ratios:0.6/0.4": 32,
    "ratios:0.7/0.3": 32,
    "scratch:paper": 32,
    "scratch:paper:dual_buffer": 48,
    "e_share:paper": 48,
    "e_share:e_off": 48,
    "e_share:split": 8,
    "e_share:r_matched": 48,
    "e_share:r_starved": 48,
    "e_share:e_critic": 48,
    "e_share:e_off_matched": 0,
    "mechanism:e_off": 48,
    "mechanism:r_matched": 48,
    "mechanism:r_starved": 48,
    "mechanism:e_critic": 48,
    "mechanism:e_off_matched": 0,
    "matched_chain:r_matched_all": 32,
    "budget:x2": 6,
    "budget:x4": 0,
    "budget:x8": 0,
    "shared_prior:shared": 32,
    "e_content:e_target_only": 8,
    "e_content:e_episodes": 8,
    "warm_start:paper": 32,
    "warm_start:warm": 32,
    "warm_start:warm_low_lr": 16,
    "her_episode:paper": 0,
    "her_episode:her_episode": 32,
    "paper_regime:episode": 0,
    "paper_regime:step": 0,
    "regime:long": 6,
    "regime:long_episode": 12,
}

PRESETS: Dict[str, Preset] = {
    "smoke": Preset(
        "CI: the whole pipeline (every experiment, table and plot) in about a minute; learns nothing",
        single_steps=_every_task(200), stage_steps=_every_task(150), adaptation_steps=_every_task(150),
        seeds=(0, 1), chain_seeds=(0, 1), default_steps=150,
        settings=("max_episode_steps=50", "eval_every=100", "eval_episodes=2", "checkpoint_every=50",
                  "sac.hidden=32,32", "sac.batch_size=32", "sac.random_steps=100", "sac.learning_starts=100",
                  "replay.capacity=10000")),
    "quick": Preset(
        "the paper's experiments at CPU budgets (rl-zoo-like goal-task settings): 4 single-task seeds, 6 chain seeds",
        single_steps=dict(QUICK_SINGLE), stage_steps=_every_task(6_000), adaptation_steps=_every_task(12_000),
        seeds=(0, 1, 2, 3), chain_seeds=tuple(range(6)), default_steps=10_000, settings=QUICK_SETTINGS),
    # The reference (results/reference): quick's budgets and settings, an evaluation at env step 0 of every
    # run (the prior's zero-shot score); each arm's seeds from REFERENCE_SEEDS unless --seeds/--chain-seeds
    # (then 10 single-task and 16 chain seeds, capped by max_seeds).
    "reference": Preset(
        "quick's settings at the seeds of results/reference (REFERENCE_SEEDS per arm), evaluation at step 0",
        single_steps=dict(QUICK_SINGLE), stage_steps=_every_task(6_000), adaptation_steps=_every_task(12_000),
        seeds=tuple(range(10)), chain_seeds=tuple(range(16)), default_steps=10_000,
        settings=QUICK_SETTINGS + ("eval_at_start=true",), arm_seeds=REFERENCE_SEEDS),
    "full": Preset(
        "quick's budgets and settings with 30 seeds everywhere (~7 h on 2 cores, or a Ray cluster)",
        single_steps=dict(QUICK_SINGLE), stage_steps=_every_task(6_000), adaptation_steps=_every_task(12_000),
        seeds=tuple(range(30)), chain_seeds=tuple(range(30)), default_steps=10_000, settings=QUICK_SETTINGS),
    # The paper's budgets (section 4.2, Table 3): ReachTarget 500 epochs, CloseBox/CloseMicrowave 200,
    # adaptation 120; an epoch is 200 episodes x 150 steps; one update per episode (Algorithm 1).
    "paper": Preset(
        "the paper's budgets and Table 3 settings (433.8M env steps: a cluster or GPU simulation)",
        single_steps=_every_task(200 * PAPER_EPOCH_STEPS, ReachTarget_v1=500 * PAPER_EPOCH_STEPS),
        stage_steps=_every_task(200 * PAPER_EPOCH_STEPS, ReachTarget_v1=500 * PAPER_EPOCH_STEPS),
        adaptation_steps=_every_task(120 * PAPER_EPOCH_STEPS), seeds=(0, 1, 2), chain_seeds=(0, 1, 2),
        default_steps=200 * PAPER_EPOCH_STEPS,
        settings=(f"eval_every={PAPER_EPOCH_STEPS}", "eval_episodes=10", f"checkpoint_every={10 * PAPER_EPOCH_STEPS}",
                  "max_episode_steps=150", "sac.random_steps=100000", "sac.learning_starts=100000",
                  "sac.update_schedule=episode", "sac.updates_per_episode=1")),
}


def preset(name: str) -> Preset:
    from ..config import ConfigError
    if name not in PRESETS:
        raise ConfigError(f"unknown preset {name!r} (choose from {', '.join(PRESETS)})")
    return PRESETS[name]
