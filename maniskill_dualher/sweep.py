"""The paper's experiment grid: run folders keyed by config, resumable, on a local pool or Ray.

    python -m maniskill_dualher.sweep                      # preset "quick": every table and plot, <= 90 min on 2 cores
    python -m maniskill_dualher.sweep --preset smoke       # the whole pipeline in about a minute (CI)
    python -m maniskill_dualher.sweep --dry-run            # list the runs, write nothing

Each run's folder is ``<out>/runs/...-<hash of its config>``: finished runs are skipped,
interrupted ones resume from their checkpoint, so killing the sweep at any moment and
rerunning the same command ends with the same tables. When the grid is done the report
(``maniskill_dualher.report``) rebuilds the tables, plots and summary.md in ``<out>``.
"""
from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

from maniskill_dualher import protocol, rundir
from maniskill_dualher.config import ConfigError, ReplayConfig, RunConfig, SACConfig, field_docs, parse_ratio
from maniskill_dualher.cli import OneLineParser
from maniskill_dualher.methods import METHOD_SPECS, method_spec
from maniskill_dualher.paper import PAPER_RATIOS
from maniskill_dualher.rundir import RUNS_DIR, SWEEP



# read from the registry at call time, so a method registered later (a plugin, a test) takes part
def _methods() -> Tuple[str, ...]:
    return tuple(METHOD_SPECS)


def _transfer_methods() -> Tuple[str, ...]:   # paper Fig. 5 / Table 5, and the scratch control
    return tuple(m for m, s in METHOD_SPECS.items() if s.transfer)


def _ratio_methods() -> Tuple[str, ...]:      # paper Table 4
    return tuple(m for m, s in METHOD_SPECS.items() if s.sampling_ratio)
EXPERIMENTS = ("single", "transfer", "ratios", "scratch")


# =========================================================================== BUDGETS: one place per preset
@dataclass
class Budget:
    """Every number a preset sets (steps are environment steps). Edit here to tune a preset."""
    single_steps: Dict[str, int]        # single-task run, per task (paper Fig. 4)
    stage_steps: Dict[str, int]         # a transfer *source* stage, per task
    adaptation_steps: Dict[str, int]    # the chain's last (target) stage, per task (paper: 120 vs 200 epochs)
    seeds: Tuple[int, ...]              # single-task experiment (paper Fig. 4)
    eval_every: int                     # env steps between evaluations
    eval_episodes: int
    checkpoint_every: int               # env steps between checkpoints (resume granularity)
    max_episode_steps: Optional[int]    # None: the task's default (150, paper Table 3)
    hidden: Tuple[int, ...]             # SAC hidden layers (not in the paper)
    batch_size: int
    random_steps: int                   # uniform random actions first (paper: 100k), every stage
    learning_starts: int
    capacity: int                       # replay capacity (paper: 1e7)
    updates_per_step: float = 1.0
    sac_variant: str = "paper"          # "paper" (V network, fixed alpha) or "modern" (no V, learned alpha)
    lr: float = 1e-4                    # paper Table 3
    gamma: float = 0.99                 # paper Table 3
    sim_backend: str = "physx_cpu"      # "physx_cuda" + num_envs > 1 for GPU simulation (paper preset on a GPU)
    num_envs: int = 1                   # parallel envs per run (CPU simulation: 1)
    tau: float = 0.005                  # Polyak rate of the target networks (not in the paper)
    terminate_on_success: bool = True   # paper 4.1: an episode ends when the task is completed
    update_schedule: str = "step"       # "step": updates_per_step per env step; "episode": Algorithm 1
    updates_per_episode: float = 1.0    # with update_schedule "episode"
    # seeds of the transfer, ratios and scratch experiments (the Table 4/5 and transfer claims);
    # None: the same as ``seeds``
    transfer_seeds: Optional[Tuple[int, ...]] = None

    def chain_seeds(self) -> Tuple[int, ...]:
        return tuple(self.seeds if self.transfer_seeds is None else self.transfer_seeds)


def _per_task(reach: int, box: int, microwave: int) -> Dict[str, int]:
    return dict(zip(protocol.TASKS, (reach, box, microwave)))


PAPER_EPOCH_STEPS = 200 * 150   # paper: an epoch is 200 episodes of 150 steps (Table 3)

