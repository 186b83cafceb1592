"""Training: one driver (``train_runs``) steps a list of runs; a run alone is a pack of one.

    python -m maniskill_dualher.train --preset quick --task ReachTarget-v1 --method dual_buffer --seed 0 --out runs/x

``train_runs`` reads top to bottom as the whole loop: every run acts, steps and stores one env step; the
updates that are due are made (batched across runs with equal networks and settings, ``pack.Updater``: that
is the only thing packing changes, besides runs evaluating at the same step side by side); every run
evaluates, checkpoints, pauses or finishes between episodes. A run (``Trainer``) is plain state with ``step()``
(-> its updates due), ``sample()``/``learn()`` around its update and ``between_episodes()`` (-> a ``Between``, what
is due) / ``evaluation()`` / ``after_step(between)``; it owns its env, replay, optimizer, counters, folder and its
``torch.Generator``, so its
metrics and weights do not depend on which runs share its process (``tests/test_pack.py``).

A run folder is the unit of truth: ``config.json``, ``metrics.csv`` (one row per evaluation),
TensorBoard events (``losses/*`` every ``log_every`` updates, ``charts/*`` and ``replay/*``),
``checkpoint.pt`` (and ``checkpoint.prev.pt`` while unfinished) and, once finished, ``done.json``
(``rundir.RunFolder`` keeps them). Running again on the same folder resumes from the checkpoint (a finished
run answers with its result; ``--continue RUN --total-steps N`` carries it on to N env steps, ``continued``);
because every training episode is reset with its own seed and checkpoints are taken between episodes together with
all random-number state and the counters (``counters.Counters``), a resumed run produces the same metrics
as an uninterrupted one (CPU simulation, one env).

Episodes end on success when ``terminate_on_success`` (the paper, section 4.1) or at ``max_episode_steps``;
with N parallel envs each env's episode ends on its own and goes to replay (with its hindsight goals) as soon
as it ends (``episodes.EnvEpisodes``: each env's clock and the episode arrays). Evaluation has its own
``EnvEpisodes``. The command line's flags and their RunConfig live in ``cli.py``.
"""
from __future__ import annotations

import dataclasses
import json
import math
import signal
import sys
import time
from pathlib import Path
from typing import Callable, Dict, Generator, List, Optional, Sequence

import numpy as np
import torch

from .config import ConfigError, RunConfig
from .counters import Counters
from .envs import EVAL_SEED_BASE, BatchEnv, make_env, train_episode_seed
from .episodes import EnvEpisodes, Score
from .faults import hold_point
from .pack import Updater
from .policy import save_policy
from .replay.base import Episode
from .replay.storage import consuming_loaded_state
from .rundir import CELL, CONFIG, POLICY, POLICY_BEST, RunFolder, array_state, load_checkpoint
from .sac import SAC
from .signals import checkpoint_on_signals, stop_asked

DEMO_SEED_BASE = 2_000_000_000

# progress(out_dir, env_steps, total_steps), called after every env step (the sweep's progress.json writer,
# experiment/backends.py: ProgressFile)
Progress = Callable[[Path, int, int], None]

class Diagnostics:
    """The learner's state on the batches it trained on, per batch source (R or E; R for single-buffer
    methods): mean |TD| over every update, and alpha, policy entropy, mean Q and the critic loss over the updates
    that log (every ``log_every``), averaged between evaluations. Reads what the update returns; changes nothing."""
    STATS = ("losses/alpha", "losses/entropy", "losses/qf_values", "losses/qf_loss")

    def __init__(self):
        self.rows: List[dict] = []
        self._win: dict = {}

    def add(self, batch, td_abs: np.ndarray, logs: Optional[dict]) -> None:
        src = getattr(batch.handle, "source", "R") or "R"
        w = self._win.setdefault(src, {"updates": 0, "td": 0.0, "logged": 0, **{k: 0.0 for k in self.STATS}})
        w["updates"] += 1
        w["td"] += float(np.mean(td_abs))
        if logs:
            w["logged"] += 1
            for k in self.STATS:
                w[k] += float(logs.get(k, float("nan")))

    def close_window(self, env_steps: int, updates: int) -> List[dict]:
        """One row for the window since the last evaluation; -> every row so far."""
        row = {"env_steps": env_steps, "updates": updates}
        for src, w in sorted(self._win.items()):
            row[f"{src}_updates"] = w["updates"]
            row[f"{src}_td_abs"] = round(w["td"] / w["updates"], 6)
            row[f"{src}_logged"] = w["logged"]
            for k in self.STATS:
                row[f"{src}_{k.split('/')[-1]}"] = round(w[k] / w["logged"], 6) if w["logged"] else ""
        self._win = {}
        self.rows.append(row)
        return self.rows

    def state_dict(self) -> dict:
        return {"rows": list(self.rows), "window": dict(self._win)}

    def load_state_dict(self, state: Optional[dict]) -> None:
        if state:
            self.rows, self._win = list(state["rows"]), dict(state["window"])



