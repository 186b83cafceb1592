"""The pieces the mechanism ablations (issue 30) stand on: the dual buffer at ratio 1/0 against SAC+HER+PER,
E batches that train the critics only, the learner diagnostics per batch source, and a new setting that
leaves every existing run's config (and folder name) as it was."""
import dataclasses

import numpy as np
import pytest
import torch

from maniskill_dualher.config import TASKS, ConfigError, RunConfig, SACConfig
from maniskill_dualher.methods import make_method
from maniskill_dualher.replay.base import Batch
from maniskill_dualher.replay.buffer import Handle
from maniskill_dualher.sac import SAC
from maniskill_dualher.sac_fused import FusedUpdate
from maniskill_dualher.train import Diagnostics

from fakes import point_episode, spec

D, A, B = 9, 2, 32


def _method(name, seed, **replay):
    cfg = RunConfig(method=name)
    cfg.replay.capacity, cfg.sac.batch_size = 10_000, B
    for k, v in replay.items():
        setattr(cfg.replay, k, v)
    return make_method(cfg.validate(), spec(), np.random.default_rng(seed))


def _fill(m):
    m.add_episode(point_episode(T=6, N=3, success_at=[(2, 1), (4, 2)], seed=1))
    m.add_episode(point_episode(T=6, N=3, seed=2))


def test_ratio_one_zero_samples_what_sac_her_per_samples():
    """Same R (real + hindsight rows, same priorities) and the same batches: at ratio 1/0 the dual buffer's
    "choose" draws nothing, so its random stream stays SAC+HER+PER's (before issue 39 it drew one number per
    batch and the streams parted)."""
    dual, her = _method("dual_buffer", 0, ratio=(1.0, 0.0)), _method("sac_her_per", 0)
    _fill(dual), _fill(her)
    n = len(dual.main)
    assert n == len(her.main) and n > 0 and len(dual.E) > 0  # E holds the real successes, never sampled
    a, b = dual.main.storage.get(np.arange(n)), her.main.storage.get(np.arange(n))
    assert all(np.array_equal(a[k], b[k]) for k in a)
    for _ in range(20):
        bd, bh = dual.sample(), her.sample()
        assert bd.handle.source == "R"
        assert torch.equal(bd.obs, bh.obs) and torch.equal(bd.reward, bh.reward)
        td = np.abs(np.random.default_rng(len(bd.obs)).normal(size=B)).astype(np.float32)
        dual.update_priorities(bd, td), her.update_priorities(bh, td)
    assert dual.rng.bit_generator.state == her.rng.bit_generator.state
    # below 1 the draw stays (the paper arm's stream as it always was): one number before each batch
    d2, h2 = _method("dual_buffer", 0, ratio=(0.999999, 0.000001)), _method("sac_her_per", 0)
    _fill(d2), _fill(h2)
    for _ in range(5):
        h2.rng.random()
        assert torch.equal(d2.sample().obs, h2.sample().obs)


def test_e_batches_critic_marks_only_E_batches():
    m = _method("dual_buffer", 0, ratio=(0.5, 0.5), e_batches="critic")
    _fill(m)
    seen = {"R": 0, "E": 0}
    for _ in range(200):
        b = m.sample()
        seen[b.handle.source] += 1
        assert b.critic_only == (b.handle.source == "E")
    assert seen["R"] > 0 and seen["E"] > 0
    m2 = _method("dual_buffer", 0, ratio=(0.5, 0.5))
    _fill(m2)
    assert not any(m2.sample().critic_only for _ in range(50))


def _batch(seed, critic_only):
    g = torch.Generator().manual_seed(seed)
    return Batch(obs=torch.randn(B, D, generator=g), action=torch.rand(B, A, generator=g) * 2 - 1,
                 reward=torch.ones(B), next_obs=torch.randn(B, D, generator=g), done=torch.ones(B),
                 critic_only=critic_only)


def _agent(impl, seed=0):
    torch.manual_seed(seed)
    return SAC(D, A, SACConfig(variant="modern", hidden=(16, 16), lr=1e-2, batch_size=B, update_impl=impl))


def _snap(params):
    return [p.detach().clone() for p in params]


