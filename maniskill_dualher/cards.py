"""Model cards of the committed policies: ``results/policies/<task>/<folder>/README.md``, written from the folder's
``policy.json`` alone, so a card says what its ``policy.json`` says (``tests/test_cards.py`` holds each card to it).

A folder is named ``<method>`` (one single-task run, its ``policy_best.pt``) or ``<method>_after_transfer``
(``folder_name``: the adaptation stage of a transfer chain, its final ``policy.pt``; ``policy.json`` then holds a
``transfer`` entry: the chain, each stage's env steps, the preset, the sweep command, the stage's run folder).

``policy.json`` holds how the policy was made and scored (command, commit, machine, versions, the held-out
evaluation); ``sync_policy_json`` adds what the policy file itself carries: its interface (observation layout,
action size, controller, episode rules) and the run's training settings (the ``RunConfig`` it was trained with).

    python -m maniskill_dualher.cards [results/policies]            # write policy.json's two entries and the cards
    python -m maniskill_dualher.cards [results/policies] --check    # say what it checked; exit 1 if one is stale
    python -m maniskill_dualher.cards export RUN [--policy best|final] [--root DIR] [--episodes 100] [--force]

Every card opens with YAML front matter a model hub indexes (``front_matter``: library, licence, tags, the env id,
the held-out success rate with its Wilson interval and episodes in a ``model-index``).

``export`` makes such a folder from a finished run folder (``export_run``): its ``policy_best.pt`` (a single-task
run's default) or ``policy.pt`` (a transfer chain's adaptation stage's default: its final state, the rule the
shipped chain policies follow), a ``policy.json`` read from the run's own files (``config.json``,
``provenance.json``, ``metrics.csv``, ``stage.json``, ``cell.json``, the sweep's ``sweep.json``), the held-out
evaluation run there, and the card. It writes into ``policies/`` beside the run unless ``--root`` names another
folder; into the committed ``results/policies`` only when named, and only a policy whose held-out success reaches
the task's committed policy's of its kind (``committed_bar``) unless ``--force``. It refuses to replace a folder
that exists, and writes the new one staged and renamed, so a kill leaves no half folder.
"""
from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

from .fileio import atomic_write_text, plural

POLICIES = Path(__file__).resolve().parents[1] / "results" / "policies"
INTERFACE, SETTINGS = "interface", "training_settings"
ACTIONS = {   # the Panda's controllers (ManiSkill's panda.py), each dimension normalized to [-1, 1]
    "pd_joint_delta_pos": "7 arm joint-position deltas (up to ±0.1 rad per step) and 1 gripper finger target",
    "pd_ee_delta_pos": "3 end-effector position deltas (up to ±0.1 m per step) and 1 gripper finger target",
}
CITATION = """@article{beyene2022prioritized,
  title   = {Prioritized Hindsight with Dual Buffer for Meta-Reinforcement Learning},
  author  = {Beyene, Sofanit Wubeshet and Han, Ji-Hyeong},
  journal = {Electronics}, volume = {11}, number = {24}, pages = {4192}, year = {2022}
}"""


TRANSFER, AFTER_TRANSFER = "transfer", "_after_transfer"


def folder_name(doc: dict) -> str:
    """The folder a policy.json belongs in under ``results/policies/<task>/``: its method, plus ``_after_transfer``
    for a chain's adapted policy."""
    return doc["method"] + (AFTER_TRANSFER if TRANSFER in doc else "")


def interface_of(policy) -> Dict[str, object]:
    """What a policy file says about how to call it (``policy.Policy``'s fields)."""
    from .tasks.common import OBS_SLOTS
    return {"env_id": policy.env_id, "control_mode": policy.control_mode, "observation_width":
            policy.obs_dim + 2 * policy.goal_dim, "observation_slots": dict(OBS_SLOTS)
            if sum(w for _, w in OBS_SLOTS) == policy.obs_dim else None, "goal_dim": policy.goal_dim,
            "policy_input_width": policy.input_dim, "action_dim": policy.act_dim, "hidden": list(policy.hidden),
            "max_episode_steps": policy.max_episode_steps, "terminate_on_success": policy.terminate_on_success}