PRESETS: Dict[str, Budget] = {
    # CI: the whole pipeline (every experiment, table and plot) in about a minute. Learns nothing.
    "smoke": Budget(
        single_steps=_per_task(200, 200, 200), stage_steps=_per_task(150, 150, 150),
        adaptation_steps=_per_task(150, 150, 150), seeds=(0, 1),
        eval_every=100, eval_episodes=2, checkpoint_every=50, max_episode_steps=50,
        hidden=(32, 32), batch_size=32, random_steps=100, learning_starts=100, capacity=10_000),
    # Default: the whole grid, every table and plot, on a 2-core CPU in about an hour (67 min on an AMD EPYC
    # with AVX512-BF16).
    # Episodes end on success (paper 4.1), 100 steps at most. Deviations from the paper, so that runs learn
    # within a CPU budget, measured with the train CLI (one seed, sac_her_per, episodes ending on success):
    # rl-zoo goal-task settings (modern SAC with learned alpha, 64x64, lr 1e-3, tau 0.05, gamma 0.95,
    # batch 256) solve CloseBox (1.0 eval success at 6k steps) and ReachTarget/CloseMicrowave within the
    # single-task budgets below, where the paper's SAC (V network, fixed alpha 0.005, lr 1e-4, gamma 0.99)
    # had 0/10 eval successes on ReachTarget at 20k. Seeds: 4 single-task, 6 for the transfer, ratio and
    # scratch experiments, where the paper's Table 4/5 claims and the transfer question are decided.
    "quick": Budget(
        single_steps=_per_task(10_000, 10_000, 16_000), stage_steps=_per_task(6_000, 6_000, 6_000),
        adaptation_steps=_per_task(12_000, 12_000, 12_000), seeds=(0, 1, 2, 3), transfer_seeds=(0, 1, 2, 3, 4, 5),
        eval_every=1_000, eval_episodes=10, checkpoint_every=5_000, max_episode_steps=100,
        hidden=(64, 64), batch_size=256, random_steps=1_000, learning_starts=1_000, capacity=1_000_000,
        sac_variant="modern", lr=1e-3, gamma=0.95, tau=0.05),
    # The quick preset's budgets and settings with 30 seeds for every experiment: what the quick reference's
    # observed spread says most claims need (its claims.csv: 14-52 seeds per side for all but claim h).
    # About 6.1M env steps: ~7 h on these 2 CPU cores (overnight), or --backend ray on a cluster.
    "full": Budget(
        single_steps=_per_task(10_000, 10_000, 16_000), stage_steps=_per_task(6_000, 6_000, 6_000),
        adaptation_steps=_per_task(12_000, 12_000, 12_000), seeds=tuple(range(30)),
        eval_every=1_000, eval_episodes=10, checkpoint_every=5_000, max_episode_steps=100,
        hidden=(64, 64), batch_size=256, random_steps=1_000, learning_starts=1_000, capacity=1_000_000,
        sac_variant="modern", lr=1e-3, gamma=0.95, tau=0.05),
    # The paper's budgets (section 4.2, Table 3): ReachTarget 500 epochs, CloseBox/CloseMicrowave 200,
    # adaptation 120; epoch = 200 episodes x 150 steps. For GPU simulation or a cluster (--backend ray).
    "paper": Budget(
        single_steps=_per_task(500 * PAPER_EPOCH_STEPS, 200 * PAPER_EPOCH_STEPS, 200 * PAPER_EPOCH_STEPS),
        stage_steps=_per_task(500 * PAPER_EPOCH_STEPS, 200 * PAPER_EPOCH_STEPS, 200 * PAPER_EPOCH_STEPS),
        adaptation_steps=_per_task(*(120 * PAPER_EPOCH_STEPS,) * 3), seeds=(0, 1, 2),
        eval_every=PAPER_EPOCH_STEPS, eval_episodes=10, checkpoint_every=10 * PAPER_EPOCH_STEPS,
        max_episode_steps=150, hidden=(256, 256), batch_size=256, random_steps=100_000,
        learning_starts=100_000, capacity=10_000_000, update_schedule="episode", updates_per_episode=1.0),
}
# ===========================================================================


