"""Tables, plots and summary.md, rebuilt from run folders alone (config.json + metrics.csv).

    python -m maniskill_dualher.report results/quick

No training happens here, so the report can be rebuilt at any time, and a killed and
resumed sweep gives byte-identical tables (no wall time in them; bootstrap CIs are
seeded). Only finished runs (done.json) count. If the folder holds a sweep.json, only
the runs that sweep lists are used (a folder can keep older runs after ``--force``).

A run folder with stage.json is a stage of a transfer chain (see protocol.py); its
last stage is the *adaptation* stage the paper's Tables 4 and 5 count; a folder without
one is a single-task run (paper Fig. 4).
"""
from __future__ import annotations

import math
import sys
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from maniskill_dualher import protocol, rundir
from maniskill_dualher.config import ConfigError, RunConfig, format_ratio
from maniskill_dualher.cli import OneLineParser
from maniskill_dualher.methods import METHOD_SPECS
from maniskill_dualher.paper import (PAPER_ADAPT_BUDGET, PAPER_ADAPT_STEPS, PAPER_RATIO, PAPER_TABLE3, PAPER_TABLE4,
                                     PAPER_TABLE5, PAPER_TARGET, SCRATCH, paper_claims)
from maniskill_dualher.fileio import atomic_write_text, atomic_write_with, csv_text, fmt


EXTRA_COLORS = ("tab:purple", "tab:brown", "tab:green", "tab:red", "tab:pink", "tab:olive", "tab:cyan")


_EXTRA_ASSIGNED: Dict[str, str] = {}


def color_of(label: str) -> str:
    """One colour per curve label in every panel: a method's own colour for its paper setting, an extra
    colour (assigned in order of first use, so distinct) for anything else, e.g. other sampling ratios."""
    base = label.replace(f" {SCRATCH}", "")
    name, _, variant = base.partition(" ")
    spec = METHOD_SPECS.get(name)
    if spec is not None and (not variant or variant == format_ratio(PAPER_RATIO)):
        return spec.color
    if base not in _EXTRA_ASSIGNED:
        _EXTRA_ASSIGNED[base] = EXTRA_COLORS[len(_EXTRA_ASSIGNED) % len(EXTRA_COLORS)]
    return _EXTRA_ASSIGNED[base]


TABLE_COLUMNS = ["experiment", "task", "chain", "method", "ratio", "metric", "n_seeds", "seeds",
                 "mean", "std", "ci95_low", "ci95_high", "env_steps", "paper"]
METRICS = {  # metric name -> one score per run, read from its metrics rows
    "successful_train_episodes": lambda r: r.final["train_successes"],
    "final_eval_success_rate": lambda r: r.final["eval_success_rate"],
    "final_eval_return": lambda r: r.final["eval_return"],
    # area under the learning curve: the mean over every evaluation of the run (a faster learner scores higher)
    "mean_eval_success_rate": lambda r: float(np.mean([row["eval_success_rate"] for row in r.rows])),
    "mean_eval_return": lambda r: float(np.mean([row["eval_return"] for row in r.rows])),
}


# --------------------------------------------------------------------------- run folders
@dataclass
class Run:
    rel: str
    cfg: RunConfig
    rows: List[Dict[str, float]]
    lineage: Optional[dict]
    done: bool

    @property
    def final(self) -> Dict[str, float]:
        return self.rows[-1]

    @property
    def chain(self) -> str:
        if not self.lineage:
            return ""
        return SCRATCH if self.lineage.get("protocol") == "scratch" else " > ".join(self.lineage["chain"])


def load_runs(folder: Path) -> Tuple[List[Run], List[str]]:
    """Finished runs of the folder's sweep (or every run folder); also the unfinished ones' names."""
    sweep = rundir.read_sweep(folder)
    if sweep is not None:
        rels = sweep["runs"]
    else:
        rels = sorted(str(p.parent.relative_to(folder)) for p in folder.rglob(rundir.CONFIG))
    runs, unfinished = [], []
    for rel in rels:
        d = folder / rel
        if not (rundir.is_done(d) and (d / rundir.METRICS).is_file() and (d / rundir.CONFIG).is_file()):
            unfinished.append(rel)
            continue
        rows = rundir.read_metrics(d)
        if not rows:
            unfinished.append(rel)
            continue
        cfg = RunConfig.from_dict(rundir.read_json(d / rundir.CONFIG))
        runs.append(Run(rel, cfg, rows, rundir.read_stage(d), True))
    return runs, unfinished


