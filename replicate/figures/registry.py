"""Every report the harness writes under reports/<profile>/, in one registry: its directory
name, how it is rebuilt from the run store, how the front door describes it and the
command that trains its grid. `nox -s report`, the front door and the command line loop
over it. A new figure is one module that defines ``FIGURE`` (a ``FigureReport``), named in
``PLUG_INS`` below, and one template; the built-in ones are declared here, their writers
imported only when a report is rebuilt, so the front door stays light.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from replicate.figures import commands, guided_share, random_start
from replicate.figures.figure import FigureReport
from replicate.grids.options import Command
from replicate.reports import words

PLUG_INS = (guided_share.FIGURE, random_start.FIGURE)


def _fig3(profile: str, store: Path, out: Path, seeds: int | None) -> Path | None:
    from replicate.figures.fig3 import rebuild_figure3

    return rebuild_figure3(profile=profile, seeds=seeds, store=store, out_dir=out)


def _fig4(profile: str, store: Path, out: Path, seeds: int | None) -> Path | None:
    from replicate.demos import default_demo_path
    from replicate.figures.fig4 import FIG4_ENV, rebuild_figure4

    if not default_demo_path(FIG4_ENV).is_file():
        return None
    return rebuild_figure4(profile, FIG4_ENV, None, store, out)


def _rlfd(profile: str, store: Path, out: Path, seeds: int | None) -> Path | None:
    from replicate.figures.rlfd import rebuild_rlfd

    return rebuild_rlfd(profile, store, out)


def _ablation(env_id: str) -> Callable[[str, Path, Path, int | None], Path | None]:
    def rebuild(profile: str, store: Path, out: Path, seeds: int | None) -> Path | None:
        from replicate.figures.ablation import rebuild_threshold_ablation

        return rebuild_threshold_ablation(profile, store, out, env_id)

    return rebuild


def _built_in() -> list[FigureReport]:
    """The built-in reports, in the order `nox -s report` rebuilds them."""
    built = [
        FigureReport("fig3", _fig3, words.describe_fig3, commands.FIG3),
        FigureReport("fig4", _fig4, words.describe_fig4, commands.FIG4),
        FigureReport("rlfd", _rlfd, words.describe_rlfd, commands.COMPARE_RLFD),
    ]
    for name, env in (
        ("ablate-threshold", "MountainCarContinuous-v0"),
        ("ablate-threshold-ant", "Ant-v5"),
        ("ablate-threshold-walker2d", "Walker2d-v5"),
    ):
        built.append(
            FigureReport(name, _ablation(env), words.describe_ablation, commands.ABLATE_THRESHOLD)
        )
    return built


def figures() -> dict[str, FigureReport]:
    """The registered reports by directory name, built-in first, then the plug-ins."""
    return {figure.name: figure for figure in (*_built_in(), *PLUG_INS)}


def figure_commands() -> list[Command]:
    """The subcommands of the registered figures, in the registry's order."""
    chosen = (figure.command for figure in figures().values() if figure.command is not None)
    return list({command.name: command for command in chosen}.values())


def describe(name: str, summary: dict[str, Any]) -> dict[str, str] | None:
    """The front door's words for report ``name`` (None: a report the registry lacks)."""
    figure = figures().get(name)
    return None if figure is None else figure.describe(summary)
