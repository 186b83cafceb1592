"""What a sweep costs before it starts: env steps, gradient updates, and wall time on this machine.

Updates follow each run's schedule: ``update_schedule="step"`` buys ``updates_per_step`` per env step
after ``learning_starts``; ``"episode"`` (Algorithm 1) buys ``updates_per_episode`` per finished
episode: one per ``max_episode_steps`` env steps if no episode ends early, up to one per env step if
every episode ends at once on success. The estimate gives that range.

Time: one SAC update of the run's network and batch size is timed here (a few dozen updates on random
data, one torch thread, as the sweep's workers run), plus a replay-sampling and priority overhead, and
env steps cost ``ENV_STEP_S`` (``bench/env_speed.py`` on the AVX2 EPYC: ~1000 env steps/s for our tasks,
one process; evaluation steps included at the preset's evaluation rate). It is an estimate: on CPU
simulation the workers share the machine's cores, so the local wall time is the core-seconds divided
by the workers; a Ray cluster's cost is the core-hours.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Dict, List, Tuple

ENV_STEP_S = 1.0 / 1000.0     # bench/env_speed.py, AVX2 EPYC, our three tasks: 961-1063 env steps/s
SAMPLE_OVERHEAD_S = 0.6e-3    # prioritized sample 256 + priority write-back (bench/replay_speed.py: 0.28 ms) + glue


@dataclass
class Cost:
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
        t0 = time.perf_counter()
        for _ in range(iters):
            step()
        _UPDATE_S[key] = (time.perf_counter() - t0) / iters / pack
    finally:
        torch.set_num_threads(threads)
    return _UPDATE_S[key]


def grid_cost(cfgs: List, pack: int = 1) -> Cost:
    """The cost of these runs, updates timed as a worker packing up to ``pack`` runs makes them."""
    steps = sum(c.total_steps for c in cfgs)
    lo = hi = 0
    sec_lo = sec_hi = 0.0
    for c in cfgs:
        u_lo, u_hi = run_updates(c)
        per_update = update_seconds(c, pack=min(pack, len(cfgs))) + SAMPLE_OVERHEAD_S
        evals = (c.total_steps // c.eval_every + 1) * c.eval_episodes * (c.max_episode_steps or 150)
        env_s = (c.total_steps + evals) * ENV_STEP_S
        lo, hi = lo + u_lo, hi + u_hi
        sec_lo += env_s + u_lo * per_update
        sec_hi += env_s + u_hi * per_update
    return Cost(steps, lo, hi, sec_lo, sec_hi)


def _dur(seconds: float) -> str:
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
        f"estimated time (update timed here, env steps at {1 / ENV_STEP_S:.0f}/s, evaluation included; "
        "an estimate, not a measurement):",
        f"  one CPU core: {rng(_dur)}; this machine with {workers} workers: "
        f"{rng(lambda s: _dur(s / workers))}",
        f"  a Ray cluster: {rng(lambda s: f'{s / 3600:,.0f} core-hours')} (wall time = that / its CPUs)",
    ]
