"""The sweep: experiments x arms x methods x seeds as resumable run folders, then the report.

    python -m maniskill_dualher.sweep --preset smoke --out /tmp/smoke   # the whole pipeline in about a minute
    python -m maniskill_dualher.sweep --dry-run                         # list the runs and their cost; write nothing
    python -m maniskill_dualher.sweep --set replay.dual_mode=split --dry-run

Each run's folder is named by its config (``grid.py``): finished runs are skipped, interrupted ones resume
from their checkpoint, so killing the sweep at any moment and rerunning the same command ends with the
same tables. When the grid is done the report (``analysis/report.py``) writes scores, tables, claims,
plots and summary.md into ``--out``.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import re
import shlex
import sys
from pathlib import Path
from typing import Callable, Dict, List, Optional, Sequence, Tuple

from .. import rundir
from ..cmdline import OneLineParser, did_you_mean, missing_package, old_flag
from ..fileio import plural
from ..config import TASKS, ConfigError, read_config_file
from ..methods import METHOD_SPECS
from ..rundir import RUNS_DIR, SWEEP
from . import overrides
from .grid import Node, build_grid, capped_arms, seed_plan, seed_span, selected_arms
from .presets import PRESETS, cell_seeds, preset
from .registry import EXPERIMENTS, PAPER_CHAIN, ablation_experiments, default_experiments

DEFINITION_VERSION = 2
# runs per worker: packing is bit-identical to running alone (tests/test_pack.py) and 1.1-1.25x faster on
# 2-core CPUs (docs/speed.md); the scheduler shares ready runs evenly, so small grids get smaller packs
DEFAULT_PACK = 8


def _split(text: str) -> List[str]:
    return [t.strip() for t in text.split(",") if t.strip()]


SEED_FORMS = "'3' is a count: seeds 0,1,2; '0,4,7' lists seeds; '7,' is seed 7 alone"


def parse_seeds(text: str, flag: str = "--seeds") -> Tuple[int, ...]:
    """One meaning per form: '3' -> (0, 1, 2) (a count); '0,4,7' -> those seeds; '7,' -> (7,) (a list of one).
    Each refusal says the forms, and '0' (a count of none) how to write seed 0 alone."""
    try:
        seeds = tuple(int(s) for s in _split(text))
    except ValueError:
        raise ConfigError(f"{flag} {text!r}: not a count or a list of seeds ({SEED_FORMS})") from None
    bad = [s for s in seeds if s < 0]
    if bad:
        raise ConfigError(f"{flag} {text!r}: a seed must be >= 0, got {bad[0]} ({SEED_FORMS})")
    if "," not in text and seeds:  # a count
        if seeds[0] == 0:
            raise ConfigError(f"{flag} 0 is a count of no seeds: seed 0 alone is {flag} 0, ({SEED_FORMS})")
        return tuple(range(seeds[0]))
    if not seeds:
        raise ConfigError(f"{flag} {text!r}: no seed given ({SEED_FORMS})")
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"{flag} {text!r} lists a seed twice: list distinct seeds ({SEED_FORMS})")
    return seeds


def _pick(text: str, allowed: Sequence[str], what: str) -> List[str]:
    items = _split(text)
    for x in items:
        if x not in allowed:
            raise ConfigError(f"unknown {what} {x!r} (choose from {', '.join(allowed)}){did_you_mean(x, allowed)}")
    if not items:
        raise ConfigError(f"no {what} given")
    return items


def _default_methods(experiments: Optional[str]) -> List[str]:
    """Without --methods: the registry's default methods and those the selected experiments name (in registry
    order), so a method registered with ``default=False`` changes no other sweep's definition."""
    named = {m for x in _experiments(experiments) for m in EXPERIMENTS[x.partition(":")[0]].method_names()}
    return [m for m, s in METHOD_SPECS.items() if s.default or m in named]


def _experiments(text: Optional[str]) -> List[str]:
    """Experiment names, groups (default, ablations, all), or NAME:ARM+ARM for some of an experiment's arms."""
    if not text or text == "default":
        return list(default_experiments())
    names: List[str] = []
    for x in _split(text):
        name, _, arms = x.partition(":")
        group = {"all": list(EXPERIMENTS), "ablations": list(ablation_experiments()),
                 "default": list(default_experiments())}.get(name)
        if arms:
            exp = EXPERIMENTS[_pick(name, list(EXPERIMENTS), "experiment")[0]]
            _pick(arms.replace("+", ","), [a.name for a in exp.arms], f"arm of {name}")
            group = [x]
        for n in group or _pick(name, list(EXPERIMENTS), "experiment"):
            if n not in names:
                names.append(n)
    return names


