"""Hindsight relabeling: goals come from the same env's own later outcomes; rewards are recomputed."""
import numpy as np
import pytest

from maniskill_dualher.config import ConfigError
from maniskill_dualher.replay.her import episode_transitions, real_transitions, relabel

from fakes import point_episode, reward_fn


def _source(goal):
    """(t_next, n) of an achieved goal (t, 100 n, 7) of the fake episode: it is next_achieved_goal[t-1, n]."""
    return goal[:, 0].astype(int) - 1, (goal[:, 1] / 100).astype(int)


def test_real_transitions_layout():
    ep = point_episode(T=5, N=3)
    rows = real_transitions(ep)
    assert rows["obs"].shape == (15, 4 + 3)
    # row t*N + n is (t, n); obs is observation ‖ desired goal
    assert np.array_equal(rows["obs"][2 * 3 + 1], np.concatenate([ep.obs[2, 1], ep.desired_goal[2, 1]]))
    assert np.array_equal(rows["next_obs"][7, 4:], ep.desired_goal[2, 1])
    assert rows["done"][4 * 3 + 0] == 1.0 and rows["done"].sum() == 1.0


@pytest.mark.parametrize("strategy", ["future", "final", "episode"])
def test_relabeled_goals_were_achieved_in_same_env_and_episode(strategy):
    T, N, k = 7, 3, 5
    ep = point_episode(T=T, N=N)
    rows = relabel(ep, strategy, k, np.random.default_rng(0), reward_fn)
    assert rows["obs"].shape == (T * N * k, 7)
    t = np.repeat(np.arange(T), N * k)
    n = np.tile(np.repeat(np.arange(N), k), T)
    goal = rows["obs"][:, 4:]
    j, src_n = _source(goal)
    # the goal is exactly an achieved goal of this episode...
    assert np.array_equal(goal, ep.next_achieved_goal[j, src_n])
    assert np.array_equal(rows["next_obs"][:, 4:], goal)
    # ...of the same env, never another
    assert np.array_equal(src_n, n)
    assert j.min() >= 0 and j.max() <= T - 1
    if strategy == "future":
        assert (j >= t).all()
        assert (j > t).any() and (j == t).any()  # both the own outcome and later ones occur
    elif strategy == "final":
        assert (j == T - 1).all()
    else:
        assert (j < t).any()
    # everything but the goal is the real transition (t, n)
    assert np.array_equal(rows["obs"][:, :4], ep.obs[t, n])
    assert np.array_equal(rows["action"], ep.action[t, n])
    assert np.array_equal(rows["done"], ep.terminated[t, n].astype(np.float32))
    # rewards are the env's reward of the achieved outcome against the new goal
    assert np.array_equal(rows["reward"], reward_fn(ep.next_achieved_goal[t, n], goal))
    assert rows["reward"][j == t].min() == 1.0 and rows["reward"][j != t].max() == 0.0


def test_future_goal_indices_are_uniform_over_remaining_steps():
    T, N, k = 4, 1, 4000
    ep = point_episode(T=T, N=N)
    rows = relabel(ep, "future", k, np.random.default_rng(1), reward_fn)
    j, _ = _source(rows["obs"][:, 4:])
    j0 = j[:k]  # t = 0: uniform over 0..3
    freq = np.bincount(j0, minlength=T) / k
    assert np.allclose(freq, 0.25, atol=0.03)


def test_episode_transitions_real_first_then_k_copies():
    ep = point_episode(T=5, N=2)
    rows = episode_transitions(ep, "future", 3, np.random.default_rng(0), reward_fn)
    assert len(rows["reward"]) == 10 + 30
    assert np.array_equal(rows["obs"][:10], real_transitions(ep)["obs"])
    assert len(episode_transitions(ep, "future", 0, np.random.default_rng(0), reward_fn)["reward"]) == 10


def test_relabel_errors_are_one_line():
    ep = point_episode()
    with pytest.raises(ConfigError, match="'nearest'"):
        relabel(ep, "nearest", 4, np.random.default_rng(0), reward_fn)
    with pytest.raises(ConfigError, match="reward_fn"):
        relabel(ep, "future", 4, np.random.default_rng(0), None)