def sync_policy_json(folder: Path, write: bool = True) -> bool:
    """Add (or refresh) policy.json's interface and training settings from the folder's policy.pt; True if
    policy.json was (or, with ``write=False``, would be) changed."""
    from .policy import load_policy
    path = Path(folder) / "policy.json"
    doc = json.loads(path.read_text())
    pol = load_policy(folder)
    new = json.loads(json.dumps(dict(doc, **{INTERFACE: interface_of(pol), SETTINGS: pol.config})))  # as read back
    if new == doc:
        return False
    if write:
        atomic_write_text(path, json.dumps(new, indent=2) + "\n")
    return True


def success_text(task: str) -> str:
    """What success means on ``task``, in words, as its file declares it (``PandaGoalEnv.success_text``); '' for
    an env this project does not register."""
    import maniskill_dualher.tasks  # noqa: F401  (registers our tasks)
    from mani_skill.utils.registration import REGISTERED_ENVS
    spec = REGISTERED_ENVS.get(task)
    return getattr(spec.cls, "success_text", "") if spec is not None else ""


def _method_display(method: str) -> str:
    from .methods import METHOD_SPECS
    spec = METHOD_SPECS.get(method)
    return spec.display if spec else method


def score_line(doc: dict) -> str:
    """The held-out score as the card gives it (tests read it back)."""
    h = doc["held_out_evaluation"]
    lo, hi = h["success_ci95_wilson"]
    return (f"{h['successes']}/{h['episodes']} episodes successful ({h['success_rate']:.2f}), 95% Wilson interval "
            f"[{lo:.3f}, {hi:.3f}], on reset seeds {h['seeds']}")


def _env_steps(cfg: dict, transfer: Optional[dict]) -> str:
    if not transfer:
        return str(cfg.get("total_steps"))
    before = ", then ".join(f"{t} {n}" for t, n in zip(transfer["chain"][:-1], transfer["stage_env_steps"][:-1]))
    carried = "networks and replay" if transfer.get("carry_replay") else "networks"
    return (f"{cfg.get('total_steps')} in this adaptation stage, after the source stages {before} "
            f"(each stage starts from the one before: its {carried})")


def _settings_rows(cfg: dict, transfer: Optional[dict] = None) -> List[str]:
    sac, rep = cfg.get("sac", {}), cfg.get("replay", {})
    learned = (sac.get("variant") == "modern") if sac.get("learn_alpha") is None else bool(sac["learn_alpha"])
    alpha = f"learned from {sac.get('alpha')}" if learned else f"fixed {sac.get('alpha')}"
    rows = [("method", f"{_method_display(cfg['method'])} (`{cfg['method']}`)"), ("seed", cfg.get("seed")),
            ("env steps", _env_steps(cfg, transfer)), ("episode", f"at most {cfg.get('max_episode_steps')} steps, "
             + ("ends on success" if cfg.get("terminate_on_success") else "fixed length")),
            ("simulation", f"{cfg.get('sim_backend')}, {cfg.get('num_envs')} env, {cfg.get('reward_mode')} reward"),
            ("SAC", f"{sac.get('variant')}, hidden {'x'.join(map(str, sac.get('hidden', [])))}, lr {sac.get('lr')}, "
                    f"gamma {sac.get('gamma')}, tau {sac.get('tau')}, batch {sac.get('batch_size')}, alpha {alpha}"),
            ("updates", f"{sac.get('updates_per_step')} per env step after {sac.get('learning_starts')} steps, "
                        f"the first {sac.get('random_steps')} actions uniformly random"
             if sac.get("update_schedule") == "step" else f"{sac.get('updates_per_episode')} per finished episode"),
            ("replay", f"capacity {rep.get('capacity')}, HER '{rep.get('her_strategy')}' k = {rep.get('her_k')}"
                       + (f", PER exponent {rep.get('priority_exponent')}" if cfg["method"] != "sac" else "")
                       + (f", R/E ratio {'/'.join(map(str, rep.get('ratio', [])))} ({rep.get('dual_mode')})"
                          if cfg["method"] == "dual_buffer" else "")),
            ("evaluation during training", f"{plural(int(cfg.get('eval_episodes') or 0), 'episode')} every {cfg.get('eval_every')} "
                                           "env steps")]
    if cfg["method"] == "sac":
        rows[-2] = ("replay", f"uniform, capacity {rep.get('capacity')}, no HER, no PER")
    return [f"| {k} | {v} |" for k, v in rows]


