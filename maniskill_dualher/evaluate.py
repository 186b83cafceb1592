"""Evaluate a trained policy: success with a confidence interval, on its own task or zero-shot on another.

    python -m maniskill_dualher.evaluate POLICY [--task OTHER_TASK] [--episodes N] [--train-eval-seeds | --reset-seed S]
                                         [--best] [--record DIR] [--movie FILE.gif|.mp4 [--movie-episode K]] [--json]
    python -m maniskill_dualher.evaluate --zero-shot-matrix FOLDER [--episodes N] [--best]

POLICY is a run folder (its ``policy.pt``, or ``policy_best.pt`` with ``--best``), a folder of
``results/policies/`` or a policy file. The env is built from the policy's run config (``RunConfig``: control
mode, time limit, reward mode, whether success ends an episode), with ``--task`` (alias ``--env``) replacing
the task: the three tasks share one observation layout, so a policy trained on one acts on the others
(zero-shot transfer).

Seeds. By default the episodes use *held-out* reset seeds ``HELDOUT_SEED_BASE + i``: no training evaluation
used them (those are ``EVAL_SEED_BASE + i``, i < eval_episodes) and no training episode of a run seed below
~2000 (``envs.train_episode_seed``), so a policy chosen by its evaluations (``--best``) is not scored on the
episodes that chose it. ``--train-eval-seeds`` uses the training evaluations' seeds instead: with
``--episodes`` = the run's ``eval_episodes`` it reproduces the run's own evaluation (state for state on
ReachTarget; once the hand touches a lid or door, PhysX's CPU simulation is not bit-reproducible across
resets, so an episode in a fresh simulator can end a step earlier or later than in the run's). ``--reset-seed S``
picks any first seed. The output names the seed set. Episodes follow the training evaluation's rules
(deterministic policy: tanh of the Gaussian mean). Always one CPU-simulated env (a GPU-trained policy
evaluates here too).

Output: success rate with a 95% Wilson interval (``analysis.stats.wilson``), mean episode length, and the mean
return with a t interval only where it differs from the success rate (sparse reward and episodes that end
on success make them equal); ``--json`` prints one JSON object with all of them.

Seeing an episode without a render device:

* ``--record [DIR]`` (DIR: ``runs/recordings`` unless given) wraps the ManiSkill env in ``RecordEpisode(save_trajectory=True, record_env_state=True)``,
  with ``save_video=True`` where the simulator can render (``scene.can_render()``): DIR/<name>.h5 + .json.
  Their env id names the module that registers it (``maniskill_dualher.tasks:CloseBox-v1``), so ManiSkill's
  replay tool takes them as typed, in a fresh process (the recipe: ``docs/tasks.md``, "Replaying a recording";
  tested, ``tests/test_evaluate.py``).

* ``--movie FILE`` (.gif or .mp4) draws one episode's state (``--movie-episode K``, default the first) with
  matplotlib (``movie.py``).

Bad input (missing folder, no policy file, unknown task, episodes < 1) is one ``error: ...`` line, exit 2.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np

from .cli import OneLineParser, did_you_mean, old_flag
from .config import TASKS, ConfigError, RunConfig
from .envs import EVAL_SEED_BASE, BatchEnv, make_env
from .fileio import plural
from .movie import MOVIE_SUFFIXES, draw_movie, task_info
from .policy import Policy, load_policy

ZERO_SHOT_CSV = "zero_shot.csv"
RECORD_DIR = "runs/recordings"  # --record without DIR: under runs/ (.gitignore), never the checkout's top
TASKS_MODULE = "maniskill_dualher.tasks"  # the module that registers config.TASKS (a recorded env id names it)
CONFIDENCE = 0.95
# Held-out reset seeds: far from the training evaluations' EVAL_SEED_BASE + i and below 2**31 - 1 (ManiSkill's
# seed range); training episodes (run_seed * 1_000_003 + episode) reach them only for run seeds near 2000.
HELDOUT_SEED_BASE = 2_000_000_000
DEFAULT_EPISODES = 100
HELD_OUT, TRAIN_EVAL, CUSTOM = "held-out", "training evaluation", "custom"


def seed_set(first: int) -> str:
    """Which seeds a first seed names: held-out, the training evaluations' own, or custom."""
    return {HELDOUT_SEED_BASE: HELD_OUT, EVAL_SEED_BASE: TRAIN_EVAL}.get(int(first), CUSTOM)


