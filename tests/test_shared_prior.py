"""The shared-prior ablation: both methods adapt from SAC+HER+PER's prior; the dual buffer's E starts from
that R's real reward-1 rows (never from its hindsight copies)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from maniskill_dualher.baselines.sac_her_per import SACHerPerReplay
from maniskill_dualher.config import ConfigError, RunConfig
from maniskill_dualher.dual_buffer import DualBufferReplay
from maniskill_dualher.experiment import grid, protocol, sweep
from maniskill_dualher.sweep import main as run_sweep, train_runs as entry_train_runs  # noqa: F401

from fakes import point_episode, spec


def _cfg(method, capacity=10_000, k=2):
    cfg = RunConfig(method=method)
    cfg.replay.capacity, cfg.replay.her_k, cfg.replay.her_strategy = capacity, k, "future"
    return cfg


def _real_success_rows(m: SACHerPerReplay) -> set:
    return {tuple(np.round(m.main.storage.get(np.array([i]))["obs"][0], 6)) for i in m.real_success_rows()}


def test_sac_her_per_marks_exactly_its_real_reward_1_rows():
    m = SACHerPerReplay(_cfg("sac_her_per"), spec(), np.random.default_rng(0))
    ep = point_episode(success_at=[(2, 0), (4, 1)])
    m.add_episode(ep)
    rows = m.main.storage.get(np.arange(len(m.main)))
    n_real = ep.reward.size
    assert rows["reward"][n_real:].sum() > 0  # hindsight copies with reward 1 exist, and are not marked
    assert list(m.real_success_rows()) == list(np.flatnonzero(rows["reward"][:n_real] == 1.0))
    assert len(m.real_success_rows()) == 2


def test_marks_follow_the_ring_when_rows_are_overwritten():
    m = SACHerPerReplay(_cfg("sac_her_per", capacity=40, k=2), spec(), np.random.default_rng(0))
    m.add_episode(point_episode(seed=0, success_at=[(1, 0)]))   # 18 real + 36 hindsight rows > 40: wraps
    m.add_episode(point_episode(seed=1))                        # no real success: overwrites older marks
    rows = m.main.storage.get(np.arange(len(m.main)))
    marked = m.real_success_rows()
    assert all(rows["reward"][i] == 1.0 for i in marked)
    assert len(marked) == 0  # the only real success row was overwritten by the second episode


def test_dual_buffer_adopts_the_prior_R_and_starts_E_from_its_real_successes():
    prior = SACHerPerReplay(_cfg("sac_her_per"), spec(), np.random.default_rng(0))
    for s in range(3):
        prior.add_episode(point_episode(seed=s, success_at=[(s, s % 3)]))
    state = prior.state_dict()
    d = DualBufferReplay(_cfg("dual_buffer"), spec(), np.random.default_rng(1))
    d.load_transfer_state(state)
    assert len(d.main) == len(prior.main)
    np.testing.assert_array_equal(d.main.storage.get(np.arange(len(d.main)))["obs"],
                                  prior.main.storage.get(np.arange(len(prior.main)))["obs"])
    assert len(d.E) == 3 == len(prior.real_success_rows())
    np.testing.assert_array_equal(d.E.storage.get(np.arange(3))["obs"],
                                  prior.main.storage.get(prior.real_success_rows())["obs"])
    # a resumed prior keeps its marks (they are part of its checkpoint)
    again = SACHerPerReplay(_cfg("sac_her_per"), spec(), np.random.default_rng(5))
    again.load_state_dict(state)
    assert list(again.real_success_rows()) == list(prior.real_success_rows())


def test_dual_buffer_refuses_a_prior_it_cannot_rebuild_E_from():
    prior = SACHerPerReplay(_cfg("sac_her_per"), spec(), np.random.default_rng(0))
    prior.add_episode(point_episode(success_at=[(2, 0)]))
    old = prior.state_dict()
    old["extra"] = {}
    d = DualBufferReplay(_cfg("dual_buffer"), spec(), np.random.default_rng(1))
    with pytest.raises(ConfigError, match="does not mark"):
        d.load_transfer_state(old)
    cfg = _cfg("dual_buffer")
    cfg.replay.success_buffer = "episodes"
    with pytest.raises(ConfigError, match="success_buffer=episodes"):
        DualBufferReplay(cfg, spec(), np.random.default_rng(1)).load_transfer_state(prior.state_dict())


def test_a_chain_may_adapt_only_from_a_prior_its_method_adopts():
    her, dual = RunConfig(method="sac_her_per"), RunConfig(method="dual_buffer")
    protocol.validate_chain([her, her, dual])  # the dual buffer adopts SAC+HER+PER's prior
    with pytest.raises(ConfigError, match="cannot adapt from a 'dual_buffer' prior"):
        protocol.validate_chain([dual, dual, her])
    with pytest.raises(ConfigError, match="source stages"):
        protocol.validate_chain([her, dual, dual])


def _definition(tmp_path, experiments):
    return sweep.definition_from_args(sweep.make_parser().parse_args(
        ["--preset", "smoke", "--experiments", experiments, "--seeds", "1", "--out", str(tmp_path / "s")]))


def test_grid_shares_the_prior_stages_with_sac_her_per_transfer(tmp_path):
    d = _definition(tmp_path, "transfer,shared_prior")
    nodes = {n.rel: n for n in grid.build_grid(d)}
    adapt = {(c["experiment"], c["method"]): n for n in nodes.values() for c in n.cells if c["role"] == "adapt"}
    dual_shared, her_shared = adapt["shared_prior", "dual_buffer"], adapt["shared_prior", "sac_her_per"]
    assert her_shared is adapt["transfer", "sac_her_per"]           # the same run serves both experiments
    assert dual_shared.parent == her_shared.parent                  # one prior: SAC+HER+PER's stage 1
    assert dual_shared.parent != adapt["transfer", "dual_buffer"].parent
    assert dual_shared.cfg.method == "dual_buffer" and nodes[dual_shared.parent].cfg.method == "sac_her_per"
    # a source stage's cells name the method that trains it
    assert all(c["method"] == "sac_her_per" for c in nodes[dual_shared.parent].cells)
    assert len(nodes) == 2 * 3 + 1  # two chains of three, plus the dual buffer's shared-prior adaptation


def test_an_arm_without_the_carried_rows_adapts_the_very_prior_a_carrying_arm_adapts(tmp_path):
    """paper_regime:step_empty (Amendment 3) is `step` with adapt.replay.carry_rows=false: one prior folder for
    both, its own adaptation folders, whose jobs load the prior's networks and none of its rows (the prior still
    keeps them for `step`), and whose memory plan reads no carried replay."""
    from maniskill_dualher.analysis import hyperparameters
    from maniskill_dualher.experiment import cost
    d = _definition(tmp_path, "paper_regime:step+step_empty")
    nodes = {n.rel: n for n in grid.build_grid(d)}
    adapt = {(c["arm"], c["method"]): n for n in nodes.values() for c in n.cells if c["role"] == "adapt"}
    assert set(adapt) == {(a, m) for a in ("step", "step_empty") for m in ("dual_buffer", "sac_her_per")}
    for m in ("dual_buffer", "sac_her_per"):
        empty, carried = adapt["step_empty", m], adapt["step", m]
        assert empty.parent == carried.parent and empty.rel != carried.rel
        assert not empty.cfg.replay.carry_rows and carried.cfg.replay.carry_rows
        assert {c["arm"] for c in nodes[empty.parent].cells} == {"step", "step_empty"}
        job, prior_job = grid.job_for(empty.payload(tmp_path), check_parent=False), \
            grid.job_for(nodes[empty.parent].payload(tmp_path), check_parent=False)
        assert job["init_from"] == str(tmp_path / empty.parent) and not job["carry_replay"]
        assert grid.job_for(carried.payload(tmp_path), check_parent=False)["carry_replay"]
        assert prior_job["keep_replay"] and prior_job["carry_replay"]   # CloseBox still takes ReachTarget's rows
        assert json.loads((tmp_path / empty.rel / "stage.json").read_text())["carry_replay"] is False
        assert cost.node_memory(empty).loaded_bytes < cost.node_memory(carried).loaded_bytes
    row = dict((name, get) for name, _, get in hyperparameters._table())["replay at the start"]
    assert row(adapt["step_empty", "sac_her_per"].cfg, 2) == "empty"
    assert row(adapt["step", "sac_her_per"].cfg, 2) == "the previous stage's, carried"


def test_a_run_refuses_carry_replay_when_its_config_takes_no_rows(tmp_path):
    from maniskill_dualher.train import Trainer
    cfg = RunConfig(env_id="CloseMicrowave-v1", method="sac_her_per", total_steps=100)
    cfg.replay.carry_rows = False
    with pytest.raises(ConfigError, match="replay.carry_rows is false"):
        Trainer(cfg, tmp_path / "dst", init_from=tmp_path / "src", carry_replay=True, show_progress=False)
    assert not (tmp_path / "dst").exists()


def test_shared_prior_sweep_end_to_end(tmp_path):
    """Smoke budgets: SAC+HER+PER's two source stages, then both adaptations from them; the claims see both."""
    import csv
    out = tmp_path / "sweep"
    assert run_sweep(["--preset", "smoke", "--out", str(out), "--backend", "inline", "--seeds", "1",
                       "--experiments", "shared_prior"]) == 0
    done = sorted(str(p.parent.relative_to(out)) for p in out.rglob("done.json"))
    assert len(done) == 4 and all(r.startswith("runs/chain/sac_her_per-s0/") for r in done)
    lineage = [json.loads((p.parent / "lineage.json").read_text()) for p in out.rglob("done.json")
               if json.loads((p.parent / "config.json").read_text())["method"] == "dual_buffer"]
    assert len(lineage) == 1 and lineage[0]["carry_replay"] and "stage1-CloseBox" in lineage[0]["init_from"]
    with open(out / "claims.csv", newline="") as f:
        rows = {r["claim"]: r for r in csv.DictReader(f)}
    assert rows["shared_a"]["n_a"] == "1" and rows["shared_a"]["n_b"] == "1"
    assert rows["shared_prior"]["verdict"] == "not measured (runs missing)"  # no transfer/paper dual buffer here


