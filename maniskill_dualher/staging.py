"""A folder's report files replaced as one: staged in full, then swapped in, so a report or ``--merge``
killed at any moment leaves the old files or the new ones, never a mix (``analysis/report.py``).

Two ways, by what the folder holds:

* **whole** (a results folder: no run folders, e.g. ``results/reference``): the folder is copied beside
  itself as ``.NAME.report-new`` (hard links, so cheap and byte-equal), the report writes there, and the
  copy takes the folder's place in one step: Linux's ``renameat2(RENAME_EXCHANGE)`` swaps the two, then the
  old one is deleted. Where the filesystem cannot swap, two renames (the folder to ``.NAME.report-old``,
  the copy to the folder): between them the folder is missing for a moment, and the next report on it
  finishes the swap first.
* **journal** (a sweep folder with its run folders, which cannot move): the new files are written into
  ``FOLDER/.report-new``; when all are there that folder is renamed ``.report-ready`` (the commit point)
  and each file is moved into the folder. The next report on it finishes an interrupted move.

Every report starts by finishing or undoing what a killed one left (``recover``): a staging folder that was
not complete is deleted (the folder is as it was), a complete one is swapped or moved in. Reports in one
parent folder take turns (an ``flock`` on the parent folder, dropped when its holder dies however it dies).
Nothing here imports torch: the analysis runs without it.
"""
from __future__ import annotations

import ctypes
import errno
import os
import shutil
import sys
import uuid
from pathlib import Path
from typing import Iterable, List, Optional

from .faults import KILL_AT, kill_point  # noqa: F401  (the tests kill a report at named moments)

try:
    import fcntl
except ImportError:  # not POSIX: no lock between two reports (their business)
    fcntl = None  # type: ignore[assignment]

