"""Env steps/s of every registered task vs a bare Panda-only ManiSkill scene, measured in the same run.

Random actions, physx_cpu, state obs, sparse reward (bare scene: no reward), one env in this process (resets on time-out are included in the time).
Rounds are interleaved (bare, table, task1, ..., bare, ...) and the median per env is reported, so load
from other processes on the machine hits every env alike; ratios use CPU time (process_time), which
other processes on a shared 2-core machine disturb far less than wall time. Two references: the Panda
alone, and the Panda on ManiSkill's table scene (which every task uses). Target: ratio >= 0.8.

    OMP_NUM_THREADS=1 python bench/env_speed.py [--steps 300] [--rounds 10] [--control-mode pd_joint_delta_pos]
"""
from __future__ import annotations

import argparse
import statistics
import time

import gymnasium as gym
import sapien
import torch

import maniskill_dualher.tasks  # noqa: F401  (registers the tasks)
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.utils.registration import register_env
from mani_skill.utils.scene_builder.table import TableSceneBuilder
from maniskill_dualher.tasks.common import registered_task_ids

BARE_ID = "BenchBarePanda-v0"
TABLE_ID = "BenchPandaTable-v0"


@register_env(BARE_ID, max_episode_steps=150)
class BarePandaEnv(BaseEnv):
    """Reference scene: the Panda alone (no table, no task objects), default state observation."""

    SUPPORTED_ROBOTS = ["panda"]

    def __init__(self, *args, robot_uids="panda", **kwargs):
        super().__init__(*args, robot_uids=robot_uids, **kwargs)

    @property
    def _default_sensor_configs(self):
        return []

    @property
    def _default_human_render_camera_configs(self):
        return []

    def _load_agent(self, options: dict):
        super()._load_agent(options, sapien.Pose(p=[-0.615, 0, 0]))

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        qpos = torch.tensor(self.agent.keyframes["rest"].qpos, dtype=torch.float32).repeat(len(env_idx), 1)
        self.agent.reset(qpos)

    def evaluate(self):
        return {}


@register_env(TABLE_ID, max_episode_steps=150)
class PandaTableEnv(BarePandaEnv):
    """Second reference: the Panda on ManiSkill's table scene (table + ground), still no task objects."""

    def _load_scene(self, options: dict):
        self.table_scene = TableSceneBuilder(env=self, robot_init_qpos_noise=0.02)
        self.table_scene.build()

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        self.table_scene.initialize(env_idx)


def steps_per_second(env, steps: int, seed: int) -> tuple:
    """(wall, cpu) random-action env steps per second; actions pre-sampled so only the env is timed."""
    gen = torch.Generator().manual_seed(seed)
    actions = torch.rand((steps,) + tuple(env.action_space.shape), generator=gen) * 2 - 1
    env.reset(seed=seed)
    for a in actions[:20]:  # warm-up
        env.step(a)
    env.reset(seed=seed)
    wall, cpu = time.perf_counter(), time.process_time()
    for a in actions:
        _, _, term, trunc, _ = env.step(a)
        if bool(term.any() or trunc.any()):
            env.reset()
    return steps / (time.perf_counter() - wall), steps / (time.process_time() - cpu)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--rounds", type=int, default=10)
    parser.add_argument("--control-mode", default="pd_joint_delta_pos")
    args = parser.parse_args(argv)
    if args.steps < 1 or args.rounds < 1:
        raise SystemExit(f"--steps={args.steps} and --rounds={args.rounds} must be >= 1")

    ids = [BARE_ID, TABLE_ID] + registered_task_ids()
    common = dict(obs_mode="state", control_mode=args.control_mode, sim_backend="physx_cpu",
                  render_backend="none", num_envs=1)
    # tasks with their default (sparse) reward; the bare scene has no task, so no reward at all
    envs = {i: gym.make(i, reward_mode="none" if i in (BARE_ID, TABLE_ID) else "sparse", **common) for i in ids}
    wall = {i: [] for i in ids}
    cpu = {i: [] for i in ids}
    for r in range(args.rounds):
        for i in ids:
            w, c = steps_per_second(envs[i], args.steps, seed=r)
            wall[i].append(w)
            cpu[i].append(c)
    for env in envs.values():
        env.close()

    med = {i: (statistics.median(wall[i]), statistics.median(cpu[i])) for i in ids}
    names = {BARE_ID: "bare Panda scene", TABLE_ID: "Panda + table scene"}
    print(f"control_mode={args.control_mode} steps={args.steps} rounds={args.rounds} "
          f"torch_threads={torch.get_num_threads()}")
    print("ratios use CPU-time steps/s (process_time): on a shared machine wall time mostly measures the neighbours")
    print(f"{'env':<22}{'wall steps/s':>13}{'cpu steps/s':>13}{'ratio vs bare':>15}{'vs table':>10}")
    for i in ids:
        w, c = med[i]
        print(f"{names.get(i, i):<22}{w:>13.0f}{c:>13.0f}{c / med[BARE_ID][1]:>15.2f}{c / med[TABLE_ID][1]:>10.2f}")


if __name__ == "__main__":
    main()
