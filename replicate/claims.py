"""The claims ledger: each claim of the paper as checks over the run store, with a verdict.

Each claim declares one primary check here, beside its code and before any run is judged;
its other checks are secondary. A check compares a mean over seeds (or a difference of
means) with a threshold through a t-interval: paired on per-seed differences where the two
algorithms share seeds and initial weights (SAC and DRL-EG), Welch's otherwise.

A check *holds* when its interval lies wholly on the claimed side, *fails* when it lies
wholly on the other, is *equivalent* when a claimed difference lies wholly within the
smallest effect of interest (a difference too small to matter, not "better" or "worse"),
is *not testable at this budget* when a precondition was never observed, and is
*inconclusive* otherwise. Secondary checks decide on Holm-adjusted p-values (one family per
claim), so a claim with many checks is not failed by chance. The claim's verdict is its
primary check's: reproduced, not reproduced, inconclusive or not testable at this budget;
"partly reproduced" when the primary holds and a secondary check fails.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from replicate.stats import (
    CONFIDENCE,
    MeanEstimate,
    curve_area,
    holm,
    seed_matched_difference,
    seeds_to_decide,
    t_mean,
)
from replicate.templating import count_seeds

MOUNTAINCAR, HOPPER, WALKER, CHEETAH, ANT = (
    "MountainCarContinuous-v0",
    "Hopper-v5",
    "Walker2d-v5",
    "HalfCheetah-v5",
    "Ant-v5",
)
MUJOCO = (HOPPER, WALKER, CHEETAH, ANT)
MOUNTAINTOP = 90.0  # the paper's MountainCar success level
NEAR_ZERO = 10.0  # |return| below this counts as "learned nothing" on MountainCar
EQUIVALENCE_MARGIN = 0.10  # "indistinguishable": |DRL-EG - SAC| within 10% of SAC's return
NEAR_DEMOS = 0.90  # "almost the same performance as the demonstrations": >= 90% of R_demo
# The smallest difference of returns that matters: 10% of the demonstrations' return on the
# env (the task's scale); a difference whose interval lies within it is "equivalent".
SMALLEST_EFFECT = 0.10
SMALLEST_INSTABILITY = 0.10  # instability is a fraction of a curve's range
STUCK_FRACTION = 0.5  # a SAC seed is stuck when it ends below half of SAC's median seed
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

REPRODUCED, PARTLY, NOT_REPRODUCED = "reproduced", "partly reproduced", "not reproduced"
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
    (same seeds, same initial weights) or ran the same seeds, else Welch over all runs."""
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
            "seeds_meeting": self.seeds_meeting,
            "n": est.n,
            "not_testable": self.not_testable,
            "decide": self.decide,
        }


def decide(checks: list[Check]) -> None:
    """Set every check's state: the primary ones on their own p-values, the secondary ones
    on Holm-adjusted p-values, one family per outcome over the claim's secondary checks."""
    secondary = [c for c in checks if not c.primary and not c.not_testable]
    raw = [c.p_values() for c in secondary]
    families = {o: holm([p.get(o, np.nan) for p in raw]) for o in (HOLDS, FAILS, EQUIVALENT)}
    for check in checks:
        if check.not_testable:
            check.state, check.adjusted = NOT_TESTABLE, {}
            continue
        if check.primary:
            p = check.p_values()
        else:
            k = secondary.index(check)
            p = {o: families[o][k] for o in raw[k]}
        check.adjusted = {o: float(v) for o, v in p.items()}
        check.state = next(
            (
                o
                for o in (EQUIVALENT, HOLDS, FAILS)
                if np.isfinite(p.get(o, np.nan)) and p[o] < ALPHA_ONE_SIDED
            ),
            INCONCLUSIVE,
        )


def _hours(steps: int, rate: float, processes: int) -> str:
    hours = steps / (rate * processes) / 3600
    return f"{hours:.1f} h" if hours >= 1 else f"{hours * 60:.0f} min"


