"""SAC + HER + PER: one prioritized buffer holding real and k hindsight copies of each transition."""
from __future__ import annotations

from typing import Optional

from maniskill_dualher.replay.base import Batch, Episode
from maniskill_dualher.replay.her import episode_transitions
from maniskill_dualher.replay.method import BufferMethod


class SACHerPerReplay(BufferMethod):
    uses_goals = True

    def __init__(self, cfg, spec, rng, device="cpu"):
        super().__init__(cfg, spec, rng, device)
        self._buffer("R", prioritized=True)

    def add_episode(self, ep: Episode) -> None:
        self._check_goal_episode(ep)
        rows = episode_transitions(ep, self.rcfg.her_strategy, self.rcfg.her_k, self.rng, self.reward_fn)
        self._check_rows(rows)
        self.main.add(rows)

    def sample(self, batch_size: Optional[int] = None) -> Batch:
        return self.main.sample(batch_size or self.batch_size, self.rng, self.device)
