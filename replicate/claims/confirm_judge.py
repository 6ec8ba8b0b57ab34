"""A registered confirmatory plan judged on its own runs: the check it names, on the runs
its seeds trained and no others, with the test and level it registered (one check per
plan, so no Holm adjustment). ``replicate.confirm.plan`` writes and trains the plans.

Imports no torch and runs no git: the reports read it.
"""

from __future__ import annotations

import tomllib
from pathlib import Path
from typing import Any

import numpy as np

from replicate.claims.checks import EQUIVALENT, FAILS, HOLDS, INCONCLUSIVE
from replicate.claims.declaration import CheckSpec
from replicate.claims.groups import claim_groups
from replicate.claims.judge import build_check
from replicate.errors import HarnessError
from replicate.store.runs import is_complete, load_run

PLANS_DIR = Path("plans")  # relative to the repository root, committed with the plans
# Plans' fresh seeds start at a multiple of this: the figures' grids number their seeds from
# 0, and a report that reads every run of a cell leaves these out
SEED_BLOCK = 1000
OUTCOMES = (EQUIVALENT, HOLDS, FAILS)  # the ledger's order: a negligible difference first


def plan_path(profile: str, check_id: str, plans_dir: Path = PLANS_DIR) -> Path:
    return Path(plans_dir) / f"{profile}-{check_id}.toml"


def read_plan(path: Path) -> dict[str, Any]:
    """A plan file as written by ``replicate.confirm.plan.write_plan``, with ``path`` added."""
    path = Path(path)
    try:
        with open(path, "rb") as handle:
            plan = tomllib.load(handle)
    except FileNotFoundError:
        raise HarnessError(
            f"no plan at {path}",
            "register it first: python -m replicate confirm --profile P --check ID",
        ) from None
    except tomllib.TOMLDecodeError as exc:
        raise HarnessError(f"{path}: {exc}", "restore the plan as committed (git)") from None
    missing = [t for t in ("plan", "check", "test", "runs") if t not in plan]
    if missing:
        raise HarnessError(f"{path}: no [{missing[0]}] table", "restore the plan as committed")
    plan["path"] = str(path)
    return plan


def registered_plans(profile: str, plans_dir: Path = PLANS_DIR) -> list[dict[str, Any]]:
    """The plans of ``profile`` in ``plans_dir``, by check id."""
    plans = [read_plan(p) for p in sorted(Path(plans_dir).glob(f"{profile}-*.toml"))]
    return [p for p in plans if p["plan"]["profile"] == profile]


def check_spec(plan: dict[str, Any]) -> Any:
    """The plan's check as a declaration's ``CheckSpec``."""
    c = plan["check"]
    return CheckSpec(
        c["kind"],
        c["algo"],
        c["env"],
        c["measure"],
        c.get("other"),
        c.get("above"),
        tuple(c["within"]) if "within" in c else None,
        c.get("smallest_effect"),
    )


def judge_plan(plan: dict[str, Any] | Path, store: Path) -> dict[str, Any]:
    """The plan's check judged on the plan's runs alone (found by their run ids), each of its
    one-sided tests at the registered level: ``state`` holds, fails, equivalent or
    inconclusive, None while runs are missing (then only ``progress`` is filled).
    ``p``: the p-value of the state reached, or for an inconclusive check of the outcome the
    plan was powered for (the larger of two for an equivalence test); ``p_values``: every
    outcome's."""

    plan = read_plan(plan) if isinstance(plan, Path) else plan
    ids = list(plan["runs"]["ids"])
    done = [Path(store) / run_id for run_id in ids if is_complete(Path(store) / run_id)]
    result: dict[str, Any] = {
        "plan": plan["path"],
        "check": plan["plan"]["check"],
        "claim": plan["plan"]["claim"],
        "what": plan["check"]["what"],
        "state": None,
        "progress": {"done": len(done), "planned": len(ids)},
        "estimate": None,
        "low": None,
        "high": None,
        "method": None,
        "p": None,
        "p_values": {},
        "level": plan["test"]["level"],
        "powered_for": plan["test"]["powered_for"],
    }
    if len(done) < len(ids):
        return result
    level = float(plan["test"]["level"])
    groups = claim_groups([load_run(d) for d in done])
    check = build_check(check_spec(plan), plan["plan"]["part"], groups, 1 - 2 * level)
    p_values = {o: float(v) for o, v in check.p_values().items()}
    state = next(
        (o for o in OUTCOMES if np.isfinite(p_values.get(o, np.nan)) and p_values[o] < level),
        INCONCLUSIVE,
    )
    est = check.estimate
    result.update(
        state=state,
        estimate=est.value,
        low=est.low,
        high=est.high,
        method=est.label,
        p=p_values.get(state if state != INCONCLUSIVE else plan["test"]["powered_for"]),
        p_values=p_values,
    )
    return result


def confirmatory_results(
    profile: str, store: Path, plans_dir: Path = PLANS_DIR
) -> dict[str, dict[str, Any]]:
    """Every registered plan of ``profile`` judged (``judge_plan``), by check id."""
    return {p["plan"]["check"]: judge_plan(p, store) for p in registered_plans(profile, plans_dir)}


def result_line(result: dict[str, Any]) -> str:
    """A judged plan in one line: its verdict, or how far its runs are."""
    progress = result["progress"]
    head = f"{result['check']:<7} {result['what']}: "
    if result["state"] is None:
        return head + f"{progress['done']} of {progress['planned']} runs done ({result['plan']})"
    p = result["p"]
    p_words = f"p = {p:.2g}" if p is not None and np.isfinite(p) else "no p-value"
    return head + (
        f"{result['state']}: {result['estimate']:.4g} [{result['low']:.4g}, "
        f"{result['high']:.4g}], {result['method']}, {p_words} at {result['level']:.3g} "
        f"one-sided ({result['plan']})"
    )


__all__ = [
    "HOLDS",
    "FAILS",
    "PLANS_DIR",
    "SEED_BLOCK",
    "confirmatory_results",
    "judge_plan",
    "read_plan",
    "registered_plans",
]
