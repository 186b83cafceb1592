"""Episodes that end on success, per-env episode assembly with N envs, E as the paper defines it,
relabeled ``done``, and the update schedule."""
import numpy as np
import torch
import pytest

from maniskill_dualher.config import ReplayConfig, RunConfig, SACConfig
from maniskill_dualher.replay.her import relabel
from maniskill_dualher.train import Trainer, run_one

from batched_goal_env import TOL, register
from fakes import point_episode, reward_fn


def point_cfg(n=3, method="dual_buffer", steps=600, **sac):
    sac_kw = dict(random_steps=10**9, learning_starts=100, batch_size=16, hidden=(16, 16))
    sac_kw.update(sac)
    return RunConfig(env_id=register(n), method=method, seed=1, total_steps=steps, max_episode_steps=20,
                     num_envs=n, eval_every=10**6, eval_episodes=n, checkpoint_every=10**6,
                     sac=SACConfig(**sac_kw), replay=ReplayConfig(capacity=50_000, her_k=2))


def train_capturing(cfg, tmp_path):
    """Run the loop, recording every episode handed to replay."""
    t = Trainer(cfg, tmp_path / "run", show_progress=False)
    eps = []
    add = t.method.add_episode
    t.method.add_episode = lambda ep: (eps.append(ep), add(ep))[1]
    run_one(t)
    t.env.close()
    return t, eps


def test_n_envs_assemble_their_own_episodes(tmp_path):
    t, eps = train_capturing(point_cfg(n=3), tmp_path)
    lengths = [ep.length for ep in eps]
    assert len(set(lengths)) > 3, "episodes of different lengths: each env ends on its own"
    assert max(lengths) <= 20
    for ep in eps:
        assert ep.obs.shape[1] == 1  # one env per stored episode
        # one env's trajectory: each step starts where the previous one ended, the goal never changes
        np.testing.assert_array_equal(ep.obs[1:], ep.next_obs[:-1])
        np.testing.assert_array_equal(ep.desired_goal, np.broadcast_to(ep.desired_goal[0], ep.desired_goal.shape))
        step = np.linalg.norm(ep.next_achieved_goal - ep.achieved_goal, axis=-1)
        assert step.max() <= 0.1 * np.sqrt(2) + 1e-6
    # every env step went into exactly one stored episode (those in flight at the end are stored cut)
    assert sum(lengths) == t.env_steps
    assert t.episodes == len(eps)


def test_success_ends_the_episode_and_is_terminal(tmp_path):
    t, eps = train_capturing(point_cfg(n=3), tmp_path)
    succeeded = [ep for ep in eps if ep.success.any()]
    assert len(succeeded) >= 5
    for ep in succeeded:
        assert ep.success[-1, 0] and not ep.success[:-1].any(), "the first success is the last step"
        assert ep.terminated[-1, 0] and not ep.terminated[:-1].any()
        assert ep.goal_terminal
    failed = [ep for ep in eps if not ep.success.any()]
    assert not any(ep.terminated.any() for ep in failed)  # time limit: truncated, bootstrapped
    assert sum(ep.length < 20 for ep in failed) <= 3  # only the episodes in flight when the budget ran out
    # E: only real reward-1 transitions, one per successful episode, all terminal (no bootstrap)
    E = t.method.E
    rows = E.storage.get(np.arange(len(E)))
    assert len(E) == len(succeeded) == t.successes
    assert np.all(rows["reward"] == 1.0) and np.all(rows["done"] == 1.0)
    # the real rows in R: done exactly at the successful steps
    R = t.method.main
    real = R.storage.get(np.arange(len(R)))
    assert real["done"].sum() >= len(succeeded)


def test_fixed_length_episodes_when_success_does_not_terminate(tmp_path):
    cfg = point_cfg(n=1, steps=200)
    cfg.terminate_on_success = False
    t, eps = train_capturing(cfg, tmp_path)
    assert all(ep.length == 20 for ep in eps)
    assert not any(ep.terminated.any() for ep in eps) and not any(ep.goal_terminal for ep in eps)


def test_success_buffer_episodes_mode_keeps_whole_successful_episodes(tmp_path):
    cfg = point_cfg(n=3)
    cfg.replay.success_buffer = "episodes"
    t, eps = train_capturing(cfg, tmp_path)
    assert len(t.method.E) == sum(ep.length for ep in eps if ep.success.any()) > 0


def test_relabeled_done_follows_relabeled_success():
    ep = point_episode(T=8, N=2, success_at=[(7, 0)])
    ep.goal_terminal = True
    rows = relabel(ep, "future", 4, np.random.default_rng(0), reward_fn)
    assert rows["reward"].sum() > 0
    np.testing.assert_array_equal(rows["done"], rows["reward"])
    ep.goal_terminal = False  # fixed-length episodes: done is the real flag, whatever the goal
    rows = relabel(ep, "future", 4, np.random.default_rng(0), reward_fn)
    assert rows["done"].sum() == 4  # point_episode: env 0's last step is terminal, 4 copies of it
    assert not np.array_equal(rows["done"], rows["reward"])


