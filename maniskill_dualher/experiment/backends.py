"""Where runs execute: a local process pool, Ray, or inline; and the scheduler that feeds them.

``run_grid`` starts every unfinished run whose parent is finished, long chains first, and never lets one
failed run stop the others. A backend has ``submit(payload)``, ``wait(handles[, timeout])``,
``result(handle)`` and ``close()``; a payload is a plain dict (``grid.Node.payload``) that ``execute`` runs
in any process.

Lost workers: a run whose process (or node) dies, as opposed to a run that raises, is run again from its
last checkpoint up to ``retries`` times. Ray does this itself (``max_retries``; a Python exception is not
retried); the local pool, which breaks as a whole when one worker dies, is rebuilt and every run that was
in flight is submitted again. Progress: a worker writes ``progress.json`` (its env steps) into its run
folder every few seconds and ``run_grid`` reads those while it waits, so the sweep's bar (and its ETA)
moves during long runs, on every backend (Ray through the shared filesystem).

A stop signal (SIGTERM, SIGUSR1, SIGINT; ``signals.py``) to the sweep stops it cleanly on the local pool and inline:
no run starts, the runs in flight checkpoint at the end of their episode (the pool's workers get it as SIGUSR1),
and ``run_grid`` raises ``SweepStopped``; the same command resumes. On Ray the sweep stops at once, as on Ctrl-C
before, and its runs resume from their last checkpoints.

``emit_commands`` writes the grid as ``python -m maniskill_dualher.train`` command lines instead (a SLURM
job array, ``docs/cluster.md``).
"""
from __future__ import annotations

import contextlib
import inspect
import json
import os
import shlex
import signal
import socket
import time
from pathlib import Path
from typing import Callable, Dict, List, Optional

from .. import rundir
from ..config import RunConfig
from ..fileio import atomic_write_text, plural
from ..signals import checkpoint_on_signals, stop_asked
from . import protocol
from .grid import Node, job_for

PROGRESS = "progress.json"      # {"env_steps", "total_steps", "pid", "host", "time"}: a run in flight
PROGRESS_EVERY_S = 2.0          # a worker writes it at most this often
POLL_S = 1.0                    # run_grid reads the files of runs in flight this often
DEFAULT_RETRIES = 2             # runs again a run whose worker or node died


class WorkerLost(RuntimeError):
    """The process or node running a run died (killed, out of memory, node lost): not an error of the run.

    ``retryable``: whether ``run_grid`` may submit it again (False where the backend has already retried)."""

    def __init__(self, msg: str, retryable: bool = True):
        super().__init__(msg)
        self.retryable = retryable


# ----------------------------------------------------------------------------- in the worker
class SweepStopped(Exception):
    """A stop signal reached the sweep: ``runs``, those in flight, checkpointed at the end of their episode."""

    def __init__(self, signal_name: str, runs: List[str]):
        super().__init__(f"stopped by {signal_name}")
        self.signal_name, self.runs = signal_name, runs

    @property
    def exit_code(self) -> int:  # as a shell reports a command killed by it
        return 128 + int(getattr(signal, self.signal_name))


class ProgressFile:
    """``Trainer.progress_hook``: writes ``<run>/progress.json`` at most every ``every_s`` seconds (and at
    the budget's end), atomically; ``listener()`` is called after each write (the inline backend's bar)."""

    def __init__(self, every_s: float = PROGRESS_EVERY_S, listener: Optional[Callable[[], None]] = None):
        self.every_s, self.listener = every_s, listener
        self.last: Dict[str, float] = {}  # per run folder: a pack's runs share one hook
        self.who = {"pid": os.getpid(), "host": socket.gethostname()}

    def __call__(self, out, env_steps: int, total_steps: int) -> None:
        now = time.monotonic()
        last = self.last.get(str(out))
        if last is not None and now - last < self.every_s and env_steps < total_steps:
            return
        self.last[str(out)] = now
        try:
            atomic_write_text(Path(out) / PROGRESS, json.dumps(
                {"env_steps": int(env_steps), "total_steps": int(total_steps), **self.who,
                 "time": round(time.time(), 3)}) + "\n")
        except OSError:  # progress is a courtesy: it never stops a run
            return
        if self.listener is not None:
            self.listener()


