"""bench/live_profile.py: py-spy's raw stacks charged to the step budget's parts, the first part a frame of a sample
belongs to, and scaled by the run's own clock."""
import gzip
import json

from bench_cli import run_bench


def test_live_profile_charges_each_sample_to_its_first_part_and_scales_by_the_runs_clock(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"method": "dual_buffer", "env_id": "CloseMicrowave-v1", "seed": 6}))
    cpu = {"model": "AMD EPYC", "avx2": True, "avx512_bf16": False, "amx_bf16": False, "family_model": "25/1"}
    (run / "provenance.json").write_text(json.dumps({"starts": [{"commit_short": "abc1234", "cpu": cpu}]}))
    # six rows, 30,000 env steps apart; the last five intervals: 150,000 env steps in 600 s = 4 ms each
    (run / "metrics.csv").write_text("env_steps,wall_time_s\n" + "".join(f"{30000 * i},{100 + 120 * i}\n"
                                                                      for i in range(6)))
    loop = "drive (maniskill_dualher/train.py:144)"
    stacks = [
        (f"{loop};SAC.update (maniskill_dualher/sac.py:284);_wrap_func.<locals>.g (x.py:1)", 50),
        (f"{loop};SAC.update (maniskill_dualher/sac.py:284);FusedUpdate._apply (maniskill_dualher/sac_fused.py:1)", 10),
        # an update inside an evaluation would be charged to the evaluation: the first part in PARTS wins
        (f"{loop};evaluate_runs (maniskill_dualher/train.py:166);SAC.update (maniskill_dualher/sac.py:284)", 5),
        (f"{loop};BatchEnv.step (maniskill_dualher/envs.py:217);LeanStep.step (tasks/lean.py:247)", 25),
        (loop, 10),
    ]
    prof = tmp_path / "p.txt.gz"
    with gzip.open(prof, "wt") as f:
        f.writelines(f"{s} {n}\n" for s, n in stacks)
    out = tmp_path / "o.json"
    r = run_bench("live_profile.py", f"{prof}={run}", "--out", str(out))
    assert r.returncode == 0, r.stderr
    entry = json.loads(out.read_text())["profiles"][0]
    assert entry["samples"] == 100 and abs(entry["ms_per_env_step"] - 4.0) < 1e-9 and entry["run_machine"] == "CPU C"
    shares = entry["shares"]
    assert shares["update: compiled graph"] == 0.5 and shares["evaluation"] == 0.05
    assert shares["env step (PhysX and its Python)"] == 0.25 and shares["training loop and the rest"] == 0.1
    assert [k for k in shares if k.startswith("update: the rest")] and abs(sum(shares.values()) - 1) < 1e-12
    assert abs(entry["ms_per_env_step_by_part"]["update: compiled graph"] - 2.0) < 1e-9
    bad = run_bench("live_profile.py", f"{prof}")
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1
