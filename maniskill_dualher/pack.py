"""Many runs in one process: S trainers stepped in turn, their gradient updates batched into one.

    from maniskill_dualher.pack import Job, run_pack
    rows = run_pack([Job(cfg_seed0, "runs/a"), Job(cfg_seed1, "runs/b")])    # the sweep: --pack S

Why: at small networks (the quick and reference presets' 64x64) one SAC update is mostly per-op overhead;
the same products of S agents in one batched call cost little more than one agent's (``bench/sweep_speed.py``
measures what that buys a sweep). The env steps, evaluations and replay stay per run.

A run's results do not depend on its pack (``tests/test_pack.py``: metrics and weights bit for bit, alone and
packed; a pack killed mid-run resumes to the same metrics):
* each run keeps its own torch random stream: the global generator's state is swapped in whenever that run
  acts, samples, evaluates or checkpoints, and a packed update draws each agent's noise from that agent's
  stream, in the order its own update would (``FusedUpdate.draw_shapes``);
* the batched products give each member what its own product gives (checked by the tests above on every
  variant and option; ``sac_fused.py`` keeps one agent's path unchanged);
* env, replay, optimizer, counters and run folder stay per run, so checkpoints and resume are per run.

Runs pack when their updates are the same computation (``pack_key``: network shapes and the SAC settings the
batched update reads; lr, tau, the schedule and alpha's start stay per run); within a pack an update round
batches the members that are due and whose batches have the same form (IS weights or not). A run that fails
is written off alone (its ``error.txt``); the others go on.
"""
from __future__ import annotations

import contextlib
import dataclasses
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
import torch

from .config import ConfigError, RunConfig
from .rundir import RunFolder

# SACConfig fields that stay per agent in a packed update (its own Adam, Polyak step, schedule, alpha start)
PER_AGENT = ("lr", "tau", "alpha", "random_steps", "learning_starts", "update_schedule", "updates_per_step",
             "updates_per_episode", "log_every")


@dataclasses.dataclass
class Job:
    """One run for a pack: what ``train.run_training`` takes."""
    cfg: RunConfig
    out: str
    init_from: Optional[str] = None
    carry_replay: bool = False
    keep_replay: bool = False


def pack_key(cfg: RunConfig) -> Optional[str]:
    """Runs with equal keys can share batched updates; None: this run updates alone (autograd or compiled
    updates, which the pack does not batch)."""
    s = cfg.sac
    if s.update_impl != "fused" or s.compile:
        return None
    shared = {k: v for k, v in dataclasses.asdict(s).items() if k not in PER_AGENT}
    return repr(sorted(shared.items())) + f"|{cfg.device}"


@dataclasses.dataclass
class _Member:
    k: int                     # index into the jobs
    trainer: object            # train.Trainer
    rng: torch.Tensor          # its torch random state while another run holds the generator
    ended: np.ndarray = None   # which envs' episodes ended this step
    due: int = 0               # updates due this step
    form: Optional[tuple] = None  # (pack_key, parameter shapes): members that may share an update; None: alone

    def __post_init__(self):  # once per run, not per update
        key = pack_key(self.trainer.cfg)
        if key is not None:
            self.form = (key, tuple(p.shape for p in self.trainer.agent.parameters()))


@contextlib.contextmanager
def _own_rng(m: _Member):
    """Run a block on member m's own torch random stream."""
    torch.set_rng_state(m.rng)
    try:
        yield
    finally:
        m.rng = torch.get_rng_state()


