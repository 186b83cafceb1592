"""The analysis wing on hand-made run folders (no training): scores, tables, claims, rebuilds from
scores alone, refusals that protect committed results."""
from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from maniskill_dualher import report, staging
from maniskill_dualher.analysis import claims as claims_mod
from maniskill_dualher.config import ReplayConfig, RunConfig
from maniskill_dualher.experiment.registry import PAPER_CHAIN, chain_name

CHAIN = chain_name(PAPER_CHAIN)


def _write_run(folder: Path, cfg: RunConfig, successes, returns, cells, done=True, wall=1.0, start=False):
    """A run folder as train.py and the sweep leave it: config.json, metrics.csv, cell.json, done.json."""
    folder.mkdir(parents=True)
    (folder / "config.json").write_text(cfg.to_json())
    steps = [0] * start + [100 * (i + 1) for i in range(len(successes) - start)]
    rows = [{"env_steps": st, "eval_return": r, "eval_success_rate": r / 10, "train_episodes": 2 * (i + 1),
             "train_successes": s, "wall_time_s": wall * (i + 1)}
            for i, (st, s, r) in enumerate(zip(steps, successes, returns))]
    with open(folder / "metrics.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    (folder / "cell.json").write_text(json.dumps({"cells": cells}))
    if done:
        (folder / "done.json").write_text(json.dumps({"final": rows[-1]}))


def _cell(exp, arm, task, method, seed, role="adapt", chain=CHAIN, variant="", stage=2):
    return {"experiment": exp, "arm": arm, "task": task, "chain": chain, "method": method, "variant": variant,
            "seed": seed, "stage": stage, "n_stages": 3, "role": role, "parent": None}


def _cfg(env, method, seed, ratio=(0.6, 0.4), steps=300):
    return RunConfig(env_id=env, method=method, seed=seed, total_steps=steps, eval_every=100,
                     replay=ReplayConfig(ratio=ratio))


@pytest.fixture
def folder(tmp_path):
    """3 seeds of sac_her_per vs dual_buffer adaptation, two ratios, and single-task runs of 2 methods."""
    out = tmp_path / "sweep"
    adapt = {("sac_her_per", (0.6, 0.4)): [1, 2, 3], ("dual_buffer", (0.6, 0.4)): [10, 12, 14],
             ("dual_buffer", (0.5, 0.5)): [4, 6, 8]}
    for (method, ratio), finals in adapt.items():
        for seed, final in enumerate(finals):
            r = "/".join(f"{x:g}" for x in ratio)
            variant = r if method == "dual_buffer" else ""
            cells = [_cell("ratios", r, "CloseMicrowave-v1", method, seed, variant=variant)] \
                if method == "dual_buffer" else []
            if ratio == (0.6, 0.4):
                cells.append(_cell("transfer", "paper", "CloseMicrowave-v1", method, seed, variant=variant))
            _write_run(out / f"runs/chain/{method}-s{seed}/stage2-{ratio[0]}", _cfg("CloseMicrowave-v1", method, seed,
                       ratio), [0, final], [0.0, final / 2], cells)
    # a source stage: never in the adaptation tables
    _write_run(out / "runs/chain/sac_her_per-s0/stage0", _cfg("ReachTarget-v1", "sac_her_per", 0), [99], [9.0],
               [_cell("transfer", "paper", "ReachTarget-v1", "sac_her_per", 0, role="source", stage=0)])
    for method, vals in (("sac", [0.0, 1.0, 2.0]), ("dual_buffer", [5.0, 6.0, 7.0])):
        for seed, v in enumerate(vals):
            _write_run(out / f"runs/single/CloseBox-v1-{method}-s{seed}", _cfg("CloseBox-v1", method, seed),
                       [1, 2], [0.0, v], [_cell("single", "paper", "CloseBox-v1", method, seed, role="single",
                                                chain="", stage=0, variant="0.6/0.4" if method == "dual_buffer" else "")])
    return out


def _table(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_tables_hold_the_final_rows_aggregated_over_seeds(folder):
    report.build_report(folder)
    t5 = {(r["method"], r["metric"]): r for r in _table(folder / "table5_multitask.csv")}
    row = t5[("dual_buffer", "successful_train_episodes")]
    assert (row["n_seeds"], row["seeds"], float(row["mean"]), float(row["std"])) == ("3", "0 1 2", 12.0, 2.0)
    assert row["paper"] == "250" and row["variant"] == "0.6/0.4" and row["experiment"] == "transfer"
    assert 6 < float(row["ci95_low"]) < 12 < float(row["ci95_high"]) < 18    # t interval, 2 dof
    # mean over each run's evaluations (area under the curve): returns [0, 0.5], [0, 1], [0, 1.5]
    assert float(t5[("sac_her_per", "mean_eval_success_rate")]["mean"]) == pytest.approx(0.05)
    assert not any(m == "mean_eval_return" for _, m in t5)   # equal to the success rate here: not tabled twice
    rate = t5[("dual_buffer", "final_eval_success_rate")]     # a rate's interval: bootstrap, inside [0, 1]
    assert 0.0 <= float(rate["ci95_low"]) <= float(rate["mean"]) <= float(rate["ci95_high"]) <= 1.0
    assert t5[("sac_her_per", "successful_train_episodes")]["paper"] == "<45"
    t4 = _table(folder / "table4_sampling_ratio.csv")
    assert [(r["arm"], float(r["mean"]), r["paper"]) for r in t4] == [("0.5/0.5", 6.0, "154"), ("0.6/0.4", 12.0, "250")]
    single = {(r["method"], r["metric"]): r for r in _table(folder / "single_task.csv")}
    assert float(single[("dual_buffer", "mean_eval_success_rate")]["mean"]) == pytest.approx(0.3)  # [0, .5..7]
    assert float(single[("sac", "final_eval_success_rate")]["mean"]) == pytest.approx(0.1)
    assert {r["task"] for r in single.values()} == {"CloseBox-v1"}          # the source stage is not a single run


def test_scores_are_one_row_per_run_cell_and_metric(folder):
    report.build_report(folder)
    scores = _table(folder / "scores.csv")
    shared = [r for r in scores if r["run"].endswith("dual_buffer-s1/stage2-0.6")
              and r["metric"] == "successful_train_episodes"]
    assert {(r["experiment"], r["arm"], r["value"]) for r in shared} == {("ratios", "0.6/0.4", "12"),
                                                                         ("transfer", "paper", "12")}
    curves = _table(folder / "curves.csv")
    assert {r["env_steps"] for r in curves if r["run"].endswith("sac_her_per-s0/stage2-0.6")} == {"100", "200"}


def test_claims_are_computed_from_the_numbers(folder):
    report.build_report(folder)
    claims = {r["claim"]: r for r in _table(folder / "claims.csv")}
    assert list(claims)[:9] == ["a", "b", "c", "d", "e", "f", "g", "h", "h'"]
    a = claims["a"]  # dual 10, 12, 14 vs sac_her_per 1, 2, 3 successful adaptation episodes
    assert (float(a["mean_a"]), float(a["mean_b"]), float(a["diff"])) == (12.0, 2.0, 10.0)
    assert float(a["diff_ci95_low"]) < 10 < float(a["diff_ci95_high"]) and a["verdict"] == "reproduced"
    assert float(a["welch_ci95_low"]) > 0 and float(a["prob_improvement"]) == 1.0
    assert claims["c"]["verdict"] == "reproduced"         # 0.6/0.4: 10..14 vs 0.5/0.5: 4..8
    assert claims["d"]["verdict"].startswith("not measured")  # no 0.7/0.3 runs
    # CloseBox curves: dual [0, 5..7] vs sac [0, 0..2], paired by seed on 3 seeds: below 5 pairs no paired
    # interval (the bootstrap-t is unstable there), the paired t's included; the exact sign-flip p stays
    f = claims["f"]
    assert f["verdict"] == "inconclusive (interval not computed below 5 pairs)" and f["diff_ci95_low"] == "nan"
    assert f["paired"] == "yes" and f["paired_t_ci95_low"] == f["paired_t_ci95_high"] == ""
    assert f["p_value"] == "nan" and f["p_holm"] == ""
    assert float(f["signflip_p"]) == pytest.approx(2 / 8)    # 3 pairs, all one sign: 2 of the 8 sign patterns
    assert claims["e"]["verdict"].startswith("not measured")
    assert claims["h"]["verdict"].startswith("not measured")  # no from-scratch control in this folder
    assert all(claims[k]["verdict"].startswith("not measured") for k in ("e_off", "warm_a"))
    s = (folder / "summary.md").read_text()
    line = next(ln for ln in s.splitlines() if ln.startswith("| a |"))
    assert "**reproduced**" in line and "Table 5: 250 vs <45" in line
    assert "compare directions" in s and "claims were tested" in s


def test_the_multiplicity_sentence_counts_the_claims_holm_adjusts(folder):
    """summary.md's "N claims were tested" counts the claims with a finite p-value, the ones Holm adjusts (the sum
    of Holm's family sizes); a measured claim without an interval (f: 3 pairs) is named apart, not counted."""
    report.build_report(folder)
    claims = _table(folder / "claims.csv")
    with_p = [r["claim"] for r in claims if r["p_value"] not in ("", "nan")]
    assert with_p == [r["claim"] for r in claims if r["p_holm"]]          # Holm's families hold exactly these
    measured = [r["claim"] for r in claims if r["diff"]]
    assert "f" in measured and "f" not in with_p and len(with_p) >= 2
    s = (folder / "summary.md").read_text()
    n = len(with_p)
    assert f"{n} claims were tested, each at 95%; with {n} independent tests" in s
    assert f"Bonferroni over all of them would use {1 - 0.05 / n:.2%} per claim" in s
    rest = [k for k in measured if k not in with_p]
    assert f"{len(rest)} measured claim{'s' if len(rest) > 1 else ''} ha{'ve' if len(rest) > 1 else 's'} no " \
           f"interval (too few seeds or pairs), hence no p-value" in s and f"left out of Holm: {', '.join(rest)}." in s


def test_the_presets_budgets_are_called_defaults_where_arms_ran_their_own():
    """summary.md's budget line names the preset's budgets as defaults, and where adaptation curves exist points to
    the next line, the budgets as run (an arm's settings may override the preset's: paper_regime's 3.6M)."""
    from maniskill_dualher.analysis.report import summary_md
    budgets = {"single": {"CloseBox-v1": 10}, "source": {"CloseBox-v1": 6}, "adapt": {"CloseBox-v1": 12}}
    tables = {n: [] for n in ("table5_multitask.csv", "table4_sampling_ratio.csv", "ablations.csv",
                              "single_task.csv")}
    curves = [{"experiment": "paper_regime", "arm": "episode", "run": "r0", "role": "adapt", "env_steps": "3600000"}]
    lines = summary_md("x", {"budgets": budgets}, [], tables, [], [], [], curves=curves).splitlines()
    assert lines[3].startswith("The preset's default budgets (env steps; an arm's settings may override them: "
                               "as run on the next line): single-task")
    assert lines[4].startswith("Adaptation budgets as run") and "3,600,000 env steps" in lines[4]
    alone = summary_md("x", {"budgets": budgets}, [], tables, [], [], []).splitlines()
    assert alone[3].startswith("The preset's default budgets (env steps): single-task")


def test_summary_tables_only_measured_claims_and_names_the_rest():
    """A folder holds some experiments: summary.md counts and tables the claims it measures, names the others
    under their family (a family with none measured keeps only that line), and prints budgets per task."""
    from maniskill_dualher.analysis.report import summary_md
    tables = {n: [] for n in ("table5_multitask.csv", "table4_sampling_ratio.csv", "ablations.csv",
                              "single_task.csv")}
    measured = {"claim": "regime_count_episode", "group": "paper_regime", "statement": "A > B", "paper": "",
                "n_a": "16", "n_b": "16", "mean_a": 341.9, "mean_b": 371.1, "diff": -29.25,
                "diff_ci95_low": -79.8, "diff_ci95_high": 21.3, "verdict": "inconclusive", "p_value": 0.23,
                "p_holm": 0.68, "survives_holm": "", "metric": "successful_train_episodes"}
    missing = [{"claim": c, "group": g, "statement": "A > B", "paper": "", "verdict": "not measured (runs missing)"}
               for c, g in (("a", "paper"), ("b", "paper"), ("regime_count_step", "paper_regime"))]
    budgets = {"single": {"CloseBox-v1": 10000}, "source": {"CloseBox-v1": 6000}, "adapt": {"CloseBox-v1": 12000}}
    s = summary_md("x", {"budgets": budgets}, [], tables, [measured, *missing], [], [])
    assert "0 of 1 measured claim decided at 95%, 0 of them after Holm within their family; 3 more are not " \
           "measured here" in s
    assert "single-task CloseBox-v1 10,000; source stage CloseBox-v1 6,000; adaptation CloseBox-v1 12,000." in s
    assert "not measured (runs missing)" not in s                 # no table row for a claim without runs
    paper = s[s.index("### The paper's claims"):s.index("### The paper's own regime")]
    assert "| a |" not in paper and "Not measured here (no runs for them in this folder): a, b." in paper
    regime = s[s.index("### The paper's own regime"):]
    assert "| regime_count_episode |" in regime
    assert "Not measured here (no runs for it in this folder): regime_count_step." in regime


def test_scratch_control_sits_beside_transfer(folder):
    """The from-scratch control enters Table 5 as its own experiment and decides claim (h)."""
    for seed, final in enumerate([3, 4, 5]):
        cfg = _cfg("CloseMicrowave-v1", "dual_buffer", seed)
        _write_run(folder / f"runs/chain/dual_buffer-s{seed}/stage0-scratch", cfg, [0, final], [0.0, 0.2],
                   [_cell("scratch", "paper", "CloseMicrowave-v1", "dual_buffer", seed, chain="CloseMicrowave-v1",
                          variant="0.6/0.4", stage=0)])
    report.build_report(folder)
    t5 = _table(folder / "table5_multitask.csv")
    assert {("scratch", "dual_buffer"), ("transfer", "dual_buffer")} <= {(r["experiment"], r["method"]) for r in t5}
    assert all(r["experiment"] == "ratios" for r in _table(folder / "table4_sampling_ratio.csv"))
    h = {r["claim"]: r for r in _table(folder / "claims.csv")}["h"]
    assert (float(h["mean_a"]), float(h["mean_b"])) == (12.0, 4.0) and h["verdict"] == "reproduced"


def test_step0_evaluation_gives_the_prior_and_the_dip(tmp_path):
    """A run evaluated at env step 0 (eval_at_start): the step-0 score is the prior's, it is left out of the
    area under the curve, and the fall below it is the fine-tuning dip."""
    out = tmp_path / "s"
    cfg = _cfg("CloseMicrowave-v1", "sac_her_per", 0)
    # eval success 0.5 at step 0, 0.1 at 100, 0.3 at 200, 0.6 at 300
    _write_run(out / "runs/r", cfg, [0, 1, 2, 12], [5.0, 1.0, 3.0, 6.0],
               [_cell("transfer", "paper", "CloseMicrowave-v1", "sac_her_per", 0)], start=True)
    report.build_report(out)
    scores = {r["metric"]: float(r["value"]) for r in _table(out / "scores.csv")}
    assert scores["step0_eval_success_rate"] == 0.5
    assert scores["mean_eval_success_rate"] == pytest.approx((0.1 + 0.3 + 0.6) / 3)
    assert scores["dip_depth"] == pytest.approx(0.4) and scores["dip_length"] == 300
    assert scores["steps_to_10_successes"] == 300 and scores["train_success_rate"] == pytest.approx(12 / 8)


def test_wall_time_and_unfinished_runs_do_not_change_tables(folder):
    report.build_report(folder)
    names = ("table4_sampling_ratio.csv", "table5_multitask.csv", "single_task.csv", "claims.csv", "scores.csv")
    before = {n: (folder / n).read_bytes() for n in names}
    # other wall times (a resumed run) and an unfinished run: same tables
    for m in folder.glob("runs/single/*/metrics.csv"):
        m.write_text(m.read_text().replace(",1.0\n", ",77.5\n"))
    _write_run(folder / "runs/single/CloseBox-v1-sac-s9", _cfg("CloseBox-v1", "sac", 9), [50], [50.0],
               [_cell("single", "paper", "CloseBox-v1", "sac", 9, role="single", chain="")], done=False)
    report.build_report(folder)
    assert {n: (folder / n).read_bytes() for n in names} == before
    assert "1 run unfinished" in (folder / "summary.md").read_text()
    assert not list(folder.glob(".*.tmp")) and not list(folder.glob(".*.png"))   # atomic writes leave no temp files


def test_rebuild_from_scores_alone_is_byte_identical(folder, tmp_path):
    """A results folder without run folders (what is committed): the report rebuilds claims.csv and every
    table byte-identical from scores.csv and curves.csv."""
    report.build_report(folder)
    copy = tmp_path / "committed"
    copy.mkdir()
    for f in folder.iterdir():
        if f.is_file():
            shutil.copy2(f, copy / f.name)
    (copy / "claims.csv").unlink()
    (copy / "table5_multitask.csv").write_text("stale\n")
    assert report.main([str(copy)]) == 0
    for name in ("claims.csv", "table5_multitask.csv", "table4_sampling_ratio.csv", "single_task.csv",
                 "scores.csv", "curves.csv"):
        assert (copy / name).read_bytes() == (folder / name).read_bytes(), name
    assert (copy / "fig5_multitask.png").is_file()


def test_report_never_replaces_scores_with_less(folder, tmp_path, capsys):
    """A folder whose scores.csv names runs it no longer has (a committed reference with a few runs made
    beside it): refused, one line, exit 2, nothing changed."""
    report.build_report(folder)
    for d in list(folder.glob("runs/single/*"))[:2]:
        shutil.rmtree(d)
    before = {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()}
    assert report.main([str(folder)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "refusing to replace it with less" in err[0]
    assert {p: p.read_bytes() for p in folder.rglob("*") if p.is_file()} == before


def test_folder_without_finished_runs_or_scores_is_refused(tmp_path, capsys):
    """The documented command on a folder it cannot rebuild exits 2 and writes nothing."""
    out = tmp_path / "x"
    _write_run(out / "runs/r", _cfg("CloseBox-v1", "sac", 0), [1], [1.0],
               [_cell("single", "paper", "CloseBox-v1", "sac", 0, role="single", chain="")], done=False)
    (out / "claims.csv").write_text("committed\n")
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert report.main([str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nothing to report" in err[0]
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


def test_reference_curves_are_overlaid(folder, tmp_path, monkeypatch):
    from maniskill_dualher.analysis import plots
    report.build_report(folder)
    ref = tmp_path / "ref"
    shutil.copytree(folder, ref, ignore=shutil.ignore_patterns("runs"))
    seen = []
    draw = plots.draw
    monkeypatch.setattr(plots, "draw", lambda ax, g, *a, **k: (seen.append(bool(k.get("reference") or
                                                                                 (len(a) > 4 and a[4]))),
                                                              draw(ax, g, *a, **k)))
    assert report.main([str(folder), "--reference", str(ref)]) == 0
    assert any(seen)
    assert report.main([str(folder), "--reference", str(tmp_path / "nope")]) == 2


def _smoke_definition() -> dict:
    from maniskill_dualher.experiment import sweep
    return sweep.definition_from_args(sweep.make_parser().parse_args(["--preset", "smoke"]))


def test_hyperparameters_put_ours_beside_table3_per_stage(folder):
    """From the sweep's definition (sweep.json) and the cells in scores.csv, through the grid's configs."""
    runs = sorted(str(p.parent.relative_to(folder)) for p in folder.rglob("config.json"))
    (folder / "sweep.json").write_text(json.dumps({**_smoke_definition(), "runs": runs}))
    report.build_report(folder)
    hp = {r["hyperparameter"]: r for r in _table(folder / "hyperparameters.csv")}
    assert hp["learning rate"]["paper"] == "0.0001" and hp["batch size"]["ours_single_task"] == "32"
    assert hp["dual buffer sampling ratio P(R)/P(E)"]["ours_adaptation"] == "0.6/0.4; 0.5/0.5 (ratios/0.5/0.5)"
    assert hp["SAC entropy temperature alpha"]["ours_adaptation"].startswith("carried from the previous stage")
    assert hp["SAC entropy temperature alpha"]["ours_source_stages"].startswith("0.005")
    assert hp["optimizer at the start"]["ours_adaptation"] == "fresh Adam (not carried)"
    assert hp["HER goals per transition k"]["ours_single_task"] == "4"    # a single-task run's, not a chain's
    assert hp["env steps per run"]["ours_single_task"] == "CloseBox-v1: 200"


def test_an_arms_override_is_tagged_with_the_arm():
    """A value no paper-treatment arm uses is tagged with the arms that set it; the paper arm's stays plain."""
    from maniskill_dualher.analysis import hyperparameters
    cells = [{"experiment": e, "arm": a, "method": "dual_buffer", "task": t, "stage": s}
             for e, a in (("transfer", "paper"), ("warm_start", "warm_low_lr"), ("e_share", "r_starved"))
             for s, t in enumerate(PAPER_CHAIN)]
    hp = {r["hyperparameter"]: r for r in hyperparameters.hyperparameter_rows(
        hyperparameters.cell_configs(_smoke_definition(), cells))}
    assert hp["learning rate"]["ours_adaptation"] == "0.0001; 0.0003 (warm_start/warm_low_lr)"  # smoke: lr default
    assert hp["learning rate"]["ours_source_stages"] == "0.0001"                  # adaptation-only arms
    assert hp["gradient update schedule"]["ours_adaptation"] == "1 per env step; 0.6 per env step (e_share/r_starved)"
    assert hp["random-action steps"]["ours_adaptation"] == "100; 0 (warm_start/warm_low_lr)"
    assert hp["env steps per run"]["ours_single_task"] == ""                     # no single-task cell asked


def test_reference_hyperparameters_are_rebuilt_from_its_csvs_and_sweep_json():
    """results/reference has no run folders: its hyperparameters.csv comes from sweep.json, scores.csv and the
    registry, byte for byte; every role's column is filled, the single-task one included."""
    from maniskill_dualher.analysis import hyperparameters
    from maniskill_dualher.analysis.runs import read_rows
    from maniskill_dualher.fileio import csv_text
    ref = Path(__file__).resolve().parents[1] / "results" / "reference"
    rows = hyperparameters.hyperparameter_rows(hyperparameters.cell_configs(
        json.loads((ref / "sweep.json").read_text()), read_rows(ref / "scores.csv")))
    assert csv_text(rows, hyperparameters.COLUMNS) == (ref / "hyperparameters.csv").read_text()
    hp = {r["hyperparameter"]: r for r in rows}
    assert hp["learning rate"]["ours_single_task"] == "0.001"
    assert "0.0003 (warm_start/warm_low_lr)" in hp["learning rate"]["ours_adaptation"]
    assert "episode (her_episode/her_episode)" in hp["HER goal strategy"]["ours_source_stages"]
    assert all(r[c] for r in rows for c in ("ours_source_stages", "ours_adaptation"))


def test_reference_folder_is_rebuilt_byte_identically_from_its_csvs(tmp_path):
    """`python -m maniskill_dualher.report results/reference` rewrites every file of the committed folder as
    it is (tables, claims, figures, hyperparameters.csv, summary.md)."""
    ref = Path(__file__).resolve().parents[1] / "results" / "reference"
    copy = tmp_path / "reference"   # summary.md names its folder
    shutil.copytree(ref, copy)
    assert report.main([str(copy)]) == 0
    differ = [p.name for p in ref.rglob("*") if p.is_file()
              and p.read_bytes() != (copy / p.relative_to(ref)).read_bytes()]
    assert differ == []
    assert sorted(p.name for p in copy.rglob("*")) == sorted(p.name for p in ref.rglob("*"))


def test_summary_names_every_claim_of_every_family():
    """summary.md lists each claim of claims.csv, measured (its table) or not (its family's "not measured" line):
    a family added to claims.FAMILIES gets its section without a change to the report."""
    ref = Path(__file__).resolve().parents[1] / "results" / "reference"
    text = (ref / "summary.md").read_text()
    with open(ref / "claims.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert {r["group"] for r in rows} == set(claims_mod.FAMILIES)
    named = ["| {} |", " {},", " {}."]   # a table's row, or in a "not measured" list
    assert [r["claim"] for r in rows if not any(n.format(r["claim"]) in text for n in named)] == []


def test_plots_are_written(folder):
    written = report.build_report(folder)
    for name in ("fig4_single_task.png", "fig5_multitask.png", "fig7_aggregate.png"):
        assert folder / name in written
        assert (folder / name).read_bytes()[:4] == b"\x89PNG"


def test_cli_on_missing_folder(tmp_path, capsys):
    assert report.main([str(tmp_path / "nope")]) == 2
    assert capsys.readouterr().err.strip().startswith("error: no such folder")
    assert report.main([str(tmp_path)]) == 2
    assert list(tmp_path.iterdir()) == []


def test_every_claim_names_a_metric_and_cells_that_exist():
    from maniskill_dualher.analysis.runs import METRICS
    from maniskill_dualher.experiment.registry import EXPERIMENTS
    keys = [c.key for c in claims_mod.CLAIMS]
    assert len(keys) == len(set(keys))
    for c in claims_mod.CLAIMS:
        assert c.metric in METRICS, c.key
        for side in (c.a, c.b):
            assert side.experiment in EXPERIMENTS, (c.key, side)
            assert side.arm in {a.name for a in EXPERIMENTS[side.experiment].arms}, (c.key, side)


def _shipped(src: Path, dst: Path, sweep: dict) -> Path:
    """A results folder as committed: the report's files without run folders, and a sweep.json."""
    report.build_report(src)
    dst.mkdir()
    for f in src.iterdir():
        if f.is_file():
            shutil.copy2(f, dst / f.name)
    (dst / "sweep.json").write_text(json.dumps(sweep))
    return dst


SWEEP = {"preset": "reference", "budgets": {"single": {"CloseBox-v1": 200}, "source": {"CloseBox-v1": 300},
                                            "adapt": {"CloseMicrowave-v1": 300}, "default": 300},
         "preset_settings": [], "settings": [],
         "task_order": list(PAPER_CHAIN), "carry_replay": True}


def _provenance(folder: Path, model: str, bf16: bool) -> None:
    for cfg in folder.rglob("config.json"):
        (cfg.parent / "provenance.json").write_text(json.dumps(
            {"starts": [{"cpu": {"model": model, "avx512_bf16": bf16, "amx_bf16": False, "avx2": True}}]}))


def _merge_pair(folder: Path, tmp_path: Path):
    """A shipped reference (from ``folder``'s runs, made on CPU A) and another sweep ``more`` (single-task
    ReachTarget runs of two methods, made on CPU B) with the same budgets: what ``--merge`` joins."""
    _provenance(folder, "CPU A", True)
    other = tmp_path / "more"
    for seed, v in enumerate([1.0, 2.0, 3.0]):
        _write_run(other / f"runs/single/ReachTarget-v1-sac-s{seed}", _cfg("ReachTarget-v1", "sac", seed), [1, 2],
                   [0.0, v], [_cell("single", "paper", "ReachTarget-v1", "sac", seed, role="single", chain="",
                                    stage=0)])
        _write_run(other / f"runs/single/ReachTarget-v1-dual_buffer-s{seed}",
                   _cfg("ReachTarget-v1", "dual_buffer", seed), [1, 2], [0.0, v + 5],
                   [_cell("single", "paper", "ReachTarget-v1", "dual_buffer", seed, role="single", chain="",
                          stage=0, variant="0.6/0.4")])
    _provenance(other, "CPU B", False)
    ref = _shipped(folder, tmp_path / "reference", SWEEP)
    report.build_report(other)
    (other / "sweep.json").write_text(json.dumps({**SWEEP, "experiments": ["single"]}))
    return ref, other


def test_merge_adds_another_sweeps_cells_with_their_machine(folder, tmp_path, capsys):
    """A reference made on one CPU gets the cells of a later sweep made on another: the claims see both
    sides, each row says its machine, run names say their sweep; overlapping cells or other budgets refuse."""
    ref, other = _merge_pair(folder, tmp_path)
    arms = {"single/paper": {"single": {"ReachTarget-v1": {"total_steps": 2}}}}  # sweep.py's record, as run
    (other / "sweep.json").write_text(json.dumps({**json.loads((other / "sweep.json").read_text()),
                                                  "arms_as_run": arms}))
    n_before = len(_table(ref / "scores.csv"))
    assert report.main([str(ref), "--merge", str(other)]) == 0
    assert json.loads((ref / "sweep.json").read_text())["arms_as_run"] == arms  # the merged arms' settings join
    scores = _table(ref / "scores.csv")
    assert len(scores) > n_before and {r["machine"] for r in scores} == {"CPU A (avx512_bf16)", "CPU B (avx2)"}
    assert all(r["run"].startswith("more/") for r in scores if r["machine"] == "CPU B (avx2)")
    claims = {r["claim"]: r for r in _table(ref / "claims.csv")}
    assert claims["e"]["n_a"] == "3" and claims["e"]["machines"] == "CPU B (avx2)"
    assert claims["a"]["machines"] == "CPU A (avx512_bf16)"
    assert json.loads((ref / "sweep.json").read_text())["merged"][0]["folder"] == "more"
    assert "CPU B (avx2): single" in (ref / "summary.md").read_text()
    # the same merge again: its cells are there and the report is complete -> one line, nothing written
    before = {p: (p.read_bytes(), p.stat().st_ino) for p in ref.rglob("*") if p.is_file()}
    capsys.readouterr()
    assert report.main([str(ref), "--merge", str(other)]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert len(out) == 1 and "already holds the 6 runs of" in out[0] and "nothing written" in out[0], out
    assert {p: (p.read_bytes(), p.stat().st_ino) for p in ref.rglob("*") if p.is_file()} == before
    # another sweep holding those cells -> refused, nothing written
    before = {p: p.read_bytes() for p in ref.rglob("*") if p.is_file()}
    again = tmp_path / "again"
    shutil.copytree(other, again)
    assert report.main([str(ref), "--merge", str(again)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "already has cell single/paper/" in err[0]
    # a sweep with other budgets -> refused
    (other / "sweep.json").write_text(json.dumps({**SWEEP, "budgets": {**SWEEP["budgets"], "adapt": {"CloseMicrowave-v1": 600}}}))
    assert report.main([str(ref), "--merge", str(other)]) == 2
    assert "other budgets" in capsys.readouterr().err
    # into a folder with run folders -> refused
    assert report.main([str(folder), "--merge", str(other)]) == 2
    assert {p: p.read_bytes() for p in ref.rglob("*") if p.is_file()} == before


REPO = Path(__file__).resolve().parents[1]


def _report_cli(args, kill=None, exchange=True) -> subprocess.CompletedProcess:
    """``python -m maniskill_dualher.report ARGS`` in a fresh process that SIGKILLs itself at the point
    ``kill`` (``staging.kill_point``); ``exchange=False`` takes the two-rename swap (a filesystem without
    ``RENAME_EXCHANGE``)."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    env.pop(staging.KILL_AT, None)
    if kill:
        env[staging.KILL_AT] = kill
    code = ("import sys; from maniskill_dualher import staging; staging.EXCHANGE = %r\n"
            "from maniskill_dualher.analysis.report import main; sys.exit(main(sys.argv[1:]))" % exchange)
    return subprocess.run([sys.executable, "-c", code, *map(str, args)], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=300)


def _tree(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _leftovers(parent: Path) -> list:
    return sorted(p.name for p in parent.rglob(".*report-*"))


# (kill point, exchange): before the swap (scores merged, tables written, all staged) and after it; the
# two-rename path between its renames leaves the folder missing for a moment, finished by the next report
MERGE_KILLS = [("merged-scores", True), ("tables", True), ("staged", True), ("exchanged", True),
               ("staged", False), ("renamed-old", False)]


def test_a_merge_killed_at_any_point_leaves_the_folder_as_before_or_merged(folder, tmp_path, capsys):
    """SIGKILL at each point of a merge and its report: the folder is byte-identical to before or to an
    uninterrupted merge, and the same command again ends byte-identical to the uninterrupted merge, no
    staging folder left."""
    ref, other = _merge_pair(folder, tmp_path)
    before = _tree(ref)
    args = ["--merge", other, "--resamples", "200"]
    done = tmp_path / "done" / "reference"        # summary.md names its folder: same name everywhere
    shutil.copytree(ref, done)
    assert report.main([str(done), *map(str, args)]) == 0
    merged = _tree(done)
    assert merged != before and merged["scores.csv"] != before["scores.csv"]
    seen = set()
    for point, exchange in MERGE_KILLS:
        copy = tmp_path / f"{point}-{exchange}" / "reference"
        shutil.copytree(ref, copy)
        r = _report_cli([copy, *args], kill=point, exchange=exchange)
        assert r.returncode == -signal.SIGKILL, (point, r.returncode, r.stderr[-2000:])
        if point == "renamed-old":   # between the renames: the old folder and the complete new one beside it
            assert not copy.exists()
            assert _tree(staging.beside(copy, "old")) == before and _tree(staging.beside(copy, "new")) == merged
        else:
            now = _tree(copy)
            assert now in (before, merged), point
            seen.add("before" if now == before else "merged")
        capsys.readouterr()
        assert report.main([str(copy), *map(str, args)]) == 0, (point, capsys.readouterr().err)
        assert _tree(copy) == merged, point
        assert _leftovers(copy.parent) == [], point
    assert seen == {"before", "merged"}


JOURNAL_KILLS = ["tables", "staged", "committed", "moved-one"]


def test_a_report_of_a_sweep_folder_killed_at_any_point_is_finished_by_the_next(folder, tmp_path):
    """A sweep folder (its run folders cannot move): the new files are staged inside it and moved in after
    a commit point. Killed before it, the report's files are as before; after it, the next report finishes
    the move first; either way the rerun ends byte-identical to an uninterrupted report."""
    report.build_report(folder, resamples=200)
    _write_run(folder / "runs/single/CloseBox-v1-sac-s7", _cfg("CloseBox-v1", "sac", 7), [3, 4], [0.0, 9.0],
               [_cell("single", "paper", "CloseBox-v1", "sac", 7, role="single", chain="", stage=0)])
    outputs = lambda d: {k: v for k, v in _tree(d).items() if "/" not in k}   # noqa: E731
    before = outputs(folder)
    done = tmp_path / "done" / "sweep"
    shutil.copytree(folder, done)
    assert report.main([str(done), "--resamples", "200"]) == 0
    new = outputs(done)
    assert new["scores.csv"] != before["scores.csv"]
    for point in JOURNAL_KILLS:
        copy = tmp_path / point / "sweep"
        shutil.copytree(folder, copy)
        r = _report_cli([copy, "--resamples", "200"], kill=point)
        assert r.returncode == -signal.SIGKILL, (point, r.returncode, r.stderr[-2000:])
        if point in ("tables", "staged"):
            assert outputs(copy) == before, point
        r = _report_cli([copy, "--resamples", "200"])
        assert r.returncode == 0, r.stderr
        assert outputs(copy) == new, point
        assert _leftovers(copy.parent) == [], point
        assert point in ("tables", "staged") or r.stdout.startswith(f"note: finished the interrupted report of")


def test_sides_are_paired_on_the_seeds_whose_two_sides_adapted_one_prior():
    def rows(arm, seed, src, value, prior_score="1"):
        base = {"experiment": "ratios", "arm": arm, "method": "dual_buffer", "task": "CloseMicrowave-v1",
                "seed": str(seed), "machine": "m"}
        return [{**base, "stage": "0", "role": "source", "metric": "successful_train_episodes",
                 "value": prior_score, "run": src},
                {**base, "stage": "2", "role": "adapt", "metric": "successful_train_episodes", "value": str(value),
                 "run": f"{src}/{arm}"}]
    c = next(c for c in claims_mod.CLAIMS if c.key == "c")    # ratios 0.6/0.4 vs 0.5/0.5
    same = [r for s in range(6) for arm in ("0.6/0.4", "0.5/0.5") for r in rows(arm, s, f"sw/runs/s{s}", 10 + s)]
    assert claims_mod.paired_seeds(same, c) == list(range(6))
    row = next(r for r in claims_mod.claim_rows(same, 200, [c]))
    assert row["paired"] == "yes" and row["paper_ratio"] == pytest.approx(250 / 154)
    # the same config and seed trained again in another sweep, every recorded score equal: one prior
    again = [r for r in same if not (r["seed"] == "5" and r["arm"] == "0.5/0.5")] + rows("0.5/0.5", 5, "sw2/runs/s5", 15)
    assert claims_mod.paired_seeds(again, c) == list(range(6))
    # a newer run of it records one more metric: still that prior (the scores both record are equal)
    newer = again + [{**again[-2], "metric": "diag_R_alpha", "value": "0.5"}]
    assert claims_mod.paired_seeds(newer, c) == list(range(6))
    # trained again with other scores (another CPU), or another config: not that prior; paired on the rest
    other = [r for r in same if not (r["seed"] in "45" and r["arm"] == "0.5/0.5")]
    other += rows("0.5/0.5", 4, "sw2/runs/s4", 14, prior_score="2") + rows("0.5/0.5", 5, "sw/runs/s5x", 15)
    assert claims_mod.paired_seeds(other, c) == [0, 1, 2, 3]
    row = claims_mod.claim_rows(other, 200, [c])[0]
    assert (row["n_a"], row["n_b"], row["paired"]) == (4, 4, "yes")
    # fewer than half of the smaller side's seeds pair: every seed, unpaired
    half = [r for r in same if not (r["seed"] in "0123" and r["arm"] == "0.5/0.5")]
    half += [r for s in range(4) for r in rows("0.5/0.5", s, f"sw3/runs/s{s}x", 10 + s)]
    assert not claims_mod.paired(half, c)
    assert claims_mod.claim_rows(half, 200, [c])[0]["n_a"] == 6
    # chain sides whose source stages are missing are not paired
    assert not claims_mod.paired([r for r in same if r["role"] == "adapt"], c)
    # sides from scratch pair by seed, on one kind of CPU only (issue 39)
    sc = next(c for c in claims_mod.CLAIMS if c.key == "scratch_r_matched")
    scratch = [_score(side.experiment, side.arm, side.method, s, 10 + s + i) for s in range(6)
               for i, side in enumerate((sc.a, sc.b))]
    assert claims_mod.paired_seeds(scratch, sc) == list(range(6))
    row = claims_mod.claim_rows(scratch, 200, [sc])[0]
    assert row["paired"] == "yes" and row["pair_corr"] == pytest.approx(1.0)
    mixed = [{**r, "machine": "CPU A"} if r["seed"] in "0123" and r["arm"] == "paper" else r for r in scratch]
    assert claims_mod.paired_seeds(mixed, sc) is None  # 2 of 6 seeds on one CPU kind: fewer than half
    # a side with a prior and one without never pair by seed
    h = next(c for c in claims_mod.CLAIMS if c.key == "h")
    assert not claims_mod.paired([_score(side.experiment, side.arm, side.method, s, s) for s in range(6)
                                  for side in (h.a, h.b)], h)


def test_a_run_identity_drops_its_sweeps_prefix():
    assert claims_mod.run_identity("ref_c/runs/chain/d-s0/stage0-x-1a") == "runs/chain/d-s0/stage0-x-1a"
    assert claims_mod.run_identity("runs/chain/d-s0/stage0-x-1a") == "runs/chain/d-s0/stage0-x-1a"
    assert claims_mod.run_identity("p/runs/a/runs/chain/x") == "runs/chain/x"
    assert claims_mod.run_identity("p/s0") == "p/s0"


def _score(exp, arm, method, seed, value, metric="successful_train_episodes", role="adapt", run=None,
           machine="CPU B", stage="2"):
    return {"experiment": exp, "arm": arm, "method": method, "task": "CloseMicrowave-v1", "seed": str(seed),
            "stage": stage, "role": role, "metric": metric, "value": str(value), "machine": machine,
            "run": run or f"{exp}/{arm}/{method}/s{seed}/{role}", "chain": "", "variant": ""}


def test_a_shared_prior_pairs_both_methods():
    """shared_prior: both methods adapt SAC+HER+PER's source stages, whose cells carry the prior's method."""
    c = next(c for c in claims_mod.CLAIMS if c.key == "shared_a")
    scores = []
    for s in range(5):
        scores.append(_score("shared_prior", "shared", "sac_her_per", s, 1, role="source", run=f"p/s{s}", stage="0"))
        scores += [_score("shared_prior", "shared", "dual_buffer", s, 50 + 10 * s + s % 2),
                   _score("shared_prior", "shared", "sac_her_per", s, 60 + 10 * s)]
    row = claims_mod.claim_rows(scores, 500, [c])[0]
    # the prior's spread (10 per seed) cancels: the per-seed differences are -10 or -9
    assert row["paired"] == "yes" and row["verdict"] == "contradicted" and row["diff_ci95_high"] < -8


def test_adjusted_p_values_within_each_family_and_machine_balance():
    keys = ("a", "h", "e_off", "r_matched", "warm_a")
    cs = [c for c in claims_mod.CLAIMS if c.key in keys]
    rng = np.random.default_rng(0)
    scores = []
    for c in cs:
        shift = {"a": 30, "h": 4, "e_off": 5, "r_matched": 30, "warm_a": 0}[c.key]
        for s in range(8):
            scores.append(_score(c.a.experiment, c.a.arm, c.a.method, s, 100 + shift + rng.normal(0, 8),
                                 metric=c.metric, machine="CPU A" if c.key == "warm_a" and s < 4 else "CPU B"))
            scores.append(_score(c.b.experiment, c.b.arm, c.b.method, s, 100 + rng.normal(0, 8), metric=c.metric))
    rows = {r["claim"]: r for r in claims_mod.claim_rows(scores, 1000, cs)}
    from maniskill_dualher.analysis import stats
    for fam in ("paper", "ablation"):
        fam_rows = [r for r in rows.values() if r["group"] == fam]
        p = [r["p_value"] for r in fam_rows]
        assert [r["p_holm"] for r in fam_rows] == pytest.approx(list(stats.holm(p)))
        assert [r["p_bh"] for r in fam_rows] == pytest.approx(list(stats.benjamini_hochberg(p)))
    # Holm over the family of 2 (a, h), not all 5 claims: h's p times 2 at most
    assert rows["h"]["p_holm"] <= 2 * max(rows["h"]["p_value"], rows["a"]["p_value"]) + 1e-12
    for r in rows.values():
        decided = not r["verdict"].startswith("inconclusive")
        assert (r.get("survives_holm", "") != "") == decided
        if decided:
            assert (r["survives_holm"] == "yes") == (r["p_holm"] < 0.05)
    # warm_a's A side ran on two machines, its B side on one
    assert rows["warm_a"]["machine_balanced"] == "no" and rows["a"]["machine_balanced"] == "yes"
    assert rows["warm_a"]["machines_by_side"] == "A: CPU A 4, CPU B 4 | B: CPU B 8"
    # the paper's numbers: a ratio of means and what it says about the paper's size, not a verdict
    assert rows["a"]["ratio"] == pytest.approx(rows["a"]["mean_a"] / rows["a"]["mean_b"])
    assert rows["a"]["paper_size"] == ("an effect of the paper's size (x5.56 or more) is excluded in this "
                                       "setting; the paper reports no spread")
    assert "ratio" not in rows["h"]


def test_mechanism_and_budget_claims_read_not_measured_until_their_runs_exist():
    rows = {r["claim"]: r for r in claims_mod.claim_rows([], 200)}
    for key in ("scratch_e_off", "scratch_e_batches", "scratch_r_updates", "scratch_e_on_starved",
                "adapt_r_updates", "adapt_e_on_starved", "matched_prior", "matched_a", "matched_gain"):
        assert rows[key]["verdict"] == "not measured (runs missing)", key
    assert "budget_trend" not in rows  # not a claim since issue 39 (budget.csv and fig8 describe the curve)


def test_mechanism_claims_on_synthetic_scores():
    """From scratch: E off = SAC+HER+PER, E's batches cost nothing, R's lost updates cost 40."""
    rng = np.random.default_rng(1)
    level = {("mechanism", "e_off", "dual_buffer"): 100, ("scratch", "paper", "sac_her_per"): 100,
             ("mechanism", "r_matched", "dual_buffer"): 100, ("mechanism", "r_starved", "dual_buffer"): 60,
             ("scratch", "paper", "dual_buffer"): 60}
    noise = {(cell, s): rng.normal(0, 3) for cell in level for s in range(16)}
    for s in range(16):  # E off is SAC+HER+PER bit for bit (issue 39): the same value on every seed
        noise[(("mechanism", "e_off", "dual_buffer"), s)] = noise[(("scratch", "paper", "sac_her_per"), s)]
    scores = [_score(e, a, m, s, v + noise[((e, a, m), s)]) for (e, a, m), v in level.items() for s in range(16)]
    keys = ("scratch_e_off", "scratch_e_batches", "scratch_r_updates", "scratch_e_on_starved")
    rows = {r["claim"]: r for r in claims_mod.claim_rows(scores, 1000, [c for c in claims_mod.CLAIMS
                                                                       if c.key in keys])}
    assert rows["scratch_e_off"]["verdict"].startswith("no difference larger than")
    assert rows["scratch_e_off"]["survives_holm"] == "yes" and rows["scratch_e_off"]["p_equivalence"] < 0.01
    assert rows["scratch_e_batches"]["verdict"].startswith("no difference larger than")
    assert rows["scratch_r_updates"]["verdict"] == "contradicted"
    assert rows["scratch_e_on_starved"]["verdict"].startswith("no difference larger than")
    assert all(r["paired"] == "yes" for r in rows.values())     # from scratch, one CPU kind: paired by seed
    e_off = rows["scratch_e_off"]  # the identity check reads exactly 0
    assert (e_off["diff"], e_off["diff_ci95_low"], e_off["diff_ci95_high"]) == (0.0, 0.0, 0.0)


def test_budget_curve_on_synthetic_scores(tmp_path):
    """The dual/HER ratio doubles with every doubling of the budget: the order of the methods changes along the
    curve; at 4x regime/long fills the seeds budget/x4 lacks. (No trend claim since issue 39.)"""
    from maniskill_dualher.analysis import budget, plots_budget
    rng = np.random.default_rng(2)

    def make(ratio_of):
        out = []
        for factor, cells in budget.budgets():
            exp, arm = cells[-1]
            for s in range(12):
                her = 100 * factor * np.exp(rng.normal(0, 0.1))
                out.append(_score(exp, arm, "sac_her_per", s, her))
                out.append(_score(exp, arm, "dual_buffer", s, her * ratio_of(factor) * np.exp(rng.normal(0, 0.1))))
                for m, v in (("sac_her_per", 0.9), ("dual_buffer", min(1.0, 0.3 * factor))):
                    out.append(_score(exp, arm, m, s, v, metric="final_eval_success_rate"))
        return out
    rising = make(lambda f: 0.25 * f)
    rows = budget.budget_rows(rising, 500)
    assert [r["budget_factor"] for r in rows] == [1.0, 2.0, 4.0, 8.0]
    assert [r["count_order"] for r in rows] == ["sac_her_per ahead", "sac_her_per ahead", "undecided",
                                                "dual_buffer ahead"]
    assert rows[0]["final_order"] == "sac_her_per ahead" and rows[3]["final_order"] == "dual_buffer ahead"
    assert "the order changes within the range measured" in budget.order_sentence(rows)
    assert rows[2]["cells"] == "budget/x4 or regime/long" and rows[2]["n_dual"] == 12
    assert plots_budget.plot_budget(rows, tmp_path / "b.png") and (tmp_path / "b.png").read_bytes()[:4] == b"\x89PNG"
    assert not plots_budget.plot_budget([], tmp_path / "none.png") and not (tmp_path / "none.png").exists()


def test_scores_hold_each_run_cell_and_metric_once(folder, tmp_path, capsys):
    """A shared prior's source run lists the same cell once per adapting method: scored once. A committed
    scores.csv written before (repeats) is read without them and rewritten once; a key holding two values
    is refused."""
    from maniskill_dualher.analysis.runs import SCORE_COLUMNS, score_key
    d = next(folder.glob("runs/chain/sac_her_per-s0/stage0"))
    cell = json.loads((d / "cell.json").read_text())["cells"][0]
    (d / "cell.json").write_text(json.dumps({"cells": [cell, dict(cell)]}))
    report.build_report(folder)
    scores = _table(folder / "scores.csv")
    keys = [score_key(r) for r in scores]
    assert len(keys) == len(set(keys)) and sum(r["run"].endswith("sac_her_per-s0/stage0") for r in scores) > 0
    curves = _table(folder / "curves.csv")
    assert len({tuple(r.values()) for r in curves}) == len(curves)
    ref = tmp_path / "ref"
    ref.mkdir()
    for f in folder.iterdir():
        if f.is_file():
            shutil.copy2(f, ref / f.name)
    clean = (ref / "scores.csv").read_bytes()
    lines = clean.decode().splitlines(keepends=True)
    (ref / "scores.csv").write_text("".join(lines + lines[1:4]))         # three rows written twice
    assert report.main([str(ref)]) == 0
    assert (ref / "scores.csv").read_bytes() == clean
    assert (ref / "claims.csv").read_bytes() == (folder / "claims.csv").read_bytes()
    bad = lines[1].split(",")
    bad[SCORE_COLUMNS.index("value")] = "12345"
    (ref / "scores.csv").write_text("".join(lines + [",".join(bad)]))
    before = {p: p.read_bytes() for p in ref.iterdir()}
    capsys.readouterr()
    assert report.main([str(ref)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "twice with different values" in err[0]
    assert {p: p.read_bytes() for p in ref.iterdir()} == before



# --------------------------------------------------------------------------- figures a reader can print (issue 43)
REFERENCE = Path(__file__).resolve().parents[1] / "results" / "reference"
PAGE_HEIGHT_IN = 11.0   # a printed page (US letter; A4 is 11.7)


def _png_inches(path: Path):
    import struct
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n", path
    w, h = struct.unpack(">II", head[16:24])
    from maniskill_dualher.analysis.plots import DPI
    return w / DPI, h / DPI


def test_no_reference_figure_is_taller_than_a_printed_page():
    pngs = sorted(REFERENCE.glob("*.png"))
    assert len(pngs) >= 5
    tall = {p.name: round(_png_inches(p)[1], 2) for p in pngs if _png_inches(p)[1] > PAGE_HEIGHT_IN}
    assert tall == {}, f"taller than {PAGE_HEIGHT_IN} in: {tall}"


def test_reference_has_one_ablation_figure_per_ablation_experiment():
    from maniskill_dualher.experiment import registry
    from maniskill_dualher.analysis.runs import read_rows
    present = {r["experiment"] for r in read_rows(REFERENCE / "ablations.csv")}
    want = {registry.fig6_file(e) for e in registry.experiments_feeding(registry.FIG6) if e in present}
    assert len(want) >= 5
    assert {p.name for p in REFERENCE.glob("fig6*.png")} == want
    summary = (REFERENCE / "summary.md").read_text()
    assert all(f"]({f})" in summary for f in want)


def test_ablation_legends_are_registry_display_names_one_colour_per_arm(tmp_path, monkeypatch):
    """Every legend label of every ablation figure drawn from the reference is "<method display>, <arm display>"
    of a registry cell (no internal arm key), one label has one colour in every figure, and no two curves of a
    figure share a colour (a split figure draws its comparison lines in every column)."""
    from maniskill_dualher.analysis import plots
    from maniskill_dualher.analysis.runs import read_rows
    from maniskill_dualher.experiment import registry
    from maniskill_dualher.methods import METHOD_SPECS
    drawn = []   # (figure, label, colour, line style)
    draw = plots.draw

    def spy(ax, groups, *a, **k):
        drawn.extend((current[0], lab, line.color, line.linestyle) for lab, line in groups.items())
        return draw(ax, groups, *a, **k)
    monkeypatch.setattr(plots, "draw", spy)
    curves = read_rows(REFERENCE / "curves.csv")
    present = {r["experiment"] for r in curves}
    current = [None]
    for e in registry.experiments_feeding(registry.FIG6):
        if e in present:
            current[0] = e
            assert plots.plot_ablation(curves, tmp_path / registry.fig6_file(e), e)
    assert len({f for f, *_ in drawn}) >= 5
    allowed = {f"{s.display}, {registry.arm_display(x.name, a.name)}"
               for x in registry.EXPERIMENTS.values() for a in x.arms for s in METHOD_SPECS.values()}
    labels = {lab for _, lab, _, _ in drawn}
    assert labels <= allowed, sorted(labels - allowed)
    keys = {a.name for x in registry.EXPERIMENTS.values() for a in x.arms if "_" in a.name}
    import re
    leaked = [(lab, k) for lab in labels for k in keys
              if re.search(rf"\b({re.escape(k)}|{re.escape(k.replace('_', ' '))})\b", lab)]
    assert leaked == []
    colour = {}
    for _, lab, c, _ in drawn:
        assert colour.setdefault(lab, c) == c, f"{lab} drawn in {colour[lab]} and {c}"
    for fig in {f for f, *_ in drawn}:
        lines = {(lab, c) for f, lab, c, _ in drawn if f == fig}
        assert len({c for _, c in lines}) == len(lines), f"{fig}: two curves in one colour"


def _train_folder(run: Path, done=True):
    """A folder as `train --out RUN` leaves it: no cell.json (no sweep), diagnostics.csv beside metrics.csv."""
    _write_run(run, _cfg("ReachTarget-v1", "dual_buffer", 0), [0, 3, 9], [0.0, 2.0, 5.0], [], done=done)
    (run / "cell.json").unlink()
    (run / "diagnostics.csv").write_text("env_steps,R_alpha,R_entropy,R_qf_loss,R_qf_values,R_td_abs,R_updates,"
                                         "E_alpha,E_qf_loss,updates\n100,0.005,5,0.3,0.1,0.8,1,,,1\n"
                                         "200,0.004,4,0.1,0.5,0.4,100,0.004,0.01,101\n"
                                         "300,0.003,3,0.05,0.7,0.2,100,0.003,0.02,201\n")


def test_report_of_one_run_draws_its_curves_and_says_its_numbers(tmp_path, capsys):
    """Issue 51: `report RUN` on train's own folder writes RUN/curves.png (every panel its files fill, none empty)
    and prints the final evaluation, the successful training episodes and the env steps; exit 0."""
    from maniskill_dualher.analysis import run_curves
    run = tmp_path / "run"
    _train_folder(run)
    assert report.main([str(run)]) == 0
    out = capsys.readouterr().out
    assert (run / "curves.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "300 of 300 env steps (finished)" in out and "successful training episodes: 9 of 6\n" in out
    assert "final evaluation (env step 300, 10 episodes): success 0.50, return 5" in out
    assert not [p for p in run.iterdir() if p.name.startswith(".")]  # written atomically: no temp file left
    from maniskill_dualher import rundir
    titles = [p["title"] for p in run_curves.panels(rundir.read_metrics(run), rundir.read_metrics(run, "diagnostics.csv"))]
    assert titles[:3] == ["Evaluation success", "Evaluation return", "Training episodes"]
    assert "Critic loss" in titles and "Alpha (entropy coefficient)" in titles
    # a sweep's folder holding only such runs says what they are, in the singular for one
    assert report.main([str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "1 finished run of no sweep" in err and f"report {run}" in err and "runs)" not in err


def test_report_of_one_run_says_where_its_critic_went_beside_what_its_rewards_allow(tmp_path, capsys):
    """A critic whose mean Q leaves 1/(1 - gamma) (rewards in {0, 1}) has diverged (the paper regime's `step`
    runs): `report RUN` says where, and how many successes came by then and after; the Q panel draws the bound."""
    from maniskill_dualher.analysis import run_curves
    run = tmp_path / "run"
    _train_folder(run)
    assert report.main([str(run)]) == 0
    out = capsys.readouterr().out
    assert "critic, mean Q on its R batches (between evaluations): peak 0.7 at env step 300, last 0.7" in out
    assert "bound a return by 1/(1 - gamma) = 100: |Q| never above it" in out
    diag = run / "diagnostics.csv"
    diag.write_text(diag.read_text().replace("\n200,0.004,4,0.1,0.5,", "\n200,0.004,4,0.1,250,"))
    assert report.main([str(run)]) == 0
    out = capsys.readouterr().out
    assert ("peak 250 at env step 200, last 0.7; rewards in {0, 1} bound a return by 1/(1 - gamma) = 100: |Q| above "
            "it at 1 of 3 points, first at env step 200, last at 200 (successful training episodes by the first: 3; "
            "after the last: 6)") in out
    cfg = json.loads((run / "config.json").read_text())
    assert run_curves.return_bound({**cfg, "reward_mode": "dense"}) is None
    assert run_curves.return_bound({**cfg, "sac": {**cfg["sac"], "gamma": 0.95}}) == pytest.approx(20)
    # a diverged critic and the bound on one symlog axis: decades from the bound out, none inside
    assert run_curves._symlog_ticks([1.0, 7e4, -50.0], 1 / (1 - 0.99)) == [0.0, 100.0, 1e3, 1e4, 1e5]
    assert run_curves._symlog_ticks([1.0, 7e4, -500.0], 100.0) == [-1e3, -100.0, 0.0, 100.0, 1e3, 1e4, 1e5]


def test_committed_critic_traces_say_what_their_report_lines_say():
    """results/paper_regime_critics: report_lines.txt is what `report RUN` says of each committed run folder
    today, so the HOW_MADE's table is checkable from the raw files."""
    from bench_cli import load_bench
    step_critics = load_bench("step_critics.py")   # the lines as the tool that writes them says them today
    repo = Path(__file__).resolve().parents[1]
    root = repo / "results" / "paper_regime_critics"
    # one study folder per merged `step` run, no more and none missing: the traces follow the confirmatory folder
    step_runs = step_critics.merged_step_runs(repo)
    assert len(step_runs) >= 2 and {p.name for p in (root / "study").iterdir()} == step_runs
    assert (root / "report_lines.txt").read_text() == step_critics.report_lines(repo)


def test_step_critics_puts_a_parts_runs_back_as_committed(tmp_path):
    """bench/step_critics.py: seed 5's two step runs, laid out as a sweep wrote them (the clone's absolute path in
    provenance, and in its argv), come back byte for byte as committed, and so does report_lines.txt; the same part again adds
    nothing; a part whose run differs from the committed folder is refused in one line, nothing written."""
    from bench_cli import run_bench
    repo = Path(__file__).resolve().parents[1]
    src = repo / "results" / "paper_regime_critics"
    root = tmp_path / "repo"
    critics = root / "results" / "paper_regime_critics"
    shutil.copytree(src, critics, ignore=shutil.ignore_patterns("curves.png"))
    (root / "results" / "paper_regime_confirm").mkdir()
    shutil.copy(repo / "results" / "paper_regime_confirm" / "scores.csv", root / "results" / "paper_regime_confirm")
    sweep = tmp_path / "s5"
    for method in ("dual_buffer", "sac_her_per"):
        run = sweep / "runs" / "chain" / f"{method}-s5" / "stage2-CloseMicrowave-v1"
        shutil.copytree(src / "study" / f"s5-{method}", run, ignore=shutil.ignore_patterns("curves.png"))
        prov = json.loads((run / "provenance.json").read_text())
        for start in prov["starts"]:
            start["repo"] = "/somewhere/frozen"
            start["argv"][0] = "/somewhere/frozen/" + start["argv"][0]   # python -m gives the module's full path
        (run / "provenance.json").write_text(json.dumps(prov, indent=2) + "\n")
        (run / "cell.json").write_text(json.dumps({"cells": [
            {"experiment": "paper_regime", "arm": "step", "role": "adapt", "seed": 5, "method": method}]}))
        shutil.rmtree(critics / "study" / f"s5-{method}")
    (critics / "report_lines.txt").write_text("stale\n")
    r = run_bench("step_critics.py", str(sweep), "--root", str(root))
    assert r.returncode == 0, r.stderr
    assert "added 2 of 2 runs" in r.stdout and "study/s5-dual_buffer: dual_buffer on CloseMicrowave-v1" in r.stdout
    for method in ("dual_buffer", "sac_her_per"):
        want = sorted(p.name for p in (src / "study" / f"s5-{method}").iterdir() if p.name != "curves.png")
        got = critics / "study" / f"s5-{method}"
        assert sorted(p.name for p in got.iterdir()) == want
        assert all((got / n).read_bytes() == (src / "study" / f"s5-{method}" / n).read_bytes() for n in want)
    assert (critics / "report_lines.txt").read_text() == (src / "report_lines.txt").read_text()
    assert "added 0 of 2 runs" in run_bench("step_critics.py", str(sweep), "--root", str(root)).stdout
    with open(sweep / "runs" / "chain" / "dual_buffer-s5" / "stage2-CloseMicrowave-v1" / "metrics.csv", "a") as f:
        f.write("\n")
    (critics / "report_lines.txt").write_text("kept\n")
    r = run_bench("step_critics.py", str(sweep), "--root", str(root))
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "s5-dual_buffer" in r.stderr
    assert (critics / "report_lines.txt").read_text() == "kept\n"


def test_report_of_an_unfinished_run_says_last_and_how_it_resumes(tmp_path, capsys):
    """A run still training (or killed) has no final evaluation yet: its last one, and the command that resumes it
    (train's own folder: `train --out` again; a sweep's run, which has cell.json: its sweep)."""
    run = tmp_path / "run"
    _train_folder(run, done=False)
    assert report.main([str(run)]) == 0
    out = capsys.readouterr().out
    assert "(unfinished: train again with the same --out to resume)" in out
    assert "last evaluation (env step 300, 10 episodes): success 0.50" in out and "final evaluation" not in out
    (run / "cell.json").write_text("{}")
    assert report.main([str(run)]) == 0
    assert "(unfinished: rerun its sweep to resume)" in capsys.readouterr().out


def test_report_of_a_run_without_an_evaluation_says_so(tmp_path, capsys):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(_cfg("ReachTarget-v1", "sac", 0).to_json())
    assert report.main([str(run)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "without an evaluation yet" in err[0] and not (run / "curves.png").exists()


def test_step_ticks_and_counts_read_in_units():
    """Issue 51: env-step ticks in k or M (3M, not 3000k); one of a thing is singular."""
    from maniskill_dualher.fileio import plural, steps_text
    assert [steps_text(v) for v in (0, 500, 4000, 12_500, 1e6, 3_000_000, 3_600_000)] == \
        ["0", "500", "4k", "12.5k", "1M", "3M", "3.6M"]
    assert (plural(1, "episode"), plural(2, "episode"), plural(0, "worker")) == ("1 episode", "2 episodes", "0 workers")
    assert (plural(3_500_001, "update", thousands=True), plural(3_500_001, "update")) == ("3,500,001 updates",
                                                                                         "3500001 updates")
