"""The lean env step: one CPU env (``physx_cpu``, ``num_envs=1``) stepped without ManiSkill's generic per-step
Python, with the same bits: :func:`lean_step` (``env`` a :class:`PandaGoalEnv`; this module builds on
``tasks/common.py``, which does not import it).

ManiSkill's ``env.step`` spends more time around PhysX's substeps than in them (CPU B, CloseMicrowave:
0.87 ms a step, 0.33 ms of it physics): one-element torch tensors, ``to_tensor`` conversions, per-joint drive
targets through property setters, a dict of ``info`` and a flatten. :class:`LeanStep` does the same work on
numpy arrays read straight from SAPIEN's objects:

1. the action (8,) in the policy's normalized units is clipped and scaled per controller exactly as
   ``clip_and_scale_action`` does (``0.5 (high + low) + 0.5 (high - low) * clip(a)``, float32, constants taken
   from the controllers' own tensors); the arm's targets are ``qpos + delta`` (``pd_joint_delta_pos``), the
   gripper's mimic joint follows its control joint (``x * multiplier + offset``); all nine drive targets are
   written in one loop over the raw SAPIEN joints;
2. PhysX steps ``sim_steps_per_control`` times (``scene.px.step()``, as ``scene.step()`` does);
3. the observation, goals, success and sparse reward are computed once from one read of each pose/joint
   array, in the same float32 operations as :meth:`PandaGoalEnv.evaluate` and ``_observation`` (the only
   non-trivial one, :func:`transform_points`, is matched below, fused multiply-add included).

What it skips: ``info`` (the caller gets success only), the ``OrderEnforcing``/``TimeLimit`` wrappers (the
caller reads ``elapsed_steps``) and the controllers' bookkeeping attributes (``_start_qpos``, ``_step``),
which this controller recomputes from scratch on every ManiSkill step, so the two paths can be mixed.
:func:`unsupported_reason` lists when it does not apply (then callers use ManiSkill's step).
``tests/test_lean_step.py`` holds both paths to bit-identical observations, rewards, terminations,
simulator states and drive targets over long random and scripted-solver rollouts, each in a fresh process.
"""
from __future__ import annotations

import functools
from array import array
from typing import Optional, Tuple

import numpy as np
import torch

from .common import FLAT_OBS_DIM, GOAL_DIM, OBS_DIM, OBS_SLICES, PandaGoalEnv

F32 = np.float32
QPOS, QVEL = OBS_SLICES["qpos"], OBS_SLICES["qvel"]
_tcp = OBS_SLICES["tcp_pose"]
TCP_P, TCP_Q = slice(_tcp.start, _tcp.start + 3), slice(_tcp.start + 3, _tcp.stop)
ACHIEVED, DESIRED = slice(OBS_DIM, OBS_DIM + GOAL_DIM), slice(OBS_DIM + GOAL_DIM, FLAT_OBS_DIM)
LEAN_CONTROL_MODE = "pd_joint_delta_pos"


# ------------------------------------------------------------------ transform_points on floats, same bits
# One point per step: Python floats holding float32 values are ~6x faster than numpy on 3-vectors. Each
# float32 operation is the float64 one rounded to float32 (exact for + - *: float64 has >= 2 * 24 + 2 bits).
_F = array("f", [0.0])


def _r32(x: float) -> float:
    _F[0] = x
    return _F[0]


def fma32(a: float, b: float, c: float) -> float:
    """``a * b + c`` with one rounding to float32 (as a hardware fused multiply-add), for float32 values.

    ``a * b`` is exact in float64; the float64 sum then rounds once more, which can break a float32 tie the
    wrong way only when it lands exactly halfway between two float32s: then TwoSum's error decides."""
    p = a * b
    s = p + c
    r = _r32(s)
    if s != r:
        m = 2.0 * s - r  # the other float32 neighbour if s is a midpoint (exact)
        if _r32(m) == m:
            bb = s - p
            err = (p - (s - bb)) + (c - bb)
            if err != 0.0:
                return max(r, m) if err > 0 else min(r, m)
    return r


def _sub32(a: float, b: float, c: float) -> float:
    """``a * b + c`` rounded twice: the product, then the sum (torch's cross without FMA)."""
    return _r32(_r32(a * b) + c)


def cross32(u, v, fused: bool):
    """``torch.linalg.cross(u, v)`` of float32 3-vectors (float lists): torch computes each component
    ``a1 * b2 - a2 * b1`` as ``fma(a1, b2, -(a2 * b1))`` where its kernels use FMA, plainly elsewhere."""
    ux, uy, uz = u
    vx, vy, vz = v
    f = fma32 if fused else _sub32
    return [f(uy, vz, -_r32(uz * vy)), f(uz, vx, -_r32(ux * vz)), f(ux, vy, -_r32(uy * vx))]