@dataclass
class Node:
    """One run of the grid: a single-task run or one stage of a transfer chain."""
    rel: str                                   # folder relative to <out>
    cfg: RunConfig
    label: str
    parent: Optional[str] = None               # rel of the stage this one starts from
    stages: Optional[List[RunConfig]] = None   # the chain (stage nodes only)
    stage: Optional[int] = None
    carry_replay: bool = False
    descendants: int = 0                       # scheduling priority: long chains first

    def payload(self, out: Path) -> dict:
        """A plain dict a worker (process or Ray) can run without the grid."""
        p = {"rel": self.rel, "out": str(out / self.rel), "cfg": self.cfg.to_dict()}
        if self.stages is not None:
            p.update(stages=[s.to_dict() for s in self.stages], stage=self.stage,
                     chain_dir=str((out / self.rel).parent), carry_replay=self.carry_replay)
        return p


# --------------------------------------------------------------------------- grid
def base_config(b: Budget, method: str, seed: int) -> RunConfig:
    return RunConfig(
        method=method, seed=seed, max_episode_steps=b.max_episode_steps, eval_every=b.eval_every,
        eval_episodes=b.eval_episodes, checkpoint_every=b.checkpoint_every, torch_threads=1,
        sim_backend=b.sim_backend, num_envs=b.num_envs, terminate_on_success=b.terminate_on_success,
        sac=SACConfig(hidden=tuple(b.hidden), batch_size=b.batch_size, random_steps=b.random_steps,
                      learning_starts=b.learning_starts, updates_per_step=b.updates_per_step,
                      update_schedule=b.update_schedule, updates_per_episode=b.updates_per_episode,
                      variant=b.sac_variant, lr=b.lr, gamma=b.gamma, tau=b.tau),
        replay=ReplayConfig(capacity=b.capacity, her_k=protocol.HER_K_SINGLE))


def build_grid(d: dict) -> List[Node]:
    """Every run of a sweep definition, deduplicated by folder (the ratio study reuses transfer's chain)."""
    b = Budget(**d["budget"])
    nodes: Dict[str, Node] = {}

    def add(n: Node) -> None:
        nodes.setdefault(n.rel, n)

    if "single" in d["experiments"]:
        for task in d["tasks"]:
            for method in d["methods"]:
                for seed in d["seeds"]:
                    cfg = base_config(b, method, seed)
                    cfg.env_id, cfg.total_steps = task, b.single_steps[task]
                    cfg.validate()
                    rel = f"{RUNS_DIR}/single/{task}-{method}-s{seed}-{protocol.short_hash(cfg.to_dict())}"
                    add(Node(rel, cfg, f"single {task} {method} seed {seed}"))

    order = d["task_order"]
    steps = [b.stage_steps[t] for t in order[:-1]] + [b.adaptation_steps[order[-1]]]
    chains = []  # (experiment folder, method, adaptation ratio, task order, step budgets)
    transfer_methods = [m for m in d["methods"] if m in _transfer_methods()]
    if "transfer" in d["experiments"]:
        chains += [("transfer", m, None, order, steps) for m in transfer_methods]
    if "ratios" in d["experiments"]:
        chains += [("transfer", m, tuple(r), order, steps) for m in d["methods"] if m in _ratio_methods()
                   for r in d["ratios"]]
    if "scratch" in d["experiments"]:  # the control: the target task from scratch, adaptation budget and settings
        chains += [("scratch", m, None, order[-1:], steps[-1:]) for m in transfer_methods]
    seeds = d.get("chain_seeds", d["seeds"])
    for kind, method, ratio, chain_order, chain_steps in chains:
        for seed in seeds:
            stages = protocol.make_stages(base_config(b, method, seed), chain_order, chain_steps,
                                          adaptation_ratio=ratio)
            protocol.validate_chain(stages)
            chain_rel = f"{RUNS_DIR}/{kind}/{method}-s{seed}"
            parent = None
            for i, cfg in enumerate(stages):
                rel = f"{chain_rel}/{protocol.stage_dirname(stages, i, d['carry_replay'])}"
                variant = method_spec(method).tag(cfg)
                tag = f" ratio {variant}" if variant else ""
                add(Node(rel, cfg, f"{kind} {method}{tag} seed {seed} stage {i} {cfg.env_id}", parent=parent,
                         stages=stages, stage=i, carry_replay=d["carry_replay"]))
                parent = rel
    for n in nodes.values():  # priority = how many runs wait on this one
        p = n.parent
        while p is not None:
            nodes[p].descendants += 1
            p = nodes[p].parent
    return list(nodes.values())


