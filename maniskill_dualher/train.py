"""One run: rollout -> replay -> SAC update -> evaluation -> metrics and checkpoint.

    python -m maniskill_dualher.train --env ReachTarget-v1 --method dual_buffer --seed 0 --steps 30000 --out runs/x

A run folder is the unit of truth: ``config.json``, ``metrics.csv`` (one row per evaluation),
TensorBoard events, ``checkpoint.pt`` and, once finished, ``done.json``. Running again on the same
folder resumes from the checkpoint; because every training episode is reset with its own seed and
checkpoints are taken at episode boundaries together with all random-number state, a resumed run
produces the same metrics as an uninterrupted one (CPU simulation).

Episodes of ManiSkill tasks have a fixed length (``max_episode_steps``; success does not end them,
as in the Fetch/HER convention), so N parallel GPU envs stay in lockstep and whole episodes go to
replay at once. Plain gymnasium envs end on ``terminated or truncated``.
"""
from __future__ import annotations

import argparse
import csv
import dataclasses
import io
import json
import math
import sys
import time
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np
import torch

from .config import ConfigError, ReplayConfig, RunConfig, SACConfig, parse_ratio
from .fileio import atomic_torch_save, atomic_write_text
from .envs import EVAL_SEED_BASE, BatchEnv, make_env, train_episode_seed
from .replay.base import Episode
from .sac import SAC

METRIC_COLUMNS = ["env_steps", "eval_return", "eval_success_rate", "eval_success_at_end",
                  "train_episodes", "train_successes", "updates", "wall_time_s"]
DEMO_SEED_BASE = 2_000_000_000
CHECKPOINT = "checkpoint.pt"


