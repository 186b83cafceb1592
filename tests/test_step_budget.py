"""bench/step_budget.py: bad input is one line and exit code 2; a short run attributes its wall time."""
import json
import shutil

import pytest
from bench_cli import run_bench


def _run(*args):
    return run_bench("step_budget.py", *args)


def test_bad_input_is_one_line_exit_2(tmp_path):
    out = tmp_path / "x.json"
    for args in (["--tasks", "Nope-v1"], ["--members", "0"], ["--steps", "-3"], ["--method", "nope"],
                 ["--learning-starts", "-1"], ["--set", "sac.nope=1"], ["--set", "sac.compile=maybe"],
                 ["--warmup-steps", "3000"], ["--warmup-steps", "-1"], ["--fill-rows", "1000"],
                 ["--floor-products-from", str(tmp_path / "missing.json")]):
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


def test_warmup_steps_are_not_counted(tmp_path):
    """--warmup-steps W: wall time, parts and counts start once every member has made W env steps, so the
    measured env steps, acting calls and updates are the run's less its first W steps'; --set reaches the runs."""
    out = tmp_path / "budget.json"
    members, steps, warm = 2, 200, 120
    r = _run("--tasks", "ReachTarget-v1", "--members", str(members), "--steps", str(steps), "--learning-starts", "50",
             "--warmup-steps", str(warm), "--set", "sac.log_every=7", "--out", str(out))
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads(out.read_text())
    res = doc["results"][0]
    n = members * (steps - warm)
    assert res["training_env_steps"] == n and res["calls"]["env python"] == n and res["calls"]["acting"] == n
    # updates after the mark: one per env step from 50 on, all of them past 120 (less the batch's first wait)
    assert 0 < res["updates"] <= n and res["calls"]["sampling"] == res["updates"]
    assert abs(sum(res["parts_wall_s"].values()) - res["wall_s"]) < 0.02 * res["wall_s"]
    assert res["cfg"]["sac"]["log_every"] == 7 and res["sets"] == ["sac.log_every=7"]
    assert f"warm-up of {warm} env steps" in doc["report"][0]


def test_checkpoint_writes_are_timed_and_charged_at_a_runs_rate(tmp_path):
    """A window's last step writes a checkpoint no run writes that often: each write is timed ("checkpoints"), and
    the report charges the mean write with the replay at the run's own rate (one per checkpoint_every env steps
    of its full budget, and one at its end)."""
    import math
    out = tmp_path / "budget.json"
    r = _run("--tasks", "ReachTarget-v1", "--members", "1", "--steps", "200", "--learning-starts", "50",
             "--warmup-steps", "100", "--set", "checkpoint_every=70", "--out", str(out))
    assert r.returncode == 0, r.stderr[-2000:]
    doc = json.loads(out.read_text())
    res = doc["results"][0]
    writes = [w["wall_s"] for w in res["checkpoint_writes"] if w["replay"]]
    # every write after the mark is in the list (the one at the end with the replay at least), none before it
    assert len(writes) >= 1 and res["calls"]["checkpoints"] == len(res["checkpoint_writes"])
    assert res["parts_wall_s"]["checkpoints"] >= 0.9 * sum(writes) > 0
    total = res["run_total_steps"]
    assert total > 200  # the preset's budget, not the window's
    per_step = sum(writes) / len(writes) * math.ceil(total / 70) / total
    assert f"{1e3 * per_step:.3f} ms per env step at that rate" in doc["report"][0]
    assert "at a run's checkpoint rate, wall:" in doc["report"][0]


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("c++") is None and shutil.which("g++") is None, reason="no C++ compiler")
def test_a_compiled_update_has_its_products_timed(tmp_path):
    """--set sac.compile=true: the products inside inductor's code are timed (extern kernels), not zero, and the
    compiled graph is not broken by the eager product timers (its overhead is below its products')."""
    out = tmp_path / "budget.json"
    r = _run("--tasks", "ReachTarget-v1", "--members", "1", "--steps", "900", "--learning-starts", "0",
             "--warmup-steps", "300", "--set", "sac.compile=true", "--out", str(out))
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads(out.read_text())["results"][0]
    parts = res["parts_wall_s"]
    assert res["cfg"]["sac"]["compile"] is True and res["updates"] > 0
    assert res["calls"]["update products"] >= 20 * res["updates"]  # 22 extern products per update at 64x64
    assert 0 < parts["update overhead"] < parts["update products"]


def test_a_filled_replay_is_sampled_at_its_full_size_and_a_floor_can_take_anothers_products(tmp_path):
    """--fill-rows fills R (not counted: it happens before the warm-up's mark) so the runs sample a tree that size;
    --floor-products-from puts another result's update products in the floor line."""
    first, second = tmp_path / "a.json", tmp_path / "b.json"
    common = ("--regime", "paper", "--members", "1", "--steps", "300", "--warmup-steps", "100", "--learning-starts",
              "50", "--set", "sac.update_schedule=step")
    r = _run(*common, "--out", str(first))
    assert r.returncode == 0, r.stderr[-2000:]
    r = _run(*common, "--fill-rows", "300000", "--floor-products-from", str(first), "--out", str(second))
    assert r.returncode == 0, r.stderr[-2000:]
    a, b = (json.loads(f.read_text()) for f in (first, second))
    products = a["results"][0]["parts_wall_s"]["update products"] / a["results"][0]["training_env_steps"]
    assert b["results"][0]["floor_products"]["wall_ms"] == pytest.approx(1e3 * products)
    assert "floor with the update products of" in b["report"][0]
    # filled, R serves a batch from the first step counted: one update per env step; empty, it waits for the
    # first 150-step episode to be stored
    assert b["results"][0]["updates"] == 300 - 100 and 0 < a["results"][0]["updates"] < 300 - 100
