"""The paper's method (Algorithm 1): prioritized buffer R + uniform success buffer E.

R (prioritized, new rows at max priority) holds real and k hindsight copies of every
transition. E (uniform) holds only REAL transitions, never hindsight ones:

* ``success_buffer="transitions"`` (default, Algorithm 1: "if r_t = 1 then store in E"): the real
  transitions with reward 1. With episodes that end on success this is one row per successful
  episode, the step that reached the goal;
* ``success_buffer="episodes"`` (section 4.2: E "only contains successful trajectories"): every real
  transition of an episode in which the task succeeded.

Sampling:

* ``dual_mode="choose"`` (Algorithm 1): the whole mini-batch comes from R with probability
  r, from E with probability e = 1 - r;
* ``dual_mode="split"``: every mini-batch has round(B*r) rows from R and the rest from E.

While E is empty, R serves everything. Priority updates only touch R rows. At ratio 1/0 the dual buffer draws
nothing to choose, so on the same seed and settings it trains bit for bit like SAC+HER+PER (E is filled, never
sampled; ``tests/test_e_mechanism.py``).
"""
from __future__ import annotations

from typing import Dict, Optional, Set

import numpy as np

from .config import ConfigError
from .methods import method_spec
from .replay.base import Batch, Episode
from .replay.buffer import Handle, to_batch
from .replay.her import concat_rows, real_transitions, relabel
from .replay.method import BufferMethod


def adopted_classes(method: str) -> Set[str]:
    """Class names of the methods whose prior ``method`` adopts (registry ``MethodSpec.adopts``): a method's
    replay state names its class (``BufferMethod.state_dict``)."""
    return {method_spec(m).target.rsplit(":", 1)[1] for m in method_spec(method).adopts}


def _select(rows: Dict[str, np.ndarray], keep: np.ndarray) -> Dict[str, np.ndarray]:
    return {k: v[keep] for k, v in rows.items()}


