"""Figures that cannot be misread: every committed figure carries its lines in its PNG metadata
(``plots.legend_data``), and over all of them no two lines of a figure share a colour, a line keeps one colour in
every figure, and no title says a figure is empty. The colour rule itself (``plots.color_of``) restyles nothing
when a method or an experiment is appended by its recipe."""
from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import pytest

from maniskill_dualher.analysis import plots
from maniskill_dualher.analysis.runs import read_rows
from maniskill_dualher.experiment import registry
from maniskill_dualher import methods

RESULTS = Path(__file__).resolve().parents[1] / "results"
REFERENCE = RESULTS / "reference"


def _figures(root: Path):
    return sorted(p for p in root.rglob("*.png") if "superseded" not in p.parts)


def colour_rule_breaks(pngs) -> list:
    """Every break of the colour rule over ``pngs``: a PNG without its lines, two lines of one figure in one
    colour, a line in two colours, an empty figure's title."""
    breaks, colour_of_line = [], defaultdict(set)
    for p in pngs:
        data = plots.read_legend_data(p)
        if data is None:
            breaks.append(f"{p}: no '{plots.LEGEND_KEY}' metadata (rerun the report of its folder)")
            continue
        titles = [data["title"]] + [ax["title"] for ax in data["axes"]]
        breaks += [f"{p}: title {t!r}" for t in titles if "no runs" in t.lower() or "no finished runs" in t.lower()]
        line_of_colour = {}
        for ax in data["axes"]:
            for ln in ax["lines"]:
                colour_of_line[ln["line"]].add((ln["colour"], p))
                other = line_of_colour.setdefault(ln["colour"], ln["line"])
                if other != ln["line"]:
                    breaks.append(f"{p}: {other!r} and {ln['line']!r} both drawn in {ln['colour']}")
    for line, seen in colour_of_line.items():
        if len({c for c, _ in seen}) > 1:
            breaks.append(f"{line!r} drawn in {sorted({c for c, _ in seen})}: "
                          f"{sorted({f'{q.parent.name}/{q.name}: {c}' for c, q in seen})}")
    return list(dict.fromkeys(breaks))


def test_every_committed_figure_keeps_the_colour_rule():
    pngs = _figures(RESULTS)
    assert len(pngs) >= 15
    assert colour_rule_breaks(pngs) == []


def test_every_committed_figure_names_its_lines():
    """The metadata is the figure's: each committed curve figure lists lines, every line a method and an arm."""
    shown = {s.display for s in methods.METHOD_SPECS.values()}
    for p in _figures(RESULTS):
        data = plots.read_legend_data(p)
        lines = [ln for ax in (data or {"axes": []})["axes"] for ln in ax["lines"]]
        if p.name != "fig8_budget.png":   # the budget figure draws a contrast of two methods, no method's line
            assert lines, p
        assert all(ln["line"].split(", ", 1)[0] in shown for ln in lines), p


def test_the_rule_catches_a_shared_colour(tmp_path):
    """The check itself: two lines in one colour, and one line in two figures in two colours, are found."""
    plt = plots._plt()
    for name, colours in (("a.png", ("#111111", "#111111")), ("b.png", ("#222222", "#333333"))):
        fig, ax = plt.subplots()
        for line, c in zip(("dual buffer, x", "dual buffer, y"), colours):
            ax.plot([0, 1], [0, 1], color=c, gid=line, label=line)
        plots.save_figure(fig, tmp_path / name)
        plt.close(fig)
    breaks = colour_rule_breaks([tmp_path / "a.png", tmp_path / "b.png"])
    assert any("both drawn in #111111" in b for b in breaks)
    assert any("'dual buffer, x' drawn in" in b for b in breaks)
    assert colour_rule_breaks([tmp_path / "b.png"]) == []


def _every_line():
    """line_name -> colour of every cell the registry plans (method x arm)."""
    out = {}
    for e in registry.EXPERIMENTS.values():
        for a in e.arms:
            for m in e.arm_methods(a):
                out[plots.line_name(e.name, a.name, m)] = plots.color_of(m, a.name, e.name)
    return out


def test_methods_differ_in_colour_and_shade():
    specs = list(methods.METHOD_SPECS)
    assert len({plots.color_of(m) for m in specs}) == len(specs)
    assert len({plots.method_shade(m) for m in specs}) == len(specs)


def test_an_appended_method_and_experiment_restyle_no_line(monkeypatch):
    """The recipes' additions (a method with no declared shade, an experiment with a new arm) take colours of
    their own: every line the registry had keeps its colour, and on any arm the new method differs from the others."""
    before = _every_line()
    monkeypatch.setitem(methods.METHOD_SPECS, "recipe", methods.MethodSpec(
        "recipe", "x:Y", "recipe method", "tab:green"))
    monkeypatch.setitem(registry.EXPERIMENTS, "recipe_exp", registry.Experiment(
        "recipe_exp", "A recipe's experiment", "chain", methods="transfer", arms=(
            registry.Arm("paper"), registry.Arm("warm", ("adapt.sac.random_steps=0",), display="recipe: warm"))))
    after = _every_line()
    assert {k: after[k] for k in before} == before
    for e in registry.EXPERIMENTS.values():
        for a in e.arms:
            colours = [plots.color_of(m, a.name, e.name) for m in methods.METHOD_SPECS]
            assert len(set(colours)) == len(colours), (e.name, a.name, colours)


def test_identical_algorithms_are_drawn_once_and_many_arms_split(tmp_path):
    """fig6b: the dual buffer with E off from scratch is SAC+HER+PER bit for bit, so it is drawn once, as
    SAC+HER+PER (its seeds), with a note; fig6a's arms are split into columns of ``ARMS_PER_PANEL``."""
    curves = read_rows(REFERENCE / "curves.csv")
    assert plots.plot_ablation(curves, tmp_path / "b.png", "mechanism")
    data = plots.read_legend_data(tmp_path / "b.png")
    names = {ln["line"] for ax in data["axes"] for ln in ax["lines"]}
    assert "SAC+HER+PER, from scratch" in names and "dual buffer, E off (ratio 1/0), from scratch" not in names
    assert '"dual buffer, E off (ratio 1/0), from scratch" is "SAC+HER+PER, from scratch" bit for bit' in data["title"]
    assert "E off (ratio 1/0), from scratch" not in plots.undrawn_arms(curves, "mechanism")
    assert plots.plot_ablation(curves, tmp_path / "a.png", "e_share")
    data = plots.read_legend_data(tmp_path / "a.png")
    own = [a for a in registry.EXPERIMENTS["e_share"].arms if not registry.is_paper_treatment("e_share", a.name)]
    columns = -(-len(own) // plots.ARMS_PER_PANEL)
    assert len(data["axes"]) == 2 * columns
    assert all(len(ax["lines"]) <= plots.ARMS_PER_PANEL + 2 for ax in data["axes"])


@pytest.mark.parametrize("figure", ["fig6a_e_share.png", "fig6b_mechanism.png"])
def test_committed_figure_is_what_the_report_draws(figure, tmp_path):
    """The committed figures are the current code's (byte for byte), so the metadata read above is not stale."""
    curves = read_rows(REFERENCE / "curves.csv")
    experiment = figure.split("_", 1)[1][:-4]
    assert plots.plot_ablation(curves, tmp_path / figure, experiment)
    assert (tmp_path / figure).read_bytes() == (REFERENCE / figure).read_bytes()
