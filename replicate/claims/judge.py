"""The claims ledger: a paper's declared claims (``replicate.claims.declaration``) judged over the
run store, part by part. The check kinds are the small functions below; which algorithms,
envs, measures, thresholds and margins each check uses is in the declaration file.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from replicate.claims.checks import (
    HOLDS,
    INCONCLUSIVE,
    LABELS,
    NOT_TESTABLE,
    PAIRED,
    Check,
    Group,
    areas,
    decide,
    finals,
    instabilities,
    where,
)
from replicate.claims.declaration import (
    CheckSpec,
    ClaimSpec,
    Declaration,
    PartSpec,
    load_declaration,
)
from replicate.claims.published import published_points
from replicate.claims.verdicts import (
    CONTRADICTED,
    NOT_TESTABLE_CLAIM,
    claim_verdict,
    part_state,
    what_would_decide,
)
from replicate.claims.words import count_seeds
from replicate.stats import seed_matched_difference, t_mean

ANT = "Ant-v5"
PAPER_FIG4_SEEDS = 4  # the paired seeds of the paper's Fig. 4
PAPER_MUJOCO_STEPS = 1_000_000  # not stated in the paper's text; its MuJoCo axes suggest 1M
# The comparison's smallest effect on its normalised scale (10% of the demonstrations'
# return), as the declaration's margins are on the raw one.
SMALLEST_EFFECT = 0.10
NO_RUNS = "no runs"

MEASURE_WORDS = {
    "final_return": "final return",
    "area": "area under the curve",
    "instability": "instability",
}
MEASURE_VALUES: dict[str, Callable[[Group], np.ndarray]] = {
    "final_return": finals,
    "area": areas,
    "instability": instabilities,
}


def label(algo: str) -> str:
    return LABELS.get(algo, algo.upper())


def _number(x: float) -> str:
    return f"{x:,.0f}" if abs(x) >= 100 else f"{x:g}"


def describe(spec: CheckSpec) -> str:
    """A check in words, from its declaration."""
    words = MEASURE_WORDS[spec.measure]
    if spec.kind == "escape":
        return (
            f"{spec.env}: on each seed where {label(spec.other)} ends below "
            f"{_number(spec.below)}, {label(spec.algo)} ends at or above it"
        )
    subject = (
        f"{label(spec.algo)} minus {label(spec.other)}, {words}"
        if spec.kind == "difference"
        else f"{label(spec.algo)} {words}"
    )
    if spec.within is not None:
        low, high = spec.within
        band = f"+-{_number(high)}" if low == -high else f"[{_number(low)}, {_number(high)}]"
        return f"{spec.env}: {subject} within {band}"
    return f"{spec.env}: {subject} above {_number(spec.above)}"


def published_reach(env_id: str, level: float, budget: int) -> tuple[str | None, str]:
    """Why ``level`` cannot be tested at ``budget`` (no published SAC reaches it by then;
    None: one does), and the budget at which published SAC first reaches it."""
    points = published_points(env_id, 10**9)
    within = [p for p in points if p.steps <= budget]
    best = max(within, key=lambda p: p.mean, default=None)
    reaching = sorted((p for p in points if p.mean >= level), key=lambda p: p.steps)
    later = (
        f"published SAC first reaches it at {reaching[0].steps:,} steps ({reaching[0].label}: "
        f"{reaching[0].mean:.0f})"
        if reaching
        else "no published SAC curve reaches it within the budgets published"
    )
    if best is None or best.mean >= level:
        return None, later
    return (
        f"no published SAC reaches {level:.0f} by {budget:,} steps (best: {best.label}, "
        f"{best.mean:.0f} at {best.steps:,}); {later}"
    ), later


# The check kinds: each turns one declared check and the groups it reads into a Check.


def _missing(spec: CheckSpec, part: str, why: str) -> Check:
    return Check(describe(spec), t_mean(np.array([]), why), part=part, not_testable=why, groups=())


def mean_check(
    spec: CheckSpec, part: str, groups: dict[tuple[str, str], Group], confidence: float
) -> Check:
    """The mean over seeds of one algorithm's measure, against a threshold or a band."""
    group = groups[(spec.env, spec.algo)]
    values = MEASURE_VALUES[spec.measure](group)
    estimate = t_mean(
        values,
        f"{where(group)}: {label(spec.algo)}, mean {MEASURE_WORDS[spec.measure]}",
        confidence,
    )
    if spec.within is not None:
        meeting = (values >= spec.within[0]) & (values <= spec.within[1])
    else:
        meeting = values > spec.above
    blocked = later = None
    if spec.needs_published_reach:
        blocked, later = published_reach(spec.env, spec.above, group.budget or 0)
    return Check(
        describe(spec),
        estimate,
        spec.above,
        spec.within,
        part=part,
        seeds_meeting=int(meeting.sum()),
        not_testable=blocked,
        testable_when=f"a longer budget: {later}" if blocked else None,
        groups=(group,),
    )


