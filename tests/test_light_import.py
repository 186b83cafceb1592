"""The analysis runs where torch, SAPIEN and ManiSkill are absent: ``import maniskill_dualher.analysis.report``
(and the package itself) in a subprocess where those imports fail; the experiment layer imports no training,
command-line or analysis code (late imports included)."""
import ast
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
HEAVY = ("torch", "sapien", "mani_skill")

BLOCKER = '''
import sys
class _Block:
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in %r:
            raise ImportError("blocked for this test: " + name)
        return None
sys.meta_path.insert(0, _Block())
''' % (HEAVY,)


def _run_blocked(tmp_path, code: str) -> subprocess.CompletedProcess:
    (tmp_path / "sitecustomize.py").write_text(BLOCKER)
    env = {"PYTHONPATH": f"{tmp_path}:{REPO}", "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    return subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)


def test_the_blocker_blocks(tmp_path):
    p = _run_blocked(tmp_path, "import torch")
    assert p.returncode != 0 and "blocked for this test: torch" in p.stderr


def test_the_analysis_imports_without_torch_sapien_or_maniskill(tmp_path):
    p = _run_blocked(tmp_path, "import maniskill_dualher, maniskill_dualher.analysis.report, "
                               "maniskill_dualher.report, maniskill_dualher.experiment.registry; print('ok')")
    assert p.returncode == 0, p.stderr[-2000:]
    assert p.stdout.strip() == "ok"


def _imports(path: Path):
    """Every module a file imports, at any depth (late imports included), as absolute dotted names."""
    pkg = "maniskill_dualher.experiment"
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module
            yield mod
            yield from (f"{mod}.{a.name}" for a in node.names)


def test_the_experiment_layer_imports_no_train_cli_or_analysis():
    banned = ("maniskill_dualher.train", "maniskill_dualher.cli", "maniskill_dualher.analysis",
              )  # pack.py (pack_key) sits below train and loads no torch at import
    bad = [(f.name, m) for f in sorted((REPO / "maniskill_dualher" / "experiment").glob("*.py"))
           for m in _imports(f) if m and m.startswith(banned)]
    assert bad == []


def test_hyperparameters_of_a_results_folder_are_built_without_torch(tmp_path):
    """hyperparameters.csv comes from sweep.json through the grid's configs: that path loads no torch either
    (RunConfig.validate on device cpu), so `report results/reference` runs where torch is absent."""
    code = ("import json; from pathlib import Path; from maniskill_dualher.analysis import hyperparameters as h; "
            "from maniskill_dualher.analysis.runs import read_rows; from maniskill_dualher.fileio import csv_text; "
            f"f = Path({str(REPO / 'results' / 'reference')!r}); "
            "rows = h.hyperparameter_rows(h.cell_configs(json.loads((f / 'sweep.json').read_text()), "
            "read_rows(f / 'scores.csv'))); "
            "print(csv_text(rows, h.COLUMNS) == (f / 'hyperparameters.csv').read_text())")
    p = _run_blocked(tmp_path, code)
    assert p.returncode == 0, p.stderr[-2000:]
    assert p.stdout.strip() == "True"


def test_report_and_sweep_without_matplotlib_say_what_to_install(tmp_path):
    """matplotlib is a dependency (report ends every sweep); an install that lacks it gets one line saying what
    to install, exit 2, no traceback: from report, and from sweep before it trains anything."""
    (tmp_path / "sitecustomize.py").write_text(BLOCKER.replace(repr(HEAVY), repr(("matplotlib",))))
    env = {"PYTHONPATH": f"{tmp_path}:{REPO}", "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    import shutil
    shutil.copytree(REPO / "results" / "reference", tmp_path / "ref")
    for argv in (["maniskill_dualher.report", str(tmp_path / "ref")],
                 ["maniskill_dualher.sweep", "--preset", "smoke", "--out", str(tmp_path / "sweep")]):
        p = subprocess.run([sys.executable, "-m", *argv], cwd=tmp_path, env=env, capture_output=True, text=True)
        err = p.stderr.strip().splitlines()
        assert p.returncode == 2 and len(err) == 1, p.stderr[-2000:]
        assert err[0].startswith("error: ") and "matplotlib" in err[0] and "pip install 'matplotlib" in err[0]
    assert not (tmp_path / "sweep").exists()