# --------------------------------------------------------------------------- statistics (analysis/ is their home)
def success_ci(successes: int, n: int, level: float = CONFIDENCE) -> tuple:
    """Wilson score interval of a binomial proportion."""
    from .analysis.stats import wilson
    return wilson(successes, n, level)


def mean_ci(x: Sequence[float], level: float = CONFIDENCE) -> tuple:
    """Student-t interval of a mean; (nan, nan) for one value, (m, m) when every value is equal."""
    from .analysis.tables import mean_ci as t_interval
    return t_interval(x, level)


# --------------------------------------------------------------------------- env
def eval_config(policy: Policy, env_id: Optional[str] = None) -> RunConfig:
    """The env settings of the policy's run (task replaced by ``env_id``), one CPU-simulated env.

    Only the fields that shape an episode are taken from the run's config (control mode, time limit,
    reward mode, terminate on success), so a policy from a GPU run or an older config still evaluates."""
    c = policy.config or {}
    return RunConfig(env_id=env_id or policy.env_id, control_mode=policy.control_mode,
                     max_episode_steps=policy.max_episode_steps, terminate_on_success=policy.terminate_on_success,
                     reward_mode=c.get("reward_mode", "sparse"), num_envs=1, sim_backend="physx_cpu", device="cpu")


def make_eval_env(policy: Policy, env_id: Optional[str] = None) -> BatchEnv:
    env = make_env(eval_config(policy, env_id))
    s = env.spec
    if (s.input_dim, s.act_dim) != (policy.input_dim, policy.act_dim):
        env.close()
        raise ConfigError(f"policy from {policy.env_id!r} (input {policy.input_dim}, action {policy.act_dim}) does "
                          f"not fit {s.env_id!r} (input {s.input_dim}, action {s.act_dim})")
    return env


def _episode(policy: Policy, env: BatchEnv, seed: int, terminate_on_success: bool, trace: bool) -> dict:
    """One episode under the training evaluation's rules (``episodes.EnvEpisodes``, as ``Trainer.evaluate``),
    deterministic policy; ``trace``: also every flat observation and success flag (for a movie)."""
    from .episodes import EnvEpisodes
    ep = EnvEpisodes(env, terminate_on_success).rollout(seed, lambda x: policy.act(x, deterministic=True))[0]
    succ = ep.success[:, 0].astype(bool)
    hits = np.flatnonzero(succ)
    out = {"seed": int(seed), "success": bool(hits.size), "success_at_end": bool(succ[-1]),
           "return": float(ep.reward.sum()), "length": int(ep.length),
           "first_success_step": int(hits[0]) + 1 if hits.size else None}
    if trace:  # our tasks only (goal envs): the flat layout is observation | achieved goal | desired goal
        first = np.concatenate([ep.obs[:, 0], ep.achieved_goal[:, 0], ep.desired_goal[:, 0]], -1)
        last = np.concatenate([ep.next_obs[-1:, 0], ep.next_achieved_goal[-1:, 0], ep.desired_goal[-1:, 0]], -1)
        out["flats"], out["successes"] = np.concatenate([first, last]), np.concatenate([[False], succ])
    return out


