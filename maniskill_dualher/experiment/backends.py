"""Where runs execute: a local process pool, Ray, or inline; and the scheduler that feeds them.

``run_grid`` starts every unfinished run whose parent is finished, long chains first, and never lets one
failed run stop the others. A backend has ``submit(payload)``, ``wait(handles)``, ``result(handle)`` and
``close()``; a payload is a plain dict (``grid.Node.payload``) that ``execute`` runs in any process.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Dict, List, Optional

from .. import rundir
from ..config import RunConfig
from . import protocol
from .grid import Node


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
    import torch
    torch.set_num_threads(1)


def execute(payload: dict) -> dict:
    """Run one grid node (in a worker) and return its final metrics row."""
    import torch
    torch.set_num_threads(1)
    cfg = RunConfig.from_dict(payload["cfg"])
    if "stages" in payload:
        stages = [RunConfig.from_dict(s) for s in payload["stages"]]
        row = protocol.run_stage(stages, payload["stage"], payload["chain_dir"], payload["carry_replay"],
                                 show_progress=False)
    else:
        from ..train import run_training
        row = run_training(cfg, payload["out"], show_progress=False)
    return {"rel": payload["rel"], "row": dict(row)}


class LocalBackend:
    """A spawn-context process pool (fork is unsafe beside torch/SAPIEN threads)."""

    def __init__(self, workers: int):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        os.environ.setdefault("MKL_NUM_THREADS", "1")
        self.pool = ProcessPoolExecutor(max_workers=workers, mp_context=multiprocessing.get_context("spawn"),
                                        initializer=_worker_init, initargs=(os.getpid(),))
        self.capacity = workers

    def submit(self, payload):
        return self.pool.submit(execute, payload)

    def wait(self, handles):
        from concurrent.futures import FIRST_COMPLETED, wait
        return list(wait(handles, return_when=FIRST_COMPLETED).done)

    @staticmethod
    def result(h):
        return h.result()

    def close(self, cancel: bool = False):
        self.pool.shutdown(wait=not cancel, cancel_futures=cancel)


class InlineBackend:
    """Runs each submitted node at once in this process (no pool): for debugging and run-time plugins."""

    capacity = 1

    class _Handle:  # hashable: run_grid keys its in-flight runs by handle
        def __init__(self, value=None, error=None):
            self.value, self.error = value, error

    def submit(self, payload):
        try:
            return self._Handle(value=execute(payload))
        except Exception as e:  # reported by run_grid like a worker's failure
            return self._Handle(error=e)

    def wait(self, handles):
        return list(handles)[:1]

    @staticmethod
    def result(h):
        if h.error is not None:
            raise h.error
        return h.value

    def close(self, cancel: bool = False):
        pass


class RayBackend:
    """Ray tasks (one CPU each); without an address a local instance is started and stopped."""

    def __init__(self, workers: Optional[int], address: Optional[str]):
        import ray
        self.ray = ray
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
        self.fn = ray.remote(num_cpus=1, max_retries=0)(execute)

    def submit(self, payload):
        return self.fn.remote(payload)

    def wait(self, handles):
        ready, _ = self.ray.wait(list(handles), num_returns=1)
        return ready

    def result(self, h):
        try:
            return self.ray.get(h)
        except self.ray.exceptions.RayTaskError as e:  # surface the run's own exception
            raise e.as_instanceof_cause() from None

    def close(self, cancel: bool = False):
        self.ray.shutdown()


def headline(row: dict) -> str:
    def num(k, fmt):
        try:
            return format(float(row[k]), fmt)
        except (KeyError, TypeError, ValueError):
            return "?"
    return (f"final eval success {num('eval_success_rate', '.2f')}, "
            f"successful training episodes {num('train_successes', '.0f')}")


def run_grid(nodes: List[Node], out: Path, backend, progress: bool = True) -> List[str]:
    """Run every unfinished node, parents before children, long chains first; return failures."""
    from tqdm import tqdm

    by_rel = {n.rel: n for n in nodes}
    done = {n.rel for n in nodes if rundir.is_done(out / n.rel)}
    todo = [n for n in nodes if n.rel not in done]
    failed: List[str] = []
    in_flight: Dict[object, Node] = {}
    total = sum(n.cfg.total_steps for n in nodes)
    # progress in env steps (finished runs count whole), so the ETA is one of work, not of run count
    bar = tqdm(total=total, initial=sum(by_rel[r].cfg.total_steps for r in done), desc="sweep", unit="step",
               unit_scale=True, disable=not progress, dynamic_ncols=True, smoothing=0.05)
    if done:
        bar.write(f"{len(done)} of {len(nodes)} runs already finished: skipped")
    try:
        while todo or in_flight:
            ready = [n for n in todo if n.parent is None or n.parent in done]
            ready.sort(key=lambda n: -n.descendants)  # stable: grid order among equals
            for n in ready[: max(0, backend.capacity - len(in_flight))]:
                in_flight[backend.submit(n.payload(out))] = n
                todo.remove(n)
            if not in_flight:
                break  # the rest waits on failed runs
            for h in backend.wait(list(in_flight)):
                n = in_flight.pop(h)
                try:
                    res = backend.result(h)
                except Exception as e:  # one failed run must not stop the others
                    failed.append(n.rel)
                    msg = str(e).strip().splitlines()[-1] if str(e).strip() else type(e).__name__
                    bar.write(f"FAILED {n.label} ({n.rel}): {type(e).__name__}: {msg}")
                    continue
                done.add(n.rel)
                bar.update(n.cfg.total_steps)
                bar.set_postfix(runs=f"{len(done)}/{len(nodes)}")
                bar.write(f"done {n.label}: {headline(res['row'])}")
        blocked = [n.rel for n in todo]
        if blocked:
            bar.write(f"{len(blocked)} runs not started: they start from a failed run")
    finally:
        bar.close()
    return failed + blocked


