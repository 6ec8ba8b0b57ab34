"""A figure's grid against the run store: the cells chosen to train, the runs stored and
those absent, and the lines a report gives the cells it lacks."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from replicate.errors import HarnessError
from replicate.grids.drl_eg_settings import T2_WAIT_REASON, waits_for_t2_rule
from replicate.grids.experiments import GridOptions, run_grid
from replicate.grids.profiles import GridOutcome
from replicate.store import checkpoint_places
from replicate.store.provenance import portable_path
from replicate.store.query import runs_of
from replicate.store.runner import prepare
from replicate.store.spec import RunSpec


def algorithm_overrides(algo: str, overrides: dict[str, Any]) -> dict[str, Any]:
    """The profile's overrides that ``algo``'s config has (each takes what it knows)."""
    from baselines.registry import get_algorithm

    known = {f.name for f in dataclasses.fields(get_algorithm(algo).config_cls)}
    return {k: v for k, v in overrides.items() if k in known}


def without_waiting(
    specs: list[RunSpec], skipped: list[tuple[str, str, str]], profile: str
) -> tuple[list[RunSpec], list[tuple[str, str, str]]]:
    """A grid less its cells that wait for the MuJoCo T2 rule, those listed as skipped: a
    report never shows them, even where the store holds runs of the same spec (the
    ablation's 1x point is one)."""
    waiting = [s for s in specs if waits_for_t2_rule(profile, s.env_id, s.algo)]
    return (
        [s for s in specs if s not in waiting],
        skipped + sorted({(s.env_id, s.algo, T2_WAIT_REASON) for s in waiting}),
    )


def absent_cells(
    specs: list[RunSpec], command: str, store: Path | None = None
) -> list[tuple[str, str, str]]:
    """A report's (env, algo, reason) line per cell for the runs not in the store yet, with
    the seeds each cell lacks and, for those whose checkpoints are kept elsewhere
    (``replicate.store.checkpoint_places``: carried, say), where and the step they are kept at."""
    kept = checkpoint_places.kept(store)
    carried_at = {run_id: k.step for k in kept for run_id in k.members}
    kept_where = {run_id: k.where for k in kept for run_id in k.members}
    seeds: dict[tuple[str, str], list[int]] = {}
    steps: dict[tuple[str, str], list[tuple[int, int]]] = {}
    wheres: dict[tuple[str, str], Path] = {}
    for spec in specs:
        cell = (spec.env_id, spec.algo)
        seeds.setdefault(cell, []).append(spec.seed)
        run_id = prepare(spec).run_id if carried_at else None
        if run_id in carried_at:
            steps.setdefault(cell, []).append((spec.seed, carried_at[run_id]))
            wheres[cell] = kept_where[run_id]
    lines = []
    for cell, lacking in seeds.items():
        one = len(lacking) == 1
        carried_note = ""
        if cell in steps:
            at = ", ".join(f"seed {seed} at step {step:,}" for seed, step in sorted(steps[cell]))
            where = portable_path(wheres[cell])
            carried_note = f"; carried unfinished in {where}: {at}"
        lines.append(
            (
                *cell,
                f"{'seed' if one else 'seeds'} {', '.join(map(str, sorted(lacking)))} "
                f"not in the store yet{carried_note} (run `{command}` to "
                f"{'train' if not carried_note else 'train or resume'} "
                f"{'it' if one else 'them'})",
            )
        )
    return lines


def stored_outcome(
    specs: list[RunSpec],
    skipped: list[tuple[str, str, str]],
    profile: str,
    store: Path,
    command: str,
) -> GridOutcome | None:
    """A grid's outcome from the store alone, for a rebuilt report: its complete runs, the
    cells that wait for the T2 rule and the runs not there yet listed as skipped; None when
    the store holds none of its runs."""
    specs, skipped = without_waiting(specs, skipped, profile)
    runs, absent = runs_of(specs, store)
    if not runs:
        return None
    return GridOutcome(runs, [], None, skipped + absent_cells(absent, command, store))


def select_cells(
    specs: list[RunSpec], algos: list[str] | None, envs: list[str] | None
) -> list[RunSpec]:
    """The specs of a grid whose algorithm is in ``algos`` and env in ``envs`` (None: any);
    a name the grid does not have is a one-line error that lists the ones it has."""
    for chosen, field, flag in ((algos, "algo", "--algos"), (envs, "env_id", "--envs")):
        if chosen is None:
            continue
        have = sorted({getattr(s, field) for s in specs})
        unknown = [name for name in chosen if name not in have]
        if unknown:
            raise HarnessError(
                f"{flag}: {', '.join(unknown)} not in this grid", f"choose from {', '.join(have)}"
            )
    return [
        s
        for s in specs
        if (algos is None or s.algo in algos) and (envs is None or s.env_id in envs)
    ]


def train_cells(
    specs: list[RunSpec],
    chosen: list[RunSpec],
    store: Path,
    command: str,
    options: GridOptions = GridOptions(),
) -> GridOutcome:
    """Train the ``chosen`` part of a grid (what is missing of it); the outcome holds every
    complete run of the whole grid, and the cells outside ``chosen`` that are still absent
    are listed, so a report written from it covers the whole grid."""
    outcome = run_grid(chosen, store, options)
    if len(chosen) == len(specs) or options.dry_run:
        return outcome
    outcome.runs, absent = runs_of(specs, store)  # in the grid's order
    outcome.skipped = absent_cells([spec for spec in absent if spec not in chosen], command, store)
    return outcome