def _transfer_policy(t: dict, doc: dict) -> str:
    b = t["best_train_eval"]
    prior = ", the prior it started from" if b["env_steps"] == 0 else ""
    return (f"the **final** policy of the transfer chain's adaptation stage (its state at the end of adaptation, "
            f"env step {doc['policy_env_steps']}: what the transfer claims measure), not the stage's "
            f"`policy_best.pt` (its best training evaluation: {b['success']} at env step {b['env_steps']}{prior})")


def _transfer_seeds(t: dict, cfg: dict) -> List[str]:
    return [f"**Seeds: this folder is one run (seed {cfg.get('seed')}) of the {t['preset']} preset's chain.** Seed 0 is the rule, fixed before any result was seen, and shipped whatever it scored (no "
            "seed was picked for its score). It shows what one run reached, not the spread over seeds; the "
            "transfer results over many seeds are in `results/reference/table5_multitask.csv` "
            f"(experiment `{t['experiment']}`).", "",
            f"The reference's sweep has the same run folder (`{t['run']}`), trained there on "
            f"{t['reference_machine']}; runs are not bit-identical across CPUs, so its scores in "
            "`results/reference/scores.csv` may differ from this run's."]


def front_matter(doc: dict) -> dict:
    """The card's YAML front matter, as a model hub indexes it (Hugging Face's model card metadata): library,
    licence, tags, the env id (the task), and a ``model-index`` whose metric is the held-out success rate with
    its 95% Wilson interval, episodes, successes and reset seeds (``args``)."""
    task, method, h, t = doc["task"], doc["method"], doc["held_out_evaluation"], doc.get(TRANSFER)
    itf = doc.get(INTERFACE, {})
    tags = ["reinforcement-learning", "deep-reinforcement-learning", "robotics", "maniskill3", "pytorch",
            "soft-actor-critic", task, method]
    if method != "sac":
        tags[-1:-1] = ["hindsight-experience-replay", "prioritized-experience-replay"]
    if t:
        tags.append("transfer-learning")
    name = f"{method} on {task}" + (f" after {' -> '.join(t['chain'][:-1])}" if t else "")
    return {
        "library_name": "maniskill_dualher",
        "license": "mit",
        "pipeline_tag": "reinforcement-learning",
        "tags": tags,
        "env_id": task,
        "task": task,
        "model-index": [{"name": name, "results": [{
            "task": {"type": "reinforcement-learning", "name": "reinforcement-learning"},
            "dataset": {"type": task, "name": f"{task} (ManiSkill3, {itf.get('control_mode', 'state')})",
                        "split": f"held-out reset seeds {h['seeds']}"},
            "metrics": [{
                "type": "success_rate", "name": "held-out success rate", "value": float(h["success_rate"]),
                "args": {"episodes": int(h["episodes"]), "successes": int(h["successes"]),
                         "ci95_wilson": [round(float(x), 4) for x in h["success_ci95_wilson"]],
                         "reset_seeds": h["seeds"], "deterministic": True}}]}]}],
    }


