"""Scripted (privileged-state) solvers for the Panda goal tasks.

``make_solver(env)`` returns a solver with ``act(obs) -> action`` (batched torch ``(N, action_dim)``) for
the env's control mode. Task solvers subclass :class:`TcpWaypointSolver` and only say where the TCP
should go next (``target_tcp(obs) -> (N, 3)`` world frame); the base turns that into an action:

* ``pd_ee_delta_pos`` / ``pd_ee_delta_pose``: the Cartesian step itself (in the robot base frame);
* ``pd_joint_delta_pos`` / ``pd_joint_pos``: a damped-least-squares step on the Panda's TCP Jacobian
  (``pytorch_kinematics``, batched on CPU or GPU; no render device needed), holding the gripper pointing
  down (``target_quat``), scaled into the controller's action range.

The gripper is kept closed (``gripper_closed``). Register a solver with ``@register_solver(EnvClass)``.
"""
from __future__ import annotations

import os
from contextlib import redirect_stderr, redirect_stdout
from typing import Optional

import numpy as np
import torch

from mani_skill.utils.geometry import rotation_conversions as rc

from .common import FLAT_OBS_DIM, OBS_SLICES, split_goal_obs

SOLVERS: dict = {}  # env class -> solver class
DOWN_QUAT = (0.0, 1.0, 0.0, 0.0)  # TCP orientation (wxyz) at the Panda rest pose: fingers pointing down
_JOINT_MODES = ("pd_joint_delta_pos", "pd_joint_pos")
_EE_MODES = ("pd_ee_delta_pos", "pd_ee_delta_pose")
SUPPORTED_SOLVER_CONTROL_MODES = _JOINT_MODES + _EE_MODES


def register_solver(env_cls):
    """Class decorator: ``@register_solver(CloseBoxEnv) class CloseBoxSolver(TcpWaypointSolver): ...``."""
    def deco(solver_cls):
        SOLVERS[env_cls] = solver_cls
        return solver_cls
    return deco


def make_solver(env, **kwargs):
    """The scripted solver registered for this env's task class (wrappers are looked through)."""
    base = env.unwrapped
    for cls in type(base).__mro__:
        if cls in SOLVERS:
            return SOLVERS[cls](base, **kwargs)
    raise ValueError(f"task={type(base).__name__!r} has no scripted solver; known: {[c.__name__ for c in SOLVERS]}")


