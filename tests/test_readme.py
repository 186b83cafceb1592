"""The README's Finding and the reference's Why (results/reference/README.md) say no more than its claims.csv.

Every sentence of the Why cites a claim (its id in backticks); every number with an interval, ``x [lo, hi]``, in a
sentence is the difference or the ratio of means of a claim that sentence cites, at the precision shown; a cited
claim decided at 95% that does not survive Holm carries a dagger, one that survives carries none. Hand-edited
numbers drift when the reference is re-merged; this catches it."""
import re
import subprocess
from pathlib import Path

import pytest

from maniskill_dualher.analysis.runs import read_rows

REPO = Path(__file__).resolve().parents[1]
INTERVAL = re.compile(r"(−?-?\d+(?:\.\d+)?)x? \[(−?-?\d+(?:\.\d+)?), (−?-?\d+(?:\.\d+)?)\]")
CITE = re.compile(r"`([a-z_']+)`(†?)(‡?)")
REPLICATION = re.compile(r": ([+−-]?\d+(?:\.\d+)?) \[([+−-]?\d+(?:\.\d+)?), ([+−-]?\d+(?:\.\d+)?)\]")


def _claims(folder: str = "reference"):
    return {r["claim"]: r for r in read_rows(REPO / "results" / folder / "claims.csv")}


# where each paragraph lives: the README's Finding, and the mechanism paragraph beside the reference it reads
SECTION_FILES = {"Finding": REPO / "README.md", "Why": REPO / "results" / "reference" / "README.md"}


def _section(name: str) -> str:
    text = SECTION_FILES[name].read_text()
    start = text.index(f"**{name}** (")
    end = min(i for i in (text.find("\n\n", start), len(text)) if i >= 0)
    return text[start:end]


def _sentences(paragraph: str):
    # a sentence ends at '.' followed by a space and a capital, a backtick or a bold marker
    return [s.strip() for s in re.split(r"(?<=\.)\s+(?=[A-Z*`])", " ".join(paragraph.split())) if s.strip()]


def _float(s: str) -> float:
    return float(s.replace("−", "-"))


def _decimals(s: str) -> int:
    return len(s.split(".")[1]) if "." in s else 0


def _matches(shown: str, value: str) -> bool:
    if not value:
        return False
    return abs(abs(_float(shown)) - abs(float(value))) <= 0.5 * 10 ** -_decimals(shown) + 1e-9


def _replication_of(claim: dict, point: str, lo: str, hi: str) -> bool:
    """The interval of a post-hoc claim's replication (claims.csv ``replication``: "seeds a-b (...): d [lo, hi] ...")."""
    m = REPLICATION.search(claim.get("replication") or "")
    return bool(m) and all(_matches(x, y) for x, y in zip((point, lo, hi), m.groups()))


def _interval_of(claim: dict, point: str, lo: str, hi: str) -> bool:
    for mid, low, high in (("diff", "diff_ci95_low", "diff_ci95_high"),
                           ("ratio", "ratio_ci95_low", "ratio_ci95_high")):
        if not claim.get(mid):
            continue
        # a cost may be written as a positive number: -89 [-159, -18] reads "costs 89 [18, 159]"
        ends = ((low, high), (high, low))
        if _matches(point, claim[mid]) and any(_matches(lo, claim[a]) and _matches(hi, claim[b]) for a, b in ends):
            return True
    return False


def _check(paragraph: str, claims: dict, every_sentence_cites: bool):
    cited_anywhere = set()
    for sentence in _sentences(paragraph):
        if sentence.startswith("**"):
            continue  # the paragraph's bold lead and legend
        cites = [(c, dagger) for c, dagger, _ in CITE.findall(sentence) if c in claims]
        for c, _, post in CITE.findall(sentence):
            if c in claims:
                assert bool(post) == bool(claims[c].get("post_hoc")), (
                    f"{c}: ‡ marks exactly the claims defined after their data (claims.csv post_hoc): {sentence!r}")
        if every_sentence_cites:
            assert cites, f"a Why sentence cites no claim: {sentence!r}"
        for claim, dagger in cites:
            r = claims[claim]
            assert r.get("n_a"), f"{claim} is cited but not measured"
            if r["survives_holm"] == "no":
                assert dagger, f"{claim} does not survive Holm: cite it as `{claim}`†: {sentence!r}"
            else:
                assert not dagger, f"{claim} survives Holm or is undecided, no dagger: {sentence!r}"
            cited_anywhere.add(claim)
        for point, lo, hi in INTERVAL.findall(sentence):
            assert any(_interval_of(claims[c], point, lo, hi) or _replication_of(claims[c], point, lo, hi)
                       for c, _ in cites), (
                f"{point} [{lo}, {hi}] is no cited claim's interval in {sentence!r}")
    return cited_anywhere


