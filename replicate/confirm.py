"""Confirmatory plans: for each open check of a profile's claims, the fresh seeds that would
decide it with an 80% chance in one registered test, what they cost and which claim
verdicts the outcome could reach; the plan written under ``plans/`` to be committed before
its runs train; and its runs trained through the grids' usual path, into the run store like
any other. ``replicate.confirm_judge`` judges a plan on its own runs.

A plan is sized from the exploratory runs (the reports' seeds) but tested on fresh seeds
alone: at the observed effect, with the spread at sigma's one-sided 80% upper confidence
limit (a plan sized at the point estimate of a spread from 5 seeds is underpowered about
half the time), for a single test at the declaration's one-sided level.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from replicate.checks import EQUIVALENT, FAILS, HOLDS, INCONCLUSIVE, Check
from replicate.confirm_judge import PLANS_DIR, plan_path, read_plan
from replicate.declaration import CheckSpec, Declaration, load_declaration
from replicate.errors import HarnessError
from replicate.profiles import Profile
from replicate.stats import (
    DECIDING_CHANCE,
    PAIRED_METHOD,
    MeanEstimate,
    chance_to_decide,
    seeds_to_decide,
)
from replicate.verdicts import MOST_SEEDS, claim_verdict, part_state

SIGMA_UPPER = 0.80  # the spread assumed: sigma's one-sided upper confidence limit at this level
SEED_BLOCK = 1000  # fresh seeds start at the first multiple of this that no run of the cells uses
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
            from replicate.profiles import BUDGETS

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


def _scaled(estimate: MeanEstimate, factor: float) -> MeanEstimate:
    variances = estimate.variances
    if variances is not None:
        variances = (variances[0] * factor**2, variances[1] * factor**2)
    return replace(estimate, se=estimate.se * factor, variances=variances)


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
    store: Path, cells: set[tuple[str, str]], plans_dir: Path | None = PLANS_DIR
) -> set[int]:
    """Every seed of the (env, algo) ``cells`` that the store holds, finished, unfinished or
    carried, at any budget, and that a plan in ``plans_dir`` registered."""
    from replicate import checkpoint_places

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
    from replicate.claims import build_check, judge_claims
    from replicate.fig3 import figure3_command, figure3_grid
    from replicate.fig4 import figure4_runs
    from replicate.grids import stored_outcome
    from replicate.report import claim_groups

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
    if found.check.counted or found.check.not_testable:
        return "decided by counting seeds, not by a test"
    if not est.defined or not np.isfinite(est.se):
        return "its estimate has no interval (fewer than 2 runs)"
    routes = {o: d for o, d in found.check.routes() if min(d) > 0}
    if not routes:
        return "its estimate sits exactly at what decides it: no number of seeds can"
    factor = sigma_upper_factor(est.df)
    if not np.isfinite(factor):
        return "its spread has no degrees of freedom"
    assumed = _scaled(est, factor)
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
    seeds = fresh_seeds(used_seeds(store, cells, plans_dir), n or MOST_SEEDS)
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
        (1 - confidence) / 2,
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


# Writing a plan: TOML by hand, the few value types a plan holds.


def _toml_value(value: Any) -> str:
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        return repr(value) if math.isfinite(value) else ("inf" if value > 0 else "-inf")
    if isinstance(value, str):
        return json.dumps(value)  # a JSON string is a TOML basic string
    if isinstance(value, (list, tuple)):
        items = [_toml_value(v) for v in value]
        flat = "[" + ", ".join(items) + "]"
        return flat if len(flat) <= 80 else "[\n" + "".join(f"  {i},\n" for i in items) + "]"
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{_key(k)} = {_toml_value(v)}" for k, v in value.items()) + " }"
    raise TypeError(f"no TOML form for {value!r}")


def _key(key: str) -> str:
    return key if re.fullmatch(r"[A-Za-z0-9_-]+", key) else json.dumps(key)


def toml_text(tables: dict[str, dict[str, Any]], comment: str = "") -> str:
    """``tables`` as TOML: one [table] each, None values left out."""
    lines = [f"# {line}".rstrip() for line in comment.splitlines()]
    for name, table in tables.items():
        lines += ["", f"[{name}]"]
        lines += [f"{_key(k)} = {_toml_value(v)}" for k, v in table.items() if v is not None]
    return "\n".join(lines).lstrip("\n") + "\n"


def plan_tables(plan: Plan, run_ids: list[str], written: str) -> dict[str, dict[str, Any]]:
    """A plan as the tables of its file."""
    from replicate.declaration import declaration_version

    spec, est, found = plan.spec, plan.estimate, plan.open
    steps, interval = plan.profile_budget
    try:
        version = declaration_version(plan.declaration.path).short
    except (OSError, ValueError):
        version = "uncommitted"
    return {
        "plan": {
            "profile": plan.profile.name,
            "paper": plan.declaration.key,
            "declaration": str(plan.declaration.path),
            "declaration_version": version,
            "claim": found.claim["id"],
            "part": found.part,
            "check": plan.check_id,
            "written": written,
        },
        "check": {
            "what": found.check.what,
            "kind": spec.kind,
            "env": spec.env,
            "algo": spec.algo,
            "other": spec.other,
            "measure": spec.measure,
            "above": spec.above,
            "within": list(spec.within) if spec.within else None,
            "smallest_effect": spec.smallest_effect,
        },
        "test": {
            "test": plan.test_name,
            "level": plan.level,
            "outcomes": [HOLDS, FAILS] + ([EQUIVALENT] if spec.smallest_effect else []),
            "powered_for": plan.outcome,
            "route": route_words(spec, plan.outcome),
            "assumed_effect": est.value,
            "assumed_sd": list(plan.sd_assumed),
            "sd_upper_limit": SIGMA_UPPER,
            "power": plan.power,
            "n": plan.n,
            "unit": plan.unit,
            "claim_verdict_now": plan.verdict_now,
            "claim_verdict_if": plan.reachable,
        },
        "exploratory": {
            "estimate": est.value,
            "low": est.low,
            "high": est.high,
            "method": est.label,
            "sd": list(plan.sd_observed),
            "df": est.df,
            "n": est.n,
            "n_other": est.n_other,
            "runs": list(found.runs),
        },
        "runs": {
            "grid": found.grid,
            "env": spec.env,
            "algos": list(plan.algos),
            "seeds": list(plan.seeds),
            "steps": steps,
            "eval_interval": interval,
            "eval_episodes": plan.profile.eval_episodes,
            "env_steps": plan.env_steps,
            "cpu_hours_2_cores": plan.hours("cpu"),
            "gpu_hours": plan.hours("gpu"),
            "ids": run_ids,
        },
    }


def plan_comment(plan: Plan) -> str:
    command = f"python -m replicate confirm --profile {plan.profile.name} --check {plan.check_id}"
    return (
        f"A confirmatory plan for check {plan.check_id} of claim {plan.open.claim['id']}, "
        f"profile {plan.profile.name}.\n"
        f"Written by `{command}`; commit it before its runs train:\n"
        f"`{command} --train` trains them only while this file is committed and unchanged,\n"
        "and refuses once it has changed after any of its runs began. Its runs are judged\n"
        "alone, by the test in [test] at its level (one check, no Holm adjustment)."
    )


def plan_specs(plan: dict[str, Any], profile: Profile) -> list[Any]:
    """The run specs of a plan file's runs: the grid's own specs of its cells (Fig. 3's, or
    Fig. 4's for a claim on Fig. 4's runs: same hyperparameters), at the plan's seeds."""
    from replicate.fig3 import figure3_grid
    from replicate.fig4 import figure4_grid

    runs = plan["runs"]
    if runs["grid"] == "fig4":
        templates = figure4_grid(profile, runs["env"], 1)
    else:
        templates = figure3_grid(profile, 1)[0]
    by_cell = {(s.env_id, s.algo): s for s in templates}
    missing = [a for a in runs["algos"] if (runs["env"], a) not in by_cell]
    if missing:
        raise HarnessError(
            f"{plan['path']}: the {runs['grid']} grid of profile {profile.name} has no "
            f"{missing[0]} on {runs['env']}",
            "register the plan at the profile whose grid has it",
        )
    return [
        replace(by_cell[(runs["env"], algo)], seed=seed)
        for algo in runs["algos"]
        for seed in runs["seeds"]
    ]


