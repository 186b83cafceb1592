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
    assert doc[cards.SETTINGS]["method"] == doc["method"] == folder.name
    assert doc[cards.INTERFACE]["env_id"] == doc["task"] == folder.parent.name


def test_the_card_follows_policy_json(tmp_path):
    """Change the score in a policy.json copy: the card changes with it (nothing is typed into the card)."""
    folder = FOLDERS[0]
    doc = json.loads((folder / "policy.json").read_text())
    h = dict(doc["held_out_evaluation"], successes=3, episodes=7, success_rate=3 / 7,
             success_ci95_wilson=list(wilson(3, 7)))
    card = cards.card_text(dict(doc, held_out_evaluation=h))
    assert SCORE.findall(card)[0][:3] == ("3", "7", "0.43")
