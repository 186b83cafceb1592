"""The paper's multi-task transfer (section 3.1): a chain of stages, each its own run.

Stage 0 trains from scratch; stage i+1 starts from stage i's final networks and, if
``carry_replay`` (and its ``replay.carry_rows``), its replay buffers (the paper's "prior policy" plus the
samples it collected). The last stage is the *adaptation* stage (the paper's target task,
CloseMicrowave, trained 120 epochs instead of 200). HER uses k = 8 in the
multi-task setting (paper 4.2.2) against 4 for single tasks.

Every stage lives in its own folder ``<chain_dir>/stage<i>-<env>[-r<ratio>]-<hash>``,
the hash covering the configs of stages 0..i and the carry flag: a killed chain
resumes at the stage in flight, and two chains that share their first stages (the
sampling-ratio study varies only the adaptation stage) can share those folders.
Each stage folder also gets ``stage.json`` (its position in the chain and its
parent); which experiment and arm a run belongs to is the sweep's ``cell.json``.
"""
from __future__ import annotations

import copy
import hashlib
import json
from pathlib import Path
from typing import List, Sequence, Union

from maniskill_dualher import rundir
from maniskill_dualher.config import ConfigError, RunConfig
from maniskill_dualher.experiment.presets import HER_K_MULTITASK, HER_K_SINGLE  # noqa: F401 (re-exported)
from maniskill_dualher.experiment.registry import PAPER_CHAIN
from maniskill_dualher.methods import method_spec

PathLike = Union[str, Path]

TRANSFER_ORDER = PAPER_CHAIN            # paper: ReachTarget -> CloseBox -> CloseMicrowave (registry data)


# --------------------------------------------------------------------------- small shared helpers
def short_hash(obj) -> str:
    """8 hex chars of sha256 over canonical JSON: the key that makes a folder name a config identity."""
    blob = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=list)
    return hashlib.sha256(blob.encode()).hexdigest()[:8]


# --------------------------------------------------------------------------- chains
def make_stages(base: RunConfig, order: Sequence[str], steps: Sequence[int],
                her_k: int = HER_K_MULTITASK, adaptation_ratio=None) -> List[RunConfig]:
    """One RunConfig per stage: ``base`` with the stage's task and budget, HER k for multi-task.

    ``adaptation_ratio`` (dual buffer's R/E sampling ratio) applies to the last stage
    only, so the ratio study compares adaptations of one shared prior.
    """
    if len(order) != len(steps) or not order:
        raise ConfigError(f"a chain needs one step budget per task, got {len(order)} tasks and {len(steps)} budgets")
    stages = []
    for i, (env_id, n) in enumerate(zip(order, steps)):
        cfg = copy.deepcopy(base)
        cfg.env_id = env_id
        cfg.total_steps = int(n)
        cfg.replay.her_k = her_k
        if adaptation_ratio is not None and i == len(order) - 1:
            cfg.replay.ratio = tuple(float(x) for x in adaptation_ratio)
        stages.append(cfg)
    return stages


def validate_chain(stages: Sequence[RunConfig]) -> None:
    if not stages:
        raise ConfigError("a transfer chain needs at least one stage")
    methods = {s.method for s in stages[:-1]}
    if len(methods) > 1:
        raise ConfigError(f"all source stages of a chain must use one method, got {sorted(methods)}")
    prior, last = stages[0].method, stages[-1].method
    if last != prior and prior not in method_spec(last).adopts:
        raise ConfigError(f"method {last!r} cannot adapt from a {prior!r} prior "
                          f"(it adopts: {', '.join(method_spec(last).adopts) or 'only its own'})")
    for s in stages:
        s.validate()


def stage_dirname(stages: Sequence[RunConfig], i: int, carry_replay: bool) -> str:
    """Readable name + hash of the chain prefix 0..i (a stage's identity includes where it started)."""
    cfg = stages[i]
    key = {"stages": [s.to_dict() for s in stages[: i + 1]], "carry_replay": bool(carry_replay)}
    variant = method_spec(cfg.method).tag(cfg)
    tag = f"-r{variant.replace('/', '-')}" if variant else ""
    return f"stage{i}-{cfg.env_id}{tag}-{short_hash(key)}"


def takes_rows(cfg: RunConfig, carry_replay: bool) -> bool:
    """Whether a stage of a chain run with ``carry_replay`` starts from its parent's replay rows: the chain's flag
    and the stage's own ``replay.carry_rows`` (an arm may take the prior's networks and none of its rows). Stage 0
    has no parent; ``stage_job`` says so."""
    return bool(carry_replay and cfg.replay.carry_rows)


def stage_lineage(stages: Sequence[RunConfig], i: int, carry_replay: bool) -> dict:
    """What the report needs to place a stage: index, chain, parent folder (relative), carry flag."""
    return {
        # a one-stage "chain" is the from-scratch control of the adaptation stage (same budget and settings)
        "protocol": "transfer" if len(stages) > 1 else "scratch",
        "stage": i,
        "n_stages": len(stages),
        "adaptation": i == len(stages) - 1,
        "chain": [s.env_id for s in stages],
        "parent": stage_dirname(stages, i - 1, carry_replay) if i > 0 else None,
        "carry_replay": takes_rows(stages[i], carry_replay),
    }


def stage_job(stages: Sequence[RunConfig], i: int, chain_dir: PathLike, carry_replay: bool = True,
              check_parent: bool = True) -> dict:
    """What training stage i of a chain takes (``train.Job``'s fields); writes the stage's ``stage.json``.
    Stage i-1 must be finished."""
    chain_dir = Path(chain_dir)
    out = chain_dir / stage_dirname(stages, i, carry_replay)
    init_from = None
    if i > 0:
        init_from = chain_dir / stage_dirname(stages, i - 1, carry_replay)
        if check_parent and not rundir.is_done(init_from):
            raise ConfigError(f"stage {i} needs finished stage {i - 1} at {init_from}")
    if rundir.read_stage(out) is None:
        rundir.write_stage(out, stage_lineage(stages, i, carry_replay))
    # a stage that does not take the rows (replay.carry_rows false) still finds its parent by the chain's flag, so
    # it adapts the very prior a carrying arm adapts; the parent keeps its replay for the arms that do take it
    return dict(cfg=stages[i], out=str(out), init_from=None if init_from is None else str(init_from),
                carry_replay=i > 0 and takes_rows(stages[i], carry_replay),
                keep_replay=bool(carry_replay and i < len(stages) - 1))


def transfer_chain_dirs(out_dir: PathLike, stages: Sequence[RunConfig], carry_replay: bool = True) -> List[Path]:
    """The stage folders a chain uses (``train.train_chain``), in order."""
    return [Path(out_dir) / stage_dirname(stages, i, carry_replay) for i in range(len(stages))]

