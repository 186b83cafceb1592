"""Vanilla SAC replay: one uniform buffer of real transitions, no relabeling.

On goal envs the network input is observation ‖ desired goal; on plain envs the observation.
"""
from __future__ import annotations

from typing import Optional

from maniskill_dualher.replay.base import Batch, Episode
from maniskill_dualher.replay.her import real_transitions
from maniskill_dualher.replay.method import BufferMethod


class SACReplay(BufferMethod):
    uses_goals = False

    def __init__(self, cfg, spec, rng, device="cpu"):
        super().__init__(cfg, spec, rng, device)
        self._buffer("R", prioritized=False)

    def add_episode(self, ep: Episode) -> None:
        rows = real_transitions(ep)
        self._check_rows(rows)
        self.main.add(rows)

    def sample(self, batch_size: Optional[int] = None) -> Batch:
        return self.main.sample(batch_size or self.batch_size, self.rng, self.device)
