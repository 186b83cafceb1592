"""Storage, sum tree, samplers and buffer: properties that would fail if the pieces were wrong."""
import numpy as np
import pytest
import torch
from scipy.stats import chisquare

from maniskill_dualher.config import ConfigError, ReplayConfig
from maniskill_dualher.replay.base import Batch
from maniskill_dualher.replay.buffer import make_buffer
from maniskill_dualher.replay.samplers import PrioritizedSampler, UniformSampler
from maniskill_dualher.replay.storage import RingStorage
from maniskill_dualher.replay.sumtree import SumTree


# ----------------------------------------------------------------- storage
def test_ring_wraps_and_keeps_newest():
    s = RingStorage(5, {"x": ((2,), np.float32), "r": ((), np.float32)})
    i1 = s.add({"x": np.arange(8, dtype=np.float32).reshape(4, 2), "r": np.arange(4, dtype=np.float32)})
    assert i1.tolist() == [0, 1, 2, 3] and len(s) == 4
    i2 = s.add({"x": np.full((3, 2), 9, np.float32), "r": np.array([10, 11, 12], np.float32)})
    assert i2.tolist() == [4, 0, 1] and len(s) == 5
    assert s.get(np.arange(5))["r"].tolist() == [11, 12, 2, 3, 10]
    i3 = s.add({"x": np.zeros((7, 2), np.float32), "r": np.arange(100, 107, dtype=np.float32)})
    assert i3.tolist() == [2, 3, 4, 0, 1]  # only the last `capacity` rows of an oversized add
    assert sorted(s.get(np.arange(5))["r"].tolist()) == [102, 103, 104, 105, 106]


def test_storage_state_dict_round_trip_saves_only_filled_part():
    s = RingStorage(1000, {"x": ((3,), np.float32)})
    s.add({"x": np.random.default_rng(0).random((7, 3)).astype(np.float32)})
    st = s.state_dict()
    assert st["data"]["x"].shape == (7, 3)
    t = RingStorage(1000, {"x": ((3,), np.float32)})
    t.load_state_dict(st)
    assert len(t) == 7 and np.array_equal(t.get(np.arange(7))["x"], s.get(np.arange(7))["x"])
    assert t.add({"x": np.zeros((1, 3), np.float32)}).tolist() == [7]  # cursor restored


def test_storage_get_returns_copies():
    s = RingStorage(4, {"x": ((), np.float32)})
    s.add({"x": np.ones(4, np.float32)})
    g = s.get(np.array([0, 1]))
    g["x"][:] = 5
    assert s.get(np.array([0]))["x"][0] == 1


# ----------------------------------------------------------------- sum tree
@pytest.mark.parametrize("cap", [1, 3, 17, 1000])
def test_sumtree_total_tracks_random_updates(cap):
    rng = np.random.default_rng(cap)
    t = SumTree(cap)
    leaves = np.zeros(cap)
    for _ in range(50):
        idx = rng.integers(0, cap, rng.integers(1, 20))
        vals = rng.random(len(idx)) * 3
        t.update(idx, vals)
        # with duplicate indices numpy keeps the last write; mirror that
        for i, v in zip(idx, vals):
            leaves[i] = v
        assert np.isclose(t.total, leaves.sum(), rtol=1e-12, atol=1e-12)
    # every internal node equals the sum of its children: rebuild changes nothing
    before = t.tree.copy()
    t.rebuild()
    assert np.array_equal(before, t.tree)


def test_sumtree_find_matches_cumsum():
    rng = np.random.default_rng(1)
    t = SumTree(37)
    vals = rng.random(37)
    vals[[3, 4, 20]] = 0.0  # zero leaves are never found
    t.update(np.arange(37), vals)
    q = rng.random(500) * t.total
    expected = np.searchsorted(np.cumsum(vals), q, side="right")
    got = t.find(q)
    ok = got == expected
    # float rounding may only disagree right at a boundary
    assert ok.mean() > 0.99 and not np.isin(got, [3, 4, 20]).any()


# ----------------------------------------------------------------- samplers
def _chi2_pvalue(counts, probs):
    return chisquare(counts, probs * counts.sum()).pvalue


def test_prioritized_frequencies_follow_p_pow_a():
    cap, a = 10, 0.5
    s = PrioritizedSampler(cap, priority_exponent=a, eps=1e-6)
    s.on_add(np.arange(cap))
    td = np.array([0.0, 0.1, 0.5, 1, 2, 4, 8, 0.01, 3, 0.3])
    s.update_priorities(np.arange(cap), td)
    probs = (td + 1e-6) ** a
    probs /= probs.sum()
    rng = np.random.default_rng(0)
    counts = np.zeros(cap)
    for _ in range(200):
        idx, _ = s.sample(cap, 256, rng)
        counts += np.bincount(idx, minlength=cap)
    assert _chi2_pvalue(counts, probs) > 1e-3
    # and clearly not uniform
    assert _chi2_pvalue(counts, np.full(cap, 0.1)) < 1e-6


