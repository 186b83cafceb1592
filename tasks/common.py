"""Shared base of the three Panda goal tasks: one observation layout, one 3-D goal space, one reward.

Every task (ReachTarget-v1, CloseBox-v1, CloseMicrowave-v1) subclasses :class:`PandaGoalEnv`, so the
flat ``obs_mode="state"`` vector has the same width and slot meaning everywhere:

``[observation (OBS_DIM = 40) | achieved_goal (3) | desired_goal (3)]``  (46 floats)

=========  =====  ===========================================================================
slots      width  meaning
=========  =====  ===========================================================================
0:9        9      Panda qpos (7 arm joints, 2 finger joints)
9:18       9      Panda qvel
18:25      7      TCP pose (``panda_hand_tcp``): position xyz, quaternion wxyz
25:32      7      task object pose, position xyz + quaternion wxyz (CloseBox: lid; CloseMicrowave:
                  door; ReachTarget: zeros, its target ball *is* the desired goal)
32         1      task joint qpos (hinge angle, rad; 0 for ReachTarget)
33         1      task joint qvel (rad/s; 0 for ReachTarget)
34:40      6      two distractor positions xyz (ReachTarget: magenta, pink ball; zeros if none)
40:43      3      achieved_goal (task-specific 3-D point, e.g. the TCP for ReachTarget)
43:46      3      desired_goal (where that point must be for success)
=========  =====  ===========================================================================

No observation slot holds the desired goal: hindsight relabeling rewrites only the ``desired_goal``
part, so a relabeled transition must not see the real goal elsewhere (``tests/test_tasks.py`` moves
each task's goal and checks the observation slots stay put). The hinged tasks observe the panel (what
the achieved goal measures), never its closed position.

``obs_mode="state_dict"`` returns ``{"observation", "achieved_goal", "desired_goal"}`` with the same
content. All poses are world frame (table top at z = 0, robot base at x = -0.615).

Reward modes (``reward_mode=``):

* ``sparse`` (default): 1.0 where ``||achieved - desired||^2 < goal_tolerance^2`` else 0.0 (float32).
  :meth:`PandaGoalEnv.compute_reward` reproduces it bit-exactly from stored goals (same float32 ops).
* ``dense``: ``1 - tanh(5 * ||achieved - desired||) + task shaping`` (shaping in ``[0, 1)``, e.g. TCP
  reaching the part to push), and ``DENSE_REWARD_MAX = 2`` on success.
* ``normalized_dense``: ``dense / DENSE_REWARD_MAX`` in ``[0, 1]``.

``info`` (from ``evaluate()``) holds ``success`` (bool), ``goal_distance`` (m), ``achieved_goal``,
``desired_goal`` and ``tcp_pose`` (N, 7) plus task extras; ManiSkill reports ``terminated = success``; the training loop ends
episodes on it when ``RunConfig.terminate_on_success`` (the paper), or ignores it (fixed-length episodes).

There is no render device on the development machines: scenes are built from collision shapes;
visual shapes are added only if ``scene.can_render()`` (see :func:`build_primitive`). Camera observations
without a render device raise one clear ``ValueError`` at construction; ``render_mode="rgb_array"`` is
accepted and ``render()`` raises it only when a frame is asked for; ``render_backend``
defaults to "none" there (ManiSkill's default "gpu" would fail inside Vulkan).

Everything is batched over ``num_envs`` (torch tensors on ``self.device``), so ``physx_cuda`` with
many environments runs the same code as the one-env-per-process CPU simulation.
"""
from __future__ import annotations

import functools
from typing import Any, Optional, Sequence, Union

import numpy as np
import sapien
import torch

from mani_skill.agents.robots import Panda
from mani_skill.envs.sapien_env import BaseEnv
from mani_skill.envs.utils.observations import parse_obs_mode_to_struct
from mani_skill.sensors.camera import CameraConfig
from mani_skill.utils import sapien_utils
from mani_skill.utils.scene_builder.table import TableSceneBuilder
from mani_skill.utils.structs import Actor, Pose

