"""Calibrate the sweep's dry-run ETA on this machine: its timed inputs and the wall times it should predict.

    python bench/eta_calibration.py --out bench/results/eta_calibration_<machine>_<commit>.json [--load NOTE]
                                    [--plans readme_first_command,smoke] [--add-plan NAME=SECONDS:ARGV ...]

Measures per plan, on one thread, idle machine wanted, what the dry run times for it:
  update_s   one SAC update of each of its runs' networks and batches at the pack size its workers batch
             (``cost.update_seconds``: an agent's share of a batched update), keyed by what it depends on
  step_s     one env step with acting of each of its envs (``cost.env_step_seconds``)
  start_s    building each of its envs (``cost.run_start_seconds``: a run's setup before its loop)
  worker_start_s  a fresh worker's imports (``cost.worker_start_seconds``)
and runs each plan (a sweep command) from an empty folder in a fresh process with ``--no-report`` (the ETA
excludes the report), timing it from start to end.
``tests/test_sweep.py::test_eta_within_25_percent_of_measured_wall_times`` feeds the model these timed inputs
and holds its ETA within the file's band of each plan's wall time (every ``eta_calibration_*.json``).

``--add-plan NAME=SECONDS:ARGV`` adds a wall time measured elsewhere (e.g. a part of a long study, whose
HOW_MADE gives it) without running it; ARGV is the sweep's arguments, space-separated. A plan may carry
``bound: low`` (its update count is the range's low end: Algorithm 1's one update per finished episode when
episodes rarely end early); the file says which and why.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

PLANS = {
    "readme_first_command": ["--experiments", "single", "--tasks", "ReachTarget-v1", "--seeds", "3"],
    "smoke": ["--preset", "smoke"],
}


def _key(cfg, pack: int) -> str:
    """What an update's time depends on (``cost.update_seconds``'s cache key, as text)."""
    sac = cfg.sac
    return f"{'x'.join(map(str, sac.hidden))}|b{sac.batch_size}|{sac.variant}|pack{pack}"


def timed_inputs(argv) -> dict:
    """The dry run's timed inputs for one plan, timed here as the dry run times them: each run's update seconds
    at the pack size its worker batches (``min(--pack, runs)``) and each env's step seconds with acting."""
    import torch
    torch.set_num_threads(1)
    import maniskill_dualher.tasks  # noqa: F401
    from maniskill_dualher.experiment import cost, sweep
    from maniskill_dualher.experiment.grid import build_grid
    from maniskill_dualher.pack import pack_key
    args = sweep.make_parser().parse_args(argv)
    cfgs = [n.cfg for n in build_grid(sweep.definition_from_args(args))]
    pack = min(args.pack or sweep.DEFAULT_PACK, len(cfgs))
    upd, steps, starts = {}, {}, {}
    for c in cfgs:
        k = _key(c, pack if pack_key(c) is not None else 1)
        if k not in upd:
            upd[k] = cost.update_seconds(c, iters=200, pack=pack)
        if c.env_id not in steps:
            steps[c.env_id] = cost.env_step_seconds(c, steps=2000)
            starts[c.env_id] = cost.run_start_seconds(c)
    return {"update_s": upd, "step_s": steps, "start_s": starts, "pack": pack,
            "worker_start_s": cost.worker_start_seconds()}


def run_plan(argv, workers: int) -> float:
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "maniskill_dualher.sweep", *argv, "--out", os.path.join(tmp, "out"),
               "--workers", str(workers), "--no-report"]
        t0 = time.perf_counter()
        r = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True,
                           env=dict(os.environ, PYTHONPATH=str(REPO)))
        wall = time.perf_counter() - t0
        if r.returncode != 0:
            raise SystemExit(f"plan {' '.join(argv)} failed (exit {r.returncode}): {r.stderr.strip()[-300:]}")
    return wall


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", required=True, help="the raw JSON file (atomic write)")
    p.add_argument("--plans", default=",".join(PLANS), help=f"comma-separated subset of {','.join(PLANS)}")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--band", type=float, default=0.25)
    p.add_argument("--load", default="", help="a note on the machine's load while this ran")
    p.add_argument("--add-plan", action="append", default=[], metavar="NAME=SECONDS:ARGV",
                   help="a wall time measured elsewhere (not run here), with the sweep arguments it ran")
    p.add_argument("--bound-low", action="append", default=[], metavar="NAME",
                   help="this plan's ETA is the estimate's low end (its updates are the range's low end)")
    a = p.parse_args(argv)
    names = [n for n in a.plans.split(",") if n]
    bad = [n for n in names if n not in PLANS]
    if bad:
        print(f"--plans={a.plans!r}: unknown plan {bad[0]!r} (choose from {','.join(PLANS)})", file=sys.stderr)
        return 2
    added = {}
    for item in a.add_plan:
        try:
            name, rest = item.split("=", 1)
            secs, args = rest.split(":", 1)
            added[name] = {"argv": args.split(), "wall_s": float(secs), "source": "measured elsewhere (--add-plan)"}
            added[name].update(timed_inputs(added[name]["argv"]))
        except ValueError:
            print(f"--add-plan {item!r}: expected NAME=SECONDS:ARGV", file=sys.stderr)
            return 2
    unknown = [n for n in a.bound_low if n not in names and n not in added]
    if unknown:
        print(f"--bound-low {unknown[0]!r}: not one of the plans ({','.join(names + list(added))})", file=sys.stderr)
        return 2
    from maniskill_dualher import provenance
    from maniskill_dualher.fileio import atomic_write_text
    prov = provenance.provenance(REPO)
    doc = {"what": "the sweep's dry-run ETA inputs timed on this machine and the wall times it should predict; "
                   "tests/test_sweep.py::test_eta_within_25_percent_of_measured_wall_times",
           "command": " ".join(["bench/eta_calibration.py"] + list(argv if argv is not None else sys.argv[1:])),
           "machine": provenance.machine_name(prov["cpu"]), "provenance": prov, "load": a.load,
           "band": a.band, "workers": a.workers}
    plans = {}
    for name in names:
        inputs = timed_inputs(PLANS[name])
        wall = run_plan(PLANS[name], a.workers)
        plans[name] = {"argv": PLANS[name], "wall_s": round(wall, 1), **inputs,
                       "source": f"run here: python -m maniskill_dualher.sweep {' '.join(PLANS[name])} --out TMP "
                                 f"--workers {a.workers} --no-report, from start to end"}
        print(f"{name}: {wall:.1f} s", flush=True)
    plans.update(added)
    for name in a.bound_low:
        plans[name]["bound"] = "low"
    doc["plans"] = plans
    atomic_write_text(a.out, json.dumps(doc, indent=1) + "\n")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
