"""Array-based binary sum tree (float64) with batched, numpy-only update and find.

Node 1 is the root, node i has children 2i and 2i+1, leaves live at ``P + j`` where P is
the capacity rounded up to a power of two (padding leaves stay 0). Every internal node
is always recomputed as ``left + right`` from its children (never by adding deltas), so
the tree is a pure function of its leaves: no drift, and rebuilding from saved leaves
reproduces it bit for bit.

``update`` recomputes the touched nodes level by level; where a level of the subtree over leaves [0, high)
has few nodes (``ROW_FACTOR``), it recomputes that whole row from two strided slices instead: the nodes it
did not need to touch get the sums they hold, so the tree is the same bit for bit.

Only leaves [0, high) have ever been written (``high``: one past the highest); the rest are 0, and so is
every node above only them. ``update`` and ``find`` therefore work level by level only inside the subtree
of 2^sub leaves that holds [0, high) (sub = ceil(log2(high))) and treat its ancestors, the leftmost chain up
to the root, one node per level: the same nodes and the same sums as a walk over all ``depth`` levels
(``tests/test_replay.py`` holds both to the same bits), at 2^sub / P of the depth while the buffer fills.
"""
from __future__ import annotations

import numpy as np

from ..config import ConfigError


# A row of at most this many times the updated leaves' count is recomputed whole from strided slices (one
# numpy call, contiguous memory) rather than gathered and scattered node by node (seven calls); the nodes left
# alone are recomputed to the same sums, since every node is its children's sum.
ROW_FACTOR = 8


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
        self.high = 0  # one past the highest leaf ever written: leaves [high, P) are 0

    @property
    def total(self) -> float:
        return float(self.tree[1])

    def _sub(self) -> int:
        """Levels of the smallest leftmost subtree holding leaves [0, high)."""
        return (self.high - 1).bit_length() if self.high > 0 else self.depth

    def leaves(self, idx: np.ndarray) -> np.ndarray:
        return self.tree[self.P + np.asarray(idx, dtype=np.int64)]

    def update(self, idx: np.ndarray, values: np.ndarray) -> None:
        """Set leaves ``idx`` to ``values`` (>= 0), then recompute their ancestors level by level.

        Duplicate indices are allowed (the last value wins); a duplicated parent is just
        recomputed twice from the same children, which is cheaper than ``np.unique``.
        """
        leaf = np.asarray(idx, dtype=np.int64)
        values = np.asarray(values, dtype=np.float64)
        if leaf.size == 0:
            return
        tree = self.tree
        node = leaf + self.P
        tree[node] = values
        m = float(values.max())
        if m > self.max_value:
            self.max_value = m
        self.high = high = max(self.high, int(leaf.max()) + 1)
        sub = self._sub()
        node = node >> 1
        left = np.empty_like(node)
        h = 1  # height above the leaves of the nodes in ``node``
        rows = ROW_FACTOR * len(node)
        while h <= sub and ((high - 1) >> h) + 1 > rows:  # low in the subtree: every touched node, all at once
            np.left_shift(node, 1, out=left)
            tree[node] = tree[left] + tree[left + 1]
            node >>= 1
            h += 1
        for h in range(h, sub + 1):  # higher up, the few nodes over leaves [0, high): the whole row from slices
            lo, n = self.P >> h, ((high - 1) >> h) + 1
            np.add(tree[2 * lo:2 * (lo + n):2], tree[2 * lo + 1:2 * (lo + n):2], out=tree[lo:lo + n])
        n = self.P >> sub  # the subtree's root; its ancestors one by one
        while n > 1:
            n >>= 1
            tree[n] = tree[2 * n] + tree[2 * n + 1]

    def find(self, prefix: np.ndarray) -> np.ndarray:
        """Leaf index j for each prefix sum s: the j with cumsum[j-1] <= s < cumsum[j].

        All queries descend together, one few-op numpy step per level. Above the subtree that holds every
        written leaf, each node's left child carries the whole mass (its right child is 0): a query goes
        right there only if s >= total, and then on to the right through zeros, to the last leaf P - 1.
        """
        s = np.array(prefix, dtype=np.float64)  # copy: modified in place
        tree = self.tree
        sub = self._sub()
        start = self.P >> sub
        beyond = s >= tree[start] if sub < self.depth else None  # right above the subtree: to leaf P - 1
        node = np.full(s.shape, start, dtype=np.int64)
        go_right = np.empty(s.shape, dtype=bool)
        for _ in range(sub):
            node <<= 1
            left = tree[node]
            np.greater_equal(s, left, out=go_right)
            s -= left * go_right
            node += go_right
        node -= self.P
        if beyond is not None and beyond.any():
            node[beyond] = self.P - 1
        return node

    def rebuild(self, n_leaves: int | None = None) -> None:
        """Recompute internal nodes from the leaves (after loading leaves).

        Only ancestors of leaves [0, n_leaves) are touched (the rest are 0 anyway), so a
        restored 10^7-capacity tree maps memory only for its filled part.
        """
        tree = self.tree
        self.high = self.P if n_leaves is None else int(n_leaves)
        lo, hi = self.P, self.P + self.high
        while lo > 1:
            plo, phi = lo >> 1, (hi + 1) >> 1
            tree[plo:phi] = tree[2 * plo:2 * phi:2] + tree[2 * plo + 1:2 * phi:2]
            lo, hi = plo, phi