class TrainingDiverged(RuntimeError):
    """A loss or weight became NaN/inf: the run stops with one line, its last checkpoint intact."""


@dataclasses.dataclass
class Job:
    """One run: what ``train_runs`` takes per run (a chain stage: its parent folder and replay flags)."""
    cfg: RunConfig
    out: str
    init_from: Optional[str] = None
    carry_replay: bool = False
    keep_replay: bool = False
    extend: bool = False  # a finished run carried on to cfg.total_steps (``continued``)


@dataclasses.dataclass
class Between:
    """What is due between episodes: ``Trainer.between_episodes`` hands it to the loop, which makes the evaluation
    (side by side with other runs', ``evaluate_runs``) into ``evaluated``, and back to ``Trainer.after_step``."""
    finished: bool                     # the budget is spent
    stopping: bool                     # paused at the loop's stop_at
    checkpoint: bool                   # a checkpoint is due
    evaluate: bool                     # an evaluation is due
    evaluated: Optional[dict] = None   # its metrics (None: after_step evaluates itself)


# --------------------------------------------------------------------------- the loop
def drive(runs: Sequence["Trainer"], stop_at: Optional[int] = None, close_finished: bool = True) -> List[dict]:
    """The training loop, for any number of runs side by side (a run alone is a pack of one). -> per run
    ``{"row": final metrics}``, ``{"row": None}`` (paused at ``stop_at`` or by a stop signal, ``checkpoint_on_signals``:
    checkpointed) or ``{"error": e}``.
    A run that fails is written off alone (its traceback in its folder's ``error.txt``); the others go on.
    ``close_finished``: a finished run's env closes at once (a pack's memory); False keeps it for the caller."""
    results: List[Optional[dict]] = [None] * len(runs)
    live = list(runs)
    for k, run in enumerate(runs):
        run.k = k
        _guard(run, results, live, run.start)              # logs, demonstrations, the step-0 evaluation
        _settle(run, results, live, close_finished)
    updater = Updater()
    fail = lambda run, e: _fail(run, e, results, live)  # noqa: E731
    while live:
        # act, step, store: each run's updates due
        due = {run: _guard(run, results, live, run.step) for run in list(live)}
        for j in range(max((due[run] for run in live), default=0)):            # update when due
            updater.round([run for run in live if due[run] > j], fail)
        # between episodes: what is due (a Between, or None), episodes in flight cut
        between = {run: _guard(run, results, live, lambda: run.between_episodes(stop_at)) for run in list(live)}
        evaluating = [run for run in live if between[run] is not None and between[run].evaluate]
        for run, metrics in evaluate_runs(evaluating, fail).items():           # evaluations, side by side
            between[run].evaluated = metrics
        for run in list(live):                                                 # metrics, checkpoint, stop
            _guard(run, results, live, lambda: run.after_step(between[run]))
            _settle(run, results, live, close_finished)
    return results


def evaluate_runs(runs: Sequence["Trainer"],
                  fail: Callable[["Trainer", Exception], None]) -> Dict["Trainer", dict]:
    """The evaluations of ``runs`` -> each run's metrics (a run whose evaluation raised is left out and handed to
    ``fail(run, e)``). One run: ``Trainer.evaluate``. Several (a pack): their evaluation
    envs step side by side, one env step of every member in turn, each member acting with its own forward:
    the same env calls and actions as alone, so the same numbers. Not one batched forward across members:
    a stacked product is not bit-identical to the members' own on every machine (docs/speed.md)."""
    out: Dict["Trainer", dict] = {}
    if len(runs) == 1:
        try:
            out[runs[0]] = runs[0].evaluate()
        except Exception as e:
            fail(runs[0], e)
        return out
    steppers = []  # [run, its evaluation (generator), its forward, its policy input]
    for run in runs:
        try:
            gen = run.evaluation()
            steppers.append([run, gen, run.agent.deterministic_actor(), next(gen)])
        except Exception as e:
            fail(run, e)
    while steppers:
        going = []
        for s in steppers:
            run, gen, act, x = s
            try:
                s[3] = gen.send(act(x))
                going.append(s)
            except StopIteration as stop:
                out[run] = stop.value
            except Exception as e:
                fail(run, e)
        steppers = going
    return out


def _settle(run: "Trainer", results: List[Optional[dict]], live: List["Trainer"], close_finished: bool) -> None:
    """A run that paused or finished leaves the loop with its row (None: paused)."""
    if run.state != "running" and run in live:
        results[run.k] = {"row": run.final_row}
        live.remove(run)
        if run.state == "finished" and close_finished:
            run.close()


def _guard(run: "Trainer", results: List[Optional[dict]], live: List["Trainer"], fn):
    """fn()'s value; an exception fails this run alone (None)."""
    try:
        return fn()
    except Exception as e:
        _fail(run, e, results, live)
        return None


def _fail(run: "Trainer", e: Exception, results: List[Optional[dict]], live: List["Trainer"]) -> None:
    run.folder.write_error()  # the traceback of the exception being handled
    results[run.k] = {"error": e}
    if run in live:
        live.remove(run)
    run.close()


