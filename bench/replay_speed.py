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


def run_interleaved(steps, iters, rounds=20, warmup=50):
    """Alternate the contenders in rounds so they share the (busy, shared) machine's conditions."""
    for step in steps.values():
        for _ in range(warmup):
            step()
    times = {k: [] for k in steps}
    per = max(1, iters // rounds)
    for _ in range(rounds):
        for k, step in steps.items():
            for _ in range(per):
                t0 = time.perf_counter()
                step()
                times[k].append(time.perf_counter() - t0)
    return {k: (1e6 * np.median(v), 1e6 * np.mean(v)) for k, v in times.items()}


def ours_steps(rows, size):
    from maniskill_dualher.config import ReplayConfig
    from maniskill_dualher.replay.buffer import make_buffer

    buf = make_buffer(size, D, A, prioritized=True, replay_cfg=ReplayConfig())
    buf.add(rows)
    rng = np.random.default_rng(0)
    td_rng = np.random.default_rng(1)
    buf.update_priorities(np.arange(size), td_rng.random(size))
    s = buf.sampler

    def arrays():
        s.is_weights = False
        _, idx, _ = buf.sample_arrays(B, rng)
        buf.update_priorities(idx, td_rng.random(B))

    def batch():
        s.is_weights = False
        b = buf.sample(B, rng)
        buf.update_priorities(b, td_rng.random(B))

    def batch_w():
        s.is_weights = True
        b = buf.sample(B, rng)
        buf.update_priorities(b, td_rng.random(B))
    return {"ours (numpy arrays)": arrays, "ours (torch Batch)": batch, "ours (torch Batch + IS weights)": batch_w}


def cpprb_step(rows, size):
    import cpprb

    env_dict = {"obs": {"shape": D}, "act": {"shape": A}, "rew": {}, "next_obs": {"shape": D}, "done": {}}
    rb = cpprb.PrioritizedReplayBuffer(size, env_dict, alpha=0.5)
    rb.add(obs=rows["obs"], act=rows["action"], rew=rows["reward"], next_obs=rows["next_obs"], done=rows["done"])
    td_rng = np.random.default_rng(1)
    rb.update_priorities(np.arange(size), td_rng.random(size) + 1e-6)

    def step():  # cpprb always computes IS weights
        s = rb.sample(B, beta=0.4)
        rb.update_priorities(s["indexes"], td_rng.random(B) + 1e-6)
    return step


def torchrl_step(size):
    from torchrl.data import PrioritizedSampler  # raises here: SumSegmentTreeFp32 is not available
    import torch
    from tensordict import TensorDict
    from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer

    rb = TensorDictReplayBuffer(storage=LazyTensorStorage(size),
                                sampler=PrioritizedSampler(size, alpha=0.5, beta=0.4), batch_size=B)
    rb.extend(TensorDict({"obs": torch.rand(size, D), "action": torch.rand(size, A), "reward": torch.rand(size),
                          "next_obs": torch.rand(size, D), "done": torch.zeros(size)}, batch_size=[size]))

    def step():
        s = rb.sample()
        s.set("td_error", torch.rand(B))
        rb.update_tensordict_priority(s)
    return step


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--size", type=int, default=1_000_000)
    p.add_argument("--iters", type=int, default=2000)
    a = p.parse_args()
    rows = fill_rows(a.size, np.random.default_rng(0))
    print(f"full buffer of {a.size:,} transitions (obs {D}, action {A}), batch {B}; sample + priority update, "
          f"median (mean) us per op, ~{a.iters} ops each, interleaved")
    steps = {}
    try:
        steps["cpprb"] = cpprb_step(rows, a.size)
    except ImportError as e:
        print(f"cpprb                            unavailable ({e})")
    steps.update(ours_steps(rows, a.size))
    try:
        steps["torchrl PrioritizedSampler"] = torchrl_step(a.size)
    except Exception as e:  # noqa: BLE001 - any failure to load/build means unavailable here
        print(f"torchrl PrioritizedSampler       unavailable ({type(e).__name__}: {str(e).splitlines()[0][:80]})")
    del rows
    results = run_interleaved(steps, a.iters)
    ref = results.get("cpprb")
    for label, (med, mean) in results.items():
        ratio = f"  {med / ref[0]:.2f}x cpprb" if ref else ""
        print(f"{label:32s} {med:8.1f} ({mean:.1f}) us{ratio}")


if __name__ == "__main__":
    main()
