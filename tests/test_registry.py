"""A new method is one file plus one registry line; the project has no import circles."""
from __future__ import annotations

import ast
import csv
from pathlib import Path
from typing import Optional

import pytest

import json

from maniskill_dualher import methods
from maniskill_dualher.analysis.plots import color_of
from maniskill_dualher.config import TASKS
from maniskill_dualher.experiment import sweep
from maniskill_dualher.experiment.grid import build_grid
from maniskill_dualher.experiment.registry import PAPER_CHAIN, PAPER_TARGET, chain_name
from maniskill_dualher.sweep import main as run_sweep, train_runs as entry_train_runs  # noqa: F401
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


def _collect_labels(monkeypatch):
    """Labels of every curve drawn into a figure."""
    from maniskill_dualher.analysis import plots
    labels = []
    draw = plots.draw
    monkeypatch.setattr(plots, "draw", lambda ax, groups, *a, **k: (labels.extend(groups), draw(ax, groups, *a, **k)))
    return labels


def test_a_registered_method_takes_part_everywhere(registered, tmp_path, monkeypatch):
    labels = _collect_labels(monkeypatch)
    out = tmp_path / "sweep"
    rc = run_sweep(["--preset", "smoke", "--out", str(out), "--backend", "inline", "--seeds", "1",
                     "--methods", "sac_her,sac_her_per", "--experiments", "single,transfer,scratch",
                     "--tasks", "ReachTarget-v1"])
    assert rc == 0
    single = _rows(out / "single_task.csv")
    assert {r["method"] for r in single} == {"sac_her", "sac_her_per"}
    t5 = _rows(out / "table5_multitask.csv")
    assert {(r["experiment"], r["chain"]) for r in t5 if r["method"] == "sac_her"} == {
        ("transfer", chain_name(PAPER_CHAIN)), ("scratch", PAPER_TARGET)}
    assert "SAC+HER" in labels and "SAC+HER, from scratch" in labels   # Fig. 4 and Fig. 5: display names
    assert color_of("sac_her") == "tab:green"
    assert "sac_her" in (out / "summary.md").read_text()
    assert list((out / "runs" / "chain").glob("sac_her-s0/stage2-*"))


def test_an_experiment_with_arms_is_one_registry_entry(tmp_path, monkeypatch):
    """Two adaptation arms (E off, warm start) beside the paper's arm, in one entry: shared source stages,
    rows in the tables, curves in a figure, and a claim comparing two arms in claims.csv."""
    from maniskill_dualher.analysis import claims
    from maniskill_dualher.experiment import registry
    exp = registry.Experiment("my_ablation", "E off vs warm start", "chain", methods=("dual_buffer",), arms=(
        registry.Arm("paper"), registry.Arm("e_off", ("adapt.replay.ratio=1/0",)),
        registry.Arm("warm", ("adapt.sac.random_steps=0",))))
    monkeypatch.setitem(registry.EXPERIMENTS, exp.name, exp)
    claim = claims.Claim("mine", "E off > paper", "", "successful_train_episodes",
                         claims.Side("my_ablation", "e_off", "dual_buffer"),
                         claims.Side("my_ablation", "paper", "dual_buffer"), group="ablation")
    monkeypatch.setattr(claims, "CLAIMS", claims.CLAIMS + [claim])
    labels = _collect_labels(monkeypatch)
    out = tmp_path / "sweep"
    assert run_sweep(["--preset", "smoke", "--out", str(out), "--backend", "inline", "--seeds", "2",
                       "--methods", "dual_buffer", "--experiments", "my_ablation"]) == 0
    runs = sorted(p.parent.name for p in (out / "runs").rglob("config.json"))
    assert len(runs) == 2 * (2 + 3)          # per seed: two shared source stages, three adaptations
    cells = [json.loads(p.read_text()) for p in (out / "runs").rglob("cell.json")]
    assert {c["arm"] for cs in cells for c in cs["cells"]} == {"paper", "e_off", "warm"}
    abl = _rows(out / "ablations.csv")
    assert {r["arm"] for r in abl} == {"paper", "e_off", "warm"}
    cfgs = {json.loads((p.parent / "cell.json").read_text())["cells"][0]["arm"]: json.loads(p.read_text())
            for p in (out / "runs").rglob("config.json") if p.parent.name.startswith("stage2")}
    assert cfgs["e_off"]["replay"]["ratio"] == [1.0, 0.0] and cfgs["warm"]["sac"]["random_steps"] == 0
    assert cfgs["paper"]["replay"]["ratio"] == [0.6, 0.4] and cfgs["paper"]["sac"]["random_steps"] == 100
    assert {"dual buffer, e off", "dual buffer, warm"} <= set(labels)   # display names
    assert [p.name for p in out.glob("fig6*.png")] == [registry.fig6_file("my_ablation")]
    row = next(r for r in _rows(out / "claims.csv") if r["claim"] == "mine")
    assert row["n_a"] == "2" and row["n_b"] == "2" and row["side_a"] == "dual_buffer my_ablation/e_off"