def read_progress(run_dir) -> Optional[dict]:
    """A run folder's ``progress.json``, or None (absent, or unreadable)."""
    try:
        d = json.loads((Path(run_dir) / PROGRESS).read_text())
        return d if isinstance(d, dict) else None
    except (OSError, ValueError):
        return None


def _worker_init(parent_pid: int) -> None:
    """Pool worker start: one torch thread (deterministic, polite); die with the sweep process."""
    try:
        import ctypes
        import signal
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
    except Exception:  # not Linux: orphans finish their run, resume stays correct
        pass
    if os.getppid() != parent_pid:
        os._exit(1)
    # An idle worker that died of a terminal's Ctrl-C (sent to the whole process group) would break the pool:
    # a worker takes SIGINT and SIGUSR1 only while it runs (``execute``; the sweep passes its stop on as
    # SIGUSR1). SIGTERM keeps its default: the pool ends a broken pool's workers with it.
    for name in ("SIGINT", "SIGUSR1"):
        signal.signal(getattr(signal, name), signal.SIG_IGN)
    import torch
    torch.set_num_threads(1)


def execute(payload: dict, train: Callable, listener: Optional[Callable[[], None]] = None,
            take_signals: bool = False) -> dict:
    """Run one grid node (in a worker) with ``train`` (``train.train_runs``, handed in by the entry point
    ``maniskill_dualher/sweep.py``: the experiment layer does not import the training code) and return its
    final metrics row; a pack payload (``{"pack": [node payloads]}``, ``run_grid(pack=S)``) runs its nodes side
    by side and returns each one's row or error: ``{"pack": [{"rel", "row"} | {"rel", "error"}]}``; with
    ``take_signals`` (a pool worker), a stop signal checkpoints its runs and they return ``{"rel", "stopped"}``."""
    import torch
    torch.set_num_threads(1)
    progress = ProgressFile(listener=listener)
    members = payload["pack"] if "pack" in payload else [payload]
    jobs, out = [], []
    for p in members:
        try:
            jobs.append(job_for(p))
            out.append({"rel": p["rel"]})
        except Exception as e:  # a stage whose parent is not there: that node alone fails
            if "pack" not in payload:
                raise
            out.append({"rel": p["rel"], "error": _error_line(e)})
    with checkpoint_on_signals() if take_signals else contextlib.nullcontext():
        res = iter(train(jobs, progress=progress))  # jobs as dicts of train.Job's fields
    for o in out:
        if "error" not in o:
            r = next(res)
            if "error" in r and "pack" not in payload:
                raise r["error"]
            if "error" in r:
                o["error"] = _error_line(r["error"])
            elif r["row"] is None:                       # paused by a stop signal: checkpointed
                o["stopped"] = r.get("stopped", "a pause")
            else:
                o["row"] = dict(r["row"])
    return {"pack": out} if "pack" in payload else out[0]


def _error_line(e: BaseException) -> str:
    """How run_grid reports a failed run: its exception type and the last line of its message."""
    msg = str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__
    return f"{type(e).__name__}: {msg}"


