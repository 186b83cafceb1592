"""From a sweep definition (``sweep.json``) to run folders: one Node per run, each with its cells.

A run's config is built in one order, so what wins is predictable:

1. the preset's settings (``presets.py``), then the experiment kind's (HER k = 8 in chains);
2. its step budget (per task and role: single, source stage, adaptation stage);
3. the sweep's ``--set`` settings (every run, or per stage: ``adapt.sac.lr=3e-4``);
4. the arm's settings.

Folders are named by identity: ``runs/single/<task>-<method>-s<seed>-<hash of config>`` and
``runs/chain/<method>-s<seed>/stage<i>-<task>[-r<ratio>]-<hash of stages 0..i>``; equal runs get equal
folders and are run once, whichever experiments and arms ask for them. Each node carries the list of
cells (experiment, arm, task, chain, method, variant, seed, stage, role, parent) that the sweep writes
into the folder's ``cell.json``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

from ..config import RunConfig
from ..methods import method_spec
from ..rundir import RUNS_DIR
from . import overrides, protocol
from .presets import HER_K_MULTITASK, Preset, cell_key
from .registry import Arm, Experiment, chain_name, experiment


@dataclass
class Node:
    """One run of the grid: a single-task run or one stage of a chain."""
    rel: str                                   # folder relative to <out>
    cfg: RunConfig
    label: str
    parent: Optional[str] = None               # rel of the stage this one starts from
    stages: Optional[List[RunConfig]] = None   # the chain (stage nodes only)
    stage: Optional[int] = None
    carry_replay: bool = False
    cells: List[dict] = field(default_factory=list)
    descendants: int = 0                       # scheduling priority: long chains first

    def payload(self, out: Path) -> dict:
        """A plain dict a worker (process or Ray) can run without the grid."""
        p = {"rel": self.rel, "out": str(out / self.rel), "cfg": self.cfg.to_dict(), "label": self.label}
        if self.stages is not None:
            p.update(stages=[s.to_dict() for s in self.stages], stage=self.stage,
                     chain_dir=str((out / self.rel).parent), carry_replay=self.carry_replay)
        return p


def selected_arms(d: dict):
    """(experiment, arm) of every arm the definition selects (``NAME:ARM+ARM`` selects some arms)."""
    for item in d["experiments"]:
        exp_name, _, only = item.partition(":")
        exp = experiment(exp_name)
        for arm in exp.arms:
            if not only or arm.name in only.split("+"):
                yield exp, arm


def _asked_seeds(d: dict, exp: Experiment) -> List[int]:
    """The seeds the definition lists for an experiment's kind: single-task runs, or chains and scratch."""
    return list(d["seeds"] if exp.kind == "single" else d["chain_seeds"])


def _seed_tasks(d: dict, exp: Experiment) -> List[str]:
    """The tasks an experiment's seeds are decided for: single-task runs per task, chains per target."""
    return list(d["tasks"] if exp.kind == "single" else d["task_order"][-1:])


def _arm_cells(d: dict, exp: Experiment, arm: Arm) -> List[Tuple[str, str]]:
    """(method, task) pairs an arm's seeds are decided for."""
    methods = [m for m in exp.arm_methods(arm) if m in d["methods"]]
    return [(m, t) for m in methods for t in _seed_tasks(d, exp)]


def seeds_for(d: dict, exp: Experiment, arm: Arm, method: str, task: str) -> List[int]:
    """The seeds one arm runs for one method and task (a chain's task: its target). The one place seeds are
    decided: the definition's seed table (``arm_seeds``: the reference preset without --seeds/--chain-seeds,
    the seeds each cell has in results/reference; none for a cell not there), else its seeds capped by
    ``Experiment.max_seeds`` / ``Arm.max_seeds``."""
    table = d.get("arm_seeds")
    if table is not None:
        return list(table.get(cell_key(exp.name, arm.name, method, task), []))
    seeds = _asked_seeds(d, exp)
    caps = [c for c in (exp.max_seeds, arm.max_seeds) if c]
    return seeds[: min(caps)] if caps else seeds


