"""ReachTarget-v1: move the Panda's TCP to the red ball, ignoring two distractor balls (RLBench's reach_target)."""
from __future__ import annotations

import torch

from mani_skill.utils.registration import register_env
from mani_skill.utils.structs import Pose

from .common import (DEFAULT_MAX_EPISODE_STEPS, FLAT_OBS_DIM, GOAL_DIM, OBS_DIM, OBS_SLICES, PandaGoalEnv,
                     build_primitive)


@register_env("ReachTarget-v1", max_episode_steps=DEFAULT_MAX_EPISODE_STEPS)
class ReachTargetEnv(PandaGoalEnv):
    """
    **Task Description:**
    Move the Panda's tool centre point (TCP, between the fingers) to the red ball. A magenta and a pink
    ball are distractors. The balls are markers without collision, so the arm never gets blocked.

    **Randomizations:**
    - the three ball centres are sampled uniformly in the box ``BALL_BOX_LOW``..``BALL_BOX_HIGH``
      (x in [-0.25, 0.10], y in [-0.25, 0.25], z in [0.05, 0.35] m; world frame, robot base at x = -0.615,
      table top at z = 0), all reachable by the Panda;
    - ball centres are at least ``MIN_BALL_SEPARATION`` (0.10 m) apart, so a TCP within tolerance of the red
      ball is never within tolerance of a distractor, and the red ball is at least ``MIN_START_DISTANCE``
      (0.25 m) from the TCP's rest position, so no episode starts solved and a random policy rarely
      touches it (~2% of episodes; rejection sampling, batched);
    - the robot's rest joint angles get Gaussian noise (``robot_init_qpos_noise``, default 0.02 rad).

    **Observation slots** (``maniskill_dualher.tasks.common.OBS_SLOTS``): robot qpos/qvel, TCP pose, the two distractor
    positions. ``object_pose`` and the joint slots are zeros: the red ball's position *is* the desired goal
    and lives only in ``desired_goal``, so a hindsight-relabeled goal never contradicts the observation.

    **Success Conditions:**
    - the TCP is within ``goal_tolerance`` = 0.05 m of the red ball centre
      (achieved_goal = TCP position, desired_goal = red ball position).
    """

    goal_tolerance = 0.05
    success_text = f"the gripper's tool centre point (TCP) within {goal_tolerance:g} m of the red ball"
    BALL_RADIUS = 0.02
    BALL_BOX_LOW = (-0.25, -0.25, 0.05)
    BALL_BOX_HIGH = (0.10, 0.25, 0.35)
    GOAL_BOX_LOW, GOAL_BOX_HIGH = BALL_BOX_LOW, BALL_BOX_HIGH
    MIN_BALL_SEPARATION = 0.10
    MIN_START_DISTANCE = 0.25
    REST_TCP_POS = (0.0, 0.0, 0.170)  # TCP at the noiseless Panda rest pose (measured; qpos noise moves it a few cm)
    _MAX_SAMPLING_ROUNDS = 100

    def _load_scene(self, options: dict):
        super()._load_scene(options)
        colors = {"target": (1, 0, 0, 1), "distractor_magenta": (1, 0, 1, 1), "distractor_pink": (1, 0.6, 0.7, 1)}
        self.balls = [
            build_primitive(self.scene, name, "sphere", self.BALL_RADIUS, color, body_type="kinematic",
                            collision=False)
            for name, color in colors.items()
        ]
        self.target = self.balls[0]
        # The balls only move in _initialize_episode / set_state_dict: cache their centres (N, 3 balls, 3)
        # so observations and goals need not read actor poses every step (a third of the step cost).
        self._ball_pos = torch.zeros((self.num_envs, 3, 3), device=self.device)
        self._no_object = torch.zeros((self.num_envs, 7), device=self.device)

    def _refresh_ball_cache(self):
        self._ball_pos = torch.stack([ball.pose.p for ball in self.balls], dim=1).to(torch.float32)

    def _sample_ball_positions(self, b: int) -> torch.Tensor:
        """(b, 3 balls, 3) centres satisfying the separation rules, by batched rejection sampling."""
        low = torch.tensor(self.BALL_BOX_LOW, device=self.device)
        high = torch.tensor(self.BALL_BOX_HIGH, device=self.device)
        rest = torch.tensor(self.REST_TCP_POS, device=self.device)
        pairs = [(0, 1), (0, 2), (1, 2)]
        pos = low + torch.rand((b, 3, 3), device=self.device) * (high - low)
        for _ in range(self._MAX_SAMPLING_ROUNDS):
            bad = torch.linalg.norm(pos[:, 0] - rest, dim=-1) < self.MIN_START_DISTANCE
            for i, j in pairs:
                bad |= torch.linalg.norm(pos[:, i] - pos[:, j], dim=-1) < self.MIN_BALL_SEPARATION
            if not bool(bad.any()):
                return pos
            fresh = low + torch.rand((b, 3, 3), device=self.device) * (high - low)
            pos = torch.where(bad[:, None, None], fresh, pos)
        raise RuntimeError("could not place the ReachTarget balls; the bounding box is too small")

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        with torch.device(self.device):
            super()._initialize_episode(env_idx, options)
            pos = self._sample_ball_positions(len(env_idx))
            for k, ball in enumerate(self.balls):
                ball.set_pose(Pose.create_from_pq(p=pos[:, k], q=[1, 0, 0, 0]))
            self._ball_pos[env_idx] = pos

    def set_state_dict(self, state: dict, env_idx: torch.Tensor = None):
        super().set_state_dict(state, env_idx)
        self._refresh_ball_cache()

    def _achieved_goal(self):
        return self.tcp_pose_at_eval[:, :3]

    def _desired_goal(self):
        return self._ball_pos[:, 0]

    def _object_pose(self):
        return self._no_object  # the target is the desired goal: not observed here (no HER inconsistency)

    def _distractor_positions(self):
        return self._ball_pos[:, 1:].reshape(self.num_envs, 6)

    def _lean_task_parts(self, obs, fused):
        balls = self._ball_pos.numpy()[0]  # (3 balls, 3): target, two distractors
        obs[_NO_OBJECT] = 0.0  # object_pose, joint_qpos, joint_qvel: the target is the desired goal
        obs[_DISTRACTORS] = balls[1:].reshape(6)
        obs[_ACHIEVED] = obs[_TCP_P]
        obs[_DESIRED] = balls[0]


# observation slots the lean step fills (tasks/lean.py)
_NO_OBJECT = slice(OBS_SLICES["object_pose"].start, OBS_SLICES["joint_qvel"].stop)
_DISTRACTORS = OBS_SLICES["distractor_pos"]
_TCP_P = slice(OBS_SLICES["tcp_pose"].start, OBS_SLICES["tcp_pose"].start + 3)
_ACHIEVED, _DESIRED = slice(OBS_DIM, OBS_DIM + GOAL_DIM), slice(OBS_DIM + GOAL_DIM, FLAT_OBS_DIM)
