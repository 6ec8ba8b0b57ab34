import numpy as np
import pytest

from replicate.stats import bootstrap_mean, bootstrap_mean_difference, welch_test


def test_bootstrap_mean_interval_contains_the_mean_and_is_reproducible():
    scores = np.random.default_rng(0).normal(size=(6, 4))
    a = bootstrap_mean(scores, np.random.default_rng(1))
    b = bootstrap_mean(scores, np.random.default_rng(1))
    np.testing.assert_allclose(a.value, scores.mean(0))
    assert np.all(a.low <= a.value) and np.all(a.value <= a.high) and np.all(a.low < a.high)
    np.testing.assert_array_equal(a.low, b.low)


def test_bootstrap_interval_narrows_with_more_runs():
    rng = np.random.default_rng(0)
    few = bootstrap_mean(rng.normal(size=5), np.random.default_rng(1))
    many = bootstrap_mean(rng.normal(size=500), np.random.default_rng(1))
    assert (many.high - many.low)[0] < (few.high - few.low)[0]


def test_constant_scores_give_a_zero_width_interval_and_one_run_none():
    const = bootstrap_mean(np.zeros((4, 3)), np.random.default_rng(0))
    np.testing.assert_array_equal(const.low, 0.0)
    np.testing.assert_array_equal(const.high, 0.0)
    single = bootstrap_mean(np.ones((1, 3)), np.random.default_rng(0))
    assert np.isnan(single.low).all()


def test_mean_difference_and_welch():
    a, b = np.array([10.0, 11.0, 12.0, 13.0]), np.array([0.0, 1.0, -1.0, 0.5])
    diff = bootstrap_mean_difference(a, b, np.random.default_rng(0))
    assert diff.value == a.mean() - b.mean() and diff.low > 5 and diff.high < 15
    t, p = welch_test(a, b)
    assert t > 0 and p < 0.01
    assert np.isnan(welch_test(np.zeros(3), np.zeros(3))[1])


def test_paired_difference_and_wilcoxon():
    from replicate.stats import paired_difference
    x = np.array([5.0, 6.0, 7.0, 8.0, 9.0, 10.0])
    estimate, p_value = paired_difference(x, x - 1.0, np.random.default_rng(0))
    assert estimate.value == 1.0 and estimate.low == 1.0 and estimate.high == 1.0
    assert p_value < 0.05
    _, undefined = paired_difference(x, x, np.random.default_rng(0))
    assert np.isnan(undefined)


def test_hedges_g_hand_computed():
    from replicate.stats import hedges_g
    a, b = np.array([1.0, 2.0, 3.0]), np.array([3.0, 4.0, 5.0])
    # pooled sd 1, raw difference -2, correction 1 - 3 / (4 * 6 - 9) = 0.8
    assert hedges_g(a, b) == pytest.approx(-1.6)
    assert np.isnan(hedges_g(a[:1], b))


def test_iqm_and_profile_hand_computed():
    from replicate.stats import interquartile_mean, optimality_gap, score_profile
    scores = np.array([[0.0], [1.0], [2.0], [3.0], [4.0], [5.0], [6.0], [100.0]])
    assert interquartile_mean(scores) == pytest.approx(3.5)  # mean of 2, 3, 4, 5
    assert score_profile(scores, np.array([2.5, 50.0])).tolist() == [5 / 8, 1 / 8]
    assert optimality_gap(np.array([[0.5], [1.5]])) == pytest.approx(0.25)


def test_iqm_is_scipys_trimmed_mean_to_the_last_bit():
    from scipy import stats

    from replicate.stats import interquartile_mean
    rng = np.random.default_rng(3)
    for runs, tasks in [(1, 1), (2, 1), (3, 2), (5, 3), (7, 4), (10, 1), (50, 5)]:
        scores = rng.normal(size=(runs, tasks)) * 10 ** rng.uniform(-3, 4)
        assert interquartile_mean(scores) == float(stats.trim_mean(scores, 0.25, axis=None))
    assert np.isnan(interquartile_mean(np.zeros((0, 2))))
    for where in (0, 7):  # a NaN anywhere, even among the cut quarters, makes it NaN
        scores = np.arange(8.0)
        scores[where] = np.nan
        assert np.isnan(interquartile_mean(scores))
        assert np.isnan(stats.trim_mean(scores, 0.25, axis=None))


def test_curve_area_and_steps_to_reach_hand_computed():
    from replicate.stats import curve_area, steps_to_reach

    steps = np.array([0, 100, 300])
    curves = np.array([[0.0, 10.0, 10.0], [0.0, 0.0, 30.0]])
    # trapezoids over 300 steps: (100 * 5 + 200 * 10) / 300 and (200 * 15) / 300
    np.testing.assert_allclose(curve_area(steps, curves), [2500 / 300, 10.0])
    reach = steps_to_reach(steps, curves, 10.0)
    assert reach[0] == 100 and reach[1] == 300
    assert np.isnan(steps_to_reach(steps, curves, 50.0)).all()  # never reached: no value
