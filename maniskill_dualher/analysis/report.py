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
The same ``--merge`` again says in one line that the folder holds those runs and is complete, and writes nothing.

A report (a merge included) is written as one (``staging.py``): built in full in a staging folder, then
swapped in, so killed at any moment the folder holds its old files or the new ones, and the next report on
it (the same command again, or any) first finishes or undoes what was cut.
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence

from .. import rundir
from ..cmdline import OneLineParser, missing_package
from ..config import ConfigError
from ..experiment import registry  # plain data: no torch, no simulator
from ..fileio import atomic_write_text, csv_text, fmt, plural
from ..staging import Staged, kill_point
from . import budget as budget_mod
from . import diagnostics as diagnostics_mod
from . import regime as regime_mod
from . import claims as claims_mod
from . import hyperparameters, plots, plots_budget, run_curves, stats
from .paper import PAPER_ADAPT_BUDGET, PAPER_ADAPT_STEPS
from .runs import (CURVE_COLUMNS, METRICS, SCORE_COLUMNS, curve_key, curve_rows, load_runs, read_rows,
                   score_key, score_rows, unique_rows)
from .tables import TABLE_COLUMNS, build_tables

SCORES, CURVES = "scores.csv", "curves.csv"


def _g(v) -> str:
    return fmt(float(f"{v:.3g}")) if isinstance(v, float) and v == v else fmt(v)


def _ci(r: dict) -> str:
    """A claim's interval as "[low, high]", or what stands in its place where none was computed."""
    lo, hi = float(r["diff_ci95_low"]), float(r["diff_ci95_high"])
    return f"[{_g(lo)}, {_g(hi)}]" if lo == lo and hi == hi else "(no interval)"


