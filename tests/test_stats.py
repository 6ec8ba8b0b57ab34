import numpy as np
import pytest
from scipy import stats as scipy_stats

from replicate.stats import (
    holm,
    paired_mean_difference,
    seed_matched_difference,
    seeds_to_decide,
    t_mean,
    t_mean_columns,
    welch_mean_difference,
)


def test_t_mean_hand_computed_and_labelled():
    est = t_mean(np.array([1.0, 2.0, 3.0]), "x")
    # mean 2, sd 1, se 1/sqrt(3), t(0.975, 2) = 4.3027
    half = 4.302652729911275 / np.sqrt(3)
    assert (
        est.value == 2.0
        and est.low == pytest.approx(2 - half)
        and est.high == pytest.approx(2 + half)
    )
    assert est.label == "95% t-interval, n = 3"
    assert est.test.startswith("one-sample t-test p = ")


def test_three_seeds_give_an_interval_wider_than_their_range():
    values = np.array([1002.59, 1046.65, 1094.01])  # the range a percentile bootstrap returns
    est = t_mean(values)
    assert est.low < values.min() and est.high > values.max()


def test_constant_and_single_runs():
    const = t_mean(np.zeros(4))
    assert const.low == const.high == 0.0
    assert "no spread" in const.test and np.isnan(const.p_two_sided)
    single = t_mean(np.ones(1))
    assert np.isnan(single.low) and not single.defined and "fewer than 2" in single.test
    band = t_mean_columns(np.zeros((1, 3)))
    assert np.isnan(band.low).all()


def test_paired_uses_the_per_seed_differences():
    sac = np.array([1000.0, 2000.0, 3000.0])
    drl = sac + np.array([-357.0, -358.0, 261.0])
    paired = paired_mean_difference(drl, sac)
    welch = welch_mean_difference(drl, sac)
    assert paired.value == pytest.approx(welch.value)
    assert paired.high - paired.low < (welch.high - welch.low) / 2  # seeds' spread cancels
    assert paired.label == "95% paired t-interval, 3 pairs"
    assert paired.p_two_sided == pytest.approx(scipy_stats.ttest_rel(drl, sac).pvalue)
    equal = paired_mean_difference(sac, sac)
    assert (equal.value, equal.low, equal.high) == (0.0, 0.0, 0.0)
    assert "every paired difference is 0" in equal.test


def test_welch_matches_scipy_and_seed_matching_chooses_the_design():
    a, b = np.array([10.0, 11.0, 12.0, 13.0]), np.array([0.0, 1.0, -1.0, 0.5, 2.0])
    est = welch_mean_difference(a, b)
    assert est.p_two_sided == pytest.approx(scipy_stats.ttest_ind(a, b, equal_var=False).pvalue)
    assert est.label == "95% Welch t-interval, 4 vs 5 seeds"
    # equal seed numbers alone do not pair: unrelated algorithms share no initial weights
    same = seed_matched_difference({0: 1.0, 1: 2.0, 2: 4.0}, {0: 0.0, 1: 0.5, 2: 1.0})
    assert same.label == "95% Welch t-interval, 3 vs 3 seeds"
    differ = seed_matched_difference({0: 1.0, 1: 2.0, 2: 4.0}, {0: 0.0, 1: 0.5, 5: 1.0})
    assert differ.label.startswith("95% Welch")
    forced = seed_matched_difference({0: 1.0, 1: 2.0, 2: 4.0}, {0: 0.0, 1: 0.5, 5: 1.0}, pair=True)
    assert forced.label == "95% paired t-interval, 2 pairs"


def test_one_sided_p_values_agree_with_the_interval():
    est = t_mean(np.array([3.0, 4.0, 5.0, 6.0]))
    assert est.p_above(est.low) == pytest.approx(0.025)
    assert est.p_below(est.high) == pytest.approx(0.025)


def test_holm_hand_computed():
    assert holm([0.01, 0.04, 0.03]) == pytest.approx([0.03, 0.06, 0.06])
    adjusted = holm([0.2, float("nan"), 0.01])
    assert adjusted[0] == pytest.approx(0.2) and np.isnan(adjusted[1])
    assert adjusted[2] == pytest.approx(0.02)


def test_seeds_to_decide_grows_as_the_effect_shrinks():
    est = t_mean(np.array([0.0, 2.0, 4.0]))  # mean 2, sd 2
    far, near = seeds_to_decide(est, [(3.0,)]), seeds_to_decide(est, [(0.5,)])
    assert far is not None and near is not None and far < near
    assert seeds_to_decide(est, [(1e-3,)]) is None  # more than the limit
    assert seeds_to_decide(est, [(0.0,)]) is None  # at the threshold: no route
    # two tests to clear (equivalence) ask for more seeds than the nearer one alone
    assert seeds_to_decide(est, [(1.0, 1.0)]) > seeds_to_decide(est, [(1.0,)])


def _lower_bounds(rng, n: int, mean_sd: tuple[float, float], other_sd: float | None):
    """The 95% interval's lower bound over 20,000 simulated samples of n seeds: a paired
    difference (``other_sd`` None) or a Welch difference from a second group of mean 0."""
    a = rng.normal(*mean_sd, (20_000, n))
    if other_sd is None:
        se, df = a.std(axis=1, ddof=1) / np.sqrt(n), n - 1
        return a.mean(axis=1) - scipy_stats.t.ppf(0.975, df) * se
    b = rng.normal(0.0, other_sd, (20_000, n))
    va, vb = a.var(axis=1, ddof=1) / n, b.var(axis=1, ddof=1) / n
    df = (va + vb) ** 2 / (va**2 / (n - 1) + vb**2 / (n - 1))
    return a.mean(axis=1) - b.mean(axis=1) - scipy_stats.t.ppf(0.975, df) * np.sqrt(va + vb)


def test_seeds_to_decide_gives_the_interval_an_80_percent_chance():
    """Simulated with the observed mean and spread: at the n it names, about 80% of
    samples give an interval wholly past the threshold; one seed fewer, fewer do (a paired
    difference, and a Welch difference of unequal spreads)."""
    rng = np.random.default_rng(0)
    paired = t_mean(np.array([0.0, 2.0, 4.0]), method="paired t-interval")  # mean 2, sd 2
    welch = welch_mean_difference(np.array([1.0, 2.0, 3.0, 4.0, 5.0]), np.array([0.0, 4.0, -4.0]))
    for est, threshold, mean_sd, other_sd in (
        (paired, 1.0, (2.0, 2.0), None),
        (welch, 1.0, (3.0, np.sqrt(2.5)), 4.0),
    ):
        n = seeds_to_decide(est, [(est.value - threshold,)])
        assert n is not None and n > 2
        chances = [
            float(np.mean(_lower_bounds(rng, m, mean_sd, other_sd) > threshold)) for m in (n - 1, n)
        ]
        assert chances[0] < 0.8 <= chances[1] + 0.01, (est.method, n, chances)


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
