"""What CloseBox and CloseMicrowave share: a shell fixed on the table with one panel (a lid, a door) on a
revolute hinge, both built from primitive collision boxes with ManiSkill's articulation builder.

A task subclasses :class:`HingedPanelEnv`, sets the hinge and randomization constants below and
describes its geometry in ``_geometry()`` (:class:`HingedGeometry`). This base then builds the
articulation (visuals only when the scene can render), places it at reset (centre x/y and yaw
uniform, hinge angle uniform, at rest), caches the desired goal per episode (the body moves only at
reset), reads the panel pose once per step in ``evaluate()`` and reuses it for the goal, the dense
reward and the observation, and fills the observation slots (panel pose; hinge angle and velocity).
The success test is the common one: the panel's free-edge point within ``goal_tolerance`` of where it
is when closed, with ``goal_tolerance = 2 L sin(SUCCESS_ANGLE / 2)`` so that it means "angle below
SUCCESS_ANGLE".
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import List, Optional, Sequence, Tuple

import numpy as np
import sapien
import torch

from mani_skill.utils.structs import Pose

from .common import FLAT_OBS_DIM, GOAL_DIM, OBS_DIM, OBS_SLICES, PandaGoalEnv, transform_points
from .lean import transform_point32

# observation slots the lean step fills (tasks/lean.py)
_OBJ = OBS_SLICES["object_pose"]
_OBJ_P, _OBJ_Q = slice(_OBJ.start, _OBJ.start + 3), slice(_OBJ.start + 3, _OBJ.stop)
_JOINT_QPOS, _JOINT_QVEL, _DISTRACTORS = OBS_SLICES["joint_qpos"], OBS_SLICES["joint_qvel"], OBS_SLICES["distractor_pos"]
_ACHIEVED, _DESIRED = slice(OBS_DIM, OBS_DIM + GOAL_DIM), slice(OBS_DIM + GOAL_DIM, FLAT_OBS_DIM)
Part = Tuple[Sequence[float], Sequence[float]]  # (centre, half size), metres, in the link's frame


@dataclass
class HingedGeometry:
    name: str                      # articulation name
    body_name: str
    panel_name: str
    joint_name: str
    body_parts: List[Part]
    panel_parts: List[Part]
    hinge_in_body: sapien.Pose     # joint frame in the body frame (joint axis = frame x-axis)
    hinge_in_panel: sapien.Pose    # joint frame in the panel frame
    free_edge_panel: Sequence[float]       # achieved-goal point, panel frame
    push_panel: Sequence[float]            # dense-reward reaching point, panel frame
    closed_free_edge_body: Sequence[float]  # desired-goal point (free edge when closed), body frame
    body_color: Sequence[float]
    panel_color: Sequence[float]
    parked_pose: sapien.Pose       # where the articulation waits until the first reset places it
    panel_density: Optional[float] = None  # None: SAPIEN's default
    # (mass, centre-of-mass pose, principal inertia) overriding the panel's computed ones, or None
    panel_mass_inertia: Optional[Tuple[float, sapien.Pose, Sequence[float]]] = field(default=None)


class HingedPanelEnv(PandaGoalEnv):
    """Base of the hinge-closing tasks (not registered itself)."""

    HINGE_LIMITS: Tuple[float, float]
    HINGE_DAMPING: float
    HINGE_FRICTION: float
    BODY_LIFT: float               # body origin height above the table
    CENTER_X_RANGE: Tuple[float, float]
    CENTER_Y_RANGE: Tuple[float, float]
    YAW_RANGE: Tuple[float, float]
    INIT_ANGLE_RANGE: Tuple[float, float]
    SUCCESS_ANGLE = 0.1
    ANGLE_INFO_KEY = "hinge_angle"  # name of the hinge angle in ``info``

    def _geometry(self) -> HingedGeometry:
        raise NotImplementedError

    # ------------------------------------------------------------------ scene
    def _load_scene(self, options: dict):
        super()._load_scene(options)
        g = self._geometry()
        render = self.scene.can_render()
        builder = self.scene.create_articulation_builder()
        body = builder.create_link_builder()
        body.set_name(g.body_name)
        panel = builder.create_link_builder(body)
        panel.set_name(g.panel_name)
        for link, parts, color, density in ((body, g.body_parts, g.body_color, None),
                                             (panel, g.panel_parts, g.panel_color, g.panel_density)):
            material = sapien.render.RenderMaterial(base_color=list(color)) if render else None
            for centre, half in parts:
                kw = {} if density is None else {"density": density}
                link.add_box_collision(sapien.Pose(list(centre)), list(half), **kw)
                if render:
                    link.add_box_visual(sapien.Pose(list(centre)), list(half), material=material)
        if g.panel_mass_inertia is not None:
            panel.set_mass_and_inertia(*g.panel_mass_inertia)
        panel.set_joint_name(g.joint_name)
        panel.set_joint_properties(
            "revolute",
            limits=[list(self.HINGE_LIMITS)],
            pose_in_parent=g.hinge_in_body,
            pose_in_child=g.hinge_in_panel,
            damping=self.HINGE_DAMPING,
        )
        builder.initial_pose = g.parked_pose
        self.articulation = builder.build(name=g.name, fix_root_link=True)
        self.hinge = self.articulation.active_joints_map[g.joint_name]
        self.hinge.set_friction(self.HINGE_FRICTION)  # the builder's friction argument is ignored
        self.panel = self.articulation.links_map[g.panel_name]

        def point(xyz):
            return torch.tensor(list(xyz), dtype=torch.float32, device=self.device)

        self._free_edge_local = point(g.free_edge_panel)
        self._free_edge_local_list = self._free_edge_local.tolist()  # for the lean step
        self._push_local = point(g.push_panel)
        self._closed_free_edge_body = point(g.closed_free_edge_body)
        # The body only moves in _initialize_episode / set_state_dict: the desired goal (N, 3) is cached
        # there. Replaced, never written in place, so goal tensors handed out earlier (info) keep their values.
        self._desired_cache = torch.zeros((self.num_envs, 3), device=self.device)
        self._panel_pose_at_eval = None

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        super()._initialize_episode(env_idx, options)
        with torch.device(self.device):
            b = len(env_idx)

            def uniform(lo_hi, n):
                lo, hi = lo_hi
                return lo + (hi - lo) * torch.rand(n)

            p = torch.full((b, 3), self.BODY_LIFT)
            p[:, 0] = uniform(self.CENTER_X_RANGE, b)
            p[:, 1] = uniform(self.CENTER_Y_RANGE, b)
            yaw = uniform(self.YAW_RANGE, b)
            q = torch.zeros((b, 4))
            q[:, 0] = torch.cos(yaw / 2)
            q[:, 3] = torch.sin(yaw / 2)
            self.articulation.set_pose(Pose.create_from_pq(p=p, q=q))
            cache = self._desired_cache.clone()
            cache[env_idx] = transform_points(torch.cat([p, q], dim=-1), self._closed_free_edge_body)
            self._desired_cache = cache
            angle = uniform(self.INIT_ANGLE_RANGE, b)
            self.articulation.set_qpos(angle[:, None])
            self.articulation.set_qvel(torch.zeros((b, 1)))

    def set_state_dict(self, state: dict, env_idx: torch.Tensor = None):
        super().set_state_dict(state, env_idx)
        self._refresh_goal_cache()

    def _refresh_goal_cache(self):
        """Recompute the cached desired goal from the body pose (call after moving the body by hand)."""
        self._desired_cache = transform_points(self.articulation.pose.raw_pose, self._closed_free_edge_body)

    # ------------------------------------------------------------------ goals and evaluation
    def _achieved_goal(self) -> torch.Tensor:
        # One panel-pose read per step (evaluate() runs first), shared with the observation and the reward.
        self._panel_pose_at_eval = self.panel.pose.raw_pose
        return transform_points(self._panel_pose_at_eval, self._free_edge_local)

    def _desired_goal(self) -> torch.Tensor:
        return self._desired_cache

    def push_point(self) -> torch.Tensor:
        """(N, 3) the dense reward's reaching point on the panel's outer face, world frame (as of evaluate())."""
        pose = self._panel_pose_at_eval
        return transform_points(self.panel.pose.raw_pose if pose is None else pose, self._push_local)

    def _evaluate_extra(self) -> dict:
        return {self.ANGLE_INFO_KEY: self.articulation.qpos[:, 0].clone()}

    def _lean_task_parts(self, obs, fused):
        pose = self.panel._objs[0].entity_pose
        p, q = pose.p, pose.q
        obs[_OBJ_P], obs[_OBJ_Q] = p, q
        art = self.articulation._objs[0]
        obs[_JOINT_QPOS], obs[_JOINT_QVEL] = art.qpos[:1], art.qvel[:1]
        obs[_DISTRACTORS] = 0.0
        obs[_ACHIEVED] = transform_point32(p.tolist() + q.tolist(), self._free_edge_local_list, fused)
        obs[_DESIRED] = self._desired_cache.numpy()[0]

    # ------------------------------------------------------------------ observations
    def _object_pose(self) -> torch.Tensor:
        # The panel pose read in this step's evaluate(), which runs before every observation.
        pose = self._panel_pose_at_eval
        return self.panel.pose.raw_pose if pose is None else pose

    def _joint_state(self) -> torch.Tensor:
        return torch.cat([self.articulation.qpos[:, :1], self.articulation.qvel[:, :1]], dim=-1)

    # ------------------------------------------------------------------ rewards
    def _dense_shaping(self, info: dict) -> torch.Tensor:
        tcp = getattr(self, "tcp_pose_at_eval", None)
        tcp = self.agent.tcp.pose.raw_pose if tcp is None else tcp
        reach = torch.linalg.norm(tcp[:, :3] - self.push_point(), dim=-1)
        return 0.5 * (1.0 - torch.tanh(10.0 * reach))


def chord_tolerance(length: float, success_angle: float) -> float:
    """The free-edge displacement of a panel ``length`` long turned by ``success_angle``: 2 L sin(angle / 2)."""
    return float(2 * length * np.sin(success_angle / 2))
