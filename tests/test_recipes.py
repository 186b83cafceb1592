"""The recipes of docs/ARCHITECTURE.md on the real thing: a method, a task, an experiment and a claim, each added
at run time as a researcher adds it (a method: its file, here the class below, and one ``MethodSpec`` line; a
task: its class, its registration and its id in ``config.TASKS``; an experiment: one ``Experiment``; a claim: one
``Claim``). Then every preset plans ``--experiments all`` (and the new task's own plan), the reference preset's
plan is the runs it was, and the report of a copy of ``results/reference`` is byte for byte what is committed,
but for the new claim's own rows in ``claims.csv`` and ``summary.md``."""
from __future__ import annotations

import difflib
import json
import re
import shutil
from pathlib import Path

import pytest

from maniskill_dualher import methods
from maniskill_dualher.analysis import claims
from maniskill_dualher.config import TASKS
from maniskill_dualher.experiment import cost, registry, sweep
from maniskill_dualher.experiment.grid import build_grid
from maniskill_dualher.experiment.presets import PRESETS
from maniskill_dualher.experiment.registry import PAPER_CHAIN

from test_registry import SACHerReplay

REFERENCE = Path(__file__).resolve().parents[1] / "results" / "reference"
NEW_METHOD, NEW_TASK, NEW_EXPERIMENT, NEW_CLAIM = "recipe_sac_her", "RecipeReach-v1", "recipe", "recipe_claim"


# the whole file of a new method: test_registry's SAC + HER with uniform replay, registered here under its own name
RecipeSACHerReplay = SACHerReplay


def _plan(*argv):
    """The sweep's definition and its runs (folder, cells), as ``sweep --dry-run`` plans them."""
    d = sweep.definition_from_args(sweep.make_parser().parse_args(list(argv)))
    return d, sorted((n.rel, json.dumps(n.cells, sort_keys=True)) for n in build_grid(d))


@pytest.fixture
def additions(monkeypatch):
    """One of each recipe, registered at run time; the registries are restored afterwards. Yields the reference
    preset's plan of every experiment from before the additions."""
    import gymnasium as gym
    from mani_skill.utils.registration import REGISTERED_ENVS, register_env
    from maniskill_dualher.tasks.reach_target import ReachTargetEnv

    before = _plan("--preset", "reference", "--experiments", "all")
    # a method: its file (the class above) and its one registry line (appended: it restyles no other method)
    monkeypatch.setitem(methods.METHOD_SPECS, NEW_METHOD, methods.MethodSpec(
        NEW_METHOD, f"{__name__}:RecipeSACHerReplay", "SAC+HER (recipe)", "tab:green"))

    # a task: its file (a PandaGoalEnv subclass registered with ManiSkill: what its import line does) and its id
    class RecipeReachEnv(ReachTargetEnv):
        goal_tolerance = 0.1
        success_text = "the TCP within 0.1 m of the red ball"

    registered = NEW_TASK not in REGISTERED_ENVS
    if registered:
        register_env(NEW_TASK, max_episode_steps=50)(RecipeReachEnv)
    TASKS.append(NEW_TASK)                               # config.TASKS itself: removed again below
    # an experiment: one entry (arms: the paper's settings and one change)
    monkeypatch.setitem(registry.EXPERIMENTS, NEW_EXPERIMENT, registry.Experiment(
        NEW_EXPERIMENT, "A recipe's experiment", "chain", methods="transfer", arms=(
            registry.Arm("paper"),
            registry.Arm("warm", ("adapt.sac.random_steps=0",), display="recipe: no random steps"))))
    # a claim: one entry
    monkeypatch.setattr(claims, "CLAIMS", claims.CLAIMS + [claims.Claim(
        NEW_CLAIM, f"{NEW_METHOD} > sac_her_per: successful adaptation episodes", "", "successful_train_episodes",
        claims.Side(NEW_EXPERIMENT, "warm", NEW_METHOD), claims.Side("transfer", "paper", "sac_her_per"),
        group="ablation")])
    try:
        yield before
    finally:
        TASKS.remove(NEW_TASK)
        if registered:
            REGISTERED_ENVS.pop(NEW_TASK, None)
            gym.registry.pop(NEW_TASK, None)


def _cells(nodes, **where):
    return [c for _, cells in nodes for c in json.loads(cells) if all(c[k] == v for k, v in where.items())]