@pytest.mark.parametrize("impl", ["fused", "autograd"])
def test_critic_only_batch_moves_critics_not_actor_or_alpha(impl):
    sac = _agent(impl)
    for critic_only in (False, True, False):  # Adam state exists before and after a skipped step
        pol, crit = _snap(sac.policy_parameters()), _snap(sac.q.parameters())
        sac.update(_batch(int(critic_only), critic_only))
        pol_moved = any(not torch.equal(a, b) for a, b in zip(pol, sac.policy_parameters()))
        crit_moved = any(not torch.equal(a, b) for a, b in zip(crit, sac.q.parameters()))
        assert crit_moved
        assert pol_moved == (not critic_only)


def test_packed_update_skips_only_the_critic_only_members_policy():
    agents = [_agent("fused", s) for s in (0, 1)]
    fused = FusedUpdate(agents)
    before = [_snap(a.policy_parameters()) for a in agents]
    batches = [_batch(3, False), _batch(4, True)]
    fused.step_pack(batches, [None, None])
    moved = [any(not torch.equal(x, y) for x, y in zip(b, a.policy_parameters())) for b, a in zip(before, agents)]
    assert moved == [True, False]


def test_new_setting_at_its_default_leaves_the_config_dict_unchanged():
    cfg = RunConfig()
    assert "e_batches" not in cfg.to_dict()["replay"]  # folder hashes of earlier runs stay valid
    cfg.replay.e_batches = "critic"
    d = cfg.to_dict()
    assert d["replay"]["e_batches"] == "critic"
    assert RunConfig.from_dict(d).replay.e_batches == "critic"
    assert RunConfig.from_dict(RunConfig().to_dict()).replay.e_batches == "full"
    with pytest.raises(ConfigError, match="e_batches"):
        dataclasses.replace(cfg, replay=dataclasses.replace(cfg.replay, dual_mode="split")).validate()
    with pytest.raises(ConfigError, match="'both'"):
        dataclasses.replace(cfg, replay=dataclasses.replace(cfg.replay, e_batches="both")).validate()


def test_diagnostics_average_per_source_between_evaluations():
    d = Diagnostics()
    logs = {"losses/alpha": 0.1, "losses/entropy": 2.0, "losses/qf_values": 1.0, "losses/qf_loss": 0.5}
    r = Batch(*(torch.zeros(1),) * 5, handle=Handle(np.zeros(1, np.int64), source="R"))
    e = Batch(*(torch.zeros(1),) * 5, handle=Handle(np.zeros(0, np.int64), source="E"))
    d.add(r, np.array([1.0, 3.0]), logs)
    d.add(r, np.array([4.0]), None)
    d.add(e, np.array([0.5]), {**logs, "losses/qf_values": 3.0})
    row = d.close_window(100, 3)[-1]
    assert row["R_updates"] == 2 and row["R_td_abs"] == 3.0 and row["R_logged"] == 1
    assert row["E_qf_values"] == 3.0 and row["R_qf_values"] == 1.0
    d.load_state_dict(d.state_dict())
    assert d.close_window(200, 3)[-1] == {"env_steps": 200, "updates": 3}


def test_diagnostics_become_scores_and_a_per_arm_table():
    from maniskill_dualher.analysis.diagnostics import diagnostic_rows
    from maniskill_dualher.analysis.runs import METRICS, Run
    diag = [{"env_steps": 1000.0, "R_updates": 100.0, "R_td_abs": 1.0, "R_logged": 1.0, "R_alpha": 0.2, "E_updates": "",
             "E_td_abs": "", "E_logged": "", "E_alpha": ""},
            {"env_steps": 2000.0, "R_updates": 300.0, "R_td_abs": 3.0, "R_logged": 3.0, "R_alpha": 0.1,
             "E_updates": 100.0, "E_td_abs": 0.5, "E_logged": 0.0, "E_alpha": ""}]
    run = Run("r", RunConfig(), [], [], "", diag)
    assert METRICS["diag_R_td_abs"][0](run) == pytest.approx((100 * 1 + 300 * 3) / 400)
    assert METRICS["diag_R_alpha"][0](run) == pytest.approx((0.2 + 3 * 0.1) / 4)
    assert METRICS["diag_E_td_abs"][0](run) == 0.5
    assert np.isnan(METRICS["diag_E_alpha"][0](run))  # no logged E update
    assert np.isnan(METRICS["diag_R_td_abs"][0](Run("old", RunConfig(), [], [])))  # made before diagnostics
    cell = {"experiment": "x", "arm": "a", "method": "dual_buffer", "task": "T", "role": "adapt"}
    scores = [{**cell, "metric": "diag_E_qf_values", "value": str(v), "run": f"r{i}"} for i, v in enumerate((1, 3))]
    scores.append({**cell, "metric": "successful_train_episodes", "value": "9", "run": "r0"})
    rows = diagnostic_rows(scores)
    assert len(rows) == 1 and rows[0]["n"] == "2" and rows[0]["diag_E_qf_values"] == "2" and rows[0]["diag_R_alpha"] == ""


