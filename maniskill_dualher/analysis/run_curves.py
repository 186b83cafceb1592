"""One run's curves: ``python -m maniskill_dualher.report RUN`` on a run folder (``train --out``, or one run
folder of a sweep) draws what its ``metrics.csv`` and ``diagnostics.csv`` hold into ``RUN/curves.png`` (written
atomically) and prints a short summary: the final evaluation, the successful training episodes, the env steps.

Panels, each drawn only where the run's files hold its columns: evaluation success (and success at the episode's
end), evaluation return, training episodes (cumulative: all and successful), and per batch source (R, or R and E
for the dual buffer) the learner's critic loss, alpha, policy entropy, mean Q and |TD| (averaged between
evaluations, ``train.Diagnostics``), and the replay's rows. A sweep's figures and tables come from a sweep folder
(``analysis/report.py``); this is one run, no statistics over seeds. No torch is loaded.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import List, Optional, Sequence, Tuple

from .. import rundir
from ..config import ConfigError
from ..fileio import plural

FIGURE = "curves.png"
Q_PANEL = "Mean Q on the batches"   # drawn beside the most a return reaches (``return_bound``)
SOURCES = {"R": "R (all replay)", "E": "E (success buffer)"}
# (title, y label, [(column, label)] or a diagnostics stat, y range or None, log y)
EVAL_PANELS = (
    ("Evaluation success", "success rate (fraction of episodes)",
     [("eval_success_rate", "success in the episode"), ("eval_success_at_end", "success at its last step")], (0, 1)),
    ("Evaluation return", "mean return per episode", [("eval_return", "return")], None),
    ("Training episodes", "episodes (cumulative)",
     [("train_episodes", "all"), ("train_successes", "successful")], None),
)
DIAG_PANELS = (  # diagnostics.csv's stat -> (title, y label)
    ("qf_loss", "Critic loss", "loss (mean between evaluations)"),
    ("alpha", "Alpha (entropy coefficient)", "alpha"),
    ("entropy", "Policy entropy", "entropy (-log pi, nats)"),
    ("qf_values", Q_PANEL, "Q"),
    ("td_abs", "|TD error| on the batches", "|TD| (sum over the two critics)"),
)


def is_run_folder(folder: Path) -> bool:
    """A run folder (train's --out, or a sweep's run), not a sweep or results folder."""
    folder = Path(folder)
    return (folder / rundir.CONFIG).is_file() and not (folder / rundir.SWEEP).is_file()


def _value(row: dict, key: str) -> float:
    v = row.get(key, "")
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def _series(rows: Sequence[dict], key: str) -> Tuple[List[float], List[float]]:
    pts = [(_value(r, "env_steps"), _value(r, key)) for r in rows]
    pts = [(x, y) for x, y in pts if x == x and y == y]
    return [x for x, _ in pts], [y for _, y in pts]


def panels(metrics: Sequence[dict], diag: Sequence[dict]) -> List[dict]:
    """The panels this run's files fill: each a dict of title, ylabel, lines [(label, xs, ys, style)], ylim, log."""
    out = []
    for title, ylabel, cols, ylim in EVAL_PANELS:
        lines = [(label, *_series(metrics, c), "-" if i == 0 else "--") for i, (c, label) in enumerate(cols)]
        lines = [ln for ln in lines if ln[1]]
        if lines:
            out.append(dict(title=title, ylabel=ylabel, lines=lines, ylim=ylim, log=False))
    for stat, title, ylabel in DIAG_PANELS:
        lines = [(SOURCES.get(src, src), *_series(diag, f"{src}_{stat}"), "-" if src == "R" else "--")
                 for src in ("R", "E")]
        lines = [ln for ln in lines if ln[1]]
        if lines:
            positive = all(y > 0 for ln in lines for y in ln[2])
            out.append(dict(title=title, ylabel=ylabel, lines=lines, ylim=None,
                            log=positive and stat in ("qf_loss", "alpha", "td_abs")))
    first = metrics[0] if metrics else {}
    sizes = sorted((k for k in first if k.startswith("replay_") and k.endswith("size")),
                   key=lambda k: (k != "replay_size", k))  # every row first; a buffer apart (E: 100x fewer)
    for k in sizes:
        xs, ys = _series(metrics, k)
        part = k[len("replay_"):-len("size")].strip("_")
        if xs:
            out.append(dict(title="Replay rows" if not part else f"{SOURCES.get(part, part)} rows",
                            ylabel="rows stored", lines=[("rows", xs, ys, "-")], ylim=None, log=False))
    if "replay_frac_batches_from_R" in first:
        xs, ys = _series(metrics, "replay_frac_batches_from_R")
        if xs:
            out.append(dict(title="Batches drawn from R", ylabel="fraction of batches (cumulative)",
                            lines=[("from R", xs, ys, "-")], ylim=(0, 1), log=False))
    return out