def test_an_experiment_lands_in_the_table_and_figure_it_declares(tmp_path, monkeypatch):
    """A registry entry declaring Table 4 and Fig. 5's ratio panel (a fourth sampling ratio): its rows are in
    table4_sampling_ratio.csv, its curves in the ratio panel, and nowhere it did not declare."""
    from maniskill_dualher.experiment import registry
    exp = registry.Experiment("ratio_08", "A fourth R/E ratio", "chain", methods="sampling_ratio",
                              arms=(registry.Arm("0.8/0.2", ("adapt.replay.ratio=0.8/0.2",)),),
                              feeds=(registry.TABLE4_CSV, registry.FIG5_RATIOS))
    monkeypatch.setitem(registry.EXPERIMENTS, exp.name, exp)
    labels = _collect_labels(monkeypatch)
    out = tmp_path / "sweep"
    assert run_sweep(["--preset", "smoke", "--out", str(out), "--backend", "inline", "--seeds", "1",
                      "--experiments", "ratio_08"]) == 0
    t4 = _rows(out / "table4_sampling_ratio.csv")
    assert {(r["experiment"], r["variant"]) for r in t4} == {("ratio_08", "0.8/0.2")}
    assert not _rows(out / "ablations.csv") and not _rows(out / "table5_multitask.csv")
    assert "dual buffer, P(R)/P(E) = 0.8/0.2" in labels and (out / "fig5_multitask.png").is_file()
    assert not list(out.glob("fig6*.png"))


TINY_TASK = "TinyReach-v1"


@pytest.fixture
def tiny_task():
    """A task registered at run time: its class (ReachTarget with a wider tolerance: the whole "file" of a
    task), its ManiSkill registration (what its import line does) and its id in the catalog (config.TASKS)."""
    from mani_skill.utils.registration import REGISTERED_ENVS, register_env
    from maniskill_dualher.tasks.reach_target import ReachTargetEnv

    class TinyReachEnv(ReachTargetEnv):
        goal_tolerance = 0.12

    if TINY_TASK not in REGISTERED_ENVS:
        register_env(TINY_TASK, max_episode_steps=50)(TinyReachEnv)
    TASKS.append(TINY_TASK)
    yield TINY_TASK
    TASKS.remove(TINY_TASK)


def test_a_task_is_its_file_and_one_id_and_the_papers_chain_is_unchanged(tiny_task, tmp_path, monkeypatch):
    """With a task added to the catalog, the paper's plan is the same runs, on the paper's chain and target (its
    tables unchanged); the task itself plans, trains a few hundred steps and is reported with no other edit."""
    from maniskill_dualher.analysis import tables

    def plan(*argv):
        d = sweep.definition_from_args(sweep.make_parser().parse_args(list(argv)))
        return d, sorted((n.rel, json.dumps(n.cells, sort_keys=True)) for n in build_grid(d))

    TASKS.remove(tiny_task)
    before = {p: plan("--preset", p) for p in ("quick", "reference")}
    TASKS.append(tiny_task)
    for p, (d, nodes) in before.items():
        d2, nodes2 = plan("--preset", p)
        assert nodes2 == nodes and d2 == d, p          # the same definition (sweep.json) and runs
    assert before["quick"][0]["task_order"] == list(PAPER_CHAIN) and tables.PAPER_TARGET == PAPER_CHAIN[-1]
    labels = _collect_labels(monkeypatch)
    out = tmp_path / "sweep"
    assert run_sweep(["--preset", "smoke", "--out", str(out), "--backend", "inline", "--experiments", "single",
                      "--tasks", tiny_task, "--methods", "sac_her_per", "--seeds", "1", "--source-steps", "300"]) == 0
    single = _rows(out / "single_task.csv")
    assert {r["task"] for r in single} == {tiny_task} and {r["n_seeds"] for r in single} == {"1"}
    cfg = json.loads(next((out / "runs" / "single").glob(f"{tiny_task}-*/config.json")).read_text())
    assert cfg["env_id"] == tiny_task and cfg["total_steps"] == 300
    assert "SAC+HER+PER" in labels and (out / "fig4_single_task.png").is_file()
    assert tiny_task in (out / "summary.md").read_text()


