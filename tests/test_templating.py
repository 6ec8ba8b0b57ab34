from replicate.templating import count_seeds, report_environment


def test_seed_counts_are_singular_for_one():
    assert count_seeds(1) == "1 seed"
    assert count_seeds(0) == "0 seeds"
    assert count_seeds(3, "paired ") == "3 paired seeds"
    assert count_seeds(1, "paired ") == "1 paired seed"


def test_report_templates_share_the_seeds_filter():
    environment = report_environment()
    assert (
        environment.from_string("{{ 1|seeds('paired ') }}, {{ 4|seeds }}").render()
        == "1 paired seed, 4 seeds"
    )
    for name in ("fig3.html", "fig4.html", "ablation.html", "rlfd.html", "table1.html"):
        environment.get_template(name)  # parses, so every filter it names is registered
