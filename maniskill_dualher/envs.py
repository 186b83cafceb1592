"""Any environment behind one batched numpy interface: a ManiSkill task (CPU or GPU simulation,
N parallel envs) or a plain gymnasium env (flat Box observation, or a goal-conditioned dict
observation with ``compute_reward``).

Observations come back flat, shape (N, D). For goal environments D = O + 2G laid out as
``[observation | achieved_goal | desired_goal]`` (our tasks produce exactly that; gymnasium
dict goal envs are flattened to it), and ``split`` cuts it apart. Actions go in as (N, A) in
[-1, 1] and are scaled to the action space's bounds here, so the policy never sees them.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Optional, Tuple

import gymnasium as gym
import numpy as np

from .config import TASKS, ConfigError, RunConfig
from .replay.base import RewardFn

EVAL_SEED_BASE = 1_000_000_000  # evaluation episodes use seeds EVAL_SEED_BASE + i in every run
# "0" turns the lean env step off (tasks/lean.py: one CPU env stepped without ManiSkill's per-step Python,
# bit-identical, tests/test_lean_step.py). An environment variable, not a RunConfig field: it changes no
# result, and a field would change every run folder's name (the hash of the config).
LEAN_STEP_ENV = "MANISKILL_DUALHER_LEAN_STEP"


def lean_step_wanted() -> bool:
    v = os.environ.get(LEAN_STEP_ENV, "1")
    if v not in ("0", "1"):
        raise ConfigError(f"{LEAN_STEP_ENV}={v!r} is not 0 or 1")
    return v == "1"


@dataclass
class EnvSpec:
    env_id: str
    obs_dim: int            # observation width without goals
    goal_dim: int           # 0 for plain environments
    act_dim: int
    num_envs: int
    max_episode_steps: int
    reward_fn: Optional[RewardFn]
    is_maniskill: bool

    @property
    def input_dim(self) -> int:
        """Width of the networks' input: observation ‖ desired goal."""
        return self.obs_dim + self.goal_dim

    @property
    def flat_dim(self) -> int:
        """Width of the flat env observation: observation ‖ achieved goal ‖ desired goal."""
        return self.obs_dim + 2 * self.goal_dim


def train_episode_seed(run_seed: int, episode: int) -> int:
    """Deterministic, distinct reset seed per training episode (so a resumed run replays exactly)."""
    return (run_seed * 1_000_003 + episode) % (2**31 - 1)


def _to_np(x) -> np.ndarray:
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x)