def test_unknown_method_names_the_registry(capsys):
    assert run_sweep(["--methods", "nope", "--dry-run"]) == 2
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


def test_no_import_circles_among_the_tasks():
    """tasks/ (maniskill_dualher.tasks): no cycle, deferred imports included; the lean step builds on the task
    base (tasks/lean.py imports tasks/common.py, never the other way)."""
    files = {".".join(p.relative_to(REPO).with_suffix("").parts): p
             for p in (REPO / "tasks").glob("*.py") if p.name != "__init__.py"}
    imports = lambda p: _imports(p, "tasks") | _imports(p, "maniskill_dualher")  # noqa: E731
    graph = {m: {i.replace("maniskill_dualher.tasks.", "tasks.") for i in imports(p)} & set(files) - {m}
             for m, p in files.items()}
    _no_cycle(graph)
    assert "tasks.common" in graph["tasks.lean"] and "tasks.lean" not in graph["tasks.common"]


def _no_cycle(graph) -> None:
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


def test_no_import_circles_among_core_modules():
    """Module-level import graph of maniskill_dualher/*.py (including deferred imports) has no cycle."""
    files = {".".join(p.relative_to(REPO).with_suffix("").parts): p
             for p in (REPO / "maniskill_dualher").rglob("*.py") if p.name != "__init__.py"}
    graph = {m: {i for i in _imports(p, "maniskill_dualher") if i in files and i != m} for m, p in files.items()}
    _no_cycle(graph)
    # the analysis reads the experiment registry and the plan (grid: configs per cell, plain config code, for
    # hyperparameters.csv) but never the runner side (backends, the sweep CLI, its lock, the timed cost, train)
    runner = ("maniskill_dualher.experiment.backends", "maniskill_dualher.experiment.sweep",
              "maniskill_dualher.experiment.lock", "maniskill_dualher.experiment.cost", "maniskill_dualher.train")
    assert not any(m in runner for a in graph if a.startswith("maniskill_dualher.analysis") for m in graph[a])
    assert any(m == "maniskill_dualher.experiment.grid" for a in graph if a.startswith("maniskill_dualher.analysis")
               for m in graph[a])   # hyperparameters.csv from the plan, not from run folders


def test_analysis_needs_no_torch_no_simulator():
    """The analysis wing (scores, statistics, claims, plots) and every project module it imports load neither
    torch, the simulator, train nor the backends at import time: a results folder can be rebuilt and checked
    with numpy/scipy/matplotlib. (The package's __init__ registers the ManiSkill tasks, as documented.)"""
    files = {".".join(p.relative_to(REPO).with_suffix("").parts): p
             for p in (REPO / "maniskill_dualher").rglob("*.py") if p.name != "__init__.py"}

    def top_level(path):
        out = set()
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.Import):
                out |= {a.name for a in node.names}
            elif isinstance(node, ast.ImportFrom):
                mod = ".".join(path.relative_to(REPO).with_suffix("").parts)
                base = mod.split(".")[: -node.level] if node.level else []
                name = ".".join(base + ([node.module] if node.module else []))
                out |= {name} | {f"{name}.{a.name}" for a in node.names}
        return out

    seen, todo = set(), [m for m in files if m.startswith("maniskill_dualher.analysis")]
    while todo:
        m = todo.pop()
        if m in seen:
            continue
        seen.add(m)
        imps = top_level(files[m])
        bad = {i for i in imps if i.split(".")[0] in ("torch", "sapien", "mani_skill", "gymnasium")}
        bad |= {i for i in imps if i in ("maniskill_dualher.train", "maniskill_dualher.experiment.backends")}
        assert not bad, f"{m} imports {sorted(bad)}"
        todo += [i for i in imps if i in files]
    assert "maniskill_dualher.analysis.report" in seen and "maniskill_dualher.config" in seen