# --------------------------------------------------------------------------- CLI parsing
def _split(text: str) -> List[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


def parse_seeds(text: str) -> Tuple[int, ...]:
    """'3' -> (0, 1, 2) (a count); '0,4,7' or '7,' -> those seeds."""
    try:
        seeds = tuple(int(s) for s in _split(text))
    except ValueError:
        raise ConfigError(f"--seeds must be a count (3) or a list (0,1,2), got {text!r}") from None
    bad = [s for s in seeds if s < 0]
    if bad:
        raise ConfigError(f"seed must be >= 0, got {bad[0]}")
    if "," not in text and seeds:  # a count
        if seeds[0] == 0:
            raise ConfigError("--seeds count must be >= 1, got 0")
        return tuple(range(seeds[0]))
    if not seeds or len(set(seeds)) != len(seeds):
        raise ConfigError(f"--seeds must list distinct seeds, got {text!r}")
    return seeds


def _pick(text: str, allowed: Sequence[str], what: str) -> List[str]:
    items = _split(text)
    for x in items:
        if x not in allowed:
            raise ConfigError(f"unknown {what} {x!r} (choose from {', '.join(allowed)})")
    if not items:
        raise ConfigError(f"no {what} given")
    return items


def _apply_budget_override(b: Budget, item: str) -> None:
    """KEY=VALUE on a Budget field; dict fields take KEY.TASK=VALUE (e.g. single_steps.CloseBox-v1=5000)."""
    if "=" not in item:
        raise ConfigError(f"--budget wants KEY=VALUE, got {item!r}")
    key, val = (s.strip() for s in item.split("=", 1))
    name, _, sub = key.partition(".")
    fields = {f.name: f for f in dataclasses.fields(Budget)}
    if name not in fields or name in ("seeds", "transfer_seeds"):
        choices = ", ".join(f for f in fields if f not in ("seeds", "transfer_seeds"))
        raise ConfigError(f"unknown budget key {name!r} (choose from {choices}; seeds via --seeds, "
                          f"--transfer-seeds)")
    cur = getattr(b, name)
    try:
        if isinstance(cur, dict):
            if sub not in cur:
                raise ConfigError(f"--budget {name} needs a task, e.g. {name}.{protocol.TASKS[0]}={val}")
            cur[sub] = int(val)
        elif name == "hidden":
            setattr(b, name, tuple(int(x) for x in _split(val)))
        elif name == "max_episode_steps":
            setattr(b, name, None if val.lower() == "none" else int(val))
        elif name in ("updates_per_step", "updates_per_episode", "tau", "lr", "gamma"):
            setattr(b, name, float(val))
        elif name in ("sim_backend", "update_schedule", "sac_variant"):
            setattr(b, name, val)
        elif name == "terminate_on_success":
            if val.lower() not in ("true", "false", "1", "0"):
                raise ValueError(val)
            setattr(b, name, val.lower() in ("true", "1"))
        else:
            setattr(b, name, int(float(val)))
    except ValueError:
        raise ConfigError(f"bad value for budget {key!r}: {val!r}") from None


def _check_budget(b: Budget) -> None:
    """Budget-only rules here; every setting it passes on is validated once, by RunConfig.validate."""
    for name in ("single_steps", "stage_steps", "adaptation_steps"):
        for t, v in getattr(b, name).items():
            if v <= 0:
                raise ConfigError(f"budget {name}.{t} must be > 0, got {v}")
    if min(b.random_steps, b.learning_starts) < 0:
        raise ConfigError("budget random_steps/learning_starts must be >= 0")
    cfg = base_config(b, next(iter(METHOD_SPECS)), 0)
    cfg.env_id = protocol.TASKS[0]
    try:
        cfg.validate()
    except ConfigError as e:
        raise ConfigError(f"budget: {e}") from None


def definition_from_args(a: argparse.Namespace) -> dict:
    """The sweep's definition (what sweep.json holds): everything that decides which runs exist."""
    b = copy.deepcopy(PRESETS[a.preset])
    if a.steps is not None:
        for t in protocol.TASKS:
            b.single_steps[t] = b.stage_steps[t] = a.steps
            b.adaptation_steps[t] = max(1, round(a.steps * 120 / 200))  # paper: adaptation 120 vs 200 epochs
    if a.adapt_steps is not None:
        b.adaptation_steps = {t: a.adapt_steps for t in protocol.TASKS}
    for item in a.budget or []:
        _apply_budget_override(b, item)
    if a.seeds is not None:
        b.seeds = parse_seeds(a.seeds)
        b.transfer_seeds = None
    if a.transfer_seeds is not None:
        b.transfer_seeds = parse_seeds(a.transfer_seeds)
    _check_budget(b)
    order = _pick(a.task_order, protocol.TASKS, "task")
    if len(set(order)) != len(order):
        raise ConfigError(f"--task-order repeats a task: {a.task_order!r}")
    ratios = [parse_ratio(r) for r in _split(a.ratios)] if a.ratios else [tuple(r) for r in PAPER_RATIOS]
    if not ratios:
        raise ConfigError("no ratio given")
    d = {
        "version": 1,
        "preset": a.preset,
        "experiments": _pick(a.experiments, EXPERIMENTS, "experiment"),
        "tasks": _pick(a.tasks, protocol.TASKS, "task") if a.tasks else list(protocol.TASKS),
        "methods": _pick(a.methods, _methods(), "method") if a.methods else list(_methods()),
        "seeds": list(b.seeds),
        "chain_seeds": list(b.chain_seeds()),
        "ratios": [list(r) for r in ratios],
        "task_order": order,
        "carry_replay": not a.no_carry_replay,
        "budget": {**dataclasses.asdict(b), "seeds": list(b.seeds), "hidden": list(b.hidden),
                   "transfer_seeds": None if b.transfer_seeds is None else list(b.transfer_seeds)},
    }
    if "ratios" in d["experiments"] and not set(d["methods"]) & set(_ratio_methods()):
        raise ConfigError(f"experiment 'ratios' needs method {' or '.join(_ratio_methods())} (it varies the R/E ratio)")
    for exp in ("transfer", "scratch"):
        if exp in d["experiments"] and not set(d["methods"]) & set(_transfer_methods()):
            raise ConfigError(f"experiment {exp!r} needs method {' or '.join(_transfer_methods())}")
    return d


def check_out_folder(out: Path, d: dict, force: bool) -> None:
    """Refuse an out folder that holds another sweep (or foreign runs) unless --force."""
    if out.exists() and not out.is_dir():
        raise ConfigError(f"--out {out} exists and is not a folder")
    f = out / SWEEP
    if f.is_file():
        try:
            old = json.loads(f.read_text())
        except (OSError, ValueError):
            old = {}
        if old != d and not force:
            diff = sorted(k for k in set(old) | set(d) if old.get(k) != d.get(k))
            raise ConfigError(f"{out} holds a different sweep (differs in: {', '.join(diff)}); "
                              f"use another --out, or --force to make this one current")
        return
    ours = set(d["runs"])
    foreign = [str(p.parent.relative_to(out)) for p in sorted((out / RUNS_DIR).rglob(rundir.CONFIG))
               if str(p.parent.relative_to(out)) not in ours] if (out / RUNS_DIR).is_dir() else []
    if foreign and not force:
        raise ConfigError(f"{out} holds {len(foreign)} runs of a different config (e.g. {foreign[0]}); "
                          f"use another --out, or --force")


def budget_docs() -> Dict[str, str]:
    """Each Budget key's doc: the doc of the config field it sets, else its own comment."""
    cfg_docs = {**field_docs(RunConfig), **field_docs(ReplayConfig), **field_docs(SACConfig)}
    out = {}
    for k, v in field_docs(Budget).items():
        same = cfg_docs.get({"sac_variant": "variant"}.get(k, k), "")
        out[k] = same or v
    return out


def make_parser() -> argparse.ArgumentParser:
    budgets = "\n".join(
        f"  {name:6s} seeds {list(b.seeds)}; steps single {sorted(set(b.single_steps.values()))}, "
        f"source stage {sorted(set(b.stage_steps.values()))}, adaptation {sorted(set(b.adaptation_steps.values()))}; "
        f"eval every {b.eval_every} x {b.eval_episodes} episodes; hidden {list(b.hidden)}"
        for name, b in PRESETS.items())
    p = OneLineParser(
        prog="python -m maniskill_dualher.sweep",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Run the paper's experiments (Beyene & Han 2022) and build its tables and plots.\n\n"
            "experiments:\n"
            f"  single    each task x methods {', '.join(_methods())} (paper Fig. 4)\n"
            f"  transfer  ReachTarget -> CloseBox -> CloseMicrowave for {', '.join(_transfer_methods())}; each stage\n"
            "            starts from the previous stage's networks and replay; HER k=8 (paper Fig. 5, Table 5)\n"
            f"  ratios    {', '.join(_ratio_methods())} transfer with R/E sampling ratios 0.5/0.5, 0.6/0.4, 0.7/0.3 in the\n"
            "            adaptation stage (paper Table 4); shares the source stages, and the 0.6/0.4 chain, with 'transfer'\n"
            "  scratch   the control: the chain's last task trained from scratch with the adaptation stage's budget\n"
            "            and settings, for each transfer method (does pretraining help?)\n\n"
            "Runs are folders <out>/runs/...-<config hash>: finished ones are skipped, interrupted ones resume\n"
            "from their checkpoint, so rerunning a killed sweep finishes it with the same results. The sweep's\n"
            "definition is kept in <out>/sweep.json; an <out> holding a different sweep is refused (exit 2)\n"
            "unless --force, which makes the new definition current (old run folders stay, the report ignores them).\n"
            "When the grid is done, the report writes the tables (CSV), plots (PNG) and summary.md into <out>."),
        epilog=("presets (budgets live in PRESETS in maniskill_dualher/sweep.py):\n" + budgets + "\n\n"
                "budget keys (--budget KEY=VALUE; dict keys per task, e.g. single_steps.CloseBox-v1=5000):\n"
                + "\n".join(f"  {k:22s} {v}" for k, v in budget_docs().items()
                            if k not in ("seeds", "transfer_seeds")) + "\n\n"
                "examples:\n"
                "  python -m maniskill_dualher.sweep --preset smoke --out /tmp/smoke\n"
                "  python -m maniskill_dualher.sweep --experiments single --tasks CloseBox-v1 --seeds 5\n"
                "  python -m maniskill_dualher.sweep --preset paper --backend ray --ray-address auto --workers 64\n"
                "  python -m maniskill_dualher.report results/quick      # rebuild tables/plots only"),
    )
    p.add_argument("--preset", choices=sorted(PRESETS), default="quick", help="budget preset (default: quick)")
    p.add_argument("--experiments", default=",".join(EXPERIMENTS),
                   help=f"comma list of {', '.join(EXPERIMENTS)} (default: all)")
    p.add_argument("--tasks", help=f"tasks of the single-task experiment (default: all: {','.join(protocol.TASKS)})")
    p.add_argument("--methods", help=f"comma list of {', '.join(_methods())} (default: all; transfer uses "
                                      f"{' and '.join(_transfer_methods())} among them)")
    p.add_argument("--seeds", help="a count (3 -> seeds 0,1,2) or a list (0,4,7; one seed: '7,') for every "
                                   "experiment; default: the preset's")
    p.add_argument("--transfer-seeds", help="seeds of the transfer, ratios and scratch experiments only "
                                            "(same syntax as --seeds); default: the preset's")
    p.add_argument("--ratios", help="dual buffer P(R)/P(E) ratios of the ratios experiment, e.g. 0.5/0.5,0.7/0.3 "
                                    "(default: the paper's 0.5/0.5,0.6/0.4,0.7/0.3)")
    p.add_argument("--task-order", default=",".join(protocol.TRANSFER_ORDER),
                   help="the transfer chain; the last task is the adaptation target (default: %(default)s)")
    p.add_argument("--steps", type=int, help="env steps of every single-task run and source stage "
                                             "(adaptation stage: 120/200 of it, as in the paper)")
    p.add_argument("--adapt-steps", type=int, help="env steps of the adaptation (last) stage")
    p.add_argument("--budget", action="append", metavar="KEY=VALUE",
                   help="override one preset budget, e.g. eval_every=500, hidden=64,64, "
                        "single_steps.CloseBox-v1=5000 (repeatable)")
    p.add_argument("--no-carry-replay", action="store_true",
                   help="transfer networks only; each stage starts with empty replay buffers")
    p.add_argument("--out", help="output folder (default: runs/<preset>, ignored by git; the committed reference "
                                 "result lives in results/ and a default run never writes there)")
    p.add_argument("--workers", type=int, help="runs in parallel (default: min(2, CPU count); with --ray-address: "
                                               "the cluster's CPUs)")
    p.add_argument("--backend", choices=("local", "ray", "inline"), default="local",
                   help="local process pool, Ray, or inline (one run at a time in this process: debugging, "
                        "methods registered at run time); same results either way")
    p.add_argument("--ray-address", help="join this Ray cluster (e.g. auto, ray://host:10001); "
                                         "without it --backend ray starts a local Ray instance. "
                                         "The cluster must see --out on a shared filesystem")
    p.add_argument("--force", action="store_true", help="use an --out that holds a different sweep")
    p.add_argument("--dry-run", action="store_true", help="print the runs and exit; write nothing")
    p.add_argument("--no-report", action="store_true", help="skip building the report at the end")
    return p


