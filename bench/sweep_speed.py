"""Sweep throughput: the same small sweep run unpacked (one run per worker, the loop as it was) and packed
(``sweep --pack S``: up to S runs per worker, their updates batched, ``maniskill_dualher/pack.py``), one after
the other on this machine, in training env steps per second of wall time; and a check that both sweeps
produced the same metrics (a run's results do not depend on its pack).

    python bench/sweep_speed.py [--packs 1,8] [--steps 4000] [--seeds 0,1,2,3] [--methods sac_her_per,dual_buffer]
                                [--tasks ID,ID,...] [--workers 2] [--preset quick]

The sweep is ``python -m maniskill_dualher.sweep --preset quick --experiments single`` at the quick preset's
settings (64x64 networks, batch 256, one update per env step after 1000 steps, evaluation every 1000 steps),
with every run's budget set to ``--steps``; each variant starts from an empty folder, in its own process, as a
user runs it (imports, pool start-up and the report excluded: ``--no-report``; time from the command's start
to its end). Wall time includes evaluation and checkpoints; env steps/s counts training env steps only.
Prints the CPU (model and the instruction sets that change speed), the workers and torch threads (one per
worker), each variant's wall time and env steps/s, and the ratio to the first variant.
"""
from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from maniskill_dualher.experiment.registry import PAPER_CHAIN  # noqa: E402  (the sweep's default tasks)


def metrics(folder: Path) -> dict:
    """Every run's metrics.csv rows without wall time, by run folder."""
    out = {}
    for f in sorted(folder.rglob("metrics.csv")):
        with open(f) as fh:
            out[str(f.parent.relative_to(folder))] = [{k: v for k, v in r.items() if k != "wall_time_s"}
                                                     for r in csv.DictReader(fh)]
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--packs", default="1,8", help="pack sizes to compare, the first is the baseline")
    p.add_argument("--steps", type=int, default=4000, help="env steps of every run")
    p.add_argument("--seeds", default="0,1,2,3")
    p.add_argument("--methods", default="sac_her_per,dual_buffer")
    p.add_argument("--tasks", default=",".join(PAPER_CHAIN), help="comma list (default: the paper's tasks, "
                   "registry.PAPER_CHAIN, the sweep's default)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--preset", default="quick")
    p.add_argument("--json", help="also write the results here")
    a = p.parse_args(argv)
    try:
        packs = [int(x) for x in a.packs.split(",")]
        if not packs or min(packs) < 1:
            raise ValueError
    except ValueError:
        print(f"error: --packs must be pack sizes >= 1 like 1,8, got {a.packs!r}", file=sys.stderr)
        return 2

    from maniskill_dualher.provenance import cpu_info, machine_label
    cpu = cpu_info()
    n_runs = len(a.seeds.split(",")) * len(a.methods.split(",")) * len(a.tasks.split(","))
    print(f"CPU: {machine_label(cpu)}; {os.cpu_count()} logical cores; {a.workers} workers, 1 torch thread each")
    print(f"sweep: preset {a.preset}, single-task, {n_runs} runs x {a.steps} env steps "
          f"(tasks {a.tasks}; methods {a.methods}; seeds {a.seeds})")
    results, seen = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for S in packs:
            out = Path(tmp) / f"pack{S}"
            cmd = [sys.executable, "-m", "maniskill_dualher.sweep", "--preset", a.preset, "--experiments", "single",
                   "--tasks", a.tasks, "--methods", a.methods, "--seeds", a.seeds, "--source-steps", str(a.steps),
                   "--workers", str(a.workers), "--pack", str(S), "--out", str(out), "--no-report"]
            t0 = time.perf_counter()
            r = subprocess.run(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            wall = time.perf_counter() - t0
            if r.returncode != 0:
                print(f"pack {S}: sweep failed (exit {r.returncode}): {r.stderr.strip().splitlines()[-1:]}")
                return 1
            seen[S] = metrics(out)
            steps = n_runs * a.steps
            results.append({"pack": S, "wall_s": round(wall, 1), "env_steps": steps,
                            "env_steps_per_s": round(steps / wall, 1)})
            base = results[0]["env_steps_per_s"]
            print(f"  pack {S:>2}: {wall:7.1f} s  {steps / wall:7.1f} env steps/s  "
                  f"x{steps / wall / base:.2f} against pack {packs[0]}", flush=True)
    same = all(seen[S] == seen[packs[0]] for S in packs)
    print(f"metrics of every run identical across pack sizes (wall time aside): {same} "
          f"({len(seen[packs[0]])} runs)")
    if a.json:
        Path(a.json).write_text(json.dumps({"cpu": machine_label(cpu), "workers": a.workers, "torch_threads": 1,
                                            "runs": n_runs, "steps": a.steps, "results": results,
                                            "identical": same}, indent=1) + "\n")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
