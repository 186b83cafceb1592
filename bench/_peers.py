"""Shared by the benches that measure us against peer libraries (train_speed.py, time_to_success.py).

* Importing this module first pins the thread counts (``--threads N`` from argv, default 1): OpenMP/MKL/
  OpenBLAS get N threads, and JAX (SBX) gets one thread when N == 1. Import it before numpy, torch or jax.
  ``--cores K`` (default: all) also pins the process to K CPUs. Why: even at one intra-op thread JAX runs
  its computations on a runtime thread of its own, which the OS may put on a second core (SBX then keeps
  one core's caches for the env and another's for the update); ``--cores 1`` compares on one core each.
* ``GoalDictEnv``: one of our tasks as a single-env gymnasium GoalEnv (Dict obs, ``compute_reward``) for
  Stable-Baselines3 / SBX and their ``HerReplayBuffer``.
* ``make_peer_sac``: SB3 or SBX SAC + SB3's HerReplayBuffer (future strategy); ``sbx_missing`` says why
  SBX cannot be used (None if it can).
* ``evaluate_peer``: a peer's deterministic policy on fixed reset seeds (ours: EVAL_SEED_BASE + i).
* ``cpu_name``, ``loadavg``, ``thread_info``: the machine line every bench prints.
* ``atomic_write_json``: JSON through ``maniskill_dualher.fileio.atomic_write_text`` (a kill never leaves half
  a file).
"""
from __future__ import annotations

import json
import os
import sys

XLA_ONE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"


def argv_int(flag: str, argv=None, default: int = 1) -> int:
    argv = sys.argv if argv is None else argv
    for i, a in enumerate(argv):
        if a == flag and i + 1 < len(argv):
            return int(argv[i + 1])
        if a.startswith(flag + "="):
            return int(a.split("=", 1)[1])
    return default


def argv_threads(argv=None, default: int = 1) -> int:
    return argv_int("--threads", argv, default)


def pin_cores(k: int) -> None:
    """Restrict this process (and every thread it starts later) to its first k allowed CPUs; 0 = all."""
    if k > 0 and hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, sorted(os.sched_getaffinity(0))[:k])


def cores_info() -> str:
    if not hasattr(os, "sched_getaffinity"):
        return f"cores: {os.cpu_count()}"
    cpus = sorted(os.sched_getaffinity(0))
    return f"pinned to CPUs {cpus} of {os.cpu_count()}"


def pin_threads(n: int) -> None:
    """Set the thread environment variables (effective only before numpy/torch/jax initialise)."""
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ.setdefault(var, str(n))
    if n == 1:
        os.environ.setdefault("XLA_FLAGS", XLA_ONE_THREAD)


pin_threads(argv_threads())
pin_cores(argv_int("--cores", default=0))

import numpy as np  # noqa: E402
import gymnasium as gym  # noqa: E402

from maniskill_dualher.fileio import atomic_write_text  # noqa: E402

HER_STRATEGY = "future"


# --------------------------------------------------------------------------- the env
class GoalDictEnv(gym.Env):
    """Our task as a single-env gymnasium GoalEnv: Dict obs {observation, achieved_goal, desired_goal} (numpy),
    ``compute_reward`` delegating to the task's batched one, ``info["is_success"]`` from the task's success.

    ``terminate_on_success=False``: successes do not end episodes (fixed ``max_episode_steps``, as our loop's
    default). ``True``: ManiSkill's ``terminated`` (= success for our tasks) is passed through, so an
    episode ends at its first success or at the time limit."""

    metadata = {"render_modes": []}

    def __init__(self, env_id: str, max_episode_steps=None, control_mode="pd_joint_delta_pos",
                 reward_mode: str = "sparse", terminate_on_success: bool = False):
        import maniskill_dualher.tasks  # noqa: F401  (registers the tasks)
        from mani_skill.utils.wrappers.gymnasium import CPUGymWrapper
        from maniskill_dualher.tasks.common import GOAL_DIM, OBS_DIM
        kw = dict(sim_backend="physx_cpu", render_backend="none", obs_mode="state", reward_mode=reward_mode)
        if control_mode is not None:
            kw["control_mode"] = control_mode
        if max_episode_steps is not None:
            kw["max_episode_steps"] = int(max_episode_steps)
        self.env = CPUGymWrapper(gym.make(env_id, **kw), ignore_terminations=not terminate_on_success)
        self.task = self.env.unwrapped
        self.terminate_on_success = bool(terminate_on_success)
        self.o, self.g = OBS_DIM, GOAL_DIM
        box = lambda n: gym.spaces.Box(-np.inf, np.inf, (n,), np.float32)  # noqa: E731
        self.observation_space = gym.spaces.Dict(
            {"observation": box(OBS_DIM), "achieved_goal": box(GOAL_DIM), "desired_goal": box(GOAL_DIM)})
        self.action_space = self.env.action_space

    def _dict(self, flat):
        flat = np.asarray(flat, dtype=np.float32).reshape(-1)
        o, g = self.o, self.g
        return {"observation": flat[:o], "achieved_goal": flat[o:o + g], "desired_goal": flat[o + g:o + 2 * g]}

    def reset(self, *, seed=None, options=None):
        obs, info = self.env.reset(seed=seed, options=options)
        return self._dict(obs), {}

    def step(self, action):
        obs, rew, term, trunc, info = self.env.step(action)
        succ = bool(info.get("success", False))
        return self._dict(obs), float(rew), bool(term), bool(trunc), {"is_success": succ}

    def compute_reward(self, achieved_goal, desired_goal, info):
        return np.asarray(self.task.compute_reward(achieved_goal, desired_goal, {}), dtype=np.float32)

    def close(self):
        self.env.close()


