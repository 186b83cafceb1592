"""The run-folder and sweep-folder contract: file names and the helpers that read and write them.

A run folder (written by ``train.py``; a transfer stage also by ``experiment/protocol.py``)::

    config.json     the RunConfig (a different config in the same folder is refused)
    metrics.csv     one row per evaluation (METRIC_COLUMNS first)
    checkpoint.pt   networks, optimizer, replay (until finished, or kept for a successor stage or a later
                    ``train --continue``), RNG
    checkpoint.prev.pt  the checkpoint before it, while the run is unfinished: an unreadable latest one
                    (a kill mid-write on a filesystem without atomic rename, a bad disk) falls back to it
    lineage.json    where its networks (and replay) came from, if transferred
    stage.json      its place in a transfer chain (index, parent folder, carry flag)
    cell.json       written by the sweep: the cells it serves (experiment, arm, task, chain, method, variant,
                    seed, stage, role, parent); the report groups by these and infers nothing
    done.json       the final metrics row, once finished (``train --continue`` removes it and carries the run on)
    policy.pt       the actor at the latest evaluation (policy.py: load_policy; evaluate.py)
    policy_best.pt  the actor at the best evaluation success so far (a tie keeps the earlier)
    provenance.json where and with what code it ran: {"starts": [one provenance() per process start]}; a start
                    that carried a finished run on to a larger budget names the budget it had ("continued_from")
    error.txt       the traceback of the last failed attempt (a later resume may still finish it)
    progress.json   env steps done, written by a sweep's worker every few seconds (the sweep's bar reads it)
    events.out.*    TensorBoard

``RunFolder`` is the trainer's handle on its folder (identity check, start records, checkpoint, metrics, done,
error); the analysis only reads folders, with the functions below.

A sweep folder holds ``sweep.json`` (the definition: which runs exist), ``.sweep.lock`` (one sweep at a
time; the OS drops it with the process) and ``runs/...``; the report writes ``scores.csv``, ``curves.csv``,
its tables, plots and summary.md beside them. Every write is atomic (``fileio``).
"""
from __future__ import annotations

import csv
import io
import json
import os
import sys
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Union

from .fileio import atomic_write_text

PathLike = Union[str, Path]

CONFIG = "config.json"
METRICS = "metrics.csv"
DIAGNOSTICS = "diagnostics.csv"
CHECKPOINT = "checkpoint.pt"
CHECKPOINT_PREV = "checkpoint.prev.pt"
ORIGIN = "lineage.json"
STAGE = "stage.json"
CELL = "cell.json"
DONE = "done.json"
POLICY = "policy.pt"
POLICY_BEST = "policy_best.pt"
PROVENANCE = "provenance.json"
ERROR = "error.txt"
SWEEP = "sweep.json"
RUNS_DIR = "runs"

METRIC_COLUMNS = ["env_steps", "eval_return", "eval_success_rate", "eval_success_at_end", "eval_episode_length",
                  "train_episodes", "train_successes", "train_episode_length", "updates", "wall_time_s"]


def is_done(run_dir: PathLike) -> bool:
    return (Path(run_dir) / DONE).is_file()


def read_done(run_dir: PathLike) -> dict:
    return json.loads((Path(run_dir) / DONE).read_text())


def write_done(run_dir: PathLike, final: dict, **extra) -> None:
    atomic_write_text(Path(run_dir) / DONE, json.dumps({"final": final, **extra}, indent=2) + "\n")


def rows_text(rows: List[dict], first: Sequence[str]) -> str:
    """CSV of dict rows: the ``first`` columns, then every other key in sorted order; cells as written."""
    cols = list(first) + sorted({k for r in rows for k in r} - set(first))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: r.get(k, "") for k in cols})
    return buf.getvalue()


def metrics_text(rows: List[dict]) -> str:
    return rows_text(rows, METRIC_COLUMNS)


def write_metrics(run_dir: PathLike, rows: List[dict]) -> None:
    atomic_write_text(Path(run_dir) / METRICS, metrics_text(rows))


def _num(v):
    try:
        return float(v)
    except (TypeError, ValueError):
        return v


