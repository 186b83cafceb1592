"""Issue 51's edges, each as a user meets it: a cut-short policy file says why it cannot be read; `evaluate
--record` writes under runs/ (ignored by git) unless given a path; one of a thing is singular; no figure title says
"no runs in this folder" (summary.md says it)."""
from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

from maniskill_dualher import evaluate

REPO = Path(__file__).resolve().parents[1]
POLICY = REPO / "results" / "policies" / "ReachTarget-v1" / "sac_her_per" / "policy.pt"


@pytest.mark.parametrize("cut, cause", [
    (lambda b: b[: len(b) // 2], "the file is cut short ("),
    (lambda b: b"", "the file is empty (0 bytes)"),
    (lambda b: b"hello, not torch", "not a torch file (it starts with b'hell'"),
])
def test_a_broken_policy_file_names_the_cause(tmp_path, capsys, cut, cause):
    bad = tmp_path / "policy.pt"
    bad.write_bytes(cut(POLICY.read_bytes()))
    assert evaluate.main([str(bad), "--episodes", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: unreadable policy file {bad}: {cause}"), err
    assert "OSError" not in err[0] and "EOFError" not in err[0]


def test_record_writes_under_runs_by_default_and_git_ignores_it(tmp_path, monkeypatch, capsys):
    """`--record` alone: runs/recordings under the working folder; `--record DIR`: DIR. Generated folders (runs/,
    a top-level run's exported policies/, a job file's -configs/) are ignored by git."""
    assert evaluate.build_parser().parse_args(["p", "--record"]).record == evaluate.RECORD_DIR == "runs/recordings"
    assert evaluate.build_parser().parse_args(["p", "--record", "mine"]).record == "mine"
    monkeypatch.chdir(tmp_path)
    assert evaluate.main([str(POLICY.parent), "--episodes", "1", "--record"]) == 0
    out = capsys.readouterr().out
    assert "1 episode on held-out seeds" in out  # singular
    written = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.rglob("*") if p.is_file())
    assert written and all(p.startswith("runs/recordings/") for p in written), written
    assert f"trajectory   {evaluate.RECORD_DIR}/" in out
    if shutil.which("git") and (REPO / ".git").exists():
        paths = ["runs/recordings/ReachTarget-v1.seed2000000000.n1.h5", "policies/ReachTarget-v1/sac/policy.json",
                 "jobs-configs/run.json"]
        r = subprocess.run(["git", "check-ignore", *paths], cwd=REPO, capture_output=True, text=True)
        assert r.stdout.split() == paths


def test_one_worker_is_singular():
    from maniskill_dualher.experiment.cost import Cost, describe
    lines = describe(Cost(runs=1, env_steps=1000, updates_low=10, updates_high=10, core_seconds_low=5.0,
                          core_seconds_high=5.0, env_steps_per_s=900.0), 1)
    assert any("this machine with 1 worker:" in ln for ln in lines) and not any("1 workers" in ln for ln in lines)


@pytest.mark.parametrize("folder", ["results/paper_regime", "results/reference"])
def test_no_figure_title_says_no_runs_and_summary_names_the_arms_not_drawn(folder, monkeypatch, tmp_path):
    """The ablation figures' titles name the experiment and how to read it; the arms a figure does not draw are
    listed in the committed summary.md instead."""
    from maniskill_dualher.analysis import plots
    from maniskill_dualher.analysis.runs import read_rows
    from maniskill_dualher.experiment import registry
    curves = read_rows(REPO / folder / "curves.csv")
    titles = {}
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: titles.__setitem__(path.name, fig._suptitle.get_text()))
    undrawn = {}
    for e in registry.experiments_feeding(registry.FIG6):
        if folder == "results/reference" and e not in ("budget", "e_share"):
            continue  # two of the reference's: enough, and quick
        if plots.plot_ablation(curves, tmp_path / registry.fig6_file(e), e):
            undrawn[registry.fig6_file(e)] = plots.undrawn_arms(curves, e)
    assert titles and not [t for t in titles.values() if "no runs" in t], titles
    summary = (REPO / folder / "summary.md").read_text()
    for fig, arms in undrawn.items():
        if arms:
            assert f"- `{fig}`: " + "; ".join(f'"{a}"' for a in arms) + "\n" in summary, fig
