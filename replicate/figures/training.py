"""A figure command's end to end: train what its grid lacks, then write its report from every
run of the grid in the store, never over a report that names more runs."""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from replicate.errors import HarnessError
from replicate.grids.experiments import GridOptions
from replicate.grids.profiles import GridOutcome
from replicate.grids.train import select_cells, train_cells, without_waiting
from replicate.reports.pages import write_unless_fewer
from replicate.store.spec import RunSpec


def train_and_report(
    specs: list[RunSpec],
    skipped: list[tuple[str, str, str]],
    profile: str,
    command: str,
    store: Path,
    out_dir: Path,
    write: Callable[[GridOutcome, Path], Path],
    algos: list[str] | None = None,
    envs: list[str] | None = None,
    options: GridOptions = GridOptions(),
) -> Path | None:
    """A figure command: train what its grid lacks (of the ``algos`` x ``envs`` cells when
    given; cells that wait for the MuJoCo T2 rule never), then ``write(outcome, out_dir)``
    its report from every run of the grid in the store, never over a report that names more
    runs (``write_unless_fewer``). Returns the report (None: nothing written)."""
    selected = select_cells(specs, algos, envs)
    specs, skipped = without_waiting(specs, skipped, profile)
    chosen = [s for s in selected if s in specs]
    if (algos or envs) and not chosen:
        why = "; they wait for the MuJoCo T2 rule" if selected else ""
        raise HarnessError(
            f"--algos/--envs: no cell of this grid to train there{why}",
            "choose other cells (`--dry-run` lists what is missing)",
        )
    for env_id, algo, reason in skipped:  # the report lists them all; here the chosen ones
        if (algos is None or algo in algos) and (envs is None or env_id in envs):
            print(f"skipped {algo} on {env_id}: {reason}")
    outcome = train_cells(specs, chosen, store, command, options)
    if options.dry_run:
        return None
    outcome.skipped = skipped + outcome.skipped
    report = write_saying_why(Path(out_dir), Path(store), lambda out: write(outcome, out))
    if outcome.failed:
        where = (
            f"the report at {report} lists them"
            if report is not None
            else f"e.g. {outcome.failed[0][0]}: {outcome.failed[0][1]}"
        )
        raise HarnessError(
            f"{len(outcome.failed)} run(s) failed; {where}",
            "read the reasons, fix, and run the same command",
        )
    return report


def write_saying_why(
    out_dir: Path, store: Path, build: Callable[[Path], Path | None]
) -> Path | None:
    """``report.write_unless_fewer``, printing its line when some of the old report's runs
    were missing; returns the index written (None: nothing written)."""
    report, note = write_unless_fewer(out_dir, store, build)
    if note:
        print(note if report is None else f"{out_dir}: {note}")
    return report