def test_new_rows_get_max_priority():
    s = PrioritizedSampler(8, priority_exponent=0.5)
    s.on_add(np.arange(4))
    assert np.allclose(s.tree.leaves(np.arange(4)), 1.0)  # initial max 1.0
    s.update_priorities(np.array([0, 1]), np.array([9.0, 0.5]))
    s.on_add(np.array([4, 5]))
    assert np.allclose(s.tree.leaves(np.array([4, 5])), np.sqrt(9.0 + 1e-6))
    assert np.isclose(s.max_priority, 9.0 + 1e-6)


def test_written_back_priorities_change_next_draws():
    s = PrioritizedSampler(100, priority_exponent=1.0)
    s.on_add(np.arange(100))
    rng = np.random.default_rng(0)
    s.update_priorities(np.arange(100), np.full(100, 1e-3))
    s.update_priorities(np.array([42]), np.array([1e3]))
    idx, _ = s.sample(100, 256, rng)
    assert (idx == 42).mean() > 0.95


def test_sampling_stays_within_filled_rows():
    s = PrioritizedSampler(1000)
    s.on_add(np.arange(10))
    idx, _ = s.sample(10, 4096, np.random.default_rng(0))
    assert idx.min() >= 0 and idx.max() <= 9


def test_is_weights_and_annealing():
    s = PrioritizedSampler(4, priority_exponent=1.0, is_exponent=0.4, is_weights=True)
    s.on_add(np.arange(4))
    s.update_priorities(np.arange(4), np.array([1.0, 2.0, 3.0, 4.0]) - 1e-6)
    rng = np.random.default_rng(0)
    idx, w = s.sample(4, 64, rng)
    p = (idx + 1.0) / 10.0
    expect = (4 * p) ** -0.4
    assert np.allclose(w, expect / expect.max(), rtol=1e-5)
    s.set_progress(1.0)
    idx, w = s.sample(4, 64, rng)
    p = (idx + 1.0) / 10.0
    assert np.allclose(w, (1 / p) / (1 / p).max(), rtol=1e-5)


def test_sampler_state_round_trip_identical_draws():
    rng = np.random.default_rng(3)
    s = PrioritizedSampler(50)
    s.on_add(np.arange(30))
    s.update_priorities(np.arange(30), rng.random(30))
    t = PrioritizedSampler(50)
    t.load_state_dict(s.state_dict())
    assert np.array_equal(s.tree.tree, t.tree.tree)
    a, _ = s.sample(30, 64, np.random.default_rng(9))
    b, _ = t.sample(30, 64, np.random.default_rng(9))
    assert np.array_equal(a, b)


def test_bad_priority_values_raise():
    with pytest.raises(ConfigError, match="priority_exponent"):
        PrioritizedSampler(4, priority_exponent=-1)
    s = PrioritizedSampler(4)
    s.on_add(np.arange(4))
    with pytest.raises(ValueError, match="non-finite"):
        s.update_priorities(np.arange(2), np.array([1.0, np.nan]))
    with pytest.raises(ValueError, match="empty"):
        UniformSampler().sample(0, 4, np.random.default_rng(0))


# ----------------------------------------------------------------- buffer
def _rows(m, d=5, a=2, start=0):
    x = np.arange(start, start + m, dtype=np.float32)
    return {"obs": np.repeat(x[:, None], d, 1), "action": np.repeat(x[:, None], a, 1), "reward": x,
            "next_obs": np.repeat(x[:, None] + 0.5, d, 1), "done": np.zeros(m, np.float32)}


def test_buffer_batch_is_float32_torch_and_rows_are_consistent():
    buf = make_buffer(100, 5, 2, prioritized=True, replay_cfg=ReplayConfig())
    buf.add(_rows(40))
    b = buf.sample(32, np.random.default_rng(0))
    assert isinstance(b, Batch) and b.obs.dtype == torch.float32 and b.obs.shape == (32, 5)
    assert b.weights is None and b.reward.shape == (32,)
    # every field of a sampled row comes from the same stored transition
    assert torch.equal(b.obs[:, 0], b.reward) and torch.equal(b.next_obs[:, 0], b.reward + 0.5)
    assert np.array_equal(b.handle.indices, b.reward.numpy().astype(np.int64))
    buf.update_priorities(b, np.full(32, 5.0))
    assert np.allclose(buf.sampler.tree.leaves(b.handle.indices), np.sqrt(5.0 + 1e-6))


def test_partial_rebuild_equals_full_tree():
    rng = np.random.default_rng(4)
    t = SumTree(1000)
    t.update(np.arange(613), rng.random(613))
    u = SumTree(1000)
    u.tree[u.P:u.P + 613] = t.tree[t.P:t.P + 613]
    u.rebuild(613)
    assert np.array_equal(t.tree, u.tree)