GOAL_DIM = 3
OBS_SLOTS = (  # (name, width) in order; the single source of the observation layout
    ("qpos", 9),
    ("qvel", 9),
    ("tcp_pose", 7),
    ("object_pose", 7),
    ("joint_qpos", 1),
    ("joint_qvel", 1),
    ("distractor_pos", 6),
)
OBS_DIM = sum(w for _, w in OBS_SLOTS)  # 40
OBS_SLICES = {}
_start = 0
for _name, _w in OBS_SLOTS:
    OBS_SLICES[_name] = slice(_start, _start + _w)
    _start += _w
del _start, _name, _w
FLAT_OBS_DIM = OBS_DIM + 2 * GOAL_DIM

DEFAULT_MAX_EPISODE_STEPS = 150
DEFAULT_CONTROL_MODE = "pd_joint_delta_pos"
DENSE_REWARD_MAX = 2.0
ROBOT_BASE_POSE = sapien.Pose(p=[-0.615, 0, 0])

# The Panda's controllers in ManiSkill 3.0.1 (tests check this against agent.supported_control_modes).
PANDA_CONTROL_MODES = (
    "pd_joint_delta_pos", "pd_joint_pos", "pd_ee_delta_pos", "pd_ee_delta_pose", "pd_ee_pose",
    "pd_joint_target_delta_pos", "pd_ee_target_delta_pos", "pd_ee_target_delta_pose",
    "pd_joint_vel", "pd_joint_pos_vel", "pd_joint_delta_pos_vel",
)
STATE_OBS_MODES = ("state", "state_dict", "none")
RENDER_MODES = ("human", "rgb_array", "sensors", "all")
REWARD_MODES = ("sparse", "dense", "normalized_dense", "none")
SIM_BACKENDS = ("auto", "cpu", "physx_cpu", "cuda", "gpu", "physx_cuda")


def registered_task_ids() -> list:
    """Ids of all registered ManiSkill envs built on :class:`PandaGoalEnv` (import ``tasks`` first)."""
    from mani_skill.utils.registration import REGISTERED_ENVS

    return sorted(k for k, spec in REGISTERED_ENVS.items()
                  if isinstance(spec.cls, type) and issubclass(spec.cls, PandaGoalEnv))


def episode_length(env) -> Optional[int]:
    """Time limit of a gym.make'd ManiSkill env (its TimeLimitWrapper keeps it, not ``env.spec``)."""
    while env is not None:
        steps = getattr(env, "_max_episode_steps", None)
        if steps is not None:
            return int(steps)
        env = getattr(env, "env", None)
    return None


def transform_points(raw_pose: torch.Tensor, local: torch.Tensor) -> torch.Tensor:
    """World positions of points given in a body frame: ``p + R(q) @ local`` for raw poses (N, 7) wxyz.

    ``local`` is (3,) or (N, 3). A few elementwise ops; ~10x cheaper than ManiSkill's ``Pose * Pose``.
    """
    p, w, u = raw_pose[..., :3], raw_pose[..., 3:4], raw_pose[..., 4:7]
    local = torch.as_tensor(local, dtype=raw_pose.dtype, device=raw_pose.device).expand_as(p)
    t = 2.0 * torch.linalg.cross(u, local, dim=-1)
    return p + local + w * t + torch.linalg.cross(u, t, dim=-1)


def split_goal_obs(x):
    """Split a flat state observation (..., OBS_DIM + 6) into (observation, achieved_goal, desired_goal).

    Works on numpy arrays and torch tensors with any leading dims; returns views (no copies).
    """
    if x.shape[-1] != FLAT_OBS_DIM:
        raise ValueError(f"observation width {x.shape[-1]} is not OBS_DIM + 2 * GOAL_DIM = {FLAT_OBS_DIM}")
    return x[..., :OBS_DIM], x[..., OBS_DIM:OBS_DIM + GOAL_DIM], x[..., OBS_DIM + GOAL_DIM:]


