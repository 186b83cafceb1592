"""GPU check: our tasks (config.TASKS) and our training loop on ManiSkill's GPU simulation (``physx_cuda``), one NVIDIA GPU.

    python bench/gpu_check.py [--envs 16,64] [--timeout 120] [--sections a,b] [--tasks ...] [--json FILE]

It first prints a preflight (always): python, torch and its CUDA build, SAPIEN (and its PhysX), ManiSkill,
gymnasium and numpy versions, the GPU's name and memory, whether ``libcuda.so`` loads, the PhysX GPU buffer
sizes in use (``--gpu-memory-scale``), and whether SAPIEN's GPU physics library is on disk (below). Then
every section runs in its own process (``python bench/gpu_check.py --_section NAME ...``) under a time limit
(``--timeout`` seconds, default 120) and ends in one line: ``NAME: PASS``, ``NAME: FAIL: reason`` or
``NAME: SKIPPED: reason``; a crash, a hang or an exception fails that section only, and the next one runs.
Exit code: 0 if no section failed, 1 if one did, 2 without a CUDA GPU (one line on stderr) or on bad flags.

Sections (``--sections``, default all, in this order; ``--envs`` lists env counts, "many envs" = the largest):

``startup``
    Makes every task (``--tasks``) with the smallest env count on ``physx_cuda``, resets and steps it once.
    Always run first when a GPU-simulation section is selected: a task that cannot start here is left out of
    the later sections (named there once) instead of failing each of them with the same error; if none
    starts, the later GPU-simulation sections are SKIPPED.
``success``
    The success flag hindsight relies on. Over ``--steps`` (300) steps with many envs, half of them driven by
    the task's scripted solver (so successes occur; random actions alone almost never succeed) and half by
    random actions, envs reset when their episode ends: the host-side reward that hindsight relabeling uses
    (the task's ``compute_reward`` on numpy CPU copies of the observation's achieved/desired goal slots, via
    ``BatchEnv.spec.reward_fn``, exactly as the replay buffers call it) must agree with the env's own
    ``info["success"]`` (torch, on the GPU, from the simulator's poses) at every env-step, and the sparse env
    reward must equal success. Two computations on two devices from two copies of the data: a broken goal
    slot, a stale observation or a device/precision difference makes it FAIL. It also FAILs when no env-step
    was a success (or none was not), since then one side of the comparison went unchecked.
``idle_drift``
    A lid (CloseBox) or door (CloseMicrowave) must not move by itself: many envs, reset to random open angles,
    100 zero-action steps (the arm holds still, clear of the panel); every hinge angle stays within 1e-3 rad
    of its start and no env reports success. GPU PhysX (different solver, contact generation and joint
    friction handling than the CPU) could let a panel creep shut, which would hand out free successes.
``partial_reset``
    The training loop resets only the envs whose episode ended (``BatchEnv.reset_envs``). After pushing every
    arm far from rest for 20 steps, every other env is reset: the envs not reset must keep their simulation
    state (every actor and articulation: pose, velocity, joint positions and velocities), their observation
    and their step counter; the reset ones must start fresh: step counter 0, robot at rest within the
    ``robot_init_qpos_noise`` Gaussian (6 sigma), at rest, TCP near its rest position (stale link poses after a
    GPU state write, ManiSkill issue 758, would leave it where the push took it), observation equal to the
    simulator's state, and the task's randomization inside its documented ranges (hinged: body x, y, yaw,
    hinge angle; ReachTarget: ball box, separations, start distance), desired goal in ``GOAL_BOX``, and
    different goals in different envs.
``contact_overflow``
    PhysX's GPU pipeline has fixed-size buffers (contacts, patches, found/lost pairs); when one overflows it
    prints a warning to the console (no exception, no return value) and drops contacts or pairs. This captures the process's file
    descriptors 2 (and 1) during a 200-step rollout of every task with many envs (solver and random actions,
    so the arm touches lids and doors) and FAILs on any line mentioning an overflow, "exceeding" or a capacity
    to increase. Raise ``--gpu-memory-scale`` (``RunConfig.gpu_memory_scale``) if it does.
``env_speed``
    Env steps per second of every task at each ``--envs`` count: ManiSkill's own step on device tensors, and
    ``BatchEnv.step`` (numpy in and out: what the training loop pays). A measurement: fails only on an error.
``train_split``
    A short ``sac_her_per`` run (the ``quick`` preset's settings, ``--train-steps`` env steps, smallest env
    count, networks on ``cuda``) through ``maniskill_dualher.train.Trainer`` in a temporary folder, timing
    where its wall time goes: env step, env reset, acting, SAC update, replay sampling, priority updates,
    storing episodes (HER), evaluation, checkpoint, other (CUDA synchronised at each boundary).

SAPIEN's GPU physics library. ``physx_cuda`` needs ``libPhysXGpu_64.so``, which no package registry carries:
on first use ``sapien.physx.enable_gpu()`` downloads it from GitHub (``requests.get`` without a timeout, so on
a machine without internet it hangs) into ``~/.sapien/physx/<PhysX version>/``. For SAPIEN 3.0.3 (PhysX
``105.1-physx-5.3.1.patch0``) on x86_64 Linux that is::

    mkdir -p ~/.sapien/physx/105.1-physx-5.3.1.patch0
    # on a machine with internet:
    curl -LO https://github.com/sapien-sim/physx-precompiled/releases/download/105.1-physx-5.3.1.patch0/linux-so.zip
    unzip linux-so.zip -d ~/.sapien/physx/105.1-physx-5.3.1.patch0/   # gives libPhysXGpu_64.so

(or copy ``~/.sapien/physx/`` from a machine where ``physx_cuda`` has run once). The preflight prints the
exact path and URL for the installed SAPIEN; without the file every GPU-simulation section is SKIPPED with
that reason (never a download, never a hang).

Testing the harness without a GPU: ``GPU_CHECK_FAKE=1`` drops the CUDA requirement and runs the sections on
CPU simulation (``physx_cpu``, one env, networks on the CPU): a harness and code-path test, not a GPU check.
``GPU_CHECK_FAKE=nolib`` also pretends the GPU physics library is missing. Only then are the stub sections
``_stub_pass``, ``_stub_fail``, ``_stub_raise``, ``_stub_hang``, ``_stub_skip``, ``_stub_crash`` and
``_stub_gpu`` (a GPU-simulation section) available. The section functions (``check_success_agrees``,
``check_idle_drift``, ...) take a :class:`Sim` and are unit-tested on CPU simulation in tests/test_gpu_check.py.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import signal
import subprocess
import sys
import tempfile
import threading
import time
import traceback
import warnings
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable, Dict, List, Sequence

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
if REPO not in sys.path:
    sys.path.insert(0, REPO)

from maniskill_dualher.config import TASKS  # noqa: E402  (the catalog: every task)
FAKE_VAR = "GPU_CHECK_FAKE"
RESULT_TAG = "@@gpu_check_result "
DRIFT_TOL = 1e-3          # rad over 100 idle steps
STATE_TOL = 1e-4          # m, rad, m/s: "unchanged" / "equal" for GPU state read back
REST_QPOS = (0.0, math.pi / 8, 0.0, -5 * math.pi / 8, 0.0, 3 * math.pi / 4, math.pi / 4, 0.04, 0.04)  # Panda rest
REST_TCP_TOL = 0.10       # m: TCP within this of its rest position right after a reset
OVERFLOW_PATTERNS = ("overflow", "exceed", "needs to increase", "increase its size", "increase capacity",
                     "increase the capacity")

warnings.filterwarnings("ignore", message="Failed to find system libvulkan")


class CheckFailed(Exception):
    """A section's check missed (its message is the FAIL reason, one line); ``data`` goes to the parent."""

    def __init__(self, reason: str, data=None):
        super().__init__(reason)
        self.data = data


