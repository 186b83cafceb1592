"""What a sweep costs before it starts: env steps, gradient updates, and wall time on this machine.

Updates follow each run's schedule: ``update_schedule="step"`` buys ``updates_per_step`` per env step
after ``learning_starts``; ``"episode"`` (Algorithm 1) buys ``updates_per_episode`` per finished
episode: one per ``max_episode_steps`` env steps if no episode ends early, up to one per env step if
every episode ends at once on success. The estimate gives that range.

Time, per run: one SAC update of the run's network and batch size is timed here (a few dozen updates on
random data, one torch thread, as the sweep's workers run; in CPU time, as the workers start beside it)
plus a replay-sampling overhead; every env step (training and evaluation, evaluation episodes taken at full
length) costs an env step plus acting, also timed here (``env_step_seconds``: a few hundred steps of the run's
own env, acting through an untrained agent's bare actor as the training loop does; the constants below where the
env cannot be built here); and each run pays its setup (env construction) before its loop. Each
worker process pays its imports once. Local wall time = the runs' core-seconds / the workers + one worker's
imports. The constants are measured (sources beside each); ``bench/results/eta_calibration_cpuB.json`` holds
the measured wall times they are checked against (tests/test_sweep.py). The report built at the end is not
counted. On CPU simulation the workers share the machine's cores; a Ray cluster's cost is the core-hours.

Memory, per run: its replay at its end (each buffer min(capacity, the rows its env steps offer it: x (1 + her_k)
for R of the HER methods, x 1 for SAC's and for the dual buffer's E, an upper bound on its real reward-1 rows;
the estimate the dry run prints takes a method's ``replay_typical`` instead where lower: E one row per full-length
episode, as episodes end at their first success),
the rows of the earlier chain stages it carries counted in) x bytes per row (``replay_row_bytes``: the transition's
floats, the sum tree's, the method's own per-row arrays), its networks with their gradients and Adam moments
(``network_bytes``), and, while it starts from a replay, what of it is held twice: a carried parent's replay
whole (read from the file, then copied in); on a resume its own checkpoint's largest field per row plus the
rest of the row outside the transition (``replay.storage.consuming_loaded_state`` moves the fields in one at a
time; a full buffer's arrays become the storage, so only the rest of its row counts). A worker adds its process
(imports, env, episode arrays) once and ``RUN_BYTES`` per further run of its pack. ``plan_memory`` fits the sweep's workers x runs per worker into the
memory this machine has available (``available_memory``), packing fewer runs per worker, then using fewer workers,
or refusing when one run alone does not fit.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from typing import Callable, Dict, List, Optional, Sequence, Tuple

from ..config import ConfigError
from ..fileio import plural
from .protocol import takes_rows

# One env step of our tasks, one thread: 0.87 ms on CPU B (CloseMicrowave, facts 2026-12-03), 0.98 ms on CPU A
# (py-spy of a quick run, facts 2026-12-02), 0.94-1.04 ms on CPU C (bench/env_speed.py: 961-1063 steps/s). Used
# only where ``env_step_seconds`` cannot time the run's env here (and by the calibration of those machines).
ENV_STEP_S = 0.93e-3
# Acting (the actor's forward pass and the step's glue): 3.5% of a quick run's loop, ~0.14 ms per env step
# (py-spy, CPU A, facts 2026-12-02).
ACT_S = 0.14e-3
SAMPLE_OVERHEAD_S = 0.6e-3    # prioritized sample 256 + priority write-back (bench/replay_speed.py: 0.28 ms;
#                               py-spy of a quick run: 0.33 ms per update) + HER relabelling and glue
# Before a process's first loop: ~12 s, of which ~10 s imports (py-spy, CPU A, facts 2026-12-02); timed here by
# worker_start_seconds, WORKER_START_S only where that fails. A pool worker imports once; each run builds its
# envs (the other ~2 s there; timed here by run_start_seconds, RUN_START_S only where the env cannot be built).
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
    env_steps_per_s: float = 0.0  # the env-step rate (with acting) the estimate used, over these runs


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


_STEP_S: Dict[tuple, float] = {}
_START_S: Dict[tuple, float] = {}


def _env_key(cfg) -> tuple:
    return (cfg.env_id, cfg.control_mode, cfg.sim_backend, cfg.num_envs, cfg.reward_mode)


STEP_PROBE = 300  # env steps timed per env (after 20 untimed): ~0.1-0.3 s, beside ~2 s to build the env


def env_step_seconds(cfg, steps: int = STEP_PROBE) -> float:
    """Seconds per env step of this run's env with acting, timed here on one thread: the run's ``BatchEnv``
    stepped by an untrained agent's bare stochastic actor (the training loop's acting), episodes reset as they
    end. Cached per env; ``ENV_STEP_S + ACT_S`` (measured constants) where the env cannot be built here (a GPU
    backend without a GPU, a missing package)."""
    key = _env_key(cfg)
    if key in _STEP_S:
        return _STEP_S[key]
    try:
        import numpy as np
        import torch

        from .. import tasks  # noqa: F401  (registers our tasks)
        from ..envs import BatchEnv
        from ..sac import SAC
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        t_build = time.thread_time()
        env = BatchEnv(cfg)
        _START_S[key] = time.thread_time() - t_build
        try:
            agent = SAC(env.spec.input_dim, env.spec.act_dim, cfg.sac, device="cpu",
                        generator=torch.Generator().manual_seed(0), init_generator=torch.Generator().manual_seed(0))
            act = agent.stochastic_actor()
            flat = env.reset(0)

            def run(n):
                nonlocal flat
                for k in range(n):
                    flat, _, term, trunc, _ = env.step(act(env.policy_input(flat)))
                    done = np.asarray(term) | np.asarray(trunc)
                    if done.any():
                        idx = np.flatnonzero(done)
                        flat[idx] = env.reset_envs(idx, [k + 1 + int(i) for i in idx])
            run(20)
            t0 = time.thread_time()
            run(steps)
            _STEP_S[key] = (time.thread_time() - t0) / steps / cfg.num_envs
        finally:
            env.close()
            torch.set_num_threads(threads)
    except Exception:  # noqa: BLE001  (an estimate: fall back to the measured constants)
        _STEP_S[key], _START_S[key] = ENV_STEP_S + ACT_S, RUN_START_S
    return _STEP_S[key]


def run_start_seconds(cfg) -> float:
    """Seconds to build this run's env here (thread CPU time; timed by ``env_step_seconds``'s probe, which it
    runs if needed); ``RUN_START_S`` where the env cannot be built here."""
    env_step_seconds(cfg)
    return _START_S[_env_key(cfg)]


def grid_cost(cfgs: List, pack: int = 1, update_s: Optional[Callable] = None,
              step_s: Optional[Callable] = None, start_s: Optional[Callable] = None) -> Cost:
    """The cost of these runs, updates timed as a worker packing up to ``pack`` runs makes them
    (``update_s(cfg, pack)``: seconds per update, default timed here by ``update_seconds``; ``step_s(cfg)``:
    seconds per env step with acting, default timed here by ``env_step_seconds``; ``start_s(cfg)``: a run's setup
    before its loop, default its env's build timed here by ``run_start_seconds``)."""
    if update_s is None or step_s is None:
        start_worker_probe()  # overlaps the timings below (local_wall_seconds collects it)
    timed = update_s or (lambda c, p: update_seconds(c, pack=p))
    stepped = step_s or env_step_seconds
    started = start_s or run_start_seconds
    steps = sum(c.total_steps for c in cfgs)
    lo = hi = 0
    sec_lo = sec_hi = 0.0
    for c in cfgs:
        u_lo, u_hi = run_updates(c)
        per_update = timed(c, min(pack, len(cfgs))) + SAMPLE_OVERHEAD_S
        evals = (c.total_steps // c.eval_every + 1) * c.eval_episodes * (c.max_episode_steps or 150)
        fixed = started(c) + (c.total_steps + evals) * stepped(c)
        lo, hi = lo + u_lo, hi + u_hi
        sec_lo += fixed + u_lo * per_update
        sec_hi += fixed + u_hi * per_update
    rate = steps / max(1e-12, sum(c.total_steps * stepped(c) for c in cfgs))
    return Cost(len(cfgs), steps, lo, hi, sec_lo, sec_hi, rate)


_WORKER_START: List[float] = []
_WORKER_PROBE: List = []  # the thread timing it, started by grid_cost so that it overlaps the other timings


def _time_worker_start() -> None:
    import subprocess
    import sys
    code = "import maniskill_dualher.train, maniskill_dualher.tasks, mani_skill.envs"
    t0 = time.perf_counter()
    try:
        r = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=120)
        _WORKER_START.append(time.perf_counter() - t0 if r.returncode == 0 else WORKER_START_S)
    except (OSError, subprocess.SubprocessError):
        _WORKER_START.append(WORKER_START_S)


def start_worker_probe() -> None:
    """Begin timing a worker's imports in the background (a subprocess; ``worker_start_seconds`` collects it)."""
    import threading
    if not _WORKER_START and not _WORKER_PROBE:
        t = threading.Thread(target=_time_worker_start, daemon=True)
        t.start()
        _WORKER_PROBE.append(t)


def worker_start_seconds() -> float:
    """Seconds a fresh worker process takes to import what a run needs (torch, SAPIEN, ManiSkill, this package),
    timed here once in a subprocess; ``WORKER_START_S`` if that fails."""
    start_worker_probe()
    _WORKER_PROBE[0].join()
    return _WORKER_START[0]


def local_wall_seconds(core_seconds: float, runs: int, workers: int,
                       worker_start: Optional[float] = None) -> float:
    """Wall time on this machine: the runs shared over the workers, each worker importing once in parallel
    (``worker_start``: its seconds, default timed here by ``worker_start_seconds``), after the sweep process's own
    imports and planning (about one worker's start)."""
    start = worker_start_seconds() if worker_start is None else worker_start
    return core_seconds / max(1, min(workers, runs)) + 2 * start


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
        f"estimated time (updates and env steps timed here: {cost.env_steps_per_s:.0f} env steps/s; evaluation "
        "and startup included, the report not; an estimate, not a measurement):",
        f"  one CPU core: {rng(_dur)}; this machine with {plural(workers, 'worker')}: "
        f"{rng(lambda s: _dur(local_wall_seconds(s, cost.runs, workers)))}",
        f"  a Ray cluster: {rng(lambda s: f'{s / 3600:,.0f} core-hours')} (wall time = that / its CPUs)",
    ]