# ----------------------------------------------------------------------------- backends
class LocalBackend:
    """A spawn-context process pool (fork is unsafe beside torch/SAPIEN threads).

    When a worker dies the pool is broken for every run in flight (``BrokenProcessPool``): ``result``
    says ``WorkerLost`` and the next ``submit`` builds a fresh pool."""

    def __init__(self, workers: int, train: Callable):
        self.train = train
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        os.environ.setdefault("MKL_NUM_THREADS", "1")
        self.capacity = workers
        self.pool = self._new_pool()

    def _new_pool(self):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor
        return ProcessPoolExecutor(max_workers=self.capacity, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_worker_init, initargs=(os.getpid(),))

    def start(self) -> None:
        """Start every worker now, each importing the training code (``train([])``: torch, ManiSkill, the
        heap frozen: ``train.freeze_imports``) while the sweep process plans and prints its estimate; before,
        the workers started only after it, ~4 s later (docs/speed.md). A warm-up that fails is not read: the
        first run in that worker meets the same error and reports it."""
        self._warm = [self.pool.submit(self.train, []) for _ in range(self.capacity)]

    def submit(self, payload):
        from concurrent.futures.process import BrokenProcessPool
        try:
            return self.pool.submit(execute, payload, self.train, take_signals=True)
        except BrokenProcessPool:  # a worker died: the old pool's workers are being ended; start over
            self.pool.shutdown(wait=False, cancel_futures=True)
            self.pool = self._new_pool()
            return self.pool.submit(execute, payload, self.train, take_signals=True)

    def pass_stop(self, name: str) -> None:
        """A stop signal that reached the sweep, passed on to every worker as SIGUSR1 (``kill <sweep pid>`` reaches
        the sweep alone; a worker that got the signal itself takes this one as the same stop)."""
        for pid in list(getattr(self.pool, "_processes", None) or {}):
            try:
                os.kill(pid, signal.SIGUSR1)
            except ProcessLookupError:
                pass

    def wait(self, handles, timeout: Optional[float] = None):
        from concurrent.futures import FIRST_COMPLETED, wait
        return list(wait(handles, timeout=timeout, return_when=FIRST_COMPLETED).done)

    @staticmethod
    def result(h):
        from concurrent.futures.process import BrokenProcessPool
        try:
            return h.result()
        except BrokenProcessPool:
            raise WorkerLost("a pool worker died (killed, or out of memory); the pool lost every run in "
                             "flight") from None

    def close(self, cancel: bool = False):
        self.pool.shutdown(wait=not cancel, cancel_futures=cancel)


class InlineBackend:
    """Runs each submitted node at once in this process (no pool): for debugging and run-time plugins."""

    capacity = 1
    listener: Optional[Callable[[], None]] = None  # run_grid's progress poll, called while a run trains

    class _Handle:  # hashable: run_grid keys its in-flight runs by handle
        def __init__(self, value=None, error=None):
            self.value, self.error = value, error

    def __init__(self, train: Callable):
        self.train = train

    def start(self) -> None:
        """Nothing to start: runs train in this process."""

    def pass_stop(self, name: str) -> None:
        """Nothing to pass on: the runs train in this process, which took the signal."""

    def submit(self, payload):
        try:
            return self._Handle(value=execute(payload, self.train, listener=self.listener))
        except Exception as e:  # reported by run_grid like a worker's failure
            return self._Handle(error=e)

    def wait(self, handles, timeout: Optional[float] = None):
        return list(handles)[:1]

    @staticmethod
    def result(h):
        if h.error is not None:
            raise h.error
        return h.value

    def close(self, cancel: bool = False):
        pass


def _send_ray_token_if_held() -> None:
    """Ray 2.60 (here) turns token authentication on for a cluster started where a token is held (its first local
    ``ray.init`` writes ``~/.ray/auth_token``), but ``ray.init(address=...)`` sends the token only with
    ``RAY_AUTH_MODE=token``: unset, it is refused ("InvalidAuthToken") by a `ray start` cluster on a machine that
    ever ran a local Ray sweep. Where the mode is unset and a token is held, send it; a cluster without
    authentication accepts such a client too (measured, Ray 2.60)."""
    if "RAY_AUTH_MODE" in os.environ:
        return   # the user's choice
    held = os.environ.get("RAY_AUTH_TOKEN") or Path(os.environ.get("RAY_AUTH_TOKEN_PATH")
                                                     or Path.home() / ".ray" / "auth_token").is_file()
    if held:
        os.environ["RAY_AUTH_MODE"] = "token"


