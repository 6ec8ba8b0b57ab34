"""Command line: ``python -m replicate COMMAND ...`` (``--help`` lists the commands)."""

from __future__ import annotations

import argparse
import os
import re
import shlex
import sys
import time
from pathlib import Path

from replicate.cli import confirm as cli_confirm
from replicate.cli import report as cli_report
from replicate.cli import runs as cli_runs
from replicate.grids.options import TIME_LIMIT_EXIT, Command

# The committed run store; smoke-profile runs (numbers that mean nothing) go to their own.
DEFAULT_STORE = Path("runs")
SMOKE_STORE = Path("runs-smoke")

_DURATION = re.compile(r"(\d+(?:\.\d*)?|\.\d+)\s*([hms]?)")
_UNIT_SECONDS = {"h": 3600.0, "m": 60.0, "s": 1.0, "": 1.0}


def parse_time_limit(text: str) -> float:
    """``90m``, ``2h``, ``1h30m``, ``45s`` or plain seconds (``5400``) as seconds; anything
    else, zero or negative is refused with the fix."""
    from replicate.errors import HarnessError

    cleaned = text.strip().lower()
    negative = cleaned.startswith("-")
    cleaned = cleaned.removeprefix("-").strip()
    pos, seconds, units = 0, 0.0, []
    while pos < len(cleaned):
        match = _DURATION.match(cleaned, pos)
        if match is None:
            break
        seconds += float(match.group(1)) * _UNIT_SECONDS[match.group(2)]
        pos = match.end()
        units.append(match.group(2))
        while pos < len(cleaned) and cleaned[pos] == " ":
            pos += 1
    # a bare number is seconds only alone: "2h30" might mean minutes
    if not units or pos != len(cleaned) or (len(units) > 1 and "" in units):
        raise HarnessError(
            f"--time-limit: cannot read '{text}' as a duration",
            "write it like 90m, 2h, 1h30m or 5400 (seconds)",
        )
    if negative or seconds <= 0:
        raise HarnessError(
            f"--time-limit must be positive, got '{text}'",
            "pass a duration like 90m or 2h, or leave the option out",
        )
    return seconds


def _joined_time_limit(argv: list[str]) -> list[str]:
    """``--time-limit -5m`` as ``--time-limit=-5m``: argparse takes a value that starts with
    '-' for an option and answers with its usage; joined, the limit's own check says on one
    line what is wrong with it."""
    joined: list[str] = []
    for arg in argv:
        if joined and joined[-1] == "--time-limit" and arg.startswith("-"):
            joined[-1] = f"--time-limit={arg}"
        else:
            joined.append(arg)
    return joined


def default_store(profile: str | None) -> Path:
    if os.environ.get("REPLICATE_STORE"):
        return Path(os.environ["REPLICATE_STORE"])
    return SMOKE_STORE if profile == "smoke" else DEFAULT_STORE


def subcommands() -> list[Command]:
    """Every subcommand, in the order ``--help`` lists them: the figures' own from the
    figure registry (``replicate.figures.registry``)."""
    from replicate.figures.registry import figure_commands

    return [
        cli_runs.TRAIN,
        cli_runs.DEMOS,
        cli_runs.EXPERT,
        *figure_commands(),
        cli_report.REPORT,
        cli_report.TABLE1,
        cli_confirm.CONFIRM,
        cli_runs.CARRY,
        cli_runs.ALGOS,
        cli_runs.ENVS,
    ]


def _build_parser(commands: list[Command]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m replicate",
        description="Replication harness for DRL-EG (SAC with demonstration-guided exploration).",
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for command in commands:
        command.declare(sub)
    return parser


def _refreshing_front_door(args: argparse.Namespace, code: int, writes_report: set[str]) -> int:
    """After a figure command wrote into reports/ (no --out, a profile that means
    something), refresh the front door reports/index.html from the reports there."""
    if (
        code == 0
        and not getattr(args, "dry_run", False)  # a dry run writes nothing
        and args.command in writes_report
        and getattr(args, "out", None) is None
        and getattr(args, "profile", "quick") != "smoke"
        and Path("reports").is_dir()
    ):
        from replicate.figures.registry import describe
        from replicate.reports.frontdoor import write_front_door

        print(f"front door: {write_front_door(Path('reports'), describe)}")
    return code


def main(argv: list[str] | None = None) -> int:
    from replicate.errors import HarnessError, TimeLimitStop
    from replicate.figures.registry import figure_commands

    argv = _joined_time_limit(sys.argv[1:] if argv is None else list(argv))
    commands = subcommands()
    args = _build_parser(commands).parse_args(argv)
    run = {command.name: command.run for command in commands}[args.command]
    writes_report = {command.name for command in figure_commands()} | {"table1"}
    if getattr(args, "store", "absent") is None:
        args.store = default_store(getattr(args, "profile", None))
    try:
        if getattr(args, "time_limit", None) is None:
            return _refreshing_front_door(args, run(args), writes_report)
        limit = parse_time_limit(args.time_limit)  # before anything is trained
        from replicate.grids.experiments import time_limit

        with time_limit(time.time() + limit):
            return _refreshing_front_door(args, run(args), writes_report)
    except TimeLimitStop as stop:
        print(
            f"time limit reached ({args.time_limit}): {stop}; run the same command again "
            f"to resume: {shlex.join(['python', '-m', 'replicate', *argv])}",
            file=sys.stderr,
        )
        return TIME_LIMIT_EXIT
    except HarnessError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(
            "interrupted: complete runs are kept in the store; run the same command again "
            "to finish the rest",
            file=sys.stderr,
        )
        return 130


if __name__ == "__main__":
    sys.exit(main())
