"""What a sweep costs before it starts: env steps, gradient updates, and wall time on this machine.

Updates follow each run's schedule: ``update_schedule="step"`` buys ``updates_per_step`` per env step
after ``learning_starts``; ``"episode"`` (Algorithm 1) buys ``updates_per_episode`` per finished
episode: one per ``max_episode_steps`` env steps if no episode ends early, up to one per env step if
every episode ends at once on success. The estimate gives that range.

Time, per run: one SAC update of the run's network and batch size is timed here (a few dozen updates on
random data, one torch thread, as the sweep's workers run; in CPU time, as the workers start beside it)
plus a replay-sampling overhead; every env step (training and evaluation, evaluation episodes taken at full
length) costs an env step plus acting; and each run pays its setup (env construction) before its loop. Each
worker process pays its imports once. Local wall time = the runs' core-seconds / the workers + one worker's
imports. The constants are measured (sources beside each); ``bench/results/eta_calibration_cpuB.json`` holds
the measured wall times they are checked against (tests/test_sweep.py). The report built at the end is not
counted. On CPU simulation the workers share the machine's cores; a Ray cluster's cost is the core-hours.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Dict, List, Optional, Tuple

# One env step of our tasks, one thread: 0.87 ms on CPU B (CloseMicrowave, facts 2026-12-03), 0.98 ms on CPU A
# (py-spy of a quick run, facts 2026-12-02), 0.94-1.04 ms on CPU C (bench/env_speed.py: 961-1063 steps/s).
ENV_STEP_S = 0.93e-3
# Acting (the actor's forward pass and the step's glue): 3.5% of a quick run's loop, ~0.14 ms per env step
# (py-spy, CPU A, facts 2026-12-02).
ACT_S = 0.14e-3
SAMPLE_OVERHEAD_S = 0.6e-3    # prioritized sample 256 + priority write-back (bench/replay_speed.py: 0.28 ms;
#                               py-spy of a quick run: 0.33 ms per update) + HER relabelling and glue
# Before a process's first loop: ~12 s, of which ~10 s imports (py-spy, CPU A, facts 2026-12-02). A pool worker
# imports once; each run builds its envs (the other ~2 s).
WORKER_START_S = 10.0
RUN_START_S = 2.0


@dataclass
class Cost:
    runs: int
    env_steps: int
    updates_low: int
    updates_high: int
    core_seconds_low: float
    core_seconds_high: float


def run_updates(cfg) -> Tuple[int, int]:
    """(fewest, most) gradient updates one run makes under its update schedule."""
    s = cfg.sac
    learn = max(0, cfg.total_steps - s.learning_starts)
    if s.update_schedule == "step":
        n = int(learn * s.updates_per_step)
        return n, n
    max_len = cfg.max_episode_steps or 150
    return int(learn / max_len * s.updates_per_episode), int(learn * s.updates_per_episode)


_UPDATE_S: Dict[tuple, float] = {}


def update_seconds(cfg, obs_dim: int = 43, act_dim: int = 8, iters: int = 30, pack: int = 1) -> float:
    """Seconds per SAC update at this config's network and batch size, timed here on one thread; with
    ``pack`` > 1, one agent's share of a batched update of that many agents (``pack.py``)."""
    s = cfg.sac
    from ..pack import pack_key
    pack = pack if pack_key(cfg) is not None else 1
    key = (tuple(s.hidden), s.batch_size, s.variant, obs_dim, act_dim, pack)
    if key in _UPDATE_S:
        return _UPDATE_S[key]
    import torch

    from ..replay.base import Batch
    from ..sac import SAC
    from ..sac_fused import FusedUpdate

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        agents = [SAC(obs_dim, act_dim, s, device="cpu", generator=g, init_generator=g)
                  for g in (torch.Generator().manual_seed(k) for k in range(pack))]  # the global one untouched
        B = s.batch_size
        g = torch.Generator().manual_seed(0)
        batch = Batch(obs=torch.randn(B, obs_dim, generator=g), action=torch.rand(B, act_dim, generator=g) * 2 - 1,
                      reward=torch.zeros(B), next_obs=torch.randn(B, obs_dim, generator=g), done=torch.zeros(B))
        if pack == 1:
            step = lambda: agents[0].update(batch)  # noqa: E731
        else:
            fused = FusedUpdate(agents)
            step = lambda: fused.step_pack([batch] * pack, [None] * pack)  # noqa: E731
        for _ in range(5):
            step()
        # this thread's CPU time: a sweep's workers start beside it (backends.LocalBackend.start)
        t0 = time.thread_time()
        for _ in range(iters):
            step()
        _UPDATE_S[key] = (time.thread_time() - t0) / iters / pack
    finally:
        torch.set_num_threads(threads)
    return _UPDATE_S[key]


def grid_cost(cfgs: List, pack: int = 1, update_s: Optional[Callable] = None) -> Cost:
    """The cost of these runs, updates timed as a worker packing up to ``pack`` runs makes them
    (``update_s(cfg, pack)``: seconds per update, default timed here by ``update_seconds``)."""
    timed = update_s or (lambda c, p: update_seconds(c, pack=p))
    steps = sum(c.total_steps for c in cfgs)
    lo = hi = 0
    sec_lo = sec_hi = 0.0
    for c in cfgs:
        u_lo, u_hi = run_updates(c)
        per_update = timed(c, min(pack, len(cfgs))) + SAMPLE_OVERHEAD_S
        evals = (c.total_steps // c.eval_every + 1) * c.eval_episodes * (c.max_episode_steps or 150)
        fixed = RUN_START_S + (c.total_steps + evals) * (ENV_STEP_S + ACT_S)
        lo, hi = lo + u_lo, hi + u_hi
        sec_lo += fixed + u_lo * per_update
        sec_hi += fixed + u_hi * per_update
    return Cost(len(cfgs), steps, lo, hi, sec_lo, sec_hi)


def local_wall_seconds(core_seconds: float, runs: int, workers: int) -> float:
    """Wall time on this machine: the runs shared over the workers, each worker importing once in parallel."""
    return core_seconds / max(1, min(workers, runs)) + WORKER_START_S


def _dur(seconds: float) -> str:
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 3600:
        return f"{seconds / 60:.0f} min"
    if seconds < 3 * 86400:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 86400:.1f} days"


def describe(cost: Cost, workers: int) -> List[str]:
    upd = f"{cost.updates_low:,}" if cost.updates_low == cost.updates_high else \
        f"{cost.updates_low:,} to {cost.updates_high:,}"
    sec = (cost.core_seconds_low, cost.core_seconds_high)
    rng = (lambda f: f(sec[0]) if sec[0] == sec[1] else f"{f(sec[0])} to {f(sec[1])}")
    return [
        f"cost: {cost.env_steps:,} env steps, {upd} gradient updates",
        f"estimated time (update timed here, env steps at {1 / (ENV_STEP_S + ACT_S):.0f}/s, evaluation and "
        "startup included, the report not; an estimate, not a measurement):",
        f"  one CPU core: {rng(_dur)}; this machine with {workers} workers: "
        f"{rng(lambda s: _dur(local_wall_seconds(s, cost.runs, workers)))}",
        f"  a Ray cluster: {rng(lambda s: f'{s / 3600:,.0f} core-hours')} (wall time = that / its CPUs)",
    ]