def goal_distance_sq(achieved_goal, desired_goal):
    """Squared goal distance with explicit elementwise float ops.

    Written out (not ``norm``) so that torch and numpy, CPU and GPU, any batch shape, give bit-identical
    results: the sparse reward and :meth:`PandaGoalEnv.compute_reward` both go through here.
    """
    d = achieved_goal - desired_goal
    sq = d * d
    return (sq[..., 0] + sq[..., 1]) + sq[..., 2]


@functools.lru_cache(maxsize=None)
def render_device_available() -> bool:
    """Whether SAPIEN finds a device it can render with (cheap probe, cached per process)."""
    try:
        sapien.render.get_device_summary()
        return True
    except RuntimeError:
        return False


def check_range(name: str, value, low=None, high=None):
    """Raise a one-line ValueError naming ``name=value`` unless ``low <= value <= high``."""
    try:
        ok = (low is None or value >= low) and (high is None or value <= high)
    except TypeError:
        ok = False
    if not ok:
        raise ValueError(f"{name}={value!r} is out of range [{low}, {high}]")
    return value


def build_primitive(
    scene,
    name: str,
    shape: str,
    size: Union[float, Sequence[float]],
    color: Sequence[float] = (0.5, 0.5, 0.5, 1.0),
    body_type: str = "kinematic",
    collision: bool = True,
    initial_pose: Optional[sapien.Pose] = None,
    density: float = 1000.0,
) -> Actor:
    """Build a box or sphere actor that works without a render device.

    ``shape``: "box" (``size`` = half sizes xyz) or "sphere" (``size`` = radius). ``collision=False``
    gives a pure marker (no contact, e.g. goal balls the arm must pass through). The visual shape is
    only added when the scene can render: ManiSkill's ``build_box``/``build_sphere`` crash otherwise.
    ``body_type``: "kinematic" (movable by set_pose, unaffected by contact), "static" or "dynamic".
    """
    builder = scene.create_actor_builder()
    material = None
    if scene.can_render():
        material = sapien.render.RenderMaterial(base_color=list(color))
    if shape == "box":
        if collision:
            builder.add_box_collision(half_size=list(size), density=density)
        if material is not None:
            builder.add_box_visual(half_size=list(size), material=material)
    elif shape == "sphere":
        if collision:
            builder.add_sphere_collision(radius=float(size), density=density)
        if material is not None:
            builder.add_sphere_visual(radius=float(size), material=material)
    else:
        raise ValueError(f"shape={shape!r} is not 'box' or 'sphere'")
    builder.initial_pose = initial_pose if initial_pose is not None else sapien.Pose()
    if body_type == "kinematic":
        return builder.build_kinematic(name=name)
    if body_type == "static":
        return builder.build_static(name=name)
    if body_type == "dynamic":
        return builder.build(name=name)
    raise ValueError(f"body_type={body_type!r} is not 'kinematic', 'static' or 'dynamic'")