# --------------------------------------------------------------------------- E off is SAC+HER+PER, bit for bit
_E_OFF_CASE = r"""
import hashlib, json, sys, warnings
warnings.filterwarnings("ignore")
from pathlib import Path
import torch
import maniskill_dualher.tasks  # noqa: F401
from maniskill_dualher.experiment import overrides
from maniskill_dualher.experiment.presets import PRESETS
from maniskill_dualher.train import run_training
method, task, out = sys.argv[1], sys.argv[2], Path(sys.argv[3])
cfg = PRESETS["smoke"].single_config(method, 0, task)
cfg.total_steps = 400
sets = ("replay.ratio=1/0",) if method == "dual_buffer" else ()
cfg = overrides.apply(cfg, overrides.parse_all(sets + ("max_episode_steps=25", "replay.her_k=8"))).validate()
run_training(cfg, out, show_progress=False)
lines = (out / "metrics.csv").read_text().splitlines()
head = lines[0].split(",")
rows = [dict(zip(head, l.split(","))) for l in lines[1:]]
state = torch.load(out / "checkpoint.pt", map_location="cpu", weights_only=True)
def digest(x, h, key=""):
    if isinstance(x, torch.Tensor):
        h.update(key.encode()); h.update(x.detach().contiguous().numpy().tobytes())
    elif isinstance(x, dict):
        for k in sorted(x, key=str):
            digest(x[k], h, f"{key}/{k}")
    elif isinstance(x, (list, tuple)):
        for i, v in enumerate(x):
            digest(v, h, f"{key}/{i}")
    else:
        h.update(f"{key}={x!r}".encode())
    return h
h = digest(state["agent"], hashlib.sha256())
policy = torch.load(out / "policy.pt", map_location="cpu", weights_only=True)
actor = digest(policy["actor"], hashlib.sha256()).hexdigest()
print(json.dumps({"rows": rows, "agent": h.hexdigest(), "actor": actor,
                  "updates": state["counters"]["updates"]}))
"""


def _e_off_case(method, task, tmp_path):
    import json
    import os
    import subprocess
    import sys
    from pathlib import Path
    root = Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, "-c", _E_OFF_CASE, method, task, str(tmp_path / method)],
                       capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(root)))
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("task", TASKS)
def test_ratio_one_zero_trains_bit_for_bit_like_sac_her_per(task, tmp_path):
    """Issue 39: E off (ratio 1/0) is SAC+HER+PER: the same metrics (every column both write, wall time
    aside) and the same weights (networks, optimizers, alpha; the saved actor) on the same seed. Each side
    in a fresh process (PhysX CPU contacts are reproducible only from a fresh process)."""
    dual, her = _e_off_case("dual_buffer", task, tmp_path), _e_off_case("sac_her_per", task, tmp_path)
    assert her["updates"] > 100 and len(her["rows"]) >= 3
    assert len(dual["rows"]) == len(her["rows"])
    for rd, rh in zip(dual["rows"], her["rows"]):
        common = (set(rd) & set(rh)) - {"wall_time_s"}
        assert len(common) > 5 and {k: rd[k] for k in common} == {k: rh[k] for k in common}
    assert dual["agent"] == her["agent"] and dual["actor"] == her["actor"]
