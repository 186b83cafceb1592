"""Generic tests over every registered PandaGoalEnv task (ReachTarget, CloseBox, CloseMicrowave, ...).

Task-specific physics tests live beside each task's own test file; here we check the shared contract:
gym.make in all reward modes, one observation layout, the GoalEnv reward, seeding, scripted solver vs
random policy, and one-line errors for bad input.
"""
import gymnasium as gym
import numpy as np
import pytest
import torch

import maniskill_dualher.tasks  # noqa: F401  (registers the tasks)
from maniskill_dualher.tasks.common import (
    DEFAULT_CONTROL_MODE,
    DEFAULT_MAX_EPISODE_STEPS,
    DENSE_REWARD_MAX,
    FLAT_OBS_DIM,
    GOAL_DIM,
    OBS_DIM,
    OBS_SLICES,
    PANDA_CONTROL_MODES,
    episode_length,
    registered_task_ids,
    split_goal_obs,
)
from maniskill_dualher.config import TASKS
from maniskill_dualher.experiment.registry import PAPER_CHAIN
from maniskill_dualher.tasks.solvers import make_solver

TASK_IDS = registered_task_ids()
_ENVS = {}


def make(task, **kwargs):
    """gym.make with a per-module cache (env creation dominates the cost of these tests)."""
    key = (task, tuple(sorted(kwargs.items())))
    if key not in _ENVS:
        _ENVS[key] = gym.make(task, **kwargs)
    _ENVS[key].action_space.seed(0)  # env.action_space.sample() reproducible within each test
    return _ENVS[key]


@pytest.fixture(scope="module", autouse=True)
def _close_envs():
    yield
    for env in _ENVS.values():
        env.close()
    _ENVS.clear()


def rollout_success(env, policy, seeds):
    """Fraction of seeded episodes in which ``policy(obs)`` reaches info['success'] before truncation."""
    wins = 0
    for seed in seeds:
        obs, info = env.reset(seed=seed)
        for _ in range(episode_length(env)):
            obs, _, term, trunc, info = env.step(policy(obs))
            if bool(info["success"].any()):
                wins += 1
                break
            if bool(term.any() or trunc.any()):
                break
    return wins / len(seeds)


def seeded_random_policy(env, seed):
    """Uniform random actions in [-1, 1] from a fixed generator, so pass/fail is reproducible."""
    gen = torch.Generator().manual_seed(seed)
    shape = tuple(env.action_space.shape)
    return lambda obs: torch.rand(shape, generator=gen) * 2 - 1


def test_tasks_registered():
    """The registered PandaGoalEnv tasks are the catalog (config.TASKS), which holds the paper's chain."""
    assert set(TASK_IDS) == set(TASKS), f"registered, not in config.TASKS: {set(TASK_IDS) - set(TASKS)}; " \
                                        f"in config.TASKS, not registered: {set(TASKS) - set(TASK_IDS)}"
    assert set(PAPER_CHAIN) <= set(TASKS)


def test_split_goal_obs_numpy_and_torch_any_leading_dims():
    x = np.arange(2 * 5 * FLAT_OBS_DIM, dtype=np.float32).reshape(2, 5, FLAT_OBS_DIM)
    for arr in (x, torch.from_numpy(x)):
        o, a, d = split_goal_obs(arr)
        assert o.shape == (2, 5, OBS_DIM) and a.shape == (2, 5, GOAL_DIM) and d.shape == (2, 5, GOAL_DIM)
        assert float(a[1, 4, 0]) == float(x[1, 4, OBS_DIM]) and float(d[0, 0, -1]) == float(x[0, 0, -1])
    with pytest.raises(ValueError, match=str(FLAT_OBS_DIM - 1)):
        split_goal_obs(x[..., :-1])


@pytest.mark.parametrize("task", TASK_IDS)
@pytest.mark.parametrize("reward_mode", ["sparse", "dense", "normalized_dense"])
def test_make_reward_modes(task, reward_mode):
    env = make(task, reward_mode=reward_mode)
    base = env.unwrapped
    assert base.control_mode == DEFAULT_CONTROL_MODE and episode_length(env) == DEFAULT_MAX_EPISODE_STEPS
    env.reset(seed=0)
    solver = make_solver(env)
    rewards, successes = [], []
    for t in range(40):  # solver then random: both reward regimes appear for most tasks
        action = solver.act(None) if t < 30 else env.action_space.sample()
        _, r, _, _, info = env.step(action)
        assert r.shape == (1,) and r.dtype == torch.float32
        rewards.append(float(r[0]))
        successes.append(bool(info["success"][0]))
    rewards = np.array(rewards)
    hi = {"sparse": 1.0, "dense": DENSE_REWARD_MAX, "normalized_dense": 1.0}[reward_mode]
    assert rewards.min() >= 0.0 and rewards.max() <= hi
    assert np.all((rewards == hi) == np.array(successes)), "max reward exactly on success steps"
    if reward_mode == "sparse":
        assert set(np.unique(rewards)) <= {0.0, 1.0}


