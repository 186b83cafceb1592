"""bench/time_to_success.py: the ratio's bootstrap interval, overrides for ours, and combining raw files."""
import json
import math

import numpy as np

from bench_cli import load_bench, run_bench




def test_ratio_interval_holds_the_ratio_of_medians_and_opens_on_censoring():
    tts = load_bench("time_to_success.py")
    peer, ours = [9000, 9000, 16000, 12000, 10000], [14000, 10000, 14000, 14000, 10000]
    lo, hi = tts.ratio_interval(peer, ours)
    point = np.median(peer) / np.median(ours)
    assert lo <= point <= hi and lo < hi
    # every resample of identical values gives one ratio
    assert tts.ratio_interval([2.0] * 4, [1.0] * 4) == [2.0, 2.0]
    # ours censored in most seeds: the lower end goes to 0; a censored peer opens the upper end
    assert tts.ratio_interval([1.0] * 5, [math.inf] * 4 + [1.0])[0] == 0.0
    assert math.isinf(tts.ratio_interval([math.inf] * 4 + [1.0], [1.0] * 5)[1])


def test_overrides_reach_ours_and_bad_keys_are_one_line_exit_2(tmp_path):
    import argparse
    from maniskill_dualher.experiment import overrides
    tts = load_bench("time_to_success.py")
    args = argparse.Namespace(preset="quick", max_steps=300, eval_every=300, eval_episodes=1,
                              overrides=overrides.parse_all(["sac.alpha=1", "replay.priority_exponent=0"]))
    args.fixed_overrides = overrides.parse_all(["sac.tau=0.01"])
    cfg = tts.our_config("CloseBox-v1", 3, args, fixed_length=True)
    assert cfg.sac.alpha == 1.0 and cfg.replay.priority_exponent == 0.0 and cfg.seed == 3
    assert cfg.sac.tau == 0.01 and tts.our_config("CloseBox-v1", 3, args).sac.tau != 0.01  # ours_fixed only
    assert cfg.terminate_on_success is False and cfg.total_steps == 300
    shared = tts.shared_settings(cfg)
    assert shared["temperature"]["ours"] == "learned, starts 1" and shared["temperature"]["equal"]
    assert shared["replay sampling"]["equal"] and not shared["HER"]["equal"]
    out = tmp_path / "x.json"
    r = run_bench("time_to_success.py", "--tasks", "ReachTarget-v1", "--contenders", "ours_fixed",
                  "--set", "sac.alphaa=1", "--out", str(out))
    assert r.returncode == 2 and "did you mean sac.alpha" in r.stderr and not out.exists()


def _raw(seeds, reached_at):
    """A complete raw file as the bench writes it, one ours_fixed run per seed."""
    runs = [{"task": "CloseBox-v1", "contender": "ours_fixed", "seed": s, "error": None, "reached": at is not None,
             "wall_s_to_threshold": at and at / 100, "cpu_s_to_threshold": at and at / 110,
             "env_steps_to_threshold": at} for s, at in zip(seeds, reached_at)]
    settings = {"threshold": 0.9, "tasks": ["CloseBox-v1"], "contenders": ["ours_fixed"], "max_steps": 30000,
                "eval_every": 1000, "eval_episodes": 10, "preset": "quick", "ours_overrides": [], "versions": {},
                "seeds": list(seeds),
                "episodes": {"CloseBox-v1": {"max_episode_steps": 100, "terminate_on_success": True}}}
    return {"complete": True, "settings": settings, "runs": runs, "argv": [], "started": "a", "finished": "b",
            "machine": {"cpu": "AMD EPYC"}}


def test_combine_pools_split_seeds_and_refuses_overlaps(tmp_path, capsys):
    tts = load_bench("time_to_success.py")

    def run(*argv):  # in this process: the bench's main as its command line calls it
        capsys.readouterr()
        rc = tts.main(list(argv))
        return rc, capsys.readouterr().err
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    a.write_text(json.dumps(_raw([0, 1, 2], [7000, None, 5000])))
    b.write_text(json.dumps(_raw([3, 4], [26000, 6000])))
    both = tmp_path / "both.json"
    rc, err = run("--combine", str(a), str(b), "--out", str(both))
    assert rc == 0, err
    doc = json.loads(both.read_text())
    st = doc["summary"]["CloseBox-v1"]["contenders"]["ours_fixed"]
    assert doc["settings"]["seeds"] == [0, 1, 2, 3, 4] and st["runs"] == 5 and st["reached"] == 4
    assert st["env_steps"]["median"] == 7000  # of 5000, 6000, 7000, 26000 and one not reached
    for bad, why in (([a, a], "twice"), ([a, tmp_path / "nope.json"], "nope.json")):
        out = tmp_path / "bad.json"
        rc, err = run("--combine", *map(str, bad), "--out", str(out))
        assert rc == 2 and why in err and len(err.strip().splitlines()) == 1
        assert not out.exists()
    c = tmp_path / "c.json"
    c.write_text(json.dumps(dict(_raw([5], [1000]), complete=False)))
    rc, err = run("--combine", str(a), str(c), "--out", str(tmp_path / "bad.json"))
    assert rc == 2 and "not complete" in err
