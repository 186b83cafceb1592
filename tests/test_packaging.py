"""Installed import names: maniskill_dualher.tasks / .baselines, never top-level `tasks` / `baselines`."""
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_installed_package_namespaces_tasks_and_baselines(tmp_path):
    """`pip install .` into a fresh folder (its own site, dependencies from this environment), then
    import from outside the repository."""
    py = sys.executable
    r = subprocess.run([py, "-m", "pip", "install", "-q", "--no-deps", "--no-build-isolation",
                        "--target", str(tmp_path / "site"), str(REPO)], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    site = tmp_path / "site"
    assert (site / "maniskill_dualher" / "tasks" / "reach_target.py").is_file()
    assert (site / "maniskill_dualher" / "baselines" / "sac.py").is_file()
    assert not (site / "tasks").exists() and not (site / "baselines").exists()
    env = {"PYTHONPATH": str(site), "PATH": "/usr/bin:/bin"}
    run = lambda code: subprocess.run([py, "-c", code], cwd=tmp_path, env=env,  # noqa: E731
                                      capture_output=True, text=True)
    ok = run("import maniskill_dualher, maniskill_dualher.tasks, maniskill_dualher.baselines.sac as b; "
             "print(maniskill_dualher.__file__, b.SACReplay.__name__)")
    assert ok.returncode == 0, ok.stderr[-2000:]
    assert str(site) in ok.stdout and "SACReplay" in ok.stdout
    for name in ("tasks", "baselines"):
        bad = run(f"import {name}")
        assert bad.returncode != 0 and "No module named" in bad.stderr
