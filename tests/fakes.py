"""A tiny goal episode for replay tests: each env's 3-D point moves along its own line."""
from types import SimpleNamespace

import numpy as np

from maniskill_dualher.replay.base import Episode

TOL = 0.05


def reward_fn(achieved, desired, info=None):
    return (np.linalg.norm(achieved - desired, axis=-1) < TOL).astype(np.float32)


def point_episode(T=6, N=3, O=4, A=2, seed=0, success_at=None):
    """Achieved goal of env n at time t is (t, 100 n, 7) (all distinct); desired goal is fixed per env.

    ``success_at``: list of (t, n) where the desired goal equals next_achieved_goal, giving real reward 1.
    """
    rng = np.random.default_rng(seed)
    t = np.arange(T + 1, dtype=np.float32)[:, None]
    n = np.arange(N, dtype=np.float32)[None, :]
    pos = np.stack(np.broadcast_arrays(t, 100 * n, np.full_like(t * n, 7)), -1).astype(np.float32)  # (T+1, N, 3)
    desired = np.broadcast_to(np.array([-50, -50, -50], np.float32), (T, N, 3)).copy()
    for (ts, ns) in success_at or []:
        desired[:, ns] = pos[ts + 1, ns]
    obs = rng.random((T, N, O)).astype(np.float32)
    nxt = rng.random((T, N, O)).astype(np.float32)
    reward = reward_fn(pos[1:], desired)
    term = np.zeros((T, N), bool)
    term[-1, 0] = True
    return Episode(obs=obs, action=rng.random((T, N, A)).astype(np.float32), reward=reward, next_obs=nxt,
                   terminated=term, achieved_goal=pos[:-1].copy(), next_achieved_goal=pos[1:].copy(),
                   desired_goal=desired, success=reward > 0)


def spec(O=4, G=3, A=2, N=3, T=6, goal=True):
    return SimpleNamespace(obs_dim=O, goal_dim=G if goal else 0, act_dim=A, reward_fn=reward_fn if goal else None,
                           num_envs=N, max_episode_steps=T)