def what_would_decide(check: Check, family: int) -> tuple[str, str] | None:
    """For an inconclusive check: how many seeds would decide it if the observed effect and
    spread held (a secondary check at the Bonferroni level of its ``family``, which Holm's
    adjustment never asks more than), and what they would cost at the rates of the store's
    runs; in full and in short (for the front door)."""
    if check.state != INCONCLUSIVE:
        return None
    est = check.estimate
    if not est.defined:
        return ("a second seed: one run gives no interval",) * 2
    level = CONFIDENCE if check.primary else 1 - (1 - CONFIDENCE) / max(family, 1)
    needed = seeds_to_decide(est, check.distance(), level)
    unit = "pairs" if est.method.startswith("paired") else "seeds"
    if needed is None:
        text = (
            "no number of seeds at this budget: the estimate sits at what decides the "
            "check; only a longer budget (where the effect may differ) can"
        )
        return text, "no number of seeds at this budget; a longer budget might"
    per_group = (
        [needed - est.n] * len(check.groups)
        if est.n_other is None
        else [needed - est.n, needed - est.n_other][: len(check.groups)]
    )
    extra_runs = sum(max(0, k) for k in per_group)
    text = (
        f"about {needed} {unit} (the smallest n whose {level * 100:.3g}% {est.method} is "
        f"narrower than the distance {check.distance():.3g} to what decides it, at the "
        "observed mean and spread)"
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
    shorts = []
    for check in checks:
        full_and_short = what_would_decide(check, family)
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


def _need(groups: dict[tuple[str, str], Group], pairs: list[tuple[str, str]]) -> str | None:
    missing = [f"{LABELS[a]} on {e}" for e, a in pairs if (e, a) not in groups]
    return "no runs of " + ", ".join(missing) if missing else None


def _smallest_effect(env_id: str, demo_returns: dict[str, float]) -> float | None:
    return SMALLEST_EFFECT * abs(demo_returns[env_id]) if env_id in demo_returns else None


def _mean_check(
    what: str,
    group: Group,
    above: float | None = None,
    within: tuple[float, float] | None = None,
    meets: Callable[[np.ndarray], np.ndarray] | None = None,
    **kwargs: Any,
) -> Check:
    est = t_mean(group.finals, f"{where(group)}: {LABELS[group.algo]}, mean final return")
    return Check(
        what,
        est,
        above,
        within,
        seeds_meeting=int(meets(group.finals).sum()) if meets else None,
        groups=(group,),
        **kwargs,
    )


def _above_check(
    what: str,
    a: Group,
    b: Group,
    values: Callable[[Group], np.ndarray],
    quantity: str,
    smallest_effect: float | None,
    **kwargs: Any,
) -> Check:
    est = difference(a, b, values, quantity)
    return Check(what, est, above=0.0, smallest_effect=smallest_effect, groups=(a, b), **kwargs)


PRIMARY_CHECKS = {
    1: "MountainCar: DRL-EG minus SAC, final return (paired), above 0",
    2: "Hopper and HalfCheetah: DRL-EG minus SAC, final return (paired), within +-10% of "
    "SAC's return",
    3: "Walker2d and Ant: DRL-EG minus SAC, final return (paired), above 0",
    4: "Ant: instability of SAC minus DRL-EG's (paired), above 0",
    5: "Ant: on a seed where SAC is stuck, DRL-EG escapes (ends at least twice as high)",
}


def claim_1(groups: dict[tuple[str, str], Group], demo_returns: dict[str, float]) -> dict[str, Any]:
    """MountainCar. Primary: DRL-EG ends above SAC (paired). Secondary: DRL-EG reaches the
    goal; SAC and PPO end near 0; PPO+BC and DDPGfD learn but end below DRL-EG."""
    title = (
        "MountainCarContinuous: only the demonstration-guided methods leave 0, "
        "and DRL-EG ends on top"
    )
    paper = (
        "SAC and PPO end near 0; DRL-EG reaches the goal; PPO+BC and DDPGfD learn "
        "but end below DRL-EG"
    )
    why = _need(groups, [(MOUNTAINCAR, "drl-eg"), (MOUNTAINCAR, "sac")])
    if why:
        return not_judged(1, title, paper, why)
    drl, sac = groups[(MOUNTAINCAR, "drl-eg")], groups[(MOUNTAINCAR, "sac")]
    effect = _smallest_effect(MOUNTAINCAR, demo_returns)
    checks = [
        _above_check(PRIMARY_CHECKS[1], drl, sac, finals, "final return", effect, primary=True)
    ]
    used = [drl, sac]
    checks.append(
        _mean_check(
            f"DRL-EG final return above {MOUNTAINTOP:g}",
            drl,
            above=MOUNTAINTOP,
            meets=lambda f: f > MOUNTAINTOP,
        )
    )
    for algo in ("sac", "ppo"):
        if (MOUNTAINCAR, algo) in groups:
            g = groups[(MOUNTAINCAR, algo)]
            used.append(g)
            checks.append(
                _mean_check(
                    f"{LABELS[algo]} final return within +-{NEAR_ZERO:g}",
                    g,
                    within=(-NEAR_ZERO, NEAR_ZERO),
                    meets=lambda f: np.abs(f) <= NEAR_ZERO,
                )
            )
    for algo in ("ppo-bc", "ddpgfd"):
        if (MOUNTAINCAR, algo) in groups:
            g = groups[(MOUNTAINCAR, algo)]
            used.append(g)
            checks.append(
                _mean_check(
                    f"{LABELS[algo]} learns: final return above {NEAR_ZERO:g}",
                    g,
                    above=NEAR_ZERO,
                    meets=lambda f: f > NEAR_ZERO,
                )
            )
            checks.append(
                _above_check(
                    f"{LABELS[algo]} ends below DRL-EG: DRL-EG minus {LABELS[algo]} above 0",
                    drl,
                    g,
                    finals,
                    "final return",
                    effect,
                )
            )
    return judge(1, title, paper, checks, used)


def claim_2(groups: dict[tuple[str, str], Group], demo_returns: dict[str, float]) -> dict[str, Any]:
    """Hopper and HalfCheetah. Primary: DRL-EG minus SAC's final return within +-10% of
    SAC's mean final return on both envs (paired). Secondary: the same for the area under
    the curve."""
    title = "Hopper and HalfCheetah: DRL-EG and SAC are indistinguishable"
    paper = "when SAC already does well, guided exploration does not change the result"
    why = _need(groups, [(e, a) for e in (HOPPER, CHEETAH) for a in ("sac", "drl-eg")])
    if why:
        return not_judged(2, title, paper, why)
    checks, used = [], []
    for env_id in (HOPPER, CHEETAH):
        drl, sac = groups[(env_id, "drl-eg")], groups[(env_id, "sac")]
        used += [drl, sac]
        # SAC's return over the seeds the paired difference uses, so that SAC seeds
        # without a DRL-EG partner move neither the estimate nor its margin
        shared = [sac.seeds.index(s) for s in sorted(set(sac.seeds) & set(drl.seeds))]
        margin = EQUIVALENCE_MARGIN * abs(float(np.mean(sac.finals[shared])))
        checks.append(
            Check(
                f"{env_id}: DRL-EG minus SAC within +-{EQUIVALENCE_MARGIN:.0%} of SAC's return "
                f"(+-{margin:.0f})",
                difference(drl, sac, finals, "final return"),
                within=(-margin, margin),
                primary=True,
                groups=(drl, sac),
            )
        )
        area_margin = EQUIVALENCE_MARGIN * abs(float(np.mean(sac.areas[shared])))
        checks.append(
            Check(
                f"{env_id}: sample efficiency, area under the curve of DRL-EG minus SAC's within "
                f"+-{EQUIVALENCE_MARGIN:.0%} of SAC's (+-{area_margin:.0f})",
                difference(drl, sac, areas, "area under the curve"),
                within=(-area_margin, area_margin),
                groups=(drl, sac),
            )
        )
    return judge(2, title, paper, checks, used)


def published_reach(env_id: str, level: float, budget: int) -> tuple[str | None, str]:
    """Why ``level`` cannot be tested at ``budget`` (no published SAC reaches it by then;
    None: one does), and the budget at which published SAC first reaches it."""
    from replicate.published import published_points

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


def claim_3(groups: dict[tuple[str, str], Group], demo_returns: dict[str, float]) -> dict[str, Any]:
    """Walker2d and Ant. Primary: DRL-EG's final return above SAC's on both envs (paired).
    Secondary: above PPO, PPO+BC and DDPGfD (Welch), the same for the area under the curve,
    and a final return of at least 90% of the demonstrations' (not testable at a budget at
    which no published SAC reaches it)."""
    title = "Walker2d and Ant: DRL-EG beats every other algorithm and ends near the demonstrations"
    paper = (
        "DRL-EG outperforms all other RL and RLfD algorithms and almost reaches the "
        "demonstrations' return"
    )
    why = _need(groups, [(e, a) for e in (WALKER, ANT) for a in ("sac", "drl-eg")])
    missing_demos = [e for e in (WALKER, ANT) if e not in demo_returns]
    if why or missing_demos:
        return not_judged(
            3, title, paper, why or "no demonstrations on " + ", ".join(missing_demos)
        )
    checks: list[Check] = []
    used = []
    for env_id in (WALKER, ANT):
        drl = groups[(env_id, "drl-eg")]
        used.append(drl)
        effect = _smallest_effect(env_id, demo_returns)
        for algo in ("sac", "ppo", "ppo-bc", "ddpgfd"):
            if (env_id, algo) not in groups:
                continue
            other = groups[(env_id, algo)]
            used.append(other)
            what = (
                PRIMARY_CHECKS[3].split(": ", 1)[1].replace("Walker2d and Ant", env_id)
                if algo == "sac"
                else f"DRL-EG minus {LABELS[algo]}, final return, above 0"
            )
            checks.append(
                _above_check(
                    f"{env_id}: {what}",
                    drl,
                    other,
                    finals,
                    "final return",
                    effect,
                    primary=algo == "sac",
                )
            )
            checks.append(
                _above_check(
                    f"{env_id}: sample efficiency, area under the curve of DRL-EG minus "
                    f"{LABELS[algo]}'s above 0",
                    drl,
                    other,
                    areas,
                    "area under the curve",
                    effect,
                )
            )
        level = NEAR_DEMOS * demo_returns[env_id]
        blocked, _ = published_reach(env_id, level, drl.budget or 0)
        checks.append(
            _mean_check(
                f"{env_id}: DRL-EG final return at least {NEAR_DEMOS:.0%} of "
                f"the demonstrations' {demo_returns[env_id]:.0f}",
                drl,
                above=level,
                meets=lambda f, level=level: f >= level,
                not_testable=blocked,
            )
        )
    return judge(3, title, paper, checks, used)


def claim_4(groups: dict[tuple[str, str], Group], demo_returns: dict[str, float]) -> dict[str, Any]:
    """Ant. Primary: SAC's instability above DRL-EG's (paired; instability of a run is the
    sum of its curve's drops over its range). Secondary: DDPGfD's above DRL-EG's (Welch)."""
    title = "Ant: SAC and DDPGfD train unstably; DRL-EG is more stable"
    paper = "SAC and DDPGfD have an unstable training course on Ant; DRL-EG shows better stability"
    why = _need(groups, [(ANT, a) for a in ("drl-eg", "sac", "ddpgfd")])
    if why:
        return not_judged(4, title, paper, why)
    drl = groups[(ANT, "drl-eg")]
    checks, used = [], [drl]
    for algo in ("sac", "ddpgfd"):
        other = groups[(ANT, algo)]
        used.append(other)
        what = (
            PRIMARY_CHECKS[4]
            if algo == "sac"
            else f"Ant: instability of {LABELS[algo]} minus DRL-EG's, above 0"
        )
        checks.append(
            _above_check(
                what,
                other,
                drl,
                instabilities,
                "instability",
                SMALLEST_INSTABILITY,
                primary=algo == "sac",
            )
        )
    return judge(4, title, paper, checks, used)


PAPER_FIG4_SEEDS = 4  # the paired seeds of the paper's Fig. 4


def claim_5(groups: dict[tuple[str, str], Group], demo_returns: dict[str, float]) -> dict[str, Any]:
    """Fig. 4, Ant with paired seeds. Primary: on a seed where SAC is stuck (ends below half
    of SAC's median seed), DRL-EG escapes (ends at least twice as high as SAC on that
    seed); not testable while no SAC seed is stuck. Secondary: DRL-EG ends at least as high
    as SAC (paired difference above 0, with the smallest effect of interest)."""
    title = "Fig. 4, Ant with paired seeds: DRL-EG escapes a local optimum where SAC stays"
    paper = (
        "same seeds and initial weights: SAC stays in a local optimum on a seed where "
        "DRL-EG escapes; DRL-EG ends at least as high"
    )
    why = _need(groups, [(ANT, "drl-eg"), (ANT, "sac")])
    if why:
        return not_judged(5, title, paper, why)
    drl, sac = groups[(ANT, "drl-eg")], groups[(ANT, "sac")]
    common = sorted(set(drl.seeds) & set(sac.seeds))
    if not common:
        return not_judged(5, title, paper, "no SAC and DRL-EG runs on shared seeds")
    a = np.array([drl.finals[drl.seeds.index(s)] for s in common])
    b = np.array([sac.finals[sac.seeds.index(s)] for s in common])
    level = STUCK_FRACTION * float(np.median(b))
    stuck = b < level
    escaped = stuck & (a >= 2 * b) & (a > 0)
    budget = sac.budget or 0
    blocked = None
    if not stuck.any():
        blocked = (
            f"no SAC seed is stuck: on all {count_seeds(len(common), 'paired ')} SAC ends "
            f"above half of its median seed ({level:.0f}) by {budget:,} steps; "
            "the steps by which SAC seeds stall on Ant are not known from these runs "
            "(the paper's Fig. 4 budget is not stated in its text)"
        )
    counts = t_mean(
        escaped.astype(float), "Ant: share of paired seeds on which SAC is stuck and DRL-EG escapes"
    )
    primary = Check(
        PRIMARY_CHECKS[5],
        counts,
        above=0.0,
        primary=True,
        seeds_meeting=int(escaped.sum()),
        not_testable=blocked,
        groups=(drl, sac),
    )
    paired = _above_check(
        f"Ant, {count_seeds(len(common), 'paired ')}: DRL-EG minus SAC, final return, above 0",
        drl,
        sac,
        finals,
        "final return",
        _smallest_effect(ANT, demo_returns),
        seeds_meeting=int((a > b).sum()),
    )
    claim = judge(5, title, paper, [primary, paired], [drl, sac])
    if not blocked:  # decided by counting seeds, not by an interval
        claim["parts"][0].update(verdict=HOLDS if escaped.any() else FAILS, decide=None)
        claim["decides"] = []
        claim["verdict"] = REPRODUCED if escaped.any() else NOT_REPRODUCED
        if escaped.any() and claim["parts"][1]["verdict"] == FAILS:
            claim["verdict"] = PARTLY
    claim["paired"] = claim["effect"] = paired.estimate.as_dict()
    return claim


CLAIMS = (claim_1, claim_2, claim_3, claim_4, claim_5)
CLAIM_ENVS = {1: (MOUNTAINCAR,), 2: (HOPPER, CHEETAH), 3: (WALKER, ANT), 4: (ANT,), 5: (ANT,)}

# What a budget short of the paper's can and cannot show, one sentence per claim;
# ``{steps}`` is the budget of the claim's env.
BUDGET_NOTES = {
    2: "At {steps:,} steps SAC is still learning on Hopper and HalfCheetah, so equal curves "
    "here say that guidance does not slow SAC early; they cannot say the two end equal.",
    3: "At {steps:,} steps a lead of DRL-EG on Walker2d and Ant shows faster early learning "
    "(the paper's sample-efficiency claim); reaching the demonstrations' return may need "
    "a longer budget.",
    4: "Instability is measured over {steps:,} steps: drops late in training, which the "
    "paper's curves show on Ant, fall outside this budget.",
    5: "At {steps:,} steps a seed that SAC has not yet escaped from may still escape later; "
    "a paired lead of DRL-EG here is evidence of earlier escape, not of a different end.",
}
PAPER_MUJOCO_STEPS = 1_000_000  # not stated in the paper's text; its MuJoCo axes suggest 1M


def budget_note(claim_id: int, groups: dict[tuple[str, str], Group]) -> str | None:
    """The claim's budget sentence when its runs are shorter than the paper's, else None."""
    budgets = [
        g.budget
        for (env, _), g in groups.items()
        if env in CLAIM_ENVS.get(claim_id, ()) and g.budget is not None
    ]
    if claim_id not in BUDGET_NOTES or not budgets or max(budgets) >= PAPER_MUJOCO_STEPS:
        return None
    return BUDGET_NOTES[claim_id].format(steps=max(budgets))


def judge_claims(
    groups: dict[tuple[str, str], Group],
    demo_returns: dict[str, float],
    meaningful: bool,
    judged_envs: set[str] | None = None,
    fig4_groups: dict[tuple[str, str], Group] | None = None,
) -> list[dict[str, Any]]:
    """Every claim's verdict: claims 1-4 from ``groups`` (Fig. 3's runs), claim 5 from
    ``fig4_groups`` (Fig. 4's paired runs; None: not judged). A profile whose numbers mean
    nothing judges none; a claim on envs outside ``judged_envs`` (the profile's Fig. 3
    envs; None: every env) is not judged at this profile."""
    ledger = []
    for number, judge_claim in enumerate(CLAIMS, start=1):
        outside = judged_envs is not None and not set(CLAIM_ENVS[number]) <= judged_envs
        these = fig4_groups if number == 5 else groups
        if outside:
            claim = judge_claim({}, {})  # its title and wording, without numbers
            claim["verdict"] = "not judged at this profile's budget"
        elif these is None:
            claim = judge_claim({}, {})
            claim["verdict"] = "not judged: no Fig. 4 runs (paired seeds) in the store"
        else:
            claim = judge_claim(these, demo_returns)
            claim["budget_note"] = budget_note(number, these)
        claim.setdefault("budget_note", None)
        claim["primary_check"] = PRIMARY_CHECKS[number]
        if not meaningful and not claim["verdict"].startswith("not judged"):
            claim["verdict"] = "not judged (smoke profile: numbers mean nothing)"
        ledger.append(claim)
    return ledger