# --------------------------------------------------------------------------- the peers
PEER_LIBS = {"sb3": "SB3", "sbx": "SBX"}


def sbx_missing():
    """None if SBX (PyPI ``sbx-rl``) is importable, else a one-line reason."""
    try:
        import sbx  # noqa: F401
    except Exception as e:  # ImportError, or a broken jax install
        return f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}".strip()
    return None


def lib_version(lib: str) -> str:
    try:
        if lib == "sbx":
            from importlib.metadata import version
            import jax
            return f"sbx-rl {version('sbx-rl')}, jax {jax.__version__}"
        import stable_baselines3
        return f"stable-baselines3 {stable_baselines3.__version__}"
    except Exception:
        return "?"


def make_peer_sac(lib: str, env, seed: int, net_arch, learning_rate: float, tau: float, gamma: float,
                  batch_size: int, buffer_size: int, learning_starts: int, n_sampled_goal: int,
                  train_freq: int = 1, gradient_steps: int = 1):
    """SAC of ``lib`` ("sb3" | "sbx") with SB3's HerReplayBuffer (future strategy), CPU, verbose 0."""
    from stable_baselines3 import HerReplayBuffer
    if lib == "sb3":
        from stable_baselines3 import SAC
        extra = dict(device="cpu")
    elif lib == "sbx":
        from sbx import SAC
        extra = {}
    else:
        raise ValueError(f"unknown peer library {lib!r} (choose {', '.join(PEER_LIBS)})")
    return SAC(
        "MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs=dict(n_sampled_goal=n_sampled_goal, goal_selection_strategy=HER_STRATEGY),
        buffer_size=buffer_size, learning_starts=learning_starts, batch_size=batch_size,
        learning_rate=learning_rate, tau=tau, gamma=gamma, train_freq=train_freq,
        gradient_steps=gradient_steps, policy_kwargs=dict(net_arch=list(net_arch)), seed=seed, verbose=0,
        **extra)


def evaluate_peer(model, env: GoalDictEnv, seeds, max_steps: int, initial_obs: bool = False) -> dict:
    """Deterministic policy, one episode per reset seed; success = ``is_success`` at any step (as ours).
    An episode ends at ``terminated or truncated`` or after ``max_steps`` steps. ``initial_obs``: also
    return each episode's first observation, flat ``[observation | achieved_goal | desired_goal]``."""
    once, rets, lens, first = [], [], [], []
    for s in seeds:
        obs, _ = env.reset(seed=int(s))
        if initial_obs:
            first.append(np.concatenate([obs[k] for k in ("observation", "achieved_goal", "desired_goal")]))
        ok, ret, t = False, 0.0, 0
        for t in range(1, int(max_steps) + 1):
            action, _ = model.predict(obs, deterministic=True)
            obs, r, term, trunc, info = env.step(action)
            ok = ok or bool(info["is_success"])
            ret += r
            if term or trunc:
                break
        once.append(ok)
        rets.append(ret)
        lens.append(t)
    out = {"eval_success_rate": float(np.mean(once)), "eval_return": float(np.mean(rets)),
           "eval_mean_length": float(np.mean(lens))}
    if initial_obs:
        out["initial_obs"] = first
    return out


# --------------------------------------------------------------------------- the machine
def cpu_name() -> str:
    import torch
    name = "?"
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    name = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return f"{name}, torch CPU capability {torch.backends.cpu.get_cpu_capability()}"


def loadavg() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg()) + f" (cores: {os.cpu_count()})"
    except OSError:
        return "?"


def thread_info() -> str:
    import torch
    env = ", ".join(f"{k}={os.environ.get(k, '(unset)')}" for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"))
    return (f"torch threads {torch.get_num_threads()} (interop {torch.get_num_interop_threads()}), {env}, "
            f"XLA_FLAGS={os.environ.get('XLA_FLAGS', '(unset)')!r}; {cores_info()}")


def atomic_write_json(path: str, doc) -> None:
    """Write ``doc`` as JSON (indent 1, trailing newline) with ``maniskill_dualher.fileio.atomic_write_text``."""
    atomic_write_text(path, json.dumps(doc, indent=1) + "\n")