def difference_check(
    spec: CheckSpec, part: str, groups: dict[tuple[str, str], Group], confidence: float
) -> Check:
    """One algorithm's measure minus another's: paired over shared seeds where the two share
    initial weights (SAC and DRL-EG), Welch's otherwise."""
    a, b = groups[(spec.env, spec.algo)], groups[(spec.env, spec.other)]
    values = MEASURE_VALUES[spec.measure]
    estimate = seed_matched_difference(
        dict(zip(a.seeds, values(a).tolist())),
        dict(zip(b.seeds, values(b).tolist())),
        f"{where(a)}: {label(spec.algo)} minus {label(spec.other)}, {MEASURE_WORDS[spec.measure]}",
        pair={spec.algo, spec.other} <= set(PAIRED),
        confidence=confidence,
    )
    return Check(
        describe(spec),
        estimate,
        spec.above,
        spec.within,
        smallest_effect=spec.smallest_effect,
        part=part,
        groups=(a, b),
    )


def escape_check(
    spec: CheckSpec, part: str, groups: dict[tuple[str, str], Group], confidence: float
) -> Check:
    """On the shared seeds where ``other`` ends below the stuck level, whether ``algo``
    ends at or above it: decided by counting seeds, not by a test."""
    a, b = groups[(spec.env, spec.algo)], groups[(spec.env, spec.other)]
    values = MEASURE_VALUES[spec.measure]
    common = sorted(set(a.seeds) & set(b.seeds))
    va = np.array([values(a)[a.seeds.index(s)] for s in common])
    vb = np.array([values(b)[b.seeds.index(s)] for s in common])
    stuck = vb < spec.below
    escaped = stuck & (va >= spec.below)
    estimate = t_mean(
        escaped[stuck].astype(float),
        f"{where(a)}: share of the seeds where {label(spec.other)} is stuck on which "
        f"{label(spec.algo)} escapes",
        confidence,
    )
    check = Check(
        describe(spec),
        estimate,
        part=part,
        seeds_meeting=int(escaped.sum()),
        groups=(a, b),
        counted=True,
    )
    if not stuck.any():
        check.not_testable = (
            f"no {label(spec.other)} seed ends below {_number(spec.below)} "
            f"(of {count_seeds(len(common), 'paired ')})"
        )
        check.testable_when = (
            f"a seed on which {label(spec.other)} stays stuck: a longer budget or more "
            "seeds may show one (the paper's Fig. 4 shows 1 in 4)"
        )
    return check


CHECK_KINDS = {"mean": mean_check, "difference": difference_check, "escape": escape_check}


def build_check(
    spec: CheckSpec, part: str, groups: dict[tuple[str, str], Group], confidence: float
) -> Check:
    needed = [spec.algo] + ([spec.other] if spec.other else [])
    missing = [a for a in needed if (spec.env, a) not in groups]
    if missing:
        return _missing(
            spec, part, "no runs of " + " or ".join(f"{label(a)} on {spec.env}" for a in missing)
        )
    return CHECK_KINDS[spec.kind](spec, part, groups, confidence)