# --------------------------------------------------------------------------- statistics
def bootstrap_ci(values: Sequence[float], resamples: int = 10_000, seed: int = 0) -> Tuple[float, float]:
    """95% percentile bootstrap CI of the mean over seeds; seeded, so tables are reproducible."""
    x = np.asarray(values, dtype=np.float64)
    if x.size == 0:
        return math.nan, math.nan
    rng = np.random.default_rng(seed)
    means = x[rng.integers(0, x.size, size=(resamples, x.size))].mean(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    return float(lo), float(hi)


def summarize(values: Sequence[float], resamples: int = 10_000, seed: int = 0) -> Dict[str, float]:
    x = np.asarray(values, dtype=np.float64)
    lo, hi = bootstrap_ci(x, resamples, seed)
    return {"n_seeds": int(x.size), "mean": float(x.mean()),
            "std": float(x.std(ddof=1)) if x.size > 1 else math.nan, "ci95_low": lo, "ci95_high": hi}


# --------------------------------------------------------------------------- grouping
def _ratio_of(run: Run) -> str:
    spec = METHOD_SPECS.get(run.cfg.method)
    return spec.tag(run.cfg) if spec else ""


def _method_order(m: str) -> int:
    names = list(METHOD_SPECS)
    return names.index(m) if m in names else len(names)


def _task_order(t: str) -> int:
    return protocol.TASKS.index(t) if t in protocol.TASKS else len(protocol.TASKS)


def group_runs(runs: List[Run], kind: str) -> Dict[tuple, List[Run]]:
    """(task, chain, method, ratio, env_steps) -> runs over seeds; kind 'single' or 'adaptation'."""
    groups: Dict[tuple, List[Run]] = defaultdict(list)
    for r in runs:
        if kind == "single" and r.lineage is None or kind == "adaptation" and r.lineage and r.lineage["adaptation"]:
            groups[(r.cfg.env_id, r.chain, r.cfg.method, _ratio_of(r), r.cfg.total_steps)].append(r)
    ordered = sorted(groups.items(), key=lambda kv: (_task_order(kv[0][0]), kv[0][1], _method_order(kv[0][2]),
                                                     kv[0][3], kv[0][4]))
    return {k: sorted(v, key=lambda r: r.cfg.seed) for k, v in ordered}


def table_rows(experiment: str, groups: Dict[tuple, List[Run]], metrics: Sequence[str], paper_fn,
               resamples: int) -> List[dict]:
    rows = []
    for (task, chain, method, ratio, steps), runs in groups.items():
        for metric in metrics:
            vals = [METRICS[metric](r) for r in runs]
            rows.append({"experiment": experiment, "task": task, "chain": chain, "method": method, "ratio": ratio,
                         "metric": metric, "seeds": " ".join(str(r.cfg.seed) for r in runs),
                         **summarize(vals, resamples), "env_steps": steps,
                         "paper": paper_fn(task, chain, method, ratio, metric)})
    return rows


def _paper_chain(chain: str) -> bool:
    return chain == " > ".join(protocol.TRANSFER_ORDER)


def paper_table4(task, chain, method, ratio, metric) -> str:
    if task != PAPER_TARGET or not _paper_chain(chain) or metric != "successful_train_episodes":
        return ""
    return next((v for r, v in PAPER_TABLE4.items() if format_ratio(r) == ratio), "")


def paper_table5(task, chain, method, ratio, metric) -> str:
    if task != PAPER_TARGET or not _paper_chain(chain) or metric != "successful_train_episodes":
        return ""
    return PAPER_TABLE5.get(method, "")


def _has_ratio(method: str) -> bool:
    return method in METHOD_SPECS and METHOD_SPECS[method].sampling_ratio


def build_tables(runs: List[Run], resamples: int = 10_000) -> Dict[str, List[dict]]:
    adapt = group_runs(runs, "adaptation")
    t4 = {k: v for k, v in adapt.items() if _has_ratio(k[2]) and k[1] != SCRATCH}
    t4 = dict(sorted(t4.items(), key=lambda kv: (_task_order(kv[0][0]), kv[0][1], kv[0][4], kv[0][3])))
    t5 = {k: v for k, v in adapt.items() if not _has_ratio(k[2]) or k[3] == format_ratio(PAPER_RATIO)}
    single = group_runs(runs, "single")
    return {
        "table4_sampling_ratio.csv": table_rows("ratios", t4, ["successful_train_episodes"], paper_table4, resamples),
        "table5_multitask.csv": table_rows("transfer", t5, ["successful_train_episodes", "final_eval_success_rate",
                                                            "mean_eval_success_rate", "mean_eval_return"],
                                           paper_table5, resamples),
        "single_task.csv": table_rows("single", single, ["final_eval_success_rate", "mean_eval_success_rate",
                                                         "mean_eval_return", "successful_train_episodes"],
                                      lambda *a: "", resamples),
    }


def hyperparameter_rows(runs: List[Run]) -> List[dict]:
    """The paper's Table 3 beside the values our runs used (read back from config.json)."""
    ordered = sorted(runs, key=lambda r: (r.lineage["stage"] if r.lineage else 0, _task_order(r.cfg.env_id), r.rel))
    single = [r.cfg for r in ordered if r.lineage is None]
    transfer = [r.cfg for r in ordered if r.lineage is not None]

    def values(cfgs, get):
        seen = []
        for c in cfgs:
            v = get(c)
            if v is not None and str(v) not in seen:
                seen.append(str(v))
        return "; ".join(seen)

    return [{"hyperparameter": name, "paper": paper, "ours_single_task": values(single, get),
             "ours_transfer": values(transfer, get)} for name, paper, get in PAPER_TABLE3]


def task_rows() -> Tuple[Optional[List[dict]], str]:
    """tasks.table.task_rows() if the tasks package has it; else (None, why)."""
    try:
        from maniskill_dualher.tasks.table import task_rows as fn
    except ImportError as e:
        return None, f"tasks.csv skipped: tasks.table.task_rows is not available ({e})"
    try:
        return [dict(r) for r in fn()], ""
    except Exception as e:  # the table is informative; never lose the rest of the report to it
        return None, f"tasks.csv skipped: tasks.table.task_rows() failed: {type(e).__name__}: {e}"


# --------------------------------------------------------------------------- writing
def save_figure(fig, path: Path) -> None:
    """Atomic PNG write (temp file in the same folder, then rename)."""
    atomic_write_with(path, lambda tmp: fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight",
                                                     metadata={"Software": None}))


