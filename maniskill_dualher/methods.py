"""Method registry: name -> replay method class. A new method is one file + one line here."""
from __future__ import annotations

import numpy as np

from baselines.sac import SACReplay
from baselines.sac_her_per import SACHerPerReplay

from .config import ConfigError, RunConfig
from .dual_buffer import DualBufferReplay

METHODS = {
    "sac": SACReplay,                 # vanilla SAC, uniform replay of real transitions
    "sac_her_per": SACHerPerReplay,   # one prioritized buffer, real + hindsight
    "dual_buffer": DualBufferReplay,  # the paper: prioritized R + uniform success buffer E
}


def make_method(cfg: RunConfig, spec, rng: np.random.Generator, device: str = "cpu"):
    """Build the replay method ``cfg.method`` for an env described by ``spec`` (an EnvSpec)."""
    cls = METHODS.get(cfg.method)
    if cls is None:
        raise ConfigError(f"unknown method {cfg.method!r} (known: {', '.join(sorted(METHODS))})")
    if cls.uses_goals and not getattr(spec, "goal_dim", 0):
        raise ConfigError(f"method {cfg.method!r} needs a goal environment (HER); {cfg.env_id!r} has no goals")
    if cls.uses_goals and getattr(spec, "is_maniskill", False) and cfg.reward_mode != "sparse":
        raise ConfigError(f"method {cfg.method!r} relabels goals with the sparse compute_reward; "
                          f"reward_mode={cfg.reward_mode!r} would mix two rewards (use reward_mode='sparse')")
    if cls.uses_goals and getattr(spec, "reward_fn", None) is None:
        raise ConfigError(f"method {cfg.method!r} needs the env's compute_reward; {cfg.env_id!r} gives none")
    return cls(cfg, spec, rng, device)