# --------------------------------------------------------------------------- execution
def _worker_init(parent_pid: int) -> None:
    """Pool worker start: one torch thread (deterministic, polite); die with the sweep process."""
    try:
        import ctypes
        import signal
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
    except Exception:  # not Linux: orphans finish their run, resume stays correct
        pass
    if os.getppid() != parent_pid:
        os._exit(1)
    import torch
    torch.set_num_threads(1)


def execute(payload: dict) -> dict:
    """Run one grid node (in a worker) and return its final metrics row."""
    import torch
    torch.set_num_threads(1)
    cfg = RunConfig.from_dict(payload["cfg"])
    if "stages" in payload:
        stages = [RunConfig.from_dict(s) for s in payload["stages"]]
        row = protocol.run_stage(stages, payload["stage"], payload["chain_dir"], payload["carry_replay"],
                                 show_progress=False)
    else:
        from maniskill_dualher.train import run_training
        row = run_training(cfg, payload["out"], show_progress=False)
    return {"rel": payload["rel"], "row": dict(row)}


class LocalBackend:
    """A spawn-context process pool (fork is unsafe beside torch/SAPIEN threads)."""

    def __init__(self, workers: int):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        os.environ.setdefault("MKL_NUM_THREADS", "1")
        self.pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                        initializer=_worker_init, initargs=(os.getpid(),))
        self.capacity = workers

    def submit(self, payload):
        return self.pool.submit(execute, payload)

    def wait(self, handles):
        from concurrent.futures import FIRST_COMPLETED, wait
        return list(wait(handles, return_when=FIRST_COMPLETED).done)

    @staticmethod
    def result(h):
        return h.result()

    def close(self, cancel: bool = False):
        self.pool.shutdown(wait=not cancel, cancel_futures=cancel)


