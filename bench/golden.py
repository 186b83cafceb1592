"""Bit-identity of training before and after a refactor: short runs' metrics and final weights as digests.

    python bench/golden.py record /tmp/golden.json            # on the code before the change
    python bench/golden.py check  /tmp/golden.json            # on the code after it: exit 1 on any difference
    python bench/golden.py record /tmp/g.json --cases alone-sac-ReachTarget-v1   # a subset

Each case runs in a fresh process (PhysX CPU contacts are not reproducible across resets within one process,
so a fresh process is compared with a fresh process). A case is the smoke preset's single-task settings at
300 env steps (100 random, then 200 with updates): every method alone on every task, the three methods as one
pack on every task, the modern SAC variant alone and packed, the autograd update alone, the compiled update (``sac.compile``,
opt-in: bits of its own, held to themselves) alone, and a two-stage chain
(ReachTarget -> CloseMicrowave, replay carried) per transfer method plus the shared-prior chain. A digest holds
metrics.csv without its wall-clock column, the final agent state (networks, optimizers, alpha) as a sha256,
policy.pt's actor as a sha256, and the run folder's name relative to the case (chains: the config hashes).

The cases use the project's public entry points only: ``train.run_training``, ``train.train_runs``/``train.Job``
(before the one-loop change: ``pack.run_pack``/``pack.Job``) and ``experiment.protocol`` (``make_stages``, ``run_transfer``), so the same script runs on both sides.
"""
from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from maniskill_dualher.config import TASKS  # the catalog: every task
METHODS = ("sac", "sac_her_per", "dual_buffer")
STEPS = 300


def cases() -> dict:
    """name -> (kind, spec) with spec plain JSON."""
    out = {}
    for t in TASKS:
        for m in METHODS:
            out[f"alone-{m}-{t}"] = ("alone", {"method": m, "task": t, "set": []})
        out[f"pack-{t}"] = ("pack", {"runs": [{"method": m, "task": t, "set": []} for m in METHODS]})
    modern = ["sac.variant=modern"]
    out["alone-modern-dual_buffer-ReachTarget-v1"] = ("alone", {"method": "dual_buffer", "task": "ReachTarget-v1",
                                                                "set": modern})
    out["pack-modern-CloseBox-v1"] = ("pack", {"runs": [{"method": m, "task": "CloseBox-v1", "set": modern}
                                                        for m in METHODS]
                                               + [{"method": "dual_buffer", "task": "CloseBox-v1",
                                                   "set": modern + ["seed=1"]}]})
    # the opt-in compiled update (its bits are its own, not the eager update's): held to itself across changes
    out["alone-compiled-modern-dual_buffer-ReachTarget-v1"] = ("alone", {"method": "dual_buffer",
                                                                       "task": "ReachTarget-v1",
                                                                       "set": modern + ["sac.compile=true"]})
    out["alone-autograd-sac_her_per-ReachTarget-v1"] = ("alone", {"method": "sac_her_per", "task": "ReachTarget-v1",
                                                                  "set": ["sac.update_impl=autograd"]})
    for m in ("sac_her_per", "dual_buffer"):
        out[f"chain-{m}"] = ("chain", {"source": m, "adapt": m})
    out["chain-shared_prior"] = ("chain", {"source": "sac_her_per", "adapt": "dual_buffer"})
    return out


# --------------------------------------------------------------------------- inside a case's process
def _config(method: str, task: str, settings):
    from maniskill_dualher.experiment import overrides
    from maniskill_dualher.experiment.presets import PRESETS
    cfg = PRESETS["smoke"].single_config(method, 0, task)
    cfg.total_steps = STEPS
    return overrides.apply(cfg, overrides.parse_all(tuple(settings))).validate()


def _tensor_digest(obj) -> str:
    import torch
    h = hashlib.sha256()

    def walk(x, key=""):
        if isinstance(x, torch.Tensor):
            h.update(key.encode())
            h.update(x.detach().cpu().contiguous().numpy().tobytes())
        elif isinstance(x, dict):
            for k in sorted(x, key=str):
                walk(x[k], f"{key}/{k}")
        elif isinstance(x, (list, tuple)):
            for i, v in enumerate(x):
                walk(v, f"{key}/{i}")
        else:
            h.update(f"{key}={x!r}".encode())
    walk(obj)
    return h.hexdigest()


def load_tensors(path: Path):
    """``torch.load(weights_only=True)``, numpy's own globals allowed by the names the file holds: a tree older
    than the checkpoint of tensors (1c79b93) pickled numpy arrays, and this script runs on that tree too, where
    ``rundir.load_torch_file`` does not exist yet. Any other global is refused, so no file runs code when read."""
    import importlib

    import torch
    names = torch.serialization.get_unsafe_globals_in_checkpoint(path)
    foreign = [n for n in names if not n.startswith("numpy.")]
    if foreign:
        raise ValueError(f"{path}: holds {', '.join(foreign)}, not tensors and numpy arrays; not loaded")
    allowed = [(getattr(importlib.import_module(n.rpartition(".")[0]), n.rpartition(".")[2]), n) for n in names]
    if names:  # a dtype's state is set on an instance of its class (numpy.dtypes.Float32DType, ...)
        import numpy as np
        allowed += list({type(np.dtype(c)) for c in np.typecodes["All"]})
    with torch.serialization.safe_globals(allowed):
        return torch.load(path, map_location="cpu", weights_only=True)


