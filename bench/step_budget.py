"""Where the wall time of a training env step goes: quick-preset runs driven side by side, every millisecond attributed.

Runs ``train.train_runs`` in this process (S members, seeds 0..S-1, the quick preset's settings, a short budget;
``train.drive`` steps them together and ``pack.Updater`` batches their updates) with timers wrapped around the
loop's pieces from outside (train.py, pack.py and sac*.py are not edited). Each timer charges the time since the
last timer event to the innermost open piece (exclusive time), so the parts add up to the whole. Parts, per
training env step (summed over members):

  physics           PhysX's substeps (``scene.px.step``) of training steps
  env python        the rest of ``BatchEnv.step``: action scaling, drive targets, observation, reward, info
  env reset         ``BatchEnv.reset``/``reset_envs`` of training episodes
  acting            ``Trainer._explore`` (uniform draws, then the actor's forward)
  episodes+store    the rest of ``Trainer.step`` (episode clocks and arrays, counters) and ``Trainer._store``
                    (HER relabeling, replay insertion)
  sampling          ``Trainer.sample`` (replay sampling, HER relabel of the batch, tensors)
  priorities        ``method.update_priorities`` (sum-tree updates)
  update products   the fused update's matrix products (torch.mm/bmm/addmm/baddbmm/mv inside sac_fused)
  update overhead   the rest of the update: elementwise ops, Adam, Polyak, stacking, per-op dispatch
                    (``SAC.update``, ``FusedUpdate``), and ``Updater.round`` grouping the due runs into packs
  update logging    the rest of ``Trainer.learn`` (counters, diagnostics, TensorBoard every log_every updates)
                    and ``Trainer._updates_due`` (the update schedule)
  eval physics      PhysX's substeps inside ``train.evaluate_runs``/``Trainer.evaluate``
  eval python       the rest of evaluation (its env Python, resets, acting, episode bookkeeping)
  logging           ``Trainer.between_episodes``/``after_step`` (cut episodes, metrics, policies), ``finish``,
                    ``_close_logs``
  checkpoints       ``Trainer.save_checkpoint`` (state, networks, the replay buffers: GBs at R = 10^7 rows)
  setup             building the trainers, ``start`` (env, networks, demonstrations, logs), ``close`` (the envs)
  driver loop       what is left inside ``train_runs``/``drive`` (run folders, guards, the loop itself): not
                    attributed

"floor" = physics (training + evaluation) + update products. Scheduler idle (a sweep's worker waiting for
runs) does not exist in one process; the bench says so instead of inventing it. The lean env step is on
unless ``MANISKILL_DUALHER_LEAN_STEP=0`` (compare the two for the env's share before/after).

A short window checkpoints at a rate no run has: a run writes one every ``checkpoint_every`` env steps (300,000
in the paper regime), and the window's last step writes one too. So each checkpoint write is timed, and the
report also gives the total and its floor ratio with the writes charged at the run's own rate (the mean write
with the replay, times the writes a run of ``total_steps`` makes, per env step): the figure a run sees.

    python bench/step_budget.py [--tasks ReachTarget-v1,...] [--members 2] [--steps 3000]
                                [--learning-starts N] [--set KEY=VALUE ...] [--warmup-steps W] [--out FILE.json]
                                [--fill-rows N] [--floor-products-from FILE.json]

``--learning-starts N`` (default: the preset's) sets both the random steps and the first update's env step
(a short run that reaches its updates: tests/test_step_budget.py). ``--learning-starts 0`` is the steady state:
no random-step phase, one update per env step from the first full batch.

``--set KEY=VALUE`` (repeatable) changes the runs' settings as ``sweep --set`` does, e.g. ``--set sac.compile=true``
(the opt-in ``torch.compile`` of the fused update; its bits differ from the default's, ``bench/golden.py``
has its own cases). ``--warmup-steps W`` counts nothing before every member has made W env steps: wall time,
CPU time, parts, calls and updates are measured from there (a compiled update's compilation, ~3 s warm and
~60 s cold, happens at the first update and is not a training step's cost; the report states W).

A compiled update's products are timed where inductor's generated code calls them (``extern_kernels.mm``, ``addmm``,
``bmm``, ``baddbmm``: looked up at every call, so a timer set there sees each one); inductor writes the critics'
matrix-vector products as its own loops, which count as overhead (the floor is understated, so the ratio to it
is overstated, not flattered).

``--regime paper`` measures a run as the ``paper_regime`` experiment's ``episode`` arm adapts (issue 41): the
``reference`` preset with that arm's adaptation settings read from the registry (Table 3: replay 10^7, HER
k = 8, 150-step episodes that end on success, lr 1e-4, gamma 0.99, alpha fixed; Algorithm 1's one update per
finished episode; evaluation of 10 episodes every 30,000 env steps, a checkpoint every 300,000), on
CloseMicrowave by default. Its 100,000 uniform-random steps are set to ``--learning-starts`` (default 1000) so
that a short bench measures the learning phase, which is 97% of a 3.6M-step run.

Both the wall time (perf_counter) and the thread's CPU time (thread_time) are split: on a busy machine the wall
time includes waiting for a core (inflating every part alike, on average), the CPU time does not; the header
says how much of the wall time the process had a core.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
import types
from pathlib import Path
from typing import Optional

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PARTS = ("physics", "env python", "env reset", "acting", "episodes+store", "sampling", "priorities",
         "update products", "update overhead", "update logging", "eval physics", "eval python", "logging",
         "checkpoints", "setup", "driver loop")
FLOOR = ("physics", "eval physics", "update products")
PRODUCTS = ("mm", "bmm", "addmm", "baddbmm", "mv")
COMPILED_PRODUCTS = ("mm", "bmm", "addmm", "baddbmm")  # inductor's extern kernels (mv: its own loops)


class Clock:
    """Exclusive time per part: every event charges the time since the previous event to the part on top,
    in wall time (perf_counter) and in this thread's CPU time (thread_time: what a busy machine disturbs least)."""

    def __init__(self):
        self.wall = {p: 0.0 for p in PARTS}
        self.cpu = {p: 0.0 for p in PARTS}
        self.calls = {p: 0 for p in PARTS}
        self.intervals = {p: 0 for p in PARTS}  # timer intervals charged to each part (each holds ~one event's cost)
        self.stack = ["driver loop"]
        self.events = 0
        self.runs = []  # the trainers, as they start (the warm-up's mark reads their counters)
        self.writes = []  # (wall s, with the replay) of each checkpoint write
        self.marked = None  # (wall, process CPU, updates) at the warm-up's end; None: not yet
        self.reset()

    def mark(self) -> None:
        """The warm-up ends here: what was charged so far is dropped, the counts start again."""
        self._charge()
        for d in (self.wall, self.cpu):
            for p in d:
                d[p] = 0.0
        for d in (self.calls, self.intervals):
            for p in d:
                d[p] = 0
        self.events = 0
        self.writes = []
        self.marked = (time.perf_counter(), time.process_time(), sum(r.count.updates for r in self.runs))

    def reset(self) -> None:
        self.last, self.last_cpu = time.perf_counter(), time.thread_time()

    def _charge(self) -> None:
        now, cpu = time.perf_counter(), time.thread_time()
        top = self.stack[-1]
        self.wall[top] += now - self.last
        self.cpu[top] += cpu - self.last_cpu
        self.intervals[top] += 1
        self.last, self.last_cpu = now, cpu
        self.events += 1

    def enter(self, part: str) -> None:
        self._charge()
        self.stack.append(part)
        self.calls[part] += 1

    def leave(self) -> None:
        self._charge()
        self.stack.pop()


