"""bench/sweep_ab.py: pair ratios and their interval, the A/A control's checks (no sweeps run here)."""
import math
import subprocess

from bench_cli import ROOT, load_bench, run_bench




def test_pairs_are_adjacent_sweeps_of_a_and_x_and_the_interval_holds_their_geometric_mean():
    ab = load_bench("sweep_ab.py")
    walls = [100, 110, 101, 99, 102, 100, 112, 100]
    timed = [{"side": s, "wall_s": w} for s, w in zip("ABACCABA", walls)]
    assert ab.pair_ratios(timed, "B") == [1.1, round(110 / 101, 4), 1.12, 1.12]
    assert ab.pair_ratios(timed, "C") == [round(99 / 101, 4), round(102 / 100, 4)]  # C-C is not a pair
    iv = ab.pair_interval(ab.pair_ratios(timed, "B"))
    gm = math.exp(sum(math.log(r) for r in ab.pair_ratios(timed, "B")) / 4)
    assert iv["n"] == 4 and abs(iv["geomean"] - gm) < 1e-12 and iv["low"] < gm < iv["high"]
    assert ab.pair_interval([1.1]) is None


def test_control_must_be_a_clone_at_this_commit(tmp_path):
    r = run_bench("sweep_ab.py", "--base", str(ROOT), "--control", str(tmp_path))
    assert r.returncode == 2 and "--control" in r.stderr and len(r.stderr.strip().splitlines()) == 1
    r = run_bench("sweep_ab.py", "--base", str(ROOT), "--control", str(ROOT), "--order", "ABBA")
    assert r.returncode == 2 and "letters ABC" in r.stderr
    # a clone of another commit is refused before any sweep runs
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    subprocess.run(["git", "-C", str(clone), "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-q",
                    "--allow-empty", "-m", "another commit"], check=True)
    r = run_bench("sweep_ab.py", "--base", str(ROOT), "--control", str(clone), "--json", str(tmp_path / "x.json"))
    assert r.returncode == 2 and "not this tree's" in r.stderr and not (tmp_path / "x.json").exists()
