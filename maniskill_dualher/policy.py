"""An actor-only policy file: what a finished (or running) run hands to whoever wants to act with it.

``policy.pt`` (every evaluation) and ``policy_best.pt`` (the best evaluation so far; a tie keeps the
earlier one) in a run folder hold one small dict (``POLICY_FORMAT``): the actor's state_dict and what it
takes to rebuild and use it without the training code's replay, critics or optimizer::

    format, actor (state_dict, CPU tensors), input_dim, obs_dim, goal_dim, act_dim, hidden, variant,
    env_id, control_mode, max_episode_steps, terminate_on_success, config (the run's RunConfig dict),
    env_steps, eval_success (the evaluation it was saved at)

Only tensors and plain Python, so ``load_policy`` reads it with ``torch.load(weights_only=True)``: a policy file
from someone else runs no code when loaded, and one holding any other object is refused (one line naming it).

``load_policy(run_dir_or_file)`` rebuilds the actor with sac.py's own ``Actor`` class, so
``Policy.act(x)`` is bit-identical to the training agent's ``agent.act(x, deterministic=True)``
(tests/test_evaluate.py). Actions come back in [-1, 1]^A: the env wrapper (envs.BatchEnv.step) scales them
to the action space's bounds, as in training.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Tuple, Union

import numpy as np
import torch

from .config import ConfigError
from .fileio import atomic_torch_save
from .rundir import POLICY, POLICY_BEST, load_torch_file
from .sac import Actor, matmul_precision

POLICY_FORMAT = 1
PathLike = Union[str, Path]


def policy_state(agent, spec, cfg, env_steps: int = 0, eval_success: Optional[float] = None,
                 control_mode: Optional[str] = None) -> dict:
    """The policy-file dict of a SAC ``agent`` acting in an env described by ``spec`` (envs.EnvSpec)."""
    cfg_dict = cfg.to_dict() if hasattr(cfg, "to_dict") else dict(cfg)
    return {
        "format": POLICY_FORMAT,
        "actor": {k: v.detach().cpu().clone() for k, v in agent.actor.state_dict().items()},
        "input_dim": int(spec.input_dim), "obs_dim": int(spec.obs_dim), "goal_dim": int(spec.goal_dim),
        "act_dim": int(spec.act_dim), "hidden": [int(h) for h in agent.cfg.hidden],
        "variant": agent.cfg.variant, "matmul_precision": agent.cfg.matmul_precision,
        "env_id": spec.env_id,
        "control_mode": control_mode if control_mode is not None else cfg_dict.get("control_mode"),
        "max_episode_steps": int(spec.max_episode_steps),
        "terminate_on_success": bool(cfg_dict.get("terminate_on_success", True)),
        "config": cfg_dict, "env_steps": int(env_steps),
        "eval_success": None if eval_success is None else float(eval_success),
    }


def save_policy(agent, path: PathLike, *, spec, cfg, env_steps: int = 0, eval_success: Optional[float] = None,
                control_mode: Optional[str] = None) -> Path:
    """Write the policy file of a sac.SAC ``agent`` acting in an env described by ``spec`` (envs.EnvSpec) under
    ``cfg`` (a RunConfig or its dict) atomically. Returns the path written."""
    state = policy_state(agent, spec, cfg, env_steps, eval_success, control_mode=control_mode)
    atomic_torch_save(state, Path(path))
    return Path(path)


@dataclass
class Policy:
    """A deterministic-or-stochastic tanh-Gaussian actor with its metadata (see the module docstring)."""
    actor: Actor
    input_dim: int
    obs_dim: int
    goal_dim: int
    act_dim: int
    hidden: Tuple[int, ...]
    env_id: str
    control_mode: Optional[str]
    max_episode_steps: int
    terminate_on_success: bool
    config: dict
    env_steps: int
    eval_success: Optional[float]
    matmul_precision: str = "highest"
    path: Optional[Path] = None
    meta: dict = field(default_factory=dict)

    @property
    def flat_dim(self) -> int:
        """Width of the env's flat observation ``[observation | achieved_goal | desired_goal]``."""
        return self.obs_dim + 2 * self.goal_dim

    def policy_input(self, flat: np.ndarray) -> np.ndarray:
        """Flat env observation (..., obs + 2 goal) -> network input (..., obs + goal): drops the achieved goal
        (as envs.BatchEnv.policy_input)."""
        flat = np.asarray(flat, dtype=np.float32)
        if not self.goal_dim:
            return flat
        o, g = self.obs_dim, self.goal_dim
        return np.concatenate([flat[..., :o], flat[..., o + g:o + 2 * g]], -1)

    @torch.no_grad()
    def act(self, x: np.ndarray, deterministic: bool = True) -> np.ndarray:
        """Actions in [-1, 1]^A for ``x`` of shape (input_dim,) or (N, input_dim): the policy input
        (observation ‖ desired goal, what ``BatchEnv.policy_input`` returns, as in Trainer.evaluate). A flat
        env observation (width obs + 2 goal, with the achieved goal) is accepted too and cut first.
        ``deterministic``: tanh of the Gaussian mean (training's evaluation); else a sample (torch's RNG)."""
        x = np.asarray(x, dtype=np.float32)
        if x.shape[-1] == self.flat_dim and self.flat_dim != self.input_dim:
            x = self.policy_input(x)
        if x.shape[-1] != self.input_dim:
            raise ValueError(f"input width {x.shape[-1]} fits neither the policy input ({self.input_dim}) "
                             f"nor the flat observation ({self.flat_dim}) of {self.env_id}")
        single = x.ndim == 1
        t = torch.as_tensor(x[None] if single else x)
        with matmul_precision(self.matmul_precision):
            a = self.actor.mean_action(t) if deterministic else self.actor.sample(t)
        a = a.numpy()
        return a[0] if single else a

    __call__ = act