def definition_from_args(a: argparse.Namespace) -> dict:
    """The sweep's definition (what sweep.json holds): everything that decides which runs exist."""
    p = preset(a.preset)
    order = _pick(a.task_order, TASKS, "task")
    if len(set(order)) != len(order):
        raise ConfigError(f"--task-order repeats a task: {a.task_order!r}")
    tasks = _pick(a.tasks, TASKS, "task") if a.tasks else list(PAPER_CHAIN)
    # budgets of the paper's tasks and of those this sweep uses: a task added to the catalog changes no other
    # sweep's definition (nor the reference's budgets, report.MERGE_SAME)
    used = [t for t in TASKS if t in PAPER_CHAIN or t in tasks or t in order]
    budgets = {role: {t: n for t, n in steps.items() if t in used}
               for role, steps in (("single", p.single_steps), ("source", p.stage_steps), ("adapt", p.adaptation_steps))}
    budgets["default"] = p.default_steps
    if a.source_steps is not None:
        if a.source_steps < 1:
            raise ConfigError(f"--source-steps must be >= 1, got {a.source_steps}")
        for t in used:
            budgets["single"][t] = budgets["source"][t] = a.source_steps
            budgets["adapt"][t] = max(1, round(a.source_steps * 120 / 200))  # paper: adaptation 120 vs 200 epochs
    if a.adapt_steps is not None:
        if a.adapt_steps < 1:
            raise ConfigError(f"--adapt-steps must be >= 1, got {a.adapt_steps}")
        budgets["adapt"] = {t: a.adapt_steps for t in used}
    seeds = parse_seeds(a.seeds) if a.seeds is not None else p.seeds
    chain_seeds = parse_seeds(a.chain_seeds, "--chain-seeds") if a.chain_seeds is not None else (
        seeds if a.seeds is not None else p.chain_seeds)
    given = file_settings(a.config) if a.config else []  # --config FILE's settings, then --set's
    settings = [o.text() for o in overrides.parse_all(given + list(a.set or []))]  # normalised, validated
    d = {
        "version": DEFINITION_VERSION,
        "preset": a.preset,
        "experiments": _experiments(a.experiments),
        "tasks": tasks,
        "methods": _pick(a.methods, list(METHOD_SPECS), "method") if a.methods else _default_methods(a.experiments),
        "seeds": list(seeds),
        "chain_seeds": list(chain_seeds),
        "task_order": order,
        "carry_replay": not a.no_carry_replay,
        "budgets": budgets,
        "preset_settings": list(p.settings),
        "settings": settings,
    }
    if p.seeds_from is not None and a.seeds is None and a.chain_seeds is None:
        # the seeds each selected arm's cells have in the preset's results folder (none for an arm not run
        # there); only the selected arms', so seeds added to another arm leave this definition as it was
        d["arm_seeds"] = cell_seeds(p.seeds_from, {f"{exp.name}:{arm.name}" for exp, arm in selected_arms(d)})
    for name in (x.split(":")[0] for x in d["experiments"]):
        e = EXPERIMENTS[name]
        takes = [m for m in e.method_names() if any(m in e.arm_methods(arm) for arm in e.arms)]
        if not set(takes) & set(d["methods"]):
            raise ConfigError(f"experiment {name!r} needs method {' or '.join(takes)}")
        if e.kind == "chain" and len(order) < 2:
            raise ConfigError(f"experiment {name!r} needs a chain of at least 2 tasks, got --task-order {a.task_order!r}")
    return d


PER_RUN = {"env_id": "--tasks", "method": "--methods", "seed": "--seeds", "total_steps": "the budgets (--preset, "
           "--source-steps, --adapt-steps)"}


