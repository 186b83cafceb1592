"""Move a results folder's rows of some cells to <folder>/superseded/ (issue 39: ratio-1/0 arms trained before
the dual buffer stopped drawing at ratio 1/0, and from-scratch cells rerun on one CPU kind).

    python bench/supersede.py results/reference --why "..." CELL [CELL ...]

A CELL is experiment/arm/method[/seeds] with seeds as a range list "0-15,32-47" (default: every seed); every
role of the cell (its adaptation and, for a chain arm, its source stages listed under that arm) moves. The moved
rows are appended to superseded/scores.csv and superseded/curves.csv (same columns), with the reason in
superseded/README.md; the folder's own scores.csv/curves.csv keep the rest. Rebuild the folder afterwards with
``python -m maniskill_dualher.report FOLDER`` (or merge the reruns into it).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from maniskill_dualher.analysis.runs import CURVE_COLUMNS, SCORE_COLUMNS, read_rows  # noqa: E402
from maniskill_dualher.fileio import atomic_write_text, csv_text  # noqa: E402


def seeds_of(text: str):
    out = set()
    for part in text.split(","):
        a, _, b = part.partition("-")
        out.update(range(int(a), int(b or a) + 1))
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("folder")
    p.add_argument("cells", nargs="+")
    p.add_argument("--why", required=True)
    a = p.parse_args(argv)
    folder = Path(a.folder)
    specs = []
    for c in a.cells:
        parts = c.split("/")
        if len(parts) not in (3, 4):
            print(f"error: bad cell {c!r} (experiment/arm/method[/seeds])", file=sys.stderr)
            return 2
        specs.append((parts[0], parts[1], parts[2], seeds_of(parts[3]) if len(parts) == 4 else None))

    def hit(r):
        return any(r["experiment"] == e and r["arm"] == arm and r["method"] == m and (s is None or int(r["seed"]) in s)
                   for e, arm, m, s in specs)
    sup = folder / "superseded"
    sup.mkdir(exist_ok=True)
    for name, cols in (("scores.csv", SCORE_COLUMNS), ("curves.csv", CURVE_COLUMNS)):
        rows = read_rows(folder / name)
        keep, move = [r for r in rows if not hit(r)], [r for r in rows if hit(r)]
        old = read_rows(sup / name) if (sup / name).is_file() else []
        atomic_write_text(sup / name, csv_text(old + move, cols))
        atomic_write_text(folder / name, csv_text(keep, cols))
        print(f"{name}: moved {len(move)} rows, kept {len(keep)}")
    readme = sup / "README.md"
    text = readme.read_text() if readme.is_file() else (
        "# Superseded rows\n\nRows moved out of this folder's `scores.csv`/`curves.csv` (same columns), kept as "
        "evidence; no table, claim or figure reads them. Moved by `bench/supersede.py`:\n")
    text += f"\n* `{' '.join(a.cells)}`: {a.why}\n"
    atomic_write_text(readme, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
