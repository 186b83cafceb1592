"""Every committed policy folder has a model card (README.md) that says what its policy.json says (issue 43)."""
import json
import re
from pathlib import Path

import pytest

from maniskill_dualher import cards
from maniskill_dualher.analysis.stats import wilson
from maniskill_dualher.experiment.registry import PAPER_CHAIN

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


# --------------------------------------------------------------------------- cards export: a run's policy shared
@pytest.fixture(scope="module")
def chain_sweep(tmp_path_factory):
    """A smoke transfer chain of the dual buffer (3 stages of 150 env steps): stage 0 is a single-task run,
    stage 2 an adaptation stage."""
    from maniskill_dualher import sweep
    out = tmp_path_factory.mktemp("export") / "sw"
    sweep.main(["--preset", "smoke", "--experiments", "transfer", "--methods", "dual_buffer", "--seeds", "1",
                "--workers", "1", "--no-report", "--out", str(out)])
    stages = sorted((out / "runs" / "chain").glob("dual_buffer-s0/stage*"))
    assert [p.name[:6] for p in stages] == ["stage0", "stage1", "stage2"]
    return stages


def _export(*args):
    try:
        return cards.main(["export", *map(str, args)])
    except SystemExit as e:  # the parser's own one-line errors
        return e.code


def test_export_makes_a_policy_folder_from_a_run(chain_sweep, tmp_path, capsys):
    """A single-task run's policy_best.pt, its policy.json read from the run's files, a held-out evaluation and
    the card: the folder passes `cards --check` and loads as a policy."""
    import csv
    from maniskill_dualher.policy import load_policy
    run = chain_sweep[0]
    assert _export(run, "--root", tmp_path, "--episodes", 3) == 0
    folder = tmp_path / "ReachTarget-v1" / "dual_buffer"
    assert sorted(p.name for p in folder.iterdir()) == ["README.md", "policy.json", "policy.pt"]
    assert (folder / "policy.pt").read_bytes() == (run / "policy_best.pt").read_bytes()
    doc = json.loads((folder / "policy.json").read_text())
    assert "transfer" not in doc and doc["exported_from"] == {"run": run.name, "policy": "best"}
    rows = list(csv.DictReader(open(run / "metrics.csv")))
    best = max(rows, key=lambda r: float(r["eval_success_rate"]))
    assert doc["policy_env_steps"] == int(float(best["env_steps"]))
    h = doc["held_out_evaluation"]
    assert h["episodes"] == 3 and h["seeds"] == "2000000000..2000000002" and "--episodes 3" in h["command"]
    assert h["success_ci95_wilson"] == pytest.approx(list(wilson(h["successes"], 3)))
    assert doc["training_settings"]["env_id"] == "ReachTarget-v1" and doc["commit"]
    assert (folder / "README.md").read_text() == cards.card_text(doc)
    assert cards.main([str(tmp_path), "--check"]) == 0
    assert load_policy(folder).env_id == "ReachTarget-v1"
    assert "wrote" in capsys.readouterr().out


def test_export_of_an_adaptation_stage_takes_its_final_policy_and_chain(chain_sweep, tmp_path):
    run = chain_sweep[2]
    assert _export(run, "--root", tmp_path, "--episodes", 2) == 0
    folder = tmp_path / "CloseMicrowave-v1" / "dual_buffer_after_transfer"
    doc = json.loads((folder / "policy.json").read_text())
    assert (folder / "policy.pt").read_bytes() == (run / "policy.pt").read_bytes()
    t = doc["transfer"]
    assert t["chain"] == list(PAPER_CHAIN) and t["policy"] == "final"
    assert t["stage_env_steps"] == [json.loads((p / "config.json").read_text())["total_steps"] for p in chain_sweep]
    assert t["preset"] == "smoke" and t["experiment"] == "transfer" and t["run"].endswith(run.name)
    assert (folder / "README.md").read_text() == cards.card_text(doc)


def test_export_refuses_to_replace_a_folder_and_bad_input(chain_sweep, tmp_path, capsys):
    """An existing folder is never replaced; a run folder that is not finished, or a bad value: one line, exit 2,
    nothing written (and no staging folder left behind)."""
    run = chain_sweep[0]
    assert _export(run, "--root", tmp_path, "--episodes", 1) == 0
    folder = tmp_path / "ReachTarget-v1" / "dual_buffer"
    before = {p.name: p.read_bytes() for p in folder.iterdir()}
    capsys.readouterr()
    assert _export(run, "--root", tmp_path, "--episodes", 1) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "exists" in err[0]
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == before
    unfinished = tmp_path / "unfinished"
    unfinished.mkdir()
    (unfinished / "config.json").write_text((run / "config.json").read_text())
    for args in ([unfinished], [run, "--episodes", 0], [run, "--policy", "middle"]):
        assert _export(*args, "--root", tmp_path / "other") == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1, args
    assert not (tmp_path / "other").exists()
    assert [p.name for p in (tmp_path / "ReachTarget-v1").iterdir()] == ["dual_buffer"]  # no staging left