def file_settings(path: str) -> List[str]:
    """``--config FILE`` (YAML or JSON, ``config.read_config_file``) as ``--set`` items: a RunConfig's nested
    mapping, or part of one (dotted keys too); a stage's own settings under ``adapt:``, ``source:`` or ``stageN:``.
    Keys the sweep sets per run are refused with the flag that sets them."""
    def flat(d: dict, stage: str, section: str) -> List[str]:
        out = []
        for k, v in d.items():
            k = str(k)
            if isinstance(v, dict) and not stage and not section and (k in overrides.STAGE_WORDS
                                                                      or re.fullmatch(r"stage\d+", k)):
                out += flat(v, k + ".", "")
            elif isinstance(v, dict) and not section and k in overrides.SECTIONS:
                out += flat(v, stage, k + ".")
            elif not section and k in PER_RUN:
                raise ConfigError(f"--config {path}: {stage}{k} is the sweep's to set per run ({PER_RUN[k]}), not a "
                                  f"setting of every run: remove it from the file")
            else:
                value = "none" if v is None else str(v).lower() if isinstance(v, bool) else \
                    ",".join(map(str, v)) if isinstance(v, (list, tuple)) else str(v)
                out.append(f"{stage}{section}{k}={value}")
        return out
    return flat(read_config_file(path), "", "")


# sweep.json's record of each arm's settings as its runs were built: derived from the definition (so it decides no
# run and is left out of the comparison that refuses another sweep's folder; folders from before it lack it)
ARMS_AS_RUN = "arms_as_run"


def arms_as_run(nodes: List[Node]) -> dict:
    """Per ``experiment/arm`` and role (``single``, ``source``, ``adapt``): each task's budget in env steps and the
    value, as the runs were configured, of every setting the arm names -> {"paper_regime/step": {"adapt":
    {"CloseMicrowave-v1": {"total_steps": 3600000, "sac.update_schedule": "step", ...}}}}. Where the runs of one
    arm, role and task differ in such a value (none do today) it lists each value, sorted."""
    record: Dict[str, Dict[str, Dict[str, Dict[str, list]]]] = {}
    for n in nodes:
        cfg = n.cfg.to_dict()
        for c in n.cells:
            exp = EXPERIMENTS.get(c["experiment"])
            arm = next((x for x in exp.arms if x.name == c["arm"]), None) if exp else None
            if arm is None:
                continue
            keys = ["total_steps"] + [o.path for o in overrides.parse_all(arm.settings)
                                      if o.applies_to(c.get("stage"), c.get("n_stages") or 1)]
            at = record.setdefault(f"{exp.name}/{arm.name}", {}).setdefault(c["role"], {}).setdefault(c["task"], {})
            for k in dict.fromkeys(keys):
                head, _, tail = k.partition(".")
                v = cfg[head][tail] if tail else cfg[head]
                v = overrides.format_value(tuple(v) if isinstance(v, list) else v) if k != "total_steps" else v
                if v not in at.setdefault(k, []):
                    at[k].append(v)
    return {arm: {role: {task: {k: v[0] if len(v) == 1 else sorted(v, key=str) for k, v in vals.items()}
                         for task, vals in sorted(tasks.items())} for role, tasks in sorted(roles.items())}
            for arm, roles in sorted(record.items())}


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
        old, d = ({k: v for k, v in x.items() if k != ARMS_AS_RUN} for x in (old, d))
        diff = sorted(k for k in set(old) | set(d) if old.get(k) != d.get(k))
        if diff == ["arm_seeds"] and old.get("runs") == d.get("runs"):
            return  # the reference's seeds in their older form (counts per arm, before issue 40): the same runs
        if old != d and not force:
            raise ConfigError(f"{out} holds a different sweep (differs in: {', '.join(diff)}); "
                              f"use another --out, or --force to make this one current")
        return
    ours = set(d["runs"])
    foreign = [str(p.parent.relative_to(out)) for p in sorted((out / RUNS_DIR).rglob(rundir.CONFIG))
               if str(p.parent.relative_to(out)) not in ours] if (out / RUNS_DIR).is_dir() else []
    if foreign and not force:
        raise ConfigError(f"{out} holds {plural(len(foreign), 'run')} of a different config (e.g. {foreign[0]}); "
                          f"use another --out, or --force")
    if (out / "scores.csv").is_file() and not (out / RUNS_DIR).is_dir() and not force:
        raise ConfigError(f"{out} holds a report without run folders (a committed reference?); "
                          f"use another --out")


