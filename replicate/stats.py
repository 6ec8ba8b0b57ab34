"""Statistics over runs: small pure functions of arrays, each with an explicit Generator.

Arrays are (runs, points): one row per seed, one column per evaluation point (or a single
column of final returns). No function touches a global random state.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import stats

CONFIDENCE = 0.95
N_BOOTSTRAP = 2000


def substream(seed: int, *keys: str) -> np.random.Generator:
    """A bootstrap stream of its own for one cell of a report (``keys``: env, algorithm,
    statistic), so that adding other cells to a report leaves this cell's interval as it was."""
    return np.random.default_rng([seed, *(zlib.crc32(key.encode()) for key in keys)])


@dataclass(frozen=True)
class Estimate:
    """A point estimate with its confidence interval (arrays broadcast per column)."""

    value: np.ndarray
    low: np.ndarray
    high: np.ndarray


# Means over seeds use Student's t. With 3-5 seeds a percentile bootstrap can only return
# the seeds' range (it covers the mean about 76-83% of the time for a nominal 95%); the
# t-interval is exact for normal seeds and stays near nominal under moderate skew
# (tests/test_stats_coverage.py simulates both). Aggregates over many runs and tasks keep
# the stratified bootstrap below.
T_METHOD = "t-interval"
PAIRED_METHOD = "paired t-interval"
WELCH_METHOD = "Welch t-interval"


@dataclass(frozen=True)
class MeanEstimate:
    """One quantity: a mean over seeds (or of per-seed differences) with its interval, the
    method and sample size that produced it, and what its tests need (standard error and
    degrees of freedom). Every check, effect line, summary and sentence that states the
    quantity reads this one object."""

    quantity: str
    value: float
    low: float
    high: float
    method: str
    n: int  # runs, or pairs for a paired difference
    se: float  # standard error of ``value``; 0 when every seed (or difference) is equal
    df: float
    n_other: int | None = None  # Welch: the second group's runs
    confidence: float = CONFIDENCE
    variances: tuple[float, float] | None = None  # Welch: each group's per-seed variance

    @property
    def label(self) -> str:
        """E.g. '95% paired t-interval, 4 pairs'."""
        if self.method == PAIRED_METHOD:
            size = f"{self.n} pair" + ("s" if self.n != 1 else "")
        elif self.n_other is not None:
            size = f"{self.n} vs {self.n_other} seeds"
        else:
            size = f"n = {self.n}"
        return f"{self.confidence:.0%} {self.method}, {size}"

    @property
    def defined(self) -> bool:
        return bool(np.isfinite(self.low) and np.isfinite(self.high))

    def p_above(self, threshold: float) -> float:
        """One-sided p-value against 'the true value is at most ``threshold``'."""
        return _one_sided_p(self.value - threshold, self.se, self.df)

    def p_below(self, threshold: float) -> float:
        """One-sided p-value against 'the true value is at least ``threshold``'."""
        return _one_sided_p(threshold - self.value, self.se, self.df)

    @property
    def p_two_sided(self) -> float:
        """Two-sided p-value of 'the true value is 0' (t-test); NaN where it is undefined
        (fewer than 2 runs, or no spread: a constant group proves nothing by a t-test)."""
        if not np.isfinite(self.se) or self.se == 0:
            return float("nan")
        return float(2 * stats.t.sf(abs(self.value) / self.se, self.df))

    @property
    def test(self) -> str:
        """The test of 0 in words, with its p-value or why there is none."""
        name = {PAIRED_METHOD: "paired t-test", WELCH_METHOD: "Welch t-test"}.get(
            self.method, "one-sample t-test"
        )
        if self.n < 2 or (self.n_other is not None and self.n_other < 2):
            return f"no {name}: fewer than 2 runs"
        if self.se == 0:
            what = "paired difference" if self.method == PAIRED_METHOD else "run"
            return f"no {name}: every {what} is {self.value:.4g}, no spread to test"
        return f"{name} p = {self.p_two_sided:.2g}"

    def as_dict(self) -> dict[str, Any]:
        return {
            "quantity": self.quantity,
            "value": self.value,
            "low": self.low,
            "high": self.high,
            "method": self.label,
            "n": self.n,
            "n_other": self.n_other,
            "test": self.test,
            "p_value": self.p_two_sided,
        }