CLOCK: Clock = None  # set in run()


def timed(fn, part, in_eval_part=None):
    """fn wrapped: its exclusive time goes to ``part`` (or ``in_eval_part`` when called during evaluation)."""
    def wrapper(*a, **kw):
        p = in_eval_part if (in_eval_part and _in_eval()) else part
        CLOCK.enter(p)
        try:
            return fn(*a, **kw)
        finally:
            CLOCK.leave()
    wrapper.__wrapped__ = fn
    return wrapper


def _in_eval() -> bool:
    return "eval python" in CLOCK.stack


class _Px:
    """scene.px with a timed step (pybind attributes cannot be patched; the scene's reference can)."""

    def __init__(self, px):
        object.__setattr__(self, "_px", px)

    def __getattr__(self, k):
        return getattr(self._px, k)

    def step(self):
        CLOCK.enter("eval physics" if _in_eval() else "physics")
        try:
            self._px.step()
        finally:
            CLOCK.leave()


def fill_replay(trainer, rows: int, chunk: int = 250_000) -> None:
    """Fill each prioritized buffer of the run's method with synthetic rows (at the maximum priority, as new rows
    arrive) to ``rows`` (at most its capacity), so that sampling and priority writes walk a tree that size: a short
    bench otherwise samples from the ~10^5 rows it stored, which sit in cache."""
    import numpy as np

    from maniskill_dualher.replay.buffer import transition_fields
    rng = np.random.default_rng(0)
    for buf in trainer.method.buffers.values():
        if not getattr(buf.sampler, "prioritized", False):
            continue
        goal = min(rows, buf.storage.capacity)
        fields = transition_fields(trainer.method.obs_dim, trainer.method.act_dim)
        while len(buf.storage) < goal:
            n = min(chunk, goal - len(buf.storage))
            buf.add({k: rng.standard_normal((n, *shape)).astype(dt) if shape else np.zeros(n, dt)
                     for k, (shape, dt) in fields.items()})