@pytest.mark.parametrize("task", TASK_IDS)
def test_normalized_dense_is_dense_over_max(task):
    envs = [make(task, reward_mode=m) for m in ("dense", "normalized_dense")]
    actions = torch.from_numpy(np.random.default_rng(0).uniform(-1, 1, (20, 1, envs[0].action_space.shape[-1])))
    rs = []
    for env in envs:
        env.reset(seed=3)
        rs.append(torch.cat([env.step(a.float())[1] for a in actions]))
    torch.testing.assert_close(rs[1] * DENSE_REWARD_MAX, rs[0])
    assert rs[0].std() > 0, "dense reward should vary along a random trajectory"


@pytest.mark.parametrize("task", TASK_IDS)
def test_observation_layout(task):
    """Width identical across tasks; slots hold what the table in tasks/common.py says; split == state_dict."""
    env = make(task)
    base = env.unwrapped
    assert env.observation_space.shape[-1] == FLAT_OBS_DIM == OBS_DIM + 2 * GOAL_DIM
    obs, info = env.reset(seed=1)
    for _ in range(3):
        obs, _, _, _, info = env.step(env.action_space.sample())
    assert obs.shape == (1, FLAT_OBS_DIM)
    o, a, d = split_goal_obs(obs)
    torch.testing.assert_close(o[:, OBS_SLICES["qpos"]], base.agent.robot.get_qpos())
    torch.testing.assert_close(o[:, OBS_SLICES["qvel"]], base.agent.robot.get_qvel())
    torch.testing.assert_close(o[:, OBS_SLICES["tcp_pose"]], base.agent.tcp.pose.raw_pose)
    torch.testing.assert_close(o[:, OBS_SLICES["object_pose"]], base._object_pose())
    torch.testing.assert_close(o[:, 32:34], base._joint_state().reshape(1, 2))
    torch.testing.assert_close(o[:, OBS_SLICES["distractor_pos"]], base._distractor_positions())
    assert torch.equal(a, info["achieved_goal"]) and torch.equal(d, info["desired_goal"])
    sd = base._get_obs_state_dict(base.get_info())
    assert list(sd) == ["observation", "achieved_goal", "desired_goal"]
    assert torch.equal(torch.cat(list(sd.values()), -1), obs)

    env_sd = make(task, obs_mode="state_dict")
    obs_sd, _ = env_sd.reset(seed=1)
    obs_flat, _ = env.reset(seed=1)
    for part, key in zip(split_goal_obs(obs_flat), ("observation", "achieved_goal", "desired_goal")):
        assert torch.equal(part, obs_sd[key])


@pytest.mark.parametrize("task", TASK_IDS)
def test_compute_reward_matches_env_reward(task):
    """Stored goals -> compute_reward (torch and numpy, batched over time) == the env's sparse reward."""
    env = make(task)
    base = env.unwrapped
    solver = make_solver(env)
    rng = np.random.default_rng(0)
    ags, dgs, rews = [], [], []
    obs, _ = env.reset(seed=0)
    for t in range(250):
        mix = rng.random()  # solver, random and mixed actions so that both rewards occur
        action = solver.act(obs) if mix < 0.6 else env.action_space.sample()
        obs, r, term, trunc, info = env.step(action)
        _, a, d = split_goal_obs(obs)
        assert torch.equal(base.compute_reward(a, d, info), r)
        ags.append(a), dgs.append(d), rews.append(r)
        if bool(term.any() or trunc.any()) or t % 50 == 49:
            obs, _ = env.reset(seed=t)
    ag, dg, rew = torch.stack(ags), torch.stack(dgs), torch.stack(rews)  # (T, 1, 3), (T, 1)
    assert 0 < float(rew.mean()) < 1, "both rewards should occur in this test"
    assert torch.equal(base.compute_reward(ag, dg, {}), rew)
    out_np = base.compute_reward(ag.numpy(), dg.numpy(), {})
    assert isinstance(out_np, np.ndarray) and out_np.dtype == np.float32 and out_np.shape == rew.shape
    assert np.array_equal(out_np, rew.numpy())


