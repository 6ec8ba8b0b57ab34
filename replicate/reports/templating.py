"""The one Jinja environment every report renders with, and the wording it shares with the
claims."""

from __future__ import annotations

import jinja2

from replicate.claims.words import count_seeds


def step_share(x: float) -> str:
    """A share of training steps as a percentage; one above 0 but under 0.1% as '<0.1%', so
    that a guider that acted rarely never reads as one that never acted."""
    return f"{x:.1%}" if x >= 0.001 or x == 0 else "<0.1%"


def share_summary(shares: list[float]) -> str:
    """The mean share over runs and their range: '14.0% (11.6% to 16.6%)'."""
    low, high = step_share(min(shares)), step_share(max(shares))
    mean = step_share(sum(shares) / len(shares))
    return f"{mean} in every run" if low == high else f"{mean} ({low} to {high})"


def report_environment() -> jinja2.Environment:
    """Templates from ``replicate/reports/templates``, HTML-escaped, failing on any undefined name."""
    environment = jinja2.Environment(
        loader=jinja2.PackageLoader("replicate.reports", "templates"),
        autoescape=jinja2.select_autoescape(["html"]),
        undefined=jinja2.StrictUndefined,
    )
    environment.filters["seeds"] = count_seeds
    environment.filters["share_summary"] = share_summary
    return environment
