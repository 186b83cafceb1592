"""The paper's regime described beside chance: what uniform-random actions give under the same episode rules.

In Table 3's regime (3.6M adaptation env steps, 150-step episodes ending on success) a policy that never learns
still succeeds now and then, so a count means something only beside the count chance gives. An experiment with
an arm named ``RANDOM_ARM`` (``paper_regime``'s: uniform-random actions for the whole budget, no update) has
every one of its (arm, method) cells described here, the random arm's beside them:

* successful training episodes per window of env steps (``WINDOWS``: the random phase, to 150k, 150k-1.2M,
  after 1.2M), from the cumulative counts ``curves.csv`` records at each evaluation;
* the training success rate over the last third of the budget, beside the random arm's rate over all of it;
* the final evaluation pooled over seeds (successes of evaluation episodes) with its exact (Clopper-Pearson)
  95% upper bound: where every run ends at 0, this says more than a difference of zeros.

Descriptive only: no claim is decided here (those are ``claims.py``'s, defined before their runs).
"""
from __future__ import annotations

from typing import Dict, List, Optional, Sequence

import numpy as np

from ..experiment import registry
from . import stats

RANDOM_ARM = "random"
# arms decided group-sequentially (results/paper_regime/AMENDMENT.md): (experiment, arm, method A, method B)
SEQUENTIAL = (("paper_regime", "step", "dual_buffer", "sac_her_per"),
              ("paper_regime", "step_empty", "dual_buffer", "sac_her_per"))   # Amendment 3: the same rule
# window ends at evaluation points (every 30k env steps in the paper's regime); the random phase is 100k steps,
# so its last evaluation inside it is at 90k
WINDOWS = ((0, 90_000, "0-90k (random phase)"), (90_000, 150_000, "90k-150k"),
           (150_000, 1_200_000, "150k-1.2M"), (1_200_000, 3_600_000, "1.2M-3.6M"))
COLUMNS = ["experiment", "arm", "method", "n_seeds", "budget", "successes_mean", "episodes_mean", "success_rate",
           *[f"successes_{lo // 1000}k_{hi // 1000}k" for lo, hi, _ in WINDOWS],
           "last_third_success_rate", "final_eval_successes", "final_eval_episodes", "final_eval_rate_upper95"]


def experiments_with_random(curves: Sequence[Dict[str, str]]) -> List[str]:
    """The experiments in these curves that have a random arm in the registry and runs of it here."""
    have = {(r["experiment"], r["arm"]) for r in curves}
    return sorted({e for e, a in have if a == RANDOM_ARM and e in registry.EXPERIMENTS
                   and any(x.name == RANDOM_ARM for x in registry.EXPERIMENTS[e].arms)})


def _eval_episodes(experiment: str, arm: str) -> Optional[int]:
    """The adaptation's evaluation episodes, from the arm's settings in the registry (None if not set there)."""
    a = next((x for x in registry.EXPERIMENTS[experiment].arms if x.name == arm), None)
    for s in (a.settings if a else ()):
        key, _, value = s.partition("=")
        if key in ("adapt.eval_episodes", "eval_episodes"):
            return int(value)
    return None


def _at(points: Dict[int, tuple], step: int) -> tuple:
    """(successes, episodes) at the last evaluation at or before ``step``."""
    below = [s for s in points if s <= step]
    return points[max(below)] if below else (0, 0)


def upper95(successes: int, n: int) -> float:
    """Exact two-sided 95% (Clopper-Pearson) upper bound of a success rate."""
    from scipy.stats import beta
    return 1.0 if successes >= n else float(beta.ppf(0.975, successes + 1, n - successes))