def _one_sided_p(margin: float, se: float, df: float) -> float:
    """P(T >= margin / se) under Student's t; a zero standard error decides by the sign."""
    if not np.isfinite(se) or not np.isfinite(df):
        return float("nan")
    if se == 0:
        return 0.0 if margin > 0 else 1.0
    return float(stats.t.sf(margin / se, df))


def _t_bounds(value: float, se: float, df: float, confidence: float) -> tuple[float, float]:
    if not np.isfinite(se) or not np.isfinite(df):
        return float("nan"), float("nan")
    half = float(stats.t.ppf(0.5 + confidence / 2, df)) * se if se > 0 else 0.0
    return value - half, value + half


def t_mean(
    values: np.ndarray, quantity: str = "", confidence: float = CONFIDENCE, method: str = T_METHOD
) -> MeanEstimate:
    """Mean over runs with a Student-t interval; with a single run the interval is NaN."""
    values = np.asarray(values, dtype=float).ravel()
    n = len(values)
    value = float(values.mean()) if n else float("nan")
    if n < 2:
        return MeanEstimate(
            quantity,
            value,
            float("nan"),
            float("nan"),
            method,
            n,
            float("nan"),
            float("nan"),
            confidence=confidence,
        )
    se = float(values.std(ddof=1) / np.sqrt(n))
    low, high = _t_bounds(value, se, n - 1, confidence)
    return MeanEstimate(
        quantity, value, low, high, method, n, se, float(n - 1), confidence=confidence
    )


def paired_mean_difference(
    a: np.ndarray, b: np.ndarray, quantity: str = "", confidence: float = CONFIDENCE
) -> MeanEstimate:
    """Mean of a_i - b_i over runs that share seed i (and so initial weights), with a
    t-interval on the per-seed differences."""
    diffs = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    return t_mean(diffs, quantity, confidence, PAIRED_METHOD)


def welch_mean_difference(
    a: np.ndarray, b: np.ndarray, quantity: str = "", confidence: float = CONFIDENCE
) -> MeanEstimate:
    """mean(a) - mean(b) for runs that share nothing, with a Welch t-interval
    (Welch-Satterthwaite degrees of freedom)."""
    a, b = np.asarray(a, dtype=float).ravel(), np.asarray(b, dtype=float).ravel()
    value = float(a.mean() - b.mean())
    if len(a) < 2 or len(b) < 2:
        return MeanEstimate(
            quantity,
            value,
            float("nan"),
            float("nan"),
            WELCH_METHOD,
            len(a),
            float("nan"),
            float("nan"),
            len(b),
            confidence,
        )
    va, vb = a.var(ddof=1) / len(a), b.var(ddof=1) / len(b)
    se = float(np.sqrt(va + vb))
    if se == 0:
        df = float(len(a) + len(b) - 2)
    else:  # a constant group contributes no variance and no degrees of freedom
        df = float((va + vb) ** 2 / ((va**2 / (len(a) - 1)) + (vb**2 / (len(b) - 1))))
    low, high = _t_bounds(value, se, df, confidence)
    variances = (float(a.var(ddof=1)), float(b.var(ddof=1)))
    return MeanEstimate(
        quantity, value, low, high, WELCH_METHOD, len(a), se, df, len(b), confidence, variances
    )


def seed_matched_difference(
    a: dict[int, float],
    b: dict[int, float],
    quantity: str = "",
    pair: bool = False,
    confidence: float = CONFIDENCE,
) -> MeanEstimate:
    """mean(a) - mean(b) over runs keyed by seed: paired over the shared seeds when ``pair``
    (the two algorithms share initial weights seed by seed by design), Welch over every run
    of each otherwise. Equal seed numbers alone do not pair two runs: unrelated algorithms
    started from the same seed share no weights, and matching them would make the interval
    depend on an arbitrary matching."""
    if pair:
        common = sorted(set(a) & set(b))
        return paired_mean_difference(
            np.array([a[s] for s in common]), np.array([b[s] for s in common]), quantity, confidence
        )
    return welch_mean_difference(
        np.array([a[s] for s in sorted(a)]),
        np.array([b[s] for s in sorted(b)]),
        quantity,
        confidence,
    )


def t_mean_columns(scores: np.ndarray, confidence: float = CONFIDENCE) -> Estimate:
    """Per column of a (runs, points) matrix, the mean over runs with its t-interval (the
    band of a learning curve); NaN bounds with a single run."""
    scores = np.asarray(scores, dtype=float)
    if scores.ndim == 1:
        scores = scores[:, None]
    mean = scores.mean(axis=0)
    n = scores.shape[0]
    if n < 2:
        nan = np.full_like(mean, np.nan)
        return Estimate(mean, nan, nan)
    half = stats.t.ppf(0.5 + confidence / 2, n - 1) * scores.std(axis=0, ddof=1) / np.sqrt(n)
    return Estimate(mean, mean - half, mean + half)