class InlineBackend:
    """Runs each submitted node at once in this process (no pool): for debugging and run-time plugins."""

    capacity = 1

    class _Handle:  # hashable: run_grid keys its in-flight runs by handle
        def __init__(self, value=None, error=None):
            self.value, self.error = value, error

    def submit(self, payload):
        try:
            return self._Handle(value=execute(payload))
        except Exception as e:  # reported by run_grid like a worker's failure
            return self._Handle(error=e)

    def wait(self, handles):
        return list(handles)[:1]

    @staticmethod
    def result(h):
        if h.error is not None:
            raise h.error
        return h.value

    def close(self, cancel: bool = False):
        pass


class RayBackend:
    """Ray tasks (one CPU each); without an address a local instance is started and stopped."""

    def __init__(self, workers: Optional[int], address: Optional[str]):
        import ray
        self.ray = ray
        env = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
        repo = str(Path(__file__).resolve().parents[1])
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [repo, os.environ.get("PYTHONPATH")]))
        kw = dict(runtime_env={"env_vars": env}, log_to_driver=False, logging_level="ERROR")
        if address:
            ray.init(address=address, **kw)
        else:
            # "local": always a fresh instance, never someone's `ray start` cluster on this machine
            ray.init(address="local", num_cpus=workers, include_dashboard=False, **kw)
        self.capacity = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        self.fn = ray.remote(num_cpus=1, max_retries=0)(execute)

    def submit(self, payload):
        return self.fn.remote(payload)

    def wait(self, handles):
        ready, _ = self.ray.wait(list(handles), num_returns=1)
        return ready

    def result(self, h):
        try:
            return self.ray.get(h)
        except self.ray.exceptions.RayTaskError as e:  # surface the run's own exception
            raise e.as_instanceof_cause() from None

    def close(self, cancel: bool = False):
        self.ray.shutdown()


