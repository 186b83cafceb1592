"""Training-loop speed: env steps/s of a full SAC loop (1 gradient update per env step, batch 256,
256x256 networks, after a warm-up) for our ``sac_her_per`` on ReachTarget-v1 beside two peers on the same
task and settings, in one process: Stable-Baselines3's SAC + HerReplayBuffer (future, n_sampled_goal=4) and
SBX's (JAX; PyPI ``sbx-rl``, optional: skipped with one line if not importable) SAC with the same SB3
HerReplayBuffer; plus the per-update cost (ms) of each, and of ours for every method (sac, sac_her_per,
dual_buffer) x SAC variant (paper, modern). Peers: lr 3e-4, tau 0.005, gamma 0.99 (SB3's defaults, also
SBX's), buffer 1e6, learning_starts 1000, train_freq 1, gradient_steps 1.

Our contenders. (1) Ours as configured by default: the fused update (hand-written gradients,
maniskill_dualher/sac_fused.py; autograd's values to float rounding) in strict fp32 ("highest"). (2) Ours at
its fastest settings: the fused update with bf16 inputs to the hidden-to-hidden products
(``matmul_precision="bf16"``, learning-checked in tests/test_sac_fused.py) under ``torch.compile``
(``SACConfig.compile``; compiled during the untimed warm-up). (3) Control: the autograd update at "medium",
this project's loop before the fused update. SB3 runs as users get it ("highest", torch's default) and, as a
control, with torch's "medium" switch set around its calls. SBX runs as users get it (JAX, fp32 on CPU).

    python bench/train_speed.py [--steps 2000] [--threads 1] [--cores 0|1] [--chunk 500] [--updates 300] [--no-sbx]
    python bench/train_speed.py --profile [--variant paper] [--updates 200]   # where one SAC.update goes

Method. Each contender warms up untimed (``learning_starts`` = 1000 random steps, then 100 learning steps;
for SBX that includes the JIT compilation). Then the timed env steps are run in alternating chunks (ours
paper, ours modern, SB3, SBX, ours paper, ...) so the contenders share the shared machine's load. Ours is
our real loop: ``train.run_one(trainer, stop_at=...)`` (evaluation and checkpoints pushed beyond the run; the
stop-checkpoint is replaced by a time stamp, so a chunk is timed from the call to the end of its last
episode). SB3 and SBX are ``model.learn(chunk, reset_num_timesteps=False)``. Threads: torch uses
``torch.set_num_threads(--threads)``; OpenMP/MKL get ``--threads`` and, with ``--threads 1``, JAX gets one
thread (``XLA_FLAGS``), set before anything loads (bench/_peers.py). Episodes are 50 steps, successes do not
end them (all). The matmul-floor section covers the torch contenders only (it counts FLOPs with torch's
profiler).
"""
from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile
import time
import warnings

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
warnings.filterwarnings("ignore")

# first: pins OpenMP/MKL threads to --threads (default 1) and JAX to one thread, before numpy/torch/jax load
from _peers import (GoalDictEnv, cpu_name, lib_version, loadavg, make_peer_sac, sbx_missing,  # noqa: E402
                    thread_info)

import numpy as np  # noqa: E402
import torch  # noqa: E402

ENV_ID = "ReachTarget-v1"
EP_LEN = 50
LEARNING_STARTS = 1000
LEARN_WARMUP = 100          # learning steps after learning_starts, untimed
CAPACITY = 1_000_000
ENV_KW = dict(sim_backend="physx_cpu", render_backend="none", obs_mode="state",
              control_mode="pd_joint_delta_pos", reward_mode="sparse", max_episode_steps=EP_LEN)


