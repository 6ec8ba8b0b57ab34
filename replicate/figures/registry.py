"""Every report the harness writes under reports/<profile>/, in one registry: its directory
name, how it is rebuilt from the run store, how the front door describes it and the
command that trains its grid. `nox -s report`, the front door and the command line loop
over it; a new figure is one module that calls ``register`` (listed in
``FIGURE_MODULES``) and one template.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from replicate.grids.options import Command

# Modules that register a figure of their own (the built-in ones are declared below, their
# writers imported only when a report is rebuilt, so the front door stays light).
FIGURE_MODULES = ("replicate.figures.guided_share", "replicate.figures.random_start")


@dataclass(frozen=True)
class FigureReport:
    """One report: ``rebuild(profile, store, out_dir, seeds)`` writes it from the runs in the
    store and returns its index (None: the store holds none of its runs, nothing is written;
    ``seeds``: how many seeds a grid report covers, None for the profile's);
    ``describe(summary)`` gives the front door's 'covers', 'budget' and 'seeds' words;
    ``command``, where the figure trains a grid of its own, its ``python -m replicate``
    subcommand (reports that share one command name it once)."""

    name: str  # its directory under reports/ (quick) or reports/<profile>/
    rebuild: Callable[[str, Path, Path, int | None], Path | None]
    describe: Callable[[dict[str, Any]], dict[str, str]]
    command: Command | None = None


_FIGURES: dict[str, FigureReport] = {}


def register(figure: FigureReport) -> FigureReport:
    _FIGURES[figure.name] = figure
    return figure


def figures() -> dict[str, FigureReport]:
    """The registered reports by directory name (their modules imported on first use)."""
    for module in FIGURE_MODULES:
        importlib.import_module(module)
    return dict(_FIGURES)


def figure_commands() -> list[Command]:
    """The subcommands of the registered figures, in the registry's order."""
    commands = (figure.command for figure in figures().values() if figure.command is not None)
    return list({command.name: command for command in commands}.values())


def steps_words(n: int) -> str:
    """50k, 1M: how budgets are spoken of."""
    if n >= 1_000_000 and n % 1_000_000 == 0:
        return f"{n // 1_000_000}M"
    return f"{n / 1000:g}k" if n >= 1000 else str(n)


def budget_words(steps: list[int]) -> str:
    """The range of budgets, e.g. '20k to 200k', or one budget alone; '' for none."""
    if not steps:
        return ""
    return " to ".join(dict.fromkeys(steps_words(s) for s in (min(steps), max(steps))))


def seed_words(counts: list[int]) -> str:
    if not counts:
        return ""
    low, high = min(counts), max(counts)
    return f"{low} seeds" if low == high else f"{low}-{high} seeds"


# The built-in reports, in the order `nox -s report` rebuilds them.


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


def _describe_fig3(summary: dict[str, Any]) -> dict[str, str]:
    envs = {f["env_id"] for f in summary["final_returns"]}
    return {
        "covers": f"Fig. 3: learning curves on {len(envs)} env(s), claims 1-4"
        if envs
        else "Fig. 3: no runs yet",
        "budget": ", ".join(
            f"{env.split('-v')[0].split('Continuous')[0]} {steps_words(steps)}"
            for env, steps in summary.get("budgets", {}).items()
        ),
        "seeds": seed_words([len(f["seeds"]) for f in summary["final_returns"]]),
    }


def _describe_fig4(summary: dict[str, Any]) -> dict[str, str]:
    return {
        "covers": f"Fig. 4: SAC and DRL-EG on {summary['env_id']} from shared seeds, claim 5",
        "budget": steps_words(summary["steps"]) if summary.get("steps") else "",
        "seeds": f"{len(summary['rows'])} pairs",
    }


def _describe_rlfd(summary: dict[str, Any]) -> dict[str, str]:
    return {
        "covers": "DRL-EG against IBRL, RLPD, JSRL, SAC and DDPGfD on shared demonstrations",
        "budget": budget_words([steps for steps, _ in summary.get("budgets", {}).values()]),
        "seeds": seed_words([c["n"] for c in summary["cells"]]),
    }


def _describe_ablation(summary: dict[str, Any]) -> dict[str, str]:
    return {
        "covers": f"DRL-EG's threshold T2 swept on {summary['env_id']}",
        "budget": steps_words(summary["steps"]) if summary.get("steps") else "",
        "seeds": seed_words([len(r["runs"]) for r in summary["rows"]]),
    }


def _register_built_in() -> None:
    from replicate.cli import figures as cli_figures

    register(FigureReport("fig3", _fig3, _describe_fig3, cli_figures.FIG3))
    register(FigureReport("fig4", _fig4, _describe_fig4, cli_figures.FIG4))
    register(FigureReport("rlfd", _rlfd, _describe_rlfd, cli_figures.COMPARE_RLFD))
    for name, env in (
        ("ablate-threshold", "MountainCarContinuous-v0"),
        ("ablate-threshold-ant", "Ant-v5"),
        ("ablate-threshold-walker2d", "Walker2d-v5"),
    ):
        register(
            FigureReport(name, _ablation(env), _describe_ablation, cli_figures.ABLATE_THRESHOLD)
        )


_register_built_in()