def _validate_env_args(cls_name: str, robot_uids, num_envs, obs_mode, reward_mode, control_mode,
                       render_mode, sim_backend, render_backend, robot_init_qpos_noise) -> str:
    """Check constructor arguments up front; return the render backend to use.

    ManiSkill itself answers bad values with asserts, multi-line RuntimeErrors or (without a render
    device) an opaque Vulkan error deep in scene setup; these are one line each, naming the value.
    """
    if robot_uids != "panda":
        raise ValueError(f"robot_uids={robot_uids!r} is not supported by {cls_name}; only 'panda' is")
    if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
        raise ValueError(f"num_envs={num_envs!r} must be a positive int")
    if not isinstance(sim_backend, str) or sim_backend.split(":")[0] not in SIM_BACKENDS:
        raise ValueError(f"sim_backend={sim_backend!r} is not one of {SIM_BACKENDS}")
    if sim_backend in ("cpu", "physx_cpu") and num_envs > 1:
        raise ValueError(f"num_envs={num_envs} needs sim_backend='physx_cuda'; CPU simulation is one env per process")
    if reward_mode is not None and reward_mode not in REWARD_MODES:
        raise ValueError(f"reward_mode={reward_mode!r} is not one of {REWARD_MODES}")
    if control_mode is not None and control_mode not in PANDA_CONTROL_MODES:
        raise ValueError(f"control_mode={control_mode!r} is not a Panda control mode {PANDA_CONTROL_MODES}")
    check_range("robot_init_qpos_noise", robot_init_qpos_noise, 0.0, 0.2)

    can_render = render_device_available() if render_backend != "none" else False
    if obs_mode is not None and obs_mode not in STATE_OBS_MODES:
        try:
            struct = parse_obs_mode_to_struct(obs_mode)
        except Exception:
            raise ValueError(f"obs_mode={obs_mode!r} is unknown; use one of {STATE_OBS_MODES} "
                             "(camera modes need a render device)") from None
        visual = any(vars(struct.visual).values()) if struct.visual is not None else False
        if visual and not can_render:
            raise ValueError(f"obs_mode={obs_mode!r} needs cameras but no render device was found; "
                             f"use one of {STATE_OBS_MODES}")
    if render_mode is not None:
        if render_mode not in RENDER_MODES:
            raise ValueError(f"render_mode={render_mode!r} is not one of {RENDER_MODES} or None")
        # no device: accepted here (ManiSkill's tools ask for "rgb_array" by default); render() refuses a frame
    if render_backend is None:  # auto: render where possible, else simulate only
        return "gpu" if render_device_available() else "none"
    if render_backend != "none" and not render_device_available():
        raise ValueError(f"render_backend={render_backend!r} needs a render device but none was found; use 'none'")
    return render_backend