# --------------------------------------------------------------------------- evaluation
def evaluate_policy(policy, env_id: Optional[str] = None, episodes: int = DEFAULT_EPISODES,
                    seed: int = HELDOUT_SEED_BASE, *,
                    record: Optional[str] = None, movie: Optional[str] = None, movie_episode: int = 0,
                    env: Optional[BatchEnv] = None, terminate_on_success: Optional[bool] = None) -> Dict:
    """Run ``episodes`` deterministic episodes (reset seeds ``seed``, ``seed + 1``, ...; default held-out) of ``policy`` (a Policy,
    a policy file or a run folder) on ``env_id`` (default: its own task) and return the summary dict:
    success rate and its 95% Wilson CI, mean return and its t CI, mean length, per-episode results.
    ``record``: a folder for ManiSkill .h5/.json trajectories; ``movie``: a .gif/.mp4 of episode number
    ``movie_episode`` (0: the first);
    ``env``: a BatchEnv to reuse (its task is then ``env_id``; not closed here)."""
    if not isinstance(policy, Policy):
        policy = load_policy(policy)
    if int(episodes) < 1:
        raise ConfigError(f"episodes must be >= 1, got {episodes}")
    if movie is not None and Path(movie).suffix.lower() not in MOVIE_SUFFIXES:
        raise ConfigError(f"--movie {movie}: use a .gif or .mp4 file name")
    if movie is not None and not 0 <= int(movie_episode) < int(episodes):
        raise ConfigError(f"--movie-episode {movie_episode}: must be in 0..{int(episodes) - 1} (one of the episodes)")
    own = env is None
    if own:
        env = make_eval_env(policy, env_id)
    target = env.spec.env_id
    terminate = policy.terminate_on_success if terminate_on_success is None else bool(terminate_on_success)
    control_mode = getattr(env.unwrapped, "control_mode", None)
    try:
        if (movie is not None or record is not None) and not (env.spec.is_maniskill and hasattr(env.unwrapped, "goal_tolerance")):
            raise ConfigError(f"--movie/--record need one of our ManiSkill tasks ({', '.join(TASKS)}), "
                              f"not {target!r}")
        traj_name = None
        if record is not None:
            from mani_skill.utils.wrappers.record import RecordEpisode
            traj_name = f"{target}.seed{int(seed)}.n{int(episodes)}"
            env.env = RecordEpisode(env.env, str(record), save_video=_can_render(env), save_trajectory=True,
                                    record_env_state=True, trajectory_name=traj_name, video_fps=10)
            # the lean step (tasks/lean.py) calls the task itself, past the wrapper: take ManiSkill's step
            env.lean, env.lean_off_reason = None, "recording (RecordEpisode wraps ManiSkill's step)"
        eps = [_episode(policy, env, int(seed) + k, terminate, trace=(k == int(movie_episode) and movie is not None))
               for k in range(int(episodes))]
    finally:
        if own or record is not None:
            env.close()  # RecordEpisode writes its last episode on close
    if record is not None:
        _replayable_json(Path(record) / f"{traj_name}.json")
    n, k = len(eps), sum(e["success"] for e in eps)
    rets = [e["return"] for e in eps]
    lo, hi = success_ci(k, n)
    rlo, rhi = mean_ci(rets)
    result = {
        "env_id": target, "source_env_id": policy.env_id, "zero_shot": target != policy.env_id,
        "policy": str(policy.path) if policy.path else None, "policy_env_steps": policy.env_steps,
        "policy_eval_success": policy.eval_success,
        "episodes": n, "seed_first": int(seed), "seed_last": int(seed) + n - 1, "seed_set": seed_set(seed),
        "control_mode": control_mode,
        "max_episode_steps": env.spec.max_episode_steps, "terminate_on_success": terminate,
        "successes": int(k), "success_rate": k / n, "success_ci": [lo, hi], "success_ci_method": "wilson",
        "confidence": CONFIDENCE,
        "success_at_end": float(np.mean([e["success_at_end"] for e in eps])),
        "mean_return": float(np.mean(rets)), "return_ci": [None if v != v else v for v in (rlo, rhi)],
        "return_ci_method": "t",
        "mean_episode_length": float(np.mean([e["length"] for e in eps])),
        "per_episode": [{kk: v for kk, v in e.items() if kk not in ("flats", "successes")} for e in eps],
    }
    if record is not None:
        result["trajectory"] = str(Path(record) / f"{traj_name}.h5")
        videos = sorted(str(v) for v in Path(record).glob("*.mp4"))
        if videos:  # written only where the simulator renders
            result["video"] = ", ".join(videos)
    if movie is not None:
        info = task_info(target)
        draw_movie(eps[int(movie_episode)], info, movie, title_source=policy)
        result["movie"] = str(movie)
    return result


def _can_render(env: BatchEnv) -> bool:
    """Whether the simulator can draw frames (a render device and a backend other than "none")."""
    scene = getattr(env.unwrapped, "scene", None)
    try:
        return bool(scene is not None and scene.can_render())
    except Exception:  # noqa: BLE001  (a scene without a renderer raises instead of answering False)
        return False


def _replayable_json(path: Path) -> None:
    """Make ManiSkill's replay tool take the file as typed, in a process where nothing imported our tasks:
    the env id names its module (``maniskill_dualher.tasks:CloseBox-v1``; gymnasium imports the module named
    before ``:`` and then makes the env), and RecordEpisode's render_backend "none" is dropped, which would
    stop a replay on a machine that renders from making its video (our tasks then pick a backend
    themselves)."""
    from .fileio import atomic_write_text
    if not path.is_file():
        return
    doc = json.loads(path.read_text())
    info = doc.get("env_info", {})
    kw = info.get("env_kwargs", {})
    changed = False
    if kw.get("render_backend") == "none":
        kw.pop("render_backend")
        changed = True
    env_id = info.get("env_id")
    if env_id in TASKS:
        info["env_id"] = f"{TASKS_MODULE}:{env_id}"
        changed = True
    if changed:
        atomic_write_text(path, json.dumps(doc, indent=2))


