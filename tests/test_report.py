"""report.py on hand-made run folders (no training): numbers, grouping, findings, robustness."""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from maniskill_dualher import protocol, report
from maniskill_dualher.config import ReplayConfig, RunConfig


def _write_run(folder: Path, cfg: RunConfig, successes, returns, stage=None, done=True, wall=1.0):
    """A run folder as train.py leaves it: config.json, metrics.csv (one row per eval), done.json."""
    folder.mkdir(parents=True)
    (folder / "config.json").write_text(cfg.to_json())
    rows = [{"env_steps": 100 * (i + 1), "eval_return": r, "eval_success_rate": r / 10, "train_episodes": 2 * (i + 1),
             "train_successes": s, "wall_time_s": wall * (i + 1)} for i, (s, r) in enumerate(zip(successes, returns))]
    with open(folder / "metrics.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    if stage is not None:
        (folder / "stage.json").write_text(json.dumps(stage))
    if done:
        (folder / "done.json").write_text(json.dumps({"final": rows[-1]}))


def _adapt_stage():
    return {"stage": 2, "n_stages": 3, "adaptation": True, "chain": list(protocol.TRANSFER_ORDER),
            "parent": "p", "carry_replay": True}


def _cfg(env, method, seed, ratio=(0.6, 0.4), steps=300):
    return RunConfig(env_id=env, method=method, seed=seed, total_steps=steps, replay=ReplayConfig(ratio=ratio))


@pytest.fixture
def folder(tmp_path):
    """3 seeds of sac_her_per vs dual_buffer adaptation, two ratios, and single-task runs of 2 methods."""
    out = tmp_path / "sweep"
    adapt = {("sac_her_per", (0.6, 0.4)): [1, 2, 3], ("dual_buffer", (0.6, 0.4)): [10, 12, 14],
             ("dual_buffer", (0.5, 0.5)): [4, 6, 8]}
    for (method, ratio), finals in adapt.items():
        for seed, final in enumerate(finals):
            _write_run(out / f"runs/transfer/{method}-s{seed}/stage2-{ratio[0]}", _cfg("CloseMicrowave-v1", method, seed,
                       ratio), [0, final], [0.0, final / 2], stage=_adapt_stage())
    # a source stage: never in the tables
    _write_run(out / "runs/transfer/sac_her_per-s0/stage0", _cfg("ReachTarget-v1", "sac_her_per", 0), [99], [9.0],
               stage={**_adapt_stage(), "stage": 0, "adaptation": False})
    for method, vals in (("sac", [0.0, 1.0, 2.0]), ("dual_buffer", [5.0, 6.0, 7.0])):
        for seed, v in enumerate(vals):
            _write_run(out / f"runs/single/CloseBox-v1-{method}-s{seed}", _cfg("CloseBox-v1", method, seed),
                       [1, 2], [0.0, v])
    return out


def _table(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_tables_hold_the_final_rows_aggregated_over_seeds(folder):
    report.build_report(folder)
    t5 = {(r["method"], r["metric"]): r for r in _table(folder / "table5_multitask.csv")}
    row = t5[("dual_buffer", "successful_train_episodes")]
    assert (row["n_seeds"], row["seeds"], float(row["mean"]), float(row["std"])) == ("3", "0 1 2", 12.0, 2.0)
    assert row["paper"] == "250" and row["ratio"] == "0.6/0.4" and row["env_steps"] == "300"
    assert 10 <= float(row["ci95_low"]) < 12 < float(row["ci95_high"]) <= 14
    # mean over each run's evaluations (area under the curve): returns [0, 0.5], [0, 1], [0, 1.5]
    assert float(t5[("sac_her_per", "mean_eval_return")]["mean"]) == 0.5
    assert t5[("sac_her_per", "successful_train_episodes")]["paper"] == "<45"
    assert ("dual_buffer", "successful_train_episodes") in t5 and len(t5) == 8  # 0.5/0.5 is Table 4's only
    t4 = _table(folder / "table4_sampling_ratio.csv")
    assert [(r["ratio"], float(r["mean"]), r["paper"]) for r in t4] == [("0.5/0.5", 6.0, "154"), ("0.6/0.4", 12.0, "250")]
    single = {(r["method"], r["metric"]): r for r in _table(folder / "single_task.csv")}
    assert float(single[("dual_buffer", "mean_eval_return")]["mean"]) == 3.0   # curves [0, 5], [0, 6], [0, 7]
    assert float(single[("sac", "final_eval_success_rate")]["mean"]) == pytest.approx(0.1)
    assert {r["task"] for r in single.values()} == {"CloseBox-v1"}          # the source stage is not a single run


def test_claims_are_computed_from_the_numbers(folder):
    report.build_report(folder)
    claims = {r["claim"]: r for r in _table(folder / "claims.csv")}
    assert list(claims) == ["a", "b", "c", "d", "e", "f", "g", "h", "h'"]
    a = claims["a"]  # dual 10, 12, 14 vs sac_her_per 1, 2, 3 successful adaptation episodes
    assert (float(a["mean_a"]), float(a["mean_b"]), float(a["diff"])) == (12.0, 2.0, 10.0)
    assert 0 < float(a["diff_ci95_low"]) < 10 < float(a["diff_ci95_high"]) and a["verdict"] == "reproduced"
    assert float(a["prob_improvement"]) == 1.0
    assert claims["c"]["verdict"] == "reproduced"         # 0.6/0.4: 10..14 vs 0.5/0.5: 4..8
    assert claims["d"]["verdict"].startswith("not measured")  # no 0.7/0.3 runs
    assert claims["f"]["verdict"] == "reproduced"         # CloseBox curves: dual [0, 5..7] vs sac [0, 0..2]
    assert claims["e"]["verdict"].startswith("not measured")
    assert claims["h"]["verdict"].startswith("not measured")  # no from-scratch control in this folder
    s = (folder / "summary.md").read_text()
    line = next(ln for ln in s.splitlines() if ln.startswith("| a |"))
    assert "**reproduced**" in line and "Table 5: 250 vs <45" in line
    assert "compare directions and ratios" in s


def test_scratch_control_sits_beside_transfer(folder):
    """The from-scratch control enters Table 5 as its own chain and decides claim (h)."""
    for seed, final in enumerate([3, 4, 5]):
        cfg = _cfg("CloseMicrowave-v1", "dual_buffer", seed)
        _write_run(folder / f"runs/scratch/dual_buffer-s{seed}/stage0", cfg, [0, final], [0.0, 0.2],
                   stage={"protocol": "scratch", "stage": 0, "n_stages": 1, "adaptation": True,
                          "chain": ["CloseMicrowave-v1"], "parent": None, "carry_replay": True})
    report.build_report(folder)
    t5 = _table(folder / "table5_multitask.csv")
    chains = {(r["chain"], r["method"]) for r in t5}
    assert (report.SCRATCH, "dual_buffer") in chains and (" > ".join(protocol.TRANSFER_ORDER), "dual_buffer") in chains
    assert all(r["chain"] != report.SCRATCH for r in _table(folder / "table4_sampling_ratio.csv"))
    h = {r["claim"]: r for r in _table(folder / "claims.csv")}["h"]
    assert (float(h["mean_a"]), float(h["mean_b"])) == (12.0, 4.0) and h["verdict"] == "reproduced"


def test_bootstrap_is_seeded_and_brackets_the_mean():
    x = [0.0, 1.0, 5.0, 2.0]
    assert report.bootstrap_ci(x) == report.bootstrap_ci(x)
    lo, hi = report.bootstrap_ci(x)
    assert 0.0 <= lo < np.mean(x) < hi <= 5.0
    one = report.summarize([3.0])
    assert one["ci95_low"] == one["ci95_high"] == 3.0 and math.isnan(one["std"])


def test_wall_time_and_unfinished_runs_do_not_change_tables(folder):
    report.build_report(folder)
    before = {n: (folder / n).read_bytes() for n in ("table4_sampling_ratio.csv", "table5_multitask.csv",
                                                      "single_task.csv")}
    # other wall times (a resumed run) and an unfinished run: same tables
    for m in folder.glob("runs/single/*/metrics.csv"):
        m.write_text(m.read_text().replace(",1.0\n", ",77.5\n"))
    _write_run(folder / "runs/single/CloseBox-v1-sac-s9", _cfg("CloseBox-v1", "sac", 9), [50], [50.0], done=False)
    report.build_report(folder)
    assert {n: (folder / n).read_bytes() for n in before} == before
    assert "1 runs unfinished" in (folder / "summary.md").read_text()
    assert not list(folder.glob(".*.tmp")) and not list(folder.glob(".*.png"))   # atomic writes leave no temp files


def test_sweep_json_selects_the_runs(folder):
    runs = sorted(str(p.parent.relative_to(folder)) for p in folder.rglob("config.json") if "single" in str(p))
    (folder / "sweep.json").write_text(json.dumps({"preset": "unit", "runs": runs}))
    report.build_report(folder)
    assert _table(folder / "table5_multitask.csv") == []
    assert len(_table(folder / "single_task.csv")) == 8  # 2 methods x 4 metrics
    assert (folder / "summary.md").read_text().startswith("# Results: unit")
    assert (folder / "fig4_single_task.png").is_file()


def test_hyperparameters_put_ours_beside_table3(folder):
    report.build_report(folder)
    hp = {r["hyperparameter"]: r for r in _table(folder / "hyperparameters.csv")}
    assert hp["learning rate"]["paper"] == "0.0001" and hp["batch size"]["ours_single_task"] == "256"
    assert hp["dual buffer sampling ratio P(R)/P(E)"]["ours_transfer"] == "0.5/0.5; 0.6/0.4"
    assert hp["replay memory size"]["paper"] == "10^7"


def test_plots_are_written(folder):
    written = report.build_report(folder)
    for name in ("fig4_single_task.png", "fig5_multitask.png"):
        assert folder / name in written
        assert (folder / name).read_bytes()[:4] == b"\x89PNG"


def test_cli_on_missing_or_empty_folder(tmp_path, capsys):
    assert report.main([str(tmp_path / "nope")]) == 2
    assert capsys.readouterr().err.strip().startswith("error: no such folder")
    assert report.main([str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no run folders" in err[0]
    assert list(tmp_path.iterdir()) == []