def test_a_stage_with_a_fixed_temperature_starts_at_its_own_alpha(tmp_path):
    """paper_regime adapts a prior that learned its temperature with Table 3's fixed alpha 0.005: the stage's
    alpha is the setting, not the prior's learned value (and it stays there)."""
    import math

    import torch

    import maniskill_dualher.tasks  # noqa: F401
    from maniskill_dualher.experiment import overrides
    from maniskill_dualher.experiment.presets import PRESETS
    from maniskill_dualher.rundir import load_checkpoint
    from maniskill_dualher.train import train_chain

    src = PRESETS["smoke"].single_config("sac_her_per", 0, "ReachTarget-v1")
    src = overrides.apply(src, overrides.parse_all(("sac.variant=modern", "total_steps=200"))).validate()
    stages = protocol.make_stages(src, ["ReachTarget-v1", "CloseMicrowave-v1"], [200, 150])
    stages[-1] = overrides.apply(stages[-1], overrides.parse_all(
        ("sac.learn_alpha=false", "sac.alpha=0.005", "sac.learning_starts=50", "sac.random_steps=50"))).validate()
    train_chain(stages, tmp_path / "chain", carry_replay=True, show_progress=False)
    d0, d1 = protocol.transfer_chain_dirs(tmp_path / "chain", stages, carry_replay=True)
    learned = load_checkpoint(d0)["agent"]["networks"]["log_alpha"]
    fixed = load_checkpoint(d1)["agent"]["networks"]["log_alpha"]
    assert float(learned) != pytest.approx(math.log(0.005), abs=1e-4)  # the prior learned another value
    assert torch.equal(fixed, torch.tensor(math.log(0.005)))