@pytest.mark.parametrize("n", [1, 3])
def test_update_schedule_per_episode(tmp_path, n):
    """Algorithm 1: one update per finished episode (after learning_starts)."""
    cfg = point_cfg(n=n, steps=300, update_schedule="episode", updates_per_episode=1.0, learning_starts=0)
    t, eps = train_capturing(cfg, tmp_path)
    # each episode that ended on its own (success or time limit) bought one update; those cut when the
    # budget ran out ended no episode loop
    natural = [ep for ep in eps if ep.success.any() or ep.length == 20]
    assert len(natural) >= len(eps) - n
    assert t.updates == len(natural)


@pytest.mark.parametrize("n, utd", [(1, 1.0), (3, 0.5)])
def test_update_schedule_per_step(tmp_path, n, utd):
    """UTD: every vector step from the first with data and >= learning_starts buys n * utd updates."""
    cfg = point_cfg(n=n, steps=300, updates_per_step=utd, learning_starts=90)
    t = Trainer(cfg, tmp_path / "run", show_progress=False)
    at = []
    learn = t.learn
    t.learn = lambda *a: (at.append(t.env_steps), learn(*a))[1]
    run_one(t)
    t.env.close()
    assert at[0] >= 90
    vector_steps = (t.env_steps - at[0]) // n + 1
    assert t.updates == len(at) == int(vector_steps * n * utd)


def test_a_paused_run_driven_again_goes_on_to_its_budget(tmp_path):
    """run_one(stop_at=k) pauses; the same Trainer driven again continues (the benches' slices), to the end."""
    t = Trainer(point_cfg(n=1, steps=300), tmp_path / "run", show_progress=False)
    assert run_one(t, stop_at=100) is None and t.state == "paused"
    paused_at = t.env_steps
    assert 100 <= paused_at < 300
    assert run_one(t, stop_at=200) is None and t.env_steps > paused_at
    final = run_one(t)
    t.env.close()
    assert t.state == "finished" and t.env_steps == 300 and final is not None


def test_n_env_loop_learns_the_point_task(tmp_path):
    """The batched loop trains: after learning, evaluation succeeds far more than random."""
    cfg = point_cfg(n=4, method="sac_her_per", steps=4000, random_steps=400, learning_starts=200,
                    batch_size=64, hidden=(64, 64), lr=1e-3, tau=0.05, gamma=0.9, variant="modern")
    cfg.eval_every, cfg.eval_episodes = 2000, 20
    cfg.replay.her_k = 4
    t = Trainer(cfg, tmp_path / "run", show_progress=False)
    final = run_one(t)
    t.env.close()
    assert t.rows[0]["eval_success_rate"] <= final["eval_success_rate"]
    assert final["eval_success_rate"] >= 0.8


def test_a_nan_loss_stops_the_run_keeping_the_last_good_checkpoint(tmp_path):
    from maniskill_dualher.train import TrainingDiverged
    import torch
    cfg = point_cfg(n=1, steps=400, log_every=1, learning_starts=20)
    cfg.checkpoint_every = 100
    t = Trainer(cfg, tmp_path / "run", show_progress=False)
    update = t.agent.update

    def poisoned(batch, actor_batch=None, want_logs=False):
        td, logs = update(batch, actor_batch, want_logs)
        if t.env_steps > 250:
            logs = {**logs, "losses/qf_loss": float("nan")}
        return td, logs

    t.agent.update = poisoned
    with pytest.raises(TrainingDiverged, match="losses/qf_loss became nan") as e:
        run_one(t)
    t.env.close()
    assert "\n" not in str(e.value) and "last good checkpoint" in str(e.value)
    state = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    assert 100 <= state["counters"]["env_steps"] <= 260
    assert not (tmp_path / "run" / "done.json").exists()