def read_metrics(run_dir: PathLike, name: str = METRICS) -> List[Dict[str, float]]:
    with open(Path(run_dir) / name, newline="") as f:
        return [{k: _num(v) for k, v in r.items() if k is not None} for r in csv.DictReader(f)]


def read_json(path: PathLike) -> Optional[dict]:
    p = Path(path)
    return json.loads(p.read_text()) if p.is_file() else None


def read_stage(run_dir: PathLike) -> Optional[dict]:
    return read_json(Path(run_dir) / STAGE)


def write_stage(run_dir: PathLike, stage: dict) -> None:
    atomic_write_text(Path(run_dir) / STAGE, json.dumps(stage, indent=2, sort_keys=True))


def write_json(path: PathLike, obj: dict) -> None:
    atomic_write_text(path, json.dumps(obj, indent=2, sort_keys=True) + "\n")


def read_sweep(folder: PathLike) -> Optional[dict]:
    return read_json(Path(folder) / SWEEP)


# --------------------------------------------------------------------------- the trainer's view of its folder
def differing_keys(a: dict, b: dict, prefix: str = "") -> List[str]:
    """Dotted names of the keys whose values differ between two nested config dicts (missing counts)."""
    out = []
    for k in sorted(set(a) | set(b)):
        va, vb = a.get(k, "<missing>"), b.get(k, "<missing>")
        if isinstance(va, dict) and isinstance(vb, dict):
            out += differing_keys(va, vb, f"{prefix}{k}.")
        elif va != vb:
            out.append(prefix + k)
    return out


# --------------------------------------------------------------------------- the checkpoint file's contents
# A checkpoint file holds only tensors and plain Python (dicts, lists, tuples, numbers, strings, None), so it
# loads with ``torch.load(weights_only=True)``: reading one executes no code from it. Checkpoints written before
# that held the replay as pickled numpy arrays; they load under weights_only=True too, with numpy's array
# reconstruction (and nothing else) allowed (``_numpy_array_globals``). A file holding any other object is
# refused, whatever folder it is in.

