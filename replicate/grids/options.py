"""What the commands of ``python -m replicate`` share: the options every figure command that
trains a grid takes (declared once), the device and time-limit options, their help, and
``Command``, a subcommand's declaration and handler."""

from __future__ import annotations

import argparse
import dataclasses
import inspect
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from replicate.grids.profiles import PROFILES

PROFILE_NAMES = tuple(PROFILES)
STORE_HELP = (
    "run store directory (default: $REPLICATE_STORE, else runs/, the committed "
    "store, or runs-smoke/ for the smoke profile)"
)
# Exit status of a command stopped at its --time-limit (sysexits' EX_TEMPFAIL: try again),
# so that a job script can tell "resume me" from success and from failure.
TIME_LIMIT_EXIT = 75


def positive_int(text: str) -> int:
    """An argparse type: a whole number of at least 1 (a count of workers or seeds)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {value}")
    return value


class HelpFormatter(argparse.HelpFormatter):
    """States an option's default once: appended only where its help does not already say
    it and there is one to state (ArgumentDefaultsHelpFormatter appends "(default: None)"
    even after a help that names its own default)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if (
            "default" in text.lower()
            or not action.option_strings
            or action.default in (None, False, [], argparse.SUPPRESS)
        ):
            return text
        return text + " (default: %(default)s)"


def profiles_help(lead: str = "budget profile") -> str:
    """Every profile with its description, for the --profile options."""
    described = [
        f"{name}: {profile.summary}"
        + ("; its numbers mean nothing." if not profile.meaningful else ".")
        for name, profile in PROFILES.items()
    ]
    return f"{lead}. " + " ".join(described)


def add_time_limit_argument(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--time-limit",
        default=None,
        metavar="DURATION",
        help="stop cleanly after this long (90m, 2h, 1h30m, or seconds): "
        "finished runs are kept, running ones checkpoint at their next "
        "episode end and stop, the rest do not start; the same command "
        f"resumes them. Exit status {TIME_LIMIT_EXIT}; no limit by default",
    )


def device_help() -> str:
    """The --device help, naming the registered algorithms that have a GPU path."""
    from baselines.registry import algorithms

    gpu = sorted(name for name, algorithm in algorithms().items() if algorithm.gpu)
    return (
        f"where algorithms with a GPU path ({', '.join(gpu)}) train: auto takes the GPU "
        "when torch sees one; cuda fails without one. The others train on CPU. Curves are "
        "reproducible bit for bit on CPU only"
    )


def add_device_argument(parser: argparse.ArgumentParser, grid: bool = False) -> None:
    from baselines.registry import batchable_algorithms

    parser.add_argument(
        "--device", default="auto", choices=["auto", "cpu", "cuda"], help=device_help()
    )
    if grid:
        parser.add_argument(
            "--gpu-workers",
            type=int,
            default=None,
            help="with --device auto and a GPU: only this many workers train "
            "on it, the others on the CPU cores. One GPU serves about two "
            "runs at once, so 2 is faster on a many-core machine, but "
            "which runs land on the GPU then depends on scheduling "
            "(default: every worker on the GPU)",
        )
        parser.add_argument(
            "--batch",
            type=int,
            default=None,
            metavar="N",
            help="train up to N runs that differ only in seed together in "
            f"one process ({', '.join(batchable_algorithms())}; the others "
            "train one per process). Default: on a GPU as many as fit its "
            "memory (up to 64), on CPU none",
        )


def add_cell_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--algos",
        nargs="+",
        default=None,
        metavar="ALGO",
        help="train only these algorithms' cells of the grid (the report is "
        "still written from every run of the grid in the store)",
    )
    parser.add_argument(
        "--envs",
        nargs="+",
        default=None,
        metavar="ENV",
        help="train only these environments' cells of the grid",
    )
    parser.add_argument(
        "--dry-run",
        action="store_true",
        help="print the runs that would train, per cell, with their env steps "
        "and estimated minutes; train and write nothing",
    )


CHECKPOINT_HELP = (
    "env steps between checkpoints of each run or seed batch (0: none); an interrupted "
    "command resumes its unfinished runs from them. A batch's holds every member's replay, "
    "so give large batches more"
)
DRY_RUN_HELP = (
    "print the runs that would train, with their env steps and estimated minutes; train "
    "and write nothing"
)


def add_grid_arguments(
    parser: argparse.ArgumentParser,
    out_help: str,
    profile_default: str = "quick",
    profile_help: str | None = None,
    seeds_help: str | None = "number of seeds (default: the profile's)",
    ray: bool = False,
    cells: bool = False,
) -> None:
    """The options every figure command that trains a grid shares, declared once."""
    parser.add_argument(
        "--profile",
        default=profile_default,
        choices=PROFILE_NAMES,
        help=profile_help or profiles_help(),
    )
    if seeds_help is not None:
        parser.add_argument("--seeds", type=int, default=None, help=seeds_help)
    parser.add_argument(
        "--workers",
        type=positive_int,
        default=None,
        help="parallel training processes (default: one per core)",
    )
    parser.add_argument("--store", type=Path, default=None, help=STORE_HELP)
    parser.add_argument("--out", type=Path, default=None, help=out_help)
    add_device_argument(parser, grid=True)
    if ray:
        parser.add_argument(
            "--executor",
            default="local",
            choices=["local", "ray"],
            help="local processes, or tasks on a running Ray cluster (--address)",
        )
        parser.add_argument(
            "--address",
            default=None,
            help="HOST:PORT of the Ray head for --executor ray; the run store must "
            "be on a filesystem every node sees",
        )
    parser.add_argument("--checkpoint-interval", type=int, default=10_000, help=CHECKPOINT_HELP)
    add_time_limit_argument(parser)
    if cells:
        add_cell_arguments(parser)
    else:
        parser.add_argument("--dry-run", action="store_true", help=DRY_RUN_HELP)


@dataclass(frozen=True)
class Command:
    """A subcommand: ``declare(sub)`` adds its parser, options and help to the subparsers
    ``sub``; ``run(args)`` carries it out and returns the exit status."""

    name: str
    declare: Callable[[Any], None]
    run: Callable[[argparse.Namespace], int]


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
