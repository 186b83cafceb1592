"""Array-based binary sum tree (float64) with batched, numpy-only update and find.

Node 1 is the root, node i has children 2i and 2i+1, leaves live at ``P + j`` where P is
the capacity rounded up to a power of two (padding leaves stay 0). Every internal node
is always recomputed as ``left + right`` from its children (never by adding deltas), so
the tree is a pure function of its leaves: no drift, and rebuilding from saved leaves
reproduces it bit for bit.
"""
from __future__ import annotations

import numpy as np

from ..config import ConfigError


class SumTree:
    def __init__(self, capacity: int):
        capacity = int(capacity)
        if capacity <= 0:
            raise ConfigError(f"sum tree capacity must be > 0, got {capacity}")
        self.capacity = capacity
        self.depth = max(1, int(np.ceil(np.log2(capacity))))  # levels below the root
        self.P = 1 << self.depth
        self.tree = np.zeros(2 * self.P, dtype=np.float64)  # lazily mapped for large P
        self.max_value = 0.0  # largest leaf value ever written

    @property
    def total(self) -> float:
        return float(self.tree[1])

    def leaves(self, idx: np.ndarray) -> np.ndarray:
        return self.tree[self.P + np.asarray(idx, dtype=np.int64)]

    def update(self, idx: np.ndarray, values: np.ndarray) -> None:
        """Set leaves ``idx`` to ``values`` (>= 0), then recompute their ancestors level by level.

        Duplicate indices are allowed (the last value wins); a duplicated parent is just
        recomputed twice from the same children, which is cheaper than ``np.unique``.
        """
        node = np.asarray(idx, dtype=np.int64) + self.P
        values = np.asarray(values, dtype=np.float64)
        if node.size == 0:
            return
        tree = self.tree
        tree[node] = values
        m = float(values.max())
        if m > self.max_value:
            self.max_value = m
        node = node >> 1
        left = np.empty_like(node)
        for _ in range(self.depth):
            np.left_shift(node, 1, out=left)
            tree[node] = tree[left] + tree[left + 1]
            node >>= 1

    def find(self, prefix: np.ndarray) -> np.ndarray:
        """Leaf index j for each prefix sum s: the j with cumsum[j-1] <= s < cumsum[j].

        All queries descend together, one few-op numpy step per level.
        """
        s = np.array(prefix, dtype=np.float64)  # copy: modified in place
        node = np.ones(s.shape, dtype=np.int64)
        tree = self.tree
        go_right = np.empty(s.shape, dtype=bool)
        for _ in range(self.depth):
            node <<= 1
            left = tree[node]
            np.greater_equal(s, left, out=go_right)
            s -= left * go_right
            node += go_right
        return node - self.P

    def rebuild(self, n_leaves: int | None = None) -> None:
        """Recompute internal nodes from the leaves (after loading leaves).

        Only ancestors of leaves [0, n_leaves) are touched (the rest are 0 anyway), so a
        restored 10^7-capacity tree maps memory only for its filled part.
        """
        tree = self.tree
        lo, hi = self.P, self.P + (self.P if n_leaves is None else int(n_leaves))
        while lo > 1:
            plo, phi = lo >> 1, (hi + 1) >> 1
            tree[plo:phi] = tree[2 * plo:2 * phi:2] + tree[2 * plo + 1:2 * phi:2]
            lo, hi = plo, phi