# --------------------------------------------------------------------------- memory
# A worker process running one run, beyond that run's replay and networks (imports of torch, SAPIEN and
# ManiSkill, the run's SAPIEN scene, episode arrays, the update's workspace): one paper-preset SAC+HER+PER run on
# CloseMicrowave, CPU B, at 1c79b93, resident memory minus its replay (rows x ``replay_row_bytes``, 401 B) and
# networks (``network_bytes``, 6 MB) at 10k, 20k and 30k env steps: 548-552 MB; 555-556 MB in a second process at
# 20k-60k (``bench/run_memory.py`` measures a whole run's peak; 0.49 GB of it before the first step).
PROCESS_BYTES = 560_000_000
# Each further run in the same worker (a pack): its env, episode arrays, evaluation and update buffers. Four such
# runs packed at 30k env steps: 597 MB beyond their replays and networks, one alone 552 MB: 15 MB per further run.
RUN_BYTES = 15_000_000
MEMORY_ENV = "MANISKILL_DUALHER_MEMORY_BYTES"  # pretend this machine has this many bytes available (tests)
SUM_TREE_NODE_BYTES = 8  # float64; a leaf per row, and its share of the internal nodes above: n/2 + n/4 + ... = n


def replay_row_bytes(obs_dim: int = 43, act_dim: int = 8, prioritized: bool = True, extra: int = 0) -> int:
    """Bytes one stored row holds: the transition's fields (``replay.buffer.transition_fields``: observation ‖
    goal twice, action, reward, done), a prioritized buffer's sum tree (a leaf and, on average, one internal node
    per row) and ``extra`` (a method's own per-row arrays). 43 inputs and 8 actions: our tasks' layout: 384 B
    uniform, 400 B prioritized (401 B with SAC+HER+PER's mark). A bare prioritized buffer grows by 400 B per row
    between 300k and 1.5M rows (bench/run_memory.py, CPU B); below that a fixed ~20 MB more, numpy's transparent
    huge pages (each array region in use ends in a partly used 2 MiB page), which ``PROCESS_BYTES`` holds."""
    return sum(_field_bytes(obs_dim, act_dim)) + (2 * SUM_TREE_NODE_BYTES if prioritized else 0) + int(extra)