def test_finding_cites_claims_with_their_intervals():
    claims = _claims()
    # the paper's-regime claims are read from the confirmatory study, the folder the Finding's sentence links
    claims.update({c: r for c, r in _claims("paper_regime_confirm").items() if c.startswith("regime_")})
    cited = _check(_section("Finding"), claims, every_sentence_cites=False)
    assert {"a", "b"} <= cited


def test_every_why_sentence_cites_a_claim_with_its_interval_and_holm():
    claims = _claims()
    cited = _check(_section("Why"), claims, every_sentence_cites=True)
    assert len(cited) >= 4


def test_the_checker_rejects_a_drifted_number():
    claims = {"a": {"n_a": "32", "diff": "-113.2", "diff_ci95_low": "-158.9", "diff_ci95_high": "-67.5",
                    "survives_holm": "yes", "ratio": "", "ratio_ci95_low": "", "ratio_ci95_high": ""}}
    _check("It loses −113 [−159, −68] (`a`).", claims, every_sentence_cites=True)
    for bad in ("It loses −113 [−159, −60] (`a`).", "It loses −113 [−159, −68].",
                "It loses −113 [−159, −68] (`a`†)."):
        try:
            _check(bad, claims, every_sentence_cites=True)
        except AssertionError:
            continue
        raise AssertionError(f"accepted {bad!r}")


def test_every_post_hoc_claim_is_marked_and_its_replication_reported_as_it_is():
    """A claim defined after its data is cited with ‡, and the sentence says what its replication is: its value
    where it has one, "half-independent" where one side's seeds were seen before the definition, and "not
    replicated" where it has none or its "replication" is its own pairs (claims.csv ``replication``)."""
    claims = _claims()
    why = _sentences(_section("Why"))
    post = [k for k, r in claims.items() if r.get("post_hoc") and r.get("n_a")]
    assert post
    for key in post:
        said = [x for x in why if f"`{key}`" in x]
        assert said, f"post-hoc claim {key} is not in the Why"
        assert any("‡" in x.split(f"`{key}`", 1)[1][:3] for x in said)
        rep = claims[key]["replication"]
        if rep.startswith(("no replication", "not a replication")) or "not a replication" in rep:
            assert any("not replicated" in x for x in said), (key, rep)
            continue
        m = REPLICATION.search(rep)
        assert m, rep
        assert any(m.group(1).lstrip("+") in x for x in said), key
        if "half-independent" in rep:
            assert any("half-independent" in x for x in said), (key, rep)


# --------------------------------------------------------------------------- the README's first hour (issue 43)
def _readme() -> str:
    return (REPO / "README.md").read_text()


def test_readme_stays_short():
    text = _readme()
    assert len(text) <= 6_000, f"README.md is {len(text)} characters: move prose to docs/"
    # the first screen answers: the finding (regime first), then the claims table, then install
    assert text.index("**Finding**") < text.index("<!-- claims table") < text.index("## Install")
    flat = " ".join(text.split())
    assert flat.index("*In the reference regime*") < flat.index("*In the paper's own regime*")


def test_readme_results_table_is_generated_from_claims_csv():
    """The table between the README's markers is `report --readme-table` of results/reference/claims.csv."""
    from maniskill_dualher.analysis import claims as claims_mod
    rows = read_rows(REPO / "results" / "reference" / "claims.csv")
    want = claims_mod.readme_table(rows)
    assert claims_mod.readme_block(_readme()) == want, (
        "regenerate it: python -m maniskill_dualher.report results/reference --readme-table")
    paper = [r for r in rows if r["group"] == "paper" and r.get("diff")]
    assert len(want.splitlines()) == 2 + len(paper) >= 3
    for r in paper:   # each row's verdict word is the claim's
        line = next(x for x in want.splitlines() if x.startswith(f"| `{r['claim']}` |"))
        assert line.rstrip(" |").endswith(r["verdict"].split(" (")[0] + ("†" if r["survives_holm"] == "no" else ""))


def test_the_generator_follows_claims_csv():
    from maniskill_dualher.analysis import claims as claims_mod
    row = {"claim": "a", "group": "paper", "statement": "dual_buffer > sac_her_per: successful CloseMicrowave-v1 "
           "adaptation episodes", "n_a": "3", "n_b": "4", "mean_a": "10", "mean_b": "12.5", "diff": "-2.5",
           "diff_ci95_low": "-4.25", "diff_ci95_high": "-0.5", "verdict": "contradicted", "survives_holm": "no"}
    line = claims_mod.readme_table([row, dict(row, group="ablation", claim="z")]).splitlines()[2:]
    assert line == ["| `a` | dual buffer > SAC+HER+PER: successful adaptation episodes | 10 (3) | 12.5 (4) | "
                    "−2.5 [−4.25, −0.5] | contradicted† |"]


