"""Figures from ``curves.csv`` (one row per evaluation of a run, per cell) and ``scores.csv``, sized for a paper.

* Curves: the mean over seeds with a 95% percentile-bootstrap band over seeds (``mean_band``), at the
  evaluation points every seed of a curve has: a band of a success rate stays in [0, 1].
* Names: methods by their registry display name (``methods.METHOD_SPECS``), experiments by their registry
  title, arms by their registry display name (``registry.arm_display``): no internal arm key in a legend.
* Which rows a figure draws: the cells whose experiment or arm declares it in ``feeds`` (registry file names,
  ``fig5_multitask.png:ratio`` for Fig. 5's ratio panel); nothing is inferred from an experiment's shape.
* Colours: one per line (a method on an arm), the same in every figure, and no two lines of a figure alike
  (``color_of``): the paper treatment (an arm whose settings change nothing, in a chain or single-task
  experiment) in its method's registry colour (``MethodSpec.color``); its from-scratch twin (the control) in that
  colour darkened; any other arm in its arm's colour (``Arm.colour``, else ``ARM_PALETTE`` in registry order,
  keyed on its display, ``registry.colour_key``: an adaptation arm and its from-scratch twin share one), shaded
  per method (``MethodSpec.shade``: the paper's method the arm's colour itself). Line style and marker are the
  method's too (``MethodSpec.linestyle`` / ``marker``). Every figure carries its lines in its PNG metadata
  (``legend_data``: per axes, each line's name, label and colour), which ``tests/test_figures.py`` holds to this
  rule over every committed figure.
* Identical algorithms: an arm whose runs repeat another cell's algorithm bit for bit (``Arm.identical_to``) is
  drawn once, as that cell, with a note, where a figure draws both (two seed subsets of one algorithm would read
  as a difference).
* Many arms: an ablation with more than ``MAX_ARMS_ONE_PANEL`` arms of its own is split into columns of
  ``ARMS_PER_PANEL`` arms, each beside the same comparison lines (the paper's settings, each claim's other side).
* Size: no figure is taller than a printed page (``tests/test_report.py``); the ablations are one figure per
  experiment (``registry.fig6_file``), not one tall figure.
* Only what differs: success is shown, the evaluation return is not (sparse reward and episodes that end on
  success make them equal).

The report calls ``plot_fig4``, ``plot_fig5``, ``plot_ablation`` (once per ablation) and ``plot_aggregate``.
"""
from __future__ import annotations

import json
import textwrap
from collections import defaultdict
from pathlib import Path
from typing import Dict, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from ..config import TASKS
from ..experiment import registry
from ..experiment.registry import EXPERIMENTS, KINDS, PAPER_ARM, PAPER_CHAIN, is_paper_treatment
from ..fileio import atomic_write_with, steps_text
from ..methods import METHOD_SPECS
from . import stats
from .regime import RANDOM_ARM

SINGLE_KIND, CHAIN_KIND, SCRATCH_KIND = KINDS
LEVEL = 0.95
RESAMPLES = 2_000
DPI = 200
FONT = {"font.size": 9, "axes.titlesize": 9.5, "axes.labelsize": 9, "xtick.labelsize": 8, "ytick.labelsize": 8,
        "legend.fontsize": 8, "figure.titlesize": 10}
# Colours of arms other than the paper treatment and its from-scratch control, in registry order of their colour
# keys; the methods' own colours (tab:blue, tab:orange, tab:gray) left out. Ordered so that the arms of one figure
# (the registry's neighbours) differ: the ratios, then e_share's six (mechanism's twins share them), then the
# smaller experiments.
ARM_PALETTE = ("#1b9e77", "#e7298a", "#8c564b", "#e377c2", "#2ca02c", "#d62728", "#17becf",
               "#bcbd22", "#006400", "#b8860b", "#8b0000", "#191970", "#6b6ecf", "#ad494a", "#31a354",
               "#d6616b", "#8ca252", "#7b4173", "#a55194", "#3182bd", "#637939", "#e6550d", "#5254a3",
               "#b5cf6b", "#cedb9c", "#e7969c", "#de9ed6")
# A method's shade on a shared arm (MethodSpec.shade) where it declares none: the first level here no method
# declares, in registry order.
SHADE_LEVELS = (0.0, 0.45, -0.35, 0.7, -0.6, 0.25, -0.2, 0.85, -0.8, 0.15)
# The from-scratch control: its method's colour darkened by this fraction, so fig. 5 tells it from the transfer
# line in the method's own colour by colour, not by line style alone.
SCRATCH_DARKEN = 0.4
LEGEND_KEY = "Legend"   # the PNG text chunk holding a figure's lines (legend_data)


# --------------------------------------------------------------------------- names and colours (registry)
def method_label(method: str) -> str:
    spec = METHOD_SPECS.get(method)
    return spec.display if spec else method