def _field_bytes(obs_dim: int, act_dim: int) -> List[int]:
    """Bytes per row of each transition field (``replay.buffer.transition_fields``)."""
    import numpy as np

    from ..replay.buffer import transition_fields
    return [int(np.prod(shape, dtype=np.int64)) * np.dtype(dtype).itemsize
            for shape, dtype in transition_fields(obs_dim, act_dim).values()]


_NET_BYTES: Dict[tuple, int] = {}


def network_bytes(sac_cfg, obs_dim: int = 43, act_dim: int = 8) -> int:
    """The agent's networks (targets included) as float32, plus a gradient and Adam's two moments of every trained
    parameter: counted on a ``sac.SAC`` built here (once per network shape)."""
    key = (tuple(sac_cfg.hidden), sac_cfg.variant, obs_dim, act_dim)
    if key not in _NET_BYTES:
        import torch

        from ..sac import SAC
        g = torch.Generator().manual_seed(0)
        agent = SAC(obs_dim, act_dim, sac_cfg, device="cpu", generator=g, init_generator=g)
        every = sum(t.numel() * t.element_size() for t in agent.state_dict().values())
        trained = sum(p.numel() * p.element_size() for p in agent.parameters() if p.requires_grad)
        _NET_BYTES[key] = every + 3 * trained
    return _NET_BYTES[key]