class BatchEnv:
    """Numpy-in, numpy-out view of a (possibly batched) environment."""

    def __init__(self, cfg: RunConfig):
        self.cfg = cfg
        env_id = cfg.env_id
        try:
            env_spec = gym.spec(env_id)
        except gym.error.Error:
            known = ", ".join(_known_task_ids())
            raise ConfigError(f"unknown environment {env_id!r} (our tasks: {known}; or any registered gymnasium id)") from None
        self.is_maniskill = _is_maniskill(env_id)
        if self.is_maniskill:
            self.env = self._make_maniskill(cfg)
        else:
            kw = {}
            if cfg.num_envs > 1:  # a batched env: the loop keeps each env's time limit itself
                kw["disable_env_checker"] = True
            elif cfg.max_episode_steps is not None:
                kw["max_episode_steps"] = cfg.max_episode_steps
            self.env = gym.make(env_id, **kw)
            n = int(getattr(self.env.unwrapped, "num_envs", 1))
            if n != cfg.num_envs:
                raise ConfigError(f"num_envs={cfg.num_envs}: {env_id!r} is a {'batched ' if n > 1 else ''}env "
                                  f"of {n} (plain gymnasium envs run one at a time here)")
        self.unwrapped = self.env.unwrapped
        # batched plain envs (tests' batched goal env) take actions (N, A) and reset per env like ManiSkill
        self._batched = self.is_maniskill or cfg.num_envs > 1
        space = getattr(self.unwrapped, "single_action_space", None) or self.env.action_space
        if not isinstance(space, gym.spaces.Box):
            raise ConfigError(f"environment {env_id!r} has a {type(space).__name__} action space; SAC needs a Box")
        self.low = np.asarray(space.low, dtype=np.float32).reshape(-1)
        self.high = np.asarray(space.high, dtype=np.float32).reshape(-1)
        self.num_envs = cfg.num_envs

        # Goal structure: our tasks expose goal_dim + compute_reward on a flat state; gymnasium
        # goal envs expose a Dict observation with the three GoalEnv keys.
        self._dict_goal = isinstance(self.env.observation_space, gym.spaces.Dict) and {
            "observation", "achieved_goal", "desired_goal"} <= set(self.env.observation_space.spaces)
        if self.is_maniskill and hasattr(self.unwrapped, "goal_tolerance"):
            from maniskill_dualher.tasks.common import GOAL_DIM, OBS_DIM
            obs_dim, goal_dim = OBS_DIM, GOAL_DIM
        elif self._dict_goal:
            sp = self.env.observation_space.spaces
            obs_dim = int(np.prod(sp["observation"].shape))
            goal_dim = int(np.prod(sp["desired_goal"].shape))
        else:
            shape = (getattr(self.unwrapped, "single_observation_space", None) or self.env.observation_space).shape
            obs_dim, goal_dim = int(np.prod(shape)), 0
        reward_fn = self._reward_fn if goal_dim else None
        if self.is_maniskill:
            max_steps = int(cfg.max_episode_steps or (self.env.spec and self.env.spec.max_episode_steps) or 150)
        else:
            max_steps = int(cfg.max_episode_steps or (self.env.spec and self.env.spec.max_episode_steps) or 1000)
        self.spec = EnvSpec(env_id, obs_dim, goal_dim, int(self.low.size), self.num_envs, max_steps,
                            reward_fn, self.is_maniskill)
        # the task env itself when it takes the lean step (tasks/lean.py), else None (ManiSkill's step)
        self.lean = None
        self.lean_off_reason = "off" if not lean_step_wanted() else None
        if self.is_maniskill and self.lean_off_reason is None:
            from maniskill_dualher.tasks.common import episode_length
            from maniskill_dualher.tasks.lean import lean_step, unsupported_reason
            self.lean_off_reason = unsupported_reason(self.unwrapped)
            if self.lean_off_reason is None:
                self.lean = self.unwrapped
                self._lean_step = lean_step
                self._time_limit = episode_length(self.env)  # ManiSkill's TimeLimitWrapper's, which lean skips

    # ------------------------------------------------------------------ making
    @staticmethod
    def _make_maniskill(cfg: RunConfig):
        kw = dict(obs_mode="state", reward_mode=cfg.reward_mode, sim_backend=cfg.sim_backend,
                  num_envs=cfg.num_envs, render_mode=None, render_backend="none")
        if cfg.control_mode is not None:
            kw["control_mode"] = cfg.control_mode
        if cfg.max_episode_steps is not None:
            kw["max_episode_steps"] = cfg.max_episode_steps
        if cfg.sim_backend == "physx_cuda" and cfg.gpu_memory_scale != 1.0:
            kw["sim_config"] = {"gpu_memory_config": gpu_memory_config(cfg.gpu_memory_scale)}
        try:
            return gym.make(cfg.env_id, **kw)
        except (ValueError, AssertionError, KeyError, NotImplementedError) as e:
            raise ConfigError(f"cannot make {cfg.env_id!r}: {str(e).splitlines()[0] if str(e) else type(e).__name__}") from None

    # --------------------------------------------------------------- interface
    @property
    def is_goal(self) -> bool:
        return self.spec.goal_dim > 0

    def _flat(self, obs) -> np.ndarray:
        if self._dict_goal:
            parts = [_to_np(obs[k]).astype(np.float32, copy=False).reshape(self.num_envs, -1)
                     for k in ("observation", "achieved_goal", "desired_goal")]
            return np.concatenate(parts, -1)
        x = _to_np(obs).astype(np.float32, copy=False)
        return x.reshape(self.num_envs, -1)

    def split(self, flat: np.ndarray) -> Tuple[np.ndarray, Optional[np.ndarray], Optional[np.ndarray]]:
        """(…, D) -> (observation, achieved_goal, desired_goal); goals are None for plain envs."""
        if not self.is_goal:
            return flat, None, None
        o, g = self.spec.obs_dim, self.spec.goal_dim
        return flat[..., :o], flat[..., o:o + g], flat[..., o + g:o + 2 * g]

    def policy_input(self, flat: np.ndarray, out: Optional[np.ndarray] = None) -> np.ndarray:
        """Network input: observation ‖ desired goal (the achieved goal is not an input). ``out``: an (N, input)
        float32 array to write it into (an evaluation loop's reused buffer); returned."""
        if out is not None:
            if not self.is_goal:
                out[...] = flat
                return out
            o, g = self.spec.obs_dim, self.spec.goal_dim
            out[..., :o] = flat[..., :o]
            out[..., o:] = flat[..., o + g:o + 2 * g]
            return out
        if not self.is_goal:
            return flat
        o, ag, dg = self.split(flat)
        return np.concatenate([o, dg], -1)

    def reset(self, seed: int) -> np.ndarray:
        """Reset every env; env i gets seed ``seed + i`` (one env: ``seed``). Returns (N, D)."""
        n = self.num_envs
        return self.reset_envs(np.arange(n), [int(seed) + i for i in range(n)])

    def reset_envs(self, idx: np.ndarray, seeds) -> np.ndarray:
        """Reset the envs ``idx`` (the others keep running) with one seed each; returns their (len(idx), D) rows.

        ManiSkill 3.0.1's partial reset mishandles a list of seeds (it overwrites every env's episode
        seed), so a partial ManiSkill reset is unseeded; a reset of all envs is seeded as usual.
        """
        idx = np.asarray(idx, dtype=np.int64)
        n = self.num_envs
        if len(idx) == n:
            obs, _ = self.env.reset(seed=int(seeds[0]) if n == 1 else [int(x) for x in seeds])
            return self._flat(obs)
        if self.is_maniskill:
            import torch
            obs, _ = self.env.reset(options={"env_idx": torch.as_tensor(idx, device=self.unwrapped.device)})
        else:
            obs, _ = self.env.reset(seed=[int(x) for x in seeds], options={"env_idx": idx})
        return self._flat(obs)[idx]

    def step(self, action: np.ndarray):
        """action in [-1, 1]^A -> (obs, reward, terminated, truncated, success or None), all numpy (N, ...)."""
        a = self.low + (np.clip(action, -1.0, 1.0) + 1.0) * 0.5 * (self.high - self.low)
        if self.lean is not None:
            obs, rew, term, elapsed = self._lean_step(self.lean, np.asarray(a, dtype=np.float32))
            trunc = np.array([self._time_limit is not None and elapsed >= self._time_limit])
            return obs, rew, term, trunc, term.copy()
        if self.is_maniskill:
            import torch
            a = torch.as_tensor(a, dtype=torch.float32, device=self.unwrapped.device)
        elif not self._batched:
            a = a.reshape(self.env.action_space.shape)
        obs, rew, term, trunc, info = self.env.step(a)
        n = self.num_envs
        rew = _to_np(rew).astype(np.float32).reshape(n)
        term = _to_np(term).astype(bool).reshape(n)
        trunc = _to_np(trunc).astype(bool).reshape(n)
        success = info.get("success", info.get("is_success")) if isinstance(info, dict) else None
        success = None if success is None else _to_np(success).astype(bool).reshape(n)
        return self._flat(obs), rew, term, trunc, success

    def _reward_fn(self, achieved: np.ndarray, desired: np.ndarray, info=None) -> np.ndarray:
        """The environment's own compute_reward, batched over the leading axis, as float32 numpy."""
        r = self.unwrapped.compute_reward(achieved, desired, info if info is not None else {})
        return _to_np(r).astype(np.float32).reshape(achieved.shape[:-1])

    def solver(self):
        """The task's scripted solver (for demonstrations), or None if the task has none."""
        try:
            from maniskill_dualher.tasks.solvers import make_solver
        except ImportError:
            return None
        try:
            return make_solver(self.env)
        except (KeyError, ValueError, NotImplementedError):
            return None

    def close(self) -> None:
        self.env.close()


def gpu_memory_config(scale: float) -> dict:
    """ManiSkill's GPUMemoryConfig defaults (PhysX GPU buffer sizes) times ``scale``, each rounded up to a power
    of two (PhysX wants a power-of-two heap; the defaults all are): ``sim_config={"gpu_memory_config": ...}``."""
    from mani_skill.utils.structs.types import GPUMemoryConfig
    return {k: 1 << max(0, math.ceil(math.log2(max(1.0, v * scale)))) for k, v in GPUMemoryConfig().dict().items()}


def _is_maniskill(env_id: str) -> bool:
    from mani_skill.utils.registration import REGISTERED_ENVS
    return env_id in REGISTERED_ENVS


def _known_task_ids():
    try:
        import maniskill_dualher.tasks  # noqa: F401
    except ImportError:
        pass
    return sorted(k for k in gym.registry if k in TASKS)


def make_env(cfg: RunConfig) -> BatchEnv:
    import maniskill_dualher.tasks  # noqa: F401  (registers our tasks)
    return BatchEnv(cfg)