class RayBackend:
    """Ray tasks (one CPU each); without an address a local instance is started and stopped.

    A task whose worker or node dies is run again by Ray up to ``retries`` times (it resumes from its
    run folder's checkpoint, so the cluster must share ``--out``); a Python exception is not retried."""

    def __init__(self, workers: Optional[int], address: Optional[str], train: Callable,
                 retries: int = DEFAULT_RETRIES):
        if address:
            _send_ray_token_if_held()   # before ray is imported: it reads the mode once, at import
        import ray
        self.ray = ray
        self.retries = retries
        env = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
        repo = str(Path(__file__).resolve().parents[2])
        env["PYTHONPATH"] = os.pathsep.join(filter(None, [repo, os.environ.get("PYTHONPATH")]))
        kw = dict(runtime_env={"env_vars": env}, log_to_driver=False, logging_level="ERROR")
        if address:
            ray.init(address=address, **kw)
        else:
            # "local": always a fresh instance, never someone's `ray start` cluster on this machine
            ray.init(address="local", num_cpus=workers, include_dashboard=False, **kw)
        self.capacity = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))
        self.fn = ray.remote(num_cpus=1, max_retries=retries, retry_exceptions=False)(execute)
        self.train = train

    def start(self) -> None:
        """Nothing to start: Ray's workers start on their first task (and a cluster's may be warm)."""

    def submit(self, payload):
        return self.fn.remote(payload, self.train)

    def wait(self, handles, timeout: Optional[float] = None):
        ready, _ = self.ray.wait(list(handles), num_returns=1, timeout=timeout)
        return ready

    def result(self, h):
        try:
            return self.ray.get(h)
        except self.ray.exceptions.RayTaskError as e:  # surface the run's own exception
            raise e.as_instanceof_cause() from None
        except self.ray.exceptions.RayError as e:  # its worker or node died, and Ray's retries ran out
            first = (str(e).strip().splitlines() or [""])[0][:200]
            raise WorkerLost(f"{type(e).__name__} after {self.retries} retries: {first}", retryable=False) from None

    def close(self, cancel: bool = False):
        self.ray.shutdown()


# ----------------------------------------------------------------------------- the scheduler
def headline(row: dict) -> str:
    def num(k, fmt):
        try:
            return format(float(row[k]), fmt)
        except (KeyError, TypeError, ValueError):
            return "?"
    return (f"final eval success {num('eval_success_rate', '.2f')}, "
            f"successful training episodes {num('train_successes', '.0f')}")


def traceback_hint(run_dir: Path) -> str:
    """'; traceback: <run>/error.txt' where the run left one (train.py writes it on a failure)."""
    p = Path(run_dir) / rundir.ERROR
    return f"; traceback: {p}" if p.is_file() else ""


class RunProgress:
    """The sweep bar in env steps: a finished run counts whole, a run in flight by its ``progress.json``.

    What a run has been credited never goes down (a retried run restarts from its checkpoint, a little
    behind its last progress file), and a finished run brings it to the run's budget exactly. A run whose
    progress file changes hands (another pid or host: Ray reran it after losing its worker or node, or it
    resumes a run of an earlier sweep) is announced once per new process."""

    def __init__(self, bar, out: Path):
        self.bar, self.out = bar, Path(out)
        self.running: Dict[str, Node] = {}
        self.credited: Dict[str, int] = {}
        self.where: Dict[str, tuple] = {}

    def start(self, n: Node) -> None:
        self.running[n.rel] = n
        self.credited.setdefault(n.rel, 0)

    def poll(self) -> None:
        step = 0
        for rel, n in self.running.items():
            p = read_progress(self.out / rel)
            try:
                seen = min(int(p["env_steps"]), n.cfg.total_steps) if p else 0
            except (KeyError, TypeError, ValueError):
                continue
            where = (p.get("host"), p.get("pid")) if p else None
            if where and self.where.get(rel, where) != where:
                self.bar.write(f"{n.label}: running again, now pid {where[1]} on {where[0]} "
                               f"(resumed from its last checkpoint; at env step {seen})")
            if where:
                self.where[rel] = where
            if seen > self.credited[rel]:
                step += seen - self.credited[rel]
                self.credited[rel] = seen
        if step:
            self.bar.update(step)

    def finish(self, n: Node, ok: bool) -> None:
        self.running.pop(n.rel, None)
        self.where.pop(n.rel, None)
        credited = self.credited.pop(n.rel, 0)
        if ok:
            self.bar.update(n.cfg.total_steps - credited)


def _wait(backend, handles: list, timeout: float) -> list:
    try:
        takes_timeout = "timeout" in inspect.signature(backend.wait).parameters
    except (TypeError, ValueError):
        takes_timeout = False
    return backend.wait(handles, timeout=timeout) if takes_timeout else backend.wait(handles)


