"""Where a running sweep's time goes: py-spy's sampled stacks of its workers, in the parts of bench/step_budget.py.

    py-spy record -p PID -d 150 -r 50 -f raw --nonblocking -o a.txt      # one worker, while it trains
    gzip a.txt
    python bench/live_profile.py a.txt.gz=RUN_A b.txt.gz=RUN_B --out bench/results/live_profile_<machine>.json

`bench/step_budget.py` times a run it starts on an idle machine; this reads the production run itself (R at its
full size, two workers sharing the machine's memory and caches). Each sample is charged to the first part
(in the order of PARTS) one of its frames belongs to; the shares times the run's own wall time per env step (the
median over the last five evaluation intervals of its metrics.csv: summarize right after profiling) give ms per
env step. py-spy sees no native frames: a part's share holds the C/C++ it calls (PhysX inside the env
step, the compiled update's kernels inside its graph). The raw stacks are committed beside the JSON, gzipped.
"""
from __future__ import annotations

import argparse
import collections
import csv
import gzip
import json
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from maniskill_dualher.cmdline import OneLineParser  # noqa: E402
from maniskill_dualher.fileio import atomic_write_text  # noqa: E402
from maniskill_dualher.provenance import machine_name, provenance  # noqa: E402

# (part, pattern on one frame "function (file:line)"): the first part any frame of a sample matches takes it
PARTS = [
    ("checkpoints", r"^Trainer\.save_checkpoint "),
    ("evaluation", r"^evaluate_runs \(maniskill_dualher/train\.py"),
    ("update: compiled graph", r"^_wrap_func\.<locals>\.g "),
    ("update: the rest (dynamo's frame and guards, fused Adam and Polyak, noise draws, Python)", r"^SAC\.update \("),
    ("sampling", r"^Trainer\.sample \("),
    ("priorities", r"update_priorities \("),
    ("env step (PhysX and its Python)", r"^BatchEnv\.step \("),
    ("env reset", r"^BatchEnv\.reset_envs \("),
    ("acting", r"^Trainer\._explore \("),
    ("storing (episodes, HER)", r"^Trainer\._store \(|add_episode \("),
    ("training loop and the rest", r""),
]


def read_stacks(path: Path):
    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt", errors="replace") as f:
        for line in f:
            stack, _, n = line.rstrip("\n").rpartition(" ")
            if stack:
                yield stack.split(";"), int(n)


def parts_of(path: Path) -> dict:
    counts = collections.Counter()
    compiled = [(name, re.compile(p)) for name, p in PARTS]
    for frames, n in read_stacks(path):
        counts[next(name for name, rx in compiled if any(rx.search(f) for f in frames))] += n
    total = sum(counts.values())
    return {"samples": total, "shares": {name: counts[name] / total for name, _ in PARTS}}


def run_clock(run: Path, intervals: int = 5) -> dict:
    """The run's own wall time per env step: the median over its last `intervals` evaluation intervals (one that
    holds a checkpoint write of the full replay, tens of seconds, is the one the median leaves out)."""
    with open(run / "metrics.csv", newline="") as f:
        rows = [(float(r["env_steps"]), float(r["wall_time_s"])) for r in csv.DictReader(f)][-1 - intervals:]
    per = sorted(1000 * (t1 - t0) / (s1 - s0) for (s0, t0), (s1, t1) in zip(rows, rows[1:]))
    return {"env_steps": [int(rows[0][0]), int(rows[-1][0])], "ms_per_env_step": per[len(per) // 2]}


def main(argv=None) -> int:
    p = OneLineParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("pairs", nargs="+", help="PROFILE=RUN: py-spy's raw stacks (.txt or .txt.gz) and the run folder")
    p.add_argument("--out", type=Path, help="the JSON to write (default: print only)")
    a = p.parse_args(argv)
    prov = {**provenance(Path(__file__).resolve().parents[1]), "repo": "."}  # no machine path in a shared file
    out = {"command": "bench/live_profile.py " + " ".join(argv if argv is not None else sys.argv[1:]),
           "machine": machine_name(prov["cpu"]), "parts_rule": PARTS, "provenance": prov, "profiles": []}
    for pair in a.pairs:
        prof, sep, run = pair.partition("=")
        prof, run = Path(prof), Path(run)
        if not sep or not prof.is_file() or not (run / "metrics.csv").is_file():
            p.error(f"{pair}: give PROFILE=RUN, a py-spy raw file and a run folder with metrics.csv")
        cfg = json.loads((run / "config.json").read_text())
        made = json.loads((run / "provenance.json").read_text())["starts"][-1]
        entry = {"profile": prof.name, "run": run.name, "method": cfg["method"], "env_id": cfg["env_id"],
                 "seed": cfg["seed"], "run_commit": made["commit_short"], "run_machine": machine_name(made["cpu"]),
                 "run_cpu": made["cpu"], **run_clock(run), **parts_of(prof)}
        entry["ms_per_env_step_by_part"] = {k: v * entry["ms_per_env_step"] for k, v in entry["shares"].items()}
        out["profiles"].append(entry)
        print(f"{entry['method']} on {entry['env_id']}, seed {entry['seed']} ({entry['run_machine']}, code "
              f"{entry['run_commit']}): {entry['ms_per_env_step']:.2f} ms per env step over env steps "
              f"{entry['env_steps'][0]:,}-{entry['env_steps'][1]:,}; {entry['samples']} samples")
        for k, v in entry["shares"].items():
            print(f"  {100 * v:5.1f}%  {entry['ms_per_env_step_by_part'][k]:.3f} ms  {k}")
    if a.out:
        atomic_write_text(a.out, json.dumps(out, indent=1) + "\n")
        print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
