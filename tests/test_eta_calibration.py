"""bench/eta_calibration.py: bad input is one line and exit code 2, nothing written; a run writes what the ETA
test reads."""
import json

import pytest

from maniskill_dualher.experiment.registry import PAPER_CHAIN
from bench_cli import run_bench


def test_bad_input_is_one_line_exit_2(tmp_path):
    out = tmp_path / "cal.json"
    for args in (["--plans", "nope"], ["--add-plan", "x"], ["--add-plan", "x=abc:--preset smoke"],
                 ["--bound-low", "nope"]):
        r = run_bench("eta_calibration.py", *args, "--out", str(out))
        assert r.returncode == 2, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and args[1] in r.stderr
    assert not out.exists()


@pytest.mark.slow
def test_a_calibration_file_holds_what_the_eta_check_reads(tmp_path):
    """The smoke plan run here, one plan added from elsewhere: the file has the timed inputs per task and every
    plan's wall time (the ETA test iterates the committed ones)."""
    out = tmp_path / "cal.json"
    r = run_bench("eta_calibration.py", "--plans", "smoke", "--add-plan", "other=100:--preset smoke",
                  "--bound-low", "other", "--out", str(out))
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads(out.read_text())
    smoke = doc["plans"]["smoke"]
    assert set(smoke["step_s"]) == set(PAPER_CHAIN)   # the smoke plan's tasks: the paper's (the sweep's default)
    assert all(0 < v < 0.05 for v in smoke["step_s"].values()) and smoke["pack"] >= 1
    assert set(smoke["start_s"]) == set(smoke["step_s"]) and all(0 < v < 60 for v in smoke["start_s"].values())
    assert smoke["update_s"] and all(0 < v < 0.1 for v in smoke["update_s"].values())
    other = doc["plans"]["other"]
    assert smoke["wall_s"] > 0 and other["wall_s"] == 100.0 and other["bound"] == "low"
    assert set(other["update_s"]) == set(smoke["update_s"]) and set(other["step_s"]) == set(smoke["step_s"])