# --------------------------------------------------------------------------- ours
def our_config(method: str, variant: str, threads: int, seed: int = 0, **sac_kw):
    import dataclasses
    from maniskill_dualher.config import ReplayConfig, RunConfig, SACConfig
    extra = {}
    if "terminate_on_success" in {f.name for f in dataclasses.fields(RunConfig)}:
        extra["terminate_on_success"] = False  # fixed 50-step episodes, as the peers' here
    return RunConfig(
        env_id=ENV_ID, method=method, seed=seed, total_steps=10**9, max_episode_steps=EP_LEN,
        control_mode=ENV_KW["control_mode"], sim_backend=ENV_KW["sim_backend"], reward_mode="sparse",
        eval_every=10**9, checkpoint_every=10**9, torch_threads=threads, **extra,
        sac=SACConfig(variant=variant, batch_size=256, hidden=(256, 256), updates_per_step=1.0,
                      random_steps=LEARNING_STARTS, learning_starts=LEARNING_STARTS, **sac_kw),
        replay=ReplayConfig(capacity=CAPACITY, her_strategy="future", her_k=4,
                            solver_demos=5 if method == "dual_buffer" else 0))


class Ours:
    """Our Trainer, driven in time slices with run(stop_at=...)."""

    def __init__(self, method: str, variant: str, threads: int, tmp: str, impl: str = "fused",
                 precision: str = "highest", compile: bool = False):
        from maniskill_dualher.train import Trainer
        self.precision = precision
        label = f"{variant}, {impl}, {precision}" + (", compiled" if compile else "")
        self.name = f"ours {method} ({label})"
        self.threads = threads
        out = os.path.join(tmp, f"{method}_{label}".replace(", ", "_"))
        cfg = our_config(method, variant, threads, update_impl=impl, matmul_precision=precision, compile=compile)
        self.tr = Trainer(cfg, out, show_progress=False)
        self._stop_t = None

        def stamp(*a, **k):  # replaces the stop-checkpoint: the chunk ends when its last episode is stored
            self._stop_t = time.perf_counter()
        self.tr.save_checkpoint = stamp

    @property
    def steps(self) -> int:
        return self.tr.env_steps

    def run(self, n: int) -> float:
        """Run >= n more env steps (whole episodes); returns seconds."""
        torch.set_num_threads(self.threads)
        target = self.tr.env_steps + n
        t0 = time.perf_counter()
        self._stop_t = None
        from maniskill_dualher.train import run_one
        run_one(self.tr, stop_at=target)
        assert self._stop_t is not None and self.tr.env_steps >= target
        return self._stop_t - t0

    def warmup(self) -> float:
        """Random steps up to learning_starts (timed but for the last episode, reported as the no-update speed;
        our loop makes its first update, and with ``compile`` compiles it, as that episode ends), then
        learning steps."""
        dt = self.run(LEARNING_STARTS - EP_LEN)
        s0 = self.steps
        self.run(EP_LEN + LEARN_WARMUP)
        assert self.tr.updates > 0, "no gradient updates after warm-up"
        return s0 / dt

    def update_fns(self):
        tr = self.tr

        def full():  # exactly the loop's update: sample + SAC.update + priority write-back
            batch, actor_batch, log_now = tr.sample()
            tr.learn(batch, *tr.agent.update(batch, actor_batch, want_logs=log_now), log_now)
        batch = tr.method.sample(tr.cfg.sac.batch_size)

        def sac_only():
            tr.agent.update(batch)
        return full, sac_only

    def close(self):
        self.tr.env.close()


# --------------------------------------------------------------------------- SB3
# same settings for both peers (SB3's SAC defaults for lr, tau, gamma; SBX has the same defaults)
PEER_HP = dict(net_arch=[256, 256], learning_rate=3e-4, tau=0.005, gamma=0.99, batch_size=256,
               buffer_size=CAPACITY, learning_starts=LEARNING_STARTS, n_sampled_goal=4, train_freq=1,
               gradient_steps=1)


