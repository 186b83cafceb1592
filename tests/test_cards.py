"""Every committed policy folder has a model card (README.md) that says what its policy.json says (issue 43)."""
import json
import re
from pathlib import Path

import pytest

from maniskill_dualher import cards
from maniskill_dualher.analysis.stats import wilson

ROOT = Path(__file__).resolve().parents[1] / "results" / "policies"
FOLDERS = sorted(p.parent for p in ROOT.glob("*/*/policy.pt"))
SCORE = re.compile(r"(\d+)/(\d+) episodes successful \(([\d.]+)\), 95% Wilson interval \[([\d.]+), ([\d.]+)\]")


def test_there_are_policy_folders():
    assert len(FOLDERS) >= 3 and cards.policy_folders(ROOT) == FOLDERS


@pytest.mark.parametrize("folder", FOLDERS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_each_policy_folder_has_a_card_that_is_its_policy_json(folder):
    doc = json.loads((folder / "policy.json").read_text())
    card = (folder / "README.md").read_text()
    assert card == cards.card_text(doc), "regenerate: python -m maniskill_dualher.cards"
    # the card's held-out score is policy.json's, and policy.json's interval is the Wilson interval of its count
    h = doc["held_out_evaluation"]
    found = SCORE.findall(card)
    assert len(found) == 1
    k, n, rate, lo, hi = found[0]
    assert (int(k), int(n)) == (h["successes"], h["episodes"]) and float(rate) == pytest.approx(h["success_rate"],
                                                                                             abs=0.005)
    assert (float(lo), float(hi)) == pytest.approx(tuple(h["success_ci95_wilson"]), abs=5e-4)
    assert tuple(h["success_ci95_wilson"]) == pytest.approx(wilson(h["successes"], h["episodes"]), abs=1e-9)
    for word in (doc["task"], doc["commit"], doc["machine"], "MIT", "@article", "Seeds: this folder is one"):
        assert word in card, word


@pytest.mark.parametrize("folder", FOLDERS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_policy_json_settings_are_the_policy_files(folder):
    """policy.json's interface and training settings are what policy.pt carries (loaded with weights_only)."""
    assert cards.sync_policy_json(folder, write=False) is False, "regenerate: python -m maniskill_dualher.cards"
    doc = json.loads((folder / "policy.json").read_text())
    assert doc[cards.SETTINGS]["method"] == doc["method"] and cards.folder_name(doc) == folder.name
    assert doc[cards.INTERFACE]["env_id"] == doc["task"] == folder.parent.name


TRANSFER = [f for f in FOLDERS if f.name.endswith(cards.AFTER_TRANSFER)]


def test_the_transfer_chain_s_adapted_policies_are_here():
    """Issue 43: the chain's adapted CloseMicrowave policies of both methods, seed 0 (the rule, whatever it scored)."""
    assert {(f.parent.name, f.name) for f in TRANSFER} >= {("CloseMicrowave-v1", "dual_buffer_after_transfer"),
                                                           ("CloseMicrowave-v1", "sac_her_per_after_transfer")}


@pytest.mark.parametrize("folder", TRANSFER, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_an_adapted_policy_is_the_final_one_and_its_card_says_how_it_was_made(folder):
    """The policy is the adaptation stage's final policy (the end of adaptation, what the transfer claims measure),
    and the card names the chain, the preset, the sweep command, the one run, its seed and the held-out score."""
    from maniskill_dualher.policy import load_policy
    doc = json.loads((folder / "policy.json").read_text())
    t, card, pol = doc[cards.TRANSFER], (folder / "README.md").read_text(), load_policy(folder)
    assert t["policy"] == "final" and t["chain"][-1] == doc["task"] and t["preset"] == "reference"
    assert pol.env_steps == pol.config["total_steps"] == t["stage_env_steps"][-1] == doc["policy_env_steps"]
    assert pol.config["seed"] == t["seed"] == 0
    assert t["sweep_command"].startswith("python -m maniskill_dualher.sweep --preset reference --experiments transfer")
    assert doc["command"].startswith(t["sweep_command"] + "; cp OUT/" + t["run"] + "/policy.pt ")
    for words in (f"adapted after {' -> '.join(t['chain'][:-1])}", "reference preset", t["sweep_command"],
                  "the **final** policy", "not the stage's `policy_best.pt`", "one run (seed 0)",
                  "Seed 0 is the rule", doc["held_out_evaluation"]["command"]):
        assert words in card, words
    assert len(SCORE.findall(card)) == 1


def test_the_card_follows_policy_json(tmp_path):
    """Change the score in a policy.json copy: the card changes with it (nothing is typed into the card)."""
    folder = FOLDERS[0]
    doc = json.loads((folder / "policy.json").read_text())
    h = dict(doc["held_out_evaluation"], successes=3, episodes=7, success_rate=3 / 7,
             success_ci95_wilson=list(wilson(3, 7)))
    card = cards.card_text(dict(doc, held_out_evaluation=h))
    assert SCORE.findall(card)[0][:3] == ("3", "7", "0.43")