class TcpWaypointSolver:
    """Base solver: subclasses implement ``target_tcp(obs)``; this class makes the action.

    ``obs`` is the flat ``(N, OBS_DIM + 6)`` state (torch or numpy), the ``state_dict`` dict, or None
    (then it is read from the env). Subclasses may also read privileged state from ``self.env``.
    """

    gripper_closed = True
    max_cartesian_step = 0.1  # m; clips the position error so the linearisation stays valid
    rot_weight = 0.5  # weight of the orientation error against the position error (m per rad)
    damping = 0.05  # damped-least-squares lambda
    hold_orientation = True

    def __init__(self, env):
        self.env = env.unwrapped
        self.device = self.env.device
        self.control_mode = self.env.control_mode
        if self.control_mode not in SUPPORTED_SOLVER_CONTROL_MODES:
            raise ValueError(f"control_mode={self.control_mode!r} is not supported by the scripted solver; "
                             f"use one of {SUPPORTED_SOLVER_CONTROL_MODES}")
        controller = self.env.agent.controller
        self._arm = controller.controllers["arm"]
        self._arm_slice = slice(*controller.action_mapping["arm"])
        self._grip_slice = slice(*controller.action_mapping["gripper"])
        space = self.env.single_action_space
        self._low = torch.as_tensor(space.low, device=self.device, dtype=torch.float32)
        self._high = torch.as_tensor(space.high, device=self.device, dtype=torch.float32)
        self.action_dim = int(space.shape[0])
        self._down = torch.tensor(DOWN_QUAT, device=self.device, dtype=torch.float32)
        if self.control_mode in _JOINT_MODES:
            import pytorch_kinematics as pk

            with open(self.env.agent.urdf_path, "rb") as f:
                urdf = f.read()
            with open(os.devnull, "w") as null, redirect_stderr(null), redirect_stdout(null):  # pk warns about URDF tags
                self._chain = pk.build_serial_chain_from_urdf(urdf, end_link_name=self.env.agent.ee_link_name)
            self._chain = self._chain.to(device=self.device, dtype=torch.float32)
            self._n_arm = len(self._chain.get_joint_parameter_names())

    # ------------------------------------------------------------------ subclass API
    def reset(self):
        """Called at episode start; override if the solver keeps per-episode state."""

    def target_tcp(self, obs: torch.Tensor) -> torch.Tensor:
        """Where the TCP should go next, (N, 3) world frame."""
        raise NotImplementedError

    def target_quat(self, obs: torch.Tensor) -> Optional[torch.Tensor]:
        """Desired TCP orientation (N, 4) wxyz world frame, or None for position-only control."""
        if not self.hold_orientation:
            return None
        return self._down.expand(obs.shape[0], 4)

    # ------------------------------------------------------------------ action
    def _flat_obs(self, obs) -> torch.Tensor:
        if obs is None:
            info = self.env.get_info()
            obs = self.env._get_obs_state_dict(info)
        if isinstance(obs, dict):
            obs = torch.cat([torch.as_tensor(obs[k]) for k in ("observation", "achieved_goal", "desired_goal")], -1)
        obs = torch.as_tensor(np.asarray(obs) if not isinstance(obs, torch.Tensor) else obs,
                              device=self.device, dtype=torch.float32)
        return obs.reshape(-1, FLAT_OBS_DIM)

    def _base_rotation_inv(self, n: int) -> torch.Tensor:
        q = self.env.agent.robot.pose.q.to(self.device)
        return rc.quaternion_invert(q).expand(n, 4)

    def act(self, obs=None) -> torch.Tensor:
        obs = self._flat_obs(obs)
        n = obs.shape[0]
        o, _, _ = split_goal_obs(obs)
        tcp = o[:, OBS_SLICES["tcp_pose"]]
        pos_err = self.target_tcp(obs).to(torch.float32) - tcp[:, :3]
        norm = torch.linalg.norm(pos_err, dim=-1, keepdim=True).clamp_min(1e-9)
        pos_err = pos_err * torch.clamp(self.max_cartesian_step / norm, max=1.0)
        inv_base = self._base_rotation_inv(n)
        pos_err_base = rc.quaternion_apply(inv_base, pos_err)

        action = torch.zeros((n, self.action_dim), device=self.device, dtype=torch.float32)
        if self.control_mode in _EE_MODES:
            upper = float(np.max(np.abs(np.broadcast_to(self._arm.config.pos_upper, 3))))
            step = pos_err_base / upper
            step = step / torch.clamp(step.abs().amax(-1, keepdim=True), min=1.0)  # keep the direction
            action[:, self._arm_slice.start:self._arm_slice.start + 3] = step
        else:
            q = o[:, OBS_SLICES["qpos"]][:, :self._n_arm]
            dq = self._dls_step(q, pos_err_base, tcp[:, 3:], inv_base, obs)
            if self.control_mode == "pd_joint_delta_pos":
                cfg = self._arm.config
                dq = dq / torch.clamp(dq.abs().amax(-1, keepdim=True) / cfg.upper, min=1.0)
                arm = (dq - cfg.lower) / (cfg.upper - cfg.lower) * 2 - 1 if cfg.normalize_action else dq
            else:  # pd_joint_pos: absolute joint targets
                arm = q + dq
            action[:, self._arm_slice] = arm
        grip = self._low if self.gripper_closed else self._high
        action[:, self._grip_slice] = grip[self._grip_slice]
        return torch.max(torch.min(action, self._high), self._low)

    def _dls_step(self, q, pos_err_base, tcp_quat, inv_base, obs) -> torch.Tensor:
        """Joint step dq = J^T (J J^T + lambda^2 I)^-1 e for the (position[, orientation]) error e."""
        jac = self._chain.jacobian(q)  # (N, 6, n_arm), base frame, at the TCP
        quat = self.target_quat(obs)
        if quat is None:
            jac, err = jac[:, :3], pos_err_base
        else:
            q_err = rc.quaternion_multiply(quat.to(torch.float32), rc.quaternion_invert(tcp_quat))
            q_err = rc.standardize_quaternion(q_err)  # shortest rotation
            rot_err = rc.quaternion_apply(inv_base, rc.quaternion_to_axis_angle(q_err))
            jac = torch.cat([jac[:, :3], self.rot_weight * jac[:, 3:]], dim=1)
            err = torch.cat([pos_err_base, self.rot_weight * rot_err], dim=-1)
        jjt = jac @ jac.transpose(1, 2)
        eye = torch.eye(jjt.shape[-1], device=self.device, dtype=jjt.dtype)
        return (jac.transpose(1, 2) @ torch.linalg.solve(jjt + self.damping ** 2 * eye, err.unsqueeze(-1))).squeeze(-1)


# ---------------------------------------------------------------------- task solvers
from .reach_target import ReachTargetEnv  # noqa: E402


@register_solver(ReachTargetEnv)
class ReachTargetSolver(TcpWaypointSolver):
    """Go straight to the red ball (the desired goal)."""

    def target_tcp(self, obs):
        return split_goal_obs(obs)[2]


from .close_box import CloseBoxEnv  # noqa: E402


