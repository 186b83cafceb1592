"""The update strategy of ``train.train_runs``: the updates that are due, batched across runs into one.

Why: at small networks (the quick and reference presets' 64x64) one SAC update is mostly per-op overhead;
the same products of S agents in one batched call cost little more than one agent's (``bench/sweep_speed.py``
measures what that buys a sweep; ``sweep --pack S``). The env steps, evaluations and replay stay per run.

A run's results do not depend on its pack (``tests/test_pack.py``: metrics and weights bit for bit, alone and
packed; a pack killed mid-run resumes to the same metrics):
* each run owns its ``torch.Generator``, and a packed update draws each agent's noise from that agent's
  generator, in the order its own update would (``FusedUpdate.draw_shapes``);
* the batched products give each member what its own product gives (checked by the tests above on every
  variant and option; ``sac_fused.py`` keeps one agent's path unchanged);
* env, replay, optimizer, counters and run folder stay per run, so checkpoints and resume are per run.

Runs share an update when it is the same computation (``pack_key``: network shapes and the SAC settings the
batched update reads; lr, tau, the schedule and alpha's start stay per run) and their batches have the same
form (IS weights or not, an actor batch or not); a run alone is a group of one and updates on its own.
"""
from __future__ import annotations

import dataclasses
from typing import Callable, Dict, List, Optional, Tuple

from .config import RunConfig

# SACConfig fields that stay per agent in a packed update (its own Adam, Polyak step, schedule, alpha start)
PER_AGENT = ("lr", "tau", "alpha", "random_steps", "learning_starts", "update_schedule", "updates_per_step",
             "updates_per_episode", "log_every")


def pack_key(cfg: RunConfig) -> Optional[str]:
    """Runs with equal keys can share batched updates; None: this run updates alone (autograd or compiled
    updates, which the pack does not batch)."""
    s = cfg.sac
    if s.update_impl != "fused" or s.compile:
        return None
    shared = {k: v for k, v in dataclasses.asdict(s).items() if k not in PER_AGENT}
    return repr(sorted(shared.items())) + f"|{cfg.device}"


class Updater:
    """One update round at a time over the runs that are due (``train.Trainer``: ``k`` its index among the
    driver's runs, ``cfg``, ``agent``, ``sample()``, ``learn()``); keeps each set of runs' batched update (packs
    shrink as runs end)."""

    def __init__(self):
        self.fused: Dict[Tuple[int, ...], object] = {}
        self.forms: Dict[int, Optional[tuple]] = {}  # per run: (pack_key, parameter shapes), None: alone

    def _form(self, run) -> Optional[tuple]:
        if run.k not in self.forms:  # once per run, not per update
            key = pack_key(run.cfg)
            self.forms[run.k] = None if key is None else (key, tuple(p.shape for p in run.agent.parameters()))
        return self.forms[run.k]

    def round(self, due: list, fail: Callable[[object, Exception], None]) -> None:
        """One update of every run in ``due``; ``fail(run, e)`` writes off a run whose step raised."""
        groups: Dict[tuple, List[tuple]] = {}
        for run in due:
            try:
                batch, actor_batch, log_now = run.sample()
            except Exception as e:
                fail(run, e)
                continue
            form = self._form(run)
            key = (form, batch.weights is None, actor_batch is None) if form is not None else (run.k,)
            groups.setdefault(key, []).append((run, batch, actor_batch, log_now))
        for members in groups.values():
            if len(members) == 1:
                run, batch, actor_batch, log_now = members[0]
                try:
                    run.learn(batch, *run.agent.update(batch, actor_batch, want_logs=log_now), log_now)
                except Exception as e:
                    fail(run, e)
            else:
                self._packed(members, fail)

    def _packed(self, members: List[tuple], fail) -> None:
        from .sac import matmul_precision
        from .sac_fused import FusedUpdate

        agents = [run.agent for run, *_ in members]
        key = tuple(run.k for run, *_ in members)
        fused = self.fused.get(key)
        if fused is None:
            fused = self.fused[key] = FusedUpdate(agents)
        try:
            with matmul_precision(agents[0].cfg.matmul_precision):
                # the losses only when a member logs this update (reading them is per agent and term)
                tds, logs = fused.step_pack([b for _, b, _, _ in members], [ab for _, _, ab, _ in members],
                                            want_logs=any(log_now for *_, log_now in members))
        except Exception as e:  # the batched update itself failed: every member of it
            for run, *_ in members:
                fail(run, e)
            return
        for (run, batch, _, log_now), td, lg in zip(members, tds, logs):
            try:
                run.learn(batch, td, lg if log_now else {}, log_now)
            except Exception as e:
                fail(run, e)
