"""The claims ledger: each claim of the paper as a check over the run store, with a verdict.

Every check compares a confidence interval with a threshold: it passes ("reproduced") when
the whole interval lies on the claimed side, fails ("not reproduced") when the whole
interval lies on the other side, and is "inconclusive" otherwise. A claim is reproduced
only when all its checks pass, and not reproduced as soon as one fails. A claim whose runs
are missing is "not judged", with what it needs. The thresholds are the harness's reading
of the paper's words and are stated beside each check.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from replicate.stats import (CONFIDENCE, bootstrap_mean, bootstrap_mean_difference,
                             curve_area, paired_difference, substream, welch_test)
from replicate.templating import count_seeds

# A check's bootstrap stream, named by its label: no check's interval depends on another's.
Streams = Callable[[str], np.random.Generator]

MOUNTAINCAR, HOPPER, WALKER, CHEETAH, ANT = ("MountainCarContinuous-v0", "Hopper-v5",
                                             "Walker2d-v5", "HalfCheetah-v5", "Ant-v5")
MOUNTAINTOP = 90.0  # the paper's MountainCar success level
NEAR_ZERO = 10.0  # |return| below this counts as "learned nothing" on MountainCar
EQUIVALENCE_MARGIN = 0.10  # "indistinguishable": |DRL-EG - SAC| within 10% of SAC's return
NEAR_DEMOS = 0.90  # "almost the same performance as the demonstrations": >= 90% of R_demo
LABELS = {"sac": "SAC", "ppo": "PPO", "ppo-bc": "PPO+BC", "ddpgfd": "DDPGfD",
          "drl-eg": "DRL-EG", "drl-eg-gmm": "DRL-EG (GMM)"}


@dataclass
class Group:
    """The runs of one algorithm on one env, by seed: final returns and curves."""

    env_id: str
    algo: str
    seeds: list[int]
    finals: np.ndarray  # (runs,) return at the last evaluation point
    curves: np.ndarray  # (runs, points) over the evaluation steps all runs share
    steps: np.ndarray | None = None  # (points,) those steps; None: evenly spaced

    @property
    def areas(self) -> np.ndarray:
        """Per run, the mean return over the curve (``replicate.stats.curve_area``)."""
        steps = self.steps if self.steps is not None else np.arange(self.curves.shape[1])
        return curve_area(steps, self.curves)


def interval_verdict(low: float, high: float, inside: tuple[float, float]) -> str:
    """reproduced if [low, high] lies inside ``inside``, not reproduced if wholly outside."""
    lo, hi = inside
    if np.isnan(low) or np.isnan(high):
        return "inconclusive"
    if lo <= low and high <= hi:
        return "reproduced"
    if high < lo or low > hi:
        return "not reproduced"
    return "inconclusive"


def combine(verdicts: list[str]) -> str:
    if "not reproduced" in verdicts:
        return "not reproduced"
    return "reproduced" if verdicts and set(verdicts) == {"reproduced"} else "inconclusive"


def instability(curve: np.ndarray) -> float:
    """Sum of the drops between consecutive evaluations, over the curve's range: 0 for a
    curve that never falls, about 1 for one that gives back everything it gained once."""
    drops = np.clip(-np.diff(curve), 0.0, None).sum()
    spread = np.ptp(curve)
    return float(drops / spread) if spread > 0 else 0.0


def _check(what: str, low: float, high: float, estimate: float, inside: tuple[float, float],
           seeds_meeting: int | None = None, n: int | None = None) -> dict[str, Any]:
    return {"what": what, "estimate": float(estimate), "low": float(low), "high": float(high),
            "verdict": interval_verdict(float(low), float(high), inside),
            "seeds_meeting": seeds_meeting, "n": n}


def _mean_check(what: str, group: Group, inside: tuple[float, float], streams: Streams,
                meets: Callable[[np.ndarray], np.ndarray]) -> dict[str, Any]:
    est = bootstrap_mean(group.finals, streams(what))
    return _check(what, est.low[0], est.high[0], est.value[0], inside,
                  int(meets(group.finals).sum()), len(group.finals))


def _difference_check(what: str, a: np.ndarray, b: np.ndarray, inside: tuple[float, float],
                      streams: Streams) -> dict[str, Any]:
    diff = bootstrap_mean_difference(a, b, streams(what))
    return _check(what, diff.low, diff.high, diff.value, inside)


def _effect(a: Group, b: Group, streams: Streams) -> dict[str, Any]:
    name = f"{LABELS[a.algo]} minus {LABELS[b.algo]} on {a.env_id}, mean final return"
    diff = bootstrap_mean_difference(a.finals, b.finals, streams(name))
    t_stat, p_value = welch_test(a.finals, b.finals)
    return {"name": name, "value": float(diff.value), "low": float(diff.low),
            "high": float(diff.high),
            "test": f"percentile bootstrap ({CONFIDENCE:.0%}); Welch t = {t_stat:.2f}, "
                    f"p = {p_value:.3g}"}


def _claim(claim_id: int, title: str, paper: str, parts: list[dict], groups: list[Group],
           effect: dict | None = None, missing: list[str] | None = None) -> dict[str, Any]:
    if missing:
        verdict = "not judged: no runs of " + ", ".join(missing)
    else:
        verdict = combine([p["verdict"] for p in parts])
    return {"id": claim_id, "title": title, "paper": paper, "verdict": verdict, "parts": parts,
            "effect": effect,
            "algorithms": sorted({f"{LABELS[g.algo]} on {g.env_id} ({count_seeds(len(g.seeds))})"
                                  for g in groups})}


def _need(groups: dict[tuple[str, str], Group], pairs: list[tuple[str, str]]) -> list[str]:
    return [f"{LABELS[a]} on {e}" for e, a in pairs if (e, a) not in groups]


def claim_1(groups: dict[tuple[str, str], Group], demo_returns: dict[str, float],
            streams: Streams) -> dict[str, Any]:
    """MountainCar: SAC and PPO end near 0; DRL-EG reaches the goal; PPO+BC and DDPGfD learn
    but end below DRL-EG. Checks on algorithms without runs are left out, DRL-EG's is needed."""
    title = "MountainCarContinuous: only the demonstration-guided methods leave 0, and DRL-EG ends on top"
    paper = "SAC and PPO end near 0; DRL-EG reaches the goal; PPO+BC and DDPGfD learn but end below DRL-EG"
    missing = _need(groups, [(MOUNTAINCAR, "drl-eg")])
    if missing:
        return _claim(1, title, paper, [], [], missing=missing)
    drl = groups[(MOUNTAINCAR, "drl-eg")]
    used = [drl]
    parts = [_mean_check(f"DRL-EG final return above {MOUNTAINTOP:g}", drl, (MOUNTAINTOP, np.inf),
                         streams, lambda f: f > MOUNTAINTOP)]
    for algo in ("sac", "ppo"):
        if (MOUNTAINCAR, algo) in groups:
            g = groups[(MOUNTAINCAR, algo)]
            used.append(g)
            parts.append(_mean_check(f"{LABELS[algo]} final return within +-{NEAR_ZERO:g}", g,
                                     (-NEAR_ZERO, NEAR_ZERO), streams,
                                     lambda f: np.abs(f) <= NEAR_ZERO))
    for algo in ("ppo-bc", "ddpgfd"):
        if (MOUNTAINCAR, algo) in groups:
            g = groups[(MOUNTAINCAR, algo)]
            used.append(g)
            parts.append(_mean_check(f"{LABELS[algo]} learns: final return above {NEAR_ZERO:g}",
                                     g, (NEAR_ZERO, np.inf), streams, lambda f: f > NEAR_ZERO))
            parts.append(_difference_check(f"{LABELS[algo]} ends below DRL-EG: DRL-EG minus "
                                           f"{LABELS[algo]} above 0", drl.finals, g.finals,
                                           (0.0, np.inf), streams))
    effect = (_effect(drl, groups[(MOUNTAINCAR, "sac")], streams)
              if (MOUNTAINCAR, "sac") in groups else None)
    return _claim(1, title, paper, parts, used, effect)


