"""The commands of ``python -m replicate`` that write reports from what the run store holds,
training nothing: ``report`` (every registered report, then Table 1 and the front door) and
``table1``."""

from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path
from typing import Any

from replicate.grids.options import PROFILE_NAMES, STORE_HELP, Command, HelpFormatter, profiles_help


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


def _cmd_report(args: argparse.Namespace) -> int:
    from replicate.figures.registry import figures
    from replicate.figures.table1 import write_table1_report
    from replicate.grids.profiles import report_dir
    from replicate.reports.pages import write_unless_fewer

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
    from replicate.figures.registry import describe
    from replicate.reports.frontdoor import write_front_door

    print(f"front door: {write_front_door(args.out or Path('reports'), describe)}")
    return 0


def _cmd_table1(args: argparse.Namespace) -> int:
    from replicate.figures.table1 import write_table1_report

    print(f"report: {write_table1_report(args.out)}")
    return 0


REPORT = Command("report", _declare_report, _cmd_report)
TABLE1 = Command("table1", _declare_table1, _cmd_table1)
