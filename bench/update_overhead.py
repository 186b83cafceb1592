"""The fused SAC update's time and its overhead at pack sizes 1, 2, 8: this tree against a base tree.

    python bench/update_overhead.py [--base DIR] [--packs 1,2,8] [--reps 5] [--updates 200] [--chunks 5]
                                    [--warmup 50] [--json FILE]
    python bench/update_overhead.py --precision-b bf16 [...]   # side B: this tree at another matmul precision
    python bench/update_overhead.py --compile-b [...]          # side B: this tree with sac.compile (torch.compile)

With ``--precision-b P`` (instead of ``--base``) side B is this tree with ``sac.matmul_precision = P`` (side A
keeps the preset's strict fp32): issue 32's question whether the opt-in bf16 products speed up the 64x64 update.
Its weights are not expected to equal A's (bf16 rounds), so the digests are reported, not required equal.
``--compile-b`` likewise makes side B this tree with ``sac.compile = True`` (``torch.compile`` of the fused
update, inductor; needs a C++ compiler): its compilation happens in the warm-up; its products phase runs the
compiled function with the product timers inside it (they break its graph), so only its total is meaningful,
and its weights differ from A's (inductor fuses the elementwise ops and rounds differently).

What one "update" is: one ``pack.Updater.round`` over S runs that are due together, as ``train.drive`` calls it:
S agents with the quick preset's update settings (``dual_buffer``'s: modern SAC, learned alpha, 64x64, batch 256,
no IS weights, no actor batch; input 43 = observation 40 + desired goal 3, 8 actions as on the Panda tasks),
each on its own fixed random batch; a group of one goes through ``SAC.update``, a larger one through
``FusedUpdate.step_pack``. Losses are read every ``log_every`` (100) updates, as the training loop asks.

What is measured, per update of the whole pack (ms; ``per agent`` = that / S):
  total      wall time of the round (``perf_counter``), and the thread's CPU time beside it (``thread_time``)
  products   wall time inside the update's matrix products (``torch.mm/bmm/addmm/baddbmm/mv`` called from
             ``sac_fused``, as ``bench/step_budget.py`` times them), in a second phase with timers around each
             product (the timers are not in ``total``)
  overhead   total - products: elementwise work, Adam, Polyak, stacking, per-op dispatch and Python
             (``docs/speed.md``'s "update overhead")
Each (side, S) runs in a fresh process (``--warmup`` untimed updates, then ``--chunks`` chunks of ``--updates``
updates; the process reports each quantity's median over its chunks) with one torch/OpenMP/MKL thread. The
processes are interleaved: per repetition and pack size, this tree (A) and the base (B) back to back, in the
order AB on even repetitions and BA on odd ones (over two repetitions: ABBA). Printed and written: per side and
S the median over the ``--reps`` processes with [min, max], and the ratio B / A of the medians with each
adjacent A/B pair's ratio (their spread). Both sides run the same script (this file) against their own
package (``PYTHONPATH``); every process also reports a digest of the agents' weights after its timed updates,
and the bench checks that both sides' digests agree (the same seeds, batches and updates: the same bits).

Measure on an idle machine: single processes on these 2-core machines vary by ~10% under load.
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PRODUCTS = ("mm", "bmm", "addmm", "baddbmm", "mv")
INPUT_DIM, ACT_DIM = 43, 8
QUANTITIES = ("total_ms", "cpu_ms", "products_ms", "overhead_ms")


# --------------------------------------------------------------------------- inside a worker process
class _Run:
    """What ``pack.Updater.round`` reads of a ``train.Trainer``: k, cfg, agent, sample(), learn()."""

    def __init__(self, k, cfg, agent, batches):
        self.k, self.cfg, self.agent, self.batches = k, cfg, agent, batches
        self.updates = 0

    def sample(self):
        batch = self.batches[self.updates % len(self.batches)]
        return batch, None, self.updates % self.cfg.sac.log_every == 0

    def learn(self, batch, td_abs, logs, log_now):
        self.updates += 1


def _fail(run, e):
    raise e


def worker(pack: int, updates: int, chunks: int, warmup: int, precision: str = "", compiled: bool = False) -> dict:
    import torch
    torch.set_num_threads(1)
    import maniskill_dualher
    import maniskill_dualher.sac_fused as sf
    from maniskill_dualher import pack as packing
    from maniskill_dualher.experiment.presets import PRESETS
    from maniskill_dualher.replay.base import Batch
    from maniskill_dualher.sac import SAC

    cfg = PRESETS["quick"].single_config("dual_buffer", 0, "ReachTarget-v1")
    if precision:
        import dataclasses
        cfg = dataclasses.replace(cfg, sac=dataclasses.replace(cfg.sac, matmul_precision=precision))
    if compiled:
        import dataclasses
        cfg = dataclasses.replace(cfg, sac=dataclasses.replace(cfg.sac, compile=True))
    B = cfg.sac.batch_size
    runs = []
    for i in range(pack):
        g = torch.Generator().manual_seed(i)
        agent = SAC(INPUT_DIM, ACT_DIM, cfg.sac, device=cfg.device, generator=g, init_generator=g)
        d = torch.Generator().manual_seed(1000 + i)
        batches = [Batch(torch.randn(B, INPUT_DIM, generator=d), torch.rand(B, ACT_DIM, generator=d) * 2 - 1,
                         (torch.rand(B, generator=d) > .7).float(), torch.randn(B, INPUT_DIM, generator=d),
                         (torch.rand(B, generator=d) > .9).float(), None) for _ in range(4)]
        runs.append(_Run(i, cfg, agent, batches))
    updater = packing.Updater()

    def rounds(n):
        for _ in range(n):
            updater.round(runs, _fail)

    rounds(warmup)
    total, cpu = [], []
    for _ in range(chunks):
        t, c = time.perf_counter(), time.thread_time()
        rounds(updates)
        cpu.append((time.thread_time() - c) / updates)
        total.append((time.perf_counter() - t) / updates)
    h = hashlib.sha256()
    for r in runs:
        for p in r.agent.parameters():
            h.update(p.detach().contiguous().numpy().tobytes())
    digest = h.hexdigest()

    # second phase: the same updates with a timer around each product (sac_fused's module-level torch)
    spent = [0.0]

    def timed(fn):
        def wrapper(*a, **kw):
            t0 = time.perf_counter()
            try:
                return fn(*a, **kw)
            finally:
                spent[0] += time.perf_counter() - t0
        return wrapper

    proxy = type(sys)("torch_proxy")
    proxy.__dict__.update({k: getattr(torch, k) for k in dir(torch) if not k.startswith("__")})
    for name in PRODUCTS:
        setattr(proxy, name, timed(getattr(torch, name)))
    sf.torch = proxy
    products = []
    for _ in range(chunks):
        spent[0] = 0.0
        rounds(updates)
        products.append(spent[0] / updates)
    med = lambda xs: 1e3 * statistics.median(xs)  # noqa: E731
    out = {"pack": pack, "total_ms": med(total), "cpu_ms": med(cpu), "products_ms": med(products),
           "chunks_total_ms": [1e3 * x for x in total], "chunks_products_ms": [1e3 * x for x in products],
           "digest": digest, "package": str(Path(maniskill_dualher.__file__).resolve().parent),
           "torch_threads": torch.get_num_threads(), "torch": torch.__version__,
           "matmul_precision": cfg.sac.matmul_precision}
    out["overhead_ms"] = out["total_ms"] - out["products_ms"]
    return out


# --------------------------------------------------------------------------- the parent
def _run_worker(tree: Path, a, pack: int, precision: str = "", compiled: bool = False) -> dict:
    env = dict(os.environ, PYTHONPATH=str(tree), OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", "--pack", str(pack), "--updates",
           str(a.updates), "--chunks", str(a.chunks), "--warmup", str(a.warmup)] + (
               ["--precision", precision] if precision else []) + (["--compile"] if compiled else [])
    r = subprocess.run(cmd, cwd=tree, env=env, capture_output=True, text=True)
    if r.returncode != 0:
        raise RuntimeError(f"worker in {tree} (pack {pack}) failed (exit {r.returncode}): "
                           f"{r.stderr.strip().splitlines()[-1:]}")
    res = json.loads(r.stdout.strip().splitlines()[-1])
    if not Path(res["package"]).is_relative_to(tree):
        raise RuntimeError(f"worker for {tree} imported maniskill_dualher from {res['package']}")
    return res


def _ints(text: str, name: str):
    try:
        vals = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        vals = []
    if not vals or min(vals) < 1:
        raise ValueError(f"--{name} must be positive integers separated by commas, got {text!r}")
    return vals


def summarize(results: list, sides: str, packs: list) -> dict:
    """Per side and pack: each quantity's median over processes with [min, max]; per pack the ratios B / A of
    the medians and of each adjacent A/B pair (the order they ran)."""
    out = {}
    for s in packs:
        row = {}
        for side in sides:
            mine = [r for r in results if r["side"] == side and r["pack"] == s]
            row[side] = {q: {"median": statistics.median(r[q] for r in mine), "min": min(r[q] for r in mine),
                             "max": max(r[q] for r in mine)} for q in QUANTITIES}
        if len(sides) == 2:
            seq = [r for r in results if r["pack"] == s]
            row["ratio_B_over_A"] = {q: row["B"][q]["median"] / row["A"][q]["median"] for q in QUANTITIES}
            row["pair_ratios_total"] = [round((y if x["side"] == "A" else x)["total_ms"]
                                              / (x if x["side"] == "A" else y)["total_ms"], 3)
                                        for x, y in zip(seq[::2], seq[1::2])]
        out[str(s)] = row
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--base", help="a tree of the base commit (side B), e.g. a clone checked out there")
    p.add_argument("--packs", default="1,2,8", help="pack sizes S (default 1,2,8)")
    p.add_argument("--reps", type=int, default=5, help="processes per side and pack size (default 5)")
    p.add_argument("--updates", type=int, default=200, help="updates per timed chunk (default 200)")
    p.add_argument("--chunks", type=int, default=5, help="timed chunks per process (default 5)")
    p.add_argument("--warmup", type=int, default=50, help="untimed updates first (default 50)")
    p.add_argument("--precision-b", help="side B: this tree with sac.matmul_precision set to this (e.g. bf16)")
    p.add_argument("--compile-b", action="store_true", help="side B: this tree with sac.compile (torch.compile)")
    p.add_argument("--json", help="write the raw results here")
    p.add_argument("--precision", default="", help=argparse.SUPPRESS)
    p.add_argument("--compile", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    p.add_argument("--pack", type=int, default=1, help=argparse.SUPPRESS)
    a = p.parse_args(argv)
    if a.worker:
        print(json.dumps(worker(a.pack, a.updates, a.chunks, a.warmup, a.precision, a.compile)))
        return 0
    try:
        packs = _ints(a.packs, "packs")
        for name in ("reps", "updates", "chunks"):
            if getattr(a, name) < 1:
                raise ValueError(f"--{name} must be >= 1, got {getattr(a, name)}")
        if a.warmup < 0:
            raise ValueError(f"--warmup must be >= 0, got {a.warmup}")
        base = None
        if a.precision_b is not None:
            sys.path.insert(0, str(REPO))
            from maniskill_dualher.config import MATMUL_PRECISIONS
            if a.base is not None or a.precision_b not in MATMUL_PRECISIONS:
                raise ValueError(f"--precision-b must be one of {', '.join(MATMUL_PRECISIONS)} and not beside "
                                 f"--base, got {a.precision_b!r}")
        if a.compile_b and (a.base is not None or a.precision_b is not None):
            raise ValueError("--compile-b compares this tree with itself: not beside --base or --precision-b")
        if a.base is not None:
            base = Path(a.base).resolve()
            if not (base / "maniskill_dualher" / "sac_fused.py").is_file():
                raise ValueError(f"--base {a.base!r} is not a tree of this project")
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2

    sys.path.insert(0, str(REPO))
    from maniskill_dualher.provenance import cpu_info, git_state, machine_label, machine_name
    variant_b = bool(a.precision_b or a.compile_b)  # side B is this tree with another setting
    trees = {"A": REPO} if base is None and not variant_b else {"A": REPO, "B": base or REPO}
    precisions = {"A": "", "B": a.precision_b or ""}
    compiles = {"A": False, "B": a.compile_b}
    sides = "".join(trees)
    commits = {k: git_state(t) for k, t in trees.items()}
    load = " ".join(Path("/proc/loadavg").read_text().split()[:3]) if Path("/proc/loadavg").exists() else "?"
    cpu = cpu_info()
    print(f"machine: {machine_name(cpu)}, {machine_label(cpu)}; load before: {load}")
    for k, t in trees.items():
        c = commits[k]
        print(f"{k} = {t} ({c['commit_short']}{'+dirty' if c['dirty'] else ''})")
    print(f"packs {packs}; {a.reps} processes per side and pack; {a.chunks} chunks of {a.updates} updates after "
          f"{a.warmup} warm-up updates")
    results = []
    for rep in range(a.reps):
        order = sides if rep % 2 == 0 else sides[::-1]
        for s in packs:
            for side in order:
                r = _run_worker(trees[side], a, s, precisions[side], compiles[side])
                r.update(side=side, rep=rep)
                results.append(r)
                print(f"  rep {rep} S={s} {side}: total {r['total_ms']:.3f} ms (cpu {r['cpu_ms']:.3f}), products "
                      f"{r['products_ms']:.3f}, overhead {r['overhead_ms']:.3f}", flush=True)
    summary = summarize(results, sides, packs)
    identical = {str(s): len({r["digest"] for r in results if r["pack"] == s}) == 1 for s in packs}
    print("\nms per update of the pack, median [min, max] over processes:")
    print("S  side  total                    overhead                 products")
    for s in packs:
        row = summary[str(s)]
        for side in sides:
            f = lambda q: f"{row[side][q]['median']:7.3f} [{row[side][q]['min']:.3f}, {row[side][q]['max']:.3f}]"  # noqa: E731
            print(f"{s:<2} {side}     {f('total_ms')}  {f('overhead_ms')}  {f('products_ms')}")
        if len(sides) == 2:
            r = row["ratio_B_over_A"]
            print(f"   B/A   total x{r['total_ms']:.3f} (pairs {', '.join(f'x{v:.2f}' for v in row['pair_ratios_total'])})"
                  f", overhead x{r['overhead_ms']:.3f}; weights identical on every process: {identical[str(s)]}")
    if a.json:
        from maniskill_dualher.fileio import atomic_write_text
        doc = {"command": " ".join(["bench/update_overhead.py"] + (sys.argv[1:] if argv is None else list(argv))),
               "machine": machine_name(cpu), "cpu": machine_label(cpu), "cpu_info": cpu, "load_before": load,
               "trees": {k: str(t) for k, t in trees.items()}, "commits": commits, "packs": packs,
               "precision_b": a.precision_b, "compile_b": a.compile_b,
               "reps": a.reps, "updates": a.updates, "chunks": a.chunks, "warmup": a.warmup,
               "results": results, "summary": summary, "weights_identical": identical}
        atomic_write_text(Path(a.json), json.dumps(doc, indent=1) + "\n")
    return 0 if variant_b or all(identical.values()) else 1


if __name__ == "__main__":
    sys.exit(main())
