"""Wall-clock seconds (and env steps) until evaluation success first reaches 0.9, ours vs two peers.

Tasks ReachTarget-v1 and CloseBox-v1 (``--tasks``). Contenders, each on one thread:

* ours: the ``sac_her_per`` method built exactly as the sweep's quick preset builds it
  (``base_config(PRESETS["quick"], "sac_her_per", seed)``, read at run time, so whatever the preset holds
  now), with ``env_id``, ``total_steps`` (= ``--max-steps``), ``eval_every`` and ``eval_episodes`` set here;
  run by ``maniskill_dualher.train.Trainer`` in slices (``run(stop_at=k * eval_every)``). Checkpoints are
  switched off (``save_checkpoint`` replaced by a no-op): the peers write none either.
* SB3: Stable-Baselines3 SAC + HerReplayBuffer; SBX: SBX (JAX; PyPI ``sbx-rl``; skipped with one line if not
  importable) SAC + SB3's HerReplayBuffer. Both at the rl-baselines3-zoo goal-task settings: net [64, 64],
  lr 1e-3, tau 0.05, gamma 0.95, batch 256, buffer 1e6, learning_starts 1000, HER future with
  n_sampled_goal=4, train_freq 1, gradient_steps 1 (everything else the libraries' defaults: learned
  entropy coefficient, uniform random actions before learning_starts). Driven by
  ``model.learn(eval_every, reset_num_timesteps=False)`` between evaluations.

Same episodes for all: the episode length is ours (the preset's ``max_episode_steps``, read from the env ours
builds); if ours ends episodes on success (``cfg.terminate_on_success``), the peers' env passes ManiSkill's
``terminated`` (= success) through, otherwise episodes are fixed-length. Same control and reward mode.
``sb3_own`` and ``sbx_own`` are the same peers at **their own convention**, as their users run HER: training
episodes of that length that do not end on success (evaluation as for everyone); ``ours_fixed`` is ours so
too (``terminate_on_success=False``). Three comparisons, each the fastest peer's median over ours': equal
semantics (ours vs sb3, sbx: "which code learns this MDP faster"), fixed-length episodes (ours_fixed vs
sb3_own, sbx_own: the same question at the peers' convention), and each at its own convention (ours vs
sb3_own, sbx_own: "how long would a user of each library wait"). ``ours_fixed`` takes ours' one declared
fixed-length setting (``OURS_FIXED``: the temperature starts at 1.0; ``--fixed-set`` replaces it), the same on
every task. ``--set`` changes ours' settings (both conventions); ``--seed-start`` and ``--combine`` split seeds
over processes and pool their raw files; every ratio gets a percentile bootstrap interval over seeds; time to
the threshold is given in wall time, process CPU time and env steps.

Evaluation: 10 fixed episodes (``--eval-episodes``) every ``--eval-every`` env steps (default 1000),
deterministic policy, reset seeds ``maniskill_dualher.envs.EVAL_SEED_BASE + i`` for all contenders (the
peers' evaluation env is reset with ours' seeds; every peer evaluation checks its initial states equal
those of the env ours builds), success = the env's ``info["success"]`` at any step of the episode. Ours
evaluates between episodes, so its evaluation points are the first episode end at or after each multiple
of ``eval_every``; the peers' are exact multiples.

Wall clock: ``time.perf_counter`` summed over the training slices and the evaluations (construction of
envs, networks and buffers excluded for all; SBX's JIT compilation included, as its users pay it). A run
that never reaches 0.9 within ``--max-steps`` counts as "not reached" (infinite in the medians).
Contenders alternate (ours s0, SB3 s0, SBX s0, ours s1, ...). Raw results, every evaluation point
included, go to ``--out`` (JSON, written atomically after every run).

    python bench/time_to_success.py [--tasks ReachTarget-v1,CloseBox-v1] [--seeds 3] [--max-steps 30000]
        [--eval-every 1000] [--eval-episodes 10] [--contenders ours,sb3,sbx,ours_fixed,sb3_own,sbx_own]
        [--out bench/results/time_to_success.json]
"""
from __future__ import annotations