def experiment_label(experiment: str) -> str:
    e = EXPERIMENTS.get(experiment)
    return e.title if e else experiment


def arm_label(experiment: str, arm: str) -> str:
    """The arm's display label (``registry.arm_display``)."""
    return registry.arm_display(experiment, arm)


def cell_label(experiment: str, arm: str, method: str) -> str:
    """A curve's legend label: the method's display name and the arm's."""
    return f"{method_label(method)}, {arm_label(experiment, arm)}"


def line_name(experiment: str, arm: str, method: str) -> str:
    """What a line is, whichever figure draws it and whatever its label there: its method and arm, the paper
    treatment of every chain or single-task experiment one line (fig. 5's "transfer", the 0.6/0.4 ratio). The
    key of its colour and of the figures' metadata (``legend_data``)."""
    arm_name = registry.PAPER_DISPLAY if is_paper_treatment(experiment, arm) else arm_label(experiment, arm)
    return f"{method_label(method)}, {arm_name}"


def _arm_colours() -> Dict[str, str]:
    """colour key (``registry.colour_key``) -> colour, in registry order."""
    out: Dict[str, str] = {}
    for e in EXPERIMENTS.values():
        for a in e.arms:
            key = registry.colour_key(e.name, a.name)
            if key not in out and not a.colour and not is_paper_treatment(e.name, a.name) \
                    and not registry.is_scratch_control(e.name, a.name):
                out[key] = ARM_PALETTE[len(out) % len(ARM_PALETTE)]
    for e in EXPERIMENTS.values():   # declared colours after the palette's: they take no palette slot
        out.update({registry.colour_key(e.name, a.name): a.colour for a in e.arms if a.colour})
    return out


def method_shade(method: str) -> float:
    """A method's shade (``MethodSpec.shade``, else the first free level of ``SHADE_LEVELS`` in registry order)."""
    declared = {s.shade for s in METHOD_SPECS.values() if s.shade is not None}
    free = iter([x for x in SHADE_LEVELS if x not in declared])
    for name, spec in METHOD_SPECS.items():
        level = spec.shade if spec.shade is not None else next(free, None)
        if level is None:
            raise ValueError(f"method {name!r}: every level of plots.SHADE_LEVELS is taken; declare its "
                             "MethodSpec(shade=...)")
        if name == method:
            return level
    return SHADE_LEVELS[0]


def _mix(colour: str, towards: str, fraction: float) -> str:
    from matplotlib.colors import to_hex, to_rgb
    c, t = np.array(to_rgb(colour)), np.array(to_rgb(towards))
    return to_hex(c + fraction * (t - c))


def shade(colour: str, amount: float) -> str:
    """``colour`` moved ``|amount|`` of the way towards contrast (white for a dark colour, black for a light one)
    where ``amount`` > 0, the other way where < 0; the colour itself at 0."""
    from matplotlib.colors import to_hex, to_rgb
    if amount == 0:
        return to_hex(colour)
    r, g, b = to_rgb(colour)
    dark = 0.299 * r + 0.587 * g + 0.114 * b < 0.5
    return _mix(colour, "white" if dark == (amount > 0) else "black", abs(amount))


def color_of(method: str, arm: str = PAPER_ARM, experiment: Optional[str] = None) -> str:
    """One colour per line (``line_name``) in every figure: the method's colour for its paper treatment (and
    without an experiment), darkened for its from-scratch control, else the arm's colour in the method's shade."""
    spec = METHOD_SPECS.get(method)
    own = spec.color if spec is not None else "black"
    if experiment is None or is_paper_treatment(experiment, arm):
        return own
    if registry.is_scratch_control(experiment, arm):
        return _mix(own, "black", SCRATCH_DARKEN)
    return shade(_arm_colours().get(registry.colour_key(experiment, arm), "black"), method_shade(method))


def style_of(method: str) -> Tuple[str, str]:
    """(line style, marker) of a method, its registry entry's (``MethodSpec.linestyle``, ``marker``): tells two
    methods of one arm apart."""
    spec = METHOD_SPECS.get(method)
    return (spec.linestyle, spec.marker) if spec is not None else (":", "D")


class Line(NamedTuple):
    """One curve of a figure: its runs (seed -> env step -> curve row), colour, style and what it is."""
    by_seed: Dict[int, Dict[int, dict]]
    color: str
    linestyle: object
    marker: str
    name: str   # line_name: its colour's key and its entry in the figure's metadata


def line_of(by_seed, experiment: str, arm: str, method: str) -> Line:
    return Line(by_seed, color_of(method, arm, experiment), *style_of(method), line_name(experiment, arm, method))


