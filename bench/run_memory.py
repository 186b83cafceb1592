"""Resident memory of one training run: its peak before the final checkpoint, inside it, and overall.

    python bench/run_memory.py                                    # this tree: a 40k-step paper-preset run
    python bench/run_memory.py --tree <clone> --no-json    # another tree (its own code, a clone)
    python bench/run_memory.py --steps 40000 --task CloseMicrowave-v1 --method sac_her_per

The run is ``python -m maniskill_dualher.train --preset paper --task TASK --method METHOD --total-steps N
--out TMP --no-progress`` in a fresh process whose PYTHONPATH is the tree measured (default: this one). A small
wrapper around ``train.Trainer.save_checkpoint`` and ``train.Trainer.start`` (on both sides) records,
from ``/proc/self/status``: VmRSS when the run starts its loop (imports done, env and networks built: the
process's baseline), VmRSS and VmHWM (the peak so far) on entering and leaving every checkpoint write with the
rows stored in its replay, and ``ru_maxrss`` at exit. The peak before the final checkpoint is VmHWM on entering
the last checkpoint that holds the replay; the overall peak is ``ru_maxrss``.

A second measurement (this tree's code): a bare buffer of capacity 10^7 (``replay.buffer.make_buffer``, the paper's
43-float input, 8 actions), prioritized and uniform, filled in episode-sized chunks to 300,000 and 1,500,000 rows:
its resident growth per row at each and between them, beside ``experiment.cost.replay_row_bytes``'s formula (the
difference at few rows is fixed: numpy asks for transparent huge pages, so each array region in use ends in a
partly filled 2 MiB page). Prints a summary and writes JSON to
``bench/results/run_memory_cpuB_<commit>.json`` (machine name from ``provenance.machine_name``; ``--no-json`` to
skip; ``--json PATH`` elsewhere).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent

CHILD = r"""
import json, resource, sys, time

def status(key):
    with open('/proc/self/status') as f:
        for line in f:
            if line.startswith(key + ':'):
                return int(line.split()[1]) * 1024
    return None

from maniskill_dualher import train

events, start = [], {}
_save = train.Trainer.save_checkpoint

def save(self, replay=True):
    rows = {k: len(b) for k, b in self.method.buffers.items()} if replay else None
    ev = {'rows': rows, 'rss_before': status('VmRSS'), 'hwm_before': status('VmHWM'), 't_before': time.time()}
    _save(self, replay)
    ev.update(rss_after=status('VmRSS'), hwm_after=status('VmHWM'), t_after=time.time())
    events.append(ev)

train.Trainer.save_checkpoint = save
_start = train.Trainer.start

def start_(self):
    start.setdefault('rss', status('VmRSS'))
    start.setdefault('hwm', status('VmHWM'))
    return _start(self)

train.Trainer.start = start_
t0 = time.time()
rc = train.main(sys.argv[1:])
print('RUN_MEMORY ' + json.dumps({'rc': rc, 'events': events, 'start': start, 'wall_s': time.time() - t0,
                                  'ru_maxrss': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}))
"""

BARE = r"""
import json, sys
import numpy as np

def rss():
    with open('/proc/self/status') as f:
        for line in f:
            if line.startswith('VmRSS:'):
                return int(line.split()[1]) * 1024

from maniskill_dualher.config import ReplayConfig
from maniskill_dualher.experiment.cost import replay_row_bytes
from maniskill_dualher.replay.buffer import make_buffer
D, A, CAP, CHUNK = 43, 8, 10**7, 750
rng = np.random.default_rng(0)
chunk = {'obs': rng.random((CHUNK, D), np.float32), 'action': rng.random((CHUNK, A), np.float32),
         'reward': np.zeros(CHUNK, np.float32), 'next_obs': rng.random((CHUNK, D), np.float32),
         'done': np.zeros(CHUNK, np.float32)}
out = {'capacity': CAP, 'obs_dim': D, 'act_dim': A, 'chunk': CHUNK, 'formula_per_row': replay_row_bytes(D, A, prioritized=True)}
for prioritized in (True, False):
    buf = make_buffer(CAP, D, A, prioritized=prioritized, replay_cfg=ReplayConfig())
    before, at = rss(), {}
    for n in (300_000, 1_500_000):
        while len(buf) < n:
            idx = buf.add(chunk)
            if prioritized:
                buf.update_priorities(idx[:256], rng.random(256))
        at[n] = rss() - before
    key = 'prioritized' if prioritized else 'uniform'
    out[key] = {'rss_growth': at, 'per_row_at_300k': at[300_000] / 300_000, 'per_row_at_1500k': at[1_500_000] / 1_500_000,
                'per_row_between': (at[1_500_000] - at[300_000]) / 1_200_000,
                'formula_per_row': replay_row_bytes(D, A, prioritized=prioritized)}
    del buf