@functools.lru_cache(maxsize=None)
def torch_cross_fused() -> Optional[bool]:
    """Whether ``torch.linalg.cross`` rounds like :func:`cross32` with ``fused`` True or False on this
    machine (None: like neither); decided once per process on inputs where the two differ."""
    rng = np.random.default_rng(12345)
    u = rng.normal(size=(2048, 3)).astype(F32)
    v = rng.normal(size=(2048, 3)).astype(F32)
    ref = torch.linalg.cross(torch.from_numpy(u), torch.from_numpy(v), dim=-1).numpy()
    for fused in (True, False):
        got = np.array([cross32(a, b, fused) for a, b in zip(u.tolist(), v.tolist())], F32)
        if np.array_equal(got, ref):
            return fused
    return None


def transform_point32(raw_pose, local, fused: bool):
    """:func:`tasks.common.transform_points` for one pose (7 floats, wxyz) and one point (3 floats), same
    bits: ``p + local + w * t + u x t`` with ``t = 2 u x local``; returns 3 floats (float32 values)."""
    w, u = raw_pose[3], raw_pose[4:7]
    t = [_r32(2.0 * c) for c in cross32(u, local, fused)]
    d = cross32(u, t, fused)
    return [_r32(_r32(_r32(p + l) + _r32(w * ti)) + di) for p, l, ti, di in zip(raw_pose[:3], local, t, d)]


# ------------------------------------------------------------------ when it applies
# PandaGoalEnv's per-task hooks whose values the lean step takes from ``_lean_task_parts`` instead
TASK_HOOKS = ("_achieved_goal", "_desired_goal", "_object_pose", "_joint_state", "_distractor_positions")


def _owner(cls, name):
    return next(c for c in cls.__mro__ if name in vars(c))


def unsupported_reason(env) -> Optional[str]:
    """Why ``env`` (a :class:`PandaGoalEnv`, unwrapped) cannot take the lean step, or None if it can.

    It covers what training uses: one CPU env, state observations, sparse (or no) reward, the default
    ``pd_joint_delta_pos`` controller without interpolation or target accumulation, and no subclass hook
    that ManiSkill's step would call (``_before_control_step`` etc.)."""
    from mani_skill.agents.base_agent import BaseAgent
    from mani_skill.agents.controllers.pd_joint_pos import PDJointPosController, PDJointPosMimicController
    from mani_skill.envs.sapien_env import BaseEnv

    if not isinstance(env, PandaGoalEnv):
        return "not a PandaGoalEnv"
    if env.gpu_sim_enabled or env.num_envs != 1:
        return "not one CPU env"
    if env.obs_mode != "state":
        return f"obs_mode={env.obs_mode!r} (lean: 'state')"
    if env.reward_mode not in ("sparse", "none"):
        return f"reward_mode={env.reward_mode!r} (lean: 'sparse', 'none')"
    if env.control_mode != LEAN_CONTROL_MODE:
        return f"control_mode={env.control_mode!r} (lean: {LEAN_CONTROL_MODE!r})"
    for hook in ("step", "_step_action", "get_info", "get_obs", "get_reward", "_before_control_step",
                 "_after_control_step", "_before_simulation_step", "_after_simulation_step"):
        if getattr(type(env), hook) is not getattr(BaseEnv, hook):
            return f"the env overrides {hook}"
    for hook in ("evaluate", "_observation", "_get_obs_state_dict", "compute_sparse_reward"):
        if getattr(type(env), hook) is not getattr(PandaGoalEnv, hook):
            return f"the task overrides {hook}"
    # the task's lean hook must be at least as derived as every hook whose result it reproduces
    lean_owner = _owner(type(env), "_lean_task_parts")
    for hook in TASK_HOOKS:
        if not issubclass(lean_owner, _owner(type(env), hook)):
            return f"{_owner(type(env), hook).__name__}.{hook} is newer than its _lean_task_parts"
    agent = env.agent
    if type(agent).set_action is not BaseAgent.set_action or \
            type(agent).before_simulation_step is not BaseAgent.before_simulation_step:
        return "the agent overrides set_action/before_simulation_step"
    ctrl = getattr(agent.controller, "controllers", None)
    if ctrl is None or list(ctrl) != ["arm", "gripper"]:
        return "the controller is not arm + gripper"
    arm, grip = ctrl["arm"], ctrl["gripper"]
    if type(arm) is not PDJointPosController or type(grip) is not PDJointPosMimicController:
        return "the controllers are not PDJointPos (arm) + PDJointPosMimic (gripper)"
    if not (arm.config.use_delta and not arm.config.use_target and not grip.config.use_delta):
        return "the controllers are not delta (arm) + absolute (gripper) targets"
    for c in (arm, grip):
        if c.config.interpolate or not c._normalize_action:
            return "a controller interpolates or takes unnormalized actions"
    if torch_cross_fused() is None:
        return "torch's cross product rounds like neither cross32 variant on this machine"
    return None


def lean_step(env, action: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray, int]:
    """ManiSkill's ``step`` of ``env`` (a :class:`PandaGoalEnv`, unwrapped; one CPU env) without its generic
    per-step overhead, with the same bits. ``action`` (1, A) or (A,) float32 in [-1, 1]; returns (obs (1, D)
    float32, reward (1,) float32, terminated = success (1,) bool, elapsed steps). No ``info``; no wrappers: the
    caller applies the time limit. Raises ValueError where :func:`unsupported_reason` names a reason. The
    env keeps its :class:`LeanStep` (``env._lean``), rebuilt after a reconfiguration."""
    lean = env._lean
    if lean is None or lean.scene is not env.scene:  # first call, or the scene was reconfigured
        lean = env._lean = LeanStep(env)
    return lean.step(action)


