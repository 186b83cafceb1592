"""One rollout through ``BatchEnv`` with the lean env step on or off, saved for a bitwise comparison.

Run in a fresh process per side (PhysX's CPU contacts are not reproducible across reset histories within
one process, so the two sides must not share one):

    python tests/lean_rollout.py TASK {lean,maniskill} OUT.npz [--random-episodes R] [--solver-episodes S]

Random episodes (uniform actions from a fixed seed) come first, then scripted-solver episodes (contact with
the panel on the hinged tasks). Every step records the observation, reward, terminated, truncated, success,
ManiSkill's ``get_state()`` (all actor and articulation poses, velocities, qpos, qvel), the nine drive targets
and the elapsed-step counter; every reset its observation.
"""
from __future__ import annotations

import argparse
import os
import sys

import numpy as np


def rollout(task: str, lean: bool, random_episodes: int, solver_episodes: int, seed: int = 7) -> dict:
    os.environ["MANISKILL_DUALHER_LEAN_STEP"] = "1" if lean else "0"
    import torch

    torch.set_num_threads(1)
    from maniskill_dualher.config import RunConfig
    from maniskill_dualher.envs import make_env

    env = make_env(RunConfig(env_id=task))
    if (env.lean is not None) != lean:
        raise SystemExit(f"lean={lean} but the env's lean step is {env.lean_off_reason or 'on'}")
    u = env.unwrapped
    joints = [j._objs[0] for c in u.agent.controller.controllers.values() for j in c.joints]
    rng = np.random.default_rng(seed)
    solver = env.solver()
    rec = {k: [] for k in ("obs", "reward", "terminated", "truncated", "success", "state", "targets",
                           "elapsed", "reset_obs")}
    for ep in range(random_episodes + solver_episodes):
        use_solver = ep >= random_episodes
        rec["reset_obs"].append(env.reset(seed * 1000 + ep))
        if use_solver:
            solver.reset()
        for _ in range(env.spec.max_episode_steps):
            if use_solver:
                a = solver.act(None).detach().cpu().numpy().reshape(1, -1).astype(np.float32)
                a = 2.0 * (a - env.low) / np.maximum(env.high - env.low, 1e-8) - 1.0
            else:
                a = rng.uniform(-1.0, 1.0, (1, env.spec.act_dim)).astype(np.float32)
            obs, rew, term, trunc, succ = env.step(a)
            rec["obs"].append(obs.copy())
            rec["reward"].append(rew)
            rec["terminated"].append(term)
            rec["truncated"].append(trunc)
            rec["success"].append(succ)
            rec["state"].append(u.get_state().cpu().numpy().copy())
            rec["targets"].append(np.array([j.drive_target[0] for j in joints], np.float32))
            rec["elapsed"].append(u.elapsed_steps.cpu().numpy().copy())
            if term[0] or trunc[0]:
                break
    env.close()
    return {k: np.stack(v) for k, v in rec.items()}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("task")
    p.add_argument("mode", choices=("lean", "maniskill"))
    p.add_argument("out")
    p.add_argument("--random-episodes", type=int, default=2)
    p.add_argument("--solver-episodes", type=int, default=2)
    args = p.parse_args(argv)
    if args.random_episodes < 0 or args.solver_episodes < 0:
        print(f"--random-episodes={args.random_episodes} --solver-episodes={args.solver_episodes} must be >= 0",
              file=sys.stderr)
        raise SystemExit(2)
    data = rollout(args.task, args.mode == "lean", args.random_episodes, args.solver_episodes)
    np.savez(args.out, **data)


if __name__ == "__main__":
    main()
