"""A small batched goal env for the N-env training loop on CPU (no simulator).

N points on a plane, each with its own goal; an action moves a point by 0.1 * action. Success
(within ``TOL`` of the goal) terminates that env's episode; resets are per env, ManiSkill-style
(``reset(seed=[...], options={"env_idx": idx})`` resets only those envs and returns every env's
observation). Observation spaces are per env (like ManiSkill's ``single_observation_space``).
"""
from __future__ import annotations

import gymnasium as gym
import numpy as np

TOL = 0.1
ENV_ID = "BatchedPointGoal-v0"


class BatchedPointGoalEnv(gym.Env):
    terminate_on_success = True  # tells the trainer that reaching the goal ends an episode

    def __init__(self, num_envs: int = 3, goal_distance: float = 0.15):
        self.num_envs = num_envs
        self.goal_distance = goal_distance
        box = lambda n: gym.spaces.Box(-np.inf, np.inf, (n,), np.float32)  # noqa: E731
        self.observation_space = gym.spaces.Dict(
            {"observation": box(2), "achieved_goal": box(2), "desired_goal": box(2)})
        self.single_action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (num_envs, 2), np.float32)
        self.pos = np.zeros((num_envs, 2), np.float32)
        self.goal = np.zeros((num_envs, 2), np.float32)
        self.resets = np.zeros(num_envs, np.int64)  # per-env reset count (tests read it)

    def _obs(self):
        return {"observation": self.pos.copy(), "achieved_goal": self.pos.copy(), "desired_goal": self.goal.copy()}

    def reset(self, *, seed=None, options=None):
        idx = np.arange(self.num_envs) if not options or "env_idx" not in options else np.asarray(options["env_idx"])
        seeds = np.broadcast_to(np.asarray(seed if seed is not None else 0), (len(idx),))
        for i, s in zip(idx, seeds):
            rng = np.random.default_rng(int(s))
            self.pos[i] = rng.uniform(-1, 1, 2)
            angle = rng.uniform(0, 2 * np.pi)
            self.goal[i] = self.pos[i] + self.goal_distance * np.array([np.cos(angle), np.sin(angle)])
            self.resets[i] += 1
        return self._obs(), {}

    def compute_reward(self, achieved_goal, desired_goal, info):
        return (np.linalg.norm(np.asarray(achieved_goal) - np.asarray(desired_goal), axis=-1) < TOL).astype(np.float32)

    def step(self, action):
        self.pos = (self.pos + 0.1 * np.clip(np.asarray(action, np.float32), -1, 1)).astype(np.float32)
        success = self.compute_reward(self.pos, self.goal, {}) > 0.5
        zeros = np.zeros(self.num_envs, bool)
        return self._obs(), success.astype(np.float32), success, zeros, {"is_success": success}


def register(num_envs: int = 3) -> str:
    env_id = f"BatchedPointGoal{num_envs}-v0"
    if env_id not in gym.registry:
        gym.register(env_id, entry_point=lambda **kw: BatchedPointGoalEnv(num_envs=num_envs, **kw),
                     disable_env_checker=True)
    return env_id
