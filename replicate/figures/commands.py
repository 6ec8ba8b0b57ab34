"""The built-in figure commands of ``python -m replicate`` (fig3, fig4, ablate-threshold,
compare-rlfd): their options and handlers. Each trains what its grid lacks and writes its
report; the figure registry names them."""

from __future__ import annotations

import argparse
from typing import Any

from replicate.grids.options import (
    Command,
    HelpFormatter,
    add_grid_arguments,
    profiles_help,
    run_figure,
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


FIG3 = Command("fig3", _declare_fig3, _cmd_fig3)
FIG4 = Command("fig4", _declare_fig4, _cmd_fig4)
ABLATE_THRESHOLD = Command("ablate-threshold", _declare_ablate, _cmd_ablate)
COMPARE_RLFD = Command("compare-rlfd", _declare_rlfd, _cmd_rlfd)