def run_one(run: "Trainer", stop_at: Optional[int] = None) -> Optional[dict]:
    """``drive`` of one run the caller built and keeps (tests, benches): its final row (None: paused); raises
    what stopped it. Its env stays open."""
    res = drive([run], stop_at, close_finished=False)[0]
    if "error" in res:
        raise res["error"]
    return res["row"]


_HEAP_FROZEN = False


def freeze_imports() -> None:
    """Once per process, before its first run is built: every object alive now (the imported modules of torch,
    ManiSkill and SAPIEN, ~460k objects) goes out of the garbage collector's reach (``gc.freeze``). ManiSkill
    calls ``gc.collect()`` when it builds and when it closes an env, and each full collection scanned them all
    (~0.2 s, twice per run; docs/speed.md); now it scans what the runs made. In a sweep worker or ``train``
    nothing else is alive yet, and modules live as long as the process, so nothing stays that would have been
    freed (in a longer-lived process, garbage alive at the first call would); no number changes. torch.optim imports ``torch._dynamo``
    at an optimizer's first step anyway (its ``_disable_dynamo`` wrapper): imported here, it is frozen too."""
    global _HEAP_FROZEN
    if _HEAP_FROZEN:
        return
    import gc

    import torch._dynamo  # noqa: F401
    import maniskill_dualher.tasks  # noqa: F401  (make_env imports it: ManiSkill, SAPIEN)
    gc.freeze()
    _HEAP_FROZEN = True


def train_runs(jobs: Sequence[Job], stop_at: Optional[int] = None, progress: Optional[Progress] = None,
               show_progress: bool = False) -> List[dict]:
    """Train (or resume, or return the result of) every job in this process: each job's run opened, then
    ``drive``. -> per job as ``drive``; a refused config (ConfigError before the run exists; a finished run's
    folder refuses another config too) writes nothing into a folder that may hold another run. A kill or
    interrupt leaves every run's last checkpoint standing."""
    freeze_imports()
    results: List[Optional[dict]] = [None] * len(jobs)
    runs: List[Trainer] = []
    jobs = [Job(**j) if isinstance(j, dict) else j for j in jobs]  # the sweep's workers pass plain dicts
    try:
        for k, job in enumerate(jobs):
            folder = RunFolder(job.out)
            if folder.done and not job.extend:
                try:  # a finished run of another config is refused as an unfinished one is
                    folder.check_identity(job.cfg.to_json())
                    results[k] = {"row": folder.final()}
                except ConfigError as e:
                    results[k] = {"error": e}
                continue
            try:
                runs.append(Trainer(job.cfg, job.out, init_from=job.init_from, carry_replay=job.carry_replay,
                                    keep_replay=job.keep_replay, progress=progress, show_progress=show_progress,
                                    extend=job.extend))
            except Exception as e:
                if not isinstance(e, ConfigError):
                    folder.write_error()
                results[k] = {"error": e}
        todo = [k for k, r in enumerate(results) if r is None]
        for k, r in zip(todo, drive(runs, stop_at)):
            if r.get("row", 0) is None and stop_asked() is not None:
                r["stopped"] = stop_asked()
            results[k] = r
    finally:
        for run in runs:
            run.close()
    return results


def run_training(cfg: RunConfig, out_dir, init_from=None, carry_replay: bool = False,
                 show_progress: bool = True, stop_at: Optional[int] = None, keep_replay: bool = False,
                 progress: Optional[Progress] = None) -> Optional[dict]:
    """One run: ``train_runs`` of one job. Returns its final metrics row (None if ``stop_at`` paused it);
    raises what stopped it."""
    job = Job(cfg, str(out_dir), None if init_from is None else str(init_from), carry_replay, keep_replay)
    return run_job(job, stop_at=stop_at, progress=progress, show_progress=show_progress)


def run_job(job: Job, show_progress: bool = True, stop_at: Optional[int] = None,
            progress: Optional[Progress] = None) -> Optional[dict]:
    """``run_training`` of a ``Job`` (``continued``'s)."""
    res = train_runs([job], stop_at=stop_at, progress=progress, show_progress=show_progress)[0]
    if "error" in res:
        raise res["error"]
    return res["row"]