def front_matter_text(doc: dict) -> str:
    import yaml
    return "---\n" + yaml.safe_dump(front_matter(doc), sort_keys=False, default_flow_style=False, width=1000) \
        + "---\n"


def card_text(doc: dict) -> str:
    """A model card from a policy.json (after ``sync_policy_json``): YAML front matter, then the card."""
    task, method = doc["task"], doc["method"]
    itf, cfg, h = doc[INTERFACE], doc[SETTINGS], doc["held_out_evaluation"]
    slots = itf.get("observation_slots")
    width = itf["observation_width"] - 2 * itf["goal_dim"]
    layout = " | ".join(f"{n} ({w})" for n, w in slots.items()) if slots else f"observation ({width})"
    g = itf["goal_dim"]
    t = doc.get(TRANSFER)
    before = " -> ".join(t["chain"][:-1]) if t else ""
    n_eval = cfg.get("eval_episodes", 10)
    lines = [
        front_matter_text(doc),
        f"# Model card: {_method_display(method)} on {task}" + (f", adapted after {before}" if t else ""),
        "",
        "Generated from this folder's `policy.json` by `python -m maniskill_dualher.cards` (do not edit by hand).",
        "",
        "## What it is",
        "",
        f"* **Task**: `{task}` (ManiSkill3, Franka Panda; this repository's `tasks/`): success is "
        f"{success_text(task) or 'as the task defines it'}.",
        f"* **Policy**: `policy.pt`, a tanh-Gaussian actor ({' x '.join(map(str, itf['hidden']))} hidden units), "
        + (_transfer_policy(t, doc) if t else "its run's best training evaluation")
        + "; acting is deterministic (the Gaussian's mean).",
        f"* **Observation**: `obs_mode=\"state\"`, a flat vector of {itf['observation_width']}: [{layout} | "
        f"achieved goal ({g}) | desired goal ({g})]. The policy reads observation ‖ desired goal "
        f"({itf['policy_input_width']}); `Policy.act` takes either. Slots a task has no object for are zeros.",
        f"* **Action**: {itf['action_dim']} numbers in [-1, 1], controller `{itf['control_mode']}`: "
        f"{ACTIONS.get(itf['control_mode'], 'see ManiSkill')}.",
        f"* **Episodes**: at most {itf['max_episode_steps']} steps"
        + (", ending on success." if itf["terminate_on_success"] else ", fixed length."),
        "",
        "## Score",
        "",
        f"Held out: {score_line(doc)} (seeds no training evaluation used), mean episode length "
        f"{h['mean_episode_length']} steps; `{h['command']}` reproduces it. "
        + (f"Its last training evaluation, at env step {doc['policy_env_steps']}: {doc['policy_train_eval_success']} "
           f"success on {plural(n_eval, 'episode')} (no evaluation chose this policy)." if t else
           f"Its training evaluation at env step {doc['policy_env_steps']}: {doc['policy_train_eval_success']} "
           f"success on {plural(n_eval, 'episode')} (the ones that chose it, so optimistic)."),
        "",
        *([doc["seed_note"]] if doc.get("seed_note") else _transfer_seeds(t, cfg) if t else [
            f"**Seeds: this folder is one training run (seed {cfg.get('seed')}).** It shows what one run reached, "
            "not the spread over seeds; the single-task results over many seeds are in "
            "`results/reference/single_task.csv` (reference preset)."]),
        "",
        "## Training settings",
        "",
        "| setting | value |",
        "|---|---|",
        *_settings_rows(cfg, t),
        "",
        f"All of them: `policy.json` → `{SETTINGS}` (the "
        + ("adaptation stage's" if t else "run's") + " `RunConfig`).",
        "",
        "## How it was made",
        "",
        *([f"The transfer chain {' -> '.join(t['chain'])} of the {t['preset']} preset's `{t['experiment']}` "
           f"experiment, one run (seed {cfg.get('seed')}); this folder's `policy.pt` is the adaptation stage's "
           f"final `policy.pt` (run folder `{t['run']}` of the sweep):", ""] if t else []),
        "```bash",
        doc["command"].replace("; ", "\n"),
        "```",
        "",
        f"Commit `{doc['commit']}`{' (with uncommitted changes)' if doc.get('dirty') else ''}, trained "
        f"{doc['trained_utc']} on {doc['machine']}. Versions: "
        + ", ".join(f"{k} {v}" for k, v in doc.get("versions", {}).items()) + ".",
        "",
        "## Intended use and limits",
        "",
        "* For research and for trying the benchmark: evaluating, comparing, zero-shot on the other tasks "
        "(one observation layout), a starting point for fine-tuning.",
        "* Simulation only: state observations of ManiSkill3's CPU simulation, never images or a real robot; "
        "other ManiSkill or SAPIEN versions may change the physics and the score.",
        *([f"* Adapted on `{task}` after {before}, at one budget and one seed: one chain's outcome, a failure "
           "included, not what the method does on average.",
           "* The final policy, chosen by no evaluation, so its training evaluations do not bias the held-out "
           "score; a better policy may have existed earlier in the stage (`policy_best.pt`, not shipped)."] if t else [
            f"* Trained on `{task}` alone, at one budget and one seed"
            + ("." if doc.get("exported_from") else
               "; zero-shot on the other tasks, earlier runs of the same settings and seed: "
               "`results/movies/zero_shot.csv` (a reaching policy closes the box, most other pairs fail)."),
            f"* Chosen by its own training evaluations ({plural(n_eval, 'episode')}), so only the held-out score above is "
            "unbiased."]),
        "",
        "## Licence and citation",
        "",
        "MIT, as the repository (`LICENSE`). Cite the paper this benchmark reproduces, and this repository with "
        f"the commit above:",
        "",
        "```bibtex",
        CITATION,
        "```",
        "",
    ]
    return "\n".join(lines)