def file_state(obj):
    """``obj`` as a checkpoint file holds it: numpy arrays as tensors sharing their memory (``torch.from_numpy``,
    no copy: torch.save's zip writer streams their bytes as they are, where pickling an array copies it, several
    times over; the peak of a large replay's checkpoint was 2.5 KB per stored row), numpy scalars as Python
    numbers; dicts, lists and tuples recursed, anything else as is."""
    import numpy as np
    import torch
    if isinstance(obj, np.ndarray):
        if obj.dtype == object:
            raise TypeError("a checkpoint cannot hold an object array")
        return torch.from_numpy(obj if obj.flags.writeable else obj.copy())
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, dict):
        return {k: file_state(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(file_state(v) for v in obj)
    return obj


def array_state(obj):
    """The numpy side of ``file_state``, for state that lives in numpy (the replay): tensors back as numpy arrays
    sharing their memory (``.numpy()``, the same bits); numpy arrays (an older checkpoint's) and everything else
    as they are; dicts, lists and tuples recursed."""
    import torch
    if isinstance(obj, torch.Tensor):
        return obj.numpy()
    if isinstance(obj, dict):
        return {k: array_state(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(array_state(v) for v in obj)
    return obj


def _numpy_array_globals() -> list:
    """What an older checkpoint's pickled numpy arrays (and scalars) need, under both numpy module names."""
    import numpy as np
    try:
        from numpy._core import multiarray
    except ImportError:  # numpy < 2
        from numpy.core import multiarray
    out = [bytes, np.ndarray, np.dtype, multiarray._reconstruct, multiarray.scalar]
    out += [(f, f"numpy.core.multiarray.{f.__name__}") for f in (multiarray._reconstruct, multiarray.scalar)]
    out += [(f, f"numpy._core.multiarray.{f.__name__}") for f in (multiarray._reconstruct, multiarray.scalar)]
    out += [type(np.dtype(t)) for t in ("f4", "f8", "i8", "i4", "u1", "?")]  # numpy.dtypes.*DType
    return out


def load_torch_file(path: PathLike, what: str) -> object:
    """``torch.load(path, weights_only=True)`` on the CPU (numpy arrays allowed, see above). Raises
    ``ConfigError`` naming the file: "refused" when it holds other objects (their names), "unreadable" when it
    is not a torch file or is cut short."""
    import pickle

    import torch

    from .config import ConfigError
    try:
        with torch.serialization.safe_globals(_numpy_array_globals()):
            return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:  # weights_only found an object it does not load
        try:
            names = torch.serialization.get_unsafe_globals_in_checkpoint(path)
        except Exception:
            names = []
        allowed = {n if isinstance(g, tuple) else f"{g.__module__}.{g.__qualname__}"
                   for g in _numpy_array_globals() for n in ([g[1]] if isinstance(g, tuple) else [None])}
        names = [n for n in names if n not in allowed]
        if names:
            shown = ", ".join(names[:3]) + (", ..." if len(names) > 3 else "")
            raise ConfigError(f"refused {what} {path}: it holds objects other than tensors and plain data "
                              f"({shown}); loading it would run code from the file") from None
        raise ConfigError(f"unreadable {what} {path}: {unreadable_cause(path, e)}") from None
    except Exception as e:  # a truncated or foreign file
        raise ConfigError(f"unreadable {what} {path}: {unreadable_cause(path, e)}") from None


def unreadable_cause(path: PathLike, error: BaseException) -> str:
    """Why a torch file did not load, in words: missing, empty, cut short (a torch file is a zip archive whose
    directory is at its end), not a torch file, or else the error itself (its first line)."""
    import zipfile
    p = Path(path)
    try:
        size = p.stat().st_size
        with open(p, "rb") as f:
            head = f.read(4)
    except OSError as e:
        return f"{type(e).__name__}: {e.strerror or e}"
    if size == 0:
        return "the file is empty (0 bytes): a copy or download that did not finish?"
    if head == b"PK\x03\x04" and not zipfile.is_zipfile(p):
        return (f"the file is cut short ({size:,} bytes, its zip archive has no end): a copy or download that did "
                f"not finish? Copy it again")
    if head[:1] != b"\x80" and head != b"PK\x03\x04":
        return f"not a torch file (it starts with {head!r}, not a zip archive or a pickle)"
    text = str(error).strip().splitlines()
    return f"{type(error).__name__}" + (f": {text[0][:160]}" if text else "")


def load_checkpoint(run_dir: PathLike) -> dict:
    """A run folder's checkpoint: checkpoint.pt, or, when that is missing, unreadable or refused, the previous
    one (checkpoint.prev.pt) with one warning line on stderr. ConfigError if neither can be read. Loaded with
    ``weights_only=True`` (``load_torch_file``); a new checkpoint's replay arrays come back as tensors, which
    ``array_state`` turns back into numpy arrays."""
    from .config import ConfigError
    latest, prev = Path(run_dir) / CHECKPOINT, Path(run_dir) / CHECKPOINT_PREV
    if not latest.is_file() and not prev.is_file():
        raise ConfigError(f"missing checkpoint: {latest}")
    problem = None
    for path in (latest, prev):
        if not path.is_file():
            continue
        try:
            state = load_torch_file(path, "checkpoint")
        except ConfigError as e:
            problem = problem or str(e)
            continue
        if path == prev:
            print(f"warning: {problem or f'missing checkpoint {latest}'}; resuming from {prev.name}",
                  file=sys.stderr)
        return state
    raise ConfigError(problem)


def record_start(run_dir: PathLike, info: Optional[dict] = None) -> dict:
    """Append ``info`` (default: ``provenance.provenance()``) to ``run_dir/provenance.json``'s ``starts``."""
    path = Path(run_dir) / PROVENANCE
    starts = []
    if path.is_file():
        try:
            starts = list(json.loads(path.read_text()).get("starts", []))
        except (ValueError, AttributeError):
            starts = []  # a foreign or broken file: start over rather than stop the run
    if info is None:
        from .provenance import provenance
        info = provenance()
    doc = {"starts": starts + [info]}
    atomic_write_text(path, json.dumps(doc, indent=2, sort_keys=True) + "\n")
    return doc


class RunFolder:
    """One run's folder as its trainer keeps it: the identity check, the start records, the checkpoint, the
    metrics, done.json and error.txt. Every write is atomic."""

    def __init__(self, path: PathLike):
        self.path = Path(path)

    def config(self) -> Optional[dict]:
        """config.json's dict (None: no run here)."""
        from .config import ConfigError
        cfg_path = self.path / CONFIG
        if not cfg_path.is_file():
            return None
        try:
            return json.loads(cfg_path.read_text())
        except json.JSONDecodeError:
            raise ConfigError(f"{cfg_path} is not valid JSON") from None

    def check_identity(self, config_json: str, ignore: Sequence[str] = ()) -> None:
        """Refuse a folder that holds a run of another config (ConfigError naming the keys that differ); the
        top-level keys in ``ignore`` may differ (``train --continue``: total_steps)."""
        from .config import ConfigError, run_identity
        old = self.config()
        if old is None:
            return
        old, new = run_identity(old), run_identity(json.loads(config_json))
        for k in ignore:
            old.pop(k, None)
            new.pop(k, None)
        if old != new:
            keys = ", ".join(differing_keys(old, new)) or "?"
            raise ConfigError(f"{self.path} holds a run of a different config (differs in: {keys}); use another --out")

    def record_start(self, config_json: str, init_from: Optional[PathLike], carry_replay: bool,
                     continued_from: Optional[int] = None) -> None:
        """config.json, lineage.json and a provenance.json entry for this process start. ``continued_from``: the
        budget of the finished run this start carries on (its lineage stays: its networks came from there)."""
        self.path.mkdir(parents=True, exist_ok=True)
        atomic_write_text(self.path / CONFIG, config_json + "\n")
        info = None
        if continued_from is None:
            write_json(self.path / ORIGIN, {"init_from": str(init_from) if init_from else None,
                                           "carry_replay": bool(carry_replay)})
        else:
            from .provenance import provenance
            info = dict(provenance(), continued_from={"total_steps": int(continued_from)})
        record_start(self.path, info)

    @property
    def has_checkpoint(self) -> bool:
        return (self.path / CHECKPOINT).is_file() or (self.path / CHECKPOINT_PREV).is_file()

    def load_checkpoint(self) -> dict:
        return load_checkpoint(self.path)

    def save_checkpoint(self, state: dict, keep_previous: bool = True) -> None:
        """checkpoint.pt (``state`` as ``file_state`` makes it: tensors and plain data), written atomically; the one
        it replaces becomes checkpoint.prev.pt (``keep_previous``) or is dropped (a finished run, which nobody
        resumes mid-way)."""
        from .fileio import atomic_torch_save
        latest, prev = self.path / CHECKPOINT, self.path / CHECKPOINT_PREV
        if keep_previous and latest.is_file():
            os.replace(latest, prev)  # until the new one lands, the loader falls back to prev
        atomic_torch_save(file_state(state), latest)
        if not keep_previous and prev.is_file():
            prev.unlink()

    def drop_previous_checkpoint(self) -> None:
        """A finished run keeps one checkpoint."""
        prev = self.path / CHECKPOINT_PREV
        if prev.is_file():
            prev.unlink()

    def write_metrics(self, rows: List[dict]) -> None:
        write_metrics(self.path, rows)

    def write_diagnostics(self, rows: List[dict]) -> None:
        """diagnostics.csv: the learner's per-update logs, averaged per batch source between evaluations."""
        atomic_write_text(self.path / DIAGNOSTICS, rows_text(rows, ("env_steps",)))

    @property
    def done(self) -> bool:
        return is_done(self.path)

    def final(self) -> dict:
        return read_done(self.path)["final"]

    def finish(self, final: dict, **extra) -> None:
        write_done(self.path, final, **extra)

    def reopen(self) -> None:
        """A finished run goes on (``train --continue``): done.json removed."""
        (self.path / DONE).unlink()

    def write_error(self) -> None:
        """error.txt: UTC time and the traceback of the exception being handled."""
        import datetime
        import traceback
        stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")
        try:
            atomic_write_text(self.path / ERROR, f"failed at {stamp} (UTC)\n{traceback.format_exc()}")
        except OSError:
            pass  # an unwritable folder must not hide the original exception