def test_a_method_task_experiment_and_claim_by_their_recipes(additions, tmp_path, monkeypatch, capsys):
    # (a) every preset plans every experiment (exit 0, in process as the command runs); the paper preset's
    # 10^7-row replays as on a machine with the memory they need (the dry run refuses runs this one cannot hold)
    monkeypatch.setenv(cost.MEMORY_ENV, str(64 << 30))
    for preset in PRESETS:
        assert sweep.main(["--preset", preset, "--experiments", "all", "--dry-run", "--out",
                           str(tmp_path / "plan")]) == 0, (preset, capsys.readouterr().err)
        assert sweep.main(["--preset", preset, "--experiments", "single", "--tasks", NEW_TASK, "--dry-run",
                           "--out", str(tmp_path / "plan")]) == 0, (preset, capsys.readouterr().err)
    capsys.readouterr()
    # the new method joins the experiments that take every method or every transfer method, and no arm whose
    # prior it does not adopt; the new task joins no default plan, the new experiment plans both
    _, quick = _plan("--preset", "quick", "--experiments", "all")
    assert {(c["experiment"], c["arm"]) for c in _cells(quick, method=NEW_METHOD)} >= {
        ("single", "paper"), ("transfer", "paper"), ("scratch", "paper"), (NEW_EXPERIMENT, "paper"),
        (NEW_EXPERIMENT, "warm")}
    assert not _cells(quick, method=NEW_METHOD, experiment="shared_prior")
    assert not _cells(quick, method=NEW_METHOD, experiment="paper_regime")
    assert {c["method"] for c in _cells(quick, experiment="shared_prior", role="adapt")} == {"sac_her_per",
                                                                                             "dual_buffer"}
    assert not _cells(quick, task=NEW_TASK)
    _, own = _plan("--preset", "quick", "--experiments", "single", "--tasks", NEW_TASK)
    assert {c["task"] for c in _cells(own)} == {NEW_TASK} and _cells(own, method=NEW_METHOD)
    # the reference preset plans the runs it did (the definition names the new experiment and method beside
    # them): none of the new entries has a cell in results/reference
    d, nodes = _plan("--preset", "reference", "--experiments", "all")
    assert nodes == additions[1]
    assert {k: v for k, v in d.items() if k not in ("experiments", "methods")} == \
        {k: v for k, v in additions[0].items() if k not in ("experiments", "methods")}

    # (b) the report of a copy of the reference: every file as committed but the claim's own rows
    folder = tmp_path / "reference"
    shutil.copytree(REFERENCE, folder)
    from maniskill_dualher.analysis.report import main as report_main
    assert report_main([str(folder)]) == 0
    changed = sorted(str(p.relative_to(folder)) for p in folder.rglob("*") if p.is_file()
                     and p.read_bytes() != (REFERENCE / p.relative_to(folder)).read_bytes())
    assert changed == ["claims.csv", "summary.md"]
    assert sorted(str(p.relative_to(folder)) for p in folder.rglob("*")) == \
        sorted(str(p.relative_to(REFERENCE)) for p in REFERENCE.rglob("*"))
    # the claim's row added to claims.csv; summary.md names it among its family's claims not measured here, and
    # counts one more of them; nothing else changes
    def norm(text):
        text = re.sub(r"; (\d+) more (?:is|are) not measured here", "; N more not measured here", text)
        return [ln for ln in text.splitlines() if not ln.startswith("Not measured here")]
    for name in changed:
        old, new = (REFERENCE / name).read_text(), (folder / name).read_text()
        if name == "summary.md":
            assert any(NEW_CLAIM in ln for ln in new.splitlines() if ln.startswith("Not measured here"))
            old, new = norm(old), norm(new)
        else:
            old, new = old.splitlines(), new.splitlines()
        diff = [d for d in difflib.ndiff(old, new) if d[:1] in "+-"]
        assert all(d.startswith("+ ") and (NEW_CLAIM in d or not d[2:].strip()) for d in diff), (name, diff)
        assert (name == "summary.md") or (len(diff) == 1 and NEW_CLAIM in diff[0]), (name, diff)


def test_tests_and_benches_read_the_catalog():
    """No test or bench lists the paper's tasks by hand, nor builds its chain from the catalog: task ids come from
    ``config.TASKS``, the chain from ``registry.PAPER_CHAIN`` (``chain_name`` for a cell's text)."""
    root = Path(__file__).resolve().parents[1]
    for path in sorted((root / "tests").glob("*.py")) + sorted((root / "bench").glob("*.py")):
        if path == Path(__file__).resolve():
            continue   # this test names what it looks for
        text = path.read_text()
        assert '" > ".join(TASKS)' not in text, path.name
        listed = [i for i, line in enumerate(text.splitlines(), 1) if all(t in line for t in PAPER_CHAIN)]
        assert not listed, f"{path.name}:{listed[0]} lists the paper's tasks by hand"