class PandaGoalEnv(BaseEnv):
    """Base of the goal-conditioned Panda tabletop tasks (not registered itself).

    Subclasses build their objects in ``_load_scene`` (call ``super()._load_scene(options)`` first for
    the table), place them in ``_initialize_episode`` (call super first for the table and robot), and
    provide:

    * ``goal_tolerance`` (float, metres): success is ``||achieved - desired|| < goal_tolerance``;
    * ``GOAL_BOX_LOW``/``GOAL_BOX_HIGH`` (xyz, metres, world frame): documented box holding every
      desired goal at reset (the tests check it over many seeds);
    * ``_achieved_goal()`` and ``_desired_goal()`` -> ``(N, 3)`` torch tensors (called from
      ``evaluate()``, where ``self.tcp_pose_at_eval`` already holds this step's raw TCP pose (N, 7));
    * ``_object_pose()`` -> ``(N, 7)``; optionally ``_joint_state()`` -> ``(N, 2)`` (qpos, qvel) and
      ``_distractor_positions()`` -> ``(N, 6)`` (zeros by default); all float32 on ``self.device``.
      These run every step: cache what only changes at reset (see ReachTarget) and prefer
      :func:`transform_points` over ``Pose * Pose`` (ManiSkill's quaternion product is slow);
    * optionally ``_dense_shaping(info)`` -> ``(N,)`` in ``[0, 1)`` added to the dense reward,
      and ``_evaluate_extra()`` -> dict merged into ``info``.
    """

    SUPPORTED_ROBOTS = ["panda"]
    SUPPORTED_REWARD_MODES = ("sparse", "dense", "normalized_dense", "none")  # sparse is the default
    agent: Panda
    goal_tolerance: float = 0.05
    success_text: str = ""   # what success means, in words (a model card's "success is ..."; cards.success_text)
    GOAL_BOX_LOW: Optional[tuple] = None
    GOAL_BOX_HIGH: Optional[tuple] = None

    def __init__(self, *args, robot_uids="panda", robot_init_qpos_noise=0.02, num_envs=1,
                 obs_mode=None, reward_mode=None, control_mode=None, render_mode=None,
                 sim_backend="auto", render_backend=None, **kwargs):
        if control_mode is None:
            control_mode = DEFAULT_CONTROL_MODE
        render_backend = _validate_env_args(
            type(self).__name__, robot_uids, num_envs, obs_mode, reward_mode, control_mode,
            render_mode, sim_backend, render_backend, robot_init_qpos_noise)
        self.robot_init_qpos_noise = float(robot_init_qpos_noise)
        self._goal_tol_sq = float(np.float32(self.goal_tolerance) ** 2)
        self._lean = None  # tasks.lean.LeanStep, built at the first tasks.lean.lean_step(self, ...)
        super().__init__(*args, robot_uids=robot_uids, num_envs=num_envs, obs_mode=obs_mode,
                         reward_mode=reward_mode, control_mode=control_mode, render_mode=render_mode,
                         sim_backend=sim_backend, render_backend=render_backend, **kwargs)

    # ------------------------------------------------------------------ scene
    @property
    def _default_sensor_configs(self):
        if self.backend.render_device is None:  # cameras cannot exist without a render device
            return []
        pose = sapien_utils.look_at(eye=[0.3, 0, 0.6], target=[-0.1, 0, 0.1])
        return [CameraConfig("base_camera", pose=pose, width=128, height=128, fov=np.pi / 2, near=0.01, far=100)]

    @property
    def _default_human_render_camera_configs(self):
        if self.backend.render_device is None:
            return []
        pose = sapien_utils.look_at([0.6, 0.7, 0.6], [0.0, 0.0, 0.35])
        return CameraConfig("render_camera", pose=pose, width=512, height=512, fov=1, near=0.01, far=100)

    def render(self):
        """A frame, where a render device exists; without one, a ValueError only when a frame is asked for, so
        tools that pass render_mode="rgb_array" by default (ManiSkill's replay_trajectory) still simulate."""
        if self.render_mode is not None and self.backend.render_device is None:
            raise ValueError(f"render_mode={self.render_mode!r}: no render device was found, so no frame can be "
                             "drawn (simulation works; use render_mode=None)")
        return super().render()

    def _load_agent(self, options: dict):
        super()._load_agent(options, ROBOT_BASE_POSE)

    def _load_scene(self, options: dict):
        self.table_scene = TableSceneBuilder(env=self, robot_init_qpos_noise=self.robot_init_qpos_noise)
        self.table_scene.build()

    def _initialize_episode(self, env_idx: torch.Tensor, options: dict):
        self.table_scene.initialize(env_idx)

    # ------------------------------------------------------------------ task hooks
    def _achieved_goal(self) -> torch.Tensor:
        raise NotImplementedError

    def _desired_goal(self) -> torch.Tensor:
        raise NotImplementedError

    def _object_pose(self) -> torch.Tensor:
        raise NotImplementedError

    def _joint_state(self) -> torch.Tensor:
        return torch.zeros((self.num_envs, 2), device=self.device)

    def _distractor_positions(self) -> torch.Tensor:
        return torch.zeros((self.num_envs, 6), device=self.device)

    def _dense_shaping(self, info: dict) -> torch.Tensor:
        return torch.zeros((self.num_envs,), device=self.device)

    def _evaluate_extra(self) -> dict:
        return {}

    def _lean_task_parts(self, obs: np.ndarray, fused: bool) -> None:
        """The lean step's task slots, bit-identical to the torch hooks above: write ``object_pose``,
        ``joint_qpos``, ``joint_qvel``, ``distractor_pos`` (``OBS_SLICES``) and both goals into ``obs`` (the
        float32 row (FLAT_OBS_DIM,), its robot and TCP slots already filled from this step's state).
        ``fused`` goes to ``tasks.lean.transform_point32``. Not implemented: such a task takes ManiSkill's
        step (``tasks.lean.unsupported_reason``)."""
        raise NotImplementedError

    # ------------------------------------------------------------------ evaluate
    def evaluate(self):
        """Success iff the achieved goal is within goal_tolerance of the desired goal.

        The goals (and the TCP pose) go into ``info`` so the observation reuses exactly the tensors the
        reward saw.
        """
        # One TCP read per step, shared by the goals (via self.tcp_pose_at_eval) and the observation.
        self.tcp_pose_at_eval = self.agent.tcp.pose.raw_pose
        achieved = self._achieved_goal().to(torch.float32)
        desired = self._desired_goal().to(torch.float32)
        dist_sq = goal_distance_sq(achieved, desired)
        info = dict(
            success=dist_sq < self._goal_tol_sq,
            goal_distance=torch.sqrt(dist_sq),
            achieved_goal=achieved,
            desired_goal=desired,
            tcp_pose=self.tcp_pose_at_eval,
        )
        info.update(self._evaluate_extra())
        return info

    # ------------------------------------------------------------------ observations
    def _observation(self, info: Optional[dict] = None) -> torch.Tensor:
        """The (N, OBS_DIM) task observation in the OBS_SLOTS order (reuses info's TCP pose if given)."""
        robot = self.agent.robot
        tcp = info.get("tcp_pose") if info is not None else None
        parts = [
            robot.get_qpos(),
            robot.get_qvel(),
            tcp if tcp is not None else self.agent.tcp.pose.raw_pose,
            self._object_pose(),
            self._joint_state(),
            self._distractor_positions(),
        ]
        return torch.cat(parts, dim=-1)  # hooks return float32 (N, width); no per-part casts (step cost)

    def _get_obs_state_dict(self, info: dict):
        # Insertion order = flattening order: [observation | achieved_goal | desired_goal].
        return dict(observation=self._observation(info), achieved_goal=info["achieved_goal"].clone(),
                    desired_goal=info["desired_goal"].clone())

    def _get_obs_extra(self, info: dict):  # used by camera obs modes (render device only)
        return dict(achieved_goal=info["achieved_goal"], desired_goal=info["desired_goal"])

    # ------------------------------------------------------------------ rewards
    def compute_reward(self, achieved_goal, desired_goal, info: Optional[dict] = None):
        """GoalEnv-style batched sparse reward: 1.0 where within goal_tolerance, else 0.0 (float32).

        Accepts torch tensors or numpy arrays of shape (..., 3) and returns the same kind with shape (...,).
        Bit-identical to the env's sparse reward for the goals it stored in the observation.
        """
        if isinstance(achieved_goal, torch.Tensor):
            desired_goal = torch.as_tensor(desired_goal, device=achieved_goal.device)
            return (goal_distance_sq(achieved_goal.to(torch.float32), desired_goal.to(torch.float32))
                    < self._goal_tol_sq).to(torch.float32)
        ag = np.asarray(achieved_goal, dtype=np.float32)
        dg = np.asarray(desired_goal, dtype=np.float32)
        return (goal_distance_sq(ag, dg) < np.float32(self._goal_tol_sq)).astype(np.float32)

    def compute_sparse_reward(self, obs: Any, action: torch.Tensor, info: dict):
        return info["success"].to(torch.float32)

    def compute_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        reward = 1.0 - torch.tanh(5.0 * info["goal_distance"]) + self._dense_shaping(info)
        return torch.where(info["success"], torch.full_like(reward, DENSE_REWARD_MAX), reward)

    def compute_normalized_dense_reward(self, obs: Any, action: torch.Tensor, info: dict):
        return self.compute_dense_reward(obs=obs, action=action, info=info) / DENSE_REWARD_MAX
