"""``hyperparameters.csv``: the paper's Table 3 beside the values our runs used, per role (single-task, source
stages, adaptation), from the sweep's definition (``sweep.json``) and the registry, not from run folders (a
committed results folder has none): every cell in ``scores.csv`` gets its config from the grid
(``experiment/grid.py``, seed 0; no setting depends on the seed), so the table is rebuilt anywhere from the CSVs.

A value that no paper-treatment arm uses (``registry.is_paper_treatment``: the paper's settings in every stage)
is tagged with the arms that use it (by experiment where two or more of its arms are in that column and all use it):
``1000; 0 (warm_start/warm, warm_start/warm_low_lr)``.
"""
from __future__ import annotations

from typing import Dict, List, Sequence, Tuple

from ..config import TASKS, RunConfig
from ..experiment.grid import build_grid  # plain config code: no torch, no simulator
from ..experiment.registry import EXPERIMENTS, is_paper_treatment
from ..methods import METHOD_SPECS
from .paper import PAPER_TABLE3

ROLES = (("single", "ours_single_task"), ("source", "ours_source_stages"), ("adapt", "ours_adaptation"))
COLUMNS = ["hyperparameter", "paper"] + [c for _, c in ROLES]


def _alpha(c: RunConfig, stage: int) -> str:
    learned = "learned" if c.sac.resolved_learn_alpha() else "fixed"
    return f"{c.sac.alpha} ({learned})" if stage == 0 else f"carried from the previous stage ({learned})"


def _table():
    """(name, the paper's value, value of ours from (config, stage)): Table 3, then what a stage starts from."""
    rows = [(n, p, (_alpha if n.startswith("SAC entropy") else (lambda c, s, g=g: g(c)))) for n, p, g in PAPER_TABLE3]
    return rows + [
        ("networks at the start", "the previous stage's (transfer)",
         lambda c, s: "random init" if s == 0 else "the previous stage's final networks"),
        ("optimizer at the start", "not stated", lambda c, s: "fresh Adam" if s == 0 else "fresh Adam (not carried)"),
        ("replay at the start", "not stated",
         lambda c, s: "empty" if s == 0 or not c.replay.carry_rows else "the previous stage's, carried"),
        ("dual buffer: E carried into this stage", "not stated",
         lambda c, s: None if c.method != "dual_buffer" or s == 0 else
         c.replay.carry_success_buffer and c.replay.carry_rows),
        ("learning starts (env steps)", "not stated", lambda c, s: c.sac.learning_starts),
        ("evaluation at env step 0", "no", lambda c, s: c.eval_at_start),
    ]


def cell_configs(sweep: dict, scores: Sequence[dict]) -> List[Tuple[RunConfig, dict]]:
    """(config, cell) of every (experiment, arm, method, task, stage) in ``scores``, built by the grid from the
    sweep's definition (its budgets and settings; a merged sweep has the same, ``report.MERGE_SAME``), for the
    methods and tasks ``scores`` holds: a method or task added to the registry since is not planned. Arms the
    registry no longer has are left out."""
    have = {(r["experiment"], r["arm"], r["method"], r["task"], str(r["stage"])) for r in scores}
    arms = {(e, a) for e, a, *_ in have}
    selected = [f"{e.name}:{'+'.join(a.name for a in e.arms if (e.name, a.name) in arms)}"
                for e in EXPERIMENTS.values() if any((e.name, a.name) in arms for a in e.arms)]
    if not selected:
        return []
    d = {k: v for k, v in sweep.items() if k != "arm_seeds"}
    d.update(experiments=selected, tasks=[t for t in TASKS if any(h[3] == t for h in have)],
             methods=[m for m in METHOD_SPECS if any(h[2] == m for h in have)], seeds=[0], chain_seeds=[0])
    return [(n.cfg, c) for n in build_grid(d) for c in n.cells
            if (c["experiment"], c["arm"], c["method"], c["task"], str(c["stage"])) in have]


def _tagged(values: List[Tuple[str, str, str, bool]], present: Dict[str, set]) -> str:
    """'; '-joined values (paper-treatment ones first, then the rest tagged with their arms)."""
    plain = list(dict.fromkeys(v for v, _, _, paper in values if paper))
    others: Dict[str, Dict[str, set]] = {}
    for v, exp, arm, _ in values:
        if v not in plain:
            others.setdefault(v, {}).setdefault(exp, set()).add(arm)
    out = plain[:]
    for v, by_exp in others.items():
        tags = []
        for exp, arms in by_exp.items():
            tags += [exp] if arms == present[exp] and len(arms) > 1 else [f"{exp}/{a}" for a in
                                                       (x.name for x in EXPERIMENTS[exp].arms) if a in arms]
        out.append(f"{v} ({', '.join(tags)})")
    return "; ".join(out)


def hyperparameter_rows(cells: Sequence[Tuple[RunConfig, dict]]) -> List[dict]:
    """One row per hyperparameter: the paper's value and ours per role, from (config, cell) pairs."""
    rows = []
    paper_arm = {k: is_paper_treatment(*k) for k in {(c["experiment"], c["arm"]) for _, c in cells}}
    for name, paper, get in _table():
        row = {"hyperparameter": name, "paper": paper}
        for role, column in ROLES:
            mine = [(cfg, c) for cfg, c in cells if c["role"] == role]
            present: Dict[str, set] = {}
            for _, c in mine:
                present.setdefault(c["experiment"], set()).add(c["arm"])
            values = []
            for cfg, c in mine:
                v = get(cfg, int(c["stage"]))
                if v is not None:
                    values.append((str(v), c["experiment"], c["arm"], paper_arm[c["experiment"], c["arm"]]))
            row[column] = _tagged(values, present)
        rows.append(row)
    return rows
