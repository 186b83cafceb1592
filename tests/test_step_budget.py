"""bench/step_budget.py: bad input is one line and exit code 2; a short run attributes its wall time."""
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(*args):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, str(ROOT / "bench" / "step_budget.py"), *args], env=env,
                          capture_output=True, text=True)


def test_bad_input_is_one_line_exit_2(tmp_path):
    out = tmp_path / "x.json"
    for args in (["--tasks", "Nope-v1"], ["--members", "0"], ["--steps", "-3"]):
        r = _run(*args, "--out", str(out))
        assert r.returncode == 2, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and args[1] in r.stderr
    assert not out.exists()


def test_short_run_attributes_its_wall_time(tmp_path):
    out = tmp_path / "budget.json"
    r = _run("--tasks", "ReachTarget-v1", "--members", "1", "--steps", "150", "--out", str(out))
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads(out.read_text())
    res = doc["results"][0]
    parts = res["parts_wall_s"]
    assert res["training_env_steps"] == 150 and res["calls"]["env python"] == 150
    assert parts["physics"] > 0 and parts["eval physics"] > 0 and parts["update products"] == 0  # no update yet
    assert parts["pack loop"] < 0.05 * sum(parts.values())  # >= 95% attributed
    assert abs(sum(parts.values()) - res["wall_s"]) < 0.02 * res["wall_s"]  # the parts add up to the whole
    assert "floor" in doc["report"][0] and doc["machine"]