def instrument(warmup_steps: int = 0, compiled: bool = False, fill_rows: int = 0) -> None:
    import maniskill_dualher.sac_fused as sf
    import maniskill_dualher.tasks  # noqa: F401  (registers the tasks)
    from maniskill_dualher import envs, pack, sac, train
    from maniskill_dualher.replay import method as rm

    # a process's one-off (imports of torch._dynamo and ManiSkill, the heap frozen) is not a training step's:
    # done here, before the clock, as the imports above are (else the first task's "driver loop" holds it)
    train.freeze_imports()
    T = train.Trainer
    T.__init__ = timed(T.__init__, "setup")
    start = timed(T.start, "setup")

    def start_and_register(self, *a, **kw):
        CLOCK.runs.append(self)
        out = start(self, *a, **kw)
        if fill_rows:
            fill_replay(self, fill_rows)  # before the warm-up's mark: not counted
        return out
    T.start = start_and_register
    T.close = timed(T.close, "setup")
    T.step = timed(T.step, "episodes+store")
    T._explore = timed(T._explore, "acting")
    T._store = timed(T._store, "episodes+store")
    T._updates_due = timed(T._updates_due, "update logging")  # the schedule's bookkeeping
    T.sample = timed(T.sample, "sampling")
    T.learn = timed(T.learn, "update logging")
    T.between_episodes = timed(T.between_episodes, "logging")
    after_step = timed(T.after_step, "logging")
    save = timed(T.save_checkpoint, "checkpoints")

    def save_and_note(self, replay: bool = True):
        t = time.perf_counter()
        out = save(self, replay)
        CLOCK.writes.append((time.perf_counter() - t, bool(replay)))
        return out
    T.save_checkpoint = save_and_note

    def after_step_and_mark(self, *a, **kw):
        out = after_step(self, *a, **kw)
        if CLOCK.marked is None and warmup_steps and all(r.count.env_steps >= warmup_steps for r in CLOCK.runs):
            CLOCK.mark()
        return out
    T.after_step = after_step_and_mark
    T.evaluate = timed(T.evaluate, "eval python")
    train.evaluate_runs = timed(train.evaluate_runs, "eval python")  # runs due together: side by side
    T.finish = timed(T.finish, "logging")
    T._close_logs = timed(T._close_logs, "logging")
    B = envs.BatchEnv
    B.step = timed(B.step, "env python", "eval python")
    B.reset = timed(B.reset, "env reset", "eval python")
    B.reset_envs = timed(B.reset_envs, "env reset", "eval python")
    B.close = timed(B.close, "setup")
    init = B.__init__

    def batch_env_init(self, cfg):
        init(self, cfg)
        if self.is_maniskill:
            scene = self.unwrapped.scene
            scene.px = _Px(scene.px)
    B.__init__ = batch_env_init
    # the update: one run's (SAC.update), a pack's (Updater.round groups the due runs; FusedUpdate.step_pack)
    pack.Updater.round = timed(pack.Updater.round, "update overhead")
    sac.SAC.update = timed(sac.SAC.update, "update overhead")
    F = sf.FusedUpdate
    F.__call__ = timed(F.__call__, "update overhead")
    F.step_pack = timed(F.step_pack, "update overhead")
    # the fused update's products: sac_fused looks them up on its module-level ``torch`` (not for a compiled
    # update: dynamo would trace into the timers and break its graph at every product)
    import torch
    if compiled:
        from torch._inductor.select_algorithm import extern_kernels
        for name in COMPILED_PRODUCTS:  # where inductor's generated code calls its products
            setattr(extern_kernels, name, timed(getattr(extern_kernels, name), "update products"))
    proxy = types.SimpleNamespace(**{k: getattr(torch, k) for k in dir(torch) if not k.startswith("__")})
    for name in PRODUCTS:
        setattr(proxy, name, timed(getattr(torch, name), "update products"))
    if not compiled:
        sf.torch = proxy
    # priority updates: every method's go through BufferMethod.update_priorities (replay/method.py)
    rm.BufferMethod.update_priorities = timed(rm.BufferMethod.update_priorities, "priorities")