class Skipped(Exception):
    """A section (or one task of it) cannot run here; the message says why."""


def _one_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return text[0] if text else ""


# --------------------------------------------------------------------------- the simulation a section uses
@dataclass
class Sim:
    """How the sections simulate: ``physx_cuda`` + ``cuda`` on the GPU, ``physx_cpu`` + ``cpu`` when faked."""
    backend: str = "physx_cuda"
    device: str = "cuda"
    gpu_memory_scale: float = 1.0

    @property
    def gpu(self) -> bool:
        return self.backend == "physx_cuda"

    def counts(self, counts: Sequence[int]) -> List[int]:
        """Env counts this simulation can run (CPU simulation: one env per process)."""
        return sorted(set(int(c) for c in counts)) if self.gpu else [1]

    def make(self, task: str, num_envs: int):
        """The training loop's env (``maniskill_dualher.envs.make_env``: numpy in and out, [-1, 1] actions)."""
        from maniskill_dualher.config import RunConfig
        from maniskill_dualher.envs import make_env
        if self.gpu:
            require_physx_gpu_library()
        cfg = RunConfig(env_id=task, sim_backend=self.backend, num_envs=num_envs if self.gpu else 1,
                        device=self.device, gpu_memory_scale=self.gpu_memory_scale)
        return make_env(cfg.validate())

    def sync(self) -> None:
        if self.device.startswith("cuda"):
            import torch
            torch.cuda.synchronize()


def fake_mode() -> str:
    """'' (a real GPU check), '1' (CPU simulation) or 'nolib' (CPU simulation, GPU physics library 'missing')."""
    v = os.environ.get(FAKE_VAR, "").strip().lower()
    return "" if v in ("", "0", "false", "no") else ("nolib" if v == "nolib" else "1")


# --------------------------------------------------------------------------- SAPIEN's GPU physics library
def physx_gpu_library() -> dict:
    """Where SAPIEN's ``sapien.physx.enable_gpu()`` looks for its GPU physics library and where it would fetch
    it from (the same rules as its source, sapien/physx/__init__.py), and whether the file is there."""
    from pathlib import Path
    import sapien.physx as px
    ver = px.version()
    parent = Path.home() / ".sapien" / "physx" / ver
    base = f"https://github.com/sapien-sim/physx-precompiled/releases/download/{ver}"
    system, machine = platform.system(), platform.machine()
    if system == "Windows":
        dll, url = parent / "PhysXGpu_64.dll", f"{base}/windows-dll.zip"
    elif system == "Linux" and machine in ("aarch64", "arm64"):
        dll, url = parent / "libPhysXGpu_64.so", f"{base}/linux-aarch64-so.zip"
    else:
        dll, url = parent / "libPhysXGpu_64.so", f"{base}/linux-so.zip"
    present = dll.is_file() and fake_mode() != "nolib"
    return {"physx_version": ver, "path": str(dll), "dir": str(parent), "url": url, "present": present,
            "enabled": bool(px.is_gpu_enabled())}


def missing_library_reason(lib: dict) -> str:
    return (f"SAPIEN's GPU physics library {lib['path']} is missing (physx_cuda would try to download it "
            f"from the internet, with no time limit)")


def require_physx_gpu_library() -> None:
    """Raise Skipped unless the library is on disk: never let SAPIEN start its (timeout-less) download."""
    lib = physx_gpu_library()
    if not lib["present"] and not lib["enabled"]:
        raise Skipped(missing_library_reason(lib))


# --------------------------------------------------------------------------- helpers of the sections
def _policy_zero(env):
    """The [-1, 1] policy action that BatchEnv turns into the env action 0 (N, A)."""
    import numpy as np
    z = -1.0 + 2.0 * (0.0 - env.low) / np.maximum(env.high - env.low, 1e-8)
    return np.tile(np.clip(z, -1.0, 1.0).astype(np.float32), (env.num_envs, 1))


def _solver_action(solver, env, flat):
    """The scripted solver's action for the flat observations, in the policy's [-1, 1] convention."""
    import numpy as np
    a = solver.act(flat)
    a = a.detach().cpu().numpy() if hasattr(a, "detach") else np.asarray(a)
    a = a.reshape(env.num_envs, -1)
    return np.clip(2.0 * (a - env.low) / np.maximum(env.high - env.low, 1e-8) - 1.0, -1.0, 1.0).astype(np.float32)


def _mixed_rollout(env, steps: int, seed: int, solver_share: float = 0.5, on_step=None):
    """Yield (step, next_flat, reward, terminated, truncated, success) of ``steps`` steps: the first
    ceil(N * solver_share) envs follow the scripted solver, the rest act at random; an env whose episode
    ended (success, time limit) is reset before the next step, as the training loop does."""
    import numpy as np
    n = env.num_envs
    solver = env.solver()
    n_solver = 0 if solver is None else min(n, math.ceil(n * solver_share))
    rng = np.random.default_rng(seed)
    flat = env.reset(seed)
    t = np.zeros(n, np.int64)
    started = 0
    for k in range(steps):
        a = rng.uniform(-1.0, 1.0, (n, env.spec.act_dim)).astype(np.float32)
        if n_solver:
            a[:n_solver] = _solver_action(solver, env, flat)[:n_solver]
        nxt, rew, term, trunc, succ = env.step(a)
        if on_step is not None:
            on_step(env, k)
        yield k, nxt, rew, term, trunc, succ
        t += 1
        ended = term | trunc | (t >= env.spec.max_episode_steps)
        if ended.any():
            idx = np.flatnonzero(ended)
            nxt = nxt.copy()
            nxt[idx] = env.reset_envs(idx, [seed + 1 + started + j for j in range(len(idx))])
            started += len(idx)
            t[idx] = 0
        flat = nxt


