"""A report as the figure registry knows it: its directory, how it is rebuilt from the run
store, how the front door describes it, and the command that trains its grid."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from replicate.grids.options import Command


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