def calibrate(n: int = 20000) -> dict:
    """Wall and CPU seconds one timer event costs (half an enter/leave pair around an empty call, less the call)."""
    global CLOCK
    saved, CLOCK = CLOCK, Clock()
    f = timed(lambda: None, "driver loop")
    g = lambda: None  # noqa: E731
    out = {}
    for name, clock in (("wall", time.perf_counter), ("cpu", time.thread_time)):
        t = clock()
        for _ in range(n):
            f()
        pair = (clock() - t) / n
        t = clock()
        for _ in range(n):
            g()
        out[name] = max(0.0, pair - (clock() - t) / n) / 2
    CLOCK = saved
    return out


def corrected(res: dict, per_event: dict) -> tuple:
    """Each part's wall and CPU time less the timer events' cost inside its intervals."""
    iv = res["intervals"]
    return tuple({p: max(0.0, res[key][p] - iv[p] * per_event[c]) for p in PARTS}
                 for key, c in (("parts_wall_s", "wall"), ("parts_cpu_s", "cpu")))


def regime_config(regime: str, method: str, seed: int, task: str):
    """A single-task run's config: the quick preset's, or (``paper``) the paper_regime ``episode`` arm's
    adaptation stage, taken from the registry so the bench measures what the experiment runs."""
    from maniskill_dualher.experiment import overrides
    from maniskill_dualher.experiment.presets import preset
    from maniskill_dualher.experiment.registry import EXPERIMENTS
    if regime == "quick":
        return preset("quick").single_config(method, seed, task)
    arm = next(a for a in EXPERIMENTS["paper_regime"].arms if a.name == "episode")
    cfg = preset("reference").single_config(method, seed, task)
    return overrides.apply(cfg, overrides.parse_all(arm.settings), stage=0, n_stages=1)  # stage 0 of 1: adapt.


def run(task: str, members: int, steps: int, method: str, learning_starts: Optional[int] = None,
        regime: str = "quick", sets: tuple = (), warmup_steps: int = 0) -> dict:
    global CLOCK
    from maniskill_dualher.experiment import overrides
    from maniskill_dualher.train import Job, train_runs

    jobs = []
    tmp = tempfile.mkdtemp(prefix="step_budget_")
    run_steps = None
    for seed in range(members):
        cfg = regime_config(regime, method, seed, task)
        run_steps = overrides.apply(cfg, sets).total_steps  # a real run's budget: its checkpoints' rate
        cfg.total_steps = steps
        if learning_starts is not None:
            cfg.sac.random_steps = cfg.sac.learning_starts = learning_starts
        cfg = overrides.apply(cfg, sets)
        cfg.validate()
        jobs.append(Job(cfg, os.path.join(tmp, f"s{seed}")))
    try:
        CLOCK = Clock()
        cpu0, wall0 = time.process_time(), time.perf_counter()
        CLOCK.reset()
        rows = train_runs(jobs)
        CLOCK._charge()
        wall = time.perf_counter() - wall0
        cpu = time.process_time() - cpu0
        updates0 = 0
        if warmup_steps:
            if CLOCK.marked is None:
                raise SystemExit(f"--warmup-steps={warmup_steps}: the runs never got there (--steps={steps})")
            wall = time.perf_counter() - CLOCK.marked[0]
            cpu = time.process_time() - CLOCK.marked[1]
            updates0 = CLOCK.marked[2]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)  # the runs' folders (checkpoints, replay) are not the result
    errors = [r["error"] for r in rows if "error" in r]
    if errors:
        raise SystemExit(f"a run failed: {errors[0]!r}")
    env_steps = (steps - warmup_steps) * members
    return {"task": task, "members": members, "steps_per_member": steps, "method": method, "regime": regime,
            "warmup_steps_per_member": warmup_steps, "sets": [o.text() for o in sets], "wall_s": wall,
            "cpu_s": cpu, "training_env_steps": env_steps, "timer_events": CLOCK.events,
            "updates": sum(int(r["row"]["updates"]) for r in rows) - updates0,
            "parts_wall_s": dict(CLOCK.wall), "parts_cpu_s": dict(CLOCK.cpu), "calls": dict(CLOCK.calls),
            "intervals": dict(CLOCK.intervals), "cfg": jobs[0].cfg.to_dict(),
            "checkpoint_writes": [{"wall_s": w, "replay": r} for w, r in CLOCK.writes],
            "run_total_steps": run_steps}