def paper_first(methods: Sequence[str]) -> List[str]:
    """``methods`` with the paper's (``MethodSpec.paper``) first, then the others in reverse registry order."""
    names = list(METHOD_SPECS)
    rank = {m: (not METHOD_SPECS[m].paper, -names.index(m)) for m in methods if m in METHOD_SPECS}
    return sorted(methods, key=lambda m: rank.get(m, (True, 1)))


# --------------------------------------------------------------------------- data
def legend_data(fig) -> dict:
    """What a figure draws, for a reader that cannot see it: its title, and per axes its title and every line
    named by ``line_name`` (its artist's gid): name, legend label, colour (hex)."""
    from matplotlib.colors import to_hex
    suptitle = getattr(fig, "_suptitle", None)
    return {"title": suptitle.get_text() if suptitle is not None else "",
            "axes": [{"title": ax.get_title(),
                      "lines": [dict(zip(("line", "label", "colour"), x)) for x in dict.fromkeys(
                          (ln.get_gid(), ln.get_label(), to_hex(ln.get_color())) for ln in ax.get_lines()
                          if ln.get_gid())]}   # once each: an error bar's caps share its gid
                     for ax in fig.axes]}


def read_legend_data(path: Path) -> Optional[dict]:
    """A PNG's ``legend_data`` (None where it holds none)."""
    from PIL import Image
    with Image.open(path) as im:
        text = getattr(im, "text", {}).get(LEGEND_KEY)
    return json.loads(text) if text else None


def save_figure(fig, path: Path) -> None:
    """The PNG, its lines in a text chunk (``legend_data``; ASCII JSON: a tEXt chunk, the same bytes every time)."""
    meta = {"Software": None, LEGEND_KEY: json.dumps(legend_data(fig), ensure_ascii=True, sort_keys=True)}
    atomic_write_with(path, lambda tmp: fig.savefig(tmp, format="png", dpi=DPI, bbox_inches="tight",
                                                     metadata=meta))


def curves_by(curves: Sequence[Dict[str, str]], where, key) -> Dict[tuple, Dict[int, Dict[int, dict]]]:
    """key(row) -> seed -> nominal env step -> curve row."""
    out: Dict[tuple, Dict[int, Dict[int, dict]]] = defaultdict(lambda: defaultdict(dict))
    for r in curves:
        if where(r):
            out[key(r)][int(r["seed"])].setdefault(int(r["env_steps"]), r)
    return out


def mean_band(by_seed: Dict[int, Dict[int, dict]], key: str):
    steps = sorted(set.intersection(*[set(v) for v in by_seed.values()]))
    if not steps:
        return np.array([]), np.array([]), np.array([]), np.array([])
    y = np.array([[float(by_seed[s][t][key]) for t in steps] for s in sorted(by_seed)])
    lo, hi = stats.boot_mean_ci(y, LEVEL, RESAMPLES)
    return np.array(steps), y.mean(axis=0), lo, hi


def _kilo(ax) -> None:
    """Env-step ticks as 0, 4k, 8k, ... or 0, 1M, 2M, ... (``fileio.steps_text``): at most 5 ticks, so long
    budgets never run together."""
    from matplotlib.ticker import FuncFormatter, MaxNLocator
    ax.xaxis.set_major_locator(MaxNLocator(nbins=5, steps=[1, 2, 2.5, 4, 5, 10]))
    ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: steps_text(v)))


