"""SAC + HER + PER: one prioritized buffer holding real and k hindsight copies of each transition.

It also remembers which rows of R are *real* reward-1 transitions (not hindsight copies), so that a
dual buffer adapting from this method's prior (the ``shared_prior`` ablation) can start its E from them;
that bookkeeping draws no random numbers and changes nothing this method samples.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from maniskill_dualher.replay.base import Batch, Episode
from maniskill_dualher.replay.her import episode_transitions
from maniskill_dualher.replay.method import BufferMethod


class SACHerPerReplay(BufferMethod):
    uses_goals = True

    def __init__(self, cfg, spec, rng, device="cpu"):
        super().__init__(cfg, spec, rng, device)
        self._buffer("R", prioritized=True)
        self._real_success = np.zeros(self.main.storage.capacity, bool)  # per R slot: a real reward-1 row

    @classmethod
    def replay_layout(cls, cfg):
        """R: each env step's real row and its k hindsight copies, prioritized; 1 byte per row marks real successes."""
        return {"R": (1.0 + cfg.replay.her_k, True, np.dtype(bool).itemsize)}

    def add_episode(self, ep: Episode) -> None:
        self._check_goal_episode(ep)
        rows = episode_transitions(ep, self.rcfg.her_strategy, self.rcfg.her_k, self.rng, self.reward_fn)
        self._check_rows(rows)
        idx = self.main.add(rows)  # real rows first, then their hindsight copies
        n_real = ep.reward.size
        ok = np.zeros(len(rows["reward"]), bool)
        ok[:n_real] = np.isclose(rows["reward"][:n_real], 1.0)
        ok = ok[len(ok) - len(idx):]  # rows past the capacity were not kept
        self._real_success[idx] = ok

    def real_success_rows(self) -> np.ndarray:
        """Indices of R rows that are real (not hindsight) reward-1 transitions."""
        return np.flatnonzero(self._real_success[: len(self.main)])

    def sample(self, batch_size: Optional[int] = None) -> Batch:
        return self.main.sample(batch_size or self.batch_size, self.rng, self.device)

    def _extra_state(self) -> dict:
        return {"real_success_rows": self.real_success_rows()}

    def _load_extra_state(self, state: dict) -> None:
        self._real_success = np.zeros(self.main.storage.capacity, bool)
        self._real_success[np.asarray(state.get("real_success_rows", []), np.int64)] = True
