"""One run: act -> step -> store -> update when due -> evaluate / log / checkpoint between episodes.

    python -m maniskill_dualher.train --env ReachTarget-v1 --method dual_buffer --seed 0 --steps 30000 --out runs/x

A run folder is the unit of truth: ``config.json``, ``metrics.csv`` (one row per evaluation),
TensorBoard events (``losses/*`` every ``log_every`` updates, ``charts/*`` and ``replay/*``),
``checkpoint.pt`` and, once finished, ``done.json``. Running again on the same folder resumes from the
checkpoint; because every training episode is reset with its own seed and checkpoints are taken between
episodes together with all random-number state, a resumed run produces the same metrics as an
uninterrupted one (CPU simulation, one env).

Episodes end on success when ``terminate_on_success`` (the paper, section 4.1) or at
``max_episode_steps``; with N parallel envs each env's episode ends on its own and goes to replay
(with its hindsight goals) as soon as it ends. Plain gymnasium envs end on ``terminated or truncated``.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np
import torch

from .config import ConfigError, ReplayConfig, RunConfig, SACConfig, field_docs, parse_ratio, run_identity
from . import rundir
from .fileio import atomic_torch_save, atomic_write_text
from .rundir import CHECKPOINT
from .envs import EVAL_SEED_BASE, BatchEnv, make_env, train_episode_seed
from .replay.base import Episode
from .cli import OneLineParser
from .sac import SAC
from .policy import save_policy
from .provenance import record_start

DEMO_SEED_BASE = 2_000_000_000


def _differing_keys(a: dict, b: dict, prefix: str = "") -> List[str]:
    """Dotted names of the keys whose values differ between two nested config dicts (missing counts)."""
    out = []
    for k in sorted(set(a) | set(b)):
        va, vb = a.get(k, "<missing>"), b.get(k, "<missing>")
        if isinstance(va, dict) and isinstance(vb, dict):
            out += _differing_keys(va, vb, f"{prefix}{k}.")
        elif va != vb:
            out.append(prefix + k)
    return out


def load_checkpoint(run_dir: Path) -> dict:
    path = Path(run_dir) / CHECKPOINT
    if not path.is_file():
        raise ConfigError(f"missing checkpoint: {path}")
    try:
        return torch.load(path, map_location="cpu", weights_only=False)
    except Exception as e:  # a truncated or foreign file
        raise ConfigError(f"unreadable checkpoint {path}: {type(e).__name__}") from None


# --------------------------------------------------------------------------- the run
class Trainer:
    # called as progress_hook(out_dir, env_steps, total_steps) after every env step when set (a callable
    # object, or a staticmethod): the sweep's progress file, experiment/backends.py: ProgressFile
    progress_hook = None

    def __init__(self, cfg: RunConfig, out_dir, init_from=None, carry_replay: bool = False,
                 show_progress: bool = True, keep_replay: bool = False):
        from .methods import make_method  # late: methods import replay pieces

        self.cfg = cfg.validate()
        self.out = Path(out_dir)
        self.show_progress = show_progress
        self.keep_replay = keep_replay  # a finished run keeps its replay only if a later stage reads it
        self._check_out_dir()
        init_state = load_checkpoint(Path(init_from)) if init_from is not None else None

        torch.set_num_threads(cfg.torch_threads)
        torch.manual_seed(cfg.seed)
        self.rng = np.random.default_rng(cfg.seed)
        self.env: BatchEnv = make_env(cfg)
        self.spec = self.env.spec
        self.method = make_method(cfg, self.spec, np.random.default_rng([cfg.seed, 1]), device=cfg.device)
        self.agent = SAC(self.spec.input_dim, self.spec.act_dim, cfg.sac, device=cfg.device)
        # relabeled transitions are terminal where their goal is reached iff real success ends an episode
        # envs whose ``terminated`` means success (ManiSkill; others say so with a class attribute)
        self.success_terminates = bool(self.spec.is_maniskill or getattr(self.env.unwrapped, "terminate_on_success", False))
        self.goal_terminal = bool(cfg.terminate_on_success and self.success_terminates and self.spec.goal_dim)

        # counters: everything needed to continue exactly where a checkpoint left off
        self.env_steps = 0
        self.episodes = 0
        self.successes = 0
        self.updates = 0
        self.update_credit = 0.0
        self.wall_time = 0.0
        self.demo_env_steps = 0
        self.started = 0              # training episodes started (their reset seeds)
        self.episode_steps_total = 0  # env steps of finished training episodes (mean episode length)
        self.best_eval_success = -1.0  # best evaluation success so far (policy_best.pt); -1: none yet
        self.rows: List[dict] = []
        self.resumed = False

        if (self.out / CHECKPOINT).is_file():
            self._restore(load_checkpoint(self.out))
            self.resumed = True
        elif init_state is not None:
            self._init_from(init_state, carry_replay)
        self.out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(self.out / rundir.CONFIG, cfg.to_json() + "\n")
        rundir.write_json(self.out / rundir.ORIGIN, {"init_from": str(init_from) if init_from else None,
                                                     "carry_replay": bool(carry_replay)})
        record_start(self.out)  # provenance.json: code, libraries, machine of this process start

    def _check_out_dir(self) -> None:
        cfg_path = self.out / rundir.CONFIG
        if cfg_path.is_file():
            try:
                old = json.loads(cfg_path.read_text())
            except json.JSONDecodeError:
                raise ConfigError(f"{cfg_path} is not valid JSON") from None
            old, new = run_identity(old), run_identity(json.loads(self.cfg.to_json()))
            if old != new:
                keys = ", ".join(_differing_keys(old, new)) or "?"
                raise ConfigError(f"{self.out} holds a run of a different config (differs in: {keys}); use another --out")

    def _init_from(self, state: dict, carry_replay: bool) -> None:
        """Transfer: start from another run's final networks (and, optionally, its replay)."""
        try:
            self.agent.load_full_state(state["agent"], networks_only=True)
        except (RuntimeError, KeyError) as e:
            raise ConfigError(f"init_from networks do not fit {self.cfg.env_id!r}: {str(e).splitlines()[0]}") from None
        if carry_replay:
            if state.get("method") is None:
                raise ConfigError("init_from checkpoint holds no replay buffers (its run did not keep them); "
                                  "rerun it, or transfer without carrying replay")
            self.method.load_transfer_state(state["method"])
            self.method.on_transfer()
            self.method.reseed(np.random.default_rng([self.cfg.seed, 1]))  # keep this run's own sampling stream

    # ------------------------------------------------------------ checkpoint
    def _state(self) -> dict:
        return {
            "config": self.cfg.to_dict(),
            "agent": self.agent.full_state(),
            "method": self.method.state_dict(),
            "counters": dict(env_steps=self.env_steps, episodes=self.episodes, successes=self.successes,
                             updates=self.updates, update_credit=self.update_credit,
                             wall_time=self.wall_time, demo_env_steps=self.demo_env_steps,
                             started=self.started, episode_steps_total=self.episode_steps_total,
                             best_eval_success=self.best_eval_success),
            "rows": self.rows,
            "rng": self.rng.bit_generator.state,
            "torch_rng": torch.get_rng_state(),
        }

    def _restore(self, state: dict) -> None:
        self.agent.load_full_state(state["agent"])
        self.method.load_state_dict(state["method"])
        for k, v in state["counters"].items():
            setattr(self, k, v)
        self.rows = list(state["rows"])
        self.rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])

    def save_checkpoint(self, replay: bool = True) -> None:
        """Write the checkpoint; ``replay=False`` leaves the replay buffers out (a finished run nobody resumes)."""
        state = self._state()
        if not replay:
            state["method"] = None
        atomic_torch_save(state, self.out / CHECKPOINT)

    # ------------------------------------------------------------ rollouts
    def _episode(self, cols: Dict[str, np.ndarray]) -> Episode:
        """Stacked per-step columns of one env, (T, ...), as a one-env Episode (T, 1, ...)."""
        arr = {k: v[:, None] for k, v in cols.items()}
        o, ag, dg = self.env.split(arr["flat"])
        no, nag, _ = self.env.split(arr["next_flat"])
        return Episode(obs=o, action=arr["action"], reward=arr["reward"], next_obs=no,
                       terminated=arr["terminated"], achieved_goal=ag, next_achieved_goal=nag,
                       desired_goal=dg, success=arr["success"], goal_terminal=self.goal_terminal)

    def _step(self, action: np.ndarray):
        """env.step with this run's episode rules: (next_flat, reward, terminated, ended, success)."""
        nxt, rew, term, trunc, succ = self.env.step(action)
        succ = succ if succ is not None else np.zeros(self.spec.num_envs, bool)
        if self.success_terminates and not self.cfg.terminate_on_success:
            term = np.zeros_like(term)  # fixed-length episodes: success is not terminal
        self.t += 1
        ended = term | trunc | (self.t >= self.spec.max_episode_steps)
        return nxt, rew, term, ended, succ

    def _rollout(self, seed: int, policy) -> List[Episode]:
        """Whole episodes of all N envs from one reset (evaluation, demonstrations); each ends on its own."""
        N = self.spec.num_envs
        flat = self.env.reset(seed)
        self.t = np.zeros(N, np.int64)
        asm = EpisodeAssembler(N)
        out: List[Optional[Episode]] = [None] * N
        while any(e is None for e in out):
            action = policy(self.env.policy_input(flat))
            nxt, rew, term, ended, succ = self._step(action)
            asm.append(flat=flat, action=action, reward=rew, next_flat=nxt, terminated=term, success=succ)
            for i in np.flatnonzero(ended):
                if out[i] is None:
                    out[i] = self._episode(asm.pop(i))
            flat = nxt
        return out  # type: ignore[return-value]

    def _explore(self, x: np.ndarray) -> np.ndarray:
        if self.env_steps < self.cfg.sac.random_steps:
            return self.rng.uniform(-1.0, 1.0, (x.shape[0], self.spec.act_dim)).astype(np.float32)
        return self.agent.act(x)

    def evaluate(self) -> dict:
        """Deterministic policy on fixed seeds shared by every run (EVAL_SEED_BASE + i)."""
        n = self.cfg.eval_episodes
        eps: List[Episode] = []
        for i in range(math.ceil(n / self.spec.num_envs)):
            eps += self._rollout(EVAL_SEED_BASE + i * self.spec.num_envs,
                                 lambda x: self.agent.act(x, deterministic=True))
        eps = eps[:n]
        return {"eval_return": float(np.mean([e.reward.sum() for e in eps])),
                "eval_success_rate": float(np.mean([e.success.any() for e in eps])),
                "eval_success_at_end": float(np.mean([e.success[-1].any() for e in eps])),
                "eval_episode_length": float(np.mean([e.length for e in eps]))}

    def _collect_demos(self) -> None:
        """Seed the success buffer with scripted-solver successes (an option the paper does not have)."""
        want = self.cfg.replay.solver_demos
        if want <= 0:
            return
        if not self.method.accepts_demos:
            raise ConfigError(f"solver_demos={want}: method {self.cfg.method!r} has no success buffer to seed")
        solver = self.env.solver()
        if solver is None:
            raise ConfigError(f"solver_demos={want}: {self.cfg.env_id!r} has no scripted solver")
        got = 0
        for i in range(3 * want):
            for ep in self._rollout(DEMO_SEED_BASE + i * self.spec.num_envs,
                                    lambda x: _solver_action(solver, self.env)):
                self.demo_env_steps += ep.length
                if ep.success.any() and got < want:
                    self.method.add_demo_episode(ep)
                    got += 1
            if got >= want:
                break

    # ------------------------------------------------------------ main loop
    def run(self, stop_at: Optional[int] = None) -> Optional[dict]:
        """Train to ``cfg.total_steps``; with ``stop_at``, checkpoint and return None once that many
        env steps are done (a time-sliced job; resuming continues the same experiment).

        The loop, top to bottom: act, step, store the step, hand every finished episode to replay,
        update when due, and between episodes evaluate / log / checkpoint when due. Each of the N envs'
        episodes ends on its own (success when ``terminate_on_success``, or the time limit) and that env
        is reset before the next step. Evaluations and checkpoints happen between episodes; with N > 1
        envs the episodes still in flight then are cut (stored as time-limit truncations) and every env
        restarts, so a checkpoint never holds half an episode.
        """
        cfg, N = self.cfg, self.spec.num_envs
        if rundir.is_done(self.out):
            return rundir.read_done(self.out)["final"]
        from torch.utils.tensorboard import SummaryWriter
        from tqdm import tqdm
        self.tb = SummaryWriter(str(self.out), purge_step=self.env_steps if self.resumed else None)
        if not self.resumed:
            self.tb.add_text("config", "```\n" + cfg.to_json() + "\n```", 0)
        if not self.resumed and self.env_steps == 0:
            self._collect_demos()
            if cfg.eval_at_start:  # the starting policy's score (a transfer stage: the prior, zero-shot)
                self._eval_row()
        next_eval = (self.env_steps // cfg.eval_every + 1) * cfg.eval_every
        next_ckpt = (self.env_steps // cfg.checkpoint_every + 1) * cfg.checkpoint_every
        bar = tqdm(total=cfg.total_steps, initial=self.env_steps, disable=not self.show_progress,
                   desc=f"{cfg.method} {cfg.env_id} seed {cfg.seed}", unit="step", dynamic_ncols=True, leave=False)
        t0 = time.perf_counter() - self.wall_time
        asm = EpisodeAssembler(N)
        needs_reset = np.ones(N, bool)  # every env starts a fresh episode (also after a resume)
        flat = np.zeros((N, self.spec.flat_dim), np.float32)
        self.t = np.zeros(N, np.int64)
        try:
            while self.env_steps < cfg.total_steps:
                if needs_reset.any():
                    flat = self._reset_envs(flat, needs_reset)
                    asm.clear(needs_reset)
                    needs_reset[:] = False
                # act, step, store
                action = self._explore(self.env.policy_input(flat))
                nxt, rew, term, ended, succ = self._step(action)
                asm.append(flat=flat, action=action, reward=rew, next_flat=nxt, terminated=term, success=succ)
                self.env_steps += N
                bar.update(N)
                if self.progress_hook is not None:
                    self.progress_hook(self.out, self.env_steps, cfg.total_steps)
                flat = nxt
                for i in np.flatnonzero(ended):
                    self._store(self._episode(asm.pop(i)))
                needs_reset |= ended
                # update when due
                for _ in range(self._updates_due(N, int(ended.sum()))):
                    self._update()
                finished = self.env_steps >= cfg.total_steps
                if not (ended.any() or finished):
                    continue
                # between episodes (or at the budget's end): evaluate, checkpoint, stop when due
                stopping = stop_at is not None and self.env_steps >= stop_at and not finished
                if self.env_steps >= next_eval or finished or self.env_steps >= next_ckpt or stopping:
                    needs_reset |= self._cut_in_flight(asm, needs_reset)
                if self.env_steps >= next_eval or finished:
                    self.wall_time = time.perf_counter() - t0
                    row = self._eval_row()
                    bar.set_postfix(success=f"{row['eval_success_rate']:.2f}", ret=f"{row['eval_return']:.1f}")
                    needs_reset[:] = True  # evaluation reset the envs
                    next_eval = (self.env_steps // cfg.eval_every + 1) * cfg.eval_every
                if self.env_steps >= next_ckpt or finished or stopping:
                    self.wall_time = time.perf_counter() - t0
                    self._check_finite()
                    self.save_checkpoint()
                    next_ckpt = (self.env_steps // cfg.checkpoint_every + 1) * cfg.checkpoint_every
                if stopping:
                    return None
        finally:
            bar.close()
            self.tb.close()
        final = dict(self.rows[-1])
        rundir.write_done(self.out, final, demo_env_steps=self.demo_env_steps)
        if not self.keep_replay:  # after done.json: a kill before it still leaves a resumable checkpoint
            self.save_checkpoint(replay=False)
        return final

    # ------------------------------------------------------------ loop pieces
    def _reset_envs(self, flat: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Reset the envs in ``mask``; each new training episode gets its own seed (exact resume)."""
        idx = np.flatnonzero(mask)
        seeds = [train_episode_seed(self.cfg.seed, self.started + k) for k in range(len(idx))]
        self.started += len(idx)
        flat = flat.copy()
        flat[idx] = self.env.reset_envs(idx, seeds)
        self.t[idx] = 0
        return flat

    def _store(self, ep: Episode) -> None:
        self.method.add_episode(ep)
        self.method.set_progress(min(1.0, self.env_steps / self.cfg.total_steps))
        self.episodes += 1
        self.successes += int(ep.success.any())
        self.episode_steps_total += ep.length

    def _cut_in_flight(self, asm: "EpisodeAssembler", needs_reset: np.ndarray) -> np.ndarray:
        """Store the episodes still running (N > 1) as truncated ones; return which envs were cut."""
        cut = np.zeros_like(needs_reset)
        for i in range(self.spec.num_envs):
            if not needs_reset[i] and asm.length(i) > 0:
                self._store(self._episode(asm.pop(i)))
                cut[i] = True
        return cut

    def _updates_due(self, n_steps: int, n_ended: int) -> int:
        """How many gradient updates this env step buys under the configured schedule."""
        s = self.cfg.sac
        if self.env_steps < s.learning_starts or not self.method.has_data():
            return 0
        self.update_credit += n_steps * s.updates_per_step if s.update_schedule == "step" \
            else n_ended * s.updates_per_episode
        due = int(self.update_credit)
        self.update_credit -= due
        return due

    def _update(self) -> None:
        s = self.cfg.sac
        batch = self.method.sample(s.batch_size)
        actor_batch = self.method.sample_uniform(s.batch_size) if s.actor_uniform_batch else None
        log_now = self.updates % s.log_every == 0
        td_abs, logs = self.agent.update(batch, actor_batch, want_logs=log_now)
        self.method.update_priorities(batch, td_abs)
        self.updates += 1
        if log_now:
            bad = [k for k, v in logs.items() if not math.isfinite(v)]
            if bad:
                raise TrainingDiverged(f"{bad[0]} became {logs[bad[0]]} at update {self.updates} "
                                       f"(env step {self.env_steps}); the last good checkpoint is kept in {self.out}")
            for k, v in logs.items():
                self.tb.add_scalar(k, v, self.env_steps)
            for k, v in self.method.stats().items():
                self.tb.add_scalar(f"replay/{k}", v, self.env_steps)

    def _check_finite(self) -> None:
        for name, p in self.agent.named_parameters():
            if not bool(torch.isfinite(p).all()):
                raise TrainingDiverged(f"network weights {name} are not finite at env step {self.env_steps}; "
                                       f"the last good checkpoint is kept in {self.out}")

    def _eval_row(self) -> dict:
        row = {"env_steps": self.env_steps, **self.evaluate(), "train_episodes": self.episodes,
               "train_successes": self.successes, "updates": self.updates,
               "train_episode_length": round(self.episode_steps_total / max(1, self.episodes), 3),
               "wall_time_s": round(self.wall_time, 2)}
        row.update({(k if k.startswith("replay_") else f"replay_{k}"): v for k, v in self.method.stats().items()})
        self.rows.append(row)
        for k, v in row.items():
            if k != "env_steps" and isinstance(v, (int, float)) and not k.startswith("replay_"):
                self.tb.add_scalar(f"charts/{k}", v, self.env_steps)
        rundir.write_metrics(self.out, self.rows)
        self._train_charts(row)
        self._save_policies(row["eval_success_rate"])
        return row

    def _train_charts(self, row: dict) -> None:
        """TensorBoard only (not metrics.csv): training success rate and env steps/s since the last evaluation."""
        self.tb.add_scalar("charts/train_success_rate", self.successes / max(1, self.episodes), self.env_steps)
        prev = self.rows[-2] if len(self.rows) > 1 else {"env_steps": 0, "wall_time_s": 0.0}
        dt = float(row["wall_time_s"]) - float(prev["wall_time_s"])
        if dt > 0:
            self.tb.add_scalar("charts/env_steps_per_s", (self.env_steps - prev["env_steps"]) / dt, self.env_steps)

    def _save_policies(self, success: float) -> None:
        """policy.pt at every evaluation; policy_best.pt when it beats every earlier one (a tie keeps the earlier)."""
        save_policy(self, self.out / rundir.POLICY, eval_success=success)
        if success > self.best_eval_success:
            self.best_eval_success = float(success)
            save_policy(self, self.out / rundir.POLICY_BEST, eval_success=success)


class TrainingDiverged(ConfigError):
    """A loss or weight became NaN/inf: the run stops with one line, its last checkpoint intact."""


class EpisodeAssembler:
    """Per-env step columns of N parallel envs whose episodes end at different steps."""

    KEYS = ("flat", "action", "reward", "next_flat", "terminated", "success")

    def __init__(self, n: int):
        self.cols: List[Dict[str, list]] = [self._empty() for _ in range(n)]

    def _empty(self) -> Dict[str, list]:
        return {k: [] for k in self.KEYS}

    def append(self, **step: np.ndarray) -> None:
        for i, c in enumerate(self.cols):
            for k in self.KEYS:
                c[k].append(step[k][i])

    def length(self, i: int) -> int:
        return len(self.cols[i]["flat"])

    def pop(self, i: int) -> Dict[str, np.ndarray]:
        c = self.cols[i]
        out = {k: np.stack(v) for k, v in c.items()}
        self.cols[i] = self._empty()
        return out

    def clear(self, mask: np.ndarray) -> None:
        for i in np.flatnonzero(mask):
            self.cols[i] = self._empty()


def _solver_action(solver, env: BatchEnv) -> np.ndarray:
    """Solver actions in the policy's [-1, 1] convention (the solver returns env-scaled actions)."""
    a = solver.act(None)
    a = a.detach().cpu().numpy() if hasattr(a, "detach") else np.asarray(a)
    a = a.reshape(env.num_envs, -1).astype(np.float32)
    return 2.0 * (a - env.low) / np.maximum(env.high - env.low, 1e-8) - 1.0


def run_training(cfg: RunConfig, out_dir, init_from=None, carry_replay: bool = False,
                 show_progress: bool = True, stop_at: Optional[int] = None,
                 keep_replay: bool = False) -> Optional[dict]:
    """Train (or resume, or return the result of) one run in ``out_dir``; returns the final metrics row
    (None if ``stop_at`` paused it early)."""
    if rundir.is_done(out_dir):
        return rundir.read_done(out_dir)["final"]
    trainer = None
    try:
        trainer = Trainer(cfg, out_dir, init_from=init_from, carry_replay=carry_replay,
                          show_progress=show_progress, keep_replay=keep_replay)
        return trainer.run(stop_at=stop_at)
    except Exception as e:  # not KeyboardInterrupt: a kill is no failure, the checkpoint resumes it
        # a refused config (ConfigError before the Trainer exists) is bad input, not a failed run: no file
        # in a folder that may hold another run; everything else leaves its traceback in the run folder
        if trainer is not None or not isinstance(e, ConfigError):
            _write_error(Path(out_dir))
        raise
    finally:
        if trainer is not None:
            trainer.env.close()


def _write_error(out: Path) -> None:
    """``error.txt``: UTC time and the full traceback of the exception being handled (atomic)."""
    import datetime
    import traceback
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
    try:
        atomic_write_text(out / rundir.ERROR, f"failed at {stamp} (UTC)\n{traceback.format_exc()}")
    except OSError:
        pass  # an unwritable folder must not hide the original exception


# --------------------------------------------------------------------------- CLI
_SECTIONS = {"sac": SACConfig, "replay": ReplayConfig}
_ALIASES = {"env_id": "env", "total_steps": "steps"}


def _field_flags(parser: argparse.ArgumentParser) -> None:
    """Every config field becomes a flag (--lr, --her-k, --ratio 0.6/0.4, --hidden 256,256, ...)."""
    groups = [("run", RunConfig)] + list(_SECTIONS.items())
    for section, cls in groups:
        g = parser.add_argument_group(f"{section} options ({cls.__name__} in maniskill_dualher/config.py)")
        docs = field_docs(cls)
        for f in dataclasses.fields(cls):
            if f.name in _SECTIONS:
                continue
            name = _ALIASES.get(f.name, f.name).replace("_", "-")
            dest = f"{section}.{f.name}"
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore
            shown = ",".join(map(str, default)) if isinstance(default, tuple) else default
            help_ = f"{docs.get(f.name, '')} [default: {shown}]".replace("%", "%%")
            if isinstance(default, bool) or f.name in ("learn_alpha",):
                g.add_argument(f"--{name}", dest=dest, action=argparse.BooleanOptionalAction, default=None, help=help_)
            else:
                g.add_argument(f"--{name}", dest=dest, default=None, metavar=f.name.upper(), help=help_)


def config_from_args(args: argparse.Namespace) -> RunConfig:
    """--config file, then --preset (its settings and this task's single-task budget), then the flags given,
    then --set KEY=VALUE: every value typed by one parser (experiment/overrides.py)."""
    from .experiment import overrides
    base = RunConfig()
    if args.config:
        p = Path(args.config)
        if not p.is_file():
            raise ConfigError(f"config file not found: {p}")
        try:
            base = RunConfig.from_dict(json.loads(p.read_text()))
        except json.JSONDecodeError as e:
            raise ConfigError(f"config file {p} is not valid JSON (line {e.lineno})") from None
        except TypeError as e:
            raise ConfigError(f"config file {p}: {e}") from None
    items = []
    for key, raw in vars(args).items():
        if "." not in key or raw is None:
            continue
        section, name = key.split(".", 1)
        path = name if section == "run" else f"{section}.{name}"
        try:
            value = raw if isinstance(raw, bool) else overrides.coerce(path, raw)
        except ConfigError as e:
            if not str(e).startswith("bad value for"):  # a message that already names the value (ratios)
                raise
            raise ConfigError(f"--{_ALIASES.get(name, name).replace('_', '-')}: bad value {raw!r}") from None
        items.append(overrides.Override(path, value))
    if args.preset:
        from .experiment.presets import preset
        given = {o.path: o.value for o in items}
        base = preset(args.preset).single_config(given.get("method", base.method), given.get("seed", base.seed),
                                                 given.get("env_id", base.env_id))
    items += [overrides.parse(i) for i in (args.set or [])]
    if any(o.stage for o in items):
        raise ConfigError("train runs one stage: --set takes KEY=VALUE without a stage prefix (adapt., source.)")
    return overrides.apply(base, items).validate()


def build_parser() -> argparse.ArgumentParser:
    p = OneLineParser(
        prog="python -m maniskill_dualher.train",
        description="Train one SAC run (sac | sac_her_per | dual_buffer) on a ManiSkill task or any gymnasium "
                    "env with a Box action space. Running again on the same --out resumes.")
    p.add_argument("--out", required=True, help="run folder (created; resumed if it holds a checkpoint)")
    p.add_argument("--config", help="JSON file with a RunConfig (flags override it)")
    p.add_argument("--preset", help="start from a sweep preset's settings and this task's single-task budget "
                                    "(quick: settings that learn in minutes; without it the defaults are the "
                                    "paper's Table 3, which learned nothing in 20k env steps on ReachTarget)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="any RunConfig setting, dotted (sac.lr=3e-4, replay.ratio=1/0); repeatable")
    p.add_argument("--init-from", help="a finished run folder whose networks start this run (transfer)")
    p.add_argument("--carry-replay", action="store_true", help="with --init-from: also carry its replay buffers")
    p.add_argument("--keep-replay", action="store_true",
                   help="keep the replay buffers in the finished run's checkpoint (for a later --carry-replay)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _field_flags(p)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        cfg = config_from_args(args)
        final = run_training(cfg, args.out, init_from=args.init_from, carry_replay=args.carry_replay,
                             show_progress=not args.no_progress, keep_replay=args.keep_replay)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(final))
    return 0


if __name__ == "__main__":
    sys.exit(main())