def run_ids(specs: list[Any]) -> list[str]:
    from replicate.runner import prepare

    return [prepare(spec).run_id for spec in specs]


def register_plan(plan: Plan, plans_dir: Path = PLANS_DIR, hours: float | None = None) -> Path:
    """Write ``plan`` as ``plans_dir/<profile>-<check>.toml``; refused where it needs more
    than ``MOST_SEEDS`` seeds, does not fit in ``hours`` on a 2-core CPU machine, or a plan
    for the check is already committed."""
    if plan.n is None:
        raise HarnessError(
            f"check {plan.check_id} would need more than {MOST_SEEDS} {plan.unit} for an "
            f"{DECIDING_CHANCE:.0%} chance",
            "choose a cheaper check (`python -m replicate confirm` lists them by cost)",
        )
    cpu = plan.hours("cpu")
    if hours is not None and (cpu is None or cpu > hours):
        cost = f"about {cpu:.1f} h" if cpu is not None else "an unknown time (no CPU rate)"
        raise HarnessError(
            f"the plan for {plan.check_id} does not fit in {hours:g} h: {plan.runs} runs, "
            f"{plan.env_steps:,} env steps, {cost} on a 2-core CPU machine",
            "give --hours more, or choose a cheaper check (`python -m replicate confirm` "
            "lists them by cost)",
        )
    path = plan_path(plan.profile.name, plan.check_id, plans_dir)
    if path.is_file():
        root = repository_root(path.parent)
        if root is not None and _last_commit(path, root) is not None:
            raise HarnessError(
                f"{path} is already registered (committed)",
                "train it with --train, or see it with --status; a registered plan is "
                "never rewritten",
            )
    ids = run_ids(
        plan_specs(
            {
                "path": str(path),
                "runs": {
                    "grid": plan.open.grid,
                    "env": plan.spec.env,
                    "algos": plan.algos,
                    "seeds": plan.seeds,
                },
            },
            plan.profile,
        )
    )
    written = datetime.now(timezone.utc).isoformat(timespec="seconds")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(toml_text(plan_tables(plan, ids, written), plan_comment(plan)))
    return path