def precondition_met(condition: Any, groups: dict[tuple[str, str], Group]) -> tuple[bool, str]:
    """Whether a precondition was observed, with what was seen."""
    group = groups.get((condition.env, condition.algo))
    if group is None:
        return False, f"no runs of {label(condition.algo)} on {condition.env}"
    values = MEASURE_VALUES[condition.measure](group)
    stuck = values < condition.below
    words = MEASURE_WORDS[condition.measure]
    if stuck.any():
        return True, (
            f"{int(stuck.sum())} of {count_seeds(len(values))} of {label(condition.algo)} "
            f"end below {_number(condition.below)} by {group.budget or 0:,} steps"
        )
    return False, (
        f"no {label(condition.algo)} seed stays stuck: all {count_seeds(len(values))} end "
        f"above {_number(condition.below)} ({words} {values.min():,.0f} to "
        f"{values.max():,.0f}) by {group.budget or 0:,} steps"
    )


def _part_summary(part: PartSpec, checks: list[Check], state: str) -> str:
    """Which check decided a part, in a few words."""
    if state == CONTRADICTED:
        against = [c for c in checks if c.contradicts]
        return "; ".join(f"{c.what}: {c.state}" for c in against)
    if state == HOLDS:
        return "every check holds" if len(checks) > 1 else "its check holds"
    open_ = [c for c in checks if c.state != HOLDS]
    untestable = [c for c in open_ if c.state == NOT_TESTABLE]
    words = f"{len(open_)} of {len(checks)} checks open" if len(checks) > 1 else "its check is open"
    if untestable:
        words += f" ({len(untestable)} not testable at this budget)"
    return words


def take_confirmatory(checks: list[Check], confirmed: dict[str, dict[str, Any]]) -> list[str]:
    """Give each check its registered confirmatory result; where that result has a state,
    the check takes it (judged on the plan's fresh seeds alone) and keeps the exploratory
    state beside it. Returns the ids of the checks whose state now rests on one."""
    rests = []
    for check in checks:
        result = confirmed.get(check.id or "")
        if result is None:
            continue
        check.confirmatory = result
        if result.get("state"):
            check.exploratory, check.state = check.state, result["state"]
            check.likely = None
            rests.append(check.id or "")
    return rests


def judge_claim(
    spec: ClaimSpec,
    groups: dict[tuple[str, str], Group],
    confidence: float,
    confirmed: dict[str, dict[str, Any]] | None = None,
) -> dict[str, Any]:
    """One claim's parts, checks, preconditions and verdict over ``groups``: intervals at
    ``confidence``, each one-sided test at half its complement; ``confirmed``: registered
    confirmatory results by check id (``replicate.claims.confirm_judge``)."""
    checks = [build_check(c, p.id, groups, confidence) for p in spec.parts for c in p.checks]
    numbered = [f"{p.id}.{k}" for p in spec.parts for k in range(1, len(p.checks) + 1)]
    for check, check_id in zip(checks, numbered):
        check.id = check_id
    decide(checks, (1 - confidence) / 2)
    for check in checks:
        if not check.groups:
            check.state = NO_RUNS
    family = sum(1 for c in checks if c.adjusted)
    for check in checks:
        decision = what_would_decide(check, family) if check.adjusted else None
        if check.state == NO_RUNS:
            check.decide = check.decide_short = f"{check.not_testable}: train them"
            continue
        if check.state == NOT_TESTABLE:
            check.decide = f"not testable: {check.not_testable}; it needs {check.testable_when}"
            check.decide_short = check.testable_when
            continue
        check.decide = decision[0] if decision else None
        check.decide_short = decision[1] if decision else None
    confirmatory = take_confirmatory(checks, confirmed or {})

    parts, states, likely_states = [], [], []
    for part in spec.parts:
        mine = [c for c in checks if c.part == part.id]
        state = part_state((c.state, c.contradicts) for c in mine)
        states.append(state)
        likely_states.append(
            part_state(
                (
                    c.likely or c.state,
                    (c.likely or c.state) == "fails"
                    or ((c.likely or c.state) == "equivalent" and c.within is None),
                )
                for c in mine
            )
        )
        parts.append(
            {
                "id": part.id,
                "statement": part.statement,
                "state": state,
                "decided_by": _part_summary(part, mine, state),
                "checks": [c.as_dict() for c in mine],
            }
        )
    observed = [precondition_met(p, groups) for p in spec.preconditions]
    preconditions = [
        {"statement": p.statement, "observed": met, "detail": detail}
        for p, (met, detail) in zip(spec.preconditions, observed)
    ]
    met_all = all(met for met, _ in observed)
    verdict = claim_verdict(states, met_all)
    likely = claim_verdict(likely_states, met_all)
    used = {id(g): g for c in checks for g in c.groups}.values()
    budgets = [g.budget for g in used if g.budget]
    seeds = [len(g.seeds) for g in used]
    paired = next(
        (
            c.estimate.as_dict()
            for c in checks
            if c.estimate.method.startswith("paired") and c.groups
        ),
        None,
    )
    return {
        "id": spec.id,
        "title": spec.title,
        "paper": spec.quote,
        "source": spec.source,
        "verdict": verdict,
        "likely": likely if likely != verdict else None,
        "steps": max(budgets) if budgets else None,
        "seeds": [min(seeds), max(seeds)] if seeds else None,
        "parts": parts,
        "preconditions": preconditions,
        "family": family,
        "contradicted": [
            f"{p['id']}: {p['decided_by']}" for p in parts if p["state"] == CONTRADICTED
        ],
        "decides": [
            f"{c.what}: {c.decide_short}"
            for c in checks
            if c.decide_short and c.state == INCONCLUSIVE
        ],
        "paired": paired,
        "confirmatory": confirmatory,
        "algorithms": sorted(
            {f"{label(g.algo)} on {g.env_id} ({count_seeds(len(g.seeds))})" for g in used}
        ),
        "budget_note": None,
    }


