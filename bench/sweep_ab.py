"""This tree against a frozen clone of an earlier commit: the same small sweep, warmed up and interleaved.

    python bench/sweep_ab.py --base /path/to/clone-of-the-base-commit [--order ABBA] [--rounds 1]
        [--control /path/to/a-second-clone-of-this-commit] [--steps 3000] [--seeds 0,1] [--methods sac_her_per,dual_buffer]
        [--tasks ID,ID,...] [--preset reference] [--workers 2] [--json FILE]

A is this working tree, B the clone at ``--base`` (``git clone <repo> DIR && git -C DIR checkout <commit>``).
Each side runs ``python -m maniskill_dualher.sweep --preset P --experiments single ... --no-report`` from its
own tree (``PYTHONPATH`` and working directory), into an empty temporary folder, as a user runs it: imports,
pool start-up, evaluation and checkpoints included, the report excluded. First one short warm-up sweep per side
(untimed: the file cache and bytecode warm), then the timed sweeps in ``--order`` repeated ``--rounds`` times
(ABBA: each side once first and once second, so a drift of the machine over the run cancels).

``--control DIR`` adds side C, a second clone of A's own commit (an A/A control, default order ABACCABA): the
ratio C/A shows how far two sweeps of identical code differ on this machine in this run, beside B/A.
Each comparison X/A also gets an interval over its pairs (adjacent sweeps of A and X in the order): the
geometric mean of the pair ratios with a 95% t-interval on their logs.

Prints and writes (``--json``): each timed sweep's wall time and training env steps per second, the ratio
B wall / A wall of the medians, the ratio of every adjacent A/B pair (its spread), and whether every run's
metrics (``metrics.csv`` without wall time) are identical between every sweep of both sides. Single sweeps on
these 2-core machines vary by about +-10% (docs/speed.md): read the pair ratios' spread beside the ratio.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from sweep_speed import metrics  # noqa: E402  (every run's metrics without wall time: one definition)
from maniskill_dualher.experiment.registry import PAPER_CHAIN  # noqa: E402  (the sweep's default tasks)


def git_commit(tree: Path) -> str:
    from maniskill_dualher.provenance import git_state
    g = git_state(tree)
    return (g["commit_short"] or "unknown") + ("+dirty" if g["dirty"] else "")


def sweep(tree: Path, out: Path, a, tasks: str, seeds: str, steps: int) -> float:
    env = dict(os.environ, PYTHONPATH=str(tree))
    env.pop("MANISKILL_DUALHER_LEAN_STEP", None)  # each side's default path
    # the budget's flag as that tree spells it: --source-steps since cf82867 (issue 31), --steps before
    flag = "--source-steps" if "--source-steps" in (tree / "maniskill_dualher/experiment/sweep.py").read_text() \
        else "--steps"
    cmd = [sys.executable, "-m", "maniskill_dualher.sweep", "--preset", a.preset, "--experiments", "single",
           "--tasks", tasks, "--methods", a.methods, "--seeds", seeds, flag, str(steps),
           "--workers", str(a.workers), "--out", str(out), "--no-report"]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=tree, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise RuntimeError(f"sweep in {tree} failed (exit {r.returncode}): {r.stderr.strip().splitlines()[-1:]}")
    return wall


def pair_ratios(timed, x: str) -> list:
    """wall X / wall A of every two adjacent timed sweeps that are one A and one X."""
    out = []
    for p, q in zip(timed, timed[1:]):
        if {p["side"], q["side"]} == {"A", x}:
            a_, x_ = (p, q) if p["side"] == "A" else (q, p)
            out.append(round(x_["wall_s"] / a_["wall_s"], 4))
    return out


def pair_interval(ratios, level: float = 0.95):
    """Geometric mean of pair ratios and a t-interval on their logs; None below two pairs."""
    import math
    if len(ratios) < 2:
        return None
    from scipy import stats
    logs = [math.log(r) for r in ratios]
    m, sd, n = statistics.mean(logs), statistics.stdev(logs), len(logs)
    h = stats.t.ppf((1 + level) / 2, n - 1) * sd / math.sqrt(n)
    return {"geomean": math.exp(m), "low": math.exp(m - h), "high": math.exp(m + h), "n": n}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--base", required=True, help="a clone of the base commit (side B)")
    p.add_argument("--order", default=None, help="the timed sweeps' order, letters A and B (and C with "
                                                 "--control) (default ABBA; ABACCABA with --control)")
    p.add_argument("--control", help="a second clone of this tree's commit (side C, an A/A control)")
    p.add_argument("--rounds", type=int, default=1, help="repeat --order this many times")
    p.add_argument("--steps", type=int, default=3000, help="env steps of every run")
    p.add_argument("--seeds", default="0,1")
    p.add_argument("--methods", default="sac_her_per,dual_buffer")
    p.add_argument("--tasks", default=",".join(PAPER_CHAIN), help="comma list (default: the paper's tasks, "
                   "registry.PAPER_CHAIN, the sweep's default)")
    p.add_argument("--preset", default="reference")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--warmup-steps", type=int, default=300)
    p.add_argument("--json", help="also write the results here")
    a = p.parse_args(argv)
    base = Path(a.base).resolve()
    if not (base / "maniskill_dualher" / "sweep.py").is_file():
        print(f"error: --base {a.base!r} is not a clone of this project", file=sys.stderr)
        return 2
    control = Path(a.control).resolve() if a.control else None
    if control is not None and not (control / "maniskill_dualher" / "sweep.py").is_file():
        print(f"error: --control {a.control!r} is not a clone of this project", file=sys.stderr)
        return 2
    sides = "ABC" if control else "AB"
    a.order = a.order or ("ABACCABA" if control else "ABBA")
    if set(a.order) - set(sides) or set(a.order) != set(sides) or a.rounds < 1:
        print(f"error: --order must use each of the letters {sides} (like {'ABACCABA' if control else 'ABBA'}) and "
              f"--rounds >= 1, got {a.order!r}, {a.rounds}", file=sys.stderr)
        return 2
    if a.steps < 1:
        print(f"error: --steps must be >= 1, got {a.steps}", file=sys.stderr)
        return 2

    from maniskill_dualher.provenance import cpu_info, machine_label, machine_name
    trees = {"A": REPO, "B": base, **({"C": control} if control else {})}
    commits = {k: git_commit(t) for k, t in trees.items()}
    if control and commits["C"] != commits["A"]:
        print(f"error: --control is at {commits['C']}, not this tree's {commits['A']}", file=sys.stderr)
        return 2
    n_runs = len([x for x in a.seeds.split(",") if x]) * len(a.methods.split(",")) * len(a.tasks.split(","))
    load = " ".join(Path("/proc/loadavg").read_text().split()[:3]) if Path("/proc/loadavg").exists() else "?"
    print(f"machine: {machine_name(cpu_info())}, {machine_label(cpu_info())}; {os.cpu_count()} logical cores; {a.workers} workers; "
          f"load before: {load}")
    print(f"A = {REPO} ({commits['A']}), B = {base} ({commits['B']})"
          + (f", C = {control} ({commits['C']}, the A/A control)" if control else ""))
    print(f"sweep: preset {a.preset}, single-task, {n_runs} runs x {a.steps} env steps; order "
          f"{a.order} x {a.rounds}")
    timed, seen = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for side in sides:
            sweep(trees[side], Path(tmp) / f"warm{side}", a, a.tasks.split(",")[0], "0,", a.warmup_steps)
        for i, side in enumerate(a.order * a.rounds):
            out = Path(tmp) / f"{i}{side}"
            wall = sweep(trees[side], out, a, a.tasks, a.seeds, a.steps)
            seen[i] = metrics(out)
            steps = n_runs * a.steps
            timed.append({"i": i, "side": side, "wall_s": round(wall, 2), "env_steps_per_s": round(steps / wall, 1)})
            print(f"  {i:>2} {side}: {wall:7.1f} s  {steps / wall:7.1f} env steps/s", flush=True)
    walls = {s: [t["wall_s"] for t in timed if t["side"] == s] for s in sides}
    ratio = statistics.median(walls["B"]) / statistics.median(walls["A"]) if walls["A"] and walls["B"] else None
    pairs = pair_ratios(timed, "B")
    comparisons = {f"{x}/A": {"median_ratio": statistics.median(walls[x]) / statistics.median(walls["A"]),
                              "pair_ratios": pair_ratios(timed, x), "interval": pair_interval(pair_ratios(timed, x))}
                   for x in sides if x != "A"}
    ref = seen[0]
    same = all(m == ref for m in seen.values()) and len(ref) == n_runs
    if ratio is not None:
        print(f"A is x{ratio:.2f} B's speed (median wall B / median wall A); adjacent A/B pairs: "
              f"{', '.join(f'x{r:.2f}' for r in pairs)}")
    for name, c in comparisons.items():
        iv = c["interval"]
        print(f"{name}: median x{c['median_ratio']:.3f}; pairs {', '.join(f'x{r:.3f}' for r in c['pair_ratios'])}"
              + (f"; geometric mean x{iv['geomean']:.3f} [{iv['low']:.3f}, {iv['high']:.3f}] (95% t over "
                 f"{iv['n']} pairs)" if iv else "; no interval (fewer than 2 pairs)"))
    print(f"metrics of every run identical in every sweep of both sides (wall time aside): {same} ({len(ref)} runs)")
    if a.json:
        from maniskill_dualher.fileio import atomic_write_text
        doc = {"command": " ".join(["bench/sweep_ab.py"] + (sys.argv[1:] if argv is None else list(argv))),
               "machine": machine_name(cpu_info()), "cpu": machine_label(cpu_info()), "load_before": load, "commits": commits,
               "workers": a.workers, "preset": a.preset, "runs": n_runs, "steps": a.steps, "order": a.order,
               "rounds": a.rounds, "timed": timed, "ratio_median_wall_B_over_A": ratio, "pair_ratios": pairs,
               "comparisons": comparisons, "identical": same}
        atomic_write_text(Path(a.json), json.dumps(doc, indent=1) + "\n")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