import argparse
import datetime as _dt
import math
import os
import shutil
import sys
import tempfile
import time
import traceback
import warnings

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, REPO)
sys.path.insert(0, HERE)
warnings.filterwarnings("ignore")

# first: pins OpenMP/MKL threads to one and JAX to one thread, before numpy/torch/jax load
from _peers import (GoalDictEnv, atomic_write_json, cpu_name, evaluate_peer, lib_version,  # noqa: E402
                    loadavg, make_peer_sac, sbx_missing, thread_info)

import numpy as np  # noqa: E402
import torch  # noqa: E402

THRESHOLD = 0.9
TASKS = ("ReachTarget-v1", "CloseBox-v1")
CONTENDERS = ("ours", "sb3", "sbx", "ours_fixed", "sb3_own", "sbx_own")
DEFAULT_OUT = os.path.join(REPO, "bench", "results", "time_to_success.json")
# rl-baselines3-zoo goal-task settings (FetchReach: net [64, 64], learning_starts 1000; the goal tasks' lr,
# tau, gamma, buffer and HER settings)
ZOO = dict(net_arch=[64, 64], learning_rate=1e-3, tau=0.05, gamma=0.95, batch_size=256, buffer_size=1_000_000,
           learning_starts=1000, n_sampled_goal=4, train_freq=1, gradient_steps=1)
NAMES = {"ours": "ours sac_her_per", "sb3": "SB3 SAC + HER", "sbx": "SBX SAC + HER",
         "ours_fixed": "ours, fixed-length", "sb3_own": "SB3, own convention", "sbx_own": "SBX, own convention"}
# per comparison: ours' contender and the peers it is set against (the fastest peer's median over ours')
COMPARISONS = (("equal semantics", "ours", ("sb3", "sbx")),
               ("fixed-length episodes (the peers' own convention)", "ours_fixed", ("sb3_own", "sbx_own")),
               ("each at its own convention", "ours", ("sb3_own", "sbx_own")))


def peer_library(contender: str) -> str:
    """sb3_own -> sb3: the library behind a contender."""
    return contender[:-len("_own")] if contender.endswith("_own") else contender


# --------------------------------------------------------------------------- settings
def our_config(task: str, seed: int, args, fixed_length: bool = False):
    """Ours as the preset builds it; ``fixed_length``: training episodes that do not end on success (the
    peers' own convention; evaluation unchanged)."""
    from maniskill_dualher.experiment.presets import PRESETS
    cfg = PRESETS[args.preset].single_config("sac_her_per", seed, task)
    extra = tuple(getattr(args, "overrides", ())) + (tuple(getattr(args, "fixed_overrides", ())) if fixed_length else ())
    if extra:
        from maniskill_dualher.experiment import overrides
        cfg = overrides.apply(cfg, extra)
    if fixed_length:
        cfg.terminate_on_success = False
    cfg.total_steps = args.max_steps
    cfg.eval_every = args.eval_every
    cfg.eval_episodes = args.eval_episodes
    return cfg.validate()


def episode_rules(task: str, args) -> dict:
    """Ours' episode rules for this task (length, termination, control, reward, evaluation seeds) and the
    initial flat observation of every evaluation episode in the env ours builds (the peers must match)."""
    from maniskill_dualher.envs import EVAL_SEED_BASE, make_env
    cfg = our_config(task, 0, args)
    n = int(getattr(cfg, "num_envs", 1))
    if n != 1:
        raise SystemExit(f"error: the {args.preset!r} preset runs {n} envs per run; this bench compares one-env runs")
    env = make_env(cfg)
    try:
        seeds = [EVAL_SEED_BASE + i for i in range(cfg.eval_episodes)]
        init = [np.asarray(env.reset(s), np.float32).reshape(-1) for s in seeds]
        T = int(env.spec.max_episode_steps)
    finally:
        env.close()
    return dict(max_episode_steps=T, terminate_on_success=bool(getattr(cfg, "terminate_on_success", False)),
                control_mode=cfg.control_mode, reward_mode=cfg.reward_mode, eval_seeds=seeds, init_obs=init)


