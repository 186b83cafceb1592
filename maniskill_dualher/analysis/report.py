"""The report: scores.csv and curves.csv from run folders, then every table, claim, figure and summary.md
from those two files alone (hyperparameters.csv from them and the sweep's definition, ``hyperparameters.py``).

    python -m maniskill_dualher.report runs/quick                       # a sweep folder with its runs
    python -m maniskill_dualher.report results/reference                # a committed folder: from its scores
    python -m maniskill_dualher.report runs/quick --reference results/reference   # overlay the reference
    python -m maniskill_dualher.report results/reference --merge runs/more        # add another sweep's cells

A folder with finished runs gets fresh ``scores.csv``/``curves.csv``; a folder without run folders is
rebuilt from the ones it holds (byte-identical tables and claims: no wall time, seeded statistics). The
report never replaces scores with fewer: where the folder's ``scores.csv`` names runs it cannot find, or
where there is nothing to build from, it refuses with one line and exit code 2, writing nothing.

``--merge OTHER`` adds another sweep's scores and curves to a results folder (one without run folders): only
cells (experiment, arm, method, task, seed, stage, role) the folder does not have yet, only from a sweep with
the same budgets and settings, each row keeping the machine it ran on; ``sweep.json`` lists what was merged.
"""
from __future__ import annotations

import sys
from pathlib import Path
from typing import Dict, List, Optional, Sequence

from .. import rundir
from ..cmdline import OneLineParser
from ..config import ConfigError
from ..experiment.registry import default_experiments  # plain data: no torch, no simulator
from ..fileio import atomic_write_text, csv_text, fmt
from . import budget as budget_mod
from . import diagnostics as diagnostics_mod
from . import claims as claims_mod
from . import hyperparameters, plots, plots_budget, stats
from .paper import PAPER_ADAPT_BUDGET, PAPER_ADAPT_STEPS
from .runs import (CURVE_COLUMNS, METRICS, SCORE_COLUMNS, curve_key, curve_rows, load_runs, read_rows,
                   score_key, score_rows, unique_rows)
from .tables import TABLE_COLUMNS, build_tables

SCORES, CURVES = "scores.csv", "curves.csv"


def _g(v) -> str:
    return fmt(float(f"{v:.3g}")) if isinstance(v, float) and v == v else fmt(v)


def claims_md(rows: List[dict]) -> List[str]:
    lines = ["| | claim (A > B) | paper | A vs B (mean over seeds, n) | A - B [95% CI] | P(A > B) | verdict | "
             "p, Holm (survives) |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "diff" not in r:
            lines.append(f"| {r['claim']} | {r['statement']} | {r['paper']} | | | | {r['verdict']} | |")
            continue
        holm = f"{_g(r['p_value'])}, {_g(r['p_holm'])}" if "p_holm" in r else ""
        if r.get("survives_holm"):
            holm += f" ({r['survives_holm']})"
        size = f"; ratio {_g(r['ratio'])} [{_g(r['ratio_ci95_low'])}, {_g(r['ratio_ci95_high'])}]: " \
               f"{r['paper_size']}" if r.get("paper_size") else ""
        p_imp = f"{r['prob_improvement']:.2f}" if "prob_improvement" in r else ""
        lines.append(f"| {r['claim']} | {r['statement']} | {r['paper']}{size} | {_g(r['mean_a'])} vs "
                     f"{_g(r['mean_b'])} (n = {r['n_a']}, {r['n_b']}) | {_g(r['diff'])} [{_g(r['diff_ci95_low'])}, "
                     f"{_g(r['diff_ci95_high'])}]{' paired' if r.get('paired') == 'yes' else ''} | "
                     f"{p_imp} | **{r['verdict']}** | {holm} |")
    return lines


def md_table(rows: List[dict], columns: List[str]) -> str:
    if not rows:
        return "_no finished runs_\n"
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(r.get(c)) for c in columns) + " |" for r in rows]
    return "\n".join(lines) + "\n"


FAMILY_TITLES = [f"{t} (`{g}`)" for g, t in claims_mod.FAMILIES.items()]


