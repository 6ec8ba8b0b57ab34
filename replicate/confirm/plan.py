"""Confirmatory plans: for each open check of a profile's claims, the fresh seeds that would
decide it with an 80% chance in one registered test, what they cost and which claim
verdicts the outcome could reach. ``replicate.confirm.register`` writes a plan under
``plans/`` (committed before its runs train) and trains its runs; ``replicate.claims.confirm_judge``
judges a plan on its own runs.

A plan is sized from the exploratory runs (the reports' seeds) but tested on fresh seeds
alone: at the observed effect, with the spread at sigma's one-sided 80% upper confidence
limit (sized at the point estimate of a spread from 5 seeds, a plan is underpowered more
often than not), for a single test at the declaration's one-sided level.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from replicate.claims.checks import EQUIVALENT, FAILS, HOLDS, INCONCLUSIVE, Check
from replicate.claims.confirm_judge import PLANS_DIR, SEED_BLOCK, plan_path, read_plan
from replicate.claims.declaration import CheckSpec, Declaration, load_declaration
from replicate.claims.groups import claim_groups
from replicate.claims.judge import build_check, judge_claims
from replicate.claims.verdicts import MOST_SEEDS, claim_verdict, part_state, scaled_spread
from replicate.errors import HarnessError
from replicate.figures.fig3 import figure3_command, figure3_grid
from replicate.figures.fig4 import figure4_runs
from replicate.grids.profiles import Profile
from replicate.grids.train import stored_outcome
from replicate.stats import (
    DECIDING_CHANCE,
    PAIRED_METHOD,
    MeanEstimate,
    chance_to_decide,
    seeds_to_decide,
)
from replicate.store import checkpoint_places

SIGMA_UPPER = 0.80  # the spread assumed: sigma's one-sided upper confidence limit at this level
CPU_PROCESSES = 2  # costs are stated for a 2-core CPU machine, one process per core
GPU_PROCESSES = 1


@dataclass(frozen=True)
class OpenCheck:
    """An inconclusive check of the ledger, with what it was judged on."""

    claim: dict[str, Any]  # the ledger's claim
    part: str
    spec: CheckSpec
    check: Check  # its estimate over the exploratory runs, and their groups
    likely: str | None  # the outcome the ledger found more seeds would most likely give
    grid: str  # "fig3" or "fig4": the grid whose runs it reads
    runs: tuple[str, ...]  # the exploratory runs' ids


@dataclass(frozen=True)
class Plan:
    """One open check's confirmatory plan (``n`` None: more than ``MOST_SEEDS`` needed)."""

    profile: Profile
    declaration: Declaration
    open: OpenCheck
    outcome: str  # the outcome it is powered for
    distances: tuple[float, ...]  # from the estimate to the bounds that outcome's tests clear
    sigma_factor: float  # assumed spread over observed
    n: int | None  # seeds per algorithm (pairs for a paired difference)
    power: float | None
    seeds: tuple[int, ...]
    level: float  # each one-sided test's
    reachable: dict[str, str]  # the claim's verdict if the check came out so

    @property
    def check_id(self) -> str:
        return self.open.check.id or ""

    @property
    def spec(self) -> CheckSpec:
        return self.open.spec

    @property
    def estimate(self) -> MeanEstimate:
        return self.open.check.estimate

    @property
    def algos(self) -> tuple[str, ...]:
        return (self.spec.algo,) + ((self.spec.other,) if self.spec.other else ())

    @property
    def paired(self) -> bool:
        return self.estimate.method == PAIRED_METHOD

    @property
    def unit(self) -> str:
        return "pairs" if self.paired else "seeds"

    @property
    def steps(self) -> int:
        return self.profile_budget[0]

    @property
    def profile_budget(self) -> tuple[int, int]:
        """(env steps, evaluation interval) of the grid's runs of this env."""
        if self.open.grid == "fig4":
            from replicate.grids.profiles import BUDGETS

            return BUDGETS["fig4"][self.profile.name][self.spec.env]
        return self.profile.steps[self.spec.env], self.profile.eval_interval[self.spec.env]

    @property
    def runs(self) -> int:
        return (self.n or MOST_SEEDS) * len(self.algos)

    @property
    def env_steps(self) -> int:
        return self.runs * self.steps

    def hours(self, kind: str = "cpu") -> float | None:
        """Wall-clock hours on a 2-core CPU machine (``cpu``: 2 processes) or a GPU machine
        (``gpu``: 1 process), at the process rates the exploratory runs recorded; None where
        a cell recorded none."""
        rates = {g.algo: g.rates.get(kind) for g in self.open.check.groups}
        if not all(rates.get(a) for a in self.algos):
            return None
        seconds = sum((self.n or MOST_SEEDS) * self.steps / rates[a] for a in self.algos)
        return seconds / (CPU_PROCESSES if kind == "cpu" else GPU_PROCESSES) / 3600

    @property
    def sd_observed(self) -> tuple[float, ...]:
        """The per-seed spread: of the differences or runs, or per group for Welch."""
        est = self.estimate
        if est.variances is not None:
            return tuple(math.sqrt(v) for v in est.variances)
        return (est.se * math.sqrt(est.n),)

    @property
    def sd_assumed(self) -> tuple[float, ...]:
        return tuple(s * self.sigma_factor for s in self.sd_observed)

    @property
    def verdict_now(self) -> str:
        return self.open.claim["verdict"]

    @property
    def test_name(self) -> str:
        return {PAIRED_METHOD: "paired t-test", "Welch t-interval": "Welch t-test"}.get(
            self.estimate.method, "one-sample t-test"
        )