def draw(ax, groups: Dict[str, Line], key: str, title: str, ylabel: str, rate: bool = False,
         reference: Optional[Dict[str, Dict[int, Dict[int, dict]]]] = None, with_n: bool = True) -> None:
    """``groups``: legend label -> ``Line``; ``with_n``: seeds in the label; ``reference``: legend label -> another
    folder's runs, drawn dotted in its line's colour."""
    for label, line in groups.items():
        x, m, lo, hi = mean_band(line.by_seed, key)
        # at most ~16 markers a curve: on a long curve, markers at every point hide its line style
        ax.plot(x, m, marker=line.marker, ms=2.5, lw=1.4, color=line.color, linestyle=line.linestyle,
                label=f"{label} (n={len(line.by_seed)})" if with_n else label, markevery=max(1, len(x) // 16),
                gid=line.name)
        ax.fill_between(x, lo, hi, color=line.color, alpha=0.15, lw=0)
    for label, by_seed in (reference or {}).items():
        x, m, _, _ = mean_band(by_seed, key)
        own = groups.get(label)
        ax.plot(x, m, color=own.color if own else "black", alpha=0.6, linestyle=":", lw=1,
                label=f"reference: {label} (n={len(by_seed)})", gid=own.name if own else None)
    ax.set_title(title)
    ax.set_xlabel("environment steps")
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    _kilo(ax)
    if rate:
        ax.set_ylim(-0.03, 1.03)
    if not groups:
        ax.text(0.5, 0.5, "no finished runs", ha="center", va="center", transform=ax.transAxes)


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    plt.rcParams.update(FONT)
    return plt


def _task_order(t: str) -> int:
    return TASKS.index(t) if t in TASKS else len(TASKS)


def _fed(figure: str):
    """A curve or score row's test: its cell (experiment, arm) feeds ``figure`` (registry ``feeds``)."""
    cells = set(registry.arms_feeding(figure))
    return lambda r: (r["experiment"], r["arm"]) in cells


def _transfer_experiments() -> List[str]:
    """The chain experiments of Fig. 5's main panels: the paper's transfer, whose paper arm holds the paper
    treatment's runs."""
    return [n for n in registry.experiments_feeding(registry.FIG5) if EXPERIMENTS[n].kind == CHAIN_KIND]


def _legend_below(fig, axes, ncol: int) -> None:
    """One legend for the figure, below it (labels of every panel, each once)."""
    seen: Dict[str, object] = {}
    for ax in np.ravel(axes):
        for h, lab in zip(*ax.get_legend_handles_labels()):
            seen.setdefault(lab, h)
    if seen:
        fig.legend(list(seen.values()), list(seen), loc="upper center", bbox_to_anchor=(0.5, 0.0), ncol=ncol,
                   frameon=False)


# --------------------------------------------------------------------------- Fig. 4
def plot_fig4(curves, path: Path, reference=None) -> bool:
    fed = _fed(registry.FIG4)
    single = lambda r: r["role"] == SINGLE_KIND and fed(r)  # noqa: E731
    tasks = sorted({r["task"] for r in curves if single(r)}, key=_task_order)
    if not tasks:
        return False
    plt = _plt()
    fig, axes = plt.subplots(1, len(tasks), figsize=(2.45 * len(tasks) + 0.3, 2.5), squeeze=False, sharey=True)
    for j, task in enumerate(tasks):
        where = lambda r, t=task: single(r) and r["task"] == t  # noqa: E731
        g = curves_by(curves, where, lambda r: (r["experiment"], r["arm"], r["method"]))
        groups = {method_label(k[2]): line_of(g[k], *k) for m in METHOD_SPECS for k in sorted(g) if k[2] == m}
        ref = {method_label(m): v for m, v in curves_by(reference, where, lambda r: r["method"]).items()} \
            if reference else None
        ns = sorted({len(v.by_seed) for v in groups.values()})
        draw(axes[0, j], groups, "eval_success_rate", f"{task} (n = {'/'.join(map(str, ns))} seeds)",
             "evaluation success rate" if j == 0 else "", rate=True, reference=ref, with_n=False)
    _legend_below(fig, axes, ncol=4)
    fig.suptitle("Single-task learning (paper Fig. 4): mean over seeds, 95% bootstrap band", y=1.02)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return True


# --------------------------------------------------------------------------- Fig. 5
def plot_fig5(curves, path: Path, reference=None) -> bool:
    fed_main, fed_ratios = _fed(registry.FIG5), _fed(registry.FIG5_RATIOS)
    scratch = [n for n in registry.experiments_feeding(registry.FIG5) if EXPERIMENTS[n].kind == SCRATCH_KIND]
    adapt = [r for r in curves if r["role"] == "adapt" and (fed_main(r) or fed_ratios(r))]
    if not adapt:
        return False
    target = sorted({r["task"] for r in adapt}, key=_task_order)[-1]
    chains = sorted({r["chain"] for r in adapt if r["task"] == target and " > " in r["chain"]})
    sources = chains[0].split(" > ")[:-1] if chains else list(PAPER_CHAIN[:-1])
    plt = _plt()
    main = lambda r: r["task"] == target and r["role"] == "adapt" and fed_main(r)  # noqa: E731
    g = curves_by(curves, main, lambda r: (r["experiment"], r["arm"], r["method"]))
    order = sorted(g, key=lambda k: (k[0] in scratch, list(METHOD_SPECS).index(k[2]) if k[2] in METHOD_SPECS else 9))
    label = lambda k: method_label(k[2]) + (", from scratch" if k[0] in scratch else ", transfer")  # noqa: E731
    groups = {label(k): line_of(g[k], *k) for k in order}
    ref = {label(k): v for k, v in curves_by(reference, main, lambda r: (r["experiment"], r["arm"], r["method"])).items()} \
        if reference else None
    ratios = curves_by(curves, lambda r: r["task"] == target and r["role"] == "adapt" and fed_ratios(r),
                       lambda r: (r["experiment"], r["arm"], r["method"]))
    rgroups = {f"{method_label(k[2])}, P(R)/P(E) = {arm_label(k[0], k[1]) if not is_paper_treatment(k[0], k[1]) else k[1]}":
               line_of(ratios[k], *k) for k in ratios}
    fig, axes = plt.subplots(1, 3, figsize=(10.5, 3.0))
    draw(axes[0], groups, "eval_success_rate", f"{target}: evaluation success", "success rate", rate=True,
         reference=ref)
    # the prior without fine-tuning: its step-0 evaluation on the target (zero-shot), as a control line
    for k in order:
        if k[0] in scratch:
            continue
        s0 = [rows[0]["eval_success_rate"] for rows in g[k].values() if 0 in rows]
        if s0:
            line = groups[label(k)]   # the step-0 value of this line: its colour and name
            axes[0].axhline(float(np.mean([float(v) for v in s0])), color=line.color, linestyle=":", lw=1,
                            alpha=0.9, label=f"{method_label(k[2])} prior, zero-shot (step 0)", gid=line.name)
    draw(axes[1], groups, "train_successes", f"{target}: successful training episodes",
         "cumulative (paper Table 5)", reference=ref)
    draw(axes[2], rgroups, "train_successes", f"{target}: sampling ratio (Table 4)", "cumulative")
    h, lab = axes[2].get_legend_handles_labels()
    axes[2].legend(h, lab, loc="upper left", frameon=False, fontsize=7.5)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="upper center", bbox_to_anchor=(0.36, 0.0), ncol=3,
               frameon=False)
    fig.suptitle(f"Multi-task transfer (paper Fig. 5): adaptation on {target} after "
                 f"{' > '.join(t.split('-')[0] for t in sources)}, vs from scratch\n"
                 "dotted: each prior's step-0 (zero-shot) score; mean over seeds, 95% bootstrap band", y=1.06)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return True


