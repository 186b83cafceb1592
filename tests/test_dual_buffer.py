"""Methods: the dual buffer's routing (R vs E), what enters E, split proportions, registry, checkpoints."""
import re

import numpy as np
import pytest
import torch

from maniskill_dualher.config import ConfigError, RunConfig
from maniskill_dualher.methods import METHOD_SPECS as METHODS, make_method

from fakes import point_episode, spec


def _cfg(method="dual_buffer", **replay):
    cfg = RunConfig(method=method)
    cfg.replay.capacity = 10_000
    cfg.sac.batch_size = 32
    for k, v in replay.items():
        setattr(cfg.replay, k, v)
    return cfg


def _filled(method="dual_buffer", seed=0, **replay):
    m = make_method(_cfg(method, **replay), spec(), np.random.default_rng(seed))
    m.add_episode(point_episode(T=6, N=3, success_at=[(2, 1), (4, 2)], seed=1))
    m.add_episode(point_episode(T=6, N=3, seed=2))
    return m


def test_only_real_reward_one_transitions_enter_E():
    m = _filled(her_k=4)
    # 2 episodes x 18 real + 4 hindsight each in R; E gets the 2 real successes only
    assert len(m.main) == 2 * 18 * 5
    assert len(m.E) == 2
    e = m.E.storage.get(np.arange(2))
    assert (e["reward"] == 1.0).all()
    ep = point_episode(T=6, N=3, success_at=[(2, 1), (4, 2)], seed=1)
    # they are exactly the real transitions (2, 1) and (4, 2) with the ORIGINAL desired goal
    assert np.array_equal(e["obs"][0], np.concatenate([ep.obs[2, 1], ep.desired_goal[2, 1]]))
    assert np.array_equal(e["obs"][1], np.concatenate([ep.obs[4, 2], ep.desired_goal[4, 2]]))
    # R holds many hindsight successes that E must not
    assert (m.main.storage.get(np.arange(len(m.main)))["reward"] == 1).sum() > 2


def test_add_demo_episode_fills_E_only():
    m = make_method(_cfg(), spec(), np.random.default_rng(0))
    m.add_demo_episode(point_episode(success_at=[(1, 0), (3, 1)]))
    assert len(m.main) == 0 and len(m.E) == 2
    b = m.sample(8)  # R empty: E serves
    assert (b.reward == 1).all()


@pytest.mark.parametrize("r", [0.6, 0.3])
def test_share_of_batches_from_R_matches_ratio(r):
    m = _filled(ratio=(r, 1 - r))
    n = 4000
    from_R = 0
    for _ in range(n):
        b = m.sample()
        from_R += b.handle.source == "R"
        if b.handle.source == "E":
            assert (b.reward == 1).all()
    se = np.sqrt(r * (1 - r) / n)
    assert abs(from_R / n - r) < 4 * se
    assert m.stats()["frac_batches_from_R"] == pytest.approx(from_R / n)


def test_R_serves_while_E_is_empty():
    m = make_method(_cfg(ratio=(0.1, 0.9)), spec(), np.random.default_rng(0))
    m.add_episode(point_episode())  # no real success
    assert len(m.E) == 0
    assert all(m.sample().handle.source == "R" for _ in range(50))
    m2 = make_method(_cfg(ratio=(0.1, 0.9), dual_mode="split"), spec(), np.random.default_rng(0))
    m2.add_episode(point_episode())
    assert m2.sample().handle.rows == slice(None)


def test_split_mode_proportions_and_priority_updates_touch_R_only():
    m = _filled(ratio=(0.6, 0.4), dual_mode="split", is_weights=True)
    b = m.sample(50)
    assert b.obs.shape == (50, 7) and b.handle.rows == slice(0, 30) and len(b.handle.indices) == 30
    assert (b.reward[30:] == 1).all()  # the E part
    assert torch.all(b.weights[30:] == 1) and b.weights.shape == (50,)
    # rows 0..29 are the R rows named by the handle
    stored = m.main.storage.get(b.handle.indices)
    assert np.array_equal(stored["obs"], b.obs[:30].numpy())
    tree_before = m.main.sampler.tree.tree.copy()
    td = np.arange(50, dtype=np.float64)
    m.update_priorities(b, td)
    leaves = m.main.sampler.tree.leaves(b.handle.indices)
    last = {int(i): td[r] for r, i in enumerate(b.handle.indices)}  # duplicates: last write wins
    assert np.allclose(leaves, [np.sqrt(last[int(i)] + 1e-6) for i in b.handle.indices])
    assert not np.array_equal(tree_before, m.main.sampler.tree.tree)
    st = m.stats()
    assert st["frac_rows_from_R"] == pytest.approx(0.6)
    assert st["replay_size"] == len(m.main) and st["E_size"] == len(m.E) == 2


def test_E_batches_leave_priorities_alone():
    m = _filled(ratio=(0.0, 1.0))
    b = m.sample()
    assert b.handle.source == "E"
    before = m.main.sampler.tree.tree.copy()
    m.update_priorities(b, np.full(32, 100.0))
    assert np.array_equal(before, m.main.sampler.tree.tree)


