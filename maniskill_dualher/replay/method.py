"""Shared plumbing of the replay methods (buffers + own rng + checkpointing).

A method subclass says how an episode enters its buffers (``add_episode``) and how a
batch leaves them (``sample``); everything else lives here.
"""
from __future__ import annotations

from typing import Dict, Optional, Tuple

import numpy as np

from ..config import ConfigError
from .base import Batch, Episode
from .buffer import Handle, ReplayBuffer, make_buffer
from .samplers import UniformSampler


class BufferMethod:
    uses_goals: bool = False
    accepts_demos: bool = False

    def __init__(self, cfg, spec, rng: np.random.Generator, device: str = "cpu"):
        self.cfg = cfg
        self.rcfg = cfg.replay
        self.spec = spec
        self.rng = rng
        self.device = device
        self.obs_dim = int(spec.obs_dim) + int(getattr(spec, "goal_dim", 0) or 0)  # network input width
        self.act_dim = int(spec.act_dim)
        self.reward_fn = getattr(spec, "reward_fn", None)
        self.batch_size = int(cfg.sac.batch_size)
        self.buffers: Dict[str, ReplayBuffer] = {}
        self._uniform = UniformSampler()

    @classmethod
    def replay_layout(cls, cfg) -> Dict[str, Tuple[float, bool, int]]:
        """What a run's memory plan needs (``experiment/cost.py``), without building anything: per buffer, (the
        most rows one env step adds to it, whether it is prioritized, bytes per row of the method's own per-row
        arrays). A method with other buffers overrides this."""
        return {"R": (1.0, False, 0)}

    @classmethod
    def replay_typical(cls, cfg) -> Dict[str, float]:
        """Per buffer, the rows one env step adds to it in a typical run, where that is well below
        ``replay_layout``'s most (the dry run prints the estimate from these and the bound from the layout; the
        memory plan fits the bound). Default: the most."""
        return {name: most for name, (most, _, _) in cls.replay_layout(cfg).items()}

    # ------------------------------------------------------------------ helpers
    def _buffer(self, name: str, prioritized: bool) -> ReplayBuffer:
        buf = make_buffer(self.rcfg.capacity, self.obs_dim, self.act_dim, prioritized, self.rcfg)
        self.buffers[name] = buf
        return buf

    def _check_rows(self, rows: Dict[str, np.ndarray]) -> None:
        if rows["obs"].shape[1] != self.obs_dim or rows["action"].shape[1] != self.act_dim:
            raise ValueError(f"episode rows have obs width {rows['obs'].shape[1]} / action width "
                             f"{rows['action'].shape[1]}, method expects {self.obs_dim} / {self.act_dim}")

    def _check_goal_episode(self, ep: Episode) -> None:
        if not ep.is_goal:
            raise ConfigError(f"method {type(self).__name__} needs goal episodes (HER); got a plain episode")

    @property
    def main(self) -> ReplayBuffer:
        return self.buffers["R"]

    # ------------------------------------------------------------------ ReplayMethod
    def __len__(self) -> int:
        return len(self.main)

    def sample_uniform(self, batch_size: Optional[int] = None) -> Batch:
        """Uniform over the main buffer (R), no weights: for training the actor on an unbiased batch."""
        return self.main.sample(batch_size or self.batch_size, self.rng, self.device, sampler=self._uniform,
                                source="R")

    def update_priorities(self, batch: Batch, td_abs: np.ndarray) -> None:
        """Write |TD| back to the prioritized rows that fed ``batch`` (no-op for uniform buffers)."""
        h: Handle = batch.handle
        buf = self.buffers.get(h.source)
        if buf is None or not buf.prioritized:
            return
        td_abs = np.asarray(td_abs).reshape(-1)
        if td_abs.shape[0] != batch.reward.shape[0]:
            raise ValueError(f"got {td_abs.shape[0]} |TD| values for a batch of {batch.reward.shape[0]}")
        buf.update_priorities(h.indices, td_abs[h.rows])

    def set_progress(self, fraction: float) -> None:
        for buf in self.buffers.values():
            buf.set_progress(fraction)

    def has_data(self) -> bool:
        return any(len(b) > 0 for b in self.buffers.values())

    def add_demo_episode(self, ep: Episode) -> None:
        """Demonstrations only seed methods with a success buffer (``accepts_demos``); others ignore them."""

    def stats(self) -> Dict[str, float]:
        """Buffer sizes and the PER max priority.

        ``replay_size`` is the main buffer R for every method; other buffers are ``<name>_size``.
        """
        out = {("replay_size" if k == "R" else f"{k}_size"): float(len(b)) for k, b in self.buffers.items()}
        for k, b in self.buffers.items():
            if b.prioritized:
                out["max_priority" if k == "R" else f"{k}_max_priority"] = float(b.sampler.max_priority)
        return out

    def load_transfer_state(self, state: dict) -> None:
        """Start from a prior run's replay (transfer). Default: the same method's buffers, as saved; a method
        that can adopt another method's replay (the shared-prior ablation) overrides this."""
        self.load_state_dict(state)

    def on_transfer(self) -> None:
        """Called once after another run's replay was loaded into this one (transfer); default: keep it all."""

    def reseed(self, rng: np.random.Generator) -> None:
        """Use a new sampling stream (e.g. after loading another run's replay for transfer)."""
        self.rng = rng

    def _extra_state(self) -> dict:
        return {}

    def _load_extra_state(self, state: dict) -> None:
        pass

    def state_dict(self) -> dict:
        return {"method": type(self).__name__, "rng": self.rng.bit_generator.state,
                "buffers": {k: b.state_dict() for k, b in self.buffers.items()}, "extra": self._extra_state()}

    def load_state_dict(self, state: dict) -> None:
        if state.get("method") != type(self).__name__:
            raise ConfigError(f"checkpoint holds replay method {state.get('method')!r}, not {type(self).__name__!r}")
        self.rng.bit_generator.state = state["rng"]
        for k, b in self.buffers.items():
            b.load_state_dict(state["buffers"][k])
        self._load_extra_state(state.get("extra", {}))
