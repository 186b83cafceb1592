"""fig7's aggregates and claims.csv's probability of improvement held to rliable (Agarwal et al. 2021), the library
people trust for them, on the same score matrices (results/reference/scores.csv, selected as the report selects
them): point estimates equal; each interval end of ours inside rliable's resampling noise, i.e. between the
quantiles q -+ d of rliable's own stratified-bootstrap distribution (same number of resamples, d = 4 standard
errors of an empirical q-quantile, sqrt(q (1 - q) / B)), which a 90% interval, a plain (unstratified) bootstrap
or an off-by-one matrix would leave.

fig7's numbers are read off the figure's own drawing calls: ``plots._aggregate_row`` draws onto axes that record
them (plots.py is not changed for the test). rliable is a test-only dependency (``pip install -e '.[test]'``)."""
import math
from pathlib import Path

import numpy as np
import pytest

try:
    from rliable import library as rly
    from rliable import metrics
except Exception as e:  # noqa: BLE001  (its dependency arch fails at import on pandas 3, not only ImportError)
    pytest.skip(f"rliable cannot be imported ({type(e).__name__}); pip install -e '.[test]' (rliable, pandas<3)",
                allow_module_level=True)

from maniskill_dualher.analysis import claims, plots, stats
from maniskill_dualher.analysis.runs import read_rows

REF = Path(__file__).resolve().parents[1] / "results" / "reference"
Q = (1 - plots.LEVEL) / 2
Z = 4.5
B, B_POI = plots.RESAMPLES, plots.RESAMPLES // 4  # fig7's resamples: IQM, mean, profiles; probability of improvement


class Axes:
    """Stands in for a matplotlib Axes: records every drawing call, returns nothing."""

    def __init__(self):
        self.calls = []

    def __getattr__(self, name):
        return lambda *a, **k: self.calls.append((name, a, k))

    def drawn(self, name):
        return [(a, k) for n, a, k in self.calls if n == name]


@pytest.fixture(scope="module")
def scores():
    return read_rows(REF / "scores.csv")


@pytest.fixture(scope="module")
def fig7(scores, tmp_path_factory):
    """Each panel row of fig7: its score matrices (method -> seeds x tasks) and what was drawn for them."""
    rows = []
    real = plots._aggregate_row

    def record(axes, mats, tasks, metric_name, rate):
        ax = [Axes(), Axes(), Axes()]
        real(ax, mats, tasks, metric_name, rate)
        rows.append((mats, tasks, ax))

    plots._aggregate_row = record
    try:
        assert plots.plot_aggregate(scores, tmp_path_factory.mktemp("fig7") / "fig7.png")
    finally:
        plots._aggregate_row = real
    assert len(rows) == 2  # single-task across tasks; the headline adaptation claim
    return rows


@pytest.fixture(autouse=True)
def _seeded_global_rng():
    """rliable's bootstrap draws from numpy's global generator: seed it here, and give it back as it was."""
    state = np.random.get_state()
    np.random.seed(0)
    yield
    np.random.set_state(state)


def _ends(drawn):
    """(point, low, high) of each errorbar drawn: errorbar(x, y, xerr=[[x - low], [high - x]])."""
    return [(a[0], a[0] - k["xerr"][0][0], a[0] + k["xerr"][1][0]) for a, k in drawn]


def _within_noise(ours: float, boot: np.ndarray, q: float, b_ours: int) -> bool:
    """``ours`` (a q-quantile of b_ours resamples) within resampling noise of the q-quantile of ``boot``."""
    d = Z * math.sqrt(q * (1 - q) * (1 / b_ours + 1 / len(boot)))
    lo, hi = np.quantile(boot, [max(q - d, 0.0), min(q + d, 1.0)])
    return lo - 1e-9 <= ours <= hi + 1e-9