@pytest.mark.parametrize("method", sorted(METHODS))
def test_state_dict_round_trip_gives_identical_future_batches(method):
    m = _filled(method, seed=5)
    for _ in range(3):
        b = m.sample()
        m.update_priorities(b, np.random.default_rng(1).random(32))
    state = m.state_dict()
    fresh = make_method(_cfg(method), spec(), np.random.default_rng(999))
    fresh.load_state_dict(state)
    for step in range(20):
        if step == 10:  # adding an episode after the restore must also stay identical
            for x in (m, fresh):
                x.add_episode(point_episode(seed=7, success_at=[(0, 0)]))
        a, c = m.sample(), fresh.sample()
        for f in ("obs", "action", "reward", "next_obs", "done"):
            assert torch.equal(getattr(a, f), getattr(c, f))
        td = np.random.default_rng(step).random(32)
        m.update_priorities(a, td)
        fresh.update_priorities(c, td)
    assert m.stats() == fresh.stats()


@pytest.mark.parametrize("method", sorted(METHODS))
def test_checkpoint_file_keeps_the_replay_bit_identical_and_loads_weights_only(method, tmp_path):
    """A checkpoint file (rundir.RunFolder.save_checkpoint) holds the replay as tensors of its filled rows only:
    it loads with torch.load(weights_only=True) (nothing but tensors and plain data), and the replay it restores
    (rundir.array_state) has the same bytes, priorities and future batches as the one written."""
    from maniskill_dualher import rundir
    m = _filled(method, seed=5)
    for k in range(3):
        b = m.sample()
        m.update_priorities(b, np.random.default_rng(k).random(32))
    m.main.storage._data["obs"][0, :3] = [np.nan, -0.0, np.float32(1e-45)]  # bits, not values, must survive
    rundir.RunFolder(tmp_path).save_checkpoint({"method": m.state_dict()})
    path = tmp_path / rundir.CHECKPOINT
    assert torch.serialization.get_unsafe_globals_in_checkpoint(str(path)) == []
    state = torch.load(path, weights_only=True)["method"]
    for name, buf in m.buffers.items():
        data = state["buffers"][name]["storage"]["data"]
        assert all(isinstance(v, torch.Tensor) and v.shape[0] == len(buf) for v in data.values())  # filled rows only
    fresh = make_method(_cfg(method), spec(), np.random.default_rng(999))
    fresh.load_state_dict(rundir.array_state(state))
    for name, buf in m.buffers.items():
        other = fresh.buffers[name]
        for f, arr in buf.storage._data.items():
            assert arr[:len(buf)].tobytes() == other.storage._data[f][:len(other)].tobytes()
        if buf.prioritized:
            assert buf.sampler.tree.tree.tobytes() == other.sampler.tree.tree.tobytes()
    if method == "sac_her_per":
        assert np.array_equal(m.real_success_rows(), fresh.real_success_rows())
    for step in range(10):
        a, c = m.sample(), fresh.sample()
        for f in ("obs", "action", "reward", "next_obs", "done"):
            assert getattr(a, f).numpy().tobytes() == getattr(c, f).numpy().tobytes()
        td = np.random.default_rng(step).random(32)
        m.update_priorities(a, td)
        fresh.update_priorities(c, td)


def test_vanilla_sac_on_plain_and_goal_envs():
    m = make_method(_cfg("sac"), spec(goal=False), np.random.default_rng(0))
    ep = point_episode()
    ep.achieved_goal = ep.next_achieved_goal = ep.desired_goal = None
    m.add_episode(ep)
    assert m.sample().obs.shape == (32, 4) and len(m.main) == 18
    g = make_method(_cfg("sac"), spec(), np.random.default_rng(0))
    g.add_episode(point_episode())
    assert g.sample().obs.shape == (32, 7) and len(g.main) == 18  # no relabeling


def test_sac_her_per_stores_real_plus_k_hindsight():
    m = _filled("sac_her_per", her_k=8)
    assert len(m.main) == 2 * 18 * 9
    assert m.sample().weights is None
    assert set(m.stats()) == {"replay_size", "max_priority"}


def test_registry_errors_are_one_line_config_errors():
    known = ", ".join(METHODS)    # the registry's names, in its order
    with pytest.raises(ConfigError, match=rf"unknown method 'nope' \(known: {re.escape(known)}\)"):
        make_method(_cfg("nope"), spec(), np.random.default_rng(0))
    for name in ("sac_her_per", "dual_buffer"):
        with pytest.raises(ConfigError, match="needs a goal environment") as e:
            make_method(_cfg(name), spec(goal=False), np.random.default_rng(0))
        assert "\n" not in str(e.value)


def test_reseed_switches_the_sampling_stream():
    m = _filled(seed=0)
    m.reseed(np.random.default_rng(123))
    a = m.sample().obs
    m.reseed(np.random.default_rng(123))
    assert torch.equal(a, m.sample().obs)
