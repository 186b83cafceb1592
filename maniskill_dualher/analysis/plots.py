"""Figures from ``curves.csv`` (one row per evaluation of a run, per cell): mean over seeds with a 95%
band at the evaluation points every seed of a curve has. Colours: a method's registry colour for its
paper arm, a fixed extra colour per other label."""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from ..config import TASKS
from ..fileio import atomic_write_with
from ..methods import METHOD_SPECS
from .tables import mean_ci

EXTRA_COLORS = ("tab:purple", "tab:brown", "tab:green", "tab:red", "tab:pink", "tab:olive", "tab:cyan")
_EXTRA_ASSIGNED: Dict[str, str] = {}


def color_of(method: str, arm: str = "paper") -> str:
    spec = METHOD_SPECS.get(method)
    if spec is not None and arm in ("paper", "0.6/0.4"):
        return spec.color
    key = f"{method} {arm}"
    if key not in _EXTRA_ASSIGNED:
        _EXTRA_ASSIGNED[key] = EXTRA_COLORS[len(_EXTRA_ASSIGNED) % len(EXTRA_COLORS)]
    return _EXTRA_ASSIGNED[key]


def save_figure(fig, path: Path) -> None:
    atomic_write_with(path, lambda tmp: fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight",
                                                     metadata={"Software": None}))


def curves_by(curves: Sequence[Dict[str, str]], where, label) -> Dict[str, Dict[int, Dict[int, dict]]]:
    """label -> seed -> nominal env step -> curve row."""
    out: Dict[str, Dict[int, Dict[int, dict]]] = defaultdict(lambda: defaultdict(dict))
    for r in curves:
        if where(r):
            out[label(r)][int(r["seed"])].setdefault(int(r["env_steps"]), r)
    return out


def band(by_seed: Dict[int, Dict[int, dict]], key: str):
    steps = sorted(set.intersection(*[set(v) for v in by_seed.values()]))
    y = np.array([[float(by_seed[s][t][key]) for t in steps] for s in sorted(by_seed)])
    lo, hi = zip(*[mean_ci(y[:, j]) if y.shape[0] > 1 else (y[0, j], y[0, j]) for j in range(len(steps))]) \
        if steps else ((), ())
    return np.array(steps), y.mean(axis=0) if steps else np.array([]), np.array(lo), np.array(hi)


def draw(ax, groups: Dict[str, Dict[int, Dict[int, dict]]], key: str, title: str, ylabel: str,
         styles: Optional[Dict[str, Tuple[str, str]]] = None,
         reference: Optional[Dict[str, Dict[int, Dict[int, dict]]]] = None) -> None:
    for label, by_seed in groups.items():
        x, m, lo, hi = band(by_seed, key)
        color, ls = (styles or {}).get(label, (None, "-"))
        (line,) = ax.plot(x, m, marker="o", ms=3, label=f"{label} (n={len(by_seed)})", color=color, linestyle=ls)
        ax.fill_between(x, lo, hi, color=line.get_color(), alpha=0.2)
    for label, by_seed in (reference or {}).items():
        x, m, _, _ = band(by_seed, key)
        ax.plot(x, m, color="black", alpha=0.5, linestyle=":", label=f"reference: {label} (n={len(by_seed)})")
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("environment steps")
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    if groups:
        ax.legend(fontsize=7)
    else:
        ax.text(0.5, 0.5, "no finished runs", ha="center", va="center", transform=ax.transAxes)


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_fig4(curves, path: Path, reference=None) -> bool:
    single = lambda r: r["role"] == "single" and r["experiment"] == "single"  # noqa: E731
    tasks = sorted({r["task"] for r in curves if single(r)}, key=lambda t: TASKS.index(t) if t in TASKS else 99)
    if not tasks:
        return False
    plt = _plt()
    fig, axes = plt.subplots(2, len(tasks), figsize=(4.8 * len(tasks), 7.5), squeeze=False)
    for j, task in enumerate(tasks):
        where = lambda r, t=task: single(r) and r["task"] == t  # noqa: E731
        g = curves_by(curves, where, lambda r: r["method"])
        ref = curves_by(reference, where, lambda r: r["method"]) if reference else None
        styles = {m: (color_of(m), "-") for m in g}
        draw(axes[0, j], g, "eval_success_rate", f"{task}: evaluation success", "success rate", styles, ref)
        draw(axes[1, j], g, "eval_return", f"{task}: evaluation return", "return per episode", styles, ref)
    fig.suptitle("Single-task learning (paper Fig. 4): mean over seeds, 95% t-interval band")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return True