def run_pack(jobs: Sequence[Job], stop_at: Optional[int] = None) -> List[dict]:
    """Train (or resume, or return the result of) every job in this process, side by side. -> per job
    ``{"row": final metrics}``, ``{"row": None}`` (paused at ``stop_at``) or ``{"error": exception}``."""
    from .train import Trainer  # late: train imports the simulator

    results: List[Optional[dict]] = [None] * len(jobs)
    live: List[_Member] = []
    fused: Dict[Tuple[int, ...], object] = {}  # batched updates by member set (packs shrink as runs end)
    try:
        for k, job in enumerate(jobs):
            folder = RunFolder(job.out)
            if folder.done:
                results[k] = {"row": folder.final()}
                continue
            try:
                tr = Trainer(job.cfg, job.out, init_from=job.init_from, carry_replay=job.carry_replay,
                             show_progress=False, keep_replay=job.keep_replay)
            except Exception as e:  # as run_training: bad input writes nothing into the folder
                if not isinstance(e, ConfigError):
                    folder.write_error()
                results[k] = {"error": e}
                continue
            m = _Member(k, tr, torch.get_rng_state())  # Trainer() seeded the generator: its stream from here
            if _guard(m, results, live, lambda: tr.start()):
                live.append(m)
        while live:
            for m in list(live):                                       # act, step, store: run by run
                _guard(m, results, live, lambda: _collect(m))
            for j in range(max((m.due for m in live), default=0)):     # updates due: batched
                _update_round([m for m in live if m.due > j], results, live, fused)
            for m in list(live):                                       # evaluate, checkpoint, finish
                _guard(m, results, live, lambda: _after_step(m, stop_at, results, live))
    finally:  # a kill or an interrupt: every run's last checkpoint stands
        for m in live:
            with contextlib.suppress(Exception):
                m.trainer.close_logs()
            with contextlib.suppress(Exception):
                m.trainer.env.close()
    return [r if r is not None else {"error": RuntimeError("not run")} for r in results]


def _collect(m: _Member) -> None:
    tr = m.trainer
    m.ended = tr.collect_step()
    m.due = tr.updates_due(m.ended)


def _after_step(m: _Member, stop_at: Optional[int], results: List[Optional[dict]], live: List[_Member]) -> None:
    tr = m.trainer
    paused = tr.between_episodes(m.ended, stop_at)
    if paused or tr.count.env_steps >= tr.cfg.total_steps:
        tr.close_logs()
        results[m.k] = {"row": None if paused else tr.finish()}
        live.remove(m)
        tr.env.close()


def _guard(m: _Member, results: List[Optional[dict]], live: List[_Member], fn) -> bool:
    """fn() on m's random stream; an exception fails m alone (its traceback into its folder). -> ok."""
    try:
        with _own_rng(m):
            fn()
        return True
    except Exception as e:
        _fail(m, e, results, live)
        return False


def _fail(m: _Member, e: Exception, results: List[Optional[dict]], live: List[_Member]) -> None:
    tr = m.trainer
    tr.folder.write_error()  # the traceback of the exception being handled
    results[m.k] = {"error": e}
    if m in live:
        live.remove(m)
    with contextlib.suppress(Exception):
        tr.close_logs()
    with contextlib.suppress(Exception):
        tr.env.close()


def _update_round(due: List[_Member], results: List[Optional[dict]], live: List[_Member], fused: dict) -> None:
    """One update of every member in ``due``: batched where members share a key and a batch form."""
    groups: Dict[Tuple, List[Tuple[_Member, tuple]]] = {}
    for m in due:
        got = []
        if not _guard(m, results, live, lambda: got.append(m.trainer.sample())):
            continue
        batch, actor_batch, _ = got[0]
        form = (m.form, batch.weights is None, actor_batch is None) if m.form is not None else (id(m),)
        groups.setdefault(form, []).append((m, got[0]))
    for members in groups.values():
        if len(members) == 1:
            m, (batch, actor_batch, log_now) = members[0]
            _guard(m, results, live, lambda: m.trainer.apply_update(
                batch, *m.trainer.agent.update(batch, actor_batch, want_logs=log_now), log_now))
            continue
        _packed_update(members, results, live, fused)


def _packed_update(members: List[Tuple[_Member, tuple]], results, live, cache: dict) -> None:
    from .sac import matmul_precision
    from .sac_fused import FusedUpdate

    agents = [m.trainer.agent for m, _ in members]
    key = tuple(m.k for m, _ in members)
    fused = cache.get(key)
    if fused is None:
        fused = cache[key] = FusedUpdate(agents)

    def draw(i: int, shapes):
        with _own_rng(members[i][0]):
            return [torch.randn(s) for s in shapes]

    batches = [b for _, (b, _, _) in members]
    actor_batches = [ab for _, (_, ab, _) in members]
    try:
        with matmul_precision(agents[0].cfg.matmul_precision):
            tds, logs = fused.step_pack(batches, actor_batches, draw)
    except Exception as e:  # the batched update itself failed: every member of it
        for m, _ in members:
            _fail(m, e, results, live)
        return
    for (m, (batch, _, log_now)), td, lg in zip(members, tds, logs):
        _guard(m, results, live, lambda: m.trainer.apply_update(batch, td, lg if log_now else {}, log_now))