def test_iqm_and_mean_with_stratified_bootstrap_intervals(fig7):
    for mats, tasks, ax in fig7:
        names = list(mats)[::-1]
        drawn = _ends(ax[0].drawn("errorbar"))
        assert len(drawn) == 2 * len(names)
        for k, fn in enumerate((metrics.aggregate_iqm, metrics.aggregate_mean)):
            for j, m in enumerate(names):
                point, low, high = drawn[k * len(names) + j]
                assert point == pytest.approx(fn(mats[m]), rel=1e-12, abs=1e-12)
                boot = rly.StratifiedBootstrap(mats[m]).apply(lambda x: np.array([fn(x)]), 4 * B)[:, 0]
                assert _within_noise(low, boot, Q, B) and _within_noise(high, boot, 1 - Q, B), \
                    (m, ["IQM", "mean"][k], low, high, np.quantile(boot, [Q, 1 - Q]))
                # rliable's own interval call, at our B, lands in the same noise
                _, ci = rly.get_interval_estimates({m: mats[m]}, lambda x: np.array([fn(x)]), reps=B)
                assert _within_noise(float(ci[m][0, 0]), boot, Q, B) and \
                    _within_noise(float(ci[m][1, 0]), boot, 1 - Q, B)


def test_performance_profiles_and_their_bands(fig7):
    for mats, tasks, ax in fig7:
        names = list(mats)[::-1]
        lines, bands = ax[1].drawn("plot"), ax[1].drawn("fill_between")
        assert len(lines) == len(bands) == len(names)
        for m, (la, _), (ba, _) in zip(names, lines, bands):
            taus, profile = la
            points, _ = rly.create_performance_profile({m: mats[m]}, taus, reps=10)
            np.testing.assert_allclose(profile, points[m], rtol=0, atol=1e-12)
            boot = rly.StratifiedBootstrap(mats[m]).apply(lambda x: rly.score_distributions(x, taus), B)
            for t in range(len(taus)):
                assert _within_noise(ba[1][t], boot[:, t], Q, B) and _within_noise(ba[2][t], boot[:, t], 1 - Q, B), \
                    (m, taus[t], ba[1][t], ba[2][t], np.quantile(boot[:, t], [Q, 1 - Q]))


def test_probability_of_improvement(fig7):
    for mats, tasks, ax in fig7:
        names = list(mats)[::-1]
        pairs = [(a, b) for i, a in enumerate(names) for b in names[i + 1:]]
        drawn = _ends(ax[2].drawn("errorbar"))
        assert len(drawn) == len(pairs) >= 1
        for (a, b), (point, low, high) in zip(pairs, drawn):
            assert point == pytest.approx(metrics.probability_of_improvement(mats[a], mats[b]), abs=1e-12)
            boot = rly.StratifiedIndependentBootstrap(mats[a], mats[b]).apply(
                lambda x, y: np.array([metrics.probability_of_improvement(x, y)]), 4 * B_POI)[:, 0]
            assert _within_noise(low, boot, Q, B_POI) and _within_noise(high, boot, 1 - Q, B_POI), \
                (a, b, low, high, np.quantile(boot, [Q, 1 - Q]))


def test_claims_prob_improvement_is_rliables(scores):
    """claims.csv's prob_improvement, as the report computes it (the claims' own seeds, paired or not), equals
    rliable's probability of improvement on the same two score vectors (one task)."""
    rows = {r["claim"]: r for r in claims.claim_rows(scores, resamples=200)}
    checked = 0
    for c in claims.CLAIMS:
        row = rows[c.key]
        if "prob_improvement" not in row:
            continue
        rows_a, rows_b = claims._side_rows(scores, c.a, c.metric), claims._side_rows(scores, c.b, c.metric)
        seeds = claims.paired_seeds(scores, c)
        if seeds is not None:
            rows_a, rows_b = {s: rows_a[s] for s in seeds}, {s: rows_b[s] for s in seeds}
        a = np.array([[float(rows_a[s]["value"])] for s in sorted(rows_a)])
        b = np.array([[float(rows_b[s]["value"])] for s in sorted(rows_b)])
        assert (len(a), len(b)) == (row["n_a"], row["n_b"])
        theirs = metrics.probability_of_improvement(a, b)
        assert row["prob_improvement"] == pytest.approx(theirs, abs=1e-12), c.key
        assert stats.prob_improvement(a[:, 0], b[:, 0]) == pytest.approx(theirs, abs=1e-12), c.key
        checked += 1
    assert checked >= 20