def claim_2(groups, demo_returns, streams) -> dict[str, Any]:
    """Hopper and HalfCheetah: DRL-EG and SAC are indistinguishable (equivalence within a
    margin of 10% of SAC's mean final return)."""
    title = "Hopper and HalfCheetah: DRL-EG and SAC are indistinguishable"
    paper = "when SAC already does well, guided exploration does not change the result"
    missing = _need(groups, [(e, a) for e in (HOPPER, CHEETAH) for a in ("sac", "drl-eg")])
    if missing:
        return _claim(2, title, paper, [], [], missing=missing)
    parts, used = [], []
    for env_id in (HOPPER, CHEETAH):
        drl, sac = groups[(env_id, "drl-eg")], groups[(env_id, "sac")]
        used += [drl, sac]
        margin = EQUIVALENCE_MARGIN * abs(float(np.mean(sac.finals)))
        parts.append(_difference_check(
            f"{env_id}: DRL-EG minus SAC within +-{EQUIVALENCE_MARGIN:.0%} of SAC's return "
            f"(+-{margin:.0f})", drl.finals, sac.finals, (-margin, margin), streams))
        area_margin = EQUIVALENCE_MARGIN * abs(float(np.mean(sac.areas)))
        parts.append(_difference_check(
            f"{env_id}: sample efficiency, area under the curve of DRL-EG minus SAC's within "
            f"+-{EQUIVALENCE_MARGIN:.0%} of SAC's (+-{area_margin:.0f})", drl.areas, sac.areas,
            (-area_margin, area_margin), streams))
    return _claim(2, title, paper, parts, used, _effect(groups[(HOPPER, "drl-eg")],
                                                        groups[(HOPPER, "sac")], streams))