def resolve_policy_path(path_or_run_dir: PathLike, best: bool = False) -> Path:
    """A run folder -> its policy.pt (policy_best.pt with ``best``); a file is itself. ConfigError if absent."""
    p = Path(path_or_run_dir)
    if p.is_dir():
        f = p / (POLICY_BEST if best else POLICY)
        if not f.is_file():
            other = p / (POLICY if best else POLICY_BEST)
            hint = f" (it has {other.name})" if other.is_file() else \
                " (its run has not reached an evaluation, or predates policy files)"
            raise ConfigError(f"no policy file {f.name} in {p}{hint}")
        return f
    if not p.exists():
        raise ConfigError(f"no such run folder or policy file: {p}")
    return p


def load_policy(path_or_run_dir: PathLike, best: bool = False) -> Policy:
    """Load a policy file, or a run folder's ``policy.pt`` (``best``: ``policy_best.pt``), on the CPU."""
    path = resolve_policy_path(path_or_run_dir, best)
    d = load_torch_file(path, "policy file")  # weights_only: a shared file runs no code; other objects refused
    if not isinstance(d, dict) or "actor" not in d or "input_dim" not in d:
        raise ConfigError(f"{path} is not a policy file (a checkpoint? use its run folder's policy.pt)")
    hidden = tuple(int(h) for h in d["hidden"])
    actor = Actor(int(d["input_dim"]), int(d["act_dim"]), hidden)
    actor.load_state_dict(d["actor"])
    actor.eval()
    actor.requires_grad_(False)
    return Policy(actor=actor, input_dim=int(d["input_dim"]), obs_dim=int(d["obs_dim"]),
                  goal_dim=int(d["goal_dim"]), act_dim=int(d["act_dim"]), hidden=hidden, env_id=d["env_id"],
                  control_mode=d.get("control_mode"), max_episode_steps=int(d["max_episode_steps"]),
                  terminate_on_success=bool(d.get("terminate_on_success", True)), config=d.get("config") or {},
                  env_steps=int(d.get("env_steps", 0)), eval_success=d.get("eval_success"),
                  matmul_precision=d.get("matmul_precision", "highest"), path=path,
                  meta={k: v for k, v in d.items() if k not in ("actor", "config")})