def summary_md(folder: Path, scores, tables, claims, figures: List[str], unfinished: List[str],
               budget_rows: Sequence[dict] = ()) -> str:
    sweep = rundir.read_sweep(folder) or {}
    runs = sorted({r["run"] for r in scores})
    s = [f"# Results: {folder.name}" + (f" (preset {sweep['preset']})" if sweep.get("preset") else ""), ""]
    s.append(f"{len(runs)} finished runs in `{SCORES}`"
             + (f"; {len(unfinished)} runs unfinished (not counted)" if unfinished else "") + ".")
    if sweep.get("budgets"):
        b = sweep["budgets"]
        s.append(f"Budgets (env steps): single-task {b['single']}; source stage {b['source']}; adaptation "
                 f"{b['adapt']} (paper's adaptation: {PAPER_ADAPT_BUDGET}; ours is "
                 f"{100 * max(b['adapt'].values()) / PAPER_ADAPT_STEPS:.2g}% of it).")
    s.append("Our tasks are ManiSkill3 re-creations of the RLBench ones and our budgets are far smaller: compare "
             "directions, not absolute counts.")
    if sweep.get("settings"):
        s.append(f"Settings given to this sweep: `{' '.join(sweep['settings'])}`.")
    for m in sweep.get("merged", []):
        s.append(f"Merged in (`report --merge`): {m['runs']} runs of the sweep `{m['folder']}` "
                 f"(experiments {', '.join(m['experiments'])}; run names prefixed `{m['folder']}/`).")
    machines: Dict[str, set] = {}
    for r in scores:
        machines.setdefault(r.get("machine") or "unknown", set()).add(r["experiment"])
    if machines:
        s.append("Machines (from each run's `provenance.json`; `machine` in `scores.csv`, `machines` in "
                 "`claims.csv`): " + "; ".join(f"{m}: {', '.join(sorted(e))}" for m, e in sorted(machines.items()))
                 + ".")
    s += ["", "Every table, claim and figure here is computed from `scores.csv` (one value per run and metric) and "
          "`curves.csv` (one row per evaluation): `python -m maniskill_dualher.report <this folder>` rebuilds them "
          "without the run folders.", ""]
    decided = [r for r in claims if claims_mod.decided(r)]
    tested = [r for r in claims if "diff" in r]
    s += ["## Verdicts (`claims.csv`)", "",
          "Each claim is 'A > B' (the paper's direction, or the ablation's question). Each side is one score "
          "per seed; the difference of means A - B gets a 95% interval (" + stats.CI_METHOD
          + ", `analysis/stats.py`; a Welch t interval beside it in `claims.csv`), and P(A > B) is the "
          "probability of improvement (Mann-Whitney, as in rliable). **reproduced / supported**: the interval "
          "excludes 0 in A's favour; **contradicted**: it excludes 0 the other way; **no difference larger than "
          f"X**: it lies within +-X (X = {claims_mod.RATE_MARGIN} for rates and returns, "
          f"{claims_mod.COUNT_MARGIN:.0%} of the larger mean for counts and env steps); **inconclusive** "
          "otherwise, with the seeds per side that would decide it at 80% power at the observed spread and "
          "difference. **paired**: decided on the seeds whose two sides adapted one prior (the same source-stage "
          "runs, or the same config and seed trained again with every recorded source-stage score equal), when "
          "they are at least half of the smaller side's seeds; the interval is on their per-seed differences.", "",
          "Verdicts are at 95% per claim. `p_value` is the two-sided p of A = B inverted from the same interval "
          "(the level at which it just reaches 0); within each family (" + "; ".join(FAMILY_TITLES)
          + ") it is adjusted by Holm (`p_holm`) and by Benjamini-Hochberg (`p_bh`). `survives_holm`: a decided "
          "verdict that still holds after Holm at 5% (an equivalence verdict: its own test, Bonferroni over the "
          "family); the last column below gives p, Holm's p and that answer. Where the paper gives a number "
          "(Tables 4, 5) the ratio of means A/B has a 95% interval (the ratios the same interval does not "
          "exclude) and `paper_size` says whether an effect of the paper's size is excluded in this setting; "
          "the paper reports one run per side, no spread.", "",
          f"{len(decided)} of {len(claims)} claims decided at 95%, "
          f"{sum(r.get('survives_holm') == 'yes' for r in claims)} of them after Holm within their family. "
          + (stats.multiplicity_note(len(tested)) if tested else ""), ""]
    unbalanced = [r["claim"] for r in claims if r.get("machine_balanced") == "no"]
    if unbalanced:
        s += ["Claims whose two sides are unbalanced by machine (a machine holds a different share of A's seeds "
              "than of B's; `machines_by_side` in `claims.csv`): " + ", ".join(unbalanced) + ".", ""]
    for group, title in (("paper", "The paper's claims"), ("ablation", "Why: ablations of the adaptation stage"),
                         ("updates", "Total updates vs R's share (defined before their runs, issue 39)"),
                         ("paper_regime", "The paper's own regime (preregistered, issue 41)")):
        rows = [r for r in claims if r["group"] == group]
        if rows:
            s += [f"### {title}", ""] + claims_md(rows) + [""]
    post = [r for r in claims if r.get("post_hoc")]
    if post:
        s += ["Defined after (some of) their data were seen (marked ‡ in the README; `post_hoc` in `claims.csv` "
              "names the commit), each replicated on the seeds run after that commit alone (`replication`): "
              + "; ".join(f"{r['claim']} ({r['post_hoc']}): {r['replication']}" for r in post) + ".", ""]
    why = [r for r in claims if r["group"] != "paper" and "diff" in r and claims_mod.explains(r["claim"])]
    if why:
        s += ["### Why the dual buffer's count differs: one sentence per ablation claim", ""]
        s += [f"- {claims_mod.explains(r['claim'])} {_g(r['diff'])} [{_g(r['diff_ci95_low'])}, "
              f"{_g(r['diff_ci95_high'])}] (`{r['metric']}`, n = {r['n_a']}, {r['n_b']}): **{r['verdict']}**"
              + (f", {'survives' if r['survives_holm'] == 'yes' else 'does not survive'} Holm"
                 if r.get("survives_holm") else "") + f" (claim {r['claim']})." for r in why] + [""]
    if budget_rows:
        s += ["## The budget curve (`budget.csv`)", "",
              "The adaptation at several budgets (factor x the adaptation budget): the ratio of mean successful "
              "adaptation episodes, dual buffer / SAC+HER+PER, with its 95% interval, and the difference in final "
              "evaluation success (dual buffer - SAC+HER+PER) with its 95% interval (`analysis/budget.py`). "
              + budget_mod.order_sentence(budget_rows), "",
              md_table(budget_rows, budget_mod.BUDGET_COLUMNS)]
    cols = ["experiment", "arm", "task", "method", "variant", "metric", "n_seeds", "mean", "std", "ci95_low",
            "ci95_high", "paper"]
    for name, title in (("table5_multitask.csv", "Table 5: transfer and scratch, adaptation stage"),
                        ("table4_sampling_ratio.csv", "Table 4: dual buffer sampling ratio, adaptation stage"),
                        ("ablations.csv", "Ablations, adaptation stage"),
                        ("single_task.csv", "Single-task learning (paper Fig. 4 gives curves only)")):
        if tables[name]:
            s += [f"## {title} (`{name}`)", "", md_table(tables[name], cols)]
    s += ["## Metrics", ""] + [f"- `{m}`: {doc}" for m, (_, doc) in METRICS.items()] + [""]
    s += ["## Figures", ""] + [f"![{f}]({f})" for f in figures] + [""]
    if unfinished:
        s += ["## Unfinished runs (not counted)", ""] + [f"- {u}" for u in unfinished] + [""]
    return "\n".join(s)


