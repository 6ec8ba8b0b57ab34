"""From checks to parts to a claim's verdict, and what would decide an open check.

A part holds when all its checks hold, is contradicted when any of its checks contradicts
it (fails, or finds a claimed difference negligible), and is open otherwise. The claim is
*reproduced* when every part holds, *not reproduced* when a part is contradicted and none
holds, *partly reproduced* when at least one part holds and at least one is contradicted,
*inconclusive* when no part is contradicted and not all hold, and *not testable at this
budget* when one of its preconditions was never observed.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import replace

import numpy as np
from scipy import stats

from replicate.claims.checks import EQUIVALENT, FAILS, HOLDS, INCONCLUSIVE, Check
from replicate.stats import DECIDING_CHANCE, MeanEstimate, seeds_to_decide

REPRODUCED, PARTLY, NOT_REPRODUCED = "reproduced", "partly reproduced", "not reproduced"
INCONCLUSIVE_CLAIM, NOT_TESTABLE_CLAIM = "inconclusive", "not testable at this budget"
CONTRADICTED, OPEN = "contradicted", "open"
MOST_SEEDS = 200  # beyond this, "what would decide it" stops counting
SIGMA_CONFIDENCE = 0.80  # the range of seeds: sigma's two-sided 80% confidence limits


def part_state(states: Iterable[tuple[str, bool]]) -> str:
    """A part's state from its checks' (state, contradicts) pairs."""
    states = list(states)
    if any(contradicts for _, contradicts in states):
        return CONTRADICTED
    if states and all(state == HOLDS for state, _ in states):
        return HOLDS
    return OPEN


def claim_verdict(part_states: list[str], preconditions_met: bool = True) -> str:
    """The claim's verdict from its parts' states."""
    if not preconditions_met:
        return NOT_TESTABLE_CLAIM
    holds = part_states.count(HOLDS)
    contradicted = part_states.count(CONTRADICTED)
    if part_states and holds == len(part_states):
        return REPRODUCED
    if contradicted and holds:
        return PARTLY
    if contradicted:
        return NOT_REPRODUCED
    return INCONCLUSIVE_CLAIM


def _hours(steps: int, rate: float, processes: int) -> str:
    hours = steps / (rate * processes) / 3600
    return f"{hours:.1f} h" if hours >= 1 else f"{hours * 60:.0f} min"


def sigma_limits(
    estimate: MeanEstimate, confidence: float = SIGMA_CONFIDENCE
) -> tuple[float, float]:
    """Factors by which the true per-seed spread may differ from the observed one: the
    two-sided ``confidence`` limits of sigma from a chi-square on the estimate's degrees of
    freedom (Welch's for a Welch difference)."""
    df = estimate.df
    if not np.isfinite(df) or df <= 0:
        return float("nan"), float("nan")
    tail = (1 - confidence) / 2
    return (
        float(np.sqrt(df / stats.chi2.ppf(1 - tail, df))),
        float(np.sqrt(df / stats.chi2.ppf(tail, df))),
    )


def scaled_spread(estimate: MeanEstimate, factor: float) -> MeanEstimate:
    """``estimate`` with its per-seed spread (and so its standard error) times ``factor``."""
    variances = estimate.variances
    if variances is not None:
        variances = (variances[0] * factor**2, variances[1] * factor**2)
    return replace(estimate, se=estimate.se * factor, variances=variances)


def what_would_decide(check: Check, family: int) -> tuple[str, str] | None:
    """For an inconclusive check: the state more seeds would most likely give at the
    observed effect, and how many seeds would give it an 80% chance of being decided (at the
    Bonferroni level of its ``family``, which Holm's adjustment never asks more than), with
    the range those seeds span over sigma's 80% confidence limits, and what the plug-in
    count would cost at the rates of the store's runs. In full and in short. Sets
    ``check.likely``."""
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
        return text, "no number of seeds at this budget"
    level = 1 - (1 - est.confidence) / max(family, 1)
    options = sorted(
        (n, outcome)
        for outcome, distances in routes
        if (n := seeds_to_decide(est, [distances], level, limit=MOST_SEEDS))
    )
    # the state the observed effect points to: the route decided with the fewest seeds, or
    # where none is within reach, the one whose bounds lie farthest from the estimate
    likely = options[0][1] if options else max(routes, key=lambda r: min(r[1]))[0]
    check.likely = likely
    if not options:
        text = (
            f"more than {MOST_SEEDS} {unit} at this budget: the estimate lies "
            f"{check.distance():.3g} from what decides the check, small against the "
            f"seeds' spread; at the observed effect it would most likely {_verb(likely)}"
        )
        return text, f"more than {MOST_SEEDS} {unit}, likely {likely}"
    needed, outcome = options[0]
    distances = dict(routes)[outcome]
    low_factor, high_factor = sigma_limits(est)
    span = []
    for factor in (low_factor, high_factor):
        n = (
            seeds_to_decide(scaled_spread(est, factor), [distances], level, limit=MOST_SEEDS)
            if np.isfinite(factor)
            else None
        )
        span.append(str(n) if n else f"more than {MOST_SEEDS}")
    span_text = f"{span[0]} to {span[1]}"
    per_group = (
        [needed - est.n] * len(check.groups)
        if est.n_other is None
        else [needed - est.n, needed - est.n_other][: len(check.groups)]
    )
    extra_runs = sum(max(0, k) for k in per_group)
    text = (
        f"most likely {_verb(outcome)} with more seeds at the observed effect: about "
        f"{needed} {unit} ({span_text} over sigma's {SIGMA_CONFIDENCE:.0%} confidence limits) "
        f"would decide it with an {DECIDING_CHANCE:.0%} chance at {level * 100:.3g}%"
    )
    short = f"~{needed} {unit} ({span_text}), likely {outcome}"
    budget = max((g.budget or 0) for g in check.groups) if check.groups else 0
    if extra_runs and budget:
        steps = extra_runs * budget
        costs = []
        for kind, machine, processes in (("cpu", "a 2-core CPU", 2), ("gpu", "a GPU machine", 1)):
            rates = [g.rates[kind] for g in check.groups if kind in g.rates]
            if rates:
                costs.append(f"{_hours(steps, min(rates), processes)} on {machine}")
        runs = f"{extra_runs} more run" + ("s" if extra_runs != 1 else "")
        text += f"; {runs}, {steps:,} env steps" + (
            ", about " + " or ".join(costs) if costs else ""
        )
        if costs:
            short += ", " + costs[0].split(" on ")[0]
    return text, short


def _verb(outcome: str) -> str:
    return {HOLDS: "hold", FAILS: "fail", EQUIVALENT: "be equivalent"}.get(outcome, outcome)