def claim_3(groups, demo_returns, streams) -> dict[str, Any]:
    """Walker2d and Ant: DRL-EG beats every other algorithm that has runs, and its final
    return reaches 90% of the demonstrations' return."""
    title = "Walker2d and Ant: DRL-EG beats every other algorithm and ends near the demonstrations"
    paper = "DRL-EG outperforms all other RL and RLfD algorithms and almost reaches the demonstrations' return"
    missing = _need(groups, [(e, a) for e in (WALKER, ANT) for a in ("sac", "drl-eg")])
    missing += [f"demonstrations on {e}" for e in (WALKER, ANT) if e not in demo_returns]
    if missing:
        return _claim(3, title, paper, [], [], missing=missing)
    parts, used = [], []
    for env_id in (WALKER, ANT):
        drl = groups[(env_id, "drl-eg")]
        used.append(drl)
        for algo in ("sac", "ppo", "ppo-bc", "ddpgfd"):
            if (env_id, algo) in groups:
                other = groups[(env_id, algo)]
                used.append(other)
                parts.append(_difference_check(
                    f"{env_id}: DRL-EG minus {LABELS[algo]} above 0", drl.finals, other.finals,
                    (0.0, np.inf), streams))
                parts.append(_difference_check(
                    f"{env_id}: sample efficiency, area under the curve of DRL-EG minus "
                    f"{LABELS[algo]}'s above 0", drl.areas, other.areas, (0.0, np.inf),
                    streams))
        level = NEAR_DEMOS * demo_returns[env_id]
        parts.append(_mean_check(f"{env_id}: DRL-EG final return at least {NEAR_DEMOS:.0%} of "
                                 f"the demonstrations' {demo_returns[env_id]:.0f}", drl,
                                 (level, np.inf), streams, lambda f, level=level: f >= level))
    return _claim(3, title, paper, parts, used, _effect(groups[(ANT, "drl-eg")],
                                                        groups[(ANT, "sac")], streams))


def claim_4(groups, demo_returns, streams) -> dict[str, Any]:
    """Ant: SAC and DDPGfD train unstably, DRL-EG more stably. Instability of a run: the sum
    of its curve's drops over its range; checked as a difference of means over seeds."""
    title = "Ant: SAC and DDPGfD train unstably; DRL-EG is more stable"
    paper = "SAC and DDPGfD have an unstable training course on Ant; DRL-EG shows better stability"
    missing = _need(groups, [(ANT, a) for a in ("drl-eg", "sac", "ddpgfd")])
    if missing:
        return _claim(4, title, paper, [], [], missing=missing)
    drl = groups[(ANT, "drl-eg")]
    drl_instability = np.array([instability(c) for c in drl.curves])
    parts, used = [], [drl]
    for algo in ("sac", "ddpgfd"):
        other = groups[(ANT, algo)]
        used.append(other)
        other_instability = np.array([instability(c) for c in other.curves])
        parts.append(_difference_check(f"Ant: instability of {LABELS[algo]} minus DRL-EG's "
                                       "above 0", other_instability, drl_instability,
                                       (0.0, np.inf), streams))
    return _claim(4, title, paper, parts, used)


PAPER_FIG4_SEEDS = 4  # the paired seeds of the paper's Fig. 4


