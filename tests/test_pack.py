"""Many runs per process (train.train_runs with pack.Updater): a run's results do not depend on its pack, bit for bit; a killed pack
resumes to the same metrics; one failing run fails alone; the sweep's scheduler packs compatible runs."""
import csv
import hashlib
import itertools
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from maniskill_dualher.config import RunConfig, SACConfig
from maniskill_dualher.pack import pack_key
from maniskill_dualher.replay.base import Batch
from maniskill_dualher.sac import SAC
from maniskill_dualher.sac_fused import FusedUpdate
from maniskill_dualher.train import Job, run_training, train_runs as run_pack

from subprocs import kill_group, wait_until
from test_train import tiny

REPO = Path(__file__).resolve().parents[1]


# ----------------------------------------------------------------------------- the batched update
def _amx_host() -> bool:
    try:
        return "amx_bf16" in open("/proc/cpuinfo").read()
    except OSError:
        return False


# Measured on CPU A (Intel Xeon, family 6 model 167, AMX), at 86e2a3f as at HEAD: after 6 packed updates of 3
# agents the paper variant's V network differs from the same agent alone by one float ulp (3.7e-9 in v.2.weight,
# v.4.weight of one agent); the modern variant, the default, stays bit-identical there. On CPU B and C both do.
# Not strict: where the bits agree the test passes as it always has.
PACK_BITS_DIFFER = pytest.mark.xfail(_amx_host(), strict=False,
                                     reason="the paper variant's V update is not bit-identical in a pack on AMX hosts")
def _batch(g, B, d, A, weights):
    return Batch(torch.randn(B, d, generator=g), torch.rand(B, A, generator=g) * 2 - 1,
                 (torch.rand(B, generator=g) > .7).float(), torch.randn(B, d, generator=g),
                 (torch.rand(B, generator=g) > .8).float(), torch.rand(B, generator=g) + .5 if weights else None)


def _agent(seed, cfg, d=11, A=3, own=True):
    """An agent seeded as a run seeds it: its own generator, or (own=False) torch's global one."""
    if not own:
        torch.manual_seed(seed)
        return SAC(d, A, cfg)
    g = torch.Generator().manual_seed(seed)
    return SAC(d, A, cfg, generator=g, init_generator=g)


@pytest.mark.parametrize("variant,weights,actor_batch,learn_alpha",
                         list(itertools.product(["modern", "paper"], [True, False], [False, True], [True, False])))
def test_a_packed_update_gives_each_agent_its_own_update(variant, weights, actor_batch, learn_alpha, request):
    if variant == "paper":
        request.applymarker(PACK_BITS_DIFFER)
    cfg = SACConfig(variant=variant, hidden=(16, 16), learn_alpha=learn_alpha, batch_size=32)
    seeds, n = [0, 1, 2], 6
    batches = {s: [(_batch(g, 32, 11, 3, weights), _batch(g, 32, 11, 3, False) if actor_batch else None)
                   for _ in range(n)] for s in seeds for g in [torch.Generator().manual_seed(100 + s)]}
    alone = {}
    for s in seeds:  # each agent alone, on the global generator (as every run did before it owned a generator)
        agent = _agent(s, cfg, own=False)
        tds = [agent.update(b, ab)[0] for b, ab in batches[s]]
        alone[s] = ([p.detach().clone() for p in agent.parameters()], np.stack(tds))
    made = [_agent(s, cfg) for s in seeds]
    fused = FusedUpdate(made)

    tds = {s: [] for s in seeds}
    for k in range(n):
        td, logs = fused.step_pack([batches[s][k][0] for s in seeds], [batches[s][k][1] for s in seeds])
        for i, s in enumerate(seeds):
            tds[s].append(td[i])
        assert len(logs) == 3 and all(np.isfinite(v) for lg in logs for v in lg.values())
    for i, s in enumerate(seeds):
        params = [p.detach() for p in made[i].parameters()]
        assert all(torch.equal(a, b) for a, b in zip(alone[s][0], params)), f"agent {s}: weights differ"
        np.testing.assert_array_equal(alone[s][1], np.stack(tds[s]))
    assert not all(torch.equal(a, b) for a, b in zip(params, alone[seeds[0]][0])), "the agents differ"


def test_pack_key_separates_updates_the_pack_cannot_batch():
    a, b = RunConfig(), RunConfig()
    b.sac.lr, b.sac.random_steps, b.seed = 3e-4, 7, 9  # per agent: still one pack
    assert pack_key(a) == pack_key(b) is not None
    b.sac.hidden = (32, 32)
    assert pack_key(a) != pack_key(b)
    b = RunConfig()
    b.sac.update_impl = "autograd"
    assert pack_key(b) is None


# ----------------------------------------------------------------------------- whole runs
CFGS = [("ReachTarget-v1", "dual_buffer", 3), ("ReachTarget-v1", "dual_buffer", 4), ("CloseBox-v1", "sac", 3)]


def _cfg(env, method, seed, steps=300, ckpt=10_000):
    c = tiny(env_id=env, method=method, steps=steps)
    c.seed, c.checkpoint_every = seed, ckpt
    return c


def _rows(run: Path):
    with open(run / "metrics.csv") as f:
        return [{k: v for k, v in r.items() if k != "wall_time_s"} for r in csv.DictReader(f)]


def _weights(run: Path) -> str:
    nets = torch.load(run / "checkpoint.pt", weights_only=True)["agent"]["networks"]
    return hashlib.sha1(b"".join(v.numpy().tobytes() for v in nets.values())).hexdigest()


@pytest.fixture(scope="module")
def alone(tmp_path_factory):
    root = tmp_path_factory.mktemp("alone")
    for i, c in enumerate(CFGS):
        run_training(_cfg(*c, ckpt=100), root / str(i), show_progress=False)
    return root