print('BARE ' + json.dumps(out))
"""


def _last(prefix: str, text: str) -> dict:
    for line in reversed(text.splitlines()):
        if line.startswith(prefix + " "):
            return json.loads(line[len(prefix) + 1:])
    raise SystemExit(f"error: the child printed no {prefix} line:\n{text[-3000:]}")


def _git_short(tree: Path) -> str:
    r = subprocess.run(["git", "rev-parse", "--short=7", "HEAD"], cwd=tree, capture_output=True, text=True)
    return r.stdout.strip() or "unknown"


def _mb(b) -> float:
    return round(b / 1e6, 1) if b is not None else None  # MB (10^6 bytes), as experiment/cost.py


def measure_run(tree: Path, task: str, method: str, steps: int, preset: str) -> dict:
    with tempfile.TemporaryDirectory(prefix="run_memory_") as tmp:
        argv = ["--preset", preset, "--task", task, "--method", method, "--total-steps", str(steps),
                "--out", str(Path(tmp) / "run"), "--no-progress"]
        env = dict(os.environ, PYTHONPATH=str(tree))
        r = subprocess.run([sys.executable, "-c", CHILD, *argv], env=env, capture_output=True, text=True, cwd=tmp)
        out = _last("RUN_MEMORY", r.stdout + "\n" + r.stderr)
    if out["rc"] != 0:
        raise SystemExit(f"error: the run exited {out['rc']}:\n{r.stderr[-3000:]}")
    with_replay = [e for e in out["events"] if e["rows"] is not None]
    if not with_replay:
        raise SystemExit("error: the run wrote no checkpoint holding its replay")
    last = with_replay[-1]
    rows = sum(last["rows"].values())
    peak_in = max(last["hwm_after"] - last["hwm_before"], 0)
    return {
        "command": "python -m maniskill_dualher.train " + " ".join(argv[:-3] + ["--out", "TMP", "--no-progress"]),
        "tree": "." if tree == HERE.parent else f"<a clone of {_git_short(tree)}>", "commit": _git_short(tree), "wall_s": round(out["wall_s"], 1),
        "rows_stored": rows, "rows_per_buffer": last["rows"],
        "rss_at_loop_start_bytes": out["start"].get("rss"),
        "rss_before_final_checkpoint_bytes": last["rss_before"],
        "peak_rss_before_final_checkpoint_bytes": last["hwm_before"],
        "peak_rss_overall_bytes": out["ru_maxrss"],
        "final_checkpoint_peak_above_prior_peak_bytes": peak_in,
        "final_checkpoint_s": round(last["t_after"] - last["t_before"], 2),
        "checkpoints": out["events"],
    }


def measure_bare(tree: Path) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree))
    r = subprocess.run([sys.executable, "-c", BARE], env=env, capture_output=True, text=True)
    return _last("BARE", r.stdout + "\n" + r.stderr)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--tree", default=str(ROOT), help="the source tree to run (its PYTHONPATH; default: this one)")
    p.add_argument("--task", default="CloseMicrowave-v1")
    p.add_argument("--method", default="sac_her_per")
    p.add_argument("--steps", type=int, default=40_000)
    p.add_argument("--preset", default="paper")
    p.add_argument("--no-bare", action="store_true", help="skip the bare-buffer measurement")
    p.add_argument("--json", help="output path (default: bench/results/run_memory_cpuB_<commit>.json)")
    p.add_argument("--no-json", action="store_true")
    a = p.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from maniskill_dualher.provenance import cpu_info, machine_name, provenance

    tree = Path(a.tree).resolve()
    run = measure_run(tree, a.task, a.method, a.steps, a.preset)
    doc = {"bench": "run_memory", "machine": machine_name(cpu_info()), "provenance": provenance(tree), "run": run}
    if not a.no_bare:
        doc["bare_buffer"] = measure_bare(ROOT)
    print(f"{run['command']}  (tree {run['commit']}, {doc['machine']}, {run['wall_s']} s)")
    print(f"  rows stored {run['rows_stored']:,}; RSS at loop start {_mb(run['rss_at_loop_start_bytes'])} MB; "
          f"before the final checkpoint {_mb(run['rss_before_final_checkpoint_bytes'])} MB "
          f"(peak so far {_mb(run['peak_rss_before_final_checkpoint_bytes'])} MB); "
          f"peak overall {_mb(run['peak_rss_overall_bytes'])} MB; the final checkpoint took "
          f"{run['final_checkpoint_s']} s and rose {_mb(run['final_checkpoint_peak_above_prior_peak_bytes'])} MB "
          "above the earlier peak")
    for key in ("prioritized", "uniform"):
        b = doc.get("bare_buffer", {}).get(key)
        if b:
            print(f"  bare {key} buffer (capacity 10^7): {b['per_row_at_300k']:.0f} B per row at 300k rows, "
                  f"{b['per_row_at_1500k']:.0f} at 1.5M, {b['per_row_between']:.0f} between them "
                  f"(formula {b['formula_per_row']} B)")
    if not a.no_json:
        path = Path(a.json) if a.json else HERE / "results" / f"run_memory_cpuB_{run['commit']}.json"
        path.write_text(json.dumps(doc, indent=2) + "\n")
        print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
