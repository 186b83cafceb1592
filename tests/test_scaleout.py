"""Past one machine: lost workers retried from their checkpoints (local pool and a two-node Ray cluster),
one sweep per out folder, progress of runs in flight on the sweep's bar, and the grid as train commands
(a SLURM job array). Every sweep here is one smoke chain (3 stages), checked against an undisturbed one."""
from __future__ import annotations

import json
import os
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from maniskill_dualher import faults, rundir
from maniskill_dualher.config import RunConfig
from maniskill_dualher.experiment import backends, sweep
from maniskill_dualher.sweep import main as run_sweep, train_runs as entry_train_runs  # noqa: F401
from maniskill_dualher.experiment.grid import Node
from maniskill_dualher.experiment.lock import LOCK_FILE, FolderLock
from subprocs import alive, kill_group, sweep_env

REPO = Path(__file__).resolve().parents[1]
TABLES = ["claims.csv", "table5_multitask.csv", "scores.csv"]
# one 3-stage chain (source stages 300 steps, adaptation 180), checkpoints every 50 steps
CHAIN = ["--preset", "smoke", "--experiments", "transfer", "--methods", "sac_her_per", "--seeds", "1,",
         "--source-steps", "300"]


def _env(hold=None):
    return sweep_env(hold, "checkpoint:*/stage[1-9]*")    # a chain's stages after the first


def _sweep_cli(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "maniskill_dualher.sweep", *args], cwd=REPO, env=_env(),
                          capture_output=True, text=True, timeout=timeout)


def _popen_sweep(log: Path, *args, hold=None):
    return subprocess.Popen([sys.executable, "-m", "maniskill_dualher.sweep", *args], cwd=REPO, env=_env(hold),
                            stdout=open(log, "w"), stderr=subprocess.STDOUT, start_new_session=True)


def _tables(out: Path) -> dict:
    return {name: (out / name).read_bytes() for name in TABLES}


def _stage_in_flight(out: Path, min_stage: int = 1):
    """A chain stage >= min_stage with a checkpoint and a progress file but not finished, or None."""
    for f in sorted(out.glob("runs/chain/*/stage*/checkpoint.pt")):
        d = f.parent
        if int(d.name[len("stage"):].split("-")[0]) >= min_stage and not rundir.is_done(d) \
                and backends.read_progress(d):
            return d
    return None


def _held_stage(p: subprocess.Popen, out: Path, log: Path) -> Path:
    """The chain stage the sweep ``p`` holds after a checkpoint (``_stage_in_flight``), waited for."""
    deadline, victim = time.time() + 240, None
    while time.time() < deadline and p.poll() is None and victim is None:
        victim = _stage_in_flight(out)
        time.sleep(0.01)
    assert victim is not None, "no stage was in flight: " + log.read_text()[-2000:]
    return victim


