"""A check: an estimate over a group of runs (a mean over seeds, or a difference of means)
against a threshold or a band, through a t-interval: paired on per-seed differences where
the two algorithms share initial weights seed by seed (SAC and DRL-EG), Welch's otherwise.

A check *holds* when the one-sided test of the claimed side rejects, *fails* when the test
of the other side does, is *equivalent* when two one-sided tests put a claimed difference
within the smallest effect of interest (a difference too small to matter, not "better" or
"worse"), is *not testable at this budget* when a precondition was never observed, and is
*inconclusive* otherwise. Every test is Holm-adjusted over the claim's testable checks, one
adjustment per outcome (holds, fails, equivalent), each at 2.5% one-sided; the 95%
intervals are shown unadjusted, so one can clear its threshold and still be inconclusive.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from replicate.stats import CONFIDENCE, MeanEstimate, curve_area, holm, seed_matched_difference
from replicate.store.measures import instabilities as measured_instabilities

ALPHA_ONE_SIDED = (1 - CONFIDENCE) / 2  # a one-sided test per side of a 95% interval
LABELS = {
    "sac": "SAC",
    "ppo": "PPO",
    "ppo-bc": "PPO+BC",
    "ddpgfd": "DDPGfD",
    "drl-eg": "DRL-EG",
    "drl-eg-gmm": "DRL-EG (GMM)",
}
PAIRED = ("sac", "drl-eg")  # same seed, same initial weights: their differences are paired
INCONCLUSIVE, NOT_TESTABLE = "inconclusive", "not testable at this budget"
HOLDS, FAILS, EQUIVALENT = "holds", "fails", "equivalent"


@dataclass
class Group:
    """The runs of one algorithm on one env, by seed: final returns and curves."""

    env_id: str
    algo: str
    seeds: list[int]
    finals: np.ndarray  # (runs,) final return: the late-training mean (replicate.store.measures)
    curves: np.ndarray  # (runs, points) over the evaluation steps all runs share
    steps: np.ndarray | None = None  # (points,) those steps; None: evenly spaced
    # env steps per second of one training process, by device kind ("cpu", "gpu"), median
    # over the group's runs (a seed batch's members together): what more seeds would cost
    rates: dict[str, float] = field(default_factory=dict)

    @property
    def areas(self) -> np.ndarray:
        """Per run, the mean return over the curve (``replicate.stats.curve_area``)."""
        steps = self.steps if self.steps is not None else np.arange(self.curves.shape[1])
        return curve_area(steps, self.curves)

    @property
    def budget(self) -> int | None:
        return int(self.steps[-1]) if self.steps is not None else None


def difference(
    a: Group, b: Group, values: Callable[[Group], np.ndarray], what: str
) -> MeanEstimate:
    """``values(a) - values(b)``: paired over shared seeds when a and b are SAC and DRL-EG
    (same seed, same initial weights), else Welch over all runs."""
    quantity = f"{where(a)}: {LABELS[a.algo]} minus {LABELS[b.algo]}, {what}"
    return seed_matched_difference(
        dict(zip(a.seeds, values(a).tolist())),
        dict(zip(b.seeds, values(b).tolist())),
        quantity,
        pair={a.algo, b.algo} <= set(PAIRED),
    )


def where(group: Group) -> str:
    """The env and budget a quantity belongs to: '(Ant-v5, 500,000 steps)' names one."""
    return f"{group.env_id} at {group.budget:,} steps" if group.budget else group.env_id


def finals(group: Group) -> np.ndarray:
    return group.finals


def areas(group: Group) -> np.ndarray:
    return group.areas


def instabilities(group: Group) -> np.ndarray:
    """Per run, the instability of its curve after the first 10% of the budget."""
    steps = group.steps if group.steps is not None else np.arange(group.curves.shape[1])
    return measured_instabilities(steps, group.curves)


@dataclass
class Check:
    """One check: an estimate against the claimed side of a threshold (``above``) or
    inside a band (``within``), with the p-values that decide it."""

    what: str
    estimate: MeanEstimate
    above: float | None = None
    within: tuple[float, float] | None = None
    smallest_effect: float | None = None  # for ``above`` on a difference
    part: str | None = None  # the claim's part it tests
    id: str | None = None  # "<part>.<k>": the k-th declared check of the part, e.g. "3b.1"
    counted: bool = False  # decided by counting seeds, not by a test
    seeds_meeting: int | None = None
    not_testable: str | None = None  # why the check cannot be decided at this budget
    testable_when: str | None = None  # what would make it testable (a longer budget, ...)
    groups: tuple[Group, ...] = ()  # whose runs more seeds would add to
    state: str = INCONCLUSIVE
    adjusted: dict[str, float] = field(default_factory=dict)
    unadjusted: dict[str, float] = field(default_factory=dict)
    decide: str | None = None
    decide_short: str | None = None
    likely: str | None = None  # the state more seeds would most likely give, if open
    # a registered confirmatory experiment's judgement of this check (its own fresh seeds);
    # where it has a state, the check takes it and ``exploratory`` keeps the one it replaced
    confirmatory: dict[str, Any] | None = None
    exploratory: str | None = None

    @property
    def contradicts(self) -> bool:
        """Its state contradicts the claim: it fails, or a claimed difference is found
        negligible (equivalent within the smallest effect of interest)."""
        return self.state == FAILS or (self.state == EQUIVALENT and self.within is None)

    def p_values(self) -> dict[str, float]:
        """One-sided p-values of 'it holds', 'it fails' and, with a smallest effect,
        'it is equivalent' (two one-sided tests)."""
        est = self.estimate
        if self.within is not None:
            lo, hi = self.within
            return {
                HOLDS: max(est.p_above(lo), est.p_below(hi)),
                FAILS: min(est.p_below(lo), est.p_above(hi)),
            }
        p = {HOLDS: est.p_above(self.above), FAILS: est.p_below(self.above)}
        if self.smallest_effect:
            p[EQUIVALENT] = max(
                est.p_above(self.above - self.smallest_effect),
                est.p_below(self.above + self.smallest_effect),
            )
        return p

    def distance(self) -> float:
        """How far the estimate lies from what would decide the check: the nearer bound of
        a band; for ``above``, the threshold, or inside the smallest effect of interest
        whichever of 'beyond the threshold' and 'within the band' comes first."""
        value = self.estimate.value
        if self.within is not None:
            return min(abs(value - self.within[0]), abs(value - self.within[1]))
        gap = abs(value - self.above)
        if self.smallest_effect and gap < self.smallest_effect:
            return max(gap, self.smallest_effect - gap)
        return gap

    def routes(self) -> list[tuple[str, tuple[float, ...]]]:
        """The ways the check could be decided from where its estimate lies: each an outcome
        and the distances from the estimate to the bounds its one-sided tests must clear:
        beyond the threshold on the estimate's side, or (with a smallest effect of interest,
        from inside it) within the band, two tests."""
        value = self.estimate.value
        if self.within is not None:
            low, high = self.within
            if low < value < high:
                return [(HOLDS, (value - low, high - value))]
            return [(FAILS, (max(low - value, value - high),))]
        gap = abs(value - self.above)
        routes = [(HOLDS if value > self.above else FAILS, (gap,))]
        if self.smallest_effect and gap < self.smallest_effect:
            routes.append((EQUIVALENT, (self.smallest_effect - gap, self.smallest_effect + gap)))
        return routes

    def as_dict(self) -> dict[str, Any]:
        est = self.estimate
        return {
            "what": self.what,
            "id": self.id,
            "part": self.part,
            "estimate": est.value,
            "low": est.low,
            "high": est.high,
            "method": est.label,
            "quantity": est.as_dict(),
            "threshold": self.above,
            "band": list(self.within) if self.within else None,
            "smallest_effect": self.smallest_effect,
            "verdict": self.state,
            "p_adjusted": self.adjusted,
            "p_unadjusted": self.unadjusted,
            "seeds_meeting": self.seeds_meeting,
            "n": est.n,
            "not_testable": self.not_testable,
            "decide": self.decide,
            "decide_short": self.decide_short,
            "likely": self.likely,
            "contradicts": self.contradicts,
            "confirmatory": self.confirmatory,
            "exploratory": self.exploratory,
        }


def decide(checks: list[Check], alpha: float = ALPHA_ONE_SIDED) -> None:
    """Set every check's state: each outcome's one-sided p-values Holm-adjusted over the
    testable checks (one family per outcome, every check in it), each decided at ``alpha``."""
    testable = [c for c in checks if not c.not_testable and not c.counted]
    raw = [c.p_values() for c in testable]
    families = {o: holm([p.get(o, np.nan) for p in raw]) for o in (HOLDS, FAILS, EQUIVALENT)}
    for k, check in enumerate(testable):
        check.unadjusted = {o: float(v) for o, v in raw[k].items()}
        check.adjusted = {o: float(families[o][k]) for o in raw[k]}
        check.state = next(
            (
                o
                for o in (EQUIVALENT, HOLDS, FAILS)
                if np.isfinite(check.adjusted.get(o, np.nan)) and check.adjusted[o] < alpha
            ),
            INCONCLUSIVE,
        )
    for check in checks:
        if check.not_testable:
            check.state, check.adjusted, check.unadjusted = NOT_TESTABLE, {}, {}
        elif check.counted:
            met, of = check.seeds_meeting or 0, check.estimate.n
            check.state = HOLDS if met == of else FAILS if met == 0 else INCONCLUSIVE
