"""Atomic writes: a temp file in the same folder, then os.replace, so a kill never leaves half a file."""
from __future__ import annotations

import csv
import io
import math
import os
import tempfile
from pathlib import Path
from typing import Callable, List, Optional, Union

PathLike = Union[str, Path]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _atomic(path: PathLike, write: Callable[[str], None]) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix="." + path.name + ".", suffix=".tmp")
    os.close(fd)
    try:
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; a result file should read like any other
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def atomic_write_text(path: PathLike, text: str) -> None:
    def write(tmp: str) -> None:
        with open(tmp, "w", newline="") as f:
            f.write(text)
    _atomic(path, write)


def atomic_torch_save(obj, path: PathLike) -> None:
    import torch  # late: the report and sweep never need torch for their own files
    _atomic(path, lambda tmp: torch.save(obj, tmp))


def atomic_write_with(path: PathLike, write: Callable[[str], None]) -> None:
    """Atomic write of any file a writer can produce from a temp path (e.g. ``fig.savefig``)."""
    _atomic(path, write)


def plural(n: int, word: str, many: Optional[str] = None, thousands: bool = False) -> str:
    """``n`` and its noun, singular for one: plural(1, "episode") -> "1 episode", plural(3, "run") -> "3 runs";
    ``thousands``: 3,500,001 (the tables keep their plain numbers)."""
    number = f"{n:,}" if thousands else f"{n}"
    return f"{number} {word if n == 1 else (many or word + 's')}"


def steps_text(v: float) -> str:
    """An env-step count as an axis tick: 0, 500, 4k, 12.5k, 3M, 3.6M (never "3000k")."""
    v = float(v)
    if v == 0:
        return "0"
    for size, unit in ((1e6, "M"), (1e3, "k")):
        if abs(v) >= size:
            return f"{v / size:g}{unit}"
    return f"{v:g}"


def fmt(v) -> str:
    """A table cell: floats to 6 significant digits (nan as 'nan'), None as empty."""
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.6g}"
    return "" if v is None else str(v)


def csv_text(rows: List[dict], columns: Optional[List[str]] = None) -> str:
    """CSV of dict rows (columns: given, or in order of first appearance), cells through ``fmt``."""
    if columns is None:
        columns = []
        for r in rows:
            columns += [k for k in r if k not in columns]
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: fmt(r.get(k)) for k in columns})
    return buf.getvalue()