@pytest.mark.parametrize("task", TASK_IDS)
def test_compute_reward_numpy_equals_torch_at_the_boundary(task):
    base = make(task).unwrapped
    rng = np.random.default_rng(1)
    a = rng.uniform(-0.5, 0.5, (20000, 3)).astype(np.float32)
    u = rng.normal(size=(20000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    d = (a + u * base.goal_tolerance * (1 + rng.uniform(-1e-6, 1e-6, (20000, 1)))).astype(np.float32)
    r_np = base.compute_reward(a, d, {})
    r_t = base.compute_reward(torch.from_numpy(a), torch.from_numpy(d), {})
    assert 0.2 < r_np.mean() < 0.8  # really on the boundary
    assert np.array_equal(r_np, r_t.numpy())
    assert np.all(base.compute_reward(a, a, {}) == 1.0)


@pytest.mark.parametrize("task", TASK_IDS)
def test_seeding_and_goal_box(task):
    env = make(task)
    base = env.unwrapped
    assert base.GOAL_BOX_LOW is not None and base.GOAL_BOX_HIGH is not None, "document the reset goal box"
    lo, hi = torch.tensor(base.GOAL_BOX_LOW), torch.tensor(base.GOAL_BOX_HIGH)
    first = {}
    for seed in range(12):
        obs, info = env.reset(seed=seed)
        again, _ = env.reset(seed=seed)
        assert torch.equal(obs, again), f"seed {seed} not reproducible"
        first[seed] = obs
        dg = split_goal_obs(obs)[2][0]
        assert torch.all(dg >= lo) and torch.all(dg <= hi), f"desired goal {dg} outside the goal box"
        assert not bool(info["success"][0]), "an episode must not start solved"
    goals = torch.stack([split_goal_obs(o)[2][0] for o in first.values()])
    assert len(torch.unique(goals, dim=0)) == len(goals), "different seeds should give different goals"
    # the robot start pose is randomized too
    qpos = torch.stack([o[0, OBS_SLICES["qpos"]] for o in first.values()])
    assert len(torch.unique(qpos, dim=0)) == len(qpos)


def test_reach_target_balls_separated_inside_box():
    env = make("ReachTarget-v1")
    base = env.unwrapped
    lo, hi = torch.tensor(base.BALL_BOX_LOW), torch.tensor(base.BALL_BOX_HIGH)
    for seed in range(30):
        obs, _ = env.reset(seed=seed)
        o, _, d = split_goal_obs(obs[0])
        balls = torch.stack([d, o[34:37], o[37:40]])
        assert torch.all(balls >= lo) and torch.all(balls <= hi)
        gaps = torch.cdist(balls, balls)[torch.triu_indices(3, 3, 1).unbind()]
        assert gaps.min() >= base.MIN_BALL_SEPARATION
        rest = torch.tensor(base.REST_TCP_POS)
        assert torch.linalg.norm(d - rest) >= base.MIN_START_DISTANCE
        assert torch.all(o[OBS_SLICES["object_pose"]] == 0)  # the red ball is the goal: not observed


@pytest.mark.parametrize("task", TASK_IDS)
def test_max_episode_steps_override(task):
    env = make(task, max_episode_steps=7)
    assert episode_length(env) == 7
    env.reset(seed=0)
    truncs = [bool(env.step(env.action_space.sample() * 0)[3].any()) for _ in range(7)]
    assert truncs == [False] * 6 + [True]


@pytest.mark.parametrize("task", TASK_IDS)
def test_scripted_solver_beats_random(task):
    """Fast version of the done criterion (slow test below: 50 episodes)."""
    env = make(task)
    solver = make_solver(env)
    assert rollout_success(env, solver.act, range(100, 110)) >= 0.9
    assert rollout_success(env, seeded_random_policy(env, 0), range(100, 120)) <= 0.1


@pytest.mark.slow
@pytest.mark.parametrize("task", TASK_IDS)
def test_scripted_solver_50_episodes(task):
    env = make(task)
    solver = make_solver(env)
    seeds = range(1000, 1050)
    assert rollout_success(env, solver.act, seeds) >= 0.9
    assert rollout_success(env, seeded_random_policy(env, 1), seeds) <= 0.1


@pytest.mark.parametrize("task", TASK_IDS)
def test_solver_with_ee_control(task):
    env = make(task, control_mode="pd_ee_delta_pos")
    assert env.action_space.shape[-1] == 4
    assert rollout_success(env, make_solver(env).act, range(200, 205)) >= 0.8


def _step_once(task, mode):
    env = gym.make(task, control_mode=mode)
    env.action_space.seed(0)
    try:
        env.reset(seed=0)
        obs, r, *_ = env.step(env.action_space.sample())
        assert obs.shape == (1, FLAT_OBS_DIM) and torch.isfinite(obs).all()
        return tuple(env.unwrapped.agent.supported_control_modes)
    finally:
        env.close()


def test_all_panda_control_modes_step():
    """The base class accepts every Panda controller (checked on one task: the arm is shared)."""
    for mode in PANDA_CONTROL_MODES:
        assert _step_once(TASK_IDS[0], mode) == PANDA_CONTROL_MODES


@pytest.mark.parametrize("task", TASK_IDS)
@pytest.mark.parametrize("mode", ["pd_joint_pos", "pd_ee_delta_pose", "pd_joint_vel"])
def test_other_control_modes_step(task, mode):
    _step_once(task, mode)


BAD_KWARGS = [
    (dict(robot_uids="fetch"), "'fetch'"),
    (dict(control_mode="pd_teleport"), "'pd_teleport'"),
    (dict(obs_mode="bogus"), "'bogus'"),
    (dict(reward_mode="shaped"), "'shaped'"),
    (dict(robot_init_qpos_noise=-0.5), "-0.5"),
    (dict(num_envs=0), "num_envs=0"),
    (dict(sim_backend="physx_cpu", num_envs=2), "num_envs=2"),
    (dict(sim_backend="tpu"), "'tpu'"),
    (dict(render_mode="movie"), "'movie'"),
]


@pytest.mark.parametrize("task", TASK_IDS)
@pytest.mark.parametrize("kwargs,named", BAD_KWARGS, ids=[next(iter(k)) + "=" + str(next(iter(k.values()))) for k, _ in BAD_KWARGS])
def test_bad_input_one_line_error(task, kwargs, named):
    with pytest.raises(ValueError) as err:
        gym.make(task, **kwargs)
    msg = str(err.value)
    assert named in msg and "\n" not in msg


@pytest.mark.parametrize("task", TASK_IDS)
@pytest.mark.parametrize("kwargs", [dict(obs_mode="rgb"), dict(obs_mode="rgbd")])
def test_no_render_device_error(task, kwargs):
    from maniskill_dualher.tasks.common import render_device_available

    if render_device_available():
        pytest.skip("this machine has a render device")
    with pytest.raises(ValueError, match="render device") as err:
        gym.make(task, **kwargs)
    assert "\n" not in str(err.value) and repr(next(iter(kwargs.values()))) in str(err.value)


@pytest.mark.parametrize("task", TASK_IDS)
def test_rgb_array_render_mode_simulates_without_device_and_refuses_a_frame(task):
    """ManiSkill's tools ask for render_mode="rgb_array" by default: the env builds, resets and steps without a
    render device, and only render() (a frame) raises, in one line naming the mode."""
    from maniskill_dualher.tasks.common import render_device_available

    if render_device_available():
        pytest.skip("this machine has a render device")
    env = gym.make(task, render_mode="rgb_array")
    try:
        env.reset(seed=0)
        obs, *_ = env.step(env.action_space.sample())
        assert obs.shape[-1] > 0
        with pytest.raises(ValueError, match="render device") as err:
            env.render()
        assert "\n" not in str(err.value) and "'rgb_array'" in str(err.value)
    finally:
        env.close()


def test_solver_rejects_unsupported_control_mode():
    env = make("ReachTarget-v1", control_mode="pd_joint_vel")
    with pytest.raises(ValueError, match="'pd_joint_vel'"):
        make_solver(env)


@pytest.mark.parametrize("task", TASK_IDS)
def test_set_state_restores_observation(task):
    """Cached task state (e.g. ReachTarget's ball positions) follows env.set_state like the sim does."""
    env = make(task)
    base = env.unwrapped
    obs_a, _ = env.reset(seed=5)
    state_a = base.get_state()
    obs_b, _ = env.reset(seed=6)
    assert not torch.equal(obs_a, obs_b)
    base.set_state(state_a)
    torch.testing.assert_close(base.get_obs(), obs_a)


def _move_goal(base, delta):
    """Move the task's desired goal by ``delta`` without touching anything the goal does not define."""
    if hasattr(base, "_ball_pos"):  # ReachTarget: the red ball is the goal
        base._ball_pos[:, 0] += delta
    elif hasattr(base, "_desired_cache"):  # hinged tasks: the panel's closed free-edge point
        base._desired_cache = base._desired_cache + delta
    else:
        pytest.fail(f"{type(base).__name__}: teach _move_goal how to move this task's desired goal")


@pytest.mark.parametrize("task", TASK_IDS)
def test_observation_does_not_contain_the_desired_goal(task):
    """Hindsight relabeling rewrites only the desired_goal slots: no observation slot may carry the goal."""
    env = make(task)
    base = env.unwrapped
    env.reset(seed=3)
    for _ in range(2):
        env.step(env.action_space.sample())
    before = base.get_obs(base.get_info())
    _move_goal(base, torch.tensor([0.07, -0.05, 0.03]))
    after = base.get_obs(base.get_info())
    o0, _, d0 = split_goal_obs(before)
    o1, _, d1 = split_goal_obs(after)
    assert not torch.allclose(d0, d1), "the desired goal moved"
    torch.testing.assert_close(o1, o0, rtol=0, atol=0)
    env.reset(seed=3)  # restore a consistent state for the cached env