def run_grid(nodes: List[Node], out: Path, backend, progress: bool = True, retries: int = DEFAULT_RETRIES,
             poll_s: float = POLL_S, pack: int = 1) -> List[str]:
    """Run every unfinished node, parents before children, long chains first; return failures.

    With ``pack`` > 1 a worker gets up to that many ready runs with equal ``pack.pack_key`` at once and trains
    them side by side (``pack.py``; a run's results do not depend on its pack). A run whose worker died
    (``WorkerLost``) is submitted again, from its checkpoint, up to ``retries`` times (with its pack); a run
    that raised is a failure at once (its traceback: ``<run>/error.txt``), the others of its pack go on. A stop
    signal starts no more runs, lets those in flight checkpoint at the end of their episode (where the backend
    passes it on: ``pass_stop``; else the sweep stops at once, as on Ctrl-C) and raises ``SweepStopped``."""
    from tqdm import tqdm

    out = Path(out)
    by_rel = {n.rel: n for n in nodes}
    done = {n.rel for n in nodes if rundir.is_done(out / n.rel)}
    todo = [n for n in nodes if n.rel not in done]
    failed: List[str] = []
    in_flight: Dict[object, List[Node]] = {}
    lost: Dict[str, int] = {}
    total = sum(n.cfg.total_steps for n in nodes)
    # progress in env steps (finished runs count whole), so the ETA is one of work, not of run count
    bar = tqdm(total=total, initial=sum(by_rel[r].cfg.total_steps for r in done), desc="sweep", unit="step",
               unit_scale=True, disable=not progress, dynamic_ncols=True, smoothing=0.05)
    tracker = RunProgress(bar, out)
    if hasattr(backend, "listener"):
        backend.listener = tracker.poll
    if done:
        bar.write(f"{len(done)} of {plural(len(nodes), 'run')} already finished: skipped")

    def fail(n: Node, why: str) -> None:
        tracker.finish(n, ok=False)
        failed.append(n.rel)
        bar.write(f"FAILED {n.label} ({n.rel}): {why}{traceback_hint(out / n.rel)}")

    stopped: List[str] = []
    try:
        with checkpoint_on_signals(on_stop=getattr(backend, "pass_stop", _stop_now)):
            while todo or in_flight:
                ready = [n for n in todo if n.parent is None or n.parent in done]
                ready.sort(key=lambda n: -n.descendants)  # stable: grid order among equals
                free = 0 if stop_asked() else backend.capacity - len(in_flight)  # a stop starts no run
                for group in packs(ready, max(0, free), pack):
                    for n in group:
                        tracker.start(n)
                        todo.remove(n)
                    in_flight[backend.submit(_payload(group, out))] = group
                if not in_flight:
                    break  # the rest waits on failed runs
                finished = _wait(backend, list(in_flight), poll_s)
                tracker.poll()
                for h in finished:
                    group = in_flight.pop(h)
                    try:
                        res = backend.result(h)
                    except WorkerLost as e:
                        again = []
                        for n in group:
                            lost[n.rel] = lost.get(n.rel, 0) + 1
                            if e.retryable and lost[n.rel] <= retries:
                                bar.write(f"LOST {n.label} ({n.rel}): {e}; retry {lost[n.rel]}/{retries} from its "
                                          f"last checkpoint{traceback_hint(out / n.rel)}")
                                again.append(n)
                            else:
                                fail(n, f"worker lost{f' ({lost[n.rel]} times)' if e.retryable else ''}: {e}")
                        if again and not stop_asked():  # after a stop: the next sweep resumes them
                            in_flight[backend.submit(_payload(again, out))] = again
                        continue
                    except Exception as e:  # one failed run must not stop the others
                        for n in group:
                            fail(n, _error_line(e))
                        continue
                    for n, r in zip(group, res["pack"] if "pack" in res else [res]):
                        if "error" in r:
                            fail(n, r["error"])
                            continue
                        if "stopped" in r:
                            tracker.finish(n, ok=False)
                            stopped.append(n.rel)
                            bar.write(f"stopped {n.label} ({n.rel}): checkpointed at the end of its episode")
                            continue
                        done.add(n.rel)
                        tracker.finish(n, ok=True)
                        bar.set_postfix(runs=f"{len(done)}/{len(nodes)}")
                        bar.write(f"done {n.label}: {headline(r['row'])}")
            if stop_asked():
                raise SweepStopped(stop_asked(), stopped)
        blocked = [n.rel for n in todo]
        if blocked:
            bar.write(f"{plural(len(blocked), 'run')} not started: they start from a failed run")
    finally:
        bar.close()
    return failed + blocked


