"""After training: policy files (policy.pt, policy_best.pt), load_policy, the evaluate CLI (own task and
zero-shot), trajectories and movies, error.txt on a failed run, provenance.json, extra TensorBoard charts."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from maniskill_dualher import rundir
from maniskill_dualher.config import TASKS, ConfigError, ReplayConfig, RunConfig, SACConfig
from maniskill_dualher.envs import EVAL_SEED_BASE
from maniskill_dualher.evaluate import (HELDOUT_SEED_BASE, _episode, evaluate_policy, main, make_eval_env, success_ci,
                                        zero_shot_matrix)
from maniskill_dualher.policy import Policy, load_policy, save_policy
from maniskill_dualher.train import Trainer, run_one, run_training

from batched_goal_env import register


def tiny(env_id="ReachTarget-v1", steps=200, **kw) -> RunConfig:
    return RunConfig(env_id=env_id, method="dual_buffer", seed=3, total_steps=steps, max_episode_steps=25,
                     eval_every=100, eval_episodes=2, checkpoint_every=10_000,
                     sac=SACConfig(random_steps=100, learning_starts=50, batch_size=32, hidden=(32, 32)),
                     replay=ReplayConfig(capacity=20_000, her_k=2), **kw)


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """One tiny ReachTarget run, plus the trainer's own deterministic rollouts on the evaluation seeds."""
    out = tmp_path_factory.mktemp("run") / "reach"
    cfg = tiny()
    t = Trainer(cfg, out, show_progress=False)
    final = run_one(t)
    probe = np.random.default_rng(0).normal(size=(16, t.spec.input_dim)).astype(np.float32)
    agent_actions = t.agent.act(probe, deterministic=True)
    rollouts = [t._rollout(EVAL_SEED_BASE + i, lambda x: t.agent.act(x, deterministic=True))[0]
                for i in range(cfg.eval_episodes)]
    evaluated = t.evaluate()
    t.env.close()
    return {"out": out, "cfg": cfg, "final": final, "trainer": t, "probe": probe,
            "agent_actions": agent_actions, "rollouts": rollouts, "evaluated": evaluated}


def test_the_lean_evaluation_gives_the_full_rollouts_metrics(trained):
    """Trainer.evaluate (lean: scores only, the bare forward) equals the metrics of the full episodes that
    rollout and agent.act give on the same seeds (ReachTarget: no contact, reproducible across resets)."""
    eps = trained["rollouts"]
    assert trained["evaluated"] == {
        "eval_return": float(np.mean([e.reward.sum() for e in eps])),
        "eval_success_rate": float(np.mean([e.success.any() for e in eps])),
        "eval_success_at_end": float(np.mean([e.success[-1].any() for e in eps])),
        "eval_episode_length": float(np.mean([e.length for e in eps]))}


# --------------------------------------------------------------------------- policy files
def point_cfg(steps=600, **kw) -> RunConfig:
    return RunConfig(env_id=register(3), method="dual_buffer", seed=1, total_steps=steps, max_episode_steps=20,
                     num_envs=3, eval_every=100, eval_episodes=3, checkpoint_every=10**6,
                     sac=SACConfig(random_steps=10**9, learning_starts=100, batch_size=16, hidden=(16, 16)),
                     replay=ReplayConfig(capacity=50_000, her_k=2), **kw)


SCRIPTED = {1: 0.0, 2: 1 / 3, 3: 1.0, 4: 1 / 3, 5: 1.0, 6: 2 / 3}  # eval success by env_steps // 100


