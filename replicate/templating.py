"""The one Jinja environment every report renders with, and the wording it shares with the
claims."""

from __future__ import annotations

import jinja2


def count_seeds(n: int, kind: str = "") -> str:
    """``n`` seeds in words, singular for one: '1 seed', '3 seeds', '1 paired seed'."""
    return f"{n} {kind}seed{'' if n == 1 else 's'}"


def report_environment() -> jinja2.Environment:
    """Templates from ``replicate/templates``, HTML-escaped, failing on any undefined name."""
    environment = jinja2.Environment(
        loader=jinja2.PackageLoader("replicate", "templates"),
        autoescape=jinja2.select_autoescape(["html"]),
        undefined=jinja2.StrictUndefined,
    )
    environment.filters["seeds"] = count_seeds
    return environment
