"""Run a bench script (bench/<name>) as a user does, in a fresh process on this tree."""
import importlib.util
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run_bench(script: str, *args):
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, str(ROOT / "bench" / script), *args], env=env,
                          capture_output=True, text=True)


def load_bench(script: str):
    """bench/<script> as a module (its functions called in this process); registered in sys.modules under its
    name, where dataclasses look their module up."""
    name = Path(script).stem
    spec = importlib.util.spec_from_file_location(name, ROOT / "bench" / script)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod
