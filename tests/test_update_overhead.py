"""bench/update_overhead.py: bad input is one line and exit code 2; a short run times both sides and finds
their weights identical (here both sides are this tree)."""
import json
from pathlib import Path

from bench_cli import run_bench

ROOT = Path(__file__).resolve().parents[1]


def _run(*args):
    return run_bench("update_overhead.py", *args)


def test_bad_input_is_one_line_exit_2(tmp_path):
    out = tmp_path / "x.json"
    for args in (["--packs", "0"], ["--packs", "1,x"], ["--reps", "0"], ["--updates", "-1"], ["--chunks", "0"],
                 ["--warmup", "-2"], ["--base", str(tmp_path / "nowhere")], ["--precision-b", "fp8"],
                 ["--compile-b", "--base", str(tmp_path)]):
        r = _run(*args, "--json", str(out))
        assert r.returncode == 2, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and args[1] in r.stderr
    assert not out.exists()


def test_a_short_run_times_both_sides_and_checks_their_weights(tmp_path):
    out = tmp_path / "overhead.json"
    r = _run("--base", str(ROOT), "--packs", "1,2", "--reps", "1", "--updates", "3", "--chunks", "2",
             "--warmup", "1", "--json", str(out))
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads(out.read_text())
    assert doc["machine"] and doc["commits"]["A"]["commit"] and doc["packs"] == [1, 2]
    runs = doc["results"]
    assert sorted((x["side"], x["pack"]) for x in runs) == [("A", 1), ("A", 2), ("B", 1), ("B", 2)]
    for x in runs:
        assert x["torch_threads"] == 1 and len(x["chunks_total_ms"]) == 2
        assert 0 < x["products_ms"] and abs(x["overhead_ms"] - (x["total_ms"] - x["products_ms"])) < 1e-9
    # the same seeds and batches: one digest per pack size, and packs of 1 and 2 differ
    assert doc["weights_identical"] == {"1": True, "2": True}
    assert len({x["digest"] for x in runs}) == 2
    assert set(doc["summary"]["2"]) == {"A", "B", "ratio_B_over_A", "pair_ratios_total"}
