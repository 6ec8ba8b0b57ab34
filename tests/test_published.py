"""Published SAC references in two groups, and the words that place our SAC among them."""

from replicate.claims.published import MODERN, SAME_ALGORITHM, compare_with_published, published_sac


def test_every_source_is_in_one_group_with_its_settings():
    points = published_sac()
    families = {p.source: p.family for p in points}
    assert families["spinningup"] == families["coach"] == families["td3-paper"] == SAME_ALGORITHM
    assert families["tianshou"] == families["sb3-zoo"] == families["cleanrl"] == MODERN
    assert all(p.about.settings and p.about.statistic for p in points)


def test_the_comparison_is_computed_from_the_numbers():
    # Hopper at 200k: Coach 600 and Spinning Up 1330 (V-network SAC), Tianshou 3234 (twin Q)
    inside = compare_with_published("Hopper-v5", 200_000, 1000.0)
    assert (
        "within the range of V-network SAC" in inside and "Coach 600 to Spinning Up 1330" in inside
    )
    assert "below twin-Q SAC (Tianshou 3234)" in inside
    assert "above V-network SAC" in compare_with_published("Hopper-v5", 200_000, 2000.0)
    assert compare_with_published("Hopper-v5", 123, 1.0) is None