def _envs(n: int) -> str:
    return f"{n} env" if n == 1 else f"{n} envs"


def _np(x):
    import numpy as np
    return x.detach().cpu().numpy() if hasattr(x, "detach") else np.asarray(x)


@contextmanager
def capture_fds(fds=(1, 2)):
    """Capture what the process writes to these file descriptors (C++ code included: PhysX logs to fd 2)
    into a dict {fd: text}, filled when the block ends; the text is not passed on (callers echo it)."""
    import ctypes
    for f in (sys.stdout, sys.stderr):
        f.flush()
    saved = {fd: os.dup(fd) for fd in fds}
    tmp = {fd: tempfile.TemporaryFile() for fd in fds}
    out: Dict[int, str] = {}
    for fd in fds:
        os.dup2(tmp[fd].fileno(), fd)
    try:
        yield out
    finally:
        for f in (sys.stdout, sys.stderr):
            f.flush()
        try:
            ctypes.CDLL(None).fflush(None)  # C stdio buffers
        except (OSError, AttributeError):
            pass
        for fd in fds:
            os.dup2(saved[fd], fd)
            os.close(saved[fd])
            tmp[fd].seek(0)
            out[fd] = tmp[fd].read().decode("utf-8", "replace")
            tmp[fd].close()


def overflow_lines(text: str) -> List[str]:
    """Lines of PhysX/SAPIEN output that report a full GPU buffer."""
    return [ln.strip() for ln in text.splitlines() if any(p in ln.lower() for p in OVERFLOW_PATTERNS)]


# --------------------------------------------------------------------------- the sections' checks
def check_startup(sim: Sim, task: str, num_envs: int, log=print) -> dict:
    """Make, reset and step the task once; report the times (and the GPU memory in use)."""
    t0 = time.perf_counter()
    env = sim.make(task, num_envs)
    try:
        made = time.perf_counter() - t0
        t0 = time.perf_counter()
        env.reset(0)
        env.step(_policy_zero(env))
        sim.sync()
        first = time.perf_counter() - t0
        mem = ""
        if sim.device.startswith("cuda"):
            import torch
            free, total = torch.cuda.mem_get_info()
            mem = f"; GPU memory in use {(total - free) / 2**30:.1f} of {total / 2**30:.1f} GiB"
        log(f"{task}: {_envs(env.num_envs)} on {sim.backend}: made in {made:.1f} s, reset + first step {first:.2f} s, "
            f"observation width {env.spec.flat_dim}{mem}")
        return {"num_envs": env.num_envs, "make_s": round(made, 2), "first_step_s": round(first, 3)}
    finally:
        env.close()


def check_success_agrees(sim: Sim, task: str, num_envs: int, steps: int = 300, reward_fn=None, seed: int = 0,
                         solver_share: float = 0.5, log=print) -> dict:
    """Host-side reward of hindsight (numpy on CPU copies of the observation's goals) == ``info["success"]``."""
    import numpy as np
    env = sim.make(task, num_envs)
    try:
        n = env.num_envs
        host_reward = reward_fn or env.spec.reward_fn
        if host_reward is None:
            raise Skipped(f"{task} is not a goal env")
        tol = float(getattr(env.unwrapped, "goal_tolerance", float("nan")))
        checked = successes = reward_bad = 0
        bad: List[tuple] = []
        n_bad = 0
        for k, nxt, rew, term, trunc, succ in _mixed_rollout(env, steps, seed, solver_share):
            if succ is None:
                raise CheckFailed(f"{task}: the env reports no info['success']")
            _, ag, dg = env.split(nxt)
            ag, dg = np.array(ag, copy=True), np.array(dg, copy=True)  # what the replay buffers hold
            host = np.asarray(host_reward(ag, dg, None)).reshape(n) > 0.5
            wrong = np.flatnonzero(host != succ)
            n_bad += len(wrong)
            for i in wrong[:max(0, 3 - len(bad))]:
                bad.append((k, int(i), bool(succ[i]), bool(host[i]), float(np.linalg.norm(ag[i] - dg[i]))))
            reward_bad += int(np.sum((rew > 0.5) != succ))
            successes += int(succ.sum())
            checked += n
        log(f"{task}: {_envs(n)} x {steps} steps ({math.ceil(n * solver_share)} solver-driven): {checked} env-steps, "
            f"{successes} successes; host-side reward vs info['success'] mismatches {n_bad}, "
            f"env reward vs success mismatches {reward_bad}")
        if n_bad:
            k, i, s, h, d = bad[0]
            raise CheckFailed(f"{task}: host-side reward (numpy on CPU copies of the goals) disagrees with "
                              f"info['success'] at {n_bad} of {checked} env-steps; first at step {k}, env {i}: "
                              f"success {s}, host reward {float(h):g}, goal distance {d:.6f} m (tolerance {tol:.6f})")
        if reward_bad:
            raise CheckFailed(f"{task}: the sparse env reward differs from info['success'] at {reward_bad} of "
                              f"{checked} env-steps")
        if successes == 0 or successes == checked:
            raise CheckFailed(f"{task}: {successes} of {checked} env-steps were successes: one side of the "
                              f"comparison went unchecked")
        return {"env_steps": checked, "successes": successes, "mismatches": n_bad, "reward_mismatches": reward_bad}
    finally:
        env.close()


def check_idle_drift(sim: Sim, task: str, num_envs: int, steps: int = 100, tol: float = DRIFT_TOL, seed: int = 0,
                     on_step=None, log=print) -> dict:
    """Zero actions for ``steps`` steps: every hinge angle stays within ``tol`` rad of its start."""
    import numpy as np
    from maniskill_dualher.tasks.hinged import HingedPanelEnv
    env = sim.make(task, num_envs)
    try:
        base = env.unwrapped
        if not isinstance(base, HingedPanelEnv):
            raise Skipped(f"{task} has no hinged panel")
        n = env.num_envs
        env.reset(seed)
        zero = _policy_zero(env)
        start = _np(base.articulation.qpos[:, 0]).astype(np.float64)
        worst = np.zeros(n)
        succeeded = np.zeros(n, bool)
        for k in range(steps):
            _, _, _, _, succ = env.step(zero)
            if on_step is not None:
                on_step(env, k)
            worst = np.maximum(worst, np.abs(_np(base.articulation.qpos[:, 0]) - start))
            if succ is not None:
                succeeded |= succ
        i = int(np.argmax(worst))
        log(f"{task}: {_envs(n)}, start angles {start.min():.3f}..{start.max():.3f} rad, {steps} zero-action steps: "
            f"largest drift {worst[i]:.2e} rad (env {i}, start {start[i]:.3f} rad; limit {tol:g})")
        moved = int(np.sum(worst > tol))
        if moved:
            raise CheckFailed(f"{task}: the panel moved by itself in {moved} of {n} envs ({steps} zero-action steps): "
                              f"worst {worst[i]:.2e} rad > {tol:g} (env {i}, start angle {start[i]:.3f} rad)")
        if succeeded.any():
            raise CheckFailed(f"{task}: {int(succeeded.sum())} of {n} idle envs reported success")
        return {"max_drift": float(worst[i]), "start_min": float(start.min()), "start_max": float(start.max())}
    finally:
        env.close()


