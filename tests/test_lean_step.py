"""The lean env step (tasks/lean.py) against ManiSkill's step: the same bits.

The rollouts run each side in a fresh process (tests/lean_rollout.py): PhysX's CPU contacts are not
reproducible across reset histories within one process, so in-process comparisons would prove nothing.
"""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from maniskill_dualher.config import TASKS   # every task of the catalog: a task added there is checked here too
from maniskill_dualher.tasks.common import transform_points
from maniskill_dualher.tasks.lean import (_r32, cross32, fma32, lean_step, torch_cross_fused,
                                          transform_point32, unsupported_reason)

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------ float32 arithmetic on floats
def test_fma32_breaks_a_double_rounding_tie_correctly():
    # a * b = 2^-24 - 2^-70 exactly; c = 1 + 2^-23. The exact sum lies just below the float32 midpoint
    # 1 + 3 * 2^-24, so it rounds down to c; the float64 sum lands on the midpoint and ties-to-even would
    # round up. Only an exact fused multiply-add gets c.
    a, b, c = (1 + 2.0**-23) * 2.0**-12, (1 - 2.0**-23) * 2.0**-12, 1 + 2.0**-23
    assert all(_r32(x) == x for x in (a, b, c))
    assert _r32(a * b + c) == 1 + 2.0**-22  # what the naive float64 route gives
    assert fma32(a, b, c) == c
    if torch_cross_fused():  # torch's cross rounds the same way: x = uy * vz - uz * vy = fma(uy, vz, -(uz * vy))
        u, v = [0.0, a, -1.0], [0.0, c, b]
        ref = torch.linalg.cross(torch.tensor([u]), torch.tensor([v]), dim=-1)[0].tolist()
        assert cross32(u, v, True)[0] == ref[0] == c


def test_cross_rounding_is_detected():
    fused = torch_cross_fused()
    assert fused is not None
    rng = np.random.default_rng(0)
    u, v = rng.normal(size=(3000, 3)).astype(np.float32), rng.normal(size=(3000, 3)).astype(np.float32)
    ref = torch.linalg.cross(torch.from_numpy(u), torch.from_numpy(v), dim=-1).numpy()
    same = np.array([cross32(a, b, fused) for a, b in zip(u.tolist(), v.tolist())], np.float32)
    other = np.array([cross32(a, b, not fused) for a, b in zip(u.tolist(), v.tolist())], np.float32)
    assert np.array_equal(same, ref)
    assert not np.array_equal(other, ref)  # the two roundings differ on these inputs: the check has teeth


def test_transform_point32_has_transform_points_bits():
    rng = np.random.default_rng(1)
    pose = rng.normal(size=(4000, 7)).astype(np.float32)
    pose[:, 3:] /= np.linalg.norm(pose[:, 3:], axis=1, keepdims=True)
    local = rng.normal(size=3).astype(np.float32)
    ref = transform_points(torch.from_numpy(pose), torch.from_numpy(local)).numpy()
    fused = torch_cross_fused()
    got = np.array([transform_point32(p, local.tolist(), fused) for p in pose.tolist()], np.float32)
    assert np.array_equal(got, ref)


# ------------------------------------------------------------------ when it applies
def _make(task="CloseBox-v1", **kw):
    import gymnasium as gym

    import maniskill_dualher  # noqa: F401

    kw = dict(dict(obs_mode="state", sim_backend="physx_cpu", num_envs=1, render_backend="none"), **kw)
    return gym.make(task, **kw)


@pytest.mark.parametrize("kw, words", [
    ({}, None),
    ({"reward_mode": "dense"}, "reward_mode='dense'"),
    ({"control_mode": "pd_ee_delta_pos"}, "control_mode='pd_ee_delta_pos'"),
    ({"obs_mode": "state_dict"}, "obs_mode='state_dict'"),
])
def test_unsupported_reason(kw, words):
    env = _make(**kw)
    try:
        reason = unsupported_reason(env.unwrapped)
        assert reason == words if words is None else words in reason
        if words is not None:
            with pytest.raises(ValueError, match="lean step unsupported"):
                lean_step(env.unwrapped, np.zeros(env.action_space.shape, np.float32))
    finally:
        env.close()


def test_a_task_hook_without_its_lean_twin_falls_back():
    from maniskill_dualher.tasks.close_box import CloseBoxEnv

    class Shifted(CloseBoxEnv):  # a new achieved goal, no new _lean_task_parts
        def _achieved_goal(self):
            return super()._achieved_goal() + 1.0

    env = Shifted(obs_mode="state", sim_backend="physx_cpu", render_backend="none")
    try:
        assert "_achieved_goal is newer than its _lean_task_parts" in unsupported_reason(env)
    finally:
        env.close()


def test_batch_env_switch(monkeypatch):
    from maniskill_dualher.config import ConfigError, RunConfig
    from maniskill_dualher.envs import LEAN_STEP_ENV, make_env

    monkeypatch.setenv(LEAN_STEP_ENV, "0")
    env = make_env(RunConfig(env_id="ReachTarget-v1"))
    assert env.lean is None and env.lean_off_reason == "off"
    env.close()
    monkeypatch.setenv(LEAN_STEP_ENV, "1")
    env = make_env(RunConfig(env_id="ReachTarget-v1"))
    assert env.lean is env.unwrapped
    env.close()
    monkeypatch.setenv(LEAN_STEP_ENV, "yes")
    with pytest.raises(ConfigError, match="MANISKILL_DUALHER_LEAN_STEP='yes'"):
        make_env(RunConfig(env_id="ReachTarget-v1"))


# ------------------------------------------------------------------ the same bits, fresh processes
def _rollouts(tmp_path, task, random_episodes, solver_episodes):
    """Both sides at once, each in its own fresh process."""
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    procs = {}
    for mode in ("lean", "maniskill"):
        out = tmp_path / f"{task}-{mode}.npz"
        procs[mode] = (out, subprocess.Popen(
            [sys.executable, str(ROOT / "tests" / "lean_rollout.py"), task, mode, str(out),
             "--random-episodes", str(random_episodes), "--solver-episodes", str(solver_episodes)],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True))
    for mode, (out, proc) in procs.items():
        log, _ = proc.communicate()
        assert proc.returncode == 0, f"{mode} rollout failed:\n{log[-2000:]}"
    return [dict(np.load(out)) for out, _ in procs.values()]


def _assert_same_bits(tmp_path, task, random_episodes, solver_episodes):
    lean, ms = _rollouts(tmp_path, task, random_episodes, solver_episodes)
    assert lean.keys() == ms.keys()
    for k in ms:
        assert lean[k].dtype == ms[k].dtype and lean[k].shape == ms[k].shape, k
        assert lean[k].tobytes() == ms[k].tobytes(), f"{task}: {k} differs"
    # what the rollout covered: every episode, time limits and the solver's successes
    assert len(ms["reset_obs"]) == random_episodes + solver_episodes
    assert ms["truncated"].sum() >= random_episodes - ms["success"][: 150 * random_episodes].sum()
    assert ms["success"].sum() >= 1 and ms["reward"].sum() == ms["success"].sum()


@pytest.mark.parametrize("task", TASKS)
def test_lean_step_same_bits(tmp_path, task):
    _assert_same_bits(tmp_path, task, random_episodes=1, solver_episodes=1)


@pytest.mark.slow
@pytest.mark.parametrize("task", TASKS)
def test_lean_step_same_bits_long(tmp_path, task):
    _assert_same_bits(tmp_path, task, random_episodes=6, solver_episodes=6)