class Peer:
    """A peer SAC + SB3's HerReplayBuffer (future, 4 goals) on the same task and settings, driven with
    ``model.learn(n, reset_num_timesteps=False)``."""

    lib = "?"

    def __init__(self, threads: int, seed: int = 0):
        self.threads = threads
        torch.set_num_threads(threads)
        self.env = GoalDictEnv(ENV_ID, EP_LEN, control_mode=ENV_KW["control_mode"], reward_mode="sparse")
        self.model = make_peer_sac(self.lib, self.env, seed, **PEER_HP)

    def precision(self):
        return contextlib.nullcontext()

    @property
    def steps(self) -> int:
        return self.model.num_timesteps

    def run(self, n: int) -> float:
        torch.set_num_threads(self.threads)
        t0 = time.perf_counter()
        with self.precision():
            self.model.learn(total_timesteps=n, reset_num_timesteps=False, progress_bar=False)
        return time.perf_counter() - t0

    def warmup(self) -> float:
        dt = self.run(LEARNING_STARTS)
        s0 = self.steps
        self.run(LEARN_WARMUP)  # SBX: includes the JIT compilation of its update
        assert self.model._n_updates > 0, f"{self.name} made no gradient updates after warm-up"
        return s0 / dt

    def update_fns(self):
        m = self.model

        def full():  # the library's train step: HER sample (relabel on the fly) + SAC update
            with self.precision():
                m.train(gradient_steps=1, batch_size=256)

        def sample_only():
            m.replay_buffer.sample(256, env=m._vec_normalize_env)
        return full, sample_only

    def close(self):
        self.model.get_env().close()


class SB3(Peer):
    lib = "sb3"

    def __init__(self, threads: int, seed: int = 0, precision: str = "highest"):
        from maniskill_dualher.sac import matmul_precision
        self.name = f"SB3 SAC + HER ({precision})"
        self._precision = precision
        self._matmul_precision = matmul_precision
        super().__init__(threads, seed)

    def precision(self):
        return self._matmul_precision(self._precision)


class SBX(Peer):
    """SBX (JAX; PyPI sbx-rl) SAC with SB3's HerReplayBuffer. Its ``train`` ends in ``.item()`` on the
    losses, so a timed call includes the device work (no async dispatch left over)."""
    lib = "sbx"
    name = "SBX SAC + HER (JAX)"