def _entity_states(base) -> Dict[str, "object"]:
    """Every actor's and articulation's simulation state (N, D) as numpy, keyed 'actors/<name>' etc."""
    out = {}
    for kind, states in base.get_state_dict().items():
        if kind == "controller" or not isinstance(states, dict):
            continue
        for name, x in states.items():
            out[f"{kind}/{name}"] = _np(x).reshape(base.num_envs, -1).astype("float64")
    return out


def initial_state_problems(base, idx, rows) -> List[str]:
    """What is wrong with envs ``idx`` as freshly reset episodes (``rows``: their flat observations)."""
    import numpy as np
    from maniskill_dualher.tasks.common import OBS_SLICES, split_goal_obs
    from maniskill_dualher.tasks.hinged import HingedPanelEnv
    from maniskill_dualher.tasks.reach_target import ReachTargetEnv
    probs: List[str] = []
    idx = np.asarray(idx)
    o, ag, dg = (np.asarray(x, dtype=np.float64) for x in split_goal_obs(np.asarray(rows)))

    def check(name, values, lo, hi, tol=STATE_TOL):
        values = np.asarray(values, dtype=np.float64)
        lo, hi = np.broadcast_to(np.asarray(lo, np.float64), values.shape), np.broadcast_to(np.asarray(hi, np.float64), values.shape)
        bad = np.flatnonzero(((values < lo - tol) | (values > hi + tol)).reshape(len(idx), -1).any(-1))
        if len(bad):
            j = bad[0]
            probs.append(f"env {idx[j]}: {name} {np.round(values[j], 4).tolist()} outside "
                         f"[{np.round(lo[j], 4).tolist()}, {np.round(hi[j], 4).tolist()}]")

    qpos = _np(base.agent.robot.get_qpos())[idx].astype(np.float64)
    if np.abs(o[:, OBS_SLICES["qpos"]] - qpos).max() > STATE_TOL:
        probs.append("the reset observation's robot qpos is not the simulator's")
    noise = 6 * float(getattr(base, "robot_init_qpos_noise", 0.02)) + 1e-3
    rest = np.asarray(REST_QPOS)
    check("robot qpos", qpos, rest - noise, rest + noise, tol=0.0)
    check("robot qvel", o[:, OBS_SLICES["qvel"]], -STATE_TOL, STATE_TOL, tol=0.0)
    rest_tcp = np.asarray(getattr(ReachTargetEnv, "REST_TCP_POS", (0.0, 0.0, 0.17)))
    check("TCP position", o[:, OBS_SLICES["tcp_pose"]][:, :3], rest_tcp - REST_TCP_TOL, rest_tcp + REST_TCP_TOL, tol=0.0)
    if base.GOAL_BOX_LOW is not None:
        check("desired goal", dg, base.GOAL_BOX_LOW, base.GOAL_BOX_HIGH)
    if isinstance(base, HingedPanelEnv):
        pose = _np(base.articulation.pose.raw_pose)[idx].astype(np.float64)
        check("body x", pose[:, 0], *base.CENTER_X_RANGE)
        check("body y", pose[:, 1], *base.CENTER_Y_RANGE)
        check("body z", pose[:, 2], base.BODY_LIFT, base.BODY_LIFT)
        check("body yaw", 2 * np.arctan2(pose[:, 6], pose[:, 3]), *base.YAW_RANGE)
        angle = _np(base.articulation.qpos[:, 0])[idx].astype(np.float64)
        check("hinge angle", angle, *base.INIT_ANGLE_RANGE)
        check("hinge velocity", _np(base.articulation.qvel[:, 0])[idx], 0.0, 0.0)
        if np.abs(o[:, OBS_SLICES["joint_qpos"]][:, 0] - angle).max() > STATE_TOL:
            probs.append("the reset observation's hinge angle is not the simulator's")
    elif isinstance(base, ReachTargetEnv):
        balls = np.stack([_np(b.pose.p)[idx] for b in base.balls], 1).astype(np.float64)  # (b, 3, 3)
        check("ball centres", balls.reshape(len(idx), -1), np.tile(base.BALL_BOX_LOW, 3), np.tile(base.BALL_BOX_HIGH, 3))
        for i, j in ((0, 1), (0, 2), (1, 2)):
            check(f"ball {i}-{j} separation", np.linalg.norm(balls[:, i] - balls[:, j], axis=-1),
                  base.MIN_BALL_SEPARATION - STATE_TOL, np.inf)
        check("target distance from the rest TCP", np.linalg.norm(balls[:, 0] - rest_tcp, axis=-1),
              base.MIN_START_DISTANCE - STATE_TOL, np.inf)
        if np.abs(balls[:, 0] - dg).max() > STATE_TOL:
            probs.append("the desired goal is not the red ball's centre")
    if len(idx) > 1 and len(np.unique(np.round(dg, 6), axis=0)) < len(idx):
        probs.append(f"{len(idx)} reset envs share desired goals ({len(np.unique(np.round(dg, 6), axis=0))} distinct)")
    return probs


