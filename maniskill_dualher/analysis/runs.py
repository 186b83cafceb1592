"""Run folders -> per-seed scores and curves (``scores.csv``, ``curves.csv``): what every table, claim and
figure is computed from, so a results folder without its run folders can be rebuilt and checked.

A run serves one or more *cells* (``cell.json``, written by the sweep): experiment, arm, task, chain,
method, variant, seed, stage, role ("single", "source" or "adapt"). A score is one number per run and
metric (``METRICS``); a curve point is one evaluation of a run, placed at its nominal env step.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Dict, List, Optional, Tuple

import numpy as np

from .. import rundir
from ..config import RunConfig
from ..provenance import machine_label

CELL_KEYS = ["experiment", "arm", "task", "chain", "method", "variant", "seed", "stage", "role"]
SCORE_COLUMNS = CELL_KEYS + ["metric", "value", "run", "machine"]
CURVE_KEYS = ["eval_success_rate", "eval_return", "train_successes", "train_episodes"]
CURVE_COLUMNS = CELL_KEYS + ["env_steps"] + CURVE_KEYS + ["run"]


@dataclass
class Run:
    rel: str
    cfg: RunConfig
    rows: List[Dict[str, float]]       # metrics.csv, one per evaluation
    cells: List[dict]
    machine: str = ""                  # the CPU(s) it ran on, from provenance.json (" + " if resumed elsewhere)
    diag: List[Dict[str, float]] = field(default_factory=list)  # diagnostics.csv (runs made since it exists)

    @property
    def trained_rows(self) -> List[Dict[str, float]]:
        """Evaluations after training began (an evaluation at env step 0 scores the starting policy)."""
        return [r for r in self.rows if r["env_steps"] > 0] or self.rows

    @property
    def start_row(self) -> Optional[Dict[str, float]]:
        return self.rows[0] if self.rows and self.rows[0]["env_steps"] == 0 else None


def _steps_to_successes(k: int) -> Callable[[Run], float]:
    def f(r: Run) -> float:  # at evaluation resolution; a run that never gets there counts its budget
        hit = [row["env_steps"] for row in r.rows if row["train_successes"] >= k]
        return float(hit[0]) if hit else float(r.cfg.total_steps)
    return f


def _dip(r: Run) -> Tuple[float, float]:
    """Fine-tuning dip: (depth, length) of the fall below the step-0 evaluation (NaN without one)."""
    s0 = r.start_row
    if s0 is None:
        return math.nan, math.nan
    base = s0["eval_success_rate"]
    later = r.trained_rows
    depth = max(0.0, base - min(row["eval_success_rate"] for row in later))
    if depth == 0:
        return 0.0, 0.0
    i_min = int(np.argmin([row["eval_success_rate"] for row in later]))
    back = [row["env_steps"] for row in later[i_min:] if row["eval_success_rate"] >= base]
    return depth, float(back[0]) if back else float(r.cfg.total_steps)


DIAG_SOURCES = ("R", "E")
DIAG_STATS = {"td_abs": ("updates", "|TD| (summed over the two critics)"), "alpha": ("logged", "alpha"),
              "entropy": ("logged", "policy entropy (-log pi)"), "qf_values": ("logged", "mean Q")}


def _diag(src: str, stat: str) -> Callable[[Run], float]:
    """The learner's mean ``stat`` on batches from ``src`` over the run (weighted by the updates it averages;
    NaN for runs without diagnostics.csv or without such batches)."""
    weight = DIAG_STATS[stat][0]

    def f(r: Run) -> float:
        pairs = [(row.get(f"{src}_{weight}"), row.get(f"{src}_{stat}")) for row in r.diag]
        pairs = [(float(w), float(v)) for w, v in pairs if isinstance(w, float) and isinstance(v, float) and w > 0
                 and not math.isnan(v)]
        total = sum(w for w, _ in pairs)
        return sum(w * v for w, v in pairs) / total if total else math.nan
    return f


# metric name -> (one score per run, what it means)
METRICS: Dict[str, Tuple[Callable[[Run], float], str]] = {
    "successful_train_episodes": (lambda r: r.rows[-1]["train_successes"],
                                  "training episodes that ended in success (the paper's 'successful attempts')"),
    "final_eval_success_rate": (lambda r: r.rows[-1]["eval_success_rate"], "evaluation success at the end"),
    "final_eval_return": (lambda r: r.rows[-1]["eval_return"], "evaluation return at the end"),
    "mean_eval_success_rate": (lambda r: float(np.mean([x["eval_success_rate"] for x in r.trained_rows])),
                               "mean evaluation success over the run's evaluations (area under the curve)"),
    "mean_eval_return": (lambda r: float(np.mean([x["eval_return"] for x in r.trained_rows])),
                         "mean evaluation return over the run's evaluations"),
    "train_success_rate": (lambda r: r.rows[-1]["train_successes"] / max(1.0, r.rows[-1]["train_episodes"]),
                           "successful training episodes / training episodes"),
    "steps_to_10_successes": (_steps_to_successes(10),
                              "env steps until 10 successful training episodes (evaluation resolution; "
                              "the budget if never)"),
    "step0_eval_success_rate": (lambda r: r.start_row["eval_success_rate"] if r.start_row else math.nan,
                                "evaluation success before any training (a transfer stage: the prior, zero-shot)"),
    "dip_depth": (lambda r: _dip(r)[0], "fall of evaluation success below its step-0 value (fine-tuning collapse)"),
    "dip_length": (lambda r: _dip(r)[1], "env steps until evaluation success is back at its step-0 value"),
    **{f"diag_{src}_{stat}": (_diag(src, stat), f"learner diagnostics: {what} on batches from {src}")
       for src in DIAG_SOURCES for stat, (_, what) in DIAG_STATS.items()},
}


def load_runs(folder: Path) -> Tuple[List[Run], List[str]]:
    """Finished runs of the folder's sweep that have cells; also the unfinished ones' names."""
    sweep = rundir.read_sweep(folder)
    if sweep is not None:
        rels = sweep.get("runs", [])
    else:
        rels = sorted(str(p.parent.relative_to(folder)) for p in folder.rglob(rundir.CONFIG))
    runs, unfinished = [], []
    for rel in rels:
        d = folder / rel
        if not (rundir.is_done(d) and (d / rundir.METRICS).is_file() and (d / rundir.CONFIG).is_file()):
            unfinished.append(rel)
            continue
        rows = rundir.read_metrics(d)
        cell = rundir.read_json(d / rundir.CELL)
        if not rows or not cell:
            unfinished.append(rel)
            continue
        cfg = RunConfig.from_dict(rundir.read_json(d / rundir.CONFIG))
        diag = rundir.read_metrics(d, rundir.DIAGNOSTICS) if (d / rundir.DIAGNOSTICS).is_file() else []
        runs.append(Run(rel, cfg, rows, list(cell["cells"]), run_machine(d), diag))
    return runs, unfinished


def run_machine(run_dir: Path) -> str:
    """The machines a run's process starts ran on (provenance.json), in order, without repeats."""
    try:
        starts = (rundir.read_json(run_dir / rundir.PROVENANCE) or {}).get("starts", [])
    except ValueError:
        return ""
    labels = [machine_label(s.get("cpu")) for s in starts if isinstance(s, dict)]
    return " + ".join(dict.fromkeys(lb for lb in labels if lb))