# --------------------------------------------------------------------------- zero-shot matrix
def finished_runs(folder) -> List[Path]:
    """Run folders under ``folder`` (itself included) that finished (done.json) and hold a policy.pt."""
    from .rundir import DONE, POLICY
    folder = Path(folder)
    found = {p.parent for p in folder.rglob(DONE) if (p.parent / POLICY).is_file()}
    return sorted(found)


def zero_shot_matrix(folder, episodes: int = 10, seed: int = HELDOUT_SEED_BASE, best: bool = False,
                     tasks: Sequence[str] = TASKS, progress=None) -> List[dict]:
    """Evaluate every finished run's policy under ``folder`` on every task; write ``folder/zero_shot.csv``
    (atomic) and return its rows (source run, source task, target task, success with its Wilson CI, ...).
    Runs on other envs (not our tasks) are skipped."""
    from .fileio import atomic_write_text, csv_text
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(f"no such folder: {folder}")
    if int(episodes) < 1:
        raise ConfigError(f"episodes must be >= 1, got {episodes}")
    runs = finished_runs(folder)
    if not runs:
        raise ConfigError(f"no finished run folder (done.json and policy.pt) under {folder}")
    envs: Dict[tuple, BatchEnv] = {}
    rows = []
    try:
        for run in runs:
            policy = load_policy(run, best=best)
            if policy.env_id not in tasks:
                continue
            for target in tasks:
                key = (target, policy.control_mode, policy.max_episode_steps, policy.config.get("reward_mode"))
                if key not in envs:
                    envs[key] = make_eval_env(policy, target)
                r = evaluate_policy(policy, target, episodes, seed, env=envs[key])
                rows.append({"source_run": str(run.relative_to(folder)) or ".", "source_task": policy.env_id,
                             "target_task": target, "zero_shot": int(target != policy.env_id),
                             "policy": Path(r["policy"]).name, "policy_env_steps": policy.env_steps,
                             "episodes": r["episodes"], "successes": r["successes"],
                             "success_rate": r["success_rate"], "ci_low": r["success_ci"][0],
                             "ci_high": r["success_ci"][1], "mean_return": r["mean_return"],
                             "mean_episode_length": r["mean_episode_length"]})
                if progress:
                    progress(rows[-1])
    finally:
        for e in envs.values():
            e.close()
    atomic_write_text(folder / ZERO_SHOT_CSV, csv_text(rows))
    return rows


# --------------------------------------------------------------------------- CLI
def _fmt_ci(ci) -> str:
    lo, hi = ci
    return "n/a" if (lo is None or hi is None or lo != lo or hi != hi) else f"[{lo:.3f}, {hi:.3f}]"