def _title(cfg: dict, done: bool, steps: float) -> str:
    from ..methods import METHOD_SPECS
    spec = METHOD_SPECS.get(cfg.get("method", ""))
    method = spec.display if spec else cfg.get("method", "?")
    total = int(cfg.get("total_steps", 0) or 0)
    state = "finished" if done else f"unfinished: {int(steps):,} of {total:,} env steps"
    return (f"{method} on {cfg.get('env_id', '?')}, seed {cfg.get('seed', '?')} ({state}); "
            f"evaluation: {plural(int(cfg.get('eval_episodes', 0) or 0), 'episode')} every "
            f"{int(cfg.get('eval_every', 0) or 0):,} env steps")


def _symlog_ticks(ys: Sequence[float], bound: float) -> List[float]:
    """0 and the decades from ``bound`` out to the data on each side (none inside the linear part)."""
    k0 = math.floor(math.log10(bound) + 1e-9)   # 1/(1 - 0.99) is 99.99999999999991
    up = [10.0 ** k for k in range(k0, math.ceil(math.log10(max(max(ys), bound))) + 1)]
    low = min(ys)
    down = [-(10.0 ** k) for k in range(k0, math.ceil(math.log10(-low)) + 1)] if low < -bound else []
    return sorted(down) + [0.0] + up


