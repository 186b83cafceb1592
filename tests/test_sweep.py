"""The experiment pipeline end to end with real tiny runs: sweep (local pool and Ray), transfer
protocol, kill-and-resume, and bad input. The smoke grid (34 runs) is run once per backend and
once killed-and-resumed; the three must give byte-identical tables."""
from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from maniskill_dualher import rundir
from maniskill_dualher.methods import METHOD_SPECS
from maniskill_dualher.config import ReplayConfig, RunConfig, SACConfig
from maniskill_dualher.experiment.registry import PAPER_CHAIN, PAPER_TARGET, chain_name
from maniskill_dualher.experiment import overrides, protocol, sweep
from maniskill_dualher.sweep import main as run_sweep, train_runs as entry_train_runs  # noqa: F401
from maniskill_dualher.experiment.backends import run_grid
from maniskill_dualher.experiment.grid import build_grid, seed_span
from maniskill_dualher.train import train_chain
from subprocs import alive, sweep_env

REPO = Path(__file__).resolve().parents[1]
TABLES = ["table4_sampling_ratio.csv", "table5_multitask.csv", "single_task.csv", "ablations.csv"]
OUTPUTS = TABLES + ["hyperparameters.csv", "fig4_single_task.png", "fig5_multitask.png", "summary.md", "scores.csv",
                    "curves.csv", "claims.csv"]
METRIC_KEYS = {"successful_train_episodes": "train_successes", "final_eval_success_rate": "eval_success_rate",
               "final_eval_return": "eval_return"}
CURVE_KEYS = {"mean_eval_success_rate": "eval_success_rate", "mean_eval_return": "eval_return"}


def _cli(*args, timeout=600, **kw):
    return subprocess.run([sys.executable, "-m", "maniskill_dualher.sweep", *args], cwd=REPO, env=sweep_env(),
                          capture_output=True, text=True, timeout=timeout, **kw)


@pytest.fixture(scope="module")
def smoke_local(tmp_path_factory):
    """The smoke preset, uninterrupted, local pool: the reference every other sweep is compared to."""
    out = tmp_path_factory.mktemp("smoke") / "local"
    t0 = time.perf_counter()
    assert run_sweep(["--preset", "smoke", "--out", str(out), "--workers", "2"]) == 0
    print(f"smoke preset, local backend: {time.perf_counter() - t0:.1f} s wall")
    return out