def _sweep_root(run: Path) -> Optional[Path]:
    """The sweep folder a run folder belongs to (the nearest parent with ``sweep.json``), if any."""
    for parent in run.resolve().parents:
        if (parent / "sweep.json").is_file():
            return parent
    return None


def _shown(path: Path) -> str:
    """A path as a command line shows it: repository-relative inside this repository."""
    try:
        return path.resolve().relative_to(POLICIES.parents[1]).as_posix()
    except ValueError:
        return path.as_posix()


def _utc(t: float) -> str:
    import datetime as dt
    return dt.datetime.fromtimestamp(t, dt.timezone.utc).strftime("%Y-%m-%dT%H:%M:%SZ")


def _command_of(start: dict) -> str:
    """A process start's command line as typed (``python -m maniskill_dualher.<module> ...``)."""
    argv = list(start.get("argv") or [])
    if not argv:
        return "(not recorded)"
    head = Path(argv[0])
    module = f"-m maniskill_dualher.{head.stem}" if head.parent.name == "maniskill_dualher" else str(argv[0])
    return " ".join(["python", module] + [str(a) for a in argv[1:]])


def export_doc(run: Path, which: Optional[str] = None) -> dict:
    """policy.json's entries for the policy of finished run folder ``run`` (``which``: "best" or "final"; None:
    best for a single-task run, final for a transfer stage), all read from the run's own files. Raises
    ValueError (one line naming what is missing) if the run cannot be exported."""
    from . import provenance as prov_mod
    from . import rundir
    from .rundir import CELL, CONFIG, DONE, POLICY, POLICY_BEST, PROVENANCE
    run = Path(run)
    for name in (CONFIG, DONE, PROVENANCE, "metrics.csv"):
        if not (run / name).is_file():
            raise ValueError(f"{run}: no {name} (an export needs a finished run folder)")
    cfg = json.loads((run / CONFIG).read_text())
    stage = rundir.read_stage(run)
    transfer = bool(stage and stage.get("adaptation"))
    which = which or ("final" if transfer else "best")
    if which not in ("best", "final"):
        raise ValueError(f"--policy {which!r}: choose best or final")
    src = run / (POLICY_BEST if which == "best" else POLICY)
    if not src.is_file():
        raise ValueError(f"{run}: no {src.name}")
    rows = [r for r in rundir.read_metrics(run) if r.get("eval_success_rate") not in (None, "")]
    if not rows:
        raise ValueError(f"{run}: metrics.csv has no evaluation row")
    best = max(rows, key=lambda r: float(r["eval_success_rate"]))  # max keeps the earliest of a tie, as policy_best
    chosen = best if which == "best" else rows[-1]
    starts = json.loads((run / PROVENANCE).read_text())["starts"]
    first, last = starts[0], starts[-1]
    cpu = last.get("cpu") or {}
    machine = (f"{prov_mod.machine_name(cpu) or 'an unnamed CPU'} ({cpu.get('cores', '?')}-core {cpu.get('model', '?')}"
               f"{' with AVX512-BF16' if cpu.get('avx512_bf16') else ''}{' and AMX' if cpu.get('amx_bf16') else ''}),"
               f" {last.get('torch_threads', '?')} torch thread(s), {cfg.get('sim_backend', 'CPU')} simulation")
    ev = cfg.get("eval_episodes")
    doc = {
        "task": cfg["env_id"], "method": cfg["method"],
        "file": f"policy.pt (the run's {src.name}: "
                + ("its best training evaluation" if which == "best" else "its state at the end of the run")
                + f", {plural(int(ev or 0), 'episode')} an evaluation)",
        "command": f"{_command_of(first)}; cp RUN/{src.name} policy.pt",
        "commit": last.get("commit"), "dirty": bool(last.get("dirty")), "machine": machine,
        "versions": dict(sorted((last.get("versions") or {}).items())),
        "trained_utc": _utc((run / DONE).stat().st_mtime),  # done.json's write: the run's end
        "policy_env_steps": int(float(chosen["env_steps"])),
        "policy_train_eval_success": float(chosen["eval_success_rate"]),
        "exported_from": {"run": run.name, "policy": which},
        "seed_note": f"**Seeds: this folder is one run (seed {cfg.get('seed')}), exported with `cards export`.** "
                     "It shows what one run reached, not the spread over seeds.",
    }
    if transfer:
        root = _sweep_root(run)
        sweep = (rundir.read_sweep(root) if root else None) or {}
        cell = (rundir.read_json(run / CELL) or {"cells": [{}]})["cells"][0]
        steps, folder = [], run  # each stage's env steps, walking the parents back to the first stage
        while folder is not None:
            steps.insert(0, int(json.loads((folder / CONFIG).read_text())["total_steps"]))
            st = rundir.read_stage(folder) or {}
            folder = folder.parent / st["parent"] if st.get("parent") else None
        doc["transfer"] = {
            "chain": list(stage["chain"]), "stage_env_steps": steps, "carry_replay": bool(stage.get("carry_replay")),
            "preset": sweep.get("preset", "(no sweep.json)"), "experiment": cell.get("experiment", stage.get("protocol")),
            "arm": cell.get("arm"), "seed": cfg.get("seed"),
            "run": str(run.resolve().relative_to(root)) if root else run.name,
            "policy": which, "best_train_eval": {"env_steps": int(float(best["env_steps"])),
                                                 "success": float(best["eval_success_rate"])}}
    return doc