# --------------------------------------------------------------------------- plots
def curve(runs: List[Run], key: str, resamples: int = 2_000):
    """Mean and 95% bootstrap band over seeds at the evaluation points every run has.

    A run evaluates at the first episode end at or after each multiple of ``eval_every`` (episodes end
    on success, so that step differs between runs), and at the end of its budget: each row is placed
    at its nominal point ``min(total_steps, floor(env_steps / eval_every) * eval_every)``."""
    def nominal(r: Run, row) -> float:
        return float(min(r.cfg.total_steps, (int(row["env_steps"]) // r.cfg.eval_every) * r.cfg.eval_every))

    points = [{nominal(r, row): row[key] for row in r.rows} for r in runs]
    steps = sorted(set.intersection(*[set(p) for p in points]))
    y = np.array([[p[s] for s in steps] for p in points], dtype=float)
    rng = np.random.default_rng(0)
    boot = y[rng.integers(0, len(runs), size=(resamples, len(runs)))].mean(axis=1)
    lo, hi = np.percentile(boot, [2.5, 97.5], axis=0)
    return np.array(steps), y.mean(axis=0), lo, hi


def _plot_groups(ax, groups: Dict[str, List[Run]], key: str, title: str, ylabel: str) -> None:
    for label, runs in groups.items():
        x, m, lo, hi = curve(runs, key)
        base = label.replace(f" {SCRATCH}", "")
        (line,) = ax.plot(x, m, marker="o", ms=3, label=f"{label} (n={len(runs)})", color=color_of(base),
                          linestyle="--" if base != label else "-")
        ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.2)
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("environment steps")
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    if groups:
        ax.legend(fontsize=8)
    else:
        ax.text(0.5, 0.5, "no finished runs", ha="center", va="center", transform=ax.transAxes)


def plot_fig4(runs: List[Run], path: Path) -> bool:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    single = group_runs(runs, "single")
    tasks = sorted({k[0] for k in single}, key=_task_order)
    if not tasks:
        return False
    fig, axes = plt.subplots(2, len(tasks), figsize=(4.8 * len(tasks), 7.5), squeeze=False)
    for j, task in enumerate(tasks):
        by_method = {k[2] + (f" {k[3]}" if k[3] else ""): v for k, v in single.items() if k[0] == task}
        _plot_groups(axes[0, j], by_method, "eval_success_rate", f"{task}: evaluation success",
                     "success rate (fraction of eval episodes)")
        _plot_groups(axes[1, j], by_method, "eval_return", f"{task}: evaluation return",
                     "return per episode (sparse reward, sum)")
    fig.suptitle("Single-task learning (paper Fig. 4): mean over seeds, 95% bootstrap CI band")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return True


def plot_fig5(runs: List[Run], path: Path) -> bool:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    adapt = group_runs(runs, "adaptation")
    if not adapt:
        return False
    target = sorted({k[0] for k in adapt}, key=_task_order)[-1]
    adapt = {k: v for k, v in adapt.items() if k[0] == target}
    paper_ratio = format_ratio(PAPER_RATIO)
    methods = {k[2] + (f" {k[3]}" if k[3] else "") + (f" {SCRATCH}" if k[1] == SCRATCH else ""): v
               for k, v in adapt.items() if not _has_ratio(k[2]) or k[3] == paper_ratio}
    ratios = {f"{k[2]} {k[3]}": v for k, v in adapt.items() if _has_ratio(k[2]) and k[1] != SCRATCH}
    fig, axes = plt.subplots(2, 2, figsize=(11, 8.5))
    _plot_groups(axes[0, 0], methods, "eval_return", f"{target} adaptation: evaluation return",
                 "return per episode (sparse reward, sum)")
    _plot_groups(axes[0, 1], methods, "eval_success_rate", f"{target} adaptation: evaluation success",
                 "success rate (fraction of eval episodes)")
    _plot_groups(axes[1, 0], methods, "train_successes", f"{target} adaptation: successful attempts (Table 5)",
                 "successful training episodes (cumulative)")
    _plot_groups(axes[1, 1], ratios, "train_successes", f"{target} adaptation: sampling ratio P(R)/P(E) (Table 4)",
                 "successful training episodes (cumulative)")
    chain = next((v[0].chain for k, v in adapt.items() if k[1] != SCRATCH), target)
    fig.suptitle(f"Multi-task transfer (paper Fig. 5): {chain} (solid) vs {target} {SCRATCH} (dashed), "
                 "same budget; mean over seeds, 95% bootstrap CI band")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return True


# --------------------------------------------------------------------------- claims
RATE_MARGIN = 0.1      # success rates and sparse returns per episode (in [0, 1]): 10 percentage points
COUNT_MARGIN = 0.1     # counts: 10% of the larger side's mean


def _side(runs: List[Run], sel: Tuple[str, ...]) -> List[Run]:
    kind, task, chain, method, ratio = sel
    groups = group_runs(runs, kind)
    found = [v for k, v in groups.items() if k[:4] == (task, chain, method, ratio)]
    return found[0] if found else []


def claim_rows(runs: List[Run], resamples: int = 10_000) -> List[dict]:
    """One row per claim: both sides' means, the difference with its 95% CI, P(A > B) and the verdict."""
    from maniskill_dualher import stats

    rows = []
    for c in paper_claims():
        a = [METRICS[c.metric](r) for r in _side(runs, c.side_a)]
        b = [METRICS[c.metric](r) for r in _side(runs, c.side_b)]
        row = {"claim": c.key, "statement": c.text, "paper": c.paper, "metric": c.metric}
        if not a or not b:
            rows.append({**row, "verdict": "not measured (runs missing)"})
            continue
        margin = COUNT_MARGIN * max(abs(np.mean(a)), abs(np.mean(b)), 1.0) if c.relative_margin else RATE_MARGIN
        cmp = stats.compare(a, b, margin, resamples)
        rows.append({**row, "n_a": cmp.n_a, "n_b": cmp.n_b, "mean_a": cmp.mean_a, "mean_b": cmp.mean_b,
                     "diff": cmp.diff, "diff_ci95_low": cmp.ci_low, "diff_ci95_high": cmp.ci_high,
                     "prob_improvement": cmp.prob_improvement, "margin": margin, "verdict": cmp.verdict_text(),
                     "seeds_to_decide": cmp.seeds_to_decide})
    return rows


CLAIM_COLUMNS = ["claim", "statement", "paper", "metric", "n_a", "n_b", "mean_a", "mean_b", "diff", "diff_ci95_low",
                 "diff_ci95_high", "prob_improvement", "margin", "verdict", "seeds_to_decide"]


def _g(v) -> str:
    return fmt(float(f"{v:.3g}")) if isinstance(v, float) and not math.isnan(v) else fmt(v)


def claims_md(rows: List[dict]) -> List[str]:
    lines = ["| | claim (A > B) | paper | ours: A vs B (mean over seeds, n) | A - B [95% CI] | P(A > B) | verdict |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        if "diff" not in r:
            lines.append(f"| {r['claim']} | {r['statement']} | {r['paper']} | | | | {r['verdict']} |")
            continue
        lines.append(f"| {r['claim']} | {r['statement']} | {r['paper']} | {_g(r['mean_a'])} vs {_g(r['mean_b'])} "
                     f"(n = {r['n_a']}, {r['n_b']}) | {_g(r['diff'])} [{_g(r['diff_ci95_low'])}, "
                     f"{_g(r['diff_ci95_high'])}] | {r['prob_improvement']:.2f} | **{r['verdict']}** |")
    return lines


def md_table(rows: List[dict], columns: List[str]) -> str:
    if not rows:
        return "_no finished runs_\n"
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(r.get(c)) for c in columns) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def summary_md(folder: Path, runs: List[Run], unfinished: List[str], tables: Dict[str, List[dict]],
               hyper: List[dict], tasks_note: str, figures: List[str], claims: List[dict]) -> str:
    sweep = rundir.read_sweep(folder) or {}
    seeds = sorted({r.cfg.seed for r in runs})
    adapt_steps = sorted({r.cfg.total_steps for r in runs if r.lineage and r.lineage["adaptation"]})
    single_steps = sorted({(r.cfg.env_id, r.cfg.total_steps) for r in runs if r.lineage is None},
                          key=lambda x: _task_order(x[0]))
    cols = ["task", "chain", "method", "ratio", "metric", "n_seeds", "mean", "std", "ci95_low", "ci95_high", "env_steps",
            "paper"]
    s = [f"# Results: {sweep.get('preset', folder.name)}", ""]
    s.append(f"{len(runs)} finished runs, seeds {seeds}"
             + (f"; {len(unfinished)} runs unfinished (not counted)" if unfinished else "") + ".")
    s.append(f"Single-task budgets (env steps): {', '.join(f'{t} {n}' for t, n in single_steps) or 'none'}. "
             f"Adaptation stage: {', '.join(map(str, adapt_steps)) or 'none'} env steps "
             f"(paper: {PAPER_ADAPT_BUDGET}).")
    if adapt_steps:
        s.append(f"Our adaptation budget is {100 * adapt_steps[0] / PAPER_ADAPT_STEPS:.2g}% of the paper's, and our tasks "
                 "are ManiSkill3 re-creations of the RLBench ones, so absolute counts are not comparable: "
                 "compare directions and ratios.")
    s += ["", "Tables are recomputed from run folders (config.json + metrics.csv); mean, sample std and a 95% "
          "percentile bootstrap CI (10,000 seeded resamples) over seeds. 'successful training episodes' = the "
          "paper's 'successful attempts': training episodes that ended in success, counted over the run.", ""]
    decided = [r for r in claims if "diff" in r and not r["verdict"].startswith(("inconclusive", "not measured"))]
    s += ["## Verdicts on the paper's claims (`claims.csv`)", "",
          "Each claim is 'A > B' in the paper's direction. The difference of the means A - B over seeds gets a "
          "95% bootstrap CI (scipy.stats.bootstrap, percentile, 10,000 seeded resamples, each side resampled "
          "within itself); P(A > B) is the probability of improvement (Mann-Whitney, as in rliable). "
          "**reproduced**: the CI excludes 0 in the paper's direction; **contradicted**: it excludes 0 the "
          f"other way; **no difference larger than X**: the CI lies within +-X (X = {RATE_MARGIN} for success "
          f"rates and per-episode returns, {COUNT_MARGIN:.0%} of the larger mean for episode counts); "
          "**inconclusive** otherwise, with the seeds per side that would likely decide it at the observed "
          "spread. Curve claims (Fig. 4, Fig. 5) compare the mean over a run's evaluations (area under its "
          "curve). With episodes that end on success the sparse return of an episode is 1 or 0, so return "
          "and success rate coincide.", "",
          f"{len(decided)} of {len(claims)} claims decided.", ""] + claims_md(claims) + [""]
    for name, title in (("table5_multitask.csv", "Table 5: SAC+HER+PER vs dual buffer, adaptation stage"),
                        ("table4_sampling_ratio.csv", "Table 4: dual buffer sampling ratio, adaptation stage"),
                        ("single_task.csv", "Single-task learning (paper Fig. 4 gives curves only)")):
        s += [f"## {title} (`{name}`)", "", md_table(tables[name], cols)]
    s += ["## Hyperparameters: paper Table 3 vs ours (`hyperparameters.csv`)", "",
          md_table(hyper, ["hyperparameter", "paper", "ours_single_task", "ours_transfer"])]
    s += ["## Tasks (`tasks.csv`)", "", tasks_note or "See tasks.csv.", ""]
    s += ["## Figures", ""] + [f"![{f}]({f})" for f in figures] + [""]
    if unfinished:
        s += ["## Unfinished runs (not counted)", ""] + [f"- {u}" for u in unfinished] + [""]
    return "\n".join(s)


def build_report(folder, resamples: int = 10_000) -> List[Path]:
    """Write every table, plot and summary.md into ``folder``; return the paths written."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(f"no such folder: {folder}")
    runs, unfinished = load_runs(folder)
    if not runs and not unfinished:
        raise ConfigError(f"{folder} holds no run folders (config.json + metrics.csv)")
    tables = build_tables(runs, resamples)
    written = []
    for name, rows in tables.items():
        atomic_write_text(folder / name, csv_text(rows, TABLE_COLUMNS))
        written.append(folder / name)
    hyper = hyperparameter_rows(runs)
    atomic_write_text(folder / "hyperparameters.csv", csv_text(hyper))
    written.append(folder / "hyperparameters.csv")
    trows, tasks_note = task_rows()
    if trows is not None:
        atomic_write_text(folder / "tasks.csv", csv_text(trows))
        written.append(folder / "tasks.csv")
    figures = []
    for name, fn in (("fig4_single_task.png", plot_fig4), ("fig5_multitask.png", plot_fig5)):
        if fn(runs, folder / name):
            figures.append(name)
            written.append(folder / name)
    claims = claim_rows(runs, resamples)
    atomic_write_text(folder / "claims.csv", csv_text(claims, CLAIM_COLUMNS))
    written.append(folder / "claims.csv")
    atomic_write_text(folder / "summary.md",
                               summary_md(folder, runs, unfinished, tables, hyper, tasks_note, figures, claims))
    written.append(folder / "summary.md")
    return written


def main(argv: Optional[Sequence[str]] = None) -> int:
    p = OneLineParser(prog="python -m maniskill_dualher.report",
                                description="Rebuild tables (CSV), plots (PNG) and summary.md of a sweep folder "
                                            "from its run folders alone; no training.")
    p.add_argument("folder", help="a sweep's --out folder (e.g. results/quick)")
    p.add_argument("--resamples", type=int, default=10_000, help="bootstrap resamples (default: %(default)s)")
    a = p.parse_args(argv)
    try:
        written = build_report(Path(a.folder), a.resamples)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for w in written:
        print(w)
    return 0


if __name__ == "__main__":
    sys.exit(main())
