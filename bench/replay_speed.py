"""Prioritized replay speed: one sample of 256 (incl. gathering the transition arrays) + one priority update,
from a full buffer of 10^6 transitions (obs 46, action 8). Ours vs cpprb (and TorchRL if it loads).

    OMP_NUM_THREADS=1 python bench/replay_speed.py [--size 1000000] [--iters 2000]
"""
from __future__ import annotations

import argparse
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

D, A, B = 46, 8, 256


def fill_rows(n, rng):
    return {"obs": rng.random((n, D), dtype=np.float32), "action": rng.random((n, A), dtype=np.float32),
            "reward": (rng.random(n) < 0.1).astype(np.float32),
            "next_obs": rng.random((n, D), dtype=np.float32), "done": np.zeros(n, np.float32)}


def timeit(step, iters, warmup=50):
    for _ in range(warmup):
        step()
    ts = np.empty(iters)
    for i in range(iters):
        t0 = time.perf_counter()
        step()
        ts[i] = time.perf_counter() - t0
    return 1e6 * np.median(ts), 1e6 * ts.mean()


def bench_ours(rows, size, iters, is_weights, to_torch):
    from maniskill_dualher.config import ReplayConfig
    from maniskill_dualher.replay.buffer import make_buffer

    cfg = ReplayConfig(is_weights=is_weights)
    buf = make_buffer(size, D, A, prioritized=True, replay_cfg=cfg)
    buf.add(rows)
    rng = np.random.default_rng(0)
    td_rng = np.random.default_rng(1)
    buf.update_priorities(np.arange(size), td_rng.random(size))

    if to_torch:
        def step():
            b = buf.sample(B, rng)
            buf.update_priorities(b, td_rng.random(B))
    else:
        def step():
            _, idx, _ = buf.sample_arrays(B, rng)
            buf.update_priorities(idx, td_rng.random(B))
    return timeit(step, iters)


def bench_cpprb(rows, size, iters):
    import cpprb

    env_dict = {"obs": {"shape": D}, "act": {"shape": A}, "rew": {}, "next_obs": {"shape": D}, "done": {}}
    rb = cpprb.PrioritizedReplayBuffer(size, env_dict, alpha=0.5)
    rb.add(obs=rows["obs"], act=rows["action"], rew=rows["reward"], next_obs=rows["next_obs"], done=rows["done"])
    td_rng = np.random.default_rng(1)
    rb.update_priorities(np.arange(size), td_rng.random(size) + 1e-6)

    def step():
        s = rb.sample(B, beta=0.4)
        rb.update_priorities(s["indexes"], td_rng.random(B) + 1e-6)
    return timeit(step, iters)


def bench_torchrl(size, iters):
    from torchrl.data import PrioritizedSampler  # noqa: F401  (raises here: SumSegmentTreeFp32 missing)
    import torch
    from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
    from tensordict import TensorDict

    rb = TensorDictReplayBuffer(storage=LazyTensorStorage(size),
                                sampler=PrioritizedSampler(size, alpha=0.5, beta=0.4), batch_size=B)
    rb.extend(TensorDict({"obs": torch.rand(size, D), "action": torch.rand(size, A), "reward": torch.rand(size),
                          "next_obs": torch.rand(size, D), "done": torch.zeros(size)}, batch_size=[size]))

    def step():
        s = rb.sample()
        s.set("td_error", torch.rand(B))
        rb.update_tensordict_priority(s)
    return timeit(step, iters)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--size", type=int, default=1_000_000)
    p.add_argument("--iters", type=int, default=2000)
    a = p.parse_args()
    rows = fill_rows(a.size, np.random.default_rng(0))
    print(f"full buffer of {a.size:,} transitions (obs {D}, action {A}), batch {B}; sample + priority update, "
          f"median (mean) us per op over {a.iters} ops")
    results = {}
    try:
        results["cpprb"] = bench_cpprb(rows, a.size, a.iters)
    except ImportError as e:
        print(f"cpprb                            unavailable ({e})")
    for label, w, tt in (("ours (numpy arrays)", False, False), ("ours (torch Batch)", False, True),
                         ("ours (torch Batch + IS weights)", True, True)):
        results[label] = bench_ours(rows, a.size, a.iters, w, tt)
    try:
        results["torchrl PrioritizedSampler"] = bench_torchrl(a.size, a.iters)
    except Exception as e:  # noqa: BLE001 - any failure to load/run means unavailable here
        print(f"torchrl PrioritizedSampler       unavailable ({type(e).__name__}: {str(e).splitlines()[0][:80]})")
    ref = results.get("cpprb")
    for label, (med, mean) in results.items():
        ratio = f"  {med / ref[0]:.2f}x cpprb" if ref else ""
        print(f"{label:32s} {med:8.1f} ({mean:.1f}) us{ratio}")


if __name__ == "__main__":
    main()