# ----------------------------------------------------------------------------- recomputation
def _recompute(out: Path) -> dict:
    """Independently of the analysis code: group finished runs by their cells, keep their metrics rows."""
    runs = json.loads((out / "sweep.json").read_text())["runs"]
    groups = defaultdict(list)
    for rel in runs:
        d = out / rel
        cfg = json.loads((d / "config.json").read_text())
        with open(d / "metrics.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        for c in json.loads((d / "cell.json").read_text())["cells"]:
            key = tuple(str(c[k]) for k in ("experiment", "arm", "task", "chain", "method", "variant", "role"))
            groups[key].append((c["seed"], rows, cfg["total_steps"]))
    return groups


def _score(metric: str, rows: list, total: int) -> float:
    last = rows[-1]
    trained = [r for r in rows if float(r["env_steps"]) > 0] or rows
    if metric in CURVE_KEYS:  # mean over the run's evaluations after training began
        return float(np.mean([float(r[CURVE_KEYS[metric]]) for r in trained]))
    if metric in METRIC_KEYS:  # the run's last evaluation row
        return float(last[METRIC_KEYS[metric]])
    if metric == "train_success_rate":
        return float(last["train_successes"]) / max(1.0, float(last["train_episodes"]))
    if metric == "steps_to_10_successes":
        hit = [float(r["env_steps"]) for r in rows if float(r["train_successes"]) >= 10]
        return hit[0] if hit else float(total)
    raise KeyError(metric)


def _check_row(row: dict, members: list) -> None:
    from scipy import stats as st
    members = sorted(members, key=lambda m: m[0])
    vals = np.array([_score(row["metric"], m[1], m[2]) for m in members])
    assert int(row["n_seeds"]) == len(vals)
    assert row["seeds"] == " ".join(str(m[0]) for m in members)
    assert float(row["mean"]) == pytest.approx(vals.mean(), rel=1e-5, abs=1e-9)
    if len(vals) > 1 and row["metric"].endswith("_rate"):  # rates: a bootstrap interval inside the values' range
        assert vals.min() - 1e-9 <= float(row["ci95_low"]) <= float(row["mean"]) <= float(row["ci95_high"]) \
            <= vals.max() + 1e-9
    elif len(vals) > 1:
        assert float(row["std"]) == pytest.approx(vals.std(ddof=1), rel=1e-5, abs=1e-9)
        h = st.t.ppf(0.975, len(vals) - 1) * vals.std(ddof=1) / np.sqrt(len(vals))
        assert float(row["ci95_low"]) == pytest.approx(vals.mean() - h, rel=1e-5, abs=1e-9)
        assert float(row["ci95_high"]) == pytest.approx(vals.mean() + h, rel=1e-5, abs=1e-9)


def assert_tables_match_runs(out: Path) -> None:
    groups = _recompute(out)
    for name in TABLES:
        with open(out / name, newline="") as f:
            rows = list(csv.DictReader(f))
        assert rows or name == "ablations.csv", name
        for row in rows:
            _check_row(row, groups[tuple(row[k] for k in ("experiment", "arm", "task", "chain", "method", "variant",
                                                          "role"))])


def _tables_bytes(out: Path) -> dict:
    """Tables and summary.md, but for summary.md's title line (it names the folder)."""
    got = {n: (out / n).read_bytes() for n in TABLES + ["hyperparameters.csv", "claims.csv", "scores.csv"]}
    got["summary.md"] = (out / "summary.md").read_bytes().split(b"\n", 1)[1]
    return got


# ----------------------------------------------------------------------------- end to end
def test_smoke_local_end_to_end(smoke_local):
    out = smoke_local
    for name in OUTPUTS:
        assert (out / name).is_file() and (out / name).stat().st_size > 0, name
    assert (out / "fig4_single_task.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    d = json.loads((out / "sweep.json").read_text())
    # 3 tasks x 3 methods x 2 seeds single; 2 methods x 3 stages x 2 seeds transfer; + 2 ratios x 2 seeds;
    # + the from-scratch control: 2 methods x 2 seeds
    assert len(d["runs"]) == 18 + 12 + 4 + 4
    cells = {rel: json.loads((out / rel / "cell.json").read_text())["cells"] for rel in d["runs"]}
    assert sum(any(c["experiment"] == "scratch" for c in cs) for cs in cells.values()) == 4
    assert all(rundir.is_done(out / r) for r in d["runs"])
    # the ratio study shares the source stages with transfer's dual_buffer chain: one stage0 per seed, and
    # its 0.6/0.4 adaptation is transfer's run (one folder, two cells)
    chain = out / "runs/chain/dual_buffer-s0"
    assert len(list(chain.glob("stage0-ReachTarget*"))) == 1
    assert len(list(chain.glob("stage2-*"))) == 3
    shared = json.loads(next(chain.glob("stage2-*-r0.6-0.4-*")).joinpath("cell.json").read_text())["cells"]
    assert {(c["experiment"], c["arm"]) for c in shared} == {("transfer", "paper"), ("ratios", "0.6/0.4")}
    assert_tables_match_runs(out)
    with open(out / "table4_sampling_ratio.csv", newline="") as f:
        t4 = {r["arm"]: r for r in csv.DictReader(f)}
    assert {k: v["paper"] for k, v in t4.items()} == {"0.5/0.5": "154", "0.6/0.4": "250", "0.7/0.3": "<75"}
    with open(out / "table5_multitask.csv", newline="") as f:
        t5 = [r for r in csv.DictReader(f) if r["metric"] == "successful_train_episodes"]
    full = chain_name(PAPER_CHAIN)
    assert {(r["experiment"], r["chain"], r["method"], r["paper"]) for r in t5} == {
        ("transfer", full, "sac_her_per", "<45"), ("transfer", full, "dual_buffer", "250"),
        ("scratch", PAPER_TARGET, "sac_her_per", ""), ("scratch", PAPER_TARGET, "dual_buffer", "")}
    for name in TABLES:  # wall time must stay out of tables (else resumed sweeps differ)
        assert "wall" not in (out / name).read_text()
    summary = (out / "summary.md").read_text()
    assert "Verdicts" in summary and "154" in summary and "38 finished runs" in summary
    hp = (out / "hyperparameters.csv").read_text()
    assert "HER goals per transition k,\"4 single-task, 8 multi-task\",4,8,8" in hp
    assert "carried from the previous stage" in hp   # alpha of stages that start from a prior


def test_report_numbers_come_from_metrics(smoke_local, tmp_path):
    """Edit one adaptation run's metrics.csv in a copy: the rebuilt tables must follow it."""
    import shutil

    from maniskill_dualher import report
    out = tmp_path / "copy"
    shutil.copytree(smoke_local, out)
    stage2 = sorted((out / "runs/chain/dual_buffer-s1").glob("stage2-CloseMicrowave-v1-r0.5-0.5-*"))[0]
    with open(stage2 / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    before = {r["arm"]: r for r in csv.DictReader(open(out / "table4_sampling_ratio.csv"))}
    rows[-1]["train_successes"] = str(float(rows[-1]["train_successes"]) + 6)
    with open(stage2 / "metrics.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    report.build_report(out)
    after = {r["arm"]: r for r in csv.DictReader(open(out / "table4_sampling_ratio.csv"))}
    assert float(after["0.5/0.5"]["mean"]) == pytest.approx(float(before["0.5/0.5"]["mean"]) + 3)
    assert after["0.6/0.4"] == before["0.6/0.4"]
    assert_tables_match_runs(out)


def test_smoke_ray_backend_same_tables(smoke_local, tmp_path):
    pytest.importorskip("ray")
    out = tmp_path / "ray"
    t0 = time.perf_counter()
    assert run_sweep(["--preset", "smoke", "--out", str(out), "--backend", "ray", "--workers", "2"]) == 0
    print(f"smoke preset, ray backend: {time.perf_counter() - t0:.1f} s wall")
    for name in OUTPUTS:
        assert (out / name).is_file(), name
    assert _tables_bytes(out) == _tables_bytes(smoke_local)
    assert_tables_match_runs(out)


def _children(pid: int) -> list:
    kids = []
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                if int((p / "stat").read_text().rsplit(")", 1)[1].split()[1]) == pid:
                    kids.append(int(p.name))
            except (OSError, IndexError, ValueError):
                pass
    return kids


# a sub-grid of smoke (same budgets, so the same run folders): 2 single-task runs + a 3-stage chain
SUBGRID = ["--preset", "smoke", "--experiments", "single,transfer", "--tasks", "CloseBox-v1",
           "--methods", "sac,dual_buffer", "--seeds", "1"]


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc to find the sweep's workers")
def test_sigkill_midway_then_resume_gives_identical_tables(smoke_local, tmp_path):
    import shutil
    # reference: the sub-grid's tables from the uninterrupted smoke runs (all done: the sweep only reports)
    ref = tmp_path / "ref"
    shutil.copytree(smoke_local, ref)
    assert run_sweep([*SUBGRID, "--out", str(ref), "--force"]) == 0
    assert len(json.loads((ref / "sweep.json").read_text())["runs"]) == 5

    out = tmp_path / "killed"
    args = [*SUBGRID, "--out", str(out)]
    log = open(tmp_path / "first.log", "w")
    hold = tmp_path / "hold"
    hold.touch()                     # runs wait after their first checkpoint: the kill lands mid-way every time
    p = subprocess.Popen([sys.executable, "-m", "maniskill_dualher.sweep", *args], cwd=REPO, env=sweep_env(hold),
                         stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        deadline = time.time() + 300
        while time.time() < deadline and p.poll() is None:
            if [c for c in out.glob("runs/**/checkpoint.pt") if not rundir.is_done(c.parent)]:
                break
            time.sleep(0.02)
        assert p.poll() is None, "the sweep finished before it could be killed"
        workers = _children(p.pid)
        p.send_signal(signal.SIGKILL)
        p.wait()
        interrupted = [c.parent for c in out.glob("runs/**/checkpoint.pt") if not rundir.is_done(c.parent)]
        assert interrupted, "no run was mid-way when the sweep was killed"
        t_end = time.time() + 15
        while any(alive(w) for w in workers) and time.time() < t_end:
            time.sleep(0.1)
        assert not [w for w in workers if alive(w)], "pool workers outlived the killed sweep"
        hold.unlink()
    finally:
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        log.close()
    assert not (out / "summary.md").exists()
    r = _cli(*args)
    assert r.returncode == 0, r.stderr[-2000:]
    assert all(rundir.is_done(d) for d in interrupted)
    assert _tables_bytes(out) == _tables_bytes(ref)


def _procs() -> dict:
    """pid -> (ppid, process group) of every live process (/proc)."""
    out = {}
    for p in Path("/proc").iterdir():
        if p.name.isdigit():
            try:
                f = (p / "stat").read_text().rsplit(")", 1)[1].split()
                if f[0] != "Z":
                    out[int(p.name)] = (int(f[1]), int(f[2]))
            except (OSError, IndexError, ValueError):
                pass
    return out


def _free_port() -> int:
    import socket
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _RayHead:
    """A local Ray cluster made by ``ray start --head`` (2 CPUs, its own ports and temp folder); ``lose()``
    SIGKILLs every process it started (GCS, raylet, agents, and the workers the raylet spawned, which sit in
    process groups of their own), by pid: a head node lost, not a clean ``ray stop``."""

    def __init__(self):
        import tempfile
        self.tmp = tempfile.mkdtemp(prefix="rh", dir="/tmp")  # short: Ray's socket paths have a length limit
        self.port = _free_port()
        self.ports = [str(_free_port()) for _ in range(4)]
        self.group = None

    @property
    def address(self) -> str:
        return f"127.0.0.1:{self.port}"

    def start(self) -> None:
        env = {k: v for k, v in sweep_env().items() if k != "RAY_ADDRESS"}
        p = subprocess.Popen([sys.executable, "-c", "import sys; from ray.scripts.scripts import main; sys.exit(main())",
                              "start", "--head", "--num-cpus", "2", "--port", str(self.port), "--temp-dir", self.tmp,
                              "--include-dashboard=false", "--disable-usage-stats", "--object-store-memory", "80000000",
                              "--ray-client-server-port", self.ports[0], "--dashboard-port", self.ports[1],
                              "--dashboard-agent-listen-port", self.ports[2], "--metrics-export-port", self.ports[3]],
                             env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                             start_new_session=True)
        self.group = p.pid
        log = p.communicate(timeout=180)[0]
        assert p.returncode == 0, log[-3000:]

    def lose(self) -> None:
        procs = _procs()
        mine = {pid for pid, (_, group) in procs.items() if group == self.group}
        while True:
            more = {pid for pid, (ppid, _) in procs.items() if ppid in mine} - mine
            if not more:
                break
            mine |= more
        for pid in mine:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        t_end = time.time() + 15
        while time.time() < t_end and set(_procs()) & mine:
            time.sleep(0.1)


# four single-task runs (two tasks, two methods), one at a time per Ray CPU
RAY_GRID = ["--preset", "smoke", "--experiments", "single", "--tasks", "ReachTarget-v1,CloseBox-v1",
            "--methods", "sac,dual_buffer", "--seeds", "1", "--pack", "1"]


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="needs /proc to find the cluster's processes")
def test_a_sweep_whose_ray_head_is_lost_resumes_to_the_same_tables(tmp_path, monkeypatch):
    """`--backend ray --ray-address` on a `ray start` cluster: once a run has finished (and before all), the
    driver and every process of the head are SIGKILLed; a new head on the same address and the same command
    finish the sweep with tables byte-identical to an uninterrupted inline sweep of the same definition.
    The machine holds a Ray token (as one does after its first local Ray sweep, Ray 2.60), so the cluster
    demands it: the driver must send it (it was refused before ``backends._send_ray_token_if_held``)."""
    pytest.importorskip("ray")
    import uuid
    token = tmp_path / "ray_auth_token"
    token.write_text(uuid.uuid4().hex + uuid.uuid4().hex)
    monkeypatch.setenv("RAY_AUTH_TOKEN_PATH", str(token))   # the cluster's and the sweeps' environment
    monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
    ref = tmp_path / "inline"
    assert run_sweep([*RAY_GRID, "--backend", "inline", "--out", str(ref)]) == 0
    runs = json.loads((ref / "sweep.json").read_text())["runs"]
    assert len(runs) == 4
    head = _RayHead()
    out = tmp_path / "ray"
    args = [*RAY_GRID, "--backend", "ray", "--ray-address", head.address, "--out", str(out)]
    log = open(tmp_path / "first.log", "w")
    driver = None
    try:
        head.start()
        driver = subprocess.Popen([sys.executable, "-m", "maniskill_dualher.sweep", *args], cwd=REPO, env=sweep_env(),
                                  stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.time() + 400
        while time.time() < deadline and driver.poll() is None:
            if any(rundir.is_done(out / r) for r in runs):
                break
            time.sleep(0.05)
        assert driver.poll() is None, (tmp_path / "first.log").read_text()[-3000:]
        os.killpg(driver.pid, signal.SIGKILL)
        driver.wait()
        head.lose()
        finished = [r for r in runs if rundir.is_done(out / r)]
        assert 1 <= len(finished) < len(runs), finished
        assert not (out / "summary.md").exists()
        head.start()                      # a new head at the same address
        r = _cli(*args)
        assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-3000:]
        assert f"{len(finished)} of {len(runs)} runs already finished: skipped" in r.stdout
    finally:
        if driver is not None and driver.poll() is None:
            os.killpg(driver.pid, signal.SIGKILL)
        head.lose()
        log.close()
        shutil.rmtree(head.tmp, ignore_errors=True)
    assert all(rundir.is_done(out / r) for r in runs)
    assert _tables_bytes(out) == _tables_bytes(ref)


# ----------------------------------------------------------------------------- transfer protocol
def _tiny(env_id, method="dual_buffer", steps=150, seed=0):
    return RunConfig(env_id=env_id, method=method, seed=seed, total_steps=steps, max_episode_steps=50,
                     eval_every=150, eval_episodes=1, checkpoint_every=150,
                     sac=SACConfig(random_steps=100, learning_starts=100, batch_size=32, hidden=(32, 32)),
                     replay=ReplayConfig(capacity=10_000))


def test_make_stages_follows_the_paper():
    base = _tiny("ReachTarget-v1")
    st = protocol.make_stages(base, protocol.TRANSFER_ORDER, [300, 200, 120], adaptation_ratio=(0.7, 0.3))
    assert [s.env_id for s in st] == list(protocol.TRANSFER_ORDER)
    assert [s.total_steps for s in st] == [300, 200, 120]
    assert all(s.replay.her_k == 8 for s in st) and base.replay.her_k == 4
    assert [s.replay.ratio for s in st] == [(0.6, 0.4), (0.6, 0.4), (0.7, 0.3)]
    # a stage's folder identity includes its predecessors' configs and the carry flag
    st2 = protocol.make_stages(base, protocol.TRANSFER_ORDER, [301, 200, 120])
    assert protocol.stage_dirname(st, 1, True) != protocol.stage_dirname(st2, 1, True)
    assert protocol.stage_dirname(st, 0, True) != protocol.stage_dirname(st, 0, False)
    mixed = [st[0], _tiny("CloseBox-v1", method="sac")]
    with pytest.raises(protocol.ConfigError, match="cannot adapt from a 'dual_buffer' prior"):
        protocol.validate_chain(mixed)


def test_run_transfer_chains_networks_and_replay(tmp_path):
    stages = protocol.make_stages(_tiny("ReachTarget-v1"), ["ReachTarget-v1", "CloseMicrowave-v1"], [150, 150])
    rows = train_chain(stages, tmp_path / "chain", carry_replay=True, show_progress=False)
    d0, d1 = protocol.transfer_chain_dirs(tmp_path / "chain", stages, True)
    assert len(rows) == 2 and all(rundir.is_done(d) for d in (d0, d1))
    info = json.loads((d1 / "stage.json").read_text())
    assert info["stage"] == 1 and info["adaptation"] and info["parent"] == d0.name
    assert json.loads((d1 / "lineage.json").read_text())["init_from"] == str(d0)
    # carried replay: stage 1 holds stage 0's transitions too, so its buffer is larger than a fresh one
    from maniskill_dualher.train import run_training
    fresh = run_training(stages[1], tmp_path / "fresh", init_from=d0, carry_replay=False, show_progress=False)
    assert rows[1]["replay_size"] > fresh["replay_size"] > 0
    # a chain whose last stage takes none of the rows (replay.carry_rows false): the same prior folder, the buffer
    # a fresh start's
    empty = [stages[0], overrides.apply(stages[1], overrides.parse_all(("replay.carry_rows=false",))).validate()]
    rows_empty = train_chain(empty, tmp_path / "chain", carry_replay=True, show_progress=False)
    assert protocol.transfer_chain_dirs(tmp_path / "chain", empty, True)[0] == d0
    assert rows_empty[0] == rows[0] and rows_empty[1]["replay_size"] == fresh["replay_size"]
    # finished chain: a second call trains nothing and returns the same rows
    assert train_chain(stages, tmp_path / "chain", show_progress=False) == rows


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize("args, expect", [
    (["--preset", "nope"], "invalid choice"),
    (["--tasks", "PickCube-v1"], "unknown task"),
    (["--task-order", "ReachTarget-v1,Nope-v0"], "unknown task"),
    (["--methods", "ddpg"], "unknown method"),
    (["--experiments", "single,bogus"], "unknown experiment"),
    (["--set", "replay.ratio=0.6/0.5"], "summing to 1"),
    (["--set", "adapt.replay.ratio=1.5/-0.5"], "non-negative"),
    (["--set", "replay.ratio=half"], "ratio"),
    (["--set", "sac.lr"], "KEY=VALUE"),
    (["--set", "replay.dual_mod=split"], "unknown setting 'replay.dual_mod'"),
    (["--set", "replay.dual_mode=both"], "dual_mode"),
    (["--set", "sac.batch_size=1.5"], "bad value for sac.batch_size"),
    (["--set", "terminate_on_success=maybe"], "bad value for terminate_on_success"),
    (["--seeds", "-1"], "--seeds '-1': a seed must be >= 0, got -1 ('3' is a count: seeds 0,1,2; "),
    (["--seeds=0,-2"], "a seed must be >= 0, got -2"),
    (["--seeds", "a,b"], "--seeds"),
    (["--set", "eval_every=0"], "eval_every"),
    (["--set", "nosuch=1"], "unknown setting"),
    (["--methods", "sac", "--experiments", "ratios"], "needs method dual_buffer"),
    (["--workers", "0"], "--workers"),
    (["--set", "num_envs=4"], "physx_cuda"),
    (["--ray-address", "auto"], "--backend ray"),
    (["--preset", "Quick"], "invalid choice: 'Quick' (choose from 'smoke', 'quick'"),
    (["--source-steps", "0"], "--source-steps must be >= 1, got 0"),
    (["--steps", "300"], "--steps is not a flag here: the single-task and source-stage budget is --source-steps N"),
    (["--methods", "dual_bufer"], f"unknown method 'dual_bufer' (choose from {', '.join(METHOD_SPECS)}) "
                                  "(did you mean dual_buffer?)"),
    (["--tasks", "ClosBox-v1"], "(did you mean CloseBox-v1?)"),
    (["--preset", "quik"], "(did you mean quick?)"),
    (["--set", "sac.gama=0.9"], "unknown setting 'sac.gama' (did you mean sac.gamma?)"),
    (["--sourcesteps", "300"], "unrecognized arguments: --sourcesteps 300 (did you mean --source-steps?)"),
    (["--source-steps", "ten"], "'ten'"),
    (["--adapt-steps", "0"], "--adapt-steps must be >= 1"),
    (["--seeds", ","], "--seeds ',': no seed given ('3' is a count"),
    (["--seeds", "7,7"], "--seeds '7,7' lists a seed twice"),
    (["--seeds", "0"], "--seeds 0 is a count of no seeds: seed 0 alone is --seeds 0, ('3' is a count: seeds 0,1,2; "
                       "'0,4,7' lists seeds; '7,' is seed 7 alone)"),
    (["--chain-seeds", "0"], "--chain-seeds 0 is a count of no seeds: seed 0 alone is --chain-seeds 0, "),
])
def test_bad_input_one_line_exit_2_nothing_written(tmp_path, capsys, args, expect):
    out = tmp_path / "o"
    with pytest.raises(SystemExit) as e:
        sys.exit(run_sweep(["--preset", "smoke", "--out", str(out), *args]))
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and expect in err[0], err
    assert not out.exists()


def _snapshot(folder: Path) -> dict:
    return {str(p): (p.stat().st_mtime_ns, p.read_bytes() if p.is_file() else b"") for p in folder.rglob("*")}


def test_out_folder_of_another_sweep_is_refused(tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "sweep.json").write_text(json.dumps({"preset": "quick", "runs": []}))
    before = _snapshot(out)
    assert run_sweep(["--preset", "smoke", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "different sweep" in err[0] and "--force" in err[0]
    assert _snapshot(out) == before
    # foreign run folders without a sweep.json are refused too
    (out / "sweep.json").unlink()
    (out / "runs/single/x-1234").mkdir(parents=True)
    (out / "runs/single/x-1234/config.json").write_text("{}")
    before = _snapshot(out)
    assert run_sweep(["--preset", "smoke", "--out", str(out)]) == 2
    assert "different config" in capsys.readouterr().err
    assert _snapshot(out) == before


def test_cli_bad_input_exit_code_and_single_error_line(tmp_path):
    out = tmp_path / "o"
    r = _cli("--preset", "smoke", "--set", "replay.ratio=0.7/0.7", "--out", str(out), timeout=120)
    assert r.returncode == 2
    # library import warnings (SAPIEN's libvulkan notice) are not ours; our answer is one line
    ours = [ln for ln in r.stderr.splitlines() if ln.strip() and "Warning" not in ln and not ln.startswith("  warn(")]
    assert ours == ["error: ratio must be two non-negative numbers summing to 1, got '0.7/0.7'"], r.stderr
    assert not out.exists()


def test_help_names_presets_budgets_and_the_one_seed_list(capsys):
    from maniskill_dualher.experiment.presets import PRESETS
    with pytest.raises(SystemExit) as e:
        run_sweep(["--help"])
    assert e.value.code == 0
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps lines
    assert f"one of {', '.join(PRESETS)}" in text
    assert "--source-steps N" in text and "--adapt-steps N" in text and "--steps" not in text.replace(
        "--source-steps", "").replace("--adapt-steps", "").replace("--total-steps", "")
    assert "'7,' is seed 7 ('7' is seeds 0-6; '0' is no seeds, refused: seed 0 alone is '0,')" in text


def test_source_steps_and_adapt_steps_budgets(tmp_path, capsys):
    """--source-steps sets single-task runs and source stages; the adaptation gets 120/200 unless --adapt-steps.
    --steps (train's whole run in issue 31's days, here the source stages) is no flag: one line names the new."""
    assert run_sweep(["--preset", "smoke", "--experiments", "transfer", "--seeds", "1", "--source-steps", "300",
                      "--dry-run", "--out", str(tmp_path / "o")]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    # transfer: 2 methods x (2 source stages of 300 + an adaptation of 180)
    assert last == f"6 runs in --out {tmp_path / 'o'}; 1560 env steps to go; nothing written (--dry-run)", last
    a = sweep.make_parser().parse_args(["--source-steps", "300", "--adapt-steps", "50"])
    d = sweep.definition_from_args(a)
    assert set(d["budgets"]["source"].values()) == {300} and set(d["budgets"]["single"].values()) == {300}
    assert set(d["budgets"]["adapt"].values()) == {50}
    assert sweep.parse_seeds("7,") == (7,) and sweep.parse_seeds("7") == tuple(range(7))
    for old in (["--steps", "300"], ["--steps=300"]):
        with pytest.raises(SystemExit) as e:
            sweep.make_parser().parse_args(old)
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "--source-steps N" in err[0] and "--adapt-steps N" in err[0], err


@pytest.mark.parametrize("path", sorted((Path(__file__).resolve().parents[1] / "bench/results").glob(
    "eta_calibration_*.json")), ids=lambda p: p.stem)
def test_eta_within_25_percent_of_measured_wall_times(path):
    """The dry run's ETA model against the wall times measured on a machine (bench/results/eta_calibration_*.json),
    with the update and env-step seconds timed there in place of the live timing (this machine may be busy or
    another kind). Older files hold one update time and one env-step time per machine; newer ones, per plan,
    what the dry run times for it (``bench/eta_calibration.py``)."""
    from maniskill_dualher.experiment.cost import RUN_START_S, WORKER_START_S, grid_cost, local_wall_seconds
    from maniskill_dualher.pack import pack_key
    cal = json.loads(path.read_text())
    band = cal["band"]
    for name, plan in cal["plans"].items():
        nodes = build_grid(sweep.definition_from_args(sweep.make_parser().parse_args(plan["argv"])))
        if "update_s" in plan:  # timed per plan: keyed as cost.update_seconds caches them
            key = lambda c, p: f"{'x'.join(map(str, c.sac.hidden))}|b{c.sac.batch_size}|{c.sac.variant}|pack{p}"  # noqa: E731
            inputs = [(lambda c, p: plan["update_s"][key(c, p if pack_key(c) is not None else 1)],
                       lambda c: plan["step_s"][c.env_id], lambda c: plan["start_s"][c.env_id])]
        else:
            step = cal["step_s"]["value"]
            inputs = [((lambda c, p, v=upd["value"]: v), (lambda c: step), (lambda c: RUN_START_S))
                      for upd in cal["update_s"].values()]
        for update_s, step_s, start_s in inputs:
            cost = grid_cost([n.cfg for n in nodes], plan.get("pack", sweep.DEFAULT_PACK), update_s=update_s,
                             step_s=step_s, start_s=start_s)
            eta = local_wall_seconds(cost.core_seconds_low if plan.get("bound") == "low" else cost.core_seconds_high,
                                     cost.runs, cal["workers"], plan.get("worker_start_s", WORKER_START_S))
            assert (1 - band) * plan["wall_s"] <= eta <= (1 + band) * plan["wall_s"], (name, eta)


def test_env_step_seconds_times_the_runs_env_here_or_falls_back():
    """The dry run times an env step with acting on this machine (cached per env); an env it cannot build here
    gives the measured constants instead of an error."""
    import dataclasses

    from maniskill_dualher.experiment import cost
    from maniskill_dualher.experiment.presets import preset
    cfg = preset("smoke").single_config("sac_her_per", 0, "ReachTarget-v1")
    s = cost.env_step_seconds(cfg, steps=50)
    assert 1e-5 < s < 0.05 and cost.env_step_seconds(cfg) == s  # timed once, then cached
    assert 0 < cost.run_start_seconds(cfg) < 60 and 0 < cost.worker_start_seconds() < 120
    bad = dataclasses.replace(cfg, env_id="NoSuchEnv-v9")
    assert cost.env_step_seconds(bad) == cost.ENV_STEP_S + cost.ACT_S and cost.run_start_seconds(bad) == cost.RUN_START_S


def test_seeds_settings_and_dry_run(tmp_path, capsys):
    assert sweep.parse_seeds("3") == (0, 1, 2)
    assert sweep.parse_seeds("4,7") == (4, 7) and sweep.parse_seeds("7,") == (7,)
    out = tmp_path / "o"
    assert run_sweep(["--preset", "smoke", "--out", str(out), "--experiments", "ratios", "--seeds", "1",
                       "--dry-run"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1] == f"5 runs in --out {out}; 750 env steps to go; nothing written (--dry-run)"  # 2+3 stages
    assert sum("stage2-CloseMicrowave-v1-r0.5-0.5" in ln for ln in lines) == 1
    assert not out.exists()


def test_set_changes_every_run_or_one_stage(tmp_path, capsys):
    """`--set` reaches any RunConfig field, for every run or (adapt./source./stageN.) one stage of a chain."""
    args = lambda *extra: sweep.definition_from_args(sweep.make_parser().parse_args(  # noqa: E731
        ["--preset", "smoke", "--seeds", "1", "--experiments", "single,transfer", *extra]))
    plain = {n.rel: n for n in build_grid(args())}
    split = build_grid(args("--set", "replay.dual_mode=split"))
    assert all(n.cfg.replay.dual_mode == "split" for n in split)
    assert not {n.rel for n in split} & set(plain)        # a changed setting is a different run
    staged = build_grid(args("--set", "adapt.sac.random_steps=0", "--set", "source.replay.her_k=2"))
    for n in staged:
        if n.stages is None:   # single-task runs: stage settings do not apply
            assert n.cfg.sac.random_steps == 100 and n.cfg.replay.her_k == 4
        elif n.stage == 2:
            assert n.cfg.sac.random_steps == 0 and n.cfg.replay.her_k == 8
        else:
            assert n.cfg.sac.random_steps == 100 and n.cfg.replay.her_k == 2
    assert run_sweep(["--set", "replay.dual_mode=split", "--dry-run", "--out", str(tmp_path / "o")]) == 0
    out = capsys.readouterr().out
    assert "96 runs" in out and not (tmp_path / "o").exists()


# ----------------------------------------------------------------------------- scheduling
class _FakeBackend:
    """In-process backend: records submissions, fails the runs it is told to, marks others done."""

    def __init__(self, out, fail=(), capacity=2):
        self.out, self.fail, self.capacity, self.order = out, set(fail), capacity, []

    def submit(self, payload):
        self.order.append(payload["rel"])
        return len(self.order) - 1

    def wait(self, handles):
        return [min(handles)]

    def result(self, h):
        rel = self.order[h]
        if rel in self.fail:
            raise RuntimeError("boom\nlast line of the error")
        (self.out / rel).mkdir(parents=True, exist_ok=True)
        (self.out / rel / "done.json").write_text("{}")
        return {"rel": rel, "row": {"eval_success_rate": 0.5, "train_successes": 3}}


def test_run_grid_parents_first_failures_block_descendants(tmp_path, capsys):
    d = sweep.definition_from_args(sweep.make_parser().parse_args(["--preset", "smoke", "--seeds", "1"]))
    nodes = build_grid(d)
    by = {n.rel: n for n in nodes}
    single = next(n.rel for n in nodes if n.parent is None and n.stages is None)
    (tmp_path / single).mkdir(parents=True)
    (tmp_path / single / "done.json").write_text("{}")                      # finished before: skipped
    stage0 = next(n.rel for n in nodes if n.stages and n.stage == 0 and n.cfg.method == "sac_her_per")
    be = _FakeBackend(tmp_path, fail={stage0})
    failed = run_grid(nodes, tmp_path, be, progress=False)
    assert single not in be.order
    pos = {rel: i for i, rel in enumerate(be.order)}
    for rel in be.order:                                                    # a stage only after its parent
        if by[rel].parent:
            assert pos[by[rel].parent] < pos[rel]
    # long chains first: the 3 stage-0 roots with descendants are submitted before any single-task run
    assert all(by[r].stages is not None for r in be.order[:2])
    blocked = {n.rel for n in nodes if n.parent and (n.parent == stage0 or by[n.parent].parent == stage0)}
    assert set(failed) == {stage0} | blocked and len(blocked) == 2
    assert not blocked & set(be.order)
    out = capsys.readouterr().out
    assert "FAILED" in out and "last line of the error" in out and "2 runs not started" in out
    assert "final eval success 0.50, successful training episodes 3" in out


def test_a_sweep_in_which_no_run_finishes_ends_with_one_line_exit_1(tmp_path):
    """Every run fails, for a real cause (each run folder's provenance.json is a folder, so no run can record
    its start): the sweep ends with one line on stderr saying how many runs did not finish and the command
    that retries them, exit 1, no traceback, no report. That command, once the cause is gone, finishes them."""
    import shlex
    out = tmp_path / "none"
    args = ["--preset", "smoke", "--experiments", "single", "--tasks", "ReachTarget-v1", "--methods", "sac",
            "--seeds", "2", "--out", str(out)]
    rels = [ln.split()[1] for ln in _cli(*args, "--dry-run").stdout.splitlines() if ln.startswith("todo ")]
    assert len(rels) == 2
    for rel in rels:
        (out / rel / rundir.PROVENANCE).mkdir(parents=True)
    r = _cli(*args)
    assert r.returncode == 1, r.stderr[-3000:]
    assert "Traceback" not in r.stderr + r.stdout
    err = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert [ln for ln in err if ln.startswith("error:")] == err[-1:], err[-5:]
    again = "python -m maniskill_dualher.sweep " + shlex.join(args)
    assert err[-1].startswith("error: 2 of 2 runs did not finish (first: runs/single/") and "no run finished" in err[-1]
    assert err[-1].endswith(f"rerun the same command to retry them: {again}"), err[-1]
    assert r.stdout.count("FAILED") == 2 and all((out / rel / rundir.ERROR).is_file() for rel in rels)
    assert not (out / "summary.md").exists() and not (out / "scores.csv").exists()
    for rel in rels:
        (out / rel / rundir.PROVENANCE).rmdir()
    r = subprocess.run([sys.executable, *shlex.split(again)[1:]], cwd=REPO, env=sweep_env(), capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]
    assert all(rundir.is_done(out / rel) for rel in rels) and (out / "summary.md").is_file()


def _fresh_copy(dst: Path) -> Path:
    """The repository as a fresh clone sees it: tracked and unignored files, committed in a new git repo."""
    files = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=REPO, capture_output=True,
                           text=True, check=True).stdout.split()
    for f in files:
        src = REPO / f
        if src.is_file():
            (dst / f).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dst / f)
    git = lambda *a: subprocess.run(["git", *a], cwd=dst, capture_output=True, text=True, check=True)  # noqa: E731
    git("init", "-q")
    git("add", "-A")
    git("-c", "user.email=t@t", "-c", "user.name=t", "commit", "-qm", "fresh")
    return dst


def test_readme_first_command_on_a_fresh_copy_writes_outside_the_reference(tmp_path):
    """README's first command, as written (plus a tiny budget): it trains, reports, writes under runs/first,
    never touches the committed results/, and leaves git status clean."""
    repo = _fresh_copy(tmp_path / "repo")
    readme = (repo / "README.md").read_text()
    first = next(ln for ln in readme.splitlines() if ln.startswith("python -m maniskill_dualher.sweep"))
    argv = first.split("#")[0].split()[3:]
    assert argv[:4] == ["--experiments", "single", "--tasks", "ReachTarget-v1"] and argv[6:] == ["--out", "runs/first"]
    assert argv[4] == "--seeds" and int(argv[5]) >= 5, "claim (e)'s paired interval needs 5 pairs"
    n_seeds = int(argv[5])
    before = {p: p.read_bytes() for p in (repo / "results").rglob("*") if p.is_file()}
    env = sweep_env()
    env["PYTHONPATH"] = str(repo)
    r = subprocess.run([sys.executable, "-m", "maniskill_dualher.sweep", *argv, "--source-steps", "60",
                        "--set", "eval_every=30", "--set", "eval_episodes=1", "--set", "sac.random_steps=20",
                        "--set", "sac.learning_starts=20"], cwd=repo, env=env, capture_output=True, text=True,
                       timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    out = repo / "runs" / "first"
    assert len(list(out.rglob("done.json"))) == 3 * n_seeds
    claims = {row["claim"]: row for row in csv.DictReader(open(out / "claims.csv"))}
    assert claims["e"]["n_a"] == str(n_seeds) and claims["e"]["diff_ci95_low"] not in ("", "nan") and not claims["e"]["verdict"].startswith("not measured")
    after = {p: p.read_bytes() for p in (repo / "results").rglob("*") if p.is_file()}
    assert after == before, "the committed reference was touched"
    status = subprocess.run(["git", "status", "--porcelain"], cwd=repo, capture_output=True, text=True).stdout
    assert status == "", status


def test_capped_arms_are_named_and_an_explicit_request_beyond_a_cap_is_refused(tmp_path, capsys):
    """Arm/Experiment.max_seeds never cut silently: every plan names the capped arms; --seeds beyond a selected
    arm's cap is one line, exit 2, nothing written, unless --allow-capped."""
    from maniskill_dualher.experiment.registry import EXPERIMENTS
    capped = [(e.name, a.name, min(c for c in (e.max_seeds, a.max_seeds) if c)) for e in EXPERIMENTS.values()
              for a in e.arms if e.max_seeds or a.max_seeds]
    assert capped, "the registry has capped arms"
    name, arm, cap = capped[0]
    out = tmp_path / "o"
    args = ["--preset", "smoke", "--experiments", f"{name}:{arm}", "--out", str(out)]
    assert run_sweep([*args, "--seeds", str(cap + 1), "--dry-run"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"error: {name}/{arm} runs at most {cap} seeds, {cap + 1} asked")
    assert not out.exists()
    assert run_sweep([*args, "--seeds", str(cap + 1), "--dry-run", "--allow-capped"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert f"capped: {name}/{arm} runs {cap} of the {cap + 1} seeds asked (max_seeds)" in lines
    assert "--allow-capped" in sweep.make_parser().format_help()


# ----------------------------------------------------------------------------- the reference's seeds
def _definition(*argv):
    return sweep.definition_from_args(sweep.make_parser().parse_args(list(argv)))


def _reference_cells():
    """(experiment, arm, method, task) -> the seeds results/reference/scores.csv has for it (single and adapt)."""
    out = defaultdict(set)
    with open(REPO / "results" / "reference" / "scores.csv", newline="") as f:
        for r in csv.DictReader(f):
            if r["role"] in ("single", "adapt"):
                out[(r["experiment"], r["arm"], r["method"], r["task"])].add(int(r["seed"]))
    return out


def test_the_reference_plan_is_exactly_the_cells_of_results_reference():
    """`sweep --preset reference --experiments all` plans the (experiment, arm, method, task, seed, stage) cells of
    results/reference/scores.csv, no more and no fewer: the preset reads each arm's seeds from those cells, so
    the two cannot drift apart (seeds merged into the reference are planned with nothing to edit)."""
    key = ("experiment", "arm", "method", "task", "seed", "stage")
    d = _definition("--preset", "reference", "--experiments", "all")
    planned = {tuple(str(c[k]) for k in key) for n in build_grid(d) for c in n.cells}
    with open(REPO / "results" / "reference" / "scores.csv", newline="") as f:
        have = {tuple(r[k] for k in key) for r in csv.DictReader(f)}
    assert sorted(planned - have)[:5] == [] and sorted(have - planned)[:5] == []
    from maniskill_dualher.analysis.report import MERGE_SAME   # the same budgets and settings as the reference
    ref = json.loads((REPO / "results" / "reference" / "sweep.json").read_text())
    assert {k: d[k] for k in MERGE_SAME} == {k: ref[k] for k in MERGE_SAME}


def test_the_reference_seeds_are_any_set_its_cells_have(tmp_path, monkeypatch, capsys):
    """An arm's seeds in the reference preset are exactly those its cells have in the folder (here 0-3 and 32-35,
    not a count from 0), per method where they differ; an arm without cells there has none."""
    from maniskill_dualher.experiment import presets
    from maniskill_dualher.experiment.grid import seeds_for
    from maniskill_dualher.experiment.registry import EXPERIMENTS
    rows = [{"experiment": "warm_start", "arm": "warm", "method": m, "task": "CloseMicrowave-v1", "seed": s,
             "stage": 2, "role": "adapt"} for m, seeds in (("dual_buffer", (0, 1, 2, 3, 32, 33, 34, 35)),
                                                         ("sac_her_per", (5,))) for s in seeds]
    rows.append(dict(rows[0], stage=0, role="source", task="ReachTarget-v1", seed=99))  # a source stage: not a seed
    with open(tmp_path / "scores.csv", "w", newline="") as f:
        w = csv.DictWriter(f, list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    monkeypatch.setattr(presets.PRESETS["reference"], "seeds_from", str(tmp_path))
    d = _definition("--preset", "reference", "--experiments", "warm_start")
    exp = EXPERIMENTS["warm_start"]
    assert seeds_for(d, exp, exp.arm("warm"), "dual_buffer", "CloseMicrowave-v1") == [0, 1, 2, 3, 32, 33, 34, 35]
    assert seeds_for(d, exp, exp.arm("warm"), "sac_her_per", "CloseMicrowave-v1") == [5]
    assert seeds_for(d, exp, exp.arm("paper"), "dual_buffer", "CloseMicrowave-v1") == []
    adapt = {(c["method"], c["seed"]) for n in build_grid(d) for c in n.cells if c["role"] == "adapt"}
    assert adapt == {("dual_buffer", s) for s in (0, 1, 2, 3, 32, 33, 34, 35)} | {("sac_her_per", 5)}
    assert run_sweep(["--preset", "reference", "--experiments", "warm_start", "--dry-run",
                      "--out", str(tmp_path / "o")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert "seeds: warm_start/warm dual_buffer: 8 (0-3, 32-35), capped: the preset lists 16 [seed table]" in lines
    assert "seeds: warm_start/warm sac_her_per: 1 (5), capped: the preset lists 16 [seed table]" in lines


def test_the_reference_seeds_decide_by_default_and_explicit_seeds_drop_them(tmp_path, capsys):
    """--preset reference alone: the cells' seeds (over max_seeds, per method/task where they differ); --seeds or
    --chain-seeds: the table is dropped and the caps apply, a request beyond one refused in one line, exit 2."""
    from maniskill_dualher.experiment.grid import seeds_for
    from maniskill_dualher.experiment.registry import EXPERIMENTS
    cells = _reference_cells()
    exp = EXPERIMENTS["her_episode"]          # max_seeds 8, more seeds in the reference
    arm = exp.arm("her_episode")
    have = sorted(cells[("her_episode", "her_episode", "dual_buffer", "CloseMicrowave-v1")])
    d = _definition("--preset", "reference", "--experiments", "her_episode")
    assert {k.split(":")[0] for k in d["arm_seeds"]} == {"her_episode"}  # only the selected arms' cells
    assert seeds_for(d, exp, arm, "dual_buffer", "CloseMicrowave-v1") == have
    assert len(have) > exp.max_seeds
    single = EXPERIMENTS["single"]
    ds = _definition("--preset", "reference", "--experiments", "single")
    got = {(m, t): seeds_for(ds, single, single.arm("paper"), m, t) for m in ("sac", "sac_her_per")
           for t in ("ReachTarget-v1", "CloseBox-v1")}
    assert got == {(m, t): sorted(cells[("single", "paper", m, t)]) for m, t in got}
    assert got[("sac_her_per", "ReachTarget-v1")] == [] and got[("sac", "CloseBox-v1")]
    for flag in ("--seeds", "--chain-seeds"):
        d2 = _definition("--preset", "reference", "--experiments", "her_episode", flag, "4")
        assert "arm_seeds" not in d2 and seeds_for(d2, exp, arm, "dual_buffer", "CloseMicrowave-v1") == [0, 1, 2, 3]
    out = tmp_path / "o"
    base = ["--preset", "reference", "--experiments", "her_episode", "--out", str(out), "--dry-run"]
    capsys.readouterr()
    assert run_sweep([*base, "--chain-seeds", "9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: her_episode/paper runs at most 8 seeds, 9 asked"), err
    assert not out.exists()
    # the table: every arm gets a seeds: line saying what it plans and whether it is capped
    assert run_sweep(base) == 0
    lines = capsys.readouterr().out.splitlines()
    assert f"seeds: her_episode/her_episode: {len(have)} ({seed_span(have)}) [seed table]" in lines
    assert "seeds: her_episode/paper: 0, capped: the preset lists 16 [seed table]" in lines
    assert ("capped: her_episode/paper runs 0 of the preset's 16 seeds (seed table): not in results/reference "
            "(--chain-seeds 16 runs it at the preset's 16)") in lines
    assert any(ln.startswith("cost: ") for ln in lines) and not out.exists()
    # explicit seeds are named as asked, not as a count from 0
    assert run_sweep([*base, "--chain-seeds", "4,5,6,7"]) == 0
    assert "seeds: her_episode/her_episode: 4 (4-7)" in capsys.readouterr().out.splitlines()


def test_a_reference_sweep_folder_with_the_older_seed_table_is_the_same_sweep(tmp_path, capsys):
    """A sweep.json whose arm_seeds are the older counts per arm (before the seeds were read from the reference)
    holds the same sweep when its runs are the same: it resumes without --force; other runs are refused."""
    out = tmp_path / "o"
    d = _definition("--preset", "reference", "--experiments", "warm_start:warm_low_lr")
    d["runs"] = sorted(n.rel for n in build_grid(d))
    old = dict(d, arm_seeds={"warm_start:warm_low_lr": 16})
    rundir.write_json(out / rundir.SWEEP, old)
    args = ["--preset", "reference", "--experiments", "warm_start:warm_low_lr", "--out", str(out), "--dry-run"]
    assert run_sweep(args) == 0
    rundir.write_json(out / rundir.SWEEP, dict(old, runs=d["runs"][:-1]))
    capsys.readouterr()
    assert run_sweep([a for a in args if a != "--dry-run"]) == 2 and "holds a different sweep" in \
        capsys.readouterr().err


def test_a_new_experiment_has_no_reference_seeds_and_its_dry_run_says_how_to_ask(tmp_path, monkeypatch, capsys):
    """One registry entry and nothing else: the reference preset plans it at no seeds (it is not in
    results/reference), says in one line how to ask for the preset's, and plans them when asked."""
    from maniskill_dualher.experiment import registry
    exp = registry.Experiment("my_new", "a lower adaptation learning rate", "chain", methods="transfer",
                              arms=(registry.Arm("low_lr", ("adapt.sac.lr=3e-4",)),))
    monkeypatch.setitem(registry.EXPERIMENTS, exp.name, exp)
    base = ["--preset", "reference", "--experiments", "my_new", "--out", str(tmp_path / "o"), "--dry-run"]
    assert run_sweep(base) == 0
    out = capsys.readouterr().out.splitlines()
    assert ("capped: my_new/low_lr runs 0 of the preset's 16 seeds (seed table): not in results/reference "
            "(--chain-seeds 16 runs it at the preset's 16)") in out
    assert out[-1] == f"0 runs in --out {tmp_path / 'o'}; 0 env steps to go; nothing written (--dry-run)"
    assert run_sweep([*base, "--chain-seeds", "16"]) == 0
    assert capsys.readouterr().out.splitlines()[-1].startswith(f"{2 * 16 * 3} runs in --out ")


# --------------------------------------------------------------------------- issue 51: settings files, dry runs
def test_sweep_config_file_is_settings_for_every_run(tmp_path, capsys):
    """`sweep --config FILE` (YAML or JSON): a RunConfig's mapping or part of one, a stage's under adapt:, each a
    --set before the command line's; the sweep's per-run keys are refused with the flag that sets them."""
    (tmp_path / "s.yaml").write_text("sac:\n  lr: 3e-4\n  hidden: [32, 32]\nadapt:\n  sac:\n    random_steps: 0\n"
                                     "replay: {ratio: [0.5, 0.5]}\nterminate_on_success: false\n")
    (tmp_path / "s.json").write_text(json.dumps({"sac": {"lr": 3e-4, "hidden": [32, 32]},
                                                 "adapt": {"sac": {"random_steps": 0}},
                                                 "replay": {"ratio": [0.5, 0.5]}, "terminate_on_success": False}))
    want = ["sac.lr=0.0003", "sac.hidden=32,32", "adapt.sac.random_steps=0", "replay.ratio=0.5/0.5",
            "terminate_on_success=False"]
    for f in ("s.yaml", "s.json"):
        a = sweep.make_parser().parse_args(["--config", str(tmp_path / f), "--set", "sac.lr=1e-4"])
        assert sweep.definition_from_args(a)["settings"] == want + ["sac.lr=0.0001"], f
    (tmp_path / "seed.yaml").write_text("seed: 3\n")
    out = tmp_path / "o"
    assert run_sweep(["--preset", "smoke", "--config", str(tmp_path / "seed.yaml"), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "seed is the sweep's to set per run (--seeds)" in err[0] and not out.exists()


def test_a_dry_run_reads_any_folder_and_names_its_out(tmp_path, capsys):
    """A dry run writes nothing, so another sweep's --out is read, not refused: the dry run says what a run would
    answer and ends with its --out; the run itself is still refused."""
    out = tmp_path / "other"
    rundir.write_json(out / rundir.SWEEP, {"preset": "quick", "runs": []})
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    args = ["--preset", "smoke", "--experiments", "transfer", "--methods", "dual_buffer", "--seeds", "1,",
            "--out", str(out)]
    assert run_sweep([*args, "--dry-run"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[-1] == f"3 runs in --out {out}; 450 env steps to go; nothing written (--dry-run)"
    assert lines[-2].startswith("note: this sweep without --dry-run would be refused: ") and "different sweep" in lines[-2]
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert run_sweep(args) == 2 and "holds a different sweep" in capsys.readouterr().err
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before


def test_sweep_json_records_each_arms_settings_as_run_and_an_older_folder_without_them_is_the_same_sweep(tmp_path):
    """sweep.json's arms_as_run: per arm, role and task, the budget and every setting the arm names, read from the
    runs' configs (the paper regime's adaptation: 3.6M env steps, whatever the preset's budgets say); the record
    decides no run, so a folder written before it existed is the same sweep, not refused."""
    out = tmp_path / "o"
    args = ["--preset", "smoke", "--experiments", "paper_regime", "--chain-seeds", "3,", "--out", str(out)]
    assert run_sweep([*args, "--emit-commands", str(tmp_path / "cmd.txt")]) == 0
    d = json.loads((out / rundir.SWEEP).read_text())
    arms = d[sweep.ARMS_AS_RUN]
    for arm, schedule in (("step", "step"), ("episode", "episode")):
        adapt = arms[f"paper_regime/{arm}"]["adapt"][PAPER_TARGET]
        assert adapt["total_steps"] == 3_600_000 and adapt["sac.update_schedule"] == schedule
        assert adapt["replay.capacity"] == "10000000" and adapt["replay.her_k"] == "8"
    assert arms["paper_regime/random"]["adapt"][PAPER_TARGET]["sac.learning_starts"] == "3600000"
    assert d["budgets"]["adapt"][PAPER_TARGET] != 3_600_000  # the preset's budget: not what these arms ran
    older = {k: v for k, v in d.items() if k != sweep.ARMS_AS_RUN}
    (out / rundir.SWEEP).write_text(json.dumps(older))
    assert run_sweep([*args, "--emit-commands", str(tmp_path / "cmd2.txt")]) == 0
    assert json.loads((out / rundir.SWEEP).read_text())[sweep.ARMS_AS_RUN] == arms
    other = sweep.definition_from_args(sweep.make_parser().parse_args([*args[:-2], "--set", "sac.lr=0.5"]))
    with pytest.raises(Exception, match="differs in: settings"):
        sweep.check_out_folder(out, {**other, "runs": d["runs"]}, force=False)


# ----------------------------------------------------------------------------- --status
def test_status_says_where_a_sweep_stands_from_its_files_and_writes_nothing(tmp_path, capsys):
    """`sweep --status --out DIR` on a sweep with one run of each kind: finished (done.json), failed
    (error.txt: its last line), started (progress.json: env steps of total, its pid, the pace between its last
    two evaluations and what is left at it, when its last checkpoint was written, or that it has none), not started; and its lock's holder, alive or ended. Nothing in the
    folder changes; a folder with no sweep.json is one line and exit 2."""
    import os
    import socket
    import subprocess
    out = tmp_path / "sw"
    runs = [f"runs/single/r{i}" for i in range(5)]
    for rel in runs:
        (out / rel).mkdir(parents=True)
        (out / rel / "config.json").write_text(json.dumps({"method": "dual_buffer", "seed": 7, "env_id": "X-v1"}))
    (out / "sweep.json").write_text(json.dumps({"runs": runs}))
    (out / runs[0] / "done.json").write_text("{}")
    (out / runs[1] / "error.txt").write_text("Traceback ...\nValueError: the last line\n")
    (out / runs[2] / "progress.json").write_text(json.dumps(
        {"env_steps": 30_000, "total_steps": 120_000, "pid": 4242, "host": "h", "time": 1000.0}))
    (out / runs[2] / "metrics.csv").write_text("env_steps,eval_return,wall_time_s\n0,0,0\n10000,0,40\n20000,0,90\n")
    (out / runs[2] / "checkpoint.pt").write_bytes(b"")
    os.utime(out / runs[2] / "checkpoint.pt", (time.time() - 1200, time.time() - 1200))
    (out / runs[3] / "progress.json").write_text(json.dumps({"env_steps": 0, "total_steps": 1}))   # no checkpoint
    (out / ".sweep.lock").write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname(),
                                                 "since": "2026-01-01T00:00:00Z"}))
    before = {p: p.stat().st_mtime_ns for p in out.rglob("*")}
    assert run_sweep(["--status", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert f"{out}: 5 runs, 1 finished, 2 started and unfinished, 1 failed, 1 not started" in text
    assert f"held by pid {os.getpid()} on host {socket.gethostname()}, since 2026-01-01T00:00:00Z: running" in text
    assert (f"{runs[2]} (dual_buffer seed 7 X-v1): 30,000 of 120,000 env steps (25.0%)" in text
            and "(pid 4242 on h); 200 env steps/s between its last two evaluations, ~8 min to go; "
                "last checkpoint written 20 min ago" in text), text
    assert f"{runs[3]} (dual_buffer seed 7 X-v1): 0 of 1 env steps (0.0%); no checkpoint yet (a resume starts it " \
           "over)" in text
    assert f"FAILED {runs[1]} (dual_buffer seed 7 X-v1): ValueError: the last line" in text
    ended = subprocess.Popen(["true"])
    ended.wait()
    (out / ".sweep.lock").write_text(json.dumps({"pid": ended.pid, "host": socket.gethostname(), "since": "s"}))
    before[out / ".sweep.lock"] = (out / ".sweep.lock").stat().st_mtime_ns
    assert run_sweep(["--status", "--out", str(out)]) == 0
    assert f"last held by pid {ended.pid} on host {socket.gethostname()}, since s, which has ended" in \
        capsys.readouterr().out
    (out / ".sweep.lock").write_text("")   # what a sweep leaves when it releases the folder
    before[out / ".sweep.lock"] = (out / ".sweep.lock").stat().st_mtime_ns
    assert run_sweep(["--status", "--out", str(out)]) == 0
    assert "; its lock names no holder" in capsys.readouterr().out
    assert {p: p.stat().st_mtime_ns for p in out.rglob("*")} == before
    assert run_sweep(["--status", "--out", str(tmp_path / "none")]) == 2
    assert capsys.readouterr().err.strip() == \
        f"error: --status: no sweep in {tmp_path / 'none'} (no sweep.json listing its runs)"
    assert not (tmp_path / "none").exists()


def test_status_of_a_finished_sweep(smoke_local, capsys):
    assert run_sweep(["--status", "--out", str(smoke_local)]) == 0
    n = len(json.loads((smoke_local / "sweep.json").read_text())["runs"])
    assert f"{n} runs, {n} finished, 0 started and unfinished, 0 failed, 0 not started" in capsys.readouterr().out