def claim_5(groups, demo_returns, streams) -> dict[str, Any]:
    """Fig. 4: on Ant, with the same seeds and initial weights, DRL-EG ends above SAC (paired
    difference over seeds) and escapes where SAC stays stuck on at least one seed."""
    title = "Fig. 4, Ant with paired seeds: DRL-EG escapes a local optimum where SAC stays"
    paper = "same seeds and initial weights: SAC stays in a local optimum on a seed where DRL-EG escapes; DRL-EG ends at least as high"
    missing = _need(groups, [(ANT, "drl-eg"), (ANT, "sac")])
    if missing:
        return _claim(5, title, paper, [], [], missing=missing)
    drl, sac = groups[(ANT, "drl-eg")], groups[(ANT, "sac")]
    common = sorted(set(drl.seeds) & set(sac.seeds))
    if not common:
        return _claim(5, title, paper, [], [], missing=["SAC and DRL-EG runs on shared seeds"])
    a = np.array([drl.finals[drl.seeds.index(s)] for s in common])
    b = np.array([sac.finals[sac.seeds.index(s)] for s in common])
    estimate, p_value = paired_difference(a, b, streams("Ant: paired DRL-EG minus SAC"))
    wilcoxon = ("no Wilcoxon signed-rank p: fewer than 2 pairs or no difference"
                if np.isnan(p_value) else f"Wilcoxon signed-rank p = {p_value:.3g}")
    part = _check(f"Ant, {count_seeds(len(common), 'paired ')}: DRL-EG minus SAC above 0 "
                  f"({wilcoxon})", estimate.low, estimate.high,
                  estimate.value, (0.0, np.inf), int((a > b).sum()), len(common))
    escaped = int(((b < 0.5 * a) & (a > 0)).sum())
    # no such seed among fewer pairs than the paper showed cannot say it would not appear
    absent = "not reproduced" if len(common) >= PAPER_FIG4_SEEDS else (
        f"inconclusive ({len(common)} of the paper's {PAPER_FIG4_SEEDS} paired seeds)")
    stuck = {"what": "a seed on which SAC ends below half of DRL-EG's return",
             "estimate": float(escaped), "low": float(escaped), "high": float(escaped),
             "verdict": "reproduced" if escaped else absent,
             "seeds_meeting": escaped, "n": len(common)}
    return _claim(5, title, paper, [part, stuck], [drl, sac])


CLAIMS = (claim_1, claim_2, claim_3, claim_4, claim_5)

# What a budget short of the paper's (about 1M env steps on MuJoCo) can and cannot show,
# one sentence per claim; ``{steps}`` is the budget of the claim's env.
BUDGET_NOTES = {
    2: "At {steps:,} steps SAC is still learning on Hopper and HalfCheetah, so equal curves "
       "here say that guidance does not slow SAC early; they cannot say the two end equal.",
    3: "At {steps:,} steps a lead of DRL-EG on Walker2d and Ant shows faster early learning "
       "(the paper's sample-efficiency claim); reaching the demonstrations' return may need "
       "the paper's full budget, so a miss on that part leaves the claim not reproduced at "
       "this budget, not refuted at the paper's.",
    4: "Instability is measured over {steps:,} steps: drops late in training, which the "
       "paper's curves show on Ant, fall outside this budget.",
    5: "At {steps:,} steps a seed that SAC has not yet escaped from may still escape later; "
       "a paired lead of DRL-EG here is evidence of earlier escape, not of a different end.",
}
CLAIM_ENVS = {2: (HOPPER, CHEETAH), 3: (WALKER, ANT), 4: (ANT,), 5: (ANT,)}
PAPER_MUJOCO_STEPS = 1_000_000


def budget_note(claim_id: int, groups: dict[tuple[str, str], Group]) -> str | None:
    """The claim's budget sentence when its runs are shorter than the paper's, else None."""
    budgets = [int(g.steps[-1]) for (env, _), g in groups.items()
               if env in CLAIM_ENVS.get(claim_id, ()) and g.steps is not None]
    if claim_id not in BUDGET_NOTES or not budgets or max(budgets) >= PAPER_MUJOCO_STEPS:
        return None
    return BUDGET_NOTES[claim_id].format(steps=max(budgets))


def claim_streams(seed: int, number: int) -> Streams:
    """Claim ``number``'s bootstrap streams, one per check, named by the check's label."""
    return lambda label: substream(seed, f"claim {number}", label)


def judge_claims(groups: dict[tuple[str, str], Group], demo_returns: dict[str, float],
                 seed: int, meaningful: bool) -> list[dict[str, Any]]:
    """Every claim's verdict; a profile whose numbers mean nothing judges none. Each check
    of each claim draws its bootstrap from a stream of its own, so adding runs that another
    check uses leaves its interval as it was."""
    ledger = []
    for number, judge in enumerate(CLAIMS, start=1):
        claim = judge(groups, demo_returns, claim_streams(seed, number))
        claim["budget_note"] = budget_note(number, groups)
        if not meaningful and not claim["verdict"].startswith("not judged"):
            claim["verdict"] = "not judged (smoke profile: numbers mean nothing)"
        ledger.append(claim)
    return ledger
