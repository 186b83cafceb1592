"""Helpers shared by the hinge-task tests (CloseBox, CloseMicrowave): poke an articulation's state, read contacts."""
import numpy as np
import torch

from mani_skill.utils.structs import Pose


def set_articulation_state(art, lift: float, angle=None, center=None, yaw=None) -> None:
    """Overwrite the hinge angle and/or the root pose (xy centre, yaw; z = lift) of a single CPU env."""
    if center is not None:
        yaw = 0.0 if yaw is None else yaw
        p = torch.tensor([[center[0], center[1], lift]], dtype=torch.float32)
        q = torch.tensor([[np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)]], dtype=torch.float32)
        art.set_pose(Pose.create_from_pq(p=p, q=q))
    if angle is not None:
        art.set_qpos(torch.tensor([[angle]], dtype=torch.float32))
        art.set_qvel(torch.zeros((1, 1)))


def robot_contact_force(env, art) -> float:
    """Largest contact force between any robot link and any link of ``art`` (N)."""
    base = env.unwrapped
    forces = [torch.linalg.norm(base.scene.get_pairwise_contact_forces(link, part), dim=-1).max()
              for link in base.agent.robot.links for part in art.links]
    return float(torch.stack(forces).max())