def shared_settings(cfg) -> dict:
    """The settings table every contender is compared under: ours' value and the peers' (rl-zoo) value per
    setting, so a reader sees at once what is equal and what is not."""
    s, r = cfg.sac, cfg.replay
    ours = {"network": list(s.hidden), "lr": s.lr, "batch": s.batch_size, "gamma": s.gamma, "tau": s.tau,
            "buffer": r.capacity, "learning_starts": s.learning_starts, "random_steps": s.random_steps,
            "train_freq (updates per env step)": s.updates_per_step,
            "temperature": f"{'learned' if s.resolved_learn_alpha() else 'fixed'}, starts {s.alpha:g}",
            "replay sampling": (f"prioritized, exponent {r.priority_exponent:g}, IS weights {r.is_weights}"
                                if r.priority_exponent > 0 else "uniform"),
            "HER": f"{r.her_strategy}, {r.her_k} goals stored per transition"}
    peers = {"network": ZOO["net_arch"], "lr": ZOO["learning_rate"], "batch": ZOO["batch_size"],
             "gamma": ZOO["gamma"], "tau": ZOO["tau"], "buffer": ZOO["buffer_size"],
             "learning_starts": ZOO["learning_starts"], "random_steps": ZOO["learning_starts"],
             "train_freq (updates per env step)": ZOO["train_freq"] * ZOO["gradient_steps"],
             "temperature": "learned, starts 1", "replay sampling": "uniform",
             "HER": f"future, {ZOO['n_sampled_goal']} goals per sampled transition, drawn at sampling time"}
    def same(a, b):
        try:
            return float(a) == float(b)
        except (TypeError, ValueError):
            return str(a) == str(b)
    return {k: {"ours": ours[k], "peers": peers[k], "equal": same(ours[k], peers[k])} for k in ours}


def describe_ours(cfg) -> str:
    s, r = cfg.sac, cfg.replay
    parts = [f"variant {s.variant}", f"net {list(s.hidden)}", f"lr {s.lr:g}", f"tau {s.tau:g}", f"gamma {s.gamma:g}",
             f"batch {s.batch_size}", f"capacity {r.capacity:g}", f"random_steps {s.random_steps}",
             f"learning_starts {s.learning_starts}", f"updates_per_step {s.updates_per_step:g}",
             f"HER {r.her_strategy} k={r.her_k}", f"priority_exponent {r.priority_exponent:g}"]
    for extra in ("update_schedule", "updates_per_episode"):
        if hasattr(s, extra):
            parts.append(f"{extra} {getattr(s, extra)}")
    return ", ".join(parts)


# --------------------------------------------------------------------------- one run each
def _point(env_steps: int, success: float, wall: float, cpu: float, **extra) -> dict:
    """One evaluation point; ``cpu_s``: the process's CPU time (all its threads) over the same slices as
    ``wall_s``, which a busy machine disturbs far less than the wall clock."""
    return {"env_steps": int(env_steps), "eval_success_rate": float(success), "wall_s": round(wall, 3),
            "cpu_s": round(cpu, 3), **extra}