def check_partial_reset(sim: Sim, task: str, num_envs: int, push_steps: int = 20, seed: int = 0, log=print) -> dict:
    """Reset every other env mid-episode: the others keep their state, the reset ones start fresh and in range."""
    import numpy as np
    env = sim.make(task, num_envs)
    try:
        base = env.unwrapped
        n = env.num_envs
        env.reset(seed)
        push = _policy_zero(env)
        push[:, :7] = np.clip(push[:, :7] + 0.5, -1.0, 1.0)  # every arm joint moves away from rest (0.05 rad/step)
        flat = None
        for _ in range(push_steps):
            flat = env.step(push)[0]
        sim.sync()
        before = _entity_states(base)
        steps_before = _np(base._elapsed_steps).copy()
        idx = np.arange(0, n, 2) if n > 1 else np.array([0])
        others = np.setdiff1d(np.arange(n), idx)
        rows = env.reset_envs(idx, [seed + 1 + j for j in range(len(idx))])
        sim.sync()
        after = _entity_states(base)
        steps_after = _np(base._elapsed_steps)
        probs: List[str] = []
        if len(others):
            for key in before:
                d = np.abs(after[key][others] - before[key][others]).max()
                if not d <= STATE_TOL:
                    j = others[int(np.argmax(np.abs(after[key][others] - before[key][others]).max(-1)))]
                    probs.append(f"env {j} was not reset but its {key} state changed by {d:.3g}")
            now = env._flat(base.get_obs(base.get_info()))
            d = np.abs(now[others] - flat[others]).max()
            if not d <= STATE_TOL:
                probs.append(f"the observations of envs not reset changed by {d:.3g}")
            if not np.array_equal(steps_after[others], steps_before[others]):
                probs.append("the step counters of envs not reset changed")
        if np.any(steps_after[idx] != 0):
            probs.append("the step counters of the reset envs are not 0")
        moved = max(np.abs(after[k][idx] - before[k][idx]).max() for k in before if k.startswith("articulations/"))
        if not moved > 1e-3:
            probs.append("the reset envs' articulations did not move: nothing was reset")
        probs += initial_state_problems(base, idx, rows)
        log(f"{task}: {_envs(n)}, {push_steps} push steps, reset {len(idx)} (every other), kept {len(others)}: "
            f"{'ok' if not probs else '; '.join(probs[:3])}")
        if probs:
            raise CheckFailed(f"{task}: {len(probs)} problem{'s' if len(probs) > 1 else ''} after a partial reset: "
                              + "; ".join(probs[:3]))
        return {"reset": len(idx), "kept": len(others)}
    finally:
        env.close()


def check_contact_overflow(sim: Sim, tasks: Sequence[str], num_envs: int, steps: int = 200, seed: int = 0,
                           on_step=None, log=print) -> dict:
    """Roll every task ``steps`` steps with fds 1 and 2 captured; FAIL on any PhysX buffer-overflow line."""
    errors: Dict[str, str] = {}
    counts: Dict[str, int] = {}
    with capture_fds((1, 2)) as cap:
        for task in tasks:
            try:
                env = sim.make(task, num_envs)
            except Exception as e:  # noqa: BLE001  (reported after the capture)
                errors[task] = f"{type(e).__name__}: {_one_line(e)}"
                continue
            try:
                counts[task] = env.num_envs
                for _ in _mixed_rollout(env, steps, seed, on_step=on_step):
                    pass
                sim.sync()
            except Exception as e:  # noqa: BLE001
                errors[task] = f"{type(e).__name__}: {_one_line(e)}"
            finally:
                env.close()
    sys.stdout.write(cap[1])   # pass the captured output on (the harness shows stderr when a section fails)
    sys.stderr.write(cap[2])
    sys.stdout.flush()
    sys.stderr.flush()
    hits = overflow_lines(cap[2]) + overflow_lines(cap[1])
    log(f"{', '.join(counts) or 'no task'}: {_envs(max(counts.values(), default=0))} x {steps} steps each; captured "
        f"{len(cap[2].splitlines())} stderr and {len(cap[1].splitlines())} stdout lines; overflow lines {len(hits)}")
    if hits:
        raise CheckFailed(f"PhysX reported a full GPU buffer ({len(hits)} line{'s' if len(hits) > 1 else ''}), "
                          f"first: {hits[0][:160]!r}; raise --gpu-memory-scale (RunConfig.gpu_memory_scale)")
    if errors:
        raise CheckFailed("; ".join(f"{t}: {m}" for t, m in errors.items()))
    return {"overflow_lines": 0, "stderr_lines": len(cap[2].splitlines())}


def measure_env_speed(sim: Sim, task: str, num_envs: int, steps: int = 100, seed: int = 0, log=print) -> dict:
    """Env steps/s: ManiSkill's own step on device tensors, and BatchEnv.step (numpy in and out)."""
    import numpy as np
    import torch
    env = sim.make(task, num_envs)
    try:
        base, n = env.unwrapped, env.num_envs
        rng = np.random.default_rng(seed)
        acts = rng.uniform(-1, 1, (steps + 5, n, env.spec.act_dim)).astype(np.float32)
        dev = torch.as_tensor(env.low + (acts + 1) * 0.5 * (env.high - env.low), device=base.device)
        env.reset(seed)
        for k in range(5):
            env.env.step(dev[k])
        sim.sync()
        t0 = time.perf_counter()
        for k in range(steps):
            env.env.step(dev[k + 5])
        sim.sync()
        raw = time.perf_counter() - t0
        env.reset(seed + 1)
        t0 = time.perf_counter()
        for k in range(steps):
            env.step(acts[k])
        loop = time.perf_counter() - t0
        out = {"num_envs": n, "steps": steps, "device_steps_per_s": n * steps / raw, "loop_steps_per_s": n * steps / loop}
        log(f"{task}: {_envs(n)}: {out['device_steps_per_s']:.0f} env steps/s on device tensors "
            f"({1e3 * raw / steps:.2f} ms per batched step), {out['loop_steps_per_s']:.0f} through BatchEnv.step "
            f"({1e3 * loop / steps:.2f} ms)")
        return out
    finally:
        env.close()


class SplitTimer:
    """Wall time by category, outermost timed call only (an evaluation's env steps count as evaluation)."""

    def __init__(self, sync: Callable[[], None]):
        self.sync, self.active = sync, None
        self.seconds: Dict[str, float] = {}
        self.calls: Dict[str, int] = {}

    def wrap(self, name: str, fn):
        def timed(*a, **k):
            if self.active is not None:
                return fn(*a, **k)
            self.sync()
            self.active, t0 = name, time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                self.sync()
                self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - t0
                self.calls[name] = self.calls.get(name, 0) + 1
                self.active = None
        return timed


def _quick_config(method: str, seed: int):
    """The 'quick' preset's RunConfig."""
    from maniskill_dualher.experiment.presets import PRESETS
    return PRESETS["quick"].base_config(method, seed)


