"""Add a finished `step` part's adaptation runs to results/paper_regime_critics (their traces; the scores go to
results/paper_regime_confirm by `report --merge`).

    python -m maniskill_dualher.report results/paper_regime_confirm --merge s6
    python bench/step_critics.py s6

For each finished adaptation run of the paper_regime `step` arm in the sweep folder, its config, metrics,
diagnostics, done, lineage and provenance files go to study/s{seed}-{method}/ (provenance's clone path written as
`.`, as in every committed folder), staged beside it and renamed; a folder already there stays as it is when it
holds the same files, and is refused (exit 2, nothing written) when it differs. Then report_lines.txt is written
anew from every study and diagnostic folder, as `report RUN` says each (what tests/test_report.py holds), and the
lines of the added runs are printed: the facts the folder's HOW_MADE table takes.
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import json
import shutil
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from maniskill_dualher.analysis import run_curves  # noqa: E402
from maniskill_dualher.cmdline import OneLineParser  # noqa: E402
from maniskill_dualher.fileio import atomic_write_text  # noqa: E402

FILES = ("config.json", "diagnostics.csv", "done.json", "lineage.json", "metrics.csv", "provenance.json")


def step_runs(sweep: Path):
    """(name, run folder) of every adaptation run of the paper_regime `step` arm in a sweep folder."""
    out = []
    for cell_file in sorted(sweep.rglob("cell.json")):
        for cell in json.loads(cell_file.read_text())["cells"]:
            if (cell["experiment"], cell["arm"], cell["role"]) == ("paper_regime", "step", "adapt"):
                out.append((f"s{cell['seed']}-{cell['method']}", cell_file.parent))
    return out


def committed_file(run: Path, name: str) -> bytes:
    data = (run / name).read_bytes()
    if name != "provenance.json":
        return data
    prov = json.loads(data)
    for start in prov["starts"]:
        # the frozen clone's path on the machine that ran it says nothing to a reader: "." and paths below it
        clone = str(start["repo"]).rstrip("/") + "/"
        if "argv" in start:
            start["argv"] = [a[len(clone):] if isinstance(a, str) and a.startswith(clone) else a
                             for a in start["argv"]]
        start["repo"] = "."
    return (json.dumps(prov, indent=2) + "\n").encode()


def merged_step_runs(root: Path) -> set:
    """s{seed}-{method} of every `step` adaptation run in results/paper_regime_confirm/scores.csv."""
    with open(root / "results" / "paper_regime_confirm" / "scores.csv", newline="") as f:
        return {f"s{r['seed']}-{r['method']}" for r in csv.DictReader(f)
                if (r["experiment"], r["arm"], r["role"]) == ("paper_regime", "step", "adapt")}


def report_lines(root: Path) -> str:
    """What `report RUN` says of each study and diagnostic folder, each named from the repository root."""
    critics = root / "results" / "paper_regime_critics"
    folders = sorted((critics / "study").iterdir()) + sorted(p for p in (critics / "diagnostic").iterdir() if p.is_dir())
    with contextlib.chdir(root):
        return "\n\n".join("\n".join(run_curves.summary(f.relative_to(root))) for f in folders) + "\n\n"


def main(argv=None) -> int:
    p = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("sweep", type=Path, help="a sweep folder holding finished paper_regime:step runs")
    p.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[1],
                   help="the repository whose results/ it adds to (default: this one)")
    a = p.parse_args(argv)
    root = a.root.resolve()
    critics = root / "results" / "paper_regime_critics"
    runs = step_runs(a.sweep) if a.sweep.is_dir() else []
    if not runs:
        p.error(f"{a.sweep}: no paper_regime step adaptation run in it")
    unfinished = [str(r) for _, r in runs if not (r / "done.json").exists()]
    if unfinished:
        p.error(f"{unfinished[0]}: not finished (no done.json)")
    merged = merged_step_runs(root)
    missing = [name for name, _ in runs if name not in merged]
    if missing:
        p.error(f"{missing[0]}: not in results/paper_regime_confirm/scores.csv; merge the part first "
                f"(report results/paper_regime_confirm --merge {a.sweep})")
    plan = []
    for name, run in runs:
        want = {n: committed_file(run, n) for n in FILES}
        dest = critics / "study" / name
        if dest.exists():
            have = {q.name: q.read_bytes() for q in dest.iterdir() if q.name != "curves.png"}
            if have != want:
                p.error(f"{dest.relative_to(root)}: already there with other files than {run}'s")
            continue
        plan.append((name, dest, want))
    for name, dest, want in plan:
        stage = Path(tempfile.mkdtemp(prefix=f".{name}-", dir=dest.parent))
        for n, data in want.items():
            (stage / n).write_bytes(data)
        stage.chmod(0o755)
        stage.rename(dest)
    text = report_lines(root)
    atomic_write_text(critics / "report_lines.txt", text)
    added = {f"results/paper_regime_critics/study/{name}" for name, _, _ in plan}
    print(f"added {len(plan)} of {len(runs)} runs to results/paper_regime_critics/study; report_lines.txt rewritten")
    for block in text.strip().split("\n\n"):
        if block.split(":")[0] in added:
            print(block + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