@PACK_BITS_DIFFER
def test_a_run_in_a_pack_matches_it_alone(alone, tmp_path, monkeypatch):
    import maniskill_dualher.train as train_mod
    batched, side_by_side = [], []
    step_pack = FusedUpdate.step_pack
    monkeypatch.setattr(FusedUpdate, "step_pack", lambda self, *a, **kw: (batched.append(len(self.sacs)),
                                                                          step_pack(self, *a, **kw))[1])
    evaluate_runs = train_mod.evaluate_runs
    monkeypatch.setattr(train_mod, "evaluate_runs", lambda runs, fail: (side_by_side.append(len(runs)),
                                                                        evaluate_runs(runs, fail))[1])
    res = run_pack([Job(_cfg(*c, ckpt=100), str(tmp_path / str(i))) for i, c in enumerate(CFGS)])
    assert [sorted(r) for r in res] == [["row"]] * 3
    assert batched and max(batched) == 3, "all three runs (two tasks, two methods) were updated together"
    assert max(side_by_side) == 3, "the last evaluations (all at the budget's end) stepped side by side"
    for i in range(len(CFGS)):
        assert _rows(tmp_path / str(i)) == _rows(alone / str(i)), CFGS[i]
        assert _weights(tmp_path / str(i)) == _weights(alone / str(i)), CFGS[i]
    # a finished pack returns its rows again without training
    again = run_pack([Job(_cfg(*c, ckpt=100), str(tmp_path / str(i))) for i, c in enumerate(CFGS)])
    assert [r["row"] for r in again] == [r["row"] for r in res]


def test_a_pack_killed_mid_run_resumes_to_the_same_metrics(alone, tmp_path):
    """SIGKILL while every run of the pack is past its first checkpoint; the rerun resumes each from its own."""
    script = ("import sys; sys.path.insert(0, %r)\n"
              "from test_pack import CFGS, _cfg\n"
              "from maniskill_dualher.train import Job, train_runs as run_pack\n"
              "run_pack([Job(_cfg(*c, ckpt=100), %r + '/' + str(i)) for i, c in enumerate(CFGS)])\n"
              % (str(REPO / "tests"), str(tmp_path)))
    p = subprocess.Popen([sys.executable, "-c", script], cwd=REPO, start_new_session=True,
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        wait_until(p, lambda: all((tmp_path / str(i) / "checkpoint.pt").exists() for i in range(len(CFGS))), 600)
    finally:
        kill_group(p)
    assert not any((tmp_path / str(i) / "done.json").exists() for i in range(len(CFGS)))
    res = run_pack([Job(_cfg(*c, ckpt=100), str(tmp_path / str(i))) for i, c in enumerate(CFGS)])
    assert [sorted(r) for r in res] == [["row"]] * 3
    for i in range(len(CFGS)):
        assert _rows(tmp_path / str(i)) == _rows(alone / str(i)), CFGS[i]


def test_a_run_that_fails_in_a_pack_fails_alone(tmp_path):
    good = _cfg("ReachTarget-v1", "sac", 3, steps=120)
    bad = _cfg("ReachTarget-v1", "sac", 4, steps=120)
    res = run_pack([Job(good, str(tmp_path / "good")), Job(bad, str(tmp_path / "bad"),
                                                          init_from=str(tmp_path / "missing"))])
    assert "row" in res[0] and (tmp_path / "good" / "done.json").exists()
    assert "error" in res[1] and not (tmp_path / "bad" / "done.json").exists()


# ----------------------------------------------------------------------------- the sweep's scheduler
def test_the_scheduler_packs_compatible_ready_runs_evenly():
    from maniskill_dualher.experiment.backends import packs
    from maniskill_dualher.experiment.grid import Node

    def node(i, hidden=(64, 64)):
        c = RunConfig(seed=i)
        c.sac.hidden = hidden
        return Node(rel=f"r{i}", cfg=c, label=str(i))

    ready = [node(i) for i in range(16)]
    assert [len(g) for g in packs(ready, 2, 8)] == [8, 8]
    assert [len(g) for g in packs(ready, 2, 16)] == [8, 8]       # shared evenly over the free workers
    more = [node(i) for i in range(24)]
    assert [len(g) for g in packs(more, 2, 8)] == [6, 6]         # 4 packs of 6 in two rounds, not 8, 8, then 8
    assert [len(g) for g in packs(ready[:5], 2, 8)] == [3, 2]
    from maniskill_dualher.experiment.sweep import DEFAULT_PACK
    # the README's first command (9 runs, 2 workers) at the default: packs of 5 and 4, as measured in docs/speed.md
    assert [len(g) for g in packs(ready[:9], 2, DEFAULT_PACK)] == [5, 4]
    assert [len(g) for g in packs(ready, 3, 1)] == [1, 1, 1]     # no packing: one run per worker
    mixed = [node(0), node(1, (32, 32)), node(2), node(3, (32, 32))]
    groups = packs(mixed, 2, 4)
    assert [[n.rel for n in g] for g in groups] == [["r0", "r2"], ["r1", "r3"]]
    assert packs(ready, 0, 8) == []


def test_sweep_refuses_a_pack_below_one(tmp_path):
    p = subprocess.run([sys.executable, "-m", "maniskill_dualher.sweep", "--preset", "smoke", "--pack", "0",
                        "--out", str(tmp_path / "s")], cwd=REPO, capture_output=True, text=True)
    assert p.returncode == 2
    assert p.stderr.strip().splitlines()[-1] == "error: --pack must be >= 1, got 0"
    assert not (tmp_path / "s").exists()
