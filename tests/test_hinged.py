"""What every hinge-closing task gets from tasks.hinged.HingedPanelEnv: the per-episode desired-goal cache,
one panel-pose read per step shared by goal, observation and reward, and the hinge in the observation."""
import gymnasium as gym
import pytest
import torch

import maniskill_dualher  # noqa: F401  (registers the tasks)
from tasks.common import OBS_SLICES, split_goal_obs, transform_points
from tasks.hinged import HingedPanelEnv

HINGED = ["CloseBox-v1", "CloseMicrowave-v1"]


@pytest.fixture(scope="module", params=HINGED)
def env(request):
    e = gym.make(request.param, control_mode="pd_joint_delta_pos")
    assert isinstance(e.unwrapped, HingedPanelEnv)
    yield e
    e.close()


def test_cached_desired_goal_follows_the_body(env):
    """The desired goal is cached at reset; it must equal the closed free edge of the body where it stands."""
    base = env.unwrapped
    firsts = []
    for seed in (9, 10):
        obs, info = env.reset(seed=seed)
        first = info["desired_goal"].clone()
        for _ in range(5):
            obs, _, _, _, info = env.step(env.action_space.sample())
        assert torch.equal(info["desired_goal"], first), "the desired goal is constant within an episode"
        assert torch.equal(split_goal_obs(obs)[2], first)
        body = transform_points(base.articulation.pose.raw_pose, base._closed_free_edge_body)
        torch.testing.assert_close(first, body, atol=1e-6, rtol=0)
        firsts.append(first)
    assert not torch.equal(*firsts), "a new episode places the body elsewhere"


def test_goal_observation_and_info_read_the_same_step(env):
    base = env.unwrapped
    env.reset(seed=3)
    for _ in range(3):
        obs, _, _, _, info = env.step(env.action_space.sample())
        o, achieved, _ = split_goal_obs(obs)
        panel = base.panel.pose.raw_pose
        torch.testing.assert_close(o[:, OBS_SLICES["object_pose"]], panel, atol=0, rtol=0)
        torch.testing.assert_close(achieved, transform_points(panel, base._free_edge_local), atol=0, rtol=0)
        angle = base.articulation.qpos[:, 0]
        torch.testing.assert_close(info[base.ANGLE_INFO_KEY], angle, atol=0, rtol=0)
        torch.testing.assert_close(o[:, OBS_SLICES["joint_qpos"]][:, 0], angle, atol=0, rtol=0)
