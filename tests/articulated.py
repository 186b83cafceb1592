"""Helpers shared by the hinge-task tests (CloseBox, CloseMicrowave): make a task's env (and a module fixture
of it), set a hinge task's state, read contacts."""
import gymnasium as gym
import numpy as np
import pytest
import torch

from mani_skill.utils.structs import Pose

CONTROL_MODE = "pd_joint_delta_pos"


def make_env(env_id: str):
    """The hinge tests' env: ``gym.make(env_id)`` (CPU, one env) with joint-delta control."""
    return gym.make(env_id, control_mode=CONTROL_MODE)


def env_fixture(env_id: str):
    """A module-scoped ``env`` fixture of ``make_env(env_id)``; bind it in the test module as ``env = ...``."""
    @pytest.fixture(scope="module", name="env")
    def _env():
        e = make_env(env_id)
        yield e
        e.close()
    return _env


def robot_contact_force(env, art) -> float:
    """Largest contact force between any robot link and any link of ``art`` (N)."""
    base = env.unwrapped
    forces = [torch.linalg.norm(base.scene.get_pairwise_contact_forces(link, part), dim=-1).max()
              for link in base.agent.robot.links for part in art.links]
    return float(torch.stack(forces).max())


def set_state(env, angle=None, center=None, yaw=None) -> None:
    """Overwrite a hinge task's hinge angle and/or body pose in the current (CPU, single) episode; a moved
    body gets its desired goal re-cached, as a reset would."""
    base = env.unwrapped
    art = base.articulation
    if center is not None:
        yaw = 0.0 if yaw is None else yaw
        p = torch.tensor([[center[0], center[1], base.BODY_LIFT]], dtype=torch.float32)
        q = torch.tensor([[np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]], dtype=torch.float32)
        art.set_pose(Pose.create_from_pq(p=p, q=q))
        base._refresh_goal_cache()
    if angle is not None:
        art.set_qpos(torch.tensor([[angle]], dtype=torch.float32))
        art.set_qvel(torch.zeros((1, 1)))


def goals_at_angle(env, angle: float, seed: int = 4):
    """Reset with ``seed``, set the hinge to ``angle`` and evaluate: ``(info, achieved_goal, desired_goal)``,
    the goals of the (single) env as (3,) tensors."""
    env.reset(seed=seed)
    set_state(env, angle=angle)
    info = env.unwrapped.evaluate()
    return info, info["achieved_goal"][0], info["desired_goal"][0]
