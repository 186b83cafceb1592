"""One prioritized buffer with a priority bonus for real successes (DDPGfD's design, Vecerik et al., 2017).

DDPGfD keeps demonstrations in the *same* prioritized replay as the agent's own transitions and adds a constant
epsilon_D to their priority, so they are drawn more often without a buffer of their own. Here the "demonstrations"
are what the dual buffer puts in E: the real (not hindsight) reward-1 transitions. They stay in R with every other
real and hindsight row (SAC+HER+PER's buffer: HER future, PER), and each priority written back for such a row is
|TD| + ``BONUS`` (then PER's epsilon and exponent as for every row). No E, no batch ratio: every update samples R.
"""
from __future__ import annotations

import numpy as np

from maniskill_dualher.baselines.sac_her_per import SACHerPerReplay
from maniskill_dualher.replay.base import Batch

# epsilon_D, DDPGfD's constant priority bonus for demonstrations. Stated, not tuned: the summed |TD| of the two
# critics on sparse 0/1 rewards is mostly below 1 here, so a bonus of 1 keeps real successes among the most
# likely rows while TD error still orders them
BONUS = 1.0


class SuccessBonusReplay(SACHerPerReplay):
    def update_priorities(self, batch: Batch, td_abs: np.ndarray) -> None:
        td_abs = np.asarray(td_abs, dtype=np.float64).reshape(-1)
        idx = batch.handle.indices
        if len(idx) and td_abs.shape[0] == batch.reward.shape[0]:
            td_abs = td_abs.copy()
            td_abs[batch.handle.rows] += BONUS * self._real_success[idx]
        super().update_priorities(batch, td_abs)