def claims_md(rows: List[dict]) -> List[str]:
    lines = ["| | claim (A > B) | paper | A vs B (mean over seeds, n) | A - B [95% CI] | P(A > B) | verdict | "
             "p, Holm (survives) |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:   # measured claims only: summary_md names the others under their family
        holm = f"{_g(r['p_value'])}, {_g(r['p_holm'])}" if "p_holm" in r else ""
        if r.get("survives_holm"):
            holm += f" ({r['survives_holm']})"
        size = f"; ratio {_g(r['ratio'])} [{_g(r['ratio_ci95_low'])}, {_g(r['ratio_ci95_high'])}]: " \
               f"{r['paper_size']}" if r.get("paper_size") else ""
        p_imp = f"{r['prob_improvement']:.2f}" if "prob_improvement" in r else ""
        lines.append(f"| {r['claim']} | {r['statement']} | {r['paper']}{size} | {_g(r['mean_a'])} vs "
                     f"{_g(r['mean_b'])} (n = {r['n_a']}, {r['n_b']}) | {_g(r['diff'])} {_ci(r)}"
                     f"{' paired' if r.get('paired') == 'yes' else ''} | "
                     f"{p_imp} | **{r['verdict']}** | {holm} |")
    return lines


def md_table(rows: List[dict], columns: List[str]) -> str:
    if not rows:
        return "_no finished runs_\n"
    lines = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    lines += ["| " + " | ".join(fmt(r.get(c)) for c in columns) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def adapt_budgets(curves: Sequence[dict]) -> Dict[tuple, int]:
    """(experiment, arm) -> the adaptation env steps its runs reached (the smallest over its runs' last
    evaluations): the budget as run, whatever the preset said."""
    last: Dict[tuple, Dict[str, int]] = {}
    for r in curves:
        if r.get("role") == "adapt":
            d = last.setdefault((r["experiment"], r["arm"]), {})
            d[r["run"]] = max(d.get(r["run"], 0), int(float(r["env_steps"])))
    return {k: min(v.values()) for k, v in last.items()}


FAMILY_TITLES = [f"{t} (`{g}`)" for g, t in claims_mod.FAMILIES.items()]
# summary.md's section of a claims family; a family not named here gets its FAMILIES description
SECTION_TITLES = {"paper": "The paper's claims", "ablation": "Why: ablations of the adaptation stage",
                  "updates": "Total updates vs R's share (defined before their runs)",
                  "paper_regime": "The paper's own regime (preregistered)",
                  "relatives": "The dual buffer's relatives (defined before their runs)"}


def _per_task(budgets) -> str:
    """{'CloseBox-v1': 6000, ...} as "CloseBox-v1 6,000, ..." (a preset's budget per task)."""
    if not isinstance(budgets, dict):
        return str(budgets)
    return ", ".join(f"{t} {n:,}" if isinstance(n, int) else f"{t} {n}" for t, n in budgets.items())


def summary_md(name: str, sweep: Optional[dict], scores, tables, claims, figures: List[str], unfinished: List[str],
               budget_rows: Sequence[dict] = (), regime_rows: Sequence[dict] = (), curves: Sequence[dict] = ()) -> str:
    sweep = sweep or {}
    runs = sorted({r["run"] for r in scores})
    s = [f"# Results: {name}" + (f" (preset {sweep['preset']})" if sweep.get("preset") else ""), ""]
    s.append(f"{plural(len(runs), 'finished run')} in `{SCORES}`"
             + (f"; {plural(len(unfinished), 'run')} unfinished (not counted)" if unfinished else "") + ".")
    ran = adapt_budgets(curves)
    if sweep.get("budgets"):
        b = sweep["budgets"]
        s.append(f"The preset's default budgets (env steps"
                 + ("; an arm's settings may override them: as run on the next line" if ran else "")
                 + f"): single-task {_per_task(b['single'])}; source stage {_per_task(b['source'])}; "
                 f"adaptation {_per_task(b['adapt'])}.")
    if ran:
        by_n: Dict[int, List[str]] = {}
        for (e, a), n in sorted(ran.items()):
            by_n.setdefault(n, []).append(f"{e}/{a}")
        s.append("Adaptation budgets as run (each arm's runs' last evaluation in `curves.csv`; an arm's settings "
                 "may set its own): " + "; ".join(f"{n:,} env steps, {100 * n / PAPER_ADAPT_STEPS:.3g}% of the "
                                                  f"paper's ({', '.join(arms)})" for n, arms in sorted(by_n.items()))
                 + f". The paper's adaptation: {PAPER_ADAPT_BUDGET}.")
    s.append("Our tasks are ManiSkill3 re-creations of the RLBench ones" + (
        " and our budgets are far smaller" if not ran or min(ran.values()) < PAPER_ADAPT_STEPS else "")
        + ": compare directions, not absolute counts.")
    if sweep.get("settings"):
        s.append(f"Settings given to this sweep: `{' '.join(sweep['settings'])}`.")
    merged = sweep.get("merged", [])
    if merged:
        s.append(f"{len(merged)} sweeps merged in (listed at the end).")
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
    measured = [r for r in claims if claims_mod.measured(r)]
    missing = len(claims) - len(measured)   # claims whose runs this folder does not hold
    # the claims Holm adjusts: those with a finite p-value (none below MIN_SEEDS per side or MIN_PAIRS pairs)
    tested = [r for r in claims if claims_mod.has_p(r)]
    untested = [r for r in measured if not claims_mod.has_p(r)]
    s += ["## Verdicts (`claims.csv`)", "",
          "Each claim is 'A > B' (the paper's direction, or the ablation's question). Each side is one score "
          "per seed; the difference of means A - B gets a 95% interval (" + stats.CI_METHOD
          + ", `analysis/stats.py`; beside it in `claims.csv` the two-sample Welch t interval, which ignores "
          "any pairing, and for paired claims two sensitivity analyses that never set the verdict: the paired t "
          "interval and an exact sign-flip permutation p; no paired interval below 5 pairs), and P(A > B) is the "
          "probability of improvement (Mann-Whitney, as in rliable). **reproduced / supported**: the interval "
          "excludes 0 in A's favour; **contradicted**: it excludes 0 the other way; **no difference larger than "
          f"X**: it lies within +-X (X = {claims_mod.RATE_MARGIN} for rates and returns, "
          f"{claims_mod.COUNT_MARGIN:.0%} of the larger mean for counts and env steps); **uninformative**: it "
          "lies within +-X but both sides' means are below X, so no difference that large could appear (a "
          "floor; not counted as decided); **inconclusive** otherwise, with the seeds per side (paired: the "
          "pairs, by the exact paired t power) that would decide it at 80% power at the observed spread and "
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
          " ".join([f"{len(decided)} of {plural(len(measured), 'measured claim')} decided at 95%, "
                    f"{sum(r.get('survives_holm') == 'yes' for r in claims)} of them after Holm within their family"
                    + (f"; {missing} more {'is' if missing == 1 else 'are'} not measured here (no runs for "
                       f"{'it' if missing == 1 else 'them'} in this folder; listed below each family's table)"
                       if missing else "") + "."]
                   + ([stats.multiplicity_note(len(tested))] if tested else [])
                   + ([f"{plural(len(untested), 'measured claim')} {'has' if len(untested) == 1 else 'have'} no "
                       f"interval (too few seeds or pairs), hence no p-value, and {'is' if len(untested) == 1 else 'are'}"
                       f" left out of Holm: {', '.join(r['claim'] for r in untested)}."] if untested else [])), ""]
    unbalanced = [r["claim"] for r in claims if r.get("machine_balanced") == "no"]
    if unbalanced:
        s += ["Claims whose two sides are unbalanced by machine (a machine holds a different share of A's seeds "
              "than of B's; `machines_by_side` in `claims.csv`): " + ", ".join(unbalanced) + ".", ""]
    for group, family in claims_mod.FAMILIES.items():   # every family, one a recipe added included
        title = SECTION_TITLES.get(group, family[:1].upper() + family[1:])
        rows = [r for r in claims if r["group"] == group]
        shown = [r for r in rows if claims_mod.measured(r)]   # a folder holds some experiments: the rest by name
        absent = [r["claim"] for r in rows if not claims_mod.measured(r)]
        if shown:
            s += [f"### {title}", ""] + claims_md(shown) + [""]
        if absent:
            s += ([] if shown else [f"### {title}", ""]) + [
                f"Not measured here (no runs for {'it' if len(absent) == 1 else 'them'} in this folder): "
                + ", ".join(absent) + ".", ""]
    post = [r for r in claims if r.get("post_hoc")]
    if post:
        s += ["Defined after (some of) their data were seen (marked ‡ in the README; `post_hoc` in `claims.csv` "
              "names the commit), each with its replication on the seeds run after that commit (`replication`, with "
              "what keeps it from being independent, where something does): "
              + "; ".join(f"{r['claim']} ({r['post_hoc']}): {r['replication']}" for r in post) + ".", ""]
    s += regime_mod.summary_lines(regime_rows) + regime_mod.sequential_lines(curves)
    why = [r for r in measured if r["group"] != "paper" and claims_mod.explains(r["claim"])]
    if why:
        s += ["### Why the dual buffer's count differs: one sentence per ablation claim", ""]
        s += [f"- {claims_mod.explains(r['claim'])} {_g(r['diff'])} {_ci(r)} "
              f"(`{r['metric']}`, n = {r['n_a']}, {r['n_b']}): **{r['verdict']}**"
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
    undrawn = [(f, plots.undrawn_arms(curves, e)) for e in registry.experiments_feeding(registry.FIG6)
               for f in [registry.fig6_file(e)] if f in figures]
    undrawn = [(f, arms) for f, arms in undrawn if arms]
    if undrawn:
        s += ["Arms an ablation figure does not draw (no runs in this folder):", ""] + [
            f"- `{f}`: " + "; ".join(f'"{a}"' for a in arms) for f, arms in undrawn] + [""]
    if merged:  # where the rows came from, after the results
        s += ["## Sweeps merged in (`report --merge`)", ""] + [
            f"- {plural(m['runs'], 'run')} of the sweep `{m['folder']}` (experiments {', '.join(m['experiments'])}; run names "
            f"prefixed `{m['folder']}/`)." for m in merged] + [""]
    if unfinished:
        s += ["## Unfinished runs (not counted)", ""] + [f"- {u}" for u in unfinished] + [""]
    return "\n".join(s)


MERGE_SAME = ("preset", "budgets", "preset_settings", "settings", "task_order", "carry_replay")
CELL_ID = ("experiment", "arm", "method", "task", "seed", "stage", "role")


def merge_into(folder: Path, other: Path, into: Optional[Path] = None) -> Optional[int]:
    """Add ``other``'s scores and curves (cells ``folder`` lacks) to ``folder`` (read from and written to
    ``into``, its staged copy, where given); refuse anything ambiguous. Returns None, or the number of
    ``other``'s runs when ``folder`` holds every one of its rows already (merged before): then writes nothing."""
    folder, other = Path(folder), Path(other)
    into = Path(into) if into is not None else folder
    for f, at in ((folder, into), (other, other)):
        if not ((at / SCORES).is_file() and (at / CURVES).is_file()):
            raise ConfigError(f"--merge needs {SCORES} and {CURVES} in {f} (run the report on it first)")
    if (into / rundir.RUNS_DIR).is_dir():
        raise ConfigError(f"{folder} holds run folders: merge into a results folder built from scores alone")
    mine, theirs = rundir.read_sweep(into) or {}, rundir.read_sweep(other) or {}
    differ = [k for k in MERGE_SAME if mine.get(k) != theirs.get(k)]
    if differ:
        raise ConfigError(f"{other} is a sweep with other {differ[0]} than {folder}: its cells would not compare")
    scores, new = read_rows(into / SCORES), read_rows(other / SCORES)
    if not new:
        raise ConfigError(f"{other / SCORES} holds no scores")
    name = other.name or Path(os.path.realpath(other)).name
    prefix = name + "/"
    new = [{**r, "run": prefix + r["run"]} for r in new]
    theirs_curves = [{**r, "run": prefix + r["run"]} for r in read_rows(other / CURVES)]
    have = {tuple(r[k] for k in CELL_ID) for r in scores}
    clash = sorted({tuple(r[k] for k in CELL_ID) for r in new} & have)
    if clash:
        if any(m.get("folder") == name for m in mine.get("merged", [])) \
                and _rows_in(new, scores, SCORE_COLUMNS) and _rows_in(theirs_curves, read_rows(into / CURVES),
                                                                      CURVE_COLUMNS):
            return len({r["run"] for r in new})
        raise ConfigError(f"{folder} already has cell {'/'.join(clash[0])} that {other} also has; "
                          f"merge only new cells (e.g. run the sweep with other --experiments)")
    curves = read_rows(into / CURVES) + theirs_curves
    scores += new
    merged = list(mine.get("merged", [])) + [{
        "folder": name, "experiments": theirs.get("experiments", []),
        "runs": len({r["run"] for r in new}), "machines": sorted({r.get("machine", "") for r in new} - {""})}]
    atomic_write_text(into / SCORES, csv_text(scores, SCORE_COLUMNS))
    kill_point("merged-scores")
    atomic_write_text(into / CURVES, csv_text(curves, CURVE_COLUMNS))
    arms = {**theirs.get("arms_as_run", {}), **mine.get("arms_as_run", {})}  # the merged arms' settings as run
    rundir.write_json(into / rundir.SWEEP, {**mine, "merged": merged, **({"arms_as_run": arms} if arms else {})})
    return None


def _rows_in(rows: List[dict], table: List[dict], columns: Sequence[str]) -> bool:
    """Every row of ``rows`` is a row of ``table`` (compared on ``columns``)."""
    have = {tuple(r.get(c, "") for c in columns) for r in table}
    return all(tuple(r.get(c, "") for c in columns) in have for r in rows)


def _read_unique(src: Path, out: Path, written: List[str]):
    """scores.csv and curves.csv, each row once (``runs.unique_rows``); a file that held repeats (written
    before a run's cells were made unique) is rewritten without them, so the next rebuild reads it as is."""
    files = ((SCORES, score_key, SCORE_COLUMNS), (CURVES, curve_key, CURVE_COLUMNS))
    read = [read_rows(out / name if (out / name).is_file() else src / name) for name, _, _ in files]
    try:  # both checked before either is rewritten
        unique = [unique_rows(rows, key, str(src / name)) for rows, (name, key, _) in zip(read, files)]
    except ValueError as e:
        raise ConfigError(str(e)) from None
    for rows, kept, (name, _, columns) in zip(read, unique, files):
        if len(kept) < len(rows):
            atomic_write_text(out / name, csv_text(kept, columns))
            if name not in written:
                written.append(name)
    return unique


@dataclass
class Outcome:
    """What a report did: ``written`` (the folder's report files, now current), ``changed`` (False: they
    were current already and nothing was written), ``notes`` (what it finished or undid of an interrupted
    report first), ``merged_before`` (``--merge``: the other sweep's runs were in the folder already)."""
    written: List[Path]
    changed: bool
    notes: List[str]
    merged_before: Optional[int] = None


def build_report(folder, resamples: int = 10_000, reference: Optional[Path] = None) -> List[Path]:
    """Write scores/curves (from runs), then tables, claims, plots and summary.md; return the paths written."""
    return report(folder, resamples, reference).written


def report(folder, resamples: int = 10_000, reference: Optional[Path] = None,
           merge: Optional[Path] = None) -> Outcome:
    """The report of ``folder`` (after adding ``merge``'s cells), written as one (``staging.py``): built in
    full in a staging folder, then swapped in; killed at any moment, the folder holds the old report or the
    new one, and the next report on it finishes or undoes what was cut."""
    folder = Path(folder)
    with Staged(folder) as st:
        if not folder.is_dir():
            raise ConfigError(f"no such folder: {folder}")
        name = folder.name or st.folder.name
        has_runs = (folder / rundir.RUNS_DIR).exists() or any(folder.rglob(rundir.CONFIG))
        if not has_runs and not ((folder / SCORES).is_file() and (folder / CURVES).is_file()):
            raise ConfigError(f"{folder} holds no run folders and no {SCORES}/{CURVES}: nothing to report "
                              f"(a sweep's --out, a results folder or one run's folder)")  # before any copy
        if merge is not None and has_runs:
            raise ConfigError(f"{folder} holds run folders: merge into a results folder built from scores alone")
        out = st.begin(whole=not has_runs, read=(SCORES, CURVES))
        src = out if st.whole else folder
        merged_before = merge_into(folder, Path(merge), into=out) if merge is not None else None
        names = _build(src, out, name, resamples, reference, merged=merge is not None and merged_before is None)
        changed = st.commit(names)
        return Outcome([folder / n for n in names], changed, st.notes, merged_before)


def nothing_to_report(src: Path, unfinished: Sequence[str]) -> str:
    """The one line of a folder whose runs are all unfinished or of no sweep (finished, without cell.json: train's
    own folders), counted apart."""
    loose = [u for u in unfinished if rundir.is_done(src / u)]
    parts = [plural(len(unfinished) - len(loose), "unfinished run")] if len(unfinished) > len(loose) else []
    if loose:
        parts.append(f"{plural(len(loose), 'finished run')} of no sweep, without {rundir.CELL}: "
                     f"`report {src / loose[0]}` draws one run's curves")
    return f"{src} holds no finished runs of a sweep and no {SCORES}/{CURVES}: nothing to report " \
           f"({'; '.join(parts) or 'no run folders'})"


def _build(src: Path, out: Path, name: str, resamples: int, reference: Optional[Path],
           merged: bool = False) -> List[str]:
    """The report's files, written into ``out``: run folders and the sweep's definition are read from
    ``src``, scores.csv and curves.csv from ``out`` where written there (else ``src``). Returns their names."""
    runs, unfinished = load_runs(src)
    unfinished = [u for u in unfinished if (src / u).is_dir()]  # a folder shipped without its runs has none
    written: List[str] = [SCORES, CURVES, rundir.SWEEP] if merged else []
    have_scores = (out / SCORES).is_file() or (src / SCORES).is_file()
    have_curves = (out / CURVES).is_file() or (src / CURVES).is_file()
    old_scores = read_rows(out / SCORES if (out / SCORES).is_file() else src / SCORES) if have_scores else None
    if runs:
        new_scores = score_rows(runs)
        if old_scores is not None:
            missing = sorted(r for r in {r["run"] for r in old_scores} - {r["run"] for r in new_scores}
                             if not (src / r).is_dir())  # runs whose folders are gone (a shipped folder)
            if missing:
                raise ConfigError(f"{src / SCORES} holds {plural(len(missing), 'run')} this folder no longer has "
                                  f"(e.g. {missing[0]}); refusing to replace it with less")
        atomic_write_text(out / SCORES, csv_text(new_scores, SCORE_COLUMNS))
        atomic_write_text(out / CURVES, csv_text(curve_rows(runs), CURVE_COLUMNS))
        written += [n for n in (SCORES, CURVES) if n not in written]
    elif old_scores is None or not have_curves:
        raise ConfigError(nothing_to_report(src, unfinished))
    # everything below reads the two files back, so a rebuild without run folders is byte-identical
    scores, curves = _read_unique(src, out, written)
    sweep = rundir.read_sweep(src)
    if sweep:  # from the definition and the registry, so a folder without run folders gets it too
        hp = hyperparameters.hyperparameter_rows(hyperparameters.cell_configs(sweep, scores))
        atomic_write_text(out / "hyperparameters.csv", csv_text(hp, hyperparameters.COLUMNS))
        written.append("hyperparameters.csv")
    ref_curves = None
    if reference is not None:
        if not (Path(reference) / CURVES).is_file():
            raise ConfigError(f"--reference {reference} holds no {CURVES}")
        ref_curves = read_rows(Path(reference) / CURVES)
    tables = build_tables(scores)
    for table, rows in tables.items():
        atomic_write_text(out / table, csv_text(rows, TABLE_COLUMNS))
        written.append(table)
    kill_point("tables")
    claims = claims_mod.claim_rows(scores, resamples)
    atomic_write_text(out / "claims.csv", csv_text(claims, claims_mod.CLAIM_COLUMNS))
    written.append("claims.csv")
    budget_rows = budget_mod.budget_rows(scores, resamples)
    if budget_rows:
        atomic_write_text(out / "budget.csv", csv_text(budget_rows, budget_mod.BUDGET_COLUMNS))
        written.append("budget.csv")
    regime_rows = regime_mod.regime_rows(curves)
    if regime_rows:
        atomic_write_text(out / "regime.csv", csv_text(regime_rows, regime_mod.COLUMNS))
        written.append("regime.csv")
    diag_rows = diagnostics_mod.diagnostic_rows(scores)
    if diag_rows:
        atomic_write_text(out / "diagnostics.csv", csv_text(diag_rows, diagnostics_mod.COLUMNS))
        written.append("diagnostics.csv")
    figures = []
    present = {r["experiment"] for r in scores}
    ablations = [(registry.fig6_file(e), lambda p, e=e: plots.plot_ablation(curves, p, e))
                 for e in registry.experiments_feeding(registry.FIG6) if e in present]
    for stale in out.glob("fig6*.png"):  # a results folder's copy: an ablation figure this report does not draw
        if stale.name not in {f for f, _ in ablations}:
            stale.unlink()
    for fig, fn in (("fig4_single_task.png", lambda p: plots.plot_fig4(curves, p, ref_curves)),
                    ("fig5_multitask.png", lambda p: plots.plot_fig5(curves, p, ref_curves)),
                    *ablations,
                    ("fig7_aggregate.png", lambda p: plots.plot_aggregate(scores, p)),
                    ("fig8_budget.png", lambda p: plots_budget.plot_budget(budget_rows, p))):
        if fn(out / fig):
            figures.append(fig)
            written.append(fig)
    atomic_write_text(out / "summary.md", summary_md(name, sweep, scores, tables, claims, figures, unfinished,
                                                     budget_rows, regime_rows, curves))
    written.append("summary.md")
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
    p.add_argument("--readme-table", action="store_true",
                   help="only print the README's results table (the paper's claims) from FOLDER/claims.csv")
    a = p.parse_args(argv)
    if run_curves.is_run_folder(Path(a.folder)) and not (a.readme_table or a.merge or a.reference):
        need = missing_package("matplotlib", "report draws its figures with")
        if need:
            print(f"error: {need}", file=sys.stderr)
            return 2
        return run_curves.main(Path(a.folder))  # one run: its curves and a summary
    if a.readme_table:
        if not (Path(a.folder) / "claims.csv").is_file():
            print(f"error: {a.folder} holds no claims.csv", file=sys.stderr)
            return 2
        print(claims_mod.readme_table(read_rows(Path(a.folder) / "claims.csv")), end="")
        return 0
    try:
        need = missing_package("matplotlib", "report draws its figures with")
        if need:
            raise ConfigError(need)
        if a.resamples < 100:
            raise ConfigError(f"--resamples must be >= 100, got {a.resamples}")
        done = report(Path(a.folder), a.resamples, Path(a.reference) if a.reference else None,
                      Path(a.merge) if a.merge else None)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for n in done.notes:
        print(f"note: {n}")
    if done.merged_before is not None:
        print(f"{a.folder} already holds the {plural(done.merged_before, 'run')} of {a.merge} (merged before) "
              + ("and its report is complete: nothing written" if not done.changed else
                 "but its report was not up to date: rebuilt (" + ", ".join(w.name for w in done.written) + ")"))
        return 0
    for w in done.written:
        print(w)
    return 0


if __name__ == "__main__":
    sys.exit(main())
