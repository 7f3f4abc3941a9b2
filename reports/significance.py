"""Confidence intervals and paired tests behind every method-comparison table: arrays in, arrays out.

The tables (:mod:`reports.statistics`) hold a method's mean over shapes x seeds; whether that mean
beats another method's is a question about the shapes, so both tools here work on one value per
shape (the mean over the shape's seeds, NaN where the shape has none):

* :func:`bootstrap_mean_ci`: the 95% percentile-bootstrap confidence interval of the mean over
  shapes (``scipy.stats.bootstrap``, 2,000 resamples of the shapes, a fixed seed: the same values
  give the same interval, in any table and any order of rows).
* :func:`paired_wilcoxon`: the two-sided Wilcoxon signed-rank test of two methods over the shapes
  both have (``scipy.stats.wilcoxon``; zero differences dropped, all-zero differences: p = 1, "no
  difference").
* :func:`against_best`: every row of a (rows x shapes) matrix against the row of the best
  statistic: p, number of paired shapes, and whether the row is significantly *worse* (p <
  :data:`ALPHA` and the signed ranks on the best's side).

The convention the tables take from this (:func:`tied_with_best`): bold is the best of a column and
every method not significantly worse than it, so a difference inside the noise reads as a tie,
never as a win. With fewer than :data:`MIN_PAIRS` paired shapes a two-sided signed-rank test cannot
reach p < 0.05 (its smallest p is 2 / 2^n), so such a method always ties; the tables say so.
"""

from __future__ import annotations

import numpy as np
from scipy import stats

from reports.table import DIGITS, best_flags

CONFIDENCE = 0.95
N_RESAMPLES = 2000
SEED = 0
ALPHA = 0.05
#: The fewest paired shapes at which the two-sided exact signed-rank test can give p < ALPHA (2 / 2**6).
MIN_PAIRS = 6


def bootstrap_mean_ci(values, confidence: float = CONFIDENCE, n_resamples: int = N_RESAMPLES,
                      seed: int = SEED) -> tuple[float, float]:
    """(low, high) percentile-bootstrap interval of the mean of the finite ``values``.

    NaN are dropped first; (NaN, NaN) with fewer than 2 values left. A constant sample gives
    exactly (c, c): the interval is clipped to the sample's range, where every resampled mean lies.
    """
    x = np.asarray(values, dtype=float).ravel()
    x = x[np.isfinite(x)]
    if len(x) < 2:
        return np.nan, np.nan
    # random_state (not rng): the keyword every scipy the project admits (>= 1.11) understands
    ci = stats.bootstrap((x,), np.mean, n_resamples=n_resamples, confidence_level=confidence, method="percentile",
                         vectorized=True, random_state=np.random.default_rng(seed)).confidence_interval
    low, high = np.clip([ci.low, ci.high], x.min(), x.max())
    return float(low), float(high)


def mean_intervals(matrix, **options) -> np.ndarray:
    """(rows, 2) :func:`bootstrap_mean_ci` of each row of ``matrix`` (rows x shapes, NaN = no value);
    ``options`` as its keywords."""
    return np.array([bootstrap_mean_ci(row, **options) for row in np.asarray(matrix, dtype=float)]).reshape(-1, 2)


def _differences(a, b) -> np.ndarray:
    """a - b over the positions where both are finite."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    keep = np.isfinite(a) & np.isfinite(b)
    return a[keep] - b[keep]


def paired_wilcoxon(a, b) -> float:
    """Two-sided Wilcoxon signed-rank p of the paired samples ``a``, ``b`` (over the positions where
    both are finite); 1.0 when every difference is zero, NaN when there is no pair."""
    d = _differences(a, b)
    if not len(d):
        return np.nan
    if not np.any(d):  # no difference at all: scipy would divide by a zero variance
        return 1.0
    return float(stats.wilcoxon(d).pvalue)


def _signed_rank_sum(d: np.ndarray) -> float:
    """Sum of the signed ranks of |d| (zeros dropped): > 0 when the positive differences dominate."""
    d = d[d != 0]
    return float(np.sum(np.sign(d) * stats.rankdata(np.abs(d)))) if len(d) else 0.0


def against_best(matrix, best: int, lower_is_better: bool, alpha: float = ALPHA):
    """Each row of ``matrix`` (rows x shapes, NaN = no value) against row ``best``, paired by column.

    Returns
    -------
    p : (rows,) two-sided :func:`paired_wilcoxon` p; NaN for ``best`` itself and rows without a pair.
    pairs : (rows,) int, the shapes a row shares with ``best``.
    worse : (rows,) bool, p < ``alpha`` and the signed ranks on the best's side (the row higher when
        lower is better, lower otherwise).
    """
    m = np.asarray(matrix, dtype=float)
    p = np.array([paired_wilcoxon(row, m[best]) for row in m])
    p[best] = np.nan
    pairs = (np.isfinite(m) & np.isfinite(m[best])).sum(axis=1)
    side = np.array([_signed_rank_sum(_differences(row, m[best])) for row in m]) * (1 if lower_is_better else -1)
    return p, pairs, (p < alpha) & (side > 0)


def tied_with_best(center, worse, lower_is_better: bool, digits: int = DIGITS) -> tuple[list[bool], list[bool]]:
    """(bold, tied) flags of a column: bold is the best of the finite ``center`` values at the printed
    precision and every other finite one not significantly ``worse``; tied marks the bold ones that
    are not the best themselves."""
    best = best_flags(list(center), lower_is_better, digits)
    bold = [b or (bool(np.isfinite(c)) and not w) for b, c, w in zip(best, center, worse)]
    return bold, [x and not b for x, b in zip(bold, best)]

