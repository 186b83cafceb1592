"""The environment of a sweep or run started in another process by a test: this checkout first on the path,
one thread, and optionally held after checkpoints (``faults.hold_point``) so a test disturbs a run in
flight at a moment it chooses instead of racing it."""
import os
import signal
import subprocess
import time
from pathlib import Path
from typing import Callable

from maniskill_dualher import faults

REPO = Path(__file__).resolve().parents[1]


def sweep_env(hold=None, pattern: str = "checkpoint:*") -> dict:
    """``hold`` (a file): the runs whose checkpoint point matches ``pattern`` wait while the file exists."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    env.setdefault("OMP_NUM_THREADS", "1")
    env.pop(faults.HOLD_AT, None)
    env.pop(faults.HOLD_WHILE, None)
    if hold is not None:
        env.update(faults.hold_env(pattern, hold))
    return env


def alive(pid: int) -> bool:
    """A process that runs (a zombie waiting for its reaper does not)."""
    try:
        return (Path("/proc") / str(pid) / "stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def kill_group(p: subprocess.Popen) -> None:
    """SIGKILL to ``p``'s process group (started with ``start_new_session=True``: its workers too), reaped."""
    try:
        os.killpg(p.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    p.wait()


def wait_until(p: subprocess.Popen, ready: Callable[[], bool], seconds: float) -> None:
    """Poll until ``ready()`` or ``seconds`` pass, and assert that ``p`` still runs (its stderr's tail if not)."""
    deadline = time.time() + seconds
    while time.time() < deadline and p.poll() is None and not ready():
        time.sleep(0.01)
    if p.poll() is not None:
        err = p.stderr.read() if p.stderr else ""
        raise AssertionError((err.decode() if isinstance(err, bytes) else err)[-2000:])
