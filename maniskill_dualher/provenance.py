"""Where and with what a result was made: code version, library versions, machine.

``provenance()`` returns a JSON-ready dict; ``train.py`` appends one per process start to a run folder's
``provenance.json`` (``{"starts": [...]}``, ``rundir.record_start``). Nothing here imports a heavy library that is
not already loaded, and every probe that can fail (no git, no /proc) gives ``None`` instead.
"""
from __future__ import annotations

import datetime as _dt
import os
import platform
import socket
import subprocess
import sys
from importlib import metadata
from pathlib import Path
from typing import Optional, Union

PACKAGES = ("torch", "numpy", "mani_skill", "sapien", "scipy", "gymnasium")
_DIST_NAMES = {"mani_skill": "mani-skill"}


def _git(args, cwd: Path) -> Optional[str]:
    try:
        r = subprocess.run(["git", *args], cwd=str(cwd), capture_output=True, text=True, timeout=20)
    except (OSError, subprocess.SubprocessError):
        return None
    return r.stdout.strip() if r.returncode == 0 else None


def git_state(path: Union[str, Path, None] = None) -> dict:
    """{"commit", "commit_short", "dirty", "repo"} of the git work tree holding ``path`` (default: this
    package's source). ``dirty``: tracked files differ from the commit (untracked files do not count).
    All None when the package is not in a git checkout (e.g. installed from a wheel)."""
    here = Path(path) if path is not None else Path(__file__).resolve().parent
    top = _git(["rev-parse", "--show-toplevel"], here)
    commit = _git(["rev-parse", "HEAD"], here) if top else None
    if not commit:
        return {"commit": None, "commit_short": None, "dirty": None, "repo": None}
    status = _git(["status", "--porcelain", "--untracked-files=no"], here)
    return {"commit": commit, "commit_short": commit[:7], "dirty": None if status is None else bool(status),
            "repo": top}


def _version(name: str) -> Optional[str]:
    mod = sys.modules.get(name)
    v = getattr(mod, "__version__", None) if mod is not None else None
    if v is None:
        try:
            v = metadata.version(_DIST_NAMES.get(name, name))
        except metadata.PackageNotFoundError:
            return None
    return str(v)


def cpu_info() -> dict:
    """CPU model line, AVX-512 BF16 / AMX / AVX2 flags (from /proc/cpuinfo on Linux), logical cores, and the
    CPU's family/model numbers: the model line of a VM can hide the generation ("AMD EPYC" is family 25 for
    Zen 3/4, 26 for Zen 5), which moves speed by up to 2x at the same flags (docs/speed.md)."""
    model, flags, ids = None, set(), {}
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                key, _, val = line.partition(":")
                key = key.strip()
                if key == "model name" and model is None:
                    model = val.strip()
                elif key == "flags" and not flags:
                    flags = set(val.split())
                elif key in ("cpu family", "model") and key not in ids:
                    ids[key] = val.strip()
                if model is not None and flags and len(ids) == 2:
                    break
    except OSError:
        pass
    try:
        usable = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        usable = None
    return {"model": model or platform.processor() or None, "cores": os.cpu_count(), "cores_usable": usable,
            "avx512_bf16": ("avx512_bf16" in flags) if flags else None,
            "amx_bf16": ("amx_bf16" in flags) if flags else None,
            "avx2": ("avx2" in flags) if flags else None,
            "family_model": f"{ids['cpu family']}/{ids['model']}" if len(ids) == 2 else None}


def machine_label(cpu: Optional[dict]) -> str:
    """A CPU in a few words, for tables: its model line and the instruction sets that change speed and
    rounding (AVX-512 BF16, AMX, AVX2); "" when unknown."""
    if not cpu or not cpu.get("model"):
        return ""
    isa = "+".join(k for k in ("avx512_bf16", "amx_bf16") if cpu.get(k)) or ("avx2" if cpu.get("avx2") else "")
    return f"{cpu['model']} ({isa})" if isa else str(cpu["model"])


def machine_name(cpu: Optional[dict]) -> str:
    """The machine as the README's machines table names it (CPU A: Intel Xeon with AVX512-BF16 and AMX; CPU B:
    AMD EPYC with AVX512-BF16; CPU C: AMD EPYC with AVX2 only), or ``machine_label`` for any other CPU."""
    if not cpu or not cpu.get("model"):
        return ""
    model = str(cpu["model"])
    if "Xeon" in model and cpu.get("amx_bf16") and cpu.get("avx512_bf16"):
        return "CPU A"
    if "EPYC" in model and cpu.get("avx512_bf16") and not cpu.get("amx_bf16"):
        return "CPU B"
    if "EPYC" in model and cpu.get("avx2") and not cpu.get("avx512_bf16"):
        return "CPU C"
    return machine_label(cpu)


def _torch_info() -> dict:
    try:
        import torch
    except ImportError:
        return {"threads": None, "gpu": None}
    gpu = None
    try:
        if torch.cuda.is_available():
            gpu = [torch.cuda.get_device_name(i) for i in range(torch.cuda.device_count())]
    except Exception:  # a broken driver must not stop a run
        gpu = None
    return {"threads": torch.get_num_threads(), "gpu": gpu, "cuda": getattr(torch.version, "cuda", None)}


def provenance(path: Union[str, Path, None] = None) -> dict:
    """Code (git commit and dirty flag of the package's repository, or of ``path``), Python and library
    versions, CPU model and flags, core count, torch threads, GPUs, hostname, UTC time, command line."""
    t = _torch_info()
    return {
        "time_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ"),
        **git_state(path),  # commit, commit_short, dirty, repo
        "python": platform.python_version(),
        "versions": {name: _version(name) for name in PACKAGES},
        "package": _version("maniskill_dualher"),
        "cpu": cpu_info(),
        "torch_threads": t["threads"],
        "gpu": t["gpu"],
        "cuda": t.get("cuda"),
        "hostname": socket.gethostname(),
        "platform": platform.platform(),
        "pid": os.getpid(),
        "argv": list(sys.argv),
    }


if __name__ == "__main__":
    import json

    print(json.dumps(provenance(), indent=2))