def test_env_episodes_own_clock_and_arrays(tmp_path):
    """EnvEpisodes (episodes.py) on its own: each env's steps land in its own episode arrays; an evaluation's
    EnvEpisodes on the same env leaves the training one's arrays alone; a rollout ends each env on its own;
    a cut hands over the episodes in flight and marks those envs for a reset."""
    from maniskill_dualher.envs import make_env
    from maniskill_dualher.episodes import EnvEpisodes
    env = make_env(point_cfg(n=3))
    try:
        train, ev = EnvEpisodes(env, True), EnvEpisodes(env, True)
        train.reset(np.arange(3), [1, 2, 3])
        flats, actions = [], np.random.default_rng(0).uniform(-0.1, 0.1, (5, 3, 2)).astype(np.float32)
        for a in actions:  # tiny moves: no env reaches its goal (0.15 away, tolerance 0.1) in 5 steps
            flats.append(train.flat.copy())
            assert not train.step(a).any()
        before = {k: v.copy() for k, v in train._arrays.items()}
        out = ev.rollout(100, lambda x: np.zeros((3, 2), np.float32))  # standing still: every env runs to 20
        assert [e.length for e in out] == [20, 20, 20] and ev.pending.all()
        for k, v in train._arrays.items():
            np.testing.assert_array_equal(v, before[k])
        assert list(train.t) == [5, 5, 5]  # its own clock
        cut = train.cut_in_flight()
        assert len(cut) == 3 and train.pending.all() and (train.length == 0).all() and train.cut_in_flight() == []
        o, _, dg = env.split(np.stack(flats))
        for i, ep in enumerate(cut):
            assert ep.length == 5 and not ep.terminated.any() and not ep.success.any()
            np.testing.assert_array_equal(ep.obs[:, 0], o[:, i])
            np.testing.assert_array_equal(ep.desired_goal[:, 0], dg[:, i])
            np.testing.assert_array_equal(ep.action[:, 0], actions[:, i])
    finally:
        env.close()


def _steering(x):
    """A deterministic policy of the point env's input (position | goal) that reaches some goals at different
    steps and misses others."""
    p, g = x[:, :2], x[:, 2:]
    return np.clip((g - p) * 2.5 + np.sin(9.0 * p[:, ::-1]), -1, 1).astype(np.float32)


@pytest.mark.parametrize("n, terminate", [(1, True), (3, True), (3, False)])
def test_scores_are_what_the_rollouts_episodes_give(n, terminate):
    """EnvEpisodes.scores (evaluation's lean rollout) makes the same env calls as rollout and gives each episode's
    return (the same numpy float32 sum), success, success at its end and length, episodes ending on success at
    different steps or running fixed-length."""
    from maniskill_dualher.envs import make_env
    from maniskill_dualher.episodes import EnvEpisodes
    envs = [make_env(point_cfg(n=n)) for _ in range(2)]
    try:
        full, lean = EnvEpisodes(envs[0], terminate), EnvEpisodes(envs[1], terminate)
        seen = {"success": 0, "lengths": set()}
        for seed in range(0, 40, n):
            eps = full.rollout(seed, _steering)
            gen = lean.scores(seed)
            x = next(gen)
            try:
                while True:
                    x = gen.send(_steering(x))
            except StopIteration as stop:
                scores = stop.value
            for ep, sc in zip(eps, scores):
                ret = ep.reward.sum()
                assert type(sc.ret) is type(ret) and sc.ret.tobytes() == ret.tobytes()
                assert (sc.success, sc.success_at_end, sc.length) == \
                    (bool(ep.success.any()), bool(ep.success[-1].any()), ep.length)
                seen["success"] += sc.success
                seen["lengths"].add(sc.length)
            assert lean.pending.all() and full.pending.all()
            np.testing.assert_array_equal(lean.flat, full.flat)
        u0, u1 = envs[0].unwrapped, envs[1].unwrapped
        np.testing.assert_array_equal(u0.pos, u1.pos)  # the same steps, in the same envs
        np.testing.assert_array_equal(u0.resets, u1.resets)
        assert 0 < seen["success"] < 40 and len(seen["lengths"]) > (1 if terminate else 0)
    finally:
        for e in envs:
            e.close()


def test_evaluations_side_by_side_equal_each_alone_and_a_failing_one_fails_alone(tmp_path):
    """train.evaluate_runs steps several runs' evaluations side by side: each gets what it gets alone
    (Trainer.evaluate); one whose forward raises is handed to ``fail`` and the others finish."""
    from maniskill_dualher.train import evaluate_runs
    runs = []
    for s in range(3):
        cfg = point_cfg(n=3)
        cfg.seed = s
        t = Trainer(cfg, tmp_path / str(s), show_progress=False)
        t.agent.actor.net[-1].bias.data[:2] += torch.tensor([2.0, -1.0]) * (s - 1)  # distinct, decisive actors
        runs.append(t)
    try:
        alone = [t.evaluate() for t in runs]
        assert len({a["eval_episode_length"] for a in alone}) > 1
        failed = []
        got = evaluate_runs(runs, lambda run, e: failed.append(run))
        assert [got[t] for t in runs] == alone and failed == []

        def boom(x):
            raise RuntimeError("boom")
        runs[1].agent.deterministic_actor = lambda: boom
        got = evaluate_runs(runs, lambda run, e: failed.append((run, str(e))))
        assert failed == [(runs[1], "boom")] and runs[1] not in got
        assert [got[runs[0]], got[runs[2]]] == [alone[0], alone[2]]
    finally:
        for t in runs:
            t.close()