# --------------------------------------------------------------------------- timing helpers
def interleaved(fns: dict, iters: int, rounds: int = 10, warmup: int = 10) -> dict:
    """Median/mean ms per call, contenders alternating in rounds (shared machine)."""
    for f in fns.values():
        for _ in range(warmup):
            f()
    times = {k: [] for k in fns}
    per = max(1, iters // rounds)
    for _ in range(rounds):
        for k, f in fns.items():
            for _ in range(per):
                t0 = time.perf_counter()
                f()
                times[k].append(time.perf_counter() - t0)
    return {k: (1e3 * float(np.median(v)), 1e3 * float(np.mean(v))) for k, v in times.items()}


@contextlib.contextmanager
def quiet_stderr():
    """Silence the profiler's native start/stop lines (written to fd 2 by C++, not through Python)."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 2)
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def matmul_flops(fn) -> float:
    """Matmul FLOPs of one call of ``fn`` (torch profiler's count: mm, addmm, bmm, baddbmm)."""
    from torch.profiler import ProfilerActivity, profile as tprofile
    with quiet_stderr(), tprofile(activities=[ProfilerActivity.CPU], with_flops=True) as prof:
        fn()
    return float(sum(e.flops for e in prof.key_averages() if e.flops and "mm" in e.key))


def matmul_rate(precision: str, n: int = 256, iters: int = 300) -> float:
    """This CPU's matmul throughput (GFLOP/s) on the update's dominant shape, (n x n) @ (n x n): fp32 under
    torch's ``precision`` setting, or bfloat16 inputs for "bf16" (the rate of the bf16 contender's hidden layers;
    its other products run at the fp32 rate, so its floor from this rate is a lower bound)."""
    from maniskill_dualher.sac import matmul_precision
    dtype = torch.bfloat16 if precision == "bf16" else torch.float32
    a, b = torch.randn(n, n, dtype=dtype), torch.randn(n, n, dtype=dtype)
    with matmul_precision(precision):
        for _ in range(20):
            a @ b
        ts = []
        for _ in range(iters):
            t0 = time.perf_counter()
            a @ b
            ts.append(time.perf_counter() - t0)
    return 2 * n ** 3 / float(np.median(ts)) / 1e9


# --------------------------------------------------------------------------- main bench
def bench(args) -> None:
    torch.set_num_threads(args.threads)
    tmp = tempfile.mkdtemp(prefix="train_speed_")
    print(f"# train_speed: {ENV_ID}, {EP_LEN}-step episodes, batch 256, 256x256, 1 update/step, "
          f"warm-up {LEARNING_STARTS}+{LEARN_WARMUP} steps, timed {args.steps} steps each in chunks of {args.chunk}, "
          f"torch threads {args.threads}")
    print(f"# cpu: {cpu_name()}")
    print(f"# threads: {thread_info()}")
    print(f"# load average at start: {loadavg()}")

    # ours as configured by default (fused update, strict fp32), then the fastest settings (bf16 hidden
    # products + torch.compile); the control is the autograd update at "medium" (this project's loop before
    # the fused update)
    loop = [Ours("sac_her_per", v, args.threads, tmp) for v in args.variants]
    loop.append(Ours("sac_her_per", args.variants[-1], args.threads, tmp, precision="bf16", compile=True))
    if not args.skip_controls:
        loop.append(Ours("sac_her_per", args.variants[-1], args.threads, tmp, impl="autograd", precision="medium"))
    sb3 = [SB3(args.threads)] + ([] if args.skip_controls else [SB3(args.threads, precision="medium")])
    why = "--no-sbx" if args.no_sbx else sbx_missing()
    if why is None:
        sbx = [SBX(args.threads)]
        print(f"# peers: {lib_version('sb3')}; {lib_version('sbx')}")
    else:
        sbx = []
        print(f"# SBX skipped ({why}); pip install sbx-rl to add it")
    ours = list(loop)
    peers = sb3 + sbx
    loop += peers
    nou = {}
    for c in loop:
        nou[c.name] = c.warmup()

    elapsed = {c.name: 0.0 for c in loop}
    done = {c.name: 0 for c in loop}
    while min(done.values()) < args.steps:
        for c in loop:
            if done[c.name] >= args.steps:
                continue
            n = min(args.chunk, args.steps - done[c.name])
            n = max(EP_LEN, int(np.ceil(n / EP_LEN)) * EP_LEN)
            s0 = c.steps
            elapsed[c.name] += c.run(n)
            done[c.name] += c.steps - s0
    sps = {k: done[k] / elapsed[k] for k in done}
    print(f"# load average after the loop: {loadavg()}")

    # per-update cost: ours for every method x variant, SB3; reuse the loop's trainers
    upd = {}
    upd_contenders = {}
    for c in loop:
        full, part = c.update_fns()
        upd_contenders[c.name] = full
        upd_contenders[c.name + " #part"] = part
    extra = []
    if not args.skip_methods:
        for method in ("sac", "dual_buffer"):
            for v in args.variants:
                o = Ours(method, v, args.threads, tmp)
                o.warmup()
                o.close()  # the update needs no env
                full, part = o.update_fns()
                upd_contenders[o.name] = full
                upd_contenders[o.name + " #part"] = part
                extra.append(o)
    torch.set_num_threads(args.threads)
    upd = interleaved(upd_contenders, args.updates)
    print(f"# load average after the update bench: {loadavg()}")

    print()
    hdr = f"{'contender':34s} {'env steps/s':>11s} {'no-update steps/s':>17s} {'update ms (med/mean)':>21s} {'part ms (med)':>14s}"
    print(hdr)
    print("-" * len(hdr))
    names = [c.name for c in loop] + [o.name for o in extra]
    for n in names:
        s = f"{sps[n]:11.1f}" if n in sps else f"{'-':>11s}"
        w = f"{nou[n]:17.1f}" if n in nou else f"{'-':>17s}"
        u = upd[n]
        p = upd[n + " #part"]
        print(f"{n:34s} {s} {w} {u[0]:10.2f} / {u[1]:8.2f} {p[0]:14.2f}")
    print("  update ms = one whole update of the training loop (ours: sample + SAC.update + priority write-back; "
          "SB3/SBX: model.train(1) incl. HER sampling)")
    print("  part ms   = ours: SAC.update alone on a fixed batch; SB3/SBX: HerReplayBuffer.sample(256) alone")
    print(f"  timed env steps: " + ", ".join(f"{k}: {done[k]} in {elapsed[k]:.1f} s" for k in done))
    print()
    print("env steps/s, ours vs peers (" + ", ".join(f"{c.name} {sps[c.name]:.1f}" for c in peers) + ")")
    for b in peers:
        for c in ours:
            print(f"{c.name} / {b.name}, env steps/s: {sps[c.name] / sps[b.name]:.2f}x   "
                  f"(update cost {b.lib.upper()}/ours: {upd[b.name][0] / upd[c.name][0]:.2f}x)")
    torch_loop = [c for c in loop if c not in sbx]  # the matmul floor is counted by torch's profiler
    floors(torch_loop, sb3, sps, nou, upd, {c.name: c.update_fns()[0] for c in torch_loop})
    for c in loop:
        c.close()


def floors(loop, sb3, sps, nou, upd, full_fns) -> None:
    """How far each update is from this CPU's matmul floor, and what that allows for the speed ratio.

    An update cannot cost less than its matmul FLOPs at the CPU's matmul rate; an env step of the loop
    cannot cost less than that floor plus the loop's no-update step. So ours/SB3 in env steps/s is at most
    (SB3's measured step time) / (our floor + our no-update step time), whatever else is optimised."""
    print()
    print("matmul floor (FLOPs counted by torch's profiler; rate = this CPU's (256x256)@(256x256) matmul at the "
          "contender's precision)")
    hdr = f"{'contender':34s} {'GFLOP/update':>12s} {'GFLOP/s':>8s} {'floor ms':>9s} {'update ms':>10s} {'matmul share':>13s}"
    print(hdr)
    print("-" * len(hdr))
    rates = {}
    floor_ms = {}
    for c in loop:
        prec = c.precision if isinstance(getattr(c, "precision", None), str) else c._precision
        if prec not in rates:
            rates[prec] = matmul_rate(prec)
        gf = matmul_flops(full_fns[c.name]) / 1e9
        floor_ms[c.name] = 1e3 * gf / rates[prec]
        u = upd[c.name][0]
        print(f"{c.name:34s} {gf:12.3f} {rates[prec]:8.1f} {floor_ms[c.name]:9.2f} {u:10.2f} {100 * floor_ms[c.name] / u:12.0f}%")
    ours = [c for c in loop if c not in sb3]
    for b in sb3[:1]:
        for c in ours:
            ceiling = (1.0 / sps[b.name]) / (floor_ms[c.name] / 1e3 + 1.0 / nou[c.name])
            print(f"ceiling of {c.name} / {b.name} on this CPU (update = pure matmul): {ceiling:.2f}x")


# --------------------------------------------------------------------------- profile
def profile(args) -> None:
    """Profile SAC.update alone on a fixed random batch (no replay, no env)."""
    from torch.profiler import ProfilerActivity, profile as tprofile
    from maniskill_dualher.config import SACConfig
    from maniskill_dualher.replay.base import Batch
    from maniskill_dualher.sac import SAC

    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    D, A, B = 43, 8, 256
    for variant in args.variants:
        agent = SAC(D, A, SACConfig(variant=variant, batch_size=B))
        g = torch.Generator().manual_seed(1)
        batch = Batch(obs=torch.randn(B, D, generator=g), action=torch.rand(B, A, generator=g) * 2 - 1,
                      reward=(torch.rand(B, generator=g) < 0.1).float(), next_obs=torch.randn(B, D, generator=g),
                      done=torch.zeros(B))
        for _ in range(20):
            agent.update(batch)
        t0 = time.perf_counter()
        for _ in range(args.updates):
            agent.update(batch)
        ms = 1e3 * (time.perf_counter() - t0) / args.updates
        print(f"\n## SAC.update ({variant}): {ms:.2f} ms/update wall (threads {args.threads}, load {loadavg()})")
        with quiet_stderr(), tprofile(activities=[ProfilerActivity.CPU]) as prof:
            for _ in range(args.updates):
                agent.update(batch)
        ka = prof.key_averages()
        rows = [(e.key, e.self_cpu_time_total, e.count) for e in ka]
        total = sum(r[1] for r in rows)
        cats = {"matmul (fwd+bwd)": 0.0, "elementwise/reduction": 0.0, "optimizer (Adam, zero_grad, lerp)": 0.0,
                "copies/views/autograd glue": 0.0}
        mm = {"mm", "addmm", "bmm", "baddbmm", "matmul", "linear"}
        glue = {"copy_", "_to_copy", "to", "view", "expand", "unsqueeze", "squeeze", "select", "slice", "as_strided",
                "detach", "detach_", "empty", "empty_like", "empty_strided", "transpose", "t", "chunk", "split",
                "permute", "reshape", "alias", "contiguous", "clone", "resolve_conj", "resolve_neg", "unbind",
                "_unsafe_view", "expand_as", "fill_", "zeros", "zeros_like", "ones_like", "lift_fresh", "result_type"}
        for k, t, _ in rows:
            lk = k.lower()
            op = lk.split("::")[-1] if lk.startswith("aten::") else None
            if "adam" in lk or "zero_grad" in lk or (op or "").startswith("_foreach"):
                cats["optimizer (Adam, zero_grad, lerp)"] += t
            elif op in mm:
                cats["matmul (fwd+bwd)"] += t
            elif op is not None and op not in glue:
                cats["elementwise/reduction"] += t
            else:
                cats["copies/views/autograd glue"] += t
        per = args.updates
        print(f"profiled self CPU time: {total / per / 1e3:.2f} ms/update (profiler overhead included)")
        for k, v in cats.items():
            print(f"  {k:34s} {v / per / 1e3:6.2f} ms  {100 * v / max(total, 1):5.1f}%")
        print(ka.table(sort_by="self_cpu_time_total", row_limit=args.rows))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--steps", type=int, default=2000, help="timed env steps per loop contender (K)")
    p.add_argument("--chunk", type=int, default=500, help="env steps per alternating chunk")
    p.add_argument("--threads", type=int, default=1, help="torch threads (both contenders)")
    p.add_argument("--cores", type=int, default=0,
                   help="pin the process to this many CPUs (0 = all; 1 = one core for every contender, SBX's "
                        "JAX runtime thread included)")
    p.add_argument("--updates", type=int, default=300, help="updates timed per contender in the update bench")
    p.add_argument("--variant", choices=("paper", "modern", "both"), default="both", help="our SAC variant(s)")
    p.add_argument("--skip-methods", action="store_true", help="update bench: skip sac and dual_buffer")
    p.add_argument("--skip-controls", action="store_true",
                   help="skip the precision controls (ours at 'highest', SB3 at 'medium')")
    p.add_argument("--no-sbx", action="store_true", help="leave out the SBX contender")
    p.add_argument("--profile", action="store_true", help="profile SAC.update alone and exit")
    p.add_argument("--rows", type=int, default=25, help="--profile: rows of the op table")
    args = p.parse_args(argv)
    args.variants = ["paper", "modern"] if args.variant == "both" else [args.variant]
    if args.profile:
        profile(args)
    else:
        bench(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
