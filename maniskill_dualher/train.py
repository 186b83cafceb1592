"""One run: act -> step -> store -> update when due -> evaluate / log / checkpoint between episodes.

    python -m maniskill_dualher.train --env ReachTarget-v1 --method dual_buffer --seed 0 --steps 30000 --out runs/x

A run folder is the unit of truth: ``config.json``, ``metrics.csv`` (one row per evaluation),
TensorBoard events (``losses/*`` every ``log_every`` updates, ``charts/*`` and ``replay/*``),
``checkpoint.pt`` and, once finished, ``done.json`` (``rundir.RunFolder`` keeps them). Running again on the
same folder resumes from the checkpoint; because every training episode is reset with its own seed and
checkpoints are taken between episodes together with all random-number state and the counters
(``counters.Counters``), a resumed run produces the same metrics as an uninterrupted one (CPU simulation,
one env).

Episodes end on success when ``terminate_on_success`` (the paper, section 4.1) or at ``max_episode_steps``;
with N parallel envs each env's episode ends on its own and goes to replay (with its hindsight goals) as soon
as it ends (``episodes.EnvEpisodes``: each env's clock and the episode arrays). Evaluation has its own
``EnvEpisodes``. The command line's flags and their RunConfig live in ``cli.py``.
"""
from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path
from typing import List, Optional

import numpy as np
import torch

from .config import ConfigError, RunConfig
from .counters import Counters
from .envs import EVAL_SEED_BASE, BatchEnv, make_env, train_episode_seed
from .episodes import EnvEpisodes
from .policy import save_policy
from .replay.base import Episode
from .rundir import POLICY, POLICY_BEST, RunFolder, load_checkpoint
from .sac import SAC

DEMO_SEED_BASE = 2_000_000_000


class Diagnostics:
    """The learner's state on the batches it trained on, per batch source (R or E; R for single-buffer
    methods): mean |TD| over every update, and alpha, policy entropy, mean Q and the critic loss over the updates
    that log (every ``log_every``), averaged between evaluations. Reads what the update returns; changes nothing."""
    STATS = ("losses/alpha", "losses/entropy", "losses/qf_values", "losses/qf_loss")

    def __init__(self):
        self.rows: List[dict] = []
        self._win: dict = {}

    def add(self, batch, td_abs: np.ndarray, logs: Optional[dict]) -> None:
        src = getattr(batch.handle, "source", "R") or "R"
        w = self._win.setdefault(src, {"updates": 0, "td": 0.0, "logged": 0, **{k: 0.0 for k in self.STATS}})
        w["updates"] += 1
        w["td"] += float(np.mean(td_abs))
        if logs:
            w["logged"] += 1
            for k in self.STATS:
                w[k] += float(logs.get(k, float("nan")))

    def close_window(self, env_steps: int, updates: int) -> List[dict]:
        """One row for the window since the last evaluation; -> every row so far."""
        row = {"env_steps": env_steps, "updates": updates}
        for src, w in sorted(self._win.items()):
            row[f"{src}_updates"] = w["updates"]
            row[f"{src}_td_abs"] = round(w["td"] / w["updates"], 6)
            row[f"{src}_logged"] = w["logged"]
            for k in self.STATS:
                row[f"{src}_{k.split('/')[-1]}"] = round(w[k] / w["logged"], 6) if w["logged"] else ""
        self._win = {}
        self.rows.append(row)
        return self.rows

    def state_dict(self) -> dict:
        return {"rows": list(self.rows), "window": dict(self._win)}

    def load_state_dict(self, state: Optional[dict]) -> None:
        if state:
            self.rows, self._win = list(state["rows"]), dict(state["window"])