# --------------------------------------------------------------------------- Fig. 6
def _claim_cells(experiment: str) -> List[Tuple[str, str, str]]:
    """(experiment, arm, method) of every claim side compared with a side in ``experiment``."""
    from .claims import CLAIMS
    out = []
    for c in CLAIMS:
        sides = (c.a, c.b)
        if any(s.experiment == experiment for s in sides):
            out += [(s.experiment, s.arm, s.method) for s in sides if s.experiment != experiment]
    return list(dict.fromkeys(out))


def _paper_cells(experiment: str, methods: Sequence[str]) -> List[Tuple[str, str, str]]:
    """The paper treatment's cells (the default single-arm chain experiment) standing in for ``experiment``'s own
    paper-treatment arm, whose runs are shared with it and may be filed under that experiment only."""
    e = EXPERIMENTS[experiment]
    if not any(is_paper_treatment(experiment, a.name) for a in e.arms):
        return []
    return [(b, PAPER_ARM, m) for b in _transfer_experiments() for m in methods]


def _twin_cells(e: str, runs: Dict[Tuple[str, str, str], set]) -> List[Tuple[str, str, str]]:
    """For an arm of ``e`` without runs here, another experiment's arm of the same display (the same runs, e.g.
    budget's x4 and regime's long) and kind."""
    x = EXPERIMENTS.get(e)
    if x is None:
        return []
    have = {k[1] for k in runs if k[0] == e}
    keys = {registry.colour_key(e, a.name) for a in x.arms if a.name not in have and a.display}
    return [k for k in runs if k[0] != e and k[0] in EXPERIMENTS and EXPERIMENTS[k[0]].kind == x.kind
            and registry.colour_key(k[0], k[1]) in keys]


def _ablation_cells(e: str, runs: Dict[Tuple[str, str, str], set]) -> List[Tuple[str, str, str]]:
    own = [k for k in runs if k[0] == e]
    extra = _twin_cells(e, runs) + _paper_cells(e, sorted({k[2] for k in own})) + _claim_cells(e)
    cells, seen = [], []
    for k in own + [k for k in extra if k in runs]:
        if frozenset(runs[k]) not in seen:  # one set of runs is drawn once
            seen.append(frozenset(runs[k]))
            cells.append(k)
    names = list(METHOD_SPECS)

    def arm_order(k):
        x = EXPERIMENTS.get(k[0])
        arms = [a.name for a in x.arms] if x is not None else []
        return arms.index(k[1]) if k[1] in arms else len(arms)
    return sorted(cells, key=lambda k: (names.index(k[2]) if k[2] in names else 9, not is_paper_treatment(k[0], k[1]),
                                        k[0] != e, arm_order(k), k[1]))


ABLATION_SIZE = (7.0, 2.7)   # inches, the two panels; the legend below adds a line per one or two curves
LEGEND_TWO_COLUMNS = 48      # longest label (characters) that two legend columns fit within the figure's width
MAX_ARMS_ONE_PANEL = 3       # more arms of its own than this and an ablation's figure is split into columns
ARMS_PER_PANEL = 2           # a split figure's arms per column, beside its comparison lines
PANEL_SIZE = (3.1, 2.4)      # inches, one panel of a split figure


