"""What a run has done so far: one dataclass, checkpointed whole, so a resume continues exactly where it left off."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass


@dataclass
class Counters:
    env_steps: int = 0              # training env steps (all envs)
    episodes: int = 0               # finished training episodes
    successes: int = 0              # ... that succeeded (the paper's "successful attempts")
    updates: int = 0                # gradient updates
    update_credit: float = 0.0      # fractional updates owed (updates_per_step below 1, or 1/0.6)
    wall_time: float = 0.0          # seconds of this run's loop, over every process start
    demo_env_steps: int = 0         # env steps of scripted demonstrations (not training steps)
    started: int = 0                # training episodes started: the next one's reset seed
    episode_steps_total: int = 0    # env steps of finished training episodes (mean episode length)
    best_eval_success: float = -1.0  # best evaluation success so far (policy_best.pt); -1: none yet

    def state_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_state(cls, state: dict) -> "Counters":
        return cls(**state)
