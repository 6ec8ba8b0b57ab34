"""``python -m replicate confirm``: confirmatory plans for the open checks of a profile's
claims (``replicate.confirm.plan``): list them by cost, register one, train a registered one,
and list the registered plans with their progress or verdict."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from replicate.grids.options import (
    CHECKPOINT_HELP,
    DRY_RUN_HELP,
    PROFILE_NAMES,
    STORE_HELP,
    Command,
    HelpFormatter,
    add_device_argument,
    add_time_limit_argument,
    positive_int,
    profiles_help,
)


def _declare(sub: Any) -> None:
    parser = sub.add_parser(
        "confirm",
        help="confirmatory plans for the open checks of the claims: list, register, train",
        description="Without --check: list every open (inconclusive) check of the profile's "
        "claims with a plan that would decide it with an 80% chance in one registered test "
        "on fresh seeds, cheapest first; nothing is written. With --check ID: write its plan "
        "to plans/<profile>-<ID>.toml, to be committed. With --check ID --train: train the "
        "committed plan's runs and judge it on them alone. --status: the registered plans, "
        "with their progress or verdict.",
        formatter_class=HelpFormatter,
    )
    parser.add_argument("--profile", default="reduced", choices=PROFILE_NAMES, help=profiles_help())
    parser.add_argument(
        "--check",
        default=None,
        metavar="ID",
        help="the check to register or train: its id (3b.1) or claim-qualified (3:3b.1)",
    )
    parser.add_argument(
        "--hours",
        type=float,
        default=None,
        help="the most wall-clock hours a plan may take on a 2-core CPU machine (2 "
        "processes): registering refuses a plan that needs more; the list shows only those "
        "that fit",
    )
    parser.add_argument("--train", action="store_true", help="train the registered plan's runs")
    parser.add_argument(
        "--status", action="store_true", help="list the registered plans and their state"
    )
    parser.add_argument("--plans", type=Path, default=Path("plans"), help="the plans' directory")
    parser.add_argument(
        "--declaration",
        type=Path,
        default=None,
        help="the claims' declaration (default: replicate/declarations/drl-eg.toml)",
    )
    parser.add_argument("--store", type=Path, default=None, help=STORE_HELP)
    parser.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="parallel training processes (default: one per core)",
    )
    add_device_argument(parser, grid=True)
    parser.add_argument(
        "--executor",
        default="local",
        choices=["local", "ray"],
        help="local processes, or tasks on a running Ray cluster (--address)",
    )
    parser.add_argument("--address", default=None, help="HOST:PORT of the Ray head")
    parser.add_argument("--checkpoint-interval", type=int, default=10_000, help=CHECKPOINT_HELP)
    add_time_limit_argument(parser)
    parser.add_argument("--dry-run", action="store_true", help=DRY_RUN_HELP)


def _hours(hours: float | None, more: bool = False) -> str:
    if hours is None:
        return "-"
    words = f"{hours:.1f} h" if hours >= 0.1 else f"{max(hours * 60, 1):.0f} min"
    return (">" if more else "") + words


def _steps(n: int) -> str:
    return f"{n / 1e6:.3g}M" if n >= 1e6 else f"{n / 1e3:.3g}k"


def _number(x: float) -> str:
    return f"{x:,.0f}" if abs(x) >= 100 else f"{x:.3g}"


def plan_row(plan: Any) -> list[str]:
    """One plan as the table's cells."""
    from replicate.claims.verdicts import MOST_SEEDS
    from replicate.confirm.plan import route_words

    more = plan.n is None
    n = f"more than {MOST_SEEDS}" if more else str(plan.n)
    seeds = "-" if more else f"{plan.seeds[0]}-{plan.seeds[-1]}"
    sd = "/".join(_number(s) for s in plan.sd_assumed)
    observed = "/".join(_number(s) for s in plan.sd_observed)
    changes = {o: v for o, v in plan.reachable.items() if v != plan.verdict_now}
    claim = f"{plan.open.claim['id']}: {plan.verdict_now}"
    claim += (
        " -> " + "; ".join(f"{v} if {o}" for o, v in changes.items())
        if changes
        else " (no outcome changes it)"
    )
    return [
        plan.check_id,
        f"{n} {plan.unit}",
        seeds,
        f"{'>' if more else ''}{plan.runs}",
        f"{'>' if more else ''}{_steps(plan.env_steps)}",
        _hours(plan.hours("cpu"), more),
        _hours(plan.hours("gpu"), more),
        f"{plan.outcome}: {route_words(plan.spec, plan.outcome)} at {_number(plan.estimate.value)}",
        f"{sd} ({observed}, df {plan.estimate.df:.3g})",
        claim,
        plan.open.check.what,
    ]