EXCHANGE = True                          # tests set it False to take the two-rename path
INSIDE_NEW, INSIDE_READY = ".report-new", ".report-ready"


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths in one step (``renameat2`` with ``RENAME_EXCHANGE``); False where that is not there."""
    if not EXCHANGE or not sys.platform.startswith("linux"):
        return False
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):  # glibc older than 2.28, or another libc
        return False
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    at_fdcwd, rename_exchange = -100, 2
    if fn(at_fdcwd, os.fsencode(str(a)), at_fdcwd, os.fsencode(str(b)), rename_exchange) == 0:
        return True
    e = ctypes.get_errno()
    if e in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP):  # the filesystem cannot swap
        return False
    raise OSError(e, os.strerror(e), str(a))


def _trash(path: Path) -> None:
    """Delete a folder: first renamed out of the way (one step), so a half-deleted one is never read."""
    gone = path.parent / f"{path.name}.trash-{uuid.uuid4().hex[:8]}"
    try:
        os.rename(path, gone)
    except FileNotFoundError:
        return
    shutil.rmtree(gone, ignore_errors=True)


def _link_or_copy(src: str, dst: str) -> None:
    try:
        os.link(src, dst, follow_symlinks=False)
    except OSError:  # another filesystem, or no hard links: a copy
        shutil.copy2(src, dst, follow_symlinks=False)


def _same(a: Path, b: Path) -> bool:
    """Two files with the same bytes (the same file, or equal contents)."""
    try:
        if os.path.samefile(a, b):
            return True
        if a.stat().st_size != b.stat().st_size:
            return False
        return a.read_bytes() == b.read_bytes()
    except OSError:
        return False


def _files(root: Path) -> List[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*") if p.is_file() or p.is_symlink())


def beside(folder: Path, what: str) -> Path:
    return folder.parent / f".{folder.name}.report-{what}"


def recover(folder: Path) -> List[str]:
    """Finish or undo what a killed report left in or beside ``folder``; one line per thing done."""
    notes: List[str] = []
    new, old = beside(folder, "new"), beside(folder, "old")
    if old.is_dir():  # the two-rename swap was cut: the copy in ``new`` was complete when it began
        if not folder.exists() and new.is_dir():
            os.rename(new, folder)
            notes.append(f"finished the interrupted report of {folder}")
        elif not folder.exists():  # the copy is gone (deleted by hand): the folder as it was
            os.rename(old, folder)
            notes.append(f"restored {folder} as it was before an interrupted report")
        _trash(old)
    if new.is_dir():  # not swapped in (the folder is as it was), or swapped (it holds the old files)
        _trash(new)
        notes.append(f"removed {new.name}, left by an interrupted report of {folder}")
    if folder.is_dir():
        ready = folder / INSIDE_READY
        if ready.is_dir():  # a journal committed but not fully moved in: move the rest
            for f in sorted(os.listdir(ready)):
                os.replace(ready / f, folder / f)
            _trash(ready)
            notes.append(f"finished the interrupted report of {folder}")
        if (folder / INSIDE_NEW).is_dir():
            _trash(folder / INSIDE_NEW)
            notes.append(f"removed {INSIDE_NEW} in {folder}, left by an interrupted report (the folder is as "
                         "before it)")
        for p in folder.glob(f"{INSIDE_NEW}.trash-*"):
            shutil.rmtree(p, ignore_errors=True)
        for p in folder.glob(f"{INSIDE_READY}.trash-*"):
            shutil.rmtree(p, ignore_errors=True)
    for p in folder.parent.glob(f".{folder.name}.report-*.trash-*"):
        shutil.rmtree(p, ignore_errors=True)
    return [n for n in notes if n]


class Staged:
    """``with Staged(folder) as st:`` takes the parent folder's lock and recovers (``st.notes``);
    ``st.begin(whole)`` makes the staging folder ``st.path``; write there, then ``st.commit(names)``. Leaving
    the block without a commit (an exception) deletes the staging folder: the folder is as it was."""

    def __init__(self, folder: Path):
        self.folder = Path(os.path.realpath(folder))
        self.path: Optional[Path] = None
        self.whole = False
        self.notes: List[str] = []
        self._lock: Optional[int] = None

    def __enter__(self) -> "Staged":
        self._take_lock()
        self.notes = recover(self.folder)
        return self

    def _take_lock(self) -> None:
        if fcntl is None:
            return
        try:
            fd = os.open(self.folder.parent, os.O_RDONLY)
        except OSError:
            return
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                print(f"waiting for another report writing in {self.folder.parent}", file=sys.stderr, flush=True)
                fcntl.flock(fd, fcntl.LOCK_EX)
        except OSError:  # a filesystem without locks on folders
            os.close(fd)
            return
        self._lock = fd

    def __exit__(self, *exc) -> None:
        try:
            if self.path is not None:
                _trash(self.path)
                self.path = None
        finally:
            if self._lock is not None:
                os.close(self._lock)
                self._lock = None

    def begin(self, whole: bool, read: Iterable[str] = ()) -> Path:
        """The staging folder: a full copy of the folder beside it (``whole``), or a folder inside it
        holding the files named in ``read`` (for the report to read back and rewrite)."""
        self.whole = whole
        if whole:
            self.path = beside(self.folder, "new")
            shutil.copytree(self.folder, self.path, symlinks=True, copy_function=_link_or_copy)
        else:
            self.path = self.folder / INSIDE_NEW
            self.path.mkdir()
            for name in read:
                if (self.folder / name).is_file():
                    _link_or_copy(str(self.folder / name), str(self.path / name))
        return self.path

    def commit(self, names: Iterable[str] = ()) -> bool:
        """Put the staged files in place as one; False (and nothing written) if they equal the folder's.
        ``names``: the staged files to move in (journal); a whole folder is swapped as it is."""
        assert self.path is not None
        new, folder = self.path, self.folder
        if self.whole:
            mine, theirs = _files(new), _files(folder)
            if mine == theirs and all(_same(new / f, folder / f) for f in mine):
                return False
            kill_point("staged")
            if _exchange(new, folder):
                kill_point("exchanged")
                self.path = new  # now the old files: __exit__ deletes them
                return True
            old = beside(folder, "old")
            os.rename(folder, old)
            kill_point("renamed-old")
            os.rename(new, folder)
            self.path = old
            return True
        for f in os.listdir(new):  # only what changes moves in
            if f not in names or _same(new / f, folder / f):
                os.unlink(new / f)
        if not os.listdir(new):
            return False
        kill_point("staged")
        ready = folder / INSIDE_READY
        os.rename(new, ready)  # the commit point: from here the next report finishes the move
        self.path = None
        kill_point("committed")
        for i, f in enumerate(sorted(os.listdir(ready))):
            os.replace(ready / f, folder / f)
            if i == 0:
                kill_point("moved-one")
        _trash(ready)
        return True
