"""Instructions per env step, ManiSkill's step against the lean step, counted by valgrind (callgrind): a measure
that other processes on the machine cannot disturb (wall and CPU time on a busy 2-core machine can be).

    python bench/step_instructions.py [--tasks CloseMicrowave-v1] [--steps 100] [--out FILE.txt]

For each task and path (``MANISKILL_DUALHER_LEAN_STEP`` 0 and 1) it runs ``--steps`` random-action
``BatchEnv.step`` calls under callgrind, counting only those steps (instrumentation switched on around them),
and reports the instructions per step, those inside PhysX's substeps (``PhysxSystemCpu::step``) and the ratio.
Instructions are not time (Python runs fewer instructions per cycle than PhysX), so the ratio is a lower bound
on the time ratio; ``bench/step_budget.py`` gives the time. Needs valgrind; ~4 min wall per run under load.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def child(task: str, steps: int) -> None:
    """Inside valgrind: build the env, warm up, count ``steps`` steps."""
    sys.path.insert(0, str(ROOT))
    import numpy as np
    import torch

    torch.set_num_threads(1)
    from maniskill_dualher.config import RunConfig
    from maniskill_dualher.envs import make_env

    env = make_env(RunConfig(env_id=task))
    acts = np.random.default_rng(0).uniform(-1, 1, (steps + 20, 1, env.spec.act_dim)).astype(np.float32)
    env.reset(0)
    for a in acts[:20]:
        env.step(a)
    env.reset(1)
    ctl = ["callgrind_control", "-i"]
    subprocess.run(ctl + ["on", str(os.getpid())], check=True, capture_output=True)
    for a in acts[20:]:
        env.step(a)
    subprocess.run(ctl + ["off", str(os.getpid())], check=True, capture_output=True)
    print(f"lean={env.lean is not None}")


def count(task: str, steps: int, lean: bool) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "cg.out")
        env = dict(os.environ, MANISKILL_DUALHER_LEAN_STEP="1" if lean else "0", PYTHONPATH=str(ROOT))
        r = subprocess.run(["valgrind", "--tool=callgrind", "--instr-atstart=no", f"--callgrind-out-file={out}",
                            os.path.realpath(sys.executable), __file__, "--child", task, "--steps", str(steps)],
                           env=env, capture_output=True, text=True)
        if r.returncode != 0 or f"lean={lean}" not in r.stdout:
            raise SystemExit(f"callgrind run failed ({task}, lean={lean}): {r.stderr.strip().splitlines()[-1:]}")
        ann = subprocess.run(["callgrind_annotate", "--inclusive=yes", out], capture_output=True, text=True).stdout
    total = int(re.search(r"([\d,]+) \(100\.0%\)\s+PROGRAM TOTALS", ann).group(1).replace(",", ""))
    physics = int(re.search(r"([\d,]+) \([\d.]+%\)\s+\S*PhysxSystemCpu::step\(\)", ann).group(1).replace(",", ""))
    return {"task": task, "lean": lean, "steps": steps, "instructions": total, "physics": physics}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", default="CloseMicrowave-v1")
    p.add_argument("--steps", type=int, default=100)
    p.add_argument("--out")
    p.add_argument("--child", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.steps < 1:
        print(f"--steps={args.steps} must be >= 1", file=sys.stderr)
        raise SystemExit(2)
    if args.child:
        return child(args.child, args.steps)
    sys.path.insert(0, str(ROOT))
    from maniskill_dualher.config import TASKS
    tasks = [t for t in args.tasks.split(",") if t]
    bad = [t for t in tasks if t not in TASKS]
    if bad or not tasks:
        print(f"--tasks={args.tasks!r}: unknown task {bad[0] if bad else ''!r}", file=sys.stderr)
        raise SystemExit(2)
    if shutil.which("valgrind") is None:
        print("valgrind not found: this bench counts instructions with callgrind", file=sys.stderr)
        raise SystemExit(2)
    from maniskill_dualher import provenance
    prov = provenance.provenance(ROOT)
    lines = [f"command: python bench/step_instructions.py {' '.join(argv if argv is not None else sys.argv[1:])}",
             f"commit: {prov.get('commit')} dirty={prov.get('dirty')}; machine: {provenance.machine_label(prov['cpu'])}",
             f"{'task':<20}{'path':<11}{'instr/step':>12}{'physics/step':>14}{'step/physics':>14}"]
    for task in tasks:
        for lean in (False, True):
            c = count(task, args.steps, lean)
            n = c["steps"]
            lines.append(f"{task:<20}{'lean' if lean else 'maniskill':<11}{c['instructions'] / n:>12.0f}"
                         f"{c['physics'] / n:>14.0f}{c['instructions'] / c['physics']:>14.3f}")
            print(lines[-1], flush=True)
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        from maniskill_dualher.fileio import atomic_write_text
        atomic_write_text(args.out, text)


if __name__ == "__main__":
    main()