def regime_rows(curves: Sequence[Dict[str, str]]) -> List[dict]:
    rows = []
    for exp in experiments_with_random(curves):
        runs: Dict[tuple, Dict[str, Dict[int, tuple]]] = {}
        final: Dict[tuple, Dict[str, tuple]] = {}   # (arm, method) -> run -> (env steps, evaluation success)
        for r in curves:
            if r["experiment"] != exp or r["role"] != "adapt":
                continue
            key = (r["arm"], r["method"])
            step = int(float(r["env_steps"]))
            runs.setdefault(key, {}).setdefault(r["run"], {})[step] = (int(float(r["train_successes"])),
                                                                       int(float(r["train_episodes"])))
            last = final.setdefault(key, {})
            if step >= last.get(r["run"], (-1,))[0]:
                last[r["run"]] = (step, float(r["eval_success_rate"]))
        for (arm, method), by_run in sorted(runs.items(), key=lambda kv: (kv[0][0] == RANDOM_ARM, kv[0])):
            budget = min(max(p) for p in by_run.values())
            ends = [_at(p, budget) for p in by_run.values()]
            row = {"experiment": exp, "arm": arm, "method": method, "n_seeds": len(by_run), "budget": budget,
                   "successes_mean": float(np.mean([s for s, _ in ends])),
                   "episodes_mean": float(np.mean([e for _, e in ends])),
                   "success_rate": sum(s for s, _ in ends) / max(1, sum(e for _, e in ends))}
            for lo, hi, _ in WINDOWS:
                row[f"successes_{lo // 1000}k_{hi // 1000}k"] = float(np.mean(
                    [_at(p, hi)[0] - _at(p, lo)[0] for p in by_run.values()])) if budget >= hi else ""
            third = budget - budget // 3
            s3 = sum(_at(p, budget)[0] - _at(p, third)[0] for p in by_run.values())
            e3 = sum(_at(p, budget)[1] - _at(p, third)[1] for p in by_run.values())
            row["last_third_success_rate"] = s3 / e3 if e3 else ""
            n_eval = _eval_episodes(exp, arm)
            if n_eval and arm != RANDOM_ARM:   # the random arm's evaluation is its untouched prior's, not chance's
                k = int(round(sum(v * n_eval for _, v in final[(arm, method)].values())))
                n = n_eval * len(by_run)
                row.update({"final_eval_successes": k, "final_eval_episodes": n,
                            "final_eval_rate_upper95": upper95(k, n)})
            rows.append(row)
    return rows


def _pct(x) -> str:
    return "" if x == "" else f"{100 * float(x):.3g}%"


def summary_lines(rows: Sequence[dict]) -> List[str]:
    """summary.md's section: every cell's counts beside the random arm's."""
    if not rows:
        return []
    heads = [w for _, _, w in WINDOWS]
    s = ["## Beside chance: uniform-random actions under the same episode rules (`regime.csv`)", "",
         "The `random` arm acts uniformly at random for the whole adaptation budget and never updates; every "
         "other cell's successful training episodes (mean over seeds, per window of env steps), its training "
         "success rate over the last third of the budget, and its final evaluation pooled over seeds (with the "
         "exact 95% upper bound of that rate) stand beside it (the random arm's evaluation is its untouched "
         "prior's, so none is given). Descriptive: no verdict is read from this table.",
         "", "| arm | method | n | successful episodes (mean) | " + " | ".join(heads)
         + " | success rate, all | last third | final evaluation, pooled (95% upper bound) |",
         "|---" * (7 + len(heads)) + "|"]
    for r in rows:
        wins = " | ".join("" if r[c] == "" else f"{r[c]:.3g}" for c in COLUMNS if c.startswith("successes_")
                          and c != "successes_mean")
        fin = (f"{r['final_eval_successes']}/{r['final_eval_episodes']} (<= {_pct(r['final_eval_rate_upper95'])})"
               if "final_eval_episodes" in r else "")
        s.append(f"| {r['arm']} | {r['method']} | {r['n_seeds']} | {r['successes_mean']:.4g} | {wins} | "
                 f"{_pct(r['success_rate'])} | {_pct(r['last_third_success_rate'])} | {fin} |")
    return s + [""]



def sequential_lines(curves: Sequence[Dict[str, str]]) -> List[str]:
    """summary.md's lines for the group-sequential arms with runs here: the amendment's look on the per-seed
    differences of successful training episodes (A - B, seeds in order, only seeds both methods have)."""
    out = []
    for exp, arm, ma, mb in SEQUENTIAL:
        final: Dict[str, Dict[int, tuple]] = {}
        for r in curves:
            if (r["experiment"], r["arm"], r["role"]) == (exp, arm, "adapt") and r["method"] in (ma, mb):
                step, seed = int(float(r["env_steps"])), int(r["seed"])
                cur = final.setdefault(r["method"], {}).get(seed)
                if cur is None or step >= cur[0]:
                    final[r["method"]][seed] = (step, float(r["train_successes"]))
        seeds = sorted(set(final.get(ma, {})) & set(final.get(mb, {})))
        if not seeds:
            continue
        look = stats.sequential_look([final[ma][k][1] - final[mb][k][1] for k in seeds])
        on = f"seed {seeds[0]} (1 pair)" if len(seeds) == 1 else f"seeds {seeds[0]}-{seeds[-1]} ({len(seeds)} pairs)"
        line = f"- {exp}/{arm}, {ma} minus {mb}, successful training episodes, paired on {on}: **{look['decision']}**"
        if "t" in look:
            line += (f" at the look at {look['pairs']} pairs (t = {look['t']:.3g} against {look['critical']}; "
                     f"repeated confidence interval [{look['rci_low']:.3g}, {look['rci_high']:.3g}]; sensitivity: "
                     f"sign-flip p {look['signflip_p']:.3g}, skewness of the differences {look['skewness']:.2g})")
        out.append(line + ".")
    if not out:
        return []
    return ["## Group-sequential looks (`results/paper_regime/AMENDMENT.md`)", ""] + out + [""]