def make_parser() -> argparse.ArgumentParser:
    presets = "\n".join(f"  {n:9s} {p.doc}" for n, p in PRESETS.items())
    exps = "\n".join(f"  {n:11s} {e.kind:7s} {e.title}" + (f" [{e.paper}]" if e.paper else "")
                     + ("" if e.default else " (ablation)") + "\n" + "".join(
                         f"              arm {a.name}: {', '.join(a.settings) or 'as the preset'}\n" for a in e.arms)
                     for n, e in EXPERIMENTS.items())
    keys = "\n".join(f"  {k:28s} {v}" for k, v in overrides.keys().items())
    p = OneLineParser(
        prog="python -m maniskill_dualher.sweep",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description=(
            "Run experiments (Beyene & Han 2022 and our ablations) and build their tables, claims and plots.\n\n"
            "Runs are folders <out>/runs/...-<config hash>: finished ones are skipped, interrupted ones resume\n"
            "from their checkpoint, and runs equal across experiments and arms are run once. The definition is\n"
            "kept in <out>/sweep.json; an <out> holding a different sweep is refused (exit 2) unless --force."),
        epilog=("presets (maniskill_dualher/experiment/presets.py):\n" + presets + "\n\n"
                "experiments (maniskill_dualher/experiment/registry.py; --experiments default|ablations|all|NAME,...):\n"
                + exps + "\n"
                "settings (--set KEY=VALUE, any RunConfig field; prefix adapt., source. or stageN. for one stage):\n"
                + keys + "\n\n"
                "examples:\n"
                "  python -m maniskill_dualher.sweep --preset smoke --out /tmp/smoke\n"
                "  python -m maniskill_dualher.sweep --experiments e_share,warm_start --dry-run\n"
                "  python -m maniskill_dualher.sweep --set adapt.sac.random_steps=0 --set sac.lr=3e-4 --dry-run\n"
                "  python -m maniskill_dualher.sweep --preset paper --backend ray --ray-address auto --workers 64\n"
                "  python -m maniskill_dualher.sweep --preset paper --emit-commands jobs.txt   # SLURM: docs/cluster.md\n"
                "  python -m maniskill_dualher.report runs/quick        # rebuild tables/plots from a sweep folder"),
    )
    p.add_argument("--preset", choices=list(PRESETS), default="quick", metavar="PRESET",
                   help=f"budget preset, one of {', '.join(PRESETS)} (listed below; default: %(default)s)")
    p.add_argument("--experiments", help="comma list of experiment names, or default (the paper's four), "
                                         "ablations, all; NAME:ARM+ARM runs some of its arms (default: default)")
    p.add_argument("--tasks", help=f"tasks of single-task experiments, of the catalog {','.join(TASKS)} (default: the "
                                   f"paper's, {','.join(PAPER_CHAIN)})")
    p.add_argument("--methods", help=f"comma list of {', '.join(METHOD_SPECS)} (default: all; each experiment "
                                     "uses those of them it is defined for)")
    p.add_argument("--seeds", help="a count or a comma list, for every experiment: '3' is a count (seeds 0,1,2); "
                                   "'0,4,7' lists seeds; one seed is a list of one, written with a trailing comma: "
                                   "'7,' is seed 7 ('7' is seeds 0-6; '0' is no seeds, refused: seed 0 alone is "
                                   "'0,'). Default: the preset's; the reference preset's "
                                   "are per arm, the seeds its cells have in results/reference/scores.csv (none for an "
                                   "arm not run there), and --seeds or --chain-seeds drops them. Costly arms are capped "
                                   "(Arm/Experiment "
                                   "max_seeds; --dry-run names them, with a seeds: line per arm): more seeds than a "
                                   "selected arm's cap are refused unless --allow-capped (then the cap applies)")
    p.add_argument("--allow-capped", action="store_true",
                   help="accept that capped arms run fewer seeds than --seeds/--chain-seeds ask")
    p.add_argument("--chain-seeds", "--transfer-seeds", dest="chain_seeds",
                   help="seeds of chain and scratch experiments only (same syntax as --seeds)")
    p.add_argument("--task-order", default=",".join(PAPER_CHAIN),
                   help="the transfer chain, tasks of the catalog (config.TASKS); the last task is the adaptation "
                        "target (default: the paper's chain, registry.PAPER_CHAIN: %(default)s)")
    p.add_argument("--source-steps", dest="source_steps", type=int, metavar="N",
                   help="env steps of every single-task run and every source (not last) stage of a chain; the "
                        "adaptation (last) stage gets 120/200 of it, as in the paper, unless --adapt-steps. "
                        "Not train's --total-steps: a chain's total is the sum of its stages")
    old_flag(p, "--steps", "the single-task and source-stage budget is --source-steps N, the adaptation's "
                           "--adapt-steps N (train's whole run: --total-steps)")
    p.add_argument("--adapt-steps", type=int, metavar="N",
                   help="env steps of the adaptation (last) stage of a chain, and of scratch runs")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="a RunConfig setting for every run, e.g. sac.lr=3e-4, or one stage: adapt.sac.random_steps=0 "
                        "(repeatable; keys below)")
    p.add_argument("--config", metavar="FILE",
                   help="settings for every run from a YAML (.yaml, .yml) or JSON file: a RunConfig's mapping or part "
                        "of one (sac: {lr: 3e-4}), a stage's under adapt:, source: or stageN:; each is a --set "
                        "before the command line's (no env_id, method, seed or total_steps: the sweep sets those)")
    p.add_argument("--no-carry-replay", action="store_true",
                   help="transfer networks only; each stage starts with empty replay buffers")
    p.add_argument("--out", help="output folder (default: runs/<preset>, ignored by git; committed results live in "
                                 "results/ and a default run never writes there)")
    p.add_argument("--workers", type=int, help="runs in parallel (default: min(2, CPU count); with --ray-address: "
                                               "the cluster's CPUs)")
    p.add_argument("--pack", type=int, default=DEFAULT_PACK, metavar="S",
                   help="train up to S runs side by side in each worker, their gradient updates batched into one "
                        "(runs with equal network and SAC settings; a run's results do not depend on its pack, bit "
                        "for bit: maniskill_dualher/pack.py; 1 = one run per worker). Default: %(default)s")
    p.add_argument("--backend", choices=("local", "ray", "inline"), default="local",
                   help="local process pool, Ray, or inline (one run at a time in this process: debugging, "
                        "methods registered at run time); same results either way")
    p.add_argument("--ray-address", help="join this Ray cluster (e.g. auto, ray://host:10001); "
                                         "without it --backend ray starts a local Ray instance. "
                                         "The cluster must see --out on a shared filesystem")
    p.add_argument("--force", action="store_true", help="use an --out that holds a different sweep")
    p.add_argument("--retries", type=int, default=2,
                   help="run again, from its last checkpoint, a run whose worker or node died (killed, out of "
                        "memory, node lost), up to this many times; a run that raises is not retried "
                        "(default: %(default)s)")
    p.add_argument("--emit-commands", metavar="FILE",
                   help="run nothing: write one `python -m maniskill_dualher.train` command per unfinished run "
                        "into FILE, parents before children (configs in FILE's folder), for a SLURM job array "
                        "or any scheduler (docs/cluster.md)")
    p.add_argument("--dry-run", action="store_true",
                   help="print the runs, their cost and --out, write nothing (any --out, read only: one another sweep "
                        "holds is named, not refused)")
    p.add_argument("--no-report", action="store_true", help="skip building the report at the end")
    p.add_argument("--status", action="store_true",
                   help="say where the sweep in --out stands (finished, in flight with its pace, failed, not started; "
                        "who holds the folder) from its files, and exit; writes nothing")
    return p


