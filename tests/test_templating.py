from replicate.claims.words import count_seeds
from replicate.reports.templating import report_environment, share_summary, step_share


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


def test_a_rare_guider_never_reads_as_one_that_never_acted():
    assert step_share(0.0) == "0.0%" and step_share(0.0003) == "<0.1%"
    assert step_share(0.14) == "14.0%"
    assert share_summary([0.116, 0.14, 0.166]) == "14.1% (11.6% to 16.6%)"
    assert share_summary([0.0003, 0.0004]) == "<0.1% in every run"
    assert share_summary([0.0, 0.0]) == "0.0% in every run"