def plot_fig5(curves, path: Path, reference=None) -> bool:
    adapt = [r for r in curves if r["role"] == "adapt" and r["experiment"] in ("transfer", "scratch", "ratios")]
    if not adapt:
        return False
    target = sorted({r["task"] for r in adapt}, key=lambda t: TASKS.index(t) if t in TASKS else 99)[-1]
    plt = _plt()
    main = lambda r: (r["task"] == target and r["role"] == "adapt"  # noqa: E731
                      and (r["experiment"] in ("transfer", "scratch")))
    lab = lambda r: r["method"] + (" from scratch" if r["experiment"] == "scratch" else "")  # noqa: E731
    g = curves_by(curves, main, lab)
    ref = curves_by(reference, main, lab) if reference else None
    styles = {k: (color_of(k.split()[0]), "--" if "scratch" in k else "-") for k in g}
    ratios = curves_by(curves, lambda r: r["task"] == target and r["role"] == "adapt" and r["experiment"] == "ratios",
                       lambda r: f"{r['method']} {r['arm']}")
    rstyles = {k: (color_of(k.split()[0], k.split()[1]), "-") for k in ratios}
    fig, axes = plt.subplots(2, 2, figsize=(11, 8.5))
    draw(axes[0, 0], g, "eval_success_rate", f"{target} adaptation: evaluation success", "success rate", styles, ref)
    # the prior without fine-tuning: its step-0 evaluation on the target (zero-shot), as a control line
    for label, by_seed in g.items():
        s0 = [rows[0]["eval_success_rate"] for rows in by_seed.values() if 0 in rows and "scratch" not in label]
        if s0:
            axes[0, 0].axhline(float(np.mean([float(v) for v in s0])), color=styles[label][0], linestyle=":",
                               alpha=0.8, label=f"{label} prior, zero-shot (step 0)")
    axes[0, 0].legend(fontsize=7)
    draw(axes[0, 1], g, "eval_return", f"{target} adaptation: evaluation return", "return per episode", styles, ref)
    draw(axes[1, 0], g, "train_successes", f"{target} adaptation: successful attempts (Table 5)",
         "successful training episodes (cumulative)", styles, ref)
    draw(axes[1, 1], ratios, "train_successes", f"{target} adaptation: sampling ratio P(R)/P(E) (Table 4)",
         "successful training episodes (cumulative)", rstyles)
    fig.suptitle(f"Multi-task transfer (paper Fig. 5): chain (solid) vs {target} from scratch (dashed); "
                 "dotted: the prior's step-0 score; mean over seeds, 95% t-interval band")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return True


def plot_ablations(curves, path: Path, experiments: Sequence[str]) -> bool:
    present = [e for e in experiments if any(r["experiment"] == e and r["role"] == "adapt" for r in curves)]
    if not present:
        return False
    plt = _plt()
    fig, axes = plt.subplots(2, len(present), figsize=(4.8 * len(present), 8), squeeze=False)
    for j, e in enumerate(present):
        where = lambda r, e=e: r["experiment"] == e and r["role"] == "adapt"  # noqa: E731
        g = curves_by(curves, where, lambda r: f"{r['method']} {r['arm']}")
        styles = {k: (color_of(*k.split(" ", 1)), "-") for k in g}
        draw(axes[0, j], g, "eval_success_rate", f"{e}: evaluation success", "success rate", styles)
        draw(axes[1, j], g, "train_successes", f"{e}: successful training episodes", "cumulative", styles)
    fig.suptitle("Ablations of the adaptation stage (same prior per method): mean over seeds, 95% t-interval band")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return True