def write_cells(nodes: List[Node], out: Path) -> None:
    """Each run folder's cells (which experiments and arms it serves): the report groups by these."""
    for n in nodes:
        path = out / n.rel / rundir.CELL
        new = {"cells": n.cells}
        if rundir.read_json(path) != new:
            rundir.write_json(path, new)


def plan_sweep_memory(todo: List[Node], out: Path, backend: str, workers: Optional[int], pack: int, local: bool):
    """(each unfinished run's memory plan, the sweep's ``cost.MemoryPlan``): on this machine (a local pool, inline,
    or a Ray instance started here) the workers and runs per worker shrink to fit its available memory, and a run
    that alone does not fit is refused (ConfigError); on a Ray cluster the plan is only described."""
    from .cost import MemoryPlan, available_memory, node_memory, plan_memory
    mems = [node_memory(n, resume=(out / n.rel / rundir.CHECKPOINT).is_file()
                        or (out / n.rel / rundir.CHECKPOINT_PREV).is_file()) for n in todo]
    w = 1 if backend == "inline" else (workers or 1)
    if not local:
        from .cost import sweep_peak
        return mems, MemoryPlan(w, pack, sweep_peak(mems, w, pack), None, "a Ray cluster's nodes")
    available, source = available_memory()
    return mems, plan_memory(mems, w, pack, available, source)