def not_judged(spec: ClaimSpec, why: str) -> dict[str, Any]:
    return {
        "id": spec.id,
        "title": spec.title,
        "paper": spec.quote,
        "source": spec.source,
        "verdict": f"not judged{why}",
        "likely": None,
        "steps": None,
        "seeds": None,
        "parts": [
            {
                "id": p.id,
                "statement": p.statement,
                "state": None,
                "decided_by": "",
                "checks": [],
                "declared": [describe(c) for c in p.checks],
            }
            for p in spec.parts
        ],
        "preconditions": [],
        "family": 0,
        "contradicted": [],
        "decides": [],
        "paired": None,
        "confirmatory": [],
        "algorithms": [],
        "budget_note": None,
    }


def budget_note(spec: ClaimSpec, claim: dict[str, Any]) -> str | None:
    """The claim's budget sentence when its runs are shorter than the paper's, else None."""
    steps = claim.get("steps")
    if not spec.budget_note or not steps or steps >= PAPER_MUJOCO_STEPS:
        return None
    return spec.budget_note.format(steps=steps)


def claim_envs(declaration: Declaration | None = None) -> dict[int, tuple[str, ...]]:
    """Each claim's envs, by id."""
    declaration = declaration or load_declaration()
    return {c.id: c.envs for c in declaration.claims}


def judge_claims(
    groups: dict[tuple[str, str], Group],
    meaningful: bool,
    judged_envs: set[str] | None = None,
    fig4_groups: dict[tuple[str, str], Group] | None = None,
    declaration: Declaration | None = None,
    confirmed: dict[str, dict[str, Any]] | None = None,
) -> list[dict[str, Any]]:
    """Every declared claim's verdict: those on Fig. 3's runs from ``groups``, those on
    Fig. 4's from ``fig4_groups`` (None: not judged). A profile whose numbers mean nothing
    judges none; a claim on envs outside ``judged_envs`` (the profile's Fig. 3 envs; None:
    every env) is not judged at this profile; ``confirmed``: registered confirmatory
    results by check id, which the checks they name take."""
    declaration = declaration or load_declaration()
    ledger = []
    for spec in declaration.claims:
        these = fig4_groups if spec.runs == "fig4" else groups
        if judged_envs is not None and not set(spec.envs) <= judged_envs:
            claim = not_judged(spec, " at this profile's budget")
        elif these is None:
            claim = not_judged(spec, ": no Fig. 4 runs (paired seeds) in the store")
        elif not meaningful:
            claim = not_judged(spec, " (smoke profile: numbers mean nothing)")
        else:
            claim = judge_claim(spec, these, declaration.confidence, confirmed)
            claim["budget_note"] = budget_note(spec, claim)
        ledger.append(claim)
    return ledger


__all__ = ["NOT_TESTABLE_CLAIM", "judge_claim", "judge_claims", "published_reach"]