EXPORTS = "policies"  # cards export's default root: a folder of that name beside the run


def default_root(run: Path) -> Path:
    """Where ``cards export RUN`` writes without --root: ``policies/`` beside the run folder (never the committed
    results/policies, which must be named)."""
    return Path(run).resolve().parent / EXPORTS


def in_committed(root: Path) -> bool:
    """``root`` is the committed results/policies (or a folder inside it)."""
    r, c = Path(root).resolve(), POLICIES.resolve()
    return r == c or c in r.parents


def committed_bar(task: str, transfer: bool, root: Path = POLICIES) -> Optional[Tuple[float, Path]]:
    """The bar a policy exported into results/policies must reach: the best held-out success of the task's
    committed policies of its kind (single-task, or adapted after transfer), with that folder; None if none."""
    best = None
    for folder in policy_folders(root):
        doc = json.loads((folder / "policy.json").read_text())
        if doc["task"] != task or (TRANSFER in doc) != transfer or "held_out_evaluation" not in doc:
            continue
        rate = float(doc["held_out_evaluation"]["success_rate"])
        if best is None or rate > best[0]:
            best = (rate, folder)
    return best


def export_run(run: Path, root: Optional[Path] = None, which: Optional[str] = None, episodes: int = 100,
               force: bool = False) -> Path:
    """``<root>/<task>/<folder>/`` from finished run folder ``run`` (root: ``default_root``, beside the run):
    policy.pt, policy.json (with the held-out evaluation of ``episodes`` episodes made here) and the card. Staged
    beside the target and renamed into place; an existing target is refused (ValueError). Into the committed
    results/policies only a policy whose held-out success reaches the bar (``committed_bar``), unless ``force``."""
    import shutil
    import tempfile
    import time
    from .evaluate import evaluate_policy, seed_set
    doc = export_doc(run, which)
    root = default_root(run) if root is None else Path(root)
    target = Path(root) / doc["task"] / folder_name(doc)
    if target.exists():
        raise ValueError(f"{target} exists: export refuses to replace a policy folder (remove it first)")
    target.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=target.parent))
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(stage, 0o777 & ~umask)  # mkdtemp's 0700 is not a shared folder's mode
    try:
        src = Path(run) / ("policy_best.pt" if doc["exported_from"]["policy"] == "best" else "policy.pt")
        shutil.copyfile(src, stage / "policy.pt")
        t0 = time.perf_counter()
        res = evaluate_policy(stage / "policy.pt", episodes=episodes)
        doc["held_out_evaluation"] = {
            "command": f"python -m maniskill_dualher.evaluate {_shown(target)}" + (
                f" --episodes {episodes}" if episodes != 100 else ""),
            "seeds": f"{res['seed_first']}..{res['seed_last']}", "episodes": res["episodes"], "successes": res["successes"],
            "success_rate": res["success_rate"], "success_ci95_wilson": list(res["success_ci"]),
            "mean_episode_length": res["mean_episode_length"], "wall_s": round(time.perf_counter() - t0, 1)}
        bar = committed_bar(doc["task"], TRANSFER in doc) if in_committed(root) else None
        if bar is not None and res["success_rate"] < bar[0] and not force:
            raise ValueError(f"held-out success {res['success_rate']:.2f} ({res['successes']}/{res['episodes']}) is "
                             f"below the bar for {_shown(root)}: {bar[0]:.2f}, the held-out success of "
                             f"{_shown(bar[1])}; nothing written (--force commits it anyway, or export elsewhere "
                             f"with --root)")
        atomic_write_text(stage / "policy.json", json.dumps(doc, indent=2) + "\n")
        sync_policy_json(stage)
        atomic_write_text(stage / "README.md", card_text(json.loads((stage / "policy.json").read_text())))
        stage.rename(target)
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    return target