MERGE_SAME = ("preset", "budgets", "preset_settings", "settings", "task_order", "carry_replay")
CELL_ID = ("experiment", "arm", "method", "task", "seed", "stage", "role")


def merge_into(folder: Path, other: Path) -> None:
    """Add ``other``'s scores and curves (cells ``folder`` lacks) to ``folder``; refuse anything ambiguous."""
    folder, other = Path(folder), Path(other)
    for f in (folder, other):
        if not ((f / SCORES).is_file() and (f / CURVES).is_file()):
            raise ConfigError(f"--merge needs {SCORES} and {CURVES} in {f} (run the report on it first)")
    if (folder / rundir.RUNS_DIR).is_dir():
        raise ConfigError(f"{folder} holds run folders: merge into a results folder built from scores alone")
    mine, theirs = rundir.read_sweep(folder) or {}, rundir.read_sweep(other) or {}
    differ = [k for k in MERGE_SAME if mine.get(k) != theirs.get(k)]
    if differ:
        raise ConfigError(f"{other} is a sweep with other {differ[0]} than {folder}: its cells would not compare")
    scores, new = read_rows(folder / SCORES), read_rows(other / SCORES)
    have = {tuple(r[k] for k in CELL_ID) for r in scores}
    clash = sorted({tuple(r[k] for k in CELL_ID) for r in new} & have)
    if clash:
        raise ConfigError(f"{folder} already has cell {'/'.join(clash[0])} that {other} also has; "
                          f"merge only new cells (e.g. run the sweep with other --experiments)")
    if not new:
        raise ConfigError(f"{other / SCORES} holds no scores")
    prefix = other.name + "/"
    curves = read_rows(folder / CURVES) + [{**r, "run": prefix + r["run"]} for r in read_rows(other / CURVES)]
    scores += [{**r, "run": prefix + r["run"]} for r in new]
    merged = list(mine.get("merged", [])) + [{
        "folder": other.name, "experiments": theirs.get("experiments", []),
        "runs": len({r["run"] for r in new}), "machines": sorted({r.get("machine", "") for r in new} - {""})}]
    atomic_write_text(folder / SCORES, csv_text(scores, SCORE_COLUMNS))
    atomic_write_text(folder / CURVES, csv_text(curves, CURVE_COLUMNS))
    rundir.write_json(folder / rundir.SWEEP, {**mine, "merged": merged})


