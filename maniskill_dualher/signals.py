"""A stop asked by a signal: the runs of a process checkpoint at the end of their current episode and pause, so
the same command resumes with no env step lost.

A scheduler warns before it kills: SLURM sends SIGTERM at a job's time limit or preemption and SIGKILL
``KillWait`` later (30 s by default), and ``#SBATCH --signal=B:USR1@300`` sends SIGUSR1 five minutes ahead.
Without this a killed run loses everything since its last scheduled checkpoint (the paper regime's
``checkpoint_every`` is 300,000 env steps, ~20 minutes of a run on CPU C). ``train`` (``python -m
maniskill_dualher.train``) and the sweep's local pool take these signals (``experiment/backends.py``: the sweep
passes its own on to its workers and ends with ``128 + the signal``, as a shell reports a killed command).
"""
from __future__ import annotations

import contextlib
import signal
import threading
from typing import Callable, Optional

STOP_SIGNALS = ("SIGTERM", "SIGUSR1", "SIGINT")
_stop_asked: Optional[str] = None  # the first stop signal's name, while checkpoint_on_signals is in force
_stop_depth = 0


def stop_asked() -> Optional[str]:
    """The name of the signal that asked this process's runs to stop (None: none did)."""
    return _stop_asked


@contextlib.contextmanager
def checkpoint_on_signals(on_stop: Optional[Callable[[str], None]] = None):
    """Inside: SIGTERM, SIGUSR1 or SIGINT asks every run of this process to checkpoint at the end of its current
    episode (at most ``max_episode_steps`` env steps later, then one checkpoint write) and pause, so that the same
    command resumes with no env step lost, as from any checkpoint. This is what a scheduler's warning is for: SLURM
    sends SIGTERM at a time limit or preemption and SIGKILL ``KillWait`` later (30 s by default), and
    ``--signal=B:USR1@300`` warns five minutes ahead (a checkpoint of the paper regime's full R, 10^7 rows, is
    ~4 GB to write). A second SIGINT after a first (Ctrl-C twice) interrupts at once: the last checkpoint stands.
    ``on_stop(name)`` runs at the first signal (the sweep passes the signal on to its workers). Outside the main
    thread, where Python takes no signals, and nested inside another ``checkpoint_on_signals``, it changes
    nothing."""
    global _stop_asked, _stop_depth
    if _stop_depth or threading.current_thread() is not threading.main_thread():
        yield
        return

    def asked(signum, frame):
        global _stop_asked
        name = signal.Signals(signum).name
        if _stop_asked is not None:
            if name == _stop_asked == "SIGINT":   # Ctrl-C twice; a sweep's worker takes the sweep's SIGUSR1 and
                raise KeyboardInterrupt            # the terminal's SIGINT as one stop
            return
        _stop_asked = name
        if on_stop is not None:
            on_stop(name)

    before = {name: signal.signal(getattr(signal, name), asked) for name in STOP_SIGNALS}
    _stop_depth += 1
    try:
        yield
    finally:
        for name, handler in before.items():
            signal.signal(getattr(signal, name), handler)
        _stop_depth -= 1
        _stop_asked = None
