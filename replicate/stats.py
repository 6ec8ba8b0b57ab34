"""Statistics over runs: small pure functions of arrays, each with an explicit Generator.

Arrays are (runs, points): one row per seed, one column per evaluation point (or a single
column of final returns). No function touches a global random state.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy import stats

CONFIDENCE = 0.95
N_BOOTSTRAP = 2000


@dataclass(frozen=True)
class Estimate:
    """A point estimate with its confidence interval (arrays broadcast per column)."""

    value: np.ndarray
    low: np.ndarray
    high: np.ndarray


def bootstrap_mean(scores: np.ndarray, rng: np.random.Generator,
                   confidence: float = CONFIDENCE, n_resamples: int = N_BOOTSTRAP) -> Estimate:
    """Mean over runs (axis 0) with a percentile-bootstrap confidence interval per column.

    With a single run the interval is undefined and returned as NaN.
    """
    scores = np.asarray(scores, dtype=float)
    if scores.ndim == 1:
        scores = scores[:, None]  # a vector is one column of runs
    mean = scores.mean(axis=0)
    if scores.shape[0] < 2:
        nan = np.full_like(mean, np.nan)
        return Estimate(mean, nan, nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # constant columns (e.g. all zeros) are fine: CI = value
        result = stats.bootstrap((scores,), np.mean, axis=0, confidence_level=confidence,
                                 n_resamples=n_resamples, method="percentile", rng=rng)
    low = np.minimum(result.confidence_interval.low, mean)
    high = np.maximum(result.confidence_interval.high, mean)
    return Estimate(mean, low, high)


def bootstrap_mean_difference(a: np.ndarray, b: np.ndarray, rng: np.random.Generator,
                              confidence: float = CONFIDENCE,
                              n_resamples: int = N_BOOTSTRAP) -> Estimate:
    """mean(a) - mean(b) for two independent samples, with a percentile-bootstrap CI
    (each sample resampled within itself)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    diff = np.array(a.mean() - b.mean())
    if len(a) < 2 or len(b) < 2:
        return Estimate(diff, np.array(np.nan), np.array(np.nan))

    def statistic(x, y, axis=-1):
        return np.mean(x, axis=axis) - np.mean(y, axis=axis)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = stats.bootstrap((a, b), statistic, confidence_level=confidence,
                                 n_resamples=n_resamples, method="percentile", rng=rng)
    return Estimate(diff, np.array(min(result.confidence_interval.low, diff)),
                    np.array(max(result.confidence_interval.high, diff)))


def welch_test(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """Welch's t statistic and two-sided p-value; NaN when either sample has < 2 runs
    or both are constant."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    if len(a) < 2 or len(b) < 2 or (np.ptp(a) == 0 and np.ptp(b) == 0):
        return float("nan"), float("nan")
    result = stats.ttest_ind(a, b, equal_var=False)
    return float(result.statistic), float(result.pvalue)
