"""bench/step_budget.py: bad input is one line and exit code 2; a short run attributes its wall time."""
import json

from bench_cli import run_bench


def _run(*args):
    return run_bench("step_budget.py", *args)


def test_bad_input_is_one_line_exit_2(tmp_path):
    out = tmp_path / "x.json"
    for args in (["--tasks", "Nope-v1"], ["--members", "0"], ["--steps", "-3"], ["--method", "nope"],
                 ["--learning-starts", "-1"]):
        r = _run(*args, "--out", str(out))
        assert r.returncode == 2, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and args[1] in r.stderr
    assert not out.exists()


def test_short_run_attributes_its_wall_time(tmp_path):
    """Two runs driven together (packed updates from env step 50): every wrapped piece of the current loop
    fires, the counts match the runs' own, and the driver's unattributed rest stays under 5%."""
    out = tmp_path / "budget.json"
    members, steps = 2, 150
    r = _run("--tasks", "ReachTarget-v1", "--members", str(members), "--steps", str(steps),
             "--learning-starts", "50", "--out", str(out))
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads(out.read_text())
    res = doc["results"][0]
    parts, calls = res["parts_wall_s"], res["calls"]
    n = members * steps
    assert res["training_env_steps"] == n and calls["env python"] == n and calls["acting"] == n
    assert calls["physics"] > 0 and calls["physics"] % n == 0  # the same substeps in every training step
    # the runs' own update count (metrics) is what the timers saw sampled and re-prioritised
    assert res["updates"] > 0 and calls["sampling"] == calls["priorities"] == res["updates"]
    assert [p for p, t in parts.items() if t <= 0 and p != "driver loop"] == []  # every piece was timed
    assert parts["driver loop"] < 0.05 * sum(parts.values())  # >= 95% attributed
    assert abs(sum(parts.values()) - res["wall_s"]) < 0.02 * res["wall_s"]  # the parts add up to the whole
    assert "floor" in doc["report"][0] and doc["machine"]


def test_paper_regime_runs_the_registry_arm_at_algorithm_1s_schedule(tmp_path):
    """--regime paper measures the paper_regime experiment's episode arm: one update per finished episode
    (so far fewer updates than env steps), 150-step episodes, HER k = 8, Table 3's lr and gamma."""
    out = tmp_path / "budget.json"
    r = _run("--regime", "paper", "--members", "1", "--steps", "400", "--learning-starts", "50",
             "--out", str(out))
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(out.read_text())["results"][0]
    cfg = res["cfg"]
    assert res["task"] == "CloseMicrowave-v1" and res["regime"] == "paper"
    assert cfg["sac"]["update_schedule"] == "episode" and cfg["replay"]["her_k"] == 8
    assert cfg["max_episode_steps"] == 150 and cfg["sac"]["lr"] == 1e-4 and cfg["sac"]["gamma"] == 0.99
    assert cfg["sac"]["random_steps"] == cfg["sac"]["learning_starts"] == 50
    # one update per finished episode after learning starts: at most (400 - 50) / 1 episodes, far fewer than steps
    assert 0 < res["updates"] < 400 - 50 and res["calls"]["sampling"] == res["updates"]
