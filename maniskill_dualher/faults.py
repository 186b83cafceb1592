"""Named points where the tests stop a process, to kill or remove it at a moment they choose instead of
one they race for. Each does nothing unless its environment variable names it.

* ``kill_point(name)``: the process SIGKILLs itself where ``$MANISKILL_DUALHER_KILL_AT`` equals ``name``
  (the report's staging steps).
* ``hold_point(name)``: the process waits, polling, for as long as the file ``$MANISKILL_DUALHER_HOLD_WHILE``
  exists, where ``name`` matches the shell pattern ``$MANISKILL_DUALHER_HOLD_AT`` (a run after it wrote a
  checkpoint: ``checkpoint:<run folder>``). A test removes the file to let it go on; a process killed while
  held resumes from that checkpoint like any other.
"""
from __future__ import annotations

import fnmatch
import os
import signal
import time

KILL_AT = "MANISKILL_DUALHER_KILL_AT"
HOLD_AT = "MANISKILL_DUALHER_HOLD_AT"
HOLD_WHILE = "MANISKILL_DUALHER_HOLD_WHILE"


def kill_point(name: str) -> None:
    if os.environ.get(KILL_AT) == name:
        os.kill(os.getpid(), signal.SIGKILL)


def hold_point(name: str, poll_s: float = 0.02) -> None:
    pattern, path = os.environ.get(HOLD_AT), os.environ.get(HOLD_WHILE)
    if not pattern or not path or not fnmatch.fnmatchcase(name, pattern):
        return
    while os.path.exists(path):
        time.sleep(poll_s)


def hold_env(pattern: str, path) -> dict:
    """The environment variables that hold a process at the points matching ``pattern`` while ``path`` exists."""
    return {HOLD_AT: pattern, HOLD_WHILE: str(path)}