def measure_train_split(sim: Sim, task: str, num_envs: int, total_steps: int, out_dir: str, log=print) -> dict:
    """A short sac_her_per run (quick preset): where the training loop's wall time goes."""
    from maniskill_dualher.train import Trainer, run_one
    cfg = _quick_config("sac_her_per", 0)
    cfg.env_id, cfg.sim_backend, cfg.device, cfg.gpu_memory_scale = task, sim.backend, sim.device, sim.gpu_memory_scale
    cfg.num_envs = num_envs if sim.gpu else 1
    cfg.total_steps = int(total_steps)
    warm = min(cfg.sac.random_steps, cfg.total_steps // 4)
    cfg.sac.random_steps = cfg.sac.learning_starts = warm
    cfg.eval_every = cfg.checkpoint_every = cfg.total_steps
    t0 = time.perf_counter()
    tr = Trainer(cfg, out_dir, show_progress=False)
    setup = time.perf_counter() - t0
    tm = SplitTimer(sim.sync)
    for obj, attr, name in ((tr.env, "step", "env step"), (tr.env, "reset_envs", "env reset"),
                            (tr.env, "reset", "env reset"), (tr.agent, "act", "act"),
                            (tr.agent, "update", "SAC update"), (tr.method, "sample", "replay sample"),
                            (tr.method, "sample_uniform", "replay sample"),
                            (tr.method, "update_priorities", "priority update"),
                            (tr.method, "add_episode", "store episode (HER)"), (tr, "evaluate", "evaluation"),
                            (tr, "save_checkpoint", "checkpoint")):
        if hasattr(obj, attr):
            setattr(obj, attr, tm.wrap(name, getattr(obj, attr)))
    try:
        t0 = time.perf_counter()
        run_one(tr)
        sim.sync()
        wall = time.perf_counter() - t0
    finally:
        tr.env.close()
    parts = dict(tm.seconds)
    parts["other"] = max(0.0, wall - sum(parts.values()))
    split = ", ".join(f"{k} {100 * v / wall:.0f}%" + (f" ({tm.calls[k]} x {1e3 * v / tm.calls[k]:.2f} ms)" if k in tm.calls else "")
                      for k, v in sorted(parts.items(), key=lambda kv: -kv[1]))
    log(f"{task} sac_her_per ('quick' preset, {_envs(cfg.num_envs)}, networks on {cfg.device}, hidden "
        f"{list(cfg.sac.hidden)}, batch {cfg.sac.batch_size}): setup {setup:.1f} s; {tr.env_steps} env steps, "
        f"{tr.updates} updates in {wall:.1f} s = {tr.env_steps / wall:.0f} env steps/s, {tr.updates / wall:.0f} updates/s")
    log(f"{task} time split: {split}")
    return {"env_steps": tr.env_steps, "updates": tr.updates, "seconds": wall,
            "split": {k: round(v, 3) for k, v in parts.items()}}


# --------------------------------------------------------------------------- sections (run in a child process)
def _per_task(tasks: Sequence[str], fn, what: str) -> dict:
    """Run fn(task) for every task; a task that fails does not stop the others; FAIL names them all."""
    failed, skipped, data = [], [], {}
    for task in tasks:
        try:
            data[task] = fn(task)
        except Skipped as e:
            skipped.append(task)
            print(f"{task}: skipped: {e}", flush=True)
        except CheckFailed as e:
            failed.append(str(e))
        except Exception as e:  # noqa: BLE001
            traceback.print_exc()
            failed.append(f"{task}: {type(e).__name__}: {_one_line(e)}")
    if failed:
        raise CheckFailed("; ".join(failed))
    if not data:
        raise Skipped(f"no task to {what}" + (f" ({', '.join(skipped)} skipped)" if skipped else ""))
    return data


def section_startup(a, sim: Sim) -> dict:
    if sim.gpu:
        import sapien.physx as px
        require_physx_gpu_library()
        t0 = time.perf_counter()
        px.enable_gpu()
        print(f"SAPIEN GPU physics enabled in {time.perf_counter() - t0:.1f} s", flush=True)
    ok, failed = [], {}
    for task in a.tasks:
        try:
            check_startup(sim, task, min(sim.counts(a.envs)))
            ok.append(task)
        except Exception as e:  # noqa: BLE001
            traceback.print_exc()
            failed[task] = f"{type(e).__name__}: {_one_line(e)}"
    data = {"tasks_ok": ok, "tasks_failed": failed}
    if failed:
        raise CheckFailed("; ".join(f"{t}: {m}" for t, m in failed.items()), data)
    return data


def section_success(a, sim):
    n = max(sim.counts(a.envs))
    return _per_task(a.tasks, lambda t: check_success_agrees(sim, t, n, a.steps), "compare")


def section_idle_drift(a, sim):
    n = max(sim.counts(a.envs))
    return _per_task([t for t in a.tasks if t != "ReachTarget-v1"], lambda t: check_idle_drift(sim, t, n), "idle (no hinged task)")


def section_partial_reset(a, sim):
    n = max(sim.counts(a.envs))
    return _per_task(a.tasks, lambda t: check_partial_reset(sim, t, n), "reset")


def section_contact_overflow(a, sim):
    if not a.tasks:
        raise Skipped("no task to roll out")
    return check_contact_overflow(sim, a.tasks, max(sim.counts(a.envs)), steps=200)


def section_env_speed(a, sim):
    def one(task):
        return [measure_env_speed(sim, task, n, a.speed_steps) for n in sim.counts(a.envs)]
    return _per_task(a.tasks, one, "time")


def section_train_split(a, sim):
    task = "ReachTarget-v1" if "ReachTarget-v1" in a.tasks else (a.tasks[0] if a.tasks else None)
    if task is None:
        raise Skipped("no task to train on")
    with tempfile.TemporaryDirectory(prefix="gpu_check_train_") as d:
        return measure_train_split(sim, task, min(sim.counts(a.envs)), a.train_steps, os.path.join(d, "run"))


def _stub(kind):
    def run(a, sim):
        if kind == "pass":
            print("stub: ran", flush=True)
        elif kind == "fail":
            raise CheckFailed("stub check missed its target")
        elif kind == "raise":
            raise RuntimeError("stub error")
        elif kind == "hang":
            print("stub: hanging", flush=True)
            time.sleep(3600)
        elif kind == "skip":
            raise Skipped("stub skipped itself")
        elif kind == "crash":
            print("stub: fatal error, exiting", file=sys.stderr, flush=True)
            os._exit(70)
        elif kind == "gpu":
            print("stub: GPU-simulation section ran", flush=True)
    return run


@dataclass
class Section:
    name: str
    run: Callable
    gpu_sim: bool          # needs GPU simulation (SAPIEN's GPU physics library, a started simulation)
    stub: bool = False


SECTIONS: Dict[str, Section] = {s.name: s for s in (
    Section("startup", section_startup, True),
    Section("success", section_success, True),
    Section("idle_drift", section_idle_drift, True),
    Section("partial_reset", section_partial_reset, True),
    Section("contact_overflow", section_contact_overflow, True),
    Section("env_speed", section_env_speed, True),
    Section("train_split", section_train_split, True),
    *(Section(f"_stub_{k}", _stub(k), k == "gpu", stub=True)
      for k in ("pass", "fail", "raise", "hang", "skip", "crash", "gpu")),
)}
DEFAULT_SECTIONS = [n for n, s in SECTIONS.items() if not s.stub]


def child_main(a) -> int:
    """``--_section NAME``: run one section, print its detail lines, then one result line for the parent."""
    fake = fake_mode()
    sim = Sim("physx_cpu", "cpu", a.gpu_memory_scale) if fake else Sim("physx_cuda", "cuda", a.gpu_memory_scale)
    status, reason, data = "PASS", "", None
    try:
        data = SECTIONS[a._section].run(a, sim)
    except Skipped as e:
        status, reason = "SKIPPED", _one_line(e)
    except CheckFailed as e:
        status, reason, data = "FAIL", _one_line(e), e.data
    except Exception as e:  # noqa: BLE001
        traceback.print_exc()
        status, reason = "FAIL", f"{type(e).__name__}: {_one_line(e)}"
    sys.stderr.flush()
    print(RESULT_TAG + json.dumps({"status": status, "reason": reason, "data": data}, default=str), flush=True)
    return 0


# --------------------------------------------------------------------------- the parent: preflight, sections
def preflight(a, fake: str) -> dict:
    """Print versions, the GPU, libcuda, the PhysX buffer sizes and the GPU physics library; return the facts."""
    import ctypes
    from importlib import metadata
    import torch

    def ver(pkg):
        try:
            return metadata.version(pkg)
        except metadata.PackageNotFoundError:
            return "not installed"

    print("preflight:")
    info: dict = {"python": platform.python_version(), "torch": torch.__version__, "torch_cuda": torch.version.cuda,
                  "sapien": ver("sapien"), "mani_skill": ver("mani_skill"), "gymnasium": ver("gymnasium"),
                  "numpy": ver("numpy")}
    print(f"  python {info['python']}, torch {info['torch']} (CUDA build {info['torch_cuda'] or 'none'}), sapien "
          f"{info['sapien']}, mani_skill {info['mani_skill']}, gymnasium {info['gymnasium']}, numpy {info['numpy']}")
    if fake:
        print(f"  {FAKE_VAR}={os.environ.get(FAKE_VAR)}: CPU simulation (physx_cpu, 1 env), networks on the CPU: "
              "a test of this script, not a GPU check")
    else:
        for i in range(torch.cuda.device_count()):
            p = torch.cuda.get_device_properties(i)
            print(f"  GPU {i}: {p.name}, {p.total_memory / 2**30:.1f} GiB, compute capability {p.major}.{p.minor}"
                  + (f"; {torch.cuda.mem_get_info(i)[0] / 2**30:.1f} GiB free" if i == 0 else ""))
        info["gpu"] = torch.cuda.get_device_name(0)
    try:
        ctypes.CDLL("libcuda.so")
        info["libcuda"] = "loads"
    except OSError as e:
        info["libcuda"] = f"does not load ({_one_line(e)})"
    print(f"  libcuda.so (the CUDA driver SAPIEN's GPU physics loads): {info['libcuda']}")
    try:
        lib = physx_gpu_library()
    except Exception as e:  # noqa: BLE001
        lib = {"present": False, "path": "?", "url": "?", "dir": "?", "physx_version": "?", "error": _one_line(e)}
        print(f"  SAPIEN's GPU physics library: cannot tell ({type(e).__name__}: {lib['error']})")
    else:
        print(f"  SAPIEN's GPU physics library (PhysX {lib['physx_version']}): {lib['path']} "
              f"{'present' if lib['present'] else 'MISSING' + (' (pretended: ' + FAKE_VAR + '=nolib)' if fake == 'nolib' else '')}")
        if not lib["present"]:
            print(f"  to supply it: on a machine with internet download {lib['url']} and unzip it into {lib['dir']}/ "
                  f"(or copy ~/.sapien/physx/ from a machine where physx_cuda has run); until then the "
                  f"GPU-simulation sections are SKIPPED")
    info["physx_gpu_library"] = lib
    try:
        from maniskill_dualher.envs import gpu_memory_config
        m = gpu_memory_config(a.gpu_memory_scale)
        print(f"  PhysX GPU buffers (--gpu-memory-scale {a.gpu_memory_scale:g}): rigid contacts {m['max_rigid_contact_count']}, "
              f"patches {m['max_rigid_patch_count']}, found/lost pairs {m['found_lost_pairs_capacity']}, heap "
              f"{m['heap_capacity'] / 2**20:.0f} MiB, temp buffer {m['temp_buffer_capacity'] / 2**20:.0f} MiB")
    except Exception as e:  # noqa: BLE001
        print(f"  PhysX GPU buffers: cannot tell ({type(e).__name__}: {_one_line(e)})")
    sys.stdout.flush()
    return info


def _child_argv(a, name: str, tasks: Sequence[str]) -> List[str]:
    return [sys.executable, os.path.abspath(__file__), "--_section", name, "--tasks", ",".join(tasks),
            "--envs", ",".join(map(str, a.envs)), "--steps", str(a.steps), "--speed-steps", str(a.speed_steps),
            "--train-steps", str(a.train_steps), "--gpu-memory-scale", repr(a.gpu_memory_scale)]


def run_section(a, name: str, tasks: Sequence[str]) -> dict:
    """Run one section in a child process (its own session) under --timeout; stream its lines indented."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    err = tempfile.TemporaryFile()
    t0 = time.perf_counter()
    p = subprocess.Popen(_child_argv(a, name, tasks), stdout=subprocess.PIPE, stderr=err, stdin=subprocess.DEVNULL,
                         env=env, start_new_session=True, text=True, errors="replace", cwd=REPO)
    box: dict = {}

    def read():
        for line in p.stdout:
            if line.startswith(RESULT_TAG):
                try:
                    box["result"] = json.loads(line[len(RESULT_TAG):])
                except json.JSONDecodeError:
                    pass
            else:
                print("  " + line.rstrip("\n"), flush=True)

    th = threading.Thread(target=read, daemon=True)
    th.start()
    timed_out = False
    try:
        p.wait(timeout=a.timeout)
    except subprocess.TimeoutExpired:
        timed_out = True
        try:
            os.killpg(p.pid, signal.SIGKILL)  # the section and anything it started
        except ProcessLookupError:
            pass
        p.wait()
    th.join(timeout=5)
    seconds = time.perf_counter() - t0
    err.seek(0)
    stderr = err.read().decode("utf-8", "replace")
    err.close()
    tail = [ln for ln in stderr.splitlines() if ln.strip()][-6:]
    res = box.get("result")
    if timed_out:
        res = {"status": "FAIL", "reason": f"timed out after {a.timeout:g} s (killed)", "data": None}
    elif res is None:
        sig = ""
        if p.returncode < 0:
            try:
                sig = f", {signal.Signals(-p.returncode).name}"
            except ValueError:
                pass
        res = {"status": "FAIL", "data": None,
               "reason": f"its process died (exit code {p.returncode}{sig}) without a result"
                         + (f"; last stderr line: {tail[-1][:200]}" if tail else "")}
    res.update(seconds=round(seconds, 1), stderr_tail=tail)
    return res


def _print_result(name: str, res: dict) -> None:
    s = res["status"]
    line = f"{name}: {s}" + (f": {res['reason']}" if s != "PASS" and res.get("reason") else "")
    if "seconds" in res:
        line += f" ({res['seconds']:.1f} s)"
    print(line, flush=True)
    if s == "FAIL":
        for ln in res.get("stderr_tail", []):
            print(f"  stderr: {ln[:300]}", flush=True)


def _csv(text: str) -> List[str]:
    return [x.strip() for x in str(text).split(",") if x.strip()]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python bench/gpu_check.py", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--envs", default="16,64", help="parallel env counts, comma list (default 16,64): the largest is "
                   "used by success, idle_drift, partial_reset and contact_overflow, the smallest by startup and "
                   "train_split, each by env_speed")
    p.add_argument("--timeout", type=float, default=120.0, help="time limit of each section in seconds (default 120)")
    p.add_argument("--sections", default=",".join(DEFAULT_SECTIONS),
                   help=f"comma list, run in this order (default all: {','.join(DEFAULT_SECTIONS)})")
    p.add_argument("--tasks", default=",".join(TASKS), help=f"comma list (default {','.join(TASKS)})")
    p.add_argument("--steps", type=int, default=300, help="steps of the success section (default 300)")
    p.add_argument("--speed-steps", type=int, default=100, help="timed steps per env count in env_speed (default 100)")
    p.add_argument("--train-steps", type=int, default=4000, help="env steps of the train_split run (default 4000)")
    p.add_argument("--gpu-memory-scale", type=float, default=1.0,
                   help="RunConfig.gpu_memory_scale of every env made here (PhysX GPU buffer sizes x this; default 1)")
    p.add_argument("--json", help="also write the preflight and every section's result to this JSON file")
    p.add_argument("--_section", help=argparse.SUPPRESS)
    return p


def parse_args(argv=None):
    p = build_parser()
    a = p.parse_args(argv)
    try:
        a.envs = [int(x) for x in _csv(a.envs)]
    except ValueError:
        p.error(f"--envs must be a comma list of integers, got {a.envs!r}")
    if not a.envs or min(a.envs) < 1:
        p.error("--envs needs at least one count >= 1")
    a.tasks = _csv(a.tasks)
    unknown = [t for t in a.tasks if t not in TASKS]
    if unknown:
        p.error(f"unknown task {unknown[0]!r} (choose from {', '.join(TASKS)})")
    a.sections = _csv(a.sections)
    allowed = [n for n, s in SECTIONS.items() if not s.stub or fake_mode()]
    for n in a.sections + ([a._section] if a._section else []):
        if n not in allowed:
            p.error(f"unknown section {n!r} (choose from {', '.join(DEFAULT_SECTIONS)})")
    if a.timeout <= 0 or a.steps < 1 or a.speed_steps < 1 or a.train_steps < 1:
        p.error("--timeout, --steps, --speed-steps and --train-steps must be positive")
    if not (a.gpu_memory_scale > 0 and math.isfinite(a.gpu_memory_scale)):
        p.error(f"--gpu-memory-scale must be a finite number > 0, got {a.gpu_memory_scale}")
    return a


def main(argv=None) -> int:
    a = parse_args(argv)
    if a._section:
        return child_main(a)
    fake = fake_mode()
    if not fake:
        import torch
        if not torch.cuda.is_available():
            build = f"CUDA build {torch.version.cuda}" if torch.version.cuda else "a build without CUDA"
            print(f"error: no CUDA GPU: torch.cuda.is_available() is False (torch {torch.__version__}, {build})",
                  file=sys.stderr)
            return 2
    t_start = time.perf_counter()
    info = preflight(a, fake)
    lib_ok = bool(info["physx_gpu_library"].get("present")) or (fake == "1")
    names = list(a.sections)
    if lib_ok and any(SECTIONS[n].gpu_sim and not SECTIONS[n].stub for n in names) and "startup" not in names:
        names.insert(0, "startup")  # the gate of the GPU-simulation sections
    tasks = list(a.tasks)
    startup_reason = None
    results: Dict[str, dict] = {}
    for name in names:
        sec = SECTIONS[name]
        if sec.gpu_sim and not lib_ok:
            res = {"status": "SKIPPED", "reason": missing_library_reason(info["physx_gpu_library"])}
        elif sec.gpu_sim and name != "startup" and not sec.stub and startup_reason is not None:
            res = {"status": "SKIPPED", "reason": startup_reason}
        else:
            res = run_section(a, name, tasks if sec.gpu_sim else a.tasks)
            if name == "startup":
                data = res.get("data")
                if res["status"] == "SKIPPED":
                    startup_reason = f"startup was skipped: {res['reason']}"
                elif isinstance(data, dict) and "tasks_ok" in data:
                    left_out = [t for t in tasks if t not in data["tasks_ok"]]
                    tasks = [t for t in tasks if t in data["tasks_ok"]]
                    if left_out:
                        print(f"  left out of the later sections (they did not start): {', '.join(left_out)}")
                    if not tasks:
                        startup_reason = f"no task's GPU simulation started (startup: {res['reason'][:200]})"
                elif res["status"] == "FAIL":  # crashed or timed out: no list of tasks that started
                    startup_reason = f"GPU simulation did not start (startup: {res['reason'][:200]})"
        results[name] = res
        _print_result(name, res)
    failed = [n for n, r in results.items() if r["status"] == "FAIL"]
    skipped = [n for n, r in results.items() if r["status"] == "SKIPPED"]
    passed = [n for n, r in results.items() if r["status"] == "PASS"]
    print(f"gpu_check: {len(passed)} PASS, {len(failed)} FAIL" + (f" ({', '.join(failed)})" if failed else "")
          + f", {len(skipped)} SKIPPED" + (f" ({', '.join(skipped)})" if skipped else "")
          + f"; {time.perf_counter() - t_start:.0f} s", flush=True)
    if a.json:
        doc = {"bench": "gpu_check", "version": 2, "argv": sys.argv[1:] if argv is None else list(argv),
               "fake": fake or None, "preflight": info, "sections": results,
               "finished": time.strftime("%Y-%m-%dT%H:%M:%S%z")}
        os.makedirs(os.path.dirname(os.path.abspath(a.json)), exist_ok=True)
        tmp = a.json + ".tmp"
        with open(tmp, "w") as f:
            json.dump(doc, f, indent=1, default=str)
            f.write("\n")
        os.replace(tmp, a.json)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