def test_quick_start_runs_a_trained_agent_before_any_sweep():
    text = _readme()
    start = text.index("## First minutes")
    commands = [ln for ln in text[start:].splitlines() if ln.startswith("python -m maniskill_dualher.")]
    assert commands[0].startswith("python -m maniskill_dualher.evaluate results/policies/"), commands[0]
    assert any(c.startswith("python -m maniskill_dualher.sweep") for c in commands[1:])


def test_load_policy_snippet_runs_as_written(tmp_path):
    """The README's Python block, exactly as written, in a fresh process from the repository's root: it makes
    the env, loads a committed policy and runs one whole episode (CPU simulation, no render device)."""
    import os
    import subprocess
    import sys
    text = _readme()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) == 1
    code = blocks[0]
    assert "load_policy(" in code and "gym.make(" in code and "env.reset(" in code and "while not done" in code
    env = dict(os.environ, PYTHONPATH=str(REPO))
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert re.fullmatch(r"success: (True|False)", r.stdout.strip().splitlines()[-1]), r.stdout


# --------------------------------------------------------------------------- the paper's regime beside chance
def test_paper_regime_counts_stand_beside_the_random_arm():
    """The README's paper-regime sentence gives both methods' mean counts (claims.csv of the confirmatory study)
    and, beside them, the count uniform-random actions give under the same episode rules (its regime.csv)."""
    folder = REPO / "results" / "paper_regime_confirm"
    claim = {r["claim"]: r for r in read_rows(folder / "claims.csv")}["regime_count_episode"]
    random_row = next(r for r in read_rows(folder / "regime.csv") if r["arm"] == "random")
    finding = " ".join(_section("Finding").split())
    m = re.search(r"dual buffer ([\d.]+) vs SAC\+HER\+PER ([\d.]+) successful episodes.*?uniform-random actions "
                  r"([\d.]+)", finding)
    assert m, "the paper-regime sentence names both counts and the random arm's"
    for shown, value in zip(m.groups(), (claim["mean_a"], claim["mean_b"], random_row["successes_mean"])):
        decimals = len(shown.partition(".")[2])  # as many as the README shows, rounded
        assert float(shown) == pytest.approx(float(value), abs=0.5 * 10 ** -decimals), (shown, value)
    pairs = int(claim["n_a"])
    if pairs < 16:
        assert f"{pairs} of the preregistered study's 16 pairs" in finding
        assert "no verdict" in finding, "an unfinished study gives no verdict"
        return
    # all 16 pairs: the preregistered verdict, in claims.csv's words, with its interval as the README rounds it
    assert "the preregistered study's 16 pairs" in finding
    verdict = claim["verdict"].split(" (")[0]
    m = re.search(r"(−?[\d.]+) \[(−?[\d.]+), (−?[\d.]+)\] \(`regime_count_episode`\): ([a-z ]+)", finding)
    assert m, "the paper-regime sentence gives the preregistered claim's difference, interval and verdict"
    for shown, value in zip(m.groups()[:3], (claim["diff"], claim["diff_ci95_low"], claim["diff_ci95_high"])):
        shown = shown.replace("−", "-")
        decimals = len(shown.partition(".")[2])
        assert float(shown) == pytest.approx(float(value), abs=0.5 * 10 ** -decimals), (shown, value)
    assert m.group(4).strip() == verdict, (m.group(4), verdict)


# --------------------------------------------------------------------------- committed prose stays prose
def test_no_committed_markdown_repeats_a_paragraph():
    """An edit script once replaced the empty string, which writes its new paragraph between every character of a
    file (results/paper_regime/HOW_MADE.md grew from 80 to 81,889 lines and was committed so): no committed
    Markdown file repeats a paragraph, or holds runs of one-character lines."""
    files = subprocess.run(["git", "ls-files", "*.md"], cwd=REPO, capture_output=True, text=True).stdout.split()
    assert len(files) >= 10
    for name in files:
        text = (REPO / name).read_text()
        paragraphs = [p.strip() for p in text.split("\n\n") if len(p.strip()) > 200]
        repeated = {p[:60] for p in paragraphs if paragraphs.count(p) > 1}
        assert not repeated, (name, repeated)
        lines = text.splitlines()
        assert sum(len(line) == 1 for line in lines) <= 20, f"{name}: {len(lines)} lines, most of one character"