def digest_run(run: Path, root: Path) -> dict:
    import torch
    lines = (run / "metrics.csv").read_text().splitlines()
    head = lines[0].split(",")
    keep = [i for i, k in enumerate(head) if k != "wall_time_s"]
    lines = [",".join(r.split(",")[i] for i in keep) for r in lines]
    metrics = "\n".join(lines)
    state = load_tensors(run / "checkpoint.pt")
    policy = load_tensors(run / "policy.pt")
    return {"folder": str(run.relative_to(root)), "metrics_sha": hashlib.sha256(metrics.encode()).hexdigest(),
            "rows": len(lines) - 1, "last_row": lines[-1], "agent_sha": _tensor_digest(state["agent"]),
            "counters": {k: v for k, v in state["counters"].items() if k != "wall_time"}, "actor_sha": _tensor_digest(policy["actor"])}


def run_case(name: str, root: Path) -> dict:
    import warnings
    warnings.filterwarnings("ignore")
    import maniskill_dualher  # noqa: F401
    try:  # tasks register on this import after the refactor; before it, on the package's
        import maniskill_dualher.tasks  # noqa: F401
    except ImportError:
        pass
    kind, spec = cases()[name]
    if kind == "alone":
        from maniskill_dualher.train import run_training
        out = root / "run"
        run_training(_config(spec["method"], spec["task"], spec["set"]), out, show_progress=False)
        return {"run": digest_run(out, root)}
    if kind == "pack":
        try:  # one driver for every run (after the refactor); before it, pack.run_pack
            from maniskill_dualher.train import Job, train_runs as run_pack
        except ImportError:
            from maniskill_dualher.pack import Job, run_pack
        jobs = [Job(_config(r["method"], r["task"], r["set"]), str(root / f"m{i}")) for i, r in enumerate(spec["runs"])]
        res = run_pack(jobs)
        errs = [r["error"] for r in res if "error" in r]
        if errs:
            raise errs[0]
        return {f"m{i}": digest_run(root / f"m{i}", root) for i in range(len(jobs))}
    from maniskill_dualher.experiment import protocol
    try:  # a chain is trained by train.py (after the refactor); before it, by protocol.run_transfer
        from maniskill_dualher.train import train_chain as run_transfer
    except ImportError:
        run_transfer = protocol.run_transfer
    src = _config(spec["source"], "ReachTarget-v1", [])
    stages = protocol.make_stages(src, ["ReachTarget-v1", "CloseMicrowave-v1"], [STEPS, STEPS])
    stages[-1].method = spec["adapt"]
    run_transfer(stages, root / "chain", carry_replay=True, show_progress=False)
    dirs = protocol.transfer_chain_dirs(root / "chain", stages, carry_replay=True)
    return {f"stage{i}": digest_run(d, root) for i, d in enumerate(dirs)}


# --------------------------------------------------------------------------- driver
def run_fresh(name: str) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        r = subprocess.run([sys.executable, __file__, "case", name, tmp], capture_output=True, text=True,
                           env={**os.environ, "PYTHONWARNINGS": "ignore"})
        if r.returncode != 0:
            return {"error": r.stderr.strip().splitlines()[-1] if r.stderr.strip() else f"rc {r.returncode}"}
        return json.loads(r.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("mode", choices=("record", "check"))
    p.add_argument("path")
    p.add_argument("--cases", nargs="*", default=None, help="case names (default: all)")
    a = p.parse_args(argv)
    names = a.cases or list(cases())
    unknown = [n for n in names if n not in cases()]
    if unknown:
        print(f"error: unknown case {unknown[0]!r}", file=sys.stderr)
        return 2
    if a.mode == "record":
        old = json.loads(Path(a.path).read_text()) if Path(a.path).is_file() else {}
        for n in names:
            old[n] = run_fresh(n)
            print(n, "error: " + old[n]["error"] if "error" in old[n] else "ok", flush=True)
            Path(a.path).write_text(json.dumps(old, indent=1, sort_keys=True))
        return 0
    want = json.loads(Path(a.path).read_text())
    bad = 0
    for n in names:
        got = run_fresh(n)
        same = got == want.get(n)
        bad += not same
        print(f"{n}: {'identical' if same else 'DIFFERENT'}", flush=True)
        if not same:
            for k in sorted(set(got) | set(want.get(n, {}))):
                if got.get(k) != want.get(n, {}).get(k):
                    print(f"  {k}: was {want.get(n, {}).get(k)}\n  {' ' * len(k)}  now {got.get(k)}")
    print(f"{len(names) - bad}/{len(names)} identical")
    return 1 if bad else 0


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "case":  # one case, in the fresh process run_fresh started
        print(json.dumps(run_case(sys.argv[2], Path(sys.argv[3]))))
        sys.exit(0)
    sys.exit(main())