def sigma_upper_factor(df: float, level: float = SIGMA_UPPER) -> float:
    """Sigma's one-sided ``level`` upper confidence limit over its estimate: chi-square on
    ``df`` degrees of freedom."""
    if not np.isfinite(df) or df <= 0:
        return float("nan")
    return float(np.sqrt(df / stats.chi2.ppf(1 - level, df)))


def route_words(spec: CheckSpec, outcome: str) -> str:
    """What the outcome's test must show, in words."""
    if spec.within is not None:
        low, high = spec.within
        if outcome == HOLDS:
            return f"within [{low:g}, {high:g}] (two one-sided tests)"
        return f"outside [{low:g}, {high:g}] (one-sided test)"
    if outcome == EQUIVALENT:
        effect = spec.smallest_effect or 0.0
        return f"within +-{effect:g} of {spec.above:g} (two one-sided tests)"
    return f"{'above' if outcome == HOLDS else 'below'} {spec.above:g} (one-sided test)"


def reachable_verdicts(claim: dict[str, Any], check_id: str, outcomes: list[str]) -> dict[str, str]:
    """The claim's verdict were ``check_id`` decided each of ``outcomes``, the other checks
    as the ledger left them."""
    met = all(p["observed"] for p in claim.get("preconditions", []))
    reached = {}
    for outcome in outcomes:
        states = []
        for part in claim["parts"]:
            pairs = [
                (outcome, outcome == FAILS or (outcome == EQUIVALENT and c["band"] is None))
                if c["id"] == check_id
                else (c["verdict"], bool(c.get("contradicts")))
                for c in part["checks"]
            ]
            states.append(part_state(pairs))
        reached[outcome] = claim_verdict(states, met)
    return reached


def outcomes_of(spec: CheckSpec) -> list[str]:
    """The states a test of the check can reach besides inconclusive."""
    return [HOLDS, FAILS] + ([EQUIVALENT] if spec.smallest_effect else [])


# Which seeds the store holds: run directories are named <algo>__<env>__s<seed>__<hash>, the
# unfinished ones behind a '.partial-' or '.lock-' prefix.
_RUN_NAME = re.compile(r"^\.?(?:partial-|lock-)?(?P<algo>.+?)__(?P<env>.+)__s(?P<seed>\d+)__\w+$")


def used_seeds(
    store: Path,
    cells: set[tuple[str, str]],
    plans_dir: Path | None = PLANS_DIR,
    besides: Path | None = None,
) -> set[int]:
    """Every seed of the (env, algo) ``cells`` that the store holds, finished, unfinished or
    carried, at any budget, and that a plan in ``plans_dir`` other than ``besides`` (the
    check's own, rewritten until committed) registered."""

    store = Path(store)
    names = [p.name for p in store.iterdir()] if store.is_dir() else []
    names += [m for k in checkpoint_places.kept(store) for m in k.members]
    slugs = {(env.replace("/", "-"), algo) for env, algo in cells}
    seeds = set()
    for name in names:
        match = _RUN_NAME.match(name)
        if match and (match["env"], match["algo"]) in slugs:
            seeds.add(int(match["seed"]))
    for path in sorted(Path(plans_dir).glob("*.toml")) if plans_dir else []:
        if besides is not None and path.resolve() == Path(besides).resolve():
            continue
        plan = read_plan(path)
        planned = {(plan["check"]["env"], a) for a in plan["runs"]["algos"]}
        if planned & cells:
            seeds.update(plan["runs"]["seeds"])
    return seeds


def fresh_seeds(used: set[int], n: int) -> tuple[int, ...]:
    """``n`` seeds from the first block of ``SEED_BLOCK`` (after the first) that ``used``
    does not touch."""
    start = SEED_BLOCK
    while any(start <= s < start + SEED_BLOCK for s in used):
        start += SEED_BLOCK
    return tuple(range(start, start + n))