def test_docs_experiment_table_is_the_registry():
    """docs/experiments.md's experiment table is the registry's, as `python -m maniskill_dualher.experiment.registry
    --markdown` prints it (`--update-docs docs/experiments.md` writes it): every experiment once, every arm with
    its doc, what each feeds."""
    from maniskill_dualher.experiment import registry
    text = (REPO / "docs" / "experiments.md").read_text()
    assert registry.docs_with_table(text) == text, \
        "docs/experiments.md: run python -m maniskill_dualher.experiment.registry --update-docs docs/experiments.md"
    table = text[text.index(registry.DOCS_BEGIN):text.index(registry.DOCS_END)]
    for name, exp in registry.EXPERIMENTS.items():
        row = next(ln for ln in table.splitlines() if ln.startswith(f"| `{name}` |"))
        assert all(f"`{a.name}`" in row for a in exp.arms) and all(a.doc in row for a in exp.arms)


def test_every_arm_has_a_display_name_and_one_display_means_one_set_of_runs():
    """Legends name arms by their registry display (issue 43): every registry arm declares one unless it is
    the paper's settings; two arms share a display (and so a colour) only when they make the same runs (same
    settings, budget and prior) in experiments of one kind, e.g. budget's x4 and regime's long."""
    from maniskill_dualher.experiment import registry
    seen = {}
    for e in registry.EXPERIMENTS.values():
        for a in e.arms:
            if not a.display:
                assert registry.is_paper_treatment(e.name, a.name), f"{e.name}:{a.name} has no display name"
                assert registry.arm_display(e.name, a.name) == registry.PAPER_DISPLAY
                continue
            assert a.display not in (a.name, a.name.replace("_", " ")) or "/" in a.name, (e.name, a.name)
            shown = registry.arm_display(e.name, a.name)
            ident = (e.kind, frozenset(a.settings), a.adapt_steps_factor, a.prior_method)
            assert seen.setdefault(shown, ident) == ident, f"{shown!r} names two different arms"
    assert registry.arm_display("mechanism", "e_off") == registry.arm_display("e_share", "e_off") + ", from scratch"
    assert registry.fig6_file("e_share") == "fig6a_e_share.png"
    assert len({registry.fig6_file(e) for e in registry.experiments_feeding(registry.FIG6)}) == len(
        registry.experiments_feeding(registry.FIG6))


def test_every_source_file_is_on_the_map():
    """docs/ARCHITECTURE.md is the map: every Python file of the package, the tasks, the baselines, the benches and
    CI is named there, by its path (`bench/env_speed.py`, `experiment/sweep.py`) or its module
    (`maniskill_dualher.tasks.solvers`), so a reader finds each by its file name. `__init__.py` files are not."""
    import subprocess
    text = (REPO / "docs" / "ARCHITECTURE.md").read_text()
    files = subprocess.run(["git", "ls-files", "*.py"], cwd=REPO, capture_output=True, text=True,
                           check=True).stdout.split()
    if not files:
        pytest.skip("not a git checkout")
    missing = []
    for f in files:
        p = Path(f)
        if p.parts[0] not in ("maniskill_dualher", "tasks", "baselines", "bench", ".ci") or p.name == "__init__.py":
            continue
        parts = p.parts if p.parts[0] == "maniskill_dualher" else ("maniskill_dualher",) + p.parts
        if p.parts[0] in ("bench", ".ci"):
            names = {f}
        else:
            inside = "/".join(parts[1:])            # experiment/sweep.py, tasks/solvers.py
            names = {f, inside, "/".join(parts), ".".join(parts)[:-3]}
            names |= {n[:-3] for n in list(names)}
        if not any(n in text for n in names):
            missing.append(f)
    assert not missing, f"not named in docs/ARCHITECTURE.md: {missing}"