class DualBufferReplay(BufferMethod):
    uses_goals = True
    accepts_demos = True

    def __init__(self, cfg, spec, rng, device="cpu"):
        super().__init__(cfg, spec, rng, device)
        self.r = float(self.rcfg.ratio[0])  # ratio and dual_mode are validated in RunConfig.validate
        self.mode = self.rcfg.dual_mode
        self._buffer("R", prioritized=True)
        self._buffer("E", prioritized=False)
        self._batches = 0      # sample() calls
        self._rows = 0         # rows served by sample()
        self._rows_from_R = 0
        self._batches_from_R = 0  # choose mode: whole batches from R

    @classmethod
    def replay_layout(cls, cfg):
        """R: each env step's real row and its k hindsight copies, prioritized. E: real rows only, at most one per
        env step (in practice ~1% of them are successes: an upper bound)."""
        return {"R": (1.0 + cfg.replay.her_k, True, 0), "E": (1.0, False, 0)}

    @classmethod
    def replay_typical(cls, cfg):
        """E keeps real reward-1 rows; when an episode ends at its first success that is one row per successful
        episode, so one per full-length episode is what a run stores even if every episode succeeds (a run
        whose episodes succeed sooner makes more of them; one per env step stays the bound). In the paper's
        regime that is 24,000 of 3.6M env steps, ~9 MB beside R's 4 GB: the bound (1.4 GB) put the dry run's
        estimate 35% over the measured peak."""
        per_step = super().replay_typical(cfg)
        if cfg.replay.success_buffer == "transitions" and cfg.terminate_on_success and cfg.max_episode_steps:
            per_step["E"] = 1.0 / cfg.max_episode_steps
        return per_step

    @property
    def E(self):
        return self.buffers["E"]

    def add_episode(self, ep: Episode) -> None:
        self._check_goal_episode(ep)
        real = real_transitions(ep)
        self._check_rows(real)
        if self.rcfg.her_k > 0:
            rows = concat_rows(real, relabel(ep, self.rcfg.her_strategy, self.rcfg.her_k, self.rng, self.reward_fn))
        else:
            rows = real
        self.main.add(rows)  # Algorithm 1: real + k hindsight copies, all at max priority
        self._add_to_E(ep, real)

    def _add_to_E(self, ep: Episode, real: Dict[str, np.ndarray]) -> None:
        if self.rcfg.success_buffer == "episodes":  # every real row of each env's successful episode
            ok = np.broadcast_to(np.asarray(ep.success, bool).any(0), ep.reward.shape).reshape(-1)
        else:  # real reward-1 transitions (Algorithm 1)
            ok = np.isclose(real["reward"], 1.0)
        if ok.any():
            self.E.add(_select(real, ok))

    def load_transfer_state(self, state: dict) -> None:
        """Adopt a prior's replay: the dual buffer's own, or that of a method its ``MethodSpec.adopts`` names
        (SAC+HER+PER's single R, the shared-prior ablation: R as it is, priorities included, and E started from
        R's real reward-1 rows, as Algorithm 1 would have stored them)."""
        if state.get("method") not in adopted_classes(self.cfg.method):
            return self.load_state_dict(state)
        if self.rcfg.success_buffer == "episodes":
            raise ConfigError("success_buffer=episodes cannot be rebuilt from a SAC+HER+PER prior "
                              "(its R does not keep episode boundaries); use success_buffer=transitions")
        if "real_success_rows" not in state.get("extra", {}):
            raise ConfigError("the SAC+HER+PER prior's checkpoint does not mark its real successes "
                              "(written by an older version); rerun its stages")
        self.rng.bit_generator.state = state["rng"]
        self.main.load_state_dict(state["buffers"]["R"])
        self._buffer("E", prioritized=False)
        rows = np.asarray(state["extra"]["real_success_rows"], np.int64)
        if len(rows):
            self.E.add(self.main.storage.get(rows))

    def on_transfer(self) -> None:
        if not self.rcfg.carry_success_buffer:  # E holds only the target task's own successes
            self._buffer("E", prioritized=False)

    def add_demo_episode(self, ep: Episode) -> None:
        """Seed E (only) with a scripted-solver episode's successes, chosen as for real episodes."""
        self._check_goal_episode(ep)
        real = real_transitions(ep)
        self._check_rows(real)
        self._add_to_E(ep, real)

    def sample(self, batch_size: Optional[int] = None) -> Batch:
        B = int(batch_size or self.batch_size)
        R, E = self.main, self.E
        use_weights = R.sampler.is_weights
        if len(R) == 0:  # only demos so far: E is all there is
            return self._from_E(B, use_weights)
        if self.mode == "choose":
            # At ratio 1/0 no draw: R serves every batch, so the random stream (HER goals, PER samples) stays
            # SAC+HER+PER's and E off trains bit for bit like it. Below 1 the draw comes first, as it always has.
            from_R = self.r >= 1.0 or self.rng.random() < self.r or len(E) == 0
            self._count(B, B if from_R else 0)
            if from_R:
                return R.sample(B, self.rng, self.device, source="R")
            return self._from_E(B, use_weights)
        # split
        nR = B if len(E) == 0 else int(round(B * self.r))
        self._count(B, nR)
        if nR == B:
            return R.sample(B, self.rng, self.device, source="R")
        if nR == 0:
            return self._from_E(B, use_weights)
        rows_R, idx, w = R.sample_arrays(nR, self.rng)
        rows_E, _, _ = E.sample_arrays(B - nR, self.rng)
        rows = {k: np.concatenate([rows_R[k], rows_E[k]]) for k in rows_R}
        if use_weights:
            w = np.concatenate([w, np.ones(B - nR, np.float32)])
        return to_batch(rows, w, Handle(idx, slice(0, nR), "R"), self.device)

    def _from_E(self, B: int, use_weights: bool) -> Batch:
        rows, _, _ = self.E.sample_arrays(B, self.rng)
        w = np.ones(B, np.float32) if use_weights else None
        batch = to_batch(rows, w, Handle(np.zeros(0, np.int64), slice(0, 0), "E"), self.device)
        batch.critic_only = self.rcfg.e_batches == "critic"
        return batch

    def _count(self, B: int, nR: int) -> None:
        self._batches += 1
        self._rows += B
        self._rows_from_R += nR
        self._batches_from_R += int(nR == B)

    def stats(self) -> Dict[str, float]:
        out = super().stats()
        out["frac_batches_from_R"] = self._batches_from_R / self._batches if self._batches else float("nan")
        out["frac_rows_from_R"] = self._rows_from_R / self._rows if self._rows else float("nan")
        return out

    def _extra_state(self) -> dict:
        return {"batches": self._batches, "rows": self._rows, "rows_from_R": self._rows_from_R,
                "batches_from_R": self._batches_from_R}

    def _load_extra_state(self, state: dict) -> None:
        self._batches = int(state.get("batches", 0))
        self._rows = int(state.get("rows", 0))
        self._rows_from_R = int(state.get("rows_from_R", 0))
        self._batches_from_R = int(state.get("batches_from_R", 0))
