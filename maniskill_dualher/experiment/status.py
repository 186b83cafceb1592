"""Where a sweep stands, read from its folder alone: ``python -m maniskill_dualher.sweep --status --out DIR``.

A sweep of hours runs in the background (``nohup``, a cluster), where its progress bar is a log of carriage
returns. This reads what the sweep and its runs already write, and writes nothing: ``sweep.json`` (the runs it
planned), each run's ``done.json`` (finished), ``error.txt`` (failed), ``progress.json`` (env steps, pid, host,
every few seconds while it trains), the time of its ``checkpoint.pt`` (where a resume goes back to) and
``metrics.csv`` (env steps and wall time at each evaluation: the run's recent pace), and the folder's lock (``lock.py``: who holds it; on this host, whether that process lives).
"""
from __future__ import annotations

import csv
import os
import socket
import time
from pathlib import Path
from typing import List, Optional

from .. import rundir
from ..config import ConfigError
from ..fileio import plural
from .backends import read_progress
from .lock import LOCK_FILE, holder_text, read_holder


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:   # alive, another user's
        return True
    return True


def holder(out: Path) -> str:
    """Who holds ``out``'s lock, in words: running (its process lives, on this host), ended, or on another host."""
    if not (out / LOCK_FILE).exists():
        return "no sweep has held this folder"
    h = read_holder(out)
    if not h:   # released (emptied) by its last holder, or torn
        return "its lock names no holder"
    who = holder_text(h)
    if h.get("host") != socket.gethostname():
        return f"last held by {who} (another host: not checked)"
    return f"held by {who}: running" if _alive(int(h["pid"])) else f"last held by {who}, which has ended"


def pace(run_dir: Path) -> Optional[float]:
    """Env steps per second of wall time between the run's last two evaluations (None: fewer than two, or
    a resume between them)."""
    try:
        with open(run_dir / rundir.METRICS, newline="") as f:
            rows = list(csv.DictReader(f))[-2:]
        (s0, w0), (s1, w1) = ((float(r["env_steps"]), float(r["wall_time_s"])) for r in rows)
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return (s1 - s0) / (w1 - w0) if w1 > w0 and s1 > s0 else None


def checkpoint_age(run_dir: Path, now: float) -> str:
    """When the run's last checkpoint was written: what a resume goes back to (the steps after it are run again).
    Read from the file's time, not the file: a checkpoint with a full replay is gigabytes."""
    try:
        written = (run_dir / rundir.CHECKPOINT).stat().st_mtime
    except OSError:
        return "no checkpoint yet (a resume starts it over)"
    return f"last checkpoint written {_hours(max(0.0, now - written))} ago"


def _label(run_dir: Path) -> str:
    try:
        cfg = rundir.read_json(run_dir / rundir.CONFIG) or {}
    except (OSError, ValueError):   # a label is not worth failing the status over
        cfg = {}
    return f"{cfg.get('method', '?')} seed {cfg.get('seed', '?')} {cfg.get('env_id', '?')}"


def _hours(s: float) -> str:
    return f"{s / 3600:.1f} h" if s >= 5400 else f"{s / 60:.0f} min" if s >= 90 else f"{s:.0f} s"


def status_lines(out: Path, now: Optional[float] = None) -> List[str]:
    """The status of the sweep in ``out`` as lines; ConfigError if ``out`` holds no sweep."""
    out = Path(out)
    sweep = rundir.read_sweep(out) if out.is_dir() else None
    if not sweep or not isinstance(sweep.get("runs"), list):
        raise ConfigError(f"--status: no sweep in {out} (no sweep.json listing its runs)")
    now = time.time() if now is None else now
    finished, failed, flight, todo = [], [], [], []
    for rel in sweep["runs"]:
        d = out / rel
        if rundir.is_done(d):
            finished.append(rel)
        elif (d / rundir.ERROR).is_file():
            failed.append(rel)
        elif read_progress(d):
            flight.append(rel)
        else:
            todo.append(rel)
    lines = [f"{out}: {plural(len(sweep['runs']), 'run')}, {len(finished)} finished, {len(flight)} started and "
             f"unfinished, {len(failed)} failed, {len(todo)} not started; {holder(out)}"]
    if flight:
        lines.append("started, unfinished (each resumes from its last checkpoint if its sweep has ended):")
    for rel in flight:
        d, p = out / rel, read_progress(out / rel)
        steps, total = int(p.get("env_steps", 0)), int(p.get("total_steps", 0))
        line = f"  {rel} ({_label(d)}): {steps:,} of {total:,} env steps"
        if total:
            line += f" ({100 * steps / total:.1f}%)"
        if "time" in p:
            line += f", progress {_hours(max(0.0, now - float(p['time'])))} ago (pid {p.get('pid')} on {p.get('host')})"
        r = pace(d)
        if r:
            line += f"; {r:,.0f} env steps/s between its last two evaluations, ~{_hours((total - steps) / r)} to go"
        lines.append(line + "; " + checkpoint_age(d, now))
    for rel in failed:
        text = (out / rel / rundir.ERROR).read_text(errors="replace").strip().splitlines()
        lines.append(f"  FAILED {rel} ({_label(out / rel)}): {text[-1] if text else 'see error.txt'}")
    return lines