def open_checks(
    profile: Profile, store: Path, declaration: Declaration | None = None
) -> list[OpenCheck]:
    """Every inconclusive check of the profile's claims, judged with ``declaration`` (the
    paper's by default) on the profile's Fig. 3 and Fig. 4 runs in the store. Judged even
    where the profile's numbers mean nothing (smoke), so that plans can be tried there."""

    declaration = declaration or load_declaration()
    specs, skipped = figure3_grid(profile)
    outcome = stored_outcome(
        specs, skipped, profile.name, Path(store), figure3_command(profile.name)
    )
    runs = {"fig3": outcome.runs if outcome else [], "fig4": figure4_runs(profile.name, store)}
    groups = {grid: claim_groups(r) for grid, r in runs.items()}
    claims = judge_claims(
        groups["fig3"], True, set(profile.steps), groups["fig4"] or None, declaration
    )
    found = []
    for claim, claim_spec in zip(claims, declaration.claims):
        states = {c["id"]: c for p in claim["parts"] for c in p["checks"]}
        for part in claim_spec.parts:
            for k, spec in enumerate(part.checks, start=1):
                judged = states.get(f"{part.id}.{k}")
                if judged is None or judged["verdict"] != INCONCLUSIVE:
                    continue
                check = build_check(spec, part.id, groups[claim_spec.runs], declaration.confidence)
                check.id = f"{part.id}.{k}"
                cells = {(spec.env, a) for a in (spec.algo, spec.other) if a}
                run_ids = tuple(
                    r.path.name
                    for r in runs[claim_spec.runs]
                    if (r.spec["env_id"], r.spec["algo"]) in cells
                )
                found.append(
                    OpenCheck(
                        claim, part.id, spec, check, judged["likely"], claim_spec.runs, run_ids
                    )
                )
    return found


def plan_check(
    found: OpenCheck,
    profile: Profile,
    declaration: Declaration,
    store: Path,
    plans_dir: Path | None = PLANS_DIR,
) -> Plan | str:
    """The plan for one open check, or why it has none."""
    est = found.check.estimate
    if found.check.counted:
        return "decided by counting seeds, not by a test"
    if not est.defined or not np.isfinite(est.se):
        return "its estimate has no interval (fewer than 2 runs)"
    routes = {o: d for o, d in found.check.routes() if min(d) > 0}
    if not routes:
        return "its estimate sits exactly at what decides it: no number of seeds can"
    factor = sigma_upper_factor(est.df)
    if not np.isfinite(factor):
        return "its spread has no degrees of freedom"
    assumed = scaled_spread(est, factor)
    confidence = declaration.confidence
    needs = {
        o: seeds_to_decide(assumed, [d], confidence, DECIDING_CHANCE, MOST_SEEDS)
        for o, d in routes.items()
    }
    # the route the ledger's likely outcome names; else the one decided with fewest seeds
    outcome = (
        found.likely
        if found.likely in routes
        else min(routes, key=lambda o: needs[o] or MOST_SEEDS + 1)
    )
    n = needs[outcome]
    if n is not None:
        n = max(2, n)
    power = chance_to_decide(assumed, routes[outcome], n, confidence) if n else None
    cells = {(found.spec.env, a) for a in (found.spec.algo, found.spec.other) if a}
    own = plan_path(profile.name, found.check.id or "", plans_dir) if plans_dir else None
    seeds = fresh_seeds(used_seeds(store, cells, plans_dir, own), n or MOST_SEEDS)
    return Plan(
        profile,
        declaration,
        found,
        outcome,
        routes[outcome],
        factor,
        n,
        power,
        seeds,
        round((1 - confidence) / 2, 12),
        reachable_verdicts(found.claim, found.check.id or "", outcomes_of(found.spec)),
    )


def plan_checks(
    profile: Profile,
    store: Path,
    declaration: Declaration | None = None,
    plans_dir: Path | None = PLANS_DIR,
) -> tuple[list[Plan], list[tuple[OpenCheck, str]]]:
    """A plan for every open check of the profile's claims, cheapest first (by hours on a
    2-core CPU machine, then env steps), and the open checks that have none, with why."""
    declaration = declaration or load_declaration()
    plans, without = [], []
    for found in open_checks(profile, store, declaration):
        plan = plan_check(found, profile, declaration, store, plans_dir)
        if isinstance(plan, Plan):
            plans.append(plan)
        else:
            without.append((found, plan))
    plans.sort(key=lambda p: (p.n is None, p.hours("cpu") or math.inf, p.env_steps, p.check_id))
    return plans, without


def find_plan(plans: list[Plan], without: list[tuple[OpenCheck, str]], wanted: str) -> Plan:
    """The plan of check ``wanted``: its id ('3b.1'), or claim-qualified ('3:3b.1')."""
    claim, _, check_id = wanted.rpartition(":")
    for plan in plans:
        if plan.check_id == check_id and claim in ("", str(plan.open.claim["id"])):
            return plan
    for found, why in without:
        if found.check.id == check_id:
            raise HarnessError(f"check {wanted} has no plan: {why}", "choose another open check")
    open_ids = ", ".join(p.check_id for p in plans) or "none"
    raise HarnessError(
        f"check {wanted} is not an open check of this profile's claims",
        f"choose one of the open checks: {open_ids}",
    )