HEADER = [
    "check",
    "n",
    "seeds",
    "runs",
    "env steps",
    "2-core CPU",
    "GPU",
    "powered for (at the observed estimate)",
    "sd assumed (observed)",
    "claim verdict: now -> reachable",
    "check",
]


def table(rows: list[list[str]]) -> str:
    widths = [max(len(r[k]) for r in [HEADER, *rows]) for k in range(len(HEADER) - 1)]
    lines = []
    for row in [HEADER, *rows]:
        cells = [c.ljust(w) for c, w in zip(row, widths)] + [row[-1]]
        lines.append("  ".join(cells).rstrip())
    return "\n".join(lines)


def _list(args: argparse.Namespace, plans: list[Any], without: list[Any]) -> int:
    from replicate.confirm.plan import CPU_PROCESSES, SIGMA_UPPER

    fits = [
        p
        for p in plans
        if args.hours is None or (p.hours("cpu") is not None and p.hours("cpu") <= args.hours)
    ]
    if not plans and not without:
        print(f"no open check in the {args.profile} profile's claims ({args.store})")
        return 0
    level = plans[0].level if plans else None
    print(
        f"Open checks of the {args.profile} profile's claims ({args.store}), each with a plan "
        "on fresh seeds: n seeds per algorithm (pairs for a paired difference) for an 80% "
        f"chance that one registered test at {level or 0:.3g} one-sided decides it, powered "
        f"at the observed estimate with sigma at its one-sided {SIGMA_UPPER:.0%} upper "
        f"confidence limit; hours on a 2-core CPU machine ({CPU_PROCESSES} processes) and a "
        "GPU machine at the rates the store's runs recorded; cheapest first."
        if plans
        else f"Open checks of the {args.profile} profile's claims ({args.store}):"
    )
    from replicate.grids.profiles import get_profile

    if not get_profile(args.profile).meaningful:
        print(f"(the {args.profile} profile's numbers mean nothing: plans to try the pipeline)")
    if fits:
        print(table([plan_row(p) for p in fits]))
    if args.hours is not None and len(fits) < len(plans):
        print(f"({len(plans) - len(fits)} plan(s) need more than {args.hours:g} h: left out)")
    for found, why in without:
        print(f"{found.check.id}: no plan: {why} ({found.check.what})")
    registered = [p.check_id for p in fits if _plan_file(args, p.check_id).is_file()]
    if registered:
        print(f"already registered (see --status): {', '.join(registered)}")
    print(
        f"register one: python -m replicate confirm --profile {args.profile} --check ID; "
        "commit plans/, then add --train"
    )
    return 0


def _plan_file(args: argparse.Namespace, check_id: str) -> Path:
    from replicate.claims.confirm_judge import plan_path

    return plan_path(args.profile, check_id.rpartition(":")[2], args.plans)


def _status(args: argparse.Namespace) -> int:
    from replicate.claims.confirm_judge import judge_plan, registered_plans, result_line

    plans = registered_plans(args.profile, args.plans)
    if not plans:
        print(f"no plans of the {args.profile} profile in {args.plans}")
    for plan in plans:
        print(result_line(judge_plan(plan, args.store)))
    return 0


def _cmd_confirm(args: argparse.Namespace) -> int:
    from replicate.errors import HarnessError

    if args.status:
        return _status(args)
    if args.train:
        if args.check is None:
            raise HarnessError("--train needs --check ID", "name the registered plan's check")
        return _train(args)
    from replicate.claims.declaration import load_declaration
    from replicate.confirm.plan import find_plan, plan_checks
    from replicate.confirm.register import register_plan
    from replicate.grids.profiles import get_profile

    declaration = load_declaration(args.declaration) if args.declaration else None
    plans, without = plan_checks(get_profile(args.profile), args.store, declaration, args.plans)
    if args.check is None:
        return _list(args, plans, without)
    plan = find_plan(plans, without, args.check)
    path = register_plan(plan, args.plans, args.hours)
    print(table([plan_row(plan)]))
    print(
        f"plan: {path} (seeds {plan.seeds[0]}-{plan.seeds[-1]}); commit it, then: "
        f"python -m replicate confirm --profile {args.profile} --check {plan.check_id} --train"
    )
    return 0


def _train(args: argparse.Namespace) -> int:
    import dataclasses

    from replicate.claims.confirm_judge import result_line
    from replicate.confirm.register import train_plan
    from replicate.grids.experiments import GridOptions

    grid = {f.name for f in dataclasses.fields(GridOptions)}
    options = GridOptions(**{k: v for k, v in vars(args).items() if k in grid})
    result = train_plan(_plan_file(args, args.check), args.store, options)
    if result is not None:
        print(result_line(result))
    return 0


CONFIRM = Command("confirm", _declare, _cmd_confirm)

__all__ = ["CONFIRM"]