@dataclass
class RunMemory:
    """One run's memory plan (bytes): its replay at its end, its networks, the replay it reads at its start."""
    label: str
    rows: Dict[str, int]          # rows each buffer holds at the run's end (capped at the capacity)
    row_bytes: Dict[str, int]     # bytes per row of each buffer
    network_bytes: int
    loaded_bytes: int = 0         # a replay read from a file at its start (held twice while it loads)
    # rows and replay read at the start in a typical run (``replay_typical``), where below the bound; None: as above
    typical_rows: Optional[Dict[str, int]] = None
    typical_loaded_bytes: Optional[int] = None

    @property
    def replay_bytes(self) -> int:
        return sum(self.rows[k] * self.row_bytes[k] for k in self.rows)

    @property
    def resident(self) -> int:
        """What it holds in its worker while it trains (beyond the process and ``RUN_BYTES``)."""
        return self.replay_bytes + self.network_bytes

    @property
    def peak(self) -> int:
        """Alone in a worker: the process, its replay and networks, and a replay being loaded."""
        return PROCESS_BYTES + self.resident + self.loaded_bytes

    @property
    def estimate(self) -> int:
        """Alone in a worker, as a typical run fills its buffers (``peak`` is the bound the plan fits)."""
        rows = self.typical_rows if self.typical_rows is not None else self.rows
        loaded = self.typical_loaded_bytes if self.typical_loaded_bytes is not None else self.loaded_bytes
        return PROCESS_BYTES + sum(rows[k] * self.row_bytes[k] for k in rows) + self.network_bytes + loaded

    def explain(self, typical: bool = False) -> str:
        rows = self.typical_rows if typical and self.typical_rows is not None else self.rows
        parts = [f"{k} {rows[k]:,} rows x {self.row_bytes[k]} B" for k in rows]
        text = f"replay {' + '.join(parts)}, networks {_size(self.network_bytes)}"
        if self.loaded_bytes:
            text += f", {_size(self.loaded_bytes)} of replay read at its start"
        return text + f", process {_size(PROCESS_BYTES)}"