def _starts(run_dir: Path) -> int:
    return len(json.loads((run_dir / rundir.PROVENANCE).read_text())["starts"])


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The chain, undisturbed, inline: what every disturbed sweep must reproduce."""
    out = tmp_path_factory.mktemp("scaleout") / "ref"
    t0 = time.perf_counter()
    assert run_sweep([*CHAIN, "--out", str(out), "--backend", "inline"]) == 0
    print(f"reference chain, inline: {time.perf_counter() - t0:.1f} s")
    return out


# ----------------------------------------------------------------------------- lost workers
@pytest.mark.skipif(not Path("/proc").is_dir(), reason="Linux: a pool worker is killed by its pid")
def test_local_pool_worker_sigkilled_midrun_is_retried_from_checkpoint(reference, tmp_path):
    out = tmp_path / "lost"
    log = tmp_path / "sweep.log"
    hold = tmp_path / "hold"
    hold.touch()
    p = _popen_sweep(log, *CHAIN, "--out", str(out), "--workers", "1", "--retries", "1", hold=hold)
    try:
        victim = _held_stage(p, out, log)
        pid = backends.read_progress(victim)["pid"]
        assert pid != p.pid
        os.kill(pid, signal.SIGKILL)                     # held after its checkpoint: killed mid-run, every time
        hold.unlink()
        p.wait(timeout=240)
    finally:
        kill_group(p)
    text = log.read_text()
    assert p.returncode == 0, text[-3000:]
    assert "LOST" in text and "retry 1/1 from its last checkpoint" in text, text[-3000:]
    assert "running again, now pid" in text                # the bar saw the new worker's progress file
    assert _starts(victim) == 2                          # resumed once, in a fresh worker
    assert _tables(out) == _tables(reference)
    assert backends.read_progress(victim)["env_steps"] == RunConfig.from_dict(
        json.loads((victim / "config.json").read_text())).total_steps


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="Linux: the pool's workers are signalled by pid")
def test_a_stop_signal_to_the_sweep_checkpoints_its_runs_and_the_same_command_resumes(reference, tmp_path):
    """SIGTERM to the sweep's own process (as `kill <pid>`; a scheduler signals every process, which the workers
    take as one stop) while a chain stage runs in a pool worker: no run starts, the stage checkpoints at the end
    of its episode in the same worker (not lost, not retried), the sweep exits 143 with one line and no report,
    and the same command resumes it to the tables of an undisturbed sweep."""
    out = tmp_path / "stopped"
    log = tmp_path / "sweep.log"
    hold = tmp_path / "hold"
    hold.touch()
    p = _popen_sweep(log, *CHAIN, "--out", str(out), "--workers", "1", hold=hold)
    try:
        victim = _held_stage(p, out, log)
        worker = backends.read_progress(victim)["pid"]
        os.kill(p.pid, signal.SIGTERM)                   # the worker is held after a checkpoint: mid-run
        time.sleep(0.5)
        hold.unlink()
        p.wait(timeout=240)
    finally:
        kill_group(p)
    text = log.read_text()
    assert p.returncode == 128 + signal.SIGTERM, text[-3000:]
    assert "stopped by SIGTERM: 1 run in flight checkpointed at the end of an episode; no report" in text, text[-3000:]
    assert "LOST" not in text and "FAILED" not in text
    assert not rundir.is_done(victim) and not (out / "summary.md").exists()
    assert not alive(worker)                              # the pool ended with the sweep
    assert _starts(victim) == 1
    r = _sweep_cli(*CHAIN, "--out", str(out), "--workers", "1")
    assert r.returncode == 0, r.stderr[-3000:]
    assert _starts(victim) == 2 and rundir.is_done(victim)
    assert _tables(out) == _tables(reference)


def test_a_stop_signal_to_an_inline_sweep_checkpoints_its_run_and_the_same_command_resumes(reference, tmp_path,
                                                                                           monkeypatch, capsys):
    """Inline (the run trains in the sweep's own process): SIGUSR1 while a chain stage is held after a checkpoint
    stops it at the end of its episode; the sweep returns 138 and the same command ends with the reference's
    tables."""
    import threading
    out = tmp_path / "inline"
    hold = tmp_path / "hold"
    hold.touch()
    monkeypatch.setenv(faults.HOLD_AT, "checkpoint:*/stage[1-9]*")
    monkeypatch.setenv(faults.HOLD_WHILE, str(hold))

    def stop_when_held():
        deadline = time.time() + 240
        while time.time() < deadline and _stage_in_flight(out) is None:
            time.sleep(0.01)
        os.kill(os.getpid(), signal.SIGUSR1)
        time.sleep(0.2)
        hold.unlink()
    t = threading.Thread(target=stop_when_held, daemon=True)
    t.start()
    rc = run_sweep([*CHAIN, "--out", str(out), "--backend", "inline"])
    t.join()
    err = capsys.readouterr().err
    assert rc == 128 + signal.SIGUSR1, err[-3000:]
    assert "stopped by SIGUSR1: 1 run in flight checkpointed at the end of an episode; no report" in err
    victim = _stage_in_flight(out)
    assert victim is not None and _starts(victim) == 1 and not (out / "summary.md").exists()
    monkeypatch.delenv(faults.HOLD_AT)
    assert run_sweep([*CHAIN, "--out", str(out), "--backend", "inline"]) == 0
    assert _starts(victim) == 2 and rundir.is_done(victim)
    assert _tables(out) == _tables(reference)


def test_lost_worker_bound_and_failure_points_to_traceback(tmp_path, capsys):
    """run_grid: a lost run is resubmitted up to ``retries`` times, then fails; a raising run fails at
    once, and both name the run's error.txt when it has one."""
    cfg = RunConfig(total_steps=10)
    nodes = [Node("runs/single/a", cfg, "run a"), Node("runs/single/b", cfg, "run b")]
    (tmp_path / "runs/single/b").mkdir(parents=True)
    (tmp_path / "runs/single/b/error.txt").write_text("Traceback ...\nValueError: bad\n")

    class Lossy:
        capacity = 2

        def __init__(self):
            self.submitted = []

        def submit(self, payload):
            self.submitted.append(payload["rel"])
            return len(self.submitted) - 1

        def wait(self, handles, timeout=None):
            return list(handles)

        def result(self, h):
            if self.submitted[h].endswith("/a"):
                raise backends.WorkerLost("a pool worker died")
            raise ValueError("bad")

    be = Lossy()
    failed = backends.run_grid(nodes, tmp_path, be, progress=False, retries=2, poll_s=0)
    assert sorted(failed) == ["runs/single/a", "runs/single/b"]
    assert be.submitted.count("runs/single/a") == 3 and be.submitted.count("runs/single/b") == 1
    out = capsys.readouterr().out
    assert "retry 1/2" in out and "retry 2/2" in out and "worker lost (3 times)" in out
    assert f"ValueError: bad; traceback: {tmp_path / 'runs/single/b/error.txt'}" in out


def test_ray_cluster_node_removed_midrun_sweep_finishes_same_tables(reference, tmp_path, monkeypatch):
    """Two Ray nodes on this machine (the head schedules nothing); the node running stage >= 1 is removed
    while that stage waits after a checkpoint, and a fresh one joins: Ray reruns the task, which resumes from
    the checkpoint."""
    pytest.importorskip("ray")
    from ray.cluster_utils import Cluster
    hold = tmp_path / "hold"
    hold.touch()
    for k, v in _env(hold).items():        # Ray's workers inherit their node's environment, not the sweep's
        if k.startswith("MANISKILL_DUALHER_"):
            monkeypatch.setenv(k, v)
    cluster = Cluster(initialize_head=True, connect=False,
                      head_node_args={"num_cpus": 0, "object_store_memory": 80 * 2**20, "include_dashboard": False})
    p = None
    try:
        node = cluster.add_node(num_cpus=1, object_store_memory=80 * 2**20)
        out = tmp_path / "ray"
        log = tmp_path / "sweep.log"
        t0 = time.perf_counter()
        p = _popen_sweep(log, *CHAIN, "--out", str(out), "--backend", "ray", "--ray-address", cluster.address)
        # 300 s was once too short beside a long sweep at nice -5 (Ray's workers start slowly on busy cores)
        deadline, victim = time.time() + 600, None
        while time.time() < deadline and p.poll() is None and victim is None:
            victim = _stage_in_flight(out)
            time.sleep(0.01)
        assert victim is not None, "no stage was in flight: " + log.read_text()[-2000:]
        pid = backends.read_progress(victim)["pid"]
        cluster.remove_node(node, allow_graceful=False)
        # a lost machine takes its processes at once; Ray's own workers die a moment after their raylet, and a
        # stage released before then once finished in the dying worker (Ray's rerun found it done: CI stop 55)
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        gone_by = time.time() + 60
        while alive(pid) and time.time() < gone_by:
            time.sleep(0.05)
        assert not alive(pid), f"the removed node's worker {pid} still runs"
        hold.unlink()
        cluster.add_node(num_cpus=1, object_store_memory=80 * 2**20)
        p.wait(timeout=300)
        print(f"ray cluster sweep with a node lost: {time.perf_counter() - t0:.1f} s")
        text = log.read_text()
        assert p.returncode == 0, text[-3000:]
        assert _starts(victim) == 2 and "running again, now pid" in text   # Ray retried it, silently but for this
        assert _tables(out) == _tables(reference)
    finally:
        if p is not None:
            kill_group(p)
        cluster.shutdown()


# ----------------------------------------------------------------------------- one sweep per folder
def test_busy_folder_refused_then_free_after_sigkill(reference, tmp_path):
    out = tmp_path / "busy"
    log = tmp_path / "first.log"
    hold = tmp_path / "hold"
    hold.touch()                                        # the first sweep waits in stage 1 until it is killed
    first = _popen_sweep(log, *CHAIN, "--out", str(out), "--workers", "1", hold=hold)
    try:
        deadline = time.time() + 120
        while time.time() < deadline and first.poll() is None and _stage_in_flight(out) is None:
            time.sleep(0.05)
        assert (out / LOCK_FILE).is_file() and (out / LOCK_FILE).read_text().strip()
        assert first.poll() is None, log.read_text()[-2000:]
        second = _sweep_cli(*CHAIN, "--out", str(out))
        assert second.returncode == 2
        err = second.stderr.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: ") and "in use by another sweep" in err[0], err
        assert f"pid {first.pid} on host" in err[0]
        assert _sweep_cli(*CHAIN, "--out", str(out), "--dry-run").returncode == 0  # the dry run takes no lock
        kill_group(first)
    finally:
        kill_group(first)
    third = _sweep_cli(*CHAIN, "--out", str(out))           # the OS dropped the killed sweep's lock
    assert third.returncode == 0, third.stderr[-2000:]
    assert _tables(out) == _tables(reference)


def test_lock_in_process(tmp_path, capsys):
    out = tmp_path / "o"
    with FolderLock(out):
        with pytest.raises(sweep.ConfigError, match="in use by another sweep"):
            FolderLock(out).acquire()
        assert run_sweep([*CHAIN, "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"pid {os.getpid()}" in err[0]
    FolderLock(out).acquire().release()                     # free again, and released by main on error
    assert not (out / rundir.SWEEP).exists()


# ----------------------------------------------------------------------------- progress of runs in flight
def test_progress_file_moves_the_bar_before_the_run_finishes(tmp_path, monkeypatch):
    seen = []

    class Recording:  # the tqdm run_grid makes, recording its position after every update
        def __init__(self, total, initial=0, **kw):
            self.n, self.total = initial, total

        def update(self, k):
            self.n += k
            seen.append(self.n)

        def write(self, *a, **k):
            pass

        def set_postfix(self, **k):
            pass

        def close(self):
            pass

    import tqdm
    monkeypatch.setattr(tqdm, "tqdm", Recording)
    cfg = RunConfig(total_steps=1000)
    node = Node("runs/single/x", cfg, "x")
    writer = backends.ProgressFile(every_s=0)

    class Slow:  # one run that writes its progress file as a worker would, finishing on the 4th wait
        capacity = 1

        def __init__(self):
            self.waits = 0

        def submit(self, payload):
            return 0

        def wait(self, handles, timeout=None):
            assert timeout is not None       # run_grid waits with a timeout so that it can poll
            self.waits += 1
            if self.waits < 4:
                writer(tmp_path / node.rel, 250 * self.waits, cfg.total_steps)
                return []
            return list(handles)

        def result(self, h):
            return {"rel": node.rel, "row": {}}

    assert backends.run_grid([node], tmp_path, Slow(), poll_s=0.01) == []
    assert seen == [250, 500, 750, 1000]


def test_progress_poller_never_goes_back_and_inline_moves_midrun(reference, tmp_path, monkeypatch):
    import io
    import tqdm
    bar = tqdm.tqdm(total=300, file=io.StringIO())
    cfg = RunConfig(total_steps=300)
    n = Node("runs/single/y", cfg, "y")
    tr = backends.RunProgress(bar, tmp_path)
    tr.start(n)
    tr.poll()
    assert bar.n == 0                                        # no file yet
    w = backends.ProgressFile(every_s=0)
    for steps, want in [(120, 120), (60, 120), (900, 300)]:  # a retry from an older checkpoint; clipped
        w(tmp_path / n.rel, steps, 300)
        tr.poll()
        assert bar.n == want
    tr.finish(n, ok=True)
    assert bar.n == 300
    # a real run, inline: the bar moves while the run trains (the worker's writes call the poller)
    grid_nodes = sweep.build_grid(sweep.definition_from_args(sweep.make_parser().parse_args(CHAIN)))
    stage0 = next(x for x in grid_nodes if x.stage == 0)
    out = tmp_path / "inline"
    positions = []
    be = backends.InlineBackend(entry_train_runs)
    real_poll = backends.RunProgress.poll

    def poll(self):
        real_poll(self)
        positions.append(sum(self.credited.values()))  # what the bar shows (disabled here: progress=False)

    monkeypatch.setattr(backends.RunProgress, "poll", poll)
    assert backends.run_grid([stage0], out, be, progress=False) == []
    assert any(0 < x < stage0.cfg.total_steps for x in positions), positions
    def rows(d):
        return [{k: v for k, v in r.items() if k != "wall_time_s"} for r in rundir.read_metrics(d)]
    assert rows(out / stage0.rel) == rows(reference / stage0.rel)


# ----------------------------------------------------------------------------- SLURM: the grid as commands
def test_emit_commands_in_dependency_order_and_they_reproduce_the_sweep(reference, tmp_path, capsys):
    out = tmp_path / "slurm"
    cmds = tmp_path / "jobs" / "commands.txt"
    assert run_sweep([*CHAIN, "--out", str(out), "--emit-commands", str(cmds)]) == 0
    printed = capsys.readouterr().out
    assert "level 2: lines 3-3" in printed
    lines = cmds.read_text().splitlines()
    assert len(lines) == 3
    outs = []
    for line in lines:
        argv = shlex.split(line)
        assert argv[:3] == ["python", "-m", "maniskill_dualher.train"]
        opt = dict(zip(argv[3::1], argv[4::1]))
        outs.append(opt["--out"])
        if "--init-from" in argv:                            # a stage after its parent
            assert opt["--init-from"] in outs[:-1] and "--carry-replay" in argv
        cfg = json.loads(Path(opt["--config"]).read_text())
        rel = str(Path(opt["--out"]).relative_to(out.resolve()))
        assert RunConfig.from_dict(cfg).to_dict() == RunConfig.from_dict(
            json.loads((reference / rel / "config.json").read_text())).to_dict()
        assert (out / rel / rundir.CELL).read_text() == (reference / rel / rundir.CELL).read_text()
    assert ["--keep-replay" in line for line in lines] == [True, True, False]
    # the job array, one line at a time (here in order): finished folders, and the sweep only reports
    t0 = time.perf_counter()
    for i, line in enumerate(lines):
        r = subprocess.run(["bash", "-c", line], cwd=tmp_path, env=_env(), capture_output=True, text=True,
                           timeout=300)
        assert r.returncode == 0, r.stderr[-2000:]
        assert rundir.is_done(outs[i])
        if i == 0:
            print(f"first emitted command: {time.perf_counter() - t0:.1f} s")
    assert run_sweep([*CHAIN, "--out", str(out)]) == 0
    assert "3 of 3 runs already finished" in capsys.readouterr().out
    assert _tables(out) == _tables(reference)


def test_local_backend_start_brings_up_every_worker_warm():
    """start() spawns every worker at once, each importing the training code (train_runs([])) before any run
    is submitted: the sweep's estimate is timed while they start (docs/speed.md)."""
    be = backends.LocalBackend(2, entry_train_runs)
    try:
        be.start()
        assert [f.result(timeout=300) for f in be._warm] == [[], []]
        assert len(be.pool._processes) == 2
    finally:
        be.close()


def test_freeze_imports_freezes_the_heap_once_per_process():
    """train_runs freezes the imported modules out of the collector's reach once, before its first run: a
    full collection then skips them (ManiSkill collects when it builds and closes an env); a second call
    freezes nothing more (objects made by runs stay collectable)."""
    code = ("import gc\n"
            "from maniskill_dualher.train import train_runs\n"
            "assert gc.get_freeze_count() == 0\n"
            "train_runs([])\n"
            "n = gc.get_freeze_count()\n"
            "import sys; assert n > 100_000 and 'mani_skill' in sys.modules and 'torch._dynamo' in sys.modules, n\n"
            "junk = [[i] for i in range(1000)]\n"
            "train_runs([])\n"
            "assert gc.get_freeze_count() == n\n"
            "print('ok', n)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.startswith("ok"), r.stderr[-2000:]


def test_hold_point_waits_while_its_file_exists_and_only_where_its_pattern_matches(tmp_path, monkeypatch):
    import threading
    hold = tmp_path / "hold"
    hold.touch()
    monkeypatch.setenv(faults.HOLD_AT, "checkpoint:*/stage[1-9]*")
    monkeypatch.setenv(faults.HOLD_WHILE, str(hold))
    t0 = time.perf_counter()
    faults.hold_point("checkpoint:out/runs/chain/x/stage0-ReachTarget-v1")      # no match: goes on at once
    assert time.perf_counter() - t0 < 0.5
    threading.Timer(0.3, hold.unlink).start()
    t0 = time.perf_counter()
    faults.hold_point("checkpoint:out/runs/chain/x/stage1-CloseBox-v1")
    assert 0.25 < time.perf_counter() - t0 < 5
    monkeypatch.delenv(faults.HOLD_AT)
    hold.touch()
    t0 = time.perf_counter()
    faults.hold_point("checkpoint:out/runs/chain/x/stage1-CloseBox-v1")         # no pattern: never holds
    assert time.perf_counter() - t0 < 0.5
