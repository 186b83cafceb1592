"""GPU check: our tasks and our training loop on ManiSkill's GPU simulation (one NVIDIA GPU, <= 5 minutes).

Sections (each one prints its lines; a failure prints one line ``<section>: FAILED: ...`` and the check
goes on to the next section; the exit code is 1 if any section failed, 0 otherwise):

* ``device``: ``torch.cuda.get_device_name()``, compute capability, memory, torch and CUDA versions.
* ``env <task>`` for ReachTarget-v1, CloseBox-v1, CloseMicrowave-v1: ``gym.make(task, num_envs=256,
  sim_backend="physx_cuda", obs_mode="state", reward_mode="sparse", render_backend="none")``, reset, 100
  uniformly random steps timed (env steps/s = num_envs x steps / seconds, CUDA synchronised).
* ``solver <task>``: the scripted solver (``maniskill_dualher.tasks.solvers.make_solver(env)``; ``solver.act(obs)`` returns
  env-scaled actions), batched over all envs, for one episode (the task's ``max_episode_steps``); reports
  the fraction of envs that succeeded at some step (target >= 0.9: below it the section fails).
  In both env sections ``info["success"]`` must equal ``env.unwrapped.compute_reward(info["achieved_goal"],
  info["desired_goal"], {}) > 0.5`` at every step for every env (any mismatch fails the section).
* ``train``: a ReachTarget-v1 run of ``maniskill_dualher.train.Trainer`` with ``base_config(PRESETS["quick"],
  "sac_her_per", 0)`` and ``sim_backend="physx_cuda"``, ``num_envs=64``, ``device="cuda"``, stopped by wall
  time (``--train-seconds``, default 120; slices of ``run(stop_at=...)``, each slice boundary resets the
  envs; checkpoints off); reports env steps/s and updates/s, and one evaluation at the end.

    python bench/gpu_check.py [--out results/gpu/gpu_check.json] [--num-envs 256] [--train-seconds 120]

Everything printed also goes to ``--out`` (JSON, written atomically after every section). Without CUDA it
prints one line to stderr and exits 2.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
import traceback
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)
TASKS = ("ReachTarget-v1", "CloseBox-v1", "CloseMicrowave-v1")
DEFAULT_OUT = os.path.join(REPO, "results", "gpu", "gpu_check.json")
SOLVER_TARGET = 0.9
NO_CUDA = "error: bench/gpu_check.py needs a CUDA GPU (torch.cuda.is_available() is False)"


class CheckFailed(Exception):
    """A measured value missed its target (the results are recorded before this is raised)."""


def atomic_write_json(path: str, doc: dict) -> None:
    # late: importing the package loads ManiSkill, which the no-CUDA exit must not wait for (or hear from)
    from maniskill_dualher.fileio import atomic_write_text
    atomic_write_text(path, json.dumps(doc, indent=1, default=str) + "\n")


class Report:
    def __init__(self, out: str, doc: dict):
        self.out, self.doc, self.failed = out, doc, []

    def section(self, name: str) -> "Section":
        return Section(self, name)

    def save(self) -> None:
        try:
            atomic_write_json(self.out, self.doc)
        except OSError as e:
            print(f"warning: cannot write {self.out}: {e}", file=sys.stderr)


class Section:
    """``with report.section(name) as d:`` -- d collects results; an exception becomes one FAILED line."""

    def __init__(self, report: Report, name: str):
        self.r, self.name, self.d = report, name, {}

    def __enter__(self) -> dict:
        self.t0 = time.perf_counter()
        return self.d

    def __exit__(self, et, ev, tb) -> bool:
        self.d["seconds"] = round(time.perf_counter() - self.t0, 3)
        if et is not None and not issubclass(et, Exception):
            return False  # KeyboardInterrupt, SystemExit: stop
        if et is not None:
            msg = str(ev).splitlines()[0] if str(ev) else ""
            line = f"{self.name}: FAILED: {et.__name__ if et is not CheckFailed else 'check'}: {msg}".rstrip(": ")
            print(line, flush=True)
            self.d.update(ok=False, error=line,
                          traceback="" if et is CheckFailed else "".join(traceback.format_exception(et, ev, tb, limit=8)))
            self.r.failed.append(self.name)
        else:
            self.d["ok"] = True
        self.r.doc["sections"][self.name] = self.d
        self.r.save()
        return True  # swallow: go on with the next section


# --------------------------------------------------------------------------- sections
def section_device(d: dict) -> None:
    import torch
    p = torch.cuda.get_device_properties(0)
    d.update(device_name=torch.cuda.get_device_name(), capability=".".join(map(str, torch.cuda.get_device_capability())),
             memory_gib=round(p.total_memory / 2**30, 1), torch=torch.__version__, cuda=torch.version.cuda,
             device_count=torch.cuda.device_count())
    print(f"device: {d['device_name']}, capability {d['capability']}, {d['memory_gib']} GiB, torch {d['torch']}, "
          f"CUDA {d['cuda']} ({d['device_count']} visible)", flush=True)


def _mismatches(u, info) -> int:
    """Envs where info["success"] != (compute_reward(achieved, desired) > 0.5)."""
    r = u.compute_reward(info["achieved_goal"], info["desired_goal"], {})
    return int((info["success"].bool() != (r > 0.5)).sum().item())


def make_gpu_env(task: str, num_envs: int):
    import gymnasium as gym
    import maniskill_dualher  # noqa: F401  (registers the tasks)
    return gym.make(task, num_envs=num_envs, sim_backend="physx_cuda", obs_mode="state", reward_mode="sparse",
                    render_backend="none")


def section_env(task: str, num_envs: int, steps: int, d: dict, envs: dict) -> None:
    import torch
    t0 = time.perf_counter()
    env = make_gpu_env(task, num_envs)
    envs[task] = env
    u = env.unwrapped
    n = int(u.num_envs)
    d["make_s"] = round(time.perf_counter() - t0, 2)
    t0 = time.perf_counter()
    obs, info = env.reset(seed=0)
    torch.cuda.synchronize()
    d["reset_s"] = round(time.perf_counter() - t0, 3)
    space = u.single_action_space
    low = torch.as_tensor(space.low, device=u.device, dtype=torch.float32)
    high = torch.as_tensor(space.high, device=u.device, dtype=torch.float32)
    g = torch.Generator(device=u.device).manual_seed(0)
    mism, dt, succ = 0, 0.0, 0
    for _ in range(steps):
        a = low + (high - low) * torch.rand((n, low.numel()), device=u.device, generator=g)
        torch.cuda.synchronize()
        t0 = time.perf_counter()
        obs, rew, term, trunc, info = env.step(a)
        torch.cuda.synchronize()
        dt += time.perf_counter() - t0
        mism += _mismatches(u, info)
        succ += int(info["success"].sum().item())
    d.update(num_envs=n, random_steps=steps, step_s=round(dt, 4), env_steps_per_s=round(n * steps / dt, 1),
             random_successes=succ, success_reward_mismatches=mism, checked=n * steps, obs_dim=int(obs.shape[-1]))
    print(f"env {task}: make {d['make_s']} s, reset {d['reset_s']} s; {n} envs x {steps} random steps in {dt:.2f} s "
          f"= {d['env_steps_per_s']:.0f} env steps/s; success vs compute_reward mismatches {mism}/{n * steps}",
          flush=True)
    if mism:
        raise CheckFailed(f"info['success'] != compute_reward > 0.5 at {mism} of {n * steps} env-steps")


def section_solver(task: str, d: dict, envs: dict) -> None:
    import gymnasium as gym
    import torch
    from maniskill_dualher.tasks.solvers import make_solver
    env = envs.get(task)
    if env is None:
        raise CheckFailed(f"no env (its 'env {task}' section failed)")
    u = env.unwrapped
    n = u.num_envs
    T = int((env.spec and env.spec.max_episode_steps) or gym.spec(task).max_episode_steps or 150)
    obs, info = env.reset(seed=1)
    solver = make_solver(env)
    solver.reset()
    once = torch.zeros(n, dtype=torch.bool, device=u.device)
    first = torch.full((n,), -1, dtype=torch.long, device=u.device)
    mism = 0
    t0 = time.perf_counter()
    for t in range(T):
        obs, rew, term, trunc, info = env.step(solver.act(obs))
        s = info["success"].bool()
        first = torch.where(s & ~once, torch.full_like(first, t + 1), first)
        once |= s
        mism += _mismatches(u, info)
    torch.cuda.synchronize()
    dt = time.perf_counter() - t0
    frac = float(once.float().mean().item())
    hit = first[first > 0].float()
    med = float(hit.median().item()) if hit.numel() else math.nan
    d.update(num_envs=n, episode_steps=T, success_fraction=round(frac, 4), successes=int(once.sum().item()),
             median_first_success_step=med, success_reward_mismatches=mism, checked=n * T, seconds_episode=round(dt, 2),
             target=SOLVER_TARGET)
    ok = frac >= SOLVER_TARGET and not mism
    print(f"solver {task}: success {d['successes']}/{n} = {frac:.3f} (target >= {SOLVER_TARGET}) in one {T}-step "
          f"episode ({dt:.1f} s), median first success at step {med:g}; success vs compute_reward mismatches "
          f"{mism}/{n * T}: {'ok' if ok else 'FAIL'}", flush=True)
    env.close()
    envs.pop(task, None)
    if frac < SOLVER_TARGET:
        raise CheckFailed(f"solver success fraction {frac:.3f} < {SOLVER_TARGET}")
    if mism:
        raise CheckFailed(f"info['success'] != compute_reward > 0.5 at {mism} of {n * T} env-steps")


def section_train(d: dict, seconds: float, num_envs: int) -> None:
    import torch
    from maniskill_dualher.sweep import PRESETS, base_config
    from maniskill_dualher.train import Trainer
    if seconds < 15:
        raise CheckFailed(f"training budget {seconds:.0f} s < 15 s (--train-seconds, or what the --budget leaves)")
    cfg = base_config(PRESETS["quick"], "sac_her_per", 0)
    cfg.env_id, cfg.sim_backend, cfg.num_envs, cfg.device = "ReachTarget-v1", "physx_cuda", num_envs, "cuda"
    cfg.total_steps = 10**9
    cfg.eval_every = cfg.checkpoint_every = 10**9  # no evaluation or checkpoint inside the timed slices
    tmp = tempfile.mkdtemp(prefix="gpu_check_train_")
    t0 = time.perf_counter()
    tr = Trainer(cfg, os.path.join(tmp, "run"), show_progress=False)
    tr.save_checkpoint = lambda: None
    d["setup_s"] = round(time.perf_counter() - t0, 2)
    s = cfg.sac
    d["config"] = dict(env_id=cfg.env_id, num_envs=num_envs, hidden=list(s.hidden), batch_size=s.batch_size,
                       updates_per_step=s.updates_per_step, random_steps=s.random_steps,
                       learning_starts=s.learning_starts, variant=s.variant, lr=s.lr, gamma=s.gamma,
                       max_episode_steps=tr.spec.max_episode_steps,
                       terminate_on_success=getattr(cfg, "terminate_on_success", None))
    slices = []
    wall, steady, min_slice = 0.0, None, math.inf
    warm = max(s.learning_starts, s.random_steps)
    try:
        while wall < seconds:
            # short probe slices (16 batched steps; a slice ends at the first episode end after its target)
            # until one runs wholly past the random/learning-start phase; its rate sizes the next slices
            # (~20 s each; every slice boundary resets the envs)
            n = 16 * num_envs if steady is None else max(num_envs, int(steady * min(20.0, seconds - wall)))
            if steady is not None and max(n, min_slice) / steady > 1.1 * (seconds - wall):
                break  # the next slice would overrun the budget
            s0, u0 = tr.env_steps, tr.updates
            learning = s0 >= warm
            t0 = time.perf_counter()
            tr.run(stop_at=tr.env_steps + n)
            torch.cuda.synchronize()
            dt = time.perf_counter() - t0
            wall += dt
            slices.append(dict(env_steps=tr.env_steps - s0, updates=tr.updates - u0, seconds=round(dt, 3),
                               learning=learning))
            if learning:
                steady = (tr.env_steps - s0) / dt
                min_slice = min(min_slice, tr.env_steps - s0)
            if steady is not None and steady * (seconds - wall) < num_envs:  # not one more batched step fits
                break
        learn = [x for x in slices if x["learning"]]
        d.update(env_steps=tr.env_steps, updates=tr.updates, seconds=round(wall, 2),
                 env_steps_per_s=round(tr.env_steps / wall, 1), updates_per_s=round(tr.updates / wall, 1),
                 learning_env_steps_per_s=round(sum(x["env_steps"] for x in learn) / max(1e-9, sum(x["seconds"] for x in learn)), 1),
                 learning_updates_per_s=round(sum(x["updates"] for x in learn) / max(1e-9, sum(x["seconds"] for x in learn)), 1),
                 train_episodes=tr.episodes, train_successes=tr.successes, slices=slices)
        print(f"train: ReachTarget-v1 sac_her_per ('quick' preset, {num_envs} envs, {cfg.device}, hidden {list(s.hidden)}, "
              f"UTD {s.updates_per_step:g}): {tr.env_steps} env steps, {tr.updates} updates in {wall:.1f} s = "
              f"{d['env_steps_per_s']:.0f} env steps/s, {d['updates_per_s']:.0f} updates/s (slices past learning start: "
              f"{d['learning_env_steps_per_s']:.0f} env steps/s, {d['learning_updates_per_s']:.0f} updates/s); "
              f"{tr.episodes} training episodes, {tr.successes} successful", flush=True)
        t0 = time.perf_counter()
        ev = tr.evaluate()
        d["eval"] = dict(ev, seconds=round(time.perf_counter() - t0, 2))
        print(f"train: evaluation after {tr.env_steps} env steps ({cfg.eval_episodes} episodes, deterministic): "
              f"success {ev['eval_success_rate']:.2f}, return {ev['eval_return']:.2f} ({d['eval']['seconds']} s)",
              flush=True)
    finally:
        tr.env.close()
        import shutil
        shutil.rmtree(tmp, ignore_errors=True)


# --------------------------------------------------------------------------- main
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--out", default=DEFAULT_OUT, help="JSON report (default results/gpu/gpu_check.json)")
    p.add_argument("--num-envs", type=int, default=256, help="parallel envs in the env/solver sections")
    p.add_argument("--random-steps", type=int, default=100, help="timed random steps per task")
    p.add_argument("--train-num-envs", type=int, default=64, help="parallel envs of the training run")
    p.add_argument("--train-seconds", type=float, default=120.0, help="wall-clock budget of the training run")
    p.add_argument("--budget", type=float, default=290.0, help="the whole check's wall-clock budget (s); the "
                   "training run is shortened to fit it")
    args = p.parse_args(argv)
    start = time.perf_counter()
    warnings.filterwarnings("ignore")

    import torch
    if not torch.cuda.is_available():
        print(NO_CUDA, file=sys.stderr)
        return 2

    doc = {"bench": "gpu_check", "version": 1, "complete": False,
           "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "argv": sys.argv[1:] if argv is None else list(argv),
           "device_name": torch.cuda.get_device_name(), "sections": {}}
    rep = Report(args.out, doc)
    with rep.section("device") as d:
        section_device(d)
    envs: dict = {}
    for task in TASKS:
        with rep.section(f"env {task}") as d:
            section_env(task, args.num_envs, args.random_steps, d, envs)
        with rep.section(f"solver {task}") as d:
            section_solver(task, d, envs)
        for env in envs.values():  # an env whose solver section failed early
            try:
                env.close()
            except Exception:
                pass
        envs.clear()
        torch.cuda.empty_cache()
    with rep.section("train") as d:
        left = args.budget - (time.perf_counter() - start) - 25.0  # setup, evaluation, teardown
        section_train(d, min(args.train_seconds, left), args.train_num_envs)
    doc.update(complete=True, failed=rep.failed, seconds=round(time.perf_counter() - start, 1))
    rep.save()
    print(f"gpu_check: {len(doc['sections']) - len(rep.failed)}/{len(doc['sections'])} sections ok"
          + (f"; failed: {', '.join(rep.failed)}" if rep.failed else "")
          + f"; {doc['seconds']} s; report {os.path.relpath(args.out)}", flush=True)
    return 1 if rep.failed else 0


if __name__ == "__main__":
    sys.exit(main())