# --------------------------------------------------------------------------- issue 51: front matter, where exports go
def _front_matter(card: str) -> dict:
    """The card's YAML front matter as a hub reads it: huggingface_hub's ModelCard where importable (its
    metadata and eval results), else yaml.safe_load of the block between the first two '---' lines."""
    assert card.startswith("---\n")
    try:
        from huggingface_hub import ModelCard
    except ImportError:
        import yaml
        return yaml.safe_load(card.split("---\n")[1])
    data = ModelCard(card).data
    (res,) = data.eval_results
    meta = data.to_dict()
    meta["_eval"] = {"task": res.task_type, "env": res.dataset_type, "metric": res.metric_type,
                     "value": res.metric_value, "args": res.metric_args}
    return meta


@pytest.mark.parametrize("folder", FOLDERS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_each_card_opens_with_front_matter_a_hub_indexes(folder):
    doc = json.loads((folder / "policy.json").read_text())
    meta = _front_matter((folder / "README.md").read_text())
    h = doc["held_out_evaluation"]
    assert meta["library_name"] == "maniskill_dualher" and meta["license"] == "mit"
    assert meta["env_id"] == meta["task"] == doc["task"] and doc["task"] in meta["tags"]
    assert {"reinforcement-learning", "robotics", "maniskill3", doc["method"]} <= set(meta["tags"])
    (result,) = meta["model-index"][0]["results"]
    (metric,) = result["metrics"]
    assert result["task"]["type"] == "reinforcement-learning" and result["dataset"]["type"] == doc["task"]
    assert metric["type"] == "success_rate" and metric["value"] == pytest.approx(h["success_rate"])
    args = metric["args"]
    assert (args["episodes"], args["successes"]) == (h["episodes"], h["successes"])
    assert args["ci95_wilson"] == pytest.approx(h["success_ci95_wilson"], abs=5e-5)
    assert args["reset_seeds"] == h["seeds"]
    if "_eval" in meta:  # huggingface_hub read the same numbers out of the model-index
        assert meta["_eval"]["env"] == doc["task"] and meta["_eval"]["value"] == pytest.approx(h["success_rate"])
        assert meta["_eval"]["args"]["episodes"] == h["episodes"]


def test_cards_help_lists_export_and_check_says_what_it_checked(capsys):
    with pytest.raises(SystemExit) as e:
        cards.main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "export RUN" in out and "subcommands" in out
    assert cards.main(["--check"]) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert out == [f"checked {len(FOLDERS)} policy folders under results/policies: each policy.json's interface and "
                   "training_settings against its policy.pt, each README.md (front matter and card) against "
                   "policy.json: all up to date"]


def test_export_goes_beside_the_run_by_default(chain_sweep):
    run = chain_sweep[0]
    assert _export(run, "--episodes", 1) == 0
    folder = run.parent / "policies" / "ReachTarget-v1" / "dual_buffer"
    assert sorted(p.name for p in folder.iterdir()) == ["README.md", "policy.json", "policy.pt"]
    assert _front_matter((folder / "README.md").read_text())["env_id"] == "ReachTarget-v1"


def test_export_into_the_committed_folder_needs_the_bar_or_force(chain_sweep, tmp_path, monkeypatch, capsys):
    """Into results/policies (here a stand-in) only a policy whose held-out success reaches the task's committed
    policy's of its kind; below it: one line naming both, nothing written, unless --force."""
    committed = tmp_path / "policies"
    src = ROOT / "ReachTarget-v1" / "sac_her_per"
    (committed / "ReachTarget-v1" / "sac_her_per").mkdir(parents=True)
    doc = json.loads((src / "policy.json").read_text())
    doc["held_out_evaluation"] = dict(doc["held_out_evaluation"], success_rate=1.0, successes=100)
    (committed / "ReachTarget-v1" / "sac_her_per" / "policy.json").write_text(json.dumps(doc))
    monkeypatch.setattr(cards, "POLICIES", committed)
    run = chain_sweep[0]  # a smoke run: it reaches nothing in 150 env steps
    assert cards.committed_bar("ReachTarget-v1", False, committed)[0] == 1.0
    assert cards.committed_bar("ReachTarget-v1", True, committed) is None  # no adapted policy of that task
    capsys.readouterr()
    assert _export(run, "--root", committed, "--episodes", 1) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "below the bar" in err[0] and "--force" in err[0] and "sac_her_per" in err[0]
    assert sorted(p.name for p in (committed / "ReachTarget-v1").iterdir()) == ["sac_her_per"]  # no staging left
    assert _export(run, "--root", committed, "--episodes", 1, "--force") == 0
    assert (committed / "ReachTarget-v1" / "dual_buffer" / "README.md").is_file()