def run_ours(task: str, seed: int, args, rules: dict, fixed_length: bool = False) -> dict:
    from maniskill_dualher.train import Trainer, run_one
    cfg = our_config(task, seed, args, fixed_length)
    tmp = tempfile.mkdtemp(prefix="tts_ours_")
    t_setup = time.perf_counter()
    tr = Trainer(cfg, os.path.join(tmp, "run"), show_progress=False)
    tr.save_checkpoint = lambda *a, **k: None  # no checkpoints (the peers write none)
    setup_s = time.perf_counter() - t_setup
    E = cfg.eval_every
    wall, cpu, curve, reached = 0.0, 0.0, [], None
    try:
        while True:
            before = tr.env_steps
            torch.set_num_threads(1)
            t0, c0 = time.perf_counter(), time.process_time()
            final = run_one(tr, stop_at=(tr.env_steps // E + 1) * E)
            wall += time.perf_counter() - t0
            cpu += time.process_time() - c0
            row = tr.rows[-1] if tr.rows else None
            if row is not None and (not curve or int(row["env_steps"]) != curve[-1]["env_steps"]):
                curve.append(_point(row["env_steps"], row["eval_success_rate"], wall, cpu, updates=int(row["updates"]),
                                    eval_episode_length=row.get("eval_episode_length"),
                                    loop_wall_time_s=row.get("wall_time_s")))
                if row["eval_success_rate"] >= THRESHOLD:
                    reached = curve[-1]
                    break
            if final is not None or tr.env_steps >= cfg.total_steps or tr.env_steps == before:
                break
        return dict(reached=reached is not None, curve=curve, setup_s=round(setup_s, 3), wall_s_total=round(wall, 3),
                    cpu_s_total=round(cpu, 3), env_steps_total=int(tr.env_steps), updates_total=int(tr.updates), config=cfg.to_dict())
    finally:
        tr.env.close()
        shutil.rmtree(tmp, ignore_errors=True)


def run_peer(contender: str, task: str, seed: int, args, rules: dict) -> dict:
    lib, own = peer_library(contender), contender.endswith("_own")
    kw = dict(max_episode_steps=rules["max_episode_steps"], control_mode=rules["control_mode"],
              reward_mode=rules["reward_mode"], terminate_on_success=rules["terminate_on_success"])
    t_setup = time.perf_counter()
    torch.set_num_threads(1)
    # own convention: training episodes never end on success; evaluation keeps the shared rules
    env = GoalDictEnv(task, **{**kw, "terminate_on_success": False}) if own else GoalDictEnv(task, **kw)
    eval_env = GoalDictEnv(task, **kw)
    model = make_peer_sac(lib, env, seed, **ZOO)
    setup_s = time.perf_counter() - t_setup
    E, cap, T = args.eval_every, args.max_steps, rules["max_episode_steps"]
    wall, cpu, curve, reached, mismatches = 0.0, 0.0, [], None, 0
    try:
        while model.num_timesteps < cap:
            n = min((model.num_timesteps // E + 1) * E, cap) - model.num_timesteps
            torch.set_num_threads(1)
            t0, c0 = time.perf_counter(), time.process_time()
            model.learn(total_timesteps=n, reset_num_timesteps=False, progress_bar=False)
            ev = evaluate_peer(model, eval_env, rules["eval_seeds"], T, initial_obs=True)
            wall += time.perf_counter() - t0
            cpu += time.process_time() - c0
            mismatches += sum(not np.allclose(a, b, atol=1e-6) for a, b in zip(ev.pop("initial_obs"), rules["init_obs"]))
            curve.append(_point(model.num_timesteps, ev["eval_success_rate"], wall, cpu, updates=int(model._n_updates),
                                eval_episode_length=ev["eval_mean_length"]))
            if ev["eval_success_rate"] >= THRESHOLD:
                reached = curve[-1]
                break
        return dict(reached=reached is not None, curve=curve, setup_s=round(setup_s, 3), wall_s_total=round(wall, 3),
                    cpu_s_total=round(cpu, 3), env_steps_total=int(model.num_timesteps), updates_total=int(model._n_updates),
                    eval_state_mismatches=int(mismatches), settings=dict(ZOO, lib=lib_version(lib),
                                                                         train_episodes_end_on_success=not own))
    finally:
        model.get_env().close()
        eval_env.close()


# --------------------------------------------------------------------------- summary
def _stats(xs):
    vals = sorted(xs)
    if not vals:
        return None
    return {"median": float(np.median(vals)), "min": float(vals[0]), "max": float(vals[-1]), "n": len(vals)}


# ours' one fixed-length setting for every task, declared before the equal-rules race (docs/speed.md: the
# temperature starts at 1.0, as the peers' does; the ablation in bench/results/fixed_length_ablation/)
OURS_FIXED = ("sac.alpha=1",)
KEYS = ("wall_s", "cpu_s", "env_steps")  # time to the threshold: wall clock, process CPU time, env steps
BOOT = 10_000  # bootstrap resamples for the ratio of medians


def ratio_interval(peer_vals, ours_vals, level: float = 0.95, seed: int = 0):
    """Percentile bootstrap interval of median(peer) / median(ours): each contender's seeds resampled on
    their own (the runs are independent, not paired). A run that did not reach is infinite: a resample whose
    ours-median is infinite gives a ratio of 0, whose peer-median is infinite gives infinity (both ends kept,
    so a censored side shows as an open end). None if either side has no runs."""
    p, o = np.asarray(peer_vals, float), np.asarray(ours_vals, float)
    if p.size == 0 or o.size == 0:
        return None
    rng = np.random.default_rng(seed)
    mp = np.median(p[rng.integers(0, p.size, (BOOT, p.size))], axis=1)
    mo = np.median(o[rng.integers(0, o.size, (BOOT, o.size))], axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.where(np.isinf(mo), 0.0, mp / mo)
    r = np.where(np.isnan(r), np.inf, r)  # inf / inf: both censored, counted as unknown-large
    lo, hi = np.quantile(r, [(1 - level) / 2, (1 + level) / 2], method="lower")
    return [float(lo), float(hi)]


def summarize(runs, tasks, contenders) -> dict:
    out = {}
    for task in tasks:
        per = {}
        for c in contenders:
            rs = [r for r in runs if r["task"] == task and r["contender"] == c and r.get("error") is None]
            if not rs:
                continue
            vals = {k: [r[f"{k}_to_threshold"] if r["reached"] and r.get(f"{k}_to_threshold") is not None
                        else math.inf for r in rs] for k in KEYS}
            per[c] = {"runs": len(rs), "reached": sum(r["reached"] for r in rs), "values": vals,
                      **{k: _stats(v) for k, v in vals.items()},
                      "errors": sum(1 for r in runs if r["task"] == task and r["contender"] == c and r.get("error"))}
        ratios = {}  # per comparison: the fastest peer's median over ours'
        for convention, ours, group in COMPARISONS:
            for key in KEYS:
                peers = {c: per[c][key]["median"] for c in per if c in group}
                if ours not in per or not peers:
                    continue
                best = min(peers, key=lambda c: peers[c])
                ours_m = per[ours][key]["median"]
                ratio = None if math.isinf(ours_m) or math.isinf(peers[best]) else peers[best] / ours_m
                ratios.setdefault(convention, {})[key] = {"ours": ours, "fastest_peer": best,
                                                           "peer_median": peers[best], "ours_median": ours_m,
                                                           "ratio": ratio,
                                                           "ratio_ci95": ratio_interval(per[best]["values"][key],
                                                                                        per[ours]["values"][key])}
        out[task] = {"contenders": per, "fastest_peer_over_ours": ratios}
    return out


def _fmt(v, digits=1) -> str:
    if v is None:
        return "-"
    if math.isinf(v):
        return "not reached"
    return f"{v:.{digits}f}" if digits else f"{int(round(v))}"


def _range(st, digits) -> str:
    if st is None:
        return "-"
    return f"{_fmt(st['median'], digits)} [{_fmt(st['min'], digits)}, {_fmt(st['max'], digits)}]"


def print_summary(summary, rules_by_task, args) -> None:
    for task, s in summary.items():
        ru = rules_by_task[task]
        print()
        print(f"## {task}: {ru['max_episode_steps']}-step episodes, end on success: "
              f"{'yes' if ru['terminate_on_success'] else 'no'}; success >= {THRESHOLD} over {args.eval_episodes} "
              f"eval episodes every {args.eval_every} env steps; cap {args.max_steps} env steps")
        hdr = (f"{'contender':22s} {'reached':>8s}  {'wall s to 0.9: median [min, max]':>36s}  "
               f"{'CPU s to 0.9: median [min, max]':>36s}  {'env steps to 0.9: median [min, max]':>38s}")
        print(hdr)
        print("-" * len(hdr))
        for c, st in s["contenders"].items():
            err = f"  ({st['errors']} failed)" if st["errors"] else ""
            print(f"{NAMES[c]:22s} {st['reached']:>3d}/{st['runs']:<4d}  {_range(st['wall_s'], 1):>36s}  "
                  f"{_range(st['cpu_s'], 1):>36s}  {_range(st['env_steps'], 0):>38s}{err}")
        for convention, by_key in s["fastest_peer_over_ours"].items():
            for key, label in (("wall_s", "median wall s"), ("cpu_s", "median CPU s"), ("env_steps", "median env steps")):
                r = by_key.get(key)
                if r is None:
                    continue
                peer, d = NAMES[r["fastest_peer"]], 0 if key == "env_steps" else 1
                head = f"fastest peer / ours ({convention}), {label}:"
                if r["ratio"] is not None:
                    ci = r.get("ratio_ci95")
                    ci_s = (f" [{ci[0]:.2f}, {'inf' if math.isinf(ci[1]) else f'{ci[1]:.2f}'}] (95% bootstrap over seeds)"
                            if ci else "")
                    print(f"{head} {peer} {_fmt(r['peer_median'], d)} / ours {_fmt(r['ours_median'], d)} = "
                          f"{r['ratio']:.2f}x{ci_s}")
                elif math.isinf(r["ours_median"]):
                    print(f"{head} n/a (ours' median run did not reach {THRESHOLD})")
                else:
                    print(f"{head} n/a (no peer's median run reached {THRESHOLD}; ours: {_fmt(r['ours_median'], d)})")


# --------------------------------------------------------------------------- main
def _now() -> str:
    return _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")


def _jsonable(x):
    if isinstance(x, float) and (math.isinf(x) or math.isnan(x)):
        return None
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x


def write_json(path: str, doc: dict) -> None:
    atomic_write_json(path, _jsonable(doc))


def combine(paths, out: str) -> int:
    """One raw file from several of one bench split across processes: their runs together, the summary
    recomputed. Refuses (exit 2, nothing written) unless every file is complete and they agree on everything
    but their seeds."""
    import json
    docs = []
    for path in paths:
        try:
            with open(path) as f:
                docs.append(json.load(f))
        except (OSError, ValueError) as e:
            print(f"error: --combine {path}: {e}", file=sys.stderr)
            return 2
    same = ("threshold", "tasks", "contenders", "max_steps", "eval_every", "eval_episodes", "preset",
            "ours_overrides", "ours_fixed_overrides", "versions")
    for path, d in zip(paths, docs):
        bad = [k for k in same if d["settings"].get(k) != docs[0]["settings"].get(k)]
        if not d.get("complete") or bad or d["machine"]["cpu"] != docs[0]["machine"]["cpu"]:
            why = "is not complete" if not d.get("complete") else f"differs from {paths[0]} in {bad or ['cpu']}"
            print(f"error: --combine {path} {why}", file=sys.stderr)
            return 2
    seeds = [s for d in docs for s in d["settings"]["seeds"]]
    if len(set(seeds)) != len(seeds):
        print(f"error: --combine: a seed appears twice ({sorted(seeds)})", file=sys.stderr)
        return 2
    runs = [r for d in docs for r in d["runs"]]
    doc = dict(docs[0], runs=runs, combined_from=[os.path.relpath(p_, REPO) for p_ in paths],
               argv=[a for d in docs for a in (d["argv"] + ["|"])][:-1],
               started=min(d["started"] for d in docs), finished=max(d["finished"] for d in docs),
               machine=dict(docs[0]["machine"], processes=[d["machine"] for d in docs]))
    doc["settings"] = dict(docs[0]["settings"], seeds=sorted(seeds))
    tasks, contenders = doc["settings"]["tasks"], doc["settings"]["contenders"]
    doc["summary"] = summarize(runs, tasks, contenders)
    write_json(out, doc)
    args = argparse.Namespace(eval_episodes=doc["settings"]["eval_episodes"], eval_every=doc["settings"]["eval_every"],
                              max_steps=doc["settings"]["max_steps"])
    print_summary(doc["summary"], doc["settings"]["episodes"], args)
    print(f"\n# combined {len(paths)} raw files ({len(runs)} runs) into {os.path.relpath(out)}")
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--tasks", default=",".join(TASKS), help="comma-separated task ids")
    p.add_argument("--seeds", type=int, default=3, help="N seeds per contender (default 3)")
    p.add_argument("--seed-start", type=int, default=0, help="the first seed (default 0: seeds 0..N-1)")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                   help="an override of ours' settings (ours and ours_fixed), as `sweep --set`; repeatable")
    p.add_argument("--fixed-set", dest="fixed_sets", action="append", default=None, metavar="KEY=VALUE",
                   help="an override for ours_fixed only; repeatable (default: ours' declared fixed-length setting, "
                        f"{' '.join(OURS_FIXED)}; --fixed-set none: the preset as is)")
    p.add_argument("--max-steps", type=int, default=30_000, help="env-step cap per run (default 30000)")
    p.add_argument("--eval-every", type=int, default=1000, help="env steps between evaluations (default 1000)")
    p.add_argument("--eval-episodes", type=int, default=10, help="fixed evaluation episodes (default 10)")
    p.add_argument("--contenders", default="ours,sb3,sbx",
                   help=f"comma-separated subset of {','.join(CONTENDERS)} (default ours,sb3,sbx; *_own: the peer at "
                        f"its own convention, episodes that do not end on success; ours_fixed: ours so too)")
    p.add_argument("--preset", default="quick", help="the sweep preset ours is built from (default quick)")
    p.add_argument("--out", default=DEFAULT_OUT, help="raw results JSON (default bench/results/time_to_success.json)")
    p.add_argument("--combine", nargs="+", metavar="RAW.json",
                   help="write --out as these complete raw files' runs together (one machine, one commit, the "
                        "same settings; e.g. two processes that ran different seeds side by side), no new runs")
    args = p.parse_args(argv)
    if args.combine:
        return combine(args.combine, args.out)
    tasks = [t for t in args.tasks.split(",") if t]
    contenders = [c for c in args.contenders.split(",") if c]
    bad = [c for c in contenders if c not in CONTENDERS]
    if bad or not contenders or not tasks or args.seeds < 1 or args.max_steps < 1 or args.eval_every < 1 \
            or args.seed_start < 0:
        p.error(f"bad arguments (contenders {bad or contenders}, tasks {tasks}, seeds {args.seeds}, "
                f"seed start {args.seed_start})")
    from maniskill_dualher.config import ConfigError
    from maniskill_dualher.experiment import overrides
    try:
        args.overrides = overrides.parse_all(args.sets)
        fixed = OURS_FIXED if args.fixed_sets is None else [x for x in args.fixed_sets if x.lower() != "none"]
        args.fixed_overrides = overrides.parse_all(fixed)
    except ConfigError as e:
        p.error(str(e))
    seeds = list(range(args.seed_start, args.seed_start + args.seeds))
    from maniskill_dualher.experiment.presets import PRESETS
    if args.preset not in PRESETS:
        p.error(f"unknown preset {args.preset!r} (choose {', '.join(PRESETS)})")
    why = sbx_missing() if any(peer_library(c) == "sbx" for c in contenders) else None
    if why is not None:
        print(f"# SBX skipped ({why}); pip install sbx-rl to add it")
        contenders = [c for c in contenders if peer_library(c) != "sbx"]
    torch.set_num_threads(1)

    print(f"# time_to_success: {', '.join(tasks)}; contenders {', '.join(NAMES[c] for c in contenders)}; "
          f"seeds {seeds[0]}..{seeds[-1]}; cap {args.max_steps} env steps; eval {args.eval_episodes} episodes every "
          f"{args.eval_every} steps; threshold {THRESHOLD}")
    print(f"# cpu: {cpu_name()}")
    print(f"# threads: {thread_info()}")
    print(f"# load average at start: {loadavg()}")
    if args.fixed_overrides:
        print(f"# ours, fixed-length: also {' '.join(o.text() for o in args.fixed_overrides)}: "
              f"{describe_ours(our_config(tasks[0], 0, args, fixed_length=True))}")
    print(f"# ours: {args.preset!r} preset, sac_her_per"
          f"{' with ' + ' '.join(o.text() for o in args.overrides) if args.overrides else ''}: "
          f"{describe_ours(our_config(tasks[0], 0, args))}")
    peers = [c for c in contenders if not c.startswith("ours")]
    if peers:
        print(f"# peers ({'; '.join(lib_version(peer_library(c)) for c in peers)}): " + ", ".join(f"{k} {v}" for k, v in ZOO.items()))

    fixed_only = "ours_fixed" in contenders and "ours" not in contenders
    print(f"# shared settings ({'ours, fixed-length' if fixed_only else 'ours'} | peers):")
    for k, v in shared_settings(our_config(tasks[0], 0, args, fixed_length=fixed_only)).items():
        print(f"#   {k:36s} {str(v['ours']):48s} | {v['peers']}{'' if v['equal'] else '   (differs)'}")
    rules_by_task = {}
    doc = {"bench": "time_to_success", "version": 1, "complete": False, "started": _now(), "finished": None,
           "argv": sys.argv[1:] if argv is None else list(argv),
           "machine": {"cpu": cpu_name(), "threads": thread_info(), "loadavg_start": loadavg()},
           "settings": {"threshold": THRESHOLD, "tasks": tasks, "seeds": seeds,
                        "ours_overrides": [o.text() for o in args.overrides],
                        "ours_fixed_overrides": [o.text() for o in args.fixed_overrides],
                        "shared": shared_settings(our_config(tasks[0], 0, args)),
                        "shared_fixed": shared_settings(our_config(tasks[0], 0, args, fixed_length=True)),
                        "contenders": contenders, "max_steps": args.max_steps, "eval_every": args.eval_every,
                        "eval_episodes": args.eval_episodes, "preset": args.preset, "peers": ZOO,
                        "versions": {c: lib_version(peer_library(c)) for c in peers}, "episodes": {}},
           "runs": [], "summary": None}
    for task in tasks:
        rules = episode_rules(task, args)
        rules_by_task[task] = rules
        doc["settings"]["episodes"][task] = {k: v for k, v in rules.items() if k != "init_obs"}
        print(f"# {task}: {rules['max_episode_steps']}-step episodes, end on success "
              f"{rules['terminate_on_success']}, control {rules['control_mode'] or 'task default'}, reward "
              f"{rules['reward_mode']}, eval seeds {rules['eval_seeds'][0]}..{rules['eval_seeds'][-1]}")
        for seed in seeds:
            for c in contenders:
                rec = {"task": task, "contender": c, "name": NAMES[c], "seed": seed, "error": None}
                try:
                    res = (run_ours(task, seed, args, rules, fixed_length=c == "ours_fixed") if c.startswith("ours")
                           else run_peer(c, task, seed, args, rules))
                    rec.update(res)
                    hit = next((pt for pt in res["curve"] if pt["eval_success_rate"] >= THRESHOLD), None)
                    rec["wall_s_to_threshold"] = hit["wall_s"] if hit else None
                    rec["env_steps_to_threshold"] = hit["env_steps"] if hit else None
                    rec["cpu_s_to_threshold"] = hit["cpu_s"] if hit else None
                    last = res["curve"][-1] if res["curve"] else {"eval_success_rate": float("nan")}
                    status = (f"0.9 at {hit['env_steps']} env steps, {hit['wall_s']:.1f} s" if hit else
                              f"not reached in {res['env_steps_total']} env steps ({res['wall_s_total']:.1f} s; "
                              f"last eval {last['eval_success_rate']:.2f})")
                    extra = (f", eval state mismatches {res['eval_state_mismatches']}"
                             if res.get("eval_state_mismatches") else "")
                    print(f"{task} {NAMES[c]:18s} seed {seed}: {status}{extra}", flush=True)
                except Exception as e:  # one failed run is reported and the bench goes on
                    rec.update(reached=False, error=f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}",
                               traceback=traceback.format_exc(limit=8))
                    print(f"{task} {NAMES[c]:18s} seed {seed}: error: {rec['error']}", flush=True)
                doc["runs"].append(rec)
                doc["summary"] = summarize(doc["runs"], tasks, contenders)
                write_json(args.out, doc)

    summary = summarize(doc["runs"], tasks, contenders)
    print_summary(summary, rules_by_task, args)
    doc.update(summary=summary, complete=True, finished=_now())
    doc["machine"]["loadavg_end"] = loadavg()
    write_json(args.out, doc)
    print(f"\n# raw results: {os.path.relpath(args.out)}; load average at the end: {loadavg()}")
    return 1 if any(r.get("error") for r in doc["runs"]) else 0


if __name__ == "__main__":
    sys.exit(main())