# Whether a plan may train: committed, unchanged since, and none of its runs begun before.


def _git(root: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True)


def repository_root(directory: Path) -> Path | None:
    """The git work tree holding ``directory``; None outside one (or without git)."""
    try:
        found = _git(Path(directory), "rev-parse", "--show-toplevel")
    except OSError:
        return None
    return Path(found.stdout.strip()) if found.returncode == 0 else None


def _last_commit(path: Path, root: Path) -> tuple[str, datetime] | None:
    logged = _git(root, "log", "-1", "--format=%H %aI", "--", _relative(path, root)).stdout
    parts = logged.split()
    return (parts[0], datetime.fromisoformat(parts[1])) if len(parts) == 2 else None


def _relative(path: Path, root: Path) -> str:
    return Path(path).resolve().relative_to(Path(root).resolve()).as_posix()


def run_starts(store: Path, ids: list[str]) -> dict[str, datetime]:
    """When each of ``ids`` that the store holds (finished or not) began training."""
    from replicate.run_recorder import read_segments

    starts = {}
    for run_id in ids:
        finished, partial = Path(store) / run_id, Path(store) / f".partial-{run_id}"
        started = None
        if (finished / "provenance.json").is_file():
            started = json.loads((finished / "provenance.json").read_text()).get("started_utc")
        elif partial.is_dir():
            segments = read_segments(partial)
            started = segments[0].get("started_utc") if segments else None
        if started:
            starts[run_id] = datetime.fromisoformat(started)
    return starts


def check_registered(plan_file: Path, root: Path, store: Path, ids: list[str]) -> str:
    """Raise, in one line, unless ``plan_file`` is committed in the repository at ``root``,
    unchanged since, and every run of ``ids`` in the store began after that commit; returns
    the commit."""
    rel = _relative(plan_file, root)
    status = _git(root, "status", "--porcelain", "--", rel)
    if status.returncode != 0:
        raise HarnessError(f"{root} is not a git repository", "keep plans in the repository")
    last = _last_commit(plan_file, root)
    if last is None:
        raise HarnessError(
            f"{rel} is not committed",
            f"commit it before its runs train: git add {rel} && git commit",
        )
    commit, date = last
    starts = run_starts(store, ids)
    early = sorted((s, r) for r, s in starts.items() if s < date)
    if early:
        started, run_id = early[0]
        raise HarnessError(
            f"{rel} changed (commit {commit[:10]} of {date.isoformat()}) after its run "
            f"{run_id} began ({started.isoformat()}): the plan is not the one its runs "
            f"were registered under",
            f"restore it as it was when its runs began (git log -- {rel}) and commit that, "
            "or register a new plan with fresh seeds",
        )
    if status.stdout.strip():
        raise HarnessError(
            f"{rel} has changes that are not committed",
            f"commit them before any run trains (git commit {rel}), or restore it "
            f"(git checkout -- {rel})"
            if not starts
            else f"restore it as committed (git checkout -- {rel}): its runs have begun",
        )
    return commit


def train_plan(
    plan_file: Path, store: Path, options: Any = None, root: Path | None = None
) -> dict[str, Any] | None:
    """Train a registered plan's runs (what the store lacks), through the grids' usual path,
    only while its file is committed, unchanged, and none of its runs began before that
    commit (``check_registered``); then judge it (``confirm_judge.judge_plan``). A dry run
    prints what would train, without the git check, and returns None."""
    from replicate.confirm_judge import judge_plan
    from replicate.experiments import GridOptions
    from replicate.grids import train_cells
    from replicate.profiles import get_profile

    options = options or GridOptions()
    plan = read_plan(plan_file)
    profile = get_profile(plan["plan"]["profile"])
    specs = plan_specs(plan, profile)
    ids = run_ids(specs)
    if ids != list(plan["runs"]["ids"]):
        raise HarnessError(
            f"{plan_file}: the grid's runs at these seeds are no longer the registered ones "
            "(the profile's budget or an algorithm's settings changed)",
            "register a new plan at the current settings, with fresh seeds",
        )
    if not options.dry_run:
        root = root or repository_root(Path(plan_file).parent)
        if root is None:
            raise HarnessError(
                f"{plan_file} is not in a git repository",
                "keep plans in the repository (plans/) and commit them before training",
            )
        check_registered(Path(plan_file), root, Path(store), ids)
    command = (
        f"python -m replicate confirm --profile {profile.name} "
        f"--check {plan['plan']['check']} --train"
    )
    outcome = train_cells(specs, specs, Path(store), command, options)
    if options.dry_run:
        return None
    if outcome.failed:
        run_id, reason = outcome.failed[0]
        raise HarnessError(
            f"{len(outcome.failed)} run(s) of the plan failed, e.g. {run_id}: {reason}",
            "read the reason, fix, and run the same command",
        )
    return judge_plan(plan, Path(store))
