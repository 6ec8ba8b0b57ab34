"""The harness's statistics against rliable (test-only reference) on the same inputs.

Point estimates must agree exactly; bootstrap intervals within Monte-Carlo error. rliable
draws from numpy's global RNG; the harness only from the Generator it is given.
"""

import numpy as np
import pytest
from rliable import library as rly
from rliable import metrics

from replicate import stats

REPS = 4000


@pytest.fixture
def scores():
    rng = np.random.default_rng(0)
    return {"a": rng.normal(0.6, 0.3, size=(10, 4)), "b": rng.normal(0.4, 0.3, size=(10, 4))}


def test_point_estimates_equal_rliables(scores):
    x = scores["a"]
    assert stats.mean_score(x) == pytest.approx(metrics.aggregate_mean(x))
    assert stats.median_score(x) == pytest.approx(metrics.aggregate_median(x))
    assert stats.interquartile_mean(x) == pytest.approx(metrics.aggregate_iqm(x))
    assert stats.optimality_gap(x) == pytest.approx(metrics.aggregate_optimality_gap(x))
    assert stats.probability_of_improvement(x, scores["b"]) == pytest.approx(
        metrics.probability_of_improvement(x, scores["b"])
    )


def interval_width_tolerance(low, high):
    return 0.15 * (high - low)  # Monte-Carlo error of percentile bounds at these sizes


@pytest.mark.parametrize(
    "name, ours, theirs",
    [
        ("iqm", stats.interquartile_mean, metrics.aggregate_iqm),
        ("mean", stats.mean_score, metrics.aggregate_mean),
        ("gap", stats.optimality_gap, metrics.aggregate_optimality_gap),
    ],
)
def test_stratified_bootstrap_intervals_agree(scores, name, ours, theirs):
    np.random.seed(1)
    _, theirs_ci = rly.get_interval_estimates(
        {"a": scores["a"]}, lambda s: np.array([theirs(s)]), reps=REPS
    )
    low, high = theirs_ci["a"][:, 0]
    mine = stats.stratified_bootstrap_ci(
        ours, (scores["a"],), np.random.default_rng(2), n_resamples=REPS
    )
    tol = interval_width_tolerance(low, high)
    assert float(mine.low) == pytest.approx(low, abs=tol)
    assert float(mine.high) == pytest.approx(high, abs=tol)


def test_probability_of_improvement_interval_agrees(scores):
    np.random.seed(3)
    _, theirs_ci = rly.get_interval_estimates(
        {"a,b": (scores["a"], scores["b"])}, metrics.probability_of_improvement, reps=REPS
    )
    low, high = np.ravel(theirs_ci["a,b"])
    mine = stats.stratified_bootstrap_ci(
        stats.probability_of_improvement,
        (scores["a"], scores["b"]),
        np.random.default_rng(4),
        n_resamples=REPS,
    )
    tol = interval_width_tolerance(low, high)
    assert float(mine.low) == pytest.approx(low, abs=tol)
    assert float(mine.high) == pytest.approx(high, abs=tol)


def test_performance_profile_agrees(scores):
    taus = np.linspace(0.0, 1.2, 7)
    np.random.seed(5)
    theirs, theirs_ci = rly.create_performance_profile({"a": scores["a"]}, taus, reps=REPS)
    assert np.allclose(stats.score_profile(scores["a"], taus), theirs["a"])
    mine = stats.stratified_bootstrap_ci(
        lambda s: stats.score_profile(s, taus),
        (scores["a"],),
        np.random.default_rng(6),
        n_resamples=REPS,
    )
    low, high = theirs_ci["a"]
    assert np.all(np.abs(mine.low - low) <= 0.08) and np.all(np.abs(mine.high - high) <= 0.08)


def test_harness_never_touches_the_global_rng(scores):
    np.random.seed(7)
    before = np.random.get_state()[1].copy()
    stats.stratified_bootstrap_ci(
        stats.interquartile_mean, (scores["a"],), np.random.default_rng(0), n_resamples=50
    )
    stats.paired_mean_difference(scores["a"][:, 0], scores["b"][:, 0])
    assert np.array_equal(np.random.get_state()[1], before)