def run_memory(cfg, carried: Sequence = (), resume: bool = False, obs_dim: int = 43, act_dim: int = 8,
               label: str = "") -> RunMemory:
    """The memory plan of a run of ``cfg`` that starts with the replay of the chain stages ``carried`` (their
    configs, in order), or from its own checkpoint (``resume``: its replay read at the start, counted at its
    end size)."""
    from ..methods import method_spec
    cls = method_spec(cfg.method).load()
    layout = getattr(cls, "replay_layout", None) or (  # a method without the hook: one prioritized buffer
        lambda c: {"R": (1.0 + (c.replay.her_k if getattr(cls, "uses_goals", False) else 0), True, 0)})
    typical = getattr(cls, "replay_typical", None) or (lambda c: {k: v[0] for k, v in layout(c).items()})
    cap = int(cfg.replay.capacity)
    rows: Dict[str, int] = {}
    before: Dict[str, int] = {}
    sizes: Dict[str, int] = {}
    t_rows: Dict[str, int] = {}
    t_before: Dict[str, int] = {}
    for name, (per_step, prioritized, extra) in layout(cfg).items():
        # the carried stages' rows as this method would hold them: their env steps at their settings (her_k)
        old = sum(s.total_steps * layout(s).get(name, (1.0,))[0] for s in carried)
        before[name] = min(cap, int(math.ceil(old)))
        rows[name] = min(cap, int(math.ceil(old + cfg.total_steps * per_step)))
        sizes[name] = replay_row_bytes(obs_dim, act_dim, prioritized, extra)
        t_old = sum(s.total_steps * min(typical(s).get(name, 1.0), layout(s).get(name, (1.0,))[0]) for s in carried)
        t_before[name] = min(before[name], int(math.ceil(t_old - 1e-6)))  # 1/150 * 150k is 1000.0000001
        t_rows[name] = min(rows[name], int(math.ceil(t_old + cfg.total_steps * min(typical(cfg)[name], per_step) - 1e-6)))
    mem = RunMemory(label or f"{cfg.method} {cfg.env_id}", rows, sizes, network_bytes(cfg.sac, obs_dim, act_dim))
    at_start = rows if resume else before
    mem.loaded_bytes = sum(_held_twice(at_start[k], sizes[k], cap, resume, obs_dim, act_dim) for k in rows)
    if t_rows != rows:
        mem.typical_rows = t_rows
        t_start = t_rows if resume else t_before
        mem.typical_loaded_bytes = sum(_held_twice(t_start[k], sizes[k], cap, resume, obs_dim, act_dim)
                                       for k in rows)
    return mem


def _held_twice(rows: int, row_bytes: int, capacity: int, resume: bool, obs_dim: int, act_dim: int) -> int:
    """Bytes of a buffer of ``rows`` rows held twice while a run starts from it: all of it for a carried
    parent's replay; on a resume (fields moved in one at a time) the largest transition field and the rest of
    the row (sum tree, a method's own arrays), and only that rest once the buffer is full (its arrays adopted)."""
    if not resume:
        return rows * row_bytes
    fields = _field_bytes(obs_dim, act_dim)
    rest = row_bytes - sum(fields)
    return rows * (rest + (0 if rows >= capacity else max(fields)))


def node_memory(node, resume: bool = False) -> RunMemory:
    """``run_memory`` of a grid node (``grid.Node``): a chain stage that carries replay counts its earlier stages."""
    carried = node.stages[:node.stage] if node.stages is not None and takes_rows(node.cfg, node.carry_replay) else ()
    return run_memory(node.cfg, carried, resume, label=node.rel)