def holm(p_values: list[float]) -> list[float]:
    """Holm's step-down adjusted p-values (family-wise error control); NaN stays NaN and
    does not count towards the family."""
    p = np.asarray(p_values, dtype=float)
    finite = np.flatnonzero(np.isfinite(p))
    adjusted = np.full(len(p), np.nan)
    m = len(finite)
    running = 0.0
    for rank, index in enumerate(finite[np.argsort(p[finite], kind="stable")]):
        running = max(running, min(1.0, (m - rank) * p[index]))
        adjusted[index] = running
    return adjusted.tolist()


DECIDING_CHANCE = 0.8  # "what would decide it" asks for an 80% chance, not a coin flip


def _projected(estimate: MeanEstimate, n: int) -> tuple[float, float]:
    """Standard error and degrees of freedom of ``estimate`` at n seeds (per group; pairs
    for a paired difference), if each group's observed per-seed spread held."""
    if estimate.n_other is None:
        return estimate.se * np.sqrt(estimate.n / n), float(n - 1)
    va, vb = estimate.variances or (estimate.se**2 * estimate.n / 2,) * 2
    se = float(np.sqrt((va + vb) / n))
    if va + vb == 0:
        return se, float(2 * n - 2)
    return se, float((va + vb) ** 2 * (n - 1) / (va**2 + vb**2))  # Welch-Satterthwaite


def chance_to_decide(
    estimate: MeanEstimate, route: tuple[float, ...], n: int, confidence: float
) -> float:
    """The chance that every one-sided test of ``route`` rejects at n seeds (each at the
    one-sided level of a ``confidence`` interval), if the true value lay each distance in
    ``route`` beyond its bound and the observed spread held: noncentral t power, combined by
    Bonferroni's inequality (a lower bound) when the route needs two tests."""
    se, df = _projected(estimate, n)
    if se == 0:
        return 1.0
    critical = stats.t.ppf(0.5 + confidence / 2, df)
    misses = sum(1.0 - float(stats.nct.sf(critical, df, d / se)) for d in route)
    return max(0.0, 1.0 - misses)


def seeds_to_decide(
    estimate: MeanEstimate,
    routes: list[tuple[float, ...]],
    confidence: float | None = None,
    chance: float = DECIDING_CHANCE,
    limit: int = 200,
) -> int | None:
    """How many seeds (per group; pairs for a paired difference) would give the check a
    ``chance`` of being decided, if the observed mean and spread were the truth: the
    smallest n at which one of ``routes`` (the ways it could be decided, each the distances
    from the estimate to the bounds its tests must clear) reaches that chance. None when no
    n up to ``limit`` does, or the spread is unknown."""
    confidence = estimate.confidence if confidence is None else confidence
    routes = [r for r in routes if r and min(r) > 0]
    if not np.isfinite(estimate.se) or estimate.n < 2 or not routes:
        return None
    if estimate.se == 0:
        return estimate.n
    for n in range(2, limit + 1):
        if max(chance_to_decide(estimate, r, n, confidence) for r in routes) >= chance:
            return n
    return None


def _as_matrix(scores: np.ndarray) -> np.ndarray:
    """(runs, tasks); a vector is one task."""
    scores = np.asarray(scores, dtype=float)
    return scores.reshape(len(scores), -1)


# Aggregate metrics over a (runs, tasks) score matrix (Agarwal et al. 2021). Scores of
# different tasks must be normalised to a common scale before they are aggregated.


def mean_score(scores: np.ndarray) -> float:
    """Mean over tasks of the per-task mean over runs."""
    return float(np.mean(np.mean(scores, axis=0)))


def median_score(scores: np.ndarray) -> float:
    """Median over tasks of the per-task mean over runs."""
    return float(np.median(np.mean(scores, axis=0)))


