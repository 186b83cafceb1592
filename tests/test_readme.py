"""The README's claims table is the reference's claims.csv, word for word: means, n, interval, verdict, machine,
whether the verdict survives Holm.

Hand-edited numbers drift when the reference is re-merged; this catches it."""
from pathlib import Path

from maniskill_dualher.analysis.report import _g
from maniskill_dualher.analysis.runs import read_rows

REPO = Path(__file__).resolve().parents[1]
# README's machine column: A and B as its legend names them (results/reference/HOW_MADE.md)
MACHINE_LETTER = {"Intel(R) Xeon(R) Processor": "A", "AMD EPYC": "B"}


def _claims():
    return {r["claim"]: r for r in read_rows(REPO / "results" / "reference" / "claims.csv")}


def _readme_rows(claims):
    rows = {}
    for line in (REPO / "README.md").read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("| ") and cells[0] in claims:
            rows[cells[0]] = cells
    return rows


def _num(text):
    return _g(float(text))


def test_readme_claims_table_is_the_references_claims_csv_word_for_word():
    claims = _claims()
    rows = _readme_rows(claims)
    measured = {k for k, r in claims.items() if r.get("n_a")}
    # every measured claim is in the table, and nothing the reference did not measure
    assert set(rows) == measured, (sorted(measured - set(rows)), sorted(set(rows) - measured))
    for key, cells in rows.items():
        r = claims[key]
        assert cells[2] == f"{_num(r['mean_a'])} vs {_num(r['mean_b'])} ({r['n_a']}, {r['n_b']})", key
        assert cells[3] == f"{_num(r['diff'])} [{_num(r['diff_ci95_low'])}, {_num(r['diff_ci95_high'])}]", key
        assert cells[4] == r["verdict"], key
        letters = {letter for cpu, letter in MACHINE_LETTER.items() if cpu in r["machines"]}
        assert letters and set(cells[5].split("+")) == letters, (key, cells[5], r["machines"])
        assert cells[6] == (r["survives_holm"] or "–"), (key, cells[6], r["survives_holm"])
