"""A check: an estimate over a group of runs (a mean over seeds, or a difference of means)
against a threshold or a band, through a t-interval: paired on per-seed differences where
the two algorithms share initial weights seed by seed (SAC and DRL-EG), Welch's otherwise.

A check *holds* when its one-sided test of the claimed side rejects at 2.5% (for a primary
check: its 95% interval lies wholly on the claimed side), *fails* when the test of the
other side does, is *equivalent* when two one-sided tests put a claimed difference within
the smallest effect of interest (a difference too small to matter, not "better" or
"worse"), is *not testable at this budget* when a precondition was never observed, and is
*inconclusive* otherwise. Secondary checks decide on Holm-adjusted p-values (one family per
claim), so a claim with many checks is not failed by chance; their 95% intervals are shown
unadjusted, so one can clear its threshold and still be inconclusive. A claim judged on two
envs is not reproduced when either env's primary check fails or is equivalent after Holm's
adjustment over the two (the route to "reproduced" needs no adjustment: both must hold).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from replicate.stats import CONFIDENCE, MeanEstimate, curve_area, holm, seed_matched_difference

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
    finals: np.ndarray  # (runs,) return at the last evaluation point
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


def instability(curve: np.ndarray) -> float:
    """Sum of the drops between consecutive evaluations, over the curve's range: 0 for a
    curve that never falls, about 1 for one that gives back everything it gained once."""
    drops = np.clip(-np.diff(curve), 0.0, None).sum()
    spread = np.ptp(curve)
    return float(drops / spread) if spread > 0 else 0.0


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
    return np.array([instability(c) for c in group.curves])


@dataclass
class Check:
    """One check: an estimate against the claimed side of a threshold (``above``) or
    inside a band (``within``), with the p-values that decide it."""

    what: str
    estimate: MeanEstimate
    above: float | None = None
    within: tuple[float, float] | None = None
    smallest_effect: float | None = None  # for ``above`` on a difference
    primary: bool = False
    seeds_meeting: int | None = None
    not_testable: str | None = None  # why the check cannot be decided at this budget
    groups: tuple[Group, ...] = ()  # whose runs more seeds would add to
    state: str = INCONCLUSIVE
    adjusted: dict[str, float] = field(default_factory=dict)
    unadjusted: dict[str, float] = field(default_factory=dict)
    decide: str | None = None

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
            "role": "primary" if self.primary else "secondary",
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
        }


def decide(checks: list[Check]) -> None:
    """Set every check's state. Secondary checks decide on Holm-adjusted p-values, one
    family per outcome over the claim's secondary checks. Primary checks decide "holds" on
    their own p-values (all must hold: an intersection-union test) and "fails" or
    "equivalent" on p-values Holm-adjusted over the claim's primary checks (either one
    would make the claim not reproduced)."""
    testable = [c for c in checks if not c.not_testable]
    for role in (False, True):
        members = [c for c in testable if c.primary == role]
        raw = [c.p_values() for c in members]
        adjusted_outcomes = (FAILS, EQUIVALENT) if role else (HOLDS, FAILS, EQUIVALENT)
        families = {o: holm([p.get(o, np.nan) for p in raw]) for o in adjusted_outcomes}
        for k, check in enumerate(members):
            p = {o: (families[o][k] if o in families else v) for o, v in raw[k].items()}
            check.unadjusted = {o: float(v) for o, v in raw[k].items()}
            check.adjusted = {o: float(v) for o, v in p.items()}
            check.state = next(
                (
                    o
                    for o in (EQUIVALENT, HOLDS, FAILS)
                    if np.isfinite(p.get(o, np.nan)) and p[o] < ALPHA_ONE_SIDED
                ),
                INCONCLUSIVE,
            )
    for check in checks:
        if check.not_testable:
            check.state, check.adjusted, check.unadjusted = NOT_TESTABLE, {}, {}