def _num(v: float) -> str:
    return "nan" if isinstance(v, float) and math.isnan(v) else f"{float(v):.10g}"


def _cell_values(c: dict) -> Dict[str, str]:
    return {k: "" if c.get(k) is None else str(c.get(k)) for k in CELL_KEYS}


def _unique_cells(cells: List[dict]) -> List[Dict[str, str]]:
    """A run's cells as CELL_KEYS values, each once: the grid lists a shared prior's source stage once per
    method that adapts from it, with the same values (the prior's method), and a score is per cell."""
    return [dict(t) for t in dict.fromkeys(tuple(_cell_values(c).items()) for c in cells)]


def score_key(r: Dict[str, str]) -> tuple:
    """What a scores.csv row is unique by: its run, its cell and its metric."""
    return (r["run"], *(r[k] for k in CELL_KEYS), r["metric"])


def curve_key(r: Dict[str, str]) -> tuple:
    return (r["run"], *(r[k] for k in CELL_KEYS), *(r[k] for k in ["env_steps"] + CURVE_KEYS))


def unique_rows(rows: List[Dict[str, str]], key: Callable[[Dict[str, str]], tuple],
                what: str) -> List[Dict[str, str]]:
    """``rows`` without repeats of a key (the first kept); a key repeated with another value is an error
    (two runs would claim one cell), raised as ValueError naming it. Scores written before the cells were
    made unique (a shared prior's source stages, listed once per adapting method) are read through this."""
    seen: Dict[tuple, Dict[str, str]] = {}
    for r in rows:
        k = key(r)
        if k in seen and seen[k] != r:
            raise ValueError(f"{what} holds {'/'.join(map(str, k))} twice with different values")
        seen.setdefault(k, r)
    return list(seen.values())


def score_rows(runs: List[Run]) -> List[Dict[str, str]]:
    out = []
    for r in sorted(runs, key=lambda r: r.rel):
        values = {m: fn(r) for m, (fn, _) in METRICS.items()}
        for c in _unique_cells(r.cells):
            for m, v in values.items():
                if isinstance(v, float) and math.isnan(v):
                    continue
                out.append({**c, "metric": m, "value": _num(v), "run": r.rel, "machine": r.machine})
    return out


def nominal_step(cfg: RunConfig, env_steps: float) -> int:
    """An evaluation's nominal point: episodes end on success, so the step it ran at differs between runs."""
    return int(min(cfg.total_steps, (int(env_steps) // cfg.eval_every) * cfg.eval_every))


def curve_rows(runs: List[Run]) -> List[Dict[str, str]]:
    out = []
    for r in sorted(runs, key=lambda r: r.rel):
        for c in _unique_cells(r.cells):
            for row in r.rows:
                out.append({**c, "env_steps": str(nominal_step(r.cfg, row["env_steps"])),
                            **{k: _num(row.get(k, math.nan)) for k in CURVE_KEYS}, "run": r.rel})
    return out


def read_rows(path: Path) -> List[Dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))