class _FullDepthSumTree:
    """The sum tree before its subtree shortcut (every level of every walk): the reference for its bits."""

    def __init__(self, capacity):
        self.depth = max(1, int(np.ceil(np.log2(capacity))))
        self.P = 1 << self.depth
        self.tree = np.zeros(2 * self.P)

    def update(self, idx, values):
        node = np.asarray(idx, dtype=np.int64) + self.P
        self.tree[node] = values
        node = node >> 1
        for _ in range(self.depth):
            left = node << 1
            self.tree[node] = self.tree[left] + self.tree[left + 1]
            node >>= 1

    def find(self, prefix):
        s = np.array(prefix, dtype=np.float64)
        node = np.ones(s.shape, dtype=np.int64)
        for _ in range(self.depth):
            node <<= 1
            left = self.tree[node]
            go_right = s >= left
            s -= left * go_right
            node += go_right
        return node - self.P


@pytest.mark.parametrize("row_factor", [0, 8, 10**9])
@pytest.mark.parametrize("cap", [1, 2, 3, 17, 64, 1000, 5000])
def test_sumtree_subtree_walks_have_full_depth_bits(cap, row_factor, monkeypatch):
    """update and find walk only the subtree of written leaves: the same tree and the same leaves found as
    walking every level, while the buffer fills and after it wraps, for queries inside and beyond the total;
    whether update recomputes a level node by node (row_factor 0), whole from slices (10**9) or either by its
    size (the default)."""
    from maniskill_dualher.replay import sumtree
    monkeypatch.setattr(sumtree, "ROW_FACTOR", row_factor)
    rng = np.random.default_rng(cap)
    t, ref = SumTree(cap), _FullDepthSumTree(cap)
    high = 0
    for step in range(60):
        high = min(cap, high + int(rng.integers(1, max(2, cap // 20 + 2))))  # fill the way a ring buffer does
        idx = rng.integers(0, high, int(rng.integers(1, 300)))  # duplicates included
        vals = rng.random(len(idx)) * 3
        vals[rng.random(len(idx)) < 0.1] = 0.0
        t.update(idx, vals)
        ref.update(idx, vals)
        assert t.tree.tobytes() == ref.tree.tobytes()
        total = t.total
        q = np.concatenate([rng.random(256) * total, [0.0, total, np.nextafter(total, np.inf), 2 * total + 1]])
        assert np.array_equal(t.find(q), ref.find(q))
        if step == 0 and cap > 2:  # a subtree shorter than the tree: a query at the total skips it, to leaf P - 1
            assert t._sub() < t.depth and t.find(np.array([total]))[0] == t.P - 1


def test_sumtree_update_recomputes_small_rows_whole_and_keeps_the_bits(monkeypatch):
    """A big tree, few leaves updated: the low levels go node by node, the top ones whole (the slice path runs:
    a row node no updated leaf lies under is recomputed to what it held), and the tree equals the full walk."""
    from maniskill_dualher.replay import sumtree
    rng = np.random.default_rng(7)
    t, ref = SumTree(100_000), _FullDepthSumTree(100_000)
    vals = rng.random(70_000)
    t.update(np.arange(70_000), vals)
    ref.update(np.arange(70_000), vals)
    adds = []
    real_add = np.add
    monkeypatch.setattr(sumtree.np, "add", lambda *a, **kw: (adds.append(kw["out"].size), real_add(*a, **kw))[1])
    for _ in range(20):
        idx, v = rng.integers(0, 70_000, 16), rng.random(16)
        t.update(idx, v)
        ref.update(idx, v)
    monkeypatch.undo()
    assert adds and max(adds) <= 8 * 16 < 70_000 // 2  # only rows of at most ROW_FACTOR x 16 nodes went whole
    assert t.tree.tobytes() == ref.tree.tobytes()


@pytest.mark.parametrize("size", [50, 37])
def test_a_storage_loaded_from_its_file_by_consuming_it_goes_on_as_the_original(tmp_path, size):
    """A checkpoint's storage loaded inside ``consuming_loaded_state``: a full one adopts the file's arrays (they are
    its storage), a partial one is copied and each field dropped from the state; either way the loaded storage then
    takes new rows (wrapping past the end) exactly as the original does, and the state no longer holds the data."""
    import torch

    from maniskill_dualher.replay.storage import RingStorage, consuming_loaded_state
    from maniskill_dualher.rundir import array_state, file_state, load_torch_file

    rng = np.random.default_rng(0)
    rows = lambda n: {"obs": rng.standard_normal((n, 3)).astype(np.float32), "done": np.ones(n, np.float32)}  # noqa: E731
    a = RingStorage(50)
    a.add(rows(size))
    torch.save(file_state(a.state_dict()), tmp_path / "s.pt")
    state = array_state(load_torch_file(tmp_path / "s.pt", "test"))
    b = RingStorage(50)
    with consuming_loaded_state():
        b.load_state_dict(state)
    assert all(v is None for v in state["data"].values())
    full = size == 50
    assert (b._data["obs"].base is not None) == full  # adopted: a view of the file's tensor; copied: its own array
    more = rows(30)
    a.add(more)
    b.add(more)
    assert len(a) == len(b) and all(np.array_equal(a._data[k], b._data[k]) for k in a._data)
    idx = np.arange(50)
    assert all(np.array_equal(a.get(idx)[k], b.get(idx)[k]) for k in a._data)