def summary_text(r: dict) -> str:
    head = f"{r['env_id']}" + (f" (zero-shot; policy trained on {r['source_env_id']})" if r["zero_shot"] else "")
    steps = r["max_episode_steps"]
    rule = "episodes end on success or" if r["terminate_on_success"] else "fixed-length episodes,"
    which = {HELD_OUT: "held-out seeds (no training evaluation used them)",
             TRAIN_EVAL: "the training evaluations' seeds (reproduces the run's own evaluation)",
             CUSTOM: "custom seeds"}[r["seed_set"]]
    lines = [
        f"{head}: policy {r['policy']} (env step {r['policy_env_steps']}, its eval success "
        f"{r['policy_eval_success'] if r['policy_eval_success'] is not None else 'n/a'})",
        f"{plural(r['episodes'], 'episode')} on {which}: {r['seed_first']}..{r['seed_last']}",
        f"deterministic policy, {rule} {steps} steps",
        f"success      {r['success_rate']:.3f} ({r['successes']}/{r['episodes']}), "
        f"95% CI {_fmt_ci(r['success_ci'])} (Wilson)",
    ]
    if abs(r["mean_return"] - r["success_rate"]) > 1e-9:  # equal under sparse reward ending on success
        lines.append(f"return       {r['mean_return']:.3f}, 95% CI {_fmt_ci(r['return_ci'])} (t)")
    lines.append(f"length       {r['mean_episode_length']:.1f} steps (mean)")
    if r.get("trajectory"):
        lines.append(f"trajectory   {r['trajectory']}")
    if r.get("video"):
        lines.append(f"video        {r['video']}")
    if r.get("movie"):
        lines.append(f"movie        {r['movie']}")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m maniskill_dualher.evaluate",
                      description="Evaluate a run's saved policy (deterministic) with confidence intervals, on "
                                  "its own task or zero-shot on another; record trajectories or draw a movie.")
    p.add_argument("run", nargs="?", metavar="POLICY",
                   help="run folder (its policy.pt), a results/policies/ folder, or a policy file")
    p.add_argument("--task", "--env", dest="task", metavar="TASK",
                   help="evaluate on this task instead of the policy's own (zero-shot transfer)")
    p.add_argument("--episodes", default=str(DEFAULT_EPISODES), metavar="N",
                   help=f"episodes (>= 1) [default: {DEFAULT_EPISODES}]")
    seeds = p.add_mutually_exclusive_group()
    seeds.add_argument("--train-eval-seeds", action="store_true",
                       help=f"use the training evaluations' seeds (EVAL_SEED_BASE = {EVAL_SEED_BASE}, +1, ...): "
                            "reproduces the run's own evaluation, optimistic for a policy chosen by it (--best)")
    seeds.add_argument("--reset-seed", dest="seed", default=None, metavar="S",
                       help="the first episode's env reset seed (not a training seed: the policy is fixed); "
                            "episodes reset with S, S+1, ... [default: HELDOUT_SEED_BASE = "
                            f"{HELDOUT_SEED_BASE}, seeds no training evaluation used]")
    old_flag(p, "--seed", "the first episode's env reset seed is --reset-seed S (--seed is train's run seed)")
    p.add_argument("--best", action="store_true", help="use policy_best.pt (the best evaluation) instead of policy.pt")
    p.add_argument("--record", metavar="DIR", nargs="?", const=RECORD_DIR,
                   help="write ManiSkill .h5/.json trajectories (replayable to video) into DIR (default, --record "
                        f"alone: {RECORD_DIR}, which git ignores)")
    p.add_argument("--movie", metavar="FILE", help="draw one episode's state to FILE (.gif or .mp4)")
    p.add_argument("--movie-episode", default="0", metavar="K",
                   help="which episode --movie draws: 0 = the first (seed S), K = seed S+K [default: 0]")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of the summary text")
    p.add_argument("--zero-shot-matrix", metavar="FOLDER",
                   help="evaluate every finished run under FOLDER on every task; write FOLDER/zero_shot.csv")
    return p


def _int(name: str, raw: str, low: int) -> int:
    try:
        v = int(raw)
    except ValueError:
        raise ConfigError(f"--{name}: bad value {raw!r} (an integer)") from None
    if v < low:
        raise ConfigError(f"--{name} must be >= {low}, got {v}")
    return v


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        episodes = _int("episodes", args.episodes, 1)
        seed = EVAL_SEED_BASE if args.train_eval_seeds else \
            HELDOUT_SEED_BASE if args.seed is None else _int("reset-seed", args.seed, 0)
        if args.zero_shot_matrix:
            if args.run or args.task or args.record or args.movie:
                raise ConfigError("--zero-shot-matrix takes no POLICY, --task, --record or --movie")
            rows = zero_shot_matrix(args.zero_shot_matrix, episodes, seed, best=args.best,
                                    progress=None if args.json else lambda r: print(
                                        f"{r['source_run']}: {r['source_task']} -> {r['target_task']} "
                                        f"{r['success_rate']:.3f} [{r['ci_low']:.3f}, {r['ci_high']:.3f}]",
                                        file=sys.stderr))
            out = Path(args.zero_shot_matrix) / ZERO_SHOT_CSV
            print(json.dumps({"zero_shot_csv": str(out), "rows": rows}) if args.json else f"wrote {out}")
            return 0
        if not args.run:
            raise ConfigError("give a policy (run folder, results/policies/ folder or policy file), "
                              "or --zero-shot-matrix FOLDER")
        if args.task is not None:
            _known_env(args.task)
        policy = load_policy(args.run, best=args.best)
        movie_episode = _int("movie-episode", args.movie_episode, 0)
        result = evaluate_policy(policy, args.task, episodes, seed, record=args.record, movie=args.movie,
                                 movie_episode=movie_episode)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(result))
    else:
        print(summary_text(result))
    return 0


def _known_env(env_id: str) -> None:
    import gymnasium as gym
    import maniskill_dualher.tasks  # noqa: F401  (registers our tasks)
    if env_id not in gym.registry:
        raise ConfigError(f"unknown environment {env_id!r} (our tasks: {', '.join(TASKS)})"
                          + did_you_mean(env_id, TASKS))


if __name__ == "__main__":
    sys.exit(main())
