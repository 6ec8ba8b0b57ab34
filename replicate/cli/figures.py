"""The figure commands of ``python -m replicate``: each trains what its grid lacks and writes
its report (``report`` and ``table1`` write reports from what is there); their options and
handlers."""

from __future__ import annotations

import argparse
import dataclasses
import inspect
from collections.abc import Callable
from pathlib import Path
from typing import Any

from replicate.grids.options import (
    PROFILE_NAMES,
    STORE_HELP,
    Command,
    HelpFormatter,
    add_grid_arguments,
    profiles_help,
)


def _declare_fig3(sub: Any) -> None:
    fig3 = sub.add_parser(
        "fig3",
        help="train what Fig. 3 needs and write its HTML report",
        description="Run the Fig. 3 grid for a profile (only runs missing from the store are "
        "trained), then write the self-contained HTML report.",
        formatter_class=HelpFormatter,
    )
    add_grid_arguments(
        fig3,
        "report directory (default: reports/fig3 for quick, reports/<profile>/fig3 otherwise)",
        ray=True,
        cells=True,
    )


def _declare_fig4(sub: Any) -> None:
    fig4 = sub.add_parser(
        "fig4",
        help="train what Fig. 4 needs (paired SAC and DRL-EG) and write its report",
        description="Train SAC and DRL-EG on the same seeds (identical initial weights) on "
        "Ant-v5, or --env, and write reports/fig4/index.html: one panel per "
        "seed, paired differences, claim 5.",
        formatter_class=HelpFormatter,
    )
    add_grid_arguments(
        fig4,
        "report directory (default: reports/fig4 for quick, reports/<profile>/fig4 otherwise)",
        seeds_help="number of seeds (default 4)",
        ray=True,
    )
    fig4.add_argument("--env", default="Ant-v5", help="environment (the paper's is Ant-v5)")


def _declare_ablate(sub: Any) -> None:
    ablate = sub.add_parser(
        "ablate-threshold",
        help="sweep DRL-EG's threshold T2 (and sigma) with optuna",
        description="Train DRL-EG over a grid of T2 (and sigma) values, one optuna trial "
        "per point, at the Fig. 3 profile's budget and seeds, and write "
        "reports/ablate-threshold/index.html. Stopped sweeps resume; several "
        "workers can share one --storage.",
        formatter_class=HelpFormatter,
    )
    add_grid_arguments(
        ablate,
        "report directory (default: reports/ablate-threshold[-<env>] for quick, under "
        "reports/<profile>/ otherwise)",
        ray=True,
    )
    ablate.add_argument(
        "--thresholds",
        type=float,
        nargs="+",
        default=None,
        help="T2 values (default: the profile's grid, 0 and 'always' included)",
    )
    ablate.add_argument(
        "--sigmas",
        type=float,
        nargs="+",
        default=None,
        help="guider noise values (default: the profile's grid)",
    )
    ablate.add_argument(
        "--storage", default=None, help="optuna storage URL (default: SQLite in the run store)"
    )
    ablate.add_argument(
        "--env",
        default="MountainCarContinuous-v0",
        help="the env to sweep: MountainCar (absolute T2 grid), or Ant-v5 or "
        "Walker2d-v5 (T2 at 1, 4, 16, 64 times the median demonstration-"
        "state spacing, and always; 3 seeds)",
    )


def _declare_rlfd(sub: Any) -> None:
    rlfd = sub.add_parser(
        "compare-rlfd",
        help="DRL-EG against IBRL, RLPD, JSRL, SAC and DDPGfD: reports/rlfd",
        description="Train the comparison grid (only runs missing from the store) on the "
        "profile's tasks and write reports/rlfd/index.html: normalised scores, IQM, "
        "probability of improvement, performance profiles, sample-efficiency "
        "curves and a verdict per method and task.",
        formatter_class=HelpFormatter,
    )
    add_grid_arguments(
        rlfd,
        "report directory (default: reports/rlfd for quick, reports/<profile>/rlfd otherwise)",
        profile_help=profiles_help(
            "budget profile (here quick is MountainCar; reduced "
            "adds the sparse dm-control tasks, Hopper and Ant)"
        ),
        seeds_help="number of seeds (default 5)",
        cells=True,
    )


def _declare_report(sub: Any) -> None:
    from replicate.figures.registry import figures

    report = sub.add_parser(
        "report",
        help="rebuild reports from the run store without training",
        description="Rebuild the reports of a profile (every registered one: "
        f"{', '.join(figures())}; then table1 and the front door, reports/index.html) "
        "from the runs already in the store; nothing is trained. Without --profile: the "
        "quick profile's reports and the other profiles' reports already written. Fig. 3 "
        "lists its missing runs; a report whose runs the store lacks is left as it is.",
        formatter_class=HelpFormatter,
    )
    report.add_argument(
        "--profile",
        default=None,
        choices=PROFILE_NAMES,
        help=profiles_help(
            "which profile's reports to rebuild (default: the quick profile's, and "
            "the reports of other profiles but smoke that were already written)"
        ),
    )
    report.add_argument(
        "--seeds", type=int, default=None, help="number of seeds (default: the profile's)"
    )
    report.add_argument("--store", type=Path, default=None, help=STORE_HELP)
    report.add_argument(
        "--out",
        type=Path,
        default=None,
        help="parent directory of the reports (default: reports/ for quick, "
        "reports/<profile>/ otherwise; with several profiles, "
        "<out>/<profile>/<name>)",
    )


