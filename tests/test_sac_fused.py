"""The fused update (hand-written gradients, sac_fused.py) against autograd over sac.py's losses.

Exactness: the same gradients of every parameter, |TD|, logs, random draws and parameters after Adam, to
float rounding, for every variant and option. bf16 rounds beyond that, so it gets a closeness bound and
learning checks instead."""
import copy
import dataclasses
import itertools
import shutil

import numpy as np
import pytest
import torch

from maniskill_dualher.config import ConfigError, RunConfig, SACConfig
from maniskill_dualher.replay.base import Batch
from maniskill_dualher.sac import SAC

D, A, B = 13, 4, 64


def make_batch(seed: int, weights: bool = False, n: int = B) -> Batch:
    g = torch.Generator().manual_seed(seed)
    return Batch(obs=torch.randn(n, D, generator=g), action=torch.rand(n, A, generator=g) * 2 - 1,
                 reward=(torch.rand(n, generator=g) < 0.3).float(), next_obs=torch.randn(n, D, generator=g),
                 done=(torch.rand(n, generator=g) < 0.2).float(),
                 weights=torch.rand(n, generator=g) + 0.5 if weights else None)


def twins(**kw):
    """An autograd agent and a fused one with the same weights and optimizer state."""
    torch.manual_seed(0)
    cfg = SACConfig(batch_size=B, hidden=(64, 64), lr=1e-3, update_impl="autograd", **kw)
    ref = SAC(D, A, cfg)
    fused = SAC(D, A, dataclasses.replace(cfg, update_impl="fused"))
    fused.load_state_dict(ref.state_dict())
    fused.optimizer.load_state_dict(ref.optimizer.state_dict())
    return ref, fused


def step_both(ref, fused, batch, actor_batch=None, rtol=1e-4, atol=1e-5):
    """One update each from the same random state: same draws, gradients, |TD| and logs."""
    rng = torch.get_rng_state()
    td_ref, logs_ref = ref.update(batch, actor_batch, want_logs=True)
    grads_ref = {n: p.grad.clone() for n, p in ref.named_parameters() if p.grad is not None}
    rng_after = torch.get_rng_state()
    torch.set_rng_state(rng)
    td_fused, logs_fused = fused.update(batch, actor_batch, want_logs=True)
    assert torch.equal(torch.get_rng_state(), rng_after), "the fused update drew different random numbers"
    grads_fused = {n: p.grad for n, p in fused.named_parameters() if p.grad is not None}
    assert grads_fused.keys() == grads_ref.keys()
    for n, g in grads_ref.items():
        torch.testing.assert_close(grads_fused[n], g, rtol=rtol, atol=atol * g.abs().max().item(),
                                   msg=lambda m: f"grad of {n}: {m}")
    np.testing.assert_allclose(td_fused, td_ref, rtol=rtol, atol=atol)
    assert logs_fused.keys() == logs_ref.keys()
    for k, v in logs_ref.items():
        np.testing.assert_allclose(logs_fused[k], v, rtol=rtol, atol=atol, err_msg=k)


def assert_same_parameters(ref, fused, rtol=1e-4, atol=1e-5):
    for (n, p), q in zip(ref.state_dict().items(), fused.state_dict().values()):
        torch.testing.assert_close(q, p, rtol=rtol, atol=atol, msg=lambda m: f"{n}: {m}")


@pytest.mark.parametrize("variant,is_weights,actor_batch,critic_only,learn_alpha",
                         [(v, w, a, c, la) for v, w, a, c, la in
                          itertools.product(["modern", "paper"], [False, True], [False, True], [False, True],
                                            [None, True])
                          if w or not c])  # critic-only IS weights matter only with IS weights
def test_fused_update_equals_autograd(variant, is_weights, actor_batch, critic_only, learn_alpha):
    ref, fused = twins(variant=variant, is_weights_critic_only=critic_only, learn_alpha=learn_alpha)
    for step in range(3):
        step_both(ref, fused, make_batch(step, is_weights), make_batch(100 + step, n=48) if actor_batch else None)
    assert_same_parameters(ref, fused)
    assert fused._n_updates == ref._n_updates == 3