def policy_folders(root: Path = POLICIES) -> List[Path]:
    return sorted(p.parent for p in Path(root).glob("*/*/policy.json"))


def export_main(argv: Sequence[str]) -> int:
    from .cmdline import OneLineParser
    p = OneLineParser(prog="python -m maniskill_dualher.cards export",
                                description="A finished run's policy as a results/policies folder with its card.")
    p.add_argument("run", help="a finished run folder (config.json, done.json, metrics.csv, its policy file)")
    p.add_argument("--policy", choices=("best", "final"), default=None,
                   help="policy_best.pt or policy.pt (default: best for a single-task run, final for a transfer stage)")
    p.add_argument("--root", help=f"where the <task>/<folder> goes (default: {EXPORTS}/ beside the run folder); "
                                  "the committed results/policies only when named here, and then only a policy whose "
                                  "held-out success reaches the task's committed policy's of its kind (else --force)")
    p.add_argument("--force", action="store_true",
                   help="with --root results/policies: commit a policy below the bar")
    p.add_argument("--episodes", type=int, default=100, help="held-out evaluation episodes (default 100)")
    a = p.parse_args(argv)
    if a.episodes < 1:
        print(f"error: --episodes={a.episodes} must be >= 1", file=sys.stderr)
        return 2
    try:
        out = export_run(Path(a.run), Path(a.root) if a.root else None, a.policy, a.episodes, a.force)
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    doc = json.loads((out / "policy.json").read_text())
    print(f"wrote {out}: {score_line(doc)}")
    return 0