def _stop_now(name: str) -> None:
    """A backend that cannot pass a stop on (Ray): the sweep stops at once, its runs resume from their last
    checkpoints."""
    raise KeyboardInterrupt


def packs(ready: List[Node], free: int, size: int) -> List[List[Node]]:
    """Up to ``free`` groups of ready runs, in ``ready``'s order, each of up to ``size`` runs with equal
    ``pack_key``, shared evenly over the free workers: 16 ready runs, 2 workers, size 8: two packs of 8; 24 runs:
    four packs of 6 (two rounds of two, not a third pack of 8 with one worker idle); two keys of 2 runs each:
    one pack per key."""
    if size <= 1:
        return [[n] for n in ready[:free]]
    from ..pack import pack_key
    keys = {n.rel: pack_key(n.cfg) for n in ready}
    left, out = list(ready), []
    while left and len(out) < free:
        key = keys[left[0].rel]
        same = [n for n in left if key is not None and keys[n.rel] == key] or left[:1]
        slots = max(1, round((free - len(out)) * len(same) / len(left)))  # this key's share of the workers
        n_packs = -(-max(-(-len(same) // size), slots) // slots) * slots  # a multiple of them: no idle round
        group = same[:-(-len(same) // n_packs)]
        out.append(group)
        left = [n for n in left if n not in group]
    return out


def _payload(group: List[Node], out: Path) -> dict:
    return group[0].payload(out) if len(group) == 1 else {"pack": [n.payload(out) for n in group]}


# ----------------------------------------------------------------------------- command lines (SLURM)
def _levels(nodes: List[Node], out: Path) -> Dict[str, int]:
    """Each unfinished run's level: 0 if it can start now, else its parent's level + 1."""
    by_rel = {n.rel: n for n in nodes}
    level: Dict[str, int] = {}

    def get(n: Node) -> int:
        if n.rel not in level:
            p = by_rel.get(n.parent) if n.parent else None
            level[n.rel] = 0 if p is None or rundir.is_done(out / p.rel) else get(p) + 1
        return level[n.rel]

    return {n.rel: get(n) for n in nodes if not rundir.is_done(out / n.rel)}


def train_command(job: dict, config_file: Path) -> str:
    """The ``python -m maniskill_dualher.train`` line that runs ``job`` (``job_for``'s arguments)."""
    args = ["python", "-m", "maniskill_dualher.train", "--config", str(config_file), "--out", str(job["out"]),
            "--no-progress"]
    if job["init_from"] is not None:
        args += ["--init-from", str(job["init_from"])]
    if job["carry_replay"]:
        args.append("--carry-replay")
    if job["keep_replay"]:
        args.append("--keep-replay")
    return " ".join(shlex.quote(a) for a in args)


def emit_commands(nodes: List[Node], out: Path, path: Path) -> List[List[int]]:
    """Write one train command per unfinished run into ``path``, level by level (a run after its parent),
    each run's config as ``<path stem>-configs/<run>.json``, and each stage's ``stage.json`` (what
    ``protocol.stage_job`` writes). Returns the 1-based line numbers of each level."""
    out, path = Path(out).resolve(), Path(path).resolve()
    levels = _levels(nodes, out)
    # level by level; within one, long chains first (as run_grid starts them), then grid order
    order = sorted((n for n in nodes if n.rel in levels), key=lambda n: (levels[n.rel], -n.descendants))
    cfg_dir = path.parent / f"{path.stem}-configs"
    lines = []
    for n in order:
        cfg_file = cfg_dir / (n.rel.replace("/", "__") + ".json")
        atomic_write_text(cfg_file, n.cfg.to_json() + "\n")
        lines.append(train_command(job_for(n.payload(out), check_parent=False), cfg_file))
    atomic_write_text(path, "".join(line + "\n" for line in lines))
    by_level: List[List[int]] = []
    for i, n in enumerate(order, 1):
        while len(by_level) <= levels[n.rel]:
            by_level.append([])
        by_level[levels[n.rel]].append(i)
    return by_level
