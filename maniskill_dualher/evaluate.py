"""Evaluate a trained policy: success with a confidence interval, on its own task or zero-shot on another.

    python -m maniskill_dualher.evaluate RUN_DIR [--env OTHER_TASK] [--episodes N] [--seed S] [--best]
                                         [--record DIR] [--movie FILE.gif|.mp4 [--movie-episode K]] [--json]
    python -m maniskill_dualher.evaluate --zero-shot-matrix FOLDER [--episodes N] [--best]

RUN_DIR is a run folder (its ``policy.pt``, or ``policy_best.pt`` with ``--best``) or a policy file.
The env is built from the policy's run config (``RunConfig``: control mode, time limit, reward mode,
whether success ends an episode), with ``--env`` replacing the task: the three tasks share one
observation layout, so a policy trained on one acts on the others (zero-shot transfer). Episodes use
reset seeds S, S+1, ... (default ``EVAL_SEED_BASE``, the seeds of the training loop's own evaluations,
so ``--episodes`` = the run's ``eval_episodes`` reproduces its own evaluation: state for state on
ReachTarget; once the hand touches a lid or door, PhysX's CPU simulation is not bit-reproducible across resets,
so an episode in a fresh simulator can end a step earlier or later than in the run's), the
deterministic policy (tanh of the Gaussian mean) and the training evaluation's episode rules. Always one
CPU-simulated env (a GPU-trained policy evaluates here too).

Output: success rate with a 95% Wilson interval (``scipy.stats.binomtest(...).proportion_ci``), mean return
with a t interval, mean episode length; ``--json`` prints one JSON object instead.

Seeing an episode without a render device:

* ``--record DIR`` wraps the ManiSkill env in ``RecordEpisode(save_video=False, save_trajectory=True,
  record_env_state=True)``: DIR/<name>.h5 + .json, replayable into a video on a machine that renders
  (our tasks must be registered, so import the package first)::

      python -c "import sys, maniskill_dualher; from mani_skill.trajectory import replay_trajectory as r; \\
                 r.main(r.parse_args(sys.argv[1:]))" --traj-path DIR/<name>.h5 --use-env-states --save-video

* ``--movie FILE`` (.gif or .mp4) draws one episode's state (``--movie-episode K``, default the first) with
  matplotlib: the TCP and goal paths
  seen from above (x-y) and the side (x-z) with the goal tolerance, the distance to the goal over time
  against the tolerance, and the hinge angle (CloseBox, CloseMicrowave) or the per-axis goal error
  (ReachTarget). Small: 384x288 px, 10 frames/s.

Bad input (missing folder, no policy file, unknown env, episodes < 1) is one ``error: ...`` line, exit 2.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np

from .cli import OneLineParser
from .config import OUR_TASKS, ConfigError, RunConfig
from .envs import EVAL_SEED_BASE, BatchEnv, make_env
from .policy import Policy, load_policy

ZERO_SHOT_CSV = "zero_shot.csv"
MOVIE_SUFFIXES = (".gif", ".mp4")
CONFIDENCE = 0.95


# --------------------------------------------------------------------------- statistics
def success_ci(successes: int, n: int, level: float = CONFIDENCE) -> tuple:
    """Wilson score interval of a binomial proportion (scipy.stats.binomtest(...).proportion_ci)."""
    from scipy.stats import binomtest
    ci = binomtest(int(successes), int(n)).proportion_ci(confidence_level=level, method="wilson")
    return float(ci.low), float(ci.high)


def mean_ci(x: Sequence[float], level: float = CONFIDENCE) -> tuple:
    """Student-t interval of a mean; (nan, nan) for one value, (m, m) when every value is equal."""
    x = np.asarray(x, dtype=np.float64)
    m = float(x.mean())
    if x.size < 2:
        return float("nan"), float("nan")
    sd = float(x.std(ddof=1))
    if sd == 0.0:
        return m, m
    from scipy.stats import t
    h = float(t.ppf(0.5 + level / 2, x.size - 1)) * sd / math.sqrt(x.size)
    return m - h, m + h


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
def evaluate_policy(policy, env_id: Optional[str] = None, episodes: int = 10, seed: int = EVAL_SEED_BASE, *,
                    record: Optional[str] = None, movie: Optional[str] = None, movie_episode: int = 0,
                    env: Optional[BatchEnv] = None, terminate_on_success: Optional[bool] = None) -> Dict:
    """Run ``episodes`` deterministic episodes (reset seeds ``seed``, ``seed + 1``, ...) of ``policy`` (a Policy,
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
            raise ConfigError(f"--movie/--record need one of our ManiSkill tasks ({', '.join(OUR_TASKS)}), "
                              f"not {target!r}")
        traj_name = None
        if record is not None:
            from mani_skill.utils.wrappers.record import RecordEpisode
            traj_name = f"{target}.seed{int(seed)}.n{int(episodes)}"
            env.env = RecordEpisode(env.env, str(record), save_video=False, save_trajectory=True,
                                    record_env_state=True, trajectory_name=traj_name)
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
        "episodes": n, "seed_first": int(seed), "seed_last": int(seed) + n - 1,
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
    if movie is not None:
        info = _task_info(policy, target)
        draw_movie(eps[int(movie_episode)], info, movie, title_source=policy)
        result["movie"] = str(movie)
    return result


def _replayable_json(path: Path) -> None:
    """RecordEpisode stores our env kwargs, render_backend "none" included, which would stop a replay on a
    machine that renders from making its video: drop it (our tasks then pick a backend themselves)."""
    from .fileio import atomic_write_text
    if not path.is_file():
        return
    doc = json.loads(path.read_text())
    kw = doc.get("env_info", {}).get("env_kwargs", {})
    if kw.get("render_backend") == "none":
        kw.pop("render_backend")
        atomic_write_text(path, json.dumps(doc, indent=2))


def _task_info(policy: Policy, env_id: str) -> dict:
    """What the movie needs to know of a task: goal tolerance, hinge (name, success angle) or none."""
    from mani_skill.utils.registration import REGISTERED_ENVS

    from .tasks.hinged import HingedPanelEnv
    cls = REGISTERED_ENVS[env_id].cls
    hinged = issubclass(cls, HingedPanelEnv)
    return {"env_id": env_id, "tolerance": float(cls.goal_tolerance), "hinged": hinged,
            "angle_name": cls.ANGLE_INFO_KEY.replace("_", " ") if hinged else None,
            "success_angle": float(cls.SUCCESS_ANGLE) if hinged else None}


# --------------------------------------------------------------------------- movie
def draw_movie(ep: dict, info: dict, path, title_source: Optional[Policy] = None, fps: int = 10,
               max_frames: int = 80, dpi: int = 60) -> Path:
    """A small movie (.gif or .mp4) of one traced episode (``_episode(..., trace=True)``): four panels drawn
    from the flat observations (slots in tasks/common.py): x-y and x-z paths of the TCP and the achieved goal
    with the desired goal and its tolerance circle, distance to goal vs step with the tolerance line, and the
    hinge angle (hinged tasks) or per-axis goal error (ReachTarget)."""
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        from matplotlib.patches import Circle
    except ImportError:
        raise ConfigError("--movie needs matplotlib (pip install -e '.[plot]')") from None
    from .tasks.common import GOAL_DIM, OBS_DIM, OBS_SLICES

    path = Path(path)
    flats = ep["flats"]
    T = flats.shape[0] - 1
    tcp = flats[:, OBS_SLICES["tcp_pose"]][:, :3]
    ag = flats[:, OBS_DIM:OBS_DIM + GOAL_DIM]
    dg = flats[:, OBS_DIM + GOAL_DIM:OBS_DIM + 2 * GOAL_DIM]
    dist = np.linalg.norm(ag - dg, axis=-1)
    angle = flats[:, OBS_SLICES["joint_qpos"]][:, 0]
    distract = flats[0, OBS_SLICES["distractor_pos"]].reshape(2, 3)
    tol = info["tolerance"]
    succ_step = ep.get("first_success_step")

    fig, axes = plt.subplots(2, 2, figsize=(6.4, 4.8), dpi=dpi)
    (ax_xy, ax_xz), (ax_d, ax_4) = axes
    pts = np.concatenate([tcp, ag, dg] + ([] if info["hinged"] else [distract]), 0)
    lo, hi = pts.min(0) - 0.06, pts.max(0) + 0.06
    views = [(ax_xy, 0, 1, "top view", "x (m)", "y (m)"), (ax_xz, 0, 2, "side view", "x (m)", "z (m)")]
    artists = []
    for ax, i, j, name, xl, yl in views:
        ax.set_title(name, fontsize=9)
        ax.set_xlabel(xl, fontsize=8, labelpad=1)
        ax.set_ylabel(yl, fontsize=8, labelpad=1)
        ax.tick_params(labelsize=7)
        ax.set_xlim(lo[i], hi[i])
        ax.set_ylim(lo[j] if j < 2 else max(lo[j], -0.02), hi[j])
        ax.set_aspect("equal", adjustable="box")
        ax.add_patch(Circle((dg[0, i], dg[0, j]), tol, fill=False, ls="--", color="tab:green", lw=1))
        ax.plot([dg[0, i]], [dg[0, j]], "*", color="tab:green", ms=9, label="desired goal")
        if not info["hinged"] and np.abs(distract).sum() > 0:
            ax.plot(distract[:, i], distract[:, j], "o", color="0.6", ms=5, label="distractors")
        (tcp_path,) = ax.plot([], [], "-", color="tab:blue", lw=1)
        (tcp_now,) = ax.plot([], [], "o", color="tab:blue", ms=5, label="TCP")
        if info["hinged"]:
            (ag_path,) = ax.plot([], [], "-", color="tab:orange", lw=1)
            (ag_now,) = ax.plot([], [], "s", color="tab:orange", ms=5, label="panel free edge")
        else:
            ag_path = ag_now = None
        artists.append((i, j, tcp_path, tcp_now, ag_path, ag_now))
        if j == 2:
            ax.axhline(0.0, color="0.5", lw=0.8)  # table top
    ax_xy.legend(fontsize=6, loc="best", framealpha=0.6)

    steps = np.arange(T + 1)
    ax_d.set_title("distance to goal", fontsize=9)
    ax_d.axhline(tol, ls="--", color="tab:green", lw=1)
    ax_d.text(0.98, tol, "tolerance", fontsize=6, va="bottom", ha="right", color="tab:green",
              transform=ax_d.get_yaxis_transform())
    ax_d.set_xlim(0, max(T, 1))
    ax_d.set_ylim(0, max(float(dist.max()), tol) * 1.1)
    ax_d.set_xlabel("step", fontsize=8, labelpad=1)
    ax_d.set_ylabel("m", fontsize=8, labelpad=1)
    ax_d.tick_params(labelsize=7)
    (d_line,) = ax_d.plot([], [], "-", color="tab:red", lw=1.2)
    ax_4.set_xlim(0, max(T, 1))
    ax_4.set_xlabel("step", fontsize=8, labelpad=1)
    ax_4.tick_params(labelsize=7)
    if info["hinged"]:
        ax_4.set_title(info["angle_name"], fontsize=9)
        ax_4.set_ylabel("rad", fontsize=8, labelpad=1)
        ax_4.axhline(info["success_angle"], ls="--", color="tab:green", lw=1)
        ax_4.text(0.98, info["success_angle"], "success below", fontsize=6, va="bottom", ha="right",
                  color="tab:green", transform=ax_4.get_yaxis_transform())
        ax_4.set_ylim(min(0.0, float(angle.min())) - 0.02, max(float(angle.max()), info["success_angle"]) * 1.1)
        lines4 = [ax_4.plot([], [], "-", color="tab:orange", lw=1.2)[0]]
        series4 = [angle]
    else:
        err = np.abs(ag - dg)
        ax_4.set_title("goal error per axis", fontsize=9)
        ax_4.set_ylabel("m", fontsize=8, labelpad=1)
        ax_4.set_ylim(0, max(float(err.max()), tol) * 1.1)
        lines4 = [ax_4.plot([], [], "-", color=c, lw=1, label=n)[0]
                  for c, n in zip(("tab:red", "tab:green", "tab:blue"), "xyz")]
        ax_4.legend(fontsize=6, loc="upper right", framealpha=0.6)
        series4 = [err[:, 0], err[:, 1], err[:, 2]]
    src = ""
    if title_source is not None and title_source.env_id != info["env_id"]:
        src = f" (policy from {title_source.env_id}, zero-shot)"
    title = fig.suptitle("", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.95), pad=0.4, h_pad=0.6, w_pad=0.6)

    frames_at = np.unique(np.linspace(0, T, min(T + 1, max_frames)).round().astype(int))
    frames = []
    for f in frames_at:
        for i, j, tcp_path, tcp_now, ag_path, ag_now in artists:
            tcp_path.set_data(tcp[:f + 1, i], tcp[:f + 1, j])
            tcp_now.set_data([tcp[f, i]], [tcp[f, j]])
            if ag_path is not None:
                ag_path.set_data(ag[:f + 1, i], ag[:f + 1, j])
                ag_now.set_data([ag[f, i]], [ag[f, j]])
        d_line.set_data(steps[:f + 1], dist[:f + 1])
        for line, ser in zip(lines4, series4):
            line.set_data(steps[:f + 1], ser[:f + 1])
        status = "success" if (succ_step is not None and f >= succ_step) else ""
        title.set_text(f"{info['env_id']}{src}, seed {ep['seed']}: step {f}/{T}  {status}")
        title.set_color("tab:green" if status else "black")
        fig.canvas.draw()
        frames.append(np.asarray(fig.canvas.buffer_rgba())[..., :3].copy())
    plt.close(fig)
    _write_frames(frames, path, fps)
    return path