def main(argv: Optional[Sequence[str]] = None) -> int:
    import argparse
    from .cmdline import OneLineParser
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv[:1] == ["export"]:
        return export_main(argv[1:])
    p = OneLineParser(
        prog="python -m maniskill_dualher.cards", formatter_class=argparse.RawDescriptionHelpFormatter,
        usage="python -m maniskill_dualher.cards [root] [--check]\n"
              "       python -m maniskill_dualher.cards export RUN [--root DIR] [--policy best|final] [--episodes N] "
              "[--force]",
        description="Write each committed policy's model card (README.md, YAML front matter first) and policy.json's "
                    "interface and training settings from its policy.json and policy.pt.",
        epilog="subcommands:\n"
               "  export RUN    a finished run's policy as a <task>/<folder> with policy.json, a held-out evaluation\n"
               f"                and its card (default: {EXPORTS}/ beside RUN; --root results/policies commits it)\n"
               "                (python -m maniskill_dualher.cards export --help)\n\n"
               "examples:\n"
               "  python -m maniskill_dualher.cards                 # rewrite results/policies' cards\n"
               "  python -m maniskill_dualher.cards --check         # exit 1 if one is not up to date\n"
               "  python -m maniskill_dualher.cards export runs/reach --episodes 20")
    p.add_argument("root", nargs="?", default=str(POLICIES), help="a folder of <task>/<folder>/policy.json "
                                                                  "(default: results/policies)")
    p.add_argument("--check", action="store_true", help="write nothing; say what was checked; exit 1 if a card or "
                                                        "policy.json is not up to date")
    a = p.parse_args(argv)
    stale = []
    folders = policy_folders(Path(a.root))
    for folder in folders:
        if sync_policy_json(folder, write=not a.check):
            stale.append(folder / "policy.json")
        doc = json.loads((folder / "policy.json").read_text())
        card = folder / "README.md"
        if INTERFACE in doc and (not card.is_file() or card.read_text() != card_text(doc)):
            stale.append(card)
            if not a.check:
                atomic_write_text(card, card_text(doc))
    for s in stale:
        print(("not up to date: " if a.check else "wrote ") + _shown(s))
    what = (f"{plural(len(folders), 'policy folder')} under {_shown(Path(a.root))}: each policy.json's {INTERFACE} and {SETTINGS} "
            f"against its policy.pt, each README.md (front matter and card) against policy.json")
    if a.check:
        print(f"checked {what}: " + (f"{plural(len(stale), 'file')} not up to date (python -m "
                                     f"maniskill_dualher.cards rewrites them)" if stale else "all up to date"))
    else:
        print(f"{plural(len(stale), 'file')} written; {what}" if stale else f"up to date: {what}")
    return 1 if a.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
