"""How verdicts and reasons speak of counts (the reports use the same words)."""

from __future__ import annotations


def count_seeds(n: int, kind: str = "") -> str:
    """``n`` seeds in words, singular for one: '1 seed', '3 seeds', '1 paired seed'."""
    return f"{n} {kind}seed{'' if n == 1 else 's'}"