def plot_aggregate(scores_rows, path: Path, metric: str = "mean_eval_success_rate") -> bool:
    """Across tasks, rliable style, from single-task scores: IQM and mean with stratified-bootstrap 95% CIs,
    the run-score performance profile, and the probability of improvement of each pair of methods."""
    from . import stats
    rows = [r for r in scores_rows if r["role"] == "single" and r["experiment"] == "single" and r["metric"] == metric]
    tasks = sorted({r["task"] for r in rows}, key=lambda t: TASKS.index(t) if t in TASKS else 99)
    methods = [m for m in METHOD_SPECS if any(r["method"] == m for r in rows)]
    vals: Dict[str, Dict[str, Dict[int, float]]] = defaultdict(lambda: defaultdict(dict))
    for r in rows:
        vals[r["method"]][r["task"]][int(r["seed"])] = float(r["value"])
    mats = {}
    for m in methods:
        seeds = sorted(set.intersection(*[set(vals[m][t]) for t in tasks])) if all(vals[m][t] for t in tasks) else []
        if len(seeds) >= 2:
            mats[m] = np.array([[vals[m][t][s] for t in tasks] for s in seeds])
    if len(mats) < 2:
        return False
    plt = _plt()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    names = list(mats)
    for k, (label, fn) in enumerate((("IQM", lambda x: stats.iqm(x, axis=1)), ("mean", lambda x: x.mean(axis=1)))):
        for j, m in enumerate(names):
            pt, lo, hi = stats.aggregate_ci(mats[m], fn)
            y = j + 0.18 * (1 - 2 * k)
            axes[0].errorbar(pt, y, xerr=[[pt - lo], [hi - pt]], fmt="o" if k == 0 else "s", color=color_of(m),
                             capsize=3, label=label if j == 0 else None, alpha=1.0 if k == 0 else 0.5)
    axes[0].set_yticks(range(len(names)), [METHOD_SPECS[m].display for m in names])
    if metric.endswith("rate"):
        axes[0].set_xlim(-0.02, 1.02)
    axes[0].set_xlabel(f"{metric} (o IQM, s mean; 95% stratified bootstrap CI)")
    axes[0].set_title(f"Aggregate over {len(tasks)} tasks", fontsize=10)
    taus = np.linspace(0, 1, 41)
    for m in names:
        axes[1].plot(taus, stats.performance_profile(mats[m], taus), color=color_of(m), label=METHOD_SPECS[m].display)
    axes[1].set_xlabel(f"threshold tau on {metric}")
    axes[1].set_ylabel("fraction of runs with score > tau")
    axes[1].set_title("Performance profile (all tasks and seeds)", fontsize=10)
    axes[1].legend(fontsize=7)
    pairs = [(a, b) for i, a in enumerate(names) for b in names[i + 1:]]
    for j, (a, b) in enumerate(pairs):
        p = np.mean([stats.prob_improvement(mats[a][:, t], mats[b][:, t]) for t in range(len(tasks))])
        axes[2].barh(j, p, color=color_of(a))
    axes[2].axvline(0.5, color="black", linestyle=":")
    axes[2].set_yticks(range(len(pairs)), [f"P({a} > {b})" for a, b in pairs], fontsize=8)
    axes[2].set_xlim(0, 1)
    axes[2].set_title("Probability of improvement (mean over tasks)", fontsize=10)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(f"Single-task learning across tasks, in rliable's style (n = {min(len(v) for v in mats.values())} "
                 "seeds per task)")
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return True
