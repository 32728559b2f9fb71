r"""Effect sizes of the within-subject tests, with seeded bootstrap 95 % intervals.

- **Matched-pairs rank-biserial correlation** of a Wilcoxon signed-rank test (Kerby 2014,
  "The simple difference formula", Compr. Psychol. 3): with ``d = a − b`` per participant, zero
  differences dropped (as ``scipy.stats.wilcoxon``'s default), ``T+`` / ``T−`` the sums of the
  ranks of ``|d|`` over positive / negative ``d``,

  .. math:: r = \frac{T_+ - T_-}{T_+ + T_-} \in [-1, 1];

  ``r > 0``: condition ``a``'s errors are the larger ones.
- **Kendall's W** of a Friedman test (the coefficient of concordance, tie-corrected through the
  Friedman statistic): :math:`W = \chi^2_F / (n (k - 1)) \in [0, 1]`, n participants,
  k conditions; 0 = the conditions' ranks differ by chance alone, 1 = every participant ranks
  the conditions the same way.

The intervals are percentile bootstraps that resample **participants** (assessors) with
replacement: they are the independent units of a within-subject design, and a participant's k
errors stay together. The generator is ``numpy.random.default_rng(seed)``; every resample's
statistic is computed in one vectorised pass.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import stats

BOOTSTRAP_RESAMPLES = 2000  # default number of bootstrap resamples
BOOTSTRAP_SEED = 0  # default seed of the bootstrap generator
CI_LEVEL = 0.95  # coverage of every interval
MIN_FINITE_SHARE = 0.5  # an interval needs at least this share of defined resamples


def percentile_ci(
    samples: NDArray[np.float64], min_share: float = MIN_FINITE_SHARE
) -> tuple[float, float] | None:
    """The 95 % percentile interval of bootstrap statistics; None if too few are defined.

    samples : (B,) float array; NaN marks a resample where the statistic is undefined.
    min_share : the share of defined resamples an interval needs (0: any one will do).
    """
    finite = samples[np.isfinite(samples)]
    if finite.size == 0 or finite.size < min_share * samples.size:
        return None
    tail = 100.0 * (1.0 - CI_LEVEL) / 2.0
    lo, hi = np.percentile(finite, [tail, 100.0 - tail])
    return float(lo), float(hi)


def resample_indices(n: int, resamples: int, seed: int) -> NDArray[np.intp]:
    """(resamples, n) indices drawn with replacement from ``0..n-1`` (``default_rng(seed)``)."""
    if n < 1 or resamples < 1:
        raise ValueError(f"n and resamples must be >= 1, got {n}, {resamples}")
    return np.random.default_rng(seed).integers(0, n, size=(resamples, n))


def rank_biserial(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """Matched-pairs rank-biserial correlation of ``a`` against ``b`` along the last axis.

    Parameters
    ----------
    a, b : (..., n) float arrays
        Paired values (errors of the same participants in two conditions), touches.

    Returns
    -------
    (...) float array
        ``r`` (module docstring); NaN where every difference is zero.
    """
    d = np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64)
    # Ranking |d| with the zeros included gives the zeros the lowest (tied) ranks; every other
    # rank is then its rank among the non-zero |d| plus the number of zeros.
    zeros = np.sum(d == 0.0, axis=-1, keepdims=True)
    ranks = stats.rankdata(np.abs(d), axis=-1) - zeros
    t_plus = np.sum(np.where(d > 0.0, ranks, 0.0), axis=-1)
    t_minus = np.sum(np.where(d < 0.0, ranks, 0.0), axis=-1)
    total = t_plus + t_minus
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(total > 0.0, (t_plus - t_minus) / total, np.nan)


def kendall_w(errors: NDArray[np.float64]) -> NDArray[np.float64]:
    r"""Kendall's W of ``errors`` (participants × conditions), tie-corrected as Friedman's χ².

    Parameters
    ----------
    errors : (..., n, k) float array
        n participants' errors in k ≥ 2 conditions.

    Returns
    -------
    (...) float array
        :math:`W = \chi^2_F / (n (k-1))`, with
        :math:`\chi^2_F = [12/(n k (k+1)) \sum_j R_j^2 - 3 n (k+1)] / c`,
        :math:`c = 1 - \sum (t^3 - t) / (n k (k^2 - 1))` over the tie groups t of each row;
        NaN where every row is one tie (c = 0).
    """
    x = np.asarray(errors, dtype=np.float64)
    n, k = x.shape[-2], x.shape[-1]
    ranks = stats.rankdata(x, axis=-1)
    rank_sums = ranks.sum(axis=-2)
    chi2 = 12.0 / (n * k * (k + 1)) * np.sum(rank_sums**2, axis=-1) - 3.0 * n * (k + 1)
    # tie groups per row: sum over values of (t^3 - t); count equal pairs through sorting
    srt = np.sort(x, axis=-1)
    ties = np.zeros(x.shape[:-1])
    run = np.ones(x.shape[:-1])
    for j in range(1, k):
        same = srt[..., j] == srt[..., j - 1]
        ties += np.where(same, 0.0, run**3 - run)
        run = np.where(same, run + 1.0, 1.0)
    ties += run**3 - run
    c = 1.0 - ties.sum(axis=-1) / (n * k * (k * k - 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(c > 0.0, chi2 / c / (n * (k - 1)), np.nan)