def _write_frames(frames: List[np.ndarray], path: Path, fps: int) -> None:
    """GIF through Pillow (adaptive palettes, the last frame held 1.5 s) or MP4 through imageio-ffmpeg."""
    import os

    from .fileio import atomic_write_with
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".gif":
        from PIL import Image
        ims = [Image.fromarray(f).quantize(colors=48, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
               for f in frames]
        durations = [int(1000 / fps)] * len(ims)
        durations[-1] = 1500
        atomic_write_with(path, lambda tmp: ims[0].save(tmp, format="GIF", save_all=True, append_images=ims[1:],
                                                         duration=durations, loop=0, optimize=True, disposal=1))
    else:
        import imageio.v2 as imageio

        tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp.mp4")  # ffmpeg picks the format by suffix
        try:
            w = imageio.get_writer(str(tmp), format="FFMPEG", fps=fps, codec="libx264", quality=6,
                                   macro_block_size=16, pixelformat="yuv420p")
            try:
                for f in frames + [frames[-1]] * fps:  # hold the last frame a second
                    w.append_data(f)
            finally:
                w.close()
            os.replace(tmp, path)
        finally:
            if tmp.exists():
                tmp.unlink()


# --------------------------------------------------------------------------- zero-shot matrix
def finished_runs(folder) -> List[Path]:
    """Run folders under ``folder`` (itself included) that finished (done.json) and hold a policy.pt."""
    from .rundir import DONE, POLICY
    folder = Path(folder)
    found = {p.parent for p in folder.rglob(DONE) if (p.parent / POLICY).is_file()}
    return sorted(found)


def zero_shot_matrix(folder, episodes: int = 10, seed: int = EVAL_SEED_BASE, best: bool = False,
                     tasks: Sequence[str] = OUR_TASKS, progress=None) -> List[dict]:
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
    lines = [
        f"{head}: policy {r['policy']} (env step {r['policy_env_steps']}, its eval success "
        f"{r['policy_eval_success'] if r['policy_eval_success'] is not None else 'n/a'})",
        f"{r['episodes']} episodes, seeds {r['seed_first']}..{r['seed_last']}, deterministic policy, {rule} "
        f"{steps} steps",
        f"success      {r['success_rate']:.3f} ({r['successes']}/{r['episodes']}), "
        f"95% CI {_fmt_ci(r['success_ci'])} (Wilson)",
        f"return       {r['mean_return']:.3f}, 95% CI {_fmt_ci(r['return_ci'])} (t)",
        f"length       {r['mean_episode_length']:.1f} steps (mean)",
    ]
    if r.get("trajectory"):
        lines.append(f"trajectory   {r['trajectory']}")
    if r.get("movie"):
        lines.append(f"movie        {r['movie']}")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(prog="python -m maniskill_dualher.evaluate",
                      description="Evaluate a run's saved policy (deterministic) with confidence intervals, on "
                                  "its own task or zero-shot on another; record trajectories or draw a movie.")
    p.add_argument("run", nargs="?", help="run folder (its policy.pt) or a policy file")
    p.add_argument("--env", help="evaluate on this task instead of the policy's own (zero-shot transfer)")
    p.add_argument("--episodes", default="10", metavar="N", help="episodes (>= 1) [default: 10]")
    p.add_argument("--seed", default=str(EVAL_SEED_BASE), metavar="S",
                   help="first reset seed; episodes use S, S+1, ... [default: EVAL_SEED_BASE = "
                        f"{EVAL_SEED_BASE}, the training evaluations' seeds]")
    p.add_argument("--best", action="store_true", help="use policy_best.pt (the best evaluation) instead of policy.pt")
    p.add_argument("--record", metavar="DIR", help="write ManiSkill .h5/.json trajectories (replayable to video) here")
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
        seed = _int("seed", args.seed, 0)
        if args.zero_shot_matrix:
            if args.run or args.env or args.record or args.movie:
                raise ConfigError("--zero-shot-matrix takes no RUN, --env, --record or --movie")
            rows = zero_shot_matrix(args.zero_shot_matrix, episodes, seed, best=args.best,
                                    progress=None if args.json else lambda r: print(
                                        f"{r['source_run']}: {r['source_task']} -> {r['target_task']} "
                                        f"{r['success_rate']:.3f} [{r['ci_low']:.3f}, {r['ci_high']:.3f}]",
                                        file=sys.stderr))
            out = Path(args.zero_shot_matrix) / ZERO_SHOT_CSV
            print(json.dumps({"zero_shot_csv": str(out), "rows": rows}) if args.json else f"wrote {out}")
            return 0
        if not args.run:
            raise ConfigError("give a run folder (or a policy file), or --zero-shot-matrix FOLDER")
        if args.env is not None:
            _known_env(args.env)
        policy = load_policy(args.run, best=args.best)
        movie_episode = _int("movie-episode", args.movie_episode, 0)
        result = evaluate_policy(policy, args.env, episodes, seed, record=args.record, movie=args.movie,
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
        raise ConfigError(f"unknown environment {env_id!r} (our tasks: {', '.join(OUR_TASKS)})")


if __name__ == "__main__":
    sys.exit(main())