def sweep_peak(mems: Sequence[RunMemory], workers: int, pack: int) -> int:
    """Bytes at once when ``workers`` workers each train up to ``pack`` runs side by side: the largest runs that
    can be alive together, each worker's process and further runs, and one replay being read per worker (a pack's
    runs start one after the other)."""
    n = len(mems)
    if n == 0:
        return 0
    w = max(1, min(workers, n))
    s = max(1, min(pack, -(-n // w)))
    alive = sorted((m.resident for m in mems), reverse=True)[:w * s]
    loading = sorted((m.loaded_bytes for m in mems), reverse=True)[:w]
    return sum(alive) + sum(loading) + w * (PROCESS_BYTES + (s - 1) * RUN_BYTES)


def available_memory() -> Tuple[Optional[int], str]:
    """(bytes this machine has available, where that number comes from); (None, why) when unknown."""
    pretend = os.environ.get(MEMORY_ENV)
    if pretend:
        try:
            return int(float(pretend)), MEMORY_ENV
        except ValueError:
            raise ConfigError(f"{MEMORY_ENV} must be a number of bytes, got {pretend!r}") from None
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024, "MemAvailable"
    except OSError:
        pass
    return None, "unknown (no /proc/meminfo)"


@dataclass
class MemoryPlan:
    workers: int
    pack: int
    peak: int                     # bytes at once with these workers and runs per worker
    available: Optional[int]
    source: str
    note: Optional[str] = None    # one line when the plan had to shrink


def plan_memory(mems: Sequence[RunMemory], workers: int, pack: int,
                available: Optional[int] = None, source: str = "") -> MemoryPlan:
    """The most runs per worker (then workers) up to ``pack`` (``workers``) whose peak fits in ``available``.
    ConfigError (one line naming the numbers) when even one run alone does not fit."""
    peak = sweep_peak(mems, workers, pack)
    if available is None or not mems or peak <= available:
        return MemoryPlan(workers, pack, peak, available, source)
    big = max(mems, key=lambda m: m.peak)
    if big.peak > available:
        raise ConfigError(f"one run needs ~{_size(big.peak)} at its peak ({big.explain()}; {big.label}) but this "
                          f"machine has {_size(available)} available ({source}): lower replay.capacity, or run it "
                          f"on a machine with more memory")
    for w in range(workers, 0, -1):
        for s in range(pack, 0, -1):
            p = sweep_peak(mems, w, s)
            if p <= available:
                what = f"{s} run{'s' if s > 1 else ''} per worker (not {pack})" if s != pack else f"{s} runs per worker"
                if w != workers:
                    what += f" on {w} worker{'s' if w > 1 else ''} (not {workers})"
                note = (f"memory: {what}, so that the sweep's peak ~{_size(p)} fits in the {_size(available)} "
                        f"available ({source}); {workers} x {pack} would need ~{_size(peak)}")
                return MemoryPlan(w, s, p, available, source, note)
    raise AssertionError("one run fits, so one worker with one run fits")  # pragma: no cover


def describe_memory(mems: Sequence[RunMemory], plan: MemoryPlan) -> List[str]:
    if not mems:
        return []
    big = max(mems, key=lambda m: m.estimate)
    small = min(m.estimate for m in mems)
    span = _size(big.estimate) if small == big.estimate else f"{_size(small)} to {_size(big.estimate)}"
    avail = "unknown" if plan.available is None else f"{_size(plan.available)} ({plan.source})"
    worst = max(mems, key=lambda m: m.peak)
    bound = ""
    if worst.peak != big.estimate:  # a buffer typically holds far fewer rows than its bound (the dual buffer's E)
        bound = (f"; at most {_size(worst.peak)} if every buffer fills to its bound ({worst.explain()}), which the "
                 f"plan fits")
    return [f"estimated peak memory (an estimate, not a measurement): one run {span} (the largest: "
            f"{big.explain(typical=True)}){bound}; the sweep with {plan.workers} worker{'s' if plan.workers > 1 else ''}"
            f" x up to {plan.pack} run{'s' if plan.pack > 1 else ''} each at once: {_size(plan.peak)}; available: "
            f"{avail}"]


def _size(b: float) -> str:
    if b >= 1e9:
        return f"{b / 1e9:.1f} GB"
    if b >= 1e6:
        return f"{b / 1e6:.0f} MB"
    return f"{b / 1e3:.0f} kB"
