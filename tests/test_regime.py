"""The paper regime's descriptive outputs (analysis/regime.py) and the amendment's sequential look."""
import numpy as np
import pytest

from maniskill_dualher.analysis import regime, stats


def _curves(arm, method, seed, successes, episodes, step=30_000, final_eval=0.0):
    """A run's curve rows: cumulative training successes/episodes at each evaluation."""
    return [{"experiment": "paper_regime", "arm": arm, "method": method, "seed": str(seed), "role": "adapt",
             "run": f"{arm}/{method}-s{seed}", "env_steps": str(i * step), "train_successes": str(s),
             "train_episodes": str(e), "eval_success_rate": str(final_eval if i == len(successes) - 1 else 0.5)}
            for i, (s, e) in enumerate(zip(successes, episodes))]


def test_windows_last_third_and_pooled_final_beside_the_random_arm():
    steps = 121                                  # evaluations at 0, 30k, ..., 3.6M
    grid = np.arange(steps) * 30_000
    learner = np.minimum(grid // 10_000, 200)    # +3 per 30k until 2M, flat after
    rand = grid // 15_000                        # +2 per 30k all along
    eps = grid // 150
    rows = (_curves("episode", "sac_her_per", 3, learner, eps) + _curves("episode", "sac_her_per", 4, learner, eps)
            + _curves("random", "sac_her_per", 3, rand, eps, final_eval=0.1))
    out = {(r["arm"], r["method"]): r for r in regime.regime_rows(rows)}
    ep, rd = out[("episode", "sac_her_per")], out[("random", "sac_her_per")]
    assert list(out) == [("episode", "sac_her_per"), ("random", "sac_her_per")]    # the random arm last
    assert ep["n_seeds"] == 2 and ep["budget"] == 3_600_000 and ep["successes_mean"] == 200
    assert ep["successes_0k_90k"] == 9 and ep["successes_150k_1200k"] == 120 - 15 and ep["successes_1200k_3600k"] == 80
    assert ep["last_third_success_rate"] == 0.0 and rd["last_third_success_rate"] == pytest.approx(2 / 200)
    assert rd["successes_mean"] == 240 and rd["success_rate"] == pytest.approx(240 / 24_000)
    # final evaluation pooled: 0 of 20 (10 episodes a run, the arm's settings) and 1 of 10, with exact bounds
    assert (ep["final_eval_successes"], ep["final_eval_episodes"]) == (0, 20)
    assert ep["final_eval_rate_upper95"] == pytest.approx(1 - 0.025 ** (1 / 20))
    assert "final_eval_successes" not in rd     # the random arm evaluates its untouched prior: not chance's
    text = "\n".join(regime.summary_lines(list(out.values())))
    assert "| random | sac_her_per | 1 | 240 |" in text and "0/20" in text
    assert regime.regime_rows([r for r in rows if r["arm"] != "random"]) == []     # no random arm: nothing


def test_sequential_look_follows_the_amendment():
    assert stats.sequential_look([5.0] * 7)["decision"].startswith("no look yet")
    strong = np.array([10, 11, 12, 10.5, 11.5, 12.5, 10.2, 11.8])
    look = stats.sequential_look(strong)
    assert look["decision"] == "stop: A > B" and look["pairs"] == 8 and look["signflip_p"] == pytest.approx(2 / 256)
    assert look["rci_low"] == pytest.approx(strong.mean() - 3.94 * strong.std(ddof=1) / np.sqrt(8))
    mixed = strong.copy()
    mixed[0] = -1.0                             # |t_7| still > 3.94, but not every difference of one sign
    assert abs(stats.sequential_look(mixed)["t"]) > 3.94 and stats.sequential_look(mixed)["decision"] == "continue"
    flat = np.array([3.0, -2, 1, -4, 2, -1, 4, -3])
    assert stats.sequential_look(flat)["decision"] == "may stop for futility"
    final = np.concatenate([flat, -flat + 0.1])
    assert stats.sequential_look(final)["decision"] == "inconclusive at the final look"
    assert stats.sequential_look(np.concatenate([strong, strong - 12]))["critical"] == 2.17
