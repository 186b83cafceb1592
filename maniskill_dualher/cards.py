"""Model cards of the committed policies: ``results/policies/<task>/<folder>/README.md``, written from the folder's
``policy.json`` alone, so a card says what its ``policy.json`` says (``tests/test_cards.py`` holds each card to it).

A folder is named ``<method>`` (one single-task run, its ``policy_best.pt``) or ``<method>_after_transfer``
(``folder_name``: the adaptation stage of a transfer chain, its final ``policy.pt``; ``policy.json`` then holds a
``transfer`` entry: the chain, each stage's env steps, the preset, the sweep command, the stage's run folder).

``policy.json`` holds how the policy was made and scored (command, commit, machine, versions, the held-out
evaluation); ``sync_policy_json`` adds what the policy file itself carries: its interface (observation layout,
action size, controller, episode rules) and the run's training settings (the ``RunConfig`` it was trained with).

    python -m maniskill_dualher.cards [results/policies]            # write policy.json's two entries and the cards
    python -m maniskill_dualher.cards [results/policies] --check    # exit 1 if a card or entry is not up to date
"""
from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Dict, List, Optional, Sequence

from .fileio import atomic_write_text

POLICIES = Path(__file__).resolve().parents[1] / "results" / "policies"
INTERFACE, SETTINGS = "interface", "training_settings"
SUCCESS = {   # what success means, as tasks/*.py define it (README "What is where")
    "ReachTarget-v1": "the gripper's tool centre point (TCP) within 0.05 m of the red ball",
    "CloseBox-v1": "the box lid closed to within 0.1 rad",
    "CloseMicrowave-v1": "the microwave door closed to within 0.1 rad",
}
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
            ("evaluation during training", f"{cfg.get('eval_episodes')} episodes every {cfg.get('eval_every')} "
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


def card_text(doc: dict) -> str:
    """A model card from a policy.json (after ``sync_policy_json``)."""
    task, method = doc["task"], doc["method"]
    itf, cfg, h = doc[INTERFACE], doc[SETTINGS], doc["held_out_evaluation"]
    slots = itf.get("observation_slots")
    width = itf["observation_width"] - 2 * itf["goal_dim"]
    layout = " | ".join(f"{n} ({w})" for n, w in slots.items()) if slots else f"observation ({width})"
    g = itf["goal_dim"]
    t = doc.get(TRANSFER)
    before = " -> ".join(t["chain"][:-1]) if t else ""
    lines = [
        f"# Model card: {_method_display(method)} on {task}" + (f", adapted after {before}" if t else ""),
        "",
        "Generated from this folder's `policy.json` by `python -m maniskill_dualher.cards` (do not edit by hand).",
        "",
        "## What it is",
        "",
        f"* **Task**: `{task}` (ManiSkill3, Franka Panda; this repository's `tasks/`): success is "
        f"{SUCCESS.get(task, 'as the task defines it')}.",
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
           "success on 10 episodes (no evaluation chose this policy)." if t else
           f"Its training evaluation at env step {doc['policy_env_steps']}: {doc['policy_train_eval_success']} "
           "success on 10 episodes (the ones that chose it, so optimistic)."),
        "",
        *(_transfer_seeds(t, cfg) if t else [
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
            f"* Trained on `{task}` alone, at one budget and one seed; zero-shot on the other tasks, earlier runs "
            "of the same settings and seed: `results/movies/zero_shot.csv` (a reaching policy closes the box, most "
            "other pairs fail).",
            "* Chosen by its own training evaluations (10 episodes), so only the held-out score above is unbiased."]),
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


def policy_folders(root: Path = POLICIES) -> List[Path]:
    return sorted(p.parent for p in Path(root).glob("*/*/policy.json"))


def main(argv: Optional[Sequence[str]] = None) -> int:
    import argparse
    p = argparse.ArgumentParser(prog="python -m maniskill_dualher.cards",
                                description="Write each committed policy's model card (README.md) from its policy.json.")
    p.add_argument("root", nargs="?", default=str(POLICIES), help="results/policies (default)")
    p.add_argument("--check", action="store_true", help="write nothing; exit 1 if a card is not up to date")
    a = p.parse_args(argv)
    stale = []
    for folder in policy_folders(Path(a.root)):
        if sync_policy_json(folder, write=not a.check):
            stale.append(folder / "policy.json")
        doc = json.loads((folder / "policy.json").read_text())
        card = folder / "README.md"
        if INTERFACE in doc and (not card.is_file() or card.read_text() != card_text(doc)):
            stale.append(card)
            if not a.check:
                atomic_write_text(card, card_text(doc))
    for s in stale:
        print(("not up to date: " if a.check else "wrote ") + str(s))
    return 1 if a.check and stale else 0


if __name__ == "__main__":
    sys.exit(main())