def _seed_groups(cells: Dict[Tuple[str, str], Tuple[int, ...]]) -> Dict[str, Tuple[int, ...]]:
    """An arm's seeds per (method, task) as a reader says them: one group ("") when they agree; else a method's
    where its tasks agree, then a task's where its other methods agree, else "method task"."""
    if len(set(cells.values())) <= 1:
        return {"": next(iter(cells.values()), ())}
    uniform = {m for m in dict.fromkeys(m for m, _ in cells)
               if len({s for (mm, _), s in cells.items() if mm == m}) == 1}
    rest = {k: s for k, s in cells.items() if k[0] not in uniform}

    def label(m: str, t: str) -> str:
        if m in uniform:
            return m
        return t if len({s for (_, tt), s in rest.items() if tt == t}) == 1 else f"{m} {t}"

    out: Dict[str, Tuple[int, ...]] = {}
    for (m, t), s in cells.items():
        out.setdefault(label(m, t), s)
    return out


def seed_plan(d: dict) -> List[Tuple[str, str, Tuple[int, ...], int]]:
    """Per selected arm, or per method or task where an arm's seeds differ between them: (experiment/arm, the
    method or task ("" for the whole arm), the seeds planned, seeds the definition lists for its kind)."""
    out = []
    for exp, arm in selected_arms(d):
        asked = len(_asked_seeds(d, exp))
        cells = {(m, t): tuple(seeds_for(d, exp, arm, m, t)) for m, t in _arm_cells(d, exp, arm)}
        out += [(f"{exp.name}/{arm.name}", g, s, asked) for g, s in _seed_groups(cells).items()]
    return out


def seed_span(seeds: Sequence[int]) -> str:
    """Seeds as a reader writes them: '0-15', '32-47', '0-3, 7'."""
    parts, s = [], sorted(seeds)
    for i, x in enumerate(s):
        if i and x == s[i - 1] + 1:
            parts[-1][1] = x
        else:
            parts.append([x, x])
    return ", ".join(f"{a}" if a == b else f"{a}-{b}" for a, b in parts)


def capped_arms(d: dict) -> List[Tuple[str, int, int]]:
    """The selected arms (or an arm's method/task) that run fewer seeds than the definition asks for their
    kind: (experiment/arm[ method/task], seeds run, seeds asked)."""
    return [(arm + (f" {g}" if g else ""), len(s), asked) for arm, g, s, asked in seed_plan(d) if len(s) < asked]


def job_for(payload: dict, check_parent: bool = True) -> dict:
    """A node's payload -> its run's arguments (``train.Job``'s fields; a chain stage's folder, parent and
    replay flags and its stage.json from ``protocol.stage_job``). The local, Ray and SLURM (command line)
    paths all take a run from here. ``check_parent=False``: the parent runs later (a command list)."""
    if "stages" in payload:
        stages = [RunConfig.from_dict(s) for s in payload["stages"]]
        return protocol.stage_job(stages, payload["stage"], payload["chain_dir"], payload["carry_replay"],
                                  check_parent=check_parent)
    return dict(cfg=RunConfig.from_dict(payload["cfg"]), out=payload["out"], init_from=None,
                carry_replay=False, keep_replay=False)


def preset_from_definition(d: dict) -> Preset:
    b = d["budgets"]
    return Preset("", single_steps=b["single"], stage_steps=b["source"], adaptation_steps=b["adapt"],
                  seeds=tuple(d["seeds"]), chain_seeds=tuple(d["chain_seeds"]),
                  settings=tuple(d["preset_settings"]), default_steps=b.get("default"))