def continued(run_dir, total_steps: int) -> Job:
    """``train --continue RUN --total-steps N``: the finished run in ``run_dir`` carried on from its final
    checkpoint (networks, optimizer, replay, counters, random streams) to N env steps, as one run whose
    config.json then says N. It equals a run planned at N from the start where the old budget ended between
    episodes at an evaluation (fixed-length episodes of a length dividing it; ``eval_every`` dividing it) and
    nothing read the budget before: PER's importance-sampling exponent is annealed over ``total_steps``
    (``set_progress``), so with ``replay.is_weights`` on (off by default) the old steps' weights differ; on a
    task with contact (CloseBox, CloseMicrowave) the fresh env's PhysX state differs by rounding, as after any
    resume. Bad input is a ConfigError naming it, before anything is written."""
    folder = RunFolder(run_dir)
    old = folder.config()
    if old is None or not folder.done:
        raise ConfigError(f"--continue {run_dir}: " + ("no run there" if old is None else
                          f"its run has not finished; resume it with --config {folder.path / CONFIG} "
                          f"--out {run_dir}"))
    if (folder.path / CELL).is_file():  # the sweep's report would mix budgets in its cell
        raise ConfigError(f"--continue {run_dir}: a sweep's run (cell.json), whose budget is the sweep's; "
                          "continue a copy of it without cell.json")
    cfg = RunConfig.from_dict(old)
    if total_steps <= cfg.total_steps:
        raise ConfigError(f"--total-steps {total_steps}: not more than the {cfg.total_steps} env steps "
                          f"{run_dir} has done")
    cfg.total_steps = int(total_steps)
    # it keeps its replay again, to be continued again (as it was kept for this)
    return Job(cfg, str(folder.path), keep_replay=True, extend=True)


def train_chain(stages: List[RunConfig], out_dir, carry_replay: bool = True,
                show_progress: bool = True) -> List[dict]:
    """A transfer chain (``experiment/protocol.py``) in ``out_dir``, stage by stage; finished stages are
    skipped, an interrupted one resumes. Returns each stage's final metrics row."""
    from .experiment import protocol

    protocol.validate_chain(stages)
    rows = []
    for i in range(len(stages)):
        job = protocol.stage_job(stages, i, out_dir, carry_replay)
        rows.append(run_training(job.pop("cfg"), job.pop("out"), show_progress=show_progress, **job))
    return rows


