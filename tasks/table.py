"""The task table (results/tasks.csv): widths, episode length and success tolerance of every task.

Read off the live environments (gym.make with default arguments), so the table cannot drift from code:

    python -m maniskill_dualher.tasks.table --out results/tasks.csv
"""
from __future__ import annotations

import argparse

import gymnasium as gym

from .common import GOAL_DIM, OBS_DIM, episode_length, registered_task_ids, split_goal_obs

COLUMNS = ("task", "observation_width", "goal_width", "action_width", "episode_length",
           "success_tolerance_m", "control_mode")


def task_rows() -> list:
    """One dict per registered task, COLUMNS as keys, measured from a freshly made env."""
    rows = []
    for task in registered_task_ids():
        env = gym.make(task)
        try:
            base = env.unwrapped
            obs, _ = env.reset(seed=0)
            o, a, d = split_goal_obs(obs)
            assert o.shape[-1] == OBS_DIM and a.shape[-1] == d.shape[-1] == GOAL_DIM
            rows.append(dict(
                task=task,
                observation_width=int(o.shape[-1]),
                goal_width=int(a.shape[-1]),
                action_width=int(env.action_space.shape[-1]),
                episode_length=episode_length(env),
                success_tolerance_m=round(float(base.goal_tolerance), 6),
                control_mode=base.control_mode,
            ))
        finally:
            env.close()
    return rows


def write_csv(rows, path: str) -> None:
    """Atomic write (the project's one writer: temp file in the same folder, then rename)."""
    from maniskill_dualher.fileio import atomic_write_text, csv_text
    atomic_write_text(path, csv_text(rows, list(COLUMNS)))


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="results/tasks.csv", help="CSV path (default: %(default)s)")
    args = parser.parse_args(argv)
    rows = task_rows()
    write_csv(rows, args.out)
    print(f"wrote {len(rows)} tasks to {args.out}")


if __name__ == "__main__":
    main()
