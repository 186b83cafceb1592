"""Evaluation's Python per episode and replay sampling per batch: this tree (A) against a frozen clone (B).

    python bench/eval_cpu.py --base <clone> [--tasks ID,ID,...]   # default: config.TASKS
        [--members 3] [--evals 3] [--batches 2000] [--fill 20000] [--order ABBA] [--json FILE]

Each measurement runs in a fresh process with ``PYTHONPATH`` set to its side's tree, the sides interleaved in
``--order`` (ABBA: each side once first and once second, so the machine's drift cancels), using only entry points
both trees have (``train.Trainer``, ``Trainer.evaluate``, ``method.sample``/``update_priorities``):

* **evaluation**: a pack of ``--members`` quick-preset ``dual_buffer`` runs (seeds 0..S-1, untrained actors)
  evaluates ``--evals`` times; each time every member evaluates (10 episodes), side by side where the tree has
  ``train.evaluate_runs`` (A), one after the other otherwise (B). Timed: wall and thread CPU, and PhysX's
  substeps (``scene.px.step``) apart, so "python" = the rest (env Python, resets, acting, bookkeeping); per
  episode and per evaluation env step.
* **sampling**: one ``dual_buffer`` run's replay filled with ``--fill`` synthetic real transitions (episodes of
  100 steps, HER k = 4, so 5x the rows in R), then ``--batches`` times ``sample(256)`` + ``update_priorities``
  with |TD| from a seeded stream; per batch.

Both sides must give the same numbers: the evaluation metrics and a digest of every sampled index, weight and
the sum tree are compared (``identical``). Writes raw JSON (``--json``, else printed): every process's numbers,
medians per side, B/A ratios, the commits and the machine (``provenance.machine_name``). Run it on an idle
machine; on a loaded one the CPU-time columns are the ones to read.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
from maniskill_dualher.config import TASKS  # noqa: E402  (the catalog; a worker reads its own tree's)


# --------------------------------------------------------------------------- inside a measurement's process
class _Px:
    """scene.px with its step timed (pybind attributes cannot be patched; the scene's reference can)."""

    def __init__(self, px, clock):
        object.__setattr__(self, "_px", px)
        object.__setattr__(self, "_clock", clock)

    def __getattr__(self, k):
        return getattr(self._px, k)

    def step(self):
        c = self._clock
        w, t = time.perf_counter(), time.thread_time()
        self._px.step()
        c["wall"] += time.perf_counter() - w
        c["cpu"] += time.thread_time() - t
        c["n"] += 1


def _trainers(task: str, members: int, tmp: str):
    from maniskill_dualher.experiment.presets import preset
    from maniskill_dualher.train import Trainer
    runs = []
    for seed in range(members):
        cfg = preset("quick").single_config("dual_buffer", seed, task)
        cfg.validate()
        runs.append(Trainer(cfg, os.path.join(tmp, f"{task}-{seed}"), show_progress=False))
    return runs


def measure_eval(task: str, members: int, evals: int) -> dict:
    import numpy as np  # noqa: F401  (imported before timing)
    from maniskill_dualher import train
    clock = {"wall": 0.0, "cpu": 0.0, "n": 0}
    with tempfile.TemporaryDirectory() as tmp:
        runs = _trainers(task, members, tmp)
        for r in runs:
            r.env.unwrapped.scene.px = _Px(r.env.unwrapped.scene.px, clock)
        side_by_side = hasattr(train, "evaluate_runs")

        def one_round():
            if side_by_side:
                got = train.evaluate_runs(runs, lambda run, e: (_ for _ in ()).throw(e))
                # the metrics per run: returned (issue 40), or each run's ``evaluated`` (older trees)
                return [got[r] if got is not None else r.evaluated for r in runs]
            return [r.evaluate() for r in runs]

        one_round()  # warm-up: imports, first allocations
        rows, walls, cpus = [], [], []
        px = {"wall": 0.0, "cpu": 0.0, "n": 0}
        for _ in range(evals):
            clock.update(wall=0.0, cpu=0.0, n=0)
            w, t = time.perf_counter(), time.thread_time()
            rows.append(one_round())
            walls.append(time.perf_counter() - w)
            cpus.append(time.thread_time() - t)
            for k in px:
                px[k] += clock[k]
        episodes = evals * sum(r.cfg.eval_episodes for r in runs)
        steps = round(sum(m["eval_episode_length"] * r.cfg.eval_episodes for m, r in zip(rows[-1], runs))) * evals
        for r in runs:
            r.close()
    wall, cpu = sum(walls), sum(cpus)
    return {"task": task, "members": members, "evals": evals, "side_by_side": side_by_side, "episodes": episodes,
            "eval_env_steps": steps, "wall_s": wall, "cpu_s": cpu, "physics_wall_s": px["wall"],
            "physics_cpu_s": px["cpu"], "substeps": px["n"],
            "python_wall_ms_per_episode": 1e3 * (wall - px["wall"]) / episodes,
            "python_cpu_ms_per_episode": 1e3 * (cpu - px["cpu"]) / episodes,
            "python_cpu_us_per_step": 1e6 * (cpu - px["cpu"]) / max(1, steps),
            "metrics": rows[-1]}


def _synthetic_episode(spec, rng, T: int = 100):
    import numpy as np
    from maniskill_dualher.replay.base import Episode
    O, G, A = spec.obs_dim, spec.goal_dim, spec.act_dim
    ag = rng.uniform(-0.3, 0.3, (T + 1, 1, G)).astype(np.float32)
    dg = np.broadcast_to(ag[-1] + rng.normal(0, 0.02, (1, G)).astype(np.float32), (T, 1, G)).copy()
    obs = rng.normal(size=(T + 1, 1, O)).astype(np.float32)
    reward = spec.reward_fn(ag[1:].reshape(T, G), dg.reshape(T, G), None).reshape(T, 1)
    return Episode(obs=obs[:-1], action=rng.uniform(-1, 1, (T, 1, A)).astype(np.float32), reward=reward,
                   next_obs=obs[1:], terminated=np.zeros((T, 1), bool), achieved_goal=ag[:-1],
                   next_achieved_goal=ag[1:], desired_goal=dg, success=reward > 0.5, goal_terminal=True)


def measure_sampling(task: str, fill: int, batches: int) -> dict:
    import numpy as np
    with tempfile.TemporaryDirectory() as tmp:
        run = _trainers(task, 1, tmp)[0]
        m, spec = run.method, run.spec
        rng = np.random.default_rng(0)
        for _ in range(max(1, fill // 100)):
            m.add_episode(_synthetic_episode(spec, rng))
        td_rng = np.random.default_rng(1)
        B = run.cfg.sac.batch_size
        digest = hashlib.sha256()
        for _ in range(50):  # warm-up (also part of the compared stream)
            b = m.sample(B)
            m.update_priorities(b, td_rng.random(B))
        times, cpus = [], []
        for _ in range(batches):
            td = td_rng.random(B)
            w, t = time.perf_counter(), time.thread_time()
            b = m.sample(B)
            m.update_priorities(b, td)
            times.append(time.perf_counter() - w)
            cpus.append(time.thread_time() - t)
            digest.update(np.asarray(b.handle.indices).tobytes())
            digest.update(b.obs.numpy().tobytes())
            if b.weights is not None:
                digest.update(b.weights.numpy().tobytes())
        tree = m.main.sampler.tree
        digest.update(tree.tree[:2 * tree.P].tobytes())
        rows = len(m.main)
        run.close()
    return {"task": task, "fill_transitions": fill, "replay_rows": rows, "batch_size": B, "batches": batches,
            "us_per_batch_wall_median": 1e6 * statistics.median(times), "us_per_batch_wall_mean": 1e6 * statistics.mean(times),
            "us_per_batch_cpu_mean": 1e6 * statistics.mean(cpus), "digest": digest.hexdigest()}


def worker(args) -> int:
    import torch
    torch.set_num_threads(1)
    out = {"eval": [measure_eval(t, args.members, args.evals) for t in args.tasks.split(",")],
           "sampling": [measure_sampling(t, args.fill, args.batches) for t in args.tasks.split(",")]}
    print(json.dumps(out))
    return 0


# --------------------------------------------------------------------------- the driver
def git_commit(tree: Path) -> str:
    r = subprocess.run(["git", "-C", str(tree), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    dirty = subprocess.run(["git", "-C", str(tree), "status", "--porcelain", "--untracked-files=no"],
                           capture_output=True, text=True).stdout.strip()
    return (r.stdout.strip() or "unknown") + ("+dirty" if dirty else "")


def _side(tree: Path, a) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    env.pop("MANISKILL_DUALHER_LEAN_STEP", None)  # each side's default path
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--tasks", a.tasks, "--members", str(a.members),
           "--evals", str(a.evals), "--batches", str(a.batches), "--fill", str(a.fill)]
    r = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"measurement in {tree} failed (exit {r.returncode}): {r.stderr.strip().splitlines()[-1:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def _bad(msg: str) -> int:
    print(f"error: {msg}", file=sys.stderr)
    return 2


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--base", help="a frozen clone of the base commit (side B)")
    p.add_argument("--tasks", default=",".join(TASKS))
    p.add_argument("--members", type=int, default=3, help="runs evaluating together (a pack)")
    p.add_argument("--evals", type=int, default=3, help="timed evaluations of every member per process")
    p.add_argument("--batches", type=int, default=2000, help="timed sample + priority update rounds per process")
    p.add_argument("--fill", type=int, default=20000, help="real transitions in the replay before sampling")
    p.add_argument("--order", default="ABBA", help="the processes' order, letters A and B")
    p.add_argument("--json", help="write the raw results here (else print them)")
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    bad_task = [t for t in a.tasks.split(",") if t not in TASKS]
    if bad_task:
        return _bad(f"--tasks {bad_task[0]!r} is not one of {', '.join(TASKS)}")
    for name in ("members", "evals", "batches", "fill"):
        if getattr(a, name) < 1:
            return _bad(f"--{name} must be >= 1, got {getattr(a, name)}")
    if a.worker:
        return worker(a)
    if a.base is None:
        return _bad("--base is required (a clone of the base commit)")
    base = Path(a.base).resolve()
    if not (base / "maniskill_dualher" / "train.py").is_file():
        return _bad(f"--base {a.base!r} is not a clone of this project")
    if not a.order or set(a.order) - {"A", "B"} or not {"A", "B"} <= set(a.order):
        return _bad(f"--order must use both letters A and B, like ABBA, got {a.order!r}")

    sys.path.insert(0, str(REPO))
    from maniskill_dualher.provenance import cpu_info, machine_label, machine_name
    trees = {"A": REPO, "B": base}
    commits = {k: git_commit(t) for k, t in trees.items()}
    load = " ".join(Path("/proc/loadavg").read_text().split()[:3]) if Path("/proc/loadavg").exists() else "?"
    print(f"machine: {machine_name(cpu_info())}; A = {REPO} ({commits['A']}), B = {base} ({commits['B']}); "
          f"load before: {load}", flush=True)
    procs = []
    for i, side in enumerate(a.order):
        res = _side(trees[side], a)
        procs.append({"i": i, "side": side, **res})
        print(f"  {i} {side}: " + ", ".join(f"{e['task']} eval python {e['python_cpu_ms_per_episode']:.1f} ms CPU/episode"
                                            for e in res["eval"])
              + "; " + ", ".join(f"sampling {s['us_per_batch_cpu_mean']:.0f} us CPU/batch" for s in res["sampling"]),
              flush=True)

    def med(side, kind, key, task):
        return statistics.median(r[key] for pr in procs if pr["side"] == side for r in pr[kind] if r["task"] == task)

    summary = []
    for task in a.tasks.split(","):
        row = {"task": task}
        for kind, key in (("eval", "python_cpu_ms_per_episode"), ("eval", "python_wall_ms_per_episode"),
                          ("eval", "python_cpu_us_per_step"), ("sampling", "us_per_batch_cpu_mean"),
                          ("sampling", "us_per_batch_wall_median")):
            va, vb = med("A", kind, key, task), med("B", kind, key, task)
            row[key] = {"A": va, "B": vb, "B_over_A": vb / va if va else None}
        summary.append(row)
        print(f"{task}: eval python x{row['python_cpu_ms_per_episode']['B_over_A']:.2f} "
              f"({row['python_cpu_ms_per_episode']['A']:.1f} vs {row['python_cpu_ms_per_episode']['B']:.1f} ms CPU/episode), "
              f"sampling x{row['us_per_batch_cpu_mean']['B_over_A']:.2f} "
              f"({row['us_per_batch_cpu_mean']['A']:.0f} vs {row['us_per_batch_cpu_mean']['B']:.0f} us CPU/batch)")
    ref = procs[0]
    identical = all([e["metrics"] for e in pr["eval"]] == [e["metrics"] for e in ref["eval"]]
                    and [s["digest"] for s in pr["sampling"]] == [s["digest"] for s in ref["sampling"]]
                    for pr in procs)
    print(f"evaluation metrics and sampled batches identical across every process of both sides: {identical}")
    doc = {"command": " ".join(["bench/eval_cpu.py"] + (sys.argv[1:] if argv is None else list(argv))),
           "machine": machine_name(cpu_info()), "cpu": machine_label(cpu_info()), "load_before": load,
           "commits": commits, "order": a.order, "members": a.members, "evals": a.evals, "batches": a.batches,
           "fill": a.fill, "processes": procs, "summary": summary, "identical": identical}
    text = json.dumps(doc, indent=1) + "\n"
    if a.json:
        from maniskill_dualher.fileio import atomic_write_text
        atomic_write_text(Path(a.json), text)
    else:
        print(text)
    return 0 if identical else 1


if __name__ == "__main__":
    sys.exit(main())