class Trainer:
    # called as progress_hook(out_dir, env_steps, total_steps) after every env step when set (a callable
    # object, or a staticmethod): the sweep's progress file, experiment/backends.py: ProgressFile
    progress_hook = None

    def __init__(self, cfg: RunConfig, out_dir, init_from=None, carry_replay: bool = False,
                 show_progress: bool = True, keep_replay: bool = False):
        from .methods import make_method  # late: methods import replay pieces

        self.cfg = cfg.validate()
        self.folder = RunFolder(out_dir)
        self.out = self.folder.path
        self.show_progress = show_progress
        self.keep_replay = keep_replay  # a finished run keeps its replay only if a later stage reads it
        self.folder.check_identity(cfg.to_json())
        init_state = load_checkpoint(Path(init_from)) if init_from is not None else None

        torch.set_num_threads(cfg.torch_threads)
        torch.manual_seed(cfg.seed)
        self.rng = np.random.default_rng(cfg.seed)
        self.env: BatchEnv = make_env(cfg)
        self.spec = self.env.spec
        self.method = make_method(cfg, self.spec, np.random.default_rng([cfg.seed, 1]), device=cfg.device)
        self.agent = SAC(self.spec.input_dim, self.spec.act_dim, cfg.sac, device=cfg.device)
        self.train_eps = EnvEpisodes(self.env, cfg.terminate_on_success)
        self.eval_eps = EnvEpisodes(self.env, cfg.terminate_on_success)  # its own clock and arrays
        self.count = Counters()
        self.rows: List[dict] = []  # metrics.csv: one per evaluation
        self.diag = Diagnostics()   # diagnostics.csv: the learner's logs per batch source (R or E)
        self.resumed = False
        if self.folder.has_checkpoint:
            self._restore(self.folder.load_checkpoint())
            self.resumed = True
        elif init_state is not None:
            self._init_from(init_state, carry_replay)
        self.folder.record_start(cfg.to_json(), init_from, carry_replay)

    # counters by name, for callers that read a trainer (policy files, benches)
    env_steps = property(lambda self: self.count.env_steps)
    updates = property(lambda self: self.count.updates)
    episodes = property(lambda self: self.count.episodes)
    successes = property(lambda self: self.count.successes)

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
        return {"config": self.cfg.to_dict(), "agent": self.agent.full_state(), "method": self.method.state_dict(),
                "counters": self.count.state_dict(), "rows": self.rows, "diag": self.diag.state_dict(),
                "rng": self.rng.bit_generator.state,
                "torch_rng": torch.get_rng_state()}

    def _restore(self, state: dict) -> None:
        self.agent.load_full_state(state["agent"])
        self.method.load_state_dict(state["method"])
        self.count = Counters.from_state(state["counters"])
        self.rows = list(state["rows"])
        self.diag.load_state_dict(state.get("diag"))
        self.rng.bit_generator.state = state["rng"]
        torch.set_rng_state(state["torch_rng"])

    def save_checkpoint(self, replay: bool = True) -> None:
        """Write the checkpoint; ``replay=False`` leaves the replay buffers out (a finished run nobody resumes)."""
        state = self._state()
        if not replay:
            state["method"] = None
        self.folder.save_checkpoint(state)

    # ------------------------------------------------------------ the loop
    def run(self, stop_at: Optional[int] = None) -> Optional[dict]:
        """Train to ``cfg.total_steps``; with ``stop_at``, checkpoint and return None once that many
        env steps are done (a time-sliced job; resuming continues the same experiment).

        Each of the N envs' episodes ends on its own and that env is reset before the next step.
        Evaluations and checkpoints happen between episodes; with N > 1 envs the episodes still in
        flight then are cut (stored as time-limit truncations), so a checkpoint never holds half an episode.
        """
        cfg, c = self.cfg, self.count
        if self.folder.done:
            return self.folder.final()
        self.start()
        try:
            while c.env_steps < cfg.total_steps:
                ended = self.collect_step()                                       # act, step, store
                for _ in range(self.updates_due(ended)):                          # update when due
                    self._update()
                if self.between_episodes(ended, stop_at):                         # evaluate, checkpoint
                    return None  # paused at stop_at: checkpointed
        finally:
            self.close_logs()
        return self.finish()

    # ------------------------------------------------------------ loop pieces (a pack calls them too: pack.py)
    def start(self) -> None:
        """Logs open; a fresh run's demonstrations and step-0 evaluation; every env starts a fresh episode."""
        c = self.count
        self._open_logs()
        if not self.resumed and c.env_steps == 0:
            self._collect_demos()
            if self.cfg.eval_at_start:  # the starting policy's score (a transfer stage: the prior, zero-shot)
                self._eval_row()
        self._t0 = time.perf_counter() - c.wall_time
        self.train_eps.restart()  # also after a resume

    def collect_step(self) -> np.ndarray:
        """One step of every env: act, step, count, store the episodes that ended. -> which envs' episodes ended."""
        eps = self.train_eps
        self._begin_episodes()
        action = self._explore(self.env.policy_input(eps.flat))
        ended = eps.step(action)
        self._count_steps(eps.n_envs)
        for ep in eps.finished(ended):
            self._store(ep)
        return ended

    def updates_due(self, ended: np.ndarray) -> int:
        return self._updates_due(self.train_eps.n_envs, int(ended.sum()))

    def between_episodes(self, ended: np.ndarray, stop_at: Optional[int]) -> bool:
        """After a step: evaluate / checkpoint / pause when an episode ended or the budget is spent; True if
        the run pauses here (``stop_at``)."""
        finished = self.count.env_steps >= self.cfg.total_steps
        return bool((ended.any() or finished) and self._between_episodes(finished, stop_at, self._t0))

    # ------------------------------------------------------------ loop pieces
    def _open_logs(self) -> None:
        from torch.utils.tensorboard import SummaryWriter
        from tqdm import tqdm
        cfg = self.cfg
        self.tb = SummaryWriter(str(self.out), purge_step=self.count.env_steps if self.resumed else None)
        if not self.resumed:
            self.tb.add_text("config", "```\n" + cfg.to_json() + "\n```", 0)
        self.bar = tqdm(total=cfg.total_steps, initial=self.count.env_steps, disable=not self.show_progress,
                        desc=f"{cfg.method} {cfg.env_id} seed {cfg.seed}", unit="step", dynamic_ncols=True,
                        leave=False)
        self._next_eval = self._next(cfg.eval_every)
        self._next_ckpt = self._next(cfg.checkpoint_every)

    def close_logs(self) -> None:
        self.bar.close()
        self.tb.close()

    def _next(self, every: int) -> int:
        return (self.count.env_steps // every + 1) * every

    def _begin_episodes(self) -> None:
        """Reset the envs whose episode ended; each new training episode gets its own seed (exact resume)."""
        idx = np.flatnonzero(self.train_eps.pending)
        if len(idx):
            seeds = [train_episode_seed(self.cfg.seed, self.count.started + k) for k in range(len(idx))]
            self.count.started += len(idx)
            self.train_eps.reset(idx, seeds)

    def _count_steps(self, n: int) -> None:
        self.count.env_steps += n
        self.bar.update(n)
        if self.progress_hook is not None:
            self.progress_hook(self.out, self.count.env_steps, self.cfg.total_steps)

    def _between_episodes(self, finished: bool, stop_at: Optional[int], t0: float) -> bool:
        """Evaluate, checkpoint and stop when due; True if the run pauses here (``stop_at``)."""
        c = self.count
        stopping = stop_at is not None and c.env_steps >= stop_at and not finished
        eval_due = c.env_steps >= self._next_eval or finished
        ckpt_due = c.env_steps >= self._next_ckpt or finished or stopping
        if eval_due or ckpt_due:
            for ep in self.train_eps.cut_in_flight():
                self._store(ep)
        if eval_due:
            c.wall_time = time.perf_counter() - t0
            row = self._eval_row()
            self.bar.set_postfix(success=f"{row['eval_success_rate']:.2f}", ret=f"{row['eval_return']:.1f}")
            self._next_eval = self._next(self.cfg.eval_every)
        if ckpt_due:
            c.wall_time = time.perf_counter() - t0
            self._check_finite()
            self.save_checkpoint()
            self._next_ckpt = self._next(self.cfg.checkpoint_every)
        return stopping

    def finish(self) -> dict:
        final = dict(self.rows[-1])
        self.folder.finish(final, demo_env_steps=self.count.demo_env_steps)
        if not self.keep_replay:  # after done.json: a kill before it still leaves a resumable checkpoint
            self.save_checkpoint(replay=False)
        return final

    def _explore(self, x: np.ndarray) -> np.ndarray:
        if self.count.env_steps < self.cfg.sac.random_steps:
            return self.rng.uniform(-1.0, 1.0, (x.shape[0], self.spec.act_dim)).astype(np.float32)
        return self.agent.act(x)

    def _store(self, ep: Episode) -> None:
        c = self.count
        self.method.add_episode(ep)
        self.method.set_progress(min(1.0, c.env_steps / self.cfg.total_steps))
        c.episodes += 1
        c.successes += int(ep.success.any())
        c.episode_steps_total += ep.length

    def _updates_due(self, n_steps: int, n_ended: int) -> int:
        """How many gradient updates this env step buys under the configured schedule."""
        s, c = self.cfg.sac, self.count
        if c.env_steps < s.learning_starts or not self.method.has_data():
            return 0
        c.update_credit += n_steps * s.updates_per_step if s.update_schedule == "step" \
            else n_ended * s.updates_per_episode
        due = int(c.update_credit)
        c.update_credit -= due
        return due

    def _update(self) -> None:
        batch, actor_batch, log_now = self.sample()
        td_abs, logs = self.agent.update(batch, actor_batch, want_logs=log_now)
        self.apply_update(batch, td_abs, logs, log_now)

    def sample(self):
        """The next update's batches -> (batch, actor batch or None, whether this update logs)."""
        s = self.cfg.sac
        batch = self.method.sample(s.batch_size)
        actor_batch = self.method.sample_uniform(s.batch_size) if s.actor_uniform_batch else None
        return batch, actor_batch, self.count.updates % s.log_every == 0

    def apply_update(self, batch, td_abs: np.ndarray, logs: dict, log_now: bool) -> None:
        """What follows the agent's update: priorities, the count, the logs (a diverged loss stops the run)."""
        c = self.count
        self.method.update_priorities(batch, td_abs)
        c.updates += 1
        self.diag.add(batch, td_abs, logs if log_now else None)
        if log_now:
            bad = [k for k, v in logs.items() if not math.isfinite(v)]
            if bad:
                raise TrainingDiverged(f"{bad[0]} became {logs[bad[0]]} at update {c.updates} "
                                       f"(env step {c.env_steps}); the last good checkpoint is kept in {self.out}")
            for k, v in logs.items():
                self.tb.add_scalar(k, v, c.env_steps)
            for k, v in self.method.stats().items():
                self.tb.add_scalar(f"replay/{k}", v, c.env_steps)

    def _check_finite(self) -> None:
        for name, p in self.agent.named_parameters():
            if not bool(torch.isfinite(p).all()):
                raise TrainingDiverged(f"network weights {name} are not finite at env step {self.count.env_steps}; "
                                       f"the last good checkpoint is kept in {self.out}")

    # ------------------------------------------------------------ evaluation, demonstrations
    def evaluate(self) -> dict:
        """Deterministic policy on fixed seeds shared by every run (EVAL_SEED_BASE + i), on the evaluation's own
        episodes; it resets the simulator, so the training episodes start anew afterwards."""
        n, N = self.cfg.eval_episodes, self.spec.num_envs
        eps: List[Episode] = []
        for i in range(math.ceil(n / N)):
            eps += self.eval_eps.rollout(EVAL_SEED_BASE + i * N, lambda x: self.agent.act(x, deterministic=True))
        self.train_eps.restart()
        eps = eps[:n]
        return {"eval_return": float(np.mean([e.reward.sum() for e in eps])),
                "eval_success_rate": float(np.mean([e.success.any() for e in eps])),
                "eval_success_at_end": float(np.mean([e.success[-1].any() for e in eps])),
                "eval_episode_length": float(np.mean([e.length for e in eps]))}

    def _rollout(self, seed: int, policy) -> List[Episode]:
        """Whole episodes of all N envs from one reset, on the evaluation's episodes (tests, demonstrations)."""
        out = self.eval_eps.rollout(seed, policy)
        self.train_eps.restart()
        return out

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
                self.count.demo_env_steps += ep.length
                if ep.success.any() and got < want:
                    self.method.add_demo_episode(ep)
                    got += 1
            if got >= want:
                break

    def _eval_row(self) -> dict:
        c = self.count
        row = {"env_steps": c.env_steps, **self.evaluate(), "train_episodes": c.episodes,
               "train_successes": c.successes, "updates": c.updates,
               "train_episode_length": round(c.episode_steps_total / max(1, c.episodes), 3),
               "wall_time_s": round(c.wall_time, 2)}
        row.update({(k if k.startswith("replay_") else f"replay_{k}"): v for k, v in self.method.stats().items()})
        self.rows.append(row)
        for k, v in row.items():
            if k != "env_steps" and isinstance(v, (int, float)) and not k.startswith("replay_"):
                self.tb.add_scalar(f"charts/{k}", v, c.env_steps)
        self.folder.write_metrics(self.rows)
        self.folder.write_diagnostics(self.diag.close_window(c.env_steps, c.updates))
        self._train_charts(row)
        self._save_policies(row["eval_success_rate"])
        return row

    def _train_charts(self, row: dict) -> None:
        """TensorBoard only (not metrics.csv): training success rate and env steps/s since the last evaluation."""
        c = self.count
        self.tb.add_scalar("charts/train_success_rate", c.successes / max(1, c.episodes), c.env_steps)
        prev = self.rows[-2] if len(self.rows) > 1 else {"env_steps": 0, "wall_time_s": 0.0}
        dt = float(row["wall_time_s"]) - float(prev["wall_time_s"])
        if dt > 0:
            self.tb.add_scalar("charts/env_steps_per_s", (c.env_steps - prev["env_steps"]) / dt, c.env_steps)

    def _save_policies(self, success: float) -> None:
        """policy.pt at every evaluation; policy_best.pt when it beats every earlier one (a tie keeps the earlier)."""
        save_policy(self, self.out / POLICY, eval_success=success)
        if success > self.count.best_eval_success:
            self.count.best_eval_success = float(success)
            save_policy(self, self.out / POLICY_BEST, eval_success=success)


class TrainingDiverged(ConfigError):
    """A loss or weight became NaN/inf: the run stops with one line, its last checkpoint intact."""


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
    folder = RunFolder(out_dir)
    if folder.done:
        return folder.final()
    trainer = None
    try:
        trainer = Trainer(cfg, out_dir, init_from=init_from, carry_replay=carry_replay,
                          show_progress=show_progress, keep_replay=keep_replay)
        return trainer.run(stop_at=stop_at)
    except Exception as e:  # not KeyboardInterrupt: a kill is no failure, the checkpoint resumes it
        # a refused config (ConfigError before the Trainer exists) is bad input, not a failed run: no file
        # in a folder that may hold another run; everything else leaves its traceback in the run folder
        if trainer is not None or not isinstance(e, ConfigError):
            folder.write_error()
        raise
    finally:
        if trainer is not None:
            trainer.env.close()


# --------------------------------------------------------------------------- python -m maniskill_dualher.train
# (the flags and how they become a RunConfig live in cli.py)
from .cli import train_config as config_from_args, train_parser as build_parser  # noqa: E402


def main(argv=None) -> int:
    """One run (or its resume); prints its final metrics row as JSON; bad input: one line, exit code 2."""
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
