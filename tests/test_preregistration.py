"""A claim is committed before the runs that decide it: each of the paper regime's amendments (the `step` schedule's
group-sequential rule, Amendment 1; the `step_empty` arm, Amendment 3) precedes every result of the arm it defines,
checked against the repository's history."""
import csv
import io
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
AMENDMENT = "results/paper_regime/AMENDMENT.md"
# (arm, the text whose first commit into AMENDMENT.md defines it): Amendment 1 is the file's first text
DEFINED_BY = [("step", "# Amendment 1 to the preregistration"), ("step_empty", "## Amendment 3: a follow-up arm")]


def _git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(REPO), *args], capture_output=True, text=True, check=True).stdout


def _arm_rows(text: str, arm: str) -> int:
    return sum(r["experiment"] == "paper_regime" and r["arm"] == arm for r in csv.DictReader(io.StringIO(text)))


def _defining_commit(marker: str):
    try:
        commits = _git("log", "-S", marker, "--format=%H", "--", AMENDMENT).split()
    except (OSError, subprocess.CalledProcessError):
        pytest.skip("no git history here")
    if not commits:
        pytest.skip(f"{AMENDMENT}'s {marker!r} is not committed yet")
    return commits[-1]   # the oldest: where the text entered the file


@pytest.mark.parametrize("arm, marker", DEFINED_BY, ids=[a for a, _ in DEFINED_BY])
def test_the_amendment_precedes_every_result_of_its_arm(arm, marker):
    commit = _defining_commit(marker)
    at_amendment = [p for p in _git("ls-tree", "-r", "--name-only", commit, "results").split()
                    if p.endswith("scores.csv")]
    assert at_amendment, "the amendment's commit holds the results folders"
    for path in at_amendment:
        assert _arm_rows(_git("show", f"{commit}:{path}"), arm) == 0, \
            f"{path} held {arm} rows at the amendment {commit}"
    # every row of the arm there is now came later: from a commit that descends from the amendment's
    for path in sorted((REPO / "results").rglob("scores.csv")):
        if _arm_rows(path.read_text(), arm):
            rel = str(path.relative_to(REPO))
            for c in _git("log", "-S", f"paper_regime,{arm},", "--format=%H", "--", rel).split():
                assert subprocess.run(["git", "-C", str(REPO), "merge-base", "--is-ancestor", commit, c]).returncode \
                    == 0, f"{rel}: {arm} rows from {c}, which does not descend from the amendment {commit}"
