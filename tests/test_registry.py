"""A new method is one file plus one registry line; the project has no import circles."""
from __future__ import annotations

import ast
import csv
from pathlib import Path
from typing import Optional

import pytest

from maniskill_dualher import methods, report, sweep
from maniskill_dualher.replay.base import Batch, Episode
from maniskill_dualher.replay.her import episode_transitions
from maniskill_dualher.replay.method import BufferMethod

REPO = Path(__file__).resolve().parents[1]


# --------------------------------------------------------------------------- the whole "one file" of a method
class SACHerReplay(BufferMethod):
    """SAC + HER with uniform replay (no prioritization): the method a user adds in an afternoon."""
    uses_goals = True

    def __init__(self, cfg, spec, rng, device="cpu"):
        super().__init__(cfg, spec, rng, device)
        self._buffer("R", prioritized=False)

    def add_episode(self, ep: Episode) -> None:
        self._check_goal_episode(ep)
        self.main.add(episode_transitions(ep, self.rcfg.her_strategy, self.rcfg.her_k, self.rng, self.reward_fn))

    def sample(self, batch_size: Optional[int] = None) -> Batch:
        return self.main.sample(batch_size or self.batch_size, self.rng, self.device)


@pytest.fixture
def registered(monkeypatch):
    """The one registry line (here added at run time; in the project it is a line in methods.py)."""
    spec = methods.MethodSpec("sac_her", f"{__name__}:SACHerReplay", "SAC+HER", "tab:green")
    monkeypatch.setitem(methods.METHOD_SPECS, spec.name, spec)
    return spec


def _rows(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_a_registered_method_takes_part_everywhere(registered, tmp_path, monkeypatch):
    labels = []
    plot = report._plot_groups
    monkeypatch.setattr(report, "_plot_groups", lambda ax, groups, *a: (labels.extend(groups), plot(ax, groups, *a)))
    out = tmp_path / "sweep"
    rc = sweep.main(["--preset", "smoke", "--out", str(out), "--backend", "inline", "--seeds", "1",
                     "--methods", "sac_her,sac_her_per", "--experiments", "single,transfer,scratch",
                     "--tasks", "ReachTarget-v1"])
    assert rc == 0
    single = _rows(out / "single_task.csv")
    assert {r["method"] for r in single} == {"sac_her", "sac_her_per"}
    t5 = _rows(out / "table5_multitask.csv")
    assert {(r["chain"], r["method"]) for r in t5 if r["method"] == "sac_her"} == {
        (" > ".join(sweep.protocol.TRANSFER_ORDER), "sac_her"), (report.SCRATCH, "sac_her")}
    assert "sac_her" in labels and f"sac_her {report.SCRATCH}" in labels   # Fig. 4 and Fig. 5 curves
    assert report.color_of("sac_her") == "tab:green"
    assert "sac_her" in (out / "summary.md").read_text()
    assert list((out / "runs" / "transfer").glob("sac_her-s0/stage2-*"))


def test_unknown_method_names_the_registry(capsys):
    assert sweep.main(["--methods", "nope", "--dry-run"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "nope" in err and "sac_her_per" in err


def _imports(path: Path, package: str):
    """Project modules imported by one file (absolute and relative, any depth in the file)."""
    tree = ast.parse(path.read_text())
    mod = ".".join(path.relative_to(REPO).with_suffix("").parts)
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = mod.split(".")[: -node.level]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            out.add(name)
            out |= {f"{name}.{a.name}" for a in node.names}
    return {m for m in out if m.split(".")[0] == package}


def test_no_import_circles_among_core_modules():
    """Module-level import graph of maniskill_dualher/*.py (including deferred imports) has no cycle."""
    files = {".".join(p.relative_to(REPO).with_suffix("").parts): p
             for p in (REPO / "maniskill_dualher").rglob("*.py") if p.name != "__init__.py"}
    graph = {m: {i for i in _imports(p, "maniskill_dualher") if i in files and i != m} for m, p in files.items()}
    state = {}

    def visit(m, path):
        if state.get(m) == 1:
            raise AssertionError("import circle: " + " -> ".join(path + [m]))
        if state.get(m) == 2:
            return
        state[m] = 1
        for n in graph[m]:
            visit(n, path + [m])
        state[m] = 2

    for m in graph:
        visit(m, [])
    assert "maniskill_dualher.sweep" not in graph["maniskill_dualher.report"]
