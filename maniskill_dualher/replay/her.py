"""Hindsight relabeling (Andrychowicz et al. 2017), vectorized over a whole episode (T, N).

Rows are flattened time-major: real transition (t, n) is row ``t*N + n``; relabeled
transition (t, n, i) (i < k) is row ``(t*N + n)*k + i``. Goals are taken only from the
same env's trajectory (same n) within this episode, so goals never leak across envs or
episodes. Rewards are recomputed by the env's own ``compute_reward`` in one batched call.
"""
from __future__ import annotations

from typing import Dict, Optional

import numpy as np

from ..config import HER_STRATEGIES, ConfigError
from .base import Episode, RewardFn, goal_input

STRATEGIES = HER_STRATEGIES  # validated in RunConfig.validate
_F32 = np.float32


def _rows(x: np.ndarray) -> np.ndarray:
    """(T, N, ...) -> (T*N, ...)."""
    return x.reshape(x.shape[0] * x.shape[1], *x.shape[2:])


def real_transitions(ep: Episode) -> Dict[str, np.ndarray]:
    """The episode as T*N transition rows; network input is observation ‖ desired goal for goal envs."""
    obs, next_obs = ep.obs, ep.next_obs
    if ep.is_goal:
        obs, next_obs = goal_input(obs, ep.desired_goal), goal_input(next_obs, ep.desired_goal)
    return {
        "obs": _rows(obs).astype(_F32, copy=False),
        "action": _rows(ep.action).astype(_F32, copy=False),
        "reward": ep.reward.reshape(-1).astype(_F32, copy=False),
        "next_obs": _rows(next_obs).astype(_F32, copy=False),
        "done": ep.terminated.reshape(-1).astype(_F32),
    }


def goal_indices(T: int, N: int, strategy: str, k: int, rng: np.random.Generator) -> np.ndarray:
    """(T, N, k) time indices whose ``next_achieved_goal`` (same env n) becomes the new goal.

    future: uniform in [t, T-1] (SB3's convention: the transition's own outcome may be the goal);
    final: T-1; episode: uniform in [0, T-1].
    """
    if strategy == "future":
        t = np.arange(T, dtype=np.int64)[:, None, None]
        return t + (rng.random((T, N, k)) * (T - t)).astype(np.int64)  # floor(u*(T-t)) in [0, T-t-1]
    if strategy == "final":
        return np.full((T, N, k), T - 1, dtype=np.int64)
    if strategy == "episode":
        return rng.integers(0, T, (T, N, k), dtype=np.int64)
    raise ConfigError(f"unknown HER strategy {strategy!r} (choose {', '.join(STRATEGIES)})")


def _row_info(info: Optional[dict], T: int, N: int, k: int) -> Optional[dict]:
    """Per-step info arrays shaped (T, N, ...) repeated to the relabeled rows; other entries as is."""
    if not info:
        return None
    out = {}
    for key, v in info.items():
        if isinstance(v, np.ndarray) and v.ndim >= 2 and v.shape[:2] == (T, N):
            out[key] = np.repeat(_rows(v), k, axis=0)
        else:
            out[key] = v
    return out


def relabel(ep: Episode, strategy: str, k: int, rng: np.random.Generator, reward_fn: RewardFn) -> Dict[str, np.ndarray]:
    """k hindsight copies of every transition, T*N*k rows; ``done`` is copied from the real transition."""
    if not ep.is_goal or ep.next_achieved_goal is None:
        raise ConfigError("HER relabeling needs a goal environment (episode has no achieved/desired goals)")
    if reward_fn is None:
        raise ConfigError("HER relabeling needs the env's reward_fn (compute_reward), got None")
    k = int(k)
    if k < 0:
        raise ConfigError(f"her_k must be >= 0, got {k}")
    T, N = ep.reward.shape
    O, G, A = ep.obs.shape[-1], ep.next_achieved_goal.shape[-1], ep.action.shape[-1]
    M = T * N * k
    if M == 0:
        return {"obs": np.zeros((0, O + G), _F32), "action": np.zeros((0, A), _F32), "reward": np.zeros(0, _F32),
                "next_obs": np.zeros((0, O + G), _F32), "done": np.zeros(0, _F32)}
    j = goal_indices(T, N, strategy, k, rng)
    n = np.arange(N, dtype=np.int64)[None, :, None]
    goals = ep.next_achieved_goal[j, n].reshape(M, G)  # same env n, times j of this episode

    def rep(x):  # (T, N, ...) -> (T*N*k, ...), each row repeated k times in place
        return np.repeat(_rows(x), k, axis=0)

    obs = np.empty((M, O + G), _F32)
    obs[:, :O] = rep(ep.obs)
    obs[:, O:] = goals
    next_obs = np.empty((M, O + G), _F32)
    next_obs[:, :O] = rep(ep.next_obs)
    next_obs[:, O:] = goals
    reward = reward_fn(rep(ep.next_achieved_goal), goals, _row_info(ep.info, T, N, k))
    reward = np.asarray(reward, dtype=_F32).reshape(-1)
    if reward.shape != (M,):
        raise ValueError(f"reward_fn returned shape {reward.shape}, expected ({M},)")
    # done follows the relabeled goal when reaching the goal is what ends an episode; else the real flag
    done = (reward > 0.5).astype(_F32) if ep.goal_terminal else rep(ep.terminated).astype(_F32)
    return {"obs": obs, "action": rep(ep.action).astype(_F32, copy=False), "reward": reward,
            "next_obs": next_obs, "done": done}


def concat_rows(*parts: Dict[str, np.ndarray]) -> Dict[str, np.ndarray]:
    return {key: np.concatenate([p[key] for p in parts], axis=0) for key in parts[0]}


def episode_transitions(ep: Episode, strategy: str, k: int, rng: np.random.Generator,
                        reward_fn: RewardFn) -> Dict[str, np.ndarray]:
    """Real rows then their hindsight copies, as Algorithm 1 stores them in R."""
    real = real_transitions(ep)
    if k == 0:
        return real
    return concat_rows(real, relabel(ep, strategy, k, rng, reward_fn))
