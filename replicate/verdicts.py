"""A claim's verdict from its checks (``replicate.checks``): its primary check's, reproduced,
not reproduced, inconclusive or not testable at this budget; "partly reproduced" when the
primary holds and a secondary check fails. For each inconclusive check, what would decide
it: how many seeds, and what they would cost at the rates of the store's runs.
"""

from __future__ import annotations

from typing import Any

from replicate.checks import (
    EQUIVALENT,
    FAILS,
    HOLDS,
    INCONCLUSIVE,
    LABELS,
    NOT_TESTABLE,
    Check,
    Group,
    decide,
)
from replicate.stats import CONFIDENCE, DECIDING_CHANCE, seeds_to_decide
from replicate.templating import count_seeds

REPRODUCED, PARTLY, NOT_REPRODUCED = "reproduced", "partly reproduced", "not reproduced"
MOST_SEEDS = 200  # beyond this, "what would decide it" stops counting


def _hours(steps: int, rate: float, processes: int) -> str:
    hours = steps / (rate * processes) / 3600
    return f"{hours:.1f} h" if hours >= 1 else f"{hours * 60:.0f} min"


def what_would_decide(check: Check, family: int, primaries: int = 1) -> tuple[str, str] | None:
    """For an inconclusive check: how many seeds would give it an 80% chance of being
    decided if the observed effect and spread held, and what they would cost at the rates
    of the store's runs; in full and in short (for the front door). Each way of deciding it
    is counted at the level it is tested at: a secondary check at the Bonferroni level of
    its ``family`` (which Holm's adjustment never asks more than), a primary check's "fails"
    and "equivalent" at the Bonferroni level of the claim's ``primaries``."""
    if check.state != INCONCLUSIVE:
        return None
    est = check.estimate
    if not est.defined:
        return ("a second seed: one run gives no interval",) * 2
    unit = "pairs" if est.method.startswith("paired") else "seeds"
    routes = check.routes()
    if not any(min(distances) > 0 for _, distances in routes):
        text = (
            "no number of seeds at this budget: the estimate sits exactly at what decides "
            "the check; only a longer budget (where the effect may differ) can"
        )
        return text, "no number of seeds at this budget; a longer budget might"

    def level(outcome: str) -> float:
        tests = family if not check.primary else (1 if outcome == HOLDS else primaries)
        return 1 - (1 - CONFIDENCE) / max(tests, 1)

    options = [
        (n, level(outcome))
        for outcome, distances in routes
        if (n := seeds_to_decide(est, [distances], level(outcome), limit=MOST_SEEDS))
    ]
    if not options:
        text = (
            f"more than {MOST_SEEDS} {unit} at this budget: the estimate lies "
            f"{check.distance():.3g} from what decides the check, small against the "
            "seeds' spread; only a longer budget (where the effect may differ) can"
        )
        return text, f"more than {MOST_SEEDS} {unit} at this budget; a longer budget might"
    needed, needed_level = min(options)
    per_group = (
        [needed - est.n] * len(check.groups)
        if est.n_other is None
        else [needed - est.n, needed - est.n_other][: len(check.groups)]
    )
    extra_runs = sum(max(0, k) for k in per_group)
    text = (
        f"about {needed} {unit} (the smallest n at which its {needed_level * 100:.3g}% "
        f"{est.method} would decide it with an {DECIDING_CHANCE:.0%} chance, if the observed "
        f"mean and spread were the truth; the estimate lies {check.distance():.3g} from "
        "what decides it)"
    )
    short = f"about {needed} {unit}"
    budget = max((g.budget or 0) for g in check.groups) if check.groups else 0
    if extra_runs and budget:
        steps = extra_runs * budget
        costs = []
        for kind, machine, processes in (("cpu", "a 2-core CPU", 2), ("gpu", "a GPU machine", 1)):
            rates = [g.rates[kind] for g in check.groups if kind in g.rates]
            if rates:
                costs.append(f"about {_hours(steps, min(rates), processes)} on {machine}")
        runs = f"{extra_runs} more run" + ("s" if extra_runs != 1 else "")
        cost = f"{runs}, {steps:,} env steps" + (", " + " or ".join(costs) if costs else "")
        text += f": {cost}" + (" at the rates the store's runs recorded" if costs else "")
        short += f": {cost}"
    return text, short


def judge(
    claim_id: int, title: str, paper: str, checks: list[Check], used: list[Group]
) -> dict[str, Any]:
    """The claim's verdict from its primary checks (all must hold: an intersection-union
    test needs no correction), with the secondary checks listed."""
    decide(checks)
    family = sum(1 for c in checks if not c.primary and not c.not_testable)
    primaries = sum(1 for c in checks if c.primary and not c.not_testable)
    shorts = []
    for check in checks:
        full_and_short = what_would_decide(check, family, primaries)
        check.decide = check.not_testable or (full_and_short[0] if full_and_short else None)
        if check.primary and check.decide:
            where_ = check.estimate.quantity.split(":")[0].split(" at ")[0]
            shorts.append(f"{where_}: " + (check.not_testable or full_and_short[1]))
    primary = [c for c in checks if c.primary]
    states = {c.state for c in primary}
    # a secondary check fails, or finds a difference the claim states equivalent to none
    failing = [
        c.what
        for c in checks
        if not c.primary and (c.state == FAILS or (c.state == EQUIVALENT and c.within is None))
    ]
    if NOT_TESTABLE in states:
        verdict = NOT_TESTABLE
    elif states == {HOLDS}:
        verdict = PARTLY if failing else REPRODUCED
    elif states & {FAILS, EQUIVALENT}:
        verdict = NOT_REPRODUCED
    else:
        verdict = INCONCLUSIVE
    budgets = [g.budget for g in used if g.budget]
    seeds = [len(g.seeds) for g in used]
    return {
        "id": claim_id,
        "title": title,
        "paper": paper,
        "verdict": verdict,
        "steps": max(budgets) if budgets else None,
        "seeds": [min(seeds), max(seeds)] if seeds else None,
        "decides": shorts,
        "primary": [c.what for c in primary],
        "not_met": failing,
        "parts": [c.as_dict() for c in checks],
        "effect": primary[0].estimate.as_dict()
        if primary and not primary[0].not_testable
        else None,
        "algorithms": sorted(
            {f"{LABELS[g.algo]} on {g.env_id} ({count_seeds(len(g.seeds))})" for g in used}
        ),
    }


def not_judged(claim_id: int, title: str, paper: str, why: str) -> dict[str, Any]:
    return {
        "id": claim_id,
        "title": title,
        "paper": paper,
        "verdict": f"not judged: {why}",
        "steps": None,
        "seeds": None,
        "decides": [],
        "primary": [],
        "not_met": [],
        "parts": [],
        "effect": None,
        "algorithms": [],
    }
