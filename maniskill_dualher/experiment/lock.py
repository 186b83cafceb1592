"""One sweep per out folder: an exclusive ``flock`` on ``<out>/.sweep.lock``.

The operating system drops the lock when its holder dies, however it dies (SIGKILL, out of memory, a lost
node), so a killed sweep never leaves its folder stuck: the lock file stays behind but locks nothing. The
holder writes its pid, host and start time into the file so that a refused sweep can say who holds it.
On Linux NFS (v4, or v3 with lockd) ``flock`` is carried out as a POSIX lock the server knows about, so two
sweeps on two machines sharing the folder exclude each other too.
"""
from __future__ import annotations

import datetime
import errno
import json
import os
import socket
from pathlib import Path
from typing import Optional, Union

from ..config import ConfigError

try:
    import fcntl
except ImportError:  # not POSIX: no lock (a second sweep on the folder is then the user's business)
    fcntl = None  # type: ignore[assignment]

LOCK_FILE = ".sweep.lock"


class FolderBusy(ConfigError):
    """Another live sweep holds the folder's lock."""


def parse_holder(raw: bytes) -> Optional[dict]:
    """The holder a lock file's bytes name (pid, host, since), or None: empty (released), torn or foreign."""
    try:
        h = json.loads(raw.decode())
    except (ValueError, UnicodeDecodeError):
        return None
    return h if isinstance(h, dict) and str(h.get("pid", "")).isdigit() else None


def read_holder(folder: Union[str, Path]) -> Optional[dict]:
    """The holder named by ``folder``'s lock file, read without locking (``sweep --status``)."""
    try:
        return parse_holder((Path(folder) / LOCK_FILE).read_bytes())
    except OSError:
        return None


def holder_text(h: Optional[dict]) -> str:
    if not h:
        return "holder unknown"
    return f"pid {h['pid']} on host {h.get('host', '?')}, since {h.get('since', '?')}"


class FolderLock:
    """``with FolderLock(out):`` holds ``out`` for this process; raises ``FolderBusy`` if another holds it."""

    def __init__(self, folder: Union[str, Path]):
        self.folder = Path(folder)
        self.path = self.folder / LOCK_FILE
        self.fd: Optional[int] = None

    def acquire(self) -> "FolderLock":
        if fcntl is None or self.fd is not None:
            return self
        if self.folder.exists() and not self.folder.is_dir():
            raise ConfigError(f"--out {self.folder} exists and is not a folder")
        self.folder.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            holder = os.pread(fd, 4096, 0) if e.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES) else None
            os.close(fd)
            if holder is None:
                raise ConfigError(f"cannot lock {self.path} ({os.strerror(e.errno or 0)}); "
                                  f"use an --out on a filesystem with file locks") from None
            raise FolderBusy(f"{self.folder} is in use by another sweep ({holder_text(parse_holder(holder))}); "
                             f"wait for it to end, or use another --out") from None
        me = {"pid": os.getpid(), "host": socket.gethostname(),
              "since": datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(me) + "\n").encode(), 0)
        self.fd = fd
        return self

    def release(self) -> None:
        """Unlock (the file stays: removing it would race with a sweep about to lock it)."""
        if self.fd is None:
            return
        fd, self.fd = self.fd, None
        try:
            os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            os.close(fd)

    def __enter__(self) -> "FolderLock":
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