def memory_lines(memory) -> List[str]:
    if memory is None:
        return []
    from .cost import describe_memory
    mems, plan = memory
    return describe_memory(mems, plan) + ([plan.note] if plan.note else [])


def main(argv: Optional[Sequence[str]] = None, train: Optional[Callable] = None,
         report: Optional[Callable] = None) -> int:
    """The sweep. ``train``: the training driver (``train.train_runs``) its workers call; ``report``: the
    report builder (``analysis.report.build_report``) run at the end. The entry point
    (``python -m maniskill_dualher.sweep``, ``maniskill_dualher/sweep.py``) hands both in, so this layer
    imports neither; without ``train`` the sweep can plan (--dry-run, --emit-commands) but not run."""
    import contextlib
    with contextlib.ExitStack() as held:  # the out folder's lock (lock.py), released however the sweep ends
        return _main(argv, held, train, report)


def _main(argv: Optional[Sequence[str]], held, train: Optional[Callable], report: Optional[Callable]) -> int:
    from .backends import InlineBackend, LocalBackend, RayBackend, SweepStopped, emit_commands, run_grid
    from .lock import FolderLock

    parser = make_parser()
    a = parser.parse_args(argv)
    if a.status:
        from .status import status_lines
        try:
            print("\n".join(status_lines(Path(a.out if a.out else Path(RUNS_DIR) / a.preset))), flush=True)
        except ConfigError as e:
            print(f"error: {e}", file=sys.stderr)
            return 2
        except BrokenPipeError:  # `--status | head -1`: the reader has what it wanted
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    try:  # validate everything before writing anything
        d = definition_from_args(a)
        capped = capped_arms(d)
        explicit = a.seeds is not None or a.chain_seeds is not None
        if capped and explicit and not a.allow_capped:
            arm, cap, asked = capped[0]
            raise ConfigError(f"{arm} runs at most {cap} seeds, {asked} asked ({len(capped)} capped arms; "
                              f"--dry-run lists them): ask for fewer, select other arms, or pass --allow-capped")
        nodes = build_grid(d)
        d["runs"] = sorted(n.rel for n in nodes)
        d[ARMS_AS_RUN] = arms_as_run(nodes)
        out = Path(a.out if a.out else Path(RUNS_DIR) / a.preset)
        if a.workers is not None and a.workers < 1:
            raise ConfigError(f"--workers must be >= 1, got {a.workers}")
        if a.ray_address and a.backend != "ray":
            raise ConfigError("--ray-address needs --backend ray")
        if a.backend == "ray":
            if importlib.util.find_spec("ray") is None:   # not imported here: RayBackend sets its mode first
                raise ConfigError("--backend ray needs Ray: pip install 'ray[default]'")
        if not (a.no_report or a.dry_run or a.emit_commands) and report is not None:  # its end, before hours
            need = missing_package("matplotlib", "the report at the end (--no-report skips it) draws its figures with")
            if need:
                raise ConfigError(need)
        if a.pack < 1:
            raise ConfigError(f"--pack must be >= 1, got {a.pack}")
        if a.retries < 0:
            raise ConfigError(f"--retries must be >= 0, got {a.retries}")
        if a.emit_commands and a.dry_run:
            raise ConfigError("--emit-commands and --dry-run: choose one")
        if train is None and not (a.dry_run or a.emit_commands):
            raise ConfigError("no training driver given: run python -m maniskill_dualher.sweep")
        workers = a.workers or (None if a.ray_address else min(2, os.cpu_count() or 1))
        todo = [n for n in nodes if not rundir.is_done(out / n.rel)]
        pack, memory = a.pack, None
        if not a.emit_commands:  # what this machine's workers hold at once: fewer per worker, or refused
            memory = plan_sweep_memory(todo, out, a.backend, workers, a.pack, local=not a.ray_address)
            pack = memory[1].pack
            if memory[1].note and a.backend != "inline":
                workers = memory[1].workers
        refused = None
        try:
            check_out_folder(out, d, a.force)
        except ConfigError as e:
            if not a.dry_run:  # a dry run reads any folder, writes nothing: it says what a run would answer
                raise
            refused = str(e)
        if not a.dry_run:  # one sweep per folder; then look again, now that no other sweep can write it
            held.enter_context(FolderLock(out))
            check_out_folder(out, d, a.force)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    todo_cfgs = [n.cfg for n in todo]
    table = d.get("arm_seeds") is not None
    of = (lambda n: f"of the preset's {n} seeds (seed table)") if table else (lambda n: f"of the {n} seeds asked")
    for arm, cap, asked in capped:  # never a silent cut
        flag = "--seeds" if EXPERIMENTS[arm.split("/")[0]].kind == "single" else "--chain-seeds"
        print(f"capped: {arm} runs {cap} {of(asked)}" + ("" if table else " (max_seeds)")
              + (f": not in {preset(a.preset).seeds_from} ({flag} {asked} runs it at the preset's {asked})"
                 if table and cap == 0 else ""))
    if a.dry_run:
        for arm, group, seeds, asked in seed_plan(d):
            line = f"seeds: {arm}{' ' + group if group else ''}: {len(seeds)}"
            if seeds:
                line += f" ({seed_span(seeds)})"
            if len(seeds) < asked:
                line += (f", capped: the preset lists {asked} [seed table]" if table
                         else f", capped: {asked} asked [max_seeds]")
            elif table:
                line += " [seed table]"
            print(line)
        for n in nodes:
            state = "done" if rundir.is_done(out / n.rel) else "todo"
            cells = sorted({f"{c['experiment']}/{c['arm']}" for c in n.cells})
            print(f"{state}  {n.rel}  [{', '.join(cells)}]")
        if todo_cfgs:
            from .cost import describe, grid_cost
            for line in describe(grid_cost(todo_cfgs, pack), workers or 1):
                print(line)
        for line in memory_lines(memory):
            print(line)
        total = sum(c.total_steps for c in todo_cfgs)
        if refused:
            print(f"note: this sweep without --dry-run would be refused: {refused}")
        print(f"{plural(len(nodes), 'run')} in --out {out}; {total} env steps to go; nothing written (--dry-run)")
        return 0

    rundir.write_json(out / SWEEP, d)
    write_cells(nodes, out)
    if a.emit_commands:
        levels = emit_commands(nodes, out, Path(a.emit_commands))
        n_cmd = sum(len(lv) for lv in levels)
        print(f"{plural(n_cmd, 'command')} in {a.emit_commands} ({plural(len(nodes) - n_cmd, 'run')} already finished); run them "
              f"level by level (a level's runs in any order, in parallel), then: python -m maniskill_dualher.report {out}")
        for i, lv in enumerate(levels):
            print(f"  level {i}: lines {lv[0]}-{lv[-1]} ({plural(len(lv), 'run')})")
        return 0
    print(f"sweep {a.preset}: {plural(len(nodes), 'run')} in {out} on {a.backend} backend"
          + (f", up to {pack} runs per worker" if pack > 1 else ""), flush=True)
    for line in memory_lines(memory):
        print(line, flush=True)
    backend = {"local": lambda: LocalBackend(workers, train), "inline": lambda: InlineBackend(train),
               "ray": lambda: RayBackend(workers, a.ray_address, train, retries=a.retries)}[a.backend]()
    cancel = True
    try:
        if todo_cfgs:
            backend.start()  # the workers import while the estimate below times an update
            from .cost import describe, grid_cost
            for line in describe(grid_cost(todo_cfgs, pack), workers or 1):
                print(line, flush=True)
        failed = run_grid(nodes, out, backend, retries=a.retries, pack=pack)
        cancel = False
    except SweepStopped as e:
        print(f"stopped by {e.signal_name}: {plural(len(e.runs), 'run')} in flight checkpointed at the end of an "
              f"episode; no report; rerun the same command to resume", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("interrupted: rerun the same command to resume", file=sys.stderr)
        return 130
    finally:
        backend.close(cancel=cancel)
    finished = sum(rundir.is_done(out / n.rel) for n in nodes)
    no_report = ""
    if not a.no_report and report is not None:
        if finished:
            try:
                written = report(out)
                print(f"report: {plural(len(written), 'file')} in {out} (summary: {out / 'summary.md'})")
            except ConfigError as e:
                if not failed:
                    print(f"error: report: {e}", file=sys.stderr)
                    return 2
                no_report = f"; no report ({e})"
        else:
            no_report = "; no report: no run finished"
    if failed:
        again = "python -m maniskill_dualher.sweep " + shlex.join(sys.argv[1:] if argv is None else list(argv))
        print(f"error: {len(failed)} of {plural(len(nodes), 'run')} did not finish (first: {failed[0]}){no_report}; "
              f"rerun the same command to retry them: {again}", file=sys.stderr)
        return 1
    return 0

