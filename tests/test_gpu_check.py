"""bench/gpu_check.py without a GPU: the no-GPU exit, the harness (each section in its own process, one
outcome line each, the next one runs, exit code), and the section checks themselves run for real on CPU
simulation (one env) through the same functions the GPU check calls, passing, and failing when fed a
wrong reward function, a moving panel, an out-of-range reset or a PhysX overflow line."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from bench_cli import load_bench

REPO = Path(__file__).resolve().parents[1]
SCRIPT = REPO / "bench" / "gpu_check.py"


def _load():
    return load_bench("gpu_check.py")


gc = _load()
CPU = gc.Sim("physx_cpu", "cpu")


def _run(args, fake=None, timeout=120):
    env = {k: v for k, v in os.environ.items() if k != gc.FAKE_VAR}
    if fake is not None:
        env[gc.FAKE_VAR] = fake
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True, env=env,
                          timeout=timeout, cwd=REPO)


# --------------------------------------------------------------------------- the script
@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA GPU")
def test_without_gpu_exits_2_with_one_stderr_line():
    r = _run([])
    assert r.returncode == 2
    lines = r.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: no CUDA GPU: "), r.stderr
    assert r.stdout == ""


def test_harness_reports_every_section_and_goes_on():
    """A section that raises, one that hangs past the time limit, one that dies, one that passes, one that
    skips itself, and a GPU-simulation section without the GPU physics library: one line each, in order."""
    names = ["_stub_raise", "_stub_hang", "_stub_crash", "_stub_pass", "_stub_skip", "_stub_fail", "_stub_gpu"]
    # the hang sleeps an hour: a harness that waited for it would overrun _run's timeout (no wall-time bound
    # here: seven sections each import torch, ~90 s on two loaded cores)
    r = _run(["--sections", ",".join(names), "--timeout", "3"], fake="nolib", timeout=600)
    assert r.returncode == 1, r.stdout + r.stderr
    out = r.stdout.splitlines()
    status = [ln for ln in out if ln.split(":")[0] in names]
    assert [ln.split(":")[0] for ln in status] == names
    got = dict(ln.split(": ", 1) for ln in status)
    assert got["_stub_raise"].startswith("FAIL: RuntimeError: stub error")
    assert got["_stub_hang"].startswith("FAIL: timed out after 3 s")
    assert got["_stub_crash"].startswith("FAIL: its process died (exit code 70)")
    assert got["_stub_pass"].startswith("PASS")
    assert got["_stub_skip"].startswith("SKIPPED: stub skipped itself")
    assert got["_stub_fail"].startswith("FAIL: stub check missed its target")
    assert got["_stub_gpu"].startswith("SKIPPED: SAPIEN's GPU physics library") and "libPhysXGpu_64.so" in got["_stub_gpu"]
    # the preflight says where the library goes and where it comes from
    assert any(ln.startswith("  to supply it:") and "physx-precompiled/releases/download/" in ln for ln in out)
    assert out[-1].startswith("gpu_check: 1 PASS, 4 FAIL")


def test_harness_exit_0_without_failures():
    r = _run(["--sections", "_stub_pass,_stub_skip,_stub_gpu"], fake="1")
    assert r.returncode == 0, r.stdout + r.stderr
    assert "_stub_gpu: PASS" in r.stdout  # fake=1: CPU simulation needs no GPU physics library


def test_bad_section_name_is_one_error():
    r = _run(["--sections", "nope"], fake="1")
    assert r.returncode == 2 and "unknown section 'nope'" in r.stderr


# --------------------------------------------------------------------------- the checks, for real on CPU
def test_success_check_passes_and_fails_with_a_wrong_reward():
    res = gc.check_success_agrees(CPU, "ReachTarget-v1", 1, steps=40, log=lambda s: None)
    assert res["mismatches"] == 0 and 0 < res["successes"] < res["env_steps"]

    def twice_the_tolerance(ag, dg, info=None):
        return (np.linalg.norm(ag - dg, axis=-1) < 0.1).astype(np.float32)

    with pytest.raises(gc.CheckFailed, match="disagrees with info\\['success'\\]"):
        gc.check_success_agrees(CPU, "ReachTarget-v1", 1, steps=40, reward_fn=twice_the_tolerance, log=lambda s: None)


def test_success_check_fails_when_nothing_succeeds():
    with pytest.raises(gc.CheckFailed, match="one side of the comparison went unchecked"):
        gc.check_success_agrees(CPU, "CloseBox-v1", 1, steps=5, solver_share=0.0, log=lambda s: None)


def test_idle_drift_passes_and_catches_a_moving_lid():
    res = gc.check_idle_drift(CPU, "CloseBox-v1", 1, log=lambda s: None)
    assert res["max_drift"] < 1e-3

    def nudge(env, k):
        if k == 50:
            art = env.unwrapped.articulation
            art.set_qpos(art.qpos + 0.002)

    with pytest.raises(gc.CheckFailed, match="moved by itself"):
        gc.check_idle_drift(CPU, "CloseBox-v1", 1, on_step=nudge, log=lambda s: None)
    with pytest.raises(gc.Skipped):
        gc.check_idle_drift(CPU, "ReachTarget-v1", 1, steps=1, log=lambda s: None)


def test_partial_reset_path_and_range_checks():
    gc.check_partial_reset(CPU, "CloseMicrowave-v1", 1, log=lambda s: None)
    env = CPU.make("CloseBox-v1", 1)
    try:
        base = env.unwrapped
        env.reset(3)
        rows = env._flat(base.get_obs(base.get_info()))
        assert gc.initial_state_problems(base, [0], rows) == []
        base.articulation.set_qpos(torch.tensor([[1.5]]))  # outside INIT_ANGLE_RANGE (0.5, 1.3)
        rows = env._flat(base.get_obs(base.get_info()))
        probs = gc.initial_state_problems(base, [0], rows)
        assert any("hinge angle" in p for p in probs), probs
    finally:
        env.close()


def test_overflow_capture_sees_c_level_and_child_stderr():
    with gc.capture_fds((2,)) as cap:
        os.write(2, b"PxgNphaseImplementationContext: Contact buffer overflow detected\n")
        subprocess.run([sys.executable, "-c", "import sys; sys.stderr.write('needs to increase foundLostPairsCapacity\\n')"])
        os.write(2, b"an ordinary warning\n")
    assert len(gc.overflow_lines(cap[2])) == 2


def test_contact_overflow_section_passes_and_fails():
    gc.check_contact_overflow(CPU, ["ReachTarget-v1"], 1, steps=10, log=lambda s: None)

    def physx_complains(env, k):
        if k == 3:
            os.write(2, b"Patch buffer overflow detected, please increase its size in the scene desc!\n")

    with pytest.raises(gc.CheckFailed, match="full GPU buffer"):
        gc.check_contact_overflow(CPU, ["ReachTarget-v1"], 1, steps=10, on_step=physx_complains, log=lambda s: None)


def test_env_speed_measures():
    res = gc.measure_env_speed(CPU, "ReachTarget-v1", 1, steps=10, log=lambda s: None)
    assert res["device_steps_per_s"] > 0 and res["loop_steps_per_s"] > 0


@pytest.mark.slow
def test_train_split_on_cpu(tmp_path):
    res = gc.measure_train_split(CPU, "ReachTarget-v1", 1, 300, str(tmp_path / "run"), log=lambda s: None)
    assert res["env_steps"] == 300 and res["updates"] > 0
    assert {"env step", "SAC update", "replay sample", "other"} <= set(res["split"])


@pytest.mark.slow
def test_real_sections_through_the_harness_on_cpu():
    r = _run(["--sections", "success,idle_drift,partial_reset", "--tasks", "ReachTarget-v1,CloseBox-v1",
              "--steps", "40"], fake="1", timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    for name in ("startup", "success", "idle_drift", "partial_reset"):
        assert f"\n{name}: PASS" in r.stdout


# --------------------------------------------------------------------------- the config field
def test_gpu_memory_scale_config_and_env_kwargs(monkeypatch):
    from mani_skill.utils.structs.types import GPUMemoryConfig
    from maniskill_dualher import envs
    from maniskill_dualher.config import ConfigError, RunConfig, run_identity
    assert envs.gpu_memory_config(1.0) == GPUMemoryConfig().dict()
    assert envs.gpu_memory_config(2.0)["max_rigid_contact_count"] == 2 * GPUMemoryConfig().max_rigid_contact_count
    assert envs.gpu_memory_config(1.5)["heap_capacity"] == 2 * GPUMemoryConfig().heap_capacity  # powers of two
    for bad in (0, -1.0, float("nan"), float("inf"), True, "2"):
        with pytest.raises(ConfigError, match="gpu_memory_scale"):
            RunConfig(gpu_memory_scale=bad).validate()
    assert run_identity(RunConfig(gpu_memory_scale=4.0).to_dict()) == run_identity(RunConfig().to_dict())

    seen = []
    monkeypatch.setattr(envs.gym, "make", lambda env_id, **kw: seen.append(kw))
    envs.BatchEnv._make_maniskill(RunConfig(sim_backend="physx_cuda", num_envs=4, gpu_memory_scale=2.0))
    envs.BatchEnv._make_maniskill(RunConfig(sim_backend="physx_cpu", gpu_memory_scale=2.0))
    envs.BatchEnv._make_maniskill(RunConfig(sim_backend="physx_cuda", num_envs=4))
    assert seen[0]["sim_config"] == {"gpu_memory_config": envs.gpu_memory_config(2.0)}
    assert "sim_config" not in seen[1] and "sim_config" not in seen[2]