def _read_unique(folder: Path, written: List[Path]):
    """scores.csv and curves.csv, each row once (``runs.unique_rows``); a file that held repeats (written
    before a run's cells were made unique) is rewritten without them, so the next rebuild reads it as is."""
    files = ((SCORES, score_key, SCORE_COLUMNS), (CURVES, curve_key, CURVE_COLUMNS))
    read = [read_rows(folder / name) for name, _, _ in files]
    try:  # both checked before either is rewritten
        unique = [unique_rows(rows, key, str(folder / name)) for rows, (name, key, _) in zip(read, files)]
    except ValueError as e:
        raise ConfigError(str(e)) from None
    for rows, kept, (name, _, columns) in zip(read, unique, files):
        if len(kept) < len(rows):
            atomic_write_text(folder / name, csv_text(kept, columns))
            if folder / name not in written:
                written.append(folder / name)
    return unique


def build_report(folder, resamples: int = 10_000, reference: Optional[Path] = None) -> List[Path]:
    """Write scores/curves (from runs), then tables, claims, plots and summary.md; return the paths written."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(f"no such folder: {folder}")
    runs, unfinished = load_runs(folder)
    unfinished = [u for u in unfinished if (folder / u).is_dir()]  # a folder shipped without its runs has none
    written: List[Path] = []
    old_scores = read_rows(folder / SCORES) if (folder / SCORES).is_file() else None
    if runs:
        new_scores = score_rows(runs)
        if old_scores is not None:
            missing = sorted(r for r in {r["run"] for r in old_scores} - {r["run"] for r in new_scores}
                             if not (folder / r).is_dir())  # runs whose folders are gone (a shipped folder)
            if missing:
                raise ConfigError(f"{folder / SCORES} holds {len(missing)} runs this folder no longer has "
                                  f"(e.g. {missing[0]}); refusing to replace it with less")
        atomic_write_text(folder / SCORES, csv_text(new_scores, SCORE_COLUMNS))
        atomic_write_text(folder / CURVES, csv_text(curve_rows(runs), CURVE_COLUMNS))
        written += [folder / SCORES, folder / CURVES]
    elif old_scores is None or not (folder / CURVES).is_file():
        raise ConfigError(f"{folder} holds no finished runs and no {SCORES}/{CURVES}: nothing to report "
                          f"({len(unfinished)} unfinished runs)")
    # everything below reads the two files back, so a rebuild without run folders is byte-identical
    scores, curves = _read_unique(folder, written)
    sweep = rundir.read_sweep(folder)
    if sweep:  # from the definition and the registry, so a folder without run folders gets it too
        hp = hyperparameters.hyperparameter_rows(hyperparameters.cell_configs(sweep, scores))
        atomic_write_text(folder / "hyperparameters.csv", csv_text(hp, hyperparameters.COLUMNS))
        written.append(folder / "hyperparameters.csv")
    ref_curves = None
    if reference is not None:
        if not (Path(reference) / CURVES).is_file():
            raise ConfigError(f"--reference {reference} holds no {CURVES}")
        ref_curves = read_rows(Path(reference) / CURVES)
    tables = build_tables(scores, default_experiments())
    for name, rows in tables.items():
        atomic_write_text(folder / name, csv_text(rows, TABLE_COLUMNS))
        written.append(folder / name)
    claims = claims_mod.claim_rows(scores, resamples)
    atomic_write_text(folder / "claims.csv", csv_text(claims, claims_mod.CLAIM_COLUMNS))
    written.append(folder / "claims.csv")
    budget_rows = budget_mod.budget_rows(scores, resamples)
    if budget_rows:
        atomic_write_text(folder / "budget.csv", csv_text(budget_rows, budget_mod.BUDGET_COLUMNS))
        written.append(folder / "budget.csv")
    diag_rows = diagnostics_mod.diagnostic_rows(scores)
    if diag_rows:
        atomic_write_text(folder / "diagnostics.csv", csv_text(diag_rows, diagnostics_mod.COLUMNS))
        written.append(folder / "diagnostics.csv")
    figures = []
    ablations = [e for e in dict.fromkeys(r["experiment"] for r in scores) if e not in default_experiments()]
    for name, fn in (("fig4_single_task.png", lambda p: plots.plot_fig4(curves, p, ref_curves)),
                     ("fig5_multitask.png", lambda p: plots.plot_fig5(curves, p, ref_curves)),
                     ("fig6_ablations.png", lambda p: plots.plot_ablations(curves, p, ablations)),
                     ("fig7_aggregate.png", lambda p: plots.plot_aggregate(scores, p)),
                     ("fig8_budget.png", lambda p: plots_budget.plot_budget(budget_rows, p))):
        if fn(folder / name):
            figures.append(name)
            written.append(folder / name)
    atomic_write_text(folder / "summary.md", summary_md(folder, scores, tables, claims, figures, unfinished,
                                                               budget_rows))
    written.append(folder / "summary.md")
    return written


def main(argv: Optional[Sequence[str]] = None) -> int:
    p = OneLineParser(prog="python -m maniskill_dualher.report",
                      description="Rebuild scores, tables (CSV), claims, plots (PNG) and summary.md of a sweep folder "
                                  "from its run folders, or from its scores.csv/curves.csv; no training.")
    p.add_argument("folder", help="a sweep's --out folder (e.g. runs/quick) or a committed results folder")
    p.add_argument("--reference", help="another results folder whose curves are drawn beside these (dotted)")
    p.add_argument("--merge", metavar="OTHER", help="first add another sweep folder's scores/curves (new cells only, "
                                                   "same budgets and settings) to FOLDER, a results folder")
    p.add_argument("--resamples", type=int, default=10_000, help="bootstrap resamples (default: %(default)s)")
    a = p.parse_args(argv)
    try:
        if a.resamples < 100:
            raise ConfigError(f"--resamples must be >= 100, got {a.resamples}")
        if a.merge:
            merge_into(Path(a.folder), Path(a.merge))
        written = build_report(Path(a.folder), a.resamples, Path(a.reference) if a.reference else None)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for w in written:
        print(w)
    return 0


if __name__ == "__main__":
    sys.exit(main())