def draw(folder: Path, path: Path) -> int:
    """``path`` (a PNG) from run folder ``folder``'s metrics.csv and diagnostics.csv; -> the panels drawn."""
    from matplotlib.ticker import NullLocator
    from .plots import _kilo, _plt, save_figure
    folder = Path(folder)
    cfg = rundir.read_json(folder / rundir.CONFIG) or {}
    metrics = rundir.read_metrics(folder)
    diag = rundir.read_metrics(folder, rundir.DIAGNOSTICS) if (folder / rundir.DIAGNOSTICS).is_file() else []
    ps = panels(metrics, diag)
    plt = _plt()
    ncol = 3 if len(ps) > 4 else 2
    nrow = -(-len(ps) // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.3 * ncol, 2.45 * nrow + 0.5), squeeze=False)
    for ax, p in zip(axes.ravel(), ps):
        for label, xs, ys, style in p["lines"]:
            ax.plot(xs, ys, style, marker="o", ms=2.5, lw=1.4, label=label, markevery=max(1, len(xs) // 16))
        ax.set_title(p["title"])
        ax.set_xlabel("environment steps")
        ax.set_ylabel(p["ylabel"])
        ax.grid(alpha=0.3)
        _kilo(ax)
        if p["ylim"]:
            ax.set_ylim(p["ylim"][0] - 0.03, p["ylim"][1] + 0.03)
        if p["log"]:
            ax.set_yscale("log")
        bound = return_bound(cfg) if p["title"] == Q_PANEL else None
        if bound is not None:
            ax.axhline(bound, color="0.35", ls=":", lw=1.2, label=f"1/(1 - gamma) = {bound:.4g}")
            ys = [y for ln in p["lines"] for y in ln[2]]
            if max(abs(y) for y in ys) > 10 * bound:
                ax.set_yscale("symlog", linthresh=bound)   # a diverged critic and the bound on one axis
                ax.set_yticks(_symlog_ticks(ys, bound))
                ax.yaxis.set_minor_locator(NullLocator())
                ax.set_ylim(bottom=min(min(ys), 0.0) - 0.2 * bound)
        if len(p["lines"]) > 1 or bound is not None:
            ax.legend(frameon=False, fontsize=7)
    for ax in axes.ravel()[len(ps):]:
        ax.remove()  # no empty panel
    steps = max((_value(r, "env_steps") for r in metrics), default=0.0)
    fig.suptitle(f"{folder.name}: {_title(cfg, rundir.is_done(folder), steps)}", fontsize=9.5)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return len(ps)


def summary(folder: Path) -> List[str]:
    """A few lines on the run: what it is, its final evaluation (its last, while unfinished), successful training
    episodes, env steps."""
    folder = Path(folder)
    cfg = rundir.read_json(folder / rundir.CONFIG) or {}
    rows = rundir.read_metrics(folder)
    last = rows[-1]
    steps, total = int(_value(last, "env_steps")), int(cfg.get("total_steps", 0) or 0)
    done = rundir.is_done(folder)
    ev = int(cfg.get("eval_episodes", 0) or 0)
    best = max(rows, key=lambda r: _value(r, "eval_success_rate"))  # the earliest of a tie, as policy_best.pt
    # a sweep's run resumes by its sweep's command (it wrote cell.json), train's own by `train --out` again
    resume = "rerun its sweep" if (folder / rundir.CELL).is_file() else "train again with the same --out"
    out = [f"{folder}: {cfg.get('method')} on {cfg.get('env_id')}, seed {cfg.get('seed')}, {steps:,} of {total:,} "
           f"env steps " + ("(finished)" if done else f"(unfinished: {resume} to resume)"),
           f"{'final' if done else 'last'} evaluation (env step {steps:,}, {plural(ev, 'episode')}): success "
           f"{_value(last, 'eval_success_rate'):.2f}, return {_value(last, 'eval_return'):.3g}",
           f"best evaluation: success {_value(best, 'eval_success_rate'):.2f} at env step "
           f"{int(_value(best, 'env_steps')):,}",
           f"successful training episodes: {int(_value(last, 'train_successes')):,} of "
           f"{int(_value(last, 'train_episodes')):,}"
           + (f"; {plural(int(_value(last, 'updates')), 'gradient update', thousands=True)}" if _value(last, "updates") == _value(
               last, "updates") else "")]
    diag = rundir.read_metrics(folder, rundir.DIAGNOSTICS) if (folder / rundir.DIAGNOSTICS).is_file() else []
    return out + critic_lines(cfg, rows, diag)


def return_bound(cfg: dict) -> Optional[float]:
    """The most a discounted return reaches where every reward is 0 or 1 (``reward_mode`` sparse): 1/(1 - gamma);
    None for other rewards. A soft value adds alpha x entropy per step (at most alpha d ln 2 for d action
    dimensions in [-1, 1]: 0.028 for the Panda's 8 at alpha 0.005), small beside it."""
    gamma = (cfg.get("sac") or {}).get("gamma")
    if cfg.get("reward_mode") != "sparse" or not isinstance(gamma, (int, float)) or not 0 <= gamma < 1:
        return None
    return 1.0 / (1.0 - gamma)


def critic_lines(cfg: dict, metrics: Sequence[dict], diag: Sequence[dict]) -> List[str]:
    """Where the critic's mean Q on its R batches went, beside what the rewards allow: a critic far above
    1/(1 - gamma) has diverged, whatever the successes say (results/paper_regime_critics: the paper regime's `step` runs)."""
    xs, ys = _series(diag, "R_qf_values")
    if not xs:
        return []
    i = max(range(len(ys)), key=ys.__getitem__)
    line = (f"critic, mean Q on its R batches (between evaluations): peak {ys[i]:.4g} at env step {int(xs[i]):,}, "
            f"last {ys[-1]:.4g}")
    bound = return_bound(cfg)
    if bound is not None:
        over = [x for x, y in zip(xs, ys) if abs(y) > bound]
        line += f"; rewards in {{0, 1}} bound a return by 1/(1 - gamma) = {bound:.4g}: "
        if not over:
            line += "|Q| never above it"
        else:
            def successes_at(step: float) -> int:
                below = [_value(r, "train_successes") for r in metrics if _value(r, "env_steps") <= step]
                return int(below[-1]) if below and below[-1] == below[-1] else 0
            total = successes_at(math.inf)
            line += (f"|Q| above it at {len(over)} of {len(xs)} points, first at env step {int(over[0]):,}, last at "
                     f"{int(over[-1]):,} (successful training episodes by the first: "
                     f"{successes_at(over[0]):,}; after the last: {total - successes_at(over[-1]):,})")
    return [line]


def report_run(folder: Path) -> Tuple[Path, List[str]]:
    """Draw ``folder/curves.png`` and return it with the summary lines; ConfigError where there is nothing to
    draw (no metrics.csv, or no evaluation in it yet)."""
    folder = Path(folder)
    if not (folder / rundir.METRICS).is_file() or not rundir.read_metrics(folder):
        raise ConfigError(f"{folder} is a run folder without an evaluation yet (no rows in {rundir.METRICS}): "
                          f"nothing to draw until its first evaluation")
    path = folder / FIGURE
    draw(folder, path)
    return path, summary(folder)


def main(folder: Path) -> int:
    import sys
    try:
        path, lines = report_run(folder)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for line in lines:
        print(line)
    print(f"wrote {path}")
    return 0

