"""Confidence intervals and paired tests of the comparison tables (reports.significance).

Hand-checkable cases: a constant sample's interval is [c, c]; the interval of a known sample holds its
mean and is seeded; identical columns give p = 1; 20 shapes shifted the same way give p = 2 / 2^20; a
two-sided signed-rank test over n < 6 pairs cannot go below 2 / 2^5 = 0.0625. In a table: a tiny,
noisy difference of means prints both methods bold (a tie, marked †), a large consistent one bolds
the winner only, in Markdown, LaTeX and HTML, and statistics.csv holds the p-values.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from reports.html import table_html
from reports.significance import (
    MIN_PAIRS,
    against_best,
    bootstrap_mean_ci,
    mean_intervals,
    paired_wilcoxon,
    tied_with_best,
)
from reports.statistics import statistics_frame
from reports.summary import build_summary, write_summary
from reports.table import table_latex
from tests.test_reports_tables import CONTEXT, md_tables


def test_interval_of_a_constant_sample_is_the_constant():
    assert bootstrap_mean_ci([2.5] * 10) == (2.5, 2.5)
    assert bootstrap_mean_ci([0.1] * 7) == (0.1, 0.1)  # exactly, not 0.09999999999999999


def test_interval_holds_the_mean_and_is_seeded():
    x = np.random.default_rng(42).normal(5.0, 1.0, 30)
    low, high = bootstrap_mean_ci(x)
    assert low < x.mean() < high
    assert 0.4 < high - low < 1.1  # about 2 x 1.96 / sqrt(30) = 0.72 for unit spread
    assert bootstrap_mean_ci(x) == (low, high)  # same seed, same numbers
    assert bootstrap_mean_ci(x, seed=1) != (low, high)
    assert bootstrap_mean_ci(np.r_[x, np.nan, np.inf]) == (low, high)  # non-finite values dropped first
    wider = bootstrap_mean_ci(x, confidence=0.99)
    assert wider[0] <= low and wider[1] >= high
    assert np.isnan(bootstrap_mean_ci([1.0])).all() and np.isnan(bootstrap_mean_ci([])).all()


def test_intervals_are_shift_equivariant_per_row():
    x = np.random.default_rng(3).normal(0.0, 1.0, 12)
    bounds = mean_intervals(np.stack([x, x + 2.0, np.full(12, np.nan)]))
    assert bounds.shape == (3, 2)
    assert bounds[1] == pytest.approx(bounds[0] + 2.0)  # the same resamples for every row of one size
    assert np.isnan(bounds[2]).all()


def test_wilcoxon_of_identical_columns_is_one_without_warnings():
    a = np.linspace(1.0, 2.0, 10)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert paired_wilcoxon(a, a) == 1.0
    assert paired_wilcoxon(a, np.r_[a[:9], np.nan]) == 1.0  # pairs with a NaN dropped
    assert np.isnan(paired_wilcoxon([np.nan, 1.0], [2.0, np.nan]))  # no pair at all


def test_wilcoxon_of_a_clear_shift_over_20_shapes():
    base = np.random.default_rng(0).uniform(1.0, 5.0, 20)
    shifted = base + 0.5 + np.random.default_rng(1).uniform(-0.1, 0.1, 20)
    p = paired_wilcoxon(shifted, base)
    assert p < 0.01 and p == pytest.approx(2 / 2**20)  # every difference positive: the exact extreme


def test_fewer_than_six_pairs_can_never_be_significant():
    best = np.arange(1.0, 7.0)
    p5, _, worse5 = against_best(np.stack([best[:5], best[:5] + 1.0]), 0, lower_is_better=True)
    p6, pairs, worse6 = against_best(np.stack([best, best + 1.0]), 0, lower_is_better=True)
    assert p5[1] == pytest.approx(2 / 2**5) and not worse5[1]  # 0.0625: the smallest p of 5 pairs
    assert p6[1] == pytest.approx(2 / 2**6) and worse6[1] and MIN_PAIRS == 6
    assert np.isnan(p6[0]) and list(pairs) == [6, 6]


def test_worse_needs_the_paired_differences_on_the_best_side():
    best = np.linspace(1.0, 2.0, 20)
    worse = best + 1.0
    better_on_ranks = best - 0.01
    better_on_ranks[0] += 100.0  # a worse mean (one disaster) but better on 19 of 20 shapes
    p, _, flag = against_best(np.stack([best, worse, better_on_ranks]), 0, lower_is_better=True)
    assert p[1] < 0.01 and flag[1]
    assert p[2] < 0.01 and not flag[2]  # significantly different, not significantly worse: a tie
    _, _, flag = against_best(np.stack([best, best - 1.0]), 0, lower_is_better=False)  # higher is better
    assert flag[1]


def test_tied_with_best_flags():
    bold, tied = tied_with_best([1.0, 1.0004, 2.0, 3.0, np.nan], [False, False, False, True, False],
                                lower_is_better=True)
    assert bold == [True, True, True, False, False]  # 1.0004 prints as the best; 2.0 is not worse; NaN never bold
    assert tied == [False, False, True, False, False]


# ---------------------------------------------------------------------------------------------
# In the tables
# ---------------------------------------------------------------------------------------------

SHAPES = [f"part{i:02d}" for i in range(20)]


def noisy_run() -> pd.DataFrame:
    """20 shapes x 3 methods x 2 seeds (seed values v -+ 1e-4, so the seed mean is v).

    a: cd = 4e-3 + 1e-4 i; b: a + 5e-4 (-1)^(i+1) (1 + 0.01 i), a mean 2.5e-6 worse but differences of
    both signs (signed ranks 110 against 100: p ~ 0.8); c: a + 2e-3 on every shape (p = 2 / 2^20)."""
    i = np.arange(20)
    a = 4e-3 + 1e-4 * i
    cd = {"a": a, "b": a + 5e-4 * (-1.0) ** (i + 1) * (1 + 0.01 * i), "c": a + 2e-3}
    rows = [dict(shape=s, method=m, seed=seed, status="ok", error=None, cd=v[k] + (2 * seed - 1) * 1e-4,
                 nc=0.9, f1_005=0.5, f1_01=0.8, ecd=0.02, ef1=0.5, ecd_flag=False, empty_prediction=0)
            for m, v in cd.items() for k, s in enumerate(SHAPES) for seed in (0, 1)]
    return pd.DataFrame(rows)


@pytest.fixture(scope="module")
def noisy(tmp_path_factory):
    context = dict(CONTEXT, methods=["a", "b", "c"], shapes=SHAPES, seeds=[0, 1])
    summary = build_summary(noisy_run(), None, context)
    return summary, write_summary(summary, context, tmp_path_factory.mktemp("noisy"))


def test_noise_is_a_tie_and_a_consistent_difference_a_win(noisy):
    summary, paths = noisy
    text = paths["summary.md"].read_text()
    mean = md_tables(text)["Mean over shapes and seeds"]
    col = mean[0].index("CD ×1e3 ↓")
    cells = {r[0]: r[col] for r in mean[1:]}
    assert cells["a"].startswith("**4.950** ") and cells["b"].startswith("**4.953†** ")  # a tie, marked
    assert cells["c"].startswith("6.950 ")  # clearly worse: not bold
    assert "tied by construction" not in text  # 20 shapes: the test can separate them
    tex = table_latex(summary.tables["mean"])
    assert r"\textbf{4.950}\,{\scriptsize [" in tex and r"\textbf{4.953$^{\dagger}$}\,{\scriptsize [" in tex
    assert r"& 6.950\,{\scriptsize [" in tex
    html = table_html(summary.tables["mean"])
    assert '<td class="r best">4.953† <span class="muted">[' in html and '<td class="r">6.950 <span' in html
    median = md_tables(text)["Median over shapes and seeds"]
    # the same rule by median: b has the best median (4.9225) and a ties with it
    assert [r[col] for r in median[1:]] == ["**4.950†**", f"**{summary.stats.values['median'].at['b', 'cd']:.3f}**",
                                            "6.950"]


def test_statistics_csv_holds_intervals_and_p_values(noisy):
    summary, paths = noisy
    stats = pd.read_csv(paths["statistics.csv"])
    assert list(stats.columns) == ["method", "metric", "scale", "shapes", "mean", "ci_low", "ci_high", "median", "std",
                                   "pairs", "p_vs_best", "bold", "tied"]
    cd = stats[stats["metric"] == "cd"].set_index("method")
    assert list(cd["shapes"]) == [20, 20, 20] and list(cd["pairs"]) == [20, 20, 20]  # seeds averaged per shape
    assert np.isnan(cd.at["a", "p_vs_best"]) and cd.at["b", "p_vs_best"] > 0.5 and cd.at["c", "p_vs_best"] < 0.01
    assert list(cd["bold"]) == [True, True, False] and list(cd["tied"]) == [False, True, False]
    assert cd.at["a", "ci_low"] < cd.at["a", "mean"] < cd.at["a", "ci_high"]
    # c is a shifted by 2 on every shape: the same resamples give the same interval, shifted
    assert cd.at["c", "ci_low"] == pytest.approx(cd.at["a", "ci_low"] + 2.0, abs=1e-5)
    nc = stats[stats["metric"] == "nc"].set_index("method")
    assert list(nc["bold"]) == [True, True, True] and list(nc["ci_low"]) == pytest.approx([0.9] * 3)
    # the frame is the function's, written as is
    assert len(statistics_frame(summary.stats, summary.metrics)) == len(stats) == 3 * len(summary.metrics)