class LeanStep:
    """One env's lean step (built for one scene; :func:`lean_step` rebuilds it after a reconfiguration). Task
    specifics come from the env's ``_lean_task_parts(obs, fused)`` hook."""

    def __init__(self, env):
        reason = unsupported_reason(env)
        if reason is not None:
            raise ValueError(f"lean step unsupported: {reason}")
        self.env = env
        self.scene = env.scene
        self.fused = torch_cross_fused()
        agent = env.agent
        arm, grip = agent.controller.controllers["arm"], agent.controller.controllers["gripper"]
        self.robot = agent.robot._objs[0]
        self.tcp = agent.tcp._objs[0]
        # drive targets in the order ManiSkill sets them: arm joints, then gripper joints
        self.joints = [j._objs[0] for j in arm.joints] + [j._objs[0] for j in grip.joints]
        self.n_arm, self.n_grip = len(arm.joints), len(grip.joints)
        self.arm_idx = arm.active_joint_indices.cpu().numpy()
        a0, a1 = agent.controller.action_mapping["arm"]
        g0, g1 = agent.controller.action_mapping["gripper"]
        if (a0, a1, g0) != (0, self.n_arm, self.n_arm):
            raise ValueError(f"lean step unsupported: action layout arm {a0}:{a1}, gripper {g0}:{g1}")
        self.act_dim = g1

        def scale(c):  # clip_and_scale_action's two constants, computed as it computes them (float32 torch)
            lo, hi = c.action_space_low, c.action_space_high
            return (0.5 * (hi + lo)).cpu().numpy(), (0.5 * (hi - lo)).cpu().numpy()

        (am, ah), (gm, gh) = scale(arm), scale(grip)
        self.mid, self.half = np.concatenate([am, gm]), np.concatenate([ah, gh])
        # gripper joints (after the arm's): control joints take the scaled action, mimic joints follow
        self.grip_ctrl = self.n_arm + grip.control_joint_indices.cpu().numpy().reshape(-1).astype(np.int64)
        self.grip_mimic = self.n_arm + grip.mimic_joint_indices.cpu().numpy().reshape(-1).astype(np.int64)
        self.grip_src = self.n_arm + grip.mimic_control_joint_indices.cpu().numpy().reshape(-1).astype(np.int64)
        self.grip_mult = grip._multiplier.cpu().numpy()
        self.grip_off = grip._offset.cpu().numpy()
        self.substeps = int(env._sim_steps_per_control)
        self.tol_sq = F32(env._goal_tol_sq)
        self.reward_none = env.reward_mode == "none"

    def targets(self, action: np.ndarray) -> np.ndarray:
        """The drive targets (arm joints, then gripper joints) ManiSkill's controllers compute for ``action``
        (A,) float32 at the current qpos."""
        if np.isnan(action).any():  # as BaseAgent.set_action
            raise ValueError("Action cannot be NaN. Environment received:", action)
        scaled = self.mid + self.half * np.minimum(np.maximum(action, -1), 1)  # clip_and_scale_action
        out = np.empty(self.n_arm + self.n_grip, F32)
        out[:self.n_arm] = self.robot.qpos[self.arm_idx] + scaled[:self.n_arm]
        out[self.grip_ctrl] = scaled[self.n_arm:]
        out[self.grip_mimic] = out[self.grip_src] * self.grip_mult + self.grip_off
        return out

    def step(self, action: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """``action`` (1, A) or (A,) float32 in [-1, 1] -> (obs (1, D) float32, reward (1,) float32,
        success = terminated (1,) bool, elapsed steps)."""
        env = self.env
        for joint, t in zip(self.joints, self.targets(np.asarray(action, F32).reshape(self.act_dim)).tolist()):
            joint.set_drive_target(t)
        px = self.scene.px
        for _ in range(self.substeps):
            px.step()
        elapsed = env._elapsed_steps.numpy()  # a view: the same counter ManiSkill's step increments
        elapsed += 1
        # evaluate()'s per-step cache belongs to ManiSkill's path; drop it so nothing reads a stale pose
        env.tcp_pose_at_eval = None
        env._panel_pose_at_eval = None
        obs = np.empty((1, FLAT_OBS_DIM), F32)
        o = obs[0]
        o[QPOS] = self.robot.qpos
        o[QVEL] = self.robot.qvel
        tcp = self.tcp.entity_pose
        o[TCP_P] = tcp.p
        o[TCP_Q] = tcp.q
        env._lean_task_parts(o, self.fused)  # object, joint, distractor and goal slots
        d = o[ACHIEVED] - o[DESIRED]
        sq = d * d
        success = bool((sq[0] + sq[1]) + sq[2] < self.tol_sq)  # goal_distance_sq, float32
        reward = np.array([0.0 if self.reward_none else success], F32)
        return obs, reward, np.array([success]), int(elapsed[0])
