"""A confirmatory plan registered and trained: written as TOML under ``plans/``, allowed to
train only while committed in git and unchanged since (and none of its runs begun before
that commit), and its runs trained as the Fig. 3 grid's (or Fig. 4's) at the plan's seeds,
through the grids' usual path into the run store. ``replicate.confirm.plan`` plans;
``replicate.claims.confirm_judge`` judges.
"""

from __future__ import annotations

import json
import math
import re
import subprocess
from dataclasses import replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from replicate.claims.confirm_judge import PLANS_DIR, plan_path, read_plan
from replicate.claims.verdicts import MOST_SEEDS
from replicate.confirm.plan import SIGMA_UPPER, Plan, outcomes_of, route_words
from replicate.errors import HarnessError
from replicate.grids.profiles import Profile
from replicate.stats import DECIDING_CHANCE

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
    from replicate.claims.declaration import declaration_version
    from replicate.store.provenance import portable_path

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
            "declaration": portable_path(plan.declaration.path),
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
            "outcomes": outcomes_of(spec),
            "decides": "each outcome's one-sided test (two for an equivalence) at the level, "
            "on the plan's runs alone: equivalent first, then holds, then fails; else "
            "inconclusive",
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
        f"profile {plan.profile.name}, written by\n"
        f"  {command}\n"
        "Commit it before its runs train: with --train the same command trains them only\n"
        "while this file is committed and unchanged, and refuses once it has changed after\n"
        "any of its runs began. The runs are judged alone, by the test in [test] at its\n"
        "level (one check: no Holm adjustment)."
    )


def plan_specs(plan: dict[str, Any], profile: Profile) -> list[Any]:
    """The run specs of a plan file's runs: the grid's own specs of its cells (Fig. 3's, or
    Fig. 4's for a claim on Fig. 4's runs: same hyperparameters), at the plan's seeds."""
    from replicate.figures.fig3 import figure3_grid
    from replicate.figures.fig4 import figure4_grid

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
    from replicate.store.runner import prepare

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
    from replicate.store.run_recorder import read_segments

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
    from replicate.claims.confirm_judge import judge_plan
    from replicate.grids.experiments import GridOptions
    from replicate.grids.profiles import get_profile
    from replicate.grids.train import train_cells

    options = options or GridOptions()
    plan = read_plan(plan_file)
    ids = list(plan["runs"]["ids"])
    if not options.dry_run:
        root = root or repository_root(Path(plan_file).parent)
        if root is None:
            raise HarnessError(
                f"{plan_file} is not in a git repository",
                "keep plans in the repository (plans/) and commit them before training",
            )
        check_registered(Path(plan_file), root, Path(store), ids)
    profile = get_profile(plan["plan"]["profile"])
    specs = plan_specs(plan, profile)
    if run_ids(specs) != ids:
        raise HarnessError(
            f"{plan_file}: the grid's runs at these seeds are no longer the registered ones "
            "(the profile's budget or an algorithm's settings changed)",
            "register a new plan at the current settings, with fresh seeds",
        )
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
