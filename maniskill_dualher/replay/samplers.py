"""Samplers decide which stored rows form a mini-batch (TorchRL style: a sampler is not a buffer).

Common interface::

    on_add(indices)                          # rows just written (new or overwritten)
    sample(size, batch_size, rng) -> (indices int64, weights float32 or None)
    update_priorities(indices, td_abs)       # no-op for uniform
    set_progress(fraction)                   # anneals the IS exponent; no-op for uniform
    state_dict() / load_state_dict(state)
"""
from __future__ import annotations

from typing import Optional, Tuple

import numpy as np

from ..config import ConfigError
from .sumtree import SumTree


def _check_size(size: int, batch_size: int) -> None:
    if size <= 0:
        raise ValueError("cannot sample from an empty buffer")
    if batch_size <= 0:
        raise ConfigError(f"batch_size must be > 0, got {batch_size}")


class UniformSampler:
    """Rows uniformly with replacement, as SB3/TorchRL's default."""

    prioritized = False

    def on_add(self, indices: np.ndarray) -> None:
        pass

    def sample(self, size: int, batch_size: int, rng: np.random.Generator) -> Tuple[np.ndarray, None]:
        _check_size(size, batch_size)
        return rng.integers(0, size, batch_size, dtype=np.int64), None

    def update_priorities(self, indices: np.ndarray, td_abs: np.ndarray) -> None:
        pass

    def set_progress(self, fraction: float) -> None:
        pass

    def state_dict(self) -> dict:
        return {}

    def load_state_dict(self, state: dict) -> None:
        pass


class PrioritizedSampler:
    """Proportional PER (Schaul et al. 2016): P(i) = p_i^a / sum_k p_k^a, p_i = |TD_i| + eps.

    ``priority_exponent`` is ``a`` (the paper's "β", PER libraries' alpha). The tree stores
    p^a directly. New rows enter at the largest priority seen so far (initially 1.0), as in
    Algorithm 1 (p_t = max_{i<t} p_i). Sampling is stratified: one uniform draw in each of
    ``batch_size`` equal slices of the total mass. Importance weights (optional; the paper
    does not use them) are w_i = (N P(i))^-beta / max_batch w, beta annealed linearly from
    ``is_exponent`` to 1 by ``set_progress``.
    """

    prioritized = True

    def __init__(self, capacity: int, priority_exponent: float = 0.5, eps: float = 1e-6,
                 is_exponent: float = 0.4, is_weights: bool = False):
        if not priority_exponent >= 0:
            raise ConfigError(f"priority_exponent must be >= 0, got {priority_exponent}")
        if not eps > 0:
            raise ConfigError(f"priority_eps must be > 0, got {eps}")
        if not 0 <= is_exponent <= 1:
            raise ConfigError(f"is_exponent must be in [0, 1], got {is_exponent}")
        self.tree = SumTree(capacity)
        self.alpha = float(priority_exponent)
        self.eps = float(eps)
        self.beta0 = float(is_exponent)
        self.beta = self.beta0
        self.is_weights = bool(is_weights)
        self.max_priority = 1.0      # raw priority (before the exponent) given to new rows
        self._high = 0               # 1 + highest row index ever written (leaves beyond are 0)

    def on_add(self, indices: np.ndarray) -> None:
        indices = np.asarray(indices, dtype=np.int64)
        if indices.size == 0:
            return
        self.tree.update(indices, np.full(indices.shape, self.max_priority ** self.alpha))
        self._high = max(self._high, int(indices.max()) + 1)

    def sample(self, size: int, batch_size: int, rng: np.random.Generator) -> Tuple[np.ndarray, Optional[np.ndarray]]:
        _check_size(size, batch_size)
        total = self.tree.total
        u = rng.random(batch_size)
        u += np.arange(batch_size)
        u *= total / batch_size
        idx = self.tree.find(u)
        np.minimum(idx, size - 1, out=idx)  # float rounding at the top end can step past the last row
        if not self.is_weights:
            return idx, None
        p = self.tree.leaves(idx) / total
        w = np.power(size * p, -self.beta)
        w /= w.max()
        return idx, w.astype(np.float32)

    def update_priorities(self, indices: np.ndarray, td_abs: np.ndarray) -> None:
        """priority = |TD| + eps (the caller sums |TD| of both critics, Eq. 9)."""
        td_abs = np.asarray(td_abs, dtype=np.float64).reshape(-1)
        indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        if td_abs.shape != indices.shape:
            raise ValueError(f"got {td_abs.size} priorities for {indices.size} indices")
        if not np.isfinite(td_abs).all():
            raise ValueError("non-finite |TD| given to update_priorities")
        p = np.abs(td_abs) + self.eps
        self.max_priority = max(self.max_priority, float(p.max()))
        self.tree.update(indices, p ** self.alpha)

    def set_progress(self, fraction: float) -> None:
        f = min(max(float(fraction), 0.0), 1.0)
        self.beta = self.beta0 + (1.0 - self.beta0) * f

    def state_dict(self) -> dict:
        """The written leaves (a view of the tree, as ``RingStorage.state_dict``'s arrays), the settings in use."""
        return {
            "leaves": self.tree.tree[self.tree.P:self.tree.P + self._high],
            "max_priority": self.max_priority,
            "max_value": self.tree.max_value,
            "beta": self.beta,
            "alpha": self.alpha,
        }

    def load_state_dict(self, state: dict) -> None:
        if float(state["alpha"]) != self.alpha:
            raise ConfigError(f"checkpoint priority_exponent {state['alpha']} != configured {self.alpha}")
        leaves = np.asarray(state["leaves"], dtype=np.float64)
        if len(leaves) > self.tree.capacity:
            raise ConfigError(f"checkpoint has {len(leaves)} priorities, capacity is {self.tree.capacity}")
        self.tree.tree = np.zeros(self.tree.tree.shape)  # fresh lazily-mapped zeros (zeros_like would memset)
        self.tree.tree[self.tree.P:self.tree.P + len(leaves)] = leaves
        self.tree.rebuild(len(leaves))
        self.tree.max_value = float(state["max_value"])
        self._high = len(leaves)
        self.max_priority = float(state["max_priority"])
        self.beta = float(state["beta"])