class AblationPlan(NamedTuple):
    adapt: List[dict]                      # the folder's adaptation curve rows
    cells: List[Tuple[str, str, str]]      # (experiment, arm, method) of every line, in legend order
    own: List[Tuple[str, str]]             # the experiment's arms drawn (a twin's cell standing in), not the paper's
    notes: List[str]                       # the arms drawn as another cell (Arm.identical_to)
    absent: List[str]                      # the experiment's arms with no runs in this folder (display names)


def _identical(cells: Sequence[Tuple[str, str, str]]) -> Dict[Tuple[str, str, str], Tuple[str, str, str]]:
    """cell -> the drawn cell whose algorithm it repeats bit for bit (``Arm.identical_to``)."""
    out = {}
    for k in cells:
        e = EXPERIMENTS.get(k[0])
        a = next((x for x in e.arms if x.name == k[1]), None) if e is not None else None
        if a is not None and tuple(a.identical_to) in cells:
            out[k] = tuple(a.identical_to)
    return out


def _ablation_plan(curves, experiment: str) -> Optional[AblationPlan]:
    """What an ablation's figure draws, or None where the folder has none of the experiment's adaptation runs."""
    adapt = [r for r in curves if r["role"] == "adapt"]
    if not any(r["experiment"] == experiment for r in adapt):
        return None
    runs: Dict[Tuple[str, str, str], set] = defaultdict(set)
    for r in adapt:
        runs[(r["experiment"], r["arm"], r["method"])].add(r["run"])
    cells = _ablation_cells(experiment, runs)
    same = _identical(cells)
    notes = [f'"{cell_label(*k)}" is "{cell_label(*t)}" bit for bit: drawn once, as the latter'
             for k, t in same.items()]
    e = EXPERIMENTS.get(experiment)
    key = lambda x, a: "paper" if is_paper_treatment(x, a) else registry.colour_key(x, a)  # noqa: E731
    drawn = {key(k[0], k[1]) for k in cells}
    absent = [arm_label(experiment, a.name) for a in (e.arms if e is not None else ())
              if key(experiment, a.name) not in drawn]
    cells = [k for k in cells if k not in same]
    twins = set(_twin_cells(experiment, runs))
    own = list(dict.fromkeys((k[0], k[1]) for k in cells
                             if (k[0] == experiment or k in twins) and not is_paper_treatment(k[0], k[1])))
    return AblationPlan(adapt, cells, own, notes, absent)


def undrawn_arms(curves, experiment: str) -> List[str]:
    """The display names of an ablation's arms its figure does not draw (no runs in this folder): summary.md
    names them beside the figure; its title does not."""
    plan = _ablation_plan(curves, experiment)
    return plan.absent if plan else []


def _columns(plan: AblationPlan) -> List[List[Tuple[str, str, str]]]:
    """The cells of each column: all of them, or, past ``MAX_ARMS_ONE_PANEL`` arms of the experiment's own,
    ``ARMS_PER_PANEL`` of those arms per column, each beside every comparison line."""
    if len(plan.own) <= MAX_ARMS_ONE_PANEL:
        return [list(plan.cells)]
    context = [k for k in plan.cells if (k[0], k[1]) not in plan.own]
    groups = [plan.own[i:i + ARMS_PER_PANEL] for i in range(0, len(plan.own), ARMS_PER_PANEL)]
    return [[k for k in plan.cells if k in context or (k[0], k[1]) in arms] for arms in groups]