def scripted_evaluate(self):
    return {"eval_return": 0.0, "eval_success_rate": SCRIPTED[self.env_steps // 100],
            "eval_success_at_end": 0.0, "eval_episode_length": 1.0}


def test_policy_files_at_every_evaluation_and_the_best_kept_across_resume(tmp_path, monkeypatch):
    import maniskill_dualher.train as train_mod
    monkeypatch.setattr(Trainer, "evaluate", scripted_evaluate)
    saved = []
    real_save = train_mod.save_policy
    monkeypatch.setattr(train_mod, "save_policy",
                        lambda a, path, **kw: (saved.append((Path(path).name, kw["env_steps"])), real_save(a, path, **kw))[1])

    run_training(point_cfg(), tmp_path / "straight", show_progress=False)
    rows = rundir.read_metrics(tmp_path / "straight")
    steps = [int(r["env_steps"]) for r in rows]
    assert [s // 100 for s in steps] == [1, 2, 3, 4, 5, 6]
    assert [s for name, s in saved if name == "policy.pt"] == steps  # every evaluation
    assert [s for name, s in saved if name == "policy_best.pt"] == [steps[0], steps[1], steps[2]]  # ties keep the earlier
    best = torch.load(tmp_path / "straight" / "policy_best.pt", weights_only=True)
    last = torch.load(tmp_path / "straight" / "policy.pt", weights_only=True)
    assert (best["env_steps"], best["eval_success"]) == (steps[2], 1.0)
    assert (last["env_steps"], last["eval_success"]) == (steps[5], pytest.approx(2 / 3))

    # paused after the best evaluation and resumed: the best is remembered (checkpoint counters)
    assert run_training(point_cfg(), tmp_path / "resumed", show_progress=False, stop_at=350) is None
    saved.clear()
    run_training(point_cfg(), tmp_path / "resumed", show_progress=False)
    assert not [s for name, s in saved if name == "policy_best.pt"]  # the tie at eval 5 did not replace it
    again = torch.load(tmp_path / "resumed" / "policy_best.pt", weights_only=True)
    assert (again["env_steps"], again["eval_success"]) == (steps[2], 1.0)
    starts = json.loads((tmp_path / "resumed" / "provenance.json").read_text())["starts"]
    assert len(starts) == 2  # one per process start


def test_old_checkpoint_without_best_counter_resumes(tmp_path, monkeypatch):
    monkeypatch.setattr(Trainer, "evaluate", scripted_evaluate)
    run_training(point_cfg(), tmp_path / "r", show_progress=False, stop_at=350)
    state = torch.load(tmp_path / "r" / "checkpoint.pt", weights_only=True)
    del state["counters"]["best_eval_success"]
    torch.save(state, tmp_path / "r" / "checkpoint.pt")
    (tmp_path / "r" / "policy_best.pt").unlink()
    run_training(point_cfg(), tmp_path / "r", show_progress=False)
    best = torch.load(tmp_path / "r" / "policy_best.pt", weights_only=True)
    assert best["eval_success"] == 1.0 and best["env_steps"] // 100 == 5  # first 1.0 after the resume


def test_load_policy_acts_like_the_agent(trained):
    t, out = trained["trainer"], trained["out"]
    pol = load_policy(out)
    assert isinstance(pol, Policy) and pol.path == out / "policy.pt"
    assert (pol.env_id, pol.input_dim, pol.obs_dim, pol.goal_dim, pol.act_dim, pol.hidden) == \
        ("ReachTarget-v1", 43, 40, 3, 8, (32, 32))
    assert pol.env_steps == trained["final"]["env_steps"] == 200
    assert pol.eval_success == trained["final"]["eval_success_rate"]
    assert pol.control_mode == "pd_joint_delta_pos" and pol.max_episode_steps == 25 and pol.terminate_on_success
    assert pol.config == trained["cfg"].to_dict()
    # bit-identical to the agent's deterministic action: batch, single row, and the flat observation
    x = trained["probe"]
    np.testing.assert_array_equal(pol.act(x), trained["agent_actions"])
    # (one row: compared with the agent on one row; a BLAS kernel may round differently per batch size)
    np.testing.assert_array_equal(pol.act(x[0]), t.agent.act(x[:1], deterministic=True)[0])
    flat = np.concatenate([x[:, :40], np.ones((len(x), 3), np.float32), x[:, 40:]], -1)  # achieved goal inserted
    np.testing.assert_array_equal(pol.act(flat), trained["agent_actions"])
    a = pol.act(x, deterministic=False)
    assert a.shape == (16, 8) and np.all(np.abs(a) <= 1) and not np.array_equal(a, trained["agent_actions"])
    with pytest.raises(ValueError, match="width 7"):
        pol.act(np.zeros(7, np.float32))
    best = load_policy(out, best=True)
    assert best.path.name == "policy_best.pt"
    assert best.eval_success == max(r["eval_success_rate"] for r in rundir.read_metrics(out))


def test_save_policy_from_an_agent(trained, tmp_path):
    t = trained["trainer"]
    save_policy(t.agent, tmp_path / "p.pt", spec=t.spec, cfg=t.cfg, env_steps=7)
    pol = load_policy(tmp_path / "p.pt")
    assert pol.env_steps == 7 and pol.eval_success is None
    np.testing.assert_array_equal(pol.act(trained["probe"]), trained["agent_actions"])
    with pytest.raises(TypeError, match="spec"):  # explicit arguments: nothing is guessed from the agent
        save_policy(t.agent, tmp_path / "q.pt")


def test_load_policy_bad_input(tmp_path, trained):
    with pytest.raises(ConfigError, match="no such run folder"):
        load_policy(tmp_path / "nope")
    with pytest.raises(ConfigError, match="no policy file policy.pt"):
        load_policy(tmp_path)
    with pytest.raises(ConfigError, match="not a policy file"):
        load_policy(trained["out"] / "checkpoint.pt")


class _Marker:
    """Unpickling it would create a file: a shared policy file must not run code when loaded."""

    def __init__(self, path):
        self.path = str(path)

    def __reduce__(self):
        return (Path.touch, (Path(self.path),))


def test_a_policy_file_holding_another_object_is_refused(tmp_path, trained):
    """load_policy reads with torch.load(weights_only=True): a policy file is tensors and plain data (every one
    written loads so, the committed ones too); one that also pickles an arbitrary object is refused in one line
    naming it, and the object's code never runs."""
    d = torch.load(trained["out"] / "policy.pt", weights_only=True)
    torch.save(dict(d, note=_Marker(tmp_path / "ran")), tmp_path / "policy.pt")
    with pytest.raises(ConfigError, match="refused policy file") as e:
        load_policy(tmp_path)
    assert "\n" not in str(e.value) and "pathlib.Path" in str(e.value) and not (tmp_path / "ran").exists()
    r = cli(tmp_path, "--episodes", "1")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "refused policy file" in r.stderr
    assert not (tmp_path / "ran").exists()


# --------------------------------------------------------------------------- evaluation
def test_evaluation_replays_the_runs_own_evaluation(trained):
    """Same seeds, same policy, same episode rules: evaluate's episodes are the training evaluation's, state for
    state, and its numbers are the run's last evaluation row."""
    pol = load_policy(trained["out"])
    env = make_eval_env(pol)
    try:
        for i, ep in enumerate(trained["rollouts"]):
            mine = _episode(pol, env, EVAL_SEED_BASE + i, pol.terminate_on_success, trace=True)
            assert mine["length"] == ep.length
            np.testing.assert_array_equal(mine["flats"][1:, :40], ep.next_obs[:, 0])
            np.testing.assert_array_equal(mine["flats"][0, :40], ep.obs[0, 0])
    finally:
        env.close()
    r = evaluate_policy(pol, episodes=trained["cfg"].eval_episodes, seed=EVAL_SEED_BASE)
    assert r["seed_set"] == "training evaluation"
    final = trained["final"]
    assert r["success_rate"] == final["eval_success_rate"]
    assert r["mean_return"] == final["eval_return"]
    assert r["mean_episode_length"] == final["eval_episode_length"]
    assert r["env_id"] == "ReachTarget-v1" and not r["zero_shot"]
    lo, hi = r["success_ci"]
    assert 0.0 <= lo <= r["success_rate"] <= hi <= 1.0


def test_success_ci_is_wilson():
    assert success_ci(0, 10)[0] == 0.0 and success_ci(10, 10)[1] == 1.0
    lo, hi = success_ci(5, 10)
    assert lo == pytest.approx(0.2366, abs=1e-4) and hi == pytest.approx(0.7634, abs=1e-4)


def cli(*args):
    return subprocess.run([sys.executable, "-m", "maniskill_dualher.evaluate", *map(str, args)],
                          capture_output=True, text=True, timeout=300)


def test_cli_own_task_and_zero_shot(trained):
    r = cli(trained["out"], "--episodes", "2")
    assert r.returncode == 0, r.stderr
    assert "ReachTarget-v1" in r.stdout and "success" in r.stdout and "95% CI [" in r.stdout and "(Wilson)" in r.stdout
    assert f"held-out seeds (no training evaluation used them): {HELDOUT_SEED_BASE}..{HELDOUT_SEED_BASE + 1}" \
        in r.stdout
    r = cli(trained["out"], "--task", "CloseMicrowave-v1", "--episodes", "2", "--best", "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["env_id"] == "CloseMicrowave-v1" and d["source_env_id"] == "ReachTarget-v1" and d["zero_shot"]
    assert d["episodes"] == 2 and len(d["success_ci"]) == 2 and d["policy"].endswith("policy_best.pt")
    assert [e["seed"] for e in d["per_episode"]] == [HELDOUT_SEED_BASE, HELDOUT_SEED_BASE + 1]
    assert d["seed_set"] == "held-out"


def test_cli_train_eval_seeds_reproduce_the_runs_evaluation(trained):
    """--train-eval-seeds: the training evaluations' seeds, named so; its success is the run's last evaluation."""
    n = trained["cfg"].eval_episodes
    r = cli(trained["out"], "--env", "ReachTarget-v1", "--episodes", n, "--train-eval-seeds", "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert [e["seed"] for e in d["per_episode"]] == [EVAL_SEED_BASE + i for i in range(n)]
    assert d["seed_set"] == "training evaluation" and d["success_rate"] == trained["final"]["eval_success_rate"]
    r = cli(trained["out"], "--episodes", 1, "--train-eval-seeds")
    assert "the training evaluations' seeds (reproduces the run's own evaluation)" in r.stdout


@pytest.mark.parametrize("args, needle", [
    (["{missing}"], "no such run folder"),
    (["{empty}"], "no policy file"),
    (["{run}", "--env", "NoSuchTask-v9"], "NoSuchTask-v9"),
    (["{run}", "--episodes", "0"], "episodes"),
    (["{run}", "--episodes", "two"], "'two'"),
    (["{run}", "--movie", "{tmp}/x.png"], "x.png"),
    (["{run}", "--movie", "{tmp}/x.gif", "--episodes", "2", "--movie-episode", "2"], "movie-episode"),
    (["{run}", "--no-such-flag"], "--no-such-flag"),
    (["{run}", "--train-eval-seeds", "--seed", "5"], "--seed is not a flag here: the first episode's env reset "
                                                     "seed is --reset-seed S (--seed is train's run seed)"),
    (["{run}", "--task", "ClosBox-v1"], "(did you mean CloseBox-v1?)"),
    (["{run}", "--episods", "3"], "unrecognized arguments: --episods 3 (did you mean --episodes?)"),
    ([], "run folder"),
    (["--zero-shot-matrix", "{empty}"], "no finished run"),
])
def test_cli_bad_input_is_one_line(trained, tmp_path, capsys, args, needle):
    (tmp_path / "empty").mkdir()
    subst = {"missing": tmp_path / "missing", "empty": tmp_path / "empty", "run": trained["out"], "tmp": tmp_path}
    argv = [a.format(**subst) for a in args]
    try:
        rc = main(argv)
    except SystemExit as e:  # argparse's own errors
        rc = e.code
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and err[0].startswith("error:") and needle in err[0], err


@pytest.mark.parametrize("args, needle", [
    (["--reset-seed", "-1"], "--reset-seed must be >= 0, got -1"),
    (["--seed", "3"], "--reset-seed S"),  # the old name: one line naming the new one
    (["--reset-seed", "3", "--train-eval-seeds"], "not allowed with"),
])
def test_reset_seed_bad_input_one_line_nothing_written(tmp_path, capsys, args, needle):
    movie = tmp_path / "m.gif"
    try:
        rc = main([str(tmp_path / "run"), *args, "--movie", str(movie)])
    except SystemExit as e:
        rc = e.code
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and err[0].startswith("error:") and needle in err[0], err
    assert list(tmp_path.iterdir()) == []


def test_help_says_the_seed_is_a_reset_seed(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--help"])
    assert e.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--reset-seed S" in text and "env reset seed (not a training seed" in text
    assert "--seed " not in text  # train's run seed; here an old spelling, refused with the new one


def test_cli_bad_input_exit_code(tmp_path):
    r = cli(tmp_path / "missing")
    assert r.returncode == 2 and r.stderr.startswith("error:") and "Traceback" not in r.stderr


def test_movie_and_trajectory_files(trained, tmp_path):
    import h5py
    from PIL import Image
    r = evaluate_policy(trained["out"], "CloseBox-v1", episodes=2, record=tmp_path / "rec", movie=tmp_path / "m.gif")
    gif = tmp_path / "m.gif"
    assert gif.is_file() and gif.stat().st_size < 1_000_000
    im = Image.open(gif)
    assert im.n_frames == r["per_episode"][0]["length"] + 1 and im.size == (800, 600)
    h5 = Path(r["trajectory"])
    assert h5.suffix == ".h5" and h5.is_file()
    meta = json.loads(h5.with_suffix(".json").read_text())
    assert [e["episode_seed"] for e in meta["episodes"]] == [HELDOUT_SEED_BASE, HELDOUT_SEED_BASE + 1]
    assert meta["env_info"]["env_id"] == "maniskill_dualher.tasks:CloseBox-v1"  # replayable in a fresh process
    assert "render_backend" not in meta["env_info"]["env_kwargs"]
    with h5py.File(h5, "r") as f:
        assert sorted(f) == ["traj_0", "traj_1"]
        for k, ep in enumerate(r["per_episode"]):
            assert f[f"traj_{k}"]["actions"].shape == (ep["length"], 8)
            assert bool(np.any(f[f"traj_{k}"]["success"][:])) == ep["success"]
            assert "env_states" in f[f"traj_{k}"]
    r = evaluate_policy(trained["out"], "ReachTarget-v1", episodes=1, movie=tmp_path / "m.mp4")
    data = (tmp_path / "m.mp4").read_bytes()
    assert data[4:8] == b"ftyp" and len(data) < 1_000_000
    assert not list(tmp_path.glob(".*tmp*"))  # no temp files left


def _doc_block(doc: Path, heading: str) -> list:
    """The command lines of the first ```bash block under ``heading`` in ``doc``."""
    text = doc.read_text().split(heading, 1)[1]
    block = text.split("```bash\n", 1)[1].split("```", 1)[0]
    return [ln for ln in block.splitlines() if ln.strip()]


def test_the_documented_replay_recipe_runs_as_typed(tmp_path):
    """docs/tasks.md's replay recipe, its two lines exactly as written, each in a fresh shell (nothing imported
    first: ManiSkill's replay tool finds our tasks through the recorded env id's module): evaluate --record writes
    the trajectory, the replay tool's defaults (render_mode "rgb_array", replay by actions) replay every episode
    to its recorded outcome."""
    import os
    import re
    root = Path(__file__).resolve().parents[1]
    lines = _doc_block(root / "docs" / "tasks.md", "### Replaying a recording")
    assert len(lines) == 2 and lines[1].startswith("python -m mani_skill.trajectory.replay_trajectory --traj-path ")
    (tmp_path / "results").symlink_to(root / "results")   # the recipe runs from the repository's root
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ.get('PATH', '')}")
    p = subprocess.run(lines[0], shell=True, capture_output=True, text=True, timeout=300, cwd=tmp_path, env=env)
    assert p.returncode == 0, p.stderr[-2000:]
    k, n = map(int, re.search(r"success +[0-9.]+ \((\d+)/(\d+)\)", p.stdout).groups())
    meta = json.loads(next((tmp_path / "traj").glob("*.json")).read_text())
    assert meta["env_info"]["env_id"] == "maniskill_dualher.tasks:CloseBox-v1"
    p = subprocess.run(lines[1], shell=True, capture_output=True, text=True, timeout=300, cwd=tmp_path, env=env)
    assert p.returncode == 0, p.stderr[-2000:]
    assert f"Replayed {n} episodes, {k}/{n}=" in p.stdout, p.stdout[-2000:]
    assert f"Replayed {n} episodes, {n}/{n}=100.00%" in (root / "docs" / "tasks.md").read_text()  # as the doc says
    assert k == n


def test_zero_shot_matrix(trained, tmp_path):
    import shutil
    shutil.copytree(trained["out"], tmp_path / "runs" / "a")
    (tmp_path / "runs" / "b").mkdir()  # unfinished: skipped
    rows = zero_shot_matrix(tmp_path / "runs", episodes=1)
    assert [(r["source_run"], r["target_task"]) for r in rows] == [("a", t) for t in TASKS]   # every catalog task
    text = (tmp_path / "runs" / "zero_shot.csv").read_text().splitlines()
    assert text[0].startswith("source_run,source_task,target_task,zero_shot") and len(text) == 1 + len(TASKS)
    assert "ci_low" in text[0] and "ci_high" in text[0]


# --------------------------------------------------------------------------- run folder extras
def test_failed_run_leaves_its_traceback(tmp_path, monkeypatch):
    def boom(self, *args):
        raise RuntimeError("boom in the update")
    monkeypatch.setattr(Trainer, "learn", boom)
    with pytest.raises(RuntimeError, match="boom"):
        run_training(tiny(steps=100), tmp_path / "r", show_progress=False)
    text = (tmp_path / "r" / "error.txt").read_text()
    assert "Traceback" in text and "RuntimeError: boom in the update" in text and "learn" in text
    # a refused config is bad input, not a failed run: the other run's folder gets no error.txt
    (tmp_path / "r" / "error.txt").unlink()
    with pytest.raises(ConfigError, match="different config"):
        run_training(tiny(steps=100, control_mode="pd_ee_delta_pos"), tmp_path / "r", show_progress=False)
    assert not (tmp_path / "r" / "error.txt").exists()


def test_provenance_and_tensorboard_extras(trained):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    doc = json.loads((trained["out"] / "provenance.json").read_text())
    assert len(doc["starts"]) == 1
    p = doc["starts"][0]
    for key in ("commit", "dirty", "python", "versions", "cpu", "torch_threads", "hostname", "time_utc", "gpu"):
        assert key in p, key
    assert p["commit"] is None or len(p["commit"]) == 40
    assert p["versions"]["torch"] == torch.__version__ and p["versions"]["mani_skill"]
    assert p["cpu"]["cores"] >= 1 and "avx512_bf16" in p["cpu"]
    ea = EventAccumulator(str(trained["out"]), size_guidance={"tensors": 0, "scalars": 0}).Reload()
    tags = ea.Tags()
    assert {"charts/train_success_rate", "charts/env_steps_per_s", "charts/eval_success_rate"} <= set(tags["scalars"])
    assert any(t.startswith("config") for t in tags["tensors"])
    rates = [e.value for e in ea.Scalars("charts/train_success_rate")]
    assert len(rates) == 2 and all(0 <= v <= 1 for v in rates)


# --------------------------------------------------------------------------- policies in the box
POLICIES = sorted((Path(__file__).resolve().parents[1] / "results" / "policies").glob("*/*/policy.pt"))


def test_committed_policies_are_small_documented_and_load():
    """Every results/policies/<task>/<method>/policy.pt is actor-only, < 200 KB, and its policy.json names the same
    task and method and a held-out evaluation (seeds that no training evaluation used)."""
    assert POLICIES, "no committed policy"
    for p in POLICIES:
        assert p.stat().st_size < 200_000, p
        doc = json.loads((p.parent / "policy.json").read_text())
        pol = load_policy(p.parent)
        folder = p.parent.name.removesuffix("_after_transfer") if "transfer" in doc else p.parent.name
        assert (doc["task"], doc["method"]) == (pol.env_id, pol.config["method"]) == (p.parent.parent.name, folder)
        h = doc["held_out_evaluation"]
        assert int(h["seeds"].split("..")[0]) == HELDOUT_SEED_BASE and h["successes"] <= h["episodes"]
        assert "checkpoint" not in pol.meta and set(torch.load(p, weights_only=True)) >= {"actor", "input_dim"}


def test_a_committed_policy_evaluates_on_held_out_seeds():
    p = next(p for p in POLICIES if p.parent.parent.name == "ReachTarget-v1")
    r = cli(p.parent, "--episodes", "3", "--json")
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert d["seed_set"] == "held-out" and d["episodes"] == 3 and 0.0 <= d["success_ci"][0] <= d["success_ci"][1] <= 1
