"""A claim is committed before the runs that decide it: the paper regime's amendment (its group-sequential rule
for the `step` schedule) precedes every `step` result, checked against the repository's history."""
import csv
import io
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
AMENDMENT = "results/paper_regime/AMENDMENT.md"


def _git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(REPO), *args], capture_output=True, text=True, check=True).stdout


def _step_rows(text: str) -> int:
    return sum(r["experiment"] == "paper_regime" and r["arm"] == "step" for r in csv.DictReader(io.StringIO(text)))


def test_the_amendment_precedes_every_step_result():
    try:
        first = _git("log", "--diff-filter=A", "--format=%H", "--", AMENDMENT).split()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("no git history here")
    if not first:
        pytest.skip(f"{AMENDMENT} is not committed yet")
    commit = first[-1]
    at_amendment = [p for p in _git("ls-tree", "-r", "--name-only", commit, "results").split()
                    if p.endswith("scores.csv")]
    assert at_amendment, "the amendment's commit holds the results folders"
    for path in at_amendment:
        assert _step_rows(_git("show", f"{commit}:{path}")) == 0, f"{path} held step rows at the amendment {commit}"
    # every step row there is now came later: from a commit that descends from the amendment's
    for path in sorted((REPO / "results").rglob("scores.csv")):
        if _step_rows(path.read_text()):
            rel = str(path.relative_to(REPO))
            added = _git("log", "-S", "paper_regime,step", "--format=%H", "--", rel).split()
            for c in added:
                assert subprocess.run(["git", "-C", str(REPO), "merge-base", "--is-ancestor", commit, c]).returncode \
                    == 0, f"{rel}: step rows from {c}, which does not descend from the amendment {commit}"