def test_fused_update_follows_the_log_std_clamp():
    """Where the policy's log-std leaves [LOG_STD_MIN, LOG_STD_MAX] the clamp cuts its gradient, in both."""
    ref, fused = twins(variant="modern")
    for agent in (ref, fused):  # push half of the log-std outputs far above the clamp, some far below
        with torch.no_grad():
            agent.actor.net[-1].bias[A:A + A // 2] = 6.0
            agent.actor.net[-1].bias[-1] = -9.0
    logstd = ref.actor.net(make_batch(0).obs)[:, A:]
    assert (logstd > 2.0).any() and (logstd < -5.0).any()
    step_both(ref, fused, make_batch(0))
    g = fused.actor.net[-1].bias.grad
    assert torch.all(g[A:A + A // 2] == 0) and g[-1] == 0 and torch.any(g[:A] != 0)


def test_fused_update_ties_in_the_critic_minimum_go_to_one_member():
    """With identical critics every min is a tie; the actor's gradient flows through one member, as autograd's."""
    ref, fused = twins(variant="modern")
    for agent in (ref, fused):
        with torch.no_grad():
            for w in list(agent.q.weights) + list(agent.q.biases):
                w[1] = w[0]
    step_both(ref, fused, make_batch(3))


def test_bf16_hidden_products_stay_close_to_fp32():
    """bf16 rounds the hidden layers' inputs (~3 significant digits): one update's |TD| and gradients stay
    within a few percent of strict fp32, not at float rounding (which would mean bf16 was not used)."""
    torch.manual_seed(0)
    cfg = SACConfig(variant="modern", batch_size=256, hidden=(256, 256), matmul_precision="highest")
    fp32 = SAC(D, A, cfg)
    bf16 = SAC(D, A, dataclasses.replace(cfg, matmul_precision="bf16"))
    bf16.load_state_dict(fp32.state_dict())
    batch = make_batch(5, n=256)
    rng = torch.get_rng_state()
    td32, _ = fp32.update(batch)
    g32 = {n: p.grad.clone() for n, p in fp32.named_parameters() if p.grad is not None}
    torch.set_rng_state(rng)
    td16, _ = bf16.update(batch)
    rel = np.abs(td16 - td32).max() / np.abs(td32).max()
    assert 1e-6 < rel < 0.05
    for n, p in bf16.named_parameters():
        if p.grad is None:
            continue
        err = ((p.grad - g32[n]).norm() / g32[n].norm()).item()
        assert err < 0.1, f"{n}: relative gradient error {err:.3f}"


@pytest.mark.parametrize("variant,is_weights,actor_batch,precision",
                         [(v, w, a, pr) for v, w, a in itertools.product(["modern", "paper"], [False, True],
                                                                         [False, True])
                          for pr in ("highest", "bf16")])
def test_row_blocks_give_the_separate_passes_bits(variant, is_weights, actor_batch, precision):
    """One agent's update joins its passes as row blocks (the policy at s and s', the critics at (s, a_pi) and
    (s, a)); on this machine that gives bit for bit what separate passes give, the claim behind "bits unchanged"
    (bench/golden.py). It would fail on a BLAS whose per-row results depend on the number of rows."""
    torch.manual_seed(0)
    cfg = SACConfig(variant=variant, batch_size=B, hidden=(64, 64), lr=1e-3, matmul_precision=precision)
    joined = SAC(D, A, cfg, generator=torch.Generator().manual_seed(3))
    apart = SAC(D, A, cfg, generator=torch.Generator().manual_seed(3))
    apart.load_state_dict(joined.state_dict())
    for agent, rows in ((joined, True), (apart, False)):
        agent.update(make_batch(0, is_weights))  # the first step (optimizer.step(): Adam's state made)
        assert agent._fused.row_blocks  # one agent: rows joined unless told otherwise
        agent._fused.row_blocks = rows
    for step in range(1, 4):
        actor_batch_ = make_batch(100 + step, n=48) if actor_batch else None
        td_j, logs_j = joined.update(make_batch(step, is_weights), actor_batch_, want_logs=True)
        td_a, logs_a = apart.update(make_batch(step, is_weights), actor_batch_, want_logs=True)
        assert np.array_equal(td_j, td_a) and logs_j == logs_a
    for (n, p), q in zip(joined.state_dict().items(), apart.state_dict().values()):
        assert torch.equal(p, q), n
    for p, q in zip(_opt_state(joined), _opt_state(apart)):
        assert torch.equal(p, q)


def test_fused_update_resumes_from_a_checkpoint_like_autograd():
    """Checkpoints are the same state_dicts: an autograd agent's full state drives a fused agent on."""
    ref, _ = twins(variant="modern")
    for step in range(2):
        ref.update(make_batch(step))
    torch.manual_seed(0)
    fused = SAC(D, A, dataclasses.replace(ref.cfg, update_impl="fused"))
    fused.load_full_state(copy.deepcopy(ref.full_state()))  # as from disk: no tensors shared with ref
    step_both(ref, fused, make_batch(7))
    assert_same_parameters(ref, fused)


@pytest.mark.skipif(shutil.which("c++") is None and shutil.which("g++") is None, reason="no C++ compiler")
def test_compiled_update_equals_the_eager_one():
    """torch.compile of the fused update: same random draws (inductor's fallback_random), values to rounding."""
    torch.manual_seed(0)
    cfg = SACConfig(variant="modern", batch_size=B, hidden=(64, 64), lr=1e-3)
    eager = SAC(D, A, cfg)
    compiled = SAC(D, A, dataclasses.replace(cfg, compile=True))
    compiled.load_state_dict(eager.state_dict())
    compiled.optimizer.load_state_dict(eager.optimizer.state_dict())
    for step in range(3):
        step_both(eager, compiled, make_batch(step))
    assert_same_parameters(eager, compiled)


@pytest.mark.slow  # two compilations (~1 min each on 2 busy cores)
@pytest.mark.skipif(shutil.which("c++") is None and shutil.which("g++") is None, reason="no C++ compiler")
def test_compiled_update_called_from_cpp_equals_the_python_wrappers_bit_for_bit(monkeypatch):
    """SACConfig.compile calls inductor's kernels from a C++ wrapper: the same kernels as its Python wrapper, so
    the same bits (the step arm's declared update does not change by the wrapper)."""
    import maniskill_dualher.sac_fused as sf
    cfg = SACConfig(variant="modern", batch_size=B, hidden=(64, 64), lr=1e-3, compile=True)
    agents = {}
    for wrapper in (True, False):
        monkeypatch.setattr(sf, "CPP_WRAPPER", wrapper)
        torch._dynamo.reset()
        torch.manual_seed(0)
        agents[wrapper] = SAC(D, A, cfg, generator=torch.Generator().manual_seed(3))
        for step in range(5):
            agents[wrapper].update(make_batch(step))
    for (k, p), q in zip(agents[True].state_dict().items(), agents[False].state_dict().values()):
        assert torch.equal(p, q), k


@pytest.mark.parametrize("bad,match", [(dict(matmul_precision="bf16", update_impl="autograd"), "bf16"),
                                       (dict(compile=True, update_impl="autograd"), "compile"),
                                       (dict(update_impl="jit"), "update_impl")])
def test_settings_the_fused_update_needs_are_checked(bad, match):
    cfg = RunConfig()
    cfg.sac = dataclasses.replace(cfg.sac, **bad)
    with pytest.raises(ConfigError, match=match):
        cfg.validate()


def test_bf16_update_learns_the_point_task(tmp_path):
    """Learning check for the bf16 products (they change numerics beyond rounding): the batched point-goal
    task is solved as with fp32 (tests/test_episodes.py::test_n_env_loop_learns_the_point_task)."""
    from maniskill_dualher.train import Trainer, run_one
    from test_episodes import point_cfg  # tests/ is on sys.path
    cfg = point_cfg(n=4, method="sac_her_per", steps=4000, random_steps=400, learning_starts=200,
                 batch_size=64, hidden=(64, 64), lr=1e-3, tau=0.05, gamma=0.9, variant="modern")
    cfg.sac.matmul_precision = "bf16"
    cfg.eval_every, cfg.eval_episodes = 2000, 20
    cfg.replay.her_k = 4
    t = Trainer(cfg, tmp_path / "run", show_progress=False)
    final = run_one(t)
    t.env.close()
    assert final["eval_success_rate"] >= 0.8


@pytest.mark.slow
@pytest.mark.parametrize("task", ["ReachTarget-v1", "CloseBox-v1"])
def test_fastest_settings_solve_the_tasks_at_256x256(tmp_path, task):
    """Learning check of the fastest settings at the size where they pay (bf16 hidden products + compile,
    256x256): the quick preset's other settings reach >= 0.9 evaluation success within its budget."""
    from maniskill_dualher.experiment.presets import PRESETS
    from maniskill_dualher.train import run_training
    from test_train import read_rows
    cfg = PRESETS["quick"].single_config("sac_her_per", 0, task)
    cfg.sac.hidden, cfg.sac.matmul_precision, cfg.sac.compile = (256, 256), "bf16", True
    run_training(cfg, tmp_path / task, show_progress=False)
    rows = read_rows(tmp_path / task / "metrics.csv")
    assert max(float(r["eval_success_rate"]) for r in rows) >= 0.9


def _opt_state(agent):
    return [t for st in agent.optimizer.state_dict()["state"].values() for _, t in sorted(st.items())]


@pytest.mark.parametrize("variant", ["modern", "paper"])
def test_one_fused_adam_call_steps_a_pack_as_optimizer_step_does(variant, monkeypatch):
    """FusedUpdate._apply runs every agent's Adam as one _fused_adam_ call: bit for bit what each agent's own
    optimizer.step() gives (the path it replaces), through the first steps (no optimizer state yet), critic-only
    batches (no actor or alpha step), per-agent lr and tau, an lr changed and an optimizer state loaded midway."""
    from maniskill_dualher.sac_fused import FusedUpdate
    cfg = SACConfig(variant=variant, hidden=(16, 16), batch_size=32, learn_alpha=True)

    def pack():
        agents = []
        for s in range(3):
            g = torch.Generator().manual_seed(s)
            c = dataclasses.replace(cfg, lr=1e-3 * (1 + s % 2), tau=0.05 if s else 0.01)
            agents.append(SAC(D, A, c, generator=g, init_generator=g))
        return agents, FusedUpdate(agents)

    fast, fast_update = pack()
    ref, ref_update = pack()
    ref_update._adam_plan = lambda i: None  # every agent through its optimizer.step(), as before
    steps, fast_steps = [], 0
    real_step = torch.optim.Adam.step
    monkeypatch.setattr(torch.optim.Adam, "step", lambda self, *a, **k: steps.append(1) or real_step(self, *a, **k))
    for k in range(6):
        batches = [make_batch(10 * k + s, weights=True) for s in range(3)]
        for s, b in enumerate(batches):
            b.critic_only = (k + s) % 3 == 0  # agent 0 starts critic-only: its actor has no state at first
        if k == 3:
            for agents in (fast, ref):
                agents[1].optimizer.param_groups[0]["lr"] = 5e-4
                agents[2].optimizer.load_state_dict(copy.deepcopy(agents[2].optimizer.state_dict()))
        ref_update.step_pack(batches, [None] * 3, want_logs=False)
        before = len(steps)
        fast_update.step_pack(batches, [None] * 3, want_logs=False)
        fast_steps += len(steps) - before
    for a, b in zip(fast, ref):
        assert all(torch.equal(p, q) for p, q in zip(a.state_dict().values(), b.state_dict().values()))
        assert all(torch.equal(p, q) for p, q in zip(_opt_state(a), _opt_state(b)))
        assert a._n_updates == b._n_updates == 6
    assert fast[0].actor.net[0].weight.grad is not None  # .grad is still set, as optimizer.step() leaves it
    # optimizer.step() only where the one call cannot stand in: before an agent's state exists, after a reload
    assert len(steps) - fast_steps == 18 and 0 < fast_steps <= 5


def test_a_fused_update_reads_weights_and_optimizer_state_loaded_after_it_was_built():
    """One agent's fused update keeps views of its parameters and its optimizer's state from one update to the
    next; a state loaded in between (resume) must be what the next update reads."""
    make = lambda seed: SAC(D, A, SACConfig(variant="modern", batch_size=B, hidden=(32, 32)),  # noqa: E731
                            generator=torch.Generator().manual_seed(seed),
                            init_generator=torch.Generator().manual_seed(seed))
    src, dst = make(0), make(1)
    for step in range(3):
        src.update(make_batch(step))
        dst.update(make_batch(50 + step))
    dst.load_full_state(copy.deepcopy(src.full_state()))
    dst.generator.set_state(src.generator.get_state())
    for step in range(3, 5):
        src.update(make_batch(step))
        dst.update(make_batch(step))
    assert all(torch.equal(p, q) for p, q in zip(src.state_dict().values(), dst.state_dict().values()))
    assert all(torch.equal(p, q) for p, q in zip(_opt_state(src), _opt_state(dst)))