def rows_to_csv(rows: List[dict]) -> str:
    cols = list(METRIC_COLUMNS) + sorted({k for r in rows for k in r} - set(METRIC_COLUMNS))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: r.get(k, "") for k in cols})
    return buf.getvalue()


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
    def __init__(self, cfg: RunConfig, out_dir, init_from=None, carry_replay: bool = False,
                 show_progress: bool = True):
        from .methods import make_method  # late: methods import replay pieces

        self.cfg = cfg.validate()
        self.out = Path(out_dir)
        self.show_progress = show_progress
        self._check_out_dir()
        init_state = load_checkpoint(Path(init_from)) if init_from is not None else None

        torch.set_num_threads(cfg.torch_threads)
        torch.manual_seed(cfg.seed)
        self.rng = np.random.default_rng(cfg.seed)
        self.env: BatchEnv = make_env(cfg)
        self.spec = self.env.spec
        self.method = make_method(cfg, self.spec, np.random.default_rng([cfg.seed, 1]), device=cfg.device)
        self.agent = SAC(self.spec.input_dim, self.spec.act_dim, cfg.sac, device=cfg.device)

        # counters: everything needed to continue exactly where a checkpoint left off
        self.env_steps = 0
        self.episodes = 0
        self.successes = 0
        self.updates = 0
        self.update_credit = 0.0
        self.wall_time = 0.0
        self.demo_env_steps = 0
        self.rows: List[dict] = []
        self.resumed = False

        if (self.out / CHECKPOINT).is_file():
            self._restore(load_checkpoint(self.out))
            self.resumed = True
        elif init_state is not None:
            self._init_from(init_state, carry_replay)
        self.out.mkdir(parents=True, exist_ok=True)
        atomic_write_text(self.out / "config.json", cfg.to_json() + "\n")
        meta = {"init_from": str(init_from) if init_from else None, "carry_replay": bool(carry_replay)}
        atomic_write_text(self.out / "lineage.json", json.dumps(meta, indent=2) + "\n")

    def _check_out_dir(self) -> None:
        cfg_path = self.out / "config.json"
        if cfg_path.is_file():
            try:
                old = json.loads(cfg_path.read_text())
            except json.JSONDecodeError:
                raise ConfigError(f"{cfg_path} is not valid JSON") from None
            new = json.loads(self.cfg.to_json())
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
            self.method.load_state_dict(state["method"])
            if hasattr(self.method, "reseed"):  # keep this run's own sampling stream
                self.method.reseed(np.random.default_rng([self.cfg.seed, 1]))

    # ------------------------------------------------------------ checkpoint
    def _state(self) -> dict:
        return {
            "config": self.cfg.to_dict(),
            "agent": self.agent.full_state(),
            "method": self.method.state_dict(),
            "counters": dict(env_steps=self.env_steps, episodes=self.episodes, successes=self.successes,
                             updates=self.updates, update_credit=self.update_credit,
                             wall_time=self.wall_time, demo_env_steps=self.demo_env_steps),
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

    def save_checkpoint(self) -> None:
        atomic_torch_save(self._state(), self.out / CHECKPOINT)

    # ------------------------------------------------------------ rollouts
    def _run_episode(self, seed: int, policy) -> Episode:
        """One episode of all N envs; ``policy(policy_input) -> actions in [-1, 1]``."""
        env, T, N = self.env, self.spec.max_episode_steps, self.spec.num_envs
        flat = env.reset(seed)
        cols: Dict[str, list] = {k: [] for k in ("flat", "action", "reward", "next_flat", "terminated", "success")}
        for t in range(T):
            action = policy(env.policy_input(flat))
            nxt, rew, term, trunc, succ = env.step(action)
            cols["flat"].append(flat)
            cols["action"].append(action.astype(np.float32, copy=False))
            cols["reward"].append(rew)
            # ManiSkill tasks: success is not terminal (fixed-length episodes); plain envs: true termination
            cols["terminated"].append(term if not self.spec.is_maniskill else np.zeros(N, bool))
            cols["success"].append(succ if succ is not None else np.zeros(N, bool))
            cols["next_flat"].append(nxt)
            flat = nxt
            if not self.spec.is_maniskill and (term | trunc).all():
                break
        arr = {k: np.stack(v) for k, v in cols.items()}
        o, ag, dg = env.split(arr["flat"])
        no, nag, _ = env.split(arr["next_flat"])
        return Episode(obs=o, action=arr["action"], reward=arr["reward"], next_obs=no,
                       terminated=arr["terminated"], achieved_goal=ag, next_achieved_goal=nag,
                       desired_goal=dg, success=arr["success"])

    def _explore(self, x: np.ndarray) -> np.ndarray:
        if self.env_steps < self.cfg.sac.random_steps:
            return self.rng.uniform(-1.0, 1.0, (x.shape[0], self.spec.act_dim)).astype(np.float32)
        return self.agent.act(x)

    def evaluate(self) -> dict:
        """Deterministic policy on fixed seeds shared by every run (EVAL_SEED_BASE + i)."""
        n_rounds = math.ceil(self.cfg.eval_episodes / self.spec.num_envs)
        rets, once, end = [], [], []
        for i in range(n_rounds):
            ep = self._run_episode(EVAL_SEED_BASE + i, lambda x: self.agent.act(x, deterministic=True))
            rets.append(ep.reward.sum(0))
            once.append(ep.success.any(0))
            end.append(ep.success[-1])
        n = self.cfg.eval_episodes
        return {"eval_return": float(np.concatenate(rets)[:n].mean()),
                "eval_success_rate": float(np.concatenate(once)[:n].mean()),
                "eval_success_at_end": float(np.concatenate(end)[:n].mean())}

    def _collect_demos(self) -> None:
        """Seed the success buffer with scripted-solver successes (an option the paper does not have)."""
        want = self.cfg.replay.solver_demos
        if want <= 0 or not hasattr(self.method, "add_demo_episode"):
            return
        solver = self.env.solver()
        if solver is None:
            raise ConfigError(f"solver_demos={want}: {self.cfg.env_id!r} has no scripted solver")
        got = 0
        for i in range(3 * want):
            ep = self._run_episode(DEMO_SEED_BASE + i, lambda x: _solver_action(solver, self.env))
            self.demo_env_steps += ep.length * self.spec.num_envs
            if ep.success.any():
                self.method.add_demo_episode(ep)
                got += int(ep.success.any(0).sum())
            if got >= want:
                break

    # ------------------------------------------------------------ main loop
    def run(self, stop_at: Optional[int] = None) -> Optional[dict]:
        """Train to ``cfg.total_steps``; with ``stop_at``, checkpoint and return None once that many
        env steps are done (a time-sliced job; resuming continues the same experiment)."""
        cfg = self.cfg
        done_path = self.out / "done.json"
        if done_path.is_file():
            return json.loads(done_path.read_text())["final"]
        from torch.utils.tensorboard import SummaryWriter
        tb = SummaryWriter(str(self.out), purge_step=self.env_steps if self.resumed else None)
        if not self.resumed and self.env_steps == 0:
            self._collect_demos()

        next_eval = (self.env_steps // cfg.eval_every + 1) * cfg.eval_every
        next_ckpt = (self.env_steps // cfg.checkpoint_every + 1) * cfg.checkpoint_every
        from tqdm import tqdm
        bar = tqdm(total=cfg.total_steps, initial=self.env_steps, disable=not self.show_progress,
                   desc=f"{cfg.method} {cfg.env_id} seed {cfg.seed}", unit="step", dynamic_ncols=True, leave=False)
        t0 = time.perf_counter() - self.wall_time
        N = self.spec.num_envs
        pending_logs: Dict[str, float] = {}
        try:
            while self.env_steps < cfg.total_steps:
                ep = self._rollout_and_learn(train_episode_seed(cfg.seed, self.episodes // N), bar, pending_logs)
                self.method.add_episode(ep)
                self.method.set_progress(min(1.0, self.env_steps / cfg.total_steps))
                self.episodes += N
                self.successes += int(ep.success.any(0).sum())
                finished = self.env_steps >= cfg.total_steps
                if self.env_steps >= next_eval or finished:
                    self.wall_time = time.perf_counter() - t0
                    row = {"env_steps": self.env_steps, **self.evaluate(), "train_episodes": self.episodes,
                           "train_successes": self.successes, "updates": self.updates,
                           "wall_time_s": round(self.wall_time, 2)}
                    row.update({(k if k.startswith("replay_") else f"replay_{k}"): v for k, v in self.method.stats().items()})
                    self.rows.append(row)
                    for k, v in row.items():
                        if k != "env_steps" and isinstance(v, (int, float)):
                            tb.add_scalar(k if k.startswith("replay_") else f"charts/{k}", v, self.env_steps)
                    for k, v in pending_logs.items():
                        tb.add_scalar(f"train/{k}", v, self.env_steps)
                    atomic_write_text(self.out / "metrics.csv", rows_to_csv(self.rows))
                    bar.set_postfix(success=f"{row['eval_success_rate']:.2f}", ret=f"{row['eval_return']:.1f}")
                    next_eval = (self.env_steps // cfg.eval_every + 1) * cfg.eval_every
                stopping = stop_at is not None and self.env_steps >= stop_at and not finished
                if self.env_steps >= next_ckpt or finished or stopping:
                    self.wall_time = time.perf_counter() - t0
                    self.save_checkpoint()
                    next_ckpt = (self.env_steps // cfg.checkpoint_every + 1) * cfg.checkpoint_every
                if stopping:
                    return None
        finally:
            bar.close()
            tb.close()
        final = dict(self.rows[-1])
        atomic_write_text(done_path, json.dumps({"final": final, "demo_env_steps": self.demo_env_steps}, indent=2) + "\n")
        return final

    def _rollout_and_learn(self, seed: int, bar, logs: Dict[str, float]) -> Episode:
        """One training episode with the update schedule interleaved step by step."""
        s, N = self.cfg.sac, self.spec.num_envs
        stored = self.episodes > 0 or self._has_replay()

        def policy(x):
            a = self._explore(x)
            self.env_steps += N
            bar.update(N)
            if stored and self.env_steps >= s.learning_starts:
                self.update_credit += N * s.updates_per_step
                while self.update_credit >= 1.0:
                    self.update_credit -= 1.0
                    self._update(logs)
            return a

        return self._run_episode(seed, policy)

    def _has_replay(self) -> bool:
        st = self.method.stats()
        return any(v > 0 for k, v in st.items() if k.endswith("size"))

    def _update(self, logs: Dict[str, float]) -> None:
        s = self.cfg.sac
        batch = self.method.sample(s.batch_size)
        actor_batch = self.method.sample_uniform(s.batch_size) if s.actor_uniform_batch else None
        td_abs, new_logs = self.agent.update(batch, actor_batch)
        self.method.update_priorities(batch, td_abs)
        self.updates += 1
        if new_logs:
            logs.update(new_logs)


def _solver_action(solver, env: BatchEnv) -> np.ndarray:
    """Solver actions in the policy's [-1, 1] convention (the solver returns env-scaled actions)."""
    a = solver.act(None)
    a = a.detach().cpu().numpy() if hasattr(a, "detach") else np.asarray(a)
    a = a.reshape(env.num_envs, -1).astype(np.float32)
    return 2.0 * (a - env.low) / np.maximum(env.high - env.low, 1e-8) - 1.0


def run_training(cfg: RunConfig, out_dir, init_from=None, carry_replay: bool = False,
                 show_progress: bool = True, stop_at: Optional[int] = None) -> Optional[dict]:
    """Train (or resume, or return the result of) one run in ``out_dir``; returns the final metrics row
    (None if ``stop_at`` paused it early)."""
    done = Path(out_dir) / "done.json"
    if done.is_file():
        return json.loads(done.read_text())["final"]
    trainer = Trainer(cfg, out_dir, init_from=init_from, carry_replay=carry_replay, show_progress=show_progress)
    try:
        return trainer.run(stop_at=stop_at)
    finally:
        trainer.env.close()


# --------------------------------------------------------------------------- CLI
_SECTIONS = {"sac": SACConfig, "replay": ReplayConfig}
_ALIASES = {"env_id": "env", "total_steps": "steps"}


def _field_flags(parser: argparse.ArgumentParser) -> None:
    """Every config field becomes a flag (--lr, --her-k, --ratio 0.6/0.4, --hidden 256,256, ...)."""
    groups = [("run", RunConfig)] + list(_SECTIONS.items())
    for section, cls in groups:
        g = parser.add_argument_group(f"{section} options")
        for f in dataclasses.fields(cls):
            if f.name in _SECTIONS:
                continue
            name = _ALIASES.get(f.name, f.name).replace("_", "-")
            dest = f"{section}.{f.name}"
            default = f.default if f.default is not dataclasses.MISSING else f.default_factory()  # type: ignore
            help_ = f"default: {default}"
            if isinstance(default, bool) or f.name in ("learn_alpha",):
                g.add_argument(f"--{name}", dest=dest, action=argparse.BooleanOptionalAction, default=None, help=help_)
            else:
                g.add_argument(f"--{name}", dest=dest, default=None, metavar=f.name.upper(), help=help_)


def _coerce(name: str, raw: str, default):
    try:
        if name == "ratio":
            return parse_ratio(raw)
        if isinstance(default, tuple):
            return tuple(int(x) for x in raw.replace("x", ",").split(",") if x)
        if isinstance(default, int) and not isinstance(default, bool):
            return int(float(raw)) if float(raw).is_integer() else int(raw)
        if isinstance(default, float):
            return float(raw)
        if default is None and name in ("max_episode_steps",):
            return int(raw)
        if default is None and name in ("target_entropy",):
            return float(raw)
        return raw
    except ValueError:
        raise ConfigError(f"--{name.replace('_', '-')}: bad value {raw!r}") from None


def config_from_args(args: argparse.Namespace) -> RunConfig:
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
    d = base.to_dict()
    for key, raw in vars(args).items():
        if "." not in key or raw is None:
            continue
        section, name = key.split(".", 1)
        target = d if section == "run" else d[section]
        default = getattr(RunConfig() if section == "run" else _SECTIONS[section](), name)
        target[name] = raw if isinstance(raw, bool) else _coerce(name, raw, default)
    return RunConfig.from_dict(d).validate()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m maniskill_dualher.train",
        description="Train one SAC run (sac | sac_her_per | dual_buffer) on a ManiSkill task or any gymnasium "
                    "env with a Box action space. Running again on the same --out resumes.")
    p.add_argument("--out", required=True, help="run folder (created; resumed if it holds a checkpoint)")
    p.add_argument("--config", help="JSON file with a RunConfig (flags override it)")
    p.add_argument("--init-from", help="a finished run folder whose networks start this run (transfer)")
    p.add_argument("--carry-replay", action="store_true", help="with --init-from: also carry its replay buffers")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _field_flags(p)
    return p


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        cfg = config_from_args(args)
        final = run_training(cfg, args.out, init_from=args.init_from, carry_replay=args.carry_replay,
                             show_progress=not args.no_progress)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(json.dumps(final))
    return 0


if __name__ == "__main__":
    sys.exit(main())