def chain_configs(p: Preset, exp: Experiment, arm_settings, user, method: str, seed: int,
                  order: Sequence[str], adapt_factor: float = 1.0,
                  prior_method: Optional[str] = None) -> List[RunConfig]:
    """The stage configs of one chain (scratch: a one-stage chain on the last task); with ``prior_method``
    the source stages are that method's (a prior shared by every method that adapts from it)."""
    tasks = list(order) if exp.kind == "chain" else list(order[-1:])
    n = len(tasks)
    stages = []
    for i, task in enumerate(tasks):
        cfg = p.base_config(prior_method if prior_method and i < n - 1 else method, seed)
        cfg.env_id = task
        cfg.replay.her_k = HER_K_MULTITASK
        cfg.total_steps = p.steps("source", task) if i < n - 1 else max(1, round(p.steps("adapt", task) * adapt_factor))
        cfg = overrides.apply(cfg, tuple(user) + tuple(arm_settings), stage=i, n_stages=n)
        stages.append(cfg.validate())
    return stages


def _seed_order(per_task: Dict[str, List[int]]):
    """Seeds in the order the definition lists them (a --seeds list need not be sorted)."""
    order = {s: i for seeds in per_task.values() for i, s in enumerate(seeds)}
    return lambda s: (order[s], s)


def build_grid(d: dict) -> List[Node]:
    """Every run of a sweep definition, deduplicated by folder, each with the cells it serves."""
    p = preset_from_definition(d)
    user = overrides.parse_all(d.get("settings", []))
    nodes: Dict[str, Node] = {}

    def add(n: Node, cell: dict) -> None:
        node = nodes.setdefault(n.rel, n)
        node.cells.append(cell)

    for item in d["experiments"]:
        exp_name, _, only = item.partition(":")   # "e_share:paper+e_off": some of its arms
        exp = experiment(exp_name)
        for arm in exp.arms:
            if only and arm.name not in only.split("+"):
                continue
            settings = overrides.parse_all(arm.settings)
            for method in [m for m in exp.arm_methods(arm) if m in d["methods"]]:
                per_task = {t: seeds_for(d, exp, arm, method, t) for t in _seed_tasks(d, exp)}
                for seed in sorted(set().union(*per_task.values()), key=_seed_order(per_task)):
                    base = {"experiment": exp.name, "arm": arm.name, "method": method, "seed": seed}
                    if exp.kind == "single":
                        for task in [t for t in d["tasks"] if seed in per_task[t]]:
                            cfg = p.base_config(method, seed)
                            cfg.env_id, cfg.total_steps = task, p.steps("single", task)
                            cfg = overrides.apply(cfg, tuple(user) + tuple(settings)).validate()
                            rel = f"{RUNS_DIR}/single/{task}-{method}-s{seed}-{protocol.short_hash(cfg.to_dict())}"
                            add(Node(rel, cfg, f"single {task} {method} seed {seed}"),
                                {**base, "task": task, "chain": "", "variant": method_spec(method).tag(cfg),
                                 "stage": 0, "n_stages": 1, "role": "single", "parent": None})
                        continue
                    stages = chain_configs(p, exp, settings, user, method, seed, d["task_order"],
                                           arm.adapt_steps_factor, arm.prior_method)
                    protocol.validate_chain(stages)
                    chain = chain_name(s.env_id for s in stages)
                    parent = None
                    for i, cfg in enumerate(stages):
                        # a chain lives under its prior's method: a shared prior's stages are that method's runs
                        rel = (f"{RUNS_DIR}/chain/{stages[0].method}-s{seed}/"
                               f"{protocol.stage_dirname(stages, i, d['carry_replay'])}")
                        variant = method_spec(cfg.method).tag(cfg)
                        role = "adapt" if i == len(stages) - 1 else "source"
                        add(Node(rel, cfg, f"{cfg.method}{' ' + variant if variant else ''} seed {seed} stage {i} "
                                           f"{cfg.env_id}", parent=parent, stages=stages, stage=i,
                                 carry_replay=d["carry_replay"]),
                            {**base, "method": cfg.method, "task": cfg.env_id, "chain": chain, "variant": variant,
                             "stage": i,
                             "n_stages": len(stages), "role": role, "parent": parent})
                        parent = rel
    for n in nodes.values():  # priority = how many runs wait on this one
        q = n.parent
        while q is not None:
            nodes[q].descendants += 1
            q = nodes[q].parent
    return list(nodes.values())