def _declare_table1(sub: Any) -> None:
    table1 = sub.add_parser(
        "table1",
        help="write Table 1 (env dims, paper beside harness, demonstrations)",
        description="Write reports/table1/index.html from the environment table, checked "
        "against the live envs, and the committed demonstration files.",
        formatter_class=HelpFormatter,
    )
    table1.add_argument("--out", type=Path, default=Path("reports/table1"), help="report directory")


def _reported(report: Path | None) -> int:
    """A figure command's end: the report it wrote, if it wrote one (a dry run writes none)."""
    if report is not None:
        print(f"report: {report}")
    return 0


def run_figure(run: Callable[..., Path | None], args: argparse.Namespace, **given: Any) -> int:
    """Call a figure's run function with the command's options: the grid options as one
    ``GridOptions``, every other option to the parameter of its name (``--out`` reaches
    ``out_dir``, ``--env`` ``env_id``); ``given`` adds or overrides."""
    from replicate.grids.experiments import GridOptions

    grid = {f.name for f in dataclasses.fields(GridOptions)}
    options = GridOptions(**{name: value for name, value in vars(args).items() if name in grid})
    named = {**vars(args), "out_dir": args.out, "env_id": getattr(args, "env", None)}
    kwargs = {p: named[p] for p in inspect.signature(run).parameters if p in named}
    return _reported(run(**{**kwargs, "options": options, **given}))


def _cmd_fig3(args: argparse.Namespace) -> int:
    from replicate.figures.fig3 import run_figure3
    from replicate.grids.profiles import report_dir

    return run_figure(run_figure3, args, out_dir=args.out or report_dir(args.profile, "fig3"))


def _cmd_fig4(args: argparse.Namespace) -> int:
    from replicate.figures.fig4 import run_figure4

    return run_figure(run_figure4, args)


def _cmd_ablate(args: argparse.Namespace) -> int:
    from replicate.figures.ablation import run_threshold_ablation

    return run_figure(run_threshold_ablation, args)


def _cmd_rlfd(args: argparse.Namespace) -> int:
    from replicate.figures.rlfd import run_rlfd

    return run_figure(run_rlfd, args)


def _cmd_report(args: argparse.Namespace) -> int:
    from replicate.figures.registry import figures
    from replicate.grids.profiles import report_dir
    from replicate.reports.pages import write_unless_fewer
    from replicate.figures.table1 import write_table1_report

    profiles = [args.profile] if args.profile else [p for p in PROFILE_NAMES if p != "smoke"]

    def target(profile: str, name: str) -> Path | None:
        """Where to write; None to leave out: without --profile, only the default profile's
        reports and those already written (committed) are rebuilt, since profiles share runs
        (reduced's MountainCar runs are quick's) and would otherwise each get a report."""
        if args.out is not None:
            return args.out / profile / name if len(profiles) > 1 else args.out / name
        path = report_dir(profile, name)
        keep = args.profile or profile == "quick" or (path / "summary.json").is_file()
        return path if keep else None

    def rebuild(profile: str, name: str, build: Callable[[Path], Path | None]) -> str:
        path = target(profile, name)
        if path is None:
            not_written.add(profile)
            return ""
        written, note = write_unless_fewer(path, args.store, build)
        if written is None:
            return note or (
                f"{path}: no runs of the {profile} profile in {args.store}; left as it is"
            )
        return f"report: {written}" + (f" ({note})" if note else "")

    not_written: set[str] = set()

    def report_line(line: str) -> None:
        if line:
            print(line)

    for profile in profiles:
        for name, figure in figures().items():
            report_line(
                rebuild(
                    profile, name, lambda out: figure.rebuild(profile, args.store, out, args.seeds)
                )
            )
    if not_written:
        names = " or ".join(sorted(not_written))
        print(
            f"reports of the {names} profile that were never written are left out "
            f"(they would share the quick profile's runs); pass --profile to write them"
        )
    table1 = write_table1_report(args.out / "table1" if args.out else Path("reports/table1"))
    print(f"report: {table1}")
    from replicate.reports.frontdoor import write_front_door

    print(f"front door: {write_front_door(args.out or Path('reports'))}")
    return 0


def _cmd_table1(args: argparse.Namespace) -> int:
    from replicate.figures.table1 import write_table1_report

    print(f"report: {write_table1_report(args.out)}")
    return 0


FIG3 = Command("fig3", _declare_fig3, _cmd_fig3)
FIG4 = Command("fig4", _declare_fig4, _cmd_fig4)
ABLATE_THRESHOLD = Command("ablate-threshold", _declare_ablate, _cmd_ablate)
COMPARE_RLFD = Command("compare-rlfd", _declare_rlfd, _cmd_rlfd)
REPORT = Command("report", _declare_report, _cmd_report)
TABLE1 = Command("table1", _declare_table1, _cmd_table1)