def checkpoints_at_run_rate(res: dict) -> Optional[dict]:
    """The window's checkpoint writes charged at a real run's rate: the mean write with the replay (s), the writes a
    run of ``run_total_steps`` makes (one every ``checkpoint_every`` env steps and at its end), and what that costs
    per env step (s). None when the window wrote none with the replay (or the result predates the field)."""
    writes = [w["wall_s"] for w in res.get("checkpoint_writes", []) if w["replay"]]
    total = res.get("run_total_steps")
    if not writes or not total:
        return None
    every = res["cfg"]["checkpoint_every"]
    mean, n_writes = sum(writes) / len(writes), -(-total // every)
    return {"mean_write_s": mean, "writes": len(writes), "run_writes": n_writes, "run_steps": total,
            "every": every, "per_step_s": mean * n_writes / total}


def _floor_ms(res: dict, parts: dict, key: str) -> float:
    """The floor per env step (ms): physics, evaluation physics and the update's products, those taken from
    ``--floor-products-from``'s run when given (``key``: its "wall_ms" or "cpu_ms")."""
    n, fp = res["training_env_steps"], res.get("floor_products")
    if fp:
        return 1e3 * (parts["physics"] + parts["eval physics"]) / n + fp[key]
    return 1e3 * sum(parts[p] for p in FLOOR) / n


def report(res: dict, per_event: dict) -> str:
    n = res["training_env_steps"]
    wall, cpu = res["wall_s"], res["cpu_s"]
    pw, pc = corrected(res, per_event)
    tw, tc = sum(pw.values()), sum(pc.values())
    timer_w = res["wall_s"] - tw
    starts = res["cfg"]["sac"]["learning_starts"]
    regime = res.get("regime", "quick")
    sched = res["cfg"]["sac"]["update_schedule"]
    lines = [f"{res['task']}: {res['members']} members x {res['steps_per_member']} env steps ({res['method']}, "
             f"{'quick preset' if regime == 'quick' else 'paper_regime:episode adaptation settings'}, "
             f"update schedule {sched!r}, updates from env step {starts}: {res['updates']} in all, lean step "
             f"{'on' if res['lean_step'] else 'off'}"
             + (f", settings {' '.join(res['sets'])}" if res.get("sets") else "")
             + (f"; measured after a warm-up of {res['warmup_steps_per_member']} env steps per member"
                if res.get("warmup_steps_per_member") else "")
             + f"), wall {wall:.1f} s, process CPU "
             f"{cpu:.1f} s ({100 * cpu / wall:.0f}% of wall: the rest waited for a core)",
             f"per training env step, timer cost removed ({res['timer_events']} events x "
             f"{1e6 * per_event['wall']:.2f} us wall / {1e6 * per_event['cpu']:.2f} us CPU = {100 * timer_w / wall:.1f}% "
             f"of the wall time):",
             f"{'part':<18}{'wall ms/step':>13}{'share':>8}{'CPU ms/step':>13}{'share':>8}"]
    for p in PARTS:
        lines.append(f"{p:<18}{1e3 * pw[p] / n:>13.3f}{100 * pw[p] / tw:>7.1f}%{1e3 * pc[p] / n:>13.3f}"
                     f"{100 * pc[p] / tc:>7.1f}%")
    lines.append(f"{'total':<18}{1e3 * tw / n:>13.3f}{100.0:>7.1f}%{1e3 * tc / n:>13.3f}{100.0:>7.1f}%")
    lines.append(f"attributed (all but 'driver loop'): {100 * (1 - pw['driver loop'] / tw):.1f}% of wall, "
                 f"{100 * (1 - pc['driver loop'] / tc):.1f}% of CPU")
    for name, parts, tot in (("wall", pw, tw), ("CPU", pc, tc)):
        floor = sum(parts[p] for p in FLOOR)
        lines.append(f"floor (physics + eval physics + update products), {name}: {1e3 * floor / n:.3f} ms/step "
                     f"against {1e3 * tot / n:.3f}: {tot / floor:.2f}x its floor")
    if res.get("floor_products"):  # a compiled update calls its products from C++, where no timer sees them
        fp = res["floor_products"]
        for name, parts, tot, key in (("wall", pw, tw, "wall_ms"), ("CPU", pc, tc, "cpu_ms")):
            floor = _floor_ms(res, parts, key)
            lines.append(f"floor with the update products of {fp['from']} ({fp[key]:.3f} ms/step, the same products "
                         f"uncompiled), {name}: {floor:.3f} ms/step against {1e3 * tot / n:.3f}: "
                         f"{1e3 * tot / n / floor:.2f}x its floor")
    ck = checkpoints_at_run_rate(res)
    if ck:
        lines.append(f"checkpoints: {ck['writes']} write(s) with the replay in this window, {ck['mean_write_s']:.2f} s "
                     f"each on average; a run of {ck['run_steps']:,} env steps writes {ck['run_writes']} (one every "
                     f"{ck['every']:,} and at its end): {1e3 * ck['per_step_s']:.3f} ms per env step at that rate, "
                     f"against {1e3 * pw['checkpoints'] / n:.3f} in this window")
        fp = res.get("floor_products")
        for name, parts, tot, key in (("wall", pw, tw, "wall_ms"), ("CPU", pc, tc, "cpu_ms")):
            at_rate = 1e3 * (tot - parts["checkpoints"]) / n + 1e3 * ck["per_step_s"]  # a write's wall, both
            floor = _floor_ms(res, parts, key)
            lines.append(f"at a run's checkpoint rate, {name}: {at_rate:.3f} ms/step against a floor of {floor:.3f}"
                         f"{' (products from ' + fp['from'] + ')' if fp else ''}: {at_rate / floor:.2f}x its floor")
    calls = res["calls"]["env python"]
    for name, parts in (("wall", pw), ("CPU", pc)):
        step = parts["physics"] + parts["env python"]
        lines.append(f"training env step (BatchEnv.step, {calls} calls), {name}: {1e3 * step / calls:.3f} ms, "
                     f"{step / parts['physics']:.2f}x its physics ({1e3 * parts['physics'] / calls:.3f} ms)")
    lines.append("scheduler idle: none in one process (a sweep's workers idle only when runs are uneven)")
    return "\n".join(lines)


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tasks", default=None, help="comma-separated tasks (default: every task of config.TASKS; "
                                                 "the paper's target with --regime paper)")
    p.add_argument("--regime", default="quick", choices=("quick", "paper"),
                   help="quick: the quick preset; paper: the paper_regime experiment's episode arm")
    p.add_argument("--members", type=int, default=2)
    p.add_argument("--steps", type=int, default=3000, help="env steps per member")
    p.add_argument("--method", default="dual_buffer")
    p.add_argument("--learning-starts", type=int, default=None,
                   help="random steps and first update's env step (default: the quick preset's)")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE",
                   help="a setting of every run, as `sweep --set` (e.g. sac.compile=true); repeatable")
    p.add_argument("--warmup-steps", type=int, default=0,
                   help="env steps per member run before anything is counted (a compiled update compiles there)")
    p.add_argument("--fill-rows", type=int, default=0, metavar="N",
                   help="fill each run's prioritized replay with N synthetic rows (up to its capacity) before the "
                        "warm-up, so sampling and priority writes walk a tree of a full run's size")
    p.add_argument("--floor-products-from", metavar="FILE.json",
                   help="another run of this bench (one task, uncompiled, the same settings otherwise) whose update "
                        "products per env step stand in the floor: a compiled update calls its products from C++ "
                        "(SACConfig.compile), where this bench's timers do not see them")
    p.add_argument("--out", help="JSON file for the raw numbers (atomic write)")
    p.add_argument("--load", default="", help="a note on the machine's load while this ran, kept in the output")
    args = p.parse_args(argv)
    if args.tasks is None:
        from maniskill_dualher.config import TASKS
        from maniskill_dualher.experiment.registry import PAPER_TARGET
        args.tasks = PAPER_TARGET if args.regime == "paper" else ",".join(TASKS)
    if args.regime == "paper" and args.learning_starts is None:
        args.learning_starts = 1000
    from maniskill_dualher.config import TASKS
    tasks = [t for t in args.tasks.split(",") if t]
    bad = [t for t in tasks if t not in TASKS]
    if bad or not tasks:
        print(f"--tasks={args.tasks!r}: unknown task {bad[0] if bad else ''!r} (choose from {','.join(TASKS)})",
              file=sys.stderr)
        raise SystemExit(2)
    if args.members < 1 or args.steps < 1:
        print(f"--members={args.members} --steps={args.steps} must be >= 1", file=sys.stderr)
        raise SystemExit(2)
    from maniskill_dualher.methods import method_names
    if args.method not in method_names():
        print(f"--method={args.method!r}: unknown method (choose from {','.join(method_names())})", file=sys.stderr)
        raise SystemExit(2)
    if args.learning_starts is not None and args.learning_starts < 0:
        print(f"--learning-starts={args.learning_starts} must be >= 0", file=sys.stderr)
        raise SystemExit(2)
    if not 0 <= args.warmup_steps < args.steps:
        print(f"--warmup-steps={args.warmup_steps} must be >= 0 and below --steps={args.steps}", file=sys.stderr)
        raise SystemExit(2)
    from maniskill_dualher.config import ConfigError
    from maniskill_dualher.experiment import overrides
    try:
        sets = overrides.parse_all(args.sets)
        compiled = set()
        for task in tasks:  # every run's config is checked before anything runs
            cfg = overrides.apply(regime_config(args.regime, args.method, 0, task), sets)
            cfg.validate()
            compiled.add(cfg.sac.compile)
    except ConfigError as e:
        print(f"--set {' '.join(args.sets)!r}: {e}", file=sys.stderr)
        raise SystemExit(2)
    import torch
    torch.set_num_threads(1)
    from maniskill_dualher import envs
    if args.fill_rows and not args.warmup_steps:
        print(f"--fill-rows={args.fill_rows} needs --warmup-steps (filling is not a training step's cost)",
              file=sys.stderr)
        raise SystemExit(2)
    instrument(args.warmup_steps, compiled == {True}, args.fill_rows)
    per_event = calibrate()
    lean = envs.lean_step_wanted()
    floor_products = None
    if args.floor_products_from:
        try:
            other = json.loads(Path(args.floor_products_from).read_text())["results"][0]
            n_other = other["training_env_steps"]
            floor_products = {"from": args.floor_products_from,
                              "wall_ms": 1e3 * other["parts_wall_s"]["update products"] / n_other,
                              "cpu_ms": 1e3 * other["parts_cpu_s"]["update products"] / n_other}
        except (OSError, ValueError, KeyError, IndexError, ZeroDivisionError) as e:
            print(f"--floor-products-from={args.floor_products_from!r}: not a step_budget result ({e})",
                  file=sys.stderr)
            raise SystemExit(2)
    results = []
    for task in tasks:
        res = run(task, args.members, args.steps, args.method, args.learning_starts, args.regime, sets,
                  args.warmup_steps)
        res["lean_step"] = lean
        res["timer_event_s"] = per_event
        res["floor_products"] = floor_products
        results.append(res)
        print(report(res, per_event), flush=True)
    if args.out:
        from maniskill_dualher.fileio import atomic_write_text
        from maniskill_dualher import provenance
        prov = provenance.provenance(ROOT)
        doc = {"command": " ".join([sys.argv[0]] + (argv if argv is not None else sys.argv[1:])),
               "lean_step": lean, "load": args.load, "timer_event_s": per_event,
               "machine": provenance.machine_name(prov["cpu"]),
               "provenance": prov, "results": results,
               "report": [report(r, per_event) for r in results]}
        atomic_write_text(args.out, json.dumps(doc, indent=1, default=str) + "\n")
        print(f"wrote {args.out}")



if __name__ == "__main__":
    main()
