"""The intervals over seeds cover the true mean as often as they say they do (about 95%),
at the seed counts the reports use: simulated on normal and on skewed returns."""

import numpy as np
import pytest

from replicate.stats import paired_mean_difference, t_mean, welch_mean_difference

TRIALS = 4000
DISTRIBUTIONS = {
    "normal": (lambda rng, size: rng.normal(1000.0, 300.0, size), 1000.0),
    # right-skewed like returns where a few seeds take off (skewness about 1.75)
    "lognormal": (lambda rng, size: rng.lognormal(7.0, 0.5, size), float(np.exp(7.125))),
}


def _coverage(draw, truth, n, interval, seed):
    rng = np.random.default_rng(seed)
    hits = 0
    for _ in range(TRIALS):
        est = interval(draw, rng, n)
        hits += est.low <= truth <= est.high
    return hits / TRIALS


@pytest.mark.parametrize("name", list(DISTRIBUTIONS))
@pytest.mark.parametrize("n", [3, 5, 10])
def test_t_interval_of_a_mean_covers(name, n):
    draw, truth = DISTRIBUTIONS[name]
    coverage = _coverage(draw, truth, n, lambda d, rng, k: t_mean(d(rng, k)), seed=n)
    assert coverage >= 0.9, coverage


@pytest.mark.parametrize("n", [3, 5, 10])
def test_paired_and_welch_differences_cover(n):
    draw, _ = DISTRIBUTIONS["lognormal"]

    def paired(d, rng, k):
        shared = d(rng, k)  # a seed's luck, common to both runs of the pair
        return paired_mean_difference(shared + 100.0 + d(rng, k) * 0.2, shared + d(rng, k) * 0.2)

    def welch(d, rng, k):
        return welch_mean_difference(d(rng, k) + 100.0, d(rng, k))

    assert _coverage(draw, 100.0, n, paired, seed=10 + n) >= 0.9
    assert _coverage(draw, 100.0, n, welch, seed=20 + n) >= 0.9


def test_the_percentile_bootstrap_it_replaces_undercovers_at_three_seeds():
    """Why the t-interval: at n = 3 a percentile bootstrap is at most the seeds' range."""
    from scipy import stats

    rng = np.random.default_rng(0)
    hits = 0
    trials = 400
    for _ in range(trials):
        x = rng.normal(size=3)
        ci = stats.bootstrap(
            (x,), np.mean, method="percentile", n_resamples=500, rng=rng
        ).confidence_interval
        hits += ci.low <= 0 <= ci.high
    assert hits / trials < 0.85
