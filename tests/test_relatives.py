"""The dual buffer's modern relatives, each one file and one registry line: mixed batches (RLPD's symmetric
sampling on R and E) and one prioritized R with a priority bonus for real successes (DDPGfD's design)."""
import numpy as np
import pytest

from maniskill_dualher.baselines import success_bonus
from maniskill_dualher.config import RunConfig
from maniskill_dualher.methods import METHOD_SPECS, make_method

from fakes import point_episode, spec


def _filled(method, **replay):
    cfg = RunConfig(method=method)
    cfg.replay.capacity = 10_000
    cfg.sac.batch_size = 256
    for k, v in replay.items():
        setattr(cfg.replay, k, v)
    m = make_method(cfg, spec(), np.random.default_rng(0))
    m.add_episode(point_episode(T=6, N=3, success_at=[(2, 1), (4, 2)], seed=1))
    m.add_episode(point_episode(T=6, N=3, seed=2))
    return m


def test_mixed_batch_takes_rows_from_R_and_E_in_every_batch_by_the_ratio():
    m = _filled("mixed_batch", ratio=(0.6, 0.4))     # dual_mode left at Algorithm 1's "choose": ignored here
    for _ in range(20):
        b = m.sample()
        assert b.handle.source == "R" and b.reward.shape[0] == 256
        assert (np.asarray(b.reward[154:]) == 1).all()            # 102 rows of E: real successes
        assert b.handle.indices.shape[0] == 154                    # priorities go back to R's 154 rows only
    assert m.stats()["frac_batches_from_R"] == 0.0 and m.stats()["frac_rows_from_R"] == pytest.approx(154 / 256)
    assert METHOD_SPECS["mixed_batch"].adopts == ("sac_her_per",)


def test_success_bonus_raises_the_priority_of_real_successes_only():
    m = _filled("success_bonus", her_k=4, priority_exponent=1.0)
    real = set(m.real_success_rows().tolist())
    assert len(real) == 2 and "E" not in m.buffers
    b = m.sample(64)
    td = np.full(64, 0.25)
    m.update_priorities(b, td)
    leaves = m.main.sampler.tree.leaves(b.handle.indices)
    eps = m.main.sampler.eps
    for i, p in zip(b.handle.indices.tolist(), leaves):
        expect = 0.25 + eps + (success_bonus.BONUS if i in real else 0.0)
        assert p == pytest.approx(expect)
    # hindsight copies with reward 1 got no bonus above: only real reward-1 rows are the "demonstrations"
    rewards = np.asarray(m.main.storage.get(b.handle.indices)["reward"]).reshape(-1)
    assert ((rewards == 1) & ~np.isin(b.handle.indices, list(real))).any()
