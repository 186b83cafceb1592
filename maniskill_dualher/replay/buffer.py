"""A replay buffer is storage + sampler; it turns sampled rows into a torch :class:`Batch`."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Optional, Union

import numpy as np
import torch

from .base import Batch
from .samplers import PrioritizedSampler, UniformSampler
from .storage import RingStorage

Sampler = Union[UniformSampler, PrioritizedSampler]

def transition_fields(obs_dim: int, act_dim: int) -> Dict[str, tuple]:
    """Field spec of a transition row; ``obs_dim`` is the network input width (observation ‖ goal)."""
    f32 = np.dtype(np.float32)
    return {"obs": ((obs_dim,), f32), "action": ((act_dim,), f32), "reward": ((), f32),
            "next_obs": ((obs_dim,), f32), "done": ((), f32)}


@dataclass
class Handle:
    """What ``update_priorities`` needs: which buffer rows fed which batch rows."""
    indices: np.ndarray          # storage rows of the prioritized part
    rows: slice = field(default_factory=lambda: slice(None))  # batch rows they fed (split batches mix buffers)
    source: str = "R"


class ReplayBuffer:
    def __init__(self, storage: RingStorage, sampler: Sampler):
        self.storage = storage
        self.sampler = sampler

    def __len__(self) -> int:
        return len(self.storage)

    @property
    def prioritized(self) -> bool:
        return self.sampler.prioritized

    def add(self, transitions: Dict[str, np.ndarray]) -> np.ndarray:
        idx = self.storage.add(transitions)
        self.sampler.on_add(idx)
        return idx

    def sample_arrays(self, batch_size: int, rng: np.random.Generator, sampler: Optional[Sampler] = None):
        """(rows dict of numpy arrays, indices, weights or None); ``sampler`` overrides ours (e.g. uniform)."""
        idx, w = (sampler or self.sampler).sample(len(self.storage), batch_size, rng)
        return self.storage.get(idx), idx, w

    def sample(self, batch_size: int, rng: np.random.Generator, device: Union[str, torch.device] = "cpu",
               sampler: Optional[Sampler] = None, source: str = "R") -> Batch:
        rows, idx, w = self.sample_arrays(batch_size, rng, sampler)
        return to_batch(rows, w, Handle(idx, slice(None), source), device)

    def update_priorities(self, batch_or_indices, td_abs: np.ndarray) -> None:
        idx = batch_or_indices.handle.indices if isinstance(batch_or_indices, Batch) else batch_or_indices
        self.sampler.update_priorities(idx, td_abs)

    def set_progress(self, fraction: float) -> None:
        self.sampler.set_progress(fraction)

    def state_dict(self) -> dict:
        return {"storage": self.storage.state_dict(), "sampler": self.sampler.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.storage.load_state_dict(state["storage"])
        self.sampler.load_state_dict(state["sampler"])


def to_batch(rows: Dict[str, np.ndarray], weights: Optional[np.ndarray], handle, device="cpu") -> Batch:
    """Zero-copy on CPU: the gathered arrays are fresh, so the tensors may share their memory."""
    def t(x):
        x = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float32))
        return x if str(device) == "cpu" else x.to(device)
    return Batch(obs=t(rows["obs"]), action=t(rows["action"]), reward=t(rows["reward"]),
                 next_obs=t(rows["next_obs"]), done=t(rows["done"]),
                 weights=None if weights is None else t(weights), handle=handle)


def make_buffer(capacity: int, obs_dim: int, act_dim: int, prioritized: bool, replay_cfg=None) -> ReplayBuffer:
    """A transition buffer; ``replay_cfg`` (ReplayConfig) supplies the PER settings."""
    storage = RingStorage(capacity, transition_fields(obs_dim, act_dim))
    if not prioritized:
        return ReplayBuffer(storage, UniformSampler())
    r = replay_cfg
    sampler = PrioritizedSampler(capacity, priority_exponent=r.priority_exponent, eps=r.priority_eps,
                                 is_exponent=r.is_exponent, is_weights=r.is_weights)
    return ReplayBuffer(storage, sampler)
