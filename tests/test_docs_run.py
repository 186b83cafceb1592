"""The docs run as typed: every ```python block and every ```bash/```sh block of README.md and docs/*.md, as
written, each in a fresh process, from a stand-in for the repository root (a temporary folder with a copy of
results/: a block's outputs, runs/, traj/, a movie, land there and the checkout stays as it was). A block that
cannot run in seconds (a sweep, an install, a cluster) is listed in ``NOT_RUN`` with why, or in ``SHORTENED``
with the budget it runs at, both keyed by the block's fingerprint: its file and first line."""
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOCS = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]

NOT_RUN = {
    "README.md: pip install torch --index-url https://download.pytorch.org/whl/cpu   # CPU torch first":
        "installs packages",
    "README.md: import gymnasium as gym":
        "run as written by tests/test_readme.py::test_load_policy_snippet_runs_as_written",
    "README.md: python -m maniskill_dualher.sweep --experiments single --tasks ReachTarget-v1 --seeds 5 --out "
    "runs/first   # ~5 min, claim (e)":
        "sweeps of minutes to hours (the smoke sweep is tests/test_sweep.py's); the report reads their runs/quick",
    "docs/experiments.md: python -m maniskill_dualher.sweep --preset smoke --out /tmp/smoke      # whole pipeline, "
    "~1 min, learns nothing":
        "sweeps of minutes to hours; `report results/reference` rewrites the committed folder; runs/mine and "
        "runs/more stand for the reader's own sweeps",
    "docs/cluster.md: # on the head node": "starts a Ray cluster",
    "docs/cluster.md: cat > /shared/jobs/line.sbatch <<'EOF'": "submits SLURM jobs on /shared",
    "docs/tasks.md: python -m maniskill_dualher.evaluate results/policies/CloseBox-v1/sac_her_per --episodes 3 "
    "--record traj/":
        "run as written by tests/test_evaluate.py::test_the_documented_replay_recipe_runs_as_typed",
}

# fingerprint -> (why, [(text as written, text run instead)])
SHORTENED = {
    "docs/training.md: python -m maniskill_dualher.train --preset quick --env CloseMicrowave-v1 --method "
    "sac_her_per --out runs/mw":
        ("a 16k-step training run (minutes); 500 env steps make the run folder the evaluations after it read",
         [("--out runs/mw\n", "--total-steps 500 --out runs/mw\n")]),
}


def doc_blocks():
    """[(fingerprint, language, code, "file:line")] of every python, bash and sh block, in file order."""
    out = []
    for doc in DOCS:
        text, name = doc.read_text(), str(doc.relative_to(REPO))
        for m in re.finditer(r"^```(python|bash|sh)\n(.*?)^```", text, re.M | re.S):
            code = m.group(2)
            first = next(ln for ln in code.splitlines() if ln.strip())
            line = text.count("\n", 0, m.start()) + 1
            out.append((f"{name}: {first.strip()}", m.group(1), code, f"{name}:{line}"))
    return out


BLOCKS = doc_blocks()


def test_every_block_runs_or_says_why_not():
    """Each block is told apart by its fingerprint, and every listed fingerprint (and text it shortens) is still
    in the docs: a list that outlived its block would hide nothing, but mislead."""
    prints = [b[0] for b in BLOCKS]
    assert len(prints) == len(set(prints)), [p for p in prints if prints.count(p) > 1]
    assert not (set(NOT_RUN) | set(SHORTENED)) - set(prints), (set(NOT_RUN) | set(SHORTENED)) - set(prints)
    assert not set(NOT_RUN) & set(SHORTENED)
    code = dict((b[0], b[2]) for b in BLOCKS)
    for key, (_, subs) in SHORTENED.items():
        assert all(old in code[key] for old, _ in subs), key


@pytest.fixture(scope="module")
def results_copy(tmp_path_factory):
    dst = tmp_path_factory.mktemp("repo") / "results"
    shutil.copytree(REPO / "results", dst, ignore=shutil.ignore_patterns("runs"))
    return dst


def run_block(lang: str, code: str, cwd: Path, results: Path) -> subprocess.CompletedProcess:
    (cwd / "results").symlink_to(results)
    env = dict(os.environ, PYTHONPATH=str(REPO),  # `python` is this interpreter, as in the reader's shell
               PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    cmd = [sys.executable, "-c", code] if lang == "python" else ["bash", "-e", "-o", "pipefail", "-c", code]
    return subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


def _params(langs):
    return [pytest.param(*b, id=b[3]) for b in BLOCKS if b[1] in langs]


def _run(key, lang, code, tmp_path, results):
    if key in NOT_RUN:
        pytest.skip(f"not run: {NOT_RUN[key]}")
    for old, new in SHORTENED.get(key, ("", []))[1]:
        code = code.replace(old, new)
    r = run_block(lang, code, tmp_path, results)
    assert r.returncode == 0, f"{key}\n{r.stdout[-2000:]}\n{r.stderr[-3000:]}"


@pytest.mark.parametrize("key, lang, code, where", _params({"python"}))
def test_python_block_runs_as_written(key, lang, code, where, tmp_path, results_copy):
    """Each Python block (a few seconds each)."""
    _run(key, lang, code, tmp_path, results_copy)


@pytest.mark.parametrize("key, lang, code, where", _params({"bash", "sh"}))
def test_command_block_runs_as_written(key, lang, code, where, tmp_path, results_copy):
    """Each command block not listed above, as written or at its shortened budget (seconds each)."""
    _run(key, lang, code, tmp_path, results_copy)