def headline(row: dict) -> str:
    def num(k, fmt):
        try:
            return format(float(row[k]), fmt)
        except (KeyError, TypeError, ValueError):
            return "?"
    return (f"final eval success {num('eval_success_rate', '.2f')}, "
            f"successful training episodes {num('train_successes', '.0f')}")


def run_grid(nodes: List[Node], out: Path, backend, progress: bool = True) -> List[str]:
    """Run every unfinished node, parents before children, long chains first; return failures."""
    from tqdm import tqdm

    by_rel = {n.rel: n for n in nodes}
    done = {n.rel for n in nodes if rundir.is_done(out / n.rel)}
    todo = [n for n in nodes if n.rel not in done]
    failed: List[str] = []
    in_flight: Dict[object, Node] = {}
    total = sum(n.cfg.total_steps for n in nodes)
    # progress in env steps (finished runs count whole), so the ETA is one of work, not of run count
    bar = tqdm(total=total, initial=sum(by_rel[r].cfg.total_steps for r in done), desc="sweep", unit="step",
               unit_scale=True, disable=not progress, dynamic_ncols=True, smoothing=0.05)
    if done:
        bar.write(f"{len(done)} of {len(nodes)} runs already finished: skipped")
    try:
        while todo or in_flight:
            ready = [n for n in todo if n.parent is None or n.parent in done]
            ready.sort(key=lambda n: -n.descendants)  # stable: grid order among equals
            for n in ready[: max(0, backend.capacity - len(in_flight))]:
                in_flight[backend.submit(n.payload(out))] = n
                todo.remove(n)
            if not in_flight:
                break  # the rest waits on failed runs
            for h in backend.wait(list(in_flight)):
                n = in_flight.pop(h)
                try:
                    res = backend.result(h)
                except Exception as e:  # one failed run must not stop the others
                    failed.append(n.rel)
                    msg = str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__
                    bar.write(f"FAILED {n.label} ({n.rel}): {type(e).__name__}: {msg}")
                    continue
                done.add(n.rel)
                bar.update(n.cfg.total_steps)
                bar.set_postfix(runs=f"{len(done)}/{len(nodes)}")
                bar.write(f"done {n.label}: {headline(res['row'])}")
        blocked = [n.rel for n in todo]
        if blocked:
            bar.write(f"{len(blocked)} runs not started: they start from a failed run")
    finally:
        bar.close()
    return failed + blocked