@register_solver(CloseBoxEnv)
class CloseBoxSolver(TcpWaypointSolver):
    """Push the lid's outer face shut: stand off in front of it, then sweep the push point down its arc.

    Stateless, from the observation only: the lid pose (origin on the hinge axis at the inner face, x
    along the lid, z = outer normal) and the hinge angle. With the TCP at (u, w) in the lid frame
    (distance along the lid, height above its inner face) it is engaged when ``|u - PUSH_RADIUS| <
    engage_du`` and ``0 < w < engage_w``; engaged, it aims at the push point rotated ``lead`` rad further
    shut (so it keeps pressing, down to 0.15 rad past closed), otherwise at the stand-off point
    ``standoff`` m off the outer face.
    """

    standoff = 0.07
    engage_du = 0.035
    engage_w = 0.09
    lead = 0.35  # rad
    press_w = 0.005  # target height above the lid's inner face while pushing (inside the lid: keep pressing)

    def __init__(self, env, **kwargs):
        super().__init__(env, **kwargs)
        self.push_radius = float(type(self.env).PUSH_RADIUS)

    def target_tcp(self, obs):
        o = split_goal_obs(obs)[0]
        lid = o[:, OBS_SLICES["object_pose"]]
        lid_p, lid_q = lid[:, :3], lid[:, 3:]
        tcp = rc.quaternion_apply(rc.quaternion_invert(lid_q), o[:, OBS_SLICES["tcp_pose"]][:, :3] - lid_p)
        u, w = tcp[:, 0], tcp[:, 2]
        engaged = ((u - self.push_radius).abs() < self.engage_du) & (w > 0) & (w < self.engage_w)
        angle = o[:, OBS_SLICES["joint_qpos"]][:, 0]
        d = torch.where(engaged, torch.clamp(angle + 0.15, max=self.lead), torch.zeros_like(angle))
        wt = torch.where(engaged, torch.full_like(d, self.press_w), torch.full_like(d, self.standoff))
        r = self.push_radius
        # (r, 0, wt) turned about the lid's +y axis by d (= closing by d), in the lid frame
        local = torch.stack([r * torch.cos(d) + wt * torch.sin(d), torch.zeros_like(d),
                             -r * torch.sin(d) + wt * torch.cos(d)], dim=-1)
        return lid_p + rc.quaternion_apply(lid_q, local)


from .close_microwave import CloseMicrowaveEnv  # noqa: E402


@register_solver(CloseMicrowaveEnv)
class CloseMicrowaveSolver(TcpWaypointSolver):
    """Push the door's outer face shut: stand off in front of its middle, then sweep that point along its arc.

    Stateless, from the observation only: the door pose (origin on the vertical hinge axis at the bottom of
    the door's outer face, x = inward normal, y along the door towards the free edge) and the hinge angle.
    With the TCP at u along the door and w out from its outer face, it is engaged when ``|u - PUSH_RADIUS| <
    engage_du``, ``0 < w < engage_w`` and the TCP is within ``engage_dz`` of ``push_height``; engaged, it
    aims at the push point rotated ``lead`` rad further shut (so it keeps pressing, down to 0.08 rad past
    closed), otherwise at the stand-off point ``standoff`` m out from it. The fingers point down and the
    palm is turned parallel to the door (joint control), so its 20 cm width never meets the door edge-on.
    The engagement window is wide and the lead large so that it also closes the door when every other
    action is random (the generic reward test mixes solver and random steps).
    """

    push_height = 0.13  # TCP z; door spans z in [0.01, 0.176], palm bottom ~TCP + 0.034
    contact_w = 0.0  # aim at the outer face itself while pushing (the fingers' thickness presses it)
    standoff = 0.03
    engage_du = 0.06
    engage_w = contact_w + standoff + 0.06
    engage_dz = 0.06
    lead = 0.6  # rad
    max_cartesian_step = 0.3  # m; larger joint steps (the joint-step limit still applies)

    def __init__(self, env, **kwargs):
        super().__init__(env, **kwargs)
        self.push_radius = float(type(self.env).PUSH_RADIUS)

    def target_tcp(self, obs):
        o = split_goal_obs(obs)[0]
        door = o[:, OBS_SLICES["object_pose"]]
        door_p, door_q = door[:, :3], door[:, 3:]
        tcp_w = o[:, OBS_SLICES["tcp_pose"]][:, :3]
        tcp = rc.quaternion_apply(rc.quaternion_invert(door_q), tcp_w - door_p)
        u, w = tcp[:, 1], -tcp[:, 0]
        engaged = ((u - self.push_radius).abs() < self.engage_du) & (w > 0) & (w < self.engage_w) \
            & ((tcp_w[:, 2] - self.push_height).abs() < self.engage_dz)
        angle = o[:, OBS_SLICES["joint_qpos"]][:, 0]
        d = torch.where(engaged, torch.clamp(angle + 0.08, max=self.lead), torch.zeros_like(angle))
        wt = torch.where(engaged, torch.full_like(d, self.contact_w),
                         torch.full_like(d, self.contact_w + self.standoff))
        r = self.push_radius
        # (-wt, r) turned about the door's vertical z axis by -d (= closing by d), in the door frame
        local = torch.stack([-wt * torch.cos(d) + r * torch.sin(d), wt * torch.sin(d) + r * torch.cos(d),
                             torch.zeros_like(d)], dim=-1)
        target = door_p + rc.quaternion_apply(door_q, local)
        target[:, 2] = self.push_height
        return target

    def target_quat(self, obs):
        """Fingers down, palm parallel to the door: the rest orientation turned by the door's yaw."""
        door_q = split_goal_obs(obs)[0][:, OBS_SLICES["object_pose"]][:, 3:]
        return rc.quaternion_multiply(door_q, self._down.expand(obs.shape[0], 4))
