"""Constraints `name==floor` for every direct dependency in pyproject.toml (and the test extra's pytest): the
lowest allowed versions, which .ci/run installs in a venv of their own to run a fast subset of the tests.

torch is the exception: its PyPI builds pull CUDA (gigabytes), so it is pinned to the build this Python has
(.ci/run installs the local CPU one first). A floor that names no release fails the install, loudly.

    python .ci/floors.py > floors.txt
"""
import re
import sys
from pathlib import Path

import tomllib

ROOT = Path(__file__).resolve().parents[1]
PINNED = {"torch"}  # name -> this Python's installed version


def floors(project: dict) -> list:
    reqs = list(project["dependencies"]) + [r for r in project["optional-dependencies"]["test"]
                                            if r.startswith("pytest")]
    out = []
    for req in reqs:
        m = re.fullmatch(r"([A-Za-z0-9_.\-]+)(\[[^\]]*\])?\s*(.*)", req.strip())
        name, spec = m.group(1), m.group(3)
        if name in PINNED:
            from importlib.metadata import version
            out.append(f"{name}=={version(name)}")
            continue
        low = re.search(r">=\s*([0-9][^,;\s]*)", spec)
        if not low:
            sys.exit(f"error: {req!r} in pyproject.toml has no floor (>=)")
        out.append(f"{name}=={low.group(1)}")
    return out


if __name__ == "__main__":
    print("\n".join(floors(tomllib.loads((ROOT / "pyproject.toml").read_text())["project"])))