def plot_ablation(curves, path: Path, experiment: str) -> bool:
    """One ablation experiment (``registry.fig6_file``): its arms, the paper treatment where the experiment has
    one, and each claim's comparison arm; evaluation success and cumulative successful training episodes. Arms
    by display name, one colour per line in every figure (the arms not drawn: ``undrawn_arms``, in summary.md);
    many arms: one column per ``ARMS_PER_PANEL`` of them (``_columns``)."""
    plan = _ablation_plan(curves, experiment)
    if plan is None:
        return False
    want = set(plan.cells)
    g = curves_by(plan.adapt, lambda r: (r["experiment"], r["arm"], r["method"]) in want,
                  lambda r: (r["experiment"], r["arm"], r["method"]))
    groups = {cell_label(*k): line_of(g[k], *k) for k in plan.cells}
    columns = _columns(plan)
    split = len(columns) > 1
    plt = _plt()
    if split:
        fig, axes = plt.subplots(2, len(columns), figsize=(PANEL_SIZE[0] * len(columns) + 0.4, 2 * PANEL_SIZE[1]),
                                 sharex=True, sharey="row", squeeze=False)
    else:
        fig, axes = plt.subplots(1, 2, figsize=ABLATION_SIZE, squeeze=False)
        axes = axes.T   # one column: evaluation success above, training episodes below
    # the random arm never updates, so its evaluation is its untouched prior's: not a curve of random actions
    chance = {cell_label(*k) for k in plan.cells if k[1] == RANDOM_ARM}
    for j, column in enumerate(columns):
        # drawn last to first, so the first listed (the paper's settings; a shorter budget, whose runs are the
        # first steps of a longer one's) lie on top; the legend keeps the listed order
        on_top = {lab: groups[lab] for lab in reversed([cell_label(*k) for k in column])}
        if split:
            # the figure's title says "without transfer" where it is so; the legend names each line in full
            arms = [arm_label(x, a).removesuffix(", from scratch") for x, a in plan.own
                    if any(k[:2] == (x, a) for k in column)]
            titles = ("\n".join(line for arm in arms for line in textwrap.wrap(arm, 46)), "")   # an arm a line
            ylabels = ("evaluation success", "successful training\nepisodes (cumulative)") if j == 0 else ("", "")
        else:
            titles, ylabels = ("evaluation success", "successful training episodes"), ("success rate", "cumulative")
        draw(axes[0, j], {k: v for k, v in on_top.items() if k not in chance}, "eval_success_rate", titles[0],
             ylabels[0], rate=True)
        draw(axes[1, j], on_top, "train_successes", titles[1], ylabels[1])
        if split and j:
            for ax in axes[:, j]:
                ax.tick_params(labelleft=False)
        if split:
            axes[0, j].set_xlabel("")
    seen: Dict[str, object] = {}
    for ax in np.ravel(axes):
        for h, lab in zip(*ax.get_legend_handles_labels()):
            seen.setdefault(lab, h)
    place = {lab: i for i, lab in enumerate(groups)}
    pairs = sorted(seen.items(), key=lambda lh: place.get(lh[0].rsplit(" (n=", 1)[0], len(place)))
    width = fig.get_size_inches()[0]
    ncol = 2 if max(len(x) for x in groups) <= LEGEND_TWO_COLUMNS * width / ABLATION_SIZE[0] else 1
    fig.legend([h for _, h in pairs], [lab for lab, _ in pairs], loc="upper center", bbox_to_anchor=(0.5, 0.0),
               ncol=ncol, frameon=False)
    title = experiment_label(experiment)
    note = "mean over seeds, 95% bootstrap band; line style: method" + (
        "; uniform-random actions: training episodes only" if chance else "") + (
        f"; {ARMS_PER_PANEL} arms per column" if split else "")
    fig.suptitle("\n".join([title, note] + [ln for n in plan.notes for ln in textwrap.wrap(n, 90)]), fontsize=9.5)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return True


# --------------------------------------------------------------------------- Fig. 7 (rliable style)
def _aggregate_row(axes, mats: Dict[str, np.ndarray], tasks: List[str], metric_name: str, rate: bool) -> None:
    names = paper_first(list(mats))  # the paper's method first: P(it > each other)
    names_of = {m: f"{method_label(m)}, {registry.PAPER_DISPLAY}" for m in names}   # each its paper treatment
    q = (1 - LEVEL) / 2
    # (1) IQM and mean with stratified-bootstrap CIs
    for k, (label, fn) in enumerate((("IQM", lambda x: float(stats.iqm(x))), ("mean", lambda x: float(x.mean())))):
        boots = stats.stratified_bootstrap(mats, fn, RESAMPLES, seed=k)
        for j, m in enumerate(names):
            pt = fn(mats[m])
            lo, hi = np.quantile(boots[m], [q, 1 - q])
            y = j + 0.15 * (1 - 2 * k)
            axes[0].errorbar(pt, y, xerr=[[pt - lo], [hi - pt]], fmt="o" if k == 0 else "s", color=color_of(m),
                             capsize=3, ms=5, mfc=color_of(m) if k == 0 else "white", gid=names_of[m])
    axes[0].set_yticks(range(len(names)), [method_label(m) for m in names])
    axes[0].set_ylim(-0.6, len(names) - 0.4)
    axes[0].set_xlabel(f"{metric_name}\n(filled: IQM, open: mean; 95% CI)")
    if rate:
        axes[0].set_xlim(-0.02, 1.02)
    # (2) performance profile with a bootstrap band
    hi_all = max(float(x.max()) for x in mats.values())
    taus = np.linspace(0, 1 if rate else hi_all * 1.02, 61)
    boots = stats.stratified_bootstrap(mats, lambda x: stats.performance_profile(x, taus), RESAMPLES, seed=2)
    for m in names:
        ls, _ = style_of(m)
        axes[1].plot(taus, stats.performance_profile(mats[m], taus), color=color_of(m), linestyle=ls,
                     label=method_label(m), gid=names_of[m])
        lo, hi = np.quantile(boots[m], [q, 1 - q], axis=0)
        axes[1].fill_between(taus, lo, hi, color=color_of(m), alpha=0.15, lw=0)
    axes[1].set_xlabel(f"threshold tau on {metric_name}")
    axes[1].set_ylabel("fraction of runs > tau")
    axes[1].legend(frameon=False)
    # (3) probability of improvement, mean over tasks, with a stratified-bootstrap CI (both sides resampled)
    pairs = [(a, b) for i, a in enumerate(names) for b in names[i + 1:]]
    rng = np.random.default_rng(3)
    for j, (a, b) in enumerate(pairs):
        p, lo, hi = stats.prob_improvement_ci(mats[a], mats[b], rng, RESAMPLES // 4, LEVEL)
        axes[2].errorbar(p, j, xerr=[[p - lo], [hi - p]], fmt="o", color=color_of(a), capsize=4, ms=6)
    axes[2].axvline(0.5, color="black", linestyle=":", lw=1)
    axes[2].set_yticks(range(len(pairs)), [f"P({method_label(a)}\n> {method_label(b)})" for a, b in pairs])
    axes[2].set_ylim(-0.6, len(pairs) - 0.4)
    axes[2].set_xlim(0, 1)
    axes[2].set_xlabel("probability of improvement (95% CI)")
    for ax in axes:
        ax.grid(alpha=0.3)


def _matrix(rows, keyfn, tasks) -> Tuple[Dict[str, np.ndarray], Dict[str, Dict[str, int]]]:
    """method -> (seeds all tasks share) x tasks; and method -> task -> seeds available."""
    vals: Dict[str, Dict[str, Dict[int, float]]] = defaultdict(lambda: defaultdict(dict))
    for r in rows:
        vals[keyfn(r)][r["task"]][int(r["seed"])] = float(r["value"])
    mats, avail = {}, {}
    for m in METHOD_SPECS:
        if m not in vals or not all(vals[m][t] for t in tasks):
            continue
        avail[m] = {t: len(vals[m][t]) for t in tasks}
        seeds = sorted(set.intersection(*[set(vals[m][t]) for t in tasks]))
        if len(seeds) >= 2:
            mats[m] = np.array([[vals[m][t][s] for t in tasks] for s in seeds])
    return mats, avail


def plot_aggregate(scores_rows, path: Path, metric: str = "mean_eval_success_rate") -> bool:
    """rliable style: IQM and mean with stratified-bootstrap 95% CIs, the performance profile with a bootstrap
    band, and the probability of improvement with a CI; top row: single-task runs across tasks (``metric``),
    bottom row: the headline adaptation claim's metric and cells (the first claim in ``claims.CLAIMS``)."""
    from .claims import CLAIMS
    fed = _fed(registry.FIG7)
    rows = [r for r in scores_rows if r["role"] == SINGLE_KIND and fed(r) and r["metric"] == metric]
    tasks = sorted({r["task"] for r in rows}, key=_task_order)
    mats, avail = _matrix(rows, lambda r: r["method"], tasks)
    head = CLAIMS[0]
    sides = {(s.experiment, s.arm, s.role, s.task) for s in (head.a, head.b)}
    hrows = [r for r in scores_rows if r["metric"] == head.metric
             and (r["experiment"], r["arm"], r["role"], r["task"]) in sides
             and r["method"] in (head.a.method, head.b.method)]
    hmats, _ = _matrix(hrows, lambda r: r["method"], [head.a.task])
    panels = [p for p in ((mats, tasks, metric, True), (hmats, [head.a.task], head.metric, False)) if len(p[0]) >= 2]
    if not panels:
        return False
    plt = _plt()
    fig, axes = plt.subplots(len(panels), 3, figsize=(10.5, 2.9 * len(panels)), squeeze=False)
    for i, (mm, tt, name, single_row) in enumerate(panels):
        rate = name.endswith("rate")
        _aggregate_row(axes[i], mm, tt, name.replace("_", " "), rate)
        n = min(x.shape[0] for x in mm.values())
        if single_row:
            have = ", ".join(f"{t.split('-')[0]} {max(avail[m][t] for m in mm)}" for t in tt)
            axes[i, 0].set_title(f"Single-task, {len(tt)} tasks: the {n} seeds every task has\n(seeds run: {have})",
                                 fontsize=8.5)
        else:
            ns = sorted({x.shape[0] for x in mm.values()})
            axes[i, 0].set_title(f"Headline adaptation claim ({head.key}): {tt[0]},\n"
                                 f"{' and '.join(map(str, ns))} seeds per method", fontsize=8.5)
        axes[i, 1].set_title("Performance profile, 95% bootstrap band", fontsize=8.5)
        axes[i, 2].set_title("Probability of improvement" + (" (mean over tasks)" if len(tt) > 1 else ""),
                             fontsize=8.5)
    fig.suptitle("Aggregates in rliable's style (stratified bootstrap over seeds)", y=1.01)
    fig.tight_layout()
    save_figure(fig, path)
    plt.close(fig)
    return True