def interquartile_mean(scores: np.ndarray) -> float:
    """IQM: the mean of the middle 50% of all run-task scores pooled together.

    ``scipy.stats.trim_mean(scores, 0.25, axis=None)``'s arithmetic, step for step (so the
    same bits), without its per-call dispatch: bootstraps call this about 2,000 times per
    interval, where scipy's wrapper took 0.7 ms a call."""
    pooled = np.ravel(np.asarray(scores, dtype=float))
    if pooled.size == 0 or np.isnan(pooled).any():  # scipy's nan_policy="propagate"
        return float("nan")
    cut = int(0.25 * pooled.size)
    middle = np.partition(pooled, (cut, pooled.size - cut - 1))[cut : pooled.size - cut]
    return float(np.mean(middle))


def optimality_gap(scores: np.ndarray, gamma: float = 1.0) -> float:
    """How far scores fall short of ``gamma`` on average (scores above it count as gamma)."""
    return float(gamma - np.mean(np.minimum(scores, gamma)))


def probability_of_improvement(x: np.ndarray, y: np.ndarray) -> float:
    """P(X > Y) + P(X = Y) / 2 for a random run of each, per task, averaged over tasks
    (the Mann-Whitney U statistic over n_x * n_y)."""
    x, y = _as_matrix(x), _as_matrix(y)
    per_task = []
    for task in range(x.shape[1]):
        greater = (x[:, task, None] > y[None, :, task]).mean()
        ties = (x[:, task, None] == y[None, :, task]).mean()
        per_task.append(greater + 0.5 * ties)
    return float(np.mean(per_task))


def score_profile(scores: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """Performance profile: for each tau, the fraction of runs scoring above tau, averaged
    over tasks."""
    scores = _as_matrix(scores)
    above = scores[None, :, :] > np.asarray(taus, dtype=float)[:, None, None]
    return above.mean(axis=1).mean(axis=1)


def _resample_runs(scores: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One stratified bootstrap sample: runs redrawn with replacement within each task."""
    n_runs, n_tasks = scores.shape
    rows = rng.integers(0, n_runs, size=(n_runs, n_tasks))
    return np.take_along_axis(scores, rows, axis=0)


def stratified_bootstrap_ci(
    statistic: Callable[..., Any],
    samples: tuple[np.ndarray, ...],
    rng: np.random.Generator,
    confidence: float = CONFIDENCE,
    n_resamples: int = N_BOOTSTRAP,
) -> Estimate:
    """Percentile CI of ``statistic(*samples)``; each (runs, tasks) sample is resampled
    within each task and independently of the others. The statistic may return an array."""
    samples = tuple(_as_matrix(s) for s in samples)
    value = np.asarray(statistic(*samples), dtype=float)
    draws = np.stack(
        [
            np.asarray(statistic(*(_resample_runs(s, rng) for s in samples)), dtype=float)
            for _ in range(n_resamples)
        ]
    )
    tail = 100 * (1 - confidence) / 2
    low, high = np.percentile(draws, [tail, 100 - tail], axis=0)
    return Estimate(value, np.minimum(low, value), np.maximum(high, value))


def hedges_g(a: np.ndarray, b: np.ndarray) -> float:
    """Standardised mean difference (a - b) / pooled sd with the small-sample correction;
    NaN when it is undefined (fewer than 2 runs each, or no spread at all)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    n_a, n_b = len(a), len(b)
    if n_a < 2 or n_b < 2:
        return float("nan")
    pooled = np.sqrt(((n_a - 1) * a.var(ddof=1) + (n_b - 1) * b.var(ddof=1)) / (n_a + n_b - 2))
    if pooled == 0:
        return float("nan")
    correction = 1 - 3 / (4 * (n_a + n_b) - 9)
    return float(correction * (a.mean() - b.mean()) / pooled)


def curve_area(steps: np.ndarray, curves: np.ndarray) -> np.ndarray:
    """Per run, the mean evaluation return over the run: the trapezoid area under its curve
    divided by the span of steps (rewards learning early as well as ending high)."""
    steps, curves = np.asarray(steps, float), np.atleast_2d(np.asarray(curves, float))
    if len(steps) < 2:
        return curves[:, -1].copy()
    return np.trapezoid(curves, steps, axis=1) / (steps[-1] - steps[0])


def steps_to_reach(steps: np.ndarray, curves: np.ndarray, level: float) -> np.ndarray:
    """Per run, the first evaluation step at which its return reaches ``level``; NaN for a
    run that never does within its curve."""
    steps, curves = np.asarray(steps, float), np.atleast_2d(np.asarray(curves, float))
    reached = curves >= level
    first = np.argmax(reached, axis=1)
    return np.where(reached.any(axis=1), steps[first], np.nan)
