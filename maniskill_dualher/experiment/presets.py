"""Presets as data: per-task step budgets, seeds, and dotted ``RunConfig`` settings.

A preset never has its own knobs: every setting is a ``RunConfig`` key (``experiment/overrides.py``), so
``sweep --set KEY=VALUE`` reaches anything a preset sets and anything it does not. Budgets are keyed by
task id; a task in ``config.TASKS`` that a preset does not name gets the preset's ``default_steps``.
The reference preset's seeds per arm are the reference's own: the cells of ``results/reference/scores.csv``
(``cell_seeds``), so an arm has the seeds it was run at there, and none until it is.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Iterable, List, Optional, Tuple

from ..config import TASKS, RunConfig
from . import overrides

REPO = Path(__file__).resolve().parents[2]   # the checkout: results/ lives beside the package

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
    # a results folder (relative to the checkout) whose cells decide each arm's seeds (``cell_seeds``) when no
    # --seeds/--chain-seeds is given; wins over max_seeds
    seeds_from: Optional[str] = None

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


def cell_key(experiment: str, arm: str, method: str, task: str) -> str:
    """The key of one cell in a seed table (``cell_seeds``; a chain's cell is its target task)."""
    return f"{experiment}:{arm}:{method}:{task}"


def cell_seeds(folder: str, arms: Optional[Iterable[str]] = None) -> Dict[str, List[int]]:
    """The seeds a results folder holds per cell: ``cell_key`` -> sorted seeds, from its ``scores.csv`` (the
    single-task and adaptation rows; no torch). ``arms`` ("experiment:arm"): only those arms' cells. A folder
    or file that is not there holds none."""
    path = (REPO / folder) / "scores.csv"
    want = None if arms is None else set(arms)
    out: Dict[str, set] = {}
    if not path.is_file():
        return {}
    with open(path, newline="") as f:
        rows = csv.reader(f)
        cols = {c: i for i, c in enumerate(next(rows, []))}
        e, a, m, t, s, role = (cols[c] for c in ("experiment", "arm", "method", "task", "seed", "role"))
        for r in rows:
            if r[role] in ("single", "adapt") and (want is None or f"{r[e]}:{r[a]}" in want):
                out.setdefault(cell_key(r[e], r[a], r[m], r[t]), set()).add(int(r[s]))
    return {k: sorted(v) for k, v in sorted(out.items())}


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
    # run (the prior's zero-shot score); each arm's seeds those its cells have in results/reference/scores.csv
    # (none for an arm not run there) unless --seeds/--chain-seeds (then 10 single-task and 16 chain seeds,
    # capped by max_seeds). Adding seeds to the reference (report --merge) adds them here; nothing to edit.
    "reference": Preset(
        "quick's settings at the seeds of results/reference (each arm's, from its scores.csv), evaluation at step 0",
        single_steps=dict(QUICK_SINGLE), stage_steps=_every_task(6_000), adaptation_steps=_every_task(12_000),
        seeds=tuple(range(10)), chain_seeds=tuple(range(16)), default_steps=10_000,
        settings=QUICK_SETTINGS + ("eval_at_start=true",), seeds_from="results/reference"),
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