def main(argv: Optional[Sequence[str]] = None) -> int:
    parser = make_parser()
    a = parser.parse_args(argv)
    try:  # validate everything before writing anything
        d = definition_from_args(a)
        nodes = build_grid(d)
        d["runs"] = sorted(n.rel for n in nodes)
        out = Path(a.out if a.out else Path(RUNS_DIR) / a.preset)
        if a.workers is not None and a.workers < 1:
            raise ConfigError(f"--workers must be >= 1, got {a.workers}")
        if a.ray_address and a.backend != "ray":
            raise ConfigError("--ray-address needs --backend ray")
        if a.backend == "ray":
            try:
                import ray  # noqa: F401
            except ImportError:
                raise ConfigError("--backend ray needs Ray: pip install 'ray[default]'") from None
        check_out_folder(out, d, a.force)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    workers = a.workers or (None if a.ray_address else min(2, os.cpu_count() or 1))
    todo_cfgs = [n.cfg for n in nodes if not rundir.is_done(out / n.rel)]
    if a.dry_run:
        for n in nodes:
            state = "done" if rundir.is_done(out / n.rel) else "todo"
            print(f"{state}  {n.rel}")
        if todo_cfgs:
            from maniskill_dualher.cost import describe, grid_cost
            for line in describe(grid_cost(todo_cfgs), workers or 1):
                print(line)
        total = sum(c.total_steps for c in todo_cfgs)
        print(f"{len(nodes)} runs; {total} env steps to go; nothing written (--dry-run)")
        return 0

    rundir.write_json(out / SWEEP, d)
    print(f"sweep {a.preset}: {len(nodes)} runs in {out} on {a.backend} backend", flush=True)
    if todo_cfgs:
        from maniskill_dualher.cost import describe, grid_cost
        for line in describe(grid_cost(todo_cfgs), workers or 1):
            print(line, flush=True)
    backend = {"local": lambda: LocalBackend(workers), "inline": InlineBackend,
               "ray": lambda: RayBackend(workers, a.ray_address)}[a.backend]()
    cancel = True
    try:
        failed = run_grid(nodes, out, backend)
        cancel = False
    except KeyboardInterrupt:
        print("interrupted: rerun the same command to resume", file=sys.stderr)
        return 130
    finally:
        backend.close(cancel=cancel)
    if not a.no_report:
        from maniskill_dualher.report import build_report
        written = build_report(out)
        print(f"report: {len(written)} files in {out} (summary: {out / 'summary.md'})")
    if failed:
        print(f"error: {len(failed)} runs did not finish (first: {failed[0]}); rerun to retry", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
