"""The claims ledger: each claim of the paper as checks over the run store, with a verdict.

Each claim declares one primary check here, beside its code and before any run is judged;
its other checks are secondary. How a check decides is in ``replicate.checks``, how the
claim's verdict follows from its checks, and what would decide an open one, in
``replicate.verdicts``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from replicate.checks import (
    FAILS,
    HOLDS,
    LABELS,
    Check,
    Group,
    areas,
    difference,
    finals,
    instabilities,
    where,
)
from replicate.stats import t_mean
from replicate.templating import count_seeds
from replicate.verdicts import NOT_REPRODUCED, PARTLY, REPRODUCED, judge, not_judged

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