# --------------------------------------------------------------------------- one run
class Trainer:
    """One run's state and its steps (``train_runs`` drives them): ``start``; per env step ``step`` (act, step,
    store; returns the updates due), that many times ``sample`` -> the update -> ``learn``, and between episodes
    ``between_episodes`` (returns what is due, a ``Between``), the evaluation (``evaluate``, or ``evaluation``
    stepped beside other runs', ``evaluate_runs``) and ``after_step(between)`` (metrics, checkpoint, pause or
    finish; sets ``state`` and ``final_row``, the run's outcome); ``close``."""

    def __init__(self, cfg: RunConfig, out_dir, init_from=None, carry_replay: bool = False,
                 show_progress: bool = True, keep_replay: bool = False, progress: Optional[Progress] = None,
                 extend: bool = False):
        from .methods import make_method  # late: methods import replay pieces

        self.cfg = cfg.validate()
        if carry_replay and not cfg.replay.carry_rows:
            raise ConfigError("--carry-replay asks for the prior's replay rows, but this config's replay.carry_rows "
                              "is false (it starts from the prior's networks only): drop one of the two")
        self.folder = RunFolder(out_dir)
        self.out = self.folder.path
        self.show_progress = show_progress
        self.progress = progress
        self.keep_replay = keep_replay  # a finished run keeps its replay only if a later stage reads it
        self.folder.check_identity(cfg.to_json(), ignore=("total_steps",) if extend else ())
        init_state = load_checkpoint(Path(init_from)) if init_from is not None else None
        state = None
        if extend:  # a finished run carried on (``continued``): its final checkpoint, replay included
            state = self.folder.load_checkpoint()
            if state["method"] is None:
                raise ConfigError(f"--continue {self.out}: its checkpoint holds no replay (it finished without "
                                  "--keep-replay), so it cannot go on as the same run; train it with --keep-replay")

        torch.set_num_threads(cfg.torch_threads)
        # this run's torch random stream (network init, exploration, the update's draws): seeded as
        # torch.manual_seed(seed) seeds the global one, so the numbers are those of a run on the global stream
        self.gen = torch.Generator().manual_seed(cfg.seed)
        self.device_gen = self.gen if torch.device(cfg.device).type == "cpu" else \
            torch.Generator(device=cfg.device).manual_seed(cfg.seed)
        self.rng = np.random.default_rng(cfg.seed)
        self.env: BatchEnv = make_env(cfg)
        self.spec = self.env.spec
        self.method = make_method(cfg, self.spec, np.random.default_rng([cfg.seed, 1]), device=cfg.device)
        self.agent = SAC(self.spec.input_dim, self.spec.act_dim, cfg.sac, device=cfg.device,
                         init_generator=self.gen, generator=self.device_gen)
        self._act = None  # acting's bare forward (stochastic_actor), made at the first policy action
        self.train_eps = EnvEpisodes(self.env, cfg.terminate_on_success)
        self.eval_eps = EnvEpisodes(self.env, cfg.terminate_on_success)  # its own clock and arrays
        self.count = Counters()
        self.rows: List[dict] = []  # metrics.csv: one per evaluation
        self.diag = Diagnostics()   # diagnostics.csv: the learner's logs per batch source (R or E)
        self.resumed = False
        self.k = 0                  # its index among the driver's jobs
        self.ended = np.zeros(self.spec.num_envs, dtype=bool)  # which envs' episodes ended this step
        self.state = "running"      # then "paused" (at stop_at) or "finished"
        self.final_row: Optional[dict] = None
        self.tb = self.bar = None
        if state is not None or self.folder.has_checkpoint:
            self._restore(state if state is not None else self.folder.load_checkpoint())
            self.resumed = True
        elif init_state is not None:
            self._init_from(init_state, carry_replay)
        continued_from = None
        if extend:
            continued_from = self.folder.config()["total_steps"]
            # done.json goes before config.json changes: a kill between them leaves the old run, unfinished at
            # its own budget, which its own command finishes again at once
            self.folder.reopen()
        self.folder.record_start(cfg.to_json(), init_from, carry_replay, continued_from)

    # counters by name, for callers that read a trainer (benches)
    env_steps = property(lambda self: self.count.env_steps)
    updates = property(lambda self: self.count.updates)
    episodes = property(lambda self: self.count.episodes)
    successes = property(lambda self: self.count.successes)

    def _init_from(self, state: dict, carry_replay: bool) -> None:
        """Transfer: start from another run's final networks (and, optionally, its replay)."""
        try:
            self.agent.load_full_state(state["agent"], networks_only=True)
        except (RuntimeError, KeyError) as e:
            raise ConfigError(f"init_from networks do not fit {self.cfg.env_id!r}: {str(e).splitlines()[0]}") from None
        if not self.cfg.sac.resolved_learn_alpha():
            # a fixed temperature is a setting, not learned state: this stage's alpha, whatever the prior learned
            # (the same bits where the prior's was fixed at the same value)
            with torch.no_grad():
                self.agent.log_alpha.fill_(math.log(self.cfg.sac.alpha))
        if carry_replay:
            if state.get("method") is None:
                raise ConfigError("init_from checkpoint holds no replay buffers (its run did not keep them); "
                                  "rerun it, or transfer without carrying replay")
            self.method.load_transfer_state(array_state(state["method"]))
            self.method.on_transfer()
            self.method.reseed(np.random.default_rng([self.cfg.seed, 1]))  # keep this run's own sampling stream

    # ------------------------------------------------------------ checkpoint
    def _state(self) -> dict:
        """Everything a resume needs. The replay's arrays are views of the live buffers, not copies (the
        checkpoint file streams them, ``rundir.file_state``): write it before the next step."""
        state = {"config": self.cfg.to_dict(), "agent": self.agent.full_state(), "method": self.method.state_dict(),
                 "counters": self.count.state_dict(), "rows": self.rows, "diag": self.diag.state_dict(),
                 "rng": self.rng.bit_generator.state,
                 "torch_rng": self.gen.get_state()}
        if self.device_gen is not self.gen:
            state["torch_rng_device"] = self.device_gen.get_state()
        return state

    def _restore(self, state: dict) -> None:
        self.agent.load_full_state(state["agent"])
        # the replay lives in numpy; taken out of the state so that loading moves it into the buffers field by
        # field instead of holding the file's copy beside them (GBs at R = 10^7 rows)
        replay = array_state(state.pop("method"))
        with consuming_loaded_state():
            self.method.load_state_dict(replay)
        del replay
        self.count = Counters.from_state(state["counters"])
        self.rows = list(state["rows"])
        self.diag.load_state_dict(state.get("diag"))
        self.rng.bit_generator.state = state["rng"]
        self.gen.set_state(state["torch_rng"])
        if self.device_gen is not self.gen and "torch_rng_device" in state:
            self.device_gen.set_state(state["torch_rng_device"])

    def save_checkpoint(self, replay: bool = True) -> None:
        """Write the checkpoint; ``replay=False`` leaves the replay buffers out (a finished run nobody resumes)."""
        state = self._state()
        if not replay:
            state["method"] = None
        self.folder.save_checkpoint(state, keep_previous=replay)

    # ------------------------------------------------------------ the steps train_runs drives
    def start(self) -> None:
        """Logs open; a fresh run's demonstrations and step-0 evaluation; every env starts a fresh episode.
        A run whose budget is already spent (killed between its last checkpoint and done.json) finishes. A run
        paused at ``stop_at`` and driven again goes on from where it paused (the benches drive runs in slices)."""
        c = self.count
        self.state = "running"
        self._open_logs()
        if not self.resumed and c.env_steps == 0:
            self._collect_demos()
            if self.cfg.eval_at_start:  # the starting policy's score (a transfer stage: the prior, zero-shot)
                self._eval_row()
        self._t0 = time.perf_counter() - c.wall_time
        self.train_eps.restart()  # also after a resume
        if c.env_steps >= self.cfg.total_steps:
            self._close_logs()
            self.final_row, self.state = self.finish(), "finished"

    def step(self) -> int:
        """One step of every env: act, step, count, store the episodes that ended -> how many updates are due."""
        eps = self.train_eps
        self._begin_episodes()
        action = self._explore(self.env.policy_input(eps.flat))
        self.ended = eps.step(action)
        self._count_steps(eps.n_envs)
        for ep in eps.finished(self.ended):
            self._store(ep)
        return self._updates_due(eps.n_envs, int(self.ended.sum()))

    def sample(self):
        """The next update's batches -> (batch, actor batch or None, whether this update logs)."""
        s = self.cfg.sac
        batch = self.method.sample(s.batch_size)
        actor_batch = self.method.sample_uniform(s.batch_size) if s.actor_uniform_batch else None
        return batch, actor_batch, self.count.updates % s.log_every == 0

    def learn(self, batch, td_abs: np.ndarray, logs: dict, log_now: bool) -> None:
        """What follows the agent's update: priorities, the count, the logs (a diverged loss stops the run)."""
        c = self.count
        self.method.update_priorities(batch, td_abs)
        c.updates += 1
        self.diag.add(batch, td_abs, logs if log_now else None)
        if log_now:
            bad = [k for k, v in logs.items() if not math.isfinite(v)]
            if bad:
                raise TrainingDiverged(f"{bad[0]} became {logs[bad[0]]} at update {c.updates} "
                                       f"(env step {c.env_steps}); the last good checkpoint is kept in {self.out}")
            for k, v in logs.items():
                self.tb.add_scalar(k, v, c.env_steps)
            for k, v in self.method.stats().items():
                self.tb.add_scalar(f"replay/{k}", v, c.env_steps)

    def between_episodes(self, stop_at: Optional[int]) -> Optional[Between]:
        """After a step, between episodes (an episode ended, or the budget is spent): what is due (None: nothing;
        an evaluation, which ``drive`` makes, side by side with other runs', into its ``evaluated``), and the
        episodes in flight stored cut when an evaluation or checkpoint is due. ``after_step`` does the rest."""
        c = self.count
        finished = c.env_steps >= self.cfg.total_steps
        if not (self.ended.any() or finished):
            return None
        stopping = ((stop_at is not None and c.env_steps >= stop_at) or stop_asked() is not None) and not finished
        due = Between(finished, stopping, checkpoint=c.env_steps >= self._next_ckpt or finished or stopping,
                      evaluate=c.env_steps >= self._next_eval or finished)
        if due.evaluate or due.checkpoint:
            for ep in self.train_eps.cut_in_flight():
                self._store(ep)
        if due.evaluate:
            c.wall_time = time.perf_counter() - self._t0
        return due

    def after_step(self, due: Optional[Between]) -> None:
        """The rest of ``between_episodes`` (``due``, its value): the evaluation's row (its metrics in
        ``due.evaluated``, else evaluated here), the checkpoint when due; pause at ``stop_at`` or finish
        (``state``; ``final_row``)."""
        if due is None:
            return
        c = self.count
        finished, stopping = due.finished, due.stopping
        if due.evaluate:
            row = self._eval_row(due.evaluated)
            self.bar.set_postfix(success=f"{row['eval_success_rate']:.2f}", ret=f"{row['eval_return']:.1f}")
            self._next_eval = self._next(self.cfg.eval_every)
        if due.checkpoint:
            c.wall_time = time.perf_counter() - self._t0
            self._check_finite()
            self.save_checkpoint()
            hold_point(f"checkpoint:{self.out}")  # the scale-out tests remove a worker here
            self._next_ckpt = self._next(self.cfg.checkpoint_every)
        if stopping:
            self._close_logs()
            self.state = "paused"
        elif finished:
            self._close_logs()
            self.final_row, self.state = self.finish(), "finished"

    def finish(self) -> dict:
        final = dict(self.rows[-1])
        self.folder.finish(final, demo_env_steps=self.count.demo_env_steps)
        if not self.keep_replay:  # after done.json: a kill before it still leaves a resumable checkpoint
            self.save_checkpoint(replay=False)
        else:
            self.folder.drop_previous_checkpoint()
        return final

    def close(self) -> None:
        """Logs and env closed (idempotent; a failed or interrupted run's checkpoint stands)."""
        for close in (self._close_logs, self.env.close):
            try:
                close()
            except Exception:
                pass
        self.env.close = lambda: None  # once

    # ------------------------------------------------------------ pieces of the steps
    def _open_logs(self) -> None:
        from torch.utils.tensorboard import SummaryWriter
        from tqdm import tqdm
        cfg = self.cfg
        # purged: what a killed process logged after the checkpoint, from the next env step on (the
        # checkpoint's own evaluation, logged at its step, stays)
        self.tb = SummaryWriter(str(self.out), purge_step=self.count.env_steps + 1 if self.resumed else None)
        if not self.resumed:
            self.tb.add_text("config", "```\n" + cfg.to_json() + "\n```", 0)
        self.bar = tqdm(total=cfg.total_steps, initial=self.count.env_steps, disable=not self.show_progress,
                        desc=f"{cfg.method} {cfg.env_id} seed {cfg.seed}", unit="step", dynamic_ncols=True,
                        leave=False)
        self._next_eval = self._next(cfg.eval_every)
        self._next_ckpt = self._next(cfg.checkpoint_every)

    def _close_logs(self) -> None:
        if self.bar is not None:
            self.bar.close()
        if self.tb is not None:
            self.tb.close()
        self.tb = self.bar = None

    def _next(self, every: int) -> int:
        return (self.count.env_steps // every + 1) * every

    def _begin_episodes(self) -> None:
        """Reset the envs whose episode ended; each new training episode gets its own seed (exact resume)."""
        idx = np.flatnonzero(self.train_eps.pending)
        if len(idx):
            seeds = [train_episode_seed(self.cfg.seed, self.count.started + k) for k in range(len(idx))]
            self.count.started += len(idx)
            self.train_eps.reset(idx, seeds)

    def _count_steps(self, n: int) -> None:
        self.count.env_steps += n
        self.bar.update(n)
        if self.progress is not None:
            self.progress(self.out, self.count.env_steps, self.cfg.total_steps)

    def _explore(self, x: np.ndarray) -> np.ndarray:
        if self.count.env_steps < self.cfg.sac.random_steps:
            return self.rng.uniform(-1.0, 1.0, (x.shape[0], self.spec.act_dim)).astype(np.float32)
        if self._act is None:  # bare weights (views: an update shows through), built once per run
            self._act = self.agent.stochastic_actor()
        return self._act(x)

    def _store(self, ep: Episode) -> None:
        c = self.count
        self.method.add_episode(ep)
        self.method.set_progress(min(1.0, c.env_steps / self.cfg.total_steps))
        c.episodes += 1
        c.successes += int(ep.success.any())
        c.episode_steps_total += ep.length

    def _updates_due(self, n_steps: int, n_ended: int) -> int:
        """How many gradient updates this env step buys under the configured schedule."""
        s, c = self.cfg.sac, self.count
        if c.env_steps < s.learning_starts or not self.method.has_data():
            return 0
        c.update_credit += n_steps * s.updates_per_step if s.update_schedule == "step" \
            else n_ended * s.updates_per_episode
        due = int(c.update_credit)
        c.update_credit -= due
        return due

    def _check_finite(self) -> None:
        for name, p in self.agent.named_parameters():
            if not bool(torch.isfinite(p).all()):
                raise TrainingDiverged(f"network weights {name} are not finite at env step {self.count.env_steps}; "
                                       f"the last good checkpoint is kept in {self.out}")

    # ------------------------------------------------------------ evaluation, demonstrations
    def evaluation(self) -> Generator[np.ndarray, np.ndarray, dict]:
        """The evaluation's episodes (deterministic policy on fixed seeds shared by every run, EVAL_SEED_BASE + i)
        as a generator of policy inputs that is sent the actions (``episodes.EnvEpisodes.scores``, on the
        evaluation's own episodes); returns the metrics. It resets the simulator, so the training episodes
        start anew afterwards."""
        n, N = self.cfg.eval_episodes, self.spec.num_envs
        scores: List[Score] = []
        for i in range(math.ceil(n / N)):
            scores += yield from self.eval_eps.scores(EVAL_SEED_BASE + i * N)
        self.train_eps.restart()
        scores = scores[:n]
        return {"eval_return": float(np.mean([e.ret for e in scores])),
                "eval_success_rate": float(np.mean([e.success for e in scores])),
                "eval_success_at_end": float(np.mean([e.success_at_end for e in scores])),
                "eval_episode_length": float(np.mean([e.length for e in scores]))}

    def evaluate(self) -> dict:
        """This run's evaluation metrics (``evaluation`` driven by the agent's bare deterministic forward)."""
        gen, act = self.evaluation(), self.agent.deterministic_actor()
        x = next(gen)
        while True:
            try:
                x = gen.send(act(x))
            except StopIteration as stop:
                return stop.value

    def _rollout(self, seed: int, policy) -> List[Episode]:
        """Whole episodes of all N envs from one reset, on the evaluation's episodes (tests, demonstrations)."""
        out = self.eval_eps.rollout(seed, policy)
        self.train_eps.restart()
        return out

    def _collect_demos(self) -> None:
        """Seed the success buffer with scripted-solver successes (an option the paper does not have)."""
        want = self.cfg.replay.solver_demos
        if want <= 0:
            return
        if not self.method.accepts_demos:
            raise ConfigError(f"solver_demos={want}: method {self.cfg.method!r} has no success buffer to seed")
        solver = self.env.solver()
        if solver is None:
            raise ConfigError(f"solver_demos={want}: {self.cfg.env_id!r} has no scripted solver")
        got = 0
        for i in range(3 * want):
            for ep in self._rollout(DEMO_SEED_BASE + i * self.spec.num_envs,
                                    lambda x: _solver_action(solver, self.env)):
                self.count.demo_env_steps += ep.length
                if ep.success.any() and got < want:
                    self.method.add_demo_episode(ep)
                    got += 1
            if got >= want:
                break

    def _eval_row(self, evaluated: Optional[dict] = None) -> dict:
        """The evaluation's row (``evaluated``: its metrics, already made; None: evaluate now) and its outputs."""
        c = self.count
        row = {"env_steps": c.env_steps, **(self.evaluate() if evaluated is None else evaluated),
               "train_episodes": c.episodes,
               "train_successes": c.successes, "updates": c.updates,
               "train_episode_length": round(c.episode_steps_total / max(1, c.episodes), 3),
               "wall_time_s": round(c.wall_time, 2)}
        row.update({(k if k.startswith("replay_") else f"replay_{k}"): v for k, v in self.method.stats().items()})
        self.rows.append(row)
        for k, v in row.items():
            if k != "env_steps" and isinstance(v, (int, float)) and not k.startswith("replay_"):
                self.tb.add_scalar(f"charts/{k}", v, c.env_steps)
        self.folder.write_metrics(self.rows)
        self.folder.write_diagnostics(self.diag.close_window(c.env_steps, c.updates))
        self._train_charts(row)
        self._save_policies(row["eval_success_rate"])
        return row

    def _train_charts(self, row: dict) -> None:
        """TensorBoard only (not metrics.csv): training success rate and env steps/s since the last evaluation."""
        c = self.count
        self.tb.add_scalar("charts/train_success_rate", c.successes / max(1, c.episodes), c.env_steps)
        prev = self.rows[-2] if len(self.rows) > 1 else {"env_steps": 0, "wall_time_s": 0.0}
        dt = float(row["wall_time_s"]) - float(prev["wall_time_s"])
        if dt > 0:
            self.tb.add_scalar("charts/env_steps_per_s", (c.env_steps - prev["env_steps"]) / dt, c.env_steps)

    def _save_policies(self, success: float) -> None:
        """policy.pt at every evaluation; policy_best.pt when it beats every earlier one (a tie keeps the earlier)."""
        control_mode = getattr(getattr(self.env, "unwrapped", None), "control_mode", None)
        policy = dict(spec=self.spec, cfg=self.cfg, env_steps=self.count.env_steps, eval_success=success,
                      control_mode=control_mode)
        save_policy(self.agent, self.out / POLICY, **policy)
        if success > self.count.best_eval_success:
            self.count.best_eval_success = float(success)
            save_policy(self.agent, self.out / POLICY_BEST, **policy)


def _solver_action(solver, env: BatchEnv) -> np.ndarray:
    """Solver actions in the policy's [-1, 1] convention (the solver returns env-scaled actions)."""
    a = solver.act(None)
    a = a.detach().cpu().numpy() if hasattr(a, "detach") else np.asarray(a)
    a = a.reshape(env.num_envs, -1).astype(np.float32)
    return 2.0 * (a - env.low) / np.maximum(env.high - env.low, 1e-8) - 1.0




# --------------------------------------------------------------------------- python -m maniskill_dualher.train
# (the flags and how they become a RunConfig live in cli.py)
from .cli import (NO_PRESET_NOTE, continue_request, printed_config, train_config as config_from_args,  # noqa: E402
                  train_parser as build_parser)


def _say_once(line: str) -> Progress:
    """A progress callback that writes ``line`` to stderr at the run's first env step (past every check of its
    input, so bad input stays one line), above the progress bar."""
    said = []

    def progress(out, env_steps, total):
        if not said:
            said.append(True)
            from tqdm import tqdm
            tqdm.write(line, file=sys.stderr)
    return progress


def main(argv=None) -> int:
    """One run (or its resume, or a finished run carried on with --continue); prints its final metrics row as
    JSON (a run found finished: and one line on stderr saying so); bad input: one line, exit code 2; stopped by a
    signal (``signals.py``): checkpointed at the end of its episode, one line, exit code 128 + the signal."""
    args = build_parser().parse_args(argv)
    with checkpoint_on_signals():
        return _train_main(args, argv)


def _train_main(args, argv) -> int:
    try:
        if args.print_config:
            print(printed_config(args, sys.argv[1:] if argv is None else list(argv)), end="")
            return 0
        again = continue_request(args)
        if again is not None:
            final = run_job(continued(*again), show_progress=not args.no_progress)
        else:
            cfg = config_from_args(args)
            was_done = RunFolder(args.out).done
            final = run_training(cfg, args.out, init_from=args.init_from, carry_replay=args.carry_replay,
                                 show_progress=not args.no_progress, keep_replay=args.keep_replay,
                                 progress=None if args.preset or args.config else _say_once(NO_PRESET_NOTE))
            if was_done:
                print(f"{args.out} holds this run, finished at {final['env_steps']} env steps: its results are "
                      f"in {Path(args.out) / 'metrics.csv'} and done.json", file=sys.stderr)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except TrainingDiverged as e:  # a failed run, not bad input
        print(f"error: {e}", file=sys.stderr)
        return 1
    if final is None and stop_asked() is not None:  # 128 + the signal, as the shell reports a killed command
        how = ("the same command resumes" if again is None else   # the folder is no longer a finished run
               f"resume with --config {Path(again[0]) / CONFIG} --out {again[0]}")
        print(f"stopped by {stop_asked()} at the end of an episode: checkpointed in "
              f"{args.out if again is None else again[0]}; {how}", file=sys.stderr)
        return 128 + int(getattr(signal, stop_asked()))
    print(json.dumps(final))
    return 0


if __name__ == "__main__":
    sys.exit(main())
